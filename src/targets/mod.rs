//! Marks and how to find them (seed 002, "Geometric calibration"): synthetic templates from a
//! certificate's geometry, coarse location from gradients, fine location by least-squares
//! matching.

pub mod certificate;
pub mod coarse;
pub mod crop_stripes;
pub mod lsm;
pub mod mark;
pub mod mark_file;
pub mod measure;
pub mod resample;
pub mod template;

pub use coarse::{locate, CoarseError, CoarseMatch, CoarseOptions};
pub use lsm::{match_template, LsmError, LsmMatch, LsmOptions};
pub use mark::{Geometry, MarkShape, Part};
pub use template::{render, Polarity, Template, TemplateSpec};
