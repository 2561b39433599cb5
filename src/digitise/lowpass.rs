use super::ImageF32;

/// Box filter of `kw` columns × `kh` rows (odd), edges clamped.
fn box_filter(img: &ImageF32, kw: usize, kh: usize) -> ImageF32 {
    let (w, h) = (img.width, img.height);
    let (rx, ry) = ((kw / 2) as isize, (kh / 2) as isize);
    let mut tmp = ImageF32::new(w, h);
    for r in 0..h {
        for c in 0..w {
            let mut s = 0.0;
            for dc in -rx..=rx {
                s += img.at((c as isize + dc).clamp(0, w as isize - 1) as usize, r);
            }
            tmp.data[r * w + c] = s / kw as f32;
        }
    }
    let mut out = ImageF32::new(w, h);
    for r in 0..h {
        for c in 0..w {
            let mut s = 0.0;
            for dr in -ry..=ry {
                s += tmp.at(c, (r as isize + dr).clamp(0, h as isize - 1) as usize);
            }
            out.data[r * w + c] = s / kh as f32;
        }
    }
    out
}

/// The seed's pre-processing (seed 002, "Test data"): a 3×3 then a 7×3 low-pass (7 columns
/// across the vertical stripes, 3 rows across the field shift). Kept as the baseline: it
/// lowers the stripes by blurring everything, edges included.
pub fn seed_lowpass(img: &ImageF32) -> ImageF32 {
    box_filter(&box_filter(img, 3, 3), 7, 3)
}
