//! Rational polynomial coefficients (RPC00B), the simulator's own: real satellite products'
//! RPCs read from GDAL's `_RPC.TXT`, evaluated, inverted at a height, and cut to a crop as
//! crop tools cut them.
//!
//! The model is NITF's RPC00B (STDI-0002, appendix E; the keys as GDAL's RPC metadata
//! documentation names them): with the ground normalised as L = (lon − LONG_OFF)/LONG_SCALE,
//! P = (lat − LAT_OFF)/LAT_SCALE, H = (h − HEIGHT_OFF)/HEIGHT_SCALE (WGS 84 degrees and
//! ellipsoidal metres), sample = SAMP_OFF + SAMP_SCALE·(SAMP_NUM·t)/(SAMP_DEN·t) and line =
//! LINE_OFF + LINE_SCALE·(LINE_NUM·t)/(LINE_DEN·t), t the 20 terms in RPC00B's order ([`terms`]).
//! (0, 0) is the centre of the image's first pixel (GDAL's pixel/line put 0 at its corner:
//! GDAL's = these + 0.5). Written again here, not taken from the host, whose RPC code this is
//! the truth for.

use std::path::{Path, PathBuf};

/// The TIFF tag GDAL keeps RPCs in (`RPCCoefficientTag`, 50844): 92 doubles, the layout of
/// [`Rpc00b::tag_values`].
pub const TIFF_TAG: u16 = 50844;

/// The 20 terms in RPC00B's order: 1, L, P, H, LP, LH, PH, L², P², H², PLH, L³, LP², LH², L²P,
/// P³, PH², L²H, P²H, H³ (STDI-0002 appendix E; RPC00A orders them otherwise).
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

/// ∂t/∂L and ∂t/∂P of [`terms`], term by term.
fn term_derivatives(l: f64, p: f64, h: f64) -> ([f64; 20], [f64; 20]) {
    let dl = [
        0.0,
        1.0,
        0.0,
        0.0,
        p,
        h,
        0.0,
        2.0 * l,
        0.0,
        0.0,
        p * h,
        3.0 * l * l,
        p * p,
        h * h,
        2.0 * l * p,
        0.0,
        0.0,
        2.0 * l * h,
        0.0,
        0.0,
    ];
    let dp = [
        0.0,
        0.0,
        1.0,
        0.0,
        l,
        0.0,
        h,
        0.0,
        2.0 * p,
        0.0,
        l * h,
        0.0,
        2.0 * l * p,
        0.0,
        l * l,
        3.0 * p * p,
        h * h,
        0.0,
        2.0 * p * h,
        0.0,
    ];
    (dl, dp)
}

fn dot(a: &[f64; 20], b: &[f64; 20]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// One image's RPC00B model.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Rpc00b {
    /// The model's stated errors, m (−1: not given).
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

/// Why an RPC file cannot be taken.
#[derive(Debug, thiserror::Error)]
pub enum RpcError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: {source}", path.display())]
    InFile {
        path: PathBuf,
        source: Box<RpcError>,
    },
    #[error("line {line}: `{text}` is not `KEY: value` (GDAL's _RPC.TXT; GDAL writes one for any RPCs it reads: gdal_translate -co RPCTXT=YES)")]
    Syntax { line: usize, text: String },
    #[error("line {line}: {key} `{value}` is not a finite number")]
    Number {
        line: usize,
        key: String,
        value: String,
    },
    #[error("line {line}: {key} is given twice")]
    Twice { line: usize, key: String },
    #[error("{key} is missing (GDAL's _RPC.TXT names all 10 offsets and scales and the 80 coefficients LINE_NUM_COEFF_1 … SAMP_DEN_COEFF_20)")]
    Missing { key: String },
    #[error("{key} = {value}: {why}")]
    Range {
        key: &'static str,
        value: f64,
        why: &'static str,
    },
}

/// The offsets and scales in GDAL's order, with what each may be.
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
const POLYS: [&str; 4] = [
    "LINE_NUM_COEFF",
    "LINE_DEN_COEFF",
    "SAMP_NUM_COEFF",
    "SAMP_DEN_COEFF",
];

impl Rpc00b {
    /// GDAL's `_RPC.TXT` (the form `gdal_translate -co RPCTXT=YES` writes and GDAL reads):
    /// one `KEY: value` a line, a unit after the value allowed (GeoEye's files), the
    /// coefficients as `LINE_NUM_COEFF_1` … `_20`; ERR_BIAS and ERR_RAND optional (−1: not
    /// given, as GDAL writes them into the TIFF tag); other keys ignored, as GDAL does.
    pub fn parse_gdal_txt(text: &str) -> Result<Rpc00b, RpcError> {
        let mut found: std::collections::HashMap<String, f64> = Default::default();
        for (n, raw) in text.lines().enumerate() {
            let line = raw.trim().trim_start_matches('\u{feff}');
            if line.is_empty() {
                continue;
            }
            let Some((k, v)) = line.split_once(':') else {
                return Err(RpcError::Syntax {
                    line: n + 1,
                    text: line.into(),
                });
            };
            let key = k.trim().to_ascii_uppercase();
            let known = SCALARS.contains(&key.as_str())
                || POLYS
                    .iter()
                    .any(|p| key.strip_prefix(p).is_some_and(|s| s.starts_with('_')));
            if !known {
                continue;
            }
            let word = v.split_whitespace().next().unwrap_or("");
            let x: f64 = word
                .parse()
                .ok()
                .filter(|x: &f64| x.is_finite())
                .ok_or_else(|| RpcError::Number {
                    line: n + 1,
                    key: key.clone(),
                    value: word.into(),
                })?;
            if found.insert(key.clone(), x).is_some() {
                return Err(RpcError::Twice { line: n + 1, key });
            }
        }
        let get = |key: &str| {
            found.get(key).copied().ok_or_else(|| RpcError::Missing {
                key: key.to_string(),
            })
        };
        let poly = |name: &str| -> Result<[f64; 20], RpcError> {
            let mut c = [0.0; 20];
            for (k, v) in c.iter_mut().enumerate() {
                *v = get(&format!("{name}_{}", k + 1))?;
            }
            Ok(c)
        };
        let r = Rpc00b {
            err_bias: found.get("ERR_BIAS").copied().unwrap_or(-1.0),
            err_rand: found.get("ERR_RAND").copied().unwrap_or(-1.0),
            line_off: get("LINE_OFF")?,
            samp_off: get("SAMP_OFF")?,
            lat_off: get("LAT_OFF")?,
            long_off: get("LONG_OFF")?,
            height_off: get("HEIGHT_OFF")?,
            line_scale: get("LINE_SCALE")?,
            samp_scale: get("SAMP_SCALE")?,
            lat_scale: get("LAT_SCALE")?,
            long_scale: get("LONG_SCALE")?,
            height_scale: get("HEIGHT_SCALE")?,
            line_num: poly("LINE_NUM_COEFF")?,
            line_den: poly("LINE_DEN_COEFF")?,
            samp_num: poly("SAMP_NUM_COEFF")?,
            samp_den: poly("SAMP_DEN_COEFF")?,
        };
        r.check()?;
        Ok(r)
    }

    /// [`Rpc00b::parse_gdal_txt`] of a file, its path in every error.
    pub fn load(path: &Path) -> Result<Rpc00b, RpcError> {
        let text = std::fs::read_to_string(path).map_err(|source| RpcError::Io {
            path: path.into(),
            source,
        })?;
        Rpc00b::parse_gdal_txt(&text).map_err(|e| RpcError::InFile {
            path: path.into(),
            source: Box::new(e),
        })
    }

    /// The ranges RPC00B gives its fields: scales positive, latitudes within ±90°,
    /// longitudes within ±180°, and the denominators' constant terms not zero (the model is
    /// undefined at its own centre otherwise).
    fn check(&self) -> Result<(), RpcError> {
        let range = |key, value: f64, ok: bool, why| {
            if ok {
                Ok(())
            } else {
                Err(RpcError::Range { key, value, why })
            }
        };
        for (key, v) in [
            ("LINE_SCALE", self.line_scale),
            ("SAMP_SCALE", self.samp_scale),
            ("LAT_SCALE", self.lat_scale),
            ("LONG_SCALE", self.long_scale),
            ("HEIGHT_SCALE", self.height_scale),
        ] {
            range(key, v, v > 0.0, "a scale must be above 0")?;
        }
        range(
            "LAT_OFF",
            self.lat_off,
            self.lat_off.abs() <= 90.0,
            "a latitude must lie within ±90°",
        )?;
        range(
            "LONG_OFF",
            self.long_off,
            self.long_off.abs() <= 180.0,
            "a longitude must lie within ±180°",
        )?;
        range(
            "LINE_DEN_COEFF_1",
            self.line_den[0],
            self.line_den[0] != 0.0,
            "the denominator must not vanish at the model's centre",
        )?;
        range(
            "SAMP_DEN_COEFF_1",
            self.samp_den[0],
            self.samp_den[0] != 0.0,
            "the denominator must not vanish at the model's centre",
        )
    }

    /// Normalised ground (L, P, H) of a longitude, latitude (degrees) and height (m).
    fn normalise(&self, lon: f64, lat: f64, h: f64) -> [f64; 3] {
        [
            (lon - self.long_off) / self.long_scale,
            (lat - self.lat_off) / self.lat_scale,
            (h - self.height_off) / self.height_scale,
        ]
    }

    /// (sample, line) of a ground point: longitude, latitude (degrees), ellipsoidal height
    /// (m). (0, 0) at the centre of the first pixel. Longitudes are taken as given, not
    /// wrapped at ±180° (no product here straddles the antimeridian).
    pub fn project(&self, lon: f64, lat: f64, h: f64) -> [f64; 2] {
        let [l, p, hh] = self.normalise(lon, lat, h);
        let t = terms(l, p, hh);
        [
            self.samp_off + self.samp_scale * dot(&self.samp_num, &t) / dot(&self.samp_den, &t),
            self.line_off + self.line_scale * dot(&self.line_num, &t) / dot(&self.line_den, &t),
        ]
    }

    /// The longitude and latitude (degrees) that [`Rpc00b::project`] sends to (sample, line)
    /// at height `h`: Newton's method on the normalised (L, P) with the analytic Jacobian of
    /// the two ratios, from `guess` (or the model's centre). It stops when the image residual
    /// is below 1e-9 px or what floating point resolves of the longitude and latitude there
    /// (twice their unit in the last place, in pixels), or when a step no longer shrinks after
    /// the first few; `None` when it ends more than 1e-6 px off or the Jacobian is singular.
    pub fn locate(
        &self,
        samp: f64,
        line: f64,
        h: f64,
        guess: Option<[f64; 2]>,
    ) -> Option<[f64; 2]> {
        let hh = (h - self.height_off) / self.height_scale;
        let [mut l, mut p] = match guess {
            Some([lon, lat]) => {
                let [l, p, _] = self.normalise(lon, lat, h);
                [l, p]
            }
            None => [0.0, 0.0],
        };
        let u = (samp - self.samp_off) / self.samp_scale;
        let v = (line - self.line_off) / self.line_scale;
        // What floating point resolves: a few units in the last place of the longitude and
        // latitude, in pixels (at 0.5 m pixels and 31° E, one unit of a longitude in degrees
        // is about 6e-10 px).
        let tol_px = {
            let [lon, lat] = [
                self.long_off + l * self.long_scale,
                self.lat_off + p * self.lat_scale,
            ];
            let res = f64::EPSILON
                * (lon.abs().max(1.0) / self.long_scale * self.samp_scale
                    + lat.abs().max(1.0) / self.lat_scale * self.line_scale);
            (2.0 * res).max(1e-9)
        };
        let mut last_step = f64::INFINITY;
        let mut best = (f64::INFINITY, [l, p]);
        for it in 0..40 {
            let t = terms(l, p, hh);
            let (sn, sd) = (dot(&self.samp_num, &t), dot(&self.samp_den, &t));
            let (ln, ld) = (dot(&self.line_num, &t), dot(&self.line_den, &t));
            let (ru, rv) = (sn / sd - u, ln / ld - v);
            let err_px = (ru * self.samp_scale).hypot(rv * self.line_scale);
            if err_px < best.0 {
                best = (err_px, [l, p]);
            }
            if err_px < tol_px {
                break;
            }
            let (tl, tp) = term_derivatives(l, p, hh);
            // ∂(N/D)/∂x = (N'·D − N·D')/D².
            let q = |n: f64, d: f64, c_n: &[f64; 20], c_d: &[f64; 20], dt: &[f64; 20]| {
                (dot(c_n, dt) * d - n * dot(c_d, dt)) / (d * d)
            };
            let (ul, up) = (
                q(sn, sd, &self.samp_num, &self.samp_den, &tl),
                q(sn, sd, &self.samp_num, &self.samp_den, &tp),
            );
            let (vl, vp) = (
                q(ln, ld, &self.line_num, &self.line_den, &tl),
                q(ln, ld, &self.line_num, &self.line_den, &tp),
            );
            let det = ul * vp - up * vl;
            if !(det.is_finite() && det != 0.0) {
                break;
            }
            let dl = (ru * vp - rv * up) / det;
            let dp = (rv * ul - ru * vl) / det;
            let step = dl.hypot(dp);
            if !step.is_finite() || (it >= 3 && step >= last_step) {
                break;
            }
            last_step = step;
            l -= dl;
            p -= dp;
        }
        let (err, [l, p]) = best;
        (err < 1e-6).then_some([
            self.long_off + l * self.long_scale,
            self.lat_off + p * self.lat_scale,
        ])
    }

    /// The RPCs of the crop whose first pixel is the product's (c0, r0), as crop tools
    /// write them: the product's offsets and scales kept and the shift folded into the
    /// numerators, SAMP_NUM′ₖ = SAMP_NUMₖ − (c0/SAMP_SCALE)·SAMP_DENₖ and LINE_NUM′ₖ =
    /// LINE_NUMₖ − (r0/LINE_SCALE)·LINE_DENₖ for all 20 k, so that
    /// sample′ = SAMP_OFF + SAMP_SCALE·(N/D − c0/SAMP_SCALE) = sample − c0.
    pub fn cropped(&self, c0: f64, r0: f64) -> Rpc00b {
        let mut r = self.clone();
        for k in 0..20 {
            r.samp_num[k] -= c0 / self.samp_scale * self.samp_den[k];
            r.line_num[k] -= r0 / self.line_scale * self.line_den[k];
        }
        r
    }

    /// The 92 doubles of the TIFF tag [`TIFF_TAG`] as GDAL lays them out (its GeoTIFF RPC
    /// tag, after the RPC00B fields): ERR_BIAS, ERR_RAND, LINE_OFF, SAMP_OFF, LAT_OFF,
    /// LONG_OFF, HEIGHT_OFF, LINE_SCALE, SAMP_SCALE, LAT_SCALE, LONG_SCALE, HEIGHT_SCALE, then
    /// the 20 LINE_NUM, LINE_DEN, SAMP_NUM and SAMP_DEN coefficients.
    pub fn tag_values(&self) -> Vec<f64> {
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
        for c in [
            &self.line_num,
            &self.line_den,
            &self.samp_num,
            &self.samp_den,
        ] {
            v.extend_from_slice(c);
        }
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The real Pléiades 1B RPCs of tests/data/rpc (Gizeh), as GDAL wrote them.
    pub(crate) fn gizeh(n: u32) -> Rpc00b {
        let p = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(format!("../tests/data/rpc/gizeh_img{n}_RPC.TXT"));
        Rpc00b::load(&p).unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn gdal_s_file_is_read_as_written() {
        let r = gizeh(1);
        assert_eq!((r.line_off, r.samp_off), (6821.5, 19999.5));
        assert_eq!((r.lat_off, r.long_off), (29.9735013834584, 31.127735952368));
        assert_eq!((r.height_off, r.height_scale), (140.0, 130.0));
        assert_eq!(r.line_num[2], -1.61293523407497);
        assert_eq!(r.samp_den[19], 1.38339863192309e-09);
        assert_eq!((r.err_bias, r.err_rand), (0.0, 0.0));
        let v = r.tag_values();
        assert_eq!(v.len(), 92);
        assert_eq!(
            (v[2], v[11], v[12 + 2], v[91]),
            (6821.5, 130.0, -1.61293523407497, r.samp_den[19])
        );
    }

    /// The points `gdaltransform -rpc` gives for ground points through the real RPCs
    /// (GDAL 3.6; its pixel/line less 0.5 here): the evaluation and the term order agree.
    #[test]
    fn evaluation_agrees_with_gdal() {
        // gdaltransform -rpc -i on a product-sized image with gizeh_img2_RPC.TXT beside it.
        let r = gizeh(2);
        for (lon, lat, h, px, ln) in [
            (
                31.127735952368,
                29.9735013834584,
                140.0,
                19889.9760565971,
                7292.27830069671,
            ),
            (
                31.127735952368,
                29.9735013834584,
                240.0,
                19828.4358113949,
                7311.42448404949,
            ),
            (31.2, 29.95, 60.0, 33242.251968112, 9646.6814490896),
        ] {
            let [s, l] = r.project(lon, lat, h);
            assert!(
                (s + 0.5 - px).abs() < 1e-7 && (l + 0.5 - ln).abs() < 1e-7,
                "({lon}, {lat}, {h}): {s} {l}"
            );
        }
    }

    /// Image → ground at a height → image comes back to 1e-8 px over the whole product,
    /// at the bottom, middle and top of the model's heights, from the model's centre.
    #[test]
    fn locate_inverts_project() {
        for n in 1..=3 {
            let r = gizeh(n);
            for &fs in &[-0.95, -0.4, 0.0, 0.3, 0.97] {
                for &fl in &[-0.9, 0.0, 0.5, 0.95] {
                    for &fh in &[-0.9, 0.0, 0.9] {
                        let s = r.samp_off + fs * r.samp_scale;
                        let l = r.line_off + fl * r.line_scale;
                        let h = r.height_off + fh * r.height_scale;
                        let [lon, lat] = r.locate(s, l, h, None).expect("converges");
                        let [s2, l2] = r.project(lon, lat, h);
                        assert!(
                            (s2 - s).abs() < 1e-8 && (l2 - l).abs() < 1e-8,
                            "view {n}: ({s}, {l}, {h}) → ({lon}, {lat}) → ({s2}, {l2})"
                        );
                    }
                }
            }
        }
    }

    /// A crop's RPCs give the product's pixel less the crop's corner, everywhere and at
    /// every height, while keeping the product's offsets and scales.
    #[test]
    fn a_crop_s_rpcs_give_the_product_s_pixel_less_its_corner() {
        let r = gizeh(3);
        let (c0, r0) = (19637.0, 6863.0);
        let c = r.cropped(c0, r0);
        assert_eq!((c.samp_off, c.line_off), (r.samp_off, r.line_off));
        assert_eq!((c.samp_scale, c.line_scale), (r.samp_scale, r.line_scale));
        assert_eq!((c.samp_den, c.line_den), (r.samp_den, r.line_den));
        for k in 0..50 {
            let lon = r.long_off + r.long_scale * (0.9 * ((k as f64 * 0.37).sin()));
            let lat = r.lat_off + r.lat_scale * (0.9 * ((k as f64 * 0.61).cos()));
            let h = r.height_off + r.height_scale * (0.8 * ((k as f64 * 0.13).sin()));
            let [s, l] = r.project(lon, lat, h);
            let [sc, lc] = c.project(lon, lat, h);
            assert!(
                (sc - (s - c0)).abs() < 1e-8 && (lc - (l - r0)).abs() < 1e-8,
                "{k}: product ({s}, {l}), crop ({sc}, {lc})"
            );
        }
    }

    #[test]
    fn bad_files_are_refused_with_the_key_and_line() {
        let good = std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data/rpc/gizeh_img1_RPC.TXT"),
        )
        .unwrap();
        let err = |t: &str| Rpc00b::parse_gdal_txt(t).unwrap_err().to_string();
        assert!(
            err(&good.replace("LINE_SCALE: 6821.5", "LINE_SCALE: 0")).contains("LINE_SCALE = 0")
        );
        assert!(
            err(&good.replace("LAT_OFF: 29.9735013834584", "LAT_OFF: nan"))
                .contains("line 5: LAT_OFF `nan`")
        );
        assert!(
            err(&good.replace("SAMP_DEN_COEFF_20: 1.38339863192309e-09\n", ""))
                .contains("SAMP_DEN_COEFF_20 is missing")
        );
        assert!(err(&format!("{good}LINE_OFF: 3\n")).contains("LINE_OFF is given twice"));
        assert!(err(&good.replace("HEIGHT_OFF: 140", "HEIGHT_OFF 140")).contains("line 7"));
        // Units after the numbers are GDAL's too.
        let units = good.replace("LINE_OFF: 6821.5", "LINE_OFF: +006821.50 pixels");
        assert_eq!(Rpc00b::parse_gdal_txt(&units).unwrap().line_off, 6821.5);
        let e = Rpc00b::load(Path::new("/nonexistent_RPC.TXT"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("/nonexistent_RPC.TXT: "), "{e}");
    }
}
