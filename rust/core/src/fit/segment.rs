//! Segmentation of a sphere from a raw scan, in the manner of ASTM E3125
//! (docs/fitting.md, "Segmentation"): the scanner's origin is known, the
//! sphere's calibrated radius R is fixed in every fit.
//!
//! 1. Start: the point closest to the scanner; the first centre estimate lies
//!    one radius beyond it along the line of sight from the scanner (or a
//!    given starting centre).
//! 2. First region: the points within R of the line of sight through that
//!    estimate, and within R of it along the line. A least-median start
//!    ([`super::lmeds`], radius fixed) and a least-squares refit of its
//!    inliers give the first centre; a stray point nearer the scanner than the
//!    sphere (a mixed pixel, dust) thus costs nothing.
//! 3. Region about a centre c, the line of sight u running from the scanner
//!    to c: the points inside the cone with its apex at c, about -u (towards
//!    the scanner), of half-angle theta (60 degrees: the standard's 120 degree
//!    cone), and inside the cylinder of radius R sin(theta) about the line of
//!    sight. The cone keeps the side facing the scanner, the cylinder the
//!    points that project onto the cap; together they drop the stand and the
//!    background and the grazing rim where a scanner's points are worst.
//! 4. Fit the region's points with the radius fixed, from the current centre,
//!    with the rejection rule (the standard's single pass: drop |r| > 3 s, s
//!    the sample standard deviation of the residuals, and refit once); take
//!    the region about the new centre; repeat until the region stops changing
//!    (at most `max_rounds` fits). The last fit is the result.
//!
//! The per-point passes (closest point, regions, residuals) run in parallel
//! over the points.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::lmeds::LeastMedian;
use super::sphere::{fit, SphereFit, SphereFitOptions, Start};
use super::{check_rejection, check_rows, non_finite, select_rows, Rejection, CHUNK};
use crate::error::{CoreError, Result};

/// How to segment a sphere from a raw scan. `new` gives the standard's
/// choices: 60 degree half-angle, single pass at 3 standard deviations, at
/// most 50 rounds, closest-point start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SegmentationOptions {
    /// Calibrated sphere radius (mm), fixed in every fit.
    pub radius: f64,
    /// The scanner's origin in the points' frame (mm).
    pub origin: [f64; 3],
    /// Starting centre (mm); `None`: one radius beyond the closest point.
    pub start: Option<[f64; 3]>,
    /// Half-angle (degrees, in (0, 90]) of the cone at the centre and of the
    /// cylinder's radius R sin(theta).
    pub half_angle_deg: f64,
    /// Rejection rule of every region fit (step 4).
    pub rule: Option<Rejection>,
    /// Region fits allowed before giving up on convergence (at least 1).
    pub max_rounds: usize,
    /// Samples and seed of the least-median start in the first region.
    pub sampling: LeastMedian,
    /// Levenberg-Marquardt steps allowed per fit (at least 1).
    pub max_iterations: usize,
}

impl SegmentationOptions {
    /// The standard's choices for a sphere of `radius` (mm) scanned from
    /// `origin` (mm).
    pub fn new(radius: f64, origin: [f64; 3]) -> Self {
        SegmentationOptions {
            radius,
            origin,
            start: None,
            half_angle_deg: 60.0,
            rule: Some(Rejection::SinglePass(3.0)),
            max_rounds: 50,
            sampling: LeastMedian::default(),
            max_iterations: 100,
        }
    }
}

/// A segmented and fitted sphere.
#[derive(Debug, Clone, PartialEq)]
pub struct Segmentation {
    /// The last region fit: residuals of every input point against it (mm,
    /// input order); `inlier` marks the points it used (in the region and
    /// kept by the rule); `rejected` counts the region's points the rule set
    /// aside.
    pub fit: SphereFit,
    /// Whether each input point lies in the region `fit` was fitted to
    /// (step 3): the converged region.
    pub region: Vec<bool>,
    /// Row of the point closest to the scanner (`None` with a given start).
    pub closest: Option<usize>,
    /// The first centre estimate (mm): one radius beyond the closest point,
    /// or the given start.
    pub initial_centre: [f64; 3],
    /// The centre fitted to the first region (mm).
    pub first_centre: [f64; 3],
    /// Region fits made (step 4), the last one included.
    pub rounds: usize,
    /// `false` when `max_rounds` ran out before the region stopped changing.
    pub converged: bool,
}

fn check(opts: &SegmentationOptions) -> Result<()> {
    let r = opts.radius;
    if !(r.is_finite() && r > 0.0) {
        return Err(CoreError::invalid_argument(
            "radius",
            format!("the calibrated radius must be a positive length in mm, got {r}"),
        ));
    }
    if !opts.origin.iter().all(|x| x.is_finite()) {
        return Err(CoreError::invalid_argument(
            "scanner_origin",
            format!("must be finite (mm), got {:?}", opts.origin),
        ));
    }
    if let Some(c) = opts.start {
        if !c.iter().all(|x| x.is_finite()) {
            return Err(CoreError::invalid_argument(
                "start",
                format!("a starting centre must be finite (mm), got {c:?}"),
            ));
        }
    }
    let a = opts.half_angle_deg;
    if !(a > 0.0 && a <= 90.0) {
        return Err(CoreError::invalid_argument(
            "half_angle",
            format!("must be an angle in (0, 90] degrees, got {a}"),
        ));
    }
    check_rejection(opts.rule)?;
    if opts.max_rounds == 0 {
        return Err(CoreError::invalid_argument(
            "max_rounds",
            "must be at least 1",
        ));
    }
    super::lmeds::check(&opts.sampling)?;
    if opts.max_iterations == 0 {
        return Err(CoreError::invalid_argument(
            "max_iterations",
            "must be at least 1",
        ));
    }
    Ok(())
}

/// Row of the point nearest `o` (the first on a tie) and its squared distance.
fn closest_point(points: &[f64], o: &Vector3<f64>) -> (usize, f64) {
    points
        .par_chunks_exact(3)
        .with_min_len(CHUNK)
        .enumerate()
        .map(|(i, p)| ((Vector3::new(p[0], p[1], p[2]) - o).norm_squared(), i))
        .reduce_with(|a, b| if (b.0, b.1) < (a.0, a.1) { b } else { a })
        .map(|(d2, i)| (i, d2))
        .expect("at least one point")
}

/// `keep(p)` for every point, in parallel.
fn mask(points: &[f64], keep: impl Fn(Vector3<f64>) -> bool + Sync + Send) -> Vec<bool> {
    points
        .par_chunks_exact(3)
        .with_min_len(CHUNK)
        .map(|p| keep(Vector3::new(p[0], p[1], p[2])))
        .collect()
}

/// Unit line of sight from `o` to `c`.
fn line_of_sight(o: &Vector3<f64>, c: &Vector3<f64>) -> Result<Vector3<f64>> {
    let d = c - o;
    let n = d.norm();
    if n.is_nan() || n <= 0.0 {
        return Err(CoreError::invalid_argument(
            "scanner_origin",
            format!(
                "coincides with the centre estimate {:?} mm: no line of sight",
                [c.x, c.y, c.z]
            ),
        ));
    }
    Ok(d / n)
}

/// The region about the centre `c` (module docs, step 3): inside the cone
/// at `c` of half-angle theta about the direction to the scanner, and within
/// R sin(theta) of the line of sight.
pub(crate) fn region(
    points: &[f64],
    o: &Vector3<f64>,
    c: &Vector3<f64>,
    radius: f64,
    half_angle_deg: f64,
) -> Result<Vec<bool>> {
    let u = line_of_sight(o, c)?;
    let (sin, cos) = half_angle_deg.to_radians().sin_cos();
    let cyl2 = (radius * sin).powi(2);
    Ok(mask(points, |p| {
        let v = p - o;
        let t = v.dot(&u);
        let w = p - c;
        // Cone: the angle between c -> p and c -> scanner within theta.
        (v.norm_squared() - t * t) <= cyl2 && -w.dot(&u) >= cos * w.norm()
    }))
}

fn count(m: &[bool]) -> usize {
    m.iter().filter(|&&k| k).count()
}

/// Segments the sphere of calibrated radius `opts.radius` from the raw
/// `points` (N x 3 row-major, mm) scanned from `opts.origin`, and fits it
/// (module docs).
///
/// Errors: `InvalidArgument` for a bad option, fewer than 4 points, a
/// non-finite coordinate (naming the first bad row), or a scanner origin on
/// a point or centre estimate; `Degenerate` when a region holds fewer than 4
/// points or a fit fails.
pub fn segment_sphere(points: &[f64], opts: &SegmentationOptions) -> Result<Segmentation> {
    check(opts)?;
    let n = check_rows(points, 4, "a sphere segmentation")?;
    if let Some(e) = non_finite(points) {
        return Err(e);
    }
    let (r, o) = (opts.radius, Vector3::from(opts.origin));
    let (closest, c0) = match opts.start {
        Some(c) => (None, Vector3::from(c)),
        None => {
            let (i, d2) = closest_point(points, &o);
            let p = Vector3::new(points[3 * i], points[3 * i + 1], points[3 * i + 2]);
            if d2.is_nan() || d2 <= 0.0 {
                return Err(CoreError::invalid_argument(
                    "scanner_origin",
                    format!("coincides with point {i}: no line of sight"),
                ));
            }
            (Some(i), p + (p - o) / d2.sqrt() * r)
        }
    };
    let fixed = |start: Start, reject: Option<Rejection>| SphereFitOptions {
        radius: Some(r),
        reject,
        start,
        max_iterations: opts.max_iterations,
        min_coverage_deg: 0.0,
    };
    // Step 2: the first region and its high-breakdown fit.
    let u0 = line_of_sight(&o, &c0)?;
    let t0 = (c0 - o).dot(&u0);
    let first = mask(points, |p| {
        let v = p - o;
        let t = v.dot(&u0);
        (v.norm_squared() - t * t) <= r * r && (t - t0).abs() <= r
    });
    let k = count(&first);
    let where_ = match closest {
        Some(i) => format!("one radius beyond the closest point (row {i})"),
        None => "the given start".to_string(),
    };
    if k < 4 {
        return Err(CoreError::Degenerate(format!(
            "the first region about {where_}, centre {:?} mm, holds {k} points: \
             fewer than the 4 a sphere needs (is scanner_origin right, and the radius?)",
            [c0.x, c0.y, c0.z]
        )));
    }
    let f = fit(
        &select_rows(points, &first),
        &fixed(Start::LeastMedian(opts.sampling), None),
        true,
    )?;
    let mut c = Vector3::from(f.centre);
    let first_centre = f.centre;
    // Steps 3 and 4: region, fit, until the region stops changing.
    let mut last: Option<(Vec<bool>, SphereFit)> = None;
    let mut rounds = 0;
    let converged = loop {
        let reg = region(points, &o, &c, r, opts.half_angle_deg)?;
        if let Some((fitted, _)) = &last {
            if *fitted == reg {
                break true;
            }
        }
        if rounds == opts.max_rounds {
            break false;
        }
        let k = count(&reg);
        if k < 4 {
            return Err(CoreError::Degenerate(format!(
                "the region about centre {:?} mm holds {k} points after {rounds} fits: \
                 fewer than the 4 a sphere needs",
                [c.x, c.y, c.z]
            )));
        }
        let f = fit(
            &select_rows(points, &reg),
            &fixed(Start::Centre([c.x, c.y, c.z]), opts.rule),
            true,
        )?;
        c = Vector3::from(f.centre);
        rounds += 1;
        last = Some((reg, f));
    };
    let (reg, mut f) = last.expect("max_rounds >= 1: at least one fit");
    // Residuals of every point; the fit's inliers back in input order.
    let fc = Vector3::from(f.centre);
    f.residuals = points
        .par_chunks_exact(3)
        .with_min_len(CHUNK)
        .map(|p| (Vector3::new(p[0], p[1], p[2]) - fc).norm() - r)
        .collect();
    let mut used = f.inlier.iter();
    f.inlier = reg
        .iter()
        .map(|&k| k && *used.next().expect("one flag per region point"))
        .collect();
    debug_assert_eq!(f.inlier.len(), n);
    Ok(Segmentation {
        fit: f,
        region: reg,
        closest,
        initial_centre: [c0.x, c0.y, c0.z],
        first_centre,
        rounds,
        converged,
    })
}

#[cfg(test)]
mod tests {
    use super::super::testdata::{cap_direction, flatten, Rng};
    use super::*;

    /// A scan of a sphere (radius 50, centre 2.8 m away from the scanner
    /// at `o`, a little above it) as the scanner sees it: the hemisphere facing it, 0.05 mm
    /// noise, with a stand below, a wall behind and a stray point in front.
    fn scan(o: Vector3<f64>, seed: u64) -> (Vec<f64>, Vector3<f64>) {
        let mut rng = Rng::new(seed);
        let c = o + Vector3::new(2000.0, 2000.0, 300.0);
        let u = (o - c).normalize();
        let mut pts: Vec<Vector3<f64>> = (0..4000)
            .map(|_| c + cap_direction(&mut rng, &u, 85.0) * (50.0 + 0.05 * rng.gauss()))
            .collect();
        // Stand: a vertical rod of radius 10 under the sphere (the part the
        // scanner sees, roughly).
        for _ in 0..1500 {
            let h = 49.0 + 150.0 * rng.uniform();
            let a = std::f64::consts::TAU * rng.uniform();
            pts.push(c + Vector3::new(10.0 * a.cos(), 10.0 * a.sin(), -h));
        }
        // Wall behind: a plane 400 mm beyond the centre, normal to the line of sight.
        let (e1, e2) = super::super::testdata::perpendiculars(&u);
        for _ in 0..1500 {
            let (a, b) = (400.0 * rng.uniform() - 200.0, 400.0 * rng.uniform() - 200.0);
            let q = c - u * 400.0 + e1 * a + e2 * b;
            // Hidden behind the sphere: not seen.
            let dir = (q - o).normalize();
            let along = (c - o).dot(&dir);
            if ((c - o) - dir * along).norm() > 50.0 {
                pts.push(q);
            }
        }
        // A stray point 20 mm in front of the sphere on the line of sight.
        pts.push(c + u * 70.0);
        (flatten(&pts), c)
    }

    #[test]
    fn segment_sphere_finds_the_centre_of_a_raw_scan() {
        let o = Vector3::new(100.0, -50.0, 20.0);
        let (rows, c) = scan(o, 1);
        let opts = SegmentationOptions::new(50.0, [o.x, o.y, o.z]);
        let s = segment_sphere(&rows, &opts).unwrap();
        assert!(s.converged && s.rounds >= 1);
        let last = rows.len() / 3 - 1;
        // The stray point is the closest one; its start still converges.
        assert_eq!(s.closest, Some(last));
        // 4000 points with 0.05 mm noise: the centre within ~1e-3 mm.
        let err = (Vector3::from(s.fit.centre) - c).norm();
        assert!(err < 0.005, "{err}");
        // Only sphere points are used: the first 4000 rows. The stray point
        // lies in the region (on the line of sight), the final rule drops it.
        assert!(s.fit.inlier[4000..].iter().all(|&k| !k));
        assert!(s.region[4000..last].iter().all(|&k| !k) && s.region[last]);
        assert!(s.fit.rejected >= 1 && s.fit.residuals[last] > 19.0);
        // The 60 degree cap of an 85 degree scan: ~ (1 - cos 60)/(1 - cos 85)
        // of the sphere's points.
        let used = s.fit.n_points as f64 / 4000.0;
        assert!(
            (used - 0.5 / (1.0 - 85f64.to_radians().cos())).abs() < 0.05,
            "{used}"
        );
        assert_eq!(s.fit.residuals.len(), rows.len() / 3);
        assert_eq!(s.fit.radius, 50.0);
        // A start near the centre gives the same region and centre.
        let near = SegmentationOptions {
            start: Some([c.x + 5.0, c.y - 3.0, c.z + 2.0]),
            ..opts
        };
        let t = segment_sphere(&rows, &near).unwrap();
        assert_eq!(t.closest, None);
        assert_eq!(t.region, s.region);
        assert!((Vector3::from(t.fit.centre) - Vector3::from(s.fit.centre)).norm() < 1e-9);
    }

    #[test]
    fn segment_sphere_errors() {
        let (rows, _) = scan(Vector3::zeros(), 2);
        let ok = SegmentationOptions::new(50.0, [0.0; 3]);
        let cases: Vec<(SegmentationOptions, &str)> = vec![
            (SegmentationOptions { radius: 0.0, ..ok }, "radius: "),
            (
                SegmentationOptions {
                    origin: [f64::NAN, 0.0, 0.0],
                    ..ok
                },
                "scanner_origin: ",
            ),
            (
                SegmentationOptions {
                    half_angle_deg: 95.0,
                    ..ok
                },
                "half_angle: ",
            ),
            (
                SegmentationOptions {
                    max_rounds: 0,
                    ..ok
                },
                "max_rounds: ",
            ),
            (
                SegmentationOptions {
                    rule: Some(Rejection::SinglePass(-1.0)),
                    ..ok
                },
                "reject: ",
            ),
            (
                SegmentationOptions {
                    start: Some([f64::INFINITY, 0.0, 0.0]),
                    ..ok
                },
                "start: ",
            ),
        ];
        for (o, msg) in cases {
            let e = segment_sphere(&rows, &o).unwrap_err();
            assert!(e.to_string().starts_with(msg), "{e}");
        }
        let e = segment_sphere(&rows[..9], &ok).unwrap_err();
        assert!(e.to_string().starts_with("points: "), "{e}");
        // A start far from every point: the first region is empty.
        let far = SegmentationOptions {
            start: Some([-1e4, 0.0, 0.0]),
            ..ok
        };
        let e = segment_sphere(&rows, &far).unwrap_err();
        assert!(e.to_string().contains("holds 0 points"), "{e}");
    }
}
