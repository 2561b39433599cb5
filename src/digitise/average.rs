use super::{DigitiseError, ImageF32};
use rayon::prelude::*;

/// Pixels per tile of the batch average: a tile's sums stay in L2 while every frame passes
/// over it, and each frame is read in runs long enough for the prefetcher.
const TILE: usize = 16384;

/// Running sum of frames in integers (exact: 16-bit frames give a u32 sum and a u64 sum of
/// squares for up to 65 536 frames), so the mean and the per-pixel σ carry no rounding from
/// the order of addition. For when frames cannot be kept; [`average_frames`] is faster.
pub struct Averager {
    width: usize,
    height: usize,
    sum: Vec<u32>,
    sum_sq: Vec<u64>,
    n: u32,
}

/// The mean of N frames and each pixel's sample standard deviation across them.
#[derive(Debug, Clone)]
pub struct Averaged {
    pub mean: ImageF32,
    pub std: ImageF32,
    pub frames: u32,
}

/// Mean and sample σ from exact sums: Σ(v−m)² = Σv² − (Σv)²/n, exact in integers up to the
/// final division.
#[inline]
fn finalize(sum: u32, sum_sq: u64, n: u32) -> (f32, f32) {
    let (s, nf) = (sum as f64, n as f64);
    let m = s / nf;
    let sd = if n > 1 {
        ((sum_sq as f64 - s * s / nf).max(0.0) / (nf - 1.0)).sqrt()
    } else {
        0.0
    };
    (m as f32, sd as f32)
}

impl Averager {
    pub fn new(width: usize, height: usize) -> Self {
        Averager {
            width,
            height,
            sum: vec![0; width * height],
            sum_sq: vec![0; width * height],
            n: 0,
        }
    }

    pub fn frames(&self) -> u32 {
        self.n
    }

    /// Adds one frame (`seq` names it in an error).
    pub fn add(
        &mut self,
        width: usize,
        height: usize,
        seq: u64,
        px: &[u16],
    ) -> Result<(), DigitiseError> {
        if width != self.width || height != self.height || px.len() != width * height {
            return Err(DigitiseError::SizeMismatch {
                seq,
                got_w: width,
                got_h: height,
                want_w: self.width,
                want_h: self.height,
            });
        }
        for ((s, q), &v) in self.sum.iter_mut().zip(self.sum_sq.iter_mut()).zip(px) {
            *s += v as u32;
            *q += (v as u64) * (v as u64);
        }
        self.n += 1;
        Ok(())
    }

    pub fn finish(&self) -> Result<Averaged, DigitiseError> {
        if self.n == 0 {
            return Err(DigitiseError::NoFrames);
        }
        let mut mean = ImageF32::new(self.width, self.height);
        let mut std = ImageF32::new(self.width, self.height);
        for i in 0..self.sum.len() {
            (mean.data[i], std.data[i]) = finalize(self.sum[i], self.sum_sq[i], self.n);
        }
        Ok(Averaged {
            mean,
            std,
            frames: self.n,
        })
    }
}

built_per_cpu! {
    /// One tile: sum every frame's pixels with 32-bit squares where the tile's largest value
    /// proves they fit (a widening 16×16 multiply that vectorises), else with 64-bit squares; then
    /// the mean and σ. Built per CPU (see `simd`).
    fn tile[](frames: &[&[u16]], off: usize, m: &mut [f32], s: &mut [f32]) = tile_body;
}

#[inline(always)]
fn tile_body(frames: &[&[u16]], off: usize, m: &mut [f32], s: &mut [f32]) {
    let len = m.len();
    let n = frames.len() as u32;
    // On the heap: a tile's sums are too big for a worker thread's stack.
    let mut sum = vec![0u32; len];
    let mut sq32 = vec![0u32; len];
    let mut max = 0u16;
    for f in frames {
        let src = &f[off..off + len];
        // Indexed over slices of one length, so the bounds checks go and the loop vectorises
        // (a three-way zip did not).
        let (a, b, src) = (&mut sum[..len], &mut sq32[..len], &src[..len]);
        // One read of each pixel: the largest value (which tells whether the squares fit) is
        // taken in the same pass as the sums.
        let mut m = 0u16;
        for i in 0..len {
            m = m.max(src[i]);
            let v = src[i] as u32;
            a[i] = a[i].wrapping_add(v);
            b[i] = b[i].wrapping_add(v * v);
        }
        max = max.max(m);
    }
    let inv_n = 1.0 / n as f64;
    let inv_n1 = if n > 1 { 1.0 / (n as f64 - 1.0) } else { 0.0 };
    let fin = |sum: u32, sq: f64| -> (f32, f32) {
        let s = sum as f64;
        (
            (s * inv_n) as f32,
            ((sq - s * s * inv_n).max(0.0) * inv_n1).sqrt() as f32,
        )
    };
    if (max as u64) * (max as u64) * (n as u64) < (1u64 << 32) {
        for i in 0..len {
            (m[i], s[i]) = fin(sum[i], sq32[i] as f64);
        }
    } else {
        // Squares that could overflow 32 bits: again, with 64-bit sums.
        let mut sq = vec![0u64; len];
        for f in frames {
            for (b, &v) in sq[..len].iter_mut().zip(&f[off..off + len]) {
                *b += (v as u64) * (v as u64);
            }
        }
        for i in 0..len {
            (m[i], s[i]) = fin(sum[i], sq[i] as f64);
        }
    }
}

/// Averages whole frames at once, tile by tile on all cores: the same exact sums as
/// [`Averager`], without streaming an accumulator through memory per frame.
pub fn average_frames(
    width: usize,
    height: usize,
    frames: &[&[u16]],
) -> Result<Averaged, DigitiseError> {
    let mut out = Averaged {
        mean: ImageF32::new(width, height),
        std: ImageF32::new(width, height),
        frames: 0,
    };
    average_frames_into(width, height, frames, &mut out)?;
    Ok(out)
}

/// [`average_frames`] into images that already exist (resized if need be), for a scan that
/// averages tile after tile: fresh output pages would cost the kernel a fault and a clear
/// each, a good part of the whole average.
pub fn average_frames_into(
    width: usize,
    height: usize,
    frames: &[&[u16]],
    out: &mut Averaged,
) -> Result<(), DigitiseError> {
    if frames.is_empty() {
        return Err(DigitiseError::NoFrames);
    }
    if let Some((i, f)) = frames
        .iter()
        .enumerate()
        .find(|(_, f)| f.len() != width * height)
    {
        return Err(DigitiseError::SizeMismatch {
            seq: i as u64,
            got_w: f.len(),
            got_h: 1,
            want_w: width,
            want_h: height,
        });
    }
    for img in [&mut out.mean, &mut out.std] {
        img.width = width;
        img.height = height;
        img.data.resize(width * height, 0.0);
    }
    out.frames = frames.len() as u32;
    out.mean
        .data
        .par_chunks_mut(TILE)
        .zip(out.std.data.par_chunks_mut(TILE))
        .enumerate()
        .for_each(|(t, (m, s))| tile(frames, t * TILE, m, s));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_and_std_closed_form() {
        let mut a = Averager::new(2, 1);
        for v in [[1u16, 10], [2, 10], [3, 10], [6, 10]] {
            a.add(2, 1, 0, &v).unwrap();
        }
        let r = a.finish().unwrap();
        assert_eq!(r.mean.data, vec![3.0, 10.0]);
        // Sample σ of 1,2,3,6: sqrt(14/3).
        assert!((r.std.data[0] as f64 - (14.0f64 / 3.0).sqrt()).abs() < 1e-6);
        assert_eq!(r.std.data[1], 0.0);
        assert!(matches!(
            a.add(3, 1, 7, &[0, 0, 0]),
            Err(DigitiseError::SizeMismatch { seq: 7, .. })
        ));
        assert!(matches!(
            Averager::new(1, 1).finish(),
            Err(DigitiseError::NoFrames)
        ));
    }

    #[test]
    fn batch_equals_streaming_bit_for_bit() {
        let (w, h) = (3000, 3); // more than one tile, a ragged last tile
        let frames: Vec<Vec<u16>> = (0..7u32)
            .map(|k| {
                (0..w * h)
                    .map(|i| ((i as u32).wrapping_mul(2654435761u32).rotate_left(k) >> 16) as u16)
                    .collect()
            })
            .collect();
        let refs: Vec<&[u16]> = frames.iter().map(|f| f.as_slice()).collect();
        let mut a = Averager::new(w, h);
        for (i, f) in frames.iter().enumerate() {
            a.add(w, h, i as u64, f).unwrap();
        }
        let (s, b) = (a.finish().unwrap(), average_frames(w, h, &refs).unwrap());
        assert_eq!(s.mean, b.mean);
        assert_eq!(s.std, b.std);
        // Into a reused result of another size: resized, every pixel overwritten.
        let mut r = average_frames(2, 2, &[&[9, 9, 9, 9]]).unwrap();
        average_frames_into(w, h, &refs, &mut r).unwrap();
        assert_eq!((r.mean.width, r.mean.height, r.frames), (w, h, 7));
        assert_eq!(r.mean, b.mean);
        assert_eq!(r.std, b.std);
        assert!(matches!(
            average_frames(w, h, &[]),
            Err(DigitiseError::NoFrames)
        ));
    }
}
