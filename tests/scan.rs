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
    check_mosaic_shares(&whole, d.path());
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
        matches!(paused, Some(11) | Some(0)),
        "Ctrl-C gave {paused:?}"
    );
    if paused == Some(11) {
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
    // The records name their sessions, certificate and script relative to the scan's folder
    // (it can move): no record holds the folder's absolute path, and each recorded path,
    // joined to the folder, is the file or session it was made from.
    let root = d.path().canonicalize().unwrap();
    for f in [
        "calibration.json",
        "manifest.json",
        "a.json",
        "b.json",
        "log.jsonl",
    ] {
        let text = std::fs::read_to_string(whole.join(f)).unwrap();
        assert!(
            !text.contains(root.to_str().unwrap()) && !text.contains(d.path().to_str().unwrap()),
            "{f} keeps an absolute path: {text}"
        );
    }
    let side: Value =
        serde_json::from_slice(&std::fs::read(whole.join("a.json")).unwrap()).unwrap();
    let at = |v: &Value| whole.join(v.as_str().unwrap()).canonicalize().unwrap();
    assert_eq!(
        at(&side["interior_orientation"]["session"]),
        i1.canonicalize().unwrap()
    );
    assert_eq!(at(&side["scan"]["script"]), s.canonicalize().unwrap());
    assert!(at(&side["camera_certificate"]["path"]).is_file());
    assert!(at(&side["pixel_to_carriage"]["session"]).is_dir());
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

/// The scan's two photos mosaicked in three shares (one empty) on "other machines" and merged
/// into a copy of the scan without its photos give the scan's own photos byte for byte; a
/// missing share and a damaged file are refused before anything is
/// copied.
fn check_mosaic_shares(whole: &Path, tmp: &Path) {
    let copy = tmp.join("shares-scan");
    copy_scan(whole, &copy);
    let photos = ["a.tiff", "a.png", "a.json", "b.tiff", "b.png", "b.json"];
    for f in photos {
        std::fs::remove_file(copy.join(f)).unwrap();
    }
    let share = |i: usize| tmp.join(format!("share-{i}"));
    for i in 1..=3 {
        let o = ok(rig()
            .args(["scan", "mosaic"])
            .arg(&copy)
            .args(["--tile", &format!("{i}/3"), "--out"])
            .arg(share(i)));
        let t = String::from_utf8_lossy(&o.stdout);
        assert!(t.contains(&format!("share {i}/3")), "{t}");
    }
    // A missing share: refused, nothing copied.
    let o = rig()
        .args(["scan", "merge"])
        .args([share(1), share(3)])
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("missing 2/3"), "{e}");
    assert!(!copy.join("a.tiff").exists());
    // A damaged file: refused, nothing copied.
    let m: Value =
        serde_json::from_slice(&std::fs::read(share(3).join("mosaic-share.json")).unwrap())
            .unwrap();
    let f = share(3).join(m["photos"][0]["files"][0]["file"].as_str().unwrap());
    let good = std::fs::read(&f).unwrap();
    std::fs::write(&f, &good[..good.len() / 2]).unwrap();
    let o = rig()
        .args(["scan", "merge"])
        .args([share(1), share(2), share(3)])
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("cut short"), "{e}");
    assert!(!copy.join("a.tiff").exists());
    std::fs::write(&f, &good).unwrap();
    // All three, out of order: into the scan they name.
    ok(rig()
        .args(["scan", "merge"])
        .args([share(3), share(1), share(2)]));
    for f in photos {
        let (x, y) = (
            std::fs::read(whole.join(f)).unwrap(),
            std::fs::read(copy.join(f)).unwrap(),
        );
        assert!(
            x == y,
            "{f} differs between the whole mosaic and the merged shares"
        );
    }
    let log = std::fs::read_to_string(copy.join("log.jsonl")).unwrap();
    assert_eq!(log.matches("\"share\"").count(), 2, "{log}");
}

/// A copy of scan or session directory `from` at `to` (its files and its tiles folder).
fn copy_scan(from: &Path, to: &Path) {
    std::fs::create_dir_all(to.join("tiles")).unwrap();
    for sub in ["", "tiles"] {
        let Ok(entries) = std::fs::read_dir(from.join(sub)) else {
            continue;
        };
        for e in entries {
            let e = e.unwrap();
            if e.file_type().unwrap().is_file() {
                std::fs::copy(e.path(), to.join(sub).join(e.file_name())).unwrap();
            }
        }
    }
}

fn edit_json(path: &Path, f: impl FnOnce(&mut Value)) {
    let mut v: Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(path, serde_json::to_vec_pretty(&v).unwrap()).unwrap();
}

/// Every file under `d` with its bytes, to show that a refused command changed nothing.
fn snapshot(d: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut v = Vec::new();
    let mut stack = vec![d.to_path_buf()];
    while let Some(p) = stack.pop() {
        for e in std::fs::read_dir(&p).unwrap() {
            let e = e.unwrap().path();
            if e.is_dir() {
                stack.push(e);
            } else if e.file_name().is_some_and(|n| n != "log.jsonl") {
                v.push((e.clone(), std::fs::read(&e).unwrap()));
            }
        }
    }
    v.sort();
    v
}

/// A hand-made 8-bit greyscale TIFF (little-endian, uncompressed) of `w` × `h` pixels.
fn tiff8(w: u16, h: u16) -> Vec<u8> {
    let tags: [(u16, u16, u32); 9] = [
        (256, 3, w as u32),
        (257, 3, h as u32),
        (258, 3, 8),
        (259, 3, 1),
        (262, 3, 1),
        (273, 4, 8 + 2 + 9 * 12 + 4),
        (277, 3, 1),
        (278, 3, h as u32),
        (279, 4, w as u32 * h as u32),
    ];
    let mut b = b"II*\0".to_vec();
    b.extend_from_slice(&8u32.to_le_bytes());
    b.extend_from_slice(&(tags.len() as u16).to_le_bytes());
    for (tag, typ, v) in tags {
        b.extend_from_slice(&tag.to_le_bytes());
        b.extend_from_slice(&typ.to_le_bytes());
        b.extend_from_slice(&1u32.to_le_bytes());
        b.extend_from_slice(&v.to_le_bytes());
    }
    b.extend_from_slice(&0u32.to_le_bytes());
    b.extend(std::iter::repeat_n(128u8, w as usize * h as usize));
    b
}

/// Nothing in a scan directory is trusted: a manifest, calibration or tile that was edited,
/// swapped or replaced is refused with a message naming it, before anything is read outside
/// the directory, allocated beyond the plan, moved or written; and the directory is left as it
/// was.
#[test]
fn damaged_or_edited_scan_directories_are_refused_and_left_unchanged() {
    use common::run_hostile;
    let (_, i1, _) = calibrated();
    let d = tempfile::tempdir().unwrap();
    let region = "[[region]]\nname = \"r\"\nphoto_mm = [0.0, 0.0, 8.0, 5.0]\n";
    let s = script(d.path(), i1, region, "unused");
    let good = d.path().join("good");
    ok(&mut repeatable_run(&s, &good, false));
    let tiles: Vec<String> = {
        let m: Value =
            serde_json::from_slice(&std::fs::read(good.join("manifest.json")).unwrap()).unwrap();
        m["tiles"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| t["file"]["file"].as_str().unwrap().to_string())
            .collect()
    };
    assert!(tiles.len() >= 2, "{tiles:?}");
    let manifest = |dir: &Path| dir.join("manifest.json");
    type Damage<'a> = Box<dyn Fn(&Path) + 'a>;
    let cases: Vec<(&str, Damage, &str)> = vec![
        (
            "region name that climbs out of the directory",
            Box::new(|p: &Path| {
                edit_json(&manifest(p), |m| {
                    m["plan"]["regions"][0]["name"] = "../escape".into()
                })
            }),
            "does not agree",
        ),
        (
            "tile file outside the directory",
            Box::new(|p: &Path| {
                edit_json(&manifest(p), |m| {
                    m["tiles"][0]["file"]["file"] = "../../escape.tiff".into()
                })
            }),
            "is recorded as `../../escape.tiff`",
        ),
        (
            "grid of width 0",
            Box::new(|p: &Path| {
                edit_json(&manifest(p), |m| {
                    m["plan"]["regions"][0]["grid"]["width"] = 0.into()
                })
            }),
            "region `r` differs",
        ),
        (
            "grid of 10^6 × 10^6 px",
            Box::new(|p: &Path| {
                edit_json(&manifest(p), |m| {
                    m["plan"]["regions"][0]["grid"]["width"] = 1_000_000.into();
                    m["plan"]["regions"][0]["grid"]["height"] = 1_000_000.into();
                })
            }),
            "region `r` differs",
        ),
        (
            "a tile dropped from the plan",
            Box::new(|p: &Path| {
                edit_json(&manifest(p), |m| {
                    m["plan"]["tiles"].as_array_mut().unwrap().pop();
                    m["tiles"].as_array_mut().unwrap().pop();
                })
            }),
            "tiles planned",
        ),
        (
            "a tile's stage position",
            Box::new(|p: &Path| {
                edit_json(&manifest(p), |m| {
                    m["tiles"][0]["stage_um"]["x"] = 1e300.into()
                })
            }),
            "from its planned",
        ),
        (
            "a truncated manifest",
            Box::new(|p: &Path| {
                let b = std::fs::read(manifest(p)).unwrap();
                std::fs::write(manifest(p), &b[..b.len() / 2]).unwrap();
            }),
            "manifest.json",
        ),
        (
            "two tiles swapped on disk",
            Box::new(|p: &Path| {
                let (a, b) = (p.join(&tiles[0]), p.join(&tiles[1]));
                let tmp = p.join("swap");
                std::fs::rename(&a, &tmp).unwrap();
                std::fs::rename(&b, &a).unwrap();
                std::fs::rename(&tmp, &b).unwrap();
            }),
            "changed on disk",
        ),
        (
            "a tile replaced by an 8-bit TIFF, its hash updated",
            Box::new(|p: &Path| {
                let b = tiff8(64, 64);
                std::fs::write(p.join(&tiles[0]), &b).unwrap();
                edit_json(&manifest(p), |m| {
                    m["tiles"][0]["file"]["hash"] = rig::scan::manifest::fnv64(&b).into()
                });
            }),
            "16-bit unsigned",
        ),
        (
            "a calibration with a pixel of 1e-9 µm",
            Box::new(|p: &Path| {
                edit_json(&p.join("calibration.json"), |c| {
                    for k in [1, 2, 4, 5] {
                        c["pixel"]["params"][k] = 1e-9.into();
                    }
                })
            }),
            "calibration.json",
        ),
        (
            "the scan's copy of the script names a reserved region",
            Box::new(|p: &Path| {
                let t = std::fs::read_to_string(p.join("script.toml")).unwrap();
                std::fs::write(p.join("script.toml"), t.replace("\"r\"", "\"manifest\"")).unwrap();
            }),
            "scan's own files",
        ),
        (
            "the scan's copy of the script edited",
            Box::new(|p: &Path| {
                let t = std::fs::read_to_string(p.join("script.toml")).unwrap();
                std::fs::write(p.join("script.toml"), t.replace("frames = 8", "frames = 9"))
                    .unwrap();
            }),
            "not the script the scan began with",
        ),
    ];
    for (k, (what, damage, want)) in cases.iter().enumerate() {
        let dir = d.path().join(format!("case-{k}"));
        copy_scan(&good, &dir);
        damage(&dir);
        let before = snapshot(d.path());
        let h = run_hostile(rig().args(["scan", "mosaic"]).arg(&dir), 4, 60);
        assert_ne!(h.code, Some(0), "{what}: accepted\n{}", h.stdout);
        assert!(
            h.stderr.contains(want),
            "{what}: wanted `{want}` in\n{}",
            h.stderr
        );
        assert!(snapshot(d.path()) == before, "{what}: files changed");
        assert!(
            !d.path().join("escape.tiff").exists()
                && !d.path().parent().unwrap().join("escape.tiff").exists()
        );
    }
    // A resume re-checks the plan against the operator's soft limits before anything moves.
    let dir = d.path().join("limits");
    copy_scan(&good, &dir);
    edit_json(&manifest(&dir), |m| m["tiles"][0] = Value::Null);
    let before = snapshot(&dir);
    let h = run_hostile(
        rig()
            .args(["scan", "--sim", "--limits", "0,20,0,20", "run"])
            .arg(&s)
            .arg("--out")
            .arg(&dir)
            .arg("--resume"),
        4,
        60,
    );
    assert_eq!(h.code, Some(3), "{}", h.stderr);
    assert!(
        h.stderr.contains("resume refused") && h.stderr.contains("soft limits"),
        "{}",
        h.stderr
    );
    assert!(snapshot(&dir) == before);
}

/// A scan whose disk fills (here: a file-size limit, so every tile write fails) reports the
/// write that failed, not the simulator's shutdown; leaves a manifest that describes what is on
/// disk and no partial file; and a resume then completes it byte for byte as an uninterrupted
/// scan.
#[test]
fn a_full_disk_stops_the_scan_with_the_first_error_and_a_resume_completes_it() {
    use std::os::unix::process::CommandExt;
    let (_, i1, _) = calibrated();
    let d = tempfile::tempdir().unwrap();
    let region = "[[region]]\nname = \"r\"\nphoto_mm = [0.0, 0.0, 8.0, 5.0]\n";
    let s = script(d.path(), i1, region, "unused");
    let whole = d.path().join("whole");
    ok(&mut repeatable_run(&s, &whole, false));
    let full = d.path().join("full");
    let mut cmd = repeatable_run(&s, &full, false);
    // SAFETY: setrlimit and signal only change this child's own limits and dispositions.
    unsafe {
        cmd.pre_exec(|| {
            let r = libc::rlimit {
                rlim_cur: 64 << 10,
                rlim_max: 64 << 10,
            };
            libc::setrlimit(libc::RLIMIT_FSIZE, &r);
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            Ok(())
        });
    }
    let h = common::run_hostile(&mut cmd, 4, 120);
    assert_eq!(h.code, Some(1), "{}", h.stderr);
    assert!(
        h.stderr.contains("writing") && h.stderr.contains("flat.tiff"),
        "{}",
        h.stderr
    );
    assert!(
        !h.stderr.contains("stopping the built-in simulator"),
        "{}",
        h.stderr
    );
    let m: Value =
        serde_json::from_slice(&std::fs::read(full.join("manifest.json")).unwrap()).unwrap();
    assert!(m["flat"].is_null() && m["tiles"].as_array().unwrap().iter().all(|t| t.is_null()));
    let parts: Vec<_> = snapshot(&full)
        .into_iter()
        .filter(|(p, _)| p.to_string_lossy().ends_with(".part"))
        .collect();
    assert!(
        parts.is_empty(),
        "partial files left: {:?}",
        parts.iter().map(|p| &p.0).collect::<Vec<_>>()
    );
    ok(&mut repeatable_run(&s, &full, true));
    assert!(
        std::fs::read(whole.join("r.tiff")).unwrap() == std::fs::read(full.join("r.tiff")).unwrap(),
        "the resumed scan differs from the uninterrupted one"
    );
}

/// A calibration session edited or damaged on disk (its certificate, its descriptor) is refused
/// by `scan plan` with the file and the range, within seconds and bounded memory: nothing is
/// tiled from a fiducial a kilometre away or a camera of one-pixel frames.
#[test]
fn a_damaged_calibration_session_refuses_the_plan() {
    use common::run_hostile;
    let (store, i1, _) = calibrated();
    let d = tempfile::tempdir().unwrap();
    let cases: [(&str, &str, &str, &str); 4] = [
        ("camera-cert.toml", "x_mm = ", "x_mm = 1e9", "±150 mm"),
        (
            "camera-cert.toml",
            "ring_radius_um = 300.0",
            "ring_radius_um = 1e9",
            "a mark dimension from 1 to 10000 µm",
        ),
        (
            "log.jsonl",
            "\"width\":",
            "\"width\":1e12,\"w\":",
            "camera.width",
        ),
        (
            "log.jsonl",
            "\"max_speed_um_s\":",
            "\"max_speed_um_s\":-1,\"m\":",
            "max_speed_um_s",
        ),
    ];
    for (k, (file, from, to, want)) in cases.iter().enumerate() {
        let session = d.path().join(format!("interior-{k}"));
        copy_scan(i1, &session);
        let p = session.join(file);
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(text.contains(from), "{file} lacks `{from}`");
        // The first fiducial's x, as a whole line.
        let edited = if from.starts_with("x_mm") {
            let mut lines: Vec<String> = text.lines().map(String::from).collect();
            let i = lines.iter().position(|l| l.starts_with("x_mm")).unwrap();
            lines[i] = "x_mm = 1e9".into();
            lines.join("\n")
        } else {
            text.replacen(from, to, 1)
        };
        std::fs::write(&p, edited).unwrap();
        let region = "[[region]]\nname = \"all\"\nwhole = true\n";
        let s = script(d.path(), &session, region, "out");
        let h = run_hostile(
            rig()
                .args(["scan", "--store", store.to_str().unwrap(), "plan"])
                .arg(&s),
            2,
            30,
        );
        assert_ne!(h.code, Some(0), "{file} `{to}` accepted:\n{}", h.stdout);
        assert!(
            h.stderr.contains(want) && h.stderr.contains(&session.display().to_string()),
            "{file} `{to}`: wanted `{want}` and the session in\n{}",
            h.stderr
        );
    }
}

/// The lab service runs the same scan twice: once untouched, once killed with SIGKILL at five
/// points and started again each time. Each restart finds the item interrupted at the front
/// and the queue stopped; started again it goes on from the last tile; the photos are the
/// untouched run's, byte for byte.
#[test]
fn a_service_killed_five_times_mid_scan_resumes_to_the_same_files() {
    use common::serve::{wait_for, Server};
    let (store, i1, _) = calibrated();
    let d = tempfile::tempdir().unwrap();
    let data = d.path().join("service");
    let regions = "[[region]]\nname = \"a\"\nphoto_mm = [-8.0, -5.0, 4.0, 5.0]\n\n[[region]]\nname = \"b\"\nphoto_mm = [2.0, 2.0, 12.0, 9.0]\n";
    let text = std::fs::read_to_string(script(d.path(), i1, regions, "unused")).unwrap();
    let args = [
        "--sim",
        "--sim-seed",
        SEED,
        "--sim-repeatable",
        "--store",
        store.to_str().unwrap(),
    ];
    let add = |s: &Server, name: &str| {
        let body = serde_json::json!({"items": [{"task": {"kind": "scan", "name": name, "script": text}}]});
        let (st, v) = s.call("POST", "/api/v1/queue/items", None, Some(&body.to_string()));
        assert_eq!(st, 200, "{v}");
        v["ids"][0].as_u64().unwrap()
    };
    let ended = |id: u64| {
        move |v: &Value| {
            v["where"] == "history" && v["item"]["state"] == "done" || {
                assert_ne!(v["item"]["state"], "failed", "item {id}: {v}");
                false
            }
        }
    };
    let s = Server::start(&data, &args);
    let whole = add(&s, "whole");
    let cut = add(&s, "cut");
    assert_eq!(s.call("POST", "/api/v1/queue/stop", None, None).0, 200);
    assert_eq!(s.call("POST", "/api/v1/queue/start", None, None).0, 200);
    wait_for(&s, &format!("/api/v1/items/{whole}"), 120, ended(whole));
    s.call("POST", "/api/v1/queue/stop", None, None);
    let total = {
        let m: Value = serde_json::from_slice(
            &std::fs::read(data.join(format!("items/{whole}/scan/manifest.json"))).unwrap(),
        )
        .unwrap();
        m["tiles"].as_array().unwrap().len()
    };
    assert!(total >= 8, "{total} tiles");
    let cut_dir = data.join(format!("items/{cut}/scan"));
    // Five kill points, different each run (printed), each after at least one more tile.
    let seed = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64;
    let mut at = Vec::new();
    let mut k = 0;
    for i in 0..5u64 {
        k += 1 + ((seed >> (8 * i)) % 2) as usize;
        at.push(k.min(total - 1));
    }
    eprintln!("{total} tiles; kill -9 of the service at {at:?}");
    let mut s = s;
    for (n, &k) in at.iter().enumerate() {
        assert_eq!(s.call("POST", "/api/v1/queue/start", None, None).0, 200);
        let t0 = Instant::now();
        while done_tiles(&cut_dir) < k {
            assert!(t0.elapsed() < Duration::from_secs(120), "scan stalled");
            std::thread::sleep(Duration::from_millis(5));
        }
        s.kill();
        s = Server::start(&data, &args);
        let (_, v) = s.call("GET", &format!("/api/v1/items/{cut}"), None, None);
        assert_eq!(v["where"], "queue", "{v}");
        assert_eq!(v["index"], 0, "{v}");
        let attempts = v["item"]["attempts"].as_array().unwrap();
        assert_eq!(attempts.len(), n + 1, "{v}");
        assert_eq!(attempts[n]["outcome"], "interrupted", "{v}");
        let (_, q) = s.call("GET", "/api/v1/queue", None, None);
        assert_eq!(
            q["options"]["running"], false,
            "the queue waits for an operator: {q}"
        );
    }
    assert_eq!(s.call("POST", "/api/v1/queue/start", None, None).0, 200);
    let v = wait_for(&s, &format!("/api/v1/items/{cut}"), 120, ended(cut));
    assert_eq!(v["item"]["attempts"].as_array().unwrap().len(), 6);
    assert!(
        v["item"]["result"]["photos"]
            .as_array()
            .is_some_and(|p| p.len() == 2),
        "{v}"
    );
    let whole_dir = data.join(format!("items/{whole}/scan"));
    for f in ["a.tiff", "a.json", "b.tiff", "b.json"] {
        let (x, y) = (
            std::fs::read(whole_dir.join(f)).unwrap(),
            std::fs::read(cut_dir.join(f)).unwrap(),
        );
        assert!(x == y, "{f} differs after five kills and resumes");
    }
}
