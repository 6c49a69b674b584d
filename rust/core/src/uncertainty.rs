//! Per-point uncertainty of compensated coordinates (docs/uncertainty.md,
//! "Per point"): the linear law of propagation (GUM eq. 10) through
//! X = S + e(S) + R(S) . E313 . ((u, v, 0) - l1), computed beside each
//! point in the kernel's pass.
//!
//! Every source is a standard uncertainty (k = 1) in the core's units (mm,
//! rad, K) and is taken as independent of the others. The covariance of a
//! point splits in two parts:
//!
//! - common to nearby points: the maps' components and squareness, the
//!   temperature through the maps' thermal sensitivity, the scanner's scale,
//!   the pose angles and the mount offset l1. A feature fitted to a patch of
//!   points keeps this part whole (it does not shrink with 1/sqrt(n));
//! - independent from point to point: the scanner's noise in u and v.
//!
//! The sensitivities are first order in the machine's errors (micrometres
//! and micro-radians): a rotation error w moves a point by w x p, with p the
//! point's arm from the carriage (the carriage's Abbe arm plus the lever).

use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use crate::effects::{Bound, Temperatures};
use crate::error::{CoreError, Result};
use crate::pose::{Digitizer, Pose};
use crate::source::{position_error_at, Options, PointError, Report, Source};

/// What the uncertainty output holds per point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Detail {
    /// u_x, u_y, u_z (mm): 3 values.
    #[default]
    Standard,
    /// u_x, u_y, u_z, then the covariance xx, yy, zz, xy, xz, yz (mm^2):
    /// 9 values.
    Covariance,
    /// As `Covariance`, then the part common to nearby points (the same six
    /// entries, mm^2): 15 values. The independent part is the difference.
    Split,
}

impl Detail {
    /// Values per point.
    pub fn width(self) -> usize {
        match self {
            Detail::Standard => 3,
            Detail::Covariance => 9,
            Detail::Split => 15,
        }
    }
}

/// Standard uncertainties of the maps' components, taken as independent
/// and as the same at every position along an axis.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MapUncertainty {
    /// [carriage X, Y, Z][dx, dy, dz], mm.
    pub position: [[f64; 3]; 3],
    /// [carriage X, Y, Z][ex, ey, ez], rad.
    pub rotation: [[f64; 3]; 3],
    /// S_xy, S_yz, S_zx, rad.
    pub squareness: [f64; 3],
    /// Relative uncertainty of each axis's positioning error (dx of X, dy
    /// of Y, dz of Z) from `reference` on (an interferometer's ppm; 1 is
    /// 100 %), added to `position`.
    pub positioning: [f64; 3],
    /// Where each axis's positioning error was referred to zero, mm.
    pub reference: [f64; 3],
}

/// One digitizer's uncertainties: its pose angles and mount offset (from
/// the calibration solvers) and its noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseUncertainty {
    /// E313 . cov(l1) . E313^T: the mount offset's covariance in machine
    /// axes, mm^2.
    offset: Matrix3<f64>,
    /// Covariance of (alpha, beta, gamma), rad^2.
    angles: Matrix3<f64>,
    /// The scanner's noise in machine axes (independent per point), mm^2.
    noise: Matrix3<f64>,
    /// beta's axis: Rz(alpha) . x (E313 = Rz(alpha) Rx(beta) Rz(gamma)).
    beta_axis: Vector3<f64>,
    u_dir: Vector3<f64>,
    v_dir: Vector3<f64>,
    /// The mount offset l1 (mm).
    l1: Vector3<f64>,
}

impl PoseUncertainty {
    /// From the pose and the mount offset the digitizer is built from,
    /// the offset's covariance (mm^2, in u, v, w), the angles' covariance
    /// (rad^2, alpha, beta, gamma) and the scanner's noise in u and v (mm).
    pub fn new(
        pose: &Pose,
        offset: [f64; 3],
        offset_covariance: [[f64; 3]; 3],
        angle_covariance: [[f64; 3]; 3],
        noise: [f64; 2],
    ) -> Result<Self> {
        let e = pose.matrix();
        let offset_cov = covariance("offset_covariance", offset_covariance)?;
        let angles = covariance("angle_covariance", angle_covariance)?;
        for (k, v) in noise.iter().enumerate() {
            standard(&format!("noise[{k}]"), *v)?;
        }
        let (u_dir, v_dir) = (e.column(0).into_owned(), e.column(1).into_owned());
        let noise = u_dir * u_dir.transpose() * noise[0].powi(2)
            + v_dir * v_dir.transpose() * noise[1].powi(2);
        let (sa, ca) = pose.alpha.to_radians().sin_cos();
        let _ = Digitizer::new(pose, offset)?;
        Ok(PoseUncertainty {
            offset: e * offset_cov * e.transpose(),
            angles,
            noise,
            beta_axis: Vector3::new(ca, sa, 0.0),
            u_dir,
            v_dir,
            l1: Vector3::from(offset),
        })
    }

    /// The independent part (the scanner's noise), mm^2.
    pub fn noise(&self) -> Matrix3<f64> {
        self.noise
    }
}

/// The sources of a point's uncertainty (all k = 1; zero switches one off).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Sources {
    pub map: MapUncertainty,
    /// The temperature's standard uncertainty, K, common to all points
    /// (a thermocouple's calibration); acts through the map set's thermal
    /// sensitivity (none with one map).
    pub temperature: f64,
    /// The scanner's relative scale uncertainty (1 = 100 %), common.
    pub scanner_scale: f64,
    /// One per digitizer, or empty: no pose, offset or noise uncertainty.
    pub poses: Vec<PoseUncertainty>,
}

impl Sources {
    /// Every value finite and non-negative; one pose entry per digitizer
    /// (or none).
    pub fn check(&self, digitizers: usize) -> Result<()> {
        for (k, axis) in ["x", "y", "z"].iter().enumerate() {
            for (j, c) in ["dx", "dy", "dz"].iter().enumerate() {
                standard(&format!("map.{axis}.{c}"), self.map.position[k][j])?;
            }
            for (j, c) in ["ex", "ey", "ez"].iter().enumerate() {
                standard(&format!("map.{axis}.{c}"), self.map.rotation[k][j])?;
            }
        }
        for (j, c) in ["xy", "yz", "zx"].iter().enumerate() {
            standard(&format!("map.squareness.{c}"), self.map.squareness[j])?;
        }
        for (k, axis) in ["x", "y", "z"].iter().enumerate() {
            standard(&format!("map.positioning.{axis}"), self.map.positioning[k])?;
            if !self.map.reference[k].is_finite() {
                return Err(CoreError::invalid_argument(
                    format!("uncertainty.map.reference.{axis}"),
                    format!("{} mm is not finite", self.map.reference[k]),
                ));
            }
        }
        standard("temperature", self.temperature)?;
        standard("scanner_scale", self.scanner_scale)?;
        if !self.poses.is_empty() && self.poses.len() != digitizers {
            return Err(CoreError::invalid_argument(
                "uncertainty.poses",
                format!(
                    "{} entries for {digitizers} digitizers (one per pose, or none)",
                    self.poses.len()
                ),
            ));
        }
        Ok(())
    }
}

fn standard(name: &str, v: f64) -> Result<()> {
    if !(v.is_finite() && v >= 0.0) {
        return Err(CoreError::invalid_argument(
            format!("uncertainty.{name}"),
            format!("{v} is not a standard uncertainty (finite, >= 0)"),
        ));
    }
    Ok(())
}

/// A covariance matrix: finite, symmetric, positive semi-definite (to the
/// rounding of its largest entry).
fn covariance(name: &str, m: [[f64; 3]; 3]) -> Result<Matrix3<f64>> {
    let bad = |why: String| CoreError::invalid_argument(format!("uncertainty.{name}"), why);
    let m = Matrix3::from_fn(|r, c| m[r][c]);
    if m.iter().any(|v| !v.is_finite()) {
        return Err(bad("has a value that is not finite".into()));
    }
    let scale = m.amax();
    if (m - m.transpose()).amax() > 1e-12 * scale {
        return Err(bad("is not symmetric".into()));
    }
    let low = SymmetricEigen::new(m).eigenvalues.min();
    if low < -1e-12 * scale {
        return Err(bad(format!(
            "is not positive semi-definite (eigenvalue {low:e})"
        )));
    }
    Ok(m)
}

/// A symmetric 3 x 3 as xx, yy, zz, xy, xz, yz.
type Sym = [f64; 6];

#[inline(always)]
fn add_outer(c: &mut Sym, w: f64, d: &Vector3<f64>) {
    c[0] += w * d.x * d.x;
    c[1] += w * d.y * d.y;
    c[2] += w * d.z * d.z;
    c[3] += w * d.x * d.y;
    c[4] += w * d.x * d.z;
    c[5] += w * d.y * d.z;
}

#[inline(always)]
fn add_matrix(c: &mut Sym, m: &Matrix3<f64>) {
    c[0] += m[(0, 0)];
    c[1] += m[(1, 1)];
    c[2] += m[(2, 2)];
    c[3] += m[(0, 1)];
    c[4] += m[(0, 2)];
    c[5] += m[(1, 2)];
}

/// The error state a row's uncertainty needs, shared by the rows of a
/// profile (same reading, temperature and pose).
#[derive(Clone, Copy)]
struct State {
    s: [f64; 3],
    pe: PointError,
    factor: f64,
    /// d e / dT (mm/K) and d w / dT (rad/K) of the maps' components.
    de_dt: Vector3<f64>,
    dw_dt: Vector3<f64>,
}

/// The propagation of one compensation call (built by the kernel beside
/// its per-row path, from the same inputs).
pub(crate) struct Propagation<'a, S: Source> {
    pub source: &'a S,
    pub bound: &'a Bound<'a>,
    pub arms: [[f64; 3]; 3],
    pub uv: &'a [f64],
    pub scales: &'a [f64],
    pub temperature: Option<&'a [f64]>,
    pub pose_index: Option<&'a [u32]>,
    pub digitizers: &'a [Digitizer],
    pub opts: Options,
    pub sources: &'a Sources,
    pub detail: Detail,
}

/// Temperature step of the thermal sensitivity (K): the map set is linear
/// in temperature between its maps, so any step inside a span is exact.
const DT: f64 = 0.01;

impl<S: Source> Propagation<'_, S> {
    /// The uncertainty rows of the points `xyz` (rows `start..`); a NaN
    /// point (a NaN input under the propagate policy) gets NaN.
    pub fn fill(&self, start: usize, xyz: &[f64], rows: &mut [f64]) -> Result<()> {
        let w = self.detail.width();
        let mut last: Option<(usize, State)> = None;
        for (j, row) in rows.chunks_exact_mut(w).enumerate() {
            let i = start + j;
            if !xyz[3 * j].is_finite() {
                row.fill(f64::NAN);
                continue;
            }
            let state = match last {
                Some((k, st)) if self.bound.is_empty() && self.same(k, i) => st,
                _ => self.state(i)?,
            };
            last = Some((i, state));
            self.write(i, &state, row);
        }
        Ok(())
    }

    /// Whether rows `k` and `i` share a reading, temperature and pose.
    #[inline(always)]
    fn same(&self, k: usize, i: usize) -> bool {
        (0..3).all(|j| self.scales[3 * k + j].to_bits() == self.scales[3 * i + j].to_bits())
            && self
                .temperature
                .is_none_or(|t| t[k].to_bits() == t[i].to_bits())
            && self.pose_index.is_none_or(|p| p[k] == p[i])
    }

    /// The per-row path's stages (the kernel's row function) up to the
    /// error state, and the maps' thermal sensitivity there.
    fn state(&self, i: usize) -> Result<State> {
        let mut s = [
            self.scales[3 * i],
            self.scales[3 * i + 1],
            self.scales[3 * i + 2],
        ];
        self.bound.reading(i, &mut s);
        let t = self.temperature.map_or(f64::NAN, |t| t[i]);
        let mut temps = Temperatures::uniform(t);
        self.bound.temperatures(i, &mut temps);
        let mut report = Report::default();
        let (components, squareness) =
            self.source
                .evaluate(i, s, &temps, &self.opts, &mut report)?;
        let mut e = crate::effects::MachineErrors {
            components,
            squareness,
        };
        self.bound.machine(i, s, &mut e);
        let pe = PointError::new(s, &e.components, e.squareness, &self.arms);
        let (de_dt, dw_dt) = if self.sources.temperature > 0.0 && t.is_finite() {
            self.thermal(s, &temps, &components, &squareness)
        } else {
            (Vector3::zeros(), Vector3::zeros())
        };
        Ok(State {
            s,
            pe,
            factor: self.bound.mount(i),
            de_dt,
            dw_dt,
        })
    }

    /// d e / dT and d w / dT of the maps at `temps` (one-sided: up, or
    /// down at the top of the maps' range; zero where neither is read).
    fn thermal(
        &self,
        s: [f64; 3],
        temps: &Temperatures,
        c0: &[crate::map::Components; 3],
        sq0: &[f64; 3],
    ) -> (Vector3<f64>, Vector3<f64>) {
        for step in [DT, -DT] {
            let shifted = Temperatures {
                map: temps.map.map(|t| t + step),
                squareness: temps.squareness + step,
                mean: temps.mean + step,
            };
            let mut report = Report::default();
            let Ok((c1, sq1)) = self.source.components(s, &shifted, &self.opts, &mut report) else {
                continue;
            };
            if report.clamped_temperature > 0 {
                continue;
            }
            let mut dc = [[0.0; 6]; 3];
            for k in 0..3 {
                for j in 0..6 {
                    dc[k][j] = (c1[k][j] - c0[k][j]) / step;
                }
            }
            let dsq = [0, 1, 2].map(|j| (sq1[j] - sq0[j]) / step);
            let de = Vector3::from(position_error_at(s, &dc, dsq, &self.arms));
            let dw = Vector3::new(
                dc[0][3] + dc[1][3] + dc[2][3],
                dc[0][4] + dc[1][4] + dc[2][4],
                dc[0][5] + dc[1][5] + dc[2][5],
            );
            return (de, dw);
        }
        (Vector3::zeros(), Vector3::zeros())
    }

    /// One row: the common covariance, the independent part, the output.
    #[inline(always)]
    fn write(&self, i: usize, st: &State, row: &mut [f64]) {
        let pose = self.pose_index.map_or(0, |p| p[i] as usize);
        let d = &self.digitizers[pose];
        let mut p = [self.uv[2 * i], self.uv[2 * i + 1]];
        self.bound.scanner_inverse(i, &mut p);
        let lever = st.pe.rotate(&d.lever_scaled(p[0], p[1], st.factor));
        let src = self.sources;
        let mut c: Sym = [0.0; 6];
        // Positions: each component along its own axis.
        for (j, cj) in c.iter_mut().take(3).enumerate() {
            *cj += src.map.position.iter().map(|p| p[j] * p[j]).sum::<f64>();
            let along = src.map.positioning[j] * (st.s[j] - src.map.reference[j]);
            *cj += along * along;
        }
        // Rotations: w x (arm_k + lever), arm_k the carriage's Abbe arm.
        for k in 0..3 {
            let [vx, vy, vz] = src.map.rotation[k].map(|u| u * u);
            if vx == 0.0 && vy == 0.0 && vz == 0.0 {
                continue;
            }
            let a = self.arms[k];
            let q = Vector3::new(a[0] * st.s[0], a[1] * st.s[1], a[2] * st.s[2]) + lever;
            c[0] += vy * q.z * q.z + vz * q.y * q.y;
            c[1] += vx * q.z * q.z + vz * q.x * q.x;
            c[2] += vx * q.y * q.y + vy * q.x * q.x;
            c[3] -= vz * q.x * q.y;
            c[4] -= vy * q.x * q.z;
            c[5] -= vx * q.y * q.z;
        }
        // Squareness: e_x -= E S_xy + F S_zx, e_y -= F S_yz.
        let [sxy, syz, szx] = src.map.squareness.map(|u| u * u);
        c[0] += sxy * st.s[1] * st.s[1] + szx * st.s[2] * st.s[2];
        c[1] += syz * st.s[2] * st.s[2];
        if src.temperature > 0.0 {
            let g = st.de_dt + st.dw_dt.cross(&lever);
            add_outer(&mut c, src.temperature.powi(2), &g);
        }
        if src.scanner_scale > 0.0 {
            let g = d.u_dir * p[0] + d.v_dir * p[1];
            add_outer(&mut c, src.scanner_scale.powi(2), &g);
        }
        let mut total = c;
        if let Some(pu) = src.poses.get(pose) {
            add_matrix(&mut c, &pu.offset);
            // d(E q)/d alpha = z x (E q); /d beta = n x (E q); /d gamma =
            // E (z x q), with q = (u, v, 0) - l1.
            let q = Vector3::new(p[0], p[1], 0.0) - pu.l1;
            let eq = pu.u_dir * q.x + pu.v_dir * q.y + pu.u_dir.cross(&pu.v_dir) * q.z;
            let j = Matrix3::from_columns(&[
                Vector3::z().cross(&eq),
                pu.beta_axis.cross(&eq),
                pu.v_dir * q.x - pu.u_dir * q.y,
            ]);
            add_matrix(&mut c, &(j * pu.angles * j.transpose()));
            total = c;
            add_matrix(&mut total, &pu.noise);
        }
        row[0] = total[0].max(0.0).sqrt();
        row[1] = total[1].max(0.0).sqrt();
        row[2] = total[2].max(0.0).sqrt();
        if row.len() >= 9 {
            row[3..9].copy_from_slice(&total);
        }
        if row.len() >= 15 {
            row[9..15].copy_from_slice(&c);
        }
    }
}

#[cfg(test)]
#[path = "uncertainty_tests.rs"]
mod tests;
