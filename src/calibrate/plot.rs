//! A PNG plot of a fit's residual vectors: each point where it lies, its residual drawn as a
//! red line magnified so the largest reads clearly, points the outlier test rejected in grey,
//! and a scale bar with its length written beside it.

use super::affine_fit::Fit;
use image::{Rgb, RgbImage};
use std::path::Path;

const SIZE: u32 = 640;
const MARGIN: f64 = 60.0;

/// 3×5 glyphs for the scale bar's label.
fn glyph(c: char) -> [u8; 5] {
    match c {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '.' => [0, 0, 0, 0, 2],
        'u' => [0, 5, 5, 5, 7],
        'm' => [0, 7, 7, 5, 5],
        'p' => [0, 7, 5, 7, 4],
        'x' => [0, 5, 2, 5, 5],
        _ => [0; 5],
    }
}

pub(crate) fn text(img: &mut RgbImage, x: i64, y: i64, s: &str, scale: i64) {
    for (k, c) in s.chars().enumerate() {
        let g = glyph(c);
        for (r, bits) in g.iter().enumerate() {
            for col in 0..3 {
                if bits & (4 >> col) != 0 {
                    for dy in 0..scale {
                        for dx in 0..scale {
                            put(
                                img,
                                x + (k as i64 * 4 + col) * scale + dx,
                                y + r as i64 * scale + dy,
                                Rgb([0, 0, 0]),
                            );
                        }
                    }
                }
            }
        }
    }
}

pub(crate) fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && x < img.width() as i64 && y < img.height() as i64 {
        img.put_pixel(x as u32, y as u32, c);
    }
}

pub(crate) fn line(img: &mut RgbImage, a: [f64; 2], b: [f64; 2], c: Rgb<u8>) {
    let n = ((b[0] - a[0]).abs().max((b[1] - a[1]).abs()).ceil() as i64).max(1);
    for k in 0..=n {
        let t = k as f64 / n as f64;
        let (x, y) = (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]));
        for (dx, dy) in [(0, 0), (1, 0), (0, 1)] {
            put(img, x.round() as i64 + dx, y.round() as i64 + dy, c);
        }
    }
}

/// A round length near `v`: 1, 2 or 5 × 10ⁿ.
fn nice(v: f64) -> f64 {
    let e = v.log10().floor();
    let b = 10f64.powf(e);
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * b)
        .rfind(|x| *x <= v)
        .unwrap_or(b)
}

/// Draws `fit`'s residuals; `unit` labels the scale bar ("um").
pub fn residual_plot(fit: &Fit, unit: &str, path: &Path) -> std::io::Result<()> {
    let mut img = RgbImage::from_pixel(SIZE, SIZE, Rgb([255, 255, 255]));
    let pts = &fit.residuals;
    if pts.is_empty() {
        return img
            .save(path)
            .map_err(|e| std::io::Error::other(e.to_string()));
    }
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for r in pts {
        for k in 0..2 {
            lo[k] = lo[k].min(r.from[k]);
            hi[k] = hi[k].max(r.from[k]);
        }
    }
    let span = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(1e-9);
    let inner = SIZE as f64 - 2.0 * MARGIN;
    // Image convention: y grows downward, as rows and (on this rig) the carriage's y do.
    let at = |p: [f64; 2]| {
        [
            MARGIN + (p[0] - lo[0]) / span * inner,
            MARGIN + (p[1] - lo[1]) / span * inner,
        ]
    };
    let vmax = pts
        .iter()
        .map(|r| r.v[0].hypot(r.v[1]))
        .fold(0.0, f64::max)
        .max(1e-12);
    // The largest residual drawn at an eighth of the plot.
    let mag = inner / 8.0 / vmax;
    let frame = Rgb([200, 200, 200]);
    for (a, b) in [
        (
            [MARGIN / 2.0, MARGIN / 2.0],
            [SIZE as f64 - MARGIN / 2.0, MARGIN / 2.0],
        ),
        (
            [SIZE as f64 - MARGIN / 2.0, MARGIN / 2.0],
            [SIZE as f64 - MARGIN / 2.0, SIZE as f64 - MARGIN / 2.0],
        ),
        (
            [SIZE as f64 - MARGIN / 2.0, SIZE as f64 - MARGIN / 2.0],
            [MARGIN / 2.0, SIZE as f64 - MARGIN / 2.0],
        ),
        (
            [MARGIN / 2.0, SIZE as f64 - MARGIN / 2.0],
            [MARGIN / 2.0, MARGIN / 2.0],
        ),
    ] {
        line(&mut img, a, b, frame);
    }
    for r in pts {
        let p = at(r.from);
        let q = [p[0] + r.v[0] * mag, p[1] + r.v[1] * mag];
        let c = if r.rejected {
            Rgb([150, 150, 150])
        } else {
            Rgb([220, 30, 30])
        };
        line(&mut img, p, q, c);
        for dy in -2..=2 {
            for dx in -2..=2 {
                put(
                    &mut img,
                    p[0].round() as i64 + dx,
                    p[1].round() as i64 + dy,
                    Rgb([0, 0, 0]),
                );
            }
        }
    }
    // Scale bar, bottom left.
    let bar = nice(vmax);
    let y = SIZE as f64 - MARGIN / 2.0 + 12.0;
    let y = y.min(SIZE as f64 - 8.0);
    line(
        &mut img,
        [MARGIN, y],
        [MARGIN + bar * mag, y],
        Rgb([220, 30, 30]),
    );
    let label = format!("{} {unit}", trim(bar));
    text(
        &mut img,
        (MARGIN + bar * mag + 10.0) as i64,
        y as i64 - 5,
        &label,
        2,
    );
    img.save(path)
        .map_err(|e| std::io::Error::other(e.to_string()))
}

fn trim(v: f64) -> String {
    let s = format!("{v:.4}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::affine_fit::{fit, Model};

    #[test]
    fn a_plot_is_drawn_and_scaled() {
        assert_eq!(nice(0.37), 0.2);
        assert_eq!(nice(7.0), 5.0);
        assert_eq!(trim(0.5), "0.5");
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
        residual_plot(&f, "um", &p).unwrap();
        let img = image::open(&p).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (SIZE, SIZE));
        let red = img.pixels().filter(|p| p.0 == [220, 30, 30]).count();
        assert!(red > 50, "residual vectors drawn: {red} red pixels");
    }
}
