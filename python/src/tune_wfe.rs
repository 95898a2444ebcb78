//! `brightpix.tune(..., criterion="wfe")`: the rule and N of least
//! end-to-end residual wavefront error, by the library behind `brightpix
//! tune --criterion wfe` (`brightpix::evaluation::tune::wfe`: the request,
//! the run, and `output::write_wfe` for the files).

use std::path::PathBuf;

use brightpix::config_file::ProcessingConfig;
use brightpix::endtoend::{Conditions, GuideStar};
use brightpix::evaluation::tune::wfe::WfeScore;
use brightpix::evaluation::tune::{output, Criterion, WfeRequest, WfeTuneResult};
use brightpix::io::FrameCube;
use brightpix::simulator::atmosphere::Layer;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::to_numpy;
use crate::config::PyConfig;
use crate::tune::{save_error, value_error};

/// What :func:`tune` with ``criterion="wfe"`` found: the tuned
/// :class:`Config` (one rule and N for every lit sub-aperture), its
/// residual wavefront error and Strehl ratio, every rule and N's, and what
/// was assumed. :meth:`save` writes the files ``brightpix tune --criterion
/// wfe`` writes.
#[pyclass(name = "WfeTuneResult", module = "brightpix", frozen)]
pub struct PyWfeTuneResult {
    result: WfeTuneResult,
    /// The sensor's assumptions (the end-to-end run's are in the result).
    lines: Vec<String>,
}

#[pymethods]
impl PyWfeTuneResult {
    /// The input configuration without its dark sub-apertures, with the
    /// chosen rule, level filter and N.
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

    /// The chosen N (the window's pixel count: all pixels).
    #[getter]
    fn n(&self) -> usize {
        self.result.pixels
    }

    /// The chosen rule and N's on-axis residual wavefront error (nm rms,
    /// matched reconstructor).
    #[getter]
    fn wfe_nm(&self) -> f64 {
        self.result.wfe_nm.value
    }

    /// Its standard error (nm, over the episodes).
    #[getter]
    fn wfe_se_nm(&self) -> f64 {
        self.result.wfe_nm.se
    }

    /// Its Strehl ratio at :attr:`science_wavelength_m`.
    #[getter]
    fn strehl(&self) -> f64 {
        self.result.strehl.value
    }

    /// The wavelength of the Strehl ratio (m).
    #[getter]
    fn science_wavelength_m(&self) -> f64 {
        self.result.science_wavelength_m
    }

    /// The residual wavefront error with all pixels (nm rms, the first
    /// rule's), or None.
    #[getter]
    fn wfe_all_pixels_nm(&self) -> Option<f64> {
        self.result.wfe_all_pixels_nm
    }

    /// The chosen rule's N whose residual is within 2 paired standard
    /// errors of the best (the chosen N included).
    #[getter]
    fn not_resolved(&self) -> Vec<usize> {
        self.result.not_resolved.clone()
    }

    /// Indices of the sub-apertures lit below the illumination threshold,
    /// left out of the simulation and of :attr:`config`.
    #[getter]
    fn dark(&self) -> Vec<usize> {
        self.result.dark.clone()
    }

    /// What was assumed, one sentence each: the sensor, then the end-to-end
    /// run (the comment block of the saved TOML).
    #[getter]
    fn assumptions(&self) -> Vec<String> {
        self.lines
            .iter()
            .chain(&self.result.scenario)
            .cloned()
            .collect()
    }

    /// Every rule and N with the matched reconstructor, as columns
    /// (``pandas.DataFrame`` takes it as is): ``rule`` (a list of str),
    /// ``n``, ``all_pixels``, ``wfe_nm``, ``wfe_se_nm``, ``strehl``,
    /// ``strehl_se`` (numpy arrays). The ``matched`` rows of
    /// ``NAME-endtoend.csv``.
    #[getter]
    fn scores<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let rows = self.result.scores();
        let n = rows.len();
        let d = PyDict::new(py);
        d.set_item(
            "rule",
            rows.iter().map(|s| s.method.label()).collect::<Vec<_>>(),
        )?;
        let count = rows.iter().map(|s| s.pixels as u32).collect::<Vec<u32>>();
        d.set_item("n", to_numpy(py, count, &[n])?)?;
        let all = rows.iter().map(|s| s.all_pixels).collect::<Vec<bool>>();
        d.set_item("all_pixels", to_numpy(py, all, &[n])?)?;
        let column = |f: &dyn Fn(&WfeScore) -> f64| {
            to_numpy(py, rows.iter().map(f).collect::<Vec<f64>>(), &[n])
        };
        d.set_item("wfe_nm", column(&|s| s.wfe_nm.value)?)?;
        d.set_item("wfe_se_nm", column(&|s| s.wfe_nm.se)?)?;
        d.set_item("strehl", column(&|s| s.strehl.value)?)?;
        d.set_item("strehl_se", column(&|s| s.strehl.se)?)?;
        Ok(d)
    }

    /// Write what ``brightpix tune --criterion wfe --out DIRECTORY --name
    /// NAME`` writes: ``NAME.toml`` (the tuned configuration, the
    /// assumptions as comments and a ``[tuned]`` table the loader ignores)
    /// and the end-to-end run's ``NAME-endtoend.csv``, ``.md`` (summary;
    /// its run line gives this run's wall-clock times) and plots
    /// (``.svg``/``.png``, ``-strehl``, ``-budget``). Returns the paths
    /// written.
    #[pyo3(signature = (directory, name = "tuned"))]
    fn save(&self, py: Python<'_>, directory: PathBuf, name: &str) -> PyResult<Vec<PathBuf>> {
        let written = py
            .detach(|| output::write_wfe(&directory, name, &self.result, &self.lines))
            .map_err(save_error)?;
        Ok(written.paths())
    }

    fn __repr__(&self) -> String {
        format!(
            "<brightpix.WfeTuneResult: {} N {}: {:.1} ± {:.1} nm>",
            self.result.method.label(),
            self.result.pixels,
            self.result.wfe_nm.value,
            self.result.wfe_nm.se
        )
    }
}

/// The end-to-end keywords of :func:`tune` (None: not given).
pub struct EndToEndKeywords {
    pub asterism: Option<Vec<Vec<f64>>>,
    pub science: Option<Vec<f64>>,
    pub layers: Option<Vec<Vec<f64>>>,
    pub wind_scale: Option<f64>,
    pub frame_rate: Option<f64>,
    pub delay: Option<f64>,
    pub science_wavelength: Option<f64>,
    pub dm_actuators: Option<usize>,
    pub dm_coupling: Option<f64>,
    pub fixed_noise: Option<f64>,
    pub episodes: Option<usize>,
    pub episode_frames: Option<usize>,
    pub calibration_episodes: Option<usize>,
}

/// `values` as `N` numbers, or a `ValueError` naming `what` and `form`.
fn exactly<const N: usize>(values: &[f64], what: &str, form: &str) -> PyResult<[f64; N]> {
    values.try_into().map_err(|_| {
        PyValueError::new_err(format!(
            "{what}: expected {form}, got {} value(s)",
            values.len()
        ))
    })
}

fn star(values: &[f64], what: &str) -> PyResult<GuideStar> {
    let [radius_arcsec, angle_deg] = exactly(values, what, "(radius_arcsec, angle_deg)")?;
    Ok(GuideStar {
        radius_arcsec,
        angle_deg,
    })
}

impl EndToEndKeywords {
    /// The names of the keywords given.
    pub fn given(&self) -> Vec<&'static str> {
        [
            ("asterism", self.asterism.is_some()),
            ("science", self.science.is_some()),
            ("layers", self.layers.is_some()),
            ("wind_scale", self.wind_scale.is_some()),
            ("frame_rate", self.frame_rate.is_some()),
            ("delay", self.delay.is_some()),
            ("science_wavelength", self.science_wavelength.is_some()),
            ("dm_actuators", self.dm_actuators.is_some()),
            ("dm_coupling", self.dm_coupling.is_some()),
            ("fixed_noise", self.fixed_noise.is_some()),
            ("episodes", self.episodes.is_some()),
            ("episode_frames", self.episode_frames.is_some()),
            ("calibration_episodes", self.calibration_episodes.is_some()),
        ]
        .into_iter()
        .filter(|(_, given)| *given)
        .map(|(name, _)| name)
        .collect()
    }

    /// The library's conditions: the defaults, with what was given.
    pub fn conditions(&self) -> PyResult<Conditions> {
        let mut c = Conditions::default();
        if let Some(stars) = &self.asterism {
            c.guide_stars = Some(
                stars
                    .iter()
                    .enumerate()
                    .map(|(k, s)| star(s, &format!("asterism: star {k}")))
                    .collect::<PyResult<_>>()?,
            );
        }
        if let Some(s) = &self.science {
            c.science = star(s, "science")?;
        }
        if let Some(layers) = &self.layers {
            c.layers = Some(
                layers
                    .iter()
                    .enumerate()
                    .map(|(k, l)| {
                        let [altitude_m, fraction, wind_speed_m_s, wind_direction_deg] = exactly(
                            l,
                            &format!("layers: layer {k}"),
                            "(altitude_m, fraction, wind_m_s, direction_deg)",
                        )?;
                        Ok(Layer {
                            altitude_m,
                            fraction,
                            wind_speed_m_s,
                            wind_direction_deg,
                        })
                    })
                    .collect::<PyResult<_>>()?,
            );
        }
        let set = |slot: &mut f64, v: Option<f64>| {
            if let Some(v) = v {
                *slot = v;
            }
        };
        set(&mut c.wind_scale, self.wind_scale);
        set(&mut c.frame_rate_hz, self.frame_rate);
        set(&mut c.delay_frames, self.delay);
        set(&mut c.science_wavelength_m, self.science_wavelength);
        set(&mut c.dm_coupling, self.dm_coupling);
        set(&mut c.fixed_noise_px, self.fixed_noise);
        if let Some(n) = self.dm_actuators {
            c.dm_actuators_across = Some(n);
        }
        c.episodes = self.episodes.unwrap_or(c.episodes);
        c.episode_frames = self.episode_frames.unwrap_or(c.episode_frames);
        c.calibration_episodes = self.calibration_episodes.unwrap_or(c.calibration_episodes);
        Ok(c)
    }
}

/// Plans and runs `request` (checked) with the GIL released.
pub fn run(
    py: Python<'_>,
    config: &ProcessingConfig,
    request: WfeRequest,
    recorded: Option<FrameCube>,
) -> PyResult<PyWfeTuneResult> {
    let (prepared, result) = py
        .detach(|| {
            let (prepared, plan) = request.plan(config, recorded.as_ref())?;
            Ok((prepared, plan.run(&|_| {})?))
        })
        .map_err(value_error)?;
    Ok(PyWfeTuneResult {
        result,
        lines: prepared.assumptions("the recorded frames", Criterion::Wfe),
    })
}
