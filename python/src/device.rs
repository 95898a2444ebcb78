//! `brightpix.Device` (the host's serial client, `brightpix::link::Client`)
//! and the simulated devices behind `brightpix.simulated_device`
//! (`brightpix::sim_device`).

use std::path::PathBuf;
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

use brightpix::config_file::ProcessingConfig;
use brightpix::link::verify::Verifier;
use brightpix::link::{Client, ClientOptions, FrameOutcome, LinkError, PixelSink, StreamReport};
use brightpix::sil::verify_outcomes;
use brightpix::sim_device::{InProcessDevice, QemuDevice, QemuOptions};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::frames as camera_frames;
use crate::config::PyConfig;
use crate::errors::{link_error, other_error, MismatchError};
use crate::process::{Outputs, PyResultSet};

/// Mismatches kept per stream for the error message.
const KEEP_MISMATCHES: usize = 10;

struct Connection {
    client: Client,
    /// The configuration the device runs, as far as this client knows.
    config: Option<Py<PyConfig>>,
    /// The reference, fed every frame streamed since the configuration was
    /// applied (its level filters follow the device's).
    verifier: Option<Verifier>,
    next_frame: u32,
    report: Option<Py<PyDict>>,
}

/// A brightpix device on a serial port (a board on USB: ``/dev/ttyACM0``;
/// a simulated one: the port :func:`brightpix.simulated_device` yields).
///
/// Connecting checks the protocol version and schema. Every failure is an
/// exception carrying the client's message: ``FileNotFoundError`` /
/// ``PermissionError`` / ``OSError`` (the port cannot be opened),
/// ``TimeoutError`` (the device does not answer, or stops for ``timeout``
/// seconds), ``ConnectionError`` (the port disappears), ``DeviceError``
/// (the device refuses), ``ValueError`` (misuse). An exception raised
/// part-way through ``stream`` or ``capture`` carries what had arrived as
/// ``.result``. Usable as a context manager (closes the port).
#[pyclass(name = "Device", module = "brightpix", frozen)]
pub struct PyDevice {
    port: String,
    connection: Mutex<Option<Connection>>,
}

/// Frames of `outcomes` (numbered from `first`) as outputs; frames that did
/// not complete are missing.
fn outputs_of(
    outcomes: &[FrameOutcome],
    first: u32,
    frames: usize,
    subapertures: usize,
) -> Outputs {
    let mut by_frame: Vec<Option<&FrameOutcome>> = vec![None; frames];
    for o in outcomes {
        if let Some(slot) = by_frame.get_mut(o.frame().wrapping_sub(first) as usize) {
            *slot = Some(o);
        }
    }
    let mut out = Outputs::with_capacity(frames, subapertures);
    for o in by_frame {
        match o {
            Some(FrameOutcome::Done(s)) => {
                for e in s.by_index(subapertures) {
                    match e {
                        Some(e) => out.push([e.slope_x, e.slope_y], e.flux, e.valid),
                        None => out.push_missing(),
                    }
                }
            }
            _ => (0..subapertures).for_each(|_| out.push_missing()),
        }
    }
    out
}

/// `error` with `.result` set to what arrived before it.
fn with_result(py: Python<'_>, error: PyErr, result: PyResultSet) -> PyErr {
    if let Ok(result) = Bound::new(py, result) {
        let _ = error.value(py).setattr("result", result);
    }
    error
}

impl PyDevice {
    fn lock(&self) -> PyResult<MutexGuard<'_, Option<Connection>>> {
        self.connection
            .try_lock()
            .map_err(|_| PyRuntimeError::new_err("the device is in use by another thread"))
    }

    fn with_connection<T>(&self, f: impl FnOnce(&mut Connection) -> PyResult<T>) -> PyResult<T> {
        let mut guard = self.lock()?;
        match guard.as_mut() {
            Some(c) => f(c),
            None => Err(PyValueError::new_err(format!(
                "the connection to {} is closed",
                self.port
            ))),
        }
    }
}

fn report_dict<'py>(
    py: Python<'py>,
    report: &StreamReport,
    verifier: Option<&Verifier>,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("frames_sent", report.frames_sent)?;
    d.set_item("frames_done", report.frames_done)?;
    d.set_item("frames_dropped", report.frames_dropped)?;
    d.set_item("pixel_bytes", report.pixel_bytes)?;
    d.set_item("elapsed_s", report.elapsed.as_secs_f64())?;
    d.set_item(
        "frames_per_second",
        report.frames_done as f64 / report.elapsed.as_secs_f64().max(1e-9),
    )?;
    if let Some(v) = verifier {
        d.set_item("frames_verified", v.frames_verified)?;
        d.set_item("slopes_compared", v.slopes_compared)?;
        d.set_item("mismatches", v.mismatch_count)?;
    }
    Ok(d)
}

#[pymethods]
impl PyDevice {
    /// Opens `port` and checks the protocol version and schema.
    #[new]
    #[pyo3(signature = (port, *, timeout = 1.5, pixels_fifo = None))]
    fn new(
        py: Python<'_>,
        port: &Bound<'_, PyAny>,
        timeout: f64,
        pixels_fifo: Option<PathBuf>,
    ) -> PyResult<Self> {
        let name: String = port.extract()?;
        // A port yielded by simulated_device() knows its pixel FIFO.
        let fifo = match pixels_fifo {
            Some(f) => Some(f),
            None => port
                .getattr("pixels_fifo")
                .ok()
                .and_then(|f| f.extract::<Option<PathBuf>>().ok())
                .flatten(),
        };
        if !(timeout.is_finite() && timeout > 0.0) {
            return Err(PyValueError::new_err(format!(
                "timeout must be a positive number of seconds, got {timeout}"
            )));
        }
        let options = ClientOptions {
            timeout: Duration::from_secs_f64(timeout),
            ..ClientOptions::default()
        };
        let mut client = py
            .detach(|| Client::open_with(&name, options))
            .map_err(link_error)?;
        if let Some(fifo) = fifo {
            client.set_pixel_sink(PixelSink::Fifo(fifo));
        }
        Ok(PyDevice {
            port: name,
            connection: Mutex::new(Some(Connection {
                client,
                config: None,
                verifier: None,
                next_frame: 0,
                report: None,
            })),
        })
    }

    #[getter]
    fn port(&self) -> &str {
        &self.port
    }

    /// The device's identity and limits (board, protocol version, schema, sizes).
    #[getter]
    fn info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        self.with_connection(|c| {
            let i = c.client.info();
            let d = PyDict::new(py);
            d.set_item("board", &i.board)?;
            d.set_item("protocol_version", i.version)?;
            d.set_item("schema", i.schema)?;
            d.set_item("max_subapertures", i.max_subapertures)?;
            d.set_item("max_camera_pixels", i.max_camera_pixels)?;
            d.set_item("max_open_windows", i.max_open_windows)?;
            d.set_item("pool_entries", i.pool_entries)?;
            d.set_item("max_results_per_row", i.max_results_per_row)?;
            d.set_item("max_frame_bytes", i.max_frame_bytes)?;
            d.set_item("pixel_source", format!("{:?}", i.pixel_source))?;
            Ok(d)
        })
    }

    /// The configuration applied by :meth:`configure` (or given to :meth:`stream`).
    #[getter]
    fn config(&self, py: Python<'_>) -> PyResult<Option<Py<PyConfig>>> {
        self.with_connection(|c| Ok(c.config.as_ref().map(|p| p.clone_ref(py))))
    }

    /// Totals of the last :meth:`stream`: frames sent/done/dropped,
    /// elapsed seconds, frames per second, and with ``verify`` the frames
    /// verified, results compared and mismatches.
    #[getter]
    fn last_stream(&self, py: Python<'_>) -> PyResult<Option<Py<PyDict>>> {
        self.with_connection(|c| Ok(c.report.as_ref().map(|p| p.clone_ref(py))))
    }

    /// The device's ``Status`` as a dict (PROTOCOL.md §5): active
    /// configuration id and digest, frames processed and dropped, link
    /// errors, overruns, pixel errors, reset reason, health, and
    /// ``engine``: windows, candidates, compactions, rescans, attentions
    /// and ``kernel_frames`` (frames in which the engine's row kernel ran).
    fn status<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        self.with_connection(|c| {
            let client = &mut c.client;
            let status = py.detach(|| client.status()).map_err(link_error)?;
            Ok(pythonize::pythonize(py, &status)?)
        })
    }

    /// Upload ``config`` in chunks, committed atomically (on any error
    /// the device keeps its previous configuration); resets the device's
    /// level filters. Returns the configuration id, windows open at once,
    /// pool entries, messages and bytes sent, and the seconds it took.
    fn configure<'py>(
        &self,
        py: Python<'py>,
        config: Bound<'py, PyConfig>,
    ) -> PyResult<Bound<'py, PyDict>> {
        self.with_connection(|c| {
            let processing: &ProcessingConfig = &config.get().inner;
            let view = processing.view();
            let client = &mut c.client;
            let done = py.detach(|| client.configure(&view)).map_err(link_error)?;
            c.verifier = Some(
                Verifier::new(&view, KEEP_MISMATCHES)
                    .map_err(|e| PyValueError::new_err(e.to_string()))?,
            );
            c.config = Some(config.clone().unbind());
            c.next_frame = 0;
            let d = PyDict::new(py);
            d.set_item("config_id", done.config_id)?;
            d.set_item("open_windows", done.open_windows)?;
            d.set_item("pool_entries", done.pool_entries)?;
            d.set_item("messages", done.messages)?;
            d.set_item("table_bytes", done.table_bytes)?;
            d.set_item("elapsed_s", done.elapsed.as_secs_f64())?;
            Ok(d)
        })
    }

    /// Send frames (``uint8``/``uint16`` ``(H, W)`` or ``(F, H, W)``, as
    /// for :func:`process`) and return the device's results.
    ///
    /// ``verify=True`` checks every integer against the reference, which
    /// has seen every frame streamed since :meth:`configure` (so the level
    /// filter is followed across calls), and raises ``MismatchError`` on
    /// any difference. With the level filter on, a ``verify=False`` call
    /// leaves the reference behind the device: verifying again then needs
    /// :meth:`configure` (a ``ValueError`` says so). ``config`` tells the
    /// client the configuration of a device configured earlier (no upload;
    /// the reference starts from a reset level filter).
    #[pyo3(signature = (frames, verify = true, *, config = None))]
    fn stream(
        &self,
        py: Python<'_>,
        frames: &Bound<'_, PyAny>,
        verify: bool,
        config: Option<Bound<'_, PyConfig>>,
    ) -> PyResult<PyResultSet> {
        self.with_connection(|c| {
            if let Some(config) = config {
                let view = config.get().inner.view();
                c.client.assume_configured(&view);
                c.verifier = Some(
                    Verifier::new(&view, KEEP_MISMATCHES)
                        .map_err(|e| PyValueError::new_err(e.to_string()))?,
                );
                c.config = Some(config.unbind());
                c.next_frame = 0;
            }
            let Some(config) = c.config.as_ref().map(|p| p.clone_ref(py)) else {
                return Err(PyValueError::new_err(
                    "the device's configuration is unknown: call configure(config) first, \
                     or pass config= for a device configured earlier",
                ));
            };
            let processing = &config.get().inner;
            if verify && c.verifier.is_none() {
                return Err(PyValueError::new_err(
                    "cannot verify: with the level filter on, the reference must see every frame \
                     the device has seen since its configuration, and frames were streamed with \
                     verify=False; call configure(config) again to restart both",
                ));
            }
            let block = camera_frames(frames, &processing.camera, "frames")?;
            let pixels = block.pixels();
            let count = block.count;
            let frame_pixels = processing.camera.pixel_count();
            let subapertures = processing.windows.len();
            let first = c.next_frame;
            let Connection {
                client, verifier, ..
            } = c;
            let before = verifier.as_ref().map_or(0, |v| v.mismatch_count);
            let kept_before = verifier.as_ref().map_or(0, |v| v.mismatches.len());
            let (outcomes, result) = py.detach(|| {
                let batch: Vec<Vec<u16>> = pixels
                    .chunks_exact(frame_pixels)
                    .map(<[u16]>::to_vec)
                    .collect();
                let mut outcomes = Vec::with_capacity(batch.len());
                let result = client.stream_frames(first, &batch, |o| outcomes.push(o));
                if verify {
                    if let Some(v) = verifier.as_mut() {
                        verify_outcomes(v, &batch, first, &outcomes);
                    }
                }
                (outcomes, result)
            });
            c.next_frame = first.wrapping_add(count as u32);
            if !verify && processing.level_filter.is_some() {
                // The device's filters moved on without the reference.
                c.verifier = None;
            }
            let outputs = outputs_of(&outcomes, first, count, subapertures);
            let result_set = PyResultSet::new(py, outputs, config, "device", block.single)?;
            let report = result.as_ref().copied().unwrap_or_default();
            let checked = if verify { c.verifier.as_ref() } else { None };
            c.report = Some(report_dict(py, &report, checked)?.unbind());
            if let Err(e) = result {
                return Err(with_result(py, link_error(e), result_set));
            }
            if let Some(v) = checked {
                let new = v.mismatch_count - before;
                if new > 0 {
                    let shown: Vec<String> = v.mismatches[kept_before..]
                        .iter()
                        .map(|m| m.to_string())
                        .collect();
                    let error = MismatchError::new_err(format!(
                        "{new} of {} sub-aperture results differ from the reference; first: {}",
                        count * subapertures,
                        if shown.is_empty() {
                            "(not kept)".to_string()
                        } else {
                            shown.join("; ")
                        }
                    ));
                    let _ = error.value(py).setattr("mismatches", shown);
                    return Err(with_result(py, error, result_set));
                }
            }
            if report.frames_dropped > 0 && !verify {
                let error = crate::errors::DeviceError::new_err(format!(
                    "{} of {count} frames were dropped by the device",
                    report.frames_dropped
                ));
                return Err(with_result(py, error, result_set));
            }
            Ok(result_set)
        })
    }

    /// Record ``count`` frames from the device's own camera (needs
    /// :meth:`configure` first); a device without a camera raises
    /// ``DeviceError`` (``NoCamera``).
    fn capture(&self, py: Python<'_>, count: u32) -> PyResult<PyResultSet> {
        self.with_connection(|c| {
            let client = &mut c.client;
            let (outcomes, error) = match py.detach(|| client.capture(count)) {
                Ok(o) => (o, None),
                Err(i) => (i.received, Some(i.error)),
            };
            let subapertures = match &c.config {
                Some(config) => config.get().inner.windows.len(),
                None => outcomes
                    .iter()
                    .flat_map(|o| o.slopes().slopes.iter())
                    .map(|s| s.index as usize + 1)
                    .max()
                    .unwrap_or(0),
            };
            let config = match &c.config {
                Some(config) => config.clone_ref(py),
                None => {
                    return Err(error.map_or_else(
                        || {
                            PyValueError::new_err(
                                "capture needs the device's configuration: call configure(config) first",
                            )
                        },
                        link_error,
                    ))
                }
            };
            let first = outcomes.first().map_or(0, FrameOutcome::frame);
            let outputs = outputs_of(&outcomes, first, outcomes.len(), subapertures);
            let result_set = PyResultSet::new(py, outputs, config, "device", false)?;
            match error {
                Some(LinkError::Usage(message)) => Err(PyValueError::new_err(message)),
                Some(e) => Err(with_result(py, link_error(e), result_set)),
                None => Ok(result_set),
            }
        })
    }

    /// Closes the port.
    fn close(&self) -> PyResult<()> {
        self.lock()?.take();
        Ok(())
    }

    fn __enter__(slf: Py<Self>) -> Py<Self> {
        slf
    }

    #[pyo3(signature = (*_args))]
    fn __exit__(&self, _args: &Bound<'_, pyo3::types::PyTuple>) -> PyResult<bool> {
        self.close()?;
        Ok(false)
    }

    fn __repr__(&self) -> String {
        format!("<brightpix.Device on {}>", self.port)
    }
}

enum Simulated {
    InProcess(InProcessDevice),
    Qemu(QemuDevice),
}

/// A simulated device (prefer :func:`brightpix.simulated_device`):
/// ``qemu=False`` runs the firmware's device loop on a thread of this
/// process on a pseudo-terminal; ``qemu=True`` runs the firmware ELF in
/// ``qemu-system-arm``, pixels through a FIFO.
#[pyclass(name = "SimulatedDevice", module = "brightpix", frozen)]
pub struct PySimulatedDevice {
    port: String,
    pixels_fifo: Option<PathBuf>,
    device: Mutex<Option<Simulated>>,
}

#[pymethods]
impl PySimulatedDevice {
    #[new]
    #[pyo3(signature = (*, qemu = false, elf = None))]
    fn new(py: Python<'_>, qemu: bool, elf: Option<PathBuf>) -> PyResult<Self> {
        let device = py.detach(|| -> anyhow::Result<Simulated> {
            if qemu {
                let device = QemuDevice::launch(QemuOptions {
                    elf,
                    pixels_fifo: true,
                    ..QemuOptions::default()
                })?;
                device.release_fifo(Duration::from_secs(10))?;
                Ok(Simulated::Qemu(device))
            } else {
                Ok(Simulated::InProcess(InProcessDevice::start_pty()?))
            }
        });
        let device = device.map_err(other_error)?;
        let (port, pixels_fifo) = match &device {
            Simulated::InProcess(d) => (d.port().to_string(), d.pixels_fifo().map(PathBuf::from)),
            Simulated::Qemu(d) => (d.port().to_string(), d.pixels_fifo().map(PathBuf::from)),
        };
        Ok(PySimulatedDevice {
            port,
            pixels_fifo,
            device: Mutex::new(Some(device)),
        })
    }

    /// The serial port a client opens (`/dev/pts/N`).
    #[getter]
    fn port(&self) -> &str {
        &self.port
    }

    /// The FIFO the device reads pixels from (QEMU), or None (pixels go over the port).
    #[getter]
    fn pixels_fifo(&self) -> Option<PathBuf> {
        self.pixels_fifo.clone()
    }

    /// Stops the device (QEMU is killed); idempotent.
    fn stop(&self, py: Python<'_>) {
        let device = self.device.lock().ok().and_then(|mut d| d.take());
        py.detach(move || match device {
            Some(Simulated::InProcess(d)) => d.stop(),
            Some(Simulated::Qemu(d)) => d.stop(),
            None => {}
        });
    }

    fn __repr__(&self) -> String {
        format!("<brightpix.SimulatedDevice on {}>", self.port)
    }
}
