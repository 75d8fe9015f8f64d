//! What a training step takes from the iteration alone, the same for every training command:
//! the learning rate (SPEC §8: polynomial decay per iteration, optional linear warmup) and the
//! seed of libtorch's generator for the step's dropout draws (so a resumed run draws what the
//! uninterrupted one drew).

use depthsense_base::hash::splitmix64;

/// Polynomial learning-rate decay per iteration to 0 at the end (SPEC §8):
/// lr_i = lr₀ · (1 − i/total)^power.
pub fn poly_lr(base: f64, iteration: u64, total: u64, power: f64) -> f64 {
    if total == 0 {
        return base;
    }
    let frac = (1.0 - iteration as f64 / total as f64).max(0.0);
    base * frac.powf(power)
}

/// [`poly_lr`] times a linear warmup over the first `warmup` iterations: iteration i
/// (0-based) uses (i + 1)/warmup of the poly rate while i < warmup. `warmup` = 0: no warmup.
pub fn warmup_poly_lr(base: f64, iteration: u64, total: u64, power: f64, warmup: u64) -> f64 {
    let ramp = if warmup > 0 {
        ((iteration + 1) as f64 / warmup as f64).min(1.0)
    } else {
        1.0
    };
    poly_lr(base, iteration, total, power) * ramp
}

/// The seed libtorch's generator takes before step `iteration` (0-based) of a run seeded
/// `seed`: dropout draws depend only on (seed, iteration).
pub fn step_seed(seed: u64, iteration: u64) -> i64 {
    (splitmix64(seed ^ splitmix64(iteration + 1)) >> 1) as i64
}

/// Seeds libtorch's generator for step `iteration` ([`step_seed`]).
pub fn seed_step(seed: u64, iteration: u64) {
    tch::manual_seed(step_seed(seed, iteration));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poly_decay_golden() {
        assert_eq!(poly_lr(1e-3, 0, 100, 0.9), 1e-3);
        assert!((poly_lr(1e-3, 50, 100, 0.9) - 1e-3 * 0.5f64.powf(0.9)).abs() < 1e-15);
        assert_eq!(poly_lr(1e-3, 100, 100, 0.9), 0.0);
    }

    #[test]
    fn warmup_ramps_then_follows_the_decay() {
        assert_eq!(warmup_poly_lr(1.0, 0, 100, 1.0, 4), 0.25);
        assert_eq!(
            warmup_poly_lr(1.0, 3, 100, 1.0, 4),
            poly_lr(1.0, 3, 100, 1.0)
        );
        assert_eq!(
            warmup_poly_lr(1.0, 7, 100, 1.0, 0),
            poly_lr(1.0, 7, 100, 1.0)
        );
    }

    #[test]
    fn step_seeds_are_non_negative_and_differ() {
        let seeds: Vec<i64> = (0..100).map(|i| step_seed(7, i)).collect();
        assert!(seeds.iter().all(|&s| s >= 0));
        let mut sorted = seeds.clone();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(sorted.len(), seeds.len());
        assert_ne!(step_seed(7, 0), step_seed(8, 0));
    }
}
