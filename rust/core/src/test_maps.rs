//! What the kernel's unit tests share: maps from a function of position and
//! deterministic points inside the thesis machine's volume.

use crate::map::{Carriage, CarriageTable, ErrorMap};

/// The thesis machine's travel per axis, mm.
pub(crate) const RANGES: [(f64, f64); 3] = [(0.0, 900.0), (0.0, 550.0), (-500.0, 0.0)];

/// A map with table rows given by `f(carriage, position) -> 6 components`
/// in table units (um, arc-second) on a 25 mm grid.
pub(crate) fn map_from(
    f: impl Fn(usize, f64) -> [f64; 6],
    squareness: [f64; 3],
    t: Option<f64>,
) -> ErrorMap {
    let tables = std::array::from_fn(|a| {
        let (lo, hi) = RANGES[a];
        let rows: Vec<[f64; 7]> = (0..=((hi - lo) / 25.0) as usize)
            .map(|i| {
                let p = lo + 25.0 * i as f64;
                let c = f(a, p);
                [p, c[0], c[1], c[2], c[3], c[4], c[5]]
            })
            .collect();
        CarriageTable::from_table_units(Carriage::ALL[a], &rows).unwrap()
    });
    ErrorMap::new(tables, squareness, t).unwrap()
}

/// Deterministic pseudo-random points inside the volume.
pub(crate) fn points(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut state = 0x2545F4914F6CDD1Du64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut uv = Vec::with_capacity(2 * n);
    let mut s = Vec::with_capacity(3 * n);
    for _ in 0..n {
        uv.push(-30.0 + 60.0 * next());
        uv.push(110.0 + 60.0 * next());
        for (lo, hi) in RANGES {
            s.push(lo + (hi - lo) * next());
        }
    }
    (uv, s)
}
