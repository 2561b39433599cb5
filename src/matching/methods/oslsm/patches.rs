//! The object-space matching of a whole block, patch by patch (seed 001 3.3.3 j: "the grid
//! DEM is separately generated patch by patch ... the aggregation of the whole DEM"):
//! overlapping patches of posts, each refined on its own (its own offsets and gains: the
//! seed's local radiometric correction), merged with weights that fall linearly to zero
//! across the overlap, so that no seam shows where one patch hands over to the next.

use crate::matching::methods::oslsm::grids::Grids;
use crate::matching::methods::oslsm::solve::{
    patch_coordinates, radiometry_at, refine, Iteration, OslsmError, OslsmParams,
};
use crate::matching::methods::oslsm::PhotoView;
use crate::matching::progress::Progress;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// How the block is cut.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PatchLayout {
    /// Posts along each side of a patch.
    pub posts: usize,
    /// Posts shared by neighbouring patches.
    pub overlap: usize,
}

impl Default for PatchLayout {
    fn default() -> Self {
        PatchLayout {
            posts: 24,
            overlap: 4,
        }
    }
}

/// One patch's outcome.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PatchReport {
    /// First post (column, row) and size in posts.
    pub first: [usize; 2],
    pub size: [usize; 2],
    /// Its offsets and gains per photo (`None` for a photo that sees none of it), σ₀ and
    /// iterations; or why it failed (its posts keep the coarse heights, with no σ).
    pub radiometry: Option<Vec<Option<[f64; 2]>>>,
    pub sigma0: Option<f64>,
    /// The adjustment ended with σ₀ stalled and posts swinging by less than
    /// [`OslsmParams::stall_m`] rather than with every post settled.
    pub stalled: bool,
    /// The factor by which the residuals' correlation widened σ.
    pub inflation: Option<f64>,
    /// The mean share of the posts' information from the grey values that is the
    /// texture's, not the pixels' noise's.
    #[serde(default)]
    pub signal_share: Option<f64>,
    pub iterations: usize,
    /// Each iteration's σ₀ and moves (the convergence plot).
    pub history: Vec<Iteration>,
    pub failure: Option<OslsmError>,
}

/// The block, merged.
#[derive(Debug, Clone, PartialEq)]
pub struct Merged {
    pub z: Vec<f64>,
    /// NaN where no patch refined the post (a failed patch, or no grey values there).
    pub sigma_z: Vec<f64>,
    /// Reflectance per groundel (NaN where none), in f32 to keep a large block small.
    pub d: Vec<f32>,
    pub patches: Vec<PatchReport>,
}

/// Starts of the patches along one axis of `n` posts.
fn starts(n: usize, size: usize, overlap: usize) -> Vec<usize> {
    if n <= size {
        return vec![0];
    }
    let step = size - overlap;
    let mut v: Vec<usize> = (0..)
        .map(|k| k * step)
        .take_while(|&s| s + size < n)
        .collect();
    v.push(n - size);
    v.dedup();
    v
}

/// A weight in a patch at post coordinate `f` (0 at its first post; groundels fall
/// between posts): 1 inside, falling linearly to near zero over the `overlap` posts at each
/// edge that another patch shares.
fn ramp(f: f64, n: usize, overlap: usize, open_low: bool, open_high: bool) -> f64 {
    let o = overlap.max(1) as f64;
    let mut w: f64 = 1.0;
    if open_low {
        w = w.min((f + 1.0) / (o + 1.0));
    }
    if open_high {
        w = w.min((n as f64 - f) / (o + 1.0));
    }
    w
}

/// The photo that frames the most posts of `g` (at their heights, 4 px inside its edge);
/// the first such in `photos` on a tie.
fn datum_for(photos: &[PhotoView<'_>], g: &Grids) -> usize {
    let mut count = vec![0usize; photos.len()];
    for j in 0..g.rows {
        for i in 0..g.cols {
            let pt = crate::coords::GroundM::new(
                g.x0 + i as f64 * g.post_m,
                g.y0 + j as f64 * g.post_m,
                g.z[j * g.cols + i],
            );
            for (k, v) in photos.iter().enumerate() {
                let (w, h) = (v.image.width as f64, v.image.height as f64);
                if v.sensor.ground_to_image(pt).is_some_and(|q| {
                    q.col >= 4.0 && q.row >= 4.0 && q.col <= w - 4.0 && q.row <= h - 4.0
                }) {
                    count[k] += 1;
                }
            }
        }
    }
    let mut best = 0;
    for k in 1..photos.len() {
        if count[k] > count[best] {
            best = k;
        }
    }
    best
}

/// A patch refined with photo `order[0]` as its datum, its radiometry (per photo of `order`)
/// put back in the block's order and, where the block's datum (photo 0) sees the patch,
/// expressed against it: with gₒ = a₀ + b₀·D, D₀ = a₀ + b₀·D and photo k's
/// gₖ = aₖ + bₖ·D = (aₖ − bₖa₀/b₀) + (bₖ/b₀)·D₀ (the offsets and gains at the patch's centre;
/// each groundel's D with photo 0's a₀ and b₀ where it lies, `sub` the patch's grids).
fn to_block_datum(
    mut r: crate::matching::methods::oslsm::solve::Refinement,
    order: &[usize],
    sub: &Grids,
) -> crate::matching::methods::oslsm::solve::Refinement {
    if order.iter().enumerate().all(|(n, &k)| n == k) {
        return r;
    }
    let kp = order.len();
    let at0 = order.iter().position(|&k| k == 0).unwrap_or(0);
    let [a0, b0] = r.radiometry[at0];
    let convert = r.photo_seen[at0] && b0.is_finite() && b0.abs() > 1e-6;
    let mut rad = vec![[0.0, 1.0]; kp];
    let mut srad = vec![[0.0, 0.0]; kp];
    let mut seen = vec![false; kp];
    let mut field = vec![[0.0, 0.0, 0.0, 1.0, 0.0, 0.0]; kp];
    for n in 0..kp {
        field[order[n]] = r.radiometry_field[n];
        let [a, b] = r.radiometry[n];
        rad[order[n]] = if convert {
            [a - b * a0 / b0, b / b0]
        } else {
            [a, b]
        };
        srad[order[n]] = r.sigma_radiometry[n];
        seen[order[n]] = r.photo_seen[n];
    }
    if convert {
        let datum = r.radiometry_field[at0];
        let (pu, _) = sub.groundels();
        for (n, d) in r.d.iter_mut().enumerate() {
            let gr = sub.groundel(n % pu, n / pu);
            let [a, b] = radiometry_at(&datum, patch_coordinates(sub, gr.x, gr.y));
            *d = a + b * *d;
        }
    }
    r.radiometry_field = field;
    r.radiometry = rad;
    r.sigma_radiometry = srad;
    r.photo_seen = seen;
    r
}

/// Refines the whole of `coarse` patch by patch and merges the patches (a patch that fails
/// keeps the coarse heights and says why in its report).
pub fn refine_block(
    photos: &[PhotoView<'_>],
    coarse: &Grids,
    layout: PatchLayout,
    p: &OslsmParams,
    progress: &dyn Progress,
) -> Result<Merged, OslsmError> {
    let posts = coarse.cols.saturating_mul(coarse.rows);
    if coarse.z.len() != posts {
        return Err(OslsmError::Inconsistent {
            posts,
            heights: coarse.z.len(),
        });
    }
    if !(1..=64).contains(&coarse.per_cell) {
        return Err(OslsmError::Groundels(coarse.per_cell));
    }
    let size = layout.posts.max(2);
    let overlap = layout.overlap.min(size - 1);
    let cs = starts(coarse.cols, size, overlap);
    let rs = starts(coarse.rows, size, overlap);
    let jobs: Vec<(usize, usize)> = rs
        .iter()
        .flat_map(|&r| cs.iter().map(move |&c| (c, r)))
        .collect();
    progress.begin("patches", jobs.len() as u64);
    // Patches are solved a few at a time in parallel and merged in the block's order, so that
    // the sums (float additions do not commute in their rounding) are the same from run to
    // run whichever patch finishes first; no patch's groundels are kept beyond its chunk's
    // merge: the block holds only the sums, in f32 (a grey value to 7 digits).
    let n = coarse.z.len();
    let (gu, gv) = coarse.groundels();
    let m = coarse.per_cell;
    struct Sums {
        zs: Vec<f64>,
        ss: Vec<f64>,
        ws: Vec<f64>,
        ds: Vec<f32>,
        dw: Vec<f32>,
        patches: Vec<PatchReport>,
    }
    let solve = |&(c0, r0): &(usize, usize)| {
        let w = size.min(coarse.cols - c0);
        let h = size.min(coarse.rows - r0);
        let sub = Grids {
            x0: coarse.x0 + c0 as f64 * coarse.post_m,
            y0: coarse.y0 + r0 as f64 * coarse.post_m,
            post_m: coarse.post_m,
            cols: w,
            rows: h,
            z: (0..h)
                .flat_map(|j| (0..w).map(move |i| (r0 + j) * coarse.cols + c0 + i))
                .map(|k| coarse.z[k])
                .collect(),
            per_cell: coarse.per_cell,
        };
        // The patch's radiometric datum: the photo that frames most of it (the block's
        // reference where it frames as much), so that a patch beyond the reference's
        // footprint is matched from the photos that do see it.
        let datum = datum_for(photos, &sub);
        let order: Vec<usize> = std::iter::once(datum)
            .chain((0..photos.len()).filter(|&k| k != datum))
            .collect();
        let views: Vec<PhotoView<'_>> = order.iter().map(|&k| photos[k]).collect();
        let res = refine(&views, &sub, p).map(|r| to_block_datum(r, &order, &sub));
        let open = [c0 > 0, c0 + w < coarse.cols, r0 > 0, r0 + h < coarse.rows];
        (c0, r0, w, h, open, res)
    };
    let mut sums = Sums {
        zs: vec![0.0; n],
        ss: vec![0.0; n],
        ws: vec![0.0; n],
        ds: vec![0.0; gu * gv],
        dw: vec![0.0; gu * gv],
        patches: Vec::with_capacity(jobs.len()),
    };
    for chunk in jobs.chunks(4 * rayon::current_num_threads().max(1)) {
        let done: Vec<_> = chunk.par_iter().map(solve).collect();
        for (c0, r0, w, h, open, res) in done {
            let s = &mut sums;
            match res {
                Ok(r) => {
                    for j in 0..h {
                        for i in 0..w {
                            let l = j * w + i;
                            if !r.informed[l] {
                                continue;
                            }
                            let wt = ramp(i as f64, w, overlap, open[0], open[1])
                                * ramp(j as f64, h, overlap, open[2], open[3]);
                            let k = (r0 + j) * coarse.cols + c0 + i;
                            s.zs[k] += wt * r.z[l];
                            s.ss[k] += wt * r.sigma_z[l];
                            s.ws[k] += wt;
                        }
                    }
                    // Groundels: the weight of the post cell they lie in, by their place in it.
                    let (pu, pv) = ((w - 1) * m, (h - 1) * m);
                    for v in 0..pv {
                        for u in 0..pu {
                            let d = r.d[v * pu + u];
                            if !d.is_finite() {
                                continue;
                            }
                            let fi = (u as f64 + 0.5) / m as f64;
                            let fj = (v as f64 + 0.5) / m as f64;
                            let wt = ramp(fi, w, overlap, open[0], open[1])
                                * ramp(fj, h, overlap, open[2], open[3]);
                            let k = (r0 * m + v) * gu + c0 * m + u;
                            s.ds[k] += (wt * d) as f32;
                            s.dw[k] += wt as f32;
                        }
                    }
                    s.patches.push(PatchReport {
                        first: [c0, r0],
                        size: [w, h],
                        radiometry: Some(
                            r.radiometry
                                .iter()
                                .zip(&r.photo_seen)
                                .map(|(v, &seen)| seen.then_some(*v))
                                .collect(),
                        ),
                        sigma0: Some(r.sigma0),
                        stalled: r.stalled,
                        inflation: Some(r.inflation),
                        signal_share: Some(r.signal_share),
                        iterations: r.iterations.len(),
                        history: r.iterations,
                        failure: None,
                    });
                }
                Err(e) => s.patches.push(PatchReport {
                    first: [c0, r0],
                    size: [w, h],
                    radiometry: None,
                    sigma0: None,
                    stalled: false,
                    inflation: None,
                    signal_share: None,
                    iterations: 0,
                    history: Vec::new(),
                    failure: Some(e),
                }),
            }
            progress.advance(1);
        }
    }
    progress.end();
    let Sums {
        zs,
        ss,
        ws,
        mut ds,
        dw,
        mut patches,
    } = sums;
    // In the block's order.
    patches.sort_by_key(|pr| (pr.first[1], pr.first[0]));
    let z = (0..n)
        .map(|k| {
            if ws[k] > 0.0 {
                zs[k] / ws[k]
            } else {
                coarse.z[k]
            }
        })
        .collect();
    let sigma_z = (0..n)
        .map(|k| if ws[k] > 0.0 { ss[k] / ws[k] } else { f64::NAN })
        .collect();
    for (d, w) in ds.iter_mut().zip(&dw) {
        *d = if *w > 0.0 { *d / w } else { f32::NAN };
    }
    let d = ds;
    Ok(Merged {
        z,
        sigma_z,
        d,
        patches,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patches_cover_every_post_and_overlap_as_asked() {
        assert_eq!(starts(10, 24, 4), vec![0]);
        assert_eq!(starts(24, 24, 4), vec![0]);
        assert_eq!(starts(25, 24, 4), vec![0, 1]);
        assert_eq!(starts(60, 24, 4), vec![0, 20, 36]);
        for n in [25, 44, 60, 101] {
            let s = starts(n, 24, 4);
            assert_eq!(*s.last().unwrap() + 24, n);
            for w in s.windows(2) {
                assert!(w[1] > w[0] && w[1] <= w[0] + 20, "{s:?}");
            }
        }
        // Weights: 1 inside, positive everywhere, lower at a shared edge.
        assert_eq!(ramp(0.0, 24, 4, false, true), 1.0);
        assert!(ramp(23.0, 24, 4, false, true) > 0.0 && ramp(23.0, 24, 4, false, true) < 0.25);
        assert_eq!(ramp(10.0, 24, 4, true, true), 1.0);
    }
}
