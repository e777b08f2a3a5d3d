//! The machine's own ceilings, measured in the step bench's run on every core rayon has:
//! Flex's matrix product (compute), random reads of a hash table's rows (gathers) and a
//! streamed read (memory bandwidth). Each is the best of a few repetitions.

use std::time::Instant;

use burn::prelude::*;
use rayon::prelude::*;
use serde::Serialize;
use talkin_nets::Device;

/// Repetitions of each probe (the best counts).
const REPEATS: usize = 3;
/// Rows of the matrix product `[M, 256] x [256, 256]`.
const GEMM_ROWS: usize = 16_384;
/// Floats the stream probe reads (256 MiB).
const STREAM_FLOATS: usize = 1 << 26;
/// Random rows the gather probe reads.
const GATHERS: usize = 1 << 23;
/// Gathers a parallel task does.
const GATHER_CHUNK: usize = 1 << 14;

/// What this machine does at best.
///
/// The gather probe reads a hash encoding's pattern: per lookup 8 rows of two floats at
/// 4 random places of one level's table (a cell's x-neighbours are adjacent rows, one
/// cache line), so its ceiling is the fine levels' rows as the encoding reads them.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Peaks {
    /// rayon's threads (the cores the probes ran on).
    pub threads: usize,
    /// Flex's `[16384, 256] x [256, 256]` product, GFLOP/s.
    pub matmul_gflops: f64,
    /// Random two-float (8-byte) rows, in adjacent pairs, of a table as large as one
    /// hashed level's: GB/s of the rows' bytes.
    pub gather_gbs: f64,
    /// The table the gather probe read (one level of the field's hash grid), MiB.
    pub gather_table_mib: f64,
    /// A 256 MiB array read and summed, GB/s.
    pub stream_gbs: f64,
}

/// Measures the three probes; `table_floats`: the floats of one hashed level of the
/// field's grid.
pub fn measure(table_floats: usize) -> Peaks {
    measure_sized(table_floats, GEMM_ROWS, GATHERS, STREAM_FLOATS)
}

fn measure_sized(table_floats: usize, gemm_rows: usize, gathers: usize, stream: usize) -> Peaks {
    let table_floats = table_floats.max(1 << 16) & !1;
    Peaks {
        threads: rayon::current_num_threads(),
        matmul_gflops: matmul_gflops(gemm_rows),
        gather_gbs: gather_gbs(table_floats, gathers),
        gather_table_mib: table_floats as f64 * 4.0 / (1024.0 * 1024.0),
        stream_gbs: stream_gbs(stream),
    }
}

fn best_seconds(mut f: impl FnMut()) -> f64 {
    f(); // warm: page faults, caches
    (0..REPEATS)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
        .max(1e-12)
}

fn matmul_gflops(rows: usize) -> f64 {
    let device = Device::flex();
    let a = Tensor::<2>::ones([rows, 256], &device).mul_scalar(0.5);
    let b = Tensor::<2>::ones([256, 256], &device).mul_scalar(0.25);
    let seconds = best_seconds(|| {
        let _ = a.clone().matmul(b.clone()).into_data();
    });
    2.0 * rows as f64 * 256.0 * 256.0 / seconds / 1e9
}

/// Random rows drawn by xorshift inside the loop (no index array to stream).
fn gather_gbs(table_floats: usize, gathers: usize) -> f64 {
    let table: Vec<f32> = (0..table_floats).map(|i| (i % 7) as f32).collect();
    let rows = (table_floats / 2) as u64;
    let mut sink = 0.0f32;
    let seconds = best_seconds(|| {
        sink += (0..gathers.div_ceil(GATHER_CHUNK))
            .into_par_iter()
            .map(|chunk| {
                let mut state = 0x9E37_79B9_7F4A_7C15u64 ^ (chunk as u64 + 1);
                let mut sum = 0.0f32;
                // Two rows (16 bytes) at each of 4 places: 8 rows a lookup.
                for _ in 0..GATHER_CHUNK / 2 {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    // A row pair below `rows - 1`, by a multiply (no division).
                    let row = (((state >> 32) * (rows - 1)) >> 32) as usize * 2;
                    sum += table[row] + table[row + 1] + table[row + 2] + table[row + 3];
                }
                sum
            })
            .sum::<f32>();
    });
    std::hint::black_box(sink);
    gathers.div_ceil(GATHER_CHUNK) as f64 * GATHER_CHUNK as f64 * 8.0 / seconds / 1e9
}

fn stream_gbs(floats: usize) -> f64 {
    let data: Vec<f32> = (0..floats).map(|i| (i & 3) as f32).collect();
    let mut sink = 0.0f32;
    let seconds = best_seconds(|| {
        sink += data.par_chunks(1 << 16).map(lanes_sum).sum::<f32>();
    });
    std::hint::black_box(sink);
    floats as f64 * 4.0 / seconds / 1e9
}

/// A sum in 16 independent lanes (one running sum would wait on each add, not memory).
fn lanes_sum(values: &[f32]) -> f32 {
    let mut lanes = [0f32; 16];
    let mut chunks = values.chunks_exact(16);
    for c in &mut chunks {
        for (l, v) in lanes.iter_mut().zip(c) {
            *l += v;
        }
    }
    lanes.iter().sum::<f32>() + chunks.remainder().iter().sum::<f32>()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_probes_measure_positive_finite_rates() {
        let p = measure_sized(1 << 16, 256, 1 << 15, 1 << 18);
        for rate in [p.matmul_gflops, p.gather_gbs, p.stream_gbs] {
            assert!(rate.is_finite() && rate > 0.0, "{p:?}");
        }
        assert!(p.threads >= 1);
    }

    #[test]
    fn the_lanes_sum_every_value() {
        let v: Vec<f32> = (0..37).map(|i| i as f32).collect();
        assert_eq!(lanes_sum(&v), 666.0);
    }
}
