//! The link test (protocol 8): the device sends a stream of fill bytes as
//! fast as its link to the host takes them, and the host times their
//! arrival (PROTOCOL.md §15). A board's results leave on that link, and
//! beyond a small camera it, not the core, sets how many boards a rig
//! needs: this is how the first board gives its rate.

use core::fmt;

use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Most fill bytes one [`HostMessage::LinkTest`](super::HostMessage) asks
/// for: 16 MiB, about 16 s of USB full speed.
pub const MAX_LINK_TEST_BYTES: u32 = 16 << 20;

/// Most fill bytes in one `LinkFill` message (its frame then stays within
/// `MAX_FRAME_LEN`).
pub const MAX_LINK_FILL: u16 = 960;

/// The fill byte at `offset` of a link test's stream: the offset modulo
/// 251 (a prime, so that a byte lost or repeated anywhere shows), zeros
/// included (COBS takes them like any other byte).
pub const fn link_fill_byte(offset: u32) -> u8 {
    (offset % 251) as u8
}

/// The fill bytes `offset .. offset + len` ([`link_fill_byte`]), `len` at
/// most [`MAX_LINK_FILL`]: a slice of one constant table, so a device sends
/// them without a buffer.
pub fn link_fill(offset: u32, len: usize) -> &'static [u8] {
    &FILL[(offset % 251) as usize..][..len]
}

const FILL_LEN: usize = 251 + MAX_LINK_FILL as usize;

static FILL: [u8; FILL_LEN] = {
    let mut fill = [0; FILL_LEN];
    let mut k = 0;
    while k < FILL_LEN {
        fill[k] = link_fill_byte(k as u32);
        k += 1;
    }
    fill
};

/// Why a link test was refused (`DeviceError::LinkTest`). Nothing was sent.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum LinkTestFault {
    /// A frame is in progress or a capture runs: the fill would delay its
    /// results.
    Streaming,
    /// More bytes than [`MAX_LINK_TEST_BYTES`].
    TooManyBytes { max: u32 },
    /// A `chunk` of 0 or above [`MAX_LINK_FILL`].
    Chunk { max: u16 },
}

impl fmt::Display for LinkTestFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            LinkTestFault::Streaming => write!(
                f,
                "the device is streaming (a frame in progress or a capture): stop it before a link test"
            ),
            LinkTestFault::TooManyBytes { max } => {
                write!(f, "a link test sends at most {max} bytes")
            }
            LinkTestFault::Chunk { max } => {
                write!(f, "a link test's chunk is 1 to {max} bytes a message")
            }
        }
    }
}
