//! Rust errors as Python exceptions, each carrying the Rust error's message.
//!
//! | Rust error | Python exception |
//! |---|---|
//! | a configuration that does not validate, a bad value or shape | `ValueError` |
//! | a configuration or data file that cannot be read | `FileNotFoundError` / `OSError` |
//! | a result file that cannot be written | `OSError`; an unknown extension `ValueError` |
//! | a port that cannot be opened | `FileNotFoundError` / `PermissionError` / `OSError` |
//! | a device that does not answer, or stops | `TimeoutError`, `ConnectionError` |
//! | a device that refuses a request, or speaks another protocol | `brightpix.DeviceError` |
//! | device results that differ from the reference | `brightpix.MismatchError` |

use std::io;

use brightpix::config_file::{ConfigFileError, ConfigFileErrorKind};
use brightpix::io::IoError;
use brightpix::link::LinkError;
use pyo3::exceptions::{
    PyConnectionError, PyFileNotFoundError, PyOSError, PyPermissionError, PyRuntimeError,
    PyTimeoutError, PyValueError,
};
use pyo3::prelude::*;

pyo3::create_exception!(
    brightpix,
    DeviceError,
    PyRuntimeError,
    "The device refused a request, dropped a frame, or speaks another protocol version."
);
pyo3::create_exception!(
    brightpix,
    MismatchError,
    PyRuntimeError,
    "The device's results differ from the reference. `.result` holds what the device sent, \
`.mismatches` the first differences."
);

/// The TOML key a configuration error names, as the keyword of
/// `brightpix.Config(...)` that sets it.
fn keyword(field: &str) -> &str {
    match field {
        "camera" => "width/height/bit_depth",
        "subapertures" | "subapertures.grid" | "subapertures.grid.skip" => "grid",
        "subapertures.window" | "subapertures.file" => "windows",
        "selection.pixels" | "selection.pixels_file" => "n",
        "selection.mean_count" => "mean_count",
        "selection.level_filter" | "selection.level_filter.gain_shift" => "level_filter",
        "calibration.background" | "calibration.background_counts" => "background",
        "calibration.flat" => "flat",
        "calibration.pixel_weight" => "pixel_weight",
        "calibration.flat * calibration.pixel_weight" => "flat * pixel_weight",
        "calibration.threshold_counts" => "threshold",
        "centroid.reference_slopes" => "reference_slopes",
        "centroid.min_flux_counts" => "min_flux",
        other => other,
    }
}

/// A configuration error. From a file: the CLI's message (file, key,
/// problem). From keywords: the keyword and the problem.
pub fn config_error(e: ConfigFileError, from_keywords: bool) -> PyErr {
    let message = if from_keywords {
        match &e.field {
            Some(field) => format!("{}: {}", keyword(field), e.message),
            None => e.message.clone(),
        }
    } else {
        e.to_string()
    };
    match e.kind {
        ConfigFileErrorKind::Read if !e.file.exists() => PyFileNotFoundError::new_err(message),
        ConfigFileErrorKind::Read => PyOSError::new_err(message),
        ConfigFileErrorKind::Data if !from_keywords => PyOSError::new_err(message),
        _ => PyValueError::new_err(message),
    }
}

fn io_error(kind: io::ErrorKind, message: String) -> PyErr {
    match kind {
        io::ErrorKind::NotFound => PyFileNotFoundError::new_err(message),
        io::ErrorKind::PermissionDenied => PyPermissionError::new_err(message),
        io::ErrorKind::TimedOut => PyTimeoutError::new_err(message),
        _ => PyOSError::new_err(message),
    }
}

/// A link error: transport problems are `OSError`s, the device's refusals
/// `DeviceError`, misuse `ValueError`.
pub fn link_error(e: LinkError) -> PyErr {
    let message = e.to_string();
    match &e {
        LinkError::Open { error: source, .. } | LinkError::Fifo { source, .. } => {
            io_error(source.kind(), message)
        }
        LinkError::NoHello { .. }
        | LinkError::Timeout { .. }
        | LinkError::NoSyncEdge { .. }
        | LinkError::WriteStalled { .. } => PyTimeoutError::new_err(message),
        LinkError::Disconnected { .. } => PyConnectionError::new_err(message),
        LinkError::Usage(_) => PyValueError::new_err(message),
        _ => DeviceError::new_err(message),
    }
}

/// An error of the `anyhow` kind the simulated devices return.
pub fn other_error(e: anyhow::Error) -> PyErr {
    let message = format!("{e:#}");
    match e.downcast_ref::<io::Error>() {
        Some(io) => io_error(io.kind(), message),
        None => PyOSError::new_err(message),
    }
}

/// A file the host library could not read or write: the operating system's
/// refusals are `OSError`s, a wrong kind of file a `ValueError`.
pub fn io_file_error(e: IoError) -> PyErr {
    let message = e.to_string();
    match &e {
        IoError::Io { error, .. } => io_error(error.kind(), message),
        _ => PyValueError::new_err(message),
    }
}
