//! The thesis compensation across the boundary: one digitizer, an ErrorMap
//! or an ErrorMapSet at one temperature or one per point; and what the
//! digitizer software reports without compensation.

use cmmpose_core::kernel;
use numpy::{PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::{options, rows, run_kernel_into, vector, MapPolicy};
use crate::errors::{input, Res};
use crate::maps::{PyErrorMap, PyErrorMapSet};
use crate::pose::PyDigitizer;

type Output<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>);

/// Compensated machine coordinates (mm). `error_map` is an ErrorMap or an
/// ErrorMapSet; with a set, `temperature` is a float or an (N,) array (C).
/// `policy` is a `cmmpose.TemperaturePolicy` (its map side: `out_of_range`,
/// `temperature_tolerance` K).
#[pyfunction]
#[pyo3(signature = (uv, scales, error_map, digitizer, policy, temperature=None, nan_policy="raise", out=None))]
#[allow(clippy::too_many_arguments)]
fn compensate<'py>(
    py: Python<'py>,
    uv: PyReadonlyArray2<'py, f64>,
    scales: PyReadonlyArray2<'py, f64>,
    error_map: &Bound<'py, PyAny>,
    digitizer: PyRef<'py, PyDigitizer>,
    policy: MapPolicy,
    temperature: Option<&Bound<'py, PyAny>>,
    nan_policy: &str,
    out: Option<&Bound<'py, PyAny>>,
) -> Res<Output<'py>> {
    let opts = policy.options(nan_policy)?;
    let uv_s = rows("uv", &uv, 2)?;
    let s = rows("scales", &scales, 3)?;
    let d = digitizer.inner;
    let n = s.len() / 3;
    if let Ok(map) = error_map.cast::<PyErrorMap>() {
        if temperature.is_some() {
            return Err(input(
                "temperature: only meaningful with an ErrorMapSet; an ErrorMap has one temperature",
            ));
        }
        let map = &map.get().inner;
        return run_kernel_into(py, n, 3, out, |out| {
            kernel::compensate(uv_s, s, map, &d, opts, out)
        });
    }
    let set = error_map
        .cast::<PyErrorMapSet>()
        .map_err(|_| input("error_map: expected an ErrorMap or an ErrorMapSet"))?;
    let set = &set.get().inner;
    let temperature = temperature.ok_or_else(|| {
        input("temperature: required with an ErrorMapSet (a float or an (N,) array, C)")
    })?;
    if let Ok(t) = temperature.extract::<f64>() {
        return run_kernel_into(py, n, 3, out, |out| {
            kernel::compensate_at_temperature(uv_s, s, t, set, &d, opts, out)
        });
    }
    let t: PyReadonlyArray1<'py, f64> = temperature
        .extract()
        .map_err(|_| input("temperature: expected a float or a float64 (N,) array"))?;
    let t = vector("temperature", &t)?;
    run_kernel_into(py, n, 3, out, |out| {
        kernel::compensate_at_temperatures(uv_s, s, t, set, &d, opts, out)
    })
}

/// What the digitizer software reports, without compensation (mm).
#[pyfunction]
#[pyo3(signature = (uv, scales, digitizer, nan_policy="raise", out=None))]
fn uncompensated<'py>(
    py: Python<'py>,
    uv: PyReadonlyArray2<'py, f64>,
    scales: PyReadonlyArray2<'py, f64>,
    digitizer: PyRef<'py, PyDigitizer>,
    nan_policy: &str,
    out: Option<&Bound<'py, PyAny>>,
) -> Res<Output<'py>> {
    let opts = options("raise", nan_policy)?;
    let uv_s = rows("uv", &uv, 2)?;
    let s = rows("scales", &scales, 3)?;
    let d = digitizer.inner;
    run_kernel_into(py, s.len() / 3, 3, out, |out| {
        kernel::uncompensated(uv_s, s, &d, opts, out)
    })
}

/// The compensation's memory traffic without its arithmetic (benches: the
/// machine's streaming limit for the same arrays).
#[pyfunction]
#[pyo3(signature = (uv, scales, temperature=None, out=None))]
fn streaming_reference<'py>(
    py: Python<'py>,
    uv: PyReadonlyArray2<'py, f64>,
    scales: PyReadonlyArray2<'py, f64>,
    temperature: Option<PyReadonlyArray1<'py, f64>>,
    out: Option<&Bound<'py, PyAny>>,
) -> Res<Bound<'py, PyArray2<f64>>> {
    let uv_s = rows("uv", &uv, 2)?;
    let s = rows("scales", &scales, 3)?;
    let t = match &temperature {
        Some(t) => Some(vector("temperature", t)?),
        None => None,
    };
    let (out, _) = run_kernel_into(py, s.len() / 3, 3, out, |out| {
        cmmpose_core::stream::streaming_reference(uv_s, s, t, out)?;
        Ok(kernel::Report::default())
    })?;
    Ok(out)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(streaming_reference, m)?)?;
    m.add_function(wrap_pyfunction!(compensate, m)?)?;
    m.add_function(wrap_pyfunction!(uncompensated, m)?)?;
    Ok(())
}
