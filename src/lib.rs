//! The rig: digitise and calibrate aerial film with a camera over motorised X/Y stages, and
//! turn the photos into elevation models. See README.md and docs/.

#[macro_use]
pub mod simd;

pub mod atomic;
pub mod calibrate;
pub mod camera;
pub mod coords;
pub mod correlation;
pub mod digitise;
pub mod exit;
pub mod geometry;
pub mod hac;
pub mod image;
pub mod matching;
pub mod orientation;
pub mod picture;
pub mod relative;
pub mod scan;
pub mod seconds;
pub mod service;
pub mod sim_scene;
pub mod stage;
pub mod targets;
#[cfg(test)]
mod test_rng;
