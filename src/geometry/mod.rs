//! Photo geometry: the frame camera and its collinearity equations, space intersection and
//! space resection, and the pixel → photo grid of a photo's image. No hardware, no images:
//! the matching core and the polynomial mapping functions build on it.

pub mod affine;
pub mod control_covariance;
pub mod control_fit;
pub mod convergence;
pub mod crs;
pub mod frame;
pub mod geographic;
pub mod intersection;
pub mod lens;
pub mod photo_grid;
pub mod pixel_frame;
pub mod pushbroom;
pub mod radial;
pub mod resection;
pub mod rpc;
pub mod sensor;

pub use crs::Crs;
pub use frame::{Exterior, FrameCamera, Interior};
pub use geographic::{Geographic, LonLatH};
pub use intersection::{intersect, Intersection};
pub use lens::Lens;
pub use photo_grid::PhotoGrid;
pub use pixel_frame::PixelToPhoto;
pub use pushbroom::Pushbroom;
pub use radial::Radial;
pub use resection::{resect, Resection, ResectionError};
pub use rpc::{Rpc, RpcSensor};
pub use sensor::{FrameSensor, PhotoSensor, ProjectionError, Sensor};
