//! Seed 001's object-space least-squares matching on one patch: the heights Z on posts, the
//! reflectance D on groundels and an offset and gain per photo, from every photo at once.
//!
//! Observation per groundel n and photo k that sees it (seed 001 eq. 9, with the reflectance
//! model of eq. 5, "perfect ambient reflection": the grey value is a linear function of D):
//!
//!   gₖ(Fₖ(Xₙ, Yₙ, Z(Xₙ, Yₙ))) = aₖ(s, t) + bₖ(s, t)·Dₙ + v,
//!
//! with the offset and the gain linear over the patch, aₖ = aₖ₀ + aₖₛ·s + aₖₜ·t and likewise
//! bₖ (s, t ∈ [−1, 1] across the patch). Seed 001 (eq. 8 ff.) takes them constant per patch
//! ("local linear radiometric correction"), and says it does not hold for large-scale photos:
//! a lens's light fall-off (cos⁴ and vignetting) changes one photo's gain against another's by
//! several per cent across a patch of a few hundred pixels, and an unmodelled gain difference
//! Δb leaves residuals Δb·(D − D̄) whose correlation with the texture's slopes moves each post
//! at random. On the independent jacksboro-close scene (vignetting 15 %), patches of 24 posts
//! had σ₀ 665 grey values against noise of 200 and posts 0.07 px off at random; patches of 8
//! posts, σ₀ 360 and 0.037 px (after the facets' curvature bias, `grids::facet_bias`).
//!
//! Fₖ the photo's sensor (ground → image), Z bilinear between the posts. Linearised (eq. 13):
//! ∂gₖ/∂Z = ∇gₖ·∂Fₖ/∂Z (eq. 11: the image gradient times the projection's movement with
//! height), spread over the groundel's four posts by their bilinear weights. Photo 0's offset
//! and gain are the datum (0 and 1: D is in its grey values). D enters each groundel's
//! observations only, so it is eliminated groundel by groundel before the normal equations
//! are assembled ("Reduced Normal Equation", seed 001 3.3.2 c), leaving the posts and the
//! radiometry, and recovered after each solution by back-substitution.
//!
//! Groundels should not fall on the datum photo's pixel grid at one phase (a groundel the
//! size of its ground pixel, aligned): bilinear sampling damps fine texture by an amount that
//! depends on where between pixel centres a sample falls, so the datum photo would be damped
//! less than the others and their gains read about 1 % off (0.04 % with groundels of 0.71
//! against pixels of 0.62 m, `tests::planted_gains_and_a_hill_are_recovered`).
//!
//! Where the texture does not fix Z, the terrain's curvature (second differences of the
//! posts along X and along Y) is observed as zero (seed 001, concluding remarks:
//! "regularization ... to minimize the surface curvature"), with a weight by rule, not tuned
//! per scene: [`OslsmParams::smoothness`] times the mean information a post receives from the
//! grey values, so it steers where the grey values are silent and yields where they speak.

use crate::coords::GroundM;
use crate::matching::methods::oslsm::banded::BorderedBand;
use crate::matching::methods::oslsm::grids::{Grids, Groundel};
use crate::matching::methods::oslsm::visibility::Occluder;
use crate::matching::methods::oslsm::PhotoView;
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Unknowns of one patch at the most: its dense normal matrix is then 200 MB (a block is cut
/// into patches by [`crate::matching::methods::oslsm::refine_block`]).
pub use crate::matching::project::matchers::OSLSM_MAX_UNKNOWNS as MAX_UNKNOWNS;

/// Parameters of the adjustment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OslsmParams {
    pub max_iterations: usize,
    /// Converged when no post moves by more than this (m) or than a fifth of its σ.
    pub converged_m: f64,
    /// Weight of the curvature observations relative to a post's mean information from the
    /// grey values.
    pub smoothness: f64,
    /// Divergence: σ₀ above this many times its lowest so far.
    pub diverging_ratio: f64,
    /// Visibility is re-tested after an iteration only if a post moved more than this, m.
    pub retest_sight_m: f64,
    /// Stalled (and ended, as converged) when σ₀ no longer falls (by 0.01 %) and no post moves
    /// more than this, m: bilinear sampling's slopes jump where a sample crosses a pixel
    /// centre, and a post whose minimum lies on such a kink swings about it by a few
    /// hundredths of a pixel for ever.
    pub stall_m: f64,
}

impl Default for OslsmParams {
    fn default() -> Self {
        OslsmParams {
            max_iterations: 60,
            converged_m: 0.005,
            smoothness: crate::matching::project::matchers::OSLSM_SMOOTHNESS,
            diverging_ratio: 2.0,
            retest_sight_m: 0.25,
            stall_m: 0.05,
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum OslsmError {
    #[error("{0} photos: the object-space matching needs at least 2")]
    TooFewPhotos(usize),
    #[error("the grids are too small: {cols} × {rows} posts (at least 2 × 2)")]
    TooSmall { cols: usize, rows: usize },
    #[error("{unknowns} unknowns in one patch: the dense normal matrix would take {mib} MiB (at most {max} unknowns: cut the block into smaller patches)")]
    TooBig {
        unknowns: usize,
        max: usize,
        mib: u64,
    },
    #[error("{heights} heights for {posts} posts")]
    Inconsistent { posts: usize, heights: usize },
    #[error("the groundels: {0} to a post cell (1 to 64)")]
    Groundels(usize),
    #[error("no groundel is seen by two photos")]
    NoObservations,
    #[error("the datum photo (the first) sees no groundel of the patch")]
    NoDatum,
    #[error("the normal equations are singular at iteration {iteration}")]
    Singular { iteration: usize },
    #[error("diverging at iteration {iteration}: σ₀ {sigma0:.3} against {best:.3} before")]
    Diverged {
        iteration: usize,
        sigma0: f64,
        best: f64,
    },
    #[error("no convergence in {iterations} iterations (last move {last_move_m:.4} m)")]
    NoConvergence { iterations: usize, last_move_m: f64 },
}

/// One iteration's figures, for the convergence plot.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Iteration {
    /// σ₀ of the grey values before this iteration's update, grey values.
    pub sigma0: f64,
    /// The largest and the RMS movement of a post, m.
    pub max_move_m: f64,
    pub rms_move_m: f64,
}

/// The refined patch.
#[derive(Debug, Clone, PartialEq)]
pub struct Refinement {
    /// The posts' heights, m (same layout as the input's).
    pub z: Vec<f64>,
    /// Their standard deviations σ₀·√Q from the reduced normal matrix, m.
    pub sigma_z: Vec<f64>,
    /// Reflectance per groundel (row v, column u at `v * cols + u`), photo 0's grey values;
    /// NaN where fewer than two photos see it.
    pub d: Vec<f64>,
    /// Photos seeing each groundel.
    pub seen_by: Vec<u8>,
    /// Offset and gain per photo at the patch's centre (photo 0's 0 and 1, the datum); a
    /// photo that sees none of the patch keeps its initial ones (see `photo_seen`).
    pub radiometry: Vec<[f64; 2]>,
    /// Each photo's whole radiometry across the patch, [a₀, aₛ, aₜ, b₀, bₛ, bₜ]
    /// ([`radiometry_at`], [`patch_coordinates`] on the patch's grids).
    pub radiometry_field: Vec<[f64; NR]>,
    /// Whether each photo observed a groundel of the patch.
    pub photo_seen: Vec<bool>,
    /// Whether each post took information from the grey values (a groundel seen by two
    /// photos around it); the others only follow the curvature observations.
    pub informed: Vec<bool>,
    /// Their standard deviations.
    pub sigma_radiometry: Vec<[f64; 2]>,
    pub sigma0: f64,
    /// Ended because σ₀ stalled with the posts swinging by less than
    /// [`OslsmParams::stall_m`], not because every post settled.
    pub stalled: bool,
    /// The factor by which the residuals' correlation between neighbouring groundels widens
    /// `sigma_z` beyond σ₀·√Q ([`correlation_inflation`]).
    pub inflation: f64,
    /// The mean share of the informed posts' information that is the texture's, not the
    /// pixels' noise's ([`honest_cofactors`]).
    pub signal_share: f64,
    pub iterations: Vec<Iteration>,
}

/// Radiometric unknowns per photo: offset and gain, each a constant and its slopes along s
/// and t across the patch (the module's documentation).
pub const NR: usize = 6;

/// Offset and gain of a photo's radiometry `r` ([a₀, aₛ, aₜ, b₀, bₛ, bₜ]) at patch
/// coordinates (s, t).
pub fn radiometry_at(r: &[f64; NR], [s, t]: [f64; 2]) -> [f64; 2] {
    [r[0] + r[1] * s + r[2] * t, r[3] + r[4] * s + r[5] * t]
}

/// Patch coordinates (s, t) ∈ [−1, 1]² of ground (x, y) on `g`'s posts.
pub fn patch_coordinates(g: &Grids, x: f64, y: f64) -> [f64; 2] {
    let w = ((g.cols - 1) as f64 * g.post_m).max(1e-9);
    let h = ((g.rows - 1) as f64 * g.post_m).max(1e-9);
    [2.0 * (x - g.x0) / w - 1.0, 2.0 * (y - g.y0) / h - 1.0]
}

/// The slopes' prior weight against their constant's information: only enough to keep the
/// normals regular where a photo sees a sliver of the patch (its s or t hardly varying).
const TREND_PRIOR: f64 = 1e-4;

/// One photo's observation of one groundel at the current linearisation point.
#[derive(Clone, Copy)]
struct Obs {
    photo: usize,
    /// Grey value observed and ∂g/∂Z.
    g: f64,
    dg_dz: f64,
    /// What white pixel noise of unit variance gives the sampled value and ∂g/∂Z as
    /// variance: bilinear interpolation averages the noise of four pixels, and its slopes
    /// difference them ([`noise_gains`]).
    noise_g: f64,
    noise_dz: f64,
}

/// The variances that white noise of unit variance in the pixels gives a bilinear sample at
/// (x, y) and the slope ∂g/∂Z = gx·∂col/∂Z + gy·∂row/∂Z (the `[dc, dr]` given) taken from
/// it ([`crate::image::ImageF32::bilinear_with_gradient`]). With fx, fy the fractions within
/// the pixel: the value ((1−fx)² + fx²)·((1−fy)² + fy²); gx = (1−fy)(p₁−p₀) + fy(q₁−q₀)
/// has 2((1−fy)² + fy²), gy likewise in fx, and their covariance is (1−2fx)(1−2fy).
pub(super) fn noise_gains(x: f64, y: f64, [dc, dr]: [f64; 2]) -> [f64; 2] {
    let (u, v) = (x - 0.5, y - 0.5);
    let (fx, fy) = (u - u.floor(), v - v.floor());
    let (sx, sy) = ((1.0 - fx).powi(2) + fx * fx, (1.0 - fy).powi(2) + fy * fy);
    let cov = (1.0 - 2.0 * fx) * (1.0 - 2.0 * fy);
    [
        sx * sy,
        2.0 * sy * dc * dc + 2.0 * sx * dr * dr + 2.0 * cov * dc * dr,
    ]
}

/// Samples every photo that sees groundel `gr` at height `z`.
fn observe(photos: &[PhotoView<'_>], sees: &[bool], gr: &Groundel, z: f64, out: &mut Vec<Obs>) {
    out.clear();
    let p = GroundM::new(gr.x, gr.y, z);
    for (k, v) in photos.iter().enumerate() {
        if !sees[k] {
            continue;
        }
        let Some(q) = v.sensor.ground_to_image(p) else {
            continue;
        };
        // The exact slope of what is sampled (not Sobel's smoothed one, which damps the
        // finest texture and so lengthens every Gauss–Newton step).
        let Some([g, gx, gy]) = v.image.bilinear_with_gradient(q.col, q.row) else {
            continue;
        };
        let Some(d) = v.sensor.height_partials(p) else {
            continue;
        };
        let [noise_g, noise_dz] = noise_gains(q.col, q.row, d);
        out.push(Obs {
            photo: k,
            g,
            dg_dz: gx * d[0] + gy * d[1],
            noise_g,
            noise_dz,
        });
    }
}

/// Refines `grids`' heights (the coarse DEM) from `photos` (photo 0 the radiometric datum).
pub fn refine(
    photos: &[PhotoView<'_>],
    grids: &Grids,
    p: &OslsmParams,
) -> Result<Refinement, OslsmError> {
    let kp = photos.len();
    if kp < 2 {
        return Err(OslsmError::TooFewPhotos(kp));
    }
    if grids.cols < 2 || grids.rows < 2 {
        return Err(OslsmError::TooSmall {
            cols: grids.cols,
            rows: grids.rows,
        });
    }
    // Unknowns: the posts, then offset and gain of photos 1..K; refused before anything is
    // allocated when the dense normal matrix (and one per worker) would be large.
    let n_posts = grids.cols.saturating_mul(grids.rows);
    let nu = n_posts.saturating_add(NR * (kp - 1));
    if nu > MAX_UNKNOWNS {
        return Err(OslsmError::TooBig {
            unknowns: nu,
            max: MAX_UNKNOWNS,
            mib: ((nu as u64).saturating_mul(nu as u64) * 8) >> 20,
        });
    }
    if grids.z.len() != n_posts {
        return Err(OslsmError::Inconsistent {
            posts: n_posts,
            heights: grids.z.len(),
        });
    }
    if !(1..=64).contains(&grids.per_cell) {
        return Err(OslsmError::Groundels(grids.per_cell));
    }
    let mut g = grids.clone();
    let (gu, gv) = g.groundels();
    let rad = |k: usize| n_posts + NR * (k - 1);
    let mut radiometry = vec![[0.0, 0.0, 0.0, 1.0, 0.0, 0.0]; kp];
    let groundels: Vec<_> = (0..gv)
        .flat_map(|v| (0..gu).map(move |u| (u, v)))
        .map(|(u, v)| g.groundel(u, v))
        .collect();
    let st: Vec<[f64; 2]> = groundels
        .iter()
        .map(|gr| patch_coordinates(&g, gr.x, gr.y))
        .collect();
    // Which photos frame each groundel is fixed at the start (with a margin for the posts'
    // moves): a groundel whose projection slipped in and out of a photo's edge from one
    // iteration to the next would change the observations and keep the posts from settling.
    let framed = framed(photos, &g, &groundels, FRAME_MARGIN_PX);
    let and = |a: Vec<Vec<bool>>| -> Vec<Vec<bool>> {
        a.into_iter()
            .zip(&framed)
            .map(|(v, f)| v.iter().zip(f).map(|(x, y)| *x && *y).collect())
            .collect()
    };
    let mut sees = and(sight(photos, &g, &groundels));
    // Initial radiometry: each photo's grey values against photo 0's over the groundels
    // both see, matched in mean and spread.
    {
        let mut pairs: Vec<Vec<(f64, f64)>> = vec![Vec::new(); kp];
        let mut obs = Vec::new();
        for (gr, s) in groundels.iter().zip(&sees) {
            observe(photos, s, gr, g.z_at(gr), &mut obs);
            if let Some(o0) = obs.iter().find(|o| o.photo == 0) {
                for o in obs.iter().filter(|o| o.photo != 0) {
                    pairs[o.photo].push((o0.g, o.g));
                }
            }
        }
        for k in 1..kp {
            let v = &pairs[k];
            if v.len() < 2 {
                continue;
            }
            let n = v.len() as f64;
            let (m0, mk) = v
                .iter()
                .fold((0.0, 0.0), |a, (x, y)| (a.0 + x / n, a.1 + y / n));
            let (s0, sk) = v.iter().fold((0.0, 0.0), |a, (x, y)| {
                (a.0 + (x - m0).powi(2), a.1 + (y - mk).powi(2))
            });
            let gain = if s0 > 0.0 { (sk / s0).sqrt() } else { 1.0 };
            radiometry[k] = [mk - gain * m0, 0.0, 0.0, gain, 0.0, 0.0];
        }
    }
    let mut d = vec![f64::NAN; groundels.len()];
    let mut seen_by = vec![0u8; groundels.len()];
    let mut iterations = Vec::new();
    let mut best_sigma0 = f64::INFINITY;
    let mut last_move = f64::INFINITY;
    let mut damping = 0.0f64;
    for iteration in 1..=p.max_iterations {
        // Each groundel's observations at the current heights; where it has no adjusted D
        // yet (the first iteration, or newly seen), its indirect back-mapping (seed 001
        // 3.3.3 e): the mean of what the photos seeing it show, in photo 0's grey values,
        // weighted by the ray's steepness.
        let per: Vec<(Option<f64>, u8, Vec<Obs>)> = groundels
            .par_iter()
            .zip(&sees)
            .zip(&d)
            .zip(&st)
            .map(|(((gr, s), dn), &pos)| {
                let mut obs = Vec::new();
                let z = g.z_at(gr);
                observe(photos, s, gr, z, &mut obs);
                // The adjusted D from the last iteration is kept where there is one.
                let keep = iteration > 1 && dn.is_finite();
                if obs.len() < 2 {
                    let back = (!keep).then_some(f64::NAN);
                    return (back, obs.len() as u8, Vec::new());
                }
                if keep {
                    return (None, obs.len() as u8, obs);
                }
                let (mut sw, mut sd) = (0.0, 0.0);
                for o in &obs {
                    let [a, b] = radiometry_at(&radiometry[o.photo], pos);
                    let w = steepness(photos[o.photo].sensor, gr, z);
                    sw += w;
                    sd += w * (o.g - a) / b;
                }
                (Some(sd / sw), obs.len() as u8, obs)
            })
            .collect();
        for (n, (back, c, _)) in per.iter().enumerate() {
            if let Some(v) = back {
                d[n] = *v;
            }
            seen_by[n] = *c;
        }
        // Normal equations with D eliminated groundel by groundel.
        let local = 4 + NR * (kp - 1);
        // (Few accumulators: each is a dense nu × nu matrix.)
        let assembled = per
            .par_iter()
            .enumerate()
            .with_min_len(
                per.len()
                    .div_ceil(rayon::current_num_threads().max(1))
                    .max(1),
            )
            .fold(
                || Assembly::zeros(nu, n_posts, kp),
                |mut acc, (n, (_, _, obs))| {
                    if obs.len() < 2 || !d[n].is_finite() {
                        return acc;
                    }
                    let Assembly {
                        n_mat,
                        rhs,
                        vv,
                        nobs,
                        noise,
                        noise_info,
                        post_residuals,
                    } = &mut acc;
                    let gr = &groundels[n];
                    let idx: Vec<usize> = gr
                        .posts
                        .iter()
                        .copied()
                        .chain((1..kp).flat_map(|k| (0..NR).map(move |i| rad(k) + i)))
                        .collect();
                    let pos = st[n];
                    let [s_, t_] = pos;
                    // Local normals over [posts(4), radiometry(NR(K−1)), D].
                    let mut nl = DMatrix::<f64>::zeros(local + 1, local + 1);
                    let mut bl = DVector::<f64>::zeros(local + 1);
                    let mut row = DVector::<f64>::zeros(local + 1);
                    let mut nz: Vec<usize> = Vec::with_capacity(local + 1);
                    // The places any observation touched: the posts and the radiometry of
                    // the photos that see this groundel.
                    let mut touched = vec![false; local];
                    let bb: f64 = obs
                        .iter()
                        .map(|o| radiometry_at(&radiometry[o.photo], pos)[1].powi(2))
                        .sum();
                    for o in obs {
                        let [a, b] = radiometry_at(&radiometry[o.photo], pos);
                        let l = o.g - a - b * d[n];
                        *vv += l * l;
                        *nobs += 1;
                        // The share of the residual and of the posts' information that the
                        // pixels' noise gives, D eliminated (its leverage b²/Σb²).
                        let free = 1.0 - b * b / bb;
                        noise[o.photo][0] += l * l;
                        noise[o.photo][1] += o.noise_g * free;
                        for (c, w) in gr.weights.iter().enumerate() {
                            noise_info[o.photo * n_posts + gr.posts[c]] +=
                                w * w * o.noise_dz * free;
                            let lc = &mut post_residuals[gr.posts[c]];
                            lc[0] += w * l * l;
                            lc[1] += w * free;
                        }
                        row.fill(0.0);
                        // g(Z + dZ) − (a + da) − (b + db)(D + dD) = 0, a and b linear in s, t:
                        // ∂g/∂Z·dZ − (da₀ + s·daₛ + t·daₜ) − D·(db₀ + …) − b·dD = −l.
                        // The row's non-zero places: the posts, this photo's radiometry, D.
                        nz.clear();
                        for (c, w) in gr.weights.iter().enumerate() {
                            row[c] = o.dg_dz * w;
                            nz.push(c);
                        }
                        if o.photo > 0 {
                            let c = 4 + NR * (o.photo - 1);
                            for (i, f) in [1.0, s_, t_].into_iter().enumerate() {
                                row[c + i] = -f;
                                row[c + 3 + i] = -d[n] * f;
                            }
                            nz.extend(c..c + NR);
                        }
                        for &i in &nz {
                            touched[i] = true;
                        }
                        row[local] = -b;
                        nz.push(local);
                        // row·rowᵀ and row·(−l) where they are not zero: the same sums as
                        // the whole products (a zero product adds nothing), without them.
                        for &i in &nz {
                            for &j in &nz {
                                nl[(i, j)] += row[i] * row[j];
                            }
                            bl[i] += row[i] * (-l);
                        }
                    }
                    // Eliminate D: N − n·nᵀ/n_dd.
                    let ndd = nl[(local, local)];
                    if ndd <= 0.0 {
                        return acc;
                    }
                    // Only where a row or column was touched: elsewhere the term is 0 − 0·x/n_dd,
                    // +0, which leaves every sum as it is (none is −0: each began at +0). A
                    // column at a time, down the column-major matrix.
                    let act: Vec<usize> = (0..local).filter(|&i| touched[i]).collect();
                    for &i in &act {
                        let ni = nl[(i, local)];
                        rhs[idx[i]] += bl[i] - ni * bl[local] / ndd;
                    }
                    for &j in &act {
                        let nj = nl[(j, local)];
                        let col = idx[j];
                        for &i in &act {
                            let ni = nl[(i, local)];
                            n_mat[(idx[i], col)] += nl[(i, j)] - ni * nj / ndd;
                        }
                    }
                    acc
                },
            )
            .reduce(|| Assembly::zeros(nu, n_posts, kp), Assembly::add);
        let Assembly {
            mut n_mat,
            mut rhs,
            vv,
            nobs,
            noise,
            noise_info,
            post_residuals,
        } = assembled;
        let observed = per.iter().filter(|x| x.2.len() >= 2).count();
        if observed == 0 {
            return Err(OslsmError::NoObservations);
        }
        if !per.iter().any(|x| x.2.iter().any(|o| o.photo == 0)) {
            return Err(OslsmError::NoDatum);
        }
        // A photo that sees none of the patch: its offset and gain stay (nothing observes
        // them). A post no observed groundel touches: held where it is by a tiny weight,
        // beside what the curvature gives it (it is not reported as informed).
        let mut photo_seen = vec![true; kp];
        for k in 1..kp {
            if n_mat[(rad(k), rad(k))] <= 0.0 {
                photo_seen[k] = false;
                for i in 0..NR {
                    n_mat[(rad(k) + i, rad(k) + i)] = 1.0;
                }
                continue;
            }
            // The slopes held towards none by a weak prior (TREND_PRIOR).
            for (c, i) in [(0, 1), (0, 2), (3, 4), (3, 5)] {
                let w = TREND_PRIOR * n_mat[(rad(k) + c, rad(k) + c)];
                n_mat[(rad(k) + i, rad(k) + i)] += w;
                rhs[rad(k) + i] -= w * radiometry[k][i];
            }
        }
        let informed: Vec<bool> = (0..n_posts).map(|i| n_mat[(i, i)] > 0.0).collect();
        // Unknowns: posts, radiometry, and one D per observed groundel.
        let dof = (nobs as f64 - (nu + observed) as f64).max(1.0);
        let sigma0 = (vv / dof).sqrt();
        // Curvature observations, weighted by rule.
        let mean_info = (0..n_posts).map(|i| n_mat[(i, i)]).sum::<f64>() / n_posts as f64;
        let w = p.smoothness * mean_info.max(1e-12);
        for (i, inf) in informed.iter().enumerate() {
            if !inf {
                n_mat[(i, i)] += 1e-6 * mean_info.max(1e-12);
            }
        }
        for r in curvature_rows(g.cols, g.rows) {
            let l = -second_difference(&r, &g.z);
            for &(i, ci) in &r {
                rhs[i] += w * ci * l;
            }
        }
        add_curvature(&mut n_mat, g.cols, g.rows, w);
        if sigma0 > p.diverging_ratio * best_sigma0 {
            return Err(OslsmError::Diverged {
                iteration,
                sigma0,
                best: best_sigma0,
            });
        }
        best_sigma0 = best_sigma0.min(sigma0);
        // Step control (Levenberg–Marquardt): while σ₀ falls the steps are Gauss–Newton's;
        // once it no longer falls (by 0.1 %) the diagonal is raised by μ·Nᵢᵢ, μ doubling
        // each such iteration, so that a post swinging between the two sides of a kink of the
        // bilinear slopes (each side's model putting the minimum on the other) closes in on
        // it instead of cycling. The solution's fixed point is Gauss–Newton's.
        if let Some(last) = iterations.last() {
            let last: &Iteration = last;
            if sigma0 > (1.0 - 1e-3) * last.sigma0 {
                damping = if damping > 0.0 { 2.0 * damping } else { 1.0 };
            } else {
                damping *= 0.5;
                if damping < 0.1 {
                    damping = 0.0;
                }
            }
        }
        let mut solve_mat = n_mat.clone();
        if damping > 0.0 {
            for i in 0..nu {
                solve_mat[(i, i)] *= 1.0 + damping;
            }
        }
        // The posts' band and the radiometry's border ([`BorderedBand`]).
        let chol =
            BorderedBand::factor(&solve_mat, n_posts).ok_or(OslsmError::Singular { iteration })?;
        let dx = chol.solve(&rhs);
        // Back-substitution of each groundel's dD, then the updates.
        let dd: Vec<f64> = per
            .par_iter()
            .enumerate()
            .map(|(n, (_, _, obs))| {
                if obs.len() < 2 || !d[n].is_finite() {
                    return 0.0;
                }
                let gr = &groundels[n];
                let (mut ndd, mut bd) = (0.0, 0.0);
                let pos = st[n];
                for o in obs {
                    let [a, b] = radiometry_at(&radiometry[o.photo], pos);
                    let l = o.g - a - b * d[n];
                    let mut rest = 0.0;
                    for (c, wt) in gr.weights.iter().enumerate() {
                        rest += o.dg_dz * wt * dx[gr.posts[c]];
                    }
                    if o.photo > 0 {
                        let r = rad(o.photo);
                        let mut dr = [0.0; NR];
                        for (i, v) in dr.iter_mut().enumerate() {
                            *v = dx[r + i];
                        }
                        let [da, db] = radiometry_at(&dr, pos);
                        rest += -da - d[n] * db;
                    }
                    // −b·dD = −l − rest  ⇒ least squares over the photos.
                    ndd += b * b;
                    bd += -b * (-l - rest);
                }
                bd / ndd
            })
            .collect();
        for (dn, ddn) in d.iter_mut().zip(&dd) {
            if dn.is_finite() {
                *dn += ddn;
            }
        }
        for k in 1..kp {
            for i in 0..NR {
                radiometry[k][i] += dx[rad(k) + i];
            }
        }
        // Convergence is judged on the posts the grey values inform (the others follow the
        // curvature and settle with them): each moved less than `converged_m`, or less than
        // a fifth of its own σ (noise keeps a Gauss–Newton step on resampled grey values
        // jittering at that level; σ₀/√Nᵢᵢ, a lower bound of σ, keeps the test strict).
        let (mut max_move, mut ss, mut settled) = (0.0f64, 0.0, true);
        for (i, ((z, dz), inf)) in g.z.iter_mut().zip(dx.iter()).zip(&informed).enumerate() {
            *z += dz;
            if *inf {
                max_move = max_move.max(dz.abs());
                ss += dz * dz;
                let tol = p
                    .converged_m
                    .max(CONVERGED_SIGMA * sigma0 / n_mat[(i, i)].max(1e-300).sqrt());
                settled &= dz.abs() < tol;
            }
        }
        iterations.push(Iteration {
            sigma0,
            max_move_m: max_move,
            rms_move_m: (ss / informed.iter().filter(|i| **i).count().max(1) as f64).sqrt(),
        });
        last_move = max_move;
        if !max_move.is_finite() {
            return Err(OslsmError::Singular { iteration });
        }
        let stalled = iterations.len() >= 2
            && max_move < p.stall_m
            && sigma0 > (1.0 - 1e-4) * iterations[iterations.len() - 2].sigma0;
        if settled || stalled {
            // The precision from the normal matrix of the last linearisation, widened by the
            // residuals' correlation between neighbouring groundels (the normal matrix takes
            // them as independent).
            drop(chol);
            let noise = noise_information(&noise, &noise_info, n_posts);
            let Some((inv, share)) = honest_cofactors(n_mat, &noise, &informed, &g, w) else {
                return Err(OslsmError::Singular { iteration });
            };
            let signal_share = mean_share(&share, &informed);
            let inflation =
                correlation_inflation(photos, &sees, &groundels, &st, &g, &d, &radiometry);
            let local = local_variance(&post_residuals);
            let sigma_z = (0..n_posts)
                .map(|i| inflation * sigma0 * (local[i] * inv[i]).max(0.0).sqrt())
                .collect();
            let sigma_radiometry = (0..kp)
                .map(|k| {
                    if k == 0 {
                        [0.0, 0.0]
                    } else {
                        [
                            sigma0 * inv[rad(k)].max(0.0).sqrt(),
                            sigma0 * inv[rad(k) + 3].max(0.0).sqrt(),
                        ]
                    }
                })
                .collect();
            for (dn, c) in d.iter_mut().zip(&seen_by) {
                if *c < 2 {
                    *dn = f64::NAN;
                }
            }
            return Ok(Refinement {
                z: g.z,
                sigma_z,
                d,
                seen_by,
                radiometry: radiometry
                    .iter()
                    .map(|r| radiometry_at(r, [0.0, 0.0]))
                    .collect(),
                radiometry_field: radiometry,
                photo_seen,
                informed,
                sigma_radiometry,
                sigma0,
                stalled: !settled,
                inflation,
                signal_share,
                iterations,
            });
        }
        // The terrain moved: who sees what may have changed. Not re-tested once the posts
        // move less than `retest_sight_m`: a groundel at a ridge's edge can be hidden at one
        // height and seen at the next, and the posts then swing between the two for ever.
        if max_move > p.retest_sight_m {
            sees = and(sight(photos, &g, &groundels));
        }
    }
    Err(OslsmError::NoConvergence {
        iterations: p.max_iterations,
        last_move_m: last_move,
    })
}

/// One worker's share of an iteration's normal equations (D eliminated), with what the
/// pixels' noise gives them.
struct Assembly {
    n_mat: DMatrix<f64>,
    rhs: DVector<f64>,
    /// The grey values' squared residuals and their number.
    vv: f64,
    nobs: usize,
    /// Per photo: Σ v² and Σ of what unit pixel noise gives v² ([`Obs::noise_g`] times
    /// 1 − the leverage of D).
    noise: Vec<[f64; 2]>,
    /// Per photo and post (photo-major): the posts' information that unit pixel noise in
    /// that photo gives their slopes ([`Obs::noise_dz`]).
    noise_info: Vec<f64>,
    /// Per post: Σ w·v² and Σ w·(1 − the leverage of D) over the observations it takes
    /// part in, w its bilinear weight ([`local_variance`]).
    post_residuals: Vec<[f64; 2]>,
}

impl Assembly {
    fn zeros(nu: usize, n_posts: usize, kp: usize) -> Self {
        Assembly {
            n_mat: DMatrix::zeros(nu, nu),
            rhs: DVector::zeros(nu),
            vv: 0.0,
            nobs: 0,
            noise: vec![[0.0; 2]; kp],
            noise_info: vec![0.0; n_posts * kp],
            post_residuals: vec![[0.0; 2]; n_posts],
        }
    }

    fn add(mut self, o: Self) -> Self {
        self.n_mat += o.n_mat;
        self.rhs += o.rhs;
        self.vv += o.vv;
        self.nobs += o.nobs;
        for (a, b) in self.noise.iter_mut().zip(&o.noise) {
            a[0] += b[0];
            a[1] += b[1];
        }
        for (a, b) in self.noise_info.iter_mut().zip(&o.noise_info) {
            *a += b;
        }
        for (a, b) in self.post_residuals.iter_mut().zip(&o.post_residuals) {
            a[0] += b[0];
            a[1] += b[1];
        }
        self
    }
}

/// Each post's variance factor against the patch's σ₀²: the mean square of the residuals
/// it takes part in (weighted by its bilinear weights, over their redundancy) against the
/// patch's. σ₀ is one number per patch, and a patch's misfit gathers where the model does
/// not hold (a fold the facets cannot follow, a hidden slope, the patch's edge): on the
/// simulator's block σ₀ was 103 grey values in the patches without, 180–290 in those with,
/// and every post of those carried it. A post seen through fewer than
/// [`LOCAL_MIN_OBSERVATIONS`] observations' worth keeps the patch's.
fn local_variance(local: &[[f64; 2]]) -> Vec<f64> {
    let (vv, n) = local
        .iter()
        .fold((0.0, 0.0), |a, l| (a.0 + l[0], a.1 + l[1]));
    if vv <= 0.0 || n <= 0.0 {
        return vec![1.0; local.len()];
    }
    let mean = vv / n;
    local
        .iter()
        .map(|[v, c]| {
            if *c >= LOCAL_MIN_OBSERVATIONS {
                v / c / mean
            } else {
                1.0
            }
        })
        .collect()
}

/// The fewest observations' worth (Σ w·(1 − leverage)) from which a post's own variance
/// factor is taken ([`local_variance`]): its relative error is then √(2/16), 35 %.
const LOCAL_MIN_OBSERVATIONS: f64 = 16.0;

/// What the pixels' noise alone gives each post's information from the grey values
/// (D eliminated): Σₖ σₖ²·Eₖᵢ, with each photo's noise variance σₖ² from its own residuals
/// (Σv² over what unit noise gives them; the model's misfit counts as noise, so this errs
/// high and σ with it).
fn noise_information(noise: &[[f64; 2]], noise_info: &[f64], n_posts: usize) -> Vec<f64> {
    let var: Vec<f64> = noise
        .iter()
        .map(|[vv, c]| if *c > 0.0 { vv / c } else { 0.0 })
        .collect();
    (0..n_posts)
        .map(|i| {
            var.iter()
                .enumerate()
                .map(|(k, s2)| s2 * noise_info[k * n_posts + i])
                .sum()
        })
        .collect()
}

/// One curvature observation: its three posts with their coefficients 1, −2, 1.
type CurvatureRow = [(usize, f64); 3];

/// The curvature observations of a `cols` × `rows` grid of posts: the second differences
/// along rows and along columns.
fn curvature_rows(cols: usize, rows: usize) -> impl Iterator<Item = CurvatureRow> {
    let row = |a, b, c| [(a, 1.0), (b, -2.0), (c, 1.0)];
    let along = (0..rows).flat_map(move |j| {
        (1..cols.saturating_sub(1)).map(move |i| {
            let k = j * cols + i;
            row(k - 1, k, k + 1)
        })
    });
    let across = (1..rows.saturating_sub(1)).flat_map(move |j| {
        (0..cols).map(move |i| {
            let k = j * cols + i;
            row(k - cols, k, k + cols)
        })
    });
    along.chain(across)
}

/// The second difference of heights `z` that curvature observation `r` takes.
fn second_difference(r: &CurvatureRow, z: &[f64]) -> f64 {
    r.iter().map(|&(i, c)| c * z[i]).sum()
}

/// Adds `w`·CᵀC, the curvature observations' normals with weight `w`, to `n`.
fn add_curvature(n: &mut DMatrix<f64>, cols: usize, rows: usize, w: f64) {
    for r in curvature_rows(cols, rows) {
        for &(i, ci) in &r {
            for &(j, cj) in &r {
                n[(i, j)] += w * ci * cj;
            }
        }
    }
}

/// Scales the grey values' normals `n_mat` (D eliminated, before the curvature) to the
/// texture's information, and gives each post's share sᵢ = 1 − Eᵢ/Nᵢᵢ of it, with Eᵢ
/// (`noise`) what the pixels' noise alone gives it. The slopes ∂g/∂Z are taken from noisy
/// pixels: where the texture is faint they are mostly noise and Nᵢᵢ is large all the same,
/// so that σ₀/√Nᵢᵢ says a post is fixed that the grey values hardly move (and Gauss–Newton's
/// steps shrink by sᵢ there, an errors-in-variables model: the posts stall short of the
/// terrain, near where they started). Scaling each post's rows and columns by √sᵢ makes the
/// diagonal N − E, where E sits.
fn texture_share(n_mat: &mut DMatrix<f64>, noise: &[f64], informed: &[bool]) -> Vec<f64> {
    let mut share: Vec<f64> = (0..n_mat.nrows())
        .map(|i| match (informed.get(i), noise.get(i)) {
            (Some(true), Some(e)) => (1.0 - e / n_mat[(i, i)]).clamp(0.0, 1.0),
            (Some(false), _) => 0.0,
            _ => 1.0,
        })
        .collect();
    let scale: Vec<f64> = share.iter().map(|s| s.sqrt()).collect();
    for j in 0..n_mat.ncols() {
        for i in 0..n_mat.nrows() {
            n_mat[(i, j)] *= scale[i] * scale[j];
        }
    }
    share.truncate(informed.len());
    share
}

/// The mean of the informed posts' shares.
fn mean_share(share: &[f64], informed: &[bool]) -> f64 {
    let (sum, n) = share
        .iter()
        .zip(informed)
        .filter(|(_, i)| **i)
        .fold((0.0, 0usize), |a, (s, _)| (a.0 + s, a.1 + 1));
    if n > 0 {
        sum / n as f64
    } else {
        0.0
    }
}

/// The cofactors' diagonal (posts, then radiometry) for the σ, and the posts' texture shares, from the solution's
/// normals `n_mat` (curvature weight `w` included) with only the texture's information
/// counted ([`texture_share`], `noise` what the pixels' noise gives each post).
///
/// The curvature keeps the solution's weight: σ₀²·Q is the covariance of this estimator,
/// whose curvature observations follow a rule. Giving the curvature the terrain's own
/// variance component instead (Förstner's estimate from the posts' second differences),
/// in the normals or as the error the rule leaves (σ₀²·QNQ + w²s_c²·QCᵀCQ), took the
/// second differences as independent where the terrain's are alike from post to post: on
/// the simulator's block (terrain bending within 10 m posts) RMS(error/σ) fell from 0.67 to
/// 0.41–0.58 and on jacksboro-close from 1.18 to 0.61, with no scene better for it.
///
/// `None` when those normals are singular (no post with texture in the patch).
fn honest_cofactors(
    mut n_mat: DMatrix<f64>,
    noise: &[f64],
    informed: &[bool],
    g: &Grids,
    w: f64,
) -> Option<(Vec<f64>, Vec<f64>)> {
    add_curvature(&mut n_mat, g.cols, g.rows, -w);
    let share = texture_share(&mut n_mat, noise, informed);
    add_curvature(&mut n_mat, g.cols, g.rows, w);
    let n_posts = g.cols * g.rows;
    BorderedBand::factor(&n_mat, n_posts).map(|c| (c.inverse_diagonal(), share))
}

/// How much the grey-value residuals' correlation between neighbouring groundels widens a
/// post's σ. A post's estimate moves with the sum of its observations' scores sₙ = ∂g/∂Z·vₙ
/// (the design row times the residual); the normal matrix takes them as independent, so its
/// variance holds Σ sₙ² only. Their correlation adds Σₙ Σₘ sₙ sₘ over neighbouring
/// groundels: the factor is Σ_lags w·Σₙ sₙ sₙ₊ₗₐ₉ / Σ sₙ² over the patch (each photo's
/// scores with its own, lags up to [`HAC_LAG`] groundels in each direction, Bartlett weights
/// w, as Newey and West's estimator), its square root widening σ. Resampling and a groundel a
/// little unlike a pixel leave residuals correlated even where the noise is white.
fn correlation_inflation(
    photos: &[PhotoView<'_>],
    sees: &[Vec<bool>],
    groundels: &[Groundel],
    st: &[[f64; 2]],
    g: &Grids,
    d: &[f64],
    radiometry: &[[f64; NR]],
) -> f64 {
    let (gu, gv) = g.groundels();
    let kp = photos.len();
    // Score per groundel and photo (0 where not observed).
    let score: Vec<f64> = groundels
        .par_iter()
        .enumerate()
        .flat_map_iter(|(n, gr)| {
            let mut obs = Vec::new();
            if d[n].is_finite() {
                observe(photos, &sees[n], gr, g.z_at(gr), &mut obs);
            }
            let mut v = vec![0.0; kp];
            if obs.len() >= 2 {
                for o in &obs {
                    let [a, b] = radiometry_at(&radiometry[o.photo], st[n]);
                    v[o.photo] = o.dg_dz * (o.g - a - b * d[n]);
                }
            }
            v
        })
        .collect();
    let l = HAC_LAG as i64;
    let (gu_i, gv_i) = (gu as i64, gv as i64);
    let mut total = 0.0;
    let mut zero = 0.0;
    for dv in -l..=l {
        for du in -l..=l {
            let mut c = 0.0;
            for v in 0.max(-dv)..gv_i.min(gv_i - dv) {
                for u in 0.max(-du)..gu_i.min(gu_i - du) {
                    let n = (v * gu_i + u) as usize * kp;
                    let m = ((v + dv) * gu_i + u + du) as usize * kp;
                    for k in 0..kp {
                        c += score[n + k] * score[m + k];
                    }
                }
            }
            let w =
                (1.0 - du.abs() as f64 / (l + 1) as f64) * (1.0 - dv.abs() as f64 / (l + 1) as f64);
            total += w * c;
            if du == 0 && dv == 0 {
                zero = c;
            }
        }
    }
    if zero > 0.0 {
        (total / zero).max(1.0).sqrt()
    } else {
        1.0
    }
}

/// Groundels of lag in the correlation of the scores ([`correlation_inflation`]): two
/// groundels of about a pixel each cover the reach of bilinear resampling and of a pixel's
/// footprint.
const HAC_LAG: usize = 2;

/// A post has settled when it moves less than this fraction of its σ (or than
/// [`OslsmParams::converged_m`]).
const CONVERGED_SIGMA: f64 = 0.2;

/// Pixels a groundel's projection must lie inside a photo's edge at the start to be observed
/// in it (a post may move a few pixels of parallax).
const FRAME_MARGIN_PX: f64 = 4.0;

/// Whether each photo's image holds each groundel of `g` at least `margin` px inside its
/// edge; none where fewer than two photos do (nothing to match). Where the datum photo (0)
/// does not, the other photos' gains, fixed where they share groundels with it, carry the
/// reflectance's scale (the patches take as datum the photo that frames most of them).
fn framed(
    photos: &[PhotoView<'_>],
    g: &Grids,
    groundels: &[Groundel],
    margin: f64,
) -> Vec<Vec<bool>> {
    groundels
        .par_iter()
        .map(|gr| {
            let pt = GroundM::new(gr.x, gr.y, g.z_at(gr));
            let v: Vec<bool> = photos
                .iter()
                .map(|v| {
                    let (w, h) = (v.image.width as f64, v.image.height as f64);
                    v.sensor.ground_to_image(pt).is_some_and(|q| {
                        q.col >= margin
                            && q.row >= margin
                            && q.col <= w - margin
                            && q.row <= h - margin
                    })
                })
                .collect();
            if v.iter().filter(|x| **x).count() >= 2 {
                v
            } else {
                vec![false; v.len()]
            }
        })
        .collect()
}

/// Which photos see each groundel on the terrain of `g`: only these observe it.
pub fn sight(photos: &[PhotoView<'_>], g: &Grids, groundels: &[Groundel]) -> Vec<Vec<bool>> {
    let terrain = Occluder::new(g);
    groundels
        .par_iter()
        .map(|gr| {
            let pt = GroundM::new(gr.x, gr.y, g.z_at(gr));
            photos.iter().map(|v| terrain.sees(v.sensor, pt)).collect()
        })
        .collect()
}

/// The weight of a photo's grey value in a groundel's back-mapped reflectance: the cosine²
/// of its ray's angle from the vertical (seed 001 3.3.3 e: "the weight is assigned according
/// to the slope of ray").
fn steepness(sensor: &(dyn crate::geometry::Sensor + Sync), gr: &Groundel, z: f64) -> f64 {
    let p = GroundM::new(gr.x, gr.y, z);
    let Some(q) = sensor.ground_to_image(p) else {
        return 0.0;
    };
    match (
        sensor.image_to_ground(q, z),
        sensor.image_to_ground(q, z + 1.0),
    ) {
        (Some(a), Some(b)) => 1.0 / (1.0 + (b.x - a.x).powi(2) + (b.y - a.y).powi(2)),
        _ => 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A post whose observations carry the patch's misfit gets a factor above 1, the clean
    /// ones below; weighted by their observations the factors average 1 (σ₀² is kept as a
    /// whole); a post with too few observations keeps the patch's.
    #[test]
    fn each_post_takes_the_variance_of_its_own_residuals() {
        // Three posts seen through 100 observations' worth each, the second with 9 × the
        // others' mean square; a fourth through 4.
        let local = [[100.0, 100.0], [900.0, 100.0], [100.0, 100.0], [4.0, 4.0]];
        let f = local_variance(&local);
        let mean = (100.0 + 900.0 + 100.0 + 4.0) / 304.0;
        for (i, &want) in [1.0 / mean, 9.0 / mean, 1.0 / mean, 1.0].iter().enumerate() {
            assert!((f[i] - want).abs() < 1e-12, "post {i}: {} for {want}", f[i]);
        }
        assert!(f[1] > 1.0 && f[0] < 1.0);
        // Among posts that all take their own, the factors weighted by the observations
        // average 1.
        let three = local_variance(&local[..3]);
        let weighted: f64 = three.iter().zip(&local[..3]).map(|(f, l)| f * l[1]).sum();
        assert!((weighted / 300.0 - 1.0).abs() < 1e-12, "{weighted}");
        // No residuals at all: every post keeps the patch's σ₀.
        assert_eq!(local_variance(&[[0.0, 50.0]; 3]), vec![1.0; 3]);
    }
}
