//! `brightpix.Rig`: several boards on one camera (`brightpix::rig`): a
//! plan or a rig file, each board's part, and a stream whose merged
//! results are one `Result` of the whole camera.

use std::path::PathBuf;

use brightpix::link::{Client, PixelSink};
use brightpix::rig::{self, BoardKind, Rig};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::frames as camera_frames;
use crate::config::PyConfig;
use crate::errors::{link_error, MismatchError};
use crate::process::{Outputs, PyResultSet};

/// One camera's sub-apertures split over several boards, each capturing a
/// rectangle of the sensor (``brightpix rig``; README, "Several boards on
/// one camera"). Build one with :meth:`plan` or :meth:`load`;
/// :meth:`stream` runs the boards together and returns one whole-camera
/// :class:`Result`, merged by frame number. Errors: ``ValueError`` (a plan
/// or rig file that cannot be, with the reason), the device errors of
/// :class:`Device`, ``MismatchError`` (``verify=True`` and a merged result
/// differs from the whole-camera reference).
#[pyclass(name = "Rig", module = "brightpix", frozen)]
pub struct PyRig {
    inner: Rig,
}

#[pymethods]
impl PyRig {
    /// Split ``config`` over ``boards`` boards of kind ``board``
    /// (``"stm32h743"``, ``"qemu-m4"``, ``"qemu-m7"``): row bands (column
    /// strips when rows cannot balance) balanced by the bench's cost model,
    /// or, with ``camera_rate``, runs of windows in raster order when only
    /// those keep up (rectangles then overlap by a row of windows);
    /// with ``camera_rate`` (Hz), a ``ValueError`` naming the boards needed
    /// when these cannot keep up, their cores or their links: each board's
    /// results on its own link (the STM32H743's USB full speed, about 1
    /// MB/s), or on one of ``link_rate`` MB/s as measured
    /// (``brightpix bench --port PORT --link``).
    #[staticmethod]
    #[pyo3(signature = (config, boards, *, board = "stm32h743", camera_rate = None, link_rate = None))]
    fn plan(
        config: &Bound<'_, PyConfig>,
        boards: usize,
        board: &str,
        camera_rate: Option<f64>,
        link_rate: Option<f64>,
    ) -> PyResult<Self> {
        let kind = BoardKind::parse(board).map_err(PyValueError::new_err)?;
        let model = match link_rate {
            None => kind.cost_model(),
            Some(r) => kind
                .cost_model()
                .with_link_rate(r)
                .map_err(|e| PyValueError::new_err(format!("link_rate {r}: {e}")))?,
        };
        let whole = config.get().inner.clone();
        let (plan, _) = rig::plan_keeping_up(&whole, boards, kind, &model, camera_rate)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        let mut inner =
            Rig::from_plan(whole, kind, camera_rate, &plan).map_err(PyValueError::new_err)?;
        inner.link_mb_per_s = link_rate;
        Ok(PyRig { inner })
    }

    /// Load and check a rig file (``brightpix rig plan --out``).
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        Rig::load(&path)
            .map(|inner| PyRig { inner })
            .map_err(|e| PyValueError::new_err(e.to_string()))
    }

    /// The whole camera's configuration.
    #[getter]
    fn config(&self) -> PyConfig {
        PyConfig {
            inner: self.inner.whole.clone(),
        }
    }

    /// Per board: ``name``, ``port`` (or None), ``rectangle``
    /// ``(x, y, width, height)``, ``subapertures`` (whole-camera indices),
    /// ``config`` (its own :class:`Config`, whose camera is the rectangle).
    #[getter]
    fn boards<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.inner
            .boards
            .iter()
            .map(|b| {
                let d = PyDict::new(py);
                d.set_item("name", &b.name)?;
                d.set_item("port", &b.port)?;
                let r = b.rectangle;
                d.set_item("rectangle", (r.x, r.y, r.width, r.height))?;
                d.set_item("subapertures", &b.windows)?;
                d.set_item(
                    "config",
                    PyConfig {
                        inner: b.config.clone(),
                    },
                )?;
                Ok(d)
            })
            .collect()
    }

    /// Stream ``frames`` (``(F, H, W)`` of the whole camera) to the boards
    /// on ``ports`` (in board order; default: the rig file's), each its
    /// rectangle, after uploading each board its part (or, with
    /// ``configure=False``, checking that it runs it). Returns the merged
    /// :class:`Result` (``received`` False where a board gave nothing for a
    /// frame). ``pixels_fifos``: per board, a FIFO the device reads pixels
    /// from (simulated devices), or None. GIL released while streaming.
    #[pyo3(signature = (frames, *, ports = None, verify = false, configure = true, pixels_fifos = None))]
    fn stream(
        &self,
        py: Python<'_>,
        frames: &Bound<'_, PyAny>,
        ports: Option<Vec<String>>,
        verify: bool,
        configure: bool,
        pixels_fifos: Option<Vec<Option<PathBuf>>>,
    ) -> PyResult<PyResultSet> {
        let rig = &self.inner;
        let block = camera_frames(frames, &rig.whole.camera, "frames")?;
        let count = rig.boards.len();
        let ports: Vec<String> = match ports {
            Some(p) if p.len() == count => p,
            Some(p) => {
                return Err(PyValueError::new_err(format!(
                    "ports: {} given for {count} boards",
                    p.len()
                )))
            }
            None => rig
                .boards
                .iter()
                .map(|b| {
                    b.port.clone().ok_or_else(|| {
                        PyValueError::new_err(format!(
                            "board {:?} has no port: give ports=[...]",
                            b.name
                        ))
                    })
                })
                .collect::<PyResult<_>>()?,
        };
        let fifos = pixels_fifos.unwrap_or_else(|| vec![None; count]);
        if fifos.len() != count {
            return Err(PyValueError::new_err(format!(
                "pixels_fifos: {} given for {count} boards",
                fifos.len()
            )));
        }
        let pixels: Vec<Vec<u16>> = block
            .pixels()
            .chunks_exact(rig.whole.camera.pixel_count().max(1))
            .map(<[u16]>::to_vec)
            .collect();
        let subapertures = rig.whole.windows.len();
        let (outputs, run) = py.detach(|| -> PyResult<_> {
            let mut clients = ports
                .iter()
                .zip(fifos)
                .map(|(port, fifo)| {
                    let mut client = Client::open(port)?;
                    if let Some(fifo) = fifo {
                        client.set_pixel_sink(PixelSink::Fifo(fifo));
                    }
                    Ok(client)
                })
                .collect::<Result<Vec<_>, _>>()
                .map_err(link_error)?;
            let started = if configure {
                rig::configure(rig, &mut clients)
            } else {
                rig::check_configurations(rig, &mut clients)
            };
            started.map_err(|e| PyValueError::new_err(e.to_string()))?;
            let mut outputs = Outputs::with_capacity(pixels.len(), subapertures);
            let run = rig::stream(rig, clients, &pixels, 0, verify, |m| {
                for r in &m.results {
                    match r {
                        Some(e) => outputs.push([e.slope_x, e.slope_y], e.flux, e.valid),
                        None => outputs.push_missing(),
                    }
                }
            });
            Ok((outputs, run))
        })?;
        if let Some(v) = run.verifier.as_ref().filter(|_| verify) {
            if !v.all_match() || v.frames_verified != pixels.len() as u64 {
                let first = v
                    .mismatches
                    .first()
                    .map_or(String::new(), |m| format!("; first: {m}"));
                return Err(MismatchError::new_err(format!(
                    "{} of {} merged frames verified, {} mismatches, {} incomplete{first}",
                    v.frames_verified,
                    pixels.len(),
                    v.mismatch_count,
                    v.frames_dropped
                )));
            }
        }
        let config = Py::new(
            py,
            PyConfig {
                inner: rig.whole.clone(),
            },
        )?;
        PyResultSet::new(py, outputs, config, "rig", block.single)
    }

    /// The rig as ``rig.toml`` text, naming the whole configuration as
    /// ``config_path``.
    fn to_toml(&self, config_path: PathBuf) -> String {
        self.inner.to_toml(&config_path, None)
    }

    fn __repr__(&self) -> String {
        format!(
            "<brightpix.Rig: {} {} boards, {} sub-apertures: {}>",
            self.inner.boards.len(),
            self.inner.kind.name(),
            self.inner.whole.windows.len(),
            self.inner.describe()
        )
    }
}
