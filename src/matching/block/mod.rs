//! A project's photos as a block: read (whole or the part the model needs), their geometry
//! for the multiphoto matchers, the ground a height can be computed on, and the work split
//! into tiles for several machines.

pub mod coverage;
pub mod geometry;
pub mod photos;
pub mod tiles;
