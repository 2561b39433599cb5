//! Where to match at the finest level (seed 002, "feature based selection of D.T.M. points"):
//! an interest operator that looks for grey-value edges across the epipolar lines (the
//! constrained matching moves each patch along its epipolar line, so an edge along that line
//! fixes nothing), with masks 3 wide across the edge and 5-7 long along it (the length keeps
//! out noise, which is steep but short), a threshold, and the best point in each cell of
//! 21-29 px; or, as the alternative, a regular grid.

use crate::coords::PixelXY;
use crate::geometry::Sensor;
use crate::image::ImageF32;
use serde::{Deserialize, Serialize};

pub use crate::matching::project::matchers::Selection;

/// Parameters of the selection.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct InterestParams {
    pub selection: Selection,
    /// Side of a cell, px: one point per cell at most (seed: 21-29).
    pub cell: usize,
    /// Length of the mask along the edge, px (seed: 5-7).
    pub length: usize,
    /// The smallest mean grey-value gradient across an edge that makes a point, grey values
    /// per pixel.
    pub threshold: f64,
    /// Points keep this far from the image's edges, px.
    pub margin: usize,
}

/// A selected point: its pixel in the reference image and the operator's value there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interest {
    pub pixel: (usize, usize),
    pub strength: f64,
}

/// The unit direction of search photo `search`'s epipolar line in the reference image at
/// pixel `q` (continuous, corner origin), from the ray through `q` at height `z` and the
/// search photo's ray back through it at `z + dz`.
pub fn epipolar_direction(
    reference: &dyn Sensor,
    search: &dyn Sensor,
    q: PixelXY,
    z: f64,
    dz: f64,
) -> Option<[f64; 2]> {
    let g = reference.image_to_ground(q, z)?;
    let qs = search.ground_to_image(g)?;
    let g1 = search.image_to_ground(qs, z + dz)?;
    let q1 = reference.ground_to_image(g1)?;
    let (dx, dy) = (q1.col - q.col, q1.row - q.row);
    let n = dx.hypot(dy);
    (n > 1e-9 && n.is_finite()).then_some([dx / n, dy / n])
}

/// The operator's value at pixel (c, r) for edges across direction `d` (unit): the mean over
/// the mask's `length` positions along the edge of the central difference across it.
fn across(img: &ImageF32, c: usize, r: usize, d: [f64; 2], length: usize) -> Option<f64> {
    let e = [-d[1], d[0]];
    let half = (length as f64 - 1.0) / 2.0;
    let (x0, y0) = (c as f64 + 0.5, r as f64 + 0.5);
    let mut s = 0.0;
    for i in 0..length {
        let t = i as f64 - half;
        let (x, y) = (x0 + t * e[0], y0 + t * e[1]);
        let a = img.bilinear(x + d[0], y + d[1])? as f64;
        let b = img.bilinear(x - d[0], y - d[1])? as f64;
        s += 0.5 * (a - b);
    }
    Some((s / length as f64).abs())
}

/// The points of `img` for matching along `directions` (one per search photo, unit vectors in
/// the image): one per cell, in row-major order of the cells.
pub fn select(img: &ImageF32, directions: &[[f64; 2]], p: &InterestParams) -> Vec<Interest> {
    let cell = p.cell.max(1);
    let m = p.margin;
    if img.width <= 2 * m || img.height <= 2 * m {
        return Vec::new();
    }
    let (w, h) = (img.width - 2 * m, img.height - 2 * m);
    let mut out = Vec::new();
    for cy in 0..h / cell {
        for cx in 0..w / cell {
            let (c0, r0) = (m + cx * cell, m + cy * cell);
            match p.selection {
                Selection::Grid => out.push(Interest {
                    pixel: (c0 + cell / 2, r0 + cell / 2),
                    strength: f64::NAN,
                }),
                Selection::Operator => {
                    let mut best: Option<Interest> = None;
                    for r in r0..r0 + cell {
                        for c in c0..c0 + cell {
                            let v = directions
                                .iter()
                                .filter_map(|&d| across(img, c, r, d, p.length))
                                .fold(0.0, f64::max);
                            if v >= p.threshold && best.is_none_or(|b| v > b.strength) {
                                best = Some(Interest {
                                    pixel: (c, r),
                                    strength: v,
                                });
                            }
                        }
                    }
                    out.extend(best);
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A vertical step edge at column 40.5 in a flat image: matching along rows (direction
    /// (1, 0)) finds it, at the edge, with half the step per pixel as its value; matching along
    /// columns (direction (0, 1)) finds nothing; the grid ignores the texture.
    #[test]
    fn edges_across_the_epipolar_lines_are_found_and_edges_along_them_are_not() {
        let mut img = ImageF32::new(100, 60);
        for r in 0..60 {
            for c in 0..100 {
                img.data[r * 100 + c] = if c <= 40 { 10.0 } else { 30.0 };
            }
        }
        let p = InterestParams {
            selection: Selection::Operator,
            cell: 25,
            length: 7,
            threshold: 2.0,
            margin: 5,
        };
        let pts = select(&img, &[[1.0, 0.0]], &p);
        // Cells: columns 5-29, 30-54, 55-79 in rows 5-29 and 30-54: the edge lies in the
        // middle column of cells.
        assert_eq!(pts.len(), 2, "{pts:?}");
        for q in &pts {
            assert!(q.pixel.0 == 40 || q.pixel.0 == 41, "{q:?}");
            assert!((q.strength - 10.0).abs() < 1e-6, "{q:?}");
        }
        assert!(select(&img, &[[0.0, 1.0]], &p).is_empty());
        let grid = select(
            &img,
            &[[0.0, 1.0]],
            &InterestParams {
                selection: Selection::Grid,
                ..p
            },
        );
        assert_eq!(grid.len(), 6);
        assert_eq!(grid[0].pixel, (17, 17));
    }
}
