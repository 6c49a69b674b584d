//! Blocks of rows in structure-of-arrays form (random readings, see
//! [`crate::blocks`]), and reading one map's tables for a whole block.
//!
//! The block's solve reads one array per component, as vectors across
//! lanes; a table row holds one lane's six components side by side. With
//! AVX (x86-64, checked at run time) four lanes are read at a time, each
//! row's components computed as one four-wide and one two-wide vector and
//! the four lanes transposed in registers into the component arrays;
//! elsewhere row by row into a small scratch, then transposed. Either way
//! the operations on each value are those of [`CarriageTable::at`] (map
//! sets: `thermal::Interval::at`), so the bits are the per-row path's
//! (tests run both ways).

use crate::map::{CarriageTable, ErrorMap};

#[cfg(target_arch = "x86_64")]
pub(crate) use avx::set_rows as set_rows_avx;

/// Whether the four-lane AVX path is taken: on x86-64 CPUs with AVX
/// (the check is one cached load). Tests switch it off per thread to
/// check the portable path against the per-row path too.
#[inline(always)]
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
pub(crate) fn use_avx() -> bool {
    #[cfg(test)]
    if PORTABLE.with(|p| p.get()) {
        return false;
    }
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(test)]
thread_local! {
    /// Set: this thread's lane paths take the portable loops.
    pub(crate) static PORTABLE: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Rows of one structure-of-arrays block (random readings).
pub(crate) const LANES: usize = 64;

/// One block of rows in structure-of-arrays form.
pub(crate) struct Lanes {
    /// Scale readings D, E, F (mm).
    pub(crate) s: [[f64; LANES]; 3],
    /// Per carriage: dx, dy, dz (mm), ex, ey, ez (rad).
    pub(crate) c: [[[f64; LANES]; 6]; 3],
    /// Squareness S_xy, S_yz, S_zx (rad).
    pub(crate) sq: [[f64; LANES]; 3],
    /// E313 . ((u, v, 0) - l1) (mm).
    pub(crate) lever: [[f64; LANES]; 3],
    /// Scratch: one carriage's components lane by lane (six used of eight,
    /// one cache line a lane), before [`Lanes::transpose`].
    pub(crate) rows: [[f64; 8]; LANES],
    /// Scratch: each lane's segment and offset (mm) on the table being read.
    pub(crate) segment: [usize; LANES],
    pub(crate) offset: [f64; LANES],
}

impl Default for Lanes {
    fn default() -> Self {
        Lanes {
            s: [[0.0; LANES]; 3],
            c: [[[0.0; LANES]; 6]; 3],
            sq: [[0.0; LANES]; 3],
            lever: [[0.0; LANES]; 3],
            rows: [[0.0; 8]; LANES],
            segment: [0; LANES],
            offset: [0.0; LANES],
        }
    }
}

impl Lanes {
    /// Lane `r`'s components and squareness.
    #[inline(always)]
    pub(crate) fn set(&mut self, r: usize, c: &[[f64; 6]; 3], sq: [f64; 3]) {
        for a in 0..3 {
            self.sq[a][r] = sq[a];
            for (lane, value) in self.c[a].iter_mut().zip(c[a]) {
                lane[r] = value;
            }
        }
    }

    /// Whether the first `m` readings of carriage `a` lie in `[lo, hi]`
    /// (false for NaN).
    #[inline(always)]
    pub(crate) fn inside(&self, a: usize, m: usize, (lo, hi): (f64, f64)) -> bool {
        let mut inside = true;
        for &x in &self.s[a][..m] {
            inside &= (x >= lo) & (x <= hi);
        }
        inside
    }

    /// Segment and offset of the first `m` lanes' readings of carriage `a`
    /// on `table`, all inside its range (the operations of
    /// `CarriageTable::locate_inside`), into `segment` and `offset`.
    #[inline(always)]
    pub(crate) fn locate(&mut self, a: usize, table: &CarriageTable, m: usize) {
        let x = &self.s[a];
        if let Some((first, inv, last)) = table.uniform_grid() {
            // locate_inside's segment, (x - first) / pitch truncated: every
            // reading is inside, so the quotient is a small non-negative
            // number and a plain truncation gives what `as usize` does.
            for (k, &x) in self.segment.iter_mut().zip(x).take(m) {
                let q = (x - first) * inv;
                debug_assert!((0.0..=(last + 1) as f64 * 1.000_001).contains(&q));
                // SAFETY: q is finite and within [0, last + 1] (see above), far
                // inside i32 (a table has fewer than 2^31 positions); i32 is the
                // width AVX converts four lanes of at once.
                *k = (unsafe { q.to_int_unchecked::<i32>() } as usize).min(last);
            }
        } else {
            for (k, &x) in self.segment.iter_mut().zip(x).take(m) {
                *k = table.locate_inside(x).segment;
            }
        }
        let positions = table.positions();
        let last = positions.len() - 2;
        for ((o, &x), &k) in self.offset.iter_mut().zip(x).zip(&self.segment).take(m) {
            debug_assert!(k <= last);
            // SAFETY: k.min(last) < positions.len() (a table has two or
            // more positions); both branches above give k <= last already,
            // so the min changes nothing. Unchecked, the loop is one vector
            // gather and subtract.
            *o = x - unsafe { *positions.get_unchecked(k.min(last)) };
        }
        self.pad(m);
    }

    /// The lanes from `m` up to the next multiple of four (read, never
    /// used, by the four-lane path) on the first segment.
    #[inline(always)]
    pub(crate) fn pad(&mut self, m: usize) {
        let m4 = m.next_multiple_of(4).min(LANES);
        self.segment[m..m4].fill(0);
        self.offset[m..m4].fill(0.0);
    }

    /// The scratch rows of the first `m` lanes into carriage `a`'s
    /// component arrays.
    #[inline(always)]
    pub(crate) fn transpose(&mut self, a: usize, m: usize) {
        let c = &mut self.c[a];
        for (k, lane) in c.iter_mut().enumerate() {
            for (value, row) in lane.iter_mut().zip(&self.rows).take(m) {
                *value = row[k];
            }
        }
    }
}

/// The components of one map for the first `m` lanes, table by table:
/// locate every lane's reading, then interpolate (the operations of
/// `CarriageTable::locate` and `at`). `None` if a reading is outside its
/// table.
#[inline(always)]
pub(crate) fn map_lanes(map: &ErrorMap, lanes: &mut Lanes, m: usize) -> Option<()> {
    for (a, table) in map.tables().iter().enumerate() {
        if !lanes.inside(a, m, table.range()) {
            return None;
        }
        lanes.locate(a, table, m);
        let (values, slopes) = (table.values(), table.slopes());
        #[cfg(target_arch = "x86_64")]
        if use_avx() {
            // SAFETY: the CPU has AVX (checked above); every lane below
            // the next multiple of four holds a segment of this table.
            unsafe { avx::map_rows(values, slopes, lanes, a, m) };
            continue;
        }
        for ((row, &k), &x) in lanes
            .rows
            .iter_mut()
            .zip(&lanes.segment)
            .zip(&lanes.offset)
            .take(m)
        {
            // Every load before the first store, so that the six are
            // loaded, computed and stored as vectors.
            let (v, s) = (values[k], slopes[k]);
            let c: [f64; 6] = std::array::from_fn(|j| v[j] + x * s[j]);
            row[..6].copy_from_slice(&c);
        }
        lanes.transpose(a, m);
    }
    let sq = map.squareness();
    for (lane, value) in lanes.sq.iter_mut().zip(sq) {
        lane[..m].fill(value);
    }
    Some(())
}

/// Four lanes at a time with AVX: each lane's six components computed as
/// one four-wide and one two-wide vector (the same operations as the
/// scalar formulas, in the same order), then four lanes transposed in
/// registers straight into the component arrays (no scratch rows).
#[cfg(target_arch = "x86_64")]
mod avx {
    use std::arch::x86_64::*;

    use super::{Lanes, LANES};
    use crate::map::Components;

    /// Four lanes' components (lane j: `lo[j]` = c0..c3, `hi[j]` = c4, c5)
    /// into `c[k][r..r + 4]`.
    #[inline]
    #[target_feature(enable = "avx")]
    unsafe fn store4(c: &mut [[f64; LANES]; 6], r: usize, lo: [__m256d; 4], hi: [__m128d; 4]) {
        let t0 = _mm256_unpacklo_pd(lo[0], lo[1]);
        let t1 = _mm256_unpackhi_pd(lo[0], lo[1]);
        let t2 = _mm256_unpacklo_pd(lo[2], lo[3]);
        let t3 = _mm256_unpackhi_pd(lo[2], lo[3]);
        let u0 = _mm_unpacklo_pd(hi[0], hi[1]);
        let u1 = _mm_unpackhi_pd(hi[0], hi[1]);
        let u2 = _mm_unpacklo_pd(hi[2], hi[3]);
        let u3 = _mm_unpackhi_pd(hi[2], hi[3]);
        let out = [
            _mm256_permute2f128_pd::<0x20>(t0, t2),
            _mm256_permute2f128_pd::<0x20>(t1, t3),
            _mm256_permute2f128_pd::<0x31>(t0, t2),
            _mm256_permute2f128_pd::<0x31>(t1, t3),
            _mm256_set_m128d(u2, u0),
            _mm256_set_m128d(u3, u1),
        ];
        for (lane, v) in c.iter_mut().zip(out) {
            _mm256_storeu_pd(lane[r..r + 4].as_mut_ptr(), v);
        }
    }

    /// One map's table of carriage `a`: v + x s per component
    /// (`CarriageTable::at`), lanes `0..m` rounded up to four (the padding
    /// lanes on a valid segment, see [`Lanes::pad`]).
    ///
    /// # Safety
    /// The CPU must have AVX.
    #[target_feature(enable = "avx")]
    pub(crate) unsafe fn map_rows(
        values: &[Components],
        slopes: &[Components],
        lanes: &mut Lanes,
        a: usize,
        m: usize,
    ) {
        let mut r = 0;
        while r < m {
            let mut lo = [_mm256_setzero_pd(); 4];
            let mut hi = [_mm_setzero_pd(); 4];
            for j in 0..4 {
                let k = lanes.segment[r + j];
                debug_assert!(k < values.len() && k < slopes.len());
                // SAFETY: `Lanes::locate` gives segments below the table's
                // last position and `Lanes::pad` segment 0 (a table has two
                // or more positions and one row of slopes fewer): unchecked,
                // the four lanes' loads carry no compare and branch each.
                let (v, s) = (values.get_unchecked(k), slopes.get_unchecked(k));
                let x = _mm256_set1_pd(lanes.offset[r + j]);
                // SAFETY: v and s are six values each: [0, 4) and [4, 6).
                lo[j] = _mm256_add_pd(
                    _mm256_loadu_pd(v.as_ptr()),
                    _mm256_mul_pd(x, _mm256_loadu_pd(s.as_ptr())),
                );
                hi[j] = _mm_add_pd(
                    _mm_loadu_pd(v.as_ptr().add(4)),
                    _mm_mul_pd(_mm256_castpd256_pd128(x), _mm_loadu_pd(s.as_ptr().add(4))),
                );
            }
            store4(&mut lanes.c[a], r, lo, hi);
            r += 4;
        }
    }

    /// A map set's packed rows of carriage `a` (`row(r)`: lane `r`'s
    /// segment row, 24 values as `thermal::Interval` packs them) at `dt[r]`
    /// C: (b + x b') + dt (s + x s') per component, as
    /// `Interval::at`, lanes `0..m` rounded up to four.
    ///
    /// # Safety
    /// The CPU must have AVX.
    #[target_feature(enable = "avx")]
    pub(crate) unsafe fn set_rows<'r>(
        row: impl Fn(usize) -> &'r [f64; 24],
        dt: &[f64; LANES],
        lanes: &mut Lanes,
        a: usize,
        m: usize,
    ) {
        let mut r = 0;
        while r < m {
            let mut lo = [_mm256_setzero_pd(); 4];
            let mut hi = [_mm_setzero_pd(); 4];
            for j in 0..4 {
                let p = row(r + j).as_ptr();
                let x = _mm256_set1_pd(lanes.offset[r + j]);
                let d = _mm256_set1_pd(dt[r + j]);
                let (x2, d2) = (_mm256_castpd256_pd128(x), _mm256_castpd256_pd128(d));
                // SAFETY: p points at 24 values; offsets 0..22 + 2 or 4.
                macro_rules! ld {
                    ($k:expr) => {
                        _mm256_loadu_pd(p.add($k))
                    };
                }
                macro_rules! ld2 {
                    ($k:expr) => {
                        _mm_loadu_pd(p.add($k))
                    };
                }
                lo[j] = _mm256_add_pd(
                    _mm256_add_pd(ld!(0), _mm256_mul_pd(x, ld!(6))),
                    _mm256_mul_pd(d, _mm256_add_pd(ld!(12), _mm256_mul_pd(x, ld!(18)))),
                );
                hi[j] = _mm_add_pd(
                    _mm_add_pd(ld2!(4), _mm_mul_pd(x2, ld2!(10))),
                    _mm_mul_pd(d2, _mm_add_pd(ld2!(16), _mm_mul_pd(x2, ld2!(22)))),
                );
            }
            store4(&mut lanes.c[a], r, lo, hi);
            r += 4;
        }
    }
}
