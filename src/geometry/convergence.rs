//! When an iteration of the geometry (a ground point from a pixel, the line of a ground point)
//! has converged: a fixed tolerance in pixels is not enough, because floating point cannot
//! always reach it. A longitude in degrees near ±180° resolves 2.8e-14°, at 80° latitude and
//! 0.31 m pixels 1.8e-9 px; a UTM northing of 8 900 km resolves 1.9e-9 m, 6e-9 px. So a step
//! is small enough when it is below the tolerance, below a few units in the last place of the
//! unknowns (the caller gives that floor in pixels), or when it stops shrinking once it is
//! far below anything that matters (a Newton step that does not at least halve is rounding).

/// Below this many pixels a step that does not halve is taken as rounding noise.
pub const STALLED_BELOW_PX: f64 = 1e-6;

/// Units in the last place the floor allows for: the residual and the Jacobian each carry a
/// few roundings.
const ULPS: f64 = 8.0;

/// The convergence test of one iteration; [`Convergence::done`] is asked after each step.
#[derive(Debug, Clone, Copy)]
pub struct Convergence {
    tolerance_px: f64,
    previous_px: f64,
    /// The last step, px (for the error of an iteration that did not converge).
    pub last_px: f64,
}

impl Convergence {
    /// A test that accepts steps below `tolerance_px`.
    pub fn new(tolerance_px: f64) -> Convergence {
        Convergence {
            tolerance_px,
            previous_px: f64::INFINITY,
            last_px: f64::INFINITY,
        }
    }

    /// Whether the iteration may stop after a step of `step_px`, the resolution of the
    /// unknowns being `ulp_px` (one unit in the last place of each, in pixels, summed).
    pub fn done(&mut self, step_px: f64, ulp_px: f64) -> bool {
        let floor = self.tolerance_px.max(ULPS * ulp_px);
        let stalled = step_px < STALLED_BELOW_PX && step_px > 0.5 * self.previous_px;
        self.previous_px = step_px;
        self.last_px = step_px;
        step_px <= floor || stalled
    }
}

/// One unit in the last place of `x` (its spacing of doubles), for the floor of
/// [`Convergence::done`].
pub fn ulp(x: f64) -> f64 {
    let a = x.abs();
    if a < f64::MIN_POSITIVE {
        return f64::MIN_POSITIVE;
    }
    f64::from_bits(a.to_bits() + 1) - a
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ulp_is_the_spacing_of_doubles() {
        assert_eq!(ulp(1.0), f64::EPSILON);
        assert_eq!(ulp(-1.0), f64::EPSILON);
        assert_eq!(ulp(180.0), 128.0 * f64::EPSILON);
        assert!(ulp(0.0) > 0.0);
    }

    #[test]
    fn a_step_stops_at_the_tolerance_the_floor_or_a_stall() {
        // Below the tolerance.
        assert!(Convergence::new(1e-9).done(5e-10, 0.0));
        // Above it, but within the floor of the unknowns' resolution.
        assert!(Convergence::new(1e-9).done(5e-9, 1e-9));
        assert!(!Convergence::new(1e-9).done(5e-9, 1e-12));
        // Shrinking quadratically: not done until small; a step that then stops shrinking is.
        let mut c = Convergence::new(1e-12);
        assert!(!c.done(1.0, 0.0));
        assert!(!c.done(1e-3, 0.0));
        assert!(!c.done(1e-7, 0.0));
        assert!(c.done(0.8e-7, 0.0));
        // A large step that does not shrink is not a stall.
        let mut c = Convergence::new(1e-9);
        assert!(!c.done(1.0, 0.0));
        assert!(!c.done(0.9, 0.0));
    }
}
