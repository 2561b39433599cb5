//! Running a scan: the scan directory (script, calibration and camera certificate copied in,
//! the manifest, the log, the flat field, the tiles, the photos), the capture loop with a
//! checkpoint after every tile and a pause at the next tile boundary on request, and the
//! mosaics at the end. A resumed scan skips the tiles the manifest holds (after checking their
//! bytes) and takes the others exactly as an uninterrupted run would have.

use super::calibration::ScanCalibration;
use super::manifest::{fnv64, intact, FileRecord, Manifest, TileRecord};
use super::mosaic::{self, Interpolation, TileSource};
use super::plan::Plan;
use super::script::{Filter, ScanScript};
use super::sidecar;
use crate::calibrate::Session;
use crate::camera::{Camera, CameraError};
use crate::digitise::capture::{capture, CaptureError};
use crate::digitise::output::{read_tiff16_f32, write_json, write_tiff16};
use crate::digitise::{FlatField, ImageF32};
use crate::geometry::PhotoGrid;
use crate::relative::relative_to;
use crate::stage::{Stage, StageError};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

pub const SCRIPT_COPY: &str = "script.toml";
pub const CALIBRATION: &str = "calibration.json";
pub const CERTIFICATE: &str = "camera-cert.toml";
pub const FLAT: &str = "flat.tiff";
pub const TILES: &str = "tiles";

#[derive(Debug, thiserror::Error)]
pub enum ScanError {
    #[error(transparent)]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Stage(#[from] StageError),
    #[error(transparent)]
    Camera(#[from] CameraError),
    #[error(transparent)]
    Capture(#[from] CaptureError),
    #[error(
        "{dir} already holds a scan: continue it with --resume, or give another output directory"
    )]
    Exists { dir: PathBuf },
    #[error("{dir} holds no scan (no manifest.json): start one with `rig scan run SCRIPT`, without --resume")]
    NothingToResume { dir: PathBuf },
    #[error("the script {script} changed since the scan in {dir} began: restore it (the original is {dir}/script.toml) or scan into a new directory")]
    ScriptChanged { script: PathBuf, dir: PathBuf },
    #[error("the flat field at photo ({x:.1}, {y:.1}) mm is not clear film base ({dark:.1} % of it is darker than 70 % of its mean): set [capture] flat_photo_mm to a clear spot, or flat_field = false")]
    FlatNotClear { x: f64, y: f64, dark: f64 },
    #[error("the film has moved since the scan began: tile {tile} taken again lies ({dx:+.2}, {dy:+.2}) px from where it was (correlation {correlation:.3}; at most {max} px allowed). Tiles from before and after would not fit: run `rig calibrate interior` again and start a new scan")]
    FilmMoved {
        tile: String,
        dx: f64,
        dy: f64,
        correlation: f64,
        max: f64,
    },
    #[error(transparent)]
    Calibration(#[from] super::calibration::CalibrationError),
    #[error("{script}: [film] names no interior_session and {store} has none: run `rig calibrate interior` or name one")]
    NoInterior { script: PathBuf, store: PathBuf },
    #[error(transparent)]
    Plan(#[from] super::plan::PlanError),
    #[error("{dir}/manifest.json does not agree with the scan's script and calibration: {detail}. The manifest was edited or belongs to another scan: restore it, or scan into a new directory")]
    Manifest { dir: PathBuf, detail: String },
    #[error("{path}: {detail}. The tile changed on disk since it was taken: run `rig scan run SCRIPT --resume` to take it again")]
    TileChanged { path: PathBuf, detail: String },
}

/// What a scan directory is checked against when it is opened again: the operator's soft
/// limits (a resume moves the stage) and the memory a mosaic may take.
#[derive(Debug, Clone, Copy)]
pub struct Reopen {
    pub limits: Option<crate::stage::SoftLimits>,
    pub max_memory_mib: u64,
}

impl Default for Reopen {
    fn default() -> Self {
        Reopen {
            limits: None,
            max_memory_mib: super::plan::DEFAULT_MAX_MEMORY_MIB,
        }
    }
}

/// How far (µm) a recorded stage position may lie from the planned one: the stage stops
/// within micrometres of its target, so more means a manifest that was edited.
const MAX_RECORDED_OFFSET_UM: f64 = 1000.0;

/// Where the scan stands, for a progress display.
#[derive(Debug, Clone)]
pub struct Progress<'a> {
    pub done: usize,
    pub total: usize,
    pub tile: &'a str,
    /// Seconds left, from this run's pace (the plan's estimate before the first tile).
    pub eta_s: f64,
}

pub enum Outcome {
    Complete {
        photos: Vec<PathBuf>,
    },
    /// Stopped on request at a tile boundary; `--resume` continues.
    Paused {
        done: usize,
        total: usize,
    },
}

pub struct ScanDir {
    pub dir: PathBuf,
    pub script: ScanScript,
    pub cal: ScanCalibration,
    pub manifest: Manifest,
    pub log: Session,
}

fn is_empty_dir(d: &Path) -> std::io::Result<bool> {
    Ok(!d.exists() || std::fs::read_dir(d)?.next().is_none())
}

impl ScanDir {
    /// A new scan in `dir` (absent or empty).
    pub fn create(
        dir: &Path,
        script: ScanScript,
        cal: ScanCalibration,
        plan: Plan,
    ) -> Result<ScanDir, ScanError> {
        if !is_empty_dir(dir)? {
            return Err(ScanError::Exists {
                dir: dir.to_path_buf(),
            });
        }
        std::fs::create_dir_all(dir.join(TILES))?;
        super::manifest::write_atomic(&dir.join(SCRIPT_COPY), script.text.as_bytes())?;
        // The records name what they came from relative to the scan's directory.
        let record = ScanCalibration {
            interior_session: relative_to(dir, &cal.interior_session),
            pixel_session: relative_to(dir, &cal.pixel_session),
            camera_certificate: relative_to(dir, &cal.camera_certificate),
            ..cal.clone()
        };
        super::manifest::write_atomic(
            &dir.join(CALIBRATION),
            &serde_json::to_vec_pretty(&record).map_err(std::io::Error::other)?,
        )?;
        std::fs::copy(&cal.camera_certificate, dir.join(CERTIFICATE))?;
        let manifest = Manifest::new(&relative_to(dir, &script.path), &script.text, plan);
        manifest.save(dir)?;
        let mut log = Session::append(dir)?;
        log.start(
            "scan",
            &json!({"script": manifest.script, "film": script.film_name, "calibration": record,
                   "capture": script.capture, "resolution_um": script.resolution_um,
                   "regions": script.regions, "tiles": manifest.plan.tiles.len(),
                   "estimate": manifest.plan.estimate}),
        )?;
        Ok(ScanDir {
            dir: dir.to_path_buf(),
            script,
            cal,
            manifest,
            log,
        })
    }

    /// The scan in `dir`, to resume with `script` (which must not have changed). Tiles whose
    /// files are missing or damaged are taken again.
    pub fn resume(dir: &Path, script: ScanScript, check: &Reopen) -> Result<ScanDir, ScanError> {
        let mut sd = Self::open(dir, check)?;
        if sd.manifest.script_hash != fnv64(script.text.as_bytes()) {
            return Err(ScanError::ScriptChanged {
                script: script.path,
                dir: dir.to_path_buf(),
            });
        }
        let mut retake = Vec::new();
        for (t, r) in sd
            .manifest
            .plan
            .tiles
            .iter()
            .zip(sd.manifest.tiles.iter_mut())
        {
            if r.as_ref().is_some_and(|r| !intact(dir, &r.file)) {
                retake.push(t.id.clone());
                *r = None;
            }
        }
        if sd.manifest.flat.as_ref().is_some_and(|f| !intact(dir, f)) {
            sd.manifest.flat = None;
            retake.push("flat".into());
        }
        sd.script = script;
        sd.log.event(
            "resumed",
            json!({"done": sd.manifest.done(), "total": sd.manifest.tiles.len(), "damaged_retaken": retake}),
        )?;
        Ok(sd)
    }

    /// The scan in `dir` as it is on disk (for mosaicking again, or a status). Nothing in the
    /// manifest is trusted: the plan is made again from the scan's copies of the script and
    /// calibration (with `check`'s soft limits) and must agree with the stored one, and every
    /// record must name its own file and a position near the planned one, so that no file is
    /// read or written outside the directory and no move goes where the script did not ask.
    pub fn open(dir: &Path, check: &Reopen) -> Result<ScanDir, ScanError> {
        let manifest = match Manifest::load(dir) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(ScanError::NothingToResume {
                    dir: dir.to_path_buf(),
                })
            }
            Err(e) => return Err(e.into()),
        };
        let script = ScanScript::load(&dir.join(SCRIPT_COPY))
            .map_err(|e| std::io::Error::other(e.to_string()))?;
        let cal_path = dir.join(CALIBRATION);
        let mut cal: ScanCalibration = serde_json::from_slice(&std::fs::read(&cal_path)?)
            .map_err(|e| std::io::Error::other(format!("{}: {e}", cal_path.display())))?;
        // Recorded relative to the scan's directory (an absolute path, as older scans kept,
        // stays as it is).
        for p in [
            &mut cal.interior_session,
            &mut cal.pixel_session,
            &mut cal.camera_certificate,
        ] {
            *p = dir.join(&*p);
        }
        cal.certificate =
            crate::targets::certificate::CameraCertificate::load(&dir.join(CERTIFICATE))
                .map_err(|e| std::io::Error::other(e.to_string()))?;
        cal.check()
            .map_err(|m| super::calibration::CalibrationError {
                path: cal_path.clone(),
                message: m,
            })?;
        if let Some(l) = &check.limits {
            cal.rig.limits = cal.rig.limits.intersect(l);
        }
        let mismatch = |detail: String| ScanError::Manifest {
            dir: dir.to_path_buf(),
            detail,
        };
        if fnv64(script.text.as_bytes()) != manifest.script_hash {
            return Err(mismatch(format!(
                "{SCRIPT_COPY} is not the script the scan began with (its hash differs)"
            )));
        }
        let again = super::plan::plan(&script, &cal, check.max_memory_mib)?;
        again.same_layout(&manifest.plan).map_err(mismatch)?;
        for (t, r) in again.tiles.iter().zip(&manifest.tiles) {
            let Some(r) = r else { continue };
            let want = tile_file(&t.id);
            if r.file.file != want {
                return Err(mismatch(format!(
                    "tile {} is recorded as `{}`, not `{want}`",
                    t.id, r.file.file
                )));
            }
            let off = (r.stage_um - t.stage_um).norm();
            if off.is_nan() || off > MAX_RECORDED_OFFSET_UM {
                return Err(mismatch(format!(
                    "tile {} is recorded at {}, {off:.0} µm from its planned {}",
                    t.id, r.stage_um, t.stage_um
                )));
            }
        }
        if let Some(f) = &manifest.flat {
            if f.file != FLAT {
                return Err(mismatch(format!(
                    "the flat field is recorded as `{}`, not `{FLAT}`",
                    f.file
                )));
            }
        }
        let log = Session::append(dir)?;
        Ok(ScanDir {
            dir: dir.to_path_buf(),
            script,
            cal,
            manifest,
            log,
        })
    }

    fn counts_per_dn(&self) -> f64 {
        crate::digitise::flat::counts_per_dn(self.cal.rig.bit_depth)
    }

    /// Writes an image in DN as counts, atomically; returns its record (hash of the bytes as
    /// read back, so the record describes exactly what is on disk).
    fn write_counts(&self, rel: &str, img: &ImageF32) -> std::io::Result<FileRecord> {
        let p = self.dir.join(rel);
        crate::digitise::flat::save_counts(&p, img, self.cal.rig.bit_depth)?;
        Ok(FileRecord {
            file: rel.into(),
            hash: fnv64(&std::fs::read(&p)?),
        })
    }

    fn read_counts(&self, rel: &str) -> std::io::Result<ImageF32> {
        read_tiff16_f32(&self.dir.join(rel))
    }
}

/// A tile's file, relative to the scan directory.
pub fn tile_file(id: &str) -> String {
    format!("{TILES}/{id}.tiff")
}

/// Reads a tile and checks its bytes against the hash recorded when it was taken.
fn read_recorded(dir: &Path, r: &FileRecord) -> Result<ImageF32, ScanError> {
    let path = dir.join(&r.file);
    let bytes = std::fs::read(&path)
        .map_err(|e| std::io::Error::new(e.kind(), format!("{}: {e}", path.display())))?;
    let hash = fnv64(&bytes);
    if hash != r.hash {
        return Err(ScanError::TileChanged {
            path,
            detail: format!("its bytes hash to {hash}, the manifest recorded {}", r.hash),
        });
    }
    Ok(crate::digitise::output::to_f32(
        crate::digitise::output::decode_tiff16(std::io::Cursor::new(bytes), &path)?,
    ))
}

/// The stage and camera a scan runs on.
pub struct ScanRig<'a> {
    pub stage: &'a mut dyn Stage,
    pub camera: &'a mut dyn Camera,
}

pub struct RunOptions<'a> {
    pub home: bool,
    /// Set (by Ctrl-C) to pause at the next tile boundary.
    pub pause: &'a AtomicBool,
    pub frame_timeout: Duration,
}

/// Moves to `at`, settles, takes `frames` frames, averages and filters them, and divides by
/// the flat field if there is one.
fn take(
    rig: &mut ScanRig,
    sd: &ScanDir,
    at: crate::coords::CarriageUm,
    frames: u32,
    timeout: Duration,
    flat: Option<&FlatField>,
) -> Result<
    (
        crate::coords::CarriageUm,
        crate::digitise::capture::Captured,
    ),
    ScanError,
> {
    let pos = rig.stage.move_to(at)?;
    std::thread::sleep(crate::stage::secs(sd.script.capture.settle_ms / 1000.0));
    // Frames the camera captured before now (during the move or the settle) are set aside.
    let settled = rig.camera.now()?;
    let mut c = capture(
        rig.camera,
        frames,
        sd.script.capture.filter == Filter::Stripes,
        timeout,
        Some(settled),
        |_| {},
    )?;
    if let Some(f) = flat {
        f.apply(&mut c.image);
    }
    Ok((pos, c))
}

/// A resumed scan first takes its last tile again and matches it with the stored one: the
/// film must not have moved.
fn check_film(
    sd: &mut ScanDir,
    rig: &mut ScanRig,
    opt: &RunOptions,
    last: usize,
    flat: Option<&FlatField>,
) -> Result<(), ScanError> {
    let tile = sd.manifest.plan.tiles[last].clone();
    let rec = sd.manifest.tiles[last].clone().expect("a tile taken");
    let (_, c) = take(
        rig,
        sd,
        tile.stage_um,
        sd.script.capture.frames,
        opt.frame_timeout,
        flat,
    )?;
    let before = read_recorded(&sd.dir, &rec.file)?;
    let check = super::verify::film_shift(&before, &c.image);
    sd.log
        .event("film_check", json!({"tile": tile.id, "check": check}))?;
    let [dx, dy] = check.shift_px;
    if dx.hypot(dy) > super::verify::MAX_SHIFT_PX || check.correlation < 0.9 {
        return Err(ScanError::FilmMoved {
            tile: tile.id,
            dx,
            dy,
            correlation: check.correlation,
            max: super::verify::MAX_SHIFT_PX,
        });
    }
    Ok(())
}

/// Takes the tiles the manifest lacks (the flat field first), checkpointing after each, then
/// mosaics every region. Returns early, paused, when `opt.pause` is set.
pub fn run(
    sd: &mut ScanDir,
    rig: &mut ScanRig,
    opt: &RunOptions,
    progress: &mut dyn FnMut(Progress),
) -> Result<Outcome, ScanError> {
    let total = sd.manifest.tiles.len();
    if sd.manifest.done() < total {
        if opt.home {
            rig.stage.home()?;
        }
        // A camera without the control scans on at its own setting; the log says so (with
        // automatic gain the flat field still evens out what stays fixed, not what drifts).
        match rig.camera.set_gain(Some(sd.script.capture.gain)) {
            Err(CameraError::Unsupported(what)) => sd.log.event(
                "note",
                json!({"camera": format!("{what} not supported: gain left to the camera")}),
            )?,
            r => r?,
        }
        if let Some(e) = sd.script.capture.exposure_ms {
            match rig.camera.set_exposure_ms(e) {
                Err(CameraError::Unsupported(what)) => sd.log.event(
                    "note",
                    json!({"camera": format!("{what} not supported: exposure left to the camera")}),
                )?,
                r => r?,
            }
        }
    }
    // The flat as stored (read back from its file), so that a resumed run divides by exactly
    // the numbers the first one did.
    let flat = match (sd.manifest.plan.flat_stage_um, sd.manifest.flat.clone()) {
        (_, Some(rec)) => Some(FlatField::from_image(&read_recorded(&sd.dir, &rec)?)),
        (Some(at), None) => {
            let (pos, c) = take(
                rig,
                sd,
                at,
                4 * sd.script.capture.frames,
                opt.frame_timeout,
                None,
            )?;
            let rec = sd.write_counts(FLAT, &c.image)?;
            let f = FlatField::from_image(&sd.read_counts(FLAT)?);
            sd.log.event(
                "flat",
                json!({"stage_um": pos, "dark_percent": f.dark_percent}),
            )?;
            if !f.is_clear() {
                let [x, y] = sd.script.capture.flat_photo_mm;
                return Err(ScanError::FlatNotClear {
                    x,
                    y,
                    dark: f.dark_percent,
                });
            }
            sd.manifest.flat = Some(rec);
            sd.manifest.save(&sd.dir)?;
            Some(f)
        }
        (None, None) => None,
    };
    if let Some(last) = (0..total).rev().find(|&i| sd.manifest.tiles[i].is_some()) {
        if sd.manifest.done() < total {
            check_film(sd, rig, opt, last, flat.as_ref())?;
        }
    }
    let started = Instant::now();
    let mut taken = 0usize;
    let per_tile_plan = sd.manifest.plan.estimate.seconds / total.max(1) as f64;
    progress(Progress {
        done: sd.manifest.done(),
        total,
        tile: "",
        eta_s: per_tile_plan * (total - sd.manifest.done()) as f64,
    });
    for i in 0..total {
        if sd.manifest.tiles[i].is_some() {
            continue;
        }
        if opt.pause.load(Ordering::SeqCst) {
            let done = sd.manifest.done();
            sd.log
                .event("paused", json!({"done": done, "total": total}))?;
            sd.log.stop(
                "paused",
                Some("stopped by the operator; --resume continues"),
            )?;
            return Ok(Outcome::Paused { done, total });
        }
        let tile = sd.manifest.plan.tiles[i].clone();
        let t0 = Instant::now();
        let (pos, c) = take(
            rig,
            sd,
            tile.stage_um,
            sd.script.capture.frames,
            opt.frame_timeout,
            flat.as_ref(),
        )?;
        let file = sd.write_counts(&tile_file(&tile.id), &c.image)?;
        let rec = TileRecord {
            file,
            stage_um: pos,
            dropped_frames: c.dropped,
            seconds: t0.elapsed().as_secs_f64(),
        };
        sd.manifest.tiles[i] = Some(rec.clone());
        sd.manifest.save(&sd.dir)?;
        sd.log
            .event("tile", json!({"id": tile.id, "index": i, "record": rec}))?;
        tracing::info!(tile = %tile.id, index = i, "tile taken");
        taken += 1;
        let done = sd.manifest.done();
        let pace = started.elapsed().as_secs_f64() / taken as f64;
        progress(Progress {
            done,
            total,
            tile: &tile.id,
            eta_s: pace * (total - done) as f64,
        });
    }
    let photos = mosaic_all(sd, Interpolation::Bicubic, &|_, _, _| {})?;
    sd.manifest.complete = true;
    sd.manifest.save(&sd.dir)?;
    sd.log.stop("done", None)?;
    Ok(Outcome::Complete { photos })
}

/// Mosaics every region from the tiles on disk; writes `<region>.tiff` and `<region>.json`.
/// `progress(region, band, bands)` follows each photo's bands.
pub fn mosaic_all(
    sd: &mut ScanDir,
    interp: Interpolation,
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> Result<Vec<PathBuf>, ScanError> {
    let mut out = Vec::new();
    for ri in 0..sd.manifest.plan.regions.len() {
        let dir = sd.dir.clone();
        let (tiff, json_path) = mosaic_region(sd, ri, interp, &dir, progress)?;
        let region = &sd.manifest.plan.regions[ri];
        sd.log.event(
            "photo",
            json!({"region": region.name, "image": relative_to(&dir, &tiff),
                   "sidecar": relative_to(&dir, &json_path),
                   "width": region.grid.width, "height": region.grid.height}),
        )?;
        out.push(json_path);
    }
    Ok(out)
}

/// Mosaics region `ri` from the tiles on disk into `dir` (the scan's, or a share's of `rig
/// scan mosaic --tile`): `<region>.tiff`, its preview `<region>.png` and its sidecar
/// `<region>.json`, each written atomically; returns the TIFF's and the sidecar's paths.
pub fn mosaic_region(
    sd: &ScanDir,
    ri: usize,
    interp: Interpolation,
    dir: &Path,
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> Result<(PathBuf, PathBuf), ScanError> {
    let region = &sd.manifest.plan.regions[ri];
    let sources: Vec<TileSource> = sd
        .manifest
        .plan
        .tiles
        .iter()
        .zip(&sd.manifest.tiles)
        .filter(|(t, _)| t.region == ri)
        .filter_map(|(_, r)| r.as_ref())
        .map(|r| {
            let dir = sd.dir.clone();
            let rec = r.file.clone();
            TileSource {
                stage_um: r.stage_um,
                load: Box::new(move || {
                    read_recorded(&dir, &rec).map_err(|e| match e {
                        ScanError::Io(e) => e,
                        e => std::io::Error::new(std::io::ErrorKind::InvalidData, e.to_string()),
                    })
                }),
            }
        })
        .collect();
    let px = mosaic::mosaic(&sd.cal, &region.grid, &sources, interp, &|b, n| {
        progress(&region.name, b, n)
    })?;
    let tiff = dir.join(format!("{}.tiff", region.name));
    write_tiff16(&tiff, region.grid.width, region.grid.height, &px)?;
    preview(&dir.join(format!("{}.png", region.name)), &region.grid, &px)?;
    let side = sidecar_for(sd, &region.name, &region.grid, sources.len(), interp);
    let json_path = dir.join(format!("{}.json", region.name));
    write_json(
        &json_path,
        &serde_json::to_value(&side).map_err(std::io::Error::other)?,
    )?;
    Ok((tiff, json_path))
}

/// An 8-bit look at the photo for the operator (at most 1600 px across, contrast stretched
/// over the 0.5–99.5 % range); the TIFF is the data.
fn preview(path: &Path, grid: &PhotoGrid, px: &[u16]) -> std::io::Result<()> {
    let (pw, ph, bytes) = crate::digitise::look8(grid.width, grid.height, 1600, |i| px[i] as f32);
    crate::atomic::write_with(path, |w| {
        image::write_buffer_with_format(
            w,
            &bytes,
            pw as u32,
            ph as u32,
            image::ExtendedColorType::L8,
            image::ImageFormat::Png,
        )
        .map_err(std::io::Error::other)
    })
}

fn sidecar_for(
    sd: &ScanDir,
    region: &str,
    grid: &PhotoGrid,
    tiles: usize,
    interp: Interpolation,
) -> sidecar::ScannedPhoto {
    let cal = &sd.cal;
    sidecar::ScannedPhoto {
        format: sidecar::FORMAT.into(),
        image: format!("{region}.tiff"),
        film: sd.script.film_name.clone(),
        region: region.into(),
        grid: *grid,
        grey: sidecar::Grey {
            counts_per_dn: sd.counts_per_dn(),
            camera_bit_depth: cal.rig.bit_depth,
            nodata: 0,
            flat_fielded: sd.manifest.flat.is_some(),
        },
        interior_orientation: sidecar::InteriorRecord {
            session: relative_to(&sd.dir, &cal.interior_session),
            version: cal.version.name().into(),
            carriage_to_photo: cal.carriage_to_photo,
            rms_um: cal.rms_um,
            fiducials: cal.fiducials.clone(),
        },
        camera_certificate: sidecar::CertificateRecord {
            path: relative_to(&sd.dir, &cal.camera_certificate),
            name: cal.certificate.name.clone(),
            focal_length_mm: cal.certificate.focal_length_mm,
            fiducials: cal
                .certificate
                .fiducials
                .iter()
                .map(|f| sidecar::CertificateFiducial {
                    id: f.id,
                    photo_mm: f.photo,
                })
                .collect(),
        },
        pixel_to_carriage: sidecar::PixelRecord {
            session: relative_to(&sd.dir, &cal.pixel_session),
            params: cal.pixel.params,
        },
        scan: sidecar::ScanRecord {
            script: sd.manifest.script.clone(),
            tiles,
            frames_per_tile: sd.script.capture.frames,
            filter: sd.script.capture.filter,
            overlap: sd.script.capture.overlap,
            resolution_um: sd.script.resolution_um,
            interpolation: match interp {
                Interpolation::Bicubic => "bicubic (Keys, a = -0.5)".into(),
                Interpolation::Nearest => "nearest".into(),
            },
            antialias_sigma_px: match interp {
                Interpolation::Bicubic => mosaic::antialias_sigma_px(cal, grid.step_mm),
                Interpolation::Nearest => 0.0,
            },
            feather_px: mosaic::FEATHER_PX,
        },
    }
}
