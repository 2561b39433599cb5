//! Calibration sessions (seed 002, "Geometric calibration"): the pixel→carriage
//! transformation from a cross stepped through the image, the measuring mark's pixel, and (with
//! a film) the carriage→image transformation from the fiducials; each session kept in the
//! store so drift between sessions shows.

pub mod affine_fit;
pub mod documents;
pub mod history;
pub mod interior;
pub mod pixel;
pub mod plot;
pub mod run;
pub mod session;

pub use affine_fit::{fit, Fit, FitError, Model};
pub use interior::{calibrate_interior, InteriorOptions, InteriorOrientation, PixelTransform};
pub use pixel::{calibrate_pixel, CalibrateError, PixelCalibration, PixelOptions, Rig};
pub use session::Session;
