//! The simulator's aerial photos in the core's terms: only their numbers cross over (the
//! geometry is the core's own), so that the core never depends on the simulator.

use crate::coords::{GroundM, PhotoMm};
use crate::geometry::{Exterior, FrameCamera, Interior};

/// A simulated photo's camera (principal point at the fiducial centre, no distortion): for
/// the demo, the scenes and the tests that compare with the simulator's truth.
pub fn frame_camera(p: &rig_sim::scene::AerialPhoto) -> FrameCamera {
    let e = p.exterior;
    FrameCamera {
        interior: Interior {
            focal_mm: p.focal_mm,
            principal_point: PhotoMm::new(0.0, 0.0),
            lens: crate::geometry::Lens::NONE,
        },
        exterior: Exterior::from_degrees(
            e.omega_deg,
            e.phi_deg,
            e.kappa_deg,
            GroundM::new(e.x0_m, e.y0_m, e.z0_m),
        ),
    }
}

/// The simulated world's coordinate system: WGS 84 / UTM zone 16N.
pub const CRS: crate::geometry::Crs = crate::geometry::Crs::Epsg(32616);

/// Where the simulator's local origin (the Jacksboro DEM's south-west corner, 84.41375° W,
/// 36.44625° N) lies in [`CRS`]: easting and northing by the Transverse Mercator series on
/// WGS 84, rounded to 10 m. The simulator treats the DEM's 3″ cells as metric and its grid as
/// east–north aligned, so its world lies within about half a kilometre of the real terrain
/// (UTM's grid is turned 1.5° there): close enough for a GIS to place it, not for surveying.
pub const ORIGIN_M: [f64; 2] = [731_800.0, 4_036_560.0];

/// A simulator ground point (local metres) in [`CRS`].
pub fn to_crs(g: [f64; 3]) -> GroundM {
    GroundM::new(g[0] + ORIGIN_M[0], g[1] + ORIGIN_M[1], g[2])
}

/// A grid computed on the simulator's local ground, moved into [`CRS`].
pub fn grid_to_crs(
    mut g: crate::matching::grid::ElevationGrid,
) -> crate::matching::grid::ElevationGrid {
    g.x0 += ORIGIN_M[0];
    g.y0 += ORIGIN_M[1];
    g
}

/// A simulated satellite view's line scanner in the core's terms, its orbit moved into
/// [`CRS`] (the same model, written twice: the simulator's and the core's).
pub fn pushbroom(v: &rig_sim::pushbroom::PushbroomView) -> crate::geometry::Pushbroom {
    let mut position = v.position;
    position[0][0] += ORIGIN_M[0];
    position[1][0] += ORIGIN_M[1];
    crate::geometry::Pushbroom {
        columns: v.columns,
        lines: v.lines,
        line_period_s: v.line_period_s,
        focal_px: v.focal_px,
        principal_col: v.principal_col,
        tilt_across: v.tilt_across_deg.to_radians(),
        tilt_along: v.tilt_along_deg.to_radians(),
        position,
        attitude: v.attitude,
    }
}
