//! Status reports: `?` asked and believed only once a line reply has followed it, positions
//! taken to machine then carriage coordinates (MPos or WPos + WCO, mm or inches).

use super::report::{self, Report};
use super::*;

impl GrblController {
    /// `?` until a well-formed report arrives, up to `tries` questions: the report and the
    /// machine position in mm.
    pub(super) fn query(&mut self, tries: usize) -> Result<(Report, (f64, f64))> {
        // A critical alarm ends the asking: GRBL answers nothing more until a reset.
        for _ in 0..tries {
            if self.critical_pending {
                break;
            }
            self.resync_reports()?;
            self.last_report = None;
            self.port.write_all(b"?")?;
            let deadline = Instant::now() + REPLY_TIMEOUT;
            while Instant::now() < deadline && self.last_report.is_none() && !self.critical_pending
            {
                self.pump(deadline.min(Instant::now() + POLL))?;
            }
            match self.last_report.take() {
                None => self.stale_reports = true, // it may yet come, late
                Some(l) => {
                    if let Some(r) = report::parse(&l) {
                        if let Some(m) = self.machine_mm(&r) {
                            return Ok((r, m));
                        }
                    }
                }
            }
        }
        Err(self.silence(StageError::Timeout {
            what: "GRBL status report (`?`)".into(),
            after: REPLY_TIMEOUT * tries as u32,
        }))
    }

    pub(super) fn raw_status(&mut self) -> Result<(Report, (f64, f64))> {
        self.query(QUERY_TRIES)
    }

    /// The machine position of a report in mm: WPos + WCO when the board reports WPos, inches
    /// converted. `None` for WPos while the offset is unknown.
    pub(super) fn machine_mm(&mut self, r: &Report) -> Option<(f64, f64)> {
        if let Some(w) = r.wco {
            self.wco = Some(w);
        }
        let unit = if self.settings.as_ref().is_some_and(|s| s.report_inches) {
            25.4
        } else {
            1.0
        };
        let p = if r.machine {
            r.pos
        } else {
            let w = self.wco?;
            [r.pos[0] + w[0], r.pos[1] + w[1]]
        };
        Some((p[0] * unit, p[1] * unit))
    }

    pub(super) fn to_status(&self, r: &Report, mpos: (f64, f64)) -> StageStatus {
        let position = CarriageUm::new(
            mpos.0 * 1000.0 + self.info.travel.x,
            mpos.1 * 1000.0 + self.info.travel.y,
        );
        let state = r.state.as_str();
        let critical = matches!(self.alarm, Some(1) | Some(2));
        let (st, fault) = match state.split(':').next().unwrap_or("") {
            "Idle" | "Check" | "Sleep" => (
                if self.homed {
                    StageState::Idle
                } else {
                    StageState::Unhomed
                },
                None,
            ),
            "Run" => (StageState::Moving, None),
            "Jog" => (StageState::Jogging, None),
            "Home" => (StageState::Homing, None),
            "Hold" | "Door" => (StageState::Holding, None),
            "Alarm" if critical || self.homed => {
                let code = self.alarm.unwrap_or(0);
                (
                    StageState::Fault,
                    Some(FaultKind::Alarm {
                        code,
                        meaning: alarm_meaning(code).into(),
                    }),
                )
            }
            _ => (StageState::Unhomed, None),
        };
        StageStatus {
            state: st,
            position,
            homed: self.homed,
            limit_switches: r.pins.chars().filter(|c| matches!(c, 'X' | 'Y')).collect(),
            fault,
            controller_state: state.to_string(),
        }
    }

    /// Reads reports until two in a row give the same state and position.
    pub(super) fn agreed_status(&mut self, first: StageStatus) -> Result<StageStatus> {
        let mut prev = first;
        for _ in 0..QUERY_TRIES * 2 {
            let st = self.status_once()?;
            if st.position == prev.position && st.controller_state == prev.controller_state {
                return Ok(st);
            }
            prev = st;
        }
        Err(StageError::Protocol(
            "GRBL status reports disagree with each other (line noise?)".into(),
        ))
    }

    /// One report, for polling; decisions use [`Controller::status`].
    pub(super) fn status_once(&mut self) -> Result<StageStatus> {
        let (r, m) = self.raw_status()?;
        let st = self.to_status(&r, m);
        self.port.observe(st.position);
        Ok(st)
    }
}
