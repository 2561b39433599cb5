//! The normalised cross-correlation (Pearson's coefficient) of two equally long series of grey
//! values: how the rig scores a match everywhere it compares two patches as a whole.

/// The correlation of `a` and `b` (equally long), from −1 to 1; 0 when either is flat.
/// Two passes (means first), so that large grey values lose no digits.
pub fn ncc(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    if n == 0 {
        return 0.0;
    }
    let (a, b) = (&a[..n], &b[..n]);
    let (ma, mb) = (
        a.iter().sum::<f64>() / n as f64,
        b.iter().sum::<f64>() / n as f64,
    );
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        let (dx, dy) = (x - ma, y - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    if saa <= 0.0 || sbb <= 0.0 {
        return 0.0;
    }
    sab / (saa * sbb).sqrt()
}

#[cfg(test)]
mod tests {
    use super::ncc;

    #[test]
    fn closed_forms() {
        let x = [1.0, 2.0, 4.0, 8.0, 16.0];
        let lin: Vec<f64> = x.iter().map(|v| 3.0 * v + 40_000.0).collect();
        assert!((ncc(&x, &lin) - 1.0).abs() < 1e-12);
        let neg: Vec<f64> = x.iter().map(|v| -v).collect();
        assert!((ncc(&x, &neg) + 1.0).abs() < 1e-12);
        // (1,2,3) with (1,3,2): covariance 0.5 over variances 1 and 1 (sums of squares 2, 2).
        assert!((ncc(&[1.0, 2.0, 3.0], &[1.0, 3.0, 2.0]) - 0.5).abs() < 1e-12);
        assert_eq!(ncc(&x, &[5.0; 5]), 0.0);
        assert_eq!(ncc(&[], &[]), 0.0);
    }
}
