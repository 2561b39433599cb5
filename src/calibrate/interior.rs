//! The carriage→image transformation, the interior orientation (seed 002, "Carriage to image
//! transformation"): the stage finds and drives to each of the film's fiducials, measures it by
//! least-squares matching against its synthetic template, moves it to carriage coordinates by
//! the pixel→carriage transformation, and fits the affine carriage→photo transformation to
//! the certificate's coordinates in the versions of seed Table 5: all fiducials, the corners
//! only, the mid-sides only.

use super::affine_fit::{fit, Fit, Model};
use super::pixel::{CalibrateError, Rig};
use crate::coords::{CarriageUm, PixelXY};
use crate::targets::certificate::{CameraCertificate, FiducialGroup};
use crate::targets::mark::MarkShape;
use crate::targets::measure::{measure, MarkResult, MarkTemplates, Quality};
use serde::{Deserialize, Serialize};
use serde_json::json;

/// Pixel → carriage as a pixel session measured it: carriage = stage + A·p + t.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct PixelTransform {
    /// a0, a1, a2, b0, b1, b2 (µm, µm per px).
    pub params: [f64; 6],
}

impl PixelTransform {
    pub fn carriage(&self, stage: CarriageUm, p: PixelXY) -> CarriageUm {
        let a = &self.params;
        stage
            + CarriageUm::new(
                a[0] + a[1] * p.col + a[2] * p.row,
                a[3] + a[4] * p.col + a[5] * p.row,
            )
    }

    pub fn um_per_px(&self) -> [[f64; 2]; 2] {
        super::affine_fit::linear_part(&self.params)
    }

    /// The pixel that sees the stage position itself.
    pub fn mark(&self) -> PixelXY {
        let a = &self.params;
        let [c, r] = super::affine_fit::solve_linear(a, [-a[0], -a[3]]);
        PixelXY::new(c, r)
    }
}

#[derive(Debug, Clone)]
pub struct InteriorOptions {
    pub frames: u32,
    pub patch: usize,
    pub blur_px: f64,
    /// Where the photo centre is expected on the carriage before any fiducial is found.
    pub film_centre: CarriageUm,
    /// How many rings of neighbouring fields to search around a prediction.
    pub search_rings: u32,
    pub quality: Quality,
}

impl Default for InteriorOptions {
    fn default() -> Self {
        InteriorOptions {
            frames: 32,
            patch: 71,
            blur_px: 0.7,
            film_centre: CarriageUm::new(125_000.0, 125_000.0),
            search_rings: 2,
            quality: Quality::default(),
        }
    }
}

/// One fiducial's measurement.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct FiducialObservation {
    pub id: u32,
    pub group: FiducialGroup,
    /// The certificate's photo coordinates, mm.
    pub photo_mm: [f64; 2],
    pub stage_um: Option<CarriageUm>,
    /// The fiducial centre in carriage coordinates.
    pub carriage_um: Option<CarriageUm>,
    /// Fields looked at before it was found.
    pub fields_searched: u32,
    #[serde(flatten)]
    pub result: Option<MarkResult>,
    /// Why it is not used; `None` = used.
    pub missing: Option<String>,
}

/// One version of the carriage→image fit (seed Table 5).
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct InteriorVersion {
    pub name: String,
    pub fiducials: Vec<u32>,
    /// Carriage µm → photo µm (mm × 1000, so residuals read in µm).
    pub fit: Option<Fit>,
    pub rms_um: Option<f64>,
    pub error: Option<String>,
}

#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct InteriorOrientation {
    /// Coarse and fine matching of the fiducials (seed Table 4).
    pub matching: Option<crate::targets::measure::MatchTable>,
    pub fiducials: Vec<FiducialObservation>,
    pub versions: Vec<InteriorVersion>,
}

/// Photo → carriage estimate from the fiducials found so far: a shift from one, a similarity
/// from two, an affine from three or more.
fn predictor(
    found: &[(CarriageUm, [f64; 2])],
    centre: CarriageUm,
) -> impl Fn([f64; 2]) -> CarriageUm {
    // Coefficients of X = c0 + c1·u + c2·v, Y = c3 + c4·u + c5·v (u, v in mm, X, Y in µm).
    let mut c = [centre.x, 1000.0, 0.0, centre.y, 0.0, 1000.0];
    match found.len() {
        0 => {}
        1 => {
            let (s, p) = found[0];
            c[0] = s.x - 1000.0 * p[0];
            c[3] = s.y - 1000.0 * p[1];
        }
        2 => {
            // Similarity: complex ratio of the two difference vectors.
            let (s0, p0) = found[0];
            let (s1, p1) = found[1];
            let (du, dv) = (p1[0] - p0[0], p1[1] - p0[1]);
            let (dx, dy) = (s1.x - s0.x, s1.y - s0.y);
            let n = du * du + dv * dv;
            let (a, b) = ((dx * du + dy * dv) / n, (dy * du - dx * dv) / n);
            c = [
                s0.x - (a * p0[0] - b * p0[1]),
                a,
                -b,
                s0.y - (b * p0[0] + a * p0[1]),
                b,
                a,
            ];
        }
        _ => {
            let pts: Vec<_> = found
                .iter()
                .enumerate()
                .map(|(i, (s, p))| (i.to_string(), *p, [s.x, s.y]))
                .collect();
            if let Ok(f) = fit(Model::Affine6, &pts, false) {
                c = f.params;
            }
        }
    }
    move |p: [f64; 2]| {
        CarriageUm::new(
            c[0] + c[1] * p[0] + c[2] * p[1],
            c[3] + c[4] * p[0] + c[5] * p[1],
        )
    }
}

/// Field offsets for a square spiral of `rings` rings, nearest first.
fn spiral(rings: u32) -> Vec<(i32, i32)> {
    let mut v = vec![(0, 0)];
    for r in 1..=rings as i32 {
        for j in -r..=r {
            for i in -r..=r {
                if i.abs() == r || j.abs() == r {
                    v.push((i, j));
                }
            }
        }
    }
    v
}

/// Runs the interior orientation of the film on the carriage.
pub fn calibrate_interior(
    rig: &mut Rig,
    cert: &CameraCertificate,
    pixel: &PixelTransform,
    opt: &InteriorOptions,
) -> Result<InteriorOrientation, CalibrateError> {
    let q = &opt.quality;
    let (w, h) = {
        let i = rig.camera.info();
        (i.width as f64, i.height as f64)
    };
    let a = pixel.um_per_px();
    // Fields overlap by a fifth when searching.
    let field = [0.8 * w * a[0][0].abs(), 0.8 * h * a[1][1].abs()];
    let mark = pixel.mark();
    // Corners first (the better calibrated group), then the mid-sides.
    let mut order: Vec<_> = cert.fiducials.iter().collect();
    order.sort_by_key(|f| (f.group, f.id));
    let mut found: Vec<(CarriageUm, [f64; 2])> = Vec::new();
    let mut obs = Vec::new();
    // Fiducials of one shape share their templates (drawing them is most of a mark's work).
    let mut drawn: Vec<(&MarkShape, MarkTemplates)> = Vec::new();
    for (k, f) in order.iter().enumerate() {
        let i = match drawn.iter().position(|(s, _)| **s == f.shape) {
            Some(i) => i,
            None => {
                let t = MarkTemplates::new(&f.shape, cert.polarity, a, opt.patch, opt.blur_px)
                    .map_err(|e| CalibrateError::NotFound(format!("fiducial {}: {e}", f.id)))?;
                drawn.push((&f.shape, t));
                drawn.len() - 1
            }
        };
        let tpl = &drawn[i].1;
        let pred = predictor(&found, opt.film_centre)([f.photo.x, f.photo.y]);
        let rings = if found.len() < 2 { opt.search_rings } else { 1 };
        let mut hit = None;
        let mut searched = 0;
        for (i, j) in spiral(rings) {
            searched += 1;
            let at = pred + CarriageUm::new(i as f64 * field[0], j as f64 * field[1]);
            (rig.progress)(super::pixel::Step::counted(
                &format!(
                    "fiducial {} ({}/{}): looking at ({:.2}, {:.2}) mm",
                    f.id,
                    k + 1,
                    order.len(),
                    at.x_mm(),
                    at.y_mm()
                ),
                k + 1,
                order.len(),
            ));
            if rig.stage.limits().check(at).is_err() {
                continue;
            }
            let (s, img) = rig.look(at, 4)?;
            if let Ok(m) = crate::targets::locate(&img, &tpl.whole, &q.coarse) {
                hit = Some(pixel.carriage(s, m.centre));
                break;
            }
        }
        let Some(rough) = hit else {
            let why = format!("not found in {searched} fields around its predicted position");
            rig.session
                .event("fiducial_missing", json!({"id": f.id, "why": why}))?;
            obs.push(FiducialObservation {
                id: f.id,
                group: f.group,
                photo_mm: [f.photo.x, f.photo.y],
                stage_um: None,
                carriage_um: None,
                fields_searched: searched,
                result: None,
                missing: Some(why),
            });
            continue;
        };
        // Centre it under the measuring mark and measure it properly.
        (rig.progress)(super::pixel::Step::counted(
            &format!("fiducial {} ({}/{}): measuring", f.id, k + 1, order.len()),
            k + 1,
            order.len(),
        ));
        let (s, img) = rig.look(rough, opt.frames)?;
        let r = measure(&img, tpl, q);
        let id = format!("fiducial-{}", f.id);
        let p = r.seen_at().unwrap_or(mark);
        rig.session.save_crop(&id, &img, p, opt.patch / 2 + 10)?;
        let carriage = r.centre().map(|p| pixel.carriage(s, p));
        if let Some(cu) = carriage {
            found.push((cu, [f.photo.x, f.photo.y]));
        }
        let o = FiducialObservation {
            id: f.id,
            group: f.group,
            photo_mm: [f.photo.x, f.photo.y],
            stage_um: Some(s),
            carriage_um: carriage,
            fields_searched: searched,
            missing: r.rejected.clone(),
            result: Some(r),
        };
        rig.session
            .event("measured", serde_json::to_value(&o).unwrap_or_default())?;
        obs.push(o);
    }
    let version = |name: &str, keep: &dyn Fn(&FiducialObservation) -> bool| {
        let pts: Vec<_> = obs
            .iter()
            .filter(|o| keep(o))
            .filter_map(|o| {
                let c = o.carriage_um?;
                Some((
                    o.id.to_string(),
                    [c.x, c.y],
                    [o.photo_mm[0] * 1000.0, o.photo_mm[1] * 1000.0],
                ))
            })
            .collect();
        let ids = pts.iter().map(|p| p.0.parse().unwrap_or(0)).collect();
        // Three points fix an affine exactly: nothing would be checked, so at least four.
        let r = if pts.len() < 4 {
            Err(super::affine_fit::FitError::TooFewPoints {
                points: pts.len(),
                params: 6,
                need: 4,
            })
        } else {
            fit(Model::Affine6, &pts, false)
        };
        match r {
            Ok(f) => InteriorVersion {
                name: name.into(),
                fiducials: ids,
                rms_um: Some(f.rms_total()),
                fit: Some(f),
                error: None,
            },
            Err(e) => InteriorVersion {
                name: name.into(),
                fiducials: ids,
                fit: None,
                rms_um: None,
                error: Some(e.to_string()),
            },
        }
    };
    let versions = vec![
        version("all", &|_| true),
        version("corners", &|o| o.group == FiducialGroup::Corner),
        version("mid-sides", &|o| o.group == FiducialGroup::MidSide),
    ];
    for v in &versions {
        if let Some(f) = &v.fit {
            let name = format!("residuals-{}.png", v.name);
            let title = format!("carriage -> photo, affine: {}", v.name);
            let labels = super::plot::Labels {
                title: &title,
                from: "carriage (mm)",
                from_per_label: 1000.0,
                unit: "µm",
                residuals: "on the photo",
            };
            super::plot::residual_plot(f, &labels, &rig.session.dir.join(name))?;
        }
    }
    rig.session.event(
        "carriage_to_image",
        serde_json::to_value(&versions).unwrap_or_default(),
    )?;
    // A session that fitted nothing must not become the newest interior orientation a scan
    // picks up: it fails (its log keeps every mark it saw and why the others were missed).
    if versions.iter().all(|v| v.fit.is_none()) {
        return Err(CalibrateError::NotFound(format!(
            "no carriage→photo affine could be fitted: {} of {} fiducials measured ({}). \
             Is the film on the carriage, lit, and the camera certificate the film's?",
            found.len(),
            obs.len(),
            versions[0].error.as_deref().unwrap_or("no fit")
        )));
    }
    Ok(InteriorOrientation {
        matching: crate::targets::measure::match_table(
            obs.iter().filter_map(|o| o.result.as_ref()),
        ),
        fiducials: obs,
        versions,
    })
}
