//! The rig's simulated world. It is the source of truth for the host's tests, so it shares no
//! geometry or image code with the host: only `firmware-protocol` and general crates.
//!
//! - [`stage`]: the physical X/Y stage (trapezoidal motion, steps, backlash, noise, drift,
//!   limit switches, homing) on a virtual clock;
//! - [`native`] and [`grbl`]: controller firmware for the two dialects;
//! - [`faults`]: fault injection on the line and on moves;
//! - [`pty`]: the real pseudo-terminal the host opens;
//! - [`camera`], [`plate`], [`film`], [`scene`]: what the camera sees: the carriage plate, the
//!   film and the aerial photo on it, rendered from a DEM; [`pushbroom`]: satellite line
//!   scanner views of the same terrain; [`rpc_scene`]: crops of real satellite products
//!   rendered through their real RPCs ([`rpc`]) over a real lidar DEM laid on UTM ([`utm`]);
//! - [`server`]: the loop that ties them together; [`truth`]: the truth file.

pub mod camera;
pub mod camera_socket;
pub mod certificates;
pub mod cli;
pub mod edges;
pub mod faults;
pub mod film;
pub mod frames;
pub mod grbl;
pub mod marks;
pub mod native;
pub mod plate;
pub mod profile;
pub mod pty;
pub mod pushbroom;
pub mod rng;
pub mod rpc;
pub mod rpc_scene;
pub mod scene;
pub mod server;
pub mod stage;
pub mod truth;
pub mod utm;

pub use faults::FaultSpec;
pub use server::{serve, Dialect, EmbeddedSim, SimConfig, World};
