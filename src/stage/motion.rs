//! Motion planning on the host: soft-limit checks, the one-direction approach that takes out
//! backlash, and how long a move may take.

use super::error::{Result, StageError};
use crate::coords::CarriageUm;
use std::time::Duration;

/// Soft limits in carriage coordinates, µm: no motion command outside them is ever sent.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SoftLimits {
    pub min: CarriageUm,
    pub max: CarriageUm,
}

impl SoftLimits {
    pub fn check(&self, p: CarriageUm) -> Result<()> {
        for (k, axis) in [(0, 'X'), (1, 'Y')] {
            let (v, lo, hi) = (p.axis(k), self.min.axis(k), self.max.axis(k));
            if !(v >= lo && v <= hi) {
                return Err(StageError::OutOfLimits {
                    axis,
                    value_mm: v / 1000.0,
                    min_mm: lo / 1000.0,
                    max_mm: hi / 1000.0,
                });
            }
        }
        Ok(())
    }

    pub fn clamp(&self, p: CarriageUm) -> CarriageUm {
        CarriageUm::new(
            p.x.clamp(self.min.x, self.max.x),
            p.y.clamp(self.min.y, self.max.y),
        )
    }

    /// The tighter of two boxes.
    pub fn intersect(&self, o: &SoftLimits) -> SoftLimits {
        SoftLimits {
            min: CarriageUm::new(self.min.x.max(o.min.x), self.min.y.max(o.min.y)),
            max: CarriageUm::new(self.max.x.min(o.max.x), self.max.y.min(o.max.y)),
        }
    }
}

/// Direction from which every target is finally approached, per axis, so the backlash is
/// always taken up on the same side.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Approach {
    /// +1 or -1 per axis; 0 disables the approach on that axis.
    pub direction: [f64; 2],
    /// How far before the target the pre-position lies; must exceed the backlash.
    pub overshoot_um: f64,
}

impl Default for Approach {
    fn default() -> Self {
        Approach {
            direction: [1.0, 1.0],
            overshoot_um: 50.0,
        }
    }
}

impl Approach {
    pub const NONE: Approach = Approach {
        direction: [0.0, 0.0],
        overshoot_um: 0.0,
    };

    /// The pre-position to visit before `target`, if the move from `from` would not end in
    /// the approach direction on some axis. It stays inside `limits`.
    pub fn pre_position(
        &self,
        from: CarriageUm,
        target: CarriageUm,
        limits: &SoftLimits,
    ) -> Option<CarriageUm> {
        let mut pre = target;
        let mut needed = false;
        for k in 0..2 {
            let d = self.direction[k];
            if d == 0.0 {
                continue;
            }
            // Moving along d by at least a hair ends right; anything else (against d, or not
            // at all, when the play may sit on either side) needs the detour.
            if (target.axis(k) - from.axis(k)) * d < 0.1 {
                pre = pre.with_axis(k, target.axis(k) - d * self.overshoot_um);
                needed = true;
            }
        }
        needed.then(|| limits.clamp(pre))
    }
}

pub use crate::seconds::{wait as secs, LONGEST_WAIT};

/// Duration of a point-to-point move of length `d` with a trapezoidal profile (speed `v`,
/// acceleration `a`): `d/v + v/a` when the cruise speed is reached, `2·sqrt(d/a)` otherwise.
/// Zero, negative or non-finite speeds and accelerations (a controller's bad settings) give
/// [`LONGEST_WAIT`], never a panic.
pub fn move_duration(d_um: f64, v_um_s: f64, a_um_s2: f64) -> Duration {
    let d = d_um.abs();
    if !(v_um_s > 0.0 && a_um_s2 > 0.0) {
        return LONGEST_WAIT;
    }
    let t = if d * a_um_s2 >= v_um_s * v_um_s {
        d / v_um_s + v_um_s / a_um_s2
    } else {
        2.0 * (d / a_um_s2).sqrt()
    };
    secs(t)
}

/// How long to wait for a motion before declaring it stuck: the expected duration (from the
/// controller's own configured rates) times a factor, plus a fixed margin for the link and
/// settling; never more than the expected duration plus a minute, and never more than the
/// operator's absolute cap.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct TimeoutPolicy {
    pub factor: f64,
    pub margin: Duration,
    /// The absolute cap on any one wait (`--timeout`).
    pub cap: Duration,
}

/// Beyond the expected duration, no wait is longer than this.
pub const MOST_OVER_EXPECTED: Duration = Duration::from_secs(60);

impl Default for TimeoutPolicy {
    fn default() -> Self {
        TimeoutPolicy {
            factor: 1.5,
            margin: Duration::from_secs(2),
            cap: Duration::from_secs(600),
        }
    }
}

impl TimeoutPolicy {
    pub fn for_duration(&self, expected: Duration) -> Duration {
        let expected = expected.min(LONGEST_WAIT);
        let scaled = secs(expected.as_secs_f64() * self.factor) + self.margin;
        scaled
            .min(expected + MOST_OVER_EXPECTED)
            .max(self.margin)
            .min(self.cap)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn box_() -> SoftLimits {
        SoftLimits {
            min: CarriageUm::new(0.0, 0.0),
            max: CarriageUm::new(100_000.0, 50_000.0),
        }
    }

    #[test]
    fn limits_refuse_outside_and_nan() {
        let l = box_();
        assert!(l.check(CarriageUm::new(0.0, 50_000.0)).is_ok());
        assert!(matches!(
            l.check(CarriageUm::new(-0.001, 0.0)),
            Err(StageError::OutOfLimits { axis: 'X', .. })
        ));
        assert!(matches!(
            l.check(CarriageUm::new(0.0, 50_000.1)),
            Err(StageError::OutOfLimits { axis: 'Y', .. })
        ));
        assert!(l.check(CarriageUm::new(f64::NAN, 0.0)).is_err());
    }

    #[test]
    fn approach_only_when_needed_and_inside_limits() {
        let a = Approach::default();
        let l = box_();
        // Moving + on both axes: no detour.
        assert_eq!(
            a.pre_position(CarriageUm::new(0.0, 0.0), CarriageUm::new(10.0, 10.0), &l),
            None
        );
        // Moving - on X: pre-position 50 µm below the target on X, Y already fine.
        let p = a
            .pre_position(
                CarriageUm::new(500.0, 0.0),
                CarriageUm::new(100.0, 10.0),
                &l,
            )
            .unwrap();
        assert_eq!(p, CarriageUm::new(50.0, 10.0));
        // Near the lower limit the detour is clamped, never outside.
        let p = a
            .pre_position(
                CarriageUm::new(500.0, 500.0),
                CarriageUm::new(20.0, 20.0),
                &l,
            )
            .unwrap();
        assert_eq!(p, CarriageUm::new(0.0, 0.0));
        assert!(Approach::NONE
            .pre_position(CarriageUm::new(500.0, 0.0), CarriageUm::new(0.0, 0.0), &l)
            .is_none());
    }

    #[test]
    fn absurd_rates_never_panic_and_every_wait_is_capped() {
        for (v, a) in [
            (0.0, 1.0),
            (-1.0, 1.0),
            (1.0, 0.0),
            (f64::INFINITY, 1.0),
            (f64::NAN, 1.0),
            (1.0, f64::NAN),
            (1e-300, 1e-300),
        ] {
            let d = move_duration(250_000.0, v, a);
            assert!(d <= LONGEST_WAIT, "{v} {a}: {d:?}");
        }
        // 1 µm/s over 250 mm is 69 hours as computed; the wait is the operator's cap.
        let p = TimeoutPolicy {
            cap: Duration::from_secs(600),
            ..TimeoutPolicy::default()
        };
        let expected = move_duration(250_000.0, 1.0, 1000.0);
        assert_eq!(p.for_duration(expected), Duration::from_secs(600));
        // A short move: factor and margin; a long one: at most a minute over the expected.
        assert_eq!(
            p.for_duration(Duration::from_secs(2)),
            Duration::from_secs(5)
        );
        assert_eq!(
            p.for_duration(Duration::from_secs(200)),
            Duration::from_secs(260)
        );
    }

    #[test]
    fn move_duration_closed_form() {
        // Long: 100 mm at 20 mm/s, 100 mm/s²: 5 + 0.2 s.
        assert!((move_duration(100_000.0, 20_000.0, 100_000.0).as_secs_f64() - 5.2).abs() < 1e-9);
        // Short: 1 mm never reaches 20 mm/s: 2·sqrt(1000/100000) = 0.2 s.
        assert!((move_duration(1000.0, 20_000.0, 100_000.0).as_secs_f64() - 0.2).abs() < 1e-9);
    }
}
