//! The camera's stripes (the shift between the video fields, the periodic column pattern; seed
//! 002) estimated from the very image a mark is measured in, when no flat of the camera is at
//! hand: the mark is found, the stripes are estimated from the pixels off its footprint, taken
//! out, and the mark measured again.
//!
//! The mark's own pixels are left out because they would bias the medians the estimate rests
//! on (a cross's bar fills half of its columns' rows in a crop), and a crop of a few dozen
//! pixels has no others to spare. The stripes are offsets of the sensor's rows and columns, so
//! the background determines them where the mark lies too. On the independent validation marks
//! (tests/data/validation/marks) with CCD artefacts and no flat this halves to thirds the
//! centre's error (benches/marks_validation.py); on clean marks it changes it by less than
//! 0.0005 px.

use super::Template;
use crate::coords::PixelXY;
use crate::digitise::{estimate_stripes_where, remove_stripes, ImageF32, StripeEstimate};

/// Pixels by which the footprint is widened around where the template departs from its
/// background: the blur, rotation and scale of the mark in the image against its coarse
/// template (drawn at 0.8 px of blur).
pub const FOOTPRINT_GROW_PX: usize = 3;

/// Where a mark lies in its (coarse) template, widened by [`FOOTPRINT_GROW_PX`]: the pixels the
/// stripes are not estimated from.
#[derive(Debug, Clone)]
pub struct Footprint {
    side: usize,
    on: Vec<bool>,
}

impl Footprint {
    /// The pixels of `t` that depart from its background (the value at its corner, where no
    /// mark reaches) by more than 10⁻³ of the contrast, grown by [`FOOTPRINT_GROW_PX`].
    pub fn of(t: &Template) -> Footprint {
        let n = t.image.width.min(t.image.height);
        let bg = t.image.data.first().copied().unwrap_or(0.0);
        let raw: Vec<bool> = (0..n * n)
            .map(|i| (t.image.data[(i / n) * t.image.width + i % n] - bg).abs() > 1e-3)
            .collect();
        let g = FOOTPRINT_GROW_PX as i64;
        let n_i = n as i64;
        let on = (0..n * n)
            .map(|i| {
                let (x, y) = ((i % n) as i64, (i / n) as i64);
                (-g..=g).any(|dy| {
                    (-g..=g).any(|dx| {
                        let (u, v) = (x + dx, y + dy);
                        (0..n_i).contains(&u)
                            && (0..n_i).contains(&v)
                            && raw[(v * n_i + u) as usize]
                    })
                })
            })
            .collect();
        Footprint { side: n, on }
    }

    /// Whether pixel (col, row) of an image lies off the footprint placed with its centre at
    /// `centre` (the half-pixel convention of [`PixelXY`]).
    pub fn off(&self, centre: PixelXY, col: usize, row: usize) -> bool {
        let n = self.side as i64;
        let c0 = (centre.col - n as f64 / 2.0).round() as i64;
        let r0 = (centre.row - n as f64 / 2.0).round() as i64;
        let (u, v) = (col as i64 - c0, row as i64 - r0);
        !((0..n).contains(&u) && (0..n).contains(&v) && self.on[(v * n + u) as usize])
    }
}

/// Estimates the stripes of `img` from its pixels off the mark's footprint at `centre` and
/// takes them out of `img`; returns the estimate.
pub fn remove_crop_stripes(img: &mut ImageF32, fp: &Footprint, centre: PixelXY) -> StripeEstimate {
    let e = estimate_stripes_where(img, &|c, r| fp.off(centre, c, r));
    remove_stripes(img, &e);
    e
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 71-px crop of a dark cross on 180 DN with a field shift of 3 DN and a 12-px column
    /// pattern of ±4 DN: the estimate from the background finds both, and leaves the mark's
    /// pixels out.
    #[test]
    fn the_background_gives_the_stripes_of_a_crop() {
        let n = 71;
        let pattern = |c: usize| 4.0 * ((c % 12) as f32 / 12.0 * std::f32::consts::TAU).sin();
        let mut data = vec![0f32; n * n];
        let mut state = 12345u64;
        let mut noise = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 33) as f32 / (1u64 << 31) as f32 - 0.5) * 2.0
        };
        for r in 0..n {
            for c in 0..n {
                let on_bar = (r.abs_diff(35) <= 1 && c.abs_diff(35) <= 16)
                    || (c.abs_diff(35) <= 1 && r.abs_diff(35) <= 16);
                let base = if on_bar { 60.0 } else { 180.0 };
                let field = if r % 2 == 1 { 3.0 } else { 0.0 };
                data[r * n + c] = base + field + pattern(c) + noise();
            }
        }
        let mut img = ImageF32 {
            width: n,
            height: n,
            data,
        };
        // The footprint of a template of the bar cross drawn by hand (a 41-px template).
        let t = 41;
        let mut tdata = vec![1f32; t * t];
        for r in 0..t {
            for c in 0..t {
                if (r.abs_diff(20) <= 1 && c.abs_diff(20) <= 16)
                    || (c.abs_diff(20) <= 1 && r.abs_diff(20) <= 16)
                {
                    tdata[r * t + c] = 0.0;
                }
            }
        }
        let tpl = Template {
            image: ImageF32 {
                width: t,
                height: t,
                data: tdata,
            },
            fine: None,
            um_per_px: [[1.0, 0.0], [0.0, 1.0]],
        };
        let fp = Footprint::of(&tpl);
        let centre = PixelXY::new(35.5, 35.5);
        assert!(!fp.off(centre, 35, 35) && !fp.off(centre, 35 + 18, 35));
        assert!(fp.off(centre, 35 + 21, 35) && fp.off(centre, 2, 2));
        let e = remove_crop_stripes(&mut img, &fp, centre);
        assert!((e.field_offset - 3.0).abs() < 0.2, "{e:?}");
        assert_eq!(e.column_period, Some(12), "{e:?}");
        // What is left of the pattern on the background: the noise's (±1 DN uniform) alone.
        let mut left = [0f64; 12];
        let mut count = [0usize; 12];
        for r in (0..n).step_by(2) {
            for c in 0..n {
                if fp.off(centre, c, r) {
                    left[c % 12] += (img.data[r * n + c] - 180.0) as f64;
                    count[c % 12] += 1;
                }
            }
        }
        for k in 0..12 {
            let m = left[k] / count[k] as f64;
            assert!(m.abs() < 0.4, "phase {k}: {m:.2} DN left");
        }
    }
}
