//! Part of an image too large to hold: a full satellite scene is 40 000 × 40 000 px (3.2 GB at
//! 16 bits, 6.4 GB as f32), while a DEM of a square kilometre needs a few thousand pixels of
//! it. A TIFF is stored in strips or tiles (TIFF 6.0, sections 3 and 15); only those that meet
//! the window are decoded. A strip too large to decode whole (one strip for the whole image is
//! common) is read row by row when it is uncompressed. A PNG has no such access: it is read
//! whole and cut.

use super::{
    check_values, f64_to_f32, fits, invalid, io_error, is_png, require_grey, samples_f32, ImageF32,
};
use crate::coords::PixelWindow;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;
use tiff::decoder::{ChunkType, Decoder, Limits};
use tiff::tags::{ByteOrder, Tag};

/// A strip or tile larger than this (decoded) is not decoded whole to take a window from.
pub const MAX_CHUNK_BYTES: u64 = 64 << 20;

/// Width and height of a grey image, from its header alone (no pixel is read).
pub fn grey_size(path: &Path) -> std::io::Result<(usize, usize)> {
    if is_png(path)? {
        let (w, h) = image::ImageReader::open(path)
            .map_err(|e| io_error(path, e))?
            .with_guessed_format()
            .map_err(|e| io_error(path, e))?
            .into_dimensions()
            .map_err(|e| invalid(path, format!("not a readable PNG ({e})")))?;
        return Ok((w as usize, h as usize));
    }
    let mut d = open_tiff(path, MAX_CHUNK_BYTES)?;
    let (w, h) = d.dimensions().map_err(|e| invalid(path, e.to_string()))?;
    Ok((w as usize, h as usize))
}

/// A TIFF decoder on the file (not a copy of it in memory), decoding at most `2 × max_bytes`
/// at once.
pub(super) fn open_tiff(
    path: &Path,
    max_bytes: u64,
) -> std::io::Result<Decoder<BufReader<std::fs::File>>> {
    let file = std::fs::File::open(path).map_err(|e| io_error(path, e))?;
    let mut limits = Limits::default();
    limits.decoding_buffer_size = usize::try_from(2 * max_bytes).unwrap_or(usize::MAX);
    Ok(Decoder::new(BufReader::new(file))
        .map_err(|e| invalid(path, format!("neither a PNG nor a readable TIFF ({e})")))?
        .with_limits(limits))
}

/// The pixels of `win` of the grey image at `path` (as [`super::load_grey`] reads them: one
/// band, NaN refused), reading no more of a TIFF than the strips or tiles that meet it. The
/// window must lie within the image; its size is checked against `max_bytes` (as f32).
pub fn load_grey_window(
    path: &Path,
    win: PixelWindow,
    max_bytes: u64,
) -> std::io::Result<ImageF32> {
    fits(path, win.width as u64, win.height as u64, max_bytes)?;
    if is_png(path)? {
        let whole = super::load_grey(path, max_bytes)?;
        check_within(path, win, whole.width, whole.height)?;
        return Ok(whole.window(win.col0, win.row0, win.width, win.height));
    }
    let bad = |what: String| invalid(path, what);
    let mut d = open_tiff(path, MAX_CHUNK_BYTES)?;
    let (w, h) = d.dimensions().map_err(|e| bad(e.to_string()))?;
    let (w, h) = (w as usize, h as usize);
    check_within(path, win, w, h)?;
    require_grey(&mut d, path)?;
    let bits = d
        .find_tag_unsigned::<u16>(Tag::BitsPerSample)
        .map_err(|e| bad(e.to_string()))?
        .unwrap_or(1) as u64;
    let (cw, ch) = d.chunk_dimensions();
    let (cw, ch) = (cw as usize, ch as usize);
    let chunk_bytes = cw as u64 * ch as u64 * bits.div_ceil(8);
    if chunk_bytes > MAX_CHUNK_BYTES {
        return rows_of_uncompressed_strips(&mut d, path, win, (w, h), bits as usize);
    }
    let across = match d.get_chunk_type() {
        ChunkType::Strip => 1,
        ChunkType::Tile => w.div_ceil(cw),
    };
    let mut out = ImageF32::new(win.width, win.height);
    for ty in win.row0 / ch..=(win.row0 + win.height - 1) / ch {
        for tx in win.col0 / cw..=(win.col0 + win.width - 1) / cw {
            let index = (ty * across + tx) as u32;
            let (dw, dh) = d.chunk_data_dimensions(index);
            let (dw, dh) = (dw as usize, dh as usize);
            let chunk = samples_f32(
                d.read_chunk(index)
                    .map_err(|e| bad(format!("its strip or tile {index} cannot be read: {e}")))?,
                path,
            )?;
            if chunk.len() != dw * dh {
                return Err(bad(
                    "one band of grey values expected (more bands found)".into()
                ));
            }
            // The chunk's pixels within the window.
            let (x0, y0) = (tx * cw, ty * ch);
            let c_from = win.col0.max(x0);
            let c_to = (win.col0 + win.width).min(x0 + dw);
            let r_from = win.row0.max(y0);
            let r_to = (win.row0 + win.height).min(y0 + dh);
            for r in r_from..r_to {
                let src = &chunk[(r - y0) * dw + (c_from - x0)..][..c_to - c_from];
                let at = (r - win.row0) * win.width + (c_from - win.col0);
                out.data[at..at + src.len()].copy_from_slice(src);
            }
        }
    }
    check_values(&out.data, path, false)?;
    Ok(out)
}

fn check_within(path: &Path, win: PixelWindow, w: usize, h: usize) -> std::io::Result<()> {
    if win.width == 0 || win.height == 0 || win.col0 + win.width > w || win.row0 + win.height > h {
        return Err(invalid(
            path,
            format!(
                "the window of columns {} … {} and rows {} … {} is not within its {w} × {h} px",
                win.col0,
                win.col0 + win.width,
                win.row0,
                win.row0 + win.height
            ),
        ));
    }
    Ok(())
}

/// The window's rows straight from the file: an uncompressed, one-band image in strips too
/// large to decode whole. Each row of the window is one contiguous run of bytes.
fn rows_of_uncompressed_strips(
    d: &mut Decoder<BufReader<std::fs::File>>,
    path: &Path,
    win: PixelWindow,
    (w, h): (usize, usize),
    bits: usize,
) -> std::io::Result<ImageF32> {
    let bad = |what: String| invalid(path, what);
    let tag = |d: &mut Decoder<BufReader<std::fs::File>>, t: Tag| {
        d.find_tag_unsigned::<u64>(t)
            .map_err(|e| bad(e.to_string()))
    };
    let compression = tag(d, Tag::Compression)?.unwrap_or(1);
    let tiled = matches!(d.get_chunk_type(), ChunkType::Tile);
    if compression != 1 || tiled {
        return Err(bad(format!(
            "its {} are too large to take a window from (over {} MiB each, decoded{}): write it with smaller tiles, e.g. gdal_translate -co TILED=YES -co BLOCKXSIZE=512 -co BLOCKYSIZE=512",
            if tiled { "tiles" } else { "strips" },
            MAX_CHUNK_BYTES >> 20,
            if compression != 1 { ", and compressed" } else { "" }
        )));
    }
    let format = tag(d, Tag::SampleFormat)?.unwrap_or(1);
    let rows_per_strip = tag(d, Tag::RowsPerStrip)?.unwrap_or(h as u64).max(1) as usize;
    let offsets = d
        .get_tag_u64_vec(Tag::StripOffsets)
        .map_err(|e| bad(format!("its StripOffsets: {e}")))?;
    if offsets.len() < h.div_ceil(rows_per_strip) {
        return Err(bad(format!(
            "{} strip offsets for {h} rows of {rows_per_strip}: the file is damaged",
            offsets.len()
        )));
    }
    let bytes = bits / 8;
    let little = d.byte_order() == ByteOrder::LittleEndian;
    if !matches!((bits, format), (8 | 16 | 32, 1 | 2) | (32 | 64, 3)) {
        return Err(bad(format!(
            "{bits}-bit samples of SampleFormat {format}: the rig reads 8/16/32-bit integers and 32/64-bit floats"
        )));
    }
    let file = d.inner();
    let mut raw = vec![0u8; win.width * bytes];
    let mut out = ImageF32::new(win.width, win.height);
    for r in 0..win.height {
        let row = win.row0 + r;
        let strip = row / rows_per_strip;
        let at = offsets[strip] + (((row - strip * rows_per_strip) * w + win.col0) * bytes) as u64;
        file.seek(SeekFrom::Start(at))
            .and_then(|_| file.read_exact(&mut raw))
            .map_err(|e| bad(format!("row {row} cannot be read: {e}")))?;
        let dst = &mut out.data[r * win.width..(r + 1) * win.width];
        decode_row(&raw, bits, format, little, dst, path)?;
    }
    check_values(&out.data, path, false)?;
    Ok(out)
}

/// One row of raw samples (`bits` wide, TIFF SampleFormat `format`) as f32.
fn decode_row(
    raw: &[u8],
    bits: usize,
    format: u64,
    little: bool,
    dst: &mut [f32],
    path: &Path,
) -> std::io::Result<()> {
    macro_rules! each {
        ($t:ty, $n:expr) => {
            for (v, b) in dst.iter_mut().zip(raw.chunks_exact($n)) {
                let a: [u8; $n] = b.try_into().expect("chunks_exact");
                *v = if little {
                    <$t>::from_le_bytes(a)
                } else {
                    <$t>::from_be_bytes(a)
                } as f32;
            }
        };
    }
    match (bits, format) {
        (8, 1) => each!(u8, 1),
        (8, 2) => each!(i8, 1),
        (16, 1) => each!(u16, 2),
        (16, 2) => each!(i16, 2),
        (32, 1) => each!(u32, 4),
        (32, 2) => each!(i32, 4),
        (32, 3) => each!(f32, 4),
        _ => {
            let v: Vec<f64> = raw
                .chunks_exact(8)
                .map(|b| {
                    let a: [u8; 8] = b.try_into().expect("chunks_exact");
                    if little {
                        f64::from_le_bytes(a)
                    } else {
                        f64::from_be_bytes(a)
                    }
                })
                .collect();
            dst.copy_from_slice(&f64_to_f32(&v, path)?);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use tiff::encoder::{colortype, Compression, DeflateLevel, TiffEncoder};

    fn pattern(w: usize, h: usize) -> Vec<u16> {
        (0..w * h)
            .map(|i| ((i % w) * 7 + (i / w) * 131) as u16)
            .collect()
    }

    /// Every window of a striped, a tiled (edge tiles padded), a one-strip and a compressed
    /// image equals the same window cut from the whole image.
    #[test]
    fn a_window_is_the_same_pixels_as_the_whole_image_cut() {
        let d = tempfile::tempdir().unwrap();
        let (w, h) = (300usize, 217usize);
        let px = pattern(w, h);
        let mut files = Vec::new();
        // Strips of 16 rows, Deflate.
        let p = d.path().join("strips.tif");
        let mut enc = TiffEncoder::new(std::fs::File::create(&p).unwrap())
            .unwrap()
            .with_compression(Compression::Deflate(DeflateLevel::Balanced));
        let mut img = enc
            .new_image::<colortype::Gray16>(w as u32, h as u32)
            .unwrap();
        img.rows_per_strip(16).unwrap();
        img.write_data(&px).unwrap();
        files.push(p);
        // Uncompressed, one strip.
        let p = d.path().join("one.tif");
        let mut enc = TiffEncoder::new(std::fs::File::create(&p).unwrap()).unwrap();
        let mut img = enc
            .new_image::<colortype::Gray16>(w as u32, h as u32)
            .unwrap();
        img.rows_per_strip(h as u32).unwrap();
        img.write_data(&px).unwrap();
        files.push(p);
        // Tiles of 64 × 64 written by hand (the encoder writes strips only).
        let p = d.path().join("tiles.tif");
        write_tiled(&p, w, h, 64, &px);
        files.push(p);
        let whole = ImageF32::from_u16(w, h, &px);
        for f in &files {
            assert_eq!(grey_size(f).unwrap(), (w, h), "{}", f.display());
            for win in [
                PixelWindow::whole(w, h),
                PixelWindow {
                    col0: 63,
                    row0: 15,
                    width: 70,
                    height: 40,
                },
                PixelWindow {
                    col0: 250,
                    row0: 200,
                    width: 50,
                    height: 17,
                },
                PixelWindow {
                    col0: 0,
                    row0: 100,
                    width: 1,
                    height: 1,
                },
            ] {
                let got = load_grey_window(f, win, 1 << 30).unwrap();
                let want = whole.window(win.col0, win.row0, win.width, win.height);
                assert_eq!(got, want, "{} {win:?}", f.display());
            }
        }
        // The row-by-row reader of a strip too large to decode whole, on the one-strip file.
        let mut dec = open_tiff(&files[1], 1 << 30).unwrap();
        let win = PixelWindow {
            col0: 17,
            row0: 33,
            width: 101,
            height: 9,
        };
        let rows = rows_of_uncompressed_strips(&mut dec, &files[1], win, (w, h), 16).unwrap();
        assert_eq!(rows, whole.window(17, 33, 101, 9));
        // And it refuses the compressed one, saying what to do.
        let mut dec = open_tiff(&files[0], 1 << 30).unwrap();
        let e = rows_of_uncompressed_strips(&mut dec, &files[0], win, (w, h), 16)
            .unwrap_err()
            .to_string();
        assert!(e.contains("strips.tif") && e.contains("TILED=YES"), "{e}");
        // A window beyond the image is refused with the image's size.
        let e = load_grey_window(
            &files[2],
            PixelWindow {
                col0: 290,
                row0: 0,
                width: 20,
                height: 5,
            },
            1 << 30,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("300 × 217"), "{e}");
    }

    /// A little-endian, uncompressed, 16-bit grey TIFF in `tile × tile` tiles (TIFF 6.0 §15:
    /// TileWidth 322, TileLength 323, TileOffsets 324, TileByteCounts 325; edge tiles padded).
    pub(crate) fn write_tiled(path: &Path, w: usize, h: usize, tile: usize, px: &[u16]) {
        let (across, down) = (w.div_ceil(tile), h.div_ceil(tile));
        let n = across * down;
        let tile_bytes = tile * tile * 2;
        let entries: Vec<(u16, u16, u32, u32)> = vec![
            (256, 4, 1, w as u32),
            (257, 4, 1, h as u32),
            (258, 3, 1, 16),
            (259, 3, 1, 1),
            (262, 3, 1, 1),
            (277, 3, 1, 1),
            (322, 3, 1, tile as u32),
            (323, 3, 1, tile as u32),
            (324, 4, n as u32, 0),
            (325, 4, n as u32, 0),
        ];
        let ifd_at = 8u32;
        let ifd_len = 2 + 12 * entries.len() + 4;
        let offsets_at = ifd_at as usize + ifd_len;
        let counts_at = offsets_at + 4 * n;
        let data_at = counts_at + 4 * n;
        let mut f = Vec::new();
        f.extend_from_slice(b"II*\0");
        f.extend_from_slice(&ifd_at.to_le_bytes());
        f.extend_from_slice(&(entries.len() as u16).to_le_bytes());
        for (tag, ty, count, value) in entries {
            f.extend_from_slice(&tag.to_le_bytes());
            f.extend_from_slice(&ty.to_le_bytes());
            f.extend_from_slice(&count.to_le_bytes());
            let v = match tag {
                324 => offsets_at as u32,
                325 => counts_at as u32,
                _ => value,
            };
            if ty == 3 && count == 1 {
                f.extend_from_slice(&(v as u16).to_le_bytes());
                f.extend_from_slice(&[0, 0]);
            } else {
                f.extend_from_slice(&v.to_le_bytes());
            }
        }
        f.extend_from_slice(&0u32.to_le_bytes());
        for k in 0..n {
            f.extend_from_slice(&((data_at + k * tile_bytes) as u32).to_le_bytes());
        }
        for _ in 0..n {
            f.extend_from_slice(&(tile_bytes as u32).to_le_bytes());
        }
        for ty in 0..down {
            for tx in 0..across {
                for r in 0..tile {
                    for c in 0..tile {
                        let (x, y) = (tx * tile + c, ty * tile + r);
                        let v = if x < w && y < h { px[y * w + x] } else { 0 };
                        f.extend_from_slice(&v.to_le_bytes());
                    }
                }
            }
        }
        std::fs::write(path, f).unwrap();
    }
}
