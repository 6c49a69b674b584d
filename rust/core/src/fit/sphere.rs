//! Sphere by orthogonal (geometric) least squares: minimise the sum of
//! squared residuals r_i = |p_i - c| - R over the centre c and radius R.
//!
//! 1. Centre the points on their mean (conditioning); refuse coincident,
//!    collinear or coplanar points (no unique sphere).
//! 2. Algebraic start: linear least squares of |q|^2 + a.q + d = 0. With
//!    centred q the normal equations split into S a = -sum q |q|^2 (S the
//!    scatter matrix) and d = -mean |q|^2; then c = -a/2, R^2 = |c|^2 - d.
//!    This start is biased on noisy partial caps, the geometric fit is not.
//! 3. Gauss-Newton on the geometric residuals, analytic Jacobian
//!    dr/dc = -(p - c)/|p - c|, dr/dR = -1, with Levenberg-Marquardt damping
//!    (Marquardt's diagonal scaling) switched on after a step that fails to
//!    lower the cost and off again as steps succeed. Each trial step takes
//!    one pass over the points, which yields the cost and J^T J, J^T r at the
//!    trial point together. Converged when the undamped step is below 1e-12
//!    of the radius, or it or an accepted step lowers the cost by less than
//!    1e-15 of it, or the residuals' RMS is below 1e-14 of the radius
//!    (noise-free points), or when damping has shrunk a failing step below
//!    1e-12 of the radius (the cost is flat to rounding); `converged = false`
//!    when `max_iterations` steps ran out first. A fit whose normal
//!    equations stay singular, or whose radius leaves (0, inf), is a
//!    `Degenerate` error.
//! 4. Polar coverage of the inliers seen from the fitted centre; a cap below
//!    `min_coverage_deg` is a `Degenerate` error.
//!
//! With a fixed radius only the centre is fitted (3 x 3 normal equations).
//! Coplanar points are refused with a fixed radius too: the two mirror-image
//! centres on either side of the plane fit them equally well. (Three points
//! are always coplanar, so a fixed-radius fit needs four in practice; fewer
//! than three is refused as too few.)

use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};
use rayon::prelude::*;

use super::{
    accumulate, check_reject, fit_robust, mean, read_points, rms_and_form, sorted_eigen,
    spread_rank,
};
use crate::error::{CoreError, Result};

/// Converged when a step is shorter than this times the radius.
const STEP_TOL: f64 = 1e-12;
/// Converged when an accepted step lowers the cost by less than this fraction.
const COST_TOL: f64 = 1e-15;
/// Converged when the residuals' RMS is below this times the radius: noise-free
/// points, whose residuals are rounding errors (~45 ulp of the radius).
const RMS_FLOOR: f64 = 1e-14;
/// Marquardt damping after the first failed Gauss-Newton step.
const LAMBDA_START: f64 = 1e-3;
/// Damping below this after a successful step drops back to Gauss-Newton.
const LAMBDA_MIN: f64 = 1e-9;
/// Damping beyond this without a usable step means the fit has stalled.
const LAMBDA_MAX: f64 = 1e16;
/// Smallest robust sigma used in rejection, relative to the radius.
const SIGMA_FLOOR: f64 = 1e-12;

/// How to fit a sphere. `Default` gives a free radius, no rejection, 100
/// iterations and a 2 degree minimum polar coverage.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SphereFitOptions {
    /// Fix the radius (mm) and fit only the centre.
    pub radius: Option<f64>,
    /// Reject points with |r| > k * 1.4826 * MAD(r) and refit
    /// ([`crate::fit`] module docs); `k` must be positive (3 to 5 is usual).
    pub reject: Option<f64>,
    /// Levenberg-Marquardt steps allowed per fit (at least 1).
    pub max_iterations: usize,
    /// Smallest polar coverage (degrees, 0..=180) accepted; a smaller cap is
    /// a `Degenerate` error.
    pub min_coverage_deg: f64,
}

impl Default for SphereFitOptions {
    fn default() -> Self {
        SphereFitOptions {
            radius: None,
            reject: None,
            max_iterations: 100,
            min_coverage_deg: 2.0,
        }
    }
}

/// A fitted sphere.
///
/// Residuals cover every input point (rejected ones included, so they can be
/// plotted); `rms`, `form`, `n_points`, `covariance` and `polar_coverage_deg`
/// describe the inliers the sphere was fitted to.
#[derive(Debug, Clone, PartialEq)]
pub struct SphereFit {
    /// Centre (mm).
    pub centre: [f64; 3],
    /// Radius (mm); the given one when it was fixed.
    pub radius: f64,
    /// Signed residual |p - c| - R of every input point (mm, input order):
    /// positive outside the sphere.
    pub residuals: Vec<f64>,
    /// Whether each input point was used in the final fit.
    pub inlier: Vec<bool>,
    /// Root mean square of the inliers' residuals (mm).
    pub rms: f64,
    /// Largest minus smallest inlier residual (mm).
    pub form: f64,
    /// Points fitted (the inliers).
    pub n_points: usize,
    /// Covariance of (centre x, y, z, radius), mm^2: s^2 (J^T J)^-1 with
    /// s^2 = SSR / (N - p), p = 4 (3 with a fixed radius, whose row and
    /// column are then zero). NaN when N = p (no degrees of freedom left).
    pub covariance: [[f64; 4]; 4],
    /// Half-angle (degrees, 0..=180) of the smallest cone about the mean
    /// direction of the inliers seen from the centre that holds them all.
    pub polar_coverage_deg: f64,
    /// Levenberg-Marquardt steps of the final fit.
    pub iterations: usize,
    /// `false` only when `max_iterations` stopped a fit that was still improving.
    pub converged: bool,
    /// Points rejected as outliers.
    pub rejected: usize,
}

/// Fits one sphere to `points` (N x 3 row-major, mm), in parallel over the
/// points when there are many ([`super::PARALLEL_MIN_POINTS`]).
///
/// Errors: `InvalidArgument` for a bad option, fewer than 4 points (3 with a
/// fixed radius) or a non-finite coordinate (naming the first bad row);
/// `Degenerate` for coincident, collinear or coplanar points, a cap below
/// `min_coverage_deg`, a fit that stalls or diverges, or outlier rejection
/// leaving too few points.
pub fn fit_sphere(points: &[f64], opts: &SphereFitOptions) -> Result<SphereFit> {
    fit(points, opts, true)
}

/// Fits many spheres in parallel (one rayon task per sphere, each fit serial).
/// Results are in the order of `sets` and equal `fit_sphere` on each set
/// (bit for bit below [`super::PARALLEL_MIN_POINTS`] points; above it
/// `fit_sphere` sums in parallel, in another order, so to rounding).
pub fn fit_spheres(sets: &[&[f64]], opts: &SphereFitOptions) -> Vec<Result<SphereFit>> {
    sets.par_iter().map(|s| fit(s, opts, false)).collect()
}

fn check_options(opts: &SphereFitOptions) -> Result<()> {
    if let Some(r) = opts.radius {
        if !(r.is_finite() && r > 0.0) {
            return Err(CoreError::invalid_argument(
                "radius",
                format!("a fixed radius must be a positive length in mm, got {r}"),
            ));
        }
    }
    check_reject(opts.reject)?;
    if opts.max_iterations == 0 {
        return Err(CoreError::invalid_argument(
            "max_iterations",
            "must be at least 1",
        ));
    }
    let c = opts.min_coverage_deg;
    if !(0.0..=180.0).contains(&c) {
        return Err(CoreError::invalid_argument(
            "min_coverage_deg",
            format!("must be an angle in [0, 180] degrees, got {c}"),
        ));
    }
    Ok(())
}

fn fit(points: &[f64], opts: &SphereFitOptions, parallel: bool) -> Result<SphereFit> {
    check_options(opts)?;
    let (min, what) = match opts.radius {
        Some(_) => (3, "a sphere of fixed radius"),
        None => (4, "a sphere"),
    };
    let pts = read_points(points, min, what)?;
    let robust = fit_robust(
        &pts,
        opts.reject,
        min,
        |m: &Solved| SIGMA_FLOOR * m.radius,
        parallel,
        |p| solve(p, opts.radius, opts.max_iterations, parallel),
        |m, p| (p - m.centre).norm() - m.radius,
    )?;
    let s = robust.model;
    let coverage = if robust.rejected == 0 {
        polar_coverage(&pts, &s.centre, parallel)
    } else {
        let kept: Vec<Vector3<f64>> = pts
            .iter()
            .zip(&robust.inlier)
            .filter(|(_, &i)| i)
            .map(|(p, _)| *p)
            .collect();
        polar_coverage(&kept, &s.centre, parallel)
    };
    if coverage < opts.min_coverage_deg {
        return Err(CoreError::Degenerate(format!(
            "polar coverage {coverage:.3} deg is below min_coverage_deg = {} deg: the cap is \
             too small to fit a sphere (fitted radius {:.6} mm)",
            opts.min_coverage_deg, s.radius
        )));
    }
    let (rms, form) = rms_and_form(&robust.residuals, &robust.inlier);
    Ok(SphereFit {
        centre: s.centre.into(),
        radius: s.radius,
        covariance: s.covariance(opts.radius.is_some()),
        residuals: robust.residuals,
        inlier: robust.inlier,
        rms,
        form,
        n_points: s.n,
        polar_coverage_deg: coverage,
        iterations: s.iterations,
        converged: s.converged,
        rejected: robust.rejected,
    })
}

/// One geometric fit to all of `pts`.
#[derive(Debug, Clone)]
struct Solved {
    centre: Vector3<f64>,
    radius: f64,
    /// Normal equations at the solution (undamped).
    normal: Normal,
    n: usize,
    iterations: usize,
    converged: bool,
}

impl Solved {
    /// s^2 (J^T J)^-1, the radius row and column zero when it was fixed.
    fn covariance(&self, fixed: bool) -> [[f64; 4]; 4] {
        let p = if fixed { 3 } else { 4 };
        let s2 = if self.n > p {
            self.normal.cost / (self.n - p) as f64
        } else {
            f64::NAN
        };
        let a = self.normal.matrix();
        // Symmetrised: an inverse from a factorisation is symmetric only to rounding.
        let mut out = [[0.0; 4]; 4];
        if fixed {
            let inv = invert3(&a.fixed_view::<3, 3>(0, 0).into_owned());
            for (i, row) in out.iter_mut().enumerate().take(3) {
                for (j, v) in row.iter_mut().enumerate().take(3) {
                    *v = s2 * 0.5 * (inv[(i, j)] + inv[(j, i)]);
                }
            }
        } else {
            let inv = a
                .cholesky()
                .map(|c| c.inverse())
                .or_else(|| a.try_inverse())
                .unwrap_or_else(|| Matrix4::repeat(f64::NAN));
            for (i, row) in out.iter_mut().enumerate() {
                for (j, v) in row.iter_mut().enumerate() {
                    *v = s2 * 0.5 * (inv[(i, j)] + inv[(j, i)]);
                }
            }
        }
        out
    }
}

fn invert3(a: &Matrix3<f64>) -> Matrix3<f64> {
    a.cholesky()
        .map(|c| c.inverse())
        .or_else(|| a.try_inverse())
        .unwrap_or_else(|| Matrix3::repeat(f64::NAN))
}

/// J^T J (upper triangle, row by row), J^T r and the cost sum r^2 for the
/// parameters (c_x, c_y, c_z, R), accumulated in one pass.
#[derive(Debug, Clone, Copy, Default)]
struct Normal {
    a: [f64; 10],
    g: [f64; 4],
    cost: f64,
}

impl Normal {
    #[inline(always)]
    fn add(mut self, q: &Vector3<f64>, c: &Vector3<f64>, radius: f64) -> Self {
        let d = q - c;
        let dist = d.norm();
        let r = dist - radius;
        // J row = -(u, 1) with u the unit direction (zero at the centre itself).
        let u = if dist > 0.0 { d / dist } else { d };
        let (x, y, z) = (u.x, u.y, u.z);
        let a = &mut self.a;
        a[0] += x * x;
        a[1] += x * y;
        a[2] += x * z;
        a[3] += x;
        a[4] += y * y;
        a[5] += y * z;
        a[6] += y;
        a[7] += z * z;
        a[8] += z;
        a[9] += 1.0;
        self.g[0] -= x * r;
        self.g[1] -= y * r;
        self.g[2] -= z * r;
        self.g[3] -= r;
        self.cost += r * r;
        self
    }

    fn merge(mut self, o: Normal) -> Self {
        for (a, b) in self.a.iter_mut().zip(o.a) {
            *a += b;
        }
        for (a, b) in self.g.iter_mut().zip(o.g) {
            *a += b;
        }
        self.cost += o.cost;
        self
    }

    fn matrix(&self) -> Matrix4<f64> {
        let a = &self.a;
        Matrix4::new(
            a[0], a[1], a[2], a[3], //
            a[1], a[4], a[5], a[6], //
            a[2], a[5], a[7], a[8], //
            a[3], a[6], a[8], a[9],
        )
    }

    /// Cost decrease |r|^2 - |r + J d|^2 that the linearised model predicts.
    fn predicted(&self, d: &Vector4<f64>) -> f64 {
        let g = Vector4::from(self.g);
        -(2.0 * g.dot(d) + d.dot(&(self.matrix() * d)))
    }

    /// The damped Gauss-Newton step (J^T J + lambda diag(J^T J)) d = -J^T r;
    /// with a fixed radius its equation becomes d_R = 0.
    fn step(&self, lambda: f64, fixed: bool) -> Option<Vector4<f64>> {
        let mut a = self.matrix();
        let mut g = Vector4::from(self.g);
        if fixed {
            for k in 0..3 {
                a[(k, 3)] = 0.0;
                a[(3, k)] = 0.0;
            }
            a[(3, 3)] = 1.0;
            g[3] = 0.0;
        }
        for k in 0..4 {
            a[(k, k)] *= 1.0 + lambda;
        }
        a.cholesky().map(|c| c.solve(&-g))
    }
}

/// Cost and normal equations at (c, R) over the centred points `q`.
fn evaluate(q: &[Vector3<f64>], c: &Vector3<f64>, radius: f64, parallel: bool) -> Normal {
    accumulate(
        q,
        parallel,
        Normal::default,
        |acc, p| acc.add(p, c, radius),
        Normal::merge,
    )
}

/// The algebraic start in centred coordinates: centre and radius.
fn algebraic(q: &[Vector3<f64>], parallel: bool) -> Result<(Vector3<f64>, f64)> {
    let (s, b) = accumulate(
        q,
        parallel,
        || (Matrix3::zeros(), Vector3::zeros()),
        |(s, b), p| (s + p * p.transpose(), b + p * p.norm_squared()),
        |(s1, b1), (s2, b2)| (s1 + s2, b1 + b2),
    );
    let (values, vectors) = sorted_eigen(s);
    match spread_rank(&values) {
        0 => Err(CoreError::Degenerate(
            "all points coincide: no unique sphere".into(),
        )),
        1 => Err(CoreError::Degenerate(
            "points are collinear: no unique sphere".into(),
        )),
        2 => Err(CoreError::Degenerate(
            "points are coplanar: no unique sphere".into(),
        )),
        _ => {
            // a = -S^-1 b through the eigen-decomposition; c = -a / 2.
            let w = vectors.transpose() * b;
            let w = Vector3::new(w.x / values[0], w.y / values[1], w.z / values[2]);
            let centre = vectors * w * 0.5;
            let r2 = centre.norm_squared() + s.trace() / q.len() as f64;
            Ok((centre, r2.max(0.0).sqrt()))
        }
    }
}

/// The geometric fit of one set of points.
fn solve(
    pts: &[Vector3<f64>],
    fixed: Option<f64>,
    max_iterations: usize,
    parallel: bool,
) -> Result<Solved> {
    let m = mean(pts, parallel);
    let q: Vec<Vector3<f64>> = pts.iter().map(|p| p - m).collect();
    let (mut c, r0) = algebraic(&q, parallel)?;
    let mut radius = r0;
    if let Some(rf) = fixed {
        // Keep the apex of the cap where the algebraic sphere puts it: move
        // the centre along the cap axis (centre -> mean) by the radius change.
        let dist = c.norm();
        if dist > 0.1 * r0 {
            c += c / dist * (rf - r0);
        }
        radius = rf;
    }
    let fixed_r = fixed.is_some();
    let mut cur = evaluate(&q, &c, radius, parallel);
    // Pure Gauss-Newton while it works; damping only after a failed step.
    let mut lambda = 0.0;
    let mut iterations = 0;
    let mut converged = false;
    loop {
        // Converged when the undamped step is negligible, or would lower the
        // cost negligibly, or the residuals are at rounding level already.
        if cur.cost <= q.len() as f64 * (RMS_FLOOR * radius).powi(2) {
            converged = true;
            break;
        }
        let gauss_newton = cur.step(0.0, fixed_r);
        if let Some(d) = gauss_newton {
            if d.norm() <= STEP_TOL * radius.abs() || cur.predicted(&d) <= COST_TOL * cur.cost {
                converged = true;
                break;
            }
        }
        if iterations == max_iterations {
            break;
        }
        let step = if lambda == 0.0 {
            gauss_newton
        } else {
            cur.step(lambda, fixed_r)
        };
        let accepted = match step {
            Some(d) => {
                iterations += 1;
                let (c_try, r_try) = (c + d.fixed_rows::<3>(0), radius + d[3]);
                let trial = evaluate(&q, &c_try, r_try, parallel);
                if trial.cost <= cur.cost {
                    let small = cur.cost - trial.cost <= COST_TOL * cur.cost;
                    (c, radius, cur) = (c_try, r_try, trial);
                    if small {
                        converged = true;
                        break;
                    }
                    true
                } else if d.norm() <= STEP_TOL * radius.abs() {
                    // Even a tiny step along the descent direction fails:
                    // the cost is flat to rounding here.
                    converged = true;
                    break;
                } else {
                    false
                }
            }
            None => false,
        };
        if accepted {
            lambda = if lambda < LAMBDA_MIN {
                0.0
            } else {
                lambda * 0.1
            };
        } else {
            lambda = (lambda * 10.0).max(LAMBDA_START);
            if lambda > LAMBDA_MAX {
                return Err(stalled(pts, &(c + m), radius, parallel));
            }
        }
    }
    let centre = c + m;
    if !(radius.is_finite() && radius > 0.0 && centre.iter().all(|x| x.is_finite())) {
        return Err(CoreError::Degenerate(format!(
            "sphere fit diverged (radius {radius} mm, polar coverage {:.3} deg): the points \
             do not describe a sphere",
            polar_coverage(pts, &centre, parallel)
        )));
    }
    Ok(Solved {
        centre,
        radius,
        normal: cur,
        n: pts.len(),
        iterations,
        converged,
    })
}

#[cold]
fn stalled(pts: &[Vector3<f64>], centre: &Vector3<f64>, radius: f64, parallel: bool) -> CoreError {
    CoreError::Degenerate(format!(
        "sphere fit did not converge (stalled at radius {radius:.6} mm, polar coverage {:.3} \
         deg): the cap is too small or the points do not describe a sphere",
        polar_coverage(pts, centre, parallel)
    ))
}

/// Half-angle (degrees) of the smallest cone about the points' mean direction
/// from `centre` that contains them all; 180 when the directions cancel.
fn polar_coverage(pts: &[Vector3<f64>], centre: &Vector3<f64>, parallel: bool) -> f64 {
    let unit = |p: &Vector3<f64>| {
        let d = p - centre;
        let n = d.norm();
        if n > 0.0 {
            d / n
        } else {
            d
        }
    };
    let sum = accumulate(
        pts,
        parallel,
        Vector3::zeros,
        |s, p| s + unit(p),
        |a, b| a + b,
    );
    let norm = sum.norm();
    if norm.is_nan() || norm <= 1e-9 * pts.len() as f64 {
        return 180.0;
    }
    let axis = sum / norm;
    let widest = accumulate(
        pts,
        parallel,
        || 0.0f64,
        |w, p| {
            let u = unit(p);
            w.max(u.cross(&axis).norm().atan2(u.dot(&axis)))
        },
        f64::max,
    );
    widest.to_degrees()
}

#[cfg(test)]
mod tests {
    use super::super::testdata::{cap_direction, cap_spiral, flatten, mean_std, Rng};
    use super::*;

    const BALL: f64 = 38.125;

    /// `n` points uniform in area on a cap of half-angle `cap_deg` about
    /// `axis` of the sphere (c, r), with Gaussian noise of `sigma` mm along
    /// the surface normal.
    fn cap(
        c: [f64; 3],
        r: f64,
        axis: [f64; 3],
        cap_deg: f64,
        n: usize,
        sigma: f64,
        seed: u64,
    ) -> Vec<Vector3<f64>> {
        let mut rng = Rng::new(seed);
        let axis = Vector3::from(axis).normalize();
        (0..n)
            .map(|_| {
                let u = cap_direction(&mut rng, &axis, cap_deg);
                Vector3::from(c) + u * (r + sigma * rng.gauss())
            })
            .collect()
    }

    fn err(r: &Result<SphereFit>) -> String {
        r.as_ref().unwrap_err().to_string()
    }

    #[test]
    fn fit_sphere_exact_recovery_full_sphere_and_caps() {
        // Noise-free points: the fit must return the truth to rounding. The
        // 5 degree cap is the worst conditioned (radius and centre along the
        // axis correlate like 1/theta^2 ~ 130), so 1e-9 mm leaves a factor of
        // about 1e3 over the ~1e-12 mm expected from 1e-16 relative rounding
        // of coordinates ~250 mm.
        let c = Vector3::new(101.3, -250.7, 40.2);
        let axis = Vector3::new(0.3, -0.2, 1.0).normalize();
        for cap_deg in [180.0, 5.0, 30.0, 60.0, 85.0, 120.0] {
            let n = 2000;
            let pts: Vec<_> = cap_spiral(&axis, cap_deg, n)
                .into_iter()
                .map(|u| c + u * BALL)
                .collect();
            let f = fit_sphere(&flatten(&pts), &SphereFitOptions::default()).unwrap();
            let dc = (Vector3::from(f.centre) - c).norm();
            assert!(dc < 1e-9, "cap {cap_deg}: centre off by {dc:e} mm");
            assert!(
                (f.radius - BALL).abs() < 1e-9,
                "cap {cap_deg}: radius off by {:e} mm",
                f.radius - BALL
            );
            assert!(f.converged && f.rms < 1e-10 && f.form < 1e-9);
            assert_eq!((f.n_points, f.rejected, f.residuals.len()), (n, 0, n));
            assert!(f.inlier.iter().all(|&i| i));
            // Coverage: the spiral's last point sits half a step inside the
            // rim and its mean direction is the axis to ~1e-3 rad: 0.5 degree.
            // A full sphere's directions nearly cancel, and the cone about the
            // small remainder is nearly 180 degrees.
            if cap_deg < 180.0 {
                assert!(
                    (f.polar_coverage_deg - cap_deg).abs() < 0.5,
                    "cap {cap_deg}: coverage {}",
                    f.polar_coverage_deg
                );
            } else {
                assert!(f.polar_coverage_deg > 175.0, "{}", f.polar_coverage_deg);
            }
        }
    }

    #[test]
    fn fit_sphere_small_ball_far_from_the_origin() {
        // A 1 mm ball 1.7 m from the origin, 10 degree cap, noise-free: the
        // coordinates carry 2e-13 mm of rounding, amplified ~1/theta^2 = 33
        // along the axis, so 1e-9 mm is ample. The fit must end converged,
        // not stall on a cost that is flat to rounding.
        let c = Vector3::new(1000.0, -1000.0, 1000.0);
        let axis = Vector3::new(-1.0, 2.0, 0.5).normalize();
        let pts: Vec<_> = cap_spiral(&axis, 10.0, 300)
            .into_iter()
            .map(|u| c + u)
            .collect();
        for radius in [None, Some(1.0)] {
            let opts = SphereFitOptions {
                radius,
                ..Default::default()
            };
            let f = fit_sphere(&flatten(&pts), &opts).unwrap();
            assert!(f.converged);
            assert!((Vector3::from(f.centre) - c).norm() < 1e-9);
            assert!((f.radius - 1.0).abs() < 1e-9);
        }
    }

    #[test]
    fn fit_sphere_coverage_of_a_hemisphere_ring() {
        // A ring on the equator plus the pole: the cone about the pole axis
        // holding them has a 90 degree half-angle (exact to rounding).
        let mut pts = vec![Vector3::new(0.0, 0.0, 10.0)];
        for k in 0..36 {
            let t = (k as f64 * 10.0f64).to_radians();
            pts.push(Vector3::new(10.0 * t.cos(), 10.0 * t.sin(), 0.0));
            pts.push(Vector3::new(
                10.0 * t.cos() * 0.5f64.sqrt(),
                10.0 * t.sin() * 0.5f64.sqrt(),
                10.0 * 0.5f64.sqrt(),
            ));
        }
        let f = fit_sphere(&flatten(&pts), &SphereFitOptions::default()).unwrap();
        assert!(
            (f.polar_coverage_deg - 90.0).abs() < 1e-9,
            "{}",
            f.polar_coverage_deg
        );
        assert!((f.radius - 10.0).abs() < 1e-12);
    }

    #[test]
    fn fit_sphere_algebraic_start_is_biased_geometric_fit_is_not() {
        // 10,000 points on a 20 degree cap of a 5 mm ball, 8 um Gaussian noise
        // along the normal, 12 seeds. The algebraic (Kasa) radius errs low by
        // a systematic amount many standard errors of the mean; the geometric
        // radius's mean error stays within 3.5 standard errors of zero (the
        // geometric fit's own bias, O(sigma^2 / R) = 1e-5 mm, is far below
        // its scatter).
        let (r, c) = (5.0, [1.0, 2.0, 3.0]);
        let (mut alg, mut geo) = (vec![], vec![]);
        for seed in 0..12 {
            let pts = cap(c, r, [0.0, 0.0, 1.0], 20.0, 10_000, 0.008, 100 + seed);
            let m = mean(&pts, false);
            let q: Vec<_> = pts.iter().map(|p| p - m).collect();
            let (_, ra) = algebraic(&q, false).unwrap();
            alg.push(ra - r);
            let f = fit_sphere(&flatten(&pts), &SphereFitOptions::default()).unwrap();
            geo.push(f.radius - r);
        }
        let (ma, sa) = mean_std(&alg);
        let (mg, sg) = mean_std(&geo);
        let n = (alg.len() as f64).sqrt();
        println!("algebraic radius error {ma:e} +- {sa:e}; geometric {mg:e} +- {sg:e}");
        assert!(ma < -10.0 * sa / n, "algebraic {ma} +- {sa}");
        assert!(mg.abs() < 3.5 * sg / n, "geometric {mg} +- {sg}");
        assert!(ma.abs() > 10.0 * mg.abs());
    }

    /// Points on the spheroid (equatorial a, polar c, axis z, centre 0) in
    /// rings from the pole to polar angle `cap_deg`, 0.2 mm apart along the
    /// meridian and around each ring. The thesis spaced them 0.1 mm; that
    /// takes four times as long here and moves no result by more than 1e-5 mm.
    fn spheroid_cap(a: f64, c: f64, cap_deg: f64) -> Vec<Vector3<f64>> {
        let step = 0.2;
        let rings = (cap_deg.to_radians() * a / step).floor() as usize;
        let mut pts = vec![Vector3::new(0.0, 0.0, c)];
        for k in 1..=rings {
            let t = k as f64 * step / a;
            let (st, ct) = t.sin_cos();
            let r = 1.0 / ((st / a).powi(2) + (ct / c).powi(2)).sqrt();
            let m = (std::f64::consts::TAU * r * st / step).round() as usize;
            for j in 0..m {
                let phi = std::f64::consts::TAU * j as f64 / m as f64;
                pts.push(Vector3::new(st * phi.cos(), st * phi.sin(), ct) * r);
            }
        }
        pts
    }

    #[test]
    fn fit_sphere_thesis_appendix_a_spheroids() {
        // Thesis Appendix A (SPEC.md section 7): caps about the pole of an
        // oblate (38.125 / 38.1225 mm) and a prolate (38.125 / 38.1275 mm)
        // spheroid. The thesis (NIST ATS fit) reports centre z -0.005,
        // -0.004, -0.003 mm (oblate) and +0.005 .. +0.003 (prolate) for 5, 60
        // and 85 degrees, radius 38.128, 38.126, 38.126 (oblate) and about
        // 38.122 .. 38.124 (prolate). Our fit must agree to the thesis's
        // printed 0.001 mm; at 5 degrees the sphere is the osculating one at
        // the pole (radius a^2/c, centre z c - a^2/c) to 1e-4 mm.
        let a = BALL;
        let cases = [
            // (c, cap, thesis centre z, thesis radius)
            (38.1225, 5.0, -0.005, 38.128),
            (38.1225, 60.0, -0.004, 38.126),
            (38.1225, 85.0, -0.003, 38.126),
            (38.1275, 5.0, 0.005, 38.122),
            (38.1275, 60.0, 0.004, 38.124),
            (38.1275, 85.0, 0.003, 38.124),
        ];
        for (c, cap_deg, z_thesis, r_thesis) in cases {
            let pts = spheroid_cap(a, c, cap_deg);
            let f = fit_sphere(&flatten(&pts), &SphereFitOptions::default()).unwrap();
            println!(
                "Appendix A: c = {c} cap {cap_deg:>2} deg ({} points): radius {:.5} mm \
                 (R - 38.125 = {:+.5}), centre z {:+.5} mm, form {:.5} mm",
                pts.len(),
                f.radius,
                f.radius - a,
                f.centre[2],
                f.form
            );
            assert!(f.converged);
            assert!(f.centre[0].abs() < 1e-9 && f.centre[1].abs() < 1e-9);
            assert!((f.centre[2] - z_thesis).abs() <= 0.001, "{}", f.centre[2]);
            assert!((f.radius - r_thesis).abs() <= 0.001, "{}", f.radius);
            if cap_deg == 5.0 {
                assert!((f.radius - a * a / c).abs() < 1e-4);
                assert!((f.centre[2] - (c - a * a / c)).abs() < 1e-4);
            }
        }
    }

    #[test]
    fn fit_sphere_covariance_matches_repeats() {
        // 200 repeats of 2000 points on a 60 degree cap with 8 um noise: the
        // sample standard deviation of each of centre x, y, z and radius
        // agrees with the mean predicted sqrt(diag(covariance)) within 20 %
        // (the standard deviation of 200 samples has ~5 % relative standard
        // error, so 20 % is four of them).
        let c = [5.0, -3.0, 12.0];
        let mut est: [Vec<f64>; 4] = Default::default();
        let mut pred = [0.0; 4];
        for seed in 0..200 {
            let pts = cap(c, BALL, [0.0, 1.0, 1.0], 60.0, 2000, 0.008, 1000 + seed);
            let f = fit_sphere(&flatten(&pts), &SphereFitOptions::default()).unwrap();
            for k in 0..4 {
                est[k].push(if k < 3 { f.centre[k] } else { f.radius });
                pred[k] += f.covariance[k][k].sqrt() / 200.0;
            }
            // Symmetric, and the radius anticorrelated with the centre along
            // the cap axis (y + z here).
            assert_eq!(f.covariance[1][3], f.covariance[3][1]);
            assert!(f.covariance[1][3] + f.covariance[2][3] < 0.0);
        }
        for k in 0..4 {
            let (_, sd) = mean_std(&est[k]);
            println!(
                "parameter {k}: sd {sd:.3e} mm, predicted {:.3e} mm",
                pred[k]
            );
            assert!(
                (sd / pred[k] - 1.0).abs() < 0.2,
                "parameter {k}: {sd} vs {}",
                pred[k]
            );
        }
    }

    #[test]
    fn fit_sphere_fixed_radius() {
        let c = Vector3::new(1.0, 2.0, 3.0);
        let axis = Vector3::new(1.0, 0.0, 1.0).normalize();
        // Noise-free: exact to rounding (1e-9 mm as for the free fit).
        let pts: Vec<_> = cap_spiral(&axis, 30.0, 500)
            .into_iter()
            .map(|u| c + u * BALL)
            .collect();
        let opts = SphereFitOptions {
            radius: Some(BALL),
            ..Default::default()
        };
        let f = fit_sphere(&flatten(&pts), &opts).unwrap();
        assert!((Vector3::from(f.centre) - c).norm() < 1e-9);
        assert_eq!(f.radius, BALL);
        // The radius row and column of the covariance are zero.
        assert!((0..4).all(|k| f.covariance[3][k] == 0.0 && f.covariance[k][3] == 0.0));
        // A radius 0.01 mm too large on a 5 degree cap: the sphere keeps the
        // cap's apex, so the centre moves 0.01 mm back along the axis (to
        // O(0.01 theta^2) ~ 1e-4 mm).
        let pts: Vec<_> = cap_spiral(&axis, 5.0, 500)
            .into_iter()
            .map(|u| c + u * BALL)
            .collect();
        let opts = SphereFitOptions {
            radius: Some(BALL + 0.01),
            ..Default::default()
        };
        let f = fit_sphere(&flatten(&pts), &opts).unwrap();
        assert!((Vector3::from(f.centre) - (c - axis * 0.01)).norm() < 1e-4);
        // Noisy (8 um) 30 degree cap: the fixed-radius centre is within 4
        // predicted sigma of the truth, and tighter along the axis than the
        // free fit's (knowing R removes the centre-radius correlation).
        let noisy = flatten(&cap(c.into(), BALL, axis.into(), 30.0, 3000, 0.008, 5));
        let opts = SphereFitOptions {
            radius: Some(BALL),
            ..Default::default()
        };
        let fixed = fit_sphere(&noisy, &opts).unwrap();
        let free = fit_sphere(&noisy, &SphereFitOptions::default()).unwrap();
        for k in 0..3 {
            let sd = fixed.covariance[k][k].sqrt();
            assert!((fixed.centre[k] - c[k]).abs() < 4.0 * sd);
        }
        let along = |cov: &[[f64; 4]; 4]| {
            (0..3)
                .flat_map(|i| (0..3).map(move |j| (i, j)))
                .map(|(i, j)| axis[i] * cov[i][j] * axis[j])
                .sum::<f64>()
        };
        assert!(along(&fixed.covariance) < 0.1 * along(&free.covariance));
    }

    #[test]
    fn fit_sphere_rejects_a_stand() {
        // 5000 points on an 85 degree cap of the ball (8 um noise) plus 300
        // on the cylindrical stand below it (radius 10 mm, 40 to 60 mm below
        // the centre, 3.1 mm or more outside the sphere). With k = 4 exactly the
        // stand goes (a Gaussian exceeds 4 sigma with probability 6e-5, so
        // at most a point or two of the ball) and the ball comes back to
        // within 4 predicted sigma (sqrt(diag(covariance)), ~0.3 um).
        let c = Vector3::new(-20.0, 35.0, 10.0);
        let mut pts = cap(c.into(), BALL, [0.0, 0.0, 1.0], 85.0, 5000, 0.008, 9);
        let mut rng = Rng::new(99);
        for _ in 0..300 {
            let phi = std::f64::consts::TAU * rng.uniform();
            let z = -40.0 - 20.0 * rng.uniform();
            let r = 10.0 + 0.008 * rng.gauss();
            pts.push(c + Vector3::new(r * phi.cos(), r * phi.sin(), z));
        }
        let flat = flatten(&pts);
        let plain = fit_sphere(&flat, &SphereFitOptions::default()).unwrap();
        assert!(
            (Vector3::from(plain.centre) - c).norm() > 0.1,
            "the stand should spoil it"
        );
        let opts = SphereFitOptions {
            reject: Some(4.0),
            ..Default::default()
        };
        let f = fit_sphere(&flat, &opts).unwrap();
        assert!(f.inlier[5000..].iter().all(|&i| !i));
        assert!((300..=302).contains(&f.rejected), "{}", f.rejected);
        assert_eq!(f.n_points, 5300 - f.rejected);
        assert_eq!(f.residuals.len(), 5300);
        assert!(f.residuals[5000..].iter().all(|&r| r > 3.0));
        for k in 0..3 {
            let sd = f.covariance[k][k].sqrt();
            assert!(sd < 1e-3 && (f.centre[k] - c[k]).abs() < 4.0 * sd, "{k}");
        }
        assert!((f.radius - BALL).abs() < 4.0 * f.covariance[3][3].sqrt());
        assert!((f.rms / 0.008 - 1.0).abs() < 0.05);
        assert!((f.polar_coverage_deg - 85.0).abs() < 2.0);
    }

    #[test]
    fn fit_spheres_equals_individual_fits() {
        // Same code path, serial inside each fit: equal to the last bit.
        let a = flatten(&cap([0.0; 3], 10.0, [0.0, 0.0, 1.0], 60.0, 800, 0.005, 1));
        let b = flatten(&cap(
            [100.0, 0.0, 5.0],
            BALL,
            [1.0, 0.0, 0.0],
            85.0,
            3000,
            0.008,
            2,
        ));
        let bad: Vec<f64> = (0..5).flat_map(|i| [i as f64, 0.0, 0.0]).collect();
        let d = flatten(&cap(
            [0.0, 50.0, 0.0],
            5.0,
            [0.0, 1.0, 1.0],
            120.0,
            100,
            0.001,
            3,
        ));
        let sets: Vec<&[f64]> = vec![&a, &b, &bad, &d];
        let opts = SphereFitOptions {
            reject: Some(3.0),
            ..Default::default()
        };
        let many = fit_spheres(&sets, &opts);
        assert_eq!(many.len(), 4);
        for (set, got) in sets.iter().zip(&many) {
            assert_eq!(got, &fit_sphere(set, &opts));
        }
        assert!(many[2].is_err());
    }

    #[test]
    fn fit_sphere_parallel_pass_matches_serial() {
        // 50,000 points take the rayon fold/reduce; only the summation order
        // differs, so the same minimum to rounding (1e-12 mm).
        let pts = flatten(&cap(
            [1.0, 2.0, 3.0],
            BALL,
            [0.0, 0.0, 1.0],
            70.0,
            50_000,
            0.008,
            4,
        ));
        let par = fit_sphere(&pts, &SphereFitOptions::default()).unwrap();
        let ser = fit(&pts, &SphereFitOptions::default(), false).unwrap();
        for k in 0..3 {
            assert!((par.centre[k] - ser.centre[k]).abs() < 1e-12);
        }
        assert!((par.radius - ser.radius).abs() < 1e-12);
        assert!((par.rms - ser.rms).abs() < 1e-12);
    }

    #[test]
    fn fit_sphere_iteration_cap_reports_not_converged() {
        // A noisy 10 degree cap: the algebraic start is biased, one step is
        // not enough; the default cap converges in a few.
        let pts = flatten(&cap([0.0; 3], BALL, [0.0, 0.0, 1.0], 10.0, 5000, 0.008, 6));
        let one = SphereFitOptions {
            max_iterations: 1,
            ..Default::default()
        };
        let f = fit_sphere(&pts, &one).unwrap();
        assert_eq!((f.iterations, f.converged), (1, false));
        let f = fit_sphere(&pts, &SphereFitOptions::default()).unwrap();
        assert!(f.converged && f.iterations < 10, "{}", f.iterations);
    }

    #[test]
    fn fit_sphere_errors() {
        let o = SphereFitOptions::default();
        let fixed = SphereFitOptions {
            radius: Some(10.0),
            ..o
        };
        let tetra = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        // Too few points.
        assert_eq!(
            err(&fit_sphere(&tetra[..9], &o)),
            "points: a sphere needs at least 4 points, got 3"
        );
        assert_eq!(
            err(&fit_sphere(&tetra[..6], &fixed)),
            "points: a sphere of fixed radius needs at least 3 points, got 2"
        );
        assert!(err(&fit_sphere(&tetra[..10], &o)).contains("not a multiple of 3"));
        // Non-finite: the first bad row is named.
        let mut bad = tetra.to_vec();
        bad[7] = f64::NAN;
        bad[11] = f64::INFINITY;
        assert_eq!(
            err(&fit_sphere(&bad, &o)),
            "points: non-finite value (NaN or inf) in row 2"
        );
        // Coplanar (a circle), collinear, coincident; three points with a
        // fixed radius are always coplanar (two mirror-image centres).
        let circle: Vec<f64> = (0..12)
            .flat_map(|k| {
                let t = k as f64 * 0.5;
                [5.0 * t.cos(), 5.0 * t.sin(), 1.0]
            })
            .collect();
        for opts in [&o, &fixed] {
            let e = fit_sphere(&circle, opts).unwrap_err();
            assert!(matches!(e, CoreError::Degenerate(_)));
            assert_eq!(e.to_string(), "points are coplanar: no unique sphere");
        }
        assert_eq!(
            err(&fit_sphere(&tetra[..9], &fixed)),
            "points are coplanar: no unique sphere"
        );
        let line: Vec<f64> = (0..6)
            .flat_map(|i| [i as f64, 1.0, -2.0 * i as f64])
            .collect();
        assert_eq!(
            err(&fit_sphere(&line, &o)),
            "points are collinear: no unique sphere"
        );
        assert_eq!(
            err(&fit_sphere(&[3.0; 15], &o)),
            "all points coincide: no unique sphere"
        );
        // A 1 degree cap is below the default 2 degree minimum...
        let small = flatten(
            &cap_spiral(&Vector3::z(), 1.0, 400)
                .into_iter()
                .map(|u| u * BALL)
                .collect::<Vec<_>>(),
        );
        let e = fit_sphere(&small, &o).unwrap_err();
        assert!(matches!(e, CoreError::Degenerate(_)));
        assert!(e.to_string().starts_with("polar coverage 0.99"), "{e}");
        // ... and fits (noise-free) when the minimum is lowered.
        let f = fit_sphere(
            &small,
            &SphereFitOptions {
                min_coverage_deg: 0.5,
                ..o
            },
        )
        .unwrap();
        assert!((f.radius - BALL).abs() < 1e-6);
        // A noisy flat patch is no sphere: whatever the fit does, the error
        // is Degenerate and names the polar coverage.
        let mut rng = Rng::new(8);
        let patch: Vec<f64> = (0..2000)
            .flat_map(|_| {
                let (x, y) = (20.0 * rng.uniform(), 20.0 * rng.uniform());
                [x, y, 0.008 * rng.gauss()]
            })
            .collect();
        let e = fit_sphere(&patch, &o).unwrap_err();
        assert!(matches!(e, CoreError::Degenerate(_)), "{e}");
        assert!(e.to_string().contains("polar coverage"), "{e}");
        // Rejection that leaves too few points.
        let noisy = flatten(&cap([0.0; 3], BALL, [0.0, 0.0, 1.0], 60.0, 100, 0.008, 7));
        let e = fit_sphere(
            &noisy,
            &SphereFitOptions {
                reject: Some(0.01),
                ..o
            },
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("fewer than the 4 the fit needs"),
            "{e}"
        );
        // Bad options.
        let cases = [
            (
                SphereFitOptions {
                    radius: Some(-1.0),
                    ..o
                },
                "radius: ",
            ),
            (
                SphereFitOptions {
                    radius: Some(f64::NAN),
                    ..o
                },
                "radius: ",
            ),
            (
                SphereFitOptions {
                    reject: Some(0.0),
                    ..o
                },
                "reject: ",
            ),
            (
                SphereFitOptions {
                    max_iterations: 0,
                    ..o
                },
                "max_iterations: ",
            ),
            (
                SphereFitOptions {
                    min_coverage_deg: 181.0,
                    ..o
                },
                "min_coverage_deg: ",
            ),
            (
                SphereFitOptions {
                    min_coverage_deg: f64::NAN,
                    ..o
                },
                "min_coverage_deg: ",
            ),
        ];
        for (opts, start) in cases {
            let e = fit_sphere(&tetra, &opts).unwrap_err();
            assert!(matches!(e, CoreError::InvalidArgument { .. }));
            assert!(e.to_string().starts_with(start), "{e}");
        }
        // Exactly 4 points fit, but leave no degrees of freedom for s^2.
        let f = fit_sphere(&tetra, &o).unwrap();
        assert!((Vector3::from(f.centre) - Vector3::repeat(0.5)).norm() < 1e-12);
        assert!(f.covariance[0][0].is_nan());
    }
}
