//! A board's crop rectangle at its camera interface
//! (`brightpix_firmware::camera::crop`): the software crop of the simulated
//! cameras keeps exactly the rectangle of each whole-sensor frame, whatever
//! pieces the frame comes in, packed as the bus packs it; the DCMI's rules
//! refuse what its crop registers cannot express; a simulated camera started
//! with a crop delivers the rectangle's frames.

use std::future::Future;
use std::pin::pin;
use std::task::{Context, Poll, Waker};

use brightpix_firmware::camera::crop::{frame_check, DCMI_MAX_SENSOR_SIDE};
use brightpix_firmware::camera::packing::unpack;
use brightpix_firmware::camera::{
    dcmi_check, DataWidth, DcmiCropRegisters, SensorCrop, SimulatedCamera, SoftRing,
};
use brightpix_firmware::device::{CameraRefused, PixelRun, PixelSource};
use brightpix_protocol::wire::CropFault;
use brightpix_protocol::{Camera, Crop};
use proptest::prelude::*;

fn camera(width: u16, height: u16, bit_depth: u8) -> Camera {
    Camera {
        width,
        height,
        bit_depth,
    }
}

fn crop(x: u16, y: u16, sensor_width: u16, sensor_height: u16) -> Crop {
    Crop {
        x,
        y,
        sensor_width,
        sensor_height,
    }
}

/// Sensor pixel `(row, column)`: its own position, so a pixel out of place
/// shows.
fn sensor_frame(width: u16, height: u16, frame: u16) -> Vec<u16> {
    (0..height)
        .flat_map(|r| (0..width).map(move |c| (r * width + c).wrapping_add(frame * 7)))
        .collect()
}

/// The rectangle by rows and columns, written independently of the crop.
fn rectangle(sensor: &[u16], sensor_width: u16, cam: Camera, at: Crop) -> Vec<u16> {
    let mut out = Vec::new();
    for r in at.y..at.y + cam.height {
        for c in at.x..at.x + cam.width {
            out.push(sensor[r as usize * sensor_width as usize + c as usize]);
        }
    }
    out
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    /// Any rectangle of any sensor, frames cut into pieces of any length:
    /// the bus carries exactly the rectangle, frame after frame.
    #[test]
    fn keeps_exactly_the_rectangle(
        sensor_width in 1u16..40,
        sensor_height in 1u16..20,
        x_frac in 0.0f64..1.0,
        y_frac in 0.0f64..1.0,
        w_frac in 0.0f64..1.0,
        h_frac in 0.0f64..1.0,
        pieces in prop::collection::vec(1usize..50, 1..40),
        eight_bit in any::<bool>(),
    ) {
        let x = (x_frac * sensor_width as f64) as u16;
        let y = (y_frac * sensor_height as f64) as u16;
        let width = 1 + (w_frac * (sensor_width - x - 1) as f64) as u16;
        let height = 1 + (h_frac * (sensor_height - y - 1) as f64) as u16;
        let bus = if eight_bit { DataWidth::Bits8 } else { DataWidth::Bits16 };
        let per_word = bus.pixels_per_word();
        let cam = camera(width, height, 8);
        let at = crop(x, y, sensor_width, sensor_height);
        let mut crop = SensorCrop::new(bus, cam, Some(at));
        prop_assert_eq!(crop.sensor_pixels(), sensor_width as usize * sensor_height as usize);
        let mut kept: Vec<Vec<u16>> = Vec::new();
        for frame in 0..3u16 {
            let sensor: Vec<u16> = sensor_frame(sensor_width, sensor_height, frame)
                .iter()
                .map(|p| p & 0xff)
                .collect();
            let expected = rectangle(&sensor, sensor_width, cam, at);
            let mut got = Vec::new();
            let mut rest = &sensor[..];
            let mut k = 0;
            while !rest.is_empty() {
                let n = pieces[k % pieces.len()].min(rest.len());
                crop.keep(&rest[..n], |run| got.extend_from_slice(run));
                rest = &rest[n..];
                k += 1;
            }
            // Pixels past the frame's end are not the frame's.
            crop.keep(&[1, 2, 3], |run| got.extend_from_slice(run));
            prop_assert_eq!(&got, &expected);
            crop.end_frame();
            kept.push(expected);
        }
        // The same frames through the packer, in other pieces.
        let mut crop = SensorCrop::new(bus, cam, Some(at));
        for (frame, expected) in kept.iter().enumerate() {
            let sensor: Vec<u16> = sensor_frame(sensor_width, sensor_height, frame as u16)
                .iter()
                .map(|p| p & 0xff)
                .collect();
            let mut packed = Vec::new();
            for piece in sensor.chunks(pieces[frame % pieces.len()]) {
                let mut out = vec![0; piece.len() / per_word + 1];
                let n = crop.keep_packed(piece, &mut out);
                packed.extend_from_slice(&out[..n]);
            }
            crop.end_frame();
            let whole = expected.len() / per_word * per_word;
            let mut pixels = vec![0; packed.len() * per_word];
            unpack(bus, &packed, &mut pixels);
            prop_assert_eq!(&pixels[..], &expected[..whole]);
        }
    }
}

/// Without a crop every pixel is kept.
#[test]
fn no_crop_keeps_the_whole_frame() {
    let cam = camera(5, 3, 16);
    let mut crop = SensorCrop::new(DataWidth::Bits16, cam, None);
    let frame = sensor_frame(5, 3, 0);
    let mut got = Vec::new();
    crop.keep(&frame, |run| got.extend_from_slice(run));
    assert_eq!(got, frame);
}

/// The DCMI's rules (RM0433, "DCMI crop feature"; the module's reading of
/// `CAPCNT`): width a multiple of 4 pixels at every bit depth, frames of
/// whole 4-word bursts, sensors of at most 2048 a side.
#[test]
fn the_dcmi_refuses_what_its_registers_cannot_express() {
    let sensor = crop(8, 16, 240, 240);
    for bus in [DataWidth::Bits10, DataWidth::Bits12, DataWidth::Bits14] {
        assert_eq!(dcmi_check(bus, camera(96, 80, 12), sensor), Ok(()));
        assert_eq!(
            dcmi_check(bus, camera(98, 80, 12), sensor),
            Err(CropFault::Width {
                width: 98,
                multiple: 4
            })
        );
        // 4 x 3 = 12 pixels: whole words, not whole bursts of 8.
        assert_eq!(
            dcmi_check(bus, camera(4, 3, 12), sensor),
            Err(CropFault::FramePixels {
                pixels: 12,
                multiple: 8
            })
        );
    }
    // The 8-bit bus: 4 pixels a word, bursts of 16 pixels.
    assert_eq!(
        dcmi_check(DataWidth::Bits8, camera(4, 4, 8), sensor),
        Ok(())
    );
    assert_eq!(
        dcmi_check(DataWidth::Bits8, camera(4, 6, 8), sensor),
        Err(CropFault::FramePixels {
            pixels: 24,
            multiple: 16
        })
    );
    assert_eq!(
        dcmi_check(DataWidth::Bits12, camera(16, 16, 12), crop(0, 0, 2049, 16)),
        Err(CropFault::SensorSize {
            width: 2049,
            height: 16,
            max: DCMI_MAX_SENSOR_SIDE
        })
    );
    assert!(frame_check(camera(3, 3, 12), 2).is_err());
    // A refusal's text names the rule.
    let text = CropFault::Width {
        width: 98,
        multiple: 4,
    }
    .to_string();
    assert!(
        text.contains("98") && text.contains("multiple of 4"),
        "{text}"
    );
}

/// The registers count pixel clocks (one a pixel) from 0, sizes less one.
#[test]
fn dcmi_registers_of_a_rectangle() {
    assert_eq!(
        DcmiCropRegisters::of(camera(96, 80, 12), crop(8, 16, 240, 240)),
        Some(DcmiCropRegisters {
            hoffcnt: 8,
            vst: 16,
            capcnt: 95,
            vline: 79
        })
    );
    assert_eq!(
        DcmiCropRegisters::of(camera(0, 80, 12), crop(0, 0, 240, 240)),
        None
    );
}

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

/// A simulated camera started with a crop tells its producer the sensor
/// and the rectangle; what the producer crops comes out as the
/// rectangle's frames. A rectangle of an odd pixel count is not whole
/// words of its 16-bit bus: refused before the capture, and at start.
#[test]
fn a_simulated_camera_delivers_its_rectangle() {
    static RING: SoftRing<64> = SoftRing::new();
    let (mut words, mut pixels) = ([0u32; 32], [0u16; 64]);
    let mut source = SimulatedCamera::new(&RING, DataWidth::Bits16, &mut words, &mut pixels);
    let cam = camera(4, 3, 16);
    let at = crop(2, 1, 9, 5);
    assert_eq!(
        source.check_crop(camera(3, 3, 16), at),
        Err(CropFault::FramePixels {
            pixels: 9,
            multiple: 2
        })
    );
    assert_eq!(source.start(camera(3, 3, 16), Some(at)), Err(CameraRefused));
    assert_eq!(source.check_crop(cam, at), Ok(()));
    source.start(cam, Some(at)).unwrap();
    let capture = RING.capture().unwrap();
    assert_eq!(capture.crop, Some(at));
    assert_eq!(capture.sensor(), camera(9, 5, 16));
    let mut crop = SensorCrop::new(DataWidth::Bits16, capture.camera, capture.crop);
    let sensor = sensor_frame(9, 5, 0);
    let mut out = [0u32; 32];
    let n = crop.keep_packed(&sensor, &mut out);
    assert!(RING.write(capture.id, &out[..n]));
    assert!(RING.end_frame(capture.id));
    let mut got = Vec::new();
    while let Some((frame, first, run)) = poll_run(&mut source) {
        assert_eq!((frame, first as usize), (0, got.len()));
        got.extend(run);
    }
    assert_eq!(got, rectangle(&sensor, 9, cam, at));
}
