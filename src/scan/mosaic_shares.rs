//! A scan's mosaics split between machines: `rig scan mosaic DIR --tile I/N --out SHARE_DIR`
//! mosaics share I of the scan's photos (regions) into SHARE_DIR, and `rig scan merge
//! SHARE_DIR…` checks every file and puts them into the scan directory. A photo is mosaicked
//! by the same code either way ([`mosaic_region`]), so the merged photos are those of `rig
//! scan mosaic DIR`, byte for byte.

use super::manifest::{fnv64, FileRecord, MANIFEST as SCAN_MANIFEST};
use super::mosaic::Interpolation;
use super::run::{mosaic_region, Reopen, ScanDir, ScanError};
use crate::matching::methods::sweep::tiles::{check_shares, TileError, TileSpec};
use crate::relative::relative_to;
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::path::{Path, PathBuf};

/// The share's description in its directory.
pub const MANIFEST: &str = "mosaic-share.json";
const FORMAT: &str = "rig scan mosaic share";

/// One photo of a share: its files (TIFF, preview, sidecar) with their hashes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SharePhoto {
    pub region: String,
    pub files: Vec<FileRecord>,
}

/// `mosaic-share.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShareManifest {
    pub format: String,
    pub rig_version: String,
    /// The scan directory, absolute, and a hash of its manifest: the merge refuses a scan
    /// that changed since.
    pub scan: PathBuf,
    pub scan_manifest_fnv64: String,
    pub tile: usize,
    pub of: usize,
    /// The scan's regions (photos) `regions[0]..regions[1]`.
    pub regions: [usize; 2],
    pub photos: Vec<SharePhoto>,
}

#[derive(Debug, thiserror::Error)]
pub enum ShareError {
    #[error(transparent)]
    Scan(#[from] ScanError),
    #[error(transparent)]
    Tile(#[from] TileError),
    #[error("{path}: {cause}")]
    Io {
        path: PathBuf,
        cause: std::io::Error,
    },
    #[error("{0}")]
    Refused(String),
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> ShareError + '_ {
    move |cause| ShareError::Io {
        path: path.to_path_buf(),
        cause,
    }
}

/// The files a photo's mosaic consists of.
fn photo_files(region: &str) -> [String; 3] {
    ["tiff", "png", "json"].map(|e| format!("{region}.{e}"))
}

/// Mosaics share `spec` of the scan's photos into `out` (absent, empty or an earlier share's
/// directory of this scan); the manifest is written last, so a share with one is whole.
pub fn mosaic_share(
    sd: &ScanDir,
    spec: TileSpec,
    out: &Path,
    interp: Interpolation,
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> Result<ShareManifest, ShareError> {
    let regions = &sd.manifest.plan.regions;
    let mine = spec.units(regions.len());
    let allowed: Vec<String> = regions
        .iter()
        .flat_map(|r| photo_files(&r.name))
        .chain([MANIFEST.to_string()])
        .collect();
    let foreign =
        crate::atomic::foreign_files(out, |f| allowed.iter().any(|a| a == f)).map_err(io(out))?;
    if !foreign.is_empty() {
        return Err(ShareError::Refused(format!(
            "{} holds files that are not this scan's mosaics ({}): give an empty or new directory",
            out.display(),
            foreign.join(", ")
        )));
    }
    // A share mosaicked again is whole only when its manifest is written again, last.
    let m = out.join(MANIFEST);
    if m.exists() {
        std::fs::remove_file(&m).map_err(io(&m))?;
    }
    std::fs::create_dir_all(out).map_err(io(out))?;
    let mut photos = Vec::new();
    for ri in mine.clone() {
        mosaic_region(sd, ri, interp, out, progress)?;
        let name = &regions[ri].name;
        let mut files = Vec::new();
        for f in photo_files(name) {
            let p = out.join(&f);
            let bytes = std::fs::read(&p).map_err(io(&p))?;
            files.push(FileRecord {
                file: f,
                hash: fnv64(&bytes),
            });
        }
        tracing::info!(region = %name, share = %spec, "photo mosaicked");
        photos.push(SharePhoto {
            region: name.clone(),
            files,
        });
    }
    let scan_manifest = sd.dir.join(SCAN_MANIFEST);
    let m = ShareManifest {
        format: FORMAT.into(),
        rig_version: env!("CARGO_PKG_VERSION").into(),
        scan: std::fs::canonicalize(&sd.dir).map_err(io(&sd.dir))?,
        scan_manifest_fnv64: fnv64(&std::fs::read(&scan_manifest).map_err(io(&scan_manifest))?),
        tile: spec.index,
        of: spec.count,
        regions: [mine.start, mine.end],
        photos,
    };
    let path = out.join(MANIFEST);
    crate::atomic::write_json(&path, &m).map_err(io(&path))?;
    Ok(m)
}

/// A share's file, read only when it is a regular file of at most `max` bytes (not a device,
/// a pipe or a link to one).
fn read_regular(path: &Path, max: u64) -> Result<Vec<u8>, ShareError> {
    let meta = std::fs::symlink_metadata(path).map_err(io(path))?;
    if !meta.file_type().is_file() || meta.len() > max {
        return Err(ShareError::Refused(format!(
            "{}: not a regular file of at most {} MiB",
            path.display(),
            max >> 20
        )));
    }
    std::fs::read(path).map_err(io(path))
}

/// Largest file of a share read: a photo's TIFF within the rig's TIFF limit, with room.
const MAX_SHARE_FILE: u64 = (crate::digitise::output::MAX_TIFF_BYTES as u64) + (64 << 20);

fn read_manifest(dir: &Path) -> Result<ShareManifest, ShareError> {
    let path = dir.join(MANIFEST);
    if std::fs::symlink_metadata(&path)
        .is_ok_and(|m| !m.file_type().is_file() || m.len() > 64 << 20)
    {
        return Err(ShareError::Refused(format!(
            "{}: not a regular file of at most 64 MiB",
            path.display()
        )));
    }
    let text = std::fs::read_to_string(&path).map_err(|cause| {
        if cause.kind() == std::io::ErrorKind::NotFound {
            ShareError::Refused(format!(
                "{}: no {MANIFEST}: not a share of `rig scan mosaic DIR --tile I/N --out SHARE_DIR`, or it has not finished (run that share again)",
                dir.display()
            ))
        } else {
            ShareError::Io {
                path: path.clone(),
                cause,
            }
        }
    })?;
    let m: ShareManifest = serde_json::from_str(&text).map_err(|e| {
        ShareError::Refused(format!(
            "{}: not a share of `rig scan mosaic --tile` ({e})",
            path.display()
        ))
    })?;
    if m.format != FORMAT {
        return Err(ShareError::Refused(format!(
            "{}: format `{}`, not `{FORMAT}`",
            path.display(),
            m.format
        )));
    }
    Ok(m)
}

/// Checks that `dirs` are shares 1…N of one scan's mosaics, each whole and unchanged, and
/// puts their photos into `into` (by default the scan directory they name), each file
/// atomically; returns the scan directory and the photos' sidecars.
pub fn merge_shares(
    dirs: &[PathBuf],
    into: Option<&Path>,
) -> Result<(PathBuf, Vec<PathBuf>), ShareError> {
    let mut set = Vec::new();
    for d in dirs {
        set.push((d.clone(), read_manifest(d)?));
    }
    let Some((d0, m0)) = set.first().cloned() else {
        return Err(ShareError::Refused("no share directories given".into()));
    };
    for (d, m) in &set {
        if m.scan != m0.scan
            || m.scan_manifest_fnv64 != m0.scan_manifest_fnv64
            || m.rig_version != m0.rig_version
        {
            return Err(ShareError::Refused(format!(
                "{} and {} are shares of different scans or rig versions ({} {} rig {}; {} {} rig {})",
                d0.display(),
                d.display(),
                m0.scan.display(),
                m0.scan_manifest_fnv64,
                m0.rig_version,
                m.scan.display(),
                m.scan_manifest_fnv64,
                m.rig_version
            )));
        }
    }
    let shares: Vec<(&Path, usize, usize)> = set
        .iter()
        .map(|(d, m)| (d.as_path(), m.tile, m.of))
        .collect();
    let order = check_shares(&shares)?;
    let into = into.map_or_else(|| m0.scan.clone(), Path::to_path_buf);
    eprintln!(
        "rig scan merge: {} shares into {}",
        set.len(),
        into.display()
    );
    let mut sd = ScanDir::open(&into, &Reopen::default())?;
    let scan_manifest = into.join(SCAN_MANIFEST);
    let now = fnv64(&std::fs::read(&scan_manifest).map_err(io(&scan_manifest))?);
    if now != m0.scan_manifest_fnv64 {
        return Err(ShareError::Refused(format!(
            "{} is not the scan the shares were mosaicked from (or changed since: its manifest's hash is {now}, theirs {}): mosaic the shares again",
            into.display(),
            m0.scan_manifest_fnv64
        )));
    }
    let regions = sd.manifest.plan.regions.clone();
    // Every share whole and as the rig splits, before anything is copied.
    for &k in &order {
        let (d, m) = &set[k];
        let want = TileSpec {
            index: m.tile,
            count: m.of,
        }
        .units(regions.len());
        let names: Vec<&str> = m.photos.iter().map(|p| p.region.as_str()).collect();
        let planned: Vec<&str> = regions[want.clone()]
            .iter()
            .map(|r| r.name.as_str())
            .collect();
        if m.regions != [want.start, want.end] || names != planned {
            return Err(ShareError::Refused(format!(
                "{}: share {}/{} holds photos {names:?}; the scan's share is {planned:?}",
                d.display(),
                m.tile,
                m.of
            )));
        }
        for p in &m.photos {
            let expected = photo_files(&p.region);
            let listed: Vec<&str> = p.files.iter().map(|f| f.file.as_str()).collect();
            if listed != expected.iter().map(String::as_str).collect::<Vec<_>>() {
                return Err(ShareError::Refused(format!(
                    "{}: photo {} lists files {listed:?}",
                    d.display(),
                    p.region
                )));
            }
            for f in &p.files {
                let path = d.join(&f.file);
                let bytes = read_regular(&path, MAX_SHARE_FILE)?;
                if fnv64(&bytes) != f.hash {
                    return Err(ShareError::Refused(format!(
                        "{}: its bytes changed since the share was mosaicked (damaged or cut short): mosaic share {}/{} again",
                        path.display(),
                        m.tile,
                        m.of
                    )));
                }
            }
        }
    }
    let mut sidecars = Vec::new();
    for k in order {
        let (d, m) = &set[k];
        for p in &m.photos {
            for f in &p.files {
                let (from, to) = (d.join(&f.file), into.join(&f.file));
                let bytes = read_regular(&from, MAX_SHARE_FILE)?;
                if fnv64(&bytes) != f.hash {
                    return Err(ShareError::Refused(format!(
                        "{}: changed while the shares were merged",
                        from.display()
                    )));
                }
                crate::atomic::write(&to, &bytes).map_err(io(&to))?;
            }
            let [tiff, _, side] = photo_files(&p.region).map(|f| into.join(f));
            sd.log
                .event(
                    "photo",
                    json!({"region": p.region, "image": relative_to(&sd.dir, &tiff),
                           "sidecar": relative_to(&sd.dir, &side), "share": format!("{}/{}", m.tile, m.of)}),
                )
                .map_err(io(&into))?;
            sidecars.push(side);
        }
    }
    Ok((into, sidecars))
}
