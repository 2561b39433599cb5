//! The matchers on scenes a renderer that is not ours made (tests/data/validation, with their
//! truth and their README's conventions), measured as that README defines the goals:
//! - the DEM's RMSE at its nodes against the true surface, in pixels of parallax (flying height
//!   / base × GSD, from scene.json), within 0.1 px;
//! - covering at least 80 % of the two-photo area (the true DEM's posts that two photos see,
//!   by the scene's own collinearity and its photos' pixels, not by our sensors);
//! - RMS(true error / σ) within 0.8–1.25, and 50–98 % of the errors within 2σ.
//!
//! Every figure is printed (`cargo test --release --test validation -- --nocapture`) for the
//! table in the README.

mod common;

use rig::matching::grid::ElevationGrid;
use rig::matching::output::read_geotiff;
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
fn measure_with_report(name: &str, method: &str) -> (Figures, Value) {
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
    let out = dir.join("out");
    let report = common::dtm_json(&dir.join("project.toml"), &out);
    let scene: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("scene.json")).unwrap()).unwrap();
    let px = scene["flying_height_m"].as_f64().unwrap() / scene["base_m"].as_f64().unwrap()
        * scene["gsd_m"].as_f64().unwrap();
    let truth = read_geotiff(&dir.join("truth_dem.tif")).unwrap();
    let dem = read_geotiff(&out.join("dem.tif")).unwrap();
    let sigma = first_of_two_bands(&out.join("quality.tif"));
    assert_eq!(sigma.len(), dem.z.len());
    let views = views(&dir, &scene);
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
    (f, report)
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

fn assert_goals(name: &str, method: &str) -> Value {
    let (f, report) = measure_with_report(name, method);
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
    report
}

#[test]
fn sweep_on_the_lidar_scene() {
    assert_goals("lidar-banks", "sweep");
}

#[test]
fn sweep_on_the_wide_angle_scene() {
    assert_goals("jacksboro-wide", "sweep");
}

#[test]
fn sweep_on_the_noisy_close_scene() {
    assert_goals("jacksboro-close", "sweep");
}

#[test]
fn mgcm_on_the_lidar_scene() {
    assert_goals("lidar-banks", "mgcm");
}

#[test]
fn mgcm_on_the_wide_angle_scene() {
    assert_goals("jacksboro-wide", "mgcm");
}

#[test]
fn mgcm_on_the_noisy_close_scene() {
    assert_goals("jacksboro-close", "mgcm");
}

/// The object-space matching (seed 001) on the 1 m lidar scene: the project's 1 m posts hold
/// fewer than its minimum of groundels (of about a ground pixel, 0.35 m), so it puts its posts
/// at a multiple of cell_m and says so, in report.json and in a warning, instead of refusing.
#[test]
fn oslsm_on_the_lidar_scene() {
    let report = assert_goals("lidar-banks", "oslsm");
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
fn oslsm_on_the_wide_angle_scene() {
    let report = assert_goals("jacksboro-wide", "oslsm");
    // The project's 80 m posts hold enough groundels: kept.
    assert_eq!(report["post_m"], report["asked_post_m"]);
}

#[test]
fn oslsm_on_the_noisy_close_scene() {
    assert_goals("jacksboro-close", "oslsm");
}
