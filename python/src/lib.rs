//! `brightpix._brightpix`: the Python bindings of the brightpix host
//! library. Thin: each function converts its arguments (numpy arrays,
//! keywords), calls the library the command line uses, and converts the
//! result or the error. The Python documentation is the docstrings here
//! (Rust doc comments become `__doc__`); `brightpix/_brightpix.pyi` holds
//! the types; `README.md` beside this crate the overview.

mod arrays;
mod config;
mod device;
mod errors;
mod frames;
mod process;
mod rig;
mod simulate;
mod tune;
mod tune_wfe;

use pyo3::prelude::*;

#[pymodule]
fn _brightpix(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("DeviceError", py.get_type::<errors::DeviceError>())?;
    m.add("MismatchError", py.get_type::<errors::MismatchError>())?;
    m.add_class::<config::PyConfig>()?;
    m.add_function(wrap_pyfunction!(config::_config_from_keywords, m)?)?;
    m.add_class::<process::PyResultSet>()?;
    m.add_function(wrap_pyfunction!(process::_result_from_arrays, m)?)?;
    m.add_function(wrap_pyfunction!(process::process, m)?)?;
    m.add_function(wrap_pyfunction!(process::centroid, m)?)?;
    m.add_function(wrap_pyfunction!(frames::read_frames, m)?)?;
    m.add_class::<device::PyDevice>()?;
    m.add_class::<device::PySimulatedDevice>()?;
    m.add_class::<rig::PyRig>()?;
    m.add_class::<simulate::PySimulation>()?;
    m.add_function(wrap_pyfunction!(simulate::simulate, m)?)?;
    m.add_class::<tune::PyTuneResult>()?;
    m.add_class::<tune_wfe::PyWfeTuneResult>()?;
    m.add_function(wrap_pyfunction!(tune::tune_instrument, m)?)?;
    Ok(())
}
