//! `twinbots._native`: the Rust half of the Python package. The arenas of a robot's task are an
//! [`arenas::Arenas`] (a vectorised env stepped in Rust with the GIL released), a trained model
//! is a [`policy::Policy`]; the Gymnasium and Stable-Baselines3 faces are Python
//! (`python/twinbots/`), which also validates what users pass before it reaches Rust.

mod actions;
mod arenas;
mod bench;
mod convert;
mod frames;
mod handover;
mod infos;
mod policy;

use pyo3::prelude::*;

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    // The thread pools, sized for this machine before the arenas or candle start any (candle
    // would otherwise recount the cores on every matrix product).
    twinbots_learn::threads::configure();
    m.add_class::<arenas::Arenas>()?;
    m.add_class::<policy::Policy>()?;
    m.add_function(wrap_pyfunction!(robots, m)?)?;
    m.add_class::<bench::RustLoop>()?;
    m.add_function(wrap_pyfunction!(infos::vector_infos, m)?)?;
    m.add_function(wrap_pyfunction!(handover::training_defaults, m)?)?;
    m.add_function(wrap_pyfunction!(handover::create_run, m)?)?;
    m.add_function(wrap_pyfunction!(handover::append_progress, m)?)?;
    m.add_function(wrap_pyfunction!(handover::truncate_progress, m)?)?;
    m.add_function(wrap_pyfunction!(handover::draw_curve, m)?)?;
    m.add_function(wrap_pyfunction!(handover::save_model, m)?)?;
    m.add_function(wrap_pyfunction!(handover::finish_run, m)?)?;
    Ok(())
}

/// Every built-in robot: a list of dicts (name, description, tasks, patterns).
#[pyfunction]
fn robots(py: Python<'_>) -> PyResult<Vec<Bound<'_, pyo3::types::PyDict>>> {
    twinbots_run::registry::robots().iter().map(|r| convert::robot_dict(py, r)).collect()
}
