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

mod stop;

use super::grbl_report::{self, Report};
use super::grbl_settings::GrblSettings;
use super::{
    Controller, ControllerInfo, FaultKind, LinkOptions, Port, Result, SetupAdvice, StageError,
    StageState, StageStatus, StopAction,
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

impl GrblController {
    /// Connects without changing anything on the board (no reset: that would abort a homing
    /// cycle in progress). A board that cannot take commands as it is (held, moving, busy with
    /// earlier commands) is refused with [`StageError::NotReady`].
    pub fn open(path: &Path, link: &LinkOptions) -> Result<Self> {
        Self::connect(path, link, false)
    }

    /// Connects to stop the board: one left held, moving, busy or silent by an earlier program
    /// is brought to a standstill and soft-reset first ([`Self::stop`]'s procedure; a silent
    /// one, in a homing cycle or a hard- or soft-limit alarm, is reset at once), so that it
    /// takes commands; the next [`Controller::stop`] reports what was done.
    pub fn open_to_stop(path: &Path, link: &LinkOptions) -> Result<Self> {
        Self::connect(path, link, true)
    }

    fn connect(path: &Path, link: &LinkOptions, to_stop: bool) -> Result<Self> {
        let port = Port::open(path, 115_200, link)?;
        let mut c = GrblController {
            port,
            rx: Vec::new(),
            inflight: VecDeque::new(),
            replies: VecDeque::new(),
            alarm: None,
            new_alarm: false,
            reset_seen: false,
            last_report: None,
            info_lines: Vec::new(),
            homed: false,
            homing: false,
            raw_settings: BTreeMap::new(),
            settings: None,
            info: ControllerInfo::unknown("grbl"),
            garbage_lines: 0,
            jogging: false,
            wco: None,
            stale_reports: false,
            late_reports: 0,
            heard: Vec::new(),
            latest_report: None,
            critical_pending: false,
            settled: None,
        };
        let (first, reset_at_connect) = c.find_grbl(to_stop)?;
        if let Some(alarm) = reset_at_connect {
            // Silent (a homing cycle), ended by a reset: where it stands is not a reference.
            c.homed = false;
            c.settled = Some(if alarm == Some(6) {
                StopAction::HomingAborted
            } else {
                StopAction::Reset
            });
        } else if to_stop {
            c.make_ready(&first)?;
        } else if !grbl_report::still(&first.state) || grbl_report::suspended(&first.state) {
            return Err(StageError::NotReady {
                state: state_words(&first.state),
            });
        }
        c.clear_partial_line()?;
        let alarm_at_connect = c.alarm.take();
        c.read_settings()?;
        c.identify();
        if !c.settings().reports_mpos {
            c.read_wco()?;
        }
        // With homing enabled GRBL boots locked in Alarm until homed; idle means it was homed
        // (or unlocked by hand, which the operator then answers for).
        let (report, _) = c.raw_status()?;
        let alarm_state = report.state.starts_with("Alarm");
        c.homed = !alarm_state && c.settings().homing;
        if alarm_state {
            c.alarm = alarm_at_connect;
            c.info.notes.push(match alarm_at_connect {
                Some(code) => format!(
                    "GRBL reported ALARM:{code} ({}) and is locked in Alarm: clear the cause, then `rig stage home`",
                    alarm_meaning(code)
                ),
                None => "GRBL is locked in Alarm (after power-up, a reset or an alarm before this \
                         connection): `rig stage home` references and unlocks it"
                    .into(),
            });
        } else if let Some(code) = alarm_at_connect {
            c.info.notes.push(format!(
                "GRBL reported ALARM:{code} ({}) as the rig connected",
                alarm_meaning(code)
            ));
        }
        c.new_alarm = false;
        c.reset_seen = false;
        if let Some(done) = c.settled {
            c.info.notes.push(format!(
                "as the rig connected to stop it: {}",
                done.describe()
            ));
        }
        Ok(c)
    }

    /// For [`Self::open_to_stop`]: a board that is not standing still and reading lines is
    /// stopped (feed hold, soft reset once still); so is one that answers `?` but no line.
    /// A board that stood still throughout was held or busy: its stop is [`StopAction::Released`].
    fn make_ready(&mut self, first: &Report) -> Result<()> {
        let busy = if !grbl_report::still(&first.state) || grbl_report::suspended(&first.state) {
            true
        } else {
            match self.clear_partial_line() {
                Ok(()) => false,
                Err(StageError::NotReady { .. }) => true,
                Err(e) => return Err(e),
            }
        };
        if busy && self.hold_and_reset(stop::STILL_CAP + stop::STILL_MARGIN)? == StopAction::Nothing
        {
            self.settled = Some(StopAction::Released);
        }
        Ok(())
    }

    fn settings(&self) -> &GrblSettings {
        self.settings
            .as_ref()
            .expect("settings are read before any use")
    }

    /// Finds a GRBL on the line without resetting it (a reset would abort a homing cycle in
    /// progress): a status report answers `?` at once, or a board that was reset by the opening
    /// of the port prints its banner. Silence is reported as such, unless `to_stop`: a silent
    /// GRBL is in a homing cycle or a critical alarm (Commands.md: `?` is not executed then),
    /// which only a reset ends, so one is sent. Returns the first report, and whether a reset
    /// was sent (with the alarm it raised).
    fn find_grbl(&mut self, to_stop: bool) -> Result<(Report, Option<Option<u32>>)> {
        self.port.purge()?;
        self.rx.clear();
        let start = Instant::now();
        let mut deadline = start + CONNECT_WAIT;
        let mut asked = 0;
        let mut next_ask = start;
        let mut reset_sent = None;
        loop {
            if Instant::now() >= deadline {
                if to_stop && self.heard.is_empty() && reset_sent.is_none() {
                    self.port.write_all(&[0x18])?;
                    self.new_alarm = false;
                    reset_sent = Some(None);
                    deadline = Instant::now() + stop::BANNER_WAIT + REPLY_TIMEOUT;
                    continue;
                }
                break;
            }
            if Instant::now() >= next_ask {
                self.port.write_all(b"?")?;
                asked += 1;
                next_ask = Instant::now() + REPLY_TIMEOUT;
            }
            self.pump(deadline.min(Instant::now() + POLL))?;
            if self.reset_seen {
                // Booted just now: ask again once it is up.
                self.reset_seen = false;
                next_ask = Instant::now() + Duration::from_millis(100);
                if reset_sent.is_some() {
                    reset_sent = Some(self.new_alarm.then_some(self.alarm).flatten());
                    self.new_alarm = false;
                }
            }
            if let Some(r) = self.last_report.take().and_then(|l| grbl_report::parse(&l)) {
                // More than one question may still be answered: believe nothing until a line
                // reply (the partial-line sync that follows) has come.
                self.stale_reports = asked > 1;
                return Ok((r, reset_sent));
            }
        }
        let path = self.port.path.display().to_string();
        Err(StageError::Protocol(if self.heard.is_empty() {
            format!(
                "no answer on {path} within {CONNECT_WAIT:?}: nothing at all was heard. A GRBL \
                 in a homing cycle is silent until the cycle ends: wait and connect again (or \
                 end the cycle with `rig stage stop`, a reset: home again); one in a hard- or \
                 soft-limit alarm is silent until reset (`rig stage stop`). Otherwise check the \
                 port, the baud rate (115200), the cable and the power. No reset was sent, so \
                 nothing in progress was aborted"
            )
        } else {
            format!(
                "{path} does not answer like GRBL 1.1: heard \"{}\" but no status report. Is it \
                 another controller (try --dialect native) or another baud rate than 115200?",
                heard(&self.heard)
            )
        }))
    }

    /// An earlier program (or a connection attempt in another dialect) may have left half a
    /// line in GRBL's receive buffer, which would spoil our first command: an empty line ends
    /// it, and its answer (`ok`, or `error:n` for the junk) is discarded.
    fn clear_partial_line(&mut self) -> Result<()> {
        self.replies.clear();
        self.send_line("")?;
        let deadline = Instant::now() + REPLY_TIMEOUT * 4;
        while self.replies.is_empty() && Instant::now() < deadline {
            self.pump(deadline.min(Instant::now() + POLL))?;
        }
        if self.replies.is_empty() {
            self.inflight.clear();
            return Err(StageError::NotReady {
                state: format!(
                    "busy with earlier commands (GRBL on {} answers `?` but not an empty line \
                     within {:?})",
                    self.port.path.display(),
                    REPLY_TIMEOUT * 4
                ),
            });
        }
        self.replies.clear();
        Ok(())
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
    /// make a 2 m travel of it, and every limit and coordinate with it. A dump answered
    /// `error:n` (a garbled command) is asked again like one that timed out.
    fn read_settings(&mut self) -> Result<()> {
        let mut prev: Option<BTreeMap<u32, f64>> = None;
        let mut last_err = None;
        for _ in 0..QUERY_TRIES * 2 {
            let lines = match self.command("$$", REPLY_TIMEOUT * 2) {
                Ok(l) => l,
                Err(e @ (StageError::Timeout { .. } | StageError::Rejected { .. })) => {
                    last_err = Some(e);
                    continue;
                }
                Err(e) => return Err(e),
            };
            let s = GrblSettings::parse_lines(&lines);
            if !super::grbl_settings::REQUIRED
                .iter()
                .all(|k| s.contains_key(k))
            {
                continue;
            }
            if prev.as_ref() == Some(&s) {
                let checked = GrblSettings::from_raw(&s)?;
                self.raw_settings = s;
                self.apply_settings(checked);
                return Ok(());
            }
            prev = Some(s);
        }
        Err(StageError::Protocol(format!(
            "could not read two complete, agreeing `$$` settings lists from GRBL{}",
            last_err.map_or(String::new(), |e| format!(" (last: {e})"))
        )))
    }

    fn apply_settings(&mut self, s: GrblSettings) {
        self.info.travel = s.travel();
        self.info.limits = s.soft_limits();
        self.info.max_speed_um_s = s.max_speed_um_s();
        self.info.accel_um_s2 = s.accel_um_s2();
        self.info.home_speed_um_s = s.seek_mm_min * 1000.0 / 60.0;
        self.info.resolution_um = 1000.0 / s.steps_per_mm[0].max(s.steps_per_mm[1]);
        self.info.homing_bound_s = s.homing_bound_s();
        self.info.notes.clear();
        if !s.soft_limits {
            self.info.notes.push(
                "GRBL's own soft limits ($20) are off: only the host's limits protect the stage"
                    .into(),
            );
        }
        if !s.homing {
            self.info
                .notes
                .push("GRBL homing ($22) is off: positions are not referenced".into());
        }
        self.info.advice = s
            .advice()
            .into_iter()
            .map(|(setting, now, todo)| SetupAdvice { setting, now, todo })
            .collect();
        self.info.settings = [
            10, 13, 20, 21, 22, 23, 24, 25, 27, 110, 111, 120, 121, 130, 131,
        ]
        .iter()
        .filter_map(|k| {
            self.raw_settings.get(k).map(|v| {
                (
                    format!("${k}"),
                    format!("{v} ({})", super::grbl_settings::meaning(*k)),
                )
            })
        })
        .collect();
        self.settings = Some(s);
    }

    /// The work offset (WCO = G54 + G92) from `$#`, for boards that report WPos.
    fn read_wco(&mut self) -> Result<()> {
        let lines = self.command("$#", REPLY_TIMEOUT * 2)?;
        let get = |tag: &str| -> Option<[f64; 2]> {
            let l = lines.iter().find(|l| l.starts_with(tag))?;
            let body = l.strip_prefix(tag)?.strip_suffix(']')?;
            let v: Vec<f64> = body
                .split(',')
                .take(2)
                .map(|x| x.parse().ok())
                .collect::<Option<_>>()?;
            (v.len() == 2 && v.iter().all(|x| x.is_finite())).then(|| [v[0], v[1]])
        };
        match (get("[G54:"), get("[G92:")) {
            (Some(a), Some(b)) => {
                self.wco = Some([a[0] + b[0], a[1] + b[1]]);
                Ok(())
            }
            _ => Err(StageError::Protocol(
                "GRBL reports WPos ($10) but its `$#` gives no G54/G92 offsets to turn them \
                 into machine positions; set `$10=1`"
                    .into(),
            )),
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

    fn classify(&mut self, line: String) {
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

    /// Before a report may be believed after an unanswered `?`: a line reply must arrive. With
    /// nothing in flight, an empty line (answered `ok` at once by an idle GRBL) asks for one.
    fn resync_reports(&mut self) -> Result<()> {
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
    fn silence(&mut self, timeout: StageError) -> StageError {
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

    /// `?` until a well-formed report arrives, up to `tries` questions: the report and the
    /// machine position in mm.
    fn query(&mut self, tries: usize) -> Result<(Report, (f64, f64))> {
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
                    if let Some(r) = grbl_report::parse(&l) {
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

    fn raw_status(&mut self) -> Result<(Report, (f64, f64))> {
        self.query(QUERY_TRIES)
    }

    /// The machine position of a report in mm: WPos + WCO when the board reports WPos, inches
    /// converted. `None` for WPos while the offset is unknown.
    fn machine_mm(&mut self, r: &Report) -> Option<(f64, f64)> {
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

    fn to_status(&self, r: &Report, mpos: (f64, f64)) -> StageStatus {
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
        let (r, m) = self.raw_status()?;
        Ok(self.to_status(&r, m))
    }

    /// One `?` during a homing wait: the state of a report that arrives within the reply time,
    /// if it is not `Home` (the cycle is over); `None` when GRBL is silent or still homing. Any
    /// report is taken, believed or not: GRBL answers a question asked during the cycle only
    /// when the cycle ends, as a `Home` report, so one in any other state was made after it
    /// (and waiting for a line reply to vouch for it could wait forever when the `$H`'s `ok`
    /// was lost).
    fn homing_probe(&mut self) -> Result<Option<String>> {
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
        Ok(grbl_report::parse(&line)
            .map(|r| r.state)
            .filter(|s| !s.starts_with("Home")))
    }

    /// A soft reset and its banner (see [`Self::soft_reset`]); the board is settled after it.
    fn reset_and_wait(&mut self) -> Result<()> {
        self.soft_reset()?;
        self.settled = Some(StopAction::Reset);
        Ok(())
    }

    /// The homing wait: GRBL answers `$H` when the cycle has ended and may say nothing before;
    /// `ok`, `error:n`, `ALARM:n` or a banner end it. A noisy line can lose that answer, so
    /// after [`HOMING_PROBE_AFTER`] a `?` is sent every [`HOMING_PROBE_EVERY`]: GRBL may ignore
    /// it during the cycle (or answer it late, still `Home`), but a report in any other state
    /// means the cycle is over — `Idle` homed (its `ok` was lost), `Alarm` failed.
    fn wait_homed(&mut self, timeout: Duration) -> Result<StageStatus> {
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
