//! A regular elevation model from the matched points (seed 000 §3.6): each point goes to the
//! grid node it falls nearest to, several points on one node are averaged, nodes no point
//! reached are nodata. And the comparison with a reference model in the figures of seed 000
//! Table 5: largest positive and negative difference, mean, mean absolute, RMSE.

use crate::coords::GroundM;
use serde::{Deserialize, Serialize};

/// Heights on a north-up grid: node (c, r) at (x0 + c·cell, y0 − r·cell).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ElevationGrid {
    /// Ground coordinates of node (0, 0), the north-west one, m.
    pub x0: f64,
    pub y0: f64,
    pub cell_m: f64,
    pub cols: usize,
    pub rows: usize,
    /// Row-major from the north-west; NaN = nodata.
    #[serde(skip)]
    pub z: Vec<f32>,
}

/// Seed 000 Table 5.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Comparison {
    pub nodes: usize,
    pub max_positive_m: f64,
    pub max_negative_m: f64,
    pub mean_m: f64,
    pub mean_abs_m: f64,
    pub rmse_m: f64,
}

impl ElevationGrid {
    /// An empty grid covering `[x_min, y_min, x_max, y_max]` with nodes on multiples of
    /// `cell_m`.
    pub fn covering(extent: [f64; 4], cell_m: f64) -> ElevationGrid {
        let x0 = (extent[0] / cell_m).ceil() * cell_m;
        let y0 = (extent[3] / cell_m).floor() * cell_m;
        let cols = (((extent[2] - x0) / cell_m).floor() as usize) + 1;
        let rows = (((y0 - extent[1]) / cell_m).floor() as usize) + 1;
        ElevationGrid {
            x0,
            y0,
            cell_m,
            cols,
            rows,
            z: vec![f32::NAN; cols * rows],
        }
    }

    pub fn node(&self, c: usize, r: usize) -> [f64; 2] {
        [
            self.x0 + c as f64 * self.cell_m,
            self.y0 - r as f64 * self.cell_m,
        ]
    }

    /// Averages the points falling nearest each node.
    pub fn fill(&mut self, pts: &[GroundM]) {
        let mut sum = vec![0.0f64; self.z.len()];
        let mut n = vec![0u32; self.z.len()];
        for p in pts {
            let c = ((p.x - self.x0) / self.cell_m).round();
            let r = ((self.y0 - p.y) / self.cell_m).round();
            if c < 0.0 || r < 0.0 || c >= self.cols as f64 || r >= self.rows as f64 {
                continue;
            }
            let i = r as usize * self.cols + c as usize;
            sum[i] += p.z;
            n[i] += 1;
        }
        for i in 0..self.z.len() {
            self.z[i] = if n[i] > 0 {
                (sum[i] / n[i] as f64) as f32
            } else {
                f32::NAN
            };
        }
    }

    /// Bilinear height at ground (x, y); NaN outside or next to nodata.
    pub fn interpolate(&self, x: f64, y: f64) -> f64 {
        let fc = (x - self.x0) / self.cell_m;
        let fr = (self.y0 - y) / self.cell_m;
        if fc < 0.0 || fr < 0.0 || fc > (self.cols - 1) as f64 || fr > (self.rows - 1) as f64 {
            return f64::NAN;
        }
        let (c, r) = (
            (fc.floor() as usize).min(self.cols.saturating_sub(2)),
            (fr.floor() as usize).min(self.rows.saturating_sub(2)),
        );
        let (tx, ty) = (fc - c as f64, fr - r as f64);
        let z = |c: usize, r: usize| self.z[r * self.cols + c] as f64;
        let a = z(c, r) + tx * (z(c + 1, r) - z(c, r));
        let b = z(c, r + 1) + tx * (z(c + 1, r + 1) - z(c, r + 1));
        a + ty * (b - a)
    }

    pub fn filled(&self) -> usize {
        self.z.iter().filter(|v| v.is_finite()).count()
    }

    /// This grid minus the reference at every node that has a height.
    pub fn differences(&self, reference: impl Fn(f64, f64) -> f64) -> Vec<f32> {
        (0..self.z.len())
            .map(|i| {
                let [x, y] = self.node(i % self.cols, i / self.cols);
                self.z[i] - reference(x, y) as f32
            })
            .collect()
    }

    pub fn compare(&self, reference: impl Fn(f64, f64) -> f64) -> Comparison {
        let d: Vec<f64> = self
            .differences(reference)
            .into_iter()
            .filter(|v| v.is_finite())
            .map(|v| v as f64)
            .collect();
        let n = d.len().max(1) as f64;
        Comparison {
            nodes: d.len(),
            max_positive_m: d.iter().cloned().fold(f64::MIN, f64::max).max(0.0),
            max_negative_m: d.iter().cloned().fold(f64::MAX, f64::min).min(0.0),
            mean_m: d.iter().sum::<f64>() / n,
            mean_abs_m: d.iter().map(|v| v.abs()).sum::<f64>() / n,
            rmse_m: (d.iter().map(|v| v * v).sum::<f64>() / n).sqrt(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_average_on_their_nearest_node_and_compare_in_closed_form() {
        let mut g = ElevationGrid::covering([0.0, 0.0, 10.0, 10.0], 5.0);
        assert_eq!((g.cols, g.rows, g.x0, g.y0), (3, 3, 0.0, 10.0));
        g.fill(&[
            GroundM::new(0.4, 9.6, 100.0),
            GroundM::new(-0.5, 10.4, 102.0),
            GroundM::new(5.1, 5.2, 50.0),
        ]);
        assert_eq!(g.z[0], 101.0);
        assert_eq!(g.z[4], 50.0);
        assert_eq!(g.filled(), 2);
        // Reference 100 everywhere: differences +1 and −50.
        let c = g.compare(|_, _| 100.0);
        assert_eq!(c.nodes, 2);
        assert_eq!((c.max_positive_m, c.max_negative_m), (1.0, -50.0));
        assert!((c.mean_m + 24.5).abs() < 1e-12 && (c.mean_abs_m - 25.5).abs() < 1e-12);
        assert!((c.rmse_m - (2501.0f64 / 2.0).sqrt()).abs() < 1e-9);
    }
}
