//! Arrays and named structures across the boundary, validated in one place:
//! float64 C-contiguous arrays are read without copying (the Python layer
//! converts other dtypes and layouts explicitly), named per-point inputs
//! arrive as a dict of arrays, effects as a dict of parameter lists, kernel
//! options as strings, reports leave as a dict.

use cmmpose_core::kernel::{NanPolicy, Options, OutOfRange, Points, Report};
use cmmpose_core::{Columns, Effects};
use numpy::{
    PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArrayDyn,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::{input, Res};

/// Zero-copy view of an (N, cols) float64 C-contiguous array.
pub fn rows<'a>(name: &str, a: &'a PyReadonlyArray2<'_, f64>, cols: usize) -> Res<&'a [f64]> {
    let shape = a.shape();
    if shape[1] != cols {
        return Err(input(format!(
            "{name}: expected shape (N, {cols}), got ({}, {})",
            shape[0], shape[1]
        )));
    }
    // `as_slice` also accepts a Fortran-ordered array, whose flat order is
    // not row by row.
    let c_order = a.is_c_contiguous();
    a.as_slice().ok().filter(|_| c_order).ok_or_else(|| {
        input(format!(
            "{name}: array must be C-contiguous (use numpy.ascontiguousarray)"
        ))
    })
}

/// Zero-copy view of a contiguous 1-D array.
pub fn vector<'a, T: numpy::Element>(name: &str, a: &'a PyReadonlyArray1<'_, T>) -> Res<&'a [T]> {
    a.as_slice()
        .map_err(|_| input(format!("{name}: array must be contiguous")))
}

pub fn options(out_of_range: &str, nan_policy: &str) -> Res<Options> {
    options_with(out_of_range, nan_policy, 0.0)
}

/// The map side of a `cmmpose.TemperaturePolicy`: what the kernel does with
/// a reading or temperature outside the maps. Read from the policy object's
/// attributes, so the one policy crosses the boundary whole and the binding
/// holds no default of its own (Python's is the only one).
#[derive(FromPyObject)]
pub struct MapPolicy {
    #[pyo3(attribute("out_of_range"))]
    pub out_of_range: String,
    #[pyo3(attribute("temperature_tolerance"))]
    pub temperature_tolerance: f64,
}

impl MapPolicy {
    /// The kernel's options under this policy and `nan_policy`.
    pub fn options(&self, nan_policy: &str) -> Res<Options> {
        options_with(&self.out_of_range, nan_policy, self.temperature_tolerance)
    }
}

/// Options with a temperature tolerance (K; finite, >= 0).
fn options_with(out_of_range: &str, nan_policy: &str, temperature_tolerance: f64) -> Res<Options> {
    let out_of_range = match out_of_range {
        "raise" => OutOfRange::Raise,
        "clamp" => OutOfRange::Clamp,
        "extrapolate" => OutOfRange::Extrapolate,
        other => {
            return Err(input(format!(
                "out_of_range: expected 'raise', 'clamp' or 'extrapolate', got {other:?}"
            )))
        }
    };
    if !(temperature_tolerance.is_finite() && temperature_tolerance >= 0.0) {
        return Err(input(format!(
            "temperature_tolerance: expected a finite number of kelvin >= 0, got {temperature_tolerance}"
        )));
    }
    let nan_policy = match nan_policy {
        "raise" => NanPolicy::Raise,
        "propagate" => NanPolicy::Propagate,
        other => {
            return Err(input(format!(
                "nan_policy: expected 'raise' or 'propagate', got {other:?}"
            )))
        }
    };
    Ok(Options {
        out_of_range,
        nan_policy,
        temperature_tolerance,
    })
}

pub fn report_dict<'py>(py: Python<'py>, r: &Report) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("points", r.points)?;
    d.set_item("clamped_position", r.clamped_position)?;
    d.set_item("clamped_temperature", r.clamped_temperature)?;
    d.set_item("clamped_points", r.clamped_points)?;
    d.set_item("held_temperature", r.held_temperature)?;
    d.set_item("extrapolated_temperature", r.extrapolated_temperature)?;
    d.set_item("max_extrapolation", r.max_extrapolation)?;
    d.set_item("nan_rows", r.nan_rows)?;
    Ok(d)
}

/// Allocate the (n, width) output and run `f` on it without the GIL.
pub fn run_kernel<'py, F>(
    py: Python<'py>,
    n: usize,
    width: usize,
    f: F,
) -> Res<(Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>)>
where
    F: FnOnce(&mut [f64]) -> cmmpose_core::Result<Report> + Send,
{
    run_kernel_into(py, n, width, None, f)
}

/// As [`run_kernel`], writing into the caller's `out` when given: an (n,
/// width) float64 C-contiguous writeable array that shares no memory with
/// the inputs (numpy's borrow check refuses an overlap, which would have
/// the kernel read what it has written). It is returned as the result.
pub fn run_kernel_into<'py, F>(
    py: Python<'py>,
    n: usize,
    width: usize,
    out: Option<&Bound<'py, PyAny>>,
    f: F,
) -> Res<(Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>)>
where
    F: FnOnce(&mut [f64]) -> cmmpose_core::Result<Report> + Send,
{
    let Some(out) = out else {
        // Uninitialised is fine: the kernel writes every element or fails.
        let fresh = unsafe { PyArray2::<f64>::new(py, [n, width], false) };
        let slice = unsafe { fresh.as_slice_mut() }.expect("fresh array is contiguous");
        let report = py.detach(|| f(slice))?;
        return Ok((fresh, report_dict(py, &report)?));
    };
    let array = out.cast::<PyArray2<f64>>().map_err(|_| {
        input(format!(
            "out: expected a float64 array of shape ({n}, {width}), got {}",
            describe(out)
        ))
    })?;
    if array.shape() != [n, width] {
        return Err(input(format!(
            "out: expected shape ({n}, {width}), got {:?}",
            array.shape()
        )));
    }
    if !array.is_c_contiguous() {
        return Err(input("out: must be C-contiguous"));
    }
    let mut view = array.try_readwrite().map_err(|e| {
        input(format!(
            "out: cannot be written ({e}): it must be writeable and share no memory with the inputs"
        ))
    })?;
    let slice = view
        .as_slice_mut()
        .map_err(|_| input("out: must be C-contiguous"))?;
    let report = py.detach(|| f(slice))?;
    drop(view);
    Ok((array.clone(), report_dict(py, &report)?))
}

/// Type and dtype of a Python object, for messages.
fn describe(x: &Bound<'_, PyAny>) -> String {
    match x.cast::<numpy::PyUntypedArray>() {
        Ok(a) => format!("an array of dtype {}", a.dtype()),
        Err(_) => x
            .get_type()
            .name()
            .map(|n| n.to_string())
            .unwrap_or_else(|_| "an object".into()),
    }
}

/// Named per-point inputs: a dict of float64 C-contiguous arrays, (N,) for
/// one value per point or (N, k) for k. Held here so the views stay valid.
pub struct NamedArrays<'py> {
    items: Vec<(String, usize, PyReadonlyArrayDyn<'py, f64>)>,
}

impl<'py> NamedArrays<'py> {
    pub fn from_dict(arg: &str, d: Option<&Bound<'py, PyDict>>) -> Res<Self> {
        let mut items = Vec::new();
        if let Some(d) = d {
            for (k, v) in d.iter() {
                let name: String = k
                    .extract()
                    .map_err(|_| input(format!("{arg}: keys must be names (str)")))?;
                let a: PyReadonlyArrayDyn<'py, f64> = v.extract().map_err(|_| {
                    input(format!("{arg}[{name:?}]: expected a float64 numpy array"))
                })?;
                let width = match a.shape() {
                    [_] => 1,
                    [_, k] => *k,
                    other => {
                        return Err(input(format!(
                            "{arg}[{name:?}]: expected shape (N,) or (N, k), got {other:?}"
                        )))
                    }
                };
                if !a.is_c_contiguous() {
                    return Err(input(format!(
                        "{arg}[{name:?}]: array must be C-contiguous"
                    )));
                }
                items.push((name, width, a));
            }
        }
        Ok(NamedArrays { items })
    }

    /// The arrays as the core's named columns.
    pub fn columns(&self) -> Res<Columns<'_>> {
        let mut c = Columns::new();
        for (name, width, a) in &self.items {
            let values = a
                .as_slice()
                .map_err(|_| input(format!("{name}: array must be C-contiguous")))?;
            c = c.with(name.as_str(), *width, values);
        }
        Ok(c)
    }
}

/// Effects from a dict of name -> parameter values (a number or a list).
pub fn effects(d: Option<&Bound<'_, PyDict>>) -> Res<Effects> {
    let Some(d) = d else {
        return Ok(Effects::none());
    };
    let mut named = Vec::new();
    for (k, v) in d.iter() {
        let key: String = k
            .extract()
            .map_err(|_| input("effects: keys must be effect names (str)"))?;
        let vals: Vec<f64> = v
            .extract::<Vec<f64>>()
            .or_else(|_| v.extract::<f64>().map(|x| vec![x]))
            .map_err(|_| input(format!("effects[{key:?}]: expected numbers")))?;
        named.push((key, vals));
    }
    Ok(Effects::new(named)?)
}

/// The kernel's points from the binding's arguments: (u, v) and readings
/// read without copying, each point's pose and the named per-point inputs.
pub fn kernel_points<'a>(
    uv: &'a PyReadonlyArray2<'_, f64>,
    scales: &'a PyReadonlyArray2<'_, f64>,
    pose_index: Option<&'a PyReadonlyArray1<'_, u32>>,
    named: &'a NamedArrays<'_>,
) -> Res<Points<'a>> {
    Ok(Points {
        uv: rows("uv", uv, 2)?,
        scales: rows("scales", scales, 3)?,
        pose_index: pose_index.map(|p| vector("pose_index", p)).transpose()?,
        columns: named.columns()?,
    })
}
