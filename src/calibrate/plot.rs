//! A PNG plot of a fit's residual vectors for a person to read: each point where it lies (in
//! the fit's input coordinates, with their ticks), its residual drawn as a line magnified so
//! the largest reads clearly and coloured by its length (colour bar in the residuals' unit),
//! points the outlier test rejected in grey, a scale bar for the vectors, a title with the
//! RMS and σ0, and a legend. 1040 × 900 px.

use super::affine_fit::Fit;
use crate::picture::{
    colour_bar, fill, frame, line, nice, save_png, sequential, swatch, text, text_width, trim,
    BLACK,
};
use image::{Rgb, RgbImage};
use std::path::Path;

const WIDTH: u32 = 1040;
const HEIGHT: u32 = 900;
/// The plotting square: left, top, side.
const LEFT: f64 = 130.0;
const TOP: f64 = 110.0;
const SIDE: f64 = 640.0;
const REJECTED: Rgb<u8> = Rgb([150, 150, 150]);

/// What the plot says about its data.
pub struct Labels<'a> {
    /// The title, e.g. "pixel → carriage, affine".
    pub title: &'a str,
    /// The input coordinates' name and unit, e.g. "camera pixel (px)".
    pub from: &'a str,
    /// Input coordinates per unit of the axes' labels (1000 to label µm in mm).
    pub from_per_label: f64,
    /// The residuals' unit, e.g. "µm".
    pub unit: &'a str,
    /// Where the residuals lie, e.g. "on the carriage".
    pub residuals: &'a str,
}

/// Draws `fit`'s residuals into `path`.
pub fn residual_plot(fit: &Fit, labels: &Labels, path: &Path) -> std::io::Result<()> {
    let mut img = RgbImage::from_pixel(WIDTH, HEIGHT, Rgb([255, 255, 255]));
    let pts = &fit.residuals;
    let used = pts.iter().filter(|r| !r.rejected).count();
    text(&mut img, 20, 16, labels.title, 3, BLACK);
    let g = |v: f64| trim(crate::picture::significant(v, 3));
    text(
        &mut img,
        20,
        54,
        &format!(
            "RMS x {} y {}, σ0 {} {u}; {used} points used, {} rejected",
            g(fit.rms[0]),
            g(fit.rms[1]),
            g(fit.sigma0),
            pts.len() - used,
            u = labels.unit
        ),
        2,
        BLACK,
    );
    if pts.is_empty() {
        return save_png(&img, path);
    }
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for r in pts {
        for k in 0..2 {
            lo[k] = lo[k].min(r.from[k]);
            hi[k] = hi[k].max(r.from[k]);
        }
    }
    // A margin of 15 % around the points (a vector is at most 12.5 % long), the same scale on
    // both axes.
    let span = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(1e-9) * 1.3;
    let mid = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
    let origin = [mid[0] - 0.5 * span, mid[1] - 0.5 * span];
    // Image convention: y grows downward, as rows and (on this rig) the carriage's y do.
    let at = |p: [f64; 2]| {
        [
            LEFT + (p[0] - origin[0]) / span * SIDE,
            TOP + (p[1] - origin[1]) / span * SIDE,
        ]
    };
    frame(
        &mut img,
        LEFT as i64,
        TOP as i64,
        SIDE as i64 + 1,
        SIDE as i64 + 1,
        BLACK,
    );
    // Ticks on the input coordinates.
    let per = if labels.from_per_label.is_finite() && labels.from_per_label > 0.0 {
        labels.from_per_label
    } else {
        1.0
    };
    let step = nice(span / per / 5.0) * per;
    let mut v = (origin[0] / step).ceil() * step;
    while v <= origin[0] + span {
        let x = (LEFT + (v - origin[0]) / span * SIDE).round() as i64;
        fill(&mut img, x, (TOP + SIDE) as i64, 2, 8, BLACK);
        let l = trim(v / per);
        text(
            &mut img,
            x - text_width(&l, 2) / 2,
            (TOP + SIDE) as i64 + 14,
            &l,
            2,
            BLACK,
        );
        v += step;
    }
    let mut v = (origin[1] / step).ceil() * step;
    while v <= origin[1] + span {
        let y = (TOP + (v - origin[1]) / span * SIDE).round() as i64;
        fill(&mut img, LEFT as i64 - 8, y, 8, 2, BLACK);
        let l = trim(v / per);
        text(
            &mut img,
            LEFT as i64 - 14 - text_width(&l, 2),
            y - 7,
            &l,
            2,
            BLACK,
        );
        v += step;
    }
    text(
        &mut img,
        LEFT as i64,
        (TOP + SIDE) as i64 + 40,
        &format!("x, y: {} (y down)", labels.from),
        2,
        BLACK,
    );
    let vmax = pts
        .iter()
        .map(|r| r.v[0].hypot(r.v[1]))
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max)
        .max(1e-12);
    // The largest residual drawn at an eighth of the plot.
    let mag = SIDE / 8.0 / vmax;
    let top_colour = nice(vmax).max(vmax);
    for r in pts {
        let p = at(r.from);
        let len = r.v[0].hypot(r.v[1]);
        let q = [p[0] + r.v[0] * mag, p[1] + r.v[1] * mag];
        let c = if r.rejected {
            REJECTED
        } else {
            sequential(0.15 + 0.85 * len / top_colour)
        };
        // Three pixels wide so that the colour reads.
        for d in [-1.0, 0.0, 1.0] {
            line(&mut img, [p[0] + d, p[1]], [q[0] + d, q[1]], c);
            line(&mut img, [p[0], p[1] + d], [q[0], q[1] + d], c);
        }
        fill(
            &mut img,
            p[0].round() as i64 - 3,
            p[1].round() as i64 - 3,
            7,
            7,
            BLACK,
        );
    }
    colour_bar(
        &mut img,
        (LEFT + SIDE) as i64 + 50,
        TOP as i64 + 30,
        28,
        400,
        0.0,
        top_colour,
        &format!("|v|, {}", labels.unit),
        &|t| sequential(0.15 + 0.85 * t),
    );
    // Scale bar of the vectors, and the legend under the colour bar.
    let base = HEIGHT as i64 - 50;
    let bar = nice(vmax);
    let x0 = LEFT as i64;
    fill(&mut img, x0, base + 4, (bar * mag).round() as i64, 5, BLACK);
    text(
        &mut img,
        x0 + (bar * mag).round() as i64 + 12,
        base,
        &format!(
            "{} {} ({}: vectors × {})",
            trim(bar),
            labels.unit,
            labels.residuals,
            trim(nice(mag))
        ),
        2,
        BLACK,
    );
    let xl = (LEFT + SIDE) as i64 + 30;
    swatch(&mut img, xl, TOP as i64 + 470, BLACK, "point");
    swatch(&mut img, xl, TOP as i64 + 500, REJECTED, "rejected");
    save_png(&img, path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::affine_fit::{fit, Model};

    #[test]
    fn a_plot_is_drawn_and_scaled() {
        let pts: Vec<_> = (0..9)
            .map(|i| {
                let p = [(i % 3) as f64 * 100.0, (i / 3) as f64 * 100.0];
                (
                    i.to_string(),
                    p,
                    [p[0] * 10.0 + (i as f64 * 0.7).sin(), p[1] * 11.0],
                )
            })
            .collect();
        let f = fit(Model::Affine6, &pts, false).unwrap();
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("r.png");
        let l = Labels {
            title: "pixel -> carriage, affine",
            from: "camera pixel (px)",
            from_per_label: 1.0,
            unit: "µm",
            residuals: "on the carriage",
        };
        residual_plot(&f, &l, &p).unwrap();
        let img = image::open(&p).unwrap().to_rgb8();
        assert!(img.width() >= 800 && img.height() >= 800);
        // The vectors are drawn in the colour bar's colours, inside the plotting square.
        let inside = |x: u32, y: u32| {
            (LEFT as u32..(LEFT + SIDE) as u32).contains(&x)
                && (TOP as u32..(TOP + SIDE) as u32).contains(&y)
        };
        let coloured = img
            .enumerate_pixels()
            .filter(|(x, y, p)| inside(*x, *y) && p.0[0] != p.0[2] && p.0 != [255, 255, 255])
            .count();
        assert!(
            coloured > 100,
            "residual vectors drawn: {coloured} coloured pixels"
        );
        // The largest vector is drawn in the colour its length has on the bar.
        let vmax = f
            .residuals
            .iter()
            .map(|r| r.v[0].hypot(r.v[1]))
            .fold(0.0, f64::max);
        let top = sequential(0.15 + 0.85 * vmax / nice(vmax).max(vmax));
        assert!(img.pixels().any(|p| *p == top));
    }
}
