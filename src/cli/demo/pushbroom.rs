//! `rig demo --sensor pushbroom`: the satellite chain on the simulator, step by step as the
//! real commands: a SPOT-like triplet rendered with its line-scanner models and RPCs, then the
//! elevation model from the three views, compared with the true DEM in metres and in pixels
//! of parallax of the widest pair.

use super::frame::{out_dir, run_step, s, DemoArgs, Method};
use anyhow::Context;
use rig::coords::PixelXY;
use rig::geometry::{Pushbroom, Sensor};
use rig::matching::block::geometry::parallax_per_m;
use rig::matching::run::Report;
use serde_json::json;
use std::path::Path;
use std::time::Instant;

fn model(dir: &Path, view: u32) -> anyhow::Result<Pushbroom> {
    let p = dir.join(format!("view-{view}.json"));
    let text = std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
    serde_json::from_str(&text).with_context(|| format!("reading {}", p.display()))
}

pub fn run(a: &DemoArgs) -> anyhow::Result<i32> {
    let out = out_dir(a)?;
    let t0 = Instant::now();
    let size = if a.quick { "600" } else { "1200" };
    let args: Vec<String> = [
        "sim",
        "scene",
        "--sensor",
        "pushbroom",
        "--views",
        "3",
        "--stereo",
        "across",
        "--size",
        size,
        "--noise-dn",
        "100",
        "--seed",
    ]
    .iter()
    .map(|v| v.to_string())
    .chain([a.seed.to_string(), "--out".into(), s(&out)])
    .collect();
    run_step(
        "a SPOT-like triplet: views tilted −20°, 0°, +20° across the track, their models and RPCs (seeds 004, 001)",
        &args,
    )?;
    // The project the scene wrote, with the demo's matcher.
    let block = out.join("block.toml");
    let text = std::fs::read_to_string(&block)?;
    let method = match a.method {
        Method::Sweep => "sweep",
        Method::Mgcm => "mgcm",
    };
    let mut text = text.replace("method = \"sweep\"", &format!("method = \"{method}\""));
    if matches!(a.method, Method::Mgcm) {
        // One point per 6 px cell rather than seed 002's 25: on 600 px views 25 px cells are
        // points 125 m apart, and the DEM between them misses the fault's scarp (9.3 m RMSE
        // against 1.3 m).
        text = text.replace(
            "[check]",
            "[matching.mgcm]\ncell = 6   # px: one point per cell (seed 002: 21-29 on aerial photos)\n\n[check]",
        );
    }
    std::fs::write(&block, text)?;
    let dtm_dir = out.join("dtm");
    let args = [
        "dtm".into(),
        s(&block),
        "--json".into(),
        "--out".into(),
        s(&dtm_dir),
    ];
    let text = run_step(
        "elevation model from the three views through their line-scanner models",
        &args,
    )?;
    let dtm = match a.method {
        Method::Sweep => Report::Sweep(serde_json::from_str(text.trim())?),
        Method::Mgcm => Report::Mgcm(serde_json::from_str(text.trim())?),
    };
    // Parallax of the widest pair (views 1 and 3) per metre of height, at the scene's middle.
    let (v1, v3) = (model(&out, 1)?, model(&out, 3)?);
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("truth.json"))?)?;
    let hs = &truth["heights_m"];
    let mid = 0.5 * (hs[0].as_f64().unwrap_or(0.0) + hs[1].as_f64().unwrap_or(0.0));
    let centre = PixelXY::new(v1.columns as f64 / 2.0, v1.lines as f64 / 2.0);
    let px_per_m = parallax_per_m(&v1, &[&v3 as &dyn Sensor], centre, mid);
    // Seed 004's triplets on the widest pair: the heights of the noise-free points from three
    // of their four image coordinates through the image → image mappings.
    let triplets = widest_pair_triplets(&out, &v1, &v3, [hs[0].as_f64(), hs[1].as_f64()])?;
    let report = json!({
        "triplets_view_1_3": triplets,
        "seed": a.seed,
        "seconds": t0.elapsed().as_secs_f64(),
        "sensor": "pushbroom",
        "rpc_fits": truth["fits"],
        "widest_pair_parallax_px_per_m": px_per_m,
        "dtm": dtm,
    });
    rig::digitise::output::write_json(&out.join("report.json"), &report)?;
    println!(
        "\nrig demo --sensor pushbroom: done in {:.0} s, everything in {}",
        t0.elapsed().as_secs_f64(),
        out.display()
    );
    if let Some(fits) = truth["fits"].as_array() {
        for f in fits {
            println!(
                "  {}: RPCs within {:.1e} px RMS of the line-scanner model ({}_RPC.TXT, as GDAL reads it)",
                f["view"].as_str().unwrap_or("?"),
                f["rpc_fit"]["check_rms_px"].as_f64().unwrap_or(f64::NAN),
                f["view"].as_str().unwrap_or("?")
            );
        }
    }
    let m = dtm.model();
    let (filled, nodes) = (m.grid_filled, m.grid.cols * m.grid.rows);
    println!(
        "  elevation model: a height at {filled} of its {nodes} nodes ({:.1} % of the default extent: where two views see the ground)",
        100.0 * filled as f64 / nodes.max(1) as f64
    );
    if let Some(c) = &m.comparison {
        println!(
            "  elevation model vs the true DEM: RMSE {:.2} m = {:.3} px of parallax of the widest pair ({:.3} px per m), mean {:+.2} m, over {} nodes",
            c.rmse_m,
            c.rmse_m * px_per_m,
            px_per_m,
            c.mean_m,
            c.nodes
        );
    }
    for t in &triplets {
        println!(
            "  triplet {} (views 1 and 3): heights of {} noise-free points within {:.3} m RMS; {:.2e} px per m, so a tenth of a pixel of measuring error is {:.1} m{}",
            t.triplet,
            t.points,
            t.rms_m,
            t.px_per_m,
            0.1 / t.px_per_m,
            if t.warning.is_some() {
                " (weak: the base lies along the other axis)"
            } else {
                ""
            }
        );
    }
    for (k, v) in dtm.summary() {
        if k == "warning" {
            println!("  warning: {v}");
        }
    }
    println!(
        "  look at: {}/report.html; the noise-free points: truth_points.csv; everything: report.json",
        dtm_dir.display()
    );
    Ok(0)
}

/// The four triplets of views 1 and 3 over the noise-free points both see (truth_points.csv,
/// centre-origin pixels).
fn widest_pair_triplets(
    out: &Path,
    v1: &Pushbroom,
    v3: &Pushbroom,
    heights: [Option<f64>; 2],
) -> anyhow::Result<Vec<rig::matching::mapping::triplets::TripletReport>> {
    let [Some(lo), Some(hi)] = heights else {
        anyhow::bail!("truth.json has no heights_m");
    };
    let maps = rig::matching::mapping::triplets::ImageToImage::from_sensors(v1, v3, [lo, hi], 3)?;
    let path = out.join("truth_points.csv");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let mut seen: std::collections::BTreeMap<String, [Option<PixelXY>; 2]> = Default::default();
    let mut z = std::collections::BTreeMap::new();
    for l in text.lines().skip(1) {
        let f: Vec<&str> = l.split(',').collect();
        let num = |k: usize| f.get(k).and_then(|v| v.parse::<f64>().ok());
        let (Some(h), Some(c), Some(r)) = (num(4), num(6), num(7)) else {
            continue;
        };
        let slot = match f.get(5) {
            Some(&"view-1") => 0,
            Some(&"view-3") => 1,
            _ => continue,
        };
        seen.entry(f[0].to_string()).or_default()[slot] = Some(PixelXY::new(c + 0.5, r + 0.5));
        z.insert(f[0].to_string(), h);
    }
    let points: Vec<(PixelXY, PixelXY, f64)> = seen
        .iter()
        .filter_map(|(id, [a, b])| Some(((*a)?, (*b)?, *z.get(id)?)))
        .collect();
    Ok(rig::matching::mapping::triplets::assess(&maps, &points))
}
