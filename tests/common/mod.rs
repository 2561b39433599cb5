//! Helpers for end-to-end tests: a `rig sim` process on a real pseudo-terminal, `rig stage`
//! invocations, and the simulator's truth file.
#![allow(dead_code)]

pub mod serve;
pub mod waiting;
pub mod webdriver;

use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Whether GDAL's tools (Debian's gdal-bin) are here; with RIG_GDALINFO=1, as `.ci/run` sets
/// after installing them, they must be (the test fails rather than skip its GDAL half).
pub fn gdal_tools() -> bool {
    let required = std::env::var("RIG_GDALINFO").is_ok_and(|v| v == "1");
    match Command::new("gdalinfo").arg("--version").output() {
        Ok(o) if o.status.success() => true,
        r => {
            assert!(!required, "RIG_GDALINFO=1 but gdalinfo cannot run: {r:?}");
            eprintln!("gdalinfo not installed: GDAL half skipped");
            false
        }
    }
}

pub fn rig() -> Command {
    Command::new(env!("CARGO_BIN_EXE_rig"))
}

/// Runs `cmd`, asserting it succeeds (its standard error in the message if not).
pub fn run_ok(cmd: &mut Command) -> Output {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{cmd:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// A quick pixel session of the simulator into `store` (a 3 × 3 grid of 8-frame looks, no
/// measuring mark): what the service's tests need for its calibration panel and interior items.
pub fn quick_pixel_session(store: &Path) {
    run_ok(
        rig()
            .args([
                "calibrate",
                "pixel",
                "--sim",
                "--grid",
                "3",
                "--frames",
                "8",
                "--grid-only",
                "--json",
                "--store",
            ])
            .arg(store),
    );
}

/// `rig sim scene ARGS --out DIR/scene`, asserted to succeed; the scene's directory.
pub fn sim_scene(dir: &Path, args: &[&str]) -> PathBuf {
    let scene = dir.join("scene");
    run_ok(
        rig()
            .args(["sim", "scene"])
            .args(args)
            .arg("--out")
            .arg(&scene),
    );
    scene
}

/// `rig sim scene ARGS --out DIR/scene`, asserted to fail with `want` in its standard error
/// and to have written nothing.
pub fn sim_scene_refused(dir: &Path, args: &[&str], want: &str) {
    let out = dir.join("scene");
    let o = rig()
        .args(["sim", "scene"])
        .args(args)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains(want), "{args:?}: {err}");
    assert!(!out.exists(), "{args:?} wrote {}", out.display());
}

/// `rig dtm PROJECT --json --out OUT`, asserted to succeed; its report.
pub fn dtm_json(project: &Path, out: &Path) -> Value {
    let o = run_ok(
        rig()
            .arg("dtm")
            .arg(project)
            .arg("--json")
            .arg("--out")
            .arg(out),
    );
    serde_json::from_slice(&o.stdout).unwrap()
}

/// `gdaltransform ARGS IMAGE` with `points` on its standard input, one a line; the numbers of
/// each output line (GDAL's own transformer: the independent check of the rig's geometry).
pub fn gdaltransform(args: &[&str], image: &Path, points: &[[f64; 3]]) -> Vec<Vec<f64>> {
    use std::io::Write;
    let mut child = Command::new("gdaltransform")
        .args(args)
        .arg(image)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let input: String = points
        .iter()
        .map(|p| format!("{:.15} {:.15} {:.15}\n", p[0], p[1], p[2]))
        .collect();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(input.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "gdaltransform {args:?} {}: {}",
        image.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| {
            l.split_whitespace()
                .map(|w| {
                    w.parse()
                        .unwrap_or_else(|_| panic!("gdaltransform printed `{l}`"))
                })
                .collect()
        })
        .collect()
}

/// A `rig sim` child process, stopped with SIGTERM on drop.
pub struct SimProcess {
    pub child: Child,
    pub port: PathBuf,
    pub truth: PathBuf,
    pub dir: tempfile::TempDir,
}

impl SimProcess {
    /// A simulator whose clock jumps (`--time-scale 0`).
    pub fn start(dialect: &str, extra: &[&str]) -> SimProcess {
        Self::start_scaled(dialect, "0", extra)
    }

    /// A simulator at `scale` wall seconds per simulated second (1: real time, so that a
    /// motion is still under way when a test interrupts it).
    pub fn start_scaled(dialect: &str, scale: &str, extra: &[&str]) -> SimProcess {
        let dir = tempfile::tempdir().unwrap();
        let truth = dir.path().join("truth.json");
        let link = dir.path().join("stage");
        let mut child = rig()
            .args([
                "sim",
                "--dialect",
                dialect,
                "--time-scale",
                scale,
                "--truth",
            ])
            .arg(&truth)
            .arg("--stage-link")
            .arg(&link)
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("spawn rig sim");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let port = PathBuf::from(line.trim());
        assert!(port.starts_with("/dev/pts"), "rig sim printed {line:?}");
        assert_eq!(
            std::fs::read_link(&link).unwrap(),
            port,
            "--stage-link points at the pty"
        );
        SimProcess {
            child,
            port,
            truth,
            dir,
        }
    }

    /// `rig stage --stage PORT --dialect D ARGS... --json`.
    pub fn stage(&self, dialect: &str, args: &[&str]) -> (i32, Value, String) {
        let out = rig()
            .arg("stage")
            .arg("--stage")
            .arg(&self.port)
            .args(["--dialect", dialect, "--json"])
            .args(args)
            .output()
            .unwrap();
        parse(out)
    }

    pub fn truth(&self) -> Value {
        read_truth(&self.truth)
    }

    /// SIGTERM, wait, and the final truth.
    pub fn stop(mut self) -> Value {
        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
        let deadline = Instant::now() + Duration::from_secs(5);
        loop {
            if let Some(st) = self.child.try_wait().unwrap() {
                assert!(st.success(), "rig sim exited with {st}");
                break;
            }
            assert!(Instant::now() < deadline, "rig sim did not stop on SIGTERM");
            std::thread::sleep(Duration::from_millis(10));
        }
        assert!(
            !self.dir.path().join("stage").exists(),
            "the --stage-link is removed on exit"
        );
        read_truth(&self.truth)
    }
}

impl Drop for SimProcess {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub fn parse(out: Output) -> (i32, Value, String) {
    let code = out.status.code().unwrap_or(-1);
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    let json = serde_json::from_str(stdout.trim()).unwrap_or(Value::Null);
    (code, json, stderr)
}

/// Reads the truth file once the simulator has written a settled state.
pub fn read_truth(path: &Path) -> Value {
    let deadline = Instant::now() + Duration::from_secs(2);
    loop {
        if let Ok(s) = std::fs::read_to_string(path) {
            if let Ok(v) = serde_json::from_str::<Value>(&s) {
                if v["busy"] == Value::Bool(false) || Instant::now() > deadline {
                    return v;
                }
            }
        }
        assert!(
            Instant::now() < deadline + Duration::from_secs(1),
            "no truth file at {}",
            path.display()
        );
        std::thread::sleep(Duration::from_millis(5));
    }
}

pub fn carriage_um(truth: &Value) -> (f64, f64) {
    (
        truth["carriage_um"][0].as_f64().unwrap(),
        truth["carriage_um"][1].as_f64().unwrap(),
    )
}

/// Opens a pseudo-terminal slave for raw, non-blocking reads and writes.
pub fn open_nonblocking(path: &Path) -> std::fs::File {
    use std::os::fd::AsRawFd;
    let f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)
        .unwrap();
    // SAFETY: fcntl on a descriptor this function owns.
    unsafe {
        let fd = f.as_raw_fd();
        libc::fcntl(
            fd,
            libc::F_SETFL,
            libc::fcntl(fd, libc::F_GETFL) | libc::O_NONBLOCK,
        );
    }
    f
}

/// How a hostile input ended.
pub struct Hostile {
    /// The exit code; `None` if a signal ended it (an abort, or our kill after a hang).
    pub code: Option<i32>,
    pub stdout: String,
    pub stderr: String,
}

/// Runs the rig on a hostile input with an address-space limit of `mem_gib` GiB (an attempt to
/// allocate far more is then an abort, not a slow swap) and a wall-clock bound of `secs` (then
/// it is killed). Asserts the properties every hostile case shares: it ended by itself, with an
/// exit code (no abort, no signal), without a panic, within the bound.
pub fn run_hostile(cmd: &mut Command, mem_gib: u64, secs: u64) -> Hostile {
    use std::os::unix::process::CommandExt;
    let limit = mem_gib << 30;
    // SAFETY: setrlimit is async-signal-safe; it only lowers this child's own limit.
    unsafe {
        cmd.pre_exec(move || {
            let r = libc::rlimit {
                rlim_cur: limit,
                rlim_max: limit,
            };
            libc::setrlimit(libc::RLIMIT_AS, &r);
            Ok(())
        });
    }
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Drained as they fill, so a chatty child never blocks on a full pipe.
    let drain = |mut r: Box<dyn std::io::Read + Send>| {
        std::thread::spawn(move || {
            let mut v = Vec::new();
            let _ = r.read_to_end(&mut v);
            String::from_utf8_lossy(&v).to_string()
        })
    };
    let out_t = drain(Box::new(child.stdout.take().unwrap()));
    let err_t = drain(Box::new(child.stderr.take().unwrap()));
    let deadline = Instant::now() + Duration::from_secs(secs);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break Some(s);
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let h = Hostile {
        code: status.and_then(|s| s.code()),
        stdout: out_t.join().unwrap_or_default(),
        stderr: err_t.join().unwrap_or_default(),
    };
    let what = format!("{cmd:?}\nstdout: {}\nstderr: {}", h.stdout, h.stderr);
    assert!(status.is_some(), "hung (killed after {secs} s): {what}");
    assert!(h.code.is_some(), "ended by a signal (abort?): {what}");
    assert!(!h.stderr.contains("panicked"), "panicked: {what}");
    h
}

/// Uniform in [0, 1) from a 64-bit LCG (Knuth's MMIX constants): test noise that is the same
/// on every machine.
pub fn uniform(s: &mut u64) -> f64 {
    *s = s
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (*s >> 11) as f64 / (1u64 << 53) as f64
}

/// A standard normal deviate (Box–Muller) from [`uniform`].
pub fn gauss(s: &mut u64) -> f64 {
    let (u, v) = (uniform(s).max(1e-300), uniform(s));
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}
