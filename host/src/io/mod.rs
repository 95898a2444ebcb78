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
mod frames;
pub mod npy;
pub mod output;
pub mod results;

pub use frames::{
    check_frame, read_frames, read_frames_for_camera, FrameCube, FrameShape, FrameSource,
};
pub(crate) use frames::{Encoding, FrameLayout};
pub use output::{check_outputs, Appender, Staged};
pub use results::{
    check_result_outputs, write_results, Layout, Provenance, Raw, Results, ResultsFormat,
};

use std::path::{Path, PathBuf};

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
mod tests;
