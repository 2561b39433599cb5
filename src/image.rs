//! Images as the core takes them: one channel of grey values as f32, row-major. The hardware
//! side (digitisation, scanning) produces them; the matchers and the least-squares measurement
//! consume them, whoever made them.

/// A single-channel floating-point image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageF32 {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl ImageF32 {
    pub fn new(width: usize, height: usize) -> Self {
        ImageF32 {
            width,
            height,
            data: vec![0.0; width * height],
        }
    }

    pub fn from_u16(width: usize, height: usize, px: &[u16]) -> Self {
        ImageF32 {
            width,
            height,
            data: px.iter().map(|&v| v as f32).collect(),
        }
    }

    #[inline]
    pub fn at(&self, col: usize, row: usize) -> f32 {
        self.data[row * self.width + col]
    }

    pub fn row(&self, row: usize) -> &[f32] {
        &self.data[row * self.width..(row + 1) * self.width]
    }
}
