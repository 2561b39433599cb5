//! A harness for the tests that mostly wait (on a simulated board's homing, its timeouts, a
//! stop's confirmation, a pseudo-terminal's replies): libtest runs two tests at a time on a
//! two-core machine, which leaves it idle for most of their time. These run sixteen at a time
//! (or as many as `--test-threads` or `RUST_TEST_THREADS` say), each on its own simulator, all
//! in one binary (`tests/controllers.rs`), so that they also wait beside one another.

/// One module's tests: name and function (a panic fails the test).
pub type Tests = &'static [(&'static str, fn())];

/// Runs the tests of `groups` (module name, its tests), named `module::test`, with libtest's
/// arguments, and exits.
pub fn run(groups: &[(&'static str, Tests)]) -> ! {
    let mut args = libtest_mimic::Arguments::from_args();
    let from_env = std::env::var("RUST_TEST_THREADS")
        .ok()
        .and_then(|v| v.parse().ok());
    args.test_threads = args.test_threads.or(from_env).or(Some(16));
    let trials = groups
        .iter()
        .flat_map(|&(module, tests)| {
            tests.iter().map(move |&(name, f)| {
                libtest_mimic::Trial::test(format!("{module}::{name}"), move || {
                    f();
                    Ok(())
                })
            })
        })
        .collect();
    libtest_mimic::run(&args, trials).exit()
}

/// `pub const TESTS`: the named test functions, for [`run`].
#[macro_export]
macro_rules! waiting_tests {
    ($($f:ident),* $(,)?) => {
        pub const TESTS: $crate::common::waiting::Tests = &[$((stringify!($f), $f as fn())),*];
    };
}
