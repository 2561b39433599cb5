//! Flat-field correction: an average of a clear, featureless field (plate glass or film
//! base) divided by its mean is the gain of every pixel — dust on the sensor, the measuring
//! mark in the optical path, uneven lighting. They sit at the same pixels in every image, so
//! every image is divided by that gain: the mark and the dust no longer pull a match, nor
//! repeat across a mosaic.

use super::ImageF32;
use std::path::Path;

/// A field is not clear when more than this share (%) of it is darker than 70 % of its mean.
pub const MAX_DARK_PERCENT: f64 = 2.0;
/// Gains below this are clipped (a dead pixel must not become a bright one).
const MIN_GAIN: f64 = 0.05;

#[derive(Debug, Clone, PartialEq)]
pub struct FlatField {
    pub width: usize,
    pub height: usize,
    /// Each pixel's value over the field's mean.
    pub gain: Vec<f32>,
    /// Share (%) of the field darker than 70 % of its mean: large if something lay in view.
    pub dark_percent: f64,
}

impl FlatField {
    pub fn from_image(img: &ImageF32) -> FlatField {
        let n = img.data.len().max(1) as f64;
        let mean = img.data.iter().map(|&v| v as f64).sum::<f64>() / n;
        let dark = img
            .data
            .iter()
            .filter(|&&v| (v as f64) < 0.7 * mean)
            .count() as f64;
        FlatField {
            width: img.width,
            height: img.height,
            gain: img
                .data
                .iter()
                .map(|&v| (v as f64 / mean).max(MIN_GAIN) as f32)
                .collect(),
            dark_percent: 100.0 * dark / n,
        }
    }

    /// Whether the field was clear enough to serve as a flat.
    pub fn is_clear(&self) -> bool {
        self.dark_percent <= MAX_DARK_PERCENT
    }

    /// Divides `img` by the gain; images of another size are left alone (returns false).
    pub fn apply(&self, img: &mut ImageF32) -> bool {
        if (img.width, img.height) != (self.width, self.height) {
            return false;
        }
        for (v, g) in img.data.iter_mut().zip(&self.gain) {
            *v /= g;
        }
        true
    }

    /// Reads a flat saved as a 16-bit TIFF (any grey scale: only ratios matter).
    pub fn load(path: &Path) -> std::io::Result<FlatField> {
        Ok(Self::from_image(&super::output::read_tiff16_f32(path)?))
    }
}

/// Saves an image in DN of a `bit_depth` camera as a 16-bit TIFF, scaled by 2^(16 − bits) so
/// that the fractions of a DN an average carries survive.
pub fn save_counts(path: &Path, img: &ImageF32, bit_depth: u32) -> std::io::Result<()> {
    let k = counts_per_dn(bit_depth);
    let px: Vec<u16> = img
        .data
        .iter()
        .map(|&v| (v as f64 * k).round().clamp(0.0, 65535.0) as u16)
        .collect();
    super::output::write_tiff16(path, img.width, img.height, &px)
}

pub fn counts_per_dn(bit_depth: u32) -> f64 {
    2f64.powi(16 - bit_depth.clamp(1, 16) as i32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flat_removes_a_fixed_speck_and_flags_a_field_that_is_not_clear() {
        let (w, h) = (32, 24);
        let speck = |c: usize, r: usize| if (c, r) == (10, 7) { 0.6 } else { 1.0 };
        let lamp = |c: usize| 1.0 + 0.002 * c as f32;
        let mut flat = ImageF32::new(w, h);
        let mut scene = ImageF32::new(w, h);
        for r in 0..h {
            for c in 0..w {
                flat.data[r * w + c] = 3000.0 * lamp(c) * speck(c, r);
                let t = 0.3 + 0.02 * ((c * 7 + r * 3) % 11) as f32;
                scene.data[r * w + c] = 2500.0 * t * lamp(c) * speck(c, r);
            }
        }
        let f = FlatField::from_image(&flat);
        assert!(f.is_clear());
        assert!(f.apply(&mut scene));
        // What is left is the scene's own transmittance times one constant.
        let k = scene.data[0] / 0.3;
        for r in 0..h {
            for c in 0..w {
                let t = 0.3 + 0.02 * ((c * 7 + r * 3) % 11) as f32;
                assert!((scene.data[r * w + c] / k - t).abs() < 1e-4, "({c},{r})");
            }
        }
        // A field with a mark across a tenth of it is no flat.
        for v in flat.data.iter_mut().take(w * h / 10) {
            *v *= 0.2;
        }
        assert!(!FlatField::from_image(&flat).is_clear());
    }
}
