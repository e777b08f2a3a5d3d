//! Parallel production of packed (ragged) per-ray output without per-ray allocation:
//! rays are cut into chunks, each chunk appends into one buffer, chunks are concatenated.

use rayon::prelude::*;

/// Rays per rayon task: large enough to amortise the task, small enough to balance.
const CHUNK: usize = 128;

/// Runs `f(scratch, ray_index, out)` for every ray in parallel, where `f` appends that
/// ray's items to `out`. Returns the per-ray offsets (`n + 1` entries) and all items,
/// ray after ray. `init` makes one scratch per worker.
pub(crate) fn par_pack<S, T, I, F>(n: usize, init: I, f: F) -> (Vec<u32>, Vec<T>)
where
    T: Send,
    I: Fn() -> S + Sync + Send,
    F: Fn(&mut S, usize, &mut Vec<T>) + Sync + Send,
{
    let chunks: Vec<(Vec<u32>, Vec<T>)> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map_init(&init, |scratch, chunk| {
            let rays = chunk * CHUNK..n.min((chunk + 1) * CHUNK);
            let mut counts = Vec::with_capacity(rays.len());
            let mut items = Vec::new();
            for i in rays {
                let before = items.len();
                f(scratch, i, &mut items);
                counts.push((items.len() - before) as u32);
            }
            (counts, items)
        })
        .collect();
    let total: usize = chunks.iter().map(|(_, items)| items.len()).sum();
    assert!(
        total <= u32::MAX as usize,
        "more than 2^32 packed items: offsets are u32"
    );
    let mut offsets = Vec::with_capacity(n + 1);
    let mut all = Vec::with_capacity(total);
    let mut running = 0u32;
    offsets.push(0);
    for (counts, items) in chunks {
        for c in counts {
            running += c;
            offsets.push(running);
        }
        all.extend(items);
    }
    (offsets, all)
}
