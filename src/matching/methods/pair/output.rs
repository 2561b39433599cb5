//! What `rig match pair` writes: float32 TIFFs on the left photo's pixels (disparity,
//! correlation, σ; NaN where there is no match, named in GDAL's nodata tag), a preview PNG
//! with its colour bar, and the report.

use crate::matching::methods::pair::matcher::{DisparityMap, PairParams, PairStats};
use crate::picture::{colour_bar, save_png, sequential, text, BLACK};
use image::{Rgb, RgbImage};
use serde::Serialize;
use std::path::Path;
use tiff::encoder::{colortype, TiffEncoder};
use tiff::tags::Tag;

/// The files a run writes (an output directory may hold these from an earlier run).
pub const OUTPUTS: &[&str] = &[
    "disparity.tif",
    "correlation.tif",
    "sigma.tif",
    "disparity.png",
    "report.json",
];

/// One float32 band, NaN as nodata, its description in GDAL's metadata. Atomic. Not
/// compressed: Deflate kept four fifths of a disparity map's bytes (its fractions are noise
/// to it) for a fifth of the whole command's time on the benchmark pair.
pub fn write_f32_tiff(
    path: &Path,
    width: usize,
    height: usize,
    data: &[f32],
    description: &str,
) -> std::io::Result<()> {
    let err = crate::matching::products::files::other::<tiff::TiffError>(path);
    if data.len() != width * height {
        return Err(std::io::Error::other(format!(
            "{}: {} values for {width} × {height} px",
            path.display(),
            data.len()
        )));
    }
    crate::atomic::write_with(path, |w| {
        let mut enc = TiffEncoder::new(w).map_err(&err)?;
        let mut img = enc
            .new_image::<colortype::Gray32Float>(width as u32, height as u32)
            .map_err(&err)?;
        img.encoder()
            .write_tag(Tag::GdalNodata, "nan")
            .map_err(&err)?;
        crate::matching::products::files::write_band_descriptions(img.encoder(), &[description])
            .map_err(&err)?;
        img.write_data(data).map_err(&err)
    })
}

/// The disparities in colour (grey where there is none), with a colour bar.
pub fn preview(m: &DisparityMap, range: [f64; 2]) -> RgbImage {
    let margin = 170u32;
    let (w, h) = (m.width as u32, m.height as u32);
    let (ih, top) = (h.max(260) + 40, 30u32);
    let mut img = RgbImage::from_pixel(w + margin, ih, Rgb([255, 255, 255]));
    let span = (range[1] - range[0]).max(1e-9);
    for r in 0..h {
        for c in 0..w {
            let d = m.d[(r * w + c) as usize];
            let px = if d.is_finite() {
                sequential(((d as f64 - range[0]) / span).clamp(0.0, 1.0))
            } else {
                Rgb([128, 128, 128])
            };
            img.put_pixel(c, r + top, px);
        }
    }
    text(
        &mut img,
        4,
        6,
        "disparity d = x_left - x_right; grey: no match",
        1,
        BLACK,
    );
    let bar_h = (h as i64 - 40).clamp(100, 600);
    colour_bar(
        &mut img,
        w as i64 + 30,
        top as i64 + 30,
        24,
        bar_h,
        range[0],
        range[1],
        "px",
        &sequential,
    );
    img
}

#[derive(Serialize)]
struct Report<'a> {
    left: String,
    right: String,
    /// Seconds of the matching itself (reading and writing files not counted), and the
    /// pixel-candidates it scored (pixels × disparities).
    seconds: f64,
    candidates: u64,
    params: &'a PairParams,
    stats: &'a PairStats,
    /// Pixel-candidates per second of the whole match.
    candidates_per_second: f64,
    /// Median σ of the disparities, px.
    sigma_median: Option<f64>,
}

/// Writes every output of a run into `dir` (created).
pub fn write_all(
    dir: &Path,
    m: &DisparityMap,
    p: &PairParams,
    left: &Path,
    right: &Path,
) -> std::io::Result<()> {
    use rayon::prelude::*;
    let bands: [(&str, &[f32], &str); 3] = [
        ("disparity.tif", &m.d, "disparity d = x_left - x_right (px)"),
        (
            "correlation.tif",
            &m.corr,
            "normalised cross-correlation at the match",
        ),
        (
            "sigma.tif",
            &m.sigma,
            "standard deviation of the disparity (px)",
        ),
    ];
    // Written side by side (each file is synced to the disk); the first failure reported.
    let (tiffs, png) = rayon::join(
        || {
            bands
                .par_iter()
                .map(|(name, v, what)| write_f32_tiff(&dir.join(name), m.width, m.height, v, what))
                .collect::<std::io::Result<Vec<()>>>()
        },
        || {
            save_png(
                &preview(m, [p.d_min as f64, p.d_max as f64]),
                &dir.join("disparity.png"),
            )
        },
    );
    tiffs?;
    png?;
    crate::atomic::write_json(&dir.join("report.json"), &report(m, p, left, right))
}

/// The report as JSON (what `--json` prints and report.json holds).
pub fn report(m: &DisparityMap, p: &PairParams, left: &Path, right: &Path) -> serde_json::Value {
    let mut s: Vec<f32> = m.sigma.iter().copied().filter(|v| v.is_finite()).collect();
    let mid = s.len() / 2;
    let median = (!s.is_empty()).then(|| *s.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1);
    let st = &m.stats;
    let r = Report {
        left: left.display().to_string(),
        right: right.display().to_string(),
        seconds: st.seconds_total,
        candidates: st.candidates,
        params: p,
        stats: st,
        candidates_per_second: st.candidates as f64 / st.seconds_total.max(1e-9),
        sigma_median: median.map(|v| v as f64),
    };
    serde_json::to_value(r).unwrap_or(serde_json::Value::Null)
}
