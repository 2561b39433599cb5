//! What the matching core writes: the elevation model as a float32 GeoTIFF with nodata (what
//! `gdalinfo` and GIS tools read), the matched points as a binary PLY, and PNG pictures for a
//! person — a hillshade of the model and a map of its differences from a reference.

use super::grid::ElevationGrid;
use crate::coords::GroundM;
use crate::geometry::Crs;
use std::io::Write;
use std::path::Path;
use tiff::encoder::{colortype, Compression, DeflateLevel, TiffEncoder};
use tiff::tags::Tag;

/// The value written for nodata nodes (and named in the GDAL_NODATA tag).
pub const NODATA: f32 = -9999.0;

fn other<E: std::fmt::Display>(path: &Path) -> impl Fn(E) -> std::io::Error + '_ {
    move |e| std::io::Error::other(format!("{}: {e}", path.display()))
}

/// Writes `grid` as a Deflate-compressed float32 GeoTIFF: pixel-is-area, the model's tie
/// point at the north-west node's cell corner, square cells, in `crs` (an EPSG projected
/// system, or a user-defined one in metres for `local`). Atomic (temporary file, rename).
pub fn write_geotiff(path: &Path, grid: &ElevationGrid, crs: Crs) -> std::io::Result<()> {
    crate::atomic::write_with(path, |w| {
        let mut enc = TiffEncoder::new(w)
            .map_err(other(path))?
            .with_compression(Compression::Deflate(DeflateLevel::Balanced));
        let mut img = enc
            .new_image::<colortype::Gray32Float>(grid.cols as u32, grid.rows as u32)
            .map_err(other(path))?;
        let e = img.encoder();
        let half = 0.5 * grid.cell_m;
        e.write_tag(
            Tag::ModelPixelScaleTag,
            &[grid.cell_m, grid.cell_m, 0.0][..],
        )
        .map_err(other(path))?;
        e.write_tag(
            Tag::ModelTiepointTag,
            &[0.0, 0.0, 0.0, grid.x0 - half, grid.y0 + half, 0.0][..],
        )
        .map_err(other(path))?;
        // GeoKeyDirectory: version 1.1.0, 4 keys: model type projected (1024 = 1), raster
        // type pixel-is-area (1025 = 1), projected CRS (3072: the EPSG code, or 32767 for
        // user-defined), linear units metre (3076 = 9001).
        let code = match crs {
            Crs::Epsg(c) => c,
            Crs::Local => 32767,
        };
        let keys: [u16; 20] = [
            1, 1, 0, 4, //
            1024, 0, 1, 1, //
            1025, 0, 1, 1, //
            3072, 0, 1, code, //
            3076, 0, 1, 9001,
        ];
        e.write_tag(Tag::GeoKeyDirectoryTag, &keys[..])
            .map_err(other(path))?;
        e.write_tag(Tag::GdalNodata, &*format!("{NODATA}"))
            .map_err(other(path))?;
        let data: Vec<f32> = grid
            .z
            .iter()
            .map(|&v| if v.is_finite() { v } else { NODATA })
            .collect();
        img.write_data(&data).map_err(other(path))
    })
}

/// Reads a single-band GeoTIFF elevation model (8/16/32-bit integers or 32/64-bit floats, as
/// GDAL writes them) into a grid: square cells, a tie point, pixel-is-area or pixel-is-point
/// (GTRasterTypeGeoKey) honoured, the GDAL_NODATA value (and −9999) read as no height.
pub fn read_geotiff(path: &Path) -> std::io::Result<ElevationGrid> {
    use tiff::decoder::DecodingResult as D;
    let f = std::fs::File::open(path)?;
    let mut d = tiff::decoder::Decoder::new(std::io::BufReader::new(f)).map_err(other(path))?;
    let (w, h) = d.dimensions().map_err(other(path))?;
    let scale = d
        .get_tag_f64_vec(Tag::ModelPixelScaleTag)
        .map_err(other(path))?;
    let tie = d
        .get_tag_f64_vec(Tag::ModelTiepointTag)
        .map_err(other(path))?;
    // GeoKeyDirectory: a header of 4 shorts, then (key, location, count, value) per key.
    let keys = d
        .find_tag_unsigned_vec::<u16>(Tag::GeoKeyDirectoryTag)
        .map_err(other(path))?
        .unwrap_or_default();
    let pixel_is_point = keys
        .get(4..)
        .unwrap_or(&[])
        .chunks_exact(4)
        .any(|k| k[0] == 1025 && k[1] == 0 && k[3] == 2);
    let nodata = d
        .find_tag(Tag::GdalNodata)
        .map_err(other(path))?
        .and_then(|v| v.into_string().ok())
        .and_then(|s| s.trim().trim_end_matches('\0').parse::<f64>().ok());
    let z: Vec<f64> = match d.read_image().map_err(other(path))? {
        D::F32(v) => v.into_iter().map(f64::from).collect(),
        D::F64(v) => v,
        D::I16(v) => v.into_iter().map(f64::from).collect(),
        D::U16(v) => v.into_iter().map(f64::from).collect(),
        D::I32(v) => v.into_iter().map(f64::from).collect(),
        D::U32(v) => v.into_iter().map(f64::from).collect(),
        D::U8(v) => v.into_iter().map(f64::from).collect(),
        D::I8(v) => v.into_iter().map(f64::from).collect(),
        _ => {
            return Err(std::io::Error::other(format!(
                "{}: heights must be one band of integers or floats",
                path.display()
            )))
        }
    };
    if z.len() != w as usize * h as usize {
        return Err(std::io::Error::other(format!(
            "{}: one band expected ({} values for {w} × {h} cells)",
            path.display(),
            z.len()
        )));
    }
    if scale.len() < 2
        || tie.len() < 6
        || !(scale[0] > 0.0 && scale[0].is_finite())
        || (scale[0] - scale[1]).abs() > 1e-9 * scale[0]
    {
        return Err(std::io::Error::other(format!(
            "{}: needs square cells and a tie point (ModelPixelScale, ModelTiepoint)",
            path.display()
        )));
    }
    let cell = scale[0];
    // The tie point names raster point (i, j) = (tie[0], tie[1]): a cell's corner when pixel
    // is area, its centre when pixel is point. Node (0, 0) is the first cell's centre.
    let shift = if pixel_is_point { 0.0 } else { 0.5 };
    let x0 = tie[3] + (shift - tie[0]) * cell;
    let y0 = tie[4] - (shift - tie[1]) * cell;
    let missing = |v: f64| !v.is_finite() || v == NODATA as f64 || nodata.is_some_and(|n| v == n);
    Ok(ElevationGrid {
        x0,
        y0,
        cell_m: cell,
        cols: w as usize,
        rows: h as usize,
        z: z.into_iter()
            .map(|v| if missing(v) { f32::NAN } else { v as f32 })
            .collect(),
    })
}

/// Binary little-endian PLY of points (x, y, z as doubles, then the matching correlation).
pub fn write_ply(path: &Path, pts: &[(GroundM, f32)]) -> std::io::Result<()> {
    crate::atomic::write_with(path, |w| {
        write!(
            w,
            "ply\nformat binary_little_endian 1.0\ncomment rig matched points, ground metres\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nproperty float quality\nend_header\n",
            pts.len()
        )?;
        for (p, q) in pts {
            w.write_all(&p.x.to_le_bytes())?;
            w.write_all(&p.y.to_le_bytes())?;
            w.write_all(&p.z.to_le_bytes())?;
            w.write_all(&q.to_le_bytes())?;
        }
        Ok(())
    })
}

fn save_rgb(path: &Path, w: usize, h: usize, rgb: Vec<u8>) -> std::io::Result<()> {
    crate::atomic::write_with(path, |f| {
        image::write_buffer_with_format(
            f,
            &rgb,
            w as u32,
            h as u32,
            image::ExtendedColorType::Rgb8,
            image::ImageFormat::Png,
        )
        .map_err(other(path))
    })
}

/// Hillshade (sun from the north-west, 45° up) of the grid; nodata in pale blue.
pub fn write_hillshade(path: &Path, g: &ElevationGrid) -> std::io::Result<()> {
    let at = |c: i64, r: i64| -> Option<f64> {
        if c < 0 || r < 0 || c >= g.cols as i64 || r >= g.rows as i64 {
            return None;
        }
        let v = g.z[r as usize * g.cols + c as usize];
        v.is_finite().then_some(v as f64)
    };
    let s = [-0.5f64, 0.5, std::f64::consts::FRAC_1_SQRT_2];
    let mut rgb = Vec::with_capacity(g.cols * g.rows * 3);
    for r in 0..g.rows as i64 {
        for c in 0..g.cols as i64 {
            let v = match (at(c - 1, r), at(c + 1, r), at(c, r - 1), at(c, r + 1)) {
                (Some(w), Some(e), Some(n), Some(so)) => {
                    let gx = (e - w) / (2.0 * g.cell_m);
                    let gy = (n - so) / (2.0 * g.cell_m);
                    let l = (-gx * s[0] - gy * s[1] + s[2]) / (gx * gx + gy * gy + 1.0).sqrt();
                    let k = (40.0 + 215.0 * l.clamp(0.0, 1.0)) as u8;
                    [k, k, k]
                }
                _ => [200, 215, 235],
            };
            rgb.extend_from_slice(&v);
        }
    }
    save_rgb(path, g.cols, g.rows, rgb)
}

/// The differences (model − reference) in colour: blue below, red above, white near zero,
/// full colour at ±`span_m`; grey where there is no height.
pub fn write_error_map(
    path: &Path,
    g: &ElevationGrid,
    diff: &[f32],
    span_m: f64,
) -> std::io::Result<()> {
    let mut rgb = Vec::with_capacity(g.cols * g.rows * 3);
    for &d in diff {
        let v = if d.is_finite() {
            let t = (d as f64 / span_m).clamp(-1.0, 1.0);
            let k = (255.0 * (1.0 - t.abs())) as u8;
            if t >= 0.0 {
                [255, k, k]
            } else {
                [k, k, 255]
            }
        } else {
            [150, 150, 150]
        };
        rgb.extend_from_slice(&v);
    }
    save_rgb(path, g.cols, g.rows, rgb)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn geotiff_round_trip_keeps_heights_nodata_and_georeference() {
        let d = tempfile::tempdir().unwrap();
        let mut g = ElevationGrid::covering([1000.0, 2000.0, 1040.0, 2030.0], 2.0, 64).unwrap();
        g.z = (0..g.z.len())
            .map(|i| {
                if i % 7 == 3 {
                    f32::NAN
                } else {
                    300.0 + i as f32 * 0.25
                }
            })
            .collect();
        let p = d.path().join("dem.tif");
        write_geotiff(&p, &g, Crs::Local).unwrap();
        let back = read_geotiff(&p).unwrap();
        assert_eq!((back.cols, back.rows), (g.cols, g.rows));
        assert_eq!((back.x0, back.y0, back.cell_m), (g.x0, g.y0, g.cell_m));
        for (a, b) in g.z.iter().zip(&back.z) {
            assert!(a == b || (a.is_nan() && b.is_nan()));
        }
    }
}
