//! Scan scripts: any text parses to a script or a typed error, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = rig::scan::script::ScanScript::parse(text, Path::new("fuzz.toml"));
    }
});
