//! The object-space matching against scenes whose terrain, reflectance and radiometry are
//! known: vertical photos rendered here by intersecting each pixel's rays with the terrain
//! (independently of the matcher's back-mapping), each pixel the mean of 3 × 3 rays.

use super::*;
use crate::coords::{GroundM, PixelXY};
use crate::geometry::{FrameSensor, Sensor};
use crate::image::ImageF32;
use crate::matching::block::orient::vertical_sensor;
use crate::matching::methods::oslsm::solve::MAX_UNKNOWNS;

const F_MM: f64 = 153.0;
const PIX_MM: f64 = 0.1;
const Z0: f64 = 1000.0;
const SIDE: usize = 400;

fn camera(x0: f64, y0: f64) -> FrameSensor {
    vertical_sensor(GroundM::new(x0, y0, Z0), F_MM, SIDE, PIX_MM)
}

/// Reflectance: waves of 3-12 m (5-20 px at 0.6 m on the ground) in several directions.
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

/// A photo of terrain `t` with reflectance `r`, grey = offset + gain·r.
fn render(s: &FrameSensor, t: &dyn Fn(f64, f64) -> f64, radiometry: [f64; 2]) -> ImageF32 {
    render_with(s, t, &reflectance, radiometry)
}

/// A photo of terrain `t` with reflectance `refl`, grey = offset + gain·refl.
fn render_with(
    s: &FrameSensor,
    t: &dyn Fn(f64, f64) -> f64,
    refl: &dyn Fn(f64, f64) -> f64,
    radiometry: [f64; 2],
) -> ImageF32 {
    let mut img = ImageF32::new(SIDE, SIDE);
    let k = 3;
    for row in 0..SIDE {
        for col in 0..SIDE {
            let mut v = 0.0;
            for j in 0..k {
                for i in 0..k {
                    let q = PixelXY::new(
                        col as f64 + (i as f64 + 0.5) / k as f64,
                        row as f64 + (j as f64 + 0.5) / k as f64,
                    );
                    // The ray meets the terrain where z = t(P(z)): fixed point.
                    let mut z = t(0.0, 0.0);
                    let mut g = s.image_to_ground(q, z).unwrap();
                    for _ in 0..30 {
                        let next = t(g.x, g.y);
                        let done = (next - z).abs() < 1e-7;
                        z = next;
                        g = s.image_to_ground(q, z).unwrap();
                        if done {
                            break;
                        }
                    }
                    v += refl(g.x, g.y);
                }
            }
            img.data[row * SIDE + col] =
                (radiometry[0] + radiometry[1] * v / (k * k) as f64) as f32;
        }
    }
    img
}

/// Posts every `post_m` over [x0, x0 + (cols−1)·post_m] × [y0, …] at heights `z(x, y)`.
fn grids(x0: f64, y0: f64, cols: usize, post_m: f64, z: &dyn Fn(f64, f64) -> f64) -> Grids {
    let zs = (0..cols)
        .flat_map(|j| (0..cols).map(move |i| (i, j)))
        .map(|(i, j)| z(x0 + i as f64 * post_m, y0 + j as f64 * post_m))
        .collect();
    Grids {
        x0,
        y0,
        post_m,
        cols,
        rows: cols,
        z: zs,
        per_cell: 8,
    }
}

/// Height per pixel of x-parallax for base `b` at height z: (Z₀ − z)²·pix/(f·B).
fn m_per_px(b: f64, z: f64) -> f64 {
    (Z0 - z).powi(2) * PIX_MM / (F_MM * b)
}

fn views<'a>(s: &'a [FrameSensor], t: &'a [ImageF32]) -> Vec<PhotoView<'a>> {
    s.iter()
        .zip(t)
        .map(|(s, t)| PhotoView {
            image: t,
            sensor: s,
        })
        .collect()
}

/// Flat terrain at 50 m, a coarse DEM a quarter of a pixel of parallax off (1.2 m): the
/// first (Gauss–Newton) step lands on the plane within 5 % of the offset (what is left is
/// the texture's curvature over the quarter pixel), and the run ends within 0.03 px of
/// parallax RMS; the reflectance is the true one (photo 0's gain 1, offset 0).
#[test]
fn a_flat_terrain_converges_in_one_step_to_the_truth() {
    let flat = |_: f64, _: f64| 50.0;
    let sensors = [camera(0.0, 0.0), camera(120.0, 0.0), camera(0.0, 120.0)];
    let images: Vec<ImageF32> = sensors
        .iter()
        .map(|s| render(s, &flat, [0.0, 1.0]))
        .collect();
    let mpp = m_per_px(120.0, 50.0);
    let offset = 0.25 * mpp;
    let g = grids(30.0, 20.0, 7, 5.0, &|_, _| 50.0 + offset);
    let r = refine(&views(&sensors, &images), &g, &OslsmParams::default()).unwrap();
    let first = r.iterations[0];
    assert!(
        (first.rms_move_m - offset).abs() < 0.05 * offset,
        "first step {:.4} m of {offset:.4} m",
        first.rms_move_m
    );
    let rms = (r.z.iter().map(|z| (z - 50.0).powi(2)).sum::<f64>() / r.z.len() as f64).sqrt();
    let max = r.z.iter().map(|z| (z - 50.0).abs()).fold(0.0, f64::max);
    eprintln!(
        "flat: first step {:.3} of {offset:.3} m, then {:?} m; RMS {:.4} px, max {:.4} px of parallax",
        first.rms_move_m,
        r.iterations[1..].iter().map(|i| i.rms_move_m).collect::<Vec<_>>(),
        rms / mpp,
        max / mpp
    );
    // What is left is resampling: bilinear interpolation shifts a 5-px wave by a phase that
    // depends on where each photo's pixels fall.
    assert!(
        rms < 0.03 * mpp && max < 0.06 * mpp,
        "RMS {rms:.3} m, max {max:.3} m"
    );
    // The reflectance: each groundel's D against the truth at its centre, in photo 0's grey
    // values (its offset 0 and gain 1): the same mean, and the pattern (pixels and bilinear
    // sampling damp the 5-px waves by a few per cent, not their places).
    let (gu, gv) = g.groundels();
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for v in 0..gv {
        for u in 0..gu {
            let gr = g.groundel(u, v);
            a.push(r.d[v * gu + u]);
            b.push(reflectance(gr.x, gr.y));
        }
    }
    let mean = |x: &[f64]| x.iter().sum::<f64>() / x.len() as f64;
    let corr = crate::correlation::ncc(&a, &b);
    assert!(corr > 0.99, "reflectance correlation {corr:.4}");
    assert!(
        (mean(&a) - mean(&b)).abs() < 0.5,
        "{} vs {}",
        mean(&a),
        mean(&b)
    );
}

/// White noise of standard deviation `sigma` added to every pixel of `img` (xorshift and
/// Box–Muller, seeded).
fn add_noise(img: &mut ImageF32, sigma: f64, seed: u64) {
    let mut s = seed | 1;
    let mut uniform = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    for v in img.data.iter_mut() {
        let (a, b) = (uniform().max(1e-300), uniform());
        *v += (sigma * (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()) as f32;
    }
}

/// [`solve::noise_gains`] against Monte Carlo: bilinear samples and slopes of a white-noise
/// image of unit variance, at fixed fractions within the pixel, on pixels far enough apart
/// to be independent.
#[test]
fn noise_gains_match_sampled_noise() {
    let n = 600;
    let mut img = ImageF32::new(n, n);
    add_noise(&mut img, 1.0, 0x9E37_79B9_7F4A_7C15);
    for (fx, fy, dc, dr) in [
        (0.0, 0.0, 1.0, 0.0),
        (0.5, 0.5, 0.6, 0.8),
        (0.2, 0.7, -0.3, 1.1),
    ] {
        let (mut g2, mut d2, mut count) = (0.0, 0.0, 0.0);
        for j in (2..n - 3).step_by(3) {
            for i in (2..n - 3).step_by(3) {
                let (x, y) = (i as f64 + 0.5 + fx, j as f64 + 0.5 + fy);
                let [g, gx, gy] = img.bilinear_with_gradient(x, y).unwrap();
                g2 += g * g;
                d2 += (gx * dc + gy * dr).powi(2);
                count += 1.0;
            }
        }
        let [want_g, want_dz] = solve::noise_gains(100.5 + fx, 100.5 + fy, [dc, dr]);
        let (got_g, got_dz) = (g2 / count, d2 / count);
        // About 39 000 samples: each variance within 3 % (four standard errors).
        assert!(
            (got_g / want_g - 1.0).abs() < 0.03,
            "{fx},{fy}: value {got_g} for {want_g}"
        );
        assert!(
            (got_dz / want_dz - 1.0).abs() < 0.03,
            "{fx},{fy}: slope {got_dz} for {want_dz}"
        );
    }
}

/// The texture's share of the posts' information on flat ground seen by two photos with 2
/// grey values of noise, for the test scene's texture (waves of 15) and for one 0.3 as
/// strong: the noise's share of the slopes' power stays, the texture's falls with the
/// amplitude squared, so the odds s/(1 − s) must fall by 0.3² = 0.09 (within a third: the
/// noise's part is estimated from the residuals). The posts start on the truth; their σ is
/// printed, not judged here (bilinear resampling leaves errors of a few hundredths of a
/// pixel that do not fall with the noise).
#[test]
fn sigma_counts_the_texture_not_the_noise() {
    let flat = |_: f64, _: f64| 50.0;
    let sensors = [camera(0.0, 0.0), camera(120.0, 0.0)];
    let mpp = m_per_px(120.0, 50.0);
    let mut shares = Vec::new();
    for (what, amplitude) in [("strong", 1.0), ("faint", 0.3)] {
        let texture = |x: f64, y: f64| 100.0 + amplitude * (reflectance(x, y) - 100.0);
        let mut ratio2 = 0.0;
        let mut n = 0.0;
        let mut share = 0.0;
        let mut sigma2 = 0.0;
        let clean: Vec<ImageF32> = sensors
            .iter()
            .map(|s| render_with(s, &flat, &texture, [0.0, 1.0]))
            .collect();
        for seed in 1..=4u64 {
            let images: Vec<ImageF32> = clean
                .iter()
                .enumerate()
                .map(|(k, img)| {
                    let mut img = img.clone();
                    add_noise(&mut img, 2.0, seed * 7919 + k as u64);
                    img
                })
                .collect();
            let g = grids(30.0, 20.0, 7, 5.0, &flat);
            let r = refine(&views(&sensors, &images), &g, &OslsmParams::default()).unwrap();
            share += r.signal_share / 4.0;
            for (z, s) in r.z.iter().zip(&r.sigma_z) {
                ratio2 += ((z - 50.0) / s).powi(2);
                sigma2 += s * s;
                n += 1.0;
            }
        }
        let ratio = (ratio2 / n).sqrt();
        eprintln!(
            "{what} texture: share {share:.3}, RMS σ {:.4} px, RMS(error/σ) {ratio:.2}",
            (sigma2 / n).sqrt() / mpp
        );
        shares.push(share);
    }
    assert!(shares[0] > 0.9, "strong texture: share {:.3}", shares[0]);
    let odds = |s: f64| s / (1.0 - s);
    let fall = odds(shares[1]) / odds(shares[0]);
    assert!(
        (0.06..0.12).contains(&fall),
        "the odds fell by {fall:.3} for 0.09: shares {shares:?}"
    );
}

/// A hill 8 m high on a plane at 50 m.
fn hill(x: f64, y: f64) -> f64 {
    50.0 + 8.0 * (-((x - 55.0).powi(2) + (y - 45.0).powi(2)) / 600.0).exp()
}

/// Offset and gain of each photo of [`hill_block`].
const PLANTED: [[f64; 2]; 3] = [[0.0, 1.0], [10.0, 1.25], [-8.0, 0.8]];

/// The hill from three places, each photo with its planted radiometry.
fn hill_block() -> ([FrameSensor; 3], Vec<ImageF32>) {
    let sensors = [camera(0.0, 0.0), camera(120.0, 0.0), camera(0.0, 120.0)];
    let images = sensors
        .iter()
        .zip(PLANTED)
        .map(|(s, rad)| render(s, &hill, rad))
        .collect();
    (sensors, images)
}

/// Photos with different radiometry (gains 1.25 and 0.8, offsets +10 and −8 grey values on a
/// range of about 150) over a hill, from a coarse DEM three pixels of parallax off in the
/// mean and tilted: the gains come back within 1 %, the offsets within 1 % of the range, the
/// heights within a tenth of a pixel of parallax, the reflectance correlates with the truth
/// at 0.98 or more.
#[test]
fn planted_gains_and_a_hill_are_recovered() {
    let truth = PLANTED;
    let (sensors, images) = hill_block();
    let mpp = m_per_px(120.0, 50.0);
    let mut g = grids(30.0, 20.0, 11, 5.0, &|x, _| {
        50.0 + 3.0 * mpp + 0.05 * (x - 55.0)
    });
    // Groundels of 0.71 m against pixels of 0.62 m on the ground: with 8 to a cell (0.625 m)
    // they would fall on photo 0's pixel grid at one phase, and bilinear sampling would damp
    // the datum photo's texture less than the others' (gains 1 % off; 0.04 % at 7).
    g.per_cell = 7;
    let r = refine(&views(&sensors, &images), &g, &OslsmParams::default()).unwrap();
    for k in 1..3 {
        let [a, b] = r.radiometry[k];
        assert!(
            (b - truth[k][1]).abs() < 0.01 * truth[k][1],
            "photo {k}: gain {b:.4} against {}",
            truth[k][1]
        );
        assert!(
            (a - truth[k][0]).abs() < 1.5,
            "photo {k}: offset {a:.2} against {}",
            truth[k][0]
        );
    }
    let mut e2 = 0.0;
    for j in 0..g.rows {
        for i in 0..g.cols {
            let (x, y) = (g.x0 + i as f64 * g.post_m, g.y0 + j as f64 * g.post_m);
            e2 += (r.z[j * g.cols + i] - hill(x, y)).powi(2);
        }
    }
    let rmse = (e2 / r.z.len() as f64).sqrt();
    eprintln!(
        "hill: gains {:?}, RMSE {:.4} px of parallax, {} iterations",
        r.radiometry,
        rmse / mpp,
        r.iterations.len()
    );
    assert!(rmse < 0.1 * mpp, "RMSE {rmse:.3} m = {:.3} px", rmse / mpp);
    let (gu, gv) = g.groundels();
    let pairs: Vec<(f64, f64)> = (0..gv)
        .flat_map(|v| (0..gu).map(move |u| (u, v)))
        .filter_map(|(u, v)| {
            let gr = g.groundel(u, v);
            let d = r.d[v * gu + u];
            d.is_finite().then(|| (d, reflectance(gr.x, gr.y)))
        })
        .collect();
    let a: Vec<f64> = pairs.iter().map(|p| p.0).collect();
    let b: Vec<f64> = pairs.iter().map(|p| p.1).collect();
    let corr = crate::correlation::ncc(&a, &b);
    eprintln!("hill: reflectance correlation {corr:.4}");
    assert!(corr >= 0.98, "reflectance correlation {corr:.4}");
}

/// A wall 40 m high along x = 60 m: a photo from the east (camera at x = 400 m) cannot see
/// the ground just west of it, the vertical photo above it can; the groundel there takes an
/// observation from the one and not from the other.
#[test]
fn an_occluded_groundel_takes_no_observation() {
    let wall = |x: f64, _: f64| {
        if (58.0..=62.0).contains(&x) {
            90.0
        } else {
            50.0
        }
    };
    let g = grids(30.0, 20.0, 25, 2.0, &wall);
    let terrain = Occluder::new(&g);
    let behind = GroundM::new(55.0, 30.0, 50.0);
    let east = camera(400.0, 0.0);
    let above = camera(55.0, 30.0);
    assert!(!terrain.sees(&east, behind));
    assert!(terrain.sees(&above, behind));
    // In front of the wall (east of it) the eastern photo sees the ground.
    assert!(terrain.sees(&east, GroundM::new(70.0, 30.0, 50.0)));
    // What the adjustment takes its observations from: groundel (u, v) = (100, 40) is
    // centred at (55.125, 30.125), behind the wall from the east; (160, 40) in front.
    let blank = ImageF32::new(SIDE, SIDE);
    let sensors = [above, east];
    let images = [blank.clone(), blank];
    let gr = g.groundel(100, 40);
    assert!(
        (gr.x - 55.125).abs() < 1e-9 && (gr.y - 30.125).abs() < 1e-9,
        "{gr:?}"
    );
    let s = sight(&views(&sensors, &images), &g, &[gr, g.groundel(160, 40)]);
    assert_eq!(s, vec![vec![true, false], vec![true, true]]);
}

/// The march's long steps against a dense one (a fiftieth of a groundel, every sample
/// tested) on steep, bumpy terrain seen from five sides: every groundel the march hides is
/// hidden (its samples lie on the ray), and it misses at most a few thin grazes.
#[test]
fn the_long_stepped_march_agrees_with_a_dense_one() {
    let bumps = |x: f64, y: f64| 50.0 + 15.0 * (x / 7.0).sin() * (y / 5.0).cos() + 0.2 * x;
    let g = grids(0.0, 0.0, 25, 2.0, &bumps);
    let terrain = Occluder::new(&g);
    let top = g.z.iter().copied().fold(f64::MIN, f64::max);
    let gm = g.groundel_m();
    let dense = |s: &FrameSensor, p: GroundM| -> bool {
        let q = s.ground_to_image(p).unwrap();
        let (a, b) = (
            s.image_to_ground(q, p.z).unwrap(),
            s.image_to_ground(q, p.z + 1.0).unwrap(),
        );
        let (dx, dy) = (b.x - a.x, b.y - a.y);
        let lean = dx.hypot(dy);
        let mut dz = gm / lean;
        while p.z + dz <= top {
            match g.z_xy(p.x + dx * dz, p.y + dy * dz) {
                Some(t) if t > p.z + dz => return false,
                Some(_) => dz += gm / 50.0 / lean,
                None => return true,
            }
        }
        true
    };
    let (mut hidden, mut missed, mut n) = (0, 0, 0);
    for s in [
        camera(24.0, 24.0),
        camera(424.0, 24.0),
        camera(-376.0, 24.0),
        camera(24.0, 424.0),
        camera(300.0, -300.0),
    ] {
        for v in (0..192).step_by(5) {
            for u in (0..192).step_by(5) {
                let gr = g.groundel(u, v);
                let p = GroundM::new(gr.x, gr.y, g.z_at(&gr));
                let (fast, slow) = (terrain.sees(&s, p), dense(&s, p));
                assert!(fast || !slow, "{p:?}: hidden by the march, seen densely");
                missed += usize::from(fast && !slow);
                hidden += usize::from(!slow);
                n += 1;
            }
        }
    }
    eprintln!(
        "{n} rays: {hidden} hidden by the dense march, {missed} of them missed by the long steps"
    );
    assert!(
        hidden > n / 50,
        "the terrain hides too little to test: {hidden} of {n}"
    );
    assert!(
        missed * 100 <= hidden,
        "{missed} of {hidden} hidden groundels missed"
    );
}

/// The hill of the planted-gains test refined in four overlapping patches of 7 × 7 posts
/// (2 shared) and merged: every patch converges with the planted gains (within 2 %: a patch
/// sees less texture), and the merged heights are as good as one patch's over the whole
/// (within a tenth of a pixel of parallax, no step where the patches meet).
#[test]
fn patches_merge_without_a_seam() {
    let truth = PLANTED;
    let (sensors, images) = hill_block();
    let mpp = m_per_px(120.0, 50.0);
    let mut g = grids(30.0, 20.0, 12, 5.0, &|x, _| {
        50.0 + 2.0 * mpp + 0.05 * (x - 55.0)
    });
    g.per_cell = 7;
    let layout = PatchLayout {
        posts: 7,
        overlap: 2,
    };
    let m = refine_block(
        &views(&sensors, &images),
        &g,
        layout,
        &OslsmParams::default(),
        &crate::matching::progress::Silent,
    )
    .unwrap();
    assert_eq!(m.patches.len(), 4, "{:?}", m.patches);
    for pr in &m.patches {
        assert!(pr.failure.is_none(), "{pr:?}");
        let rad: Vec<[f64; 2]> = pr
            .radiometry
            .as_ref()
            .unwrap()
            .iter()
            .map(|r| r.expect("every photo sees every patch"))
            .collect();
        for k in 1..3 {
            assert!(
                (rad[k][1] - truth[k][1]).abs() < 0.02 * truth[k][1],
                "{pr:?}"
            );
        }
    }
    let errors: Vec<f64> = (0..g.rows)
        .flat_map(|j| (0..g.cols).map(move |i| (i, j)))
        .map(|(i, j)| {
            let (x, y) = (g.x0 + i as f64 * g.post_m, g.y0 + j as f64 * g.post_m);
            m.z[j * g.cols + i] - hill(x, y)
        })
        .collect();
    let rmse = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
    let max = errors.iter().map(|e| e.abs()).fold(0.0, f64::max);
    eprintln!(
        "patches: RMSE {:.4} px, max {:.4} px of parallax",
        rmse / mpp,
        max / mpp
    );
    assert!(
        rmse < 0.1 * mpp && max < 0.25 * mpp,
        "RMSE {rmse:.3} m, max {max:.3} m"
    );
    assert!(m.sigma_z.iter().all(|s| s.is_finite() && *s > 0.0));
}

/// A patch too large for a dense normal matrix is refused before anything is allocated.
#[test]
fn a_patch_too_large_is_refused_up_front() {
    let sensors = [camera(0.0, 0.0), camera(120.0, 0.0)];
    let blank = ImageF32::new(8, 8);
    let images = [blank.clone(), blank];
    let g = Grids {
        x0: 0.0,
        y0: 0.0,
        post_m: 1.0,
        cols: 100_000,
        rows: 100_000,
        z: Vec::new(),
        per_cell: 1,
    };
    match refine(&views(&sensors, &images), &g, &OslsmParams::default()) {
        Err(OslsmError::TooBig { unknowns, .. }) => assert!(unknowns > MAX_UNKNOWNS),
        other => panic!("{other:?}"),
    }
}

/// Fields: reflectance steps of 25 along curved borders 20-60 m apart, nothing inside them
/// (weak texture: only the borders carry a match).
fn fields(x: f64, y: f64) -> f64 {
    let v = (x / 23.0).sin()
        + 1.3 * (y / 31.0 + 0.3 * (x / 17.0).sin()).sin()
        + 0.5 * ((x + y) / 41.0).cos();
    100.0 + 25.0 * (2.0 * v).floor()
}

/// The feature route's line pairs over a diagonal base: the epipolar lines run along the
/// base's image (the closed form for two vertical photos at one height), and a ground point
/// at any height on a reference sample's ray projects onto the conjugate line (within
/// 0.001 px), where `intersect` finds its height again (within 1 mm).
#[test]
fn line_pairs_are_conjugate_at_every_height() {
    use crate::matching::methods::oslsm::coarse_features::{intersect, line_pairs};
    let (a, b) = (camera(0.0, 0.0), camera(120.0, 60.0));
    let img = ImageF32::new(SIDE, SIDE);
    let (va, vb) = (
        PhotoView {
            image: &img,
            sensor: &a,
        },
        PhotoView {
            image: &img,
            sensor: &b,
        },
    );
    let h = [-20.0, 60.0];
    let lines = line_pairs(va, vb, h, 10.0);
    assert!(lines.len() > 20, "{} lines", lines.len());
    // The base (120, 60) m appears in the image as (120, −60) px-wise (rows run south).
    let base = [120.0f64, -60.0];
    let nb = base[0].hypot(base[1]);
    let mut worst: [f64; 3] = [0.0; 3];
    for lp in &lines {
        let n = lp.reference.len();
        let (q0, q1) = (lp.reference[0], lp.reference[n - 1]);
        let d = [q1.col - q0.col, q1.row - q0.row];
        let cross = (d[0] * base[1] - d[1] * base[0]) / (d[0].hypot(d[1]) * nb);
        worst[0] = worst[0].max(cross.abs());
        // Away from the ends, where a point at another height falls beyond the run.
        for i in (40..n.saturating_sub(40)).step_by(37) {
            for z in [-15.0, 5.0, 33.0, 55.0] {
                let g = a.image_to_ground(lp.reference[i], z).unwrap();
                let p = b.ground_to_image(g).unwrap();
                // Distance from the conjugate polyline's segment nearest p.
                let off = lp
                    .other
                    .windows(2)
                    .map(|w| {
                        let (u, v) = (w[0], w[1]);
                        let (dx, dy) = (v.col - u.col, v.row - u.row);
                        let t = (((p.col - u.col) * dx + (p.row - u.row) * dy)
                            / (dx * dx + dy * dy))
                            .clamp(0.0, 1.0);
                        (p.col - u.col - t * dx).hypot(p.row - u.row - t * dy)
                    })
                    .fold(f64::INFINITY, f64::min);
                worst[1] = worst[1].max(off);
                let (u, v) = (lp.other[i], lp.other[i + 1]);
                let l = (v.col - u.col).hypot(v.row - u.row);
                let dir = [(v.col - u.col) / l, (v.row - u.row) / l];
                let zz = intersect(va, vb, lp.reference[i], p, dir, 20.0).unwrap();
                worst[2] = worst[2].max((zz - z).abs());
            }
        }
    }
    eprintln!(
        "direction {:.2e}, off the line {:.2e} px, height {:.2e} m",
        worst[0], worst[1], worst[2]
    );
    assert!(
        worst[0] < 1e-6,
        "lines off the base's direction by {:.2e}",
        worst[0]
    );
    assert!(
        worst[1] < 1e-3,
        "a point {:.2e} px off its conjugate line",
        worst[1]
    );
    assert!(worst[2] < 1e-3, "a height {:.2e} m off", worst[2]);
}

/// The feature route on weak texture (fields with nothing inside them) over a hill on a
/// slope, photos with a gain and offset between them: the borders' edges, matched as
/// strings, give the terrain within half a pixel of parallax RMS (the closed form
/// f·B/(H²·pixel) for two vertical photos) at most nodes of an 8 m grid over the photos' overlap.
#[test]
fn the_feature_route_finds_the_terrain_from_field_borders() {
    use crate::matching::grid::ElevationGrid;
    use crate::matching::methods::oslsm::coarse_features::feature_grid;
    let terrain = |x: f64, y: f64| 20.0 + 0.05 * x + 12.0 * (-(x * x + y * y) / 6400.0).exp();
    let (a, b) = (camera(0.0, 0.0), camera(120.0, 60.0));
    let (ia, ib) = (
        render_with(&a, &terrain, &fields, [0.0, 1.0]),
        render_with(&b, &terrain, &fields, [10.0, 1.2]),
    );
    let (va, vb) = (
        PhotoView {
            image: &ia,
            sensor: &a,
        },
        PhotoView {
            image: &ib,
            sensor: &b,
        },
    );
    let px_per_m = F_MM * 1e-3 * 120f64.hypot(60.0) / ((Z0 - 25.0).powi(2) * PIX_MM * 1e-3);
    let m_per_px = 1.0 / px_per_m;
    let mut g = ElevationGrid::covering([0.0, -60.0, 120.0, 120.0], 8.0, 64).unwrap();
    let rep = feature_grid(
        va,
        &[(vb, "2".to_string())],
        [-20.0, 60.0],
        &mut g,
        3.0 * m_per_px,
        &crate::matching::progress::Silent,
    );
    let c = g.compare(terrain);
    eprintln!(
        "{} points, {} rejected, {} nodes of {}: RMSE {:.2} m = {:.3} px, max {:+.2} / {:+.2} m",
        rep.points,
        rep.rejected,
        rep.nodes,
        g.z.len(),
        c.rmse_m,
        c.rmse_m / m_per_px,
        c.max_positive_m,
        c.max_negative_m
    );
    assert!(
        rep.nodes * 2 >= g.z.len(),
        "only {} of {} nodes",
        rep.nodes,
        g.z.len()
    );
    assert!(
        c.rmse_m / m_per_px <= 0.5,
        "RMSE {:.3} px",
        c.rmse_m / m_per_px
    );
}
