//! Mosaicking throughput: 4×4 tiles of 512×512 px into one photo at 10 µm (2.56 MP of
//! output), bicubic with the anti-alias smoothing against nearest neighbour without it (the
//! baseline), both measured in this run; reported as output megapixels per second and their
//! ratio.

mod common;

use criterion::{criterion_group, Criterion};
use rig::coords::{CarriageUm, PhotoMm, PixelXY};
use rig::digitise::ImageF32;
use rig::scan::mosaic::{mosaic, Interpolation, TileSource};
use rig::scan::PhotoGrid;
use rig::scan::ScanCalibration;
use std::hint::black_box;
use std::time::Duration;

struct Setup {
    cal: ScanCalibration,
    grid: PhotoGrid,
    tiles: Vec<(CarriageUm, ImageF32)>,
}

fn setup() -> Setup {
    let cal = ScanCalibration::synthetic();
    let centre = PixelXY::new(256.0, 256.0);
    // 4 × 4 tiles 4 mm apart (the usable tile is about 5 × 5.4 mm).
    let mut tiles = Vec::new();
    for j in 0..4 {
        for i in 0..4 {
            let p = PhotoMm::new(-6.0 + 4.0 * i as f64, 6.0 - 4.0 * j as f64);
            let stage = cal.stage_for(p, centre);
            let mut img = ImageF32::new(512, 512);
            for (k, v) in img.data.iter_mut().enumerate() {
                let (x, y) = ((k % 512) as f32, (k / 512) as f32);
                *v = 20_000.0
                    + 5_000.0 * ((x * 0.37 + i as f32).sin() * (y * 0.23 + j as f32).cos());
            }
            tiles.push((stage, img));
        }
    }
    let grid = PhotoGrid::covering([-8.0, -8.0, 8.0, 8.0], 0.010);
    Setup { cal, grid, tiles }
}

fn run(s: &Setup, interp: Interpolation) -> Vec<u16> {
    let src: Vec<TileSource> = s
        .tiles
        .iter()
        .map(|(stage, img)| TileSource {
            stage_um: *stage,
            load: Box::new(move || Ok(img.clone())),
        })
        .collect();
    mosaic(&s.cal, &s.grid, &src, interp, &|_, _| {}).unwrap()
}

fn mosaicking(c: &mut Criterion) {
    let s = setup();
    let mut g = c.benchmark_group("mosaic_16_tiles");
    g.sample_size(10).measurement_time(Duration::from_secs(8));
    g.bench_function("nearest_baseline", |b| {
        b.iter(|| black_box(run(&s, Interpolation::Nearest)))
    });
    g.bench_function("bicubic_antialiased", |b| {
        b.iter(|| black_box(run(&s, Interpolation::Bicubic)))
    });
    g.finish();
}

criterion_group!(benches, mosaicking);

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    if std::env::args().any(|a| a == "--list" || a == "--test") {
        return;
    }
    let s = setup();
    let mp = (s.grid.width * s.grid.height) as f64 / 1e6;
    if let (Some(base), Some(t)) = (
        common::mean_ns("mosaic_16_tiles", "nearest_baseline"),
        common::mean_ns("mosaic_16_tiles", "bicubic_antialiased"),
    ) {
        println!(
            "\nmosaic of 16 tiles into {:.2} MP: bicubic + anti-alias {:.1} MP/s, nearest neighbour {:.1} MP/s (time ratio {:.2})",
            mp,
            mp / (t * 1e-9),
            mp / (base * 1e-9),
            t / base
        );
    }
}
