//! `brightpix.read_frames`: camera frames from a file, by the host
//! library's reader (the one `brightpix process --frames` uses).

use std::path::PathBuf;

use brightpix::io::FrameSource;
use pyo3::prelude::*;

use crate::arrays::to_numpy;
use crate::errors::io_file_error;

/// Read camera frames from a file, as ``brightpix process --frames`` does:
/// ``.npy`` (uint8/uint16), a FITS cube (the first image, or ``hdu``: an
/// index or EXTNAME), or an AOT file (Adaptive Optics Telemetry,
/// ``.aot.fits``): the detector pixel intensities of its Shack-Hartmann
/// sensor ``sensor`` (the sensor's UID; default: the file's only sensor).
///
/// Returns a ``uint16`` array of shape ``(frames, height, width)``, ready
/// for :func:`process`. Every pixel must be a whole count in 0..=65535.
///
/// Raises ``ValueError`` naming the file for a file that is not frames: an
/// AOT file with no wavefront sensor, no sensor ``sensor`` (the message
/// lists those there are), a sensor that is not Shack-Hartmann or whose
/// detector has no pixel intensities, ``sensor`` for a file that is not
/// AOT; ``OSError`` (``FileNotFoundError``, ...) when it cannot be read.
#[pyfunction]
#[pyo3(signature = (path, *, sensor = None, hdu = None))]
pub fn read_frames<'py>(
    py: Python<'py>,
    path: PathBuf,
    sensor: Option<String>,
    hdu: Option<String>,
) -> PyResult<Bound<'py, PyAny>> {
    let cube = py
        .detach(|| FrameSource::open_sensor(&path, hdu.as_deref(), sensor.as_deref())?.read_all())
        .map_err(io_file_error)?;
    let s = cube.shape;
    to_numpy(py, cube.pixels, &[s.frames, s.height, s.width])
}
