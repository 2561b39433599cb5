//! The sweep over N photos (project format 2): every photo becomes a [`Sensor`] (its camera
//! and orientation, given or resected from the control points), every pair whose footprints
//! overlap gets mapping functions from the two sensors (seed 004 §4) and seed 000's sweep,
//! and the heights of all pairs are merged into one grid in the project's CRS.

pub mod height_sweep;
pub mod pair_model;
pub mod regions;
pub mod scanned_pair;

use crate::coords::{GroundM, PixelWindow, PixelXY};
use crate::geometry::control_covariance::{block_covariance, CrossCovariances, Resected};
use crate::geometry::control_fit::{
    correct_orbit, correct_rpc_shift, ControlFit, ControlFitError, OrbitPrior,
};
use crate::geometry::{
    resect, Crs, FrameCamera, FrameSensor, Geographic, Interior, PhotoGrid, PhotoSensor,
    PixelToPhoto, Resection, ResectionError, RpcSensor, Sensor,
};
use crate::matching::accuracy::averaging::{remove_window_averaging, AveragingReport, Kernel};
use crate::matching::accuracy::precision::{
    check_sigma, sigma_vs_reference, variance_factor, SigmaCheck, VarianceFactor,
};
use crate::matching::grid::{Comparison, ElevationGrid};
use crate::matching::mapping::pmf_set::{FitReport, SampleGrid, TermSet};
use crate::matching::methods::sweep::height_sweep::{
    step_for_parallax, sweep_bands, HeightMap, SweepLayout, SweepParams, SweptBands,
};
use crate::matching::methods::sweep::pair_model::{
    estimate, pmf_dtm_from_heights, Budget, DtmError, PmfDtmParams, PmfDtmReport,
};
use crate::matching::methods::sweep::regions::RegionParams;
use crate::matching::methods::sweep::scanned_pair::{Photo, PipelineError};
use crate::matching::products::files::read_geotiff;
use crate::matching::products::ortho::View;
use crate::matching::project::GivenModel;
use crate::matching::project::{Kind, Observation, Project2, Project2Error, Source};
use crate::matching::{MatchedPoint, PmfSet};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum Pipeline2Error {
    #[error(transparent)]
    Project(#[from] Project2Error),
    #[error("photo `{id}`: {message}")]
    Photo { id: String, message: String },
    #[error("photo `{id}`: resection from {points} control points: {cause}")]
    Resection {
        id: String,
        points: usize,
        cause: ResectionError,
    },
    #[error("{0}")]
    Heights(String),
    #[error("no two photos overlap on the ground at {z:.0} m (the middle of the heights tried){within}: {prints}; check [dem] heights (do they bracket the terrain?), [dem] extent and the photos' orientations")]
    NoOverlap {
        z: f64,
        /// Each photo's footprint at `z`, in the project's CRS.
        prints: String,
        /// " within [dem] extent …" when the project gives one.
        within: String,
    },
    #[error("photos `{left}` and `{right}`: {cause}")]
    Pair {
        left: String,
        right: String,
        cause: DtmError,
    },
    #[error("photos `{left}` and `{right}`: mapping functions from the sensors: {message}")]
    Mappings {
        left: String,
        right: String,
        message: String,
    },
    #[error("the DEM grid: {0}")]
    Grid(String),
    #[error("the object-space matching: {0}")]
    Oslsm(String),
    /// The output directory, the reference model and the files written: as for format 1.
    #[error(transparent)]
    Output(#[from] PipelineError),
}

/// One pair's part of the run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PairReport {
    pub left: String,
    pub right: String,
    /// Height step used, m (half a pixel of parallax unless the project gave one).
    pub h_step_m: f64,
    pub pmf: Vec<FitReport>,
    pub dtm: PmfDtmReport,
    /// Matched points it added to the merged model.
    pub points: usize,
}

/// `report.json` of a format-2 run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report2 {
    pub project: PathBuf,
    pub crs: Crs,
    /// Photos resected from the control points (the others had their orientation given).
    pub resected: Vec<(String, Resection)>,
    /// Given models corrected by their control points.
    #[serde(default)]
    pub corrected: Vec<(String, ControlFit)>,
    pub heights_m: [f64; 2],
    pub extent: [f64; 4],
    pub pairs: Vec<PairReport>,
    pub points: usize,
    /// How the pairs' node heights disagree against their σ (from the pairs' redundancy);
    /// `None` where no node was seen by two pairs often enough to estimate it. Reported, not
    /// applied: pairs that share a photo share its noise and the terrain's averaging, which
    /// their difference cannot show (on tests/data/validation it came out 0.76 where the true
    /// errors were 1.9 × σ).
    pub variance_factor: Option<VarianceFactor>,
    /// The window averaging taken out of the nodes (see [`crate::matching::accuracy::averaging`]).
    #[serde(default)]
    pub averaging: Option<AveragingReport>,
    /// The RMS over the nodes of the height σ the orientations' own uncertainty gives (see
    /// [`crate::matching::accuracy::orientation_error`]), m; in quality.tif's σ. `None` where every orientation
    /// was taken as exact.
    #[serde(default)]
    pub orientation_sigma_m: Option<f64>,
    #[serde(flatten)]
    pub model: ModelFigures,
}

impl Report2 {
    /// The figures a person looks at first, for report.html.
    pub fn summary(&self) -> Vec<(String, String)> {
        let mut v = vec![(
            "heights tried".into(),
            format!("{:.1} … {:.1} m", self.heights_m[0], self.heights_m[1]),
        )];
        for (id, r) in &self.resected {
            v.push((
                format!("photo {id}"),
                format!(
                    "resected from {} control points, σ0 {:.4} mm on the photo",
                    r.residuals_mm.len(),
                    r.sigma0_mm
                ),
            ));
        }
        v.extend(corrected_lines(&self.corrected));
        for pr in &self.pairs {
            v.push((
                format!("photos {} × {}", pr.left, pr.right),
                format!(
                    "step {:.2} m, {:.1} % matched, {} points kept",
                    pr.h_step_m, pr.dtm.matched_percent, pr.points
                ),
            ));
            for w in pr.dtm.warnings() {
                v.push(("warning".into(), w));
            }
        }
        if let Some(a) = &self.averaging {
            v.push((
                "window averaging".into(),
                format!(
                    "windows of {:.1} m on the ground: the terrain's curvature {} {:.3} m RMS (at most {:.3} m)",
                    a.kernel.window_m,
                    if a.moved { "moved the nodes by" } else { "counted in σ (nodes finer than the windows), a bias of" },
                    a.rms_correction_m,
                    a.max_correction_m
                ),
            ));
        }
        if let Some(o) = self.orientation_sigma_m {
            v.push((
                "orientation".into(),
                format!(
                    "the photos' orientations add σ {o:.3} m (RMS over the nodes) to every height"
                ),
            ));
        }
        if let Some(f) = &self.variance_factor {
            v.push((
                "pairs' agreement".into(),
                format!(
                    "node heights of two pairs differ {:.2} × their σ (from {} nodes; pairs that share a photo share errors their difference cannot show)",
                    f.s0, f.comparisons
                ),
            ));
        }
        v.extend(self.model.lines());
        v
    }
}

/// Cov(δq_i, δq_j) (px²) at `g` of photos `i` and `j` resected from shared control:
/// J_i·C_ij·J_jᵀ.
fn shared_pointing(plan: &Plan, i: usize, j: usize, g: GroundM) -> Option<[[f64; 2]; 2]> {
    let c = plan.shared_orientation.between(i, j)?;
    let ji = plan.sensors[i].frame()?.exterior_partials(g)?;
    let jj = plan.sensors[j].frame()?.exterior_partials(g)?;
    let mut out = [[0.0; 2]; 2];
    for (r, row) in out.iter_mut().enumerate() {
        for (s, v) in row.iter_mut().enumerate() {
            for a in 0..6 {
                for b in 0..6 {
                    *v += ji[r][a] * c[a][b] * jj[s][b];
                }
            }
        }
    }
    Some(out)
}

/// Adds to each node's σ the orientations' part: the σ of the mean of the heights the pairs
/// whose photos both see the ground there intersect, from the photos' pointing covariances
/// and the covariances of photos resected from shared control
/// ([`crate::matching::accuracy::orientation_error::height_sigma`]). Returns its RMS over the nodes, `None` where
/// no photo has a pointing covariance.
fn add_orientation_sigma(grid: &ElevationGrid, sigma: &mut [f32], plan: &Plan) -> Option<f64> {
    use rayon::prelude::*;
    let inside = |s: &PhotoSensor, g: GroundM| {
        let (w, h) = s.image_size();
        s.ground_to_image(g)
            .is_some_and(|q| q.col >= 0.0 && q.row >= 0.0 && q.col <= w as f64 && q.row <= h as f64)
    };
    let centre = grid.node(grid.cols / 2, grid.rows / 2);
    let mid = grid.z.iter().copied().find(|z| z.is_finite())? as f64;
    let g0 = GroundM::new(centre[0], centre[1], mid);
    if plan
        .sensors
        .iter()
        .all(|s| s.pointing_covariance(g0).is_none())
    {
        return None;
    }
    // The orientations' part changes slowly across a model (a tilt, a shift): taken on a
    // lattice of at most SAMPLES × SAMPLES nodes, each node takes its nearest sample's. (Each
    // sample costs some forty projections per pair; on every node it doubled `rig demo`'s
    // model's time.)
    const SAMPLES: usize = 48;
    let step = grid.cols.max(grid.rows).div_ceil(SAMPLES).max(1);
    let (sc, sr) = (grid.cols.div_ceil(step), grid.rows.div_ceil(step));
    let sample = |c: usize, r: usize| -> Option<f64> {
        // The sample's own height, else the nearest with one in its block.
        let mut g = None;
        'find: for rr in r..(r + step).min(grid.rows) {
            for cc in c..(c + step).min(grid.cols) {
                let z = grid.z[rr * grid.cols + cc] as f64;
                if z.is_finite() {
                    let [x, y] = grid.node(cc, rr);
                    g = Some(GroundM::new(x, y, z));
                    break 'find;
                }
            }
        }
        let g = g?;
        let seeing: Vec<(usize, usize)> = plan
            .pairs
            .iter()
            .map(|p| (p.left, p.right))
            .filter(|&(i, j)| inside(&plan.sensors[i], g) && inside(&plan.sensors[j], g))
            .collect();
        crate::matching::accuracy::orientation_error::height_sigma(
            &plan.sensors,
            &seeing,
            g,
            &|i, j| shared_pointing(plan, i, j, g),
        )
        .map(|s| s * s)
    };
    let lattice: Vec<Option<f64>> = (0..sc * sr)
        .into_par_iter()
        .map(|k| sample((k % sc) * step, (k / sc) * step))
        .collect();
    let per_node: Vec<Option<f64>> = (0..grid.z.len())
        .map(|i| lattice[(i / grid.cols / step) * sc + (i % grid.cols) / step])
        .collect();
    let (mut ss, mut n) = (0.0, 0usize);
    for (s, v) in sigma.iter_mut().zip(&per_node) {
        if let (Some(v), true) = (v, s.is_finite()) {
            *s = (*s as f64).hypot(v.sqrt()) as f32;
            ss += v;
            n += 1;
        }
    }
    // Pointing covariances of zero (an RPC stating no error) say nothing either.
    (n > 0 && ss > 0.0).then(|| (ss / n as f64).sqrt())
}

/// A format-2 model, whichever matcher made it, and its checks (in report.json at the top
/// level).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelFigures {
    pub grid: ElevationGrid,
    pub grid_filled: usize,
    /// The model against the project's reference DEM, node by node (seed 000 Table 5).
    pub comparison: Option<Comparison>,
    /// The model's heights at the check points against theirs, with quality.tif's σ there
    /// (each check point once, however many photos observe it).
    pub check_points: Option<SigmaCheck>,
    /// quality.tif's σ against the reference model's differences, node by node.
    pub sigma_vs_reference: Option<SigmaCheck>,
}

impl ModelFigures {
    /// Project `p`'s reference DEM, read once before the matching (so a bad path fails
    /// before the long work, not after it).
    pub fn read_reference(p: &Project2) -> Result<Option<ElevationGrid>, Pipeline2Error> {
        Ok(match &p.reference {
            Some(r) => Some(read_geotiff(r).map_err(|source| PipelineError::Reference {
                path: r.clone(),
                cause: source,
            })?),
            None => None,
        })
    }

    /// The model `grid` with its σ's `sigma_m` (per node) against project `p`'s reference
    /// DEM (from [`ModelFigures::read_reference`], handed back) and check points `obs`
    /// (their survey error, `[points] ground_sigma_m`, adds to the model's).
    pub fn check(
        p: &Project2,
        reference: Option<ElevationGrid>,
        obs: &[Observation],
        grid: ElevationGrid,
        sigma_m: &[f32],
    ) -> (ModelFigures, Option<ElevationGrid>) {
        let survey_sigma_z_m = p.control_sigma_m.map_or(0.0, |[_, z]| z);
        let comparison = reference
            .as_ref()
            .map(|g| grid.compare(|x, y| g.interpolate(x, y)));
        let sigma_vs_reference = reference
            .as_ref()
            .and_then(|g| sigma_vs_reference(&grid, sigma_m, g));
        let mut seen = std::collections::HashSet::new();
        let cps = obs
            .iter()
            .filter(|o| o.kind == Kind::Cp && seen.insert(o.id.as_str()));
        let check_points = check_sigma(cps.filter_map(|o| {
            let g = o.ground?;
            let s = grid
                .node_index(g.x, g.y)
                .map_or(f64::NAN, |i| sigma_m[i] as f64);
            Some((grid.interpolate(g.x, g.y) - g.z, s.hypot(survey_sigma_z_m)))
        }));
        let figures = ModelFigures {
            grid_filled: grid.filled(),
            grid,
            comparison,
            check_points,
            sigma_vs_reference,
        };
        (figures, reference)
    }

    /// The summary lines: the grid, the comparison, σ against the check points and the
    /// reference.
    pub fn lines(&self) -> Vec<(String, String)> {
        let mut v = vec![(
            "grid".to_string(),
            format!(
                "{} × {} nodes, {} with a height",
                self.grid.cols, self.grid.rows, self.grid_filled
            ),
        )];
        if let Some(c) = &self.comparison {
            v.push(("against the reference".into(), c.summary()));
        }
        for (what, c) in [
            ("check points", &self.check_points),
            ("the reference", &self.sigma_vs_reference),
        ] {
            if let Some(c) = c {
                v.push((
                    format!("σ against {what}"),
                    format!(
                        "RMSE {:.2} m, RMS σ {:.2} m, errors {:.1} × σ, {:.0} % within 2σ over {}",
                        c.rmse_m, c.rms_sigma_m, c.ratio, c.within_2_sigma_percent, c.points
                    ),
                ));
            }
        }
        v
    }
}

/// A vertical photo (ω = φ = κ = 0, principal point at the centre) from `centre`, a square
/// image of `side` pixels of `pixel_mm`: the closed-form case of the matchers' tests.
pub fn vertical_sensor(centre: GroundM, focal_mm: f64, side: usize, pixel_mm: f64) -> FrameSensor {
    FrameSensor {
        camera: FrameCamera {
            interior: Interior {
                focal_mm,
                principal_point: crate::coords::PhotoMm::new(0.0, 0.0),
            },
            exterior: crate::geometry::Exterior::from_degrees(0.0, 0.0, 0.0, centre),
        },
        frame: centred_grid(side, side, pixel_mm).into(),
        exterior_cov: None,
    }
}

/// The grid of a plain image with square pixels of `pixel_mm`, its centre on the photo
/// coordinates' origin: x = (col − (W−1)/2)·p, y = ((H−1)/2 − row)·p at pixel centres.
pub fn centred_grid(width: usize, height: usize, pixel_mm: f64) -> PhotoGrid {
    PhotoGrid {
        corner_mm: [
            -0.5 * width as f64 * pixel_mm,
            0.5 * height as f64 * pixel_mm,
        ],
        step_mm: pixel_mm,
        width,
        height,
    }
}

/// A camera's pixel → photo relation applied to an image of `width × height`.
pub(crate) fn frame_of(
    camera: &crate::matching::project::Camera2,
    width: usize,
    height: usize,
) -> Option<PixelToPhoto> {
    match camera.pixel_to_photo {
        Some(p) => PixelToPhoto::from_centre_origin(p, width, height),
        None => Some(centred_grid(width, height, camera.pixel_mm).into()),
    }
}

/// The ground rectangle (xmin, ymin, xmax, ymax) the image's corners and middle see at `z`;
/// the point that has none, and why, when one fails.
pub fn footprint(s: &dyn Sensor, z: f64) -> Result<[f64; 4], String> {
    let (w, h) = s.image_size();
    let (w, h) = (w as f64, h as f64);
    let mut r = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
    for (name, c, q) in [
        ("top-left corner", 0.0, 0.0),
        ("top-right corner", w, 0.0),
        ("bottom-left corner", 0.0, h),
        ("bottom-right corner", w, h),
        ("centre", 0.5 * w, 0.5 * h),
    ] {
        let g = s.try_image_to_ground(PixelXY::new(c, q), z).map_err(|e| {
            format!("its {name} (pixel {c:.0}, {q:.0}) has no ground point at {z:.0} m: {e}")
        })?;
        r = [r[0].min(g.x), r[1].min(g.y), r[2].max(g.x), r[3].max(g.y)];
    }
    Ok(r)
}

/// "No overlap", with where each photo does see the ground, so that the operator can tell a
/// wrong height from a wrong orientation or a photo of somewhere else.
fn no_overlap(
    photos: &[crate::matching::project::Photo2],
    prints: &[[f64; 4]],
    extent: Option<[f64; 4]>,
    z: f64,
) -> Pipeline2Error {
    let prints = photos
        .iter()
        .zip(prints)
        .map(|(ph, r)| {
            format!(
                "`{}` sees x {:.1} … {:.1}, y {:.1} … {:.1}",
                ph.id, r[0], r[2], r[1], r[3]
            )
        })
        .collect::<Vec<_>>()
        .join("; ");
    let within = extent.map_or(String::new(), |e| {
        format!(
            " within [dem] extent x {:.1} … {:.1}, y {:.1} … {:.1}",
            e[0], e[2], e[1], e[3]
        )
    });
    Pipeline2Error::NoOverlap { z, prints, within }
}

fn overlap(a: [f64; 4], b: [f64; 4]) -> Option<[f64; 4]> {
    let o = [
        a[0].max(b[0]),
        a[1].max(b[1]),
        a[2].min(b[2]),
        a[3].min(b[3]),
    ];
    (o[2] > o[0] && o[3] > o[1]).then_some(o)
}

/// A photo's geometry without its pixels: what the plan needs.
#[derive(Debug, Clone, Copy)]
pub struct PhotoGeometry {
    /// Which photo point each pixel of the whole image shows.
    pub frame: PixelToPhoto,
    pub interior: Interior,
    /// The whole image's size, pixels.
    pub width: usize,
    pub height: usize,
    /// The part of it that was read (the matchers see this part; their sensors are shifted
    /// to it).
    pub window: PixelWindow,
}

impl Photo {
    pub fn geometry(&self) -> PhotoGeometry {
        PhotoGeometry {
            frame: self.frame,
            interior: self.interior,
            width: self.frame.width,
            height: self.frame.height,
            window: self.window,
        }
    }
}

/// One pair to sweep: photos `left` and `right` (indices into the project's photos).
#[derive(Debug, Clone)]
pub struct PlannedPair {
    pub left: usize,
    pub right: usize,
    pub pmfs: PmfSet,
    pub params: PmfDtmParams,
    pub layout: SweepLayout,
}

/// Everything decided before the sweep, from the project and the photos' geometry alone: the
/// same on every machine of a tiled run.
#[derive(Debug, Clone)]
pub struct Plan {
    pub sensors: Vec<PhotoSensor>,
    pub resected: Vec<(String, Resection)>,
    pub corrected: Vec<(String, ControlFit)>,
    /// As [`Oriented::shared_orientation`].
    pub shared_orientation: CrossCovariances,
    pub heights: [f64; 2],
    pub extent: [f64; 4],
    pub pairs: Vec<PlannedPair>,
    pub budget: Budget,
}

impl Plan {
    /// The units of work: every band of every pair's sweep, pair by pair.
    pub fn units(&self) -> usize {
        self.pairs.iter().map(|p| p.layout.bands()).sum()
    }

    /// The bands of each pair that units `u` hold: (pair, bands) in order.
    pub fn bands_of(&self, u: std::ops::Range<usize>) -> Vec<(usize, std::ops::Range<usize>)> {
        let mut out = Vec::new();
        let mut first = 0;
        for (k, pair) in self.pairs.iter().enumerate() {
            let n = pair.layout.bands();
            let (a, b) = (u.start.max(first), u.end.min(first + n));
            if a < b {
                out.push((k, a - first..b - first));
            }
            first += n;
        }
        out
    }
}

/// Each corrected model's line for a report's summary.
pub fn corrected_lines(corrected: &[(String, ControlFit)]) -> Vec<(String, String)> {
    corrected
        .iter()
        .map(|(id, f)| {
            (
                format!("photo {id}"),
                format!(
                    "{} corrected by {} control points: their RMS {:.3} px before, {:.3} px after",
                    f.kind, f.points, f.rms_before_px, f.rms_after_px
                ),
            )
        })
        .collect()
}

/// A control point's measurement on a photo, px: what a given model is corrected to.
pub const CONTROL_SIGMA_PX: f64 = 0.5;

/// A project's photos as sensors, what the matchers share before they differ: each photo's
/// orientation (given or resected), the heights to search, the ground extent of the model and
/// the pairs of photos whose footprints overlap.
#[derive(Debug, Clone)]
pub struct Oriented {
    pub sensors: Vec<PhotoSensor>,
    pub resected: Vec<(String, Resection)>,
    /// Given models (line scanners, RPCs) corrected by their photos' control points.
    pub corrected: Vec<(String, ControlFit)>,
    /// Cov(δpᵢ, δpⱼ) of resected photos i < j that share control points with a stated
    /// ground error ([`crate::geometry::control_covariance`]).
    pub shared_orientation: CrossCovariances,
    pub heights: [f64; 2],
    pub extent: [f64; 4],
    /// Pairs (i, j), i < j, of photos that overlap on the ground at the middle height.
    pub overlapping: Vec<(usize, usize)>,
}

/// The orientations, heights, extent and overlapping pairs of a project.
pub fn orient(p: &Project2, photos: &[PhotoGeometry]) -> Result<Oriented, Pipeline2Error> {
    let obs = p.observations()?;
    let control: Vec<&Observation> = obs.iter().filter(|o| o.kind == Kind::Gcp).collect();
    // Orientation: given, or resected from this photo's control points.
    let mut resected = Vec::new();
    let mut corrected = Vec::new();
    let mut sensors = Vec::new();
    // The resected photos (their index among the sensors) with the control they came from.
    let mut from_control: Vec<(usize, Resected)> = Vec::new();
    for (ph, input) in p.photos.iter().zip(photos) {
        if let Source::Model { model, .. } = &ph.source {
            // A given model is corrected by the control points on its photo, when there are
            // any: the orbit and attitude of a line scanner, the image shift of RPCs.
            let pts: Vec<(PixelXY, GroundM)> = control
                .iter()
                .filter(|o| o.photo == ph.id)
                .filter_map(|o| Some((PixelXY::new(o.col, o.row), o.ground?)))
                .collect();
            let failed = |cause: ControlFitError| {
                Pipeline2Error::Photo {
                id: ph.id.clone(),
                message: format!(
                    "correcting its model by its {} control points: {cause} (remove them from the points file to use the model as given)",
                    pts.len()
                ),
            }
            };
            sensors.push(match model.as_ref() {
                GivenModel::Pushbroom(m) if pts.is_empty() => PhotoSensor::Pushbroom(*m),
                GivenModel::Pushbroom(m) => {
                    let (m, fit) = correct_orbit(m, &pts, CONTROL_SIGMA_PX, OrbitPrior::default())
                        .map_err(failed)?;
                    corrected.push((ph.id.clone(), fit));
                    PhotoSensor::Pushbroom(m)
                }
                GivenModel::Rpc(rpc) => {
                    let s = RpcSensor {
                        rpc: rpc.as_ref().clone(),
                        geo: Geographic::new(p.crs).map_err(|e| Pipeline2Error::Photo {
                            id: ph.id.clone(),
                            message: e.to_string(),
                        })?,
                        width: input.width,
                        height: input.height,
                    };
                    s.check_extent().map_err(|message| Pipeline2Error::Photo {
                        id: ph.id.clone(),
                        message,
                    })?;
                    if pts.is_empty() {
                        PhotoSensor::Rpc(Box::new(s))
                    } else {
                        let (s, fit) =
                            correct_rpc_shift(&s, &pts, CONTROL_SIGMA_PX).map_err(failed)?;
                        corrected.push((ph.id.clone(), fit));
                        PhotoSensor::Rpc(Box::new(s))
                    }
                }
            });
            continue;
        }
        let (exterior, cov) = match ph.exterior {
            Some(e) => (e, None),
            None => {
                let named: Vec<_> = control
                    .iter()
                    .filter(|o| o.photo == ph.id)
                    .filter_map(|o| {
                        Some((
                            o.id.as_str(),
                            input.frame.photo(PixelXY::new(o.col, o.row)),
                            o.ground?,
                        ))
                    })
                    .collect();
                let pts: Vec<_> = named.iter().map(|(_, q, g)| (*q, *g)).collect();
                let r =
                    resect(&input.interior, &pts).map_err(|source| Pipeline2Error::Resection {
                        id: ph.id.clone(),
                        points: pts.len(),
                        cause: source,
                    })?;
                from_control.push((
                    sensors.len(),
                    Resected {
                        interior: input.interior,
                        exterior: r.exterior,
                        points: named,
                    },
                ));
                let e = (r.exterior, Some(r.covariance));
                resected.push((ph.id.clone(), r));
                e
            }
        };
        sensors.push(PhotoSensor::Frame(FrameSensor {
            camera: FrameCamera {
                interior: input.interior,
                exterior,
            },
            frame: input.frame,
            exterior_cov: cov,
        }));
    }
    // Control with a stated ground error: the resected photos share it.
    let mut shared_orientation = CrossCovariances::default();
    if let (Some([sxy, sz]), false) = (p.control_sigma_m, from_control.is_empty()) {
        let (at, resected_photos): (Vec<usize>, Vec<Resected>) = from_control.into_iter().unzip();
        match block_covariance(&resected_photos, sxy, sz) {
            Some(b) => {
                for (k, &i) in at.iter().enumerate() {
                    if let PhotoSensor::Frame(f) = &mut sensors[i] {
                        f.exterior_cov = Some(b.own[k]);
                    }
                }
                shared_orientation = b.cross.renamed(&at);
            }
            None => tracing::warn!(
                "[points] ground_sigma_m: a resected photo has fewer than 4 control points, so its measuring and ground errors cannot be told apart; the orientations' σ takes each photo as independent"
            ),
        }
    }
    // Heights: given, or the control and check points' range with a margin.
    let heights = match p.heights {
        Some(h) => h,
        None => {
            let zs: Vec<f64> = obs
                .iter()
                .filter(|o| o.kind != Kind::Tie)
                .filter_map(|o| o.ground.map(|g| g.z))
                .collect();
            if zs.len() < 2 {
                return Err(Pipeline2Error::Heights(format!(
                    "{}: give [dem] heights = [min, max] (no control or check points to take them from)",
                    p.path.display()
                )));
            }
            let lo = zs.iter().copied().fold(f64::MAX, f64::min);
            let hi = zs.iter().copied().fold(f64::MIN, f64::max);
            let m = (0.2 * (hi - lo)).max(20.0);
            [lo - m, hi + m]
        }
    };
    // Each photo's sensor seen through the window of its image that was read.
    let sensors: Vec<PhotoSensor> = sensors
        .into_iter()
        .zip(photos)
        .map(|(s, g)| s.windowed(g.window))
        .collect();
    let mid = 0.5 * (heights[0] + heights[1]);
    let prints: Vec<[f64; 4]> = sensors
        .iter()
        .zip(&p.photos)
        .map(|(s, ph)| {
            footprint(s as &dyn Sensor, mid).map_err(|m| Pipeline2Error::Photo {
                id: ph.id.clone(),
                message: format!("its footprint on the ground: {m}"),
            })
        })
        .collect::<Result<_, _>>()?;
    let mut overlapping = Vec::new();
    let mut union: Option<[f64; 4]> = None;
    for i in 0..sensors.len() {
        for j in i + 1..sensors.len() {
            // Within the project's extent, when it gives one.
            let o = overlap(prints[i], prints[j])
                .and_then(|o| p.extent.map_or(Some(o), |e| overlap(o, e)));
            if let Some(o) = o {
                overlapping.push((i, j));
                union = Some(match union {
                    None => o,
                    Some(u) => [
                        u[0].min(o[0]),
                        u[1].min(o[1]),
                        u[2].max(o[2]),
                        u[3].max(o[3]),
                    ],
                });
            }
        }
    }
    let extent = match (p.extent, union) {
        (Some(e), _) => e,
        // Where the pairs see the ground at every height (the union of their footprints'
        // overlaps bounds it).
        (None, Some(u)) => {
            let dyns: Vec<&dyn Sensor> = sensors.iter().map(|s| s as &dyn Sensor).collect();
            crate::matching::block::coverage::covered_extent(&dyns, &overlapping, u, heights).unwrap_or_else(|| {
                tracing::warn!(
                    "no ground is seen by two photos at every height tried: the DEM covers the photos' overlap at the middle height"
                );
                u
            })
        }
        (None, None) => return Err(no_overlap(&p.photos, &prints, p.extent, mid)),
    };
    if overlapping.is_empty() {
        return Err(no_overlap(&p.photos, &prints, p.extent, mid));
    }
    Ok(Oriented {
        sensors,
        resected,
        corrected,
        shared_orientation,
        heights,
        extent,
        overlapping,
    })
}

/// The orientations, heights, pairs, mappings and sweep parameters of a project, with each
/// pair's work checked against the budget.
pub fn plan(
    p: &Project2,
    photos: &[PhotoGeometry],
    max_memory_mb: Option<u64>,
) -> Result<Plan, Pipeline2Error> {
    let Oriented {
        sensors,
        resected,
        corrected,
        shared_orientation,
        heights,
        extent,
        overlapping,
    } = orient(p, photos)?;
    let budget = Budget {
        max_memory_mb: max_memory_mb.unwrap_or(p.limits.max_memory_mb),
        max_candidates: p.limits.max_candidates_g * 1e9,
    };
    let m = &p.matching;
    let mut pairs = Vec::new();
    for (i, j) in overlapping {
        let (l, r) = (&sensors[i], &sensors[j]);
        let (li, ri) = (&p.photos[i].id, &p.photos[j].id);
        // A line scanner's (or its RPCs') mappings may take seed 004's extended terms.
        let scanner = |s: &PhotoSensor| s.frame().is_none();
        let set = if scanner(l) || scanner(r) {
            TermSet::Extended
        } else {
            TermSet::Basic
        };
        let grid = m
            .pmf_grid
            .map(|[n, levels]| SampleGrid { n, levels })
            .unwrap_or_default();
        let pmfs = PmfSet::from_sensors_on(l, r, heights, m.order, grid, set).map_err(|e| {
            Pipeline2Error::Mappings {
                left: li.clone(),
                right: ri.clone(),
                message: e.to_string(),
            }
        })?;
        let (w, h) = l.image_size();
        let h_step = m
            .h_step
            .or_else(|| step_for_parallax(&pmfs.left_to_right, w, h, heights, 0.5))
            .unwrap_or(1.0);
        let params = PmfDtmParams {
            sweep: SweepParams {
                h_min: heights[0],
                h_max: heights[1],
                h_step,
                window: m.window,
                threshold: m.threshold,
                subpixel: m.subpixel,
                stride: m.stride,
                ..Default::default()
            },
            regions: RegionParams {
                search_distance: m.search_distance,
                height_threshold: m.height_threshold.unwrap_or(1.5 * h_step),
                population_threshold: m.population_threshold,
            },
            cell_m: p.cell_m,
        };
        let (a, b) = (&photos[i].window, &photos[j].window);
        estimate((a.width, a.height), (b.width, b.height), &params, &budget).map_err(|source| {
            Pipeline2Error::Pair {
                left: li.clone(),
                right: ri.clone(),
                cause: source,
            }
        })?;
        pairs.push(PlannedPair {
            left: i,
            right: j,
            pmfs,
            layout: SweepLayout::new(a.width, a.height, &params.sweep),
            params,
        });
    }
    Ok(Plan {
        sensors,
        resected,
        corrected,
        shared_orientation,
        heights,
        extent,
        pairs,
        budget,
    })
}

/// One pair's swept bands, with the seconds they took.
#[derive(Debug, Clone)]
pub struct PairPart {
    pub pair: usize,
    pub bands: SweptBands,
    pub seconds: f64,
}

/// Sweeps units `units` of the plan (see [`Plan::units`]); `photos[k]` must hold every photo
/// of the pairs these units touch.
pub fn sweep_units(
    p: &Project2,
    plan: &Plan,
    units: std::ops::Range<usize>,
    photos: &[Option<&Photo>],
    progress: &dyn crate::matching::progress::Progress,
) -> Result<Vec<PairPart>, Pipeline2Error> {
    let mut parts = Vec::new();
    for (k, bands) in plan.bands_of(units) {
        let pair = &plan.pairs[k];
        let (li, ri) = (&p.photos[pair.left].id, &p.photos[pair.right].id);
        let get = |i: usize| {
            photos
                .get(i)
                .copied()
                .flatten()
                .ok_or_else(|| Pipeline2Error::Photo {
                    id: p.photos[i].id.clone(),
                    message: "not loaded for the sweep (a defect of the caller)".into(),
                })
        };
        let (l, r) = (get(pair.left)?, get(pair.right)?);
        let t = std::time::Instant::now();
        let swept = sweep_bands(
            &l.image,
            &r.image,
            &pair.pmfs.left_to_right,
            &pair.params.sweep,
            bands,
            &crate::matching::progress::Prefixed {
                inner: progress,
                prefix: format!("photos {li} × {ri}: "),
            },
        );
        parts.push(PairPart {
            pair: k,
            bands: swept,
            seconds: t.elapsed().as_secs_f64(),
        });
    }
    Ok(parts)
}

/// Runs a format-2 project on its loaded photos into `out`.
pub fn run(
    p: &Project2,
    photos: &[Photo],
    out: &Path,
    max_memory_mb: Option<u64>,
    progress: &dyn crate::matching::progress::Progress,
) -> Result<Report2, Pipeline2Error> {
    crate::matching::methods::sweep::scanned_pair::check_out_dir(out)?;
    let geometry: Vec<PhotoGeometry> = photos.iter().map(Photo::geometry).collect();
    let plan = plan(p, &geometry, max_memory_mb)?;
    let refs: Vec<Option<&Photo>> = photos.iter().map(Some).collect();
    let parts = sweep_units(p, &plan, 0..plan.units(), &refs, progress)?;
    finish(p, &plan, parts, photos, out)
}

/// The run after the sweep, from its parts (of one machine or of all tiles): each pair's wrong
/// heights removed and its points, the merged grid, the variance factor, the comparisons and
/// the outputs in `out`.
pub fn finish(
    p: &Project2,
    plan: &Plan,
    parts: Vec<PairPart>,
    photos: &[Photo],
    out: &Path,
) -> Result<Report2, Pipeline2Error> {
    crate::matching::methods::sweep::scanned_pair::check_out_dir(out)?;
    let obs = p.observations()?;
    let reference_dem = ModelFigures::read_reference(p)?;
    let Plan {
        sensors,
        resected,
        corrected,
        heights,
        extent,
        budget,
        ..
    } = plan.clone();
    let mut by_pair: Vec<(Vec<SweptBands>, f64)> = vec![(Vec::new(), 0.0); plan.pairs.len()];
    for part in parts {
        let slot = by_pair.get_mut(part.pair).ok_or_else(|| {
            Pipeline2Error::Grid(format!(
                "a part of pair {} of {}",
                part.pair + 1,
                plan.pairs.len()
            ))
        })?;
        slot.0.push(part.bands);
        slot.1 += part.seconds;
    }
    let mut per_pair = Vec::new();
    let mut reports = Vec::new();
    for (pair, (bands, secs)) in plan.pairs.iter().zip(by_pair) {
        let (li, ri) = (&p.photos[pair.left].id, &p.photos[pair.right].id);
        let hm = HeightMap::from_bands(pair.layout, bands).map_err(|e| {
            Pipeline2Error::Grid(format!("photos {li} × {ri}: the sweep's parts: {e}"))
        })?;
        let d = pmf_dtm_from_heights(hm, &pair.pmfs, &pair.params, &budget, None, None, secs)
            .map_err(|source| Pipeline2Error::Pair {
                left: li.clone(),
                right: ri.clone(),
                cause: source,
            })?;
        let h_step = pair.params.sweep.h_step;
        tracing::info!(
            pair = %format!("{li} × {ri}"),
            h_step_m = h_step,
            matched_percent = d.report.matched_percent,
            points = d.points.len(),
            "pair swept"
        );
        reports.push(PairReport {
            left: li.clone(),
            right: ri.clone(),
            h_step_m: h_step,
            pmf: pair.pmfs.report.clone(),
            dtm: d.report,
            points: d.points.len(),
        });
        per_pair.push(d.points);
    }
    let mut grid = ElevationGrid::covering(extent, p.cell_m, budget.max_memory_mb)
        .map_err(|e| Pipeline2Error::Grid(e.to_string()))?;
    // How the pairs agree, for the report (not applied: see `Report2::variance_factor`).
    let refs: Vec<&[MatchedPoint]> = per_pair.iter().map(|v| v.as_slice()).collect();
    let factor = variance_factor(&grid, &refs);
    tracing::info!(?factor, "variance factor from the pairs");
    // The window on the ground, from each pair's reference photo at its centre and the middle
    // height, weighted by the points the pair gave.
    let (mut ws, mut wn) = (0.0, 0.0);
    for (pair, pts) in plan.pairs.iter().zip(&per_pair) {
        let s = &plan.sensors[pair.left];
        let (w, h) = s.image_size();
        let centre = PixelXY::new(0.5 * w as f64, 0.5 * h as f64);
        if let Some(g) = s.ground_pixel_m(centre, 0.5 * (heights[0] + heights[1])) {
            ws += pts.len() as f64 * g * pair.params.sweep.window as f64;
            wn += pts.len() as f64;
        }
    }
    let all: Vec<MatchedPoint> = per_pair.into_iter().flatten().collect();
    let pts: Vec<GroundM> = all.iter().map(|p| p.ground).collect();
    grid.fill_median(&pts);
    let mut quality = grid.quality(&all);
    let averaging = remove_window_averaging(
        &mut grid,
        &mut quality,
        Kernel::cell_mean(ws / wn.max(1.0), p.cell_m),
    );
    tracing::info!(?averaging, "window averaging removed");
    let orientation_sigma_m = add_orientation_sigma(&grid, &mut quality.sigma_m, plan);
    let (model, reference) = ModelFigures::check(p, reference_dem, &obs, grid, &quality.sigma_m);
    let write = |source| PipelineError::Write {
        dir: out.to_path_buf(),
        cause: source,
    };
    let report = Report2 {
        project: p.path.clone(),
        crs: p.crs,
        resected,
        corrected,
        heights_m: heights,
        extent,
        pairs: reports,
        points: all.len(),
        variance_factor: factor,
        averaging,
        orientation_sigma_m,
        model,
    };
    write_model(
        out,
        &report.model.grid,
        &all,
        &quality,
        photos,
        &sensors,
        reference.as_ref().zip(report.model.comparison.as_ref()),
        p.crs,
        &report,
        &report.summary(),
    )
    .map_err(write)?;
    Ok(report)
}

/// A format-2 run's model files ([`crate::matching::methods::sweep::scanned_pair::write_outputs`]), the orthophoto from
/// `photos` through their `sensors`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn write_model(
    out: &Path,
    grid: &ElevationGrid,
    points: &[MatchedPoint],
    quality: &crate::matching::grid::NodeQuality,
    photos: &[Photo],
    sensors: &[PhotoSensor],
    reference: Option<(&ElevationGrid, &Comparison)>,
    crs: Crs,
    report: &impl Serialize,
    summary: &[(String, String)],
) -> std::io::Result<()> {
    let projections: Vec<_> = sensors
        .iter()
        .map(|s| move |g: GroundM| s.ground_to_image(g))
        .collect();
    let views: Vec<View> = photos
        .iter()
        .zip(&projections)
        .map(|(ph, f)| View {
            image: &ph.image,
            project: f,
        })
        .collect();
    crate::matching::methods::sweep::scanned_pair::write_outputs(
        out, grid, points, quality, &views, reference, crs, report, summary,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vertical(x0: f64, z0: f64) -> FrameSensor {
        vertical_sensor(GroundM::new(x0, 0.0, z0), 153.0, 2000, 0.1)
    }

    /// Two vertical photos with base B at height Z₀: x-parallax p = f·B/(Z₀ − h) (in pixels of
    /// size s: /s), so dp/dh = f·B/(s·(Z₀ − h)²), largest at the top of the range; the step
    /// from the mapping functions is half a pixel of it there, in metres.
    #[test]
    fn the_step_is_half_a_pixel_of_parallax() {
        let (b, z0, heights) = (2500.0, 6900.0, [300.0, 700.0]);
        let (l, r) = (vertical(0.0, z0), vertical(b, z0));
        let set = PmfSet::from_sensors(&l, &r, heights, 3).unwrap();
        let got = step_for_parallax(&set.left_to_right, 2000, 2000, heights, 0.5).unwrap();
        let top = z0 - heights[1];
        let want = 0.5 / (153.0 * b / (0.1 * top * top));
        assert!((got - want).abs() < 0.01 * want, "{got} m vs {want} m");
        // A pair with no base has no parallax: its mappings cannot be fitted (nothing varies
        // with the height), or give no step.
        if let Ok(none) = PmfSet::from_sensors(&l, &vertical(0.0, z0), heights, 3) {
            let step = step_for_parallax(&none.left_to_right, 2000, 2000, heights, 0.5);
            assert_eq!(step, None);
        }
    }
}
