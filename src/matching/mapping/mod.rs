//! Polynomial mapping functions (seed 000 §2.1; seed 004 §4): image ↔ image and image ↔
//! ground relations of a stereo pair fitted to control points or derived from two sensors,
//! and the heights they give from a point's image coordinates.

pub mod given;
pub mod pmf;
pub mod pmf_set;
pub mod triplets;
