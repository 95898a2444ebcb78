//! `brightpix.simulate`: the project's Monte-Carlo Shack-Hartmann simulator
//! (`brightpix::simulator`), frames tiled as `brightpix demo` tiles them
//! (`brightpix::sil::simulate_tiled`).

use brightpix::sil::{named_conditions, simulate_tiled};
use brightpix::simulator::{SimulationParams, Simulator};
use brightpix_protocol::Camera;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};

use crate::arrays::to_numpy;
use crate::config::PyConfig;

/// Monte-Carlo Shack-Hartmann frames (the simulator of ``brightpix
/// paper``) and the slopes that made them.
#[pyclass(name = "Simulation", module = "brightpix", frozen)]
pub struct PySimulation {
    /// ``(F, rows * size, columns * size)`` camera counts; each frame holds
    /// ``columns x rows`` independent sub-aperture images, row by row.
    #[pyo3(get)]
    frames: Py<PyAny>,
    /// ``(F, S, 2)`` ``[x, y]`` pixels from each sub-aperture's centre: the
    /// centre of gravity of the noiseless image (the paper's true slope).
    #[pyo3(get)]
    true_slopes: Py<PyAny>,
    /// ``(F, S, 2)`` pixels: the wavefront's G-tilt as a spot shift.
    #[pyo3(get)]
    phase_slopes: Py<PyAny>,
    /// Every simulator parameter (the keys a conditions dict may give).
    #[pyo3(get)]
    conditions: Py<PyAny>,
    /// Side of a sub-aperture image, pixels.
    #[pyo3(get)]
    subaperture_size: usize,
    /// ``(columns, rows)``.
    #[pyo3(get)]
    grid: (usize, usize),
    /// Counts added to every pixel (what calibration should subtract).
    #[pyo3(get)]
    background: f64,
    /// Camera bit depth.
    #[pyo3(get)]
    bit_depth: u8,
}

#[pymethods]
impl PySimulation {
    /// A :class:`Config` for these frames (camera, grid, background);
    /// ``keywords`` as for ``Config`` (``rule``, ``n``, ...).
    #[pyo3(signature = (**kwargs))]
    fn config(&self, py: Python<'_>, kwargs: Option<&Bound<'_, PyDict>>) -> PyResult<Py<PyConfig>> {
        let (columns, rows) = self.grid;
        let size = self.subaperture_size;
        let grid = PyDict::new(py);
        for (k, v) in [
            ("x", 0),
            ("y", 0),
            ("columns", columns),
            ("rows", rows),
            ("width", size),
            ("height", size),
        ] {
            grid.set_item(k, v)?;
        }
        let all = PyDict::new(py);
        all.set_item("width", columns * size)?;
        all.set_item("height", rows * size)?;
        all.set_item("bit_depth", self.bit_depth)?;
        all.set_item("grid", grid)?;
        all.set_item("background", self.background)?;
        if let Some(kwargs) = kwargs {
            all.update(kwargs.as_mapping())?;
        }
        let config = py.get_type::<PyConfig>().call((), Some(&all))?;
        Ok(config.cast_into::<PyConfig>()?.unbind())
    }

    fn __repr__(&self) -> String {
        format!(
            "<brightpix.Simulation: {}x{} sub-apertures of {} pixels>",
            self.grid.0, self.grid.1, self.subaperture_size
        )
    }
}

fn conditions(obj: Option<&Bound<'_, PyAny>>) -> PyResult<SimulationParams> {
    match obj {
        None => Ok(SimulationParams::canary()),
        Some(o) if o.is_instance_of::<PyString>() => {
            named_conditions(&o.extract::<String>()?).map_err(PyValueError::new_err)
        }
        Some(o) if o.is_instance_of::<PyDict>() => {
            pythonize::depythonize(o).map_err(|e| PyValueError::new_err(format!("conditions: {e}")))
        }
        Some(o) => Err(PyTypeError::new_err(format!(
            "conditions must be a name (\"ngs\", \"rayleigh:DEPTH\", \"sodium:SEPARATION\"), \
             a dict of simulator parameters, or None; not {}",
            o.get_type().name()?
        ))),
    }
}

/// Simulate Shack-Hartmann frames with the paper's Monte-Carlo model.
///
/// ``conditions``: None or ``"ngs"`` (the paper's CANARY NGS: 16x16
/// pixels of 0.22", r0 = 12.5 cm, 200 photons, 2 e- read noise, 50-count
/// background), ``"rayleigh:DEPTH[:ALTITUDE]"`` or
/// ``"sodium:SEPARATION[:ALTITUDE]"`` (the paper's LGS cases, metres; the
/// elongation is along x), or a dict of simulator parameters (the keys of
/// :attr:`Simulation.conditions`, e.g. ``{"r0_m": 0.1, "photons": 150,
/// "source": {"kind": "rayleigh", ...}}``; unknown keys are errors).
/// ``grid``: ``(columns, rows)`` of sub-apertures per frame. Results
/// depend only on ``seed`` (not on threads). GIL released.
#[pyfunction]
#[pyo3(signature = (conditions = None, frames = 100, seed = 1, *, grid = (1, 1)))]
pub fn simulate(
    py: Python<'_>,
    conditions: Option<&Bound<'_, PyAny>>,
    frames: usize,
    seed: u64,
    grid: (usize, usize),
) -> PyResult<PySimulation> {
    let params = self::conditions(conditions)?;
    let (columns, rows) = grid;
    let sim = Simulator::new(params.clone()).map_err(|e| PyValueError::new_err(e.to_string()))?;
    let size = sim.size();
    let (width, height) = (columns * size, rows * size);
    if columns == 0 || rows == 0 || width > 4096 || height > 4096 {
        return Err(PyValueError::new_err(format!(
            "grid {grid:?} of {size}-pixel sub-apertures: the frame must be 1..=4096 pixels a side"
        )));
    }
    let camera = Camera {
        width: width as u16,
        height: height as u16,
        bit_depth: params.bit_depth,
    };
    let run = py.detach(|| simulate_tiled(&sim, camera, columns, rows, frames, seed));
    let spots = columns * rows;
    let flat = |slopes: Vec<Vec<[f64; 2]>>| -> Vec<f64> {
        slopes.into_iter().flatten().flatten().collect()
    };
    let pixels: Vec<u16> = run.frames.into_iter().flatten().collect();
    Ok(PySimulation {
        frames: to_numpy(py, pixels, &[frames, height, width])?.unbind(),
        true_slopes: to_numpy(py, flat(run.true_slopes), &[frames, spots, 2])?.unbind(),
        phase_slopes: to_numpy(py, flat(run.phase_slopes), &[frames, spots, 2])?.unbind(),
        conditions: pythonize::pythonize(py, &params)?.unbind(),
        subaperture_size: size,
        grid,
        background: sim.calibration_background(),
        bit_depth: params.bit_depth,
    })
}
