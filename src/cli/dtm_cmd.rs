//! `rig dtm`: elevation models from a matching project.

use anyhow::Context;
use clap::{Args, Subcommand};
use rig::matching::pipeline;
use rig::matching::pmf_dtm::PmfDtm;
use rig::matching::pmf_set::FitReport;
use rig::matching::project::Project;
use rig::matching::regions::RegionStats;
use rig::scan::ScannedPhoto;
use std::path::PathBuf;

/// Options of `rig dtm` (its help text is on `Command::Dtm`).
#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct DtmArgs {
    #[command(subcommand)]
    pub action: Option<DtmAction>,
    /// The project file (TOML).
    #[arg(value_name = "PROJECT.toml")]
    pub project: Option<PathBuf>,
    /// Output directory (created; empty, or holding only an earlier run's outputs, which are
    /// replaced).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Most memory the run may take, MiB (overrides the project's [limits] max_memory_mb).
    #[arg(long, value_name = "MIB", value_parser = clap::value_parser!(u64).range(16..=1_048_576))]
    pub max_memory: Option<u64>,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Subcommand)]
pub enum DtmAction {
    /// Seed 000's method: polynomial mapping functions from the control points (terms chosen by
    /// the check points), a height sweep along their epipolar lines, removal of wrong heights
    /// by the height and population criteria, gridding, comparison with a reference.
    ///
    /// Writes into --out: dem.tif (float32 GeoTIFF, nodata −9999), quality.tif (σ, correlation),
    /// ortho.tif, points.ply, points.las, hillshade.png, quality.png, error.png (with a
    /// reference), report.json, pmfs.json (the mappings, reusable with
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

pub fn print_report(pmf: &[FitReport], r: &PmfDtm) {
    println!("mapping functions (seed 000 Table 2):");
    for f in pmf {
        println!(
            "  {:28} {:>2} terms   GCP RMSE {:7.3}   CP RMSE {:7.3} {}",
            f.name, f.terms, f.gcp_rmse, f.cp_rmse, f.units
        );
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

/// A format-2 project: photos loaded (scans through the scan's hand-over), the N-photo sweep.
fn run_format2(
    project: &std::path::Path,
    out: &std::path::Path,
    max_memory: Option<u64>,
    json: bool,
) -> anyhow::Result<i32> {
    use rig::matching::pipeline2;
    use rig::matching::project2::Project2;
    let p = Project2::load(project)?;
    // The rig's own scans come through the scan's hand-over.
    let scan =
        |sidecar: &std::path::Path| ScannedPhoto::load_photo(sidecar).map_err(|e| e.to_string());
    let photos = pipeline2::load_photos(&p, &scan)?;
    let bar = super::progress_bar::Bar::new(!json);
    let r = pipeline2::run(&p, &photos, out, max_memory, &bar)?;
    for pr in &r.pairs {
        if let Some(w) = pr.dtm.pile_warning() {
            eprintln!("rig dtm: warning: photos {} × {}: {w}", pr.left, pr.right);
        }
    }
    if json {
        println!("{}", serde_json::to_string(&r)?);
        return Ok(0);
    }
    println!(
        "{} photos, {} pairs swept, heights {:.0}…{:.0} m; CRS {}",
        p.photos.len(),
        r.pairs.len(),
        r.heights_m[0],
        r.heights_m[1],
        r.crs
    );
    for pr in &r.pairs {
        println!(
            "  {} × {}: step {:.2} m, {:.1} % matched, {} points kept",
            pr.left, pr.right, pr.h_step_m, pr.dtm.matched_percent, pr.points
        );
    }
    println!(
        "elevation model: {} × {} nodes of {} m, {} with a height",
        r.grid.cols, r.grid.rows, p.cell_m, r.grid_filled
    );
    if let Some(c) = &r.comparison {
        println!(
            "against the reference: RMSE {:.2} m, mean {:+.2} m, max +{:.2} / {:.2} m over {} nodes",
            c.rmse_m, c.mean_m, c.max_positive_m, c.max_negative_m, c.nodes
        );
    }
    match &r.variance_factor {
        Some(f) => println!(
            "standard deviations (quality.tif): the matching's, × {:.2} from {} node heights compared between pairs (a lower bound where pairs share a photo)",
            f.s0, f.comparisons
        ),
        None => println!(
            "standard deviations (quality.tif): the matching's alone (too few nodes seen by two pairs to scale them)"
        ),
    }
    for (what, c) in [
        ("check points", &r.check_points),
        ("the reference", &r.sigma_vs_reference),
    ] {
        if let Some(c) = c {
            let verdict = if c.ratio > 1.5 {
                format!(
                    ": the errors are {:.1} × the standard deviations (errors the pairs share, as of the orientations or the sweep's sub-step bias, are not in them)",
                    c.ratio
                )
            } else {
                String::new()
            };
            println!(
                "  against {what}: RMSE {:.2} m, RMS σ {:.2} m, {:.0} % within 2σ over {}{verdict}",
                c.rmse_m, c.rms_sigma_m, c.within_2_sigma_percent, c.points
            );
        }
    }
    println!(
        "written to {}: dem.tif, quality.tif (σ, correlation), ortho.tif, points.ply, points.las, hillshade.png, quality.png{}, report.json",
        out.display(),
        if r.comparison.is_some() { ", error.png" } else { "" }
    );
    Ok(0)
}

pub fn run(a: DtmArgs) -> anyhow::Result<i32> {
    let action = match (a.action, a.project, a.out) {
        (Some(act), _, _) => act,
        (None, Some(project), Some(out)) => {
            let text = std::fs::read_to_string(&project)
                .with_context(|| format!("reading {}", project.display()))?;
            match rig::matching::project2::format_of(&text) {
                Ok(2) => return run_format2(&project, &out, a.max_memory, a.json),
                Ok(_) => {}
                Err(e) => anyhow::bail!("{}: {e}", project.display()),
            }
            DtmAction::Pmf {
                project,
                out,
                json: a.json,
                max_memory: a.max_memory,
            }
        }
        (None, None, _) => {
            eprintln!(
                "rig dtm: give the project: rig dtm PROJECT.toml --out DIR (see rig dtm --help)"
            );
            return Ok(rig::exit::USAGE);
        }
        (None, Some(_), None) => {
            eprintln!("rig dtm: give the output directory: rig dtm PROJECT.toml --out DIR");
            return Ok(rig::exit::USAGE);
        }
    };
    match action {
        DtmAction::Pmf {
            project,
            out,
            json,
            max_memory,
        } => {
            let p = Project::load(&project)?;
            let load = |f: &PathBuf| {
                ScannedPhoto::load_photo(f)
                    .with_context(|| format!("project {}: photo {}", p.path.display(), f.display()))
            };
            let (left, right) = (load(&p.photos.left)?, load(&p.photos.right)?);
            let bar = super::progress_bar::Bar::new(!json);
            let (r, report) = pipeline::run(&p, [&left, &right], &out, max_memory, &bar)?;
            if let Some(w) = r.report.pile_warning() {
                eprintln!("rig dtm: warning: {w}");
            }
            if json {
                println!("{}", serde_json::to_string(&report)?);
            } else {
                print_report(&report.pmf, &r);
                if let Some(c) = &report.sigma_vs_reference {
                    println!(
                        "standard deviations (quality.tif, the matching's own: one pair cannot scale them): RMS {:.2} m; against the reference the errors are {:.1} × them, {:.0} % within 2σ",
                        c.rms_sigma_m, c.ratio, c.within_2_sigma_percent
                    );
                }
                println!(
                "written to {}: dem.tif, quality.tif, ortho.tif, points.ply, points.las, hillshade.png, quality.png{}, report.json, pmfs.json",
                out.display(),
                if report.dtm.comparison.is_some() { ", error.png" } else { "" }
            );
            }
            Ok(0)
        }
    }
}
