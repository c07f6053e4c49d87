//! Tests' random numbers: a 64-bit LCG (Knuth's MMIX constants), so every test draws the same
//! sequence on every machine without a dependency.

/// Uniform numbers in [−0.5, 0.5), the sequence fixed by `seed`.
pub fn centred(mut seed: u64) -> impl FnMut() -> f64 {
    move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    }
}
