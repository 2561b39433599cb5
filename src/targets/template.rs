//! Synthetic ideal templates of the marks (seed 002: "least squares matching with a
//! synthetically generated ideal cross"), drawn from the geometry a plate or camera certificate
//! gives, at the pixel spacing of the camera, and softened by the optics' blur so that the
//! template looks like the image it is matched against.

use super::mark::MarkShape;
use crate::digitise::ImageF32;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// How a mark appears: dark on clear (a diapositive, the plate in transmitted light) or clear
/// on dark (a negative).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Polarity {
    #[default]
    #[serde(alias = "dark_on_bright")]
    DarkOnClear,
    #[serde(alias = "bright_on_dark")]
    ClearOnDark,
}

/// A square template: grey values 0 (mark) to 1 (background) for a dark mark, the mark's
/// centre at the middle of the patch.
#[derive(Debug, Clone)]
pub struct Template {
    pub image: ImageF32,
    /// The same template drawn [`FINE`] times finer, with a margin of [`FINE_PAD`] template
    /// pixels: least-squares matching samples the template (smooth, finely drawn) instead of
    /// resampling the image, whose sharp edges would bias the centre by the interpolation
    /// error (about ±0.015 px, varying with the sub-pixel phase). Drawn when asked for.
    pub fine: Option<ImageF32>,
    /// Pixel → µm as drawn (see [`TemplateSpec::um_per_px`]).
    pub um_per_px: [[f64; 2]; 2],
}

/// Oversampling of [`Template::fine`].
pub const FINE: usize = 4;
/// Margin of [`Template::fine`] around the patch, template pixels.
pub const FINE_PAD: usize = 4;

impl Template {
    /// Side in pixels (odd).
    pub fn size(&self) -> usize {
        self.image.width
    }

    /// The mark's centre in template pixel coordinates (corner origin): the middle of the
    /// middle pixel.
    pub fn centre(&self) -> f64 {
        self.image.width as f64 / 2.0
    }
}

/// How to draw a template.
#[derive(Debug, Clone, Copy)]
pub struct TemplateSpec {
    /// Side of the patch in pixels; made odd.
    pub size: usize,
    /// Pixel → µm (the 2×2 part of the pixel→carriage affine, or its nominal diagonal):
    /// `[[a1, a2], [b1, b2]]`.
    pub um_per_px: [[f64; 2]; 2],
    /// The optics' blur, a Gaussian σ in pixels, applied after each pixel's own area.
    pub blur_px: f64,
    pub polarity: Polarity,
    /// Also draw [`Template::fine`], for least-squares matching (not needed to locate coarsely).
    pub fine: bool,
}

/// Draws `shape` into a template: each pixel's coverage integrated on a 6×6 sub-grid, then the
/// blur.
pub fn render(shape: &MarkShape, spec: &TemplateSpec) -> Template {
    let size = spec.size | 1;
    let fine = spec.fine.then(|| {
        let k = FINE as f64;
        let m = spec.um_per_px;
        let fine_spec = TemplateSpec {
            size: (size + 2 * FINE_PAD) * FINE,
            um_per_px: [[m[0][0] / k, m[0][1] / k], [m[1][0] / k, m[1][1] / k]],
            // The optics; the image pixel's own area below.
            blur_px: spec.blur_px * k,
            polarity: spec.polarity,
            fine: false,
        };
        let mut img = draw(shape, &fine_spec, fine_spec.size);
        pixel_area(&mut img, FINE);
        img
    });
    Template {
        image: draw(shape, spec, size),
        fine,
        um_per_px: spec.um_per_px,
    }
}

/// Sub-samples per pixel side of the coverage integration.
const SUB: usize = 6;

/// The work of [`render`] with `fine` drawn, in tests of a part (pixels × sub-samples × the
/// parts' cost), to refuse a mark too large to draw before it is drawn.
pub fn render_work(shape: &MarkShape, size: usize) -> f64 {
    let per_sample: f64 = shape.parts.iter().map(|p| p.cost()).sum();
    let fine = ((size + 2 * FINE_PAD) * FINE) as f64;
    let px = (size as f64).powi(2) + fine * fine;
    px * (SUB * SUB) as f64 * per_sample
}

/// Draws a `size`×`size` template centred at size/2.
fn draw(shape: &MarkShape, spec: &TemplateSpec, size: usize) -> ImageF32 {
    let margin = (3.0 * spec.blur_px).ceil() as usize;
    let big = size + 2 * margin;
    let c = big as f64 / 2.0;
    let m = spec.um_per_px;
    let mut cov = vec![0f64; big * big];
    // A pixel's samples lie within `reach` µm of its centre (the farthest corner of the
    // samples' square, a millionth more against rounding): a pixel whose disk of that radius is
    // wholly in or out of the mark is all samples in or out, 1 or 0 without sampling.
    let half = (SUB as f64 - 1.0) / (2.0 * SUB as f64);
    let reach = [[1.0, 1.0], [1.0, -1.0]]
        .iter()
        .map(|[a, b]| {
            let (x, y) = (a * half, b * half);
            (m[0][0] * x + m[0][1] * y).hypot(m[1][0] * x + m[1][1] * y)
        })
        .fold(0.0, f64::max)
        * (1.0 + 1e-6)
        + 1e-9;
    // Rows in parallel: every pixel's coverage is its own.
    cov.par_chunks_mut(big.max(1))
        .enumerate()
        .for_each(|(r, row)| {
            for (col, v) in row.iter_mut().enumerate() {
                let (x, y) = (col as f64 + 0.5 - c, r as f64 + 0.5 - c);
                let centre = [m[0][0] * x + m[0][1] * y, m[1][0] * x + m[1][1] * y];
                if let Some(inside) = shape.disk(centre, reach) {
                    *v = if inside { 1.0 } else { 0.0 };
                    continue;
                }
                let mut n = 0;
                for sj in 0..SUB {
                    for si in 0..SUB {
                        let x = col as f64 + (si as f64 + 0.5) / SUB as f64 - c;
                        let y = r as f64 + (sj as f64 + 0.5) / SUB as f64 - c;
                        let p = [m[0][0] * x + m[0][1] * y, m[1][0] * x + m[1][1] * y];
                        n += shape.contains(p) as usize;
                    }
                }
                *v = n as f64 / (SUB * SUB) as f64;
            }
        });
    let cov = gaussian_blur(&cov, big, spec.blur_px);
    let mut image = ImageF32::new(size, size);
    for r in 0..size {
        for col in 0..size {
            let k = cov[(r + margin) * big + col + margin];
            image.data[r * size + col] = match spec.polarity {
                Polarity::DarkOnClear => 1.0 - k,
                Polarity::ClearOnDark => k,
            } as f32;
        }
    }
    image
}

/// Each value of a grid drawn `k` times finer than the image becomes the mean over one image
/// pixel's area centred on it: the integral of the bilinear surface through the samples over
/// ±k/2 samples, by the trapezoidal rule (weights ½, 1, …, 1, ½ over k + 1 samples), exact for
/// it, in both directions. Sampling the result anywhere then gives what a pixel there sees
/// (a Gaussian of the box's variance had left 0.01 px of phase-dependent error on sharp marks).
fn pixel_area(img: &mut ImageF32, k: usize) {
    let (w, h) = (img.width, img.height);
    let half = (k / 2) as i64;
    let wts: Vec<f64> = (-half..=half)
        .map(|d| if d.abs() == half { 0.5 } else { 1.0 } / k as f64)
        .collect();
    let at = |i: i64, n: usize| i.clamp(0, n as i64 - 1) as usize;
    let mut tmp = vec![0f32; w * h];
    for r in 0..h {
        for c in 0..w {
            let mut v = 0.0;
            for (j, wt) in wts.iter().enumerate() {
                v += wt * img.data[r * w + at(c as i64 + j as i64 - half, w)] as f64;
            }
            tmp[r * w + c] = v as f32;
        }
    }
    for r in 0..h {
        for c in 0..w {
            let mut v = 0.0;
            for (j, wt) in wts.iter().enumerate() {
                v += wt * tmp[at(r as i64 + j as i64 - half, h) * w + c] as f64;
            }
            img.data[r * w + c] = v as f32;
        }
    }
}

/// Separable Gaussian blur of a square grid (edges clamped).
fn gaussian_blur(src: &[f64], n: usize, sigma: f64) -> Vec<f64> {
    if sigma <= 0.0 {
        return src.to_vec();
    }
    let rad = (3.0 * sigma).ceil() as i64;
    let k: Vec<f64> = (-rad..=rad)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let ks: f64 = k.iter().sum();
    let k: Vec<f64> = k.iter().map(|v| v / ks).collect();
    let at = |i: i64| i.clamp(0, n as i64 - 1) as usize;
    let mut tmp = vec![0.0; n * n];
    for r in 0..n {
        for c in 0..n {
            tmp[r * n + c] = (-rad..=rad)
                .map(|d| k[(d + rad) as usize] * src[r * n + at(c as i64 + d)])
                .sum();
        }
    }
    let mut out = vec![0.0; n * n];
    for r in 0..n {
        for c in 0..n {
            out[r * n + c] = (-rad..=rad)
                .map(|d| k[(d + rad) as usize] * tmp[at(r as i64 + d) * n + c])
                .sum();
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::targets::mark::Part;

    #[test]
    fn a_cross_template_is_symmetric_and_centred() {
        let t = render(
            &MarkShape::cross(1000.0, 40.0),
            &TemplateSpec {
                size: 70, // made odd
                um_per_px: [[10.0, 0.0], [0.0, 10.0]],
                blur_px: 0.7,
                polarity: Polarity::DarkOnClear,
                fine: false,
            },
        );
        assert_eq!(t.size(), 71);
        assert_eq!(t.centre(), 35.5);
        let im = &t.image;
        // Centre dark, corner clear; the 4-px line's middle is dark along the arm.
        assert!(im.at(35, 35) < 0.05 && im.at(0, 0) > 0.999);
        assert!(im.at(35, 5) < 0.1 && im.at(5, 35) < 0.1);
        // Mirror symmetry about both axes.
        for r in 0..71 {
            for c in 0..71 {
                assert!((im.at(c, r) - im.at(70 - c, r)).abs() < 1e-5);
                assert!((im.at(c, r) - im.at(c, 70 - r)).abs() < 1e-5);
            }
        }
        // The dark area is the line area: 2 bars of 4 px × 71 px, less the overlap.
        let dark: f64 = im.data.iter().map(|&v| 1.0 - v as f64).sum();
        assert!((dark - (2.0 * 4.0 * 71.0 - 16.0)).abs() < 1.0, "{dark}");
    }

    /// Pixels wholly in or out of the mark are set without sampling: the drawing is the same,
    /// to the bit, as sampling every pixel (the old way, here), for every kind of part, a
    /// skewed pixel and the fine drawing's small one.
    #[test]
    fn skipping_whole_pixels_draws_the_same_bits_as_sampling_all() {
        fn by_samples(shape: &MarkShape, spec: &TemplateSpec, size: usize) -> Vec<f64> {
            let margin = (3.0 * spec.blur_px).ceil() as usize;
            let big = size + 2 * margin;
            let c = big as f64 / 2.0;
            let m = spec.um_per_px;
            let mut cov = vec![0f64; big * big];
            for r in 0..big {
                for col in 0..big {
                    let mut n = 0;
                    for sj in 0..SUB {
                        for si in 0..SUB {
                            let x = col as f64 + (si as f64 + 0.5) / SUB as f64 - c;
                            let y = r as f64 + (sj as f64 + 0.5) / SUB as f64 - c;
                            let p = [m[0][0] * x + m[0][1] * y, m[1][0] * x + m[1][1] * y];
                            n += shape.contains(p) as usize;
                        }
                    }
                    cov[r * big + col] = n as f64 / (SUB * SUB) as f64;
                }
            }
            let cov = gaussian_blur(&cov, big, spec.blur_px);
            let mut out = Vec::new();
            for r in 0..size {
                for col in 0..size {
                    out.push(1.0 - cov[(r + margin) * big + col + margin]);
                }
            }
            out
        }
        let spokes = MarkShape {
            parts: vec![
                Part::Ring {
                    radius: 300.0,
                    width: 40.0,
                },
                Part::Spokes {
                    count: 4,
                    from: 340.0,
                    to: 440.0,
                    width: 40.0,
                    angle0_deg: 3.0,
                },
                Part::Spokes {
                    count: 36,
                    from: 100.0,
                    to: 250.0,
                    width: 12.0,
                    angle0_deg: 0.0,
                },
            ],
        };
        let shapes = [
            MarkShape::cross(1000.0, 40.0),
            MarkShape::ring_with_dot(300.0, 40.0, 40.0),
            MarkShape::dot_with_line(60.0, 40.0, 150.0, 600.0, [0.6, -0.8]),
            MarkShape::cross(700.0, 33.0).turned(17.0),
            spokes,
        ];
        for shape in &shapes {
            for (m, blur, size) in [
                ([[10.19, 0.09], [0.10, 10.96]], 0.8, 111),
                ([[10.19 / 4.0, 0.0], [0.0, 10.96 / 4.0]], 3.2, 97),
                ([[25.0, -2.0], [1.5, 24.0]], 0.0, 61),
            ] {
                let spec = TemplateSpec {
                    size,
                    um_per_px: m,
                    blur_px: blur,
                    polarity: Polarity::DarkOnClear,
                    fine: false,
                };
                let drawn = draw(shape, &spec, size);
                let want = by_samples(shape, &spec, size);
                for (k, (a, b)) in drawn.data.iter().zip(&want).enumerate() {
                    assert_eq!(
                        a.to_bits(),
                        (*b as f32).to_bits(),
                        "{shape:?} {m:?}: pixel {k}"
                    );
                }
            }
        }
    }
}
