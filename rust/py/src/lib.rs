//! pyo3 bindings of cmmpose-core: the `cmmpose._core` module. Only
//! conversion lives here: arrays in (float64, C-contiguous, read without
//! copying), one output array allocated, the kernel run with the GIL
//! released, core errors mapped one-to-one onto Python exceptions.

use cmmpose_core as core;
use core::kernel::{self, NanPolicy, Options, OutOfRange, Report};
use core::{Carriage, CarriageTable, CoreError, Digitizer, ErrorMap, ErrorMapSet, Pose};
use numpy::{
    PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::PyDict;

create_exception!(
    _core,
    Error,
    PyException,
    "Base class of every cmmpose error."
);
create_exception!(
    _core,
    MapError,
    Error,
    "A malformed error map or map file (names the file, carriage and row)."
);
create_exception!(
    _core,
    OutOfRangeError,
    Error,
    "A scale reading or temperature outside what the maps cover."
);
create_exception!(
    _core,
    InputError,
    Error,
    "An input array or argument with the wrong shape, length or value."
);
create_exception!(
    _core,
    GeometryError,
    Error,
    "Degenerate geometry (zero normal, coplanar points, ...)."
);

/// One core error variant, one Python exception.
fn to_py(e: CoreError) -> PyErr {
    let msg = e.to_string();
    match e {
        CoreError::InvalidMap { .. } => MapError::new_err(msg),
        CoreError::PositionOutOfRange { .. } | CoreError::TemperatureOutOfRange { .. } => {
            OutOfRangeError::new_err(msg)
        }
        CoreError::NonFinite { .. } | CoreError::InvalidArgument { .. } => InputError::new_err(msg),
        CoreError::Degenerate(_) => GeometryError::new_err(msg),
    }
}

fn options(out_of_range: &str, nan_policy: &str) -> PyResult<Options> {
    let out_of_range = match out_of_range {
        "raise" => OutOfRange::Raise,
        "clamp" => OutOfRange::Clamp,
        other => {
            return Err(InputError::new_err(format!(
                "out_of_range: expected 'raise' or 'clamp', got {other:?}"
            )))
        }
    };
    let nan_policy = match nan_policy {
        "raise" => NanPolicy::Raise,
        "propagate" => NanPolicy::Propagate,
        other => {
            return Err(InputError::new_err(format!(
                "nan_policy: expected 'raise' or 'propagate', got {other:?}"
            )))
        }
    };
    Ok(Options {
        out_of_range,
        nan_policy,
    })
}

/// Zero-copy view of an (N, cols) float64 C-contiguous array.
fn rows<'a>(name: &str, a: &'a PyReadonlyArray2<'_, f64>, cols: usize) -> PyResult<&'a [f64]> {
    let shape = a.shape();
    if shape[1] != cols {
        return Err(InputError::new_err(format!(
            "{name}: expected shape (N, {cols}), got ({}, {})",
            shape[0], shape[1]
        )));
    }
    a.as_slice().map_err(|_| {
        InputError::new_err(format!(
            "{name}: array must be C-contiguous (use numpy.ascontiguousarray)"
        ))
    })
}

fn report_dict<'py>(py: Python<'py>, r: &Report) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("points", r.points)?;
    d.set_item("clamped_position", r.clamped_position)?;
    d.set_item("clamped_temperature", r.clamped_temperature)?;
    d.set_item("nan_rows", r.nan_rows)?;
    Ok(d)
}

/// Allocate the (n, width) output and run `f` on it without the GIL.
fn run_kernel<'py, F>(
    py: Python<'py>,
    n: usize,
    width: usize,
    f: F,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>)>
where
    F: FnOnce(&mut [f64]) -> core::Result<Report> + Send,
{
    // Uninitialised is fine: the kernel writes every element or fails.
    let out = unsafe { PyArray2::<f64>::new(py, [n, width], false) };
    let slice = unsafe { out.as_slice_mut() }.expect("fresh array is contiguous");
    let report = py.detach(|| f(slice)).map_err(to_py)?;
    let report = report_dict(py, &report)?;
    Ok((out, report))
}

fn digitizer(pose: (f64, f64, f64), offset: (f64, f64, f64)) -> PyResult<Digitizer> {
    let pose = Pose::new(pose.0, pose.1, pose.2).map_err(to_py)?;
    Digitizer::new(&pose, [offset.0, offset.1, offset.2]).map_err(to_py)
}

/// The 21 component errors at one temperature.
#[pyclass(name = "ErrorMap", module = "cmmpose._core", frozen)]
struct PyErrorMap {
    inner: ErrorMap,
}

#[pymethods]
impl PyErrorMap {
    /// Tables are (n, 7): position mm, dx dy dz um, ex ey ez arc-second;
    /// squareness (S_xy, S_yz, S_zx) arc-second; temperature C or None.
    #[new]
    #[pyo3(signature = (x, y, z, squareness, temperature=None))]
    fn new(
        x: PyReadonlyArray2<'_, f64>,
        y: PyReadonlyArray2<'_, f64>,
        z: PyReadonlyArray2<'_, f64>,
        squareness: [f64; 3],
        temperature: Option<f64>,
    ) -> PyResult<Self> {
        let mut tables = Vec::with_capacity(3);
        for (c, (name, t)) in Carriage::ALL
            .into_iter()
            .zip([("x", &x), ("y", &y), ("z", &z)])
        {
            let flat = rows(name, t, 7)?;
            let table_rows: Vec<[f64; 7]> = flat
                .chunks_exact(7)
                .map(|r| r.try_into().unwrap())
                .collect();
            tables.push(CarriageTable::from_table_units(c, &table_rows).map_err(to_py)?);
        }
        let tables: [CarriageTable; 3] = tables
            .try_into()
            .map_err(|_| Error::new_err("three tables"))?;
        Ok(PyErrorMap {
            inner: ErrorMap::new(tables, squareness, temperature).map_err(to_py)?,
        })
    }

    /// The table of one carriage ('X', 'Y' or 'Z') in table units, (n, 7).
    fn table<'py>(&self, py: Python<'py>, carriage: &str) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let c = match carriage {
            "X" | "x" => Carriage::X,
            "Y" | "y" => Carriage::Y,
            "Z" | "z" => Carriage::Z,
            other => {
                return Err(InputError::new_err(format!(
                    "carriage: expected 'X', 'Y' or 'Z', got {other:?}"
                )))
            }
        };
        let rows: Vec<Vec<f64>> = self
            .inner
            .table(c)
            .to_table_units()
            .iter()
            .map(|r| r.to_vec())
            .collect();
        PyArray2::from_vec2(py, &rows).map_err(|e| Error::new_err(e.to_string()))
    }

    /// (S_xy, S_yz, S_zx) in arc-seconds.
    #[getter]
    fn squareness(&self) -> (f64, f64, f64) {
        let s = self.inner.squareness_arcsec();
        (s[0], s[1], s[2])
    }

    #[getter]
    fn temperature(&self) -> Option<f64> {
        self.inner.temperature()
    }

    /// ((lo, hi) mm) for X, Y, Z.
    #[getter]
    fn ranges(&self) -> [(f64, f64); 3] {
        self.inner.ranges()
    }

    fn with_temperature(&self, temperature: Option<f64>) -> PyResult<Self> {
        if let Some(t) = temperature {
            if !t.is_finite() {
                return Err(MapError::new_err(format!(
                    "temperature: {t} C is not finite"
                )));
            }
        }
        Ok(PyErrorMap {
            inner: self.inner.clone().with_temperature(temperature),
        })
    }

    #[pyo3(signature = (scales, out_of_range="raise", nan_policy="raise"))]
    fn position_error<'py>(
        &self,
        py: Python<'py>,
        scales: PyReadonlyArray2<'py, f64>,
        out_of_range: &str,
        nan_policy: &str,
    ) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>)> {
        let opts = options(out_of_range, nan_policy)?;
        let s = rows("scales", &scales, 3)?;
        let map = &self.inner;
        run_kernel(py, s.len() / 3, 3, |out| {
            kernel::position_error(s, map, opts, out)
        })
    }

    #[pyo3(signature = (scales, out_of_range="raise", nan_policy="raise"))]
    fn rotation_error<'py>(
        &self,
        py: Python<'py>,
        scales: PyReadonlyArray2<'py, f64>,
        out_of_range: &str,
        nan_policy: &str,
    ) -> PyResult<(Bound<'py, PyArray3<f64>>, Bound<'py, PyDict>)> {
        let opts = options(out_of_range, nan_policy)?;
        let s = rows("scales", &scales, 3)?;
        let map = &self.inner;
        let n = s.len() / 3;
        let (flat, report) = run_kernel(py, n, 9, |out| kernel::rotation_error(s, map, opts, out))?;
        Ok((flat.reshape([n, 3, 3])?, report))
    }

    fn __eq__(&self, other: &Self) -> bool {
        self.inner == other.inner
    }
}

/// Error maps at several temperatures.
#[pyclass(name = "ErrorMapSet", module = "cmmpose._core", frozen)]
struct PyErrorMapSet {
    inner: ErrorMapSet,
}

#[pymethods]
impl PyErrorMapSet {
    #[new]
    fn new(maps: Vec<PyRef<'_, PyErrorMap>>) -> PyResult<Self> {
        let maps = maps.iter().map(|m| m.inner.clone()).collect();
        Ok(PyErrorMapSet {
            inner: ErrorMapSet::new(maps).map_err(to_py)?,
        })
    }

    #[getter]
    fn temperatures(&self) -> Vec<f64> {
        self.inner.temperatures()
    }

    /// The maps, sorted by temperature.
    #[getter]
    fn maps(&self) -> Vec<PyErrorMap> {
        self.inner
            .maps()
            .iter()
            .map(|m| PyErrorMap { inner: m.clone() })
            .collect()
    }

    /// The map blended at `temperature` (C).
    #[pyo3(signature = (temperature, out_of_range="raise"))]
    fn at(&self, temperature: f64, out_of_range: &str) -> PyResult<PyErrorMap> {
        let opts = options(out_of_range, "raise")?;
        let inner = self
            .inner
            .at(temperature, opts.out_of_range == OutOfRange::Clamp)
            .map_err(to_py)?;
        Ok(PyErrorMap { inner })
    }
}

/// Compensated machine coordinates (mm). `error_map` is an ErrorMap or an
/// ErrorMapSet; with a set, `temperature` is a float or an (N,) array (C).
#[pyfunction]
#[pyo3(signature = (uv, scales, error_map, pose, offset, temperature=None, out_of_range="raise", nan_policy="raise"))]
#[allow(clippy::too_many_arguments)]
fn compensate<'py>(
    py: Python<'py>,
    uv: PyReadonlyArray2<'py, f64>,
    scales: PyReadonlyArray2<'py, f64>,
    error_map: &Bound<'py, PyAny>,
    pose: (f64, f64, f64),
    offset: (f64, f64, f64),
    temperature: Option<&Bound<'py, PyAny>>,
    out_of_range: &str,
    nan_policy: &str,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>)> {
    let opts = options(out_of_range, nan_policy)?;
    let uv_s = rows("uv", &uv, 2)?;
    let s = rows("scales", &scales, 3)?;
    let d = digitizer(pose, offset)?;
    let n = s.len() / 3;
    if let Ok(map) = error_map.cast::<PyErrorMap>() {
        if temperature.is_some() {
            return Err(InputError::new_err(
                "temperature: only meaningful with an ErrorMapSet; an ErrorMap has one temperature",
            ));
        }
        let map = &map.get().inner;
        return run_kernel(py, n, 3, |out| {
            kernel::compensate(uv_s, s, map, &d, opts, out)
        });
    }
    let set = error_map
        .cast::<PyErrorMapSet>()
        .map_err(|_| InputError::new_err("error_map: expected an ErrorMap or an ErrorMapSet"))?;
    let set = &set.get().inner;
    let temperature = temperature.ok_or_else(|| {
        InputError::new_err(
            "temperature: required with an ErrorMapSet (a float or an (N,) array, C)",
        )
    })?;
    if let Ok(t) = temperature.extract::<f64>() {
        return run_kernel(py, n, 3, |out| {
            kernel::compensate_at_temperature(uv_s, s, t, set, &d, opts, out)
        });
    }
    let t: PyReadonlyArray1<'py, f64> = temperature.extract().map_err(|_| {
        InputError::new_err("temperature: expected a float or a float64 (N,) array")
    })?;
    let t = t
        .as_slice()
        .map_err(|_| InputError::new_err("temperature: array must be contiguous"))?;
    run_kernel(py, n, 3, |out| {
        kernel::compensate_at_temperatures(uv_s, s, t, set, &d, opts, out)
    })
}

/// What the digitizer software reports, without compensation (mm).
#[pyfunction]
#[pyo3(signature = (uv, scales, pose, offset, nan_policy="raise"))]
fn uncompensated<'py>(
    py: Python<'py>,
    uv: PyReadonlyArray2<'py, f64>,
    scales: PyReadonlyArray2<'py, f64>,
    pose: (f64, f64, f64),
    offset: (f64, f64, f64),
    nan_policy: &str,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>)> {
    let opts = options("raise", nan_policy)?;
    let uv_s = rows("uv", &uv, 2)?;
    let s = rows("scales", &scales, 3)?;
    let d = digitizer(pose, offset)?;
    run_kernel(py, s.len() / 3, 3, |out| {
        kernel::uncompensated(uv_s, s, &d, opts, out)
    })
}

/// E313 of eq. 7 for angles in degrees.
#[pyfunction]
fn euler313<'py>(
    py: Python<'py>,
    alpha: f64,
    beta: f64,
    gamma: f64,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let m = Pose::new(alpha, beta, gamma).map_err(to_py)?.matrix();
    let rows: Vec<Vec<f64>> = (0..3)
        .map(|r| (0..3).map(|c| m[(r, c)]).collect())
        .collect();
    PyArray2::from_vec2(py, &rows).map_err(|e| Error::new_err(e.to_string()))
}

/// (alpha, beta, gamma) degrees of the pose whose w axis is `normal`.
#[pyfunction]
fn pose_from_normal(normal: [f64; 3], gamma: f64) -> PyResult<(f64, f64, f64)> {
    let p = Pose::from_normal(normal, gamma).map_err(to_py)?;
    Ok((p.alpha, p.beta, p.gamma))
}

/// Number of threads the kernels use (rayon's global pool; set
/// RAYON_NUM_THREADS before the first call to change it).
#[pyfunction]
fn thread_count() -> usize {
    core::thread_count()
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("Error", py.get_type::<Error>())?;
    m.add("MapError", py.get_type::<MapError>())?;
    m.add("OutOfRangeError", py.get_type::<OutOfRangeError>())?;
    m.add("InputError", py.get_type::<InputError>())?;
    m.add("GeometryError", py.get_type::<GeometryError>())?;
    m.add_class::<PyErrorMap>()?;
    m.add_class::<PyErrorMapSet>()?;
    m.add_function(wrap_pyfunction!(compensate, m)?)?;
    m.add_function(wrap_pyfunction!(uncompensated, m)?)?;
    m.add_function(wrap_pyfunction!(euler313, m)?)?;
    m.add_function(wrap_pyfunction!(pose_from_normal, m)?)?;
    m.add_function(wrap_pyfunction!(thread_count, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
