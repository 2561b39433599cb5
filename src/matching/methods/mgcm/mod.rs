//! Hierarchical multiphoto geometrically constrained matching (seed 002, with seed 004's
//! mapping functions through [`crate::geometry::Sensor`]): the image pyramid, the interest
//! operator, the constrained adjustment at one point and its blunder tests per ray.

pub mod adjust;
pub mod config;
pub mod interest;
pub mod point;
pub mod pyramid;
pub mod run;

pub use adjust::{AdjustParams, Constraint, PointFailure, RayFit, Solution, View};
pub use point::{match_point, PointResult, RayRejection, RayTests};

#[cfg(test)]
mod tests;
