//! Shared by the benchmarks: read criterion's estimate of a benchmark from this run.
#![allow(dead_code)]

/// Mean time of `group/bench` in this run, ns.
pub fn mean_ns(group: &str, bench: &str) -> Option<f64> {
    let p = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("../criterion")
        .join(group)
        .join(bench)
        .join("new/estimates.json");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(p).ok()?).ok()?;
    v["mean"]["point_estimate"].as_f64()
}
