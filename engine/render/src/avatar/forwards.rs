//! How a frame's sampled rays become field forwards. The host samples the frame in
//! chunks of rays (in parallel); the forwards then take those samples in runs of
//! consecutive rays of at most a cap of samples each: a chunk over the cap is halved by
//! its rays until each part fits (or is one ray), and on a GPU consecutive parts are
//! joined while they fit together, since there every forward costs a hundred-odd kernel
//! launches whatever its size.

use std::ops::Range;

use talkin_grids::PackedSamples;

/// One field forward: consecutive rays of the frame and their samples.
#[derive(Debug)]
pub(crate) struct Forward {
    pub rays: Range<usize>,
    pub samples: PackedSamples,
}

/// The forwards of `chunks` (each a range of the frame's rays, in order, and its
/// samples): halved to at most `max_samples` samples (a single ray may exceed it) and,
/// with `join`, consecutive ones joined up to it.
pub(crate) fn plan_forwards(
    chunks: Vec<(Range<usize>, PackedSamples)>,
    max_samples: usize,
    join: bool,
) -> Vec<Forward> {
    let mut parts = Vec::new();
    for (rays, samples) in chunks {
        halve_into(rays, samples, max_samples, &mut parts);
    }
    if !join {
        return parts;
    }
    let mut joined: Vec<Forward> = Vec::with_capacity(parts.len());
    for part in parts {
        match joined.last_mut() {
            Some(last)
                if last.rays.end == part.rays.start
                    && last.samples.num_samples() + part.samples.num_samples() <= max_samples =>
            {
                last.rays.end = part.rays.end;
                last.samples.append(part.samples);
            }
            _ => joined.push(part),
        }
    }
    joined
}

/// `samples` of `rays`, halved by rays while over `max_samples` and longer than a ray.
fn halve_into(
    rays: Range<usize>,
    samples: PackedSamples,
    max_samples: usize,
    out: &mut Vec<Forward>,
) {
    if samples.num_samples() <= max_samples || rays.len() <= 1 {
        out.push(Forward { rays, samples });
        return;
    }
    let k = rays.len() / 2;
    let (head, tail) = samples.split_at_ray(k);
    let mid = rays.start + k;
    halve_into(rays.start..mid, head, max_samples, out);
    halve_into(mid..rays.end, tail, max_samples, out);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `counts[i]` samples on ray `i`.
    fn packed(counts: &[u32]) -> PackedSamples {
        let mut p = PackedSamples {
            ray_offsets: vec![0],
            ..Default::default()
        };
        for &c in counts {
            for s in 0..c {
                p.t_start.push(s as f32);
                p.t_end.push(s as f32 + 0.5);
                p.part_mask.push(1);
                p.bone_mask.push(u64::from(c));
            }
            p.ray_offsets.push(p.t_start.len() as u32);
        }
        p
    }

    /// The frame's rays `counts` in chunks of `chunk` rays.
    fn chunks(counts: &[u32], chunk: usize) -> Vec<(Range<usize>, PackedSamples)> {
        counts
            .chunks(chunk)
            .enumerate()
            .map(|(i, c)| (i * chunk..i * chunk + c.len(), packed(c)))
            .collect()
    }

    /// The forwards cover every ray once, in order, with the frame's samples.
    fn assert_covers(forwards: &[Forward], counts: &[u32]) {
        let mut next = 0;
        let mut all = PackedSamples::default();
        for f in forwards {
            assert_eq!(f.rays.start, next);
            assert_eq!(f.samples.num_rays(), f.rays.len());
            next = f.rays.end;
            all.append(f.samples.clone());
        }
        assert_eq!(next, counts.len());
        assert_eq!(all, packed(counts));
    }

    #[test]
    fn halving_bounds_each_forward_and_a_lone_ray_may_exceed_it() {
        let counts = [3, 0, 5, 2, 9, 1, 0, 0, 4, 4];
        let forwards = plan_forwards(chunks(&counts, 4), 6, false);
        assert_covers(&forwards, &counts);
        for f in &forwards {
            assert!(f.samples.num_samples() <= 6 || f.rays.len() == 1, "{f:?}");
        }
        // Without joining, no forward spans two chunks.
        assert!(
            forwards
                .iter()
                .all(|f| f.rays.start / 4 == (f.rays.end - 1) / 4)
        );
    }

    #[test]
    fn joining_fills_forwards_up_to_the_cap_across_chunks() {
        let counts: Vec<u32> = (0..40).map(|i| (i % 3) as u32).collect();
        let separate = plan_forwards(chunks(&counts, 4), 12, false);
        let joined = plan_forwards(chunks(&counts, 4), 12, true);
        assert_covers(&joined, &counts);
        assert!(joined.len() < separate.len());
        assert!(joined.iter().all(|f| f.samples.num_samples() <= 12));
        // Greedy: no two neighbours would fit together.
        for w in joined.windows(2) {
            assert!(w[0].samples.num_samples() + w[1].samples.num_samples() > 12);
        }
        // A cap above the frame's samples makes one forward.
        let one = plan_forwards(chunks(&counts, 4), 1000, true);
        assert_eq!(one.len(), 1);
        assert_covers(&one, &counts);
    }
}
