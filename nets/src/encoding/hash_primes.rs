//! The hash grid's spatial-hash constants, shared by the host indexing (`hash_grid`) and
//! the device indexing (`hash_corners`, the device kernels).

/// instant-ngp's spatial-hash primes (the first is 1 for cache coherence along x).
pub(crate) const PRIMES: [u32; 3] = [1, 2_654_435_761, 805_459_861];
/// Mixes the identity into the spatial hash (a fourth coordinate).
pub(crate) const IDENTITY_PRIME: u32 = 3_674_653_429;
