//! Height-sweep throughput in pixel·candidate-heights per second: the plane sweep (the search
//! photo resampled once per height, NCC from running sums, bands of rows in parallel) against
//! a straightforward per-pixel baseline (both windows' means and deviations recomputed for
//! every candidate, one thread), on the same simulator pair and the same full height range;
//! then the sweep with its least-squares refinement of every winner.

mod common;

use criterion::{criterion_group, Criterion};
use rig::digitise::ImageF32;
use rig::geometry::FrameSensor;
use rig::matching::mapping::pmf::Mapping;
use rig::matching::methods::sweep::height_sweep::{sweep, SweepParams};
use rig::matching::plane_sweep::refine::Subpixel;
use rig::matching::PmfSet;
use rig::scan::PhotoGrid;
use rig_sim::scene::{jacksboro, AerialPhoto};
use std::hint::black_box;
use std::time::Duration;

struct Case {
    left: ImageF32,
    right: ImageF32,
    map: Mapping,
    p: SweepParams,
}

fn photo(a: &AerialPhoto, g: PhotoGrid) -> (FrameSensor, ImageF32) {
    let r = FrameSensor {
        camera: rig::sim_scene::frame_camera(a),
        frame: g.into(),
        exterior_cov: None,
        radial: Default::default(),
    };
    let img = ImageF32 {
        width: g.width,
        height: g.height,
        data: a.render(g.corner_mm, g.step_mm, g.width, g.height, 2),
    };
    (r, img)
}

fn case() -> Case {
    let d = jacksboro();
    let (a, b) = (
        AerialPhoto::new(d.clone(), 5, 1, 60.0),
        AerialPhoto::new(d, 5, 2, 60.0),
    );
    let (l, li) = photo(&a, PhotoGrid::covering([44.0, -2.0, 48.0, 2.0], 0.025));
    let (r, ri) = photo(&b, PhotoGrid::covering([-54.0, -5.0, -38.0, 5.0], 0.025));
    let set = PmfSet::from_sensors(&l, &r, [340.0, 600.0], 3).unwrap();
    Case {
        left: li,
        right: ri,
        map: set.left_to_right,
        p: SweepParams {
            h_min: 340.0,
            h_max: 600.0,
            h_step: 2.0,
            subpixel: Subpixel::Parabola,
            ..Default::default()
        },
    }
}

/// The straightforward matcher: for every pixel and every candidate height, both windows'
/// statistics from scratch.
fn naive(c: &Case) -> (Vec<f32>, u64) {
    let k = c.p.window as i64 / 2;
    let (w, h) = (c.left.width as i64, c.left.height as i64);
    let n = ((c.p.h_max - c.p.h_min) / c.p.h_step).floor() as i64;
    let bil = |x: f64, y: f64| -> Option<f64> {
        let (u, v) = (x - 0.5, y - 0.5);
        if u < 0.0 || v < 0.0 {
            return None;
        }
        let (i, j) = (u.floor() as usize, v.floor() as usize);
        if i + 1 >= c.right.width || j + 1 >= c.right.height {
            return None;
        }
        let (fx, fy) = (u - i as f64, v - j as f64);
        let at = |i: usize, j: usize| c.right.data[j * c.right.width + i] as f64;
        Some(
            (1.0 - fy) * ((1.0 - fx) * at(i, j) + fx * at(i + 1, j))
                + fy * ((1.0 - fx) * at(i, j + 1) + fx * at(i + 1, j + 1)),
        )
    };
    let mut out = Vec::new();
    let mut tried = 0u64;
    for r in k..h - k {
        for col in k..w - k {
            let mut best = (f64::MIN, f32::NAN);
            for i in 0..=n {
                let hh = c.p.h_min + i as f64 * c.p.h_step;
                let q = c.map.eval([col as f64 + 0.5, r as f64 + 0.5, hh]);
                tried += 1;
                let mut a = Vec::new();
                let mut b = Vec::new();
                for dy in -k..=k {
                    for dx in -k..=k {
                        a.push(c.left.data[((r + dy) * w + col + dx) as usize] as f64);
                        b.push(bil(q[0] + dx as f64, q[1] + dy as f64).unwrap_or(f64::NAN));
                    }
                }
                if b.iter().any(|v| v.is_nan()) {
                    continue;
                }
                let m = a.len() as f64;
                let (ma, mb) = (a.iter().sum::<f64>() / m, b.iter().sum::<f64>() / m);
                let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
                for (x, y) in a.iter().zip(&b) {
                    sab += (x - ma) * (y - mb);
                    saa += (x - ma) * (x - ma);
                    sbb += (y - mb) * (y - mb);
                }
                let ncc = sab / (saa * sbb).sqrt();
                if ncc > best.0 {
                    best = (ncc, hh as f32);
                }
            }
            out.push(if best.0 >= c.p.threshold {
                best.1
            } else {
                f32::NAN
            });
        }
    }
    (out, tried)
}

fn matching(cr: &mut Criterion) {
    let c = case();
    let mut g = cr.benchmark_group("sweep_160x160");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    g.bench_function("per_pixel_baseline", |b| b.iter(|| black_box(naive(&c))));
    g.bench_function("matcher_full_range", |b| {
        b.iter(|| black_box(sweep(&c.left, &c.right, &c.map, &c.p)))
    });
    let mut pn = c.p.clone();
    pn.subpixel = Subpixel::Lsm;
    g.bench_function("matcher_lsm", |b| {
        b.iter(|| black_box(sweep(&c.left, &c.right, &c.map, &pn)))
    });
    g.finish();
}

criterion_group!(benches, matching);

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    if std::env::args().any(|a| a == "--list" || a == "--test") {
        return;
    }
    let c = case();
    let (base_h, base_n) = naive(&c);
    let full = sweep(&c.left, &c.right, &c.map, &c.p);
    let mut pn = c.p.clone();
    pn.subpixel = Subpixel::Lsm;
    let near = sweep(&c.left, &c.right, &c.map, &pn);
    let same = base_h
        .iter()
        .zip(&full.h)
        .filter(|(a, b)| a.is_finite() && b.is_finite() && (**a - **b).abs() <= c.p.h_step as f32)
        .count();
    let name = "sweep_160x160";
    if let (Some(tb), Some(tf), Some(tn)) = (
        common::mean_ns(name, "per_pixel_baseline"),
        common::mean_ns(name, "matcher_full_range"),
        common::mean_ns(name, "matcher_lsm"),
    ) {
        let px = (full.cols * full.rows) as f64;
        println!(
            "\nheight sweep, {} px × {} heights: per-pixel baseline {:.2} M pixel·heights/s; plane sweep {:.2} M/s ({:.1}×); with least squares on every winner {:.0} px/s against the baseline's {:.0} px/s ({:.1}×; {:.1} % of pixels given a height). Same height (±1 step) as the baseline at {:.1} % of pixels.",
            px,
            base_n as f64 / px,
            base_n as f64 / tb * 1e3,
            full.candidates as f64 / tf * 1e3,
            tb / tf,
            px / tn * 1e9,
            px / tb * 1e9,
            tb / tn,
            100.0 * near.matched() as f64 / px,
            100.0 * same as f64 / px
        );
    }
}
