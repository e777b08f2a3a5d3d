//! Parallel production of packed (ragged) per-ray output without per-ray allocation:
//! rays are cut into chunks, each chunk appends into its own buffer, chunks are
//! concatenated.

use rayon::prelude::*;

use crate::samples::{PackedSamples, Sample};

/// Rays per rayon task: large enough to amortise the task, small enough to balance.
pub(crate) const CHUNK: usize = 128;

/// A chunk's output buffer.
pub(crate) trait ChunkBuffer: Default + Send {
    fn len(&self) -> usize;

    /// An empty buffer for a chunk of `rays` rays.
    fn for_rays(_rays: usize) -> Self {
        Self::default()
    }
}

impl<T: Send> ChunkBuffer for Vec<T> {
    fn len(&self) -> usize {
        Vec::len(self)
    }
}

/// Runs `f(scratch, ray_index, out)` for every ray in parallel, where `f` appends that
/// ray's items to `out`. Returns the per-ray offsets (`n + 1` entries) and the chunks'
/// buffers in ray order. `init` makes one scratch per worker.
fn par_chunks<S, B, I, F>(n: usize, init: I, f: F) -> (Vec<u32>, Vec<B>)
where
    B: ChunkBuffer,
    I: Fn() -> S + Sync + Send,
    F: Fn(&mut S, usize, &mut B) + Sync + Send,
{
    let chunks: Vec<(Vec<u32>, B)> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map_init(&init, |scratch, chunk| {
            let rays = chunk * CHUNK..n.min((chunk + 1) * CHUNK);
            let mut counts = Vec::with_capacity(rays.len());
            let mut items = B::for_rays(rays.len());
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
    let mut running = 0u32;
    offsets.push(0);
    let mut buffers = Vec::with_capacity(chunks.len());
    for (counts, items) in chunks {
        for c in counts {
            running += c;
            offsets.push(running);
        }
        buffers.push(items);
    }
    (offsets, buffers)
}

/// [`par_chunks`] with items in one vector.
pub(crate) fn par_pack<S, T, I, F>(n: usize, init: I, f: F) -> (Vec<u32>, Vec<T>)
where
    T: Send,
    I: Fn() -> S + Sync + Send,
    F: Fn(&mut S, usize, &mut Vec<T>) + Sync + Send,
{
    let (offsets, chunks) = par_chunks(n, init, f);
    let mut all = Vec::with_capacity(*offsets.last().unwrap_or(&0) as usize);
    for items in chunks {
        all.extend(items);
    }
    (offsets, all)
}

/// Samples as they are produced: one vector per field, so they are packed with copies
/// of plain arrays and never regrouped.
#[derive(Default)]
pub(crate) struct SampleColumns {
    t_start: Vec<f32>,
    t_end: Vec<f32>,
    part_mask: Vec<u8>,
    bone_mask: Vec<u64>,
}

impl SampleColumns {
    #[inline]
    pub(crate) fn push(&mut self, s: Sample) {
        self.t_start.push(s.t_start);
        self.t_end.push(s.t_end);
        self.part_mask.push(s.part_mask);
        self.bone_mask.push(s.bone_mask);
    }
}

/// Room reserved per ray in a chunk's sample buffer: the accelerated samplers produce
/// ~30 a ray, so most chunks never grow their buffers.
const SAMPLES_PER_RAY_RESERVED: usize = 40;

impl ChunkBuffer for SampleColumns {
    fn len(&self) -> usize {
        self.t_start.len()
    }

    fn for_rays(rays: usize) -> Self {
        let n = rays * SAMPLES_PER_RAY_RESERVED;
        SampleColumns {
            t_start: Vec::with_capacity(n),
            t_end: Vec::with_capacity(n),
            part_mask: Vec::with_capacity(n),
            bone_mask: Vec::with_capacity(n),
        }
    }
}

/// [`par_chunks`] for samples: the chunks are copied into the packed arrays in parallel.
pub(crate) fn par_pack_samples<S, I, F>(n: usize, init: I, f: F) -> PackedSamples
where
    I: Fn() -> S + Sync + Send,
    F: Fn(&mut S, usize, &mut SampleColumns) + Sync + Send,
{
    let (ray_offsets, chunks) = par_chunks(n, init, f);
    let total = *ray_offsets.last().unwrap_or(&0) as usize;
    let mut out = PackedSamples {
        ray_offsets,
        t_start: vec![0.0; total],
        t_end: vec![0.0; total],
        part_mask: vec![0; total],
        bone_mask: vec![0; total],
    };
    let mut pieces = Vec::with_capacity(chunks.len());
    let (mut t_start, mut t_end) = (&mut out.t_start[..], &mut out.t_end[..]);
    let (mut part_mask, mut bone_mask) = (&mut out.part_mask[..], &mut out.bone_mask[..]);
    for chunk in &chunks {
        let k = chunk.len();
        let (a, rest_a) = std::mem::take(&mut t_start).split_at_mut(k);
        let (b, rest_b) = std::mem::take(&mut t_end).split_at_mut(k);
        let (c, rest_c) = std::mem::take(&mut part_mask).split_at_mut(k);
        let (d, rest_d) = std::mem::take(&mut bone_mask).split_at_mut(k);
        (t_start, t_end, part_mask, bone_mask) = (rest_a, rest_b, rest_c, rest_d);
        pieces.push((chunk, a, b, c, d));
    }
    pieces.into_par_iter().for_each(|(chunk, a, b, c, d)| {
        a.copy_from_slice(&chunk.t_start);
        b.copy_from_slice(&chunk.t_end);
        c.copy_from_slice(&chunk.part_mask);
        d.copy_from_slice(&chunk.bone_mask);
    });
    out
}
