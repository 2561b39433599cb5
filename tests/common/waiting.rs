//! A harness for test binaries whose tests mostly wait (on a simulated board's homing, its
//! timeouts, a stop's confirmation): libtest runs two tests at a time on a two-core machine,
//! which leaves it idle for most of their time. These run eight at a time (or as many as
//! `--test-threads` or `RUST_TEST_THREADS` say), each still on its own simulator.

/// Runs `tests` (name, function; a panic fails the test) with libtest's arguments and exits.
pub fn run(tests: &[(&'static str, fn())]) -> ! {
    let mut args = libtest_mimic::Arguments::from_args();
    let from_env = std::env::var("RUST_TEST_THREADS")
        .ok()
        .and_then(|v| v.parse().ok());
    args.test_threads = args.test_threads.or(from_env).or(Some(8));
    let trials = tests
        .iter()
        .map(|&(name, f)| {
            libtest_mimic::Trial::test(name, move || {
                f();
                Ok(())
            })
        })
        .collect();
    libtest_mimic::run(&args, trials).exit()
}

/// `fn main` running the named test functions through [`run`].
#[macro_export]
macro_rules! waiting_tests {
    ($($f:ident),* $(,)?) => {
        fn main() {
            common::waiting::run(&[$((stringify!($f), $f as fn())),*])
        }
    };
}
