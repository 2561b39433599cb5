use super::{DigitiseError, ImageF32};

/// Running sum of frames in integers (exact: 32 frames of 16 bits fit a u32 sum and a u64 sum
/// of squares), so the mean and the per-pixel σ carry no rounding from the order of addition.
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
        let n = self.n as f64;
        let mut mean = ImageF32::new(self.width, self.height);
        let mut std = ImageF32::new(self.width, self.height);
        for i in 0..self.sum.len() {
            let s = self.sum[i] as f64;
            let m = s / n;
            mean.data[i] = m as f32;
            if self.n > 1 {
                // Σ(v−m)² = Σv² − (Σv)²/n, exact in integers up to the final division.
                let ss = self.sum_sq[i] as f64 - s * s / n;
                std.data[i] = (ss.max(0.0) / (n - 1.0)).sqrt() as f32;
            }
        }
        Ok(Averaged {
            mean,
            std,
            frames: self.n,
        })
    }
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
}
