//! Error maps across the boundary: `ErrorMap` (one temperature) and
//! `ErrorMapSet` (several), with the map-level kernels.

use cmmpose_core::kernel;
use cmmpose_core::{Carriage, CarriageTable, ErrorMap, ErrorMapSet, Kinematics, MapSource, Side};
use numpy::{PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::{options, rows, run_kernel, MapPolicy};
use crate::errors::{input, Res};

/// The maps a compensation reads: an ErrorMap, or an ErrorMapSet (one map
/// alone in a set holds at every temperature, as a single map does).
pub fn map_source<'a>(obj: &'a Bound<'_, PyAny>) -> Res<MapSource<'a>> {
    if let Ok(m) = obj.cast::<PyErrorMap>() {
        return Ok(MapSource::Map(&m.get().inner));
    }
    let set = &obj
        .cast::<PyErrorMapSet>()
        .map_err(|_| input("maps: expected an ErrorMap or an ErrorMapSet"))?
        .get()
        .inner;
    Ok(match set.maps() {
        [one] => MapSource::Map(one),
        _ => MapSource::Set(set),
    })
}

/// The 21 component errors at one temperature.
#[pyclass(name = "ErrorMap", module = "cmmpose._core", frozen)]
pub struct PyErrorMap {
    pub inner: ErrorMap,
}

#[pymethods]
impl PyErrorMap {
    /// Tables are (n, 7): position mm, dx dy dz um, ex ey ez arc-second;
    /// squareness (S_xy, S_yz, S_zx) arc-second; temperature C or None.
    #[new]
    #[pyo3(signature = (x, y, z, squareness, temperature=None))]
    fn new(
        x: PyReadonlyArray2<'_, f64>,
        y: PyReadonlyArray2<'_, f64>,
        z: PyReadonlyArray2<'_, f64>,
        squareness: [f64; 3],
        temperature: Option<f64>,
    ) -> Res<Self> {
        let mut tables = Vec::with_capacity(3);
        for (c, (name, t)) in Carriage::ALL
            .into_iter()
            .zip([("x", &x), ("y", &y), ("z", &z)])
        {
            let flat = rows(name, t, 7)?;
            let table_rows: Vec<[f64; 7]> = flat
                .chunks_exact(7)
                .map(|r| r.try_into().unwrap())
                .collect();
            tables.push(CarriageTable::from_table_units(c, &table_rows)?);
        }
        let tables: [CarriageTable; 3] = tables.try_into().map_err(|_| input("three tables"))?;
        Ok(PyErrorMap {
            inner: ErrorMap::new(tables, squareness, temperature)?,
        })
    }

    /// The table of one carriage ('X', 'Y' or 'Z') in table units, (n, 7).
    fn table<'py>(&self, py: Python<'py>, carriage: &str) -> Res<Bound<'py, PyArray2<f64>>> {
        let c = match carriage {
            "X" | "x" => Carriage::X,
            "Y" | "y" => Carriage::Y,
            "Z" | "z" => Carriage::Z,
            other => {
                return Err(input(format!(
                    "carriage: expected 'X', 'Y' or 'Z', got {other:?}"
                )))
            }
        };
        let rows: Vec<Vec<f64>> = self
            .inner
            .table(c)
            .to_table_units()
            .iter()
            .map(|r| r.to_vec())
            .collect();
        PyArray2::from_vec2(py, &rows).map_err(|e| input(e.to_string()))
    }

    /// (S_xy, S_yz, S_zx) in arc-seconds.
    #[getter]
    fn squareness(&self) -> (f64, f64, f64) {
        let s = self.inner.squareness_arcsec();
        (s[0], s[1], s[2])
    }

    #[getter]
    fn temperature(&self) -> Option<f64> {
        self.inner.temperature()
    }

    /// ((lo, hi) mm) for X, Y, Z.
    #[getter]
    fn ranges(&self) -> [(f64, f64); 3] {
        self.inner.ranges()
    }

    fn with_temperature(&self, temperature: Option<f64>) -> Res<Self> {
        Ok(PyErrorMap {
            inner: self.inner.clone().with_temperature(temperature)?,
        })
    }

    #[pyo3(signature = (scales, out_of_range="raise", nan_policy="raise"))]
    fn position_error<'py>(
        &self,
        py: Python<'py>,
        scales: PyReadonlyArray2<'py, f64>,
        out_of_range: &str,
        nan_policy: &str,
    ) -> Res<(Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>)> {
        let opts = options(out_of_range, nan_policy)?;
        let s = rows("scales", &scales, 3)?;
        let map = &self.inner;
        run_kernel(py, s.len() / 3, 3, |out| {
            kernel::position_error(s, map, opts, out)
        })
    }

    #[pyo3(signature = (scales, out_of_range="raise", nan_policy="raise"))]
    fn rotation_error<'py>(
        &self,
        py: Python<'py>,
        scales: PyReadonlyArray2<'py, f64>,
        out_of_range: &str,
        nan_policy: &str,
    ) -> Res<(Bound<'py, PyArray3<f64>>, Bound<'py, PyDict>)> {
        let opts = options(out_of_range, nan_policy)?;
        let s = rows("scales", &scales, 3)?;
        let map = &self.inner;
        let n = s.len() / 3;
        let (flat, report) = run_kernel(py, n, 9, |out| kernel::rotation_error(s, map, opts, out))?;
        Ok((flat.reshape([n, 3, 3])?, report))
    }

    /// The machine configuration the map is for (a name of
    /// `kinematics_configurations()`).
    #[getter]
    fn kinematics(&self) -> &'static str {
        kinematics_name(self.inner.kinematics())
    }

    /// The same map for a machine configured as `kinematics` (a name).
    fn with_kinematics(&self, kinematics: &str) -> Res<Self> {
        Ok(PyErrorMap {
            inner: self
                .inner
                .clone()
                .with_kinematics(Kinematics::named(kinematics)?),
        })
    }

    fn __eq__(&self, other: &Self) -> bool {
        self.inner == other.inner
    }

    /// Pickling: the map's exact parts (kernel and table units), rebuilt
    /// bit for bit by `_error_map_from_state`.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, (MapState,))> {
        let rebuild = py
            .import("cmmpose._core")?
            .getattr("_error_map_from_state")?;
        Ok((rebuild, (map_state(&self.inner),)))
    }
}

/// One carriage table's exact parts: positions (mm), components and
/// slopes (kernel units), 1/pitch, rows in table units.
type TableState = (
    Vec<f64>,
    Vec<[f64; 6]>,
    Vec<[f64; 6]>,
    Option<f64>,
    Vec<[f64; 7]>,
);

/// A map's exact parts: three tables, squareness (rad, arc-second),
/// temperature (C), configuration name (None if custom) and stacking
/// ((carriage index, 'probe' or 'part') from the base up).
type MapState = (
    [TableState; 3],
    [f64; 3],
    [f64; 3],
    Option<f64>,
    Option<String>,
    Vec<(usize, String)>,
);

fn map_state(map: &ErrorMap) -> MapState {
    let tables = std::array::from_fn(|a| {
        let t = map.table(Carriage::ALL[a]);
        (
            t.positions().to_vec(),
            t.values().to_vec(),
            t.slopes().to_vec(),
            t.inv_pitch(),
            t.to_table_units(),
        )
    });
    let k = map.kinematics();
    let stack = k
        .stack()
        .iter()
        .map(|&(a, side)| (a, side.name().to_string()))
        .collect();
    (
        tables,
        map.squareness(),
        map.squareness_arcsec(),
        map.temperature(),
        k.name().map(str::to_string),
        stack,
    )
}

fn map_from_state(state: MapState) -> Res<ErrorMap> {
    let (tables, squareness, squareness_arcsec, temperature, name, stack) = state;
    let mut built = Vec::with_capacity(3);
    for (c, (positions, values, slopes, inv_pitch, rows)) in Carriage::ALL.into_iter().zip(tables) {
        built.push(CarriageTable::from_saved(
            c, positions, values, slopes, inv_pitch, rows,
        )?);
    }
    let tables: [CarriageTable; 3] = built.try_into().map_err(|_| input("three tables"))?;
    let kinematics = match name {
        Some(name) => Kinematics::named(&name)?,
        None => {
            let mut s = [(0, Side::Probe); 3];
            if stack.len() != 3 {
                return Err(input(format!(
                    "map state: the stacking needs 3 carriages, got {}",
                    stack.len()
                )));
            }
            for (slot, (a, side)) in s.iter_mut().zip(stack) {
                let side = Side::from_name(&side).ok_or_else(|| {
                    input(format!(
                        "map state: a carriage carries 'probe' or 'part', got {side:?}"
                    ))
                })?;
                *slot = (a, side);
            }
            Kinematics::new(s)?
        }
    };
    Ok(ErrorMap::from_saved(
        tables,
        squareness,
        squareness_arcsec,
        temperature,
        kinematics,
    )?)
}

/// Unpickling an ErrorMap (its `__reduce__`).
#[pyfunction]
fn _error_map_from_state(state: MapState) -> Res<PyErrorMap> {
    Ok(PyErrorMap {
        inner: map_from_state(state)?,
    })
}

/// Unpickling an ErrorMapSet (its `__reduce__`): the set rebuilt from its
/// maps, as it was built.
#[pyfunction]
fn _error_map_set_from_state(states: Vec<MapState>) -> Res<PyErrorMapSet> {
    let maps = states
        .into_iter()
        .map(map_from_state)
        .collect::<Res<Vec<_>>>()?;
    Ok(PyErrorMapSet {
        inner: ErrorMapSet::new(maps)?,
    })
}

/// The name of a map's stacking (maps are only stacked by name here).
fn kinematics_name(k: Kinematics) -> &'static str {
    k.name().unwrap_or("custom")
}

/// The named machine configurations: name, description and the stacking
/// from the base up as (carriage letter, 'probe' or 'part').
#[pyfunction]
fn kinematics_configurations<'py>(py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
    Kinematics::names()
        .into_iter()
        .map(|(name, description)| {
            let d = PyDict::new(py);
            d.set_item("name", name)?;
            d.set_item("description", description)?;
            let stack: Vec<(String, &str)> = Kinematics::named(name)
                .expect("a listed name")
                .stack()
                .iter()
                .map(|&(a, side)| (Carriage::ALL[a].letter().to_string(), side.name()))
                .collect();
            d.set_item("stack", stack)?;
            Ok(d)
        })
        .collect()
}

/// Error maps at several temperatures.
#[pyclass(name = "ErrorMapSet", module = "cmmpose._core", frozen)]
pub struct PyErrorMapSet {
    pub inner: ErrorMapSet,
}

#[pymethods]
impl PyErrorMapSet {
    #[new]
    fn new(maps: Vec<PyRef<'_, PyErrorMap>>) -> Res<Self> {
        let maps = maps.iter().map(|m| m.inner.clone()).collect();
        Ok(PyErrorMapSet {
            inner: ErrorMapSet::new(maps)?,
        })
    }

    #[getter]
    fn temperatures(&self) -> Vec<f64> {
        self.inner.temperatures()
    }

    /// The maps, sorted by temperature.
    #[getter]
    fn maps(&self) -> Vec<PyErrorMap> {
        self.inner
            .maps()
            .iter()
            .map(|m| PyErrorMap { inner: m.clone() })
            .collect()
    }

    /// The machine configuration of the set's maps.
    #[getter]
    fn kinematics(&self) -> &'static str {
        kinematics_name(self.inner.kinematics())
    }

    /// The same set for a machine configured as `kinematics` (a name).
    fn with_kinematics(&self, kinematics: &str) -> Res<Self> {
        Ok(PyErrorMapSet {
            inner: self.inner.with_kinematics(Kinematics::named(kinematics)?),
        })
    }

    /// The map blended at `temperature` (C), held within the policy's
    /// `temperature_tolerance` (K) outside the maps, clamped or extrapolated
    /// beyond as its `out_of_range` says (`policy`: a `cmmpose.TemperaturePolicy`).
    fn at(&self, temperature: f64, policy: MapPolicy) -> Res<PyErrorMap> {
        let opts = policy.options("raise")?;
        let (inner, _) = self.inner.at_with(temperature, &opts)?;
        Ok(PyErrorMap { inner })
    }

    fn __eq__(&self, other: &Self) -> bool {
        self.inner.maps() == other.inner.maps()
    }

    /// Pickling: the maps' exact parts; the set is rebuilt from them.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, (Vec<MapState>,))> {
        let rebuild = py
            .import("cmmpose._core")?
            .getattr("_error_map_set_from_state")?;
        Ok((
            rebuild,
            (self.inner.maps().iter().map(map_state).collect(),),
        ))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyErrorMap>()?;
    m.add_class::<PyErrorMapSet>()?;
    m.add_function(wrap_pyfunction!(kinematics_configurations, m)?)?;
    m.add_function(wrap_pyfunction!(_error_map_from_state, m)?)?;
    m.add_function(wrap_pyfunction!(_error_map_set_from_state, m)?)?;
    Ok(())
}
