//! The photo-coordinate grid of a scanned photo: which photo point (mm) each output pixel
//! shows. Pixel (c, r) covers [c, c+1) × [r, r+1) in continuous pixel coordinates, as
//! everywhere in the rig ([`crate::coords::PixelXY`]); rows run down the photo's y axis.

use crate::coords::{PhotoMm, PixelXY};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PhotoGrid {
    /// Photo coordinates of the top-left corner of pixel (0, 0), mm.
    pub corner_mm: [f64; 2],
    /// Pixel size, mm: x grows with the column, y falls with the row.
    pub step_mm: f64,
    pub width: usize,
    pub height: usize,
}

impl PhotoGrid {
    /// The grid covering `[x_min, y_min, x_max, y_max]` (mm) at `step_mm`, from its top-left
    /// corner; the last column and row reach up to one step past the right and bottom edges.
    pub fn covering(r: [f64; 4], step_mm: f64) -> PhotoGrid {
        let n = |span: f64| ((span / step_mm) - 1e-9).ceil().max(1.0) as usize;
        PhotoGrid {
            corner_mm: [r[0], r[3]],
            step_mm,
            width: n(r[2] - r[0]),
            height: n(r[3] - r[1]),
        }
    }

    /// The photo point at continuous pixel coordinates `q`.
    pub fn photo(&self, q: PixelXY) -> PhotoMm {
        PhotoMm::new(
            self.corner_mm[0] + q.col * self.step_mm,
            self.corner_mm[1] - q.row * self.step_mm,
        )
    }

    /// Continuous pixel coordinates of photo point `p`.
    pub fn pixel(&self, p: PhotoMm) -> PixelXY {
        PixelXY::new(
            (p.x - self.corner_mm[0]) / self.step_mm,
            (self.corner_mm[1] - p.y) / self.step_mm,
        )
    }

    /// The photo area the grid covers: x_min, y_min, x_max, y_max, mm.
    pub fn extent_mm(&self) -> [f64; 4] {
        [
            self.corner_mm[0],
            self.corner_mm[1] - self.height as f64 * self.step_mm,
            self.corner_mm[0] + self.width as f64 * self.step_mm,
            self.corner_mm[1],
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pixel_centres_and_round_trip() {
        let g = PhotoGrid::covering([-10.0, -5.0, 10.0, 5.0], 0.025);
        assert_eq!((g.width, g.height), (800, 400));
        let c = g.photo(PixelXY::new(0.5, 0.5));
        assert!((c.x + 9.9875).abs() < 1e-12 && (c.y - 4.9875).abs() < 1e-12);
        let q = g.pixel(PhotoMm::new(1.234, -2.5));
        let p = g.photo(q);
        assert!((p.x - 1.234).abs() < 1e-12 && (p.y + 2.5).abs() < 1e-12);
        assert_eq!(g.extent_mm(), [-10.0, -5.0, 10.0, 5.0]);
    }
}
