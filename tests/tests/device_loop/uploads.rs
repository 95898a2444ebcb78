//! Configuration uploads: failed ones leave the running configuration as it
//! was; a commit in the middle of a frame.

use super::*;

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
