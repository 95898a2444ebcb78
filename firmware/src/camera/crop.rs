//! A configuration's crop rectangle (`Config::crop`: a board of a rig sees
//! part of a sensor shared with other boards) at the camera interface:
//!
//! - what the STM32H743's DCMI can crop ([`dcmi_check`]) and the register
//!   values that crop it ([`DcmiCropRegisters`]);
//! - the same crop done in software for the simulated cameras
//!   ([`SensorCrop`]): they make whole-sensor frames, and the board keeps,
//!   as the DCMI does, rows `y .. y + height` and of each of them columns
//!   `x .. x + width`, packed into the words of its bus.
//!
//! # What the DCMI counts (RM0433, "DCMI crop feature", `DCMI_CWSTRT`,
//! `DCMI_CWSIZE`)
//!
//! - `VST` is the first line captured (13 bits), `VLINE` the lines
//!   captured less one (14 bits): lines are camera rows.
//! - `HOFFCNT` is the pixel clocks skipped at the start of each line, and
//!   `CAPCNT` the pixel clocks captured less one (14 bits each). In every
//!   mode a monochrome camera uses (`EDM` 8, 10, 12 or 14 bits) the DCMI
//!   samples one pixel per pixel clock, so both are in pixels here. (An
//!   RGB565 camera on the 8-bit bus would take two clocks a pixel; not a
//!   wavefront sensor's format.)
//! - `CAPCNT` "must correspond to word-aligned data": the pixels of a line
//!   must fill whole 32-bit words, 4 of the 8-bit mode and 2 of the wider
//!   ones. The crop section adds that `CAPCNT` "can only be a multiple of
//!   4 (two least significant bits are forced to 0)", which contradicts its
//!   own encoding (0 means one pixel clock) and ST's examples (which write
//!   the count less one). A width that is a multiple of 4 pixels is whole
//!   words in every mode and loses nothing under either reading, so the
//!   width must be a multiple of 4 at every bit depth. (Not yet checked on
//!   hardware.)
//! - The DMA moves the ring's words in bursts of 4 (`dcmi.rs` on the
//!   board): a frame must be whole bursts, or its last one waits in the DMA
//!   FIFO past the frame's end.
//! - "For B&W ... the maximum input size is 2048 x 2048 pixels": the
//!   sensor, whatever the rectangle.

use brightpix_protocol::wire::CropFault;
use brightpix_protocol::{Camera, Crop};

use super::packing::{pack, DataWidth};

/// Pixels the DCMI's crop width must be a multiple of, at every bit depth
/// (see the module documentation).
pub const DCMI_WIDTH_MULTIPLE: u16 = 4;
/// Words in one DMA burst of the STM32H743 board's camera ring.
pub const DCMI_BURST_WORDS: usize = 4;
/// The DCMI's largest monochrome input, pixels a side.
pub const DCMI_MAX_SENSOR_SIDE: u16 = 2048;

/// Why a DCMI sampling `width` bits cannot capture `camera` (a
/// configuration's camera: the rectangle) at `crop` of its sensor.
pub fn dcmi_check(width: DataWidth, camera: Camera, crop: Crop) -> Result<(), CropFault> {
    if crop.sensor_width > DCMI_MAX_SENSOR_SIDE || crop.sensor_height > DCMI_MAX_SENSOR_SIDE {
        return Err(CropFault::SensorSize {
            width: crop.sensor_width,
            height: crop.sensor_height,
            max: DCMI_MAX_SENSOR_SIDE,
        });
    }
    if !camera.width.is_multiple_of(DCMI_WIDTH_MULTIPLE) {
        return Err(CropFault::Width {
            width: camera.width,
            multiple: DCMI_WIDTH_MULTIPLE,
        });
    }
    frame_check(camera, width.pixels_per_word() * DCMI_BURST_WORDS)
}

/// Why a camera interface whose frames must be a multiple of `multiple`
/// pixels cannot capture `camera`.
pub fn frame_check(camera: Camera, multiple: usize) -> Result<(), CropFault> {
    let pixels = camera.pixel_count();
    if pixels.is_multiple_of(multiple) {
        Ok(())
    } else {
        Err(CropFault::FramePixels {
            pixels: u32::try_from(pixels).unwrap_or(u32::MAX),
            multiple: u16::try_from(multiple).unwrap_or(u16::MAX),
        })
    }
}

/// `DCMI_CWSTRT` and `DCMI_CWSIZE` for a rectangle (one pixel clock a
/// pixel; the counts of `CWSIZE` are less one).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DcmiCropRegisters {
    pub hoffcnt: u16,
    pub vst: u16,
    pub capcnt: u16,
    pub vline: u16,
}

impl DcmiCropRegisters {
    /// `None` for an empty rectangle (a valid configuration has none).
    pub fn of(camera: Camera, crop: Crop) -> Option<DcmiCropRegisters> {
        Some(DcmiCropRegisters {
            hoffcnt: crop.x,
            vst: crop.y,
            capcnt: camera.width.checked_sub(1)?,
            vline: camera.height.checked_sub(1)?,
        })
    }
}

/// The crop of a simulated camera, in software: whole-sensor frames go in,
/// in raster order and in pieces of any length, and the rectangle's pixels
/// come out, packed into words as a bus of `width` packs them (a word that
/// straddles two rows of the rectangle is completed by the next row's
/// pixels, as the DCMI's packer does).
pub struct SensorCrop {
    width: DataWidth,
    sensor_width: u32,
    frame_pixels: u32,
    columns: (u32, u32),
    rows: (u32, u32),
    /// Sensor pixels of the current frame seen so far.
    next: u32,
    pending: [u16; 4],
    pending_len: usize,
}

impl SensorCrop {
    /// The crop of `camera` (a configuration's camera) at `crop` of its
    /// sensor; `None`: the camera is the sensor, every pixel is kept.
    pub fn new(width: DataWidth, camera: Camera, crop: Option<Crop>) -> SensorCrop {
        let crop = crop.unwrap_or(Crop {
            x: 0,
            y: 0,
            sensor_width: camera.width,
            sensor_height: camera.height,
        });
        let (x, y) = (crop.x as u32, crop.y as u32);
        SensorCrop {
            width,
            sensor_width: crop.sensor_width as u32,
            frame_pixels: crop.sensor_width as u32 * crop.sensor_height as u32,
            columns: (x, x + camera.width as u32),
            rows: (y, y + camera.height as u32),
            next: 0,
            pending: [0; 4],
            pending_len: 0,
        }
    }

    /// Sensor pixels in a frame.
    pub fn sensor_pixels(&self) -> usize {
        self.frame_pixels as usize
    }

    /// Takes the next sensor pixels of the frame and calls `keep` with each
    /// run of them inside the rectangle, in order. Pixels past the sensor
    /// frame's end are ignored.
    pub fn keep<'p>(&mut self, pixels: &'p [u16], mut keep: impl FnMut(&'p [u16])) {
        let mut rest = pixels;
        let width = self.sensor_width.max(1);
        while !rest.is_empty() && self.next < self.frame_pixels {
            let (row, column) = (self.next / width, self.next % width);
            let take = (rest.len() as u32).min(width - column);
            if (self.rows.0..self.rows.1).contains(&row) {
                let from = column.max(self.columns.0);
                let to = (column + take).min(self.columns.1);
                if from < to {
                    keep(&rest[(from - column) as usize..(to - column) as usize]);
                }
            }
            rest = &rest[take as usize..];
            self.next += take;
        }
    }

    /// [`SensorCrop::keep`], the kept pixels packed into `out`, which must
    /// hold `pixels.len() / pixels_per_word + 1` words; returns the words
    /// written. Pixels short of a word wait for the next call.
    pub fn keep_packed(&mut self, pixels: &[u16], out: &mut [u32]) -> usize {
        let width = self.width;
        let per_word = width.pixels_per_word();
        let mut written = 0;
        let (mut pending, mut pending_len) = (self.pending, self.pending_len);
        self.keep(pixels, |run| {
            for &p in run {
                pending[pending_len] = p;
                pending_len += 1;
                if pending_len == per_word {
                    written += pack(width, &pending[..per_word], &mut out[written..]);
                    pending_len = 0;
                }
            }
        });
        self.pending = pending;
        self.pending_len = pending_len;
        written
    }

    /// The frame ended: the next pixels start the next frame. A partial
    /// word is dropped (a rectangle of whole words leaves none).
    pub fn end_frame(&mut self) {
        self.next = 0;
        self.pending_len = 0;
    }
}
