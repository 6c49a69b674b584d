//! High-breakdown start for a sphere: least median of squares (LMedS,
//! Rousseeuw 1984), docs/fitting.md.
//!
//! 1. Draw `samples` minimal samples of distinct points from a seeded
//!    generator (SplitMix64; the same seed gives the same samples on every
//!    machine and thread count): 4 points with a free radius (the sphere
//!    through them), 3 with a fixed radius R (the two spheres of radius R
//!    through them: the triangle's circumcentre moved by
//!    +-sqrt(R^2 - rho^2) along its normal, rho the circumradius; none when
//!    rho > R). Samples that are (nearly) coplanar, collinear or coincident
//!    give no sphere and are skipped.
//! 2. Score every candidate sphere by the median of the squared residuals
//!    (|p - c| - R)^2 over at most [`SCORE_POINTS`] points (every k-th point
//!    when there are more), candidates in parallel; the lowest median wins
//!    (the earliest sample on a tie, so the result does not depend on the
//!    scheduling). A candidate is first screened against the lowest median
//!    found so far, m: its median exceeds m exactly when fewer than half of
//!    its squared residuals are <= m, which a count settles (stopping as soon
//!    as enough exceed m) without the median's selection; the points are
//!    held as coordinate columns and counted a block at a time in SIMD
//!    lanes. Only candidates that may beat m are ranked, so the winner is the
//!    one full ranking would give, whatever the order the threads meet the
//!    candidates in (a test checks it against full ranking on NIST's scans).
//! 3. Robust scale of the winner over all points,
//!    s0 = 1.4826 (1 + 5 / (N - p)) sqrt(median r^2) (Rousseeuw and Leroy
//!    1987, p the sample size), and its inliers |r| <= 2.5 s0.
//!
//! The median stays on the clean points while they are more than half of
//! them, so the winner is a sphere through clean points at up to (nearly) 50 %
//! contamination of any kind. With w the clean fraction, a sample is clean
//! with probability w^p: 500 samples all miss with probability
//! (1 - 0.5^4)^500 ~ 1e-14 for a free radius at 50 %.

use std::sync::atomic::{AtomicU64, Ordering};

use multiversion::multiversion;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::{median, PARALLEL_MIN_POINTS};
use crate::error::{CoreError, Result};

/// Points scored per candidate at most (evenly strided when there are more).
pub const SCORE_POINTS: usize = 20_000;

/// Inliers of the winning sphere: |r| within this many robust scales.
const INLIER_SCALES: f64 = 2.5;

/// 1.4826 * sqrt(median r^2) estimates sigma for Gaussian noise.
const MAD_TO_SIGMA: f64 = 1.4826;

/// Smallest robust scale used, relative to the radius.
const SCALE_FLOOR: f64 = 1e-12;

/// How to draw the high-breakdown start. `Default`: 500 samples, seed 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LeastMedian {
    /// Minimal samples drawn (at least 1).
    pub samples: usize,
    /// Seed of the sample generator.
    pub seed: u64,
}

impl Default for LeastMedian {
    fn default() -> Self {
        LeastMedian {
            samples: 500,
            seed: 0,
        }
    }
}

/// The winning sphere, its robust scale and its inliers.
#[derive(Debug, Clone)]
pub(crate) struct MedianFit {
    pub centre: Vector3<f64>,
    pub radius: f64,
    /// Robust scale s0 (mm).
    pub scale: f64,
    /// |r| <= 2.5 s0, every input point.
    pub inlier: Vec<bool>,
    pub kept: usize,
}

/// SplitMix64: a small, well-mixed 64-bit generator.
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in 0..n (n > 0), by Lemire's multiply-shift (the bias is
    /// below n / 2^64, immaterial here).
    fn below(&mut self, n: usize) -> usize {
        ((self.next() as u128 * n as u128) >> 64) as usize
    }
}

/// Checks the sampling options.
pub(crate) fn check(opts: &LeastMedian) -> Result<()> {
    if opts.samples == 0 {
        return Err(CoreError::invalid_argument(
            "samples",
            "the high-breakdown start needs at least 1 sample",
        ));
    }
    Ok(())
}

/// `count` samples of `size` distinct indices below `n` (n >= size).
fn draw(n: usize, size: usize, count: usize, seed: u64) -> Vec<[usize; 4]> {
    let mut rng = SplitMix(seed);
    (0..count)
        .map(|_| {
            let mut s = [usize::MAX; 4];
            let mut k = 0;
            while k < size {
                let i = rng.below(n);
                if !s[..k].contains(&i) {
                    s[k] = i;
                    k += 1;
                }
            }
            s
        })
        .collect()
}

fn row(rows: &[f64], i: usize) -> Vector3<f64> {
    Vector3::new(rows[3 * i], rows[3 * i + 1], rows[3 * i + 2])
}

/// The sphere through four points, if they are not (nearly) coplanar.
pub(crate) fn sphere_through_four(p: &[Vector3<f64>; 4]) -> Option<(Vector3<f64>, f64)> {
    // Relative to p0: 2 q_i . x = |q_i|^2 for the centre x - p0.
    let q = [p[1] - p[0], p[2] - p[0], p[3] - p[0]];
    let scale = q.iter().map(|v| v.norm()).fold(0.0, f64::max);
    if scale.is_nan() || scale <= 0.0 {
        return None;
    }
    let a = Matrix3::from_rows(&[
        (2.0 * q[0]).transpose(),
        (2.0 * q[1]).transpose(),
        (2.0 * q[2]).transpose(),
    ]);
    // |det| against the largest it could be for these lengths: a flat
    // tetrahedron has no sphere (or one far away, numerically meaningless).
    if a.determinant().abs() <= 1e-9 * (2.0 * scale).powi(3) {
        return None;
    }
    let b = Vector3::new(
        q[0].norm_squared(),
        q[1].norm_squared(),
        q[2].norm_squared(),
    );
    let x = a.lu().solve(&b)?;
    let r = x.norm();
    r.is_finite().then(|| (p[0] + x, r))
}

/// The (up to two) spheres of radius `radius` through three points.
pub(crate) fn spheres_through_three(
    p: &[Vector3<f64>; 3],
    radius: f64,
) -> [Option<Vector3<f64>>; 2] {
    let (b, c) = (p[1] - p[0], p[2] - p[0]);
    let n = b.cross(&c);
    let n2 = n.norm_squared();
    if n2.is_nan() || n2 <= 1e-18 * b.norm_squared() * c.norm_squared() {
        return [None, None];
    }
    // Circumcentre relative to p0.
    let x = (b.norm_squared() * c - c.norm_squared() * b).cross(&n) / (2.0 * n2);
    let h2 = radius * radius - x.norm_squared();
    if h2.is_nan() || h2 < 0.0 {
        return [None, None];
    }
    let off = n / n2.sqrt() * h2.sqrt();
    let m = p[0] + x;
    [Some(m + off), Some(m - off)]
}

/// The scored points (every `stride`-th row) as three coordinate columns, so
/// the screen below runs over them in SIMD lanes.
struct Scored {
    x: Vec<f64>,
    y: Vec<f64>,
    z: Vec<f64>,
}

impl Scored {
    fn new(rows: &[f64], stride: usize) -> Self {
        let picked = || rows.chunks_exact(3).step_by(stride);
        Scored {
            x: picked().map(|p| p[0]).collect(),
            y: picked().map(|p| p[1]).collect(),
            z: picked().map(|p| p[2]).collect(),
        }
    }

    fn len(&self) -> usize {
        self.x.len()
    }
}

/// Points screened between two looks at the count (a multiple of every
/// SIMD width).
const SCREEN_BLOCK: usize = 256;

/// Whether more than `allowed` of the points have |p - c|^2 outside
/// [lo, hi] (NaN counts as outside). Counted branch-free a block at a time
/// and stopped after the first block that settles it: the answer is the
/// whole count's. Every target does the same IEEE operations per point in
/// the same order (Rust never fuses a multiply and an add), so the counts
/// are those of a scalar loop on any CPU.
#[multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
fn too_many_outside(s: &Scored, c: [f64; 3], lo: f64, hi: f64, allowed: usize) -> bool {
    let mut outside = 0usize;
    let blocks =
        s.x.chunks(SCREEN_BLOCK)
            .zip(s.y.chunks(SCREEN_BLOCK))
            .zip(s.z.chunks(SCREEN_BLOCK));
    for ((x, y), z) in blocks {
        let mut inside = 0u64;
        for ((&x, &y), &z) in x.iter().zip(y).zip(z) {
            let (dx, dy, dz) = (x - c[0], y - c[1], z - c[2]);
            let d2 = dx * dx + dy * dy + dz * dz;
            inside += u64::from((lo <= d2) & (d2 <= hi));
        }
        outside += x.len() - inside as usize;
        if outside > allowed {
            return true;
        }
    }
    false
}

/// Median of (|p - c| - R)^2 over the scored points, or `None` when it is
/// certainly above `best` (fewer than half of them are <= `best`: then
/// both middle order statistics exceed it).
fn score(s: &Scored, c: &Vector3<f64>, r: f64, best: f64, buf: &mut Vec<f64>) -> Option<f64> {
    let scored = s.len();
    // At most this many may exceed `best` for the median to stay <= best.
    let allowed_above = scored - scored.div_ceil(2);
    if best.is_finite() {
        // (|p - c| - R)^2 <= best  <=>  |p - c|^2 in [lo, hi]: no square root
        // per point. The band is widened by a relative 1e-12 so rounding can
        // only keep a candidate, never drop one the median would rank.
        let (w, widen) = (best.sqrt(), 1e-12);
        let lo = ((r - w).max(0.0)).powi(2) * (1.0 - widen);
        let hi = (r + w).powi(2) * (1.0 + widen);
        if too_many_outside(s, [c.x, c.y, c.z], lo, hi, allowed_above) {
            return None;
        }
    }
    buf.clear();
    buf.extend(s.x.iter().zip(&s.y).zip(&s.z).map(|((&x, &y), &z)| {
        let d = ((x - c.x).powi(2) + (y - c.y).powi(2) + (z - c.z).powi(2)).sqrt() - r;
        d * d
    }));
    Some(median(buf))
}

/// LMedS sphere of the rows (N x 3 row-major, mm, finite), fixed radius or
/// free, as described in the module docs.
pub(crate) fn median_fit(
    rows: &[f64],
    fixed: Option<f64>,
    opts: &LeastMedian,
    parallel: bool,
) -> Result<MedianFit> {
    check(opts)?;
    let n = rows.len() / 3;
    let size = if fixed.is_some() { 3 } else { 4 };
    if n < size + 1 {
        return Err(CoreError::invalid_argument(
            "points",
            format!(
                "the high-breakdown start needs at least {} points, got {n}",
                size + 1
            ),
        ));
    }
    let stride = n.div_ceil(SCORE_POINTS);
    let scored = Scored::new(rows, stride);
    let samples = draw(n, size, opts.samples, opts.seed);
    // The lowest median ranked so far, shared by the threads (the bits of a
    // non-negative f64 order as the numbers do).
    let lowest = AtomicU64::new(f64::INFINITY.to_bits());
    // (median, sample index, candidate) of a sample's best candidate.
    let best_of = |(k, s): (usize, &[usize; 4]), buf: &mut Vec<f64>| {
        let cands: [Option<(Vector3<f64>, f64)>; 2] = match fixed {
            Some(r) => {
                let p = [row(rows, s[0]), row(rows, s[1]), row(rows, s[2])];
                spheres_through_three(&p, r).map(|c| c.map(|c| (c, r)))
            }
            None => {
                let p = [
                    row(rows, s[0]),
                    row(rows, s[1]),
                    row(rows, s[2]),
                    row(rows, s[3]),
                ];
                [sphere_through_four(&p), None]
            }
        };
        cands
            .into_iter()
            .flatten()
            .filter_map(|(c, r)| {
                let m = score(
                    &scored,
                    &c,
                    r,
                    f64::from_bits(lowest.load(Ordering::Relaxed)),
                    buf,
                )?;
                if !m.is_finite() {
                    return None;
                }
                lowest.fetch_min(m.to_bits(), Ordering::Relaxed);
                Some((m, k, c, r))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
    };
    let better = |a: (f64, usize, Vector3<f64>, f64), b: (f64, usize, Vector3<f64>, f64)| {
        if (b.0, b.1) < (a.0, a.1) {
            b
        } else {
            a
        }
    };
    let best = if parallel {
        samples
            .par_iter()
            .enumerate()
            .map_init(Vec::new, |buf, ks| best_of(ks, buf))
            .flatten()
            .reduce_with(better)
    } else {
        let mut buf = Vec::new();
        samples
            .iter()
            .enumerate()
            .filter_map(|ks| best_of(ks, &mut buf))
            .reduce(better)
    };
    let (_, _, centre, radius) = best.ok_or_else(|| {
        CoreError::Degenerate(format!(
            "high-breakdown start: none of the {} minimal samples of {size} points gave a \
             sphere{} (coplanar or collinear points?)",
            opts.samples,
            match fixed {
                Some(r) => format!(" of radius {r} mm"),
                None => String::new(),
            }
        ))
    })?;
    let residual = |p: &[f64]| {
        ((p[0] - centre.x).powi(2) + (p[1] - centre.y).powi(2) + (p[2] - centre.z).powi(2)).sqrt()
            - radius
    };
    let res: Vec<f64> = if parallel && n > PARALLEL_MIN_POINTS {
        rows.par_chunks_exact(3).map(residual).collect()
    } else {
        rows.chunks_exact(3).map(residual).collect()
    };
    let mut sq: Vec<f64> = res.iter().map(|r| r * r).collect();
    let med = median(&mut sq);
    let scale =
        (MAD_TO_SIGMA * (1.0 + 5.0 / (n - size) as f64) * med.sqrt()).max(SCALE_FLOOR * radius);
    let limit = INLIER_SCALES * scale;
    let inlier: Vec<bool> = res.iter().map(|r| r.abs() <= limit).collect();
    let kept = inlier.iter().filter(|&&i| i).count();
    Ok(MedianFit {
        centre,
        radius,
        scale,
        inlier,
        kept,
    })
}

#[cfg(test)]
mod tests {
    use super::super::testdata::{cap_direction, flatten, Rng};
    use super::*;

    #[test]
    fn lmeds_minimal_spheres_are_exact() {
        let c = Vector3::new(1.0, -2.0, 3.0);
        let r = 7.5;
        let d = [
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
            Vector3::new(0.6, 0.0, 0.8),
            Vector3::new(-0.36, 0.48, -0.8),
        ];
        let p = d.map(|u| c + u * r);
        let (c4, r4) = sphere_through_four(&p).unwrap();
        assert!((c4 - c).norm() < 1e-12 && (r4 - r).abs() < 1e-12);
        let both = spheres_through_three(&[p[0], p[1], p[2]], r);
        assert!(both.iter().flatten().any(|x| (x - c).norm() < 1e-12));
        // Too small a radius for the triangle: no sphere; coplanar: none.
        assert_eq!(
            spheres_through_three(&[p[0], p[1], p[2]], 0.1),
            [None, None]
        );
        let flat = [p[0], p[1], p[2], (p[0] + p[1]) * 0.5];
        assert!(sphere_through_four(&flat).is_none());
    }

    #[test]
    fn lmeds_draws_are_deterministic_and_distinct() {
        let a = draw(10, 4, 200, 7);
        assert_eq!(a, draw(10, 4, 200, 7));
        assert_ne!(a, draw(10, 4, 200, 8));
        for s in &a {
            let mut v = s.to_vec();
            v.sort();
            v.dedup();
            assert_eq!(v.len(), 4);
            assert!(v.iter().all(|&i| i < 10));
        }
    }

    /// A 90 degree cap (radius 50, centre c) with `frac` of its points
    /// pushed `push` mm outward, all of them on one side of the cap.
    fn one_sided(frac: f64, push: f64, seed: u64) -> (Vec<f64>, Vector3<f64>) {
        let mut rng = Rng::new(seed);
        let c = Vector3::new(10.0, -20.0, 5.0);
        let axis = Vector3::new(0.0, 0.0, 1.0);
        let mut dirs: Vec<Vector3<f64>> = (0..3000)
            .map(|_| cap_direction(&mut rng, &axis, 90.0))
            .collect();
        // The points with the largest x are the contaminated ones.
        dirs.sort_by(|a, b| b.x.total_cmp(&a.x));
        let bad = (frac * dirs.len() as f64) as usize;
        let pts: Vec<Vector3<f64>> = dirs
            .iter()
            .enumerate()
            .map(|(i, u)| {
                let r = 50.0 + 0.01 * rng.gauss() + if i < bad { push } else { 0.0 };
                c + u * r
            })
            .collect();
        (flatten(&pts), c)
    }

    #[test]
    fn lmeds_recovers_the_clean_sphere_under_40_percent_one_sided_contamination() {
        for (fixed, parallel) in [(Some(50.0), true), (None, true), (Some(50.0), false)] {
            let (rows, c) = one_sided(0.4, 5.0, 3);
            let f = median_fit(&rows, fixed, &LeastMedian::default(), parallel).unwrap();
            // A minimal sample through noisy points: within a few noise sigmas.
            assert!((f.centre - c).norm() < 0.1, "{fixed:?}: {}", f.centre - c);
            // Every contaminated point is out, nearly every clean one in.
            assert!(f.inlier[..1200].iter().all(|&i| !i));
            assert!(f.kept > 1750 && f.kept <= 1800, "{}", f.kept);
        }
        // Same seed, same answer, serial or parallel.
        let (rows, _) = one_sided(0.3, 5.0, 4);
        let o = LeastMedian::default();
        let a = median_fit(&rows, Some(50.0), &o, true).unwrap();
        let b = median_fit(&rows, Some(50.0), &o, false).unwrap();
        assert_eq!(
            (a.centre, a.radius, a.inlier),
            (b.centre, b.radius, b.inlier)
        );
    }

    /// The plain algorithm, kept as the reference: every candidate's median
    /// of all its scored squared residuals, the lowest (earliest on a tie)
    /// wins; no screen, serial.
    fn reference_winner(
        rows: &[f64],
        fixed: Option<f64>,
        opts: &LeastMedian,
    ) -> (Vector3<f64>, f64) {
        let n = rows.len() / 3;
        let size = if fixed.is_some() { 3 } else { 4 };
        let stride = n.div_ceil(SCORE_POINTS);
        let mut best: Option<(f64, Vector3<f64>, f64)> = None;
        for s in draw(n, size, opts.samples, opts.seed) {
            let cands: Vec<(Vector3<f64>, f64)> = match fixed {
                Some(r) => {
                    spheres_through_three(&[row(rows, s[0]), row(rows, s[1]), row(rows, s[2])], r)
                        .into_iter()
                        .flatten()
                        .map(|c| (c, r))
                        .collect()
                }
                None => sphere_through_four(&[
                    row(rows, s[0]),
                    row(rows, s[1]),
                    row(rows, s[2]),
                    row(rows, s[3]),
                ])
                .into_iter()
                .collect(),
            };
            for (c, r) in cands {
                let mut sq: Vec<f64> = rows
                    .chunks_exact(3)
                    .step_by(stride)
                    .map(|p| {
                        let d =
                            ((p[0] - c.x).powi(2) + (p[1] - c.y).powi(2) + (p[2] - c.z).powi(2))
                                .sqrt()
                                - r;
                        d * d
                    })
                    .collect();
                let m = median(&mut sq);
                if m.is_finite() && best.is_none_or(|b| m < b.0) {
                    best = Some((m, c, r));
                }
            }
        }
        let (_, c, r) = best.expect("a sphere");
        (c, r)
    }

    /// NIST's raw scans (data/nist_dmg, metres -> mm).
    fn nist_scans() -> Vec<(String, Vec<f64>)> {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/nist_dmg");
        (101..=105)
            .map(|k| {
                let name = format!("SPH{k}");
                let text = std::fs::read_to_string(dir.join(format!("{name}.xyz"))).unwrap();
                let rows = text
                    .split_whitespace()
                    .map(|v| v.parse::<f64>().unwrap() * 1000.0)
                    .collect();
                (name, rows)
            })
            .collect()
    }

    #[test]
    fn lmeds_screen_picks_the_plain_algorithms_winner_on_every_nist_scan() {
        // Each raw scan (35-40 % stand and background) and its points within
        // 60 mm of the closest-point start, fixed and free radius, serial and
        // parallel: the same sphere, bit for bit, as ranking every candidate.
        let o = LeastMedian::default();
        for (name, raw) in nist_scans() {
            let near = raw
                .chunks_exact(3)
                .min_by(|a, b| {
                    let d = |p: &[f64]| p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
                    d(a).total_cmp(&d(b))
                })
                .map(|p| Vector3::new(p[0], p[1], p[2]))
                .unwrap();
            let c0 = near + near.normalize() * 50.0;
            let region: Vec<f64> = raw
                .chunks_exact(3)
                .filter(|p| (Vector3::new(p[0], p[1], p[2]) - c0).norm() < 60.0)
                .flatten()
                .copied()
                .collect();
            for rows in [&raw, &region] {
                for fixed in [Some(50.0), None] {
                    let want = reference_winner(rows, fixed, &o);
                    for parallel in [true, false] {
                        let f = median_fit(rows, fixed, &o, parallel).unwrap();
                        assert_eq!(
                            (f.centre, f.radius),
                            want,
                            "{name} {} points, {fixed:?}",
                            rows.len() / 3
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn lmeds_errors() {
        let e = median_fit(
            &[0.0; 12],
            None,
            &LeastMedian {
                samples: 0,
                seed: 0,
            },
            false,
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("samples: "), "{e}");
        let e = median_fit(&[0.0; 12], None, &LeastMedian::default(), false).unwrap_err();
        assert!(e.to_string().starts_with("points: "), "{e}");
        // Coincident points: no sample gives a sphere.
        let e = median_fit(&[1.0; 30], None, &LeastMedian::default(), false).unwrap_err();
        assert!(e.to_string().contains("none of the 500"), "{e}");
    }
}
