//! The simulator's physics across the boundary: the truth machine (the
//! effects' terms applied forward in exact kinematics), the scanner's
//! forward errors, and scanner profiles of artefact surfaces.

use cmmpose_core::artefact::Surface;
use cmmpose_core::effects;
use cmmpose_core::scanner::{self, ScanFrame, ScannerModel};
use cmmpose_core::truth;
use numpy::{
    PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::{effects as effects_from, rows, vector, NamedArrays};
use crate::errors::{input, Res};
use crate::maps::PyErrorMapSet;
use crate::pose::PyDigitizer;

/// True mount points and ram orientations of the truth machine at scale
/// readings `scales` (N, 3) mm. `inputs` maps names to per-reading arrays:
/// `temperature` (N,) C, the machine mean, and what the effects read (e.g.
/// `axis_temperature` (N, 3) C, `gradient` (N,) K). `effects` maps effect
/// names to their true parameter values. Returns a dict: `p` (N, 3) mm,
/// `r` (N, 3, 3), `mount_scale` (N,) (factor on the mount offset).
#[pyfunction]
#[pyo3(signature = (scales, maps, *, inputs, effects=None))]
fn true_frames<'py>(
    py: Python<'py>,
    scales: PyReadonlyArray2<'py, f64>,
    maps: PyRef<'py, PyErrorMapSet>,
    inputs: &Bound<'py, PyDict>,
    effects: Option<&Bound<'py, PyDict>>,
) -> Res<Bound<'py, PyDict>> {
    let s = rows("scales", &scales, 3)?;
    let named = NamedArrays::from_dict("inputs", Some(inputs))?;
    let columns = named.columns()?;
    let fx = effects_from(effects)?;
    let set = &maps.inner;
    let tf = py.detach(|| truth::true_frames(s, &columns, set, &fx))?;
    let n = s.len() / 3;
    let d = PyDict::new(py);
    d.set_item("p", PyArray1::from_vec(py, tf.p).reshape([n, 3])?)?;
    d.set_item("r", PyArray1::from_vec(py, tf.r).reshape([n, 3, 3])?)?;
    d.set_item("mount_scale", PyArray1::from_vec(py, tf.mount_scale))?;
    Ok(d)
}

/// What the scanner reports for true scan-plane points `uv` (N, 2) mm under
/// the scanner `effects`; `inputs` holds what they read (e.g. `incidence`,
/// degrees).
#[pyfunction]
#[pyo3(signature = (uv, *, inputs=None, effects=None))]
fn scanner_forward<'py>(
    py: Python<'py>,
    uv: PyReadonlyArray2<'py, f64>,
    inputs: Option<&Bound<'py, PyDict>>,
    effects: Option<&Bound<'py, PyDict>>,
) -> Res<Bound<'py, PyArray2<f64>>> {
    let uv_s = rows("uv", &uv, 2)?;
    let named = NamedArrays::from_dict("inputs", inputs)?;
    let columns = named.columns()?;
    let fx = effects_from(effects)?;
    let n = uv_s.len() / 2;
    let out = unsafe { PyArray2::<f64>::new(py, [n, 2], false) };
    let slice = unsafe { out.as_slice_mut() }.expect("fresh array is contiguous");
    py.detach(|| effects::scanner_forward(uv_s, &columns, &fx, slice))?;
    Ok(out)
}

fn surface(kind: &str, params: &[f64]) -> Res<Surface> {
    let v3 = |i: usize| [params[i], params[i + 1], params[i + 2]];
    let need = |k: usize| -> Res<()> {
        if params.len() == k {
            Ok(())
        } else {
            Err(input(format!(
                "surfaces: a {kind} takes {k} numbers, got {}",
                params.len()
            )))
        }
    };
    match kind {
        "sphere" => {
            need(4)?;
            Ok(Surface::sphere(v3(0), params[3])?)
        }
        "spheroid" => {
            need(8)?;
            Ok(Surface::spheroid(v3(0), v3(3), params[6], params[7])?)
        }
        "disc" => {
            need(7)?;
            Ok(Surface::disc(v3(0), v3(3), params[6])?)
        }
        other => Err(input(format!(
            "surfaces: unknown kind {other:?} (sphere, spheroid, disc)"
        ))),
    }
}

/// Simulated profiles. `frames` is what `true_frames` returns for M
/// profiles (`p` (M, 3) mm, `r` (M, 3, 3), `mount_scale` (M,)); `digitizer`
/// the true pose and mount offset; `surfaces` a list of (kind, numbers).
/// Returns a dict: `profile` (K,) index of each point's profile, `u`, `v`
/// (K,) mm, `cos_incidence` (K,), `xyz` (K, 3) true position, mm.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
#[pyo3(signature = (frames, digitizer, surfaces, *, u_range=(-30.0, 30.0), v_range=(-30.0, 30.0), points_per_profile=1024, max_incidence_deg=70.0))]
fn scan_profiles<'py>(
    py: Python<'py>,
    frames: &Bound<'py, PyDict>,
    digitizer: PyRef<'py, PyDigitizer>,
    surfaces: Vec<(String, Vec<f64>)>,
    u_range: (f64, f64),
    v_range: (f64, f64),
    points_per_profile: usize,
    max_incidence_deg: f64,
) -> Res<Bound<'py, PyDict>> {
    let item = |k: &str| -> Res<Bound<'py, PyAny>> {
        frames.get_item(k)?.ok_or_else(|| {
            input(format!(
                "frames: missing {k:?} (pass what true_frames returns)"
            ))
        })
    };
    let p: PyReadonlyArray2<'py, f64> = item("p")?
        .extract()
        .map_err(|_| input("frames['p']: expected a float64 (M, 3) array"))?;
    let r: PyReadonlyArray3<'py, f64> = item("r")?
        .extract()
        .map_err(|_| input("frames['r']: expected a float64 (M, 3, 3) array"))?;
    let ms: PyReadonlyArray1<'py, f64> = item("mount_scale")?
        .extract()
        .map_err(|_| input("frames['mount_scale']: expected a float64 (M,) array"))?;
    let ps = rows("frames['p']", &p, 3)?;
    let m = ps.len() / 3;
    if r.shape() != [m, 3, 3] {
        return Err(input(format!(
            "frames['r']: expected shape ({m}, 3, 3), got {:?}",
            r.shape()
        )));
    }
    let c_order = r.is_c_contiguous();
    let rs = r
        .as_slice()
        .ok()
        .filter(|_| c_order)
        .ok_or_else(|| input("frames['r']: array must be C-contiguous"))?;
    let ms = vector("frames['mount_scale']", &ms)?;
    if ms.len() != m {
        return Err(input(format!(
            "frames['mount_scale']: has {} values for {m} profiles",
            ms.len()
        )));
    }
    let e313 = digitizer.pose.matrix();
    let offset = digitizer.offset;
    let surfaces = surfaces
        .iter()
        .map(|(k, v)| surface(k, v))
        .collect::<Res<Vec<_>>>()?;
    let model = ScannerModel {
        u_range,
        v_range,
        points_per_profile,
        max_incidence_deg,
    };
    let (index, pts) = py.detach(|| {
        let frames: Vec<ScanFrame> = (0..m)
            .map(|i| {
                let pv = nalgebra::Vector3::new(ps[3 * i], ps[3 * i + 1], ps[3 * i + 2]);
                let rm = nalgebra::Matrix3::from_row_slice(&rs[9 * i..9 * i + 9]);
                let l1 = offset.map(|o| o * ms[i]);
                ScanFrame::new(pv, &rm, &e313, l1)
            })
            .collect();
        scanner::profiles(&frames, &surfaces, &model)
    })?;
    let d = PyDict::new(py);
    d.set_item(
        "profile",
        PyArray1::from_vec(py, index.into_iter().map(|k| k as i64).collect()),
    )?;
    d.set_item("u", PyArray1::from_iter(py, pts.iter().map(|q| q.u)))?;
    d.set_item("v", PyArray1::from_iter(py, pts.iter().map(|q| q.v)))?;
    d.set_item(
        "cos_incidence",
        PyArray1::from_iter(py, pts.iter().map(|q| q.cos_incidence)),
    )?;
    let xyz: Vec<f64> = pts.iter().flat_map(|q| q.xyz).collect();
    d.set_item("xyz", PyArray1::from_vec(py, xyz).reshape([pts.len(), 3])?)?;
    Ok(d)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(true_frames, m)?)?;
    m.add_function(wrap_pyfunction!(scanner_forward, m)?)?;
    m.add_function(wrap_pyfunction!(scan_profiles, m)?)?;
    Ok(())
}
