//! `rig dtm`: elevation models from a matching project.

use anyhow::Context;
use clap::{Args, Subcommand};
use rig::coords::{PhotoMm, PixelXY};
use rig::digitise::ImageF32;
use rig::geometry::{resect, FrameCamera, Interior};
use rig::matching::output::{write_error_map, write_geotiff, write_hillshade, write_ply};
use rig::matching::pmf_dtm::{pmf_dtm, Budget, PmfDtm, PmfDtmParams};
use rig::matching::project::PmfSource;
use rig::matching::project::Project;
use rig::matching::regions::{RegionParams, RegionStats};
use rig::matching::sweep::SweepParams;
use rig::matching::{PmfSet, RigorousPhoto, StereoPoint};
use rig::scan::ScannedPhoto;
use serde_json::json;
use std::path::{Path, PathBuf};

#[derive(Debug, Args)]
pub struct DtmArgs {
    #[command(subcommand)]
    pub action: DtmAction,
}

#[derive(Debug, Subcommand)]
pub enum DtmAction {
    /// Seed 000's method: polynomial mapping functions from the control points (terms chosen by
    /// the check points), a height sweep along their epipolar lines, removal of wrong heights
    /// by the height and population criteria, gridding, comparison with a reference.
    ///
    /// Writes into --out: dem.tif (float32 GeoTIFF, nodata −9999), points.ply, hillshade.png,
    /// error.png (with a reference), report.json, pmfs.json (the mappings, reusable with
    /// `from = "file"`). Each file is written whole or not at all; a run that was killed can
    /// be run again into the same directory.
    ///
    /// Memory and work are estimated first and the run refused above [limits] in the
    /// project (max_memory_mb, default 4096; max_candidates_g, default 20) or --max-memory.
    #[command(verbatim_doc_comment)]
    Pmf {
        /// The project file (TOML; see the README; `rig sim scene` writes one).
        #[arg(long, value_name = "FILE")]
        project: PathBuf,
        /// Output directory (created; empty, or holding only an earlier run's outputs, which
        /// are replaced).
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// Most memory the run may take, MiB (overrides the project's [limits]
        /// max_memory_mb).
        #[arg(long, value_name = "MIB", value_parser = clap::value_parser!(u64).range(16..=1_048_576))]
        max_memory: Option<u64>,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
}

/// A scanned (or rendered) photo as an image in its grey counts.
pub fn load_photo(sidecar: &Path) -> anyhow::Result<(ScannedPhoto, ImageF32)> {
    let (s, px) = ScannedPhoto::load(sidecar)?;
    let img = ImageF32 {
        width: s.grid.width,
        height: s.grid.height,
        data: px.into_iter().map(|v| v as f32).collect(),
    };
    Ok((s, img))
}

/// The files `rig dtm pmf` writes (and their temporary `.part` names while it writes them).
const OUTPUTS: [&str; 6] = [
    "dem.tif",
    "points.ply",
    "hillshade.png",
    "error.png",
    "report.json",
    "pmfs.json",
];

/// An output directory must be new, empty, or hold only an earlier run's outputs (a run that
/// was killed half way left some of them, or `.part` files): anything else is not ours to
/// replace.
fn check_out_dir(out: &Path) -> anyhow::Result<()> {
    if !out.exists() {
        return Ok(());
    }
    let mut foreign = Vec::new();
    for e in std::fs::read_dir(out).with_context(|| format!("reading {}", out.display()))? {
        let name = e?.file_name().to_string_lossy().to_string();
        let base = name.strip_suffix(".part").unwrap_or(&name);
        if !OUTPUTS.contains(&base) {
            foreign.push(name);
        }
    }
    if !foreign.is_empty() {
        foreign.sort();
        anyhow::bail!(
            "{} holds files that are not a `rig dtm pmf` run's ({}): give a new or empty directory",
            out.display(),
            foreign.join(", ")
        );
    }
    Ok(())
}

/// Runs a project into `out`; returns the result and the report document.
pub fn run_project(
    p: &Project,
    out: &Path,
    max_memory_mb: Option<u64>,
) -> anyhow::Result<(PmfDtm, serde_json::Value)> {
    check_out_dir(out)?;
    let (sl, left) = load_photo(&p.photos.left)?;
    let (sr, right) = load_photo(&p.photos.right)?;
    let pts = p.points()?;
    let mut orientation = serde_json::Value::Null;
    let pmfs = match p.pmf.from {
        PmfSource::Points => {
            PmfSet::from_points(p.pmf.order, &pts.gcps, &pts.cps).with_context(|| {
                format!(
                    "fitting the mapping functions to {}",
                    p.points.file.display()
                )
            })?
        }
        PmfSource::File => {
            let f = p
                .pmf
                .file
                .as_ref()
                .expect("checked when the project was read");
            let text = std::fs::read_to_string(f)
                .with_context(|| format!("reading the mappings {}", f.display()))?;
            serde_json::from_str::<PmfSet>(&text)
                .with_context(|| format!("{}: not a set of mapping functions", f.display()))?
        }
        PmfSource::Rigorous => {
            let orient = |s: &ScannedPhoto, px: &dyn Fn(&StereoPoint) -> [f64; 2]| {
                let interior = Interior {
                    focal_mm: s.camera_certificate.focal_length_mm,
                    principal_point: PhotoMm::new(0.0, 0.0),
                };
                let obs: Vec<_> = pts
                    .gcps
                    .iter()
                    .map(|g| {
                        let q = px(g);
                        (s.grid.photo(PixelXY::new(q[0], q[1])), g.ground)
                    })
                    .collect();
                resect(&interior, &obs).map(|r| (interior, r))
            };
            let (il, rl) = orient(&sl, &|g| g.left).context("resection of the left photo")?;
            let (ir, rr) = orient(&sr, &|g| g.right).context("resection of the right photo")?;
            orientation = json!({"left": rl, "right": rr});
            let l = RigorousPhoto {
                camera: FrameCamera {
                    interior: il,
                    exterior: rl.exterior,
                },
                grid: sl.grid,
            };
            let r = RigorousPhoto {
                camera: FrameCamera {
                    interior: ir,
                    exterior: rr.exterior,
                },
                grid: sr.grid,
            };
            PmfSet::from_rigorous(&l, &r, [p.matching.h_min, p.matching.h_max], p.pmf.order)
                .context("deriving the mapping functions from the resected photos")?
        }
    };
    let params = PmfDtmParams {
        sweep: SweepParams {
            h_min: p.matching.h_min,
            h_max: p.matching.h_max,
            h_step: p.matching.h_step,
            window: p.matching.window,
            threshold: p.matching.threshold,
            neighbours: p.matching.neighbours,
            stride: p.matching.stride,
            ..Default::default()
        },
        regions: RegionParams {
            search_distance: p.regions.search_distance,
            height_threshold: p.height_threshold(),
            population_threshold: p.regions.population_threshold,
        },
        cell_m: p.grid.cell_m,
    };
    let reference = match &p.grid.reference {
        Some(r) => Some(
            rig::matching::output::read_geotiff(r)
                .with_context(|| format!("reading the reference model {}", r.display()))?,
        ),
        None => None,
    };
    let f = reference
        .as_ref()
        .map(|g| move |x: f64, y: f64| g.interpolate(x, y));
    let budget = Budget {
        max_memory_mb: max_memory_mb.unwrap_or(p.limits.max_memory_mb),
        max_candidates: p.limits.max_candidates_g * 1e9,
    };
    let r = pmf_dtm(
        &left,
        &right,
        &pmfs,
        &params,
        &budget,
        f.as_ref().map(|f| f as &dyn Fn(f64, f64) -> f64),
        p.grid.flying_height_m,
    )
    .with_context(|| format!("project {}", p.path.display()))?;
    std::fs::create_dir_all(out)?;
    // A rerun replaces an earlier run's files; one without a reference leaves no old error map.
    if p.grid.reference.is_none() {
        let _ = std::fs::remove_file(out.join("error.png"));
    }
    write_geotiff(&out.join("dem.tif"), &r.grid)?;
    write_ply(&out.join("points.ply"), &r.points)?;
    write_hillshade(&out.join("hillshade.png"), &r.grid)?;
    if let (Some(g), Some(c)) = (&reference, &r.report.comparison) {
        let d = r.grid.differences(|x, y| g.interpolate(x, y));
        write_error_map(
            &out.join("error.png"),
            &r.grid,
            &d,
            (3.0 * c.rmse_m).max(1.0),
        )?;
    }
    let doc = json!({"project": p.path, "pmf_from": p.pmf.from, "orientation": orientation,
                     "pmf": pmfs.report, "dtm": r.report});
    rig::digitise::output::write_json(&out.join("report.json"), &doc)?;
    rig::digitise::output::write_json(&out.join("pmfs.json"), &serde_json::to_value(&pmfs)?)?;
    Ok((r, doc))
}

pub fn print_report(pmf: &serde_json::Value, r: &PmfDtm) {
    println!("mapping functions (seed 000 Table 2):");
    if let Some(rows) = pmf.as_array() {
        for f in rows {
            println!(
                "  {:28} {:>2} terms   GCP RMSE {:7.3}   CP RMSE {:7.3} {}",
                f["name"].as_str().unwrap_or(""),
                f["terms"],
                f["gcp_rmse"].as_f64().unwrap_or(f64::NAN),
                f["cp_rmse"].as_f64().unwrap_or(f64::NAN),
                f["units"].as_str().unwrap_or("")
            );
        }
    }
    let t = &r.report;
    let s = &t.params.sweep;
    println!(
        "matching (Table 3): heights {:.0}…{:.0} m by {} m, window {w}×{w}, threshold {}",
        s.h_min,
        s.h_max,
        s.h_step,
        s.threshold,
        w = s.window
    );
    println!(
        "  {} of {} points matched ({:.1} %), {:.1} M candidate heights in {:.1} s ({:.0} points/s)",
        t.points_matched,
        t.points_total,
        t.matched_percent,
        t.candidates as f64 / 1e6,
        t.matching_seconds,
        t.pixels_per_second
    );
    let g = &t.regions;
    println!(
        "wrong heights (Table 4): {} regions; removed {} by height, {} by population; {} left",
        g.regions, g.regions_removed_by_height, g.regions_removed_by_population, g.regions_left
    );
    println!(
        "  points removed {} ({:.2} %), left {} ({:.2} %)",
        g.points_removed,
        RegionStats::percent(g.points_removed, g.points),
        g.points_left,
        RegionStats::percent(g.points_left, g.points)
    );
    println!(
        "elevation model: {} × {} nodes of {} m, {} with a height",
        r.grid.cols, r.grid.rows, t.params.cell_m, t.grid_filled
    );
    if let Some(c) = &t.comparison {
        println!(
            "against the reference (Table 5): max +{:.2} m, max {:.2} m, mean {:+.2} m, mean |Δ| {:.2} m, RMSE {:.2} m over {} nodes",
            c.max_positive_m, c.max_negative_m, c.mean_m, c.mean_abs_m, c.rmse_m, c.nodes
        );
        if let Some(pm) = t.rmse_permille_of_flying_height {
            println!("  RMSE = {pm:.3} ‰ of the flying height");
        }
    }
}

pub fn run(a: DtmArgs) -> anyhow::Result<i32> {
    match a.action {
        DtmAction::Pmf {
            project,
            out,
            json,
            max_memory,
        } => {
            let p = Project::load(&project)?;
            let (r, doc) = run_project(&p, &out, max_memory)?;
            if json {
                println!("{doc}");
            } else {
                print_report(&doc["pmf"], &r);
                println!("written to {}", out.display());
            }
            Ok(0)
        }
    }
}
