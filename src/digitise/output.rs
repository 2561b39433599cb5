//! Writing digitised images: 16-bit greyscale TIFF, written to a temporary file and renamed, so
//! a crash never leaves half an image under the final name.

use std::path::Path;

/// Writes `px` (row-major, `width × height`) as a 16-bit greyscale TIFF at `path`, atomically.
pub fn write_tiff16(path: &Path, width: usize, height: usize, px: &[u16]) -> std::io::Result<()> {
    let bytes: Vec<u8> = px.iter().flat_map(|v| v.to_ne_bytes()).collect();
    crate::atomic::write_with(path, |w| {
        image::write_buffer_with_format(
            w,
            &bytes,
            width as u32,
            height as u32,
            image::ExtendedColorType::L16,
            image::ImageFormat::Tiff,
        )
        .map_err(std::io::Error::other)
    })
}

/// Reads a 16-bit greyscale TIFF back (for tests and for later stages).
pub fn read_tiff16(path: &Path) -> std::io::Result<(usize, usize, Vec<u16>)> {
    let img = image::open(path)
        .map_err(|e| std::io::Error::other(format!("reading {}: {e}", path.display())))?;
    let g = img.into_luma16();
    Ok((g.width() as usize, g.height() as usize, g.into_raw()))
}

/// Reads a 16-bit greyscale TIFF into an image of its counts.
pub fn read_tiff16_f32(path: &Path) -> std::io::Result<crate::digitise::ImageF32> {
    let (w, h, px) = read_tiff16(path)?;
    Ok(crate::digitise::ImageF32 {
        width: w,
        height: h,
        data: px.into_iter().map(|v| v as f32).collect(),
    })
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
}
