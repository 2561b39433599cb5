//! Rational polynomial coefficients, RPC00B: the rigid polynomial mapping functions of seed 004
//! §4 as every satellite image now ships them. Line and sample are ratios of two cubic
//! polynomials of normalised longitude L, latitude P and height H, each of 20 terms in the
//! RPC00B order 1, L, P, H, LP, LH, PH, L², P², H², PLH, L³, LP², LH², L²P, P³, PH², L²H,
//! P²H, H³ (NITF STDI-0002 RPC00B, and GDAL's RPC transformer).
//!
//! Image coordinates of an RPC have (0, 0) at the centre of the top-left pixel, as the
//! standard and GDAL take them; the core's continuous pixels have it at the pixel's corner:
//! core column = sample + 0.5, core row = line + 0.5, and nowhere else is that shift made.

use super::convergence::{ulp, Convergence};
use super::geographic::{Geographic, GeographicError, LonLatH};
use super::{ProjectionError, Sensor};
use crate::coords::{GroundM, PixelXY};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Newton's iterations of [`Rpc::locate`] (ground at a height from a pixel).
const MAX_ITERATIONS: usize = 30;

#[derive(Debug, thiserror::Error)]
pub enum RpcError {
    #[error("{path}: {message}")]
    File { path: String, message: String },
    #[error("{0}")]
    Invalid(String),
    #[error(transparent)]
    Geographic(#[from] GeographicError),
    #[error("fitting RPCs: {0}")]
    Fit(String),
}

/// The 20 terms of RPC00B at normalised (L, P, H).
pub fn terms(l: f64, p: f64, h: f64) -> [f64; 20] {
    [
        1.0,
        l,
        p,
        h,
        l * p,
        l * h,
        p * h,
        l * l,
        p * p,
        h * h,
        p * l * h,
        l * l * l,
        l * p * p,
        l * h * h,
        l * l * p,
        p * p * p,
        p * h * h,
        l * l * h,
        p * p * h,
        h * h * h,
    ]
}

fn dot(c: &[f64; 20], t: &[f64; 20]) -> f64 {
    c.iter().zip(t).map(|(a, b)| a * b).sum()
}

/// One image's RPC00B model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Rpc {
    /// RMS bias and random error, metres per horizontal axis; −1 where unknown.
    pub err_bias: f64,
    pub err_rand: f64,
    pub line_off: f64,
    pub samp_off: f64,
    pub lat_off: f64,
    pub long_off: f64,
    pub height_off: f64,
    pub line_scale: f64,
    pub samp_scale: f64,
    pub lat_scale: f64,
    pub long_scale: f64,
    pub height_scale: f64,
    pub line_num: [f64; 20],
    pub line_den: [f64; 20],
    pub samp_num: [f64; 20],
    pub samp_den: [f64; 20],
}

/// The TIFF tag that holds RPCs (RPCCoefficientTag), the 92 numbers of [`Rpc::to_values`].
pub const TIFF_TAG: u16 = 50844;

/// The keys of a GDAL `_RPC.TXT` file and of GDAL's RPC metadata, in the order of the TIFF
/// RPCCoefficientTag (50844).
const SCALARS: [&str; 12] = [
    "ERR_BIAS",
    "ERR_RAND",
    "LINE_OFF",
    "SAMP_OFF",
    "LAT_OFF",
    "LONG_OFF",
    "HEIGHT_OFF",
    "LINE_SCALE",
    "SAMP_SCALE",
    "LAT_SCALE",
    "LONG_SCALE",
    "HEIGHT_SCALE",
];
const ARRAYS: [&str; 4] = [
    "LINE_NUM_COEFF",
    "LINE_DEN_COEFF",
    "SAMP_NUM_COEFF",
    "SAMP_DEN_COEFF",
];

impl Rpc {
    /// The 92 numbers of the TIFF RPCCoefficientTag, in its order.
    pub fn to_values(&self) -> Vec<f64> {
        let mut v = vec![
            self.err_bias,
            self.err_rand,
            self.line_off,
            self.samp_off,
            self.lat_off,
            self.long_off,
            self.height_off,
            self.line_scale,
            self.samp_scale,
            self.lat_scale,
            self.long_scale,
            self.height_scale,
        ];
        for a in [
            &self.line_num,
            &self.line_den,
            &self.samp_num,
            &self.samp_den,
        ] {
            v.extend_from_slice(a);
        }
        v
    }

    /// From the 92 numbers of the TIFF tag; checked.
    pub fn from_values(v: &[f64]) -> Result<Rpc, RpcError> {
        if v.len() != 92 {
            return Err(RpcError::Invalid(format!(
                "an RPC00B model has 92 numbers, not {}",
                v.len()
            )));
        }
        let arr = |k: usize| -> [f64; 20] {
            let mut a = [0.0; 20];
            a.copy_from_slice(&v[12 + 20 * k..32 + 20 * k]);
            a
        };
        let r = Rpc {
            err_bias: v[0],
            err_rand: v[1],
            line_off: v[2],
            samp_off: v[3],
            lat_off: v[4],
            long_off: v[5],
            height_off: v[6],
            line_scale: v[7],
            samp_scale: v[8],
            lat_scale: v[9],
            long_scale: v[10],
            height_scale: v[11],
            line_num: arr(0),
            line_den: arr(1),
            samp_num: arr(2),
            samp_den: arr(3),
        };
        r.check().map_err(RpcError::Invalid)?;
        Ok(r)
    }

    /// Every number in its range, with the key named.
    pub fn check(&self) -> Result<(), String> {
        let v = self.to_values();
        for (k, x) in SCALARS.iter().zip(&v) {
            if !x.is_finite() {
                return Err(format!("{k} must be a finite number (got {x})"));
            }
        }
        for (n, name) in ARRAYS.iter().enumerate() {
            for (i, x) in v[12 + 20 * n..32 + 20 * n].iter().enumerate() {
                if !x.is_finite() {
                    return Err(format!(
                        "{name}_{} must be a finite number (got {x})",
                        i + 1
                    ));
                }
            }
        }
        let ranges = [
            ("LAT_OFF", self.lat_off, -90.0, 90.0),
            ("LONG_OFF", self.long_off, -180.0, 360.0),
            ("LAT_SCALE", self.lat_scale, 1e-5, 90.0),
            ("LONG_SCALE", self.long_scale, 1e-5, 180.0),
            ("HEIGHT_SCALE", self.height_scale, 1e-6, 1e5),
            ("HEIGHT_OFF", self.height_off, -1e4, 1e5),
            ("LINE_SCALE", self.line_scale, 1e-6, 1e7),
            ("SAMP_SCALE", self.samp_scale, 1e-6, 1e7),
            ("LINE_OFF", self.line_off, -1e7, 1e7),
            ("SAMP_OFF", self.samp_off, -1e7, 1e7),
        ];
        for (k, x, lo, hi) in ranges {
            if !(lo..=hi).contains(&x) {
                return Err(format!("{k} must be {lo} … {hi} (got {x})"));
            }
        }
        for (k, e) in [("ERR_BIAS", self.err_bias), ("ERR_RAND", self.err_rand)] {
            if e != -1.0 && !(0.0..=1e4).contains(&e) {
                return Err(format!("{k} must be −1 (unknown) or 0 … 10000 m (got {e})"));
            }
        }
        if self.line_den.iter().all(|c| *c == 0.0) || self.samp_den.iter().all(|c| *c == 0.0) {
            return Err("LINE_DEN_COEFF and SAMP_DEN_COEFF must not be all zero".into());
        }
        Ok(())
    }

    /// Normalised (L, P, H) of a ground point.
    fn normalise(&self, g: LonLatH) -> (f64, f64, f64) {
        // Longitudes differ by less than half a turn (a scene across ±180°, an offset
        // given in 0 … 360).
        let dlon = (g.lon - self.long_off + 180.0).rem_euclid(360.0) - 180.0;
        (
            dlon / self.long_scale,
            (g.lat - self.lat_off) / self.lat_scale,
            (g.h - self.height_off) / self.height_scale,
        )
    }

    /// (sample, line) in the RPC's convention ((0, 0) at the top-left pixel's centre); `None`
    /// where a denominator vanishes.
    pub fn project(&self, g: LonLatH) -> Option<(f64, f64)> {
        let (l, p, h) = self.normalise(g);
        let t = terms(l, p, h);
        let (ld, sd) = (dot(&self.line_den, &t), dot(&self.samp_den, &t));
        if ld.abs() < 1e-12 || sd.abs() < 1e-12 {
            return None;
        }
        let line = dot(&self.line_num, &t) / ld * self.line_scale + self.line_off;
        let samp = dot(&self.samp_num, &t) / sd * self.samp_scale + self.samp_off;
        (line.is_finite() && samp.is_finite()).then_some((samp, line))
    }

    /// The longitude and latitude at height `h` seen at (sample, line): Newton's method on
    /// the forward model, from the model's centre, with the Jacobian by central differences
    /// over 1e-6 of the scales; converged ([`Convergence`]) when the step is below 1e-9 px or
    /// below what the longitude's and latitude's own resolution gives in pixels (at 0.31 m
    /// pixels near ±180° and 80° latitude one unit in the last place of a longitude is
    /// 1.8e-9 px), or when it stops shrinking.
    pub fn locate(&self, samp: f64, line: f64, h: f64) -> Result<LonLatH, ProjectionError> {
        const VANISHES: ProjectionError =
            ProjectionError::Model("a denominator of the RPCs vanishes on the way to the point");
        let mut g = LonLatH {
            lon: self.long_off,
            lat: self.lat_off,
            h,
        };
        let (dl, dp) = (self.long_scale * 1e-6, self.lat_scale * 1e-6);
        let mut test = Convergence::new(1e-9);
        for _ in 0..MAX_ITERATIONS {
            let (s, l) = self.project(g).ok_or(VANISHES)?;
            let at = |dlon: f64, dlat: f64| {
                self.project(LonLatH {
                    lon: g.lon + dlon,
                    lat: g.lat + dlat,
                    h,
                })
                .ok_or(VANISHES)
            };
            let (a, b) = (at(dl, 0.0)?, at(-dl, 0.0)?);
            let (c, d) = (at(0.0, dp)?, at(0.0, -dp)?);
            let j = [
                [(a.0 - b.0) / (2.0 * dl), (c.0 - d.0) / (2.0 * dp)],
                [(a.1 - b.1) / (2.0 * dl), (c.1 - d.1) / (2.0 * dp)],
            ];
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            if !det.is_finite() || det == 0.0 {
                return Err(ProjectionError::Model(
                    "the RPCs' Jacobian is singular there (the model folds over)",
                ));
            }
            let (rs, rl) = (samp - s, line - l);
            let dlon = (j[1][1] * rs - j[0][1] * rl) / det;
            let dlat = (-j[1][0] * rs + j[0][0] * rl) / det;
            g.lon += dlon;
            g.lat += dlat;
            if g.lat.is_nan() || g.lat.abs() > 90.0 || !g.lon.is_finite() {
                return Err(ProjectionError::Model(
                    "the RPCs' inverse leaves the globe (latitude beyond ±90°): the pixel is far outside the model's domain",
                ));
            }
            let px =
                (j[0][0] * dlon).hypot(j[1][1] * dlat) + (j[0][1] * dlat).hypot(j[1][0] * dlon);
            // One unit in the last place of the longitude and latitude, in pixels.
            let (ul, up) = (ulp(g.lon), ulp(g.lat));
            let floor = (j[0][0] * ul).hypot(j[1][0] * ul) + (j[0][1] * up).hypot(j[1][1] * up);
            if test.done(px, floor) {
                // In −180° … 180° whichever form LONG_OFF takes (0 … 360 too).
                g.lon = (g.lon + 180.0).rem_euclid(360.0) - 180.0;
                return Ok(g);
            }
        }
        Err(ProjectionError::NoConvergence {
            iterations: MAX_ITERATIONS,
            last_px: test.last_px,
        })
    }

    /// GDAL's `_RPC.TXT`: one `KEY: value` per line, the coefficients as `KEY_n`.
    pub fn to_txt(&self) -> String {
        let v = self.to_values();
        let mut s = String::new();
        for (k, x) in SCALARS.iter().zip(&v) {
            s.push_str(&format!("{k}: {x:e}\n"));
        }
        for (n, name) in ARRAYS.iter().enumerate() {
            for (i, x) in v[12 + 20 * n..32 + 20 * n].iter().enumerate() {
                s.push_str(&format!("{name}_{}: {x:e}\n", i + 1));
            }
        }
        s
    }

    /// Reads GDAL's `_RPC.TXT` (also the vendors' form with units after the numbers, and
    /// GDAL's metadata form with the 20 coefficients on one line); every key is required once,
    /// unknown keys are ignored, and every number is checked with its key and line named.
    pub fn parse_txt(text: &str, path: &Path) -> Result<Rpc, RpcError> {
        let fail = |message: String| RpcError::File {
            path: path.display().to_string(),
            message,
        };
        let mut values: Vec<Option<f64>> = vec![None; 92];
        for (n, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() {
                continue;
            }
            let Some((key, rest)) = line.split_once(':') else {
                continue;
            };
            let key = key.trim().to_ascii_uppercase();
            let number = |s: &str| -> Result<f64, RpcError> {
                s.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| {
                        fail(format!(
                            "line {}: {key}: `{s}` is not a finite number",
                            n + 1
                        ))
                    })
            };
            let mut words = rest.split_whitespace();
            let slot = if let Some(i) = SCALARS.iter().position(|k| *k == key) {
                Some(i)
            } else if let Some((base, idx)) = key.rsplit_once('_') {
                match (ARRAYS.iter().position(|k| *k == base), idx.parse::<usize>()) {
                    (Some(a), Ok(i)) if (1..=20).contains(&i) => Some(12 + 20 * a + i - 1),
                    (Some(_), _) => {
                        return Err(fail(format!(
                            "line {}: {key}: coefficients are numbered 1 … 20",
                            n + 1
                        )))
                    }
                    _ => None,
                }
            } else {
                None
            };
            if let Some(i) = slot {
                let w = words
                    .next()
                    .ok_or_else(|| fail(format!("line {}: {key} has no value", n + 1)))?;
                if values[i].replace(number(w)?).is_some() {
                    return Err(fail(format!("line {}: {key} is given twice", n + 1)));
                }
            } else if let Some(a) = ARRAYS.iter().position(|k| *k == key) {
                let all: Vec<&str> = words.collect();
                if all.len() != 20 {
                    return Err(fail(format!(
                        "line {}: {key} must have 20 numbers (got {})",
                        n + 1,
                        all.len()
                    )));
                }
                for (i, w) in all.iter().enumerate() {
                    if values[12 + 20 * a + i].replace(number(w)?).is_some() {
                        return Err(fail(format!("line {}: {key} is given twice", n + 1)));
                    }
                }
            }
        }
        let mut v = Vec::with_capacity(92);
        for (i, x) in values.iter().enumerate() {
            match (x, i) {
                (Some(x), _) => v.push(*x),
                // The errors are optional: unknown.
                (None, 0 | 1) => v.push(-1.0),
                (None, _) => {
                    let name = if i < 12 {
                        SCALARS[i].to_string()
                    } else {
                        format!("{}_{}", ARRAYS[(i - 12) / 20], (i - 12) % 20 + 1)
                    };
                    return Err(fail(format!("{name} is missing")));
                }
            }
        }
        Rpc::from_values(&v).map_err(|e| fail(e.to_string()))
    }

    /// Writes GDAL's `_RPC.TXT` beside `image` (atomically); the path written.
    pub fn write_beside(&self, image: &Path) -> std::io::Result<std::path::PathBuf> {
        let p = Rpc::txt_path(image);
        crate::atomic::write(&p, self.to_txt().as_bytes())?;
        Ok(p)
    }

    /// Reads the `_RPC.TXT` beside `image` (GDAL's name for it, or the same in lower case).
    pub fn read_beside(image: &Path) -> Result<Rpc, RpcError> {
        let upper = Rpc::txt_path(image);
        let lower = upper.with_file_name(
            upper
                .file_name()
                .map(|n| n.to_string_lossy().replace("_RPC.TXT", "_rpc.txt"))
                .unwrap_or_default(),
        );
        let path = if upper.exists() || !lower.exists() {
            upper
        } else {
            lower
        };
        let text = std::fs::read_to_string(&path).map_err(|e| RpcError::File {
            path: path.display().to_string(),
            message: format!("cannot read it: {e}"),
        })?;
        Rpc::parse_txt(&text, &path)
    }

    /// Reads the RPCs from a TIFF's RPCCoefficientTag ([`TIFF_TAG`], as GDAL writes them
    /// into a GeoTIFF), every number range-checked.
    pub fn read_tiff_tag(image: &Path) -> Result<Rpc, RpcError> {
        let fail = |message: String| RpcError::File {
            path: image.display().to_string(),
            message,
        };
        let f = std::fs::File::open(image).map_err(|e| fail(format!("cannot read it: {e}")))?;
        let mut d = tiff::decoder::Decoder::new(std::io::BufReader::new(f))
            .map_err(|e| fail(format!("not a TIFF: {e}")))?;
        let values = d
            .find_tag(tiff::tags::Tag::Unknown(TIFF_TAG))
            .map_err(|e| fail(format!("its RPC tag ({TIFF_TAG}) cannot be read: {e}")))?
            .ok_or_else(|| {
                fail(format!(
                    "it has no RPC tag ({TIFF_TAG}, RPCCoefficientTag): give the _RPC.TXT beside it instead"
                ))
            })?
            .into_f64_vec()
            .map_err(|e| fail(format!("its RPC tag ({TIFF_TAG}) is not numbers: {e}")))?;
        Rpc::from_values(&values).map_err(|e| fail(format!("its RPC tag ({TIFF_TAG}): {e}")))
    }

    /// GDAL's name for the RPC file of an image: `photo.tif` → `photo_RPC.TXT`.
    pub fn txt_path(image: &Path) -> std::path::PathBuf {
        let stem = image
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        image.with_file_name(format!("{stem}_RPC.TXT"))
    }
}

/// An image with its RPCs as a [`Sensor`]: ground in the project's CRS, converted to WGS 84
/// for the polynomials.
#[derive(Debug, Clone)]
pub struct RpcSensor {
    pub rpc: Rpc,
    pub geo: Geographic,
    pub width: usize,
    pub height: usize,
}

impl RpcSensor {
    /// Where the model is valid, in its normalised longitude and latitude: vendors fit the
    /// polynomials over the image at the height range and normalise that to ±1; an off-nadir
    /// view's corners at the extreme heights reach a little beyond (±1.05). Beyond ±1.2 the
    /// cubic is extrapolated and the image is not the one the RPCs describe.
    pub const DOMAIN: f64 = 1.2;

    /// The image must lie where its RPCs are valid. Judged by where the image's corners and
    /// centre fall on the ground (through the model, at the lowest, middle and highest of the
    /// RPCs' heights), not by the offsets: a crop's RPCs keep the full product's LINE_OFF and
    /// SAMP_OFF and fold the crop's shift into the numerators, and are right for the crop.
    /// The error names the first point that fails, and why.
    pub fn check_extent(&self) -> Result<(), String> {
        let r = &self.rpc;
        let (w, h) = (self.width as f64, self.height as f64);
        // The image's outer edges, in the RPCs' centre-origin pixels.
        let points = [
            ("top-left corner", -0.5, -0.5),
            ("top-right corner", w - 0.5, -0.5),
            ("bottom-left corner", -0.5, h - 0.5),
            ("bottom-right corner", w - 0.5, h - 0.5),
            ("centre", 0.5 * w - 0.5, 0.5 * h - 0.5),
        ];
        for (name, samp, line) in points {
            for z in [
                r.height_off - r.height_scale,
                r.height_off,
                r.height_off + r.height_scale,
            ] {
                let at = format!(
                    "the image's {name} (sample {samp:.1}, line {line:.1} in the RPCs' pixels) at {z:.0} m"
                );
                let g = r.locate(samp, line, z).map_err(|e| {
                    format!(
                        "{at} has no ground point through the RPCs ({e}): are they the RPCs of this {} × {} px image?",
                        self.width, self.height
                    )
                })?;
                let (l, p, _) = r.normalise(g);
                if l.abs() > Self::DOMAIN || p.abs() > Self::DOMAIN {
                    return Err(format!(
                        "{at} falls at longitude {:.6}°, latitude {:.6}°: {:.2} × LONG_SCALE from LONG_OFF and {:.2} × LAT_SCALE from LAT_OFF, outside where the RPCs are valid (±{}): are they the RPCs of this {} × {} px image, not of a smaller one?",
                        g.lon,
                        g.lat,
                        l.abs(),
                        p.abs(),
                        Self::DOMAIN,
                        self.width,
                        self.height
                    ));
                }
            }
        }
        Ok(())
    }
}

impl Sensor for RpcSensor {
    fn image_size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn try_ground_to_image(&self, g: GroundM) -> Result<PixelXY, ProjectionError> {
        let l = self.geo.to_lonlat(g).map_err(|_| ProjectionError::Crs)?;
        let (s, line) = self.rpc.project(l).ok_or(ProjectionError::Model(
            "a denominator of the RPCs vanishes at the point",
        ))?;
        Ok(PixelXY::new(s + 0.5, line + 0.5))
    }

    fn try_image_to_ground(&self, q: PixelXY, z: f64) -> Result<GroundM, ProjectionError> {
        let l = self.rpc.locate(q.col - 0.5, q.row - 0.5, z)?;
        let g = self.geo.to_ground(l).map_err(|_| ProjectionError::Crs)?;
        Ok(GroundM::new(g.x, g.y, z))
    }

    /// The RPC's stated errors (ERR_BIAS² + ERR_RAND², metres² per horizontal axis) carried
    /// to pixels through the horizontal partials; `None` where both are unknown (−1).
    fn pointing_covariance(&self, g: GroundM) -> Option<[[f64; 2]; 2]> {
        let known = |e: f64| if e >= 0.0 { Some(e * e) } else { None };
        let var = match (known(self.rpc.err_bias), known(self.rpc.err_rand)) {
            (None, None) => return None,
            (a, b) => a.unwrap_or(0.0) + b.unwrap_or(0.0),
        };
        let j = self.partials(g)?;
        let horizontal = [[var, 0.0, 0.0], [0.0, var, 0.0], [0.0, 0.0, 0.0]];
        Some(super::sensor::propagate(&j, &horizontal))
    }
}

/// How densely a sensor is sampled for the fit: `n × n` image points at `layers` heights
/// (the check points at the cells' centres and between the layers).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FitGrid {
    pub n: usize,
    pub layers: usize,
}

impl Default for FitGrid {
    /// 21 × 21 × 7: dense enough that 78 coefficients are over-determined 40 times, and every
    /// fitted pixel is within a twentieth of the image of a sample.
    fn default() -> FitGrid {
        FitGrid { n: 21, layers: 7 }
    }
}

/// The fit's figures, pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RpcFitReport {
    pub samples: usize,
    pub checks: usize,
    pub fit_rms_px: f64,
    pub check_rms_px: f64,
    pub check_max_px: f64,
    /// Iterations of the reweighting (Tao and Hu's terrain-independent solution).
    pub iterations: usize,
}

/// Samples of a sensor: ground (WGS 84) and the core's pixel.
fn sample(
    sensor: &dyn Sensor,
    geo: &Geographic,
    heights: [f64; 2],
    grid: FitGrid,
    between: bool,
) -> Result<Vec<(LonLatH, PixelXY)>, RpcError> {
    let (w, h) = sensor.image_size();
    let (n, layers) = (grid.n.max(2), grid.layers.max(2));
    let cells = if between { n - 1 } else { n };
    let zs = if between { layers - 1 } else { layers };
    let mut out = Vec::with_capacity(cells * cells * zs);
    for iz in 0..zs {
        let fz = (iz as f64 + if between { 0.5 } else { 0.0 }) / (layers - 1) as f64;
        let z = heights[0] + fz * (heights[1] - heights[0]);
        for ir in 0..cells {
            for ic in 0..cells {
                let off = if between { 0.5 } else { 0.0 };
                let q = PixelXY::new(
                    (ic as f64 + off) / (n - 1) as f64 * w as f64,
                    (ir as f64 + off) / (n - 1) as f64 * h as f64,
                );
                let Some(g) = sensor.image_to_ground(q, z) else {
                    return Err(RpcError::Fit(format!(
                        "the sensor sees nothing at pixel ({:.1}, {:.1}) and height {z:.1} m",
                        q.col, q.row
                    )));
                };
                out.push((geo.to_lonlat(g)?, q));
            }
        }
    }
    Ok(out)
}

/// Fits RPC00B to any sensor over the image and the height range `heights` (m): Tao and
/// Hu's terrain-independent least squares, line and sample separately, each
/// `num − r·den = 0` linear in the 39 unknowns (the denominator's constant fixed at 1),
/// reweighted by 1/den² and with a small Tikhonov term (1e-12 of the normals' mean
/// diagonal) that keeps the nearly undetermined denominator terms of a near-affine sensor at
/// zero. The check points lie between the samples, in the image and in height.
pub fn fit_rpc(
    sensor: &dyn Sensor,
    geo: &Geographic,
    heights: [f64; 2],
    grid: FitGrid,
) -> Result<(Rpc, RpcFitReport), RpcError> {
    if !(heights[0].is_finite() && heights[1].is_finite() && heights[1] > heights[0]) {
        return Err(RpcError::Fit(format!(
            "the heights must be two finite numbers, the lower first (got {heights:?})"
        )));
    }
    if !(2..=200).contains(&grid.n) || !(2..=50).contains(&grid.layers) {
        return Err(RpcError::Fit(format!(
            "the grid must be 2 … 200 points a side at 2 … 50 heights (got {} × {})",
            grid.n, grid.layers
        )));
    }
    let fit = sample(sensor, geo, heights, grid, false)?;
    let checks = sample(sensor, geo, heights, grid, true)?;
    let span = |f: &dyn Fn(&(LonLatH, PixelXY)) -> f64| {
        let (lo, hi) = fit
            .iter()
            .map(f)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(v), b.max(v))
            });
        ((lo + hi) / 2.0, ((hi - lo) / 2.0).max(1e-5))
    };
    let (lat_off, lat_scale) = span(&|s| s.0.lat);
    let (long_off, long_scale) = span(&|s| s.0.lon);
    let (line_off, line_scale) = span(&|s| s.1.row - 0.5);
    let (samp_off, samp_scale) = span(&|s| s.1.col - 0.5);
    let height_off = (heights[0] + heights[1]) / 2.0;
    let height_scale = (heights[1] - heights[0]) / 2.0;
    let mut rpc = Rpc {
        err_bias: -1.0,
        err_rand: -1.0,
        line_off,
        samp_off,
        lat_off,
        long_off,
        height_off,
        line_scale,
        samp_scale,
        lat_scale,
        long_scale,
        height_scale,
        line_num: [0.0; 20],
        line_den: [0.0; 20],
        samp_num: [0.0; 20],
        samp_den: [0.0; 20],
    };
    let t: Vec<[f64; 20]> = fit
        .iter()
        .map(|(g, _)| {
            let (l, p, h) = rpc.normalise(*g);
            terms(l, p, h)
        })
        .collect();
    let lines: Vec<f64> = fit
        .iter()
        .map(|s| (s.1.row - 0.5 - line_off) / line_scale)
        .collect();
    let samps: Vec<f64> = fit
        .iter()
        .map(|s| (s.1.col - 0.5 - samp_off) / samp_scale)
        .collect();
    const ITERATIONS: usize = 10;
    let mut iterations = 0;
    for (target, num, den) in [(&lines, 0, 1), (&samps, 2, 3)] {
        let (n, d, used) = fit_ratio(&t, target, ITERATIONS)?;
        iterations = iterations.max(used);
        let set = |rpc: &mut Rpc, k: usize, v: [f64; 20]| match k {
            0 => rpc.line_num = v,
            1 => rpc.line_den = v,
            2 => rpc.samp_num = v,
            _ => rpc.samp_den = v,
        };
        set(&mut rpc, num, n);
        set(&mut rpc, den, d);
    }
    rpc.check().map_err(RpcError::Fit)?;
    let errors = |set: &[(LonLatH, PixelXY)]| -> Result<Vec<f64>, RpcError> {
        set.iter()
            .map(|(g, q)| {
                let (s, l) = rpc.project(*g).ok_or_else(|| {
                    RpcError::Fit("a denominator vanishes inside the scene".into())
                })?;
                Ok(PixelXY::new(s + 0.5, l + 0.5).dist(*q))
            })
            .collect()
    };
    let rms = |e: &[f64]| (e.iter().map(|x| x * x).sum::<f64>() / e.len().max(1) as f64).sqrt();
    let (ef, ec) = (errors(&fit)?, errors(&checks)?);
    let report = RpcFitReport {
        samples: fit.len(),
        checks: checks.len(),
        fit_rms_px: rms(&ef),
        check_rms_px: rms(&ec),
        check_max_px: ec.iter().cloned().fold(0.0, f64::max),
        iterations,
    };
    Ok((rpc, report))
}

/// One ratio r = num/den by iterated reweighted least squares; returns numerator,
/// denominator (constant term 1) and the iterations used.
fn fit_ratio(
    t: &[[f64; 20]],
    r: &[f64],
    iterations: usize,
) -> Result<([f64; 20], [f64; 20], usize), RpcError> {
    use nalgebra::{DMatrix, DVector};
    let mut den = [0.0; 20];
    den[0] = 1.0;
    let mut num = [0.0; 20];
    let mut used = 0;
    for it in 0..iterations {
        used = it + 1;
        let mut n = DMatrix::<f64>::zeros(39, 39);
        let mut b = DVector::<f64>::zeros(39);
        let mut row = [0.0; 39];
        for (tk, rk) in t.iter().zip(r) {
            let d = dot(&den, tk);
            let w = 1.0 / (d * d).max(1e-24);
            row[..20].copy_from_slice(tk);
            for k in 1..20 {
                row[19 + k] = -rk * tk[k];
            }
            for i in 0..39 {
                let wi = w * row[i];
                b[i] += wi * rk;
                for j in i..39 {
                    n[(i, j)] += wi * row[j];
                }
            }
        }
        for i in 0..39 {
            for j in 0..i {
                n[(i, j)] = n[(j, i)];
            }
        }
        let mean = (0..39).map(|i| n[(i, i)]).sum::<f64>() / 39.0;
        for i in 0..39 {
            n[(i, i)] += 1e-12 * mean;
        }
        let x = n
            .cholesky()
            .ok_or_else(|| RpcError::Fit("the normal equations are singular".into()))?
            .solve(&b);
        let mut new_num = [0.0; 20];
        new_num.copy_from_slice(&x.as_slice()[..20]);
        let mut new_den = [0.0; 20];
        new_den[0] = 1.0;
        new_den[1..].copy_from_slice(&x.as_slice()[20..]);
        let change = new_den
            .iter()
            .zip(&den)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        num = new_num;
        den = new_den;
        if change < 1e-12 {
            break;
        }
    }
    Ok((num, den, used))
}

// The other forms RPCs come in (DigitalGlobe .RPB, Airbus DIMAP RPC_*.XML) and the one
// entry point for all of them, `Rpc::read`.
mod dimap;
mod read;
mod rpb;

#[cfg(test)]
mod tests;
