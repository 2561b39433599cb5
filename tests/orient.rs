//! `rig orient` on a block a renderer that is not ours made (tests/data/validation/blocks), judged
//! as that renderer's judge judges it: the check points (points whose ground the block never
//! sees, kept in truth.json) intersected here from their image observations with the oriented
//! photos, by the scene's own conventions (not the rig's sensors), against their true ground.
//! The goal: within the true orientation's figures + 25 %, which this test measures too.

mod common;

use nalgebra::{Matrix3, Vector3};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn block_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/validation/blocks/jacksboro-block")
}

/// R = R_ω R_φ R_κ (scene.json's conventions), angles in degrees.
fn rotation(a: [f64; 3]) -> Matrix3<f64> {
    let [o, p, k] = a.map(f64::to_radians);
    let rw = Matrix3::new(1.0, 0.0, 0.0, 0.0, o.cos(), -o.sin(), 0.0, o.sin(), o.cos());
    let rp = Matrix3::new(p.cos(), 0.0, p.sin(), 0.0, 1.0, 0.0, -p.sin(), 0.0, p.cos());
    let rk = Matrix3::new(k.cos(), -k.sin(), 0.0, k.sin(), k.cos(), 0.0, 0.0, 0.0, 1.0);
    rw * rp * rk
}

type Photos = BTreeMap<String, (Vector3<f64>, Matrix3<f64>)>;
/// A ray: the projection centre and its direction.
type Ray = (Vector3<f64>, Vector3<f64>);

fn photos_of_toml(path: &Path) -> Photos {
    let t: toml::Table = std::fs::read_to_string(path).unwrap().parse().unwrap();
    let num = |v: &toml::Value| v.as_float().or(v.as_integer().map(|i| i as f64)).unwrap();
    t["photo"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let pos: Vec<f64> = p["position"].as_array().unwrap().iter().map(num).collect();
            let ang: Vec<f64> = p["angles_deg"]
                .as_array()
                .unwrap()
                .iter()
                .map(num)
                .collect();
            (
                p["id"].as_str().unwrap().to_string(),
                (
                    Vector3::new(pos[0], pos[1], pos[2]),
                    rotation([ang[0], ang[1], ang[2]]),
                ),
            )
        })
        .collect()
}

/// Check points' XY and Z RMSE (m) with `photos`: each point's rays (W = H = 300, p = 0.8 mm,
/// f = 153 mm, principal point 0) intersected by least squares, the nearest point to all rays.
fn check_rmse(photos: &Photos, points_csv: &str) -> (f64, f64, usize) {
    let truth: Value =
        serde_json::from_str(&std::fs::read_to_string(block_dir().join("truth.json")).unwrap())
            .unwrap();
    let mut rays: BTreeMap<String, Vec<Ray>> = BTreeMap::new();
    for line in points_csv.lines().skip(1) {
        let c: Vec<&str> = line.split(',').collect();
        if truth["points"][c[0]]["kind"] != "cp" {
            continue;
        }
        let (col, row): (f64, f64) = (c[6].parse().unwrap(), c[7].parse().unwrap());
        let (x, y) = ((col - 149.5) * 0.8, (149.5 - row) * 0.8);
        let (centre, r) = photos[c[5]];
        rays.entry(c[0].to_string())
            .or_default()
            .push((centre, (r * Vector3::new(x, y, -153.0)).normalize()));
    }
    let (mut sxy, mut sz, mut n) = (0.0, 0.0, 0);
    for (id, rs) in &rays {
        if rs.len() < 2 {
            continue;
        }
        let (mut a, mut b) = (Matrix3::zeros(), Vector3::zeros());
        for (c, d) in rs {
            let m = Matrix3::identity() - d * d.transpose();
            a += m;
            b += m * c;
        }
        let x = a.try_inverse().unwrap() * b;
        let t: Vec<f64> = truth["points"][id]["xyz"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        sxy += (x.x - t[0]).powi(2) + (x.y - t[1]).powi(2);
        sz += (x.z - t[2]).powi(2);
        n += 1;
    }
    ((sxy / n as f64).sqrt(), (sz / n as f64).sqrt(), n)
}

fn truth_photos() -> Photos {
    let truth: Value =
        serde_json::from_str(&std::fs::read_to_string(block_dir().join("truth.json")).unwrap())
            .unwrap();
    truth["photos"]
        .as_object()
        .unwrap()
        .iter()
        .map(|(id, v)| {
            let f = |k: &str| -> Vec<f64> {
                v[k].as_array()
                    .unwrap()
                    .iter()
                    .map(|x| x.as_f64().unwrap())
                    .collect()
            };
            let (p, a) = (f("position"), f("angles_deg"));
            (
                id.clone(),
                (Vector3::new(p[0], p[1], p[2]), rotation([a[0], a[1], a[2]])),
            )
        })
        .collect()
}

/// Orients `project` into a temporary folder; the oriented photos and the report.
fn orient(project: &Path) -> (Photos, Value, tempfile::TempDir) {
    let out = tempfile::tempdir().unwrap();
    common::run_ok(
        common::rig()
            .args(["orient", "--json"])
            .arg(project)
            .arg("--out")
            .arg(out.path()),
    );
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(out.path().join("report.json")).unwrap())
            .unwrap();
    (
        photos_of_toml(&out.path().join("project.toml")),
        report,
        out,
    )
}

/// The block with the given points, and with its control points alone (every tie point the
/// rig's own): all eight photos oriented, the check points within the true orientation's
/// RMSE + 25 % (measured here with the true orientation, the yardstick), and `rig dtm` can
/// read the oriented project.
#[test]
fn the_validation_block_is_oriented_to_within_the_true_orientations_figures() {
    let points = std::fs::read_to_string(block_dir().join("points.csv")).unwrap();
    let (txy, tz, tn) = check_rmse(&truth_photos(), &points);
    assert_eq!(tn, 55);
    // The renderer's README: 1.34 / 2.11 m with the true orientation.
    assert!(
        (txy - 1.34).abs() < 0.05 && (tz - 2.11).abs() < 0.05,
        "the yardstick itself: {txy:.2} / {tz:.2}"
    );
    // With the given points.
    let (photos, report, out) = orient(&block_dir().join("project.toml"));
    assert_eq!(photos.len(), 8);
    let (xy, z, _) = check_rmse(&photos, &points);
    println!("given points: check points XY {xy:.2} m, Z {z:.2} m (truth {txy:.2} / {tz:.2}); {} tie points, σ̂₀ {}", report["tie_points"], report["sigma0"]);
    assert!(
        xy <= 1.25 * txy && z <= 1.25 * tz,
        "XY {xy:.2} Z {z:.2} against {txy:.2} / {tz:.2} + 25 %"
    );
    assert!(
        report["tie_points"].as_u64().unwrap() > 300,
        "the rig's own tie points: {}",
        report["tie_points"]
    );
    // The oriented project is a project `rig dtm` and `rig orient` read (paths relative to it).
    let t: toml::Table = std::fs::read_to_string(out.path().join("project.toml"))
        .unwrap()
        .parse()
        .unwrap();
    let img = t["photo"][0]["image"].as_str().unwrap();
    assert!(
        out.path().join(img).exists(),
        "{img} from {}",
        out.path().display()
    );
    rig::matching::project::Project::load(&out.path().join("project.toml")).unwrap();
    // With the control points alone.
    let dir = tempfile::tempdir().unwrap();
    for e in std::fs::read_dir(block_dir()).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), dir.path().join(e.file_name())).unwrap();
    }
    let gcp_only: String = points
        .lines()
        .filter(|l| !l.contains(",tie,"))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(dir.path().join("points.csv"), gcp_only).unwrap();
    let (photos, report, _out) = orient(&dir.path().join("project.toml"));
    let (xy, z, _) = check_rmse(&photos, &points);
    println!(
        "control points only: check points XY {xy:.2} m, Z {z:.2} m; {} tie points",
        report["tie_points"]
    );
    assert!(
        xy <= 1.25 * txy && z <= 1.25 * tz,
        "XY {xy:.2} Z {z:.2} against {txy:.2} / {tz:.2} + 25 %"
    );
}

/// Bad blocks: an error naming the cause, exit code not 0, and nothing written.
#[test]
fn bad_blocks_are_refused_by_name_and_nothing_is_written() {
    let points = std::fs::read_to_string(block_dir().join("points.csv")).unwrap();
    let gcps: Vec<&str> = {
        let mut v: Vec<&str> = points
            .lines()
            .filter(|l| l.contains(",gcp,"))
            .map(|l| l.split(',').next().unwrap())
            .collect();
        v.dedup();
        v
    };
    let cases: Vec<(String, &str)> = vec![
        // Two control points: as tie points the others.
        (
            points
                .lines()
                .map(|l| {
                    let id = l.split(',').next().unwrap();
                    if gcps[2..].contains(&id) {
                        let c: Vec<&str> = l.split(',').collect();
                        format!("{},tie,,,,{},{},{}\n", c[0], c[5], c[6], c[7])
                    } else {
                        format!("{l}\n")
                    }
                })
                .collect(),
            "at least 3",
        ),
        // A point outside its photo.
        (
            format!("{points}X1,gcp,745000,4053000,500,3,400.0,20.0\n"),
            "outside its image",
        ),
        // Photo 4 with no observation at all and no tie points of the rig's (its image is
        // blank): it shares no point.
        (
            points
                .lines()
                .filter(|l| l.split(',').nth(5) != Some("4"))
                .map(|l| format!("{l}\n"))
                .collect(),
            "shares no tie point",
        ),
    ];
    for (k, (csv, says)) in cases.iter().enumerate() {
        let dir = tempfile::tempdir().unwrap();
        for e in std::fs::read_dir(block_dir()).unwrap() {
            let e = e.unwrap();
            std::fs::copy(e.path(), dir.path().join(e.file_name())).unwrap();
        }
        std::fs::write(dir.path().join("points.csv"), csv).unwrap();
        if k == 2 {
            // A blank photo 4: no texture, no tie point found in it.
            let img = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_pixel(
                300,
                300,
                image::Luma([30000]),
            );
            img.save(dir.path().join("photo_4.tif")).unwrap();
        }
        // `rig orient`, and `rig dtm` (which orients such a block first): the cause, and
        // nothing written.
        let refused = |command: &str| {
            let out = dir.path().join(command);
            let o = common::rig()
                .arg(command)
                .arg(dir.path().join("project.toml"))
                .arg("--out")
                .arg(&out)
                .output()
                .unwrap();
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(
                !o.status.success() && err.contains(says),
                "case {k}, rig {command}: {err}"
            );
            out
        };
        let out = refused("orient");
        assert!(
            !out.join("project.toml").exists(),
            "case {k}: wrote a project"
        );
        let out = refused("dtm");
        assert!(
            !out.join("orientation").exists() && !out.join("dem.tif").exists(),
            "case {k}: rig dtm wrote"
        );
    }
}

/// A copy of the block with `edit` applied to its project's text (paths stay beside it).
fn block_copy(edit: &dyn Fn(&str) -> String) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    for e in std::fs::read_dir(block_dir()).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), dir.path().join(e.file_name())).unwrap();
    }
    let p = dir.path().join("project.toml");
    let mut perm = std::fs::metadata(&p).unwrap().permissions();
    #[allow(clippy::permissions_set_readonly_false)]
    perm.set_readonly(false);
    std::fs::set_permissions(&p, perm).unwrap();
    std::fs::write(&p, edit(&std::fs::read_to_string(&p).unwrap())).unwrap();
    dir
}

/// `rig dtm` on the block of approximations orients it first (DIR/orientation/: the oriented
/// project, its covariance and report, as `rig orient` writes them), matches the oriented
/// block, and carries the orientations' covariance into the heights' σ. Judged against the
/// renderer's truth: the same project with the true orientations (and the same heights)
/// gives a model within 0.1 px of parallax of this one (the base 1200 m over a flying height
/// of 1912 m at 10 m pixels: 0.1 px is 1.6 m of height), and the model's heights at the 60
/// check points of truth.json, ground the block never saw, are within a few metres.
#[test]
fn rig_dtm_orients_a_block_of_approximations_first() {
    let out = tempfile::tempdir().unwrap();
    let dtm = out.path().join("dtm");
    let r = common::dtm_json(&block_dir().join("project.toml"), &dtm);
    let folder = dtm.join("orientation");
    for f in [
        "project.toml",
        "covariance.csv",
        "points.csv",
        "report.json",
        "report.html",
    ] {
        assert!(folder.join(f).exists(), "{f} in {}", folder.display());
    }
    let oriented = rig::matching::project::Project::load(&folder.join("project.toml")).unwrap();
    assert!(oriented.orientation_covariance.is_some());
    let heights = oriented.heights.expect("heights from the tie points");
    // The tie points reach where the 5 control points (334 … 628 m with their margin) do not.
    assert!(heights[0] < 330.0 && heights[1] > 940.0, "{heights:?}");
    let orientation_sigma = r["orientation_sigma_m"]
        .as_f64()
        .expect("the orientations' σ");
    assert!(orientation_sigma > 0.05, "{orientation_sigma}");
    // The true orientations, the same heights.
    let truth: Value =
        serde_json::from_str(&std::fs::read_to_string(block_dir().join("truth.json")).unwrap())
            .unwrap();
    let true_block = block_copy(&|text: &str| {
        let mut s = String::new();
        let mut id = String::new();
        for line in text.lines() {
            if let Some(v) = line.strip_prefix("id = ") {
                id = v.trim_matches('"').to_string();
            }
            let t = &truth["photos"][&id];
            if line.starts_with("position_sigma_m") || line.starts_with("angles_sigma_deg") {
                continue;
            } else if line.starts_with("position =") {
                s += &format!("position = {}\n", t["position"]);
            } else if line.starts_with("angles_deg =") {
                s += &format!("angles_deg = {}\n", t["angles_deg"]);
            } else if line.starts_with("cell_m") {
                s += &format!("{line}\nheights = [{}, {}]\n", heights[0], heights[1]);
            } else {
                s += &format!("{line}\n");
            }
        }
        s
    });
    let true_dtm = out.path().join("true");
    common::dtm_json(&true_block.path().join("project.toml"), &true_dtm);
    let read = |d: &Path| rig::matching::products::files::read_geotiff(&d.join("dem.tif")).unwrap();
    let (a, b) = (read(&dtm), read(&true_dtm));
    let per_px = 1200.0 / 1912.5 / 10.0;
    let d: Vec<f64> = (0..a.rows)
        .flat_map(|r| (0..a.cols).map(move |c| (c, r)))
        .filter_map(|(c, r)| {
            let [x, y] = a.node(c, r);
            let (za, zb) = (a.z[r * a.cols + c] as f64, b.interpolate(x, y));
            (za.is_finite() && zb.is_finite()).then_some((za - zb) * per_px)
        })
        .collect();
    assert!(d.len() > 1500, "{} nodes in both", d.len());
    let mean = d.iter().sum::<f64>() / d.len() as f64;
    let rms = (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt();
    println!("oriented − true orientation: mean {mean:+.3} px, RMS {rms:.3} px of parallax over {} nodes", d.len());
    assert!(
        mean.abs() <= 0.1 && rms <= 0.1,
        "mean {mean:.3} RMS {rms:.3} px"
    );
    // Against the renderer's truth DEM: coverage of its posts that two photos see (the true
    // orientations, the scene's conventions), and the model's σ (quality.tif) against its
    // errors.
    let tq =
        rig::matching::products::files::read_geotiff(&block_dir().join("truth_dem.tif")).unwrap();
    let photos = truth_photos();
    let (mut seen2, mut covered) = (0usize, 0usize);
    for r in 0..tq.rows {
        for c in 0..tq.cols {
            let [x, y] = tq.node(c, r);
            let g = Vector3::new(x, y, tq.z[r * tq.cols + c] as f64);
            let seen = photos
                .values()
                .filter(|(centre, rot)| {
                    let u = rot.transpose() * (g - centre);
                    let (px, py) = (-153.0 * u.x / u.z, -153.0 * u.y / u.z);
                    u.z < 0.0 && px.abs() < 116.0 && py.abs() < 116.0
                })
                .count();
            if seen >= 2 {
                seen2 += 1;
                covered += usize::from(a.node_index(x, y).is_some_and(|k| a.z[k].is_finite()));
            }
        }
    }
    let coverage = covered as f64 / seen2 as f64;
    // quality.tif: band 1 σ (m), band 2 the correlation, interleaved.
    let mut d = tiff::decoder::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(dtm.join("quality.tif")).unwrap(),
    ))
    .unwrap();
    let tiff::decoder::DecodingResult::F32(q) = d.read_image().unwrap() else {
        panic!("quality.tif is not float32");
    };
    assert_eq!(q.len(), 2 * a.z.len());
    let (mut e2, mut n) = (0.0, 0usize);
    for k in 0..a.z.len() {
        let [x, y] = a.node(k % a.cols, k / a.cols);
        let (z, s, zt) = (a.z[k] as f64, q[2 * k] as f64, tq.interpolate(x, y));
        if z.is_finite() && s > 0.0 && zt.is_finite() {
            e2 += ((z - zt) / s).powi(2);
            n += 1;
        }
    }
    let normalised = (e2 / n as f64).sqrt();
    println!(
        "against the truth DEM: {:.1} % of the {seen2} posts two photos see covered; RMS(error/σ) {normalised:.2} over {n} nodes",
        100.0 * coverage
    );
    assert!(coverage >= 0.8, "coverage {coverage:.3}");
    assert!(
        (0.8..=1.25).contains(&normalised),
        "RMS(error/σ) {normalised:.2}"
    );
    // The check points' ground.
    let e: Vec<f64> = truth["points"]
        .as_object()
        .unwrap()
        .values()
        .filter_map(|p| {
            let g: Vec<f64> = p["xyz"]
                .as_array()?
                .iter()
                .filter_map(Value::as_f64)
                .collect();
            let z = a.interpolate(g[0], g[1]);
            z.is_finite().then_some(z - g[2])
        })
        .collect();
    let rmse = (e.iter().map(|v| v * v).sum::<f64>() / e.len() as f64).sqrt();
    println!("model at {} check points: RMSE {rmse:.2} m", e.len());
    assert!(
        e.len() >= 30 && rmse < 4.0,
        "{} points, RMSE {rmse:.2} m",
        e.len()
    );
}

/// `[orientation] refraction` and `earth_curvature` are taken (the displacements at this
/// block's 1:12 500 are below 0.02 px, so the check points keep their figures) and kept in the
/// oriented project, beside its covariance, for the matchers.
#[test]
fn refraction_and_curvature_keys_are_taken_and_kept() {
    let dir = block_copy(&|t: &str| {
        format!("{t}\n[orientation]\nrefraction = true\nearth_curvature = true\n")
    });
    let (photos, _, out) = orient(&dir.path().join("project.toml"));
    let points = std::fs::read_to_string(block_dir().join("points.csv")).unwrap();
    let (xy, z, _) = check_rmse(&photos, &points);
    let (txy, tz, _) = check_rmse(&truth_photos(), &points);
    assert!(xy <= 1.25 * txy && z <= 1.25 * tz, "XY {xy:.2} Z {z:.2}");
    let p = rig::matching::project::Project::load(&out.path().join("project.toml")).unwrap();
    assert!(p.radial.refraction && p.radial.earth_curvature);
    assert!(p.orientation_covariance.is_some());
}

/// Self-calibration on the renderer's block, given a camera 2 mm short of the renderer's
/// (153 mm, principal point 0, no distortion): `[orientation] self_calibration` with all four
/// finds the focal length, principal point and k₁, k₂ within 3 σ of the renderer's, each σ
/// small enough to mean something, writes them (with their σ) into the oriented project, and
/// the check points (adjusted as tie points with the calibrated camera; their ground kept in
/// truth.json) stay within the true orientation's figures + 25 %.
#[test]
fn self_calibration_finds_the_renderers_camera() {
    let dir = block_copy(&|t: &str| {
        format!(
            "{}\n[orientation]\nself_calibration = [\"focal\", \"principal_point\", \"k1\", \"k2\"]\n",
            t.replace("focal_mm = 153.0", "focal_mm = 151.0")
        )
    });
    let (_, report, out) = orient(&dir.path().join("project.toml"));
    let c = &report["cameras"][0];
    let f = |k: &str| c[k].as_f64().unwrap();
    let v = |k: &str, i: usize| c[k][i].as_f64().unwrap();
    let found = [
        (f("focal_mm") - 153.0, f("sigma_focal_mm"), 1.0),
        (
            v("principal_point_mm", 0),
            v("sigma_principal_point_mm", 0),
            0.4,
        ),
        (
            v("principal_point_mm", 1),
            v("sigma_principal_point_mm", 1),
            0.4,
        ),
        (v("distortion", 0), v("sigma_distortion", 0), 1e-3),
        (v("distortion", 1), v("sigma_distortion", 1), 1e-3),
    ];
    for (k, (err, sigma, useful)) in found.iter().enumerate() {
        assert!(
            err.abs() < 3.0 * sigma && *sigma > 0.0 && sigma < useful,
            "parameter {k}: error {err} σ {sigma} (useful below {useful}): {c}"
        );
    }
    let p = rig::matching::project::Project::load(&out.path().join("project.toml")).unwrap();
    let rig::matching::project::Source::Image { camera, .. } = &p.photos[0].source else {
        panic!("an image photo")
    };
    assert!((camera.focal_mm - f("focal_mm")).abs() < 1e-5);
    assert!((camera.lens.k1 - v("distortion", 0)).abs() < 1e-12);
    // Check points: the adjusted tie points whose ground truth.json keeps.
    let truth: Value =
        serde_json::from_str(&std::fs::read_to_string(block_dir().join("truth.json")).unwrap())
            .unwrap();
    let (mut sxy, mut sz, mut n) = (0.0, 0.0, 0);
    for line in std::fs::read_to_string(out.path().join("points.csv"))
        .unwrap()
        .lines()
        .skip(1)
    {
        let c: Vec<&str> = line.split(',').collect();
        let t = &truth["points"][c[0]];
        if t["kind"] != "cp" {
            continue;
        }
        let g: Vec<f64> = (0..3).map(|i| t["xyz"][i].as_f64().unwrap()).collect();
        let x: Vec<f64> = (2..5).map(|i| c[i].parse().unwrap()).collect();
        sxy += (x[0] - g[0]).powi(2) + (x[1] - g[1]).powi(2);
        sz += (x[2] - g[2]).powi(2);
        n += 1;
    }
    let (xy, z) = ((sxy / n as f64).sqrt(), (sz / n as f64).sqrt());
    let points = std::fs::read_to_string(block_dir().join("points.csv")).unwrap();
    let (txy, tz, _) = check_rmse(&truth_photos(), &points);
    println!("self-calibrated: {c}; check points XY {xy:.2} Z {z:.2} m over {n}");
    assert_eq!(n, 55);
    assert!(xy <= 1.25 * txy && z <= 1.25 * tz, "XY {xy:.2} Z {z:.2}");
}
