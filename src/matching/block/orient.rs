//! A project's photos as sensors, what every matcher starts from: each photo's orientation
//! (given, corrected by its control points, or resected from them, with the covariances
//! shared control gives), the heights to search, the model's ground extent and the pairs of
//! photos whose footprints overlap.

use crate::coords::{GroundM, PixelXY};
use crate::geometry::control_covariance::{block_covariance, CrossCovariances, Resected};
use crate::geometry::control_fit::{
    correct_orbit, correct_rpc_shift, ControlFit, ControlFitError, OrbitPrior,
};
use crate::geometry::{
    resect, FrameCamera, FrameSensor, Geographic, Interior, PhotoSensor, Resection, RpcSensor,
    Sensor,
};
use crate::matching::block::photo::{centred_grid, PhotoGeometry};
use crate::matching::error::MatchingError;
use crate::matching::project::GivenModel;
use crate::matching::project::{Kind, Observation, Project, Source};

/// A vertical photo (ω = φ = κ = 0, principal point at the centre) from `centre`, a square
/// image of `side` pixels of `pixel_mm`: the closed-form case of the matchers' tests.
pub fn vertical_sensor(centre: GroundM, focal_mm: f64, side: usize, pixel_mm: f64) -> FrameSensor {
    FrameSensor {
        camera: FrameCamera {
            interior: Interior {
                focal_mm,
                principal_point: crate::coords::PhotoMm::new(0.0, 0.0),
                lens: crate::geometry::Lens::NONE,
            },
            exterior: crate::geometry::Exterior::from_degrees(0.0, 0.0, 0.0, centre),
        },
        frame: centred_grid(side, side, pixel_mm).into(),
        exterior_cov: None,
        radial: Default::default(),
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
    photos: &[crate::matching::project::PhotoEntry],
    prints: &[[f64; 4]],
    extent: Option<[f64; 4]>,
    z: f64,
) -> MatchingError {
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
    MatchingError::NoOverlap { z, prints, within }
}

/// The overlap of two ground rectangles (xmin, ymin, xmax, ymax), if they overlap.
pub fn overlap(a: [f64; 4], b: [f64; 4]) -> Option<[f64; 4]> {
    let o = [
        a[0].max(b[0]),
        a[1].max(b[1]),
        a[2].min(b[2]),
        a[3].min(b[3]),
    ];
    (o[2] > o[0] && o[3] > o[1]).then_some(o)
}

/// The covariance of independent parameters with σ `[position m; angles deg]`, in the order
/// ω, φ, κ (rad), X₀, Y₀, Z₀ (m).
fn diagonal(sigma: [[f64; 3]; 2]) -> [[f64; 6]; 6] {
    let [pos, ang] = sigma;
    let s = [
        ang[0].to_radians(),
        ang[1].to_radians(),
        ang[2].to_radians(),
        pos[0],
        pos[1],
        pos[2],
    ];
    std::array::from_fn(|r| std::array::from_fn(|c| if r == c { s[r] * s[r] } else { 0.0 }))
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
    /// The points file's observations (read once, here).
    pub observations: Vec<Observation>,
}

/// The orientations, heights, extent and overlapping pairs of a project.
pub fn orient(p: &Project, photos: &[PhotoGeometry]) -> Result<Oriented, MatchingError> {
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
                MatchingError::Photo {
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
                        geo: Geographic::new(p.crs).map_err(|e| MatchingError::Photo {
                            id: ph.id.clone(),
                            message: e.to_string(),
                        })?,
                        width: input.width,
                        height: input.height,
                    };
                    s.check_extent().map_err(|message| MatchingError::Photo {
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
            // An oriented photo's σ (as `rig orient` wrote it), each parameter independent;
            // the block's covariance file, read below, replaces it.
            Some(e) => (e, ph.sigma.map(diagonal)),
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
                    resect(&input.interior, &pts).map_err(|source| MatchingError::Resection {
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
            radial: p.radial,
        }));
    }
    // Control with a stated ground error: the resected photos share it.
    let mut shared_orientation = CrossCovariances::default();
    // A block's orientations, correlated as its adjustment found them.
    if let Some(path) = &p.orientation_covariance {
        let ids: Vec<String> = p.photos.iter().map(|ph| ph.id.clone()).collect();
        let c =
            crate::orientation::covariance::read(path, &ids).map_err(MatchingError::Covariance)?;
        for (k, own) in c.own.iter().enumerate() {
            if let (Some(own), PhotoSensor::Frame(f)) = (own, &mut sensors[k]) {
                f.exterior_cov = Some(*own);
            }
        }
        shared_orientation = c.cross;
    }
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
                return Err(MatchingError::Heights(format!(
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
    // Each photo's sensor seen through the view of its image that was read.
    let sensors: Vec<PhotoSensor> = sensors
        .into_iter()
        .zip(photos)
        .map(|(s, g)| s.viewed(g.view))
        .collect();
    let mid = 0.5 * (heights[0] + heights[1]);
    let prints: Vec<[f64; 4]> = sensors
        .iter()
        .zip(&p.photos)
        .map(|(s, ph)| {
            footprint(s as &dyn Sensor, mid).map_err(|m| MatchingError::Photo {
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
        observations: obs,
    })
}
