//! Framing: COBS + CRC + delimiter, and a byte-at-a-time decoder that resynchronises.

use crate::message::{Frame, Message, Writer};
use crate::{cobs_decode, cobs_encode, crc16};

/// Largest raw frame (kind, seq, body, CRC).
pub const MAX_RAW: usize = 40;
/// Largest frame on the wire, delimiter included.
pub const MAX_WIRE: usize = MAX_RAW + 2;

/// Why a frame could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EncodeError {
    /// The output buffer is shorter than the frame (use [`MAX_WIRE`] bytes).
    BufferTooSmall,
}

/// Why bytes between two delimiters were not a frame. The decoder has already resynchronised
/// when it reports one of these; the caller only counts or logs it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DecodeError {
    /// More than [`MAX_WIRE`] bytes without a delimiter.
    Overflow,
    /// Not valid COBS.
    BadCobs,
    /// Shorter than kind + seq + CRC.
    TooShort,
    /// CRC mismatch: the frame was damaged on the line.
    BadCrc,
    /// Unknown kind, wrong body length or a field outside its enumeration.
    BadBody { kind: u8 },
}

/// Encodes `frame` onto `out` (delimiter included) and returns the number of bytes written.
pub fn encode(frame: &Frame, out: &mut [u8]) -> Result<usize, EncodeError> {
    let mut raw = [0u8; MAX_RAW];
    let mut w = Writer {
        buf: &mut raw,
        pos: 0,
    };
    w.u8(frame.msg.kind()).ok_or(EncodeError::BufferTooSmall)?;
    w.u8(frame.seq).ok_or(EncodeError::BufferTooSmall)?;
    frame
        .msg
        .write_body(&mut w)
        .ok_or(EncodeError::BufferTooSmall)?;
    let n = w.pos;
    let crc = crc16(&raw[..n]);
    raw.get_mut(n..n + 2)
        .ok_or(EncodeError::BufferTooSmall)?
        .copy_from_slice(&crc.to_le_bytes());
    let len = cobs_encode(&raw[..n + 2], out).ok_or(EncodeError::BufferTooSmall)?;
    *out.get_mut(len).ok_or(EncodeError::BufferTooSmall)? = 0;
    Ok(len + 1)
}

/// Byte-at-a-time frame decoder with a fixed buffer.
#[derive(Debug, Clone)]
pub struct Decoder {
    buf: [u8; MAX_WIRE],
    len: usize,
    overflow: bool,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    pub const fn new() -> Self {
        Decoder {
            buf: [0; MAX_WIRE],
            len: 0,
            overflow: false,
        }
    }

    /// Forgets any partial frame (after a purge of the line).
    pub fn reset(&mut self) {
        self.len = 0;
        self.overflow = false;
    }

    /// Feeds one byte. Returns a frame or an error when `byte` is a delimiter that closes a
    /// non-empty block; `None` otherwise.
    pub fn push(&mut self, byte: u8) -> Option<Result<Frame, DecodeError>> {
        if byte != 0 {
            if self.len < self.buf.len() {
                self.buf[self.len] = byte;
                self.len += 1;
            } else {
                self.overflow = true;
            }
            return None;
        }
        let (len, overflow) = (self.len, self.overflow);
        self.reset();
        if overflow {
            return Some(Err(DecodeError::Overflow));
        }
        if len == 0 {
            return None;
        }
        Some(Self::parse(&self.buf[..len]))
    }

    fn parse(block: &[u8]) -> Result<Frame, DecodeError> {
        let mut raw = [0u8; MAX_WIRE];
        let n = cobs_decode(block, &mut raw).ok_or(DecodeError::BadCobs)?;
        if n < 4 {
            return Err(DecodeError::TooShort);
        }
        let (data, crc) = raw[..n].split_at(n - 2);
        if crc16(data) != u16::from_le_bytes([crc[0], crc[1]]) {
            return Err(DecodeError::BadCrc);
        }
        let kind = data[0];
        let msg = Message::read_body(kind, &data[2..]).ok_or(DecodeError::BadBody { kind })?;
        Ok(Frame { seq: data[1], msg })
    }
}
