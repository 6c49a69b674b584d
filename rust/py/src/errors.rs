//! The exception hierarchy and the one conversion from core errors: each
//! `CoreError` variant maps to one Python exception (polars' shape).

use cmmpose_core::CoreError;
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

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

/// A failure on its way to Python: a core error already mapped, or a
/// Python error. `?` converts both; pyo3 turns it into the exception.
pub struct Failure(PyErr);

pub type Res<T> = Result<T, Failure>;

/// The choices after an out-of-range error, in the Python API's words (the
/// CLI rewrites this one sentence into its flags: cmmpose.cli).
pub const TEMPERATURE_CHOICES: &str = " (choices: out_of_range='clamp' holds it at the edge, \
'extrapolate' extends the maps linearly, or a wider temperature_tolerance in K)";
pub const POSITION_CHOICES: &str = " (choices: out_of_range='clamp' holds it at the table's end)";

impl From<CoreError> for Failure {
    fn from(e: CoreError) -> Self {
        let msg = e.to_string();
        Failure(match e {
            CoreError::InvalidMap { .. } => MapError::new_err(msg),
            CoreError::PositionOutOfRange { .. } => {
                OutOfRangeError::new_err(msg + POSITION_CHOICES)
            }
            CoreError::TemperatureOutOfRange { .. } => {
                OutOfRangeError::new_err(msg + TEMPERATURE_CHOICES)
            }
            CoreError::NonFinite { .. } | CoreError::InvalidArgument { .. } => {
                InputError::new_err(msg)
            }
            CoreError::Degenerate(_) => GeometryError::new_err(msg),
        })
    }
}

impl From<PyErr> for Failure {
    fn from(e: PyErr) -> Self {
        Failure(e)
    }
}

impl From<Failure> for PyErr {
    fn from(f: Failure) -> Self {
        f.0
    }
}

/// An `InputError` naming the argument at fault.
pub fn input(msg: impl Into<String>) -> Failure {
    Failure(InputError::new_err(msg.into()))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("Error", py.get_type::<Error>())?;
    m.add("MapError", py.get_type::<MapError>())?;
    m.add("OutOfRangeError", py.get_type::<OutOfRangeError>())?;
    m.add("InputError", py.get_type::<InputError>())?;
    m.add("GeometryError", py.get_type::<GeometryError>())?;
    Ok(())
}
