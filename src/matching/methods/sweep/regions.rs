//! Removal of wrong heights (seed 000 §2.3): matched pixels are grouped into homogeneous
//! regions — a pixel joins a region when some pixel of it within the neighbour search
//! distance differs in height by no more than the threshold. The height criterion then
//! removes, of two adjacent regions, the one with fewer pixels (so the one large region of
//! correct heights survives and the islands of wrong ones within it go); the population
//! criterion removes every region left with fewer pixels than a threshold (wrong heights
//! where there is nothing around to compare with, e.g. in featureless areas).

use crate::matching::methods::sweep::height_sweep::HeightMap;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RegionParams {
    /// Neighbour search distance, cells of the height map (seed 000: 2 pixels).
    pub search_distance: usize,
    /// Largest height difference within a region, m (seed 000: about 1.5 × the height step).
    pub height_threshold: f64,
    /// Regions with fewer pixels are removed.
    pub population_threshold: usize,
}

/// The figures of seed 000 Table 4.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RegionStats {
    pub points: usize,
    pub matched: usize,
    pub regions: usize,
    pub regions_removed_by_height: usize,
    pub regions_removed_by_population: usize,
    pub regions_left: usize,
    pub points_removed: usize,
    pub points_left: usize,
}

impl RegionStats {
    pub fn percent(part: usize, whole: usize) -> f64 {
        100.0 * part as f64 / whole.max(1) as f64
    }
}

fn find(parent: &mut [usize], mut i: usize) -> usize {
    while parent[i] != i {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    i
}

/// Labels the regions, applies both criteria, sets removed heights to NaN.
pub fn remove_wrong_heights(m: &mut HeightMap, p: &RegionParams) -> RegionStats {
    let (w, h) = (m.cols, m.rows);
    let n = w * h;
    let d = p.search_distance.max(1) as i64;
    let ok = |i: usize| m.h[i].is_finite();
    let mut parent: Vec<usize> = (0..n).collect();
    // Pairs within the search distance: joined when close in height, else remembered as a
    // border between (possibly) different regions.
    let mut borders = Vec::new();
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            let i = (y * w as i64 + x) as usize;
            if !ok(i) {
                continue;
            }
            // Each unordered pair once: the neighbours after this cell in raster order.
            for dy in 0..=d {
                for dx in -d..=d {
                    if dy == 0 && dx <= 0 {
                        continue;
                    }
                    let (xx, yy) = (x + dx, y + dy);
                    if xx < 0 || xx >= w as i64 || yy >= h as i64 {
                        continue;
                    }
                    let j = (yy * w as i64 + xx) as usize;
                    if !ok(j) {
                        continue;
                    }
                    if ((m.h[i] - m.h[j]).abs() as f64) <= p.height_threshold {
                        let (a, b) = (find(&mut parent, i), find(&mut parent, j));
                        if a != b {
                            parent[a.max(b)] = a.min(b);
                        }
                    } else {
                        borders.push((i, j));
                    }
                }
            }
        }
    }
    let mut size = vec![0usize; n];
    let mut matched = 0;
    for i in 0..n {
        if ok(i) {
            matched += 1;
            let r = find(&mut parent, i);
            size[r] += 1;
        }
    }
    let regions = size.iter().filter(|&&s| s > 0).count();
    // Height criterion: of two adjacent regions the smaller goes (both when equal).
    let mut removed = vec![false; n];
    for &(i, j) in &borders {
        let (a, b) = (find(&mut parent, i), find(&mut parent, j));
        if a == b {
            continue;
        }
        if size[a] <= size[b] {
            removed[a] = true;
        }
        if size[b] <= size[a] {
            removed[b] = true;
        }
    }
    let by_height = (0..n).filter(|&r| size[r] > 0 && removed[r]).count();
    // Population criterion on what is left.
    let mut by_population = 0;
    for r in 0..n {
        if size[r] > 0 && !removed[r] && size[r] < p.population_threshold {
            removed[r] = true;
            by_population += 1;
        }
    }
    let mut points_removed = 0;
    for i in 0..n {
        if m.h[i].is_finite() && removed[find(&mut parent, i)] {
            m.h[i] = f32::NAN;
            points_removed += 1;
        }
    }
    RegionStats {
        points: n,
        matched,
        regions,
        regions_removed_by_height: by_height,
        regions_removed_by_population: by_population,
        regions_left: regions - by_height - by_population,
        points_removed,
        points_left: matched - points_removed,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(w: usize, h: usize, f: impl Fn(usize, usize) -> f32) -> HeightMap {
        HeightMap {
            cols: w,
            rows: h,
            col0: 0,
            row0: 0,
            stride: 1,
            h: (0..w * h).map(|i| f(i % w, i / w)).collect(),
            corr: vec![1.0; w * h],
            sigma: vec![0.1; w * h],
            candidates: 0,
        }
    }

    #[test]
    fn islands_of_wrong_heights_and_small_lonely_regions_go() {
        // A slope (0.5 m per cell) with: a 4×4 island 40 m too high, a single spike, and a
        // 3×3 patch cut off by unmatched cells all round (lonely, but correct heights).
        let m0 = map(60, 50, |x, y| {
            if (10..14).contains(&x) && (10..14).contains(&y) {
                return 400.0 + 0.5 * x as f32 + 40.0;
            }
            if (x, y) == (30, 30) {
                return 900.0;
            }
            if (44..53).contains(&x) && (38..47).contains(&y) {
                if (47..50).contains(&x) && (41..44).contains(&y) {
                    return 400.0 + 0.5 * x as f32;
                }
                return f32::NAN;
            }
            400.0 + 0.5 * x as f32
        });
        let mut m = m0.clone();
        let s = remove_wrong_heights(
            &mut m,
            &RegionParams {
                search_distance: 2,
                height_threshold: 3.0,
                population_threshold: 20,
            },
        );
        assert_eq!(s.regions, 4, "{s:?}");
        assert_eq!(s.regions_removed_by_height, 2);
        assert_eq!(s.regions_removed_by_population, 1);
        assert_eq!(s.regions_left, 1);
        assert_eq!(s.points_removed, 16 + 1 + 9);
        assert!(m.h[12 * 60 + 12].is_nan() && m.h[30 * 60 + 30].is_nan());
        assert!(m.h[42 * 60 + 48].is_nan());
        assert!(m.h[0].is_finite() && m.h[49 * 60 + 59].is_finite());
    }
}
