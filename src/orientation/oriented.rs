//! What orienting a block gives: the adjusted block, with what the matchers and the outputs
//! take from it.

use super::bundle::{Adjusted, Block};

/// The adjusted block with the block it came from.
#[derive(Debug, Clone)]
pub struct Oriented {
    pub block: Block,
    pub adjusted: Adjusted,
    /// σ of a measured ray (the points file's) after the variance components, px.
    pub image_sigma_px: f64,
    /// The terrain's heights, m: the project's, else the adjusted points' with a margin.
    pub heights: [f64; 2],
    /// Pairs (i, j), i < j, of photos whose oriented footprints overlap at the middle height.
    pub pairs: Vec<(usize, usize)>,
}
