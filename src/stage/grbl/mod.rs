//! Client for GRBL 1.1 controllers, built to GRBL's interface documents rather than to any
//! emulator.
//!
//! - Millimetre units (`G21`), moves in machine coordinates (`G53`, so a work offset set by
//!   other software changes nothing), character-counting streaming (never more than the
//!   128-byte receive buffer in flight), `G4 P0.01` as the motion-sync point (GRBL answers it
//!   only when the planner is empty), alarms mapped to typed faults.
//! - Homing: `$H` is answered `ok` only when the cycle has ended (`ALARM:n` when it failed), and
//!   GRBL may leave `?` unanswered meanwhile, so the host does not ask; it waits for the answer
//!   within a bound from the board's own travel, seek and locate rates and pull-off. A `?`
//!   that went unanswered may be answered late (after the cycle): no report is believed until a
//!   line reply has arrived after it, so a late report never answers a later question.
//! - Connecting never resets the board (that would abort a homing cycle in progress); a silent
//!   board is reported as such.
//! - A stop always acts and leaves a board that takes the next command ([`stop`]): a feed hold
//!   at once, a soft reset once the board stands still (`Hold:0`), the position compared across
//!   it; a soft reset anyway if it does not stand still in time. What was done is reported, and a
//!   stop that was not confirmed is an error, never "stopped". A board left held, moving or busy
//!   by an earlier program is refused by [`GrblController::open`] and brought to rest by
//!   [`GrblController::open_to_stop`].
//! - Reports in MPos or WPos (`$10`; WPos + WCO), in mm or inches (`$13`); the homing switch at
//!   either end per axis (`$23`). Machine coordinates run from −max travel to 0 whichever way the
//!   board homes; the host's carriage coordinates are machine + max travel (`$130`, `$131`).
//! - Every setting used is range-checked first ([`GrblSettings::from_raw`]).

mod connect;
mod homing;
mod line;
mod report;
pub mod settings;
mod status;
mod stop;

use super::{
    Controller, ControllerInfo, FaultKind, LinkOptions, Port, Result, SetupAdvice, StageError,
    StageState, StageStatus, StopAction,
};
use crate::coords::CarriageUm;
use settings::GrblSettings;
use std::collections::{BTreeMap, VecDeque};
use std::path::Path;
use std::time::{Duration, Instant};

/// GRBL's serial receive buffer.
const RX_BUFFER: usize = 128;
const REPLY_TIMEOUT: Duration = Duration::from_millis(500);
const QUERY_TRIES: usize = 4;
const POLL: Duration = Duration::from_millis(25);
/// During a homing wait, the first `?` (GRBL may ignore it while the cycle runs) …
const HOMING_PROBE_AFTER: Duration = Duration::from_secs(2);
/// … and the next ones.
const HOMING_PROBE_EVERY: Duration = Duration::from_secs(1);
/// How long a board that was just opened may take to answer (an Arduino that resets on DTR
/// boots in about 1.5 s).
const CONNECT_WAIT: Duration = Duration::from_millis(2500);

/// GRBL 1.1's alarm codes.
pub fn alarm_meaning(code: u32) -> &'static str {
    match code {
        1 => "hard limit triggered; position lost, re-home",
        2 => "soft limit: target beyond the machine travel; position kept",
        3 => "reset while in motion; position lost, re-home",
        4 => "probe fail: not in the expected initial state",
        5 => "probe fail: did not contact",
        6 => "homing fail: reset during the cycle",
        7 => "homing fail: safety door opened",
        8 => "homing fail: could not pull off the switch",
        9 => "homing fail: switch not found",
        _ => "unknown alarm",
    }
}

/// GRBL 1.1's error codes (the ones a host can cause).
pub fn error_meaning(code: u32) -> &'static str {
    match code {
        1 => "expected command letter",
        2 => "bad number format",
        3 => "invalid $ statement",
        4 => "negative value",
        5 => "homing not enabled",
        8 => "not idle",
        9 => "locked out: alarm or jog state",
        10 => "soft limits need homing enabled",
        11 => "line too long",
        15 => "jog beyond the machine travel",
        16 => "invalid jog command",
        20 => "unsupported G-code",
        22 => "feed rate undefined",
        _ => "see GRBL's error table",
    }
}

#[derive(Debug)]
enum Reply {
    Ok,
    Error(u32),
}

/// Up to 80 bytes of what the line said, printable (for "does not speak GRBL" messages).
fn heard(bytes: &[u8]) -> String {
    let mut s: String = bytes
        .iter()
        .take(80)
        .flat_map(|&b| std::ascii::escape_default(b))
        .map(char::from)
        .collect();
    if bytes.len() > 80 {
        s.push('…');
    }
    s
}

pub struct GrblController {
    port: Port,
    rx: Vec<u8>,
    /// Lengths of the lines sent and not yet answered (character counting).
    inflight: VecDeque<usize>,
    replies: VecDeque<Reply>,
    /// The last alarm code, kept until a successful homing (or reset, for soft limits).
    alarm: Option<u32>,
    /// An alarm arrived that no wait has reported yet.
    new_alarm: bool,
    /// A boot banner arrived (reset) that no wait has reported yet.
    reset_seen: bool,
    last_report: Option<String>,
    /// `[…]` and `$N=` lines since the last command.
    info_lines: Vec<String>,
    /// GRBL does not report whether it is homed: the host tracks it.
    homed: bool,
    /// A `$H` is under way.
    homing: bool,
    /// The settings as read (`$$`) and as checked.
    pub raw_settings: BTreeMap<u32, f64>,
    settings: Option<GrblSettings>,
    info: ControllerInfo,
    /// Lines that were neither replies nor reports (line noise).
    pub garbage_lines: u64,
    /// Whether the last motion we started was a jog (no `G4` sync for those).
    jogging: bool,
    /// The last work coordinate offset, in report units (for WPos reports).
    wco: Option<[f64; 2]>,
    /// A `?` went unanswered, so a late report may still come: reports are not believed until
    /// a line reply, an alarm or a banner has arrived after it.
    stale_reports: bool,
    /// Reports discarded as possibly late.
    pub late_reports: u64,
    /// The first bytes heard on the line, for messages.
    heard: Vec<u8>,
    /// The last report heard, believed or not (the stop's wait reads reports as they come: a
    /// held board answers no line, so none can vouch for them).
    latest_report: Option<String>,
    /// A critical alarm (hard or soft limit, ALARM:1/2) arrived and no reset since: GRBL then
    /// waits for a reset and answers nothing else.
    critical_pending: bool,
    /// The board was confirmed still after this stop, and nothing that moves was sent since.
    settled: Option<StopAction>,
}

/// GRBL's state in words, for messages.
fn state_words(state: &str) -> String {
    let what = match state.split(':').next().unwrap_or("") {
        "Hold" => "in a feed hold",
        "Door" => "in a safety-door hold",
        "Run" => "moving",
        "Jog" => "jogging",
        "Home" => "homing",
        "Sleep" => "asleep",
        _ => "busy",
    };
    format!("{what} ({state})")
}

impl Controller for GrblController {
    fn info(&self) -> &ControllerInfo {
        &self.info
    }

    /// Reports carry no checksum, and one garbled digit would move the carriage 200 mm in the
    /// host's mind: every status the host decides on is two reports that agree.
    fn status(&mut self) -> Result<StageStatus> {
        let first = self.status_once()?;
        self.agreed_status(first)
    }

    fn start_move(&mut self, target: CarriageUm, speed_um_s: f64) -> Result<()> {
        self.settle_line()?;
        self.settled = None;
        self.jogging = false;
        let (x, y) = self.to_machine_mm(target);
        let f = (speed_um_s * 60.0 / 1000.0).max(1.0);
        let line = format!("G21 G90 G53 G1 X{x:.4} Y{y:.4} F{f:.1}");
        self.send_line(&line)?;
        match self.wait_reply(Instant::now() + REPLY_TIMEOUT)? {
            Some(Reply::Ok) => {}
            Some(Reply::Error(n)) => {
                return Err(StageError::Rejected {
                    command: line,
                    reason: format!("error:{n} ({})", error_meaning(n)),
                })
            }
            None => {
                // The `ok` was lost or the line was. Never resend a move: accept it only if
                // the controller shows it running or done.
                let st = self.status()?;
                if let Some(e) = self.take_fault() {
                    return Err(e);
                }
                let done_here = st.state == StageState::Idle && (st.position - target).norm() < 1.0;
                if st.state != StageState::Moving && !done_here {
                    return Err(StageError::Timeout {
                        what: line,
                        after: REPLY_TIMEOUT,
                    });
                }
                self.inflight.clear();
            }
        }
        // The sync point: GRBL answers a dwell only once the planner has run empty.
        self.send_line("G4 P0.01")
    }

    fn start_home(&mut self) -> Result<()> {
        self.settle_line()?;
        self.settled = None;
        self.jogging = false;
        if !self.settings().homing {
            return Err(StageError::Rejected {
                command: "$H".into(),
                reason: "homing is disabled on this GRBL ($22=0); see `rig stage check-setup`"
                    .into(),
            });
        }
        self.homed = false;
        self.homing = true;
        self.send_line("$H")
    }

    fn start_jog(&mut self, delta: CarriageUm, speed_um_s: f64) -> Result<()> {
        self.settle_line()?;
        self.settled = None;
        let f = (speed_um_s * 60.0 / 1000.0).max(1.0);
        let line = format!(
            "$J=G91 G21 X{:.4} Y{:.4} F{f:.1}",
            delta.x / 1000.0,
            delta.y / 1000.0
        );
        self.send_line(&line)?;
        match self.wait_reply(Instant::now() + REPLY_TIMEOUT)? {
            Some(Reply::Ok) => {
                self.jogging = true;
                Ok(())
            }
            Some(Reply::Error(n)) => Err(StageError::Rejected {
                command: line,
                reason: format!("error:{n} ({})", error_meaning(n)),
            }),
            None => Err(StageError::Timeout {
                what: line,
                after: REPLY_TIMEOUT,
            }),
        }
    }

    fn wait_done(&mut self, timeout: Duration) -> Result<StageStatus> {
        if self.homing {
            return self.wait_homed(timeout);
        }
        let deadline = Instant::now() + timeout;
        let mut idle_with_inflight: Option<Instant> = None;
        let mut stale_since: Option<Instant> = None;
        let mut error_reply = None;
        loop {
            // Replies: the dwell's `ok` is the fast path; an error is remembered.
            while let Some(r) = self.replies.pop_front() {
                if let Reply::Error(n) = r {
                    error_reply = Some(n);
                }
            }
            if let Some(e) = self.take_fault() {
                return Err(e);
            }
            if Instant::now() >= deadline {
                // Stopping is the driver's decision (it stops on every error).
                return Err(StageError::MotionTimeout { after: timeout });
            }
            if self.stale_reports && !self.inflight.is_empty() {
                // A question went unanswered: no report is believed until the next reply. If
                // the line in flight lost its answer on the wire too, none would ever come
                // (GRBL answers a line when it takes it, not when the motion ends): so after
                // a while without one, ask for one, with an empty line (answered `ok` in turn;
                // the answer lost before it is then taken as lost once the board idles).
                let since = *stale_since.get_or_insert_with(Instant::now);
                if since.elapsed() > REPLY_TIMEOUT * 2 {
                    self.send_line("")?;
                    stale_since = Some(Instant::now());
                }
                self.pump(deadline.min(Instant::now() + POLL * 4))?;
                continue;
            }
            stale_since = None;
            // GRBL answers `?` at once, ahead of lines still waiting in its buffer: only a
            // report requested after the last answer arrived speaks for those lines.
            let all_answered = self.inflight.is_empty();
            let st = self.status_once()?;
            if let Some(e) = self.take_fault() {
                return Err(e);
            }
            match st.state {
                StageState::Fault => {
                    return Err(StageError::Fault {
                        kind: st.fault.clone().unwrap_or(FaultKind::Reset),
                        position: Some(st.position),
                    })
                }
                s if s.is_moving() => idle_with_inflight = None,
                _ => {
                    // Idle: done once every line is answered, or after idling long enough that
                    // an answer must have been lost on the line.
                    let lost = match idle_with_inflight {
                        Some(t) => t.elapsed() > Duration::from_millis(400),
                        None => {
                            idle_with_inflight = Some(Instant::now());
                            false
                        }
                    };
                    // Reports carry no checksum: decide only on two that agree.
                    let st = self.agreed_status(st)?;
                    if st.state.is_moving() {
                        idle_with_inflight = None;
                    } else if all_answered || lost {
                        self.inflight.clear();
                        self.jogging = false;
                        if let Some(n) = error_reply {
                            return Err(StageError::Rejected {
                                command: "motion".into(),
                                reason: format!("error:{n} ({})", error_meaning(n)),
                            });
                        }
                        return Ok(st);
                    }
                }
            }
            self.pump(Instant::now() + POLL * 4)?;
        }
    }

    /// GRBL's stop that leaves the board taking commands (see [`stop`]): a homing cycle ends by
    /// a reset (a feed hold does not act on it); a critical alarm, which waits for a reset and
    /// answers nothing else, gets one; a board confirmed still since the last stop, with nothing
    /// sent that moves, is only looked at; otherwise a feed hold, the wait for a standstill (up
    /// to the v/a a stop from full speed takes, capped), and a soft reset.
    fn stop(&mut self) -> Result<StopAction> {
        if self.homing {
            return self.abort_homing();
        }
        if self.critical_pending {
            self.soft_reset_confirmed()?;
            self.settled = Some(StopAction::Nothing);
            return Ok(StopAction::Nothing);
        }
        if let Some(done) = self.settled {
            if let Some(seen) = self.look(Instant::now() + REPLY_TIMEOUT)? {
                let state = seen.report.state;
                if state == "Idle" || state.starts_with("Alarm") {
                    return Ok(done);
                }
            }
        }
        let v_a =
            super::secs(self.info.max_speed_um_s / self.info.accel_um_s2).min(stop::STILL_CAP);
        self.hold_and_reset(v_a + stop::STILL_MARGIN)
    }

    fn emergency_stop(&mut self) -> Result<()> {
        let r = self.reset_and_wait();
        self.homed = false;
        r
    }

    /// A reset leaves GRBL in Alarm. After a soft-limit alarm (ALARM:2) nothing moved and the
    /// position is good, so `$X` unlocks it; after any other alarm the position is lost and only
    /// homing (`$H`, which the driver sends next) may unlock it.
    fn clear_fault(&mut self) -> Result<()> {
        self.soft_reset()?;
        self.settled = Some(StopAction::Nothing);
        if self.alarm == Some(2) && self.homed {
            self.command("$X", REPLY_TIMEOUT)?;
            self.alarm = None;
        }
        Ok(())
    }
}
