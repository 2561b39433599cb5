//! Usage errors that the commands' own checks find (a value out of range, a flag this case
//! needs): they exit [`rig::exit::USAGE`], 2, as the parser's own do, whoever rejects the
//! input (`exit_code_of`). The message names the flag and the allowed values.

/// A flag or value the command cannot use; the message says what to give instead.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct UsageError(pub String);

/// Returns from the enclosing function with a [`UsageError`] of this message (`format!`
/// arguments), as `anyhow::bail!` does with any error.
macro_rules! usage_bail {
    ($($arg:tt)*) => {
        return Err(anyhow::Error::new($crate::cli::usage::UsageError(format!($($arg)*))))
    };
}
pub(crate) use usage_bail;

/// A value of a flag that did not parse: a [`UsageError`] naming the flag, with the cause.
pub trait OrUsage<T> {
    fn or_usage(self, what: impl FnOnce() -> String) -> anyhow::Result<T>;
}

impl<T, E: std::fmt::Display> OrUsage<T> for Result<T, E> {
    fn or_usage(self, what: impl FnOnce() -> String) -> anyhow::Result<T> {
        self.map_err(|e| anyhow::Error::new(UsageError(format!("{}: {e}", what()))))
    }
}
