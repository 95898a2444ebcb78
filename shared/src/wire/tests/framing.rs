//! Framing (PROTOCOL.md §2): the CRC, the documented encodings, damaged and
//! random input, the frame reader, the `HelloReply` prefix, the edge rows' checksum.

use super::*;

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
