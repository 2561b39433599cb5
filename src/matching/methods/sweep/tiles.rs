//! A run split between machines: `rig dtm PROJECT --tile I/N` sweeps a share of the work and
//! `rig dtm merge TILE_DIR… --out DIR` finishes the run from all shares.
//!
//! The unit of work is a band of [`BAND_ROWS`](crate::matching::methods::sweep::height_sweep::BAND_ROWS) rows of one pair's
//! sweep (the longest step by far). A band's heights depend on nothing outside it (the
//! neighbours that bracket a height are taken within the band; each window reads the photo
//! rows it needs, the overlap), so the shares hold exactly the heights one machine would find.
//! What needs the whole model — wrong-height regions that cross shares, the grid, the variance
//! factor, the orthophoto — runs in the merge, on the joined heights, the same code as a
//! single run: the merged outputs are the single run's, byte for byte.

use crate::matching::block::photo::Photo;
use crate::matching::block::photos::{load_photo, load_photos, views};
use crate::matching::methods::context::{prepare, Run};
use crate::matching::methods::sweep::height_sweep::SweptBands;
use crate::matching::methods::sweep::plan::plan;
use crate::matching::methods::sweep::plan::Plan;
use crate::matching::methods::sweep::PairPart;
use crate::matching::methods::sweep::{finish, sweep_units, SweepReport};
use crate::matching::progress::Progress;
use crate::matching::project::{Method, Project};
use crate::matching::MatchingError;
use serde::{Deserialize, Serialize};
use std::ops::Range;
use std::path::{Path, PathBuf};

/// The tile's description in its directory.
pub const MANIFEST: &str = "tile.json";
const FORMAT: &str = "rig dtm tile";

/// Share `index` (1…count) of a run split in `count`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TileSpec {
    pub index: usize,
    pub count: usize,
}

/// Most shares a run may be split in.
pub const MAX_TILES: usize = 100_000;

impl std::str::FromStr for TileSpec {
    type Err = String;
    fn from_str(s: &str) -> Result<TileSpec, String> {
        let bad = || {
            format!("`{s}`: give the share as I/N with 1 ≤ I ≤ N ≤ {MAX_TILES}, e.g. 3/16 (a Slurm array: --tile $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT)")
        };
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let i: usize = i.trim().parse().map_err(|_| bad())?;
        let n: usize = n.trim().parse().map_err(|_| bad())?;
        if i == 0 || i > n || n > MAX_TILES {
            return Err(bad());
        }
        Ok(TileSpec { index: i, count: n })
    }
}

impl std::fmt::Display for TileSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl TileSpec {
    /// This share's units of `total`: contiguous, as even as whole units allow, all shares
    /// together covering 0..total once.
    pub fn units(&self, total: usize) -> Range<usize> {
        let at = |k: usize| ((k as u128 * total as u128) / self.count as u128) as usize;
        at(self.index - 1)..at(self.index)
    }
}

/// One pair's bands in a tile directory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PartEntry {
    /// The pair's place in the plan (0-based) and its photos.
    pub pair: usize,
    pub left: String,
    pub right: String,
    pub bands: [usize; 2],
    pub rows: [usize; 2],
    /// Cells of the rows: the file holds heights, correlations and σ, each `cells` f32
    /// little-endian, one after the other.
    pub cells: usize,
    pub candidates: u64,
    pub seconds: f64,
    pub file: String,
}

/// `tile.json`: which share of which project a directory holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TileManifest {
    pub format: String,
    pub rig_version: String,
    /// The project, absolute, and a hash of its bytes: the merge reads the same file and
    /// refuses it changed.
    pub project: PathBuf,
    pub project_fnv64: String,
    /// A hash of everything the sweep's heights depend on besides the project file: the plan
    /// (orientations from the points, mappings, parameters) and every photo's pixels. Shares
    /// and the merge must agree on it.
    pub inputs_fnv64: String,
    pub tile: usize,
    pub of: usize,
    pub units: [usize; 2],
    pub total_units: usize,
    pub parts: Vec<PartEntry>,
}

#[derive(Debug, thiserror::Error)]
pub enum TileError {
    #[error("{path}: {cause}")]
    Io {
        path: PathBuf,
        cause: std::io::Error,
    },
    #[error("{path}: not a tile of `rig dtm --tile` ({cause})")]
    Manifest {
        path: PathBuf,
        cause: serde_json::Error,
    },
    #[error("{path}: {message}")]
    Damaged { path: PathBuf, message: String },
    #[error("the tiles do not belong together: {0}")]
    Mismatch(String),
    #[error("--tile splits the sweep's work; {project} uses method \"{method}\": run it whole")]
    NotSweep { project: PathBuf, method: Method },
    /// The project or its inputs changed between the shares' sweep and the merge.
    #[error("{0}: sweep the tiles again")]
    Changed(String),
    #[error(transparent)]
    Matching(#[from] MatchingError),
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> TileError + '_ {
    move |cause| TileError::Io {
        path: path.to_path_buf(),
        cause,
    }
}

/// The bytes of a part's file: heights, correlations, σ.
fn encode(b: &SweptBands) -> Vec<u8> {
    let mut v = Vec::with_capacity(12 * b.h.len());
    for a in [&b.h, &b.corr, &b.sigma] {
        for x in a.iter() {
            v.extend_from_slice(&x.to_le_bytes());
        }
    }
    v
}

/// Writes a tile's parts and then its manifest (last, so a directory with a manifest is whole)
/// into `dir`; every file atomically.
pub fn write_tile(
    dir: &Path,
    source: &Inputs<'_>,
    spec: TileSpec,
    plan: &Plan,
    photo_ids: &[String],
    parts: &[PairPart],
) -> Result<TileManifest, TileError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let mut entries = Vec::new();
    for p in parts {
        let file = part_file(p.pair, p.bands.bands.clone());
        let path = dir.join(&file);
        crate::atomic::write(&path, &encode(&p.bands)).map_err(io(&path))?;
        let pair = &plan.pairs[p.pair];
        entries.push(PartEntry {
            pair: p.pair,
            left: photo_ids[pair.left].clone(),
            right: photo_ids[pair.right].clone(),
            bands: [p.bands.bands.start, p.bands.bands.end],
            rows: [p.bands.rows.start, p.bands.rows.end],
            cells: p.bands.h.len(),
            candidates: p.bands.candidates,
            seconds: p.seconds,
            file,
        });
    }
    let u = spec.units(plan.units());
    let m = TileManifest {
        format: FORMAT.into(),
        rig_version: env!("CARGO_PKG_VERSION").into(),
        project: source.project.to_path_buf(),
        project_fnv64: crate::atomic::fnv64(source.project_bytes),
        inputs_fnv64: source.inputs_fnv64.clone(),
        tile: spec.index,
        of: spec.count,
        units: [u.start, u.end],
        total_units: plan.units(),
        parts: entries,
    };
    let path = dir.join(MANIFEST);
    crate::atomic::write_json(&path, &m).map_err(io(&path))?;
    Ok(m)
}

/// The name of a part's file in its tile directory.
fn part_file(pair: usize, bands: Range<usize>) -> String {
    format!(
        "pair-{}-bands-{}-{}.f32",
        pair.saturating_add(1),
        bands.start,
        bands.end
    )
}

/// What a share was swept from: the project file (its absolute path and bytes) and the hash of
/// the plan and the photos' pixels ([`inputs_fingerprint`]).
pub struct Inputs<'a> {
    pub project: &'a Path,
    pub project_bytes: &'a [u8],
    pub inputs_fnv64: String,
}

/// The hash of a plan and of each photo's pixels (`pixels[k]`: [`pixels_fnv64`] of photo k).
pub fn inputs_fingerprint(plan: &Plan, pixels: &[String]) -> String {
    // The plan's Debug form writes every number exactly (shortest round-trip form); the
    // budget (--max-memory) may differ between machines and changes no height.
    let mut q = plan.clone();
    q.budget = crate::matching::methods::sweep::pair_model::Budget {
        max_memory_mb: 0,
        max_candidates: 0.0,
    };
    let mut text = format!("{q:?}");
    for p in pixels {
        text.push('\n');
        text.push_str(p);
    }
    crate::atomic::fnv64(text.as_bytes())
}

/// The hash of an image's pixels.
pub fn pixels_fnv64(img: &crate::image::ImageF32) -> String {
    let bytes: Vec<u8> = img.data.iter().flat_map(|v| v.to_le_bytes()).collect();
    crate::atomic::fnv64(&bytes)
}

/// Files a tile directory may hold (a rerun of the same tile replaces them).
fn is_tile_output(name: &str) -> bool {
    name == MANIFEST || (name.starts_with("pair-") && name.ends_with(".f32"))
}

/// Readies `dir` for a share: refused when it holds anything but a share's files; an earlier
/// share's manifest removed first, so that the directory counts as whole again only when the
/// new manifest is written, last.
pub fn prepare_dir(dir: &Path) -> Result<(), TileError> {
    let foreign = crate::atomic::foreign_files(dir, is_tile_output).map_err(io(dir))?;
    if !foreign.is_empty() {
        return Err(TileError::Damaged {
            path: dir.to_path_buf(),
            message: format!(
                "holds files that are not a tile's ({}): give an empty or new directory",
                foreign.join(", ")
            ),
        });
    }
    let m = dir.join(MANIFEST);
    if m.exists() {
        std::fs::remove_file(&m).map_err(io(&m))?;
    }
    Ok(())
}

/// Reads a tile directory's manifest.
pub fn read_manifest(dir: &Path) -> Result<TileManifest, TileError> {
    let path = dir.join(MANIFEST);
    if std::fs::symlink_metadata(&path)
        .is_ok_and(|m| !m.file_type().is_file() || m.len() > 64 << 20)
    {
        return Err(TileError::Damaged {
            path,
            message: "not a regular file of at most 64 MiB".into(),
        });
    }
    let text = std::fs::read_to_string(&path).map_err(|cause| {
        if cause.kind() == std::io::ErrorKind::NotFound {
            TileError::Damaged {
                path: dir.to_path_buf(),
                message: format!("no {MANIFEST}: not a share of `rig dtm PROJECT --tile I/N --out DIR`, or its sweep has not finished (run that share again)"),
            }
        } else {
            TileError::Io {
                path: path.clone(),
                cause,
            }
        }
    })?;
    let m: TileManifest = serde_json::from_str(&text).map_err(|cause| TileError::Manifest {
        path: path.clone(),
        cause,
    })?;
    if m.format != FORMAT {
        return Err(TileError::Damaged {
            path,
            message: format!("format `{}`, not `{FORMAT}`", m.format),
        });
    }
    Ok(m)
}

/// Checks that the manifests are shares 1…N of one run of one project (each once) by this
/// version of the rig, and returns them in share order.
pub fn check_set(
    set: Vec<(PathBuf, TileManifest)>,
) -> Result<Vec<(PathBuf, TileManifest)>, TileError> {
    let Some((d0, m0)) = set.first().cloned() else {
        return Err(TileError::Mismatch("no tile directories given".into()));
    };
    for (d, m) in &set {
        let differs = |what: &str, a: &dyn std::fmt::Display, b: &dyn std::fmt::Display| {
            TileError::Mismatch(format!(
                "{} has {what} {a}, {} has {b}",
                d0.display(),
                d.display()
            ))
        };
        if m.project_fnv64 != m0.project_fnv64 || m.project != m0.project {
            return Err(differs(
                "project",
                &format!("{} ({})", m0.project.display(), m0.project_fnv64),
                &format!("{} ({})", m.project.display(), m.project_fnv64),
            ));
        }
        if m.inputs_fnv64 != m0.inputs_fnv64 {
            return Err(differs(
                "inputs (photos, points, orientations) hashing to",
                &m0.inputs_fnv64,
                &m.inputs_fnv64,
            ));
        }
        if m.of != m0.of {
            return Err(differs("a split in", &m0.of, &m.of));
        }
        if m.total_units != m0.total_units {
            return Err(differs("work units", &m0.total_units, &m.total_units));
        }
        if m.rig_version != m0.rig_version {
            return Err(differs("rig version", &m0.rig_version, &m.rig_version));
        }
        let want = TileSpec {
            index: m.tile.clamp(1, m.of.max(1)),
            count: m.of.max(1),
        }
        .units(m.total_units);
        if m.tile == 0 || m.tile > m.of || m.units != [want.start, want.end] {
            return Err(TileError::Damaged {
                path: d.join(MANIFEST),
                message: format!(
                    "share {}/{} with units {:?}, which is not how the rig splits",
                    m.tile, m.of, m.units
                ),
            });
        }
    }
    let shares: Vec<(&Path, usize, usize)> = set
        .iter()
        .map(|(d, m)| (d.as_path(), m.tile, m.of))
        .collect();
    let order = check_shares(&shares)?;
    let mut set: Vec<Option<(PathBuf, TileManifest)>> = set.into_iter().map(Some).collect();
    let set = order.into_iter().filter_map(|k| set[k].take()).collect();
    Ok(set)
}

/// Checks that `shares` (directory, I, N) are shares 1…N of one split, each once; returns
/// their places in share order.
pub fn check_shares(shares: &[(&Path, usize, usize)]) -> Result<Vec<usize>, TileError> {
    let Some(&(d0, _, n)) = shares.first() else {
        return Err(TileError::Mismatch("no tile directories given".into()));
    };
    if n == 0 || n > MAX_TILES {
        return Err(TileError::Mismatch(format!(
            "{}: a split in {n}; the rig splits in 1 to {MAX_TILES}",
            d0.display()
        )));
    }
    let mut at: Vec<Option<usize>> = vec![None; n];
    for (k, &(d, i, of)) in shares.iter().enumerate() {
        if of != n {
            return Err(TileError::Mismatch(format!(
                "{} is share {i}/{of}, {} a share of {n}",
                d.display(),
                d0.display()
            )));
        }
        if i == 0 || i > n {
            return Err(TileError::Mismatch(format!(
                "{}: share {i}/{of} does not exist",
                d.display()
            )));
        }
        if let Some(j) = at[i - 1] {
            return Err(TileError::Mismatch(format!(
                "share {i}/{n} is given twice: {} and {}",
                shares[j].0.display(),
                d.display()
            )));
        }
        at[i - 1] = Some(k);
    }
    let missing: Vec<String> = (1..=n)
        .filter(|k| at[k - 1].is_none())
        .map(|k| format!("{k}/{n}"))
        .collect();
    if !missing.is_empty() {
        return Err(TileError::Mismatch(format!(
            "{} of {n} shares given; missing {}{}",
            n - missing.len(),
            missing[..missing.len().min(20)].join(", "),
            if missing.len() > 20 { ", …" } else { "" }
        )));
    }
    Ok(at.into_iter().flatten().collect())
}

/// Reads the parts a tile's manifest lists, each checked against the plan of the merge.
pub fn read_parts(dir: &Path, m: &TileManifest, plan: &Plan) -> Result<Vec<PairPart>, TileError> {
    // Exactly the parts the rig sweeps for this share, in order: nothing twice, nothing of
    // another share, so memory stays that of the share.
    let want: Vec<(usize, [usize; 2])> = plan
        .bands_of(m.units[0]..m.units[1])
        .into_iter()
        .map(|(k, b)| (k, [b.start, b.end]))
        .collect();
    let have: Vec<(usize, [usize; 2])> = m.parts.iter().map(|e| (e.pair, e.bands)).collect();
    if have != want {
        return Err(TileError::Damaged {
            path: dir.join(MANIFEST),
            message: format!(
                "its parts (pair, bands) {have:?} are not those of share {}/{}, {want:?}",
                m.tile, m.of
            ),
        });
    }
    let mut out = Vec::new();
    for e in &m.parts {
        // Only the name the rig gives such a part: nothing outside the directory is read.
        let want = part_file(e.pair, e.bands[0]..e.bands[1]);
        if e.file != want {
            return Err(TileError::Damaged {
                path: dir.join(MANIFEST),
                message: format!("a part named `{}`, not `{want}`", e.file),
            });
        }
        let path = dir.join(&e.file);
        let damaged = |message: String| TileError::Damaged {
            path: path.clone(),
            message,
        };
        let pair = plan.pairs.get(e.pair).ok_or_else(|| {
            damaged(format!(
                "pair {} of a plan with {}",
                e.pair + 1,
                plan.pairs.len()
            ))
        })?;
        let l = pair.layout;
        let bands = e.bands[0]..e.bands[1];
        if bands.is_empty() || bands.end > l.bands() {
            return Err(damaged(format!(
                "bands {:?} of a sweep with {}",
                e.bands,
                l.bands()
            )));
        }
        let rows = l.band_rows(bands.clone());
        let cells = rows.len() * l.cols;
        if [rows.start, rows.end] != e.rows || e.cells != cells {
            return Err(damaged(format!(
                "rows {:?} with {} cells; the plan has rows {rows:?} with {cells}",
                e.rows, e.cells
            )));
        }
        // A regular file of the right size before anything is read (not a device or a pipe).
        let meta = std::fs::symlink_metadata(&path).map_err(io(&path))?;
        if !meta.file_type().is_file() || meta.len() != 12 * cells as u64 {
            return Err(damaged(format!(
                "{} bytes of a {}, 3 × {cells} f32 ({} bytes) expected: the file is damaged or cut short",
                meta.len(),
                if meta.file_type().is_file() { "file" } else { "non-file" },
                12 * cells
            )));
        }
        let bytes = std::fs::read(&path).map_err(io(&path))?;
        if bytes.len() != 12 * cells {
            return Err(damaged(format!(
                "{} bytes, {} expected (3 × {cells} f32): the file is damaged or cut short",
                bytes.len(),
                12 * cells
            )));
        }
        let f = |k: usize| -> Vec<f32> {
            bytes[4 * k * cells..4 * (k + 1) * cells]
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        };
        out.push(PairPart {
            pair: e.pair,
            bands: SweptBands {
                bands,
                rows,
                h: f(0),
                corr: f(1),
                sigma: f(2),
                candidates: e.candidates,
            },
            seconds: if e.seconds.is_finite() && e.seconds >= 0.0 {
                e.seconds
            } else {
                0.0
            },
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shares_cover_every_unit_once() {
        for total in [0usize, 1, 7, 16, 1000] {
            for n in [1usize, 2, 3, 7, 16, 50] {
                let mut next = 0;
                for i in 1..=n {
                    let u = TileSpec { index: i, count: n }.units(total);
                    assert_eq!(u.start, next, "total {total}, {i}/{n}");
                    assert!(u.len() <= total.div_ceil(n));
                    next = u.end;
                }
                assert_eq!(next, total);
            }
        }
    }

    #[test]
    fn share_syntax_is_checked() {
        assert_eq!(
            "3/16".parse::<TileSpec>(),
            Ok(TileSpec {
                index: 3,
                count: 16
            })
        );
        for bad in ["0/4", "5/4", "4", "a/b", "1/0", "-1/4", "1/100001", ""] {
            let e = bad.parse::<TileSpec>().unwrap_err();
            assert!(e.contains("1 ≤ I ≤ N"), "{bad}: {e}");
        }
    }
}

/// What a share swept, for its summary.
#[derive(Debug, Clone)]
pub struct Share {
    pub manifest: TileManifest,
    /// The units of work it swept, of `total_units`.
    pub units: Range<usize>,
    pub total_units: usize,
    pub pairs: usize,
    pub photos: usize,
}

/// Share `spec` of project `p`'s sweep into `out`: the plan from every photo's geometry
/// (each photo read once and let go), then the sweep of this share's bands with only the
/// photos of their pairs in memory. `scan` reads the rig's own scans.
pub fn sweep_share(
    p: &Project,
    spec: TileSpec,
    out: &Path,
    max_memory_mb: Option<u64>,
    scan: &crate::matching::block::photo::ScanReader,
    progress: &dyn Progress,
) -> Result<Share, TileError> {
    let project = p.path.as_path();
    let bytes = std::fs::read(project).map_err(io(project))?;
    if p.matching.method != Method::Sweep {
        return Err(TileError::NotSweep {
            project: project.to_path_buf(),
            method: p.matching.method,
        });
    }
    prepare_dir(out)?;
    let mut geometry = Vec::new();
    let mut pixels = Vec::new();
    let wins = views(p, scan)?;
    for (k, &w) in wins.iter().enumerate() {
        let ph = load_photo(p, k, scan, w)?;
        geometry.push(ph.geometry());
        pixels.push(pixels_fnv64(&ph.image));
    }
    let plan = plan(p, &geometry, max_memory_mb)?;
    let units = spec.units(plan.units());
    let mut loaded: Vec<Option<Photo>> = (0..p.photos.len()).map(|_| None).collect();
    for (k, _) in plan.bands_of(units.clone()) {
        for i in [plan.pairs[k].left, plan.pairs[k].right] {
            if loaded[i].is_none() {
                loaded[i] = Some(load_photo(p, i, scan, wins[i])?);
            }
        }
    }
    let refs: Vec<Option<&Photo>> = loaded.iter().map(|o| o.as_ref()).collect();
    let parts = sweep_units(p, &plan, units.clone(), &refs, progress)?;
    let absolute = std::fs::canonicalize(project).map_err(io(project))?;
    let ids: Vec<String> = p.photos.iter().map(|ph| ph.id.clone()).collect();
    let source = Inputs {
        project: &absolute,
        project_bytes: &bytes,
        inputs_fnv64: inputs_fingerprint(&plan, &pixels),
    };
    let manifest = write_tile(out, &source, spec, &plan, &ids, &parts)?;
    Ok(Share {
        manifest,
        units,
        total_units: plan.units(),
        pairs: plan.pairs.len(),
        photos: p.photos.len(),
    })
}

/// `rig dtm merge`: the shares in `dirs` checked to belong together and to the project as it
/// is now, their heights joined, the run finished into `out` as a single run would.
pub fn merge(
    dirs: &[PathBuf],
    out: &Path,
    max_memory_mb: Option<u64>,
    scan: &crate::matching::block::photo::ScanReader,
    progress: &dyn Progress,
) -> Result<(Project, SweepReport), TileError> {
    let mut set = Vec::new();
    for d in dirs {
        set.push((d.clone(), read_manifest(d)?));
    }
    let set = check_set(set)?;
    let m0 = &set[0].1;
    tracing::info!(shares = set.len(), project = %m0.project.display(), "merging");
    let bytes = std::fs::read(&m0.project).map_err(io(&m0.project))?;
    let now = crate::atomic::fnv64(&bytes);
    if now != m0.project_fnv64 {
        return Err(TileError::Changed(format!(
            "{} changed since the tiles were swept (hash {} then, {now} now)",
            m0.project.display(),
            m0.project_fnv64
        )));
    }
    let p = Project::load(&m0.project).map_err(MatchingError::from)?;
    let reference = prepare(&p, out)?;
    let photos = load_photos(&p, scan, progress)?;
    let geometry: Vec<_> = photos.iter().map(|ph| ph.geometry()).collect();
    let plan = plan(&p, &geometry, max_memory_mb)?;
    let pixels: Vec<String> = photos.iter().map(|ph| pixels_fnv64(&ph.image)).collect();
    let now = inputs_fingerprint(&plan, &pixels);
    if now != m0.inputs_fnv64 {
        return Err(TileError::Changed(format!(
            "the photos, points or orientations of {} changed since the tiles were swept (their hash was {}, it is {now})",
            m0.project.display(),
            m0.inputs_fnv64
        )));
    }
    if plan.units() != m0.total_units {
        return Err(TileError::Changed(format!(
            "the tiles split {} units of work, the project now gives {}",
            m0.total_units,
            plan.units()
        )));
    }
    let mut parts = Vec::new();
    for (d, m) in &set {
        parts.extend(read_parts(d, m, &plan)?);
    }
    let run = Run {
        project: &p,
        photos: &photos,
        out,
        reference: reference.as_ref(),
        max_memory_mb,
        progress,
    };
    let report = finish(&run, &plan, parts)?;
    Ok((p, report))
}
