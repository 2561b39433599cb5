//! `rig match pair`: disparities of an epipolar-rectified stereo pair.

use anyhow::Context;
use clap::builder::TypedValueParser;
use clap::{Args, Subcommand, ValueEnum};
use rig::matching::methods::pair::output as pair_output;
use rig::matching::methods::pair::sgm::SgmParams;
use rig::matching::methods::pair::{match_pair, Filter, PairParams, Subpixel};
use rig::matching::methods::sweep::regions::RegionParams;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub struct MatchArgs {
    #[command(subcommand)]
    pub action: MatchAction,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum FilterArg {
    /// Semi-global aggregation of the correlations along 5 or 8 paths, --paths (Hirschmüller 2008).
    Sgm,
    /// Seed 000's region filter: small regions and islands of other disparities removed.
    Regions,
    /// The best correlation per pixel, nothing more.
    None,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum SubpixelArg {
    /// A parabola through the best plane and its two neighbours: of the aggregated costs with
    /// SGM (as Hirschmüller 2008 takes it), else of the correlations (fast).
    Parabola,
    /// Least-squares matching of the winning window, with its σ (slower, more exact).
    Lsm,
}

#[derive(Debug, Subcommand)]
pub enum MatchAction {
    /// Disparities of an epipolar-rectified pair (rows correspond; PNG or TIFF, grey or
    /// colour, colour turned grey as 0.299 R + 0.587 G + 0.114 B).
    ///
    /// The disparity is d = x_left − x_right in whole and fractional pixels, on the left
    /// photo's pixels (Middlebury's and OpenCV's convention). MIN and MAX are inclusive and
    /// may be negative. Every pixel is compared with the right photo at each disparity by
    /// normalised cross-correlation over a window. Disparities whose window lies beyond the
    /// right photo are never a match; a pixel gets no disparity where its best one has such a
    /// neighbour, lies at MIN or MAX (the match may be beyond: a warning says to widen the
    /// range), is not clearly better than every other disparity (--uniqueness), correlates
    /// below --threshold, or where the right photo's own best match points elsewhere
    /// (left-right check). A warning says when fewer than half the pixels match (a range that
    /// misses the scene, photos not rectified or not of one scene). At most 4096 disparities,
    /// within ±1 000 000 px.
    ///
    /// Writes into --out: disparity.tif (float32, NaN where there is no match),
    /// correlation.tif, sigma.tif (σ of each disparity, px), disparity.png (a preview with its
    /// colour bar) and report.json (what was done, and why pixels have no disparity).
    ///
    /// Examples:
    ///   rig match pair left.png right.png --disparity 0 63 --out match
    ///   rig match pair l.tif r.tif --disparity -20 40 --filter regions --subpixel lsm --out m
    ///   rig match pair l.png r.png --disparity 0 127 --out m --json | jq .stats.matched
    #[command(verbatim_doc_comment)]
    Pair {
        /// The left photo (the disparities lie on its pixels).
        left: PathBuf,
        /// The right photo: the same number of rows.
        right: PathBuf,
        /// The disparities searched, whole pixels, both inclusive.
        #[arg(long, num_args = 2, value_names = ["MIN", "MAX"], allow_negative_numbers = true, required = true)]
        disparity: Vec<i64>,
        /// Output directory (created; empty, or holding only an earlier run's outputs).
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// Side of the correlation window, px (odd, 3 … 31). Default 5 with --filter sgm, 7
        /// otherwise: without aggregation a pixel has only its window's evidence (on the
        /// benchmark pair, bad-2 3.7 % with 7 against 7.0 % with 5; SGM is best with 5).
        #[arg(long)]
        window: Option<usize>,
        /// Lowest correlation accepted at the match (−1 … 1).
        #[arg(long, default_value_t = 0.3, allow_negative_numbers = true)]
        threshold: f64,
        #[arg(long, value_enum, default_value = "sgm")]
        filter: FilterArg,
        #[arg(long, value_enum, default_value = "parabola")]
        subpixel: SubpixelArg,
        /// Largest disagreement between the left's and the right's disparity, px; 0 turns the
        /// check off.
        #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
        lr_tolerance: f64,
        /// Uniqueness ratio, percent: every disparity beyond the winner's two neighbours must
        /// cost at least 100/(100 − PERCENT) times the winner's cost (the aggregated cost with
        /// SGM, 1 − correlation without), else the pixel is ambiguous and gets no match
        /// (Hirschmüller 2008; OpenCV's uniquenessRatio). 0 turns the test off.
        #[arg(long, default_value_t = 10.0, value_name = "PERCENT")]
        uniqueness: f64,
        /// SGM penalty for a change of one disparity between neighbours, in cost units (256
        /// is the cost of an uncorrelated window; 0 … 65534, below --p2).
        #[arg(long, default_value_t = SgmParams::default().p1)]
        p1: u16,
        /// SGM penalty for a larger change (a discontinuity), in the same units.
        #[arg(long, default_value_t = SgmParams::default().p2)]
        p2: u16,
        /// SGM's paths: 5 (along the row both ways and three from the row before, in one
        /// pass that keeps no volume: OpenCV's default) or 8 (Hirschmüller's, over a volume of
        /// 2 bytes per pixel and disparity; on the benchmark pair bad-2 2.1 % against 2.3 %,
        /// sub-pixel RMSE 0.17 against 0.19 px, at 2–3 × the time and 5 × the memory).
        #[arg(long, default_value = "5", value_parser = clap::builder::PossibleValuesParser::new(["5", "8"]).map(|v| if v == "8" { 8u8 } else { 5u8 }))]
        paths: u8,
        /// Most memory the run may take, MiB.
        #[arg(long, value_name = "MIB", default_value_t = 4096, value_parser = clap::value_parser!(u64).range(16..=1_048_576))]
        max_memory: u64,
        #[command(flatten)]
        output: super::shared_args::JsonOutput,
    },
}

pub fn run(a: MatchArgs) -> anyhow::Result<i32> {
    let MatchAction::Pair {
        left,
        right,
        disparity,
        out,
        window,
        threshold,
        filter,
        subpixel,
        lr_tolerance,
        uniqueness,
        p1,
        p2,
        paths,
        max_memory,
        output: super::shared_args::JsonOutput { json },
    } = a.action;
    if !(lr_tolerance.is_finite() && (0.0..=1000.0).contains(&lr_tolerance)) {
        eprintln!("rig match pair: --lr-tolerance {lr_tolerance}: 0 (no check) to 1000 px");
        return Ok(rig::exit::USAGE);
    }
    if p1 >= p2 {
        eprintln!("rig match pair: --p1 {p1} must be below --p2 {p2}");
        return Ok(rig::exit::USAGE);
    }
    if out.exists() && !out.is_dir() {
        eprintln!(
            "rig match pair: --out {} is a file: give a directory (new, or holding an earlier run's outputs)",
            out.display()
        );
        return Ok(rig::exit::USAGE);
    }
    let foreign = rig::atomic::foreign_files(&out, |f| pair_output::OUTPUTS.contains(&f))
        .with_context(|| format!("reading {}", out.display()))?;
    if !foreign.is_empty() {
        eprintln!(
            "rig match pair: {} holds other files ({}): give a new or empty directory",
            out.display(),
            foreign.join(", ")
        );
        return Ok(rig::exit::USAGE);
    }
    // Found out before the work, not after it.
    std::fs::create_dir_all(&out).with_context(|| {
        format!(
            "creating the output directory {} (give a directory you can write to)",
            out.display()
        )
    })?;
    let max_bytes = max_memory.saturating_mul(1 << 20);
    let l = rig::image::load_luma(&left, max_bytes)?;
    let r = rig::image::load_luma(&right, max_bytes)?;
    let p = PairParams {
        d_min: disparity[0],
        d_max: disparity[1],
        window: window.unwrap_or(match filter {
            FilterArg::Sgm => 5,
            FilterArg::Regions | FilterArg::None => 7,
        }),
        threshold,
        filter: match filter {
            FilterArg::Sgm => Filter::Sgm,
            FilterArg::Regions => Filter::Regions,
            FilterArg::None => Filter::None,
        },
        sgm: SgmParams { p1, p2, paths },
        regions: RegionParams {
            search_distance: 2,
            height_threshold: 1.5,
            population_threshold: 50,
        },
        lr_tolerance: (lr_tolerance > 0.0).then_some(lr_tolerance),
        uniqueness: uniqueness / 100.0,
        subpixel: match subpixel {
            SubpixelArg::Parabola => Subpixel::Parabola,
            SubpixelArg::Lsm => Subpixel::Lsm,
        },
    };
    let bar = super::progress_bar::Bar::new(!json);
    let m = match match_pair(&l, &r, &p, max_memory, &bar) {
        Ok(m) => m,
        Err(e) => {
            eprintln!("rig match pair: {e}");
            return Ok(rig::exit::USAGE);
        }
    };
    pair_output::write_all(&out, &m, &p, &left, &right)?;
    let report = pair_output::report(&m, &p, &left, &right);
    let s = &m.stats;
    if s.at_range_end as f64 > 0.01 * s.pixels.max(1) as f64 {
        eprintln!(
            "rig match pair: warning: {:.1} % of the pixels had their best correlation at MIN or MAX: the disparities may reach beyond {} … {}; widen --disparity",
            100.0 * s.at_range_end as f64 / s.pixels as f64,
            p.d_min,
            p.d_max
        );
    }
    // Most windows flat or on no data: little could be matched at all.
    if s.pixels > 0 && s.unscored as f64 > 0.5 * s.pixels as f64 {
        eprintln!(
            "rig match pair: warning: {:.1} % of the pixels have a flat window or no data (NaN) in it: nothing to match there (is the left photo blank, or mostly no data?)",
            100.0 * s.unscored as f64 / s.pixels as f64
        );
    }
    // Few matches where the photo has texture: as a rule a disparity range that misses the
    // scene (the winners are wrong, and the left-right check or the threshold refuse them).
    let seen = s.pixels.saturating_sub(s.unseen + s.unscored);
    if s.pixels > 0 && (s.matched as f64) < 0.5 * seen as f64 {
        eprintln!(
            "rig match pair: warning: only {:.1} % of the pixels the right photo sees were matched ({} ambiguous, {} left-right check, {} below threshold): the disparities may lie outside {} … {}, or the photos may not be rectified (rows must correspond)",
            100.0 * s.matched as f64 / seen.max(1) as f64,
            s.ambiguous,
            s.left_right,
            s.below_threshold,
            p.d_min,
            p.d_max
        );
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(0);
    }
    let pct = |n: usize| 100.0 * n as f64 / s.pixels.max(1) as f64;
    println!(
        "{} × {} px, disparities {} … {} ({}), window {} px, --filter {}, --subpixel {}, --lr-tolerance {}",
        s.width,
        s.height,
        p.d_min,
        p.d_max,
        s.disparities,
        p.window,
        format!("{:?}", p.filter).to_lowercase(),
        format!("{:?}", p.subpixel).to_lowercase(),
        p.lr_tolerance.map_or("0 (no check)".to_string(), |t| t.to_string())
    );
    println!(
        "matched {:.1} % of {} pixels; no match: right photo does not see {:.1} %, flat or no data {:.1} %, best at MIN or MAX {:.1} %, ambiguous {:.1} %, below threshold {:.1} %, left-right check {:.1} %, regions {:.1} %",
        pct(s.matched),
        s.pixels,
        pct(s.unseen),
        pct(s.unscored),
        pct(s.at_range_end),
        pct(s.ambiguous),
        pct(s.below_threshold),
        pct(s.left_right),
        pct(s.regions)
    );
    if p.subpixel == Subpixel::Lsm {
        println!(
            "least squares refined {:.1} % of the matches; failed: {:?}",
            100.0 * s.lsm_refined as f64 / s.matched.max(1) as f64,
            s.lsm_failures
        );
    }
    println!(
        "{:.2} s ({:.0} M pixel-candidates/s); written to {}/ (disparity.tif, correlation.tif, sigma.tif, disparity.png, report.json)",
        s.seconds_total,
        s.candidates as f64 / s.seconds_total.max(1e-9) / 1e6,
        out.display()
    );
    Ok(0)
}
