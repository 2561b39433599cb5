//! Calibration items on the hardware thread: a pixel or interior session into the store
//! (rig::calibrate::run, as `rig calibrate` runs it), with progress events. A pause or a stop
//! ends the session before its next move; a paused calibration starts a new session when
//! resumed, since one session's marks are measured in one stretch (seed 002 shows the rig's
//! figures drifting over time).

use super::devices::Rig;
use super::events::Kind;
use super::queue::{ItemId, Task};
use crate::calibrate::pixel::Step;
use crate::calibrate::run::{Hands, InteriorJob, PixelJob};
use crate::calibrate::{InteriorOptions, PixelOptions, Session};
use crate::coords::CarriageUm;
use serde_json::{json, Value};
use std::path::PathBuf;
use std::time::Instant;

/// Runs a calibration task; the result names the session and its figures.
pub fn run(rig: &mut Rig, id: ItemId, task: &Task) -> Result<Value, String> {
    let store = rig.settings.store.clone();
    let kind = match task {
        Task::CalibratePixel { .. } => "pixel",
        Task::CalibrateInterior { .. } => "interior",
        _ => unreachable!("not a calibration"),
    };
    let session = Session::new_in_store(&store, kind)
        .map_err(|e| format!("creating a {kind} session in {}: {e}", store.display()))?;
    // The simulator's certificate, kept in the session as `rig calibrate --sim` keeps it.
    let own = |session: &Session, name: &str, text: &Option<String>| -> Result<PathBuf, String> {
        let text = text
            .as_ref()
            .ok_or("no certificate given and the hardware has none of its own")?;
        session
            .keep_certificate(name, text)
            .map_err(|e| format!("writing {}: {e}", session.dir.join(name).display()))
    };
    let bus = rig.bus;
    let t0 = Instant::now();
    let mut progress = |s: Step<'_>| {
        let (step, of) = s.of.unwrap_or((0, 0));
        let left = (step > 0 && of >= step)
            .then(|| t0.elapsed().as_secs_f64() / step as f64 * (of - step) as f64);
        bus.publish(
            Kind::Progress,
            json!({"item": id, "step": step, "of": of, "what": s.what, "seconds_left": left}),
        );
    };
    let last_look = rig.last_look;
    let mut seen = |img: &crate::digitise::ImageF32| {
        if bus.clients() > 0 {
            super::devices::show(bus, last_look, img, json!({"item": id}));
        }
    };
    let sim = rig.settings.sim;
    let dev = &mut *rig.dev;
    // An interior session homes first unless the stage is homed (a pixel session always does).
    let homed = dev.stage.status().map_err(|e| e.to_string())?.homed;
    let hands = Hands {
        stage: dev.stage.as_mut(),
        camera: dev.camera.as_mut(),
        progress: &mut progress,
        interrupt: Some(&rig.control.pause),
        seen: Some(&mut seen),
    };
    match task {
        Task::CalibratePixel {
            frames,
            grid,
            grid_only,
            no_flat,
            pixel_um,
            plate_cert,
        } => {
            let plate_certificate = match plate_cert {
                Some(n) => super::task::certificate_path(n, rig.settings)?,
                None => own(&session, "plate-cert.toml", &dev.certificates.plate)?,
            };
            let job = PixelJob {
                plate_certificate,
                options: PixelOptions {
                    frames: *frames,
                    grid: *grid,
                    nominal_um_per_px: *pixel_um,
                    home: true,
                    all_crosses: !grid_only,
                    flat_field: !no_flat,
                    ..Default::default()
                },
                sim,
            };
            let f =
                crate::calibrate::run::pixel(session, hands, &job).map_err(|e| e.to_string())?;
            let c = &f.calibration;
            Ok(json!({
                "session": f.dir,
                "x_scale": c.x_scale, "y_scale": c.y_scale,
                "x_shear": c.x_shear, "y_shear": c.y_shear,
                "rms_um": c.rms_um,
                "mark_px": c.mark.as_ref().map(|m| [m.mean.col, m.mean.row]),
            }))
        }
        Task::CalibrateInterior {
            frames,
            film_centre_mm,
            pixel_session,
            camera_cert,
        } => {
            let pixel_session = match pixel_session {
                Some(n) => super::task::session_in_store(n, rig.settings)?,
                None => crate::calibrate::session::newest(&store, "pixel")
                    .map_err(|e| format!("{}: {e}", store.display()))?
                    .ok_or_else(|| {
                        format!(
                            "no pixel session in {}: calibrate pixel first",
                            store.display()
                        )
                    })?,
            };
            let camera_certificate = match camera_cert {
                Some(n) => super::task::certificate_path(n, rig.settings)?,
                None => own(&session, "camera-cert.toml", &dev.certificates.camera)?,
            };
            let job = InteriorJob {
                camera_certificate,
                pixel_session,
                options: InteriorOptions {
                    frames: *frames,
                    film_centre: CarriageUm::from_mm(film_centre_mm[0], film_centre_mm[1]),
                    ..Default::default()
                },
                home: !homed,
                film_centre_mm: *film_centre_mm,
                sim,
            };
            let f =
                crate::calibrate::run::interior(session, hands, &job).map_err(|e| e.to_string())?;
            let versions: Vec<Value> = f
                .calibration
                .versions
                .iter()
                .map(|v| json!({"name": v.name, "rms_um": v.fit.as_ref().map(|f| f.rms_total()), "fiducials": v.fiducials.len()}))
                .collect();
            Ok(json!({"session": f.dir, "versions": versions}))
        }
        _ => unreachable!("not a calibration"),
    }
}
