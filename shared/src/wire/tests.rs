extern crate std;

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

#[test]
fn every_host_message_round_trips() {
    let payload: Vec<u8> = (0..MAX_CHUNK_BYTES.max(MAX_PIXEL_BYTES))
        .map(|i| (i % 256) as u8)
        .collect();
    for message in host_examples(&payload) {
        let mut buf = Vec::new();
        assert_eq!(round_trip(&message, &mut buf), message);
    }
}

#[test]
fn every_device_message_round_trips() {
    for message in device_examples() {
        let mut buf = Vec::new();
        assert_eq!(round_trip(&message, &mut buf), message);
    }
}

#[test]
fn largest_messages_fit_the_message_limit() {
    let payload = vec![0xFFu8; MAX_CHUNK_BYTES.max(MAX_PIXEL_BYTES)];
    let mut plain = vec![0u8; 4 * MAX_MESSAGE_LEN];
    for message in host_examples(&payload) {
        let len = postcard::to_slice(&message, &mut plain).unwrap().len();
        assert!(len <= MAX_MESSAGE_LEN, "{:?}: {len} bytes", message.kind());
    }
    for message in device_examples() {
        let len = postcard::to_slice(&message, &mut plain).unwrap().len();
        assert!(len <= MAX_MESSAGE_LEN, "{message:?}: {len} bytes");
    }
}

#[test]
fn config_errors_convert_without_loss() {
    let e = ConfigError::MemoryBudget {
        needed: 6400,
        available: 80,
        what: MemoryKind::SelectionEntries,
    };
    let fault = ConfigFault::from(e);
    assert_eq!(ConfigError::from(fault), e);
    assert_eq!(std::format!("{fault}"), std::format!("{e}"));
}

#[test]
fn crc_is_iso_hdlc() {
    assert_eq!(CRC32.checksum(b"123456789"), 0xCBF4_3926);
}

/// The worked examples of PROTOCOL.md, byte for byte.
#[test]
fn encoding_is_as_documented() {
    let frame = |m: &dyn Fn(&mut [u8]) -> usize| {
        let mut buf = [0u8; 64];
        let n = m(&mut buf);
        buf[..n].to_vec()
    };
    let enc_host = |m: HostMessage<'static>| frame(&move |b| encode(&m, b).unwrap().len());
    let enc_device = |m: DeviceMessage<'static>| frame(&move |b| encode(&m, b).unwrap().len());
    assert_eq!(
        enc_host(HostMessage::StatusRequest),
        [0x06, 0x05, 0x02, 0x1b, 0x68, 0xa2, 0x00]
    );
    assert_eq!(
        enc_host(HostMessage::Capture {
            frames: 0,
            start: CaptureStart::Immediate,
            edge_rows: false,
        }),
        [0x02, 0x08, 0x01, 0x01, 0x05, 0xf3, 0xf7, 0xf0, 0xe4, 0x00]
    );
    assert_eq!(
        enc_host(HostMessage::Hello {
            protocol: Hello {
                version: 5,
                schema: 300
            },
            session: 7
        }),
        [0x01, 0x09, 0x05, 0xac, 0x02, 0x07, 0x0a, 0x54, 0xcc, 0x8d, 0x00]
    );
    assert_eq!(
        enc_device(DeviceMessage::FrameDone {
            frame: 3,
            count: 24
        }),
        [0x08, 0x05, 0x03, 0x18, 0x6c, 0xd0, 0xcb, 0xc1, 0x00]
    );
    let mut results = SlopeList::new();
    results
        .push(SlopeEntry {
            index: 7,
            slope_x: -65536,
            slope_y: 32768,
            flux: 1000,
            valid: true,
        })
        .unwrap();
    assert_eq!(
        enc_device(DeviceMessage::Slopes { frame: 3, results }),
        [
            0x12, 0x04, 0x03, 0x01, 0x07, 0xff, 0xff, 0x07, 0x80, 0x80, 0x04, 0xd0, 0x0f, 0x01,
            0x0a, 0x24, 0x80, 0x6c, 0x00
        ]
    );
    // The body of a frame is the postcard encoding, then the CRC (LE).
    let mut buf = [0u8; 64];
    let len = encode(&HostMessage::StatusRequest, &mut buf).unwrap().len();
    assert_eq!(unstuff(&mut buf[..len - 1]).unwrap(), [0x05]);
    // A HelloReply of this build: its frozen prefix reads back.
    let reply = &device_examples()[0];
    let len = encode(reply, &mut [0u8; MAX_FRAME_LEN][..]).unwrap().len();
    let mut buf = vec![0u8; MAX_FRAME_LEN];
    encode(reply, &mut buf).unwrap();
    assert_eq!(hello_prefix(&mut buf[..len - 1]), Some(Hello::CURRENT));
}

#[test]
fn random_bytes_never_panic() {
    let mut rng = Rng(0x5EED_1234_5678_9ABC);
    let mut reader = FrameReader::new(vec![0u8; MAX_FRAME_LEN]);
    let mut frames = 0;
    for _ in 0..20_000 {
        let len = rng.below(64) as usize + 1;
        let mut bytes = rng.bytes(len);
        // Make delimiters common enough to cut many frames.
        for b in bytes.iter_mut() {
            if rng.below(16) == 0 {
                *b = 0;
            }
        }
        let mut rest = &bytes[..];
        while !rest.is_empty() {
            let n = reader.push(rest);
            rest = &rest[n..];
            while let Some(received) = reader.next_frame() {
                if let Received::Frame(frame) = received {
                    frames += 1;
                    let mut copy = frame.to_vec();
                    let _ = decode::<HostMessage>(frame);
                    let _ = decode::<DeviceMessage>(&mut copy.clone());
                    let _ = hello_prefix(&mut copy);
                }
            }
        }
    }
    assert!(frames > 1000);
}

#[test]
fn random_bodies_with_valid_crc_never_panic() {
    // Past the CRC, so postcard's decoder sees every kind of garbage.
    let mut rng = Rng(42);
    let mut decoded = 0;
    for _ in 0..50_000 {
        let len = rng.below(40) as usize + 1;
        let mut body = rng.bytes(len);
        body[0] = rng.below(12) as u8; // plausible tags
        let crc = CRC32.checksum(&body).to_le_bytes();
        body.extend_from_slice(&crc);
        let mut frame = vec![0u8; cobs::max_encoding_length(body.len())];
        let n = cobs::encode(&body, &mut frame);
        frame.truncate(n);
        if decode::<HostMessage>(&mut frame.clone()).is_ok() {
            decoded += 1;
        }
        let _ = decode::<DeviceMessage>(&mut frame.clone());
        let _ = hello_prefix(&mut frame);
    }
    assert!(decoded > 0);
}

#[test]
fn corrupted_frames_are_rejected() {
    let mut rng = Rng(7);
    let payload = vec![0x55u8; MAX_PIXEL_BYTES];
    let examples = host_examples(&payload);
    let mut buf = vec![0u8; MAX_FRAME_LEN];
    for _ in 0..5_000 {
        let message = &examples[rng.below(examples.len() as u64) as usize];
        let frame = encode(message, &mut buf).unwrap();
        let len = frame.len() - 1;
        let mut frame = frame[..len].to_vec();
        // Flip 1..=3 bits, never creating a 0x00 (the reader would cut there).
        for _ in 0..=rng.below(3) {
            let i = rng.below(len as u64) as usize;
            let flipped = frame[i] ^ (1 << rng.below(8));
            if flipped != 0 {
                frame[i] = flipped;
            }
        }
        if let Ok(m) = decode::<HostMessage>(&mut frame) {
            assert_eq!(&m, message, "a corrupted frame decoded to another message");
        }
    }
}

/// The edge rows' checksum is FNV-1a 64 of the pixels as u16 LE, folded.
#[test]
fn edge_row_checksum_is_folded_fnv1a() {
    assert_eq!(EDGE_ROW_SEED, 0xcbf2_9ce4_8422_2325);
    let state = edge_row_update(EDGE_ROW_SEED, &[0x0201, 0x0403]);
    assert_eq!(state, fnv1a64(EDGE_ROW_SEED, &[1, 2, 3, 4]));
    assert_eq!(edge_row_checksum(state), (state ^ (state >> 32)) as u32);
    // Split anywhere, the same.
    let split = edge_row_update(edge_row_update(EDGE_ROW_SEED, &[0x0201]), &[0x0403]);
    assert_eq!(split, state);
    assert_ne!(
        edge_row_checksum(edge_row_update(EDGE_ROW_SEED, &[0x0403, 0x0201])),
        edge_row_checksum(state)
    );
}

#[test]
fn frame_reader_cuts_streams() {
    let messages = [
        HostMessage::StatusRequest,
        HostMessage::Capture {
            frames: 3,
            start: CaptureStart::OnSync,
            edge_rows: false,
        },
        HostMessage::ConfigAbort,
    ];
    let mut stream = vec![0u8]; // a leading delimiter is ignored
    for m in &messages {
        let mut buf = [0u8; 64];
        stream.extend_from_slice(encode(m, &mut buf).unwrap());
        stream.push(0); // empty frames are ignored
    }
    // Every split of the stream into two reads gives the same frames.
    for split in 0..stream.len() {
        let mut reader = FrameReader::new([0u8; 64]);
        let mut got = Vec::new();
        for part in [&stream[..split], &stream[split..]] {
            assert_eq!(reader.push(part), part.len());
            while let Some(Received::Frame(f)) = reader.next_frame() {
                got.push(decode::<HostMessage>(f).unwrap().kind());
            }
        }
        assert_eq!(got, messages.clone().map(|m| m.kind()));
        assert_eq!(reader.pending(), 0);
    }
}

#[test]
fn frame_reader_drops_long_frames_once() {
    let mut reader = FrameReader::new([0u8; 16]);
    let mut events = Vec::new();
    let mut feed = |reader: &mut FrameReader<[u8; 16]>, bytes: &[u8]| {
        let mut rest = bytes;
        while !rest.is_empty() {
            let n = reader.push(rest);
            rest = &rest[n..];
            while let Some(r) = reader.next_frame() {
                events.push(match r {
                    Received::Frame(f) => decode::<HostMessage>(f).ok().map(|m| m.kind()),
                    Received::TooLong => None,
                });
            }
        }
    };
    feed(&mut reader, &[0x11; 40]);
    feed(&mut reader, &[0x11, 0x00]);
    let mut buf = [0u8; 16];
    let good = encode(&HostMessage::StopCapture, &mut buf)
        .unwrap()
        .to_vec();
    feed(&mut reader, &good);
    assert_eq!(events, [None, Some(MessageKind::StopCapture)]);
}

#[test]
fn hello_prefix_reads_any_version() {
    // A future HelloReply: same frozen prefix, different everything else.
    #[derive(Serialize)]
    enum Future {
        HelloReply {
            version: u16,
            schema: u64,
            other: [u8; 3],
        },
    }
    let mut buf = [0u8; 64];
    let frame = encode(
        &Future::HelloReply {
            version: 9,
            schema: 0xDEAD_BEEF_0000_0001,
            other: [1, 2, 3],
        },
        &mut buf,
    )
    .unwrap();
    let len = frame.len() - 1;
    assert_eq!(
        hello_prefix(&mut buf[..len]),
        Some(Hello {
            version: 9,
            schema: 0xDEAD_BEEF_0000_0001
        })
    );
    let frame = encode(&DeviceMessage::Error(DeviceError::Crc), &mut buf).unwrap();
    let len = frame.len() - 1;
    assert_eq!(hello_prefix(&mut buf[..len]), None);
    let mismatch = VersionMismatch::check(Hello {
        version: 9,
        schema: 1,
    })
    .unwrap_err();
    let text = std::format!("{mismatch}");
    assert!(text.contains("protocol 9"), "{text}");
    assert!(VersionMismatch::check(Hello::CURRENT).is_ok());
}

// --- configuration digest -------------------------------------------------

#[test]
fn largest_header_encoding_fits() {
    let mut out = [0u8; ConfigHeader::MAX_ENCODED_LEN];
    let encoded = header().encode(&mut out);
    let mut big = [0u8; 256];
    assert_eq!(encoded, &*postcard::to_slice(&header(), &mut big).unwrap());
    assert!(
        encoded.len() < ConfigHeader::MAX_ENCODED_LEN,
        "{}",
        encoded.len()
    );
}

#[test]
fn uniform_background_travels_as_one_value() {
    let camera = crate::Camera {
        width: 4,
        height: 2,
        bit_depth: 12,
    };
    let windows = [SubapertureWindow {
        x: 0,
        y: 0,
        width: 2,
        height: 2,
    }];
    let uniform = [-48i32; 8];
    let mut varied = uniform;
    varied[7] = 0;
    let config = |background: Option<&'static [i32]>| Config {
        camera,
        windows: &windows,
        calibration: Calibration {
            background,
            gain: None,
            threshold: None,
        },
        selection: Selection {
            rule: crate::SelectionRule::SubtractNext,
            count: PixelCount::All(2),
            level_filter: None,
        },
        centroid: Centroid {
            min_flux: 0,
            reference_slopes: None,
        },
        crop: None,
    };
    let uniform: &'static [i32] = std::vec![-48i32; 8].leak();
    let varied: &'static [i32] = varied.to_vec().leak();
    assert_eq!(ConfigHeader::of(&config(None)).background, Background::None);
    let constant = ConfigHeader::of(&config(Some(uniform)));
    assert_eq!(constant.background, Background::Constant(-48));
    assert_eq!(constant.table_elements(Table::Background), None);
    let map = ConfigHeader::of(&config(Some(varied)));
    assert_eq!(map.background, Background::Map);
    assert_eq!(map.table_elements(Table::Background), Some(8));
    // The digest tells the three apart although the tables are the same size.
    let digests = [
        config_digest(&config(None)),
        config_digest(&config(Some(uniform))),
        config_digest(&config(Some(varied))),
    ];
    assert_ne!(digests[0], digests[1]);
    assert_ne!(digests[1], digests[2]);
}

// --- schema hash ----------------------------------------------------------

/// The pinned hash: a change of any message type changes SCHEMA_HASH and
/// fails this test, a reminder to update PROTOCOL.md (and, if a meaning
/// changed without a type change, PROTOCOL_VERSION).
#[test]
fn schema_hash_is_pinned() {
    assert_eq!(
        SCHEMA_HASH, PINNED_SCHEMA_HASH,
        "the wire schema changed: SCHEMA_HASH is now {SCHEMA_HASH:#018x}; update \
         PINNED_SCHEMA_HASH here and the value in shared/PROTOCOL.md"
    );
}

const PINNED_SCHEMA_HASH: u64 = 0x0089_76a2_63c0_2cbd;

fn hash_of<T: Schema + ?Sized>() -> u64 {
    u64::from_le_bytes(hash_ty_path::<T>(WIRE_CONVENTIONS))
}

#[test]
fn schema_hash_changes_with_any_type_change() {
    // Variants of a message, each one change away from `Base`.
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Base {
        A { x: u16, y: i32 },
        B,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Wider {
        A { x: u32, y: i32 },
        B,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Signed {
        A { x: i16, y: i32 },
        B,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Swapped {
        A { y: i32, x: u16 },
        B,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Renamed {
        A { x: u16, z: i32 },
        B,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum ExtraField {
        A { x: u16, y: i32, z: bool },
        B,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum ExtraVariant {
        A { x: u16, y: i32 },
        B,
        C,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Reordered {
        B,
        A { x: u16, y: i32 },
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Optional {
        A { x: Option<u16>, y: i32 },
        B,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    struct Inner {
        v: u8,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    struct InnerChanged {
        v: u16,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Nested {
        A { x: u16, y: i32 },
        B(Inner),
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum NestedChanged {
        A { x: u16, y: i32 },
        B(InnerChanged),
    }
    let hashes = [
        hash_of::<Base>(),
        hash_of::<Wider>(),
        hash_of::<Signed>(),
        hash_of::<Swapped>(),
        hash_of::<Renamed>(),
        hash_of::<ExtraField>(),
        hash_of::<ExtraVariant>(),
        hash_of::<Reordered>(),
        hash_of::<Optional>(),
        hash_of::<Nested>(),
        hash_of::<NestedChanged>(),
    ];
    for i in 0..hashes.len() {
        for j in 0..i {
            assert_ne!(hashes[i], hashes[j], "variants {i} and {j} hash alike");
        }
    }
}

#[test]
fn schema_covers_every_message_and_config_type() {
    // The hashed schema is derived from the message types themselves: every
    // variant of both enums is in it, with ConfigError's variants nested.
    let DataModelType::Enum(host) = HostMessage::SCHEMA.ty else {
        panic!("HostMessage is an enum")
    };
    assert_eq!(host.len(), 11);
    assert_eq!(host[0].name, "Hello");
    let DataModelType::Enum(device) = DeviceMessage::SCHEMA.ty else {
        panic!("DeviceMessage is an enum")
    };
    assert_eq!(device.len(), 9);
    assert_eq!(device[0].name, "HelloReply");
    let DataModelType::Enum(config_errors) = ConfigFault::SCHEMA.ty else {
        panic!()
    };
    assert!(config_errors.iter().any(|v| v.name == "MemoryBudget"));
    // The limits and conventions are part of the hash too.
    assert_ne!(
        SCHEMA_HASH,
        hash_of::<(HostMessage<'static>, DeviceMessage<'static>)>()
    );
}

// --- tables and upload plan ------------------------------------------------

struct Owned {
    windows: Vec<SubapertureWindow>,
    counts: Vec<u16>,
    background: Vec<i32>,
    gain: Vec<u16>,
    references: Vec<[i32; 2]>,
}

impl Owned {
    fn new() -> Self {
        let windows: Vec<_> = (0..50u16)
            .map(|k| SubapertureWindow {
                x: (k % 10) * 6,
                y: (k / 10) * 6,
                width: 6,
                height: 6,
            })
            .collect();
        Owned {
            counts: (0..50).map(|k| 1 + k % 7).collect(),
            background: (0..60 * 30).map(|k| k * 37 - 20_000).collect(),
            gain: (0..60 * 30).map(|k| (k * 13 % 65536) as u16).collect(),
            references: (0..50).map(|k| [k * 1000 - 7, -k * 999]).collect(),
            windows,
        }
    }
    fn config(&self) -> Config<'_> {
        Config {
            camera: Camera {
                width: 60,
                height: 30,
                bit_depth: 12,
            },
            windows: &self.windows,
            calibration: Calibration {
                background: Some(&self.background),
                gain: Some(&self.gain),
                threshold: Some(-5),
            },
            selection: Selection {
                rule: SelectionRule::SubtractNextDistinct,
                count: PixelCount::PerSubaperture(&self.counts),
                level_filter: Some(LevelFilter { gain_shift: 3 }),
            },
            centroid: Centroid {
                reference_slopes: Some(&self.references),
                min_flux: 12,
            },
            crop: None,
        }
    }
}

#[test]
fn upload_plan_rebuilds_the_configuration() {
    let owned = Owned::new();
    let config = owned.config();
    for chunk in [8, 100, 960, 5000] {
        let mut plan = UploadPlan::new(config, 77, chunk);
        let expected_count = plan.message_count();
        let mut scratch = vec![0u8; MAX_CHUNK_BYTES];
        let mut header = None;
        let mut tables: [Vec<u8>; 5] = Default::default();
        let mut commit = None;
        let mut count = 0;
        let mut last = (0usize, 0u32);
        while let Some(message) = plan.next(&mut scratch) {
            count += 1;
            // Through the wire and back.
            let mut buf = vec![0u8; MAX_FRAME_LEN];
            let len = encode(&message, &mut buf).unwrap().len() - 1;
            match decode::<HostMessage>(&mut buf[..len]).unwrap() {
                HostMessage::ConfigBegin {
                    upload_id,
                    header: h,
                } => {
                    assert_eq!(upload_id, 77);
                    header = Some(h);
                }
                HostMessage::ConfigChunk {
                    upload_id,
                    table,
                    offset,
                    bytes,
                } => {
                    assert_eq!(upload_id, 77);
                    assert!(bytes.len() <= MAX_CHUNK_BYTES);
                    assert_eq!(bytes.len() % table.element_size(), 0);
                    assert!((table.position(), offset) >= last, "chunks in order");
                    last = (table.position(), offset);
                    assert_eq!(offset as usize, tables[table.position()].len());
                    tables[table.position()].extend_from_slice(bytes);
                }
                HostMessage::ConfigCommit { upload_id, crc32 } => {
                    assert_eq!(upload_id, 77);
                    commit = Some(crc32);
                }
                other => panic!("unexpected {other:?}"),
            }
        }
        assert_eq!(count, expected_count);
        let header = header.unwrap();
        assert_eq!(header, ConfigHeader::of(&config));
        let mut encoded = [0u8; ConfigHeader::MAX_ENCODED_LEN];
        let mut all: Vec<u8> = header.encode(&mut encoded).to_vec();
        all.extend(tables.concat());
        assert_eq!(commit, Some(CRC32.checksum(&all)));
        assert_eq!(commit, Some(config_digest(&config)));
        let windows: Vec<_> = tables[0].chunks(8).map(read_window).collect();
        let counts: Vec<u16> = tables[1]
            .chunks(2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
            .collect();
        let background: Vec<i32> = tables[2]
            .chunks(4)
            .map(|b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        let mut gain = vec![0u16; tables[3].len() / 2];
        pixels_from_le(&tables[3], &mut gain);
        let references: Vec<_> = tables[4].chunks(8).map(read_reference_slope).collect();
        let rebuilt = header
            .config(TableSlices {
                windows: &windows,
                pixel_counts: &counts,
                background: &background,
                gain: &gain,
                reference_slopes: &references,
            })
            .unwrap();
        assert_eq!(rebuilt, config);
    }
}

#[test]
fn pixel_rows_plan_covers_the_frame() {
    let pixels: Vec<u16> = (0..1000u32).map(|k| (k * 977 % 65536) as u16).collect();
    let mut plan = PixelRowsPlan::new(5, &pixels, 300);
    let mut scratch = [0u8; MAX_PIXEL_BYTES];
    let mut out = Vec::new();
    while let Some(HostMessage::PixelRows {
        frame,
        first_pixel,
        pixels,
    }) = plan.next(&mut scratch)
    {
        assert_eq!(frame, 5);
        assert_eq!(first_pixel as usize, out.len());
        let mut decoded = vec![0u16; pixels.len() / 2];
        pixels_from_le(pixels, &mut decoded);
        out.extend(decoded);
    }
    assert_eq!(out, pixels);
}
