//! The README's two commands (`cargo run --release -- demo`, `cargo test --workspace --release`)
//! must share one compile of every crate they have in common: a crate whose features differ
//! between the two resolutions (a dev-dependency turning one on) is compiled twice, and with it
//! everything above it — on two cores, the whole workspace a second time. Cargo resolves the
//! features; this compares its two answers.

use std::collections::BTreeMap;
use std::process::Command;

/// Each package of `cargo tree`'s answer with its features; a package resolved twice with
/// different features (for the host and the target) is itself a second compile.
fn features(args: &[&str]) -> BTreeMap<String, String> {
    let o = Command::new(env!("CARGO"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(["tree", "--offline", "--prefix", "none", "-f", "{p}|{f}"])
        .args(args)
        .output()
        .expect("cargo tree runs");
    assert!(
        o.status.success(),
        "cargo tree {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let mut m = BTreeMap::new();
    for l in String::from_utf8_lossy(&o.stdout).lines() {
        let Some((p, f)) = l.split_once('|') else {
            continue;
        };
        let (p, f) = (
            p.replace(" (*)", "").trim().to_string(),
            f.replace(" (*)", "").trim().to_string(),
        );
        if let Some(other) = m.insert(p.clone(), f.clone()) {
            assert_eq!(
                other, f,
                "{p} is resolved twice with different features ({args:?})"
            );
        }
    }
    m
}

#[test]
fn the_demo_and_the_tests_resolve_the_same_features() {
    let run = features(&["-p", "rig", "-e", "normal,build"]);
    let test = features(&["--workspace", "-e", "normal,build,dev"]);
    assert!(run.len() > 50, "{} packages", run.len());
    let differ: Vec<String> = run
        .iter()
        .filter_map(|(p, f)| {
            let t = test.get(p)?;
            (t != f).then(|| format!("{p}: run [{f}], test [{t}]"))
        })
        .collect();
    assert!(
        differ.is_empty(),
        "compiled twice (turn the test build's features on in Cargo.toml's pinned entries):\n{}",
        differ.join("\n")
    );
}
