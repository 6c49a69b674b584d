//! pyo3 bindings of cmmpose-core: the `cmmpose._core` module. Only
//! conversion lives here: arrays in (float64, C-contiguous, read without
//! copying), one output array allocated, the kernel run with the GIL
//! released, core errors mapped one-to-one onto Python exceptions.

use cmmpose_core as core;
use core::artefact::Surface;
use core::fit::{self, PlaneFit, PlaneFitOptions, SphereFit, SphereFitOptions};
use core::kernel::{self, NanPolicy, Options, OutOfRange, Report};
use core::model::{self, EffectParams, ModelInputs};
use core::scanner::{self, ScanFrame, ScannerModel};
use core::truth::{self, MachineEffects};
use core::{Carriage, CarriageTable, CoreError, Digitizer, ErrorMap, ErrorMapSet, Pose};
use numpy::{
    PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyReadonlyArray3, PyUntypedArrayMethods,
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

fn optional_rows<'a>(
    name: &str,
    a: &'a Option<PyReadonlyArray2<'_, f64>>,
    cols: usize,
) -> PyResult<Option<&'a [f64]>> {
    a.as_ref().map(|a| rows(name, a, cols)).transpose()
}

fn optional_vector<'a>(
    name: &str,
    a: &'a Option<PyReadonlyArray1<'_, f64>>,
) -> PyResult<Option<&'a [f64]>> {
    a.as_ref()
        .map(|a| {
            a.as_slice()
                .map_err(|_| InputError::new_err(format!("{name}: array must be contiguous")))
        })
        .transpose()
}

/// Kernel-level effect parameters from a dict of name -> value(s).
fn effect_params(d: Option<&Bound<'_, PyDict>>) -> PyResult<EffectParams> {
    let mut fx = EffectParams::default();
    let Some(d) = d else { return Ok(fx) };
    for (k, v) in d.iter() {
        let key: String = k.extract()?;
        let vals: Vec<f64> = v
            .extract::<Vec<f64>>()
            .or_else(|_| v.extract::<f64>().map(|x| vec![x]))
            .map_err(|_| InputError::new_err(format!("effects[{key:?}]: expected numbers")))?;
        let slot: &mut [f64] = match key.as_str() {
            "squareness" => &mut fx.squareness,
            "scale_ppm" => &mut fx.scale_ppm,
            "roll_slope" => &mut fx.roll_slope,
            "axis_temperature_gain" => std::slice::from_mut(&mut fx.axis_temperature_gain),
            "granite_squareness" => &mut fx.granite_squareness,
            "latency" => std::slice::from_mut(&mut fx.latency),
            "scanner_scale" => &mut fx.scanner_scale,
            "incidence" => &mut fx.incidence,
            other => {
                return Err(InputError::new_err(format!(
                    "effects: unknown kernel term {other:?} (known: squareness, scale_ppm, \
                     roll_slope, axis_temperature_gain, granite_squareness, latency, \
                     scanner_scale, incidence)"
                )))
            }
        };
        if vals.len() != slot.len() || !vals.iter().all(|x| x.is_finite()) {
            return Err(InputError::new_err(format!(
                "effects[{key:?}]: expected {} finite values, got {vals:?}",
                slot.len()
            )));
        }
        slot.copy_from_slice(&vals);
    }
    Ok(fx)
}

/// Compensation under a diagnosis model: the thesis kernel plus the
/// kernel-level effects (rust/core/src/model.rs). `poses` is one
/// (alpha, beta, gamma, U1, V1, W1) per pose index (degrees, mm). Returns the
/// (N, 3) coordinates (mm) and the number of clamped points.
#[pyfunction]
#[pyo3(signature = (uv, scales, pose_index, temperature, maps, poses, effects=None, axis_temperature=None, gradient=None, velocity=None, incidence=None, clamp=false))]
#[allow(clippy::too_many_arguments)]
fn compensate_model<'py>(
    py: Python<'py>,
    uv: PyReadonlyArray2<'py, f64>,
    scales: PyReadonlyArray2<'py, f64>,
    pose_index: PyReadonlyArray1<'py, u32>,
    temperature: PyReadonlyArray1<'py, f64>,
    maps: &Bound<'py, PyAny>,
    poses: Vec<(f64, f64, f64, f64, f64, f64)>,
    effects: Option<&Bound<'py, PyDict>>,
    axis_temperature: Option<PyReadonlyArray2<'py, f64>>,
    gradient: Option<PyReadonlyArray1<'py, f64>>,
    velocity: Option<PyReadonlyArray2<'py, f64>>,
    incidence: Option<PyReadonlyArray1<'py, f64>>,
    clamp: bool,
) -> PyResult<(Bound<'py, PyArray2<f64>>, usize)> {
    let single;
    let set: &ErrorMapSet = if let Ok(m) = maps.cast::<PyErrorMap>() {
        single = ErrorMapSet::new(vec![m.get().inner.clone().with_temperature(Some(20.0))])
            .map_err(to_py)?;
        &single
    } else {
        &maps
            .cast::<PyErrorMapSet>()
            .map_err(|_| InputError::new_err("maps: expected an ErrorMap or an ErrorMapSet"))?
            .get()
            .inner
    };
    let digitizers = poses
        .iter()
        .map(|&(a, b, g, u1, v1, w1)| digitizer((a, b, g), (u1, v1, w1)))
        .collect::<PyResult<Vec<_>>>()?;
    let fx = effect_params(effects)?;
    let inputs = ModelInputs {
        uv: rows("uv", &uv, 2)?,
        scales: rows("scales", &scales, 3)?,
        pose_index: pose_index
            .as_slice()
            .map_err(|_| InputError::new_err("pose_index: array must be contiguous"))?,
        temperature: temperature
            .as_slice()
            .map_err(|_| InputError::new_err("temperature: array must be contiguous"))?,
        axis_temperature: optional_rows("axis_temperature", &axis_temperature, 3)?,
        gradient: optional_vector("gradient", &gradient)?,
        velocity: optional_rows("velocity", &velocity, 3)?,
        incidence_deg: optional_vector("incidence", &incidence)?,
    };
    let n = inputs.pose_index.len();
    let out = unsafe { PyArray2::<f64>::new(py, [n, 3], false) };
    let buf = unsafe { out.as_slice_mut() }.expect("fresh array is contiguous");
    let clamped = py
        .detach(|| model::compensate_model(&inputs, set, &digitizers, &fx, clamp, buf))
        .map_err(to_py)?;
    Ok((out, clamped))
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

/// True mount points P (N, 3) mm and ram orientations R (N, 3, 3) of the
/// truth machine. `states` is (N, 5): carriage map temperatures X, Y, Z (C),
/// squareness temperature (C), granite top-minus-bottom (K). `effects` is
/// (squareness_offset a-s, scale_error_ppm, roll_slope a-s/m, granite_squareness a-s/K),
/// each three values.
#[pyfunction]
#[allow(clippy::type_complexity)]
fn true_frames<'py>(
    py: Python<'py>,
    scales: PyReadonlyArray2<'py, f64>,
    states: PyReadonlyArray2<'py, f64>,
    map_set: PyRef<'py, PyErrorMapSet>,
    effects: ([f64; 3], [f64; 3], [f64; 3], [f64; 3]),
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray3<f64>>)> {
    let s = rows("scales", &scales, 3)?;
    let st = rows("states", &states, truth::STATE_WIDTH)?;
    let n = s.len() / 3;
    if st.len() / truth::STATE_WIDTH != n {
        return Err(InputError::new_err(format!(
            "states: has {} rows but scales has {n}",
            st.len() / truth::STATE_WIDTH
        )));
    }
    let fx = MachineEffects {
        squareness_offset: effects.0,
        scale_error_ppm: effects.1,
        roll_slope: effects.2,
        granite_squareness: effects.3,
    };
    let p = unsafe { PyArray2::<f64>::new(py, [n, 3], false) };
    let r = unsafe { PyArray3::<f64>::new(py, [n, 3, 3], false) };
    let (ps, rs) = unsafe {
        (
            p.as_slice_mut().expect("contiguous"),
            r.as_slice_mut().expect("contiguous"),
        )
    };
    let set = &map_set.inner;
    py.detach(|| truth::true_frames(s, st, set, &fx, ps, rs))
        .map_err(to_py)?;
    Ok((p, r))
}

fn surface(kind: &str, params: &[f64]) -> PyResult<Surface> {
    let v3 = |i: usize| [params[i], params[i + 1], params[i + 2]];
    let need = |k: usize| -> PyResult<()> {
        if params.len() == k {
            Ok(())
        } else {
            Err(InputError::new_err(format!(
                "surfaces: a {kind} takes {k} numbers, got {}",
                params.len()
            )))
        }
    };
    match kind {
        "sphere" => {
            need(4)?;
            Surface::sphere(v3(0), params[3]).map_err(to_py)
        }
        "spheroid" => {
            need(8)?;
            Surface::spheroid(v3(0), v3(3), params[6], params[7]).map_err(to_py)
        }
        "disc" => {
            need(7)?;
            Surface::disc(v3(0), v3(3), params[6]).map_err(to_py)
        }
        other => Err(InputError::new_err(format!(
            "surfaces: unknown kind {other:?} (sphere, spheroid, disc)"
        ))),
    }
}

/// Simulated profiles. `p` (M, 3) and `r` (M, 3, 3) are the true mount points
/// and ram orientations of M profiles; `pose`/`offset` the true digitizer
/// pose (deg) and mount offset (mm); `surfaces` a list of (kind, numbers).
/// Returns (profile index (K,), points (K, 6): u, v mm, cos(incidence), true X, Y, Z mm).
#[pyfunction]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
#[pyo3(signature = (p, r, pose, offset, surfaces, u_range=(-30.0, 30.0), v_range=(-30.0, 30.0), points_per_profile=1024, max_incidence_deg=70.0))]
fn scan_profiles<'py>(
    py: Python<'py>,
    p: PyReadonlyArray2<'py, f64>,
    r: PyReadonlyArray3<'py, f64>,
    pose: (f64, f64, f64),
    offset: (f64, f64, f64),
    surfaces: Vec<(String, Vec<f64>)>,
    u_range: (f64, f64),
    v_range: (f64, f64),
    points_per_profile: usize,
    max_incidence_deg: f64,
) -> PyResult<(Bound<'py, PyArray1<i64>>, Bound<'py, PyArray2<f64>>)> {
    let ps = rows("p", &p, 3)?;
    let m = ps.len() / 3;
    if r.shape() != [m, 3, 3] {
        return Err(InputError::new_err(format!(
            "r: expected shape ({m}, 3, 3), got {:?}",
            r.shape()
        )));
    }
    let rs = r
        .as_slice()
        .map_err(|_| InputError::new_err("r: array must be C-contiguous"))?;
    let e313 = Pose::new(pose.0, pose.1, pose.2).map_err(to_py)?.matrix();
    let offset = [offset.0, offset.1, offset.2];
    let surfaces = surfaces
        .iter()
        .map(|(k, v)| surface(k, v))
        .collect::<PyResult<Vec<_>>>()?;
    let model = ScannerModel {
        u_range,
        v_range,
        points_per_profile,
        max_incidence_deg,
    };
    let (index, pts) = py
        .detach(|| {
            let frames: Vec<ScanFrame> = (0..m)
                .map(|i| {
                    let pv = nalgebra::Vector3::new(ps[3 * i], ps[3 * i + 1], ps[3 * i + 2]);
                    let rm = nalgebra::Matrix3::from_row_slice(&rs[9 * i..9 * i + 9]);
                    ScanFrame::new(pv, &rm, &e313, offset)
                })
                .collect();
            scanner::profiles(&frames, &surfaces, &model)
        })
        .map_err(to_py)?;
    let idx = PyArray1::from_vec(py, index.into_iter().map(|k| k as i64).collect());
    let flat: Vec<f64> = pts
        .iter()
        .flat_map(|q| [q.u, q.v, q.cos_incidence, q.xyz[0], q.xyz[1], q.xyz[2]])
        .collect();
    let out = PyArray1::from_vec(py, flat).reshape([pts.len(), 6])?;
    Ok((idx, out))
}

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
        PyArray2::from_vec2(py, &cov).map_err(|e| Error::new_err(e.to_string()))?,
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
) -> PyResult<Bound<'py, PyDict>> {
    let p = rows("points", &points, 3)?;
    let opts = sphere_options(radius, reject, max_iterations, min_coverage);
    let f = py.detach(|| fit::fit_sphere(p, &opts)).map_err(to_py)?;
    sphere_dict(py, f)
}

/// One sphere per group: `points` (N, 3) sorted by group, `bounds` (G + 1,)
/// row offsets. Fits run in parallel across groups; a failed group gives
/// its error message instead of a dict.
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
) -> PyResult<Vec<Bound<'py, PyAny>>> {
    let p = rows("points", &points, 3)?;
    let b = bounds
        .as_slice()
        .map_err(|_| InputError::new_err("bounds: array must be contiguous"))?;
    let n = p.len() / 3;
    if b.is_empty()
        || b[0] != 0
        || *b.last().unwrap() as usize != n
        || b.windows(2).any(|w| w[1] < w[0])
    {
        return Err(InputError::new_err(format!(
            "bounds: must rise from 0 to the number of points ({n})"
        )));
    }
    let sets: Vec<&[f64]> = b
        .windows(2)
        .map(|w| &p[3 * w[0] as usize..3 * w[1] as usize])
        .collect();
    let opts = sphere_options(radius, reject, max_iterations, min_coverage);
    let fits = py.detach(|| fit::fit_spheres(&sets, &opts));
    fits.into_iter()
        .map(|r| match r {
            Ok(f) => Ok(sphere_dict(py, f)?.into_any()),
            Err(e) => Ok(to_py(e).into_value(py).into_bound(py).into_any()),
        })
        .collect()
}

/// Total least-squares plane through (N, 3) points (mm).
#[pyfunction]
#[pyo3(signature = (points, reject=None))]
fn fit_plane<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    reject: Option<f64>,
) -> PyResult<Bound<'py, PyDict>> {
    let p = rows("points", &points, 3)?;
    let opts = PlaneFitOptions { reject };
    let f: PlaneFit = py.detach(|| fit::fit_plane(p, &opts)).map_err(to_py)?;
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
        PyArray2::from_vec2(py, &cov).map_err(|e| Error::new_err(e.to_string()))?,
    )?;
    d.set_item("rejected", f.rejected)?;
    Ok(d)
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
    m.add_function(wrap_pyfunction!(compensate_model, m)?)?;
    m.add_function(wrap_pyfunction!(euler313, m)?)?;
    m.add_function(wrap_pyfunction!(pose_from_normal, m)?)?;
    m.add_function(wrap_pyfunction!(thread_count, m)?)?;
    m.add_function(wrap_pyfunction!(true_frames, m)?)?;
    m.add_function(wrap_pyfunction!(scan_profiles, m)?)?;
    m.add_function(wrap_pyfunction!(fit_sphere, m)?)?;
    m.add_function(wrap_pyfunction!(fit_spheres, m)?)?;
    m.add_function(wrap_pyfunction!(fit_plane, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
