//! Tie points found by the rig: interest points in each photo, each matched into every photo
//! that sees it, so that a point carries as many rays as photos see it (across strips too).
//!
//! - Interest points: in each cell of a grid, the pixel whose grey-value structure tensor has
//!   the largest smaller eigenvalue (a corner, well placed in both directions; Förstner &
//!   Gülch 1987, the roundness and weight of the error ellipse; Shi & Tomasi 1994).
//! - Search: along the epipolar segment between the lowest and highest height, widened across
//!   it by the orientation's uncertainty, by normalised cross-correlation at a pyramid level
//!   where the segment is a few tens of pixels, then ±2^L px at full resolution.
//! - Refinement: least-squares matching with an affine and a linear radiometric model (Gruen
//!   1985, "Adaptive least squares correlation"), its σ of the shift from σ̂₀²·N⁻¹: the ray's
//!   weight in the bundle adjustment.
//!
//! A point already matched into a photo takes that photo's cell, so that the photo's own
//! interest points do not measure it a second time.

use crate::coords::PixelXY;
use crate::geometry::{FrameCamera, PixelToPhoto};
use crate::image::ImageF32;
use crate::matching::methods::mgcm::pyramid::halve;
use nalgebra::{SMatrix, SVector};
use rayon::prelude::*;

#[derive(Debug, Clone, Copy)]
pub struct TieOptions {
    /// One interest point per cell of this side, px (full resolution).
    pub cell_px: usize,
    /// Template side, px (odd), at full resolution and at the search level.
    pub template: usize,
    /// Smallest correlation of a match.
    pub min_ncc: f64,
    /// How far across the epipolar line to search, px (the orientations' uncertainty).
    pub across_px: f64,
    /// The terrain's height range, m.
    pub heights: [f64; 2],
}

/// One found ray: photo, corner-origin pixel, σ px.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FoundRay {
    pub photo: usize,
    pub pixel: PixelXY,
    pub sigma_px: f64,
}

/// A photo as the search sees it: pyramid, camera, pixel → photo relation.
pub struct SearchPhoto<'a> {
    pub levels: Vec<ImageF32>,
    pub camera: FrameCamera,
    pub frame: &'a PixelToPhoto,
}

impl<'a> SearchPhoto<'a> {
    pub fn new(
        image: &ImageF32,
        camera: FrameCamera,
        frame: &'a PixelToPhoto,
        levels: usize,
    ) -> Self {
        let mut v = vec![image.clone()];
        for _ in 0..levels {
            let h = halve(v.last().unwrap());
            v.push(h);
        }
        SearchPhoto {
            levels: v,
            camera,
            frame,
        }
    }

    fn to_pixel(&self, g: crate::coords::GroundM) -> Option<PixelXY> {
        Some(self.frame.pixel(self.camera.project(g)?))
    }

    fn ground(&self, q: PixelXY, z: f64) -> crate::coords::GroundM {
        self.camera.at_height(self.frame.photo(q), z)
    }
}

/// The interest points of `img`: one per cell, at pixel centres (corner-origin continuous
/// coordinates), where the smaller eigenvalue of the structure tensor over a 5 × 5 window is
/// largest and at least a tenth of the photo's median; none whose template has a pixel of 0
/// (no data) or leaves the image.
pub fn interest_points(img: &ImageF32, cell: usize, margin: usize) -> Vec<PixelXY> {
    let (w, h) = (img.width, img.height);
    if w < 2 * margin + 3 || h < 2 * margin + 3 {
        return Vec::new();
    }
    let g = |c: usize, r: usize| img.data[r * w + c] as f64;
    let lam = |c: usize, r: usize| {
        let (mut a, mut b, mut d) = (0.0, 0.0, 0.0);
        for y in r - 2..=r + 2 {
            for x in c - 2..=c + 2 {
                let gx = 0.5 * (g(x + 1, y) - g(x - 1, y));
                let gy = 0.5 * (g(x, y + 1) - g(x, y - 1));
                a += gx * gx;
                b += gx * gy;
                d += gy * gy;
            }
        }
        0.5 * (a + d) - (0.25 * (a - d) * (a - d) + b * b).sqrt()
    };
    let m = margin.max(3);
    let cells: Vec<(usize, usize)> = (m..h - m)
        .step_by(cell)
        .flat_map(|r0| (m..w - m).step_by(cell).map(move |c0| (c0, r0)))
        .collect();
    let best: Vec<(f64, usize, usize)> = cells
        .par_iter()
        .filter_map(|&(c0, r0)| {
            let mut best: Option<(f64, usize, usize)> = None;
            for r in r0..(r0 + cell).min(h - m) {
                for c in c0..(c0 + cell).min(w - m) {
                    let l = lam(c, r);
                    if best.is_none_or(|b| l > b.0) {
                        best = Some((l, c, r));
                    }
                }
            }
            let (l, c, r) = best?;
            // No-data pixels (0) in the template: a photo's edge, a ray that missed.
            let hm = margin.min(r).min(c);
            for y in r - hm..=(r + hm).min(h - 1) {
                for x in c - hm..=(c + hm).min(w - 1) {
                    if img.data[y * w + x] == 0.0 {
                        return None;
                    }
                }
            }
            Some((l, c, r))
        })
        .collect();
    let mut ls: Vec<f64> = best.iter().map(|b| b.0).collect();
    if ls.is_empty() {
        return Vec::new();
    }
    ls.sort_by(f64::total_cmp);
    let floor = 0.1 * ls[ls.len() / 2];
    best.into_iter()
        .filter(|b| b.0 > floor && b.0 > 0.0)
        .map(|(_, c, r)| PixelXY::new(c as f64 + 0.5, r as f64 + 0.5))
        .collect()
}

/// Zero-mean, unit-norm samples of `img` in a square of side 2h + 1 at integer pixel
/// (c, r); `None` off the image, on no-data or on a flat patch.
fn patch(img: &ImageF32, c: isize, r: isize, h: isize) -> Option<Vec<f64>> {
    if c - h < 0 || r - h < 0 || c + h >= img.width as isize || r + h >= img.height as isize {
        return None;
    }
    let mut v = Vec::with_capacity(((2 * h + 1) * (2 * h + 1)) as usize);
    for y in r - h..=r + h {
        for x in c - h..=c + h {
            let g = img.data[y as usize * img.width + x as usize] as f64;
            if g == 0.0 {
                return None;
            }
            v.push(g);
        }
    }
    let m = v.iter().sum::<f64>() / v.len() as f64;
    v.iter_mut().for_each(|x| *x -= m);
    let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    if n < 1e-9 {
        return None;
    }
    v.iter_mut().for_each(|x| *x /= n);
    Some(v)
}

fn ncc(t: &[f64], img: &ImageF32, c: isize, r: isize, h: isize) -> Option<f64> {
    let p = patch(img, c, r, h)?;
    Some(t.iter().zip(&p).map(|(a, b)| a * b).sum())
}

/// Least-squares matching of the template of `a` at `qa` into `b` from `qb` with the affine
/// shape `lin` (∂b/∂a): the matched point and its σ (px), or `None` when it does not converge
/// or correlates below `min_ncc`.
pub fn lsm(
    a: &ImageF32,
    qa: PixelXY,
    b: &ImageF32,
    qb: PixelXY,
    lin: [f64; 4],
    half: isize,
    min_ncc: f64,
) -> Option<(PixelXY, f64)> {
    let mut t = Vec::new();
    for dy in -half..=half {
        for dx in -half..=half {
            t.push((
                dx as f64,
                dy as f64,
                a.bilinear(qa.col + dx as f64, qa.row + dy as f64)? as f64,
            ));
        }
    }
    // x_b = p0 + p1 dx + p2 dy, y_b = p3 + p4 dx + p5 dy; g_a = r0 + r1 g_b.
    let mut p = [qb.col, lin[0], lin[1], qb.row, lin[2], lin[3], 0.0, 1.0];
    let n_obs = t.len() as f64;
    for _ in 0..30 {
        let mut n = SMatrix::<f64, 8, 8>::zeros();
        let mut u = SVector::<f64, 8>::zeros();
        let mut ss = 0.0;
        for &(dx, dy, ga) in &t {
            let (x, y) = (p[0] + p[1] * dx + p[2] * dy, p[3] + p[4] * dx + p[5] * dy);
            let [v, gx, gy] = b.bilinear_with_gradient(x, y)?;
            let e = ga - (p[6] + p[7] * v);
            let (jx, jy) = (p[7] * gx, p[7] * gy);
            let row = SVector::<f64, 8>::from([jx, jx * dx, jx * dy, jy, jy * dx, jy * dy, 1.0, v]);
            n += row * row.transpose();
            u += row * e;
            ss += e * e;
        }
        let ninv = n.try_inverse()?;
        let d = ninv * u;
        for k in 0..8 {
            p[k] += d[k];
        }
        if !p.iter().all(|x| x.is_finite())
            || (p[0] - qb.col).abs() > 3.0
            || (p[3] - qb.row).abs() > 3.0
        {
            return None;
        }
        if d[0].abs() < 1e-3 && d[3].abs() < 1e-3 {
            let s0 = (ss / (n_obs - 8.0)).sqrt();
            let sigma = s0 * (0.5 * (ninv[(0, 0)] + ninv[(3, 3)])).sqrt();
            // The correlation of the matched patches.
            let mut ys = Vec::with_capacity(t.len());
            for &(dx, dy, _) in &t {
                ys.push(
                    b.bilinear(p[0] + p[1] * dx + p[2] * dy, p[3] + p[4] * dx + p[5] * dy)? as f64,
                );
            }
            let xs: Vec<f64> = t.iter().map(|x| x.2).collect();
            let r = crate::correlation::ncc(&xs, &ys);
            return (r >= min_ncc && sigma.is_finite())
                .then_some((PixelXY::new(p[0], p[3]), sigma));
        }
    }
    None
}

/// Matches point `q` of photo `i` into photo `k`: the pixel and σ, or `None`.
fn match_into(
    ph: &[SearchPhoto],
    i: usize,
    k: usize,
    q: PixelXY,
    o: &TieOptions,
    level: usize,
) -> Option<(PixelXY, f64)> {
    let (a, b) = (&ph[i], &ph[k]);
    let s = (1u32 << level) as f64;
    let lo = b.to_pixel(a.ground(q, o.heights[0]))?;
    let hi = b.to_pixel(a.ground(q, o.heights[1]))?;
    let (w, h) = (b.levels[0].width as f64, b.levels[0].height as f64);
    let inside = |p: PixelXY| p.col >= 0.0 && p.row >= 0.0 && p.col < w && p.row < h;
    if !inside(lo) && !inside(hi) {
        return None;
    }
    let half = (o.template / 2) as isize;
    // Search at the level.
    let t = patch(
        &a.levels[level],
        (q.col / s).floor() as isize,
        (q.row / s).floor() as isize,
        half,
    )?;
    let (dx, dy) = ((hi.col - lo.col) / s, (hi.row - lo.row) / s);
    let len = dx.hypot(dy).max(1e-9);
    let (ux, uy) = (dx / len, dy / len);
    let across = (o.across_px / s).ceil() as isize;
    let mut best: Option<(f64, isize, isize, f64)> = None;
    let steps = len.ceil() as isize;
    for st in 0..=steps {
        let f = st as f64 / steps.max(1) as f64;
        for off in -across..=across {
            let x = lo.col / s + f * dx - uy * off as f64;
            let y = lo.row / s + f * dy + ux * off as f64;
            let (c, r) = (x.floor() as isize, y.floor() as isize);
            if let Some(v) = ncc(&t, &b.levels[level], c, r, half) {
                if best.is_none_or(|bb| v > bb.0) {
                    best = Some((v, c, r, f));
                }
            }
        }
    }
    let (v, c, r, f) = best?;
    if v < o.min_ncc - 0.1 {
        return None;
    }
    // Full resolution: around the level's pick.
    let t0 = patch(
        &a.levels[0],
        q.col.floor() as isize,
        q.row.floor() as isize,
        half,
    )?;
    let (c0, r0) = (
        ((c as f64 + 0.5) * s).floor() as isize,
        ((r as f64 + 0.5) * s).floor() as isize,
    );
    let reach = (s as isize) + 1;
    let mut best0: Option<(f64, isize, isize)> = None;
    for y in r0 - reach..=r0 + reach {
        for x in c0 - reach..=c0 + reach {
            if let Some(v) = ncc(&t0, &b.levels[0], x, y, half) {
                if best0.is_none_or(|bb| v > bb.0) {
                    best0 = Some((v, x, y));
                }
            }
        }
    }
    let (_, x, y) = best0?;
    // The affine shape from the geometry at the height found.
    let z = o.heights[0] + f * (o.heights[1] - o.heights[0]);
    let at = |dc: f64, dr: f64| b.to_pixel(a.ground(PixelXY::new(q.col + dc, q.row + dr), z));
    let (p0, px, py) = (at(0.0, 0.0)?, at(1.0, 0.0)?, at(0.0, 1.0)?);
    let lin = [
        px.col - p0.col,
        py.col - p0.col,
        px.row - p0.row,
        py.row - p0.row,
    ];
    lsm(
        &a.levels[0],
        q,
        &b.levels[0],
        PixelXY::new(x as f64 + 0.5, y as f64 + 0.5),
        lin,
        half,
        o.min_ncc,
    )
}

/// The tie points of the block: each a list of rays (two or more).
pub fn find(
    photos: &[SearchPhoto],
    pairs: &[(usize, usize)],
    o: &TieOptions,
    level: usize,
) -> Vec<Vec<FoundRay>> {
    let n = photos.len();
    let cell = o.cell_px.max(4) as f64;
    let grid = |i: usize| {
        let im = &photos[i].levels[0];
        (
            im.width.div_ceil(o.cell_px.max(4)),
            im.height.div_ceil(o.cell_px.max(4)),
        )
    };
    let mut taken: Vec<Vec<bool>> = (0..n).map(|i| vec![false; grid(i).0 * grid(i).1]).collect();
    let mark = |taken: &mut Vec<Vec<bool>>, i: usize, p: PixelXY| {
        let (gw, gh) = grid(i);
        let (c, r) = ((p.col / cell) as usize, (p.row / cell) as usize);
        if c < gw && r < gh {
            taken[i][r * gw + c] = true;
        }
    };
    let mut tracks = Vec::new();
    for i in 0..n {
        let partners: Vec<usize> = pairs
            .iter()
            .filter_map(|&(a, b)| {
                if a == i {
                    Some(b)
                } else if b == i {
                    Some(a)
                } else {
                    None
                }
            })
            .collect();
        if partners.is_empty() {
            continue;
        }
        let (gw, _) = grid(i);
        let pts: Vec<PixelXY> =
            interest_points(&photos[i].levels[0], o.cell_px.max(4), o.template / 2 + 2)
                .into_iter()
                .filter(|p| !taken[i][(p.row / cell) as usize * gw + (p.col / cell) as usize])
                .collect();
        let found: Vec<Vec<FoundRay>> = pts
            .par_iter()
            .filter_map(|&q| {
                let mut rays = Vec::new();
                let mut sig = Vec::new();
                for &k in &partners {
                    if let Some((p, s)) = match_into(photos, i, k, q, o, level) {
                        rays.push(FoundRay {
                            photo: k,
                            pixel: p,
                            sigma_px: s,
                        });
                        sig.push(s);
                    }
                }
                if rays.is_empty() {
                    return None;
                }
                // The template's own noise is in each match's σ: shared by its rays.
                let s = sig.iter().sum::<f64>() / sig.len() as f64;
                rays.iter_mut()
                    .for_each(|r| r.sigma_px = (r.sigma_px / std::f64::consts::SQRT_2).max(0.02));
                rays.insert(
                    0,
                    FoundRay {
                        photo: i,
                        pixel: q,
                        sigma_px: (s / std::f64::consts::SQRT_2).max(0.02),
                    },
                );
                Some(rays)
            })
            .collect();
        for t in found {
            for r in &t[1..] {
                mark(&mut taken, r.photo, r.pixel);
            }
            tracks.push(t);
        }
    }
    tracks
}
