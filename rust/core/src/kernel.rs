//! Per-point compensation (thesis eqs. 10-13 and 26-35; docs/conventions.md):
//!
//! ```text
//! X_H = S + e(S) + R(S) . E313 . ((u, v, 0) - l1)
//! ```
//!
//! One kernel: the thesis compensation is [`compensate_points`] with no
//! effect switched on; the diagnosis model switches on terms of
//! [`crate::effects`]. Every kernel runs through one per-block path
//! ([`drive`]): one NaN rule, one range / clamp rule, one [`Options`] and
//! one [`Report`]. Points are processed in parallel chunks (rayon) straight
//! from the caller's buffers into one preallocated output; nothing is
//! allocated per point.

use multiversion::multiversion;
use nalgebra::Vector3;
use rayon::prelude::*;

use crate::blocks::Call;
use crate::effects::{Columns, Effects, MachineErrors, Temperatures};
use crate::error::{CoreError, Quantity, Result};
use crate::map::ErrorMap;
use crate::pose::Digitizer;
use crate::source::Source;
pub use crate::source::{
    inv_sqrt_one_plus, position_error_at, tan_small, NanPolicy, Options, OutOfRange, PointError,
    Report,
};
use crate::thermal::ErrorMapSet;
use crate::uncertainty::Propagation;
pub use crate::uncertainty::{Detail, Sources};
use crate::units::{plausible_length, plausible_result, MAX_RESULT_MM};

/// Points per parallel work item: large enough to amortise scheduling, small
/// enough to balance two or more threads on a few thousand points.
const CHUNK: usize = 4096;

/// Input arrays of one call, flat row-major.
struct Inputs<'a, 'c> {
    uv: Option<&'a [f64]>,
    scales: &'a [f64],
    columns: &'c Columns<'a>,
}

impl Inputs<'_, '_> {
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
        self.columns.check(n)?;
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
    fn non_finite(&self, i: usize) -> Option<&str> {
        if let Some(uv) = self.uv {
            if !(uv[2 * i].is_finite() && uv[2 * i + 1].is_finite()) {
                return Some("uv");
            }
        }
        if !self.scales[3 * i..3 * i + 3].iter().all(|x| x.is_finite()) {
            return Some("scales");
        }
        self.columns.non_finite(i)
    }

    /// The first finite input of row `i` that no machine gives, with its
    /// value and unit: a length beyond [`MAX_LENGTH_MM`] (not millimetres;
    /// compensating it would give a finite nonsense) or a temperature
    /// outside [`TEMPERATURE_RANGE_C`] (not degrees C; a range policy would
    /// hold it at the maps' edge).
    #[inline(always)]
    fn implausible(&self, i: usize) -> Option<(&str, f64, Quantity)> {
        if let Some(uv) = self.uv {
            if let Some(&x) = uv[2 * i..2 * i + 2].iter().find(|x| !plausible_length(**x)) {
                return Some(("uv", x, Quantity::Length));
            }
        }
        if let Some(&x) = self.scales[3 * i..3 * i + 3]
            .iter()
            .find(|x| !plausible_length(**x))
        {
            return Some(("scales", x, Quantity::Length));
        }
        self.columns
            .implausible_temperature(i)
            .map(|(name, x)| (name, x, Quantity::Temperature))
    }
}

/// Run `row_fn` over every row in parallel chunks: the one per-block path
/// of every kernel (NaN rule, error order, report). Each chunk stops at its
/// first error; the error of the lowest row wins, so the message names the
/// first bad row of the input.
fn drive<C, F>(
    inputs: &Inputs,
    opts: Options,
    out: &mut [f64],
    width: usize,
    row_fn: F,
) -> Result<Report>
where
    C: Default,
    F: Fn(usize, [f64; 3], &mut [f64], &mut Report, &mut C) -> Result<()> + Sync,
{
    drive_blocks(inputs, opts, out, width, |_, _| None, row_fn, None)
}

/// A second output filled chunk by chunk after the points (the per-point
/// uncertainty): its buffer, its width per row, and
/// `fill(start, points, rows)` given the chunk's computed points.
pub(crate) struct Extra<'x> {
    pub buffer: &'x mut [f64],
    pub width: usize,
    #[allow(clippy::type_complexity)]
    pub fill: &'x (dyn Fn(usize, &[f64], &mut [f64]) -> Result<()> + Sync),
}

/// [`drive`] with a block path: `block_fn(start, block)` fills a chunk's
/// output and returns its report, or `None` to give the chunk to the
/// per-row path, which then does it again from the start (so errors, the
/// NaN policy and the report are the per-row path's whatever the block path
/// does).
fn drive_blocks<C, B, F>(
    inputs: &Inputs,
    opts: Options,
    out: &mut [f64],
    width: usize,
    block_fn: B,
    row_fn: F,
    extra: Option<Extra>,
) -> Result<Report>
where
    C: Default,
    B: Fn(usize, &mut [f64]) -> Option<Report> + Sync,
    F: Fn(usize, [f64; 3], &mut [f64], &mut Report, &mut C) -> Result<()> + Sync,
{
    let n = inputs.check(out, width)?;
    let one = |ci: usize, block: &mut [f64]| {
        chunk::<C, B, F>(inputs, opts, block, ci * CHUNK, width, &block_fn, &row_fn)
    };
    let chunk_results: Vec<(Report, Option<CoreError>)> = match extra {
        None => out
            .par_chunks_mut(width * CHUNK)
            .enumerate()
            .map(|(ci, block)| one(ci, block))
            .collect(),
        Some(x) => {
            if x.buffer.len() != x.width * n {
                return Err(CoreError::invalid_argument(
                    "uncertainty out",
                    format!("has {} values, expected {}", x.buffer.len(), x.width * n),
                ));
            }
            // The second output of a chunk right after its points, while
            // the chunk's inputs are still in cache.
            out.par_chunks_mut(width * CHUNK)
                .zip(x.buffer.par_chunks_mut(x.width * CHUNK))
                .enumerate()
                .map(|(ci, (block, rows))| {
                    let (report, err) = one(ci, block);
                    if err.is_some() {
                        return (report, err);
                    }
                    (report, (x.fill)(ci * CHUNK, block, rows).err())
                })
                .collect()
        }
    };
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

/// One chunk: the block path, else the rows. Compiled once per SIMD target
/// and chosen at run time (multiversion); every target does the same IEEE
/// operations in the same order (Rust never fuses a multiply and an add on
/// its own), so the same bits, in wider registers. AVX-512 (eight lanes a
/// register) takes the random-reading blocks' solve about 10 % faster than
/// AVX2 on the Xeon of the README's speed table (issue 27).
#[multiversion(targets(
    "x86_64+avx512f+avx512vl+avx512dq+avx2+fma",
    "x86_64+avx2+fma",
    "x86_64+avx"
))]
fn chunk<C, B, F>(
    inputs: &Inputs,
    opts: Options,
    block: &mut [f64],
    start: usize,
    width: usize,
    block_fn: &B,
    row_fn: &F,
) -> (Report, Option<CoreError>)
where
    C: Default,
    B: Fn(usize, &mut [f64]) -> Option<Report> + Sync,
    F: Fn(usize, [f64; 3], &mut [f64], &mut Report, &mut C) -> Result<()> + Sync,
{
    if let Some(report) = block_fn(start, block) {
        return (report, None);
    }
    block_rows::<C, F>(inputs, opts, block, start, width, row_fn)
}

/// The rows of one block; stops at its first error.
#[inline(always)]
fn block_rows<C, F>(
    inputs: &Inputs,
    opts: Options,
    block: &mut [f64],
    start: usize,
    width: usize,
    row_fn: &F,
) -> (Report, Option<CoreError>)
where
    C: Default,
    F: Fn(usize, [f64; 3], &mut [f64], &mut Report, &mut C) -> Result<()> + Sync,
{
    let mut report = Report::default();
    // State a row function carries from one row to the next within the
    // block (the error state of the last scale reading).
    let mut carry = C::default();
    for (j, slot) in block.chunks_exact_mut(width).enumerate() {
        let i = start + j;
        if let Some(argument) = inputs.non_finite(i) {
            if opts.nan_policy == NanPolicy::Raise {
                return (
                    report,
                    Some(CoreError::NonFinite {
                        argument: argument.to_string(),
                        row: i,
                    }),
                );
            }
            slot.fill(f64::NAN);
            report.nan_rows += 1;
            continue;
        }
        if let Some((argument, value, quantity)) = inputs.implausible(i) {
            return (report, Some(implausible(argument, i, value, quantity)));
        }
        let s = [
            inputs.scales[3 * i],
            inputs.scales[3 * i + 1],
            inputs.scales[3 * i + 2],
        ];
        let before = report.clamped_sum();
        if let Err(e) = row_fn(i, s, slot, &mut report, &mut carry) {
            return (report, Some(e));
        }
        report.clamped_points += (report.clamped_sum() != before) as usize;
    }
    report.points = block.len() / width;
    (report, None)
}

/// The error maps a compensation reads.
#[derive(Debug, Clone, Copy)]
pub enum MapSource<'a> {
    /// One map, at every temperature (no `temperature` input needed).
    Map(&'a ErrorMap),
    /// Maps at several temperatures, interpolated at each point's
    /// `temperature` input (C).
    Set(&'a ErrorMapSet),
}

/// The points of one compensation call, flat row-major.
#[derive(Debug, Clone)]
pub struct Points<'a> {
    /// N x 2: scan-plane u, v (mm).
    pub uv: &'a [f64],
    /// N x 3: scale readings D, E, F (mm).
    pub scales: &'a [f64],
    /// N: index of each point's digitizer; `None`: all at the first.
    pub pose_index: Option<&'a [u32]>,
    /// `temperature` (N, C) and the inputs the effects read.
    pub columns: Columns<'a>,
}

/// Compensated machine coordinates (N x 3, mm) of `points`: the thesis
/// compensation (eqs. 10-13, 26-35) with the `effects` switched on, each
/// point with its digitizer (pose and mount offset). With no effect this is
/// the thesis model. Per point:
///
/// 1. scanner terms undo the scanner's errors on (u, v);
/// 2. reading terms move the scale reading to the profile's instant;
/// 3. temperature terms choose each carriage's map temperature;
/// 4. the maps are read there, machine terms add what the maps lack;
/// 5. X = S + e + R . E313 . ((u, v, 0) - f l1), f from the mount terms.
pub fn compensate_points(
    points: &Points,
    maps: MapSource,
    digitizers: &[Digitizer],
    effects: &Effects,
    opts: Options,
    out: &mut [f64],
) -> Result<Report> {
    let d = digitizers;
    match maps {
        MapSource::Map(m) => compensate_with(points, m, false, d, effects, opts, out, None),
        MapSource::Set(s) => compensate_with(points, s, true, d, effects, opts, out, None),
    }
}

/// As [`compensate_points`], and each point's standard uncertainty (k = 1)
/// from `sources` into `uncertainty` (N x `detail.width()`, see
/// [`Detail`]), in the same parallel pass: each chunk's uncertainties are
/// computed right after its points (docs/uncertainty.md, "Per point").
/// The points are the same bits as [`compensate_points`] gives.
#[allow(clippy::too_many_arguments)]
pub fn compensate_points_with_uncertainty(
    points: &Points,
    maps: MapSource,
    digitizers: &[Digitizer],
    effects: &Effects,
    opts: Options,
    sources: &Sources,
    detail: Detail,
    out: &mut [f64],
    uncertainty: &mut [f64],
) -> Result<Report> {
    sources.check(digitizers.len())?;
    let d = digitizers;
    let u = Some((sources, detail, uncertainty));
    match maps {
        MapSource::Map(m) => compensate_with(points, m, false, d, effects, opts, out, u),
        MapSource::Set(s) => compensate_with(points, s, true, d, effects, opts, out, u),
    }
}

#[allow(clippy::too_many_arguments)]
fn compensate_with<S: Source>(
    points: &Points,
    source: &S,
    needs_temperature: bool,
    digitizers: &[Digitizer],
    effects: &Effects,
    opts: Options,
    out: &mut [f64],
    uncertainty: Option<(&Sources, Detail, &mut [f64])>,
) -> Result<Report> {
    let n = Inputs {
        uv: Some(points.uv),
        scales: points.scales,
        columns: &points.columns,
    }
    .check(out, 3)?;
    if digitizers.is_empty() {
        return Err(CoreError::invalid_argument("poses", "no digitizer given"));
    }
    if let Some(idx) = points.pose_index {
        if idx.len() != n {
            return Err(CoreError::invalid_argument(
                "pose_index",
                format!("has {} values but scales has {n} rows", idx.len()),
            ));
        }
        if let Some(i) = idx.iter().position(|&p| p as usize >= digitizers.len()) {
            return Err(CoreError::invalid_argument(
                "pose_index",
                format!(
                    "row {i}: pose {} but only {} poses were given",
                    idx[i],
                    digitizers.len()
                ),
            ));
        }
    }
    let temperature = match points.columns.get("temperature") {
        Some(c) if c.width == 1 => Some(c.values),
        Some(c) => {
            return Err(CoreError::invalid_argument(
                "temperature",
                format!("expected one value per point, got {}", c.width),
            ))
        }
        None if needs_temperature => {
            return Err(CoreError::invalid_argument(
                "temperature",
                "required with an ErrorMapSet (one value per point, C)",
            ))
        }
        None => None,
    };
    let bound = effects.bind(&points.columns)?;
    // Rows are checked for NaN in the inputs the call reads: the
    // temperature and the effects' inputs.
    let read = points
        .columns
        .only(|name| name == "temperature" || effects.reads(name));
    let inputs = Inputs {
        uv: Some(points.uv),
        scales: points.scales,
        columns: &read,
    };
    let (uv, idx) = (points.uv, points.pose_index);
    let profiled = has_profiles(points.scales, temperature);
    let arms = source.kinematics().arms();
    let call = Call {
        source,
        arms,
        bound: &bound,
        state_columns: bound.state_columns(),
        uv: points.uv,
        scales: points.scales,
        temperature,
        pose_index: idx,
        digitizers,
        opts,
    };
    // Profiles take the block path with or without effects; random
    // readings only without (the diagnosis's data are profiles).
    let random_blocks = bound.is_empty();
    let propagation = uncertainty
        .as_ref()
        .map(|(sources, detail, _)| Propagation {
            source,
            bound: &bound,
            arms,
            uv: points.uv,
            scales: points.scales,
            temperature,
            pose_index: idx,
            digitizers,
            opts,
            sources,
            detail: *detail,
        });
    let fill = |start: usize, xyz: &[f64], rows: &mut [f64]| match &propagation {
        Some(p) => p.fill(start, xyz, rows),
        None => Ok(()),
    };
    let extra = uncertainty.map(|(_, detail, buffer)| Extra {
        buffer,
        width: detail.width(),
        fill: &fill,
    });
    drive_blocks(
        &inputs,
        opts,
        out,
        3,
        // Inlined so that it is compiled for the chunk's SIMD target.
        #[inline(always)]
        |start, block| match (profiled, random_blocks) {
            (true, _) => call.profiles(start, block),
            (false, true) => call.random(start, block),
            (false, false) => None,
        },
        #[inline(always)]
        // Row by row (a block the block paths gave back): the same stages in
        // the same order, so the same bits; with no effect every stage but
        // the maps' is the identity and the mount factor is 1.
        |i, s, slot, report, _: &mut ()| {
            let d = &digitizers[idx.map_or(0, |p| p[i] as usize)];
            let t = temperature.map_or(f64::NAN, |t| t[i]);
            let mut p = [uv[2 * i], uv[2 * i + 1]];
            bound.scanner_inverse(i, &mut p);
            let mut s = s;
            bound.reading(i, &mut s);
            let mut temps = Temperatures::uniform(t);
            bound.temperatures(i, &mut temps);
            let (components, squareness) = source.evaluate(i, s, &temps, &opts, report)?;
            let mut e = MachineErrors {
                components,
                squareness,
            };
            bound.machine(i, s, &mut e);
            let pe = PointError::new(s, &e.components, e.squareness, &arms);
            let lever = d.lever_scaled(p[0], p[1], bound.mount(i));
            let x = Vector3::from(s) + pe.e + pe.rotate(&lever);
            if !(plausible_result(x.x) && plausible_result(x.y) && plausible_result(x.z)) {
                return Err(overflow(i));
            }
            slot.copy_from_slice(x.as_slice());
            Ok(())
        },
        extra,
    )
}

/// A finite input no machine gives.
#[cold]
fn implausible(argument: &str, row: usize, value: f64, quantity: Quantity) -> CoreError {
    CoreError::Implausible {
        argument: argument.to_string(),
        row,
        value,
        quantity,
    }
}

/// Plausible inputs whose result is not (beyond [`MAX_RESULT_MM`]): maps
/// extrapolated far beyond their tables.
#[cold]
fn overflow(row: usize) -> CoreError {
    CoreError::invalid_argument(
        "uv/scales",
        format!(
            "row {row}: the compensated point is beyond +-{MAX_RESULT_MM} mm (the maps extrapolated far beyond their tables)"
        ),
    )
}

/// Whether the points come in profiles that share a scale reading and a
/// temperature (scanner data: ~1000 points per profile), judged on the first
/// rows: then the kernel keeps each profile's error state; on random
/// readings keeping it would only cost.
fn has_profiles(scales: &[f64], temperature: Option<&[f64]>) -> bool {
    let n = (scales.len() / 3).min(1 << 16);
    if n < 2 {
        return false;
    }
    let same = (1..n)
        .filter(|&i| {
            scales[3 * i..3 * i + 3] == scales[3 * i - 3..3 * i]
                && temperature.is_none_or(|t| t[i].to_bits() == t[i - 1].to_bits())
        })
        .count();
    4 * same >= n
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
    let points = Points {
        uv,
        scales,
        pose_index: None,
        columns: Columns::new(),
    };
    compensate_points(
        &points,
        MapSource::Map(map),
        std::slice::from_ref(digitizer),
        &Effects::none(),
        opts,
        out,
    )
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
    let points = Points {
        uv,
        scales,
        pose_index: None,
        columns: Columns::new().with("temperature", 1, temperatures),
    };
    compensate_points(
        &points,
        MapSource::Set(set),
        std::slice::from_ref(digitizer),
        &Effects::none(),
        opts,
        out,
    )
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
            return Err(CoreError::NotFinite {
                argument: "temperature".into(),
                value: temperature,
                unit: "C",
            });
        }
        let columns = Columns::new();
        let n = Inputs {
            uv: Some(uv),
            scales,
            columns: &columns,
        }
        .check(out, 3)?;
        out.fill(f64::NAN);
        return Ok(Report {
            points: n,
            nan_rows: n,
            ..Default::default()
        });
    }
    let (map, one) = set.at_with(temperature, &opts)?;
    let mut report = compensate(uv, scales, &map, digitizer, opts, out)?;
    let n = report.points;
    report.held_temperature = one.held_temperature * n;
    report.clamped_temperature = one.clamped_temperature * n;
    report.extrapolated_temperature = one.extrapolated_temperature * n;
    report.max_extrapolation = if n > 0 { one.max_extrapolation } else { 0.0 };
    if one.clamped_temperature > 0 {
        report.clamped_points = n;
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
    let columns = Columns::new();
    let inputs = Inputs {
        uv: Some(uv),
        scales,
        columns: &columns,
    };
    drive(&inputs, opts, out, 3, |i, s, slot, _, _: &mut ()| {
        let x = Vector3::from(s) + digitizer.lever(uv[2 * i], uv[2 * i + 1]);
        if !(plausible_result(x.x) && plausible_result(x.y) && plausible_result(x.z)) {
            return Err(overflow(i));
        }
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
    let columns = Columns::new();
    let inputs = Inputs {
        uv: None,
        scales,
        columns: &columns,
    };
    let arms = map.kinematics().arms();
    drive(&inputs, opts, out, 3, |i, s, slot, report, _: &mut ()| {
        let (c, sq) = map.evaluate(i, s, &Temperatures::uniform(f64::NAN), &opts, report)?;
        slot.copy_from_slice(PointError::new(s, &c, sq, &arms).e.as_slice());
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
    let columns = Columns::new();
    let inputs = Inputs {
        uv: None,
        scales,
        columns: &columns,
    };
    let arms = map.kinematics().arms();
    drive(&inputs, opts, out, 9, |i, s, slot, report, _: &mut ()| {
        let (c, sq) = map.evaluate(i, s, &Temperatures::uniform(f64::NAN), &opts, report)?;
        let pe = PointError::new(s, &c, sq, &arms);
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
