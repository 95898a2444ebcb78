//! The link test (PROTOCOL.md §15).

use super::*;
use brightpix_protocol::wire::{link_fill_byte, LinkTestFault, MAX_LINK_FILL, MAX_LINK_TEST_BYTES};

/// The fill messages of `replies`, in order.
fn fills(replies: &[Reply]) -> Vec<(u32, Vec<u8>)> {
    replies
        .iter()
        .filter_map(|r| match r {
            Reply::LinkFill { offset, fill } => Some((*offset, fill.clone())),
            _ => None,
        })
        .collect()
}

/// A link test sends exactly the bytes asked for, the protocol's fill in
/// order, `chunk` a message and the rest in the last, then its `Ack`; it
/// is refused (nothing sent) while a frame is in progress, above its
/// limits and with a chunk of 0, and a frame asked for afterwards
/// streams as before.
#[test]
fn a_link_test_sends_the_fill_and_is_refused_while_streaming() {
    let owned = config_a();
    let config = owned.view();
    let frames = frames(CAMERA, 3, 5);
    let expected = direct(config, &frames);
    let (mut storage, mut host, link) = setup(SIZES, 64);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    host.hello();
    configure(&mut host, &mut device, config, 1);

    host.send(&HostMessage::LinkTest {
        bytes: 2_000,
        chunk: 300,
    });
    host.send(&HostMessage::LinkTest { bytes: 0, chunk: 1 });
    run(&mut device);
    let replies = host.replies();
    let sent = fills(&replies);
    let offsets: Vec<u32> = sent.iter().map(|(o, _)| *o).collect();
    assert_eq!(offsets, [0, 300, 600, 900, 1200, 1500, 1800]);
    assert_eq!(sent.last().unwrap().1.len(), 200);
    let all: Vec<u8> = sent.into_iter().flat_map(|(_, f)| f).collect();
    let want: Vec<u8> = (0..2_000).map(link_fill_byte).collect();
    assert_eq!(all, want);
    assert_eq!(
        acks(&replies),
        [
            Ack::LinkTestDone {
                bytes: 2_000,
                messages: 7
            },
            Ack::LinkTestDone {
                bytes: 0,
                messages: 0
            }
        ]
    );
    // The Ack comes after the last fill.
    assert!(matches!(replies.last(), Some(Reply::Ack(_))));

    // A frame in progress: refused, and the frame completes.
    host.frame_from(0, &frames[0][..500], 0, 100);
    host.send(&HostMessage::LinkTest {
        bytes: 10,
        chunk: 10,
    });
    host.frame_from(0, &frames[0], 500, 100);
    // Its limits.
    host.send(&HostMessage::LinkTest {
        bytes: MAX_LINK_TEST_BYTES + 1,
        chunk: 10,
    });
    host.send(&HostMessage::LinkTest {
        bytes: 10,
        chunk: 0,
    });
    host.send(&HostMessage::LinkTest {
        bytes: 10,
        chunk: MAX_LINK_FILL + 1,
    });
    // The largest chunk fits a frame.
    host.send(&HostMessage::LinkTest {
        bytes: 3 * MAX_LINK_FILL as u32,
        chunk: MAX_LINK_FILL,
    });
    for (k, f) in frames[1..].iter().enumerate() {
        host.frame(1 + k as u32, f, 480);
    }
    run(&mut device);
    let replies = host.replies();
    assert_eq!(
        errors(&replies),
        [
            DeviceError::LinkTest(LinkTestFault::Streaming),
            DeviceError::LinkTest(LinkTestFault::TooManyBytes {
                max: MAX_LINK_TEST_BYTES
            }),
            DeviceError::LinkTest(LinkTestFault::Chunk { max: MAX_LINK_FILL }),
            DeviceError::LinkTest(LinkTestFault::Chunk { max: MAX_LINK_FILL }),
        ]
    );
    let sent = fills(&replies);
    assert_eq!(sent.len(), 3);
    assert!(sent.iter().all(|(_, f)| f.len() == MAX_LINK_FILL as usize));
    for (k, want) in expected.iter().enumerate() {
        expect_verified(&replies, k as u32, want);
    }
}
