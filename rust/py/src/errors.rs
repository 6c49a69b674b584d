//! The one conversion from core errors: each `CoreError` variant maps to one
//! class of `cmmpose.errors` (polars' shape), built from the variant's fields
//! (what, value, allowed range, unit, row, argument, remedy). The classes are
//! Python's own, so they pickle and keep their class across processes; how a
//! remedy reads in Python and on the command line is said there, from the
//! fields, never by rewriting this text.

use cmmpose_core::CoreError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

/// A failure on its way to Python: a core error, an input error raised by
/// the bindings, or a Python error. `?` converts each; the
/// exception is built (with the GIL held) when pyo3 raises it.
pub enum Failure {
    Core(CoreError),
    Input(String),
    Py(PyErr),
}

pub type Res<T> = Result<T, Failure>;

impl From<CoreError> for Failure {
    fn from(e: CoreError) -> Self {
        Failure::Core(e)
    }
}

impl From<PyErr> for Failure {
    fn from(e: PyErr) -> Self {
        Failure::Py(e)
    }
}

impl From<Failure> for PyErr {
    fn from(f: Failure) -> Self {
        match f {
            Failure::Py(e) => e,
            other => Python::attach(|py| build(py, other).unwrap_or_else(|e| e)),
        }
    }
}

/// An `InputError` naming the argument at fault.
pub fn input(msg: impl Into<String>) -> Failure {
    Failure::Input(msg.into())
}

/// The exception of `cmmpose.errors` for ``failure``, with its fields.
fn build(py: Python<'_>, failure: Failure) -> PyResult<PyErr> {
    let fields = PyDict::new(py);
    let (class, message) = match failure {
        Failure::Py(e) => return Ok(e),
        Failure::Input(m) => ("InputError", m),
        Failure::Core(e) => {
            let message = e.to_string();
            let class = match e {
                CoreError::InvalidMap { location, .. } => {
                    fields.set_item("what", location)?;
                    "MapError"
                }
                CoreError::PositionOutOfRange {
                    row,
                    axis,
                    value,
                    lo,
                    hi,
                } => {
                    fields.set_item("what", format!("{axis} scale reading"))?;
                    fields.set_item("value", value)?;
                    fields.set_item("allowed", (lo, hi))?;
                    fields.set_item("unit", "mm")?;
                    fields.set_item("row", row)?;
                    fields.set_item("remedy", "position_out_of_range")?;
                    "OutOfRangeError"
                }
                CoreError::TemperatureOutOfRange {
                    row, value, lo, hi, ..
                } => {
                    fields.set_item("what", "temperature")?;
                    fields.set_item("value", value)?;
                    fields.set_item("allowed", (lo, hi))?;
                    fields.set_item("unit", "C")?;
                    fields.set_item("row", row)?;
                    fields.set_item("option", "temperature")?;
                    fields.set_item("remedy", "temperature_out_of_range")?;
                    "OutOfRangeError"
                }
                CoreError::NonFinite { argument, row } => {
                    fields.set_item("what", &argument)?;
                    fields.set_item("option", argument)?;
                    fields.set_item("row", row)?;
                    fields.set_item("remedy", "nan_policy")?;
                    "InputError"
                }
                CoreError::NotFinite {
                    argument,
                    value,
                    unit,
                } => {
                    fields.set_item("what", &argument)?;
                    fields.set_item("option", argument)?;
                    fields.set_item("value", value)?;
                    fields.set_item("unit", unit)?;
                    fields.set_item("remedy", "nan_policy")?;
                    "InputError"
                }
                CoreError::Implausible {
                    argument,
                    row,
                    value,
                    quantity,
                } => {
                    let unit = quantity.unit();
                    fields.set_item("what", &argument)?;
                    fields.set_item("option", argument)?;
                    fields.set_item("row", row)?;
                    fields.set_item("value", value)?;
                    fields.set_item("unit", unit)?;
                    "InputError"
                }
                CoreError::InvalidArgument { argument, .. } => {
                    fields.set_item("what", &argument)?;
                    fields.set_item("option", argument)?;
                    "InputError"
                }
                CoreError::Degenerate(_) => "GeometryError",
            };
            (class, message)
        }
    };
    let cls = py.import("cmmpose.errors")?.getattr(class)?;
    let exc = cls.call(PyTuple::new(py, [message])?, Some(&fields))?;
    Ok(PyErr::from_value(exc))
}
