//! numpy arrays in and out: camera frames (uint8/uint16, any memory or byte
//! order) checked against a camera, float arrays for configuration maps,
//! and result vectors as shaped arrays.

use brightpix::config_file::ArrayValues;
use brightpix_protocol::Camera;
use numpy::{
    Element, PyArray1, PyArrayDescrMethods, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn,
    PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};

/// Camera frames as one C-contiguous, native-endian uint16 block.
pub struct Frames<'py> {
    array: PyReadonlyArrayDyn<'py, u16>,
    /// Frames in the block.
    pub count: usize,
    /// Given as one `(H, W)` frame rather than a stack.
    pub single: bool,
}

impl Frames<'_> {
    /// All pixels, frame after frame, row-major.
    pub fn pixels(&self) -> &[u16] {
        self.array
            .as_slice()
            .expect("frames were made C-contiguous")
    }
}

fn type_name(obj: &Bound<'_, PyAny>) -> String {
    obj.get_type()
        .name()
        .map_or_else(|_| "?".to_string(), |n| n.to_string())
}

/// `obj` as frames of `camera`: a numpy uint8 or uint16 array of shape
/// `(H, W)` or `(F, H, W)`. Anything else is a `TypeError` (dtype) or a
/// `ValueError` (shape) naming `what`. Copies only when the array is not
/// already C-contiguous, aligned, native uint16.
pub fn frames<'py>(obj: &Bound<'py, PyAny>, camera: &Camera, what: &str) -> PyResult<Frames<'py>> {
    let Ok(array) = obj.cast::<PyUntypedArray>() else {
        return Err(PyTypeError::new_err(format!(
            "{what} must be a numpy array of uint8 or uint16 camera counts, not {}",
            type_name(obj)
        )));
    };
    let dtype = array.dtype();
    let (kind, size) = (dtype.kind(), dtype.itemsize());
    if kind != b'u' || !(size == 1 || size == 2) {
        let hint = match kind {
            b'f' | b'c' => "; camera frames are whole counts: convert with frames.astype(np.uint16) if that is what they hold",
            b'i' | b'u' => "; convert with frames.astype(np.uint16) once the values are known to fit the camera's bit depth",
            _ => "",
        };
        return Err(PyTypeError::new_err(format!(
            "{what} must be uint8 or uint16 camera counts; got dtype {}{hint}",
            dtype.str()?
        )));
    }
    let shape = array.shape().to_vec();
    let (count, single, height, width) = match shape[..] {
        [h, w] => (1, true, h, w),
        [f, h, w] => (f, false, h, w),
        _ => {
            return Err(PyValueError::new_err(format!(
                "{what} must have shape (height, width) or (frames, height, width); got {}",
                shape_text(&shape)
            )))
        }
    };
    if height != camera.height as usize || width != camera.width as usize {
        return Err(PyValueError::new_err(format!(
            "{what} are {height}x{width} pixels (height x width); the configuration's camera is {}x{}",
            camera.height, camera.width
        )));
    }
    let contiguous = as_c_array(obj, "uint16")?;
    let array = contiguous
        .cast::<PyArrayDyn<u16>>()
        .map_err(PyErr::from)?
        .readonly();
    Ok(Frames {
        array,
        count,
        single,
    })
}

/// `numpy.require(obj, dtype=numpy.<dtype>, requirements="CA")`:
/// C-contiguous, aligned, native byte order, dimensions kept (a 0-d array
/// stays 0-d). Copies only when `obj` is not already so. Aligned matters:
/// arrays that crossed a process boundary (pickle protocol 5's out-of-band
/// buffers, as dask.distributed hands them over) may start at any byte, and
/// `numpy.asarray` keeps such an array as it is.
fn as_c_array<'py>(obj: &Bound<'py, PyAny>, dtype: &str) -> PyResult<Bound<'py, PyAny>> {
    let numpy = obj.py().import("numpy")?;
    let kwargs = PyDict::new(obj.py());
    kwargs.set_item("dtype", numpy.getattr(dtype)?)?;
    kwargs.set_item("requirements", "CA")?;
    numpy.call_method("require", (obj,), Some(&kwargs))
}

/// `(3, 4)`, as numpy prints shapes.
pub fn shape_text(shape: &[usize]) -> String {
    match shape {
        [one] => format!("({one},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// Any array-like of numbers as float64 values (C order), for the
/// configuration loader; `what` names it in a `TypeError`.
pub fn float_values(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<ArrayValues> {
    let py = obj.py();
    if obj.is_instance_of::<PyString>() {
        return Err(PyTypeError::new_err(format!(
            "{what} must be a number or an array of numbers, not a string"
        )));
    }
    let (shape, values) = values::<f64>(obj, "float64").map_err(|e| {
        PyTypeError::new_err(format!(
            "{what} must be a number or an array of numbers ({})",
            e.value(py)
        ))
    })?;
    Ok(ArrayValues::new(shape, values))
}

/// Any array-like as `numpy.<dtype>` values (`T` its element), in C order,
/// with its shape; copied from whatever buffer holds them.
pub fn values<T: Element + Copy>(
    obj: &Bound<'_, PyAny>,
    dtype: &str,
) -> PyResult<(Vec<usize>, Vec<T>)> {
    let converted = as_c_array(obj, dtype)?;
    let array = converted
        .cast::<PyArrayDyn<T>>()
        .map_err(PyErr::from)?
        .readonly();
    Ok((array.shape().to_vec(), array.as_slice()?.to_vec()))
}

/// `data` as a numpy array of `shape`.
pub fn to_numpy<'py, T: Element>(
    py: Python<'py>,
    data: Vec<T>,
    shape: &[usize],
) -> PyResult<Bound<'py, PyAny>> {
    Ok(PyArray1::from_vec(py, data)
        .reshape(shape.to_vec())?
        .into_any())
}
