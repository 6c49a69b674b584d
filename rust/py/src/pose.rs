//! The digitizer pose across the boundary: a named `Digitizer` (Euler 3-1-3
//! angles and mount offset), E313 itself, and the pose of a normal.

use cmmpose_core::{Digitizer, Pose};
use numpy::PyArray2;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::Res;

/// The digitizer as the kernels take it: Euler 3-1-3 angles alpha, beta,
/// gamma (degrees) and the mount offset l1 = (U1, V1, W1) (mm).
#[pyclass(name = "Digitizer", module = "cmmpose._core", frozen)]
pub struct PyDigitizer {
    pub inner: Digitizer,
    pub pose: Pose,
    pub offset: [f64; 3],
}

#[pymethods]
impl PyDigitizer {
    #[new]
    #[pyo3(signature = (*, alpha, beta, gamma, offset))]
    fn new(alpha: f64, beta: f64, gamma: f64, offset: [f64; 3]) -> Res<Self> {
        let pose = Pose::new(alpha, beta, gamma)?;
        Ok(PyDigitizer {
            inner: Digitizer::new(&pose, offset)?,
            pose,
            offset,
        })
    }

    #[getter]
    fn alpha(&self) -> f64 {
        self.pose.alpha
    }
    #[getter]
    fn beta(&self) -> f64 {
        self.pose.beta
    }
    #[getter]
    fn gamma(&self) -> f64 {
        self.pose.gamma
    }
    /// (U1, V1, W1), mm.
    #[getter]
    fn offset(&self) -> [f64; 3] {
        self.offset
    }

    /// Pickling: rebuilt from its angles (degrees) and offset (mm).
    fn __getnewargs_ex__<'py>(&self, py: Python<'py>) -> PyResult<((), Bound<'py, PyDict>)> {
        let kwargs = PyDict::new(py);
        kwargs.set_item("alpha", self.pose.alpha)?;
        kwargs.set_item("beta", self.pose.beta)?;
        kwargs.set_item("gamma", self.pose.gamma)?;
        kwargs.set_item("offset", self.offset)?;
        Ok(((), kwargs))
    }

    fn __repr__(&self) -> String {
        format!(
            "Digitizer(alpha={}, beta={}, gamma={}, offset={:?})",
            self.pose.alpha, self.pose.beta, self.pose.gamma, self.offset
        )
    }
}

/// E313 of eq. 7 for angles in degrees.
#[pyfunction]
pub fn euler313<'py>(
    py: Python<'py>,
    alpha: f64,
    beta: f64,
    gamma: f64,
) -> Res<Bound<'py, PyArray2<f64>>> {
    let m = Pose::new(alpha, beta, gamma)?.matrix();
    let rows: Vec<Vec<f64>> = (0..3)
        .map(|r| (0..3).map(|c| m[(r, c)]).collect())
        .collect();
    PyArray2::from_vec2(py, &rows).map_err(|e| crate::errors::input(e.to_string()))
}

/// (alpha, beta, gamma) degrees of the pose whose w axis is `normal`.
#[pyfunction]
pub fn pose_from_normal(normal: [f64; 3], gamma: f64) -> Res<(f64, f64, f64)> {
    let p = Pose::from_normal(normal, gamma)?;
    Ok((p.alpha, p.beta, p.gamma))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyDigitizer>()?;
    m.add_function(wrap_pyfunction!(euler313, m)?)?;
    m.add_function(wrap_pyfunction!(pose_from_normal, m)?)?;
    Ok(())
}
