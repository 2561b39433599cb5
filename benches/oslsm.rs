//! The object-space matching's cost per million groundels, and where it goes: three vertical
//! photos of a textured hill (0.62 m ground pixels, groundels of 0.71 m, posts every 5 m, a
//! coarse model a pixel of parallax off), blocks of 0.25 and 1 million groundels refined patch
//! by patch. Beside each, measured in the same run: the baseline, one pass that only samples
//! every photo at every groundel (the least any iteration must do), reported as the ratio of
//! the adjustment's time to it per iteration; and the solve of one patch's normal equations
//! (24² posts in a band two grid rows wide, 12 radiometric unknowns bordering them), as the
//! adjustment does it (a bordered-band Cholesky, the inverse's diagonal) and, as the baseline
//! in the same run, densely (nalgebra's Cholesky and whole inverse, as it was done before):
//! the banded solve's share of the adjustment's time and the dense one's time over it.
//! Memory: the estimate the run refuses by, the process's peak resident size, and both
//! extrapolated to a 10 000 × 10 000-groundel block.
//!
//! `cargo bench --bench oslsm`

use nalgebra::DMatrix;
use rig::coords::{GroundM, PixelXY};
use rig::geometry::{FrameSensor, Sensor};
use rig::image::ImageF32;
use rig::matching::block::orient::vertical_sensor;
use rig::matching::methods::oslsm::banded::BorderedBand;
use rig::matching::methods::oslsm::run::memory_bytes;
use rig::matching::methods::oslsm::solve::NR;
use rig::matching::methods::oslsm::{refine_block, Grids, OslsmParams, PatchLayout, PhotoView};
use rig::matching::progress::Silent;
use std::time::Instant;

const Z0: f64 = 1000.0;
const F_MM: f64 = 153.0;
const PIX_MM: f64 = 0.1;
const POST_M: f64 = 5.0;
const PER_CELL: usize = 7;

fn terrain(x: f64, y: f64) -> f64 {
    50.0 + 8.0 * (x / 90.0).sin() * (y / 110.0).cos()
}

fn reflectance(x: f64, y: f64) -> f64 {
    let waves = [
        (1.31, 0.41, 0.0),
        (-0.52, 1.13, 1.0),
        (0.77, -0.95, 2.0),
        (0.25, 1.73, 0.5),
        (1.91, 0.65, 2.5),
    ];
    100.0
        + waves
            .iter()
            .map(|&(a, b, ph)| 15.0 * (a * x + b * y + ph).sin())
            .sum::<f64>()
}

/// A photo of the terrain, 2 × 2 samples a pixel, each ray followed to the terrain.
fn render(s: &FrameSensor, side: usize, gain: f64) -> ImageF32 {
    use rayon::prelude::*;
    let mut img = ImageF32::new(side, side);
    img.data
        .par_chunks_mut(side)
        .enumerate()
        .for_each(|(row, line)| {
            for (col, out) in line.iter_mut().enumerate() {
                let mut v = 0.0;
                for j in 0..2 {
                    for i in 0..2 {
                        let q = PixelXY::new(
                            col as f64 + 0.25 + 0.5 * i as f64,
                            row as f64 + 0.25 + 0.5 * j as f64,
                        );
                        let mut z = 50.0;
                        let mut g = s.image_to_ground(q, z).unwrap();
                        for _ in 0..20 {
                            z = terrain(g.x, g.y);
                            g = s.image_to_ground(q, z).unwrap();
                        }
                        v += reflectance(g.x, g.y);
                    }
                }
                *out = (gain * v / 4.0) as f32;
            }
        });
    img
}

/// Peak resident size of this process so far, MiB (Linux).
fn peak_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn main() {
    let threads = rayon::current_num_threads() as u64;
    println!(
        "oslsm: 3 photos, groundels {:.3} m, posts {POST_M} m, patches of 24 posts, {threads} threads",
        POST_M / PER_CELL as f64
    );
    println!(
        "{:>10} {:>8} {:>10} {:>6} {:>14} {:>12} {:>10} {:>10}",
        "groundels", "s", "s/Mgroundel", "iters", "× sampling", "solve", "est. MiB", "peak MiB"
    );
    for cells in [72usize, 143] {
        let side_m = cells as f64 * POST_M;
        // Photos centred over the block, large enough to see it from each place.
        let gsd = PIX_MM * (Z0 - 50.0) / F_MM;
        let side_px = ((side_m + 260.0) / gsd) as usize;
        let c = side_m / 2.0;
        let sensors = [
            vertical_sensor(GroundM::new(c, c, Z0), F_MM, side_px, PIX_MM),
            vertical_sensor(GroundM::new(c + 120.0, c, Z0), F_MM, side_px, PIX_MM),
            vertical_sensor(GroundM::new(c, c + 120.0, Z0), F_MM, side_px, PIX_MM),
        ];
        let images: Vec<ImageF32> = sensors
            .iter()
            .zip([1.0, 1.2, 0.85])
            .map(|(s, g)| render(s, side_px, g))
            .collect();
        let views: Vec<PhotoView> = sensors
            .iter()
            .zip(&images)
            .map(|(s, i)| PhotoView {
                image: i,
                sensor: s,
            })
            .collect();
        let mpp = (Z0 - 50.0).powi(2) * PIX_MM / (F_MM * 120.0);
        let posts = cells + 1;
        let coarse = Grids {
            x0: 0.0,
            y0: 0.0,
            post_m: POST_M,
            cols: posts,
            rows: posts,
            z: (0..posts * posts)
                .map(|k| {
                    let (x, y) = ((k % posts) as f64 * POST_M, (k / posts) as f64 * POST_M);
                    terrain(x, y) + mpp * (x / 37.0).sin()
                })
                .collect(),
            per_cell: PER_CELL,
        };
        let (gu, gv) = coarse.groundels();
        let n = (gu * gv) as f64;
        // The baseline: every photo sampled at every groundel once.
        let t = Instant::now();
        let mut sum = 0.0;
        for v in 0..gv {
            for u in 0..gu {
                let g = coarse.groundel(u, v);
                let p = GroundM::new(g.x, g.y, coarse.z_at(&g));
                for view in &views {
                    if let Some(q) = view.sensor.ground_to_image(p) {
                        if let Some([a, _, _]) = view.image.bilinear_with_gradient(q.col, q.row) {
                            sum += a;
                        }
                    }
                }
            }
        }
        std::hint::black_box(sum);
        let sampling = t.elapsed().as_secs_f64() / threads as f64;
        let layout = PatchLayout::default();
        let p = OslsmParams {
            converged_m: 0.005 * mpp,
            retest_sight_m: 0.5 * mpp,
            stall_m: 0.05 * mpp,
            ..OslsmParams::default()
        };
        let t = Instant::now();
        let merged = refine_block(&views, &coarse, layout, &p, &Silent).unwrap();
        let secs = t.elapsed().as_secs_f64();
        let iterations: usize = merged.patches.iter().map(|p| p.iterations).sum();
        let patches = merged.patches.len();
        let failed = merged
            .patches
            .iter()
            .filter(|p| p.failure.is_some())
            .count();
        for pr in merged.patches.iter().filter(|p| p.failure.is_some()) {
            eprintln!(
                "  patch at {:?}: {}",
                pr.first,
                pr.failure.as_ref().unwrap()
            );
        }
        // One patch's normal equations in their shape: the posts' band (a groundel's four
        // posts, a curvature row's three, two grid rows apart), the radiometry's border.
        let n_posts = layout.posts * layout.posts;
        let bw = 2 * layout.posts;
        let nu = n_posts + 2 * NR;
        let a = DMatrix::<f64>::from_fn(nu, nu, |i, j| {
            let far = i.abs_diff(j);
            if i == j {
                nu as f64 + 1.0
            } else if i < n_posts && j < n_posts && far > bw {
                0.0
            } else {
                1.0 / (1.0 + far as f64)
            }
        });
        // A factorisation per iteration, the inverse's diagonal per patch (its σ).
        let reps = 5;
        let time = |f: &dyn Fn()| {
            let t = Instant::now();
            for _ in 0..reps {
                f();
            }
            t.elapsed().as_secs_f64() / reps as f64
        };
        let factor = time(&|| {
            std::hint::black_box(BorderedBand::factor(&a, n_posts).unwrap());
        });
        let banded = BorderedBand::factor(&a, n_posts).unwrap();
        let inverse = time(&|| {
            std::hint::black_box(banded.inverse_diagonal());
        });
        let dense_factor = time(&|| {
            std::hint::black_box(a.clone().cholesky().unwrap());
        });
        let chol = a.clone().cholesky().unwrap();
        let dense_inverse = time(&|| {
            std::hint::black_box(chol.inverse());
        });
        let cost = |f: f64, i: f64| f * iterations as f64 + i * patches as f64;
        let solve_share = cost(factor, inverse) / (secs * threads as f64);
        let dense_ratio = cost(dense_factor, dense_inverse) / cost(factor, inverse);
        let per_patch_groundels = ((layout.posts - 1) * PER_CELL).pow(2) as u64;
        let est = memory_bytes(
            n as u64,
            (layout.posts * layout.posts) as u64,
            per_patch_groundels,
            3,
            threads,
        ) as f64
            / (1u64 << 20) as f64;
        // The refined posts against the terrain (a failed patch's keep the coarse model).
        let rms = {
            let (mut s, mut n) = (0.0, 0usize);
            for k in 0..posts * posts {
                if merged.sigma_z[k].is_finite() {
                    let (x, y) = ((k % posts) as f64 * POST_M, (k / posts) as f64 * POST_M);
                    s += (merged.z[k] - terrain(x, y)).powi(2);
                    n += 1;
                }
            }
            (s / n.max(1) as f64).sqrt() / mpp
        };
        println!(
            "{:>10.0} {:>8.1} {:>10.1} {:>6.1} {:>14.1} {:>11.1}% {:>10.0} {:>10.0}   ({patches} patches, {failed} failed, refined posts' RMSE {rms:.3} px; the dense solve {dense_ratio:.0} × the banded one)",
            n,
            secs,
            secs / (n / 1e6),
            iterations as f64 / patches as f64,
            secs / (sampling * iterations as f64 / patches as f64),
            100.0 * solve_share,
            est,
            peak_mib()
        );
        if cells == 143 {
            let big = 1e8;
            let est_big = memory_bytes(
                big as u64,
                (layout.posts * layout.posts) as u64,
                per_patch_groundels,
                3,
                threads,
            ) as f64
                / (1u64 << 20) as f64;
            // Three photos of the block at a ground pixel of groundel / 1.15, 4 bytes each.
            let photos = 3.0 * big * 1.15f64.powi(2) * 4.0 / (1u64 << 20) as f64;
            println!(
                "10 000 × 10 000 groundels: the adjustment's estimate {est_big:.0} MiB + its photos {photos:.0} MiB = {:.0} MiB (limit 4096), about {:.1} h at this rate on {threads} threads",
                est_big + photos,
                secs / (n / 1e6) * 100.0 / 3600.0
            );
        }
    }
}
