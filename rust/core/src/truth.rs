//! The truth machine: where the digitizer mount really is, given scale
//! readings, temperatures, error maps and the physical effects of
//! [`crate::effects`] (the same terms the compensation inverts). Exact
//! rigid-body kinematics with full rotation matrices; the compensation model
//! (eqs. 11-13, 29-31) must invert it to second order in the angles.
//!
//! The kinematic chain is the maps' stacking ([`crate::kinematics`]); for
//! the thesis's moving-bridge X-Y-Z CMM (X on the table carries the bridge
//! Y, which carries the ram Z):
//!
//! ```text
//! P = [D, 0, 0] + d(X) + R_X ( [0, E, 0] + d(Y) + R_Y ( [0, 0, F] + d(Z) ) ) + shear
//! shear = (-E S_xy - F S_zx, -F S_yz, 0)
//! R = R_X R_Y R_Z,     R_A = Rz(ez(A)) Ry(ey(A)) Rx(ex(A))
//! ```
//!
//! A carriage that carries the part (a moving table) turns and moves the
//! part instead: the mount point and orientation are given relative to the
//! part (see [`rigid_body`]).
//!
//! Squareness is the angle between the axes' mean lines of travel, measured in
//! the machine frame (as a ballbar or square measures it), so it enters as a
//! shear of the readings in that frame, exactly as in eqs. 11-12, and is not
//! turned by the carriage rotations. What compensation leaves is then of
//! second order in the carriage angles alone (angle x angle x lever, angle x
//! straightness), well under 0.05 um on the thesis machine.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use crate::effects::{Bound, Columns, Effects, MachineErrors, Temperatures};
use crate::error::{CoreError, Result};
use crate::kinematics::{Kinematics, Side};
use crate::map::{Carriage, Components};
use crate::thermal::ErrorMapSet;

#[inline]
fn rot_x(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c)
}

#[inline]
fn rot_y(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
}

#[inline]
fn rot_z(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

/// Rotation of one carriage from its three angles (rad), right-hand rule.
#[inline]
pub fn carriage_rotation(ex: f64, ey: f64, ez: f64) -> Matrix3<f64> {
    rot_z(ez) * rot_y(ey) * rot_x(ex)
}

/// Where the digitizer mount really is at each reading: the true mount
/// point P (mm), the ram orientation R (row-major) and the factor on the
/// mount offset l1 from the effects' mount stage.
#[derive(Debug, Clone, PartialEq)]
pub struct TrueFrames {
    /// N x 3, mm.
    pub p: Vec<f64>,
    /// N x 9, row-major.
    pub r: Vec<f64>,
    /// N, dimensionless (1: the calibrated offset).
    pub mount_scale: Vec<f64>,
}

/// True mount points, ram orientations and mount factors for each reading.
///
/// `scales` is N x 3 (mm). `columns` holds `temperature` (N, C: the
/// machine mean, at which squareness and, unless an effect says otherwise,
/// every carriage's map are taken) and the inputs of the `effects`, the same
/// terms the compensation inverts (e.g. `axis-temperature` with gain 1 and
/// the carriages' real temperatures in `axis_temperature`).
pub fn true_frames(
    scales: &[f64],
    columns: &Columns,
    set: &ErrorMapSet,
    effects: &Effects,
) -> Result<TrueFrames> {
    if scales.len() % 3 != 0 {
        return Err(CoreError::invalid_argument(
            "scales",
            format!("length {} is not a multiple of 3", scales.len()),
        ));
    }
    let n = scales.len() / 3;
    columns.check(n)?;
    let t = match columns.get("temperature") {
        Some(c) if c.width == 1 => c.values,
        _ => {
            return Err(CoreError::invalid_argument(
                "temperature",
                "required, one value per reading (C)",
            ))
        }
    };
    if let Some(i) = (0..n).find(|&i| !scales[3 * i..3 * i + 3].iter().all(|x| x.is_finite())) {
        return Err(CoreError::NonFinite {
            argument: "scales".into(),
            row: i,
        });
    }
    if let Some(name) = (0..n).find_map(|i| columns.non_finite(i)) {
        let row = (0..n)
            .find(|&i| columns.non_finite(i).is_some())
            .unwrap_or(0);
        return Err(CoreError::NonFinite {
            argument: name.to_string(),
            row,
        });
    }
    let bound = effects.bind(columns)?;
    let mut out = TrueFrames {
        p: vec![0.0; 3 * n],
        r: vec![0.0; 9 * n],
        mount_scale: vec![1.0; n],
    };
    let bad = out
        .p
        .par_chunks_mut(3)
        .zip(out.r.par_chunks_mut(9))
        .zip(out.mount_scale.par_iter_mut())
        .enumerate()
        .filter_map(|(i, ((p, r), m))| {
            let s = [scales[3 * i], scales[3 * i + 1], scales[3 * i + 2]];
            match frame(i, s, t[i], set, &bound) {
                Ok((pp, rr)) => {
                    p.copy_from_slice(pp.as_slice());
                    for row in 0..3 {
                        for col in 0..3 {
                            r[3 * row + col] = rr[(row, col)];
                        }
                    }
                    *m = bound.mount(i);
                    None
                }
                Err(e) => Some((i, e)),
            }
        })
        .min_by_key(|(i, _)| *i);
    match bad {
        Some((i, what)) => Err(CoreError::invalid_argument(
            "scales/temperatures",
            format!("row {i}: {what}"),
        )),
        None => Ok(out),
    }
}

fn frame(
    i: usize,
    s: [f64; 3],
    t: f64,
    set: &ErrorMapSet,
    bound: &Bound,
) -> std::result::Result<(Vector3<f64>, Matrix3<f64>), String> {
    let mut temps = Temperatures::uniform(t);
    bound.temperatures(i, &mut temps);
    let mut c: [Components; 3] = [[0.0; 6]; 3];
    for a in Carriage::ALL {
        let k = a as usize;
        let tk = temps.map[k];
        c[k] = set.carriage_at(a, s[k], tk).ok_or_else(|| {
            let (lo, hi) = set.maps()[0].table(a).range();
            let (tlo, thi) = set.temperature_range();
            if !(tk >= tlo && tk <= thi) {
                // The truth machine is the maps themselves: it does not extrapolate.
                format!("{} carriage temperature {tk} C is outside the maps' {tlo}..{thi} C (the truth machine does not extrapolate)", a.letter())
            } else {
                format!("{} reading {} mm is outside the {} map's {lo}..{hi} mm", a.letter(), s[k], a.letter())
            }
        })?;
    }
    let squareness = set.squareness_at(temps.squareness).ok_or_else(|| {
        format!(
            "squareness temperature {} C outside the maps",
            temps.squareness
        )
    })?;
    let mut e = MachineErrors {
        components: c,
        squareness,
    };
    bound.machine(i, s, &mut e);
    Ok(rigid_body(s, &e, set.kinematics()))
}

/// The mount point and ram orientation relative to the part, exactly, for
/// a machine stacked as `kinematics` with carriage errors `e` at readings
/// `s` (mm).
///
/// Probe chain, from the top down: P = s_A + d(A) + R_A P, R = R_A R.
/// Part chain (a table), from the base up: P = Q_B P + s_B + d(B), R = Q_B R,
/// with Q_B the rotation of the map's angles. Both are what a map measures
/// when one carriage moves and the others stay at zero: the travel plus
/// d(A), turned by eps(A). Then the squareness shear, in the machine frame.
fn rigid_body(
    s: [f64; 3],
    e: &MachineErrors,
    kinematics: Kinematics,
) -> (Vector3<f64>, Matrix3<f64>) {
    let (c, [s_xy, s_yz, s_zx]) = (e.components, e.squareness);
    let rot: [Matrix3<f64>; 3] =
        std::array::from_fn(|k| carriage_rotation(c[k][3], c[k][4], c[k][5]));
    let travel = |k: usize| {
        let mut v = Vector3::zeros();
        v[k] = s[k];
        v + Vector3::new(c[k][0], c[k][1], c[k][2])
    };
    let probe: Vec<usize> = kinematics.chain(Side::Probe).collect();
    let mut p = Vector3::zeros();
    for &a in probe.iter().rev() {
        p = travel(a) + rot[a] * p;
    }
    let mut r = Matrix3::identity();
    for &a in &probe {
        r *= rot[a];
    }
    for b in kinematics.chain(Side::Part) {
        p = rot[b] * p + travel(b);
        r = rot[b] * r;
    }
    let shear = Vector3::new(-s[1] * s_xy - s[2] * s_zx, -s[2] * s_yz, 0.0);
    (p + shear, r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernel::{compensate, Options};
    use crate::kinematics::Kinematics;
    use crate::map::{CarriageTable, ErrorMap};
    use crate::pose::{Digitizer, Pose};

    fn map(t: f64, k: f64) -> ErrorMap {
        let ranges = [(0.0, 900.0), (0.0, 550.0), (-500.0, 0.0)];
        let tables = std::array::from_fn(|a| {
            let (lo, hi) = ranges[a];
            let rows: Vec<[f64; 7]> = (0..=((hi - lo) / 25.0) as usize)
                .map(|i| {
                    let p = lo + 25.0 * i as f64;
                    let w = k * (p / 77.0 + a as f64).sin();
                    [
                        p,
                        80.0 * k * p / 900.0,
                        3.0 * w,
                        -2.0 * w,
                        2.0 * w,
                        4.0 * w,
                        -3.0 * w,
                    ]
                })
                .collect();
            CarriageTable::from_table_units(Carriage::ALL[a], &rows).unwrap()
        });
        ErrorMap::new(tables, [-173.0 * k, -19.0 * k, 21.0 * k], Some(t)).unwrap()
    }

    /// For every named stacking, compensating with the maps of that machine
    /// inverts its truth machine to < 1 nm (what is left is second order:
    /// angles of about 1 arc-second, (5e-6 rad)^2 x 1000 mm ~ 3e-8 mm); the
    /// thesis's arms on another machine leave a first-order error.
    /// `n` readings (N x 3) and scan-plane points (N x 2) across the volume.
    fn sweep(n: usize) -> (Vec<f64>, Vec<f64>) {
        let mut scales = Vec::new();
        let mut uv = Vec::new();
        for i in 0..n {
            let f = i as f64 / n as f64;
            scales.extend([900.0 * f, 550.0 * (1.0 - f), -500.0 * (f * 7.0).fract()]);
            uv.extend([
                -30.0 + 60.0 * (f * 13.0).fract(),
                110.0 + 60.0 * (f * 5.0).fract(),
            ]);
        }
        (scales, uv)
    }

    #[test]
    fn each_configuration_inverts_its_truth_machine() {
        let pose = Pose::new(90.0, 90.0, 30.0).unwrap();
        let d = Digitizer::new(&pose, [1.001, 264.505, 129.575]).unwrap();
        let n = 2000;
        let (scales, uv) = sweep(n);
        let temps = vec![22.0; n];
        let columns = Columns::new().with("temperature", 1, &temps);
        let residual = |set: &ErrorMapSet, model: &ErrorMap| {
            let tf = true_frames(&scales, &columns, set, &Effects::none()).unwrap();
            let mut comp = vec![0.0; 3 * n];
            compensate(&uv, &scales, model, &d, Options::default(), &mut comp).unwrap();
            (0..n)
                .map(|i| {
                    let rr = Matrix3::from_row_slice(&tf.r[9 * i..9 * i + 9]);
                    let truth = Vector3::new(tf.p[3 * i], tf.p[3 * i + 1], tf.p[3 * i + 2])
                        + rr * d.lever(uv[2 * i], uv[2 * i + 1]) * tf.mount_scale[i];
                    (truth - Vector3::new(comp[3 * i], comp[3 * i + 1], comp[3 * i + 2])).norm()
                })
                .fold(0.0, f64::max)
        };
        for (name, _) in Kinematics::names() {
            let k = Kinematics::named(name).unwrap();
            let set = ErrorMapSet::new(vec![map(20.0, 0.25), map(25.0, 0.3)])
                .unwrap()
                .with_kinematics(k);
            let model = set.at(22.0, false).unwrap();
            assert_eq!(model.kinematics(), k);
            let worst = residual(&set, &model);
            assert!(worst < 1e-6, "{name}: {worst:e} mm");
            if k.arms() != Kinematics::thesis().arms() {
                let wrong = residual(&set, &model.clone().with_kinematics(Kinematics::thesis()));
                assert!(
                    wrong > 1e-4,
                    "{name}: the thesis's arms leave only {wrong:e} mm"
                );
            }
        }
    }

    #[test]
    fn compensation_inverts_the_truth_machine_to_second_order() {
        let set = ErrorMapSet::new(vec![map(20.0, 1.0), map(25.0, 1.3)]).unwrap();
        let pose = Pose::new(90.0, 90.0, 30.0).unwrap();
        let offset = [1.001, 264.505, 129.575];
        let d = Digitizer::new(&pose, offset).unwrap();
        let n = 2000;
        let (scales, uv) = sweep(n);
        let t = 22.0;
        let temps = vec![t; n];
        let tf = true_frames(
            &scales,
            &Columns::new().with("temperature", 1, &temps),
            &set,
            &Effects::none(),
        )
        .unwrap();
        let (p, r) = (tf.p, tf.r);
        let blended = set.at(t, false).unwrap();
        let mut comp = vec![0.0; 3 * n];
        compensate(&uv, &scales, &blended, &d, Options::default(), &mut comp).unwrap();
        let mut worst: f64 = 0.0;
        for i in 0..n {
            let rr = Matrix3::from_row_slice(&r[9 * i..9 * i + 9]);
            let truth = Vector3::new(p[3 * i], p[3 * i + 1], p[3 * i + 2])
                + rr * d.lever(uv[2 * i], uv[2 * i + 1]);
            let got = Vector3::new(comp[3 * i], comp[3 * i + 1], comp[3 * i + 2]);
            worst = worst.max((truth - got).norm());
        }
        // angle x angle x lever ~ (3e-5 rad)^2 * 1000 mm ~ 1e-6 mm
        assert!(worst < 1e-5, "{worst:e} mm");
    }

    #[test]
    fn scale_error_and_roll_effects_act_alone() {
        let set = ErrorMapSet::new(vec![map(20.0, 0.0)]).unwrap();
        let s = [450.0, 275.0, -250.0];
        let b = Effects::new([("scale", vec![10.0, 0.0, 0.0])]).unwrap();
        let cols = Columns::new();
        let (p, r) = frame(0, s, 20.0, &set, &b.bind(&cols).unwrap()).unwrap();
        assert!((p - Vector3::from(s) - Vector3::new(450.0 * 10e-6, 0.0, 0.0)).norm() < 1e-12);
        assert_eq!(r, Matrix3::identity());
        let b = Effects::new([("roll", vec![0.0, 0.0, 5.0])]).unwrap();
        let (p, r) = frame(0, s, 20.0, &set, &b.bind(&cols).unwrap()).unwrap();
        assert!((p - Vector3::from(s)).norm() < 1e-12); // Z roll turns the ram, not P
        let angle = 5.0 * crate::units::ARCSEC_TO_RAD * -250.0 / 1000.0;
        assert!((r - rot_z(angle)).norm() < 1e-15);
    }

    #[test]
    fn missing_temperature_and_inputs_are_named() {
        let set = ErrorMapSet::new(vec![map(20.0, 0.0)]).unwrap();
        let s = [450.0, 275.0, -250.0];
        let e = true_frames(&s, &Columns::new(), &set, &Effects::none()).unwrap_err();
        assert!(e.to_string().contains("temperature"), "{e}");
        let t = [20.0];
        let fx = Effects::new([("granite-gradient", vec![0.0, 10.0, 10.0])]).unwrap();
        let e = true_frames(&s, &Columns::new().with("temperature", 1, &t), &set, &fx).unwrap_err();
        assert!(e.to_string().contains("gradient"), "{e}");
    }
}
