//! A regular elevation model from the matched points (seed 000 §3.6): each point goes to the
//! grid node it falls nearest to, several points on one node are averaged (after the slope of
//! the plane through them is taken out), nodes no point reached are nodata. And the comparison with a reference model in the figures of seed 000
//! Table 5: largest positive and negative difference, mean, mean absolute, RMSE.

use crate::coords::GroundM;
use crate::matching::point::MatchedPoint;
use serde::{Deserialize, Serialize};

/// Heights on a north-up grid: node (c, r) at (x0 + c·cell, y0 − r·cell).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ElevationGrid {
    /// Ground coordinates of node (0, 0), the north-west one, m.
    pub x0: f64,
    pub y0: f64,
    pub cell_m: f64,
    pub cols: usize,
    pub rows: usize,
    /// Row-major from the north-west; NaN = nodata.
    #[serde(skip)]
    pub z: Vec<f32>,
}

/// How well each node's height is known, on the grid's nodes (NaN where it has none).
#[derive(Debug, Clone, PartialEq)]
pub struct NodeQuality {
    /// Root mean square of the standard deviations of the node's points, m: not divided by
    /// their number, for neighbouring matches share most of their windows and their errors.
    pub sigma_m: Vec<f32>,
    /// Mean correlation of the node's points.
    pub corr: Vec<f32>,
}

/// Seed 000 Table 5.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Comparison {
    pub nodes: usize,
    pub max_positive_m: f64,
    pub max_negative_m: f64,
    pub mean_m: f64,
    pub mean_abs_m: f64,
    pub rmse_m: f64,
    /// RMSE once the least-squares plane of the differences is taken out: what is left when
    /// the model's shift and tilt (an orientation's error, common to every node) are not
    /// counted. Near `rmse_m` when the errors are the matching's; well below it when a tilt
    /// dominates.
    pub rmse_without_plane_m: f64,
}

impl Comparison {
    /// One line for a person: RMSE, mean, the extremes and the nodes.
    pub fn summary(&self) -> String {
        if self.nodes == 0 {
            return "no node to compare (the model has no height where the reference has one)"
                .into();
        }
        format!(
            "RMSE {:.2} m ({:.2} m with the best plane removed), mean {:+.2} m, max +{:.2} / {:.2} m over {} nodes",
            self.rmse_m,
            self.rmse_without_plane_m,
            self.mean_m,
            self.max_positive_m,
            self.max_negative_m,
            self.nodes
        )
    }
}

/// A grid that cannot be made.
#[derive(Debug, thiserror::Error)]
pub enum GridError {
    #[error("the points' extent {extent:?} or the cell {cell_m} m is not a number")]
    NotFinite { extent: [f64; 4], cell_m: f64 },
    #[error("a grid of {cols:.0} × {rows:.0} nodes of {cell_m} m would take {mib:.0} MiB; the limit is {limit_mib} MiB: use a larger [grid] cell_m, or raise [limits] max_memory_mb (or --max-memory)")]
    TooLarge {
        cols: f64,
        rows: f64,
        cell_m: f64,
        mib: f64,
        limit_mib: u64,
    },
}

/// Bytes a grid node takes while it and its products are made: the heights, the sums and
/// counts of `fill` (12) and of `quality` (24), its σ and correlation (8), the pairs' variance
/// factor (one comparison per pair of pairs, 8 each for up to 3), the orthophoto and the
/// differences from a reference (8).
pub const BYTES_PER_NODE: f64 = 4.0 + 12.0 + 24.0 + 8.0 + 24.0 + 8.0;

/// Removes (sets NaN) every node of a row-major grid further than `limit` from the median of
/// its finite neighbours among the 8 (when it has at least 3); the number removed. All nodes
/// are judged against the grid as it was, so a blunder does not shield its neighbour.
pub fn remove_blunders(z: &mut [f64], cols: usize, rows: usize, limit: f64) -> usize {
    let mut out = Vec::new();
    for j in 0..rows {
        for i in 0..cols {
            let v = z[j * cols + i];
            if !v.is_finite() {
                continue;
            }
            let mut n = Vec::with_capacity(8);
            for b in j.saturating_sub(1)..(j + 2).min(rows) {
                for a in i.saturating_sub(1)..(i + 2).min(cols) {
                    let w = z[b * cols + a];
                    if (a, b) != (i, j) && w.is_finite() {
                        n.push(w);
                    }
                }
            }
            if n.len() < 3 {
                continue;
            }
            let mid = n.len() / 2;
            let med = *n.select_nth_unstable_by(mid, f64::total_cmp).1;
            if (v - med).abs() > limit {
                out.push(j * cols + i);
            }
        }
    }
    for &k in &out {
        z[k] = f64::NAN;
    }
    out.len()
}

/// Fills a row-major grid's NaN nodes from their filled neighbours, ring by ring inward (the mean of
/// the filled ones among the 8); the number filled, or `None` when no node has a height.
pub fn fill_holes(z: &mut [f64], cols: usize, rows: usize) -> Option<usize> {
    let holes = z.iter().filter(|v| !v.is_finite()).count();
    if holes == z.len() {
        return None;
    }
    loop {
        let before: Vec<f64> = z.to_vec();
        let mut changed = false;
        for r in 0..rows {
            for c in 0..cols {
                if before[r * cols + c].is_finite() {
                    continue;
                }
                let (mut s, mut n) = (0.0, 0);
                for dr in -1i64..=1 {
                    for dc in -1i64..=1 {
                        let (rr, cc) = (r as i64 + dr, c as i64 + dc);
                        if rr < 0 || cc < 0 || rr >= rows as i64 || cc >= cols as i64 {
                            continue;
                        }
                        let v = before[rr as usize * cols + cc as usize];
                        if v.is_finite() {
                            s += v;
                            n += 1;
                        }
                    }
                }
                if n > 0 {
                    z[r * cols + c] = s / n as f64;
                    changed = true;
                }
            }
        }
        if !changed {
            return Some(holes);
        }
    }
}

impl ElevationGrid {
    /// An empty grid covering `[x_min, y_min, x_max, y_max]` with nodes on multiples of
    /// `cell_m`, refused (before anything is allocated) if it would take more than
    /// `limit_mib`.
    pub fn covering(
        extent: [f64; 4],
        cell_m: f64,
        limit_mib: u64,
    ) -> Result<ElevationGrid, GridError> {
        if !(extent.iter().all(|v| v.is_finite()) && cell_m.is_finite() && cell_m > 0.0) {
            return Err(GridError::NotFinite { extent, cell_m });
        }
        let x0 = (extent[0] / cell_m).ceil() * cell_m;
        let y0 = (extent[3] / cell_m).floor() * cell_m;
        let cols = ((extent[2] - x0) / cell_m).floor().max(0.0) + 1.0;
        let rows = ((y0 - extent[1]) / cell_m).floor().max(0.0) + 1.0;
        let mib = cols * rows * BYTES_PER_NODE / (1u64 << 20) as f64;
        if mib.is_nan() || mib > limit_mib as f64 {
            return Err(GridError::TooLarge {
                cols,
                rows,
                cell_m,
                mib,
                limit_mib,
            });
        }
        // Both below 2^40 here (the product is within the limit).
        let (cols, rows) = (cols as usize, rows as usize);
        Ok(ElevationGrid {
            x0,
            y0,
            cell_m,
            cols,
            rows,
            z: vec![f32::NAN; cols * rows],
        })
    }

    /// The index of the node nearest ground (x, y); `None` outside the grid or for NaN.
    pub fn node_index(&self, x: f64, y: f64) -> Option<usize> {
        let c = ((x - self.x0) / self.cell_m).round();
        let r = ((self.y0 - y) / self.cell_m).round();
        // Written so that NaN (a point from a degenerate mapping) falls outside too.
        let inside = c >= 0.0 && r >= 0.0 && c < self.cols as f64 && r < self.rows as f64;
        inside.then(|| r as usize * self.cols + c as usize)
    }

    pub fn node(&self, c: usize, r: usize) -> [f64; 2] {
        [
            self.x0 + c as f64 * self.cell_m,
            self.y0 - r as f64 * self.cell_m,
        ]
    }

    /// The points falling nearest each node, as (x − node x, y − node y, z).
    fn per_node(&self, pts: &[GroundM]) -> Vec<Vec<[f64; 3]>> {
        let mut per: Vec<Vec<[f64; 3]>> = vec![Vec::new(); self.z.len()];
        for p in pts {
            if let Some(i) = self.node_index(p.x, p.y).filter(|_| p.z.is_finite()) {
                let [nx, ny] = self.node(i % self.cols, i / self.cols);
                per[i].push([p.x - nx, p.y - ny, p.z]);
            }
        }
        per
    }

    /// Each node's height from the points falling nearest it: their mean, each point first
    /// moved to the node along the plane fitted to them (seed 000 §3.6 averages the points; on
    /// a slope the mean lands where the points' centroid is, not at the node, so the plane's
    /// slope is taken out first). Fewer than 3 points, or points in a line: the plain mean.
    pub fn fill(&mut self, pts: &[GroundM]) {
        self.z = self.node_heights(pts, false);
    }

    /// Like [`ElevationGrid::fill`] but with the median of the slope-corrected heights: for
    /// heights merged from several pairs, where one pair's blunders must not pull the others'.
    pub fn fill_median(&mut self, pts: &[GroundM]) {
        self.z = self.node_heights(pts, true);
    }

    /// Each node's height from its points ([`node_height`]); the plane's slope from the
    /// node's own points, or, where they do not fix one (a sliver at the edge of the matched
    /// area, points in a line), from the points of the node and its eight neighbours.
    fn node_heights(&self, pts: &[GroundM], median: bool) -> Vec<f32> {
        let per = self.per_node(pts);
        // A full cell's points: the median count over the nodes that have any.
        let mut counts: Vec<usize> = per.iter().map(Vec::len).filter(|&n| n > 0).collect();
        counts.sort_unstable();
        let full = counts.get(counts.len() / 2).copied().unwrap_or(0);
        (0..self.z.len())
            .map(|i| {
                let v = &per[i];
                if v.is_empty() {
                    return f32::NAN;
                }
                let slope = plane_slope(v, self.cell_m).or_else(|| {
                    let (c, r) = ((i % self.cols) as isize, (i / self.cols) as isize);
                    let mut near = Vec::new();
                    for dr in -1..=1isize {
                        for dc in -1..=1isize {
                            let (cc, rr) = (c + dc, r + dr);
                            if cc < 0
                                || rr < 0
                                || cc >= self.cols as isize
                                || rr >= self.rows as isize
                            {
                                continue;
                            }
                            let (ox, oy) = (dc as f64 * self.cell_m, -dr as f64 * self.cell_m);
                            near.extend(
                                per[rr as usize * self.cols + cc as usize]
                                    .iter()
                                    .map(|p| [p[0] + ox, p[1] + oy, p[2]]),
                            );
                        }
                    }
                    plane_slope(&near, self.cell_m)
                });
                // Fewer than half a full cell's points, off to one side: the matched area ends
                // inside this cell.
                let partial = 2 * v.len() < full && v.len() >= 3;
                node_height(v, slope, self.cell_m, median, partial)
            })
            .collect()
    }

    /// The standard deviation and correlation of each node that has a height, from the points
    /// that fall nearest it (those [`ElevationGrid::fill`] and `fill_median` used).
    pub fn quality(&self, pts: &[MatchedPoint]) -> NodeQuality {
        self.quality_scaled(pts, 1.0)
    }

    /// [`ElevationGrid::quality`] with every standard deviation multiplied by `scale` (the
    /// variance factor of [`crate::matching::accuracy::precision`]).
    pub fn quality_scaled(&self, pts: &[MatchedPoint], scale: f64) -> NodeQuality {
        let n = self.z.len();
        let (mut ss, mut ns) = (vec![0.0f64; n], vec![0u32; n]);
        let (mut sc, mut nc) = (vec![0.0f64; n], vec![0u32; n]);
        for p in pts {
            let g = p.ground;
            let Some(i) = self.node_index(g.x, g.y).filter(|_| g.z.is_finite()) else {
                continue;
            };
            if p.sigma_m.is_finite() {
                ss[i] += (p.sigma_m as f64).powi(2);
                ns[i] += 1;
            }
            if p.corr.is_finite() {
                sc[i] += p.corr as f64;
                nc[i] += 1;
            }
        }
        let at = |i: usize, sum: f64, k: u32, f: fn(f64) -> f64| {
            if self.z[i].is_finite() && k > 0 {
                f(sum / k as f64) as f32
            } else {
                f32::NAN
            }
        };
        NodeQuality {
            sigma_m: (0..n)
                .map(|i| at(i, ss[i], ns[i], f64::sqrt) * scale as f32)
                .collect(),
            corr: (0..n).map(|i| at(i, sc[i], nc[i], |v| v)).collect(),
        }
    }

    /// Each node's height from scattered points (a sparse matcher's, a few cells apart): a
    /// plane fitted by least squares to the points within `radius_m`, each weighted by
    /// (1 − (d/R)²)², its value at the node; at least 3 points not in a line, else no height.
    /// The node's σ propagates the points' own and the plane's misfit s (what the terrain
    /// does between the points): a = Σ ℓᵢ zᵢ, σ² = Σ ℓᵢ² (σᵢ² + s²). The correlation is the
    /// weighted mean of the points'.
    pub fn fill_scattered(&mut self, pts: &[MatchedPoint], radius_m: f64) -> NodeQuality {
        let n = self.z.len();
        let mut q = NodeQuality {
            sigma_m: vec![f32::NAN; n],
            corr: vec![f32::NAN; n],
        };
        let r = radius_m.max(self.cell_m);
        // Buckets of side r over the grid's extent.
        let (bx0, by0) = (self.x0 - r, self.y0 + r);
        let bc = ((self.cols as f64 * self.cell_m + 2.0 * r) / r).ceil() as usize + 1;
        let br = ((self.rows as f64 * self.cell_m + 2.0 * r) / r).ceil() as usize + 1;
        let mut buckets: Vec<Vec<usize>> = vec![Vec::new(); bc * br];
        let bucket = |x: f64, y: f64| -> Option<(usize, usize)> {
            let (u, v) = ((x - bx0) / r, (by0 - y) / r);
            (u >= 0.0 && v >= 0.0 && u < bc as f64 && v < br as f64)
                .then_some((u as usize, v as usize))
        };
        for (i, p) in pts.iter().enumerate() {
            if !p.ground.z.is_finite() {
                continue;
            }
            if let Some((u, v)) = bucket(p.ground.x, p.ground.y) {
                buckets[v * bc + u].push(i);
            }
        }
        for row in 0..self.rows {
            for col in 0..self.cols {
                let [x, y] = self.node(col, row);
                let Some((u, v)) = bucket(x, y) else { continue };
                let mut near = Vec::new();
                for vv in v.saturating_sub(1)..(v + 2).min(br) {
                    for uu in u.saturating_sub(1)..(u + 2).min(bc) {
                        for &i in &buckets[vv * bc + uu] {
                            let g = pts[i].ground;
                            let d2 = (g.x - x).powi(2) + (g.y - y).powi(2);
                            if d2 < r * r {
                                near.push((i, (1.0 - d2 / (r * r)).powi(2)));
                            }
                        }
                    }
                }
                if near.len() < 3 {
                    continue;
                }
                // Points around the node, not all off to one side of it: no extrapolation
                // beyond the points' edge.
                let (mut cx, mut cy, mut sw) = (0.0, 0.0, 0.0);
                for &(i, w) in &near {
                    cx += w * (pts[i].ground.x - x);
                    cy += w * (pts[i].ground.y - y);
                    sw += w;
                }
                if (cx / sw).hypot(cy / sw) > 0.35 * r {
                    continue;
                }
                // Weighted normal equations of z = a + b·dx + c·dy (dx, dy in units of r).
                let mut nm = nalgebra::Matrix3::<f64>::zeros();
                for &(i, w) in &near {
                    let g = pts[i].ground;
                    let a = nalgebra::Vector3::new(1.0, (g.x - x) / r, (g.y - y) / r);
                    nm += w * a * a.transpose();
                }
                let Some(inv) = nm.try_inverse().filter(|m| m.iter().all(|v| v.is_finite())) else {
                    continue;
                };
                if nm.determinant().abs() < 1e-9 * nm[(0, 0)].powi(3) {
                    continue;
                }
                // ℓᵢ = wᵢ·(N⁻¹·aᵢ)₀.
                let mut z = 0.0;
                let mut ell = Vec::with_capacity(near.len());
                for &(i, w) in &near {
                    let g = pts[i].ground;
                    let a = nalgebra::Vector3::new(1.0, (g.x - x) / r, (g.y - y) / r);
                    let l = w * (inv * a)[0];
                    z += l * g.z;
                    ell.push(l);
                }
                let sol = {
                    let mut b = nalgebra::Vector3::<f64>::zeros();
                    for &(i, w) in &near {
                        let g = pts[i].ground;
                        let a = nalgebra::Vector3::new(1.0, (g.x - x) / r, (g.y - y) / r);
                        b += w * a * g.z;
                    }
                    inv * b
                };
                let (mut vv, mut sw) = (0.0, 0.0);
                for &(i, w) in &near {
                    let g = pts[i].ground;
                    let fit = sol[0] + sol[1] * (g.x - x) / r + sol[2] * (g.y - y) / r;
                    vv += w * (g.z - fit).powi(2);
                    sw += w;
                }
                let dof = near.len() as f64 - 3.0;
                let s2 = if dof > 0.0 {
                    vv / sw * near.len() as f64 / dof
                } else {
                    0.0
                };
                // The misfit holds the points' own noise too: only what exceeds it is the
                // terrain's.
                let (mut ws2, mut wsum) = (0.0, 0.0);
                for &(i, w) in &near {
                    let si = pts[i].sigma_m as f64;
                    if si.is_finite() {
                        ws2 += w * si * si;
                        wsum += w;
                    }
                }
                let s2 = if wsum > 0.0 {
                    (s2 - ws2 / wsum).max(0.0)
                } else {
                    s2
                };
                let (mut var, mut corr, mut wc) = (0.0, 0.0, 0.0);
                for (&(i, w), l) in near.iter().zip(&ell) {
                    let s = pts[i].sigma_m as f64;
                    var += l * l * (if s.is_finite() { s * s } else { 0.0 } + s2);
                    if pts[i].corr.is_finite() {
                        corr += w * pts[i].corr as f64;
                        wc += w;
                    }
                }
                let k = row * self.cols + col;
                self.z[k] = z as f32;
                q.sigma_m[k] = var.sqrt() as f32;
                q.corr[k] = if wc > 0.0 {
                    (corr / wc) as f32
                } else {
                    f32::NAN
                };
            }
        }
        q
    }

    /// Bilinear height at ground (x, y); NaN outside, next to nodata, or on a grid of fewer
    /// than 2 × 2 nodes (nothing to interpolate between).
    pub fn interpolate(&self, x: f64, y: f64) -> f64 {
        if self.cols < 2 || self.rows < 2 || self.z.len() < self.cols * self.rows {
            return f64::NAN;
        }
        let fc = (x - self.x0) / self.cell_m;
        let fr = (self.y0 - y) / self.cell_m;
        let inside =
            fc >= 0.0 && fr >= 0.0 && fc <= (self.cols - 1) as f64 && fr <= (self.rows - 1) as f64;
        if !inside {
            return f64::NAN;
        }
        let (c, r) = (
            (fc.floor() as usize).min(self.cols.saturating_sub(2)),
            (fr.floor() as usize).min(self.rows.saturating_sub(2)),
        );
        let (tx, ty) = (fc - c as f64, fr - r as f64);
        let z = |c: usize, r: usize| self.z[r * self.cols + c] as f64;
        let a = z(c, r) + tx * (z(c + 1, r) - z(c, r));
        let b = z(c, r + 1) + tx * (z(c + 1, r + 1) - z(c, r + 1));
        a + ty * (b - a)
    }

    pub fn filled(&self) -> usize {
        self.z.iter().filter(|v| v.is_finite()).count()
    }

    /// This grid minus the reference at every node that has a height.
    pub fn differences(&self, reference: impl Fn(f64, f64) -> f64) -> Vec<f32> {
        (0..self.z.len())
            .map(|i| {
                let [x, y] = self.node(i % self.cols, i / self.cols);
                self.z[i] - reference(x, y) as f32
            })
            .collect()
    }

    pub fn compare(&self, reference: impl Fn(f64, f64) -> f64) -> Comparison {
        let nodes: Vec<[f64; 3]> = self
            .differences(reference)
            .into_iter()
            .enumerate()
            .filter(|(_, v)| v.is_finite())
            .map(|(i, v)| {
                let [x, y] = self.node(i % self.cols, i / self.cols);
                [x, y, v as f64]
            })
            .collect();
        let d: Vec<f64> = nodes.iter().map(|p| p[2]).collect();
        let n = d.len().max(1) as f64;
        let mean = d.iter().sum::<f64>() / n;
        // The plane through the differences: z − mean = a·(x − x̄) + b·(y − ȳ).
        let rmse_without_plane_m = {
            let (mx, my) = nodes
                .iter()
                .fold((0.0, 0.0), |a, p| (a.0 + p[0] / n, a.1 + p[1] / n));
            let centred: Vec<[f64; 3]> = nodes
                .iter()
                .map(|p| [p[0] - mx, p[1] - my, p[2] - mean])
                .collect();
            let slope = plane_slope(&centred, self.cell_m).unwrap_or([0.0, 0.0]);
            (centred
                .iter()
                .map(|p| (p[2] - slope[0] * p[0] - slope[1] * p[1]).powi(2))
                .sum::<f64>()
                / n)
                .sqrt()
        };
        Comparison {
            nodes: d.len(),
            max_positive_m: d.iter().cloned().fold(f64::MIN, f64::max).max(0.0),
            max_negative_m: d.iter().cloned().fold(f64::MAX, f64::min).min(0.0),
            mean_m: mean,
            mean_abs_m: d.iter().map(|v| v.abs()).sum::<f64>() / n,
            rmse_m: (d.iter().map(|v| v * v).sum::<f64>() / n).sqrt(),
            rmse_without_plane_m,
        }
    }
}

/// The slope (∂z/∂x, ∂z/∂y) of the least-squares plane through points given relative to a
/// node; None for fewer than 3 points or points spread along a line (less than a tenth of the
/// cell across it).
fn plane_slope(v: &[[f64; 3]], cell: f64) -> Option<[f64; 2]> {
    if v.len() < 3 {
        return None;
    }
    let n = v.len() as f64;
    let (mx, my, mz) = v
        .iter()
        .fold((0.0, 0.0, 0.0), |a, p| (a.0 + p[0], a.1 + p[1], a.2 + p[2]));
    let (mx, my, mz) = (mx / n, my / n, mz / n);
    let (mut sxx, mut sxy, mut syy, mut sxz, mut syz) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for p in v {
        let (x, y, z) = (p[0] - mx, p[1] - my, p[2] - mz);
        sxx += x * x;
        sxy += x * y;
        syy += y * y;
        sxz += x * z;
        syz += y * z;
    }
    let det = sxx * syy - sxy * sxy;
    // The smaller spread (an eigenvalue of the scatter over n) must reach (cell/10)².
    let tr = sxx + syy;
    let small = 0.5 * (tr - ((sxx - syy).powi(2) + 4.0 * sxy * sxy).sqrt()) / n;
    if !(det > 0.0 && small >= (0.1 * cell).powi(2)) {
        return None;
    }
    Some([(syy * sxz - sxy * syz) / det, (sxx * syz - sxy * sxz) / det])
}

/// A node's height from its points (relative to it): mean or median of the heights moved to
/// the node along the plane of slope `slope` (or unmoved without one); NaN without points, and
/// NaN for a `partial` cell (fewer points than a full one) whose centroid lies more than
/// [`OFF_CENTRE`] of a cell from the node: a sliver of points at the far side of a node's cell
/// (where the matched area ends) would put a height at the node that the terrain's curvature
/// between them and the node does not hold; the neighbouring node, whose cell they fill, has
/// them. (A cell that holds few points everywhere, as under coarse pixels, keeps them, and so
/// does one of one or two points.)
fn node_height(
    v: &[[f64; 3]],
    slope: Option<[f64; 2]>,
    cell: f64,
    median: bool,
    partial: bool,
) -> f32 {
    if v.is_empty() {
        return f32::NAN;
    }
    if partial {
        let n = v.len() as f64;
        let (mx, my) = v.iter().fold((0.0, 0.0), |a, p| (a.0 + p[0], a.1 + p[1]));
        if (mx / n).hypot(my / n) > OFF_CENTRE * cell {
            return f32::NAN;
        }
    }
    let [gx, gy] = slope.unwrap_or([0.0, 0.0]);
    let mut z: Vec<f64> = v.iter().map(|p| p[2] - gx * p[0] - gy * p[1]).collect();
    if !median {
        return (z.iter().sum::<f64>() / z.len() as f64) as f32;
    }
    z.sort_by(f64::total_cmp);
    let n = z.len();
    (if n % 2 == 1 {
        z[n / 2]
    } else {
        0.5 * (z[n / 2 - 1] + z[n / 2])
    }) as f32
}

/// How far (in cells) the points' centroid may lie from their node.
const OFF_CENTRE: f64 = 0.35;

#[cfg(test)]
mod tests {
    use super::*;

    /// A model off its reference by a plane (a tilt of 1 m per km and a shift) plus a ripple
    /// of RMS 0.5 m: the RMSE holds both, the RMSE with the best plane removed the ripple
    /// alone (its closed form, 0.5 m, to the ripple's own small plane).
    #[test]
    fn the_best_plane_removed_leaves_the_errors_that_are_not_a_tilt() {
        let mut g = ElevationGrid::covering([0.0, 0.0, 2000.0, 2000.0], 20.0, 64).unwrap();
        // sin·cos has an RMS of ½.
        let ripple = |x: f64, y: f64| (x / 37.0).sin() * (y / 53.0).cos();
        for i in 0..g.z.len() {
            let [x, y] = g.node(i % g.cols, i / g.cols);
            g.z[i] = (0.3 + 0.001 * x - 0.0005 * y + ripple(x, y)) as f32;
        }
        let c = g.compare(|_, _| 0.0);
        assert!(
            (c.rmse_without_plane_m - 0.5).abs() < 0.03,
            "{}",
            c.summary()
        );
        assert!(c.rmse_m > 1.0, "{}", c.summary());
    }

    /// Holes are filled from their neighbours, a ring at a time; a grid with no height at
    /// all is refused.
    #[test]
    fn holes_fill_from_the_neighbours() {
        let n = f64::NAN;
        let mut z = vec![1.0, n, n, 1.0, n, n, 1.0, 1.0, n];
        assert_eq!(fill_holes(&mut z, 3, 3), Some(5));
        assert!(z.iter().all(|v| (v - 1.0).abs() < 1e-12), "{z:?}");
        // A ramp's hole in the middle takes its eight neighbours' mean.
        let mut r = vec![0.0, 1.0, 2.0, 0.0, n, 2.0, 0.0, 1.0, 2.0];
        assert_eq!(fill_holes(&mut r, 3, 3), Some(1));
        assert!((r[4] - 1.0).abs() < 1e-12);
        let mut none = vec![n; 4];
        assert_eq!(fill_holes(&mut none, 2, 2), None);
    }

    /// A spike on a plane is removed and nothing else; nodes with fewer than 3 neighbours
    /// are not judged.
    #[test]
    fn a_spike_is_a_blunder() {
        let (cols, rows) = (5, 4);
        let mut z: Vec<f64> = (0..cols * rows)
            .map(|k| 100.0 + 0.5 * (k % cols) as f64 - 0.3 * (k / cols) as f64)
            .collect();
        z[2 * cols + 2] += 9.0;
        let plane = z.clone();
        assert_eq!(remove_blunders(&mut z, cols, rows, 2.0), 1);
        for k in 0..z.len() {
            if k == 2 * cols + 2 {
                assert!(z[k].is_nan());
            } else {
                assert_eq!(z[k], plane[k]);
            }
        }
        let mut pair = vec![0.0, 50.0];
        assert_eq!(remove_blunders(&mut pair, 2, 1, 1.0), 0);
    }

    /// Points on the plane z = 100 + 0.2·x − 0.1·y with σ 0.5 m, on a 3 m lattice: every
    /// node inside gets the plane's height exactly, and a σ below the points' (several
    /// averaged) but above σ/√n; nodes far from every point get none.
    #[test]
    fn scattered_points_on_a_plane_give_the_plane_and_propagated_sigmas() {
        let mut g = ElevationGrid::covering([0.0, 0.0, 60.0, 60.0], 5.0, 64).unwrap();
        let plane = |x: f64, y: f64| 100.0 + 0.2 * x - 0.1 * y;
        let mut pts = Vec::new();
        for j in 0..14 {
            for i in 0..14 {
                let (x, y) = (1.0 + 3.0 * i as f64, 1.0 + 3.0 * j as f64);
                pts.push(MatchedPoint {
                    ground: GroundM::new(x, y, plane(x, y)),
                    corr: 0.9,
                    sigma_m: 0.5,
                });
            }
        }
        let q = g.fill_scattered(&pts, 7.0);
        let [x, y] = g.node(4, 4);
        let k = g.node_index(x, y).unwrap();
        assert!(
            (g.z[k] as f64 - plane(x, y)).abs() < 1e-4,
            "{} at ({x}, {y})",
            g.z[k]
        );
        let s = q.sigma_m[k] as f64;
        assert!(s < 0.5 && s > 0.5 / (pts.len() as f64).sqrt(), "{s}");
        assert!((q.corr[k] - 0.9).abs() < 1e-6);
        // (60, 0) lies 18 m from the nearest point: nothing.
        let far = g.node_index(60.0, 0.0).unwrap();
        assert!(g.z[far].is_nan() && q.sigma_m[far].is_nan());
    }

    #[test]
    fn degenerate_grids_and_points_are_refused_or_skipped_never_a_panic() {
        // One node: nothing to interpolate between.
        let one = ElevationGrid {
            x0: 0.0,
            y0: 0.0,
            cell_m: 1.0,
            cols: 1,
            rows: 1,
            z: vec![5.0],
        };
        assert!(one.interpolate(0.0, 0.0).is_nan());
        // Points that are not numbers fall outside.
        let mut g = ElevationGrid::covering([0.0, 0.0, 10.0, 10.0], 5.0, 64).unwrap();
        g.fill(&[
            GroundM::new(f64::NAN, 5.0, 1.0),
            GroundM::new(5.0, f64::NAN, 1.0),
            GroundM::new(5.0, 5.0, f64::NAN),
            GroundM::new(5.0, 5.0, 7.0),
        ]);
        assert_eq!(g.filled(), 1);
        assert_eq!(g.z[4], 7.0);
        // 1 µm cells over 100 m: 1e16 nodes, refused before allocation; NaN extents too.
        assert!(matches!(
            ElevationGrid::covering([0.0, 0.0, 100.0, 100.0], 1e-6, 4096),
            Err(GridError::TooLarge { .. })
        ));
        assert!(matches!(
            ElevationGrid::covering([0.0, f64::NAN, 100.0, 100.0], 1.0, 4096),
            Err(GridError::NotFinite { .. })
        ));
        // At the limit, exactly: 1024 × 1024 nodes of 80 bytes is 80 MiB.
        assert_eq!(BYTES_PER_NODE, 80.0);
        assert!(ElevationGrid::covering([0.0, 0.0, 1023.0, 1023.0], 1.0, 80).is_ok());
        assert!(ElevationGrid::covering([0.0, 0.0, 1024.0, 1023.0], 1.0, 80).is_err());
    }

    /// Points on a steep plane, all on one side of their node: the mean would be the height
    /// at their centroid, the slope-corrected mean (and median) is the plane's height at the
    /// node, exactly.
    #[test]
    fn a_slope_is_taken_out_before_the_points_are_averaged() {
        let mut g = ElevationGrid::covering([0.0, 0.0, 20.0, 20.0], 10.0, 64).unwrap();
        let plane = |x: f64, y: f64| 300.0 + 0.8 * x - 0.5 * y;
        // Node (1, 1) is at (10, 10); points in its cell's north-east quarter only.
        let pts: Vec<GroundM> = (0..20)
            .map(|k| {
                let (x, y) = (10.5 + (k % 5) as f64, 10.5 + (k / 5) as f64);
                GroundM::new(x, y, plane(x, y))
            })
            .collect();
        g.fill(&pts);
        let z = g.z[g.cols + 1] as f64;
        assert!(
            (z - plane(10.0, 10.0)).abs() < 1e-3,
            "{z} vs {}",
            plane(10.0, 10.0)
        );
        g.fill_median(&pts);
        assert!((g.z[g.cols + 1] as f64 - plane(10.0, 10.0)).abs() < 1e-3);
        // Points in a line: no plane, the plain mean.
        let line: Vec<GroundM> = (0..5)
            .map(|k| GroundM::new(10.5 + k as f64, 10.5, 7.0 + k as f64))
            .collect();
        g.fill(&line);
        assert_eq!(g.z[g.cols + 1], 9.0);
    }

    /// Where the matched area ends inside a cell, its few points along the far edge are no
    /// height for the node (they sat 6–16 m off on the validation scenes' edges); a grid whose
    /// cells all hold as few keeps them.
    #[test]
    fn a_sliver_at_the_far_side_of_a_cell_gives_no_height() {
        let hill = |x: f64, y: f64| 100.0 + 0.002 * ((x - 40.0).powi(2) + (y - 40.0).powi(2));
        let mut g = ElevationGrid::covering([0.0, 0.0, 80.0, 80.0], 20.0, 64).unwrap();
        let mut pts = Vec::new();
        // Full cells of 2 m points, except node (4, 2) (x 80): only a sliver at x 70–71.
        for j in 0..45 {
            for i in 0..45 {
                let (x, y) = (-9.0 + 2.0 * i as f64, -9.0 + 2.0 * j as f64);
                if x >= 70.0 && !(40.0..60.0).contains(&y) {
                    continue;
                }
                if x >= 72.0 {
                    continue;
                }
                pts.push(GroundM::new(x, y, hill(x, y)));
            }
        }
        g.fill_median(&pts);
        let sliver = g.node_index(80.0, 50.0).unwrap();
        assert!(g.z[sliver].is_nan(), "{}", g.z[sliver]);
        let full = g.node_index(40.0, 40.0).unwrap();
        assert!(
            (g.z[full] as f64 - hill(40.0, 40.0)).abs() < 0.5,
            "{}",
            g.z[full]
        );
        // The same sliver alone in a grid of sparse cells: kept.
        let few: Vec<GroundM> = pts.iter().copied().filter(|p| p.x >= 70.0).collect();
        g.fill_median(&few);
        assert!(g.z[sliver].is_finite());
    }

    #[test]
    fn points_average_on_their_nearest_node_and_compare_in_closed_form() {
        let mut g = ElevationGrid::covering([0.0, 0.0, 10.0, 10.0], 5.0, 64).unwrap();
        assert_eq!((g.cols, g.rows, g.x0, g.y0), (3, 3, 0.0, 10.0));
        g.fill(&[
            GroundM::new(0.4, 9.6, 100.0),
            GroundM::new(-0.5, 10.4, 102.0),
            GroundM::new(5.1, 5.2, 50.0),
        ]);
        assert_eq!(g.z[0], 101.0);
        assert_eq!(g.z[4], 50.0);
        assert_eq!(g.filled(), 2);
        // Reference 100 everywhere: differences +1 and −50.
        let c = g.compare(|_, _| 100.0);
        assert_eq!(c.nodes, 2);
        assert_eq!((c.max_positive_m, c.max_negative_m), (1.0, -50.0));
        assert!((c.mean_m + 24.5).abs() < 1e-12 && (c.mean_abs_m - 25.5).abs() < 1e-12);
        assert!((c.rmse_m - (2501.0f64 / 2.0).sqrt()).abs() < 1e-9);
    }
}
