//! A PNG plot of a fit's residual vectors: each point where it lies, its residual drawn as a
//! red line magnified so the largest reads clearly, points the outlier test rejected in grey,
//! and a scale bar with its length written beside it.

use super::affine_fit::Fit;
use crate::picture::{line, nice, put, save_png, text, trim, BLACK};
use image::{Rgb, RgbImage};
use std::path::Path;

const SIZE: u32 = 640;
const MARGIN: f64 = 60.0;

/// Draws `fit`'s residuals; `unit` labels the scale bar ("um").
pub fn residual_plot(fit: &Fit, unit: &str, path: &Path) -> std::io::Result<()> {
    let mut img = RgbImage::from_pixel(SIZE, SIZE, Rgb([255, 255, 255]));
    let pts = &fit.residuals;
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
        BLACK,
    );
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
        residual_plot(&f, "um", &p).unwrap();
        let img = image::open(&p).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (SIZE, SIZE));
        let red = img.pixels().filter(|p| p.0 == [220, 30, 30]).count();
        assert!(red > 50, "residual vectors drawn: {red} red pixels");
    }
}
