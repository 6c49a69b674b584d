//! Physical effects beyond the error maps (docs/conventions.md, "Effects").
//!
//! Every effect that computes per point is one [`Term`] in this file, written
//! once: the truth machine ([`crate::truth`]) and the simulated scanner apply
//! it forward, the compensation kernel ([`crate::kernel`]) inverts it. The
//! thesis compensation is the kernel with no term switched on. Effects that
//! act on the whole pose or on an artefact's length only (alignment, mount
//! offset, artefact expansion) have no term: they live in their Python file.
//!
//! A term acts on one point at up to five stages, in this order:
//! 1. `scanner`: the reported (u, v) of a true one (forward) and back (inverse);
//! 2. `reading`: the scale reading at the instant of the profile (model side;
//!    the simulator moves the latch along the trajectory instead);
//! 3. `temperatures`: each carriage's map temperature, squareness temperature;
//! 4. `machine`: additions to the interpolated components and squareness,
//!    the same in the truth machine and in the model;
//! 5. `mount`: a factor on the mount offset l1.
//!
//! Forward scanner stages run in registry order, inverse ones in reverse, so
//! the model undoes exactly what the simulator did.
//!
//! Adding an effect: write a unit struct with its `Term` impl and list it in
//! [`TERMS`] (docs/adding-an-effect.md).

#![allow(clippy::needless_range_loop)] // per-axis loops read clearer indexed

use crate::error::{CoreError, Result};
use crate::map::Components;
use crate::units::{plausible_temperature, ARCSEC_TO_RAD, TEMPERATURE_RANGE_C};

/// One named per-point input: `width` values per point, flat row-major.
#[derive(Debug, Clone, Copy)]
pub struct Column<'a> {
    pub name: &'a str,
    pub width: usize,
    pub values: &'a [f64],
}

/// The named per-point inputs of a call beyond (u, v) and the scale readings:
/// `temperature` (C, the machine mean) and whatever the terms need.
#[derive(Debug, Clone, Default)]
pub struct Columns<'a> {
    list: Vec<Column<'a>>,
}

impl<'a> Columns<'a> {
    pub fn new() -> Self {
        Columns { list: Vec::new() }
    }

    /// Add the input `name` with `width` values per point.
    pub fn with(mut self, name: &'a str, width: usize, values: &'a [f64]) -> Self {
        self.list.push(Column {
            name,
            width,
            values,
        });
        self
    }

    pub fn get(&self, name: &str) -> Option<&Column<'a>> {
        self.list.iter().find(|c| c.name == name)
    }

    /// The columns for which `keep(name)` holds.
    pub(crate) fn only(&self, keep: impl Fn(&str) -> bool) -> Columns<'a> {
        Columns {
            list: self.list.iter().filter(|c| keep(c.name)).cloned().collect(),
        }
    }

    pub fn iter(&self) -> impl Iterator<Item = &Column<'a>> {
        self.list.iter()
    }

    /// Every column holds `width` values for each of `n` points.
    pub(crate) fn check(&self, n: usize) -> Result<()> {
        for (k, c) in self.list.iter().enumerate() {
            if self.list[..k].iter().any(|o| o.name == c.name) {
                return Err(CoreError::invalid_argument(c.name, "given twice"));
            }
            if c.width == 0 || c.values.len() != c.width * n {
                return Err(CoreError::invalid_argument(
                    c.name,
                    format!(
                        "has {} values, expected {} ({} per point for {n} points)",
                        c.values.len(),
                        c.width * n,
                        c.width
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The first temperature column (`temperature`, `*_temperature`) with
    /// a value in row `i` outside the temperatures a machine works at, and
    /// that value.
    #[inline(always)]
    pub(crate) fn implausible_temperature(&self, i: usize) -> Option<(&'a str, f64)> {
        self.list
            .iter()
            .filter(|c| is_temperature(c.name))
            .find_map(|c| {
                c.values[c.width * i..c.width * (i + 1)]
                    .iter()
                    .find(|&&x| !plausible_temperature(x))
                    .map(|&x| (c.name, x))
            })
    }

    /// The first column with a non-finite value in row `i`.
    #[inline(always)]
    pub(crate) fn non_finite(&self, i: usize) -> Option<&'a str> {
        self.list
            .iter()
            .find(|c| {
                !c.values[c.width * i..c.width * (i + 1)]
                    .iter()
                    .all(|x| x.is_finite())
            })
            .map(|c| c.name)
    }
}

/// The inputs of one point that a term declared, in its declared order.
#[derive(Clone, Copy)]
pub struct Row<'a> {
    i: usize,
    cols: &'a [&'a [f64]],
}

impl Row<'_> {
    /// The `k`-th declared input of a width-1 column.
    #[inline(always)]
    pub fn scalar(&self, k: usize) -> f64 {
        self.cols[k][self.i]
    }

    /// The `k`-th declared input of a width-3 column.
    #[inline(always)]
    pub fn triple(&self, k: usize) -> [f64; 3] {
        let c = self.cols[k];
        [c[3 * self.i], c[3 * self.i + 1], c[3 * self.i + 2]]
    }
}

/// What the temperature stage sets for one point (C).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Temperatures {
    /// The temperature at which each carriage's map is taken.
    pub map: [f64; 3],
    /// The temperature at which squareness is taken (the machine mean
    /// unless a term says otherwise).
    pub squareness: f64,
    /// The machine mean: what terms read as "the mean", whatever the
    /// terms before them set the other two to.
    pub mean: f64,
}

impl Temperatures {
    /// All carriages and squareness at the machine mean `t`.
    #[inline(always)]
    pub fn uniform(t: f64) -> Self {
        Temperatures {
            map: [t; 3],
            squareness: t,
            mean: t,
        }
    }
}

/// The machine's errors at one reading: each carriage's six components
/// (dx, dy, dz mm; ex, ey, ez rad) and squareness S_xy, S_yz, S_zx (rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MachineErrors {
    pub components: [Components; 3],
    pub squareness: [f64; 3],
}

/// One physical effect that computes per point. Parameters arrive in the
/// units the Python effect file states (arc-second, ppm, s, ...); every
/// hook does nothing unless the term overrides it.
pub trait Term: Sync + Send {
    /// The one name of the effect everywhere (Python, CLI, JSON, docs).
    fn name(&self) -> &'static str;
    /// Parameter names, in order.
    fn params(&self) -> &'static [&'static str];
    /// Per-point inputs the term reads: (name, values per point).
    fn inputs(&self) -> &'static [(&'static str, usize)] {
        &[]
    }
    /// True (u, v) -> what the scanner reports (mm).
    fn scanner_forward(&self, _p: &[f64], _row: Row, _uv: &mut [f64; 2]) {}
    /// What the scanner reports -> true (u, v) (mm).
    fn scanner_inverse(&self, _p: &[f64], _row: Row, _uv: &mut [f64; 2]) {}
    /// Recorded scale reading -> the reading at the profile's instant (mm).
    fn reading(&self, _p: &[f64], _row: Row, _s: &mut [f64; 3]) {}
    /// Map and squareness temperatures (C).
    fn temperatures(&self, _p: &[f64], _row: Row, _t: &mut Temperatures) {}
    /// Errors the maps lack, at the reading `s` (mm).
    fn machine(&self, _p: &[f64], _row: Row, _s: [f64; 3], _e: &mut MachineErrors) {}
    /// Factor on the mount offset l1 (1: none).
    fn mount(&self, _p: &[f64], _row: Row) -> f64 {
        1.0
    }
    /// Whether the stages other than the scanner's read the term's inputs.
    /// A term whose inputs serve only its scanner stage (a per-point
    /// quantity such as the angle of incidence) says `false`: the points of
    /// a profile then share one machine state whatever those inputs are.
    /// The default, `true`, is always correct.
    fn state_reads_inputs(&self) -> bool {
        true
    }
    /// [`Term::scanner_inverse`] over consecutive rows `start..` of `uv`
    /// (N x 2, mm): the same operations per row, in one loop that is
    /// compiled for the term (no call per point), so it vectorises.
    fn scanner_inverse_rows(&self, p: &[f64], cols: &[&[f64]], start: usize, uv: &mut [f64]) {
        for (r, q) in uv.chunks_exact_mut(2).enumerate() {
            let mut point = [q[0], q[1]];
            self.scanner_inverse(p, Row { i: start + r, cols }, &mut point);
            q[0] = point[0];
            q[1] = point[1];
        }
    }
    /// Whether the term has a scanner stage (overrides `scanner_forward`
    /// and `scanner_inverse`); the kernel calls only those that do. A
    /// registry test checks that a term saying `false` leaves (u, v) alone.
    fn acts_on_scanner(&self) -> bool {
        false
    }
}

/// Squareness the map has wrong: S_xy, S_yz, S_zx += (xy, yz, zx) arc-second.
struct Squareness;
impl Term for Squareness {
    fn name(&self) -> &'static str {
        "squareness"
    }
    fn params(&self) -> &'static [&'static str] {
        &["xy", "yz", "zx"]
    }
    fn machine(&self, p: &[f64], _: Row, _: [f64; 3], e: &mut MachineErrors) {
        for k in 0..3 {
            e.squareness[k] += p[k] * ARCSEC_TO_RAD;
        }
    }
}

/// Scale error of each axis: the linear error grows by ppm 1e-6 x reading.
struct Scale;
impl Term for Scale {
    fn name(&self) -> &'static str {
        "scale"
    }
    fn params(&self) -> &'static [&'static str] {
        &["x", "y", "z"]
    }
    fn machine(&self, p: &[f64], _: Row, s: [f64; 3], e: &mut MachineErrors) {
        for k in 0..3 {
            e.components[k][k] += p[k] * 1e-6 * s[k];
        }
    }
}

/// Roll of each carriage about its own axis, linear in the reading
/// (arc-second per metre of travel from home).
struct Roll;
impl Term for Roll {
    fn name(&self) -> &'static str {
        "roll"
    }
    fn params(&self) -> &'static [&'static str] {
        &["x", "y", "z"]
    }
    fn machine(&self, p: &[f64], _: Row, s: [f64; 3], e: &mut MachineErrors) {
        for k in 0..3 {
            e.components[k][3 + k] += p[k] * ARCSEC_TO_RAD * s[k] / 1000.0;
        }
    }
}

/// Each carriage's map taken at T + gain (T_k - T), T_k its own scale
/// thermocouples (gain 1: fully per axis; the truth machine uses 1).
struct AxisTemperature;
impl Term for AxisTemperature {
    fn name(&self) -> &'static str {
        "axis-temperature"
    }
    fn params(&self) -> &'static [&'static str] {
        &["gain"]
    }
    fn inputs(&self) -> &'static [(&'static str, usize)] {
        &[("axis_temperature", 3)]
    }
    fn temperatures(&self, p: &[f64], row: Row, t: &mut Temperatures) {
        let axis = row.triple(0);
        let mean = t.mean;
        for k in 0..3 {
            t.map[k] = mean + p[0] * (axis[k] - mean);
        }
    }
}

/// Squareness taken at T + gain (T_s - T), T_s the thermocouples the data
/// chose (the bindings' `squareness_sensor` column: the mean of one role's
/// channels) instead of the machine mean T (gain 1: fully at the sensor).
struct SquarenessTemperature;
impl Term for SquarenessTemperature {
    fn name(&self) -> &'static str {
        "squareness-temperature"
    }
    fn params(&self) -> &'static [&'static str] {
        &["gain"]
    }
    fn inputs(&self) -> &'static [(&'static str, usize)] {
        &[("squareness_sensor", 1)]
    }
    fn temperatures(&self, p: &[f64], row: Row, t: &mut Temperatures) {
        t.squareness = t.mean + p[0] * (row.scalar(0) - t.mean);
    }
}

/// Squareness change per kelvin of granite top-minus-bottom gradient
/// (xy, yz, zx arc-second/K).
struct GraniteGradient;
impl Term for GraniteGradient {
    fn name(&self) -> &'static str {
        "granite-gradient"
    }
    fn params(&self) -> &'static [&'static str] {
        &["xy", "yz", "zx"]
    }
    fn inputs(&self) -> &'static [(&'static str, usize)] {
        &[("gradient", 1)]
    }
    fn machine(&self, p: &[f64], row: Row, _: [f64; 3], e: &mut MachineErrors) {
        let g = row.scalar(0);
        for k in 0..3 {
            e.squareness[k] += p[k] * g * ARCSEC_TO_RAD;
        }
    }
}

/// The scales were latched `seconds` before the profile: the reading at the
/// profile is the recorded one plus latency x scale velocity.
struct Latency;
impl Term for Latency {
    fn name(&self) -> &'static str {
        "latency"
    }
    fn params(&self) -> &'static [&'static str] {
        &["seconds"]
    }
    fn inputs(&self) -> &'static [(&'static str, usize)] {
        &[("velocity", 3)]
    }
    fn reading(&self, p: &[f64], row: Row, s: &mut [f64; 3]) {
        let v = row.triple(0);
        for k in 0..3 {
            s[k] += p[0] * v[k];
        }
    }
}

/// Scanner scale errors: reported u = (1 + lateral) u, v = (1 + depth) v.
struct ScannerScale;
impl Term for ScannerScale {
    fn name(&self) -> &'static str {
        "scanner-scale"
    }
    fn params(&self) -> &'static [&'static str] {
        &["lateral", "depth"]
    }
    fn acts_on_scanner(&self) -> bool {
        true
    }
    fn scanner_forward(&self, p: &[f64], _: Row, uv: &mut [f64; 2]) {
        uv[0] *= 1.0 + p[0];
        uv[1] *= 1.0 + p[1];
    }
    fn scanner_inverse(&self, p: &[f64], _: Row, uv: &mut [f64; 2]) {
        uv[0] /= 1.0 + p[0];
        uv[1] /= 1.0 + p[1];
    }
}

/// Depth error growing with the incidence angle theta (degrees) and depth:
/// reported v = v + per_degree theta + per_degree_mm v theta.
struct Incidence;
impl Term for Incidence {
    fn name(&self) -> &'static str {
        "incidence"
    }
    fn params(&self) -> &'static [&'static str] {
        &["per_degree", "per_degree_mm"]
    }
    fn inputs(&self) -> &'static [(&'static str, usize)] {
        &[("incidence", 1)]
    }
    fn acts_on_scanner(&self) -> bool {
        true
    }
    fn scanner_forward(&self, p: &[f64], row: Row, uv: &mut [f64; 2]) {
        let theta = row.scalar(0);
        uv[1] = uv[1] + p[0] * theta + p[1] * uv[1] * theta;
    }
    fn scanner_inverse(&self, p: &[f64], row: Row, uv: &mut [f64; 2]) {
        let theta = row.scalar(0);
        uv[1] = (uv[1] - p[0] * theta) / (1.0 + p[1] * theta);
    }
    fn state_reads_inputs(&self) -> bool {
        false
    }
}

/// The mount offset l1 scales by 1 + alpha (T_mount - 20 C): the mount's
/// thermal expansion (ppm/K), T_mount from its own thermocouple.
struct MountExpansion;
impl Term for MountExpansion {
    fn name(&self) -> &'static str {
        "mount-expansion"
    }
    fn params(&self) -> &'static [&'static str] {
        &["ppm_per_kelvin"]
    }
    fn inputs(&self) -> &'static [(&'static str, usize)] {
        &[("mount_temperature", 1)]
    }
    fn mount(&self, p: &[f64], row: Row) -> f64 {
        1.0 + p[0] * 1e-6 * (row.scalar(0) - 20.0)
    }
}

/// Every term, in stage order of the forward scanner model.
pub static TERMS: &[&dyn Term] = &[
    &Squareness,
    &Scale,
    &Roll,
    &AxisTemperature,
    &SquarenessTemperature,
    &GraniteGradient,
    &Latency,
    &ScannerScale,
    &Incidence,
    &MountExpansion,
];

/// The term named `name`.
pub fn term(name: &str) -> Option<&'static dyn Term> {
    TERMS.iter().copied().find(|t| t.name() == name)
}

/// Names of every term, in registry order.
pub fn term_names() -> Vec<&'static str> {
    TERMS.iter().map(|t| t.name()).collect()
}

/// The effects switched on in a model or a truth machine, each with its
/// parameters. Terms whose parameters are all zero are dropped: at zero an
/// effect is the thesis model and needs none of its inputs.
#[derive(Clone, Default)]
pub struct Effects {
    /// (index into [`TERMS`], parameters), in registry order.
    list: Vec<(usize, Vec<f64>)>,
}

impl std::fmt::Debug for Effects {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_map()
            .entries(self.list.iter().map(|(k, p)| (TERMS[*k].name(), p)))
            .finish()
    }
}

impl Effects {
    /// No effect: the thesis model.
    pub fn none() -> Self {
        Effects::default()
    }

    /// From (name, parameters) pairs; names must be terms of [`TERMS`],
    /// each once, with one finite value per parameter.
    pub fn new<S: AsRef<str>>(named: impl IntoIterator<Item = (S, Vec<f64>)>) -> Result<Self> {
        let mut list: Vec<(usize, Vec<f64>)> = Vec::new();
        for (name, params) in named {
            let name = name.as_ref();
            let Some(k) = TERMS.iter().position(|t| t.name() == name) else {
                return Err(CoreError::invalid_argument(
                    format!("effects[{name:?}]"),
                    format!("unknown term (known: {})", term_names().join(", ")),
                ));
            };
            let want = TERMS[k].params();
            if params.len() != want.len() || !params.iter().all(|x| x.is_finite()) {
                return Err(CoreError::invalid_argument(
                    format!("effects[{name:?}]"),
                    format!(
                        "expected {} finite values ({}), got {params:?}",
                        want.len(),
                        want.join(", ")
                    ),
                ));
            }
            if list.iter().any(|(j, _)| *j == k) {
                return Err(CoreError::invalid_argument(
                    format!("effects[{name:?}]"),
                    "given twice",
                ));
            }
            if params.iter().any(|&x| x != 0.0) {
                list.push((k, params));
            }
        }
        list.sort_by_key(|(k, _)| *k);
        Ok(Effects { list })
    }

    pub fn is_empty(&self) -> bool {
        self.list.is_empty()
    }

    /// Whether a term switched on reads the input `name`.
    pub fn reads(&self, name: &str) -> bool {
        self.list
            .iter()
            .any(|(k, _)| TERMS[*k].inputs().iter().any(|&(n, _)| n == name))
    }

    /// Names of the terms switched on.
    pub fn names(&self) -> Vec<&'static str> {
        self.list.iter().map(|(k, _)| TERMS[*k].name()).collect()
    }

    /// Resolve each term's inputs among `columns`; names the missing one.
    pub fn bind<'a>(&'a self, columns: &Columns<'a>) -> Result<Bound<'a>> {
        let mut active = Vec::with_capacity(self.list.len());
        for (k, params) in &self.list {
            let term = TERMS[*k];
            let mut cols = Vec::new();
            for &(name, width) in term.inputs() {
                let c = columns.get(name).ok_or_else(|| {
                    CoreError::invalid_argument(
                        name,
                        format!(
                            "effect {:?} needs it ({width} per point) but none was given",
                            term.name()
                        ),
                    )
                })?;
                if c.width != width {
                    return Err(CoreError::invalid_argument(
                        name,
                        format!(
                            "effect {:?} needs {width} values per point, got {}",
                            term.name(),
                            c.width
                        ),
                    ));
                }
                cols.push(c.values);
            }
            active.push(Active { term, params, cols });
        }
        Ok(Bound { active })
    }
}

struct Active<'a> {
    term: &'static dyn Term,
    params: &'a [f64],
    cols: Vec<&'a [f64]>,
}

/// Effects with their inputs resolved: the per-point stages.
pub struct Bound<'a> {
    active: Vec<Active<'a>>,
}

impl<'a> Bound<'a> {
    pub fn is_empty(&self) -> bool {
        self.active.is_empty()
    }

    /// The input columns (values, width) that the state stages read:
    /// points that agree on these (and on the reading, temperature and
    /// pose) share one machine state.
    /// The inputs the state stage reads, each with the range its values
    /// must lie in for the block paths (finite; a temperature within a
    /// machine's), beyond which they hand the block to the per-row path.
    pub(crate) fn state_columns(&self) -> Vec<(&'a [f64], usize, (f64, f64))> {
        self.active
            .iter()
            .filter(|a| a.term.state_reads_inputs())
            .flat_map(|a| {
                a.term
                    .inputs()
                    .iter()
                    .zip(&a.cols)
                    .map(|(&(name, width), &values)| {
                        let range = if is_temperature(name) {
                            TEMPERATURE_RANGE_C
                        } else {
                            (-f64::MAX, f64::MAX)
                        };
                        (values, width, range)
                    })
            })
            .collect()
    }

    #[inline(always)]
    fn each(&self, i: usize, mut f: impl FnMut(&dyn Term, &[f64], Row)) {
        for a in &self.active {
            f(a.term, a.params, Row { i, cols: &a.cols });
        }
    }

    #[inline]
    pub fn scanner_forward(&self, i: usize, uv: &mut [f64; 2]) {
        self.each(i, |t, p, r| {
            if t.acts_on_scanner() {
                t.scanner_forward(p, r, uv)
            }
        });
    }

    #[inline]
    pub fn scanner_inverse(&self, i: usize, uv: &mut [f64; 2]) {
        for a in self.active.iter().rev() {
            if a.term.acts_on_scanner() {
                a.term
                    .scanner_inverse(a.params, Row { i, cols: &a.cols }, uv);
            }
        }
    }

    /// [`Bound::scanner_inverse`] over consecutive rows `start..` of `uv`
    /// (N x 2, mm), term by term in the same (reverse) order.
    pub fn scanner_inverse_rows(&self, start: usize, uv: &mut [f64]) {
        for a in self.active.iter().rev() {
            if a.term.acts_on_scanner() {
                a.term.scanner_inverse_rows(a.params, &a.cols, start, uv);
            }
        }
    }

    /// Whether a term switched on has a scanner stage.
    pub fn acts_on_scanner(&self) -> bool {
        self.active.iter().any(|a| a.term.acts_on_scanner())
    }

    #[inline]
    pub fn reading(&self, i: usize, s: &mut [f64; 3]) {
        self.each(i, |t, p, r| t.reading(p, r, s));
    }

    #[inline]
    pub fn temperatures(&self, i: usize, temps: &mut Temperatures) {
        self.each(i, |t, p, r| t.temperatures(p, r, temps));
    }

    #[inline]
    pub fn machine(&self, i: usize, s: [f64; 3], e: &mut MachineErrors) {
        self.each(i, |t, p, r| t.machine(p, r, s, e));
    }

    #[inline]
    pub fn mount(&self, i: usize) -> f64 {
        let mut f = 1.0;
        self.each(i, |t, p, r| f *= t.mount(p, r));
        f
    }
}

/// What the scanner reports for true scan-plane points `uv` (N x 2, mm):
/// the forward scanner stage of `effects`, in parallel. `columns` holds the
/// terms' inputs (e.g. `incidence`, degrees).
pub fn scanner_forward(
    uv: &[f64],
    columns: &Columns,
    effects: &Effects,
    out: &mut [f64],
) -> Result<()> {
    use rayon::prelude::*;
    if uv.len() % 2 != 0 || out.len() != uv.len() {
        return Err(CoreError::invalid_argument(
            "uv",
            format!(
                "expected N x 2 values and an output of the same size, got {} and {}",
                uv.len(),
                out.len()
            ),
        ));
    }
    let n = uv.len() / 2;
    columns.check(n)?;
    let bound = effects.bind(columns)?;
    out.par_chunks_mut(2).enumerate().for_each(|(i, o)| {
        let mut p = [uv[2 * i], uv[2 * i + 1]];
        bound.scanner_forward(i, &mut p);
        o.copy_from_slice(&p);
    });
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn registry_names_are_unique_and_parameters_named() {
        let names = term_names();
        for (k, n) in names.iter().enumerate() {
            assert!(!names[..k].contains(n), "{n} twice");
            assert!(!term(n).unwrap().params().is_empty());
        }
    }

    /// The kernel skips the scanner stage of a term that says it has none,
    /// and shares one machine state across points that differ only in the
    /// inputs of a term whose state stages do not read them: both claims
    /// are checked here for every registered term.
    #[test]
    fn terms_declare_their_scanner_stage_and_state_inputs_truly() {
        let n = 8;
        for t in TERMS {
            let params: Vec<f64> = (0..t.params().len())
                .map(|k| 0.3 + 0.1 * k as f64)
                .collect();
            let a: Vec<Vec<f64>> = t
                .inputs()
                .iter()
                .map(|&(_, w)| (0..n * w).map(|k| 20.0 + k as f64).collect())
                .collect();
            let b: Vec<Vec<f64>> = t
                .inputs()
                .iter()
                .map(|&(_, w)| (0..n * w).map(|k| 35.0 - 2.0 * k as f64).collect())
                .collect();
            let ra: Vec<&[f64]> = a.iter().map(|v| v.as_slice()).collect();
            let rb: Vec<&[f64]> = b.iter().map(|v| v.as_slice()).collect();
            for i in 0..n {
                let (row_a, row_b) = (Row { i, cols: &ra }, Row { i, cols: &rb });
                if !t.acts_on_scanner() {
                    let mut uv = [12.5, 140.25];
                    t.scanner_forward(&params, row_a, &mut uv);
                    t.scanner_inverse(&params, row_a, &mut uv);
                    assert_eq!(uv, [12.5, 140.25], "{} moves (u, v)", t.name());
                    let mut fwd = [12.5, 140.25];
                    t.scanner_forward(&params, row_a, &mut fwd);
                    assert_eq!(fwd, [12.5, 140.25], "{} moves (u, v)", t.name());
                }
                if !t.state_reads_inputs() {
                    let s0 = [100.0, 200.0, -300.0];
                    let (mut sa, mut sb) = (s0, s0);
                    t.reading(&params, row_a, &mut sa);
                    t.reading(&params, row_b, &mut sb);
                    assert_eq!(sa, sb, "{}", t.name());
                    let (mut ta, mut tb) =
                        (Temperatures::uniform(21.0), Temperatures::uniform(21.0));
                    t.temperatures(&params, row_a, &mut ta);
                    t.temperatures(&params, row_b, &mut tb);
                    assert_eq!(
                        (ta.map, ta.squareness),
                        (tb.map, tb.squareness),
                        "{}",
                        t.name()
                    );
                    let e0 = MachineErrors {
                        components: [[1e-3; 6]; 3],
                        squareness: [1e-5; 3],
                    };
                    let (mut ea, mut eb) = (e0, e0);
                    t.machine(&params, row_a, s0, &mut ea);
                    t.machine(&params, row_b, s0, &mut eb);
                    assert_eq!(ea, eb, "{}", t.name());
                    assert_eq!(
                        t.mount(&params, row_a),
                        t.mount(&params, row_b),
                        "{}",
                        t.name()
                    );
                }
            }
        }
    }

    #[test]
    fn unknown_wrong_length_duplicate_and_zero_terms() {
        let e = Effects::new([("nope", vec![1.0])]).unwrap_err().to_string();
        assert!(e.contains("nope") && e.contains("squareness"), "{e}");
        let e = Effects::new([("scale", vec![1.0])])
            .unwrap_err()
            .to_string();
        assert!(e.contains("x, y, z"), "{e}");
        let e = Effects::new([("latency", vec![f64::NAN])])
            .unwrap_err()
            .to_string();
        assert!(e.contains("finite"), "{e}");
        let e = Effects::new([("latency", vec![1.0]), ("latency", vec![2.0])])
            .unwrap_err()
            .to_string();
        assert!(e.contains("twice"), "{e}");
        assert!(Effects::new([("latency", vec![0.0])]).unwrap().is_empty());
    }

    #[test]
    fn missing_input_is_named() {
        let fx = Effects::new([("latency", vec![0.01])]).unwrap();
        let e = fx.bind(&Columns::new()).err().unwrap().to_string();
        assert!(e.contains("velocity") && e.contains("latency"), "{e}");
        let v = [1.0; 2];
        let e = fx
            .bind(&Columns::new().with("velocity", 1, &v))
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("3 values per point"), "{e}");
    }

    #[test]
    fn scanner_inverse_undoes_forward_in_reverse_order() {
        let theta: Vec<f64> = (0..50).map(|i| i as f64 * 1.3).collect();
        let uv: Vec<f64> = (0..100).map(|i| (i as f64 * 0.37).sin() * 25.0).collect();
        let fx = Effects::new([
            ("incidence", vec![2e-4, 3e-5]),
            ("scanner-scale", vec![3e-4, -7e-4]),
        ])
        .unwrap();
        let cols = Columns::new().with("incidence", 1, &theta);
        let mut reported = vec![0.0; 100];
        scanner_forward(&uv, &cols, &fx, &mut reported).unwrap();
        let b = fx.bind(&cols).unwrap();
        for i in 0..50 {
            // Forward: scale first, then incidence on the scaled depth.
            let v2 = uv[2 * i + 1] * (1.0 - 7e-4);
            let want = v2 + 2e-4 * theta[i] + 3e-5 * v2 * theta[i];
            assert!((reported[2 * i + 1] - want).abs() < 1e-12);
            let mut p = [reported[2 * i], reported[2 * i + 1]];
            b.scanner_inverse(i, &mut p);
            assert!((p[0] - uv[2 * i]).abs() < 1e-12 && (p[1] - uv[2 * i + 1]).abs() < 1e-12);
        }
    }
}

/// Whether an input column holds temperatures, C (by the name terms declare).
pub(crate) fn is_temperature(name: &str) -> bool {
    name == "temperature" || name.ends_with("_temperature")
}
