//! Streamed slopes against a direct run of the engine, and a row of results
//! longer than one message.

use super::*;

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
