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

/// A covariance quadratic in the point's (u, v): every sensitivity is
/// affine in (u, v) (the lever is), so per profile the common part is
/// C(u, v) = A0 + u A1 + v A2 + u^2 A3 + u v A4 + v^2 A5, and each point
/// costs a few multiply-adds whatever the number of sources.
#[derive(Clone, Copy, Default)]
struct Quadratic([Sym; 6]);

impl Quadratic {
    /// Add w g g^T with g = a + u b + v c.
    #[inline(always)]
    fn add(&mut self, w: f64, a: &Vector3<f64>, b: &Vector3<f64>, c: &Vector3<f64>) {
        if w == 0.0 {
            return;
        }
        let outer = |p: &Vector3<f64>, q: &Vector3<f64>| -> Sym {
            [
                w * p.x * q.x,
                w * p.y * q.y,
                w * p.z * q.z,
                w * p.x * q.y,
                w * p.x * q.z,
                w * p.y * q.z,
            ]
        };
        let both = |p: &Vector3<f64>, q: &Vector3<f64>| -> Sym {
            [
                2.0 * w * p.x * q.x,
                2.0 * w * p.y * q.y,
                2.0 * w * p.z * q.z,
                w * (p.x * q.y + q.x * p.y),
                w * (p.x * q.z + q.x * p.z),
                w * (p.y * q.z + q.y * p.z),
            ]
        };
        for (k, term) in [
            outer(a, a),
            both(a, b),
            both(a, c),
            outer(b, b),
            both(b, c),
            outer(c, c),
        ]
        .iter()
        .enumerate()
        {
            for (x, t) in self.0[k].iter_mut().zip(term) {
                *x += t;
            }
        }
    }

    /// Add J S J^T with J = J0 + u Ju + v Jv (3 x 3) and S symmetric.
    #[inline(always)]
    fn add_matrix(
        &mut self,
        j0: &Matrix3<f64>,
        ju: &Matrix3<f64>,
        jv: &Matrix3<f64>,
        s: &Matrix3<f64>,
    ) {
        let sym = |m: Matrix3<f64>| -> Sym {
            [
                m[(0, 0)],
                m[(1, 1)],
                m[(2, 2)],
                m[(0, 1)],
                m[(0, 2)],
                m[(1, 2)],
            ]
        };
        let cross =
            |p: &Matrix3<f64>, q: &Matrix3<f64>| p * s * q.transpose() + q * s * p.transpose();
        let terms = [
            sym(j0 * s * j0.transpose()),
            sym(cross(j0, ju)),
            sym(cross(j0, jv)),
            sym(ju * s * ju.transpose()),
            sym(cross(ju, jv)),
            sym(jv * s * jv.transpose()),
        ];
        for (k, term) in terms.iter().enumerate() {
            for (x, t) in self.0[k].iter_mut().zip(term) {
                *x += t;
            }
        }
    }

    /// The diagonal of C(u, v): all a standard uncertainty needs.
    #[inline(always)]
    fn diagonal_at(&self, u: f64, v: f64) -> [f64; 3] {
        let [a0, a1, a2, a3, a4, a5] = &self.0;
        std::array::from_fn(|k| {
            a0[k] + u * (a1[k] + u * a3[k] + v * a4[k]) + v * (a2[k] + v * a5[k])
        })
    }

    /// C(u, v).
    #[inline(always)]
    fn at(&self, u: f64, v: f64) -> Sym {
        let [a0, a1, a2, a3, a4, a5] = &self.0;
        std::array::from_fn(|k| {
            a0[k] + u * (a1[k] + u * a3[k] + v * a4[k]) + v * (a2[k] + v * a5[k])
        })
    }
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
        let mut last: Option<(usize, Quadratic, Sym)> = None;
        for (j, row) in rows.chunks_exact_mut(w).enumerate() {
            let i = start + j;
            if !xyz[3 * j].is_finite() {
                row.fill(f64::NAN);
                continue;
            }
            let (quad, noise) = match last {
                Some((k, q, n)) if self.bound.is_empty() && self.same(k, i) => (q, n),
                _ => self.quadratic(i)?,
            };
            last = Some((i, quad, noise));
            let mut p = [self.uv[2 * i], self.uv[2 * i + 1]];
            self.bound.scanner_inverse(i, &mut p);
            if w == 3 {
                // The same sums as `at` for the diagonal, so the same bits as the other details.
                let d = quad.diagonal_at(p[0], p[1]);
                for k in 0..3 {
                    row[k] = (d[k] + noise[k]).max(0.0).sqrt();
                }
                continue;
            }
            let common = quad.at(p[0], p[1]);
            let total: Sym = std::array::from_fn(|k| common[k] + noise[k]);
            row[0] = total[0].max(0.0).sqrt();
            row[1] = total[1].max(0.0).sqrt();
            row[2] = total[2].max(0.0).sqrt();
            if w >= 9 {
                row[3..9].copy_from_slice(&total);
            }
            if w >= 15 {
                row[9..15].copy_from_slice(&common);
            }
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

    /// Row `i`'s state as a covariance quadratic in (u, v) (the common
    /// part) and its pose's independent part (the noise).
    fn quadratic(&self, i: usize) -> Result<(Quadratic, Sym)> {
        let st = self.state(i)?;
        let pose = self.pose_index.map_or(0, |p| p[i] as usize);
        let d = &self.digitizers[pose];
        let src = self.sources;
        let mut q = Quadratic::default();
        let zero = Vector3::zeros();
        // The lever L = R (f origin + u u_dir + v v_dir), affine in (u, v).
        let l0 = st.pe.rotate(&(d.origin * st.factor));
        let (lu, lv) = (st.pe.rotate(&d.u_dir), st.pe.rotate(&d.v_dir));
        // Positions: each component along its own axis; positioning grows
        // with the distance from its reference.
        for j in 0..3 {
            let along = src.map.positioning[j] * (st.s[j] - src.map.reference[j]);
            let var = src.map.position.iter().map(|p| p[j] * p[j]).sum::<f64>() + along * along;
            q.0[0][j] += var;
        }
        // Rotations: w x (arm_k + L), arm_k the carriage's Abbe arm.
        for k in 0..3 {
            let a = self.arms[k];
            let arm = Vector3::new(a[0] * st.s[0], a[1] * st.s[1], a[2] * st.s[2]) + l0;
            for (axis, u) in src.map.rotation[k].iter().enumerate() {
                let e = Vector3::ith(axis, 1.0);
                q.add(u * u, &e.cross(&arm), &e.cross(&lu), &e.cross(&lv));
            }
        }
        // Squareness: e_x -= E S_xy + F S_zx, e_y -= F S_yz.
        let [sxy, syz, szx] = src.map.squareness.map(|u| u * u);
        q.0[0][0] += sxy * st.s[1] * st.s[1] + szx * st.s[2] * st.s[2];
        q.0[0][1] += syz * st.s[2] * st.s[2];
        if src.temperature > 0.0 {
            let g0 = st.de_dt + st.dw_dt.cross(&l0);
            let (gu, gv) = (st.dw_dt.cross(&lu), st.dw_dt.cross(&lv));
            q.add(src.temperature * src.temperature, &g0, &gu, &gv);
        }
        q.add(
            src.scanner_scale * src.scanner_scale,
            &zero,
            &d.u_dir,
            &d.v_dir,
        );
        let mut noise = [0.0; 6];
        if let Some(pu) = src.poses.get(pose) {
            for (k, x) in [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
                .iter()
                .enumerate()
            {
                q.0[0][k] += pu.offset[*x];
                noise[k] = pu.noise[*x];
            }
            // d(E q)/d alpha = z x (E q); /d beta = n x (E q); /d gamma =
            // E (z x q); q = (u, v, 0) - l1, so E q = E0 + u u_dir + v v_dir.
            let w_dir = pu.u_dir.cross(&pu.v_dir);
            let eq0 = -(pu.u_dir * pu.l1.x + pu.v_dir * pu.l1.y + w_dir * pu.l1.z);
            let z = Vector3::z();
            let n = pu.beta_axis;
            let j0 = Matrix3::from_columns(&[
                z.cross(&eq0),
                n.cross(&eq0),
                pu.u_dir * pu.l1.y - pu.v_dir * pu.l1.x,
            ]);
            let ju = Matrix3::from_columns(&[z.cross(&pu.u_dir), n.cross(&pu.u_dir), pu.v_dir]);
            let jv = Matrix3::from_columns(&[z.cross(&pu.v_dir), n.cross(&pu.v_dir), -pu.u_dir]);
            q.add_matrix(&j0, &ju, &jv, &pu.angles);
        }
        Ok((q, noise))
    }
}

#[cfg(test)]
#[path = "uncertainty_tests.rs"]
mod tests;
