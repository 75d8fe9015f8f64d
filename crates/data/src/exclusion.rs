//! Withholding training scenes by condition (SPEC §10.5): `train --exclude night=1.0,rain=0.5`.
//!
//! The withholding rule ([`withheld_scenes`]), deterministic and independent of the seed:
//! for each `condition=fraction`, take the distinct scene names of the training partition
//! whose conditions include that condition (a night+rain scene counts for both), order them
//! by the key `(splitmix64(fnv1a64(name)), name)` (a fixed pseudo-random order that does not
//! depend on the other scenes), and withhold the first `round(fraction × n)` (half away from
//! zero). Exclusions of several conditions withhold the union. Validation and test scenes
//! are never touched: every grid cell is selected and tested on the same scenes.

use std::collections::BTreeSet;
use std::str::FromStr;

use depthsense_base::hash::fnv1a64;
use depthsense_prep::layout::{Condition, IndexEntry};
use serde::{Deserialize, Serialize};

use depthsense_base::hash::splitmix64;
use depthsense_dataset::Partition;
use depthsense_dataset::{DataError, ExclusionFault};

/// Withhold `fraction` of the training scenes of `condition`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Exclusion {
    pub condition: Condition,
    pub fraction: f64,
}

fn condition_name(c: Condition) -> &'static str {
    match c {
        Condition::Day => "day",
        Condition::Night => "night",
        Condition::Rain => "rain",
    }
}

impl std::fmt::Display for Exclusion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}={}", condition_name(self.condition), self.fraction)
    }
}

impl FromStr for Exclusion {
    type Err = DataError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = |fault| DataError::BadExclusion {
            word: s.to_string(),
            fault,
        };
        let (c, f) = s
            .split_once('=')
            .ok_or_else(|| bad(ExclusionFault::NoFraction))?;
        let condition = match c.trim() {
            "day" => Condition::Day,
            "night" => Condition::Night,
            "rain" => Condition::Rain,
            _ => return Err(bad(ExclusionFault::UnknownCondition)),
        };
        let fraction: f64 = f
            .trim()
            .parse()
            .map_err(|_| bad(ExclusionFault::NotANumber))?;
        if !(0.0..=1.0).contains(&fraction) {
            return Err(bad(ExclusionFault::OutOfRange));
        }
        Ok(Exclusion {
            condition,
            fraction,
        })
    }
}

/// Parse "night=1.0,rain=0.5" (empty or "full" = no exclusion).
pub fn parse_exclusions(s: &str) -> Result<Vec<Exclusion>, DataError> {
    let s = s.trim();
    if s.is_empty() || s == "full" {
        return Ok(vec![]);
    }
    s.split(',').map(|x| x.parse()).collect()
}

/// "night=1,rain=0.5", or "full".
pub fn exclusions_label(ex: &[Exclusion]) -> String {
    if ex.is_empty() {
        "full".into()
    } else {
        ex.iter()
            .map(|e| e.to_string())
            .collect::<Vec<_>>()
            .join(",")
    }
}

/// The scenes `exclude` withholds from `train` (module docs), sorted by name.
pub fn withheld_scenes(train: &[IndexEntry], exclude: &[Exclusion]) -> Vec<String> {
    let mut out = BTreeSet::new();
    for ex in exclude {
        let scenes: BTreeSet<&str> = train
            .iter()
            .filter(|e| e.conditions.contains(&ex.condition))
            .map(|e| e.scene_name.as_str())
            .collect();
        let mut order: Vec<(u64, &str)> = scenes
            .into_iter()
            .map(|n| (splitmix64(fnv1a64(n.as_bytes())), n))
            .collect();
        order.sort();
        let k = (ex.fraction * order.len() as f64).round() as usize;
        out.extend(order.iter().take(k).map(|(_, n)| n.to_string()));
    }
    out.into_iter().collect()
}

/// Remove the withheld scenes from `part.train` and say so in `part.method`; returns them.
pub fn apply_exclusions(part: &mut Partition, exclude: &[Exclusion]) -> Vec<String> {
    if exclude.is_empty() {
        return vec![];
    }
    let gone = withheld_scenes(&part.train, exclude);
    part.train.retain(|e| !gone.contains(&e.scene_name));
    part.method = format!(
        "{}; --exclude {} withheld {} training scene(s): {}",
        part.method,
        exclusions_label(exclude),
        gone.len(),
        gone.join(", ")
    );
    gone
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each malformed `--exclude` word is refused with the word and what is wrong with it.
    #[test]
    fn a_malformed_exclusion_names_the_word_and_the_fault() {
        let fault = |s: &str| match s.parse::<Exclusion>() {
            Err(DataError::BadExclusion { word, fault }) => {
                assert_eq!(word, s);
                Some(fault)
            }
            Err(e) => panic!("{s}: {e}"),
            Ok(_) => None,
        };
        assert_eq!(fault("night"), Some(ExclusionFault::NoFraction));
        assert_eq!(fault("fog=1"), Some(ExclusionFault::UnknownCondition));
        assert_eq!(fault("rain=half"), Some(ExclusionFault::NotANumber));
        assert_eq!(fault("day=1.5"), Some(ExclusionFault::OutOfRange));
        assert_eq!(fault(" night = 0.5 "), None);
        let text = |s: &str| parse_exclusions(s).unwrap_err().to_string();
        assert_eq!(
            text("night=1,night"),
            "configuration: --exclude \"night\": expected CONDITION=FRACTION, e.g. night=1.0"
        );
        assert_eq!(
            text("fog=1"),
            "configuration: --exclude \"fog=1\": condition must be day, night or rain"
        );
        assert_eq!(
            text("rain=half"),
            "configuration: --exclude \"rain=half\": fraction must be a number"
        );
        assert_eq!(
            text("day=1.5"),
            "configuration: --exclude \"day=1.5\": fraction must be within [0, 1]"
        );
    }
}
