//! The camera ring that software fills (`brightpix_firmware::camera::soft`),
//! behind the simulated devices' camera: what a producer writes comes out
//! of `SimulatedCamera` as the same frames, whatever the pieces; a producer
//! a ring ahead is an overrun (the frame dropped, the next one whole); the
//! writes of a stopped or restarted capture are refused; the producer sees
//! the configured geometry.

use std::future::Future;
use std::pin::pin;
use std::task::{Context, Poll, Waker};

use brightpix_firmware::camera::packing::pack;
use brightpix_firmware::camera::{DataWidth, SimulatedCamera, SoftRing};
use brightpix_firmware::device::{CameraRefused, PixelRun, PixelSource};
use brightpix_protocol::Camera;

const CAMERA: Camera = Camera {
    width: 6,
    height: 4,
    bit_depth: 16,
};

/// The next run, if one is ready (owned).
fn poll_run<S: PixelSource>(source: &mut S) -> Option<(u32, u32, Vec<u16>)> {
    let mut cx = Context::from_waker(Waker::noop());
    let mut next = pin!(source.next());
    match next.as_mut().poll(&mut cx) {
        Poll::Ready(PixelRun {
            frame,
            first_pixel,
            pixels,
            ..
        }) => Some((frame, first_pixel, pixels.to_vec())),
        Poll::Pending => None,
    }
}

/// Every run ready now.
fn drain<S: PixelSource>(source: &mut S) -> Vec<(u32, u32, Vec<u16>)> {
    std::iter::from_fn(|| poll_run(source)).collect()
}

/// Runs reassembled into frames (by frame number), checking each run
/// continues its frame.
fn frames_of(runs: &[(u32, u32, Vec<u16>)]) -> Vec<(u32, Vec<u16>)> {
    let mut out: Vec<(u32, Vec<u16>)> = Vec::new();
    for (frame, first, pixels) in runs {
        match out.last_mut() {
            Some((f, p)) if f == frame => {
                assert_eq!(*first as usize, p.len(), "frame {frame}: a gap");
                p.extend(pixels);
            }
            _ => {
                assert_eq!(*first, 0, "frame {frame} starts at pixel 0");
                out.push((*frame, pixels.clone()));
            }
        }
    }
    out
}

fn frame(k: u16) -> Vec<u16> {
    // Every 16-bit value range, the top bits included.
    (0..24u16)
        .map(|i| i.wrapping_mul(2749).wrapping_add(k.wrapping_mul(40503)))
        .collect()
}

fn words(pixels: &[u16]) -> Vec<u32> {
    let mut out = vec![0; pixels.len() / 2];
    pack(DataWidth::Bits16, pixels, &mut out);
    out
}

#[test]
fn frames_written_in_any_pieces_come_out_whole() {
    let ring: SoftRing<32> = SoftRing::new();
    let (mut w, mut p) = (vec![0u32; 5], vec![0u16; 10]);
    let mut camera = SimulatedCamera::new(&ring, DataWidth::Bits16, &mut w, &mut p);
    assert!(ring.capture().is_none());
    camera.start(CAMERA, None).unwrap();
    let capture = ring.capture().unwrap();
    assert_eq!(capture.camera, CAMERA);
    let mut runs = Vec::new();
    for k in 0..9u16 {
        // Pieces of 1, 2, 3... words, read between pieces or not.
        let all = words(&frame(k));
        let mut rest = &all[..];
        let mut size = 1 + k as usize % 4;
        while !rest.is_empty() {
            let n = size.min(rest.len());
            assert!(ring.write(capture.id, &rest[..n]));
            rest = &rest[n..];
            size += 1;
            if k % 2 == 0 {
                runs.extend(drain(&mut camera));
            }
        }
        assert!(ring.end_frame(capture.id));
        runs.extend(drain(&mut camera));
    }
    let frames = frames_of(&runs);
    assert_eq!(frames.len(), 9);
    for (k, (number, pixels)) in frames.iter().enumerate() {
        assert_eq!(*number, k as u32);
        assert_eq!(pixels, &frame(k as u16), "frame {k}");
    }
    let stats = camera.stats();
    assert_eq!(stats.frames_delivered, 9);
    assert_eq!(
        stats.overruns + stats.frames_dropped + stats.length_errors,
        0
    );
}

#[test]
fn a_producer_a_ring_ahead_is_an_overrun() {
    // 16 words: one frame (12 words) fits, two do not.
    let ring: SoftRing<16> = SoftRing::new();
    let (mut w, mut p) = (vec![0u32; 16], vec![0u16; 32]);
    let mut camera = SimulatedCamera::new(&ring, DataWidth::Bits16, &mut w, &mut p);
    camera.start(CAMERA, None).unwrap();
    let id = ring.capture().unwrap().id;
    for k in 0..3 {
        assert!(ring.write(id, &words(&frame(k))));
        assert!(ring.end_frame(id));
    }
    let runs = drain(&mut camera);
    assert!(camera.stats().overruns >= 1, "{:?}", camera.stats());
    // Nothing of frames 0 and 1 completes: the device sees a gap.
    let complete: Vec<u32> = frames_of_lenient(&runs);
    assert!(!complete.contains(&0) && !complete.contains(&1), "{runs:?}");
    // The camera carries on: the next frame comes whole.
    assert!(ring.write(id, &words(&frame(3))));
    assert!(ring.end_frame(id));
    let later = drain(&mut camera);
    let last = frames_of(&later);
    assert_eq!(last, vec![(3, frame(3))]);
}

/// Frames delivered whole from pixel 0 to the end (gaps allowed elsewhere).
fn frames_of_lenient(runs: &[(u32, u32, Vec<u16>)]) -> Vec<u32> {
    let mut whole = Vec::new();
    let mut current: Option<(u32, usize)> = None;
    for (frame, first, pixels) in runs {
        current = match current {
            Some((f, n)) if f == *frame && n == *first as usize => Some((f, n + pixels.len())),
            _ if *first == 0 => Some((*frame, pixels.len())),
            _ => None,
        };
        if let Some((f, 24)) = current {
            whole.push(f);
        }
    }
    whole
}

#[test]
fn writes_of_a_stopped_or_restarted_capture_are_refused() {
    let ring: SoftRing<32> = SoftRing::new();
    let (mut w, mut p) = (vec![0u32; 8], vec![0u16; 16]);
    let mut camera = SimulatedCamera::new(&ring, DataWidth::Bits16, &mut w, &mut p);
    camera.start(CAMERA, None).unwrap();
    let first = ring.capture().unwrap().id;
    assert!(ring.write(first, &[1, 2]));
    camera.stop();
    assert!(ring.capture().is_none());
    assert!(!ring.is_running(first));
    assert!(!ring.write(first, &[3]));
    assert!(!ring.end_frame(first));
    let other = Camera {
        width: 4,
        height: 2,
        bit_depth: 12,
    };
    camera.start(other, None).unwrap();
    let second = ring.capture().unwrap();
    assert_ne!(second.id, first);
    assert_eq!(second.camera, other);
    // The old capture's producer is refused; the new one starts at word 0.
    assert!(!ring.write(first, &[0xDEAD_BEEF; 4]));
    let pixels = [7, 8, 9, 10, 11, 12, 13, 4095];
    assert!(ring.write(second.id, &words(&pixels)));
    assert!(ring.end_frame(second.id));
    assert_eq!(frames_of(&drain(&mut camera)), vec![(0, pixels.to_vec())]);
}

#[test]
fn a_frame_of_an_odd_pixel_count_is_refused() {
    let ring: SoftRing<16> = SoftRing::new();
    let (mut w, mut p) = (vec![0u32; 8], vec![0u16; 16]);
    let mut camera = SimulatedCamera::new(&ring, DataWidth::Bits16, &mut w, &mut p);
    let odd = Camera {
        width: 3,
        height: 3,
        bit_depth: 16,
    };
    assert_eq!(camera.start(odd, None), Err(CameraRefused));
    assert!(ring.capture().is_none());
}
