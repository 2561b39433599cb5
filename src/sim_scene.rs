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
        },
        exterior: Exterior::from_degrees(
            e.omega_deg,
            e.phi_deg,
            e.kappa_deg,
            GroundM::new(e.x0_m, e.y0_m, e.z0_m),
        ),
    }
}
