//! Object-space least-squares matching (seed 001, Lo and Mulder): terrain heights and terrain
//! reflectance solved together in object space from any number of photos, each seen through
//! its [`crate::geometry::Sensor`] only (frame, pushbroom or RPC alike).

pub mod banded;
pub mod coarse_features;
pub mod config;
pub mod edge_strings;
pub mod grids;
pub mod patches;
pub mod plot;
pub mod run;
pub mod solve;
pub mod visibility;

pub use grids::{Grids, Groundel};
pub use patches::{refine_block, Merged, PatchLayout, PatchReport};
pub use solve::{refine, sight, Iteration, OslsmError, OslsmParams, Refinement};
pub use visibility::Occluder;

/// A photo as the object-space matching sees it: its grey values and its sensor (the slopes
/// are the bilinear surface's own, taken where it is sampled).
#[derive(Clone, Copy)]
pub struct PhotoView<'a> {
    pub image: &'a crate::image::ImageF32,
    pub sensor: &'a (dyn crate::geometry::Sensor + Sync),
}

#[cfg(test)]
mod tests;
