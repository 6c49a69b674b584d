//! What the compensation kernel reads the maps through, and the arithmetic
//! every path shares: the [`Source`] of the per-point error components (one
//! map here; a map set in [`crate::thermal`]), the call's [`Options`] and
//! [`Report`], and the error state of one reading ([`PointError`], thesis
//! eqs. 11-13 and 26-31).
//!
//! Layers (lowest first): [`crate::map`] and [`crate::lanes`], this module,
//! [`crate::thermal`] (map sets), [`crate::blocks`] (the block paths),
//! [`crate::kernel`] (the public entry points). A module uses only the ones
//! below it (`tests/package/test_structure.py` checks it).

use nalgebra::Vector3;

use crate::effects::Temperatures;
use crate::error::{CoreError, Result};
use crate::lanes::{map_lanes, Lanes};
use crate::map::{Components, ErrorMap};

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
    pub(crate) fn merge(mut self, o: Report) -> Report {
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
    pub(crate) fn clamped_sum(&self) -> usize {
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

pub(crate) fn axis_error(map: &ErrorMap, a: usize, row: usize, s: [f64; 3]) -> CoreError {
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

    /// Table by table over the lanes (see [`map_lanes`]).
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
        map_lanes(self, lanes, m)
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
