//! A project's photos and points as a block to adjust: each frame photo's interior
//! orientation and pixel → photo relation, its approximation and prior, the points file's
//! control (`gcp`, weighted by `[points] ground_sigma_m`), tie and check (`cp`, never
//! adjusted) points, every ray in photo millimetres with its σ.

use super::bundle::{Block, BlockPhoto, BlockPoint, Prior, Ray, Role, SelfCalibration};
use crate::coords::PixelXY;
use crate::matching::block::photo::PhotoGeometry;
use crate::matching::project::{Kind, Observation, Project, Source};
use std::collections::BTreeMap;

#[derive(Debug, Clone, Copy)]
pub struct OrientOptions {
    /// σ of a measured ray (the points file's), px.
    pub image_sigma_px: f64,
    /// σ of a control point's ground (X and Y, Z; m) where `[points] ground_sigma_m` is silent.
    pub control_sigma_m: [f64; 2],
}

impl Default for OrientOptions {
    fn default() -> Self {
        OrientOptions {
            image_sigma_px: 0.5,
            control_sigma_m: [0.01, 0.01],
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum OrientError {
    #[error("photo `{id}`: a block orientation takes frame photos (image and camera, or the rig's scans); this one has its own sensor model (pushbroom or RPC), which is its orientation")]
    NotFrame { id: String },
    #[error("point `{id}` in photo `{photo}` at pixel ({col:.1}, {row:.1}): outside its image of {width} × {height} px")]
    Outside {
        id: String,
        photo: String,
        col: f64,
        row: f64,
        width: usize,
        height: usize,
    },
    #[error("point `{id}`: {what}")]
    Point { id: String, what: String },
    #[error("photo `{id}`: [orientation] self_calibration takes photos with a [camera.NAME]; this is a rig scan, whose interior is its camera certificate's: orient without self_calibration, or give the scan's image with a [camera] table")]
    ScanCalibration { id: String },
    #[error(transparent)]
    Bundle(#[from] super::bundle::BundleError),
    #[error(transparent)]
    Matching(#[from] crate::matching::error::MatchingError),
    #[error(transparent)]
    Project(#[from] crate::matching::project::ProjectError),
    #[error("writing the orientation: {0}")]
    Write(String),
}

/// The pixel's size, mm (the square root of the pixel → photo affine's determinant).
pub fn pixel_mm(g: &PhotoGeometry) -> f64 {
    let p = g.frame.params;
    (p[1] * p[5] - p[2] * p[4]).abs().sqrt()
}

/// The block of `p`'s photos (`geometry` in the same order) and the observations `obs`.
pub fn block_of(
    p: &Project,
    geometry: &[PhotoGeometry],
    obs: &[Observation],
    o: OrientOptions,
) -> Result<Block, OrientError> {
    let mut photos = Vec::with_capacity(p.photos.len());
    for (ph, g) in p.photos.iter().zip(geometry) {
        if let Source::Model { .. } = ph.source {
            return Err(OrientError::NotFrame { id: ph.id.clone() });
        }
        photos.push(BlockPhoto {
            id: ph.id.clone(),
            interior: g.interior,
            pixel_mm: pixel_mm(g),
            approx: ph.exterior,
            prior: ph.approximate.map(|[sp, sa]| Prior {
                position_sigma_m: sp,
                angles_sigma_rad: sa.to_radians(),
            }),
        });
    }
    let [sxy, sz] = p.control_sigma_m.unwrap_or(o.control_sigma_m);
    // Ground σ of 0 (exact control) is taken as a millimetre: a weight, not a constraint.
    let (sxy, sz) = (sxy.max(1e-3), sz.max(1e-3));
    let mut points: Vec<BlockPoint> = Vec::new();
    let mut index: BTreeMap<&str, usize> = BTreeMap::new();
    let mut rays = Vec::with_capacity(obs.len());
    for ob in obs {
        let k = match index.get(ob.id.as_str()) {
            Some(&k) => {
                let same = match (points[k].role, ob.kind, ob.ground) {
                    (Role::Tie, Kind::Tie, _) => true,
                    (Role::Control { ground, .. }, Kind::Gcp, Some(g))
                    | (Role::Check { ground }, Kind::Cp, Some(g)) => {
                        (ground.x - g.x).abs() < 1e-6
                            && (ground.y - g.y).abs() < 1e-6
                            && (ground.z - g.z).abs() < 1e-6
                    }
                    _ => false,
                };
                if !same {
                    return Err(OrientError::Point {
                        id: ob.id.clone(),
                        what: "its lines disagree on its kind or ground coordinates (each line of a point must give the same kind, x, y and z)".into(),
                    });
                }
                k
            }
            None => {
                let role = match (ob.kind, ob.ground) {
                    (Kind::Tie, _) => Role::Tie,
                    (Kind::Gcp, Some(ground)) => Role::Control {
                        ground,
                        sigma_m: [sxy, sxy, sz],
                    },
                    (Kind::Cp, Some(ground)) => Role::Check { ground },
                    _ => {
                        return Err(OrientError::Point {
                            id: ob.id.clone(),
                            what: "a gcp or cp line needs x, y and z".into(),
                        })
                    }
                };
                points.push(BlockPoint {
                    id: ob.id.clone(),
                    role,
                });
                index.insert(&ob.id, points.len() - 1);
                points.len() - 1
            }
        };
        let i = p
            .photos
            .iter()
            .position(|ph| ph.id == ob.photo)
            .expect("the points file names only the project's photos");
        let g = &geometry[i];
        if !(0.0..=g.width as f64).contains(&ob.col) || !(0.0..=g.height as f64).contains(&ob.row) {
            return Err(OrientError::Outside {
                id: ob.id.clone(),
                photo: ob.photo.clone(),
                col: ob.col - 0.5,
                row: ob.row - 0.5,
                width: g.width,
                height: g.height,
            });
        }
        rays.push(Ray {
            point: k,
            photo: i,
            xy: g.frame.photo(PixelXY::new(ob.col, ob.row)),
            sigma_mm: o.image_sigma_px * photos[i].pixel_mm,
            group: 0,
        });
    }
    Ok(Block {
        calibrate: self_calibration(p, &photos)?,
        photos,
        points,
        rays,
        radial: p.radial,
    })
}

/// The cameras to calibrate with the block (`[orientation] self_calibration`): the photos of
/// each `[camera.NAME]` share its interior. A scan's interior is its camera certificate's,
/// one per scan: it is refused.
fn self_calibration(
    p: &Project,
    photos: &[BlockPhoto],
) -> Result<Vec<SelfCalibration>, OrientError> {
    if !p.self_calibration.iter().any(|f| *f) {
        return Ok(Vec::new());
    }
    let mut out: Vec<SelfCalibration> = Vec::new();
    for (i, ph) in p.photos.iter().enumerate() {
        let Source::Image { camera_name, .. } = &ph.source else {
            return Err(OrientError::ScanCalibration {
                id: photos[i].id.clone(),
            });
        };
        match out.iter_mut().find(|c| &c.camera == camera_name) {
            Some(c) => c.photos.push(i),
            None => out.push(SelfCalibration {
                camera: camera_name.clone(),
                photos: vec![i],
                free: p.self_calibration,
            }),
        }
    }
    Ok(out)
}
