//! Paths a record names, relative to the record's own directory: a scan folder moved, copied
//! to another machine or archived still names its sessions, certificate and script
//! (`../sessions/interior-photo-1`), an oriented project its photos, and neither holds a trace
//! of where it was first written.

use std::path::{Component, Path, PathBuf};

/// `target` as seen from the directory `base`: both made absolute (against the working
/// directory) and their symbolic links resolved where they exist, then the shared leading
/// components dropped and one `..` put for each of `base`'s others. `target` unchanged when
/// the two share no root (another drive) or a path cannot be made absolute.
pub fn relative_to(base: &Path, target: &Path) -> PathBuf {
    let resolve = |p: &Path| {
        p.canonicalize()
            .or_else(|_| std::path::absolute(p))
            .map(|p| normalise(&p))
    };
    let (Ok(b), Ok(t)) = (resolve(base), resolve(target)) else {
        return target.to_path_buf();
    };
    let (bc, tc): (Vec<Component>, Vec<Component>) =
        (b.components().collect(), t.components().collect());
    if bc.first() != tc.first() {
        return target.to_path_buf();
    }
    let common = bc.iter().zip(&tc).take_while(|(x, y)| x == y).count();
    let mut out = PathBuf::new();
    for _ in common..bc.len() {
        out.push("..");
    }
    for c in &tc[common..] {
        out.push(c.as_os_str());
    }
    if out.as_os_str().is_empty() {
        out.push(".");
    }
    out
}

/// `p` with `.` dropped and each `..` taking back the component before it (lexically: for a
/// path that does not exist yet, whose links cannot be resolved).
fn normalise(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                if !out.pop() {
                    out.push("..");
                }
            }
            c => out.push(c.as_os_str()),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Paths that do not exist are taken lexically: siblings, children, the same directory,
    /// `.` and `..` inside them.
    #[test]
    fn lexical_cases() {
        let r = |b: &str, t: &str| relative_to(Path::new(b), Path::new(t));
        assert_eq!(
            r("/nowhere/a/scan", "/nowhere/a/sessions/i1"),
            Path::new("../sessions/i1")
        );
        assert_eq!(
            r("/nowhere/a", "/nowhere/a/s/x.toml"),
            Path::new("s/x.toml")
        );
        assert_eq!(r("/nowhere/a", "/nowhere/a"), Path::new("."));
        assert_eq!(
            r("/nowhere/a/./b/../c", "/nowhere/a/d.toml"),
            Path::new("../d.toml")
        );
        assert_eq!(
            r("/nowhere/x/y", "/elsewhere/z"),
            Path::new("../../../elsewhere/z")
        );
    }

    /// Existing directories through a symbolic link: the link resolved, so the relative path
    /// leads from the real directory to the real target, and joined to the base it names the
    /// target's file.
    #[test]
    fn existing_paths_resolve_links() {
        let tmp = tempfile::tempdir().unwrap();
        let real = tmp.path().join("real");
        std::fs::create_dir_all(real.join("scan")).unwrap();
        std::fs::create_dir_all(real.join("sessions")).unwrap();
        std::fs::write(real.join("sessions/cert.toml"), "x").unwrap();
        let link = tmp.path().join("link");
        std::os::unix::fs::symlink(&real, &link).unwrap();
        let rel = relative_to(&link.join("scan"), &real.join("sessions/cert.toml"));
        assert_eq!(rel, Path::new("../sessions/cert.toml"));
        assert_eq!(
            std::fs::read_to_string(real.join("scan").join(&rel)).unwrap(),
            "x"
        );
    }
}
