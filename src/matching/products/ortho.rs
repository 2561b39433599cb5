//! An orthophoto on the elevation model's grid: each node that has a height is projected into
//! the photos that see it and takes the grey value of the one that sees it most nearly from
//! above (its image point nearest that photo's centre), so that relief displacement and the
//! seams between photos stay small.

use crate::coords::{GroundM, PixelXY};
use crate::image::ImageF32;
use crate::matching::grid::ElevationGrid;
use rayon::prelude::*;

/// A photo as the orthophoto sees it: its grey values and where a ground point falls in it
/// (continuous pixel coordinates, as [`ImageF32::bilinear`] takes them).
pub struct View<'a> {
    pub image: &'a ImageF32,
    pub project: &'a (dyn Fn(GroundM) -> Option<PixelXY> + Sync),
}

/// Grey value per node (row-major, as the grid), NaN where the node has no height or no photo
/// sees it.
pub fn orthophoto(grid: &ElevationGrid, views: &[View<'_>]) -> Vec<f32> {
    (0..grid.rows)
        .into_par_iter()
        .flat_map_iter(|r| {
            (0..grid.cols).map(move |c| {
                let z = grid.z[r * grid.cols + c];
                if !z.is_finite() {
                    return f32::NAN;
                }
                let [x, y] = grid.node(c, r);
                let g = GroundM::new(x, y, z as f64);
                let mut best = (f64::INFINITY, f32::NAN);
                for v in views {
                    let Some(q) = (v.project)(g) else { continue };
                    let Some(grey) = v.image.bilinear(q.col, q.row) else {
                        continue;
                    };
                    let (w, h) = (v.image.width as f64, v.image.height as f64);
                    // Distance from the centre as a share of the half-diagonal: comparable
                    // between photos of different sizes.
                    let d = (q.col - 0.5 * w).hypot(q.row - 0.5 * h) / (0.5 * w.hypot(h));
                    if d < best.0 {
                        best = (d, grey);
                    }
                }
                best.1
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two "photos" that are plain affine views of a ground pattern: the ortho must give back
    /// the pattern wherever a photo sees it, from the photo nearer its centre.
    #[test]
    fn nodes_take_the_grey_value_of_the_most_central_view() {
        let mut g = ElevationGrid::covering([0.0, 0.0, 39.0, 19.0], 1.0, 64).unwrap();
        g.z.iter_mut().for_each(|z| *z = 100.0);
        g.z[5] = f32::NAN;
        // Ground pattern: grey = 2x + 3y, and photo b reads 1000 brighter.
        let img = |x0: f64, offset: f64| {
            let mut im = ImageF32::new(30, 30);
            for r in 0..30 {
                for c in 0..30 {
                    // Pixel (c, r)'s centre shows ground (x0 + c, 25 − r).
                    let (x, y) = (x0 + c as f64, 25.0 - r as f64);
                    im.data[r * 30 + c] = (2.0 * x + 3.0 * y + offset) as f32;
                }
            }
            im
        };
        let (a, b) = (img(0.0, 0.0), img(15.0, 1000.0));
        let pa = |g: GroundM| Some(PixelXY::new(g.x + 0.5, 25.0 - g.y + 0.5));
        let pb = |g: GroundM| Some(PixelXY::new(g.x - 15.0 + 0.5, 25.0 - g.y + 0.5));
        let views = [
            View {
                image: &a,
                project: &pa,
            },
            View {
                image: &b,
                project: &pb,
            },
        ];
        let o = orthophoto(&g, &views);
        // Photo a's centre shows x = 14.5, b's x = 29.5: nodes west of x = 22 come from a.
        for r in 0..g.rows {
            for c in 0..g.cols {
                let [x, y] = g.node(c, r);
                let v = o[r * g.cols + c];
                if r * g.cols + c == 5 {
                    assert!(v.is_nan(), "node ({c}, {r}) has no height");
                } else if x != 22.0 {
                    let want = 2.0 * x + 3.0 * y + if x > 22.0 { 1000.0 } else { 0.0 };
                    assert!(
                        (v - want as f32).abs() < 1e-3,
                        "node ({c}, {r}): {v}, not {want}"
                    );
                }
            }
        }
    }
}
