//! The core's progress drawn as an `indicatif` bar on standard error: the step's name, a bar,
//! the count, the rate and the time left. When standard error is not a terminal (a run left
//! in the background with its output in a log) a plain line instead at the start, at most
//! every [`LOG_EVERY`] and at the end of each step; nothing with `--json`.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use rig::matching::progress::Progress;
use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// How often a log line is written at the most (not a terminal).
pub const LOG_EVERY: Duration = Duration::from_secs(60);

pub struct Bar {
    bar: Mutex<Option<ProgressBar>>,
    shown: bool,
    /// Lines for a log: the step's name and when the last line was written.
    log: Option<Mutex<(String, Instant)>>,
}

impl Bar {
    /// A bar drawn when `wanted` and standard error is a terminal; log lines when `wanted`
    /// and it is not.
    pub fn new(wanted: bool) -> Bar {
        let tty = std::io::stderr().is_terminal();
        Bar {
            bar: Mutex::new(None),
            shown: wanted && tty,
            log: (wanted && !tty).then(|| Mutex::new((String::new(), Instant::now()))),
        }
    }

    /// One log line for bar `b` of step `what`.
    fn log_line(what: &str, b: &ProgressBar, last: bool) {
        let (pos, len) = (b.position(), b.length().unwrap_or(0));
        let secs = b.elapsed().as_secs_f64();
        if last {
            eprintln!("{what}: {pos}/{len} done in {secs:.0} s");
        } else {
            eprintln!(
                "{what}: {pos}/{len} after {secs:.0} s ({:.2}/s, about {:.0} s left)",
                b.per_sec(),
                b.eta().as_secs_f64()
            );
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
        if let Some(Ok(mut l)) = self.log.as_ref().map(|l| l.lock()) {
            eprintln!("{what}: 0/{total}");
            *l = (what.to_string(), Instant::now());
        }
        if let Ok(mut g) = self.bar.lock() {
            *g = Some(b);
        }
    }

    fn advance(&self, n: u64) {
        if let Ok(g) = self.bar.lock() {
            if let Some(b) = g.as_ref() {
                b.inc(n);
                if let Some(Ok(mut l)) = self.log.as_ref().map(|l| l.lock()) {
                    if l.1.elapsed() >= LOG_EVERY {
                        Self::log_line(&l.0, b, false);
                        l.1 = Instant::now();
                    }
                }
            }
        }
    }

    fn end(&self) {
        if let Ok(mut g) = self.bar.lock() {
            if let Some(b) = g.take() {
                if let Some(Ok(l)) = self.log.as_ref().map(|l| l.lock()) {
                    Self::log_line(&l.0, &b, true);
                }
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
