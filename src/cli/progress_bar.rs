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

/// A drive's steps for the operator: a series (the grid, the crosses, the fiducials, the
/// tiles, the bands of a mosaic) as a bar with its rate and time left, single steps as lines
/// above it. On a terminal only; otherwise one line per step on standard error, or nothing
/// with `--json`.
pub struct Steps {
    bar: Option<ProgressBar>,
    tty: bool,
    json: bool,
}

impl Steps {
    pub fn new(json: bool) -> Steps {
        Steps {
            bar: None,
            tty: std::io::stderr().is_terminal(),
            json,
        }
    }

    /// Step `what`; `of` = (k, n): the k-th (from 1) of a series of n.
    pub fn step(&mut self, what: &str, of: Option<(usize, usize)>) {
        if self.json {
            return;
        }
        if !self.tty {
            eprintln!("{what}");
            return;
        }
        match of {
            Some((k, n)) => {
                let (k, n) = (k as u64, n as u64);
                let same = self
                    .bar
                    .as_ref()
                    .is_some_and(|b| b.length() == Some(n) && b.position() < k);
                if !same {
                    self.finish();
                    let b = ProgressBar::with_draw_target(Some(n), ProgressDrawTarget::stderr());
                    if let Ok(style) = ProgressStyle::with_template(
                        "[{bar:30}] {pos}/{len} ({per_sec}, {eta} left) {msg}",
                    ) {
                        b.set_style(style.progress_chars("=> "));
                    }
                    self.bar = Some(b);
                }
                if let Some(b) = &self.bar {
                    // The steps before this one are done.
                    b.set_position(k.saturating_sub(1));
                    b.set_message(what.to_string());
                }
            }
            None => match &self.bar {
                Some(b) => b.println(what),
                None => eprintln!("{what}"),
            },
        }
    }

    /// The series is over: the bar is cleared.
    pub fn finish(&mut self) {
        if let Some(b) = self.bar.take() {
            b.finish_and_clear();
        }
    }
}

impl Drop for Steps {
    fn drop(&mut self) {
        self.finish();
    }
}
