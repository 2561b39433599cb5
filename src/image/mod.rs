//! Images as the core takes them: one channel of grey values as f32, row-major. The hardware
//! side (digitisation, scanning) produces them; the matchers and the least-squares measurement
//! consume them, whoever made them.

pub mod window;

pub use window::{grey_size, load_grey_reduced, load_grey_reduced_with, load_grey_window};

/// A single-channel floating-point image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageF32 {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl ImageF32 {
    pub fn new(width: usize, height: usize) -> Self {
        ImageF32 {
            width,
            height,
            data: vec![0.0; width * height],
        }
    }

    pub fn from_u16(width: usize, height: usize, px: &[u16]) -> Self {
        ImageF32 {
            width,
            height,
            data: px.iter().map(|&v| v as f32).collect(),
        }
    }

    /// Bilinear value at continuous coordinates (pixel c covers [c, c + 1), its centre at
    /// c + 0.5); `None` outside the pixel centres' hull.
    #[inline]
    pub fn bilinear(&self, x: f64, y: f64) -> Option<f32> {
        let cell = self.bilinear_cell(x, y)?;
        Some(self.bilinear_in(cell))
    }

    /// Where [`ImageF32::bilinear`] takes (x, y) from: the first of its four pixels (an index
    /// into `data`) and the fractions across and down; `None` outside the centres' hull. An
    /// image of the same size takes the same cell ([`ImageF32::bilinear_in`]).
    #[inline(always)]
    pub fn bilinear_cell(&self, x: f64, y: f64) -> Option<(usize, f32, f32)> {
        let (u, v) = (x - 0.5, y - 0.5);
        // Written so that NaN and huge coordinates fall outside too.
        let (w1, h1) = (self.width as f64 - 1.0, self.height as f64 - 1.0);
        if u.is_nan() || v.is_nan() || u < 0.0 || v < 0.0 || u > w1 || v > h1 {
            return None;
        }
        if self.width < 2 || self.height < 2 {
            return None;
        }
        // The last centres (u = W − 1) interpolate in the last cell with weight 1.
        let (i, j) = (
            (u as usize).min(self.width - 2),
            (v as usize).min(self.height - 2),
        );
        let (fx, fy) = ((u - i as f64) as f32, (v - j as f64) as f32);
        Some((j * self.width + i, fx, fy))
    }

    /// The bilinear value in a cell of [`ImageF32::bilinear_cell`] (of an image this size).
    #[inline(always)]
    pub fn bilinear_in(&self, (k, fx, fy): (usize, f32, f32)) -> f32 {
        let p = &self.data[k..];
        let q = &self.data[k + self.width..];
        let a = p[0] + fx * (p[1] - p[0]);
        let b = q[0] + fx * (q[1] - q[0]);
        a + fy * (b - a)
    }

    /// The bilinear value and its exact derivatives ∂/∂x, ∂/∂y at (x, y) (those of the
    /// interpolating surface itself, so that a least-squares model sampled with
    /// [`ImageF32::bilinear`] has its true Jacobian); `None` where `bilinear` is.
    pub fn bilinear_with_gradient(&self, x: f64, y: f64) -> Option<[f64; 3]> {
        let v = self.bilinear(x, y)? as f64;
        let (u, w) = (x - 0.5, y - 0.5);
        let i = (u as usize).min(self.width - 2);
        let j = (w as usize).min(self.height - 2);
        let (fx, fy) = (u - i as f64, w - j as f64);
        let p = &self.data[j * self.width + i..];
        let q = &self.data[(j + 1) * self.width + i..];
        let (p0, p1, q0, q1) = (p[0] as f64, p[1] as f64, q[0] as f64, q[1] as f64);
        Some([
            v,
            (1.0 - fy) * (p1 - p0) + fy * (q1 - q0),
            (1.0 - fx) * (q0 - p0) + fx * (q1 - p1),
        ])
    }

    pub fn at(&self, col: usize, row: usize) -> f32 {
        self.data[row * self.width + col]
    }

    pub fn row(&self, row: usize) -> &[f32] {
        &self.data[row * self.width..(row + 1) * self.width]
    }

    /// The image averaged over blocks of `f` × `f` pixels: a pyramid level, whose pixel c
    /// covers [c·f, (c + 1)·f) of this one's, so coordinates scale by `f` exactly (a last
    /// partial block is left out).
    pub fn averaged(&self, f: usize) -> ImageF32 {
        let f = f.max(1);
        let (w, h) = (self.width / f, self.height / f);
        let mut out = ImageF32::new(w, h);
        let norm = 1.0 / (f * f) as f32;
        for r in 0..h {
            for c in 0..w {
                let mut sum = 0.0f32;
                for y in r * f..(r + 1) * f {
                    let row = &self.data[y * self.width + c * f..y * self.width + (c + 1) * f];
                    sum += row.iter().sum::<f32>();
                }
                out.data[r * w + c] = sum * norm;
            }
        }
        out
    }

    /// The part from column `c0`, row `r0`, at most `w` × `h` (clipped to the image).
    pub fn window(&self, c0: usize, r0: usize, w: usize, h: usize) -> ImageF32 {
        let c0 = c0.min(self.width);
        let r0 = r0.min(self.height);
        let w = w.min(self.width - c0);
        let h = h.min(self.height - r0);
        let mut out = ImageF32::new(w, h);
        for r in 0..h {
            out.data[r * w..(r + 1) * w]
                .copy_from_slice(&self.data[(r0 + r) * self.width + c0..][..w]);
        }
        out
    }
}

/// An error about the image at `path`: its name, then what is wrong.
fn invalid(path: &std::path::Path, what: String) -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::InvalidData,
        format!("{}: {what}", path.display()),
    )
}

/// An I/O error with the file named.
fn io_error(path: &std::path::Path, e: std::io::Error) -> std::io::Error {
    std::io::Error::new(e.kind(), format!("{}: {e}", path.display()))
}

/// Whether the file starts with PNG's signature (else it is read as a TIFF).
fn is_png(path: &std::path::Path) -> std::io::Result<bool> {
    use std::io::Read;
    let mut head = [0u8; 8];
    let mut f = std::fs::File::open(path).map_err(|e| io_error(path, e))?;
    let n = f.read(&mut head).map_err(|e| io_error(path, e))?;
    Ok(head[..n].starts_with(b"\x89PNG"))
}

/// A `w × h` image as f32 must exist and fit in `max_bytes`, checked before it is decoded.
fn fits(path: &std::path::Path, w: u64, h: u64, max_bytes: u64) -> std::io::Result<()> {
    if w == 0 || h == 0 || 4 * w * h > max_bytes {
        return Err(invalid(
            path,
            format!(
                "{w} × {h} px needs {} MiB as an image; the limit is {} MiB",
                (4 * w * h) >> 20,
                max_bytes >> 20
            ),
        ));
    }
    Ok(())
}

/// Reads a grey image for the matching core: a one-band TIFF (8/16/32-bit integers, 32/64-bit
/// floats, either byte order — the decoder converts) or a PNG (8/16-bit grey), its grey values
/// unscaled. Colour is refused rather than mixed into grey. Its size is checked against
/// `max_bytes` (as f32) before the pixels are decoded. NaN (no data) is refused: the height
/// sweep's photos have a value everywhere.
pub fn load_grey(path: &std::path::Path, max_bytes: u64) -> std::io::Result<ImageF32> {
    read_grey(path, max_bytes, false)
}

/// [`load_grey`], with NaN in a float TIFF kept as no data when `nodata` (infinite values are
/// refused either way).
fn read_grey(path: &std::path::Path, max_bytes: u64, nodata: bool) -> std::io::Result<ImageF32> {
    let bad = |what: String| invalid(path, what);
    let fits = |w: u64, h: u64| fits(path, w, h, max_bytes);
    if is_png(path)? {
        let bytes = std::fs::read(path).map_err(|e| io_error(path, e))?;
        let r =
            image::ImageReader::with_format(std::io::Cursor::new(&bytes), image::ImageFormat::Png);
        let (w, h) = r
            .into_dimensions()
            .map_err(|e| bad(format!("not a readable PNG ({e})")))?;
        fits(w as u64, h as u64)?;
        let img = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png)
            .map_err(|e| bad(format!("not a readable PNG ({e})")))?;
        let data: Vec<f32> = match img {
            image::DynamicImage::ImageLuma8(g) => g.into_raw().into_iter().map(f32::from).collect(),
            image::DynamicImage::ImageLuma16(g) => {
                g.into_raw().into_iter().map(f32::from).collect()
            }
            other => {
                return Err(bad(format!(
                    "{:?} pixels: a grey image is needed (convert it to grey first)",
                    other.color()
                )))
            }
        };
        return Ok(ImageF32 {
            width: w as usize,
            height: h as usize,
            data,
        });
    }
    let mut d = window::open_tiff(path, max_bytes)?;
    let (w, h) = d.dimensions().map_err(|e| bad(e.to_string()))?;
    fits(w as u64, h as u64)?;
    require_grey(&mut d, path)?;
    let data = samples_f32(d.read_image().map_err(|e| bad(e.to_string()))?, path)?;
    if data.len() != w as usize * h as usize {
        return Err(bad(
            "one band of grey values expected (more bands found)".into()
        ));
    }
    check_values(&data, path, nodata)?;
    Ok(ImageF32 {
        width: w as usize,
        height: h as usize,
        data,
    })
}

/// A one-band grey TIFF, or an error saying what it is instead.
fn require_grey<R: std::io::Read + std::io::Seek>(
    d: &mut tiff::decoder::Decoder<R>,
    path: &std::path::Path,
) -> std::io::Result<()> {
    match d.colortype() {
        Ok(tiff::ColorType::Gray(_)) => Ok(()),
        Ok(c) => Err(invalid(
            path,
            format!("{c:?} pixels: a one-band grey image is needed (convert it to grey first)"),
        )),
        Err(e) => Err(invalid(path, e.to_string())),
    }
}

/// A TIFF's decoded samples as the core's f32 grey values.
fn samples_f32(
    r: tiff::decoder::DecodingResult,
    path: &std::path::Path,
) -> std::io::Result<Vec<f32>> {
    use tiff::decoder::DecodingResult as D;
    Ok(match r {
        D::U8(v) => v.into_iter().map(f32::from).collect(),
        D::U16(v) => v.into_iter().map(f32::from).collect(),
        D::U32(v) => v.into_iter().map(|x| x as f32).collect(),
        D::I8(v) => v.into_iter().map(f32::from).collect(),
        D::I16(v) => v.into_iter().map(f32::from).collect(),
        D::I32(v) => v.into_iter().map(|x| x as f32).collect(),
        D::F32(v) => v,
        D::F64(v) => f64_to_f32(&v, path)?,
        _ => return Err(invalid(path, "a sample type the rig does not read".into())),
    })
}

/// 64-bit floats as f32, refused beyond f32's range (not turned infinite).
fn f64_to_f32(v: &[f64], path: &std::path::Path) -> std::io::Result<Vec<f32>> {
    if v.iter().any(|x| x.is_finite() && x.abs() > f32::MAX as f64) {
        return Err(invalid(
            path,
            format!(
                "grey values beyond ±{:.1e}, the largest the rig computes with (rescale the image)",
                f32::MAX
            ),
        ));
    }
    Ok(v.iter().map(|&x| x as f32).collect())
}

/// No infinite value; NaN only where it is no data (`nodata`).
fn check_values(data: &[f32], path: &std::path::Path, nodata: bool) -> std::io::Result<()> {
    if data.iter().any(|v| v.is_infinite()) {
        return Err(invalid(
            path,
            "infinite grey values: finite values expected (NaN where there is no data)".into(),
        ));
    }
    if !nodata && data.iter().any(|v| v.is_nan()) {
        return Err(invalid(
            path,
            "NaN grey values: this input needs a value at every pixel (fill the gaps first)".into(),
        ));
    }
    Ok(())
}

/// Reads an image for a plain stereo pair: grey as [`load_grey`] reads it; anything else the
/// `image` crate decodes (colour or grey with alpha, 8/16-bit or float samples) turned grey
/// with Rec. 601 weights 0.299 R + 0.587 G + 0.114 B (as OpenCV's cvtColor does), on a 0–255
/// scale, alpha ignored. Multi-page TIFFs: the first page. NaN in a float TIFF is no data
/// (never matched).
pub fn load_luma(path: &std::path::Path, max_bytes: u64) -> std::io::Result<ImageF32> {
    let grey_error = match read_grey(path, max_bytes, true) {
        Ok(img) => return Ok(img),
        Err(e) => e,
    };
    let bad = |what: String| invalid(path, what);
    let open = || -> std::io::Result<_> {
        image::ImageReader::open(path)?
            .with_guessed_format()
            .map_err(|e| bad(e.to_string()))
    };
    let decoded = (|| -> std::io::Result<ImageF32> {
        let (w, h) = open()?
            .into_dimensions()
            .map_err(|e| bad(format!("not a readable image ({e})")))?;
        fits(path, w as u64, h as u64, max_bytes)?;
        let img = open()?
            .decode()
            .map_err(|e| bad(format!("not a readable image ({e})")))?;
        let rgb = img.to_rgb32f();
        let data: Vec<f32> = rgb
            .pixels()
            .map(|p| 255.0 * (0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2]))
            .collect();
        // (A float image's values may be infinite, or overflow in the weighting.)
        if data.iter().any(|v| v.is_infinite()) {
            return Err(bad("infinite grey values (or too large to weight into grey): finite values expected, NaN where there is no data".into()));
        }
        Ok(ImageF32 {
            width: w as usize,
            height: h as usize,
            data,
        })
    })();
    match decoded {
        Ok(img) => Ok(img),
        // A colour image the decoder could not read: its own reason. Else the grey reader's.
        Err(e) if grey_error.to_string().contains("pixels: a") => Err(e),
        Err(_) => Err(grey_error),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On a plane g = 3c + 5r bilinear sampling is exact everywhere in the centres' hull,
    /// including its last row and column; outside, at NaN and on 1-pixel images: nothing.
    #[test]
    fn bilinear_is_exact_on_a_plane_up_to_the_last_centres() {
        let mut img = ImageF32::new(4, 3);
        for r in 0..3 {
            for c in 0..4 {
                img.data[r * 4 + c] = (3 * c + 5 * r) as f32;
            }
        }
        let plane = |x: f64, y: f64| (3.0 * (x - 0.5) + 5.0 * (y - 0.5)) as f32;
        for (x, y) in [(0.5, 0.5), (3.5, 2.5), (3.5, 0.5), (0.5, 2.5), (2.25, 1.75)] {
            assert_eq!(img.bilinear(x, y), Some(plane(x, y)), "({x}, {y})");
        }
        for (x, y) in [
            (3.51, 1.0),
            (0.49, 1.0),
            (1.0, 2.51),
            (f64::NAN, 1.0),
            (1e300, 1.0),
        ] {
            assert_eq!(img.bilinear(x, y), None, "({x}, {y})");
        }
        assert_eq!(ImageF32::new(1, 5).bilinear(0.5, 1.0), None);
    }

    #[test]
    fn grey_tiff_and_png_read_their_values_and_colour_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let px: Vec<u16> = vec![0, 1000, 65535, 7];
        let t = d.path().join("a.tif");
        let raw: Vec<u8> = px.iter().flat_map(|v| v.to_ne_bytes()).collect();
        image::save_buffer(&t, &raw, 2, 2, image::ExtendedColorType::L16).unwrap();
        let img = load_grey(&t, 1 << 20).unwrap();
        assert_eq!((img.width, img.height), (2, 2));
        assert_eq!(img.data, vec![0.0, 1000.0, 65535.0, 7.0]);
        let p = d.path().join("a.png");
        image::save_buffer(&p, &[0u8, 50, 100, 255], 2, 2, image::ExtendedColorType::L8).unwrap();
        assert_eq!(
            load_grey(&p, 1 << 20).unwrap().data,
            vec![0.0, 50.0, 100.0, 255.0]
        );
        let c = d.path().join("c.png");
        image::save_buffer(&c, &[0u8; 12], 2, 2, image::ExtendedColorType::Rgb8).unwrap();
        assert!(load_grey(&c, 1 << 20)
            .unwrap_err()
            .to_string()
            .contains("grey"));
        assert!(load_grey(&t, 8).unwrap_err().to_string().contains("limit"));
    }

    /// A float TIFF's NaN is no data for a plain pair (kept, never matched) and refused where
    /// every pixel needs a value; an infinite value is refused by both, naming the file.
    #[test]
    fn nan_is_no_data_for_a_pair_and_infinity_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let write = |name: &str, px: &[f32]| {
            let path = d.path().join(name);
            let f = std::fs::File::create(&path).unwrap();
            let mut enc = tiff::encoder::TiffEncoder::new(f).unwrap();
            enc.write_image::<tiff::encoder::colortype::Gray32Float>(2, 2, px)
                .unwrap();
            path
        };
        let nan = write("nan.tif", &[1.0, f32::NAN, 3.0, 4.5]);
        let img = load_luma(&nan, 1 << 20).unwrap();
        assert_eq!((img.data[0], img.data[2], img.data[3]), (1.0, 3.0, 4.5));
        assert!(img.data[1].is_nan());
        let e = load_grey(&nan, 1 << 20).unwrap_err().to_string();
        assert!(e.contains("nan.tif") && e.contains("NaN"), "{e}");
        let inf = write("inf.tif", &[1.0, f32::INFINITY, 3.0, 4.5]);
        for e in [load_grey(&inf, 1 << 20), load_luma(&inf, 1 << 20)] {
            let e = e.unwrap_err().to_string();
            assert!(e.contains("inf.tif") && e.contains("infinite"), "{e}");
        }
        // Colour floats go through the colour reader: infinity is refused there too.
        let rgb = d.path().join("rgb.tif");
        let mut enc =
            tiff::encoder::TiffEncoder::new(std::fs::File::create(&rgb).unwrap()).unwrap();
        let px = [
            1.0f32,
            2.0,
            3.0,
            f32::INFINITY,
            0.0,
            0.0,
            1.0,
            1.0,
            1.0,
            0.5,
            0.5,
            0.5,
        ];
        enc.write_image::<tiff::encoder::colortype::RGB32Float>(2, 2, &px)
            .unwrap();
        let e = load_luma(&rgb, 1 << 20).unwrap_err().to_string();
        assert!(e.contains("rgb.tif") && e.contains("infinite"), "{e}");
        // A 64-bit float beyond f32's range is refused as such, not as infinite.
        let big = d.path().join("big.tif");
        let mut enc =
            tiff::encoder::TiffEncoder::new(std::fs::File::create(&big).unwrap()).unwrap();
        enc.write_image::<tiff::encoder::colortype::Gray64Float>(2, 1, &[1.0, 1e300])
            .unwrap();
        let e = load_luma(&big, 1 << 20).unwrap_err().to_string();
        assert!(e.contains("big.tif") && e.contains("beyond"), "{e}");
    }
}
