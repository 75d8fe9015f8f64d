//! Deterministic draws for the unit tests: libtorch's generator is global and the tests of a
//! binary run in parallel, so `manual_seed` + `randn` in one test can interleave with another
//! test's draws and give other values from run to run.

use tch::Tensor;

/// Uniform [0, 1) values of `shape` from a seeded xorshift (`seed` advances).
pub(crate) fn uniform(shape: &[i64], seed: &mut u64) -> Tensor {
    let n: i64 = shape.iter().product();
    let v: Vec<f32> = (0..n)
        .map(|_| {
            *seed ^= *seed << 13;
            *seed ^= *seed >> 7;
            *seed ^= *seed << 17;
            (*seed >> 40) as f32 / (1u64 << 24) as f32
        })
        .collect();
    Tensor::from_slice(&v).view(shape)
}
