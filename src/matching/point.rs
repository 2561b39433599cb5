//! A matched point as the matchers hand it on: where it lies on the ground and how well it is
//! known, so that the grid, the quality raster, the point files and the report all read the
//! same three things.

use crate::coords::GroundM;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MatchedPoint {
    /// Ground position in the project's CRS, m.
    pub ground: GroundM,
    /// Correlation of the match (−1 … 1).
    pub corr: f32,
    /// Standard deviation of the height, m (NaN when the matcher could not estimate it).
    pub sigma_m: f32,
}
