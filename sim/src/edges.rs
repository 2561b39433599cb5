//! Edges softened by the optics: the coverage of a blurred band and disk, in closed form
//! through the error function (the camera's measuring mark, the plate's crosses, the film's
//! fiducials and marks from mark files all draw with them).

/// Fraction of a band |d| ≤ `half` that covers offset `d` after a Gaussian blur of σ `s`.
pub fn band(d: f64, half: f64, s: f64) -> f64 {
    let k = std::f64::consts::SQRT_2 * s;
    0.5 * (erf((d + half) / k) - erf((d - half) / k))
}

/// Fraction of a disk of `radius` that covers the point at `r` from its centre after a
/// Gaussian blur of σ `s` (the straight-edge approximation, good while s ≪ radius).
pub fn disk(r: f64, radius: f64, s: f64) -> f64 {
    0.5 * (1.0 - erf((r - radius) / (std::f64::consts::SQRT_2 * s)))
}

/// Error function (Abramowitz & Stegun 7.1.26, |error| < 1.5e-7).
pub fn erf(x: f64) -> f64 {
    let s = x.signum();
    let x = x.abs();
    let t = 1.0 / (1.0 + 0.327_591_1 * x);
    let y = 1.0
        - (((((1.061_405_429 * t - 1.453_152_027) * t) + 1.421_413_741) * t - 0.284_496_736) * t
            + 0.254_829_592)
            * t
            * (-x * x).exp();
    s * y
}
