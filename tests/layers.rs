//! The two halves of the rig, enforced on the sources: the core (images, sensor geometry, least
//! squares, mapping functions, DEM grids, matchers) imports nothing from the hardware side
//! (stage, camera, digitise, targets, calibrate, scan, the service, the CLI, the simulator), so that it takes
//! anyone's photos and orientations as plain data; and the simulator never imports the host.

use std::path::{Path, PathBuf};

/// The core: these files and folders under `src/`.
const CORE: [&str; 12] = [
    "relative.rs",
    "orientation",
    "geometry",
    "hac.rs",
    "simd.rs",
    "seconds.rs",
    "picture.rs",
    "matching",
    "image",
    "correlation.rs",
    "coords.rs",
    "atomic.rs",
];
/// What the core may not name: modules of the hardware side, and the simulator's crate.
const HARDWARE: [&str; 10] = [
    "crate::stage",
    "crate::service",
    "crate::camera",
    "crate::digitise",
    "crate::targets",
    "crate::calibrate",
    "crate::scan",
    "crate::cli",
    "crate::sim_scene",
    "rig_sim",
];

fn rust_files(p: &Path, out: &mut Vec<PathBuf>) {
    if p.is_dir() {
        for e in std::fs::read_dir(p).unwrap() {
            rust_files(&e.unwrap().path(), out);
        }
    } else if p.extension().is_some_and(|e| e == "rs") {
        out.push(p.to_path_buf());
    }
}

/// Every line of `text` (comments left out) that names one of `forbidden` as a path: `use
/// a::b`, `a::b::c(…)`, or `a::{…}`. A word that merely contains one (`my_crate::stage_x`)
/// does not count.
fn offences(text: &str, forbidden: &[&str]) -> Vec<(usize, String)> {
    let mut v = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let code = line.split("//").next().unwrap_or("");
        for f in forbidden {
            let mut at = 0;
            while let Some(k) = code[at..].find(f) {
                let start = at + k;
                let end = start + f.len();
                let before = code[..start].chars().next_back();
                let after = code[end..].chars().next();
                let word_start =
                    !before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':');
                let word_end = !after.is_some_and(|c| c.is_alphanumeric() || c == '_');
                if word_start && word_end {
                    v.push((i + 1, line.trim().to_string()));
                }
                at = end;
            }
        }
    }
    v
}

#[test]
fn the_checker_sees_a_hardware_import() {
    let bad =
        "use crate::scan::PhotoGrid;\nfn f() { crate::stage::open(); }\nuse rig_sim::World;\n";
    assert_eq!(offences(bad, &HARDWARE).len(), 3);
    let fine = "use crate::scanner::X; // crate::scan::Y in a comment\nuse crate::geometry::PhotoGrid;\nlet my_rig_sim = 1;";
    assert!(
        offences(fine, &HARDWARE).is_empty(),
        "{:?}",
        offences(fine, &HARDWARE)
    );
}

#[test]
fn the_core_imports_nothing_from_the_hardware_side() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    for c in CORE {
        let p = src.join(c);
        assert!(p.exists(), "core part {} is missing", p.display());
        rust_files(&p, &mut files);
    }
    assert!(files.len() >= 10, "{files:?}");
    let mut found = Vec::new();
    for f in &files {
        for (line, text) in offences(&std::fs::read_to_string(f).unwrap(), &HARDWARE) {
            found.push(format!("{}:{line}: {text}", f.display()));
        }
    }
    assert!(
        found.is_empty(),
        "the core imports the hardware side:\n{}",
        found.join("\n")
    );
}

#[test]
fn the_simulator_and_the_protocol_never_import_the_host() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for krate in ["sim", "firmware-protocol"] {
        let manifest = std::fs::read_to_string(root.join(krate).join("Cargo.toml")).unwrap();
        let deps = manifest.lines().any(|l| {
            let l = l.trim_start();
            l.starts_with("rig =") || l.starts_with("rig=") || l.starts_with("[dependencies.rig]")
        });
        assert!(!deps, "{krate}/Cargo.toml depends on the rig");
        let mut files = Vec::new();
        rust_files(&root.join(krate).join("src"), &mut files);
        for f in &files {
            let o = offences(&std::fs::read_to_string(f).unwrap(), &["rig::"]);
            assert!(o.is_empty(), "{} imports the host: {o:?}", f.display());
        }
    }
}
