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
    load_grey_reduced(path, win, 1, max_bytes)
}

/// [`load_grey_window`] averaged over blocks of `factor` × `factor` pixels as it is read
/// ([`ImageF32::averaged`]'s level: its pixel c covers the window's [c·f, (c + 1)·f), a last
/// partial block left out). A TIFF is streamed a row of strips or tiles at a time, so memory
/// holds the level and one such row, never the window at full size: a 19 000² film scan
/// read at a 16th of its size takes 5.6 MiB and a few strips. `max_bytes` bounds both.
pub fn load_grey_reduced(
    path: &Path,
    win: PixelWindow,
    factor: usize,
    max_bytes: u64,
) -> std::io::Result<ImageF32> {
    load_grey_reduced_with(path, win, factor, max_bytes, &|_| {})
}

/// [`load_grey_reduced`], calling `pixels_read(n)` as each `n` pixels of the window are read
/// (a 19 000² scan takes seconds: the caller's progress).
pub fn load_grey_reduced_with(
    path: &Path,
    win: PixelWindow,
    factor: usize,
    max_bytes: u64,
    pixels_read: &dyn Fn(u64),
) -> std::io::Result<ImageF32> {
    let f = factor.max(1);
    let (ow, oh) = (win.width / f, win.height / f);
    if ow == 0 || oh == 0 {
        return Err(invalid(
            path,
            format!(
                "its window of {} × {} px has no whole block of {f} × {f} px to average",
                win.width, win.height
            ),
        ));
    }
    fits(path, ow as u64, oh as u64, max_bytes)?;
    if is_png(path)? {
        // A PNG has no strips: it is read whole (within the limit) and cut.
        let whole = super::load_grey(path, max_bytes)?;
        check_within(path, win, whole.width, whole.height)?;
        let part = whole.window(win.col0, win.row0, win.width, win.height);
        return Ok(if f == 1 { part } else { part.averaged(f) });
    }
    let mut out = ImageF32::new(ow, oh);
    // Sums of the level's row in progress, f64 so that 4 096 16-bit values add exactly.
    let mut acc = vec![0.0f64; ow];
    let norm = 1.0 / (f * f) as f64;
    let used = (ow * f, oh * f);
    each_row(
        path,
        win,
        max_bytes.saturating_sub(4 * (ow * oh) as u64),
        |r, row| {
            if r % 256 == 255 {
                pixels_read(256 * win.width as u64);
            }
            if r >= used.1 {
                return;
            }
            if f == 1 {
                out.data[r * ow..(r + 1) * ow].copy_from_slice(row);
                return;
            }
            for (a, block) in acc.iter_mut().zip(row[..used.0].chunks_exact(f)) {
                *a += block.iter().map(|&v| v as f64).sum::<f64>();
            }
            if (r + 1) % f == 0 {
                let dst = &mut out.data[(r / f) * ow..(r / f + 1) * ow];
                for (d, a) in dst.iter_mut().zip(acc.iter_mut()) {
                    *d = (*a * norm) as f32;
                    *a = 0.0;
                }
            }
        },
    )?;
    pixels_read((win.height % 256) as u64 * win.width as u64);
    check_values(&out.data, path, false)?;
    Ok(out)
}

/// Calls `sink` with each row of `win` of the TIFF at `path`, top to bottom (its index within
/// the window and its grey values), decoding one row of strips or tiles at a time; the rows
/// of such a row are gathered in a buffer of at most `max_bytes`.
fn each_row(
    path: &Path,
    win: PixelWindow,
    max_bytes: u64,
    mut sink: impl FnMut(usize, &[f32]),
) -> std::io::Result<()> {
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
        return rows_of_uncompressed_strips(&mut d, path, win, (w, h), bits as usize, sink);
    }
    let across = match d.get_chunk_type() {
        ChunkType::Strip => 1,
        ChunkType::Tile => w.div_ceil(cw),
    };
    // One row of chunks within the window.
    let band_bytes = 4 * (ch as u64) * (win.width as u64);
    if band_bytes > max_bytes {
        return Err(bad(format!(
            "a row of its {} ({ch} rows × {} columns) needs {} MiB as it is read; the limit is {} MiB",
            if across == 1 { "strips" } else { "tiles" },
            win.width,
            band_bytes >> 20,
            max_bytes >> 20
        )));
    }
    let mut band = vec![0.0f32; ch * win.width];
    for ty in win.row0 / ch..=(win.row0 + win.height - 1) / ch {
        let y0 = ty * ch;
        let r_from = win.row0.max(y0);
        let mut r_to = r_from;
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
            let x0 = tx * cw;
            let c_from = win.col0.max(x0);
            let c_to = (win.col0 + win.width).min(x0 + dw);
            r_to = (win.row0 + win.height).min(y0 + dh);
            for r in r_from..r_to {
                let src = &chunk[(r - y0) * dw + (c_from - x0)..][..c_to - c_from];
                let at = (r - r_from) * win.width + (c_from - win.col0);
                band[at..at + src.len()].copy_from_slice(src);
            }
        }
        for r in r_from..r_to {
            let k = r - r_from;
            sink(r - win.row0, &band[k * win.width..(k + 1) * win.width]);
        }
    }
    Ok(())
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

/// The window's rows straight from the file, each handed to `sink`: an uncompressed, one-band image in strips too
/// large to decode whole. Each row of the window is one contiguous run of bytes.
fn rows_of_uncompressed_strips(
    d: &mut Decoder<BufReader<std::fs::File>>,
    path: &Path,
    win: PixelWindow,
    (w, h): (usize, usize),
    bits: usize,
    mut sink: impl FnMut(usize, &[f32]),
) -> std::io::Result<()> {
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
    let mut row_values = vec![0.0f32; win.width];
    for r in 0..win.height {
        let row = win.row0 + r;
        let strip = row / rows_per_strip;
        let at = offsets[strip] + (((row - strip * rows_per_strip) * w + win.col0) * bytes) as u64;
        file.seek(SeekFrom::Start(at))
            .and_then(|_| file.read_exact(&mut raw))
            .map_err(|e| bad(format!("row {row} cannot be read: {e}")))?;
        decode_row(&raw, bits, format, little, &mut row_values, path)?;
        sink(r, &row_values);
    }
    Ok(())
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
                // Read at a level 2, 4, 8 times smaller: the window cut, then averaged in
                // blocks (the level's values are means of integers, exact in f32 here).
                for factor in [2usize, 4, 8] {
                    if win.width < factor || win.height < factor {
                        continue;
                    }
                    let got = load_grey_reduced(f, win, factor, 1 << 30).unwrap();
                    let want = want.averaged(factor);
                    assert_eq!((got.width, got.height), (want.width, want.height));
                    for (a, b) in got.data.iter().zip(&want.data) {
                        assert!(
                            (a - b).abs() <= 1e-3 * b.abs().max(1.0),
                            "{} {win:?} ×{factor}: {a} vs {b}",
                            f.display()
                        );
                    }
                }
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
        let mut rows = ImageF32::new(win.width, win.height);
        rows_of_uncompressed_strips(&mut dec, &files[1], win, (w, h), 16, |r, v| {
            rows.data[r * win.width..(r + 1) * win.width].copy_from_slice(v)
        })
        .unwrap();
        assert_eq!(rows, whole.window(17, 33, 101, 9));
        // And it refuses the compressed one, saying what to do.
        let mut dec = open_tiff(&files[0], 1 << 30).unwrap();
        let e = rows_of_uncompressed_strips(&mut dec, &files[0], win, (w, h), 16, |_, _| {})
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
