//! A picture of a scan plan, for the operator to look at before anything moves: the film
//! frame with its fiducials, every tile's usable area, the path the stage takes, the regions
//! and the flat field's spot, in photo coordinates (x to the right, y up).

use super::calibration::ScanCalibration;
use super::plan::Plan;
use crate::picture::{line, put, save_png, text, BLACK};
use image::{Rgb, RgbImage};
use std::path::Path;

/// Pixels per photo millimetre, and the half-size of the drawn area (mm).
const SCALE: f64 = 4.0;
const HALF_MM: f64 = 120.0;

pub fn plan_plot(
    plan: &Plan,
    cal: &ScanCalibration,
    flat_mm: [f64; 2],
    path: &Path,
) -> std::io::Result<()> {
    let n = (2.0 * HALF_MM * SCALE) as u32;
    let mut img = RgbImage::from_pixel(n, n, Rgb([255, 255, 255]));
    let at = |x: f64, y: f64| [(x + HALF_MM) * SCALE, (HALF_MM - y) * SCALE];
    let rect = |img: &mut RgbImage, r: [f64; 4], c: Rgb<u8>| {
        let (a, b, d, e) = (
            at(r[0], r[1]),
            at(r[2], r[1]),
            at(r[2], r[3]),
            at(r[0], r[3]),
        );
        line(img, a, b, c);
        line(img, b, d, c);
        line(img, d, e, c);
        line(img, e, a, c);
    };
    // The 230 mm frame.
    rect(&mut img, [-115.0, -115.0, 115.0, 115.0], Rgb([0, 0, 0]));
    for f in &cal.certificate.fiducials {
        let p = at(f.photo.x, f.photo.y);
        for d in -3..=3 {
            put(&mut img, p[0] as i64 + d, p[1] as i64, Rgb([0, 0, 0]));
            put(&mut img, p[0] as i64, p[1] as i64 + d, Rgb([0, 0, 0]));
        }
        text(
            &mut img,
            p[0] as i64 + 5,
            p[1] as i64 + 5,
            &f.id.to_string(),
            2,
            BLACK,
        );
    }
    let [hx, hy] = plan.tile_half_mm;
    for t in &plan.tiles {
        let (x, y) = (t.photo_mm.x, t.photo_mm.y);
        rect(
            &mut img,
            [x - hx, y - hy, x + hx, y + hy],
            Rgb([150, 170, 230]),
        );
    }
    for w in plan.tiles.windows(2) {
        line(
            &mut img,
            at(w[0].photo_mm.x, w[0].photo_mm.y),
            at(w[1].photo_mm.x, w[1].photo_mm.y),
            Rgb([230, 120, 30]),
        );
    }
    for r in &plan.regions {
        rect(&mut img, r.grid.extent_mm(), Rgb([200, 0, 0]));
    }
    if plan.flat_stage_um.is_some() {
        let p = at(flat_mm[0], flat_mm[1]);
        for dy in -4..=4 {
            for dx in -4..=4 {
                put(
                    &mut img,
                    p[0] as i64 + dx,
                    p[1] as i64 + dy,
                    Rgb([0, 160, 0]),
                );
            }
        }
    }
    save_png(&img, path)
}
