//! Plane by total least squares: the plane through the centroid whose normal
//! is the eigenvector of the centred 3 x 3 scatter matrix with the smallest
//! eigenvalue (the direction of least spread), which minimises the sum of
//! squared orthogonal distances. Closed form, no iteration.
//!
//! Sign convention: the normal's largest-magnitude component is positive (on
//! a tie, the first of x, y, z among the largest). A plane facing +z thus
//! gets a normal with positive z, and the same points always give the same
//! normal.

use nalgebra::{Matrix3, Vector3};

use super::{accumulate, check_rejection, fit_robust, mean, read_points, rms_and_form, Rejection};
use super::{sorted_eigen, spread_rank};
use crate::error::{CoreError, Result};

/// Smallest robust sigma used in rejection, relative to the points' RMS spread.
const SIGMA_FLOOR: f64 = 1e-12;

/// How to fit a plane. `Default`: no outlier rejection.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PlaneFitOptions {
    /// Reject points with |r - median(r)| > k * 1.4826 * MAD(r) and refit
    /// ([`Rejection::Mad`], [`crate::fit`] module docs); `k` must be positive.
    pub reject: Option<f64>,
}

/// A fitted plane.
///
/// Residuals cover every input point (rejected ones included); the other
/// fields describe the inliers the plane was fitted to.
#[derive(Debug, Clone, PartialEq)]
pub struct PlaneFit {
    /// Centroid of the inliers (mm): a point on the plane.
    pub point: [f64; 3],
    /// Unit normal, largest-magnitude component positive (module docs).
    pub normal: [f64; 3],
    /// Signed distance (p - point) . normal of every input point (mm, input order).
    pub residuals: Vec<f64>,
    /// Whether each input point was used in the final fit.
    pub inlier: Vec<bool>,
    /// Root mean square of the inliers' residuals (mm).
    pub rms: f64,
    /// Largest minus smallest inlier residual (mm): the flatness.
    pub form: f64,
    /// Points fitted (the inliers).
    pub n_points: usize,
    /// In-plane principal directions (unit): `axes[0]` along the largest
    /// spread of the points (largest-magnitude component positive),
    /// `axes[1] = normal x axes[0]`, so `(axes[0], axes[1], normal)` is
    /// right-handed.
    pub axes: [[f64; 3]; 2],
    /// Covariance (rad^2) of the normal's tilts t1, t2 towards `axes[0]`
    /// and `axes[1]` (fitted normal ~ true normal + t1 `axes[0]` + t2 `axes[1]`):
    /// diag(s^2 / l1, s^2 / l2), with l1, l2 the scatter matrix's in-plane
    /// eigenvalues (sum of squared coordinates along the axes, mm^2) and
    /// s^2 = SSR / (N - 3). This is the slope covariance of the regression
    /// of the distance on the in-plane coordinates, which are uncorrelated
    /// along the principal axes: first order in the noise, for independent
    /// noise of equal variance along the normal. NaN when N = 3.
    pub tilt_covariance: [[f64; 2]; 2],
    /// Points rejected as outliers.
    pub rejected: usize,
}

/// Fits a plane to `points` (N x 3 row-major, mm).
///
/// Errors: `InvalidArgument` for a bad option, fewer than 3 points or a
/// non-finite coordinate (naming the first bad row); `Degenerate` for
/// coincident or collinear points, or outlier rejection leaving too few.
pub fn fit_plane(points: &[f64], opts: &PlaneFitOptions) -> Result<PlaneFit> {
    let rule = opts.reject.map(Rejection::Mad);
    check_rejection(rule)?;
    let pts = read_points(points, 3, "a plane")?;
    let robust = fit_robust(
        &pts,
        rule,
        3,
        |m: &Model| SIGMA_FLOOR * m.spread,
        true,
        solve,
        |m, p| (p - m.point).dot(&m.normal),
    )?;
    let m = robust.model;
    let (rms, form) = rms_and_form(&robust.residuals, &robust.inlier);
    let s2 = if m.n > 3 {
        m.values[2].max(0.0) / (m.n - 3) as f64
    } else {
        f64::NAN
    };
    Ok(PlaneFit {
        point: m.point.into(),
        normal: m.normal.into(),
        residuals: robust.residuals,
        inlier: robust.inlier,
        rms,
        form,
        n_points: m.n,
        axes: [m.axes[0].into(), m.axes[1].into()],
        tilt_covariance: [[s2 / m.values[0], 0.0], [0.0, s2 / m.values[1]]],
        rejected: robust.rejected,
    })
}

/// One total-least-squares fit.
struct Model {
    point: Vector3<f64>,
    normal: Vector3<f64>,
    axes: [Vector3<f64>; 2],
    /// Scatter eigenvalues, descending (mm^2).
    values: [f64; 3],
    /// RMS distance of the points from the centroid (mm).
    spread: f64,
    n: usize,
}

fn solve(pts: &[Vector3<f64>]) -> Result<Model> {
    let m = mean(pts, true);
    let s = accumulate(
        pts,
        true,
        Matrix3::zeros,
        |s, p| {
            let q = p - m;
            s + q * q.transpose()
        },
        |a, b| a + b,
    );
    let (values, vectors) = sorted_eigen(s);
    match spread_rank(&values) {
        0 => Err(CoreError::Degenerate(
            "all points coincide: no unique plane".into(),
        )),
        1 => Err(CoreError::Degenerate(
            "points are collinear: no unique plane".into(),
        )),
        _ => {
            let normal = positive_largest(vectors.column(2).into_owned());
            let a0 = positive_largest(vectors.column(0).into_owned());
            let a1 = normal.cross(&a0);
            Ok(Model {
                point: m,
                normal,
                axes: [a0, a1],
                values,
                spread: (s.trace() / pts.len() as f64).sqrt(),
                n: pts.len(),
            })
        }
    }
}

/// `v` or `-v`, whichever has its largest-magnitude component positive
/// (the first such component on a tie).
fn positive_largest(v: Vector3<f64>) -> Vector3<f64> {
    let k = (1..3).fold(0, |k, i| if v[i].abs() > v[k].abs() { i } else { k });
    if v[k] < 0.0 {
        -v
    } else {
        v
    }
}

#[cfg(test)]
mod tests {
    use super::super::testdata::{flatten, mean_std, perpendiculars, Rng};
    use super::*;

    /// An `nu` x `nv` grid on the plane through `p0` with normal `n`, spaced
    /// `du` and `dv` mm along the perpendiculars of `n`, with Gaussian noise
    /// `sigma` along `n`.
    #[allow(clippy::too_many_arguments)]
    fn grid(
        p0: Vector3<f64>,
        n: Vector3<f64>,
        nu: usize,
        nv: usize,
        du: f64,
        dv: f64,
        sigma: f64,
        seed: u64,
    ) -> Vec<Vector3<f64>> {
        let mut rng = Rng::new(seed);
        let (u, v) = perpendiculars(&n);
        let mut out = vec![];
        for i in 0..nu {
            for j in 0..nv {
                let a = (i as f64 - 0.5 * (nu - 1) as f64) * du;
                let b = (j as f64 - 0.5 * (nv - 1) as f64) * dv;
                out.push(p0 + u * a + v * b + n * (sigma * rng.gauss()));
            }
        }
        out
    }

    #[test]
    fn fit_plane_exact_recovery() {
        // Noise-free points 100 mm from the origin: normal to 1e-12 (rounding
        // of 1e-16 relative on 100 mm over a 20 mm extent gives ~1e-15) and
        // distances to 1e-12 mm.
        let n = Vector3::new(0.2, -0.5, 0.8).normalize();
        let p0 = Vector3::new(50.0, 60.0, -70.0);
        let pts = grid(p0, n, 21, 11, 1.0, 2.0, 0.0, 1);
        let f = fit_plane(&flatten(&pts), &PlaneFitOptions::default()).unwrap();
        assert!(
            (Vector3::from(f.normal) - n).norm() < 1e-12,
            "{:?}",
            f.normal
        );
        // The centroid of the symmetric grid is p0.
        assert!((Vector3::from(f.point) - p0).norm() < 1e-12);
        assert!(f.rms < 1e-12 && f.form < 1e-12);
        assert_eq!((f.n_points, f.rejected, f.residuals.len()), (231, 0, 231));
        // Residuals are signed distances along the normal.
        let mut q = pts.clone();
        q[5] += n * 0.25;
        let f = fit_plane(&flatten(&q), &PlaneFitOptions::default()).unwrap();
        assert!(f.residuals[5] > 0.0 && (f.residuals[5] - f.form).abs() < 0.01);
        // Right-handed axes, orthonormal to rounding.
        let [a0, a1] = f.axes.map(Vector3::from);
        assert!((a0.cross(&a1) - Vector3::from(f.normal)).norm() < 1e-12);
    }

    #[test]
    fn fit_plane_normal_sign_convention() {
        // Exact comparisons: the sign flip is exact and unit normals of
        // axis-aligned planes come out to rounding (1e-12).
        let cases = [
            (Vector3::new(0.0, 0.0, -1.0), Vector3::new(0.0, 0.0, 1.0)),
            (Vector3::new(-1.0, 0.0, 0.0), Vector3::new(1.0, 0.0, 0.0)),
            (
                Vector3::new(0.3, -0.9, 0.1).normalize(),
                Vector3::new(-0.3, 0.9, -0.1).normalize(),
            ),
        ];
        for (given, expected) in cases {
            let pts = grid(Vector3::new(1.0, 2.0, 3.0), given, 5, 7, 1.0, 1.0, 0.0, 2);
            let f = fit_plane(&flatten(&pts), &PlaneFitOptions::default()).unwrap();
            assert!(
                (Vector3::from(f.normal) - expected).norm() < 1e-12,
                "{given:?} -> {:?}",
                f.normal
            );
        }
        assert_eq!(
            positive_largest(Vector3::new(-1.0, 1.0, 0.0)),
            Vector3::new(1.0, -1.0, 0.0)
        );
    }

    #[test]
    fn fit_plane_tilt_covariance_matches_repeats() {
        // 200 repeats of a 30 x 10 mm grid (different spreads along the two
        // axes) with 8 um noise: the scatter of the fitted normal's tilts
        // towards x and y agrees with sqrt(diag(tilt_covariance)) within
        // 20 % (the standard deviation of 200 samples has ~5 % relative
        // standard error, so 20 % is four of them).
        let n = Vector3::z();
        let (mut t1, mut t2, mut pred) = (vec![], vec![], [0.0; 2]);
        for seed in 0..200 {
            let pts = grid(Vector3::zeros(), n, 31, 11, 1.0, 1.0, 0.008, 500 + seed);
            let f = fit_plane(&flatten(&pts), &PlaneFitOptions::default()).unwrap();
            let fn_ = Vector3::from(f.normal);
            let (u, v) = perpendiculars(&n);
            t1.push(fn_.dot(&u));
            t2.push(fn_.dot(&v));
            // axes[0] lies along the 31-point (u) direction.
            assert!(Vector3::from(f.axes[0]).dot(&u).abs() > 0.999);
            pred[0] += f.tilt_covariance[0][0].sqrt() / 200.0;
            pred[1] += f.tilt_covariance[1][1].sqrt() / 200.0;
        }
        let (_, s1) = mean_std(&t1);
        let (_, s2) = mean_std(&t2);
        println!("tilt sd {s1:e} vs {:e}, {s2:e} vs {:e}", pred[0], pred[1]);
        assert!((s1 / pred[0] - 1.0).abs() < 0.2);
        assert!((s2 / pred[1] - 1.0).abs() < 0.2);
    }

    #[test]
    fn fit_plane_rejects_outliers() {
        // 50 of 600 points lifted 1 mm off a plane with 5 um noise: with
        // k = 4 all 50 go and the normal is back to the noise (its tilt
        // sigma is ~5e-3 / sqrt(sum of squares ~ 1e5) ~ 2e-5 rad, so 1e-4).
        let n = Vector3::new(0.0, 0.6, 0.8);
        let mut pts = grid(Vector3::zeros(), n, 30, 20, 1.0, 1.0, 0.005, 3);
        for p in pts.iter_mut().step_by(12) {
            *p += n * 1.0;
        }
        let opts = PlaneFitOptions { reject: Some(4.0) };
        let f = fit_plane(&flatten(&pts), &opts).unwrap();
        assert_eq!(f.rejected, 50);
        assert!(f.inlier.iter().step_by(12).all(|&i| !i));
        assert!((Vector3::from(f.normal) - n).norm() < 1e-4);
        assert!(f.residuals[0] > 0.9 && f.residuals.len() == 600);
        assert_eq!(f.n_points, 550);
    }

    #[test]
    fn fit_plane_errors() {
        let o = PlaneFitOptions::default();
        let e = fit_plane(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0], &o).unwrap_err();
        assert_eq!(
            e.to_string(),
            "points: a plane needs at least 3 points, got 2"
        );
        let e = fit_plane(&[0.0, 0.0, 0.0, 1.0, f64::NAN, 0.0, 0.0, 1.0, 0.0], &o).unwrap_err();
        assert_eq!(
            e.to_string(),
            "points: non-finite value (NaN or inf) in row 1"
        );
        // Collinear: 10 points on a line, and 3 coincident points.
        let line: Vec<f64> = (0..10)
            .flat_map(|i| [i as f64, 2.0 * i as f64, 1.0])
            .collect();
        let e = fit_plane(&line, &o).unwrap_err();
        assert!(matches!(e, CoreError::Degenerate(_)));
        assert_eq!(e.to_string(), "points are collinear: no unique plane");
        let e = fit_plane(&[1.0; 9], &o).unwrap_err();
        assert_eq!(e.to_string(), "all points coincide: no unique plane");
        let e = fit_plane(&line, &PlaneFitOptions { reject: Some(-1.0) }).unwrap_err();
        assert!(
            e.to_string().starts_with("reject: must be a positive"),
            "{e}"
        );
        // Exactly three points fit, without degrees of freedom for a covariance.
        let f = fit_plane(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0], &o).unwrap();
        assert_eq!(f.normal, [0.0, 0.0, 1.0]);
        assert!(f.tilt_covariance[0][0].is_nan());
    }
}
