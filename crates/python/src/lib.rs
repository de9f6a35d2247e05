//! `dwslam._dwslam`: the native half of dwslam's Python package (PyO3, abi3).
//!
//! It holds no algorithm and no loop of its own: [`run::run`] is `runner::execute` (the loop
//! of `dwslam run`), [`live::System`] makes its system with `runner::new_system` and drives it
//! frame by frame, [`sequence::Sequence`] reads frames with `runner::open_sequence`,
//! [`eval::eval_arrays`] calls `data::eval`. What it adds is the crossing: numpy arrays in and out, Python exceptions with
//! the Rust message, and the interpreter released while frames are processed. The Python
//! half (`python/dwslam`) wraps the dicts returned here into typed results.

mod args;
mod arrays;
mod camera;
mod errors;
mod eval;
mod live;
mod run;
mod sequence;

use pyo3::prelude::*;

/// The native module.
#[pymodule]
fn _dwslam(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("DwslamError", m.py().get_type::<errors::DwslamError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(run::run, m)?)?;
    m.add_function(wrap_pyfunction!(eval::read_trajectory, m)?)?;
    m.add_function(wrap_pyfunction!(eval::eval_arrays, m)?)?;
    m.add_class::<live::System>()?;
    m.add_class::<sequence::Sequence>()?;
    Ok(())
}
