//! Per-point compensation (thesis eqs. 10-13 and 26-35, SPEC.md section 4):
//!
//! ```text
//! X_H = S + e(S) + R(S) . E313 . ((u, v, 0) - l1)
//! ```
//!
//! Points are processed in parallel chunks (rayon) straight from the caller's
//! buffers into one preallocated output; nothing is allocated per point.

use nalgebra::Vector3;
use rayon::prelude::*;

use crate::error::{CoreError, Result};
use crate::map::{Components, ErrorMap};
use crate::pose::Digitizer;
use crate::thermal::ErrorMapSet;

/// Points per parallel work item: large enough to amortise scheduling, small
/// enough to balance two or more threads on a few thousand points.
const CHUNK: usize = 4096;

/// What to do with a scale reading or temperature outside the maps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OutOfRange {
    /// Fail, naming the first offending row (default: no silent extrapolation).
    #[default]
    Raise,
    /// Hold the end value of the table (or the end map) and count the points.
    Clamp,
}

/// What to do with NaN or infinite inputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum NanPolicy {
    /// Fail, naming the first offending row.
    #[default]
    Raise,
    /// Write a NaN row for it and go on.
    Propagate,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Options {
    pub out_of_range: OutOfRange,
    pub nan_policy: NanPolicy,
}

/// What a kernel call did besides its output.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Report {
    pub points: usize,
    /// Points whose X, Y, Z scale reading was clamped into the map.
    pub clamped_position: [usize; 3],
    /// Points whose temperature was clamped into the map set's range.
    pub clamped_temperature: usize,
    /// Rows written as NaN under [`NanPolicy::Propagate`].
    pub nan_rows: usize,
}

impl Report {
    fn merge(mut self, o: Report) -> Report {
        self.points += o.points;
        for k in 0..3 {
            self.clamped_position[k] += o.clamped_position[k];
        }
        self.clamped_temperature += o.clamped_temperature;
        self.nan_rows += o.nan_rows;
        self
    }
}

/// The error state of the machine at one scale reading: position error e
/// (mm) and the columns X_p, Y_p, Z_p of the rotation R (eqs. 29-31).
#[derive(Debug, Clone, Copy)]
pub struct PointError {
    pub e: Vector3<f64>,
    pub x_p: Vector3<f64>,
    pub y_p: Vector3<f64>,
    pub z_p: Vector3<f64>,
}

impl PointError {
    /// Position error (eqs. 11-13) and rotation (eqs. 26-31) from the three
    /// carriages' interpolated components (mm, rad) and squareness (rad).
    ///
    /// X_p is the right-handed form (1, tan eZ, tan eX tan eZ - tan eY)/norm,
    /// not the printed eq. 30 (SPEC.md section 8, docs/conventions.md).
    #[inline(always)]
    pub fn new(s: [f64; 3], c: &[Components; 3], sq: [f64; 3]) -> Self {
        let [cx, cy, cz] = c;
        let (e_, f_) = (s[1], s[2]);
        let [s_xy, s_yz, s_zx] = sq;
        let e = Vector3::new(
            cx[0] + cy[0] + cz[0] - e_ * cx[5] + f_ * cx[4] + f_ * cy[4] - e_ * s_xy - f_ * s_zx,
            cx[1] + cy[1] + cz[1] - f_ * cy[3] - f_ * cx[3] - f_ * s_yz,
            cx[2] + cy[2] + cz[2] + e_ * cx[3],
        );
        let tx = tan_small(cx[3] + cy[3] + cz[3]);
        let ty = tan_small(cx[4] + cy[4] + cz[4]);
        let tz = tan_small(cx[5] + cy[5] + cz[5]);
        let z_p = Vector3::new(ty, -tx, 1.0) * inv_sqrt_one_plus(tx * tx + ty * ty);
        let xz = tx * tz - ty;
        let x_p = Vector3::new(1.0, tz, xz) * inv_sqrt_one_plus(tz * tz + xz * xz);
        let y_p = z_p.cross(&x_p);
        PointError { e, x_p, y_p, z_p }
    }

    /// R . lever, with R = [X_p Y_p Z_p].
    #[inline(always)]
    pub fn rotate(&self, q: &Vector3<f64>) -> Vector3<f64> {
        self.x_p * q.x + self.y_p * q.y + self.z_p * q.z
    }
}

/// tan(x) to full double precision. Machine angles are arc-seconds, far below
/// 1/64 rad, where the Taylor series through x^7 leaves a remainder
/// (62/2835 x^9) under half an ulp; larger angles take `f64::tan`. This is
/// the kernel's hottest call, and libm's tan costs several times more.
#[inline(always)]
pub fn tan_small(x: f64) -> f64 {
    if x.abs() < 1.0 / 64.0 {
        let x2 = x * x;
        x + x * x2 * (1.0 / 3.0 + x2 * (2.0 / 15.0 + x2 * (17.0 / 315.0)))
    } else {
        x.tan()
    }
}

/// 1 / sqrt(1 + a) for a >= 0 to full double precision. For a < 1e-6 (angles
/// under 200 arc-seconds) the series 1 - a/2 + 3a^2/8 leaves 5a^3/16, under
/// half an ulp of 1, and saves a square root and a division per call.
#[inline(always)]
pub fn inv_sqrt_one_plus(a: f64) -> f64 {
    if a < 1e-6 {
        1.0 - a * (0.5 - 0.375 * a)
    } else {
        (1.0 + a).sqrt().recip()
    }
}

/// Which input fell outside the maps; the full error is built off the hot path.
#[derive(Debug, Clone, Copy)]
enum Miss {
    Axis(usize),
    Temperature,
}

type Evaluated = ([Components; 3], [f64; 3]);

/// Where the per-point error components come from.
trait Source: Sync {
    /// Components of the three carriages and squareness at reading `s` and
    /// temperature `t`; counts clamping in `report`.
    fn components(
        &self,
        s: [f64; 3],
        t: f64,
        clamp: bool,
        report: &mut Report,
    ) -> std::result::Result<Evaluated, Miss>;

    /// The readable error for a miss at `row`.
    fn miss_error(&self, miss: Miss, row: usize, s: [f64; 3], t: f64) -> CoreError;

    #[inline(always)]
    fn evaluate(
        &self,
        row: usize,
        s: [f64; 3],
        t: f64,
        clamp: bool,
        report: &mut Report,
    ) -> Result<Evaluated> {
        match self.components(s, t, clamp, report) {
            Ok(v) => Ok(v),
            Err(m) => Err(cold_error(self, m, row, s, t)),
        }
    }
}

#[cold]
#[inline(never)]
fn cold_error<S: Source + ?Sized>(
    source: &S,
    miss: Miss,
    row: usize,
    s: [f64; 3],
    t: f64,
) -> CoreError {
    source.miss_error(miss, row, s, t)
}

fn axis_error(map: &ErrorMap, a: usize, row: usize, s: [f64; 3]) -> CoreError {
    let (lo, hi) = map.tables()[a].range();
    CoreError::PositionOutOfRange {
        row,
        axis: AXES[a],
        value: s[a],
        lo,
        hi,
    }
}

const AXES: [char; 3] = ['X', 'Y', 'Z'];

impl Source for ErrorMap {
    #[inline(always)]
    fn miss_error(&self, miss: Miss, row: usize, s: [f64; 3], _t: f64) -> CoreError {
        match miss {
            Miss::Axis(a) => axis_error(self, a, row, s),
            Miss::Temperature => unreachable!("a single map has no temperature range"),
        }
    }

    #[inline(always)]
    fn components(
        &self,
        s: [f64; 3],
        _t: f64,
        clamp: bool,
        report: &mut Report,
    ) -> std::result::Result<Evaluated, Miss> {
        let mut c = [[0.0; 6]; 3];
        for a in 0..3 {
            let table = &self.tables()[a];
            let loc = if clamp {
                let (loc, moved) = table.locate_clamped(s[a]);
                report.clamped_position[a] += moved as usize;
                loc
            } else {
                table.locate(s[a]).ok_or(Miss::Axis(a))?
            };
            c[a] = table.at(loc);
        }
        Ok((c, self.squareness()))
    }
}

impl Source for ErrorMapSet {
    #[inline(always)]
    fn miss_error(&self, miss: Miss, row: usize, s: [f64; 3], t: f64) -> CoreError {
        match miss {
            Miss::Temperature => {
                let (lo, hi) = self.temperature_range();
                CoreError::TemperatureOutOfRange {
                    row: Some(row),
                    value: t,
                    lo,
                    hi,
                }
            }
            // Every interval's grid is the same common range, so any map names it.
            Miss::Axis(a) => match self.interval_of(self.clamp_temperature(t).0) {
                Some((iv, _)) => axis_error(&iv.base, a, row, s),
                None => axis_error(&self.maps()[0], a, row, s),
            },
        }
    }

    #[inline(always)]
    fn components(
        &self,
        s: [f64; 3],
        t: f64,
        clamp: bool,
        report: &mut Report,
    ) -> std::result::Result<Evaluated, Miss> {
        let (tc, moved) = self.clamp_temperature(t);
        if moved {
            if !clamp {
                return Err(Miss::Temperature);
            }
            report.clamped_temperature += 1;
        }
        let Some((iv, dt)) = self.interval_of(tc) else {
            // A single map: in range means exactly at its temperature.
            return self.maps()[0].components(s, tc, clamp, report);
        };
        let mut c = [[0.0; 6]; 3];
        for a in 0..3 {
            let table = &iv.base.tables()[a];
            let loc = if clamp {
                let (loc, moved) = table.locate_clamped(s[a]);
                report.clamped_position[a] += moved as usize;
                loc
            } else {
                table.locate(s[a]).ok_or(Miss::Axis(a))?
            };
            c[a] = iv.at(a, loc, dt);
        }
        Ok((c, iv.squareness(dt)))
    }
}

/// Input arrays of one call, flat row-major.
struct Inputs<'a> {
    uv: Option<&'a [f64]>,
    scales: &'a [f64],
    temperatures: Option<&'a [f64]>,
}

impl<'a> Inputs<'a> {
    fn check(&self, out: &[f64], width: usize) -> Result<usize> {
        if self.scales.len() % 3 != 0 {
            return Err(CoreError::invalid_argument(
                "scales",
                format!(
                    "length {} is not a multiple of 3 (D, E, F per row)",
                    self.scales.len()
                ),
            ));
        }
        let n = self.scales.len() / 3;
        if let Some(uv) = self.uv {
            if uv.len() != 2 * n {
                return Err(CoreError::invalid_argument(
                    "uv",
                    format!("has {} rows but scales has {n}", uv.len() / 2),
                ));
            }
        }
        if let Some(t) = self.temperatures {
            if t.len() != n {
                return Err(CoreError::invalid_argument(
                    "temperature",
                    format!("has {} values but scales has {n} rows", t.len()),
                ));
            }
        }
        if out.len() != width * n {
            return Err(CoreError::invalid_argument(
                "out",
                format!("has {} values, expected {}", out.len(), width * n),
            ));
        }
        Ok(n)
    }

    /// The first non-finite argument in row `i`, if any.
    #[inline(always)]
    fn non_finite(&self, i: usize) -> Option<&'static str> {
        if let Some(uv) = self.uv {
            if !(uv[2 * i].is_finite() && uv[2 * i + 1].is_finite()) {
                return Some("uv");
            }
        }
        if !self.scales[3 * i..3 * i + 3].iter().all(|x| x.is_finite()) {
            return Some("scales");
        }
        if let Some(t) = self.temperatures {
            if !t[i].is_finite() {
                return Some("temperature");
            }
        }
        None
    }
}

/// Run `row_fn` over every row in parallel chunks. Each chunk stops at its
/// first error; the error of the lowest row wins, so the message names the
/// first bad row of the input.
fn drive<F>(
    inputs: &Inputs,
    opts: Options,
    out: &mut [f64],
    width: usize,
    row_fn: F,
) -> Result<Report>
where
    F: Fn(usize, [f64; 3], f64, &mut [f64], &mut Report) -> Result<()> + Sync,
{
    let n = inputs.check(out, width)?;
    let avx2 = has_avx2();
    let chunk_results: Vec<(Report, Option<CoreError>)> = out
        .par_chunks_mut(width * CHUNK)
        .enumerate()
        .map(|(ci, block)| {
            if avx2 {
                // SAFETY: AVX2 was detected on this CPU at run time.
                #[cfg(target_arch = "x86_64")]
                return unsafe { block_avx2(inputs, opts, block, ci * CHUNK, width, &row_fn) };
            }
            block_rows(inputs, opts, block, ci * CHUNK, width, &row_fn)
        })
        .collect();
    let mut total = Report::default();
    for (report, err) in chunk_results {
        if let Some(e) = err {
            return Err(e);
        }
        total = total.merge(report);
    }
    debug_assert_eq!(total.points, n);
    Ok(total)
}

/// Whether the per-block loop may run its AVX2 build.
#[inline]
fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The rows of one block; stops at its first error.
#[inline(always)]
fn block_rows<F>(
    inputs: &Inputs,
    opts: Options,
    block: &mut [f64],
    start: usize,
    width: usize,
    row_fn: &F,
) -> (Report, Option<CoreError>)
where
    F: Fn(usize, [f64; 3], f64, &mut [f64], &mut Report) -> Result<()> + Sync,
{
    let mut report = Report::default();
    for (j, slot) in block.chunks_exact_mut(width).enumerate() {
        let i = start + j;
        if let Some(argument) = inputs.non_finite(i) {
            if opts.nan_policy == NanPolicy::Raise {
                return (report, Some(CoreError::NonFinite { argument, row: i }));
            }
            slot.fill(f64::NAN);
            report.nan_rows += 1;
            continue;
        }
        let s = [
            inputs.scales[3 * i],
            inputs.scales[3 * i + 1],
            inputs.scales[3 * i + 2],
        ];
        let t = inputs.temperatures.map_or(f64::NAN, |t| t[i]);
        if let Err(e) = row_fn(i, s, t, slot, &mut report) {
            return (report, Some(e));
        }
    }
    report.points = block.len() / width;
    (report, None)
}

/// [`block_rows`] compiled for AVX2: the same IEEE operations in the same
/// order (no fused multiply-add), so the same bits, in wider registers.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn block_avx2<F>(
    inputs: &Inputs,
    opts: Options,
    block: &mut [f64],
    start: usize,
    width: usize,
    row_fn: &F,
) -> (Report, Option<CoreError>)
where
    F: Fn(usize, [f64; 3], f64, &mut [f64], &mut Report) -> Result<()> + Sync,
{
    block_rows(inputs, opts, block, start, width, row_fn)
}

fn compensate_with<S: Source>(
    uv: &[f64],
    scales: &[f64],
    temperatures: Option<&[f64]>,
    source: &S,
    digitizer: &Digitizer,
    opts: Options,
    out: &mut [f64],
) -> Result<Report> {
    let inputs = Inputs {
        uv: Some(uv),
        scales,
        temperatures,
    };
    let clamp = opts.out_of_range == OutOfRange::Clamp;
    drive(&inputs, opts, out, 3, |i, s, t, slot, report| {
        let (c, sq) = source.evaluate(i, s, t, clamp, report)?;
        let pe = PointError::new(s, &c, sq);
        let x = Vector3::from(s) + pe.e + pe.rotate(&digitizer.lever(uv[2 * i], uv[2 * i + 1]));
        slot.copy_from_slice(x.as_slice());
        Ok(())
    })
}

/// Compensated machine coordinates (mm) of points `uv` (N x 2, mm) taken at
/// scale readings `scales` (N x 3, mm), with one error map. `out` is N x 3.
pub fn compensate(
    uv: &[f64],
    scales: &[f64],
    map: &ErrorMap,
    digitizer: &Digitizer,
    opts: Options,
    out: &mut [f64],
) -> Result<Report> {
    compensate_with(uv, scales, None, map, digitizer, opts, out)
}

/// As [`compensate`], with a map set and one temperature (C) per point.
pub fn compensate_at_temperatures(
    uv: &[f64],
    scales: &[f64],
    temperatures: &[f64],
    set: &ErrorMapSet,
    digitizer: &Digitizer,
    opts: Options,
    out: &mut [f64],
) -> Result<Report> {
    compensate_with(uv, scales, Some(temperatures), set, digitizer, opts, out)
}

/// As [`compensate`], with a map set at one temperature (C) for all points:
/// the set is blended once.
pub fn compensate_at_temperature(
    uv: &[f64],
    scales: &[f64],
    temperature: f64,
    set: &ErrorMapSet,
    digitizer: &Digitizer,
    opts: Options,
    out: &mut [f64],
) -> Result<Report> {
    if !temperature.is_finite() {
        if opts.nan_policy == NanPolicy::Raise {
            return Err(CoreError::invalid_argument("temperature", format!("{temperature} C is not finite (pass nan_policy='propagate' to get NaN rows instead)")));
        }
        let n = Inputs {
            uv: Some(uv),
            scales,
            temperatures: None,
        }
        .check(out, 3)?;
        out.fill(f64::NAN);
        return Ok(Report {
            points: n,
            nan_rows: n,
            ..Default::default()
        });
    }
    let map = set.at(temperature, opts.out_of_range == OutOfRange::Clamp)?;
    let mut report = compensate(uv, scales, &map, digitizer, opts, out)?;
    if set.clamp_temperature(temperature).1 {
        report.clamped_temperature = report.points;
    }
    Ok(report)
}

/// What the digitizer software reports: S + E313 . ((u, v, 0) - l1), mm.
pub fn uncompensated(
    uv: &[f64],
    scales: &[f64],
    digitizer: &Digitizer,
    opts: Options,
    out: &mut [f64],
) -> Result<Report> {
    let inputs = Inputs {
        uv: Some(uv),
        scales,
        temperatures: None,
    };
    drive(&inputs, opts, out, 3, |i, s, _t, slot, _| {
        let x = Vector3::from(s) + digitizer.lever(uv[2 * i], uv[2 * i + 1]);
        slot.copy_from_slice(x.as_slice());
        Ok(())
    })
}

/// Position error e(S) of eqs. 11-13 (mm), N x 3.
pub fn position_error(
    scales: &[f64],
    map: &ErrorMap,
    opts: Options,
    out: &mut [f64],
) -> Result<Report> {
    let inputs = Inputs {
        uv: None,
        scales,
        temperatures: None,
    };
    let clamp = opts.out_of_range == OutOfRange::Clamp;
    drive(&inputs, opts, out, 3, |i, s, t, slot, report| {
        let (c, sq) = map.evaluate(i, s, t, clamp, report)?;
        slot.copy_from_slice(PointError::new(s, &c, sq).e.as_slice());
        Ok(())
    })
}

/// Rotation R(S) of eqs. 29-32, N x 3 x 3 row-major (columns X_p, Y_p, Z_p).
pub fn rotation_error(
    scales: &[f64],
    map: &ErrorMap,
    opts: Options,
    out: &mut [f64],
) -> Result<Report> {
    let inputs = Inputs {
        uv: None,
        scales,
        temperatures: None,
    };
    let clamp = opts.out_of_range == OutOfRange::Clamp;
    drive(&inputs, opts, out, 9, |i, s, t, slot, report| {
        let (c, sq) = map.evaluate(i, s, t, clamp, report)?;
        let pe = PointError::new(s, &c, sq);
        for r in 0..3 {
            slot[3 * r] = pe.x_p[r];
            slot[3 * r + 1] = pe.y_p[r];
            slot[3 * r + 2] = pe.z_p[r];
        }
        Ok(())
    })
}

#[cfg(test)]
#[path = "kernel_tests.rs"]
mod tests;
