//! A GRBL 1.1 controller (the documented interface: `ok`/`error:N`, `ALARM:N`, `<…>` status
//! reports, the real-time bytes `?` `!` `~` 0x18 0x85, `$H`, `$J=`, `$X`, `$$`, the banner),
//! on the simulated stage. Machine coordinates run from -max travel to 0 after homing, whichever
//! way the axes home (`$23`): machine zero on a + switch, minus the max travel on a − switch.
//! As the interface documents, and unlike an eager emulator:
//! - a status request during a homing cycle is not answered then: GRBL services it once the
//!   cycle has ended, as one late `<Home|…>` report before the `$H`'s `ok` (requests coalesce);
//!   after a critical alarm (hard or soft limit) it is not answered at all until a reset;
//! - `$10` chooses MPos or WPos (WPos = MPos − WCO, with a `WCO:` field every 10th report when
//!   idle, every 30th when busy, and at once after the offset changed); `$13=1` reports inches;
//! - an empty line is answered `ok` (hosts use it to sync);
//! - a reset during homing is ALARM:6, during motion ALARM:3 (a decelerating hold, `Hold:1`,
//!   is motion); in `Hold:0` or Idle it keeps the position and comes up Idle;
//! - the parser takes one line at a time and answers it once executed: a `G4` first waits for
//!   the planner to empty (protocol_buffer_synchronize), so the lines behind it and their `ok`s
//!   wait too; the dwell itself runs with GRBL Idle;
//! - a feed hold (`!`) acts in Idle, Run and Jog (Commands.md): from Run it decelerates
//!   (`Hold:1`) to `Hold:0`, from Idle it is `Hold:0` at once, in a jog it cancels the jog. Once
//!   the hold is complete GRBL suspends its main loop (protocol_exec_rt_suspend) until cycle start
//!   `~` or a reset: no line is read, so nothing is answered `ok` and a pending `G4` never
//!   completes, as the planner does not empty while held. `?` is answered all along.

use crate::stage::{MotionKind, Stage, StageEvent, StopCause};
use std::collections::{BTreeMap, VecDeque};

const RX_BUFFER: usize = 128;
const PLANNER_BLOCKS: usize = 15;
pub const BANNER: &str = "\r\nGrbl 1.1h ['$' for help]\r\n";

#[derive(Debug, Clone, Copy, PartialEq)]
enum Block {
    Move { target: [f64; 2], speed: f64 },
    Jog { target: [f64; 2], speed: f64 },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    Idle,
    Run,
    Hold,
    Jog,
    Home,
    Alarm,
}

/// What holds the parser until the machine catches up (GRBL blocks its main loop for these).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Sync {
    /// `G4`: wait for the planner to empty, dwell, then `ok`. `started`: the planner is empty
    /// and the dwell's delay runs.
    Dwell { seconds: f64, started: bool },
    /// `$H`: `ok` when homing is done.
    Home,
}

pub struct GrblFirmware {
    rx: VecDeque<u8>,
    planner: VecDeque<Block>,
    current: Option<Block>,
    sync: Option<Sync>,
    mode: Mode,
    /// Critical alarm (hard limit): only a reset is accepted.
    critical: bool,
    absolute: bool,
    inches: bool,
    feed_mm_min: Option<f64>,
    pub settings: BTreeMap<u32, f64>,
    pub rx_overflow: u64,
    /// A `?` arrived during homing: one report is owed when the cycle ends.
    late_report: bool,
    /// G54 and G92 offsets, machine µm: WCO = their sum.
    g54_um: [f64; 2],
    g92_um: [f64; 2],
    /// Reports until the next one carries `WCO:` (GRBL's `sys.report_wco_counter`).
    wco_counter: u32,
}

/// The `$23` mask of per-axis homing directions (bit set: toward −).
fn homing_mask(dir: [f64; 2]) -> f64 {
    (0..2)
        .filter(|&k| dir[k] < 0.0)
        .map(|k| (1u32 << k) as f64)
        .sum()
}

fn fmt_setting(v: f64) -> String {
    if v.fract() == 0.0 && v.abs() < 1e9 {
        format!("{}", v as i64)
    } else {
        format!("{v:.3}")
    }
}

/// `$23`'s homing direction per axis: a set bit homes that axis toward −.
pub fn homing_dirs(mask: f64) -> [f64; 2] {
    let m = if (0.0..256.0).contains(&mask) {
        mask as u32
    } else {
        0
    };
    [0, 1].map(|k| if m & (1 << k) != 0 { -1.0 } else { 1.0 })
}

impl GrblFirmware {
    /// A board with its default settings, then `overrides` (as if an operator had set them
    /// with `$N=`; not range-checked, as GRBL checks little), booting: banner and, with
    /// homing enabled, the alarm lock.
    pub fn new(stage: &Stage, overrides: &[(u32, f64)], out: &mut Vec<u8>) -> Self {
        let c = &stage.cfg;
        let steps_per_mm = 1000.0 / c.step_um;
        let settings: BTreeMap<u32, f64> = [
            (0, 10.0),
            (1, 25.0),
            (2, 0.0),
            (3, 0.0),
            (4, 0.0),
            (5, 0.0),
            (6, 0.0),
            (10, 1.0),
            (11, 0.010),
            (12, 0.002),
            (13, 0.0),
            (20, 1.0),
            (21, 1.0),
            (22, 1.0),
            (23, homing_mask(c.home_dir)),
            (24, 25.0),
            (25, c.home_speed_um_s * 0.06),
            (26, 250.0),
            (27, c.pulloff_um / 1000.0),
            (30, 1000.0),
            (31, 0.0),
            (32, 0.0),
            (100, steps_per_mm),
            (101, steps_per_mm),
            (102, 250.0),
            (110, c.max_speed_um_s * 0.06),
            (111, c.max_speed_um_s * 0.06),
            (112, 500.0),
            (120, c.accel_um_s2 / 1000.0),
            (121, c.accel_um_s2 / 1000.0),
            (122, 10.0),
            (130, c.travel_um[0] / 1000.0),
            (131, c.travel_um[1] / 1000.0),
            (132, 100.0),
        ]
        .into_iter()
        .collect();
        let mut settings = settings;
        for &(k, v) in overrides {
            settings.insert(k, v);
        }
        let mut g = GrblFirmware {
            rx: VecDeque::new(),
            planner: VecDeque::new(),
            current: None,
            sync: None,
            mode: Mode::Idle,
            critical: false,
            absolute: true,
            inches: false,
            feed_mm_min: None,
            settings,
            rx_overflow: 0,
            late_report: false,
            g54_um: [0.0; 2],
            g92_um: [0.0; 2],
            wco_counter: 0,
        };
        g.boot(stage, out, true);
        g
    }

    /// Start-up: the banner. At power-up with homing enabled (and no kept reference) GRBL locks
    /// itself in Alarm; a soft reset keeps an Alarm state and otherwise comes up Idle (GRBL
    /// 1.1 keeps `sys.state` across resets).
    fn boot(&mut self, stage: &Stage, out: &mut Vec<u8>, power_on: bool) {
        let alarm = if power_on {
            self.settings[&22] != 0.0 && !stage.homed
        } else {
            self.mode == Mode::Alarm
        };
        self.rx.clear();
        self.planner.clear();
        self.current = None;
        self.sync = None;
        self.critical = false;
        self.absolute = true;
        self.inches = false;
        self.feed_mm_min = None;
        self.late_report = false;
        self.g92_um = [0.0; 2];
        self.wco_counter = 0;
        out.extend_from_slice(BANNER.as_bytes());
        if alarm {
            self.mode = Mode::Alarm;
            out.extend_from_slice(b"[MSG:'$H'|'$X' to unlock]\r\n");
        } else {
            self.mode = Mode::Idle;
        }
    }

    fn mode_name(&self, stage: &Stage) -> &'static str {
        match self.mode {
            Mode::Idle => "Idle",
            Mode::Run => "Run",
            Mode::Hold => {
                if stage.is_busy() {
                    "Hold:1"
                } else {
                    "Hold:0"
                }
            }
            Mode::Jog => "Jog",
            Mode::Home => "Home",
            Mode::Alarm => "Alarm",
        }
    }

    pub fn state_name(&self, stage: &Stage) -> String {
        self.mode_name(stage).to_string()
    }

    fn setting_bits(&self, k: u32) -> u32 {
        let v = self.settings.get(&k).copied().unwrap_or(0.0);
        if (0.0..65536.0).contains(&v) {
            v as u32
        } else {
            0
        }
    }

    fn wco(&self) -> [f64; 2] {
        [0, 1].map(|k| self.g54_um[k] + self.g92_um[k])
    }

    /// A coordinate in the report unit `$13` asks for: mm with 3 decimals or inches with 4.
    fn coord(&self, um: f64) -> String {
        if self.setting_bits(13) & 1 != 0 {
            format!("{:.4}", um / 25_400.0 + 0.0)
        } else {
            format!("{:.3}", mm3(um))
        }
    }

    /// A status report as `$10` and `$13` ask: MPos or WPos, mm or inches.
    fn status_report(&mut self, stage: &Stage) -> String {
        let inch = self.setting_bits(13) & 1 != 0;
        let machine = [stage.logical(0), stage.logical(1)];
        let wco = self.wco();
        let (label, pos) = if self.setting_bits(10) & 1 != 0 {
            ("MPos", machine)
        } else {
            ("WPos", [machine[0] - wco[0], machine[1] - wco[1]])
        };
        let feed = if stage.is_busy() && stage.motion_kind() != Some(MotionKind::Dwell) {
            self.feed_mm_min.unwrap_or(0.0) / if inch { 25.4 } else { 1.0 }
        } else {
            0.0
        };
        let mut s = format!(
            "<{}|{label}:{},{},{}|FS:{},0",
            self.mode_name(stage),
            self.coord(pos[0]),
            self.coord(pos[1]),
            self.coord(0.0),
            feed.round() as i64
        );
        let sw = stage.switches();
        if sw != 0 {
            s.push_str("|Pn:");
            if sw & 0b0110 != 0 {
                s.push('X');
            }
            if sw & 0b1_1000 != 0 {
                s.push('Y');
            }
        }
        if self.wco_counter > 0 {
            self.wco_counter -= 1;
        } else {
            self.wco_counter = if stage.is_busy() { 29 } else { 9 };
            let wco = [self.coord(wco[0]), self.coord(wco[1]), self.coord(0.0)];
            s.push_str(&format!("|WCO:{}", wco.join(",")));
        }
        s.push_str(">\r\n");
        s
    }

    fn alarm(&mut self, stage: &mut Stage, code: u32, out: &mut Vec<u8>) {
        stage.halt();
        self.late_report = false;
        self.planner.clear();
        self.current = None;
        self.sync = None;
        self.mode = Mode::Alarm;
        out.extend_from_slice(format!("ALARM:{code}\r\n").as_bytes());
    }

    /// Bytes from the host, one burst between two looks of GRBL's main loop. As GRBL's serial
    /// interrupt does, real-time bytes only raise flags (several of one kind count once) and the
    /// rest fills the receive buffer; the main loop then acts on the flags in the order of
    /// protocol.c's protocol_exec_rt_system: a reset (which drops the rest), the status report,
    /// the feed hold, cycle start (not when a hold came with it). A `?` that arrives with a `!`
    /// is therefore answered with the state from before the hold.
    pub fn on_bytes(&mut self, bytes: &[u8], stage: &mut Stage, out: &mut Vec<u8>) {
        let (mut reset, mut report, mut hold, mut start, mut jog_cancel) =
            (false, false, false, false, false);
        for &b in bytes {
            match b {
                b'?' => report = true,
                b'!' => hold = true,
                b'~' => start = true,
                0x18 => reset = true,
                0x85 => jog_cancel = true,
                0x80..=0xFF => {} // other real-time overrides: accepted, not modelled
                _ => {
                    if self.rx.len() < RX_BUFFER - 1 {
                        self.rx.push_back(b);
                    } else {
                        self.rx_overflow += 1;
                    }
                }
            }
        }
        if reset {
            self.soft_reset(stage, out);
            return;
        }
        if report {
            if self.mode == Mode::Home {
                // During homing GRBL's main loop is in the cycle: the request waits.
                self.late_report = true;
            } else if self.critical {
                // A critical alarm (hard or soft limit) spins until a reset and answers no `?`
                // (Commands.md: "except during a homing cycle and when critical alarm (hard/soft
                // limit error) is thrown").
            } else {
                let r = self.status_report(stage);
                out.extend_from_slice(r.as_bytes());
            }
        }
        if hold {
            self.feed_hold(stage);
        } else if jog_cancel && self.mode == Mode::Jog {
            self.cancel_jog(stage);
        }
        if start && !hold {
            self.cycle_start(stage);
        }
        self.pump(stage, out);
    }

    /// `!` (Commands.md: "executes when Grbl is in an IDLE, RUN, or JOG state. It is otherwise
    /// ignored"). Run: decelerate to `Hold:0`. Idle: `Hold:0` at once (protocol.c: "If IDLE, Grbl
    /// is not in motion. Simply indicate suspend state and hold is complete"), which also
    /// suspends a dwell under way. Jog: the jog is cancelled and its blocks flushed, back to Idle.
    fn feed_hold(&mut self, stage: &mut Stage) {
        match self.mode {
            Mode::Run => {
                stage.stop();
                self.mode = Mode::Hold;
            }
            Mode::Jog => self.cancel_jog(stage),
            Mode::Idle => {
                if let Some(Sync::Dwell { seconds, .. }) = self.sync {
                    // The dwell's delay is suspended; it runs again on resume.
                    stage.halt();
                    self.sync = Some(Sync::Dwell {
                        seconds,
                        started: false,
                    });
                }
                self.mode = Mode::Hold;
            }
            Mode::Hold | Mode::Home | Mode::Alarm => {}
        }
    }

    /// `~`: resumes a complete hold (`Hold:0`); ignored otherwise, a hold still decelerating
    /// included (protocol.c: cycle start "only when IDLE or when a hold is complete"). With
    /// motion left the cycle runs on; without, GRBL is Idle again and the parser resumes.
    fn cycle_start(&mut self, stage: &mut Stage) {
        if self.mode != Mode::Hold || stage.is_busy() {
            return;
        }
        match self.current {
            Some(Block::Move { target, speed }) | Some(Block::Jog { target, speed }) => {
                self.mode = Mode::Run;
                stage.start_move(target, speed);
            }
            _ => self.mode = Mode::Idle,
        }
    }

    /// Jog cancel (0x85, or `!` during a jog): decelerate, flush the jog blocks; Idle once
    /// stopped.
    fn cancel_jog(&mut self, stage: &mut Stage) {
        stage.stop();
        self.planner.retain(|b| !matches!(b, Block::Jog { .. }));
        self.current = None;
    }

    /// A complete hold: GRBL's main loop is suspended and reads no line.
    fn suspended(&self, stage: &Stage) -> bool {
        self.mode == Mode::Hold && !stage.is_busy()
    }

    fn soft_reset(&mut self, stage: &mut Stage, out: &mut Vec<u8>) {
        let moving = stage.is_busy() && !matches!(stage.motion_kind(), Some(MotionKind::Dwell));
        let homing = self.mode == Mode::Home;
        stage.halt();
        if homing {
            // Homing fail: reset during the cycle; the reference is not set.
            stage.lose_reference();
            out.extend_from_slice(b"ALARM:6\r\n");
            self.mode = Mode::Alarm;
        } else if moving {
            // Reset while in motion: steps may be lost, so GRBL drops its position.
            stage.lose_reference();
            out.extend_from_slice(b"ALARM:3\r\n");
            self.mode = Mode::Alarm;
        }
        self.boot(stage, out, false);
    }

    /// Parses lines while nothing holds the parser and the planner has room; feeds blocks to
    /// the stage.
    fn pump(&mut self, stage: &mut Stage, out: &mut Vec<u8>) {
        loop {
            self.execute(stage);
            if self.critical {
                // Only a reset (and status reports) are heard after a critical alarm.
                self.rx.clear();
                return;
            }
            // A pending `G4` or `$H` holds the parser (the lines behind it wait, unanswered),
            // as do a full planner and a complete feed hold (the main loop is suspended).
            if self.sync.is_some() || self.planner.len() >= PLANNER_BLOCKS || self.suspended(stage)
            {
                return;
            }
            let Some(nl) = self.rx.iter().position(|&b| b == b'\n' || b == b'\r') else {
                return;
            };
            let line: Vec<u8> = self.rx.drain(..=nl).collect();
            let line = String::from_utf8_lossy(&line[..nl]).to_string();
            // An empty line is answered `ok` (a host's way to sync).
            match self.line(&line, stage, out) {
                Ok(true) => out.extend_from_slice(b"ok\r\n"),
                Ok(false) => {} // ok deferred (sync)
                Err(code) => out.extend_from_slice(format!("error:{code}\r\n").as_bytes()),
            }
        }
    }

    /// Starts the next planner block when the stage is free; with the planner empty the cycle
    /// ends (Idle) and a pending `G4` starts its delay, GRBL staying Idle meanwhile (mc_dwell:
    /// protocol_buffer_synchronize, then the delay).
    fn execute(&mut self, stage: &mut Stage) {
        if stage.is_busy() || matches!(self.mode, Mode::Hold | Mode::Alarm | Mode::Home) {
            return;
        }
        self.current = None;
        match self.planner.pop_front() {
            Some(b) => {
                self.current = Some(b);
                match b {
                    Block::Move { target, speed } => {
                        self.mode = Mode::Run;
                        stage.start_move(target, speed);
                    }
                    Block::Jog { target, speed } => {
                        self.mode = Mode::Jog;
                        stage.start_move(target, speed);
                    }
                }
            }
            None => {
                if matches!(self.mode, Mode::Run | Mode::Jog) {
                    self.mode = Mode::Idle;
                }
                if let Some(Sync::Dwell {
                    seconds,
                    started: false,
                }) = self.sync
                {
                    self.sync = Some(Sync::Dwell {
                        seconds,
                        started: true,
                    });
                    stage.start_dwell(seconds);
                }
            }
        }
    }

    fn soft_ok(&self, t: [f64; 2]) -> bool {
        if self.settings[&20] == 0.0 {
            return true;
        }
        (0..2).all(|k| t[k] <= 0.0 && t[k] >= -self.settings[&(130 + k as u32)] * 1000.0)
    }

    /// One line. `Ok(true)`: answer `ok` now; `Ok(false)`: `ok` comes later; `Err(n)`:
    /// `error:n`.
    fn line(&mut self, raw: &str, stage: &mut Stage, out: &mut Vec<u8>) -> Result<bool, u32> {
        let line: String = strip_comments(raw)
            .chars()
            .filter(|c| !c.is_whitespace())
            .collect::<String>()
            .to_uppercase();
        if line.is_empty() {
            return Ok(true);
        }
        if let Some(rest) = line.strip_prefix('$') {
            return self.dollar(rest, stage, out);
        }
        if self.mode == Mode::Alarm || self.mode == Mode::Jog {
            return Err(9);
        }
        let words = parse_words(&line)?;
        self.gcode(&words, stage, false, out)
            .map(|deferred| !deferred)
    }

    /// G-code words (already validated as letter + number). Returns whether `ok` is deferred.
    fn gcode(
        &mut self,
        words: &[(char, f64)],
        stage: &mut Stage,
        jog: bool,
        out: &mut Vec<u8>,
    ) -> Result<bool, u32> {
        let mut motion: Option<u32> = None;
        let mut dwell = false;
        // G53: this block in machine coordinates; G10 L2/L20 P1 and G92: work offsets.
        let (mut machine, mut g10, mut g92, mut g92_clear) = (false, false, false, false);
        let (mut absolute, mut inches) = (self.absolute, self.inches);
        let (mut x, mut y, mut f, mut p, mut l) = (None, None, None, None, None);
        for &(letter, v) in words {
            match letter {
                'G' => {
                    let g = (v * 10.0).round() as u32;
                    match g {
                        0 | 10 => motion = Some(g / 10),
                        40 => dwell = true,
                        100 => g10 = true,
                        200 => inches = true,
                        210 => inches = false,
                        530 => machine = true,
                        900 => absolute = true,
                        910 => absolute = false,
                        920 => g92 = true,
                        921 => g92_clear = true,
                        170 | 940 | 540 => {}
                        _ => return Err(20),
                    }
                }
                'M' => match v as u32 {
                    0 | 1 | 2 | 5 | 9 | 30 => {}
                    _ => return Err(20),
                },
                'X' => x = Some(v),
                'Y' => y = Some(v),
                'Z' => {} // no Z axis on this stage: accepted, nothing moves
                'F' => f = Some(v),
                'P' => p = Some(v),
                'L' => l = Some(v),
                'N' | 'S' | 'T' => {}
                _ => return Err(20),
            }
        }
        if jog && (dwell || motion.is_some() || g10 || g92 || g92_clear) {
            return Err(16);
        }
        let unit = if inches { 25_400.0 } else { 1000.0 };
        if !jog {
            self.absolute = absolute;
            self.inches = inches;
        }
        if let Some(f) = f {
            if f <= 0.0 {
                return Err(4);
            }
            if !jog {
                self.feed_mm_min = Some(f * unit / 1000.0);
            }
        }
        if dwell {
            let s = p.ok_or(28u32)?;
            if s < 0.0 {
                return Err(4);
            }
            self.sync = Some(Sync::Dwell {
                seconds: s,
                started: false,
            });
            return Ok(true); // deferred: `ok` after the dwell
        }
        let here = self.planned_end(stage);
        if g10 {
            // G10 L2 P1: the G54 offset itself; G10 L20 P1: the offset that makes the current
            // position read as the given work position.
            if p.map(|p| p.round()) != Some(1.0) {
                return Err(29); // only G54 is modelled
            }
            for (k, v) in [(0, x), (1, y)] {
                if let Some(v) = v {
                    self.g54_um[k] = match l.map(|l| l.round()) {
                        Some(2.0) => v * unit,
                        Some(20.0) => here[k] - self.g92_um[k] - v * unit,
                        _ => return Err(20),
                    };
                }
            }
            self.wco_counter = 0;
            return Ok(false);
        }
        if g92 || g92_clear {
            for (k, v) in [(0, x), (1, y)] {
                if g92_clear {
                    self.g92_um[k] = 0.0;
                } else if let Some(v) = v {
                    self.g92_um[k] = here[k] - self.g54_um[k] - v * unit;
                }
            }
            self.wco_counter = 0;
            return Ok(false);
        }
        let is_motion = jog || (motion.is_some() && (x.is_some() || y.is_some()));
        if !is_motion {
            return Ok(false);
        }
        // (deferred = false: `ok` as soon as the block is planned, as GRBL does)
        // Target from the end of the queued path, in logical (machine) µm.
        let base = here;
        let wco = if machine { [0.0; 2] } else { self.wco() };
        let mut t = base;
        for (k, v) in [(0, x), (1, y)] {
            if let Some(v) = v {
                t[k] = if absolute || machine {
                    v * unit + wco[k]
                } else {
                    base[k] + v * unit
                };
            }
        }
        let max_rate = self.settings[&110].min(self.settings[&111]) * 1000.0 / 60.0;
        let speed = if jog {
            f.ok_or(16u32)? * unit / 1000.0 * 1000.0 / 60.0
        } else if motion == Some(0) {
            max_rate
        } else {
            self.feed_mm_min.ok_or(22u32)? * 1000.0 / 60.0
        }
        .min(max_rate);
        if !self.soft_ok(t) {
            if jog {
                return Err(15);
            }
            // GRBL 1.1: a soft-limit violation is a critical alarm (nothing moved, so the
            // position is kept); the line gets no `ok`, only a reset continues.
            self.alarm(stage, 2, out);
            self.critical = true;
            out.extend_from_slice(b"[MSG:Reset to continue]\r\n");
            return Ok(true);
        }
        self.planner.push_back(if jog {
            Block::Jog { target: t, speed }
        } else {
            Block::Move { target: t, speed }
        });
        if jog {
            self.mode = Mode::Jog;
        }
        self.execute(stage);
        Ok(false) // not deferred
    }

    fn planned_end(&self, stage: &Stage) -> [f64; 2] {
        match self.planner.iter().rev().chain(self.current.iter()).next() {
            Some(Block::Move { target, .. } | Block::Jog { target, .. }) => *target,
            None => [stage.logical(0), stage.logical(1)],
        }
    }

    fn dollar(&mut self, rest: &str, stage: &mut Stage, out: &mut Vec<u8>) -> Result<bool, u32> {
        let idle_or_alarm = matches!(self.mode, Mode::Idle | Mode::Alarm) && !stage.is_busy();
        match rest {
            "" => {
                out.extend_from_slice(
                    b"[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]\r\n",
                );
                Ok(true)
            }
            "$" => {
                if !idle_or_alarm {
                    return Err(8);
                }
                for (k, v) in &self.settings {
                    out.extend_from_slice(format!("${k}={}\r\n", fmt_setting(*v)).as_bytes());
                }
                Ok(true)
            }
            "I" => {
                out.extend_from_slice(b"[VER:1.1h.20190830:rig-sim]\r\n[OPT:V,15,128]\r\n");
                Ok(true)
            }
            "G" => {
                let g = format!(
                    "[GC:G0 G54 G17 {} {} G94 M5 M9 T0 F{} S0]\r\n",
                    if self.inches { "G20" } else { "G21" },
                    if self.absolute { "G90" } else { "G91" },
                    fmt_setting(self.feed_mm_min.unwrap_or(0.0))
                );
                out.extend_from_slice(g.as_bytes());
                Ok(true)
            }
            "#" => {
                // The offsets as they are, in the report unit ($13).
                let f = |um: f64| self.coord(um);
                let (a, b) = (self.g54_um, self.g92_um);
                let z = f(0.0);
                out.extend_from_slice(
                    format!(
                        "[G54:{},{},{z}]\r\n[G28:{z},{z},{z}]\r\n[G30:{z},{z},{z}]\r\n[G92:{},{},{z}]\r\n[TLO:{z}]\r\n[PRB:{z},{z},{z}:0]\r\n",
                        f(a[0]),
                        f(a[1]),
                        f(b[0]),
                        f(b[1])
                    )
                    .as_bytes(),
                );
                Ok(true)
            }
            "X" => {
                if self.mode == Mode::Alarm {
                    self.mode = Mode::Idle;
                    out.extend_from_slice(b"[MSG:Caution: Unlocked]\r\n");
                }
                Ok(true)
            }
            "H" => {
                if self.settings[&22] == 0.0 {
                    return Err(5);
                }
                if !idle_or_alarm {
                    return Err(8);
                }
                self.mode = Mode::Home;
                self.sync = Some(Sync::Home);
                // `$23` picks the switch per axis; machine zero on a + switch, minus the max
                // travel on a − switch; then the pull-off (`$27`) away from it.
                let dir = homing_dirs(self.settings[&23]);
                let trip = [0, 1].map(|k| {
                    if dir[k] > 0.0 {
                        0.0
                    } else {
                        -self.settings[&(130 + k as u32)] * 1000.0
                    }
                });
                stage.start_home(crate::stage::HomingCycle {
                    dir,
                    trip_logical_um: Some(trip),
                    pulloff_um: Some(self.settings[&27] * 1000.0),
                });
                Ok(false)
            }
            _ => {
                if let Some(j) = rest.strip_prefix("J=") {
                    if !matches!(self.mode, Mode::Idle | Mode::Jog) {
                        return Err(8);
                    }
                    let words = parse_words(j).map_err(|_| 16u32)?;
                    return self
                        .gcode(&words, stage, true, out)
                        .map(|deferred| !deferred);
                }
                if let Some((k, v)) = rest.split_once('=') {
                    let k: u32 = k.parse().map_err(|_| 3u32)?;
                    let v: f64 = v.parse().map_err(|_| 2u32)?;
                    if !self.settings.contains_key(&k) {
                        return Err(3);
                    }
                    if !idle_or_alarm {
                        return Err(8);
                    }
                    if v < 0.0 {
                        return Err(4);
                    }
                    if k == 20 && v != 0.0 && self.settings[&22] == 0.0 {
                        return Err(10);
                    }
                    self.settings.insert(k, v);
                    return Ok(true);
                }
                Err(3)
            }
        }
    }

    pub fn next_event_time(&self) -> Option<f64> {
        None
    }

    pub fn on_event(&mut self, ev: StageEvent, stage: &mut Stage, out: &mut Vec<u8>) {
        match ev {
            StageEvent::MotionDone(kind) => {
                if kind == MotionKind::HomeSeek {
                    // Homing cut short (a stop during the seek): GRBL's homing failure.
                    self.late_report = false;
                    self.alarm(stage, 9, out);
                    return;
                }
                if kind == MotionKind::Dwell {
                    if let Some(Sync::Dwell { started: true, .. }) = self.sync {
                        self.sync = None;
                        out.extend_from_slice(b"ok\r\n");
                    }
                }
                if self.mode == Mode::Hold {
                    return; // Hold:0 until `~` or a reset
                }
                self.execute(stage);
                self.pump(stage, out);
            }
            StageEvent::Homed => {
                if std::mem::take(&mut self.late_report) {
                    // The request that waited through the cycle, answered before its `ok`.
                    let r = self.status_report(stage);
                    out.extend_from_slice(r.as_bytes());
                }
                self.mode = Mode::Idle;
                if let Some(Sync::Home) = self.sync {
                    self.sync = None;
                    out.extend_from_slice(b"ok\r\n");
                }
                self.pump(stage, out);
            }
            StageEvent::Faulted(StopCause::Limit { .. })
            | StageEvent::Faulted(StopCause::Stall { .. }) => {
                // Hard limit (a stalled driver reports through the limit pin, as sensorless
                // set-ups do): position lost, reset required.
                stage.lose_reference();
                self.alarm(stage, 1, out);
                self.critical = true;
                out.extend_from_slice(b"[MSG:Reset to continue]\r\n");
            }
            StageEvent::Faulted(StopCause::EStop) => {
                // The e-stop is wired to the reset pin.
                stage.lose_reference();
                out.extend_from_slice(b"ALARM:3\r\n");
                self.mode = Mode::Alarm;
                self.boot(stage, out, false);
            }
            StageEvent::Reset => {
                stage.power_on_reference();
                self.boot(stage, out, true);
            }
            StageEvent::Disconnect => {}
        }
    }
}

/// µm → mm rounded to GRBL's three decimals, without a "-0.000".
fn mm3(um: f64) -> f64 {
    (um / 1000.0 * 1000.0).round() / 1000.0 + 0.0
}

fn strip_comments(s: &str) -> String {
    let mut out = String::new();
    let mut paren = false;
    for c in s.chars() {
        match c {
            '(' => paren = true,
            ')' => paren = false,
            ';' if !paren => break,
            _ if !paren => out.push(c),
            _ => {}
        }
    }
    out
}

/// Splits `G1X10.5Y-3F600` into letter/number words: error 1 for a non-letter where a letter
/// belongs, error 2 for a bad number.
fn parse_words(line: &str) -> Result<Vec<(char, f64)>, u32> {
    let b = line.as_bytes();
    let mut i = 0;
    let mut words = Vec::new();
    while i < b.len() {
        let l = b[i] as char;
        if !l.is_ascii_alphabetic() {
            return Err(1);
        }
        i += 1;
        let start = i;
        while i < b.len() && (b[i].is_ascii_digit() || b[i] == b'.' || b[i] == b'-' || b[i] == b'+')
        {
            i += 1;
        }
        let v: f64 = line[start..i].parse().map_err(|_| 2u32)?;
        if !v.is_finite() {
            return Err(2);
        }
        words.push((l, v));
    }
    Ok(words)
}

/// The firmware on a stage under a virtual clock, byte for byte, against what GRBL 1.1's
/// documents and source say: Interface.md ("send a line, wait for `ok`"; a line is answered
/// once executed), Commands.md (`!`, `~`, 0x18), protocol.c (a complete hold suspends the main
/// loop), motion_control.c (mc_dwell synchronises with the planner; mc_reset's alarms).
#[cfg(test)]
mod tests {
    use super::*;
    use crate::faults::FaultSpec;
    use crate::rng::Rng;
    use crate::stage::StageConfig;

    struct Board {
        fw: GrblFirmware,
        stage: Stage,
        out: Vec<u8>,
    }

    impl Board {
        /// A board homed toward + before this run (machine −250..0 mm), Idle at machine
        /// −100, −100 mm.
        fn homed() -> Board {
            let mut rng = Rng::new(3);
            let mut cfg = StageConfig::grbl(&mut rng, [1.0, 1.0]);
            cfg.repeat_sigma_um = 0.0;
            let stage = Stage::new(cfg, FaultSpec::default(), 3, true);
            let mut boot = Vec::new();
            let fw = GrblFirmware::new(&stage, &[], &mut boot);
            let mut b = Board {
                fw,
                stage,
                out: Vec::new(),
            };
            assert_eq!(b.tx(b"G90 G21 G53 G0 X-100 Y-100\n"), "ok\r\n");
            b.run(60.0);
            assert_eq!(b.mpos(), "MPos:-100.000,-100.000,0.000");
            b
        }

        /// Bytes in; what the board printed at once.
        fn tx(&mut self, bytes: &[u8]) -> String {
            self.fw.on_bytes(bytes, &mut self.stage, &mut self.out);
            String::from_utf8(std::mem::take(&mut self.out)).unwrap()
        }

        /// Runs the virtual clock `dt` seconds on; what the board printed meanwhile.
        fn run(&mut self, dt: f64) -> String {
            let end = self.stage.t + dt;
            for _ in 0..10_000 {
                let next = self.stage.next_event_time().filter(|&t| t <= end);
                let mut events = Vec::new();
                self.stage.advance(next.unwrap_or(end), &mut events);
                for e in events {
                    self.fw.on_event(e, &mut self.stage, &mut self.out);
                }
                if next.is_none() {
                    break;
                }
            }
            String::from_utf8(std::mem::take(&mut self.out)).unwrap()
        }

        fn state(&mut self) -> String {
            let r = self.tx(b"?");
            r.trim_start_matches('<').split('|').next().unwrap().into()
        }

        fn mpos(&mut self) -> String {
            let r = self.tx(b"?");
            r.split('|').nth(1).unwrap().into()
        }
    }

    /// A `G4` waits for the planner to empty before its delay, and the parser takes no line
    /// until it is done: the lines behind it, and their `ok`s, wait (mc_dwell →
    /// protocol_buffer_synchronize; protocol_main_loop executes one line before it reads the
    /// next). The dwell itself runs with GRBL Idle (the cycle has ended).
    #[test]
    fn lines_and_their_oks_wait_behind_a_pending_dwell() {
        let mut b = Board::homed();
        // 50 mm at 10 mm/s: 5 s of motion; then the sync point and two more lines.
        let out = b.tx(b"G90 G21 G53 G1 X-60 Y-70 F600\nG4 P0.5\n\n$I\n");
        assert_eq!(
            out, "ok\r\n",
            "only the move is answered: the G4 holds the parser"
        );
        assert_eq!(b.run(2.0), "", "mid-move: nothing more answered");
        assert_eq!(b.state(), "Run");
        // The move ends (5.1 s); the dwell's delay runs, GRBL Idle, nothing answered yet.
        let out = b.run(3.3);
        assert_eq!(out, "", "{out:?}");
        assert_eq!(b.state(), "Idle");
        // The dwell ends: its `ok`, then the lines behind it, in order.
        let out = b.run(1.0);
        assert!(
            out.starts_with("ok\r\nok\r\n[VER:") && out.ends_with("ok\r\n"),
            "{out:?}"
        );
    }

    /// A feed hold stops the motion and the planner does not empty, so a pending `G4` never
    /// completes; once the hold is complete (`Hold:0`) GRBL's main loop is suspended and reads
    /// no line (protocol_exec_rt_suspend) until cycle start, which resumes the motion, after
    /// which the `G4` and the lines behind it are answered in order.
    #[test]
    fn a_pending_dwell_waits_behind_a_feed_hold_until_cycle_start() {
        let mut b = Board::homed();
        assert_eq!(b.tx(b"G90 G21 G53 G1 X-60 Y-70 F600\nG4 P0.01\n"), "ok\r\n");
        b.run(1.0);
        assert_eq!(b.tx(b"!"), "");
        assert_eq!(b.state(), "Hold:1", "decelerating");
        b.run(1.0);
        assert_eq!(b.state(), "Hold:0", "hold complete");
        let held_at = b.mpos();
        // Held: no line is answered, however long, and nothing moves.
        assert_eq!(b.tx(b"\n$I\n"), "");
        assert_eq!(b.run(120.0), "");
        assert_eq!((b.state(), b.mpos()), ("Hold:0".to_string(), held_at));
        // `~` resumes: the move ends, then the dwell's `ok` and the lines behind it.
        assert_eq!(b.tx(b"~"), "");
        assert_eq!(b.state(), "Run");
        let out = b.run(10.0);
        assert!(
            out.starts_with("ok\r\nok\r\n[VER:") && out.ends_with("ok\r\n"),
            "{out:?}"
        );
        assert_eq!(b.mpos(), "MPos:-60.000,-70.000,0.000");
    }

    /// GRBL's way out of a hold that should not resume: a soft reset once still. In `Hold:0`
    /// it keeps the position and raises no alarm (Commands.md: "If reset while in not motion,
    /// position is retained"); the banner says the planner and the pending lines are gone, and
    /// the next line is answered at once. In `Hold:1` (still decelerating) it is ALARM:3.
    #[test]
    fn a_soft_reset_in_hold_0_keeps_the_position_and_frees_the_parser() {
        let mut b = Board::homed();
        b.tx(b"G90 G21 G53 G1 X-60 Y-70 F600\nG4 P0.01\n\n");
        b.run(1.0);
        b.tx(b"!");
        b.run(1.0);
        let held_at = b.mpos();
        let out = b.tx(&[0x18]);
        assert_eq!(out, BANNER, "no alarm, no `ok` for the dropped lines");
        assert_eq!((b.state(), b.mpos()), ("Idle".to_string(), held_at));
        assert!(b.stage.homed, "the reference is kept");
        assert_eq!(b.run(30.0), "", "the rest of the move was dropped");
        assert_eq!(b.tx(b"\n"), "ok\r\n");

        let mut b = Board::homed();
        b.tx(b"G90 G21 G53 G1 X-60 Y-70 F600\n");
        b.run(1.0);
        b.tx(b"!");
        assert_eq!(b.state(), "Hold:1");
        let out = b.tx(&[0x18]);
        assert!(out.starts_with("ALARM:3\r\n"), "{out:?}");
        assert_eq!(b.state(), "Alarm");
        assert!(!b.stage.homed, "reset while decelerating: position lost");
    }

    /// `!` in Idle is `Hold:0` at once (protocol.c: "If IDLE, Grbl is not in motion. Simply
    /// indicate suspend state and hold is complete"), with the main loop suspended; `~` brings
    /// it back to Idle and the waiting line is answered. In a jog, `!` cancels the jog (Idle,
    /// not Hold); during homing and in Alarm it is ignored.
    #[test]
    fn feed_hold_in_idle_jog_homing_and_alarm() {
        let mut b = Board::homed();
        // A `?` that comes with the `!` is answered first (protocol_exec_rt_system serves the
        // status report before the hold): Idle, then Hold:0.
        assert!(b.tx(b"!?").starts_with("<Idle|"));
        assert_eq!(b.state(), "Hold:0");
        assert_eq!(b.tx(b"\n"), "", "suspended: the line waits");
        assert_eq!(b.tx(b"~"), "ok\r\n", "resumed to Idle, the line answered");
        assert_eq!(b.state(), "Idle");

        assert_eq!(b.tx(b"$J=G91 G21 X-20 F600\n"), "ok\r\n");
        b.run(0.5);
        b.tx(b"!");
        b.run(1.0);
        assert_eq!(b.state(), "Idle", "a feed hold cancels a jog");

        let mut b = Board::homed();
        assert_eq!(b.tx(b"$H\n"), "");
        b.run(0.5);
        b.tx(b"!");
        assert_eq!(b.tx(b"?"), "", "silent while homing; the hold is ignored");
        // A reset aborts the cycle: ALARM:6, and the reference is not set.
        let out = b.tx(&[0x18]);
        assert!(
            out.starts_with("ALARM:6\r\n") && out.contains("Grbl 1.1h") && out.contains("unlock"),
            "{out:?}"
        );
        assert_eq!(b.state(), "Alarm");
        assert!(!b.stage.homed);
        b.tx(b"!");
        assert_eq!(b.state(), "Alarm", "ignored in Alarm");
    }
}
