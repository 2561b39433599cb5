//! GRBL 1.1's `$$` settings as the rig uses them, each range-checked before use (a `$110=0`
//! would otherwise make every wait infinite, a `$130=1e9` a 1000 km travel), and what the rig
//! needs of a board's set-up (`rig stage check-setup`).

use crate::coords::CarriageUm;
use crate::stage::limits_check::{check, Range};
use crate::stage::{Result, SoftLimits};
use serde::Serialize;
use std::collections::BTreeMap;

/// The settings the rig computes with; units as GRBL's (mm, mm/min, mm/s², ms).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GrblSettings {
    /// `$10` bit 0: reports carry MPos (set) or WPos (clear).
    pub reports_mpos: bool,
    /// `$13`: reports in inches.
    pub report_inches: bool,
    /// `$20`, `$21`, `$22`.
    pub soft_limits: bool,
    pub hard_limits: bool,
    pub homing: bool,
    /// `$23`: per axis, homing toward the − switch (bit set) instead of the + switch.
    pub home_negative: [bool; 2],
    /// `$24` locate (slow) and `$25` seek (fast) homing rates, mm/min.
    pub locate_mm_min: f64,
    pub seek_mm_min: f64,
    /// `$26` switch debounce, ms.
    pub debounce_ms: f64,
    /// `$27` pull-off from the switch after homing, mm.
    pub pulloff_mm: f64,
    /// `$100`, `$101`, steps/mm.
    pub steps_per_mm: [f64; 2],
    /// `$110`, `$111` max rates, mm/min.
    pub max_rate_mm_min: [f64; 2],
    /// `$120`, `$121` accelerations, mm/s².
    pub accel_mm_s2: [f64; 2],
    /// `$130`, `$131` max travel, mm.
    pub travel_mm: [f64; 2],
}

const FLAG: Range = Range::closed(0.0, 1.0);
const MASK: Range = Range::closed(0.0, 255.0);
const RATE: Range = Range::closed(1.0, 100_000.0);
const ACCEL: Range = Range::closed(0.1, 100_000.0);
const TRAVEL: Range = Range::closed(1.0, 10_000.0);
const STEPS: Range = Range::positive(1_000_000.0);
const DEBOUNCE: Range = Range::closed(0.0, 10_000.0);

/// What each setting is, for messages.
pub fn meaning(k: u32) -> &'static str {
    match k {
        10 => "status report mask",
        13 => "report inches",
        20 => "soft limits",
        21 => "hard limits",
        22 => "homing cycle",
        23 => "homing direction mask",
        24 => "homing locate rate, mm/min",
        25 => "homing seek rate, mm/min",
        26 => "homing debounce, ms",
        27 => "homing pull-off, mm",
        100 => "X steps/mm",
        101 => "Y steps/mm",
        110 => "X max rate, mm/min",
        111 => "Y max rate, mm/min",
        120 => "X acceleration, mm/s²",
        121 => "Y acceleration, mm/s²",
        130 => "X max travel, mm",
        131 => "Y max travel, mm",
        _ => "setting",
    }
}

/// The settings the rig cannot work without.
pub const REQUIRED: [u32; 11] = [10, 13, 22, 24, 25, 27, 110, 111, 120, 121, 130];

impl GrblSettings {
    /// Parses the `$N=value` lines of a `$$` dump (other lines ignored).
    pub fn parse_lines(lines: &[String]) -> BTreeMap<u32, f64> {
        let mut s = BTreeMap::new();
        for l in lines {
            if let Some((k, v)) = l.strip_prefix('$').and_then(|r| r.split_once('=')) {
                if let (Ok(k), Ok(v)) = (k.trim().parse::<u32>(), v.trim().parse::<f64>()) {
                    s.insert(k, v);
                }
            }
        }
        s
    }

    /// Checks every setting the rig uses; the first one out of range is the error.
    pub fn from_raw(raw: &BTreeMap<u32, f64>) -> Result<GrblSettings> {
        let get = |k: u32, r: &Range| -> Result<f64> {
            let name = format!("${k} ({})", meaning(k));
            match raw.get(&k) {
                Some(&v) => check("GRBL", &name, v, r, &format!("`${k}=…`")),
                None => Err(super::StageError::Protocol(format!(
                    "GRBL's `$$` lacks ${k} ({}): is this GRBL 1.1?",
                    meaning(k)
                ))),
            }
        };
        let bits = |k: u32| -> Result<u32> { Ok(get(k, &MASK)?.round() as u32) };
        let flag = |k: u32| -> Result<bool> { Ok(get(k, &FLAG)? != 0.0) };
        let travel = [get(130, &TRAVEL)?, get(131, &TRAVEL)?];
        let max_pulloff = travel[0].min(travel[1]) / 4.0;
        let pulloff = get(27, &Range::closed(0.0, max_pulloff))?;
        let dir = bits(23)?;
        // Optional: a board without them has GRBL's defaults.
        let opt = |k: u32, r: &Range, default: f64| -> Result<f64> {
            if raw.contains_key(&k) {
                get(k, r)
            } else {
                Ok(default)
            }
        };
        Ok(GrblSettings {
            reports_mpos: bits(10)? & 1 != 0,
            report_inches: flag(13)?,
            soft_limits: opt(20, &FLAG, 0.0)? != 0.0,
            hard_limits: opt(21, &FLAG, 0.0)? != 0.0,
            homing: flag(22)?,
            home_negative: [dir & 1 != 0, dir & 2 != 0],
            locate_mm_min: get(24, &RATE)?,
            seek_mm_min: get(25, &RATE)?,
            debounce_ms: opt(26, &DEBOUNCE, 250.0)?,
            pulloff_mm: pulloff,
            steps_per_mm: [opt(100, &STEPS, 1000.0)?, opt(101, &STEPS, 1000.0)?],
            max_rate_mm_min: [get(110, &RATE)?, get(111, &RATE)?],
            accel_mm_s2: [get(120, &ACCEL)?, get(121, &ACCEL)?],
            travel_mm: travel,
        })
    }

    pub fn travel(&self) -> CarriageUm {
        CarriageUm::from_mm(self.travel_mm[0], self.travel_mm[1])
    }

    /// The carriage range the rig may use: the travel, kept a pull-off away from the homing
    /// switch on each axis (at the − end for a `$23` bit set, else at the + end).
    pub fn soft_limits(&self) -> SoftLimits {
        let p = self.pulloff_mm * 1000.0;
        let t = self.travel();
        let (mut min, mut max) = (CarriageUm::new(0.0, 0.0), t);
        for k in 0..2 {
            if self.home_negative[k] {
                min = min.with_axis(k, p);
            } else {
                max = max.with_axis(k, (t.axis(k) - p).max(0.0));
            }
        }
        SoftLimits { min, max }
    }

    /// Where a completed homing cycle leaves the carriage (the pull-off from the switch).
    pub fn home_position(&self) -> CarriageUm {
        let p = self.pulloff_mm * 1000.0;
        let t = self.travel();
        CarriageUm::new(
            if self.home_negative[0] { p } else { t.x - p },
            if self.home_negative[1] { p } else { t.y - p },
        )
    }

    pub fn max_speed_um_s(&self) -> f64 {
        self.max_rate_mm_min[0].min(self.max_rate_mm_min[1]) * 1000.0 / 60.0
    }

    pub fn accel_um_s2(&self) -> f64 {
        self.accel_mm_s2[0].min(self.accel_mm_s2[1]) * 1000.0
    }

    /// The longest a homing cycle can take, seconds, from GRBL 1.1's documented cycle: a seek
    /// of up to 1.5 × the max travel at `$25`, pull-off, a locate of up to 5 × the pull-off at
    /// `$24`, the final pull-off; a debounce delay and an acceleration ramp in each phase. The
    /// axes are summed (a board built to home X and Y in turn takes that long).
    pub fn homing_bound_s(&self) -> f64 {
        let seek = self.seek_mm_min / 60.0;
        let locate = self.locate_mm_min / 60.0;
        let a = self.accel_mm_s2[0].min(self.accel_mm_s2[1]);
        let p = self.pulloff_mm.max(0.1);
        let per_axis = |t: f64| {
            1.5 * t / seek + 2.0 * p / seek + 5.0 * p / locate + 4.0 * (seek / a + locate / a)
        };
        per_axis(self.travel_mm[0]) + per_axis(self.travel_mm[1]) + 4.0 * self.debounce_ms / 1000.0
    }

    /// What the board's set-up means for the rig: (setting, what it is now, what to do).
    /// Empty when nothing needs changing.
    pub fn advice(&self) -> Vec<(String, String, String)> {
        let mut a = Vec::new();
        let mut say = |k: &str, now: String, todo: &str| a.push((k.to_string(), now, todo.into()));
        if !self.homing {
            say(
                "$22",
                "0 (homing off)".into(),
                "send `$22=1`: without homing no position is referenced and the rig will not move",
            );
        }
        if !self.soft_limits {
            say(
                "$20",
                "0 (soft limits off)".into(),
                "send `$20=1` (after `$22=1`): the board then refuses targets beyond $130/$131 too, not only the rig",
            );
        }
        if !self.hard_limits {
            say(
                "$21",
                "0 (hard limits off)".into(),
                "send `$21=1` if the switches are wired: a switch hit outside homing then stops the motors",
            );
        }
        if !self.reports_mpos {
            say(
                "$10",
                "WPos reports".into(),
                "works (the rig adds the WCO), but `$10=1` (MPos) saves a lookup",
            );
        }
        if self.report_inches {
            say(
                "$13",
                "1 (inches)".into(),
                "works (the rig converts), but `$13=0` keeps the reports in the rig's unit",
            );
        }
        a
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raw() -> BTreeMap<u32, f64> {
        [
            (10, 1.0),
            (13, 0.0),
            (20, 1.0),
            (21, 1.0),
            (22, 1.0),
            (23, 0.0),
            (24, 25.0),
            (25, 600.0),
            (26, 250.0),
            (27, 1.0),
            (110, 1200.0),
            (111, 1200.0),
            (120, 100.0),
            (121, 100.0),
            (130, 250.0),
            (131, 200.0),
        ]
        .into_iter()
        .collect()
    }

    #[test]
    fn limits_keep_a_pull_off_from_the_homing_switch() {
        let s = GrblSettings::from_raw(&raw()).unwrap();
        let l = s.soft_limits();
        assert_eq!(l.min, CarriageUm::new(0.0, 0.0));
        assert_eq!(l.max, CarriageUm::new(249_000.0, 199_000.0));
        assert_eq!(s.home_position(), CarriageUm::new(249_000.0, 199_000.0));
        let mut r = raw();
        r.insert(23, 2.0); // Y homes toward −
        let s = GrblSettings::from_raw(&r).unwrap();
        assert_eq!(s.soft_limits().min, CarriageUm::new(0.0, 1000.0));
        assert_eq!(s.soft_limits().max, CarriageUm::new(249_000.0, 200_000.0));
        assert_eq!(s.home_position(), CarriageUm::new(249_000.0, 1000.0));
    }

    #[test]
    fn absurd_settings_are_refused_by_name() {
        for (k, v) in [
            (110, 0.0),
            (111, -5.0),
            (120, f64::INFINITY),
            (121, 0.0),
            (130, 1e9),
            (131, f64::NAN),
            (24, 0.0),
            (25, 1e12),
            (27, -1.0),
            (27, 100.0),
            (13, 7.0),
            (23, 1e6),
        ] {
            let mut r = raw();
            r.insert(k, v);
            let e = GrblSettings::from_raw(&r).unwrap_err().to_string();
            assert!(e.contains(&format!("${k} (")), "${k}={v}: {e}");
            assert!(e.contains("allowed range"), "{e}");
        }
        let mut r = raw();
        r.remove(&130);
        assert!(GrblSettings::from_raw(&r)
            .unwrap_err()
            .to_string()
            .contains("$130"));
    }

    #[test]
    fn homing_bound_from_the_documented_cycle() {
        // Closed form for 250 x 200 mm at 600 mm/min seek, 25 mm/min locate, 1 mm pull-off,
        // 100 mm/s², 250 ms debounce.
        let s = GrblSettings::from_raw(&raw()).unwrap();
        let (seek, loc) = (10.0, 25.0 / 60.0);
        let ramps = 4.0 * (seek / 100.0 + loc / 100.0);
        let axis = |t: f64| 1.5 * t / seek + 2.0 / seek + 5.0 / loc + ramps;
        let want = axis(250.0) + axis(200.0) + 1.0;
        assert!((s.homing_bound_s() - want).abs() < 1e-9);
        // …which is longer than the seek alone over the whole travel, as it must be.
        assert!(s.homing_bound_s() > 450.0 / seek);
    }
}
