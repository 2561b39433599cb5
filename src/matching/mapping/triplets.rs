//! Heights from three of a stereo point's four image coordinates (seed 004 §4, after Kratky):
//! (x′, y′, x″), (x″, y″, x′), (x′, y′, y″) and (x″, y″, y′), each solved for the height h at
//! which the image→image mapping carries the first photo's point onto the third coordinate.
//! The seed's SPOT pair had its base along x: the first two triplets gave 6.2 m RMS (as the
//! rigorous solution), the last two about 135 m, since y″ hardly changes with the height
//! there. Which triplets are weak follows from the geometry alone (the pixels the third
//! coordinate moves per metre of height), and is said as a warning.

use crate::coords::PixelXY;
use crate::geometry::Sensor;
use crate::matching::mapping::pmf::{Mapping, PmfError};
use crate::matching::mapping::pmf_set::PmfSet;
use serde::{Deserialize, Serialize};

/// Which three coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Triplet {
    /// (x′, y′, x″)
    LeftX,
    /// (x″, y″, x′)
    RightX,
    /// (x′, y′, y″)
    LeftY,
    /// (x″, y″, y′)
    RightY,
}

impl Triplet {
    pub const ALL: [Triplet; 4] = [
        Triplet::LeftX,
        Triplet::RightX,
        Triplet::LeftY,
        Triplet::RightY,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Triplet::LeftX => "(x′, y′, x″)",
            Triplet::RightX => "(x″, y″, x′)",
            Triplet::LeftY => "(x′, y′, y″)",
            Triplet::RightY => "(x″, y″, y′)",
        }
    }

    /// The photo whose point is given whole (0 left, 1 right), and the other photo's
    /// coordinate used (0 column x, 1 row y).
    fn parts(self) -> (usize, usize) {
        match self {
            Triplet::LeftX => (0, 0),
            Triplet::RightX => (1, 0),
            Triplet::LeftY => (0, 1),
            Triplet::RightY => (1, 1),
        }
    }
}

/// The image→image mappings of a pair both ways (seed 004: six polynomials; these are the two
/// the triplets use), fitted from the two sensors over `heights`.
#[derive(Debug, Clone)]
pub struct ImageToImage {
    pub left_to_right: Mapping,
    pub right_to_left: Mapping,
    pub heights: [f64; 2],
}

/// Steps of the scan for the root's bracket over the heights (and a fifth of the range
/// beyond each end).
const SCAN_STEPS: usize = 64;

/// The height in `[lo, hi]` where `f` (the predicted coordinate minus the observed one)
/// crosses zero: the first bracket of a scan, then bisection to a micrometre; `None` where
/// no crossing lies in the range.
fn root(f: impl Fn(f64) -> f64, lo: f64, hi: f64) -> Option<f64> {
    let step = (hi - lo) / SCAN_STEPS as f64;
    let mut a = lo;
    let mut fa = f(a);
    for k in 1..=SCAN_STEPS {
        let b = lo + k as f64 * step;
        let fb = f(b);
        if fa == 0.0 {
            return Some(a);
        }
        if fa.is_finite() && fb.is_finite() && (fa < 0.0) != (fb < 0.0) {
            let (mut a, mut b, mut fa) = (a, b, fa);
            for _ in 0..100 {
                let m = 0.5 * (a + b);
                let fm = f(m);
                if !fm.is_finite() {
                    return None;
                }
                if (fm < 0.0) == (fa < 0.0) {
                    a = m;
                    fa = fm;
                } else {
                    b = m;
                }
                if b - a < 1e-6 {
                    break;
                }
            }
            return Some(0.5 * (a + b));
        }
        a = b;
        fa = fb;
    }
    None
}

fn search_range(h: [f64; 2]) -> (f64, f64) {
    let m = 0.2 * (h[1] - h[0]);
    (h[0] - m, h[1] + m)
}

impl ImageToImage {
    pub fn from_sensors(
        left: &dyn Sensor,
        right: &dyn Sensor,
        heights: [f64; 2],
        order: u8,
    ) -> Result<ImageToImage, PmfError> {
        let set = PmfSet::from_sensors(left, right, heights, order)?;
        Ok(ImageToImage {
            right_to_left: set.right_to_left.ok_or(PmfError::Singular)?,
            left_to_right: set.left_to_right,
            heights,
        })
    }

    /// The height from triplet `t` of a point at `left` and `right` (pixels, corner origin).
    pub fn height(&self, t: Triplet, left: PixelXY, right: PixelXY) -> Option<f64> {
        let (from, coord) = t.parts();
        let (m, p, q) = if from == 0 {
            (&self.left_to_right, left, right)
        } else {
            (&self.right_to_left, right, left)
        };
        let target = if coord == 0 { q.col } else { q.row };
        let f = |h: f64| m.eval([p.col, p.row, h])[coord] - target;
        let (lo, hi) = search_range(self.heights);
        root(f, lo, hi)
    }

    /// Pixels the triplet's third coordinate moves per metre of height at `left` and `h`.
    pub fn px_per_m(&self, t: Triplet, left: PixelXY, right: PixelXY, h: f64) -> f64 {
        let (from, coord) = t.parts();
        let (m, p) = if from == 0 {
            (&self.left_to_right, left)
        } else {
            (&self.right_to_left, right)
        };
        let e = |h: f64| m.eval([p.col, p.row, h])[coord];
        (e(h + 1.0) - e(h - 1.0)).abs() / 2.0
    }
}

/// The rigorous height from the same triplet: through the sensors themselves, the given
/// photo's ray followed to height h and seen in the other photo.
pub fn rigorous_height(
    left: &dyn Sensor,
    right: &dyn Sensor,
    t: Triplet,
    l: PixelXY,
    r: PixelXY,
    heights: [f64; 2],
) -> Option<f64> {
    let (from, coord) = t.parts();
    let (a, b, p, q) = if from == 0 {
        (left, right, l, r)
    } else {
        (right, left, r, l)
    };
    let target = if coord == 0 { q.col } else { q.row };
    let f = |h: f64| {
        a.image_to_ground(p, h)
            .and_then(|g| b.ground_to_image(g))
            .map_or(
                f64::NAN,
                |s| if coord == 0 { s.col } else { s.row } - target,
            )
    };
    let (lo, hi) = search_range(heights);
    root(f, lo, hi)
}

/// One triplet over a set of points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TripletReport {
    pub triplet: String,
    /// Points whose height the triplet gave (within the heights and a fifth beyond).
    pub points: usize,
    /// RMS of the heights against the points' known heights, m.
    pub rms_m: f64,
    /// Median pixels of the third coordinate per metre of height.
    pub px_per_m: f64,
    /// Set where the triplet is weak: its coordinate moves under a fifth as much per metre
    /// as the strongest triplet's (the base lies along the other axis).
    pub warning: Option<String>,
}

/// All four triplets over `points` (left pixel, right pixel, known height), with the
/// geometry's warning for the weak ones.
pub fn assess(maps: &ImageToImage, points: &[(PixelXY, PixelXY, f64)]) -> Vec<TripletReport> {
    let mut out: Vec<TripletReport> = Triplet::ALL
        .iter()
        .map(|&t| {
            let errors: Vec<f64> = points
                .iter()
                .filter_map(|(l, r, z)| maps.height(t, *l, *r).map(|h| h - z))
                .collect();
            let mut rates: Vec<f64> = points
                .iter()
                .map(|(l, r, z)| maps.px_per_m(t, *l, *r, *z))
                .collect();
            rates.sort_by(f64::total_cmp);
            let rms =
                (errors.iter().map(|e| e * e).sum::<f64>() / errors.len().max(1) as f64).sqrt();
            TripletReport {
                triplet: t.name().into(),
                points: errors.len(),
                rms_m: if errors.is_empty() { f64::NAN } else { rms },
                px_per_m: rates.get(rates.len() / 2).copied().unwrap_or(f64::NAN),
                warning: None,
            }
        })
        .collect();
    let best = out.iter().map(|r| r.px_per_m).fold(0.0, f64::max);
    for r in &mut out {
        if r.px_per_m < 0.2 * best {
            r.warning = Some(format!(
                "{}: its third coordinate moves {:.2e} px per metre of height, against {:.2e} for the best triplet: the base lies along the other image axis, so its heights are {:.0} times as uncertain",
                r.triplet,
                r.px_per_m,
                best,
                best / r.px_per_m.max(1e-12)
            ));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::coords::GroundM;
    use crate::geometry::Pushbroom;

    /// A SPOT-like across-track pair (tilted −20° and +20°, 10 m pixels): the base, and the
    /// parallax, along the columns x.
    fn pair() -> (Pushbroom, Pushbroom) {
        let view = |deg: f64| {
            let tilt = deg.to_radians();
            Pushbroom {
                columns: 2000,
                lines: 2000,
                line_period_s: 10.0 / 6600.0,
                focal_px: 83_000.0,
                principal_col: 1000.0,
                tilt_across: tilt,
                tilt_along: 0.0,
                // Southbound: right of the track is west, so a right tilt sits east.
                position: [
                    [500_000.0 + 830_000.0 * tilt.tan(), 15.0, 0.0],
                    [4_000_000.0, -6600.0, 0.0],
                    [830_000.0, 0.0, 0.0],
                ],
                attitude: [
                    [1e-4 * deg.signum(), 1e-6, 0.0],
                    [-1e-4, 0.0, 0.0],
                    [5e-4, 0.0, 0.0],
                ],
            }
        };
        (view(-20.0), view(20.0))
    }

    /// Issue 20's goal: the triplets' heights through the mapping functions equal the rigorous
    /// intersection of the same triplet within 1 % of the height error per pixel of parallax;
    /// with 0.3 px of measuring noise the x-triplets keep the rigorous precision and the
    /// y-triplets fail, with the warning (as seed 004's 6.2 m against 135 m).
    #[test]
    fn triplet_heights_equal_the_rigorous_ones_and_the_weak_ones_are_named() {
        let (l, r) = pair();
        let heights = [0.0, 2000.0];
        let maps = ImageToImage::from_sensors(&l, &r, heights, 3).unwrap();
        let mut pts = Vec::new();
        let mut worst = [0.0f64; 4];
        let mut noisy = Vec::new();
        for i in 0..12 {
            for j in 0..12 {
                let q = PixelXY::new(100.0 + 160.0 * i as f64, 90.0 + 165.0 * j as f64);
                let z = 50.0 + ((i * 5 + j * 7) % 12) as f64 * 160.0;
                let g: GroundM = l.image_to_ground(q, z).unwrap();
                let Some(q2) = r.ground_to_image(g) else {
                    continue;
                };
                if !(0.0..2000.0).contains(&q2.col) || !(0.0..2000.0).contains(&q2.row) {
                    continue;
                }
                // Measuring noise of 0.3 px (as matching), the same for both routes.
                let e = |k: usize| 0.3 * (((i * 31 + j * 17 + k * 13) % 21) as f64 / 10.0 - 1.0);
                let (ln, rn) = (
                    PixelXY::new(q.col + e(0), q.row + e(1)),
                    PixelXY::new(q2.col + e(2), q2.row + e(3)),
                );
                for (k, t) in Triplet::ALL.iter().enumerate() {
                    let (Some(a), Some(b)) = (
                        maps.height(*t, ln, rn),
                        rigorous_height(&l, &r, *t, ln, rn, heights),
                    ) else {
                        continue;
                    };
                    // Metres per pixel of this triplet's coordinate.
                    let m_per_px = 1.0 / maps.px_per_m(*t, ln, rn, b);
                    worst[k] = worst[k].max((a - b).abs() / m_per_px);
                }
                pts.push((q, q2, z));
                noisy.push((ln, rn, z));
            }
        }
        assert!(pts.len() > 100, "{} points", pts.len());
        for (k, t) in Triplet::ALL.iter().enumerate() {
            eprintln!(
                "{}: mapping functions against the rigorous triplet: {:.2e} of the metres per pixel",
                t.name(),
                worst[k]
            );
        }
        // The strong triplets agree within 1 % of a pixel's worth of height.
        assert!(worst[0] <= 0.01 && worst[1] <= 0.01, "{worst:?}");
        let exact = assess(&maps, &pts);
        let report = assess(&maps, &noisy);
        for r in exact.iter().chain(&report) {
            eprintln!("{r:?}");
        }
        // Noise-free, the strong triplets find the height (the mappings are exact enough).
        assert!(exact[..2].iter().all(|r| r.rms_m < 0.05), "{exact:?}");
        // With noise the base decides: the x-triplets within a few metres, the y-triplets
        // tens of times worse, and named.
        let (x, y) = (&report[0], &report[2]);
        assert!(x.rms_m < 5.0 && x.warning.is_none(), "{x:?}");
        assert!(report[1].warning.is_none());
        assert!(
            y.warning.is_some() && report[3].warning.is_some(),
            "{report:?}"
        );
        let y_rms = |r: &TripletReport| if r.points > 0 { r.rms_m } else { f64::INFINITY };
        assert!(
            y_rms(y) > 10.0 * x.rms_m || y.points < report[0].points / 2,
            "{report:?}"
        );
    }
}
