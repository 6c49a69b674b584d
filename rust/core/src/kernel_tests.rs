//! Analytic cases of the kernel: each isolates one term of eqs. 11-13 / 29-31.

use super::*;
use crate::map::{Carriage, CarriageTable};
use crate::pose::Pose;
use crate::units::{ARCSEC_TO_RAD, MAX_LENGTH_MM};

use crate::test_maps::{map_from, points, RANGES};
const OFFSET: [f64; 3] = [1.001, 264.505, 129.575];

/// Two maps, at 20 C and `t_hi`, that differ in every component.
fn two_maps_at(t_hi: f64) -> (ErrorMap, ErrorMap) {
    let lo = map_from(
        |a, p| [p / 50.0, a as f64, 1.0, 0.5, -0.5, p / 300.0],
        [-173.0, -19.0, 21.0],
        Some(20.0),
    );
    let hi = map_from(
        |a, p| [p / 40.0, -(a as f64), 3.0, 1.5, 0.5, -p / 300.0],
        [-178.0, -4.0, 42.0],
        Some(t_hi),
    );
    (lo, hi)
}

fn digitizer(alpha: f64, beta: f64, gamma: f64) -> Digitizer {
    Digitizer::new(&Pose::new(alpha, beta, gamma).unwrap(), OFFSET).unwrap()
}

fn run(map: &ErrorMap, d: &Digitizer, uv: &[f64], s: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let n = s.len() / 3;
    let mut comp = vec![0.0; 3 * n];
    let mut raw = vec![0.0; 3 * n];
    compensate(uv, s, map, d, Options::default(), &mut comp).unwrap();
    uncompensated(uv, s, d, Options::default(), &mut raw).unwrap();
    (comp, raw)
}

#[test]
fn zero_map_gives_the_uncompensated_transform_exactly() {
    let map = map_from(|_, _| [0.0; 6], [0.0; 3], None);
    let (uv, s) = points(10_000);
    for pose in [(90.0, 90.0, 0.0), (180.0, 90.0, 0.0), (12.0, 34.0, 56.0)] {
        let (comp, raw) = run(&map, &digitizer(pose.0, pose.1, pose.2), &uv, &s);
        assert_eq!(comp, raw);
    }
}

#[test]
fn pure_squareness_shifts_by_minus_reading_times_angle() {
    let sq = [-173.0, -19.0, 21.0];
    let map = map_from(|_, _| [0.0; 6], sq, None);
    let (uv, s) = points(1000);
    let (comp, raw) = run(&map, &digitizer(90.0, 90.0, 0.0), &uv, &s);
    let [sxy, syz, szx] = sq.map(|v| v * ARCSEC_TO_RAD);
    for i in 0..1000 {
        let (e_, f_) = (s[3 * i + 1], s[3 * i + 2]);
        assert!((comp[3 * i] - raw[3 * i] - (-e_ * sxy - f_ * szx)).abs() < 1e-12);
        assert!((comp[3 * i + 1] - raw[3 * i + 1] - (-f_ * syz)).abs() < 1e-12);
        assert!((comp[3 * i + 2] - raw[3 * i + 2]).abs() < 1e-12);
    }
}

#[test]
fn pure_linear_scale_error_is_proportional_to_the_reading() {
    // 80 um over 900 mm on X, -30 um over 500 mm on Z (Z table runs -500..0).
    let map = map_from(
        |a, p| match a {
            0 => [p * 80.0 / 900.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            2 => [0.0, 0.0, p * 30.0 / 500.0, 0.0, 0.0, 0.0],
            _ => [0.0; 6],
        },
        [0.0; 3],
        None,
    );
    let (uv, s) = points(1000);
    let (comp, raw) = run(&map, &digitizer(180.0, 90.0, 30.0), &uv, &s);
    for i in 0..1000 {
        assert!((comp[3 * i] - raw[3 * i] - s[3 * i] * 80e-3 / 900.0).abs() < 1e-12);
        assert!((comp[3 * i + 2] - raw[3 * i + 2] - s[3 * i + 2] * 30e-3 / 500.0).abs() < 1e-12);
    }
}

#[test]
fn pure_pitch_error_acts_through_the_ram_and_digitizer_levers() {
    // eps_y(X) = 10 a-s everywhere: the ram (lever F) and the digitizer
    // (lever q = E313 (uv - l1)) both turn about Y by eps.
    let eps_as = 10.0;
    let map = map_from(
        |a, _| {
            if a == 0 {
                [0.0, 0.0, 0.0, 0.0, eps_as, 0.0]
            } else {
                [0.0; 6]
            }
        },
        [0.0; 3],
        None,
    );
    let eps = eps_as * ARCSEC_TO_RAD;
    let d = digitizer(90.0, 90.0, 0.0);
    let (uv, s) = points(1000);
    let (comp, raw) = run(&map, &d, &uv, &s);
    for i in 0..1000 {
        let q = d.lever(uv[2 * i], uv[2 * i + 1]);
        let (se, ce) = eps.sin_cos();
        let rq = Vector3::new(ce * q.x + se * q.z, q.y, -se * q.x + ce * q.z);
        let expected = Vector3::new(s[3 * i + 2] * eps, 0.0, 0.0) + rq - q;
        for k in 0..3 {
            assert!(
                (comp[3 * i + k] - raw[3 * i + k] - expected[k]).abs() < 1e-12,
                "row {i} axis {k}"
            );
        }
        // The digitizer lever (W1 = 129.6 mm along X here) shows the Abbe
        // error in z: -eps * q.x, up to eps^2 |q| / 2 ~ 4e-7 mm.
        assert!((expected.z - (-eps * q.x)).abs() < 1e-6);
    }
}

#[test]
fn rotation_is_orthonormal_and_right_handed() {
    let map = map_from(
        |a, p| {
            [
                0.0,
                0.0,
                0.0,
                3.0 + p / 100.0,
                -2.0 - a as f64,
                4.0 - p / 200.0,
            ]
        },
        [-173.0, -19.0, 21.0],
        None,
    );
    let (_, s) = points(500);
    let mut r = vec![0.0; 9 * 500];
    rotation_error(&s, &map, Options::default(), &mut r).unwrap();
    for m in r.chunks_exact(9) {
        let m = nalgebra::Matrix3::from_row_slice(m);
        assert!((m.transpose() * m - nalgebra::Matrix3::identity()).norm() < 1e-14);
        assert!((m.determinant() - 1.0).abs() < 1e-14);
        // Small rotation about +Z by eps_Z moves X towards +Y (right-hand rule).
        assert!(m[(1, 0)] > 0.0);
    }
}

#[test]
fn midpoint_temperature_gives_mean_of_neighbours() {
    let (lo, hi) = two_maps_at(25.0);
    let set = ErrorMapSet::new(vec![lo.clone(), hi.clone()]).unwrap();
    let (uv, s) = points(2000);
    let d = digitizer(90.0, 90.0, 45.0);
    let mut a = vec![0.0; 6000];
    let mut b = vec![0.0; 6000];
    let mut m = vec![0.0; 6000];
    let mut p = vec![0.0; 6000];
    compensate(&uv, &s, &lo, &d, Options::default(), &mut a).unwrap();
    compensate(&uv, &s, &hi, &d, Options::default(), &mut b).unwrap();
    compensate_at_temperature(&uv, &s, 22.5, &set, &d, Options::default(), &mut m).unwrap();
    compensate_at_temperatures(
        &uv,
        &s,
        &vec![22.5; 2000],
        &set,
        &d,
        Options::default(),
        &mut p,
    )
    .unwrap();
    for k in 0..6000 {
        // Position error is linear in the components; the rotation only to
        // first order: R(mean eps) - mean R(eps) ~ |d eps|^2 |q| ~ (5e-6)^2 * 300 mm.
        assert!(
            (m[k] - 0.5 * (a[k] + b[k])).abs() < 1e-7,
            "{k}: {} vs {}",
            m[k],
            0.5 * (a[k] + b[k])
        );
        assert!((p[k] - m[k]).abs() < 1e-12, "{k}");
    }
    let (mut pa, mut pb, mut pm) = (vec![0.0; 6000], vec![0.0; 6000], vec![0.0; 6000]);
    position_error(&s, &lo, Options::default(), &mut pa).unwrap();
    position_error(&s, &hi, Options::default(), &mut pb).unwrap();
    position_error(
        &s,
        &set.at(22.5, false).unwrap(),
        Options::default(),
        &mut pm,
    )
    .unwrap();
    for k in 0..6000 {
        assert!((pm[k] - 0.5 * (pa[k] + pb[k])).abs() < 1e-15, "{k}");
    }
}

#[test]
fn out_of_range_raises_naming_row_or_clamps_and_counts() {
    let map = map_from(|_, _| [1.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0; 3], None);
    let d = digitizer(90.0, 90.0, 0.0);
    let uv = [0.0, 140.0, 0.0, 140.0, 0.0, 140.0];
    let s = [10.0, 10.0, -10.0, 10.0, 600.0, -10.0, 950.0, 700.0, 5.0];
    let mut out = [0.0; 9];
    let e = compensate(&uv, &s, &map, &d, Options::default(), &mut out).unwrap_err();
    assert_eq!(
        e,
        CoreError::PositionOutOfRange {
            row: 1,
            axis: 'Y',
            value: 600.0,
            lo: 0.0,
            hi: 550.0
        }
    );
    assert!(e
        .to_string()
        .starts_with("row 1: Y scale reading 600 mm is outside the Y map range [0, 550] mm"));
    let opts = Options {
        out_of_range: OutOfRange::Clamp,
        ..Default::default()
    };
    let r = compensate(&uv, &s, &map, &d, opts, &mut out).unwrap();
    assert_eq!(r.clamped_position, [1, 2, 1]);

    let set = ErrorMapSet::new(vec![
        map.clone().with_temperature(Some(20.0)).unwrap(),
        map.with_temperature(Some(30.0)).unwrap(),
    ])
    .unwrap();
    let s_ok = [10.0, 10.0, -10.0, 10.0, 10.0, -10.0, 10.0, 10.0, -10.0];
    let e = compensate_at_temperatures(
        &uv,
        &s_ok,
        &[25.0, 25.0, 31.0],
        &set,
        &d,
        Options::default(),
        &mut out,
    )
    .unwrap_err();
    assert!(
        e.to_string()
            .starts_with("row 2: temperature 31 C is 1.000 K outside the maps' range [20, 30] C"),
        "{e}"
    );
    let r = compensate_at_temperatures(&uv, &s_ok, &[19.0, 25.0, 31.0], &set, &d, opts, &mut out)
        .unwrap();
    assert_eq!(r.clamped_temperature, 2);
    let r = compensate_at_temperature(&uv, &s_ok, 35.0, &set, &d, opts, &mut out).unwrap();
    assert_eq!(r.clamped_temperature, 3);
}

#[test]
fn nan_raises_with_first_row_or_propagates() {
    let map = map_from(|_, _| [0.0; 6], [0.0; 3], None);
    let d = digitizer(90.0, 90.0, 0.0);
    let (mut uv, mut s) = points(10_000);
    s[3 * 9000 + 1] = f64::NAN;
    uv[2 * 7000] = f64::INFINITY;
    let mut out = vec![0.0; 30_000];
    let e = compensate(&uv, &s, &map, &d, Options::default(), &mut out).unwrap_err();
    assert_eq!(
        e,
        CoreError::NonFinite {
            argument: "uv".into(),
            row: 7000
        }
    );
    let opts = Options {
        nan_policy: NanPolicy::Propagate,
        ..Default::default()
    };
    let r = compensate(&uv, &s, &map, &d, opts, &mut out).unwrap();
    assert_eq!(r.nan_rows, 2);
    assert!(out[3 * 9000].is_nan() && out[3 * 7000 + 2].is_nan() && out[3 * 8000].is_finite());
}

#[test]
fn mismatched_lengths_are_rejected() {
    let map = map_from(|_, _| [0.0; 6], [0.0; 3], None);
    let d = digitizer(90.0, 90.0, 0.0);
    let mut out = [0.0; 6];
    let e = compensate(&[0.0; 2], &[1.0; 6], &map, &d, Options::default(), &mut out).unwrap_err();
    assert!(
        e.to_string().starts_with("uv: has 1 rows but scales has 2"),
        "{e}"
    );
    let e = compensate(&[0.0; 4], &[1.0; 5], &map, &d, Options::default(), &mut out).unwrap_err();
    assert!(e.to_string().starts_with("scales: length 5"), "{e}");
}

#[test]
fn threads_do_not_change_results() {
    let map = map_from(
        |a, p| [p / 50.0, a as f64, 1.0, 0.5, -0.5, p / 300.0],
        [-173.0, -19.0, 21.0],
        None,
    );
    let (uv, s) = points(50_000);
    let d = digitizer(10.0, 80.0, 45.0);
    let go = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let mut out = vec![0.0; 150_000];
        pool.install(|| compensate(&uv, &s, &map, &d, Options::default(), &mut out).unwrap());
        out
    };
    assert_eq!(go(1), go(2));
}

#[test]
fn tan_small_matches_libm_to_rounding() {
    let mut worst: f64 = 0.0;
    for i in -20_000..=20_000 {
        let x = i as f64 * (1.0 / 64.0) / 20_000.0 * 1.0001;
        let (a, b) = (tan_small(x), x.tan());
        if b != 0.0 {
            worst = worst.max(((a - b) / b).abs());
        }
    }
    // Two ulps of relative error at most (libm itself is within one).
    assert!(worst < 4.5e-16, "{worst:e}");
    assert_eq!(tan_small(0.5), 0.5f64.tan());
}

#[test]
fn inv_sqrt_one_plus_matches_the_exact_form() {
    for i in 0..=100_000 {
        let a = i as f64 * 2e-11; // up to 2e-6, across the switch at 1e-6
        let exact = (1.0 + a).sqrt().recip();
        assert!(
            (inv_sqrt_one_plus(a) - exact).abs() <= f64::EPSILON,
            "{a:e}"
        );
    }
    assert_eq!(inv_sqrt_one_plus(3.0), 0.5);
}

/// The kernel (block paths, dispatched to the CPU's widest SIMD target) and
/// the portable per-row path give the same bits, on profiles and on random
/// readings, with one map, a map set and several poses.
#[test]
fn block_paths_give_the_same_bits_as_the_rows() {
    let (lo, hi) = two_maps_at(25.0);
    let set = ErrorMapSet::new(vec![lo.clone(), hi]).unwrap();
    let n = 10_000;
    let (uv, s_random) = points(n);
    // Profiles of 37 rows (runs cross chunk and lane boundaries).
    let s_profiles: Vec<f64> = (0..3 * n)
        .map(|k| s_random[3 * (k / 3 / 37 * 37) + k % 3])
        .collect();
    let t_random: Vec<f64> = (0..n)
        .map(|i| 20.0 + 5.0 * (i as f64 * 0.618).fract())
        .collect();
    let t_profiles: Vec<f64> = (0..n).map(|i| t_random[i / 37 * 37]).collect();
    let ds = [digitizer(90.0, 90.0, 45.0), digitizer(0.0, 30.0, -10.0)];
    let pose_index: Vec<u32> = (0..n).map(|i| ((i / 37) % 2) as u32).collect();
    for (s, t) in [(&s_random, &t_random), (&s_profiles, &t_profiles)] {
        for with_set in [false, true] {
            let columns = if with_set {
                Columns::new().with("temperature", 1, t)
            } else {
                Columns::new()
            };
            let pts = Points {
                uv: &uv,
                scales: s,
                pose_index: Some(&pose_index),
                columns: columns.clone(),
            };
            let maps = if with_set {
                MapSource::Set(&set)
            } else {
                MapSource::Map(&lo)
            };
            let mut fast = vec![0.0; 3 * n];
            let rf = compensate_points(
                &pts,
                maps,
                &ds,
                &Effects::none(),
                Options::default(),
                &mut fast,
            )
            .unwrap();
            let inputs = Inputs {
                uv: Some(&uv),
                scales: s,
                columns: &columns,
            };
            let row_fn = |i: usize,
                          sc: [f64; 3],
                          slot: &mut [f64],
                          report: &mut Report,
                          _: &mut ()|
             -> Result<()> {
                let tt = Temperatures::uniform(t[i]);
                let (c, sq) = if with_set {
                    set.evaluate(i, sc, &tt, &Options::default(), report)?
                } else {
                    lo.evaluate(i, sc, &tt, &Options::default(), report)?
                };
                let pe =
                    PointError::new(sc, &c, sq, &crate::kinematics::Kinematics::thesis().arms());
                let d = &ds[pose_index[i] as usize];
                let x = Vector3::from(sc) + pe.e + pe.rotate(&d.lever(uv[2 * i], uv[2 * i + 1]));
                slot.copy_from_slice(x.as_slice());
                Ok(())
            };
            let mut rows = vec![0.0; 3 * n];
            let rr = block_rows::<(), _>(&inputs, Options::default(), &mut rows, 0, 3, &row_fn);
            assert!(rr.1.is_none());
            assert_eq!(rf.points, n);
            let differ = fast
                .iter()
                .zip(&rows)
                .filter(|(x, y)| x.to_bits() != y.to_bits())
                .count();
            assert_eq!(
                differ,
                0,
                "set {with_set}, profiles {}",
                std::ptr::eq(s, &s_profiles)
            );
        }
    }
}

// ---- the kernel with effects switched on (the diagnosis model) ----------

use crate::effects::Effects;
use crate::truth::true_frames;

fn two_maps() -> ErrorMapSet {
    let (lo, hi) = two_maps_at(30.0);
    ErrorMapSet::new(vec![lo, hi]).unwrap()
}

struct Case {
    uv: Vec<f64>,
    s: Vec<f64>,
    t: Vec<f64>,
    idx: Vec<u32>,
}

fn case(n: usize) -> Case {
    let (uv, s) = points(n);
    Case {
        uv,
        s,
        t: (0..n)
            .map(|i| 25.0 + 4.0 * (i as f64 * 1.3).sin())
            .collect(),
        idx: (0..n).map(|i| (i % 2) as u32).collect(),
    }
}

fn two_digitizers() -> Vec<Digitizer> {
    vec![digitizer(90.0, 90.0, 0.0), digitizer(180.0, 90.0, 30.0)]
}

fn model_run(c: &Case, cols: Columns, fx: &Effects, opts: Options) -> Result<(Vec<f64>, Report)> {
    let set = two_maps();
    let points = Points {
        uv: &c.uv,
        scales: &c.s,
        pose_index: Some(&c.idx),
        columns: cols,
    };
    let mut out = vec![0.0; c.s.len()];
    let r = compensate_points(
        &points,
        MapSource::Set(&set),
        &two_digitizers(),
        fx,
        opts,
        &mut out,
    )?;
    Ok((out, r))
}

#[test]
fn no_effects_is_the_thesis_kernel_bit_for_bit_at_each_pose() {
    let c = case(10_001);
    let (got, _) = model_run(
        &c,
        Columns::new().with("temperature", 1, &c.t),
        &Effects::none(),
        Options::default(),
    )
    .unwrap();
    let set = two_maps();
    for (p, d) in two_digitizers().iter().enumerate() {
        let rows: Vec<usize> = (0..c.idx.len())
            .filter(|&i| c.idx[i] as usize == p)
            .collect();
        let pick = |v: &[f64], w: usize| -> Vec<f64> {
            rows.iter()
                .flat_map(|&i| v[w * i..w * i + w].to_vec())
                .collect()
        };
        let mut want = vec![0.0; 3 * rows.len()];
        compensate_at_temperatures(
            &pick(&c.uv, 2),
            &pick(&c.s, 3),
            &pick(&c.t, 1),
            &set,
            d,
            Options::default(),
            &mut want,
        )
        .unwrap();
        assert!(pick(&got, 3)
            .iter()
            .zip(&want)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
    }
}

#[test]
fn axis_temperature_gain_one_with_equal_axes_is_the_uniform_model() {
    let c = case(101);
    let axis: Vec<f64> = c.t.iter().flat_map(|&t| [t, t, t]).collect();
    let cols = || {
        Columns::new()
            .with("temperature", 1, &c.t)
            .with("axis_temperature", 3, &axis)
    };
    let fx = Effects::new([("axis-temperature", vec![1.0])]).unwrap();
    let (a, _) = model_run(&c, cols(), &fx, Options::default()).unwrap();
    let (b, _) = model_run(&c, cols(), &Effects::none(), Options::default()).unwrap();
    assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-12));
    // Offset axes do change the result.
    let warm: Vec<f64> = c.t.iter().flat_map(|&t| [t + 1.0, t, t]).collect();
    let cols = Columns::new()
        .with("temperature", 1, &c.t)
        .with("axis_temperature", 3, &warm);
    let (w, _) = model_run(&c, cols, &fx, Options::default()).unwrap();
    assert!(w.iter().zip(&b).any(|(x, y)| (x - y).abs() > 1e-6));
}

#[test]
fn squareness_temperature_takes_the_maps_squareness_at_the_sensor() {
    // Two maps 20 and 30 C: squareness is linear in temperature between
    // them, so squareness read at the sensor (gain 1) equals the mean's
    // squareness plus the map's change over (sensor - mean), which the
    // `squareness` term adds as a constant when the mean is constant.
    let mut c = case(64);
    c.t = vec![23.0; 64];
    let sensor = vec![25.5; 64];
    let cols = || {
        Columns::new()
            .with("temperature", 1, &c.t)
            .with("squareness_sensor", 1, &sensor)
    };
    let fx = Effects::new([("squareness-temperature", vec![1.0])]).unwrap();
    let (got, _) = model_run(&c, cols(), &fx, Options::default()).unwrap();
    // Slopes per K of the two maps' squareness (a-s): (-178 + 173)/10 etc.
    let per_k = [-0.5, 1.5, 2.1];
    let shift: Vec<f64> = per_k.iter().map(|k| k * 2.5).collect();
    let sq = Effects::new([("squareness", shift)]).unwrap();
    let (want, _) = model_run(
        &c,
        Columns::new().with("temperature", 1, &c.t),
        &sq,
        Options::default(),
    )
    .unwrap();
    assert!(got.iter().zip(&want).all(|(a, b)| (a - b).abs() < 1e-9));
    // Gain 1/2 goes half way; a sensor at the mean changes nothing.
    let half = Effects::new([("squareness-temperature", vec![0.5])]).unwrap();
    let (h, _) = model_run(&c, cols(), &half, Options::default()).unwrap();
    let (none, _) = model_run(
        &c,
        Columns::new().with("temperature", 1, &c.t),
        &Effects::none(),
        Options::default(),
    )
    .unwrap();
    for k in 0..got.len() {
        assert!((h[k] - 0.5 * (got[k] + none[k])).abs() < 1e-9);
    }
    let at_mean = Columns::new()
        .with("temperature", 1, &c.t)
        .with("squareness_sensor", 1, &c.t);
    let (m, _) = model_run(&c, at_mean, &fx, Options::default()).unwrap();
    assert!(m.iter().zip(&none).all(|(a, b)| a.to_bits() == b.to_bits()));
    // The carriages stay at the mean: axis-temperature reads the mean, not
    // the squareness temperature the term before it set.
    let axis: Vec<f64> = c.t.iter().flat_map(|&t| [t, t, t]).collect();
    let both = Effects::new([
        ("axis-temperature", vec![1.0]),
        ("squareness-temperature", vec![1.0]),
    ])
    .unwrap();
    let (b, _) = model_run(
        &c,
        cols().with("axis_temperature", 3, &axis),
        &both,
        Options::default(),
    )
    .unwrap();
    assert!(b.iter().zip(&got).all(|(x, y)| (x - y).abs() < 1e-12));
}

#[test]
fn latency_moves_the_reading_along_the_velocity() {
    let c = case(20);
    let vel: Vec<f64> = (0..20).flat_map(|_| [35.0, 0.0, 0.0]).collect();
    let fx = Effects::new([("latency", vec![0.01])]).unwrap();
    let cols = Columns::new()
        .with("temperature", 1, &c.t)
        .with("velocity", 3, &vel);
    let (got, _) = model_run(&c, cols, &fx, Options::default()).unwrap();
    let mut moved = case(20);
    for i in 0..20 {
        moved.s[3 * i] += 0.35;
    }
    let (want, _) = model_run(
        &moved,
        Columns::new().with("temperature", 1, &moved.t),
        &Effects::none(),
        Options::default(),
    )
    .unwrap();
    assert!(got.iter().zip(&want).all(|(x, y)| (x - y).abs() < 1e-12));
}

#[test]
fn model_inverts_the_truth_machine_with_machine_effects_on() {
    // The same terms forward in the exact truth machine and inverted by the
    // first-order kernel: what is left is second order (< 0.05 um).
    let set = two_maps();
    let n = 2000;
    let c = case(n);
    let grad: Vec<f64> = (0..n).map(|i| 1.5 * (i as f64 * 0.1).cos()).collect();
    let axis: Vec<f64> =
        c.t.iter()
            .flat_map(|&t| [t + 0.7, t - 0.4, t + 0.2])
            .collect();
    let fx = Effects::new([
        ("squareness", vec![5.0, -3.0, 8.0]),
        ("scale", vec![6.0, -4.0, 9.0]),
        ("roll", vec![10.0, -7.0, 4.0]),
        ("granite-gradient", vec![2.0, 10.0, -6.0]),
        ("axis-temperature", vec![1.0]),
        ("squareness-temperature", vec![1.0]),
    ])
    .unwrap();
    let sensor: Vec<f64> = c.t.iter().map(|&t| t - 0.8).collect();
    let cols = || {
        Columns::new()
            .with("temperature", 1, &c.t)
            .with("gradient", 1, &grad)
            .with("axis_temperature", 3, &axis)
            .with("squareness_sensor", 1, &sensor)
    };
    let tf = true_frames(&c.s, &cols(), &set, &fx).unwrap();
    let (got, _) = model_run(&c, cols(), &fx, Options::default()).unwrap();
    let (thesis, _) = model_run(
        &c,
        Columns::new().with("temperature", 1, &c.t),
        &Effects::none(),
        Options::default(),
    )
    .unwrap();
    let ds = two_digitizers();
    let (mut worst, mut worst_thesis) = (0.0f64, 0.0f64);
    for i in 0..n {
        let r = nalgebra::Matrix3::from_row_slice(&tf.r[9 * i..9 * i + 9]);
        let d = &ds[c.idx[i] as usize];
        let truth = Vector3::new(tf.p[3 * i], tf.p[3 * i + 1], tf.p[3 * i + 2])
            + r * d.lever(c.uv[2 * i], c.uv[2 * i + 1]);
        let at = |v: &[f64]| Vector3::new(v[3 * i], v[3 * i + 1], v[3 * i + 2]);
        worst = worst.max((truth - at(&got)).norm());
        worst_thesis = worst_thesis.max((truth - at(&thesis)).norm());
    }
    assert!(worst < 5e-5, "{worst:e} mm");
    assert!(
        worst_thesis > 1e-3,
        "the effects must matter: {worst_thesis:e} mm"
    );
}

#[test]
fn model_errors_name_argument_and_row_and_clamping_is_counted() {
    let mut c = case(10);
    c.t[4] = 45.0;
    fn cols(c: &Case) -> Columns<'_> {
        Columns::new().with("temperature", 1, &c.t)
    }
    let e = model_run(&c, cols(&c), &Effects::none(), Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("45") && e.contains("row 4"), "{e}");
    let opts = Options {
        out_of_range: OutOfRange::Clamp,
        ..Default::default()
    };
    let (_, r) = model_run(&c, cols(&c), &Effects::none(), opts).unwrap();
    assert_eq!((r.clamped_temperature, r.clamped_points), (1, 1));
    c.t[4] = 25.0;
    c.uv[7] = f64::NAN;
    let e = model_run(&c, cols(&c), &Effects::none(), Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("uv") && e.contains("row 3"), "{e}");
    c.uv[7] = 0.0;
    c.idx[2] = 9;
    let e = model_run(&c, cols(&c), &Effects::none(), Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("pose_index") && e.contains("row 2"), "{e}");
    c.idx[2] = 0;
    let fx = Effects::new([("latency", vec![0.01])]).unwrap();
    let e = model_run(&c, cols(&c), &fx, Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("velocity"), "{e}");
    let e = model_run(&c, Columns::new(), &Effects::none(), Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("temperature"), "{e}");
}

// ---- temperatures outside the maps: tolerance, clamp, extrapolate ---------

fn run_t(t: &[f64], opts: Options) -> Result<(Vec<f64>, Report)> {
    let set = two_maps();
    let n = t.len();
    let (uv, s) = points(n);
    let mut out = vec![0.0; 3 * n];
    let r = compensate_at_temperatures(
        &uv,
        &s,
        t,
        &set,
        &digitizer(90.0, 90.0, 0.0),
        opts,
        &mut out,
    )?;
    Ok((out, r))
}

#[test]
fn a_hair_outside_is_held_at_the_edge_and_counted() {
    let opts = Options {
        temperature_tolerance: 0.5,
        ..Default::default()
    };
    let (got, r) = run_t(&[19.9998, 30.3, 25.0], opts).unwrap();
    assert_eq!(
        (r.held_temperature, r.clamped_temperature, r.clamped_points),
        (2, 0, 0)
    );
    let (want, _) = run_t(&[20.0, 30.0, 25.0], Options::default()).unwrap();
    assert!(got
        .iter()
        .zip(&want)
        .all(|(a, b)| a.to_bits() == b.to_bits()));
    // Beyond the tolerance: an error naming the row, the distance and the tolerance.
    let e = run_t(&[25.0, 19.2], opts).unwrap_err().to_string();
    assert!(
        e.contains("row 1") && e.contains("0.800 K") && e.contains("0.5 K tolerance"),
        "{e}"
    );
}

#[test]
fn extrapolation_extends_the_end_slope_and_reports_the_distance() {
    let opts = Options {
        out_of_range: OutOfRange::Extrapolate,
        temperature_tolerance: 0.5,
        ..Default::default()
    };
    let (x, r) = run_t(&[32.0, 18.0, 25.0], opts).unwrap();
    assert_eq!(r.extrapolated_temperature, 2);
    assert!((r.max_extrapolation - 2.0).abs() < 1e-12);
    // Linear in temperature: the 32 C point lies on the line through 28 and 30 C.
    let (a, _) = run_t(&[28.0, 18.0, 25.0], opts).unwrap();
    let (b, _) = run_t(&[30.0, 18.0, 25.0], opts).unwrap();
    // Components are linear in temperature; X is linear in them to first
    // order (the rotation's second order in arc-second angles: < 1e-9 mm).
    for k in 0..3 {
        let d = (x[k] - (b[k] + (b[k] - a[k]))).abs();
        assert!(d < 1e-7, "{d:e} mm");
    }
    // The blended single-temperature path agrees.
    let set = two_maps();
    let (m, one) = set.at_with(32.0, &opts).unwrap();
    assert_eq!(one.extrapolated_temperature, 1);
    let (uv, s) = points(3);
    let mut y = vec![0.0; 9];
    compensate(&uv, &s, &m, &digitizer(90.0, 90.0, 0.0), opts, &mut y).unwrap();
    assert!((y[0] - x[0]).abs() < 1e-9 && (y[1] - x[1]).abs() < 1e-9);
}

#[test]
fn inputs_beyond_a_machines_lengths_are_refused_naming_the_row_on_every_path() {
    // A finite number beyond 100 m is not millimetres: refused whatever the
    // NaN or range policy, on the profile path (points sharing a reading),
    // the lane path (random readings) and the per-row path (one point),
    // naming the argument and the first such row. Without the bound, u = 5e5
    // gives a finite nonsense on every path.
    let map = map_from(|_, _| [0.0; 6], [0.0; 3], None);
    let d = digitizer(90.0, 90.0, 0.0);
    let (uv, s) = points(10_000);
    let profiles: Vec<f64> = (0..10_000)
        .flat_map(|i| [100.0 + (i / 1000) as f64, 50.0, -20.0])
        .collect();
    let opts = Options {
        out_of_range: OutOfRange::Clamp,
        nan_policy: NanPolicy::Propagate,
        ..Default::default()
    };
    for readings in [&s, &profiles] {
        let mut bad_uv = uv.clone();
        bad_uv[2 * 7000 + 1] = 5e5;
        let mut bad_s = readings.to_vec();
        bad_s[3 * 9000 + 2] = -2e5;
        let mut out = vec![0.0; 30_000];
        let e = compensate(&bad_uv, &bad_s, &map, &d, opts, &mut out).unwrap_err();
        let text = e.to_string();
        assert!(
            text.starts_with("uv: row 7000: 500000 mm is beyond"),
            "{text}"
        );
        let e = compensate(&uv, &bad_s, &map, &d, opts, &mut out).unwrap_err();
        let text = e.to_string();
        assert!(
            text.starts_with("scales: row 9000: -200000 mm is beyond"),
            "{text}"
        );
        let e = uncompensated(&bad_uv, readings, &d, opts, &mut out).unwrap_err();
        assert!(e.to_string().starts_with("uv: row 7000:"), "{e}");
    }
    // A temperature no machine works at is not held at the maps' edge.
    let set = two_maps();
    for readings in [&s, &profiles] {
        let mut t = vec![21.0; 10_000];
        t[4321] = -300.0;
        let mut out = vec![0.0; 30_000];
        let e = compensate_at_temperatures(&uv, readings, &t, &set, &d, opts, &mut out)
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "temperature: row 4321: -300 C is outside -50 to 150 C: not degrees C on a machine"
        );
    }
    // At the bound itself a row is taken (a machine's lengths, inclusive).
    let mut out = [0.0; 3];
    compensate(
        &[MAX_LENGTH_MM, 0.0],
        &[100.0, 50.0, -20.0],
        &map,
        &d,
        opts,
        &mut out,
    )
    .unwrap();
    assert!(out.iter().all(|x| x.is_finite()));
}

#[test]
fn the_error_is_no_larger_than_its_variants_before_the_bounds() {
    // Results carry it through the kernel's hot loops: the bounds' variant
    // (an owned name, a row, a value, a small enum) must not widen it.
    assert!(
        std::mem::size_of::<CoreError>() <= 56,
        "{}",
        std::mem::size_of::<CoreError>()
    );
}

#[test]
fn plausible_inputs_whose_point_is_not_are_refused_naming_the_row() {
    // Maps 1e-9 C apart extrapolated to 30 C: a slope of 1e14 um/K makes
    // the point far beyond MAX_RESULT_MM from plausible inputs.
    let lo = map_from(|_, _| [0.0; 6], [0.0; 3], Some(20.0));
    let hi = map_from(
        |_, _| [1e5, 0.0, 0.0, 0.0, 0.0, 0.0],
        [0.0; 3],
        Some(20.0 + 1e-9),
    );
    let set = ErrorMapSet::new(vec![lo, hi]).unwrap();
    let d = digitizer(90.0, 90.0, 0.0);
    let (uv, s) = points(3);
    let opts = Options {
        out_of_range: OutOfRange::Extrapolate,
        ..Default::default()
    };
    let mut out = [0.0; 9];
    let e = compensate_at_temperatures(&uv, &s, &[20.0, 30.0, 20.0], &set, &d, opts, &mut out)
        .unwrap_err()
        .to_string();
    assert!(e.contains("row 1") && e.contains("is beyond"), "{e}");
}

#[test]
fn profiles_reuse_the_error_state_with_the_same_bits_and_counts() {
    // 12 profiles of 50 points sharing a reading and a temperature, some
    // outside the map (clamped) and some a hair outside the temperatures
    // (held): the whole call equals each point alone, bit for bit, and the
    // report counts every point.
    let set = two_maps();
    let d = digitizer(90.0, 90.0, 30.0);
    let (uv, _) = points(600);
    let mut s = Vec::new();
    let mut t = Vec::new();
    for k in 0..12 {
        let reading = [
            100.0 + 70.0 * k as f64,
            50.0 + 40.0 * k as f64,
            -20.0 - 30.0 * k as f64,
        ];
        let reading = if k == 5 {
            [950.0, 100.0, -100.0]
        } else {
            reading
        };
        for _ in 0..50 {
            s.extend(reading);
            t.push(if k == 7 { 30.2 } else { 21.0 + 0.5 * k as f64 });
        }
    }
    let opts = Options {
        out_of_range: OutOfRange::Clamp,
        temperature_tolerance: 0.5,
        ..Default::default()
    };
    let mut all = vec![0.0; 1800];
    let r = compensate_at_temperatures(&uv, &s, &t, &set, &d, opts, &mut all).unwrap();
    assert_eq!(
        (r.clamped_position[0], r.held_temperature, r.clamped_points),
        (50, 50, 50)
    );
    for i in 0..600 {
        let mut one = [0.0; 3];
        compensate_at_temperatures(
            &uv[2 * i..2 * i + 2],
            &s[3 * i..3 * i + 3],
            &t[i..i + 1],
            &set,
            &d,
            opts,
            &mut one,
        )
        .unwrap();
        assert!(
            one.iter()
                .zip(&all[3 * i..3 * i + 3])
                .all(|(a, b)| a.to_bits() == b.to_bits()),
            "row {i}"
        );
    }
}

/// With effects switched on, profiles share one machine state per run (the
/// block path) and give the bits of the per-row path, which each row run
/// alone takes; the angle of incidence varies point by point inside a
/// profile, as on a real scan, and must not break the runs' sharing.
#[test]
fn model_profiles_give_the_bits_of_single_rows() {
    let (lo, hi) = two_maps_at(25.0);
    let set = ErrorMapSet::new(vec![lo, hi]).unwrap();
    let n = 3000;
    let profile = |i: usize| i / 37 * 37;
    let (uv, s0) = points(n);
    let s: Vec<f64> = (0..3 * n).map(|k| s0[3 * profile(k / 3) + k % 3]).collect();
    let t: Vec<f64> = (0..n)
        .map(|i| 20.5 + 4.0 * (profile(i) as f64 * 0.618).fract())
        .collect();
    let axis: Vec<f64> = (0..3 * n)
        .map(|k| t[k / 3] + 0.1 * (k % 3) as f64)
        .collect();
    let gradient: Vec<f64> = (0..n).map(|i| 0.01 * (profile(i) % 7) as f64).collect();
    let velocity: Vec<f64> = (0..3 * n)
        .map(|k| ((profile(k / 3) + k % 3) % 5) as f64)
        .collect();
    let mount: Vec<f64> = (0..n).map(|i| 21.0 + (profile(i) % 3) as f64).collect();
    let incidence: Vec<f64> = (0..n).map(|i| (i % 41) as f64).collect();
    let fx = Effects::new([
        ("squareness", vec![2.0, -3.0, 4.0]),
        ("scale", vec![5.0, -6.0, 7.0]),
        ("roll", vec![1.0, 2.0, -1.0]),
        ("axis-temperature", vec![0.7]),
        ("granite-gradient", vec![3.0, 1.0, -2.0]),
        ("latency", vec![0.002]),
        ("scanner-scale", vec![3e-4, -7e-4]),
        ("incidence", vec![2e-4, 3e-5]),
        ("mount-expansion", vec![23.0]),
    ])
    .unwrap();
    let ds = [digitizer(90.0, 90.0, 45.0), digitizer(0.0, 30.0, -10.0)];
    let pose_index: Vec<u32> = (0..n).map(|i| ((i / 37) % 2) as u32).collect();
    let cols = |r: std::ops::Range<usize>| {
        Columns::new()
            .with("temperature", 1, &t[r.clone()])
            .with("axis_temperature", 3, &axis[3 * r.start..3 * r.end])
            .with("gradient", 1, &gradient[r.clone()])
            .with("velocity", 3, &velocity[3 * r.start..3 * r.end])
            .with("mount_temperature", 1, &mount[r.clone()])
            .with("incidence", 1, &incidence[r.clone()])
    };
    let whole = Points {
        uv: &uv,
        scales: &s,
        pose_index: Some(&pose_index),
        columns: cols(0..n),
    };
    let mut fast = vec![0.0; 3 * n];
    compensate_points(
        &whole,
        MapSource::Set(&set),
        &ds,
        &fx,
        Options::default(),
        &mut fast,
    )
    .unwrap();
    for i in 0..n {
        let one = Points {
            uv: &uv[2 * i..2 * i + 2],
            scales: &s[3 * i..3 * i + 3],
            pose_index: Some(&pose_index[i..i + 1]),
            columns: cols(i..i + 1),
        };
        let mut row = [0.0; 3];
        compensate_points(
            &one,
            MapSource::Set(&set),
            &ds,
            &fx,
            Options::default(),
            &mut row,
        )
        .unwrap();
        for k in 0..3 {
            assert_eq!(fast[3 * i + k].to_bits(), row[k].to_bits(), "row {i}");
        }
    }
}

/// A NaN in an input no switched-on effect reads is not an error; in one
/// that is read, it is, naming the input and the row.
#[test]
fn nan_only_matters_in_inputs_the_call_reads() {
    let map = map_from(|_, _| [0.0; 6], [0.0; 3], None);
    let (uv, s) = points(100);
    let mut gradient = vec![0.0; 100];
    gradient[42] = f64::NAN;
    let pts = Points {
        uv: &uv,
        scales: &s,
        pose_index: None,
        columns: Columns::new().with("gradient", 1, &gradient),
    };
    let d = [digitizer(90.0, 90.0, 0.0)];
    let mut out = vec![0.0; 300];
    compensate_points(
        &pts,
        MapSource::Map(&map),
        &d,
        &Effects::none(),
        Options::default(),
        &mut out,
    )
    .unwrap();
    let fx = Effects::new([("granite-gradient", vec![1.0, 0.0, 0.0])]).unwrap();
    let e = compensate_points(
        &pts,
        MapSource::Map(&map),
        &d,
        &fx,
        Options::default(),
        &mut out,
    )
    .unwrap_err();
    assert_eq!(
        e,
        CoreError::NonFinite {
            argument: "gradient".into(),
            row: 42
        }
    );
}

/// The random-readings block path locates readings as the per-row path
/// does: on a uniform grid (readings on nodes and at the ends included) and
/// on an uneven one.
#[test]
fn random_blocks_locate_as_the_rows_do() {
    let uniform = map_from(
        |a, p| [p / 50.0, a as f64, 1.0, 0.5, -0.5, p / 300.0],
        [-173.0, -19.0, 21.0],
        None,
    );
    let uneven = {
        let tables = std::array::from_fn(|a| {
            let (lo, hi) = RANGES[a];
            let mut p = lo;
            let mut rows = Vec::new();
            let mut k = 0;
            while p < hi {
                rows.push([p, p / 40.0, -(a as f64), 3.0, 1.5, 0.5, -p / 300.0]);
                p += [7.0, 31.0, 18.5][k % 3];
                k += 1;
            }
            rows.push([hi, hi / 40.0, -(a as f64), 3.0, 1.5, 0.5, -hi / 300.0]);
            CarriageTable::from_table_units(Carriage::ALL[a], &rows).unwrap()
        });
        ErrorMap::new(tables, [1.0, 2.0, 3.0], None).unwrap()
    };
    let n = 5000;
    let (uv, mut s) = points(n);
    // Every 7th row on a 25 mm node, the first rows at the ends.
    for i in (0..n).step_by(7) {
        for a in 0..3 {
            s[3 * i + a] = (s[3 * i + a] / 25.0).round() * 25.0;
        }
    }
    for a in 0..3 {
        s[a] = RANGES[a].0;
        s[3 + a] = RANGES[a].1;
    }
    let d = digitizer(90.0, 90.0, 45.0);
    let columns = Columns::new();
    let inputs = Inputs {
        uv: Some(&uv),
        scales: &s,
        columns: &columns,
    };
    for map in [&uniform, &uneven] {
        let mut fast = vec![0.0; 3 * n];
        compensate(&uv, &s, map, &d, Options::default(), &mut fast).unwrap();
        let row_fn = |i: usize,
                      sc: [f64; 3],
                      slot: &mut [f64],
                      report: &mut Report,
                      _: &mut ()|
         -> Result<()> {
            let (c, sq) = map.evaluate(
                i,
                sc,
                &Temperatures::uniform(f64::NAN),
                &Options::default(),
                report,
            )?;
            let pe = PointError::new(sc, &c, sq, &crate::kinematics::Kinematics::thesis().arms());
            let x = Vector3::from(sc) + pe.e + pe.rotate(&d.lever(uv[2 * i], uv[2 * i + 1]));
            slot.copy_from_slice(x.as_slice());
            Ok(())
        };
        let mut rows = vec![0.0; 3 * n];
        assert!(
            block_rows::<(), _>(&inputs, Options::default(), &mut rows, 0, 3, &row_fn)
                .1
                .is_none()
        );
        assert!(fast
            .iter()
            .zip(&rows)
            .all(|(x, y)| x.to_bits() == y.to_bits()));
    }
}
