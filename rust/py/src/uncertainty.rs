//! Per-point uncertainty across the boundary: the compensation with each
//! point's standard uncertainty from the kernel's pass. The sources arrive
//! as one named structure (`cmmpose.point_uncertainty.KernelSources`),
//! already in the core's units (mm, rad, K, relative): the Python layer is
//! the one place that converts from um, arc-seconds and ppm.

use cmmpose_core::kernel;
use cmmpose_core::uncertainty::{Detail, MapUncertainty, PoseUncertainty, Sources};
use cmmpose_core::Digitizer;
use numpy::{PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::{effects, kernel_points, report_dict, MapPolicy, NamedArrays};
use crate::errors::{input, Res};
use crate::maps::map_source;
use crate::pose::PyDigitizer;

/// One digitizer's uncertainty (mm^2 in u, v, w; rad^2 of alpha, beta,
/// gamma; mm).
#[derive(FromPyObject)]
struct PoseSources {
    #[pyo3(attribute("offset_covariance"))]
    offset_covariance: [[f64; 3]; 3],
    #[pyo3(attribute("angle_covariance"))]
    angle_covariance: [[f64; 3]; 3],
    #[pyo3(attribute("noise"))]
    noise: [f64; 2],
}

/// The sources, in the core's units.
#[derive(FromPyObject)]
struct KernelSources {
    #[pyo3(attribute("map_position"))]
    map_position: [[f64; 3]; 3],
    #[pyo3(attribute("map_rotation"))]
    map_rotation: [[f64; 3]; 3],
    #[pyo3(attribute("map_squareness"))]
    map_squareness: [f64; 3],
    #[pyo3(attribute("map_positioning"))]
    map_positioning: [f64; 3],
    #[pyo3(attribute("map_reference"))]
    map_reference: [f64; 3],
    #[pyo3(attribute("temperature"))]
    temperature: f64,
    #[pyo3(attribute("scanner_scale"))]
    scanner_scale: f64,
    #[pyo3(attribute("poses"))]
    poses: Vec<Option<PoseSources>>,
}

fn detail(name: &str) -> Res<Detail> {
    match name {
        "standard" => Ok(Detail::Standard),
        "covariance" => Ok(Detail::Covariance),
        "split" => Ok(Detail::Split),
        other => Err(input(format!(
            "detail: {other:?} is not one of 'standard', 'covariance', 'split'"
        ))),
    }
}

type Output<'py> = (
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyDict>,
);

/// Compensated machine coordinates (N, 3) mm and each point's uncertainty
/// (N, 3 / 9 / 15 by `detail`: u_x, u_y, u_z mm; then the covariance xx,
/// yy, zz, xy, xz, yz mm^2; then its part common to nearby points), under
/// the model's maps and `effects` as `compensate_model` takes them.
#[pyfunction]
#[pyo3(signature = (uv, scales, maps, digitizers, policy, sources, *, pose_index=None, inputs=None, effects=None, nan_policy="raise", detail="standard"))]
#[allow(clippy::too_many_arguments)]
fn compensate_uncertainty<'py>(
    py: Python<'py>,
    uv: PyReadonlyArray2<'py, f64>,
    scales: PyReadonlyArray2<'py, f64>,
    maps: &Bound<'py, PyAny>,
    digitizers: Vec<PyRef<'py, PyDigitizer>>,
    policy: MapPolicy,
    sources: KernelSources,
    pose_index: Option<PyReadonlyArray1<'py, u32>>,
    inputs: Option<&Bound<'py, PyDict>>,
    effects: Option<&Bound<'py, PyDict>>,
    nan_policy: &str,
    detail: &str,
) -> Res<Output<'py>> {
    let opts = policy.options(nan_policy)?;
    let detail = self::detail(detail)?;
    let source = map_source(maps)?;
    let fx = self::effects(effects)?;
    let named = NamedArrays::from_dict("inputs", inputs)?;
    let mut poses = Vec::new();
    if sources.poses.iter().any(Option::is_some) {
        if sources.poses.len() != digitizers.len() {
            return Err(input(format!(
                "sources.poses: {} entries for {} digitizers",
                sources.poses.len(),
                digitizers.len()
            )));
        }
        for (d, p) in digitizers.iter().zip(&sources.poses) {
            let zero = [[0.0; 3]; 3];
            let (oc, ac, noise) = p.as_ref().map_or((zero, zero, [0.0; 2]), |p| {
                (p.offset_covariance, p.angle_covariance, p.noise)
            });
            poses.push(PoseUncertainty::new(&d.pose, d.offset, oc, ac, noise)?);
        }
    }
    let sources = Sources {
        map: MapUncertainty {
            position: sources.map_position,
            rotation: sources.map_rotation,
            squareness: sources.map_squareness,
            positioning: sources.map_positioning,
            reference: sources.map_reference,
        },
        temperature: sources.temperature,
        scanner_scale: sources.scanner_scale,
        poses,
    };
    let digitizers: Vec<Digitizer> = digitizers.iter().map(|d| d.inner).collect();
    let points = kernel_points(&uv, &scales, pose_index.as_ref(), &named)?;
    let n = points.scales.len() / 3;
    // Uninitialised is fine: the kernel writes every element or fails.
    let xyz = unsafe { PyArray2::<f64>::new(py, [n, 3], false) };
    let unc = unsafe { PyArray2::<f64>::new(py, [n, detail.width()], false) };
    let out = unsafe { xyz.as_slice_mut() }.expect("fresh array is contiguous");
    let u = unsafe { unc.as_slice_mut() }.expect("fresh array is contiguous");
    let report = py.detach(|| {
        kernel::compensate_points_with_uncertainty(
            &points,
            source,
            &digitizers,
            &fx,
            opts,
            &sources,
            detail,
            out,
            u,
        )
    })?;
    Ok((xyz, unc, report_dict(py, &report)?))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(compensate_uncertainty, m)?)?;
    Ok(())
}
