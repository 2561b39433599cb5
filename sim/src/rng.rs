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

    /// Two independent standard normals by Marsaglia and Bray's polar method (1964, SIAM
    /// Review 6(3)): a point uniform in the unit disc, scaled by √(−2 ln s / s), s its squared
    /// radius. Exact, as Box–Muller, without its sine and cosine (the simulated camera draws
    /// one normal a pixel and frame); it takes a varying number of draws (4/π pairs of
    /// uniforms on average).
    pub fn normal_pair(&mut self) -> [f64; 2] {
        loop {
            let u = 2.0 * self.uniform() - 1.0;
            let v = 2.0 * self.uniform() - 1.0;
            let s = u * u + v * v;
            if s > 0.0 && s < 1.0 {
                let f = (-2.0 * s.ln() / s).sqrt();
                return [u * f, v * f];
            }
        }
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

    /// The tails as the normal distribution's (1 − erf(x/√2) beyond ±x, the closed form), and
    /// the two of a pair independent in size too (their squares uncorrelated), as Box–Muller's:
    /// 400 000 normals, each share within 4 binomial standard errors.
    #[test]
    fn normal_pairs_have_the_normal_tails() {
        let mut r = Rng::new(11);
        let pairs = 200_000;
        let mut beyond = [0usize; 3];
        let (mut s2, mut s22, mut s2b2) = ([0.0f64; 2], [0.0f64; 2], 0.0);
        for _ in 0..pairs {
            let [a, b] = r.normal_pair();
            for z in [a, b] {
                for (k, n) in beyond.iter_mut().enumerate() {
                    *n += usize::from(z.abs() > (k + 1) as f64);
                }
            }
            for (k, z) in [a, b].into_iter().enumerate() {
                s2[k] += z * z;
                s22[k] += z.powi(4);
            }
            s2b2 += a * a * b * b;
        }
        let n = (2 * pairs) as f64;
        for (k, &count) in beyond.iter().enumerate() {
            let x = (k + 1) as f64;
            let p = 1.0 - crate::edges::erf(x / std::f64::consts::SQRT_2);
            let got = count as f64 / n;
            assert!(
                (got - p).abs() < 4.0 * (p * (1.0 - p) / n).sqrt(),
                "beyond ±{x}: {got} against {p}"
            );
        }
        // Squares: mean 1, variance 2 each; their covariance 0 ± 4 standard errors (a²b² has
        // a standard deviation of √8).
        let m = pairs as f64;
        let cov = s2b2 / m - (s2[0] / m) * (s2[1] / m);
        assert!(
            cov.abs() < 4.0 * 8f64.sqrt() / m.sqrt(),
            "cov of squares {cov}"
        );
        for k in 0..2 {
            let var = s22[k] / m - (s2[k] / m).powi(2);
            assert!((var - 2.0).abs() < 0.1, "variance of the squares {var}");
        }
    }
}
