//! The matchers on scenes a renderer that is not ours made (tests/data/validation, with their
//! truth and their README's conventions), measured as that README defines the goals:
//! - the DEM's RMSE at its nodes against the true surface, in pixels of parallax (flying height
//!   / base × GSD, from scene.json), within 0.1 px;
//! - covering at least 80 % of the two-photo area (the true DEM's posts that two photos see,
//!   by the scene's own collinearity and its photos' pixels, not by our sensors);
//! - RMS(true error / σ) within 0.8–1.25, and 50–98 % of the errors within 2σ.
//!
//! The sweep is measured on the OSLSM's coarse model, which is the sweep of the same project
//! run into `out/coarse` (one sweep a scene where two ran).
//!
//! And the marks (the `marks` module below) to their goals.
//!
//! Every figure is printed (`cargo test --release --test validation -- --nocapture`) for the
//! table in the README.

mod common;

use rig::matching::grid::ElevationGrid;
use rig::matching::products::files::read_geotiff;
use serde_json::Value;
use std::path::{Path, PathBuf};

fn scene_dir(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/validation/scenes")
        .join(name)
}

/// Band 1 of a two-band float32 TIFF written pixel-interleaved (quality.tif: σ, correlation).
fn first_of_two_bands(path: &Path) -> Vec<f32> {
    let f = std::fs::File::open(path).unwrap();
    let mut d = tiff::decoder::Decoder::new(std::io::BufReader::new(f)).unwrap();
    match d.read_image().unwrap() {
        tiff::decoder::DecodingResult::F32(v) => v.chunks_exact(2).map(|p| p[0]).collect(),
        other => panic!("{}: float32 expected, not {other:?}", path.display()),
    }
}

/// A 16-bit photo's grey values and width (0 where the renderer's ray missed the DEM).
fn photo(path: &Path) -> (Vec<u16>, usize, usize) {
    let f = std::fs::File::open(path).unwrap();
    let mut d = tiff::decoder::Decoder::new(std::io::BufReader::new(f)).unwrap();
    let (w, h) = d.dimensions().unwrap();
    match d.read_image().unwrap() {
        tiff::decoder::DecodingResult::U16(v) => (v, w as usize, h as usize),
        other => panic!("{}: 16-bit grey expected, not {other:?}", path.display()),
    }
}

/// The scene's own collinearity (scene.json's conventions: x = xp − c·(m₁·d)/(m₃·d), the
/// photo's M = Rᵀ given as `M_object_to_image`, x = (col − (W−1)/2)·p, y = ((H−1)/2 − row)·p),
/// written here from its README, not taken from the rig's camera.
struct View {
    m: [[f64; 3]; 3],
    centre: [f64; 3],
    c: f64,
    pp: [f64; 2],
    p: f64,
    grey: Vec<u16>,
    w: usize,
    h: usize,
}

impl View {
    fn sees(&self, x: f64, y: f64, z: f64) -> bool {
        let d = [x - self.centre[0], y - self.centre[1], z - self.centre[2]];
        let r = |i: usize| self.m[i][0] * d[0] + self.m[i][1] * d[1] + self.m[i][2] * d[2];
        let (u, v, w) = (r(0), r(1), r(2));
        let (px, py) = (self.pp[0] - self.c * u / w, self.pp[1] - self.c * v / w);
        let col = px / self.p + (self.w as f64 - 1.0) / 2.0;
        let row = (self.h as f64 - 1.0) / 2.0 - py / self.p;
        if !(col >= 0.0 && row >= 0.0 && col <= self.w as f64 - 1.0 && row <= self.h as f64 - 1.0) {
            return false;
        }
        self.grey[row.round() as usize * self.w + col.round() as usize] != 0
    }
}

fn views(dir: &Path, scene: &Value) -> Vec<View> {
    let (e0, n0) = (
        scene["object_system"]["E0"].as_f64().unwrap_or(0.0),
        scene["object_system"]["N0"].as_f64().unwrap_or(0.0),
    );
    scene["photos"]
        .as_array()
        .unwrap()
        .iter()
        .map(|ph| {
            let (e, i) = (&ph["exterior"], &ph["interior"]);
            let m = e["M_object_to_image"].as_array().unwrap();
            let m: Vec<[f64; 3]> = m
                .iter()
                .map(|r| {
                    let r = r.as_array().unwrap();
                    [
                        r[0].as_f64().unwrap(),
                        r[1].as_f64().unwrap(),
                        r[2].as_f64().unwrap(),
                    ]
                })
                .collect();
            let (grey, w, h) = photo(&dir.join(ph["file"].as_str().unwrap()));
            View {
                m: [m[0], m[1], m[2]],
                centre: [
                    e["X0"].as_f64().unwrap() + e0,
                    e["Y0"].as_f64().unwrap() + n0,
                    e["Z0"].as_f64().unwrap(),
                ],
                c: i["focal_mm"].as_f64().unwrap(),
                pp: [
                    i["principal_point_mm"][0].as_f64().unwrap(),
                    i["principal_point_mm"][1].as_f64().unwrap(),
                ],
                p: i["pixel_size_um"].as_f64().unwrap() / 1000.0,
                grey,
                w,
                h,
            }
        })
        .collect()
}

/// The figures of one matcher on one scene.
#[derive(Debug)]
struct Figures {
    rmse_px: f64,
    coverage_percent: f64,
    sigma_ratio: f64,
    within_2_sigma_percent: f64,
}

/// Runs `rig dtm` with `method` on a copy of the scene and measures it against the truth;
/// the figures and the run's report.json.
/// `rig dtm` of scene `name` with `method`, in a copy of the scene: the copy's directory
/// (its run in `out/`, kept while the `TempDir` lives) and the run's report.
fn run_scene(name: &str, method: &str) -> (tempfile::TempDir, PathBuf, Value) {
    let src = scene_dir(name);
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join(name);
    std::fs::create_dir_all(&dir).unwrap();
    for e in std::fs::read_dir(&src).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), dir.join(e.file_name())).unwrap();
    }
    let project = std::fs::read_to_string(dir.join("project.toml")).unwrap();
    assert!(project.contains("method = \"sweep\""), "{project}");
    let project = project.replace("method = \"sweep\"", &format!("method = \"{method}\""));
    std::fs::write(dir.join("project.toml"), project).unwrap();
    let report = common::dtm_json(&dir.join("project.toml"), &dir.join("out"));
    (tmp, dir, report)
}

/// The figures of the model in `out` of scene `name` (copied into `dir`), as `method` made it.
fn measure(name: &str, method: &str, dir: &Path, out: &Path) -> Figures {
    let scene: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("scene.json")).unwrap()).unwrap();
    let px = scene["flying_height_m"].as_f64().unwrap() / scene["base_m"].as_f64().unwrap()
        * scene["gsd_m"].as_f64().unwrap();
    let truth = read_geotiff(&dir.join("truth_dem.tif")).unwrap();
    let dem = read_geotiff(&out.join("dem.tif")).unwrap();
    let sigma = first_of_two_bands(&out.join("quality.tif"));
    assert_eq!(sigma.len(), dem.z.len());
    let views = views(dir, &scene);
    let seen_twice = |x: f64, y: f64, z: f64| views.iter().filter(|v| v.sees(x, y, z)).count() >= 2;
    // Errors at the DEM's nodes where two photos see the true surface.
    let (mut ee, mut rr, mut n, mut inside) = (0.0, 0.0, 0usize, 0usize);
    for r in 0..dem.rows {
        for c in 0..dem.cols {
            let k = r * dem.cols + c;
            let [x, y] = dem.node(c, r);
            let zt = truth.interpolate(x, y);
            let z = dem.z[k] as f64;
            if !(zt.is_finite() && z.is_finite() && seen_twice(x, y, zt)) {
                continue;
            }
            let e = z - zt;
            ee += e * e;
            n += 1;
            let s = sigma[k] as f64;
            assert!(
                s.is_finite() && s > 0.0,
                "{name} {method}: node {c},{r} without a σ"
            );
            rr += (e / s).powi(2);
            inside += usize::from(e.abs() <= 2.0 * s);
        }
    }
    // Coverage: the true posts two photos see, with a height in the DEM cell holding them.
    let (mut area, mut covered) = (0usize, 0usize);
    for r in 0..truth.rows {
        for c in 0..truth.cols {
            let [x, y] = truth.node(c, r);
            let zt = truth.z[r * truth.cols + c] as f64;
            if !(zt.is_finite() && seen_twice(x, y, zt)) {
                continue;
            }
            area += 1;
            covered += usize::from(has_height(&dem, x, y));
        }
    }
    assert!(
        n > 100 && area > 100,
        "{name} {method}: {n} nodes, {area} posts"
    );
    let f = Figures {
        rmse_px: (ee / n as f64).sqrt() / px,
        coverage_percent: 100.0 * covered as f64 / area as f64,
        sigma_ratio: (rr / n as f64).sqrt(),
        within_2_sigma_percent: 100.0 * inside as f64 / n as f64,
    };
    println!(
        "{name:16} {method:6}: RMSE {:.3} px of parallax ({:.3} m over {n} nodes), coverage {:.1} % of the two-photo area, RMS(error/σ) {:.2}, {:.0} % within 2σ",
        f.rmse_px,
        f.rmse_px * px,
        f.coverage_percent,
        f.sigma_ratio,
        f.within_2_sigma_percent
    );
    f
}

/// Whether the DEM cell (nodes at cell centres) holding ground (x, y) has a height.
fn has_height(dem: &ElevationGrid, x: f64, y: f64) -> bool {
    let c = ((x - dem.x0) / dem.cell_m + 0.5).floor();
    let r = ((dem.y0 - y) / dem.cell_m + 0.5).floor();
    c >= 0.0
        && r >= 0.0
        && (c as usize) < dem.cols
        && (r as usize) < dem.rows
        && dem.z[r as usize * dem.cols + c as usize].is_finite()
}

fn assert_goals(name: &str, method: &str, f: &Figures) {
    assert!(f.rmse_px <= 0.1, "{name} {method}: {f:?}");
    assert!(f.coverage_percent >= 80.0, "{name} {method}: {f:?}");
    assert!(
        (0.8..=1.25).contains(&f.sigma_ratio),
        "{name} {method}: σ not honest: {f:?}"
    );
    assert!(
        (50.0..=98.0).contains(&f.within_2_sigma_percent),
        "{name} {method}: {f:?}"
    );
}

/// `method` on scene `name`, held to the goals; its report.
fn method_to_its_goals(name: &str, method: &str) -> Value {
    let (_tmp, dir, report) = run_scene(name, method);
    assert_goals(name, method, &measure(name, method, &dir, &dir.join("out")));
    report
}

/// The object-space matching on scene `name` and, from the same run, the sweep: the OSLSM's
/// coarse model is the sweep's run of the same project into `out/coarse` (one sweep where
/// two were run), both held to the goals. The OSLSM's report.
fn sweep_and_oslsm_to_their_goals(name: &str) -> Value {
    let (_tmp, dir, report) = run_scene(name, "oslsm");
    assert_eq!(report["coarse_source"], "the sweep, in coarse/", "{report}");
    let coarse = dir.join("out").join("coarse");
    assert_goals(name, "sweep", &measure(name, "sweep", &dir, &coarse));
    assert_goals(
        name,
        "oslsm",
        &measure(name, "oslsm", &dir, &dir.join("out")),
    );
    report
}

#[test]
fn mgcm_on_the_lidar_scene() {
    method_to_its_goals("lidar-banks", "mgcm");
}

#[test]
fn mgcm_on_the_wide_angle_scene() {
    method_to_its_goals("jacksboro-wide", "mgcm");
}

#[test]
fn mgcm_on_the_noisy_close_scene() {
    method_to_its_goals("jacksboro-close", "mgcm");
}

/// The object-space matching (seed 001) on the 1 m lidar scene: the project's 1 m posts hold
/// fewer than its minimum of groundels (of about a ground pixel, 0.35 m), so it puts its posts
/// at a multiple of cell_m and says so, in report.json and in a warning, instead of refusing.
#[test]
fn sweep_and_oslsm_on_the_lidar_scene() {
    let report = sweep_and_oslsm_to_their_goals("lidar-banks");
    let (post, asked) = (
        report["post_m"].as_f64().unwrap(),
        report["asked_post_m"].as_f64().unwrap(),
    );
    assert_eq!(asked, 1.0, "{report}");
    assert!(
        post > asked && (post / asked).fract() == 0.0,
        "posts every {post} m"
    );
    let warnings = report["warnings"].as_array().unwrap();
    assert!(
        warnings
            .iter()
            .any(|w| w.as_str().unwrap().contains("cell_m = 1 m")
                && w.as_str().unwrap().contains(&format!("every {post} m"))),
        "{warnings:?}"
    );
}

#[test]
fn sweep_and_oslsm_on_the_wide_angle_scene() {
    let report = sweep_and_oslsm_to_their_goals("jacksboro-wide");
    // The project's 80 m posts hold enough groundels: kept.
    assert_eq!(report["post_m"], report["asked_post_m"]);
}

#[test]
fn sweep_and_oslsm_on_the_noisy_close_scene() {
    sweep_and_oslsm_to_their_goals("jacksboro-close");
}

/// `rig measure` on the validation marks (tests/data/validation/marks, see its README: 4 marks
/// of each type × condition chosen from the 20 of the validation set, made by an independent
/// renderer with exact centres), measured through the command line as a user would, with no
/// flat (the stripes are estimated from each crop): the centre's RMSE, RMS(true error / σ), and
/// a gate that accepts every mark within 3σ of the truth and refuses a scratched, a cut and a
/// wrong mark. All 300 marks: `benches/marks_validation.py`.
mod marks {
    use super::common::{rig, run_ok};
    use serde_json::Value;
    use std::path::{Path, PathBuf};

    const CONDITIONS: [&str; 5] = ["a_read2", "b_read8", "c_ccd", "d_avg32", "d_avg32_16bit"];

    /// The mark file of a type (the validation README's ideal marks, in px), kept beside the
    /// images for this test and benches/marks_validation.py alike.
    fn mark_file(kind: &str) -> String {
        std::fs::read_to_string(data().join(format!("{kind}.toml"))).unwrap()
    }

    fn data() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/validation/marks")
    }

    /// (file, true col, true row) of one folder.
    fn truth(dir: &Path) -> Vec<(String, f64, f64)> {
        let text = std::fs::read_to_string(dir.join("truth.csv")).unwrap();
        text.lines()
            .skip(1)
            .filter(|l| !l.trim().is_empty())
            .map(|l| {
                let f: Vec<&str> = l.split(',').collect();
                (
                    f[0].to_string(),
                    f[1].parse().unwrap(),
                    f[2].parse().unwrap(),
                )
            })
            .collect()
    }

    /// Per mark: (Δcol, Δrow, σcol, σrow, accepted).
    fn measure(kind: &str, mark: &str, condition: &str) -> Vec<(f64, f64, f64, f64, bool)> {
        let tmp = tempfile::tempdir().unwrap();
        let mf = tmp.path().join(format!("{kind}.toml"));
        std::fs::write(&mf, mark).unwrap();
        let dir = data().join(kind).join(condition);
        let t = truth(&dir);
        let mut cmd = rig();
        cmd.arg("measure")
            .arg("--mark")
            .arg(&mf)
            .arg("--json")
            .arg("-q");
        for (f, _, _) in &t {
            cmd.arg(dir.join(f));
        }
        let out = run_ok(&mut cmd);
        let v: Value = serde_json::from_slice(&out.stdout).unwrap();
        let arr = v.as_array().expect("an array for several images");
        assert_eq!(arr.len(), t.len());
        arr.iter()
            .zip(&t)
            .map(|(r, (f, c, rw))| {
                let col = r["col"]
                    .as_f64()
                    .unwrap_or_else(|| panic!("{kind}/{condition}/{f}: no centre: {r}"));
                let row = r["row"].as_f64().unwrap();
                (
                    col - c,
                    row - rw,
                    r["sigma_col"].as_f64().unwrap(),
                    r["sigma_row"].as_f64().unwrap(),
                    r["accepted"].as_bool().unwrap(),
                )
            })
            .collect()
    }

    /// The goals per type × condition; returns (RMSE, Σ(err/σ)², count of axes) for pooling.
    fn check(kind: &str, mark: &str) -> (f64, usize) {
        let (mut z2, mut nz) = (0.0, 0);
        for cond in CONDITIONS {
            let m = measure(kind, mark, cond);
            let rmse =
                (m.iter().map(|e| e.0 * e.0 + e.1 * e.1).sum::<f64>() / m.len() as f64).sqrt();
            for e in &m {
                z2 += (e.0 / e.2).powi(2) + (e.1 / e.3).powi(2);
                nz += 2;
                // The gate accepts every mark within 3σ of the truth.
                if e.0.abs() < 3.0 * e.2 && e.1.abs() < 3.0 * e.3 {
                    assert!(e.4, "{kind}/{cond}: a mark within 3σ refused: {e:?}");
                }
            }
            // At 2 DN the centre's Cramér–Rao bound on these marks (contrast 120 DN, blur
            // σ 0.7–1.0 px) is 0.004–0.0055 px radial: 4 marks' RMSE within 0.0065 px.
            let goal = match cond {
                "a_read2" => 0.0065,
                "b_read8" => 0.03,
                _ => 0.02,
            };
            eprintln!("{kind:8} {cond:14} RMSE {rmse:.4} px (goal {goal})");
            assert!(
                rmse <= goal,
                "{kind}/{cond}: RMSE {rmse:.4} px above {goal}: {m:?}"
            );
        }
        (z2, nz)
    }

    fn honest(kind: &str, mark: &str) {
        let (z2, n) = check(kind, mark);
        let z = (z2 / n as f64).sqrt();
        eprintln!("{kind}: RMS(error / σ) {z:.2} over {n} axes");
        assert!((0.7..=1.35).contains(&z), "{kind}: RMS(error/σ) {z:.2}");
    }

    #[test]
    fn crosses_to_their_goals() {
        honest("cross", &mark_file("cross"));
    }

    #[test]
    fn corner_fiducials_to_their_goals() {
        honest("corner", &mark_file("corner"));
    }

    #[test]
    fn midside_fiducials_to_their_goals() {
        honest("midside", &mark_file("midside"));
    }

    /// One grey image of the validation marks, as stored (8 or 16 bits), as u16 values.
    fn read_grey(path: &Path) -> (Vec<u16>, usize, usize, bool) {
        let f = std::fs::File::open(path).unwrap();
        let mut d = tiff::decoder::Decoder::new(std::io::BufReader::new(f)).unwrap();
        let (w, h) = d.dimensions().unwrap();
        match d.read_image().unwrap() {
            tiff::decoder::DecodingResult::U16(v) => (v, w as usize, h as usize, true),
            tiff::decoder::DecodingResult::U8(v) => (
                v.into_iter().map(u16::from).collect(),
                w as usize,
                h as usize,
                false,
            ),
            other => panic!(
                "{}: 8- or 16-bit grey expected, not {other:?}",
                path.display()
            ),
        }
    }

    fn write_grey(path: &Path, v: &[u16], w: usize, h: usize, wide: bool) {
        let f = std::fs::File::create(path).unwrap();
        let mut e = tiff::encoder::TiffEncoder::new(std::io::BufWriter::new(f)).unwrap();
        if wide {
            e.write_image::<tiff::encoder::colortype::Gray16>(w as u32, h as u32, v)
                .unwrap();
        } else {
            let b: Vec<u8> = v.iter().map(|&x| x.min(255) as u8).collect();
            e.write_image::<tiff::encoder::colortype::Gray8>(w as u32, h as u32, &b)
                .unwrap();
        }
    }

    /// The gate on someone else's marks: a scratch across a corner fiducial's ring (2 px of
    /// the mark's own dark grey, off the centre) is refused as damaged; the same mark cut by
    /// the frame through its centre as cut (or not found); a cross measured with the
    /// mid-side's mark file is not accepted. Each one's clean original is accepted.
    #[test]
    fn the_gate_refuses_scratched_cut_and_wrong_marks() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = data().join("corner/a_read2");
        let t = truth(&dir);
        let (file, tc, tr) = &t[0];
        let (v, w, h, wide) = read_grey(&dir.join(file));
        let dark = *v.iter().min().unwrap();
        let mut scratched = v.clone();
        for r in 0..h {
            for c in 0..w {
                // A line at 17° from the columns, 5 px right of the centre: it crosses the
                // ring (radius 13–15) twice and misses the dot.
                let d = (c as f64 - tc - 5.0) - 0.3 * (r as f64 - tr);
                if d.abs() < 1.0 {
                    scratched[r * w + c] = dark;
                }
            }
        }
        let cut_at = tc.round() as usize;
        let cut: Vec<u16> = (0..h)
            .flat_map(|r| v[r * w + cut_at..(r + 1) * w].to_vec())
            .collect();
        let paths = [
            ("original", v.clone(), w),
            ("scratched", scratched, w),
            ("cut", cut, w - cut_at),
        ]
        .map(|(name, img, width)| {
            let p = tmp.path().join(format!("{name}.tif"));
            write_grey(&p, &img, width, h, wide);
            p
        });
        let mf = tmp.path().join("corner.toml");
        std::fs::write(&mf, mark_file("corner")).unwrap();
        let out = run_ok(
            rig()
                .args(["measure", "--json", "-q", "--mark"])
                .arg(&mf)
                .args(&paths),
        );
        let v: Value = serde_json::from_slice(&out.stdout).unwrap();
        for r in v.as_array().unwrap() {
            eprintln!("{}: {} {}", r["image"], r["accepted"], r["message"]);
        }
        assert_eq!(v[0]["accepted"], true, "{}", v[0]);
        assert_eq!(v[1]["reason"], "damaged", "{}", v[1]);
        assert!(
            ["cut", "not_found"].contains(&v[2]["reason"].as_str().unwrap_or("")),
            "{}",
            v[2]
        );
        // A cross with the mid-side fiducial's mark file.
        let mf = tmp.path().join("midside.toml");
        std::fs::write(&mf, mark_file("midside")).unwrap();
        let dir = data().join("cross/a_read2");
        let out = run_ok(
            rig()
                .args(["measure", "--json", "-q", "--mark"])
                .arg(&mf)
                .arg(dir.join(&truth(&dir)[0].0)),
        );
        let r: Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(r["accepted"], false, "{r}");
    }
}
