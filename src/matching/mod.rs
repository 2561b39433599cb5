//! The matching core: elevation models from two or more photos. Here: polynomial mapping
//! functions and the height sweep along their epipolar lines (seeds 000 and 004).

pub mod pmf;
pub mod pmf_set;

pub use pmf_set::{PmfSet, SampleGrid, StereoPoint, TermSet};
pub use point::MatchedPoint;
pub mod accuracy;
pub mod averaging;
pub mod block_geometry;
pub mod block_match;
pub mod coverage;
pub mod edge_strings;
pub mod grid;
pub mod html;
pub mod maps;
pub mod matcher_config;
pub mod mgcm;
pub mod orientation_error;
pub mod ortho;
pub mod oslsm;
pub mod output;
pub mod outputs;
pub mod pair;
pub mod photos;
pub mod pipeline;
pub mod pipeline2;
pub mod plane_sweep;
pub mod pmf_dtm;
pub mod point;
pub mod precision;
pub mod progress;
pub mod project;
pub mod project2;
pub mod refine;
pub mod regions;
pub mod sgm;
pub mod sweep;
pub mod tiles;
pub mod triplets;
pub mod volume;
pub mod winner;
