//! What a window matcher's DEM node holds on curved terrain, and how far to trust it.
//!
//! An area-based matcher measures the terrain's mean over its window, not the height at the
//! window's centre, and a node averages its cell's points once more. For a surface
//! z = z₀ + ½(κₓx² + κᵧy²) and an averaging kernel of variance v in each direction the mean is
//! z₀ + ½·∇²z·v; a square of side W has v = W²/12, and kernels applied one after the other add
//! their variances, so a node of cell a from windows W on the ground lies ∇²z·(W² + a²)/24 off
//! the terrain (above it in a valley, below it on a ridge). On the independent scenes of
//! tests/data/validation this was the largest error left: 2–12 × the matching's σ where |∇²z|
//! is largest.
//!
//! [`remove_window_averaging`] estimates that bias from the curvature of the DEM itself (a
//! quadratic fitted to each node's neighbourhood about a window wide: the curvature at the
//! scale the window averages) and takes it out where the nodes are no finer than about a
//! window (a 3 × 3 fit: on the 12 m and 5 m validation scenes the DEM's RMSE halves). On nodes
//! much finer than the window the nodes resolve detail no quadratic over the window follows (on
//! the real-RPC Gizeh crops, 1 m nodes under 5 m windows, the correction raised the RMSE from
//! 0.18 to 0.25 m): there the bias stays and is counted in σ. Either way the σ states what the
//! nodes cannot know: terrain finer than the nodes bends the surface too, by an amount of the
//! same order as the correction, so [`UNRESOLVED`] of it stays in the node's σ (most of it:
//! what the nodes miss is as large as what they see). The matching's own σ is counted per
//! independent window ([`Kernel::noise_scale`]): points closer than a window share their pixels
//! and their noise.

use crate::matching::grid::{ElevationGrid, NodeQuality};

/// The share of the curvature correction kept in the σ (terrain the nodes do not resolve).
/// Measured on tests/data/validation (sweep): 0.75 leaves the 1 m lidar scene's errors 1.25 × σ,
/// 1.0 makes the 12 m scene's 0.73 × σ; 0.9 gives 1.20, 0.83 and 0.91 on its three scenes.
pub const UNRESOLVED: f64 = 0.9;

/// How a matcher's node averages the terrain.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Kernel {
    /// The matching window's side on the ground, m.
    pub window_m: f64,
    /// The variance in each direction of how the node then combines the points, m².
    pub node_var_m2: f64,
    /// What the node's σ from its points is multiplied by for the windows' overlap: below 1
    /// where a node averages several independent windows, above 1 where its points were taken
    /// as independent but their windows overlap.
    pub noise_scale: f64,
}

impl Kernel {
    /// A node as the mean of the points in its cell (side `cell_m`, [`ElevationGrid::fill`]),
    /// its σ their RMS σ: a cell of a² holds max(1, a²/W²) independent windows.
    pub fn cell_mean(window_m: f64, cell_m: f64) -> Kernel {
        Kernel {
            window_m,
            node_var_m2: cell_m * cell_m / 12.0,
            noise_scale: 1.0 / (cell_m / window_m).max(1.0),
        }
    }

    /// A node as the plane fitted to points `spacing_m` apart within `radius_m`, weighted
    /// (1 − d²/R²)² ([`ElevationGrid::fill_scattered`]): on a disc those weights have
    /// E[x²] = R²/8. Its σ propagates the points as independent, as if from
    /// N = (Σw)²/Σw² = (5/9)·πR²/spacing² of them; windows wider than the spacing share their
    /// pixels, so only N·(spacing/W)² are (at least one): σ grows by min(W/spacing, √N).
    pub fn scattered(window_m: f64, spacing_m: f64, radius_m: f64) -> Kernel {
        let n = 5.0 / 9.0 * std::f64::consts::PI * (radius_m / spacing_m).powi(2);
        Kernel {
            window_m,
            node_var_m2: radius_m * radius_m / 8.0,
            noise_scale: (window_m / spacing_m).min(n.sqrt()).max(1.0),
        }
    }
}

/// What the averaging did, for the report.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AveragingReport {
    pub kernel: Kernel,
    /// Whether the nodes were moved (nodes no finer than about a window), or the bias only
    /// counted in their σ.
    pub moved: bool,
    /// The RMS of the corrections applied, m, and the largest.
    pub rms_correction_m: f64,
    pub max_correction_m: f64,
}

/// Moves each node of `grid` by the averaging bias of `kernel` (its window's and its node's),
/// and sets its σ to the matching's per independent window and the share of the correction
/// the nodes cannot resolve (module docs). Nodes without a height are left alone; a node
/// whose curvature cannot be fitted takes its neighbours'. `None` for a kernel that is not
/// positive numbers (nothing is changed).
pub fn remove_window_averaging(
    grid: &mut ElevationGrid,
    quality: &mut NodeQuality,
    kernel: Kernel,
) -> Option<AveragingReport> {
    let Kernel {
        window_m,
        node_var_m2,
        noise_scale,
    } = kernel;
    let ok = |v: f64| v.is_finite() && v > 0.0;
    if !(ok(window_m) && ok(noise_scale) && node_var_m2.is_finite() && node_var_m2 >= 0.0) {
        return None;
    }
    let reach = curvature_reach(window_m, grid.cell_m);
    let lap = laplacian(grid, reach);
    // Moved only where the nodes are no finer than about a window (see the module docs); the
    // σ keeps what is left, the whole bias where it is not taken out.
    let correct = reach == 1;
    let left = if correct {
        UNRESOLVED
    } else {
        UNRESOLVED.hypot(1.0)
    };
    let v = window_m * window_m / 12.0 + node_var_m2;
    let (mut ss, mut n, mut max) = (0.0, 0usize, 0.0f64);
    for (i, z) in grid.z.iter_mut().enumerate() {
        if !z.is_finite() {
            continue;
        }
        let b = if lap[i].is_finite() {
            0.5 * lap[i] * v
        } else {
            0.0
        };
        if correct {
            *z -= b as f32;
        }
        let s = quality.sigma_m[i] as f64;
        if s.is_finite() {
            quality.sigma_m[i] = (s * noise_scale).hypot(left * b) as f32;
        }
        ss += b * b;
        n += 1;
        max = max.max(b.abs());
    }
    Some(AveragingReport {
        kernel,
        moved: correct,
        rms_correction_m: if n > 0 { (ss / n as f64).sqrt() } else { 0.0 },
        max_correction_m: max,
    })
}

/// The half-width in nodes of the neighbourhood [`laplacian`] fits, about half a window
/// (a neighbourhood about a window and a cell wide): the curvature that moves a window's mean
/// is the terrain's at the window's scale, and a finer fit only amplifies the nodes' noise
/// (with 5 m windows on 1 m nodes a 3 × 3 fit moved nodes by metres of noise).
pub fn curvature_reach(window_m: f64, cell_m: f64) -> usize {
    ((window_m / (2.0 * cell_m)).round() as usize).clamp(1, MAX_REACH)
}

/// The widest neighbourhood fitted, nodes each side.
const MAX_REACH: usize = 16;

/// ∇²z at each node, per m: 2(c₂₀ + c₀₂) of the quadratic c₀₀ + c₁₀x + c₀₁y + c₂₀x² + c₁₁xy +
/// c₀₂y² fitted by least squares to the node's (2k + 1)² neighbourhood. On that full, symmetric
/// stencil the second-order terms are orthogonal to the others once x² is centred:
/// c₂₀ = Σᵢⱼ (xⱼ² − m)·z / ((2k + 1)·Σⱼ (xⱼ² − m)²), m the mean of xⱼ² (for k = 1 the mean of
/// the three rows' second differences over 6a²), and likewise c₀₂; the sums are taken along
/// columns first, so a node costs O(k). Nodes whose neighbourhood is not complete (the DEM's
/// edges, holes) take the mean of their neighbours' values, a ring at a time; NaN only where no
/// node has a curvature.
pub fn laplacian(grid: &ElevationGrid, k: usize) -> Vec<f64> {
    let (cols, rows, a) = (grid.cols, grid.rows, grid.cell_m);
    let n = 2 * k + 1;
    let mut lap = vec![f64::NAN; cols * rows];
    if cols < n || rows < n {
        crate::matching::grid::fill_holes(&mut lap, cols, rows);
        return lap;
    }
    let z = |c: usize, r: usize| grid.z[r * cols + c] as f64;
    // The centred squares of the offsets, and their sum of squares.
    let m = (0..n).map(|j| (j as f64 - k as f64).powi(2)).sum::<f64>() / n as f64;
    let dev: Vec<f64> = (0..n).map(|j| (j as f64 - k as f64).powi(2) - m).collect();
    let ss = dev.iter().map(|d| d * d).sum::<f64>();
    // Sums over the n rows around each row (per column), and over the n columns (per row).
    let mut down = vec![f64::NAN; cols * rows];
    let mut across = vec![f64::NAN; cols * rows];
    for r in k..rows - k {
        for c in 0..cols {
            down[r * cols + c] = (r - k..=r + k).map(|rr| z(c, rr)).sum();
        }
    }
    for r in 0..rows {
        for c in k..cols - k {
            across[r * cols + c] = (c - k..=c + k).map(|cc| z(cc, r)).sum();
        }
    }
    for r in k..rows - k {
        for c in k..cols - k {
            let (mut sx, mut sy) = (0.0, 0.0);
            for (j, d) in dev.iter().enumerate() {
                sx += d * down[r * cols + c + j - k];
                sy += d * across[(r + j - k) * cols + c];
            }
            // Offsets in nodes: c₂₀ per node², so /a² per m².
            let (c20, c02) = (sx / (n as f64 * ss), sy / (n as f64 * ss));
            lap[r * cols + c] = 2.0 * (c20 + c02) / (a * a);
        }
    }
    crate::matching::grid::fill_holes(&mut lap, cols, rows);
    lap
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid_of(f: impl Fn(f64, f64) -> f64, cell: f64, n: usize) -> ElevationGrid {
        let mut g = ElevationGrid::covering(
            [0.0, 0.0, cell * (n - 1) as f64, cell * (n - 1) as f64],
            cell,
            64,
        )
        .unwrap();
        for r in 0..g.rows {
            for c in 0..g.cols {
                let [x, y] = g.node(c, r);
                g.z[r * g.cols + c] = f(x, y) as f32;
            }
        }
        g
    }

    /// A paraboloid's Laplacian is its curvature sum, exactly, at every node (the edges from
    /// their neighbours, which on a quadratic hold the same value).
    #[test]
    fn the_laplacian_of_a_quadratic_is_exact_everywhere() {
        let f = |x: f64, y: f64| {
            500.0 + 0.3 * x - 0.2 * y + 0.002 * x * x + 0.001 * x * y - 0.003 * y * y
        };
        let g = grid_of(f, 10.0, 12);
        for k in [1, 2, 5] {
            let lap = laplacian(&g, k);
            for v in &lap {
                assert!((v - 2.0 * (0.002 - 0.003)).abs() < 2e-6, "k {k}: {v}");
            }
        }
        // A neighbourhood wider than the grid: no curvature anywhere.
        assert!(laplacian(&g, 6).iter().all(|v| v.is_nan()));
        assert_eq!(
            (curvature_reach(3.15, 1.0), curvature_reach(108.0, 80.0)),
            (2, 1)
        );
        assert_eq!(
            (curvature_reach(45.0, 80.0), curvature_reach(1e6, 1.0)),
            (1, 16)
        );
    }

    /// Windows of 50 m averaging a paraboloid, cells of 30 m averaging them again (both in
    /// closed form): the node moved back onto the terrain, σ with the correction's share.
    #[test]
    fn a_box_averaged_paraboloid_comes_back_to_the_terrain() {
        let (w, a, k) = (50.0, 30.0, 0.004);
        let terrain = |x: f64, y: f64| 200.0 + 0.5 * k * (x * x + y * y);
        // The mean of x² over a box of side s is s²/12; two boxes: (w² + a²)/12.
        let averaged = |x: f64, y: f64| terrain(x, y) + 0.5 * k * 2.0 * (w * w + a * a) / 12.0;
        let mut g = grid_of(averaged, a, 9);
        let n = g.z.len();
        let mut q = NodeQuality {
            sigma_m: vec![0.1; n],
            corr: vec![0.9; n],
        };
        let r = remove_window_averaging(&mut g, &mut q, Kernel::cell_mean(w, a)).unwrap();
        assert!(r.moved);
        let bias = 2.0 * k * (w * w + a * a) / 24.0;
        assert!((r.max_correction_m - bias).abs() < 1e-3, "{r:?} vs {bias}");
        for row in 0..g.rows {
            for col in 0..g.cols {
                let [x, y] = g.node(col, row);
                let i = row * g.cols + col;
                assert!((g.z[i] as f64 - terrain(x, y)).abs() < 2e-3, "{}", g.z[i]);
                // One window per cell (a < w): the matching's σ kept whole.
                let want = (0.01 + (UNRESOLVED * bias).powi(2)).sqrt();
                assert!(
                    (q.sigma_m[i] as f64 - want).abs() < 1e-4,
                    "{}",
                    q.sigma_m[i]
                );
            }
        }
        // Cells four windows wide: the matching σ halves; a plane is not moved.
        let mut plane = grid_of(|x, y| 10.0 + 0.2 * x + 0.1 * y, 40.0, 5);
        let mut q = NodeQuality {
            sigma_m: vec![0.2; 25],
            corr: vec![0.9; 25],
        };
        let before = plane.z.clone();
        let r = remove_window_averaging(&mut plane, &mut q, Kernel::cell_mean(20.0, 40.0)).unwrap();
        assert_eq!(r.kernel.noise_scale, 0.5);
        for (a, b) in plane.z.iter().zip(&before) {
            assert!((a - b).abs() < 1e-3);
        }
        assert!(q.sigma_m.iter().all(|s| (s - 0.1).abs() < 1e-4));
        assert!(
            remove_window_averaging(&mut plane, &mut q, Kernel::cell_mean(f64::NAN, 40.0))
                .is_none()
        );
        // A fill_scattered node: the disc's weights, and windows twice the spacing.
        let k = Kernel::scattered(20.0, 10.0, 16.0);
        assert_eq!((k.node_var_m2, k.noise_scale), (32.0, 2.0));
        // Windows wider than the disc: every point in it shares one window, √N.
        let k = Kernel::scattered(100.0, 10.0, 16.0);
        let n: f64 = 5.0 / 9.0 * std::f64::consts::PI * 1.6f64.powi(2);
        assert!((k.noise_scale - n.sqrt()).abs() < 1e-12, "{k:?}");
    }
}
