//! A device with its own camera (a pixel source), started at once or on the
//! sync line, and pixels from a separate stream.

use super::*;

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
