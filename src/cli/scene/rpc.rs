//! `rig sim scene --sensor rpc`: crops of real satellite products as crop tools hand them out,
//! rendered by the simulator through the products' real RPCs (`--rpc`, GDAL's `_RPC.TXT`)
//! over a real 1 m lidar DEM laid under their common ground: each crop `img_0N.tif` (16-bit
//! grey) with its RPCs in the TIFF tag 50844 only — the product's LINE_OFF/SAMP_OFF kept and the
//! crop's corner folded into the numerators — the true DEM (truth-dem.tif, in the area's UTM
//! zone), the noise-free points (truth_points.csv) and a format-2 project (block.toml) that
//! names the TIFFs as their own RPC files, with no control points.

use super::frame::{check_shared, scene_heights, to_grey, SceneArgs};
use crate::cli::usage::usage_bail;
use rig::geometry::Crs;
use rig::matching::grid::ElevationGrid;
use rig_sim::rpc::{Rpc00b, TIFF_TAG};
use rig_sim::rpc_scene::{RpcScene, SceneError, HEIGHT_MARGIN_M};
use serde_json::json;
use std::fmt::Write as _;

/// Crops' side by default, px (250 m at Pléiades' 0.5 m, inside the 400 m lidar DEM).
pub const RPC_SIZE: usize = 500;
/// truth-dem.tif's cell by default: the lidar DEM's own, m.
const RPC_TRUTH_CELL_M: f64 = 1.0;
/// The project's DEM cell, m: about two of the products' 0.5 m pixels.
const DEM_CELL_M: f64 = 1.0;

pub fn run(a: &SceneArgs) -> anyhow::Result<i32> {
    let size = a.size.unwrap_or(RPC_SIZE);
    if !(64..=4000).contains(&size) {
        usage_bail!("--size {size}: 64 to 4000 pixels");
    }
    if !(2..=5).contains(&a.rpc.len()) {
        usage_bail!(
            "--sensor rpc takes --rpc 2 to 5 times (one product's _RPC.TXT per view), not {}",
            a.rpc.len()
        );
    }
    if a.cps > 10_000 {
        usage_bail!("--cps {}: 0 to 10000", a.cps);
    }
    let views = a.rpc.len() as u32;
    let (gains, offsets) = check_shared(a, views)?;
    let truth_cell_m = a.truth_cell_m.unwrap_or(RPC_TRUTH_CELL_M);
    let products = a
        .rpc
        .iter()
        .map(|p| Rpc00b::load(p))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| anyhow::anyhow!("--rpc {e}"))?;
    let mut scene = RpcScene::new(products, size, a.seed).map_err(|e| match e {
        SceneError::TooLarge { .. } => anyhow::anyhow!("--size {size}: {e}"),
        e => anyhow::anyhow!("--rpc: {e}"),
    })?;
    scene.texture = a.texture.into();
    let epsg = scene.zone.epsg();
    let crs = Crs::Epsg(u16::try_from(epsg)?);
    // The ground every crop sees.
    let common = scene.common_ground(24)?;
    if common.len() < 16 {
        anyhow::bail!(
            "the crops hardly overlap ({} of 625 sample points of img_01 in all of them)",
            common.len()
        );
    }
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for g in &common {
        lo = [lo[0].min(g[0]), lo[1].min(g[1])];
        hi = [hi[0].max(g[0]), hi[1].max(g[1])];
    }
    let truth = truth_grid(&scene, [lo[0], lo[1], hi[0], hi[1]], truth_cell_m)?;
    let ([zmin, zmax], heights) =
        scene_heights(common.iter().map(|g| g[2]), &truth, HEIGHT_MARGIN_M);
    std::fs::create_dir_all(&a.out)?;
    for (k, v) in scene.views.iter().enumerate() {
        let name = format!("img_{:02}", v.number);
        let t = std::time::Instant::now();
        let img = scene.render(k, 3)?;
        let px = to_grey(
            &img,
            a.noise_dn,
            [offsets[k], gains[k]],
            0x9015E ^ v.number as u64 ^ scene.texture_seed,
            &name,
            [scene.t_min, scene.t_max],
        )?;
        // The crop's RPCs in the TIFF tag only, as a crop tool hands the crop out.
        rig::digitise::output::write_tiff16_tagged(
            &a.out.join(format!("{name}.tif")),
            size,
            size,
            &px,
            &[(TIFF_TAG, &v.crop.tag_values())],
        )?;
        eprintln!(
            "rendered {name}: {size}×{size} px from the product's sample {} and line {} ({:.1} s)",
            v.corner[0],
            v.corner[1],
            t.elapsed().as_secs_f64()
        );
    }
    // Noise-free points on the terrain where every crop sees them (the simulator's own
    // projection), in the crops' pixels: (0, 0) at the centre of the first pixel, as RPC00B.
    let mut rng = rig_sim::rng::Rng::new(a.seed ^ 0x6C9);
    let mut csv = String::from("id,kind,x,y,z,photo,col,row\n");
    let (mut made, mut tries) = (0usize, 0usize);
    while made < a.cps && tries < 100 * a.cps.max(1) {
        tries += 1;
        let x = lo[0] + rng.uniform() * (hi[0] - lo[0]);
        let y = lo[1] + rng.uniform() * (hi[1] - lo[1]);
        let g = [x, y, scene.dem.height(x, y)];
        let Some(seen) = scene.seen_by_all(g) else {
            continue;
        };
        made += 1;
        let [e, n] = scene.to_utm(x, y);
        for (v, q) in scene.views.iter().zip(&seen) {
            writeln!(
                csv,
                "cp{made},cp,{e:.6},{n:.6},{:.6},img_{:02},{:.6},{:.6}",
                g[2], v.number, q[0], q[1]
            )?;
        }
    }
    rig::atomic::write(&a.out.join("truth_points.csv"), csv.as_bytes())?;
    rig::matching::products::files::write_geotiff(&a.out.join("truth-dem.tif"), &truth, crs)?;
    let mut parallax = Vec::new();
    for i in 0..scene.views.len() {
        for j in i + 1..scene.views.len() {
            parallax.push(json!({
                "pair": [format!("img_{:02}", i + 1), format!("img_{:02}", j + 1)],
                "px_per_m": scene.parallax_px_per_m(i, j)
            }));
        }
    }
    let rpc_files: Vec<String> = a.rpc.iter().map(|p| p.display().to_string()).collect();
    rig::digitise::output::write_json(
        &a.out.join("truth.json"),
        &json!({"seed": a.seed, "sensor": "rpc", "crs": format!("EPSG:{epsg}"),
                "rpc_files": rpc_files, "scene": scene,
                "parallax": parallax, "terrain_m": [zmin, zmax], "heights_m": heights,
                "dem": format!("tests/data/lidar_dem_1m.tif (1 m lidar, heights + {} m), truth-dem.tif at {truth_cell_m} m", scene.height_shift_m),
                "noise_dn": a.noise_dn,
                "radiometry": {"gains": gains, "offsets_dn": offsets,
                    "grey": "offset + gain × 60000 × (t_min + (t_max − t_min) × reflectance) + noise"},
                "points": "truth_points.csv: noise-free, by the simulator's own projection through the crops' RPCs; x, y in the CRS, col, row with (0, 0) at the centre of the first pixel"}),
    )?;
    std::fs::write(
        a.out.join("block.toml"),
        block_toml(a.seed, &scene, epsg, heights),
    )?;
    for p in &parallax {
        eprintln!(
            "{} and {}: {:.3} px of parallax per metre",
            p["pair"][0].as_str().unwrap_or("?"),
            p["pair"][1].as_str().unwrap_or("?"),
            p["px_per_m"].as_f64().unwrap_or(f64::NAN)
        );
    }
    println!(
        "scene in {}: {} crops (img_0N.tif, their RPCs in the TIFF tag, the products' offsets kept), {made} noise-free points in truth_points.csv, truth-dem.tif (EPSG:{epsg}), block.toml (format 2)",
        a.out.display(),
        scene.views.len()
    );
    Ok(0)
}

/// The terrain on a square grid of `cell_m` in the scene's UTM zone over the local ground
/// rectangle `ground` (xmin, ymin, xmax, ymax) and 5 cells beyond it: the lidar's own
/// heights (shifted) at 1 m, whose nodes the scene puts on whole metres of the grid.
fn truth_grid(scene: &RpcScene, ground: [f64; 4], cell_m: f64) -> anyhow::Result<ElevationGrid> {
    let m = 5.0 * cell_m;
    let [x0, y0] = scene.to_utm(ground[0] - m, ground[1] - m);
    let [x1, y1] = scene.to_utm(ground[2] + m, ground[3] + m);
    let mut grid = ElevationGrid::covering(
        [x0, y0, x1, y1],
        cell_m,
        rig::matching::project::pair::default_memory_mb(),
    )?;
    for r in 0..grid.rows {
        for c in 0..grid.cols {
            let [e, n] = grid.node(c, r);
            let (x, y) = (e - scene.origin_m[0], n - scene.origin_m[1]);
            grid.z[r * grid.cols + c] = scene.dem.height(x, y) as f32;
        }
    }
    Ok(grid)
}

/// A format-2 project of the crops as they come: each TIFF its own RPC file, the area's UTM
/// zone, the terrain's heights with a margin, the true DEM as the reference, no points.
fn block_toml(seed: u64, scene: &RpcScene, epsg: u32, heights: [f64; 2]) -> String {
    let mut t = format!(
        "# The crops of `rig sim scene --sensor rpc --seed {seed}`: real products' RPCs in each TIFF's\n# RPC tag, as crop tools hand them out, and no control points. Run it with\n#   rig dtm block.toml --out OUT\nformat = 2\ncrs = \"EPSG:{epsg}\"\n"
    );
    for v in &scene.views {
        let _ = write!(
            t,
            "\n[[photo]]\nid = \"img_{0:02}\"\nimage = \"img_{0:02}.tif\"\nrpc = \"img_{0:02}.tif\"\n",
            v.number
        );
    }
    let _ = write!(
        t,
        "\n[dem]\ncell_m = {DEM_CELL_M:?}\nheights = [{:?}, {:?}]\n\n[matching]\nmethod = \"sweep\"\n\n[check]\nreference = \"truth-dem.tif\"\n",
        heights[0], heights[1]
    );
    t
}
