//! Camera frames and calibration maps on disk: NumPy `.npy` and FITS (read
//! by cfitsio: the primary HDU or an image extension, tile-compressed
//! included), chosen by file extension; results (slopes, flux, validity,
//! provenance) in [`results`].
//!
//! - Frames: [`FrameSource`] streams a cube of shape (frames, height, width)
//!   one frame at a time (seeking in the file, never loading the whole cube
//!   unless the `.npy` is Fortran-ordered); [`read_frames`] loads it whole.
//!   A frame is a row-major `Vec<u16>` of raw camera counts.
//! - Maps and other arrays: [`read_array`] / [`read_map`] return an [`Array`]
//!   of `f64` in row-major (NumPy) axis order, whatever the stored type.
//! - Writing: [`write_array`] writes `u8`, `u16`, `i16`, `i32`, `f32` or `f64`
//!   arrays of any shape to `.npy` or FITS.
//!
//! Shapes are always given in NumPy order, slowest axis first: a FITS cube
//! with `NAXIS1` = width, `NAXIS2` = height, `NAXIS3` = frames has shape
//! `[frames, height, width]`.

pub mod aot;
pub mod fits;
mod fits_in;
mod fits_out;
pub mod npy;
pub mod output;
pub mod results;

pub use output::{check_outputs, Appender, Staged};
pub use results::{
    check_result_outputs, write_results, Layout, Provenance, Raw, Results, ResultsFormat,
};

use std::fmt;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use brightpix_protocol::Camera;

/// Why a frame or map file could not be read or written. Every variant names
/// the file.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The operating system refused (missing file, permissions, short read).
    #[error("{}: {error}", path.display())]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    /// The extension is none of `.npy`, `.fits`, `.fit`, `.fts`.
    #[error(
        "{}: unrecognised file type; expected a .npy (NumPy) or .fits/.fit/.fts/.fz (FITS) file",
        path.display()
    )]
    UnknownFormat { path: PathBuf },
    /// The file is not a well-formed `.npy` or FITS file.
    #[error("{}: {message}", path.display())]
    Malformed { path: PathBuf, message: String },
    /// Well-formed, but not the data type or shape that was asked for.
    #[error("{}: found {found}; expected {expected}", path.display())]
    Unexpected {
        path: PathBuf,
        found: String,
        expected: String,
    },
    /// A frame pixel that is not a raw camera value.
    #[error(
        "{}: frame {frame}, row {row}, column {column}: value {value} is outside the {bit_depth}-bit camera range 0..={}",
        path.display(),
        (1u32 << bit_depth) - 1
    )]
    PixelRange {
        path: PathBuf,
        frame: usize,
        row: usize,
        column: usize,
        value: i64,
        bit_depth: u8,
    },
    /// A frame pixel flagged undefined by the FITS `BLANK` keyword.
    #[error("{}: frame {frame}, row {row}, column {column}: undefined pixel (FITS BLANK)", path.display())]
    BlankPixel {
        path: PathBuf,
        frame: usize,
        row: usize,
        column: usize,
    },
}

impl IoError {
    pub(crate) fn io(path: &Path, error: std::io::Error) -> Self {
        IoError::Io {
            path: path.to_path_buf(),
            error,
        }
    }
    pub(crate) fn malformed(path: &Path, message: impl Into<String>) -> Self {
        IoError::Malformed {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }
    pub(crate) fn unexpected(
        path: &Path,
        found: impl Into<String>,
        expected: impl Into<String>,
    ) -> Self {
        IoError::Unexpected {
            path: path.to_path_buf(),
            found: found.into(),
            expected: expected.into(),
        }
    }
    /// The file this error is about.
    pub fn path(&self) -> &Path {
        match self {
            IoError::Io { path, .. }
            | IoError::UnknownFormat { path }
            | IoError::Malformed { path, .. }
            | IoError::Unexpected { path, .. }
            | IoError::PixelRange { path, .. }
            | IoError::BlankPixel { path, .. } => path,
        }
    }
}

/// File formats, detected by extension (case-insensitive).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FileFormat {
    /// NumPy `.npy`.
    Npy,
    /// FITS `.fits`, `.fit`, `.fts`, `.fz` (fpack): read by cfitsio.
    Fits,
}

impl FileFormat {
    pub fn from_path(path: &Path) -> Result<Self, IoError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("npy") => Ok(FileFormat::Npy),
            Some("fits" | "fit" | "fts" | "fz") => Ok(FileFormat::Fits),
            _ => Err(IoError::UnknownFormat {
                path: path.to_path_buf(),
            }),
        }
    }
}

/// `(2, 3)`-style rendering of a shape, as NumPy prints it.
pub fn shape_string(shape: &[usize]) -> String {
    match shape {
        [one] => format!("({one},)"),
        _ => {
            let parts: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
            format!("({})", parts.join(", "))
        }
    }
}

/// An n-dimensional array of `f64`, row-major, shape slowest axis first.
#[derive(Clone, Debug, PartialEq)]
pub struct Array {
    pub shape: Vec<usize>,
    pub data: Vec<f64>,
}

impl Array {
    /// Number of dimensions.
    pub fn ndim(&self) -> usize {
        self.shape.len()
    }
}

/// Reads any numeric array (integer or float, any shape) as `f64`.
/// FITS values have `BSCALE`/`BZERO` applied and `BLANK` pixels become NaN.
pub fn read_array(path: impl AsRef<Path>) -> Result<Array, IoError> {
    let path = path.as_ref();
    match FileFormat::from_path(path)? {
        FileFormat::Npy => npy::read_array(path),
        FileFormat::Fits => fits_in::read_array(path),
    }
}

/// Reads a 1-D or 2-D map as `f64`; other dimensionalities are an error.
pub fn read_map(path: impl AsRef<Path>) -> Result<Array, IoError> {
    let path = path.as_ref();
    let array = read_array(path)?;
    if !(1..=2).contains(&array.ndim()) {
        return Err(IoError::unexpected(
            path,
            format!(
                "a {}-D array of shape {}",
                array.ndim(),
                shape_string(&array.shape)
            ),
            "a 1-D or 2-D map",
        ));
    }
    Ok(array)
}

mod sealed {
    pub trait Sealed {}
}

/// Element types that can be written: `u8`, `u16`, `i16`, `i32`, `f32`, `f64`.
/// In FITS, `u16` is written as BITPIX 16 with `BZERO = 32768` (the
/// astronomy convention for unsigned 16-bit data).
pub trait Element: npyz::AutoSerialize + Copy + sealed::Sealed {
    /// FITS BITPIX of this type.
    const BITPIX: i32;
    /// FITS BZERO needed to store this type, if any.
    const BZERO: Option<i64> = None;
    /// Appends the FITS (big-endian, BZERO-offset) encoding.
    fn put_fits(self, out: &mut Vec<u8>);
}

macro_rules! element {
    ($t:ty, $bitpix:expr) => {
        impl sealed::Sealed for $t {}
        impl Element for $t {
            const BITPIX: i32 = $bitpix;
            fn put_fits(self, out: &mut Vec<u8>) {
                out.extend_from_slice(&self.to_be_bytes());
            }
        }
    };
}
element!(u8, 8);
element!(i16, 16);
element!(i32, 32);
element!(f32, -32);
element!(f64, -64);

impl sealed::Sealed for u16 {}
impl Element for u16 {
    const BITPIX: i32 = 16;
    const BZERO: Option<i64> = Some(32768);
    fn put_fits(self, out: &mut Vec<u8>) {
        // stored = value - 32768, as i16: flipping the top bit does exactly that.
        out.extend_from_slice(&(self ^ 0x8000).to_be_bytes());
    }
}

/// Writes `data` (row-major, `shape` slowest axis first) as `.npy` or FITS
/// by the extension of `path`: whole or not at all (a temporary sibling,
/// then a rename; see [`stage_array`] to commit several outputs together).
pub fn write_array<T: Element>(
    path: impl AsRef<Path>,
    shape: &[usize],
    data: &[T],
) -> Result<(), IoError> {
    stage_array(path, shape, data)?.commit()
}

/// [`write_array`] into a temporary sibling of `path`, moved into place by
/// [`Staged::commit`] (and removed if dropped uncommitted).
pub fn stage_array<T: Element>(
    path: impl AsRef<Path>,
    shape: &[usize],
    data: &[T],
) -> Result<Staged, IoError> {
    let path = path.as_ref();
    FileFormat::from_path(path)?;
    Staged::write(path, |temp| write_in_place(temp, path, shape, data))
}

/// Writes the file `temp` in the format of `path`'s extension.
fn write_in_place<T: Element>(
    temp: &Path,
    path: &Path,
    shape: &[usize],
    data: &[T],
) -> Result<(), IoError> {
    let format = FileFormat::from_path(path)?;
    let expected: usize = shape.iter().product();
    if expected != data.len() {
        return Err(IoError::unexpected(
            path,
            format!("{} values to write", data.len()),
            format!("{expected} values for shape {}", shape_string(shape)),
        ));
    }
    match format {
        FileFormat::Npy => npy::write(temp, shape, data),
        FileFormat::Fits => fits::write(temp, shape, data),
    }
}

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

#[cfg(test)]
pub(crate) mod test_util {
    use std::path::PathBuf;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// A fresh empty directory under the system temp dir.
    pub fn temp_dir(tag: &str) -> PathBuf {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let dir =
            std::env::temp_dir().join(format!("brightpix-test-{}-{tag}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }
}

#[cfg(test)]
mod tests {
    use super::test_util::temp_dir;
    use super::*;

    fn camera(width: u16, height: u16, bit_depth: u8) -> Camera {
        Camera {
            width,
            height,
            bit_depth,
        }
    }

    fn ramp_u16(n: usize) -> Vec<u16> {
        (0..n)
            .map(|i| (i as u64 * 2654435761 % 65536) as u16)
            .collect()
    }

    #[test]
    fn format_by_extension() {
        assert_eq!(
            FileFormat::from_path(Path::new("a/b.npy")).unwrap(),
            FileFormat::Npy
        );
        for name in ["x.fits", "x.FITS", "x.fit", "x.fts"] {
            assert_eq!(
                FileFormat::from_path(Path::new(name)).unwrap(),
                FileFormat::Fits
            );
        }
        for name in ["x.txt", "x", "x.fits.gz", "x.npz"] {
            let err = FileFormat::from_path(Path::new(name)).unwrap_err();
            assert!(matches!(err, IoError::UnknownFormat { .. }), "{name}");
            let msg = err.to_string();
            assert!(
                msg.contains(name) && msg.contains(".npy") && msg.contains(".fits"),
                "{msg}"
            );
        }
    }

    #[test]
    fn frames_round_trip_u16_and_u8_both_formats() {
        let dir = temp_dir("frames");
        let shape = FrameShape {
            frames: 3,
            height: 5,
            width: 7,
        };
        let pixels = ramp_u16(3 * 5 * 7);
        let cube = FrameCube {
            shape,
            pixels: pixels.clone(),
        };
        for ext in ["npy", "fits"] {
            let path = dir.join(format!("cube16.{ext}"));
            cube.write(&path).unwrap();
            assert_eq!(read_frames(&path).unwrap(), cube, "{ext}");
            // streaming, out of order, and as an iterator
            let mut source = FrameSource::open(&path).unwrap();
            assert_eq!(source.shape(), shape);
            assert_eq!(source.read_frame(2).unwrap(), cube.frame(2));
            assert_eq!(source.read_frame(0).unwrap(), cube.frame(0));
            let frames: Vec<Vec<u16>> = source.map(|f| f.unwrap()).collect();
            assert_eq!(frames.len(), 3);
            assert_eq!(frames[1], cube.frame(1));

            let bytes: Vec<u8> = pixels.iter().map(|&v| v as u8).collect();
            let path = dir.join(format!("cube8.{ext}"));
            write_array(&path, &[3, 5, 7], &bytes).unwrap();
            let back = read_frames(&path).unwrap();
            assert_eq!(back.shape, shape);
            assert!(back.pixels.iter().zip(&bytes).all(|(&a, &b)| a == b as u16));
        }
    }

    #[test]
    fn single_2d_frame_is_one_frame() {
        let dir = temp_dir("single");
        let data = ramp_u16(4 * 6);
        for ext in ["npy", "fits"] {
            let path = dir.join(format!("one.{ext}"));
            write_array(&path, &[4, 6], &data).unwrap();
            let cube = read_frames(&path).unwrap();
            assert_eq!(
                cube.shape,
                FrameShape {
                    frames: 1,
                    height: 4,
                    width: 6
                }
            );
            assert_eq!(cube.pixels, data);
        }
    }

    #[test]
    fn frames_checked_against_camera() {
        let dir = temp_dir("camera");
        let mut data = vec![100u16; 2 * 3 * 4];
        data[12 + 4 + 2] = 4096; // frame 1, row 1, column 2
        for ext in ["npy", "fits"] {
            let path = dir.join(format!("f.{ext}"));
            write_array(&path, &[2, 3, 4], &data).unwrap();
            // 16-bit camera: fine
            read_frames_for_camera(&path, &camera(4, 3, 16)).unwrap();
            // 12-bit camera: 4096 is out of range
            let err = read_frames_for_camera(&path, &camera(4, 3, 12)).unwrap_err();
            match &err {
                IoError::PixelRange {
                    frame: 1,
                    row: 1,
                    column: 2,
                    value: 4096,
                    bit_depth: 12,
                    ..
                } => {}
                other => panic!("{other:?}"),
            }
            let msg = err.to_string();
            assert!(
                msg.contains("frame 1, row 1, column 2: value 4096"),
                "{msg}"
            );
            assert!(msg.contains("0..=4095"), "{msg}");
            // frame 0 is still readable
            let mut source = FrameSource::open_for_camera(&path, &camera(4, 3, 12)).unwrap();
            source.read_frame(0).unwrap();
            // wrong size
            let err = FrameSource::open_for_camera(&path, &camera(3, 4, 16)).unwrap_err();
            assert!(matches!(err, IoError::Unexpected { .. }), "{err}");
            assert!(err.to_string().contains("4x3"), "{err}");
        }
    }

    #[test]
    fn a_run_of_frames_is_read_at_once_as_frame_by_frame() {
        let dir = temp_dir("runs");
        let pixels = ramp_u16(4 * 3 * 5);
        let bytes: Vec<u8> = pixels.iter().map(|&v| v as u8).collect();
        for ext in ["npy", "fits"] {
            let path16 = dir.join(format!("run16.{ext}"));
            write_array(&path16, &[4, 3, 5], &pixels).unwrap();
            let path8 = dir.join(format!("run8.{ext}"));
            write_array(&path8, &[4, 3, 5], &bytes).unwrap();
            for path in [&path16, &path8] {
                let mut source = FrameSource::open(path).unwrap();
                let mut expected = vec![7u16];
                for index in 1..4 {
                    expected.extend(source.read_frame(index).unwrap());
                }
                // Appended after what `out` holds.
                let mut out = vec![7u16];
                source.read_frames_into(1, 3, &mut out).unwrap();
                assert_eq!(out, expected, "{}", path.display());
                let mut none = Vec::new();
                source.read_frames_into(4, 0, &mut none).unwrap();
                assert!(none.is_empty());
                let err = source.read_frames_into(2, 3, &mut out).unwrap_err();
                assert!(err.to_string().contains("frame 4"), "{err}");
                assert_eq!(out, expected, "a failed read leaves `out` as it was");
                // Into a buffer of whole frames, over what it held.
                let mut buffer = vec![9u16; 2 * 15];
                source.read_frames_to(2, &mut buffer).unwrap();
                assert_eq!(buffer, expected[1 + 15..]);
                let err = source.read_frames_to(0, &mut buffer[..7]).unwrap_err();
                assert!(err.to_string().contains("whole frames of 15"), "{err}");
            }
        }
        // The camera check names the frame within the run.
        let mut data = vec![100u16; 3 * 3 * 5];
        data[2 * 15 + 7] = 4096; // frame 2, row 1, column 2
        let path = dir.join("bad.npy");
        write_array(&path, &[3, 3, 5], &data).unwrap();
        let mut source = FrameSource::open_for_camera(&path, &camera(5, 3, 12)).unwrap();
        match source.read_frames_into(0, 3, &mut Vec::new()).unwrap_err() {
            IoError::PixelRange {
                frame: 2,
                row: 1,
                column: 2,
                ..
            } => {}
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn truncated_cube_is_an_error() {
        let dir = temp_dir("trunc");
        for ext in ["npy", "fits"] {
            let path = dir.join(format!("t.{ext}"));
            write_array(&path, &[4, 30, 30], &vec![1u16; 3600]).unwrap();
            let len = std::fs::metadata(&path).unwrap().len();
            let file = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
            file.set_len(len - 3000).unwrap();
            let err = FrameSource::open(&path).unwrap_err();
            assert!(err.to_string().contains("truncated"), "{err}");
        }
    }

    #[test]
    fn read_map_rejects_3d() {
        let dir = temp_dir("map3d");
        let path = dir.join("m.npy");
        write_array(&path, &[2, 2, 2], &[0.0f64; 8]).unwrap();
        let err = read_map(&path).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("(2, 2, 2)") && msg.contains("1-D or 2-D"),
            "{msg}"
        );
        assert_eq!(read_array(&path).unwrap().shape, vec![2, 2, 2]);
    }

    #[test]
    fn write_checks_length() {
        let dir = temp_dir("len");
        let err = write_array(dir.join("x.npy"), &[2, 3], &[1.0f64; 5]).unwrap_err();
        assert!(err.to_string().contains("6 values"), "{err}");
    }

    #[test]
    fn missing_file_names_path() {
        let err = read_array("/nonexistent/dir/bg.fits").unwrap_err();
        assert!(matches!(err, IoError::Io { .. }));
        assert!(
            err.to_string().contains("/nonexistent/dir/bg.fits"),
            "{err}"
        );
    }
}
