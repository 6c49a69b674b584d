//! The simulated line scanner: one profile is the set of points where the
//! laser sheet (the scan plane) meets the artefacts, sampled at evenly spaced
//! u across the field of view, seen along -v from the sensor side of the depth
//! of view. Only surface facing the sensor within the incidence limit is seen.
//! Hymarc Hyscan 45C (thesis Table 17): 60 mm wide, 60 mm deep, 140 mm
//! stand-off. The laser origin L sits in the middle of the depth of view, so
//! the field is u, v in [-30, 30] mm and the sensor is 140 mm away along +v.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use crate::artefact::Surface;
use crate::error::{CoreError, Result};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScannerModel {
    /// Field of view across the line, u (mm).
    pub u_range: (f64, f64),
    /// Depth of view along v (mm); v points from the part towards the sensor.
    pub v_range: (f64, f64),
    /// Samples across the line (at most 1024 on the Hyscan).
    pub points_per_profile: usize,
    /// Largest angle between the surface normal and +v that still returns a point (degrees).
    pub max_incidence_deg: f64,
}

impl Default for ScannerModel {
    fn default() -> Self {
        ScannerModel {
            u_range: (-30.0, 30.0),
            v_range: (-30.0, 30.0),
            points_per_profile: 1024,
            max_incidence_deg: 70.0,
        }
    }
}

impl ScannerModel {
    pub fn validate(&self) -> Result<()> {
        let ok_range = |(a, b): (f64, f64)| a.is_finite() && b.is_finite() && a < b;
        if !ok_range(self.u_range) || !ok_range(self.v_range) {
            return Err(CoreError::invalid_argument(
                "scanner",
                "u_range and v_range must be finite (lo, hi) with lo < hi (mm)",
            ));
        }
        if self.points_per_profile < 1 || self.points_per_profile > 1 << 20 {
            return Err(CoreError::invalid_argument(
                "scanner.points_per_profile",
                format!("must be 1..=1048576, got {}", self.points_per_profile),
            ));
        }
        if !(self.max_incidence_deg > 0.0 && self.max_incidence_deg < 90.0) {
            return Err(CoreError::invalid_argument(
                "scanner.max_incidence_deg",
                format!("must be in (0, 90) degrees, got {}", self.max_incidence_deg),
            ));
        }
        Ok(())
    }
}

/// Where the scan plane is: the laser origin L and the u, v directions in
/// machine coordinates (mm, unit vectors).
#[derive(Debug, Clone, Copy)]
pub struct ScanFrame {
    pub origin: Vector3<f64>,
    pub u_dir: Vector3<f64>,
    pub v_dir: Vector3<f64>,
}

impl ScanFrame {
    /// From the true mount point P, ram orientation R, pose matrix E313 and
    /// mount offset l1: L = P - R E313 l1, u = R E313 e_u, v = R E313 e_v.
    pub fn new(p: Vector3<f64>, r: &Matrix3<f64>, e313: &Matrix3<f64>, offset: [f64; 3]) -> Self {
        let m = r * e313;
        ScanFrame {
            origin: p - m * Vector3::from(offset),
            u_dir: m.column(0).into_owned(),
            v_dir: m.column(1).into_owned(),
        }
    }
}

/// One scanned point: u, v in the laser frame (mm), the cosine of the
/// incidence angle between the surface normal and +v, and where the point
/// really is in machine coordinates (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProfilePoint {
    pub u: f64,
    pub v: f64,
    pub cos_incidence: f64,
    pub xyz: [f64; 3],
}

/// Points of one profile, appended to `out`.
pub fn profile(
    frame: &ScanFrame,
    surfaces: &[Surface],
    model: &ScannerModel,
    out: &mut Vec<ProfilePoint>,
) {
    let (u0, u1) = model.u_range;
    let (v0, v1) = model.v_range;
    let n = model.points_per_profile;
    let cos_limit = model.max_incidence_deg.to_radians().cos();
    let down = -frame.v_dir;
    for i in 0..n {
        let u = if n == 1 {
            0.5 * (u0 + u1)
        } else {
            u0 + (u1 - u0) * i as f64 / (n - 1) as f64
        };
        let start = frame.origin + frame.u_dir * u + frame.v_dir * v1;
        let nearest = surfaces
            .iter()
            .filter_map(|s| s.hit(&start, &down))
            .min_by(|a, b| a.distance.total_cmp(&b.distance));
        if let Some(h) = nearest {
            let v = v1 - h.distance;
            let cos_inc = h.normal.dot(&frame.v_dir);
            if v >= v0 && cos_inc >= cos_limit {
                let x = start + down * h.distance;
                out.push(ProfilePoint {
                    u,
                    v,
                    cos_incidence: cos_inc,
                    xyz: [x.x, x.y, x.z],
                });
            }
        }
    }
}

/// Many profiles in parallel. Returns, in profile order, the index of the
/// profile each point belongs to and the points.
pub fn profiles(
    frames: &[ScanFrame],
    surfaces: &[Surface],
    model: &ScannerModel,
) -> Result<(Vec<usize>, Vec<ProfilePoint>)> {
    model.validate()?;
    let per: Vec<Vec<ProfilePoint>> = frames
        .par_iter()
        .map(|f| {
            let mut v = Vec::new();
            profile(f, surfaces, model, &mut v);
            v
        })
        .collect();
    let total = per.iter().map(Vec::len).sum();
    let mut index = Vec::with_capacity(total);
    let mut points = Vec::with_capacity(total);
    for (k, v) in per.into_iter().enumerate() {
        index.extend(std::iter::repeat_n(k, v.len()));
        points.extend(v);
    }
    Ok((index, points))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::Pose;

    #[test]
    fn points_lie_on_the_sphere_and_face_the_sensor() {
        let e = Pose::new(90.0, 90.0, 0.0).unwrap().matrix();
        let offset = [1.001, 264.505, 129.575];
        let centre = Vector3::new(400.0, 275.0, -300.0);
        let r = 38.125;
        // Laser origin at the ball top, 5 mm off the centre along X (the sweep axis).
        let l = Vector3::new(centre.x + 5.0, centre.y, centre.z + r);
        let p = l + e * Vector3::from(offset);
        let frame = ScanFrame::new(p, &Matrix3::identity(), &e, offset);
        assert!((frame.origin - l).norm() < 1e-12);
        let ball = Surface::sphere(centre.into(), r).unwrap();
        let model = ScannerModel::default();
        let mut pts = Vec::new();
        profile(&frame, &[ball], &model, &mut pts);
        assert!(pts.len() > 800, "{}", pts.len());
        for q in &pts {
            let x = frame.origin + frame.u_dir * q.u + frame.v_dir * q.v;
            assert!(((x - centre).norm() - r).abs() < 1e-9);
            assert!((x - Vector3::from(q.xyz)).norm() < 1e-12);
            assert!(q.cos_incidence >= model.max_incidence_deg.to_radians().cos());
            assert!(q.v >= -30.0 && q.v <= 30.0);
        }
    }

    #[test]
    fn rejects_bad_models() {
        let m = ScannerModel {
            max_incidence_deg: 95.0,
            ..Default::default()
        };
        assert!(profiles(&[], &[], &m).is_err());
        let m = ScannerModel {
            u_range: (5.0, -5.0),
            ..Default::default()
        };
        assert!(m.validate().is_err());
    }
}
