//! The compensation kernel's block paths: the same equations as the per-row
//! path in [`crate::kernel`] (which drives them), the same IEEE operations in the same order (so
//! the same bits), arranged so that the compiler can keep them in vector
//! registers.
//!
//! * **Profiles.** A line scanner's points come in profiles of ~1000 that
//!   share one scale reading, time and temperature. The machine's error
//!   state is computed once per run of equal rows; the points of the run then
//!   go through one short loop with no branch and no call.
//! * **Random readings.** Rows are taken 64 at a time into a
//!   structure-of-arrays block ([`crate::lanes`]): the maps are read table
//!   by table (one map: every lane located on the table at once, see
//!   [`crate::lanes::map_lanes`]; a map set: every lane's temperature
//!   interval first, then the same, see [`crate::thermal`]), then the
//!   rotation and the lever are computed for the whole block in
//!   straight-line loops. The next block's inputs are prefetched while
//!   one computes (a hint only: no value changes).
//!
//! A block path never reports an error itself: on anything unusual (a
//! non-finite input or one beyond a machine's lengths, a reading outside a map, an angle past the series'
//! range, an overflow) it gives the block back and the per-row path, which
//! names the row and applies the NaN policy, does it again from the start.

use nalgebra::Vector3;

use crate::effects::{Bound, MachineErrors, Temperatures};
use crate::lanes::{Lanes, LANES};
use crate::pose::Digitizer;
use crate::source::{position_error_at, Options, PointError, Report, Source};
use crate::units::{plausible_length, plausible_result, plausible_temperature};

/// Largest |angle| (rad) for which [`tan_small`](crate::source::tan_small) takes its series.
const TAN_SERIES: f64 = 1.0 / 64.0;
/// Largest argument for which [`inv_sqrt_one_plus`](crate::source::inv_sqrt_one_plus) takes its series.
const INV_SQRT_SERIES: f64 = 1e-6;

/// One compensation call, as the block paths read it (with or without
/// effects switched on).
pub(crate) struct Call<'a, S: Source> {
    pub source: &'a S,
    /// The machine's arms (see [`crate::kinematics`]).
    pub arms: [[f64; 3]; 3],
    /// The effects switched on, bound to their inputs.
    pub bound: &'a Bound<'a>,
    /// Inputs that the effects' state stages read (values, width).
    pub state_columns: Vec<(&'a [f64], usize, (f64, f64))>,
    pub uv: &'a [f64],
    pub scales: &'a [f64],
    /// One value per point (C); `None` when no temperature column was given.
    pub temperature: Option<&'a [f64]>,
    pub pose_index: Option<&'a [u32]>,
    pub digitizers: &'a [Digitizer],
    pub opts: Options,
}

impl<S: Source> Call<'_, S> {
    /// Rows `start..` into `block` (N x 3) with the profile path; `None`
    /// hands the block to the per-row path.
    #[inline(always)]
    pub fn profiles(&self, start: usize, block: &mut [f64]) -> Option<Report> {
        let n = block.len() / 3;
        let mut report = Report {
            points: n,
            ..Default::default()
        };
        let mut finite = true;
        let mut j = 0;
        while j < n {
            let i = start + j;
            let s = self.reading(i);
            let t = self.temperature.map_or(f64::NAN, |t| t[i]);
            let pose = self.pose_index.map_or(0, |p| p[i]);
            let mut k = j + 1;
            while k < n && self.same_state(i, start + k, s, t, pose) {
                k += 1;
            }
            let (s, pe, factor) = self.state(i, s, t, k - j, &mut report)?;
            let se = Vector3::from(s) + pe.e;
            let d = &self.digitizers[pose as usize];
            let out = &mut block[3 * j..3 * k];
            finite &= if self.bound.acts_on_scanner() {
                self.scanned_points(i, &se, &pe, d, factor, out)
            } else {
                profile_points(&se, &pe, d, factor, &self.uv[2 * i..2 * (start + k)], out)
            };
            j = k;
        }
        finite.then_some(report)
    }

    /// Rows `start..` into `block` (N x 3), [`LANES`] rows at a time; `None`
    /// hands the block to the per-row path.
    #[inline(always)]
    pub fn random(&self, start: usize, block: &mut [f64]) -> Option<Report> {
        let n = block.len() / 3;
        let mut report = Report {
            points: n,
            ..Default::default()
        };
        let mut lanes = Lanes::default();
        let mut j = 0;
        while j < n {
            let m = LANES.min(n - j);
            let first = start + j;
            // The next block's inputs are asked for while this one
            // computes, in two halves so that the requests never wait for a
            // free line buffer: without it a third of the time went on
            // waiting for each block's first reads (the hardware prefetcher
            // runs too little ahead of a loop this long).
            let next = (first + m, LANES.min(n - j - m));
            prefetch_lines(&self.scales[3 * next.0..3 * (next.0 + next.1)]);
            self.gather(first, m, &mut lanes)?;
            let t = self.temperature.map(|t| &t[first..first + m]);
            self.source
                .fill_lanes(&mut lanes, t, m, &self.opts, &mut report)?;
            prefetch_lines(&self.uv[2 * next.0..2 * (next.0 + next.1)]);
            if let Some(t) = self.temperature {
                prefetch_lines(&t[next.0..next.0 + next.1]);
            }
            if !solve(&lanes, m, &self.arms, &mut block[3 * j..3 * (j + m)]) {
                return None;
            }
            j += m;
        }
        Some(report)
    }

    #[inline(always)]
    fn reading(&self, i: usize) -> [f64; 3] {
        [
            self.scales[3 * i],
            self.scales[3 * i + 1],
            self.scales[3 * i + 2],
        ]
    }

    /// Whether row `k` has the exact reading, temperature, pose and state
    /// inputs of row `i`, which starts a run with `s`, `t`, `pose`.
    #[inline(always)]
    fn same_state(&self, i: usize, k: usize, s: [f64; 3], t: f64, pose: u32) -> bool {
        let sk = self.reading(k);
        sk[0].to_bits() == s[0].to_bits()
            && sk[1].to_bits() == s[1].to_bits()
            && sk[2].to_bits() == s[2].to_bits()
            && self
                .temperature
                .is_none_or(|tt| tt[k].to_bits() == t.to_bits())
            && self.pose_index.is_none_or(|p| p[k] == pose)
            && self.state_columns.iter().all(|&(values, w, _)| {
                values[w * k..w * (k + 1)]
                    .iter()
                    .zip(&values[w * i..w * (i + 1)])
                    .all(|(a, b)| a.to_bits() == b.to_bits())
            })
    }

    /// The machine state of a run of `len` rows starting at row `i` with
    /// reading `s` and temperature `t`: the reading after the effects, the
    /// error state and the mount's scale factor. Its clamp counts go into
    /// `report` once per row. `None` on a non-finite or implausible input or a miss.
    #[inline(always)]
    fn state(
        &self,
        i: usize,
        s: [f64; 3],
        t: f64,
        len: usize,
        report: &mut Report,
    ) -> Option<([f64; 3], PointError, f64)> {
        let finite = s.iter().all(|&x| plausible_length(x))
            && (self.temperature.is_none() || plausible_temperature(t))
            && self.state_columns.iter().all(|&(values, w, (lo, hi))| {
                values[w * i..w * (i + 1)]
                    .iter()
                    .all(|&x| (lo..=hi).contains(&x))
            });
        if !finite {
            return None;
        }
        let mut one = Report::default();
        if self.bound.is_empty() {
            let (c, sq) = self
                .source
                .components(s, &Temperatures::uniform(t), &self.opts, &mut one)
                .ok()?;
            report.add_counts_times(&one, len);
            return Some((s, PointError::new(s, &c, sq, &self.arms), 1.0));
        }
        // The per-row path's stages, in its order.
        let mut s = s;
        self.bound.reading(i, &mut s);
        let mut temps = Temperatures::uniform(t);
        self.bound.temperatures(i, &mut temps);
        let (components, squareness) = self
            .source
            .components(s, &temps, &self.opts, &mut one)
            .ok()?;
        report.add_counts_times(&one, len);
        let mut e = MachineErrors {
            components,
            squareness,
        };
        self.bound.machine(i, s, &mut e);
        Some((
            s,
            PointError::new(s, &e.components, e.squareness, &self.arms),
            self.bound.mount(i),
        ))
    }

    /// The points of a run starting at row `i` when an effect has a scanner
    /// stage: (u, v) corrected point by point, then as [`profile_points`].
    #[inline(always)]
    fn scanned_points(
        &self,
        i: usize,
        se: &Vector3<f64>,
        pe: &PointError,
        d: &Digitizer,
        factor: f64,
        out: &mut [f64],
    ) -> bool {
        // A few hundred points at a time: (u, v) corrected term by term
        // over the piece, then the points as without a scanner stage.
        const PIECE: usize = 256;
        let mut corrected = [0.0; 2 * PIECE];
        let mut finite = true;
        for (k, piece) in out.chunks_mut(3 * PIECE).enumerate() {
            let first = i + k * PIECE;
            let m = piece.len() / 3;
            let buf = &mut corrected[..2 * m];
            buf.copy_from_slice(&self.uv[2 * first..2 * (first + m)]);
            self.bound.scanner_inverse_rows(first, buf);
            finite &= profile_points(se, pe, d, factor, buf, piece);
        }
        finite
    }

    /// Rows `first..first + m` into the lanes: readings and levers, loop
    /// by loop over the block. `None` on a non-finite or implausible input.
    #[inline(always)]
    fn gather(&self, first: usize, m: usize, lanes: &mut Lanes) -> Option<()> {
        let scales = &self.scales[3 * first..3 * (first + m)];
        let uv = &self.uv[2 * first..2 * (first + m)];
        let mut finite = true;
        for (r, s) in scales.chunks_exact(3).enumerate() {
            for (lane, &value) in lanes.s.iter_mut().zip(s) {
                lane[r] = value;
                finite &= plausible_length(value);
            }
        }
        for &p in uv {
            finite &= plausible_length(p);
        }
        if let Some(t) = self.temperature {
            for &x in &t[first..first + m] {
                finite &= plausible_temperature(x);
            }
        }
        if !finite {
            return None;
        }
        // Digitizer::lever's operations, (origin + u_dir u) + v_dir v.
        let lever = |r: usize, d: &Digitizer, lanes: &mut Lanes| {
            let (u, v) = (uv[2 * r], uv[2 * r + 1]);
            for a in 0..3 {
                lanes.lever[a][r] = (d.origin[a] + d.u_dir[a] * u) + d.v_dir[a] * v;
            }
        };
        match self.pose_index {
            None => {
                let d = &self.digitizers[0];
                for r in 0..m {
                    lever(r, d, lanes);
                }
            }
            Some(p) => {
                for (r, &k) in p[first..first + m].iter().enumerate() {
                    lever(r, &self.digitizers[k as usize], lanes);
                }
            }
        }
        Some(())
    }
}

/// Asks for the cache lines holding `values` (a hint: no value is read or
/// changed, and off x86-64 it does nothing).
#[inline(always)]
fn prefetch_lines(values: &[f64]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        // Every eighth value (64-byte lines) and the last: one in each line.
        let ask = |v: &f64| {
            // SAFETY: a prefetch neither reads nor faults; SSE is part of
            // every x86-64 CPU.
            #[allow(unused_unsafe)]
            unsafe {
                _mm_prefetch::<_MM_HINT_T0>((v as *const f64).cast::<i8>())
            };
        };
        values.iter().step_by(8).for_each(ask);
        if let Some(v) = values.last() {
            ask(v);
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = values;
}

/// The points of one run: X = (S + e) + R . lever(u, v), the lever's mount
/// offset scaled by `factor`, as the per-row path computes it (origin x 1
/// is the origin, so with no effect these are `Digitizer::lever`'s bits).
/// Returns whether every (u, v) is a length on a machine and every result
/// plausible ([`crate::units`]).
#[inline(always)]
fn profile_points(
    se: &Vector3<f64>,
    pe: &PointError,
    d: &Digitizer,
    factor: f64,
    uv: &[f64],
    out: &mut [f64],
) -> bool {
    let origin = d.origin * factor;
    // (u, v) in a loop of their own over the flat slice, which vectorizes;
    // tested inside the point loop they cost a tenth of its throughput.
    let mut finite = uv.iter().fold(true, |ok, &p| ok & plausible_length(p));
    for (p, o) in uv.chunks_exact(2).zip(out.chunks_exact_mut(3)) {
        let l = origin + d.u_dir * p[0] + d.v_dir * p[1];
        let x = se + pe.rotate(&l);
        o[0] = x.x;
        o[1] = x.y;
        o[2] = x.z;
        finite &= plausible_result(x.x) & plausible_result(x.y) & plausible_result(x.z);
    }
    finite
}

/// [`PointError::new`] and the point, for the first `m` lanes, written
/// row-major into `out`. The series of `tan_small` and
/// `inv_sqrt_one_plus` are taken without their branch; a lane outside
/// their range or a non-finite result returns false (checked in the one
/// vector loop; the copy into `out` is a plain interleave).
#[inline(always)]
fn solve(lanes: &Lanes, m: usize, arms: &[[f64; 3]; 3], out: &mut [f64]) -> bool {
    let [cx, cy, cz] = &lanes.c;
    let mut inside = true;
    let mut x = [[0.0; LANES]; 3];
    for r in 0..m {
        let s = [lanes.s[0][r], lanes.s[1][r], lanes.s[2][r]];
        let c = [
            std::array::from_fn(|k| cx[k][r]),
            std::array::from_fn(|k| cy[k][r]),
            std::array::from_fn(|k| cz[k][r]),
        ];
        let sq = [lanes.sq[0][r], lanes.sq[1][r], lanes.sq[2][r]];
        let [ex, ey, ez] = position_error_at(s, &c, sq, arms);
        let ax = cx[3][r] + cy[3][r] + cz[3][r];
        let ay = cx[4][r] + cy[4][r] + cz[4][r];
        let az = cx[5][r] + cy[5][r] + cz[5][r];
        inside &= (ax.abs() < TAN_SERIES) & (ay.abs() < TAN_SERIES) & (az.abs() < TAN_SERIES);
        let tx = tan_series(ax);
        let ty = tan_series(ay);
        let tz = tan_series(az);
        let a_z = tx * tx + ty * ty;
        let xz = tx * tz - ty;
        let a_x = tz * tz + xz * xz;
        inside &= (a_z < INV_SQRT_SERIES) & (a_x < INV_SQRT_SERIES);
        let nz = inv_sqrt_series(a_z);
        let nx = inv_sqrt_series(a_x);
        // Z_p = (ty, -tx, 1) nz; X_p = (1, tz, xz) nx; Y_p = Z_p x X_p.
        let (zx, zy, zz) = (ty * nz, -tx * nz, 1.0 * nz);
        let (xx, xy, xzz) = (1.0 * nx, tz * nx, xz * nx);
        let yx = zy * xzz - zz * xy;
        let yy = zz * xx - zx * xzz;
        let yz = zx * xy - zy * xx;
        let (lx, ly, lz) = (lanes.lever[0][r], lanes.lever[1][r], lanes.lever[2][r]);
        // (S + e) + (X_p lx + Y_p ly + Z_p lz), in PointError::rotate's order.
        x[0][r] = (lanes.s[0][r] + ex) + ((xx * lx + yx * ly) + zx * lz);
        x[1][r] = (lanes.s[1][r] + ey) + ((xy * lx + yy * ly) + zy * lz);
        x[2][r] = (lanes.s[2][r] + ez) + ((xzz * lx + yz * ly) + zz * lz);
        inside &= plausible_result(x[0][r]) & plausible_result(x[1][r]) & plausible_result(x[2][r]);
    }
    for (r, o) in out.chunks_exact_mut(3).enumerate().take(m) {
        o[0] = x[0][r];
        o[1] = x[1][r];
        o[2] = x[2][r];
    }
    inside
}

/// The series branch of [`tan_small`](crate::source::tan_small), with the same operations.
#[inline(always)]
fn tan_series(x: f64) -> f64 {
    let x2 = x * x;
    x + x * x2 * (1.0 / 3.0 + x2 * (2.0 / 15.0 + x2 * (17.0 / 315.0)))
}

/// The series branch of [`inv_sqrt_one_plus`](crate::source::inv_sqrt_one_plus), with the same operations.
#[inline(always)]
fn inv_sqrt_series(a: f64) -> f64 {
    1.0 - a * (0.5 - 0.375 * a)
}

#[cfg(test)]
mod tests {
    // Lane, carriage and component indices are the quantities compared here.
    #![allow(clippy::needless_range_loop)]
    use super::*;
    use crate::kernel::compensate_at_temperatures;
    use crate::lanes::PORTABLE;
    use crate::map::{Carriage, CarriageTable, ErrorMap};
    use crate::pose::Pose;
    use crate::source::{inv_sqrt_one_plus, tan_small, OutOfRange};
    use crate::thermal::{set_lanes, ErrorMapSet};

    /// Uniform in [0, 1), a fixed sequence.
    struct Seq(f64);

    impl Seq {
        fn next(&mut self) -> f64 {
            self.0 = (self.0 * 997.0 + 0.618_033_988_7).fract();
            self.0
        }
    }

    /// A thesis-like map at `t` C on `grid(a)` of each carriage.
    fn map(t: f64, grid: impl Fn(usize) -> Vec<f64>) -> ErrorMap {
        let tables = std::array::from_fn(|a| {
            let rows: Vec<[f64; 7]> = grid(a)
                .into_iter()
                .map(|p| {
                    let w = (p / 97.0 + a as f64 + 0.3 * t).sin();
                    [
                        p,
                        80.0 * p / 900.0 + t,
                        2.0 * w,
                        -w,
                        3.0 * w,
                        5.0 * w * w,
                        -2.0 * w,
                    ]
                })
                .collect();
            CarriageTable::from_table_units(Carriage::ALL[a], &rows).unwrap()
        });
        ErrorMap::new(tables, [-173.0 + t, -19.0, 21.0 - t], Some(t)).unwrap()
    }

    const RANGES: [(f64, f64); 3] = [(0.0, 900.0), (0.0, 550.0), (-500.0, 0.0)];

    fn uniform(a: usize) -> Vec<f64> {
        let (lo, hi) = RANGES[a];
        (0..=((hi - lo) / 25.0) as usize)
            .map(|i| lo + 25.0 * i as f64)
            .collect()
    }

    /// Non-uniform grids, the X range shorter: the intervals' union grids
    /// and ranges then differ from interval to interval.
    fn uneven(a: usize) -> Vec<f64> {
        let (lo, hi) = RANGES[a];
        let hi = if a == 0 { hi - 100.0 } else { hi };
        let mut g: Vec<f64> = (0..=20)
            .map(|i| lo + (hi - lo) * (i as f64 / 20.0).powf(1.3))
            .collect();
        g.dedup();
        g
    }

    /// Sets of 1, 2 and 4 maps (uniform, uneven and mixed grids).
    fn sets() -> Vec<ErrorMapSet> {
        vec![
            ErrorMapSet::new(vec![map(22.0, uniform)]).unwrap(),
            ErrorMapSet::new(vec![map(20.0, uniform), map(30.0, uniform)]).unwrap(),
            ErrorMapSet::new(vec![
                map(20.0, uniform),
                map(23.0, uniform),
                map(26.0, uniform),
                map(30.0, uniform),
            ])
            .unwrap(),
            ErrorMapSet::new(vec![
                map(20.0, uniform),
                map(24.0, uneven),
                map(27.0, uniform),
                map(30.0, uneven),
            ])
            .unwrap(),
        ]
    }

    #[test]
    fn set_lanes_give_the_per_row_components_bit_for_bit() {
        // The four-lane AVX path (where the CPU has AVX) and the portable
        // loops alike.
        for portable in [false, true] {
            PORTABLE.with(|p| p.set(portable));
            set_lanes_against_rows();
        }
        PORTABLE.with(|p| p.set(false));
    }

    fn set_lanes_against_rows() {
        let opts = Options::default();
        let mut q = Seq(0.123_456_789);
        for set in sets() {
            let (tlo, thi) = set.temperature_range();
            // Blocks whose lanes share one interval, span several, sit on
            // map temperatures and interval ends, and readings on the ends.
            for block in 0..40 {
                let m = [LANES, 1, 17, LANES][block % 4];
                let mut lanes = Lanes::default();
                let mut t = [0.0; LANES];
                for r in 0..m {
                    for a in 0..3 {
                        let (lo, hi) = RANGES[a];
                        let hi = if a == 0 { hi - 100.0 } else { hi };
                        lanes.s[a][r] = match (block + r) % 13 {
                            0 => lo,
                            1 => hi,
                            _ => lo + (hi - lo) * q.next(),
                        };
                    }
                    t[r] = match block % 5 {
                        0 => tlo + (thi - tlo) * (0.2 + 0.1 * q.next()),
                        1 => set.temperatures()[r % set.temperatures().len()],
                        _ => tlo + (thi - tlo) * q.next(),
                    };
                }
                let mut report = Report::default();
                set_lanes(&set, &mut lanes, &t, m).expect("every input inside");
                for r in 0..m {
                    let s = [lanes.s[0][r], lanes.s[1][r], lanes.s[2][r]];
                    let temps = Temperatures::uniform(t[r]);
                    let (c, sq) = set.components(s, &temps, &opts, &mut report).unwrap();
                    for a in 0..3 {
                        assert_eq!(lanes.sq[a][r].to_bits(), sq[a].to_bits());
                        for k in 0..6 {
                            assert_eq!(
                                lanes.c[a][k][r].to_bits(),
                                c[a][k].to_bits(),
                                "{block} {r} {a} {k}"
                            );
                        }
                    }
                }
                assert_eq!(report, Report::default());
            }
            // A temperature or a reading outside: the block goes back.
            let mut lanes = Lanes::default();
            let mut t = [tlo; LANES];
            t[5] = thi + 0.01;
            assert!(set_lanes(&set, &mut lanes, &t, LANES).is_none());
            t[5] = thi;
            lanes.s[1][7] = 551.0;
            assert!(set_lanes(&set, &mut lanes, &t, LANES).is_none());
            t[5] = f64::NAN;
            assert!(set_lanes(&set, &mut lanes, &t, LANES).is_none());
        }
    }

    #[test]
    fn random_readings_with_a_set_give_the_per_row_paths_points() {
        // The lane path (the default options) against the per-row path
        // (clamping, which no input here needs): the same bits, and the
        // same error for a reading outside a table.
        let d = Digitizer::new(
            &Pose::new(90.0, 90.0, 0.0).unwrap(),
            [1.001, 264.505, 129.575],
        )
        .unwrap();
        let mut q = Seq(0.271_828);
        let n = 10_000;
        let mut uv = Vec::with_capacity(2 * n);
        let mut s = Vec::with_capacity(3 * n);
        for _ in 0..n {
            uv.extend([-30.0 + 60.0 * q.next(), 110.0 + 60.0 * q.next()]);
            for (a, (lo, hi)) in RANGES.into_iter().enumerate() {
                let hi = if a == 0 { hi - 100.0 } else { hi };
                s.push(lo + (hi - lo) * q.next());
            }
        }
        for set in sets() {
            let (tlo, thi) = set.temperature_range();
            let t: Vec<f64> = (0..n).map(|_| tlo + (thi - tlo) * q.next()).collect();
            let mut lane = vec![0.0; 3 * n];
            let mut row = vec![0.0; 3 * n];
            let clamp = Options {
                out_of_range: OutOfRange::Clamp,
                ..Default::default()
            };
            let a =
                compensate_at_temperatures(&uv, &s, &t, &set, &d, Options::default(), &mut lane)
                    .unwrap();
            let b = compensate_at_temperatures(&uv, &s, &t, &set, &d, clamp, &mut row).unwrap();
            assert_eq!(a, b);
            assert!(lane
                .iter()
                .zip(&row)
                .all(|(x, y)| x.to_bits() == y.to_bits()));
            let mut bad = s.clone();
            bad[3 * 6000 + 2] = 1.0;
            let e =
                compensate_at_temperatures(&uv, &bad, &t, &set, &d, Options::default(), &mut lane)
                    .unwrap_err();
            assert!(e.to_string().contains("6000"), "{e}");
        }
    }

    #[test]
    fn series_match_the_scalar_functions_inside_their_range() {
        for k in -200i32..=200 {
            let x = k as f64 * (TAN_SERIES / 201.0);
            assert_eq!(tan_series(x).to_bits(), tan_small(x).to_bits());
            let a = (k.abs() as f64) * (INV_SQRT_SERIES / 201.0);
            assert_eq!(inv_sqrt_series(a).to_bits(), inv_sqrt_one_plus(a).to_bits());
        }
    }
}
