//! The 2×2 algebra of affine transformations `x = a0 + a1·c + a2·r, y = b0 + b1·c + b2·r`
//! (parameters in that order): the one place their linear part is inverted, for the
//! calibrations, the scan's photo → pixel chain and least-squares matching alike.

/// The inverse of a 2×2 matrix; `None` when it is singular.
pub fn inv2(m: [[f64; 2]; 2]) -> Option<[[f64; 2]; 2]> {
    let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
    (det.abs() > 1e-12).then(|| {
        [
            [m[1][1] / det, -m[0][1] / det],
            [-m[1][0] / det, m[0][0] / det],
        ]
    })
}

/// `m·v`.
pub fn mul2(m: [[f64; 2]; 2], v: [f64; 2]) -> [f64; 2] {
    [
        m[0][0] * v[0] + m[0][1] * v[1],
        m[1][0] * v[0] + m[1][1] * v[1],
    ]
}

/// The product of two 2×2 matrices.
pub fn mul22(a: [[f64; 2]; 2], b: [[f64; 2]; 2]) -> [[f64; 2]; 2] {
    [
        [
            a[0][0] * b[0][0] + a[0][1] * b[1][0],
            a[0][0] * b[0][1] + a[0][1] * b[1][1],
        ],
        [
            a[1][0] * b[0][0] + a[1][1] * b[1][0],
            a[1][0] * b[0][1] + a[1][1] * b[1][1],
        ],
    ]
}

/// The 2×2 part of affine parameters a0, a1, a2, b0, b1, b2.
pub fn linear_part(p: &[f64; 6]) -> [[f64; 2]; 2] {
    [[p[1], p[2]], [p[4], p[5]]]
}

/// The linear part's inverse applied to `d` (NaN when it is singular).
pub fn solve_linear(p: &[f64; 6], d: [f64; 2]) -> [f64; 2] {
    inv2(linear_part(p)).map_or([f64::NAN; 2], |m| mul2(m, d))
}
