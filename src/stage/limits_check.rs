//! Numbers a controller reports about itself are input, not truth: each is range-checked before
//! the host computes a limit, a speed or a wait from it.

use super::error::{Result, StageError};

/// One setting's allowed range, inclusive unless `lo_open` (then `lo < value`).
pub struct Range {
    pub lo: f64,
    pub hi: f64,
    pub lo_open: bool,
}

impl Range {
    pub const fn closed(lo: f64, hi: f64) -> Range {
        Range {
            lo,
            hi,
            lo_open: false,
        }
    }

    /// `(0, hi]`: strictly positive.
    pub const fn positive(hi: f64) -> Range {
        Range {
            lo: 0.0,
            hi,
            lo_open: true,
        }
    }

    pub fn contains(&self, v: f64) -> bool {
        v.is_finite()
            && (if self.lo_open {
                v > self.lo
            } else {
                v >= self.lo
            })
            && v <= self.hi
    }
}

impl std::fmt::Display for Range {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let open = if self.lo_open { '(' } else { '[' };
        write!(f, "{open}{}, {}]", self.lo, self.hi)
    }
}

/// Checks `value` of the controller's setting `name` (e.g. "$110 (X max rate, mm/min)")
/// against `range`; the error names the setting, the value and the range, and says how to fix
/// it (`fix`).
pub fn check(
    dialect: &'static str,
    name: &str,
    value: f64,
    range: &Range,
    fix: &str,
) -> Result<f64> {
    if range.contains(value) {
        Ok(value)
    } else {
        Err(StageError::BadSetting {
            dialect,
            setting: name.to_string(),
            value: format!("{value}"),
            allowed: range.to_string(),
            fix: fix.to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_refuse_the_edges_they_exclude_and_every_non_number() {
        let r = Range::positive(10.0);
        assert!(r.contains(10.0) && r.contains(1e-9));
        for v in [
            0.0,
            -1.0,
            10.000_001,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ] {
            assert!(!r.contains(v), "{v}");
        }
        let c = Range::closed(0.0, 1.0);
        assert!(c.contains(0.0) && c.contains(1.0) && !c.contains(-0.1));
        let e = check("grbl", "$110 (X max rate, mm/min)", 0.0, &r, "`$110=…`").unwrap_err();
        let m = e.to_string();
        assert!(
            m.contains("$110") && m.contains("(0, 10]") && m.contains("= 0"),
            "{m}"
        );
    }
}
