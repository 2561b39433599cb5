//! Photo geometry: the frame camera and its collinearity equations, space intersection and
//! space resection. No hardware, no images: the matching core and the polynomial mapping
//! functions build on it.

pub mod frame;
pub mod intersection;
pub mod resection;

pub use frame::{Exterior, FrameCamera, Interior};
pub use intersection::{intersect, Intersection};
pub use resection::{resect, Resection};
