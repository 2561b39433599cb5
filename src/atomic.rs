//! The one way the rig saves a file: write a temporary file beside the target, fsync it, rename
//! it over the target, fsync the directory. A crash, a kill or a full disk leaves either the old
//! file or the new one under the final name, never half of one; a failed write removes its
//! temporary file and reports the first error.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// The temporary name for `path`: `NAME.part` in the same directory (a rename within one
/// directory is atomic on POSIX file systems).
fn part_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".part");
    path.with_file_name(name)
}

/// Writes what `fill` writes into a buffered file, atomically at `path`. The writer seeks, so
/// encoders that patch offsets (TIFF) can write through it.
pub fn write_with(
    path: &Path,
    fill: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let tmp = part_path(path);
    let r = (|| {
        let mut w = BufWriter::new(File::create(&tmp)?);
        fill(&mut w)?;
        w.flush()?;
        let f = w.into_inner().map_err(|e| e.into_error())?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = r {
        let _ = std::fs::remove_file(&tmp);
        return Err(std::io::Error::new(
            e.kind(),
            format!("writing {}: {e}", path.display()),
        ));
    }
    // The rename itself must reach the disk too.
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// FNV-1a, 64 bits, as hex: enough to notice a damaged or replaced file (a scan's tiles, a
/// tiled run's project), no dependency.
pub fn fnv64(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// The files in `dir` (none when it does not exist) that are neither `ours` nor the temporary
/// `NAME.part` of one of ours (a write that was cut short), sorted: what a command must not
/// write over when it is given an output directory.
pub fn foreign_files(dir: &Path, ours: impl Fn(&str) -> bool) -> std::io::Result<Vec<String>> {
    if !dir.exists() {
        return Ok(Vec::new());
    }
    let mut foreign = Vec::new();
    for e in std::fs::read_dir(dir)? {
        let name = e?.file_name().to_string_lossy().into_owned();
        if !ours(name.strip_suffix(".part").unwrap_or(&name)) {
            foreign.push(name);
        }
    }
    foreign.sort();
    Ok(foreign)
}

/// Writes `bytes` to `path` atomically.
pub fn write(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_with(path, |w| w.write_all(bytes))
}

/// Writes `value` as pretty JSON (with a final newline) to `path` atomically.
pub fn write_json<T: serde::Serialize + ?Sized>(path: &Path, value: &T) -> std::io::Result<()> {
    write_with(path, |w| {
        serde_json::to_writer_pretty(&mut *w, value)?;
        w.write_all(b"\n")
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn fnv_matches_the_published_vectors() {
        assert_eq!(super::fnv64(b""), "cbf29ce484222325");
        assert_eq!(super::fnv64(b"a"), "af63dc4c8601ec8c");
        assert_eq!(super::fnv64(b"foobar"), "85944171f73967e8");
    }

    #[test]
    fn replaces_whole_and_leaves_no_part_file() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("a.json");
        super::write(&p, b"one").unwrap();
        super::write(&p, b"two").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 1);
    }

    #[test]
    fn a_failed_fill_keeps_the_old_file() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("a.bin");
        super::write(&p, b"old").unwrap();
        let e = super::write_with(&p, |w| {
            use std::io::Write;
            w.write_all(b"half")?;
            Err(std::io::Error::other("disk full"))
        })
        .unwrap_err();
        assert!(e.to_string().contains("disk full"), "{e}");
        assert!(e.to_string().contains("a.bin"), "{e}");
        assert_eq!(std::fs::read(&p).unwrap(), b"old");
        assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 1);
    }
}
