//! Matching projects, formats 1 and 2, and the format-2 points file: any text parses (every
//! number range-checked) or is a typed error, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;
use rig::matching::project::pair::PairProject;
use rig::matching::project::{parse_points, Project};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = PairProject::parse(text, Path::new("project.toml"));
        if let Ok(p) = Project::parse(text, Path::new("project.toml")) {
            let _ = parse_points(text, Path::new("points.csv"), &p.photos);
        }
    }
});
