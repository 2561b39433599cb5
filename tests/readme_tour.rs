//! The README's tour runs as written: its shell block (after `<!-- tour -->`) is run by bash
//! with `set -e` in an empty directory, with the rig under test on the PATH, against the
//! simulator it starts in the background. Every command must succeed, the stage must stay
//! homed between commands, and the files the tour names must be there at the end.

use std::io::Read;
use std::os::unix::process::CommandExt;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The block after the marker, as written.
fn tour() -> String {
    let readme = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md"))
        .expect("README.md");
    let after = readme
        .split_once("<!-- tour -->\n```sh\n")
        .expect("the README marks its tour with <!-- tour --> before a ```sh block")
        .1;
    after
        .split_once("\n```")
        .expect("the tour's block ends")
        .0
        .to_string()
}

#[test]
fn the_readme_tour_runs_as_written() {
    let d = tempfile::tempdir().unwrap();
    // The directory stands for the checkout after the set-up's build: the rig under test at
    // target/release/rig, which the tour's first line puts on the PATH (the test does not).
    let release = d.path().join("target/release");
    std::fs::create_dir_all(&release).unwrap();
    std::os::unix::fs::symlink(env!("CARGO_BIN_EXE_rig"), release.join("rig")).unwrap();
    let path = std::env::var("PATH").unwrap_or_default();
    assert!(
        !path
            .split(':')
            .any(|p| std::path::Path::new(p).join("rig").exists()),
        "a rig on the PATH already would hide the tour's own PATH line"
    );
    let script = format!("set -e\n{}\n", tour());
    let mut child = Command::new("bash")
        .arg("-c")
        .arg(&script)
        .current_dir(d.path())
        .env("PATH", path)
        .env_remove("RIG_STAGE")
        .env_remove("RIG_DIALECT")
        .env_remove("RIG_CAMERA")
        .env("HOME", d.path())
        .env("XDG_CONFIG_HOME", d.path().join("config"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        // Its own process group, so that the simulators it starts go with it.
        .process_group(0)
        .spawn()
        .unwrap();
    let pgid = child.id() as i32;
    // Both pipes drained as the tour runs, so that no amount of output blocks it.
    let drain = |mut r: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut t = String::new();
            let _ = r.read_to_string(&mut t);
            t
        })
    };
    let out_t = drain(Box::new(child.stdout.take().unwrap()));
    let err_t = drain(Box::new(child.stderr.take().unwrap()));
    let deadline = Instant::now() + Duration::from_secs(400);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break Some(s);
        }
        if Instant::now() > deadline {
            break None;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    // Whatever is left of the group (a simulator after a failure) is stopped.
    unsafe {
        libc::kill(-pgid, libc::SIGTERM);
    }
    let (out, err) = (out_t.join().unwrap(), err_t.join().unwrap());
    let status = status.unwrap_or_else(|| panic!("the tour ran over 400 s\n{out}\n{err}"));
    assert!(
        status.success(),
        "the tour failed ({status})\n--- stdout\n{out}\n--- stderr\n{err}"
    );
    // `rig stage status --json`, after `home` in an earlier command: still homed.
    let status_line = out
        .lines()
        .find(|l| l.starts_with('{') && l.contains("\"homed\""))
        .unwrap_or_else(|| panic!("no status JSON in\n{out}"));
    let v: serde_json::Value = serde_json::from_str(status_line).unwrap();
    assert_eq!(v["homed"], true, "{status_line}");
    let t = d.path().join("tour");
    for f in [
        "plate.tiff",
        "plate.json",
        "plan.png",
        "scans/photo-1/centre.tiff",
        "scans/photo-1/centre.json",
        "dtm/dem.tif",
        "dtm/report.html",
    ] {
        assert!(t.join(f).is_file(), "{f} is missing after the tour\n{out}");
    }
    let sessions: Vec<String> = std::fs::read_dir(t.join("rig-sessions"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        sessions.iter().any(|s| s.ends_with("-pixel"))
            && sessions.iter().any(|s| s.ends_with("-interior")),
        "{sessions:?}"
    );
}
