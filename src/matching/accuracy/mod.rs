//! How far to trust a model: the window averaging on curved terrain, the orientations' share
//! of a height's error, variance factors and σ against a reference, and seed 002's accuracy
//! tables.

pub mod averaging;
pub mod figures;
pub mod orientation_error;
pub mod precision;
pub mod tables;
