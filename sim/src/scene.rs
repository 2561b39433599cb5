//! The terrain under the aerial photos and the photos themselves: a real elevation model (the
//! Jacksboro fault DEM, Tennessee; see tests/data/README.md for its source and licence), a
//! procedural ground texture shaded by the terrain, and frame cameras with known interior and
//! exterior orientation over it in seed 002's configuration (RC10, f = 153 mm, photo scale
//! about 1:42 500, 6 500 m above the terrain, a 2×2 block with 60 % forward overlap).
//!
//! The simulator's own collinearity and ray–terrain intersection: it shares no geometry code
//! with the host, whose photogrammetry it is the truth for.

use crate::rng::Rng;
use serde::Serialize;
use std::sync::{Arc, OnceLock};

/// A regular grid of heights. Ground coordinates in metres: X east, Y north, origin at the
/// grid's south-west corner; node (i, j) (column i, row j from the north) lies at the centre
/// of its cell, ((i + ½)·dx, (rows − j − ½)·dy).
#[derive(Debug, Clone)]
pub struct Dem {
    pub cols: usize,
    pub rows: usize,
    /// Cell size, m (x, y).
    pub cell_m: [f64; 2],
    /// Row-major from the north-west node.
    pub heights: Vec<f32>,
    pub min_m: f64,
    pub max_m: f64,
}

/// The DEM the simulator's photos are rendered from, parsed once.
pub fn jacksboro() -> Arc<Dem> {
    static DEM: OnceLock<Arc<Dem>> = OnceLock::new();
    DEM.get_or_init(|| {
        let text = include_str!("../../tests/data/jacksboro_fault_dem.asc");
        Arc::new(Dem::parse_esri_ascii(text).expect("the bundled DEM parses"))
    })
    .clone()
}

impl Dem {
    /// An ESRI ASCII grid. Geographic cells (a cell size below 0.1, in degrees) are turned
    /// into metres at the grid's mid-latitude (1° of latitude 110 574 m, of longitude
    /// 111 320 m·cos φ) — a local flat-earth approximation, ample for a test scene.
    pub fn parse_esri_ascii(text: &str) -> Result<Dem, String> {
        let mut header = std::collections::HashMap::new();
        let mut lines = text.lines().enumerate().peekable();
        while let Some((_, l)) = lines.peek() {
            let mut it = l.split_whitespace();
            match (it.next(), it.next()) {
                (Some(k), Some(v)) if k.chars().next().is_some_and(|c| c.is_alphabetic()) => {
                    let v: f64 = v
                        .parse()
                        .map_err(|_| format!("header `{k}`: `{v}` is not a number"))?;
                    header.insert(k.to_ascii_lowercase(), v);
                    lines.next();
                }
                _ => break,
            }
        }
        let get = |k: &str| header.get(k).copied().ok_or(format!("header lacks `{k}`"));
        let (cols, rows) = (get("ncols")? as usize, get("nrows")? as usize);
        let cell = get("cellsize")?;
        let nodata = header.get("nodata_value").copied();
        let mut heights = Vec::with_capacity(cols * rows);
        for (n, l) in lines {
            for t in l.split_whitespace() {
                let v: f64 = t
                    .parse()
                    .map_err(|_| format!("line {}: `{t}` is not a number", n + 1))?;
                if Some(v) == nodata {
                    return Err(format!("line {}: nodata cells are not supported", n + 1));
                }
                heights.push(v as f32);
            }
        }
        if heights.len() != cols * rows {
            return Err(format!(
                "{} heights for a {cols}×{rows} grid",
                heights.len()
            ));
        }
        let cell_m = if cell < 0.1 {
            let lat = get("yllcorner")? + 0.5 * rows as f64 * cell;
            [cell * 111_320.0 * lat.to_radians().cos(), cell * 110_574.0]
        } else {
            [cell, cell]
        };
        let min_m = heights.iter().fold(f64::MAX, |m, &h| m.min(h as f64));
        let max_m = heights.iter().fold(f64::MIN, |m, &h| m.max(h as f64));
        Ok(Dem {
            cols,
            rows,
            cell_m,
            heights,
            min_m,
            max_m,
        })
    }

    /// Width and height of the area the nodes span, m.
    pub fn extent_m(&self) -> [f64; 2] {
        [
            self.cols as f64 * self.cell_m[0],
            self.rows as f64 * self.cell_m[1],
        ]
    }

    pub fn mean_m(&self) -> f64 {
        self.heights.iter().map(|&h| h as f64).sum::<f64>() / self.heights.len() as f64
    }

    fn node(&self, i: i64, j: i64) -> f64 {
        let i = i.clamp(0, self.cols as i64 - 1) as usize;
        let j = j.clamp(0, self.rows as i64 - 1) as usize;
        self.heights[j * self.cols + i] as f64
    }

    /// Bilinear height at ground (x, y), held constant beyond the outer nodes.
    pub fn height(&self, x: f64, y: f64) -> f64 {
        let fx = x / self.cell_m[0] - 0.5;
        let fy = self.rows as f64 - y / self.cell_m[1] - 0.5;
        let (i, j) = (fx.floor(), fy.floor());
        let (tx, ty) = (fx - i, fy - j);
        let (i, j) = (i as i64, j as i64);
        let top = self.node(i, j) + tx * (self.node(i + 1, j) - self.node(i, j));
        let bot = self.node(i, j + 1) + tx * (self.node(i + 1, j + 1) - self.node(i, j + 1));
        top + ty * (bot - top)
    }

    /// ∂h/∂x, ∂h/∂y by central differences over one cell.
    pub fn gradient(&self, x: f64, y: f64) -> [f64; 2] {
        let [dx, dy] = self.cell_m;
        [
            (self.height(x + 0.5 * dx, y) - self.height(x - 0.5 * dx, y)) / dx,
            (self.height(x, y + 0.5 * dy) - self.height(x, y - 0.5 * dy)) / dy,
        ]
    }
}

/// Where a ray of direction `d` (pointing down), at ground `at(z)` when at height z, first
/// meets the terrain: marched down from above the highest point in steps of a fifth of a
/// cell's worth of the ray's slope, then bisected to a millimetre.
pub fn first_hit(dem: &Dem, d: [f64; 3], at: impl Fn(f64) -> [f64; 2]) -> [f64; 3] {
    // f(z) = z − h(ray at height z): positive above the terrain.
    let f = |z: f64| {
        let [x, y] = at(z);
        z - dem.height(x, y)
    };
    let horiz = (d[0] * d[0] + d[1] * d[1]).sqrt() / d[2].abs();
    let dz = (0.2 * dem.cell_m[0].min(dem.cell_m[1]) / horiz.max(1e-6)).clamp(0.5, 50.0);
    let (mut hi, mut lo) = (dem.max_m + 1.0, dem.max_m + 1.0);
    while lo > dem.min_m - 1.0 {
        lo = hi - dz;
        if f(lo) <= 0.0 {
            break;
        }
        hi = lo;
    }
    for _ in 0..60 {
        let mid = 0.5 * (hi + lo);
        if f(mid) > 0.0 {
            hi = mid;
        } else {
            lo = mid;
        }
        if hi - lo < 1e-3 {
            break;
        }
    }
    let z = 0.5 * (hi + lo);
    let [x, y] = at(z);
    [x, y, z]
}

/// Smooth value noise in [0, 1) on a unit lattice (C¹: smoothstep between lattice values).
pub fn value_noise(seed: u64, x: f64, y: f64) -> f64 {
    let h = |i: i64, j: i64| -> f64 {
        let mut z = seed
            ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    };
    let (i, j) = (x.floor() as i64, y.floor() as i64);
    let (fx, fy) = (x - x.floor(), y - y.floor());
    let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
    let a = h(i, j) + sx * (h(i + 1, j) - h(i, j));
    let b = h(i, j + 1) + sx * (h(i + 1, j + 1) - h(i, j + 1));
    a + sy * (b - a)
}

/// Ground reflectance in (0, 1): land-cover patches about a kilometre across with soft
/// borders, detail at 70, 14 and 4 m (4 m is about 0.1 mm on the photo), lit from the north-west
/// at 45° over the terrain's slopes.
pub fn reflectance(seed: u64, dem: &Dem, x: f64, y: f64) -> f64 {
    let cover = value_noise(seed, x / 900.0, y / 900.0) * 5.0;
    let (k, f) = (cover.floor(), cover - cover.floor());
    let t = ((f - 0.8) / 0.2).clamp(0.0, 1.0);
    let class = k + t * t * (3.0 - 2.0 * t);
    let r = 0.22
        + 0.09 * class
        + 0.14 * (value_noise(seed ^ 0x11, x / 70.0, y / 70.0) - 0.5)
        + 0.16 * (value_noise(seed ^ 0x22, x / 14.0, y / 14.0) - 0.5)
        + 0.12 * (value_noise(seed ^ 0x33, x / 4.0, y / 4.0) - 0.5);
    (r * shade(dem, x, y)).clamp(0.03, 0.97)
}

/// The terrain's shading at (x, y): Lambert, sun from azimuth 315°, elevation 45°, with a
/// tenth of ambient light.
fn shade(dem: &Dem, x: f64, y: f64) -> f64 {
    let [gx, gy] = dem.gradient(x, y);
    let n = [-gx, -gy, 1.0];
    let s = [-0.5, 0.5, std::f64::consts::FRAC_1_SQRT_2];
    let lambert = (n[0] * s[0] + n[1] * s[1] + n[2] * s[2]) / (gx * gx + gy * gy + 1.0).sqrt();
    0.1 + 1.1 * lambert
}

/// What the ground looks like.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Texture {
    /// Land cover with detail at 70, 14 and 4 m ([`reflectance`]).
    #[default]
    Natural,
    /// Fields with sharp borders and almost no texture inside ([`fields_reflectance`]): the
    /// weak texture where windows of grey values correlate little but noise.
    Fields,
}

impl Texture {
    /// The ground's reflectance at (x, y) in this texture.
    pub fn at(self, seed: u64, dem: &Dem, x: f64, y: f64) -> f64 {
        match self {
            Texture::Natural => reflectance(seed, dem, x, y),
            Texture::Fields => fields_reflectance(seed, dem, x, y),
        }
    }
}

/// Fields about 50-150 m across with sharp borders (smooth noise on a 150 m lattice cut into
/// 7 levels of reflectance 0.07 apart), a faint texture inside them (±0.005 at 4 m), shaded
/// as [`reflectance`].
pub fn fields_reflectance(seed: u64, dem: &Dem, x: f64, y: f64) -> f64 {
    let level = (value_noise(seed ^ 0x44, x / 150.0, y / 150.0) * 7.0).floor();
    let r = 0.2 + 0.07 * level + 0.01 * (value_noise(seed ^ 0x33, x / 4.0, y / 4.0) - 0.5);
    (r * shade(dem, x, y)).clamp(0.03, 0.97)
}

/// Exterior orientation: angles in degrees (R = Rω·Rφ·Rκ), projection centre in ground metres.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Exterior {
    pub omega_deg: f64,
    pub phi_deg: f64,
    pub kappa_deg: f64,
    pub x0_m: f64,
    pub y0_m: f64,
    pub z0_m: f64,
}

impl Exterior {
    /// The rotation from the image system to the ground system.
    pub fn rotation(&self) -> [[f64; 3]; 3] {
        let (so, co) = self.omega_deg.to_radians().sin_cos();
        let (sp, cp) = self.phi_deg.to_radians().sin_cos();
        let (sk, ck) = self.kappa_deg.to_radians().sin_cos();
        [
            [cp * ck, -cp * sk, sp],
            [co * sk + so * sp * ck, co * ck - so * sp * sk, -so * cp],
            [so * sk - co * sp * ck, so * ck + co * sp * sk, co * cp],
        ]
    }
}

/// One aerial photo: a frame camera (principal point at the fiducial centre, no distortion)
/// over the terrain. Photo coordinates in mm, x along the flight, y to its left.
#[derive(Debug, Clone, Serialize)]
pub struct AerialPhoto {
    /// Position in the block: 1, 2, 5 along the first strip, 3, 4, 6 along the second.
    pub number: u32,
    pub focal_mm: f64,
    pub exterior: Exterior,
    pub texture_seed: u64,
    pub texture: Texture,
    /// Transmittance of the darkest and clearest picture areas (a diapositive).
    pub t_min: f64,
    pub t_max: f64,
    #[serde(skip)]
    pub dem: Arc<Dem>,
    /// Ground (x, y) of the photo grid's nodes, for fast rendering (shared by clones).
    #[serde(skip)]
    grid: Arc<PhotoGrid>,
}

/// The rendering grid's nodes, ray-traced a block at a time when first read: a scan or a
/// calibration looks at a few per cent of the photo, and tracing all 850 000 nodes took most
/// of a simulated camera's start. Each node is the same function of its place, so the
/// rendering is the same, to the bit, whichever block is traced first.
#[derive(Debug, Default)]
struct PhotoGrid {
    step_mm: f64,
    half_mm: f64,
    /// Nodes along each side.
    n: usize,
    /// Blocks of BLOCK × BLOCK nodes, row-major, each (x, y) of its nodes row-major.
    blocks: Vec<OnceLock<Box<[[f32; 2]]>>>,
}

/// Nodes along a side of one of the grid's blocks.
const BLOCK: usize = 32;

impl PhotoGrid {
    fn blocks_across(&self) -> usize {
        self.n.div_ceil(BLOCK)
    }

    /// Photo point (mm) of node (i, j).
    fn node_mm(&self, i: usize, j: usize) -> [f64; 2] {
        [
            -self.half_mm + i as f64 * self.step_mm,
            -self.half_mm + j as f64 * self.step_mm,
        ]
    }

    /// Ground (x, y) of node (i, j) of `photo`'s grid.
    #[inline]
    fn node(&self, photo: &AerialPhoto, i: usize, j: usize) -> [f32; 2] {
        let across = self.blocks_across();
        let (bi, bj) = (i / BLOCK, j / BLOCK);
        let block = self.blocks[bj * across + bi].get_or_init(|| {
            // Traced on this thread (not in parallel: a rayon worker waiting here could be
            // handed a task that waits for this very block).
            let (i0, j0) = (bi * BLOCK, bj * BLOCK);
            let mut nodes = Vec::with_capacity(BLOCK * BLOCK);
            for j in j0..(j0 + BLOCK).min(self.n) {
                for i in i0..(i0 + BLOCK).min(self.n) {
                    let g = photo.ground_point(self.node_mm(i, j));
                    nodes.push([g[0] as f32, g[1] as f32]);
                }
            }
            nodes.into_boxed_slice()
        });
        let w = BLOCK.min(self.n - bi * BLOCK);
        block[(j % BLOCK) * w + i % BLOCK]
    }
}

/// The block's layout: base 40 % and strip spacing 70 % of the 230 mm format at the photo
/// scale.
pub const FORMAT_MM: f64 = 230.0;
pub const FOCAL_MM: f64 = 153.0;
pub const FLYING_HEIGHT_M: f64 = 6_500.0;

/// The exterior orientation of photo `number` (1–6) of the block over `dem`: the nominal
/// layout plus small random attitude and position errors drawn from `seed`.
pub fn block_exterior(dem: &Dem, seed: u64, number: u32) -> Exterior {
    let mut rng = Rng::new(seed ^ 0xB10C_u64 ^ (number as u64).wrapping_mul(0x9E37_79B9));
    let scale = FLYING_HEIGHT_M / (FOCAL_MM / 1000.0);
    let side = FORMAT_MM / 1000.0 * scale;
    let (base, spacing) = (0.4 * side, 0.7 * side);
    let [ex, ey] = dem.extent_m();
    // Strip 1: photos 1, 2, 5 along the flight; strip 2: 3, 4, 6 beside them.
    let (along, across) = match number.clamp(1, 6) {
        1 => (-0.5, 0.5),
        2 => (0.5, 0.5),
        3 => (-0.5, -0.5),
        4 => (0.5, -0.5),
        5 => (1.5, 0.5),
        _ => (1.5, -0.5),
    };
    let mut u = || 2.0 * rng.uniform() - 1.0;
    Exterior {
        omega_deg: 1.5 * u(),
        phi_deg: 1.5 * u(),
        kappa_deg: 2.0 * u(),
        x0_m: 0.5 * ex + along * base + 30.0 * u(),
        y0_m: 0.5 * ey + across * spacing + 30.0 * u(),
        z0_m: dem.mean_m() + FLYING_HEIGHT_M + 20.0 * u(),
    }
}

impl AerialPhoto {
    /// Photo `number` of the block drawn from `seed`, with the grid that renders it covering
    /// ±`half_mm`.
    pub fn new(dem: Arc<Dem>, seed: u64, number: u32, half_mm: f64) -> AerialPhoto {
        let exterior = block_exterior(&dem, seed, number);
        let mut p = AerialPhoto {
            number,
            focal_mm: FOCAL_MM,
            exterior,
            texture_seed: seed ^ 0x7E47_u64,
            texture: Texture::Natural,
            t_min: 0.05,
            t_max: 0.88,
            dem,
            grid: Arc::default(),
        };
        let step_mm = 0.25;
        let n = (2.0 * half_mm / step_mm).ceil() as usize + 3;
        let blocks = n.div_ceil(BLOCK);
        p.grid = Arc::new(PhotoGrid {
            step_mm,
            half_mm: half_mm + step_mm,
            n,
            blocks: (0..blocks * blocks).map(|_| OnceLock::new()).collect(),
        });
        p
    }

    /// Collinearity: ground point → photo (mm).
    pub fn project(&self, g: [f64; 3]) -> [f64; 2] {
        let r = self.exterior.rotation();
        let d = [
            g[0] - self.exterior.x0_m,
            g[1] - self.exterior.y0_m,
            g[2] - self.exterior.z0_m,
        ];
        let c = |k: usize| r[0][k] * d[0] + r[1][k] * d[1] + r[2][k] * d[2];
        let (kx, ky, kz) = (c(0), c(1), c(2));
        [-self.focal_mm * kx / kz, -self.focal_mm * ky / kz]
    }

    /// The ray through photo point `p` (mm): its direction in the ground system, and where it
    /// is at height z (ground x, y).
    fn ray(&self, p: [f64; 2]) -> ([f64; 3], impl Fn(f64) -> [f64; 2] + '_) {
        let r = self.exterior.rotation();
        let v = [p[0], p[1], -self.focal_mm];
        let d: [f64; 3] = std::array::from_fn(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2]);
        let e = &self.exterior;
        let at = move |z: f64| {
            let l = (z - e.z0_m) / d[2];
            [e.x0_m + l * d[0], e.y0_m + l * d[1]]
        };
        (d, at)
    }

    /// Where the ray through photo point `p` (mm) first meets the terrain: marched down from
    /// above the highest point in steps of a fifth of a cell, then bisected to a millimetre.
    pub fn ground_point(&self, p: [f64; 2]) -> [f64; 3] {
        let (d, at) = self.ray(p);
        first_hit(&self.dem, d, at)
    }

    /// Ground (x, y) under photo point `p` from the rendering grid (bilinear).
    fn ground_fast(&self, p: [f64; 2]) -> [f64; 2] {
        let g = &self.grid;
        let fx = ((p[0] + g.half_mm) / g.step_mm).clamp(0.0, (g.n - 1) as f64 - 1e-9);
        let fy = ((p[1] + g.half_mm) / g.step_mm).clamp(0.0, (g.n - 1) as f64 - 1e-9);
        let (i, j) = (fx.floor() as usize, fy.floor() as usize);
        let (tx, ty) = (fx - i as f64, fy - j as f64);
        let [n00, n10, n01, n11] =
            [(i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1)].map(|(i, j)| g.node(self, i, j));
        std::array::from_fn(|k| {
            let q = |n: [f32; 2]| n[k] as f64;
            let a = q(n00) + tx * (q(n10) - q(n00));
            let b = q(n01) + tx * (q(n11) - q(n01));
            a + ty * (b - a)
        })
    }

    /// The picture's transmittance at photo point `p` (mm): the ground's reflectance where
    /// the ray meets it, as a diapositive.
    pub fn transmittance(&self, p: [f64; 2]) -> f64 {
        let [x, y] = self.ground_fast(p);
        self.transmittance_at(x, y)
    }

    /// As [`AerialPhoto::transmittance`], the ray followed to the terrain exactly
    /// ([`AerialPhoto::ground_point`]) rather than through the rendering grid, whose bilinear
    /// nodes 0.25 mm apart misplace the ground by 4 cm RMS and up to half a metre where the
    /// terrain's facets meet: a rendered scene is the truth the matchers are measured
    /// against to a few centimetres.
    pub fn transmittance_exact(&self, p: [f64; 2]) -> f64 {
        let [x, y, _] = self.ground_point_near(p);
        self.transmittance_at(x, y)
    }

    /// [`AerialPhoto::ground_point`] from the rendering grid's guess: the ray's crossing of
    /// the terrain bracketed within ±4 m of the height there (widened if need be) and found by
    /// regula falsi (Illinois) to a millimetre; the full march from above where no bracket
    /// holds. The same point but where the ray grazes the terrain twice within the bracket.
    pub fn ground_point_near(&self, p: [f64; 2]) -> [f64; 3] {
        let [gx, gy] = self.ground_fast(p);
        let guess = self.dem.height(gx, gy);
        let (_, at) = self.ray(p);
        let f = |z: f64| {
            let [x, y] = at(z);
            z - self.dem.height(x, y)
        };
        let mut w = 4.0;
        let (mut hi, mut lo);
        let (mut fh, mut fl);
        loop {
            (hi, lo) = (guess + w, guess - w);
            (fh, fl) = (f(hi), f(lo));
            if fh > 0.0 && fl <= 0.0 {
                break;
            }
            w *= 4.0;
            if w > 300.0 {
                return self.ground_point(p);
            }
        }
        let mut side = 0;
        for _ in 0..60 {
            let z = (lo * fh - hi * fl) / (fh - fl);
            let fz = f(z);
            if fz > 0.0 {
                hi = z;
                fh = fz;
                if side == 1 {
                    fl *= 0.5;
                }
                side = 1;
            } else {
                lo = z;
                fl = fz;
                if side == -1 {
                    fh *= 0.5;
                }
                side = -1;
            }
            if fz.abs() < 1e-4 || hi - lo < 1e-3 {
                break;
            }
        }
        let z = (lo * fh - hi * fl) / (fh - fl);
        let [x, y] = at(z);
        [x, y, z]
    }

    fn transmittance_at(&self, x: f64, y: f64) -> f64 {
        self.t_min + (self.t_max - self.t_min) * self.reflectance_at(x, y)
    }

    /// The ground's reflectance at (x, y) in this photo's texture.
    pub fn reflectance_at(&self, x: f64, y: f64) -> f64 {
        self.texture.at(self.texture_seed, &self.dem, x, y)
    }
}

impl AerialPhoto {
    /// The photo as an image: `width × height` pixels of `step_mm` from the top-left corner
    /// `corner_mm` (x right, y up), each the mean of `k × k` samples of the picture's
    /// transmittance (each sample's ray followed to the terrain exactly); rows run down the
    /// photo's y axis.
    pub fn render(
        &self,
        corner_mm: [f64; 2],
        step_mm: f64,
        width: usize,
        height: usize,
        k: usize,
    ) -> Vec<f32> {
        use rayon::prelude::*;
        let k = k.max(1);
        let mut img = vec![0f32; width * height];
        img.par_chunks_mut(width).enumerate().for_each(|(r, row)| {
            for (c, v) in row.iter_mut().enumerate() {
                let mut s = 0.0;
                for j in 0..k {
                    for i in 0..k {
                        let x = corner_mm[0] + (c as f64 + (i as f64 + 0.5) / k as f64) * step_mm;
                        let y = corner_mm[1] - (r as f64 + (j as f64 + 0.5) / k as f64) * step_mm;
                        s += self.transmittance_exact([x, y]);
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

    #[test]
    fn the_bundled_dem_is_the_documented_one() {
        let d = jacksboro();
        assert_eq!((d.cols, d.rows), (403, 344));
        assert_eq!((d.min_m, d.max_m), (236.0, 1076.0));
        // 3″ cells at 36.6° N: about 74.5 × 92.1 m.
        assert!((d.cell_m[0] - 74.5).abs() < 0.5 && (d.cell_m[1] - 92.1).abs() < 0.5);
    }

    #[test]
    fn rays_meet_the_terrain_where_they_project_back() {
        let p = AerialPhoto::new(jacksboro(), 7, 2, 10.0);
        for q in [[0.0, 0.0], [95.0, -80.0], [-100.0, 100.0], [33.3, 12.1]] {
            let g = p.ground_point(q);
            assert!((g[2] - p.dem.height(g[0], g[1])).abs() < 0.01);
            let b = p.project(g);
            assert!(
                (b[0] - q[0]).abs() < 1e-6 && (b[1] - q[1]).abs() < 1e-6,
                "{q:?} → {b:?}"
            );
        }
        // The scale is the seed's, about 1:42 500.
        let a = p.ground_point([-5.0, 0.0]);
        let b = p.ground_point([5.0, 0.0]);
        let scale = (a[0] - b[0]).hypot(a[1] - b[1]) / 0.010;
        assert!((35_000.0..50_000.0).contains(&scale), "1:{scale:.0}");
    }

    /// The fast exact intersection is the marching one's point (to the marching's own
    /// millimetre), where the grid's guess is off by decimetres.
    #[test]
    fn the_bracketed_intersection_is_the_marched_one() {
        let p = AerialPhoto::new(jacksboro(), 3, 1, 110.0);
        for j in 0..40 {
            for i in 0..40 {
                let q = [
                    38.0 + 0.3 * i as f64 + 0.011,
                    -70.0 + 0.3 * j as f64 + 0.007,
                ];
                let (a, b) = (p.ground_point(q), p.ground_point_near(q));
                assert!((a[2] - b[2]).abs() < 3e-3, "{q:?}: {a:?} vs {b:?}");
                assert!(
                    (a[0] - b[0]).hypot(a[1] - b[1]) < 3e-3,
                    "{q:?}: {a:?} vs {b:?}"
                );
            }
        }
    }

    #[test]
    fn neighbours_in_a_strip_overlap_by_about_sixty_percent() {
        let d = jacksboro();
        let (a, b) = (
            AerialPhoto::new(d.clone(), 3, 1, 1.0),
            AerialPhoto::new(d, 3, 2, 1.0),
        );
        // The ground under photo 1's centre appears in photo 2 about 92 mm (40 % of 230) back.
        let g = a.ground_point([0.0, 0.0]);
        let q = b.project(g);
        assert!((q[0] + 92.0).abs() < 12.0 && q[1].abs() < 12.0, "{q:?}");
    }

    /// Photos 5 and 6 continue the strips: photo 5 lies a base beyond photo 2 and photo 6
    /// beside it in strip 2 (the 30 % side lap), so photo 1's ground near x = 80 mm, y = −62 mm
    /// is in all six.
    #[test]
    fn photos_five_and_six_continue_the_strips() {
        let d = jacksboro();
        let p: Vec<AerialPhoto> = (1..=6)
            .map(|n| AerialPhoto::new(d.clone(), 3, n, 1.0))
            .collect();
        let g = p[0].ground_point([0.0, 0.0]);
        let q5 = p[4].project(g);
        assert!((q5[0] + 184.0).abs() < 14.0 && q5[1].abs() < 14.0, "{q5:?}");
        let q6 = p[5].project(g);
        assert!(
            (q6[0] + 184.0).abs() < 14.0 && (q6[1] - 161.0).abs() < 14.0,
            "{q6:?}"
        );
        let inside = p[0].ground_point([84.0, -62.0]);
        for ph in &p {
            let q = ph.project(inside);
            assert!(
                q[0].abs() < 110.0 && q[1].abs() < 110.0,
                "photo {}: {q:?}",
                ph.number
            );
        }
    }
}
