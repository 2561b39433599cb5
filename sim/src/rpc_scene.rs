//! Crops of real satellite products, rendered through the products' real RPCs over a real
//! terrain: what a user's pair of Pléiades crops looks like, with the truth known.
//!
//! The terrain is a real 1 m lidar DEM (400 × 400 m; tests/data/README.md gives its source),
//! laid on the UTM grid under the views' common ground point — its metres taken as local east
//! and north offsets in the point's UTM zone, its nodes on whole metres of the grid — and its
//! heights shifted into the heights all the RPCs cover (HEIGHT_OFF ± HEIGHT_SCALE). Each view
//! is an `size × size` crop of its product around that point: the crop's first pixel is the
//! product's (c0, r0), and its RPCs are the product's with the crop folded in
//! ([`Rpc00b::cropped`]), as crop tools hand them out. A pixel's grey value is the ground's
//! reflectance where the pixel's line of sight meets the terrain: the line of sight is the
//! RPC's inverse at every height ([`Rpc00b::locate`], the simulator's own iteration), and the
//! height where it meets the terrain comes from a secant iteration on
//! g(z) = z − terrain(ground of the pixel at z) (bisection where that fails). The geometry,
//! UTM included ([`crate::utm`]), is the simulator's own.

use crate::rpc::Rpc00b;
use crate::scene::{Dem, Texture};
use crate::utm::Zone;
use serde::Serialize;
use std::sync::{Arc, OnceLock};

/// Heights above and below the terrain that the views must cover, m.
pub const HEIGHT_MARGIN_M: f64 = 10.0;
/// The ground a crop sees must stay this far inside the terrain's edge, m.
const EDGE_MARGIN_M: f64 = 3.0;
/// Where a line of sight meets the terrain: to this many metres of height (at Pléiades'
/// obliquity, 3e-6 m on the ground, 6e-6 of a 0.5 m pixel).
const HIT_TOLERANCE_M: f64 = 1e-5;

/// The lidar DEM as its file holds it (heights unshifted), parsed once.
pub fn lidar() -> Arc<Dem> {
    static DEM: OnceLock<Arc<Dem>> = OnceLock::new();
    DEM.get_or_init(|| {
        let bytes = include_bytes!("../../tests/data/lidar_dem_1m.tif");
        Arc::new(parse_geotiff_dem(bytes).expect("the bundled lidar DEM reads"))
    })
    .clone()
}

/// A single-band float32 GeoTIFF DEM on a north-up grid: its heights row by row from the
/// north, its cell from ModelPixelScaleTag (33550). Its place on the Earth is not used: the
/// scene lays it where the views look.
pub fn parse_geotiff_dem(bytes: &[u8]) -> Result<Dem, String> {
    use tiff::decoder::{Decoder, DecodingResult};
    use tiff::tags::Tag;
    let mut d = Decoder::new(std::io::Cursor::new(bytes)).map_err(|e| e.to_string())?;
    let (w, h) = d.dimensions().map_err(|e| e.to_string())?;
    let scale = d
        .get_tag_f64_vec(Tag::ModelPixelScaleTag)
        .map_err(|e| format!("ModelPixelScaleTag: {e}"))?;
    if scale.len() < 2 || !(scale[0] > 0.0 && scale[1] > 0.0) {
        return Err(format!(
            "ModelPixelScaleTag {scale:?}: two cell sizes above 0"
        ));
    }
    let heights = match d.read_image().map_err(|e| e.to_string())? {
        DecodingResult::F32(v) => v,
        _ => return Err("not float32".into()),
    };
    if let Some(k) = heights.iter().position(|z| z.is_nan() || z.abs() >= 1e6) {
        return Err(format!(
            "node ({}, {}) holds {} (nodata is not supported)",
            k % w as usize,
            k / w as usize,
            heights[k]
        ));
    }
    let min_m = heights.iter().fold(f64::MAX, |m, &z| m.min(z as f64));
    let max_m = heights.iter().fold(f64::MIN, |m, &z| m.max(z as f64));
    Ok(Dem {
        cols: w as usize,
        rows: h as usize,
        cell_m: [scale[0], scale[1]],
        heights,
        min_m,
        max_m,
    })
}

/// One view: a crop of a product.
#[derive(Debug, Clone, Serialize)]
pub struct RpcView {
    /// 1, 2, … in the order the RPCs were given.
    pub number: u32,
    /// The product's RPCs, as read.
    pub product: Rpc00b,
    /// The crop's: the product's with the crop's corner folded in.
    pub crop: Rpc00b,
    /// The crop's first pixel in the product's pixels (column c0, row r0).
    pub corner: [i64; 2],
    /// Columns and rows of the crop.
    pub size: usize,
}

/// The terrain under the views, where it lies, and the views.
#[derive(Debug, Clone, Serialize)]
pub struct RpcScene {
    /// The terrain in local metres (x east, y north from its south-west corner), heights
    /// shifted by `height_shift_m`.
    #[serde(skip)]
    pub dem: Arc<Dem>,
    pub zone: Zone,
    /// UTM easting and northing of the local origin, m.
    pub origin_m: [f64; 2],
    /// Added to the lidar's heights to put them among the RPCs' heights, m.
    pub height_shift_m: f64,
    /// The common ground point the crops are centred on: local metres and height, and its
    /// longitude and latitude.
    pub centre_m: [f64; 3],
    pub centre_lonlat: [f64; 2],
    pub views: Vec<RpcView>,
    pub texture_seed: u64,
    pub texture: Texture,
    /// Reflectance → signal, as the other scenes' t_min + (t_max − t_min)·reflectance.
    pub t_min: f64,
    pub t_max: f64,
}

/// Why a scene cannot be laid out.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("give 2 or more views' RPCs, not {0}")]
    TooFewViews(usize),
    #[error("view {view}'s RPCs do not reach view 1's centre ({lon:.6}°, {lat:.6}°): they cover longitudes {lon_lo:.6} … {lon_hi:.6}° and latitudes {lat_lo:.6} … {lat_hi:.6}° (LONG_OFF ± LONG_SCALE, LAT_OFF ± LAT_SCALE): are they of the same area?")]
    NoCommonGround {
        view: u32,
        lon: f64,
        lat: f64,
        lon_lo: f64,
        lon_hi: f64,
        lat_lo: f64,
        lat_hi: f64,
    },
    #[error("the views' RPCs all cover only the heights {lo:.1} … {hi:.1} m (HEIGHT_OFF ± HEIGHT_SCALE): too few for the terrain's {relief:.1} m of relief and {margin} m above and below it")]
    Heights {
        lo: f64,
        hi: f64,
        relief: f64,
        margin: f64,
    },
    #[error("view {view}: the crop's samples {c0} … {c1} and lines {r0} … {r1} leave the product's {s_lo:.1} … {s_hi:.1} and {l_lo:.1} … {l_hi:.1} (SAMP_OFF ± SAMP_SCALE, LINE_OFF ± LINE_SCALE)")]
    CropOutside {
        view: u32,
        c0: i64,
        c1: i64,
        r0: i64,
        r1: i64,
        s_lo: f64,
        s_hi: f64,
        l_lo: f64,
        l_hi: f64,
    },
    #[error("view {view}: a crop of {size} px sees ground up to {seen_m:.0} m from its centre, beyond the {half_m:.0} m the terrain reaches: at most about {max} px")]
    TooLarge {
        view: u32,
        size: usize,
        seen_m: f64,
        half_m: f64,
        max: usize,
    },
    #[error("view {view}: the RPCs cannot be inverted at pixel ({col:.2}, {row:.2}) of the crop")]
    NoGround { view: u32, col: f64, row: f64 },
}

/// Where the last line of sight met the terrain: the next one, a fraction of a pixel away,
/// starts there.
#[derive(Debug, Clone, Copy)]
pub struct Warm {
    lonlat: Option<[f64; 2]>,
    z: f64,
    /// dg/dz there: 1 less the terrain's rise along the sight per metre of height.
    slope: f64,
}

impl RpcScene {
    /// The views of `products` over the lidar terrain, `size × size` pixels each, centred on
    /// the first product's centre (LONG_OFF, LAT_OFF); the texture drawn from `seed`.
    pub fn new(products: Vec<Rpc00b>, size: usize, seed: u64) -> Result<RpcScene, SceneError> {
        if products.len() < 2 {
            return Err(SceneError::TooFewViews(products.len()));
        }
        let raw = lidar();
        let (lon, lat) = (products[0].long_off, products[0].lat_off);
        for (k, r) in products.iter().enumerate() {
            if (lon - r.long_off).abs() > r.long_scale || (lat - r.lat_off).abs() > r.lat_scale {
                return Err(SceneError::NoCommonGround {
                    view: k as u32 + 1,
                    lon,
                    lat,
                    lon_lo: r.long_off - r.long_scale,
                    lon_hi: r.long_off + r.long_scale,
                    lat_lo: r.lat_off - r.lat_scale,
                    lat_hi: r.lat_off + r.lat_scale,
                });
            }
        }
        // The terrain's heights inside the heights every model covers, as near their
        // offsets' mean as they fit.
        let lo = products
            .iter()
            .map(|r| r.height_off - r.height_scale)
            .fold(f64::MIN, f64::max);
        let hi = products
            .iter()
            .map(|r| r.height_off + r.height_scale)
            .fold(f64::MAX, f64::min);
        let relief = raw.max_m - raw.min_m;
        let half = 0.5 * relief + HEIGHT_MARGIN_M;
        if hi - lo < 2.0 * half {
            return Err(SceneError::Heights {
                lo,
                hi,
                relief,
                margin: HEIGHT_MARGIN_M,
            });
        }
        let mean_off = products.iter().map(|r| r.height_off).sum::<f64>() / products.len() as f64;
        let mid = mean_off.clamp(lo + half, hi - half);
        let height_shift_m = (mid - 0.5 * (raw.min_m + raw.max_m)).round();
        let mut shifted = (*raw).clone();
        for z in &mut shifted.heights {
            *z = (*z as f64 + height_shift_m) as f32;
        }
        shifted.min_m += height_shift_m;
        shifted.max_m += height_shift_m;
        let dem = Arc::new(shifted);
        // The DEM's middle under the point, its nodes on whole cells of the UTM grid (node i
        // lies at origin + (i + ½)·cell).
        let zone = Zone::of(lon, lat);
        let [e, n] = zone.forward(lon, lat);
        let [ex, ey] = dem.extent_m();
        let [cx, cy] = dem.cell_m;
        let origin_m = [
            ((e - 0.5 * ex) / cx).round() * cx - 0.5 * cx,
            ((n - 0.5 * ey) / cy).round() * cy - 0.5 * cy,
        ];
        let (x, y) = (e - origin_m[0], n - origin_m[1]);
        let centre_m = [x, y, dem.height(x, y)];
        let mut scene = RpcScene {
            dem,
            zone,
            origin_m,
            height_shift_m,
            centre_m,
            centre_lonlat: [lon, lat],
            views: Vec::new(),
            texture_seed: seed ^ 0x7E47_u64,
            texture: Texture::Natural,
            t_min: 0.05,
            t_max: 0.88,
        };
        for (k, product) in products.into_iter().enumerate() {
            let number = k as u32 + 1;
            let [s, l] = product.project(lon, lat, centre_m[2]);
            let half_px = 0.5 * (size as f64 - 1.0);
            let corner = [(s - half_px).round() as i64, (l - half_px).round() as i64];
            let last = size as i64 - 1;
            let (s_lo, s_hi) = (
                product.samp_off - product.samp_scale,
                product.samp_off + product.samp_scale,
            );
            let (l_lo, l_hi) = (
                product.line_off - product.line_scale,
                product.line_off + product.line_scale,
            );
            if (corner[0] as f64) < s_lo - 0.5
                || (corner[0] + last) as f64 > s_hi + 0.5
                || (corner[1] as f64) < l_lo - 0.5
                || (corner[1] + last) as f64 > l_hi + 0.5
            {
                return Err(SceneError::CropOutside {
                    view: number,
                    c0: corner[0],
                    c1: corner[0] + last,
                    r0: corner[1],
                    r1: corner[1] + last,
                    s_lo,
                    s_hi,
                    l_lo,
                    l_hi,
                });
            }
            let crop = product.cropped(corner[0] as f64, corner[1] as f64);
            scene.views.push(RpcView {
                number,
                product,
                crop,
                corner,
                size,
            });
        }
        scene.check_footprints()?;
        Ok(scene)
    }

    /// Every crop's edge must see ground inside the terrain (with a margin): the largest
    /// size that would is named otherwise.
    fn check_footprints(&self) -> Result<(), SceneError> {
        let [ex, ey] = self.dem.extent_m();
        let half_m = 0.5 * ex.min(ey) - EDGE_MARGIN_M;
        for (k, v) in self.views.iter().enumerate() {
            let n = v.size as f64;
            let mut seen_m: f64 = 0.0;
            for i in 0..=8 {
                for (c, r) in [
                    (-0.5 + n * i as f64 / 8.0, -0.5),
                    (-0.5 + n * i as f64 / 8.0, n - 0.5),
                    (-0.5, -0.5 + n * i as f64 / 8.0),
                    (n - 0.5, -0.5 + n * i as f64 / 8.0),
                ] {
                    let g = self.ground_point(k, c, r, &mut self.warm())?;
                    let d = (g[0] - 0.5 * ex).abs().max((g[1] - 0.5 * ey).abs());
                    seen_m = seen_m.max(d);
                }
            }
            if seen_m > half_m {
                return Err(SceneError::TooLarge {
                    view: v.number,
                    size: v.size,
                    seen_m,
                    half_m,
                    max: (n * half_m / seen_m).floor() as usize,
                });
            }
        }
        Ok(())
    }

    /// A start for [`RpcScene::ground_point`]: the centre's height.
    pub fn warm(&self) -> Warm {
        Warm {
            lonlat: None,
            z: self.centre_m[2],
            slope: 1.0,
        }
    }

    /// UTM easting and northing of local (x, y).
    pub fn to_utm(&self, x: f64, y: f64) -> [f64; 2] {
        [self.origin_m[0] + x, self.origin_m[1] + y]
    }

    /// Longitude and latitude of local (x, y).
    pub fn lonlat(&self, x: f64, y: f64) -> [f64; 2] {
        let [e, n] = self.to_utm(x, y);
        self.zone.inverse(e, n)
    }

    /// Local (x, y) of a longitude and latitude.
    pub fn local(&self, [lon, lat]: [f64; 2]) -> [f64; 2] {
        let [e, n] = self.zone.forward(lon, lat);
        [e - self.origin_m[0], n - self.origin_m[1]]
    }

    /// Where view `k`'s crop sees local ground point g: (sample, line) of the crop, (0, 0)
    /// at the centre of its first pixel, through the crop's RPCs.
    pub fn project(&self, k: usize, g: [f64; 3]) -> [f64; 2] {
        let [lon, lat] = self.lonlat(g[0], g[1]);
        self.views[k].crop.project(lon, lat, g[2])
    }

    /// Where the line of sight of view `k`'s crop pixel (col, row) ((0, 0) at the centre of
    /// its first pixel) meets the terrain, local metres: through the product's RPCs at the
    /// product's pixel (c0 + col, r0 + row). The height by a secant iteration on
    /// g(z) = z − terrain(x(z), y(z)) from `warm` (g rises with z wherever the terrain's slope
    /// times the sight's obliquity stays below 1, so its one root is the first hit), by
    /// bisection over the terrain's heights where the secant stalls.
    pub fn ground_point(
        &self,
        k: usize,
        col: f64,
        row: f64,
        warm: &mut Warm,
    ) -> Result<[f64; 3], SceneError> {
        let v = &self.views[k];
        let (s, l) = (v.corner[0] as f64 + col, v.corner[1] as f64 + row);
        let fail = || SceneError::NoGround {
            view: v.number,
            col,
            row,
        };
        let eval = |z: f64, guess: Option<[f64; 2]>| -> Option<(f64, [f64; 2], [f64; 2])> {
            let ll = v.product.locate(s, l, z, guess)?;
            let [x, y] = self.local(ll);
            Some((z - self.dem.height(x, y), ll, [x, y]))
        };
        let done = |z: f64, xy: [f64; 2], ll: [f64; 2], slope: f64, warm: &mut Warm| {
            *warm = Warm {
                lonlat: Some(ll),
                z,
                slope,
            };
            [xy[0], xy[1], z]
        };
        let mut z0 = warm.z;
        let (mut g0, mut ll, mut xy) = eval(z0, warm.lonlat)
            .or_else(|| eval(z0, None))
            .ok_or_else(fail)?;
        if g0.abs() < HIT_TOLERANCE_M {
            return Ok(done(z0, xy, ll, warm.slope, warm));
        }
        // First step along the last sight's slope (1 at the start: the terrain's height under
        // the sight at z0), then secant steps.
        let mut slope = warm.slope.clamp(0.1, 10.0);
        let mut z1 = z0 - g0 / slope;
        for _ in 0..30 {
            let Some((g1, ll1, xy1)) = eval(z1, Some(ll)) else {
                break;
            };
            (ll, xy) = (ll1, xy1);
            if z1 != z0 {
                slope = (g1 - g0) / (z1 - z0);
            }
            if g1.abs() < HIT_TOLERANCE_M {
                return Ok(done(z1, xy, ll, slope, warm));
            }
            if !(slope.is_finite() && slope > 0.05) {
                break;
            }
            (z0, g0) = (z1, g1);
            z1 -= g1 / slope;
        }
        // Bisection between heights above and below all the terrain.
        let (mut lo, mut hi) = (self.dem.min_m - 1.0, self.dem.max_m + 1.0);
        let mut guess = Some(ll);
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            let (g, l2, xy2) = eval(mid, guess).ok_or_else(fail)?;
            guess = Some(l2);
            if g.abs() < HIT_TOLERANCE_M || hi - lo < HIT_TOLERANCE_M {
                return Ok(done(mid, xy2, l2, 1.0, warm));
            }
            if g > 0.0 {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        Err(fail())
    }

    /// The ground's reflectance at local (x, y).
    pub fn reflectance_at(&self, x: f64, y: f64) -> f64 {
        self.texture.at(self.texture_seed, &self.dem, x, y)
    }

    /// View `k`'s crop as an image, `size × size`, each pixel the mean signal of `n × n`
    /// lines of sight spread evenly across it (t_min + (t_max − t_min)·reflectance).
    pub fn render(&self, k: usize, n: usize) -> Result<Vec<f32>, SceneError> {
        use rayon::prelude::*;
        let n = n.max(1);
        let size = self.views[k].size;
        let mut img = vec![0f32; size * size];
        img.par_chunks_mut(size).enumerate().try_for_each(
            |(r, row)| -> Result<(), SceneError> {
                let mut sums = vec![0.0; size];
                let mut warm = self.warm();
                for j in 0..n {
                    let line = r as f64 - 0.5 + (j as f64 + 0.5) / n as f64;
                    for (c, sum) in sums.iter_mut().enumerate() {
                        for i in 0..n {
                            let col = c as f64 - 0.5 + (i as f64 + 0.5) / n as f64;
                            let [x, y, _] = self.ground_point(k, col, line, &mut warm)?;
                            *sum +=
                                self.t_min + (self.t_max - self.t_min) * self.reflectance_at(x, y);
                        }
                    }
                }
                for (v, s) in row.iter_mut().zip(&sums) {
                    *v = (s / (n * n) as f64) as f32;
                }
                Ok(())
            },
        )?;
        Ok(img)
    }

    /// Where every crop sees local ground point g, each within its pixels' centres
    /// (0 … size − 1); `None` if one does not.
    pub fn seen_by_all(&self, g: [f64; 3]) -> Option<Vec<[f64; 2]>> {
        (0..self.views.len())
            .map(|k| {
                let q = self.project(k, g);
                let last = self.views[k].size as f64 - 1.0;
                ((0.0..=last).contains(&q[0]) && (0.0..=last).contains(&q[1])).then_some(q)
            })
            .collect()
    }

    /// The ground all the crops see: view 1's crop sampled on an (n + 1) × (n + 1) grid of
    /// pixels, each point kept where every other crop sees it.
    pub fn common_ground(&self, n: usize) -> Result<Vec<[f64; 3]>, SceneError> {
        let size = self.views[0].size as f64;
        let mut out = Vec::new();
        let mut warm = self.warm();
        for j in 0..=n {
            for i in 0..=n {
                let (c, r) = (
                    (size - 1.0) * i as f64 / n as f64,
                    (size - 1.0) * j as f64 / n as f64,
                );
                let g = self.ground_point(0, c, r, &mut warm)?;
                if self.seen_by_all(g).is_some() {
                    out.push(g);
                }
            }
        }
        Ok(out)
    }

    /// Pixels of parallax per metre of height between views `a` and `b` at the centre: how
    /// far a point's image in `b` moves against its image in `a` when it rises 1 m.
    pub fn parallax_px_per_m(&self, a: usize, b: usize) -> f64 {
        let g = self.centre_m;
        let up = [g[0], g[1], g[2] + 1.0];
        let d = |k: usize| {
            let (p, q) = (self.project(k, g), self.project(k, up));
            [q[0] - p[0], q[1] - p[1]]
        };
        let (da, db) = (d(a), d(b));
        (db[0] - da[0]).hypot(db[1] - da[1])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gizeh(n: u32) -> Rpc00b {
        let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(format!("../tests/data/rpc/gizeh_img{n}_RPC.TXT"));
        Rpc00b::load(&p).unwrap()
    }

    #[test]
    fn the_bundled_lidar_dem_is_the_documented_one() {
        let d = lidar();
        assert_eq!((d.cols, d.rows, d.cell_m), (400, 400, [1.0, 1.0]));
        assert!((d.min_m - 379.659).abs() < 1e-3 && (d.max_m - 410.759).abs() < 1e-3);
    }

    /// Crop pixel → terrain → crop pixel (through the crop's folded RPCs) comes back to
    /// 1e-6 px, the point lies on the terrain, and the crop's centre sees the common point.
    #[test]
    fn lines_of_sight_meet_the_terrain_where_they_project_back() {
        let s = RpcScene::new(vec![gizeh(1), gizeh(2), gizeh(3)], 300, 1).unwrap();
        assert_eq!(s.zone.epsg(), 32636);
        // The terrain sits inside 10 … 270 m, around HEIGHT_OFF = 140 m.
        assert!(
            s.dem.min_m > 20.0 && s.dem.max_m < 260.0,
            "{:?}",
            (s.dem.min_m, s.dem.max_m)
        );
        for k in 0..3 {
            let c = s.project(k, s.centre_m);
            assert!(
                (c[0] - 149.5).abs() <= 0.5 && (c[1] - 149.5).abs() <= 0.5,
                "{c:?}"
            );
            let mut warm = s.warm();
            for (col, row) in [
                (0.0, 0.0),
                (299.0, 0.0),
                (17.3, 250.9),
                (150.0, 150.0),
                (-0.5, 299.5),
            ] {
                let g = s.ground_point(k, col, row, &mut warm).unwrap();
                assert!((g[2] - s.dem.height(g[0], g[1])).abs() < 1e-5);
                let q = s.project(k, g);
                assert!(
                    (q[0] - col).abs() < 1e-6 && (q[1] - row).abs() < 1e-6,
                    "view {k}: ({col}, {row}) → {g:?} → {q:?}"
                );
            }
        }
        // The pair of views 2 and 3 sees 0.29 px of parallax per metre (the triplet's widest).
        let p = s.parallax_px_per_m(1, 2);
        assert!((0.27..0.31).contains(&p), "{p}");
    }

    #[test]
    fn scenes_that_cannot_be_are_refused() {
        let e = RpcScene::new(vec![gizeh(1), gizeh(2)], 2000, 1)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("a crop of 2000 px") && e.contains("at most about"),
            "{e}"
        );
        let mut far = gizeh(2);
        far.long_off += 1.0;
        let e = RpcScene::new(vec![gizeh(1), far], 300, 1)
            .unwrap_err()
            .to_string();
        assert!(e.contains("view 2's RPCs do not reach"), "{e}");
        let mut low = gizeh(2);
        low.height_scale = 15.0;
        let e = RpcScene::new(vec![gizeh(1), low], 300, 1)
            .unwrap_err()
            .to_string();
        assert!(e.contains("only the heights 125.0 … 155.0 m"), "{e}");
    }
}
