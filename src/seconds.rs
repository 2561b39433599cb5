//! Seconds from a number (a flag, a setting, a controller's rates, a device's clock) as a
//! `Duration`, written once and never a panic, with the two policies the rig needs: a wait is
//! clamped (negative waits nothing; NaN, infinite or above [`LONGEST_WAIT`] waits the longest,
//! and an absolute cap applies anyway), a clock reading is refused when it cannot be one
//! (negative, not finite, or more than a year).

use std::time::Duration;

/// The longest wait the rig ever computes: a day.
pub const LONGEST_WAIT: Duration = Duration::from_secs(86_400);

/// The latest a clock reading may be, s (about a year of uptime).
const LATEST_CLOCK_S: f64 = 3.2e7;

/// A wait of `t` seconds, clamped to 0 … [`LONGEST_WAIT`].
pub fn wait(t: f64) -> Duration {
    if t.is_nan() {
        return LONGEST_WAIT;
    }
    Duration::try_from_secs_f64(t.max(0.0)).map_or(LONGEST_WAIT, |d| d.min(LONGEST_WAIT))
}

/// A clock reading of `t` seconds; `None` when it cannot be one.
pub fn clock(t: f64) -> Option<Duration> {
    if (0.0..=LATEST_CLOCK_S).contains(&t) {
        Duration::try_from_secs_f64(t).ok()
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn waits_clamp_and_clocks_refuse() {
        assert_eq!(wait(f64::NAN), LONGEST_WAIT);
        assert_eq!(wait(-3.0), Duration::ZERO);
        assert_eq!(wait(f64::INFINITY), LONGEST_WAIT);
        assert_eq!(wait(1e300), LONGEST_WAIT);
        assert_eq!(wait(1.5), Duration::from_millis(1500));
        assert_eq!(clock(2.25), Some(Duration::from_millis(2250)));
        for bad in [-1e-9, f64::NAN, f64::INFINITY, 4e7] {
            assert_eq!(clock(bad), None, "{bad}");
        }
    }
}
