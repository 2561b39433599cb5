//! One calibration session from its start to its end, as `rig calibrate` and the lab service
//! both run it: the certificate read, the descriptor written, the calibration run on the
//! hardware, its results and its end (done, or failed with the reason) recorded in the session.

use super::documents::{InteriorDescriptor, PixelDescriptor, Results};
use super::pixel::{CalibrateError, Step};
use super::session::{DocumentError, Session};
use super::{
    calibrate_interior, calibrate_pixel, InteriorOptions, InteriorOrientation, PixelCalibration,
    PixelOptions, Rig,
};
use crate::camera::Camera;
use crate::stage::Stage;
use crate::targets::certificate::{CameraCertificate, CertificateError, PlateCertificate};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error(transparent)]
    Certificate(#[from] CertificateError),
    #[error(transparent)]
    Document(#[from] DocumentError),
    #[error("the pixel session's flat field {path}: {source}")]
    Flat {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("writing the session {dir}: {source}")]
    Record {
        dir: PathBuf,
        source: std::io::Error,
    },
    /// The calibration itself failed; the session is stored as failed.
    #[error("{source} (the session, stored as failed, is in {dir})")]
    Calibrate {
        dir: PathBuf,
        source: Box<CalibrateError>,
    },
}

/// The hardware a session runs on, and who watches it.
pub struct Hands<'a> {
    pub stage: &'a mut dyn Stage,
    pub camera: &'a mut dyn Camera,
    pub progress: &'a mut dyn FnMut(Step<'_>),
    /// Ends the session before its next move when set (the service's pause and stop).
    pub interrupt: Option<&'a AtomicBool>,
    /// Shown every averaged image the session takes.
    pub seen: Option<&'a mut dyn FnMut(&crate::digitise::ImageF32)>,
}

/// A pixel session's request (`rig calibrate pixel`).
pub struct PixelJob {
    pub plate_certificate: PathBuf,
    pub options: PixelOptions,
    /// Run on the simulator (recorded in the descriptor).
    pub sim: bool,
}

/// An interior session's request (`rig calibrate interior`).
pub struct InteriorJob {
    pub camera_certificate: PathBuf,
    /// The pixel session whose transformation and flat field it uses.
    pub pixel_session: PathBuf,
    pub options: InteriorOptions,
    /// Home before the first fiducial.
    pub home: bool,
    pub film_centre_mm: [f64; 2],
    pub sim: bool,
}

/// A finished session: the calibration, its results document as written, its folder.
pub struct Finished<T> {
    pub calibration: T,
    pub results: serde_json::Value,
    pub dir: PathBuf,
}

fn record(dir: &Path) -> impl Fn(std::io::Error) -> SessionError + '_ {
    move |source| SessionError::Record {
        dir: dir.to_path_buf(),
        source,
    }
}

/// Runs `body` on the hardware, then writes the results and ends the session done, or ends
/// it failed with the reason.
fn finish<T: serde::Serialize>(
    mut session: Session,
    kind: &str,
    hands: Hands,
    flat: Option<crate::digitise::FlatField>,
    body: impl FnOnce(&mut Rig) -> Result<T, CalibrateError>,
) -> Result<Finished<T>, SessionError> {
    let r = body(&mut Rig {
        stage: hands.stage,
        camera: hands.camera,
        session: &mut session,
        progress: hands.progress,
        flat,
        interrupt: hands.interrupt,
        // (Each reference re-borrowed for the session's shorter life.)
        seen: match hands.seen {
            Some(s) => Some(s),
            None => None,
        },
    });
    let dir = session.dir.clone();
    match r {
        Ok(calibration) => {
            let results = Results {
                kind: kind.to_string(),
                session: dir.clone(),
                calibration: &calibration,
            };
            let written = session
                .write_results(&results)
                .and_then(|_| serde_json::to_value(&results).map_err(Into::into));
            let doc = match written {
                Ok(d) => d,
                Err(e) => {
                    // Never left without an end: the record says why it failed.
                    let _ = session.stop("failed", Some(&format!("writing the results: {e}")));
                    return Err(record(&dir)(e));
                }
            };
            session.stop("done", None).map_err(record(&dir))?;
            Ok(Finished {
                calibration,
                results: doc,
                dir,
            })
        }
        Err(source) => {
            // The calibration's own error is the one reported; the record of it is best effort.
            let _ = session.stop("failed", Some(&source.to_string()));
            Err(SessionError::Calibrate {
                dir,
                source: Box::new(source),
            })
        }
    }
}

/// A pixel session (seed 002, "Geometric calibration"): the plate certificate read, the
/// descriptor written, the cross measured through the grid and under the measuring mark.
pub fn pixel(
    mut session: Session,
    hands: Hands,
    job: &PixelJob,
) -> Result<Finished<PixelCalibration>, SessionError> {
    let plate = PlateCertificate::load(&job.plate_certificate)?;
    let opt = &job.options;
    let dir = session.dir.clone();
    session
        .start(
            "pixel",
            &PixelDescriptor {
                plate_certificate: job.plate_certificate.clone(),
                plate: plate.name.clone(),
                camera: hands.camera.info(),
                stage: hands.stage.info().clone(),
                frames: opt.frames,
                grid: opt.grid,
                patch: opt.patch,
                blur_px: opt.blur_px,
                nominal_um_per_px: opt.nominal_um_per_px,
                sim: job.sim,
            },
        )
        .map_err(record(&dir))?;
    finish(session, "pixel", hands, None, |rig| {
        calibrate_pixel(rig, &plate, opt)
    })
}

/// An interior session (seed 002, Table 5): the camera certificate and the pixel session read,
/// the descriptor written, the fiducials found and measured, carriage→image fitted.
pub fn interior(
    mut session: Session,
    hands: Hands,
    job: &InteriorJob,
) -> Result<Finished<InteriorOrientation>, SessionError> {
    let cert = CameraCertificate::load(&job.camera_certificate)?;
    let pixel = super::documents::pixel_transform(&job.pixel_session)?;
    let flat_path = job.pixel_session.join(super::pixel::FLAT);
    let flat = match flat_path.exists() {
        true => Some(
            crate::digitise::FlatField::load(&flat_path).map_err(|source| SessionError::Flat {
                path: flat_path.clone(),
                source,
            })?,
        ),
        false => None,
    };
    let dir = session.dir.clone();
    session
        .start(
            "interior",
            &InteriorDescriptor {
                camera_certificate: job.camera_certificate.clone(),
                camera_name: cert.name.clone(),
                pixel_session: job.pixel_session.clone(),
                pixel_to_carriage: pixel,
                flat_field: flat.is_some().then(|| flat_path.clone()),
                camera: hands.camera.info(),
                stage: hands.stage.info().clone(),
                frames: job.options.frames,
                patch: job.options.patch,
                film_centre_mm: job.film_centre_mm,
                sim: job.sim,
            },
        )
        .map_err(record(&dir))?;
    let home = job.home;
    finish(session, "interior", hands, flat, |rig| {
        if home {
            (rig.progress)(Step::note("homing"));
            rig.stage.home()?;
        }
        calibrate_interior(rig, &cert, &pixel, &job.options)
    })
}
