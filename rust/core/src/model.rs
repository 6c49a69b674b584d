//! Compensation with a diagnosis model's extra physical effects (issue 6):
//! the thesis kernel of [`crate::kernel`] plus the terms the diagnosis can
//! switch on, each the model-side counterpart of a simulator effect
//! (`cmmpose.sim.effects`, [`crate::truth::MachineEffects`]). With every
//! effect at zero this is the thesis compensation at the per-point machine
//! temperature (tested against [`crate::kernel`]).
//!
//! Per point, in order:
//! 1. scanner: undo incidence error (dv = a theta + b v theta) then scale
//!    errors (u (1 + lateral), v (1 + depth));
//! 2. latency: the scale reading is moved on by latency x scale velocity;
//! 3. carriage k's map at T + g (T_k - T) (g: per-axis temperature gain,
//!    T_k its scale thermocouples), squareness at T;
//! 4. machine terms added to the interpolated components: scale error
//!    (ppm x reading), roll (slope x reading), squareness offset and
//!    granite gradient x squareness coefficient;
//! 5. X = S + e + R . lever(pose of the point), as eqs. 10-13 and 26-35.
//!
//! Pose-level effects (alignment angles, mount offset) reach this kernel as
//! the per-pose digitizers.

use nalgebra::Vector3;
use rayon::prelude::*;

use crate::error::{CoreError, Result};
use crate::kernel::PointError;
use crate::map::{Carriage, Components};
use crate::pose::Digitizer;
use crate::thermal::ErrorMapSet;
use crate::units::ARCSEC_TO_RAD;

/// Points per parallel work item.
const CHUNK: usize = 4096;

/// Parameters of the kernel-level effects. All zero: the thesis model.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct EffectParams {
    /// Added to S_xy, S_yz, S_zx (arc-second).
    pub squareness: [f64; 3],
    /// Scale error of X, Y, Z (ppm of the reading).
    pub scale_ppm: [f64; 3],
    /// Roll eps_x(X), eps_y(Y), eps_z(Z) per metre of travel (arc-second/m).
    pub roll_slope: [f64; 3],
    /// Weight of each carriage's own scale temperature against the machine
    /// mean (1: per-axis maps; dimensionless).
    pub axis_temperature_gain: f64,
    /// Squareness change per kelvin of granite top-minus-bottom (arc-second/K).
    pub granite_squareness: [f64; 3],
    /// Time from the scale latch to the profile (s).
    pub latency: f64,
    /// Scanner scale errors (lateral u, depth v), dimensionless.
    pub scanner_scale: [f64; 2],
    /// Incidence error: mm per degree, and per degree per mm of depth.
    pub incidence: [f64; 2],
}

/// Per-point inputs, flat row-major; `None` where the model does not need them.
#[derive(Debug, Clone, Copy)]
pub struct ModelInputs<'a> {
    /// N x 2, mm.
    pub uv: &'a [f64],
    /// N x 3, mm.
    pub scales: &'a [f64],
    /// N: index into the digitizers.
    pub pose_index: &'a [u32],
    /// N: machine mean temperature (C).
    pub temperature: &'a [f64],
    /// N x 3: each carriage's scale temperature (C).
    pub axis_temperature: Option<&'a [f64]>,
    /// N: granite top minus bottom (K).
    pub gradient: Option<&'a [f64]>,
    /// N x 3: scale velocity (mm/s).
    pub velocity: Option<&'a [f64]>,
    /// N: incidence angle between surface normal and beam (degrees).
    pub incidence_deg: Option<&'a [f64]>,
}

impl ModelInputs<'_> {
    fn check(&self, n_poses: usize, out: &[f64]) -> Result<usize> {
        let n = self.pose_index.len();
        let lens: [(&str, Option<usize>, usize); 8] = [
            ("uv", Some(self.uv.len()), 2),
            ("scales", Some(self.scales.len()), 3),
            ("temperature", Some(self.temperature.len()), 1),
            (
                "axis_temperature",
                self.axis_temperature.map(<[f64]>::len),
                3,
            ),
            ("gradient", self.gradient.map(<[f64]>::len), 1),
            ("velocity", self.velocity.map(<[f64]>::len), 3),
            ("incidence", self.incidence_deg.map(<[f64]>::len), 1),
            ("out", Some(out.len()), 3),
        ];
        for (name, len, width) in lens {
            if let Some(len) = len {
                if len != width * n {
                    return Err(CoreError::invalid_argument(
                        name,
                        format!(
                            "has {} values, expected {} ({width} per point for {n} points)",
                            len,
                            width * n
                        ),
                    ));
                }
            }
        }
        if let Some(i) = self.pose_index.iter().position(|&p| p as usize >= n_poses) {
            return Err(CoreError::invalid_argument(
                "pose_index",
                format!(
                    "row {i}: pose {} but only {n_poses} poses given",
                    self.pose_index[i]
                ),
            ));
        }
        Ok(n)
    }

    /// The first non-finite argument of row `i`.
    fn non_finite(&self, i: usize) -> Option<&'static str> {
        let bad = |s: &[f64]| !s.iter().all(|x| x.is_finite());
        if bad(&self.uv[2 * i..2 * i + 2]) {
            return Some("uv");
        }
        if bad(&self.scales[3 * i..3 * i + 3]) {
            return Some("scales");
        }
        if !self.temperature[i].is_finite() {
            return Some("temperature");
        }
        if self
            .axis_temperature
            .is_some_and(|a| bad(&a[3 * i..3 * i + 3]))
        {
            return Some("axis_temperature");
        }
        if self.gradient.is_some_and(|g| !g[i].is_finite()) {
            return Some("gradient");
        }
        if self.velocity.is_some_and(|v| bad(&v[3 * i..3 * i + 3])) {
            return Some("velocity");
        }
        if self.incidence_deg.is_some_and(|a| !a[i].is_finite()) {
            return Some("incidence");
        }
        None
    }
}

/// Compensated machine coordinates (N x 3, mm) under a model with effects.
/// `clamp`: hold readings and temperatures outside the maps at the end
/// values instead of failing; returns how many points were clamped.
pub fn compensate_model(
    inputs: &ModelInputs,
    set: &ErrorMapSet,
    digitizers: &[Digitizer],
    fx: &EffectParams,
    clamp: bool,
    out: &mut [f64],
) -> Result<usize> {
    let n = inputs.check(digitizers.len(), out)?;
    let needs = |name: &str, used: bool, given: bool| -> Result<()> {
        if used && !given {
            return Err(CoreError::invalid_argument(
                name,
                "the model's effects need it but none was given",
            ));
        }
        Ok(())
    };
    needs(
        "axis_temperature",
        fx.axis_temperature_gain != 0.0,
        inputs.axis_temperature.is_some(),
    )?;
    needs(
        "gradient",
        fx.granite_squareness.iter().any(|&x| x != 0.0),
        inputs.gradient.is_some(),
    )?;
    needs("velocity", fx.latency != 0.0, inputs.velocity.is_some())?;
    needs(
        "incidence",
        fx.incidence.iter().any(|&x| x != 0.0),
        inputs.incidence_deg.is_some(),
    )?;
    let results: Vec<(usize, Option<CoreError>)> = out
        .par_chunks_mut(3 * CHUNK)
        .enumerate()
        .map(|(ci, block)| {
            let mut clamped = 0;
            for (j, slot) in block.chunks_exact_mut(3).enumerate() {
                let i = ci * CHUNK + j;
                if let Some(argument) = inputs.non_finite(i) {
                    return (clamped, Some(CoreError::NonFinite { argument, row: i }));
                }
                match point(inputs, i, set, digitizers, fx, clamp) {
                    Ok((x, moved)) => {
                        slot.copy_from_slice(x.as_slice());
                        clamped += moved as usize;
                    }
                    Err(e) => return (clamped, Some(e)),
                }
            }
            (clamped, None)
        })
        .collect();
    let mut clamped = 0;
    for (c, err) in results {
        if let Some(e) = err {
            return Err(e);
        }
        clamped += c;
    }
    debug_assert!(clamped <= n);
    Ok(clamped)
}

/// One point: the compensated position and whether anything was clamped.
#[inline]
fn point(
    inp: &ModelInputs,
    i: usize,
    set: &ErrorMapSet,
    digitizers: &[Digitizer],
    fx: &EffectParams,
    clamp: bool,
) -> Result<(Vector3<f64>, bool)> {
    // 1. Scanner: the reported v is (1 + d) v + a theta + b (1 + d) v theta.
    let (mut u, mut v) = (inp.uv[2 * i], inp.uv[2 * i + 1]);
    if let Some(theta) = inp.incidence_deg.map(|a| a[i]) {
        v = (v - fx.incidence[0] * theta) / (1.0 + fx.incidence[1] * theta);
    }
    u /= 1.0 + fx.scanner_scale[0];
    v /= 1.0 + fx.scanner_scale[1];
    // 2. Latency: the scales were latched `latency` before the profile.
    let mut s = [
        inp.scales[3 * i],
        inp.scales[3 * i + 1],
        inp.scales[3 * i + 2],
    ];
    if let Some(vel) = inp.velocity {
        for k in 0..3 {
            s[k] += fx.latency * vel[3 * i + k];
        }
    }
    // 3. Temperatures.
    let t = inp.temperature[i];
    let mut moved = false;
    let (lo, hi) = set.temperature_range();
    // A single map holds at every temperature (the thesis at one temperature).
    let single = set.maps().len() == 1;
    let in_range = |name: &'static str, value: f64, moved: &mut bool| -> Result<f64> {
        if single || (value >= lo && value <= hi) {
            Ok(value)
        } else if clamp {
            *moved = true;
            Ok(value.clamp(lo, hi))
        } else {
            Err(with_context(
                CoreError::TemperatureOutOfRange {
                    row: Some(i),
                    value,
                    lo,
                    hi,
                },
                name,
            ))
        }
    };
    let t_sq = in_range("temperature", t, &mut moved)?;
    let mut c: [Components; 3] = [[0.0; 6]; 3];
    for a in Carriage::ALL {
        let k = a as usize;
        let tk = match inp.axis_temperature {
            Some(at) if fx.axis_temperature_gain != 0.0 => {
                t + fx.axis_temperature_gain * (at[3 * i + k] - t)
            }
            _ => t,
        };
        let tk = in_range("axis_temperature", tk, &mut moved)?;
        let table = set.maps()[0].table(a);
        let (rlo, rhi) = table.range();
        let x = if s[k] >= rlo && s[k] <= rhi {
            s[k]
        } else if clamp {
            moved = true;
            s[k].clamp(rlo, rhi)
        } else {
            return Err(CoreError::PositionOutOfRange {
                row: i,
                axis: a.letter(),
                value: s[k],
                lo: rlo,
                hi: rhi,
            });
        };
        c[k] = if single {
            table.eval(x)
        } else {
            set.carriage_at(a, x, tk)
        }
        .expect("reading and temperature inside the maps");
        // 4. Machine terms the maps lack.
        c[k][k] += fx.scale_ppm[k] * 1e-6 * s[k];
        c[k][3 + k] += fx.roll_slope[k] * ARCSEC_TO_RAD * s[k] / 1000.0;
    }
    let sq0 = if single {
        set.maps()[0].squareness()
    } else {
        set.squareness_at(t_sq)
            .expect("temperature inside the maps")
    };
    let g = inp.gradient.map_or(0.0, |g| g[i]);
    let sq: [f64; 3] = std::array::from_fn(|k| {
        sq0[k] + (fx.squareness[k] + fx.granite_squareness[k] * g) * ARCSEC_TO_RAD
    });
    // 5. The thesis kernel.
    let pe = PointError::new(s, &c, sq);
    let d = &digitizers[inp.pose_index[i] as usize];
    Ok((Vector3::from(s) + pe.e + pe.rotate(&d.lever(u, v)), moved))
}

/// Name the argument in a temperature error (machine mean or per-axis).
#[cold]
fn with_context(e: CoreError, name: &'static str) -> CoreError {
    match e {
        CoreError::TemperatureOutOfRange { row, value, lo, hi } if name != "temperature" => {
            CoreError::invalid_argument(
                name,
                format!(
                    "row {}: {value} C is outside the maps' {lo}..{hi} C (pass out_of_range='clamp' to clamp)",
                    row.unwrap_or(0)
                ),
            )
        }
        other => other,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernel::{compensate_at_temperatures, Options};
    use crate::map::{CarriageTable, ErrorMap};
    use crate::pose::Pose;

    fn set() -> ErrorMapSet {
        // Two maps 10 K apart whose components differ (table units: um,
        // arc-second), so temperature matters.
        let mk = |t: f64, k: f64| {
            let tables = std::array::from_fn(|a| {
                let rows: Vec<[f64; 7]> = (0..=10)
                    .map(|j| {
                        let x = j as f64 * 100.0;
                        let f = (x / 100.0 + a as f64) * k;
                        [x, f, -f, 0.5 * f, 0.2 * f, -0.1 * f, 0.0]
                    })
                    .collect();
                CarriageTable::from_table_units(Carriage::ALL[a], &rows).unwrap()
            });
            ErrorMap::new(tables, [3.0 * k, -2.0 * k, 5.0 * k], Some(t)).unwrap()
        };
        ErrorMapSet::new(vec![mk(20.0, 1.0), mk(30.0, 2.0)]).unwrap()
    }

    struct Case {
        uv: Vec<f64>,
        scales: Vec<f64>,
        t: Vec<f64>,
        idx: Vec<u32>,
    }

    fn case(n: usize) -> Case {
        let f = |i: usize, a: f64| (i as f64 * a).sin();
        Case {
            uv: (0..2 * n).map(|i| 25.0 * f(i, 0.37)).collect(),
            scales: (0..3 * n).map(|i| 500.0 + 450.0 * f(i, 0.71)).collect(),
            t: (0..n).map(|i| 25.0 + 4.0 * f(i, 1.3)).collect(),
            idx: (0..n).map(|i| (i % 2) as u32).collect(),
        }
    }

    fn digitizers() -> Vec<Digitizer> {
        vec![
            Digitizer::new(&Pose::new(90.0, 90.0, 0.0).unwrap(), [1.0, 264.5, 129.6]).unwrap(),
            Digitizer::new(&Pose::new(180.0, 90.0, 30.0).unwrap(), [1.0, 264.5, 129.6]).unwrap(),
        ]
    }

    fn inputs(c: &Case) -> ModelInputs<'_> {
        ModelInputs {
            uv: &c.uv,
            scales: &c.scales,
            pose_index: &c.idx,
            temperature: &c.t,
            axis_temperature: None,
            gradient: None,
            velocity: None,
            incidence_deg: None,
        }
    }

    #[test]
    fn no_effects_is_the_thesis_kernel() {
        let (s, d, c) = (set(), digitizers(), case(10_001));
        let mut out = vec![0.0; 3 * 10_001];
        compensate_model(
            &inputs(&c),
            &s,
            &d,
            &EffectParams::default(),
            false,
            &mut out,
        )
        .unwrap();
        for (p, digitizer) in d.iter().enumerate() {
            let rows: Vec<usize> = (0..c.idx.len())
                .filter(|&i| c.idx[i] as usize == p)
                .collect();
            let pick = |v: &[f64], w: usize| -> Vec<f64> {
                rows.iter()
                    .flat_map(|&i| v[w * i..w * i + w].to_vec())
                    .collect()
            };
            let mut want = vec![0.0; 3 * rows.len()];
            compensate_at_temperatures(
                &pick(&c.uv, 2),
                &pick(&c.scales, 3),
                &pick(&c.t, 1),
                &s,
                digitizer,
                Options::default(),
                &mut want,
            )
            .unwrap();
            let got = pick(&out, 3);
            let worst = got
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(worst < 1e-9, "pose {p}: {worst} mm");
        }
    }

    #[test]
    fn axis_temperature_gain_one_equals_maps_at_each_carriage_temperature() {
        // All three carriages at the same offset temperature: gain 1 equals
        // the thesis kernel at that temperature (squareness still at the mean).
        let (s, d, c) = (set(), digitizers(), case(101));
        let axis: Vec<f64> = c.t.iter().flat_map(|&t| [t, t, t]).collect();
        let mut inp = inputs(&c);
        inp.axis_temperature = Some(&axis);
        let fx = EffectParams {
            axis_temperature_gain: 1.0,
            ..Default::default()
        };
        let (mut a, mut b) = (vec![0.0; 303], vec![0.0; 303]);
        compensate_model(&inp, &s, &d, &fx, false, &mut a).unwrap();
        compensate_model(&inputs(&c), &s, &d, &EffectParams::default(), false, &mut b).unwrap();
        assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-12));
    }

    #[test]
    fn scanner_terms_invert_the_simulated_errors() {
        // Reported (u', v') from true (u, v): u' = (1+l) u, v'' = (1+d) v,
        // v' = v'' + a theta + b v'' theta. The model recovers the truth.
        let (s, d, mut c) = (set(), digitizers(), case(50));
        let truth = c.uv.clone();
        let theta: Vec<f64> = (0..50).map(|i| (i as f64) * 1.3).collect();
        let (l, dd, a, b) = (3e-4, -7e-4, 2e-4, 3e-5);
        for (i, th) in theta.iter().enumerate() {
            c.uv[2 * i] *= 1.0 + l;
            let v2 = c.uv[2 * i + 1] * (1.0 + dd);
            c.uv[2 * i + 1] = v2 + a * th + b * v2 * th;
        }
        let mut inp = inputs(&c);
        inp.incidence_deg = Some(&theta);
        let fx = EffectParams {
            scanner_scale: [l, dd],
            incidence: [a, b],
            ..Default::default()
        };
        let mut got = vec![0.0; 150];
        compensate_model(&inp, &s, &d, &fx, false, &mut got).unwrap();
        let tc = Case {
            uv: truth,
            ..case(50)
        };
        let mut want = vec![0.0; 150];
        compensate_model(
            &inputs(&tc),
            &s,
            &d,
            &EffectParams::default(),
            false,
            &mut want,
        )
        .unwrap();
        let worst = got
            .iter()
            .zip(&want)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(worst < 1e-12, "{worst}");
    }

    #[test]
    fn latency_moves_the_reading_along_the_velocity() {
        let (s, d, c) = (set(), digitizers(), case(20));
        let vel: Vec<f64> = (0..20).flat_map(|_| [35.0, 0.0, 0.0]).collect();
        let mut inp = inputs(&c);
        inp.velocity = Some(&vel);
        let fx = EffectParams {
            latency: 0.01,
            ..Default::default()
        };
        let mut got = vec![0.0; 60];
        compensate_model(&inp, &s, &d, &fx, false, &mut got).unwrap();
        let mut moved = Case { ..case(20) };
        for i in 0..20 {
            moved.scales[3 * i] += 0.35;
        }
        let mut want = vec![0.0; 60];
        compensate_model(
            &inputs(&moved),
            &s,
            &d,
            &EffectParams::default(),
            false,
            &mut want,
        )
        .unwrap();
        assert!(got.iter().zip(&want).all(|(x, y)| (x - y).abs() < 1e-12));
    }

    #[test]
    fn bad_input_names_the_argument_and_row() {
        let (s, d, mut c) = (set(), digitizers(), case(10));
        let mut out = vec![0.0; 30];
        c.t[4] = 45.0;
        let e = compensate_model(
            &inputs(&c),
            &s,
            &d,
            &EffectParams::default(),
            false,
            &mut out,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("45") && e.contains('4'), "{e}");
        assert_eq!(
            compensate_model(
                &inputs(&c),
                &s,
                &d,
                &EffectParams::default(),
                true,
                &mut out
            )
            .unwrap(),
            1
        );
        c.t[4] = 25.0;
        c.uv[7] = f64::NAN;
        let e = compensate_model(
            &inputs(&c),
            &s,
            &d,
            &EffectParams::default(),
            false,
            &mut out,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("uv") && e.contains('3'), "{e}");
        c.uv[7] = 0.0;
        c.idx[2] = 9;
        let e = compensate_model(
            &inputs(&c),
            &s,
            &d,
            &EffectParams::default(),
            false,
            &mut out,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("pose_index") && e.contains("row 2"), "{e}");
        c.idx[2] = 0;
        let fx = EffectParams {
            latency: 0.01,
            ..Default::default()
        };
        let e = compensate_model(&inputs(&c), &s, &d, &fx, false, &mut out)
            .unwrap_err()
            .to_string();
        assert!(e.contains("velocity"), "{e}");
    }
}
