use super::ImageF32;

/// Where a contrast stretch put its black and white points.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Stretch {
    pub low: f32,
    pub high: f32,
    pub low_percentile: f64,
    pub high_percentile: f64,
}

/// Stretches `img` to the full 16-bit range, clipping the darkest `low_pct` and brightest
/// `100 − high_pct` per cent.
pub fn stretch(img: &ImageF32, low_pct: f64, high_pct: f64) -> (Vec<u16>, Stretch) {
    let mut sorted: Vec<f32> = img.data.iter().copied().filter(|v| v.is_finite()).collect();
    sorted.sort_by(f32::total_cmp);
    let pick = |p: f64| -> f32 {
        if sorted.is_empty() {
            return 0.0;
        }
        let i = ((p / 100.0) * (sorted.len() - 1) as f64).round() as usize;
        sorted[i.min(sorted.len() - 1)]
    };
    let (lo, hi) = (pick(low_pct), pick(high_pct));
    let span = (hi - lo).max(f32::EPSILON);
    let out = img
        .data
        .iter()
        .map(|&v| (((v - lo) / span).clamp(0.0, 1.0) * 65535.0).round() as u16)
        .collect();
    (
        out,
        Stretch {
            low: lo,
            high: hi,
            low_percentile: low_pct,
            high_percentile: high_pct,
        },
    )
}

/// An 8-bit look for the operator (a scan's preview, the service's live view): block averages of
/// `value(index)` over a `width` × `height` image, at most `max_side` px across, contrast
/// stretched over the 0.5–99.5 % range. Returns (width, height, grey bytes).
pub fn look8(
    width: usize,
    height: usize,
    max_side: usize,
    value: impl Fn(usize) -> f32,
) -> (usize, usize, Vec<u8>) {
    let k = width.max(height).div_ceil(max_side.max(1)).max(1);
    let (w, h) = (width / k, height / k);
    let mut small = ImageF32::new(w.max(1), h.max(1));
    for r in 0..h {
        for c in 0..w {
            let mut s = 0.0;
            for j in 0..k {
                for i in 0..k {
                    s += value((r * k + j) * width + c * k + i);
                }
            }
            small.data[r * w + c] = s / (k * k) as f32;
        }
    }
    let (v, _) = stretch(&small, 0.5, 99.5);
    let bytes = v.iter().map(|&x| (x >> 8) as u8).collect();
    (small.width, small.height, bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn full_range_monotonic_clipped() {
        let img = ImageF32 {
            width: 101,
            height: 1,
            data: (0..101).map(|v| v as f32).collect(),
        };
        let (out, s) = stretch(&img, 1.0, 99.0);
        assert_eq!((s.low, s.high), (1.0, 99.0));
        assert_eq!((out[0], out[1], out[99], out[100]), (0, 0, 65535, 65535));
        assert!(out.windows(2).all(|w| w[0] <= w[1]));
    }
}
