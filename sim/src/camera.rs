//! The simulated camera over the carriage (seed 002's CCD on the AC1): it renders what lies
//! under the lens at the stage's true position, through the pixel→carriage affine, and adds
//! the sensor's faults as the seed describes them: shot and read noise, a grey-level shift
//! between the two video fields (alternate rows, 4–5 DN), vertical 3-pixel stripes darker every
//! 12 pixels, more noise on the top rows, dust, automatic gain, quantisation.
//!
//! Every parameter and the affine are part of the truth ([`CameraConfig`] serialises).

use crate::edges::{band, erf};
use crate::plate::Plate;
use crate::rng::Rng;
use rayon::prelude::*;
use serde::Serialize;

/// Pixel → local carriage coordinates (µm, origin at the measuring mark):
/// `x = a[0]·(col − mark.0) + a[1]·(row − mark.1)`, `y = b[0]·(col − mark.0) + b[1]·(row − mark.1)`.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct PixelToCarriage {
    pub a: [f64; 2],
    pub b: [f64; 2],
    /// Pixel (col, row) of the measuring mark.
    pub mark_px: [f64; 2],
}

impl PixelToCarriage {
    /// Seed 002's figures: 10.19 µm in x, 10.96 µm in y, shears about 0.1 µm, the measuring
    /// mark near pixel (238, 230).
    pub fn seed_default() -> Self {
        PixelToCarriage {
            a: [10.19, 0.09],
            b: [0.10, 10.96],
            mark_px: [238.3, 229.6],
        }
    }

    /// A camera with square pixels of 10.5 µm (shears about 0.1 µm): the form that hid no
    /// rotation of a rotationally symmetric mark, unlike seed 002's 10.19 × 10.96.
    pub fn square() -> Self {
        PixelToCarriage {
            a: [10.5, 0.09],
            b: [0.10, 10.5],
            mark_px: [238.3, 229.6],
        }
    }

    pub fn local_um(&self, col: f64, row: f64) -> [f64; 2] {
        let (dc, dr) = (col - self.mark_px[0], row - self.mark_px[1]);
        [
            self.a[0] * dc + self.a[1] * dr,
            self.b[0] * dc + self.b[1] * dr,
        ]
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct CameraConfig {
    pub width: usize,
    pub height: usize,
    pub bit_depth: u32,
    pub affine: PixelToCarriage,
    /// Optical blur (Gaussian σ, pixels), before the pixel's own box.
    pub psf_sigma_px: f64,
    /// Grey level of fully clear glass at gain 1 and the reference exposure, in 8-bit DN.
    pub white_dn8: f64,
    pub exposure_ms: f64,
    pub gain: f64,
    /// Automatic gain: a slow flicker of the gain from frame to frame.
    pub auto_gain: bool,
    /// Shot noise: variance in DN² per DN of signal (8-bit scale).
    pub shot_dn8: f64,
    /// Read noise σ, 8-bit DN.
    pub read_noise_dn8: f64,
    /// Extra noise on the top rows: σ × (1 + factor·exp(−row / rows)).
    pub top_noise_factor: f64,
    pub top_noise_rows: f64,
    /// Grey-level shift of the odd rows (the second video field), 8-bit DN, and its jitter
    /// from frame to frame.
    pub field_shift_dn8: f64,
    pub field_jitter_dn8: f64,
    /// Vertical stripes: 3 pixels wide, alternately dark and light, the dark ones darker
    /// every 12 pixels. Depth of the dark and of the darker stripes, 8-bit DN; phase in pixels.
    pub stripe_dark_dn8: f64,
    pub stripe_darker_dn8: f64,
    pub stripe_phase_px: usize,
    /// The measuring mark, fixed in the optical path at `affine.mark_px` (seed 002: "the
    /// measuring mark is in every digital image"): a dark dot of this radius (µm on the
    /// carriage) and this transmittance at its centre.
    pub mark_radius_um: f64,
    pub mark_transmittance: f64,
    /// Dust on the sensor: (col, row, radius px, transmittance at its centre).
    pub dust: Vec<(f64, f64, f64, f64)>,
    pub frame_rate_hz: f64,
}

impl CameraConfig {
    pub fn new(rng: &mut Rng) -> Self {
        let mut dust = Vec::new();
        for _ in 0..4 {
            dust.push((
                rng.uniform() * 512.0,
                rng.uniform() * 512.0,
                2.0 + 4.0 * rng.uniform(),
                0.6 + 0.3 * rng.uniform(),
            ));
        }
        CameraConfig {
            width: 512,
            height: 512,
            bit_depth: 8,
            affine: PixelToCarriage::seed_default(),
            psf_sigma_px: 0.6,
            white_dn8: 220.0,
            exposure_ms: 20.0,
            gain: 1.0,
            auto_gain: true,
            shot_dn8: 0.02,
            read_noise_dn8: 1.0,
            top_noise_factor: 1.5,
            top_noise_rows: 30.0,
            field_shift_dn8: 4.5,
            field_jitter_dn8: 0.3,
            stripe_dark_dn8: 2.0,
            stripe_darker_dn8: 3.5,
            stripe_phase_px: rng.below(12) as usize,
            mark_radius_um: 12.0,
            mark_transmittance: 0.45,
            dust,
            frame_rate_hz: 25.0,
        }
    }

    /// DN of the configured bit depth per 8-bit DN.
    pub fn scale(&self) -> f64 {
        (1u64 << self.bit_depth) as f64 / 256.0
    }

    /// The stripe offset of a column, 8-bit DN (the fixed pattern, not yet scaled).
    pub fn stripe_dn8(&self, col: usize) -> f64 {
        match ((col + self.stripe_phase_px) % 12) / 3 {
            0 => -self.stripe_darker_dn8,
            2 => -self.stripe_dark_dn8,
            _ => 0.0,
        }
    }
}

/// Pixel spacing along x and along y, µm.
fn spacing_um(cfg: &CameraConfig) -> [f64; 2] {
    let af = &cfg.affine;
    [af.a[0].hypot(af.b[0]), af.a[1].hypot(af.b[1])]
}

/// Blur of one pixel's sample in µm along x and along y: the optics' Gaussian and the pixel's
/// own box (variance 1/12 px²).
fn blur_um(cfg: &CameraConfig) -> [f64; 2] {
    let s = (cfg.psf_sigma_px * cfg.psf_sigma_px + 1.0 / 12.0).sqrt();
    let px = spacing_um(cfg);
    [s * px[0], s * px[1]]
}

/// The noiseless image (transmittance 0..1) of the plate with the measuring mark at carriage
/// position `mark_um`.
pub fn render_plate(cfg: &CameraConfig, plate: &Plate, mark_um: [f64; 2]) -> Vec<f32> {
    let (w, h) = (cfg.width, cfg.height);
    let mut img = vec![plate.clear as f32; w * h];
    let af = &cfg.affine;
    let px = spacing_um(cfg);
    let [sx, sy] = blur_um(cfg);
    let centre = af.local_um(w as f64 / 2.0, h as f64 / 2.0);
    let view_r = (w as f64 * px[0]).max(h as f64 * px[1]);
    let centre = [mark_um[0] + centre[0], mark_um[1] + centre[1]];
    let dark = 1.0 - plate.line / plate.clear;
    let half = plate.line_um / 2.0;
    let crosses: Vec<_> = plate.crosses_near(centre, view_r).collect();
    let s = 0.5 * (sx + sy);
    // Rows in parallel; each pixel takes the crosses, then the dirt, in the order the plate
    // lists them (the same products, to the bit, as one row after another).
    img.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(row, img_row)| {
            for c in &crosses {
                for (col, px_v) in img_row.iter_mut().enumerate() {
                    let l = af.local_um(col as f64 + 0.5, row as f64 + 0.5);
                    let d = [
                        mark_um[0] + l[0] - c.true_um[0],
                        mark_um[1] + l[1] - c.true_um[1],
                    ];
                    if d[0].abs() > plate.arm_um + 5.0 * sx && d[1].abs() > plate.arm_um + 5.0 * sy
                    {
                        continue;
                    }
                    // Horizontal bar (along x) and vertical bar (along y).
                    let hb = band(d[1], half, sy) * band(d[0], plate.arm_um, sx);
                    let vb = band(d[0], half, sx) * band(d[1], plate.arm_um, sy);
                    let cov = hb + vb - hb * vb;
                    *px_v *= (1.0 - dark * cov) as f32;
                }
            }
            for d in &plate.dirt {
                for (col, px_v) in img_row.iter_mut().enumerate() {
                    let l = af.local_um(col as f64 + 0.5, row as f64 + 0.5);
                    let r = (mark_um[0] + l[0] - d[0]).hypot(mark_um[1] + l[1] - d[1]);
                    if r > d[2] + 5.0 * s {
                        continue;
                    }
                    let cov = 0.5 * (1.0 - erf((r - d[2]) / (std::f64::consts::SQRT_2 * s)));
                    *px_v *= (1.0 - (1.0 - d[3]) * cov) as f32;
                }
            }
        });
    img
}

/// Darkens the measuring mark into a rendered image: a blurred disk at the mark's pixel.
fn draw_measuring_mark(cfg: &CameraConfig, img: &mut [f32]) {
    let af = &cfg.affine;
    let [sx, sy] = blur_um(cfg);
    let s = 0.5 * (sx + sy);
    let (c0, r0) = (af.mark_px[0].floor() as i64, af.mark_px[1].floor() as i64);
    let reach = 4 + ((cfg.mark_radius_um + 5.0 * s) / spacing_um(cfg)[0]) as i64;
    for row in (r0 - reach).max(0)..(r0 + reach).min(cfg.height as i64) {
        for col in (c0 - reach).max(0)..(c0 + reach).min(cfg.width as i64) {
            let l = af.local_um(col as f64 + 0.5, row as f64 + 0.5);
            let r = l[0].hypot(l[1]);
            let cov = 0.5 * (1.0 - erf((r - cfg.mark_radius_um) / (std::f64::consts::SQRT_2 * s)));
            img[row as usize * cfg.width + col as usize] *=
                (1.0 - (1.0 - cfg.mark_transmittance) * cov) as f32;
        }
    }
}

/// The noiseless image of everything under the lens: the plate or, when one is loaded, the
/// film in its clear carrier; the measuring mark over either.
pub fn render_scene(
    cfg: &CameraConfig,
    plate: &Plate,
    film: Option<&crate::film::Film>,
    mark_um: [f64; 2],
) -> Vec<f32> {
    // The film lies in a carrier of clear glass that takes the calibration plate's place.
    let mut img = match film {
        Some(_) => vec![plate.clear as f32; cfg.width * cfg.height],
        None => render_plate(cfg, plate, mark_um),
    };
    if let Some(f) = film {
        let af = &cfg.affine;
        // One blur for the film: the mean of the two axes'.
        let [bx, by] = blur_um(cfg);
        let s = 0.5 * (bx + by);
        // Rows in parallel: every pixel is its own.
        img.par_chunks_mut(cfg.width.max(1))
            .enumerate()
            .for_each(|(row, img_row)| {
                for (col, px_v) in img_row.iter_mut().enumerate() {
                    let l = af.local_um(col as f64 + 0.5, row as f64 + 0.5);
                    let t = f.transmittance([mark_um[0] + l[0], mark_um[1] + l[1]], s);
                    *px_v *= t as f32;
                }
            });
    }
    draw_measuring_mark(cfg, &mut img);
    img
}

/// Draws of the noise stream set aside for each row of a frame: a row of w pixels takes about
/// 4/π·w, far fewer (the rows' parts never overlap).
const ROW_DRAWS: u64 = 1 << 32;

/// Turns a noiseless image into one frame from the sensor: gain, dust, shot and read noise
/// (more on the top rows), the field shift, the stripes, quantisation. `seq` is the frame
/// number (it drives the gain flicker and seeds the noise with `seed`). Rows are exposed in
/// parallel, each from its own part of the frame's noise stream ([`ROW_DRAWS`] draws apart),
/// so that the frame is the same, to the bit, on any number of threads.
pub fn expose(cfg: &CameraConfig, ideal: &[f32], seed: u64, seq: u64) -> Vec<u16> {
    let (w, h) = (cfg.width, cfg.height);
    let mut rng = Rng::new(seed ^ seq.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ 0x00CA_3E5A);
    let sc = cfg.scale();
    let max = ((1u64 << cfg.bit_depth) - 1) as f64;
    let flicker = if cfg.auto_gain {
        1.0 + 0.003 * (seq as f64 * 0.7).sin()
    } else {
        1.0
    };
    let level = cfg.white_dn8 * cfg.gain * flicker * cfg.exposure_ms / 20.0;
    let field = cfg.field_shift_dn8 + cfg.field_jitter_dn8 * rng.normal();
    let mut out = vec![0u16; w * h];
    if w == 0 {
        return out;
    }
    out.par_chunks_mut(w)
        .enumerate()
        .for_each(|(row, out_row)| {
            // The row's own part of the stream (a pair of normals takes a varying number of
            // draws, so a pixel's place in one stream would depend on the rows before it).
            let mut rng = rng.jumped(ROW_DRAWS * row as u64);
            let mut spare = None;
            let mut t: Vec<f64> = ideal[row * w..(row + 1) * w]
                .iter()
                .map(|&v| v as f64)
                .collect();
            let top = 1.0 + cfg.top_noise_factor * (-(row as f64) / cfg.top_noise_rows).exp();
            let read = cfg.read_noise_dn8 * top;
            let field_dn = if row % 2 == 1 { field } else { 0.0 };
            // Dust darkens within three radii of its centre (beyond, exp(−9) is nothing).
            for &(dc, dr, r, depth) in &cfg.dust {
                let dy = row as f64 - dr;
                if dy.abs() >= 3.0 * r {
                    continue;
                }
                let c0 = (dc - 3.0 * r).floor().max(0.0) as usize;
                let c1 = ((dc + 3.0 * r).ceil().max(0.0) as usize).min(w);
                for (col, tv) in t.iter_mut().enumerate().take(c1).skip(c0) {
                    let q = ((col as f64 - dc).powi(2) + dy * dy) / (r * r);
                    if q < 9.0 {
                        *tv *= 1.0 - (1.0 - depth) * (-q).exp();
                    }
                }
            }
            for (col, (&tv, o)) in t.iter().zip(out_row.iter_mut()).enumerate() {
                let s = level * tv;
                let sigma = (cfg.shot_dn8 * s * top * top + read * read).sqrt();
                // The polar method gives normals in pairs: both are used.
                let z = match spare.take() {
                    Some(z) => z,
                    None => {
                        let [a, b] = rng.normal_pair();
                        spare = Some(b);
                        a
                    }
                };
                let v = s + sigma * z + field_dn + cfg.stripe_dn8(col);
                // Rounded half up (non-negative after the clamp); NaN becomes 0.
                *o = ((v * sc).clamp(0.0, max) + 0.5) as u16;
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The frame is the same, to the bit, on one thread and on several (odd and even widths,
    /// with dust), and a different frame number draws different noise; the noise about the
    /// ideal frame has the spread the model gives it (shot and read noise, in grey levels).
    #[test]
    fn a_frame_is_the_same_on_any_number_of_threads() {
        for width in [37, 40] {
            let mut cfg = CameraConfig::new(&mut Rng::new(3));
            cfg.width = width;
            cfg.height = 23;
            cfg.dust = vec![(10.0, 8.0, 2.5, 0.6), (30.0, 20.0, 1.5, 0.3)];
            let ideal: Vec<f32> = (0..width * 23)
                .map(|k| 0.2 + 0.6 * ((k % 17) as f32 / 17.0))
                .collect();
            for seq in [0, 1, 5] {
                let on = |threads: usize| {
                    rayon::ThreadPoolBuilder::new()
                        .num_threads(threads)
                        .build()
                        .unwrap()
                        .install(|| expose(&cfg, &ideal, 9, seq))
                };
                let one = on(1);
                assert_eq!(one, on(3), "width {width}, frame {seq}");
                assert_eq!(one, expose(&cfg, &ideal, 9, seq));
                assert_ne!(one, expose(&cfg, &ideal, 9, seq + 1));
            }
        }
        // The spread: a flat frame without dust, field jitter or flicker (the stripes and the
        // field shift are the same in every frame), many
        // frames of it; every pixel's deviation from the mean frame over the model's σ.
        let mut cfg = CameraConfig::new(&mut Rng::new(4));
        (cfg.width, cfg.height) = (64, 48);
        cfg.dust.clear();
        cfg.auto_gain = false;
        cfg.field_shift_dn8 = 0.0;
        cfg.field_jitter_dn8 = 0.0;
        let ideal = vec![0.5f32; 64 * 48];
        let frames: Vec<Vec<u16>> = (0..40).map(|q| expose(&cfg, &ideal, 5, q)).collect();
        let sc = cfg.scale();
        let level = cfg.white_dn8 * cfg.gain * cfg.exposure_ms / 20.0 * 0.5;
        let (mut ratio, mut n) = (0.0, 0usize);
        for row in 30..48 {
            let top = 1.0 + cfg.top_noise_factor * (-(row as f64) / cfg.top_noise_rows).exp();
            let read = cfg.read_noise_dn8 * top;
            let sigma = (cfg.shot_dn8 * level * top * top + read * read).sqrt() * sc;
            for col in 0..64 {
                let v: Vec<f64> = frames.iter().map(|f| f[row * 64 + col] as f64).collect();
                let m = v.iter().sum::<f64>() / v.len() as f64;
                let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64;
                // Quantisation adds 1/12 of a level².
                ratio += (var - 1.0 / 12.0) / (sigma * sigma);
                n += 1;
            }
        }
        let ratio = ratio / n as f64;
        assert!((ratio - 1.0).abs() < 0.05, "variance / model {ratio}");
        // Neighbouring rows draw different noise (their parts of the stream do not overlap):
        // the correlation of their deviations from the mean frame is 0 ± 4/√n.
        let dev = |f: &[u16], row: usize, col: usize| {
            let m = frames.iter().map(|g| g[row * 64 + col] as f64).sum::<f64>() / 40.0;
            f[row * 64 + col] as f64 - m
        };
        let (mut sab, mut saa, mut sbb, mut pairs) = (0.0, 0.0, 0.0, 0usize);
        for f in &frames {
            for row in 30..47 {
                for col in 0..64 {
                    let (a, b) = (dev(f, row, col), dev(f, row + 1, col));
                    (sab, saa, sbb) = (sab + a * b, saa + a * a, sbb + b * b);
                    pairs += 1;
                }
            }
        }
        let r = sab / (saa * sbb).sqrt();
        assert!(
            r.abs() < 4.0 / (pairs as f64).sqrt(),
            "rows correlated: {r}"
        );
    }

    #[test]
    fn erf_matches_known_values() {
        for (x, e) in [
            (0.0, 0.0),
            (0.5, 0.520_499_877_8),
            (1.0, 0.842_700_792_9),
            (2.0, 0.995_322_265_0),
            (-1.0, -0.842_700_792_9),
        ] {
            assert!((erf(x) - e).abs() < 2e-7, "erf({x})");
        }
    }

    #[test]
    fn stripe_pattern_is_three_wide_darker_every_twelve() {
        let mut c = CameraConfig::new(&mut Rng::new(1));
        c.stripe_phase_px = 0;
        let p: Vec<f64> = (0..24).map(|i| c.stripe_dn8(i)).collect();
        assert_eq!(&p[0..3], &[-3.5; 3]);
        assert_eq!(&p[3..6], &[0.0; 3]);
        assert_eq!(&p[6..9], &[-2.0; 3]);
        assert_eq!(&p[12..15], &[-3.5; 3]);
    }

    /// Asserts that the darkest pixel is within a pixel of the measuring mark; returns its value.
    fn darkest_is_at_the_mark(cfg: &CameraConfig, img: &[f32]) -> f32 {
        let (mut best, mut at) = (f32::MAX, 0);
        for (i, &v) in img.iter().enumerate() {
            if v < best {
                best = v;
                at = i;
            }
        }
        let (col, row) = ((at % 512) as f64 + 0.5, (at / 512) as f64 + 0.5);
        assert!(
            (col - cfg.affine.mark_px[0]).abs() <= 1.0
                && (row - cfg.affine.mark_px[1]).abs() <= 1.0,
            "{col},{row}"
        );
        best
    }

    #[test]
    fn a_cross_renders_where_the_affine_puts_it() {
        let mut rng = Rng::new(2);
        let cfg = CameraConfig::new(&mut rng);
        let plate = Plate::new(&mut rng);
        let c = plate.crosses[4];
        // Put the cross exactly under the measuring mark: its centre must be the darkest
        // spot, at the mark's pixel.
        let img = render_plate(&cfg, &plate, c.true_um);
        let best = darkest_is_at_the_mark(&cfg, &img);
        assert!(best < 0.2 && img[0] > 0.8);
    }

    #[test]
    fn the_measuring_mark_is_in_every_image() {
        let mut rng = Rng::new(3);
        let cfg = CameraConfig::new(&mut rng);
        let plate = Plate::new(&mut rng);
        // Clear glass between the crosses: the only dark spot is the mark.
        let img = render_scene(&cfg, &plate, None, [75_000.0, 75_000.0]);
        let best = darkest_is_at_the_mark(&cfg, &img);
        let clear = plate.clear as f32;
        assert!(best < 0.8 * clear, "the mark is visible: {best} vs {clear}");
    }
}
