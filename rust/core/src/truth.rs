//! The truth machine: where the digitizer mount really is, given scale
//! readings, temperatures, error maps and extra physical effects. Exact
//! rigid-body kinematics with full rotation matrices; the compensation model
//! (eqs. 11-13, 29-31) must invert it to second order in the angles.
//!
//! Kinematic chain of a moving-bridge X-Y-Z CMM (X on the table carries the
//! bridge Y, which carries the ram Z):
//!
//! ```text
//! P = [D, 0, 0] + d(X) + R_X ( [0, E, 0] + d(Y) + R_Y ( [0, 0, F] + d(Z) ) ) + shear
//! shear = (-E S_xy - F S_zx, -F S_yz, 0)
//! R = R_X R_Y R_Z,     R_A = Rz(ez(A)) Ry(ey(A)) Rx(ex(A))
//! ```
//!
//! Squareness is the angle between the axes' mean lines of travel, measured in
//! the machine frame (as a ballbar or square measures it), so it enters as a
//! shear of the readings in that frame, exactly as in eqs. 11-12, and is not
//! turned by the carriage rotations. What compensation leaves is then of
//! second order in the carriage angles alone (angle x angle x lever, angle x
//! straightness), well under 0.05 um on the thesis machine.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use crate::error::{CoreError, Result};
use crate::map::{Carriage, Components};
use crate::thermal::ErrorMapSet;
use crate::units::ARCSEC_TO_RAD;

/// Machine effects beyond the maps. All zero by default.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MachineEffects {
    /// Added to S_xy, S_yz, S_zx (arc-second): a squareness the map has wrong.
    pub squareness_offset: [f64; 3],
    /// Scale error of X, Y, Z (ppm): the linear error grows by ppm * 1e-6 * reading.
    pub scale_error_ppm: [f64; 3],
    /// Unmeasured roll eps_x(X), eps_y(Y), eps_z(Z), linear in the reading
    /// (arc-second per metre of travel from home).
    pub roll_slope: [f64; 3],
    /// Squareness change per kelvin of granite top-minus-bottom gradient
    /// (arc-second/K) for S_xy, S_yz, S_zx.
    pub granite_squareness: [f64; 3],
}

/// Temperatures at one instant, degrees C: the map temperature of each
/// carriage (its scale thermocouples), the temperature at which squareness is
/// taken (the machine mean in the thesis), and the granite top-minus-bottom
/// difference (K).
pub const STATE_WIDTH: usize = 5;

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

/// True mount point P (mm) and ram orientation R for each reading.
///
/// `scales` is N x 3 (mm), `states` N x [`STATE_WIDTH`] (see there).
/// Outputs: `p_out` N x 3, `r_out` N x 9 row-major.
pub fn true_frames(
    scales: &[f64],
    states: &[f64],
    set: &ErrorMapSet,
    fx: &MachineEffects,
    p_out: &mut [f64],
    r_out: &mut [f64],
) -> Result<()> {
    let n = scales.len() / 3;
    if scales.len() != 3 * n
        || states.len() != STATE_WIDTH * n
        || p_out.len() != 3 * n
        || r_out.len() != 9 * n
    {
        return Err(CoreError::invalid_argument(
            "true_frames",
            format!("inconsistent lengths for {n} points"),
        ));
    }
    let bad = p_out
        .par_chunks_mut(3)
        .zip(r_out.par_chunks_mut(9))
        .enumerate()
        .filter_map(|(i, (p, r))| {
            let s = &scales[3 * i..3 * i + 3];
            let st = &states[STATE_WIDTH * i..STATE_WIDTH * (i + 1)];
            match frame(s, st, set, fx) {
                Ok((pp, rr)) => {
                    p.copy_from_slice(pp.as_slice());
                    for row in 0..3 {
                        for col in 0..3 {
                            r[3 * row + col] = rr[(row, col)];
                        }
                    }
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
        None => Ok(()),
    }
}

fn frame(
    s: &[f64],
    st: &[f64],
    set: &ErrorMapSet,
    fx: &MachineEffects,
) -> std::result::Result<(Vector3<f64>, Matrix3<f64>), String> {
    let mut c: [Components; 3] = [[0.0; 6]; 3];
    for a in Carriage::ALL {
        let k = a as usize;
        c[k] = set.carriage_at(a, s[k], st[k]).ok_or_else(|| {
            let (lo, hi) = set.maps()[0].table(a).range();
            let (tlo, thi) = set.temperature_range();
            format!("{} reading {} mm or temperature {} C outside the maps ({lo}..{hi} mm, {tlo}..{thi} C)", a.letter(), s[k], st[k])
        })?;
        c[k][k] += fx.scale_error_ppm[k] * 1e-6 * s[k];
        c[k][3 + k] += fx.roll_slope[k] * ARCSEC_TO_RAD * s[k] / 1000.0;
    }
    let sq = set
        .squareness_at(st[3])
        .ok_or_else(|| format!("squareness temperature {} C outside the maps", st[3]))?;
    let sq: [f64; 3] = std::array::from_fn(|k| {
        sq[k] + (fx.squareness_offset[k] + fx.granite_squareness[k] * st[4]) * ARCSEC_TO_RAD
    });
    let [s_xy, s_yz, s_zx] = sq;
    let r: [Matrix3<f64>; 3] =
        std::array::from_fn(|k| carriage_rotation(c[k][3], c[k][4], c[k][5]));
    let d = |k: usize| Vector3::new(c[k][0], c[k][1], c[k][2]);
    let shear = Vector3::new(-s[1] * s_xy - s[2] * s_zx, -s[2] * s_yz, 0.0);
    let p = Vector3::new(s[0], 0.0, 0.0)
        + d(0)
        + r[0]
            * (Vector3::new(0.0, s[1], 0.0) + d(1) + r[1] * (Vector3::new(0.0, 0.0, s[2]) + d(2)))
        + shear;
    Ok((p, r[0] * r[1] * r[2]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernel::{compensate, Options};
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

    #[test]
    fn compensation_inverts_the_truth_machine_to_second_order() {
        let set = ErrorMapSet::new(vec![map(20.0, 1.0), map(25.0, 1.3)]).unwrap();
        let pose = Pose::new(90.0, 90.0, 30.0).unwrap();
        let offset = [1.001, 264.505, 129.575];
        let d = Digitizer::new(&pose, offset).unwrap();
        let n = 2000;
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
        let t = 22.0;
        let states: Vec<f64> = (0..n).flat_map(|_| [t, t, t, t, 0.0]).collect();
        let mut p = vec![0.0; 3 * n];
        let mut r = vec![0.0; 9 * n];
        true_frames(
            &scales,
            &states,
            &set,
            &MachineEffects::default(),
            &mut p,
            &mut r,
        )
        .unwrap();
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
        let st = [20.0, 20.0, 20.0, 20.0, 0.0];
        let fx = MachineEffects {
            scale_error_ppm: [10.0, 0.0, 0.0],
            ..Default::default()
        };
        let (p, r) = frame(&s, &st, &set, &fx).unwrap();
        assert!((p - Vector3::from(s) - Vector3::new(450.0 * 10e-6, 0.0, 0.0)).norm() < 1e-12);
        assert_eq!(r, Matrix3::identity());
        let fx = MachineEffects {
            roll_slope: [0.0, 0.0, 5.0],
            ..Default::default()
        };
        let (p, r) = frame(&s, &st, &set, &fx).unwrap();
        assert!((p - Vector3::from(s)).norm() < 1e-12); // Z roll turns the ram, not P
        let angle = 5.0 * ARCSEC_TO_RAD * -250.0 / 1000.0;
        assert!((r - rot_z(angle)).norm() < 1e-15);
    }
}
