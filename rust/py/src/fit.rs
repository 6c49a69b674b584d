//! Fits across the boundary: sphere (one, or one per group in parallel),
//! the E3125-style segmentation of a sphere from a raw scan, and plane;
//! results leave as dicts of named fields (for many spheres, named columns:
//! one array per field). Options cross by name (`rule="mad"`,
//! `start="lmeds"`), never as positional tuples.

use cmmpose_core::fit::{
    self, LeastMedian, PlaneFit, PlaneFitOptions, Rejection, SegmentationOptions, SphereFit,
    SphereFitOptions, Start,
};
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

/// The rejection rule named by `rule` ("none", "mad", "e3125"; `None`:
/// "mad" when a multiple is given, else "none") with the multiple `reject`
/// (default 3.5 for "mad", 3 for "e3125").
fn rejection(rule: Option<&str>, reject: Option<f64>) -> Res<Option<Rejection>> {
    let rule = rule.unwrap_or(if reject.is_some() { "mad" } else { "none" });
    Ok(match rule {
        "none" => {
            if let Some(k) = reject {
                return Err(input(format!(
                    "reject: rule='none' rejects nothing, got reject={k} (choose rule='mad' or 'e3125')"
                )));
            }
            None
        }
        "mad" => Some(Rejection::Mad(reject.unwrap_or(3.5))),
        "e3125" => Some(Rejection::SinglePass(reject.unwrap_or(3.0))),
        other => {
            return Err(input(format!(
                "rule: expected 'none', 'mad' (repeated, median-centred MAD) or 'e3125' \
                 (one pass at 3 standard deviations), got {other:?}"
            )))
        }
    })
}

/// The start named by `start` ("algebraic", "lmeds" or "centre", the last
/// with `centre`, mm).
fn start_of(start: &str, centre: Option<[f64; 3]>, samples: usize, seed: u64) -> Res<Start> {
    let lm = LeastMedian { samples, seed };
    Ok(match (start, centre) {
        ("algebraic", None) => Start::Algebraic,
        ("lmeds", None) => Start::LeastMedian(lm),
        ("centre", Some(c)) => Start::Centre(c),
        ("centre", None) => return Err(input("start: 'centre' needs centre=(x, y, z) in mm")),
        ("algebraic" | "lmeds", Some(_)) => {
            return Err(input(format!(
                "centre: a starting centre goes with start='centre', not start={start:?}"
            )))
        }
        (other, _) => {
            return Err(input(format!(
                "start: expected 'algebraic', 'lmeds' (least median of squares, high \
                 breakdown) or 'centre', got {other:?}"
            )))
        }
    })
}

#[allow(clippy::too_many_arguments)]
fn sphere_options(
    radius: Option<f64>,
    rule: Option<&str>,
    reject: Option<f64>,
    start: &str,
    centre: Option<[f64; 3]>,
    samples: usize,
    seed: u64,
    max_iterations: usize,
    min_coverage: f64,
) -> Res<SphereFitOptions> {
    Ok(SphereFitOptions {
        radius,
        reject: rejection(rule, reject)?,
        start: start_of(start, centre, samples, seed)?,
        max_iterations,
        min_coverage_deg: min_coverage,
    })
}

/// Geometric least-squares sphere through (N, 3) points (mm).
#[pyfunction]
#[pyo3(signature = (points, radius=None, *, reject=None, rule=None, start="algebraic", centre=None,
    samples=500, seed=0, max_iterations=100, min_coverage=2.0))]
#[allow(clippy::too_many_arguments)]
fn fit_sphere<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    radius: Option<f64>,
    reject: Option<f64>,
    rule: Option<&str>,
    start: &str,
    centre: Option<[f64; 3]>,
    samples: usize,
    seed: u64,
    max_iterations: usize,
    min_coverage: f64,
) -> Res<Bound<'py, PyDict>> {
    let p = rows("points", &points, 3)?;
    let opts = sphere_options(
        radius,
        rule,
        reject,
        start,
        centre,
        samples,
        seed,
        max_iterations,
        min_coverage,
    )?;
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
#[pyo3(signature = (points, bounds, radius=None, *, reject=None, rule=None, start="algebraic",
    samples=500, seed=0, max_iterations=100, min_coverage=2.0))]
#[allow(clippy::too_many_arguments)]
fn fit_spheres<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    bounds: PyReadonlyArray1<'py, i64>,
    radius: Option<f64>,
    reject: Option<f64>,
    rule: Option<&str>,
    start: &str,
    samples: usize,
    seed: u64,
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
    let opts = sphere_options(
        radius,
        rule,
        reject,
        start,
        None,
        samples,
        seed,
        max_iterations,
        min_coverage,
    )?;
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

/// Segments a sphere of calibrated `radius` (mm) from a raw scan (N, 3)
/// (mm) taken from `origin` (mm), in the manner of ASTM E3125, and fits it
/// with the radius fixed. The dict holds `fit` (a sphere dict: residuals of
/// every point, `inlier` the points used), `region` (N,) bool, `closest`
/// (row or None), `initial_centre`, `first_centre` (mm), `rounds`,
/// `converged`.
#[pyfunction]
#[pyo3(signature = (points, radius, origin, *, start=None, half_angle=60.0, rule="e3125",
    reject=None, max_rounds=50, samples=500, seed=0, max_iterations=100))]
#[allow(clippy::too_many_arguments)]
fn segment_sphere<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    radius: f64,
    origin: [f64; 3],
    start: Option<[f64; 3]>,
    half_angle: f64,
    rule: &str,
    reject: Option<f64>,
    max_rounds: usize,
    samples: usize,
    seed: u64,
    max_iterations: usize,
) -> Res<Bound<'py, PyDict>> {
    let p = rows("points", &points, 3)?;
    let opts = SegmentationOptions {
        start,
        half_angle_deg: half_angle,
        rule: rejection(Some(rule), reject)?,
        max_rounds,
        sampling: LeastMedian { samples, seed },
        max_iterations,
        ..SegmentationOptions::new(radius, origin)
    };
    let s = py.detach(|| fit::segment_sphere(p, &opts))?;
    let d = PyDict::new(py);
    d.set_item("fit", sphere_dict(py, s.fit)?)?;
    d.set_item("region", PyArray1::from_vec(py, s.region))?;
    d.set_item("closest", s.closest)?;
    d.set_item("initial_centre", s.initial_centre)?;
    d.set_item("first_centre", s.first_centre)?;
    d.set_item("rounds", s.rounds)?;
    d.set_item("converged", s.converged)?;
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
    m.add_function(wrap_pyfunction!(segment_sphere, m)?)?;
    m.add_function(wrap_pyfunction!(fit_plane, m)?)?;
    Ok(())
}
