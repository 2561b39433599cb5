//! `rig orient`'s run: the project's photos and points as a block, adjusted, its σ̂₀ fed back
//! into the rays' weights once (a variance-component estimate for the measurements, so that
//! the approximations' and the control's σ weigh against the rays' true precision), and the
//! outputs written ([`super::outputs`]).

use super::bundle::{adjust, Adjusted, Block, Settings};
use super::from_project::{block_of, OrientError, OrientOptions};
use crate::matching::block::photo::{Photo, PhotoGeometry};
use crate::matching::block::photos::load_photo;
use crate::matching::project::Project;
use std::path::Path;

/// The adjusted block with the block it came from.
#[derive(Debug, Clone)]
pub struct Oriented {
    pub block: Block,
    pub adjusted: Adjusted,
    /// σ of a measured ray after the variance-component step, px.
    pub image_sigma_px: f64,
}

/// Each photo's geometry, read as a matcher reads it (scans through `scan`).
pub fn geometry(
    p: &Project,
    scan: &dyn Fn(&Path) -> Result<Photo, String>,
) -> Result<Vec<PhotoGeometry>, OrientError> {
    (0..p.photos.len())
        .map(|k| Ok(load_photo(p, k, scan, None)?.geometry()))
        .collect()
}

/// Orients the project's block: adjusted with the stated σ, then once more with the rays'
/// σ scaled by σ̂₀ when it differs from 1 by more than a tenth.
pub fn orient_block(
    p: &Project,
    geometry: &[PhotoGeometry],
    options: OrientOptions,
) -> Result<Oriented, OrientError> {
    let obs = p.observations()?;
    let mut o = options;
    let mut block = block_of(p, geometry, &obs, o)?;
    let mut adjusted = adjust(&block, Settings::default())?;
    if (adjusted.sigma0 - 1.0).abs() > 0.1 {
        o.image_sigma_px *= adjusted.sigma0;
        block = block_of(p, geometry, &obs, o)?;
        adjusted = adjust(&block, Settings::default())?;
    }
    Ok(Oriented {
        block,
        adjusted,
        image_sigma_px: o.image_sigma_px,
    })
}
