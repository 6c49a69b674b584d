//! pyo3 bindings of cmmpose-core: the `cmmpose._core` module. Only
//! conversion lives here, one module per concern: arrays and named inputs
//! in (float64, C-contiguous, read without copying), one output array
//! allocated, the kernel run with the GIL released, core errors converted
//! once (`errors::Failure`) onto the exception classes of `cmmpose.errors`.

mod arrays;
mod compensate;
mod errors;
mod fit;
mod maps;
mod model;
mod pose;
mod sim;
mod uncertainty;

use cmmpose_core::units;
use pyo3::prelude::*;

/// Number of threads the kernels use (rayon's global pool; set
/// RAYON_NUM_THREADS before the first call to change it).
#[pyfunction]
fn thread_count() -> usize {
    cmmpose_core::thread_count()
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    maps::register(m)?;
    pose::register(m)?;
    compensate::register(m)?;
    model::register(m)?;
    sim::register(m)?;
    fit::register(m)?;
    uncertainty::register(m)?;
    m.add_function(wrap_pyfunction!(thread_count, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    // The core's bounds of a machine's numbers, for the file schemas to state the same ones.
    m.add("MAX_LENGTH_MM", units::MAX_LENGTH_MM)?;
    m.add("MAX_TRANSLATION_UM", units::MAX_TRANSLATION_UM)?;
    m.add("MAX_ANGLE_ARCSEC", units::MAX_ANGLE_ARCSEC)?;
    m.add("TEMPERATURE_RANGE_C", units::TEMPERATURE_RANGE_C)?;
    Ok(())
}
