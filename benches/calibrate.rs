//! Calibration benchmarks, each beside a baseline measured in the same run:
//! - least-squares matching of one cross (71×71 patch, 6 affine + 2 radiometric parameters)
//!   against a plain normalised-correlation grid search with a parabola through the peak (the
//!   method of today's open tools): time per mark and precision against the simulator's truth;
//! - a whole `rig calibrate pixel --sim` session at time scale 0, in seconds, beside the time
//!   the same frames take to render and average alone.

mod common;

use criterion::{criterion_group, Criterion};
use rig::coords::PixelXY;
use rig::digitise::{average_frames, estimate_stripes, remove_stripes, ImageF32};
use rig::targets::{
    match_template, render, LsmOptions, MarkShape, Polarity, Template, TemplateSpec,
};
use rig_sim::camera::{expose, render_scene, CameraConfig};
use rig_sim::plate::Plate;
use rig_sim::rng::Rng;
use std::hint::black_box;
use std::time::{Duration, Instant};

struct Case {
    img: ImageF32,
    truth: PixelXY,
    start: PixelXY,
}

fn cases(n: usize) -> (Template, Vec<Case>) {
    let mut rng = Rng::new(11);
    let cfg = CameraConfig::new(&mut rng);
    let plate = Plate::new(&mut rng);
    let c = plate.crosses[4].true_um;
    let af = cfg.affine;
    let tpl = render(
        &MarkShape::cross(plate.arm_um, plate.line_um),
        &TemplateSpec {
            size: 71,
            um_per_px: [[af.a[0], af.a[1]], [af.b[0], af.b[1]]],
            blur_px: 0.7,
            polarity: Polarity::DarkOnClear,
            fine: true,
        },
    );
    let v = (0..n)
        .map(|k| {
            let want = [60.0 + 390.0 * rng.uniform(), 60.0 + 390.0 * rng.uniform()];
            let (dc, dr) = (want[0] - af.mark_px[0], want[1] - af.mark_px[1]);
            let mark = [
                c[0] - (af.a[0] * dc + af.a[1] * dr),
                c[1] - (af.b[0] * dc + af.b[1] * dr),
            ];
            let ideal = render_scene(&cfg, &plate, None, mark);
            let frames: Vec<Vec<u16>> = (0..32)
                .map(|s| expose(&cfg, &ideal, 11, 100 * k as u64 + s))
                .collect();
            let refs: Vec<&[u16]> = frames.iter().map(|f| f.as_slice()).collect();
            let mut img = average_frames(512, 512, &refs).unwrap().mean;
            let e = estimate_stripes(&img);
            remove_stripes(&mut img, &e);
            // A coarse start a third of a pixel off, as coarse location gives.
            let start = PixelXY::new(want[0] + 0.3, want[1] - 0.25);
            Case {
                img,
                truth: PixelXY::new(want[0], want[1]),
                start,
            }
        })
        .collect();
    (tpl, v)
}

/// The baseline: normalised correlation of the template at every integer offset within ±`r`
/// px of the start, then a parabola through the peak and its neighbours in each direction.
fn ncc_parabola(img: &ImageF32, tpl: &Template, start: PixelXY, r: i64) -> PixelXY {
    let n = tpl.size();
    let tm = tpl.image.data.iter().map(|&v| v as f64).sum::<f64>() / (n * n) as f64;
    let tv: f64 = tpl
        .image
        .data
        .iter()
        .map(|&v| (v as f64 - tm).powi(2))
        .sum();
    let c = tpl.centre();
    let ncc = |ox: i64, oy: i64| -> f64 {
        let (mut sg, mut sgg, mut sgt) = (0.0, 0.0, 0.0);
        for j in 0..n {
            let row = &img.data[(oy as usize + j) * img.width + ox as usize..][..n];
            let trow = &tpl.image.data[j * n..][..n];
            for i in 0..n {
                let g = row[i] as f64;
                sg += g;
                sgg += g * g;
                sgt += g * (trow[i] as f64 - tm);
            }
        }
        let gv = sgg - sg * sg / (n * n) as f64;
        sgt / (gv * tv).sqrt()
    };
    let (x0, y0) = (
        (start.col - c).round() as i64,
        (start.row - c).round() as i64,
    );
    let mut best = (f64::MIN, 0, 0);
    for dy in -r..=r {
        for dx in -r..=r {
            let s = ncc(x0 + dx, y0 + dy);
            if s > best.0 {
                best = (s, x0 + dx, y0 + dy);
            }
        }
    }
    let (s0, bx, by) = best;
    let peak = |m: f64, p: f64| {
        let d = m - 2.0 * s0 + p;
        if d < 0.0 {
            0.5 * (m - p) / d
        } else {
            0.0
        }
    };
    let fx = peak(ncc(bx - 1, by), ncc(bx + 1, by));
    let fy = peak(ncc(bx, by - 1), ncc(bx, by + 1));
    PixelXY::new(bx as f64 + fx + c, by as f64 + fy + c)
}

fn rmse(e: &[(f64, f64)]) -> f64 {
    (e.iter().map(|(x, y)| x * x + y * y).sum::<f64>() / (2 * e.len()) as f64).sqrt()
}

fn matching(c: &mut Criterion) {
    let (tpl, cs) = cases(8);
    let mut g = c.benchmark_group("match_one_cross_71px");
    g.measurement_time(Duration::from_secs(5)).sample_size(20);
    g.bench_function("ncc_grid_parabola_baseline", |b| {
        b.iter(|| {
            for k in &cs {
                black_box(ncc_parabola(&k.img, &tpl, k.start, 3));
            }
        })
    });
    g.bench_function("least_squares_8_parameters", |b| {
        b.iter(|| {
            for k in &cs {
                black_box(match_template(&k.img, &tpl, k.start, &LsmOptions::default()).unwrap());
            }
        })
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
    // Precision of both against the truth, on the same images.
    let (tpl, cs) = cases(8);
    let (mut el, mut en) = (Vec::new(), Vec::new());
    for k in &cs {
        let m = match_template(&k.img, &tpl, k.start, &LsmOptions::default()).unwrap();
        el.push((m.centre.col - k.truth.col, m.centre.row - k.truth.row));
        let p = ncc_parabola(&k.img, &tpl, k.start, 3);
        en.push((p.col - k.truth.col, p.row - k.truth.row));
    }
    if let (Some(base), Some(t)) = (
        common::mean_ns("match_one_cross_71px", "ncc_grid_parabola_baseline"),
        common::mean_ns("match_one_cross_71px", "least_squares_8_parameters"),
    ) {
        let n = cs.len() as f64;
        println!(
            "\none cross, 71×71 patch: least squares {:.2} ms, RMSE {:.4} px; correlation grid ±3 px + parabola {:.2} ms, RMSE {:.4} px (time ratio {:.2}, error ratio {:.1})",
            t / n / 1e6,
            rmse(&el),
            base / n / 1e6,
            rmse(&en),
            t / base,
            rmse(&en) / rmse(&el)
        );
    }
    // The whole session on the simulator, and the same frames rendered and averaged alone.
    let exe = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/release/rig");
    if !exe.is_file() {
        println!("(build the release binary to time a whole session: cargo build --release)");
        return;
    }
    let dir = std::env::temp_dir().join(format!("rig-bench-{}", std::process::id()));
    let t0 = Instant::now();
    let ok = std::process::Command::new(&exe)
        .args([
            "calibrate",
            "pixel",
            "--sim",
            "--sim-time-scale",
            "0",
            "--json",
            "--out",
        ])
        .arg(&dir)
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    let session = t0.elapsed().as_secs_f64();
    let _ = std::fs::remove_dir_all(&dir);
    let mut rng = Rng::new(1);
    let cfg = CameraConfig::new(&mut rng);
    let plate = Plate::new(&mut rng);
    let t0 = Instant::now();
    // 3 first-look pictures of 4 frames, 25 + 9 positions of 32 frames.
    for (k, frames) in std::iter::repeat_n(4u64, 3)
        .chain(std::iter::repeat_n(32, 34))
        .enumerate()
    {
        let ideal = render_scene(&cfg, &plate, None, [125_000.0 + k as f64 * 37.0, 125_000.0]);
        let fs: Vec<Vec<u16>> = (0..frames).map(|s| expose(&cfg, &ideal, 1, s)).collect();
        let refs: Vec<&[u16]> = fs.iter().map(|f| f.as_slice()).collect();
        black_box(average_frames(512, 512, &refs).unwrap());
    }
    let frames_only = t0.elapsed().as_secs_f64();
    println!(
        "rig calibrate pixel --sim (time scale 0): {session:.1} s{}; the same {} frames rendered and averaged alone {frames_only:.1} s (ratio {:.2})",
        if ok { "" } else { " (FAILED)" },
        3 * 4 + 34 * 32,
        session / frames_only
    );
}
