//! Drawing for the pictures a person reads (maps of the models, residual plots, scan plans):
//! points, lines, rectangles and text in an 8 × 8 bitmap font (the `font8x8` glyphs, so no
//! system font is needed), and the furniture of a map: colour bar with units, scale bar,
//! north arrow, legend swatches. Pictures are saved atomically.

use font8x8::UnicodeFonts;
use image::{Rgb, RgbImage};
use std::path::Path;

pub const BLACK: Rgb<u8> = Rgb([0, 0, 0]);
pub const WHITE: Rgb<u8> = Rgb([255, 255, 255]);

/// Sets a pixel; outside the image nothing happens.
pub fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && x < img.width() as i64 && y < img.height() as i64 {
        img.put_pixel(x as u32, y as u32, c);
    }
}

/// A line two pixels thick from `a` to `b`.
pub fn line(img: &mut RgbImage, a: [f64; 2], b: [f64; 2], c: Rgb<u8>) {
    let len = (b[0] - a[0]).abs().max((b[1] - a[1]).abs());
    // Written so that NaN or huge ends draw nothing rather than loop for ever.
    if !len.is_finite() || len > 1e5 {
        return;
    }
    let n = (len.ceil() as i64).max(1);
    for k in 0..=n {
        let t = k as f64 / n as f64;
        let (x, y) = (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]));
        for (dx, dy) in [(0, 0), (1, 0), (0, 1)] {
            put(img, x.round() as i64 + dx, y.round() as i64 + dy, c);
        }
    }
}

/// A filled rectangle, corner (x, y), size w × h.
pub fn fill(img: &mut RgbImage, x: i64, y: i64, w: i64, h: i64, c: Rgb<u8>) {
    for yy in y..y + h {
        for xx in x..x + w {
            put(img, xx, yy, c);
        }
    }
}

/// An outline one pixel wide.
pub fn frame(img: &mut RgbImage, x: i64, y: i64, w: i64, h: i64, c: Rgb<u8>) {
    fill(img, x, y, w, 1, c);
    fill(img, x, y + h - 1, w, 1, c);
    fill(img, x, y, 1, h, c);
    fill(img, x + w - 1, y, 1, h, c);
}

fn glyph(ch: char) -> [u8; 8] {
    font8x8::BASIC_FONTS
        .get(ch)
        .or_else(|| font8x8::LATIN_FONTS.get(ch))
        .or_else(|| font8x8::GREEK_FONTS.get(ch))
        .unwrap_or(font8x8::BASIC_FONTS.get('?').unwrap_or([0; 8]))
}

/// Width in pixels of `s` at `scale` (each glyph 8 × 8 pixels times the scale).
pub fn text_width(s: &str, scale: i64) -> i64 {
    s.chars().count() as i64 * 8 * scale
}

/// Writes `s` with its top-left corner at (x, y).
pub fn text(img: &mut RgbImage, x: i64, y: i64, s: &str, scale: i64, c: Rgb<u8>) {
    for (k, ch) in s.chars().enumerate() {
        for (r, bits) in glyph(ch).iter().enumerate() {
            for col in 0..8 {
                if bits & (1 << col) != 0 {
                    fill(
                        img,
                        x + (k as i64 * 8 + col) * scale,
                        y + r as i64 * scale,
                        scale,
                        scale,
                        c,
                    );
                }
            }
        }
    }
}

/// A round length near `v` from below: 1, 2 or 5 × 10ⁿ.
pub fn nice(v: f64) -> f64 {
    if !(v.is_finite() && v > 0.0) {
        return 1.0;
    }
    let b = 10f64.powf(v.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * b)
        .rfind(|x| *x <= v * (1.0 + 1e-12))
        .unwrap_or(b)
}

/// A number without trailing zeros (at most 4 decimals).
pub fn trim(v: f64) -> String {
    let s = format!("{v:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.to_string()
    }
}

/// The colour at t (0…1, NaN as 0) along a ramp of stops (t, colour).
fn lerp(stops: &[(f64, [u8; 3])], t: f64) -> Rgb<u8> {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    for w in stops.windows(2) {
        let ((a, ca), (b, cb)) = (w[0], w[1]);
        if t <= b {
            let u = if b > a { (t - a) / (b - a) } else { 0.0 };
            let m = |i: usize| (ca[i] as f64 + u * (cb[i] as f64 - ca[i] as f64)).round() as u8;
            return Rgb([m(0), m(1), m(2)]);
        }
    }
    Rgb(stops.last().map_or([0; 3], |s| s.1))
}

/// Greens through ochre to brown, low to high.
pub fn terrain(t: f64) -> Rgb<u8> {
    lerp(
        &[
            (0.0, [40, 120, 70]),
            (0.35, [150, 195, 100]),
            (0.65, [225, 205, 135]),
            (1.0, [150, 100, 70]),
        ],
        t,
    )
}

/// Blue (−1) through white (0) to red (+1).
pub fn diverging(t: f64) -> Rgb<u8> {
    lerp(
        &[
            (0.0, [40, 70, 200]),
            (0.5, [255, 255, 255]),
            (1.0, [200, 40, 40]),
        ],
        t,
    )
}

/// Pale yellow (0) to dark violet (1).
pub fn sequential(t: f64) -> Rgb<u8> {
    lerp(
        &[
            (0.0, [255, 250, 200]),
            (0.5, [230, 110, 80]),
            (1.0, [70, 20, 100]),
        ],
        t,
    )
}

/// `v` rounded to `digits` significant digits (for labels).
pub fn significant(v: f64, digits: i32) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    let p = 10f64.powi(digits - 1 - v.abs().log10().floor() as i32);
    (v * p).round() / p
}

/// A vertical colour bar at (x, y) of `w × h`, `colour(t)` for t from 0 (bottom) to 1 (top),
/// labelled with round values between `lo` and `hi` and `unit` above it.
#[allow(clippy::too_many_arguments)]
pub fn colour_bar(
    img: &mut RgbImage,
    x: i64,
    y: i64,
    w: i64,
    h: i64,
    lo: f64,
    hi: f64,
    unit: &str,
    colour: &dyn Fn(f64) -> Rgb<u8>,
) {
    for k in 0..h {
        let t = 1.0 - k as f64 / (h - 1).max(1) as f64;
        fill(img, x, y + k, w, 1, colour(t));
    }
    frame(img, x, y, w, h, BLACK);
    text(img, x, y - 20, unit, 2, BLACK);
    if !(lo.is_finite() && hi.is_finite() && hi > lo) {
        return;
    }
    let step = nice((hi - lo) / 5.0);
    let mut v = (lo / step).ceil() * step;
    while v <= hi + 1e-9 * step {
        let yy = y + ((hi - v) / (hi - lo) * (h - 1) as f64).round() as i64;
        fill(img, x + w, yy, 6, 2, BLACK);
        text(img, x + w + 10, yy - 7, &trim(v), 2, BLACK);
        v += step;
    }
}

/// A scale bar at (x, y) for a map of `px_per_m` pixels per metre, about `max_px` long at most.
pub fn scale_bar(img: &mut RgbImage, x: i64, y: i64, px_per_m: f64, max_px: f64) {
    if !(px_per_m.is_finite() && px_per_m > 0.0) {
        return;
    }
    let m = nice(max_px / px_per_m);
    let len = (m * px_per_m).round() as i64;
    fill(img, x, y, len, 6, BLACK);
    fill(img, x + len / 2, y + 1, len - len / 2 - 1, 4, WHITE);
    fill(img, x, y - 6, 2, 12, BLACK);
    fill(img, x + len - 2, y - 6, 2, 12, BLACK);
    let label = if m >= 1000.0 {
        format!("{} km", trim(m / 1000.0))
    } else {
        format!("{} m", trim(m))
    };
    text(img, x + len + 12, y - 5, &label, 2, BLACK);
}

/// A north arrow (the maps are north-up) with its top at (x, y).
pub fn north_arrow(img: &mut RgbImage, x: i64, y: i64) {
    let (xf, yf) = (x as f64, y as f64);
    line(img, [xf, yf + 40.0], [xf, yf], BLACK);
    line(img, [xf, yf], [xf - 8.0, yf + 14.0], BLACK);
    line(img, [xf, yf], [xf + 8.0, yf + 14.0], BLACK);
    text(img, x - 7, y + 46, "N", 2, BLACK);
}

/// A legend entry: a swatch and its label.
pub fn swatch(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>, label: &str) {
    fill(img, x, y, 24, 16, c);
    frame(img, x, y, 24, 16, BLACK);
    text(img, x + 34, y, label, 2, BLACK);
}

/// Saves `img` as PNG, atomically.
pub fn save_png(img: &RgbImage, path: &Path) -> std::io::Result<()> {
    crate::atomic::write_with(path, |f| {
        image::write_buffer_with_format(
            f,
            img.as_raw(),
            img.width(),
            img.height(),
            image::ExtendedColorType::Rgb8,
            image::ImageFormat::Png,
        )
        .map_err(|e| std::io::Error::other(format!("{}: {e}", path.display())))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_lengths_and_labels() {
        assert_eq!(nice(0.37), 0.2);
        assert_eq!(nice(7.0), 5.0);
        assert_eq!(nice(1000.0), 1000.0);
        assert_eq!(nice(f64::NAN), 1.0);
        assert_eq!(trim(0.5), "0.5");
        assert_eq!(trim(-0.00001), "0");
    }

    #[test]
    fn text_is_drawn_in_its_box_and_only_there() {
        let mut img = RgbImage::from_pixel(100, 40, WHITE);
        text(&mut img, 10, 10, "A1", 2, BLACK);
        let (mut inside, mut outside) = (0, 0);
        for (x, y, p) in img.enumerate_pixels() {
            if *p == BLACK {
                if (10..10 + text_width("A1", 2)).contains(&(x as i64))
                    && (10..26).contains(&(y as i64))
                {
                    inside += 1;
                } else {
                    outside += 1;
                }
            }
        }
        assert!(inside > 40, "{inside}");
        assert_eq!(outside, 0);
        // Off the image: nothing drawn, nothing panics.
        text(&mut img, -1000, 5000, "µσ±", 3, BLACK);
        line(&mut img, [f64::NAN, 0.0], [1e300, 5.0], BLACK);
    }
}
