//! The scan's checkpoint: the plan and, for every tile taken, its file, a hash of its bytes and
//! where the stage reported it stood. Rewritten atomically after every tile (temporary file,
//! fsync, rename, fsync of the directory), so after a crash it describes exactly the tiles
//! that are safely on disk.

use super::plan::Plan;
use crate::coords::CarriageUm;
use serde::{Deserialize, Serialize};
use std::path::Path;

pub const MANIFEST: &str = "manifest.json";
pub const FORMAT: &str = "rig-scan-manifest/1";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FileRecord {
    /// Relative to the scan directory.
    pub file: String,
    /// FNV-1a 64 of the file's bytes, hex.
    pub hash: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TileRecord {
    pub file: FileRecord,
    /// The position the controller reported after the move (the mosaic uses this one).
    pub stage_um: CarriageUm,
    pub dropped_frames: u64,
    pub seconds: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    /// Hash of the script's text: a resume refuses a script that changed.
    pub script_hash: String,
    /// The script as it was named when the scan began.
    pub script: std::path::PathBuf,
    pub plan: Plan,
    pub flat: Option<FileRecord>,
    /// One entry per planned tile, `None` until it is safely on disk.
    pub tiles: Vec<Option<TileRecord>>,
    pub complete: bool,
}

pub use crate::atomic::fnv64;

pub use crate::atomic::write as write_atomic;

impl Manifest {
    pub fn new(script: &Path, script_text: &str, plan: Plan) -> Manifest {
        Manifest {
            format: FORMAT.into(),
            script_hash: fnv64(script_text.as_bytes()),
            script: script.to_path_buf(),
            tiles: vec![None; plan.tiles.len()],
            plan,
            flat: None,
            complete: false,
        }
    }

    pub fn load(dir: &Path) -> std::io::Result<Manifest> {
        let p = dir.join(MANIFEST);
        let text = std::fs::read_to_string(&p)?;
        let m: Manifest = serde_json::from_str(&text).map_err(|e| {
            std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("{}: {e}", p.display()),
            )
        })?;
        if m.format != FORMAT || m.tiles.len() != m.plan.tiles.len() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("{}: not a scan manifest of this rig", p.display()),
            ));
        }
        Ok(m)
    }

    pub fn save(&self, dir: &Path) -> std::io::Result<()> {
        write_atomic(&dir.join(MANIFEST), &serde_json::to_vec_pretty(self)?)
    }

    pub fn done(&self) -> usize {
        self.tiles.iter().filter(|t| t.is_some()).count()
    }
}

/// Whether the file a record names is there with the bytes it had.
pub fn intact(dir: &Path, r: &FileRecord) -> bool {
    std::fs::read(dir.join(&r.file)).is_ok_and(|b| fnv64(&b) == r.hash)
}
