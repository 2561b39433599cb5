//! Writing digitised images: 16-bit greyscale TIFF, written to a temporary file and renamed, so
//! a crash never leaves half an image under the final name.

use std::path::Path;

/// Writes `px` (row-major, `width × height`) as a 16-bit greyscale TIFF at `path`, atomically.
pub fn write_tiff16(path: &Path, width: usize, height: usize, px: &[u16]) -> std::io::Result<()> {
    write_tiff16_tagged(path, width, height, px, &[])
}

/// [`write_tiff16`] with extra tags of doubles, `(tag, values)` (as the RPCs' tag 50844).
pub fn write_tiff16_tagged(
    path: &Path,
    width: usize,
    height: usize,
    px: &[u16],
    tags: &[(u16, &[f64])],
) -> std::io::Result<()> {
    use tiff::encoder::{colortype, Compression, DeflateLevel, Predictor, TiffEncoder};
    use tiff::tags::Tag;
    let (w, h) = (
        u32::try_from(width).map_err(std::io::Error::other)?,
        u32::try_from(height).map_err(std::io::Error::other)?,
    );
    crate::atomic::write_with(path, |out| {
        // Deflate after horizontal differencing (TIFF predictor 2), lossless: neighbouring
        // pixels differ little, so their differences compress where the raw 16-bit values do
        // not; every TIFF reader (GDAL, libtiff, QGIS) takes it.
        let mut enc = TiffEncoder::new(out)
            .map_err(std::io::Error::other)?
            .with_predictor(Predictor::Horizontal)
            .with_compression(Compression::Deflate(DeflateLevel::Fast));
        let mut image = enc
            .new_image::<colortype::Gray16>(w, h)
            .map_err(std::io::Error::other)?;
        for (tag, values) in tags {
            image
                .encoder()
                .write_tag(Tag::Unknown(*tag), *values)
                .map_err(std::io::Error::other)?;
        }
        image.write_data(px).map_err(std::io::Error::other)
    })
}

/// Reads a 16-bit greyscale TIFF back (for tests and for later stages).
pub fn read_tiff16(path: &Path) -> std::io::Result<(usize, usize, Vec<u16>)> {
    let f = std::fs::File::open(path)
        .map_err(|e| std::io::Error::new(e.kind(), format!("{}: {e}", path.display())))?;
    decode_tiff16(std::io::BufReader::new(f), path)
}

/// [`read_tiff16`] of bytes already read (`path` names them in errors).
pub fn decode_tiff16<R: std::io::Read + std::io::Seek>(
    r: R,
    path: &Path,
) -> std::io::Result<(usize, usize, Vec<u16>)> {
    use tiff::decoder::{Decoder, DecodingResult, Limits};
    let bad = |what: String| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "{}: {what}; the rig reads the 16-bit unsigned greyscale little-endian TIFFs it \
                 writes, and converts nothing silently",
                path.display()
            ),
        )
    };
    let mut limits = Limits::default();
    limits.decoding_buffer_size = MAX_TIFF_BYTES;
    let mut d = Decoder::new(r)
        .map_err(|e| bad(format!("not a readable TIFF ({e})")))?
        .with_limits(limits);
    if d.byte_order() != tiff::tags::ByteOrder::LittleEndian {
        return Err(bad("big-endian (Motorola byte order)".into()));
    }
    match d.colortype() {
        Ok(tiff::ColorType::Gray(16)) => {}
        Ok(c) => return Err(bad(format!("{c:?} pixels"))),
        Err(e) => return Err(bad(format!("unreadable pixel format ({e})"))),
    }
    let (w, h) = d.dimensions().map_err(|e| bad(e.to_string()))?;
    let bytes = 2 * w as u64 * h as u64;
    if w == 0 || h == 0 || bytes > MAX_TIFF_BYTES as u64 {
        return Err(bad(format!(
            "{w} × {h} px ({} MiB; 1 px to {} MiB)",
            bytes >> 20,
            MAX_TIFF_BYTES >> 20
        )));
    }
    match d.read_image().map_err(|e| bad(e.to_string()))? {
        DecodingResult::U16(v) if v.len() == w as usize * h as usize => {
            Ok((w as usize, h as usize, v))
        }
        DecodingResult::U16(_) => Err(bad("pixel count differs from its size".into())),
        _ => Err(bad("signed or floating-point samples".into())),
    }
}

/// Largest TIFF read (bytes of pixels): a 230 mm photo at 7 µm is about 2 GiB.
pub const MAX_TIFF_BYTES: usize = 4 << 30;

/// Reads a 16-bit greyscale TIFF into an image of its counts.
pub fn read_tiff16_f32(path: &Path) -> std::io::Result<crate::digitise::ImageF32> {
    Ok(to_f32(read_tiff16(path)?))
}

/// Counts as grey values.
pub fn to_f32((width, height, px): (usize, usize, Vec<u16>)) -> crate::digitise::ImageF32 {
    crate::digitise::ImageF32 {
        width,
        height,
        data: px.into_iter().map(|v| v as f32).collect(),
    }
}

/// Writes JSON next to an image, atomically.
pub fn write_json(path: &Path, v: &serde_json::Value) -> std::io::Result<()> {
    crate::atomic::write_json(path, v)
}

#[cfg(test)]
mod tests {
    #[test]
    fn tiff_roundtrip() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.tiff");
        let px: Vec<u16> = (0..12).map(|v| v * 5000).collect();
        super::write_tiff16(&p, 4, 3, &px).unwrap();
        assert_eq!(super::read_tiff16(&p).unwrap(), (4, 3, px));
        assert!(!p.with_extension("tiff.part").exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    /// A baseline TIFF of 2 × 1 pixels, written by hand from the TIFF 6.0 specification (an
    /// independent writer): `bits` per sample, `format` (SampleFormat: 1 uint, 2 int, 3 float),
    /// `samples` per pixel, in either byte order.
    fn hand_tiff(big: bool, bits: u16, format: u16, samples: u16, px: &[u8]) -> Vec<u8> {
        let u16b = |v: u16| {
            if big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            }
        };
        let u32b = |v: u32| {
            if big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            }
        };
        let tags: [(u16, u16, u32); 10] = [
            (256, 3, 2),
            (257, 3, 1),
            (258, 3, bits as u32),
            (259, 3, 1),
            (262, 3, if samples == 3 { 2 } else { 1 }),
            (273, 4, 0), // filled below
            (277, 3, samples as u32),
            (278, 3, 1),
            (279, 4, px.len() as u32),
            (339, 3, format as u32),
        ];
        let ifd_len = 2 + 12 * tags.len() + 4;
        let data_at = (8 + ifd_len) as u32;
        let mut b = Vec::new();
        b.extend_from_slice(if big { b"MM" } else { b"II" });
        b.extend_from_slice(&u16b(42));
        b.extend_from_slice(&u32b(8));
        b.extend_from_slice(&u16b(tags.len() as u16));
        for (tag, typ, v) in tags {
            let v = if tag == 273 { data_at } else { v };
            b.extend_from_slice(&u16b(tag));
            b.extend_from_slice(&u16b(typ));
            b.extend_from_slice(&u32b(1));
            if typ == 3 {
                // A SHORT sits in the first two bytes of the value field.
                b.extend_from_slice(&u16b(v as u16));
                b.extend_from_slice(&[0, 0]);
            } else {
                b.extend_from_slice(&u32b(v));
            }
        }
        b.extend_from_slice(&u32b(0));
        b.extend_from_slice(px);
        b
    }

    #[test]
    fn reads_a_hand_written_tiff_and_refuses_what_it_would_have_to_convert() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.tiff");
        let read = |bytes: Vec<u8>| {
            std::fs::write(&p, bytes).unwrap();
            super::read_tiff16(&p)
        };
        // Little-endian 16-bit unsigned: 0x1234 and 0xfffe.
        let ok = read(hand_tiff(false, 16, 1, 1, &[0x34, 0x12, 0xfe, 0xff])).unwrap();
        assert_eq!(ok, (2, 1, vec![0x1234, 0xfffe]));
        let refused = [
            (
                "big-endian",
                hand_tiff(true, 16, 1, 1, &[0x12, 0x34, 0xff, 0xfe]),
            ),
            ("8-bit", hand_tiff(false, 8, 1, 1, &[1, 2])),
            ("RGB", hand_tiff(false, 16, 1, 3, &[0; 12])),
            ("signed", hand_tiff(false, 16, 2, 1, &[0; 4])),
            ("float", hand_tiff(false, 32, 3, 1, &[0; 8])),
            ("not a TIFF", b"P5 2 1 65535 ....".to_vec()),
        ];
        for (what, bytes) in refused {
            let e = read(bytes).expect_err(what).to_string();
            assert!(
                e.contains("t.tiff") && e.contains("16-bit unsigned"),
                "{what}: {e}"
            );
        }
    }

    #[test]
    fn tiffs_are_deflate_compressed_and_read_back_exactly() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("a.tiff");
        // A smooth picture with noise in the lowest bits, as a scan is.
        let (w, h) = (300usize, 200usize);
        let px: Vec<u16> = (0..w * h)
            .map(|i| (20_000 + (i % w) * 50 + (i / w) * 30 + (i * 7919 % 13)) as u16)
            .collect();
        super::write_tiff16(&p, w, h, &px).unwrap();
        assert_eq!(super::read_tiff16(&p).unwrap(), (w, h, px.clone()));
        let mut dec = tiff::decoder::Decoder::new(std::fs::File::open(&p).unwrap()).unwrap();
        let c = dec.get_tag_u32(tiff::tags::Tag::Compression).unwrap();
        assert_eq!(c, 8, "Deflate (Adobe) is compression 8");
        let size = std::fs::metadata(&p).unwrap().len();
        assert!(size < (w * h * 2) as u64 / 2, "{size} bytes");
    }
}
