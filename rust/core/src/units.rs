//! The one unit boundary of the core. Maps are given and reported in the
//! metrologist's units (um, arc-seconds, as in the thesis tables); the kernel
//! works in mm and radians. Every conversion goes through these constants.

/// Micrometres to millimetres.
pub const UM_TO_MM: f64 = 1e-3;

/// Arc-seconds to radians (1 a-s = pi / 648000 rad).
pub const ARCSEC_TO_RAD: f64 = std::f64::consts::PI / 648_000.0;

/// The largest length the core takes as millimetres on a machine: a scale
/// reading, a scan-plane coordinate (u, v), a map position. 100 m: the
/// largest CMMs travel some 30 m; beyond, the numbers are not millimetres.
pub const MAX_LENGTH_MM: f64 = 1e5;

/// A map's largest translation component, um (10 cm: no machine is mapped
/// with a larger error; the model file's bound, `cmmpose.schemas`).
pub const MAX_TRANSLATION_UM: f64 = 1e5;

/// A map's largest rotation component or squareness, arc-seconds (one
/// degree; the model file's bound).
pub const MAX_ANGLE_ARCSEC: f64 = 3600.0;

/// The temperatures, C, a map may be labelled with (the model and machine
/// files' range, `cmmpose.schemas.TEMPERATURE_C`).
pub const TEMPERATURE_RANGE_C: (f64, f64) = (-50.0, 150.0);

/// The largest compensated coordinate, mm: a result beyond it comes from
/// inputs no machine gives (its inputs within [`MAX_LENGTH_MM`] and its
/// maps within their bounds keep it well inside). The block paths test
/// their results against it in place of a finiteness test, at the same
/// cost, and hand anything beyond to the per-row path, which names the row.
pub const MAX_RESULT_MM: f64 = 1e6;

/// Whether `x` can be a length on a machine, mm (false for NaN and inf).
#[inline(always)]
pub fn plausible_length(x: f64) -> bool {
    within(x, MAX_LENGTH_MM)
}

/// Whether `t` can be a temperature on a machine, C (false for NaN and inf).
#[inline(always)]
pub fn plausible_temperature(t: f64) -> bool {
    // One comparison about the range's middle (both ends exact in binary):
    // the block paths test every temperature of a block with it.
    const MID: f64 = 0.5 * (TEMPERATURE_RANGE_C.0 + TEMPERATURE_RANGE_C.1);
    const HALF: f64 = 0.5 * (TEMPERATURE_RANGE_C.1 - TEMPERATURE_RANGE_C.0);
    (t - MID).abs() <= HALF
}

/// Whether `x` can be a compensated coordinate, mm (false for NaN and inf).
#[inline(always)]
pub fn plausible_result(x: f64) -> bool {
    within(x, MAX_RESULT_MM)
}

/// |x| <= bound (bound >= 0), false for NaN: compared as the bits of |x|,
/// which order as the magnitudes do (NaN above infinity above any bound).
/// Integer operations, as `is_finite` compiles to: the block paths test
/// every input and result with it, and a floating-point compare there
/// costs a few per cent of the kernel's throughput.
#[inline(always)]
fn within(x: f64, bound: f64) -> bool {
    (x.to_bits() & !(1u64 << 63)) <= bound.to_bits()
}

/// The largest magnitude of component `k` of a carriage table in table
/// units (um for 0..3, arc-second for 3..6).
#[inline]
pub fn component_bound(k: usize) -> f64 {
    if k < 3 {
        MAX_TRANSLATION_UM
    } else {
        MAX_ANGLE_ARCSEC
    }
}

/// Component `k` of a carriage table (0..3 straightness/linear, 3..6 angular)
/// converted from table units (um, arc-second) to kernel units (mm, rad).
#[inline]
pub fn component_to_kernel(k: usize, value: f64) -> f64 {
    if k < 3 {
        value * UM_TO_MM
    } else {
        value * ARCSEC_TO_RAD
    }
}

/// Inverse of [`component_to_kernel`].
#[inline]
pub fn component_from_kernel(k: usize, value: f64) -> f64 {
    if k < 3 {
        value / UM_TO_MM
    } else {
        value / ARCSEC_TO_RAD
    }
}

/// A number for a message: as written below a million, else with an
/// exponent (1e30, not thirty-one digits).
pub fn shown(x: f64) -> String {
    if x.abs() < 1e6 {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}
