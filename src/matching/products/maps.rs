//! Maps of a model for a person to read at a glance: at least 800 px wide, north up, with a
//! title, a colour bar in its units, a scale bar, a north arrow and a legend — the hillshade
//! (heights in colour, shaded by a sun from the north-west, 45° up), the differences from a
//! reference, and the heights' standard deviations.

use crate::geometry::Crs;
use crate::matching::grid::ElevationGrid;
use crate::picture::{
    colour_bar, diverging, frame, north_arrow, save_png, scale_bar, sequential, swatch, terrain,
    text, BLACK, WHITE,
};
use image::{Rgb, RgbImage};
use std::path::Path;

/// The narrowest map drawn, px (the "at least 800 px wide").
pub const MIN_MAP_PX: usize = 800;
/// The widest: larger grids are drawn every n-th node.
pub const MAX_MAP_PX: usize = 4000;
const NO_HEIGHT: Rgb<u8> = Rgb([200, 215, 235]);
const LEFT: i64 = 30;
const TOP: i64 = 80;
const RIGHT: i64 = 200;
const BOTTOM: i64 = 110;

/// Pixels per node (k ≥ 1) and nodes per pixel (s ≥ 1) for a grid of `cols × rows` nodes: at
/// least [`MIN_MAP_PX`] wide where the height allows, neither side above [`MAX_MAP_PX`].
fn zoom(cols: usize, rows: usize) -> (usize, usize) {
    let (cols, rows) = (cols.max(1), rows.max(1));
    let s = cols.max(rows).div_ceil(MAX_MAP_PX).max(1);
    if s > 1 {
        return (1, s);
    }
    let k = MIN_MAP_PX.div_ceil(cols).min(MAX_MAP_PX / rows).max(1);
    (k, 1)
}

/// Node values sampled at map pixel (x, y): bilinear between the four nodes around it, NaN when
/// one of them has no value (so nodata keeps its edges).
fn sampler(
    values: &[f32],
    cols: usize,
    rows: usize,
    k: usize,
    s: usize,
) -> impl Fn(usize, usize) -> f32 + '_ {
    move |x, y| {
        let fc = ((x as f64 + 0.5) / k as f64 - 0.5) * s as f64;
        let fr = ((y as f64 + 0.5) / k as f64 - 0.5) * s as f64;
        let fc = fc.clamp(0.0, (cols - 1) as f64);
        let fr = fr.clamp(0.0, (rows - 1) as f64);
        let (c, r) = (fc.floor() as usize, fr.floor() as usize);
        let (c1, r1) = ((c + 1).min(cols - 1), (r + 1).min(rows - 1));
        let (tx, ty) = ((fc - c as f64) as f32, (fr - r as f64) as f32);
        let v = |c: usize, r: usize| values[r * cols + c];
        let a = v(c, r) + tx * (v(c1, r) - v(c, r));
        let b = v(c, r1) + tx * (v(c1, r1) - v(c, r1));
        a + ty * (b - a)
    }
}

/// Lays out a map of `grid`'s extent: each pixel coloured by `colour` from the node fields
/// `fields` sampled there (no height where the first is NaN), the title, a subtitle, a colour
/// bar from `lo` to `hi` in `unit`, and the legend entries.
#[allow(clippy::too_many_arguments)]
fn draw(
    grid: &ElevationGrid,
    fields: &[&[f32]],
    colour: &dyn Fn(&[f32]) -> Rgb<u8>,
    title: &str,
    subtitle: &str,
    bar: (f64, f64, &str, &dyn Fn(f64) -> Rgb<u8>),
    legend: &[(Rgb<u8>, &str)],
) -> RgbImage {
    let (cols, rows) = (grid.cols.max(1), grid.rows.max(1));
    let (k, s) = zoom(cols, rows);
    let (mw, mh) = (cols.div_ceil(s) * k, rows.div_ceil(s) * k);
    let (w, h) = (LEFT + mw as i64 + RIGHT, TOP + mh as i64 + BOTTOM);
    let mut img = RgbImage::from_pixel(w as u32, h as u32, WHITE);
    text(&mut img, LEFT, 16, title, 2, BLACK);
    text(&mut img, LEFT, 44, subtitle, 2, Rgb([70, 70, 70]));
    if fields.iter().all(|f| f.len() == cols * rows) {
        let at: Vec<_> = fields
            .iter()
            .map(|f| sampler(f, cols, rows, k, s))
            .collect();
        let mut v = vec![0.0f32; fields.len()];
        for y in 0..mh {
            for x in 0..mw {
                for (vi, a) in v.iter_mut().zip(&at) {
                    *vi = a(x, y);
                }
                let c = if v.first().is_some_and(|z| z.is_finite()) {
                    colour(&v)
                } else {
                    NO_HEIGHT
                };
                img.put_pixel((LEFT as usize + x) as u32, (TOP as usize + y) as u32, c);
            }
        }
    }
    frame(
        &mut img,
        LEFT - 1,
        TOP - 1,
        mw as i64 + 2,
        mh as i64 + 2,
        BLACK,
    );
    let bar_h = (mh as i64 - 40).clamp(40, 600);
    colour_bar(
        &mut img,
        LEFT + mw as i64 + 30,
        TOP + 24,
        24,
        bar_h,
        bar.0,
        bar.1,
        bar.2,
        bar.3,
    );
    let base = TOP + mh as i64 + 30;
    scale_bar(
        &mut img,
        LEFT,
        base + 6,
        k as f64 / (s as f64 * grid.cell_m),
        0.3 * mw as f64,
    );
    north_arrow(&mut img, LEFT + mw as i64 + 60, base - 20);
    let mut x = LEFT + (0.55 * mw as f64) as i64;
    for (c, label) in legend {
        swatch(&mut img, x, base, *c, label);
        x += 60 + crate::picture::text_width(label, 2);
    }
    img
}

fn range(v: &[f32]) -> Option<(f64, f64)> {
    let (lo, hi) = v
        .iter()
        .filter(|x| x.is_finite())
        .fold((f32::MAX, f32::MIN), |(a, b), &x| (a.min(x), b.max(x)));
    (lo <= hi).then_some((lo as f64, hi as f64))
}

/// Shade (0 … 1) per node from its neighbours (one-sided at edges and next to nodata).
fn shade(g: &ElevationGrid) -> Vec<f32> {
    let at = |c: i64, r: i64| -> Option<f64> {
        if c < 0 || r < 0 || c >= g.cols as i64 || r >= g.rows as i64 {
            return None;
        }
        let v = g.z[r as usize * g.cols + c as usize];
        v.is_finite().then_some(v as f64)
    };
    let slope = |here: f64, before: Option<f64>, after: Option<f64>| match (before, after) {
        (Some(b), Some(a)) => Some((a - b) / (2.0 * g.cell_m)),
        (None, Some(a)) => Some((a - here) / g.cell_m),
        (Some(b), None) => Some((here - b) / g.cell_m),
        (None, None) => None,
    };
    let sun = [-0.5f64, 0.5, std::f64::consts::FRAC_1_SQRT_2];
    let mut out = vec![f32::NAN; g.z.len()];
    for r in 0..g.rows as i64 {
        for c in 0..g.cols as i64 {
            let Some(z) = at(c, r) else { continue };
            let gx = slope(z, at(c - 1, r), at(c + 1, r)).unwrap_or(0.0);
            // Rows run southward: north is the row before.
            let gy = slope(z, at(c, r + 1), at(c, r - 1)).unwrap_or(0.0);
            let l = (-gx * sun[0] - gy * sun[1] + sun[2]) / (gx * gx + gy * gy + 1.0).sqrt();
            out[r as usize * g.cols + c as usize] = l.clamp(0.0, 1.0) as f32;
        }
    }
    out
}

/// The hillshade: heights in colour (bar in m), shaded.
pub fn write_hillshade(path: &Path, g: &ElevationGrid, crs: Crs) -> std::io::Result<()> {
    let (lo, hi) = range(&g.z).unwrap_or((0.0, 1.0));
    let span = (hi - lo).max(1e-6);
    let sh = shade(g);
    let img = draw(
        g,
        &[&g.z, &sh],
        &|v| {
            let Rgb(c) = terrain((v[0] as f64 - lo) / span);
            // Shade NaN (no neighbour to slope to): unshaded.
            let f = if v[1].is_finite() {
                0.35 + 0.65 * v[1]
            } else {
                1.0
            };
            Rgb(c.map(|x| (x as f32 * f).round() as u8))
        },
        "Elevation model: heights, shaded (sun NW, 45 deg up)",
        &format!(
            "{crs}, cell {} m, {} of {} nodes with a height",
            crate::picture::trim(g.cell_m),
            g.filled(),
            g.cols * g.rows
        ),
        (lo, hi, "m", &terrain),
        &[(NO_HEIGHT, "no height")],
    );
    save_png(&img, path)
}

/// The differences (model − reference): blue below, red above, full colour at ±`span_m`.
pub fn write_error_map(
    path: &Path,
    g: &ElevationGrid,
    diff: &[f32],
    span_m: f64,
    summary: &str,
) -> std::io::Result<()> {
    let span = if span_m.is_finite() && span_m > 0.0 {
        span_m
    } else {
        1.0
    };
    let img = draw(
        g,
        &[diff],
        &|d| diverging(0.5 + 0.5 * d[0] as f64 / span),
        "Model minus reference",
        summary,
        (-span, span, "m", &diverging),
        &[(NO_HEIGHT, "no height")],
    );
    save_png(&img, path)
}

/// The heights' standard deviations (bar from 0 to the 99th percentile, m).
pub fn write_sigma_map(
    path: &Path,
    g: &ElevationGrid,
    sigma: &[f32],
    summary: &str,
) -> std::io::Result<()> {
    let mut v: Vec<f32> = sigma.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f32::total_cmp);
    let top = v
        .get(v.len().saturating_sub(1).min(v.len() * 99 / 100))
        .map_or(1.0, |&x| x as f64)
        .max(1e-6);
    let img = draw(
        g,
        &[sigma],
        &|s| sequential(s[0] as f64 / top),
        "Standard deviation of the heights",
        summary,
        (0.0, top, "m", &sequential),
        &[(NO_HEIGHT, "no height")],
    );
    save_png(&img, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn maps_are_wide_enough_and_show_the_data_and_nodata() {
        let d = tempfile::tempdir().unwrap();
        let mut g = ElevationGrid::covering([0.0, 0.0, 900.0, 700.0], 10.0, 64).unwrap();
        for r in 0..g.rows {
            for c in 0..g.cols {
                g.z[r * g.cols + c] = if c < 10 { f32::NAN } else { (c + r) as f32 };
            }
        }
        let p = d.path().join("h.png");
        write_hillshade(&p, &g, Crs::Local).unwrap();
        let img = image::open(&p).unwrap().to_rgb8();
        // The map area itself (without its margins) is at least MIN_MAP_PX wide.
        let (k, s) = zoom(g.cols, g.rows);
        assert!(g.cols.div_ceil(s) * k >= MIN_MAP_PX, "{k} px per node");
        assert_eq!(
            img.width() as usize,
            LEFT as usize + g.cols * k + RIGHT as usize
        );
        // West of column 10 the map shows "no height"; east of it, coloured terrain.
        let y = (TOP as usize + g.rows * k / 2) as u32;
        assert_eq!(*img.get_pixel(LEFT as u32 + 2, y), NO_HEIGHT);
        assert_ne!(
            *img.get_pixel((LEFT as usize + 50 * k) as u32, y),
            NO_HEIGHT
        );
        // A huge grid is drawn at most MAX_MAP_PX on either side, a thin one too.
        assert_eq!(zoom(10_000, 10), (1, 3));
        assert_eq!(zoom(1, 1_000_000), (1, 250));
        assert_eq!(zoom(2, 3_000), (1, 1));
        assert_eq!(zoom(91, 73), (9, 1));
    }
}
