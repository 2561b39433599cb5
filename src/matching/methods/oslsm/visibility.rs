//! Whether a photo sees a groundel: the ray from the groundel toward the sensor (whatever
//! the sensor: the ray is the sensor's own, through the pixel where it puts the groundel) must
//! stay above the terrain until it clears the highest post (seed 001: a groundel hidden in a
//! photo takes no observation from it).
//!
//! The march takes the longest step the terrain's steepest slope allows: with the ray a gap
//! c above the terrain, rising 1/lean per horizontal metre against a terrain that rises at
//! most `slope`, the gap cannot close within c / (slope − 1/lean) metres; and a ray that rises
//! faster than any slope never meets the terrain again. Never shorter than half a groundel,
//! so it samples at least as densely as a plain march (an obstacle narrower than that may
//! slip between samples, as it would there).

use crate::coords::GroundM;
use crate::geometry::Sensor;
use crate::matching::methods::oslsm::grids::Grids;

/// Steps of the ray march, at the most (a ray that leans so little that it needs more is
/// followed this far and then taken as clear).
const MAX_STEPS: usize = 4096;

/// The terrain of a patch as the rays see it: its grids, its highest post and its steepest
/// slope (computed once for all the groundels' rays).
pub struct Occluder<'a> {
    grids: &'a Grids,
    top: f64,
    slope: f64,
}

impl<'a> Occluder<'a> {
    pub fn new(grids: &'a Grids) -> Self {
        Occluder {
            grids,
            top: grids.z.iter().copied().fold(f64::MIN, f64::max),
            slope: grids.max_slope(),
        }
    }

    /// `true` when `sensor` sees ground point `g` (on the terrain) unobstructed: the ray from
    /// `g` rises above every post without passing under the terrain. The march starts one
    /// groundel away from `g` (closer, the terrain's own slope at `g` would hide it from rays
    /// that graze it).
    pub fn sees(&self, sensor: &dyn Sensor, g: GroundM) -> bool {
        let Some(q) = sensor.ground_to_image(g) else {
            return false;
        };
        let (Some(a), Some(b)) = (
            sensor.image_to_ground(q, g.z),
            sensor.image_to_ground(q, g.z + 1.0),
        ) else {
            return false;
        };
        let grids = self.grids;
        let gm = grids.groundel_m();
        // Sideways movement of the ray per metre of rise.
        let (dx, dy) = (b.x - a.x, b.y - a.y);
        let lean = dx.hypot(dy);
        let rise = self.top - g.z;
        if rise <= 0.0 || lean * rise < gm {
            return true;
        }
        // Horizontal metres along the ray's ground track; the ray's height above g is s/lean.
        let (ux, uy) = (dx / lean, dy / lean);
        let climb = 1.0 / lean;
        let closing = self.slope - climb;
        let (min_step, end) = (0.5 * gm, lean * rise);
        let mut s = gm;
        for _ in 0..=MAX_STEPS {
            let z = g.z + s * climb;
            match grids.z_xy(g.x + ux * s, g.y + uy * s) {
                Some(t) if t > z => return false,
                Some(t) => {
                    // Above the terrain here; a terrain no steeper than the ray's rise can
                    // never catch it.
                    if closing <= 0.0 {
                        return true;
                    }
                    s += ((z - t) / closing).max(min_step);
                }
                // Off the grid the terrain is unknown: taken as not hiding.
                None => return true,
            }
            if s > end {
                return true;
            }
        }
        true
    }
}
