//! The rig's stage-controller wire protocol: a `no_std`, allocation-free codec.
//!
//! `PROTOCOL.md` beside this crate is the specification. Frames are COBS-encoded, end in a
//! `0x00` delimiter and carry a CRC-16/CCITT-FALSE, so a receiver resynchronises after any
//! garbage at the next delimiter. [`encode`] writes one frame into a caller's buffer;
//! [`Decoder`] takes bytes one at a time and yields frames.
#![no_std]
#![forbid(unsafe_code)]

mod cobs;
mod crc;
mod message;
mod wire;

pub use cobs::{cobs_decode, cobs_encode};
pub use crc::crc16;
pub use message::*;
pub use wire::{encode, DecodeError, Decoder, EncodeError, MAX_RAW, MAX_WIRE};

/// Protocol version 1.0, as `major << 8 | minor`.
pub const PROTOCOL_VERSION: u16 = 0x0100;

/// Major part of a `major << 8 | minor` version.
pub const fn major(version: u16) -> u8 {
    (version >> 8) as u8
}
