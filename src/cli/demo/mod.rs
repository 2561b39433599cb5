//! `rig demo`: the whole job on the simulator, with a frame camera's scanned film (`frame`) or
//! a pushbroom satellite's views (`pushbroom`).

pub mod frame;
pub mod pushbroom;

pub use frame::{DemoArgs, DemoSensor};

/// Runs the demo of the sensor asked for into a new (or empty) directory.
pub fn run(a: &DemoArgs) -> anyhow::Result<i32> {
    if a.out.exists() && std::fs::read_dir(&a.out)?.next().is_some() {
        anyhow::bail!("{} is not empty: give a new directory", a.out.display());
    }
    match a.sensor {
        DemoSensor::Frame => frame::run(a),
        DemoSensor::Pushbroom => pushbroom::run(a),
    }
}
