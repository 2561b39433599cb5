//! Consistent Overhead Byte Stuffing (Cheshire & Baker, 1999): removes every zero from a
//! block so that zero can delimit frames.

/// Encodes `src` into `dst` (without the trailing delimiter). Returns the encoded length, or
/// `None` if `dst` is too small (it needs `src.len() + src.len() / 254 + 1` bytes).
pub fn cobs_encode(src: &[u8], dst: &mut [u8]) -> Option<usize> {
    let mut code_idx = 0;
    let mut out = 1;
    let mut code: u8 = 1;
    if dst.is_empty() {
        return None;
    }
    for &b in src {
        if b == 0 {
            dst[code_idx] = code;
            code_idx = out;
            *dst.get_mut(out)? = 0;
            out += 1;
            code = 1;
        } else {
            *dst.get_mut(out)? = b;
            out += 1;
            code += 1;
            if code == 0xFF {
                dst[code_idx] = code;
                code_idx = out;
                *dst.get_mut(out)? = 0;
                out += 1;
                code = 1;
            }
        }
    }
    dst[code_idx] = code;
    Some(out)
}

/// Decodes one COBS block (without its delimiter) into `dst`. Returns the decoded length, or
/// `None` if the block is malformed (a zero inside it, a code running past its end) or `dst`
/// is too small.
pub fn cobs_decode(src: &[u8], dst: &mut [u8]) -> Option<usize> {
    let mut i = 0;
    let mut out = 0;
    while i < src.len() {
        let code = src[i] as usize;
        if code == 0 || i + code > src.len() {
            return None;
        }
        for &b in &src[i + 1..i + code] {
            if b == 0 {
                return None;
            }
            *dst.get_mut(out)? = b;
            out += 1;
        }
        i += code;
        if code < 0xFF && i < src.len() {
            *dst.get_mut(out)? = 0;
            out += 1;
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_vectors() {
        // Vectors from the COBS paper's examples.
        let cases: &[(&[u8], &[u8])] = &[
            (&[0x00], &[0x01, 0x01]),
            (&[0x00, 0x00], &[0x01, 0x01, 0x01]),
            (&[0x11, 0x22, 0x00, 0x33], &[0x03, 0x11, 0x22, 0x02, 0x33]),
            (&[0x11, 0x22, 0x33, 0x44], &[0x05, 0x11, 0x22, 0x33, 0x44]),
            (&[0x11, 0x00, 0x00, 0x00], &[0x02, 0x11, 0x01, 0x01, 0x01]),
        ];
        for (raw, enc) in cases {
            let mut buf = [0u8; 16];
            let n = cobs_encode(raw, &mut buf).unwrap();
            assert_eq!(&buf[..n], *enc);
            let mut back = [0u8; 16];
            let m = cobs_decode(enc, &mut back).unwrap();
            assert_eq!(&back[..m], *raw);
        }
    }

    #[test]
    fn long_run_without_zero() {
        let raw = [0x42u8; 300];
        let mut enc = [0u8; 310];
        let n = cobs_encode(&raw, &mut enc).unwrap();
        assert!(!enc[..n].contains(&0));
        let mut back = [0u8; 310];
        let m = cobs_decode(&enc[..n], &mut back).unwrap();
        assert_eq!(&back[..m], &raw[..]);
    }
}
