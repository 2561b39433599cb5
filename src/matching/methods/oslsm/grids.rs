//! The two object-space grids of seed 001's object-space least-squares matching: the terrain
//! heights Z on posts (bilinear between them) and the terrain reflectance D on groundels, a
//! whole number of groundels to a post cell so that every groundel lies in one cell.
//!
//! Axes: X east, Y north; post (i, j) at (x0 + i·post_m, y0 + j·post_m) (j grows northward);
//! groundel (u, v) centred at (x0 + (u + ½)·g, y0 + (v + ½)·g), g = post_m / per_cell.

/// Heights on posts and the groundel layout over them.
#[derive(Debug, Clone, PartialEq)]
pub struct Grids {
    pub x0: f64,
    pub y0: f64,
    pub post_m: f64,
    /// Posts across (X) and along (Y).
    pub cols: usize,
    pub rows: usize,
    /// Height of post (i, j) at `z[j * cols + i]`, m.
    pub z: Vec<f64>,
    /// Groundels per post cell along each axis.
    pub per_cell: usize,
}

/// A groundel's place: its centre, and the four posts (indices) around it with their
/// bilinear weights.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Groundel {
    pub x: f64,
    pub y: f64,
    pub posts: [usize; 4],
    pub weights: [f64; 4],
}

impl Grids {
    /// Groundels across and along.
    pub fn groundels(&self) -> (usize, usize) {
        (
            (self.cols.saturating_sub(1)) * self.per_cell,
            (self.rows.saturating_sub(1)) * self.per_cell,
        )
    }

    /// The groundel size, m.
    pub fn groundel_m(&self) -> f64 {
        self.post_m / self.per_cell as f64
    }

    pub fn groundel(&self, u: usize, v: usize) -> Groundel {
        let m = self.per_cell;
        let (i, j) = (u / m, v / m);
        let fx = ((u % m) as f64 + 0.5) / m as f64;
        let fy = ((v % m) as f64 + 0.5) / m as f64;
        let g = self.groundel_m();
        let p = j * self.cols + i;
        Groundel {
            x: self.x0 + (u as f64 + 0.5) * g,
            y: self.y0 + (v as f64 + 0.5) * g,
            posts: [p, p + 1, p + self.cols, p + self.cols + 1],
            weights: [
                (1.0 - fx) * (1.0 - fy),
                fx * (1.0 - fy),
                (1.0 - fx) * fy,
                fx * fy,
            ],
        }
    }

    /// Height at a groundel.
    pub fn z_at(&self, g: &Groundel) -> f64 {
        g.posts
            .iter()
            .zip(&g.weights)
            .map(|(&p, w)| w * self.z[p])
            .sum()
    }

    /// The steepest the bilinear surface gets anywhere (rise per horizontal metre): in a cell
    /// ∂z/∂x is a blend of its two X edges' differences and ∂z/∂y of its two Y edges', so
    /// the gradient's length is at most the hypotenuse of the larger of each. 0 without cells;
    /// infinite when a height is not finite.
    pub fn max_slope(&self) -> f64 {
        let (c, z) = (self.cols, &self.z);
        let mut worst: f64 = 0.0;
        for j in 0..self.rows.saturating_sub(1) {
            for i in 0..c.saturating_sub(1) {
                let p = j * c + i;
                let dx = (z[p + 1] - z[p]).abs().max((z[p + c + 1] - z[p + c]).abs());
                let dy = (z[p + c] - z[p]).abs().max((z[p + c + 1] - z[p + 1]).abs());
                let s = dx.hypot(dy);
                worst = if s.is_nan() {
                    f64::INFINITY
                } else {
                    worst.max(s)
                };
            }
        }
        worst / self.post_m
    }

    /// Height anywhere inside the posts' hull (bilinear); `None` outside.
    pub fn z_xy(&self, x: f64, y: f64) -> Option<f64> {
        let u = (x - self.x0) / self.post_m;
        let v = (y - self.y0) / self.post_m;
        let (w1, h1) = (self.cols as f64 - 1.0, self.rows as f64 - 1.0);
        if u.is_nan() || v.is_nan() || u < 0.0 || v < 0.0 || u > w1 || v > h1 {
            return None;
        }
        let i = (u as usize).min(self.cols.saturating_sub(2));
        let j = (v as usize).min(self.rows.saturating_sub(2));
        let (fx, fy) = (u - i as f64, v - j as f64);
        let p = j * self.cols + i;
        let z = &self.z;
        Some(
            (1.0 - fy) * ((1.0 - fx) * z[p] + fx * z[p + 1])
                + fy * ((1.0 - fx) * z[p + self.cols] + fx * z[p + self.cols + 1]),
        )
    }
}

/// How far a post stands from the terrain where the terrain bends between posts: a
/// least-squares surface linear between posts h apart, fitted to a curve of second derivative
/// f'', passes off it by the mean of the interpolation error f''·t(h − t)/2 over the span,
/// f''·h²/12, and a post's second differences along X and Y are f''·h² (a crease between
/// posts shows there too): √(Δ²ₓ² + Δ²ᵧ²)/12, m. A post the grey values fix to the hundredth
/// of a pixel still carries this (NaN heights count as flat).
pub fn representation_sigma(z: &[f64], cols: usize, rows: usize) -> Vec<f64> {
    let at = |i: usize, j: usize| z[j * cols + i];
    let second = |a: f64, b: f64, c: f64| {
        let d = a - 2.0 * b + c;
        if d.is_finite() {
            d
        } else {
            0.0
        }
    };
    (0..rows)
        .flat_map(|j| (0..cols).map(move |i| (i, j)))
        .map(|(i, j)| {
            let dx = if i > 0 && i + 1 < cols {
                second(at(i - 1, j), at(i, j), at(i + 1, j))
            } else {
                0.0
            };
            let dy = if j > 0 && j + 1 < rows {
                second(at(i, j - 1), at(i, j), at(i, j + 1))
            } else {
                0.0
            };
            dx.hypot(dy) / 12.0
        })
        .collect()
}

/// How far the least-squares facets' posts lie from the terrain where it curves, m (to be
/// added to the posts). The adjustment fits the surface bilinear between posts h apart to
/// the terrain in the least-squares sense: the L² projection onto linear elements, whose
/// nodes on a curve of second derivative f'' lie f''·h²/12 off it (the interpolant through
/// the curve stands f''·t(h − t)/2 off it, f''·h²/12 on average over a span, and the
/// projection is the interpolant shifted by that mean: Strang and Fix 1973, An Analysis of
/// the Finite Element Method, §1.6; for tensor-product elements per axis). The posts lie
/// below the terrain in a valley and above it on a ridge, by ∇²z·h²/12, the opposite of a
/// window's mean (`crate::matching::accuracy::averaging`). ∇²z is taken from the posts themselves, a
/// quadratic fitted to each post's 3 × 3 neighbourhood ([`crate::matching::accuracy::averaging::laplacian`]
/// at reach 1, the scale of the facets' support). On the independent jacksboro scenes
/// (80 m posts) the errors regressed on ∇²z·h² gave −0.073 and −0.074 (the rule: −1/12).
/// `grid` holds the posts (NaN where none); NaN where no curvature could be fitted.
pub fn facet_bias(grid: &crate::matching::grid::ElevationGrid) -> Vec<f64> {
    let h2 = grid.cell_m * grid.cell_m;
    crate::matching::accuracy::averaging::laplacian(grid, 1)
        .into_iter()
        .map(|l| l * h2 / 12.0)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plane z = 2 + 0.5·x − 0.25·y on the posts is reproduced exactly at every groundel
    /// (bilinear interpolation is exact on planes), and the weights sum to 1.
    #[test]
    fn groundels_interpolate_a_plane_exactly() {
        let (cols, rows, s) = (4, 3, 10.0);
        let plane = |x: f64, y: f64| 2.0 + 0.5 * x - 0.25 * y;
        let z = (0..rows)
            .flat_map(|j| (0..cols).map(move |i| plane(i as f64 * s, j as f64 * s)))
            .collect();
        let g = Grids {
            x0: 0.0,
            y0: 0.0,
            post_m: s,
            cols,
            rows,
            z,
            per_cell: 5,
        };
        assert_eq!(g.groundels(), (15, 10));
        for v in 0..10 {
            for u in 0..15 {
                let gr = g.groundel(u, v);
                assert!((gr.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
                assert!((g.z_at(&gr) - plane(gr.x, gr.y)).abs() < 1e-9);
                assert!((g.z_xy(gr.x, gr.y).unwrap() - plane(gr.x, gr.y)).abs() < 1e-9);
            }
        }
        assert!(g.z_xy(-0.1, 5.0).is_none() && g.z_xy(5.0, 20.1).is_none());
        // A plane has no representation error.
        assert!(representation_sigma(&g.z, cols, rows)
            .iter()
            .all(|s| s.abs() < 1e-12));
    }

    /// Bilinear facets fitted by least squares to a bowl z = ½κ(x² + y²) (the L² projection,
    /// solved here by brute force: the normals of many sample points of the bowl against the
    /// posts' bilinear weights) lie ∇²z·h²/12 = κh²/6 below it at the inner posts, and
    /// `facet_bias` says so from the fitted posts alone.
    #[test]
    fn facets_fitted_to_a_bowl_lie_below_it_by_the_facet_bias() {
        use nalgebra::{DMatrix, DVector};
        let (n, h, kappa) = (7usize, 4.0, 0.05);
        let bowl = |x: f64, y: f64| 0.5 * kappa * (x * x + y * y);
        let g = Grids {
            x0: -12.0,
            y0: -12.0,
            post_m: h,
            cols: n,
            rows: n,
            z: vec![0.0; n * n],
            per_cell: 16,
        };
        let mut a = DMatrix::<f64>::zeros(n * n, n * n);
        let mut b = DVector::<f64>::zeros(n * n);
        let (gu, gv) = g.groundels();
        for v in 0..gv {
            for u in 0..gu {
                let gr = g.groundel(u, v);
                let z = bowl(gr.x, gr.y);
                for (i, wi) in gr.posts.iter().zip(&gr.weights) {
                    b[*i] += wi * z;
                    for (j, wj) in gr.posts.iter().zip(&gr.weights) {
                        a[(*i, *j)] += wi * wj;
                    }
                }
            }
        }
        let z = a.cholesky().unwrap().solve(&b);
        let grid = crate::matching::grid::ElevationGrid {
            x0: g.x0,
            y0: g.y0 + (n - 1) as f64 * h,
            cell_m: h,
            cols: n,
            rows: n,
            z: z.iter().map(|v| *v as f32).collect(),
        };
        let bias = facet_bias(&grid);
        let want = 2.0 * kappa * h * h / 12.0;
        for j in 2..n - 2 {
            for i in 2..n - 2 {
                let k = j * n + i;
                let (x, y) = (g.x0 + i as f64 * h, g.y0 + j as f64 * h);
                let off = bowl(x, y) - z[k];
                // The rule, and the facets' own offset (sampling at 16 groundels a side).
                assert!((off - want).abs() < 0.02 * want, "{off} vs {want}");
                assert!(
                    (bias[k] - want).abs() < 0.02 * want,
                    "{} vs {want}",
                    bias[k]
                );
            }
        }
    }

    /// A parabola z = x² on posts h apart: second differences 2h², so h²/6 at every inner
    /// post, the mean distance between the parabola and its chord over a span (h²/6: the
    /// chord's error t(h − t) averaged over t).
    #[test]
    fn representation_error_of_a_parabola() {
        let h = 3.0;
        let z: Vec<f64> = (0..3)
            .flat_map(|_| (0..5).map(|i| (i as f64 * h).powi(2)))
            .collect();
        let s = representation_sigma(&z, 5, 3);
        // The chord from x = h to 2h minus the parabola, averaged over the span.
        let n = 10_000;
        let mean = (0..n)
            .map(|k| {
                let t = (k as f64 + 0.5) / n as f64 * h;
                let chord = (h * h) + t / h * (4.0 * h * h - h * h);
                chord - (h + t).powi(2)
            })
            .sum::<f64>()
            / n as f64;
        for i in 1..4 {
            assert!((s[5 + i] - mean).abs() < 1e-6, "{} vs {mean}", s[5 + i]);
        }
    }
}
