//! Analytic cases of the kernel: each isolates one term of eqs. 11-13 / 29-31.

use super::*;
use crate::map::{Carriage, CarriageTable};
use crate::pose::Pose;
use crate::units::ARCSEC_TO_RAD;

const RANGES: [(f64, f64); 3] = [(0.0, 900.0), (0.0, 550.0), (-500.0, 0.0)];
const OFFSET: [f64; 3] = [1.001, 264.505, 129.575];

/// A map with table rows given by `f(carriage, position) -> 6 components`
/// in table units (um, arc-second) on a 25 mm grid.
fn map_from(f: impl Fn(usize, f64) -> [f64; 6], squareness: [f64; 3], t: Option<f64>) -> ErrorMap {
    let tables = std::array::from_fn(|a| {
        let (lo, hi) = RANGES[a];
        let rows: Vec<[f64; 7]> = (0..=((hi - lo) / 25.0) as usize)
            .map(|i| {
                let p = lo + 25.0 * i as f64;
                let c = f(a, p);
                [p, c[0], c[1], c[2], c[3], c[4], c[5]]
            })
            .collect();
        CarriageTable::from_table_units(Carriage::ALL[a], &rows).unwrap()
    });
    ErrorMap::new(tables, squareness, t).unwrap()
}

/// Deterministic pseudo-random points inside the volume.
fn points(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut state = 0x2545F4914F6CDD1Du64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut uv = Vec::with_capacity(2 * n);
    let mut s = Vec::with_capacity(3 * n);
    for _ in 0..n {
        uv.push(-30.0 + 60.0 * next());
        uv.push(110.0 + 60.0 * next());
        for (lo, hi) in RANGES {
            s.push(lo + (hi - lo) * next());
        }
    }
    (uv, s)
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
    let lo = map_from(
        |a, p| [p / 50.0, a as f64, 1.0, 0.5, -0.5, p / 300.0],
        [-173.0, -19.0, 21.0],
        Some(20.0),
    );
    let hi = map_from(
        |a, p| [p / 40.0, -(a as f64), 3.0, 1.5, 0.5, -p / 300.0],
        [-178.0, -4.0, 42.0],
        Some(25.0),
    );
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
        map.clone().with_temperature(Some(20.0)),
        map.with_temperature(Some(30.0)),
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
            .starts_with("row 2: temperature 31 C is outside the maps' range [20, 30] C"),
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
            argument: "uv",
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

#[cfg(target_arch = "x86_64")]
#[test]
fn avx2_block_gives_the_same_bits_as_the_portable_one() {
    if !has_avx2() {
        return; // nothing to compare on this CPU
    }
    let lo = map_from(
        |a, p| [p / 50.0, a as f64, 1.0, 0.5, -0.5, p / 300.0],
        [-173.0, -19.0, 21.0],
        Some(20.0),
    );
    let hi = map_from(
        |a, p| [p / 40.0, -(a as f64), 3.0, 1.5, 0.5, -p / 300.0],
        [-178.0, -4.0, 42.0],
        Some(25.0),
    );
    let set = ErrorMapSet::new(vec![lo, hi]).unwrap();
    let (uv, s) = points(5000);
    let t: Vec<f64> = (0..5000)
        .map(|i| 20.0 + 5.0 * (i as f64 * 0.618).fract())
        .collect();
    let d = digitizer(90.0, 90.0, 45.0);
    let inputs = Inputs {
        uv: Some(&uv),
        scales: &s,
        temperatures: Some(&t),
    };
    let row_fn =
        |i: usize, sc: [f64; 3], tt: f64, slot: &mut [f64], report: &mut Report| -> Result<()> {
            let (c, sq) = set.evaluate(i, sc, tt, false, report)?;
            let pe = PointError::new(sc, &c, sq);
            let x = Vector3::from(sc) + pe.e + pe.rotate(&d.lever(uv[2 * i], uv[2 * i + 1]));
            slot.copy_from_slice(x.as_slice());
            Ok(())
        };
    let (mut a, mut b) = (vec![0.0; 15000], vec![0.0; 15000]);
    let ra = block_rows(&inputs, Options::default(), &mut a, 0, 3, &row_fn);
    // SAFETY: AVX2 detected above.
    let rb = unsafe { block_avx2(&inputs, Options::default(), &mut b, 0, 3, &row_fn) };
    assert!(ra.1.is_none() && rb.1.is_none());
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
}
