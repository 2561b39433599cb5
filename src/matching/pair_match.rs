//! Matching an epipolar-rectified pair (rows correspond): the plane sweep over whole-pixel
//! disparities d = x_left − x_right (Middlebury's and OpenCV's convention), the winner per
//! pixel, or per pixel after semi-global aggregation, a left-right consistency check, and the
//! sub-pixel disparity by a parabola or by least-squares matching with its σ.

use super::plane_sweep::{score, winner, Cells, Planes, Prepared, Scores, Unseen, Winner};
pub use super::refine::Subpixel;
use super::refine::{refine, RefineFailure, Window};
use super::regions::{remove_wrong_heights, RegionParams};
use super::sgm::{aggregate, SgmParams};
use super::sweep::HeightMap;
use crate::image::ImageF32;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// What removes wrong matches after the winner is taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Filter {
    /// The winner per pixel, nothing more.
    None,
    /// Seed 000's region filter (§2.3) on the disparities.
    Regions,
    /// Semi-global aggregation along 8 paths before the winner (Hirschmüller 2008).
    Sgm,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PairParams {
    /// Disparities searched, whole pixels, both inclusive.
    pub d_min: i64,
    pub d_max: i64,
    /// Side of the correlation window, px (odd).
    pub window: usize,
    /// Lowest correlation accepted at the winning disparity.
    pub threshold: f64,
    pub filter: Filter,
    pub sgm: SgmParams,
    pub regions: RegionParams,
    /// Largest difference between the left's and the right's disparity, px; None: no check.
    pub lr_tolerance: Option<f64>,
    pub subpixel: Subpixel,
}

impl Default for PairParams {
    fn default() -> Self {
        PairParams {
            d_min: 0,
            d_max: 63,
            window: 5,
            threshold: 0.3,
            filter: Filter::Sgm,
            sgm: SgmParams::default(),
            regions: RegionParams {
                search_distance: 2,
                height_threshold: 1.5,
                population_threshold: 50,
            },
            lr_tolerance: Some(1.0),
            subpixel: Subpixel::Parabola,
        }
    }
}

/// What happened to the pixels, for the report.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PairStats {
    pub width: usize,
    pub height: usize,
    pub disparities: usize,
    /// Pixel-candidates scored (pixels × disparities).
    pub candidates: u64,
    /// Pixels whose window lies inside the left photo.
    pub pixels: usize,
    /// Pixels for which the right photo does not see every disparity searched.
    pub unseen: usize,
    /// Pixels with a flat window, or a winner with a flat neighbour.
    pub unscored: usize,
    pub below_threshold: usize,
    pub left_right: usize,
    pub regions: usize,
    pub matched: usize,
    pub lsm_refined: usize,
    /// Why least squares failed, and how often (the parabola's value was kept).
    pub lsm_failures: BTreeMap<String, usize>,
    pub seconds_score: f64,
    pub seconds_total: f64,
}

/// Disparities on the left photo's pixels (NaN where no match), their correlation and σ (px).
#[derive(Debug, Clone, PartialEq)]
pub struct DisparityMap {
    pub width: usize,
    pub height: usize,
    pub d: Vec<f32>,
    pub corr: Vec<f32>,
    pub sigma: Vec<f32>,
    pub stats: PairStats,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PairError {
    #[error("the photos have {left} and {right} rows: a rectified pair has the same number of rows in both (rectify it first)")]
    Rows { left: usize, right: usize },
    #[error("disparities {min} … {max}: MIN must not exceed MAX, and at most {MAX_DISPARITIES} disparities are searched")]
    Range { min: i64, max: i64 },
    #[error("window {0}: odd, from 3 to 31 px")]
    Window(usize),
    #[error("the left photo ({w} × {h} px) is smaller than the window ({window} px)")]
    TooSmall { w: usize, h: usize, window: usize },
    #[error("threshold {0}: a correlation from −1 to 1")]
    Threshold(f64),
    #[error("matching needs about {need_mb:.0} MB; the limit is {limit_mb} MB: crop the photos, narrow the disparities, use --filter none or regions (no volume kept), or raise --max-memory")]
    Memory { need_mb: f64, limit_mb: u64 },
}

pub const MAX_DISPARITIES: i64 = 4096;
/// Rows scored together (one rayon task).
const BAND: usize = 32;

/// Bytes that matching `left` against `right` holds at once.
pub fn bytes_needed(w: usize, h: usize, wr: usize, p: &PairParams) -> f64 {
    let np = (p.d_max - p.d_min + 1).max(0) as usize;
    let k = p.window / 2;
    let cols = w.saturating_sub(2 * k);
    let rows = h.saturating_sub(2 * k);
    let images = 8.0 * (w * h + wr * h) as f64 + 12.0 * (w * h) as f64;
    let band = Cells {
        col0: k,
        stride: 1,
        cols,
        rows: (0..BAND.min(rows)).collect(),
    };
    let bands = super::plane_sweep::bytes_needed(w, &band, np, k, false)
        * rayon::current_num_threads() as f64;
    let volume = match p.filter {
        Filter::Sgm => {
            4.0 * (cols * rows * np) as f64 + super::sgm::bytes_needed(cols * rows, np, cols)
        }
        _ => 0.0,
    };
    images + bands + volume
}

fn check(left: &ImageF32, right: &ImageF32, p: &PairParams) -> Result<(), PairError> {
    if left.height != right.height {
        return Err(PairError::Rows {
            left: left.height,
            right: right.height,
        });
    }
    if p.d_min > p.d_max || p.d_max - p.d_min >= MAX_DISPARITIES {
        return Err(PairError::Range {
            min: p.d_min,
            max: p.d_max,
        });
    }
    if p.window.is_multiple_of(2) || !(3..=31).contains(&p.window) {
        return Err(PairError::Window(p.window));
    }
    if left.width < p.window || left.height < p.window {
        return Err(PairError::TooSmall {
            w: left.width,
            h: left.height,
            window: p.window,
        });
    }
    if !(-1.0..=1.0).contains(&p.threshold) {
        return Err(PairError::Threshold(p.threshold));
    }
    Ok(())
}

/// Per cell of a row of scores ("higher is better", NaN where unseen): the winner, and the
/// right photo's own winner for each right column (for the left-right check).
fn row_winners(row: &[f32], cols: usize, np: usize) -> Vec<Option<Winner>> {
    (0..cols)
        .map(|i| winner(&row[i * np..(i + 1) * np], Unseen::Skip))
        .collect()
}

/// The right photo's best plane for right column x: the best over cells i with
/// x = col0 + i − first − p (the same scores, read along the other diagonal).
fn right_best(
    row: &[f32],
    cols: usize,
    np: usize,
    col0: usize,
    first: i64,
    wr: usize,
) -> Vec<Option<usize>> {
    let mut best: Vec<Option<(usize, f32)>> = vec![None; wr];
    for i in 0..cols {
        let s = &row[i * np..(i + 1) * np];
        for (p, &v) in s.iter().enumerate() {
            let x = (col0 + i) as i64 - first - p as i64;
            // Unseen (NaN) and unscored planes are nobody's best.
            if x < 0 || x >= wr as i64 || v.is_nan() || v == f32::NEG_INFINITY {
                continue;
            }
            let b = &mut best[x as usize];
            if b.is_none_or(|b| v > b.1) {
                *b = Some((p, v));
            }
        }
    }
    best.into_iter().map(|b| b.map(|b| b.0)).collect()
}

/// One row's matches: its pixel row, (column, disparity, correlation, σ) of each match, and
/// what happened to the rest.
type RowMatches = (usize, Vec<(usize, f32, f32, f32)>, PairStats);

/// Matches a rectified pair.
pub fn match_pair(
    left: &ImageF32,
    right: &ImageF32,
    p: &PairParams,
    max_memory_mb: u64,
    progress: &dyn super::progress::Progress,
) -> Result<DisparityMap, PairError> {
    check(left, right, p)?;
    let need = bytes_needed(left.width, left.height, right.width, p);
    if need > max_memory_mb as f64 * 1048576.0 {
        return Err(PairError::Memory {
            need_mb: need / 1048576.0,
            limit_mb: max_memory_mb,
        });
    }
    let t0 = std::time::Instant::now();
    let (w, h) = (left.width, left.height);
    let k = p.window / 2;
    let np = (p.d_max - p.d_min + 1) as usize;
    let first = p.d_min;
    let planes = Planes::Shifts { first, count: np };
    let (lp, rp) = (Prepared::new(left), Prepared::new(right));
    let cols = w - 2 * k;
    let rows: Vec<usize> = (k..h - k).collect();
    let bands: Vec<&[usize]> = rows.chunks(BAND).collect();
    progress.begin("score (rows)", rows.len() as u64);
    let band_scores: Vec<Scores> = bands
        .par_iter()
        .map(|b| {
            let cells = Cells {
                col0: k,
                stride: 1,
                cols,
                rows: b.to_vec(),
            };
            let s = score(&lp, &rp, &planes, k, &cells);
            progress.advance(b.len() as u64);
            s
        })
        .collect();
    progress.end();
    let seconds_score = t0.elapsed().as_secs_f64();
    // The "higher is better" volume the winners are taken from: the scores, or −S.
    let chosen: Vec<Vec<f32>> = match p.filter {
        Filter::Sgm => {
            let mut all = Scores {
                planes: np,
                cols,
                rows: rows.len(),
                v: Vec::with_capacity(cols * rows.len() * np),
            };
            for b in &band_scores {
                all.v.extend_from_slice(&b.v);
            }
            let s = aggregate(&all, &p.sgm);
            let mut out: Vec<Vec<f32>> = Vec::with_capacity(band_scores.len());
            let mut o = 0;
            for b in &band_scores {
                let n = b.v.len();
                let mut v: Vec<f32> = s[o..o + n].iter().map(|&x| -(x as f32)).collect();
                // Unseen and unscored stay what they were.
                for (x, raw) in v.iter_mut().zip(&b.v) {
                    if raw.is_nan() {
                        *x = f32::NAN;
                    }
                }
                for i in 0..n / np {
                    let raw = &b.v[i * np..(i + 1) * np];
                    if raw.iter().all(|x| *x == f32::NEG_INFINITY) {
                        v[i * np..(i + 1) * np]
                            .iter_mut()
                            .for_each(|x| *x = f32::NEG_INFINITY);
                    }
                }
                out.push(v);
                o += n;
            }
            out
        }
        _ => band_scores.iter().map(|b| b.v.clone()).collect(),
    };
    let mut stats = PairStats {
        width: w,
        height: h,
        disparities: np,
        candidates: (cols * rows.len() * np) as u64,
        pixels: cols * rows.len(),
        ..Default::default()
    };
    let mut d = vec![f32::NAN; w * h];
    let mut corr = vec![f32::NAN; w * h];
    let mut sigma = vec![f32::NAN; w * h];
    // Winners, thresholds, the left-right check, the sub-pixel step; rows in parallel.
    progress.begin("sub-pixel (rows)", rows.len() as u64);
    let per_row: Vec<RowMatches> = rows
        .par_iter()
        .enumerate()
        .map(|(j, &r)| {
            let (b, jb) = (j / BAND, j % BAND);
            let row = &chosen[b][jb * cols * np..(jb + 1) * cols * np];
            let raw = &band_scores[b].v[jb * cols * np..(jb + 1) * cols * np];
            let wins = row_winners(row, cols, np);
            let rb = p
                .lr_tolerance
                .map(|_| right_best(row, cols, np, k, first, right.width));
            let mut st = PairStats::default();
            let mut got = Vec::new();
            for (i, win) in wins.iter().enumerate() {
                let c = k + i;
                let cell = &raw[i * np..(i + 1) * np];
                let Some(win) = win else {
                    if cell.iter().any(|v| v.is_nan()) {
                        st.unseen += 1;
                    } else {
                        st.unscored += 1;
                    }
                    continue;
                };
                let rho = cell[win.plane];
                if (rho as f64) < p.threshold {
                    st.below_threshold += 1;
                    continue;
                }
                if let (Some(tol), Some(rb)) = (p.lr_tolerance, &rb) {
                    let x = c as i64 - first - win.plane as i64;
                    let ok = (0..right.width as i64).contains(&x)
                        && rb[x as usize]
                            .is_some_and(|q| (q as f64 - win.plane as f64).abs() <= tol);
                    if !ok {
                        st.left_right += 1;
                        continue;
                    }
                }
                // The parabola on the raw correlations (around the chosen plane).
                let raw_win = Winner {
                    plane: win.plane,
                    score: rho,
                    below: win
                        .plane
                        .checked_sub(1)
                        .map(|q| cell[q])
                        .filter(|v| v.is_finite()),
                    above: cell.get(win.plane + 1).copied().filter(|v| v.is_finite()),
                };
                let (off, den) = raw_win.parabola().unwrap_or((0.0, f64::NAN));
                let mut t = win.plane as f64 + off;
                let n = (p.window * p.window) as f64;
                let mut sd =
                    (den < 0.0).then(|| ((1.0 - (rho as f64).min(0.999)) / (n * -den)).sqrt());
                if p.subpixel == Subpixel::Lsm {
                    let (x, y) = (c as f64 + 0.5, r as f64 + 0.5);
                    let locate = |u: f64, v: f64, t: f64| planes.locate(x + u, y + v, t);
                    match refine(left, Window { c, r, k }, right, &locate, t, 1.0) {
                        Ok(f) => {
                            t = f.t;
                            sd = Some(f.sigma_t);
                            st.lsm_refined += 1;
                        }
                        Err(e) => *st.lsm_failures.entry(failure_name(e)).or_default() += 1,
                    }
                }
                got.push((
                    c,
                    (first as f64 + t) as f32,
                    rho,
                    sd.map_or(f32::NAN, |v| v as f32),
                ));
            }
            progress.advance(1);
            (r, got, st)
        })
        .collect();
    progress.end();
    for (r, got, st) in per_row {
        for (c, dv, rho, sd) in got {
            d[r * w + c] = dv;
            corr[r * w + c] = rho;
            sigma[r * w + c] = sd;
        }
        stats.unseen += st.unseen;
        stats.unscored += st.unscored;
        stats.below_threshold += st.below_threshold;
        stats.left_right += st.left_right;
        stats.lsm_refined += st.lsm_refined;
        for (k, v) in st.lsm_failures {
            *stats.lsm_failures.entry(k).or_default() += v;
        }
    }
    if p.filter == Filter::Regions {
        let mut hm = HeightMap {
            cols: w,
            rows: h,
            col0: 0,
            row0: 0,
            stride: 1,
            h: d,
            corr: corr.clone(),
            sigma: sigma.clone(),
            candidates: 0,
        };
        let before = hm.matched();
        remove_wrong_heights(&mut hm, &p.regions);
        stats.regions = before - hm.matched();
        d = hm.h;
        for ((dv, c), s) in d.iter().zip(corr.iter_mut()).zip(sigma.iter_mut()) {
            if dv.is_nan() {
                *c = f32::NAN;
                *s = f32::NAN;
            }
        }
    }
    stats.matched = d.iter().filter(|v| v.is_finite()).count();
    stats.seconds_score = seconds_score;
    stats.seconds_total = t0.elapsed().as_secs_f64();
    Ok(DisparityMap {
        width: w,
        height: h,
        d,
        corr,
        sigma,
        stats,
    })
}

fn failure_name(e: RefineFailure) -> String {
    format!("{e:?}").to_lowercase()
}
