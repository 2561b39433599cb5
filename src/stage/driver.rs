//! The safety policy over any [`Controller`].

use super::motion::{move_duration, secs, Approach, SoftLimits, TimeoutPolicy};
use super::{
    Controller, ControllerInfo, FaultKind, Result, Stage, StageError, StageState, StageStatus,
    StopAction, Stopped,
};
use crate::coords::CarriageUm;
use std::time::Duration;

#[derive(Debug, Clone)]
pub struct DriverOptions {
    pub approach: Approach,
    pub timeouts: TimeoutPolicy,
    /// Largest accepted difference between target and reported position, µm.
    pub tolerance_um: f64,
    /// Move speed; `None` = the controller's maximum.
    pub speed_um_s: Option<f64>,
    /// Extra soft limits from the operator, intersected with the controller's.
    pub limits: Option<SoftLimits>,
}

impl Default for DriverOptions {
    fn default() -> Self {
        DriverOptions {
            approach: Approach::default(),
            timeouts: TimeoutPolicy::default(),
            tolerance_um: 2.0,
            speed_um_s: None,
            limits: None,
        }
    }
}

pub struct Driver<C: Controller> {
    ctl: C,
    opts: DriverOptions,
    limits: SoftLimits,
}

impl<C: Controller> Driver<C> {
    pub fn new(ctl: C, opts: DriverOptions) -> Self {
        // The controller's own limits, never beyond its travel, narrowed by the operator's.
        let info = ctl.info();
        let travel = SoftLimits {
            min: crate::coords::CarriageUm::new(0.0, 0.0),
            max: info.travel,
        };
        let own = info.limits.intersect(&travel);
        let limits = opts.limits.map_or(own, |l| l.intersect(&own));
        Driver { ctl, opts, limits }
    }

    /// A homed controller's position must lie within its travel (give or take 5 mm or 5 %):
    /// anything else is a garbled report, wrong settings or a lost reference, and is a fault,
    /// never shown as a good position.
    fn plausible(&self, st: StageStatus) -> Result<StageStatus> {
        let t = self.ctl.info().travel;
        let slack = |v: f64| (0.05 * v).max(5000.0);
        let out = |p: f64, t: f64| !(p >= -slack(t) && p <= t + slack(t));
        if st.homed && (out(st.position.x, t.x) || out(st.position.y, t.y)) {
            return Err(StageError::Fault {
                kind: FaultKind::ImplausiblePosition {
                    x_mm: st.position.x_mm(),
                    y_mm: st.position.y_mm(),
                    travel_x_mm: t.x_mm(),
                    travel_y_mm: t.y_mm(),
                },
                position: None,
            });
        }
        Ok(st)
    }

    /// Stops the stages after `cause`; a stop that was not confirmed turns the error into
    /// [`StageError::StopFailed`], so no message claims the stages stopped when they may not
    /// have.
    fn stop_after(&mut self, cause: StageError) -> StageError {
        match self.ctl.stop() {
            Ok(_) => cause,
            Err(e) => StageError::StopFailed {
                cause: Box::new(cause),
                why: e.to_string(),
            },
        }
    }

    fn speed(&self) -> f64 {
        let max = self.ctl.info().max_speed_um_s;
        // Never zero: a move's timeout is computed from its speed.
        self.opts.speed_um_s.map_or(max, |s| s.min(max)).max(1.0)
    }

    /// On any error but a refusal before sending, stop the stages (best effort: the link may
    /// be what failed) and pass the error on.
    fn guard<T>(&mut self, r: Result<T>) -> Result<T> {
        match r {
            Err(e)
                if !matches!(
                    e,
                    StageError::OutOfLimits { .. }
                        | StageError::NotHomed
                        | StageError::Disconnected(_)
                        | StageError::BadSetting { .. }
                ) =>
            {
                Err(self.stop_after(e))
            }
            r => r,
        }
    }

    fn fault_of(st: &StageStatus) -> StageError {
        StageError::Fault {
            kind: st.fault.clone().unwrap_or(super::FaultKind::Reset),
            position: Some(st.position),
        }
    }

    /// Starts a motion, waits for its end with a timeout from its expected duration, and
    /// turns a fault into an error; on any error the stages are stopped (see [`Self::guard`]).
    fn run(
        &mut self,
        start: impl FnOnce(&mut C) -> Result<()>,
        expected: Duration,
    ) -> Result<StageStatus> {
        let timeout = self.opts.timeouts.for_duration(expected);
        let r = start(&mut self.ctl).and_then(|_| self.ctl.wait_done(timeout));
        let st = self.guard(r)?;
        if st.state == StageState::Fault {
            return Err(Self::fault_of(&st));
        }
        let r = self.plausible(st);
        self.guard(r)
    }

    /// One straight leg: check, send, wait, check for faults, check the reported position
    /// against `to` within `tol_um` per axis.
    fn leg(&mut self, from: CarriageUm, to: CarriageUm, tol_um: [f64; 2]) -> Result<StageStatus> {
        self.limits.check(to)?;
        let speed = self.speed();
        let expected = move_duration((to - from).norm(), speed, self.ctl.info().accel_um_s2);
        let st = self.run(|c| c.start_move(to, speed), expected)?;
        if !st.homed {
            return Err(StageError::Fault {
                kind: super::FaultKind::Reset,
                position: Some(st.position),
            });
        }
        // Every leg is checked, the approach detour too: a detour that went astray (a garbled
        // line on a controller without checksums) would let the last leg arrive from the
        // wrong side with the backlash unseen.
        let err = st.position - to;
        if err.x.abs() > tol_um[0] || err.y.abs() > tol_um[1] {
            return Err(self.stop_after(StageError::PositionMismatch {
                target: to,
                actual: st.position,
                tolerance_um: tol_um[0].max(tol_um[1]),
            }));
        }
        Ok(st)
    }

    fn ready_to_move(&mut self) -> Result<StageStatus> {
        let st = self.ctl.status()?;
        match st.state {
            StageState::Fault => Err(Self::fault_of(&st)),
            _ if !st.homed => Err(StageError::NotHomed),
            s if s.is_moving() => Err(StageError::Rejected {
                command: "move".into(),
                reason: format!(
                    "the stage is still {}; stop it or wait",
                    st.controller_state
                ),
            }),
            _ => Ok(st),
        }
    }
}

impl<C: Controller> Stage for Driver<C> {
    fn info(&self) -> &ControllerInfo {
        self.ctl.info()
    }

    fn limits(&self) -> SoftLimits {
        self.limits
    }

    fn status(&mut self) -> Result<StageStatus> {
        let st = self.ctl.status()?;
        self.plausible(st)
    }

    fn home(&mut self) -> Result<CarriageUm> {
        let st = self.ctl.status()?;
        if st.state == StageState::Fault {
            self.ctl.clear_fault()?;
        }
        let expected = self.ctl.homing_duration();
        tracing::info!(bound_s = expected.as_secs_f64(), "homing");
        let st = self.run(|c| c.start_home(), expected)?;
        if !st.homed {
            return Err(StageError::Protocol(format!(
                "homing ended but the controller is not homed ({})",
                st.controller_state
            )));
        }
        Ok(st.position)
    }

    fn move_to(&mut self, target: CarriageUm) -> Result<CarriageUm> {
        // Refuse before anything is sent.
        self.limits.check(target)?;
        tracing::debug!(%target, "move");
        let st = self.ready_to_move()?;
        let mut from = st.position;
        let tol = self.opts.tolerance_um;
        if let Some(pre) = self.opts.approach.pre_position(from, target, &self.limits) {
            // The detour lands against the approach direction, backlash and all: it only has
            // to end well on the approach side of the target (half the overshoot), while an
            // axis that needs no detour must already be exactly where it will stay.
            let loose = |k: usize| {
                if pre.axis(k) != target.axis(k) {
                    (self.opts.approach.overshoot_um / 2.0).max(tol)
                } else {
                    tol
                }
            };
            from = self.leg(from, pre, [loose(0), loose(1)])?.position;
        }
        Ok(self.leg(from, target, [tol, tol])?.position)
    }

    fn jog(&mut self, delta: CarriageUm, speed_um_s: f64) -> Result<CarriageUm> {
        let st = self.ready_to_move()?;
        let to = self.limits.clamp(st.position + delta);
        let d = to - st.position;
        if d.norm() < 0.01 {
            return Ok(st.position);
        }
        let speed = speed_um_s.min(self.ctl.info().max_speed_um_s).max(1.0);
        let expected = move_duration(d.norm(), speed, self.ctl.info().accel_um_s2);
        let st = self.run(|c| c.start_jog(d, speed), expected)?;
        Ok(st.position)
    }

    fn stop(&mut self) -> Result<Stopped> {
        let action = self.ctl.stop()?;
        let (position, fault) = match action {
            StopAction::Nothing | StopAction::Decelerated | StopAction::Released => {
                let info = self.ctl.info();
                // From full speed a stop takes v/a.
                let expected = secs(info.max_speed_um_s / info.accel_um_s2);
                match self
                    .ctl
                    .wait_done(self.opts.timeouts.for_duration(expected))
                {
                    Ok(st) => (Some(self.plausible(st)?.position), None),
                    // Stopped, in an alarm of its own (a GRBL soft-limit alarm survives the
                    // reset): the stop is done; the fault is said, not taken for a failed stop.
                    Err(StageError::Fault { kind, position }) => (position, Some(kind.to_string())),
                    Err(e) => return Err(e),
                }
            }
            // The reference is gone: whatever the controller counts is not a carriage position.
            StopAction::Reset | StopAction::HomingAborted => (None, None),
        };
        Ok(Stopped {
            action,
            position,
            fault,
        })
    }

    fn emergency_stop(&mut self) -> Result<()> {
        self.ctl.emergency_stop()
    }

    fn wait_motion(&mut self, expected: Duration) -> Result<StageStatus> {
        let r = self
            .ctl
            .wait_done(self.opts.timeouts.for_duration(expected));
        self.guard(r)
    }
}
