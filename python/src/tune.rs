//! `brightpix.tune`: the rule and N for the user's instrument, by the
//! library behind `brightpix tune` (`brightpix::evaluation::tune`: the
//! request, the simulation and scoring, and the files it writes); the
//! end-to-end criterion's result is in `tune_wfe.rs`.

use std::path::PathBuf;

use brightpix::config_file::ConfigFileError;
use brightpix::evaluation::tune::{
    output, parse_score, tune, Criterion, Lgs, Prepared, TuneRequest, TuneResult, WfeRequest,
};
use brightpix::evaluation::Axis;
use brightpix::io::{FrameCube, FrameShape};
use brightpix::simulator::SimulationParams;
use pyo3::exceptions::{PyTypeError, PyUserWarning, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::arrays::{frames, to_numpy};
use crate::config::PyConfig;
use crate::errors::config_error;
use crate::tune_wfe::{self, EndToEndKeywords};

pub(crate) fn value_error(e: anyhow::Error) -> PyErr {
    PyValueError::new_err(format!("{e:#}"))
}

/// A file that cannot be written is an `OSError` (as `Config.save`'s);
/// a bad name a `ValueError`.
pub(crate) fn save_error(e: anyhow::Error) -> PyErr {
    match e.downcast::<ConfigFileError>() {
        Ok(e) => config_error(e, false),
        Err(e) => match e.downcast::<std::io::Error>() {
            Ok(io) => PyErr::from(io),
            Err(e) => value_error(e),
        },
    }
}

/// What :func:`tune` found: the tuned :class:`Config`, the chosen rule,
/// each class of sub-apertures with its N and R, every candidate's score,
/// and what was assumed. :meth:`save` writes the files ``brightpix tune``
/// writes.
#[pyclass(name = "TuneResult", module = "brightpix", frozen)]
pub struct PyTuneResult {
    prepared: Prepared,
    result: TuneResult,
    assumptions: Vec<String>,
}

#[pymethods]
impl PyTuneResult {
    /// The input configuration with the chosen rule, level filter and N
    /// (per sub-aperture when the classes differ); dark sub-apertures left
    /// out unless ``keep_dark``.
    #[getter]
    fn config(&self) -> PyConfig {
        PyConfig {
            inner: self.result.config.clone(),
        }
    }

    /// The chosen rule, as ``brightpix tune`` prints it (e.g.
    /// ``"subtract-next"``, ``"subtract-mean(M=4)"``).
    #[getter]
    fn rule(&self) -> String {
        self.result.method.label()
    }

    /// What R is scored on: ``"x and y"`` or ``"along the elongation"``.
    #[getter]
    fn score(&self) -> &'static str {
        self.prepared.conditions.score_axis.name()
    }

    /// What was assumed, one sentence each.
    #[getter]
    fn assumptions(&self) -> Vec<String> {
        self.assumptions.clone()
    }

    /// Indices of the sub-apertures lit below the illumination threshold.
    #[getter]
    fn dark(&self) -> Vec<usize> {
        self.result.plan.dark.clone()
    }

    /// Indices of the classes whose spots lose more than ``max_truncation``
    /// of their light outside the window (their N is not reliable).
    #[getter]
    fn truncated(&self) -> Vec<usize> {
        self.result.truncated.clone()
    }

    /// One dict per class of sub-apertures: ``windows`` (indices in the
    /// input configuration), ``n`` (the chosen N), ``r``, ``r_se`` (R on
    /// :attr:`score` and its standard error, pixels), ``r_along``,
    /// ``r_across``, ``r_all_pixels`` (no selection), ``r_current`` (the
    /// input configuration's rule and N, or None), ``lit_fraction``,
    /// ``photons``, ``distance_m`` (to the launch position),
    /// ``elongation_angle_deg``, ``light_in_window``.
    #[getter]
    fn classes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let axis = self.prepared.conditions.score_axis;
        let list = PyList::empty(py);
        for c in &self.result.plan.classes {
            let chosen = c.chosen.as_ref().expect("tune chose every class");
            let d = PyDict::new(py);
            d.set_item("windows", c.members.clone())?;
            d.set_item("representative", c.representative)?;
            d.set_item("n", chosen.pixels)?;
            d.set_item("r", chosen.r(axis).value)?;
            d.set_item("r_se", chosen.r(axis).se)?;
            d.set_item("r_along", chosen.r(Axis::Along).value)?;
            d.set_item("r_across", chosen.r(Axis::Across).value)?;
            d.set_item("r_all_pixels", c.all_pixels().map(|s| s.r(axis).value))?;
            d.set_item("r_current", c.current.as_ref().map(|s| s.r(axis).value))?;
            d.set_item("lit_fraction", c.placement.lit_fraction)?;
            d.set_item("photons", c.photons)?;
            d.set_item("distance_m", c.placement.distance_m)?;
            d.set_item("elongation_angle_deg", c.placement.angle_deg)?;
            d.set_item("light_in_window", c.field_fraction)?;
            list.append(d)?;
        }
        Ok(list)
    }

    /// Every candidate in every class, as columns (``pandas.DataFrame``
    /// takes it as is): ``class``, ``rule`` (str), ``n``, ``all_pixels``
    /// (N is every pixel), ``r``, ``r_se`` (on :attr:`score`), ``r_along``,
    /// ``r_across``: numpy arrays but ``rule``, a list. The rows of
    /// ``NAME-tune.csv``.
    #[getter]
    fn scores<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let axis = self.prepared.conditions.score_axis;
        let rows: Vec<_> = self
            .result
            .plan
            .classes
            .iter()
            .enumerate()
            .flat_map(|(k, c)| c.scores.iter().map(move |s| (k, s)))
            .collect();
        let n = rows.len();
        let column =
            |f: &dyn Fn(&brightpix::evaluation::Score) -> f64| -> PyResult<Bound<'py, PyAny>> {
                to_numpy(
                    py,
                    rows.iter().map(|(_, s)| f(s)).collect::<Vec<f64>>(),
                    &[n],
                )
            };
        let d = PyDict::new(py);
        d.set_item(
            "class",
            to_numpy(
                py,
                rows.iter().map(|&(k, _)| k as u32).collect::<Vec<u32>>(),
                &[n],
            )?,
        )?;
        d.set_item(
            "rule",
            rows.iter()
                .map(|(_, s)| s.method.label())
                .collect::<Vec<_>>(),
        )?;
        d.set_item(
            "n",
            to_numpy(
                py,
                rows.iter()
                    .map(|(_, s)| s.pixels as u32)
                    .collect::<Vec<u32>>(),
                &[n],
            )?,
        )?;
        d.set_item(
            "all_pixels",
            to_numpy(
                py,
                rows.iter()
                    .map(|(_, s)| s.all_pixels)
                    .collect::<Vec<bool>>(),
                &[n],
            )?,
        )?;
        d.set_item("r", column(&|s| s.r(axis).value)?)?;
        d.set_item("r_se", column(&|s| s.r(axis).se)?)?;
        d.set_item("r_along", column(&|s| s.r(Axis::Along).value)?)?;
        d.set_item("r_across", column(&|s| s.r(Axis::Across).value)?)?;
        Ok(d)
    }

    /// Write what ``brightpix tune --out DIRECTORY --name NAME`` writes:
    /// ``NAME.toml`` (the tuned configuration, the assumptions as comments
    /// and a ``[tuned]`` table the loader ignores), ``NAME-tune.csv``
    /// (:attr:`scores`) and ``NAME-tune.svg``/``.png`` (R against N).
    /// Returns the paths written.
    #[pyo3(signature = (directory, name = "tuned"))]
    fn save(&self, py: Python<'_>, directory: PathBuf, name: &str) -> PyResult<Vec<PathBuf>> {
        let written = py
            .detach(|| {
                output::check_name(name)?;
                output::write(
                    &directory,
                    name,
                    &self.prepared,
                    &self.result,
                    &self.assumptions,
                )
            })
            .map_err(save_error)?;
        let mut paths = vec![written.config, written.scores];
        paths.extend(written.plots);
        Ok(paths)
    }

    fn __repr__(&self) -> String {
        let ns: Vec<usize> = self
            .result
            .plan
            .classes
            .iter()
            .filter_map(|c| c.chosen.as_ref().map(|s| s.pixels))
            .collect();
        format!(
            "<brightpix.TuneResult: {}, N {:?} over {} class(es)>",
            self.result.method.label(),
            ns,
            ns.len()
        )
    }
}

/// The simulator conditions of a dict, and the names it gave.
fn conditions(obj: Option<&Bound<'_, PyAny>>) -> PyResult<TuneRequest> {
    let Some(obj) = obj else {
        return Ok(TuneRequest::default());
    };
    let Ok(dict) = obj.cast::<PyDict>() else {
        return Err(PyTypeError::new_err(format!(
            "conditions must be a dict of simulator parameters (the keys of Simulation.conditions) or None, not {}; a laser guide star is lgs=\"rayleigh:DEPTH\" or \"sodium:SEPARATION\"",
            obj.get_type().name()?
        )));
    };
    let params: SimulationParams = pythonize::depythonize(dict.as_any())
        .map_err(|e| PyValueError::new_err(format!("conditions: {e}")))?;
    let names: Vec<String> = dict.keys().extract()?;
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    TuneRequest::with_conditions(params, &names).map_err(value_error)
}

/// Simulate the instrument of ``config`` and choose the rule and N that
/// minimise ``criterion``, as ``brightpix tune`` does: ``"r"`` (the
/// paper's slope error R, N per class of sub-apertures) or ``"wfe"`` (the
/// on-axis residual wavefront error of an end-to-end open-loop MOAO
/// simulation, one N for every sub-aperture; ``brightpix tune --criterion
/// wfe``).
///
/// ``conditions``: None (the paper's CANARY NGS: r0 = 12.5 cm, 200
/// photons, 2 e- read noise, 0.22"/pixel, a 4.2 m telescope) or a dict of
/// simulator parameters over those (the keys of
/// :attr:`Simulation.conditions`; ``source``, ``pixels_per_subaperture``,
/// ``bit_depth`` and ``background`` come from ``lgs`` and ``config``;
/// ``subapertures_across`` defaults to the configuration's grid).
/// ``recorded``: frames of the configured camera (``(F, H, W)`` uint8 or
/// uint16, e.g. from :func:`read_frames`): the read noise, background
/// error, photons and, for a NGS, r0 are measured in them instead.
/// ``obscuration``: central obscuration (m); sub-apertures lit below
/// ``illumination_threshold`` of their area are dark (left out).
/// ``level_filter``: also try each subtracting rule with this gain shift
/// (1..=16). ``seed`` of the random streams.
///
/// Criterion ``"r"`` only: ``lgs``: ``"rayleigh:DEPTH[:ALTITUDE]"`` or
/// ``"sodium:SEPARATION[:ALTITUDE]"`` (metres), launched from ``launch``
/// (``(x, y)`` m from the pupil centre, default ``(0, 0)``) with an
/// unelongated spot of ``lgs_spot`` arcsec (default 0.28); ``keep_dark`` (default False) keeps dark
/// sub-apertures with the median N; ``score``: ``"along"`` (the
/// elongation; the default for a LGS) or ``"pooled"`` (x and y; the
/// default for a NGS); ``frames`` simulated per class (default 4000, at
/// least 20; 4000 takes minutes), ``classes`` (default 4) and
/// ``angle_classes`` (default 2) for a LGS; ``max_truncation`` (default
/// 0.05).
///
/// Criterion ``"wfe"`` only (the command line's defaults): ``asterism``
/// ``[(radius_arcsec, angle_deg), ...]``, one wavefront sensor per guide
/// star (default: the paper's ``[(40.2, 26.6), (40.2, 153.4), (19.0,
/// 288.4)]``); ``science`` ``(radius_arcsec, angle_deg)`` (default on
/// axis); ``layers`` ``[(altitude_m, fraction, wind_m_s, direction_deg),
/// ...]``, fractions normalised (default ``[(0, 0.6, 7.5, 0), (500, 0.3,
/// 10, 90), (5000, 0.1, 15, 45)]``); ``wind_scale`` (1); ``frame_rate``
/// (250 Hz); ``delay`` (2 frames); ``science_wavelength`` (1.65e-6 m, of
/// the Strehl ratio); ``dm_actuators`` across (sub-apertures across + 1);
/// ``dm_coupling`` (0.2); ``fixed_noise`` (0.2 px, the fixed
/// reconstructor's); ``episodes`` (40, at least 2), ``episode_frames``
/// (100), ``calibration_episodes`` (1).
///
/// Returns a :class:`TuneResult` (``"r"``) or a :class:`WfeTuneResult`
/// (``"wfe"``). With ``"r"``, spots that lose more than ``max_truncation``
/// of their light outside the window give a ``UserWarning`` (the command
/// line exits non-zero) and are listed in :attr:`TuneResult.truncated`.
/// Bad values, and a keyword of the other criterion (which would be
/// ignored), raise ``ValueError`` (``TypeError`` for a wrong type) before
/// any simulation. GIL released.
#[pyfunction(name = "tune")]
#[pyo3(signature = (
    config, conditions = None, *, criterion = "r", frames = None, seed = 1, recorded = None,
    lgs = None, launch = None, lgs_spot = None, obscuration = 0.0,
    illumination_threshold = 0.5, keep_dark = None, score = None, level_filter = None,
    classes = None, angle_classes = None, max_truncation = None, asterism = None, science = None,
    layers = None, wind_scale = None, frame_rate = None, delay = None, science_wavelength = None,
    dm_actuators = None, dm_coupling = None, fixed_noise = None, episodes = None,
    episode_frames = None, calibration_episodes = None
))]
#[allow(clippy::too_many_arguments)]
pub fn tune_instrument(
    py: Python<'_>,
    config: Bound<'_, PyConfig>,
    conditions: Option<&Bound<'_, PyAny>>,
    criterion: &str,
    frames: Option<usize>,
    seed: u64,
    recorded: Option<&Bound<'_, PyAny>>,
    lgs: Option<&str>,
    launch: Option<(f64, f64)>,
    lgs_spot: Option<f64>,
    obscuration: f64,
    illumination_threshold: f64,
    keep_dark: Option<bool>,
    score: Option<&str>,
    level_filter: Option<u8>,
    classes: Option<usize>,
    angle_classes: Option<usize>,
    max_truncation: Option<f64>,
    asterism: Option<Vec<Vec<f64>>>,
    science: Option<Vec<f64>>,
    layers: Option<Vec<Vec<f64>>>,
    wind_scale: Option<f64>,
    frame_rate: Option<f64>,
    delay: Option<f64>,
    science_wavelength: Option<f64>,
    dm_actuators: Option<usize>,
    dm_coupling: Option<f64>,
    fixed_noise: Option<f64>,
    episodes: Option<usize>,
    episode_frames: Option<usize>,
    calibration_episodes: Option<usize>,
) -> PyResult<Py<PyAny>> {
    let criterion = Criterion::parse(criterion).map_err(value_error)?;
    let endtoend = EndToEndKeywords {
        asterism,
        science,
        layers,
        wind_scale,
        frame_rate,
        delay,
        science_wavelength,
        dm_actuators,
        dm_coupling,
        fixed_noise,
        episodes,
        episode_frames,
        calibration_episodes,
    };
    let mut given = endtoend.given();
    for (name, is_given) in [
        ("frames", frames.is_some()),
        ("launch", launch.is_some()),
        ("lgs_spot", lgs_spot.is_some()),
        ("score", score.is_some()),
        ("classes", classes.is_some()),
        ("angle_classes", angle_classes.is_some()),
        ("keep_dark", keep_dark.is_some()),
        ("max_truncation", max_truncation.is_some()),
    ] {
        if is_given {
            given.push(name);
        }
    }
    criterion.check_given(&given).map_err(value_error)?;
    let mut request = self::conditions(conditions)?;
    request.lgs = lgs.map(Lgs::parse).transpose().map_err(value_error)?;
    if let Some((x, y)) = launch {
        request.launch_m = [x, y];
    }
    request.lgs_spot_fwhm_arcsec = lgs_spot.unwrap_or(request.lgs_spot_fwhm_arcsec);
    request.pupil.obscuration_m = obscuration;
    request.pupil.illumination_threshold = illumination_threshold;
    request.score = score.map(parse_score).transpose().map_err(value_error)?;
    request.level_filter = level_filter;
    request.frames = frames.unwrap_or(request.frames);
    request.seed = seed;
    request.classes = classes.unwrap_or(request.classes);
    request.angle_classes = angle_classes.unwrap_or(request.angle_classes);
    request.max_truncation = max_truncation.unwrap_or(request.max_truncation);
    let config = &config.get().inner;
    if criterion == Criterion::Wfe {
        let request = WfeRequest {
            tune: request,
            endtoend: endtoend.conditions()?,
        };
        request.check().map_err(value_error)?;
        let recorded = recorded.map(|obj| frames_of(obj, config)).transpose()?;
        let result = tune_wfe::run(py, config, request, recorded)?;
        return Ok(Bound::new(py, result)?.into_any().unbind());
    }
    request.check().map_err(value_error)?;
    let recorded = recorded.map(|obj| frames_of(obj, config)).transpose()?;
    let keep_dark = keep_dark.unwrap_or(false);
    let (prepared, result) = py
        .detach(|| {
            let prepared = request.prepare(config, recorded.as_ref())?;
            let result = tune(
                config,
                &prepared.conditions,
                &prepared.options,
                keep_dark,
                &|_, _| {},
            )?;
            Ok((prepared, result))
        })
        .map_err(value_error)?;
    if let Some(message) = result.truncation(request.max_truncation) {
        PyErr::warn(
            py,
            &py.get_type::<PyUserWarning>(),
            &std::ffi::CString::new(message)?,
            1,
        )?;
    }
    let assumptions = prepared.assumptions("the recorded frames", Criterion::R);
    let result = PyTuneResult {
        prepared,
        result,
        assumptions,
    };
    Ok(Bound::new(py, result)?.into_any().unbind())
}

/// `obj` as a cube of the configured camera's frames.
fn frames_of(
    obj: &Bound<'_, PyAny>,
    config: &brightpix::config_file::ProcessingConfig,
) -> PyResult<FrameCube> {
    let block = frames(obj, &config.camera, "recorded")?;
    Ok(FrameCube {
        shape: FrameShape {
            frames: block.count,
            height: config.camera.height as usize,
            width: config.camera.width as usize,
        },
        pixels: block.pixels().to_vec(),
    })
}
