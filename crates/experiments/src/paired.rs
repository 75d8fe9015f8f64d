//! The paired comparison of two variants over seeds: each seed trains both, so the per-seed
//! differences d_s = metric(variant, s) − metric(baseline, s) remove what the seed does to both
//! (initialisation, data order, dropout). Their mean, its standard error sd(d)/√n and the
//! two-sided paired t-test at 5 % (Student's t with n − 1 degrees of freedom) decide whether a
//! difference is a finding (docs/guide/experiments.md, "The ablation, with seeds").

use serde::{Deserialize, Serialize};

/// The paired test of one metric over the seeds both variants ran.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PairedTest {
    /// Number of pairs (seeds present on both sides).
    pub n: usize,
    /// Mean over seeds of variant − baseline.
    pub mean_difference: f64,
    /// Sample standard deviation of the differences (divisor n − 1); `None` when n < 2.
    pub std_difference: Option<f64>,
    /// Standard error of the mean difference, sd(d)/√n; `None` when n < 2.
    pub standard_error: Option<f64>,
    /// mean / standard error (±∞ when the differences are all equal and non-zero).
    pub t: Option<f64>,
    /// The two-sided 5 % critical value of Student's t with n − 1 degrees of freedom.
    pub t_critical: Option<f64>,
    /// |t| > t_critical; `None` when n < 2.
    pub significant: Option<bool>,
}

/// Two-sided 95 % quantiles t_{0.975, df} of Student's t for df = 1..=30 (standard tables).
const T_975: [f64; 30] = [
    12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160,
    2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056,
    2.052, 2.048, 2.045, 2.042,
];

/// t_{0.975, df}: the table up to 30, beyond it the first-order Cornish-Fisher expansion
/// z + (z³ + z)/(4 df) around z = 1.95996 (within 0.002 of the exact value for df > 30).
pub fn t_critical_975(df: usize) -> Option<f64> {
    match df {
        0 => None,
        1..=30 => Some(T_975[df - 1]),
        _ => {
            let z = 1.959_964_f64;
            Some(z + (z.powi(3) + z) / (4.0 * df as f64))
        }
    }
}

/// The paired test of `(variant, baseline)` values, one pair per seed; pairs with a
/// non-finite value are left out. `None` when no pair is left.
pub fn paired_test(pairs: &[(f64, f64)]) -> Option<PairedTest> {
    let d: Vec<f64> = pairs
        .iter()
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .map(|(a, b)| a - b)
        .collect();
    let n = d.len();
    if n == 0 {
        return None;
    }
    let mean = d.iter().sum::<f64>() / n as f64;
    if n < 2 {
        return Some(PairedTest {
            n,
            mean_difference: mean,
            std_difference: None,
            standard_error: None,
            t: None,
            t_critical: None,
            significant: None,
        });
    }
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    let sd = var.sqrt();
    let se = sd / (n as f64).sqrt();
    let t = if se > 0.0 {
        mean / se
    } else if mean == 0.0 {
        0.0
    } else {
        mean.signum() * f64::INFINITY
    };
    let t_critical = t_critical_975(n - 1);
    Some(PairedTest {
        n,
        mean_difference: mean,
        std_difference: Some(sd),
        standard_error: Some(se),
        t: Some(t),
        t_critical,
        significant: t_critical.map(|c| t.abs() > c),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paired_test_by_hand() {
        // d = (−0.2, −0.1, −0.3, 0.0): mean −0.15, sd = √(0.05/3) = 0.129099,
        // se = sd/2 = 0.0645497, t = −2.32379; t_{0.975,3} = 3.182 → not significant.
        let p = paired_test(&[(9.8, 10.0), (9.9, 10.0), (9.7, 10.0), (10.0, 10.0)]).unwrap();
        assert_eq!(p.n, 4);
        assert!((p.mean_difference + 0.15).abs() < 1e-12);
        assert!((p.std_difference.unwrap() - (0.05f64 / 3.0).sqrt()).abs() < 1e-12);
        assert!((p.standard_error.unwrap() - 0.064_549_722).abs() < 1e-8);
        assert!((p.t.unwrap() + 2.323_790_0).abs() < 1e-6);
        assert_eq!(p.t_critical, Some(3.182));
        assert_eq!(p.significant, Some(false));
        // The same mean with a small spread is significant.
        let p = paired_test(&[(9.85, 10.0), (9.86, 10.0), (9.84, 10.0)]).unwrap();
        assert!((p.mean_difference + 0.15).abs() < 1e-9);
        assert_eq!(p.significant, Some(true));
    }

    #[test]
    fn pairing_removes_what_the_seed_does_to_both() {
        // The seed moves both variants by ±1 m; the variant is always 0.1 m better. Unpaired
        // stds (≈ 1.3) swamp the difference; the paired test finds it.
        let pairs: Vec<(f64, f64)> = [0.0, 1.0, -1.0, 2.0, -2.0]
            .iter()
            .map(|s| (10.0 + s - 0.1, 10.0 + s))
            .collect();
        let p = paired_test(&pairs).unwrap();
        assert!((p.mean_difference + 0.1).abs() < 1e-9);
        assert!(p.t.unwrap() < -10.0, "{p:?}");
        assert_eq!(p.significant, Some(true));
    }

    #[test]
    fn too_few_pairs_and_non_finite_values() {
        let p = paired_test(&[(1.0, 2.0), (f64::NAN, 1.0)]).unwrap();
        assert_eq!(p.n, 1);
        assert_eq!(p.significant, None);
        assert!(paired_test(&[(f64::NAN, 1.0)]).is_none());
        assert_eq!(
            paired_test(&[(1.0, 1.0), (2.0, 2.0)]).unwrap().significant,
            Some(false)
        );
    }

    #[test]
    fn critical_values() {
        assert_eq!(t_critical_975(0), None);
        assert_eq!(t_critical_975(7), Some(2.365));
        // df 40: 2.021, df 120: 1.980 (tables).
        assert!((t_critical_975(40).unwrap() - 2.021).abs() < 0.002);
        assert!((t_critical_975(120).unwrap() - 1.980).abs() < 0.002);
    }
}
