//! A format-1 project (one scanned pair, its points in JSON) written as format 2: the same
//! photos, points, heights, grid and sweep parameters, so that one project model holds both.
//! The pair's photos become `[[photo]]`s "left" and "right" read from their scans and
//! resected from the control points; the mappings keep their source (`from = "points"` is
//! `mappings = "points"`, seed 000; `from = "rigorous"` is `mappings = "sensors"`, seed
//! 004); the points become the format's CSV, in its pixel convention (centres at integers:
//! the core's corner-origin value − 0.5, docs/conventions.md).

use crate::matching::mapping::pmf_set::StereoPoint;
use crate::matching::project::pair::{PairProject, PmfSource, PointFile};
use crate::matching::project::{format_of, parse_points, Project, ProjectError};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Why a format-1 project has no format-2 form.
#[derive(Debug, thiserror::Error)]
pub enum UpgradeError {
    #[error("{path}: [pmf] from = \"file\" names no file: add file = \"pmfs.json\" (the mapping functions as an earlier run wrote them)")]
    MappingsFromFile { path: PathBuf },
    #[error("{path}: point {id:?} is listed twice (ids name points in format 2's CSV)")]
    DuplicateId { path: PathBuf, id: String },
    #[error("{path}: point id {id:?} holds a comma or a line break, which format 2's CSV cannot: rename it")]
    BadId { path: PathBuf, id: String },
    #[error("{path} is format 2 already (it has `format = 2`)")]
    AlreadyFormat2 { path: PathBuf },
    #[error("{new} must be in the old project's directory ({dir}), where its photos and points are named from")]
    Elsewhere { new: PathBuf, dir: PathBuf },
    #[error("{path} exists: it is not overwritten (remove it, or give another name)")]
    Exists { path: PathBuf },
    #[error(transparent)]
    Project(#[from] ProjectError),
    #[error(transparent)]
    Points(#[from] crate::matching::project::pair::PairProjectError),
    #[error("writing {path}: {cause}")]
    Write {
        path: PathBuf,
        cause: std::io::Error,
    },
}

impl UpgradeError {
    /// Whether the user asked for something this cannot do as asked (a usage error), rather
    /// than a file being wrong or unwritable.
    pub fn is_usage(&self) -> bool {
        matches!(
            self,
            UpgradeError::AlreadyFormat2 { .. }
                | UpgradeError::Elsewhere { .. }
                | UpgradeError::Exists { .. }
        )
    }
}

/// What [`write_beside`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct Written {
    pub project: PathBuf,
    pub points: PathBuf,
    pub point_count: usize,
}

/// Reads the format-1 project at `old` and writes it as format 2 to `new` (default
/// OLD-format2.toml beside it) with its points as NEW-points.csv beside that, each written
/// whole (atomically) and only where no file is; what was written is read back as format 2.
pub fn write_beside(old: &Path, new: Option<&Path>) -> Result<Written, UpgradeError> {
    let text = std::fs::read_to_string(old).map_err(|cause| ProjectError::Read {
        path: old.to_path_buf(),
        cause,
    })?;
    if format_of(&text) == Ok(2) {
        return Err(UpgradeError::AlreadyFormat2 {
            path: old.to_path_buf(),
        });
    }
    let p = PairProject::parse(&text, old)?;
    let dir = folder(old);
    let dir = dir.as_path();
    let stem = |f: &Path| {
        f.file_stem()
            .map_or_else(|| "project".into(), |s| s.to_string_lossy().into_owned())
    };
    let project = new.map_or_else(
        || dir.join(format!("{}-format2.toml", stem(old))),
        Path::to_path_buf,
    );
    if std::fs::canonicalize(folder(&project)).ok() != std::fs::canonicalize(dir).ok() {
        return Err(UpgradeError::Elsewhere {
            new: project,
            dir: dir.to_path_buf(),
        });
    }
    let csv_name = format!("{}-points.csv", stem(&project));
    let points = dir.join(&csv_name);
    for f in [&project, &points] {
        if f.exists() {
            return Err(UpgradeError::Exists { path: f.clone() });
        }
    }
    let pts = p.points()?;
    let u = upgrade(&p, &pts, dir, &csv_name)?;
    let write = |path: &Path, text: &str| {
        crate::atomic::write(path, text.as_bytes()).map_err(|cause| UpgradeError::Write {
            path: path.to_path_buf(),
            cause,
        })
    };
    write(&points, &u.csv)?;
    write(&project, &u.toml)?;
    Project::load(&project)?.observations()?;
    Ok(Written {
        project,
        points,
        point_count: pts.gcps.len() + pts.cps.len(),
    })
}

/// A file's directory ("." for a bare name).
fn folder(f: &Path) -> PathBuf {
    match f.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// The format-1 project in `text` (read from `path`) as the format-2 [`Project`] that
/// [`write_beside`] would write, its points read from the JSON once, here.
pub fn read(text: &str, path: &Path) -> Result<Project, UpgradeError> {
    let p = PairProject::parse(text, path)?;
    let pts = p.points()?;
    let dir = folder(path);
    let name = p.points.file.strip_prefix(&dir).unwrap_or(&p.points.file);
    let u = upgrade(&p, &pts, &dir, &name.to_string_lossy())?;
    let mut project = Project::parse(&u.toml, path)?;
    project.points_given = Some(parse_points(&u.csv, &p.points.file, &project.photos)?);
    Ok(project)
}

/// The two files of the upgraded project: the format-2 TOML and its points CSV.
#[derive(Debug, Clone, PartialEq)]
pub struct Upgraded {
    pub toml: String,
    pub csv: String,
}

/// `p` (read from its file) and its points `pts` as format 2. `points_csv` is the name the
/// CSV will have beside the new project; paths are written relative to `dir`, the new
/// project's directory, where the old ones lie below it.
pub fn upgrade(
    p: &PairProject,
    pts: &PointFile,
    dir: &Path,
    points_csv: &str,
) -> Result<Upgraded, UpgradeError> {
    let rel = |f: &Path| -> String {
        let shown = f.strip_prefix(dir).unwrap_or(f);
        quoted(&shown.to_string_lossy())
    };
    let mappings = match (p.pmf.from, &p.pmf.file) {
        (PmfSource::Points, _) => "\"points\"".to_string(),
        (PmfSource::Rigorous, _) => "\"sensors\"".to_string(),
        (PmfSource::File, Some(f)) => format!("\"file\"\nmappings_file = {}", rel(f)),
        (PmfSource::File, None) => {
            return Err(UpgradeError::MappingsFromFile {
                path: p.path.clone(),
            })
        }
    };
    let m = &p.matching;
    let r = &p.regions;
    let mut t = String::new();
    let _ = writeln!(
        t,
        "# Written by `rig dtm upgrade` from {} (format 1: one scanned pair).",
        p.path.file_name().map_or_else(
            || p.path.display().to_string(),
            |n| n.to_string_lossy().into_owned()
        )
    );
    let _ = writeln!(t, "format = 2\ncrs = {}\n", quoted(&p.crs.to_string()));
    for (id, scan) in [("left", &p.photos.left), ("right", &p.photos.right)] {
        let _ = writeln!(t, "[[photo]]\nid = \"{id}\"\nscan = {}\n", rel(scan));
    }
    let _ = writeln!(t, "[points]\nfile = {}\n", quoted(points_csv));
    let _ = writeln!(
        t,
        "[dem]\ncell_m = {}\nheights = [{}, {}]\n",
        num(p.grid.cell_m),
        num(m.h_min),
        num(m.h_max)
    );
    let order = match p.pmf.order {
        0 => "\"auto\"".to_string(),
        n => n.to_string(),
    };
    let _ = writeln!(
        t,
        "[matching]\nmethod = \"sweep\"\nmappings = {mappings}\norder = {order}"
    );
    if let Some(s) = m.h_step {
        let _ = writeln!(t, "h_step = {}", num(s));
    }
    let subpixel = match m.subpixel {
        crate::matching::plane_sweep::refine::Subpixel::Lsm => "lsm",
        crate::matching::plane_sweep::refine::Subpixel::Parabola => "parabola",
    };
    let _ = writeln!(
        t,
        "window = {}\nthreshold = {}\nsubpixel = \"{subpixel}\"\nstride = {}\nsearch_distance = {}\npopulation_threshold = {}",
        m.window,
        num(m.threshold),
        m.stride,
        r.search_distance,
        r.population_threshold
    );
    if let Some(h) = r.height_threshold {
        let _ = writeln!(t, "height_threshold = {}", num(h));
    }
    t.push('\n');
    if let Some(reference) = &p.grid.reference {
        let _ = writeln!(t, "[check]\nreference = {}\n", rel(reference));
    }
    let _ = writeln!(
        t,
        "[limits]\nmax_memory_mb = {}\nmax_candidates_g = {}",
        p.limits.max_memory_mb,
        num(p.limits.max_candidates_g)
    );
    // Format 2 reports the RMSE in metres and pixels of parallax; format 1's per-mille
    // figure is kept as a comment, so that the number is not lost.
    if let Some(h) = p.grid.flying_height_m {
        let _ = writeln!(
            t,
            "\n# format 1 gave flying_height_m = {} (its RMSE in per mille of it): RMSE / {} × 1000",
            num(h),
            num(h)
        );
    }
    Ok(Upgraded {
        toml: t,
        csv: points_csv_text(pts, &p.path)?,
    })
}

/// The points as format 2's CSV (`id,kind,x,y,z,photo,col,row`, pixel centres at integers).
fn points_csv_text(pts: &PointFile, path: &Path) -> Result<String, UpgradeError> {
    let mut seen = std::collections::BTreeSet::new();
    let mut s = String::from("id,kind,x,y,z,photo,col,row\n");
    for (kind, list) in [("gcp", &pts.gcps), ("cp", &pts.cps)] {
        for q in list.iter() {
            if q.id.contains([',', '\n', '\r']) {
                return Err(UpgradeError::BadId {
                    path: path.to_path_buf(),
                    id: q.id.clone(),
                });
            }
            if !seen.insert(q.id.clone()) {
                return Err(UpgradeError::DuplicateId {
                    path: path.to_path_buf(),
                    id: q.id.clone(),
                });
            }
            line(&mut s, q, kind);
        }
    }
    Ok(s)
}

fn line(s: &mut String, q: &StereoPoint, kind: &str) {
    let g = q.ground;
    for (photo, px) in [("left", q.left), ("right", q.right)] {
        let _ = writeln!(
            s,
            "{},{kind},{},{},{},{photo},{},{}",
            q.id,
            num(g.x),
            num(g.y),
            num(g.z),
            num(px[0] - 0.5),
            num(px[1] - 0.5)
        );
    }
}

/// A number as Rust writes it shortest (it reads back to the same f64).
fn num(v: f64) -> String {
    let s = format!("{v:?}");
    s.strip_suffix(".0").map_or(s.clone(), str::to_string)
}

/// A TOML basic string: quotes, backslashes and control characters escaped.
fn quoted(s: &str) -> String {
    let mut q = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => q.push_str("\\\""),
            '\\' => q.push_str("\\\\"),
            c if c.is_control() => {
                let _ = write!(q, "\\u{:04X}", c as u32);
            }
            c => q.push(c),
        }
    }
    q.push('"');
    q
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::coords::GroundM;
    use crate::matching::project::{parse_points, Kind, Mappings, Project};

    const OLD: &str = r#"
crs = "EPSG:32616"
[photos]
left = "scans/a.json"
right = "scans/b.json"
[points]
file = "points.json"
[pmf]
order = "auto"
from = "points"
[matching]
h_min = 330.5
h_max = 640.0
h_step = 0.7
window = 11
threshold = 0.6
subpixel = "parabola"
stride = 3
[regions]
search_distance = 3
height_threshold = 2.5
population_threshold = 150
[grid]
cell_m = 12.5
reference = "truth dem.tif"
flying_height_m = 6500.0
[limits]
max_memory_mb = 2048
max_candidates_g = 7.5
"#;

    fn point(id: &str, z: f64) -> StereoPoint {
        StereoPoint {
            id: id.into(),
            left: [10.25, 20.0 + z / 1000.0],
            right: [0.1, 1.0 / 3.0],
            ground: GroundM::new(746_398.200_881_036_2, 4_056_146.858_676_112, z),
        }
    }

    /// Every value of the old project reaches its format-2 key, and the points come back in
    /// the core's convention to the last bits the CSV keeps.
    #[test]
    fn an_upgraded_project_reads_back_with_every_value() {
        let dir = Path::new("/data/block");
        let old = PairProject::parse(OLD, &dir.join("old.toml")).unwrap();
        let pts = PointFile {
            gcps: vec![point("g1", 392.0), point("g2", 441.6)],
            cps: vec![point("c1", 500.25)],
        };
        let u = upgrade(&old, &pts, dir, "new-points.csv").unwrap();
        let new = Project::parse(&u.toml, &dir.join("new.toml")).unwrap();
        assert_eq!(new.crs, old.crs);
        assert_eq!(new.photos.len(), 2);
        assert_eq!(new.heights, Some([330.5, 640.0]));
        assert_eq!(new.cell_m, 12.5);
        assert_eq!(new.extent, None);
        assert_eq!(new.reference, Some(dir.join("truth dem.tif")));
        assert_eq!(new.points_file, Some(dir.join("new-points.csv")));
        let m = &new.matching;
        assert_eq!(m.mappings, Mappings::Points);
        assert_eq!(
            (m.order, m.h_step, m.window, m.threshold, m.stride),
            (0, Some(0.7), 11, 0.6, 3)
        );
        assert_eq!(m.subpixel, old.matching.subpixel);
        assert_eq!(
            (
                m.search_distance,
                m.height_threshold,
                m.population_threshold
            ),
            (3, Some(2.5), 150)
        );
        assert_eq!(new.limits.max_memory_mb, 2048);
        assert_eq!(new.limits.max_candidates_g, 7.5);
        assert!(u.toml.contains("flying_height_m = 6500"), "{}", u.toml);
        let obs = parse_points(&u.csv, Path::new("new-points.csv"), &new.photos).unwrap();
        assert_eq!(obs.len(), 6);
        for (o, (p, kind)) in obs.chunks(2).zip([
            (&pts.gcps[0], Kind::Gcp),
            (&pts.gcps[1], Kind::Gcp),
            (&pts.cps[0], Kind::Cp),
        ]) {
            for (ob, (photo, px)) in o.iter().zip([("left", p.left), ("right", p.right)]) {
                assert_eq!(
                    (ob.id.as_str(), ob.kind, ob.photo.as_str()),
                    (p.id.as_str(), kind, photo)
                );
                assert_eq!(ob.ground, Some(p.ground));
                assert!(
                    (ob.col - px[0]).abs() < 1e-12 && (ob.row - px[1]).abs() < 1e-12,
                    "{ob:?}"
                );
            }
        }
    }

    #[test]
    fn mappings_from_a_file_are_kept_and_bad_ids_are_refused_by_name() {
        let dir = Path::new("/data/block");
        let pts = PointFile {
            gcps: vec![point("g1", 1.0)],
            cps: vec![],
        };
        let file = OLD.replace(
            "from = \"points\"",
            "from = \"file\"\nfile = \"maps/pmfs.json\"",
        );
        let old = PairProject::parse(&file, &dir.join("old.toml")).unwrap();
        let u = upgrade(&old, &pts, dir, "p.csv").unwrap();
        let new = Project::parse(&u.toml, &dir.join("new.toml")).unwrap();
        assert_eq!(new.matching.mappings, Mappings::File);
        assert_eq!(new.matching.mappings_file, Some(dir.join("maps/pmfs.json")));
        let old = PairProject::parse(OLD, &dir.join("old.toml")).unwrap();
        let twice = PointFile {
            gcps: vec![point("g1", 1.0)],
            cps: vec![point("g1", 2.0)],
        };
        let e = upgrade(&old, &twice, dir, "p.csv").unwrap_err().to_string();
        assert!(e.contains("\"g1\" is listed twice"), "{e}");
        let comma = PointFile {
            gcps: vec![point("g,1", 1.0)],
            cps: vec![],
        };
        let e = upgrade(&old, &comma, dir, "p.csv").unwrap_err().to_string();
        assert!(e.contains("comma"), "{e}");
        // mappings = "points" is the sweep's alone.
        let u = upgrade(&old, &pts, dir, "p.csv").unwrap();
        let mgcm = u.toml.replace("method = \"sweep\"", "method = \"mgcm\"");
        let e = Project::parse(&mgcm, &dir.join("new.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("mappings = \"points\" is the sweep's"), "{e}");
    }
}
