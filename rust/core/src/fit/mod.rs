//! Least-squares fits of the evaluation artefacts (docs/conventions.md, Evaluation).
//!
//! - [`fit_sphere`] / [`fit_spheres`] / [`fit_sphere_groups`] (columns of
//!   results, [`SphereFits`]): orthogonal (geometric) least squares,
//!   Levenberg-Marquardt from an algebraic start ([`sphere`]).
//! - [`fit_plane`]: total least squares from the centred scatter matrix
//!   ([`plane`]).
//!
//! Points are N x 3 row-major slices in mm, like every array the core takes.
//! Both fits centre the points on their mean first (conditioning), report
//! signed residuals in mm in input order, and can reject outliers by a
//! [`Rejection`] rule (docs/fitting.md):
//!
//! - [`Rejection::Mad`] (`k`, repeated): every point with
//!   |r - median(r)| > k * 1.4826 * MAD(r) is set aside and the rest refitted,
//!   until the set of inliers stops changing (at most [`MAX_REJECT_ROUNDS`]
//!   refits). The median and the MAD (median absolute deviation from the
//!   median) are those of the current inliers' residuals; 1.4826 MAD
//!   estimates sigma for Gaussian noise. Every point is classified again in
//!   each round, so a point rejected against an early, biased fit can come
//!   back. Centring on the median matters: with one-sided contamination the
//!   residuals of the clean points are not centred on zero.
//! - [`Rejection::SinglePass`] (`k`, once; ASTM E3125's rule with k = 3): the
//!   points with |r| > k * s are set aside, s the sample standard deviation
//!   (n - 1) of the residuals of the first fit, and the rest refitted once.
//!
//! Either rule starts from a least-squares fit of all the points (or, for
//! spheres, of the inliers of a high-breakdown start, [`lmeds`]), so on its own
//! it cannot undo heavy contamination that has already biased that fit.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;

use crate::error::{CoreError, Result};

pub mod lmeds;
pub mod plane;
pub mod segment;
pub mod sphere;

pub use lmeds::LeastMedian;
pub use plane::{fit_plane, PlaneFit, PlaneFitOptions};
pub use segment::{segment_sphere, Segmentation, SegmentationOptions};
pub use sphere::{
    fit_sphere, fit_sphere_groups, fit_spheres, SphereFit, SphereFitOptions, SphereFits, Start,
};

/// Above this many points a pass over them runs in parallel (rayon
/// fold/reduce); below it the scheduling costs more than it saves.
pub const PARALLEL_MIN_POINTS: usize = 20_000;

/// Points per parallel work item.
pub(crate) const CHUNK: usize = 4096;

/// Refits at most this many times when rejecting outliers.
pub const MAX_REJECT_ROUNDS: usize = 10;

/// 1.4826 * MAD estimates the standard deviation of Gaussian noise.
const MAD_TO_SIGMA: f64 = 1.4826;

/// Relative size (to the largest) under which an eigenvalue of the centred
/// scatter matrix counts as zero: a spread of 1e-6 of the points' extent.
pub(crate) const FLAT: f64 = 1e-12;

/// Points as vectors, after checking the shape, the count and finiteness.
/// `what` names the fitted shape in the count message ("a sphere").
pub(crate) fn read_points(points: &[f64], min: usize, what: &str) -> Result<Vec<Vector3<f64>>> {
    check_rows(points, min, what)?;
    if let Some(e) = non_finite(points) {
        return Err(e);
    }
    Ok(points
        .chunks_exact(3)
        .map(|p| Vector3::new(p[0], p[1], p[2]))
        .collect())
}

/// The number of N x 3 rows in `points`, after checking the shape and that
/// there are at least `min` ("a sphere needs at least 4 points").
pub(crate) fn check_rows(points: &[f64], min: usize, what: &str) -> Result<usize> {
    if points.len() % 3 != 0 {
        return Err(CoreError::invalid_argument(
            "points",
            format!(
                "length {} is not a multiple of 3 (expected N x 3 row-major, mm)",
                points.len()
            ),
        ));
    }
    let n = points.len() / 3;
    if n < min {
        return Err(CoreError::invalid_argument(
            "points",
            format!("{what} needs at least {min} points, got {n}"),
        ));
    }
    Ok(n)
}

/// The error naming the first row of `points` with a NaN or infinite
/// coordinate, if there is one.
pub(crate) fn non_finite(points: &[f64]) -> Option<CoreError> {
    points
        .chunks_exact(3)
        .position(|p| !p.iter().all(|x| x.is_finite()))
        .map(|row| {
            CoreError::invalid_argument(
                "points",
                format!("non-finite value (NaN or inf) in row {row}"),
            )
        })
}

/// Folds `f` over the points, in parallel chunks when `parallel` and there
/// are more than [`PARALLEL_MIN_POINTS`]; one pass either way.
pub(crate) fn accumulate<A, F, M>(
    pts: &[Vector3<f64>],
    parallel: bool,
    init: impl Fn() -> A + Sync + Send,
    f: F,
    merge: M,
) -> A
where
    A: Send,
    F: Fn(A, &Vector3<f64>) -> A + Sync + Send,
    M: Fn(A, A) -> A + Sync + Send,
{
    if parallel && pts.len() > PARALLEL_MIN_POINTS {
        pts.par_chunks(CHUNK)
            .map(|c| c.iter().fold(init(), &f))
            .reduce(&init, &merge)
    } else {
        pts.iter().fold(init(), f)
    }
}

/// `f` applied to every point, in parallel under the same rule as [`accumulate`].
pub(crate) fn map_points<F>(pts: &[Vector3<f64>], parallel: bool, f: F) -> Vec<f64>
where
    F: Fn(&Vector3<f64>) -> f64 + Sync + Send,
{
    if parallel && pts.len() > PARALLEL_MIN_POINTS {
        pts.par_iter().map(f).collect()
    } else {
        pts.iter().map(f).collect()
    }
}

/// Mean of the points.
pub(crate) fn mean(pts: &[Vector3<f64>], parallel: bool) -> Vector3<f64> {
    let sum = accumulate(pts, parallel, Vector3::zeros, |s, p| s + p, |a, b| a + b);
    sum / pts.len() as f64
}

/// Eigen-decomposition of a symmetric 3x3 matrix with the eigenvalues in
/// descending order and the eigenvectors as the matching columns.
pub(crate) fn sorted_eigen(s: Matrix3<f64>) -> ([f64; 3], Matrix3<f64>) {
    let e = SymmetricEigen::new(s);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| e.eigenvalues[j].total_cmp(&e.eigenvalues[i]));
    let values = order.map(|i| e.eigenvalues[i]);
    let vectors = Matrix3::from_columns(&order.map(|i| e.eigenvectors.column(i).into_owned()));
    (values, vectors)
}

/// How many directions the scatter (eigenvalues, descending) spans
/// numerically: 0 (all points coincide), 1 (collinear), 2 (coplanar) or 3.
pub(crate) fn spread_rank(values: &[f64; 3]) -> usize {
    let top = values[0];
    if top.is_nan() || top <= 0.0 {
        return 0;
    }
    1 + values[1..].iter().filter(|&&v| v > FLAT * top).count()
}

/// Median of a non-empty buffer (reordered in place).
pub(crate) fn median(v: &mut [f64]) -> f64 {
    let n = v.len();
    let (lo, mid, _) = v.select_nth_unstable_by(n / 2, f64::total_cmp);
    let mid = *mid;
    if n % 2 == 1 {
        mid
    } else {
        let below = lo.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        0.5 * (below + mid)
    }
}

/// The rows (N x 3, row-major) where `keep`.
pub(crate) fn select_rows(rows: &[f64], keep: &[bool]) -> Vec<f64> {
    rows.chunks_exact(3)
        .zip(keep)
        .filter(|(_, &k)| k)
        .flat_map(|(p, _)| [p[0], p[1], p[2]])
        .collect()
}

/// The median of `r` and 1.4826 * median |r - median r| (non-empty `r`).
pub(crate) fn median_and_sigma(mut r: Vec<f64>) -> (f64, f64) {
    let m = median(&mut r);
    r.iter_mut().for_each(|x| *x = (*x - m).abs());
    (m, MAD_TO_SIGMA * median(&mut r))
}

/// An outlier rejection rule (module docs, docs/fitting.md).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rejection {
    /// Repeated: set aside |r - median(r)| > k * 1.4826 * MAD(r) and refit
    /// until the inliers stop changing (3 to 5 is usual).
    Mad(f64),
    /// Once: set aside |r| > k * s, s the sample standard deviation of the
    /// first fit's residuals, and refit (ASTM E3125: k = 3).
    SinglePass(f64),
}

impl Rejection {
    /// The multiple k of the rule's sigma.
    pub fn k(&self) -> f64 {
        match *self {
            Rejection::Mad(k) | Rejection::SinglePass(k) => k,
        }
    }

    /// Refits allowed: [`MAX_REJECT_ROUNDS`] for the repeated rule, one for
    /// the single pass.
    pub(crate) fn rounds(&self) -> usize {
        match self {
            Rejection::Mad(_) => MAX_REJECT_ROUNDS,
            Rejection::SinglePass(_) => 1,
        }
    }

    /// The rule's name in messages.
    pub(crate) fn describe(&self) -> String {
        match self {
            Rejection::Mad(k) => format!("rule 'mad', reject = {k}, robust sigma"),
            Rejection::SinglePass(k) => {
                format!("rule 'e3125' (single pass), reject = {k}, standard deviation")
            }
        }
    }
}

/// Checks a rejection rule: its multiple a positive finite number.
pub(crate) fn check_rejection(reject: Option<Rejection>) -> Result<()> {
    match reject {
        Some(r) if !(r.k().is_finite() && r.k() > 0.0) => Err(CoreError::invalid_argument(
            "reject",
            format!(
                "must be a positive multiple of the rule's sigma, got {}",
                r.k()
            ),
        )),
        _ => Ok(()),
    }
}

/// A fitted model after outlier rejection.
pub(crate) struct Robust<M> {
    pub model: M,
    /// Residuals of all input points against `model`, input order.
    pub residuals: Vec<f64>,
    /// Points `model` was fitted to.
    pub inlier: Vec<bool>,
    /// `false` entries of `inlier`.
    pub rejected: usize,
}

/// Fits `fit` to all points, then (with `reject = Some(k)`) rejects and
/// refits as described in the module docs. `floor` gives the smallest robust
/// sigma used (mm), so noise-free data do not reject their rounding errors;
/// `min` is the fewest inliers the model accepts.
pub(crate) fn fit_robust<M: Sync>(
    pts: &[Vector3<f64>],
    reject: Option<Rejection>,
    min: usize,
    floor: impl Fn(&M) -> f64,
    parallel: bool,
    fit: impl Fn(&[Vector3<f64>]) -> Result<M>,
    residual: impl Fn(&M, &Vector3<f64>) -> f64 + Sync + Send,
) -> Result<Robust<M>> {
    let mut model = fit(pts)?;
    let mut residuals = map_points(pts, parallel, |p| residual(&model, p));
    let mut inlier = vec![true; pts.len()];
    if let Some(rule) = reject {
        for _ in 0..rule.rounds() {
            let (next, sigma) = reclassify(&residuals, &inlier, &rule, floor(&model));
            if next == inlier {
                break;
            }
            let kept: Vec<Vector3<f64>> = pts
                .iter()
                .zip(&next)
                .filter(|(_, &i)| i)
                .map(|(p, _)| *p)
                .collect();
            if kept.len() < min {
                return Err(too_few_inliers(&rule, sigma, kept.len(), pts.len(), min));
            }
            inlier = next;
            model = fit(&kept)?;
            residuals = map_points(pts, parallel, |p| residual(&model, p));
        }
    }
    let rejected = inlier.iter().filter(|&&i| !i).count();
    Ok(Robust {
        model,
        residuals,
        inlier,
        rejected,
    })
}

/// One round of a rejection rule over the current inliers' residuals: the
/// new inlier flags of every point and the sigma used (at least `floor`).
/// [`Rejection::Mad`]: |r - median| <= k * 1.4826 MAD; [`Rejection::SinglePass`]:
/// |r| <= k * s, s the sample standard deviation.
pub(crate) fn reclassify(
    residuals: &[f64],
    inlier: &[bool],
    rule: &Rejection,
    floor: f64,
) -> (Vec<bool>, f64) {
    let inliers = residuals
        .iter()
        .zip(inlier)
        .filter(|(_, &i)| i)
        .map(|(r, _)| *r);
    match *rule {
        Rejection::Mad(k) => {
            let (m, sigma) = median_and_sigma(inliers.collect());
            let sigma = sigma.max(floor);
            let limit = k * sigma;
            (
                residuals.iter().map(|r| (r - m).abs() <= limit).collect(),
                sigma,
            )
        }
        Rejection::SinglePass(k) => {
            let sigma = sample_std(inliers).max(floor);
            let limit = k * sigma;
            (residuals.iter().map(|r| r.abs() <= limit).collect(), sigma)
        }
    }
}

/// Sample standard deviation (n - 1) about the mean; 0 for fewer than two values.
pub(crate) fn sample_std(values: impl Iterator<Item = f64> + Clone) -> f64 {
    let (n, sum) = values
        .clone()
        .fold((0usize, 0.0), |(n, s), v| (n + 1, s + v));
    if n < 2 {
        return 0.0;
    }
    let mean = sum / n as f64;
    let ss: f64 = values.map(|v| (v - mean) * (v - mean)).sum();
    (ss / (n - 1) as f64).sqrt()
}

/// The error when rejection leaves `kept` of `total` points, fewer than `min`.
#[cold]
pub(crate) fn too_few_inliers(
    rule: &Rejection,
    sigma: f64,
    kept: usize,
    total: usize,
    min: usize,
) -> CoreError {
    CoreError::Degenerate(format!(
        "rejecting outliers ({} {sigma:.3e} mm) left {kept} of {total} points, fewer than \
         the {min} the fit needs",
        rule.describe()
    ))
}

/// RMS and form (max - min) of the inliers' residuals.
pub(crate) fn rms_and_form(residuals: &[f64], inlier: &[bool]) -> (f64, f64) {
    let (mut ss, mut n, mut lo, mut hi) = (0.0, 0usize, f64::INFINITY, f64::NEG_INFINITY);
    for (&r, _) in residuals.iter().zip(inlier).filter(|(_, &i)| i) {
        ss += r * r;
        n += 1;
        lo = lo.min(r);
        hi = hi.max(r);
    }
    ((ss / n as f64).sqrt(), hi - lo)
}

/// Deterministic test data: xorshift64* uniforms and Box-Muller Gaussians.
#[cfg(test)]
pub(crate) mod testdata {
    use nalgebra::Vector3;

    pub struct Rng(u64);

    impl Rng {
        pub fn new(seed: u64) -> Self {
            // Any non-zero state works; mix the seed so 1, 2, 3 differ at once.
            Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
        }

        pub fn next_u64(&mut self) -> u64 {
            let mut x = self.0;
            x ^= x >> 12;
            x ^= x << 25;
            x ^= x >> 27;
            self.0 = x;
            x.wrapping_mul(0x2545_F491_4F6C_DD1D)
        }

        /// Uniform in (0, 1): the top 53 bits, offset by half a step.
        pub fn uniform(&mut self) -> f64 {
            ((self.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        }

        /// Standard normal (Box-Muller, one of the pair).
        pub fn gauss(&mut self) -> f64 {
            let (u1, u2) = (self.uniform(), self.uniform());
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        }
    }

    /// A unit vector uniform in area over the cap of half-angle `cap_deg`
    /// about `axis` (unit).
    pub fn cap_direction(rng: &mut Rng, axis: &Vector3<f64>, cap_deg: f64) -> Vector3<f64> {
        let cos_max = cap_deg.to_radians().cos();
        let ct = 1.0 - rng.uniform() * (1.0 - cos_max);
        let st = (1.0 - ct * ct).max(0.0).sqrt();
        let phi = std::f64::consts::TAU * rng.uniform();
        let (u, v) = perpendiculars(axis);
        axis * ct + (u * phi.cos() + v * phi.sin()) * st
    }

    /// `n` unit vectors evenly spread in area over the cap of half-angle
    /// `cap_deg` about `axis` (unit): a golden-angle spiral.
    pub fn cap_spiral(axis: &Vector3<f64>, cap_deg: f64, n: usize) -> Vec<Vector3<f64>> {
        let cos_max = cap_deg.to_radians().cos();
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let (u, v) = perpendiculars(axis);
        (0..n)
            .map(|i| {
                let ct = 1.0 - (i as f64 + 0.5) / n as f64 * (1.0 - cos_max);
                let st = (1.0 - ct * ct).max(0.0).sqrt();
                let phi = golden * i as f64;
                axis * ct + (u * phi.cos() + v * phi.sin()) * st
            })
            .collect()
    }

    /// Two unit vectors completing `axis` to a right-handed frame.
    pub fn perpendiculars(axis: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
        let helper = if axis.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let u = axis.cross(&helper).normalize();
        (u, axis.cross(&u))
    }

    pub fn flatten(pts: &[Vector3<f64>]) -> Vec<f64> {
        pts.iter().flat_map(|p| [p.x, p.y, p.z]).collect()
    }

    /// Sample mean and standard deviation (n - 1).
    pub fn mean_std(v: &[f64]) -> (f64, f64) {
        let n = v.len() as f64;
        let m = v.iter().sum::<f64>() / n;
        let s = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        (m, s)
    }
}

#[cfg(test)]
mod tests {
    use super::testdata::Rng;
    use super::*;

    #[test]
    fn fit_median_and_robust_sigma() {
        // Exact order statistics: no tolerance needed.
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        // MAD of 1..=5 about 3 is 1.
        assert_eq!(
            median_and_sigma(vec![1.0, 2.0, 3.0, 4.0, 5.0]).1,
            MAD_TO_SIGMA
        );
    }

    #[test]
    fn fit_robust_sigma_estimates_gaussian_sigma() {
        // 100,000 N(0, 2^2) draws: the MAD estimator's relative standard
        // error is about 1.17 / sqrt(2 n) = 0.26 %, so 2 % is a safe bound.
        let mut rng = Rng::new(7);
        let s = median_and_sigma((0..100_000).map(|_| 2.0 * rng.gauss()).collect()).1;
        assert!((s / 2.0 - 1.0).abs() < 0.02, "{s}");
    }

    #[test]
    fn fit_reclassify_centres_on_the_median() {
        // Residuals 1 mm +- 0.01 mm (a fit pulled off by outliers), and one
        // point at 3 mm: about zero nothing would be within 3.5 sigma; about
        // the median all but the far point are.
        let mut r: Vec<f64> = (0..100).map(|i| 1.0 + 0.0002 * (i as f64 - 50.0)).collect();
        r.push(3.0);
        let all = vec![true; r.len()];
        let (keep, sigma) = reclassify(&r, &all, &Rejection::Mad(3.5), 0.0);
        assert!(keep[..100].iter().all(|&k| k) && !keep[100]);
        assert!(sigma > 0.0 && sigma < 0.02, "{sigma}");
        // The single pass: about zero, s the sample standard deviation.
        let (keep, s) = reclassify(&r, &all, &Rejection::SinglePass(3.0), 0.0);
        let want = sample_std(r.iter().copied());
        assert_eq!(s, want);
        assert_eq!(
            keep,
            r.iter().map(|x| x.abs() <= 3.0 * want).collect::<Vec<_>>()
        );
        assert_eq!(sample_std([1.0, 2.0, 3.0].into_iter()), 1.0);
        assert_eq!(sample_std([5.0].into_iter()), 0.0);
    }

    #[test]
    fn fit_read_points_checks_shape_count_and_finiteness() {
        let e = read_points(&[0.0; 7], 1, "a thing").unwrap_err();
        assert!(e.to_string().contains("multiple of 3"), "{e}");
        let e = read_points(&[0.0; 6], 3, "a thing").unwrap_err();
        assert_eq!(
            e.to_string(),
            "points: a thing needs at least 3 points, got 2"
        );
        let mut p = vec![0.0; 12];
        p[7] = f64::INFINITY;
        let e = read_points(&p, 3, "a thing").unwrap_err();
        assert_eq!(
            e.to_string(),
            "points: non-finite value (NaN or inf) in row 2"
        );
    }
}
