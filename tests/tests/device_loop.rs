//! The firmware's device loop on the host, over an in-memory link: the
//! host side speaks the wire protocol through `brightpix_protocol::wire`,
//! the device is the same `brightpix_firmware::device::Device` the boards
//! run. Slopes are compared with a direct run of the engine.

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

// --- tests ---------------------------------------------------------------------

#[test]
fn handshake_refuses_until_matching_hello() {
    let (mut storage, mut host, link) = setup(SIZES, 7);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "test-board");
    // Nothing is served before a Hello.
    host.send(&HostMessage::StatusRequest);
    // A host of another schema is answered with the device's identity and refused.
    host.send(&HostMessage::Hello {
        protocol: Hello {
            version: PROTOCOL_VERSION,
            schema: SCHEMA_HASH ^ 1,
        },
        session: 5,
    });
    host.send(&HostMessage::StatusRequest);
    // A host of a later protocol version whose Hello has grown a field: the
    // device still recognises the frozen prefix and answers with its identity.
    // variant 0, version 3, schema 5, then fields this build does not know
    let future_hello = [0x00, 0x03, 0x05, 0x07, 0x01, 0x02];
    host.send_raw(&frame_of(&future_hello));
    host.send(&HostMessage::StatusRequest);
    host.hello();
    host.send(&HostMessage::StatusRequest);
    run(&mut device);
    let replies = host.replies();
    let hello = |session| Reply::Hello {
        version: PROTOCOL_VERSION,
        schema: SCHEMA_HASH,
        session,
        board: "test-board".into(),
        source: PixelSourceKind::Link,
        max_subapertures: SIZES.subapertures as u32,
    };
    assert_eq!(
        replies,
        [
            Reply::Error(DeviceError::HelloRequired),
            hello(5),
            Reply::Error(DeviceError::HelloRequired),
            hello(0), // a Hello read only to its frozen prefix
            Reply::Error(DeviceError::HelloRequired),
            hello(1),
            Reply::Status(Status {
                session: Some(1),
                ..Status::default()
            }),
        ]
    );
    let caps = device.capabilities();
    assert_eq!(caps.max_camera_pixels, SIZES.map_pixels as u32);
    assert_eq!(caps.max_open_windows, SIZES.open_windows as u32);
    assert_eq!(caps.max_results_per_row, SIZES.results_per_row as u32);
    assert_eq!(caps.max_frame_bytes, MAX_FRAME_LEN as u32);
}

/// Issue 10, fault 1: a client that dies in the middle of a frame and an
/// upload must not reach the next session. The new client's 0x00 ends the
/// dead one's cut message, its `Hello` abandons the frame, the upload and
/// the level filters, and nothing after its `HelloReply` is about them: the
/// next session's frames verify from a clean start, with no stray error.
#[test]
fn a_new_session_starts_clean() {
    let owned = config_filtered();
    let config = owned.view();
    let frames = frames(CAMERA, 6, 5);
    let expected = direct(config, &frames[3..]);
    let (mut storage, mut host, link) = setup(SIZES, 50);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    host.hello();
    configure(&mut host, &mut device, config, 1);
    let before = status(&mut host, &mut device);
    // The first client: two frames (level filters move), half a third, half
    // of an upload, and a message cut off in the middle; then the next
    // client's 0x00 and Hello, all read in one go.
    host.frame(57, &frames[0], 480);
    host.frame(58, &frames[1], 480);
    host.frame(59, &frames[2][..700], 100);
    let b = config_b();
    let mut plan = UploadPlan::new(b.view(), 2, 64);
    let mut scratch = vec![0u8; MAX_CHUNK_BYTES];
    for _ in 0..2 {
        let m = plan.next(&mut scratch).unwrap();
        host.send(&m);
    }
    let mut cut = vec![0u8; MAX_FRAME_LEN];
    let n = encode(
        &HostMessage::PixelRows {
            frame: 59,
            first_pixel: 700,
            pixels: &[1; 200],
        },
        &mut cut,
    )
    .unwrap()
    .len();
    host.send_raw(&cut[..n / 2]);
    host.send_raw(&[0]);
    host.send(&HostMessage::hello(0xB0B));
    host.send(&HostMessage::StatusRequest);
    run(&mut device);
    let replies = host.replies();
    let at = replies
        .iter()
        .position(|r| matches!(r, Reply::Hello { session: 0xB0B, .. }))
        .expect("HelloReply to the new session");
    assert_eq!(
        errors(&replies[..at]),
        [DeviceError::Decode],
        "only the cut message is reported, before the new session"
    );
    let [Reply::Status(s)] = &replies[at + 1..] else {
        panic!(
            "after the HelloReply, only the Status: {:?}",
            &replies[at + 1..]
        )
    };
    assert_eq!(s.session, Some(0xB0B));
    assert_eq!(s.upload_id, None, "the dead client's upload is discarded");
    assert_eq!(s.config_id, Some(1), "the configuration stays");
    assert_eq!(s.frames_processed, before.frames_processed + 2);
    assert_eq!(s.frames_dropped, before.frames_dropped + 1, "frame 59");
    assert_eq!(s.decode_errors, before.decode_errors + 1);
    // Its frames verify as if the device had just been configured (the
    // level filters restarted), and nothing else arrives.
    for (k, f) in frames[3..].iter().enumerate() {
        host.frame(k as u32, f, 480);
    }
    run(&mut device);
    let replies = host.replies();
    assert_eq!(errors(&replies), []);
    for (k, want) in expected.iter().enumerate() {
        expect_verified(&replies, k as u32, want);
    }
    assert!(
        replies.iter().all(|r| match r {
            Reply::Slopes { frame, .. } | Reply::FrameDone { frame, .. } => *frame < 3,
            _ => false,
        }),
        "{replies:?}"
    );
}

/// A `Hello` of another protocol (another client that will give up) is
/// answered and changes nothing: the session in progress goes on.
#[test]
fn a_mismatched_hello_does_not_end_the_session() {
    let a = config_a();
    let frames = frames(CAMERA, 1, 9);
    let expected = direct(a.view(), &frames);
    let (mut storage, mut host, link) = setup(SIZES, 64);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    host.hello();
    configure(&mut host, &mut device, a.view(), 1);
    let half = frames[0].len() / 2;
    host.frame(0, &frames[0][..half], 100);
    host.send(&HostMessage::Hello {
        protocol: Hello {
            version: PROTOCOL_VERSION + 1,
            schema: 42,
        },
        session: 77,
    });
    host.frame_from(0, &frames[0], half, 100);
    host.send(&HostMessage::StatusRequest);
    run(&mut device);
    let replies = host.replies();
    assert_eq!(errors(&replies), []);
    assert!(replies
        .iter()
        .any(|r| matches!(r, Reply::Hello { session: 77, .. })));
    expect_verified(&replies, 0, &expected[0]);
    let Some(Reply::Status(s)) = replies.last() else {
        panic!("{replies:?}")
    };
    assert_eq!((s.session, s.frames_dropped), (Some(1), 0));
}

#[test]
fn streamed_slopes_equal_a_direct_engine_run() {
    let owned = config_filtered();
    let config = owned.view();
    let frames = frames(CAMERA, 12, 1);
    let expected = direct(config, &frames);
    let (mut storage, mut host, link) = setup(SIZES, 61);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    host.hello();
    run(&mut device);
    host.replies();
    configure(&mut host, &mut device, config, 11);
    // Message sizes that cut rows anywhere.
    for (k, f) in frames.iter().enumerate() {
        host.frame(100 + k as u32, f, [37, 48, 480, 1][k % 4]);
    }
    run(&mut device);
    let replies = host.replies();
    assert_eq!(errors(&replies), []);
    for (k, want) in expected.iter().enumerate() {
        expect_verified(&replies, 100 + k as u32, want);
        // One message per finished row of sub-apertures: the host sees each
        // row as soon as its last camera row arrives.
        assert_eq!(slopes_of(&replies, 100 + k as u32).1, 4);
    }
    let s = status(&mut host, &mut device);
    assert_eq!(s.frames_processed, 12);
    assert_eq!(s.config_id, Some(11));
    assert_eq!((s.crc_errors, s.decode_errors, s.frames_dropped), (0, 0, 0));
}

#[test]
fn a_long_row_of_results_is_split_into_messages() {
    let owned = Owned {
        camera: Camera {
            width: 160,
            height: 8,
            bit_depth: 16,
        },
        windows: grid(40, 1, 4, 8),
        ..config_a()
    };
    let config = owned.view();
    let frames = frames(owned.camera, 2, 5);
    let expected = direct(config, &frames);
    let (mut storage, mut host, link) = setup(SIZES, 1000);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    host.hello();
    configure(&mut host, &mut device, config, 1);
    for (k, f) in frames.iter().enumerate() {
        host.frame(k as u32, f, 480);
    }
    run(&mut device);
    let replies = host.replies();
    for (k, want) in expected.iter().enumerate() {
        expect_verified(&replies, k as u32, want);
        assert_eq!(slopes_of(&replies, k as u32).1, 2, "32 + 8 results");
    }
}

#[test]
fn failed_uploads_leave_the_previous_configuration_running() {
    let a = config_a();
    let b = config_b();
    let frames = frames(CAMERA, 2, 9);
    let with_a = direct(a.view(), &frames);
    let with_b = direct(b.view(), &frames);
    assert_ne!(with_a, with_b);
    let (mut storage, mut host, link) = setup(SIZES, 300);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    host.hello();
    configure(&mut host, &mut device, a.view(), 1);

    let b_header = ConfigHeader::of(&b.view());
    let mut chunk = vec![0u8; 96];
    let n = write_table(&b.view(), Table::Windows, 0, &mut chunk);
    let windows_chunk = &chunk[..n];
    let begin = |id| HostMessage::ConfigBegin {
        upload_id: id,
        header: b_header,
    };
    let first_chunk = |id| HostMessage::ConfigChunk {
        upload_id: id,
        table: Table::Windows,
        offset: 0,
        bytes: windows_chunk,
    };
    let verify = |host: &mut Host,
                  device: &mut Device<'_, Link, LinkOnly>,
                  scenario: &str,
                  expected_error: Option<DeviceError>| {
        run(device);
        let replies = host.replies();
        let errs = errors(&replies);
        match expected_error {
            Some(e) => assert!(errs.contains(&e), "{scenario}: {replies:?}"),
            None => assert_eq!(errs, [], "{scenario}"),
        }
        host.frame(7, &frames[0], 480);
        host.frame(8, &frames[1], 200);
        run(device);
        let replies = host.replies();
        expect_verified(&replies, 7, &with_a[0]);
        expect_verified(&replies, 8, &with_a[1]);
        assert_eq!(status(host, device).config_id, Some(1), "{scenario}");
    };

    // Begin + a chunk, then Abort.
    host.send(&begin(2));
    host.send(&first_chunk(2));
    host.send(&HostMessage::ConfigAbort);
    verify(&mut host, &mut device, "abort", None);

    // Begin + a chunk, then a new Begin, then a commit of the incomplete one.
    host.send(&begin(3));
    host.send(&first_chunk(3));
    host.send(&begin(4));
    host.send(&first_chunk(4));
    host.send(&HostMessage::ConfigCommit {
        upload_id: 4,
        crc32: 0,
    });
    verify(
        &mut host,
        &mut device,
        "incomplete",
        Some(DeviceError::UploadIncomplete {
            table: Table::Windows,
            received: 96,
            expected: 16 * 8,
        }),
    );

    // A chunk for the replaced upload id, then one out of order.
    host.send(&begin(5));
    host.send(&first_chunk(4));
    host.send(&HostMessage::ConfigChunk {
        upload_id: 5,
        table: Table::Windows,
        offset: 8,
        bytes: &windows_chunk[..8],
    });
    host.send(&HostMessage::ConfigCommit {
        upload_id: 5,
        crc32: 0,
    });
    run(&mut device);
    let replies = host.replies();
    assert_eq!(
        errors(&replies),
        [
            DeviceError::UploadMismatch {
                expected: 5,
                found: 4
            },
            DeviceError::ChunkOutOfOrder {
                expected: Some(TablePosition {
                    table: Table::Windows,
                    offset: 0
                }),
                found: TablePosition {
                    table: Table::Windows,
                    offset: 8
                },
            },
            DeviceError::NoUpload,
        ]
    );
    verify(&mut host, &mut device, "out of order", None);

    // A complete upload with a wrong CRC.
    let mut plan = UploadPlan::new(b.view(), 6, 500);
    let mut scratch = vec![0u8; MAX_CHUNK_BYTES];
    while let Some(m) = plan.next(&mut scratch) {
        match m {
            HostMessage::ConfigCommit { upload_id, crc32 } => {
                host.send(&HostMessage::ConfigCommit {
                    upload_id,
                    crc32: crc32 ^ 0x100,
                })
            }
            m => host.send(&m),
        }
    }
    let crc = brightpix_protocol::wire::tables::config_digest(&b.view());
    verify(
        &mut host,
        &mut device,
        "bad crc",
        Some(DeviceError::UploadCrc {
            computed: crc,
            claimed: crc ^ 0x100,
        }),
    );

    // A complete, intact upload of an invalid configuration.
    let mut invalid = config_b();
    invalid.windows[3].x = 40; // 40 + 12 > 48
    host.upload(invalid.view(), 7, MAX_CHUNK_BYTES);
    verify(
        &mut host,
        &mut device,
        "invalid",
        Some(DeviceError::Config(ConfigFault::WindowOutsideCamera {
            index: 3,
        })),
    );

    // A valid configuration that does not fit the engine's memory: 80 windows
    // open at once (SIZES.open_windows is 64).
    let wide = Owned {
        camera: Camera {
            width: 160,
            height: 32,
            bit_depth: 12,
        },
        windows: grid(80, 1, 2, 32),
        ..config_a()
    };
    host.upload(wide.view(), 8, MAX_CHUNK_BYTES);
    verify(
        &mut host,
        &mut device,
        "memory",
        Some(DeviceError::Config(
            ConfigError::MemoryBudget {
                needed: 80,
                available: 64,
                what: MemoryKind::OpenWindows,
            }
            .into(),
        )),
    );

    // Larger than the device's tables.
    let mut huge = config_a();
    huge.camera = Camera {
        width: 1024,
        height: 1024,
        bit_depth: 12,
    };
    huge.background = Some(vec![0; 1024 * 1024]);
    host.upload(huge.view(), 9, MAX_CHUNK_BYTES);
    verify(
        &mut host,
        &mut device,
        "capacity",
        Some(DeviceError::Capacity {
            what: CapacityKind::CameraPixels,
            needed: 1024 * 1024,
            available: SIZES.map_pixels as u32,
        }),
    );

    // And finally B, intact: it replaces A.
    configure(&mut host, &mut device, b.view(), 10);
    host.frame(1, &frames[0], 480);
    host.frame(2, &frames[1], 33);
    run(&mut device);
    let replies = host.replies();
    expect_verified(&replies, 1, &with_b[0]);
    expect_verified(&replies, 2, &with_b[1]);
}

#[test]
fn a_failed_commit_mid_frame_does_not_disturb_the_frame() {
    let a = config_filtered();
    let frames = frames(CAMERA, 3, 17);
    let expected = direct(a.view(), &frames);
    let (mut storage, mut host, link) = setup(SIZES, 64);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    host.hello();
    configure(&mut host, &mut device, a.view(), 1);
    host.frame(0, &frames[0], 480);
    // Half of frame 1, a whole upload that fails validation, the other half.
    let half = frames[1].len() / 2;
    host.frame(1, &frames[1][..half], 100);
    let mut invalid = config_b();
    let PixelCounts::PerSubaperture(list) = &mut invalid.pixels else {
        unreachable!("config_b has N per sub-aperture")
    };
    list[2] = 0;
    host.upload(invalid.view(), 2, 256);
    host.frame_from(1, &frames[1], half, 100);
    host.frame(2, &frames[2], 480);
    run(&mut device);
    let replies = host.replies();
    assert_eq!(
        errors(&replies),
        [DeviceError::Config(ConfigFault::PixelCountZero {
            index: 2
        })]
    );
    for (k, want) in expected.iter().enumerate() {
        expect_verified(&replies, k as u32, want);
    }
}

#[test]
fn a_successful_commit_mid_frame_drops_that_frame() {
    let a = config_a();
    let b = config_b();
    let frames = frames(CAMERA, 2, 23);
    let with_b = direct(b.view(), &frames[1..]);
    let (mut storage, mut host, link) = setup(SIZES, 64);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    host.hello();
    configure(&mut host, &mut device, a.view(), 1);
    host.frame(0, &frames[0][..500], 100);
    host.upload(b.view(), 2, MAX_CHUNK_BYTES);
    host.frame_from(0, &frames[0], 500, 100); // the rest of the dropped frame: ignored
    host.frame(1, &frames[1], 480);
    run(&mut device);
    let replies = host.replies();
    assert_eq!(
        errors(&replies),
        [DeviceError::Frame {
            frame: 0,
            fault: FrameFault::Reconfigured
        }]
    );
    expect_verified(&replies, 1, &with_b[0]);
    let s = status(&mut host, &mut device);
    assert_eq!(
        (s.frames_dropped, s.frames_processed, s.config_id),
        (1, 1, Some(2))
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

#[test]
fn a_corrupted_frame_is_counted_and_the_next_frame_verifies() {
    let a = config_a();
    let frames = frames(CAMERA, 3, 31);
    let expected = direct(a.view(), &frames);
    let (mut storage, mut host, link) = setup(SIZES, 97);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    host.hello();
    configure(&mut host, &mut device, a.view(), 1);
    // Frame 0 with its third PixelRows message corrupted on the link.
    let mut plan = PixelRowsPlan::new(0, &frames[0], 200);
    let mut scratch = vec![0u8; MAX_PIXEL_BYTES];
    let mut k = 0;
    while let Some(m) = plan.next(&mut scratch) {
        if k == 2 {
            host.send_raw(&with_bad_crc(&m));
        } else {
            host.send(&m);
        }
        k += 1;
    }
    host.frame(1, &frames[1], 200);
    // A random bit flip in frame 2's first message: caught as a CRC or
    // COBS/decode error, then frame 2 is resent whole as frame 3.
    let mut buf = vec![0u8; MAX_FRAME_LEN];
    let mut first = PixelRowsPlan::new(2, &frames[2], 200);
    let len = encode(&first.next(&mut scratch).unwrap(), &mut buf)
        .unwrap()
        .len();
    buf[len / 2] ^= if buf[len / 2] == 0x10 { 0x20 } else { 0x10 };
    host.send_raw(&buf[..len]);
    host.frame(3, &frames[2], 200);
    run(&mut device);
    let replies = host.replies();
    let errs = errors(&replies);
    assert_eq!(errs[0], DeviceError::Crc);
    assert_eq!(
        errs[1],
        DeviceError::Frame {
            frame: 0,
            fault: FrameFault::Gap {
                expected: 400,
                found: 600
            }
        }
    );
    assert!(matches!(errs[2], DeviceError::Crc | DeviceError::Decode));
    assert_eq!(errs.len(), 3, "{errs:?}");
    let (partial, _, done) = slopes_of(&replies, 0);
    assert_eq!(done, None, "the corrupted frame is not reported complete");
    // Results of the windows finished before the loss stand (SPEC.md §8).
    assert_eq!(
        partial,
        expected[0][..partial.len()]
            .iter()
            .map(entry)
            .collect::<Vec<_>>()
    );
    expect_verified(&replies, 1, &expected[1]);
    expect_verified(&replies, 3, &expected[2]);
    let s = status(&mut host, &mut device);
    assert_eq!(s.crc_errors + s.decode_errors, 2);
    assert_eq!(
        (s.frames_dropped, s.overruns, s.frames_processed),
        (1, 1, 2)
    );
}

#[test]
fn garbage_long_frames_and_bad_pixels_are_refused_without_harm() {
    let a = config_a();
    let frames = frames(CAMERA, 2, 41);
    let expected = direct(a.view(), &frames);
    let (mut storage, mut host, link) = setup(SIZES, 128);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    host.hello();
    configure(&mut host, &mut device, a.view(), 1);
    host.send_raw(&[1, 2, 3, 0]); // not COBS of a message
    host.send_raw(&[0x42; 3000]); // longer than any frame
    host.send_raw(&[0]);
    let mut bad = frames[0].clone();
    bad[5 * 48 + 7] = 4096; // 12-bit camera
    host.frame(0, &bad, 480);
    host.send(&HostMessage::PixelRows {
        frame: 9,
        first_pixel: 0,
        pixels: &[1, 2, 3],
    });
    host.send(&HostMessage::PixelRows {
        frame: 9,
        first_pixel: 1500,
        pixels: &[0; 200],
    });
    host.frame(1, &frames[1], 480);
    run(&mut device);
    let replies = host.replies();
    assert_eq!(
        errors(&replies),
        [
            DeviceError::Decode,
            DeviceError::FrameTooLong,
            DeviceError::Frame {
                frame: 0,
                fault: FrameFault::PixelOutOfRange {
                    row: 5,
                    column: 7,
                    value: 4096
                }
            },
            DeviceError::Frame {
                frame: 9,
                fault: FrameFault::OddLength
            },
            DeviceError::Frame {
                frame: 9,
                fault: FrameFault::Gap {
                    expected: 0,
                    found: 1500
                }
            },
        ]
    );
    expect_verified(&replies, 1, &expected[1]);
    let s = status(&mut host, &mut device);
    assert_eq!(
        (s.decode_errors, s.pixel_errors, s.frames_processed),
        (2, 1, 1)
    );
}

#[test]
fn unconfigured_device_refuses_pixels() {
    let (mut storage, mut host, link) = setup(SIZES, 128);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    host.hello();
    host.send(&HostMessage::PixelRows {
        frame: 0,
        first_pixel: 0,
        pixels: &[0; 8],
    });
    host.send(&HostMessage::ResetLevelFilters);
    host.send(&HostMessage::Capture {
        frames: 1,
        start: CaptureStart::Immediate,
        edge_rows: false,
    });
    run(&mut device);
    let replies = host.replies();
    assert_eq!(
        errors(&replies),
        [
            DeviceError::NotConfigured,
            DeviceError::NotConfigured,
            DeviceError::NoCamera
        ]
    );
}

#[test]
fn results_per_row_must_fit_the_queue() {
    let a = config_a(); // 6 windows end in each row of windows
    let (mut storage, mut host, link) = setup(
        Sizes {
            results_per_row: 5,
            ..SIZES
        },
        128,
    );
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    host.hello();
    host.upload(a.view(), 1, MAX_CHUNK_BYTES);
    run(&mut device);
    let replies = host.replies();
    assert_eq!(
        errors(&replies),
        [DeviceError::Capacity {
            what: CapacityKind::ResultsPerRow,
            needed: 6,
            available: 5
        }]
    );
}

#[test]
fn level_filters_reset_on_request() {
    let f = config_filtered();
    let frames = frames(CAMERA, 4, 51);
    let (mut storage, mut host, link) = setup(SIZES, 128);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    host.hello();
    configure(&mut host, &mut device, f.view(), 1);
    host.frame(0, &frames[0], 480);
    host.frame(1, &frames[1], 480);
    host.send(&HostMessage::ResetLevelFilters);
    host.frame(2, &frames[2], 480);
    host.frame(3, &frames[3], 480);
    run(&mut device);
    let replies = host.replies();
    assert_eq!(acks(&replies), [Ack::LevelFiltersReset]);
    let before = direct(f.view(), &frames[..2]);
    let after = direct(f.view(), &frames[2..]);
    expect_verified(&replies, 0, &before[0]);
    expect_verified(&replies, 1, &before[1]);
    expect_verified(&replies, 2, &after[0]);
    expect_verified(&replies, 3, &after[1]);
}

// --- a device with its own camera --------------------------------------------------

/// A camera that delivers `frames` a row at a time once started, then
/// closes the link. With a sync line it arms on the first poll after its
/// start (as a simulated camera's producer does, later than the request),
/// and records how many bytes the device had sent by then.
struct TestCamera {
    frames: Vec<Vec<u16>>,
    width: usize,
    started: bool,
    next: usize,
    link: Rc<RefCell<LinkState>>,
    sync_line: bool,
    start: CaptureStart,
    armed: bool,
    /// The device's output when the camera armed.
    sent_before_arming: Option<Vec<u8>>,
}

impl TestCamera {
    fn new(frames: Vec<Vec<u16>>, link: Rc<RefCell<LinkState>>, sync_line: bool) -> Self {
        TestCamera {
            frames,
            width: CAMERA.width as usize,
            started: false,
            next: 0,
            link,
            sync_line,
            start: CaptureStart::Immediate,
            armed: false,
            sent_before_arming: None,
        }
    }
}

impl PixelSource for TestCamera {
    fn kind(&self) -> PixelSourceKind {
        PixelSourceKind::Camera
    }

    fn set_start(&mut self, start: CaptureStart) -> Result<(), SyncFault> {
        if start != CaptureStart::Immediate && !self.sync_line {
            return Err(SyncFault::NoSyncLine);
        }
        self.start = start;
        Ok(())
    }

    fn armed(&self) -> bool {
        self.armed
    }

    fn start(&mut self, camera: Camera, _crop: Option<Crop>) -> Result<(), CameraRefused> {
        if camera.width as usize != self.width {
            return Err(CameraRefused);
        }
        self.started = true;
        self.armed = self.start == CaptureStart::Immediate;
        Ok(())
    }

    fn stop(&mut self) {
        self.started = false;
        self.link.borrow_mut().closed = true;
    }

    async fn next(&mut self) -> PixelRun<'_> {
        if self.started && !self.armed {
            self.armed = true;
            self.sent_before_arming = Some(self.link.borrow().output.clone());
            return PixelRun {
                frame: 0,
                first_pixel: 0,
                pixels: &[],
                began: None,
            };
        }
        let frame_len = self.frames[0].len();
        std::future::poll_fn(|_| {
            if self.started && self.next < self.frames.len() * frame_len {
                Poll::Ready(())
            } else {
                Poll::Pending
            }
        })
        .await;
        let (f, p) = (self.next / frame_len, self.next % frame_len);
        let began = (self.next == 0).then_some(CaptureBegin {
            synced: self.start != CaptureStart::Immediate,
            camera_frame: Some(41),
        });
        self.next += self.width;
        PixelRun {
            frame: f as u32,
            first_pixel: p as u32,
            pixels: &self.frames[f][p..p + self.width],
            began,
        }
    }
}

#[test]
fn capture_from_a_camera_streams_slopes() {
    let a = config_filtered();
    let frames = frames(CAMERA, 5, 61);
    let expected = direct(a.view(), &frames[..3]);
    let (mut storage, mut host, link) = setup(SIZES, 128);
    let camera = TestCamera::new(frames.clone(), host.link.clone(), false);
    let mut device = Device::new(link, camera, storage.buffers(), "cam");
    host.hello();
    host.upload(a.view(), 1, MAX_CHUNK_BYTES);
    host.send(&HostMessage::Capture {
        frames: 3,
        start: CaptureStart::Immediate,
        edge_rows: true,
    });
    host.send(&HostMessage::PixelRows {
        frame: 0,
        first_pixel: 0,
        pixels: &[0; 2],
    });
    // The camera stops the link when the capture ends.
    host.link.borrow_mut().closed = false;
    run(&mut device);
    let replies = host.replies();
    assert_eq!(
        errors(&replies),
        [DeviceError::Unexpected {
            message: brightpix_protocol::wire::MessageKind::PixelRows
        }]
    );
    let acks = acks(&replies);
    assert!(acks.contains(&Ack::CaptureStarted { frames: 3 }));
    assert_eq!(acks.last(), Some(&Ack::CaptureStopped { frames: 3 }));
    for (k, want) in expected.iter().enumerate() {
        expect_verified(&replies, k as u32, want);
    }
    assert!(
        slopes_of(&replies, 3).0.is_empty(),
        "no frame after the capture"
    );
    // How the capture began, once, after the acknowledgement and before
    // any result.
    let began: Vec<usize> = (0..replies.len())
        .filter(|&k| matches!(replies[k], Reply::Began { .. }))
        .collect();
    assert_eq!(began.len(), 1, "{replies:?}");
    assert_eq!(
        replies[began[0]],
        Reply::Began {
            synced: false,
            camera_frame: Some(41)
        }
    );
    let first_result = replies
        .iter()
        .position(|r| matches!(r, Reply::Slopes { .. }))
        .unwrap();
    let ack = replies
        .iter()
        .position(|r| *r == Reply::Ack(Ack::CaptureStarted { frames: 3 }))
        .unwrap();
    assert!(ack < began[0] && began[0] < first_result, "{replies:?}");
    // Asked for: each frame's first and last rows' checksums, just before
    // its FrameDone.
    let width = CAMERA.width as usize;
    for (k, frame) in frames[..3].iter().enumerate() {
        let row = |r: usize| {
            edge_row_checksum(edge_row_update(
                EDGE_ROW_SEED,
                &frame[r * width..(r + 1) * width],
            ))
        };
        let edge = Reply::EdgeRows {
            frame: k as u32,
            first: row(0),
            last: row(CAMERA.height as usize - 1),
        };
        let at = replies.iter().position(|r| *r == edge);
        let done = replies
            .iter()
            .position(|r| matches!(r, Reply::FrameDone { frame, .. } if *frame == k as u32));
        assert!(at.is_some() && at < done, "frame {k}: {replies:?}");
    }
    assert_ne!(frames[0][..width], frames[1][..width]);
}

/// On the sync line: refused by a camera without one; with one, the
/// device acknowledges `Capture` only once the camera is armed (so a host
/// can then release the leader), and says the capture began on the edge.
#[test]
fn a_capture_on_the_sync_line_is_acknowledged_once_armed() {
    let a = config_filtered();
    let frames = frames(CAMERA, 2, 62);
    let expected = direct(a.view(), &frames);
    for start in [CaptureStart::OnSync, CaptureStart::DriveSync] {
        let (mut storage, mut host, link) = setup(SIZES, 128);
        let camera = TestCamera::new(frames.clone(), host.link.clone(), false);
        let mut device = Device::new(link, camera, storage.buffers(), "cam");
        host.hello();
        host.upload(a.view(), 1, MAX_CHUNK_BYTES);
        host.send(&HostMessage::Capture {
            frames: 2,
            start,
            edge_rows: false,
        });
        run(&mut device);
        let replies = host.replies();
        assert_eq!(
            errors(&replies),
            [DeviceError::Sync(SyncFault::NoSyncLine)],
            "{start:?}"
        );
        assert!(!acks(&replies).contains(&Ack::CaptureStarted { frames: 2 }));

        let (mut storage, mut host, link) = setup(SIZES, 128);
        let camera = TestCamera::new(frames.clone(), host.link.clone(), true);
        let mut device = Device::new(link, camera, storage.buffers(), "cam");
        host.hello();
        host.upload(a.view(), 1, MAX_CHUNK_BYTES);
        host.send(&HostMessage::Capture {
            frames: 2,
            start,
            edge_rows: false,
        });
        host.link.borrow_mut().closed = false;
        run(&mut device);
        let replies = host.replies();
        assert!(errors(&replies).is_empty(), "{replies:?}");
        assert_eq!(
            acks(&replies)[4..],
            [
                Ack::CaptureStarted { frames: 2 },
                Ack::CaptureStopped { frames: 2 }
            ]
        );
        assert!(replies.contains(&Reply::Began {
            synced: true,
            camera_frame: Some(41)
        }));
        // Not asked for: no edge rows.
        assert!(!replies.iter().any(|r| matches!(r, Reply::EdgeRows { .. })));
        for (k, want) in expected.iter().enumerate() {
            expect_verified(&replies, k as u32, want);
        }
        // Nothing acknowledged the capture before the camera armed.
        let before = device.source().sent_before_arming.clone().unwrap();
        let mut reader = FrameReader::new(vec![0u8; MAX_FRAME_LEN]);
        let mut rest = &before[..];
        while !rest.is_empty() {
            let n = reader.push(rest);
            rest = &rest[n..];
            while let Some(Received::Frame(f)) = reader.next_frame() {
                let m = decode::<DeviceMessage>(f).unwrap();
                assert!(
                    !matches!(m, DeviceMessage::Ack(Ack::CaptureStarted { .. })),
                    "acknowledged before armed"
                );
            }
        }
    }
}

/// A byte stream that closes the link when it runs dry.
struct StreamReader {
    data: VecDeque<u8>,
    link: Rc<RefCell<LinkState>>,
}

impl ErrorType for StreamReader {
    type Error = Infallible;
}

impl Read for StreamReader {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        let n = buf.len().min(self.data.len()).min(333);
        for b in &mut buf[..n] {
            *b = self.data.pop_front().unwrap();
        }
        if n == 0 {
            self.link.borrow_mut().closed = true;
        }
        Ok(n)
    }
}

#[test]
fn pixels_from_a_separate_stream() {
    let a = config_filtered();
    let frames = frames(CAMERA, 4, 71);
    let expected = direct(a.view(), &frames);
    let (mut storage, mut host, link) = setup(SIZES, 128);
    // The stream: PixelRows frames, with some noise a host might leave in a file.
    let mut data = Vec::new();
    for (k, f) in frames.iter().enumerate() {
        let mut plan = PixelRowsPlan::new(k as u32, f, 300);
        let mut scratch = vec![0u8; MAX_PIXEL_BYTES];
        let mut buf = vec![0u8; MAX_FRAME_LEN];
        while let Some(m) = plan.next(&mut scratch) {
            data.extend_from_slice(encode(&m, &mut buf).unwrap());
        }
        data.extend_from_slice(&[0, 0x33, 0x44, 0]); // ignored
    }
    let mut frame_buffer = vec![0u8; MAX_FRAME_LEN];
    let mut pixels = vec![0u16; MAX_PIXEL_BYTES / 2];
    let stream = PixelRowsStream::new(
        StreamReader {
            data: data.into(),
            link: host.link.clone(),
        },
        &mut frame_buffer,
        &mut pixels,
    );
    let mut device = Device::new(link, stream, storage.buffers(), "stream");
    host.hello();
    host.upload(a.view(), 1, MAX_CHUNK_BYTES);
    host.link.borrow_mut().closed = false;
    run(&mut device);
    let replies = host.replies();
    assert!(matches!(
        &replies[0],
        Reply::Hello {
            source: PixelSourceKind::Stream,
            ..
        }
    ));
    assert_eq!(errors(&replies), []);
    for (k, want) in expected.iter().enumerate() {
        expect_verified(&replies, k as u32, want);
    }
    assert_eq!(device.source().skipped, 4);
}

// --- random configurations and frames ------------------------------------------------

fn sizes_for(config: &Config<'_>) -> Sizes {
    let n = config.windows.len();
    let engine = brightpix::engine_runner::EngineBuffers::needed(config).unwrap_or_default();
    Sizes {
        subapertures: n,
        map_pixels: config.camera.pixel_count(),
        open_windows: n,
        pool_entries: engine.pool_entries,
        history_pixels: engine.history_pixels,
        scratch_entries: engine.scratch_entries,
        results_per_row: n,
    }
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 256,
        max_shrink_iters: 500,
        ..ProptestConfig::default()
    })]

    /// Any configuration the differential tests generate, uploaded in
    /// chunks of any size and streamed in messages of any size, gives the
    /// engine's slopes.
    #[test]
    fn device_matches_the_engine_on_random_cases(
        (case, frames, chunks) in case(),
        chunk in 8usize..=960,
        max_read in 1usize..=300,
    ) {
        let config = case.view();
        let expected = direct(config, &frames);
        let (mut storage, mut host, link) = setup(sizes_for(&config), max_read);
        let mut device = Device::new(link, LinkOnly, storage.buffers(), "prop");
        host.hello();
        host.upload(config, 3, chunk);
        for (k, f) in frames.iter().enumerate() {
            host.frame(k as u32, f, chunks[k % chunks.len()]);
        }
        run(&mut device);
        let replies = host.replies();
        prop_assert_eq!(errors(&replies), []);
        for (k, want) in expected.iter().enumerate() {
            // Windows that end in the same camera row may come in another
            // order when pixels arrive in other chunks (the engine emits a
            // pushed run's windows by first column): compare by index.
            let (mut got, _, done) = slopes_of(&replies, k as u32);
            let mut want: Vec<SlopeEntry> = want.iter().map(entry).collect();
            got.sort_by_key(|e| e.index);
            want.sort_by_key(|e| e.index);
            prop_assert_eq!(&got, &want);
            prop_assert_eq!(done, Some(want.len() as u32));
        }
    }
}

// --- the watchdog ------------------------------------------------------------------

/// A watchdog that is due at every other poll, counting its feeds.
struct CountingWatchdog {
    feeds: Rc<RefCell<u32>>,
    ready: bool,
}

impl brightpix_firmware::device::Watchdog for CountingWatchdog {
    fn timeout_ms(&self) -> Option<u32> {
        Some(1000)
    }
    fn feed(&mut self) {
        *self.feeds.borrow_mut() += 1;
    }
    async fn due(&mut self) {
        std::future::poll_fn(|cx| {
            self.ready = !self.ready;
            if self.ready {
                Poll::Ready(())
            } else {
                cx.waker().wake_by_ref();
                Poll::Pending
            }
        })
        .await
    }
}

/// A link whose writes wait a while (a host that reads slowly).
struct SlowLink {
    inner: Link,
    stalls: Rc<RefCell<u32>>,
}

impl ErrorType for SlowLink {
    type Error = Infallible;
}

impl Read for SlowLink {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        self.inner.read(buf).await
    }
}

impl brightpix_firmware::device::embedded_io_async::Write for SlowLink {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        let mut waits = 3;
        std::future::poll_fn(|cx| {
            if waits == 0 {
                Poll::Ready(())
            } else {
                waits -= 1;
                *self.stalls.borrow_mut() += 1;
                cx.waker().wake_by_ref();
                Poll::Pending
            }
        })
        .await;
        self.inner.write(buf).await
    }
    async fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

/// The loop feeds its watchdog as it works and while a slow host makes it
/// wait, and `Status` reports the watchdog and the reset reason.
#[test]
fn the_device_loop_feeds_its_watchdog() {
    let a = config_a();
    let frames = frames(CAMERA, 2, 31);
    let expected = direct(a.view(), &frames);
    let (mut storage, mut host, link) = setup(SIZES, 64);
    let feeds = Rc::new(RefCell::new(0));
    let stalls = Rc::new(RefCell::new(0));
    let slow = SlowLink {
        inner: link,
        stalls: stalls.clone(),
    };
    let mut device =
        Device::new(slow, LinkOnly, storage.buffers(), "t").with_watchdog(CountingWatchdog {
            feeds: feeds.clone(),
            ready: false,
        });
    device.set_reset_reason(ResetReason::Watchdog);
    host.hello();
    host.upload(a.view(), 1, MAX_CHUNK_BYTES);
    for (k, f) in frames.iter().enumerate() {
        host.frame(k as u32, f, 480);
    }
    host.send(&HostMessage::StatusRequest);
    match block_on(device.run()) {
        Err(LinkError::Closed) => {}
        other => panic!("device stopped with {other:?}"),
    }
    let replies = host.replies();
    assert_eq!(errors(&replies), []);
    for (k, want) in expected.iter().enumerate() {
        expect_verified(&replies, k as u32, want);
    }
    let Some(Reply::Status(s)) = replies.last() else {
        panic!("{replies:?}")
    };
    assert_eq!(
        (s.watchdog_ms, s.reset_reason),
        (Some(1000), ResetReason::Watchdog)
    );
    // Every write stalled 3 polls, and the watchdog was due at every other
    // poll: it was fed during the waits as well as once per pass.
    let (feeds, stalls) = (*feeds.borrow(), *stalls.borrow());
    let messages = replies.len() as u32;
    assert!(
        stalls >= 3 * messages,
        "{stalls} stalls for {messages} messages"
    );
    assert!(feeds >= messages, "{feeds} feeds for {messages} messages");
}

// --- the bench request (PROTOCOL.md §14) ------------------------------------------

/// A board's bench mode that scribbles over all the memory the device lends
/// it (the engine's, the staging slot's tables), as a real bench does.
struct ScribblingBench {
    runs: Vec<(usize, u32)>,
}

impl brightpix_firmware::device::BenchRunner for ScribblingBench {
    fn workloads(&self) -> usize {
        2
    }

    fn name(&self, index: usize) -> &'static str {
        ["first", "second"][index]
    }

    fn max_frames(&self) -> u32 {
        8
    }

    fn run(
        &mut self,
        index: usize,
        frames: u32,
        memory: brightpix_firmware::device::BenchMemory<'_>,
    ) -> brightpix_protocol::wire::BenchReport<'static> {
        use brightpix_protocol::wire::{BenchLimit, BenchReport, BenchResult, CountUnit};
        self.runs.push((index, frames));
        memory.windows.fill(SubapertureWindow {
            x: 9999,
            y: 9999,
            width: 1,
            height: 1,
        });
        memory.background.fill(i32::MIN);
        memory.gain.fill(0xABCD);
        memory.engine.order.fill(u16::MAX);
        memory.engine.free.fill(u16::MAX);
        memory.engine.history.fill(0x5555);
        memory.engine.scratch.fill(-7);
        BenchReport {
            workload: self.name(index),
            unit: CountUnit::Cycles,
            clock_hz: Some(400_000_000),
            pixels: 100,
            frames,
            result: BenchResult::DoesNotFit {
                limit: BenchLimit::Pixels,
            },
        }
    }
}

/// The bench request: refused (and nothing changes) while a frame is in
/// progress, while an upload is, for an unknown workload or too many
/// frames, and by a device without a bench mode; otherwise one report per
/// workload and `Ack(BenchDone)`. A bench that overwrote every byte lent to
/// it leaves the configuration and its digest as they were, and the next
/// frames verify as after a fresh configuration (the level filters start
/// again, as PROTOCOL.md §14 says).
#[test]
fn a_bench_is_refused_while_streaming_and_keeps_the_configuration() {
    use brightpix_protocol::wire::BenchFault;
    let owned = config_filtered();
    let config = owned.view();
    let frames = frames(CAMERA, 6, 21);
    let mut bench = ScribblingBench { runs: Vec::new() };
    let (mut storage, mut host, link) = setup(SIZES, 64);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    device.set_bench(&mut bench);
    host.hello();
    configure(&mut host, &mut device, config, 1);
    let before = status(&mut host, &mut device);
    let bench_request = |workload, frames| HostMessage::Bench { workload, frames };

    // A frame in progress: refused, and the frame completes as if nothing
    // had been asked.
    let expected = direct(config, &frames[..2]);
    host.frame(0, &frames[0], 480);
    host.frame_from(1, &frames[1][..500], 0, 100);
    host.send(&bench_request("all", 0));
    host.frame_from(1, &frames[1], 500, 100);
    // An upload in progress: refused.
    let b = config_b();
    let mut plan = UploadPlan::new(b.view(), 2, 64);
    let mut scratch = vec![0u8; MAX_CHUNK_BYTES];
    let begin = plan.next(&mut scratch).unwrap();
    host.send(&begin);
    host.send(&bench_request("all", 0));
    host.send(&HostMessage::ConfigAbort);
    // Unknown workload, too many frames.
    host.send(&bench_request("third", 0));
    host.send(&bench_request("first", 9));
    run(&mut device);
    let replies = host.replies();
    expect_verified(&replies, 0, &expected[0]);
    expect_verified(&replies, 1, &expected[1]);
    assert_eq!(
        errors(&replies),
        [
            DeviceError::Bench(BenchFault::Streaming),
            DeviceError::Bench(BenchFault::UploadInProgress),
            DeviceError::Bench(BenchFault::UnknownWorkload),
            DeviceError::Bench(BenchFault::TooManyFrames { max: 8 }),
        ]
    );
    assert!(replies.iter().all(|r| !matches!(r, Reply::Bench(_))));

    // Every workload, then one by name.
    host.send(&bench_request("all", 0));
    host.send(&bench_request("second", 5));
    host.send(&HostMessage::StatusRequest);
    run(&mut device);
    let replies = host.replies();
    let names: Vec<(&str, u32)> = replies
        .iter()
        .filter_map(|r| match r {
            Reply::Bench(row) => Some((row.workload.as_str(), row.frames)),
            _ => None,
        })
        .collect();
    assert_eq!(names, [("first", 0), ("second", 0), ("second", 5)]);
    assert_eq!(
        acks(&replies),
        [
            Ack::BenchDone { workloads: 2 },
            Ack::BenchDone { workloads: 1 }
        ]
    );
    let Some(Reply::Status(after)) = replies.last() else {
        panic!("{replies:?}")
    };
    assert_eq!(after.config_id, before.config_id);
    assert_eq!(after.config_digest, before.config_digest);
    assert_eq!(after.frames_dropped, before.frames_dropped);

    // Streaming goes on, from a fresh engine.
    let expected = direct(config, &frames[2..]);
    for (k, f) in frames[2..].iter().enumerate() {
        host.frame(10 + k as u32, f, 480);
    }
    run(&mut device);
    let replies = host.replies();
    assert_eq!(errors(&replies), []);
    for (k, want) in expected.iter().enumerate() {
        expect_verified(&replies, 10 + k as u32, want);
    }
    drop(device);
    assert_eq!(bench.runs, [(0, 0), (1, 0), (1, 5)]);

    // A device without a bench mode says so.
    let (mut storage, mut host, link) = setup(SIZES, 64);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    host.hello();
    host.send(&bench_request("all", 0));
    run(&mut device);
    assert_eq!(
        errors(&host.replies()),
        [DeviceError::Bench(BenchFault::NotSupported)]
    );
}
