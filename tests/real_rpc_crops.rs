//! Issue 36: crops of real satellite products, as crop tools hand them out, through `rig dtm`.
//!
//! No real satellite image can be stored here, so the images are rendered: `rig sim scene
//! --sensor rpc` takes the real RPCs of a Pléiades 1B tri-stereo acquisition over Gizeh
//! (tests/data/rpc/gizeh_img{1,2,3}_RPC.TXT, GDAL's reading of CNES/cars' test data; see the
//! README there), lays a real 1 m lidar DEM under the views' common ground, and renders a crop
//! of each product around it through the product's RPCs (the simulator's own RPC evaluation,
//! inversion, UTM and terrain intersection). Each crop's RPCs are only in its TIFF tag, in the
//! crop-tool form: the product's LINE_OFF/SAMP_OFF kept, the crop's corner folded into the
//! numerators. Checked against independent truth: GDAL reads the tag and puts the
//! simulator's noise-free points on the same pixels; the DSM `rig dtm` writes from the crops
//! as they come agrees with the simulator's terrain.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

fn rpc(n: u32) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("tests/data/rpc/gizeh_img{n}_RPC.TXT"))
}

/// `rig sim scene --sensor rpc` of the products `views` (1–3: the triplet's images), `size`
/// px crops, σ = 100 grey values of noise, `cps` noise-free points.
fn scene(dir: &Path, views: &[u32], size: usize, cps: usize) -> PathBuf {
    let mut args: Vec<String> = [
        "--sensor",
        "rpc",
        "--noise-dn",
        "100",
        "--seed",
        "3",
        "--size",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    args.push(size.to_string());
    args.push("--cps".into());
    args.push(cps.to_string());
    for &v in views {
        args.push("--rpc".into());
        args.push(rpc(v).display().to_string());
    }
    let a: Vec<&str> = args.iter().map(String::as_str).collect();
    common::sim_scene(dir, &a)
}

/// A noise-free point of truth_points.csv: ground in the scene's CRS, the crop, and the
/// crop's (sample, line) with (0, 0) at the centre of its first pixel.
struct Point {
    id: String,
    ground: [f64; 3],
    photo: String,
    pixel: [f64; 2],
}

fn points(scene: &Path) -> Vec<Point> {
    let text = std::fs::read_to_string(scene.join("truth_points.csv")).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("id,kind,x,y,z,photo,col,row"));
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let n = |k: usize| f[k].parse::<f64>().unwrap();
            Point {
                id: f[0].into(),
                ground: [n(2), n(3), n(4)],
                photo: f[5].into(),
                pixel: [n(6), n(7)],
            }
        })
        .collect()
}

fn truth(scene: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(scene.join("truth.json")).unwrap()).unwrap()
}

/// `gdalinfo`'s RPC metadata of an image: KEY → value.
fn gdal_rpc_metadata(image: &Path) -> std::collections::BTreeMap<String, String> {
    let o = common::run_ok(Command::new("gdalinfo").arg(image));
    let text = String::from_utf8_lossy(&o.stdout).into_owned();
    let block = text
        .split("RPC Metadata:")
        .nth(1)
        .unwrap_or_else(|| panic!("gdalinfo shows no RPC metadata for {}", image.display()));
    block
        .lines()
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.trim().split_once('='))
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
}

/// `gdaltransform -rpc -i -t_srs CRS image`: the pixels GDAL finds for ground points given in
/// the scene's CRS (GDAL's own conversion to WGS 84, then the image's RPC tag).
fn gdal_pixels(image: &Path, crs: &str, ground: &[[f64; 3]]) -> Vec<[f64; 2]> {
    common::gdaltransform(&["-rpc", "-i", "-t_srs", crs], image, ground)
        .iter()
        .map(|v| [v[0], v[1]])
        .collect()
}

/// GDAL reads each crop's TIFF tag as the crop tool's form (the product's LINE_OFF and
/// SAMP_OFF, as GDAL read them from the product's _RPC.TXT; the numerators' constant terms
/// moved), with no _RPC.TXT beside the crop, and `gdaltransform -rpc` maps every noise-free
/// point to the crop's pixel where the simulator put it (GDAL's pixel/line + 0.5 from the
/// centre-of-pixel convention).
#[test]
fn gdal_reads_the_crops_tags_with_the_products_offsets_kept() {
    if !common::gdal_tools() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let scene = scene(d.path(), &[2, 3], 200, 60);
    let crs = truth(&scene)["crs"].as_str().unwrap().to_string();
    assert_eq!(crs, "EPSG:32636", "Gizeh lies in UTM zone 36N");
    let pts = points(&scene);
    assert_eq!(pts.len(), 2 * 60);
    let mut worst: f64 = 0.0;
    for (k, product) in [(1, 2), (2, 3)] {
        let name = format!("img_{k:02}");
        let image = scene.join(format!("{name}.tif"));
        assert!(
            !scene.join(format!("{name}_RPC.TXT")).exists()
                && !scene.join(format!("{name}_rpc.txt")).exists()
                && !scene.join(format!("{name}.RPB")).exists(),
            "{name}: the RPCs must come from the tag alone"
        );
        // The product's numbers as GDAL reads its _RPC.TXT (beside a stand-in image).
        let stand_in = d.path().join(format!("product{product}.tif"));
        rig::digitise::output::write_tiff16(&stand_in, 16, 16, &[1000u16; 256]).unwrap();
        std::fs::copy(
            rpc(product),
            d.path().join(format!("product{product}_RPC.TXT")),
        )
        .unwrap();
        let (crop, full) = (gdal_rpc_metadata(&image), gdal_rpc_metadata(&stand_in));
        for key in [
            "LINE_OFF",
            "SAMP_OFF",
            "LINE_SCALE",
            "SAMP_SCALE",
            "LAT_OFF",
            "LONG_OFF",
        ] {
            assert_eq!(crop[key], full[key], "{name}: {key}");
        }
        assert_eq!(crop["LINE_DEN_COEFF"], full["LINE_DEN_COEFF"], "{name}");
        assert_ne!(crop["LINE_NUM_COEFF"], full["LINE_NUM_COEFF"], "{name}");
        assert_ne!(crop["SAMP_NUM_COEFF"], full["SAMP_NUM_COEFF"], "{name}");
        let mine: Vec<&Point> = pts.iter().filter(|p| p.photo == name).collect();
        let ground: Vec<[f64; 3]> = mine.iter().map(|p| p.ground).collect();
        let got = gdal_pixels(&image, &crs, &ground);
        assert_eq!(got.len(), mine.len());
        for (p, g) in mine.iter().zip(&got) {
            let e = (g[0] - 0.5 - p.pixel[0]).hypot(g[1] - 0.5 - p.pixel[1]);
            worst = worst.max(e);
            assert!(
                e < 1e-3,
                "{name} {}: GDAL ({:.5}, {:.5}) − 0.5 against the simulator's ({:.5}, {:.5})",
                p.id,
                g[0],
                g[1],
                p.pixel[0],
                p.pixel[1]
            );
            // Inside the crop: the offsets kept did not send GDAL to the product's pixels.
            assert!((0.0..200.0).contains(&g[0]) && (0.0..200.0).contains(&g[1]));
        }
    }
    eprintln!(
        "gdaltransform -rpc on the crops' tags: {} points within {worst:.1e} px of the simulator's",
        pts.len()
    );
}

/// The DSM `rig dtm` writes at a grid's node nearest (x, y) and its bilinear height there
/// (`None` where a corner has no height).
fn dsm_at(dem: &rig::matching::grid::ElevationGrid, x: f64, y: f64) -> Option<f64> {
    let fx = (x - dem.x0) / dem.cell_m;
    let fy = (dem.y0 - y) / dem.cell_m;
    let (c, r) = (fx.floor(), fy.floor());
    if c < 0.0 || r < 0.0 || c + 1.0 >= dem.cols as f64 || r + 1.0 >= dem.rows as f64 {
        return None;
    }
    let (c, r) = (c as usize, r as usize);
    let (tx, ty) = (fx - c as f64, fy - r as f64);
    let z = |c: usize, r: usize| dem.z[r * dem.cols + c] as f64;
    let q = [z(c, r), z(c + 1, r), z(c, r + 1), z(c + 1, r + 1)];
    if q.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let top = q[0] + tx * (q[1] - q[0]);
    let bot = q[2] + tx * (q[3] - q[2]);
    Some(top + ty * (bot - top))
}

/// `rig dtm` on the crops as they come (block.toml: `rpc = "img_0N.tif"`, an EPSG UTM CRS,
/// no control points) writes a DSM whose RMSE against the simulator's true DEM, in pixels of
/// parallax of the pair (the widest of a triplet), is within the sweep's 0.25 px goal; so is
/// the RMSE at the simulator's noise-free points (spread evenly where every crop sees the
/// ground) against their true heights, and the DSM holds a height at most of them.
#[test]
fn rig_dtm_on_the_crops_as_they_come_writes_the_dsm_within_a_quarter_pixel() {
    let d = tempfile::tempdir().unwrap();
    // The pair at the 500 px; the triplet smaller, to keep the test quick.
    for (name, views, size) in [("pair", vec![2, 3], 500), ("triplet", vec![1, 2, 3], 400)] {
        let dir = d.path().join(name);
        std::fs::create_dir_all(&dir).unwrap();
        let scene = scene(&dir, &views, size, 400);
        let block = std::fs::read_to_string(scene.join("block.toml")).unwrap();
        assert!(
            block.contains("crs = \"EPSG:32636\"")
                && block.contains("rpc = \"img_01.tif\"")
                && !block.contains("[points]"),
            "{block}"
        );
        let t = truth(&scene);
        // The widest pair's pixels of parallax per metre, from the simulator's projection of
        // the common point at two heights through the crops' RPCs.
        let px_per_m = t["parallax"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["px_per_m"].as_f64().unwrap())
            .fold(0.0, f64::max);
        assert!((0.28..0.31).contains(&px_per_m), "{name}: {px_per_m}");
        let out = d.path().join(format!("{name}-dtm"));
        let r = common::dtm_json(&scene.join("block.toml"), &out);
        let c = &r["comparison"];
        let rmse = c["rmse_m"].as_f64().unwrap();
        let nodes = c["nodes"].as_u64().unwrap();
        let dem = rig::matching::products::files::read_geotiff(&out.join("dem.tif")).unwrap();
        let pts = points(&scene);
        let first = &pts[0].photo;
        let ground: Vec<[f64; 3]> = pts
            .iter()
            .filter(|p| &p.photo == first)
            .map(|p| p.ground)
            .collect();
        assert_eq!(ground.len(), 400, "{name}");
        let errors: Vec<f64> = ground
            .iter()
            .filter_map(|g| dsm_at(&dem, g[0], g[1]).map(|z| z - g[2]))
            .collect();
        let coverage = errors.len() as f64 / ground.len() as f64;
        let rmse_points =
            (errors.iter().map(|e| e * e).sum::<f64>() / errors.len().max(1) as f64).sqrt();
        let g = &r["grid"];
        let filled = r["grid_filled"].as_f64().unwrap()
            / (g["cols"].as_f64().unwrap() * g["rows"].as_f64().unwrap());
        eprintln!(
            "{name}: RMSE {rmse:.3} m = {:.3} px of parallax ({px_per_m:.3} px/m) over {nodes} nodes of 1 m, a height at {:.1} % of the DEM's nodes; at the {} noise-free points: {rmse_points:.3} m = {:.3} px, a height at {:.1} % of them",
            rmse * px_per_m,
            100.0 * filled,
            ground.len(),
            rmse_points * px_per_m,
            100.0 * coverage
        );
        assert!(rmse * px_per_m <= 0.25, "{name}: {rmse} m");
        assert!(rmse_points * px_per_m <= 0.25, "{name}: {rmse_points} m");
        // The DEM's default extent is a north-up rectangle mostly inside the overlap (95 % of
        // it seen by a pair), and it holds a height nearly everywhere; the crops are turned
        // 13° from north, so a rectangle wholly inside holds about 70 % of their common ground
        // (a square turned θ keeps 1/(cos θ + sin θ)² of itself), one 95 % inside about 78 %.
        assert!(filled >= 0.9, "{name}: {filled}");
        assert!(coverage >= 0.6, "{name}: {coverage}");
    }
}

/// Bad `--sensor rpc` scenes are refused before anything is written, naming the flag.
#[test]
fn bad_rpc_scenes_are_refused_by_flag() {
    let d = tempfile::tempdir().unwrap();
    let (r1, r2) = (rpc(1).display().to_string(), rpc(2).display().to_string());
    let missing = d.path().join("none_RPC.TXT").display().to_string();
    for (args, want) in [
        (vec!["--rpc", r1.as_str()], "--rpc 2 to 5 times"),
        (
            vec!["--rpc", r1.as_str(), "--rpc", r2.as_str(), "--size", "10"],
            "--size 10: 64 to 4000",
        ),
        (
            vec!["--rpc", r1.as_str(), "--rpc", r2.as_str(), "--size", "1500"],
            "--size 1500: view 1: a crop of 1500 px sees ground",
        ),
        (
            vec!["--rpc", r1.as_str(), "--rpc", missing.as_str()],
            "none_RPC.TXT",
        ),
        (
            vec!["--rpc", r1.as_str(), "--rpc", r2.as_str(), "--gains", "1"],
            "1 values for 2 photos",
        ),
    ] {
        let args: Vec<&str> = ["--sensor", "rpc"].into_iter().chain(args).collect();
        common::sim_scene_refused(d.path(), &args, want);
    }
}

/// A project whose RPCs are wrong is refused, and the refusal helps to find why: a truncated
/// RPC file names the file and the missing term; another product's RPCs, or heights far above
/// the terrain, end in "no overlap" only once each photo's footprint exists, and the message
/// says where each photo sees the ground (the operator can tell a photo of somewhere else from
/// a wrong height).
#[test]
fn wrong_rpcs_and_heights_are_refused_saying_where_each_photo_sees() {
    let d = tempfile::tempdir().unwrap();
    let scene = scene(d.path(), &[1, 2], 200, 10);
    let block = std::fs::read_to_string(scene.join("block.toml")).unwrap();
    let rpb = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/rpc/md_dg.RPB");
    let full = std::fs::read_to_string(rpc(2)).unwrap();
    std::fs::write(scene.join("cut_RPC.TXT"), &full[..400]).unwrap();
    for (name, edit, want) in [
        (
            "truncated",
            block.replace("rpc = \"img_02.tif\"", "rpc = \"cut_RPC.TXT\""),
            vec!["cut_RPC.TXT", "is missing", "img_02"],
        ),
        (
            "another product",
            block.replace(
                "rpc = \"img_02.tif\"",
                &format!("rpc = {:?}", rpb.display().to_string()),
            ),
            vec![
                "no two photos overlap",
                "`img_01` sees x 3",
                "`img_02` sees x -1",
            ],
        ),
        (
            "heights above the terrain",
            block.replace("heights = [", "heights = [5000.0, 5100.0] # ["),
            vec!["at 5050 m", "`img_01` sees x 3", "`img_02` sees x 3"],
        ),
    ] {
        assert_ne!(edit, block, "{name}");
        let p = scene.join(format!("{}.toml", name.replace(' ', "-")));
        std::fs::write(&p, edit).unwrap();
        let out = d.path().join(format!("{name}-dtm"));
        let o = common::rig()
            .arg("dtm")
            .arg(&p)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{name}: {err}");
        for w in want {
            assert!(err.contains(w), "{name}: wants {w:?} in {err}");
        }
        assert!(!out.join("dem.tif").exists(), "{name}");
    }
}
