//! Least squares on marks of each symmetry (issue 17), on square pixels, against marks drawn
//! here by their own coverage integration (not the rig's template renderer): a ring with a
//! dot, whose rotation and shear nothing determines, and a dot with one line, turned 2°.

mod common;

use common::{gauss, uniform};

use rig::coords::PixelXY;
use rig::digitise::ImageF32;
use rig::targets::measure::scale_rotation;
use rig::targets::{
    match_template, render, Geometry, LsmOptions, MarkShape, Polarity, TemplateSpec,
};

/// A `n`×`n` image of a dark mark (`on(x, y)`, µm about its centre) at `centre` (px, pixel
/// centres at whole numbers + 0.5 as the README's corner origin has them), `px_um` µm square
/// pixels, each pixel's coverage from 20 × 20 samples; grey 200 clear, 50 on the mark, with
/// Gaussian noise σ `noise` DN.
fn draw(
    n: usize,
    centre: [f64; 2],
    px_um: f64,
    on: &dyn Fn(f64, f64) -> bool,
    noise: f64,
    seed: &mut u64,
) -> ImageF32 {
    const S: usize = 20;
    let mut img = ImageF32::new(n, n);
    for r in 0..n {
        for c in 0..n {
            let mut k = 0;
            for j in 0..S {
                for i in 0..S {
                    let x = (c as f64 + (i as f64 + 0.5) / S as f64 - centre[0]) * px_um;
                    let y = (r as f64 + (j as f64 + 0.5) / S as f64 - centre[1]) * px_um;
                    k += on(x, y) as usize;
                }
            }
            let cover = k as f64 / (S * S) as f64;
            img.data[r * n + c] = (200.0 - 150.0 * cover + noise * gauss(seed)) as f32;
        }
    }
    img
}

struct Run {
    converged: usize,
    /// The mark's rotation in the image, degrees, per converged trial.
    rotations: Vec<f64>,
    errors: Vec<f64>,
    /// True error / σ, per axis.
    ratios: Vec<f64>,
}

fn run(
    shape: &MarkShape,
    on: &dyn Fn(f64, f64) -> bool,
    geometry: Geometry,
    trials: usize,
    noise: f64,
) -> Run {
    let px = 10.0;
    let tpl = render(
        shape,
        &TemplateSpec {
            size: 71,
            um_per_px: [[px, 0.0], [0.0, px]],
            blur_px: 0.0,
            polarity: Polarity::DarkOnClear,
            fine: true,
        },
    );
    let opt = LsmOptions {
        geometry,
        ..LsmOptions::default()
    };
    let mut seed = 7u64;
    let mut out = Run {
        converged: 0,
        errors: Vec::new(),
        ratios: Vec::new(),
        rotations: Vec::new(),
    };
    for _ in 0..trials {
        let centre = [60.0 + uniform(&mut seed), 60.0 + uniform(&mut seed)];
        let img = draw(121, centre, px, on, noise, &mut seed);
        // A start as coarse location leaves it: within half a pixel.
        let start = PixelXY::new(
            centre[0] + uniform(&mut seed) - 0.5,
            centre[1] + uniform(&mut seed) - 0.5,
        );
        if let Ok(m) = match_template(&img, &tpl, start, &opt) {
            out.converged += 1;
            let e = [m.centre.col - centre[0], m.centre.row - centre[1]];
            out.errors.push(e[0].hypot(e[1]));
            if std::env::var_os("MARK_DEBUG").is_some() {
                eprintln!(
                    "{:+.4} {:+.4}  σ {:.4} {:.4}",
                    e[0], e[1], m.sigma_px[0], m.sigma_px[1]
                );
            }
            if let Some((_, rot)) = scale_rotation(&m, [[px, 0.0], [0.0, px]]) {
                out.rotations.push(rot);
            }
            out.ratios.push(e[0] / m.sigma_px[0]);
            out.ratios.push(e[1] / m.sigma_px[1]);
        }
    }
    out
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// A ring with a dot on square pixels: with shifts and scale only, every trial converges to
/// within a few thousandths of a pixel; with the full affine the rotation and shear are free.
#[test]
fn a_ring_converges_with_shifts_and_scale() {
    let shape = MarkShape::ring_with_dot(300.0, 40.0, 40.0);
    assert_eq!(shape.geometry(), Geometry::ShiftScale);
    let on = |x: f64, y: f64| {
        let r = x.hypot(y);
        r <= 40.0 || (r - 300.0).abs() <= 20.0
    };
    let n = 60;
    let ring = run(&shape, &on, Geometry::ShiftScale, n, 2.0);
    let affine = run(&shape, &on, Geometry::Affine, n, 2.0);
    eprintln!(
        "ring, shifts + scale: {}/{n} converged, RMSE {:.4} px, RMS(error/σ) {:.2}; full affine: {}/{n}",
        ring.converged,
        rms(&ring.errors),
        rms(&ring.ratios),
        affine.converged
    );
    assert_eq!(ring.converged, n);
    assert!(rms(&ring.errors) < 0.01, "RMSE {}", rms(&ring.errors));
    // The σ is honest; the free rotation and shear of the full affine lose trials.
    assert!(
        (0.7..1.4).contains(&rms(&ring.ratios)),
        "{}",
        rms(&ring.ratios)
    );
    assert!(affine.converged < n, "{}", affine.converged);
}

/// A dot with one line, turned 2° in the image: shifts, scale and rotation find it.
#[test]
fn a_dot_with_a_line_converges_with_a_rotation() {
    let shape = MarkShape::dot_with_line(60.0, 40.0, 150.0, 320.0, [0.0, -1.0]);
    assert_eq!(shape.geometry(), Geometry::Similarity);
    let (s, c) = 2f64.to_radians().sin_cos();
    let on = move |x: f64, y: f64| {
        // The mark turned by 2°: a point of the image is the mark's point turned back.
        let (u, v) = (c * x + s * y, -s * x + c * y);
        shape_on(u, v)
    };
    fn shape_on(u: f64, v: f64) -> bool {
        u.hypot(v) <= 60.0 || (u.abs() <= 20.0 && (150.0..=320.0).contains(&-v))
    }
    let n = 40;
    let r = run(&shape, &on, Geometry::Similarity, n, 2.0);
    eprintln!(
        "dot with line, similarity: {}/{n} converged, RMSE {:.4} px, RMS(error/σ) {:.2}",
        r.converged,
        rms(&r.errors),
        rms(&r.ratios)
    );
    assert_eq!(r.converged, n);
    assert!(rms(&r.errors) < 0.01, "RMSE {}", rms(&r.errors));
    assert!((0.7..1.4).contains(&rms(&r.ratios)), "{}", rms(&r.ratios));
    // The rotation found is the 2° the mark was drawn turned by.
    for rot in &r.rotations {
        assert!((rot - 2.0).abs() < 0.2, "rotation {rot}°");
    }
}
