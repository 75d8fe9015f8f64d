//! Scene splits shipped with the repository (`splits/*.txt`, one scene token per line).

use std::collections::HashSet;

use crate::pipeline::PrepError;

/// Split names accepted by `--split`, with their scene lists (None = every scene).
pub const SPLIT_NAMES: [&str; 8] = [
    "train",
    "test",
    "test-day",
    "test-night",
    "test-rain",
    "official-train",
    "official-val",
    "all",
];

fn split_text(name: &str) -> Option<&'static str> {
    Some(match name {
        "train" => include_str!("../../../splits/train_scenes.txt"),
        "test" => include_str!("../../../splits/test_scenes.txt"),
        "test-day" => include_str!("../../../splits/test_day_scenes.txt"),
        "test-night" => include_str!("../../../splits/test_night_scenes.txt"),
        "test-rain" => include_str!("../../../splits/test_rain_scenes.txt"),
        "official-train" => include_str!("../../../splits/official_train_scenes.txt"),
        "official-val" => include_str!("../../../splits/official_val_scenes.txt"),
        _ => return None,
    })
}

/// Scene tokens of split `name`; `Ok(None)` for "all"; an error for an unknown name.
pub fn split_scene_tokens(name: &str) -> Result<Option<HashSet<String>>, PrepError> {
    if name == "all" {
        return Ok(None);
    }
    let text = split_text(name).ok_or_else(|| PrepError::UnknownSplit(name.to_string()))?;
    Ok(Some(
        text.lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .map(String::from)
            .collect(),
    ))
}

/// Every named split (except "all") that contains `scene_token`.
pub fn splits_of_scene(scene_token: &str) -> Vec<String> {
    SPLIT_NAMES
        .iter()
        .filter(|n| **n != "all")
        .filter(|n| {
            split_text(n)
                .map(|t| t.lines().any(|l| l.trim() == scene_token))
                .unwrap_or(false)
        })
        .map(|n| n.to_string())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_sizes_match_the_readme() {
        let n = |s| split_scene_tokens(s).unwrap().unwrap().len();
        assert_eq!(n("train"), 765);
        assert_eq!(n("test"), 85);
        assert_eq!(n("test-day") + n("test-night") + n("test-rain"), 85);
        assert_eq!(n("official-train"), 700);
        assert_eq!(n("official-val"), 150);
        assert!(split_scene_tokens("all").unwrap().is_none());
        assert!(split_scene_tokens("bogus").is_err());
        let train = split_scene_tokens("train").unwrap().unwrap();
        let test = split_scene_tokens("test").unwrap().unwrap();
        assert!(train.is_disjoint(&test));
        assert!(train.iter().all(|t| t.len() == 32));
    }
}
