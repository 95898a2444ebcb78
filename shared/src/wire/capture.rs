//! A capture's start (PROTOCOL.md §9): at once, or on a rig's sync line,
//! and why a device refuses the sync line; the edge rows' checksum of the
//! alignment self-check.

use core::fmt;

use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use super::fnv1a64;

/// Which camera frame a capture's frame 0 is (PROTOCOL.md §9). Several
/// boards on one camera number the same camera frame alike only if they
/// start on the same one: a sync line wired to every board gives them that.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum CaptureStart {
    /// The first frame that starts (VSYNC) after the request: each board on
    /// its own, wherever its request happened to land.
    Immediate,
    /// A follower on the rig's sync line: arms (then `Ack(CaptureStarted)`)
    /// and counts from the first frame start after the line's next rising
    /// edge; no frame before that edge.
    OnSync,
    /// The rig's leader: arms, waits for a frame start, raises the sync
    /// line, and counts from the next frame start, the one every armed
    /// follower starts on too. The line goes low again when the capture
    /// stops.
    DriveSync,
}

/// Why a device cannot start a capture on the rig's sync line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum SyncFault {
    /// The device has no sync line (a board without the wiring, a
    /// simulated device not sharing a simulated camera).
    NoSyncLine,
    /// `OnSync`, but the line is already high: no rising edge can come
    /// (a leader still driving it, or a line stuck high).
    LineHigh,
}

impl fmt::Display for SyncFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SyncFault::NoSyncLine => "the device has no sync line",
            SyncFault::LineHigh => {
                "the sync line is already high, so no rising edge can start the capture (is another capture still driving it?)"
            }
        })
    }
}

/// FNV-1a 64 offset basis: the state of [`edge_row_checksum`] before any
/// pixel.
pub const EDGE_ROW_SEED: u64 = 0xcbf2_9ce4_8422_2325;

/// Adds `pixels` (as u16 little-endian) to an edge row's checksum state
/// (FNV-1a 64 from [`EDGE_ROW_SEED`]).
pub fn edge_row_update(mut state: u64, pixels: &[u16]) -> u64 {
    for p in pixels {
        state = fnv1a64(state, &p.to_le_bytes());
    }
    state
}

/// An edge row's checksum from its state: the FNV-1a 64 of its pixels,
/// folded to 32 bits (high half XOR low half).
pub const fn edge_row_checksum(state: u64) -> u32 {
    (state ^ (state >> 32)) as u32
}
