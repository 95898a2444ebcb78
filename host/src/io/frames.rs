//! Camera frame cubes on disk: their shape, how their bytes become pixels,
//! reading them frame by frame ([`FrameSource`]) or whole ([`read_frames`]),
//! and checking frames against a camera ([`check_frame`]).

use std::fmt;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use brightpix_protocol::Camera;

use super::{aot, fits_in, npy, shape_string, write_array, FileFormat, IoError};

/// Size of a frame cube, in NumPy axis order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameShape {
    pub frames: usize,
    pub height: usize,
    pub width: usize,
}

impl FrameShape {
    pub fn pixels_per_frame(&self) -> usize {
        self.width * self.height
    }
}

impl fmt::Display for FrameShape {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} frame(s) of {}x{} (width x height)",
            self.frames, self.width, self.height
        )
    }
}

/// How the raw bytes of one frame become `u16` pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Encoding {
    /// One unsigned byte per pixel.
    U8,
    /// Unsigned 16-bit.
    U16 { big_endian: bool },
}

impl Encoding {
    pub(crate) fn bytes_per_pixel(&self) -> usize {
        match self {
            Encoding::U8 => 1,
            Encoding::U16 { .. } => 2,
        }
    }
}

/// Where the frames are in an opened file.
pub(crate) struct FrameLayout {
    pub shape: FrameShape,
    pub data_offset: u64,
    pub encoding: Encoding,
    /// The whole cube, already decoded, when it cannot be read frame by frame
    /// (a Fortran-ordered `.npy`).
    pub preloaded: Option<Vec<u16>>,
}

/// Frames from a `.npy` or FITS file, one at a time.
///
/// Accepted data: `.npy` of dtype uint8 or uint16 (either byte order), FITS
/// of integer BITPIX (8, 16, 32, 64) with `BSCALE = 1` and an integer `BZERO`
/// (BITPIX 16 + `BZERO = 32768` is unsigned 16-bit), shape
/// (frames, height, width) or a single (height, width) frame. Each pixel must
/// be in `0..=65535`, and with [`FrameSource::open_for_camera`] in
/// `0..2^bit_depth`.
pub struct FrameSource {
    path: PathBuf,
    file: File,
    /// FITS frames, read by cfitsio (the other fields then serve `.npy`).
    fits: Option<fits_in::FitsImage>,
    values: Vec<f64>,
    layout: FrameLayout,
    camera: Option<Camera>,
    next: usize,
    buffer: Vec<u8>,
}

impl fmt::Debug for FrameSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("FrameSource")
            .field("path", &self.path)
            .field("shape", &self.layout.shape)
            .field("next", &self.next)
            .finish()
    }
}

impl FrameSource {
    /// Opens a frame file and reads its header; no pixels are read yet.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, IoError> {
        Self::open_hdu(path, None)
    }

    /// [`FrameSource::open`]; in a FITS file, the frames of the HDU `hdu`
    /// (an index, 0 the primary, or an `EXTNAME`) instead of the first HDU
    /// holding an image. Tile-compressed images are read like any other.
    pub fn open_hdu(path: impl AsRef<Path>, hdu: Option<&str>) -> Result<Self, IoError> {
        Self::open_sensor(path, hdu, None)
    }

    /// [`FrameSource::open_hdu`]; an AOT file (see [`aot`]) without `hdu`
    /// gives the detector pixel intensities of its Shack-Hartmann sensor
    /// `sensor` (a `UID`; `None`: the file's only sensor). `sensor` for any
    /// other file, or with `hdu`, is an error.
    pub fn open_sensor(
        path: impl AsRef<Path>,
        hdu: Option<&str>,
        sensor: Option<&str>,
    ) -> Result<Self, IoError> {
        let path = path.as_ref();
        let fits = FileFormat::from_path(path)? == FileFormat::Fits;
        if fits && hdu.is_none() {
            if let Some(at) = aot::locate_pixels(path, sensor)? {
                return Self::open_image(&at.file, at.hdu.as_deref());
            }
        }
        if let Some(name) = sensor {
            return Err(IoError::unexpected(
                path,
                if hdu.is_some() {
                    format!("--sensor {name} with --hdu")
                } else {
                    format!("--sensor {name} for a file that is not AOT (no AOT-VERS keyword)")
                },
                "--sensor only for an AOT file, without --hdu",
            ));
        }
        Self::open_image(path, hdu)
    }

    /// Opens the frames of `hdu` in `path` (`.npy`, or any FITS image).
    fn open_image(path: &Path, hdu: Option<&str>) -> Result<Self, IoError> {
        let format = FileFormat::from_path(path)?;
        if hdu.is_some() && format != FileFormat::Fits {
            return Err(IoError::unexpected(
                path,
                "--hdu for a file that is not FITS",
                "a FITS file with --hdu",
            ));
        }
        let mut file = File::open(path).map_err(|e| IoError::io(path, e))?;
        let mut fits = None;
        let layout = match format {
            FileFormat::Npy => npy::frame_layout(path, &mut file)?,
            FileFormat::Fits => {
                let mut image = fits_in::open_image(path, hdu)?;
                let layout = fits_frame_layout(path, &image)?;
                // A truncated file fails here, before any work, not at its last frame.
                let total = layout.shape.frames * layout.shape.pixels_per_frame();
                if total > 0 {
                    image.read(path, total - 1, 1, &mut Vec::new())?;
                }
                fits = Some(image);
                layout
            }
        };
        if layout.preloaded.is_none() && fits.is_none() {
            let needed = layout.data_offset
                + (layout.shape.frames * layout.shape.pixels_per_frame()) as u64
                    * layout.encoding.bytes_per_pixel() as u64;
            let len = file.metadata().map_err(|e| IoError::io(path, e))?.len();
            if len < needed {
                return Err(IoError::malformed(
                    path,
                    format!(
                        "file is truncated: {} needs {needed} bytes, the file has {len}",
                        layout.shape
                    ),
                ));
            }
        }
        Ok(FrameSource {
            path: path.to_path_buf(),
            file,
            fits,
            values: Vec::new(),
            layout,
            camera: None,
            next: 0,
            buffer: Vec::new(),
        })
    }

    /// Opens a frame file for `camera`: the frame size must be the camera's,
    /// and every frame read is checked against the camera's bit depth.
    pub fn open_for_camera(path: impl AsRef<Path>, camera: &Camera) -> Result<Self, IoError> {
        let mut source = Self::open(path)?;
        source.set_camera(camera)?;
        Ok(source)
    }

    /// Checks the frame size against `camera` and, from now on, every pixel
    /// read against its bit depth.
    pub fn set_camera(&mut self, camera: &Camera) -> Result<(), IoError> {
        let s = self.layout.shape;
        if s.width != camera.width as usize || s.height != camera.height as usize {
            return Err(IoError::unexpected(
                &self.path,
                format!("frames of {}x{} (width x height)", s.width, s.height),
                format!(
                    "{}x{} frames, the configured camera size",
                    camera.width, camera.height
                ),
            ));
        }
        self.camera = Some(*camera);
        Ok(())
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn shape(&self) -> FrameShape {
        self.layout.shape
    }

    /// Number of frames in the file.
    pub fn len(&self) -> usize {
        self.layout.shape.frames
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Reads frame `index` (0-based) into `out`, replacing its contents.
    pub fn read_frame_into(&mut self, index: usize, out: &mut Vec<u16>) -> Result<(), IoError> {
        out.clear();
        self.read_frames_into(index, 1, out)
    }

    /// Reads frames `first .. first + count` and appends them to `out`,
    /// frame after frame (see [`read_frames_to`](Self::read_frames_to)).
    /// On an error `out` is as it was.
    pub fn read_frames_into(
        &mut self,
        first: usize,
        count: usize,
        out: &mut Vec<u16>,
    ) -> Result<(), IoError> {
        self.check_range(first, count)?;
        let start = out.len();
        out.resize(start + count * self.layout.shape.pixels_per_frame(), 0);
        let read = self.read_frames_to(first, &mut out[start..]);
        if read.is_err() {
            out.truncate(start);
        }
        read
    }

    /// Reads frames from `first` on into `out`, as many as it holds (its
    /// length a whole number of frames), frame after frame: a run of `.npy`
    /// frames in one read, straight into `out` (uint16 in the machine's
    /// byte order needs no decoding). A caller that reads batch after batch
    /// into the same buffer writes each pixel once.
    pub fn read_frames_to(&mut self, first: usize, out: &mut [u16]) -> Result<(), IoError> {
        let shape = self.layout.shape;
        let n = shape.pixels_per_frame();
        let count = out.len().checked_div(n).unwrap_or(0);
        if count * n != out.len() {
            return Err(IoError::unexpected(
                &self.path,
                format!("a buffer of {} pixels", out.len()),
                format!("whole frames of {n} pixels"),
            ));
        }
        self.check_range(first, count)?;
        if out.is_empty() {
            // Nothing to read (no frame asked for, or frames of no pixels).
            return Ok(());
        }
        if let Some(fits) = &mut self.fits {
            for (k, frame) in out.chunks_exact_mut(n).enumerate() {
                let index = first + k;
                fits.read(&self.path, index * n, n, &mut self.values)?;
                for (pixel, (&v, p)) in self.values.iter().zip(frame.iter_mut()).enumerate() {
                    if v.is_nan() {
                        return Err(pixel_error(
                            &self.path,
                            index,
                            shape.width,
                            pixel,
                            PixelProblem::Blank,
                        ));
                    }
                    if !(0.0..=65535.0).contains(&v) || v.fract() != 0.0 {
                        let problem = if v.fract() != 0.0 {
                            PixelProblem::NotInteger(v)
                        } else {
                            PixelProblem::Range(v.clamp(i64::MIN as f64, i64::MAX as f64) as i64)
                        };
                        return Err(pixel_error(&self.path, index, shape.width, pixel, problem));
                    }
                    *p = v as u16;
                }
            }
        } else if let Some(all) = &self.layout.preloaded {
            out.copy_from_slice(&all[first * n..(first + count) * n]);
        } else {
            let encoding = self.layout.encoding;
            let offset = self.layout.data_offset + (first * n * encoding.bytes_per_pixel()) as u64;
            self.file
                .seek(SeekFrom::Start(offset))
                .and_then(|_| read_pixels(&mut self.file, encoding, out, &mut self.buffer))
                .map_err(|e| IoError::io(&self.path, e))?;
        }
        if let Some(camera) = &self.camera {
            for (k, frame) in out.chunks_exact(n).enumerate() {
                check_frame(&self.path, first + k, shape.width, frame, camera)?;
            }
        }
        Ok(())
    }

    /// `first .. first + count` are frames of the file.
    fn check_range(&self, first: usize, count: usize) -> Result<(), IoError> {
        let frames = self.layout.shape.frames;
        if first.checked_add(count).is_some_and(|end| end <= frames) {
            return Ok(());
        }
        Err(IoError::unexpected(
            &self.path,
            format!(
                "a request for frame {}",
                first.saturating_add(count.max(1) - 1)
            ),
            format!("a frame index below {frames}"),
        ))
    }

    /// Reads frame `index` (0-based).
    pub fn read_frame(&mut self, index: usize) -> Result<Vec<u16>, IoError> {
        let mut out = Vec::with_capacity(self.layout.shape.pixels_per_frame());
        self.read_frame_into(index, &mut out)?;
        Ok(out)
    }

    /// Reads all remaining frames into one cube.
    pub fn read_all(mut self) -> Result<FrameCube, IoError> {
        let shape = self.layout.shape;
        let mut pixels = Vec::with_capacity(shape.frames * shape.pixels_per_frame());
        self.read_frames_into(0, shape.frames, &mut pixels)?;
        Ok(FrameCube { shape, pixels })
    }
}

/// Frames in order; after an error the iteration goes on with the next frame.
impl Iterator for FrameSource {
    type Item = Result<Vec<u16>, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.next >= self.layout.shape.frames {
            return None;
        }
        let index = self.next;
        self.next += 1;
        Some(self.read_frame(index))
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let left = self.layout.shape.frames - self.next;
        (left, Some(left))
    }
}

impl ExactSizeIterator for FrameSource {}

/// A whole cube of frames in memory, row-major.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FrameCube {
    pub shape: FrameShape,
    /// `frames * height * width` raw pixels.
    pub pixels: Vec<u16>,
}

impl FrameCube {
    /// Frame `index` (0-based). Panics if out of range.
    pub fn frame(&self, index: usize) -> &[u16] {
        let n = self.shape.pixels_per_frame();
        &self.pixels[index * n..(index + 1) * n]
    }

    pub fn frames(&self) -> impl Iterator<Item = &[u16]> {
        self.pixels
            .chunks_exact(self.shape.pixels_per_frame().max(1))
    }

    /// Writes the cube as uint16 `.npy` or FITS (BITPIX 16, BZERO 32768).
    pub fn write(&self, path: impl AsRef<Path>) -> Result<(), IoError> {
        let s = self.shape;
        write_array(path, &[s.frames, s.height, s.width], &self.pixels)
    }
}

/// Loads every frame of a `.npy` or FITS file.
pub fn read_frames(path: impl AsRef<Path>) -> Result<FrameCube, IoError> {
    FrameSource::open(path)?.read_all()
}

/// Loads every frame, checking size and bit depth against `camera`.
pub fn read_frames_for_camera(
    path: impl AsRef<Path>,
    camera: &Camera,
) -> Result<FrameCube, IoError> {
    FrameSource::open_for_camera(path, camera)?.read_all()
}

/// Checks a frame's pixels against the camera's bit depth: the first value
/// `>= 2^bit_depth` is an error naming frame, row, column and value. `path`
/// only names the source in the error.
pub fn check_frame(
    path: &Path,
    frame_index: usize,
    width: usize,
    frame: &[u16],
    camera: &Camera,
) -> Result<(), IoError> {
    let max = camera.max_raw();
    match frame.iter().position(|&v| v > max) {
        None => Ok(()),
        Some(pixel) => Err(IoError::PixelRange {
            path: path.to_path_buf(),
            frame: frame_index,
            row: pixel / width.max(1),
            column: pixel % width.max(1),
            value: frame[pixel] as i64,
            bit_depth: camera.bit_depth,
        }),
    }
}

/// What is wrong with a decoded pixel.
#[derive(Debug)]
pub(crate) enum PixelProblem {
    Range(i64),
    Blank,
    /// A scaled FITS value (`BSCALE`, `BZERO`) that is not a whole count.
    NotInteger(f64),
}

/// The frame shape of a FITS image: integer data of 2 (one frame) or 3 axes.
fn fits_frame_layout(path: &Path, image: &fits_in::FitsImage) -> Result<FrameLayout, IoError> {
    let expected = "an image of NAXIS 2 (one frame) or 3 (NAXIS3 frames)";
    let found = format!(
        "{}: a {} image of shape {} (NAXIS = {})",
        image.describe,
        if image.integer {
            "integer"
        } else {
            "floating-point"
        },
        shape_string(&image.shape),
        image.shape.len()
    );
    // Floating-point images are read too: each value must be a whole count.
    let shape = match image.shape[..] {
        [height, width] => FrameShape {
            frames: 1,
            height,
            width,
        },
        [frames, height, width] => FrameShape {
            frames,
            height,
            width,
        },
        _ => return Err(IoError::unexpected(path, found, expected)),
    };
    Ok(FrameLayout {
        shape,
        data_offset: 0,
        encoding: Encoding::U16 { big_endian: true },
        preloaded: None,
    })
}

fn pixel_error(
    path: &Path,
    frame: usize,
    width: usize,
    pixel: usize,
    problem: PixelProblem,
) -> IoError {
    let (row, column) = (pixel / width.max(1), pixel % width.max(1));
    match problem {
        PixelProblem::Range(value) => IoError::PixelRange {
            path: path.to_path_buf(),
            frame,
            row,
            column,
            value,
            bit_depth: 16,
        },
        PixelProblem::Blank => IoError::BlankPixel {
            path: path.to_path_buf(),
            frame,
            row,
            column,
        },
        PixelProblem::NotInteger(value) => IoError::malformed(
            path,
            format!(
                "frame {frame}, row {row}, column {column}: value {value} (after BSCALE and BZERO) is not a whole camera count"
            ),
        ),
    }
}

/// Reads `out.len()` pixels of `encoding` from `file` into `out`: 16-bit
/// pixels straight into `out`'s memory (then put in the machine's byte
/// order in place), 8-bit ones through `buffer`.
fn read_pixels(
    file: &mut File,
    encoding: Encoding,
    out: &mut [u16],
    buffer: &mut Vec<u8>,
) -> std::io::Result<()> {
    match encoding {
        Encoding::U8 => {
            buffer.resize(out.len(), 0);
            file.read_exact(buffer)?;
            for (p, &b) in out.iter_mut().zip(buffer.iter()) {
                *p = b as u16;
            }
        }
        Encoding::U16 { big_endian } => {
            // SAFETY: `out` is `2 len` initialised bytes, and any bytes are
            // a valid u16.
            let bytes = unsafe {
                std::slice::from_raw_parts_mut(out.as_mut_ptr() as *mut u8, 2 * out.len())
            };
            file.read_exact(bytes)?;
            if big_endian != cfg!(target_endian = "big") {
                for v in out.iter_mut() {
                    *v = v.swap_bytes();
                }
            }
        }
    }
    Ok(())
}
