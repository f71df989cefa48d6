//! The random number generator every simulated run draws from: a leaf, so that the truth
//! models, the engines and the catalog name it without reaching up to the crate root.

/// The random number generator of one Monte Carlo run (xoshiro256++: fast, seedable, and
/// with independent streams per seed).
pub type SimRng = rand::rngs::Xoshiro256PlusPlus;

/// Seed k of a sequence from `first`, kept below 2^63 (TOML stores seeds as signed 64-bit
/// integers).
pub fn seed_at(first: u64, k: usize) -> u64 {
    first.wrapping_add(k as u64) & (u64::MAX >> 1)
}
