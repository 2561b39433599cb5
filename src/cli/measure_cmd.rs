//! `rig measure`: a mark (fiducial or cross) in any image, by coarse location and
//! least-squares matching, with its σ and the gate's verdict.

use anyhow::Context;
use clap::Args;
use rig::coords::PixelXY;
use rig::digitise::estimate_stripes;
use rig::targets::lsm::match_work;
use rig::targets::mark_file::MarkFile;
use rig::targets::measure::{
    scale_rotation, BlurSearch, MarkTemplates, Measurer, Quality, Stripes, BLUR_DRAWINGS, BLUR_GRID,
};
use rig::targets::template::render_work;
use rig::targets::{coarse::locate_work, Geometry};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// `rig measure`: the flags (the command's help is on [`super::Command::Measure`]).
#[derive(Debug, Args)]
pub struct MeasureArgs {
    /// The images (one mark measured in each).
    #[arg(required_unless_present = "list", value_name = "IMAGE")]
    pub images: Vec<PathBuf>,
    /// Also the images listed in FILE, one path per line (relative to FILE's folder; blank
    /// lines and lines starting with # left out).
    #[arg(long, value_name = "FILE")]
    pub list: Option<PathBuf>,
    /// The mark file.
    #[arg(long, value_name = "MARK.toml")]
    pub mark: PathBuf,
    /// The pixel size in µm along columns and rows (one value for square pixels): needed
    /// when the mark file's units are "um".
    #[arg(long, value_name = "SX[,SY]")]
    pub pixel_um: Option<String>,
    /// Where to look for the mark: COL,ROW in the pixel convention above.
    #[arg(long, value_name = "COL,ROW", allow_hyphen_values = true)]
    pub near: Option<String>,
    /// How far from --near the centre may lie, px.
    #[arg(
        long,
        value_name = "PX",
        default_value_t = 20.0,
        requires = "near",
        allow_hyphen_values = true
    )]
    pub search: f64,
    /// The optics' blur in the images, a Gaussian σ in px (0 … 20). Without it, each image's
    /// blur is found by least squares (the blur whose template leaves the least residual).
    #[arg(long, value_name = "PX")]
    pub blur: Option<f64>,
    /// Largest σ of the centre accepted, px.
    #[arg(long, value_name = "PX", default_value_t = Quality::default().max_sigma_px)]
    pub max_sigma: f64,
    /// Largest share of the evidence (the template's squared gradients) on outlying
    /// residuals accepted, percent.
    #[arg(long, value_name = "PERCENT", default_value_t = 100.0 * Quality::default().max_outlier_share)]
    pub max_outliers: f64,
    /// Largest share of the mark's own pixels (where its template has a gradient) with
    /// outlying residuals accepted, percent.
    #[arg(long, value_name = "PERCENT", default_value_t = 100.0 * Quality::default().max_outlier_pixels)]
    pub max_outlier_pixels: f64,
    /// Smallest share of the mark inside the image accepted, percent.
    #[arg(long, value_name = "PERCENT", default_value_t = 100.0 * Quality::default().min_inside_share)]
    pub min_inside: f64,
    /// Most work the search for the mark in one image, or drawing its templates, may take, in
    /// billions of template-pixel visits or sample tests (a 4000 × 3000 image with a 60-px
    /// mark takes about 3, drawing a 60-px mark 0.2): use --near and --search on larger
    /// images.
    #[arg(long, value_name = "G", default_value_t = 5.0)]
    pub max_work: f64,
    /// Remove the camera's stripe noise (the shift between the video fields, the periodic
    /// column pattern) as estimated from IMAGE, a flat or a full frame of the same camera with
    /// the same columns as the images measured. Without it (and without --keep-stripes) the
    /// stripes are estimated from each image itself, off the mark's footprint.
    #[arg(long, value_name = "IMAGE")]
    pub stripes_from: Option<PathBuf>,
    /// Measure the images as they are, their stripes left in: for images already destriped,
    /// or of a camera without stripes (the estimate from the image costs a second match).
    #[arg(long, conflicts_with = "stripes_from")]
    pub keep_stripes: bool,
    /// The default since the stripes are estimated from each image unless --stripes-from or
    /// --keep-stripes says otherwise; kept so that scripts that give it still run.
    #[arg(long, hide = true, conflicts_with_all = ["stripes_from", "keep_stripes"])]
    pub destripe: bool,
    #[command(flatten)]
    pub output: super::shared_args::JsonOutput,
    /// Also write the results as CSV (one row per image, atomically).
    #[arg(long, value_name = "FILE")]
    pub csv: Option<PathBuf>,
    /// Exit with code 12 when any mark is refused.
    #[arg(long)]
    pub strict: bool,
}

/// One image's result, in the pixel convention (docs/conventions.md).
#[derive(Debug, Serialize)]
struct Row {
    image: String,
    col: Option<f64>,
    row: Option<f64>,
    sigma_col: Option<f64>,
    sigma_row: Option<f64>,
    rotation_deg: Option<f64>,
    scale: Option<f64>,
    correlation: Option<f64>,
    /// The blur used (found, or given).
    blur_px: Option<f64>,
    /// Shares of the evidence and of the mark's pixels on outlying residuals (the gate's
    /// `damaged`).
    outlier_share: Option<f64>,
    outlier_pixels: Option<f64>,
    iterations: Option<u32>,
    converged: bool,
    accepted: bool,
    /// A code (see --help), null when accepted.
    reason: Option<String>,
    /// The reason in words.
    message: Option<String>,
}

/// Most images in one run (each one's result is kept until the end).
const MAX_IMAGES: usize = 1_000_000;
/// Largest list file read.
const MAX_LIST_BYTES: u64 = 64 << 20;

const CSV_COLUMNS: [&str; 16] = [
    "image",
    "col",
    "row",
    "sigma_col",
    "sigma_row",
    "rotation_deg",
    "scale",
    "correlation",
    "blur_px",
    "outlier_share",
    "outlier_pixels",
    "iterations",
    "converged",
    "accepted",
    "reason",
    "message",
];

fn usage(what: String) -> anyhow::Result<i32> {
    eprintln!("rig measure: {what}");
    Ok(rig::exit::USAGE)
}

/// "A" or "A,B" as one or two finite numbers.
fn pair(s: &str) -> Option<[f64; 2]> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .ok()?;
    let v = match v.as_slice() {
        [a] => [*a, *a],
        [a, b] => [*a, *b],
        _ => return None,
    };
    v.iter().all(|x| x.is_finite()).then_some(v)
}

pub fn run(a: MeasureArgs) -> anyhow::Result<i32> {
    let pixel_um = match &a.pixel_um {
        None => None,
        Some(s) => match pair(s) {
            Some(p) if p.iter().all(|v| (0.01..=1000.0).contains(v)) => Some(p),
            _ => {
                return usage(format!(
                    "--pixel-um {s}: one or two sizes (SX or SX,SY), 0.01 to 1000 µm"
                ))
            }
        },
    };
    let near = match &a.near {
        None => None,
        Some(s) => match pair(s) {
            Some(p) if s.contains(',') && p.iter().all(|v| v.abs() <= 1e7) => {
                Some(PixelXY::new(p[0] + 0.5, p[1] + 0.5))
            }
            _ => return usage(format!("--near {s}: COL,ROW in pixels (within ±10⁷)")),
        },
    };
    if !(a.search.is_finite() && (0.0..=100_000.0).contains(&a.search)) {
        return usage(format!("--search {}: 0 to 100000 px", a.search));
    }
    if let Some(b) = a.blur {
        if !(b.is_finite() && (0.0..=20.0).contains(&b)) {
            return usage(format!("--blur {b}: 0 to 20 px"));
        }
    }
    if !(a.max_sigma.is_finite() && a.max_sigma > 0.0 && a.max_sigma <= 100.0) {
        return usage(format!(
            "--max-sigma {}: above 0, at most 100 px",
            a.max_sigma
        ));
    }
    for (name, v) in [
        ("--max-outliers", a.max_outliers),
        ("--max-outlier-pixels", a.max_outlier_pixels),
        ("--min-inside", a.min_inside),
    ] {
        if !(v.is_finite() && (0.0..=100.0).contains(&v)) {
            return usage(format!("{name} {v}: 0 to 100 percent"));
        }
    }
    if !(a.max_work.is_finite() && a.max_work > 0.0 && a.max_work <= 1e6) {
        return usage(format!("--max-work {}: above 0, at most 10⁶", a.max_work));
    }
    let mark = MarkFile::load(&a.mark)?;
    if mark.units == rig::targets::mark_file::Units::Px && pixel_um.is_some() {
        eprintln!(
            "rig measure: note: {} gives its sizes in px; --pixel-um is not used",
            a.mark.display()
        );
    }
    let (shape, um_per_px) = match mark.in_um(pixel_um) {
        Ok(v) => v,
        Err(e) => return usage(e),
    };
    let px = um_per_px[0][0].min(um_per_px[1][1]);
    let reach_px = shape.reach_um() / px;
    let widest = a.blur.unwrap_or(BLUR_GRID[BLUR_GRID.len() - 1]);
    let patch = (2.0 * reach_px + 2.0 * (3.0 * widest + 4.0)).ceil() as usize | 1;
    let context = || format!("the mark of {}", a.mark.display());
    // Drawing the templates (each blur tried: the grid and up to four refinements per image,
    // the drawings kept on a 0.02 px grid) before anything is drawn.
    let renders = if a.blur.is_some() {
        1.0
    } else {
        BLUR_DRAWINGS as f64
    };
    // Drawing, and matching the patch once per drawing in each image.
    let drawing = renders * (render_work(&shape, patch) + match_work(patch)) / 1e9;
    if drawing > a.max_work {
        return usage(format!(
            "the mark of {} reaches {reach_px:.0} px: drawing its templates would take {drawing:.0} G \
             sample tests (--max-work {}): check its sizes, units and --pixel-um, or raise --max-work",
            a.mark.display(),
            a.max_work
        ));
    }
    let mut how = match a.blur {
        Some(b) => Measurer::Fixed {
            templates: MarkTemplates::new(&shape, mark.polarity, um_per_px, patch, b)
                .map_err(anyhow::Error::msg)
                .with_context(context)?,
            blur_px: b,
        },
        None => Measurer::Search(
            BlurSearch::new(&shape, mark.polarity, um_per_px, patch)
                .map_err(anyhow::Error::msg)
                .with_context(context)?,
        ),
    };
    let (whole_size, geometry) = (how.whole().size(), how.geometry());
    let quality = Quality {
        max_sigma_px: a.max_sigma,
        max_outlier_share: a.max_outliers / 100.0,
        max_outlier_pixels: a.max_outlier_pixels / 100.0,
        min_inside_share: a.min_inside / 100.0,
        ..Quality::default()
    };
    let max_bytes = 4u64 << 30;
    let mut images = a.images.clone();
    if let Some(list) = &a.list {
        let size = std::fs::metadata(list)
            .with_context(|| format!("reading the list {}", list.display()))?
            .len();
        if size > MAX_LIST_BYTES {
            return usage(format!(
                "--list {}: {size} bytes; at most {MAX_LIST_BYTES} (split the list)",
                list.display()
            ));
        }
        let text = std::fs::read_to_string(list)
            .with_context(|| format!("reading the list {}", list.display()))?;
        let base = list.parent().unwrap_or(Path::new("."));
        for line in text.lines().map(str::trim) {
            if !line.is_empty() && !line.starts_with('#') {
                images.push(base.join(line));
            }
        }
        if images.len() > MAX_IMAGES {
            return usage(format!(
                "{} images: at most {MAX_IMAGES} in one run (split the list)",
                images.len()
            ));
        }
    }
    if images.is_empty() {
        return usage("no images: give IMAGE… or a --list that names some".into());
    }
    let (stripes, flat_width) = match &a.stripes_from {
        None if a.keep_stripes => (Stripes::Keep, None),
        None => (Stripes::FromImage, None),
        Some(p) => {
            let flat = rig::image::load_luma(p, max_bytes)?;
            if flat.data.iter().any(|v| v.is_nan()) {
                anyhow::bail!(
                    "{}: NaN grey values: a flat needs a value at every pixel",
                    p.display()
                );
            }
            let e = estimate_stripes(&flat);
            if e.column_period.is_none() && !a.output.json {
                eprintln!(
                    "rig measure: note: {} shows no column pattern; only the field shift ({:.2} DN) is removed",
                    p.display(),
                    e.field_offset
                );
            }
            (Stripes::Known(e), Some((p.clone(), flat.width)))
        }
    };
    let mut rows = Vec::with_capacity(a.images.len());
    for path in &images {
        let img = rig::image::load_luma(path, max_bytes)?;
        if img.data.iter().any(|v| v.is_nan()) {
            anyhow::bail!(
                "{}: NaN grey values: marks are measured on images with a value at every pixel",
                path.display()
            );
        }
        let mut img = img;
        if let Some((p, w)) = &flat_width {
            if img.width != *w {
                anyhow::bail!(
                    "{}: {} px wide, but the stripes were estimated on {} ({w} px wide): give a \
                     flat of the same camera and geometry",
                    path.display(),
                    img.width,
                    p.display()
                );
            }
        }
        let near = near.map(|p| (p, a.search));
        let (sw, sh) = match near {
            Some((_, s)) => {
                let side = (2.0 * s + whole_size as f64 + 2.0) as usize;
                (side.min(img.width), side.min(img.height))
            }
            None => (img.width, img.height),
        };
        let work = locate_work(sw, sh, whole_size) / 1e9;
        if work > a.max_work {
            anyhow::bail!(
                "{}: finding the mark in {sw} × {sh} px would take {work:.0} G template-pixel visits \
                 (--max-work {}): give --near COL,ROW and --search PX, or raise --max-work",
                path.display(),
                a.max_work
            );
        }
        let (r, blur, _) = how.measure_destriped(&mut img, &stripes, &quality, near);
        let m = r.lsm.as_ref();
        let sr = m.and_then(|m| scale_rotation(m, um_per_px));
        rows.push(Row {
            image: path.display().to_string(),
            col: r.seen_at().map(|p| p.col - 0.5),
            row: r.seen_at().map(|p| p.row - 0.5),
            sigma_col: m.map(|m| m.sigma_px[0]),
            sigma_row: m.map(|m| m.sigma_px[1]),
            rotation_deg: sr.filter(|_| geometry != Geometry::ShiftScale).map(|s| s.1),
            scale: sr.map(|s| s.0),
            correlation: m.map(|m| m.correlation),
            blur_px: blur,
            outlier_share: m.map(|m| m.outlier_share),
            outlier_pixels: m.map(|m| m.outlier_pixels),
            iterations: m.map(|m| m.iterations),
            converged: m.is_some(),
            accepted: r.refusal.is_none() && m.is_some(),
            reason: r.refusal.as_ref().map(|x| x.code().to_string()),
            message: r.rejected.clone(),
        });
    }
    if let Some(csv) = &a.csv {
        rig::atomic::write(csv, to_csv(&rows).as_bytes())
            .with_context(|| format!("writing {}", csv.display()))?;
    }
    if a.output.json {
        if rows.len() == 1 {
            println!("{}", serde_json::to_string_pretty(&rows[0])?);
        } else {
            println!("{}", serde_json::to_string_pretty(&rows)?);
        }
    } else {
        print_rows(&rows, &mark.path);
    }
    let refused = rows.iter().filter(|r| !r.accepted).count();
    Ok(if a.strict && refused > 0 {
        rig::exit::DOUBTFUL
    } else {
        rig::exit::OK
    })
}

fn print_rows(rows: &[Row], mark: &Path) {
    println!(
        "{} image(s), mark {} (col, row: integer values at pixel centres)",
        rows.len(),
        mark.display()
    );
    for r in rows {
        match (r.col, r.row, r.sigma_col, r.sigma_row) {
            (Some(c), Some(w), Some(sc), Some(sw)) => println!(
                "{}: {:.4} ± {:.4}, {:.4} ± {:.4} px; scale {:.4}{}; correlation {:.4}; blur {:.2} px; {} iterations; {}",
                r.image,
                c,
                sc,
                w,
                sw,
                r.scale.unwrap_or(f64::NAN),
                r.rotation_deg
                    .map(|d| format!(", rotation {d:+.3}°"))
                    .unwrap_or_default(),
                r.correlation.unwrap_or(f64::NAN),
                r.blur_px.unwrap_or(f64::NAN),
                r.iterations.unwrap_or(0),
                match &r.message {
                    None => "accepted".to_string(),
                    Some(m) => format!("REFUSED: {m}"),
                }
            ),
            (Some(c), Some(w), _, _) => println!(
                "{}: seen near {c:.1}, {w:.1}, not measured: {}",
                r.image,
                r.message.as_deref().unwrap_or("?")
            ),
            _ => println!(
                "{}: {}",
                r.image,
                r.message.as_deref().unwrap_or("?")
            ),
        }
    }
}

/// One field: numbers in full precision, empty for none, text quoted when it must be.
fn field(s: Option<String>) -> String {
    match s {
        None => String::new(),
        Some(s) if s.contains([',', '"', '\n', '\r']) => format!("\"{}\"", s.replace('"', "\"\"")),
        Some(s) => s,
    }
}

fn to_csv(rows: &[Row]) -> String {
    let mut out = CSV_COLUMNS.join(",") + "\n";
    let num = |v: Option<f64>| v.map(|x| x.to_string());
    for r in rows {
        let fields = [
            field(Some(r.image.clone())),
            field(num(r.col)),
            field(num(r.row)),
            field(num(r.sigma_col)),
            field(num(r.sigma_row)),
            field(num(r.rotation_deg)),
            field(num(r.scale)),
            field(num(r.correlation)),
            field(num(r.blur_px)),
            field(num(r.outlier_share)),
            field(num(r.outlier_pixels)),
            field(r.iterations.map(|i| i.to_string())),
            r.converged.to_string(),
            r.accepted.to_string(),
            field(r.reason.clone()),
            field(r.message.clone()),
        ];
        out += &fields.join(",");
        out.push('\n');
    }
    out
}
