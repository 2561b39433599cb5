//! The convergence plot of an object-space run: each patch's RMS post movement per iteration
//! (pixels of parallax, logarithmic) and its σ₀ (grey values), so that a person sees at a
//! glance whether every patch settled, and how fast.

use crate::matching::methods::oslsm::patches::PatchReport;
use crate::picture::{fill, frame, line, save_png, text, text_width, trim};
use image::{Rgb, RgbImage};
use std::path::Path;

const W: u32 = 1100;
const H: u32 = 560;
const BLACK: Rgb<u8> = Rgb([0, 0, 0]);
const GREY: Rgb<u8> = Rgb([200, 200, 200]);
/// One panel: left edge, top, width, height.
const PANELS: [[f64; 4]; 2] = [[110.0, 100.0, 400.0, 360.0], [660.0, 100.0, 400.0, 360.0]];

/// Writes the plot of `patches` (failed ones left out, counted in the title) to `path`;
/// movements in metres are shown as pixels of parallax through `m_per_px`.
pub fn convergence_plot(
    patches: &[PatchReport],
    m_per_px: f64,
    converged_px: f64,
    path: &Path,
) -> std::io::Result<()> {
    let mut img = RgbImage::from_pixel(W, H, Rgb([255, 255, 255]));
    let ok: Vec<&PatchReport> = patches.iter().filter(|p| !p.history.is_empty()).collect();
    let failed = patches.iter().filter(|p| p.failure.is_some()).count();
    let most = ok.iter().map(|p| p.history.len()).max().unwrap_or(1).max(2);
    text(
        &mut img,
        20,
        16,
        &format!(
            "Convergence of {} patches{}",
            ok.len(),
            if failed > 0 {
                format!(" ({failed} failed: see report.json)")
            } else {
                String::new()
            }
        ),
        3,
        BLACK,
    );
    let titles = ["RMS move, px of parallax", "sigma0, grey values"];
    // Panel 0: log10 of the move, from the converged threshold / 10 up to the largest.
    let moves = |p: &PatchReport| -> Vec<f64> {
        p.history
            .iter()
            .map(|i| (i.rms_move_m / m_per_px).max(1e-6).log10())
            .collect()
    };
    let s0 = |p: &PatchReport| -> Vec<f64> { p.history.iter().map(|i| i.sigma0).collect() };
    let series: [Vec<Vec<f64>>; 2] = [
        ok.iter().map(|p| moves(p)).collect(),
        ok.iter().map(|p| s0(p)).collect(),
    ];
    for (k, ([x0, y0, w, h], title)) in PANELS.iter().zip(titles).enumerate() {
        frame(
            &mut img,
            *x0 as i64,
            *y0 as i64,
            *w as i64 + 1,
            *h as i64 + 1,
            BLACK,
        );
        text(&mut img, *x0 as i64, *y0 as i64 - 26, title, 2, BLACK);
        let all = series[k]
            .iter()
            .flatten()
            .copied()
            .filter(|v| v.is_finite());
        let (mut lo, mut hi) = all.fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(v), b.max(v)));
        if k == 0 {
            lo = lo.min((converged_px / 10.0).log10()).floor();
            hi = hi.max(converged_px.log10()).ceil();
        } else {
            lo = 0.0;
            hi = if hi > 0.0 { hi * 1.1 } else { 1.0 };
        }
        if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
            hi = lo + 1.0;
        }
        let at = |i: usize, v: f64| {
            [
                x0 + (i as f64) / (most - 1) as f64 * w,
                y0 + h - (v - lo) / (hi - lo) * h,
            ]
        };
        // Ticks: iterations along x, values (decades on the log panel) along y.
        for i in 0..most {
            let [x, _] = at(i, lo);
            fill(&mut img, x as i64, (y0 + h) as i64, 2, 6, BLACK);
            let l = format!("{}", i + 1);
            text(
                &mut img,
                x as i64 - text_width(&l, 2) / 2,
                (y0 + h) as i64 + 10,
                &l,
                2,
                BLACK,
            );
        }
        // Decades on the logarithmic panel (its bounds are whole), fifths on the other.
        let ticks = if k == 0 {
            (hi - lo).round().max(1.0) as usize
        } else {
            5
        };
        for t in 0..=ticks {
            let v = lo + (hi - lo) * t as f64 / ticks as f64;
            let [_, y] = at(0, v);
            line(&mut img, [*x0, y], [x0 + w, y], GREY);
            let l = if k == 0 {
                let e = v.round() as i32;
                if e >= -3 {
                    trim(10f64.powi(e))
                } else {
                    format!("1e{e}")
                }
            } else {
                trim(crate::picture::significant(v, 3))
            };
            text(
                &mut img,
                *x0 as i64 - text_width(&l, 2) - 8,
                y as i64 - 8,
                &l,
                2,
                BLACK,
            );
        }
        if k == 0 {
            let [_, y] = at(0, converged_px.log10());
            line(&mut img, [*x0, y], [x0 + w, y], Rgb([200, 40, 40]));
        }
        for (n, s) in series[k].iter().enumerate() {
            let c = crate::picture::sequential(n as f64 / ok.len().max(2) as f64 * 0.8 + 0.1);
            for (i, pair) in s.windows(2).enumerate() {
                line(&mut img, at(i, pair[0]), at(i + 1, pair[1]), c);
            }
        }
        text(
            &mut img,
            (x0 + w / 2.0) as i64 - 40,
            (y0 + h) as i64 + 34,
            "iteration",
            2,
            BLACK,
        );
    }
    text(
        &mut img,
        PANELS[0][0] as i64,
        H as i64 - 28,
        &format!(
            "red: converged_px = {} (a post also settles below a fifth of its sigma)",
            trim(converged_px)
        ),
        2,
        Rgb([200, 40, 40]),
    );
    save_png(&img, path)
}
