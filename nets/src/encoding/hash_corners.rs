//! The hash grid's cell corners and table rows as int tensor ops on the points' device,
//! for backends without the fused op: a GPU computes them where the points are, with no
//! readback in the middle of a forward.
//!
//! The same indexing as `hash_grid::vertex_row`, in i32 arithmetic that never overflows
//! (GPU ints are 32-bit and WGSL wraps but Flex checks): a hashed level keeps only the
//! low bits of `c * prime`, and `(c * p) mod 2^20` is `c * (p mod 2^10) + ((c * (p >> 10
//! mod 2^10)) mod 2^10) * 2^10`, every product below 2^23 for `c < 2^13`. Grids beyond
//! those bounds return `None` and take the host path.

use burn::prelude::*;

use super::hash_primes::{IDENTITY_PRIME, PRIMES};

/// Vertex coordinates must stay below this (a resolution of 8191 cells).
const MAX_VERTEX: usize = 1 << 13;
/// Hashed levels must have at most this many rows (`2^20`).
const LOW_BITS: u32 = 20;
const LOW_MASK: i32 = (1 << LOW_BITS) - 1;

/// Lower cell corners `[n, L, 3]` (float) and the 8 vertex rows of every point and level,
/// `[n * L * 8]` in `[n, L, 8]` order, corner `k` at `(k & 1, k >> 1 & 1, k >> 2)`. `x`:
/// `[n, 3]`, already clamped to the unit cube.
pub(super) fn corners_on_device(
    x: &Tensor<2>,
    resolutions: &[usize],
    offsets: &[usize],
    id: u32,
) -> Option<(Tensor<3>, Tensor<1, Int>)> {
    let fits = resolutions.iter().enumerate().all(|(level, &res)| {
        let size = offsets[level + 1] - offsets[level];
        res + 1 < MAX_VERTEX && size <= 1 << LOW_BITS
    });
    if !fits || resolutions.is_empty() {
        return None;
    }
    let device = x.device();
    let [n, _] = x.dims();
    let x = x.clone().detach();
    let corner = |pattern: [i32; 8]| {
        Tensor::<2, Int>::from_data(TensorData::new(pattern.to_vec(), [1, 8]), &device)
    };
    let (dx, dy, dz) = (
        corner([0, 1, 0, 1, 0, 1, 0, 1]),
        corner([0, 0, 1, 1, 0, 0, 1, 1]),
        corner([0, 0, 0, 0, 1, 1, 1, 1]),
    );
    let mut lowers = Vec::with_capacity(resolutions.len());
    let mut rows = Vec::with_capacity(resolutions.len());
    for (level, &res) in resolutions.iter().enumerate() {
        let cell = (x.clone() * res as f32)
            .floor()
            .clamp(0.0, res as f32 - 1.0); // [n, 3]
        lowers.push(cell.clone().unsqueeze_dim::<3>(1)); // [n, 1, 3]
        let c = cell.int(); // [n, 3]
        let axis = |a: usize, d: &Tensor<2, Int>| c.clone().narrow(1, a, 1) + d.clone(); // [n, 8]
        let (cx, cy, cz) = (axis(0, &dx), axis(1, &dy), axis(2, &dz));
        let res1 = (res + 1) as i32;
        let block = (res + 1).pow(3);
        let size = offsets[level + 1] - offsets[level];
        let offset = offsets[level] as i32;
        let local = if block <= size && size.is_multiple_of(block) {
            let shift = ((id as usize * block) % size) as i32;
            (cx + cy.mul_scalar(res1) + cz.mul_scalar(res1 * res1))
                .add_scalar(shift)
                .remainder_scalar(size as i32)
        } else {
            let id_hash = (id.wrapping_mul(IDENTITY_PRIME) as i64 & LOW_MASK as i64) as i32;
            mul_low(cx, PRIMES[0])
                .bitwise_xor(mul_low(cy, PRIMES[1]))
                .bitwise_xor(mul_low(cz, PRIMES[2]))
                .bitwise_xor_scalar(id_hash)
                .bitwise_and_scalar(size as i32 - 1)
        };
        rows.push(local.add_scalar(offset).unsqueeze_dim::<3>(1)); // [n, 1, 8]
    }
    let l = resolutions.len();
    let lower = Tensor::cat(lowers, 1); // [n, L, 3]
    let rows = Tensor::cat(rows, 1).reshape([n * l * 8]);
    Some((lower, rows))
}

/// `(c * prime) mod 2^20` for `0 <= c < 2^13`, in i32 without overflow.
fn mul_low(c: Tensor<2, Int>, prime: u32) -> Tensor<2, Int> {
    let a = (prime & 1023) as i32;
    let b = ((prime >> 10) & 1023) as i32;
    let high = c
        .clone()
        .mul_scalar(b)
        .bitwise_and_scalar(1023)
        .bitwise_left_shift_scalar(10);
    (c.mul_scalar(a) + high).bitwise_and_scalar(LOW_MASK)
}
