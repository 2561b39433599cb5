//! Scripted scanning end to end on the simulator: the scanned photos against the film's true
//! picture in photo coordinates, kill -9 and Ctrl-C with resume against an uninterrupted run,
//! bad scripts, and a plan refused at the soft limits.

mod common;

use common::rig;
use rig::coords::PixelXY;
use rig::scan::ScannedPhoto;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

const SEED: &str = "5";

fn ok(cmd: &mut Command) -> Output {
    let out = cmd.output().expect("run rig");
    assert!(
        out.status.success(),
        "{cmd:?} failed: {}\n{}",
        String::from_utf8_lossy(&out.stderr),
        String::from_utf8_lossy(&out.stdout)
    );
    out
}

/// A pixel session and an interior session for photos 1 and 2 of the block, made once for
/// the whole file: (store, interior session of photo 1, of photo 2).
fn calibrated() -> &'static (PathBuf, PathBuf, PathBuf) {
    static CAL: OnceLock<(tempfile::TempDir, (PathBuf, PathBuf, PathBuf))> = OnceLock::new();
    &CAL.get_or_init(|| {
        let d = tempfile::tempdir().unwrap();
        let store = d.path().join("sessions");
        let s = store.to_str().unwrap();
        ok(rig().args([
            "calibrate",
            "pixel",
            "--sim",
            "--sim-seed",
            SEED,
            "--grid",
            "3",
            "--frames",
            "8",
            "--grid-only",
            "--store",
            s,
        ]));
        let mut interior = Vec::new();
        for photo in ["1", "2"] {
            let out = d.path().join(format!("interior-{photo}"));
            ok(rig()
                .args([
                    "calibrate",
                    "interior",
                    "--sim",
                    "--sim-seed",
                    SEED,
                    "--sim-photo",
                    photo,
                    "--frames",
                    "8",
                    "--store",
                    s,
                    "--out",
                ])
                .arg(&out));
            interior.push(out);
        }
        let v = (store, interior[0].clone(), interior[1].clone());
        (d, v)
    })
    .1
}

fn script(dir: &Path, interior: &Path, regions: &str, out: &str) -> PathBuf {
    let p = dir.join("scan.toml");
    std::fs::write(
        &p,
        format!(
            r#"# a test scan
[film]
name = "test film"
interior_session = "{}"

[output]
dir = "{out}"
resolution_um = 25.0

[capture]
frames = 8
overlap = 0.2
settle_ms = 0

{regions}"#,
            interior.display()
        ),
    )
    .unwrap();
    p
}

/// The film's true picture, as the simulator renders it, for photo `photo`.
fn truth_film(photo: u32) -> rig_sim::film::Film {
    let w = rig_sim::World::new(&rig_sim::SimConfig {
        seed: SEED.parse().unwrap(),
        film: true,
        photo,
        ..Default::default()
    });
    w.film.clone().expect("a film")
}

/// The true picture over the output pixel (c, r) of `grid` shifted by `d` (mm): the mean of
/// 4×4 samples over the pixel.
fn truth_patch(
    film: &rig_sim::film::Film,
    grid: &rig::scan::PhotoGrid,
    c0: usize,
    r0: usize,
    n: usize,
    d: [f64; 2],
) -> Vec<f64> {
    let mut v = Vec::with_capacity(n * n);
    for r in r0..r0 + n {
        for c in c0..c0 + n {
            let mut s = 0.0;
            for j in 0..4 {
                for i in 0..4 {
                    let p = grid.photo(PixelXY::new(
                        c as f64 + (i as f64 + 0.5) / 4.0,
                        r as f64 + (j as f64 + 0.5) / 4.0,
                    ));
                    s += film.picture(p.x + d[0], p.y + d[1]);
                }
            }
            v.push(s / 16.0);
        }
    }
    v
}

/// Where the mosaic's patch really lies on the film: the shift d (mm) that makes
/// `a + b·truth(x + d)` fit the patch best (Gauss–Newton on shift, gain and offset).
fn measured_shift(
    film: &rig_sim::film::Film,
    grid: &rig::scan::PhotoGrid,
    img: &[u16],
    c0: usize,
    r0: usize,
    n: usize,
) -> [f64; 2] {
    let m: Vec<f64> = (r0..r0 + n)
        .flat_map(|r| (c0..c0 + n).map(move |c| (r, c)))
        .map(|(r, c)| img[r * grid.width + c] as f64)
        .collect();
    let mut d = [0.0, 0.0];
    let h = 0.2 * grid.step_mm;
    for _ in 0..6 {
        let t = truth_patch(film, grid, c0, r0, n, d);
        let tx = {
            let p = truth_patch(film, grid, c0, r0, n, [d[0] + h, d[1]]);
            let q = truth_patch(film, grid, c0, r0, n, [d[0] - h, d[1]]);
            p.iter()
                .zip(&q)
                .map(|(a, b)| (a - b) / (2.0 * h))
                .collect::<Vec<_>>()
        };
        let ty = {
            let p = truth_patch(film, grid, c0, r0, n, [d[0], d[1] + h]);
            let q = truth_patch(film, grid, c0, r0, n, [d[0], d[1] - h]);
            p.iter()
                .zip(&q)
                .map(|(a, b)| (a - b) / (2.0 * h))
                .collect::<Vec<_>>()
        };
        // Gain and offset first (linear), then the shift with them.
        let nn = t.len() as f64;
        let (mt, mm) = (t.iter().sum::<f64>() / nn, m.iter().sum::<f64>() / nn);
        let b = t
            .iter()
            .zip(&m)
            .map(|(a, y)| (a - mt) * (y - mm))
            .sum::<f64>()
            / t.iter().map(|a| (a - mt).powi(2)).sum::<f64>();
        let a = mm - b * mt;
        let mut n = nalgebra::Matrix2::<f64>::zeros();
        let mut g = nalgebra::Vector2::<f64>::zeros();
        for k in 0..t.len() {
            let j = nalgebra::Vector2::new(b * tx[k], b * ty[k]);
            let r = m[k] - (a + b * t[k]);
            n += j * j.transpose();
            g += j * r;
        }
        let step = n.try_inverse().expect("textured patch") * g;
        d = [d[0] + step[0], d[1] + step[1]];
        if step.norm() < 1e-5 * grid.step_mm {
            break;
        }
    }
    d
}

/// Scans `regions` of photo `photo` and checks features against the true picture.
fn scan_and_check(photo: u32, interior: &Path, region: [f64; 4], kill: bool) -> f64 {
    let d = tempfile::tempdir().unwrap();
    let regions = format!(
        "[[region]]\nname = \"overlap\"\nphoto_mm = [{}, {}, {}, {}]\n",
        region[0], region[1], region[2], region[3]
    );
    let s = script(d.path(), interior, &regions, "out");
    let photo_arg = photo.to_string();
    let sim = ["--sim-photo", photo_arg.as_str()];
    let out_dir = d.path().join("out");
    if kill {
        // Killed half-way and resumed on the ordinary (not repeatable) simulator: the stage
        // re-homes, the film check passes, the photo must still be right.
        assert_eq!(interrupt_with(&sim, &s, &out_dir, false, 4, false), None);
    }
    let mut cmd = rig();
    cmd.args(["scan", "--sim", "--sim-seed", SEED])
        .args(sim)
        .args(["--json", "run"])
        .arg(&s);
    if kill {
        cmd.arg("--resume");
    }
    let out = ok(&mut cmd);
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["status"], "complete");
    let (side, img) = ScannedPhoto::load(&d.path().join("out").join("overlap.json")).unwrap();
    assert!(img.iter().all(|&p| p != side.grey.nodata), "no holes");
    let film = truth_film(photo);
    let g = side.grid;
    let n = 41;
    let mut worst: f64 = 0.0;
    let mut sum2 = 0.0;
    let mut count = 0;
    for fy in [0.15, 0.5, 0.85] {
        for fx in [0.15, 0.5, 0.85] {
            let c0 = ((g.width - n) as f64 * fx) as usize;
            let r0 = ((g.height - n) as f64 * fy) as usize;
            let dm = measured_shift(&film, &g, &img, c0, r0, n);
            let px = [dm[0] / g.step_mm, dm[1] / g.step_mm];
            let centre = g.photo(PixelXY::new((c0 + n / 2) as f64, (r0 + n / 2) as f64));
            eprintln!(
                "photo {photo} at ({:7.2}, {:6.2}) mm: off by ({:+.4}, {:+.4}) px",
                centre.x, centre.y, px[0], px[1]
            );
            worst = worst.max(px[0].hypot(px[1]));
            sum2 += px[0] * px[0] + px[1] * px[1];
            count += 1;
        }
    }
    let rms = (sum2 / (2.0 * count as f64)).sqrt();
    eprintln!("photo {photo}: RMS {rms:.4} px per coordinate, worst {worst:.4} px");
    assert!(
        worst < 0.1,
        "a feature lies {worst:.3} output px from its true photo position"
    );
    worst
}

#[test]
fn scanned_photos_of_a_stereo_pair_lie_on_their_true_photo_coordinates() {
    let (_, i1, i2) = calibrated();
    // The same ground in both photos: photo 2 lies about 92 mm along x from photo 1.
    scan_and_check(1, i1, [40.0, -6.0, 52.0, 6.0], true);
    scan_and_check(2, i2, [-52.0, -6.0, -40.0, 6.0], false);
}

fn done_tiles(dir: &Path) -> usize {
    std::fs::read(dir.join("manifest.json"))
        .ok()
        .and_then(|b| serde_json::from_slice::<Value>(&b).ok())
        .map(|m| {
            m["tiles"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|t| !t.is_null())
                .count()
        })
        .unwrap_or(0)
}

/// Starts a repeatable scan into `out` and interrupts it once at least `at` tiles are done:
/// with SIGKILL, or with SIGINT (a pause). Returns the exit status (None when killed).
/// `rig scan --sim --sim-repeatable run SCRIPT --out OUT [--resume]`.
fn repeatable_run(script: &Path, out: &Path, resume: bool) -> Command {
    let mut cmd = rig();
    cmd.args([
        "scan",
        "--sim",
        "--sim-seed",
        SEED,
        "--sim-repeatable",
        "run",
    ])
    .arg(script)
    .arg("--out")
    .arg(out);
    if resume {
        cmd.arg("--resume");
    }
    cmd
}

fn interrupt_at(script: &Path, out: &Path, resume: bool, at: usize, sigint: bool) -> Option<i32> {
    interrupt_with(&["--sim-repeatable"], script, out, resume, at, sigint)
}

fn interrupt_with(
    sim: &[&str],
    script: &Path,
    out: &Path,
    resume: bool,
    at: usize,
    sigint: bool,
) -> Option<i32> {
    let mut cmd = rig();
    cmd.args(["scan", "--sim", "--sim-seed", SEED])
        .args(sim)
        .arg("run")
        .arg(script)
        .arg("--out")
        .arg(out);
    if resume {
        cmd.arg("--resume");
    }
    let mut child = cmd
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while done_tiles(out) < at {
        if let Some(s) = child.try_wait().unwrap() {
            return s.code();
        }
        assert!(t0.elapsed() < Duration::from_secs(120), "scan stalled");
        std::thread::sleep(Duration::from_millis(5));
    }
    if sigint {
        unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
        child.wait().unwrap().code()
    } else {
        child.kill().unwrap();
        child.wait().unwrap();
        None
    }
}

#[test]
fn a_scan_killed_and_resumed_is_byte_identical_to_an_uninterrupted_one() {
    let (_, i1, _) = calibrated();
    let d = tempfile::tempdir().unwrap();
    let regions = "[[region]]\nname = \"a\"\nphoto_mm = [-8.0, -5.0, 4.0, 5.0]\n\n[[region]]\nname = \"b\"\nphoto_mm = [2.0, 2.0, 12.0, 9.0]\n";
    let s = script(d.path(), i1, regions, "unused");
    let whole = d.path().join("whole");
    ok(&mut repeatable_run(&s, &whole, false));
    let total = {
        let m: Value =
            serde_json::from_slice(&std::fs::read(whole.join("manifest.json")).unwrap()).unwrap();
        m["tiles"].as_array().unwrap().len()
    };
    assert!(total >= 8, "{total} tiles");
    // Random interruption points, different each run (the seed is printed).
    let seed = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64;
    let k1 = 1 + (seed % (total as u64 / 3)) as usize;
    let k2 = k1 + 1 + ((seed >> 16) % (total as u64 / 3)) as usize;
    let k3 = (k2 + 1 + ((seed >> 32) % 2) as usize).min(total - 1);
    eprintln!("{total} tiles; kill -9 at {k1}, kill -9 at {k2}, Ctrl-C at {k3}");
    let cut = d.path().join("cut");
    assert_eq!(interrupt_at(&s, &cut, false, k1, false), None);
    assert!(!cut.join("a.tiff").exists());
    // Resuming with another film on the carriage (photo 2 instead of 1) is refused: the tile
    // taken again does not match the stored one.
    let before = done_tiles(&cut);
    let out = rig()
        .args([
            "scan",
            "--sim",
            "--sim-seed",
            SEED,
            "--sim-repeatable",
            "--sim-photo",
            "2",
            "run",
        ])
        .arg(&s)
        .arg("--out")
        .arg(&cut)
        .arg("--resume")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(e.contains("the film has moved"), "{e}");
    assert_eq!(done_tiles(&cut), before, "a refused resume takes no tile");
    assert_eq!(interrupt_at(&s, &cut, true, k2, false), None);
    let paused = interrupt_at(&s, &cut, true, k3, true);
    // Ctrl-C pauses at the next tile boundary (exit 4) unless the scan had just finished.
    assert!(
        matches!(paused, Some(4) | Some(0)),
        "Ctrl-C gave {paused:?}"
    );
    if paused == Some(4) {
        assert!(done_tiles(&cut) < total);
        let log = std::fs::read_to_string(cut.join("log.jsonl")).unwrap();
        assert!(log.contains("\"paused\""));
        ok(&mut repeatable_run(&s, &cut, true));
    }
    for f in ["a.tiff", "a.json", "b.tiff", "b.json"] {
        let (x, y) = (
            std::fs::read(whole.join(f)).unwrap(),
            std::fs::read(cut.join(f)).unwrap(),
        );
        assert!(x == y, "{f} differs after kill and resume");
    }
    // The log tells the story: two resumes at least, every tile logged once per taking.
    let log = std::fs::read_to_string(cut.join("log.jsonl")).unwrap();
    assert!(log.matches("\"resumed\"").count() >= 2);
    // Starting over in a directory with a scan in it is refused.
    let out = rig()
        .args(["scan", "--sim", "run"])
        .arg(&s)
        .arg("--out")
        .arg(&cut)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--resume"));
}

#[test]
fn bad_scripts_and_plans_outside_the_soft_limits_are_refused_before_anything_moves() {
    let (store, i1, _) = calibrated();
    let d = tempfile::tempdir().unwrap();
    let region = "[[region]]\nname = \"r\"\nphoto_mm = [60.0, -10.0, 100.0, 10.0]\n";
    let s = script(d.path(), i1, region, "out");
    let plan = |extra: &[&str]| {
        rig()
            .args(["scan", "--store", store.to_str().unwrap(), "plan"])
            .arg(&s)
            .args(extra)
            .output()
            .unwrap()
    };
    let png = d.path().join("plan.png");
    let out = plan(&["--json", "--plot", png.to_str().unwrap()]);
    assert!(out.status.success());
    assert!(std::fs::read(&png).unwrap().starts_with(b"\x89PNG"));
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["plan"]["tiles"].as_array().unwrap().len() > 10);
    assert!(v["plan"]["estimate"]["seconds"].as_f64().unwrap() > 0.0);
    // The film lies about 125 mm into the carriage: photo x = 100 mm needs the stage near
    // 225 mm. Soft limits at 200 mm refuse the plan, naming the script's line and region.
    let out = plan(&["--limits", "0,200,0,250"]);
    assert_eq!(out.status.code(), Some(3));
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(
        e.contains("scan.toml:16: region `r`") && e.contains("soft limits"),
        "{e}"
    );
    // …and so does `run`, before anything moves.
    let out = rig()
        .args(["scan", "--sim", "--limits", "0,200,0,250", "run"])
        .arg(&s)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(3));
    assert!(!d.path().join("out").exists());
    // Bad scripts: the message names the file, the line and the field.
    let text = std::fs::read_to_string(&s).unwrap();
    for (from, to, want) in [
        (
            "resolution_um = 25.0",
            "resolution_um = 0.1",
            "scan.toml:8: output.resolution_um",
        ),
        ("frames = 8", "frames = 0", "scan.toml:11: capture.frames"),
        (
            "[60.0, -10.0, 100.0, 10.0]",
            "[60.0, 10.0]",
            "scan.toml:17: region[1].photo_mm",
        ),
        ("overlap = 0.2", "overlapp = 0.2", "line 12"),
    ] {
        std::fs::write(&s, text.replace(from, to)).unwrap();
        let out = plan(&[]);
        assert_eq!(out.status.code(), Some(1), "{to}");
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(e.contains(want), "{to}: {e}");
    }
    std::fs::write(&s, text).unwrap();
}
