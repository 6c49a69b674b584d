//! Each source alone against the kernel itself: the input moved by a small
//! step, the points' change over the step is the sensitivity, and the
//! stated covariance must be u^2 g g^T. The model is linear in every input
//! but the angles; an angle's second-order term is (step + the map's own
//! angles, ~1e-5 rad) relative, so 1e-4 relative holds on any CPU (rounding
//! of ~1e3 mm coordinates over a 1e-3 mm change is 1e-10 relative).

use super::*;
use crate::effects::{Columns, Effects};
use crate::kernel::{compensate_points, MapSource, Points};
use crate::thermal::ErrorMapSet;
use crate::units::ARCSEC_TO_RAD;

use crate::test_maps::{map_from, points, RANGES};
const OFFSET: [f64; 3] = [1.001, 264.505, 129.575];
const POSE: (f64, f64, f64) = (90.0, 90.0, 10.0);

fn components(a: usize, p: f64) -> [f64; 6] {
    [p / 50.0, a as f64, 1.0, 0.5, -0.5, p / 300.0]
}

const SQUARENESS: [f64; 3] = [-173.0, -19.0, 21.0];

fn pose() -> Pose {
    Pose::new(POSE.0, POSE.1, POSE.2).unwrap()
}

struct Case<'a> {
    uv: &'a [f64],
    s: &'a [f64],
    t: Option<&'a [f64]>,
}

impl<'a> Case<'a> {
    /// The kernel's points: (u, v), readings and, when given, a temperature per point.
    fn points(&self) -> Points<'a> {
        Points {
            uv: self.uv,
            scales: self.s,
            pose_index: None,
            columns: match self.t {
                Some(t) => Columns::new().with("temperature", 1, t),
                None => Columns::new(),
            },
        }
    }
}

fn xyz(case: &Case, maps: MapSource, pose: &Pose, offset: [f64; 3]) -> Vec<f64> {
    let d = Digitizer::new(pose, offset).unwrap();
    let points = case.points();
    let mut out = vec![0.0; case.s.len()];
    compensate_points(
        &points,
        maps,
        &[d],
        &Effects::none(),
        Options::default(),
        &mut out,
    )
    .unwrap();
    out
}

fn stated(case: &Case, maps: MapSource, sources: &Sources) -> (Vec<f64>, Vec<f64>) {
    let d = Digitizer::new(&pose(), OFFSET).unwrap();
    let points = case.points();
    let n = case.s.len() / 3;
    let (mut out, mut unc) = (vec![0.0; 3 * n], vec![0.0; 15 * n]);
    crate::kernel::compensate_points_with_uncertainty(
        &points,
        maps,
        &[d],
        &Effects::none(),
        Options::default(),
        sources,
        Detail::Split,
        &mut out,
        &mut unc,
    )
    .unwrap();
    (out, unc)
}

/// The stated covariance (total, entries 3..9) against u^2 g g^T with
/// g = (moved - base) / step, relative to the largest entry.
fn agrees(unc: &[f64], base: &[f64], moved: &[f64], step: f64, u: f64) {
    let n = base.len() / 3;
    let mut worst: f64 = 0.0;
    for i in 0..n {
        let g: Vec<f64> = (0..3)
            .map(|k| (moved[3 * i + k] - base[3 * i + k]) / step)
            .collect();
        let want = [
            g[0] * g[0],
            g[1] * g[1],
            g[2] * g[2],
            g[0] * g[1],
            g[0] * g[2],
            g[1] * g[2],
        ]
        .map(|v| v * u * u);
        let got = &unc[15 * i + 3..15 * i + 9];
        let scale = want[..3].iter().fold(0.0f64, |a, &b| a.max(b)).max(1e-30);
        for k in 0..6 {
            worst = worst.max((got[k] - want[k]).abs() / scale);
        }
        for k in 0..3 {
            assert!((unc[15 * i + k] - got[k].sqrt()).abs() <= 1e-12 * got[k].sqrt().max(1e-300));
        }
    }
    assert!(worst < 1e-4, "worst relative difference {worst:e}");
}

#[test]
fn each_map_component_alone_matches_the_kernel_moved_by_it() {
    let (uv, s) = points(300);
    let case = Case {
        uv: &uv,
        s: &s,
        t: None,
    };
    let base_map = map_from(components, SQUARENESS, None);
    let base = xyz(&case, MapSource::Map(&base_map), &pose(), OFFSET);
    for carriage in 0..3 {
        for j in 0..6 {
            // One um or one arc-second, as the tables are written.
            let moved_map = map_from(
                |a, p| {
                    let mut c = components(a, p);
                    if a == carriage {
                        c[j] += 1.0;
                    }
                    c
                },
                SQUARENESS,
                None,
            );
            let moved = xyz(&case, MapSource::Map(&moved_map), &pose(), OFFSET);
            let (step, u) = if j < 3 {
                (1e-3, 2e-3)
            } else {
                (ARCSEC_TO_RAD, 3.0 * ARCSEC_TO_RAD)
            };
            let mut sources = Sources::default();
            if j < 3 {
                sources.map.position[carriage][j] = u;
            } else {
                sources.map.rotation[carriage][j - 3] = u;
            }
            let (out, unc) = stated(&case, MapSource::Map(&base_map), &sources);
            assert_eq!(out, base, "the points are the plain kernel's bits");
            agrees(&unc, &base, &moved, step, u);
        }
    }
    for j in 0..3 {
        let mut sq = SQUARENESS;
        sq[j] += 1.0;
        let moved = xyz(
            &case,
            MapSource::Map(&map_from(components, sq, None)),
            &pose(),
            OFFSET,
        );
        let mut sources = Sources::default();
        sources.map.squareness[j] = 2.0 * ARCSEC_TO_RAD;
        let (_, unc) = stated(&case, MapSource::Map(&base_map), &sources);
        agrees(&unc, &base, &moved, ARCSEC_TO_RAD, 2.0 * ARCSEC_TO_RAD);
    }
}

#[test]
#[allow(clippy::needless_range_loop)]
fn positioning_grows_with_the_distance_from_its_reference() {
    let (uv, s) = points(300);
    let case = Case {
        uv: &uv,
        s: &s,
        t: None,
    };
    let base_map = map_from(components, SQUARENESS, None);
    let base = xyz(&case, MapSource::Map(&base_map), &pose(), OFFSET);
    for axis in 0..3 {
        // One um per metre from the table's start: 1e-6 relative.
        let reference = RANGES[axis].0;
        let moved_map = map_from(
            |a, p| {
                let mut c = components(a, p);
                if a == axis {
                    c[a] += (p - reference) / 1000.0;
                }
                c
            },
            SQUARENESS,
            None,
        );
        let moved = xyz(&case, MapSource::Map(&moved_map), &pose(), OFFSET);
        let mut sources = Sources::default();
        sources.map.positioning[axis] = 2.5e-6;
        sources.map.reference[axis] = reference;
        let (_, unc) = stated(&case, MapSource::Map(&base_map), &sources);
        agrees(&unc, &base, &moved, 1e-6, 2.5e-6);
    }
}

#[test]
fn temperature_acts_through_the_map_sets_thermal_sensitivity() {
    let (uv, s) = points(300);
    let lo = map_from(components, SQUARENESS, Some(20.0));
    let hi = map_from(
        |a, p| [p / 40.0, -(a as f64), 3.0, 1.5, 0.5, -p / 300.0],
        [-178.0, -4.0, 42.0],
        Some(24.0),
    );
    let set = ErrorMapSet::new(vec![lo, hi]).unwrap();
    let t: Vec<f64> = (0..300).map(|i| 20.5 + 3.0 * i as f64 / 300.0).collect();
    let t_moved: Vec<f64> = t.iter().map(|x| x + 0.1).collect();
    let case = Case {
        uv: &uv,
        s: &s,
        t: Some(&t),
    };
    let base = xyz(&case, MapSource::Set(&set), &pose(), OFFSET);
    let moved_case = Case {
        uv: &uv,
        s: &s,
        t: Some(&t_moved),
    };
    let moved = xyz(&moved_case, MapSource::Set(&set), &pose(), OFFSET);
    let sources = Sources {
        temperature: 0.2,
        ..Default::default()
    };
    let (_, unc) = stated(&case, MapSource::Set(&set), &sources);
    agrees(&unc, &base, &moved, 0.1, 0.2);
    // One map has no thermal sensitivity: the temperature adds nothing.
    let map = map_from(components, SQUARENESS, None);
    let plain = Case {
        uv: &uv,
        s: &s,
        t: None,
    };
    let (_, unc) = stated(&plain, MapSource::Map(&map), &sources);
    assert!(unc.iter().all(|&v| v == 0.0));
}

#[test]
fn pose_offset_scale_and_noise_match_the_kernel_moved_by_them() {
    let (uv, s) = points(300);
    let case = Case {
        uv: &uv,
        s: &s,
        t: None,
    };
    let map = map_from(components, SQUARENESS, None);
    let base = xyz(&case, MapSource::Map(&map), &pose(), OFFSET);
    let zero = [[0.0; 3]; 3];
    let with_pose = |offset_cov, angle_cov, noise| Sources {
        poses: vec![PoseUncertainty::new(&pose(), OFFSET, offset_cov, angle_cov, noise).unwrap()],
        ..Default::default()
    };
    // The mount offset, one component at a time.
    for k in 0..3 {
        let mut offset = OFFSET;
        offset[k] += 1e-3;
        let moved = xyz(&case, MapSource::Map(&map), &pose(), offset);
        let mut cov = zero;
        cov[k][k] = 0.01f64.powi(2);
        let (_, unc) = stated(&case, MapSource::Map(&map), &with_pose(cov, zero, [0.0; 2]));
        agrees(&unc, &base, &moved, 1e-3, 0.01);
    }
    // The angles, one at a time (a 1e-4 degree step).
    for k in 0..3 {
        let mut a = [POSE.0, POSE.1, POSE.2];
        a[k] += 1e-4;
        let moved = xyz(
            &case,
            MapSource::Map(&map),
            &Pose::new(a[0], a[1], a[2]).unwrap(),
            OFFSET,
        );
        let mut cov = zero;
        let u = 0.01f64.to_radians();
        cov[k][k] = u * u;
        let (_, unc) = stated(&case, MapSource::Map(&map), &with_pose(zero, cov, [0.0; 2]));
        agrees(&unc, &base, &moved, 1e-4f64.to_radians(), u);
    }
    // The scanner's scale: (u, v) stretched.
    let stretched: Vec<f64> = uv.iter().map(|x| x * (1.0 + 1e-6)).collect();
    let moved = xyz(
        &Case {
            uv: &stretched,
            s: &s,
            t: None,
        },
        MapSource::Map(&map),
        &pose(),
        OFFSET,
    );
    let sources = Sources {
        scanner_scale: 50e-6,
        ..Default::default()
    };
    let (_, unc) = stated(&case, MapSource::Map(&map), &sources);
    agrees(&unc, &base, &moved, 1e-6, 50e-6);
    // The noise: independent, the common part stays zero.
    let shifted: Vec<f64> = uv
        .iter()
        .enumerate()
        .map(|(i, x)| if i % 2 == 0 { x + 1e-3 } else { *x })
        .collect();
    let moved = xyz(
        &Case {
            uv: &shifted,
            s: &s,
            t: None,
        },
        MapSource::Map(&map),
        &pose(),
        OFFSET,
    );
    let (_, unc) = stated(
        &case,
        MapSource::Map(&map),
        &with_pose(zero, zero, [0.02, 0.0]),
    );
    agrees(&unc, &base, &moved, 1e-3, 0.02);
    assert!(unc.chunks(15).all(|r| r[9..15].iter().all(|&v| v == 0.0)));
}

#[test]
fn bad_sources_are_refused_by_name() {
    let neg = Sources {
        temperature: -0.1,
        ..Default::default()
    };
    let e = neg.check(1).unwrap_err().to_string();
    assert!(e.contains("uncertainty.temperature"), "{e}");
    let mut nan = Sources::default();
    nan.map.rotation[1][2] = f64::NAN;
    assert!(nan.check(1).unwrap_err().to_string().contains("map.y.ez"));
    let not_psd = [[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let e = PoseUncertainty::new(&pose(), OFFSET, not_psd, [[0.0; 3]; 3], [0.0; 2])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("offset_covariance") && e.contains("semi-definite"),
        "{e}"
    );
    let asym = [[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    assert!(PoseUncertainty::new(&pose(), OFFSET, [[0.0; 3]; 3], asym, [0.0; 2]).is_err());
    let two = Sources {
        poses: vec![
            PoseUncertainty::new(&pose(), OFFSET, [[0.0; 3]; 3], [[0.0; 3]; 3], [0.0; 2])
                .unwrap();
            2
        ],
        ..Default::default()
    };
    assert!(two.check(1).unwrap_err().to_string().contains("poses"));
}

#[test]
fn profiles_share_their_state_and_give_each_rows_own_result() {
    // 40 profiles of 120 points, each sharing a reading: the cached state
    // must give the bits of each row computed alone.
    let (uv, s0) = points(4800);
    let s: Vec<f64> = (0..4800)
        .flat_map(|i| s0[3 * (i / 120 * 120)..3 * (i / 120 * 120) + 3].to_vec())
        .collect();
    let map = map_from(components, SQUARENESS, None);
    let mut sources = Sources {
        scanner_scale: 1e-4,
        poses: vec![PoseUncertainty::new(
            &pose(),
            OFFSET,
            [[1e-4, 0.0, 0.0], [0.0, 2e-4, 0.0], [0.0, 0.0, 3e-4]],
            [[1e-8, 0.0, 0.0], [0.0, 1e-8, 0.0], [0.0, 0.0, 1e-8]],
            [0.01, 0.02],
        )
        .unwrap()],
        ..Default::default()
    };
    sources.map.rotation = [[1e-6; 3]; 3];
    sources.map.position = [[1e-3; 3]; 3];
    let (_, all) = stated(
        &Case {
            uv: &uv,
            s: &s,
            t: None,
        },
        MapSource::Map(&map),
        &sources,
    );
    for i in (0..4800).step_by(97) {
        let one = Case {
            uv: &uv[2 * i..2 * i + 2],
            s: &s[3 * i..3 * i + 3],
            t: None,
        };
        let (_, alone) = stated(&one, MapSource::Map(&map), &sources);
        assert_eq!(&all[15 * i..15 * i + 15], &alone[..], "row {i}");
    }
}
