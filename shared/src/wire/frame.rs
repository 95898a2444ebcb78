//! Framing: `COBS(postcard ++ CRC-32 LE) ++ 0x00`, and a receive buffer that
//! cuts a byte stream into frames.
//!
//! Used by both sides: the device with static buffers, the host with any
//! buffer (`FrameReader<Vec<u8>>`, `[u8; MAX_FRAME_LEN]`, ...).

use core::fmt;

use crc::{Crc, CRC_32_ISO_HDLC};
use postcard::ser_flavors::{crc::CrcModifier, Cobs, Slice};
use serde::{Deserialize, Serialize};

use super::{Hello, MAX_FRAME_LEN};

/// CRC-32/ISO-HDLC (the zlib/Ethernet CRC-32): poly 0x04C11DB7 reflected,
/// init and xorout 0xFFFFFFFF. `CRC32.checksum(b"123456789") == 0xCBF43926`.
pub static CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

/// A running CRC-32 (of an upload: the header's encoding, then its tables; PROTOCOL.md §7).
pub type Crc32Digest = crc::Digest<'static, u32>;

/// Bytes of the CRC after the postcard bytes.
pub const CRC_LEN: usize = 4;

/// Why a frame was not a message. Never a panic: every byte sequence gives
/// either a message or one of these.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WireError {
    /// Not valid COBS (or empty).
    Cobs,
    /// Fewer bytes than a CRC and a message tag.
    TooShort,
    /// The CRC does not match the bytes.
    Crc { computed: u32, received: u32 },
    /// The bytes are not a message of this protocol.
    Decode,
    /// A message followed by extra bytes.
    TrailingBytes,
    /// Encoding: the message does not fit the buffer or [`MAX_FRAME_LEN`].
    TooLong,
}

impl fmt::Display for WireError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            WireError::Cobs => write!(f, "frame is not valid COBS"),
            WireError::TooShort => write!(f, "frame is too short to hold a message and CRC"),
            WireError::Crc { computed, received } => write!(
                f,
                "frame CRC mismatch (computed {computed:#010x}, received {received:#010x})"
            ),
            WireError::Decode => write!(f, "frame does not hold a valid message"),
            WireError::TrailingBytes => write!(f, "frame has bytes after its message"),
            WireError::TooLong => write!(f, "message does not fit in a frame"),
        }
    }
}

impl core::error::Error for WireError {}

/// Encodes `message` as one frame (delimiter included) at the start of
/// `buf`; at most [`MAX_FRAME_LEN`] bytes are used.
pub fn encode<'b, M: Serialize + ?Sized>(
    message: &M,
    buf: &'b mut [u8],
) -> Result<&'b mut [u8], WireError> {
    let limit = buf.len().min(MAX_FRAME_LEN);
    let cobs = Cobs::try_new(Slice::new(&mut buf[..limit])).map_err(|_| WireError::TooLong)?;
    postcard::serialize_with_flavor(message, CrcModifier::new(cobs, CRC32.digest()))
        .map_err(|_| WireError::TooLong)
}

/// Decodes one frame (without its 0x00 delimiter) in place. The message
/// borrows its byte payloads from `frame`.
pub fn decode<'a, M: Deserialize<'a>>(frame: &'a mut [u8]) -> Result<M, WireError> {
    decode_body(unstuff(frame)?)
}

/// COBS-decodes `frame` in place and checks its CRC: returns the postcard
/// bytes (the body), for [`decode_body`] and [`hello_in_body`].
pub fn unstuff(frame: &mut [u8]) -> Result<&[u8], WireError> {
    if frame.is_empty() {
        return Err(WireError::Cobs);
    }
    let len = cobs::decode_in_place(frame).map_err(|_| WireError::Cobs)?;
    if len < CRC_LEN + 1 || len > frame.len() {
        return Err(WireError::TooShort);
    }
    let (body, crc) = frame[..len].split_at(len - CRC_LEN);
    let received = u32::from_le_bytes([crc[0], crc[1], crc[2], crc[3]]);
    let computed = CRC32.checksum(body);
    if computed != received {
        return Err(WireError::Crc { computed, received });
    }
    Ok(body)
}

/// Decodes a message from a frame's body: all of it, no trailing bytes.
pub fn decode_body<'a, M: Deserialize<'a>>(body: &'a [u8]) -> Result<M, WireError> {
    let (message, rest) = postcard::take_from_bytes(body).map_err(|_| WireError::Decode)?;
    if !rest.is_empty() {
        return Err(WireError::TrailingBytes);
    }
    Ok(message)
}

/// The frozen prefix of a `Hello` or `HelloReply` body (variant 0, then
/// `version` and `schema`), read without decoding the rest: lets either
/// side recognise a peer of another protocol version, whose messages do not
/// decode, and report the mismatch. `None` if the body is not variant 0.
pub fn hello_in_body(body: &[u8]) -> Option<Hello> {
    let (tag, rest): (u32, &[u8]) = postcard::take_from_bytes(body).ok()?;
    if tag != 0 {
        return None;
    }
    let (hello, _): (Hello, _) = postcard::take_from_bytes(rest).ok()?;
    Some(hello)
}

/// [`hello_in_body`] of a whole frame (decoded in place).
pub fn hello_prefix(frame: &mut [u8]) -> Option<Hello> {
    hello_in_body(unstuff(frame).ok()?)
}

/// What [`FrameReader::next_frame`] found.
#[derive(Debug, PartialEq, Eq)]
pub enum Received<'a> {
    /// A frame, without its delimiter, ready for [`decode`] (which may
    /// modify it).
    Frame(&'a mut [u8]),
    /// A frame longer than the buffer was dropped up to its delimiter.
    TooLong,
}

/// Cuts a byte stream into frames at 0x00 bytes. Read into [`space`], tell
/// the reader with [`advance`], then take frames with [`next_frame`] until
/// it returns `None` (before the next [`space`]). Empty frames (0x00 0x00) are skipped, so a sender may
/// send a lone 0x00 to resynchronise; a frame longer than the buffer is
/// reported once as [`Received::TooLong`] and dropped.
///
/// [`space`]: FrameReader::space
/// [`advance`]: FrameReader::advance
/// [`next_frame`]: FrameReader::next_frame
pub struct FrameReader<B> {
    buf: B,
    /// Start of unconsumed bytes.
    start: usize,
    /// End of received bytes.
    end: usize,
    /// `buf[start..scan]` holds no 0x00.
    scan: usize,
    /// Dropping the rest of a too-long frame.
    overflow: bool,
}

impl<B: AsRef<[u8]> + AsMut<[u8]>> FrameReader<B> {
    /// `buf`'s length is the longest frame accepted (delimiter excluded);
    /// [`MAX_FRAME_LEN`] holds every frame of this protocol.
    pub fn new(buf: B) -> Self {
        FrameReader {
            buf,
            start: 0,
            end: 0,
            scan: 0,
            overflow: false,
        }
    }

    /// Free space to receive into (never empty if the buffer is not).
    pub fn space(&mut self) -> &mut [u8] {
        let capacity = self.buf.as_ref().len();
        if self.start > 0 {
            self.buf.as_mut().copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.scan -= self.start;
            self.start = 0;
        }
        if self.end == capacity {
            // A whole buffer without a delimiter: the frame is too long.
            self.overflow = true;
            self.end = 0;
            self.scan = 0;
        }
        &mut self.buf.as_mut()[self.end..]
    }

    /// `n` bytes were received into [`space`](Self::space).
    pub fn advance(&mut self, n: usize) {
        self.end = (self.end + n).min(self.buf.as_ref().len());
    }

    /// Copies `bytes` in, as far as they fit; returns how many were taken.
    /// (For callers that receive into their own buffer.)
    pub fn push(&mut self, bytes: &[u8]) -> usize {
        let space = self.space();
        let n = space.len().min(bytes.len());
        space[..n].copy_from_slice(&bytes[..n]);
        self.advance(n);
        n
    }

    /// The next complete frame, if one has been received.
    pub fn next_frame(&mut self) -> Option<Received<'_>> {
        loop {
            let found = self.buf.as_ref()[self.scan..self.end]
                .iter()
                .position(|&b| b == 0);
            let Some(offset) = found else {
                self.scan = self.end;
                return None;
            };
            let zero = self.scan + offset;
            let start = self.start;
            self.start = zero + 1;
            self.scan = zero + 1;
            if self.overflow {
                self.overflow = false;
                return Some(Received::TooLong);
            }
            if zero > start {
                return Some(Received::Frame(&mut self.buf.as_mut()[start..zero]));
            }
        }
    }

    /// Bytes received but not yet part of a complete frame.
    pub fn pending(&self) -> usize {
        self.end - self.start
    }

    /// Forgets everything received.
    pub fn clear(&mut self) {
        self.start = 0;
        self.end = 0;
        self.scan = 0;
        self.overflow = false;
    }
}
