//! Homing: `$H` answered `ok` only when the cycle has ended; the host waits within a bound
//! from the board's own travel, rates and pull-off, and probes with `?` only after a while.

use super::report;
use super::*;

impl GrblController {
    /// One `?` during a homing wait: the state of a report that arrives within the reply time,
    /// if it is not `Home` (the cycle is over); `None` when GRBL is silent or still homing. Any
    /// report is taken, believed or not: GRBL answers a question asked during the cycle only
    /// when the cycle ends, as a `Home` report, so one in any other state was made after it
    /// (and waiting for a line reply to vouch for it could wait forever when the `$H`'s `ok`
    /// was lost).
    pub(super) fn homing_probe(&mut self) -> Result<Option<String>> {
        self.latest_report = None;
        self.port.write_all(b"?")?;
        let deadline = Instant::now() + REPLY_TIMEOUT;
        while Instant::now() < deadline && self.latest_report.is_none() && self.replies.is_empty() {
            self.pump(deadline.min(Instant::now() + POLL))?;
        }
        let Some(line) = self.latest_report.take() else {
            // Ignored, or it may yet be answered late: later reports need a resync first.
            self.stale_reports = true;
            return Ok(None);
        };
        self.last_report = None;
        Ok(report::parse(&line)
            .map(|r| r.state)
            .filter(|s| !s.starts_with("Home")))
    }

    /// A soft reset and its banner (see [`Self::soft_reset`]); the board is settled after it.
    pub(super) fn reset_and_wait(&mut self) -> Result<()> {
        self.soft_reset()?;
        self.settled = Some(StopAction::Reset);
        Ok(())
    }

    /// The homing wait: GRBL answers `$H` when the cycle has ended and may say nothing before;
    /// `ok`, `error:n`, `ALARM:n` or a banner end it. A noisy line can lose that answer, so
    /// after [`HOMING_PROBE_AFTER`] a `?` is sent every [`HOMING_PROBE_EVERY`]: GRBL may ignore
    /// it during the cycle (or answer it late, still `Home`), but a report in any other state
    /// means the cycle is over — `Idle` homed (its `ok` was lost), `Alarm` failed.
    pub(super) fn wait_homed(&mut self, timeout: Duration) -> Result<StageStatus> {
        let start = Instant::now();
        let deadline = start + timeout;
        let mut probe_at = start + HOMING_PROBE_AFTER;
        let over = loop {
            match self.wait_reply(deadline.min(probe_at))? {
                Some(Reply::Ok) => break None,
                Some(Reply::Error(n)) => {
                    self.homing = false;
                    return Err(StageError::Rejected {
                        command: "$H".into(),
                        reason: format!("error:{n} ({})", error_meaning(n)),
                    });
                }
                // Stopping (a reset, which alone ends a homing cycle) is the driver's decision.
                None if Instant::now() >= deadline => {
                    return Err(StageError::MotionTimeout { after: timeout })
                }
                None => {}
            }
            probe_at = Instant::now() + HOMING_PROBE_EVERY;
            if let Some(state) = self.homing_probe()? {
                break Some(state);
            }
        };
        if let Some(state) = over {
            if state.starts_with("Alarm") {
                self.homing = false;
                return Err(StageError::Fault {
                    kind: FaultKind::Alarm {
                        code: self.alarm.unwrap_or(0),
                        meaning: "the homing cycle ended in Alarm (its ALARM line was lost)".into(),
                    },
                    position: None,
                });
            }
            // Idle: the `ok` was lost on the line, or is still on its way: it must not answer a
            // later command, so it is waited for briefly and set aside. The checks below then
            // decide as for an `ok`.
            let _ = self.wait_reply(Instant::now() + REPLY_TIMEOUT)?;
            self.replies.clear();
        }
        self.homing = false;
        self.inflight.clear();
        let first = self.status_once()?;
        let st = self.agreed_status(first)?;
        if st.controller_state != "Idle" {
            return Err(StageError::Protocol(format!(
                "homing answered `ok` but GRBL is {}",
                st.controller_state
            )));
        }
        // Referenced again, old alarms void.
        self.homed = true;
        self.alarm = None;
        // GRBL 1.1 sets the position after the pull-off to −$27 (+ switch) or −$130 + $27 (−
        // switch): anything else means the board's frame is not the documented one.
        let want = self.settings().home_position();
        let off = st.position - want;
        if off.x.abs() > 50.0 || off.y.abs() > 50.0 {
            self.homed = false;
            return Err(StageError::Protocol(format!(
                "after homing GRBL reports {}, where GRBL 1.1 puts the carriage at {want} \
                 ($23 homing directions, $27 pull-off, $130/$131 travel). A board built with \
                 HOMING_FORCE_SET_ORIGIN, or whose settings do not match its switches, cannot be \
                 used: see `rig stage check-setup`",
                st.position
            )));
        }
        Ok(StageStatus {
            homed: true,
            state: StageState::Idle,
            ..st
        })
    }
}
