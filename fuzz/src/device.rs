//! The device-loop target: the firmware's `Device` (the code the boards
//! run) on an in-memory link, fed a configuration and arbitrary traffic
//! drawn from the input, then checked by a clean session against the
//! reference implementation.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::convert::Infallible;
use std::rc::Rc;
use std::task::Poll;

use brightpix::config_file::{PixelCounts, ProcessingConfig};
use brightpix::reference::Reference;
use brightpix::sim_device::{HeapDeviceStorage, SimSizes};
use brightpix_firmware::device::embedded_io_async::{ErrorType, Read, Write};
use brightpix_firmware::device::{vet, Device, LinkOnly};
use brightpix_protocol::wire::{
    decode, encode, Ack, CaptureStart, DeviceMessage, FrameReader, Hello, HostMessage,
    PixelRowsPlan, Received, Table, UploadPlan, MAX_CHUNK_BYTES, MAX_FRAME_LEN, MAX_LINK_FILL,
    MAX_LINK_TEST_BYTES, MAX_PIXEL_BYTES,
};
use brightpix_protocol::{Camera, LevelFilter, SelectionRule, SubapertureWindow};

use crate::Bytes;

/// The device's buffers: small, so that limits are reached.
const SIZES: SimSizes = SimSizes {
    subapertures: 48,
    map_pixels: 24 * 24,
    open_windows: 12,
    pool_entries: 12 * 40,
    history_pixels: 12 * 24,
    scratch_entries: 12 * 12,
    results_per_row: 12,
};

#[derive(Default)]
struct LinkState {
    input: VecDeque<u8>,
    output: Vec<u8>,
    max_read: usize,
}

#[derive(Clone)]
struct Link(Rc<RefCell<LinkState>>);

impl ErrorType for Link {
    type Error = Infallible;
}

impl Read for Link {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        std::future::poll_fn(|_| {
            let mut s = self.0.borrow_mut();
            // An empty input is the end of the stream: `run` returns.
            let n = buf.len().min(s.input.len()).min(s.max_read.max(1));
            for b in &mut buf[..n] {
                *b = s.input.pop_front().unwrap_or(0);
            }
            Poll::Ready(Ok(n))
        })
        .await
    }
}

impl Write for Link {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        self.0.borrow_mut().output.extend_from_slice(buf);
        Ok(buf.len())
    }
    async fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

struct Host {
    link: Rc<RefCell<LinkState>>,
    frame: Vec<u8>,
    scratch: Vec<u8>,
}

impl Host {
    fn send(&mut self, m: &HostMessage<'_>) {
        let n = encode(m, &mut self.frame).expect("fits a frame").len();
        self.link.borrow_mut().input.extend(&self.frame[..n]);
    }
    fn raw(&self, bytes: &[u8]) {
        self.link.borrow_mut().input.extend(bytes);
    }
    fn upload(&mut self, config: &ProcessingConfig, id: u32, chunk: usize, stop_after: usize) {
        let mut plan = UploadPlan::new(config.view(), id, chunk);
        let mut scratch = std::mem::take(&mut self.scratch);
        let mut k = 0;
        while let Some(m) = plan.next(&mut scratch) {
            if k == stop_after {
                break;
            }
            self.send(&m);
            k += 1;
        }
        self.scratch = scratch;
    }
    fn pixels(&mut self, frame: u32, pixels: &[u16], per_message: usize) {
        let mut plan = PixelRowsPlan::new(frame, pixels, per_message.clamp(1, MAX_PIXEL_BYTES / 2));
        let mut scratch = std::mem::take(&mut self.scratch);
        while let Some(m) = plan.next(&mut scratch) {
            self.send(&m);
        }
        self.scratch = scratch;
    }
    /// Everything the device sent: each must be a valid frame.
    fn replies(&mut self) -> Vec<Vec<u8>> {
        let output = std::mem::take(&mut self.link.borrow_mut().output);
        let mut reader = FrameReader::new(vec![0u8; MAX_FRAME_LEN]);
        let mut frames = Vec::new();
        let mut rest = &output[..];
        while !rest.is_empty() {
            let n = reader.push(rest);
            rest = &rest[n..];
            while let Some(r) = reader.next_frame() {
                match r {
                    Received::Frame(f) => {
                        let copy = f.to_vec();
                        decode::<DeviceMessage>(f).expect("the device sends valid frames");
                        frames.push(copy);
                    }
                    Received::TooLong => panic!("the device sent a frame too long"),
                }
            }
        }
        assert_eq!(reader.pending(), 0, "a partial frame from the device");
        frames
    }
}

/// A configuration drawn from the input: small cameras and windows, every
/// rule and option, sometimes invalid.
fn draw_config(b: &mut Bytes<'_>) -> ProcessingConfig {
    let camera = Camera {
        width: 1 + b.below(24) as u16,
        height: 1 + b.below(24) as u16,
        bit_depth: match b.u8() {
            0 => 0,
            1 => 17,
            v => 1 + v % 16,
        },
    };
    let count = 1 + b.below(8) as usize;
    let windows: Vec<SubapertureWindow> = (0..count)
        .map(|_| {
            let (w, h) = (b.below(13) as u16, b.below(13) as u16);
            SubapertureWindow {
                x: b.below(camera.width as u32 + 2) as u16,
                y: b.below(camera.height as u32 + 2) as u16,
                width: w,
                height: h,
            }
        })
        .collect();
    let mut config = ProcessingConfig::new(camera, windows);
    config.rule = match b.u8() % 4 {
        0 => SelectionRule::Threshold,
        1 => SelectionRule::SubtractNext,
        2 => SelectionRule::SubtractNextDistinct,
        _ => SelectionRule::SubtractMean {
            count: b.below(18) as u16,
        },
    };
    let flags = b.u8();
    config.pixels = if flags & 1 != 0 {
        PixelCounts::PerSubaperture((0..count).map(|_| b.below(300) as u16).collect())
    } else {
        PixelCounts::All(b.below(300) as u16)
    };
    let pixels = camera.pixel_count();
    if flags & 2 != 0 {
        config.level_filter = Some(LevelFilter {
            gain_shift: b.below(18) as u8,
        });
    }
    if flags & 4 != 0 {
        config.background = Some((0..pixels).map(|_| b.u16() as i16 as i32 * 16).collect());
    }
    if flags & 8 != 0 {
        config.gain = Some((0..pixels).map(|_| b.u16()).collect());
    }
    if flags & 16 != 0 {
        config.threshold = Some(b.u32() as i32 >> 6);
    }
    if flags & 32 != 0 {
        config.reference_slopes = Some(
            (0..count)
                .map(|_| [b.u32() as i32 >> 8, b.u32() as i32 >> 8])
                .collect(),
        );
    }
    if flags & 64 != 0 {
        config.min_flux = (b.u32() >> 4) as i64;
    }
    config
}

/// A deterministic frame for `camera`, pixel values up to its maximum.
fn frame_for(camera: Camera, seed: u32) -> Vec<u16> {
    let mut x = seed as u64 | 1;
    (0..camera.pixel_count())
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x % (camera.max_raw() as u64 + 1)) as u16
        })
        .collect()
}

/// The device-loop target.
pub fn device_loop(data: &[u8]) {
    let mut b = Bytes(data);
    let config = draw_config(&mut b);
    let state = Rc::new(RefCell::new(LinkState {
        max_read: 1 + b.below(600) as usize,
        ..LinkState::default()
    }));
    let mut host = Host {
        link: state.clone(),
        frame: vec![0u8; MAX_FRAME_LEN],
        scratch: vec![0u8; MAX_CHUNK_BYTES.max(MAX_PIXEL_BYTES)],
    };
    let mut storage = HeapDeviceStorage::new(SIZES);
    let mut device = Device::new(Link(state.clone()), LinkOnly, storage.buffers(), "fuzz");
    let run = |device: &mut Device<'_, Link, LinkOnly>| {
        let _ = embassy_futures::block_on(device.run());
    };

    // Arbitrary traffic, in at most 64 steps.
    for _ in 0..64 {
        if b.is_empty() {
            break;
        }
        match b.u8() % 10 {
            0 => {
                let n = b.u8() as usize * 4;
                host.raw(b.take(n));
            }
            1 => {
                let session = b.u32();
                let protocol = if session % 5 == 0 {
                    Hello {
                        version: b.u16(),
                        schema: b.u32() as u64,
                    }
                } else {
                    Hello::CURRENT
                };
                host.send(&HostMessage::Hello { protocol, session });
            }
            2 => {
                let chunk = 8 * (1 + b.below(MAX_CHUNK_BYTES as u32 / 8)) as usize;
                let stop = b.u8() as usize;
                host.upload(&config, b.u32(), chunk, stop);
            }
            3 => {
                let frame = b.u32() % 4;
                let first = b.u32() % (config.camera.pixel_count() as u32 + 2);
                let n = b.u8() as usize;
                let bytes = b.take(2 * n).to_vec();
                host.send(&HostMessage::PixelRows {
                    frame,
                    first_pixel: first,
                    pixels: &bytes,
                });
            }
            4 => {
                let frame = b.u32() % 4;
                let mut pixels = frame_for(config.camera, b.u32());
                if b.u8() == 0 {
                    // One pixel above the bit depth.
                    let at = b.below(pixels.len() as u32) as usize;
                    pixels[at] = config.camera.max_raw().saturating_add(1);
                }
                host.pixels(frame, &pixels, b.u16() as usize);
            }
            5 => {
                let m = match b.u8() % 8 {
                    0 => HostMessage::StatusRequest,
                    1 => HostMessage::ConfigAbort,
                    2 => HostMessage::ResetLevelFilters,
                    3 => HostMessage::Capture {
                        frames: b.u32(),
                        start: [
                            CaptureStart::Immediate,
                            CaptureStart::OnSync,
                            CaptureStart::DriveSync,
                        ][usize::from(b.u8() % 3)],
                        edge_rows: b.u8() % 2 == 0,
                    },
                    4 => HostMessage::StopCapture,
                    5 => HostMessage::ConfigCommit {
                        upload_id: b.u32(),
                        crc32: b.u32(),
                    },
                    6 => HostMessage::ConfigChunk {
                        upload_id: b.u32(),
                        table: [
                            Table::Windows,
                            Table::PixelCounts,
                            Table::Background,
                            Table::Gain,
                            Table::ReferenceSlopes,
                        ][b.below(5) as usize],
                        offset: b.u32() % 4096,
                        bytes: &[1, 2, 3, 4, 5, 6, 7, 8][..b.below(9) as usize],
                    },
                    // A link test: mostly a few messages, now and then
                    // beyond its limits (chunk 0 or 961, too many bytes).
                    _ => HostMessage::LinkTest {
                        bytes: if b.u8() == 0 {
                            MAX_LINK_TEST_BYTES + 1
                        } else {
                            b.u32() % 4096
                        },
                        chunk: b.below(u32::from(MAX_LINK_FILL) + 2) as u16,
                    },
                };
                host.send(&m);
            }
            6 => {
                // A well-formed message damaged in one byte.
                let session = b.u32();
                let n = encode(&HostMessage::hello(session), &mut host.frame)
                    .unwrap()
                    .len();
                let at = b.below(n as u32) as usize;
                host.frame[at] ^= 1 << (b.u8() % 8);
                let bytes = host.frame[..n].to_vec();
                host.raw(&bytes);
            }
            7 => host.raw(&[0]),
            8 => run(&mut device),
            _ => {
                state.borrow_mut().max_read = 1 + b.below(600) as usize;
            }
        }
    }
    run(&mut device);
    host.replies();

    // A clean session afterwards works exactly: garbage leaves no trace.
    let clean = if config.validate().is_ok() {
        config
    } else {
        let mut c = ProcessingConfig::new(
            Camera {
                width: 12,
                height: 10,
                bit_depth: 12,
            },
            vec![SubapertureWindow {
                x: 1,
                y: 2,
                width: 6,
                height: 5,
            }],
        );
        c.pixels = PixelCounts::All(4);
        c
    };
    let view = clean.view();
    let n = view.windows.len();
    let verdict = vet::check_offline(
        &view,
        device.capabilities(),
        &mut vec![0u16; n],
        &mut vec![0u16; n],
    );
    host.raw(&[0]);
    host.send(&HostMessage::hello(0xC1EA));
    host.upload(&clean, 0xC0DE, MAX_CHUNK_BYTES, usize::MAX);
    let pixels = frame_for(clean.camera, 99);
    host.pixels(7, &pixels, 100);
    host.send(&HostMessage::StatusRequest);
    state.borrow_mut().max_read = MAX_FRAME_LEN;
    run(&mut device);
    let mut session = false;
    let mut applied = None;
    let mut results = vec![None; n];
    let mut done = None;
    let mut errors = Vec::new();
    for mut f in host.replies() {
        let m = decode::<DeviceMessage>(&mut f).unwrap();
        match m {
            DeviceMessage::HelloReply(h) if h.session == 0xC1EA => {
                // The last one counts (the traffic may have used this id).
                session = true;
                applied = None;
                results = vec![None; n];
                done = None;
                errors.clear();
            }
            _ if !session => {} // the earlier traffic's
            DeviceMessage::Ack(Ack::ConfigApplied { config_id, .. }) => applied = Some(config_id),
            DeviceMessage::Slopes {
                frame: 7,
                results: r,
            } => {
                for e in r {
                    let slot = &mut results[e.index as usize];
                    assert!(slot.is_none(), "sub-aperture {} sent twice", e.index);
                    *slot = Some(e);
                }
            }
            DeviceMessage::FrameDone { frame: 7, count } => done = Some(count),
            DeviceMessage::Error(e) => errors.push(e),
            _ => {}
        }
    }
    assert!(session, "no HelloReply to the clean session");
    match verdict {
        Ok(_) => {
            assert_eq!(applied, Some(0xC0DE), "upload refused: {errors:?}");
            assert_eq!(errors, [], "errors in a clean session");
            assert_eq!(done, Some(n as u32), "errors: {errors:?}");
            let expected = Reference::new(&view)
                .expect("valid")
                .process_frame(&pixels)
                .expect("in range");
            for (r, d) in expected.iter().zip(&results) {
                let d = d.expect("every sub-aperture has a result");
                assert_eq!(
                    (d.slope_x, d.slope_y, d.flux, d.valid),
                    (r.slope_x, r.slope_y, r.flux, r.valid),
                    "sub-aperture {}",
                    r.index
                );
            }
        }
        Err(e) => {
            assert_eq!(applied, None);
            assert!(errors.contains(&e), "expected {e:?}, got {errors:?}");
        }
    }
}
