//! Stopping a GRBL board so that it takes the next command.
//!
//! A feed hold (`!`) stops the motion, not GRBL's program: once the hold is complete (`Hold:0`,
//! "hold complete, ready to resume" in the interface document) its main loop is suspended
//! (protocol.c, protocol_exec_rt_suspend) and reads no line until cycle start (`~`) resumes
//! the motion or a soft reset (0x18) drops it. A `G4` sent to learn when a motion ends waits for
//! the planner to empty (mc_dwell), which it never does while held, and every line behind it
//! waits unanswered. So a stop that should not resume is: `!` at once; the wait until the board
//! stands still (`Hold:0`, Idle or Alarm: two reports that agree); a soft reset, which keeps the
//! position when nothing moves (Commands.md: "If reset while in not motion, position is
//! retained"; mc_reset raises ALARM:3 only in a motion state, a decelerating hold included);
//! its banner; and a status report after the banner compared with the one before. A homing
//! cycle ignores a feed hold: only a reset ends it (ALARM:6, not homed).
//!
//! Reports are read here as they come, without the line reply that normally vouches for them
//! (a held board answers no line); decisions rest on two that agree, and every wait is capped.

use super::report::{self as grbl_report, Report};
use super::{GrblController, POLL, REPLY_TIMEOUT};
use crate::stage::{Result, StageError, StopAction};
use std::time::{Duration, Instant};

/// How long a board may take to print its banner after a soft reset (GRBL re-initialises in
/// milliseconds).
pub(super) const BANNER_WAIT: Duration = Duration::from_millis(2500);
/// A reset whose banner has not come by then is sent again (a byte lost on a noisy line; a
/// second reset of a board that has just reset changes nothing).
const RESET_AGAIN: Duration = Duration::from_millis(800);
/// The longest a stop waits for the board to stand still, whatever its settings say (from full
/// speed a stop takes v/a: 0.2 s at 1200 mm/min and 100 mm/s²).
pub(super) const STILL_CAP: Duration = Duration::from_secs(10);
/// Added to v/a for the reports' round trips.
pub(super) const STILL_MARGIN: Duration = Duration::from_secs(1);
/// How long a report with a machine position may take to come after the banner.
const REPORT_AFTER_RESET: Duration = Duration::from_secs(2);
/// Two machine positions are the same within this, mm (GRBL prints 3 decimals in mm, 4 in
/// inches: 2.54 µm).
const SAME_MM: f64 = 0.003;

/// A machine position, mm.
type Xy = (f64, f64);

/// One report as it came, with its machine position (`None`: a WPos report before any work
/// offset was known).
pub(super) struct Look {
    pub report: Report,
    pub machine: Option<Xy>,
}

/// Where and how the board came to rest.
struct Rest {
    machine: Option<Xy>,
    /// It was moving when the stop began (a report in motion, or the position changed).
    moved: bool,
}

fn same(a: Option<Xy>, b: Option<Xy>) -> bool {
    match (a, b) {
        (Some(a), Some(b)) => (a.0 - b.0).abs() <= SAME_MM && (a.1 - b.1).abs() <= SAME_MM,
        _ => false,
    }
}

impl GrblController {
    /// One `?`, answered or not by `deadline` (and within the reply time): the report as it
    /// comes, with its machine position when it can be known.
    pub(super) fn look(&mut self, deadline: Instant) -> Result<Option<Look>> {
        self.latest_report = None;
        self.port.write_all(b"?")?;
        let until = deadline.min(Instant::now() + REPLY_TIMEOUT);
        while self.latest_report.is_none() && Instant::now() < until {
            self.pump(until.min(Instant::now() + POLL))?;
        }
        Ok(self
            .latest_report
            .take()
            .and_then(|l| grbl_report::parse(&l))
            .map(|report| Look {
                machine: self.machine_mm(&report),
                report,
            }))
    }

    /// Polls until two reports in a row agree on a still state and position; `None` if the
    /// board does not stand still by `deadline`, or if it raised a critical alarm (it then
    /// answers nothing until a reset).
    fn wait_still(&mut self, deadline: Instant) -> Result<Option<Rest>> {
        let mut prev: Option<Look> = None;
        let mut moved = false;
        while Instant::now() < deadline && !self.critical_pending {
            let Some(now) = self.look(deadline)? else {
                continue;
            };
            let (r, m) = (&now.report, now.machine);
            if !grbl_report::still(&r.state) {
                moved = true;
            }
            if matches!(r.state.as_str(), "Run" | "Jog") && prev.is_some() {
                // Not holding (GRBL answers `?` before it acts on a `!` that came with it, so
                // the first report may predate it): the `!` may have been lost on the line. A
                // second one is ignored by a board already holding.
                self.port.write_all(b"!")?;
            }
            if let Some(p) = &prev {
                if !same(p.machine, m) && p.machine.is_some() && m.is_some() {
                    moved = true;
                }
                // WPos reports need the work offset, which comes every 10th to 30th report:
                // wait for it rather than compare positions that cannot be known.
                let agree = p.report.state == r.state && p.report.pos == r.pos;
                if agree && grbl_report::still(&r.state) && m.is_some() {
                    return Ok(Some(Rest { machine: m, moved }));
                }
            }
            prev = Some(now);
            std::thread::sleep(POLL.min(deadline.saturating_duration_since(Instant::now())));
        }
        Ok(None)
    }

    /// `!`, the wait for a standstill within `still_within`, then a soft reset: the position is
    /// compared across it. Not still in time (or in a critical alarm): reset anyway; if that
    /// raised ALARM:3 or the position cannot be compared, it is lost.
    pub(super) fn hold_and_reset(&mut self, still_within: Duration) -> Result<StopAction> {
        if self.jogging {
            // Jog cancel (ignored outside a jog); `!` cancels a jog too.
            self.port.write_all(&[0x85])?;
        }
        self.port.write_all(b"!")?;
        let critical_before = self.critical_pending;
        let rest = self.wait_still(Instant::now() + still_within)?;
        let critical = critical_before || self.critical_pending;
        let (alarm, after) = self.soft_reset_confirmed()?;
        let action = match rest {
            // GRBL stopped itself on a limit alarm: its code says whether the position is kept
            // (ALARM:2, soft limit: nothing moved) or not (the alarm already cleared `homed`).
            _ if critical && alarm.is_none() => StopAction::Nothing,
            Some(rest) if alarm != Some(3) && same(rest.machine, after) => {
                if rest.moved {
                    StopAction::Decelerated
                } else {
                    StopAction::Nothing
                }
            }
            _ => {
                self.homed = false;
                StopAction::Reset
            }
        };
        tracing::debug!(?action, ?alarm, "GRBL stopped and reset");
        self.settled = Some(action);
        Ok(action)
    }

    /// A soft reset and the banner that says GRBL re-initialised (its receive buffer and
    /// planner empty): the alarm the reset raised, if any (ALARM:3 in motion, ALARM:6 in a homing
    /// cycle).
    pub(super) fn soft_reset(&mut self) -> Result<Option<u32>> {
        self.reset_seen = false;
        self.new_alarm = false;
        self.port.write_all(&[0x18])?;
        let start = Instant::now();
        let deadline = start + BANNER_WAIT;
        let mut again = start + RESET_AGAIN;
        while !self.reset_seen {
            let now = Instant::now();
            if now >= deadline {
                return Err(StageError::Timeout {
                    what: "GRBL's banner after a soft reset (0x18)".into(),
                    after: BANNER_WAIT,
                });
            }
            if now >= again {
                self.port.write_all(&[0x18])?;
                again = now + RESET_AGAIN;
            }
            self.pump(deadline.min(again).min(Instant::now() + POLL))?;
        }
        let alarm = self.new_alarm.then_some(self.alarm).flatten();
        self.reset_seen = false;
        self.new_alarm = false;
        self.homing = false;
        self.jogging = false;
        self.inflight.clear();
        self.replies.clear();
        Ok(alarm)
    }

    /// [`Self::soft_reset`], then a report from after the banner (a question asked before the
    /// reset is dropped with it): the alarm the reset raised and the machine position after it.
    pub(super) fn soft_reset_confirmed(&mut self) -> Result<(Option<u32>, Option<Xy>)> {
        let alarm = self.soft_reset()?;
        let deadline = Instant::now() + REPORT_AFTER_RESET;
        while Instant::now() < deadline {
            if let Some(Look {
                report,
                machine: Some(m),
            }) = self.look(deadline)?
            {
                tracing::debug!(state = %report.state, x = m.0, y = m.1, "GRBL after its reset");
                return Ok((alarm, Some(m)));
            }
        }
        Err(StageError::Timeout {
            what: "a GRBL status report after its soft reset".into(),
            after: REPORT_AFTER_RESET,
        })
    }

    /// A homing cycle ignores a feed hold: a reset ends it (ALARM:6, "homing fail: reset during
    /// the cycle"); the reference is then gone, and a report after the banner confirms the board
    /// answers.
    pub(super) fn abort_homing(&mut self) -> Result<StopAction> {
        self.soft_reset_confirmed()?;
        self.homed = false;
        self.settled = Some(StopAction::HomingAborted);
        Ok(StopAction::HomingAborted)
    }
}
