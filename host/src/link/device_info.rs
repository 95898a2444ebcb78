//! What the device says about itself in `HelloReply`: its protocol,
//! limits, board and pixel source.

use std::fmt;

use brightpix_protocol::wire::{Capabilities, PixelSourceKind};

/// What the device said about itself in `HelloReply`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DeviceInfo {
    pub version: u16,
    pub schema: u64,
    pub max_subapertures: u32,
    pub max_camera_pixels: u32,
    pub max_open_windows: u32,
    pub pool_entries: u32,
    pub history_pixels: u32,
    pub scratch_entries: u32,
    pub max_results_per_row: u32,
    pub max_frame_bytes: u32,
    pub pixel_source: PixelSourceKind,
    pub board: String,
    /// The session id the device echoed.
    pub session: u32,
}

impl DeviceInfo {
    pub(super) fn new(version: u16, schema: u64, session: u32, c: &Capabilities<'_>) -> Self {
        DeviceInfo {
            version,
            schema,
            session,
            max_subapertures: c.max_subapertures,
            max_camera_pixels: c.max_camera_pixels,
            max_open_windows: c.max_open_windows,
            pool_entries: c.pool_entries,
            history_pixels: c.history_pixels,
            scratch_entries: c.scratch_entries,
            max_results_per_row: c.max_results_per_row,
            max_frame_bytes: c.max_frame_bytes,
            pixel_source: c.pixel_source,
            board: c.board.to_string(),
        }
    }
}

impl fmt::Display for DeviceInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "board \"{}\", protocol {} (schema {:#018x}); up to {} sub-apertures, {} map pixels, \
             {} open windows, {} pool entries, {} history pixels, {} scratch entries, {} results per \
             row, frames of {} bytes; pixels: {:?}",
            self.board,
            self.version,
            self.schema,
            self.max_subapertures,
            self.max_camera_pixels,
            self.max_open_windows,
            self.pool_entries,
            self.history_pixels,
            self.scratch_entries,
            self.max_results_per_row,
            self.max_frame_bytes,
            self.pixel_source
        )
    }
}
