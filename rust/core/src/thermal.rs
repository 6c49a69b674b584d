//! Error maps at several temperatures (thesis section 6.4): linear between the
//! two closest map temperatures, for all 21 components.
//!
//! Blending happens once per temperature interval, not per point: for each
//! pair of neighbouring maps we resample both onto the union of their grids
//! (exact, since both are piecewise linear there) and keep a base map and a
//! per-degree slope map. A point at temperature T then costs one table lookup
//! of base and slope.

use crate::error::{CoreError, Result};
use crate::kinematics::Kinematics;
use crate::map::{Carriage, CarriageTable, Components, ErrorMap, Located};

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
        let r = &self.packed[carriage][loc.segment];
        let x = loc.offset;
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
            return Err(CoreError::invalid_map(
                "error map set",
                format!(
                    "the maps are for differently stacked machines ({:?} and {:?})",
                    maps[0].kinematics(),
                    maps[i].kinematics()
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

    /// The intervals between neighbouring maps, coldest first (none for a
    /// single map).
    #[inline(always)]
    pub(crate) fn intervals(&self) -> &[Interval] {
        &self.intervals
    }

    /// Whether every interval's table of carriage `a` has the same grid.
    #[inline(always)]
    pub(crate) fn shared_grid(&self, a: usize) -> bool {
        self.shared_grid[a]
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
        let opts = crate::kernel::Options {
            out_of_range: if clamp {
                crate::kernel::OutOfRange::Clamp
            } else {
                crate::kernel::OutOfRange::Raise
            },
            ..Default::default()
        };
        Ok(self.at_with(t, &opts)?.0)
    }
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
