//! Progress on a terminal and not elsewhere: a calibration drive run with its standard error on
//! a pseudo-terminal draws a bar with the count, the rate and the time left; with --json, or
//! with standard error in a pipe, no bar is drawn.

mod common;

use common::rig;
use std::io::Read;
use std::os::fd::{FromRawFd, OwnedFd};
use std::process::Stdio;

/// Runs `rig args` with standard error on a new pseudo-terminal; returns what it drew there.
fn on_a_terminal(args: &[&str], dir: &std::path::Path) -> String {
    let (mut master, mut slave) = (0, 0);
    let r = unsafe {
        libc::openpty(
            &mut master,
            &mut slave,
            std::ptr::null_mut(),
            std::ptr::null(),
            std::ptr::null(),
        )
    };
    assert_eq!(r, 0, "openpty");
    let (master, slave) = unsafe { (OwnedFd::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
    let mut child = rig()
        .args(args)
        .current_dir(dir)
        .stdout(Stdio::null())
        .stderr(Stdio::from(slave))
        .spawn()
        .unwrap();
    let mut reader = std::fs::File::from(master);
    let drain = std::thread::spawn(move || {
        let mut all = Vec::new();
        let mut buf = [0u8; 4096];
        // EIO once the child has closed its side.
        while let Ok(n) = reader.read(&mut buf) {
            if n == 0 {
                break;
            }
            all.extend_from_slice(&buf[..n]);
        }
        String::from_utf8_lossy(&all).into_owned()
    });
    let st = child.wait().unwrap();
    assert!(st.success(), "rig {args:?}: {st}");
    drain.join().unwrap()
}

#[test]
fn calibration_drives_show_a_bar_on_a_terminal_only() {
    let d = tempfile::tempdir().unwrap();
    let args = [
        "calibrate",
        "pixel",
        "--sim",
        "--grid",
        "3",
        "--frames",
        "2",
        "--store",
        "s",
    ];
    let t = on_a_terminal(&args, d.path());
    assert!(t.contains("/9 (") && t.contains(" left)"), "{t}");
    assert!(t.contains("grid 9/9") && t.contains("cross 9 (9/9)"), "{t}");
    let mut json = args.to_vec();
    json.push("--json");
    let t = on_a_terminal(&json, d.path());
    assert!(!t.contains(" left)"), "a bar with --json:\n{t}");
    // In a pipe: one plain line per step, no bar.
    let o = rig().args(args).current_dir(d.path()).output().unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success());
    assert!(
        e.lines()
            .any(|l| l == "grid 1/9: cross 5 toward pixel (48, 48)"),
        "{e}"
    );
    assert!(!e.contains(" left)") && !e.contains('\r'), "{e}");
}
