//! GRBL's line protocol: character-counting streaming within the 128-byte receive buffer,
//! every line classified as it arrives (replies, reports, alarms, messages), commands with their
//! `ok`, and a silent board reported as such.

use super::*;

impl GrblController {
    /// Reads what the line has until `deadline`, sorting complete lines into replies, alarms,
    /// reports and garbage.
    pub(super) fn pump(&mut self, deadline: Instant) -> Result<()> {
        let mut bytes = Vec::new();
        self.port.read_until(deadline, &mut bytes)?;
        if self.heard.len() < 200 {
            self.heard.extend_from_slice(&bytes[..bytes.len().min(200)]);
        }
        self.rx.extend_from_slice(&bytes);
        while let Some(nl) = self.rx.iter().position(|&b| b == b'\n') {
            let raw: Vec<u8> = self.rx.drain(..=nl).collect();
            let line = String::from_utf8_lossy(&raw).trim().to_string();
            self.classify(line);
        }
        if self.rx.len() > 512 {
            self.rx.clear(); // no newline in 512 bytes: noise
            self.garbage_lines += 1;
        }
        Ok(())
    }

    pub(super) fn classify(&mut self, line: String) {
        if line.is_empty() {
            return;
        }
        let is_reply = line == "ok" || line.starts_with("error:");
        if is_reply || line.starts_with("ALARM:") || line.starts_with("Grbl ") {
            // Whatever a late report would have been, it came before this.
            self.stale_reports = false;
        }
        if line.starts_with('<') {
            self.latest_report = Some(line.clone());
        }
        if line == "ok" {
            self.inflight.pop_front();
            self.replies.push_back(Reply::Ok);
        } else if let Some(code) = line.strip_prefix("error:").and_then(|c| c.parse().ok()) {
            self.inflight.pop_front();
            self.replies.push_back(Reply::Error(code));
        } else if let Some(code) = line.strip_prefix("ALARM:").and_then(|c| c.parse().ok()) {
            self.alarm = Some(code);
            self.new_alarm = true;
            self.critical_pending = matches!(code, 1 | 2);
            if code != 2 {
                self.homed = false;
            }
        } else if line.starts_with("Grbl ") {
            // A (re)boot: the receive buffer and planner are empty now.
            self.reset_seen = true;
            self.critical_pending = false;
            self.inflight.clear();
            self.jogging = false;
            self.wco = None;
        } else if line.starts_with('<') && line.ends_with('>') {
            if self.stale_reports {
                self.late_reports += 1;
            } else {
                self.last_report = Some(line);
            }
        } else if line.starts_with('[') || line.starts_with('$') {
            self.info_lines.push(line);
        } else {
            self.garbage_lines += 1;
        }
    }

    /// Sends one line, waiting first until GRBL's receive buffer has room for it.
    pub(super) fn send_line(&mut self, line: &str) -> Result<()> {
        let len = line.len() + 1;
        let deadline = Instant::now() + REPLY_TIMEOUT * 4;
        while self.inflight.iter().sum::<usize>() + len > RX_BUFFER - 1 {
            if Instant::now() >= deadline {
                return Err(StageError::Timeout {
                    what: "room in GRBL's receive buffer".into(),
                    after: REPLY_TIMEOUT * 4,
                });
            }
            self.pump(Instant::now() + POLL)?;
        }
        let mut b = Vec::with_capacity(len);
        b.extend_from_slice(line.as_bytes());
        b.push(b'\n');
        self.port.write_all(&b)?;
        self.inflight.push_back(len);
        Ok(())
    }

    /// Waits for the next `ok`/`error:N`, or `None` at the deadline. A new alarm or a reset is
    /// an error.
    pub(super) fn wait_reply(&mut self, deadline: Instant) -> Result<Option<Reply>> {
        loop {
            if let Some(e) = self.take_fault() {
                return Err(e);
            }
            if let Some(r) = self.replies.pop_front() {
                return Ok(Some(r));
            }
            if Instant::now() >= deadline {
                return Ok(None);
            }
            self.pump(deadline.min(Instant::now() + POLL))?;
        }
    }

    /// Reports a new alarm or reset once.
    pub(super) fn take_fault(&mut self) -> Option<StageError> {
        if self.new_alarm || self.reset_seen {
            self.homing = false;
        }
        if self.new_alarm {
            self.new_alarm = false;
            self.reset_seen = false;
            let code = self.alarm.unwrap_or(0);
            return Some(StageError::Fault {
                kind: FaultKind::Alarm {
                    code,
                    meaning: alarm_meaning(code).into(),
                },
                position: None,
            });
        }
        if self.reset_seen {
            self.reset_seen = false;
            self.homed = false;
            return Some(StageError::Fault {
                kind: FaultKind::Reset,
                position: None,
            });
        }
        None
    }

    /// Forgets stale alarms, resets and replies before a new command.
    pub(super) fn settle_line(&mut self) -> Result<()> {
        self.pump(Instant::now())?;
        self.new_alarm = false;
        self.reset_seen = false;
        self.replies.clear();
        Ok(())
    }

    /// A `$` command answered by lines and `ok`. Idempotent: the caller may retry.
    pub(super) fn command(&mut self, cmd: &str, timeout: Duration) -> Result<Vec<String>> {
        self.info_lines.clear();
        self.replies.clear();
        self.send_line(cmd)?;
        match self.wait_reply(Instant::now() + timeout)? {
            Some(Reply::Ok) => Ok(std::mem::take(&mut self.info_lines)),
            Some(Reply::Error(n)) => Err(StageError::Rejected {
                command: cmd.into(),
                reason: format!("error:{n} ({})", error_meaning(n)),
            }),
            None => {
                self.inflight.clear();
                Err(StageError::Timeout {
                    what: cmd.into(),
                    after: timeout,
                })
            }
        }
    }

    /// Before a report may be believed after an unanswered `?`: a line reply must arrive. With
    /// nothing in flight, an empty line (answered `ok` at once by an idle GRBL) asks for one.
    pub(super) fn resync_reports(&mut self) -> Result<()> {
        if !self.stale_reports {
            return Ok(());
        }
        if self.inflight.is_empty() {
            self.send_line("")?;
        }
        let deadline = Instant::now() + REPLY_TIMEOUT * 2;
        while self.stale_reports && Instant::now() < deadline && !self.critical_pending {
            self.pump(deadline.min(Instant::now() + POLL))?;
        }
        // The marker's `ok` is no answer to anything else.
        self.replies.retain(|r| !matches!(r, Reply::Ok));
        if self.stale_reports {
            return Err(self.silence(StageError::Timeout {
                what: "GRBL (silent: a homing cycle in progress?)".into(),
                after: REPLY_TIMEOUT * 2,
            }));
        }
        Ok(())
    }

    /// Why GRBL said nothing: after a critical alarm (hard or soft limit) it answers nothing
    /// until a reset (Commands.md), so the alarm is the error; otherwise `timeout`.
    pub(super) fn silence(&mut self, timeout: StageError) -> StageError {
        if !self.critical_pending {
            return timeout;
        }
        self.new_alarm = false;
        let code = self.alarm.unwrap_or(0);
        StageError::Fault {
            kind: FaultKind::Alarm {
                code,
                meaning: alarm_meaning(code).into(),
            },
            position: None,
        }
    }
}
