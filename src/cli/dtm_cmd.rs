//! `rig dtm`: elevation models from a matching project.

use super::shared_args::JsonOutput;
use clap::{Args, Subcommand};
use rig::matching::methods::sweep::tiles::{self, TileError, TileSpec};
use rig::matching::methods::sweep::SweepReport;
use rig::matching::products::outputs::{self, Writer};
use rig::matching::project::Project;
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
    #[command(flatten)]
    pub run: RunOptions,
    /// Sweep only share I of N of the work (I counts from 1) into --out, for a cluster or
    /// several machines; `rig dtm merge` joins the shares (format-2 projects).
    #[arg(long, value_name = "I/N")]
    pub tile: Option<TileSpec>,
}

/// What every `rig dtm` run takes: its memory limit and the report's form.
#[derive(Debug, Clone, Copy, Args)]
pub struct RunOptions {
    /// Most memory the run may take, MiB (overrides the project's [limits] max_memory_mb).
    #[arg(long, value_name = "MIB", value_parser = clap::value_parser!(u64).range(16..=1_048_576))]
    pub max_memory: Option<u64>,
    #[command(flatten)]
    pub output: JsonOutput,
    /// Exit 12 when the run warns (heights piled at a bound of the range tried, few points
    /// matched); the outputs are written all the same.
    #[arg(long)]
    pub strict: bool,
}

#[derive(Debug, Subcommand)]
pub enum DtmAction {
    /// Join the shares of `rig dtm PROJECT --tile I/N --out TILE_DIR` (all N, any order) and
    /// finish the run: the outputs are byte for byte those of one `rig dtm PROJECT --out DIR`.
    ///
    /// Each share sweeps a contiguous part of the work (bands of 16 rows of every pair's
    /// sweep, the longest step); the merge removes the wrong heights, grids, scales the
    /// standard deviations and writes the outputs. The project must be the file the shares
    /// read (its path and a hash are in each TILE_DIR/tile.json), unchanged.
    ///
    /// Examples:
    ///   for i in 1 2 3 4; do rig dtm block.toml --tile $i/4 --out tiles/$i & done; wait
    ///   rig dtm merge tiles/* --out dtm
    #[command(verbatim_doc_comment)]
    Merge {
        /// The shares' directories.
        #[arg(value_name = "TILE_DIR", required = true, num_args = 1..)]
        tiles: Vec<PathBuf>,
        /// Output directory (as for `rig dtm`).
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        #[command(flatten)]
        run: RunOptions,
    },
    /// Formerly format 1's run; now `rig dtm PROJECT --out DIR`, which reads both formats.
    #[command(hide = true)]
    Pmf {
        /// The project file (TOML; see docs/elevation-models.md; `rig sim scene` writes one).
        #[arg(long, value_name = "FILE")]
        project: PathBuf,
        /// Output directory (created; empty, or holding only an earlier run's outputs, which
        /// are replaced).
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        #[command(flatten)]
        run: RunOptions,
    },
    /// Write a format-1 project (one scanned pair, [photos] left/right, points in JSON) as
    /// format 2: the same photos, points, heights, grid and sweep parameters, the points as
    /// format 2's CSV (pixel centres at integers). `[pmf] from = "points"` becomes
    /// `[matching] mappings = "points"` (seed 000), `from = "rigorous"` the default
    /// `mappings = "sensors"` (seed 004), `from = "file"` `mappings = "file"` with its file.
    /// `rig dtm` reads a format-1 project as this very project; nothing is overwritten.
    ///
    /// Examples:
    ///   rig dtm upgrade scene/project.toml                 # writes scene/project-format2.toml
    ///   rig dtm upgrade old.toml --out block.toml           # and block-points.csv beside it
    #[command(verbatim_doc_comment)]
    Upgrade {
        /// The format-1 project.
        #[arg(value_name = "OLD.toml")]
        project: PathBuf,
        /// The format-2 project to write, in the old one's directory (its points go beside it
        /// as NAME-points.csv); default: OLD-format2.toml.
        #[arg(long, value_name = "NEW.toml")]
        out: Option<PathBuf>,
    },
}

/// `rig dtm upgrade`: the format-2 project and its points beside the old project.
fn upgrade(project: &std::path::Path, out: Option<PathBuf>) -> anyhow::Result<i32> {
    use rig::matching::project::upgrade::write_beside;
    match write_beside(project, out.as_deref()) {
        Ok(w) => {
            println!(
                "wrote {} (format 2) and {} ({} points); run it with: rig dtm {} --out DIR",
                w.project.display(),
                w.points.display(),
                w.point_count,
                w.project.display()
            );
            Ok(rig::exit::OK)
        }
        Err(e) if e.is_usage() => {
            eprintln!("rig dtm upgrade: {e}");
            Ok(rig::exit::USAGE)
        }
        Err(e) => Err(e.into()),
    }
}

/// The rig's own scans come through the scan's hand-over.
fn scan_photo(sidecar: &std::path::Path) -> Result<rig::matching::block::photo::ScanImage, String> {
    ScannedPhoto::hand_over(sidecar).map_err(|e| e.to_string())
}

/// The project with `--max-memory` over its `[limits] max_memory_mb`.
fn with_memory(p: &Project, max_memory: Option<u64>) -> Project {
    let mut p = p.clone();
    if let Some(m) = max_memory {
        p.limits.max_memory_mb = m;
    }
    p
}

/// A project: photos loaded (scans through the scan's hand-over), its method run.
fn run_project(
    p: &Project,
    out: &std::path::Path,
    RunOptions {
        max_memory,
        output: JsonOutput { json },
        strict,
    }: RunOptions,
) -> anyhow::Result<i32> {
    use rig::matching::run::Report;
    // --max-memory holds for the photos read as for the matching.
    let p = &with_memory(p, max_memory);
    // A block of approximate photos is oriented first, into out/orientation/.
    let first = rig::orientation::run::before_matching(
        p,
        out,
        &scan_photo,
        rig::orientation::OrientOptions::default(),
    )?;
    if let Some(f) = &first {
        let r = &f.report;
        eprintln!(
            "rig dtm: the block oriented first ({} photos, {} control and {} tie points, σ̂₀ {:.3}{}); its project, covariance and report in {}",
            r.photos,
            r.control_points,
            r.tie_points,
            r.sigma0,
            r.check_rmse_m.map_or(String::new(), |[xy, z]| format!(
                ", check points RMSE XY {xy:.2} m, Z {z:.2} m"
            )),
            f.folder.display()
        );
    }
    let p = first.as_ref().map_or(p, |f| &f.project);
    let views = rig::matching::run::preflight(p, &scan_photo, max_memory)?;
    let bar = super::progress_bar::Bar::new(!json);
    let photos = rig::matching::block::photos::load_viewed(p, &scan_photo, &views, &bar)?;
    match rig::matching::run::run(p, &photos, out, max_memory, &bar)? {
        Report::Mgcm(r) => print_mgcm(&r, out, json, strict),
        Report::Oslsm(r) => print_oslsm(&r, out, json, strict),
        Report::Sweep(r) => print_sweep(p, &r, out, json, strict),
    }
}

/// A run's exit code: `DOUBTFUL` when it warned and `--strict` asks scripts to stop there.
fn exit_code(doubtful: bool, strict: bool) -> i32 {
    if strict && doubtful {
        rig::exit::DOUBTFUL
    } else {
        rig::exit::OK
    }
}

/// The report of an MGCM run.
fn print_mgcm(
    r: &rig::matching::methods::mgcm::run::MgcmReport,
    out: &std::path::Path,
    json: bool,
    strict: bool,
) -> anyhow::Result<i32> {
    // Few points kept is the run's doubt.
    let few = r.kept * 4 < r.selected;
    if few {
        eprintln!(
            "rig dtm: warning: only {} of {} points kept: see points.csv for the reasons (do [dem] heights bracket the terrain?)",
            r.kept, r.selected
        );
    }
    // (Without --json the summary below carries them.)
    if json {
        for w in &r.warnings {
            eprintln!("rig dtm: warning: {w}");
        }
    }
    let doubtful = few || !r.warnings.is_empty();
    let code = exit_code(doubtful, strict);
    if json {
        println!("{}", json_report(out, r)?);
        return Ok(code);
    }
    for (k, v) in r.summary() {
        println!("{k}: {v}");
    }
    if let Some(a) = &r.accuracy {
        println!("\n{}", a.table());
    }
    println!(
        "outputs in {}: {}",
        out.display(),
        outputs::listed(Some(Writer::Mgcm), r.accuracy.is_some())
    );
    Ok(code)
}

/// The report of an object-space run.
fn print_oslsm(
    r: &rig::matching::methods::oslsm::run::OslsmReport,
    out: &std::path::Path,
    json: bool,
    strict: bool,
) -> anyhow::Result<i32> {
    // (Without --json the summary below carries them.)
    if json {
        for w in &r.warnings {
            eprintln!("rig dtm: warning: {w}");
        }
    }
    let code = exit_code(!r.warnings.is_empty(), strict);
    if json {
        println!("{}", json_report(out, r)?);
        return Ok(code);
    }
    for (k, v) in r.summary() {
        println!("{k}: {v}");
    }
    println!(
        "outputs in {}: {} (reflectance.tif in photo {}'s grey values){}",
        out.display(),
        outputs::listed(Some(Writer::Oslsm), r.model.comparison.is_some()),
        r.reference,
        match r.config.coarse {
            rig::matching::project::matchers::CoarseSource::Sweep =>
                "; the sweep's coarse model in coarse/",
            rig::matching::project::matchers::CoarseSource::Features =>
                "; the feature route's coarse model in coarse/dem.tif",
            rig::matching::project::matchers::CoarseSource::File(_) => "",
        }
    );
    Ok(code)
}

/// Share `spec` of a format-2 run into `out`.
fn run_tile(
    p: &Project,
    spec: TileSpec,
    out: &std::path::Path,
    max_memory: Option<u64>,
    json: bool,
) -> anyhow::Result<i32> {
    let bar = super::progress_bar::Bar::new(!json);
    let s = match tiles::sweep_share(p, spec, out, max_memory, &scan_photo, &bar) {
        Err(e @ TileError::NotSweep { .. }) => {
            eprintln!("rig dtm: {e}");
            return Ok(rig::exit::USAGE);
        }
        r => r?,
    };
    let m = &s.manifest;
    if json {
        println!("{}", serde_json::to_string(m)?);
        return Ok(rig::exit::OK);
    }
    println!(
        "share {spec}: units {}…{} of {} ({} pairs of {} photos), {} part{} written to {}",
        s.units.start,
        s.units.end,
        s.total_units,
        s.pairs,
        s.photos,
        m.parts.len(),
        if m.parts.len() == 1 { "" } else { "s" },
        out.display()
    );
    for e in &m.parts {
        println!(
            "  {} × {}: rows {}…{} in {:.1} s",
            e.left, e.right, e.rows[0], e.rows[1], e.seconds
        );
    }
    println!(
        "when all {} shares are done: rig dtm merge TILE_DIR… --out DIR",
        spec.count
    );
    Ok(rig::exit::OK)
}

/// `rig dtm merge`: the shares joined and the run finished as a single run would.
fn merge(
    dirs: &[PathBuf],
    out: &std::path::Path,
    RunOptions {
        max_memory,
        output: JsonOutput { json },
        strict,
    }: RunOptions,
) -> anyhow::Result<i32> {
    eprintln!("rig dtm merge: {} shares", dirs.len());
    let bar = super::progress_bar::Bar::new(!json);
    let (p, r) = tiles::merge(dirs, out, max_memory, &scan_photo, &bar)?;
    print_sweep(&p, &r, out, json, strict)
}

/// The run's report for `--json`: report.json as it was written (with what every run adds,
/// `photos_read`), on one line; the method's own report where it cannot be read back.
fn json_report(out: &std::path::Path, r: &impl serde::Serialize) -> anyhow::Result<String> {
    let written = std::fs::read_to_string(out.join(rig::matching::products::outputs::REPORT_JSON))
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok());
    Ok(match written {
        Some(v) => serde_json::to_string(&v)?,
        None => serde_json::to_string(r)?,
    })
}

/// The report of a sweep (single or merged).
fn print_sweep(
    p: &Project,
    r: &SweepReport,
    out: &std::path::Path,
    json: bool,
    strict: bool,
) -> anyhow::Result<i32> {
    let mut warned = false;
    for pr in &r.pairs {
        for w in pr.dtm.warnings() {
            eprintln!("rig dtm: warning: photos {} × {}: {w}", pr.left, pr.right);
            warned = true;
        }
    }
    let code = exit_code(warned, strict);
    if json {
        println!("{}", json_report(out, r)?);
        return Ok(code);
    }
    println!(
        "{} photos, {} pairs swept, heights {:.0}…{:.0} m; CRS {}",
        p.photos.len(),
        r.pairs.len(),
        r.heights_m[0],
        r.heights_m[1],
        r.crs
    );
    for (what, line) in rig::matching::block::orient::corrected_lines(&r.corrected) {
        println!("  {what}: {line}");
    }
    for pr in &r.pairs {
        println!(
            "  {} × {}: step {:.2} m, {:.1} % matched, {} points kept",
            pr.left, pr.right, pr.h_step_m, pr.dtm.matched_percent, pr.points
        );
        // Seed 000 Table 2's figure a person checks first: how well the mapping the sweep
        // follows fits the check points (every fit is in report.json).
        let along: Vec<String> = pr
            .pmf
            .iter()
            .filter(|f| f.name.starts_with("left→right"))
            .map(|f| {
                format!(
                    "{} {} terms, check points {:.3} {}",
                    f.name, f.terms, f.cp_rmse, f.units
                )
            })
            .collect();
        if !along.is_empty() {
            println!("    mapping functions: {}", along.join("; "));
        }
    }
    println!(
        "elevation model: {} × {} nodes of {} m, {} with a height",
        r.model.grid.cols, r.model.grid.rows, p.cell_m, r.model.grid_filled
    );
    if let Some(c) = &r.model.comparison {
        println!("against the reference: {}", c.summary());
    }
    println!(
        "standard deviations (quality.tif): the matching's per independent window and the terrain's curvature the nodes do not resolve{}",
        r.orientation_sigma_m
            .map_or(String::new(), |o| format!(", with the orientations' {o:.3} m"))
    );
    for (what, line) in r.summary() {
        if what == "window averaging" || what == "pairs' agreement" {
            println!("  {what}: {line}");
        }
    }
    for (what, c) in [
        ("check points", &r.model.check_points),
        ("the reference", &r.model.sigma_vs_reference),
    ] {
        if let Some(c) = c {
            let verdict = if c.ratio > 1.5 {
                format!(
                    ": the errors are {:.1} × the standard deviations (errors σ does not hold, as of the interior orientation, a film's scan or terrain breaks, are in them)",
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
        "written to {}: {}",
        out.display(),
        outputs::listed(Some(Writer::Sweep), r.model.comparison.is_some())
    );
    Ok(code)
}

pub fn run(a: DtmArgs) -> anyhow::Result<i32> {
    let (project, out) = match (a.action, a.project, a.out) {
        (Some(DtmAction::Merge { tiles, out, run }), _, _) => return merge(&tiles, &out, run),
        (Some(DtmAction::Pmf { project, out, run }), _, _) => {
            eprintln!(
                "rig dtm: `rig dtm pmf --project P --out D` is now `rig dtm P --out D` (both formats); running that"
            );
            return run_project(&Project::load(&project)?, &out, run);
        }
        (Some(DtmAction::Upgrade { project, out }), _, _) => return upgrade(&project, out),
        (None, Some(project), Some(out)) => (project, out),
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
    let p = Project::load(&project)?;
    if a.tile.is_some() && p.has_approximate_photos() {
        eprintln!(
            "rig dtm --tile: {}'s photos are approximate (position_sigma_m); orient the block once first: rig orient {} --out ORIENTED, then tile ORIENTED/project.toml",
            project.display(),
            project.display()
        );
        return Ok(rig::exit::USAGE);
    }
    match a.tile {
        Some(spec) => run_tile(
            &with_memory(&p, a.run.max_memory),
            spec,
            &out,
            a.run.max_memory,
            a.run.output.json,
        ),
        None => run_project(&p, &out, a.run),
    }
}
