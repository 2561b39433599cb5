//! The unit tests' random numbers: reproducible from a seed, and no crate for them.

/// Uniform numbers in [0, 1) from `seed` (a linear congruential generator, Knuth's MMIX
/// constants, the top 53 bits).
pub fn uniform(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed;
    move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    }
}
