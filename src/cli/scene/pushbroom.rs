//! `rig sim scene --sensor pushbroom`: two or three SPOT-like line-scanner views of the
//! simulator's terrain, each with its rigorous model (`view-N.json`), its RPCs as GDAL reads
//! them (`view-N_RPC.TXT`), the noise-free points (`truth_points.csv`), the true DEM and
//! reflectance, and format-2 projects for the rigorous models and for the RPCs.

use super::frame::{
    scene_heights, to_grey, truth_grid_over, truth_reflectance, write_truth_grids, SceneArgs,
};
use crate::cli::usage::usage_bail;
use rig::geometry::rpc::{fit_rpc, FitGrid};
use rig::geometry::Geographic;
use rig_sim::pushbroom::{PushbroomView, Stereo};
use rig_sim::scene::jacksboro;
use serde_json::json;
use std::fmt::Write as _;

/// The heights every view is fitted and matched over: the terrain's range in the scene
/// and this margin, m.
const HEIGHT_MARGIN_M: f64 = 50.0;

pub fn run(a: &SceneArgs) -> anyhow::Result<i32> {
    let size = a.size.unwrap_or(super::frame::PUSHBROOM_SIZE);
    let truth_cell_m = a.truth_cell_m.unwrap_or(super::frame::TRUTH_CELL_M);
    if !(a.gsd_m.is_finite() && (0.5..=50.0).contains(&a.gsd_m)) {
        usage_bail!("--gsd-m {}: 0.5 to 50 m", a.gsd_m);
    }
    if !(200..=6000).contains(&size) {
        usage_bail!("--size {}: 200 to 6000 pixels", size);
    }
    let dem = jacksboro();
    let [ex, ey] = dem.extent_m();
    let footprint = size as f64 * a.gsd_m / 20f64.to_radians().cos().powi(2);
    if footprint > 0.9 * ex.min(ey) {
        usage_bail!(
            "--size {} at --gsd-m {}: the tilted views would cover {:.1} km, more than the simulated terrain's {:.1} km: make the views smaller or their pixels finer",
            size,
            a.gsd_m,
            footprint / 1000.0,
            0.9 * ex.min(ey) / 1000.0
        );
    }
    if a.gcps > 10_000 || a.cps > 10_000 {
        usage_bail!("--gcps {} and --cps {}: 0 to 10000 each", a.gcps, a.cps);
    }
    let (gains, offsets) = super::frame::check_shared(a, a.views)?;
    let stereo = match a.stereo {
        super::frame::StereoArg::Across => Stereo::Across,
        super::frame::StereoArg::Along => Stereo::Along,
    };
    let views: Vec<PushbroomView> = (1..=a.views)
        .map(|n| {
            let mut v = PushbroomView::new(dem.clone(), a.seed, stereo, a.views, n, size, a.gsd_m);
            v.texture = a.texture.into();
            v
        })
        .collect();
    // The ground all views see: the first view's footprint on the terrain, cut to what the
    // others see of it.
    let mut lo = [f64::MAX; 2];
    let mut hi = [f64::MIN; 2];
    let n = 24;
    let mut ground = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (c, r) = (
                size as f64 * i as f64 / n as f64,
                size as f64 * j as f64 / n as f64,
            );
            let g = views[0].ground_point(c, r);
            let inside_all = views.iter().all(|v| {
                v.project(g).is_some_and(|q| {
                    (0.0..=size as f64).contains(&q[0]) && (0.0..=size as f64).contains(&q[1])
                })
            });
            if inside_all {
                lo = [lo[0].min(g[0]), lo[1].min(g[1])];
                hi = [hi[0].max(g[0]), hi[1].max(g[1])];
                ground.push(g);
            }
        }
    }
    if ground.len() < 16 {
        anyhow::bail!(
            "the views hardly overlap ({} of {} sample points in all of them)",
            ground.len(),
            (n + 1) * (n + 1)
        );
    }
    let truth = truth_grid_over(&dem, [lo[0], lo[1], hi[0], hi[1]], truth_cell_m)?;
    let ([zmin, zmax], heights) =
        scene_heights(ground.iter().map(|g| g[2]), &truth, HEIGHT_MARGIN_M);
    let v0 = views[0].clone();
    let (reflectance, reflectance_cell_m) =
        truth_reflectance(&move |x, y| v0.reflectance_at(x, y), &truth, Some(a.gsd_m))?;
    std::fs::create_dir_all(&a.out)?;
    let geo = Geographic::new(rig::sim_scene::CRS)?;
    let mut fits = Vec::new();
    for (k, v) in views.iter().enumerate() {
        let name = format!("view-{}", v.number);
        eprintln!(
            "rendering {name} ({0}×{0} px, tilted {1:+.0}° across and {2:+.0}° along the track)…",
            size, v.tilt_across_deg, v.tilt_along_deg
        );
        let img = v.render(3);
        let px = to_grey(
            &img,
            a.noise_dn,
            [offsets[k], gains[k]],
            0x9015E ^ v.number as u64 ^ v.texture_seed,
            &name,
            [v.t_min, v.t_max],
        )?;
        let tiff = a.out.join(format!("{name}.tiff"));
        let model = rig::sim_scene::pushbroom(v);
        model.check().map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        rig::atomic::write_json(&a.out.join(format!("{name}.json")), &model)?;
        let (rpc, report) = fit_rpc(&model, &geo, heights, FitGrid::default())?;
        // The RPCs twice, as GDAL keeps them: in the image's RPC tag and beside it.
        rig::digitise::output::write_tiff16_tagged(
            &tiff,
            size,
            size,
            &px,
            &[(rig::geometry::rpc::TIFF_TAG, &rpc.to_values())],
        )?;
        rpc.write_beside(&tiff)?;
        fits.push(json!({"view": name, "rpc_fit": report}));
    }
    // Noise-free points: ground on the terrain, where every view sees it (by the simulator's
    // own projection), in the pixel convention (docs/conventions.md) (0, 0 at the top-left pixel's centre).
    let mut rng = rig_sim::rng::Rng::new(a.seed ^ 0x6C9);
    let mut csv = String::from("id,kind,x,y,z,photo,col,row\n");
    let (mut made, mut tries) = (0usize, 0usize);
    let want = a.gcps + a.cps;
    while made < want && tries < 100 * want.max(1) {
        tries += 1;
        let x = lo[0] + rng.uniform() * (hi[0] - lo[0]);
        let y = lo[1] + rng.uniform() * (hi[1] - lo[1]);
        let g = [x, y, dem.height(x, y)];
        let seen: Option<Vec<[f64; 2]>> = views
            .iter()
            .map(|v| {
                v.project(g).filter(|q| {
                    (1.0..size as f64 - 1.0).contains(&q[0])
                        && (1.0..size as f64 - 1.0).contains(&q[1])
                })
            })
            .collect();
        let Some(seen) = seen else { continue };
        let (id, kind) = if made < a.gcps {
            (format!("gcp{}", made + 1), "gcp")
        } else {
            (format!("cp{}", made - a.gcps + 1), "cp")
        };
        let w = rig::sim_scene::to_crs(g);
        for (v, q) in views.iter().zip(&seen) {
            writeln!(
                csv,
                "{id},{kind},{:.3},{:.3},{:.3},view-{},{:.4},{:.4}",
                w.x,
                w.y,
                w.z,
                v.number,
                q[0] - 0.5,
                q[1] - 0.5
            )?;
        }
        made += 1;
    }
    rig::atomic::write(&a.out.join("truth_points.csv"), csv.as_bytes())?;
    write_truth_grids(&a.out, &truth, &reflectance)?;
    rig::digitise::output::write_json(
        &a.out.join("truth.json"),
        &json!({"seed": a.seed, "sensor": "pushbroom", "stereo": stereo,
                "views": views, "terrain_m": [zmin, zmax], "heights_m": heights,
                "fits": fits, "noise_dn": a.noise_dn,
                "radiometry": {"gains": gains, "offsets_dn": offsets,
                    "grey": "offset + gain × 60000 × (t_min + (t_max − t_min) × reflectance) + noise"},
                "reflectance": format!("truth-reflectance.tif, {reflectance_cell_m} m cells"),
                "points": "truth_points.csv: noise-free, by the simulator's own projection"}),
    )?;
    for (file, rpc) in [("block.toml", false), ("block-rpc.toml", true)] {
        std::fs::write(a.out.join(file), block_toml(a.seed, &views, heights, rpc))?;
    }
    for f in &fits {
        let r = &f["rpc_fit"];
        eprintln!(
            "{}: RPCs fitted to the rigorous model within {:.1e} px RMS, {:.1e} px at most (check points)",
            f["view"].as_str().unwrap_or("?"),
            r["check_rms_px"].as_f64().unwrap_or(f64::NAN),
            r["check_max_px"].as_f64().unwrap_or(f64::NAN)
        );
    }
    println!(
        "scene in {}: {} views (view-N.tiff, their models view-N.json and RPCs view-N_RPC.TXT), {made} noise-free points in truth_points.csv, truth-dem.tif, truth-reflectance.tif, block.toml (format 2, rigorous models) and block-rpc.toml (format 2, RPCs)",
        a.out.display(),
        views.len()
    );
    Ok(0)
}

/// A format-2 project of the views with their true models (or their RPCs), the terrain's
/// heights with a margin, the true DEM as the reference.
fn block_toml(seed: u64, views: &[PushbroomView], heights: [f64; 2], rpc: bool) -> String {
    let mut t = format!(
        "# The views of `rig sim scene --sensor pushbroom --seed {seed}` with their true {}: the matchers\n# alone, with no orientation error. Run it with\n#   rig dtm {} --out OUT\nformat = 2\ncrs = \"{}\"\n",
        if rpc { "RPCs" } else { "line-scanner models" },
        if rpc { "block-rpc.toml" } else { "block.toml" },
        rig::sim_scene::CRS
    );
    for v in views {
        let _ = write!(
            t,
            "\n[[photo]]\nid = \"view-{0}\"\nimage = \"view-{0}.tiff\"\n",
            v.number
        );
        if rpc {
            let _ = writeln!(t, "rpc = \"view-{}_RPC.TXT\"", v.number);
        } else {
            let _ = writeln!(t, "pushbroom = \"view-{}.json\"", v.number);
        }
    }
    let _ = write!(
        t,
        "\n[points]\nfile = \"truth_points.csv\"\n\n[dem]\ncell_m = 10.0\nheights = [{}, {}]\n\n[matching]\nmethod = \"sweep\"\n\n[check]\nreference = \"truth-dem.tif\"\n",
        heights[0], heights[1]
    );
    t
}
