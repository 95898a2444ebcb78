//! `brightpix.process`, `brightpix.centroid` and their `Result`: frames
//! through the host's engine runner (or the reference), the GIL released.

use std::path::{Path, PathBuf};

use brightpix::config_file::{
    ArrayValues, BackgroundValues, ConfigValues, PixelValues, ProcessingConfig, RuleName,
    SubapertureValues,
};
use brightpix::io::{
    check_result_outputs, write_results, FrameShape, Layout, Provenance, Raw, Results,
};
use brightpix::parallel::{BatchError, ParallelEngine};
use brightpix::reference::Reference;
use brightpix_protocol::{Camera, SubapertureWindow, MAX_WINDOW_SIDE};
use numpy::{PyUntypedArray, PyUntypedArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;

use crate::arrays::{frames, to_numpy};
use crate::config::PyConfig;
use crate::errors::{config_error, io_file_error};

/// Results of a run, one entry per frame and sub-aperture, frame-major.
#[derive(Default)]
pub struct Outputs {
    pub frames: usize,
    pub subapertures: usize,
    /// `[x, y]` in 2^-16 pixel.
    pub slopes: Vec<[i32; 2]>,
    /// 1/16 count.
    pub flux: Vec<i64>,
    pub valid: Vec<bool>,
    /// Whether a result arrived (always true but for a device's lost results).
    pub received: Vec<bool>,
}

impl Outputs {
    pub fn with_capacity(frames: usize, subapertures: usize) -> Self {
        let n = frames * subapertures;
        Outputs {
            frames,
            subapertures,
            slopes: Vec::with_capacity(n),
            flux: Vec::with_capacity(n),
            valid: Vec::with_capacity(n),
            received: Vec::with_capacity(n),
        }
    }

    pub fn push(&mut self, slope: [i32; 2], flux: i64, valid: bool) {
        self.slopes.push(slope);
        self.flux.push(flux);
        self.valid.push(valid);
        self.received.push(true);
    }

    pub fn push_missing(&mut self) {
        self.slopes.push([0, 0]);
        self.flux.push(0);
        self.valid.push(false);
        self.received.push(false);
    }
}

/// `pixels` (`frames` whole frames) through the streaming engine on
/// `threads` threads (None: all cores), or through the reference; the error
/// names the frame.
pub fn run(
    config: &ProcessingConfig,
    pixels: &[u16],
    frames: usize,
    reference: bool,
    threads: Option<usize>,
) -> Result<Outputs, String> {
    let view = config.view();
    let subapertures = config.windows.len();
    if reference {
        let mut out = Outputs::with_capacity(frames, subapertures);
        let mut reference = Reference::new(&view).map_err(|e| e.to_string())?;
        let frame_pixels = config.camera.pixel_count().max(1);
        for (k, frame) in pixels.chunks_exact(frame_pixels).take(frames).enumerate() {
            let results = reference
                .process_frame(frame)
                .map_err(|e| format!("frame {k}: {e}"))?;
            for r in results {
                out.push([r.slope_x, r.slope_y], r.flux, r.valid);
            }
        }
        return Ok(out);
    }
    let mut engine = ParallelEngine::new(&view, threads).map_err(|e| e.to_string())?;
    let shape = FrameShape {
        frames,
        height: config.camera.height as usize,
        width: config.camera.width as usize,
    };
    let results = engine.process(pixels, shape).map_err(|e| match e {
        BatchError::Pixel { frame, error } => format!("frame {frame}: {error}"),
        other => other.to_string(),
    })?;
    Ok(Outputs {
        frames,
        subapertures,
        received: vec![true; results.slopes.len()],
        slopes: results.slopes,
        flux: results.flux,
        valid: results.valid,
    })
}

/// Slopes, flux and validity of every frame and sub-aperture, with what
/// made them. For a single ``(H, W)`` frame the leading frame axis is
/// absent: ``slopes`` is ``(S, 2)``, ``flux`` ``(S,)``.
#[pyclass(name = "Result", module = "brightpix", frozen)]
pub struct PyResultSet {
    /// ``(F, S, 2)`` ``[x, y]`` pixels from the window centre, reference
    /// slopes subtracted: ``slopes_q16 / 65536``. 0.0 where not valid; NaN
    /// where a device sent nothing.
    #[pyo3(get)]
    slopes: Py<PyAny>,
    /// ``(F, S, 2)`` the engine's integers, 2^-16 pixel.
    #[pyo3(get)]
    slopes_q16: Py<PyAny>,
    /// ``(F, S)`` the sum of the selected weights, 1/16 count.
    #[pyo3(get)]
    flux: Py<PyAny>,
    /// ``(F, S)`` flux above ``min_flux``.
    #[pyo3(get)]
    valid: Py<PyAny>,
    /// ``(F, S)`` a result arrived (False only for a device's lost results).
    #[pyo3(get)]
    received: Py<PyAny>,
    /// What computed it: "engine", "reference", "device" or "rig" (merged
    /// from several boards).
    #[pyo3(get)]
    source: &'static str,
    /// The configuration that produced it.
    #[pyo3(get)]
    config: Py<PyConfig>,
    /// The brightpix version that produced it.
    #[pyo3(get)]
    version: &'static str,
    frames: usize,
    subapertures: usize,
    /// The results in the engine's integers, for [`PyResultSet::save`].
    outputs: Outputs,
}

impl PyResultSet {
    /// Wraps `outputs`; with `single`, the frame axis is dropped.
    pub fn new(
        py: Python<'_>,
        outputs: Outputs,
        config: Py<PyConfig>,
        source: &'static str,
        single: bool,
    ) -> PyResult<Self> {
        let (f, s) = (outputs.frames, outputs.subapertures);
        let lead: Vec<usize> = if single { vec![s] } else { vec![f, s] };
        let with = |last: usize| [lead.as_slice(), &[last]].concat();
        let slopes: Vec<f64> = outputs
            .slopes
            .iter()
            .zip(&outputs.received)
            .flat_map(|(xy, &got)| xy.map(|v| if got { v as f64 / 65536.0 } else { f64::NAN }))
            .collect();
        let q16: Vec<i32> = outputs.slopes.iter().flatten().copied().collect();
        Ok(PyResultSet {
            slopes: to_numpy(py, slopes, &with(2))?.unbind(),
            slopes_q16: to_numpy(py, q16, &with(2))?.unbind(),
            flux: to_numpy(py, outputs.flux.clone(), &lead)?.unbind(),
            valid: to_numpy(py, outputs.valid.clone(), &lead)?.unbind(),
            received: to_numpy(py, outputs.received.clone(), &lead)?.unbind(),
            source,
            config,
            version: env!("CARGO_PKG_VERSION"),
            frames: f,
            subapertures: s,
            outputs,
        })
    }

    /// The results as the command line's writers take them (a sub-aperture
    /// whose result never arrived is `None`: NaN, invalid).
    fn results(&self) -> Results {
        let o = &self.outputs;
        let mut results = Results::new(o.subapertures);
        for k in 0..o.slopes.len() {
            results.push(o.received[k].then(|| Raw {
                slope_x: o.slopes[k][0],
                slope_y: o.slopes[k][1],
                flux: o.flux[k],
                valid: o.valid[k],
            }));
        }
        results
    }
}

#[pymethods]
impl PyResultSet {
    /// Frames.
    #[getter]
    fn n_frames(&self) -> usize {
        self.frames
    }

    #[getter]
    fn n_subapertures(&self) -> usize {
        self.subapertures
    }

    fn __len__(&self) -> usize {
        self.frames
    }

    /// Pickling (a result returned from a Dask or multiprocessing worker):
    /// the engine's integers and the configuration; the float slopes are
    /// derived from them again.
    #[allow(clippy::type_complexity)]
    fn __reduce__<'py>(
        slf: &Bound<'py, Self>,
    ) -> PyResult<(
        Bound<'py, PyAny>,
        (
            Py<PyAny>,
            Py<PyAny>,
            Py<PyAny>,
            Py<PyAny>,
            &'static str,
            Py<PyConfig>,
        ),
    )> {
        let py = slf.py();
        let r = slf.get();
        let rebuild = py
            .import("brightpix._brightpix")?
            .getattr("_result_from_arrays")?;
        Ok((
            rebuild,
            (
                r.slopes_q16.clone_ref(py),
                r.flux.clone_ref(py),
                r.valid.clone_ref(py),
                r.received.clone_ref(py),
                r.source,
                r.config.clone_ref(py),
            ),
        ))
    }

    /// Write slopes, flux, validity and provenance as ``brightpix process
    /// --out`` does, with the same writers, in the format of ``path``'s
    /// extension (docs/OUTPUTS.md):
    ///
    /// - ``x.npy``: ``x.npy`` (slopes, float64 pixels), ``x.flux.npy``
    ///   (float64 counts), ``x.valid.npy`` (uint8 0/1), ``x.json``
    ///   (provenance);
    /// - ``x.fits`` (``.fit``, ``.fts``): ``SLOPES``, ``FLUX`` and ``VALID``
    ///   image extensions, provenance keywords in the primary header;
    /// - ``x.csv``: one row per frame and sub-aperture;
    /// - ``x.aot.fits``: Adaptive Optics Telemetry (AOT), one Shack-Hartmann
    ///   sensor with the configuration's geometry (``aotpy`` reads it).
    ///
    /// ``layout``: ``"pairs"`` (slopes ``(F, S, 2)``) or ``"vector"``
    /// (``(F, 2S)``, ``[x_0..x_S-1, y_0..y_S-1]`` per frame, as AO codes take
    /// them). A single-frame result is written as one frame. Every file is
    /// written whole or not at all. Returns the paths written.
    ///
    /// Raises ``ValueError`` (unknown extension or layout),
    /// ``FileNotFoundError`` (no such directory), ``OSError`` (the files
    /// cannot be written).
    #[pyo3(signature = (path, *, layout = "pairs"))]
    fn save(&self, py: Python<'_>, path: PathBuf, layout: &str) -> PyResult<Vec<PathBuf>> {
        let layout = match layout {
            "pairs" => Layout::Pairs,
            "vector" => Layout::Vector,
            other => {
                return Err(PyValueError::new_err(format!(
                    "layout: {other:?}; expected \"pairs\" or \"vector\""
                )))
            }
        };
        let config = self.config.get().inner.view();
        let producer = format!("brightpix Python package ({})", self.source);
        let provenance = Provenance::of(producer, &config, None);
        // Checked before any work, as the command line checks `--out`.
        check_result_outputs(&[], &[&path]).map_err(io_file_error)?;
        let results = self.results();
        py.detach(|| write_results(&path, &results, &provenance, layout))
            .map_err(io_file_error)
    }

    fn __repr__(&self) -> String {
        format!(
            "<brightpix.Result: {} frames x {} sub-apertures, by the {}>",
            self.frames, self.subapertures, self.source
        )
    }
}

/// Compute the slopes of camera frames, as ``brightpix process`` does.
///
/// ``frames``: a numpy ``uint8`` or ``uint16`` array of counts, ``(H, W)``
/// or ``(F, H, W)``, in any memory order and byte order (FITS data from
/// astropy, big-endian, is fine; so is a read-only or misaligned buffer, as
/// arrays arrive from another process: it is copied only when not
/// C-contiguous, aligned, native uint16). Raw values must be below
/// ``2**config.bit_depth``.
///
/// ``reference=True`` uses the independent reference implementation (a
/// full sort per sub-aperture) instead of the streaming engine; the
/// results are identical, bit for bit.
///
/// The GIL is released while processing, and the engine runs on ``threads``
/// threads (default: all cores), as ``brightpix process`` does
/// (``brightpix::parallel::ParallelEngine``: frames split across threads,
/// or, with the level filter, bands of sub-apertures, each with its own
/// filter state); results do not depend on the thread count. With the
/// level filter on, frames are processed in order and the filter starts
/// from its reset state: one call on a cube is one pass over it.
///
/// Raises ``TypeError`` (not uint8/uint16, not an array), ``ValueError``
/// (shape, a pixel above the bit depth: the message names frame, row,
/// column and value; nothing is processed then, ``threads=0``).
#[pyfunction]
#[pyo3(signature = (frames, config, *, reference = false, threads = None))]
pub fn process(
    py: Python<'_>,
    frames: &Bound<'_, PyAny>,
    config: Bound<'_, PyConfig>,
    reference: bool,
    threads: Option<usize>,
) -> PyResult<PyResultSet> {
    let processing = &config.get().inner;
    let block = crate::arrays::frames(frames, &processing.camera, "frames")?;
    let pixels = block.pixels();
    let count = block.count;
    let outputs = py
        .detach(|| run(processing, pixels, count, reference, threads))
        .map_err(PyValueError::new_err)?;
    let source = if reference { "reference" } else { "engine" };
    PyResultSet::new(py, outputs, config.unbind(), source, block.single)
}

/// Brightest-pixel centre of gravity of sub-aperture images, the
/// engine's arithmetic, for people used to aotools.
///
/// ``image``: ``uint8``/``uint16`` counts, ``(h, w)`` or a stack
/// ``(k, h, w)``, at most 64x64. Returns ``[x, y]`` pixels from the
/// image's centre, ``(2,)`` or ``(k, 2)`` (note: aotools returns ``(2, k)``);
/// NaN where no pixel has weight. Rounded to 2^-16 pixel.
///
/// aotools: ``aotools.brightest_pixel(img, t)`` subtracts the
/// ``round(t * h * w)``-th brightest value, clips at 0 and takes the centre
/// of gravity with the origin at pixel ``[0, 0]``. That is
/// ``centroid(img, n=round(t * h * w) - 1, rule="subtract-next")`` plus
/// ``[(w - 1) / 2, (h - 1) / 2]``, to within 2^-16 pixel.
#[pyfunction]
#[pyo3(signature = (image, n, rule = "subtract-next", *, mean_count = None, background = 0.0, threshold = None))]
pub fn centroid<'py>(
    py: Python<'py>,
    image: &Bound<'py, PyAny>,
    n: i64,
    rule: &str,
    mean_count: Option<u16>,
    background: f64,
    threshold: Option<f64>,
) -> PyResult<Bound<'py, PyAny>> {
    let Ok(array) = image.cast::<PyUntypedArray>() else {
        return Err(PyTypeError::new_err(
            "image must be a numpy array of uint8 or uint16 counts, (h, w) or (k, h, w)",
        ));
    };
    let shape = array.shape().to_vec();
    let (h, w) = match shape[..] {
        [h, w] | [_, h, w] => (h, w),
        _ => {
            return Err(PyValueError::new_err(format!(
                "image must have shape (h, w) or (k, h, w); got {}",
                crate::arrays::shape_text(&shape)
            )))
        }
    };
    let side = MAX_WINDOW_SIDE as usize;
    if !(1..=side).contains(&h) || !(1..=side).contains(&w) {
        return Err(PyValueError::new_err(format!(
            "a sub-aperture image is at most {side}x{side} pixels; got {h}x{w}"
        )));
    }
    let camera = Camera {
        width: w as u16,
        height: h as u16,
        bit_depth: 16,
    };
    let window = SubapertureWindow {
        x: 0,
        y: 0,
        width: w as u16,
        height: h as u16,
    };
    let mut values = ConfigValues::new(camera, SubapertureValues::Windows(vec![window]));
    values.rule = RuleName::from_name(rule).ok_or_else(|| {
        PyValueError::new_err(format!(
            "rule: {rule:?} is not a rule; expected one of {}",
            RuleName::ALL.map(|(_, n)| n).join(", ")
        ))
    })?;
    values.mean_count = mean_count;
    values.pixels = PixelValues::Table(ArrayValues::new(vec![], vec![n as f64]));
    values.background = (background != 0.0).then_some(BackgroundValues::Constant(background));
    values.threshold_counts = threshold;
    let config = ProcessingConfig::from_values(values, Path::new("centroid(...)"))
        .map_err(|e| config_error(e, true))?;
    let block = frames(image, &camera, "image")?;
    let pixels = block.pixels();
    let count = block.count;
    let outputs = py
        .detach(|| run(&config, pixels, count, false, None))
        .map_err(PyValueError::new_err)?;
    let slopes: Vec<f64> = outputs
        .slopes
        .iter()
        .zip(&outputs.valid)
        .flat_map(|(xy, &valid)| xy.map(|v| if valid { v as f64 / 65536.0 } else { f64::NAN }))
        .collect();
    let out_shape: &[usize] = if block.single { &[2] } else { &[count, 2] };
    to_numpy(py, slopes, out_shape)
}

/// `Result` from its pickled arrays (`Result.__reduce__`), from any buffer
/// (misaligned, read-only: copied).
#[pyfunction]
pub fn _result_from_arrays(
    py: Python<'_>,
    slopes_q16: &Bound<'_, PyAny>,
    flux: &Bound<'_, PyAny>,
    valid: &Bound<'_, PyAny>,
    received: &Bound<'_, PyAny>,
    source: &str,
    config: Py<PyConfig>,
) -> PyResult<PyResultSet> {
    let source = ["engine", "reference", "device", "rig"]
        .into_iter()
        .find(|&s| s == source)
        .ok_or_else(|| PyValueError::new_err(format!("result source {source:?}")))?;
    let (shape, q16) = crate::arrays::values::<i32>(slopes_q16, "int32")?;
    let (lead, flux) = crate::arrays::values::<i64>(flux, "int64")?;
    let (valid_shape, valid) = crate::arrays::values::<bool>(valid, "bool")?;
    let (received_shape, received) = crate::arrays::values::<bool>(received, "bool")?;
    let single = lead.len() == 1;
    let (frames, subapertures) = match lead[..] {
        [s] => (1, s),
        [f, s] => (f, s),
        _ => return Err(PyValueError::new_err("result arrays of an unknown shape")),
    };
    if shape != [lead.as_slice(), &[2]].concat() || valid_shape != lead || received_shape != lead {
        return Err(PyValueError::new_err(
            "result arrays of inconsistent shapes",
        ));
    }
    let outputs = Outputs {
        frames,
        subapertures,
        slopes: q16.chunks_exact(2).map(|xy| [xy[0], xy[1]]).collect(),
        flux,
        valid,
        received,
    };
    PyResultSet::new(py, outputs, config, source, single)
}
