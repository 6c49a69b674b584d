//! Sphere by orthogonal (geometric) least squares: minimise the sum of
//! squared residuals r_i = |p_i - c| - R over the centre c and radius R.
//!
//! 1. Centre the points on their mean (conditioning): one pass sums the
//!    points (a NaN or infinity shows in the sums), a second (for the
//!    algebraic start only) their moments about the mean. Refuse coincident, collinear or coplanar points (no
//!    unique sphere).
//! 2. Algebraic start: linear least squares of |q|^2 + a.q + d = 0. With
//!    centred q the normal equations split into S a = -sum q |q|^2 (S the
//!    scatter matrix) and d = -mean |q|^2; then c = -a/2, R^2 = |c|^2 - d.
//!    This start is biased on noisy partial caps, the geometric fit is not.
//! 3. Gauss-Newton on the geometric residuals, analytic Jacobian
//!    dr/dc = -(p - c)/|p - c|, dr/dR = -1, with Levenberg-Marquardt damping
//!    (Marquardt's diagonal scaling) switched on after a step that fails to
//!    lower the cost and off again as steps succeed. The parameters are kept
//!    relative to the mean. Each trial step takes one pass over the points,
//!    which yields the cost and J^T J, J^T r at the trial point together, and
//!    also writes the residuals there, with their extremes and the polar
//!    coverage, so an accepted last step needs no further pass. Converged
//!    when the undamped step is below 1e-12 of the radius, or it or an
//!    accepted step lowers the cost by less than 1e-15 of it, or the
//!    residuals' RMS is below 1e-14 of the radius (noise-free points), or
//!    when damping has shrunk a failing step below 1e-12 of the radius (the
//!    cost is flat to rounding); `converged = false` when `max_iterations`
//!    steps ran out first. A fit whose normal equations stay singular, or
//!    whose radius leaves (0, inf), is a `Degenerate` error.
//! 4. Polar coverage of the inliers seen from the fitted centre
//!    ([`SphereFit::polar_coverage_deg`]); a cap below `min_coverage_deg` is
//!    a `Degenerate` error.
//!
//! [`Start`] replaces step 2 by a given centre, or by the least-median
//! sphere of [`super::lmeds`] (the fit then uses its inliers only); a
//! [`super::Rejection`] rule refits from the previous solution
//! (docs/fitting.md).
//!
//! With a fixed radius only the centre is fitted (3 x 3 normal equations).
//! Coplanar points are refused with a fixed radius too: the two mirror-image
//! centres on either side of the plane fit them equally well. (Three points
//! are always coplanar, so a fixed-radius fit needs four in practice; fewer
//! than three is refused as too few.)
//!
//! The passes read the N x 3 points where they are (no copy) [`LANES`] at a
//! time, and keep [`LANES`] independent partial sums (and minima, maxima) of
//! every quantity, added up in a fixed order at the end, so that they run
//! on SIMD vectors and the result does not depend on the instruction set: on
//! x86-64 with AVX when the CPU has it (detected at run time by
//! multiversion, as for the compensation kernel) and SSE2 otherwise, bit for
//! bit the same.

use std::borrow::Cow;

use multiversion::{multiversion, target::match_target};
use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};
use rayon::prelude::*;

use super::lmeds::{self, LeastMedian};
#[cfg(test)]
use super::mean;
use super::{
    check_rejection, check_rows, non_finite, reclassify, rms_and_form, select_rows, sorted_eigen,
    spread_rank, too_few_inliers, Rejection, CHUNK, PARALLEL_MIN_POINTS,
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
/// The polar coverage is 180 degrees when the points' mean is closer to the
/// centre than this times the radius (no axis to measure it about).
const AXIS_FLOOR: f64 = 1e-9;

/// Points per SIMD block, and independent partial sums of every quantity.
const LANES: usize = 4;
/// Coordinates of a block of points.
const BLOCK: usize = 3 * LANES;
/// Blocks per group in [`moments_rows`] and [`evaluate_rows`].
const GROUP: usize = 64;

/// Where the geometric fit starts (docs/fitting.md).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Start {
    /// The algebraic sphere of all the points (module docs, step 2).
    #[default]
    Algebraic,
    /// A given centre (mm); with a free radius the start radius is the mean
    /// distance of the points from it.
    Centre([f64; 3]),
    /// The high-breakdown least-median-of-squares sphere ([`super::lmeds`]):
    /// the least-squares fit starts from it, on its inliers only.
    LeastMedian(LeastMedian),
}

/// How to fit a sphere. `Default` gives a free radius, the algebraic start,
/// no rejection, 100 iterations and a 2 degree minimum polar coverage.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SphereFitOptions {
    /// Fix the radius (mm) and fit only the centre.
    pub radius: Option<f64>,
    /// Outlier rejection rule ([`crate::fit`] module docs); its multiple
    /// must be positive (3 to 5 is usual).
    pub reject: Option<Rejection>,
    /// Where the fit starts.
    pub start: Start,
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
            start: Start::Algebraic,
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
    /// Half-angle (degrees, 0..=180) of the smallest cone with its apex at
    /// the centre, about the axis from the centre through the inliers' mean
    /// (centroid), that holds all the inliers: the arccos of the smallest
    /// cosine between that axis and a point's direction from the centre.
    /// 180 when the mean is within 1e-9 of the radius of the centre (a
    /// full sphere's points have no axis). A cap uniform about its axis gives
    /// its half-angle, a hemisphere 90 degrees.
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
/// fixed radius), a non-finite coordinate (naming the first bad row) or
/// coordinates so large (~1e308 / N) that their sum overflows;
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
    if let Err(e) = check_many(opts) {
        return sets.iter().map(|_| Err(e.clone())).collect();
    }
    sets.par_iter().map(|s| fit(s, opts, false)).collect()
}

/// A starting centre belongs to one sphere: refused for many.
fn check_many(opts: &SphereFitOptions) -> Result<()> {
    if let Start::Centre(_) = opts.start {
        return Err(CoreError::invalid_argument(
            "start",
            "a starting centre belongs to one sphere; fits of many spheres start from the \
             algebraic or the least-median (high-breakdown) sphere",
        ));
    }
    Ok(())
}

/// Sphere fits of many groups of points, one entry per group in each field
/// (columns, in the order of the groups), and the per-point fields for all
/// points in input order. A group that could not be fitted has its error in
/// [`SphereFits::error`], NaN in the float fields, zero counts,
/// `converged = false`, and NaN residuals and `false` inlier flags for its
/// points. Each field means what it does in [`SphereFit`].
#[derive(Debug, Clone, Default)]
pub struct SphereFits {
    /// Centre of each sphere (mm).
    pub centre: Vec<[f64; 3]>,
    /// Radius (mm); the given one when it was fixed.
    pub radius: Vec<f64>,
    /// Root mean square of the inliers' residuals (mm).
    pub rms: Vec<f64>,
    /// Largest minus smallest inlier residual (mm).
    pub form: Vec<f64>,
    /// Points fitted (the inliers).
    pub n_points: Vec<usize>,
    /// Covariance of (centre x, y, z, radius), mm^2.
    pub covariance: Vec<[[f64; 4]; 4]>,
    /// Polar coverage of the inliers (degrees, 0..=180).
    pub polar_coverage_deg: Vec<f64>,
    /// Levenberg-Marquardt steps of the final fit.
    pub iterations: Vec<usize>,
    /// `false` when `max_iterations` stopped a fit still improving, or the
    /// group failed.
    pub converged: Vec<bool>,
    /// Points rejected as outliers.
    pub rejected: Vec<usize>,
    /// Why each group could not be fitted; `None` for a fitted one.
    pub error: Vec<Option<CoreError>>,
    /// Signed residual |p - c| - R of every input point (mm, input order).
    pub residuals: Vec<f64>,
    /// Whether each input point was used in its group's final fit.
    pub inlier: Vec<bool>,
}

/// Fits one sphere to each group of `points` (N x 3 row-major, mm), the
/// groups being the runs of rows `bounds[k]..bounds[k + 1]` (`bounds` rises
/// from 0 to N), in parallel over the groups (each fit serial, as in
/// [`fit_spheres`]: entry k equals `fit_sphere` on group k, bit for bit below
/// [`super::PARALLEL_MIN_POINTS`] points).
///
/// Errors: `InvalidArgument` for a bad option, or `points` or `bounds` of
/// the wrong shape. A group that cannot be fitted does not stop the others:
/// its error is in [`SphereFits::error`].
pub fn fit_sphere_groups(
    points: &[f64],
    bounds: &[usize],
    opts: &SphereFitOptions,
) -> Result<SphereFits> {
    check_options(opts)?;
    check_many(opts)?;
    let n = check_rows(points, 0, "a set of spheres")?;
    if bounds.first() != Some(&0)
        || bounds.last() != Some(&n)
        || bounds.windows(2).any(|w| w[1] < w[0])
    {
        return Err(CoreError::invalid_argument(
            "bounds",
            format!("must rise from 0 to the number of points ({n})"),
        ));
    }
    let k = bounds.len() - 1;
    // Each group's fit writes its residuals and inlier flags straight into
    // its own part of the output, so nothing per point is copied twice.
    let mut residuals = vec![f64::NAN; n];
    let mut inlier = vec![false; n];
    let mut parts = Vec::with_capacity(k);
    let (mut res_rest, mut inl_rest) = (residuals.as_mut_slice(), inlier.as_mut_slice());
    for w in bounds.windows(2) {
        let len = w[1] - w[0];
        let (r, rr) = std::mem::take(&mut res_rest).split_at_mut(len);
        let (i, ir) = std::mem::take(&mut inl_rest).split_at_mut(len);
        (res_rest, inl_rest) = (rr, ir);
        parts.push((&points[3 * w[0]..3 * w[1]], r, i));
    }
    let fits: Vec<Result<SphereFit>> = parts
        .into_par_iter()
        .map(|(set, res, inl)| {
            let mut f = fit(set, opts, false)?;
            res.copy_from_slice(&f.residuals);
            inl.copy_from_slice(&f.inlier);
            // Already copied out: free the group's vectors here, in parallel.
            f.residuals = Vec::new();
            f.inlier = Vec::new();
            Ok(f)
        })
        .collect();
    let mut out = SphereFits {
        residuals,
        inlier,
        ..SphereFits::default()
    };
    for r in fits {
        let (f, e) = match r {
            Ok(f) => (f, None),
            Err(e) => (failed_fit(), Some(e)),
        };
        out.centre.push(f.centre);
        out.radius.push(f.radius);
        out.rms.push(f.rms);
        out.form.push(f.form);
        out.n_points.push(f.n_points);
        out.covariance.push(f.covariance);
        out.polar_coverage_deg.push(f.polar_coverage_deg);
        out.iterations.push(f.iterations);
        out.converged.push(f.converged);
        out.rejected.push(f.rejected);
        out.error.push(e);
    }
    Ok(out)
}

/// The fields of a group that could not be fitted: NaN, zero, `false`.
fn failed_fit() -> SphereFit {
    SphereFit {
        centre: [f64::NAN; 3],
        radius: f64::NAN,
        residuals: Vec::new(),
        inlier: Vec::new(),
        rms: f64::NAN,
        form: f64::NAN,
        n_points: 0,
        covariance: [[f64::NAN; 4]; 4],
        polar_coverage_deg: f64::NAN,
        iterations: 0,
        converged: false,
        rejected: 0,
    }
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
    check_rejection(opts.reject)?;
    match opts.start {
        Start::Centre(c) if !c.iter().all(|x| x.is_finite()) => {
            return Err(CoreError::invalid_argument(
                "start",
                format!("a starting centre must be finite (mm), got {c:?}"),
            ));
        }
        Start::LeastMedian(lm) => lmeds::check(&lm)?,
        _ => {}
    }
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

pub(crate) fn fit(points: &[f64], opts: &SphereFitOptions, parallel: bool) -> Result<SphereFit> {
    check_options(opts)?;
    let (min, what) = match opts.radius {
        Some(_) => (3, "a sphere of fixed radius"),
        None => (4, "a sphere"),
    };
    let n = check_rows(points, min, what)?;
    let cloud = Cloud::new(Cow::Borrowed(points), parallel).map_err(|()| {
        non_finite(points).unwrap_or_else(|| {
            CoreError::invalid_argument("points", "coordinates too large to average")
        })
    })?;
    let mut residuals = vec![0.0; n];
    let mut inlier = vec![true; n];
    // Whether `residuals` came from the pass that gave `s` its sums.
    let mut same_pass = true;
    let mut s = match opts.start {
        Start::Algebraic => solve(&cloud, opts, None, parallel, &mut residuals)?,
        Start::Centre(c) => {
            let c = Vector3::from(c);
            let r = opts
                .radius
                .unwrap_or_else(|| cloud.mean_distance(&c, parallel));
            solve(
                &cloud,
                opts,
                Some((c - cloud.mean, r)),
                parallel,
                &mut residuals,
            )?
        }
        Start::LeastMedian(lm) => {
            let m = lmeds::median_fit(points, opts.radius, &lm, parallel)?;
            if m.kept < min {
                return Err(CoreError::Degenerate(format!(
                    "high-breakdown start: {} of {n} points within 2.5 robust scales \
                     ({:.3e} mm) of the least-median sphere, fewer than the {min} the fit needs",
                    m.kept, m.scale
                )));
            }
            inlier = m.inlier;
            let sub = cloud.subset(&inlier, parallel);
            let init = (m.centre - sub.mean, m.radius);
            let mut scratch = vec![0.0; sub.n];
            let s = solve(&sub, opts, Some(init), parallel, &mut scratch)?;
            if sub.n < n {
                let t = Trial::new(&s.centre, s.radius, &(cloud.mean - s.centre));
                evaluate(&cloud, &t, parallel, &mut residuals);
                same_pass = false;
            } else {
                residuals = scratch;
            }
            s
        }
    };
    if let Some(rule) = opts.reject {
        for _ in 0..rule.rounds() {
            let (next, sigma) = reclassify(&residuals, &inlier, &rule, SIGMA_FLOOR * s.radius);
            if next == inlier {
                break;
            }
            let kept = next.iter().filter(|&&i| i).count();
            if kept < min {
                return Err(too_few_inliers(&rule, sigma, kept, n, min));
            }
            inlier = next;
            let sub = cloud.subset(&inlier, parallel);
            let mut scratch = vec![0.0; kept];
            // From where the previous fit ended.
            let init = (s.centre - sub.mean, s.radius);
            s = solve(&sub, opts, Some(init), parallel, &mut scratch)?;
            // Residuals of every point.
            let t = Trial::new(&s.centre, s.radius, &(cloud.mean - s.centre));
            evaluate(&cloud, &t, parallel, &mut residuals);
            same_pass = false;
        }
    }
    let rejected = inlier.iter().filter(|&&i| !i).count();
    let coverage = s.coverage;
    if coverage < opts.min_coverage_deg {
        return Err(CoreError::Degenerate(format!(
            "polar coverage {coverage:.3} deg is below min_coverage_deg = {} deg: the cap is \
             too small to fit a sphere (fitted radius {:.6} mm)",
            opts.min_coverage_deg, s.radius
        )));
    }
    let (rms, form) = if same_pass {
        // All points are inliers, and the pass that wrote their residuals
        // summed their squares and found their extremes.
        ((s.normal.cost / n as f64).sqrt(), s.hi - s.lo)
    } else {
        rms_and_form(&residuals, &inlier)
    };
    Ok(SphereFit {
        centre: s.centre.into(),
        radius: s.radius,
        covariance: s.covariance(opts.radius.is_some()),
        residuals,
        inlier,
        rms,
        form,
        n_points: s.n,
        polar_coverage_deg: coverage,
        iterations: s.iterations,
        converged: s.converged,
        rejected,
    })
}

/// One geometric fit to all of a cloud.
#[derive(Debug, Clone)]
struct Solved {
    centre: Vector3<f64>,
    radius: f64,
    /// Normal equations at the solution (undamped).
    normal: Normal,
    /// Smallest and largest residual.
    lo: f64,
    hi: f64,
    /// Polar coverage (degrees).
    coverage: f64,
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
/// parameters (c_x, c_y, c_z, R).
#[derive(Debug, Clone, Copy, Default)]
struct Normal {
    a: [f64; 10],
    g: [f64; 4],
    cost: f64,
}

impl Normal {
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

/// The algebraic start in centred coordinates from the moments of `n`
/// centred points: centre and radius.
fn algebraic_start(m: &Moments, n: usize) -> Result<(Vector3<f64>, f64)> {
    let (values, vectors) = sorted_eigen(m.s);
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
            let w = vectors.transpose() * m.b;
            let w = Vector3::new(w.x / values[0], w.y / values[1], w.z / values[2]);
            let centre = vectors * w * 0.5;
            let r2 = centre.norm_squared() + m.s.trace() / n as f64;
            Ok((centre, r2.max(0.0).sqrt()))
        }
    }
}

/// The algebraic start of the centred points `q`: centre and radius.
#[cfg(test)]
fn algebraic(q: &[Vector3<f64>], _parallel: bool) -> Result<(Vector3<f64>, f64)> {
    let (s, b) = q
        .iter()
        .fold((Matrix3::zeros(), Vector3::zeros()), |(s, b), p| {
            (s + p * p.transpose(), b + p * p.norm_squared())
        });
    algebraic_start(&Moments { s, b }, q.len())
}

/// The geometric fit of one cloud, from `init` (centre relative to the
/// cloud's mean, radius; the fixed radius wins) or else the algebraic start;
/// `res` receives the residuals at the solution.
fn solve(
    cloud: &Cloud,
    opts: &SphereFitOptions,
    init: Option<(Vector3<f64>, f64)>,
    parallel: bool,
    res: &mut [f64],
) -> Result<Solved> {
    let (fixed, max_iterations) = (opts.radius, opts.max_iterations);
    let n = cloud.n;
    let (mut c, mut radius) = match init {
        // A given start: the fixed radius wins.
        Some((c, r)) => (c, fixed.unwrap_or(r)),
        None => {
            let (mut c, r0) = algebraic_start(&cloud.moments(parallel), n)?;
            match fixed {
                Some(rf) => {
                    // Keep the apex of the cap where the algebraic sphere puts
                    // it: move the centre along the cap axis (centre -> mean)
                    // by the radius change.
                    let dist = c.norm();
                    if dist > 0.1 * r0 {
                        c += c / dist * (rf - r0);
                    }
                    (c, rf)
                }
                None => (c, r0),
            }
        }
    };
    let fixed_r = fixed.is_some();
    // The parameters are relative to the mean; the passes evaluate the
    // sphere about mean + c.
    let trial = |c: &Vector3<f64>, radius: f64| Trial::new(&(cloud.mean + c), radius, &-c);
    let mut cur = evaluate(cloud, &trial(&c, radius), parallel, res);
    // Whether `res` holds the residuals at (c, radius) (not a failed trial's).
    let mut res_current = true;
    // Pure Gauss-Newton while it works; damping only after a failed step.
    let mut lambda = 0.0;
    let mut iterations = 0;
    let mut converged = false;
    loop {
        // Converged when the undamped step is negligible, or would lower the
        // cost negligibly, or the residuals are at rounding level already.
        let normal = &cur.normal;
        if normal.cost <= n as f64 * (RMS_FLOOR * radius).powi(2) {
            converged = true;
            break;
        }
        let gauss_newton = normal.step(0.0, fixed_r);
        if let Some(d) = gauss_newton {
            if d.norm() <= STEP_TOL * radius.abs() || normal.predicted(&d) <= COST_TOL * normal.cost
            {
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
            normal.step(lambda, fixed_r)
        };
        let accepted = match step {
            Some(d) => {
                iterations += 1;
                let (c_try, r_try) = (c + d.fixed_rows::<3>(0), radius + d[3]);
                let next = evaluate(cloud, &trial(&c_try, r_try), parallel, res);
                res_current = next.normal.cost <= cur.normal.cost;
                if res_current {
                    let small = cur.normal.cost - next.normal.cost <= COST_TOL * cur.normal.cost;
                    (c, radius, cur) = (c_try, r_try, next);
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
                return Err(stalled(cloud, &trial(&c, radius), parallel));
            }
        }
    }
    let t = trial(&c, radius);
    if !(radius.is_finite() && radius > 0.0 && t.c.iter().all(|x| x.is_finite())) {
        return Err(CoreError::Degenerate(format!(
            "sphere fit diverged (radius {radius} mm, polar coverage {:.3} deg): the points \
             do not describe a sphere",
            coverage(cloud, &t, parallel)
        )));
    }
    if !res_current {
        // The same pass as the one that gave `cur`, so the same numbers.
        cur = evaluate(cloud, &t, parallel, res);
    }
    Ok(Solved {
        centre: Vector3::from(t.c),
        radius,
        normal: cur.normal,
        lo: cur.lo,
        hi: cur.hi,
        coverage: cur.coverage,
        n,
        iterations,
        converged,
    })
}

/// Polar coverage (degrees) of `cloud` seen from the centre of `t`.
#[cold]
fn coverage(cloud: &Cloud, t: &Trial, parallel: bool) -> f64 {
    evaluate(cloud, t, parallel, &mut vec![0.0; cloud.n]).coverage
}

#[cold]
fn stalled(cloud: &Cloud, t: &Trial, parallel: bool) -> CoreError {
    CoreError::Degenerate(format!(
        "sphere fit did not converge (stalled at radius {:.6} mm, polar coverage {:.3} deg): \
         the cap is too small or the points do not describe a sphere",
        t.radius,
        coverage(cloud, t, parallel)
    ))
}

/// Points (N x 3 row-major, mm) with their mean.
struct Cloud<'a> {
    rows: Cow<'a, [f64]>,
    n: usize,
    mean: Vector3<f64>,
}

/// Scatter matrix S = sum q q^T and b = sum q |q|^2 of centred points q.
#[derive(Debug, Clone, Copy)]
struct Moments {
    s: Matrix3<f64>,
    b: Vector3<f64>,
}

impl<'a> Cloud<'a> {
    /// One pass: the sums of the coordinates. `Err` when a sum is not
    /// finite: a NaN or infinite coordinate (or an overflow).
    fn new(rows: Cow<'a, [f64]>, parallel: bool) -> std::result::Result<Cloud<'a>, ()> {
        let n = rows.len() / 3;
        let parallel = parallel && n > PARALLEL_MIN_POINTS;
        let sum = fold_rows(&rows, parallel, sum_chunk, |a, b| {
            [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
        });
        // A NaN or an infinity anywhere makes its coordinate's sum NaN or
        // infinite.
        if !sum.iter().all(|s| s.is_finite()) {
            return Err(());
        }
        let mean = Vector3::from(sum) / n as f64;
        Ok(Cloud { rows, n, mean })
    }

    /// The moments about the mean (a second pass), for the algebraic start
    /// only: a fit from a given start (refits, the least-median start, a
    /// starting centre, segmentation rounds) does not need them.
    fn moments(&self, parallel: bool) -> Moments {
        let m = [self.mean.x, self.mean.y, self.mean.z];
        let parallel = parallel && self.n > PARALLEL_MIN_POINTS;
        fold_rows(
            &self.rows,
            parallel,
            |r| moments_chunk(r, &m),
            MomentSums::merge,
        )
        .total()
    }

    /// Mean distance (mm) of the points from `c`: one pass.
    fn mean_distance(&self, c: &Vector3<f64>, parallel: bool) -> f64 {
        let dist = |rows: &[f64]| -> f64 {
            rows.chunks_exact(3)
                .map(|p| {
                    ((p[0] - c.x).powi(2) + (p[1] - c.y).powi(2) + (p[2] - c.z).powi(2)).sqrt()
                })
                .sum()
        };
        fold_rows(
            &self.rows,
            parallel && self.n > PARALLEL_MIN_POINTS,
            dist,
            |a, b| a + b,
        ) / self.n as f64
    }

    /// The cloud of the points where `keep`.
    fn subset(&self, keep: &[bool], parallel: bool) -> Cloud<'static> {
        Cloud::new(Cow::Owned(select_rows(&self.rows, keep)), parallel)
            .expect("finite points have finite sums")
    }
}

/// `f` over chunks of [`CHUNK`] rows of `rows`, the results merged, in
/// parallel when `parallel`; `f` on all the rows otherwise.
fn fold_rows<A, F, M>(rows: &[f64], parallel: bool, f: F, merge: M) -> A
where
    A: Send,
    F: Fn(&[f64]) -> A + Sync + Send,
    M: Fn(A, A) -> A + Sync + Send,
{
    if parallel {
        rows.par_chunks(3 * CHUNK)
            .map(f)
            .reduce_with(merge)
            .expect("at least one chunk")
    } else {
        f(rows)
    }
}

/// A sphere to evaluate, with the unit axis about which the polar coverage
/// is measured (zero when there is none).
struct Trial {
    c: [f64; 3],
    radius: f64,
    axis: [f64; 3],
}

impl Trial {
    /// The sphere (c, radius); the axis is `towards_mean` (from the centre to
    /// the points' mean) normalised, or none when it is shorter than
    /// [`AXIS_FLOOR`] times the radius.
    fn new(c: &Vector3<f64>, radius: f64, towards_mean: &Vector3<f64>) -> Trial {
        let norm = towards_mean.norm();
        let axis = if norm > AXIS_FLOOR * radius.abs() {
            towards_mean / norm
        } else {
            Vector3::zeros()
        };
        Trial {
            c: [c.x, c.y, c.z],
            radius,
            axis: [axis.x, axis.y, axis.z],
        }
    }

    /// Whether there is an axis to measure the polar coverage about.
    fn has_axis(&self) -> bool {
        self.axis != [0.0; 3]
    }
}

/// Cost, normal equations, residual extremes and coverage at one sphere.
#[derive(Debug, Clone, Copy)]
struct Eval {
    normal: Normal,
    lo: f64,
    hi: f64,
    /// Polar coverage (degrees) of the points seen from the sphere's centre.
    coverage: f64,
}

/// Evaluates the sphere `t` on every point of `cloud`, writing the
/// residuals to `res`; one pass.
fn evaluate(cloud: &Cloud, t: &Trial, parallel: bool, res: &mut [f64]) -> Eval {
    debug_assert_eq!(res.len(), cloud.n);
    let acc = if parallel && cloud.n > PARALLEL_MIN_POINTS {
        cloud
            .rows
            .par_chunks(3 * CHUNK)
            .zip(res.par_chunks_mut(CHUNK))
            .map(|(rows, res)| evaluate_chunk(rows, t, res))
            .reduce_with(EvalSums::merge)
            .expect("at least one chunk")
    } else {
        evaluate_chunk(&cloud.rows, t, res)
    };
    let [xx, xy, xz, yy, yz, zz] = acc.uu.map(lanes_sum);
    let [x, y, z] = acc.u.map(lanes_sum);
    let [xr, yr, zr] = acc.ur.map(lanes_sum);
    let lowest = |v: [f64; LANES]| v.iter().copied().fold(f64::INFINITY, f64::min);
    let cos = lowest(acc.cos);
    Eval {
        normal: Normal {
            a: [xx, xy, xz, x, yy, yz, y, zz, z, cloud.n as f64],
            g: [-xr, -yr, -zr, -lanes_sum(acc.r)],
            cost: lanes_sum(acc.rr),
        },
        lo: lowest(acc.lo),
        hi: acc.hi.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        coverage: if t.has_axis() {
            cos.clamp(-1.0, 1.0).acos().to_degrees()
        } else {
            180.0
        },
    }
}

/// The lanes of a partial sum added in a fixed order.
#[inline(always)]
fn lanes_sum(v: [f64; LANES]) -> f64 {
    (v[0] + v[1]) + (v[2] + v[3])
}

/// Partial sums of one evaluation pass, lane by lane. With u the unit
/// direction from the centre and r the residual: sums of the products of
/// u's components, of u, of u r, r and r^2; the smallest and largest r and
/// the smallest cosine u . axis.
#[derive(Clone, Copy)]
struct EvalSums {
    /// xx, xy, xz, yy, yz, zz.
    uu: [[f64; LANES]; 6],
    u: [[f64; LANES]; 3],
    ur: [[f64; LANES]; 3],
    r: [f64; LANES],
    rr: [f64; LANES],
    lo: [f64; LANES],
    hi: [f64; LANES],
    cos: [f64; LANES],
}

impl EvalSums {
    fn merge(mut self, o: EvalSums) -> Self {
        let sums = self.uu.iter_mut().chain(&mut self.u).chain(&mut self.ur);
        let other = o.uu.iter().chain(&o.u).chain(&o.ur);
        for (a, b) in sums.zip(other) {
            for (x, y) in a.iter_mut().zip(b) {
                *x += y;
            }
        }
        for j in 0..LANES {
            self.r[j] += o.r[j];
            self.rr[j] += o.rr[j];
            self.lo[j] = self.lo[j].min(o.lo[j]);
            self.hi[j] = self.hi[j].max(o.hi[j]);
            self.cos[j] = self.cos[j].min(o.cos[j]);
        }
        self
    }
}

/// Partial sums of [`Moments`], lane by lane.
#[derive(Clone, Copy)]
struct MomentSums {
    /// xx, xy, xz, yy, yz, zz.
    s: [[f64; LANES]; 6],
    b: [[f64; LANES]; 3],
}

impl MomentSums {
    fn merge(mut self, o: MomentSums) -> Self {
        for (a, b) in self
            .s
            .iter_mut()
            .chain(&mut self.b)
            .zip(o.s.iter().chain(&o.b))
        {
            for (x, y) in a.iter_mut().zip(b) {
                *x += y;
            }
        }
        self
    }

    fn total(&self) -> Moments {
        let s = self.s.map(lanes_sum);
        let b = self.b.map(lanes_sum);
        Moments {
            s: Matrix3::new(
                s[0], s[1], s[2], //
                s[1], s[3], s[4], //
                s[2], s[4], s[5],
            ),
            b: Vector3::from(b),
        }
    }
}

/// [`LANES`] f64 values operated on together (a SIMD vector where there is
/// one). Every operation is the IEEE one lane by lane, so all
/// implementations give the same bits.
trait Quad: Copy {
    fn splat(v: f64) -> Self;
    fn from_array(a: [f64; LANES]) -> Self;
    fn store(self, a: &mut [f64; LANES]);
    /// The x, y and z of the block of [`LANES`] points `rows` (N x 3
    /// row-major).
    fn load_rows(rows: &[f64; BLOCK]) -> (Self, Self, Self);
    fn add(self, o: Self) -> Self;
    fn sub(self, o: Self) -> Self;
    fn mul(self, o: Self) -> Self;
    fn div(self, o: Self) -> Self;
    fn sqrt(self) -> Self;
    /// `if self < o { self } else { o }` (the x86 MINPD rule).
    fn min(self, o: Self) -> Self;
    /// `if self > o { self } else { o }` (the x86 MAXPD rule).
    fn max(self, o: Self) -> Self;
    /// `self` where `m > 0`, zero elsewhere (and where `m` is NaN).
    fn where_positive(self, m: Self) -> Self;

    #[inline(always)]
    fn load(a: &[f64]) -> Self {
        Self::from_array(a[..LANES].try_into().expect("LANES values"))
    }

    #[inline(always)]
    fn to_array(self) -> [f64; LANES] {
        let mut a = [0.0; LANES];
        self.store(&mut a);
        a
    }
}

/// The portable implementation: plain arrays.
impl Quad for [f64; LANES] {
    #[inline(always)]
    fn splat(v: f64) -> Self {
        [v; LANES]
    }
    #[inline(always)]
    fn from_array(a: [f64; LANES]) -> Self {
        a
    }
    #[inline(always)]
    fn store(self, a: &mut [f64; LANES]) {
        *a = self;
    }
    #[inline(always)]
    fn load_rows(rows: &[f64; BLOCK]) -> (Self, Self, Self) {
        (
            std::array::from_fn(|j| rows[3 * j]),
            std::array::from_fn(|j| rows[3 * j + 1]),
            std::array::from_fn(|j| rows[3 * j + 2]),
        )
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        std::array::from_fn(|j| self[j] + o[j])
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        std::array::from_fn(|j| self[j] - o[j])
    }
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        std::array::from_fn(|j| self[j] * o[j])
    }
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        std::array::from_fn(|j| self[j] / o[j])
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        self.map(f64::sqrt)
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        std::array::from_fn(|j| if self[j] < o[j] { self[j] } else { o[j] })
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        std::array::from_fn(|j| if self[j] > o[j] { self[j] } else { o[j] })
    }
    #[inline(always)]
    fn where_positive(self, m: Self) -> Self {
        std::array::from_fn(|j| if m[j] > 0.0 { self[j] } else { 0.0 })
    }
}

/// x86-64 implementations of [`Quad`]: two SSE2 registers (every x86-64
/// CPU has SSE2) or one AVX register.
#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    use super::{Quad, BLOCK, LANES};

    /// Two SSE2 vectors: lanes 0-1 and 2-3.
    #[derive(Clone, Copy)]
    pub struct Sse2(__m128d, __m128d);

    // SAFETY (every `unsafe` block in this impl): SSE2 is part of x86-64,
    // so these intrinsics are available on every CPU this code runs on, and
    // the loads and stores stay inside the arrays they are given.
    impl Quad for Sse2 {
        #[inline(always)]
        fn splat(v: f64) -> Self {
            unsafe { Sse2(_mm_set1_pd(v), _mm_set1_pd(v)) }
        }
        #[inline(always)]
        fn from_array(a: [f64; LANES]) -> Self {
            unsafe { Sse2(_mm_loadu_pd(a.as_ptr()), _mm_loadu_pd(a.as_ptr().add(2))) }
        }
        #[inline(always)]
        fn store(self, a: &mut [f64; LANES]) {
            unsafe {
                _mm_storeu_pd(a.as_mut_ptr(), self.0);
                _mm_storeu_pd(a.as_mut_ptr().add(2), self.1);
            }
        }
        #[inline(always)]
        fn load_rows(rows: &[f64; BLOCK]) -> (Self, Self, Self) {
            unsafe {
                let p = rows.as_ptr();
                // [x0 y0] [z0 x1] [y1 z1] [x2 y2] [z2 x3] [y3 z3]
                let (a, b, c) = (
                    _mm_loadu_pd(p),
                    _mm_loadu_pd(p.add(2)),
                    _mm_loadu_pd(p.add(4)),
                );
                let (d, e, f) = (
                    _mm_loadu_pd(p.add(6)),
                    _mm_loadu_pd(p.add(8)),
                    _mm_loadu_pd(p.add(10)),
                );
                (
                    Sse2(_mm_shuffle_pd::<0b10>(a, b), _mm_shuffle_pd::<0b10>(d, e)),
                    Sse2(_mm_shuffle_pd::<0b01>(a, c), _mm_shuffle_pd::<0b01>(d, f)),
                    Sse2(_mm_shuffle_pd::<0b10>(b, c), _mm_shuffle_pd::<0b10>(e, f)),
                )
            }
        }
        #[inline(always)]
        fn add(self, o: Self) -> Self {
            unsafe { Sse2(_mm_add_pd(self.0, o.0), _mm_add_pd(self.1, o.1)) }
        }
        #[inline(always)]
        fn sub(self, o: Self) -> Self {
            unsafe { Sse2(_mm_sub_pd(self.0, o.0), _mm_sub_pd(self.1, o.1)) }
        }
        #[inline(always)]
        fn mul(self, o: Self) -> Self {
            unsafe { Sse2(_mm_mul_pd(self.0, o.0), _mm_mul_pd(self.1, o.1)) }
        }
        #[inline(always)]
        fn div(self, o: Self) -> Self {
            unsafe { Sse2(_mm_div_pd(self.0, o.0), _mm_div_pd(self.1, o.1)) }
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            unsafe { Sse2(_mm_sqrt_pd(self.0), _mm_sqrt_pd(self.1)) }
        }
        #[inline(always)]
        fn min(self, o: Self) -> Self {
            unsafe { Sse2(_mm_min_pd(self.0, o.0), _mm_min_pd(self.1, o.1)) }
        }
        #[inline(always)]
        fn max(self, o: Self) -> Self {
            unsafe { Sse2(_mm_max_pd(self.0, o.0), _mm_max_pd(self.1, o.1)) }
        }
        #[inline(always)]
        fn where_positive(self, m: Self) -> Self {
            unsafe {
                let zero = _mm_setzero_pd();
                Sse2(
                    _mm_and_pd(self.0, _mm_cmpgt_pd(m.0, zero)),
                    _mm_and_pd(self.1, _mm_cmpgt_pd(m.1, zero)),
                )
            }
        }
    }

    /// One AVX vector. Used only inside the AVX clones of the dispatched
    /// passes ([`super::evaluate_chunk`] and the others, `match_target!`
    /// arms for `x86_64+avx`), which run only where multiversion detected AVX.
    #[derive(Clone, Copy)]
    pub struct Avx(__m256d);

    // SAFETY (every `unsafe` block in this impl): `Avx` values exist only
    // inside the AVX clones of the multiversioned passes, compiled with AVX
    // enabled and called only after multiversion detected AVX on the CPU;
    // the loads and stores stay inside the arrays they are given.
    impl Quad for Avx {
        #[inline(always)]
        fn splat(v: f64) -> Self {
            unsafe { Avx(_mm256_set1_pd(v)) }
        }
        #[inline(always)]
        fn from_array(a: [f64; LANES]) -> Self {
            unsafe { Avx(_mm256_loadu_pd(a.as_ptr())) }
        }
        #[inline(always)]
        fn store(self, a: &mut [f64; LANES]) {
            unsafe { _mm256_storeu_pd(a.as_mut_ptr(), self.0) }
        }
        #[inline(always)]
        fn load_rows(rows: &[f64; BLOCK]) -> (Self, Self, Self) {
            unsafe {
                let p = rows.as_ptr();
                // a = [x0 y0 | z0 x1], b = [y1 z1 | x2 y2], c = [z2 x3 | y3 z3]
                let (a, b, c) = (
                    _mm256_loadu_pd(p),
                    _mm256_loadu_pd(p.add(4)),
                    _mm256_loadu_pd(p.add(8)),
                );
                let xy = _mm256_blend_pd::<0b1100>(a, b); // [x0 y0 | x2 y2]
                let zx = _mm256_permute2f128_pd::<0x21>(a, c); // [z0 x1 | z2 x3]
                let yz = _mm256_blend_pd::<0b1100>(b, c); // [y1 z1 | y3 z3]
                (
                    Avx(_mm256_shuffle_pd::<0b1010>(xy, zx)),
                    Avx(_mm256_shuffle_pd::<0b0101>(xy, yz)),
                    Avx(_mm256_shuffle_pd::<0b1010>(zx, yz)),
                )
            }
        }
        #[inline(always)]
        fn add(self, o: Self) -> Self {
            unsafe { Avx(_mm256_add_pd(self.0, o.0)) }
        }
        #[inline(always)]
        fn sub(self, o: Self) -> Self {
            unsafe { Avx(_mm256_sub_pd(self.0, o.0)) }
        }
        #[inline(always)]
        fn mul(self, o: Self) -> Self {
            unsafe { Avx(_mm256_mul_pd(self.0, o.0)) }
        }
        #[inline(always)]
        fn div(self, o: Self) -> Self {
            unsafe { Avx(_mm256_div_pd(self.0, o.0)) }
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            unsafe { Avx(_mm256_sqrt_pd(self.0)) }
        }
        #[inline(always)]
        fn min(self, o: Self) -> Self {
            unsafe { Avx(_mm256_min_pd(self.0, o.0)) }
        }
        #[inline(always)]
        fn max(self, o: Self) -> Self {
            unsafe { Avx(_mm256_max_pd(self.0, o.0)) }
        }
        #[inline(always)]
        fn where_positive(self, m: Self) -> Self {
            unsafe {
                let positive = _mm256_cmp_pd::<_CMP_GT_OQ>(m.0, _mm256_setzero_pd());
                Avx(_mm256_and_pd(self.0, positive))
            }
        }
    }
}

/// Sum of each coordinate of N x 3 row-major `rows`, [`LANES`] points at a
/// time.
#[inline(always)]
fn sum_rows(rows: &[f64]) -> [f64; 3] {
    let mut acc = [0.0; BLOCK];
    let blocks = rows.chunks_exact(BLOCK);
    let rest = blocks.remainder();
    for b in blocks {
        for (a, v) in acc.iter_mut().zip(b) {
            *a += v;
        }
    }
    let mut s = [0.0; 3];
    for (k, a) in acc.iter().enumerate() {
        s[k % 3] += a;
    }
    for (k, v) in rest.iter().enumerate() {
        s[k % 3] += v;
    }
    s
}

/// [`MomentSums`] in vectors. Separate fields, not arrays, so that the
/// compiler keeps them in registers.
struct MomentAcc<V> {
    xx: V,
    xy: V,
    xz: V,
    yy: V,
    yz: V,
    zz: V,
    bx: V,
    by: V,
    bz: V,
}

impl<V: Quad> MomentAcc<V> {
    #[inline(always)]
    fn new() -> Self {
        let zero = V::splat(0.0);
        MomentAcc {
            xx: zero,
            xy: zero,
            xz: zero,
            yy: zero,
            yz: zero,
            zz: zero,
            bx: zero,
            by: zero,
            bz: zero,
        }
    }

    /// Adds the moments of the centred points (x, y, z).
    #[inline(always)]
    fn add(&mut self, x: V, y: V, z: V) {
        let (xx, yy, zz) = (x.mul(x), y.mul(y), z.mul(z));
        self.xx = self.xx.add(xx);
        self.xy = self.xy.add(x.mul(y));
        self.xz = self.xz.add(x.mul(z));
        self.yy = self.yy.add(yy);
        self.yz = self.yz.add(y.mul(z));
        self.zz = self.zz.add(zz);
        let q2 = xx.add(yy).add(zz);
        self.bx = self.bx.add(x.mul(q2));
        self.by = self.by.add(y.mul(q2));
        self.bz = self.bz.add(z.mul(q2));
    }

    #[inline(always)]
    fn sums(&self) -> MomentSums {
        MomentSums {
            s: [self.xx, self.xy, self.xz, self.yy, self.yz, self.zz].map(V::to_array),
            b: [self.bx, self.by, self.bz].map(V::to_array),
        }
    }
}

/// Moments about `m` of N x 3 row-major `rows`.
#[inline(always)]
fn moments_rows<V: Quad>(rows: &[f64], m: &[f64; 3]) -> MomentSums {
    let (mx, my, mz) = (V::splat(m[0]), V::splat(m[1]), V::splat(m[2]));
    let mut acc = MomentAcc::<V>::new();
    let (full, rest) = rows.split_at(rows.len() / BLOCK * BLOCK);
    let mut q = [[0.0; BLOCK]; GROUP];
    for g in full.chunks(GROUP * BLOCK) {
        for (b, q) in g.chunks_exact(BLOCK).zip(&mut q) {
            let (x, y, z) = V::load_rows(b.try_into().expect("a block"));
            let (qx, rest) = q.split_at_mut(LANES);
            let (qy, qz) = rest.split_at_mut(LANES);
            x.sub(mx).store(qx.try_into().expect("a block"));
            y.sub(my).store(qy.try_into().expect("a block"));
            z.sub(mz).store(qz.try_into().expect("a block"));
        }
        for q in &q[..g.len() / BLOCK] {
            acc.add(V::load(q), V::load(&q[LANES..]), V::load(&q[2 * LANES..]));
        }
    }
    if !rest.is_empty() {
        // Padded with the mean: centred, the padding is zero and adds nothing.
        let b: [f64; BLOCK] = std::array::from_fn(|k| rest.get(k).copied().unwrap_or(m[k % 3]));
        let (x, y, z) = V::load_rows(&b);
        acc.add(x.sub(mx), y.sub(my), z.sub(mz));
    }
    acc.sums()
}

/// Unit directions u from the centre and residuals r of a block of points.
#[derive(Clone, Copy)]
struct Unit<V> {
    x: V,
    y: V,
    z: V,
    r: V,
}

/// The [`Unit`] of the points (x, y, z) for the sphere (`c`, `radius`).
#[inline(always)]
fn unit<V: Quad>(x: V, y: V, z: V, c: &[V; 3], radius: V) -> Unit<V> {
    let (dx, dy, dz) = (x.sub(c[0]), y.sub(c[1]), z.sub(c[2]));
    let dist = dx.mul(dx).add(dy.mul(dy)).add(dz.mul(dz)).sqrt();
    // J row = -(u, 1) with u the unit direction (zero at the centre itself).
    let inv = V::splat(1.0).div(dist).where_positive(dist);
    Unit {
        x: dx.mul(inv),
        y: dy.mul(inv),
        z: dz.mul(inv),
        r: dist.sub(radius),
    }
}

/// The sums of an evaluation pass that need only the residuals r: of r,
/// of r^2, and the smallest and largest r, in vectors.
struct ResidualSums<V> {
    r: V,
    rr: V,
    lo: V,
    hi: V,
}

impl<V: Quad> ResidualSums<V> {
    #[inline(always)]
    fn new() -> Self {
        let zero = V::splat(0.0);
        ResidualSums {
            r: zero,
            rr: zero,
            lo: V::splat(f64::INFINITY),
            hi: V::splat(f64::NEG_INFINITY),
        }
    }

    /// Adds `r`; `lo` and `hi` are `r`, or +inf and -inf in lanes that are
    /// padding (where `r` is zero).
    #[inline(always)]
    fn add(&mut self, r: V, lo: V, hi: V) {
        self.r = self.r.add(r);
        self.rr = self.rr.add(r.mul(r));
        self.lo = lo.min(self.lo);
        self.hi = hi.max(self.hi);
    }
}

/// The sums of an evaluation pass over u: the products of its components
/// and the components, in vectors.
struct DirectionSums<V> {
    xx: V,
    xy: V,
    xz: V,
    yy: V,
    yz: V,
    zz: V,
    x: V,
    y: V,
    z: V,
}

impl<V: Quad> DirectionSums<V> {
    #[inline(always)]
    fn new() -> Self {
        let zero = V::splat(0.0);
        DirectionSums {
            xx: zero,
            xy: zero,
            xz: zero,
            yy: zero,
            yz: zero,
            zz: zero,
            x: zero,
            y: zero,
            z: zero,
        }
    }

    #[inline(always)]
    fn add(&mut self, u: &Unit<V>) {
        let (x, y, z) = (u.x, u.y, u.z);
        self.xx = self.xx.add(x.mul(x));
        self.xy = self.xy.add(x.mul(y));
        self.xz = self.xz.add(x.mul(z));
        self.yy = self.yy.add(y.mul(y));
        self.yz = self.yz.add(y.mul(z));
        self.zz = self.zz.add(z.mul(z));
        self.x = self.x.add(x);
        self.y = self.y.add(y);
        self.z = self.z.add(z);
    }
}

/// The sums of an evaluation pass over u and r: of u r, and the smallest
/// cosine u . axis, in vectors.
struct GradientSums<V> {
    xr: V,
    yr: V,
    zr: V,
    cos: V,
}

impl<V: Quad> GradientSums<V> {
    #[inline(always)]
    fn new() -> Self {
        let zero = V::splat(0.0);
        GradientSums {
            xr: zero,
            yr: zero,
            zr: zero,
            cos: V::splat(f64::INFINITY),
        }
    }

    /// Adds `u`; `cos` is its cosine to the axis, or +inf in lanes that are
    /// padding.
    #[inline(always)]
    fn add(&mut self, u: &Unit<V>, cos: V) {
        self.xr = self.xr.add(u.x.mul(u.r));
        self.yr = self.yr.add(u.y.mul(u.r));
        self.zr = self.zr.add(u.z.mul(u.r));
        self.cos = cos.min(self.cos);
    }
}

/// u . axis.
#[inline(always)]
fn cosine<V: Quad>(u: &Unit<V>, axis: &[V; 3]) -> V {
    u.x.mul(axis[0]).add(u.y.mul(axis[1])).add(u.z.mul(axis[2]))
}

/// `v` with the lanes from `n` on replaced by `fill`.
#[inline(always)]
fn keep<V: Quad>(v: V, n: usize, fill: f64) -> V {
    let mut a = v.to_array();
    a[n..].fill(fill);
    V::from_array(a)
}

/// Evaluates the sphere `t` on the N x 3 row-major points `rows`, writing
/// their residuals to `res` (N long).
///
/// In groups of [`GROUP`] blocks of points, three loops: the square roots
/// and divisions (long latency, one unit) with the sums of r, keeping u;
/// then the sums over u; then those over u and r. Short loops with few live
/// sums each, which the processor overlaps better than one long one.
#[inline(always)]
fn evaluate_rows<V: Quad>(rows: &[f64], t: &Trial, res: &mut [f64]) -> EvalSums {
    let c = t.c.map(V::splat);
    let axis = t.axis.map(V::splat);
    let radius = V::splat(t.radius);
    let mut rs = ResidualSums::<V>::new();
    let mut us = DirectionSums::<V>::new();
    let mut gs = GradientSums::<V>::new();
    let full = res.len() / LANES;
    let (res_full, res_rest) = res.split_at_mut(full * LANES);
    let (rows_full, rows_rest) = rows.split_at(full * BLOCK);
    let mut units = [[0.0; BLOCK]; GROUP];
    let load = |w: &[f64; BLOCK], r: &[f64]| Unit {
        x: V::load(w),
        y: V::load(&w[LANES..]),
        z: V::load(&w[2 * LANES..]),
        r: V::load(r),
    };
    for (rows, res) in rows_full
        .chunks(GROUP * BLOCK)
        .zip(res_full.chunks_mut(GROUP * LANES))
    {
        let blocks = rows.chunks_exact(BLOCK).zip(res.chunks_exact_mut(LANES));
        for ((p, r), w) in blocks.zip(&mut units) {
            let (x, y, z) = V::load_rows(p.try_into().expect("a block"));
            let u = unit(x, y, z, &c, radius);
            u.r.store(r.try_into().expect("a block"));
            let (wx, rest) = w.split_at_mut(LANES);
            let (wy, wz) = rest.split_at_mut(LANES);
            u.x.store(wx.try_into().expect("a block"));
            u.y.store(wy.try_into().expect("a block"));
            u.z.store(wz.try_into().expect("a block"));
            rs.add(u.r, u.r, u.r);
        }
        for (w, r) in units.iter().zip(res.chunks_exact(LANES)) {
            us.add(&load(w, r));
        }
        for (w, r) in units.iter().zip(res.chunks_exact(LANES)) {
            let u = load(w, r);
            gs.add(&u, cosine(&u, &axis));
        }
    }
    if !res_rest.is_empty() {
        let n = res_rest.len();
        let mut p = [0.0; BLOCK];
        p[..rows_rest.len()].copy_from_slice(rows_rest);
        let (x, y, z) = V::load_rows(&p);
        let u = unit(x, y, z, &c, radius);
        res_rest.copy_from_slice(&u.r.to_array()[..n]);
        // Padding lanes add zero to the sums and nothing to the extremes.
        let cos = keep(cosine(&u, &axis), n, f64::INFINITY);
        let (lo, hi) = (keep(u.r, n, f64::INFINITY), keep(u.r, n, f64::NEG_INFINITY));
        let u = Unit {
            x: keep(u.x, n, 0.0),
            y: keep(u.y, n, 0.0),
            z: keep(u.z, n, 0.0),
            r: keep(u.r, n, 0.0),
        };
        rs.add(u.r, lo, hi);
        us.add(&u);
        gs.add(&u, cos);
    }
    let a = |v: V| v.to_array();
    EvalSums {
        uu: [a(us.xx), a(us.xy), a(us.xz), a(us.yy), a(us.yz), a(us.zz)],
        u: [a(us.x), a(us.y), a(us.z)],
        ur: [a(gs.xr), a(gs.yr), a(gs.zr)],
        r: a(rs.r),
        rr: a(rs.rr),
        lo: a(rs.lo),
        hi: a(rs.hi),
        cos: a(gs.cos),
    }
}

// The passes below are compiled once per SIMD target and chosen at run time
// by multiversion, the dispatch the compensation kernel uses too
// (`crate::kernel`). Every target does the same IEEE operations lane by
// lane in the same order (Rust never fuses a multiply and an add on its
// own), so every target gives the same bits; the AVX clones only hold the
// [`LANES`] lanes in one register instead of two.

/// [`sum_rows`] with the best vectors the CPU has.
#[multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
fn sum_chunk(rows: &[f64]) -> [f64; 3] {
    sum_rows(rows)
}

/// [`moments_rows`] with the best vectors the CPU has.
#[multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
fn moments_chunk(rows: &[f64], m: &[f64; 3]) -> MomentSums {
    match_target! {
        "x86_64+avx" => moments_rows::<x86::Avx>(rows, m),
        "x86_64" => moments_rows::<x86::Sse2>(rows, m),
        _ => moments_rows::<[f64; LANES]>(rows, m),
    }
}

/// [`evaluate_rows`] with the best vectors the CPU has.
#[multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
fn evaluate_chunk(rows: &[f64], t: &Trial, res: &mut [f64]) -> EvalSums {
    match_target! {
        "x86_64+avx" => evaluate_rows::<x86::Avx>(rows, t, res),
        "x86_64" => evaluate_rows::<x86::Sse2>(rows, t, res),
        _ => evaluate_rows::<[f64; LANES]>(rows, t, res),
    }
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
        // Thesis Appendix A (docs/conventions.md, Spheroid fits of Appendix A): caps about the pole of an
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
            reject: Some(Rejection::Mad(4.0)),
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

    /// A 90 degree cap (8 um noise) with the `frac` of its points on one
    /// side (largest x) pushed `push` mm outward.
    fn one_sided(frac: f64, push: f64, seed: u64) -> (Vec<f64>, Vector3<f64>) {
        let c = Vector3::new(5.0, -7.0, 12.0);
        let mut pts = cap(c.into(), 50.0, [0.0, 0.0, 1.0], 90.0, 3000, 0.008, seed);
        pts.sort_by(|a, b| b.x.total_cmp(&a.x));
        let bad = (frac * pts.len() as f64) as usize;
        for p in pts.iter_mut().take(bad) {
            *p = c + (*p - c) * ((50.0 + push) / (*p - c).norm());
        }
        (flatten(&pts), c)
    }

    #[test]
    fn fit_sphere_median_centred_rejection_survives_one_sided_contamination() {
        // 10 % of the points 5 mm out: the least-squares fit is pulled
        // outward, so the clean points' residuals sit below zero, close to
        // their median. The rule centred on the median drops exactly the
        // pushed points and the refits come back to the clean centre.
        let (rows, c) = one_sided(0.1, 5.0, 21);
        let opts = SphereFitOptions {
            radius: Some(50.0),
            reject: Some(Rejection::Mad(3.5)),
            ..Default::default()
        };
        let f = fit_sphere(&rows, &opts).unwrap();
        assert!(f.inlier[..300].iter().all(|&i| !i), "{}", f.rejected);
        assert!(f.rejected < 310, "{}", f.rejected);
        assert!((Vector3::from(f.centre) - c).norm() < 1e-3);
        // At 30 % the biased first fit spreads the clean residuals over
        // millimetres: the rule alone keeps a fit (centred on zero it kept
        // no point and failed), the least-median start is what recovers the
        // centre (next test).
        let (rows, _) = one_sided(0.3, 5.0, 21);
        assert!(fit_sphere(&rows, &opts).is_ok());
    }

    #[test]
    fn fit_sphere_least_median_start_recovers_the_clean_centre_up_to_40_percent() {
        for frac in [0.0, 0.1, 0.2, 0.3, 0.4] {
            let (rows, c) = one_sided(frac, 5.0, 22);
            for (radius, tol) in [(Some(50.0), 1e-3), (None, 5e-3)] {
                for reject in [None, Some(Rejection::Mad(3.5))] {
                    let opts = SphereFitOptions {
                        radius,
                        reject,
                        start: Start::LeastMedian(LeastMedian::default()),
                        ..Default::default()
                    };
                    let f = fit_sphere(&rows, &opts).unwrap();
                    let e = (Vector3::from(f.centre) - c).norm();
                    assert!(e < tol, "{frac} {radius:?} {reject:?}: {e}");
                    let bad = (frac * 3000.0) as usize;
                    assert!(f.inlier[..bad].iter().all(|&i| !i));
                    // 2.5 robust scales keep ~98.8 % of the clean points.
                    assert!(
                        f.n_points as f64 >= 0.97 * (3000 - bad) as f64,
                        "{}",
                        f.n_points
                    );
                }
            }
        }
    }

    #[test]
    fn fit_sphere_single_pass_rule_refits_once() {
        // Five points 1 mm out among 2000: one pass at 3 s drops them (s is
        // inflated by them, ~0.05 mm, still far below 1 mm) and refits once.
        let c = Vector3::new(1.0, 2.0, 3.0);
        let mut pts = cap(c.into(), 20.0, [0.0, 1.0, 0.0], 70.0, 2000, 0.01, 23);
        for p in pts.iter_mut().take(5) {
            *p = c + (*p - c) * (21.0 / (*p - c).norm());
        }
        let rows = flatten(&pts);
        let opts = SphereFitOptions {
            radius: Some(20.0),
            reject: Some(Rejection::SinglePass(3.0)),
            ..Default::default()
        };
        let f = fit_sphere(&rows, &opts).unwrap();
        assert!(f.inlier[..5].iter().all(|&i| !i));
        // The pass set aside the five and a few 3 s tails at most.
        assert!(f.rejected >= 5 && f.rejected < 15, "{}", f.rejected);
        assert_eq!(f.n_points + f.rejected, 2000);
        assert!((Vector3::from(f.centre) - c).norm() < 2e-3);
    }

    #[test]
    fn fit_sphere_from_a_given_centre() {
        // A 30 degree cap: from a start near the truth the fit lands where the
        // algebraic start leads it too (one minimum), free or fixed radius.
        let c = Vector3::new(-3.0, 4.0, 100.0);
        let rows = flatten(&cap(c.into(), 25.0, [1.0, 1.0, 0.0], 30.0, 1500, 0.002, 24));
        for radius in [None, Some(25.0)] {
            let plain = fit_sphere(
                &rows,
                &SphereFitOptions {
                    radius,
                    ..Default::default()
                },
            )
            .unwrap();
            let start = [c.x + 1.0, c.y - 2.0, c.z + 0.5];
            let f = fit_sphere(
                &rows,
                &SphereFitOptions {
                    radius,
                    start: Start::Centre(start),
                    ..Default::default()
                },
            )
            .unwrap();
            let d = (Vector3::from(f.centre) - Vector3::from(plain.centre)).norm();
            assert!(d < 1e-7, "{radius:?}: {d}");
        }
        let e = fit_sphere(
            &rows,
            &SphereFitOptions {
                start: Start::Centre([f64::NAN, 0.0, 0.0]),
                ..Default::default()
            },
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("start: "), "{e}");
        let e = fit_sphere_groups(
            &rows,
            &[0, 1500],
            &SphereFitOptions {
                start: Start::Centre([0.0; 3]),
                ..Default::default()
            },
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("start: "), "{e}");
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
            reject: Some(Rejection::Mad(3.0)),
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
    fn fit_sphere_groups_columns_equal_individual_fits() {
        // The groups' columns hold exactly what fit_sphere gives each group
        // (same serial path), a failed group its error with NaN fields, and
        // the per-point fields follow the input rows.
        let a = flatten(&cap([0.0; 3], 10.0, [0.0, 0.0, 1.0], 60.0, 800, 0.005, 1));
        let collinear: Vec<f64> = (0..5).flat_map(|i| [i as f64, 0.0, 0.0]).collect();
        let mut b = flatten(&cap(
            [100.0, 0.0, 5.0],
            BALL,
            [1.0, 0.0, 0.0],
            85.0,
            300,
            0.008,
            2,
        ));
        // An outlier for the rejection to find.
        b[30] += 2.0;
        let too_few = vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        let points: Vec<f64> = [&a, &collinear, &b, &too_few]
            .into_iter()
            .flatten()
            .copied()
            .collect();
        let bounds = [0, 800, 805, 1105, 1107];
        let opts = SphereFitOptions {
            reject: Some(Rejection::Mad(3.0)),
            ..Default::default()
        };
        let fits = fit_sphere_groups(&points, &bounds, &opts).unwrap();
        assert_eq!(fits.radius.len(), 4);
        assert_eq!((fits.residuals.len(), fits.inlier.len()), (1107, 1107));
        for (k, w) in bounds.windows(2).enumerate() {
            let (lo, hi) = (w[0], w[1]);
            match fit_sphere(&points[3 * lo..3 * hi], &opts) {
                Ok(f) => {
                    assert!(fits.error[k].is_none());
                    assert_eq!(fits.centre[k], f.centre);
                    assert_eq!(fits.radius[k].to_bits(), f.radius.to_bits());
                    assert_eq!(fits.rms[k].to_bits(), f.rms.to_bits());
                    assert_eq!(fits.form[k].to_bits(), f.form.to_bits());
                    assert_eq!(fits.n_points[k], f.n_points);
                    assert_eq!(fits.covariance[k], f.covariance);
                    assert_eq!(fits.polar_coverage_deg[k], f.polar_coverage_deg);
                    assert_eq!(fits.iterations[k], f.iterations);
                    assert_eq!(fits.converged[k], f.converged);
                    assert_eq!(fits.rejected[k], f.rejected);
                    assert_eq!(&fits.residuals[lo..hi], f.residuals.as_slice());
                    assert_eq!(&fits.inlier[lo..hi], f.inlier.as_slice());
                }
                Err(e) => {
                    assert_eq!(fits.error[k].as_ref(), Some(&e));
                    assert!(fits.centre[k].iter().all(|c| c.is_nan()));
                    assert!(fits.radius[k].is_nan() && fits.rms[k].is_nan());
                    assert!(fits.covariance[k].iter().flatten().all(|c| c.is_nan()));
                    assert_eq!((fits.n_points[k], fits.iterations[k]), (0, 0));
                    assert!(!fits.converged[k]);
                    assert!(fits.residuals[lo..hi].iter().all(|r| r.is_nan()));
                    assert!(fits.inlier[lo..hi].iter().all(|&i| !i));
                }
            }
        }
        assert!(fits.error[1]
            .as_ref()
            .unwrap()
            .to_string()
            .contains("collinear"));
        assert!(fits.error[3]
            .as_ref()
            .unwrap()
            .to_string()
            .contains("at least 4 points"));
        assert!(fits.rejected[2] >= 1);
        assert!(!fits.inlier[805 + 10]);
    }

    #[test]
    fn fit_sphere_groups_empty_and_bad_bounds() {
        // No points, no groups: empty columns.
        let opts = SphereFitOptions::default();
        let none = fit_sphere_groups(&[], &[0], &opts).unwrap();
        assert!(none.radius.is_empty() && none.error.is_empty() && none.residuals.is_empty());
        let pts = flatten(&cap([0.0; 3], 10.0, [0.0, 0.0, 1.0], 60.0, 10, 0.005, 1));
        for bounds in [&[][..], &[0, 5], &[1, 10], &[0, 6, 4, 10], &[0, 11]] {
            let e = fit_sphere_groups(&pts, bounds, &opts).unwrap_err();
            assert!(e.to_string().starts_with("bounds: must rise from 0"), "{e}");
        }
        // A bad option is refused once, not per group.
        let bad = SphereFitOptions {
            max_iterations: 0,
            ..opts
        };
        let e = fit_sphere_groups(&pts, &[0, 10], &bad).unwrap_err();
        assert!(e.to_string().starts_with("max_iterations"), "{e}");
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
                reject: Some(Rejection::Mad(0.01)),
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
                    reject: Some(Rejection::Mad(0.0)),
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

    /// Points on a 70 degree cap (8 um noise), N x 3 row-major.
    fn noisy_rows(n: usize, seed: u64) -> Vec<f64> {
        flatten(&cap(
            [450.0, 380.0, -420.0],
            BALL,
            [0.3, -0.5, 0.8],
            70.0,
            n,
            0.008,
            seed,
        ))
    }

    /// The bits of every partial sum.
    fn bits(e: &EvalSums) -> Vec<u64> {
        let mut v: Vec<&[f64; LANES]> = e.uu.iter().chain(&e.u).chain(&e.ur).collect();
        v.extend([&e.r, &e.rr, &e.lo, &e.hi, &e.cos]);
        v.into_iter().flatten().map(|x| x.to_bits()).collect()
    }

    #[test]
    fn fit_sphere_passes_agree_bit_for_bit_across_instruction_sets() {
        // Every implementation of the passes (plain arrays, SSE2, AVX where
        // the CPU has it) does the same IEEE operations lane by lane, so the
        // sums and residuals are identical, whatever the number of points
        // (full blocks, a partial last block, several groups).
        let t = Trial::new(
            &Vector3::new(451.0, 379.0, -419.5),
            38.1,
            &Vector3::new(0.1, -0.2, 0.3),
        );
        for n in [1, 2, 3, 4, 5, 7, 255, 256, 257, 1001, 4099] {
            let rows = noisy_rows(n, n as u64);
            let mut want = vec![0.0; n];
            let plain = evaluate_rows::<[f64; LANES]>(&rows, &t, &mut want);
            // The residuals are |p - c| - R computed point by point.
            for (p, r) in rows.chunks_exact(3).zip(&want) {
                let d = [p[0] - t.c[0], p[1] - t.c[1], p[2] - t.c[2]];
                let direct = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - t.radius;
                assert_eq!(r.to_bits(), direct.to_bits(), "n = {n}");
            }
            let m = [450.0, 380.0, -420.0];
            let moments = moments_rows::<[f64; LANES]>(&rows, &m);
            let mut got = vec![0.0; n];
            let dispatched = evaluate_chunk(&rows, &t, &mut got);
            assert_eq!(bits(&plain), bits(&dispatched), "n = {n}");
            assert_eq!(want, got);
            assert_eq!(sum_rows(&rows), sum_chunk(&rows));
            let dispatched = moments_chunk(&rows, &m);
            assert_eq!(moments.s, dispatched.s);
            assert_eq!(moments.b, dispatched.b);
            #[cfg(target_arch = "x86_64")]
            {
                let sse2 = evaluate_rows::<x86::Sse2>(&rows, &t, &mut got);
                assert_eq!(bits(&plain), bits(&sse2), "n = {n}");
                assert_eq!(want, got);
                let sse2 = moments_rows::<x86::Sse2>(&rows, &m);
                assert_eq!(moments.s, sse2.s);
                assert_eq!(moments.b, sse2.b);
            }
        }
    }

    #[test]
    fn fit_sphere_sums_match_a_direct_computation() {
        // The pass against a plain loop over the points: the same sums to
        // rounding, extremes exactly, whatever the block and group layout.
        let t = Trial::new(
            &Vector3::new(450.5, 380.2, -419.0),
            38.0,
            &Vector3::new(-0.3, 0.1, -1.0),
        );
        let axis = Vector3::from(t.axis);
        for n in [6, 1003, 20_001] {
            let rows = noisy_rows(n, 11);
            let pts: Vec<Vector3<f64>> = rows
                .chunks_exact(3)
                .map(|p| Vector3::new(p[0], p[1], p[2]))
                .collect();
            let cloud = Cloud::new(Cow::Borrowed(&rows), false).unwrap();
            // Summed in another order: the same to rounding (n ulp of 450 mm).
            assert!((cloud.mean - mean(&pts, false)).norm() < 1e-9);
            let mut res = vec![0.0; n];
            let e = evaluate(&cloud, &t, false, &mut res);
            let (mut a, mut g, mut cost) = (Matrix4::zeros(), Vector4::zeros(), 0.0);
            let (mut lo, mut hi, mut cos) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY);
            for p in &pts {
                let d = p - Vector3::from(t.c);
                let u = d / d.norm();
                let r = d.norm() - t.radius;
                let j = Vector4::new(-u.x, -u.y, -u.z, -1.0);
                a += j * j.transpose();
                g += j * r;
                cost += r * r;
                lo = lo.min(r);
                hi = hi.max(r);
                cos = cos.min(u.dot(&axis));
            }
            let scale = n as f64;
            assert!((e.normal.matrix() - a).abs().max() < 1e-12 * scale);
            assert!((Vector4::from(e.normal.g) - g).abs().max() < 1e-12 * scale);
            assert!((e.normal.cost - cost).abs() < 1e-12 * cost);
            assert_eq!((e.lo, e.hi), (lo, hi));
            let cov = e.coverage.to_radians().cos();
            assert!((cov - cos).abs() < 1e-15, "{cov} {cos}");
            // The parallel pass (above PARALLEL_MIN_POINTS) only sums in
            // another order.
            let mut par = vec![0.0; n];
            let p = evaluate(&cloud, &t, true, &mut par);
            assert_eq!(par, res);
            assert!((p.normal.matrix() - e.normal.matrix()).abs().max() < 1e-12 * scale);
            assert!((p.normal.cost - e.normal.cost).abs() < 1e-12 * cost);
            assert_eq!((p.lo, p.hi, p.coverage), (e.lo, e.hi, e.coverage));
        }
    }
}
