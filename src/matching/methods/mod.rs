//! The matchers: the height sweep over every overlapping pair (seed 000), multiphoto
//! geometrically constrained matching (seed 002), object-space least-squares matching
//! (seed 001), and the rectified-pair matcher of `rig match pair`.

pub mod context;
pub mod mgcm;
pub mod oslsm;
pub mod pair;
pub mod sweep;
