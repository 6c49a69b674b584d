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

use crate::blocks::{Call, Lanes};
use crate::effects::{Columns, Effects, MachineErrors, Temperatures};
use crate::error::{CoreError, Result};
use crate::map::{Components, ErrorMap};
use crate::pose::Digitizer;
use crate::thermal::ErrorMapSet;

/// Points per parallel work item: large enough to amortise scheduling, small
/// enough to balance two or more threads on a few thousand points.
const CHUNK: usize = 4096;

/// What to do with a scale reading or temperature outside the maps (a
/// temperature within [`Options::temperature_tolerance`] of the maps' range
/// is always held at the edge and counted; docs/conventions.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OutOfRange {
    /// Fail, naming the first offending row (default: no silent extrapolation).
    #[default]
    Raise,
    /// Hold the end value of the table (or the end map) and count the points.
    Clamp,
    /// Temperatures: extend the maps linearly beyond their range (the two
    /// end maps' slope), counting the points and the largest distance.
    /// Scale readings outside a table still fail.
    Extrapolate,
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

#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Options {
    pub out_of_range: OutOfRange,
    pub nan_policy: NanPolicy,
    /// K: a temperature this close outside the maps' range is held at the
    /// edge (thermocouple noise at the reference temperature), whatever
    /// `out_of_range` says.
    pub temperature_tolerance: f64,
}

/// What a kernel call did besides its output.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Report {
    pub points: usize,
    /// Points whose X, Y, Z scale reading was clamped into the map.
    pub clamped_position: [usize; 3],
    /// Points whose temperature was clamped into the map set's range.
    pub clamped_temperature: usize,
    /// Points where anything (a reading or a temperature) was clamped.
    pub clamped_points: usize,
    /// Points with a temperature within the tolerance outside the maps,
    /// held at the edge.
    pub held_temperature: usize,
    /// Points with a temperature extrapolated beyond the maps.
    pub extrapolated_temperature: usize,
    /// Largest distance of an extrapolated temperature from the maps, K.
    pub max_extrapolation: f64,
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
        self.clamped_points += o.clamped_points;
        self.held_temperature += o.held_temperature;
        self.extrapolated_temperature += o.extrapolated_temperature;
        self.max_extrapolation = self.max_extrapolation.max(o.max_extrapolation);
        self.nan_rows += o.nan_rows;
        self
    }

    /// Add the counts of one map evaluation `times` over (the rows of a run
    /// that share it), as the per-row path would count them.
    #[inline(always)]
    pub(crate) fn add_counts_times(&mut self, d: &Report, times: usize) {
        for k in 0..3 {
            self.clamped_position[k] += d.clamped_position[k] * times;
        }
        self.clamped_temperature += d.clamped_temperature * times;
        self.held_temperature += d.held_temperature * times;
        self.extrapolated_temperature += d.extrapolated_temperature * times;
        self.max_extrapolation = self.max_extrapolation.max(d.max_extrapolation);
        if d.clamped_sum() > 0 {
            self.clamped_points += times;
        }
    }

    #[inline(always)]
    fn clamped_sum(&self) -> usize {
        self.clamped_position[0]
            + self.clamped_position[1]
            + self.clamped_position[2]
            + self.clamped_temperature
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
    /// Position error (eqs. 11-13, the arms from the machine's stacking,
    /// see [`crate::kinematics`]) and rotation (eqs. 26-31) from the three
    /// carriages' interpolated components (mm, rad) and squareness (rad).
    ///
    /// X_p is the right-handed form (1, tan eZ, tan eX tan eZ - tan eY)/norm,
    /// not the printed eq. 30 (docs/conventions.md, Sign of eps_Z in X_p).
    #[inline(always)]
    pub fn new(s: [f64; 3], c: &[Components; 3], sq: [f64; 3], arms: &[[f64; 3]; 3]) -> Self {
        let [cx, cy, cz] = c;
        let e = Vector3::from(position_error_at(s, c, sq, arms));
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

/// Position error e(S) (mm) at reading `s` (mm) from the carriages'
/// components `c` (mm, rad), squareness `sq` (rad) and `arms` (see
/// [`crate::kinematics::Kinematics::arms`]):
/// e = sum d + sum_A eps(A) x arm(A) + shear.
///
/// The terms are summed in the order of eqs. 11-13 (x and z: carriages X,
/// Y, Z; y: Z, Y, X), so the thesis machine gets the printed equations' bits
/// (a zero arm adds a signed zero, which changes no sum).
#[inline(always)]
pub fn position_error_at(
    s: [f64; 3],
    c: &[Components; 3],
    sq: [f64; 3],
    arms: &[[f64; 3]; 3],
) -> [f64; 3] {
    let [cx, cy, cz] = c;
    let (e_, f_) = (s[1], s[2]);
    let [s_xy, s_yz, s_zx] = sq;
    let arm = |a: usize| [arms[a][0] * s[0], arms[a][1] * s[1], arms[a][2] * s[2]];
    let (rx, ry, rz) = (arm(0), arm(1), arm(2));
    [
        cx[0] + cy[0] + cz[0] - rx[1] * cx[5] + rx[2] * cx[4] - ry[1] * cy[5] + ry[2] * cy[4]
            - rz[1] * cz[5]
            + rz[2] * cz[4]
            - e_ * s_xy
            - f_ * s_zx,
        cx[1] + cy[1] + cz[1] + rz[0] * cz[5] - rz[2] * cz[3] + ry[0] * cy[5] - ry[2] * cy[3]
            + rx[0] * cx[5]
            - rx[2] * cx[3]
            - f_ * s_yz,
        cx[2] + cy[2] + cz[2] + rx[1] * cx[3] - rx[0] * cx[4] + ry[1] * cy[3] - ry[0] * cy[4]
            + rz[1] * cz[3]
            - rz[0] * cz[4],
    ]
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
pub(crate) enum Miss {
    Axis(usize),
    Temperature(f64),
}

pub(crate) type Evaluated = ([Components; 3], [f64; 3]);

/// Where the per-point error components come from: one map, or a map set
/// interpolated in temperature.
pub(crate) trait Source: Sync {
    /// How the machine the maps describe is stacked.
    fn kinematics(&self) -> crate::kinematics::Kinematics;

    /// Components of the three carriages and squareness at reading `s` and
    /// temperatures `t`; counts clamping in `report`.
    fn components(
        &self,
        s: [f64; 3],
        t: &Temperatures,
        opts: &Options,
        report: &mut Report,
    ) -> std::result::Result<Evaluated, Miss>;

    /// Components and squareness of the first `m` lanes, whose readings are
    /// in `lanes.s` (and temperatures in `t`, C, one per lane). `None` on
    /// anything [`components`](Self::components) would not take quietly;
    /// the per-row path then does the rows again. Row by row by default.
    #[inline(always)]
    fn fill_lanes(
        &self,
        lanes: &mut Lanes,
        t: Option<&[f64]>,
        m: usize,
        opts: &Options,
        report: &mut Report,
    ) -> Option<()> {
        for r in 0..m {
            let s = [lanes.s[0][r], lanes.s[1][r], lanes.s[2][r]];
            let temps = Temperatures::uniform(t.map_or(f64::NAN, |t| t[r]));
            let mut one = Report::default();
            let (c, sq) = self.components(s, &temps, opts, &mut one).ok()?;
            if one != Report::default() {
                report.add_counts_times(&one, 1);
            }
            lanes.set(r, &c, sq);
        }
        Some(())
    }

    /// The readable error for a miss at `row`.
    fn miss_error(
        &self,
        miss: Miss,
        row: usize,
        s: [f64; 3],
        t: &Temperatures,
        opts: &Options,
    ) -> CoreError;

    #[inline(always)]
    fn evaluate(
        &self,
        row: usize,
        s: [f64; 3],
        t: &Temperatures,
        opts: &Options,
        report: &mut Report,
    ) -> Result<Evaluated> {
        match self.components(s, t, opts, report) {
            Ok(v) => Ok(v),
            Err(m) => Err(cold_error(self, m, row, s, t, opts)),
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
    t: &Temperatures,
    opts: &Options,
) -> CoreError {
    source.miss_error(miss, row, s, t, opts)
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
    fn kinematics(&self) -> crate::kinematics::Kinematics {
        ErrorMap::kinematics(self)
    }

    /// Table by table over the lanes (see [`crate::blocks::map_lanes`]).
    #[inline(always)]
    fn fill_lanes(
        &self,
        lanes: &mut Lanes,
        _t: Option<&[f64]>,
        m: usize,
        opts: &Options,
        _report: &mut Report,
    ) -> Option<()> {
        // Clamping counts per row: that case goes row by row.
        if opts.out_of_range == OutOfRange::Clamp {
            return None;
        }
        crate::blocks::map_lanes(self, lanes, m)
    }

    #[inline(always)]
    fn miss_error(
        &self,
        miss: Miss,
        row: usize,
        s: [f64; 3],
        _t: &Temperatures,
        _opts: &Options,
    ) -> CoreError {
        match miss {
            Miss::Axis(a) => axis_error(self, a, row, s),
            Miss::Temperature(_) => unreachable!("a single map has no temperature range"),
        }
    }

    /// One map holds at every temperature: `t` is not read.
    #[inline(always)]
    fn components(
        &self,
        s: [f64; 3],
        _t: &Temperatures,
        opts: &Options,
        report: &mut Report,
    ) -> std::result::Result<Evaluated, Miss> {
        let clamp = opts.out_of_range == OutOfRange::Clamp;
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
    fn kinematics(&self) -> crate::kinematics::Kinematics {
        ErrorMapSet::kinematics(self)
    }

    /// Interval by interval, table by table over the lanes (see
    /// [`crate::blocks::set_lanes`]).
    #[inline(always)]
    fn fill_lanes(
        &self,
        lanes: &mut Lanes,
        t: Option<&[f64]>,
        m: usize,
        opts: &Options,
        _report: &mut Report,
    ) -> Option<()> {
        // Clamping counts per row: that case goes row by row.
        if opts.out_of_range == OutOfRange::Clamp {
            return None;
        }
        crate::blocks::set_lanes(self, lanes, t?, m)
    }

    #[inline(always)]
    fn miss_error(
        &self,
        miss: Miss,
        row: usize,
        s: [f64; 3],
        t: &Temperatures,
        opts: &Options,
    ) -> CoreError {
        match miss {
            Miss::Temperature(value) => {
                let (lo, hi) = self.temperature_range();
                CoreError::TemperatureOutOfRange {
                    row: Some(row),
                    value,
                    lo,
                    hi,
                    tolerance: opts.temperature_tolerance,
                }
            }
            // Every interval's grid is the same common range, so any map names it.
            Miss::Axis(a) => match self.interval_of(self.clamp_temperature(t.squareness).0) {
                Some((iv, _)) => axis_error(&iv.base, a, row, s),
                None => axis_error(&self.maps()[0], a, row, s),
            },
        }
    }

    #[inline(always)]
    fn components(
        &self,
        s: [f64; 3],
        t: &Temperatures,
        opts: &Options,
        report: &mut Report,
    ) -> std::result::Result<Evaluated, Miss> {
        let mut fate = Fate::Inside;
        let tc = self.resolve(t.squareness, opts, &mut fate)?;
        // Carriages at their own temperatures (an effect's choice) look up
        // their own interval; the usual case shares the squareness one.
        let uniform = t.map == [t.squareness; 3];
        let mut per_axis = [tc; 3];
        if !uniform {
            for (a, slot) in per_axis.iter_mut().enumerate() {
                *slot = self.resolve(t.map[a], opts, &mut fate)?;
            }
        }
        fate.count(report);
        let Some((iv, dt)) = self.interval_of(tc) else {
            // A single map holds at its own temperature (and within the tolerance).
            return self.maps()[0].components(s, t, opts, report);
        };
        let clamp = opts.out_of_range == OutOfRange::Clamp;
        let mut c = [[0.0; 6]; 3];
        for a in 0..3 {
            let (iva, dta) = if uniform {
                (iv, dt)
            } else {
                self.interval_of(per_axis[a])
                    .expect("a set of two or more maps has intervals")
            };
            let table = &iva.base.tables()[a];
            let loc = if clamp {
                let (loc, moved) = table.locate_clamped(s[a]);
                report.clamped_position[a] += moved as usize;
                loc
            } else {
                table.locate(s[a]).ok_or(Miss::Axis(a))?
            };
            c[a] = iva.at(a, loc, dta);
        }
        Ok((c, iv.squareness(dt)))
    }
}

/// What happened to one point's temperatures (the worst of its carriages').
#[derive(Debug, Clone, Copy, PartialEq)]
enum Fate {
    Inside,
    Held,
    Clamped,
    Extrapolated(f64),
}

impl Fate {
    #[inline(always)]
    fn worse(&mut self, other: Fate) {
        let rank = |f: &Fate| match f {
            Fate::Inside => 0,
            Fate::Held => 1,
            Fate::Clamped => 2,
            Fate::Extrapolated(_) => 3,
        };
        *self = match (*self, other) {
            (Fate::Extrapolated(a), Fate::Extrapolated(b)) => Fate::Extrapolated(a.max(b)),
            (a, b) if rank(&b) > rank(&a) => b,
            (a, _) => a,
        };
    }

    #[inline(always)]
    fn count(self, report: &mut Report) {
        match self {
            Fate::Inside => {}
            Fate::Held => report.held_temperature += 1,
            Fate::Clamped => report.clamped_temperature += 1,
            Fate::Extrapolated(d) => {
                report.extrapolated_temperature += 1;
                report.max_extrapolation = report.max_extrapolation.max(d);
            }
        }
    }
}

impl ErrorMapSet {
    /// The map at temperature `t` (C) under `opts` (tolerance, clamp or
    /// extrapolate, as per point), and what happened to it, counted as one
    /// point of a [`Report`].
    pub fn at_with(&self, t: f64, opts: &Options) -> Result<(ErrorMap, Report)> {
        if !t.is_finite() {
            return Err(CoreError::NonFinite {
                argument: "temperature".into(),
                row: 0,
            });
        }
        let mut fate = Fate::Inside;
        let tu = self.resolve(t, opts, &mut fate).map_err(|_| {
            let (lo, hi) = self.temperature_range();
            CoreError::TemperatureOutOfRange {
                row: None,
                value: t,
                lo,
                hi,
                tolerance: opts.temperature_tolerance,
            }
        })?;
        let mut report = Report {
            points: 1,
            ..Default::default()
        };
        fate.count(&mut report);
        report.clamped_points = (fate == Fate::Clamped) as usize;
        if let Some(m) = self.maps().iter().find(|m| m.temperature() == Some(tu)) {
            return Ok((m.clone(), report));
        }
        let (iv, _) = self
            .interval_of(tu)
            .expect("a temperature off the maps' own ones needs two or more maps");
        Ok((iv.blend(tu), report))
    }

    /// The temperature at which to read the maps for `t` (C) under `opts`:
    /// inside the range as is; within the tolerance outside, held at the
    /// edge; beyond it, an error, the edge (clamp) or `t` itself
    /// (extrapolate, read off the end interval's slope).
    #[inline(always)]
    fn resolve(&self, t: f64, opts: &Options, fate: &mut Fate) -> std::result::Result<f64, Miss> {
        let (tc, moved) = self.clamp_temperature(t);
        if !moved {
            return Ok(t);
        }
        let distance = (t - tc).abs();
        if distance <= opts.temperature_tolerance {
            fate.worse(Fate::Held);
            return Ok(tc);
        }
        match opts.out_of_range {
            OutOfRange::Raise => Err(Miss::Temperature(t)),
            OutOfRange::Clamp => {
                fate.worse(Fate::Clamped);
                Ok(tc)
            }
            OutOfRange::Extrapolate if self.maps().len() > 1 => {
                fate.worse(Fate::Extrapolated(distance));
                Ok(t)
            }
            // One map has no slope to extend: it holds.
            OutOfRange::Extrapolate => {
                fate.worse(Fate::Clamped);
                Ok(tc)
            }
        }
    }
}

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
    drive_blocks(inputs, opts, out, width, |_, _| None, row_fn)
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
) -> Result<Report>
where
    C: Default,
    B: Fn(usize, &mut [f64]) -> Option<Report> + Sync,
    F: Fn(usize, [f64; 3], &mut [f64], &mut Report, &mut C) -> Result<()> + Sync,
{
    let n = inputs.check(out, width)?;
    let chunk_results: Vec<(Report, Option<CoreError>)> = out
        .par_chunks_mut(width * CHUNK)
        .enumerate()
        .map(|(ci, block)| {
            chunk::<C, B, F>(inputs, opts, block, ci * CHUNK, width, &block_fn, &row_fn)
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

/// One chunk: the block path, else the rows. Compiled once per SIMD target
/// and chosen at run time (multiversion); every target does the same IEEE
/// operations in the same order (Rust never fuses a multiply and an add on
/// its own), so the same bits, in wider registers.
#[multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
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
    match maps {
        MapSource::Map(m) => compensate_with(points, m, false, digitizers, effects, opts, out),
        MapSource::Set(s) => compensate_with(points, s, true, digitizers, effects, opts, out),
    }
}

fn compensate_with<S: Source>(
    points: &Points,
    source: &S,
    needs_temperature: bool,
    digitizers: &[Digitizer],
    effects: &Effects,
    opts: Options,
    out: &mut [f64],
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
            if !(x.x.is_finite() && x.y.is_finite() && x.z.is_finite()) {
                return Err(overflow(i));
            }
            slot.copy_from_slice(x.as_slice());
            Ok(())
        },
    )
}

/// Finite inputs whose result is not: readings or (u, v) too large to be
/// millimetres on a machine.
#[cold]
fn overflow(row: usize) -> CoreError {
    CoreError::invalid_argument(
        "uv/scales",
        format!(
            "row {row}: the compensated point overflows (readings or u, v far too large to be mm)"
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
        if !(x.x.is_finite() && x.y.is_finite() && x.z.is_finite()) {
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
