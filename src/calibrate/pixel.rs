//! The pixel→carriage calibration (seed 002, "Pixel to carriage transformation"): the central
//! cross of the carriage plate is stepped through a 5×5 grid of image positions, measured at
//! each, and the affine transformation from pixel to local carriage coordinates (origin at
//! the measuring mark) is fitted, with the 4-parameter variant beside it; then the stage
//! drives to all crosses of the plate to find the measuring mark's pixel (seed Table 3).
//!
//! Local carriage coordinates of a pixel p seen with the stage at S: `A·p + t`, so a point at
//! carriage C appears where `C − S = A·p + t`; the mark (the pixel that sees S itself) is
//! `−A⁻¹·t`.

use super::affine_fit::{fit, inv2, Fit, FitError, Model};
use super::session::Session;
use crate::camera::Camera;
use crate::coords::{CarriageUm, PixelXY};
use crate::digitise::{capture, CaptureError, ImageF32};
use crate::stage::{Stage, StageError};
use crate::targets::certificate::PlateCertificate;
use crate::targets::measure::{measure, MarkResult, MarkTemplates, Quality};
use serde::Serialize;
use serde_json::json;
use std::time::Duration;

#[derive(Debug, Clone)]
pub struct PixelOptions {
    /// Frames averaged at each position (the seed used 32).
    pub frames: u32,
    /// Positions per side of the grid.
    pub grid: usize,
    /// Side of the least-squares patch, px.
    pub patch: usize,
    /// The optics' blur for the templates, px.
    pub blur_px: f64,
    /// Pixel spacing to start from (µm, x and y) until the first look measures it.
    pub nominal_um_per_px: [f64; 2],
    /// The first look's stage steps, µm.
    pub look_step_um: f64,
    pub home: bool,
    /// Also visit every cross of the plate to locate the measuring mark.
    pub all_crosses: bool,
    /// Take a flat field on clear plate glass first and divide every image by it.
    pub flat_field: bool,
    pub quality: Quality,
}

impl Default for PixelOptions {
    fn default() -> Self {
        PixelOptions {
            frames: 32,
            grid: 5,
            patch: 71,
            blur_px: 0.7,
            nominal_um_per_px: [10.0, 10.0],
            look_step_um: 1000.0,
            home: true,
            all_crosses: true,
            flat_field: true,
            quality: Quality::default(),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum CalibrateError {
    #[error(transparent)]
    Stage(#[from] StageError),
    #[error(transparent)]
    Capture(#[from] CaptureError),
    #[error("session store")]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Fit(#[from] FitError),
    #[error("{0}")]
    NotFound(String),
    /// Asked to pause (or stop) by the operator; seen before the next move.
    #[error("interrupted by the operator before the next mark; the session ends here (a calibration's marks are measured in one stretch: a paused one starts a new session when resumed)")]
    Interrupted,
    #[error("the flat field at carriage {at} is not clear glass ({dark:.1} % of it is dark): is a film lying over the plate? Lift it off (the simulator's: `rig run lift-film`); else clean the plate there, or calibrate without a flat field (--no-flat, or no_flat in a queue item)")]
    FlatNotClear { at: CarriageUm, dark: f64 },
}

/// The session's flat field, beside its results.
pub const FLAT: &str = "flat.tiff";

/// The point of the plate farthest from every cross, inside the crosses' bounding box: clear
/// glass for the flat field.
fn clear_spot(plate: &PlateCertificate) -> CarriageUm {
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for c in &plate.crosses {
        lo = [lo[0].min(c.x_um), lo[1].min(c.y_um)];
        hi = [hi[0].max(c.x_um), hi[1].max(c.y_um)];
    }
    let mut best = (f64::MIN, CarriageUm::new(lo[0], lo[1]));
    for j in 0..=40 {
        for i in 0..=40 {
            let p = CarriageUm::new(
                lo[0] + (hi[0] - lo[0]) * i as f64 / 40.0,
                lo[1] + (hi[1] - lo[1]) * j as f64 / 40.0,
            );
            let d = plate
                .crosses
                .iter()
                .map(|c| (c.position() - p).norm())
                .fold(f64::MAX, f64::min);
            if d > best.0 + 1e-6 {
                best = (d, p);
            }
        }
    }
    best.1
}

/// One measured position of a cross.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct CrossObservation {
    pub id: String,
    pub cross: u32,
    /// Where the stage was (its verified position).
    pub stage_um: CarriageUm,
    #[serde(flatten)]
    pub result: MarkResult,
}

/// The measuring mark's pixel from each cross and together (seed Table 3).
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct MarkLocation {
    pub mean: PixelXY,
    pub std: [f64; 2],
    pub from_affine: PixelXY,
    pub per_cross: Vec<(u32, PixelXY)>,
}

#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct PixelCalibration {
    /// The first look's 2×2 (µm per px), from stage steps.
    pub first_look: [[f64; 2]; 2],
    pub grid: Vec<CrossObservation>,
    pub affine: Fit,
    /// Scales and shears as seed Table 2 lists them, µm.
    pub x_scale: f64,
    pub y_scale: f64,
    pub x_shear: f64,
    pub y_shear: f64,
    pub rms_um: f64,
    pub crosses: Vec<CrossObservation>,
    pub mark: Option<MarkLocation>,
    /// Pixel coordinates centred at the mark, no shifts (the seed's first attempt).
    pub linear4: Option<Fit>,
    /// Coarse and fine matching of every cross measured (seed Table 1).
    pub matching: Option<crate::targets::measure::MatchTable>,
}

fn mul2(m: [[f64; 2]; 2], v: [f64; 2]) -> [f64; 2] {
    [
        m[0][0] * v[0] + m[0][1] * v[1],
        m[1][0] * v[0] + m[1][1] * v[1],
    ]
}

/// One step of a calibration drive, for the operator: what it does and, in a series (the grid,
/// the crosses, the fiducials), which of how many it is (from 1).
#[derive(Debug, Clone, Copy)]
pub struct Step<'a> {
    pub what: &'a str,
    pub of: Option<(usize, usize)>,
}

impl<'a> Step<'a> {
    pub fn note(what: &'a str) -> Step<'a> {
        Step { what, of: None }
    }

    pub fn counted(what: &'a str, k: usize, n: usize) -> Step<'a> {
        Step {
            what,
            of: Some((k, n)),
        }
    }
}

/// The hardware and the record of one session.
pub struct Rig<'a> {
    pub stage: &'a mut dyn Stage,
    pub camera: &'a mut dyn Camera,
    pub session: &'a mut Session,
    /// Progress messages for the operator.
    pub progress: &'a mut dyn FnMut(Step<'_>),
    /// Divides every image taken (dust, the measuring mark): the pixel session takes it, the
    /// sessions after it reuse it.
    pub flat: Option<crate::digitise::FlatField>,
    /// Set from outside to end the session before the next move (the service's pause and
    /// stop); `None`: runs to its end.
    pub interrupt: Option<&'a std::sync::atomic::AtomicBool>,
    /// Shown every averaged image the session takes (the service's live view).
    pub seen: Option<&'a mut dyn FnMut(&ImageF32)>,
}

impl Rig<'_> {
    /// Moves to `at` and takes a filtered average of `frames` frames there.
    pub(super) fn look(
        &mut self,
        at: CarriageUm,
        frames: u32,
    ) -> Result<(CarriageUm, ImageF32), CalibrateError> {
        if self
            .interrupt
            .is_some_and(|i| i.load(std::sync::atomic::Ordering::SeqCst))
        {
            return Err(CalibrateError::Interrupted);
        }
        let s = self.stage.move_to(at)?;
        // Frames captured before the stage stood still are set aside.
        let settled = self.camera.now().map_err(CaptureError::from)?;
        let mut c = capture(
            self.camera,
            frames,
            true,
            Duration::from_secs(5),
            Some(settled),
            |_| {},
        )?;
        if let Some(f) = &self.flat {
            f.apply(&mut c.image);
        }
        if let Some(seen) = self.seen.as_mut() {
            seen(&c.image);
        }
        Ok((s, c.image))
    }
}

/// Runs the pixel→carriage calibration.
pub fn calibrate_pixel(
    rig: &mut Rig,
    plate: &PlateCertificate,
    opt: &PixelOptions,
) -> Result<PixelCalibration, CalibrateError> {
    if opt.home {
        (rig.progress)(Step::note("homing"));
        rig.stage.home()?;
        rig.session.event("homed", json!({}))?;
    }
    if opt.flat_field {
        let at = clear_spot(plate);
        (rig.progress)(Step::note("flat field on clear plate glass"));
        rig.flat = None;
        let (s, img) = rig.look(at, 4 * opt.frames)?;
        let f = crate::digitise::FlatField::from_image(&img);
        rig.session.event(
            "flat",
            json!({"stage_um": s, "dark_percent": f.dark_percent, "file": FLAT}),
        )?;
        if !f.is_clear() {
            return Err(CalibrateError::FlatNotClear {
                at: s,
                dark: f.dark_percent,
            });
        }
        crate::digitise::flat::save_counts(
            &rig.session.dir.join(FLAT),
            &img,
            rig.camera.info().bit_depth,
        )?;
        rig.flat = Some(f);
    }
    let central = plate.central();
    let c0 = central.position();
    let nominal = [
        [opt.nominal_um_per_px[0], 0.0],
        [0.0, opt.nominal_um_per_px[1]],
    ];
    // First look: the cross under the mark, then one step in x and one in y.
    (rig.progress)(Step::note(&format!("first look at cross {}", central.id)));
    let t_nom = MarkTemplates::new(
        &plate.shape,
        plate.polarity,
        nominal,
        opt.patch,
        opt.blur_px,
    )
    .map_err(CalibrateError::NotFound)?;
    let q = &opt.quality;
    let mut seen = Vec::new();
    for d in [[0.0, 0.0], [opt.look_step_um, 0.0], [0.0, opt.look_step_um]] {
        let (s, img) = rig.look(c0 + CarriageUm::new(d[0], d[1]), 4)?;
        let co = crate::targets::locate(&img, &t_nom.whole, &q.coarse).map_err(|e| {
            CalibrateError::NotFound(format!(
                "cross {} not in view with the stage at ({:.3}, {:.3}) mm: {e}. Is the plate \
                 in place and lit, and is --pixel-um near the camera's real spacing?",
                central.id,
                s.x_mm(),
                s.y_mm()
            ))
        })?;
        seen.push((s, co.centre));
    }
    // A stage step ΔS moves the cross by −A⁻¹·ΔS in the image.
    let col = |k: usize| {
        let ds = seen[k].0 - seen[0].0;
        let dp = [seen[0].1.col - seen[k].1.col, seen[0].1.row - seen[k].1.row];
        (ds, dp)
    };
    let (dsx, dpx) = col(1);
    let (dsy, dpy) = col(2);
    // A⁻¹ from two steps: [dpx dpy] = A⁻¹ [dsx dsy].
    let ds = [[dsx.x, dsy.x], [dsx.y, dsy.y]];
    let dp = [[dpx[0], dpy[0]], [dpx[1], dpy[1]]];
    let ainv = {
        let dsi =
            inv2(ds).ok_or_else(|| CalibrateError::NotFound("the stage did not step".into()))?;
        [
            [
                dp[0][0] * dsi[0][0] + dp[0][1] * dsi[1][0],
                dp[0][0] * dsi[0][1] + dp[0][1] * dsi[1][1],
            ],
            [
                dp[1][0] * dsi[0][0] + dp[1][1] * dsi[1][0],
                dp[1][0] * dsi[0][1] + dp[1][1] * dsi[1][1],
            ],
        ]
    };
    let a = inv2(ainv)
        .filter(|m| m[0][0] > 0.0 && m[1][1] > 0.0)
        .ok_or_else(|| {
            CalibrateError::NotFound(
                "the cross did not move with the stage as a camera over the carriage would".into(),
            )
        })?;
    rig.session
        .event("first_look", json!({"um_per_px": a, "seen": seen}))?;
    let tpl = MarkTemplates::new(&plate.shape, plate.polarity, a, opt.patch, opt.blur_px)
        .map_err(CalibrateError::NotFound)?;
    let (p0, s0) = (seen[0].1, seen[0].0);

    // The 5×5 grid of image positions.
    let (w, h) = {
        let i = rig.camera.info();
        (i.width as f64, i.height as f64)
    };
    let margin = opt.patch as f64 / 2.0 + 12.0;
    let n = opt.grid.max(2);
    let mut grid = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let q_px = [
                margin + (w - 2.0 * margin) * i as f64 / (n - 1) as f64,
                margin + (h - 2.0 * margin) * j as f64 / (n - 1) as f64,
            ];
            let d = mul2(a, [q_px[0] - p0.col, q_px[1] - p0.row]);
            let target = s0 - CarriageUm::new(d[0], d[1]);
            let k = grid.len() + 1;
            (rig.progress)(Step::counted(
                &format!(
                    "grid {k}/{}: cross {} toward pixel ({:.0}, {:.0})",
                    n * n,
                    central.id,
                    q_px[0],
                    q_px[1]
                ),
                k,
                n * n,
            ));
            let (s, img) = rig.look(target, opt.frames)?;
            let r = measure(&img, &tpl, q);
            let id = format!("grid-{}-{}", i + 1, j + 1);
            let at = r.seen_at();
            if let Some(c) = at {
                rig.session.save_crop(&id, &img, c, opt.patch / 2 + 10)?;
            }
            let o = CrossObservation {
                id,
                cross: central.id,
                stage_um: s,
                result: r,
            };
            rig.session
                .event("measured", serde_json::to_value(&o).unwrap_or_default())?;
            grid.push(o);
        }
    }
    let pts: Vec<(String, [f64; 2], [f64; 2])> = grid
        .iter()
        .filter_map(|o| {
            let p = o.result.centre()?;
            let l = c0 - o.stage_um;
            Some((o.id.clone(), [p.col, p.row], [l.x, l.y]))
        })
        .collect();
    if pts.len() < 4 {
        let why = grid
            .iter()
            .find_map(|o| o.result.rejected.clone())
            .unwrap_or_default();
        return Err(CalibrateError::NotFound(format!(
            "cross {} was measured usably at only {} of {} grid positions (first reason: {why}); \
             clean the cross or see the crops in the session",
            central.id,
            pts.len(),
            grid.len()
        )));
    }
    let affine = fit(Model::Affine6, &pts, true)?;
    let ap = affine.params;
    if (ap[1] * ap[5] - ap[2] * ap[4]).abs() < 1e-12 {
        return Err(FitError::Singular.into());
    }
    let mark_affine = {
        let m = affine.inverse_linear([-ap[0], -ap[3]]);
        PixelXY::new(m[0], m[1])
    };
    rig.session.event(
        "pixel_to_carriage",
        serde_json::to_value(&affine).unwrap_or_default(),
    )?;

    // Every cross under the mark: where the mark is in the image.
    let mut crosses = Vec::new();
    let mut mark = None;
    let mut linear4 = None;
    if opt.all_crosses {
        let mut per = Vec::new();
        for (k, c) in plate.crosses.iter().enumerate() {
            (rig.progress)(Step::counted(
                &format!(
                    "cross {} ({}/{}) under the measuring mark",
                    c.id,
                    k + 1,
                    plate.crosses.len()
                ),
                k + 1,
                plate.crosses.len(),
            ));
            let (s, img) = rig.look(c.position(), opt.frames)?;
            let r = measure(&img, &tpl, q);
            let id = format!("cross-{}", c.id);
            if let Some(p) = r.seen_at() {
                rig.session.save_crop(&id, &img, p, opt.patch / 2 + 10)?;
            }
            if let Some(p) = r.centre() {
                let l = c.position() - s;
                let d = affine.inverse_linear([l.x, l.y]);
                per.push((c.id, PixelXY::new(p.col - d[0], p.row - d[1])));
            }
            let o = CrossObservation {
                id,
                cross: c.id,
                stage_um: s,
                result: r,
            };
            rig.session
                .event("measured", serde_json::to_value(&o).unwrap_or_default())?;
            crosses.push(o);
        }
        if !per.is_empty() {
            let n = per.len() as f64;
            let mc = per.iter().map(|p| p.1.col).sum::<f64>() / n;
            let mr = per.iter().map(|p| p.1.row).sum::<f64>() / n;
            let sd = |f: &dyn Fn(&PixelXY) -> f64, m: f64| {
                if per.len() > 1 {
                    (per.iter().map(|p| (f(&p.1) - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
                } else {
                    0.0
                }
            };
            let m = MarkLocation {
                mean: PixelXY::new(mc, mr),
                std: [sd(&|p| p.col, mc), sd(&|p| p.row, mr)],
                from_affine: mark_affine,
                per_cross: per,
            };
            // The seed's first attempt: pixel coordinates centred at the mark, 4 parameters.
            let centred: Vec<_> = pts
                .iter()
                .map(|(id, p, l)| (id.clone(), [p[0] - mc, p[1] - mr], *l))
                .collect();
            linear4 = fit(Model::Linear4, &centred, false).ok();
            mark = Some(m);
        }
    }
    let labels = |title| super::plot::Labels {
        title,
        from: "camera pixel (px)",
        from_per_label: 1.0,
        unit: "µm",
        residuals: "on the carriage",
    };
    super::plot::residual_plot(
        &affine,
        &labels("pixel -> carriage, affine (6 parameters)"),
        &rig.session.dir.join("residuals-affine.png"),
    )?;
    if let Some(l) = &linear4 {
        super::plot::residual_plot(
            l,
            &labels("pixel -> carriage, linear (4 parameters)"),
            &rig.session.dir.join("residuals-linear4.png"),
        )?;
    }
    let matching =
        crate::targets::measure::match_table(grid.iter().chain(&crosses).map(|o| &o.result));
    Ok(PixelCalibration {
        matching,
        first_look: a,
        x_scale: ap[1],
        y_scale: ap[5],
        x_shear: ap[2],
        y_shear: ap[4],
        rms_um: affine.rms_total(),
        affine,
        grid,
        crosses,
        mark,
        linear4,
    })
}
