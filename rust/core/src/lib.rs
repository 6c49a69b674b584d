//! cmmpose-core: geometric and quasi-static thermal error compensation of a
//! laser line scanner (digitizer) on a coordinate measuring machine, after
//! J. O. Harris's PhD thesis (McMaster University). Pure Rust, no Python.
//!
//! Units: scale readings, positions and results in mm; map tables in um and
//! arc-seconds at the API boundary ([`units`]), mm and rad inside.

pub mod artefact;
mod blocks;
pub mod effects;
pub mod error;
pub mod fit;
pub mod kernel;
pub mod kinematics;
mod lanes;
pub mod map;
pub mod pose;
pub mod scanner;
mod source;
pub mod stream;
#[cfg(test)]
mod test_maps;
pub mod thermal;
pub mod truth;
pub mod uncertainty;
pub mod units;

pub use effects::{Columns, Effects};
pub use error::{CoreError, Result};
pub use kernel::{MapSource, NanPolicy, Options, OutOfRange, PointError, Points, Report};
pub use kinematics::{Kinematics, Side};
pub use map::{Carriage, CarriageTable, ErrorMap};
pub use pose::{Digitizer, Pose};
pub use thermal::ErrorMapSet;

/// Threads the parallel kernels use (rayon's global pool).
pub fn thread_count() -> usize {
    rayon::current_num_threads()
}
