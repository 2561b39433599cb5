//! Cholesky factorisation of the object-space matching's normal matrix in its own shape: the
//! posts, numbered row by row, couple only with posts within a band (a groundel's four posts
//! lie one grid row apart, a curvature row's three two rows apart), and the few radiometric
//! unknowns after them couple with every post (a bordered band, an "arrowhead"). The factor
//! keeps that shape: L's band rows stay in the band and its border rows are dense, so a patch
//! of n posts with band b and m border unknowns costs n·b² + m·n·b instead of the dense n³/3,
//! and σ needs only the inverse's diagonal, n²·b/2 + m·n² rather than a whole inverse
//! (the fill-in of a band factor stays inside the band: Golub and Van Loan 2013, §4.3).

use nalgebra::{DMatrix, DVector};

/// The lower factor L of A = L·Lᵀ for a bordered band.
#[derive(Debug, Clone)]
pub struct BorderedBand {
    /// Unknowns in the band (the posts), then `m` in the border.
    n: usize,
    m: usize,
    /// Half-bandwidth: A[i][j] = 0 for i, j < n and |i − j| > bw.
    bw: usize,
    /// Band rows: L[i][i − bw + k] at `band[i·(bw + 1) + k]`, k = 0..=bw (i − bw + k ≥ 0).
    band: Vec<f64>,
    /// Border rows: L[n + r][j] at `border[r·(n + m) + j]`, j ≤ n + r.
    border: Vec<f64>,
}

impl BorderedBand {
    /// The half-bandwidth of `a`'s first `n` rows and columns: the largest i − j of a non-zero
    /// there (the lower triangle read down each column, from the bottom, only below the band
    /// found so far).
    pub fn bandwidth(a: &DMatrix<f64>, n: usize) -> usize {
        let n = n.min(a.nrows()).min(a.ncols());
        let mut bw = 0;
        for j in 0..n {
            if let Some(i) = (j + bw + 1..n).rev().find(|&i| a[(i, j)] != 0.0) {
                bw = i - j;
            }
        }
        bw
    }

    /// Factors symmetric `a` (its lower triangle read) whose first `n` unknowns form a band
    /// (its width found, [`Self::bandwidth`]); `None` when `a` is not square or not positive
    /// definite (a pivot ≤ 0 or not finite).
    pub fn factor(a: &DMatrix<f64>, n: usize) -> Option<Self> {
        let size = a.nrows();
        if a.ncols() != size || n > size {
            return None;
        }
        let bw = Self::bandwidth(a, n);
        let m = size - n;
        let w = bw + 1;
        let mut band = vec![0.0; n * w];
        let pivot = |s: f64| (s > 0.0 && s.is_finite()).then(|| s.sqrt());
        for i in 0..n {
            let lo = i.saturating_sub(bw);
            for j in lo..=i {
                // Σ_k L[i][k]·L[j][k] over k < j in both rows' bands.
                let k0 = lo.max(j.saturating_sub(bw));
                let mut s = a[(i, j)];
                for k in k0..j {
                    s -= band[i * w + (k + bw - i)] * band[j * w + (k + bw - j)];
                }
                band[i * w + (j + bw - i)] = if j == i {
                    pivot(s)?
                } else {
                    s / band[j * w + bw]
                };
            }
        }
        let stride = n + m;
        let mut border = vec![0.0; m * stride];
        for r in 0..m {
            // Against the band's columns: each column's L has its rows' band only.
            for j in 0..n {
                let k0 = j.saturating_sub(bw);
                let mut s = a[(n + r, j)];
                for k in k0..j {
                    s -= border[r * stride + k] * band[j * w + (k + bw - j)];
                }
                border[r * stride + j] = s / band[j * w + bw];
            }
            // Against the border's columns, dense.
            for c in 0..=r {
                let mut s = a[(n + r, n + c)];
                for k in 0..n + c {
                    s -= border[r * stride + k] * border[c * stride + k];
                }
                border[r * stride + n + c] = if c == r {
                    pivot(s)?
                } else {
                    s / border[c * stride + n + c]
                };
            }
        }
        Some(BorderedBand {
            n,
            m,
            bw,
            band,
            border,
        })
    }

    /// L[i][j] (j ≤ i), zero outside the shape.
    #[inline]
    fn l(&self, i: usize, j: usize) -> f64 {
        if i < self.n {
            if i - j <= self.bw {
                self.band[i * (self.bw + 1) + (j + self.bw - i)]
            } else {
                0.0
            }
        } else {
            self.border[(i - self.n) * (self.n + self.m) + j]
        }
    }

    /// Where row i of L starts: its first column that can be non-zero.
    #[inline]
    fn first(&self, i: usize) -> usize {
        if i < self.n {
            i.saturating_sub(self.bw)
        } else {
            0
        }
    }

    /// x with A·x = b.
    pub fn solve(&self, b: &DVector<f64>) -> DVector<f64> {
        let size = self.n + self.m;
        let mut y = b.clone();
        for i in 0..size {
            let mut s = y[i];
            for k in self.first(i)..i {
                s -= self.l(i, k) * y[k];
            }
            y[i] = s / self.l(i, i);
        }
        // Lᵀ·x = y, column by column from the last: x[i] is final once the rows below it
        // are done, and then leaves its share in the rows it reaches.
        for i in (0..size).rev() {
            y[i] /= self.l(i, i);
            let xi = y[i];
            for k in self.first(i)..i {
                y[k] -= self.l(i, k) * xi;
            }
        }
        y
    }

    /// The diagonal of A⁻¹: (A⁻¹)ᵢᵢ = ‖L⁻¹·eᵢ‖², L⁻¹·eᵢ by forward substitution from row i
    /// (its earlier entries are zero).
    pub fn inverse_diagonal(&self) -> Vec<f64> {
        use rayon::prelude::*;
        let size = self.n + self.m;
        (0..size)
            .into_par_iter()
            .map_init(
                || vec![0.0; size],
                |z, i| {
                    z[i] = 1.0 / self.l(i, i);
                    let mut ss = z[i] * z[i];
                    for k in i + 1..size {
                        let mut s = 0.0;
                        for (j, zj) in z.iter().enumerate().take(k).skip(self.first(k).max(i)) {
                            s -= self.l(k, j) * zj;
                        }
                        z[k] = s / self.l(k, k);
                        ss += z[k] * z[k];
                    }
                    ss
                },
            )
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bordered band as the matching builds one: a grid's posts row by row, each cell's four
    /// posts coupled (weights of a bilinear groundel), second differences along both axes, a
    /// border of `m` unknowns coupled with every post; positive definite.
    fn normals(cols: usize, rows: usize, m: usize, seed: u64) -> DMatrix<f64> {
        let n = cols * rows;
        let mut a = DMatrix::<f64>::zeros(n + m, n + m);
        let mut s = seed;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let add_row = |a: &mut DMatrix<f64>, row: &[(usize, f64)]| {
            for &(i, x) in row {
                for &(j, y) in row {
                    a[(i, j)] += x * y;
                }
            }
        };
        for r in 0..rows - 1 {
            for c in 0..cols - 1 {
                let p = r * cols + c;
                for _ in 0..3 {
                    let (u, v) = (rnd(), rnd());
                    let g = 2.0 * rnd() - 1.0;
                    let mut row = vec![
                        (p, g * (1.0 - u) * (1.0 - v)),
                        (p + 1, g * u * (1.0 - v)),
                        (p + cols, g * (1.0 - u) * v),
                        (p + cols + 1, g * u * v),
                    ];
                    for k in 0..m {
                        row.push((n + k, rnd() - 0.5));
                    }
                    add_row(&mut a, &row);
                }
            }
        }
        for r in 0..rows {
            for c in 1..cols - 1 {
                let p = r * cols + c;
                add_row(&mut a, &[(p - 1, 0.3), (p, -0.6), (p + 1, 0.3)]);
            }
        }
        for r in 1..rows - 1 {
            for c in 0..cols {
                let p = r * cols + c;
                add_row(&mut a, &[(p - cols, 0.3), (p, -0.6), (p + cols, 0.3)]);
            }
        }
        for i in 0..n + m {
            a[(i, i)] += 1e-3;
        }
        a
    }

    /// The solution and the inverse's diagonal are nalgebra's dense Cholesky's (another
    /// algorithm on the whole matrix) to 1e-9 relative, for square and oblong grids, with and
    /// without a border; the band found is the grid's two rows.
    #[test]
    fn agrees_with_the_dense_factorisation() {
        for (cols, rows, m) in [(7, 6, 4), (12, 5, 0), (5, 11, 6), (2, 2, 1)] {
            let a = normals(cols, rows, m, (cols * 31 + rows) as u64);
            let n = cols * rows;
            let bw = BorderedBand::bandwidth(&a, n);
            assert_eq!(bw, (2 * cols).min(n - 1).max(cols + 1), "{cols}×{rows}");
            let f = BorderedBand::factor(&a, n).unwrap();
            let dense = a.clone().cholesky().unwrap();
            let b = DVector::from_fn(n + m, |i, _| (i as f64 * 0.37).sin());
            let (x, xd) = (f.solve(&b), dense.solve(&b));
            let scale = xd.amax();
            assert!((x - &xd).amax() < 1e-9 * scale, "{cols}×{rows}+{m}: solve");
            let inv = dense.inverse();
            for (i, d) in f.inverse_diagonal().iter().enumerate() {
                assert!(
                    (d - inv[(i, i)]).abs() < 1e-9 * inv[(i, i)].abs(),
                    "{cols}×{rows}+{m}: ({i}, {i}) {d} against {}",
                    inv[(i, i)]
                );
            }
        }
    }

    /// A matrix that is not positive definite is refused rather than factored wrongly; an
    /// entry far outside the posts' usual band widens the band (the factor stays right); no
    /// posts at all (the border alone) and no border are factored too.
    #[test]
    fn refuses_what_it_cannot_factor_and_takes_any_band() {
        let a = normals(6, 6, 3, 5);
        let n = 36;
        let mut b = a.clone();
        b[(20, 20)] = -1.0;
        assert!(BorderedBand::factor(&b, n).is_none());
        let mut c = a.clone();
        c[(38, 38)] = f64::NAN;
        assert!(BorderedBand::factor(&c, n).is_none());
        assert!(BorderedBand::factor(&DMatrix::zeros(3, 4), 3).is_none());
        let mut wide = a.clone();
        // A positive-definite addition ([[0.02, 0.01], [0.01, 0.02]] at posts 0 and 35).
        (wide[(35, 0)], wide[(0, 35)]) = (0.01, 0.01);
        wide[(0, 0)] += 0.02;
        wide[(35, 35)] += 0.02;
        assert_eq!(BorderedBand::bandwidth(&wide, n), 35);
        for (m, k) in [(wide, n), (a.clone(), 0), (a.clone(), 39)] {
            let f = BorderedBand::factor(&m, k).unwrap();
            let dense = m.clone().cholesky().unwrap();
            let rhs = DVector::from_fn(39, |i, _| 1.0 + i as f64);
            assert!((f.solve(&rhs) - dense.solve(&rhs)).amax() < 1e-9, "n = {k}");
            let inv = dense.inverse();
            for (i, d) in f.inverse_diagonal().iter().enumerate() {
                assert!((d - inv[(i, i)]).abs() < 1e-9 * inv[(i, i)], "n = {k}, {i}");
            }
        }
    }
}
