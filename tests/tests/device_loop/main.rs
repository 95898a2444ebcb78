//! The firmware's device loop on the host, over an in-memory link: the
//! host side speaks the wire protocol through `brightpix_protocol::wire`,
//! the device is the same `brightpix_firmware::device::Device` the boards
//! run. Slopes are compared with a direct run of the engine.
//!
//! Here the harness (the link, the host side, configurations and frames);
//! the tests by concern in the modules below.

mod bench;
mod camera;
mod faults;
mod link_test;
mod random;
mod session;
mod streaming;
mod uploads;
mod watchdog;

use std::cell::RefCell;
use std::collections::VecDeque;
use std::convert::Infallible;
use std::rc::Rc;
use std::task::Poll;

use brightpix_firmware::device::embedded_io_async::{ErrorType, Read};
use brightpix_firmware::device::{
    CameraRefused, CaptureBegin, Device, LinkError, LinkOnly, PixelRowsStream, PixelRun,
    PixelSource,
};
use brightpix_firmware::engine::SubapertureResult;
use brightpix_protocol::wire::tables::write_table;
use brightpix_protocol::wire::{
    decode, edge_row_checksum, edge_row_update, encode, Ack, CapacityKind, CaptureStart,
    ConfigFault, ConfigHeader, DeviceError, DeviceMessage, FrameFault, FrameReader, Hello,
    HostMessage, PixelRowsPlan, PixelSourceKind, Received, ResetReason, SlopeEntry, Status,
    SyncFault, Table, TablePosition, UploadPlan, CRC32, EDGE_ROW_SEED, MAX_CHUNK_BYTES,
    MAX_FRAME_LEN, MAX_PIXEL_BYTES, PROTOCOL_VERSION, SCHEMA_HASH, SLOPES_PER_MESSAGE,
};
use brightpix_protocol::{
    Camera, Config, ConfigError, Crop, LevelFilter, MemoryKind, RegularGrid, SelectionRule,
    SubapertureWindow,
};
use brightpix_tests::{case, direct, PixelCounts, ProcessingConfig};
use embassy_futures::block_on;
use proptest::prelude::*;

// --- the in-memory link ------------------------------------------------------

use brightpix_tests::memory_link::{LinkState, MemoryLink as Link};

// --- device storage on the heap (the host's, as the in-process device uses) ---

use brightpix::sim_device::{HeapDeviceStorage, SimSizes};

type Sizes = SimSizes;

const SIZES: Sizes = Sizes {
    subapertures: 256,
    map_pixels: 64 * 64,
    open_windows: 64,
    pool_entries: 64 * 256,
    history_pixels: 64 * 64,
    scratch_entries: 64 * 64,
    results_per_row: 64,
};

// --- the host side -------------------------------------------------------------

/// A device message, owned.
#[derive(Clone, Debug, PartialEq, Eq)]
enum Reply {
    Hello {
        version: u16,
        schema: u64,
        session: u32,
        board: String,
        source: PixelSourceKind,
        max_subapertures: u32,
    },
    Ack(Ack),
    Error(DeviceError),
    Status(Status),
    Slopes {
        frame: u32,
        results: Vec<SlopeEntry>,
    },
    FrameDone {
        frame: u32,
        count: u32,
    },
    Bench(brightpix::link::BenchRow),
    Began {
        synced: bool,
        camera_frame: Option<u32>,
    },
    EdgeRows {
        frame: u32,
        first: u32,
        last: u32,
    },
    LinkFill {
        offset: u32,
        fill: Vec<u8>,
    },
}

impl From<DeviceMessage<'_>> for Reply {
    fn from(m: DeviceMessage<'_>) -> Self {
        match m {
            DeviceMessage::HelloReply(h) => Reply::Hello {
                version: h.version,
                schema: h.schema,
                session: h.session,
                board: h.capabilities.board.to_string(),
                source: h.capabilities.pixel_source,
                max_subapertures: h.capabilities.max_subapertures,
            },
            DeviceMessage::Ack(a) => Reply::Ack(a),
            DeviceMessage::Error(e) => Reply::Error(e),
            DeviceMessage::Status(s) => Reply::Status(s),
            DeviceMessage::Slopes { frame, results } => Reply::Slopes {
                frame,
                results: results.to_vec(),
            },
            DeviceMessage::FrameDone { frame, count } => Reply::FrameDone { frame, count },
            DeviceMessage::BenchReport(r) => Reply::Bench(brightpix::link::BenchRow::of(&r)),
            DeviceMessage::CaptureBegan {
                synced,
                camera_frame,
            } => Reply::Began {
                synced,
                camera_frame,
            },
            DeviceMessage::EdgeRows { frame, first, last } => {
                Reply::EdgeRows { frame, first, last }
            }
            DeviceMessage::LinkFill { offset, fill } => Reply::LinkFill {
                offset,
                fill: fill.to_vec(),
            },
        }
    }
}

struct Host {
    link: Rc<RefCell<LinkState>>,
    reader: FrameReader<Vec<u8>>,
}

impl Host {
    fn send(&self, message: &HostMessage<'_>) {
        let mut buf = vec![0u8; MAX_FRAME_LEN];
        let frame = encode(message, &mut buf).unwrap();
        self.send_raw(frame);
    }

    fn send_raw(&self, bytes: &[u8]) {
        self.link.borrow_mut().input.extend(bytes);
    }

    /// `Hello` of session 1.
    fn hello(&self) {
        self.send(&HostMessage::hello(1));
    }

    /// Every message of an upload of `config`.
    fn upload(&self, config: Config<'_>, upload_id: u32, chunk: usize) {
        let mut plan = UploadPlan::new(config, upload_id, chunk);
        let mut scratch = vec![0u8; MAX_CHUNK_BYTES];
        while let Some(m) = plan.next(&mut scratch) {
            self.send(&m);
        }
    }

    fn frame(&self, frame: u32, pixels: &[u16], per_message: usize) {
        let mut plan = PixelRowsPlan::new(frame, pixels, per_message);
        let mut scratch = vec![0u8; MAX_PIXEL_BYTES];
        while let Some(m) = plan.next(&mut scratch) {
            self.send(&m);
        }
    }

    /// `PixelRows` for pixels `first ..` of a frame.
    fn frame_from(&self, frame: u32, pixels: &[u16], first: usize, per_message: usize) {
        let mut bytes = vec![0u8; 2 * per_message];
        for (k, part) in pixels[first..].chunks(per_message).enumerate() {
            let n = brightpix_protocol::wire::tables::pixels_to_le(part, &mut bytes);
            self.send(&HostMessage::PixelRows {
                frame,
                first_pixel: (first + k * per_message) as u32,
                pixels: &bytes[..n],
            });
        }
    }

    /// Everything the device sent since the last call.
    fn replies(&mut self) -> Vec<Reply> {
        let output = std::mem::take(&mut self.link.borrow_mut().output);
        let mut out = Vec::new();
        let mut rest = &output[..];
        while !rest.is_empty() {
            let n = self.reader.push(rest);
            rest = &rest[n..];
            while let Some(received) = self.reader.next_frame() {
                match received {
                    Received::Frame(f) => out.push(Reply::from(
                        decode::<DeviceMessage>(f).expect("the device sends valid frames"),
                    )),
                    Received::TooLong => panic!("the device sent a frame too long"),
                }
            }
        }
        assert_eq!(self.reader.pending(), 0, "a partial frame from the device");
        out
    }
}

fn setup(sizes: Sizes, max_read: usize) -> (HeapDeviceStorage, Host, Link) {
    let state = Rc::new(RefCell::new(LinkState {
        closed: true,
        max_read,
        ..LinkState::default()
    }));
    let host = Host {
        link: state.clone(),
        reader: FrameReader::new(vec![0u8; MAX_FRAME_LEN]),
    };
    (HeapDeviceStorage::new(sizes), host, Link(state))
}

/// Runs the device until it has handled all input.
fn run<C: PixelSource>(device: &mut Device<'_, Link, C>) {
    match block_on(device.run()) {
        Err(LinkError::Closed) => {}
        other => panic!("device stopped with {other:?}"),
    }
}

// --- configurations and frames ---------------------------------------------------

/// The configurations here are the host's owned configuration type.
type Owned = ProcessingConfig;

fn grid(columns: u16, rows: u16, width: u16, height: u16) -> Vec<SubapertureWindow> {
    RegularGrid {
        x: 0,
        y: 0,
        columns,
        rows,
        width,
        height,
        pitch_x: width,
        pitch_y: height,
    }
    .windows()
    .collect()
}

const CAMERA: Camera = Camera {
    width: 48,
    height: 32,
    bit_depth: 12,
};

/// Plain: subtract-next, N = 5, 6 x 4 windows of 8 x 8.
fn config_a() -> Owned {
    Owned {
        pixels: PixelCounts::All(5),
        ..Owned::new(CAMERA, grid(6, 4, 8, 8))
    }
}

/// Everything: maps, threshold, per-sub-aperture N, references, 4 x 4
/// windows of 12 x 8, threshold rule.
fn config_b() -> Owned {
    let pixels = CAMERA.pixel_count();
    Owned {
        camera: CAMERA,
        windows: grid(4, 4, 12, 8),
        grid: None,
        pixels: PixelCounts::PerSubaperture((0..16).map(|k| 3 + k % 9).collect()),
        background: Some((0..pixels as i32).map(|k| (k * 7919) % 801 - 400).collect()),
        gain: Some((0..pixels).map(|k| 3500 + (k * 31 % 1200) as u16).collect()),
        threshold: Some(40),
        rule: SelectionRule::Threshold,
        level_filter: None,
        reference_slopes: Some(
            (0..16)
                .map(|k| [k * 4099 - 30_000, 12_345 - k * 777])
                .collect(),
        ),
        min_flux: 100,
        crop: None,
    }
}

/// Subtract-mean with a level filter (its state carries across frames).
fn config_filtered() -> Owned {
    Owned {
        rule: SelectionRule::SubtractMean { count: 3 },
        level_filter: Some(LevelFilter { gain_shift: 2 }),
        pixels: PixelCounts::PerSubaperture((0..24).map(|k| 4 + k % 6).collect()),
        ..config_a()
    }
}

/// Deterministic spots on noise.
fn frames(camera: Camera, count: usize, seed: u64) -> Vec<Vec<u16>> {
    let mut state = seed | 1;
    let mut rng = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let max = camera.max_raw() as u64;
    let (w, h) = (camera.width as usize, camera.height as usize);
    (0..count)
        .map(|_| {
            let mut f: Vec<u16> = (0..w * h).map(|_| (rng() % 40) as u16).collect();
            for _ in 0..(w * h / 40) {
                let (x, y) = ((rng() % w as u64) as usize, (rng() % h as u64) as usize);
                let peak = max / 2 + rng() % (max / 2);
                for (dx, dy, div) in [(0, 0, 1), (1, 0, 3), (0, 1, 3), (1, 1, 5)] {
                    if x + dx < w && y + dy < h {
                        let p = &mut f[(y + dy) * w + x + dx];
                        *p = (*p as u64).max(peak / div) as u16;
                    }
                }
            }
            f
        })
        .collect()
}

fn entry(r: &SubapertureResult) -> SlopeEntry {
    SlopeEntry {
        index: r.index,
        slope_x: r.slope_x,
        slope_y: r.slope_y,
        flux: r.flux,
        valid: r.valid,
    }
}

/// Slopes of `frame` in arrival order, the number of Slopes messages, and
/// the FrameDone count.
fn slopes_of(replies: &[Reply], frame: u32) -> (Vec<SlopeEntry>, usize, Option<u32>) {
    let mut results = Vec::new();
    let mut messages = 0;
    let mut done = None;
    for r in replies {
        match r {
            Reply::Slopes {
                frame: f,
                results: r,
            } if *f == frame => {
                assert!(done.is_none(), "slopes after FrameDone");
                assert!(!r.is_empty() && r.len() <= SLOPES_PER_MESSAGE);
                results.extend_from_slice(r);
                messages += 1;
            }
            Reply::FrameDone { frame: f, count } if *f == frame => {
                assert!(done.is_none(), "two FrameDone");
                done = Some(*count);
            }
            _ => {}
        }
    }
    (results, messages, done)
}

fn expect_verified(replies: &[Reply], frame: u32, expected: &[SubapertureResult]) {
    let (got, _, done) = slopes_of(replies, frame);
    let want: Vec<SlopeEntry> = expected.iter().map(entry).collect();
    assert_eq!(got, want, "frame {frame}");
    assert_eq!(done, Some(want.len() as u32), "frame {frame} FrameDone");
}

fn acks(replies: &[Reply]) -> Vec<Ack> {
    replies
        .iter()
        .filter_map(|r| match r {
            Reply::Ack(a) => Some(*a),
            _ => None,
        })
        .collect()
}

fn errors(replies: &[Reply]) -> Vec<DeviceError> {
    replies
        .iter()
        .filter_map(|r| match r {
            Reply::Error(e) => Some(*e),
            _ => None,
        })
        .collect()
}

fn status(host: &mut Host, device: &mut Device<'_, Link, LinkOnly>) -> Status {
    host.send(&HostMessage::StatusRequest);
    run(device);
    match host.replies().as_slice() {
        [Reply::Status(s)] => *s,
        other => panic!("expected a status, got {other:?}"),
    }
}

/// Uploads `config` and checks it was applied.
fn configure(
    host: &mut Host,
    device: &mut Device<'_, Link, LinkOnly>,
    config: Config<'_>,
    id: u32,
) {
    host.upload(config, id, MAX_CHUNK_BYTES);
    run(device);
    let replies = host.replies();
    assert_eq!(errors(&replies), []);
    assert!(
        matches!(acks(&replies).last(), Some(Ack::ConfigApplied { config_id, .. }) if *config_id == id),
        "{replies:?}"
    );
}

/// COBS, as PROTOCOL.md describes it (delimiter excluded).
fn cobs_encode(data: &[u8]) -> Vec<u8> {
    let mut out = vec![0];
    let mut code_at = 0;
    for &b in data {
        if b != 0 {
            out.push(b);
        }
        if b == 0 || out.len() - code_at == 255 {
            out[code_at] = (out.len() - code_at) as u8;
            code_at = out.len();
            out.push(0);
        }
    }
    out[code_at] = (out.len() - code_at) as u8;
    out
}

fn cobs_decode(data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < data.len() {
        let code = data[i] as usize;
        out.extend_from_slice(&data[i + 1..i + code]);
        i += code;
        if code < 255 && i < data.len() {
            out.push(0);
        }
    }
    out
}

/// A frame of any postcard bytes.
fn frame_of(body: &[u8]) -> Vec<u8> {
    let mut plain = body.to_vec();
    plain.extend_from_slice(&CRC32.checksum(body).to_le_bytes());
    let mut frame = cobs_encode(&plain);
    frame.push(0);
    frame
}

/// A frame whose CRC is wrong: the postcard bytes are intact.
fn with_bad_crc(message: &HostMessage<'_>) -> Vec<u8> {
    let mut buf = vec![0u8; MAX_FRAME_LEN];
    let len = encode(message, &mut buf).unwrap().len();
    let mut plain = cobs_decode(&buf[..len - 1]);
    let n = plain.len();
    let crc = u32::from_le_bytes(plain[n - 4..].try_into().unwrap());
    assert_eq!(
        crc,
        CRC32.checksum(&plain[..n - 4]),
        "PROTOCOL.md's framing"
    );
    plain[n - 4] ^= 1;
    let mut frame = cobs_encode(&plain);
    assert_eq!(cobs_encode(&cobs_decode(&frame)), frame);
    frame.push(0);
    frame
}
