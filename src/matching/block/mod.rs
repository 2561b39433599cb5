//! A project's photos as a block: read (whole or the part the model needs), oriented as
//! sensors, their geometry for the multiphoto matchers, and the ground a height can be
//! computed on.

pub mod coverage;
pub mod geometry;
pub mod orient;
pub mod photo;
pub mod photos;
