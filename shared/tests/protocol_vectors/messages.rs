//! The example messages the vectors are built from: every host message and
//! every device message, with every variant of every enum in them.

use brightpix_protocol::wire::*;
use brightpix_protocol::{
    Camera, ConfigError, Crop, LevelFilter, MapKind, MemoryKind, SelectionRule,
};

fn header(rule: SelectionRule, pixel_count: PixelCountMode) -> ConfigHeader {
    ConfigHeader {
        camera: Camera {
            width: 112,
            height: 112,
            bit_depth: 16,
        },
        windows: 49,
        rule,
        pixel_count,
        level_filter: None,
        threshold: None,
        min_flux: 0,
        background: Background::Map,
        gain: false,
        reference_slopes: false,
        crop: None,
    }
}

pub fn host_messages(payload: &[u8]) -> Vec<(&'static str, HostMessage<'_>)> {
    let mut all = vec![
        (
            "open a session (session id 0x1234abcd)",
            HostMessage::hello(0x1234_abcd),
        ),
        (
            "a Hello of another protocol version (the frozen prefix is what matters)",
            HostMessage::Hello {
                protocol: Hello {
                    version: 1,
                    schema: 300,
                },
                session: 7,
            },
        ),
        (
            "the CANARY header: subtract-next, N = 20, background map",
            HostMessage::ConfigBegin {
                upload_id: 0x0102_0304,
                header: header(SelectionRule::SubtractNext, PixelCountMode::All(20)),
            },
        ),
        (
            "every optional field present; N per sub-aperture",
            HostMessage::ConfigBegin {
                upload_id: 1,
                header: ConfigHeader {
                    level_filter: Some(LevelFilter { gain_shift: 4 }),
                    threshold: Some(-160),
                    min_flux: 1600,
                    gain: true,
                    reference_slopes: true,
                    ..header(
                        SelectionRule::SubtractMean { count: 3 },
                        PixelCountMode::PerSubaperture,
                    )
                },
            },
        ),
        (
            "a board of a rig: the 112x112 camera is the rectangle at (16, 48) of a 240x240 sensor",
            HostMessage::ConfigBegin {
                upload_id: 6,
                header: ConfigHeader {
                    crop: Some(Crop {
                        x: 16,
                        y: 48,
                        sensor_width: 240,
                        sensor_height: 240,
                    }),
                    ..header(SelectionRule::SubtractNext, PixelCountMode::All(20))
                },
            },
        ),
        (
            "a constant background of -3 counts (-48/16) as one value, no table",
            HostMessage::ConfigBegin {
                upload_id: 5,
                header: ConfigHeader {
                    background: Background::Constant(-48),
                    ..header(SelectionRule::SubtractNext, PixelCountMode::All(20))
                },
            },
        ),
    ];
    for (k, rule) in [
        SelectionRule::Threshold,
        SelectionRule::SubtractNextDistinct,
    ]
    .into_iter()
    .enumerate()
    {
        all.push((
            "another selection rule",
            HostMessage::ConfigBegin {
                upload_id: 2 + k as u32,
                header: header(rule, PixelCountMode::All(5)),
            },
        ));
    }
    let tables = [
        (
            "one window: x 0, y 16, 16 x 16 (8 bytes per element)",
            Table::Windows,
            0,
            &payload[..8],
        ),
        (
            "N of two sub-apertures (2 bytes each), from byte 98",
            Table::PixelCounts,
            98,
            &payload[..4],
        ),
        (
            "two background pixels (i32, 4 bytes each), from byte 960",
            Table::Background,
            960,
            &payload[..8],
        ),
        (
            "two gain pixels (u16), from byte 0",
            Table::Gain,
            0,
            &payload[..4],
        ),
        (
            "one reference slope pair (2 x i32)",
            Table::ReferenceSlopes,
            8,
            &payload[..8],
        ),
    ];
    for (what, table, offset, bytes) in tables {
        all.push((
            what,
            HostMessage::ConfigChunk {
                upload_id: 0x0102_0304,
                table,
                offset,
                bytes,
            },
        ));
    }
    all.extend([
        (
            "commit: the configuration's digest, CRC-32 of the header's encoding then every table's bytes (PROTOCOL.md §7)",
            HostMessage::ConfigCommit {
                upload_id: 0x0102_0304,
                crc32: 0xCBF4_3926,
            },
        ),
        ("", HostMessage::ConfigAbort),
        ("", HostMessage::StatusRequest),
        ("", HostMessage::ResetLevelFilters),
        (
            "pixels 112.. of frame 3: 0, 1, 256, 65535 (u16 little-endian)",
            HostMessage::PixelRows {
                frame: 3,
                first_pixel: 112,
                pixels: &[0x00, 0x00, 0x01, 0x00, 0x00, 0x01, 0xff, 0xff],
            },
        ),
        (
            "capture until StopCapture, from the next frame start",
            HostMessage::Capture {
                frames: 0,
                start: CaptureStart::Immediate,
                edge_rows: false,
            },
        ),
        (
            "capture 1000 frames from the first frame start after the sync line's next rising edge (a follower)",
            HostMessage::Capture {
                frames: 1000,
                start: CaptureStart::OnSync,
                edge_rows: false,
            },
        ),
        (
            "capture 1000 frames, raising the sync line after a frame start (the leader), with every frame's edge rows' checksums",
            HostMessage::Capture {
                frames: 1000,
                start: CaptureStart::DriveSync,
                edge_rows: true,
            },
        ),
        ("", HostMessage::StopCapture),
        (
            "every workload the board has, each its own count of frames",
            HostMessage::Bench {
                workload: "all",
                frames: 0,
            },
        ),
        (
            "one workload, 16 frames",
            HostMessage::Bench {
                workload: "canary-subtract-next-n20",
                frames: 16,
            },
        ),
        (
            "a million fill bytes, 256 a message",
            HostMessage::LinkTest {
                bytes: 1_000_000,
                chunk: 256,
            },
        ),
    ]);
    all
}

pub fn device_messages() -> Vec<(&'static str, DeviceMessage<'static>)> {
    let position = |table, offset| TablePosition { table, offset };
    let mut all = vec![
        (
            "the QEMU board's HelloReply to session 0x1234abcd",
            DeviceMessage::HelloReply(HelloReply {
                version: PROTOCOL_VERSION,
                schema: SCHEMA_HASH,
                session: 0x1234_abcd,
                capabilities: Capabilities {
                    max_subapertures: 6400,
                    max_camera_pixels: 65536,
                    max_open_windows: 256,
                    pool_entries: 69376,
                    history_pixels: 64 * 4096,
                    scratch_entries: 4096,
                    max_results_per_row: 1024,
                    max_frame_bytes: 1034,
                    pixel_source: PixelSourceKind::Link,
                    board: "qemu-mps2-an386",
                },
            }),
        ),
        (
            "a device with its own camera",
            DeviceMessage::HelloReply(HelloReply {
                version: PROTOCOL_VERSION,
                schema: SCHEMA_HASH,
                session: 1,
                capabilities: Capabilities {
                    max_subapertures: 1024,
                    max_camera_pixels: 0,
                    max_open_windows: 64,
                    pool_entries: 4096,
                    history_pixels: 16 * 240,
                    scratch_entries: 256,
                    max_results_per_row: 64,
                    max_frame_bytes: 1034,
                    pixel_source: PixelSourceKind::Camera,
                    board: "stm32h743-nucleo",
                },
            }),
        ),
        (
            "a device reading pixels from a stream",
            DeviceMessage::HelloReply(HelloReply {
                version: PROTOCOL_VERSION,
                schema: SCHEMA_HASH,
                session: 0,
                capabilities: Capabilities {
                    max_subapertures: 6400,
                    max_camera_pixels: 65536,
                    max_open_windows: 256,
                    pool_entries: 69376,
                    history_pixels: 64 * 4096,
                    scratch_entries: 4096,
                    max_results_per_row: 1024,
                    max_frame_bytes: 1034,
                    pixel_source: PixelSourceKind::Stream,
                    board: "qemu-mps2-an386",
                },
            }),
        ),
        (
            "a device that has run since power-on",
            DeviceMessage::Status(Status {
                config_id: Some(0x0102_0304),
                upload_id: None,
                capturing: false,
                frames_processed: 200,
                frames_dropped: 1,
                crc_errors: 2,
                decode_errors: 3,
                overruns: 4,
                pixel_errors: 5,
                session: Some(0x1234_abcd),
                reset_reason: ResetReason::PowerOn,
                watchdog_ms: Some(1000),
                health: Health::default(),
                config_digest: Some(0x89ab_cdef),
                // CANARY's 49 windows a frame, the row kernel in every one.
                engine: EngineCounters {
                    windows: 9_800,
                    candidates: 558_600,
                    compactions: 12,
                    rescans: 3,
                    attentions: 20_531,
                    kernel_frames: 201,
                },
            }),
        ),
        (
            "a board that reads its own health (an STM32H743 rev Y in bring-up)",
            DeviceMessage::Status(Status {
                session: Some(1),
                reset_reason: ResetReason::Pin,
                watchdog_ms: Some(2000),
                health: Health {
                    silicon: Some(Silicon {
                        device_id: 0x450,
                        revision_id: 0x1003,
                        axi_sram_fix: ErratumFix::Applied,
                    }),
                    clocks: Some(Clocks {
                        sysclk_configured_hz: 400_000_000,
                        sysclk_read_hz: 400_000_000,
                        voltage_scale_configured: 1,
                        voltage_scale_read: 1,
                        voltage_ready: true,
                    }),
                    usb_clock: Some(UsbClockSync {
                        sync_source: 3,
                        synced: true,
                        trim: 33,
                        sync_errors: 0,
                    }),
                    stack: Some(StackUsage {
                        size: 47_808,
                        peak: 3_120,
                        guarded: true,
                    }),
                    camera_interface: Some(CameraInterface {
                        overruns: 1,
                        sync_errors: 0,
                        dma_transfer_errors: 0,
                        dma_fifo_errors: 2,
                        fifo_not_drained: 0,
                    }),
                    idle_permille: Some(875),
                    faults: Some(FaultLog { before_reset: None }),
                },
                ..Status::default()
            }),
        ),
        (
            "a board whose last reset was a HardFault (an undefined instruction: CFSR.UNDEFINSTR, HFSR.FORCED)",
            DeviceMessage::Status(Status {
                reset_reason: ResetReason::Software,
                health: Health {
                    faults: Some(FaultLog {
                        before_reset: Some(Fault {
                            kind: FaultKind::HardFault,
                            pc: 0x0800_1234,
                            lr: 0x0800_0f01,
                            cfsr: 1 << 16,
                            hfsr: 1 << 30,
                            mmfar: 0xe000_edf8,
                            bfar: 0xe000_edf8,
                        }),
                    }),
                    ..Health::default()
                },
                ..Status::default()
            }),
        ),
    ];
    for fix in [ErratumFix::NotNeeded, ErratumFix::Failed] {
        all.push((
            "the AXI SRAM erratum's workaround on other revisions",
            DeviceMessage::Status(Status {
                health: Health {
                    silicon: Some(Silicon {
                        device_id: 0x450,
                        revision_id: 0x2003,
                        axi_sram_fix: fix,
                    }),
                    ..Health::default()
                },
                ..Status::default()
            }),
        ));
    }
    for reason in [
        ResetReason::Unknown,
        ResetReason::Pin,
        ResetReason::Brownout,
        ResetReason::Software,
        ResetReason::Watchdog,
        ResetReason::Other,
    ] {
        all.push((
            "a fresh device: no configuration, no session",
            DeviceMessage::Status(Status {
                upload_id: Some(9),
                capturing: true,
                reset_reason: reason,
                ..Status::default()
            }),
        ));
    }
    let mut results = SlopeList::new();
    for (index, slope_x, slope_y, flux, valid) in
        [(7u16, -65536, 32768, 1000i64, true), (8, 0, 0, 0, false)]
    {
        results
            .push(SlopeEntry {
                index,
                slope_x,
                slope_y,
                flux,
                valid,
            })
            .unwrap();
    }
    all.push((
        "two results: (-1, +0.5) px, flux 62.5 counts, valid; an invalid one",
        DeviceMessage::Slopes { frame: 3, results },
    ));
    all.push((
        "frame 3 complete, 49 results sent",
        DeviceMessage::FrameDone {
            frame: 3,
            count: 49,
        },
    ));
    all.push((
        "frame 0 began on the first frame start after the sync edge, camera frame 1234",
        DeviceMessage::CaptureBegan {
            synced: true,
            camera_frame: Some(1234),
        },
    ));
    all.push((
        "frame 3's first and last rows' checksums (the alignment self-check)",
        DeviceMessage::EdgeRows {
            frame: 3,
            first: 0x1234_5678,
            last: 0x9abc_def0,
        },
    ));
    all.push((
        "a link test's fill, bytes 500 .. 510: each the offset modulo 251",
        DeviceMessage::LinkFill {
            offset: 500,
            fill: link_fill(500, 10),
        },
    ));
    all.push((
        "frame 0 began without a sync edge; the camera does not number its frames",
        DeviceMessage::CaptureBegan {
            synced: false,
            camera_frame: None,
        },
    ));
    for ack in [
        Ack::UploadStarted {
            upload_id: 0x0102_0304,
        },
        Ack::ChunkStored {
            upload_id: 0x0102_0304,
            table: Table::Background,
            end: 960,
        },
        Ack::ConfigApplied {
            config_id: 0x0102_0304,
            open_windows: 7,
            pool_entries: 1680,
        },
        Ack::UploadAborted { upload_id: None },
        Ack::UploadAborted { upload_id: Some(5) },
        Ack::LevelFiltersReset,
        Ack::CaptureStarted { frames: 0 },
        Ack::CaptureStopped { frames: 100 },
        Ack::BenchDone { workloads: 20 },
        Ack::LinkTestDone {
            bytes: 1_000_000,
            messages: 3907,
        },
    ] {
        all.push(("", DeviceMessage::Ack(ack)));
    }
    let spread = |min, median, max| Spread { min, median, max };
    all.push((
        "CANARY on the STM32H743 at 400 MHz: 8 frames of 12,544 pixels in DWT cycles",
        DeviceMessage::BenchReport(BenchReport {
            workload: "canary-subtract-next-n20",
            unit: CountUnit::Cycles,
            clock_hz: Some(400_000_000),
            pixels: 12_544,
            frames: 8,
            result: BenchResult::Measured(BenchFigures {
                engine_total: 1_300_000,
                engine_frame: spread(160_000, 162_000, 168_000),
                engine_last_row: spread(7_000, 7_400, 9_100),
                floor_total: 450_000,
                floor_frame: spread(55_000, 56_000, 58_000),
                floor_last_row: spread(1_500, 1_600, 1_700),
                floor_check: FloorCheck::Equal,
            }),
        }),
    ));
    all.push((
        "the QEMU board under -icount: instructions, another rule",
        DeviceMessage::BenchReport(BenchReport {
            workload: "canary-threshold-n20",
            unit: CountUnit::Instructions,
            clock_hz: None,
            pixels: 12_544,
            frames: 1,
            result: BenchResult::Measured(BenchFigures {
                engine_total: 200_000,
                engine_frame: spread(200_000, 200_000, 200_000),
                engine_last_row: spread(8_000, 8_000, 8_000),
                floor_total: 69_000,
                floor_frame: spread(69_000, 69_000, 69_000),
                floor_last_row: spread(1_765, 1_765, 1_765),
                floor_check: FloorCheck::NotComparable,
            }),
        }),
    ));
    for (unit, result) in [
        (
            CountUnit::Uncounted,
            BenchResult::DoesNotFit {
                limit: BenchLimit::Pixels,
            },
        ),
        (
            CountUnit::Cycles,
            BenchResult::DoesNotFit {
                limit: BenchLimit::Windows,
            },
        ),
        (
            CountUnit::Cycles,
            BenchResult::DoesNotFit {
                limit: BenchLimit::EngineMemory,
            },
        ),
        (CountUnit::Cycles, BenchResult::SlopesDiffer { window: 17 }),
    ] {
        all.push((
            "",
            DeviceMessage::BenchReport(BenchReport {
                workload: "elt-800-10x10-n20",
                unit,
                clock_hz: None,
                pixels: 640_000,
                frames: 1,
                result,
            }),
        ));
    }
    let errors = [
        DeviceError::Decode,
        DeviceError::Crc,
        DeviceError::FrameTooLong,
        DeviceError::HelloRequired,
        DeviceError::Unexpected {
            message: MessageKind::PixelRows,
        },
        DeviceError::Unexpected {
            message: MessageKind::Capture,
        },
        DeviceError::NoUpload,
        DeviceError::UploadMismatch {
            expected: 1,
            found: 2,
        },
        DeviceError::ChunkOutOfOrder {
            expected: Some(position(Table::Windows, 960)),
            found: position(Table::Background, 0),
        },
        DeviceError::ChunkOutOfOrder {
            expected: None,
            found: position(Table::Gain, 0),
        },
        DeviceError::ChunkLength {
            table: Table::Windows,
            len: 7,
        },
        DeviceError::ChunkPastEnd {
            table: Table::PixelCounts,
            end: 100,
            len: 98,
        },
        DeviceError::UploadIncomplete {
            table: Table::Background,
            received: 960,
            expected: 50176,
        },
        DeviceError::UploadCrc {
            computed: 1,
            claimed: 2,
        },
        DeviceError::Capacity {
            what: CapacityKind::Subapertures,
            needed: 6401,
            available: 6400,
        },
        DeviceError::Capacity {
            what: CapacityKind::CameraPixels,
            needed: 262144,
            available: 65536,
        },
        DeviceError::Capacity {
            what: CapacityKind::ResultsPerRow,
            needed: 2000,
            available: 1024,
        },
        DeviceError::NotConfigured,
        DeviceError::NoCamera,
        DeviceError::Crop(CropFault::Width {
            width: 118,
            multiple: 4,
        }),
        DeviceError::Crop(CropFault::FramePixels {
            pixels: 1500,
            multiple: 8,
        }),
        DeviceError::Crop(CropFault::SensorSize {
            width: 4096,
            height: 2048,
            max: 2048,
        }),
        DeviceError::Bench(BenchFault::NotSupported),
        DeviceError::Bench(BenchFault::Streaming),
        DeviceError::Bench(BenchFault::UploadInProgress),
        DeviceError::Bench(BenchFault::UnknownWorkload),
        DeviceError::Bench(BenchFault::TooManyFrames { max: 64 }),
        DeviceError::Sync(SyncFault::NoSyncLine),
        DeviceError::Sync(SyncFault::LineHigh),
        DeviceError::LinkTest(LinkTestFault::Streaming),
        DeviceError::LinkTest(LinkTestFault::TooManyBytes {
            max: MAX_LINK_TEST_BYTES,
        }),
        DeviceError::LinkTest(LinkTestFault::Chunk { max: MAX_LINK_FILL }),
        DeviceError::Unexpected {
            message: MessageKind::Bench,
        },
    ];
    for e in errors {
        all.push(("", DeviceMessage::Error(e)));
    }
    let config_errors = [
        ConfigError::CameraSize {
            width: 0,
            height: 112,
        },
        ConfigError::BitDepth { bit_depth: 17 },
        ConfigError::NoSubapertures,
        ConfigError::TooManySubapertures {
            count: 20000,
            max: 16384,
        },
        ConfigError::EmptyWindow { index: 3 },
        ConfigError::WindowTooLarge {
            index: 4,
            width: 65,
            height: 16,
        },
        ConfigError::WindowOutsideCamera { index: 5 },
        ConfigError::PixelCountZero { index: 6 },
        ConfigError::PixelCountZeroAll,
        ConfigError::CropOutsideSensor {
            x: 200,
            y: 0,
            width: 112,
            height: 112,
            sensor_width: 240,
            sensor_height: 240,
        },
        ConfigError::PixelCountListLength {
            expected: 49,
            found: 48,
        },
        ConfigError::MeanCount { count: 17 },
        ConfigError::LevelFilterGain { gain_shift: 0 },
        ConfigError::LevelFilterWithoutSubtraction,
        ConfigError::MapSize {
            map: MapKind::Background,
            expected: 12544,
            found: 12543,
        },
        ConfigError::MapSize {
            map: MapKind::Gain,
            expected: 12544,
            found: 0,
        },
        ConfigError::MapSize {
            map: MapKind::ReferenceSlopes,
            expected: 49,
            found: 48,
        },
        ConfigError::BackgroundOutOfRange {
            pixel: 7,
            value: -1_048_577,
        },
        ConfigError::ThresholdOutOfRange { value: 33_554_433 },
        ConfigError::ReferenceSlopeOutOfRange { index: 8 },
        ConfigError::NegativeMinFlux,
        ConfigError::MemoryBudget {
            needed: 300,
            available: 256,
            what: MemoryKind::OpenWindows,
        },
        ConfigError::MemoryBudget {
            needed: 70000,
            available: 69376,
            what: MemoryKind::SelectionEntries,
        },
        ConfigError::MemoryBudget {
            needed: 7000,
            available: 6400,
            what: MemoryKind::Subapertures,
        },
        ConfigError::MemoryBudget {
            needed: 4480,
            available: 3840,
            what: MemoryKind::RowHistory,
        },
        ConfigError::MemoryBudget {
            needed: 1024,
            available: 256,
            what: MemoryKind::ScratchEntries,
        },
    ];
    for e in config_errors {
        all.push(("", DeviceMessage::Error(DeviceError::Config(e.into()))));
    }
    let faults = [
        FrameFault::PixelOutOfRange {
            row: 1,
            column: 2,
            value: 4096,
        },
        FrameFault::Gap {
            expected: 480,
            found: 960,
        },
        FrameFault::Incomplete { received: 5 },
        FrameFault::PastEnd {
            first_pixel: 12500,
            count: 480,
        },
        FrameFault::OddLength,
        FrameFault::Reconfigured,
        FrameFault::Stopped,
    ];
    for fault in faults {
        all.push((
            "",
            DeviceMessage::Error(DeviceError::Frame { frame: 9, fault }),
        ));
    }
    all
}
