//! The compensation's memory traffic without its arithmetic: what the
//! machine can stream through the same arrays (read u, v, D, E, F and a
//! temperature per point, write X, Y, Z). Benches print the kernel's speed
//! as a fraction of this limit, measured in the same run.

use rayon::prelude::*;

use crate::error::{CoreError, Result};

/// Points per parallel work item, as in the kernel.
const CHUNK: usize = 4096;

/// `out = scales + (u, v, u) + t` row by row (N x 3), in parallel chunks:
/// one add per value written, so the time is the memory's.
pub fn streaming_reference(
    uv: &[f64],
    scales: &[f64],
    temperature: Option<&[f64]>,
    out: &mut [f64],
) -> Result<()> {
    let n = scales.len() / 3;
    if scales.len() != 3 * n || uv.len() != 2 * n || out.len() != 3 * n {
        return Err(CoreError::invalid_argument(
            "uv/scales/out",
            format!(
                "expected N x 2, N x 3 and N x 3 values, got {}, {} and {}",
                uv.len(),
                scales.len(),
                out.len()
            ),
        ));
    }
    if let Some(t) = temperature {
        if t.len() != n {
            return Err(CoreError::invalid_argument(
                "temperature",
                format!("has {} values but scales has {n} rows", t.len()),
            ));
        }
    }
    out.par_chunks_mut(3 * CHUNK)
        .enumerate()
        .for_each(|(c, block)| {
            let first = c * CHUNK;
            for (r, o) in block.chunks_exact_mut(3).enumerate() {
                let i = first + r;
                let t = temperature.map_or(0.0, |t| t[i]);
                let (u, v) = (uv[2 * i], uv[2 * i + 1]);
                o[0] = scales[3 * i] + u + t;
                o[1] = scales[3 * i + 1] + v + t;
                o[2] = scales[3 * i + 2] + u + t;
            }
        });
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adds_row_by_row_and_checks_lengths() {
        let uv = [1.0, 2.0, 3.0, 4.0];
        let s = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0];
        let mut out = [0.0; 6];
        streaming_reference(&uv, &s, Some(&[0.5, 0.25]), &mut out).unwrap();
        assert_eq!(out, [11.5, 22.5, 31.5, 43.25, 54.25, 63.25]);
        assert!(streaming_reference(&uv, &s[..3], None, &mut out).is_err());
        assert!(streaming_reference(&uv, &s, Some(&[1.0]), &mut out).is_err());
    }
}
