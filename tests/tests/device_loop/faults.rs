//! Bad input on the link: a corrupted frame, garbage, long frames, bad
//! pixels, pixels before a configuration, results that do not fit the queue.

use super::*;

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
