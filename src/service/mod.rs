//! The rig as a lab service (`rig serve`): one process holds the stage and camera for hours,
//! runs a queue of work, tells every client what happens as it happens, and forgets nothing
//! across a crash. docs/service.md is the operator's guide.
//!
//! The parts, in the order a request meets them: `http` (routes, roles, limits) → `service`
//! (the state, journaled) → `hardware` (the one thread that owns the devices). The design
//! follows bluesky's queue server (a queue of plans; pause, resume, stop, abort, halt; a
//! history) and Micro-Manager's live view.

pub mod auth;
pub mod calibration;
pub mod devices;
pub mod events;
pub mod hardware;
pub mod http;
pub mod journal;
pub mod ledger;
pub mod listen;
pub mod openapi;
pub mod queue;
pub mod runner;
pub mod server;
pub mod task;
pub mod work;
