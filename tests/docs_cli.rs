//! What a new user looks at first: `rig --version` names the features built, completions and
//! the manual come from the parser's own definitions (and a shell accepts the completions),
//! and every command's help ends with the one exit-code table.

mod common;

use common::rig;

fn stdout(args: &[&str]) -> String {
    let o = rig().args(args).output().unwrap();
    assert!(
        o.status.success(),
        "rig {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8(o.stdout).unwrap()
}

#[test]
fn version_completions_manual_and_the_exit_table() {
    let v = stdout(&["--version"]);
    assert!(v.starts_with("rig ") && v.contains("features:"), "{v}");
    assert_eq!(v.contains("v4l2)"), cfg!(feature = "v4l2"), "{v}");

    let bash = stdout(&["completions", "bash"]);
    assert!(bash.contains("_rig()") && bash.contains("dtm") && bash.contains("--sim-seed"));
    // bash itself reads the script without a syntax error (when bash is here).
    let d = tempfile::tempdir().unwrap();
    let f = d.path().join("rig.bash");
    std::fs::write(&f, &bash).unwrap();
    if let Ok(o) = std::process::Command::new("bash")
        .arg("-n")
        .arg(&f)
        .output()
    {
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    for shell in ["zsh", "fish", "elvish", "powershell"] {
        assert!(stdout(&["completions", shell]).contains("rig"), "{shell}");
    }

    let man = stdout(&["man"]);
    assert!(man.contains(".TH rig 1") && man.contains("dtm"), "{man}");
    let pages = d.path().join("man");
    stdout(&["man", "--out", pages.to_str().unwrap()]);
    for page in ["rig.1", "rig-dtm.1", "rig-stage-home.1", "rig-scan-run.1"] {
        let t = std::fs::read_to_string(pages.join(page)).unwrap();
        assert!(t.contains(".TH"), "{page}");
    }

    // -v/-q and RUST_LOG choose the log on standard error; stdout keeps the answer.
    let log = |env: Option<&str>, flags: &[&str]| {
        let mut c = rig();
        c.env_remove("RUST_LOG");
        if let Some(v) = env {
            c.env("RUST_LOG", v);
        }
        let o = c
            .args(flags)
            .args([
                "stage",
                "--sim",
                "--sim-time-scale",
                "0",
                "move",
                "100",
                "100",
            ])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stderr).to_string()
    };
    assert!(!log(None, &[]).contains("DEBUG"));
    assert!(log(None, &["-vv"]).contains("DEBUG rig::stage::driver: move"));
    assert!(log(Some("rig::stage=debug"), &[]).contains("DEBUG"));
    assert!(!log(None, &["-q"]).contains("WARN"));

    // A reader that goes away (`| head`) ends rig quietly, never with a panic.
    for args in [
        &["--help"][..],
        &["stage", "--sim", "--sim-time-scale", "0", "info"],
    ] {
        let mut child = rig()
            .args(args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take());
        let o = child.wait_with_output().unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!e.contains("panicked"), "rig {args:?}: {e}");
    }

    // One table, shown by every command's help, with the codes the commands use.
    let top = stdout(&["--help"]);
    for cmd in ["stage", "camera", "calibrate", "scan", "dtm", "demo"] {
        let h = stdout(&[cmd, "--help"]);
        assert!(
            h.contains(rig::exit::TABLE),
            "rig {cmd} --help lacks the table"
        );
    }
    assert!(top.contains(rig::exit::TABLE));
    // A bad value is bad usage everywhere.
    for args in [
        &["completions", "nosh"][..],
        &["stage", "--sim", "move", "x", "1"],
        &["dtm"],
        &["scan", "--sim-seed", "x", "plan", "s.toml"],
        // A file named for a format it would not hold.
        &["camera", "--sim", "grab", "-o", "frame.png"],
    ] {
        let o = rig().args(args).output().unwrap();
        assert_eq!(o.status.code(), Some(rig::exit::USAGE), "rig {args:?}");
    }
}

/// A usage error exits 2 whoever rejects it: the parser (a word where a number belongs) or the
/// command's own check (a number out of range, a flag this case needs), with the flag named,
/// and nothing written.
#[test]
fn every_usage_error_exits_2() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out");
    let o = out.to_str().unwrap();
    let tiff = d.path().join("out.tiff");
    let t = tiff.to_str().unwrap();
    for (args, flag) in [
        // The parser's.
        (
            vec!["camera", "--sim", "grab", "--exposure", "20ms", "-o", t],
            "--exposure",
        ),
        (vec!["stage", "--sim", "move", "120mm", "80"], "120mm"),
        // Our own checks'.
        (
            vec!["camera", "--sim", "grab", "--frames", "0", "-o", t],
            "--frames",
        ),
        (
            vec!["camera", "--sim", "grab", "--stretch", "50,10", "-o", t],
            "--stretch",
        ),
        (
            vec!["camera", "--sim", "grab", "--at", "1", "-o", t],
            "--at",
        ),
        (
            vec!["stage", "--sim", "--sim-faults", "drop=2", "status"],
            "--sim-faults",
        ),
        (
            vec!["stage", "--sim", "--sim-faults", "nonsense", "status"],
            "--sim-faults",
        ),
        (
            vec!["calibrate", "pixel", "--sim", "--frames", "0", "--out", o],
            "--frames",
        ),
        (vec!["calibrate", "pixel", "--out", o], "--plate-cert"),
        (
            vec!["sim", "scene", "--noise-dn=-5", "--out", o],
            "--noise-dn",
        ),
        (vec!["sim", "scene", "--area", "1,2", "--out", o], "--area"),
        (
            vec!["sim", "scene", "--gains", "1,x", "--out", o],
            "--gains",
        ),
    ] {
        let r = rig().args(&args).output().unwrap();
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(flag), "{args:?}: {err}");
        assert!(!out.exists() && !tiff.exists(), "{args:?} wrote");
    }
}
