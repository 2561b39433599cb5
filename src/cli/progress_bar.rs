//! The core's progress drawn as an `indicatif` bar on standard error: the step's name, a bar,
//! the count, the rate and the time left; hidden when standard error is not a terminal or the
//! output is `--json`, so scripts and logs get none of it.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use rig::matching::progress::Progress;
use std::io::IsTerminal;
use std::sync::Mutex;

pub struct Bar {
    bar: Mutex<Option<ProgressBar>>,
    shown: bool,
}

impl Bar {
    /// A bar drawn only when `wanted` and standard error is a terminal.
    pub fn new(wanted: bool) -> Bar {
        Bar {
            bar: Mutex::new(None),
            shown: wanted && std::io::stderr().is_terminal(),
        }
    }
}

impl Progress for Bar {
    fn begin(&self, what: &str, total: u64) {
        let b = ProgressBar::with_draw_target(
            Some(total),
            if self.shown {
                ProgressDrawTarget::stderr()
            } else {
                ProgressDrawTarget::hidden()
            },
        );
        if let Ok(style) =
            ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} ({per_sec}, {eta} left)")
        {
            b.set_style(style.progress_chars("=> "));
        }
        b.set_message(what.to_string());
        if let Ok(mut g) = self.bar.lock() {
            *g = Some(b);
        }
    }

    fn advance(&self, n: u64) {
        if let Ok(g) = self.bar.lock() {
            if let Some(b) = g.as_ref() {
                b.inc(n);
            }
        }
    }

    fn end(&self) {
        if let Ok(mut g) = self.bar.lock() {
            if let Some(b) = g.take() {
                b.finish_and_clear();
            }
        }
    }
}
