//! Sub-plane refinement of a sweep's winner by least-squares matching (Gruen 1985) in the
//! plane sweep's own terms: the reference window l(u, v) = a + b·s(q(u, v)), s the search photo
//! resampled bilinearly, q(u, v) where reference point (c + u, r + v) lands on the plane
//! t + t_u·u + t_v·v — a plane tilted across the window, so that a slope (a height or a
//! disparity changing across the window) distorts the search window as it does on the ground.
//! The mapping is linearised at the window centre: q(u, v) = q₀ + J·(u, v) + ∂q/∂t·(t_u·u +
//! t_v·v). Unknowns t, t_u, t_v, a, b, iterated from the winning plane; σ_t = σ₀·√Q_tt from
//! the normal matrix.

use crate::image::ImageF32;
use nalgebra::{SMatrix, SVector};

type M5 = SMatrix<f64, 5, 5>;
type V5 = SVector<f64, 5>;

/// The highest correlation that means anything: 1 is noise-free only in theory (resampling
/// alone leaves ~10⁻³). It bounds the sweep's σ, least squares' σ0 and the smallest cost the
/// uniqueness test tells apart.
pub const RHO_MAX: f64 = 0.999;

/// The projects' default refinement: least squares.
pub fn default_subpixel() -> Subpixel {
    Subpixel::Lsm
}

/// How a sweep's winner is refined below the plane step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Subpixel {
    /// A parabola through the winner's and its neighbours' correlations (fast; biased
    /// towards the swept planes, and blind to slopes across the window).
    Parabola,
    /// Least-squares matching of the winning window on a tilted plane ([`refine`]).
    Lsm,
}

/// A refined plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Refined {
    /// The continuous plane at the window centre.
    pub t: f64,
    /// Its standard deviation, planes.
    pub sigma_t: f64,
    /// The plane's change per pixel across the window (columns, rows).
    pub tilt: [f64; 2],
    /// The grey-value residual's standard deviation (σ₀).
    pub sigma0: f64,
    /// n / n_eff: how many window pixels make one independent observation, from the
    /// residuals' correlation between neighbours along the rows (r_x) and the columns (r_y),
    /// n/n_eff = (1 + r_x)/(1 − r_x) · (1 + r_y)/(1 − r_y), at least 1 (the effective number of
    /// an autocorrelated series, Bayley & Hammersley 1946, J. R. Stat. Soc. Suppl. 8(2), for
    /// a first-order process in each direction). σ_t leaves it out; a caller whose residuals
    /// are correlated by blur and resampling scales σ_t² by it.
    pub dependence: f64,
    pub iterations: usize,
}

/// Why a refinement was refused (the pixel then keeps the parabola's value, or none).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum RefineFailure {
    #[error("the window left the search photo")]
    OutsideImage,
    #[error("the normal matrix is singular (no gradient along the search line)")]
    Singular,
    #[error("no convergence within the iterations allowed")]
    NoConvergence,
    #[error(
        "the solution moved more than its reach from the winner, or tilted until the window folds"
    )]
    Wandered,
    #[error("the radiometric gain turned negative or vanished")]
    Inverted,
    #[error("converged, but with a σ above a plane: the window does not fix the plane")]
    Imprecise,
}

const MAX_ITERATIONS: usize = 15;

/// Sums over a window row (then over the window) of the products of the derivative b·g
/// (g the search window's slope along the line), the resampled grey value s and the residual
/// e with the window offsets u (and v): named for their factors.
#[derive(Debug, Default, Clone, Copy)]
struct Sums {
    gg: f64,
    ggu: f64,
    gguu: f64,
    ggv: f64,
    gguv: f64,
    ggvv: f64,
    g: f64,
    gu: f64,
    gv: f64,
    gs: f64,
    gsu: f64,
    gsv: f64,
    ge: f64,
    geu: f64,
    gev: f64,
    s: f64,
    ss: f64,
    e: f64,
    se: f64,
    ee: f64,
}

impl Sums {
    /// Adds a row's sums (over u, at offset v) to the window's.
    #[inline(always)]
    fn add_row(&mut self, r: &Sums, v: f64) {
        self.gg += r.gg;
        self.ggu += r.ggu;
        self.gguu += r.gguu;
        self.ggv += r.gg * v;
        self.gguv += r.ggu * v;
        self.ggvv += r.gg * v * v;
        self.g += r.g;
        self.gu += r.gu;
        self.gv += r.g * v;
        self.gs += r.gs;
        self.gsu += r.gsu;
        self.gsv += r.gs * v;
        self.ge += r.ge;
        self.geu += r.geu;
        self.gev += r.ge * v;
        self.s += r.s;
        self.ss += r.ss;
        self.e += r.e;
        self.se += r.se;
        self.ee += r.ee;
    }
}

/// Converged when the plane changes by less than this.
const CONVERGED: f64 = 1e-3;

/// The reference window: half-size `k`, centred on pixel (c, r), wholly inside its photo.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    pub c: usize,
    pub r: usize,
    pub k: usize,
}

built_per_cpu! {
    /// Refines plane `t0` for reference window `win` of `left`. `locate(u, v, t)` is where
    /// reference point (c + u, r + v) lands in `right` on plane t; it is asked for the offsets
    /// (u, v) = (0, 0), (1, 0) and (0, 1) alone. The solution must stay within `reach` planes of
    /// `t0`. Built per CPU (see `simd`): the sweep refines every matched pixel.
    pub fn refine[L: Fn(f64, f64, f64) -> [f64; 2]](
        left: &ImageF32,
        win: Window,
        right: &ImageF32,
        locate: &L,
        t0: f64,
        reach: f64,
    ) -> Result<Refined, RefineFailure> = refine_body;
}

#[inline(always)]
fn refine_body<L: Fn(f64, f64, f64) -> [f64; 2]>(
    left: &ImageF32,
    win: Window,
    right: &ImageF32,
    locate: &L,
    t0: f64,
    reach: f64,
) -> Result<Refined, RefineFailure> {
    let Window { c, r, k } = win;
    let side = 2 * k + 1;
    let mut lw = Vec::with_capacity(side * side);
    for rr in r - k..=r + k {
        lw.extend(
            left.data[rr * left.width + c - k..][..side]
                .iter()
                .map(|&v| v as f64),
        );
    }
    let n = (side * side) as f64;
    // σ0 has floors, else a window that happens to fit exactly reports σ of 10⁻¹⁵ px:
    // - whole grey values (an 8- or 16-bit file) are known to their rounding at best, 1/√12
    //   in each window, the right's times the gain;
    // - a correlation of 1 is noise-free only in theory: the residual is at least that of
    //   ρ = RHO_MAX, √(1 − ρ²)·σ_l (as the sweep's σ takes it).
    let quantised = lw.iter().all(|v| v.fract() == 0.0);
    let mean_l = lw.iter().sum::<f64>() / n;
    // Σ(l − l̄)², for the floor and for the first a and b.
    let ss_l = lw.iter().map(|v| (v - mean_l).powi(2)).sum::<f64>();
    let resampling = ((1.0 - RHO_MAX * RHO_MAX) * (ss_l / n)).sqrt();
    let mut sw = vec![0.0f64; side * side];
    let mut gw = vec![0.0f64; side * side];
    let mut res = vec![0.0f64; side * side];
    let (mut t, mut tu, mut tv) = (t0, 0.0f64, 0.0f64);
    let mut a = 0.0f64;
    let mut b = 1.0f64;
    for it in 0..=MAX_ITERATIONS {
        let q0 = locate(0.0, 0.0, t);
        let qu = locate(1.0, 0.0, t);
        let qv = locate(0.0, 1.0, t);
        let (qa, qb) = (locate(0.0, 0.0, t - 0.5), locate(0.0, 0.0, t + 0.5));
        let dir = [qb[0] - qa[0], qb[1] - qa[1]];
        // Where sample (u, v) lands: q₀ + (J + dir·tiltᵀ)·(u, v).
        let ju = [qu[0] - q0[0] + dir[0] * tu, qu[1] - q0[1] + dir[1] * tu];
        let jv = [qv[0] - q0[0] + dir[0] * tv, qv[1] - q0[1] + dir[1] * tv];
        sample(right, q0, [ju, jv], k, dir, &mut sw, &mut gw)?;
        if it == 0 {
            // a and b from the windows' means and deviations, so that the first step is small.
            let ms = sw.iter().sum::<f64>() / n;
            let ss_s = sw.iter().map(|v| (v - ms).powi(2)).sum::<f64>();
            if ss_s > 0.0 && ss_l > 0.0 {
                b = (ss_l / ss_s).sqrt();
                a = mean_l - b * ms;
            }
        }
        // The normals and the right-hand side from sums over the window: within a row v is
        // fixed, so each row sums the products of (b·g, s, e) with 1, u and u² once, and the
        // row's sums enter with 1, v and v² (14 sums a sample instead of the 21 products of
        // the derivatives (∂/∂t, ∂/∂t_u, ∂/∂t_v, ∂/∂a, ∂/∂b) = (b·g, b·g·u, b·g·v, 1, s)).
        let mut tot = Sums::default();
        for jj in 0..side {
            let v = jj as f64 - k as f64;
            let mut row = Sums::default();
            let o = jj * side;
            for ii in 0..side {
                let u = ii as f64 - k as f64;
                let (l, s, g) = (lw[o + ii], sw[o + ii], gw[o + ii]);
                let e = l - (a + b * s);
                res[o + ii] = e;
                let bg = b * g;
                let (gg, gu) = (bg * bg, bg * u);
                row.gg += gg;
                row.ggu += gg * u;
                row.gguu += gg * u * u;
                row.g += bg;
                row.gu += gu;
                row.gs += bg * s;
                row.gsu += gu * s;
                row.ge += bg * e;
                row.geu += gu * e;
                row.s += s;
                row.ss += s * s;
                row.e += e;
                row.se += s * e;
                row.ee += e * e;
            }
            tot.add_row(&row, v);
        }
        let nm = M5::new(
            tot.gg, tot.ggu, tot.ggv, tot.g, tot.gs, //
            tot.ggu, tot.gguu, tot.gguv, tot.gu, tot.gsu, //
            tot.ggv, tot.gguv, tot.ggvv, tot.gv, tot.gsv, //
            tot.g, tot.gu, tot.gv, n, tot.s, //
            tot.gs, tot.gsu, tot.gsv, tot.s, tot.ss,
        );
        let rhs = V5::new(tot.ge, tot.geu, tot.gev, tot.e, tot.se);
        let vv = tot.ee;
        let chol = nm.cholesky().ok_or(RefineFailure::Singular)?;
        let dx = chol.solve(&rhs);
        if !dx.iter().all(|v| v.is_finite()) {
            return Err(RefineFailure::Singular);
        }
        // Q_tt = (N⁻¹)₀₀ = ‖L⁻¹·e₀‖².
        let q_tt = {
            let l = chol.l_dirty();
            let mut z = [0.0f64; 5];
            z[0] = 1.0 / l[(0, 0)];
            for i in 1..5 {
                let s: f64 = (0..i).map(|j| l[(i, j)] * z[j]).sum();
                z[i] = -s / l[(i, i)];
            }
            z.iter().map(|v| v * v).sum::<f64>()
        };
        t += dx[0];
        tu += dx[1];
        tv += dx[2];
        a += dx[3];
        b += dx[4];
        // A tilt whose parallax changes by a pixel per pixel folds the window over itself.
        let fold = dir[0].hypot(dir[1]) * tu.abs().max(tv.abs());
        if (t - t0).abs() > reach || fold.is_nan() || fold >= 0.9 {
            return Err(RefineFailure::Wandered);
        }
        if b <= 1e-6 {
            return Err(RefineFailure::Inverted);
        }
        let mut sigma0 = (vv / (n - 5.0)).sqrt().max(resampling);
        if quantised {
            sigma0 = sigma0.max(((1.0 + b * b) / 12.0).sqrt());
        }
        // Converged: a step below a thousandth of a plane, or below a fifth of the plane's own
        // σ (the bilinear surface's gradient jumps at pixel borders, so the last steps jitter
        // at the level of the noise rather than shrink).
        let sigma_t = sigma0 * q_tt.sqrt();
        if it > 0 && (dx[0].abs() < CONVERGED || dx[0].abs() < 0.2 * sigma_t) {
            if sigma_t.is_nan() || sigma_t > 1.0 {
                return Err(RefineFailure::Imprecise);
            }
            return Ok(Refined {
                t,
                sigma_t,
                tilt: [tu, tv],
                sigma0,
                dependence: dependence(&res, side, vv),
                iterations: it,
            });
        }
    }
    Err(RefineFailure::NoConvergence)
}

/// n / n_eff of a window's residuals `e` (side × side, Σe² = `vv`): see
/// [`Refined::dependence`]. Each lag-1 correlation is taken in [0, 0.9] (a negative one, as
/// often from 25 residuals by chance, is no gain).
fn dependence(e: &[f64], side: usize, vv: f64) -> f64 {
    if vv <= 0.0 || side < 2 {
        return 1.0;
    }
    let (mut cx, mut cy) = (0.0, 0.0);
    for j in 0..side {
        for i in 0..side {
            let v = e[j * side + i];
            if i + 1 < side {
                cx += v * e[j * side + i + 1];
            }
            if j + 1 < side {
                cy += v * e[(j + 1) * side + i];
            }
        }
    }
    let f = |c: f64| {
        let r = (c / vv).clamp(0.0, 0.9);
        (1.0 + r) / (1.0 - r)
    };
    f(cx) * f(cy)
}

/// The search photo's window of half-size `k` at `q0 + j[0]·u + j[1]·v` (bilinear) into `s`,
/// and each sample's derivative along `dir` (the bilinear surface's own gradient) into `g`.
#[inline(always)]
fn sample(
    img: &ImageF32,
    q0: [f64; 2],
    j: [[f64; 2]; 2],
    k: usize,
    dir: [f64; 2],
    s: &mut [f64],
    g: &mut [f64],
) -> Result<(), RefineFailure> {
    let side = 2 * k + 1;
    let (w, h) = (img.width, img.height);
    if w < 2 || h < 2 {
        return Err(RefineFailure::OutsideImage);
    }
    let kf = k as f64;
    // The window lands on a parallelogram: inside the photo when its corners are.
    let at = |u: f64, v: f64| {
        [
            q0[0] + j[0][0] * u + j[1][0] * v - 0.5,
            q0[1] + j[0][1] * u + j[1][1] * v - 0.5,
        ]
    };
    for (u, v) in [(-kf, -kf), (kf, -kf), (-kf, kf), (kf, kf)] {
        let [x, y] = at(u, v);
        // Pixel centres at +0.5; the four neighbours must exist.
        if !(x >= 0.0 && y >= 0.0 && x < (w - 1) as f64 && y < (h - 1) as f64) {
            return Err(RefineFailure::OutsideImage);
        }
    }
    let wd = img.width;
    for jj in 0..side {
        let v = jj as f64 - kf;
        let row = &mut s[jj * side..(jj + 1) * side];
        let grow = &mut g[jj * side..(jj + 1) * side];
        for (ii, (sv, gv)) in row.iter_mut().zip(grow.iter_mut()).enumerate() {
            let [x, y] = at(ii as f64 - kf, v);
            // Inside by the corners (the minimum keeps a rounding at the border in).
            let (i0, j0) = ((x as usize).min(w - 2), (y as usize).min(h - 2));
            let (fx, fy) = (x - i0 as f64, y - j0 as f64);
            let o = j0 * wd + i0;
            let (p00, p01) = (img.data[o] as f64, img.data[o + 1] as f64);
            let (p10, p11) = (img.data[o + wd] as f64, img.data[o + wd + 1] as f64);
            let top = p00 + fx * (p01 - p00);
            let bottom = p10 + fx * (p11 - p10);
            let gx = (1.0 - fy) * (p01 - p00) + fy * (p11 - p10);
            let gy = bottom - top;
            *sv = top + fy * (bottom - top);
            *gv = gx * dir[0] + gy * dir[1];
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A band-limited texture, sampled at pixel centres (pixel c over [c, c + 1)).
    fn tex(x: f64, y: f64) -> f64 {
        (x * 0.61).sin() * (y * 0.47).cos()
            + (x * 0.29 + y * 0.33).sin()
            + 0.4 * (x * 1.1 - y * 0.8).sin()
    }

    /// A right photo shifted by a known fraction with a gain and offset: the refinement finds
    /// the shift within 0.02 px from a start half a pixel off, and σ_t grows with the noise.
    #[test]
    fn finds_a_known_sub_pixel_shift() {
        let (w, h) = (40usize, 30usize);
        let mut left = ImageF32::new(w, h);
        let mut right = ImageF32::new(w, h);
        let shift = 3.37;
        for r in 0..h {
            for c in 0..w {
                let (x, y) = (c as f64 + 0.5, r as f64 + 0.5);
                left.data[r * w + c] = (100.0 + 40.0 * tex(x, y)) as f32;
                right.data[r * w + c] = (20.0 + 0.8 * (100.0 + 40.0 * tex(x + shift, y))) as f32;
            }
        }
        // Right x = left x − t (disparity t).
        let locate = |u: f64, v: f64, t: f64| [20.5 + u - t, 15.5 + v];
        let at =
            |img: &ImageF32| refine(&left, Window { c: 20, r: 15, k: 4 }, img, &locate, 3.0, 1.0);
        let got = at(&right).unwrap();
        assert!((got.t - shift).abs() < 0.02, "{got:?}");
        assert!(got.sigma_t < 0.01, "{got:?}");
        // Noise: σ grows, and the shift is still found within 3σ + the resampling's share.
        let mut noisy = right.clone();
        let mut s = 1u64;
        for v in noisy.data.iter_mut() {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            *v += ((s >> 33) as f64 / (1u64 << 31) as f64 - 0.5) as f32 * 8.0;
        }
        let g2 = at(&noisy).unwrap();
        assert!(g2.sigma_t > 2.0 * got.sigma_t, "{g2:?} vs {got:?}");
        assert!((g2.t - shift).abs() < 3.0 * g2.sigma_t + 0.02, "{g2:?}");
    }

    /// Grey values shifted by exactly three pixels fit without residual; σ is then that of
    /// the floors, not zero: whole grey values keep their rounding, √((1 + b²)/12) with b = 1,
    /// and any keep the residual of a correlation of 0.999, √(1 − 0.999²)·σ_l (grey values
    /// made from colour are not whole); σ_t = σ0·√Q_tt.
    #[test]
    fn an_exact_fit_keeps_the_floors() {
        let (w, h) = (40usize, 30usize);
        let mut left = ImageF32::new(w, h);
        let mut right = ImageF32::new(w, h);
        for r in 0..h {
            for c in 0..w {
                let (x, y) = (c as f64 + 0.5, r as f64 + 0.5);
                left.data[r * w + c] = (100.0 + 40.0 * tex(x, y)).round() as f32;
                right.data[r * w + c] = (100.0 + 40.0 * tex(x + 3.0, y)).round() as f32;
            }
        }
        let win = Window { c: 20, r: 15, k: 4 };
        let sd = |img: &ImageF32| {
            let v: Vec<f64> = (11..=19)
                .flat_map(|rr| (16..=24).map(move |cc| (rr, cc)))
                .map(|(rr, cc)| img.data[rr * w + cc] as f64)
                .collect();
            let m = v.iter().sum::<f64>() / v.len() as f64;
            (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
        };
        let locate = |u: f64, v: f64, t: f64| [20.5 + u - t, 15.5 + v];
        let got = refine(&left, win, &right, &locate, 3.2, 1.0).unwrap();
        assert!((got.t - 3.0).abs() < 1e-3, "{got:?}");
        let want = (2.0f64 / 12.0)
            .sqrt()
            .max((1.0 - 0.999f64.powi(2)).sqrt() * sd(&left));
        assert!((got.sigma0 - want).abs() < 0.02 * want, "{got:?} vs {want}");
        assert!(got.sigma_t > 1e-3 && got.sigma_t < 0.05, "{got:?}");
        // Not whole (as from colour): the rounding floor goes, the correlation's stays.
        let scale = |img: &ImageF32| {
            let mut o = img.clone();
            o.data.iter_mut().for_each(|v| *v *= 0.299);
            o
        };
        let (l2, r2) = (scale(&left), scale(&right));
        let g2 = refine(&l2, win, &r2, &locate, 3.2, 1.0).unwrap();
        let want2 = (1.0 - 0.999f64.powi(2)).sqrt() * sd(&l2);
        assert!(
            (g2.sigma0 - want2).abs() < 0.02 * want2,
            "{g2:?} vs {want2}"
        );
        assert!(g2.sigma_t > 1e-3, "{g2:?}");
    }

    /// A window whose search line runs along the texture's stripes has no gradient there.
    #[test]
    fn no_gradient_along_the_line_is_refused() {
        let (w, h) = (30usize, 30usize);
        let mut img = ImageF32::new(w, h);
        for r in 0..h {
            for c in 0..w {
                img.data[r * w + c] = (r as f32 * 0.7).sin() * 50.0;
            }
        }
        let locate = |u: f64, v: f64, t: f64| [15.5 + u - t, 15.5 + v];
        let got = refine(&img, Window { c: 15, r: 15, k: 4 }, &img, &locate, 0.3, 1.0);
        assert!(
            matches!(
                got,
                Err(RefineFailure::Singular
                    | RefineFailure::Wandered
                    | RefineFailure::NoConvergence)
            ),
            "{got:?}"
        );
    }
}
