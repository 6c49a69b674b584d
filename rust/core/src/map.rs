//! Error maps: per carriage a table of six component errors over scale
//! position, plus three squareness errors (thesis section 3.3, Table 6).
//!
//! Tables are stored in kernel units (mm, rad) with a precomputed slope per
//! segment, so evaluating a component is one multiply-add.

use crate::error::{CoreError, Result};
use crate::kinematics::Kinematics;
use crate::units::{
    component_bound, component_from_kernel, component_to_kernel, plausible_length, shown,
    ARCSEC_TO_RAD, MAX_ANGLE_ARCSEC, MAX_LENGTH_MM, TEMPERATURE_RANGE_C,
};

/// The three carriages of the CMM, in kinematic order (X on the table, Y on
/// the bridge, Z the ram).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Carriage {
    X = 0,
    Y = 1,
    Z = 2,
}

impl Carriage {
    pub const ALL: [Carriage; 3] = [Carriage::X, Carriage::Y, Carriage::Z];

    pub fn letter(self) -> char {
        ['X', 'Y', 'Z'][self as usize]
    }
}

/// Names of the six components, in table column order.
pub const COMPONENT_NAMES: [&str; 6] = ["dx", "dy", "dz", "ex", "ey", "ez"];

/// Six component errors: delta_x, delta_y, delta_z (mm), eps_x, eps_y, eps_z (rad).
pub type Components = [f64; 6];

/// Where a scale reading falls in a table: segment index and offset (mm) from
/// the segment's start.
#[derive(Debug, Clone, Copy)]
pub struct Located {
    pub segment: usize,
    pub offset: f64,
}

/// One carriage's table on a strictly increasing position grid.
///
/// Two tables are equal when their rows as given (positions mm, table
/// units) are equal: the kernel-unit values, slopes and 1/pitch are derived
/// from them and may differ in the last bit between a blended table and the
/// same rows read back from a file.
#[derive(Debug, Clone)]
pub struct CarriageTable {
    positions: Vec<f64>,
    values: Vec<Components>,
    /// Per segment: change of each component per mm.
    slopes: Vec<Components>,
    /// 1 / pitch when the grid is uniform, enabling O(1) lookup.
    inv_pitch: Option<f64>,
    /// The rows as given in table units, so that reading and writing a map
    /// returns the digits the user supplied (unit conversion is not exact
    /// in binary floating point).
    table_rows: Vec<[f64; 7]>,
}

impl PartialEq for CarriageTable {
    fn eq(&self, other: &Self) -> bool {
        self.table_rows == other.table_rows
    }
}

impl CarriageTable {
    /// Build from values already in kernel units (mm, rad). `carriage` only
    /// labels error messages.
    pub fn new(carriage: Carriage, positions: Vec<f64>, values: Vec<Components>) -> Result<Self> {
        let where_ = |row: usize| format!("{} carriage table, row {}", carriage.letter(), row);
        if positions.len() != values.len() {
            return Err(CoreError::invalid_map(
                format!("{} carriage table", carriage.letter()),
                format!(
                    "{} positions but {} rows of components",
                    positions.len(),
                    values.len()
                ),
            ));
        }
        if positions.len() < 2 {
            return Err(CoreError::invalid_map(
                format!("{} carriage table", carriage.letter()),
                format!(
                    "needs at least 2 rows to interpolate, got {}",
                    positions.len()
                ),
            ));
        }
        for (i, (&p, v)) in positions.iter().zip(&values).enumerate() {
            if !p.is_finite() {
                return Err(CoreError::invalid_map(
                    where_(i),
                    format!("position {p} is not finite"),
                ));
            }
            if !plausible_length(p) {
                return Err(CoreError::invalid_map(
                    where_(i),
                    format!("position {} mm is beyond +-{MAX_LENGTH_MM} mm: not a position on a machine", shown(p)),
                ));
            }
            if let Some(k) = v.iter().position(|c| !c.is_finite()) {
                return Err(CoreError::invalid_map(
                    where_(i),
                    format!("component {} is not finite ({})", COMPONENT_NAMES[k], v[k]),
                ));
            }
            if i > 0 && p <= positions[i - 1] {
                let what = if p == positions[i - 1] {
                    "duplicates"
                } else {
                    "is less than"
                };
                return Err(CoreError::invalid_map(
                    where_(i),
                    format!("position {p} mm {what} the previous position {} mm; positions must strictly increase", positions[i - 1]),
                ));
            }
        }
        let slopes = positions
            .windows(2)
            .zip(values.windows(2))
            .map(|(p, v)| {
                let h = p[1] - p[0];
                std::array::from_fn(|k| (v[1][k] - v[0][k]) / h)
            })
            .collect();
        let n = positions.len();
        let pitch = (positions[n - 1] - positions[0]) / (n - 1) as f64;
        let uniform = positions
            .windows(2)
            .all(|w| ((w[1] - w[0]) - pitch).abs() <= 1e-9 * pitch.abs().max(1.0));
        let table_rows = positions
            .iter()
            .zip(&values)
            .map(|(&p, v)| {
                let mut row = [p, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
                for k in 0..6 {
                    row[k + 1] = component_from_kernel(k, v[k]);
                }
                row
            })
            .collect();
        Ok(CarriageTable {
            positions,
            values,
            slopes,
            inv_pitch: uniform.then(|| 1.0 / pitch),
            table_rows,
        })
    }

    /// Build from rows in table units: position (mm), three deltas (um) and
    /// three angles (arc-second), as printed in the thesis.
    /// The door of a map a user gives: each component within a machine's
    /// error (10 cm, one degree), which the tables derived inside the core
    /// (a map set's slopes per C, an extrapolated blend) need not be.
    pub fn from_table_units(carriage: Carriage, rows: &[[f64; 7]]) -> Result<Self> {
        for (i, row) in rows.iter().enumerate() {
            let table = |k: usize| row[k + 1];
            if let Some(k) = (0..6).find(|&k| table(k).abs() > component_bound(k)) {
                let unit = if k < 3 { "um" } else { "arc-second" };
                return Err(CoreError::invalid_map(
                    format!("{} carriage table, row {}", carriage.letter(), i),
                    format!(
                        "component {} is {} {unit}, beyond +-{} {unit}: not a machine's error",
                        COMPONENT_NAMES[k],
                        shown(table(k)),
                        component_bound(k)
                    ),
                ));
            }
        }
        let positions = rows.iter().map(|r| r[0]).collect();
        let values = rows
            .iter()
            .map(|r| std::array::from_fn(|k| component_to_kernel(k, r[k + 1])))
            .collect();
        let mut table = Self::new(carriage, positions, values)?;
        table.table_rows = rows.to_vec();
        Ok(table)
    }

    /// Rows in table units (position mm, um x3, arc-second x3).
    pub fn to_table_units(&self) -> Vec<[f64; 7]> {
        self.table_rows.clone()
    }

    pub fn positions(&self) -> &[f64] {
        &self.positions
    }

    /// Change of each component per mm, one per segment (kernel units).
    pub fn slopes(&self) -> &[Components] {
        &self.slopes
    }

    /// 1 / pitch (1/mm) when the grid is uniform.
    pub fn inv_pitch(&self) -> Option<f64> {
        self.inv_pitch
    }

    /// Rebuild a table bit for bit from what [`positions`](Self::positions),
    /// [`values`](Self::values), [`slopes`](Self::slopes),
    /// [`inv_pitch`](Self::inv_pitch) and
    /// [`to_table_units`](Self::to_table_units) return (serialising: a
    /// blended table's slopes are not recomputed, so results stay equal to
    /// the last bit). The grid is checked as [`new`](Self::new) checks it.
    pub fn from_saved(
        carriage: Carriage,
        positions: Vec<f64>,
        values: Vec<Components>,
        slopes: Vec<Components>,
        inv_pitch: Option<f64>,
        table_rows: Vec<[f64; 7]>,
    ) -> Result<Self> {
        let mut table = Self::new(carriage, positions, values)?;
        let n = table.positions.len();
        if slopes.len() != n - 1 || table_rows.len() != n {
            return Err(CoreError::invalid_map(
                format!("{} carriage table", carriage.letter()),
                format!(
                    "saved state: {n} positions need {} slopes and {n} table rows, got {} and {}",
                    n - 1,
                    slopes.len(),
                    table_rows.len()
                ),
            ));
        }
        if slopes.iter().flatten().any(|v| !v.is_finite())
            || inv_pitch.is_some_and(|p| !(p.is_finite() && p > 0.0))
        {
            return Err(CoreError::invalid_map(
                format!("{} carriage table", carriage.letter()),
                "saved state: slopes and 1/pitch must be finite",
            ));
        }
        table.slopes = slopes;
        table.inv_pitch = inv_pitch;
        table.table_rows = table_rows;
        Ok(table)
    }

    /// Components in kernel units (mm, rad), one per grid position.
    pub fn values(&self) -> &[Components] {
        &self.values
    }

    /// First and last grid position (mm).
    pub fn range(&self) -> (f64, f64) {
        (self.positions[0], self.positions[self.positions.len() - 1])
    }

    /// Segment holding `x`, or `None` when `x` is outside the table (or NaN).
    #[inline(always)]
    pub fn locate(&self, x: f64) -> Option<Located> {
        let (lo, hi) = self.range();
        if !(x >= lo && x <= hi) {
            return None;
        }
        Some(self.locate_inside(x))
    }

    /// Like [`locate`](Self::locate) but clamps to the table ends; the flag
    /// says whether clamping happened.
    #[inline]
    pub fn locate_clamped(&self, x: f64) -> (Located, bool) {
        let (lo, hi) = self.range();
        if x < lo {
            (
                Located {
                    segment: 0,
                    offset: 0.0,
                },
                true,
            )
        } else if x > hi {
            let s = self.positions.len() - 2;
            (
                Located {
                    segment: s,
                    offset: self.positions[s + 1] - self.positions[s],
                },
                true,
            )
        } else {
            (self.locate_inside(x), false)
        }
    }

    /// The first node, 1 / pitch and the last segment's index of a uniform
    /// grid (what `locate_inside` computes a segment from), or `None`.
    #[inline(always)]
    pub(crate) fn uniform_grid(&self) -> Option<(f64, f64, usize)> {
        self.inv_pitch
            .map(|inv| (self.positions[0], inv, self.positions.len() - 2))
    }

    #[inline(always)]
    pub(crate) fn locate_inside(&self, x: f64) -> Located {
        let last = self.positions.len() - 2;
        let segment = match self.inv_pitch {
            // O(1) on a uniform grid. Rounding can put a reading that sits
            // on a node into the neighbouring segment; the line through that
            // segment passes through the node, so the value is the same.
            Some(inv) => (((x - self.positions[0]) * inv) as usize).min(last),
            None => self
                .positions
                .partition_point(|&p| p <= x)
                .saturating_sub(1)
                .min(last),
        };
        Located {
            segment,
            offset: x - self.positions[segment],
        }
    }

    /// Value at the start of segment `i` and change per mm along it.
    #[inline(always)]
    pub(crate) fn segment(&self, i: usize) -> (&Components, &Components) {
        (&self.values[i], &self.slopes[i])
    }

    pub(crate) fn segment_count(&self) -> usize {
        self.slopes.len()
    }

    /// Components (mm, rad) at a located position.
    #[inline(always)]
    pub fn at(&self, loc: Located) -> Components {
        let v = &self.values[loc.segment];
        let s = &self.slopes[loc.segment];
        std::array::from_fn(|k| v[k] + loc.offset * s[k])
    }

    /// Components (mm, rad) at `x`, or `None` outside the table.
    pub fn eval(&self, x: f64) -> Option<Components> {
        self.locate(x).map(|l| self.at(l))
    }
}

/// The 21 geometric component errors of a CMM at one temperature.
///
/// Two maps are equal when what they are is equal: the tables' rows as given
/// (see [`CarriageTable`]), the squareness in arc-seconds as given, the
/// temperature and the stacking; not the caches derived from them (radians,
/// slopes), which may differ in the last bit.
#[derive(Debug, Clone)]
pub struct ErrorMap {
    tables: [CarriageTable; 3],
    /// S_xy, S_yz, S_zx in radians.
    squareness: [f64; 3],
    /// The same as given, in arc-seconds (kept for exact round trips).
    squareness_arcsec: [f64; 3],
    temperature: Option<f64>,
    /// How the carriages are stacked: over which arms the angles act.
    kinematics: Kinematics,
}

impl PartialEq for ErrorMap {
    fn eq(&self, other: &Self) -> bool {
        self.tables == other.tables
            && self.squareness_arcsec == other.squareness_arcsec
            && self.temperature == other.temperature
            && self.kinematics == other.kinematics
    }
}

impl ErrorMap {
    /// Squareness in arc-seconds, tables already built.
    pub fn new(
        tables: [CarriageTable; 3],
        squareness_arcsec: [f64; 3],
        temperature: Option<f64>,
    ) -> Result<Self> {
        const NAMES: [&str; 3] = ["S_xy", "S_yz", "S_zx"];
        for (name, s) in NAMES.iter().zip(squareness_arcsec) {
            if !s.is_finite() {
                return Err(CoreError::invalid_map(
                    "squareness",
                    format!("{name} is not finite ({s})"),
                ));
            }
            if !(s.abs() <= MAX_ANGLE_ARCSEC) {
                return Err(CoreError::invalid_map(
                    "squareness",
                    format!("{name} is {} arc-second, beyond +-{MAX_ANGLE_ARCSEC} arc-second (one degree): not a machine's squareness", shown(s)),
                ));
            }
        }
        Self::check_temperature(temperature)?;
        Ok(ErrorMap {
            tables,
            squareness: squareness_arcsec.map(|s| s * ARCSEC_TO_RAD),
            squareness_arcsec,
            temperature,
            kinematics: Kinematics::thesis(),
        })
    }

    /// A map with every component zero on the given ranges: the
    /// uncompensated machine.
    pub fn zero(ranges: [(f64, f64); 3]) -> Self {
        let tables = std::array::from_fn(|a| {
            let (lo, hi) = ranges[a];
            CarriageTable::new(Carriage::ALL[a], vec![lo, hi], vec![[0.0; 6]; 2])
                .expect("zero table is valid when lo < hi")
        });
        ErrorMap {
            tables,
            squareness: [0.0; 3],
            squareness_arcsec: [0.0; 3],
            temperature: None,
            kinematics: Kinematics::thesis(),
        }
    }

    pub fn table(&self, carriage: Carriage) -> &CarriageTable {
        &self.tables[carriage as usize]
    }

    pub fn tables(&self) -> &[CarriageTable; 3] {
        &self.tables
    }

    /// S_xy, S_yz, S_zx in radians.
    pub fn squareness(&self) -> [f64; 3] {
        self.squareness
    }

    pub fn squareness_arcsec(&self) -> [f64; 3] {
        self.squareness_arcsec
    }

    pub fn temperature(&self) -> Option<f64> {
        self.temperature
    }

    /// A non-finite temperature is refused as in [`ErrorMap::new`].
    pub fn with_temperature(mut self, temperature: Option<f64>) -> Result<Self> {
        Self::check_temperature(temperature)?;
        self.temperature = temperature;
        Ok(self)
    }

    /// The map temperature's check, one for [`ErrorMap::new`] and
    /// [`ErrorMap::with_temperature`].
    fn check_temperature(temperature: Option<f64>) -> Result<()> {
        match temperature {
            Some(t) if !t.is_finite() => Err(CoreError::invalid_map(
                "temperature",
                format!("{t} C is not finite"),
            )),
            Some(t) if !(TEMPERATURE_RANGE_C.0..=TEMPERATURE_RANGE_C.1).contains(&t) => {
                Err(CoreError::invalid_map(
                    "temperature",
                    format!(
                        "{} C is outside {} to {} C: not a temperature a machine is mapped at",
                        shown(t),
                        TEMPERATURE_RANGE_C.0,
                        TEMPERATURE_RANGE_C.1
                    ),
                ))
            }
            _ => Ok(()),
        }
    }

    /// How the machine's carriages are stacked (the thesis's X-Y-Z chain
    /// unless set).
    pub fn kinematics(&self) -> Kinematics {
        self.kinematics
    }

    /// The same map for a machine stacked as `kinematics`.
    pub fn with_kinematics(mut self, kinematics: Kinematics) -> Self {
        self.kinematics = kinematics;
        self
    }

    /// (lo, hi) scale range in mm for each carriage.
    pub fn ranges(&self) -> [(f64, f64); 3] {
        std::array::from_fn(|a| self.tables[a].range())
    }

    /// Rebuild a map bit for bit from its parts (serialising): tables as
    /// [`CarriageTable::from_saved`] makes them, squareness in radians and
    /// as given in arc-seconds, temperature (C) and stacking.
    pub fn from_saved(
        tables: [CarriageTable; 3],
        squareness: [f64; 3],
        squareness_arcsec: [f64; 3],
        temperature: Option<f64>,
        kinematics: Kinematics,
    ) -> Result<Self> {
        let mut map = Self::new(tables, squareness_arcsec, temperature)?;
        if squareness.iter().any(|s| !s.is_finite()) {
            return Err(CoreError::invalid_map(
                "squareness",
                "saved state: radians must be finite",
            ));
        }
        map.squareness = squareness;
        map.kinematics = kinematics;
        Ok(map)
    }

    /// Build a map with `squareness` in radians (internal use by blending).
    pub(crate) fn from_parts(
        tables: [CarriageTable; 3],
        squareness: [f64; 3],
        temperature: Option<f64>,
        kinematics: Kinematics,
    ) -> Self {
        ErrorMap {
            tables,
            squareness,
            squareness_arcsec: squareness.map(|s| s / ARCSEC_TO_RAD),
            temperature,
            kinematics,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(positions: &[f64]) -> Result<CarriageTable> {
        let rows: Vec<[f64; 7]> = positions
            .iter()
            .map(|&p| [p, p, 0.0, 0.0, 0.0, 0.0, 2.0 * p])
            .collect();
        CarriageTable::from_table_units(Carriage::Y, &rows)
    }

    #[test]
    fn interpolates_linearly_on_uniform_and_nonuniform_grids() {
        for grid in [vec![0.0, 25.0, 50.0, 75.0], vec![0.0, 10.0, 35.0, 75.0]] {
            let t = table(&grid).unwrap();
            for x in [0.0, 3.3, 10.0, 24.999, 25.0, 49.0, 74.5, 75.0] {
                let c = t.eval(x).unwrap();
                assert!((c[0] - x * 1e-3).abs() < 1e-15, "dx at {x}");
                assert!((c[5] - 2.0 * x * ARCSEC_TO_RAD).abs() < 1e-15, "ez at {x}");
            }
            assert!(t.eval(-0.001).is_none());
            assert!(t.eval(75.001).is_none());
            assert!(t.eval(f64::NAN).is_none());
        }
    }

    #[test]
    fn values_beyond_a_machines_bounds_are_refused_naming_row_and_component() {
        let rows = |p1: f64, v: [f64; 6]| {
            let r = [0.0; 7];
            let mut s = [p1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
            s[1..].copy_from_slice(&v);
            CarriageTable::from_table_units(Carriage::X, &[r, s])
        };
        let at_bounds = [1e5, -1e5, 0.0, 3600.0, -3600.0, 0.0];
        rows(1e5, at_bounds).unwrap();
        let e = rows(1e5 + 1.0, [0.0; 6]).unwrap_err().to_string();
        assert!(
            e.contains("X carriage table, row 1") && e.contains("100001 mm is beyond"),
            "{e}"
        );
        let e = rows(25.0, [0.0, 1e30, 0.0, 0.0, 0.0, 0.0])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("row 1") && e.contains("component dy is 1e30 um"),
            "{e}"
        );
        let e = rows(25.0, [0.0, 0.0, 0.0, 0.0, 0.0, -3601.0])
            .unwrap_err()
            .to_string();
        assert!(e.contains("component ez is -3601 arc-second"), "{e}");
        let tables = || [0.0, 1.0, 2.0].map(|_| table(&[0.0, 25.0, 50.0]).unwrap());
        ErrorMap::new(tables(), [3600.0, -3600.0, 0.0], Some(-50.0)).unwrap();
        let e = ErrorMap::new(tables(), [0.0, -1e9, 0.0], None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("S_yz is -1e9 arc-second"), "{e}");
        for t in [-273.16, 150.5, 1e300] {
            let e = ErrorMap::new(tables(), [0.0; 3], Some(t))
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("temperature") && e.contains("is outside -50 to 150 C"),
                "{e}"
            );
        }
    }

    #[test]
    fn saved_parts_rebuild_the_same_table_and_map() {
        let t = table(&[0.0, 10.0, 35.0, 75.0]).unwrap();
        let back = CarriageTable::from_saved(
            Carriage::Y,
            t.positions().to_vec(),
            t.values().to_vec(),
            t.slopes().to_vec(),
            t.inv_pitch(),
            t.to_table_units(),
        )
        .unwrap();
        assert_eq!(back, t);
        assert_eq!(back.values(), t.values());
        assert_eq!(back.slopes(), t.slopes());
        assert_eq!(back.inv_pitch(), t.inv_pitch());
        let short = CarriageTable::from_saved(
            Carriage::Y,
            t.positions().to_vec(),
            t.values().to_vec(),
            t.slopes()[1..].to_vec(),
            t.inv_pitch(),
            t.to_table_units(),
        );
        assert!(short.unwrap_err().to_string().contains("slopes"));
        let tables = [0.0, 1.0, 2.0].map(|_| table(&[0.0, 25.0, 50.0]).unwrap());
        let map = ErrorMap::new(tables.clone(), [1.5, -2.0, 0.25], Some(21.0)).unwrap();
        let k = Kinematics::named("gantry").unwrap();
        let map = map.with_kinematics(k);
        let back = ErrorMap::from_saved(
            tables,
            map.squareness(),
            map.squareness_arcsec(),
            map.temperature(),
            k,
        )
        .unwrap();
        assert_eq!(back, map);
        assert_eq!(back.squareness(), map.squareness());
    }

    #[test]
    fn equality_is_the_rows_as_given_not_the_derived_caches() {
        let t = table(&[0.0, 10.0, 35.0, 75.0]).unwrap();
        // The same rows with a slope off by one ulp (as blending can leave it).
        let mut slopes = t.slopes().to_vec();
        slopes[1][0] = f64::from_bits(slopes[1][0].to_bits() + 1);
        let nudged = CarriageTable::from_saved(
            Carriage::Y,
            t.positions().to_vec(),
            t.values().to_vec(),
            slopes,
            t.inv_pitch(),
            t.to_table_units(),
        )
        .unwrap();
        assert_eq!(nudged, t);
        let mut rows = t.to_table_units();
        rows[2][3] += 0.5;
        assert_ne!(
            CarriageTable::from_table_units(Carriage::Y, &rows).unwrap(),
            t
        );
        let tables = || [0.0, 1.0, 2.0].map(|_| table(&[0.0, 25.0, 50.0]).unwrap());
        let map = ErrorMap::new(tables(), [1.5, -2.0, 0.25], Some(21.0)).unwrap();
        let mut rad = map.squareness();
        rad[0] = f64::from_bits(rad[0].to_bits() + 1);
        let same = ErrorMap::from_saved(
            tables(),
            rad,
            map.squareness_arcsec(),
            map.temperature(),
            map.kinematics(),
        )
        .unwrap();
        assert_eq!(same, map);
        assert_ne!(map.clone().with_temperature(Some(21.5)).unwrap(), map);
        assert_ne!(
            map.clone()
                .with_kinematics(Kinematics::named("gantry").unwrap()),
            map
        );
        let other = ErrorMap::new(tables(), [1.5, -2.0, 0.5], Some(21.0)).unwrap();
        assert_ne!(other, map);
    }

    #[test]
    fn with_temperature_refuses_what_new_refuses() {
        let tables = || [0.0, 1.0, 2.0].map(|_| table(&[0.0, 25.0, 50.0]).unwrap());
        let map = ErrorMap::new(tables(), [1.5, -2.0, 0.25], None).unwrap();
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let e = map.clone().with_temperature(Some(bad)).unwrap_err();
            let n = ErrorMap::new(tables(), [1.5, -2.0, 0.25], Some(bad)).unwrap_err();
            assert_eq!(e.to_string(), n.to_string());
            assert!(
                e.to_string().contains("temperature") && e.to_string().contains("not finite"),
                "{e}"
            );
        }
        let warm = map.clone().with_temperature(Some(21.5)).unwrap();
        assert_eq!(warm.temperature(), Some(21.5));
        assert_eq!(warm.with_temperature(None).unwrap().temperature(), None);
    }

    #[test]
    fn clamping_reports_and_holds_end_values() {
        let t = table(&[0.0, 25.0, 50.0]).unwrap();
        let (l, c) = t.locate_clamped(60.0);
        assert!(c);
        assert!((t.at(l)[0] - 0.05).abs() < 1e-15);
        let (l, c) = t.locate_clamped(-1.0);
        assert!(c);
        assert_eq!(t.at(l)[0], 0.0);
        assert!(!t.locate_clamped(10.0).1);
    }

    #[test]
    fn rejects_bad_tables_with_row_numbers() {
        let e = table(&[0.0, 25.0, 25.0]).unwrap_err().to_string();
        assert!(
            e.contains("Y carriage table, row 2") && e.contains("duplicates"),
            "{e}"
        );
        let e = table(&[0.0, 25.0, 20.0]).unwrap_err().to_string();
        assert!(e.contains("row 2") && e.contains("less than"), "{e}");
        let e = table(&[0.0]).unwrap_err().to_string();
        assert!(e.contains("at least 2 rows"), "{e}");
        let e = table(&[0.0, f64::NAN]).unwrap_err().to_string();
        assert!(e.contains("row 1") && e.contains("not finite"), "{e}");
        let rows = [[0.0, 0.0, 0.0, f64::INFINITY, 0.0, 0.0, 0.0], [1.0; 7]];
        let e = CarriageTable::from_table_units(Carriage::Z, &rows)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("Z carriage table, row 0") && e.contains("dz"),
            "{e}"
        );
    }

    #[test]
    fn round_trips_table_units() {
        let rows = [
            [0.0, 1.5, -2.0, 3.0, 0.57, -0.37, 12.0],
            [25.0, 2.0, 0.0, 0.0, 1.0, 2.0, 3.0],
        ];
        let t = CarriageTable::from_table_units(Carriage::X, &rows).unwrap();
        let back = t.to_table_units();
        assert_eq!(back, rows.to_vec());
    }
}
