//! Digitisation throughput, each beside a baseline measured in the same run:
//! - averaging 32 frames of 1280×1024 against a plain copy of the same bytes (aim: within 2×);
//! - stripe estimation + removal against the seed's 3×3 + 7×3 low-pass, in megapixels per second.

mod common;

use criterion::{criterion_group, Criterion};
use rig::digitise::{
    average_frames, average_frames_into, estimate_stripes, remove_stripes, seed_lowpass, Averager,
    ImageF32,
};
use std::hint::black_box;
use std::time::Duration;

const W: usize = 1280;
const H: usize = 1024;
const N: usize = 32;

fn frames() -> Vec<Vec<u16>> {
    let mut x = 0x1234_5678_9abc_def0u64;
    (0..N)
        .map(|_| {
            (0..W * H)
                .map(|i| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    // A scene, stripes, field shift and noise, 10-bit.
                    let (c, r) = (i % W, i / W);
                    let v = 400.0
                        + 200.0 * ((c as f64 / 40.0).sin() * (r as f64 / 30.0).cos())
                        + if r % 2 == 1 { 18.0 } else { 0.0 }
                        + if (c % 12) < 3 { -14.0 } else { 0.0 }
                        + (x % 16) as f64;
                    v as u16
                })
                .collect()
        })
        .collect()
}

fn averaging(c: &mut Criterion) {
    let fs = frames();
    let mut g = c.benchmark_group("average_32_frames_1280x1024");
    g.measurement_time(Duration::from_secs(6)).sample_size(20);
    g.bench_function("memcpy_baseline", |b| {
        let mut dst = vec![0u16; W * H];
        b.iter(|| {
            for f in &fs {
                dst.copy_from_slice(f);
                black_box(&dst);
            }
        })
    });
    let refs: Vec<&[u16]> = fs.iter().map(|f| f.as_slice()).collect();
    g.bench_function("average_frames", |b| {
        b.iter(|| black_box(average_frames(W, H, &refs).unwrap()))
    });
    // As a scan uses it: the output images are reused from tile to tile.
    let mut out = average_frames(W, H, &refs).unwrap();
    g.bench_function("average_frames_into", |b| {
        b.iter(|| {
            average_frames_into(W, H, &refs, &mut out).unwrap();
            black_box(&out);
        })
    });
    g.bench_function("streaming_averager", |b| {
        b.iter(|| {
            let mut a = Averager::new(W, H);
            for (i, f) in fs.iter().enumerate() {
                a.add(W, H, i as u64, f).unwrap();
            }
            black_box(a.finish().unwrap())
        })
    });
    g.finish();

    let mut a = Averager::new(W, H);
    for (i, f) in fs.iter().enumerate() {
        a.add(W, H, i as u64, f).unwrap();
    }
    let img: ImageF32 = a.finish().unwrap().mean;
    let mut g = c.benchmark_group("stripes_1280x1024");
    g.measurement_time(Duration::from_secs(6)).sample_size(20);
    g.bench_function("seed_lowpass_baseline", |b| {
        b.iter(|| black_box(seed_lowpass(&img)))
    });
    g.bench_function("estimate_and_remove", |b| {
        b.iter(|| {
            let mut m = img.clone();
            let e = estimate_stripes(&m);
            remove_stripes(&mut m, &e);
            black_box(m)
        })
    });
    g.finish();
}

criterion_group!(benches, averaging);

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    let mp = (W * H) as f64 / 1e6;
    if let (Some(base), Some(t)) = (
        common::mean_ns("average_32_frames_1280x1024", "memcpy_baseline"),
        common::mean_ns("average_32_frames_1280x1024", "average_frames"),
    ) {
        println!("\naveraging 32 frames of 1280×1024: {:.1} ms = {:.2} × a plain copy of the same bytes ({:.1} ms)", t / 1e6, t / base, base / 1e6);
    }
    if let (Some(base), Some(t)) = (
        common::mean_ns("average_32_frames_1280x1024", "memcpy_baseline"),
        common::mean_ns("average_32_frames_1280x1024", "average_frames_into"),
    ) {
        println!(
            "  into reused output images: {:.1} ms = {:.2} × the copy",
            t / 1e6,
            t / base
        );
    }
    if let (Some(base), Some(t)) = (
        common::mean_ns("stripes_1280x1024", "seed_lowpass_baseline"),
        common::mean_ns("stripes_1280x1024", "estimate_and_remove"),
    ) {
        println!(
            "stripe removal: {:.1} MP/s; the seed's low-pass {:.1} MP/s (ratio {:.2})",
            mp / (t / 1e9),
            mp / (base / 1e9),
            base / t
        );
    }
}
