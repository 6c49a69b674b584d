//! Digitizer pose: Euler 3-1-3 angles (thesis eq. 7) and the mount offset l1.

use nalgebra::{Matrix3, Vector3};

use crate::error::{CoreError, Result};

/// Orientation of the scan plane: alpha about Z, beta about the new X',
/// gamma about the new Z'' (= W). Angles in degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub alpha: f64,
    pub beta: f64,
    pub gamma: f64,
}

impl Pose {
    pub fn new(alpha: f64, beta: f64, gamma: f64) -> Result<Self> {
        for (name, v) in [("alpha", alpha), ("beta", beta), ("gamma", gamma)] {
            if !v.is_finite() {
                return Err(CoreError::invalid_argument(
                    format!("pose.{name}"),
                    format!("{v} deg is not finite"),
                ));
            }
        }
        Ok(Pose { alpha, beta, gamma })
    }

    /// E313 (eq. 7): columns are the u, v, w directions in machine axes (eq. 8).
    pub fn matrix(&self) -> Matrix3<f64> {
        let (sa, ca) = self.alpha.to_radians().sin_cos();
        let (sb, cb) = self.beta.to_radians().sin_cos();
        let (sg, cg) = self.gamma.to_radians().sin_cos();
        Matrix3::new(
            ca * cg - sa * cb * sg,
            -ca * sg - sa * cb * cg,
            sa * sb,
            ca * cb * sg + sa * cg,
            ca * cb * cg - sa * sg,
            -ca * sb,
            sb * sg,
            sb * cg,
            cb,
        )
    }

    /// Pose whose w axis (scan-plane normal) is `normal`, with the given gamma.
    /// beta = acos(n_z), alpha = atan2(n_x, -n_y) (quadrant-safe form of eq. 6).
    /// When the normal is along Z, alpha is not defined and is set to 0.
    pub fn from_normal(normal: [f64; 3], gamma: f64) -> Result<Self> {
        let n = Vector3::from(normal);
        let norm = n.norm();
        if !norm.is_finite() || norm < 1e-12 {
            return Err(CoreError::Degenerate(format!(
                "normal: {normal:?} has no direction (zero length or non-finite)"
            )));
        }
        let n = n / norm;
        let beta = n.z.clamp(-1.0, 1.0).acos().to_degrees();
        let horizontal = n.x.hypot(n.y);
        let alpha = if horizontal < 1e-15 {
            0.0
        } else {
            n.x.atan2(-n.y).to_degrees()
        };
        Pose::new(alpha, beta, gamma)
    }
}

/// The digitizer as the kernel needs it: E313 and the mount offset
/// l1 = (U1, V1, W1) in mm, the mount point P seen from the laser origin L.
#[derive(Debug, Clone, Copy)]
pub struct Digitizer {
    /// Machine-axis direction of u.
    pub u_dir: Vector3<f64>,
    /// Machine-axis direction of v.
    pub v_dir: Vector3<f64>,
    /// -E313 . l1: where the point (u, v) = (0, 0) sits relative to P.
    pub origin: Vector3<f64>,
}

impl Digitizer {
    pub fn new(pose: &Pose, offset: [f64; 3]) -> Result<Self> {
        for (name, v) in ["U1", "V1", "W1"].iter().zip(offset) {
            if !v.is_finite() {
                return Err(CoreError::invalid_argument(
                    format!("offset.{name}"),
                    format!("{v} mm is not finite"),
                ));
            }
        }
        let m = pose.matrix();
        Ok(Digitizer {
            u_dir: m.column(0).into_owned(),
            v_dir: m.column(1).into_owned(),
            origin: -(m * Vector3::from(offset)),
        })
    }

    /// E313 . ((u, v, 0) - l1): the point relative to P in machine axes.
    #[inline(always)]
    pub fn lever(&self, u: f64, v: f64) -> Vector3<f64> {
        self.origin + self.u_dir * u + self.v_dir * v
    }

    /// As [`Digitizer::lever`] with the mount offset l1 scaled by `factor`
    /// (an effect such as the mount's thermal expansion).
    #[inline(always)]
    pub fn lever_scaled(&self, u: f64, v: f64, factor: f64) -> Vector3<f64> {
        self.origin * factor + self.u_dir * u + self.v_dir * v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thesis_alignments_point_w_along_x_and_y() {
        let w = Pose::new(90.0, 90.0, 0.0)
            .unwrap()
            .matrix()
            .column(2)
            .into_owned();
        assert!((w - Vector3::x()).norm() < 1e-15);
        let w = Pose::new(180.0, 90.0, 0.0)
            .unwrap()
            .matrix()
            .column(2)
            .into_owned();
        assert!((w - Vector3::y()).norm() < 1e-15);
    }

    #[test]
    fn matrix_is_a_proper_rotation() {
        for (a, b, g) in [(10.0, 20.0, 30.0), (-170.0, 95.0, 271.0), (0.0, 0.0, 0.0)] {
            let m = Pose::new(a, b, g).unwrap().matrix();
            assert!((m.transpose() * m - Matrix3::identity()).norm() < 1e-14);
            assert!((m.determinant() - 1.0).abs() < 1e-14);
        }
    }

    #[test]
    fn from_normal_recovers_alpha_beta_in_every_quadrant() {
        for alpha in [-170.0, -95.0, -10.0, 0.0, 45.0, 90.0, 135.0, 179.0] {
            for beta in [5.0, 60.0, 90.0, 150.0] {
                let p = Pose::new(alpha, beta, 33.0).unwrap();
                let n = p.matrix().column(2).into_owned();
                let q = Pose::from_normal([n.x * 3.0, n.y * 3.0, n.z * 3.0], 33.0).unwrap();
                assert!(
                    (q.alpha - alpha).abs() < 1e-9 && (q.beta - beta).abs() < 1e-9,
                    "{alpha} {beta}: {q:?}"
                );
            }
        }
        assert!(Pose::from_normal([0.0, 0.0, 0.0], 0.0).is_err());
        assert_eq!(Pose::from_normal([0.0, 0.0, 2.0], 0.0).unwrap().alpha, 0.0);
    }
}
