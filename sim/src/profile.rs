//! Trapezoidal velocity profile along a path of length `len`, starting at speed `v0`.

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Profile {
    pub len: f64,
    v0: f64,
    vp: f64,
    acc: f64,
    dec: f64,
    t1: f64,
    t2: f64,
    pub duration: f64,
}

impl Profile {
    /// Accelerate from `v0` toward `vmax` at `a`, cruise, decelerate at `a` to stop at `len`.
    /// If `v0` is already too fast to stop within `len`, decelerates harder (a stop request
    /// plans exactly `v0²/2a`, so this only absorbs rounding).
    pub fn new(len: f64, v0: f64, vmax: f64, a: f64) -> Profile {
        let len = len.max(0.0);
        let v0 = v0.max(0.0);
        if len == 0.0 {
            return Profile {
                len,
                v0: 0.0,
                vp: 0.0,
                acc: a,
                dec: a,
                t1: 0.0,
                t2: 0.0,
                duration: 0.0,
            };
        }
        let stop_dist = v0 * v0 / (2.0 * a);
        if stop_dist >= len {
            let dec = v0 * v0 / (2.0 * len);
            let t = v0 / dec;
            return Profile {
                len,
                v0,
                vp: v0,
                acc: a,
                dec,
                t1: 0.0,
                t2: 0.0,
                duration: t,
            };
        }
        let vmax = vmax.max(v0);
        let d_full = (vmax * vmax - v0 * v0) / (2.0 * a) + vmax * vmax / (2.0 * a);
        let vp = if d_full <= len {
            vmax
        } else {
            ((2.0 * a * len + v0 * v0) / 2.0).sqrt()
        };
        let t1 = (vp - v0) / a;
        let d1 = (vp * vp - v0 * v0) / (2.0 * a);
        let d3 = vp * vp / (2.0 * a);
        let cruise = (len - d1 - d3).max(0.0) / vp;
        let t2 = t1 + cruise;
        Profile {
            len,
            v0,
            vp,
            acc: a,
            dec: a,
            t1,
            t2,
            duration: t2 + vp / a,
        }
    }

    /// Standing still for `seconds` (a dwell).
    pub fn dwell(seconds: f64) -> Profile {
        Profile {
            duration: seconds.max(0.0),
            ..Profile::new(0.0, 0.0, 1.0, 1.0)
        }
    }

    /// The first time at which the distance covered reaches `s` (bisection on the monotonic
    /// profile); `None` if the profile never gets that far.
    pub fn time_at(&self, s: f64) -> Option<f64> {
        if s > self.len {
            return None;
        }
        let (mut lo, mut hi) = (0.0, self.duration);
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            if self.at(mid).0 >= s {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        Some(hi)
    }

    /// Distance and speed `t` seconds after the start.
    pub fn at(&self, t: f64) -> (f64, f64) {
        if t <= 0.0 {
            return (0.0, self.v0);
        }
        if t >= self.duration {
            return (self.len, 0.0);
        }
        if t < self.t1 {
            return (self.v0 * t + 0.5 * self.acc * t * t, self.v0 + self.acc * t);
        }
        let d1 = self.v0 * self.t1 + 0.5 * self.acc * self.t1 * self.t1;
        if t < self.t2 {
            return (d1 + self.vp * (t - self.t1), self.vp);
        }
        let d2 = d1 + self.vp * (self.t2 - self.t1);
        let u = t - self.t2;
        (
            (d2 + self.vp * u - 0.5 * self.dec * u * u).min(self.len),
            (self.vp - self.dec * u).max(0.0),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reaches_length_and_stops() {
        for &(len, v0) in &[(10.0, 0.0), (10_000.0, 0.0), (1.0, 0.0), (500.0, 300.0)] {
            let p = Profile::new(len, v0, 1000.0, 5000.0);
            let (s, v) = p.at(p.duration);
            assert!((s - len).abs() < 1e-9 && v == 0.0);
            // Monotonic and never faster than allowed.
            let mut last = 0.0;
            for i in 0..=100 {
                let (s, v) = p.at(p.duration * i as f64 / 100.0);
                assert!(s + 1e-9 >= last && v <= 1000.0 + 1e-9);
                last = s;
            }
        }
    }

    #[test]
    fn long_move_duration_closed_form() {
        // d = 10 000, v = 1000, a = 5000: t = d/v + v/a = 10.2 s.
        let p = Profile::new(10_000.0, 0.0, 1000.0, 5000.0);
        assert!((p.duration - 10.2).abs() < 1e-9);
        // Short move never reaches vmax: t = 2 sqrt(d/a).
        let p = Profile::new(20.0, 0.0, 1000.0, 5000.0);
        assert!((p.duration - 2.0 * (20.0f64 / 5000.0).sqrt()).abs() < 1e-9);
    }
}
