//! The default extent of a DEM: where a height can be computed. A point of the ground can have
//! one when two photos of an overlapping pair see it at the terrain's height; that height is
//! unknown, so the middle of the heights searched stands for it (demanding the lowest and the
//! highest too would cut a block's borders wherever the terrain is not at the range's ends:
//! on independent scenes that dropped 16–28 % of the heights a DEM can hold). The photos'
//! common ground is seldom a rectangle (a satellite's track is inclined, a block's photos are
//! turned, its corners seen by one photo only), while a DEM is: the default extent is the
//! rectangle holding the most of that common ground of which at least [`MIN_FILL`] is common
//! ground, so that the DEM holds a height nearly everywhere in it rather than leaving the
//! corners of a bounding box empty.

use crate::coords::GroundM;
use crate::geometry::Sensor;

/// The share of the default extent that two photos must see. Measured on six scenes (three
/// independent aerial blocks, the simulator's block, a pushbroom triplet, real RPC crops): at
/// 0.95 each DEM holds a height at 91–96 % of its extent and 93–100 % of the heights its
/// footprints' bounding box held; at 0.97, 94–99 % of the extent but only 90–97 % of the
/// heights.
pub const MIN_FILL: f64 = 0.95;

/// Cells per side of the ground sampled between the footprints.
const CELLS: usize = 64;

/// Pixels a seen point must lie inside its image: a correlation window's half and a pixel.
const EDGE_PX: f64 = 8.0;

/// The rectangle (xmin, ymin, xmax, ymax) within `bounds` where the pairs `pairs` of `sensors`
/// see the ground at the middle of `heights` (low, high), as described above; `None` where
/// no sample is seen.
pub fn covered_extent(
    sensors: &[&dyn Sensor],
    pairs: &[(usize, usize)],
    bounds: [f64; 4],
    heights: [f64; 2],
) -> Option<[f64; 4]> {
    let (dx, dy) = (
        (bounds[2] - bounds[0]) / CELLS as f64,
        (bounds[3] - bounds[1]) / CELLS as f64,
    );
    let z = 0.5 * (heights[0] + heights[1]);
    let sees = |s: &dyn Sensor, g: GroundM| {
        let (w, h) = s.image_size();
        s.ground_to_image(g).is_some_and(|q| {
            q.col >= EDGE_PX
                && q.row >= EDGE_PX
                && q.col <= w as f64 - EDGE_PX
                && q.row <= h as f64 - EDGE_PX
        })
    };
    // covered[j][i]: cell (i, j) from the south-west.
    let mut covered = vec![[false; CELLS]; CELLS];
    for (j, row) in covered.iter_mut().enumerate() {
        for (i, c) in row.iter_mut().enumerate() {
            let (x, y) = (
                bounds[0] + (i as f64 + 0.5) * dx,
                bounds[1] + (j as f64 + 0.5) * dy,
            );
            let g = GroundM::new(x, y, z);
            *c = pairs
                .iter()
                .any(|&(a, b)| sees(sensors[a], g) && sees(sensors[b], g));
        }
    }
    let [i0, j0, i1, j1] = fullest_rectangle(&covered, MIN_FILL)?;
    Some([
        bounds[0] + i0 as f64 * dx,
        bounds[1] + j0 as f64 * dy,
        bounds[0] + i1 as f64 * dx,
        bounds[1] + j1 as f64 * dy,
    ])
}

/// Of the rectangles of cells [i0, i1) × [j0, j1) whose covered share is at least `fill`, the
/// one holding the most covered cells (ties: the smaller); `None` when no cell is covered.
/// Every rectangle is tried through a summed-area table: 64⁴/4 sums.
fn fullest_rectangle(covered: &[[bool; CELLS]], fill: f64) -> Option<[usize; 4]> {
    let n = covered.len();
    // sum[j][i]: covered cells in [0, i) × [0, j).
    let mut sum = vec![vec![0u32; CELLS + 1]; n + 1];
    for j in 0..n {
        for i in 0..CELLS {
            sum[j + 1][i + 1] =
                sum[j][i + 1] + sum[j + 1][i] - sum[j][i] + u32::from(covered[j][i]);
        }
    }
    let mut best: Option<(u32, usize, [usize; 4])> = None;
    for j0 in 0..n {
        for j1 in j0 + 1..=n {
            for i0 in 0..CELLS {
                for i1 in i0 + 1..=CELLS {
                    let c = sum[j1][i1] + sum[j0][i0] - sum[j0][i1] - sum[j1][i0];
                    let area = (i1 - i0) * (j1 - j0);
                    if c == 0 || (c as f64) < fill * area as f64 {
                        continue;
                    }
                    let better = match best {
                        None => true,
                        Some((bc, ba, _)) => c > bc || (c == bc && area < ba),
                    };
                    if better {
                        best = Some((c, area, [i0, j0, i1, j1]));
                    }
                }
            }
        }
    }
    best.map(|(_, _, r)| r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::block::orient::vertical_sensor;

    /// A parallelogram of covered cells (a sheared overlap): the rectangle found holds at
    /// least the required share, and no rectangle of that share holds more (checked against
    /// the plain count of every rectangle).
    #[test]
    fn the_fullest_rectangle_of_a_sheared_overlap() {
        let mut c = vec![[false; CELLS]; CELLS];
        for (j, row) in c.iter_mut().enumerate().take(50).skip(10) {
            for (i, v) in row.iter_mut().enumerate() {
                let shift = j / 3;
                *v = (5 + shift..40 + shift).contains(&i);
            }
        }
        let [i0, j0, i1, j1] = fullest_rectangle(&c, 0.95).unwrap();
        let count = |i0: usize, j0: usize, i1: usize, j1: usize| {
            (j0..j1)
                .map(|j| (i0..i1).filter(|&i| c[j][i]).count())
                .sum::<usize>()
        };
        let got = count(i0, j0, i1, j1);
        let area = (i1 - i0) * (j1 - j0);
        assert!(got as f64 >= 0.95 * area as f64);
        // Brute force over a coarser set of rectangles: none better.
        for a in (0..CELLS).step_by(3) {
            for b in (a + 1..=CELLS).step_by(3) {
                for p in (0..CELLS).step_by(3) {
                    for q in (p + 1..=CELLS).step_by(3) {
                        let k = count(a, p, b, q);
                        if k as f64 >= 0.95 * ((b - a) * (q - p)) as f64 {
                            assert!(k <= got, "[{a}, {p}, {b}, {q}] holds {k} > {got}");
                        }
                    }
                }
            }
        }
        // Nearly all of the covered band's 40 rows, and less than its sheared bounding box.
        assert!(j1 - j0 >= 30 && got < 40 * 48, "{:?}", [i0, j0, i1, j1]);
        assert!(fullest_rectangle(&vec![[false; CELLS]; CELLS], 0.95).is_none());
    }

    /// Two vertical photos with a base along x: the ground both see at the middle height is
    /// the strip between the right photo's left edge and the left photo's right edge there
    /// (closed form), less the edge margin.
    #[test]
    fn two_vertical_photos_cover_their_common_strip_at_the_middle_height() {
        let (z0, f, side, p) = (1000.0, 100.0, 1000, 0.1);
        let l = vertical_sensor(GroundM::new(0.0, 0.0, z0), f, side, p);
        let r = vertical_sensor(GroundM::new(400.0, 0.0, z0), f, side, p);
        let heights = [0.0, 200.0];
        // Half the image on the ground at height z: (side/2 − edge)·p·(z0 − z)/f.
        let half = |z: f64| (side as f64 / 2.0 - EDGE_PX) * p * (z0 - z) / f;
        let want = [400.0 - half(100.0), -half(100.0), half(100.0), half(100.0)];
        let bounds = [-600.0, -600.0, 1000.0, 600.0];
        let e = covered_extent(&[&l, &r], &[(0, 1)], bounds, heights).unwrap();
        let cell = 1600.0 / CELLS as f64;
        for k in 0..4 {
            assert!((e[k] - want[k]).abs() <= cell, "{e:?} vs {want:?}");
        }
    }
}
