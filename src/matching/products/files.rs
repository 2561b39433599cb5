//! What the matching core writes: the elevation model as a float32 GeoTIFF with nodata (what
//! `gdalinfo` and GIS tools read), the matched points as a binary PLY, and PNG pictures for a
//! person — a hillshade of the model and a map of its differences from a reference.

use crate::geometry::Crs;
use crate::matching::grid::{ElevationGrid, NodeQuality};
use crate::matching::MatchedPoint;
use std::io::Write;
use std::path::Path;
use tiff::encoder::{colortype, Compression, DeflateLevel, TiffEncoder};
use tiff::tags::{PhotometricInterpretation, SampleFormat, Tag};

/// The value written for nodata nodes (and named in the GDAL_NODATA tag).
pub const NODATA: f32 = -9999.0;

pub(crate) fn other<E: std::fmt::Display>(path: &Path) -> impl Fn(E) -> std::io::Error + '_ {
    move |e| std::io::Error::other(format!("{}: {e}", path.display()))
}

/// Two float32 bands per pixel (GDAL's layout for a multi-band raster: minimum-is-black, the
/// second sample "unspecified" extra).
struct TwoBands32Float;
impl colortype::ColorType for TwoBands32Float {
    type Inner = f32;
    const TIFF_VALUE: PhotometricInterpretation = PhotometricInterpretation::BlackIsZero;
    const BITS_PER_SAMPLE: &'static [u16] = &[32, 32];
    const SAMPLE_FORMAT: &'static [SampleFormat] = &[SampleFormat::IEEEFP, SampleFormat::IEEEFP];
    fn horizontal_predict(row: &[f32], result: &mut Vec<f32>) {
        // Only called with a predictor, which is never set here: samples unchanged.
        result.extend_from_slice(row);
    }
}

/// Writes `data` (row-major, `bands.len()` samples per node, NaN = nodata) on `grid`'s nodes
/// as a Deflate-compressed float32 GeoTIFF: pixel-is-area, the tie point at the north-west
/// node's cell corner, square cells, in `crs` (an EPSG projected system, or a user-defined one
/// in metres for `local`), each band's description in GDAL's metadata. Atomic.
fn write_raster(
    path: &Path,
    grid: &ElevationGrid,
    crs: Crs,
    data: &[f32],
    bands: &[&str],
) -> std::io::Result<()> {
    if data.len() != grid.cols * grid.rows * bands.len() || !(1..=2).contains(&bands.len()) {
        return Err(std::io::Error::other(format!(
            "{}: {} values for {} × {} nodes and {} bands",
            path.display(),
            data.len(),
            grid.cols,
            grid.rows,
            bands.len()
        )));
    }
    let data: Vec<f32> = data
        .iter()
        .map(|&v| if v.is_finite() { v } else { NODATA })
        .collect();
    crate::atomic::write_with(path, |w| {
        let mut enc = TiffEncoder::new(w)
            .map_err(other(path))?
            .with_compression(Compression::Deflate(DeflateLevel::Balanced));
        let (cols, rows) = (grid.cols as u32, grid.rows as u32);
        let tags = |e: &mut tiff::encoder::DirectoryEncoder<'_, _, _>| -> std::io::Result<()> {
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
            write_band_descriptions(e, bands).map_err(other(path))
        };
        if bands.len() == 1 {
            let mut img = enc
                .new_image::<colortype::Gray32Float>(cols, rows)
                .map_err(other(path))?;
            tags(img.encoder())?;
            img.write_data(&data).map_err(other(path))
        } else {
            let mut img = enc
                .new_image::<TwoBands32Float>(cols, rows)
                .map_err(other(path))?;
            tags(img.encoder())?;
            img.encoder()
                .write_tag(Tag::ExtraSamples, &[0u16][..])
                .map_err(other(path))?;
            img.write_data(&data).map_err(other(path))
        }
    })
}

/// GDAL's TIFF tag for its XML metadata (band descriptions).
const GDAL_METADATA: u16 = 42112;

/// Each band's description (`gdalinfo` shows it) as GDAL's XML metadata tag.
pub(crate) fn write_band_descriptions<
    W: std::io::Write + std::io::Seek,
    K: tiff::encoder::TiffKind,
>(
    e: &mut tiff::encoder::DirectoryEncoder<'_, W, K>,
    bands: &[&str],
) -> tiff::TiffResult<()> {
    let mut meta = String::from("<GDALMetadata>");
    for (i, b) in bands.iter().enumerate() {
        meta +=
            &format!("<Item name=\"DESCRIPTION\" sample=\"{i}\" role=\"description\">{b}</Item>");
    }
    meta += "</GDALMetadata>";
    e.write_tag(Tag::Unknown(GDAL_METADATA), &*meta)
}

/// Writes the elevation model: one float32 band of heights, m.
pub fn write_geotiff(path: &Path, grid: &ElevationGrid, crs: Crs) -> std::io::Result<()> {
    write_raster(path, grid, crs, &grid.z, &["height (m)"])
}

/// Writes the model's quality on its grid: band 1 the standard deviation of each node's height
/// (m), band 2 the correlation of its matches.
pub fn write_quality(
    path: &Path,
    grid: &ElevationGrid,
    crs: Crs,
    quality: &NodeQuality,
) -> std::io::Result<()> {
    let data: Vec<f32> = quality
        .sigma_m
        .iter()
        .zip(&quality.corr)
        .flat_map(|(&s, &c)| [s, c])
        .collect();
    write_raster(
        path,
        grid,
        crs,
        &data,
        &["height standard deviation (m)", "correlation"],
    )
}

/// Writes an orthophoto on the model's grid: one float32 band of grey values.
pub fn write_ortho(
    path: &Path,
    grid: &ElevationGrid,
    crs: Crs,
    grey: &[f32],
) -> std::io::Result<()> {
    write_raster(path, grid, crs, grey, &["grey value"])
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

/// Binary little-endian PLY of the matched points: x, y, z (doubles, m, in `crs`, named in a
/// header comment), the correlation and the height's standard deviation (m).
pub fn write_ply(path: &Path, pts: &[MatchedPoint], crs: Crs) -> std::io::Result<()> {
    crate::atomic::write_with(path, |w| {
        write!(
            w,
            "ply\nformat binary_little_endian 1.0\ncomment rig matched points, ground metres\ncomment crs {crs}\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nproperty float quality\nproperty float sigma_z\nend_header\n",
            pts.len()
        )?;
        for p in pts {
            w.write_all(&p.ground.x.to_le_bytes())?;
            w.write_all(&p.ground.y.to_le_bytes())?;
            w.write_all(&p.ground.z.to_le_bytes())?;
            w.write_all(&p.corr.to_le_bytes())?;
            w.write_all(&p.sigma_m.to_le_bytes())?;
        }
        Ok(())
    })
}

/// The matched points as LAS 1.2, point format 0, millimetre resolution, with the CRS as the
/// GeoTIFF keys of a LASF_Projection record (34735) as the LAS specification has it for these
/// point formats (`local`: no record); intensity = correlation × 65535 (negative as 0).
pub fn write_las(path: &Path, pts: &[MatchedPoint], crs: Crs) -> std::io::Result<()> {
    let las_err = |e: las::Error| std::io::Error::other(format!("{}: {e}", path.display()));
    let mut b = las::Builder::from((1, 2));
    b.generating_software = "rig".into();
    let finite = |p: &&MatchedPoint| {
        p.ground.x.is_finite() && p.ground.y.is_finite() && p.ground.z.is_finite()
    };
    // The offsets near the data's lowest corner (of the finite points only).
    let first = pts
        .iter()
        .filter(finite)
        .fold(None, |m: Option<[f64; 3]>, p| {
            let g = [p.ground.x, p.ground.y, p.ground.z];
            Some(m.map_or(g, |m| [m[0].min(g[0]), m[1].min(g[1]), m[2].min(g[2])]))
        });
    let first = first.unwrap_or([0.0; 3]);
    // Offsets at whole kilometres near the data: coordinates as i32 millimetres stay in range.
    let t = |o: f64| las::Transform {
        scale: 0.001,
        offset: (o / 1000.0).round() * 1000.0,
    };
    b.transforms = las::Vector {
        x: t(first[0]),
        y: t(first[1]),
        z: t(first[2]),
    };
    if let Crs::Epsg(code) = crs {
        // Version 1.1.0, 3 keys: projected model (1024 = 1), pixel-is-area (1025 = 1),
        // the projected CRS (3072 = code); little-endian shorts as the record holds them.
        let keys: [u16; 16] = [1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, code];
        b.vlrs.push(las::Vlr {
            user_id: "LASF_Projection".into(),
            record_id: 34735,
            description: "GeoKeyDirectoryTag".into(),
            data: keys.iter().flat_map(|k| k.to_le_bytes()).collect(),
        });
    }
    let header = b.into_header().map_err(las_err)?;
    let mut w = las::Writer::new(std::io::Cursor::new(Vec::new()), header).map_err(las_err)?;
    for p in pts.iter().filter(finite) {
        let out_of_range = [p.ground.x, p.ground.y, p.ground.z]
            .iter()
            .zip([first[0], first[1], first[2]])
            .any(|(v, o)| (v - o).abs() > 2.0e6);
        if out_of_range {
            // Not representable at a millimetre from the offset (±2 147 km): left out.
            continue;
        }
        w.write_point(las::Point {
            x: p.ground.x,
            y: p.ground.y,
            z: p.ground.z,
            intensity: (p.corr.clamp(0.0, 1.0) * 65535.0) as u16,
            // One return per point, as validators expect of points without returns.
            return_number: 1,
            number_of_returns: 1,
            ..Default::default()
        })
        .map_err(las_err)?;
    }
    let bytes = w.into_inner().map_err(las_err)?.into_inner();
    crate::atomic::write(path, &bytes)
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
