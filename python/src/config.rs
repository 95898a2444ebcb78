//! `brightpix.Config`: a processing configuration, loaded from TOML by the
//! host's loader or built from keywords by the same converter
//! ([`ProcessingConfig::from_values`]): one set of rules and messages.

use std::path::{Path, PathBuf};

use brightpix::config_file::{
    BackgroundValues, ConfigValues, GridValues, PixelCounts, PixelValues, ProcessingConfig,
    RuleName, SubapertureValues,
};
use brightpix_protocol::{Camera, LevelFilter};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt};

use crate::arrays::{float_values, to_numpy};
use crate::errors::config_error;

/// How a configuration built from keywords is named in errors.
const KEYWORDS: &str = "Config(...)";

/// A processing configuration: camera, sub-aperture windows, calibration,
/// selection rule and N, centroiding (docs/CONFIG.md).
///
/// From a TOML file with :meth:`load` (the same format, validation and
/// error messages as the ``brightpix`` command line), or from keywords,
/// converted and validated by the same code. Every conversion to the
/// engine's fixed point rounds half away from zero; a value that does not
/// fit is a ``ValueError`` naming the keyword (and, for maps, the pixel).
///
/// Keywords (all but ``width`` and ``height`` optional; give exactly one of
/// ``grid`` and ``windows``):
///
/// - ``width``, ``height``: the camera frame, pixels (1..=4096).
/// - ``bit_depth``: bits per raw pixel, 1..=16 (default 16); frames are
///   checked against it.
/// - ``grid``: a dict with the keys of ``[subapertures.grid]``: ``x``,
///   ``y`` (first window's top-left corner), ``columns``, ``rows``,
///   ``width``, ``height`` (window size), optional ``pitch_x``,
///   ``pitch_y`` (default: the window size) and ``skip`` (a list of
///   ``[column, row]`` positions without a window). Windows are numbered
///   row by row.
/// - ``windows``: an ``(S, 4)`` integer array of ``x, y, width, height``
///   per window, pixels, in output order. Windows are at most 64x64.
/// - ``rule``: ``"subtract-next"`` (default; the paper's N+1th
///   subtracted), ``"threshold"``, ``"subtract-next-distinct"`` or
///   ``"subtract-mean"`` (SPEC.md §3).
/// - ``n``: N, the brightest pixels kept: an int for every sub-aperture,
///   or an ``(S,)`` integer array (default 20).
/// - ``mean_count``: M for ``"subtract-mean"`` (1..=16).
/// - ``background``: counts, a number or an ``(H, W)`` map.
/// - ``flat``, ``pixel_weight``: ``(H, W)`` gain maps (dimensionless);
///   the engine applies flat x pixel_weight, within 0..=65535/4096.
/// - ``threshold``: counts; calibrated values below it become 0.
/// - ``min_flux``: counts; a sub-aperture is valid only if its flux
///   exceeds it (default 0).
/// - ``reference_slopes``: ``(S, 2)`` ``[x, y]`` pixels subtracted from
///   the slopes.
/// - ``level_filter``: gain shift G (1..=16) of the temporal filter of
///   the subtracted level (SPEC.md §4), or None (off).
#[pyclass(name = "Config", module = "brightpix", frozen, eq)]
#[derive(Clone, PartialEq)]
pub struct PyConfig {
    pub inner: ProcessingConfig,
}

fn small_int<T: TryFrom<i64>>(value: i64, keyword: &str, range: &str) -> PyResult<T> {
    T::try_from(value).map_err(|_| {
        PyValueError::new_err(format!(
            "{keyword}: {value} is out of range; expected {range}"
        ))
    })
}

fn optional_f64(value: Option<&Bound<'_, PyAny>>, keyword: &str) -> PyResult<Option<f64>> {
    match value {
        None => Ok(None),
        Some(v) if v.is_instance_of::<PyBool>() => Err(PyTypeError::new_err(format!(
            "{keyword} must be a number (counts), not a bool"
        ))),
        Some(v) => v
            .extract::<f64>()
            .map(Some)
            .map_err(|_| PyTypeError::new_err(format!("{keyword} must be a number (counts)"))),
    }
}

#[pymethods]
impl PyConfig {
    /// Builds a configuration from keywords (see the class documentation).
    #[new]
    #[pyo3(signature = (
        *, width, height, bit_depth = 16, grid = None, windows = None, rule = "subtract-next",
        n = None, mean_count = None, background = None, flat = None, pixel_weight = None,
        threshold = None, min_flux = None, reference_slopes = None, level_filter = None
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        width: i64,
        height: i64,
        bit_depth: i64,
        grid: Option<&Bound<'_, PyAny>>,
        windows: Option<&Bound<'_, PyAny>>,
        rule: &str,
        n: Option<&Bound<'_, PyAny>>,
        mean_count: Option<i64>,
        background: Option<&Bound<'_, PyAny>>,
        flat: Option<&Bound<'_, PyAny>>,
        pixel_weight: Option<&Bound<'_, PyAny>>,
        threshold: Option<&Bound<'_, PyAny>>,
        min_flux: Option<&Bound<'_, PyAny>>,
        reference_slopes: Option<&Bound<'_, PyAny>>,
        level_filter: Option<i64>,
    ) -> PyResult<Self> {
        let camera = Camera {
            width: small_int(width, "width", "1..=4096 pixels")?,
            height: small_int(height, "height", "1..=4096 pixels")?,
            bit_depth: small_int(bit_depth, "bit_depth", "1..=16 bits")?,
        };
        let subapertures = match (grid, windows) {
            (Some(grid), None) => {
                let grid: GridValues = pythonize::depythonize(grid).map_err(|e| {
                    PyValueError::new_err(format!(
                        "grid: {e} (keys as in [subapertures.grid]: x, y, columns, rows, width, height, pitch_x, pitch_y, skip)"
                    ))
                })?;
                SubapertureValues::Grid(grid)
            }
            (None, Some(windows)) => SubapertureValues::Table(float_values(windows, "windows")?),
            _ => {
                return Err(PyValueError::new_err(
                    "give exactly one of grid (a dict: x, y, columns, rows, width, height, ...) \
                     or windows (an (n, 4) array: x, y, width, height)",
                ))
            }
        };
        let mut values = ConfigValues::new(camera, subapertures);
        values.rule = RuleName::from_name(rule).ok_or_else(|| {
            let names: Vec<_> = RuleName::ALL
                .iter()
                .map(|(_, n)| format!("{n:?}"))
                .collect();
            PyValueError::new_err(format!(
                "rule: {rule:?} is not a rule; expected one of {}",
                names.join(", ")
            ))
        })?;
        values.mean_count = mean_count
            .map(|m| small_int(m, "mean_count", "1..=16"))
            .transpose()?;
        if let Some(n) = n {
            if n.is_instance_of::<PyBool>() {
                return Err(PyTypeError::new_err(
                    "n must be an integer or an array of integers",
                ));
            }
            values.pixels = PixelValues::Table(float_values(n, "n")?);
        }
        values.level_filter = level_filter
            .map(|g| small_int(g, "level_filter", "a gain shift of 1..=16"))
            .transpose()?
            .map(|gain_shift| LevelFilter { gain_shift });
        values.background = match background {
            None => None,
            Some(b) if b.is_instance_of::<PyFloat>() || b.is_instance_of::<PyInt>() => {
                Some(BackgroundValues::Constant(b.extract()?))
            }
            Some(b) => Some(BackgroundValues::Map(float_values(b, "background")?)),
        };
        values.flat = flat.map(|a| float_values(a, "flat")).transpose()?;
        values.pixel_weight = pixel_weight
            .map(|a| float_values(a, "pixel_weight"))
            .transpose()?;
        values.threshold_counts = optional_f64(threshold, "threshold")?;
        values.min_flux_counts = optional_f64(min_flux, "min_flux")?;
        values.reference_slopes = reference_slopes
            .map(|a| float_values(a, "reference_slopes"))
            .transpose()?;
        ProcessingConfig::from_values(values, Path::new(KEYWORDS))
            .map(|inner| PyConfig { inner })
            .map_err(|e| config_error(e, true))
    }

    /// Load a TOML configuration; relative data-file paths resolve
    /// against its directory. Errors: ``FileNotFoundError``/``OSError``
    /// (unreadable files), ``ValueError`` (everything else), with the
    /// command line's message (file, key, problem).
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        ProcessingConfig::load(&path)
            .map(|inner| PyConfig { inner })
            .map_err(|e| config_error(e, false))
    }

    /// Parse TOML text; relative data-file paths resolve against
    /// ``base_dir`` (default: the current directory).
    #[staticmethod]
    #[pyo3(signature = (text, base_dir = None))]
    fn from_toml(text: &str, base_dir: Option<PathBuf>) -> PyResult<Self> {
        let origin = base_dir.unwrap_or_default().join("<toml>");
        ProcessingConfig::from_toml_str(text, &origin)
            .map(|inner| PyConfig { inner })
            .map_err(|e| config_error(e, false))
    }

    /// The configuration as TOML. Maps, reference slopes and long lists
    /// are referenced as ``{name}-*.npy`` files, which :meth:`save` writes.
    #[pyo3(signature = (name = "config"))]
    fn to_toml(&self, name: &str) -> String {
        self.inner.to_toml_string(name)
    }

    /// Write ``directory/name.toml`` and its ``.npy`` data files (exact:
    /// loading them gives this configuration back); return the TOML path.
    #[pyo3(signature = (directory, name = "config"))]
    fn save(&self, directory: PathBuf, name: &str) -> PyResult<PathBuf> {
        self.inner
            .save(directory, name)
            .map_err(|e| config_error(e, false))
    }

    /// Camera width, pixels.
    #[getter]
    fn width(&self) -> u16 {
        self.inner.camera.width
    }

    /// Camera height, pixels.
    #[getter]
    fn height(&self) -> u16 {
        self.inner.camera.height
    }

    #[getter]
    fn bit_depth(&self) -> u8 {
        self.inner.camera.bit_depth
    }

    /// S, the number of windows.
    #[getter]
    fn n_subapertures(&self) -> usize {
        self.inner.windows.len()
    }

    /// ``(S, 4)``: x, y, width, height of each window, pixels.
    #[getter]
    fn windows<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let data = self
            .inner
            .windows
            .iter()
            .flat_map(|w| [w.x, w.y, w.width, w.height].map(i32::from))
            .collect();
        to_numpy(py, data, &[self.inner.windows.len(), 4])
    }

    #[getter]
    fn rule(&self) -> &'static str {
        RuleName::of(self.inner.rule).name()
    }

    #[getter]
    fn mean_count(&self) -> Option<u16> {
        match self.inner.rule {
            brightpix_protocol::SelectionRule::SubtractMean { count } => Some(count),
            _ => None,
        }
    }

    /// N: one int, or ``(S,)`` per sub-aperture.
    #[getter]
    fn n<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        match &self.inner.pixels {
            PixelCounts::All(n) => Ok(n.into_pyobject(py)?.into_any()),
            PixelCounts::PerSubaperture(list) => to_numpy(py, list.clone(), &[list.len()]),
        }
    }

    /// The level filter's gain shift, or None.
    #[getter]
    fn level_filter(&self) -> Option<u8> {
        self.inner.level_filter.map(|f| f.gain_shift)
    }

    /// ``(H, W)`` counts (multiples of 1/16), or None.
    #[getter]
    fn background<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        self.camera_map(py, self.inner.background.as_deref(), 16.0)
    }

    /// ``(H, W)`` flat x pixel weight (multiples of 1/4096), or None.
    #[getter]
    fn gain<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        self.camera_map(py, self.inner.gain.as_deref(), 4096.0)
    }

    /// Counts, or None.
    #[getter]
    fn threshold(&self) -> Option<f64> {
        self.inner.threshold.map(|t| t as f64 / 16.0)
    }

    /// Counts.
    #[getter]
    fn min_flux(&self) -> f64 {
        self.inner.min_flux as f64 / 16.0
    }

    /// ``(S, 2)`` pixels, or None.
    #[getter]
    fn reference_slopes<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        self.inner
            .reference_slopes
            .as_ref()
            .map(|r| {
                let data = r
                    .iter()
                    .flat_map(|p| p.map(|v| v as f64 / 65536.0))
                    .collect();
                to_numpy(py, data, &[r.len(), 2])
            })
            .transpose()
    }

    /// The keywords that rebuild this configuration: ``Config(**c.keywords()) == c``.
    fn keywords<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let c = &self.inner;
        let d = PyDict::new(py);
        d.set_item("width", c.camera.width)?;
        d.set_item("height", c.camera.height)?;
        d.set_item("bit_depth", c.camera.bit_depth)?;
        match c
            .grid
            .as_ref()
            .filter(|layout| layout.windows() == c.windows)
        {
            Some(layout) => {
                let g = layout.grid;
                let grid = PyDict::new(py);
                for (k, v) in [
                    ("x", g.x),
                    ("y", g.y),
                    ("columns", g.columns),
                    ("rows", g.rows),
                    ("width", g.width),
                    ("height", g.height),
                    ("pitch_x", g.pitch_x),
                    ("pitch_y", g.pitch_y),
                ] {
                    grid.set_item(k, v)?;
                }
                let skip: Vec<(u16, u16)> = layout.skip.iter().map(|&[c, r]| (c, r)).collect();
                grid.set_item("skip", skip)?;
                d.set_item("grid", grid)?;
            }
            None => d.set_item("windows", self.windows(py)?)?,
        }
        d.set_item("rule", self.rule())?;
        d.set_item("n", self.n(py)?)?;
        d.set_item("mean_count", self.mean_count())?;
        d.set_item("background", self.background(py)?)?;
        d.set_item("flat", self.gain(py)?)?;
        d.set_item("threshold", self.threshold())?;
        d.set_item("min_flux", self.min_flux())?;
        d.set_item("reference_slopes", self.reference_slopes(py)?)?;
        d.set_item("level_filter", self.level_filter())?;
        Ok(d)
    }

    /// Pickling (Dask ships configurations to its workers): by keywords.
    fn __reduce__<'py>(
        slf: &Bound<'py, Self>,
    ) -> PyResult<(Bound<'py, PyAny>, (Bound<'py, PyDict>,))> {
        let py = slf.py();
        let rebuild = py
            .import("brightpix._brightpix")?
            .getattr("_config_from_keywords")?;
        Ok((rebuild, (slf.get().keywords(py)?,)))
    }

    fn __repr__(&self) -> String {
        let n = match &self.inner.pixels {
            PixelCounts::All(n) => n.to_string(),
            PixelCounts::PerSubaperture(_) => "per sub-aperture".to_string(),
        };
        format!(
            "<brightpix.Config: {}x{} {}-bit camera, {} sub-apertures, {} N = {}{}>",
            self.inner.camera.width,
            self.inner.camera.height,
            self.inner.camera.bit_depth,
            self.inner.windows.len(),
            RuleName::of(self.inner.rule).name(),
            n,
            if self.inner.level_filter.is_some() {
                ", level filter"
            } else {
                ""
            }
        )
    }
}

impl PyConfig {
    fn camera_map<'py, T: Copy + Into<f64>>(
        &self,
        py: Python<'py>,
        map: Option<&[T]>,
        scale: f64,
    ) -> PyResult<Option<Bound<'py, PyAny>>> {
        let shape = [
            self.inner.camera.height as usize,
            self.inner.camera.width as usize,
        ];
        map.map(|m| to_numpy(py, m.iter().map(|&v| v.into() / scale).collect(), &shape))
            .transpose()
    }
}

/// `Config(**keywords)`, for unpickling.
#[pyfunction]
pub fn _config_from_keywords(
    py: Python<'_>,
    keywords: &Bound<'_, PyDict>,
) -> PyResult<Py<PyConfig>> {
    let config = py.get_type::<PyConfig>().call((), Some(keywords))?;
    Ok(config.cast_into::<PyConfig>()?.unbind())
}
