//! A prepared data folder (`index.json` and its sample folders) and its partition into
//! training, validation and test scenes (SPEC §8: validation picks checkpoints, test scenes are
//! only reported).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use depthsense_prep::layout::{IndexEntry, PreparedIndex, INDEX_FILE};
use serde::{Deserialize, Serialize};

use crate::error::{DataError, NotPrepared};

/// A prepared data directory: `index.json` and its sample folders.
#[derive(Debug, Clone)]
pub struct Dataset {
    pub root: PathBuf,
    pub index: PreparedIndex,
}

/// What `root`, which has no `index.json`, is instead.
fn not_prepared(root: &Path) -> NotPrepared {
    if !root.is_dir() {
        let parent = root
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        let mut prepared_siblings: Vec<String> = std::fs::read_dir(parent)
            .map(|rd| {
                rd.flatten()
                    .filter(|e| e.path().join(INDEX_FILE).is_file())
                    .map(
                        |e| match root.parent().filter(|p| !p.as_os_str().is_empty()) {
                            Some(p) => p.join(e.file_name()).display().to_string(),
                            None => e.file_name().to_string_lossy().into_owned(),
                        },
                    )
                    .collect()
            })
            .unwrap_or_default();
        prepared_siblings.sort();
        return NotPrepared::Missing { prepared_siblings };
    }
    let mut shards: Vec<String> = std::fs::read_dir(root)
        .map(|rd| {
            rd.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with("index.shard-") && n.ends_with(".json"))
                .collect()
        })
        .unwrap_or_default();
    shards.sort();
    if !shards.is_empty() {
        return NotPrepared::Shards(shards);
    }
    let versions = depthsense_nuscenes::tables::version_folders(root);
    if !versions.is_empty() {
        return NotPrepared::Dataroot(versions);
    }
    NotPrepared::Other
}

impl Dataset {
    /// Open `root/index.json`.
    pub fn open(root: &Path) -> Result<Self, DataError> {
        let path = root.join(INDEX_FILE);
        if !path.exists() {
            return Err(DataError::NoIndex {
                root: root.display().to_string(),
                found: not_prepared(root),
            });
        }
        let bytes = std::fs::read(&path).map_err(|e| DataError::io(&path, e))?;
        let index: PreparedIndex =
            serde_json::from_slice(&bytes).map_err(|e| DataError::Parse {
                path: path.to_path_buf(),
                reason: e.to_string(),
            })?;
        if index.samples.is_empty() {
            return Err(DataError::EmptyIndex { index: path });
        }
        Ok(Self {
            root: root.to_path_buf(),
            index,
        })
    }

    /// (width, height) of every sample's maps: the index says it (`frame_size`); an index
    /// written before it did is answered from the first sample's image header (its pixels are
    /// not decoded).
    pub fn frame_size(&self) -> Result<(u32, u32), DataError> {
        if let Some([w, h]) = self.index.frame_size {
            return Ok((w, h));
        }
        let first = self
            .index
            .samples
            .first()
            .ok_or_else(|| DataError::EmptyIndex {
                index: self.root.join(INDEX_FILE),
            })?;
        let image = self
            .sample_dir(first)
            .join(depthsense_prep::layout::IMAGE_FILE);
        image::image_dimensions(&image).map_err(|e| DataError::Parse {
            path: image.clone(),
            reason: e.to_string(),
        })
    }

    pub fn sample_dir(&self, e: &IndexEntry) -> PathBuf {
        self.root.join(&e.dir)
    }

    /// Every distinct split name in the index.
    pub fn split_names(&self) -> BTreeSet<String> {
        self.index
            .samples
            .iter()
            .flat_map(|s| s.splits.iter().cloned())
            .collect()
    }

    /// Entries of a split ("all" = everything).
    pub fn split(&self, name: &str) -> Vec<IndexEntry> {
        self.index
            .samples
            .iter()
            .filter(|s| name == "all" || s.splits.iter().any(|x| x == name))
            .cloned()
            .collect()
    }

    /// Scene names in index order, deduplicated.
    pub fn scenes(&self) -> Vec<String> {
        let mut seen = BTreeSet::new();
        let mut out = Vec::new();
        for s in &self.index.samples {
            if seen.insert(s.scene_name.clone()) {
                out.push(s.scene_name.clone());
            }
        }
        out
    }
}

/// The train / validation / test partition: `train` fits, `val` selects (checkpoints, epochs,
/// hyper-parameters), `test` only reports. The three scene sets are disjoint in every mode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Partition {
    /// How it was made (see [`partition`]).
    pub method: String,
    pub train: Vec<IndexEntry>,
    pub val: Vec<IndexEntry>,
    pub test: Vec<IndexEntry>,
    /// Scenes of the validation set (names, sorted).
    pub val_scenes: Vec<String>,
    /// Scenes of the test set (names, sorted).
    pub test_scenes: Vec<String>,
}

impl Partition {
    /// A training run needs both training and validation samples: the error names the
    /// prepared folder `data`, both counts and how the partition was made.
    pub fn require_train_and_val(&self, data: &Path) -> Result<(), DataError> {
        if self.train.is_empty() || self.val.is_empty() {
            return Err(DataError::NoTrainOrVal {
                data: data.to_path_buf(),
                train: self.train.len(),
                val: self.val.len(),
                method: self.method.clone(),
            });
        }
        Ok(())
    }
}

fn scene_names(entries: &[IndexEntry]) -> Vec<String> {
    let set: BTreeSet<String> = entries.iter().map(|e| e.scene_name.clone()).collect();
    set.into_iter().collect()
}

/// Scenes at positions every−1, 2·every−1, … of `scenes` (sorted); the last one when that
/// picks none and there are at least 2.
fn every_nth(scenes: &[String], every: usize) -> Vec<String> {
    let every = every.max(2);
    let mut picked: Vec<String> = scenes
        .iter()
        .enumerate()
        .filter(|(i, _)| i % every == every - 1)
        .map(|(_, s)| s.clone())
        .collect();
    if picked.is_empty() && scenes.len() >= 2 {
        picked.push(scenes[scenes.len() - 1].clone());
    }
    picked
}

/// Split samples into training, validation and test sets; nothing is ever selected on test.
///
/// 1. The index has `train` and `val` splits (`prepare` writes them: a synthetic world's own
///    lists, or the released lists with a fixed validation subset of the training scenes):
///    they are used, and `test` is the `test` split (possibly empty).
/// 2. The index has `train` (and maybe `test`) but no `val` (prepared before validation
///    splits existed): the validation scenes are every `every`-th training scene by name.
/// 3. No split lists (`--split all`): scenes sorted by name; positions ≡ every−1 (mod every)
///    are test, positions ≡ every−2 are validation, the rest train (at least one scene each
///    when there are ≥ 3 scenes).
///
/// Deterministic; the scene names of val and test are recorded.
pub fn partition(ds: &Dataset, every: usize) -> Result<Partition, DataError> {
    let names = ds.split_names();
    if names.contains("train") && names.contains("val") {
        return Ok(Partition::of_sets(
            "splits (train / val / test of index.json)".into(),
            ds.split("train"),
            ds.split("val"),
            ds.split("test"),
        ));
    }
    if names.contains("train") {
        return Ok(partition_train_split(ds, every));
    }
    partition_scene_modulo(ds, every)
}

impl Partition {
    /// The partition of these three sets, with their scene names recorded.
    fn of_sets(
        method: String,
        train: Vec<IndexEntry>,
        val: Vec<IndexEntry>,
        test: Vec<IndexEntry>,
    ) -> Partition {
        Partition {
            method,
            val_scenes: scene_names(&val),
            test_scenes: scene_names(&test),
            train,
            val,
            test,
        }
    }
}

/// Mode 2 of [`partition`]: a `train` split but no `val`; every `every`-th training scene by
/// name is validation, `test` is the `test` split.
fn partition_train_split(ds: &Dataset, every: usize) -> Partition {
    let train_all = ds.split("train");
    let val_scenes = every_nth(&scene_names(&train_all), every);
    let (val, train): (Vec<_>, Vec<_>) = train_all
        .into_iter()
        .partition(|e| val_scenes.contains(&e.scene_name));
    Partition::of_sets(
        format!(
            "train split, every {}th training scene by name held out for validation",
            every.max(2)
        ),
        train,
        val,
        ds.split("test"),
    )
}

/// Mode 3 of [`partition`]: no split lists; test and validation scenes by position modulo
/// `every` among the scenes sorted by name.
fn partition_scene_modulo(ds: &Dataset, every: usize) -> Result<Partition, DataError> {
    let mut scenes = ds.scenes();
    scenes.sort();
    if scenes.len() < 3 {
        return Err(DataError::TooFewScenes {
            root: ds.root.clone(),
            scenes: scenes.len(),
        });
    }
    let every = every.max(3);
    let (val_scenes, test_scenes) = modulo_val_test_scenes(&scenes, every);
    let of = |set: &[String]| -> Vec<IndexEntry> {
        ds.index
            .samples
            .iter()
            .filter(|e| set.contains(&e.scene_name))
            .cloned()
            .collect()
    };
    let train: Vec<IndexEntry> = ds
        .index
        .samples
        .iter()
        .filter(|e| !val_scenes.contains(&e.scene_name) && !test_scenes.contains(&e.scene_name))
        .cloned()
        .collect();
    Ok(Partition::of_sets(
        format!(
            "scene-modulo (no split lists: of the scenes sorted by name, every {every}th is test, \
             the one before it validation)"
        ),
        train,
        of(&val_scenes),
        of(&test_scenes),
    ))
}

/// (validation, test) scenes of sorted `scenes` (at least 3): positions ≡ every−2 and
/// ≡ every−1 (mod `every`), the second-last and last scene when that picks none.
fn modulo_val_test_scenes(scenes: &[String], every: usize) -> (Vec<String>, Vec<String>) {
    let mut test_scenes: Vec<String> = Vec::new();
    let mut val_scenes: Vec<String> = Vec::new();
    for (i, s) in scenes.iter().enumerate() {
        if i % every == every - 1 {
            test_scenes.push(s.clone());
        } else if i % every == every - 2 {
            val_scenes.push(s.clone());
        }
    }
    if test_scenes.is_empty() {
        test_scenes.push(scenes[scenes.len() - 1].clone());
    }
    if val_scenes.is_empty() {
        val_scenes.push(scenes[scenes.len() - 2].clone());
    }
    (val_scenes, test_scenes)
}

/// At most `max` entries, evenly spaced (all of them for `None`, 0 or fewer entries).
pub fn subsample(entries: &[IndexEntry], max: Option<usize>) -> Vec<IndexEntry> {
    match max {
        Some(m) if m > 0 && entries.len() > m => (0..m)
            .map(|i| entries[i * entries.len() / m].clone())
            .collect(),
        _ => entries.to_vec(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use depthsense_prep::layout::{IndexEntry, IMAGE_FILE};

    /// A prepared folder of one sample whose image is `w`×`h`; `frame_size` in the index.
    fn folder(w: u32, h: u32, in_index: bool) -> (tempfile::TempDir, Dataset) {
        let d = tempfile::tempdir().unwrap();
        let entry = IndexEntry {
            sample_token: "s0".into(),
            scene_token: "t0".into(),
            scene_name: "scene-0".into(),
            splits: vec!["train".into()],
            conditions: vec![],
            dir: "s0".into(),
        };
        std::fs::create_dir_all(d.path().join("s0")).unwrap();
        image::RgbImage::new(w, h)
            .save(d.path().join("s0").join(IMAGE_FILE))
            .unwrap();
        let index = PreparedIndex {
            samples: vec![entry],
            frame_size: in_index.then_some([w, h]),
            ..PreparedIndex::default()
        };
        let json = serde_json::to_vec(&index).unwrap();
        std::fs::write(d.path().join(INDEX_FILE), json).unwrap();
        let ds = Dataset::open(d.path()).unwrap();
        (d, ds)
    }

    /// A partition without validation samples, a split-less folder of fewer than 3 scenes
    /// and an index without samples are refused with the counts and files at fault.
    #[test]
    fn partitions_that_cannot_be_made_say_why() {
        let (d, mut ds) = folder(8, 4, true);
        let root = d.path().display();
        // One training scene: none is left for validation.
        let p = partition(&ds, 5).unwrap();
        let e = p.require_train_and_val(d.path()).unwrap_err();
        assert!(matches!(
            e,
            DataError::NoTrainOrVal {
                train: 1,
                val: 0,
                ..
            }
        ));
        assert_eq!(
            e.to_string(),
            format!(
                "data: {root}: 1 training and 0 validation samples ({}): need both",
                p.method
            )
        );
        ds.index.samples[0].splits.clear();
        let e = partition(&ds, 5).unwrap_err();
        assert!(matches!(e, DataError::TooFewScenes { scenes: 1, .. }));
        assert_eq!(
            e.to_string(),
            format!("data: {root}: need at least 3 scenes for train / validation / test, found 1")
        );
        let index = d.path().join(INDEX_FILE);
        let json = serde_json::to_vec(&PreparedIndex::default()).unwrap();
        std::fs::write(&index, json).unwrap();
        let e = Dataset::open(d.path()).unwrap_err();
        assert!(matches!(&e, DataError::EmptyIndex { index: i } if i == &index));
        assert_eq!(
            e.to_string(),
            format!(
                "data: {} lists no samples: run `depthsense prepare` first",
                index.display()
            )
        );
    }

    #[test]
    fn the_frame_size_comes_from_the_index_or_an_image_header() {
        let (d, ds) = folder(96, 40, true);
        // The sample's files are gone: the index alone says the size.
        std::fs::remove_dir_all(d.path().join("s0")).unwrap();
        assert_eq!(ds.frame_size().unwrap(), (96, 40));
        // An index written before `frame_size`: the first image's header says it.
        let (d, ds) = folder(64, 24, false);
        assert_eq!(ds.frame_size().unwrap(), (64, 24));
        std::fs::remove_dir_all(d.path().join("s0")).unwrap();
        let e = ds.frame_size().unwrap_err().to_string();
        assert!(e.contains(IMAGE_FILE), "{e}");
    }
}
