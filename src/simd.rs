//! Code built per CPU: for AVX-512 (F, BW, VL, DQ) and for AVX2, the one chosen at run time
//! that the CPU has, and for the baseline x86-64 target (SSE2) everywhere else. The default
//! build must run on any x86-64 machine, and the hot loops (the plane sweep, block matching,
//! SGM, frame averaging) run about a third faster on AVX2's eight lanes than on SSE2's four,
//! and block matching another 15 % faster on AVX-512's sixteen (on an AMD Zen 5). Every build
//! does the same operations (no fused multiply-add), so they give the same numbers.

use std::sync::atomic::{AtomicU8, Ordering};

/// The instruction sets a build is chosen by, in ascending order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Level {
    Baseline = 0,
    Avx2 = 1,
    Avx512 = 2,
}

impl Level {
    pub const NAMES: &'static str = "baseline, avx2, avx512";

    /// `baseline`, `avx2` or `avx512` (any case).
    pub fn parse(s: &str) -> Option<Level> {
        match s.trim().to_ascii_lowercase().as_str() {
            "baseline" | "sse2" => Some(Level::Baseline),
            "avx2" => Some(Level::Avx2),
            "avx512" => Some(Level::Avx512),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Level::Baseline => "baseline",
            Level::Avx2 => "avx2",
            Level::Avx512 => "avx512",
        }
    }
}

static CEILING: AtomicU8 = AtomicU8::new(Level::Avx512 as u8);

/// Uses no build above `l` from now on (to compare the builds, or to rule one out): the
/// binary sets it from `RIG_SIMD`.
pub fn limit(l: Level) {
    CEILING.store(l as u8, Ordering::Relaxed);
}

/// The best build this CPU has, below the limit.
pub fn level() -> Level {
    let ceiling = match CEILING.load(Ordering::Relaxed) {
        0 => Level::Baseline,
        1 => Level::Avx2,
        _ => Level::Avx512,
    };
    detected().min(ceiling)
}

/// The best build this CPU has (the standard library caches the answers).
fn detected() -> Level {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::is_x86_feature_detected as has;
        if has!("avx512f") && has!("avx512bw") && has!("avx512vl") && has!("avx512dq") {
            return Level::Avx512;
        }
        if has!("avx2") {
            return Level::Avx2;
        }
    }
    Level::Baseline
}

/// `built_per_cpu!(fn name[generics](args) -> ret = body;)` defines `name`, which calls
/// `body` (an `#[inline(always)]` function with the same arguments) compiled for the best of
/// [`level`]'s builds, else as built. Attributes before `fn` go on `name`.
macro_rules! built_per_cpu {
    ($(#[$m:meta])* $vis:vis fn $name:ident [$($gen:tt)*] ($($arg:ident : $ty:ty),* $(,)?) $(-> $ret:ty)? = $body:ident;) => {
        $(#[$m])*
        $vis fn $name<$($gen)*>($($arg: $ty),*) $(-> $ret)? {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq,avx2")]
                $(#[$m])*
                unsafe fn avx512<$($gen)*>($($arg: $ty),*) $(-> $ret)? {
                    $body($($arg),*)
                }
                #[target_feature(enable = "avx2")]
                $(#[$m])*
                unsafe fn avx2<$($gen)*>($($arg: $ty),*) $(-> $ret)? {
                    $body($($arg),*)
                }
                match $crate::simd::level() {
                    // SAFETY: `level` names only builds whose features the CPU has.
                    $crate::simd::Level::Avx512 => return unsafe { avx512($($arg),*) },
                    // SAFETY: as above.
                    $crate::simd::Level::Avx2 => return unsafe { avx2($($arg),*) },
                    $crate::simd::Level::Baseline => {}
                }
            }
            $body($($arg),*)
        }
    };
}
