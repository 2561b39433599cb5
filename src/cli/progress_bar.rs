//! The core's progress drawn as an `indicatif` bar on standard error: the step's name, a bar,
//! the count, the rate and the time left. When standard error is not a terminal (a run left
//! in the background with its output in a log) a plain line instead at the start, at most
//! every [`log_every`] and at the end of each step; nothing with `--json`.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use rig::matching::progress::Progress;
use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// How often a log line is written at the most (not a terminal), by default.
pub const LOG_EVERY: Duration = Duration::from_secs(60);

/// The environment variable that sets it, seconds (0.1 … 3600): a script that follows a long
/// run's time left (benches/film_scaling.py checks it against the step's real end).
pub const LOG_EVERY_VAR: &str = "RIG_LOG_EVERY_S";

/// How often a log line is written at the most: [`LOG_EVERY_VAR`] where it holds a number
/// within range, else [`LOG_EVERY`] (a bad value is said once, not obeyed).
pub fn log_every() -> Duration {
    static EVERY: std::sync::OnceLock<Duration> = std::sync::OnceLock::new();
    *EVERY.get_or_init(|| match std::env::var(LOG_EVERY_VAR) {
        Err(_) => LOG_EVERY,
        Ok(v) => match v.trim().parse::<f64>() {
            Ok(s) if (0.1..=3600.0).contains(&s) => {
                Duration::try_from_secs_f64(s).unwrap_or(LOG_EVERY)
            }
            _ => {
                eprintln!(
                    "{LOG_EVERY_VAR}={v:?} is not 0.1 … 3600 seconds: progress lines every {} s",
                    LOG_EVERY.as_secs()
                );
                LOG_EVERY
            }
        },
    })
}

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
            eprintln!("{what}: {pos}/{len} done in {secs:.1} s");
        } else {
            eprintln!(
                "{what}: {pos}/{len} after {secs:.1} s ({:.2}/s, about {:.1} s left)",
                pos as f64 / secs.max(1e-9),
                time_left(b.elapsed(), pos, len).as_secs_f64()
            );
        }
    }
}

/// The time a step has left at the rate it has kept since it began: its units are chosen to
/// cost alike (the sweep counts candidate heights and least squares in them), so the average
/// over the whole step is steadier than a recent window's (indicatif's own, which a slow first
/// band of each thread threw 50 % off).
pub fn time_left(elapsed: Duration, pos: u64, len: u64) -> Duration {
    if pos == 0 {
        return Duration::ZERO;
    }
    let s = elapsed.as_secs_f64() * (len.saturating_sub(pos)) as f64 / pos as f64;
    Duration::try_from_secs_f64(s.min(1e7)).unwrap_or(Duration::ZERO)
}

/// [`time_left`] as the bar's `{left}`.
#[derive(Clone)]
struct Left;

impl indicatif::style::ProgressTracker for Left {
    fn clone_box(&self) -> Box<dyn indicatif::style::ProgressTracker> {
        Box::new(self.clone())
    }
    fn tick(&mut self, _: &indicatif::ProgressState, _: Instant) {}
    fn reset(&mut self, _: &indicatif::ProgressState, _: Instant) {}
    fn write(&self, state: &indicatif::ProgressState, w: &mut dyn std::fmt::Write) {
        let left = time_left(state.elapsed(), state.pos(), state.len().unwrap_or(0));
        let _ = write!(w, "{}", indicatif::HumanDuration(left));
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
            ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} ({per_sec}, {left} left)")
        {
            b.set_style(style.progress_chars("=> ").with_key("left", Left));
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
                    if l.1.elapsed() >= log_every() {
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
