//! `rig measure` end to end (issue 17), on marks drawn here by their own coverage integration
//! (not the rig's template renderer), with exactly known centres: a corner fiducial (dot,
//! ring, four spokes) on square pixels, a mid-side fiducial on 10.19 × 10.96 µm pixels, near
//! the frame, scratched, half cut by the frame, and hostile flags and files.

mod common;

use common::{gauss, rig, run_hostile, uniform};
use serde_json::Value;
use std::path::{Path, PathBuf};

const CORNER: &str = r#"units = "px"
polarity = "dark_on_bright"
[[part]]
kind = "dot"
radius = 2.0
[[part]]
kind = "ring"
radius = 14.0
width = 2.0
[[part]]
kind = "spokes"
count = 4
from = 17.0
to = 22.0
width = 2.0
angle0_deg = 0.0
"#;

/// Whether (x, y) px from the centre is on the corner fiducial.
fn corner_on(x: f64, y: f64) -> bool {
    let r = x.hypot(y);
    let spoke = (17.0..=22.0).contains(&r) && (x.abs() <= 1.0 || y.abs() <= 1.0);
    r <= 2.0 || (r - 14.0).abs() <= 1.0 || spoke
}

/// A `w`×`h` float image: grey 200, 50 on the mark (`on`, in µm from the centre; pixel
/// `px_um` µm), the centre at `centre` in the README's convention (integer values at pixel
/// centres), drawn on a grid 8 times finer (each cell's coverage from 4 × 4 jittered samples), blurred
/// there by a Gaussian of σ 0.6 px (the optics), averaged over each pixel's 8 × 8 cells, with
/// Gaussian noise σ 2 DN.
fn draw(
    w: usize,
    h: usize,
    centre: [f64; 2],
    px_um: [f64; 2],
    on: &dyn Fn(f64, f64) -> bool,
    seed: &mut u64,
) -> Vec<f32> {
    const K: usize = 8;
    const S: usize = 4;
    let (fw, fh) = (w * K, h * K);
    let mut cover = vec![0f64; fw * fh];
    for r in 0..fh {
        for c in 0..fw {
            let mut k = 0;
            for j in 0..S {
                for i in 0..S {
                    // Jittered within its stratum: on a fixed lattice an edge along the
                    // lattice would move in steps of 1/32 px.
                    let (ju, jv) = (uniform(seed), uniform(seed));
                    let x = ((c as f64 + (i as f64 + ju) / S as f64) / K as f64 - 0.5 - centre[0])
                        * px_um[0];
                    let y = ((r as f64 + (j as f64 + jv) / S as f64) / K as f64 - 0.5 - centre[1])
                        * px_um[1];
                    k += on(x, y) as usize;
                }
            }
            cover[r * fw + c] = k as f64 / (S * S) as f64;
        }
    }
    // The blur, separable, on the fine grid (edges clamped).
    let sigma = 0.6 * K as f64;
    let half = (4.0 * sigma).ceil() as i64;
    let kernel: Vec<f64> = (-half..=half)
        .map(|d| (-(d * d) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let norm: f64 = kernel.iter().sum();
    let pass = |src: &[f64], along_rows: bool| -> Vec<f64> {
        let mut out = vec![0.0; fw * fh];
        for r in 0..fh as i64 {
            for c in 0..fw as i64 {
                let mut v = 0.0;
                for (t, k) in kernel.iter().enumerate() {
                    let d = t as i64 - half;
                    let (cc, rr) = if along_rows {
                        ((c + d).clamp(0, fw as i64 - 1), r)
                    } else {
                        (c, (r + d).clamp(0, fh as i64 - 1))
                    };
                    v += k * src[(rr * fw as i64 + cc) as usize];
                }
                out[(r * fw as i64 + c) as usize] = v / norm;
            }
        }
        out
    };
    let blurred = pass(&pass(&cover, true), false);
    let mut out = vec![0f32; w * h];
    for r in 0..h {
        for c in 0..w {
            let mut sum = 0.0;
            for j in 0..K {
                for i in 0..K {
                    sum += blurred[(r * K + j) * fw + c * K + i];
                }
            }
            let cov = sum / (K * K) as f64;
            out[r * w + c] = (200.0 - 150.0 * cov + 2.0 * gauss(seed)) as f32;
        }
    }
    out
}

fn write_tiff(path: &Path, w: usize, h: usize, data: &[f32]) {
    let mut enc = tiff::encoder::TiffEncoder::new(std::fs::File::create(path).unwrap()).unwrap();
    enc.write_image::<tiff::encoder::colortype::Gray32Float>(w as u32, h as u32, data)
        .unwrap();
}

fn measure(args: &[&str]) -> (i32, String, String) {
    let o = rig().arg("measure").args(args).output().unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stdout).to_string(),
        String::from_utf8_lossy(&o.stderr).to_string(),
    )
}

fn setup() -> (tempfile::TempDir, PathBuf) {
    let d = tempfile::tempdir().unwrap();
    let mark = d.path().join("corner.toml");
    std::fs::write(&mark, CORNER).unwrap();
    (d, mark)
}

/// Clean corner fiducials on square pixels, one near the frame (its window cut, the mark
/// whole), and one 61 × 61 image smaller than the matching window: every one accepted,
/// within 0.02 px of the truth and within 4σ, in the README's convention; the CSV says the
/// same.
#[test]
fn corner_fiducials_are_measured_to_hundredths_in_the_readme_convention() {
    let (d, mark) = setup();
    let mut seed = 3u64;
    let mut cases: Vec<(PathBuf, [f64; 2])> = Vec::new();
    for k in 0..6 {
        let (w, h, base) = match k {
            // Near the left edge: 24 px from it.
            4 => (101, 101, [24.0, 50.0]),
            // Smaller than the window.
            5 => (61, 61, [30.0, 30.0]),
            _ => (101, 101, [50.0, 50.0]),
        };
        let centre = [base[0] + uniform(&mut seed), base[1] + uniform(&mut seed)];
        let img = draw(w, h, centre, [1.0, 1.0], &corner_on, &mut seed);
        let p = d.path().join(format!("c{k}.tif"));
        write_tiff(&p, w, h, &img);
        cases.push((p, centre));
    }
    let csv = d.path().join("out.csv");
    let mut args: Vec<String> = cases.iter().map(|c| c.0.display().to_string()).collect();
    args.extend([
        "--mark".into(),
        mark.display().to_string(),
        "--json".into(),
        "--csv".into(),
        csv.display().to_string(),
    ]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let (code, out, err) = measure(&args);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    let rows = v.as_array().expect("an array for several images");
    assert_eq!(rows.len(), cases.len());
    for (r, (p, truth)) in rows.iter().zip(&cases) {
        let (col, row) = (r["col"].as_f64().unwrap(), r["row"].as_f64().unwrap());
        let (sc, sr) = (
            r["sigma_col"].as_f64().unwrap(),
            r["sigma_row"].as_f64().unwrap(),
        );
        let (ec, er) = (col - truth[0], row - truth[1]);
        eprintln!(
            "{}: error {ec:+.4} {er:+.4} px, σ {sc:.4} {sr:.4}, blur {}, {}",
            p.display(),
            r["blur_px"],
            r["reason"]
        );
        assert_eq!(r["accepted"], true, "{r}");
        assert!(r["reason"].is_null());
        assert!(ec.abs() < 0.02 && er.abs() < 0.02, "{ec} {er}");
        assert!(
            ec.abs() < 4.0 * sc && er.abs() < 4.0 * sr,
            "{ec}/{sc} {er}/{sr}"
        );
        assert!(sc > 0.0005 && sc < 0.02, "σ {sc}");
        // Four spokes fix a rotation: reported, and near 0.
        assert!(r["rotation_deg"].as_f64().unwrap().abs() < 1.0);
        assert!((r["scale"].as_f64().unwrap() - 1.0).abs() < 0.01);
    }
    // The same images from a list file (relative paths, a comment, a blank line).
    let list = d.path().join("images.txt");
    let names: Vec<String> = cases
        .iter()
        .map(|c| c.0.file_name().unwrap().to_string_lossy().to_string())
        .collect();
    std::fs::write(&list, format!("# the fiducials\n\n{}\n", names.join("\n"))).unwrap();
    let (code, out2, err) = measure(&[
        "--list",
        list.to_str().unwrap(),
        "--mark",
        mark.to_str().unwrap(),
        "--json",
        "--blur",
        "0.6",
    ]);
    assert_eq!(code, 0, "{err}");
    let v2: Value = serde_json::from_str(&out2).unwrap();
    assert_eq!(v2.as_array().unwrap().len(), cases.len());
    for (r, (_, truth)) in v2.as_array().unwrap().iter().zip(&cases) {
        assert!((r["col"].as_f64().unwrap() - truth[0]).abs() < 0.02, "{r}");
    }
    let text = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert!(lines[0].starts_with("image,col,row,sigma_col,sigma_row,rotation_deg,scale"));
    assert_eq!(lines.len(), cases.len() + 1);
    let first_col: f64 = lines[1].split(',').nth(1).unwrap().parse().unwrap();
    assert_eq!(first_col, rows[0]["col"].as_f64().unwrap());
}

/// A mid-side fiducial (dot and ring) in µm on 10.19 × 10.96 µm pixels: shifts and scale only
/// (no rotation reported); --near finds it among two marks.
#[test]
fn a_ring_on_non_square_pixels_and_near() {
    let (d, _) = setup();
    let mark = d.path().join("mid.toml");
    std::fs::write(
        &mark,
        "units = \"um\"\n[[part]]\nkind = \"dot\"\nradius = 20.0\n[[part]]\nkind = \"ring\"\nradius = 140.0\nwidth = 20.0\n",
    )
    .unwrap();
    let on = |x: f64, y: f64| {
        let r = x.hypot(y);
        r <= 20.0 || (r - 140.0).abs() <= 10.0
    };
    let mut seed = 9u64;
    let a = [40.3, 45.7];
    let b = [120.2, 44.1];
    let img_a = draw(160, 90, a, [10.19, 10.96], &on, &mut seed);
    let img_b = draw(160, 90, b, [10.19, 10.96], &on, &mut seed);
    // Both marks in one image (each drawn on its own background; the darker wins).
    let both: Vec<f32> = img_a.iter().zip(&img_b).map(|(x, y)| x.min(*y)).collect();
    let p = d.path().join("two.tif");
    write_tiff(&p, 160, 90, &both);
    let (code, out, err) = measure(&[
        p.to_str().unwrap(),
        "--mark",
        mark.to_str().unwrap(),
        "--pixel-um",
        "10.19,10.96",
        "--near",
        "118,46",
        "--search",
        "10",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let r: Value = serde_json::from_str(&out).unwrap();
    assert!(r.is_object(), "an object for one image");
    let (ec, er) = (
        r["col"].as_f64().unwrap() - b[0],
        r["row"].as_f64().unwrap() - b[1],
    );
    eprintln!("ring: error {ec:+.4} {er:+.4}; {r}");
    assert_eq!(r["accepted"], true, "{r}");
    assert!(ec.abs() < 0.02 && er.abs() < 0.02, "{ec} {er}");
    assert!(r["rotation_deg"].is_null(), "a ring has no rotation");
    // --near where neither mark lies within --search, and --near off the image: not found,
    // never the mark beyond.
    for (near, search) in [("80,45", "5"), ("-500,45", "20"), ("100000,45", "20")] {
        let (code, out, err) = measure(&[
            p.to_str().unwrap(),
            "--mark",
            mark.to_str().unwrap(),
            "--pixel-um",
            "10.19,10.96",
            "--near",
            near,
            "--search",
            search,
            "--json",
        ]);
        assert_eq!(code, 0, "{err}");
        let r: Value = serde_json::from_str(&out).unwrap();
        assert_eq!(r["reason"], "not_found", "--near {near}: {r}");
    }
    // Without the pixel size a µm mark cannot be drawn: said so.
    let (code, _, err) = measure(&[p.to_str().unwrap(), "--mark", mark.to_str().unwrap()]);
    assert_eq!(code, 2);
    assert!(err.contains("--pixel-um"), "{err}");
}

/// The gate: a scratch across the mark is refused as damaged, a mark half cut by the frame as
/// cut, a cross measured with the ring's mark file not accepted; --strict exits 12.
#[test]
fn damaged_marks_are_refused_with_typed_reasons() {
    let (d, mark) = setup();
    let mut seed = 5u64;
    let c = [50.4, 49.8];
    let mut scratched = draw(101, 101, c, [1.0, 1.0], &corner_on, &mut seed);
    for r in 0..101 {
        for col in 0..101 {
            // A 2-px dark line across the ring, off the centre.
            let dist = (col as f64 - r as f64 * 0.3 - 52.0).abs();
            if dist < 1.0 {
                scratched[r * 101 + col] = 60.0;
            }
        }
    }
    let cut = draw(101, 101, [1.2, 50.3], [1.0, 1.0], &corner_on, &mut seed);
    let cross = draw(
        101,
        101,
        c,
        [1.0, 1.0],
        &|x: f64, y: f64| {
            (x.abs() <= 1.5 && y.abs() <= 30.0) || (y.abs() <= 1.5 && x.abs() <= 30.0)
        },
        &mut seed,
    );
    let mut paths = Vec::new();
    for (name, img) in [("scratch", &scratched), ("cut", &cut), ("cross", &cross)] {
        let p = d.path().join(format!("{name}.tif"));
        write_tiff(&p, 101, 101, img);
        paths.push(p);
    }
    let mut args: Vec<&str> = paths.iter().map(|p| p.to_str().unwrap()).collect();
    args.extend(["--mark", mark.to_str().unwrap(), "--json", "--strict"]);
    let (code, out, err) = measure(&args);
    assert_eq!(code, 12, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    for r in v.as_array().unwrap() {
        eprintln!("{}: {} ({})", r["image"], r["reason"], r["message"]);
        assert_eq!(r["accepted"], false, "{r}");
    }
    assert_eq!(v[0]["reason"], "damaged");
    // The right mark with the wrong polarity: refused as inverted, not fitted with a
    // negative contrast.
    let neg = d.path().join("negative.toml");
    std::fs::write(&neg, CORNER.replace("dark_on_bright", "bright_on_dark")).unwrap();
    let good = d.path().join("good.tif");
    write_tiff(
        &good,
        101,
        101,
        &draw(101, 101, c, [1.0, 1.0], &corner_on, &mut seed),
    );
    let (code, out, err) = measure(&[
        good.to_str().unwrap(),
        "--mark",
        neg.to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let r: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(r["reason"], "inverted", "{r}");
    assert_eq!(v[1]["reason"], "cut", "{}", v[1]);
    assert!(
        ["not_found", "damaged"].contains(&v[2]["reason"].as_str().unwrap()),
        "{}",
        v[2]
    );
}

/// Hostile flags and files: each refused with the exit code of bad usage or an error naming
/// what is wrong, never a panic, within bounds.
#[test]
fn hostile_input_is_refused_by_name() {
    let (d, mark) = setup();
    let img = d.path().join("i.tif");
    write_tiff(&img, 40, 40, &[100.0; 1600]);
    let bad_mark = d.path().join("bad.toml");
    std::fs::write(&bad_mark, CORNER.replace("count = 4", "count = 100000")).unwrap();
    let huge = d.path().join("huge.toml");
    std::fs::write(&huge, CORNER.replace("to = 22.0", "to = 499.0")).unwrap();
    let nan = d.path().join("nan.tif");
    write_tiff(&nan, 40, 40, &[f32::NAN; 1600]);
    let i = img.to_str().unwrap();
    let m = mark.to_str().unwrap();
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec![i, "--mark", m, "--near", "nan,3"], "--near"),
        (vec![i, "--mark", m, "--near", "5"], "--near"),
        (
            vec![i, "--mark", m, "--near", "1,1", "--search", "-1"],
            "--search",
        ),
        (vec![i, "--mark", m, "--blur", "inf"], "--blur"),
        (vec![i, "--mark", m, "--pixel-um", "0,5"], "--pixel-um"),
        (vec![i, "--mark", m, "--max-sigma", "0"], "--max-sigma"),
        (vec![i, "--mark", m, "--min-inside", "101"], "--min-inside"),
        (
            vec![i, "--mark", bad_mark.to_str().unwrap()],
            "count 100000",
        ),
        (vec![i, "--mark", "/nonexistent.toml"], "nonexistent"),
        (vec![nan.to_str().unwrap(), "--mark", m], "NaN"),
        (vec!["/nonexistent.tif", "--mark", m], "nonexistent"),
        (vec![i, "--mark", huge.to_str().unwrap()], "template"),
    ];
    for (args, want) in cases {
        let mut cmd = rig();
        cmd.arg("measure").args(&args);
        let h = run_hostile(&mut cmd, 4, 60);
        assert!(
            h.code != Some(0) && (h.stderr.contains(want) || h.stdout.contains(want)),
            "{args:?}: exit {:?}, {}",
            h.code,
            h.stderr
        );
    }
    // A flat image: nothing found, said so, exit 0 (no --strict).
    let (code, out, _) = measure(&[i, "--mark", m, "--json"]);
    assert_eq!(code, 0);
    let r: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(r["accepted"], false);
    assert_eq!(r["reason"], "not_found");
}

/// Column stripes (a 12-px pattern of a few DN, as seed 002's camera had) bias a cross's
/// centre: with `--stripes-from FLAT` (a flat of the same camera) and by default (the stripes
/// estimated from each image off the mark's footprint) the error falls against
/// `--keep-stripes`, and σ covers what is left.
#[test]
fn stripes_estimated_on_a_flat_are_removed_from_the_images() {
    let (d, _) = setup();
    let mark = d.path().join("cross.toml");
    std::fs::write(
        &mark,
        "units = \"px\"\n[[part]]\nkind = \"bar\"\nlength = 60.0\nwidth = 3.0\n[[part]]\nkind = \"bar\"\nlength = 60.0\nwidth = 3.0\nangle_deg = 90.0\n",
    )
    .unwrap();
    let cross =
        |x: f64, y: f64| (x.abs() <= 1.5 && y.abs() <= 30.0) || (y.abs() <= 1.5 && x.abs() <= 30.0);
    let pattern = |c: usize| -> f32 {
        match ((c + 7) % 12) / 3 {
            0 => -7.0,
            2 => -4.0,
            _ => 0.0,
        }
    };
    let (w, h) = (101usize, 101usize);
    let mut seed = 17u64;
    // The flat: clear glass, 32 frames averaged (noise 2/√32 DN), the same columns.
    let flat: Vec<f32> = (0..w * h)
        .map(|i| 200.0 + pattern(i % w) + (2.0 / 32f64.sqrt() * gauss(&mut seed)) as f32)
        .collect();
    let flat_path = d.path().join("flat.tif");
    write_tiff(&flat_path, w, h, &flat);
    let mut paths = Vec::new();
    let mut truth = Vec::new();
    for k in 0..10 {
        let c = [50.0 + uniform(&mut seed), 50.0 + uniform(&mut seed)];
        let mut img = draw(w, h, c, [1.0, 1.0], &cross, &mut seed);
        write_tiff(&d.path().join(format!("n{k}.tif")), w, h, &img);
        for (i, v) in img.iter_mut().enumerate() {
            *v += pattern(i % w);
        }
        let p = d.path().join(format!("s{k}.tif"));
        write_tiff(&p, w, h, &img);
        paths.push(p.display().to_string());
        truth.push(c);
    }
    let run_on = |paths: &[String], extra: &[&str]| -> (f64, f64) {
        let mut args: Vec<&str> = paths.iter().map(String::as_str).collect();
        args.extend(["--mark", mark.to_str().unwrap(), "--json"]);
        args.extend(extra);
        let (code, out, err) = measure(&args);
        assert_eq!(code, 0, "{err}");
        let v: Value = serde_json::from_str(&out).unwrap();
        let (mut e2, mut z2) = (0.0, 0.0);
        for (r, t) in v.as_array().unwrap().iter().zip(&truth) {
            assert_eq!(r["accepted"], true, "{r}");
            let ec = r["col"].as_f64().unwrap() - t[0];
            let er = r["row"].as_f64().unwrap() - t[1];
            if std::env::var_os("MARK_DEBUG").is_some() {
                eprintln!(
                    "{ec:+.4} {er:+.4} σ {:.4} blur {} rot {} scale {}",
                    r["sigma_col"], r["blur_px"], r["rotation_deg"], r["scale"]
                );
            }
            e2 += ec * ec + er * er;
            z2 += (ec / r["sigma_col"].as_f64().unwrap()).powi(2)
                + (er / r["sigma_row"].as_f64().unwrap()).powi(2);
        }
        let n = truth.len() as f64;
        ((e2 / n).sqrt(), (z2 / (2.0 * n)).sqrt())
    };
    let run = |extra: &[&str]| run_on(&paths, extra);
    let none: Vec<String> = paths.iter().map(|p| p.replace("/s", "/n")).collect();
    let (base, base_z) = run_on(&none, &[]);
    eprintln!("cross without stripes: RMSE {base:.4} px (RMS err/σ {base_z:.2})");
    let (raw, raw_z) = run(&["--keep-stripes"]);
    let (own, own_z) = run(&[]);
    let (clean, clean_z) = run(&["--stripes-from", flat_path.to_str().unwrap()]);
    eprintln!(
        "cross with stripes: RMSE {raw:.4} px (RMS err/σ {raw_z:.2}); with the flat's stripes removed {clean:.4} px ({clean_z:.2}); with the image's own {own:.4} px ({own_z:.2})"
    );
    assert!(clean < 0.7 * raw, "{clean} against {raw}");
    assert!(own < 0.7 * raw, "{own} against {raw}");
    assert!(
        raw_z < 2.0 && clean_z < 2.0 && own_z < 2.0,
        "{raw_z} {clean_z} {own_z}"
    );
    // A flat of another width is refused by name.
    let narrow = d.path().join("narrow.tif");
    write_tiff(&narrow, 50, 50, &flat[..2500]);
    let mut args: Vec<&str> = paths.iter().take(1).map(String::as_str).collect();
    args.extend([
        "--mark",
        mark.to_str().unwrap(),
        "--stripes-from",
        narrow.to_str().unwrap(),
    ]);
    let (code, _, err) = measure(&args);
    assert_eq!(code, 1);
    assert!(err.contains("50 px wide"), "{err}");
}
