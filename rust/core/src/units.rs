//! The one unit boundary of the core. Maps are given and reported in the
//! metrologist's units (um, arc-seconds, as in the thesis tables); the kernel
//! works in mm and radians. Every conversion goes through these constants.

/// Micrometres to millimetres.
pub const UM_TO_MM: f64 = 1e-3;

/// Arc-seconds to radians (1 a-s = pi / 648000 rad).
pub const ARCSEC_TO_RAD: f64 = std::f64::consts::PI / 648_000.0;

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
