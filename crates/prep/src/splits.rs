//! Scene splits: the lists shipped with the repository (`splits/*.txt`, one scene token per
//! line) or the dataroot's own lists, and the three-way train / val / test assignment.
//!
//! **Dataroot lists.** A dataroot may carry `<dataroot>/<version>/splits/{train,val,test}_scenes.txt`
//! (one scene token per line; the synthetic world writes them). When that folder holds any of
//! the three files, they alone define the splits of that version ([`SplitAssignment::source`]
//! = `"dataroot"`).
//!
//! **Shipped lists** (`source` = `"shipped"`). "val" is a fixed subset of the released train
//! list (765 scenes), chosen without looking at any result: among the train-list scenes present
//! in the version's scene table, grouped by condition (SPEC §2: the condition set of the
//! description, so night+rain scenes form their own group), sorted by scene name, every
//! [`VAL_EVERY`]th scene (positions 9, 19, 29 … of each group); a group of ≥ 2 scenes that gets
//! none gives its last scene. Those scenes carry "val" instead of "train", so "train" = the
//! released train list minus val. The test lists are never touched.

use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};
use std::path::{Path, PathBuf};

use depthsense_nuscenes::NuScenes;

use crate::error::PrepError;
use crate::layout::conditions_of;

/// Folder of a dataroot's own split lists, inside the version folder.
pub const DATAROOT_SPLITS_DIR: &str = "splits";
/// Names of the three-way split (file `<name>_scenes.txt`).
pub const THREE_WAY: [&str; 3] = ["train", "val", "test"];
/// Every `VAL_EVERY`th train-list scene of a condition group becomes "val" (shipped lists).
pub const VAL_EVERY: usize = 10;

/// Split names accepted by `--split`, with their scene lists (None = every scene).
pub const SPLIT_NAMES: [&str; 9] = [
    "train",
    "val",
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

/// Scene tokens of a shipped split `name`; `Ok(None)` for "all"; an error for an unknown
/// name. "train" here is the released list (val included); "val" depends on the version's
/// scene table: use [`assign_splits`] for both.
pub fn split_scene_tokens(name: &str) -> Result<Option<HashSet<String>>, PrepError> {
    if name == "all" {
        return Ok(None);
    }
    if name == "val" {
        return Err(PrepError::ValPerSceneTable);
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

/// Every shipped split list (except "all") that contains `scene_token` ("train" is the
/// released list, before val is taken out of it).
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

/// The split tags of every scene of one version, and where they came from.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SplitAssignment {
    /// `"dataroot"` (the version's own `splits/` lists) or `"shipped"` (the repository's lists
    /// with val taken out of train).
    pub source: String,
    /// The folder the lists were read from (dataroot source only).
    pub lists_dir: Option<PathBuf>,
    /// Scene token → split names (e.g. ["train", "official-train"], ["test", "test-night"],
    /// ["val", "official-train"]); scenes in no list are absent.
    pub scene_splits: HashMap<String, Vec<String>>,
    /// Scene tokens of train / val / test present in the scene table, in table order.
    pub train_scenes: Vec<String>,
    pub val_scenes: Vec<String>,
    pub test_scenes: Vec<String>,
}

impl SplitAssignment {
    /// Split names of a scene (["all"] when it is in no list).
    pub fn splits_of(&self, scene_token: &str) -> Vec<String> {
        match self.scene_splits.get(scene_token) {
            Some(v) if !v.is_empty() => v.clone(),
            _ => vec!["all".to_string()],
        }
    }

    /// True when scene `scene_token` belongs to split `name` ("all": every scene).
    pub fn contains(&self, name: &str, scene_token: &str) -> bool {
        name == "all"
            || self
                .scene_splits
                .get(scene_token)
                .is_some_and(|v| v.iter().any(|s| s == name))
    }
}

/// The dataroot's own lists, `<dataroot>/<version>/splits/{train,val,test}_scenes.txt`:
/// `Ok(None)` when none of the three files exists; a missing one of the three is empty.
pub fn read_dataroot_lists(
    dataroot: &Path,
    version: &str,
) -> Result<Option<BTreeMap<String, Vec<String>>>, PrepError> {
    let dir = dataroot.join(version).join(DATAROOT_SPLITS_DIR);
    let mut out = BTreeMap::new();
    let mut any = false;
    for name in THREE_WAY {
        let p = dir.join(format!("{name}_scenes.txt"));
        let toks = match std::fs::read_to_string(&p) {
            Ok(t) => {
                any = true;
                t.lines()
                    .map(str::trim)
                    .filter(|l| !l.is_empty() && !l.starts_with('#'))
                    .map(String::from)
                    .collect()
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
            Err(e) => {
                return Err(PrepError::SplitList {
                    path: p.to_path_buf(),
                    source: e,
                })
            }
        };
        out.insert(name.to_string(), toks);
    }
    Ok(any.then_some(out))
}

/// The val scenes taken out of the released train list (see the module docs): `scenes` are
/// (token, name, description) of the version's scene table, `train` the released train list.
pub fn val_from_train(
    scenes: &[(String, String, String)],
    train: &HashSet<String>,
) -> BTreeSet<String> {
    let mut groups: BTreeMap<Vec<crate::layout::Condition>, Vec<(&str, &str)>> = BTreeMap::new();
    for (tok, name, desc) in scenes {
        if train.contains(tok) {
            groups
                .entry(conditions_of(desc))
                .or_default()
                .push((name.as_str(), tok.as_str()));
        }
    }
    let mut val = BTreeSet::new();
    for g in groups.values_mut() {
        g.sort();
        g.dedup();
        let before = val.len();
        for (j, (_, tok)) in g.iter().enumerate() {
            if j % VAL_EVERY == VAL_EVERY - 1 {
                val.insert(tok.to_string());
            }
        }
        if val.len() == before && g.len() >= 2 {
            val.insert(g[g.len() - 1].1.to_string());
        }
    }
    val
}

/// Split tags of every scene of `nu` (dataroot lists when present, else shipped lists with
/// val taken out of train).
pub fn assign_splits(nu: &NuScenes) -> Result<SplitAssignment, PrepError> {
    let mut a = SplitAssignment::default();
    if let Some(lists) = read_dataroot_lists(&nu.dataroot, &nu.version)? {
        a.source = "dataroot".into();
        a.lists_dir = Some(nu.dataroot.join(&nu.version).join(DATAROOT_SPLITS_DIR));
        for (name, toks) in &lists {
            for t in toks {
                let v = a.scene_splits.entry(t.clone()).or_default();
                if !v.contains(name) {
                    v.push(name.clone());
                }
            }
        }
    } else {
        a.source = "shipped".into();
        let scenes: Vec<(String, String, String)> = nu
            .scene
            .iter()
            .map(|s| (s.token.to_string(), s.name.clone(), s.description.clone()))
            .collect();
        let train = split_scene_tokens("train")?.unwrap_or_default();
        let val = val_from_train(&scenes, &train);
        for (tok, _, _) in &scenes {
            let mut v = splits_of_scene(tok);
            if val.contains(tok) {
                v.retain(|s| s != "train");
                v.insert(0, "val".into());
            }
            if !v.is_empty() {
                a.scene_splits.insert(tok.clone(), v);
            }
        }
    }
    let in_split = |name: &str| -> Vec<String> {
        nu.scene
            .iter()
            .map(|s| s.token.to_string())
            .filter(|t| a.contains(name, t))
            .collect()
    };
    let (train, val, test) = (in_split("train"), in_split("val"), in_split("test"));
    a.train_scenes = train;
    a.val_scenes = val;
    a.test_scenes = test;
    Ok(a)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(i: usize, desc: &str) -> (String, String, String) {
        (
            format!("{i:032x}"),
            format!("scene-{i:04}"),
            desc.to_string(),
        )
    }

    #[test]
    fn val_is_every_tenth_train_scene_per_condition() {
        // 25 day, 12 night, 3 rain, 1 night+rain train scenes, 5 test scenes, in shuffled
        // table order.
        let mut scenes = Vec::new();
        for i in 0..25 {
            scenes.push(scene(i, "Parked cars, peds"));
        }
        for i in 100..112 {
            scenes.push(scene(i, "Night, turn"));
        }
        for i in 200..203 {
            scenes.push(scene(i, "Rain, wet road"));
        }
        scenes.push(scene(300, "Night, rain"));
        for i in 400..405 {
            scenes.push(scene(i, "Night, test scene"));
        }
        scenes.reverse();
        let train: HashSet<String> = scenes
            .iter()
            .filter(|s| !s.1.starts_with("scene-04"))
            .map(|s| s.0.clone())
            .collect();
        let test: HashSet<String> = scenes
            .iter()
            .filter(|s| s.1.starts_with("scene-04"))
            .map(|s| s.0.clone())
            .collect();
        let val = val_from_train(&scenes, &train);
        let names: BTreeSet<String> = val
            .iter()
            .map(|t| scenes.iter().find(|s| &s.0 == t).unwrap().1.clone())
            .collect();
        // Day: sorted positions 9 and 19; night: position 9; rain (3 scenes): none at
        // position 9, so its last; night+rain (1 scene): none.
        let want: BTreeSet<String> = ["scene-0009", "scene-0019", "scene-0109", "scene-0202"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        assert_eq!(names, want);
        assert!(val.iter().all(|t| train.contains(t)));
        assert!(val.iter().all(|t| !test.contains(t)));
        // Deterministic whatever the table order.
        let mut shuffled = scenes.clone();
        shuffled.rotate_left(17);
        assert_eq!(val_from_train(&shuffled, &train), val);
    }

    #[test]
    fn val_of_the_shipped_lists_is_disjoint_from_train_and_test() {
        // The released train list as a scene table (descriptions unknown here: all day).
        let train = split_scene_tokens("train").unwrap().unwrap();
        let test = split_scene_tokens("test").unwrap().unwrap();
        let mut scenes: Vec<(String, String, String)> = train
            .iter()
            .chain(test.iter())
            .map(|t| (t.clone(), format!("s-{t}"), "day".to_string()))
            .collect();
        scenes.sort();
        let val = val_from_train(&scenes, &train);
        assert_eq!(val.len(), train.len() / VAL_EVERY);
        assert!(val.iter().all(|t| train.contains(t) && !test.contains(t)));
    }

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
