//! The operator's settings: flag > environment > ./rig.toml > the user's rig.toml > default,
//! as `rig config show` reports and as the commands use them (a port named only in a file is
//! the one the stage command tries to open); bad files and values are refused by name.

mod common;

use common::rig;
use std::path::Path;

/// `rig ARGS` in `dir` with a fresh home and config directory and no RIG_ variables but `env`.
fn run(dir: &Path, home: &Path, env: &[(&str, &str)], args: &[&str]) -> std::process::Output {
    let mut c = rig();
    c.current_dir(dir)
        .env("HOME", home)
        .env("XDG_CONFIG_HOME", home.join("config"))
        .env_remove("RIG_STAGE")
        .env_remove("RIG_DIALECT")
        .env_remove("RIG_CAMERA");
    for (k, v) in env {
        c.env(k, v);
    }
    c.args(args).output().unwrap()
}

fn show(dir: &Path, home: &Path, env: &[(&str, &str)], flags: &[&str]) -> serde_json::Value {
    let mut args = vec!["config"];
    args.extend_from_slice(flags);
    args.extend(["show", "--json"]);
    let o = run(dir, home, env, &args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

#[test]
fn flag_over_environment_over_file_over_default() {
    let d = tempfile::tempdir().unwrap();
    let (work, home) = (d.path().join("work"), d.path().join("home"));
    std::fs::create_dir_all(&work).unwrap();
    std::fs::create_dir_all(home.join("config/rig")).unwrap();
    // Nothing anywhere: the default dialect, no stage, no camera.
    let v = show(&work, &home, &[], &[]);
    assert_eq!(v["dialect"]["value"], "native");
    assert_eq!(v["dialect"]["source"], "default");
    assert!(v["stage"]["value"].is_null() && v["camera"]["value"].is_null());
    // The user's file.
    std::fs::write(
        home.join("config/rig/rig.toml"),
        "stage = \"/dev/user-port\"\ndialect = \"grbl\"\ncamera = \"sim:/tmp/user-cam\"\n",
    )
    .unwrap();
    let v = show(&work, &home, &[], &[]);
    assert_eq!(v["stage"]["value"], "/dev/user-port");
    assert_eq!(v["dialect"]["value"], "grbl");
    assert!(v["stage"]["source"]["file"]
        .as_str()
        .unwrap()
        .ends_with("rig/rig.toml"));
    // ./rig.toml wins over the user's file (the whole file: its missing keys are not taken
    // from the other).
    std::fs::write(work.join("rig.toml"), "stage = \"/dev/local-port\"\n").unwrap();
    let v = show(&work, &home, &[], &[]);
    assert_eq!(v["stage"]["value"], "/dev/local-port");
    assert_eq!(v["dialect"]["source"], "default");
    // The environment over the file, the flag over the environment.
    let env = [("RIG_STAGE", "/dev/env-port"), ("RIG_DIALECT", "grbl")];
    let v = show(&work, &home, &env, &[]);
    assert_eq!(v["stage"]["value"], "/dev/env-port");
    assert_eq!(v["stage"]["source"]["env"], "RIG_STAGE");
    assert_eq!(v["dialect"]["value"], "grbl");
    let v = show(
        &work,
        &home,
        &env,
        &["--stage", "/dev/flag-port", "--dialect", "native"],
    );
    assert_eq!(v["stage"]["value"], "/dev/flag-port");
    assert_eq!(v["stage"]["source"], "flag");
    assert_eq!(v["dialect"]["value"], "native");

    // The commands use them: the port from the file is the one `rig stage` tries to open.
    let o = run(&work, &home, &[], &["stage", "status"]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(rig::exit::PORT), "{e}");
    assert!(e.contains("/dev/local-port"), "{e}");
    let o = run(&work, &home, &env, &["stage", "status"]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("/dev/env-port"));
    // --sim ignores a configured port (and keeps working).
    let o = run(
        &work,
        &home,
        &env,
        &[
            "stage",
            "--sim",
            "--sim-time-scale",
            "0",
            "status",
            "--json",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    // Bad values are refused by name, with the file or variable.
    std::fs::write(work.join("rig.toml"), "stages = \"/dev/x\"\n").unwrap();
    let o = run(&work, &home, &[], &["config", "show"]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(rig::exit::OTHER));
    assert!(e.contains("rig.toml") && e.contains("stages"), "{e}");
    std::fs::write(work.join("rig.toml"), "dialect = \"marlin\"\n").unwrap();
    let e =
        String::from_utf8_lossy(&run(&work, &home, &[], &["config", "show"]).stderr).to_string();
    assert!(
        e.contains("rig.toml") && e.contains("marlin") && e.contains("native or grbl"),
        "{e}"
    );
    std::fs::remove_file(work.join("rig.toml")).unwrap();
    let o = run(&work, &home, &[("RIG_DIALECT", "x")], &["config", "show"]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("RIG_DIALECT"));
}
