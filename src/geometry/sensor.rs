//! One sensor abstraction for every model that maps ground to image and back (as GDAL's
//! transformers have one for rigorous models and RPCs): the frame camera now, a pushbroom
//! scanner or an RPC later. Mapping functions are fitted from any `Sensor` (seed 004 §4), and
//! the matchers ask nothing else of a photo's geometry.
//!
//! Image coordinates are continuous pixels of the sensor's own image, `PixelXY` (column,
//! row), as everywhere in the core; ground coordinates are `GroundM` in the project's CRS.

use super::{FrameCamera, PixelToPhoto};
use crate::coords::{GroundM, PixelView, PixelXY};

/// Why a sensor could not map a point, so that a failure reaches the user with its cause (and
/// the caller names the photo and the point) instead of a bare "not seen".
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ProjectionError {
    #[error("the point is behind the sensor")]
    Behind,
    #[error("the ray never reaches height {z:.1} m")]
    HeightNotReached { z: f64 },
    #[error("{0}")]
    Model(&'static str),
    #[error(
        "the iteration did not converge in {iterations} steps (its last step {last_px:.1e} px)"
    )]
    NoConvergence { iterations: usize, last_px: f64 },
    #[error("the ground point has no WGS 84 longitude and latitude in the project's CRS")]
    Crs,
}

pub trait Sensor {
    /// Width and height of the image, pixels.
    fn image_size(&self) -> (usize, usize);

    /// Where ground point `g` appears, or why it cannot be said.
    fn try_ground_to_image(&self, g: GroundM) -> Result<PixelXY, ProjectionError>;

    /// The ground point at height `z` seen at pixel `q`, or why it cannot be found.
    fn try_image_to_ground(&self, q: PixelXY, z: f64) -> Result<GroundM, ProjectionError>;

    /// [`Sensor::try_ground_to_image`] where only whether matters (the matchers' inner loops).
    fn ground_to_image(&self, g: GroundM) -> Option<PixelXY> {
        self.try_ground_to_image(g).ok()
    }

    /// [`Sensor::try_image_to_ground`] where only whether matters.
    fn image_to_ground(&self, q: PixelXY, z: f64) -> Option<GroundM> {
        self.try_image_to_ground(q, z).ok()
    }

    /// The ground distance one pixel step along the rows covers at pixel `q` and height `z`,
    /// m (the ground pixel there).
    fn ground_pixel_m(&self, q: PixelXY, z: f64) -> Option<f64> {
        let a = self.image_to_ground(q, z)?;
        let b = self.image_to_ground(PixelXY::new(q.col + 1.0, q.row), z)?;
        let d = (a.x - b.x).hypot(a.y - b.y);
        (d.is_finite() && d > 0.0).then_some(d)
    }

    /// ∂(col, row)/∂(X, Y, Z) at `g`, pixels per metre: by default central differences of
    /// [`Sensor::ground_to_image`] over ±0.5 m (a model with closed forms overrides it).
    fn partials(&self, g: GroundM) -> Option<[[f64; 3]; 2]> {
        let mut d = [[0.0; 3]; 2];
        for k in 0..3 {
            [d[0][k], d[1][k]] = central_difference(self, g, k)?;
        }
        Some(d)
    }

    /// ∂(col, row)/∂Z at `g`, pixels per metre: the last column of [`Sensor::partials`], the
    /// same numbers, for a caller that needs only it (object-space matching follows heights
    /// alone): by default its two central differences, a third of the work. A model that
    /// overrides `partials` overrides this too.
    fn height_partials(&self, g: GroundM) -> Option<[f64; 2]> {
        central_difference(self, g, 2)
    }

    /// The covariance (px²) of where the sensor puts `g`, from its orientation's own
    /// uncertainty (a resection's, an RPC's stated error); `None` where the orientation is
    /// taken as exact.
    fn pointing_covariance(&self, _g: GroundM) -> Option<[[f64; 2]; 2]> {
        None
    }
}

/// ∂(col, row)/∂(ground coordinate k) at `g` (k = 0, 1, 2: X, Y, Z), pixels per metre: the
/// central difference of [`Sensor::ground_to_image`] over ±0.5 m, the default of
/// [`Sensor::partials`] and [`Sensor::height_partials`].
fn central_difference<S: Sensor + ?Sized>(s: &S, g: GroundM, k: usize) -> Option<[f64; 2]> {
    const H: f64 = 0.5;
    let at = |d: f64| {
        let mut p = [g.x, g.y, g.z];
        p[k] += d;
        s.ground_to_image(GroundM::new(p[0], p[1], p[2]))
    };
    let (a, b) = (at(H)?, at(-H)?);
    Some([(a.col - b.col) / (2.0 * H), (a.row - b.row) / (2.0 * H)])
}

/// A frame photo as a sensor: its camera (collinearity) and which photo point each pixel of
/// its image shows.
#[derive(Debug, Clone, Copy)]
pub struct FrameSensor {
    pub camera: FrameCamera,
    pub frame: PixelToPhoto,
    /// Covariance of the exterior orientation's ω, φ, κ (rad) and X0, Y0, Z0 (m) when it
    /// was estimated (a resection's); `None` when given as exact.
    pub exterior_cov: Option<[[f64; 6]; 6]>,
    /// Refraction and the Earth's curvature, where the project turns them on
    /// ([`super::radial`]): the photo shows collinearity's point displaced along its radius.
    pub radial: super::Radial,
}

impl Sensor for FrameSensor {
    fn image_size(&self) -> (usize, usize) {
        (self.frame.width, self.frame.height)
    }

    fn try_ground_to_image(&self, g: GroundM) -> Result<PixelXY, ProjectionError> {
        let at = self.seen(g.z);
        let q = self
            .camera
            .project(g)
            .map(|p| self.frame.pixel(self.radial.distort(p, &at)))
            .ok_or(ProjectionError::Behind)?;
        if q.col.is_finite() && q.row.is_finite() {
            Ok(q)
        } else {
            Err(ProjectionError::Model(
                "the pixel → photo affine is singular",
            ))
        }
    }

    fn try_image_to_ground(&self, q: PixelXY, z: f64) -> Result<GroundM, ProjectionError> {
        let p = self.radial.undistort(self.frame.photo(q), &self.seen(z));
        let g = self.camera.at_height(p, z);
        if [g.x, g.y].iter().all(|v| v.is_finite()) {
            Ok(g)
        } else {
            Err(ProjectionError::HeightNotReached { z })
        }
    }

    /// J·Σ·Jᵀ with J = [`FrameSensor::exterior_partials`].
    fn pointing_covariance(&self, g: GroundM) -> Option<[[f64; 2]; 2]> {
        let cov = self.exterior_cov?;
        Some(propagate(&self.exterior_partials(g)?, &cov))
    }
}

impl FrameSensor {
    /// How this camera sees ground at height `ground_m` (what its radial displacements take).
    fn seen(&self, ground_m: f64) -> super::radial::Seen {
        super::radial::Seen::of(
            &self.camera.interior,
            self.camera.exterior.centre.z,
            ground_m,
        )
    }

    /// ∂(col, row)/∂(ω, φ, κ, X0, Y0, Z0) at `g`, px per rad and per m, by central
    /// differences over [`super::Exterior::STEPS`].
    pub fn exterior_partials(&self, g: GroundM) -> Option<[[f64; 6]; 2]> {
        let mut j = [[0.0; 6]; 2];
        for (k, step) in super::Exterior::STEPS.iter().enumerate() {
            let at = |s: f64| {
                let cam = FrameCamera {
                    interior: self.camera.interior,
                    exterior: self.camera.exterior.nudged(k, s),
                };
                cam.project(g).map(|p| self.frame.pixel(p))
            };
            let (a, b) = (at(*step)?, at(-*step)?);
            j[0][k] = (a.col - b.col) / (2.0 * step);
            j[1][k] = (a.row - b.row) / (2.0 * step);
        }
        Some(j)
    }
}

/// J·Σ·Jᵀ: the covariance `cov` of N parameters carried to a pixel's column and row through
/// their partials `j` (px per parameter).
pub fn propagate<const N: usize>(j: &[[f64; N]; 2], cov: &[[f64; N]; N]) -> [[f64; 2]; 2] {
    propagate_between(j, cov, j)
}

/// Jₐ·Σₐᵦ·Jᵦᵀ: the covariance of two pixels (rows a's column and row) whose N parameters
/// each covary as `cov` (rows a's parameters, columns b's), through their partials.
pub fn propagate_between<const N: usize>(
    ja: &[[f64; N]; 2],
    cov: &[[f64; N]; N],
    jb: &[[f64; N]; 2],
) -> [[f64; 2]; 2] {
    let mut c = [[0.0; 2]; 2];
    for (r, cr) in c.iter_mut().enumerate() {
        for (s, v) in cr.iter_mut().enumerate() {
            for a in 0..N {
                for b in 0..N {
                    *v += ja[r][a] * cov[a][b] * jb[s][b];
                }
            }
        }
    }
    c
}

/// Any photo's sensor, as a project's photos come: a frame camera, a line scanner's
/// rigorous model, or RPCs; or one of those seen through a window of its image (a large
/// image of which only the part that sees the project's area was read).
// A project holds a few of them, made once: their sizes do not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
pub enum PhotoSensor {
    Frame(FrameSensor),
    Pushbroom(super::Pushbroom),
    Rpc(Box<super::RpcSensor>),
    Window(Box<Windowed>),
}

impl PhotoSensor {
    fn inner(&self) -> &(dyn Sensor + Sync) {
        match self {
            PhotoSensor::Frame(s) => s,
            PhotoSensor::Pushbroom(s) => s,
            PhotoSensor::Rpc(s) => s.as_ref(),
            PhotoSensor::Window(s) => s.as_ref(),
        }
    }

    /// The frame camera, where the photo is one (through a window or not).
    pub fn frame(&self) -> Option<&FrameSensor> {
        match self {
            PhotoSensor::Frame(s) => Some(s),
            PhotoSensor::Window(w) => w.sensor.frame(),
            _ => None,
        }
    }

    /// How many of its image's pixels a pixel of this sensor spans a side (a view read at a
    /// pyramid level: 2ᴸ; else 1): what converts [`FrameSensor::exterior_partials`], in the
    /// image's pixels, to this sensor's.
    pub fn pixel_factor(&self) -> f64 {
        match self {
            PhotoSensor::Window(w) => w.view.scale(),
            _ => 1.0,
        }
    }

    /// The sensor as seen through `view` of its image (itself for the whole image as it is).
    pub fn viewed(self, view: PixelView) -> PhotoSensor {
        let (w, h) = self.image_size();
        if view.is_whole(w, h) {
            return self;
        }
        PhotoSensor::Window(Box::new(Windowed { sensor: self, view }))
    }
}

/// A sensor through a view of its image ([`PixelView`]): the view's point (x, y) is the
/// image's (col0 + f·x, row0 + f·y), so its pixels are f times larger: the partials divide
/// by f, the pointing covariance by f².
#[derive(Debug, Clone)]
pub struct Windowed {
    pub sensor: PhotoSensor,
    pub view: PixelView,
}

impl Sensor for Windowed {
    fn image_size(&self) -> (usize, usize) {
        self.view.size()
    }

    fn try_ground_to_image(&self, g: GroundM) -> Result<PixelXY, ProjectionError> {
        let q = self.sensor.try_ground_to_image(g)?;
        let (x, y) = self.view.to_read(q.col, q.row);
        Ok(PixelXY::new(x, y))
    }

    fn try_image_to_ground(&self, q: PixelXY, z: f64) -> Result<GroundM, ProjectionError> {
        let (x, y) = self.view.to_image(q.col, q.row);
        self.sensor.try_image_to_ground(PixelXY::new(x, y), z)
    }

    fn partials(&self, g: GroundM) -> Option<[[f64; 3]; 2]> {
        let f = self.view.scale();
        self.sensor
            .partials(g)
            .map(|d| d.map(|row| row.map(|v| v / f)))
    }

    fn height_partials(&self, g: GroundM) -> Option<[f64; 2]> {
        let f = self.view.scale();
        self.sensor.height_partials(g).map(|d| d.map(|v| v / f))
    }

    fn pointing_covariance(&self, g: GroundM) -> Option<[[f64; 2]; 2]> {
        let f2 = self.view.scale() * self.view.scale();
        self.sensor
            .pointing_covariance(g)
            .map(|c| c.map(|row| row.map(|v| v / f2)))
    }
}

impl Sensor for PhotoSensor {
    fn image_size(&self) -> (usize, usize) {
        self.inner().image_size()
    }

    fn try_ground_to_image(&self, g: GroundM) -> Result<PixelXY, ProjectionError> {
        self.inner().try_ground_to_image(g)
    }

    fn try_image_to_ground(&self, q: PixelXY, z: f64) -> Result<GroundM, ProjectionError> {
        self.inner().try_image_to_ground(q, z)
    }

    fn ground_to_image(&self, g: GroundM) -> Option<PixelXY> {
        self.inner().ground_to_image(g)
    }

    fn image_to_ground(&self, q: PixelXY, z: f64) -> Option<GroundM> {
        self.inner().image_to_ground(q, z)
    }

    fn partials(&self, g: GroundM) -> Option<[[f64; 3]; 2]> {
        self.inner().partials(g)
    }

    fn height_partials(&self, g: GroundM) -> Option<[f64; 2]> {
        self.inner().height_partials(g)
    }

    fn pointing_covariance(&self, g: GroundM) -> Option<[[f64; 2]; 2]> {
        self.inner().pointing_covariance(g)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::coords::PhotoMm;
    use crate::coords::PixelWindow;
    use crate::geometry::{Exterior, Interior};

    /// A vertical photo (ω = φ = κ = 0) of focal length f from (0, 0, Z0): x = f·X/(Z0 − Z),
    /// y = f·Y/(Z0 − Z) in mm, so ∂x/∂X = f/(Z0 − Z) and ∂x/∂Z = f·X/(Z0 − Z)², in pixels
    /// divided by the grid's step (rows run against y).
    #[test]
    fn a_vertical_photo_has_the_closed_form_partials_and_round_trips() {
        let (f, z0, step) = (153.0, 6500.0, 0.025);
        let s = FrameSensor {
            camera: FrameCamera {
                interior: Interior {
                    focal_mm: f,
                    principal_point: PhotoMm::new(0.0, 0.0),
                    lens: crate::geometry::Lens::NONE,
                },
                exterior: Exterior::from_degrees(0.0, 0.0, 0.0, GroundM::new(0.0, 0.0, z0)),
            },
            frame: crate::geometry::PhotoGrid::covering([-10.0, -10.0, 10.0, 10.0], step).into(),
            exterior_cov: None,
            radial: Default::default(),
        };
        let g = GroundM::new(300.0, -200.0, 400.0);
        let d = s.partials(g).unwrap();
        let h = z0 - g.z;
        let want = [
            [f / h / step, 0.0, f * g.x / (h * h) / step],
            [0.0, -f / h / step, -f * g.y / (h * h) / step],
        ];
        for r in 0..2 {
            for c in 0..3 {
                assert!((d[r][c] - want[r][c]).abs() < 1e-6, "{d:?} vs {want:?}");
            }
        }
        assert_eq!(s.height_partials(g), Some([d[0][2], d[1][2]]));
        let q = s.ground_to_image(g).unwrap();
        let back = s.image_to_ground(q, g.z).unwrap();
        assert!((back.x - g.x).abs() < 1e-6 && (back.y - g.y).abs() < 1e-6);
        // Above the camera nothing is seen.
        assert!(s
            .ground_to_image(GroundM::new(0.0, 0.0, z0 + 10.0))
            .is_none());
    }

    /// A sensor through a view of its image sees at view point q what the whole image shows at
    /// (col0, row0) + f·q, both ways; its partials are those of its own projection (taken
    /// here by central differences); the whole image as it is is the sensor itself.
    #[test]
    fn a_view_shifts_and_scales_the_pixels_and_nothing_else() {
        let s = PhotoSensor::Pushbroom(crate::geometry::pushbroom::fixtures::spot_like(12.0));
        let win = PixelWindow {
            col0: 1200,
            row0: 700,
            width: 300,
            height: 200,
        };
        for factor in [1usize, 4] {
            let w = s.clone().viewed(PixelView {
                window: win,
                factor,
            });
            let fl = factor as f64;
            assert_eq!(w.image_size(), (300 / factor, 200 / factor));
            for (c, r, z) in [(0.0, 0.0, 100.0), (37.5, 24.25, 900.0), (75.0, 50.0, -50.0)] {
                let g = w.try_image_to_ground(PixelXY::new(c, r), z).unwrap();
                let whole = s
                    .try_image_to_ground(PixelXY::new(1200.0 + fl * c, 700.0 + fl * r), z)
                    .unwrap();
                assert_eq!((g.x, g.y), (whole.x, whole.y));
                let q = w.try_ground_to_image(g).unwrap();
                assert!(
                    (q.col - c).abs() < 1e-6 && (q.row - r).abs() < 1e-6,
                    "{q:?}"
                );
                let d = w.partials(g).unwrap();
                for (k, h) in [(0usize, 0.5), (1, 0.5), (2, 0.5)] {
                    let mut a = [g.x, g.y, g.z];
                    let mut b = a;
                    a[k] += h;
                    b[k] -= h;
                    let qa = w
                        .try_ground_to_image(GroundM::new(a[0], a[1], a[2]))
                        .unwrap();
                    let qb = w
                        .try_ground_to_image(GroundM::new(b[0], b[1], b[2]))
                        .unwrap();
                    let num = [(qa.col - qb.col) / (2.0 * h), (qa.row - qb.row) / (2.0 * h)];
                    for i in 0..2 {
                        assert!(
                            (d[i][k] - num[i]).abs() < 1e-4 * num[i].abs().max(1e-3),
                            "×{factor} ∂{i}/∂{k}: {} vs {}",
                            d[i][k],
                            num[i]
                        );
                    }
                }
                // The height's column alone is that column, to the bit, through the view too.
                assert_eq!(w.height_partials(g), Some([d[0][2], d[1][2]]));
            }
            assert!(w.frame().is_none());
        }
        assert!(matches!(
            s.clone().viewed(PixelView::whole(3000, 3000)),
            PhotoSensor::Pushbroom(_)
        ));
    }
}
