//! `O/index.json` and the shard indexes: reading (a corrupt file is an error, never replaced),
//! the one-settings-per-folder rule, the lock that makes several `prepare` processes on one
//! `--out` safe, stale temporary folders, and `depthsense index merge`.
//!
//! Concurrency rules for one output folder:
//! - a sample is assembled in `.tmp-<pid>-<sample_token>` and renamed into place; when the
//!   final folder is already complete (another process finished it first) the copy is dropped;
//! - start-up removes only the temporary folders of processes that are no longer running
//!   (`/proc/<pid>` absent; where there is no `/proc`, none);
//! - `index.json` and `index.shard-I-of-N.json` are read, checked and rewritten while holding
//!   `.index.lock` (an advisory `flock`, released by the kernel when its holder dies), and
//!   written by atomic rename;
//! - every `prepare` holds a shared lock of the folder (`.depthsense.lock`) and `index merge` an
//!   exclusive one, so neither runs beside `mer apply` or a merge.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::time::Duration;

use depthsense_base::fsutil::write_atomic;
use depthsense_base::lock::OutputLock;

use crate::error::PrepError;
use crate::layout::{self, IndexEntry, PreparedIndex};

/// How long to wait for another process's index lock.
pub const LOCK_WAIT: Duration = Duration::from_secs(120);

/// Whether process `pid` is running: it exists and is neither a zombie (killed, not yet reaped
/// by its parent — a `prepare` killed under a shell or a job runner stays one for a while) nor
/// dead. Without `/proc` nothing can be told: every other process counts as running.
pub fn pid_alive(pid: u32) -> bool {
    if pid == std::process::id() {
        return true;
    }
    let proc_dir = Path::new("/proc");
    if !proc_dir.join("self").exists() {
        return true;
    }
    let Ok(stat) = std::fs::read_to_string(proc_dir.join(pid.to_string()).join("stat")) else {
        return false;
    };
    // `pid (comm) S …`: the state follows the last ')' (comm may hold anything).
    let state = stat
        .rsplit_once(')')
        .and_then(|(_, rest)| rest.trim_start().chars().next());
    !matches!(state, None | Some('Z') | Some('X') | Some('x'))
}

/// The held index lock (an advisory `flock` on `out/.index.lock`, released on drop or when the
/// process ends; [`depthsense_base::lock`]).
pub type IndexLock = OutputLock;

/// Take `out/.index.lock`, waiting up to [`LOCK_WAIT`] for the running holder (the lock of a
/// process that died is released by the kernel).
pub fn lock_index(out: &Path) -> Result<IndexLock, PrepError> {
    Ok(OutputLock::wait_exclusive(
        &out.join(layout::INDEX_LOCK_FILE),
        "depthsense prepare (index update)",
        LOCK_WAIT,
    )?)
}

/// Read an index file: `None` when it does not exist, an error naming the file when it cannot
/// be read or parsed (it is never silently replaced).
pub fn read_index(path: &Path) -> Result<Option<PreparedIndex>, PrepError> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(PrepError::output(path, e)),
    };
    serde_json::from_slice(&bytes)
        .map(Some)
        .map_err(|source| PrepError::CorruptIndex {
            path: path.to_path_buf(),
            source,
        })
}

/// Refuse an index of another dataset version or with other map settings.
pub fn check_index(
    path: &Path,
    index: &PreparedIndex,
    version: &str,
    settings: &BTreeMap<String, serde_json::Value>,
) -> Result<(), PrepError> {
    if !index.version.is_empty() && index.version != version {
        return Err(PrepError::VersionMismatch {
            path: path.to_path_buf(),
            old: index.version.clone(),
            new: version.to_string(),
        });
    }
    if index.settings.is_empty() {
        return Ok(());
    }
    match first_difference(&index.settings, settings) {
        None => Ok(()),
        Some(d) => Err(PrepError::SettingsMismatch {
            path: path.to_path_buf(),
            what: d.key,
            old: d.old,
            new: d.new,
        }),
    }
}

/// A setting whose value differs between two settings maps, with both values as JSON (`null`
/// where a map lacks the key).
struct SettingDifference {
    key: String,
    old: String,
    new: String,
}

/// The first setting (in key order) whose value differs between `old` and `new`.
fn first_difference(
    old: &BTreeMap<String, serde_json::Value>,
    new: &BTreeMap<String, serde_json::Value>,
) -> Option<SettingDifference> {
    let keys: std::collections::BTreeSet<&String> = old.keys().chain(new.keys()).collect();
    keys.into_iter().find_map(|k| {
        let (o, n) = (
            old.get(k).unwrap_or(&serde_json::Value::Null),
            new.get(k).unwrap_or(&serde_json::Value::Null),
        );
        (o != n).then(|| SettingDifference {
            key: k.clone(),
            old: o.to_string(),
            new: n.to_string(),
        })
    })
}

/// Index files of a folder: `index.json` (if present) and every `index.shard-*.json`, sorted.
pub fn index_files(dir: &Path) -> Result<Vec<PathBuf>, PrepError> {
    let mut out = Vec::new();
    let rd = match std::fs::read_dir(dir) {
        Ok(rd) => rd,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(out),
        Err(e) => return Err(PrepError::output(dir, e)),
    };
    for e in rd {
        let e = e.map_err(|e| PrepError::output(dir, e))?;
        let name = e.file_name().to_string_lossy().into_owned();
        if name == layout::INDEX_FILE
            || (name.starts_with("index.shard-") && name.ends_with(".json"))
        {
            out.push(e.path());
        }
    }
    out.sort();
    Ok(out)
}

/// Parse `.tmp-<pid>-<token>` (this version) or `.tmp-<token>-<pid>` (before issue 10).
fn temp_dir_pid(name: &str) -> Option<u32> {
    let rest = name.strip_prefix(".tmp-")?;
    let (a, b) = rest.split_once('-')?;
    if !a.is_empty() && a.bytes().all(|c| c.is_ascii_digit()) {
        return a.parse().ok();
    }
    let b = b.rsplit('-').next().unwrap_or(b);
    b.parse().ok()
}

/// Name of this process's temporary folder for a sample.
pub fn temp_dir_name(sample_token: &str) -> String {
    format!(".tmp-{}-{sample_token}", std::process::id())
}

/// The process id in the name of an atomic write's temporary sibling
/// (`.index.json.<pid>.tmp`, `depthsense_base::fsutil::temp_sibling`).
fn temp_file_pid(name: &str) -> Option<u32> {
    let stem = name.strip_prefix('.')?.strip_suffix(".tmp")?;
    stem.rsplit_once('.')?.1.parse().ok()
}

/// Remove temporary sample folders, and the temporary siblings of atomic writes (an index
/// written when the process was killed), of processes that are no longer running (never those
/// of a running process: another `prepare` may be writing there). Returns how many went.
pub fn remove_stale_temp_dirs(out: &Path) -> usize {
    let Ok(rd) = std::fs::read_dir(out) else {
        return 0;
    };
    let mut removed = 0;
    for e in rd.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let is_dir = e.file_type().is_ok_and(|t| t.is_dir());
        let gone = match (temp_dir_pid(&name), temp_file_pid(&name)) {
            (Some(pid), _) if is_dir => {
                !pid_alive(pid) && std::fs::remove_dir_all(e.path()).is_ok()
            }
            (_, Some(pid)) if !is_dir => !pid_alive(pid) && std::fs::remove_file(e.path()).is_ok(),
            _ => false,
        };
        removed += usize::from(gone);
    }
    removed
}

/// Add or replace `entries` (by sample token) in `index`, keeping its order.
pub fn merge_entries(index: &mut PreparedIndex, entries: impl IntoIterator<Item = IndexEntry>) {
    let mut pos: HashMap<String, usize> = index
        .samples
        .iter()
        .enumerate()
        .map(|(i, e)| (e.sample_token.clone(), i))
        .collect();
    for e in entries {
        match pos.get(&e.sample_token) {
            Some(&i) => index.samples[i] = e,
            None => {
                pos.insert(e.sample_token.clone(), index.samples.len());
                index.samples.push(e);
            }
        }
    }
}

/// Write an index atomically.
pub fn write_index_file(path: &Path, index: &PreparedIndex) -> Result<(), PrepError> {
    let bytes =
        serde_json::to_vec_pretty(index).map_err(|e| PrepError::encode(path.display(), e))?;
    write_atomic(path, &bytes).map_err(|e| PrepError::output(path, e))
}

/// What `depthsense index merge` did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MergeSummary {
    /// Index files read.
    pub sources: Vec<PathBuf>,
    /// Samples in the merged index.
    pub samples: usize,
    /// Sample folders moved into the output folder from other folders.
    pub moved: usize,
}

/// One index file to merge: (source file, its folder, index).
type Source = (PathBuf, PathBuf, PreparedIndex);

/// `depthsense index merge OUT [DIR...]`: combine the shard indexes of `out` (and the
/// `index.json` and shard indexes of each other folder in `others`, whose sample folders are
/// moved into `out`) into `out/index.json`, which keeps its own entries. Refuses sources of
/// another version or with other map settings (naming both files), a shard set with a missing
/// part, and shard sets of different N. The merged order is the unsharded run's: shard scene
/// lists are interleaved (scene j came from shard j mod N).
/// A refusal leaves no output folder behind that the merge created.
pub fn merge(out: &Path, others: &[PathBuf]) -> Result<MergeSummary, PrepError> {
    let created = !out.exists();
    std::fs::create_dir_all(out).map_err(|e| PrepError::output(out, e))?;
    let merged = merge_into(out, others);
    if merged.is_err() && created {
        remove_if_only_locks(out);
    }
    merged
}

/// Removes `out` when it holds nothing but this crate's two lock files (a merge refused before
/// anything moved) and nobody holds its lock; anything else in it keeps it.
fn remove_if_only_locks(out: &Path) {
    let locks = [depthsense_base::lock::LOCK_FILE, layout::INDEX_LOCK_FILE];
    let Ok(_lock) = OutputLock::exclusive(out, "depthsense index merge") else {
        return;
    };
    let Ok(entries) = std::fs::read_dir(out) else {
        return;
    };
    let only_locks = entries.into_iter().all(|e| {
        e.is_ok_and(|e| {
            locks
                .iter()
                .any(|l| e.file_name() == std::ffi::OsStr::new(l))
        })
    });
    if only_locks {
        for l in locks {
            let _ = std::fs::remove_file(out.join(l));
        }
        let _ = std::fs::remove_dir(out);
    }
}

fn merge_into(out: &Path, others: &[PathBuf]) -> Result<MergeSummary, PrepError> {
    let _writing = lock_folders(out, others)?;
    let _lock = lock_index(out)?;
    let target = out.join(layout::INDEX_FILE);
    let mut merged = read_index(&target)?.unwrap_or_default();
    let sources = merge_sources(out, others, &target)?;
    // One version and one set of settings across everything, the target included.
    let (ref_path, ref_index) = if merged.settings.is_empty() && merged.version.is_empty() {
        (sources[0].0.clone(), sources[0].2.clone())
    } else {
        (target.clone(), merged.clone())
    };
    check_sources_agree(&sources, &ref_path, &ref_index)?;
    let shard_set = check_shard_set(out, &sources)?;
    let mut summary = MergeSummary {
        sources: sources.iter().map(|s| s.0.clone()).collect(),
        ..Default::default()
    };
    summary.moved = move_sample_folders(out, &sources)?;
    let ordered = merged_order(&sources, shard_set.as_ref());
    let first = &sources[0].2;
    merged.version = ref_index.version.clone();
    merged.settings = ref_index.settings.clone();
    merged.frame_size = ref_index.frame_size;
    merged.shard = None;
    if merged.split_source.is_empty() {
        merged.split_source = first.split_source.clone();
        merged.train_scenes = first.train_scenes.clone();
        merged.val_scenes = first.val_scenes.clone();
        merged.test_scenes = first.test_scenes.clone();
    }
    merge_entries(&mut merged, ordered);
    summary.samples = merged.samples.len();
    write_index_file(&target, &merged)?;
    Ok(summary)
}

/// Nobody else writes the folders while samples move and the index is rewritten: the
/// exclusive locks of `out` and of every folder of `others`, held while the result lives.
fn lock_folders(out: &Path, others: &[PathBuf]) -> Result<Vec<OutputLock>, PrepError> {
    let mut writing = vec![OutputLock::exclusive(out, "depthsense index merge")?];
    for o in others {
        writing.push(OutputLock::exclusive(o, "depthsense index merge")?);
    }
    Ok(writing)
}

/// The index files to merge: the shard indexes of `out` (not `target`), then every index of
/// each other folder; an error when there is none, or another folder holds none.
fn merge_sources(out: &Path, others: &[PathBuf], target: &Path) -> Result<Vec<Source>, PrepError> {
    let mut sources: Vec<Source> = Vec::new();
    for p in index_files(out)? {
        if p != target {
            if let Some(ix) = read_index(&p)? {
                sources.push((p, out.to_path_buf(), ix));
            }
        }
    }
    for d in others {
        if d == out {
            continue;
        }
        let files = index_files(d)?;
        if files.is_empty() {
            return Err(PrepError::NoIndexToMerge { dir: d.clone() });
        }
        for p in files {
            if let Some(ix) = read_index(&p)? {
                sources.push((p, d.clone(), ix));
            }
        }
    }
    if sources.is_empty() {
        return Err(PrepError::NothingToMerge {
            out: out.to_path_buf(),
        });
    }
    Ok(sources)
}

/// Every source has the reference's version and settings (`ref_path` is named beside the
/// source that differs).
fn check_sources_agree(
    sources: &[Source],
    ref_path: &Path,
    ref_index: &PreparedIndex,
) -> Result<(), PrepError> {
    for (p, _, ix) in sources {
        let difference = if ix.version != ref_index.version {
            Some(SettingDifference {
                key: "dataset version".to_string(),
                old: format!("{:?}", ref_index.version),
                new: format!("{:?}", ix.version),
            })
        } else {
            first_difference(&ref_index.settings, &ix.settings)
        };
        if let Some(d) = difference {
            return Err(PrepError::IndexesDisagree {
                path: p.clone(),
                against: ref_path.to_path_buf(),
                what: d.key,
                old: d.old,
                new: d.new,
            });
        }
    }
    Ok(())
}

/// The shard set among the sources: N and, for each shard index, its position in `sources`.
struct ShardSet {
    count: usize,
    source_of: BTreeMap<usize, usize>,
}

/// Shard sets must be complete and of one N; `None` when no source is a shard index.
fn check_shard_set(out: &Path, sources: &[Source]) -> Result<Option<ShardSet>, PrepError> {
    let shard_counts: std::collections::BTreeSet<usize> = sources
        .iter()
        .filter_map(|(_, _, ix)| ix.shard.as_ref().map(|s| s.count))
        .collect();
    if shard_counts.len() > 1 {
        return Err(PrepError::MixedShardCounts {
            out: out.to_path_buf(),
            counts: shard_counts,
        });
    }
    let mut shards: BTreeMap<usize, usize> = BTreeMap::new();
    for (i, (_, _, ix)) in sources.iter().enumerate() {
        if let Some(s) = &ix.shard {
            if shards.insert(s.index, i).is_some() {
                return Err(PrepError::DuplicateShard {
                    index: s.index,
                    count: s.count,
                });
            }
        }
    }
    let Some(&n) = shard_counts.iter().next() else {
        return Ok(None);
    };
    let missing: Vec<usize> = (0..n).filter(|i| !shards.contains_key(i)).collect();
    if !missing.is_empty() {
        return Err(PrepError::MissingShards { missing, count: n });
    }
    Ok(Some(ShardSet {
        count: n,
        source_of: shards,
    }))
}

/// Move sample folders of other folders into `out`; returns how many moved.
fn move_sample_folders(out: &Path, sources: &[Source]) -> Result<usize, PrepError> {
    let mut moved = 0;
    for (p, dir, ix) in sources {
        if dir == out {
            continue;
        }
        for e in &ix.samples {
            let src = dir.join(&e.dir);
            let dst = out.join(&e.dir);
            if dst.join(layout::META_FILE).is_file() {
                continue;
            }
            if !src.join(layout::META_FILE).is_file() {
                return Err(PrepError::IncompleteSource {
                    sample: src,
                    index: p.to_path_buf(),
                });
            }
            if dst.exists() {
                std::fs::remove_dir_all(&dst).map_err(|e| PrepError::output(&dst, e))?;
            }
            std::fs::rename(&src, &dst).map_err(|source| PrepError::CannotMove {
                from: src.clone(),
                to: dst.clone(),
                source,
            })?;
            moved += 1;
        }
    }
    Ok(moved)
}

/// Order: shards interleaved by scene, then other sources in file order.
fn merged_order(sources: &[Source], shard_set: Option<&ShardSet>) -> Vec<IndexEntry> {
    let mut ordered: Vec<IndexEntry> = Vec::new();
    if let Some(set) = shard_set {
        interleave_shards(sources, set, &mut ordered);
    }
    for (_, _, ix) in sources.iter().filter(|s| s.2.shard.is_none()) {
        ordered.extend(ix.samples.iter().cloned());
    }
    ordered
}

/// The shards' entries as one unsharded run orders them: scene k of every shard in shard
/// order, for k = 0, 1, … (scene j of the selection went to shard j mod N).
fn interleave_shards(sources: &[Source], set: &ShardSet, ordered: &mut Vec<IndexEntry>) {
    let (n, shards) = (set.count, &set.source_of);
    let by_scene: Vec<HashMap<&str, Vec<&IndexEntry>>> = (0..n)
        .map(|i| {
            let mut m: HashMap<&str, Vec<&IndexEntry>> = HashMap::new();
            for e in &sources[shards[&i]].2.samples {
                m.entry(e.scene_token.as_str()).or_default().push(e);
            }
            m
        })
        .collect();
    let lists: Vec<&Vec<String>> = (0..n)
        .map(|i| {
            &sources[shards[&i]]
                .2
                .shard
                .as_ref()
                .expect("shard sources carry ShardInfo")
                .scenes
        })
        .collect();
    let longest = lists.iter().map(|l| l.len()).max().unwrap_or(0);
    for k in 0..longest {
        for i in 0..n {
            if let Some(scene) = lists[i].get(k) {
                if let Some(es) = by_scene[i].get(scene.as_str()) {
                    ordered.extend(es.iter().map(|e| (*e).clone()));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_killed_process_not_yet_reaped_is_not_alive() {
        if !Path::new("/proc/self/stat").exists() {
            return; // nothing can be told without /proc
        }
        let mut running = std::process::Command::new("sleep")
            .arg("30")
            .spawn()
            .unwrap();
        assert!(pid_alive(running.id()));
        running.kill().unwrap();
        // Killed, not reaped yet: a zombie until `wait`.
        let t = std::time::Instant::now();
        while pid_alive(running.id()) {
            assert!(
                t.elapsed() < Duration::from_secs(10),
                "still alive after SIGKILL"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        assert!(
            Path::new("/proc").join(running.id().to_string()).exists(),
            "a zombie"
        );
        running.wait().unwrap();
        assert!(!pid_alive(running.id()));
        assert!(pid_alive(std::process::id()));
    }

    #[test]
    fn temp_dir_names_carry_the_pid() {
        assert_eq!(temp_dir_pid(".tmp-1234-abcdef"), Some(1234));
        assert_eq!(temp_dir_pid(".tmp-abcdef-99"), Some(99));
        assert_eq!(temp_dir_pid(".tmp-abc"), None);
        assert_eq!(temp_dir_pid("abc"), None);
        assert!(temp_dir_name("tok").starts_with(&format!(".tmp-{}-", std::process::id())));
    }

    #[test]
    fn index_lock_is_exclusive_and_a_stale_record_does_not_block() {
        let d = tempfile::tempdir().unwrap();
        // The record of a process that died holding it: no flock, so no obstacle.
        std::fs::write(d.path().join(layout::INDEX_LOCK_FILE), "pid=4000000000\n").unwrap();
        let l = lock_index(d.path()).unwrap();
        let other = OutputLock::wait_exclusive(
            &d.path().join(layout::INDEX_LOCK_FILE),
            "test",
            std::time::Duration::from_millis(50),
        );
        assert!(other.is_err(), "the index lock is exclusive");
        drop(l);
        let _l = lock_index(d.path()).unwrap();
    }

    #[test]
    fn stale_temp_dirs_of_dead_processes_only() {
        let d = tempfile::tempdir().unwrap();
        let dead = d.path().join(".tmp-4000000000-aaaa");
        let running = d.path().join(format!(".tmp-{}-bbbb", 1)); // pid 1 runs
        std::fs::create_dir_all(&dead).unwrap();
        std::fs::create_dir_all(&running).unwrap();
        // An index written by a process killed between its temporary sibling and the rename.
        let dead_file = d.path().join(".index.json.4000000000.tmp");
        let live_file = d
            .path()
            .join(format!(".index.json.{}.tmp", std::process::id()));
        std::fs::write(&dead_file, "{").unwrap();
        std::fs::write(&live_file, "{").unwrap();
        assert_eq!(remove_stale_temp_dirs(d.path()), 2);
        assert!(!dead.exists() && !dead_file.exists());
        assert!(
            live_file.exists(),
            "a running process's temporary file stays"
        );
        assert!(running.exists() || !Path::new("/proc/1").exists());
        assert_eq!(temp_file_pid(".index.json.77.tmp"), Some(77));
        assert_eq!(temp_file_pid("index.json"), None);
    }
}
