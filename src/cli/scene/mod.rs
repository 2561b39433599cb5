//! `rig sim scene`: a block rendered over simulated terrain with its truth, for a frame camera
//! (`frame`, which also holds the arguments and checks the sensors share), a pushbroom
//! satellite (`pushbroom`) or RPC-described crops (`rpc`).

pub mod frame;
pub mod pushbroom;
pub mod rpc;

pub use frame::{SceneArgs, SensorArg};

/// Renders the scene of the sensor asked for.
pub fn run(a: &SceneArgs) -> anyhow::Result<i32> {
    match a.sensor {
        SensorArg::Frame => frame::run(a),
        SensorArg::Pushbroom => pushbroom::run(a),
        SensorArg::Rpc => rpc::run(a),
    }
}
