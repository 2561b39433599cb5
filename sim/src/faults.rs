//! Fault injection: what `--faults SPEC` asks for, and the line filter that applies the
//! byte-level faults to both directions.
//!
//! SPEC is a comma-separated list of `kind=value` items:
//!
//! | item | meaning |
//! |---|---|
//! | `drop=P` | each byte, in either direction, is lost with probability P |
//! | `corrupt=P` | each byte has one random bit flipped with probability P |
//! | `dup=P` | each byte is sent twice with probability P |
//! | `delay=P:MS` | before each byte the controller sends, with probability P, the line goes quiet for MS ms |
//! | `stall=P` or `stall=x:P` | each move stalls an axis (x, y or a random one) part way with probability P |
//! | `limit=P` | each move trips a limit switch part way with probability P |
//! | `reset=P` | each move is cut by a controller reset part way with probability P |
//! | `estop=P` | each move is cut by the emergency-stop button part way with probability P |
//! | `disconnect=P` | each move is followed by the line going dead part way with probability P |
//!
//! Example: `--faults drop=0.001,corrupt=0.001,reset=0.1`.

use crate::rng::Rng;
use serde::Serialize;
use std::time::{Duration, Instant};

#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct FaultSpec {
    pub drop: f64,
    pub corrupt: f64,
    pub dup: f64,
    pub delay: f64,
    pub delay_ms: u64,
    pub stall: f64,
    /// 0 = x, 1 = y, None = random.
    pub stall_axis: Option<usize>,
    pub limit: f64,
    pub reset: f64,
    pub estop: f64,
    pub disconnect: f64,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FaultSpecError {
    #[error("fault item `{0}` is not `kind=value`")]
    Syntax(String),
    #[error("unknown fault kind `{0}` (known: drop, corrupt, dup, delay, stall, limit, reset, estop, disconnect)")]
    UnknownKind(String),
    #[error("fault `{item}`: {why}")]
    BadValue { item: String, why: String },
}

fn prob(item: &str, s: &str) -> Result<f64, FaultSpecError> {
    let p: f64 = s.trim().parse().map_err(|_| FaultSpecError::BadValue {
        item: item.into(),
        why: format!("`{s}` is not a number"),
    })?;
    if !(0.0..=1.0).contains(&p) {
        return Err(FaultSpecError::BadValue {
            item: item.into(),
            why: format!("probability {p} is not in 0..1"),
        });
    }
    Ok(p)
}

impl FaultSpec {
    pub fn parse(spec: &str) -> Result<FaultSpec, FaultSpecError> {
        let mut f = FaultSpec::default();
        for item in spec.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let (k, v) = item
                .split_once('=')
                .ok_or_else(|| FaultSpecError::Syntax(item.into()))?;
            match k.trim() {
                "drop" => f.drop = prob(item, v)?,
                "corrupt" => f.corrupt = prob(item, v)?,
                "dup" => f.dup = prob(item, v)?,
                "delay" => {
                    let (p, ms) = v.split_once(':').ok_or_else(|| FaultSpecError::BadValue {
                        item: item.into(),
                        why: "expected delay=P:MS".into(),
                    })?;
                    f.delay = prob(item, p)?;
                    f.delay_ms = ms.trim().trim_end_matches("ms").parse().map_err(|_| {
                        FaultSpecError::BadValue {
                            item: item.into(),
                            why: format!("`{ms}` is not a whole number of milliseconds"),
                        }
                    })?;
                }
                "stall" => match v.split_once(':') {
                    Some((axis, p)) => {
                        f.stall_axis = Some(match axis.trim() {
                            "x" | "X" => 0,
                            "y" | "Y" => 1,
                            other => {
                                return Err(FaultSpecError::BadValue {
                                    item: item.into(),
                                    why: format!("axis `{other}` is not x or y"),
                                })
                            }
                        });
                        f.stall = prob(item, p)?;
                    }
                    None => f.stall = prob(item, v)?,
                },
                "limit" => f.limit = prob(item, v)?,
                "reset" => f.reset = prob(item, v)?,
                "estop" => f.estop = prob(item, v)?,
                "disconnect" => f.disconnect = prob(item, v)?,
                other => return Err(FaultSpecError::UnknownKind(other.into())),
            }
        }
        Ok(f)
    }
}

/// A fault that cuts a move part way, drawn when the move starts.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MoveFault {
    Stall { axis: usize },
    Limit,
    Reset,
    EStop,
    Disconnect,
}

impl FaultSpec {
    /// Draws at most one move fault for a new move.
    pub fn draw_move_fault(&self, rng: &mut Rng) -> Option<MoveFault> {
        if rng.chance(self.stall) {
            let axis = self.stall_axis.unwrap_or_else(|| rng.below(2) as usize);
            return Some(MoveFault::Stall { axis });
        }
        if rng.chance(self.limit) {
            return Some(MoveFault::Limit);
        }
        if rng.chance(self.reset) {
            return Some(MoveFault::Reset);
        }
        if rng.chance(self.estop) {
            return Some(MoveFault::EStop);
        }
        if rng.chance(self.disconnect) {
            return Some(MoveFault::Disconnect);
        }
        None
    }
}

/// Counts of byte faults applied, for the truth file.
#[derive(Debug, Clone, Default, Serialize)]
pub struct LineFaultCounts {
    pub dropped: u64,
    pub corrupted: u64,
    pub duplicated: u64,
    pub delayed: u64,
}

/// Applies byte faults to the line in both directions, and holds delayed output.
pub struct LineFilter {
    spec: FaultSpec,
    rng: Rng,
    pub counts: LineFaultCounts,
    pending: std::collections::VecDeque<u8>,
    quiet_until: Option<Instant>,
}

impl LineFilter {
    pub fn new(spec: FaultSpec, seed: u64) -> Self {
        LineFilter {
            spec,
            rng: Rng::new(seed ^ 0x11e_f11e),
            counts: LineFaultCounts::default(),
            pending: Default::default(),
            quiet_until: None,
        }
    }

    fn mangle(&mut self, b: u8, out: &mut Vec<u8>) {
        if self.rng.chance(self.spec.drop) {
            self.counts.dropped += 1;
            return;
        }
        let mut b = b;
        if self.rng.chance(self.spec.corrupt) {
            self.counts.corrupted += 1;
            b ^= 1 << self.rng.below(8);
        }
        out.push(b);
        if self.rng.chance(self.spec.dup) {
            self.counts.duplicated += 1;
            out.push(b);
        }
    }

    /// Host → controller bytes as the controller receives them.
    pub fn incoming(&mut self, bytes: &[u8]) -> Vec<u8> {
        let mut out = Vec::with_capacity(bytes.len());
        for &b in bytes {
            self.mangle(b, &mut out);
        }
        out
    }

    /// Queues controller → host bytes.
    pub fn outgoing(&mut self, bytes: &[u8]) {
        let mut out = Vec::with_capacity(bytes.len());
        for &b in bytes {
            self.mangle(b, &mut out);
        }
        self.pending.extend(out);
    }

    /// The bytes that may be written now; a delay fault holds back the rest.
    pub fn ready(&mut self, now: Instant) -> Vec<u8> {
        let mut out = Vec::new();
        while let Some(&b) = self.pending.front() {
            if let Some(t) = self.quiet_until {
                if now < t {
                    break;
                }
                self.quiet_until = None;
            } else if self.rng.chance(self.spec.delay) {
                self.counts.delayed += 1;
                self.quiet_until = Some(now + Duration::from_millis(self.spec.delay_ms));
                continue;
            }
            out.push(b);
            self.pending.pop_front();
        }
        out
    }

    /// Puts back bytes the pty did not take.
    pub fn unwrite(&mut self, bytes: &[u8]) {
        for &b in bytes.iter().rev() {
            self.pending.push_front(b);
        }
    }

    pub fn has_pending(&self) -> bool {
        !self.pending.is_empty()
    }

    /// Until when a delay fault holds the pending bytes back (`None`: none is).
    pub fn held_until(&self) -> Option<Instant> {
        self.quiet_until.filter(|_| !self.pending.is_empty())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_every_kind() {
        let f = FaultSpec::parse("drop=0.1, corrupt=0.2,dup=0.3,delay=0.4:50,stall=y:0.5,limit=0.6,reset=0.7,estop=0.8,disconnect=0.9").unwrap();
        assert_eq!(f.drop, 0.1);
        assert_eq!(f.delay_ms, 50);
        assert_eq!(f.stall_axis, Some(1));
        assert_eq!(f.disconnect, 0.9);
    }

    #[test]
    fn rejects_bad_items() {
        assert!(matches!(
            FaultSpec::parse("drop"),
            Err(FaultSpecError::Syntax(_))
        ));
        assert!(matches!(
            FaultSpec::parse("melt=0.1"),
            Err(FaultSpecError::UnknownKind(_))
        ));
        assert!(matches!(
            FaultSpec::parse("drop=2"),
            Err(FaultSpecError::BadValue { .. })
        ));
        assert!(matches!(
            FaultSpec::parse("stall=z:0.1"),
            Err(FaultSpecError::BadValue { .. })
        ));
    }

    #[test]
    fn drop_rate_is_respected() {
        let mut lf = LineFilter::new(FaultSpec::parse("drop=0.25").unwrap(), 3);
        let out = lf.incoming(&[1u8; 40_000]);
        let rate = 1.0 - out.len() as f64 / 40_000.0;
        assert!((rate - 0.25).abs() < 0.01, "rate {rate}");
    }
}
