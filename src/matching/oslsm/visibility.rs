//! Whether a photo sees a groundel: the ray from the groundel toward the sensor (whatever
//! the sensor: the ray is the sensor's own, through the pixel where it puts the groundel) must
//! stay above the terrain until it clears the highest post (seed 001: a groundel hidden in a
//! photo takes no observation from it).

use super::grids::Grids;
use crate::coords::GroundM;
use crate::geometry::Sensor;

/// Steps of the ray march, at the most (a ray that leans so little that it needs more is
/// followed this far and then taken as clear).
const MAX_STEPS: usize = 4096;

/// `true` when `sensor` sees ground point `g` (on the terrain of `grids`) unobstructed: the
/// ray from `g` rises above every post's height, `z_top`, without passing under the terrain.
/// The march steps half a groundel sideways at a time and starts one groundel away from `g`
/// (closer, the terrain's own slope at `g` would hide it from rays that graze it).
pub fn visible(sensor: &dyn Sensor, g: GroundM, grids: &Grids, z_top: f64) -> bool {
    let Some(q) = sensor.ground_to_image(g) else {
        return false;
    };
    let (Some(a), Some(b)) = (
        sensor.image_to_ground(q, g.z),
        sensor.image_to_ground(q, g.z + 1.0),
    ) else {
        return false;
    };
    // Sideways movement of the ray per metre of rise.
    let (dx, dy) = (b.x - a.x, b.y - a.y);
    let lean = dx.hypot(dy);
    let rise = z_top - g.z;
    if rise <= 0.0 || lean * rise < grids.groundel_m() {
        return true;
    }
    let step = 0.5 * grids.groundel_m() / lean;
    let first = grids.groundel_m() / lean;
    let n = (((rise - first) / step).ceil().max(0.0) as usize).min(MAX_STEPS);
    for k in 0..=n {
        let dz = first + k as f64 * step;
        let (x, y, z) = (g.x + dx * dz, g.y + dy * dz, g.z + dz);
        match grids.z_xy(x, y) {
            Some(t) if t > z => return false,
            Some(_) => {}
            // Off the grid the terrain is unknown: taken as not hiding.
            None => return true,
        }
    }
    true
}
