//! The image pyramid of the hierarchical matching (seed 002, "Computation of approximate
//! values"): each level half the size of the one below, low-passed before it is decimated,
//! down to about 64 px on the short side; and each photo's sensor seen at a level.
//!
//! Continuous pixels are the core's (corner origin: pixel c covers [c, c + 1)), so a level-k
//! point is the level-0 point divided by 2ᵏ exactly. Level-(k+1) pixel c covers level-k pixels
//! 2c and 2c + 1; its value is the binomial [1 3 3 1]/8 filter centred between them (the
//! smallest Gaussian-like kernel that is centred there), separably in both directions, with the
//! edge pixels repeated. Seed 002 used a 13-tap half-band kernel; a wider kernel keeps more of
//! the finest texture at the top, which the sweep there does not need.

use crate::coords::{GroundM, PixelXY};
use crate::geometry::{ProjectionError, Sensor};
use crate::image::ImageF32;

/// A level's image with its gradients, sampled together: least-squares matching needs the
/// grey value and its slope at the same point. The gradients are Sobel's (a central
/// difference across, [1 2 1]/4 along; edge pixels repeated): a third of a plain central
/// difference's noise for the same slope of a smooth picture, for the slopes enter the
/// design and their noise makes the precision look better than it is.
#[derive(Debug, Clone)]
pub struct Textured {
    pub image: ImageF32,
    pub gx: ImageF32,
    pub gy: ImageF32,
}

impl Textured {
    pub fn new(image: ImageF32) -> Textured {
        let (w, h) = (image.width, image.height);
        let (mut gx, mut gy) = (ImageF32::new(w, h), ImageF32::new(w, h));
        let at = |c: isize, r: isize| {
            image.at(
                c.clamp(0, w as isize - 1) as usize,
                r.clamp(0, h as isize - 1) as usize,
            )
        };
        for r in 0..h as isize {
            for c in 0..w as isize {
                let dx = |rr: isize| 0.5 * (at(c + 1, rr) - at(c - 1, rr));
                let dy = |cc: isize| 0.5 * (at(cc, r + 1) - at(cc, r - 1));
                let k = r as usize * w + c as usize;
                gx.data[k] = 0.25 * dx(r - 1) + 0.5 * dx(r) + 0.25 * dx(r + 1);
                gy.data[k] = 0.25 * dy(c - 1) + 0.5 * dy(c) + 0.25 * dy(c + 1);
            }
        }
        Textured { image, gx, gy }
    }

    /// Grey value and gradient (per pixel) at continuous point (x, y), bilinearly; `None`
    /// outside the pixel centres' hull.
    /// The three images are one size, so the cell is found once.
    #[inline]
    pub fn sample(&self, x: f64, y: f64) -> Option<[f64; 3]> {
        let cell = self.image.bilinear_cell(x, y)?;
        Some([
            self.image.bilinear_in(cell) as f64,
            self.gx.bilinear_in(cell) as f64,
            self.gy.bilinear_in(cell) as f64,
        ])
    }
}

/// One level up: half the size (rounded up), [1 3 3 1]/8 in both directions.
pub fn halve(img: &ImageF32) -> ImageF32 {
    const K: [f32; 4] = [0.125, 0.375, 0.375, 0.125];
    let (w, h) = (img.width, img.height);
    let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
    let clamp = |i: isize, n: usize| i.clamp(0, n as isize - 1) as usize;
    // Columns first, into a w2 × h buffer, then rows.
    let mut tmp = vec![0f32; w2 * h];
    for r in 0..h {
        let row = img.row(r);
        for c in 0..w2 {
            let mut s = 0.0;
            for (t, k) in K.iter().enumerate() {
                s += k * row[clamp(2 * c as isize - 1 + t as isize, w)];
            }
            tmp[r * w2 + c] = s;
        }
    }
    let mut out = ImageF32::new(w2, h2);
    for r in 0..h2 {
        for c in 0..w2 {
            let mut s = 0.0;
            for (t, k) in K.iter().enumerate() {
                s += k * tmp[clamp(2 * r as isize - 1 + t as isize, h) * w2 + c];
            }
            out.data[r * w2 + c] = s;
        }
    }
    out
}

/// The number of levels above level 0 that bring the short side down to about `top_px`
/// (at most 10).
pub fn levels_for(width: usize, height: usize, top_px: usize) -> usize {
    let mut short = width.min(height);
    let mut n = 0;
    while short >= 2 * top_px.max(8) && n < 10 {
        short = short.div_ceil(2);
        n += 1;
    }
    n
}

/// Level 0 (the image itself) and `levels` more, each half the one below.
pub fn pyramid(img: ImageF32, levels: usize) -> Vec<Textured> {
    let mut imgs = vec![img];
    for _ in 0..levels {
        let next = halve(imgs.last().expect("level 0 is there"));
        imgs.push(next);
    }
    imgs.into_iter().map(Textured::new).collect()
}

/// A sensor seen at pyramid level `level`: its pixels 2^level times larger.
pub struct AtLevel<'a> {
    pub inner: &'a (dyn Sensor + Sync),
    pub level: usize,
}

impl AtLevel<'_> {
    fn scale(&self) -> f64 {
        (1u64 << self.level.min(30)) as f64
    }
}

impl Sensor for AtLevel<'_> {
    fn image_size(&self) -> (usize, usize) {
        let (w, h) = self.inner.image_size();
        let s = 1usize << self.level.min(30);
        (w.div_ceil(s), h.div_ceil(s))
    }

    fn try_ground_to_image(&self, g: GroundM) -> Result<PixelXY, ProjectionError> {
        let q = self.inner.try_ground_to_image(g)?;
        let s = self.scale();
        Ok(PixelXY::new(q.col / s, q.row / s))
    }

    fn try_image_to_ground(&self, q: PixelXY, z: f64) -> Result<GroundM, ProjectionError> {
        let s = self.scale();
        self.inner
            .try_image_to_ground(PixelXY::new(q.col * s, q.row * s), z)
    }

    fn partials(&self, g: GroundM) -> Option<[[f64; 3]; 2]> {
        let s = self.scale();
        self.inner.partials(g).map(|d| d.map(|r| r.map(|v| v / s)))
    }

    fn height_partials(&self, g: GroundM) -> Option<[f64; 2]> {
        let s = self.scale();
        self.inner.height_partials(g).map(|d| d.map(|v| v / s))
    }

    fn pointing_covariance(&self, g: GroundM) -> Option<[[f64; 2]; 2]> {
        let s2 = self.scale().powi(2);
        self.inner
            .pointing_covariance(g)
            .map(|c| c.map(|r| r.map(|v| v / s2)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A linear ramp stays the same ramp at every level, in the level's own continuous
    /// coordinates (x₀ = 2ᵏ·xₖ): the filter is centred where the level's pixel centre lies.
    #[test]
    fn a_ramp_keeps_its_place_up_the_pyramid() {
        let (w, h) = (200, 130);
        let mut img = ImageF32::new(w, h);
        let ramp = |x: f64, y: f64| 3.0 * x - 2.0 * y + 10.0;
        for r in 0..h {
            for c in 0..w {
                img.data[r * w + c] = ramp(c as f64 + 0.5, r as f64 + 0.5) as f32;
            }
        }
        let levels = levels_for(w, h, 16);
        assert_eq!(levels, 3, "130 → 65 → 33 → 17");
        let p = pyramid(img, levels);
        for (k, t) in p.iter().enumerate() {
            let s = (1 << k) as f64;
            // Away from the repeated edges.
            for (c, r) in [(4, 4), (7, 5), (t.image.width / 2, t.image.height / 2)] {
                let (x, y) = (c as f64 + 0.5, r as f64 + 0.5);
                let want = ramp(x * s, y * s);
                let got = t.image.at(c, r) as f64;
                assert!(
                    (got - want).abs() < 1e-3,
                    "level {k} ({c}, {r}): {got} vs {want}"
                );
                let [_, gx, gy] = t.sample(x, y).unwrap();
                assert!((gx - 3.0 * s).abs() < 1e-3 && (gy + 2.0 * s).abs() < 1e-3);
            }
        }
        assert_eq!((p[3].image.width, p[3].image.height), (25, 17));
    }
}
