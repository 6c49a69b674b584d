//! Artefact surfaces the simulated scanner sees: spheres, spheroids (the form
//! error of thesis Appendix A) and flat discs. Each answers one question: where
//! does a ray first meet it, and what is the outward normal there.

use nalgebra::{Unit, Vector3};

use crate::error::{CoreError, Result};

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Surface {
    /// Centre (mm) and radius (mm).
    Sphere { centre: Vector3<f64>, radius: f64 },
    /// Spheroid of revolution about `axis`: equatorial radius `a`, polar
    /// semi-axis `c` (mm). c < a is oblate, c > a prolate.
    Spheroid {
        centre: Vector3<f64>,
        axis: Unit<Vector3<f64>>,
        a: f64,
        c: f64,
    },
    /// Flat disc: a point on it, its normal, and its radius (mm).
    Disc {
        centre: Vector3<f64>,
        normal: Unit<Vector3<f64>>,
        radius: f64,
    },
}

/// A ray hit: distance along the (unit) direction and outward unit normal.
#[derive(Debug, Clone, Copy)]
pub struct Hit {
    pub distance: f64,
    pub normal: Vector3<f64>,
}

impl Surface {
    pub fn sphere(centre: [f64; 3], radius: f64) -> Result<Self> {
        check_positive("radius", radius)?;
        Ok(Surface::Sphere {
            centre: finite("centre", centre)?,
            radius,
        })
    }

    pub fn spheroid(centre: [f64; 3], axis: [f64; 3], a: f64, c: f64) -> Result<Self> {
        check_positive("a", a)?;
        check_positive("c", c)?;
        Ok(Surface::Spheroid {
            centre: finite("centre", centre)?,
            axis: unit("axis", axis)?,
            a,
            c,
        })
    }

    pub fn disc(centre: [f64; 3], normal: [f64; 3], radius: f64) -> Result<Self> {
        check_positive("radius", radius)?;
        Ok(Surface::Disc {
            centre: finite("centre", centre)?,
            normal: unit("normal", normal)?,
            radius,
        })
    }

    /// First intersection of the ray `origin + s * dir` (s > 0, |dir| = 1).
    pub fn hit(&self, origin: &Vector3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
        match *self {
            Surface::Sphere { centre, radius } => {
                let s = first_root(
                    dir.norm_squared(),
                    dir.dot(&(origin - centre)),
                    (origin - centre).norm_squared() - radius * radius,
                )?;
                let p = origin + dir * s;
                Some(Hit {
                    distance: s,
                    normal: (p - centre) / radius,
                })
            }
            Surface::Spheroid { centre, axis, a, c } => {
                // Scale the polar direction by a/c: the spheroid becomes a sphere of radius a.
                let k = a / c;
                let squash = |v: Vector3<f64>| v + axis.as_ref() * (axis.dot(&v) * (k - 1.0));
                let o = squash(origin - centre);
                let d = squash(*dir);
                let s = first_root(d.norm_squared(), d.dot(&o), o.norm_squared() - a * a)?;
                let q = origin + dir * s - centre;
                // Gradient of x_perp^2/a^2 + x_ax^2/c^2.
                let ax = axis.dot(&q);
                let g = (q - axis.as_ref() * ax) / (a * a) + axis.as_ref() * (ax / (c * c));
                Some(Hit {
                    distance: s,
                    normal: g.normalize(),
                })
            }
            Surface::Disc {
                centre,
                normal,
                radius,
            } => {
                let denom = dir.dot(&normal);
                if denom.abs() < 1e-15 {
                    return None;
                }
                let s = (centre - origin).dot(&normal) / denom;
                let p = origin + dir * s;
                (s > 0.0 && (p - centre).norm() <= radius).then_some(Hit {
                    distance: s,
                    normal: normal.into_inner(),
                })
            }
        }
    }
}

/// Smallest positive root of a s^2 + 2 b s + c = 0.
#[inline]
fn first_root(a: f64, b: f64, c: f64) -> Option<f64> {
    let disc = b * b - a * c;
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    let s1 = (-b - sq) / a;
    let s2 = (-b + sq) / a;
    if s1 > 0.0 {
        Some(s1)
    } else if s2 > 0.0 {
        Some(s2)
    } else {
        None
    }
}

fn check_positive(name: &str, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(CoreError::invalid_argument(
            name,
            format!("must be a positive length in mm, got {v}"),
        ))
    }
}

fn finite(name: &str, v: [f64; 3]) -> Result<Vector3<f64>> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(Vector3::from(v))
    } else {
        Err(CoreError::invalid_argument(
            name,
            format!("must be finite, got {v:?}"),
        ))
    }
}

fn unit(name: &str, v: [f64; 3]) -> Result<Unit<Vector3<f64>>> {
    let v = finite(name, v)?;
    Unit::try_new(v, 1e-12)
        .ok_or_else(|| CoreError::Degenerate(format!("{name}: {v:?} has no direction")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_hit_from_outside() {
        let s = Surface::sphere([0.0, 0.0, 0.0], 10.0).unwrap();
        let h = s
            .hit(
                &Vector3::new(1.0, 0.0, 100.0),
                &Vector3::new(0.0, 0.0, -1.0),
            )
            .unwrap();
        assert!((h.distance - (100.0 - 99.0f64.sqrt())).abs() < 1e-12);
        assert!((h.normal - Vector3::new(1.0, 0.0, 99.0f64.sqrt()) / 10.0).norm() < 1e-12);
        assert!(s
            .hit(
                &Vector3::new(11.0, 0.0, 100.0),
                &Vector3::new(0.0, 0.0, -1.0)
            )
            .is_none());
    }

    #[test]
    fn spheroid_poles_and_equator() {
        let s = Surface::spheroid([0.0, 0.0, 0.0], [0.0, 0.0, 2.0], 38.125, 38.1225).unwrap();
        let top = s
            .hit(
                &Vector3::new(0.0, 0.0, 100.0),
                &Vector3::new(0.0, 0.0, -1.0),
            )
            .unwrap();
        assert!((100.0 - top.distance - 38.1225).abs() < 1e-12);
        let side = s
            .hit(
                &Vector3::new(100.0, 0.0, 0.0),
                &Vector3::new(-1.0, 0.0, 0.0),
            )
            .unwrap();
        assert!((100.0 - side.distance - 38.125).abs() < 1e-12);
        assert!((side.normal - Vector3::x()).norm() < 1e-12);
    }

    #[test]
    fn disc_limits_and_bad_arguments() {
        let d = Surface::disc([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 5.0).unwrap();
        assert!(d
            .hit(&Vector3::new(1.0, 1.0, 10.0), &Vector3::new(0.0, 0.0, -1.0))
            .is_some());
        assert!(d
            .hit(&Vector3::new(6.0, 0.0, 10.0), &Vector3::new(0.0, 0.0, -1.0))
            .is_none());
        assert!(Surface::sphere([0.0; 3], -1.0).is_err());
        assert!(Surface::disc([0.0; 3], [0.0; 3], 1.0).is_err());
    }
}
