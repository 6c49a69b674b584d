//! The compensation model across the boundary: the one kernel with effects
//! switched on, several digitizers (one per pose) and named per-point
//! inputs; and the registry of effect terms, for the Python effects to
//! check themselves against.

use cmmpose_core::effects::TERMS;
use cmmpose_core::kernel;
use cmmpose_core::Digitizer;
use numpy::{PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::{effects, kernel_points, run_kernel, MapPolicy, NamedArrays};
use crate::errors::Res;
use crate::maps::map_source;
use crate::pose::PyDigitizer;

/// Compensated machine coordinates (N, 3) mm under a model: the thesis
/// compensation plus the `effects` (name -> parameter values, in the units
/// of the effect's Python file). `digitizers` holds one Digitizer per pose,
/// `pose_index` (N,) uint32 each point's; `inputs` maps names to (N,) or
/// (N, k) float64 arrays: `temperature` (C) and what the effects read.
/// Returns the coordinates and the kernel's report (a dict).
#[pyfunction]
#[pyo3(signature = (uv, scales, maps, digitizers, policy, *, pose_index=None, inputs=None, effects=None, nan_policy="raise"))]
#[allow(clippy::too_many_arguments)]
fn compensate_model<'py>(
    py: Python<'py>,
    uv: PyReadonlyArray2<'py, f64>,
    scales: PyReadonlyArray2<'py, f64>,
    maps: &Bound<'py, PyAny>,
    digitizers: Vec<PyRef<'py, PyDigitizer>>,
    policy: MapPolicy,
    pose_index: Option<PyReadonlyArray1<'py, u32>>,
    inputs: Option<&Bound<'py, PyDict>>,
    effects: Option<&Bound<'py, PyDict>>,
    nan_policy: &str,
) -> Res<(Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>)> {
    let opts = policy.options(nan_policy)?;
    let source = map_source(maps)?;
    let digitizers: Vec<Digitizer> = digitizers.iter().map(|d| d.inner).collect();
    let fx = self::effects(effects)?;
    let named = NamedArrays::from_dict("inputs", inputs)?;
    let points = kernel_points(&uv, &scales, pose_index.as_ref(), &named)?;
    let n = points.scales.len() / 3;
    run_kernel(py, n, 3, |out| {
        kernel::compensate_points(&points, source, &digitizers, &fx, opts, out)
    })
}

/// The effect terms of the core, in registry order: dicts with `name`,
/// `params` (names) and `inputs` ((name, values per point) pairs).
#[pyfunction]
fn effect_terms(py: Python<'_>) -> Res<Vec<Bound<'_, PyDict>>> {
    let mut out = Vec::new();
    for t in TERMS {
        let d = PyDict::new(py);
        d.set_item("name", t.name())?;
        d.set_item("params", t.params().to_vec())?;
        d.set_item("inputs", t.inputs().to_vec())?;
        out.push(d);
    }
    Ok(out)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(compensate_model, m)?)?;
    m.add_function(wrap_pyfunction!(effect_terms, m)?)?;
    Ok(())
}
