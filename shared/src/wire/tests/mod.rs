//! The wire module's tests: the example messages and helpers here, the
//! tests by concern in the modules below.

extern crate std;

mod digest;
mod framing;
mod messages;
mod schema;
mod upload;

use std::vec;
use std::vec::Vec;

use postcard_schema::key::hash::fnv1a64::hash_ty_path;
use postcard_schema::schema::DataModelType;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use super::tables::{
    config_digest, pixels_from_le, read_reference_slope, read_window, TableSlices,
};
use super::*;
use crate::config::{
    Calibration, Centroid, Config, ConfigError, Crop, MapKind, MemoryKind, PixelCount, Selection,
    SubapertureWindow,
};

/// xorshift64*: deterministic randomness without a dependency.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
    fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| self.next() as u8).collect()
    }
}

const CAMERA: Camera = Camera {
    width: 4096,
    height: 4096,
    bit_depth: 16,
};

fn header() -> ConfigHeader {
    ConfigHeader {
        camera: CAMERA,
        windows: u32::MAX,
        rule: SelectionRule::SubtractMean { count: u16::MAX },
        pixel_count: PixelCountMode::All(u16::MAX),
        level_filter: Some(LevelFilter { gain_shift: 16 }),
        threshold: Some(i32::MIN),
        min_flux: i64::MIN,
        background: Background::Constant(i32::MIN),
        gain: false,
        reference_slopes: true,
        crop: Some(Crop {
            x: u16::MAX,
            y: u16::MAX,
            sensor_width: u16::MAX,
            sensor_height: u16::MAX,
        }),
    }
}

/// One example of every host message, extreme values where sizes matter.
fn host_examples(payload: &[u8]) -> Vec<HostMessage<'_>> {
    let all = vec![
        HostMessage::hello(u32::MAX),
        HostMessage::ConfigBegin {
            upload_id: u32::MAX,
            header: header(),
        },
        HostMessage::ConfigChunk {
            upload_id: u32::MAX,
            table: Table::ReferenceSlopes,
            offset: u32::MAX,
            bytes: &payload[..MAX_CHUNK_BYTES],
        },
        HostMessage::ConfigCommit {
            upload_id: 7,
            crc32: u32::MAX,
        },
        HostMessage::ConfigAbort,
        HostMessage::StatusRequest,
        HostMessage::ResetLevelFilters,
        HostMessage::PixelRows {
            frame: u32::MAX,
            first_pixel: u32::MAX,
            pixels: &payload[..MAX_PIXEL_BYTES],
        },
        HostMessage::Capture {
            frames: u32::MAX,
            start: CaptureStart::DriveSync,
            edge_rows: true,
        },
        HostMessage::StopCapture,
    ];
    // Every kind is present (MessageKind is matched exhaustively in kind()).
    for kind in [
        MessageKind::Hello,
        MessageKind::ConfigBegin,
        MessageKind::ConfigChunk,
        MessageKind::ConfigCommit,
        MessageKind::ConfigAbort,
        MessageKind::StatusRequest,
        MessageKind::ResetLevelFilters,
        MessageKind::PixelRows,
        MessageKind::Capture,
        MessageKind::StopCapture,
    ] {
        assert!(
            all.iter().any(|m| m.kind() == kind),
            "{kind:?} has no example"
        );
    }
    all
}

fn entry(k: u16) -> SlopeEntry {
    SlopeEntry {
        index: u16::MAX - k,
        slope_x: i32::MIN,
        slope_y: i32::MAX,
        flux: i64::MIN,
        valid: true,
    }
}

fn device_examples() -> Vec<DeviceMessage<'static>> {
    let mut out = vec![
        DeviceMessage::HelloReply(HelloReply {
            version: PROTOCOL_VERSION,
            schema: SCHEMA_HASH,
            session: u32::MAX,
            capabilities: Capabilities {
                max_subapertures: u32::MAX,
                max_camera_pixels: u32::MAX,
                max_open_windows: u32::MAX,
                pool_entries: u32::MAX,
                history_pixels: u32::MAX,
                scratch_entries: u32::MAX,
                max_results_per_row: u32::MAX,
                max_frame_bytes: MAX_FRAME_LEN as u32,
                pixel_source: PixelSourceKind::Camera,
                board: "0123456789abcdef0123456789abcdef",
            },
        }),
        DeviceMessage::Status(Status {
            config_id: Some(u32::MAX),
            upload_id: Some(u32::MAX),
            capturing: true,
            frames_processed: u64::MAX,
            frames_dropped: u64::MAX,
            crc_errors: u32::MAX,
            decode_errors: u32::MAX,
            overruns: u32::MAX,
            pixel_errors: u32::MAX,
            session: Some(u32::MAX),
            reset_reason: ResetReason::Watchdog,
            watchdog_ms: Some(u32::MAX),
            health: Health {
                silicon: Some(Silicon {
                    device_id: u16::MAX,
                    revision_id: u16::MAX,
                    axi_sram_fix: ErratumFix::Failed,
                }),
                clocks: Some(Clocks {
                    sysclk_configured_hz: u32::MAX,
                    sysclk_read_hz: u32::MAX,
                    voltage_scale_configured: u8::MAX,
                    voltage_scale_read: u8::MAX,
                    voltage_ready: true,
                }),
                usb_clock: Some(UsbClockSync {
                    sync_source: u8::MAX,
                    synced: true,
                    trim: u8::MAX,
                    sync_errors: u32::MAX,
                }),
                stack: Some(StackUsage {
                    size: u32::MAX,
                    peak: u32::MAX,
                    guarded: true,
                }),
                camera_interface: Some(CameraInterface {
                    overruns: u32::MAX,
                    sync_errors: u32::MAX,
                    dma_transfer_errors: u32::MAX,
                    dma_fifo_errors: u32::MAX,
                    fifo_not_drained: u32::MAX,
                }),
                idle_permille: Some(u16::MAX),
                faults: Some(FaultLog {
                    before_reset: Some(Fault {
                        kind: FaultKind::HardFault,
                        pc: u32::MAX,
                        lr: u32::MAX,
                        cfsr: u32::MAX,
                        hfsr: u32::MAX,
                        mmfar: u32::MAX,
                        bfar: u32::MAX,
                    }),
                }),
            },
            config_digest: Some(u32::MAX),
            engine: EngineCounters {
                windows: u64::MAX,
                candidates: u64::MAX,
                compactions: u64::MAX,
                rescans: u64::MAX,
                attentions: u64::MAX,
                kernel_frames: u64::MAX,
            },
        }),
        DeviceMessage::Slopes {
            frame: u32::MAX,
            results: (0..SLOPES_PER_MESSAGE as u16).map(entry).collect(),
        },
        DeviceMessage::FrameDone {
            frame: u32::MAX,
            count: u32::MAX,
        },
    ];
    let position = TablePosition {
        table: Table::Gain,
        offset: u32::MAX,
    };
    for ack in [
        Ack::UploadStarted { upload_id: 1 },
        Ack::ChunkStored {
            upload_id: 1,
            table: Table::Background,
            end: 960,
        },
        Ack::ConfigApplied {
            config_id: 1,
            open_windows: 80,
            pool_entries: 1680,
        },
        Ack::UploadAborted { upload_id: None },
        Ack::LevelFiltersReset,
        Ack::CaptureStarted { frames: 0 },
        Ack::CaptureStopped { frames: 100 },
    ] {
        out.push(DeviceMessage::Ack(ack));
    }
    let config_errors = [
        ConfigError::CameraSize {
            width: 0,
            height: 1,
        },
        ConfigError::TooManySubapertures {
            count: usize::MAX >> 32,
            max: 16384,
        },
        ConfigError::MapSize {
            map: MapKind::Gain,
            expected: 4,
            found: 3,
        },
        ConfigError::MemoryBudget {
            needed: 100,
            available: 10,
            what: MemoryKind::OpenWindows,
        },
        ConfigError::NegativeMinFlux,
        ConfigError::CropOutsideSensor {
            x: u16::MAX,
            y: u16::MAX,
            width: u16::MAX,
            height: u16::MAX,
            sensor_width: u16::MAX,
            sensor_height: u16::MAX,
        },
    ];
    let faults = [
        FrameFault::PixelOutOfRange {
            row: 1,
            column: 2,
            value: 4096,
        },
        FrameFault::Gap {
            expected: 10,
            found: 20,
        },
        FrameFault::Incomplete { received: 5 },
        FrameFault::PastEnd {
            first_pixel: 3,
            count: 9,
        },
        FrameFault::OddLength,
        FrameFault::Reconfigured,
        FrameFault::Stopped,
    ];
    let mut errors = vec![
        DeviceError::Decode,
        DeviceError::Crc,
        DeviceError::FrameTooLong,
        DeviceError::HelloRequired,
        DeviceError::Unexpected {
            message: MessageKind::PixelRows,
        },
        DeviceError::NoUpload,
        DeviceError::UploadMismatch {
            expected: 1,
            found: 2,
        },
        DeviceError::ChunkOutOfOrder {
            expected: Some(position),
            found: position,
        },
        DeviceError::ChunkOutOfOrder {
            expected: None,
            found: position,
        },
        DeviceError::ChunkLength {
            table: Table::Windows,
            len: 7,
        },
        DeviceError::ChunkPastEnd {
            table: Table::PixelCounts,
            end: 10,
            len: 8,
        },
        DeviceError::UploadIncomplete {
            table: Table::Background,
            received: 0,
            expected: 4,
        },
        DeviceError::UploadCrc {
            computed: 1,
            claimed: 2,
        },
        DeviceError::Capacity {
            what: CapacityKind::ResultsPerRow,
            needed: 3,
            available: 2,
        },
        DeviceError::NotConfigured,
        DeviceError::NoCamera,
        DeviceError::Crop(CropFault::FramePixels {
            pixels: u32::MAX,
            multiple: u16::MAX,
        }),
    ];
    errors.extend(config_errors.map(|e| DeviceError::Config(e.into())));
    errors.extend(faults.map(|fault| DeviceError::Frame { frame: 9, fault }));
    out.extend(errors.into_iter().map(DeviceMessage::Error));
    out
}

fn round_trip<'a, M>(message: &M, buf: &'a mut Vec<u8>) -> M
where
    M: Serialize + Deserialize<'a> + core::fmt::Debug,
{
    buf.resize(MAX_FRAME_LEN, 0xAA);
    let frame = encode(message, buf).unwrap_or_else(|e| panic!("{message:?}: {e}"));
    let len = frame.len();
    assert!(len <= MAX_FRAME_LEN);
    assert_eq!(frame[len - 1], 0, "frame ends with the delimiter");
    assert!(!frame[..len - 1].contains(&0), "no 0x00 inside a frame");
    buf.truncate(len - 1);
    decode(buf).unwrap()
}
