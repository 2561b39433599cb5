//! The physical X/Y stage: motors, backlash, carriage, limit switches, repeatability noise and
//! drift, moving on a virtual clock. The firmware dialects drive it; the truth file reads it.
//!
//! Coordinates: *physical* micrometres, where 0..travel is the carriage range a correctly homed
//! controller reports as 0..travel. The controller's *logical* position is `motor + reference`,
//! the reference being set by homing (arbitrary at power-on).

use crate::faults::{FaultSpec, MoveFault};
use crate::profile::Profile;
use crate::rng::Rng;
use serde::Serialize;

#[derive(Debug, Clone, Serialize)]
pub struct StageConfig {
    pub travel_um: [f64; 2],
    pub step_um: f64,
    pub backlash_um: [f64; 2],
    /// σ of where the carriage settles after a move, per axis.
    pub repeat_sigma_um: f64,
    /// Slow drift of the carriage with respect to the motors and encoders.
    pub drift_um_per_h: [f64; 2],
    pub max_speed_um_s: f64,
    pub accel_um_s2: f64,
    pub home_speed_um_s: f64,
    /// Physical positions of the min and max limit switches per axis.
    pub switch_um: [[f64; 2]; 2],
    /// Homing direction per axis: -1 toward the min switch, +1 toward the max switch.
    pub home_dir: [f64; 2],
    /// A GRBL board (machine zero on the homing switch, coordinates -travel..0) rather than the
    /// rig's own firmware (the carriage frame itself).
    pub grbl: bool,
    /// Distance moved back off the switch after homing.
    pub pulloff_um: f64,
    /// σ of the switch's trip point.
    pub switch_sigma_um: f64,
    /// Following error beyond which a stalled axis is detected; 0 = at the moment of the
    /// stall (sensorless stall detection in the driver, as on GRBL boards).
    pub following_tol_um: f64,
}

impl StageConfig {
    /// The rig's own firmware: homes to the min switches, 0.5 mm pull-off, a following-error
    /// check on the encoders.
    pub fn native(rng: &mut Rng) -> Self {
        Self::build(rng, [-1.0, -1.0], false)
    }

    /// A GRBL board homing toward + (`home_dir[k] > 0`) or − per axis (`$23`). The switch it
    /// homes on sits at the end of the 0..travel carriage frame (so a correctly homed board's
    /// machine coordinates plus the travel are the carriage frame), the other switch 0.5 mm
    /// beyond the far end of the travel.
    pub fn grbl(rng: &mut Rng, home_dir: [f64; 2]) -> Self {
        Self::build(rng, home_dir, true)
    }

    fn build(rng: &mut Rng, home_dir: [f64; 2], grbl: bool) -> Self {
        let travel = [250_000.0, 250_000.0];
        let switches = |k: usize| {
            if !grbl {
                [-500.0, travel[k] + 500.0]
            } else if home_dir[k] > 0.0 {
                [-500.0, travel[k]]
            } else {
                [0.0, travel[k] + 500.0]
            }
        };
        StageConfig {
            travel_um: travel,
            step_um: 0.25,
            backlash_um: [3.0, 2.5],
            repeat_sigma_um: 0.15,
            drift_um_per_h: [(rng.uniform() - 0.5) * 4.0, (rng.uniform() - 0.5) * 4.0],
            max_speed_um_s: 20_000.0,
            accel_um_s2: 100_000.0,
            home_speed_um_s: 10_000.0,
            switch_um: [switches(0), switches(1)],
            home_dir,
            grbl,
            pulloff_um: if grbl { 1000.0 } else { 500.0 },
            switch_sigma_um: 0.2,
            following_tol_um: if grbl { 0.0 } else { 20.0 },
        }
    }
}

/// How a controller takes its reference in a homing cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HomingCycle {
    /// -1 toward the min switch, +1 toward the max switch, per axis.
    pub dir: [f64; 2],
    /// The logical position given to each switch's trip point; `None`: the carriage frame
    /// itself (the native firmware's logical position is the carriage's).
    pub trip_logical_um: Option<[f64; 2]>,
    /// After the trip, move this far back off the switch; `None`: go to logical 0.
    pub pulloff_um: Option<f64>,
}

impl HomingCycle {
    /// The rig's own firmware: min switches, pull off to the carriage frame's origin.
    pub const NATIVE: HomingCycle = HomingCycle {
        dir: [-1.0, -1.0],
        trip_logical_um: None,
        pulloff_um: None,
    };
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MotionKind {
    Move,
    Jog,
    HomeSeek,
    HomePulloff,
    Dwell,
}

#[derive(Debug, Clone)]
struct Motion {
    kind: MotionKind,
    start_m: [f64; 2],
    dir: [f64; 2],
    profile: Profile,
    t0: f64,
    /// Exact motor end (step grid) for moves.
    end_m: Option<[f64; 2]>,
    fault: Option<(f64, MoveFault)>,
    /// Jog dead-man time.
    deadline: Option<f64>,
}

/// What happened while the clock advanced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StageEvent {
    MotionDone(MotionKind),
    Homed,
    /// Motion stopped at once by a fault.
    Faulted(StopCause),
    Reset,
    Disconnect,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopCause {
    /// Following error on this axis (a stall).
    Stall {
        axis: usize,
    },
    /// A limit switch closed: bits as in the protocol's status flags.
    Limit {
        switches: u8,
    },
    EStop,
}

#[derive(Debug, Clone, Serialize)]
pub struct InjectedFault {
    pub t_s: f64,
    pub fault: MoveFault,
    pub during: MotionKind,
    pub carriage_um: [f64; 2],
}

pub struct Stage {
    pub cfg: StageConfig,
    rng: Rng,
    /// Virtual time in seconds.
    pub t: f64,
    motor: [f64; 2],
    /// Backlash play taken up: carriage = motor + play + slip + settle (0 ≤ play ≤ backlash).
    play: [f64; 2],
    settle: [f64; 2],
    /// Persistent offset of the carriage from the motor: steps lost in a stall.
    slip: [f64; 2],
    /// Carriage of a stalled axis, frozen.
    stalled: [Option<f64>; 2],
    reference: [f64; 2],
    /// Where logical 0 lies in the carriage frame (set by homing): 0 for the native firmware,
    /// the machine zero for GRBL.
    zero_um: [f64; 2],
    pub homed: bool,
    motion: Option<Motion>,
    home_next: Option<MotionKind>,
    homing: Option<HomingCycle>,
    pub faults: FaultSpec,
    pub injected: Vec<InjectedFault>,
    /// Every target the controller accepted, in logical µm.
    pub accepted_targets: Vec<[f64; 2]>,
    /// Extremes of the carriage since the last homing, physical µm.
    pub excursion: Option<[[f64; 2]; 2]>,
    pub moves_done: u64,
}

impl Stage {
    pub fn new(cfg: StageConfig, faults: FaultSpec, seed: u64, start_homed: bool) -> Stage {
        let mut rng = Rng::new(seed ^ 0x57a9e);
        // Power-on somewhere inside the travel, away from the switches.
        let mut motor = [0.0; 2];
        for k in 0..2 {
            motor[k] = (0.2 + 0.6 * rng.uniform()) * cfg.travel_um[k];
        }
        let zero_um = if cfg.grbl { cfg.travel_um } else { [0.0; 2] };
        let mut s = Stage {
            cfg,
            rng,
            t: 0.0,
            motor,
            play: [0.0; 2],
            settle: [0.0; 2],
            slip: [0.0; 2],
            stalled: [None; 2],
            reference: [-motor[0], -motor[1]],
            zero_um,
            homed: false,
            motion: None,
            home_next: None,
            homing: None,
            faults,
            injected: Vec::new(),
            accepted_targets: Vec::new(),
            excursion: None,
            moves_done: 0,
        };
        if start_homed {
            // As if homed before this run (an absolute encoder, or a controller that kept its
            // reference): logical = motor, carriage taken up in + direction.
            s.reference = [-s.logical_to_carriage(0), -s.logical_to_carriage(1)];
            s.homed = true;
            for k in 0..2 {
                s.motor[k] = s.snap(s.motor[k]);
            }
            s.excursion = Some([[s.carriage(0); 2], [s.carriage(1); 2]]);
        }
        s
    }

    fn snap(&self, v: f64) -> f64 {
        (v / self.cfg.step_um).round() * self.cfg.step_um
    }

    /// Mechanical carriage position (what a linear encoder sees), physical µm.
    pub fn carriage(&self, k: usize) -> f64 {
        self.stalled[k].unwrap_or(self.mechanism(k))
    }

    /// Where the motor, the play and the slip put the carriage (ignoring a stall).
    fn mechanism(&self, k: usize) -> f64 {
        self.motor[k] + self.play[k] + self.slip[k] + self.settle[k]
    }

    /// The carriage where it really is, drift included: the truth.
    pub fn carriage_true(&self, k: usize) -> f64 {
        self.carriage(k) + self.cfg.drift_um_per_h[k] * self.t / 3600.0
    }

    /// A linear encoder on the carriage, referenced with the controller at homing: the carriage
    /// in the controller's frame (the slip is in the reference, not in what the scale sees).
    pub fn encoder(&self, k: usize) -> f64 {
        self.carriage(k) + self.reference[k] - self.slip[k]
    }

    /// Controller's logical position (its step count), µm.
    pub fn logical(&self, k: usize) -> f64 {
        self.motor[k] + self.reference[k]
    }

    /// Offset from a homed controller's logical frame to carriage coordinates: 0 for the
    /// native firmware, where GRBL's machine zero lies for GRBL (set by its homing).
    pub fn logical_to_carriage(&self, k: usize) -> f64 {
        self.zero_um[k]
    }

    pub fn is_busy(&self) -> bool {
        self.motion.is_some()
    }

    pub fn motion_kind(&self) -> Option<MotionKind> {
        self.motion.as_ref().map(|m| m.kind)
    }

    /// Closed limit switches, as protocol status flag bits.
    pub fn switches(&self) -> u8 {
        let mut f = 0;
        for k in 0..2 {
            let c = self.carriage(k);
            if c <= self.cfg.switch_um[k][0] {
                f |= 1 << (1 + 2 * k);
            }
            if c >= self.cfg.switch_um[k][1] {
                f |= 1 << (2 + 2 * k);
            }
        }
        f
    }

    /// When the next thing happens on its own (end of motion, a scheduled fault, a jog
    /// deadline), for a clock that jumps instead of waiting.
    pub fn next_event_time(&self) -> Option<f64> {
        let m = self.motion.as_ref()?;
        let mut t = m.t0 + m.profile.duration;
        if let Some((tf, _)) = m.fault {
            t = t.min(tf);
        }
        if let Some(d) = m.deadline {
            t = t.min(d);
        }
        Some(t)
    }

    fn begin(&mut self, kind: MotionKind, delta: [f64; 2], speed: f64, end_m: Option<[f64; 2]>) {
        let full = (delta[0] * delta[0] + delta[1] * delta[1]).sqrt();
        if !full.is_finite() {
            return; // no motor takes an infinite or NaN step count
        }
        let dir = if full > 0.0 {
            [delta[0] / full, delta[1] / full]
        } else {
            [0.0, 0.0]
        };
        // No path is longer than the frame the carriage runs in: a longer one would meet a
        // switch (and the end stop behind it) first. Capping keeps the clock's arithmetic sane
        // for absurd targets (GRBL happily parses X-1e39).
        let frame = 2.0 * (self.cfg.travel_um[0].max(self.cfg.travel_um[1]) + 10_000.0);
        let (len, end_m) = if full > frame {
            (frame, None)
        } else {
            (full, end_m)
        };
        let profile = Profile::new(
            len,
            0.0,
            speed.min(self.cfg.max_speed_um_s).max(1.0),
            self.cfg.accel_um_s2,
        );
        let fault = if matches!(kind, MotionKind::Move | MotionKind::Jog) && len > 0.0 {
            self.faults.draw_move_fault(&mut self.rng).map(|f| {
                let frac = 0.1 + 0.8 * self.rng.uniform();
                (self.t + frac * profile.duration, f)
            })
        } else {
            None
        };
        self.motion = Some(Motion {
            kind,
            start_m: self.motor,
            dir,
            profile,
            t0: self.t,
            end_m,
            fault,
            deadline: None,
        });
    }

    /// Starts a straight move to a logical target (already checked against soft limits).
    pub fn start_move(&mut self, target_logical: [f64; 2], speed: f64) {
        self.accepted_targets.push(target_logical);
        let mut end = [0.0; 2];
        for k in 0..2 {
            end[k] = self.snap(target_logical[k]) - self.reference[k];
        }
        let delta = [end[0] - self.motor[0], end[1] - self.motor[1]];
        self.begin(MotionKind::Move, delta, speed, Some(end));
    }

    /// Starts a jog at the given velocity, bounded by the logical box `bounds` and a dead-man
    /// time.
    pub fn start_jog(&mut self, v: [f64; 2], bounds: [[f64; 2]; 2], max_s: f64) {
        let speed = (v[0] * v[0] + v[1] * v[1]).sqrt();
        if speed == 0.0 {
            return;
        }
        let dir = [v[0] / speed, v[1] / speed];
        // Distance along dir to the edge of the box.
        let mut len = f64::INFINITY;
        for k in 0..2 {
            let p = self.logical(k);
            if dir[k] > 0.0 {
                len = len.min((bounds[k][1] - p) / dir[k]);
            } else if dir[k] < 0.0 {
                len = len.min((bounds[k][0] - p) / dir[k]);
            }
        }
        let len = len.max(0.0);
        self.begin(MotionKind::Jog, [dir[0] * len, dir[1] * len], speed, None);
        if let Some(m) = &mut self.motion {
            m.deadline = Some(self.t + max_s);
        }
    }

    pub fn start_dwell(&mut self, seconds: f64) {
        self.motion = Some(Motion {
            kind: MotionKind::Dwell,
            start_m: self.motor,
            dir: [0.0; 2],
            profile: Profile::dwell(seconds),
            t0: self.t,
            end_m: None,
            fault: None,
            deadline: None,
        });
    }

    /// Homing: seek the switch in `cycle.dir` on both axes, take the reference at its trip
    /// point, pull off.
    pub fn start_home(&mut self, cycle: HomingCycle) {
        self.homed = false;
        // The jam is cleared: the carriage stays where it froze while the motor ran on.
        for k in 0..2 {
            if let Some(c) = self.stalled[k].take() {
                self.slip[k] += c - self.mechanism(k);
            }
        }
        // Motor distance until each switch trips: first the play, then the carriage travel.
        let mut delta = [0.0; 2];
        for k in 0..2 {
            let d = cycle.dir[k];
            let sw = self.cfg.switch_um[k][if d > 0.0 { 1 } else { 0 }];
            let play_take = if d > 0.0 {
                self.play[k]
            } else {
                self.cfg.backlash_um[k] - self.play[k]
            };
            delta[k] = d * (play_take + (sw - self.carriage(k)).abs());
        }
        // Axes seek independently; model as one straight motion (both switches trip at the end).
        self.begin(MotionKind::HomeSeek, delta, self.cfg.home_speed_um_s, None);
        self.home_next = Some(MotionKind::HomePulloff);
        self.homing = Some(cycle);
    }

    /// Decelerating stop.
    pub fn stop(&mut self) {
        let Some(m) = &self.motion else { return };
        if m.kind == MotionKind::Dwell {
            self.motion = None;
            return;
        }
        let (s, v) = m.profile.at(self.t - m.t0);
        let stop_len = v * v / (2.0 * self.cfg.accel_um_s2);
        let mut nm = m.clone();
        nm.start_m = [m.start_m[0] + m.dir[0] * s, m.start_m[1] + m.dir[1] * s];
        nm.profile = Profile::new(stop_len, v, v, self.cfg.accel_um_s2);
        nm.t0 = self.t;
        nm.end_m = None;
        nm.deadline = None;
        self.motion = Some(nm);
        self.home_next = None;
    }

    /// Stop at once (emergency stop, fault, reset).
    pub fn halt(&mut self) {
        self.motion = None;
        self.home_next = None;
        self.homing = None;
    }

    /// After a power cycle the controller counts from 0 wherever the carriage is.
    pub fn power_on_reference(&mut self) {
        self.halt();
        self.homed = false;
        self.reference = [-self.motor[0], -self.motor[1]];
    }

    /// Clears the position reference (after a reset or a fault that lost steps).
    pub fn lose_reference(&mut self) {
        self.homed = false;
    }

    fn set_motor(&mut self, m: [f64; 2]) {
        for k in 0..2 {
            let dm = m[k] - self.motor[k];
            self.play[k] = (self.play[k] - dm).clamp(0.0, self.cfg.backlash_um[k]);
            self.motor[k] = m[k];
        }
        let c = [self.carriage(0), self.carriage(1)];
        if let Some(ex) = &mut self.excursion {
            for k in 0..2 {
                ex[k][0] = ex[k][0].min(c[k]);
                ex[k][1] = ex[k][1].max(c[k]);
            }
        }
    }

    /// When the carriage would reach a limit switch on this motion (a switch trips where it
    /// sits, however coarse the clock's steps). The play is taken as already taken up in the
    /// direction of travel, which can only make the trip earlier.
    fn switch_time(&self, m: &Motion) -> f64 {
        let mut t_hit = f64::INFINITY;
        for k in 0..2 {
            let d = m.dir[k];
            if d == 0.0 || self.stalled[k].is_some() {
                continue;
            }
            // Carriage = motor + play + slip + settle, with play 0 moving up and the backlash
            // moving down.
            let play = if d > 0.0 {
                0.0
            } else {
                self.cfg.backlash_um[k]
            };
            let sw = self.cfg.switch_um[k][if d > 0.0 { 1 } else { 0 }] + d * 1e-6;
            let s = (sw - play - self.slip[k] - self.settle[k] - m.start_m[k]) / d;
            if s <= 0.0 {
                // Already on the switch and driving further into it: it trips at once.
                t_hit = t_hit.min(self.t);
            } else if let Some(ts) = m.profile.time_at(s) {
                t_hit = t_hit.min(m.t0 + ts);
            }
        }
        t_hit.max(self.t)
    }

    /// Advances the clock to `t`, returning what happened on the way, in order.
    pub fn advance(&mut self, t: f64, events: &mut Vec<StageEvent>) {
        while let Some(m) = self.motion.clone() {
            let end = m.t0 + m.profile.duration;
            let fault_t = m.fault.map(|(tf, _)| tf).unwrap_or(f64::INFINITY);
            let dead_t = m.deadline.unwrap_or(f64::INFINITY);
            let switch_t = if m.kind == MotionKind::HomeSeek {
                f64::INFINITY
            } else {
                self.switch_time(&m)
            };
            let step_t = t.min(end).min(fault_t).min(dead_t).min(switch_t);
            let (s, _) = m.profile.at(step_t - m.t0);
            self.t = self.t.max(step_t);
            self.set_motor([m.start_m[0] + m.dir[0] * s, m.start_m[1] + m.dir[1] * s]);

            // A stalled axis is noticed once the motor has run away from the carriage.
            for k in 0..2 {
                if let Some(c) = self.stalled[k] {
                    if (self.mechanism(k) - c).abs() > self.cfg.following_tol_um {
                        self.halt();
                        events.push(StageEvent::Faulted(StopCause::Stall { axis: k }));
                        return;
                    }
                }
            }
            // A real switch closing outside homing stops everything.
            if !matches!(m.kind, MotionKind::HomeSeek | MotionKind::HomePulloff)
                && self.switches() != 0
            {
                let sw = self.switches();
                self.halt();
                events.push(StageEvent::Faulted(StopCause::Limit { switches: sw }));
                return;
            }
            if step_t >= fault_t {
                let (_, f) = m.fault.unwrap();
                self.injected.push(InjectedFault {
                    t_s: self.t,
                    fault: f,
                    during: m.kind,
                    carriage_um: [self.carriage_true(0), self.carriage_true(1)],
                });
                if let Some(mm) = &mut self.motion {
                    mm.fault = None;
                }
                match f {
                    MoveFault::Stall { axis } => {
                        self.stalled[axis] = Some(self.carriage(axis));
                        if self.cfg.following_tol_um <= 0.0 {
                            self.halt();
                            events.push(StageEvent::Faulted(StopCause::Stall { axis }));
                            return;
                        }
                    }
                    MoveFault::Limit => {
                        // A switch bounces closed (a loose wire, dirt on the contact).
                        let axis = self.rng.below(2) as usize;
                        let bit = 1u8 << (1 + 2 * axis + if m.dir[axis] > 0.0 { 1 } else { 0 });
                        self.halt();
                        events.push(StageEvent::Faulted(StopCause::Limit { switches: bit }));
                        return;
                    }
                    MoveFault::EStop => {
                        self.halt();
                        events.push(StageEvent::Faulted(StopCause::EStop));
                        return;
                    }
                    MoveFault::Reset => {
                        self.halt();
                        self.homed = false;
                        events.push(StageEvent::Reset);
                        return;
                    }
                    MoveFault::Disconnect => events.push(StageEvent::Disconnect),
                }
                continue;
            }
            if step_t >= dead_t {
                self.stop();
                continue;
            }
            if step_t < end {
                return; // still moving at t
            }
            // Motion finished.
            self.motion = None;
            if let Some(e) = m.end_m {
                self.set_motor(e);
            }
            if matches!(
                m.kind,
                MotionKind::Move | MotionKind::Jog | MotionKind::HomePulloff
            ) {
                for k in 0..2 {
                    if self.stalled[k].is_none() {
                        self.settle[k] = self.cfg.repeat_sigma_um * self.rng.normal();
                    }
                }
                self.moves_done += 1;
            }
            match (m.kind, self.home_next.take()) {
                (MotionKind::HomeSeek, Some(MotionKind::HomePulloff)) => {
                    // Reference at the trip point. The carriage sits on the switch: pin it there
                    // exactly (the slip absorbs any lost steps), and give the trip point the
                    // logical position the controller wants there (native: the carriage frame's
                    // own; GRBL: 0 on a + switch, minus the max travel on a − switch). Plus
                    // the switch's scatter.
                    let cycle = self.homing.unwrap_or(HomingCycle {
                        dir: self.cfg.home_dir,
                        trip_logical_um: None,
                        pulloff_um: None,
                    });
                    for k in 0..2 {
                        let noise = self.cfg.switch_sigma_um * self.rng.normal();
                        let sw = self.cfg.switch_um[k][if cycle.dir[k] > 0.0 { 1 } else { 0 }];
                        self.settle[k] = 0.0;
                        self.slip[k] = sw - self.motor[k] - self.play[k];
                        let trip = cycle.trip_logical_um.map_or(sw, |t| t[k]);
                        self.zero_um[k] = sw - trip;
                        self.reference[k] = self.slip[k] + noise - self.zero_um[k];
                    }
                    let delta = match cycle.pulloff_um {
                        Some(p) => [-cycle.dir[0] * p, -cycle.dir[1] * p],
                        // Native: pull off to logical 0 (the carriage frame's origin).
                        None => [-self.logical(0), -self.logical(1)],
                    };
                    let end = [
                        self.snap(self.motor[0] + delta[0]),
                        self.snap(self.motor[1] + delta[1]),
                    ];
                    self.begin(
                        MotionKind::HomePulloff,
                        [end[0] - self.motor[0], end[1] - self.motor[1]],
                        self.cfg.home_speed_um_s,
                        Some(end),
                    );
                    self.home_next = Some(MotionKind::Dwell); // marks "pull-off then homed"
                }
                (MotionKind::HomePulloff, Some(MotionKind::Dwell)) => {
                    self.homed = true;
                    self.excursion = Some([[self.carriage(0); 2], [self.carriage(1); 2]]);
                    events.push(StageEvent::Homed);
                }
                _ => events.push(StageEvent::MotionDone(m.kind)),
            }
        }
        self.t = self.t.max(t);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// GRBL's default cycle: + switches, machine zero on them, 1 mm pull-off.
    const GRBL_PLUS: HomingCycle = HomingCycle {
        dir: [1.0, 1.0],
        trip_logical_um: Some([0.0, 0.0]),
        pulloff_um: Some(1000.0),
    };

    fn stage(home_dir: f64, homed: bool) -> Stage {
        let mut rng = Rng::new(5);
        let mut cfg = if home_dir > 0.0 {
            StageConfig::grbl(&mut rng, [home_dir; 2])
        } else {
            StageConfig::native(&mut rng)
        };
        cfg.repeat_sigma_um = 0.0;
        cfg.switch_sigma_um = 0.0;
        Stage::new(cfg, FaultSpec::default(), 5, homed)
    }

    fn run(s: &mut Stage) -> Vec<StageEvent> {
        let mut ev = Vec::new();
        while let Some(t) = s.next_event_time() {
            s.advance(t, &mut ev);
        }
        ev
    }

    #[test]
    fn backlash_shows_only_when_arriving_downward() {
        let mut s = stage(-1.0, true);
        s.start_move([10_000.0, 10_000.0], 20_000.0);
        run(&mut s);
        s.start_move([100_000.0, 100_000.0], 20_000.0);
        run(&mut s);
        // Arriving in + direction: carriage = motor = target.
        assert!((s.carriage(0) - 100_000.0).abs() < 1e-9);
        s.start_move([90_000.0, 90_000.0], 20_000.0);
        run(&mut s);
        // Arriving in - direction: the carriage trails by the backlash.
        assert!((s.carriage(0) - 90_000.0 - s.cfg.backlash_um[0]).abs() < 1e-9);
        assert!((s.carriage(1) - 90_000.0 - s.cfg.backlash_um[1]).abs() < 1e-9);
        assert_eq!(s.logical(0), 90_000.0);
    }

    #[test]
    fn targets_land_on_the_step_grid() {
        let mut s = stage(-1.0, true);
        s.start_move([12_345.678, 1.1], 20_000.0);
        run(&mut s);
        assert_eq!(s.logical(0), 12_345.75); // 0.25 µm steps
        assert_eq!(s.logical(1), 1.0);
    }

    #[test]
    fn homing_frames_of_both_dialects() {
        // Native: min switches, origin at 0, last motion upward (no backlash showing).
        let mut s = stage(-1.0, false);
        s.start_home(HomingCycle::NATIVE);
        let ev = run(&mut s);
        assert_eq!(ev, vec![StageEvent::Homed]);
        assert!(s.homed);
        for k in 0..2 {
            assert!(
                s.logical(k).abs() < 1e-6 && s.carriage(k).abs() < 1e-6,
                "axis {k}: {} {}",
                s.logical(k),
                s.carriage(k)
            );
        }
        // GRBL: max switches, machine zero on the switch, pulled off downward by 1 mm, so the
        // carriage sits a backlash above what the controller reports.
        let mut s = stage(1.0, false);
        s.start_home(GRBL_PLUS);
        run(&mut s);
        for k in 0..2 {
            assert!((s.logical(k) + 1000.0).abs() < 1e-6);
            let reported = s.logical(k) + s.logical_to_carriage(k);
            assert!((s.carriage(k) - reported - s.cfg.backlash_um[k]).abs() < 1e-6);
        }
    }

    #[test]
    fn grbl_homing_toward_the_minus_switches() {
        // $23=3: the switches are at the 0 end; the trip point is machine −travel; the 1 mm
        // pull-off upward first takes up the backlash left by the downward seek, so the carriage
        // ends 1 mm less the backlash in, and machine + travel is the carriage frame.
        let mut rng = Rng::new(5);
        let mut cfg = StageConfig::grbl(&mut rng, [-1.0, -1.0]);
        cfg.repeat_sigma_um = 0.0;
        cfg.switch_sigma_um = 0.0;
        let mut s = Stage::new(cfg, FaultSpec::default(), 5, false);
        let travel = s.cfg.travel_um;
        s.start_home(HomingCycle {
            dir: [-1.0, -1.0],
            trip_logical_um: Some([-travel[0], -travel[1]]),
            pulloff_um: Some(1000.0),
        });
        assert_eq!(run(&mut s), vec![StageEvent::Homed]);
        for k in 0..2 {
            let c = 1000.0 - s.cfg.backlash_um[k];
            assert!((s.carriage(k) - c).abs() < 1e-6, "{}", s.carriage(k));
            assert!((s.logical(k) - (c - travel[k])).abs() < 1e-6);
            assert!((s.logical(k) + s.logical_to_carriage(k) - s.carriage(k)).abs() < 1e-6);
        }
    }

    #[test]
    fn drift_accumulates_with_virtual_time() {
        let mut s = stage(-1.0, true);
        let c0 = s.carriage_true(0);
        s.advance(3600.0, &mut Vec::new());
        assert!((s.carriage_true(0) - c0 - s.cfg.drift_um_per_h[0]).abs() < 1e-9);
        assert_eq!(s.carriage(0), c0 - 0.0, "the mechanism itself did not move");
    }

    #[test]
    fn running_onto_a_switch_is_a_limit_fault() {
        // Beyond the soft limits (the firmware would refuse these; the physics must still
        // stop), including an absurd target that GRBL would happily parse.
        for x in [-2_000.0, -1e42] {
            let mut s = stage(-1.0, true);
            s.start_move([x, 50_000.0], 20_000.0);
            let ev = run(&mut s);
            assert!(
                matches!(ev.as_slice(), [StageEvent::Faulted(StopCause::Limit { switches })] if switches & 0b10 != 0),
                "{x}: {ev:?}"
            );
            assert!(!s.is_busy());
            // It stops on the switch, not past it, even though the clock jumped in one step.
            let sw = s.cfg.switch_um[0][0];
            assert!(
                s.carriage(0) <= sw && s.carriage(0) > sw - 0.01,
                "{x}: stopped at {} for a switch at {sw}",
                s.carriage(0)
            );
        }
    }

    #[test]
    fn driving_further_into_a_closed_switch_trips_at_once() {
        let mut s = stage(-1.0, true);
        s.start_move([-2_000.0, 50_000.0], 20_000.0);
        run(&mut s);
        let c0 = s.carriage(0);
        s.start_move([-200_000.0, 50_000.0], 20_000.0);
        let ev = run(&mut s);
        assert!(
            matches!(
                ev.as_slice(),
                [StageEvent::Faulted(StopCause::Limit { .. })]
            ),
            "{ev:?}"
        );
        assert!(
            (s.carriage(0) - c0).abs() < 1e-6,
            "did not move further: {} vs {c0}",
            s.carriage(0)
        );
    }

    #[test]
    fn after_a_stall_homing_restores_carriage_and_encoder() {
        let mut rng = Rng::new(5);
        let mut cfg = StageConfig::native(&mut rng);
        cfg.repeat_sigma_um = 0.0;
        cfg.switch_sigma_um = 0.0;
        let mut s = Stage::new(cfg, FaultSpec::parse("stall=y:1").unwrap(), 5, true);
        s.start_move([100_000.0, 150_000.0], 20_000.0);
        let ev = run(&mut s);
        assert!(
            matches!(
                ev.as_slice(),
                [StageEvent::Faulted(StopCause::Stall { axis: 1 })]
            ),
            "{ev:?}"
        );
        // Steps were lost on Y: the carriage is not where the motor count says.
        assert!((s.carriage(1) - (s.logical(1))).abs() > 10.0);
        s.faults = FaultSpec::default();
        s.start_home(HomingCycle::NATIVE);
        assert_eq!(run(&mut s), vec![StageEvent::Homed]);
        s.start_move([50_000.0, 60_000.0], 20_000.0);
        run(&mut s);
        for (k, want) in [(0, 50_000.0), (1, 60_000.0)] {
            assert!(
                (s.carriage(k) - want).abs() < 1e-6,
                "axis {k}: carriage {}",
                s.carriage(k)
            );
            assert!(
                (s.encoder(k) - want).abs() < 1e-6,
                "axis {k}: encoder {}",
                s.encoder(k)
            );
        }
    }

    #[test]
    fn stop_decelerates_over_v_squared_over_2a() {
        let mut s = stage(-1.0, true);
        let x0 = s.logical(0);
        s.start_move(
            [
                x0 + 200_000.0_f64.min(s.cfg.travel_um[0] - x0),
                s.logical(1),
            ],
            20_000.0,
        );
        // Cruise reached after v/a = 0.2 s; stop at 1 s.
        s.advance(1.0, &mut Vec::new());
        let x1 = s.logical(0);
        s.stop();
        run(&mut s);
        let v: f64 = 20_000.0;
        let expect = v * v / (2.0 * s.cfg.accel_um_s2);
        assert!(
            (s.logical(0) - x1 - expect).abs() < 1e-6,
            "stopping distance {}",
            s.logical(0) - x1
        );
    }
}
