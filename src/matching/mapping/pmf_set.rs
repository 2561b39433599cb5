//! The mappings of a stereo pair as polynomial mapping functions: image→image (what the
//! height sweep follows), image→ground and ground→image for both photos, and the height from
//! a triplet (x′, y′, x″). Fitted to ground control points with the terms chosen by check
//! points (seed 000), or derived from any two sensors on a 5×5 grid of the left image at
//! three heights (seed 004 §4), the check points then at the cells' centres at two heights in
//! between. Image coordinates are pixels of each photo (continuous, corner origin).

use crate::coords::{GroundM, PixelView, PixelXY};
use crate::geometry::Sensor;
use crate::matching::mapping::pmf::{
    extend, select, select_order, Mapping, PmfError, Polynomial, Sample, Selection, Units,
};
use serde::{Deserialize, Serialize};

/// A point seen in both photos, with its ground coordinates.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StereoPoint {
    pub id: String,
    /// Pixel (column, row) in the left and the right photo.
    pub left: [f64; 2],
    pub right: [f64; 2],
    pub ground: GroundM,
}

/// How one polynomial came out (seed 000 Table 2's rows).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitReport {
    pub name: String,
    /// The order whose full form the terms were chosen from (given, or by the check points).
    #[serde(default)]
    pub order: u8,
    pub terms: usize,
    pub gcp_rmse: f64,
    pub cp_rmse: f64,
    pub units: String,
    /// The terms seed 004's extended set added to the basic one (none: the basic set).
    #[serde(default)]
    pub extended: Vec<String>,
    /// The check points' RMSE in the other space, where the ground pixel converts it
    /// (metres for a mapping into an image, pixels for one onto the ground; mappings from
    /// sensors only).
    #[serde(default)]
    pub cp_rmse_other: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PmfSet {
    /// (x′, y′, h) → (x″, y″).
    pub left_to_right: Mapping,
    /// (x″, y″, h) → (x′, y′) (seed 004's sixth mapping; absent from older files).
    #[serde(default)]
    pub right_to_left: Option<Mapping>,
    /// (x′, y′, h) → (X, Y).
    pub left_to_ground: Mapping,
    /// (x″, y″, h) → (X, Y).
    pub right_to_ground: Mapping,
    /// (X, Y, h) → (x′, y′).
    pub ground_to_left: Mapping,
    /// (X, Y, h) → (x″, y″).
    pub ground_to_right: Mapping,
    /// (x′, y′, x″) → h.
    pub height: Polynomial,
    pub report: Vec<FitReport>,
}

/// Which of seed 004's term sets a fit may use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum TermSet {
    /// The terms chosen from the full form of the order.
    Basic,
    /// The basic terms and up to two fourth-order ones in y where the check points want
    /// them (a line scanner with a quadratic orbit).
    Extended,
}

fn chosen(
    name: &str,
    units: &str,
    (order, set): (u8, TermSet),
    g: &[Sample],
    c: &[Sample],
    report: &mut Vec<FitReport>,
) -> Result<Polynomial, PmfError> {
    // Order 0: chosen by the check points among 1 … 3.
    let (order, s): (u8, Selection) = if order == 0 {
        select_order(g, c)?
    } else {
        (order, select(order, g, c)?)
    };
    let (s, added) = match set {
        TermSet::Basic => (s, Vec::new()),
        TermSet::Extended => extend(s, g, c),
    };
    report.push(FitReport {
        name: name.into(),
        order,
        terms: s.poly.terms.len(),
        gcp_rmse: s.gcp_rmse,
        cp_rmse: s.cp_rmse,
        units: units.into(),
        extended: added.iter().map(|t| t.to_string()).collect(),
        cp_rmse_other: None,
    });
    Ok(s.poly)
}

/// The grid a sensor is sampled on (seed 004 §4): `n` × `n` over the left image at `levels`
/// heights from the lowest to the highest; the check points at the cells' centres at the
/// heights between.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct SampleGrid {
    pub n: usize,
    pub levels: usize,
}

impl SampleGrid {
    /// Seed 004's own: 5 × 5 at three heights (75 points).
    pub const SEED_004: SampleGrid = SampleGrid { n: 5, levels: 3 };
}

impl Default for SampleGrid {
    /// 5 × 5 at five heights: a frame pair's parallax goes with 1/(Z₀ − h), whose cubic term
    /// is still a tenth of a pixel over a few hundred metres, and at three heights h³ cannot
    /// be told from h.
    fn default() -> Self {
        SampleGrid { n: 5, levels: 5 }
    }
}

/// A view's pixel units in its image's: image = f · view + the window's corner.
fn view_units(v: PixelView) -> [Units; 2] {
    let f = v.scale();
    [
        Units {
            scale: f,
            offset: v.window.col0 as f64,
        },
        Units {
            scale: f,
            offset: v.window.row0 as f64,
        },
    ]
}

impl PmfSet {
    /// The same mappings for each photo's pixels in other units: old pixel = `scale` · new +
    /// `offset` (per photo: `left`, `right`, each [col, row]), as a view read from each image
    /// counts them ([`crate::coords::PixelView`]), or back. The ground is unchanged.
    pub fn in_pixels(&self, left: [Units; 2], right: [Units; 2]) -> PmfSet {
        let s = Units::SAME;
        let (l, r) = ([left[0], left[1], s], [right[0], right[1], s]);
        PmfSet {
            left_to_right: self.left_to_right.in_units(l, right),
            right_to_left: self.right_to_left.as_ref().map(|m| m.in_units(r, left)),
            left_to_ground: self.left_to_ground.in_units(l, [s, s]),
            right_to_ground: self.right_to_ground.in_units(r, [s, s]),
            ground_to_left: self.ground_to_left.in_units([s; 3], left),
            ground_to_right: self.ground_to_right.in_units([s; 3], right),
            height: self.height.with_variables_in([left[0], left[1], right[0]]),
            report: self.report.clone(),
        }
    }

    /// The mappings of whole images' pixels in the pixels of `left` and `right` views of them.
    pub fn in_views(&self, left: PixelView, right: PixelView) -> PmfSet {
        self.in_pixels(view_units(left), view_units(right))
    }

    /// The mappings of views' pixels in their whole images' pixels (the inverse of
    /// [`PmfSet::in_views`]).
    pub fn from_views(&self, left: PixelView, right: PixelView) -> PmfSet {
        let back = |v: PixelView| {
            view_units(v).map(|u| Units {
                scale: 1.0 / u.scale,
                offset: -u.offset / u.scale,
            })
        };
        self.in_pixels(back(left), back(right))
    }

    /// All six mappings from control and check points, terms chosen from the full form of
    /// `order` (seed 000 started from the second order; third gave no better accuracy).
    pub fn from_points(
        order: u8,
        gcps: &[StereoPoint],
        cps: &[StereoPoint],
    ) -> Result<PmfSet, PmfError> {
        Self::from_points_with(order, TermSet::Basic, gcps, cps)
    }

    /// [`PmfSet::from_points`] with the term set named.
    pub fn from_points_with(
        order: u8,
        set: TermSet,
        gcps: &[StereoPoint],
        cps: &[StereoPoint],
    ) -> Result<PmfSet, PmfError> {
        let order = (order, set);
        let mut report = Vec::new();
        let mut pair = |name: &str,
                        units: &str,
                        from: &dyn Fn(&StereoPoint) -> [f64; 3],
                        to: &dyn Fn(&StereoPoint) -> [f64; 2]|
         -> Result<Mapping, PmfError> {
            let s = |pts: &[StereoPoint], k: usize| -> Vec<Sample> {
                pts.iter().map(|p| (from(p), to(p)[k])).collect()
            };
            Ok(Mapping {
                x: chosen(
                    &format!("{name} x"),
                    units,
                    order,
                    &s(gcps, 0),
                    &s(cps, 0),
                    &mut report,
                )?,
                y: chosen(
                    &format!("{name} y"),
                    units,
                    order,
                    &s(gcps, 1),
                    &s(cps, 1),
                    &mut report,
                )?,
            })
        };
        let left = |p: &StereoPoint| [p.left[0], p.left[1], p.ground.z];
        let right = |p: &StereoPoint| [p.right[0], p.right[1], p.ground.z];
        let ground = |p: &StereoPoint| [p.ground.x, p.ground.y, p.ground.z];
        let left_to_right = pair("left→right", "px", &left, &|p| p.right)?;
        let right_to_left = pair("right→left", "px", &right, &|p| p.left)?;
        let left_to_ground = pair("left→ground", "m", &left, &|p| [p.ground.x, p.ground.y])?;
        let right_to_ground = pair("right→ground", "m", &right, &|p| [p.ground.x, p.ground.y])?;
        let ground_to_left = pair("ground→left", "px", &ground, &|p| p.left)?;
        let ground_to_right = pair("ground→right", "px", &ground, &|p| p.right)?;
        let triplet = |pts: &[StereoPoint]| -> Vec<Sample> {
            pts.iter()
                .map(|p| ([p.left[0], p.left[1], p.right[0]], p.ground.z))
                .collect()
        };
        let height = chosen(
            "height from (x′, y′, x″)",
            "m",
            order,
            &triplet(gcps),
            &triplet(cps),
            &mut report,
        )?;
        Ok(PmfSet {
            left_to_right,
            right_to_left: Some(right_to_left),
            left_to_ground,
            right_to_ground,
            ground_to_left,
            ground_to_right,
            height,
            report,
        })
    }

    /// Seed 004 §4 on the default grid ([`SampleGrid::default`], 5 × 5 at five heights) with
    /// the basic terms.
    pub fn from_sensors(
        left: &dyn Sensor,
        right: &dyn Sensor,
        heights: [f64; 2],
        order: u8,
    ) -> Result<PmfSet, PmfError> {
        Self::from_sensors_on(
            left,
            right,
            heights,
            order,
            SampleGrid::default(),
            TermSet::Basic,
        )
    }

    /// Seed 004 §4: a grid over the left photo at several heights from the lowest to the
    /// highest through the rigorous models into the ground and the right photo, the check
    /// points at the grid cells' centres at the heights in between; each fit's check-point
    /// RMSE also in the other space (the left photo's ground pixel at the middle height).
    pub fn from_sensors_on(
        left: &dyn Sensor,
        right: &dyn Sensor,
        heights: [f64; 2],
        order: u8,
        grid: SampleGrid,
        set: TermSet,
    ) -> Result<PmfSet, PmfError> {
        if !(2..=50).contains(&grid.n) || !(2..=20).contains(&grid.levels) {
            return Err(PmfError::Grid(grid.n, grid.levels));
        }
        let (w, h) = left.image_size();
        let (w, h) = (w as f64, h as f64);
        let point = |id: String, px: [f64; 2], z: f64| -> Option<StereoPoint> {
            let g = left.image_to_ground(PixelXY::new(px[0], px[1]), z)?;
            let q = right.ground_to_image(g)?;
            Some(StereoPoint {
                id,
                left: px,
                right: [q.col, q.row],
                ground: g,
            })
        };
        let [lo, hi] = heights;
        let (n, levels) = (grid.n, grid.levels);
        let cell = (n - 1) as f64;
        let level = |t: f64| lo + (hi - lo) * t / (levels - 1) as f64;
        let mut gcps = Vec::new();
        for (k, z) in (0..levels).map(|k| level(k as f64)).enumerate() {
            for j in 0..n {
                for i in 0..n {
                    let px = [w * i as f64 / cell, h * j as f64 / cell];
                    gcps.extend(point(format!("g{i}_{j}_{k}"), px, z));
                }
            }
        }
        let mut cps = Vec::new();
        for (k, z) in (0..levels - 1).map(|k| level(k as f64 + 0.5)).enumerate() {
            for j in 0..n - 1 {
                for i in 0..n - 1 {
                    let px = [w * (i as f64 + 0.5) / cell, h * (j as f64 + 0.5) / cell];
                    cps.extend(point(format!("c{i}_{j}_{k}"), px, z));
                }
            }
        }
        let mut set = Self::from_points_with(order, set, &gcps, &cps)?;
        // The ground pixel: the left photo's neighbouring pixels at the middle height.
        let mid = 0.5 * (lo + hi);
        let gsd = match (
            left.image_to_ground(PixelXY::new(0.5 * w, 0.5 * h), mid),
            left.image_to_ground(PixelXY::new(0.5 * w + 1.0, 0.5 * h + 1.0), mid),
        ) {
            (Some(a), Some(b)) => (a.x - b.x).hypot(a.y - b.y) / 2f64.sqrt(),
            _ => f64::NAN,
        };
        if gsd.is_finite() && gsd > 0.0 {
            for r in set.report.iter_mut().filter(|r| r.name.contains('→')) {
                r.cp_rmse_other = Some(if r.units == "px" {
                    r.cp_rmse * gsd
                } else {
                    r.cp_rmse / gsd
                });
            }
        }
        Ok(set)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pushbroom::fixtures::spot_like;
    use crate::geometry::Pushbroom;

    /// A SPOT-like across-track pair from two passes (−20°, +20°, 10 m pixels) with a curved
    /// orbit and a drifting attitude (the quadratic model of seed 004's rigorous solution).
    fn pair() -> (Pushbroom, Pushbroom) {
        (spot_like(-20.0), spot_like(20.0))
    }

    /// Mappings in views' pixels read the same geometry: at points of a SPOT pair, every
    /// mapping of the set in the views, given the views' pixels, gives the views' values (a
    /// second computation: the original set, the pixels converted by hand); back from the
    /// views, the same values as the original.
    #[test]
    fn mappings_in_views_hold_the_same_geometry() {
        use crate::coords::PixelWindow;
        let (l, r) = pair();
        let s = PmfSet::from_sensors(&l, &r, [0.0, 2000.0], 2).unwrap();
        let view = |col0: usize, row0: usize, factor: usize| PixelView {
            window: PixelWindow {
                col0,
                row0,
                width: 4000,
                height: 4000,
            },
            factor,
        };
        for (vl, vr) in [
            (view(1234, 77, 1), view(301, 4096, 1)),
            (view(1234, 77, 4), view(300, 16, 8)),
        ] {
            let m = s.in_views(vl, vr);
            let to_l = |p: [f64; 2]| {
                let (x, y) = vl.to_read(p[0], p[1]);
                [x, y]
            };
            let to_r = |p: [f64; 2]| {
                let (x, y) = vr.to_read(p[0], p[1]);
                [x, y]
            };
            let back = m.from_views(vl, vr);
            for (x, y, h) in [
                (100.0, 200.0, 50.0),
                (2900.0, 1500.0, 1800.0),
                (0.0, 0.0, 0.0),
            ] {
                let close = |a: [f64; 2], b: [f64; 2]| {
                    assert!(
                        (a[0] - b[0]).abs() < 1e-6 && (a[1] - b[1]).abs() < 1e-6,
                        "{a:?} {b:?}"
                    )
                };
                let (lw, g) = (to_l([x, y]), s.left_to_ground.eval([x, y, h]));
                let q = s.left_to_right.eval([x, y, h]);
                let rw = to_r(q);
                close(m.left_to_right.eval([lw[0], lw[1], h]), rw);
                close(back.left_to_right.eval([x, y, h]), q);
                close(m.left_to_ground.eval([lw[0], lw[1], h]), g);
                let bl = s.right_to_left.as_ref().unwrap().eval([q[0], q[1], h]);
                let mb = m.right_to_left.as_ref().unwrap();
                close(mb.eval([rw[0], rw[1], h]), to_l(bl));
                close(
                    m.right_to_ground.eval([rw[0], rw[1], h]),
                    s.right_to_ground.eval([q[0], q[1], h]),
                );
                let gl = s.ground_to_left.eval([g[0], g[1], h]);
                close(m.ground_to_left.eval([g[0], g[1], h]), to_l(gl));
                let gr = s.ground_to_right.eval([g[0], g[1], h]);
                close(m.ground_to_right.eval([g[0], g[1], h]), to_r(gr));
                let z = s.height.eval([x, y, q[0]]);
                assert!((m.height.eval([lw[0], lw[1], rw[0]]) - z).abs() < 1e-6);
                assert!((back.height.eval([x, y, q[0]]) - z).abs() < 1e-6);
            }
        }
        // The whole images as they are: the same set, to the last bit.
        assert_eq!(
            s.in_views(PixelView::whole(9, 9), PixelView::whole(9, 9)),
            s
        );
    }

    /// Seed 004's check of the mapping functions: every one of the six, on seed 004's own
    /// 5 × 5 × 3 grid and on the default 5 × 5 × 5, basic and extended, within 1 m in object
    /// space and 1 µm (0.077 SPOT pixels) in image space at the check points, and the
    /// extended set never worse than the basic.
    #[test]
    fn all_six_mappings_of_a_spot_pair_meet_seed_004s_check() {
        let (l, r) = pair();
        let heights = [0.0, 2000.0];
        for grid in [SampleGrid::SEED_004, SampleGrid::default()] {
            let mut basic_rmse = Vec::new();
            for set in [TermSet::Basic, TermSet::Extended] {
                let s = PmfSet::from_sensors_on(&l, &r, heights, 0, grid, set).unwrap();
                assert!(s.right_to_left.is_some());
                let maps: Vec<&FitReport> =
                    s.report.iter().filter(|f| f.name.contains('→')).collect();
                assert_eq!(maps.len(), 12, "six mappings, two coordinates each");
                for (k, f) in maps.iter().enumerate() {
                    let (px, m) = if f.units == "px" {
                        (f.cp_rmse, f.cp_rmse_other.unwrap())
                    } else {
                        (f.cp_rmse_other.unwrap(), f.cp_rmse)
                    };
                    eprintln!(
                        "{grid:?} {set:?} {}: {} terms (order {}, added {:?}), check points {px:.2e} px = {m:.2e} m",
                        f.name, f.terms, f.order, f.extended
                    );
                    assert!(px <= 0.077 && m <= 1.0, "{f:?}");
                    if set == TermSet::Basic {
                        basic_rmse.push(f.cp_rmse);
                    } else {
                        assert!(f.cp_rmse <= basic_rmse[k] * (1.0 + 1e-9), "{f:?}");
                    }
                }
            }
        }
        assert!(PmfSet::from_sensors_on(
            &l,
            &r,
            heights,
            0,
            SampleGrid { n: 1, levels: 3 },
            TermSet::Basic
        )
        .is_err());
    }
}

#[cfg(test)]
mod extended_tests {
    use super::*;
    use crate::geometry::pushbroom::fixtures::spot_like;

    /// Seed 004: the extended set is for a rigorous solution with a quadratic model. On a
    /// long strip (24 000 lines, 240 km) whose attitude drifts quadratically the fourth-order
    /// terms in y are chosen by the check points, and the image → image mapping along the
    /// track fits them 30 times better; where they do not help they are not taken.
    #[test]
    fn a_long_strip_with_a_quadratic_drift_takes_the_extended_terms() {
        let strip = |deg: f64| {
            let mut m = spot_like(deg);
            m.lines = 24_000;
            m.attitude[0][2] = 1e-7;
            m.attitude[1][2] = 2e-7;
            m.position[0][2] = 3.0;
            m
        };
        let (l, r) = (strip(-20.0), strip(20.0));
        let fit = |set| {
            PmfSet::from_sensors_on(&l, &r, [0.0, 2000.0], 0, SampleGrid::SEED_004, set).unwrap()
        };
        let (basic, extended) = (fit(TermSet::Basic), fit(TermSet::Extended));
        let find = |s: &PmfSet, name: &str| s.report.iter().find(|f| f.name == name).cloned();
        let (b, e) = (
            find(&basic, "left→right y").unwrap(),
            find(&extended, "left→right y").unwrap(),
        );
        eprintln!(
            "left→right y: basic {:.2e} px, extended {:.2e} px with {:?}",
            b.cp_rmse, e.cp_rmse, e.extended
        );
        assert!(e.extended.iter().any(|t| t == "y^4"), "{e:?}");
        assert!(e.cp_rmse * 5.0 < b.cp_rmse, "{b:?} {e:?}");
        for (fb, fe) in basic.report.iter().zip(&extended.report) {
            assert!(fe.cp_rmse <= fb.cp_rmse * (1.0 + 1e-9), "{fb:?} {fe:?}");
            assert!(fb.extended.is_empty());
        }
    }
}
