//! Block orientation (aerotriangulation): a block of overlapping frame photos with
//! approximate orientations (a flight index map's) or none, a few control points and tie
//! points, oriented by one bundle adjustment ([`bundle`]). `rig orient` writes the oriented
//! project, the tie points' ground and a report; `rig dtm` runs the same code first on a
//! project whose photos are approximate, and the elevation model's σ carries the
//! orientations' covariance.
//!
//! Core: it takes a [`crate::matching::project::Project`] and the photos' geometry as plain
//! data, and nothing of the hardware.

pub mod bundle;
pub mod collinearity;
pub mod covariance;
pub mod from_project;
pub mod oriented;
pub mod outputs;
pub mod reduced;
pub mod run;
pub mod synthetic;
pub mod ties;

pub use bundle::{adjust, Adjusted, Block, BundleError, Settings};
pub use from_project::{block_of, OrientError, OrientOptions};
