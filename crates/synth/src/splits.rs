//! Train / val / test scene lists of a synthetic world, written into the dataroot at
//! `<dataroot>/<version>/splits/{train,val,test}_scenes.txt` (one scene token per line, in
//! scene order). `depthsense prepare` reads them (see `depthsense_prep::splits`).
//!
//! The assignment depends only on the scene's condition and index, never on its content:
//! within each condition (in scene order) the last scenes go to test, the ones before them to
//! val, the rest to train. Each condition with ≥ 3 scenes gives val and test at least one
//! scene each (≈ 15 % each for larger groups); a condition with 2 scenes gives one to train
//! and one to test; a single scene goes to train.

use crate::Weather;

/// Folder of the split lists inside the version folder.
pub const SPLITS_DIR: &str = "splits";
/// The three split names, in file order.
pub const SPLIT_NAMES: [&str; 3] = ["train", "val", "test"];

/// Split of one scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum SceneSplit {
    Train,
    Val,
    Test,
}

impl SceneSplit {
    pub fn name(self) -> &'static str {
        match self {
            SceneSplit::Train => "train",
            SceneSplit::Val => "val",
            SceneSplit::Test => "test",
        }
    }
}

/// File name of split `name` ("train" → "train_scenes.txt").
pub fn split_file_name(name: &str) -> String {
    format!("{name}_scenes.txt")
}

/// Split of every scene, given the scenes' conditions (see the module docs).
pub fn assign_splits(conditions: &[Weather]) -> Vec<SceneSplit> {
    let mut out = vec![SceneSplit::Train; conditions.len()];
    for w in [Weather::Day, Weather::Night, Weather::Rain] {
        let group: Vec<usize> = (0..conditions.len())
            .filter(|&i| conditions[i] == w)
            .collect();
        let n = group.len();
        let (n_val, n_test) = match n {
            0 | 1 => (0, 0),
            2 => (0, 1),
            _ => {
                let k = ((n as f64 * 0.15).round() as usize).max(1);
                (k, k)
            }
        };
        for (j, &i) in group.iter().enumerate() {
            out[i] = if j >= n - n_test {
                SceneSplit::Test
            } else if j >= n - n_test - n_val {
                SceneSplit::Val
            } else {
                SceneSplit::Train
            };
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::generate::allocate_conditions;

    #[test]
    fn every_condition_reaches_val_and_test() {
        let mix = [
            (Weather::Day, 0.5),
            (Weather::Night, 0.25),
            (Weather::Rain, 0.25),
        ];
        let ws = allocate_conditions(20, &mix);
        let s = assign_splits(&ws);
        for w in [Weather::Day, Weather::Night, Weather::Rain] {
            for sp in [SceneSplit::Val, SceneSplit::Test, SceneSplit::Train] {
                assert!(
                    (0..20).any(|i| ws[i] == w && s[i] == sp),
                    "{w:?} has no {sp:?} scene: {s:?}"
                );
            }
        }
        // Small groups: 2 scenes → train + test, 1 scene → train.
        let s = assign_splits(&[Weather::Day, Weather::Night, Weather::Day]);
        assert_eq!(
            s,
            vec![SceneSplit::Train, SceneSplit::Train, SceneSplit::Test]
        );
    }
}
