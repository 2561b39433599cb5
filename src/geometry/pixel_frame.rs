//! Which photo point (mm) each pixel of an image shows, for any image: an affine from the
//! core's continuous pixels (corner origin: pixel c covers [c, c + 1)) to photo millimetres,
//! and the image's size. A scan's [`PhotoGrid`] is the axis-aligned case; a plain image's
//! `pixel_mm` or `pixel_to_photo` (docs/conventions.md, centre origin) give the others.

use super::affine::{inv2, linear_part, mul2};
use super::PhotoGrid;
use crate::coords::{PhotoMm, PixelXY};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PixelToPhoto {
    /// x = p0 + p1·col + p2·row, y = p3 + p4·col + p5·row (mm; corner-origin pixels).
    pub params: [f64; 6],
    pub width: usize,
    pub height: usize,
}

impl PixelToPhoto {
    /// From the convention of docs/conventions.md (integer values at pixel centres): the same affine moved
    /// by half a pixel. `None` when its linear part cannot be inverted.
    pub fn from_centre_origin(p: [f64; 6], width: usize, height: usize) -> Option<PixelToPhoto> {
        inv2(linear_part(&p))?;
        Some(PixelToPhoto {
            params: [
                p[0] - 0.5 * (p[1] + p[2]),
                p[1],
                p[2],
                p[3] - 0.5 * (p[4] + p[5]),
                p[4],
                p[5],
            ],
            width,
            height,
        })
    }

    pub fn photo(&self, q: PixelXY) -> PhotoMm {
        let p = &self.params;
        PhotoMm::new(
            p[0] + p[1] * q.col + p[2] * q.row,
            p[3] + p[4] * q.col + p[5] * q.row,
        )
    }

    /// The pixel showing photo point `x` (NaN when the affine is singular).
    pub fn pixel(&self, x: PhotoMm) -> PixelXY {
        let p = &self.params;
        let [c, r] =
            inv2(linear_part(p)).map_or([f64::NAN; 2], |m| mul2(m, [x.x - p[0], x.y - p[3]]));
        PixelXY::new(c, r)
    }
}

impl From<PhotoGrid> for PixelToPhoto {
    fn from(g: PhotoGrid) -> PixelToPhoto {
        PixelToPhoto {
            params: [
                g.corner_mm[0],
                g.step_mm,
                0.0,
                g.corner_mm[1],
                0.0,
                -g.step_mm,
            ],
            width: g.width,
            height: g.height,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn agrees_with_the_grid_and_the_centre_convention() {
        let g = PhotoGrid::covering([-10.0, -5.0, 10.0, 5.0], 0.025);
        let f = PixelToPhoto::from(g);
        for q in [
            PixelXY::new(0.0, 0.0),
            PixelXY::new(12.5, 399.5),
            PixelXY::new(799.0, 3.25),
        ] {
            let (a, b) = (g.photo(q), f.photo(q));
            assert!((a.x - b.x).abs() < 1e-12 && (a.y - b.y).abs() < 1e-12);
            let back = f.pixel(b);
            assert!((back.col - q.col).abs() < 1e-9 && (back.row - q.row).abs() < 1e-9);
        }
        // docs/conventions.md: x = (col − (W−1)/2)·p, y = ((H−1)/2 − row)·p at pixel centres; the centre of
        // pixel (0, 0) is corner-origin (0.5, 0.5).
        let (w, h, p) = (800, 400, 0.025);
        let c = PixelToPhoto::from_centre_origin(
            [
                -(w as f64 - 1.0) / 2.0 * p,
                p,
                0.0,
                (h as f64 - 1.0) / 2.0 * p,
                0.0,
                -p,
            ],
            w,
            h,
        )
        .unwrap();
        let at = c.photo(PixelXY::new(0.5, 0.5));
        assert!((at.x + 399.5 * p).abs() < 1e-12 && (at.y - 199.5 * p).abs() < 1e-12);
        assert!(PixelToPhoto::from_centre_origin([0.0, 1.0, 2.0, 0.0, 2.0, 4.0], 1, 1).is_none());
    }
}
