//! The reduced camera system of a bundle adjustment: the normal equations with the object
//! points eliminated (the Schur complement S = U − W·V⁻¹·Wᵀ; Triggs, McLauchlan, Hartley &
//! Fitzgibbon 2000, "Bundle adjustment — a modern synthesis", §6.1), 6 × 6 blocks over the
//! photos' ω, φ, κ, X₀, Y₀, Z₀. A photo is tied only to the photos it shares points with, so S
//! is sparse: a block of 1 000 photos in strips has ~9 blocks a block row. It is factored by
//! `faer`'s sparse Cholesky with its fill-reducing ordering; the symbolic factorisation is kept
//! while the pattern (which photos share points) stays the same.

use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Mat, Side};
use nalgebra::{DMatrix, DVector, Matrix6};
use std::collections::HashMap;

/// S as its lower blocks (row photo ≥ column photo).
#[derive(Debug, Clone)]
pub struct Reduced {
    pub photos: usize,
    pub blocks: Vec<Matrix6<f64>>,
    keys: Vec<(usize, usize)>,
    index: HashMap<(usize, usize), usize>,
    symbolic: Option<SymbolicLlt<usize>>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ReducedError {
    #[error("the reduced normal equations are not positive definite (the block's datum is not fixed, or a photo is held by too few points)")]
    NotPositive,
    #[error("the sparse solver failed: {0}")]
    Solver(String),
}

impl Reduced {
    /// S's pattern for `photos` photos tied in `pairs` (i, k) (any order, repeats allowed);
    /// every diagonal block is present.
    pub fn new(photos: usize, pairs: impl IntoIterator<Item = (usize, usize)>) -> Reduced {
        let mut keys: Vec<(usize, usize)> = (0..photos).map(|i| (i, i)).collect();
        keys.extend(pairs.into_iter().map(|(i, k)| (i.max(k), i.min(k))));
        keys.sort_unstable();
        keys.dedup();
        let index = keys.iter().enumerate().map(|(n, k)| (*k, n)).collect();
        Reduced {
            photos,
            blocks: vec![Matrix6::zeros(); keys.len()],
            keys,
            index,
            symbolic: None,
        }
    }

    /// The slot of block (i, k) (i ≥ k), if the pattern has it.
    pub fn slot(&self, i: usize, k: usize) -> Option<usize> {
        self.index.get(&(i.max(k), i.min(k))).copied()
    }

    pub fn key(&self, slot: usize) -> (usize, usize) {
        self.keys[slot]
    }

    pub fn len(&self) -> usize {
        self.keys.len()
    }

    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    pub fn clear(&mut self) {
        self.blocks.iter_mut().for_each(|b| *b = Matrix6::zeros());
    }

    fn matrix(&self) -> Result<SparseColMat<usize, f64>, ReducedError> {
        let mut t = Vec::with_capacity(self.keys.len() * 36);
        for ((i, k), b) in self.keys.iter().zip(&self.blocks) {
            for r in 0..6 {
                for c in 0..6 {
                    let (row, col) = (6 * i + r, 6 * k + c);
                    if row >= col {
                        t.push(Triplet::new(row, col, b[(r, c)]));
                    }
                }
            }
        }
        let n = 6 * self.photos;
        SparseColMat::try_new_from_triplets(n, n, &t)
            .map_err(|e| ReducedError::Solver(format!("{e:?}")))
    }

    fn factor(&mut self) -> Result<Llt<usize, f64>, ReducedError> {
        let m = self.matrix()?;
        let symbolic = match &self.symbolic {
            Some(s) => s.clone(),
            None => {
                let s = SymbolicLlt::try_new(m.symbolic(), Side::Lower)
                    .map_err(|e| ReducedError::Solver(format!("{e:?}")))?;
                self.symbolic = Some(s.clone());
                s
            }
        };
        Llt::try_new_with_symbolic(symbolic, m.as_ref(), Side::Lower)
            .map_err(|_| ReducedError::NotPositive)
    }

    /// Solves S·x = rhs.
    pub fn solve(&mut self, rhs: &DVector<f64>) -> Result<DVector<f64>, ReducedError> {
        let llt = self.factor()?;
        let mut b = Mat::<f64>::from_fn(rhs.len(), 1, |i, _| rhs[i]);
        llt.solve_in_place(b.as_mut());
        let x = DVector::from_fn(rhs.len(), |i, _| b[(i, 0)]);
        if x.iter().all(|v| v.is_finite()) {
            Ok(x)
        } else {
            Err(ReducedError::NotPositive)
        }
    }

    /// S⁻¹ whole (6n × 6n): the orientations' cofactor matrix, column panels of the identity
    /// solved at once.
    pub fn inverse(&mut self) -> Result<DMatrix<f64>, ReducedError> {
        let llt = self.factor()?;
        let n = 6 * self.photos;
        let mut out = DMatrix::zeros(n, n);
        const PANEL: usize = 192;
        for c0 in (0..n).step_by(PANEL) {
            let w = PANEL.min(n - c0);
            let mut b = Mat::<f64>::zeros(n, w);
            for c in 0..w {
                b[(c0 + c, c)] = 1.0;
            }
            llt.solve_in_place(b.as_mut());
            for c in 0..w {
                for r in 0..n {
                    out[(r, c0 + c)] = b[(r, c)];
                }
            }
        }
        Ok(out)
    }

    /// S as a dense matrix (for the benchmark's dense solve beside the sparse one, and tests).
    pub fn dense(&self) -> DMatrix<f64> {
        let n = 6 * self.photos;
        let mut d = DMatrix::zeros(n, n);
        for ((i, k), b) in self.keys.iter().zip(&self.blocks) {
            for r in 0..6 {
                for c in 0..6 {
                    d[(6 * i + r, 6 * k + c)] = b[(r, c)];
                    d[(6 * k + c, 6 * i + r)] = b[(r, c)];
                }
            }
        }
        d
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sparse solve and inverse agree with nalgebra's dense Cholesky on a random
    /// positive-definite block-banded S (three photos in a chain and one tied to all).
    #[test]
    fn sparse_solve_and_inverse_match_a_dense_cholesky() {
        let mut u = crate::test_rng::uniform(7);
        let pairs = [(0, 1), (1, 2), (3, 0), (3, 1), (3, 2)];
        let mut s = Reduced::new(4, pairs);
        // A = Jᵀ J + I with J random over the pattern.
        for _ in 0..40 {
            let (i, k) = pairs[(u() * 5.0) as usize % 5];
            let a = nalgebra::SMatrix::<f64, 3, 6>::from_fn(|_, _| u() - 0.5);
            let b = nalgebra::SMatrix::<f64, 3, 6>::from_fn(|_, _| u() - 0.5);
            let (hi, lo, ah, al) = if i > k { (i, k, a, b) } else { (k, i, b, a) };
            let sl = s.slot(hi, lo).unwrap();
            s.blocks[sl] += ah.transpose() * al;
            let d = s.slot(hi, hi).unwrap();
            s.blocks[d] += ah.transpose() * ah;
            let d = s.slot(lo, lo).unwrap();
            s.blocks[d] += al.transpose() * al;
        }
        for i in 0..4 {
            let d = s.slot(i, i).unwrap();
            s.blocks[d] += Matrix6::identity();
        }
        let dense = s.dense();
        let rhs = DVector::from_fn(24, |i, _| (i as f64 * 0.37).sin());
        let x = s.solve(&rhs).unwrap();
        let xd = dense.clone().cholesky().unwrap().solve(&rhs);
        assert!((x - xd).amax() < 1e-10);
        let inv = s.inverse().unwrap();
        let invd = dense.cholesky().unwrap().inverse();
        assert!((inv - invd).amax() < 1e-10);
    }

    #[test]
    fn an_indefinite_system_is_refused() {
        let mut s = Reduced::new(2, [(0, 1)]);
        let d = s.slot(0, 0).unwrap();
        s.blocks[d] = Matrix6::identity();
        // Photo 1's block is zero: nothing fixes it.
        assert_eq!(
            s.solve(&DVector::zeros(12)).unwrap_err(),
            ReducedError::NotPositive
        );
    }
}
