//! Matching projects: any text parses (every number range-checked) or is a typed error, never
//! a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;
use rig::matching::project::Project;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = Project::parse(text, Path::new("project.toml"));
    }
});
