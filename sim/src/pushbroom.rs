//! Pushbroom (SPOT-like) views of the simulated terrain: a satellite's linear array sweeping
//! the ground line by line, rendered by following every detector's ray to the terrain.
//!
//! The model, as the host documents its own (written here again so the simulator shares no
//! geometry with the host): line r is taken at t = (r − lines/2)·period; the position and the
//! roll, pitch, yaw are quadratic polynomials of t; the orbital frame has e₁ along the
//! horizontal velocity, e₃ up, e₂ = e₃ × e₁; body = orbital·Rx(roll)·Ry(pitch)·Rz(yaw);
//! sensor = body·Ry(−along)·Rx(−across); detector u = (col − c₀)/f looks along (0, u, −1) in
//! the sensor frame (columns to the left of the flight, so a southbound pass is north up,
//! east right). Ground in the simulator's local metres (x east, y north, z up).

use crate::rng::Rng;
use crate::scene::{first_hit, Dem, Texture};
use serde::Serialize;
use std::sync::Arc;

/// Height of the orbit above the terrain's mean, m (SPOT: 832 km).
pub const ORBIT_M: f64 = 830_000.0;
/// Ground speed of the nadir point, m/s.
pub const GROUND_SPEED: f64 = 6_600.0;

/// How the views of a stereo set differ.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Stereo {
    /// From different passes, the mirror tilted across the track (SPOT 1-4): the base, and
    /// the parallax, along the image's columns.
    Across,
    /// One pass looking backward, down and forward (SPOT 5 HRS, ALOS PRISM): the parallax
    /// along the rows.
    Along,
}

#[derive(Debug, Clone, Serialize)]
pub struct PushbroomView {
    /// 1, 2, 3 in the set.
    pub number: u32,
    pub columns: usize,
    pub lines: usize,
    pub line_period_s: f64,
    pub focal_px: f64,
    pub principal_col: f64,
    pub tilt_across_deg: f64,
    pub tilt_along_deg: f64,
    /// Position x, y, z (local m) as polynomials of t: `[axis][power]`.
    pub position: [[f64; 3]; 3],
    /// Roll, pitch, yaw (rad) as polynomials of t.
    pub attitude: [[f64; 3]; 3],
    pub texture_seed: u64,
    pub texture: Texture,
    /// Reflectance → signal: the sensor's darkest and brightest response (as a photo's
    /// transmittance range).
    pub t_min: f64,
    pub t_max: f64,
    #[serde(skip)]
    pub dem: Arc<Dem>,
}

type M3 = [[f64; 3]; 3];

fn mul(a: &M3, b: &M3) -> M3 {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

fn apply(a: &M3, v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| a[i][0] * v[0] + a[i][1] * v[1] + a[i][2] * v[2])
}

fn rx(a: f64) -> M3 {
    let (s, c) = a.sin_cos();
    [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]
}

fn ry(a: f64) -> M3 {
    let (s, c) = a.sin_cos();
    [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
}

fn rz(a: f64) -> M3 {
    let (s, c) = a.sin_cos();
    [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
}

fn quad(c: [f64; 3], t: f64) -> f64 {
    c[0] + c[1] * t + c[2] * t * t
}

impl PushbroomView {
    /// View `number` of a set of `views` (2 or 3) over the middle of `dem`, drawn from `seed`:
    /// `side` × `side` pixels of `gsd_m` at nadir. Across: tilts −20°, +20° (and 0° between
    /// them for a third view), each from its own pass with its own heading and drift; along:
    /// one southbound pass looking 20° back, down and 20° forward. Each view's middle pixel
    /// sees the DEM's middle at its mean height.
    pub fn new(
        dem: Arc<Dem>,
        seed: u64,
        stereo: Stereo,
        views: u32,
        number: u32,
        side: usize,
        gsd_m: f64,
    ) -> PushbroomView {
        let mut rng = Rng::new(seed ^ 0x5907 ^ (number as u64).wrapping_mul(0x9E37_79B9));
        let mut u = || 2.0 * rng.uniform() - 1.0;
        let k = number.clamp(1, views.clamp(2, 3)) as f64;
        let tilt = |k: f64| match views {
            2 => -20.0 + 40.0 * (k - 1.0),
            _ => -20.0 + 20.0 * (k - 1.0),
        };
        // Views 1, 2, 3 of a triplet: −20°, 0°, +20°; of a pair: −20°, +20°.
        let t = tilt(k);
        let (tilt_across_deg, tilt_along_deg, heading_deg) = match stereo {
            Stereo::Across => (t, 0.0, 190.0 + 2.0 * u()),
            Stereo::Along => (0.0, t, 190.0),
        };
        let attitude = match stereo {
            // Each pass has its own pointing errors and drifts.
            Stereo::Across => [
                [2e-4 * u(), 2e-6 * u(), 1e-8 * u()],
                [2e-4 * u(), 2e-6 * u(), 0.0],
                [5e-4 * u(), 1e-6 * u(), 0.0],
            ],
            // One pass: one drift, seen at different times.
            Stereo::Along => [[1e-4, 1e-6, 0.0], [-1e-4, 2e-6, 0.0], [3e-4, 0.0, 0.0]],
        };
        let h = dem.mean_m() + ORBIT_M;
        let speed = match stereo {
            Stereo::Across => GROUND_SPEED * (1.0 + 0.002 * u()),
            Stereo::Along => GROUND_SPEED,
        };
        let (sh, ch) = heading_deg.to_radians().sin_cos();
        let velocity = [speed * sh, speed * ch, 0.0];
        let mut v = PushbroomView {
            number,
            columns: side,
            lines: side,
            line_period_s: gsd_m / GROUND_SPEED,
            focal_px: ORBIT_M / gsd_m,
            principal_col: side as f64 / 2.0 + 3.0 * u(),
            tilt_across_deg,
            tilt_along_deg,
            position: [
                [0.0, velocity[0], 0.0],
                [0.0, velocity[1], 0.0],
                [h, -2.0 * u(), 0.0],
            ],
            attitude,
            texture_seed: seed ^ 0x7E47_u64,
            texture: Texture::Natural,
            t_min: 0.05,
            t_max: 0.88,
            dem,
        };
        // The along-track views of one pass see the middle at different times: t = 0 at
        // each view's own middle line, so the pass's position is shifted instead.
        let [ex, ey] = v.dem.extent_m();
        let centre = [0.5 * ex, 0.5 * ey, v.dem.mean_m()];
        let d = v.direction(v.principal_col, v.lines as f64 / 2.0);
        let l = (centre[2] - h) / d[2];
        v.position[0][0] = centre[0] - l * d[0];
        v.position[1][0] = centre[1] - l * d[1];
        v
    }

    pub fn time(&self, row: f64) -> f64 {
        (row - self.lines as f64 / 2.0) * self.line_period_s
    }

    fn at(&self, t: f64) -> [f64; 3] {
        std::array::from_fn(|k| quad(self.position[k], t))
    }

    /// Ground ← sensor rotation at time t.
    fn rotation(&self, t: f64) -> M3 {
        let p = &self.position;
        let (vx, vy) = (p[0][1] + 2.0 * p[0][2] * t, p[1][1] + 2.0 * p[1][2] * t);
        let n = vx.hypot(vy);
        let e1 = [vx / n, vy / n, 0.0];
        let e2 = [-e1[1], e1[0], 0.0];
        let orbital = [[e1[0], e2[0], 0.0], [e1[1], e2[1], 0.0], [0.0, 0.0, 1.0]];
        let a = &self.attitude;
        let body = mul(
            &orbital,
            &mul(
                &rx(quad(a[0], t)),
                &mul(&ry(quad(a[1], t)), &rz(quad(a[2], t))),
            ),
        );
        mul(
            &body,
            &mul(
                &ry(-self.tilt_along_deg.to_radians()),
                &rx(-self.tilt_across_deg.to_radians()),
            ),
        )
    }

    /// The unit direction of the ray of pixel (col, row), corner origin.
    pub fn direction(&self, col: f64, row: f64) -> [f64; 3] {
        let u = (col - self.principal_col) / self.focal_px;
        let d = apply(&self.rotation(self.time(row)), [0.0, u, -1.0]);
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        [d[0] / n, d[1] / n, d[2] / n]
    }

    /// Where the ray of pixel (col, row) first meets the terrain ([`first_hit`]).
    pub fn ground_point(&self, col: f64, row: f64) -> [f64; 3] {
        let o = self.at(self.time(row));
        let d = self.direction(col, row);
        first_hit(&self.dem, d, |z| {
            let l = (z - o[2]) / d[2];
            [o[0] + l * d[0], o[1] + l * d[1]]
        })
    }

    /// Where ground point g appears: (col, row), corner origin. The row by bisection on the
    /// scan plane's side of g over the image's time span and a margin (not Newton, as the
    /// host does), the column from the ray's angle in the plane.
    pub fn project(&self, g: [f64; 3]) -> Option<[f64; 2]> {
        let side = |t: f64| {
            let r = self.rotation(t);
            let o = self.at(t);
            let v = [g[0] - o[0], g[1] - o[1], g[2] - o[2]];
            // The sensor's x axis is the rotation's first column.
            r[0][0] * v[0] + r[1][0] * v[1] + r[2][0] * v[2]
        };
        let span = self.lines as f64 * self.line_period_s;
        let (mut lo, mut hi) = (-1.5 * span, 1.5 * span);
        let (flo, fhi) = (side(lo), side(hi));
        if !(flo > 0.0 && fhi < 0.0) {
            return None;
        }
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if side(mid) > 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
            if hi - lo < 1e-12 * span {
                break;
            }
        }
        let t = 0.5 * (lo + hi);
        let r = self.rotation(t);
        let o = self.at(t);
        let v = [g[0] - o[0], g[1] - o[1], g[2] - o[2]];
        let s = |k: usize| r[0][k] * v[0] + r[1][k] * v[1] + r[2][k] * v[2];
        let (sy, sz) = (s(1), s(2));
        if sz >= 0.0 {
            return None;
        }
        Some([
            self.principal_col - self.focal_px * sy / sz,
            t / self.line_period_s + self.lines as f64 / 2.0,
        ])
    }

    /// The ground's reflectance at (x, y) in this view's texture.
    pub fn reflectance_at(&self, x: f64, y: f64) -> f64 {
        self.texture.at(self.texture_seed, &self.dem, x, y)
    }

    /// The view as an image, `columns × lines`, each pixel the mean signal of `k × k` rays
    /// across it (t_min + (t_max − t_min)·reflectance).
    pub fn render(&self, k: usize) -> Vec<f32> {
        use rayon::prelude::*;
        let k = k.max(1);
        let mut img = vec![0f32; self.columns * self.lines];
        img.par_chunks_mut(self.columns)
            .enumerate()
            .for_each(|(r, row)| {
                for (c, v) in row.iter_mut().enumerate() {
                    let mut s = 0.0;
                    for j in 0..k {
                        for i in 0..k {
                            let col = c as f64 + (i as f64 + 0.5) / k as f64;
                            let line = r as f64 + (j as f64 + 0.5) / k as f64;
                            let [x, y, _] = self.ground_point(col, line);
                            s += self.t_min + (self.t_max - self.t_min) * self.reflectance_at(x, y);
                        }
                    }
                    *v = (s / (k * k) as f64) as f32;
                }
            });
        img
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::jacksboro;

    #[test]
    fn rays_meet_the_terrain_where_they_project_back() {
        for stereo in [Stereo::Across, Stereo::Along] {
            for n in 1..=3 {
                let v = PushbroomView::new(jacksboro(), 5, stereo, 3, n, 1200, 5.0);
                for (c, r) in [(0.5, 0.5), (600.0, 600.0), (1199.5, 37.25), (17.0, 1100.0)] {
                    let g = v.ground_point(c, r);
                    assert!((g[2] - v.dem.height(g[0], g[1])).abs() < 0.01);
                    let q = v.project(g).unwrap();
                    assert!(
                        (q[0] - c).abs() < 1e-6 && (q[1] - r).abs() < 1e-6,
                        "{stereo:?} view {n}: ({c}, {r}) → {g:?} → {q:?}"
                    );
                }
            }
        }
    }

    /// The views of a set see the DEM's middle near their own middle, about 5 m a pixel at
    /// nadir, and the across-track pair sees a hill shifted along the columns, the
    /// along-track pair along the rows.
    #[test]
    fn the_views_overlap_and_their_parallax_lies_along_the_base() {
        let dem = jacksboro();
        let [ex, ey] = dem.extent_m();
        for (stereo, axis) in [(Stereo::Across, 0), (Stereo::Along, 1)] {
            let v: Vec<PushbroomView> = (1..=3)
                .map(|n| PushbroomView::new(dem.clone(), 2, stereo, 3, n, 1000, 5.0))
                .collect();
            let g = [0.5 * ex, 0.5 * ey, dem.mean_m()];
            let up = [g[0], g[1], g[2] + 100.0];
            let mut shifts = Vec::new();
            for view in &v {
                let q = view.project(g).unwrap();
                assert!(
                    (q[0] - 500.0).abs() < 10.0 && (q[1] - 500.0).abs() < 10.0,
                    "{q:?}"
                );
                let e = view.project([g[0] + 50.0, g[1], g[2]]).unwrap();
                assert!(
                    ((e[0] - q[0]) - 10.0).abs() < 1.5,
                    "{stereo:?}: {q:?} {e:?}"
                );
                let h = view.project(up).unwrap();
                shifts.push([h[0] - q[0], h[1] - q[1]]);
            }
            // 100 m of height seen ±20° apart: along the track the ground moves 100·tan 20° in
            // 5 m lines; across it the tilted view's pixels are 5/cos² 20° m wide.
            let b = 20f64.to_radians();
            let want = match stereo {
                Stereo::Along => 2.0 * 100.0 * b.tan() / 5.0,
                Stereo::Across => 2.0 * 100.0 * b.sin() * b.cos() / 5.0,
            };
            let p = shifts[2][axis] - shifts[0][axis];
            let other = shifts[2][1 - axis] - shifts[0][1 - axis];
            assert!(
                (p.abs() - want).abs() < 0.5 && other.abs() < 1.0,
                "{stereo:?}: {shifts:?}, want {want:.2}"
            );
        }
    }
}
