//! Fits across the boundary: sphere (one, or one per group in parallel) and
//! plane; results leave as dicts of named fields (for many spheres, named
//! columns: one array per field).

use cmmpose_core::fit::{self, PlaneFit, PlaneFitOptions, SphereFit, SphereFitOptions};
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::rows;
use crate::errors::{input, Failure, Res};

fn sphere_dict<'py>(py: Python<'py>, f: SphereFit) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("centre", f.centre)?;
    d.set_item("radius", f.radius)?;
    d.set_item("residuals", PyArray1::from_vec(py, f.residuals))?;
    d.set_item("inlier", PyArray1::from_vec(py, f.inlier))?;
    d.set_item("rms", f.rms)?;
    d.set_item("form", f.form)?;
    d.set_item("n_points", f.n_points)?;
    let cov: Vec<Vec<f64>> = f.covariance.iter().map(|r| r.to_vec()).collect();
    d.set_item(
        "covariance",
        PyArray2::from_vec2(py, &cov).map_err(|e| input(e.to_string()))?,
    )?;
    d.set_item("polar_coverage", f.polar_coverage_deg)?;
    d.set_item("iterations", f.iterations)?;
    d.set_item("converged", f.converged)?;
    d.set_item("rejected", f.rejected)?;
    Ok(d)
}

fn sphere_options(
    radius: Option<f64>,
    reject: Option<f64>,
    max_iterations: usize,
    min_coverage: f64,
) -> SphereFitOptions {
    SphereFitOptions {
        radius,
        reject,
        max_iterations,
        min_coverage_deg: min_coverage,
    }
}

/// Geometric least-squares sphere through (N, 3) points (mm).
#[pyfunction]
#[pyo3(signature = (points, radius=None, reject=None, max_iterations=100, min_coverage=2.0))]
fn fit_sphere<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    radius: Option<f64>,
    reject: Option<f64>,
    max_iterations: usize,
    min_coverage: f64,
) -> Res<Bound<'py, PyDict>> {
    let p = rows("points", &points, 3)?;
    let opts = sphere_options(radius, reject, max_iterations, min_coverage);
    let f = py.detach(|| fit::fit_sphere(p, &opts))?;
    Ok(sphere_dict(py, f)?)
}

/// One sphere per group: `points` (N, 3) sorted by group, `bounds` (G + 1,)
/// row offsets. Fits run in parallel across groups with the GIL released.
/// The result is a dict of named columns, one entry per group (centre
/// (G, 3), radius (G,), ..., covariance (G, 4, 4)), the per-point
/// `residuals` and `inlier` (N,) in the rows' order, and `error`: a list of
/// the exception of each group that failed, None for the others.
#[pyfunction]
#[pyo3(signature = (points, bounds, radius=None, reject=None, max_iterations=100, min_coverage=2.0))]
#[allow(clippy::too_many_arguments)]
fn fit_spheres<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    bounds: PyReadonlyArray1<'py, i64>,
    radius: Option<f64>,
    reject: Option<f64>,
    max_iterations: usize,
    min_coverage: f64,
) -> Res<Bound<'py, PyDict>> {
    let p = rows("points", &points, 3)?;
    let b = bounds
        .as_slice()
        .map_err(|_| input("bounds: array must be contiguous"))?;
    // A negative offset cannot rise from 0; the core checks the rest.
    let b: Vec<usize> = b
        .iter()
        .map(|&v| usize::try_from(v).unwrap_or(usize::MAX))
        .collect();
    let opts = sphere_options(radius, reject, max_iterations, min_coverage);
    let f = py.detach(|| fit::fit_sphere_groups(p, &b, &opts))?;
    let k = f.radius.len();
    let counts = |v: Vec<usize>| PyArray1::from_vec(py, v.into_iter().map(|c| c as i64).collect());
    let d = PyDict::new(py);
    d.set_item(
        "centre",
        PyArray1::from_vec(py, f.centre.into_flattened()).reshape([k, 3])?,
    )?;
    d.set_item("radius", PyArray1::from_vec(py, f.radius))?;
    d.set_item("rms", PyArray1::from_vec(py, f.rms))?;
    d.set_item("form", PyArray1::from_vec(py, f.form))?;
    d.set_item("n_points", counts(f.n_points))?;
    d.set_item(
        "covariance",
        PyArray1::from_vec(py, f.covariance.into_flattened().into_flattened())
            .reshape([k, 4, 4])?,
    )?;
    d.set_item(
        "polar_coverage",
        PyArray1::from_vec(py, f.polar_coverage_deg),
    )?;
    d.set_item("iterations", counts(f.iterations))?;
    d.set_item("converged", PyArray1::from_vec(py, f.converged))?;
    d.set_item("rejected", counts(f.rejected))?;
    d.set_item("residuals", PyArray1::from_vec(py, f.residuals))?;
    d.set_item("inlier", PyArray1::from_vec(py, f.inlier))?;
    let error: Vec<Option<Bound<'py, PyAny>>> = f
        .error
        .into_iter()
        .map(|e| {
            e.map(|e| {
                PyErr::from(Failure::from(e))
                    .into_value(py)
                    .into_bound(py)
                    .into_any()
            })
        })
        .collect();
    d.set_item("error", error)?;
    Ok(d)
}

/// Total least-squares plane through (N, 3) points (mm).
#[pyfunction]
#[pyo3(signature = (points, reject=None))]
fn fit_plane<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    reject: Option<f64>,
) -> Res<Bound<'py, PyDict>> {
    let p = rows("points", &points, 3)?;
    let opts = PlaneFitOptions { reject };
    let f: PlaneFit = py.detach(|| fit::fit_plane(p, &opts))?;
    let d = PyDict::new(py);
    d.set_item("point", f.point)?;
    d.set_item("normal", f.normal)?;
    d.set_item("residuals", PyArray1::from_vec(py, f.residuals))?;
    d.set_item("inlier", PyArray1::from_vec(py, f.inlier))?;
    d.set_item("rms", f.rms)?;
    d.set_item("form", f.form)?;
    d.set_item("n_points", f.n_points)?;
    d.set_item("axes", f.axes)?;
    let cov: Vec<Vec<f64>> = f.tilt_covariance.iter().map(|r| r.to_vec()).collect();
    d.set_item(
        "tilt_covariance",
        PyArray2::from_vec2(py, &cov).map_err(|e| input(e.to_string()))?,
    )?;
    d.set_item("rejected", f.rejected)?;
    Ok(d)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(fit_sphere, m)?)?;
    m.add_function(wrap_pyfunction!(fit_spheres, m)?)?;
    m.add_function(wrap_pyfunction!(fit_plane, m)?)?;
    Ok(())
}
