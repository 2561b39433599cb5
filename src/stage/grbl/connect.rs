//! Connecting to a GRBL board without resetting it: finding it on the line (a partial line
//! cleared, a board mid-cycle or in alarm recognised), identifying it, and reading and checking
//! the settings the host computes with (`$$`, the work offset).

use super::report::{self, Report};
use super::settings::GrblSettings;
use super::*;

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

    pub(super) fn connect(path: &Path, link: &LinkOptions, to_stop: bool) -> Result<Self> {
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
        } else if !report::still(&first.state) || report::suspended(&first.state) {
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
    pub(super) fn make_ready(&mut self, first: &Report) -> Result<()> {
        let busy = if !report::still(&first.state) || report::suspended(&first.state) {
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

    pub(super) fn settings(&self) -> &GrblSettings {
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
    pub(super) fn find_grbl(&mut self, to_stop: bool) -> Result<(Report, Option<Option<u32>>)> {
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
            if let Some(r) = self.last_report.take().and_then(|l| report::parse(&l)) {
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
    pub(super) fn clear_partial_line(&mut self) -> Result<()> {
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

    pub(super) fn identify(&mut self) {
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
    pub(super) fn read_settings(&mut self) -> Result<()> {
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
            if !super::settings::REQUIRED.iter().all(|k| s.contains_key(k)) {
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

    pub(super) fn apply_settings(&mut self, s: GrblSettings) {
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
                    format!("{v} ({})", super::settings::meaning(*k)),
                )
            })
        })
        .collect();
        self.settings = Some(s);
    }

    /// The work offset (WCO = G54 + G92) from `$#`, for boards that report WPos.
    pub(super) fn read_wco(&mut self) -> Result<()> {
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

    pub(super) fn to_machine_mm(&self, p: CarriageUm) -> (f64, f64) {
        (
            (p.x - self.info.travel.x) / 1000.0,
            (p.y - self.info.travel.y) / 1000.0,
        )
    }
}
