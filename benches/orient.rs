//! Block orientation at scale (issue 56): a synthetic block of 1 000 photos (25 strips of 40,
//! 60 % forward and 30 % side overlap) with about 200 tie rays a photo (the generator's 240 asked, fewer seen) and 25 control points,
//! approximations 30 m and 3° off, oriented by `rig::orientation::adjust` — Levenberg–
//! Marquardt, data snooping with the full cofactor matrix of the orientations. Reported: the
//! whole adjustment's time and peak memory, and, in the same run, one factorisation of its
//! reduced camera system (6 000 unknowns) by the sparse Cholesky beside nalgebra's dense one.
//!
//! `cargo bench --bench orient` (`-- 8 12` for 8 strips of 12 photos)

use rig::orientation::bundle::{adjust, reduced_at_start, Settings};
use rig::orientation::synthetic::{make, Spec};
use std::time::Instant;

fn peak_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines().find(|l| l.starts_with("VmHWM:")).and_then(|l| {
                l.split_whitespace()
                    .nth(1)
                    .and_then(|v| v.parse::<f64>().ok())
            })
        })
        .map_or(f64::NAN, |kib| kib / 1024.0)
}

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let (strips, per_strip) = match args.as_slice() {
        [a, b, ..] => (*a, *b),
        _ => (25, 40),
    };
    let t = Instant::now();
    let s = make(Spec {
        strips,
        per_strip,
        rays_per_photo: 240,
        control_side: 5,
        noise_px: 0.3,
        position_sigma_m: 30.0,
        angles_sigma_deg: 3.0,
        seed: 1,
    });
    let n = s.block.photos.len();
    println!(
        "block: {n} photos, {} points, {} rays ({:.0} a photo); made in {:.2} s",
        s.block.points.len(),
        s.block.rays.len(),
        s.block.rays.len() as f64 / n as f64,
        t.elapsed().as_secs_f64()
    );
    let t = Instant::now();
    let a = adjust(&s.block, Settings::default()).expect("the synthetic block adjusts");
    let whole = t.elapsed().as_secs_f64();
    let pos: f64 = (0..n)
        .map(|i| {
            let (e, tr) = (a.exteriors[i].centre, s.exteriors[i].centre);
            (e.x - tr.x).powi(2) + (e.y - tr.y).powi(2) + (e.z - tr.z).powi(2)
        })
        .sum::<f64>()
        / n as f64;
    println!(
        "adjustment: {whole:.2} s, peak memory {:.0} MiB; {} iterations, σ̂₀ {:.3}, {} rays rejected, centres {:.3} m RMS from the truth",
        peak_mib(),
        a.iterations,
        a.sigma0,
        a.rejected,
        pos.sqrt()
    );
    let mut r = reduced_at_start(&s.block).unwrap();
    let rhs = nalgebra::DVector::from_element(6 * n, 1.0);
    let t = Instant::now();
    let x = r.solve(&rhs).unwrap();
    let sparse = t.elapsed().as_secs_f64();
    let dense_m = r.dense();
    let t = Instant::now();
    let xd = dense_m
        .cholesky()
        .expect("S is positive definite")
        .solve(&rhs);
    let dense = t.elapsed().as_secs_f64();
    println!(
        "reduced system {} × {}: sparse Cholesky (symbolic + numeric + solve) {sparse:.3} s, dense {dense:.3} s: dense / sparse = {:.1}; solutions agree to {:.1e} (relative)",
        6 * n,
        6 * n,
        dense / sparse,
        (&x - &xd).amax() / xd.amax()
    );
}
