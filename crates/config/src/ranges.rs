//! The ranges of numeric flags, checked while the command line is parsed so that a refusal
//! names its flag (clap writes `invalid value '-1' for '--lr <LR>': …`) before any work: a
//! learning rate or a size is positive, a count is at least 1, a probability lies in [0, 1].
//! The flags that use them also accept a leading minus (`allow_negative_numbers`), so that
//! `--epochs -3` is refused for its value instead of read as an unknown flag.

/// A number `> 0` (learning rates, sizes in MB).
pub fn positive(s: &str) -> Result<f64, String> {
    let v = number(s)?;
    if v > 0.0 {
        Ok(v)
    } else {
        Err(format!("must be greater than 0 (got {s})"))
    }
}

/// A number `>= 0` (weight decay, the decay's power).
pub fn non_negative(s: &str) -> Result<f64, String> {
    let v = number(s)?;
    if v >= 0.0 {
        Ok(v)
    } else {
        Err(format!("must be 0 or more (got {s})"))
    }
}

/// A probability in [0, 1] (dropout, radar drop, momentum).
pub fn probability(s: &str) -> Result<f64, String> {
    let v = number(s)?;
    if (0.0..=1.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("must be between 0 and 1 (got {s})"))
    }
}

/// A count `>= 1` (epochs, batch size, samples).
pub fn count(s: &str) -> Result<usize, String> {
    let v = integer(s)?;
    usize::try_from(v)
        .ok()
        .filter(|&n| n >= 1)
        .ok_or_else(|| format!("must be at least 1 (got {s})"))
}

/// A count `>= 1` as a u64 (iterations).
pub fn count_u64(s: &str) -> Result<u64, String> {
    let v = integer(s)?;
    u64::try_from(v)
        .ok()
        .filter(|&n| n >= 1)
        .ok_or_else(|| format!("must be at least 1 (got {s})"))
}

/// An integer `>= 0` (`--jobs 0`: all cores; cadences where 0 means never).
pub fn non_negative_usize(s: &str) -> Result<usize, String> {
    let v = integer(s)?;
    usize::try_from(v).map_err(|_| format!("must be 0 or more (got {s})"))
}

/// An integer `>= 0` as a u64.
pub fn non_negative_u64(s: &str) -> Result<u64, String> {
    let v = integer(s)?;
    u64::try_from(v).map_err(|_| format!("must be 0 or more (got {s})"))
}

fn number(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("not a number: {s}"))?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("must be a finite number (got {s})"))
    }
}

fn integer(s: &str) -> Result<i128, String> {
    s.trim()
        .parse()
        .map_err(|_| format!("not a whole number: {s}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_refuse_with_the_value() {
        assert_eq!(positive("1e-3"), Ok(1e-3));
        assert_eq!(
            positive("-1").unwrap_err(),
            "must be greater than 0 (got -1)"
        );
        assert_eq!(positive("0").unwrap_err(), "must be greater than 0 (got 0)");
        assert!(positive("nan").is_err() && positive("inf").is_err());
        assert_eq!(probability("1"), Ok(1.0));
        assert_eq!(
            probability("1.5").unwrap_err(),
            "must be between 0 and 1 (got 1.5)"
        );
        assert_eq!(count("3"), Ok(3));
        assert_eq!(count("-3").unwrap_err(), "must be at least 1 (got -3)");
        assert_eq!(count("0").unwrap_err(), "must be at least 1 (got 0)");
        assert_eq!(count("x").unwrap_err(), "not a whole number: x");
        assert_eq!(non_negative_usize("0"), Ok(0));
        assert!(non_negative_usize("-1").is_err());
        assert_eq!(count_u64("7"), Ok(7));
        assert_eq!(
            non_negative("-0.1").unwrap_err(),
            "must be 0 or more (got -0.1)"
        );
    }
}
