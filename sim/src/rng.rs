//! A small, version-stable PRNG (SplitMix64) so that `--seed` replays a run exactly,
//! whatever crate versions are in the lock file.

#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed ^ 0x9E37_79B9_7F4A_7C15)
    }

    /// The generator `n` draws further on (SplitMix64's state advances by a constant a draw),
    /// so that parts of one stream can be drawn in parallel and still give the same numbers.
    pub fn jumped(&self, n: u64) -> Rng {
        Rng(self.0.wrapping_add(n.wrapping_mul(0x9E37_79B9_7F4A_7C15)))
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        p > 0.0 && self.uniform() < p
    }

    /// Two independent standard normals (Box–Muller: the cosine and the sine of one draw).
    pub fn normal_pair(&mut self) -> [f64; 2] {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        let r = (-2.0 * u1.ln()).sqrt();
        let (s, c) = (2.0 * std::f64::consts::PI * u2).sin_cos();
        [r * c, r * s]
    }

    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }

    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n.max(1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_pairs_are_standard_and_independent() {
        let mut r = Rng::new(7);
        let n = 200_000;
        let (mut s, mut ss, mut sab) = ([0.0f64; 2], [0.0f64; 2], 0.0);
        for _ in 0..n {
            let [a, b] = r.normal_pair();
            s = [s[0] + a, s[1] + b];
            ss = [ss[0] + a * a, ss[1] + b * b];
            sab += a * b;
        }
        let nf = n as f64;
        for k in 0..2 {
            // Mean 0 ± 4 standard errors (1/√n), variance 1 ± 4·√(2/n).
            assert!((s[k] / nf).abs() < 4.0 / nf.sqrt(), "mean {}", s[k] / nf);
            assert!(
                (ss[k] / nf - 1.0).abs() < 4.0 * (2.0 / nf).sqrt(),
                "var {}",
                ss[k] / nf
            );
        }
        assert!(
            (sab / nf).abs() < 4.0 / nf.sqrt(),
            "correlation {}",
            sab / nf
        );
    }
}
