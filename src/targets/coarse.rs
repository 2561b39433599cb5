//! Coarse location of a mark from its known geometry and the grey-level gradients (seed 002:
//! "a coarse matching, which utilises the known cross geometry and grey level gradients …
//! gives approximate values better than 0.5 pixel, does not require that the cross is entirely
//! in the image").
//!
//! The gradient magnitudes of the image and of a template of the whole mark are correlated
//! (normalised, over the part of the template that lies in the image, so a mark cut by the
//! frame still scores), first exhaustively on a coarse pyramid level, then refined level by
//! level, and finally to sub-pixel by a parabola through the scores. Gradients, not grey
//! values, so that the mark's edges count and the background's shading does not.

use super::template::Template;
use crate::coords::PixelXY;
use crate::digitise::ImageF32;
use rayon::prelude::*;
use serde::Serialize;

#[derive(Debug, Clone, Copy)]
pub struct CoarseOptions {
    /// Below this score (the correlation over the part of the template in view, times the
    /// square root of that part's share) there is no mark.
    pub min_score: f64,
    /// At least this share of the template's edges must lie in the image.
    pub min_visible: f64,
}

impl Default for CoarseOptions {
    fn default() -> Self {
        CoarseOptions {
            min_score: 0.5,
            min_visible: 0.15,
        }
    }
}

#[derive(Debug, Clone, Copy, Serialize, serde::Deserialize)]
pub struct CoarseMatch {
    pub centre: PixelXY,
    /// Correlation of the gradient magnitudes at the best position, times √visible.
    pub score: f64,
    /// Share of the template's edge strength inside the image there.
    pub visible: f64,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error, Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum CoarseError {
    #[error("no mark found: the best match scores {best_score:.2} (needs {min_score:.2})")]
    NotFound { best_score: f64, min_score: f64 },
}

/// Sobel gradient magnitude (borders zero).
fn gradient_magnitude(img: &ImageF32) -> ImageF32 {
    let (w, h) = (img.width, img.height);
    let mut out = ImageF32::new(w, h);
    if w < 3 || h < 3 {
        return out;
    }
    out.data[w..(h - 1) * w]
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(k, row)| {
            let r = k + 1;
            let p = |c: usize, rr: usize| img.data[rr * w + c];
            for c in 1..w - 1 {
                let gx = (p(c + 1, r - 1) + 2.0 * p(c + 1, r) + p(c + 1, r + 1))
                    - (p(c - 1, r - 1) + 2.0 * p(c - 1, r) + p(c - 1, r + 1));
                let gy = (p(c - 1, r + 1) + 2.0 * p(c, r + 1) + p(c + 1, r + 1))
                    - (p(c - 1, r - 1) + 2.0 * p(c, r - 1) + p(c + 1, r - 1));
                row[c] = gx.hypot(gy);
            }
        });
    out
}

/// Mean of s×s blocks (the last partial row and column dropped).
fn downsample(img: &ImageF32, s: usize) -> ImageF32 {
    let (w, h) = (img.width / s, img.height / s);
    let mut out = ImageF32::new(w, h);
    for r in 0..h {
        for c in 0..w {
            let mut acc = 0.0;
            for j in 0..s {
                for i in 0..s {
                    acc += img.data[(r * s + j) * img.width + c * s + i];
                }
            }
            out.data[r * w + c] = acc / (s * s) as f32;
        }
    }
    out
}

/// Σt, Σt², Σg, Σg², Σt·g of two rows of equal length, in four lanes so that the compiler
/// can keep them in vector registers (one running sum per quantity cannot be vectorised: it
/// fixes the order of the additions).
#[inline]
fn row_sums(t: &[f32], g: &[f32]) -> [f32; 5] {
    const L: usize = 4;
    let (mut a, mut aa, mut b, mut bb, mut ab) =
        ([0f32; L], [0f32; L], [0f32; L], [0f32; L], [0f32; L]);
    let (tc, gc) = (t.chunks_exact(L), g.chunks_exact(L));
    let (tr, gr) = (tc.remainder(), gc.remainder());
    for (tv, gv) in tc.zip(gc) {
        // Whole lanes: no bounds check is left in the loop below.
        let (Ok(tv), Ok(gv)) = (<&[f32; L]>::try_from(tv), <&[f32; L]>::try_from(gv)) else {
            continue;
        };
        for k in 0..L {
            a[k] += tv[k];
            aa[k] += tv[k] * tv[k];
            b[k] += gv[k];
            bb[k] += gv[k] * gv[k];
            ab[k] += tv[k] * gv[k];
        }
    }
    let mut s = [a, aa, b, bb, ab].map(|v| v.iter().sum::<f32>());
    for (&tv, &gv) in tr.iter().zip(gr) {
        s[0] += tv;
        s[1] += tv * tv;
        s[2] += gv;
        s[3] += gv * gv;
        s[4] += tv * gv;
    }
    s
}

/// Normalised correlation of template `t` with the image `g` with the template's top-left at
/// (ox, oy) (may be negative), over their overlap; and the share of the template's sum inside.
fn score_at(g: &ImageF32, t: &ImageF32, t_sum: f64, ox: i64, oy: i64) -> (f64, f64) {
    let c0 = (-ox).max(0) as usize;
    let r0 = (-oy).max(0) as usize;
    let c1 = (g.width as i64 - ox).min(t.width as i64);
    let r1 = (g.height as i64 - oy).min(t.height as i64);
    if c1 <= c0 as i64 || r1 <= r0 as i64 {
        return (0.0, 0.0);
    }
    let (c1, r1) = (c1 as usize, r1 as usize);
    let (mut n, mut st, mut stt, mut sg, mut sgg, mut stg) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for r in r0..r1 {
        let trow = &t.data[r * t.width + c0..r * t.width + c1];
        let gi = (oy + r as i64) as usize * g.width + (ox + c0 as i64) as usize;
        let grow = &g.data[gi..gi + (c1 - c0)];
        let [a, aa, b, bb, ab] = row_sums(trow, grow);
        n += (c1 - c0) as f64;
        st += a as f64;
        stt += aa as f64;
        sg += b as f64;
        sgg += bb as f64;
        stg += ab as f64;
    }
    let vt = stt - st * st / n;
    let vg = sgg - sg * sg / n;
    let visible = st / t_sum;
    if vt <= 0.0 || vg <= 0.0 {
        return (0.0, visible);
    }
    // The correlation over the part in view, weighted by √(share in view): a placement that
    // sees only one straight arm correlates perfectly but explains little of the mark.
    (
        (stg - st * sg / n) / (vt * vg).sqrt() * visible.clamp(0.0, 1.0).sqrt(),
        visible,
    )
}

/// Pyramid levels above full resolution for a template of `size` px: the coarsest keeps it at
/// 25 to 50 px.
fn pyramid_levels(size: usize) -> usize {
    let mut levels = 0;
    while size >> levels > 50 {
        levels += 1;
    }
    levels
}

/// The work of [`locate`] in template-pixel visits (the exhaustive search at the coarsest
/// level dominates), to refuse a search that would take hours before it starts.
pub fn locate_work(width: usize, height: usize, tpl_size: usize) -> f64 {
    let s = (1u64 << pyramid_levels(tpl_size)) as f64;
    let t = (tpl_size as f64 / s).ceil();
    (width as f64 / s + t) * (height as f64 / s + t) * t * t
}

/// Finds the template's mark in the image; the template must show the whole mark on a flat
/// background.
pub fn locate(
    img: &ImageF32,
    tpl: &Template,
    opt: &CoarseOptions,
) -> Result<CoarseMatch, CoarseError> {
    let gi = gradient_magnitude(img);
    let gt = gradient_magnitude(&tpl.image);
    // The coarsest level keeps the template at 25 to 50 px: the exhaustive search there costs
    // (image + template)² × template², so each level less makes it about 16 times dearer.
    let levels = pyramid_levels(tpl.size());
    let pyr: Vec<(ImageF32, ImageF32)> = (0..=levels)
        .map(|l| {
            let s = 1 << l;
            if s == 1 {
                (gi.clone(), gt.clone())
            } else {
                (downsample(&gi, s), downsample(&gt, s))
            }
        })
        .collect();
    let (g, t) = &pyr[levels];
    let t_sum: f64 = t.data.iter().map(|&v| v as f64).sum();
    // Exhaustive at the top: every placement with enough of the template inside.
    let (tw, th) = (t.width as i64, t.height as i64);
    let gw = g.width as i64;
    let best = (-th + 1..g.height as i64)
        .into_par_iter()
        .map(|oy| {
            let mut b = (-2.0, 0, 0);
            for ox in -tw + 1..gw {
                let (s, v) = score_at(g, t, t_sum, ox, oy);
                let s = if v >= opt.min_visible { s } else { -1.0 };
                if s > b.0 {
                    b = (s, ox, oy);
                }
            }
            b
        })
        .reduce(|| (-2.0, 0, 0), |a, b| if b.0 > a.0 { b } else { a });
    let (mut ox, mut oy) = (best.1, best.2);
    // Down the pyramid: ±2 px around twice the position above.
    let mut at0 = None;
    for l in (0..levels).rev() {
        let (g, t) = &pyr[l];
        let t_sum: f64 = t.data.iter().map(|&v| v as f64).sum();
        let mut grid = [[(-2.0f64, 0.0f64); 5]; 5];
        let (cx, cy) = (2 * ox, 2 * oy);
        let mut b = (-2.0, 0, 0);
        for dy in -2..=2i64 {
            for dx in -2..=2i64 {
                let (s, v) = score_at(g, t, t_sum, cx + dx, cy + dy);
                let s = if v >= opt.min_visible { s } else { -1.0 };
                grid[(dy + 2) as usize][(dx + 2) as usize] = (s, v);
                if s > b.0 {
                    b = (s, cx + dx, cy + dy);
                }
            }
        }
        (ox, oy) = (b.1, b.2);
        if l == 0 {
            at0 = Some((grid, cx, cy));
        }
    }
    // The scores around the best full-resolution placement, for the parabola.
    let (t0, g0) = (&pyr[0].1, &pyr[0].0);
    let t_sum0: f64 = t0.data.iter().map(|&v| v as f64).sum();
    let s = |dx: i64, dy: i64| -> (f64, f64) {
        if let Some((grid, cx, cy)) = &at0 {
            let (i, j) = (ox + dx - cx + 2, oy + dy - cy + 2);
            if (0..5).contains(&i) && (0..5).contains(&j) {
                return grid[j as usize][i as usize];
            }
        }
        score_at(g0, t0, t_sum0, ox + dx, oy + dy)
    };
    let (s00, vis) = s(0, 0);
    if s00 < opt.min_score {
        return Err(CoarseError::NotFound {
            best_score: s00.max(0.0),
            min_score: opt.min_score,
        });
    }
    let peak = |m: f64, z: f64, p: f64| {
        let den = m - 2.0 * z + p;
        if den < 0.0 {
            (0.5 * (m - p) / den).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    let fx = peak(s(-1, 0).0, s00, s(1, 0).0);
    let fy = peak(s(0, -1).0, s00, s(0, 1).0);
    let c = tpl.centre();
    Ok(CoarseMatch {
        centre: PixelXY::new(ox as f64 + fx + c, oy as f64 + fy + c),
        score: s00,
        visible: vis,
    })
}
