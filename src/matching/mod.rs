//! The matching core: elevation models from two or more photos, with no hardware in it.
//!
//! - [`project`]: what a run is asked (the project file: photos, points, heights, method).
//! - [`block`]: the photos and their geometry (read, oriented, paired, split into tiles).
//! - [`mapping`]: polynomial mapping functions between the photos and the ground
//!   (Ackermann 1984 after Kratky; seed 000 and seed 004).
//! - [`plane_sweep`]: the search over heights or disparities that the sweep and the pair
//!   matcher share.
//! - [`methods`]: the matchers — the height sweep, multiphoto geometrically constrained
//!   matching, object-space least-squares matching, and the rectified-pair matcher.
//! - [`accuracy`]: how far to trust a model (σ, variance factors, tables against truth).
//! - [`products`]: the files a run leaves (GeoTIFF, LAS, PLY, maps, the report).
//! - [`run`]: the one driver: a project's photos through its method to its files.

pub mod accuracy;
pub mod block;
pub mod error;
pub mod grid;
pub mod mapping;
pub mod methods;
pub mod plane_sweep;
pub mod point;
pub mod products;
pub mod progress;
pub mod project;
pub mod run;

pub use error::MatchingError;
pub use mapping::pmf_set::{PmfSet, SampleGrid, StereoPoint, TermSet};
pub use point::MatchedPoint;
