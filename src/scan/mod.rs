//! Scripted film scanning (docs/scanning.md): a script names the film, its calibration and the
//! regions of the photo; the plan tiles them and checks them against the soft limits; the run
//! takes every tile (averaged, filtered, flat-fielded) with a checkpoint after each and can be
//! paused and resumed; the mosaic resamples the tiles through pixel→carriage→photo into one
//! image per region in photo coordinates, the hand-over to the matching core.

pub mod calibration;
pub mod manifest;
pub mod mosaic;
pub mod mosaic_shares;
pub mod plan;
pub mod plan_plot;

pub mod run;
pub mod script;
pub mod sidecar;
pub mod verify;

pub use crate::geometry::PhotoGrid;
pub use calibration::ScanCalibration;
pub use plan::{plan, Plan};
pub use run::{ScanDir, ScanError};
pub use script::ScanScript;
pub use sidecar::ScannedPhoto;
