//! A small deterministic RNG (SplitMix64) with independent streams derived from ids, so that
//! parallel generation gives byte-identical output for a seed regardless of scheduling. The
//! generator and the hashes are the workspace's one copy (`depthsense_base::hash`).

use depthsense_base::hash::{fnv1a64, SplitMix64};

/// SplitMix64 finaliser: a good 64-bit mixing function.
use depthsense_base::hash::splitmix64_mix as mix;

/// Hash a list of ids under a seed.
pub fn hash_ids(seed: u64, ids: &[u64]) -> u64 {
    let mut h = mix(seed ^ 0x9E37_79B9_7F4A_7C15);
    for (i, &id) in ids.iter().enumerate() {
        h = mix(h ^ mix(id.wrapping_add((i as u64 + 1).wrapping_mul(0x632B_E59B_D9B4_E019))));
    }
    h
}

/// FNV-1a of a string, for ids derived from names.
pub fn hash_str(s: &str) -> u64 {
    fnv1a64(s.as_bytes())
}

/// SplitMix64 generator whose state is the seed itself (the loader's `Rng` mixes its seed
/// first: the two streams differ by design and each stays as it was).
#[derive(Debug, Clone)]
pub struct Rng(SplitMix64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(SplitMix64::from_state(seed))
    }

    /// An independent stream for `ids` under `seed`.
    pub fn stream(seed: u64, ids: &[u64]) -> Self {
        Rng(SplitMix64::from_state(hash_ids(seed, ids)))
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }

    /// Uniform in [0, 1).
    pub fn f64(&mut self) -> f64 {
        self.0.next_f64()
    }

    /// Uniform in [a, b).
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.f64()
    }

    /// Uniform integer in 0..n (n > 0).
    pub fn below(&mut self, n: usize) -> usize {
        (((self.next_u64() >> 32) * n as u64) >> 32) as usize
    }

    pub fn chance(&mut self, p: f64) -> bool {
        self.f64() < p
    }

    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.f64().max(1e-300);
        let u2 = self.f64();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    pub fn pick<'a, T>(&mut self, xs: &'a [T]) -> &'a T {
        &xs[self.below(xs.len())]
    }
}

/// A 32-hex-digit token from ids (nuScenes tokens are 32 lower-case hex digits).
pub fn token(seed: u64, ids: &[u64]) -> String {
    let a = hash_ids(seed, ids);
    let b = mix(a ^ 0xD6E8_FEB8_6659_FD93);
    format!("{a:016x}{b:016x}")
}

/// A token that depends only on a name (sensors, categories, attributes): stable across seeds.
pub fn name_token(kind: &str, name: &str) -> String {
    token(hash_str(kind), &[hash_str(name)])
}

/// Cheap hash noise in [0, 1) of an integer lattice point.
#[inline]
pub fn lattice(x: i64, y: i64, z: i64, salt: u64) -> f32 {
    let h = mix((x as u64).wrapping_mul(0x9E37_79B1)
        ^ (y as u64).wrapping_mul(0x85EB_CA77_0000_0000)
        ^ (z as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ salt);
    (h >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_stream_is_splitmix64_from_the_seed() {
        // state = seed; each draw: state += γ, then the finaliser (values from a Python
        // transcription of splitmix64.c): the synthetic world's bytes depend on this stream
        let mut r = Rng::new(7);
        assert_eq!(r.next_u64(), 7191089600892374487);
        assert_eq!(r.next_u64(), 309689372594955804);
    }

    #[test]
    fn streams_are_deterministic_and_distinct() {
        let mut a = Rng::stream(7, &[1, 2]);
        let mut b = Rng::stream(7, &[1, 2]);
        let mut c = Rng::stream(7, &[2, 1]);
        let xa: Vec<u64> = (0..4).map(|_| a.next_u64()).collect();
        let xb: Vec<u64> = (0..4).map(|_| b.next_u64()).collect();
        let xc: Vec<u64> = (0..4).map(|_| c.next_u64()).collect();
        assert_eq!(xa, xb);
        assert_ne!(xa, xc);
    }

    #[test]
    fn uniform_and_normal_moments() {
        let mut r = Rng::new(3);
        let n = 20000;
        let (mut s, mut s2, mut u) = (0.0, 0.0, 0.0);
        for _ in 0..n {
            let x = r.normal();
            s += x;
            s2 += x * x;
            u += r.f64();
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        assert!(mean.abs() < 0.03, "{mean}");
        assert!((var - 1.0).abs() < 0.05, "{var}");
        assert!((u / n as f64 - 0.5).abs() < 0.01);
        for _ in 0..1000 {
            assert!(r.below(7) < 7);
        }
    }

    #[test]
    fn tokens_are_32_hex() {
        let t = token(1, &[2, 3]);
        assert_eq!(t.len(), 32);
        assert!(t
            .chars()
            .all(|c| c.is_ascii_hexdigit() && !c.is_ascii_uppercase()));
        assert_ne!(t, token(1, &[2, 4]));
        assert_eq!(
            name_token("sensor", "CAM_FRONT"),
            name_token("sensor", "CAM_FRONT")
        );
    }
}
