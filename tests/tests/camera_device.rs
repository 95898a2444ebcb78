//! The firmware's device loop with the DCMI camera source over the simulated
//! ring (`camera_sim`): `Capture` streams slopes equal to a direct engine
//! run, and an overrun reaches the host as a counted, dropped frame.

mod camera_sim;

use std::cell::RefCell;
use std::future::Future;
use std::pin::pin;
use std::rc::Rc;
use std::task::{Context, Poll, Waker};

use brightpix::engine_runner::EngineBuffers;
use brightpix::sim_device::{HeapDeviceStorage, SimSizes};
use brightpix_firmware::camera::{DataWidth, DcmiSource};
use brightpix_firmware::device::{Device, LinkError};
use brightpix_firmware::engine::{Engine, SubapertureResult};
use brightpix_protocol::wire::{
    decode, encode, Ack, DeviceError, DeviceMessage, FrameFault, FrameReader, HostMessage,
    PixelSourceKind, Received, SlopeEntry, Status, UploadPlan, MAX_CHUNK_BYTES, MAX_FRAME_LEN,
};
use brightpix_protocol::{
    Calibration, Camera, Centroid, Config, PixelCount, RegularGrid, Selection, SelectionRule,
    SubapertureWindow,
};
use camera_sim::*;

// --- an in-memory link -----------------------------------------------------------

use brightpix_tests::memory_link::{LinkState, MemoryLink as Link};

/// The host's side of the link.
trait HostSide {
    fn send(&self, message: &HostMessage<'_>);
    fn replies(&self) -> Vec<Reply>;
}

impl HostSide for Link {
    fn send(&self, message: &HostMessage<'_>) {
        let mut buf = vec![0u8; MAX_FRAME_LEN];
        let frame = encode(message, &mut buf).unwrap();
        self.0.borrow_mut().input.extend(frame.iter());
    }

    fn replies(&self) -> Vec<Reply> {
        let output = std::mem::take(&mut self.0.borrow_mut().output);
        let mut reader = FrameReader::new(vec![0u8; MAX_FRAME_LEN]);
        let mut out = Vec::new();
        let mut rest = &output[..];
        while !rest.is_empty() {
            let n = reader.push(rest);
            rest = &rest[n..];
            while let Some(received) = reader.next_frame() {
                let Received::Frame(f) = received else {
                    panic!("a frame too long");
                };
                out.push(match decode::<DeviceMessage>(f).unwrap() {
                    DeviceMessage::HelloReply(h) => Reply::Hello(h.capabilities.pixel_source),
                    DeviceMessage::Ack(a) => Reply::Ack(a),
                    DeviceMessage::Error(e) => Reply::Error(e),
                    DeviceMessage::Status(s) => Reply::Status(s),
                    DeviceMessage::Slopes { frame, results } => {
                        Reply::Slopes(frame, results.to_vec())
                    }
                    DeviceMessage::FrameDone { frame, count } => Reply::FrameDone(frame, count),
                    DeviceMessage::BenchReport(r) => panic!("a bench report: {r:?}"),
                    DeviceMessage::CaptureBegan {
                        synced,
                        camera_frame,
                    } => Reply::Began(synced, camera_frame),
                    DeviceMessage::EdgeRows { frame, first, last } => {
                        Reply::EdgeRows(frame, first, last)
                    }
                    DeviceMessage::LinkFill { offset, .. } => panic!("link test fill at {offset}"),
                });
            }
        }
        out
    }
}

#[derive(Clone, Debug, PartialEq, Eq)]
enum Reply {
    Hello(PixelSourceKind),
    Ack(Ack),
    Error(DeviceError),
    Status(Status),
    Slopes(u32, Vec<SlopeEntry>),
    Began(bool, Option<u32>),
    EdgeRows(u32, u32, u32),
    FrameDone(u32, u32),
}

// --- device storage on the heap ----------------------------------------------------

/// The host's heap-backed device storage, sized for these tests.
fn storage(subapertures: usize, pixels: usize) -> HeapDeviceStorage {
    HeapDeviceStorage::new(SimSizes {
        subapertures,
        map_pixels: pixels,
        open_windows: subapertures,
        pool_entries: subapertures * 256,
        history_pixels: 64 * 64,
        scratch_entries: 64 * 64,
        results_per_row: subapertures,
    })
}

// --- the scenario ----------------------------------------------------------------------

const CAMERA: Camera = Camera {
    width: 40,
    height: 24,
    bit_depth: 12,
};

fn windows() -> Vec<SubapertureWindow> {
    RegularGrid {
        x: 0,
        y: 0,
        columns: 5,
        rows: 3,
        width: 8,
        height: 8,
        pitch_x: 8,
        pitch_y: 8,
    }
    .windows()
    .collect()
}

fn config(windows: &[SubapertureWindow]) -> Config<'_> {
    Config {
        camera: CAMERA,
        windows,
        calibration: Calibration {
            background: None,
            gain: None,
            threshold: None,
        },
        selection: Selection {
            rule: SelectionRule::SubtractNext,
            count: PixelCount::All(5),
            level_filter: None,
        },
        centroid: Centroid {
            reference_slopes: None,
            min_flux: 0,
        },
        crop: None,
    }
}

fn entry(r: &SubapertureResult) -> SlopeEntry {
    SlopeEntry {
        index: r.index,
        slope_x: r.slope_x,
        slope_y: r.slope_y,
        flux: r.flux,
        valid: r.valid,
    }
}

/// Configures the device, captures `capture` frames from a camera that
/// sends `frames`; `stall(written)` as in `camera_sim::drive`. Returns
/// every reply and the source's counters.
fn capture_session(
    frames: &[Vec<u16>],
    capture: u32,
    stall: impl FnMut(u64) -> usize,
) -> (Vec<Reply>, brightpix_firmware::camera::CameraStats) {
    let windows = windows();
    let config = config(&windows);
    let link = Link(Rc::new(RefCell::new(LinkState {
        max_read: 64,
        ..LinkState::default()
    })));
    let sim = SimRing::new(
        96,
        Behaviour {
            late_events: true,
            speculate_percent: 5,
            ..Behaviour::default()
        },
        3,
    );
    let (mut words, mut pixels) = (vec![0u32; 32], vec![0u16; 128]);
    let source = DcmiSource::new(sim.clone(), DataWidth::Bits12, &mut words, &mut pixels);
    let mut storage = storage(64, CAMERA.pixel_count());
    let mut device = Device::new(link.clone(), source, storage.buffers(), "sim-dcmi");
    link.send(&HostMessage::hello(1));
    let mut plan = UploadPlan::new(config, 1, MAX_CHUNK_BYTES);
    let mut scratch = vec![0u8; MAX_CHUNK_BYTES];
    while let Some(m) = plan.next(&mut scratch) {
        link.send(&m);
    }
    link.send(&HostMessage::Capture {
        frames: capture,
        start: brightpix_protocol::wire::CaptureStart::Immediate,
        edge_rows: false,
    });

    let mut stall = stall;
    let mut rng = Rng::new(17);
    let mut queued = false;
    let mut status_asked = false;
    {
        let mut run = pin!(device.run());
        let mut cx = Context::from_waker(Waker::noop());
        for _ in 0..1_000_000 {
            match run.as_mut().poll(&mut cx) {
                Poll::Ready(Err(LinkError::Closed)) => break,
                Poll::Ready(other) => panic!("device stopped: {other:?}"),
                Poll::Pending => {}
            }
            let running = sim.state.borrow().running;
            if running {
                if !queued {
                    // The capture has started: the camera sends.
                    for f in frames {
                        sim.send_frame(DataWidth::Bits12, f);
                    }
                    queued = true;
                }
                let stalled = stall(sim.written());
                sim.advance(stalled + rng.range(1, 24));
            } else if queued && !status_asked {
                link.send(&HostMessage::StatusRequest);
                status_asked = true;
            } else if status_asked {
                link.0.borrow_mut().closed = true;
            }
        }
    }
    let stats = device.source().stats();
    (link.replies(), stats)
}

fn direct(frames: &[Vec<u16>]) -> Vec<Vec<SlopeEntry>> {
    let windows = windows();
    let config = config(&windows);
    let mut buffers = EngineBuffers::for_config(&config);
    let mut engine = Engine::new(config, buffers.memory()).unwrap();
    frames
        .iter()
        .map(|f| {
            let mut out = Vec::new();
            engine.push(f, &mut |r| out.push(entry(&r))).unwrap();
            out.sort_by_key(|e| e.index);
            out
        })
        .collect()
}

fn camera_frames(count: u32) -> Vec<Vec<u16>> {
    (0..count)
        .map(|f| frame_pixels(f, CAMERA.pixel_count(), 12))
        .collect()
}

/// Slopes per frame that the device finished with `FrameDone`.
fn done_frames(replies: &[Reply]) -> Vec<(u32, Vec<SlopeEntry>)> {
    let mut out = Vec::new();
    for r in replies {
        if let Reply::FrameDone(frame, count) = r {
            let mut slopes: Vec<SlopeEntry> = replies
                .iter()
                .filter_map(|r| match r {
                    Reply::Slopes(f, s) if f == frame => Some(s.clone()),
                    _ => None,
                })
                .flatten()
                .collect();
            assert_eq!(slopes.len() as u32, *count, "frame {frame}");
            slopes.sort_by_key(|e| e.index);
            out.push((*frame, slopes));
        }
    }
    out
}

fn status(replies: &[Reply]) -> Status {
    replies
        .iter()
        .rev()
        .find_map(|r| match r {
            Reply::Status(s) => Some(*s),
            _ => None,
        })
        .expect("a status")
}

#[test]
fn capture_streams_slopes_equal_to_a_direct_engine_run() {
    let frames = camera_frames(8);
    let expected = direct(&frames);
    let (replies, stats) = capture_session(&frames, 6, |_| 0);
    assert_eq!(replies[0], Reply::Hello(PixelSourceKind::Camera));
    let errors: Vec<_> = replies
        .iter()
        .filter(|r| matches!(r, Reply::Error(_)))
        .collect();
    assert!(errors.is_empty(), "{errors:?}");
    let acks: Vec<_> = replies
        .iter()
        .filter_map(|r| match r {
            Reply::Ack(a) => Some(*a),
            _ => None,
        })
        .collect();
    assert!(acks.contains(&Ack::CaptureStarted { frames: 6 }));
    assert!(acks.contains(&Ack::CaptureStopped { frames: 6 }));
    // One `CaptureBegan` before any result: not on a sync edge, and a DCMI
    // cannot number the camera's frames.
    let began: Vec<usize> = (0..replies.len())
        .filter(|&k| matches!(replies[k], Reply::Began(..)))
        .collect();
    let first_result = replies
        .iter()
        .position(|r| matches!(r, Reply::Slopes(..)))
        .unwrap();
    assert_eq!(began.len(), 1, "{replies:?}");
    assert_eq!(replies[began[0]], Reply::Began(false, None));
    assert!(began[0] < first_result);
    let done = done_frames(&replies);
    assert_eq!(
        done.iter().map(|d| d.0).collect::<Vec<_>>(),
        [0, 1, 2, 3, 4, 5]
    );
    for (frame, slopes) in done {
        assert_eq!(slopes, expected[frame as usize], "frame {frame}");
    }
    let status = status(&replies);
    assert_eq!(status.frames_processed, 6);
    assert_eq!((status.overruns, status.frames_dropped), (0, 0));
    assert!(!status.capturing);
    assert_eq!(stats.overruns, 0);
}

#[test]
fn an_overrun_reaches_the_host_as_a_counted_dropped_frame() {
    let frames = camera_frames(20);
    let expected = direct(&frames);
    // Frames are 480 words, the ring 96: the consumer stops looking for
    // 300 words in the middle of frame 2.
    let mut stalled = false;
    let (replies, stats) = capture_session(&frames, 8, |written| {
        if !stalled && written > 2 * 480 + 100 {
            stalled = true;
            300
        } else {
            0
        }
    });
    assert_eq!(stats.overruns, 1, "{stats:?}");
    let done = done_frames(&replies);
    assert_eq!(done.len(), 8);
    for (frame, slopes) in &done {
        assert_eq!(*slopes, expected[*frame as usize], "frame {frame}");
    }
    let finished: Vec<u32> = done.iter().map(|d| d.0).collect();
    assert!(!finished.contains(&2), "{finished:?}");
    // The device saw the gap: frame 2 reported, the overrun counted.
    assert!(replies.iter().any(|r| matches!(
        r,
        Reply::Error(DeviceError::Frame {
            frame: 2,
            fault: FrameFault::Incomplete { .. }
        }) | Reply::Error(DeviceError::Frame {
            frame: 2,
            fault: FrameFault::Gap { .. }
        })
    )));
    let status = status(&replies);
    assert_eq!(status.overruns, 1, "{status:?}");
    assert!(status.frames_dropped >= 1);
    assert_eq!(status.frames_processed, 8);
}

/// A crop rectangle the camera interface cannot capture (here 17 x 17
/// pixels: not whole words of its 12-bit bus) is refused at `ConfigBegin`
/// with the reason, and nothing of the upload is kept (its first chunk
/// finds no upload); the same windows on a rectangle of whole words are
/// applied.
#[test]
fn a_crop_the_camera_interface_cannot_take_is_refused_before_the_upload() {
    let windows: Vec<SubapertureWindow> = RegularGrid {
        x: 0,
        y: 0,
        columns: 2,
        rows: 2,
        width: 8,
        height: 8,
        pitch_x: 8,
        pitch_y: 8,
    }
    .windows()
    .collect();
    let part = |width, height| Config {
        camera: Camera {
            width,
            height,
            bit_depth: 12,
        },
        crop: Some(brightpix_protocol::Crop {
            x: 3,
            y: 5,
            sensor_width: 40,
            sensor_height: 24,
        }),
        ..config(&windows)
    };
    let link = Link(Rc::new(RefCell::new(LinkState::default())));
    let sim = SimRing::new(96, Behaviour::default(), 3);
    let (mut words, mut pixels) = (vec![0u32; 32], vec![0u16; 128]);
    let source = DcmiSource::new(sim, DataWidth::Bits12, &mut words, &mut pixels);
    let mut storage = storage(64, CAMERA.pixel_count());
    let mut device = Device::new(link.clone(), source, storage.buffers(), "sim-dcmi");
    link.send(&HostMessage::hello(1));
    for (id, config) in [(1, part(17, 17)), (2, part(18, 17))] {
        let mut plan = UploadPlan::new(config, id, MAX_CHUNK_BYTES);
        let mut scratch = vec![0u8; MAX_CHUNK_BYTES];
        while let Some(m) = plan.next(&mut scratch) {
            link.send(&m);
        }
    }
    link.0.borrow_mut().closed = true;
    {
        let mut run = pin!(device.run());
        let mut cx = Context::from_waker(Waker::noop());
        for _ in 0..10_000 {
            if let Poll::Ready(r) = run.as_mut().poll(&mut cx) {
                assert_eq!(r, Err(LinkError::Closed));
                break;
            }
        }
    }
    let replies = link.replies();
    assert_eq!(
        replies[1],
        Reply::Error(DeviceError::Crop(
            brightpix_protocol::wire::CropFault::FramePixels {
                pixels: 289,
                multiple: 2
            }
        ))
    );
    assert_eq!(replies[2], Reply::Error(DeviceError::NoUpload));
    assert!(replies
        .iter()
        .any(|r| matches!(r, Reply::Ack(Ack::ConfigApplied { config_id: 2, .. }))));
}
