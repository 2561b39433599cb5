//! Mosaicking: every output pixel of a region's photo-coordinate grid is taken back through
//! photo → carriage → pixel into each tile that saw it (the inverses of the carriage→photo
//! and pixel→carriage affines), sampled there bicubically, and the tiles that overlap are
//! blended with weights that fall to zero towards each tile's edge, so no seam shows.
//!
//! Before sampling, a tile is smoothed to the output's pixel size when that is coarser than the
//! camera's (a Gaussian that widens the camera pixel's box aperture to the output pixel's),
//! so that the coarser grid does not alias the film's fine detail.
//!
//! The result depends only on the tiles on disk, the recorded stage positions and the
//! calibration: rows are computed in parallel but each pixel sums its tiles in a fixed
//! order, so the same tiles always give the same bytes.

use super::calibration::ScanCalibration;
use super::plan::MOSAIC_MARGIN_PX;
use crate::coords::{CarriageUm, PixelXY};
use crate::digitise::ImageF32;
use crate::geometry::PhotoGrid;
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::Arc;

/// Width (px) over which a tile's weight rises from zero at its usable edge to one.
pub const FEATHER_PX: f64 = 24.0;
/// Output rows computed together (the tiles they need are held in memory).
const BAND_ROWS: usize = 64;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Interpolation {
    /// Keys' cubic convolution (a = −0.5), after the anti-alias smoothing.
    Bicubic,
    /// The nearest tile pixel, no smoothing: the baseline the benchmark compares with.
    Nearest,
}

/// One tile as the mosaic sees it: where the stage stood, and how to load its pixels.
pub struct TileSource<'a> {
    pub stage_um: CarriageUm,
    pub load: Box<dyn Fn() -> std::io::Result<ImageF32> + Send + Sync + 'a>,
}

/// σ (tile px) of the Gaussian that takes the camera pixel's box aperture to the output's.
pub fn antialias_sigma_px(cal: &ScanCalibration, step_mm: f64) -> f64 {
    let a = cal.pixel.um_per_px();
    let cam_um = 0.5 * (a[0][0].hypot(a[1][0]) + a[0][1].hypot(a[1][1]));
    let k = step_mm * 1000.0 / cam_um;
    if k <= 1.0 {
        0.0
    } else {
        // Variances of boxes add: (k² − 1)/12 in tile pixels.
        ((k * k - 1.0) / 12.0).sqrt()
    }
}

/// Separable Gaussian smoothing with edge clamping.
pub fn gaussian(img: &ImageF32, sigma: f64) -> ImageF32 {
    if sigma <= 0.0 {
        return img.clone();
    }
    let r = (3.0 * sigma).ceil() as i64;
    let k: Vec<f32> = {
        let w: Vec<f64> = (-r..=r)
            .map(|i| (-0.5 * (i as f64 / sigma).powi(2)).exp())
            .collect();
        let s: f64 = w.iter().sum();
        w.iter().map(|v| (v / s) as f32).collect()
    };
    let (w, h) = (img.width as i64, img.height as i64);
    let mut tmp = ImageF32::new(img.width, img.height);
    for y in 0..h {
        let row = &img.data[(y * w) as usize..][..w as usize];
        let out = &mut tmp.data[(y * w) as usize..][..w as usize];
        for x in 0..w {
            let mut s = 0.0f32;
            for (j, kv) in k.iter().enumerate() {
                let xx = (x + j as i64 - r).clamp(0, w - 1);
                s += kv * row[xx as usize];
            }
            out[x as usize] = s;
        }
    }
    let mut out = ImageF32::new(img.width, img.height);
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0f32;
            for (j, kv) in k.iter().enumerate() {
                let yy = (y + j as i64 - r).clamp(0, h - 1);
                s += kv * tmp.data[(yy * w + x) as usize];
            }
            out.data[(y * w + x) as usize] = s;
        }
    }
    out
}

/// Where a tile lands on the output grid: the affine from output pixel to tile pixel
/// (`q = q0 + col·dc + row·dr`, at the output pixel's centre) and the output rows it touches.
struct Placement {
    q0: [f64; 2],
    dc: [f64; 2],
    dr: [f64; 2],
    rows: (usize, usize),
}

fn place(cal: &ScanCalibration, grid: &PhotoGrid, stage: CarriageUm) -> Placement {
    let (t, m) = cal.photo_to_pixel(stage);
    let to_q = |p: crate::coords::PhotoMm| {
        [
            t[0] + m[0][0] * p.x + m[0][1] * p.y,
            t[1] + m[1][0] * p.x + m[1][1] * p.y,
        ]
    };
    let q0 = to_q(grid.photo(PixelXY::new(0.5, 0.5)));
    let q1 = to_q(grid.photo(PixelXY::new(1.5, 0.5)));
    let q2 = to_q(grid.photo(PixelXY::new(0.5, 1.5)));
    let (w, h) = (cal.rig.width as f64, cal.rig.height as f64);
    let mut lo = f64::MAX;
    let mut hi = f64::MIN;
    for q in [[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]] {
        let p = cal.photo_at(stage, PixelXY::new(q[0], q[1]));
        let r = grid.pixel(p).row;
        lo = lo.min(r);
        hi = hi.max(r);
    }
    let rows = (
        lo.floor().clamp(0.0, grid.height as f64) as usize,
        (hi.ceil() + 1.0).clamp(0.0, grid.height as f64) as usize,
    );
    Placement {
        q0,
        dc: [q1[0] - q0[0], q1[1] - q0[1]],
        dr: [q2[0] - q0[0], q2[1] - q0[1]],
        rows,
    }
}

/// Weight of tile pixel `q` in a `w × h` tile: 0 outside the usable area, rising smoothly
/// to 1 over [`FEATHER_PX`].
#[inline]
fn weight(q: [f64; 2], w: f64, h: f64) -> f64 {
    let d = (q[0] - MOSAIC_MARGIN_PX)
        .min(w - MOSAIC_MARGIN_PX - q[0])
        .min(q[1] - MOSAIC_MARGIN_PX)
        .min(h - MOSAIC_MARGIN_PX - q[1]);
    if d <= 0.0 {
        return 0.0;
    }
    let t = (d / FEATHER_PX).min(1.0);
    t * t * (3.0 - 2.0 * t)
}

/// The output columns `[lo, hi)` of a row where tile pixel `a + c·dc` can lie inside the
/// usable area (a column more on each side; [`weight`] decides).
fn columns(a: [f64; 2], dc: [f64; 2], tw: f64, th: f64, width: usize) -> (usize, usize) {
    let (mut lo, mut hi) = (f64::MIN, f64::MAX);
    for (k, len) in [(0, tw), (1, th)] {
        let (min, max) = (MOSAIC_MARGIN_PX, len - MOSAIC_MARGIN_PX);
        if dc[k].abs() < 1e-12 {
            if a[k] <= min || a[k] >= max {
                return (0, 0);
            }
            continue;
        }
        let (c1, c2) = ((min - a[k]) / dc[k], (max - a[k]) / dc[k]);
        lo = lo.max(c1.min(c2));
        hi = hi.min(c1.max(c2));
    }
    let lo = (lo.floor() - 1.0).clamp(0.0, width as f64) as usize;
    let hi = (hi.ceil() + 2.0).clamp(0.0, width as f64) as usize;
    (lo, hi.max(lo))
}

/// The region's photo on `grid`, in the tiles' grey units; 0 where no tile reached (nodata;
/// data values are kept ≥ 1).
pub fn mosaic(
    cal: &ScanCalibration,
    grid: &PhotoGrid,
    tiles: &[TileSource<'_>],
    interp: Interpolation,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> std::io::Result<Vec<u16>> {
    let sigma = match interp {
        Interpolation::Bicubic => antialias_sigma_px(cal, grid.step_mm),
        Interpolation::Nearest => 0.0,
    };
    let places: Vec<Placement> = tiles.iter().map(|t| place(cal, grid, t.stage_um)).collect();
    let (tw, th) = (cal.rig.width as f64, cal.rig.height as f64);
    let mut out = vec![0u16; grid.width * grid.height];
    let mut cache: HashMap<usize, Arc<ImageF32>> = HashMap::new();
    let bands = grid.height.div_ceil(BAND_ROWS);
    for (b, band) in out.chunks_mut(BAND_ROWS * grid.width).enumerate() {
        let (r0, r1) = (b * BAND_ROWS, ((b + 1) * BAND_ROWS).min(grid.height));
        let need: Vec<usize> = (0..tiles.len())
            .filter(|&i| places[i].rows.0 < r1 && places[i].rows.1 > r0)
            .collect();
        cache.retain(|k, _| need.contains(k));
        let missing: Vec<usize> = need
            .iter()
            .copied()
            .filter(|i| !cache.contains_key(i))
            .collect();
        let loaded: Vec<(usize, std::io::Result<ImageF32>)> = missing
            .par_iter()
            .map(|&i| (i, (tiles[i].load)().map(|img| gaussian(&img, sigma))))
            .collect();
        for (i, r) in loaded {
            cache.insert(i, Arc::new(r?));
        }
        let imgs: Vec<(&Placement, &ImageF32)> =
            need.iter().map(|&i| (&places[i], &*cache[&i])).collect();
        band.par_chunks_mut(grid.width)
            .enumerate()
            .for_each(|(k, row_out)| {
                let row = (r0 + k) as f64;
                let (mut sw, mut sv) = (vec![0.0f64; grid.width], vec![0.0f64; grid.width]);
                // Tile by tile in a fixed order over the columns each one covers.
                for (p, img) in &imgs {
                    let a = [p.q0[0] + row * p.dr[0], p.q0[1] + row * p.dr[1]];
                    let (lo, hi) = columns(a, p.dc, tw, th, grid.width);
                    for col in lo..hi {
                        let c = col as f64;
                        let q = [a[0] + c * p.dc[0], a[1] + c * p.dc[1]];
                        let w = weight(q, tw, th);
                        if w <= 0.0 {
                            continue;
                        }
                        let v = match interp {
                            Interpolation::Bicubic => {
                                match crate::targets::resample::value(img, q[0], q[1]) {
                                    Some(v) => v,
                                    None => continue,
                                }
                            }
                            Interpolation::Nearest => {
                                img.data[q[1] as usize * img.width + q[0] as usize] as f64
                            }
                        };
                        sw[col] += w;
                        sv[col] += w * v;
                    }
                }
                for ((o, w), v) in row_out.iter_mut().zip(&sw).zip(&sv) {
                    if *w > 0.0 {
                        *o = (v / w).round().clamp(1.0, 65535.0) as u16;
                    }
                }
            });
        progress(b + 1, bands);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_keeps_the_mean_and_smooths() {
        let mut img = ImageF32::new(21, 21);
        img.data[10 * 21 + 10] = 100.0;
        let g = gaussian(&img, 1.0);
        let s: f32 = g.data.iter().sum();
        assert!((s - 100.0).abs() < 1e-3);
        // The centre of a unit Gaussian sampled at integers: 1/(2π) of the mass.
        assert!((g.data[10 * 21 + 10] - 100.0 / (2.0 * std::f32::consts::PI)).abs() < 0.3);
    }

    #[test]
    fn weights_fall_to_zero_at_the_usable_edge() {
        assert_eq!(weight([MOSAIC_MARGIN_PX, 100.0], 512.0, 512.0), 0.0);
        assert_eq!(weight([256.0, 256.0], 512.0, 512.0), 1.0);
        let mid = weight([MOSAIC_MARGIN_PX + FEATHER_PX / 2.0, 256.0], 512.0, 512.0);
        assert!((mid - 0.5).abs() < 1e-12);
    }
}
