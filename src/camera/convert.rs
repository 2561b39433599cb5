//! V4L2 pixel formats to 16-bit greyscale. Separate from the device code (and always built) so
//! that it is tested on recorded buffers without a camera.

/// What a pixel format gives the rig.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Grey {
    /// Usable for measurement, with this many significant bits.
    Bits(u32),
    /// Not usable: why.
    Refused(&'static str),
}

/// Whether a FourCC can be measured with, and at what depth.
pub fn classify(fourcc: &[u8; 4]) -> Grey {
    match fourcc {
        b"GREY" => Grey::Bits(8),
        b"Y10 " => Grey::Bits(10),
        b"Y12 " => Grey::Bits(12),
        b"Y16 " => Grey::Bits(16),
        b"YUYV" => Grey::Bits(8),
        b"MJPG" | b"JPEG" => {
            Grey::Refused("lossy JPEG compression moves edges and adds block artefacts")
        }
        b"H264" | b"HEVC" | b"VP80" | b"VP90" => Grey::Refused("lossy video compression"),
        _ => Grey::Refused(
            "not a greyscale format the rig reads (GREY, Y10, Y12, Y16 or the luma of YUYV)",
        ),
    }
}

/// How much a format is preferred for measurement (higher is better).
pub fn preference(fourcc: &[u8; 4]) -> u32 {
    match fourcc {
        b"Y16 " => 5,
        b"Y12 " => 4,
        b"Y10 " => 3,
        b"GREY" => 2,
        b"YUYV" => 1,
        _ => 0,
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ConvertError {
    #[error("pixel format {0} cannot be used for measurement: {1}")]
    Refused(String, &'static str),
    #[error("buffer of {got} bytes is too short for {width}×{height} {fourcc} with a stride of {stride} bytes")]
    Short {
        got: usize,
        width: usize,
        height: usize,
        stride: usize,
        fourcc: String,
    },
}

/// Converts one buffer (rows `stride` bytes apart) to greyscale. Returns the pixels (the
/// format's own bit depth, not rescaled) and that depth.
pub fn to_grey16(
    fourcc: &[u8; 4],
    width: usize,
    height: usize,
    stride: usize,
    data: &[u8],
) -> Result<(Vec<u16>, u32), ConvertError> {
    let name = String::from_utf8_lossy(fourcc).trim().to_string();
    let bits = match classify(fourcc) {
        Grey::Bits(b) => b,
        Grey::Refused(why) => return Err(ConvertError::Refused(name, why)),
    };
    let bpp = match fourcc {
        b"GREY" => 1,
        b"YUYV" => 2,
        _ => 2,
    };
    let row_bytes = width * bpp;
    if stride < row_bytes || data.len() < stride * (height.max(1) - 1) + row_bytes {
        return Err(ConvertError::Short {
            got: data.len(),
            width,
            height,
            stride,
            fourcc: name,
        });
    }
    let mut out = Vec::with_capacity(width * height);
    for r in 0..height {
        let row = &data[r * stride..r * stride + row_bytes];
        match fourcc {
            b"GREY" => out.extend(row.iter().map(|&v| v as u16)),
            // Luma sits in bytes 0 and 2 of each Y0 U Y1 V macropixel.
            b"YUYV" => out.extend(row.chunks_exact(2).map(|p| p[0] as u16)),
            // Little-endian 16-bit words, the significant bits low.
            _ => {
                let mask = if bits == 16 {
                    0xFFFF
                } else {
                    (1u16 << bits) - 1
                };
                out.extend(
                    row.chunks_exact(2)
                        .map(|p| u16::from_le_bytes([p[0], p[1]]) & mask),
                )
            }
        }
    }
    Ok((out, bits))
}

#[cfg(test)]
mod tests {
    use super::*;

    // Buffers as drivers hand them over, rows padded to the stride.

    #[test]
    fn grey_with_padding() {
        let buf = [1u8, 2, 3, 0xEE, 4, 5, 6, 0xEE];
        assert_eq!(
            to_grey16(b"GREY", 3, 2, 4, &buf).unwrap(),
            (vec![1, 2, 3, 4, 5, 6], 8)
        );
    }

    #[test]
    fn yuyv_takes_the_luma() {
        // Y0 U Y1 V for two 2-pixel rows.
        let buf = [10u8, 128, 20, 128, 30, 99, 40, 77];
        assert_eq!(
            to_grey16(b"YUYV", 2, 2, 4, &buf).unwrap(),
            (vec![10, 20, 30, 40], 8)
        );
    }

    #[test]
    fn y10_y12_y16_little_endian() {
        let buf = [0xFF, 0x03, 0x00, 0x02, 0xFF, 0xFF];
        assert_eq!(
            to_grey16(b"Y10 ", 3, 1, 6, &buf).unwrap(),
            (vec![1023, 512, 1023], 10)
        );
        assert_eq!(
            to_grey16(b"Y12 ", 3, 1, 6, &buf).unwrap(),
            (vec![1023, 512, 4095], 12)
        );
        assert_eq!(
            to_grey16(b"Y16 ", 3, 1, 6, &buf).unwrap(),
            (vec![1023, 512, 65535], 16)
        );
    }

    #[test]
    fn lossy_and_unknown_formats_are_refused_with_a_reason() {
        assert!(
            matches!(to_grey16(b"MJPG", 2, 2, 4, &[0; 16]), Err(ConvertError::Refused(f, why)) if f == "MJPG" && why.contains("lossy"))
        );
        assert!(matches!(classify(b"RGB3"), Grey::Refused(_)));
        assert!(
            preference(b"Y16 ") > preference(b"GREY") && preference(b"GREY") > preference(b"YUYV")
        );
    }

    #[test]
    fn short_buffers_are_errors_not_panics() {
        assert!(matches!(
            to_grey16(b"GREY", 4, 4, 4, &[0; 15]),
            Err(ConvertError::Short { .. })
        ));
        assert!(matches!(
            to_grey16(b"Y16 ", 4, 1, 6, &[0; 8]),
            Err(ConvertError::Short { .. })
        ));
    }
}
