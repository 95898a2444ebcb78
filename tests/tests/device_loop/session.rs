//! A session: the handshake, a new session, a mismatched `Hello`, and the
//! level filters reset on request.

use super::*;

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
