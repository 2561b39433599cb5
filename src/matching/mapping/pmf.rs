//! Polynomial mapping functions (seed 000 §2.1; seed 004 §4): each coordinate of one space
//! as a polynomial of up to third order in the coordinates of another and the height h,
//! `F(x, y, h) = Σ c_t·x^i·y^j·h^k`. Fitted by least squares to ground control points; the
//! terms are chosen by the check points' RMSE (start from the full form, remove in turn the
//! term whose removal lowers the check-point RMSE most, until no removal lowers it).
//!
//! Variables are centred and scaled to about ±1 over the control points before the powers are
//! taken, so that third powers of pixel numbers and heights stay well conditioned.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

/// The monomial x^i·y^j·h^k.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Term(pub u8, pub u8, pub u8);

impl Term {
    pub fn degree(self) -> u8 {
        self.0 + self.1 + self.2
    }

    #[inline]
    fn eval(self, u: [f64; 3]) -> f64 {
        u[0].powi(self.0 as i32) * u[1].powi(self.1 as i32) * u[2].powi(self.2 as i32)
    }
}

impl std::fmt::Display for Term {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut s = String::new();
        for (n, v) in [(self.0, "x"), (self.1, "y"), (self.2, "h")] {
            match n {
                0 => {}
                1 => s.push_str(v),
                _ => s.push_str(&format!("{v}^{n}")),
            }
        }
        if s.is_empty() {
            s.push('1');
        }
        f.write_str(&s)
    }
}

/// Every term of total degree up to `order`, lowest degree first.
pub fn full_terms(order: u8) -> Vec<Term> {
    let mut v = Vec::new();
    for d in 0..=order {
        for i in (0..=d).rev() {
            for j in (0..=d - i).rev() {
                v.push(Term(i, j, d - i - j));
            }
        }
    }
    v
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Normaliser {
    pub centre: [f64; 3],
    pub scale: [f64; 3],
}

impl Normaliser {
    /// Centre and half-range of each variable over `pts`.
    pub fn over(pts: &[[f64; 3]]) -> Normaliser {
        let mut lo = [f64::MAX; 3];
        let mut hi = [f64::MIN; 3];
        for p in pts {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        Normaliser {
            centre: std::array::from_fn(|k| 0.5 * (lo[k] + hi[k])),
            scale: std::array::from_fn(|k| (0.5 * (hi[k] - lo[k])).max(1e-9)),
        }
    }

    #[inline]
    pub fn apply(&self, v: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|k| (v[k] - self.centre[k]) / self.scale[k])
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Polynomial {
    pub terms: Vec<Term>,
    pub coef: Vec<f64>,
    pub norm: Normaliser,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PmfError {
    #[error("{points} control points for {terms} terms: a fit needs more points than terms")]
    TooFewPoints { points: usize, terms: usize },
    #[error("{points} control points: mapping functions need at least {need} (the first-order form's 4 terms and {REDUNDANCY} to check the fit); measure more control points, or use from = \"rigorous\" (4 or more points per photo)")]
    TooFewForMappings { points: usize, need: usize },
    #[error("the control points do not determine the terms (all in a line or at one height?)")]
    Singular,
    #[error("no check points: the terms are chosen by the check points' RMSE")]
    NoCheckPoints,
    #[error("a sampling grid of {0} × {0} at {1} heights: 2 … 50 across, 2 … 20 heights")]
    Grid(usize, usize),
    #[error("a control or check point has a coordinate that is not a number")]
    NotFinite,
    #[error("the control points do not determine the first-order term(s) {missing}: they lie on a line, at one place or at one height; spread them over the photo and the terrain's heights")]
    Degenerate { missing: String },
}

/// How many powers of a variable [`powers`] holds: a polynomial with an exponent this high or
/// higher takes a `powi` per term instead.
pub const MOST_POWERS: usize = 8;

/// x⁰ … x^top (`top` < [`MOST_POWERS`]; the rest 1), each the `powi` a term takes, so that
/// sums built from them are the per-term ones to the last bit.
#[inline]
pub fn powers(x: f64, top: u8) -> [f64; MOST_POWERS] {
    let mut p = [1.0f64; MOST_POWERS];
    for (k, slot) in p.iter_mut().enumerate().take(top as usize + 1).skip(1) {
        *slot = x.powi(k as i32);
    }
    p
}

/// The most terms an [`AlongHeight`] holds: every term of a cubic in three variables.
pub const ALONG_MOST: usize = 20;

/// A polynomial with its first two variables fixed ([`Polynomial::along_height`]): each term
/// keeps the product of its first two powers, so that its value at a height is
/// [`Polynomial::eval`]'s to the last bit, for a third of the work.
#[derive(Debug, Clone, Copy)]
pub struct AlongHeight {
    centre: f64,
    scale: f64,
    top: u8,
    n: usize,
    coef: [f64; ALONG_MOST],
    xy: [f64; ALONG_MOST],
    e: [u8; ALONG_MOST],
}

impl AlongHeight {
    /// The value at height `h` (not normalised).
    #[inline]
    pub fn eval(&self, h: f64) -> f64 {
        let p = powers((h - self.centre) / self.scale, self.top);
        (0..self.n)
            .map(|k| self.coef[k] * (self.xy[k] * p[self.e[k] as usize]))
            .sum()
    }
}

/// One sample: the three variables and the value.
pub type Sample = ([f64; 3], f64);

impl Polynomial {
    #[inline]
    pub fn eval(&self, v: [f64; 3]) -> f64 {
        let u = self.norm.apply(v);
        // Each variable's powers once, not three `powi` a term (a sixth of the height sweep's
        // time went to them); each power is the `powi` the term took, so the sum is the same
        // to the last bit.
        let top = self.top_exponents();
        if top.iter().any(|&e| e as usize >= MOST_POWERS) {
            return self
                .terms
                .iter()
                .zip(&self.coef)
                .map(|(t, c)| c * t.eval(u))
                .sum();
        }
        let pw = [
            powers(u[0], top[0]),
            powers(u[1], top[1]),
            powers(u[2], top[2]),
        ];
        self.terms
            .iter()
            .zip(&self.coef)
            .map(|(t, c)| c * (pw[0][t.0 as usize] * pw[1][t.1 as usize] * pw[2][t.2 as usize]))
            .sum()
    }

    /// The polynomial at (x, y) as a function of the third variable alone, for the many
    /// heights tried at one point; `None` for one of more terms than [`ALONG_MOST`] or a
    /// height exponent of [`MOST_POWERS`] or more (evaluate it whole).
    #[inline]
    pub fn along_height(&self, x: f64, y: f64) -> Option<AlongHeight> {
        let n = self.terms.len();
        let [tx, ty, top] = self.top_exponents();
        if n > ALONG_MOST || top as usize >= MOST_POWERS {
            return None;
        }
        let u = self.norm.apply([x, y, self.norm.centre[2]]);
        let few = (tx as usize) < MOST_POWERS && (ty as usize) < MOST_POWERS;
        let (px, py) = if few {
            (powers(u[0], tx), powers(u[1], ty))
        } else {
            ([1.0; MOST_POWERS], [1.0; MOST_POWERS])
        };
        let mut a = AlongHeight {
            centre: self.norm.centre[2],
            scale: self.norm.scale[2],
            top,
            n,
            coef: [0.0; ALONG_MOST],
            xy: [0.0; ALONG_MOST],
            e: [0; ALONG_MOST],
        };
        for (k, (t, c)) in self.terms.iter().zip(&self.coef).enumerate() {
            // The product `eval` forms first (its powers are these `powi`).
            a.xy[k] = if few {
                px[t.0 as usize] * py[t.1 as usize]
            } else {
                u[0].powi(t.0 as i32) * u[1].powi(t.1 as i32)
            };
            a.coef[k] = *c;
            a.e[k] = t.2;
        }
        Some(a)
    }

    /// The highest exponent of each variable over the terms.
    #[inline]
    pub fn top_exponents(&self) -> [u8; 3] {
        let mut top = [0u8; 3];
        for t in &self.terms {
            top = [top[0].max(t.0), top[1].max(t.1), top[2].max(t.2)];
        }
        top
    }

    /// The same function of variables in other units: old variable k = `u[k].scale` · new +
    /// `u[k].offset`. Only the normaliser changes (u = (old − c)/s = (new − (c − b)/a)/(s/a)),
    /// so the value is the same expression, exactly.
    pub fn with_variables_in(&self, u: [Units; 3]) -> Polynomial {
        let mut p = self.clone();
        for ((c, s), u) in p.norm.centre.iter_mut().zip(&mut p.norm.scale).zip(u) {
            *c = (*c - u.offset) / u.scale;
            *s /= u.scale;
        }
        p
    }

    /// The same function with its value in other units: old value = `u.scale` · new +
    /// `u.offset`.
    pub fn with_value_in(&self, u: Units) -> Polynomial {
        let mut p = self.minus(u.offset);
        if u.scale != 1.0 {
            for c in &mut p.coef {
                *c /= u.scale;
            }
        }
        p
    }

    /// The polynomial less `c` (its constant term moved; one added where it has none).
    pub fn minus(&self, c: f64) -> Polynomial {
        let mut p = self.clone();
        if c == 0.0 {
            return p;
        }
        match p.terms.iter().position(|t| *t == Term(0, 0, 0)) {
            Some(k) => p.coef[k] -= c,
            None => {
                p.terms.push(Term(0, 0, 0));
                p.coef.push(-c);
            }
        }
        p
    }

    /// Least-squares coefficients of `terms` over `samples`.
    pub fn fit(terms: &[Term], norm: &Normaliser, samples: &[Sample]) -> Result<Self, PmfError> {
        if samples.len() <= terms.len() {
            return Err(PmfError::TooFewPoints {
                points: samples.len(),
                terms: terms.len(),
            });
        }
        let a = DMatrix::from_fn(samples.len(), terms.len(), |r, c| {
            terms[c].eval(norm.apply(samples[r].0))
        });
        let b = DVector::from_iterator(samples.len(), samples.iter().map(|s| s.1));
        let svd = a.svd(true, true);
        let smax = svd.singular_values.max();
        if svd.singular_values.min() < 1e-10 * smax.max(1e-300) {
            return Err(PmfError::Singular);
        }
        let x = svd.solve(&b, 0.0).map_err(|_| PmfError::Singular)?;
        Ok(Polynomial {
            terms: terms.to_vec(),
            coef: x.iter().copied().collect(),
            norm: norm.clone(),
        })
    }

    pub fn rmse(&self, samples: &[Sample]) -> f64 {
        if samples.is_empty() {
            return f64::NAN;
        }
        (samples
            .iter()
            .map(|s| (self.eval(s.0) - s.1).powi(2))
            .sum::<f64>()
            / samples.len() as f64)
            .sqrt()
    }
}

/// What the term selection did, for the report (seed 000 Table 2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Selection {
    pub poly: Polynomial,
    pub gcp_rmse: f64,
    pub cp_rmse: f64,
    /// The full form's check-point RMSE, and each removal with the RMSE after it.
    pub start_cp_rmse: f64,
    pub removed: Vec<(Term, f64)>,
}

/// The terms, lowest degree first, that the control points can tell apart: a term whose
/// column is a combination of those before it is left out (at three heights h³ is h, as in
/// seed 004's 5×5×3 grid).
fn independent(terms: &[Term], norm: &Normaliser, gcps: &[Sample]) -> Vec<Term> {
    let mut kept: Vec<Term> = Vec::new();
    for &t in terms {
        let mut trial = kept.clone();
        trial.push(t);
        let a = DMatrix::from_fn(gcps.len(), trial.len(), |r, c| {
            trial[c].eval(norm.apply(gcps[r].0))
        });
        let sv = a.svd(false, false).singular_values;
        if sv.min() > 1e-9 * sv.max() {
            kept = trial;
        }
    }
    kept
}

/// Control points a fit must have beyond its terms, so that its residuals show something.
pub const REDUNDANCY: usize = 2;

/// Seed 000 §2.1: from the full form of `order`, remove in turn the term whose removal lowers
/// the check points' RMSE most, until no removal lowers it. Coefficients always from the
/// control points alone.
pub fn select(order: u8, gcps: &[Sample], cps: &[Sample]) -> Result<Selection, PmfError> {
    if cps.is_empty() {
        return Err(PmfError::NoCheckPoints);
    }
    // Even a first-order mapping (x, y and the height, and a constant) needs its four terms
    // and a redundancy that shows whether it fits; with fewer there is nothing to choose from.
    let need = 4 + REDUNDANCY;
    if gcps.len() < need {
        return Err(PmfError::TooFewForMappings {
            points: gcps.len(),
            need,
        });
    }
    if gcps
        .iter()
        .chain(cps)
        .any(|s| !(s.1.is_finite() && s.0.iter().all(|v| v.is_finite())))
    {
        return Err(PmfError::NotFinite);
    }
    let pts: Vec<[f64; 3]> = gcps.iter().map(|s| s.0).collect();
    let norm = Normaliser::over(&pts);
    let mut terms = independent(&full_terms(order), &norm, gcps);
    // Without the first-order terms the mapping cannot follow the image or the height at all
    // (points on a line, or all at one height): refuse rather than fit a constant.
    let missing: Vec<String> = [Term(1, 0, 0), Term(0, 1, 0), Term(0, 0, 1)]
        .into_iter()
        .filter(|t| !terms.contains(t))
        .map(|t| t.to_string())
        .collect();
    if !missing.is_empty() {
        return Err(PmfError::Degenerate {
            missing: missing.join(", "),
        });
    }
    // Too few points for the full form with its redundancy: the highest terms go first (the
    // first-order ones, the height's among them, stay: there are points enough for them).
    while terms.len() + REDUNDANCY > gcps.len() && terms.len() > 4 {
        terms.pop();
    }
    let mut best = Polynomial::fit(&terms, &norm, gcps)?;
    let mut best_rmse = best.rmse(cps);
    let start_cp_rmse = best_rmse;
    let mut removed = Vec::new();
    while terms.len() > 1 {
        let mut cand: Option<(usize, Polynomial, f64)> = None;
        for k in 0..terms.len() {
            let mut t = terms.clone();
            t.remove(k);
            // The height's last term never goes: without it a sweep along the mapping sees no
            // parallax and every height would score the same (a flat block's check points may
            // prefer it, their heights varying too little to show its use).
            if !t.iter().any(|u| u.2 > 0) {
                continue;
            }
            let Ok(p) = Polynomial::fit(&t, &norm, gcps) else {
                continue;
            };
            let r = p.rmse(cps);
            if cand.as_ref().is_none_or(|c| r < c.2) {
                cand = Some((k, p, r));
            }
        }
        match cand {
            Some((k, p, r)) if r < best_rmse => {
                removed.push((terms[k], r));
                terms.remove(k);
                best = p;
                best_rmse = r;
            }
            _ => break,
        }
    }
    Ok(Selection {
        gcp_rmse: best.rmse(gcps),
        cp_rmse: best_rmse,
        poly: best,
        start_cp_rmse,
        removed,
    })
}

/// The highest order a mapping is fitted with.
pub const MAX_ORDER: u8 = 3;

/// The share of the lower order's check-point RMSE a higher order must stay below to be taken.
pub const HIGHER_ORDER_GAIN: f64 = 0.95;

/// The order by evidence (seed 000's own criterion, one level up): [`select`] from the full
/// form of each order 1…[`MAX_ORDER`], the one whose check points fit best kept (a higher
/// order only when it fits them clearly better, see [`HIGHER_ORDER_GAIN`]). Returns it with its
/// order.
pub fn select_order(gcps: &[Sample], cps: &[Sample]) -> Result<(u8, Selection), PmfError> {
    let mut best: Option<(u8, Selection)> = None;
    let mut first_error = None;
    for order in 1..=MAX_ORDER {
        match select(order, gcps, cps) {
            Ok(s) => {
                // A higher order must lower the check points' RMSE by more than 5 %: what is
                // within their noise does not buy the extra terms.
                if best
                    .as_ref()
                    .is_none_or(|b| s.cp_rmse < HIGHER_ORDER_GAIN * b.1.cp_rmse)
                {
                    best = Some((order, s));
                }
            }
            Err(e) => {
                first_error.get_or_insert(e);
            }
        }
    }
    match (best, first_error) {
        (Some(b), _) => Ok(b),
        (None, Some(e)) => Err(e),
        (None, None) => Err(PmfError::Singular),
    }
}

/// The fourth-order terms Kratky's extended set draws from (seed 004: "two more terms
/// involving mainly powers of y or Y", for a line scanner whose orbit and attitude were
/// modelled as quadratic in time: time runs along y).
pub const EXTENDED_TERMS: [Term; 3] = [Term(0, 4, 0), Term(1, 3, 0), Term(0, 3, 1)];

/// Seed 004's extended set: `basic` with up to two of [`EXTENDED_TERMS`], each added only
/// when it lowers the check points' RMSE below [`HIGHER_ORDER_GAIN`] of what it was (the
/// basic set stays where they do not help). Returns the selection and the terms added.
pub fn extend(basic: Selection, gcps: &[Sample], cps: &[Sample]) -> (Selection, Vec<Term>) {
    let mut best = basic;
    let mut added = Vec::new();
    let norm = best.poly.norm.clone();
    for _ in 0..2 {
        let mut cand: Option<(Term, Polynomial, f64)> = None;
        for t in EXTENDED_TERMS {
            if best.poly.terms.contains(&t) || best.poly.terms.len() + 1 + REDUNDANCY > gcps.len() {
                continue;
            }
            let mut terms = best.poly.terms.clone();
            terms.push(t);
            let Ok(p) = Polynomial::fit(&terms, &norm, gcps) else {
                continue;
            };
            let r = p.rmse(cps);
            if cand.as_ref().is_none_or(|c| r < c.2) {
                cand = Some((t, p, r));
            }
        }
        match cand {
            Some((t, p, r)) if r < HIGHER_ORDER_GAIN * best.cp_rmse => {
                added.push(t);
                best = Selection {
                    gcp_rmse: p.rmse(gcps),
                    cp_rmse: r,
                    poly: p,
                    start_cp_rmse: best.start_cp_rmse,
                    removed: best.removed,
                };
            }
            _ => break,
        }
    }
    (best, added)
}

/// Two polynomials of the same variables: a mapping to a 2-D space.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Mapping {
    pub x: Polynomial,
    pub y: Polynomial,
}

impl Mapping {
    #[inline]
    pub fn eval(&self, v: [f64; 3]) -> [f64; 2] {
        [self.x.eval(v), self.y.eval(v)]
    }

    /// The mapping at (x, y) as a function of the height alone (see
    /// [`Polynomial::along_height`]).
    #[inline]
    pub fn along_height(&self, x: f64, y: f64) -> Option<[AlongHeight; 2]> {
        Some([self.x.along_height(x, y)?, self.y.along_height(x, y)?])
    }

    /// The mapping between the photos' pyramid levels `f` times coarser (pixel coordinates
    /// divided by `f`, heights as they are).
    pub fn coarser(&self, f: f64) -> Mapping {
        let px = Units {
            scale: f,
            offset: 0.0,
        };
        self.in_units([px, px, Units::SAME], [px, px])
    }

    /// The same mapping of variables and to values in other units ([`Units`]).
    pub fn in_units(&self, from: [Units; 3], to: [Units; 2]) -> Mapping {
        Mapping {
            x: self.x.with_variables_in(from).with_value_in(to[0]),
            y: self.y.with_variables_in(from).with_value_in(to[1]),
        }
    }
}

/// A change of a coordinate's units: the old value = `scale` · the new + `offset` (a window's
/// pixels: scale 1, offset its corner; a pyramid level's: scale its factor).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Units {
    pub scale: f64,
    pub offset: f64,
}

impl Units {
    pub const SAME: Units = Units {
        scale: 1.0,
        offset: 0.0,
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::test_rng::uniform;

    /// The powers taken once per variable give each term's value to the last bit, as three
    /// `powi` a term did (tiles and merges compare outputs byte for byte).
    #[test]
    fn eval_is_the_sum_of_the_terms_to_the_last_bit() {
        let mut terms = full_terms(4);
        terms.push(Term(7, 0, 1));
        let coef: Vec<f64> = (0..terms.len()).map(|k| 0.3 + (k as f64).sin()).collect();
        let p = Polynomial {
            terms: terms.clone(),
            coef: coef.clone(),
            norm: Normaliser {
                centre: [0.1, -0.2, 0.3],
                scale: [1.7, 0.9, 2.3],
            },
        };
        let mut u = uniform(11);
        let mut r = || 4.0 * u() - 2.0;
        for _ in 0..2000 {
            let v = [r(), r(), r()];
            let u = p.norm.apply(v);
            let each: f64 = terms.iter().zip(&coef).map(|(t, c)| c * t.eval(u)).sum();
            assert_eq!(p.eval(v).to_bits(), each.to_bits(), "at {v:?}");
        }
        // Exponents beyond the table take the terms' own powers.
        let high = Polynomial {
            terms: vec![Term(9, 1, 0), Term(0, 0, 2)],
            coef: vec![1.5, -0.5],
            norm: p.norm,
        };
        let u = high.norm.apply([0.7, 0.2, -1.1]);
        let each = 1.5 * Term(9, 1, 0).eval(u) + -0.5 * Term(0, 0, 2).eval(u);
        assert_eq!(high.eval([0.7, 0.2, -1.1]).to_bits(), each.to_bits());
    }

    /// A polynomial with x and y fixed gives `eval`'s value at every height to the last bit
    /// (every cubic term, and a chosen few in another order); one of more terms than it holds,
    /// or a height power beyond the table, is left to `eval`.
    #[test]
    fn along_height_is_eval_to_the_last_bit() {
        let norm = Normaliser {
            centre: [310.5, -42.0, 180.0],
            scale: [250.0, 190.0, 60.0],
        };
        let few = vec![
            Term(0, 0, 3),
            Term(1, 2, 0),
            Term(0, 0, 0),
            Term(2, 0, 1),
            Term(0, 1, 2),
        ];
        let mut u = uniform(5);
        let mut r = || 2.0 * u() - 1.0;
        for terms in [full_terms(3), few] {
            let p = Polynomial {
                coef: (0..terms.len()).map(|_| 3.0 * r()).collect(),
                terms,
                norm: norm.clone(),
            };
            for _ in 0..200 {
                let (x, y) = (310.5 + 300.0 * r(), -42.0 + 200.0 * r());
                let a = p.along_height(x, y).unwrap();
                for _ in 0..20 {
                    let h = 180.0 + 90.0 * r();
                    assert_eq!(
                        a.eval(h).to_bits(),
                        p.eval([x, y, h]).to_bits(),
                        "{x} {y} {h}"
                    );
                }
            }
        }
        let long = Polynomial {
            terms: full_terms(4),
            coef: vec![1.0; 35],
            norm: norm.clone(),
        };
        assert!(long.along_height(1.0, 2.0).is_none());
        let steep = Polynomial {
            terms: vec![Term(0, 0, 9)],
            coef: vec![1.0],
            norm,
        };
        assert!(steep.along_height(1.0, 2.0).is_none());
    }

    #[test]
    fn full_forms_have_the_binomial_counts() {
        assert_eq!(full_terms(1).len(), 4);
        assert_eq!(full_terms(2).len(), 10);
        assert_eq!(full_terms(3).len(), 20);
        assert_eq!(full_terms(2)[0], Term(0, 0, 0));
        assert_eq!(Term(2, 0, 1).to_string(), "x^2h");
    }

    #[test]
    fn selection_keeps_the_true_terms_and_drops_the_others() {
        // f = 3 + 2x − y·h + 0.5x²: four of the twenty terms, plus small noise.
        let f = |v: [f64; 3]| 3.0 + 2.0 * v[0] - v[1] * v[2] + 0.5 * v[0] * v[0];
        let mut s: u64 = 7;
        let mut noise = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 33) as f64 / (1u64 << 31) as f64 - 0.5) * 1e-3
        };
        let mut gcps = Vec::new();
        let mut cps = Vec::new();
        for i in 0..6 {
            for j in 0..6 {
                for k in 0..3 {
                    let v = [i as f64 * 100.0, j as f64 * 80.0, 200.0 + k as f64 * 150.0];
                    let w = [v[0] + 50.0, v[1] + 40.0, v[2] + 75.0];
                    let n = noise();
                    gcps.push((v, f([v[0] / 100.0, v[1] / 100.0, v[2] / 100.0]) + n));
                    cps.push((w, f([w[0] / 100.0, w[1] / 100.0, w[2] / 100.0]) + noise()));
                }
            }
        }
        let sel = select(3, &gcps, &cps).unwrap();
        assert!(sel.cp_rmse < 1e-3, "{sel:?}");
        assert!(sel.cp_rmse <= sel.start_cp_rmse);
        let kept: Vec<Term> = sel.poly.terms.clone();
        for t in [Term(0, 0, 0), Term(1, 0, 0), Term(0, 1, 1), Term(2, 0, 0)] {
            assert!(kept.contains(&t), "{t} dropped: {kept:?}");
        }
        assert!(kept.len() < 20, "nothing removed");
    }

    /// A nearly flat block: the value hardly depends on the height, and the control points'
    /// errors happen to grow with it, so the check points (at another height) prefer a form
    /// without any height term. The selection keeps one: a sweep along a mapping without the
    /// height would see no parallax at all.
    #[test]
    fn a_height_term_is_always_kept() {
        let f = |v: [f64; 3]| 1.0 + 0.5 * v[0] - 0.3 * v[1] + 1e-4 * v[2];
        let mut gcps = Vec::new();
        let mut cps = Vec::new();
        for i in 0..3 {
            for j in 0..3 {
                let h = 400.0 + ((i * 3 + j) % 4) as f64;
                let v = [i as f64 * 100.0, j as f64 * 100.0, h];
                gcps.push((v, f(v) + 0.1 * (h - 401.5)));
                let w = [v[0] + 50.0, v[1] + 50.0, 412.0];
                cps.push((w, f(w)));
            }
        }
        // Without the rule, the check points would drop h (verified by fitting both forms).
        let norm = Normaliser::over(&gcps.iter().map(|g| g.0).collect::<Vec<_>>());
        let with = Polynomial::fit(
            &[Term(0, 0, 0), Term(1, 0, 0), Term(0, 1, 0), Term(0, 0, 1)],
            &norm,
            &gcps,
        )
        .unwrap();
        let without =
            Polynomial::fit(&[Term(0, 0, 0), Term(1, 0, 0), Term(0, 1, 0)], &norm, &gcps).unwrap();
        assert!(
            without.rmse(&cps) < with.rmse(&cps),
            "the case does not test the rule"
        );
        let sel = select(2, &gcps, &cps).unwrap();
        assert!(
            sel.poly.terms.iter().any(|t| t.2 > 0),
            "{:?}",
            sel.poly.terms
        );
    }

    #[test]
    fn too_few_control_points_are_refused_saying_how_many_are_needed() {
        let g: Vec<Sample> = (0..5)
            .map(|k| ([k as f64, (k * k) as f64, (k % 3) as f64], k as f64))
            .collect();
        let e = select(2, &g, &g).unwrap_err();
        assert!(
            matches!(e, PmfError::TooFewForMappings { points: 5, need: 6 }),
            "{e:?}"
        );
        assert!(e.to_string().contains("at least 6"), "{e}");
    }

    /// A cubic in x: the order chosen by the check points is 3, and its check points fit
    /// better than the best of order 2; a plane stays at order 1.
    #[test]
    fn the_order_is_chosen_by_the_check_points() {
        let grid = |f: &dyn Fn([f64; 3]) -> f64, off: f64| -> Vec<Sample> {
            let mut v = Vec::new();
            for i in 0..6 {
                for j in 0..5 {
                    for k in 0..3 {
                        let p = [i as f64 + off, j as f64 + off, k as f64 + 0.5 * off];
                        // Measuring noise of ±0.005, the same draw every run.
                        let seed = (i * 31 + j * 17 + k * 7) as f64 + 1000.0 * off;
                        let n = ((seed * 12.9898).sin() * 43_758.545).fract() * 0.01 - 0.005;
                        v.push((p, f(p) + n));
                    }
                }
            }
            v
        };
        let cubic = |p: [f64; 3]| 1.0 + p[0] - 0.5 * p[2] + 0.05 * p[0].powi(3);
        let (g, c) = (grid(&cubic, 0.0), grid(&cubic, 0.37));
        let (order, s) = select_order(&g, &c).unwrap();
        assert_eq!(order, 3, "{s:?}");
        let two = select(2, &g, &c).unwrap();
        assert!(
            s.cp_rmse < 0.1 * two.cp_rmse,
            "{} vs {}",
            s.cp_rmse,
            two.cp_rmse
        );
        let plane = |p: [f64; 3]| 2.0 + 0.3 * p[0] - p[1] + 0.1 * p[2];
        let (g, c) = (grid(&plane, 0.0), grid(&plane, 0.37));
        assert_eq!(select_order(&g, &c).unwrap().0, 1);
    }
}
