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

/// One row of 40 windows: more results than one message holds.
fn long_row() -> Owned {
    Owned {
        camera: Camera {
            width: 160,
            height: 8,
            bit_depth: 16,
        },
        windows: grid(40, 1, 4, 8),
        ..config_a()
    }
}

#[test]
fn a_long_row_of_results_is_split_into_messages() {
    let owned = long_row();
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

/// What the device sends for a frame's results stays within what `rig
/// plan` counts for the board's link (`brightpix::rig::frame_bytes`: the
/// same messages, each result at its configuration's bound), with one
/// `Slopes` message per row of sub-apertures and 32 results.
#[test]
fn a_frame_of_results_takes_no_more_than_the_rig_counts() {
    for owned in [config_a(), config_filtered(), long_row()] {
        let config = owned.view();
        let bounds = brightpix::rig::ResultBounds::of(&owned);
        let all: Vec<usize> = (0..owned.windows.len()).collect();
        let counted = brightpix::rig::frame_bytes(&owned, &bounds, &all, false);
        let (mut storage, mut host, link) = setup(SIZES, 1000);
        let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
        host.hello();
        configure(&mut host, &mut device, config, 1);
        // A saturated pixel in each window's far corner (the largest
        // slopes), then spots on noise (within ~2% of the count for
        // `config_a`).
        let mut corners = vec![0u16; owned.camera.pixel_count()];
        for w in &owned.windows {
            let at = w.last_row() as usize * owned.camera.width as usize;
            corners[at + (w.x + w.width - 1) as usize] = owned.camera.max_raw();
        }
        let mut all_frames = vec![corners];
        all_frames.extend(frames(owned.camera, 3, 9));
        for (k, f) in all_frames.iter().enumerate() {
            host.frame(u32::MAX - k as u32, f, 480);
            run(&mut device);
            let sent = host.link.borrow().output.len();
            let replies = host.replies();
            assert_eq!(errors(&replies), []);
            let rows = owned.windows.iter().fold(Vec::new(), |mut rows, w| {
                if !rows.contains(&w.last_row()) {
                    rows.push(w.last_row());
                }
                rows
            });
            let per_row = owned.windows.len() / rows.len();
            let messages = rows.len() * per_row.div_ceil(SLOPES_PER_MESSAGE);
            assert_eq!(
                slopes_of(&replies, u32::MAX - k as u32).1,
                messages,
                "{replies:?}"
            );
            assert!(sent <= counted, "{sent} bytes sent, {counted} counted");
        }
    }
}
