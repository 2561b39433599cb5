//! A cell's winner among the planes of a sweep: the highest score (NaN, a plane the search
//! photo does not see, is never the best), its first place, and the neighbours a parabola or
//! a check needs. Shared by the height sweep and the rectified-pair matcher.

/// The best plane of one cell's scores.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Winner {
    pub plane: usize,
    pub score: f32,
    /// The scores one plane below and above (None at the ends of the range).
    pub below: Option<f32>,
    pub above: Option<f32>,
}

impl Winner {
    /// The peak below the plane step by a parabola through the three scores (−0.5 … 0.5),
    /// and the second difference (negative at a peak).
    pub fn parabola(&self) -> Option<(f64, f64)> {
        let (a, b) = (self.below? as f64, self.above? as f64);
        let (off, den) = parabola(a, self.score as f64, b);
        (den < 0.0).then_some((off, den))
    }
}

/// The parabola through the scores `a` one plane below the peak, `s` at it and `b` above: the
/// peak's place below the plane step (−0.5 … 0.5) and the second difference a − 2s + b. The
/// place is NaN where the three are no peak (the difference not negative, or a score NaN).
/// Without a branch, so that a row's peaks are taken on vector lanes.
#[inline(always)]
pub fn parabola(a: f64, s: f64, b: f64) -> (f64, f64) {
    let den = a - 2.0 * s + b;
    let off = (0.5 * (a - b) / den).clamp(-0.5, 0.5);
    (if den < 0.0 { off } else { f64::NAN }, den)
}

/// What a plane the search photo does not see (a NaN score) does to a pixel's winner.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unseen {
    /// The pixel gets no winner: its match may lie on that plane (the height sweep, where
    /// nothing else checks the winner).
    Refuse,
    /// The plane is left out, and the winner must have seen neighbours on both sides (a peak
    /// against the unseen part may be the flank of a match beyond it). For a check that
    /// catches a winner whose true match is unseen: left-right consistency.
    Skip,
}

/// The highest of the scores, NaN left out (−∞ when none): in sixteen lanes (two independent
/// vectors, so that it runs on vector lanes without waiting on itself), reduced as a tree,
/// then the tail.
#[inline(always)]
pub fn highest(s: &[f32]) -> f32 {
    let max = |a: f32, b: f32| if b > a { b } else { a };
    let mut lanes = [f32::NEG_INFINITY; 16];
    let chunks = s.chunks_exact(16);
    let tail = chunks.remainder();
    for ch in chunks {
        for l in 0..16 {
            lanes[l] = max(lanes[l], ch[l]);
        }
    }
    let mut half = 8;
    while half > 0 {
        for l in 0..half {
            lanes[l] = max(lanes[l], lanes[l + half]);
        }
        half /= 2;
    }
    tail.iter().fold(lanes[0], |v, &x| max(v, x))
}

/// The plane with the highest score, scored on both sides (a neighbour not scored — flat,
/// unseen — is no peak that a parabola can refine or trust; the ends of the range excepted).
#[inline(always)]
pub fn winner(s: &[f32], unseen: Unseen) -> Option<Winner> {
    if unseen == Unseen::Refuse && s.iter().any(|v| v.is_nan()) {
        return None;
    }
    let v = highest(s);
    if v == f32::NEG_INFINITY {
        return None;
    }
    let (b, ch) = s
        .chunks(8)
        .enumerate()
        .find(|(_, ch)| ch.iter().fold(false, |a, &x| a | (x == v)))?;
    let p = b * 8 + ch.iter().position(|&x| x == v)?;
    let side = |q: Option<usize>| q.and_then(|q| s.get(q).copied());
    let below = side(p.checked_sub(1));
    let above = side(Some(p + 1));
    let scored = |x: Option<f32>| x.is_none_or(|b| b > f32::NEG_INFINITY);
    if !scored(below) || !scored(above) {
        return None;
    }
    Some(Winner {
        plane: p,
        score: v,
        below,
        above,
    })
}

/// The right photo's own winners, for the left-right check: for each right column x, the
/// plane of the highest score among the reference cells that meet it on a rectified pair
/// (x = c − first − p). Kept by reversed column (wr − 1 − x), so that one reference cell's
/// planes meet them ascending and its update is one pass over contiguous slices (u32 planes
/// beside f32 scores, so that it runs on vector lanes).
pub struct RightBest {
    best: Vec<f32>,
    at: Vec<u32>,
    planes: Vec<u32>,
}

impl RightBest {
    /// For a right photo `wr` columns wide and `np` planes.
    pub fn new(wr: usize, np: usize) -> RightBest {
        RightBest {
            best: vec![f32::NEG_INFINITY; wr],
            at: vec![u32::MAX; wr],
            planes: (0..np as u32).collect(),
        }
    }

    /// Forgets every winner (a new row).
    pub fn clear(&mut self) {
        self.best.fill(f32::NEG_INFINITY);
        self.at.fill(u32::MAX);
    }

    /// Offers planes `lo..hi` of the scores `s` of the reference cell at x0 = c − first (those
    /// planes must meet the right photo: 0 ≤ x0 − p < wr). NaN (unseen) and −∞ (unscored) are
    /// nobody's best; of equal scores the first offered stays.
    #[inline(always)]
    pub fn offer(&mut self, x0: i64, s: &[f32], lo: usize, hi: usize) {
        // The reversed index of plane lo (in i64 first: wr − 1 − x0 may be negative).
        let s0 = (self.best.len() as i64 - 1 - x0 + lo as i64) as usize;
        let s1 = s0 + (hi - lo);
        keep_best(
            &mut self.best[s0..s1],
            &mut self.at[s0..s1],
            &s[lo..hi],
            &self.planes[lo..hi],
        );
    }

    /// The winner of each right column x into `out[x]` (u32::MAX where none).
    pub fn write(&self, out: &mut [u32]) {
        for (o, &a) in out.iter_mut().zip(self.at.iter().rev()) {
            *o = a;
        }
    }
}

/// Where `d` beats `best`, the score and its plane are kept. The slices are a function's
/// arguments, so that the compiler knows them apart.
#[inline(always)]
fn keep_best(best: &mut [f32], at: &mut [u32], d: &[f32], planes: &[u32]) {
    for (((d, v), b), &pi) in d.iter().zip(best).zip(at).zip(planes) {
        let better = *d > *v;
        *v = if better { *d } else { *v };
        *b = if better { pi } else { *b };
    }
}

/// A cell's winner (on the chosen scores) and the correlations around it (the raw ones).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pick {
    /// The winning plane, None where there is none.
    pub plane: Option<u32>,
    pub rho: f32,
    /// The raw correlations one plane below and above the winner, where finite.
    pub below: Option<f32>,
    pub above: Option<f32>,
    /// Some plane the right photo does not see (NaN).
    pub unseen: bool,
    /// The peak below the plane step from the chosen scores, where they are not the raw
    /// correlations (aggregated costs); None: from the raw correlations.
    pub offset: Option<f32>,
    /// The winner is unique (see [`unique`]); true where there is no winner.
    pub unique: bool,
}

impl Pick {
    /// From the chosen scores' winner and the raw scores `raw(p)` of the `np` planes.
    #[inline(always)]
    pub fn new(win: Option<Winner>, np: usize, raw: impl Fn(usize) -> f32) -> Pick {
        let finite = |p: Option<usize>| p.filter(|&p| p < np).map(&raw).filter(|v| v.is_finite());
        match win {
            Some(w) => Pick {
                plane: Some(w.plane as u32),
                rho: raw(w.plane),
                below: finite(w.plane.checked_sub(1)),
                above: finite(Some(w.plane + 1)),
                unseen: false,
                offset: None,
                unique: true,
            },
            None => Pick {
                plane: None,
                rho: f32::NAN,
                below: None,
                above: None,
                unseen: (0..np).any(|p| raw(p).is_nan()),
                offset: None,
                unique: true,
            },
        }
    }
}

/// A row's picks in arrays, one value per cell in each (so that a row's matches are taken on
/// vector lanes): what [`Pick`] holds, with NaN for None and [`RowPicks::NONE`] for no plane.
#[derive(Debug, Clone, Default)]
pub struct RowPicks {
    /// The winning plane, NONE where there is none.
    pub plane: Vec<u32>,
    /// The winner's raw correlation; where there is no plane, NaN where some plane is unseen
    /// and −∞ where the cell has nothing to match.
    pub rho: Vec<f32>,
    /// The raw correlations one plane below and above the winner, NaN where not finite.
    pub below: Vec<f32>,
    pub above: Vec<f32>,
    /// The peak below the plane step from the chosen scores, NaN: from the raw correlations.
    pub offset: Vec<f32>,
    /// The winner is unique (see [`unique`]); true where there is no winner.
    pub unique: Vec<bool>,
}

impl RowPicks {
    pub const NONE: u32 = u32::MAX;

    pub fn len(&self) -> usize {
        self.plane.len()
    }

    pub fn is_empty(&self) -> bool {
        self.plane.is_empty()
    }

    pub fn clear(&mut self) {
        self.plane.clear();
        self.rho.clear();
        self.below.clear();
        self.above.clear();
        self.offset.clear();
        self.unique.clear();
    }

    /// `n` cells of which no plane is seen.
    pub fn unseen(&mut self, n: usize) {
        self.clear();
        self.plane.resize(n, Self::NONE);
        for v in [
            &mut self.rho,
            &mut self.below,
            &mut self.above,
            &mut self.offset,
        ] {
            v.resize(n, f32::NAN);
        }
        self.unique.resize(n, true);
    }

    pub fn push(&mut self, p: &Pick) {
        let nan = |v: Option<f32>| v.unwrap_or(f32::NAN);
        self.plane.push(p.plane.unwrap_or(Self::NONE));
        let rho = match (p.plane, p.unseen) {
            (Some(_), _) => p.rho,
            (None, true) => f32::NAN,
            (None, false) => f32::NEG_INFINITY,
        };
        self.rho.push(rho);
        self.below.push(nan(p.below));
        self.above.push(nan(p.above));
        self.offset.push(nan(p.offset));
        self.unique.push(p.unique);
    }

    /// Cell i as a [`Pick`] (a cell without a plane has NaN for its correlation).
    pub fn get(&self, i: usize) -> Pick {
        let some = |v: f32| (!v.is_nan()).then_some(v);
        let plane = (self.plane[i] != Self::NONE).then_some(self.plane[i]);
        Pick {
            plane,
            rho: if plane.is_some() {
                self.rho[i]
            } else {
                f32::NAN
            },
            below: some(self.below[i]),
            above: some(self.above[i]),
            unseen: plane.is_none() && self.rho[i].is_nan(),
            offset: some(self.offset[i]),
            unique: self.unique[i],
        }
    }
}

/// Whether the winner `plane` of the chosen scores is unique, as the uniqueness ratio of
/// Hirschmüller (2008) and OpenCV takes it: every plane beyond the winner's two neighbours
/// costs at least 1/(1 − u) times the winner's cost, the costs being `cost(score)` (unseen
/// planes, NaN, are left out). A photo pair that shows nothing in common has many planes
/// nearly as good as the best; a real match stands out. Both costs are counted from `floor`
/// (the smallest cost that means anything: a correlation of 1 is noise-free only in theory),
/// so that two planes at cost 0 (a repeating texture) are a tie, not unique.
#[inline(always)]
pub fn unique(chosen: &[f32], plane: usize, u: f32, floor: f32, cost: impl Fn(f32) -> f32) -> bool {
    if u <= 0.0 {
        return true;
    }
    let (lo, hi) = (plane.saturating_sub(1), (plane + 2).min(chosen.len()));
    let other = highest(&chosen[..lo]).max(highest(&chosen[hi..]));
    stands_out(chosen[plane], other, u, floor, cost)
}

/// The uniqueness ratio's test of [`unique`] on the winner's score `best` and the highest
/// `other` beyond its neighbours (−∞ where none).
#[inline(always)]
pub fn stands_out(best: f32, other: f32, u: f32, floor: f32, cost: impl Fn(f32) -> f32) -> bool {
    other == f32::NEG_INFINITY || (cost(other) + floor) * (1.0 - u) >= cost(best) + floor
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The lane-wise winner is the plain scan's: the first place of the highest score, NaN
    /// never the best, no winner when all are −∞ or a neighbour is not scored, over lengths
    /// that fill the lanes, miss them and leave tails, with ties across the lanes.
    #[test]
    fn winner_is_the_first_best() {
        let mut seed = 11u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            seed >> 33
        };
        for n in 1..70usize {
            for _ in 0..200 {
                let s: Vec<f32> = (0..n)
                    .map(|_| match next() % 16 {
                        0 => f32::NAN,
                        1 => f32::NEG_INFINITY,
                        // Few distinct values, so that ties are common.
                        v => (v % 5) as f32 * 0.1,
                    })
                    .collect();
                let mut want: Option<usize> = None;
                for (i, &x) in s.iter().enumerate() {
                    if x > f32::NEG_INFINITY && want.is_none_or(|w| x > s[w]) {
                        want = Some(i);
                    }
                }
                let want = want.filter(|&p| {
                    let ok = |q: Option<usize>| q.is_none_or(|q| s[q] > f32::NEG_INFINITY);
                    ok(p.checked_sub(1)) && ok((p + 1 < n).then_some(p + 1))
                });
                let got = winner(&s, Unseen::Skip).map(|w| w.plane);
                assert_eq!(got, want, "{s:?}");
            }
        }
    }

    /// A row's picks in arrays give back the picks put in: a winner with and without its
    /// neighbours and its own place, a cell with some plane unseen, one with nothing to match.
    #[test]
    fn row_picks_keep_what_a_pick_holds() {
        let w = |plane, below, above| Winner {
            plane,
            score: 0.9,
            below,
            above,
        };
        let s = [0.2f32, 0.5, 0.9, 0.7, f32::NAN];
        let mut picks = vec![
            Pick::new(Some(w(2, Some(0.5), Some(0.7))), 5, |p| s[p]),
            Pick::new(Some(w(0, None, Some(0.5))), 5, |p| s[p]),
            Pick::new(None, 5, |p| s[p]),
            Pick::new(None, 1, |_| f32::NEG_INFINITY),
        ];
        picks[0].offset = Some(-0.25);
        picks[1].unique = false;
        let mut rp = RowPicks::default();
        for p in &picks {
            rp.push(p);
        }
        assert_eq!(rp.len(), 4);
        for (i, p) in picks.iter().enumerate() {
            let g = rp.get(i);
            assert_eq!(
                (g.plane, g.below, g.above, g.unseen),
                (p.plane, p.below, p.above, p.unseen)
            );
            assert_eq!((g.offset, g.unique), (p.offset, p.unique));
            assert!(g.rho == p.rho || (g.rho.is_nan() && p.rho.is_nan()), "{i}");
        }
        assert!(rp.get(2).unseen && !rp.get(3).unseen);
        // A row the right photo has no rows for: every cell unseen.
        rp.unseen(3);
        assert!((0..3).all(|i| rp.get(i).unseen && rp.get(i).plane.is_none()));
    }

    /// The uniqueness ratio by its definition: the winner's neighbours do not count, any
    /// other plane must cost at least 1/(1 − u) times the winner, NaN planes are left out.
    #[test]
    fn uniqueness_by_its_definition() {
        let cost = |v: f32| 1.0 - v;
        // Winner at 4 (cost 0.10); its neighbours nearly as good; plane 8 costs 0.11.
        let mut s = vec![0.2f32, 0.3, 0.5, 0.89, 0.9, 0.895, 0.4, 0.3, 0.89, f32::NAN];
        // 0.11·(1 − u) ≥ 0.10 ⇔ u ≤ 1/11 ≈ 0.0909.
        assert!(unique(&s, 4, 0.09, 0.0, cost));
        assert!(!unique(&s, 4, 0.095, 0.0, cost));
        assert!(unique(&s, 4, 0.0, 0.0, cost), "0 turns the test off");
        // Without plane 8 the next is plane 2 (cost 0.5): unique up to u = 0.8.
        s[8] = 0.3;
        assert!(unique(&s, 4, 0.79, 0.0, cost));
        assert!(!unique(&s, 4, 0.81, 0.0, cost));
        // A winner at the end, and nothing else seen: unique.
        let t = [f32::NAN, f32::NAN, 0.7, 0.9];
        assert!(unique(&t, 3, 0.5, 0.0, cost));
        // Aggregated costs (chosen = −S): S 100 at the winner, 104 beyond: u ≤ 1 − 100/104.
        let a = [-104.0f32, -120.0, -101.0, -100.0, -101.0];
        assert!(unique(&a, 3, 0.038, 0.0, |v| -v));
        assert!(!unique(&a, 3, 0.039, 0.0, |v| -v));
        // Two planes at cost 0 (a repeating texture): a tie, counted from the floor.
        let r = [1.0f32, 0.2, 0.1, 0.3, 1.0, 0.4];
        assert!(
            unique(&r, 4, 0.1, 0.0, cost),
            "without a floor 0 ≥ 0 passes"
        );
        assert!(!unique(&r, 4, 0.1, 1e-3, cost));
        // The floor barely moves a clear winner: cost 0.001 against 0.5.
        let c = [0.5f32, 0.999, 0.5];
        assert!(unique(&c, 1, 0.9, 1e-3, cost));
    }
}
