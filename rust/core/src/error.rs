//! One error enum for the whole core; the bindings map each variant to one
//! Python exception (polars' shape). Messages name the row, carriage or
//! argument at fault so a user can find it in their data; they say what is
//! wrong, never which option of an interface changes it (the bindings add
//! that from the variant's fields).

use thiserror::Error;

/// Everything that can go wrong in the core.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CoreError {
    /// An error map (or one of its tables) is malformed.
    #[error("{location}: {reason}")]
    InvalidMap { location: String, reason: String },

    /// A scale reading lies outside the map's table for that carriage.
    #[error(
        "row {row}: {axis} scale reading {value} mm is outside the {axis} map range \
         [{lo}, {hi}] mm"
    )]
    PositionOutOfRange {
        row: usize,
        axis: char,
        value: f64,
        lo: f64,
        hi: f64,
    },

    /// A temperature lies outside the temperatures covered by a map set.
    #[error(
        "{}temperature {value} C is {:.3} K outside the maps' range [{lo}, {hi}] C, \
         more than the {tolerance} K tolerance",
        row.map(|r| format!("row {r}: ")).unwrap_or_default(),
        if *value < *lo { lo - value } else { value - hi }
    )]
    TemperatureOutOfRange {
        row: Option<usize>,
        value: f64,
        lo: f64,
        hi: f64,
        /// K beyond the range within which a temperature is held at the edge.
        tolerance: f64,
    },

    /// NaN or infinity in an input array. (The bindings add how to let
    /// such rows through, in each interface's words.)
    #[error("{argument}: non-finite value (NaN or inf) in row {row}")]
    NonFinite { argument: String, row: usize },

    /// A number no machine gives: a length beyond
    /// [`crate::units::MAX_LENGTH_MM`], a temperature outside
    /// [`crate::units::TEMPERATURE_RANGE_C`]; refused whatever the NaN or
    /// range policy.
    #[error(
        "{argument}: row {row}: {} {} is {}: not {} on a machine",
        crate::units::shown(*value),
        quantity.unit(),
        quantity.bound(),
        quantity.words()
    )]
    Implausible {
        argument: String,
        row: usize,
        value: f64,
        quantity: Quantity,
    },

    /// NaN or infinity given for one scalar argument.
    #[error("{argument}: {value} {unit} is not finite")]
    NotFinite {
        argument: String,
        value: f64,
        unit: &'static str,
    },

    /// An argument with the wrong shape, length or value.
    #[error("{argument}: {reason}")]
    InvalidArgument { argument: String, reason: String },

    /// Geometry that admits no unique answer (zero normal, coplanar points, ...).
    #[error("{0}")]
    Degenerate(String),
}

pub type Result<T> = std::result::Result<T, CoreError>;

/// What an implausible input was taken as (its unit and bounds). A small
/// enum, so the error stays as small as its other variants: results pass
/// through the kernel's hot loops.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quantity {
    /// A length on a machine, mm.
    Length,
    /// A temperature on a machine, C.
    Temperature,
}

impl Quantity {
    pub fn unit(self) -> &'static str {
        match self {
            Quantity::Length => "mm",
            Quantity::Temperature => "C",
        }
    }

    /// The bound, in words ("beyond +-100000 mm").
    pub fn bound(self) -> String {
        match self {
            Quantity::Length => format!("beyond +-{} mm", crate::units::MAX_LENGTH_MM),
            Quantity::Temperature => {
                let (lo, hi) = crate::units::TEMPERATURE_RANGE_C;
                format!("outside {lo} to {hi} C")
            }
        }
    }

    /// What a number beyond the bound is not.
    pub fn words(self) -> &'static str {
        match self {
            Quantity::Length => "millimetres",
            Quantity::Temperature => "degrees C",
        }
    }
}

impl CoreError {
    pub(crate) fn invalid_map(location: impl Into<String>, reason: impl Into<String>) -> Self {
        CoreError::InvalidMap {
            location: location.into(),
            reason: reason.into(),
        }
    }

    pub(crate) fn invalid_argument(argument: impl Into<String>, reason: impl Into<String>) -> Self {
        CoreError::InvalidArgument {
            argument: argument.into(),
            reason: reason.into(),
        }
    }
}
