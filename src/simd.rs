//! Code built twice: for AVX2, chosen at run time where the CPU has it, and for the baseline
//! x86-64 target (SSE2) everywhere else. The default build must run on any x86-64 machine, and
//! the hot loops (the plane sweep, SGM, frame averaging) run about a third faster on AVX2's
//! eight lanes. Both builds do the same operations (no fused multiply-add), so they give the
//! same numbers.

/// `built_twice!(fn name[generics](args) -> ret = body;)` defines `name`, which calls
/// `body` (an `#[inline(always)]` function with the same arguments) compiled with AVX2 where
/// the CPU has it, else as built. Attributes before `fn` go on `name`.
macro_rules! built_twice {
    ($(#[$m:meta])* $vis:vis fn $name:ident [$($gen:tt)*] ($($arg:ident : $ty:ty),* $(,)?) $(-> $ret:ty)? = $body:ident;) => {
        $(#[$m])*
        $vis fn $name<$($gen)*>($($arg: $ty),*) $(-> $ret)? {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx2")]
                $(#[$m])*
                unsafe fn avx2<$($gen)*>($($arg: $ty),*) $(-> $ret)? {
                    $body($($arg),*)
                }
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: the CPU has AVX2, checked just above.
                    return unsafe { avx2($($arg),*) };
                }
            }
            $body($($arg),*)
        }
    };
}
