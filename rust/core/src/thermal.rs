//! Error maps at several temperatures (thesis section 6.4): linear between the
//! two closest map temperatures, for all 21 components.
//!
//! Blending happens once per temperature interval, not per point: for each
//! pair of neighbouring maps we resample both onto the union of their grids
//! (exact, since both are piecewise linear there) and keep a base map and a
//! per-degree slope map. A point at temperature T then costs one table lookup
//! of base and slope.
//!
//! Everything a set does lives here: the temperature policy per point
//! (`at_with`, held / clamped / extrapolated temperatures), the `Source`
//! the kernel reads it through, and a block of rows at once (`set_lanes`).

use crate::effects::Temperatures;
use crate::error::{CoreError, Result};
use crate::kinematics::Kinematics;
#[cfg(target_arch = "x86_64")]
use crate::lanes::set_rows_avx;
use crate::lanes::{map_lanes, use_avx, Lanes, LANES};
use crate::map::{Carriage, CarriageTable, Components, ErrorMap, Located};
use crate::source::{axis_error, Evaluated, Miss, Options, OutOfRange, Report, Source};

/// Base map at `t_lo` and its rate of change per degree C up to `t_hi`.
#[derive(Debug, Clone)]
pub(crate) struct Interval {
    pub t_lo: f64,
    pub t_hi: f64,
    pub base: ErrorMap,
    /// Same grids as `base`; values are per degree C.
    pub slope: ErrorMap,
    /// Per carriage and segment, base and slope side by side (value, per mm,
    /// value per C, per mm per C) so one point reads one cache line run.
    packed: [Vec<[f64; 24]>; 3],
}

impl Interval {
    fn new(t_lo: f64, t_hi: f64, base: ErrorMap, slope: ErrorMap) -> Self {
        let packed = std::array::from_fn(|a| {
            let (b, s) = (&base.tables()[a], &slope.tables()[a]);
            (0..b.segment_count())
                .map(|i| {
                    let ((bv, bs), (sv, ss)) = (b.segment(i), s.segment(i));
                    let mut row = [0.0; 24];
                    row[..6].copy_from_slice(bv);
                    row[6..12].copy_from_slice(bs);
                    row[12..18].copy_from_slice(sv);
                    row[18..].copy_from_slice(ss);
                    row
                })
                .collect()
        });
        Interval {
            t_lo,
            t_hi,
            base,
            slope,
            packed,
        }
    }

    #[inline(always)]
    pub fn at(&self, carriage: usize, loc: Located, dt: f64) -> Components {
        Self::row_at(&self.packed[carriage][loc.segment], loc.offset, dt)
    }

    /// The components of one packed segment row at `x` mm into the segment
    /// and `dt` C above `t_lo`: (base + x . per mm) + dt . (slope + x .
    /// slope per mm), the one formula of the per-row and the lane paths.
    #[inline(always)]
    fn row_at(r: &[f64; 24], x: f64, dt: f64) -> Components {
        std::array::from_fn(|k| (r[k] + x * r[6 + k]) + dt * (r[12 + k] + x * r[18 + k]))
    }

    #[inline(always)]
    pub fn squareness(&self, dt: f64) -> [f64; 3] {
        let b = self.base.squareness();
        let s = self.slope.squareness();
        std::array::from_fn(|k| b[k] + dt * s[k])
    }

    pub(crate) fn blend(&self, t: f64) -> ErrorMap {
        let dt = t - self.t_lo;
        let tables = std::array::from_fn(|a| {
            let base = &self.base.tables()[a];
            let slope = &self.slope.tables()[a];
            let values = base
                .values()
                .iter()
                .zip(slope.values())
                .map(|(b, s)| std::array::from_fn(|k| b[k] + dt * s[k]))
                .collect();
            CarriageTable::new(Carriage::ALL[a], base.positions().to_vec(), values)
                .expect("blend of valid tables is valid")
        });
        ErrorMap::from_parts(tables, self.squareness(dt), Some(t), self.base.kinematics())
    }
}

/// A set of error maps measured at different temperatures.
#[derive(Debug, Clone)]
pub struct ErrorMapSet {
    maps: Vec<ErrorMap>,
    intervals: Vec<Interval>,
    /// Per carriage: whether every interval has the same grid (maps
    /// measured on the same positions), so that a reading is located once
    /// for whichever interval its temperature falls in.
    shared_grid: [bool; 3],
}

/// Resample a table onto `grid` (inside its range) by linear interpolation.
fn resample(table: &CarriageTable, grid: &[f64]) -> Vec<Components> {
    grid.iter()
        .map(|&x| table.eval(x).expect("grid lies inside the table"))
        .collect()
}

/// Union of two grids over the intersection of their ranges.
fn union_grid(a: &[f64], b: &[f64]) -> Vec<f64> {
    let lo = a[0].max(b[0]);
    let hi = a[a.len() - 1].min(b[b.len() - 1]);
    let mut g: Vec<f64> = a
        .iter()
        .chain(b)
        .copied()
        .filter(|&x| x >= lo && x <= hi)
        .collect();
    g.sort_by(|x, y| x.partial_cmp(y).expect("finite grid"));
    g.dedup();
    g
}

impl ErrorMapSet {
    /// Maps in any order; each must carry a distinct temperature.
    pub fn new(mut maps: Vec<ErrorMap>) -> Result<Self> {
        if maps.is_empty() {
            return Err(CoreError::invalid_map(
                "error map set",
                "needs at least one map",
            ));
        }
        for (i, m) in maps.iter().enumerate() {
            if m.temperature().is_none() {
                return Err(CoreError::invalid_map(
                    format!("error map set, map {i}"),
                    "has no temperature; every map in a set needs one",
                ));
            }
        }
        maps.sort_by(|a, b| {
            a.temperature()
                .partial_cmp(&b.temperature())
                .expect("finite temperatures")
        });
        for w in maps.windows(2) {
            if w[0].temperature() == w[1].temperature() {
                return Err(CoreError::invalid_map(
                    "error map set",
                    format!(
                        "two maps at the same temperature {} C",
                        w[0].temperature().unwrap()
                    ),
                ));
            }
        }
        if let Some(i) = maps
            .iter()
            .position(|m| m.kinematics() != maps[0].kinematics())
        {
            // A named configuration by its name; a custom stacking by its carriages.
            let said = |k: &crate::kinematics::Kinematics| {
                k.name()
                    .map(|n| format!("'{n}'"))
                    .unwrap_or_else(|| format!("a custom stacking {:?}", k.stack()))
            };
            return Err(CoreError::invalid_map(
                "error map set",
                format!(
                    "the maps are for differently stacked machines: map 0 {}, map {i} {}",
                    said(&maps[0].kinematics()),
                    said(&maps[i].kinematics())
                ),
            ));
        }
        let mut intervals = Vec::with_capacity(maps.len().saturating_sub(1));
        for w in maps.windows(2) {
            intervals.push(Self::interval(&w[0], &w[1])?);
        }
        let shared_grid = std::array::from_fn(|a| {
            intervals
                .windows(2)
                .all(|w| w[0].base.tables()[a].positions() == w[1].base.tables()[a].positions())
        });
        Ok(ErrorMapSet {
            maps,
            intervals,
            shared_grid,
        })
    }

    fn interval(lo: &ErrorMap, hi: &ErrorMap) -> Result<Interval> {
        let (t_lo, t_hi) = (lo.temperature().unwrap(), hi.temperature().unwrap());
        let inv_dt = 1.0 / (t_hi - t_lo);
        let mut base_tables = Vec::with_capacity(3);
        let mut slope_tables = Vec::with_capacity(3);
        for c in Carriage::ALL {
            let (a, b) = (lo.table(c), hi.table(c));
            let grid = union_grid(a.positions(), b.positions());
            if grid.len() < 2 {
                return Err(CoreError::invalid_map(
                    format!("error map set, {} carriage", c.letter()),
                    format!("the maps at {t_lo} C and {t_hi} C have no common position range"),
                ));
            }
            let va = resample(a, &grid);
            let vb = resample(b, &grid);
            let slope = va
                .iter()
                .zip(&vb)
                .map(|(x, y)| std::array::from_fn(|k| (y[k] - x[k]) * inv_dt))
                .collect();
            base_tables.push(CarriageTable::new(c, grid.clone(), va)?);
            slope_tables.push(CarriageTable::new(c, grid, slope)?);
        }
        let to_array = |v: Vec<CarriageTable>| -> [CarriageTable; 3] {
            v.try_into().expect("three carriages")
        };
        let (sa, sb) = (lo.squareness(), hi.squareness());
        Ok(Interval::new(
            t_lo,
            t_hi,
            ErrorMap::from_parts(to_array(base_tables), sa, Some(t_lo), lo.kinematics()),
            ErrorMap::from_parts(
                to_array(slope_tables),
                std::array::from_fn(|k| (sb[k] - sa[k]) * inv_dt),
                None,
                lo.kinematics(),
            ),
        ))
    }

    pub fn maps(&self) -> &[ErrorMap] {
        &self.maps
    }

    /// How the machine's carriages are stacked (every map's).
    pub fn kinematics(&self) -> Kinematics {
        self.maps[0].kinematics()
    }

    /// The same set for a machine stacked as `kinematics`.
    pub fn with_kinematics(&self, kinematics: Kinematics) -> Self {
        let maps = self
            .maps
            .iter()
            .map(|m| m.clone().with_kinematics(kinematics))
            .collect();
        ErrorMapSet::new(maps).expect("the same maps, restacked, are a valid set")
    }

    pub fn temperatures(&self) -> Vec<f64> {
        self.maps.iter().map(|m| m.temperature().unwrap()).collect()
    }

    /// Lowest and highest map temperature (C).
    pub fn temperature_range(&self) -> (f64, f64) {
        (
            self.maps[0].temperature().unwrap(),
            self.maps[self.maps.len() - 1].temperature().unwrap(),
        )
    }

    /// Which interval holds `t` (already inside the range) and the offset
    /// from its lower temperature. `None` when the set has a single map.
    #[inline]
    pub(crate) fn interval_of(&self, t: f64) -> Option<(&Interval, f64)> {
        let last = self.intervals.len().checked_sub(1)?;
        // Branch-free count: temperatures of neighbouring points vary at random
        // between intervals, where a search would mispredict.
        let i = self.intervals[..last]
            .iter()
            .map(|iv| (t > iv.t_hi) as usize)
            .sum::<usize>();
        let iv = &self.intervals[i];
        Some((iv, t - iv.t_lo))
    }

    /// Clamp `t` into the covered range; the flag says whether it moved.
    #[inline]
    pub(crate) fn clamp_temperature(&self, t: f64) -> (f64, bool) {
        let (lo, hi) = self.temperature_range();
        if t < lo {
            (lo, true)
        } else if t > hi {
            (hi, true)
        } else {
            (t, false)
        }
    }

    /// Components (mm, rad) of one carriage at reading `x` (mm) and temperature
    /// `t` (C), both already inside the covered ranges; `None` outside.
    #[inline]
    pub fn carriage_at(&self, carriage: Carriage, x: f64, t: f64) -> Option<Components> {
        let (lo, hi) = self.temperature_range();
        if !(t >= lo && t <= hi) {
            return None;
        }
        match self.interval_of(t) {
            Some((iv, dt)) => iv.base.tables()[carriage as usize]
                .locate(x)
                .map(|loc| iv.at(carriage as usize, loc, dt)),
            None => self.maps[0].table(carriage).eval(x),
        }
    }

    /// Squareness (rad) at temperature `t` (C) inside the covered range.
    pub fn squareness_at(&self, t: f64) -> Option<[f64; 3]> {
        let (lo, hi) = self.temperature_range();
        if !(t >= lo && t <= hi) {
            return None;
        }
        Some(match self.interval_of(t) {
            Some((iv, dt)) => iv.squareness(dt),
            None => self.maps[0].squareness(),
        })
    }

    /// The map at temperature `t` (C): linear between the two closest maps
    /// for all 21 components. Outside the range: an error, or the end map
    /// when `clamp` is set (no tolerance; see [`ErrorMapSet::at_with`]).
    pub fn at(&self, t: f64, clamp: bool) -> Result<ErrorMap> {
        let opts = Options {
            out_of_range: if clamp {
                OutOfRange::Clamp
            } else {
                OutOfRange::Raise
            },
            ..Default::default()
        };
        Ok(self.at_with(t, &opts)?.0)
    }
}

impl Source for ErrorMapSet {
    fn kinematics(&self) -> Kinematics {
        ErrorMapSet::kinematics(self)
    }

    /// Interval by interval, table by table over the lanes (see
    /// [`set_lanes`]).
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
        set_lanes(self, lanes, t?, m)
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

/// The components of a map set for the first `m` lanes at temperatures `t`
/// (C, one per lane): every lane's interval and offset in temperature
/// first, then table by table as [`map_lanes`], each lane reading its
/// interval's base and slope (the operations of the per-row path:
/// `ErrorMapSet::interval_of`, `CarriageTable::locate`, `Interval::at` and
/// `Interval::squareness`, so the same bits). The readings are located once
/// for the whole block when its lanes share one grid: one interval (a
/// machine's temperature moves slowly), or maps measured on the same
/// positions; else lane by lane. `None` if a temperature is outside the
/// set's range (held, clamped or extrapolated temperatures are counted per
/// row: the per-row path does them) or a reading outside its table.
#[inline(always)]
pub(crate) fn set_lanes(set: &ErrorMapSet, lanes: &mut Lanes, t: &[f64], m: usize) -> Option<()> {
    let t = &t[..m];
    let (lo, hi) = set.temperature_range();
    let mut inside = true;
    for &x in t {
        inside &= (x >= lo) & (x <= hi);
    }
    if !inside {
        return None;
    }
    let intervals = &set.intervals[..];
    let Some(last) = intervals.len().checked_sub(1) else {
        // A single map: every temperature inside its range is its own.
        return map_lanes(&set.maps[0], lanes, m);
    };
    // interval_of's branch-free count, interval by interval over the
    // lanes (one vector loop each; a set has a few intervals), then each
    // lane's offset from its interval's lower temperature.
    let mut which = [0usize; LANES];
    let mut dt = [0.0; LANES];
    for iv in &intervals[..last] {
        for (w, &x) in which.iter_mut().zip(t) {
            *w += (x > iv.t_hi) as usize;
        }
    }
    for (i, iv) in intervals.iter().enumerate() {
        for ((d, &w), &x) in dt.iter_mut().zip(&which).zip(t) {
            *d = if w == i { x - iv.t_lo } else { *d };
        }
    }
    let shared = which[1..m].iter().all(|&w| w == which[0]);
    for a in 0..3 {
        if shared || set.shared_grid[a] {
            // One grid for every lane: located once for the block.
            let table = &intervals[which[0]].base.tables()[a];
            if !lanes.inside(a, m, table.range()) {
                return None;
            }
            lanes.locate(a, table, m);
        } else {
            for r in 0..m {
                let at = intervals[which[r]].base.tables()[a].locate(lanes.s[a][r])?;
                lanes.segment[r] = at.segment;
                lanes.offset[r] = at.offset;
            }
            lanes.pad(m);
        }
        #[cfg(target_arch = "x86_64")]
        if use_avx() {
            let segment = lanes.segment;
            let row = |r: usize| &intervals[which[r]].packed[a][segment[r]];
            // SAFETY: the CPU has AVX (checked above); every lane below the
            // next multiple of four holds an interval (padding: the first)
            // and a segment of its table (see `Lanes::pad`).
            unsafe { set_rows_avx(row, &dt, lanes, a, m) };
            continue;
        }
        if shared {
            let packed = &intervals[which[0]].packed[a][..];
            for (((row, &k), &x), &d) in lanes
                .rows
                .iter_mut()
                .zip(&lanes.segment)
                .zip(&lanes.offset)
                .zip(&dt)
                .take(m)
            {
                row[..6].copy_from_slice(&Interval::row_at(&packed[k], x, d));
            }
        } else {
            for ((((row, &k), &x), &d), &w) in lanes
                .rows
                .iter_mut()
                .zip(&lanes.segment)
                .zip(&lanes.offset)
                .zip(&dt)
                .zip(&which)
                .take(m)
            {
                row[..6].copy_from_slice(&Interval::row_at(&intervals[w].packed[a][k], x, d));
            }
        }
        lanes.transpose(a, m);
    }
    // Interval::squareness, interval by interval over the lanes.
    for (i, iv) in intervals.iter().enumerate() {
        if !shared || i == which[0] {
            let (b, s) = (iv.base.squareness(), iv.slope.squareness());
            for (k, lane) in lanes.sq.iter_mut().enumerate() {
                for ((q, &w), &d) in lane.iter_mut().zip(&which).zip(&dt).take(m) {
                    *q = if w == i { b[k] + d * s[k] } else { *q };
                }
            }
        }
    }
    Some(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat_map(grid: &[f64], value: f64, sq: f64, t: f64) -> ErrorMap {
        let tables = std::array::from_fn(|a| {
            let rows: Vec<[f64; 7]> = grid
                .iter()
                .map(|&p| [p, value, value, value, value, value, value + p])
                .collect();
            CarriageTable::from_table_units(Carriage::ALL[a], &rows).unwrap()
        });
        ErrorMap::new(tables, [sq, -sq, 2.0 * sq], Some(t)).unwrap()
    }

    #[test]
    fn midpoint_is_mean_of_neighbours_for_all_components() {
        let set = ErrorMapSet::new(vec![
            flat_map(&[0.0, 25.0, 50.0], 10.0, 100.0, 25.0),
            flat_map(&[0.0, 25.0, 50.0], 2.0, -40.0, 20.0),
        ])
        .unwrap();
        let m = set.at(22.5, false).unwrap();
        let a = set.maps()[0].table(Carriage::Y).eval(30.0).unwrap();
        let b = set.maps()[1].table(Carriage::Y).eval(30.0).unwrap();
        let c = m.table(Carriage::Y).eval(30.0).unwrap();
        for k in 0..6 {
            assert!((c[k] - 0.5 * (a[k] + b[k])).abs() < 1e-15);
        }
        for k in 0..3 {
            assert!(
                (m.squareness()[k]
                    - 0.5 * (set.maps()[0].squareness()[k] + set.maps()[1].squareness()[k]))
                    .abs()
                    < 1e-18
            );
        }
        assert_eq!(m.temperature(), Some(22.5));
    }

    #[test]
    fn blends_maps_on_different_grids_exactly() {
        let set = ErrorMapSet::new(vec![
            flat_map(&[0.0, 50.0, 100.0], 0.0, 0.0, 20.0),
            flat_map(&[0.0, 30.0, 90.0], 6.0, 0.0, 30.0),
        ])
        .unwrap();
        let m = set.at(25.0, false).unwrap();
        assert_eq!(m.table(Carriage::X).positions(), &[0.0, 30.0, 50.0, 90.0]);
        for x in [0.0, 12.0, 30.0, 47.0, 77.0, 90.0] {
            let a = set.maps()[0].table(Carriage::X).eval(x).unwrap();
            let b = set.maps()[1].table(Carriage::X).eval(x).unwrap();
            let c = m.table(Carriage::X).eval(x).unwrap();
            for k in 0..6 {
                assert!((c[k] - 0.5 * (a[k] + b[k])).abs() < 1e-15);
            }
        }
    }

    #[test]
    fn rejects_out_of_range_and_bad_sets() {
        let set = ErrorMapSet::new(vec![
            flat_map(&[0.0, 1.0], 0.0, 0.0, 20.0),
            flat_map(&[0.0, 1.0], 1.0, 0.0, 30.0),
        ])
        .unwrap();
        let e = set.at(31.0, false).unwrap_err().to_string();
        assert!(e.contains("31") && e.contains("[20, 30]"), "{e}");
        assert_eq!(set.at(31.0, true).unwrap().temperature(), Some(30.0));
        assert!(ErrorMapSet::new(vec![]).is_err());
        let e = ErrorMapSet::new(vec![
            flat_map(&[0.0, 1.0], 0.0, 0.0, 20.0),
            flat_map(&[0.0, 1.0], 0.0, 0.0, 20.0),
        ])
        .unwrap_err();
        assert!(e.to_string().contains("same temperature"));
        let e = ErrorMapSet::new(vec![
            flat_map(&[0.0, 1.0], 0.0, 0.0, 20.0),
            flat_map(&[2.0, 3.0], 0.0, 0.0, 25.0),
        ])
        .unwrap_err();
        assert!(e.to_string().contains("no common position range"), "{e}");
    }
}
