//! Client for GRBL 1.1 controllers.
//!
//! Millimetre units (`G21`), absolute moves (`G90`), character-counting streaming (never more
//! than the 128-byte receive buffer in flight), `G4 P0.01` as the motion-sync point (GRBL
//! answers it only when the planner is empty), alarms mapped to typed faults. GRBL reports
//! machine coordinates that are negative after homing toward the + switches; the host maps
//! them to carriage coordinates `0..travel` by adding the max travel (`$130`, `$131`).

use super::{
    Controller, ControllerInfo, FaultKind, LinkOptions, Port, Result, SoftLimits, StageError,
    StageState, StageStatus,
};
use crate::coords::CarriageUm;
use std::collections::{BTreeMap, VecDeque};
use std::path::Path;
use std::time::{Duration, Instant};

/// GRBL's serial receive buffer.
const RX_BUFFER: usize = 128;
const REPLY_TIMEOUT: Duration = Duration::from_millis(500);
const QUERY_TRIES: usize = 4;
const POLL: Duration = Duration::from_millis(25);

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
    last_status: Option<String>,
    /// `[…]` and `$N=` lines since the last command.
    info_lines: Vec<String>,
    /// GRBL does not report whether it is homed: the host tracks it.
    homed: bool,
    /// A `$H` is under way.
    homing: bool,
    pub settings: BTreeMap<u32, f64>,
    info: ControllerInfo,
    /// Lines that were neither replies nor reports (line noise).
    pub garbage_lines: u64,
    /// Whether the last motion we started was a jog (no `G4` sync for those).
    jogging: bool,
}

impl GrblController {
    pub fn open(path: &Path, link: &LinkOptions) -> Result<Self> {
        let port = Port::open(path, 115_200, link)?;
        let mut c = GrblController {
            port,
            rx: Vec::new(),
            inflight: VecDeque::new(),
            replies: VecDeque::new(),
            alarm: None,
            new_alarm: false,
            reset_seen: false,
            last_status: None,
            info_lines: Vec::new(),
            homed: false,
            homing: false,
            settings: BTreeMap::new(),
            info: ControllerInfo::unknown("grbl"),
            garbage_lines: 0,
            jogging: false,
        };
        c.sync_line()?;
        // A boot banner that raced our purge is not a reset during our session.
        c.reset_seen = false;
        c.new_alarm = false;
        c.read_settings()?;
        c.identify();
        // With homing enabled GRBL boots locked in Alarm until homed; idle means it was homed
        // (or unlocked by hand, which the operator then answers for).
        let state = c.status()?.controller_state;
        c.homed = state != "Alarm" && c.settings.get(&22) == Some(&1.0);
        c.new_alarm = false;
        c.reset_seen = false;
        Ok(c)
    }

    /// Finds a GRBL on the line: a status report answers `?` at once; failing that, a soft
    /// reset and its banner.
    fn sync_line(&mut self) -> Result<()> {
        self.port.purge()?;
        self.rx.clear();
        if self.raw_status().is_ok() {
            return Ok(());
        }
        self.reset_seen = false;
        self.port.write_all(&[0x18])?;
        let deadline = Instant::now() + Duration::from_secs(2);
        while Instant::now() < deadline {
            self.pump(deadline)?;
            if self.reset_seen {
                self.inflight.clear();
                self.replies.clear();
                return Ok(());
            }
        }
        Err(StageError::Protocol(format!(
            "no GRBL status report or banner on {}",
            self.port.path.display()
        )))
    }

    fn identify(&mut self) {
        self.info.identity = match self.command("$I", REPLY_TIMEOUT) {
            Ok(lines) => lines
                .iter()
                .find(|l| l.starts_with("[VER:"))
                .cloned()
                .unwrap_or_else(|| "GRBL".into()),
            Err(_) => "GRBL (no $I)".into(),
        };
    }

    /// `$$`, until two complete dumps agree: a doubled digit in `$131=200` would otherwise
    /// make a 2 m travel of it, and every limit and coordinate with it.
    fn read_settings(&mut self) -> Result<()> {
        let mut prev: Option<BTreeMap<u32, f64>> = None;
        for _ in 0..QUERY_TRIES * 2 {
            let lines = match self.command("$$", REPLY_TIMEOUT * 2) {
                Ok(l) => l,
                Err(StageError::Timeout { .. }) => continue,
                Err(e) => return Err(e),
            };
            let mut s = BTreeMap::new();
            for l in &lines {
                if let Some((k, v)) = l.strip_prefix('$').and_then(|r| r.split_once('=')) {
                    if let (Ok(k), Ok(v)) = (k.parse::<u32>(), v.parse::<f64>()) {
                        s.insert(k, v);
                    }
                }
            }
            let need = [27, 110, 111, 120, 121, 130, 131];
            if !need.iter().all(|k| s.contains_key(k)) {
                continue;
            }
            if prev.as_ref() == Some(&s) {
                self.settings = s;
                self.apply_settings();
                return Ok(());
            }
            prev = Some(s);
        }
        Err(StageError::Protocol(
            "could not read two complete, agreeing `$$` settings lists from GRBL".into(),
        ))
    }

    fn apply_settings(&mut self) {
        let s = &self.settings;
        let travel = CarriageUm::new(s[&130] * 1000.0, s[&131] * 1000.0);
        let pulloff = s[&27] * 1000.0;
        self.info.travel = travel;
        // Machine zero sits on the + switches: keep a pull-off away from them.
        self.info.limits = SoftLimits {
            min: CarriageUm::new(0.0, 0.0),
            max: CarriageUm::new((travel.x - pulloff).max(0.0), (travel.y - pulloff).max(0.0)),
        };
        self.info.max_speed_um_s = s[&110].min(s[&111]) * 1000.0 / 60.0;
        self.info.accel_um_s2 = s[&120].min(s[&121]) * 1000.0;
        self.info.home_speed_um_s = s.get(&25).copied().unwrap_or(s[&110]) * 1000.0 / 60.0;
        self.info.resolution_um = s.get(&100).map_or(1.0, |spm| 1000.0 / spm);
        self.info.notes.clear();
        if s.get(&20) != Some(&1.0) {
            self.info.notes.push(
                "GRBL's own soft limits ($20) are off: only the host's limits protect the stage"
                    .into(),
            );
        }
        if s.get(&22) != Some(&1.0) {
            self.info
                .notes
                .push("GRBL homing ($22) is off: positions are not referenced".into());
        }
    }

    fn to_machine_mm(&self, p: CarriageUm) -> (f64, f64) {
        (
            (p.x - self.info.travel.x) / 1000.0,
            (p.y - self.info.travel.y) / 1000.0,
        )
    }

    /// Reads what the line has until `deadline`, sorting complete lines into replies, alarms,
    /// reports and garbage.
    fn pump(&mut self, deadline: Instant) -> Result<()> {
        let mut bytes = Vec::new();
        self.port.read_until(deadline, &mut bytes)?;
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

    fn classify(&mut self, line: String) {
        if line.is_empty() {
            return;
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
            if code != 2 {
                self.homed = false;
            }
        } else if line.starts_with("Grbl ") {
            // A (re)boot: the receive buffer and planner are empty now.
            self.reset_seen = true;
            self.inflight.clear();
            self.jogging = false;
        } else if line.starts_with('<') && line.ends_with('>') {
            self.last_status = Some(line);
        } else if line.starts_with('[') || line.starts_with('$') {
            self.info_lines.push(line);
        } else {
            self.garbage_lines += 1;
        }
    }

    /// Sends one line, waiting first until GRBL's receive buffer has room for it.
    fn send_line(&mut self, line: &str) -> Result<()> {
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
    fn wait_reply(&mut self, deadline: Instant) -> Result<Option<Reply>> {
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
    fn take_fault(&mut self) -> Option<StageError> {
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
    fn settle_line(&mut self) -> Result<()> {
        self.pump(Instant::now())?;
        self.new_alarm = false;
        self.reset_seen = false;
        self.replies.clear();
        Ok(())
    }

    /// A `$` command answered by lines and `ok`. Idempotent: the caller may retry.
    fn command(&mut self, cmd: &str, timeout: Duration) -> Result<Vec<String>> {
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

    /// `?` until a well-formed report arrives: (state, machine position mm, pins).
    fn raw_status(&mut self) -> Result<(String, (f64, f64), String)> {
        for _ in 0..QUERY_TRIES {
            self.last_status = None;
            self.port.write_all(b"?")?;
            let deadline = Instant::now() + REPLY_TIMEOUT;
            while Instant::now() < deadline && self.last_status.is_none() {
                self.pump(deadline.min(Instant::now() + POLL))?;
            }
            if let Some(parsed) = self.last_status.take().and_then(|l| parse_status(&l)) {
                return Ok(parsed);
            }
        }
        Err(StageError::Timeout {
            what: "GRBL status report (`?`)".into(),
            after: REPLY_TIMEOUT * QUERY_TRIES as u32,
        })
    }

    fn to_status(&self, state: &str, mpos: (f64, f64), pins: &str) -> StageStatus {
        let position = CarriageUm::new(
            mpos.0 * 1000.0 + self.info.travel.x,
            mpos.1 * 1000.0 + self.info.travel.y,
        );
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
            limit_switches: pins.chars().filter(|c| matches!(c, 'X' | 'Y')).collect(),
            fault,
            controller_state: state.to_string(),
        }
    }

    /// Reads reports until two in a row give the same state and position.
    fn agreed_status(&mut self, first: StageStatus) -> Result<StageStatus> {
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
    fn status_once(&mut self) -> Result<StageStatus> {
        let (s, p, pins) = self.raw_status()?;
        Ok(self.to_status(&s, p, &pins))
    }

    /// Waits for a boot banner after a soft reset.
    fn reset_and_wait(&mut self) -> Result<()> {
        self.reset_seen = false;
        self.port.write_all(&[0x18])?;
        let deadline = Instant::now() + Duration::from_secs(2);
        while !self.reset_seen {
            if Instant::now() >= deadline {
                return Err(StageError::Timeout {
                    what: "GRBL banner after a reset".into(),
                    after: Duration::from_secs(2),
                });
            }
            self.pump(deadline.min(Instant::now() + POLL))?;
        }
        self.reset_seen = false;
        self.new_alarm = false;
        self.inflight.clear();
        self.replies.clear();
        Ok(())
    }
}

/// Parses `<Idle|MPos:-1.000,-2.000,0.000|FS:0,0|Pn:XY>`.
fn parse_status(line: &str) -> Option<(String, (f64, f64), String)> {
    let body = line.strip_prefix('<')?.strip_suffix('>')?;
    let mut fields = body.split('|');
    let state = fields.next()?.to_string();
    if ![
        "Idle", "Run", "Hold", "Jog", "Alarm", "Door", "Check", "Home", "Sleep",
    ]
    .contains(&state.split(':').next()?)
    {
        return None;
    }
    let mut mpos = None;
    let mut pins = String::new();
    for f in fields {
        if let Some(p) = f.strip_prefix("MPos:") {
            let v: Vec<f64> = p
                .split(',')
                .map(|x| x.parse().ok())
                .collect::<Option<_>>()?;
            if v.len() < 2 || v.iter().any(|x| !x.is_finite()) {
                return None;
            }
            mpos = Some((v[0], v[1]));
        } else if let Some(p) = f.strip_prefix("Pn:") {
            pins = p.to_string();
        }
    }
    Some((state, mpos?, pins))
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
        self.jogging = false;
        let (x, y) = self.to_machine_mm(target);
        let f = (speed_um_s * 60.0 / 1000.0).max(1.0);
        let line = format!("G90 G21 G1 X{x:.4} Y{y:.4} F{f:.1}");
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
        self.jogging = false;
        if self.settings.get(&22) != Some(&1.0) {
            return Err(StageError::Rejected {
                command: "$H".into(),
                reason: "homing is disabled on this GRBL ($22=0)".into(),
            });
        }
        self.homed = false;
        self.homing = true;
        self.send_line("$H")
    }

    fn start_jog(&mut self, delta: CarriageUm, speed_um_s: f64) -> Result<()> {
        self.settle_line()?;
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
        let deadline = Instant::now() + timeout;
        let mut idle_with_inflight: Option<Instant> = None;
        let mut error_reply = None;
        loop {
            // Replies: the dwell's `ok` (or `$H`'s) is the fast path; an error is remembered.
            while let Some(r) = self.replies.pop_front() {
                if let Reply::Error(n) = r {
                    error_reply = Some(n);
                }
            }
            if let Some(e) = self.take_fault() {
                return Err(e);
            }
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
                        if std::mem::take(&mut self.homing) && st.controller_state == "Idle" {
                            // `$H` answered and GRBL idle: referenced again, old alarms void.
                            self.homed = true;
                            self.alarm = None;
                            return Ok(StageStatus {
                                homed: true,
                                state: StageState::Idle,
                                ..st
                            });
                        }
                        return Ok(st);
                    }
                }
            }
            if Instant::now() >= deadline {
                // Stopping is the driver's decision (it stops on every error).
                return Err(StageError::MotionTimeout { after: timeout });
            }
            self.pump(Instant::now() + POLL * 4)?;
        }
    }

    fn stop(&mut self) -> Result<()> {
        let (state, _, _) = self.raw_status()?;
        let kind = state.split(':').next().unwrap_or("").to_string();
        match kind.as_str() {
            "Alarm" => return Ok(()), // already stopped, and GRBL takes nothing else
            "Idle" if self.inflight.is_empty() => return Ok(()),
            "Jog" => {
                self.port.write_all(&[0x85])?;
                return Ok(());
            }
            _ => {}
        }
        self.port.write_all(b"!")?;
        let deadline = Instant::now() + Duration::from_secs(3);
        loop {
            let (s, _, _) = self.raw_status()?;
            if s == "Hold:0" || s == "Idle" || s.starts_with("Alarm") {
                break;
            }
            if Instant::now() >= deadline {
                return Err(StageError::Timeout {
                    what: "feed hold".into(),
                    after: Duration::from_secs(3),
                });
            }
        }
        // A reset from a finished hold flushes the planner and keeps the position.
        self.reset_and_wait()
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
        self.reset_and_wait()?;
        if self.alarm == Some(2) && self.homed {
            self.command("$X", REPLY_TIMEOUT)?;
            self.alarm = None;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::parse_status;

    #[test]
    fn parses_reports() {
        let (s, p, pins) = parse_status("<Idle|MPos:-1.000,-2.500,0.000|FS:0,0|Pn:XY>").unwrap();
        assert_eq!((s.as_str(), p, pins.as_str()), ("Idle", (-1.0, -2.5), "XY"));
        assert_eq!(
            parse_status("<Hold:0|MPos:0.000,0.000,0.000|FS:0,0>")
                .unwrap()
                .0,
            "Hold:0"
        );
        assert!(
            parse_status("<Idle|WPos:0,0,0>").is_none(),
            "needs MPos ($10=1)"
        );
        assert!(parse_status("<Idxe|MPos:0,0,0>").is_none());
        assert!(parse_status("<Idle|MPos:0,x,0>").is_none());
    }
}
