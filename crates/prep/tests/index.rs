//! The prepared index cannot mix runs (issue 10 defect 5), and sharded preparation merges to
//! exactly what one run gives (issue 10 "scale past one machine"), on a synthetic world.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use depthsense_prep::index::merge;
use depthsense_prep::layout::{self, PreparedIndex};
use depthsense_prep::{prepare, PrepError, PrepareOptions, Shard};
use depthsense_progress::Progress;
use depthsense_synth::{generate, SynthConfig};

/// 5 scenes × 2 keyframes (3 train, 2 test scenes), generated once for the whole file.
fn world() -> &'static (tempfile::TempDir, PathBuf, String) {
    static W: OnceLock<(tempfile::TempDir, PathBuf, String)> = OnceLock::new();
    W.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("world");
        let cfg = SynthConfig {
            scenes: 5,
            keyframes_per_scene: 2,
            ..SynthConfig::tiny()
        };
        generate(&root, &cfg, &Progress::hidden()).unwrap();
        (dir, root, cfg.version_name)
    })
}

fn opts(out: &Path) -> PrepareOptions {
    let (_, root, version) = world();
    PrepareOptions {
        dataroot: root.clone(),
        version: version.clone(),
        out: out.to_path_buf(),
        radar_sweeps: 1,
        lidar_sweeps: 1,
        jobs: 2,
        ..Default::default()
    }
}

fn run(o: &PrepareOptions) -> Result<depthsense_prep::PrepareSummary, PrepError> {
    prepare(o, &Progress::hidden())
}

fn read_index(p: &Path) -> PreparedIndex {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

/// Every file under `dir` except the index files and the lock, by relative path.
fn sample_files(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            for f in std::fs::read_dir(&p).unwrap() {
                let f = f.unwrap().path();
                out.insert(
                    f.strip_prefix(dir).unwrap().to_path_buf(),
                    std::fs::read(&f).unwrap(),
                );
            }
        }
    }
    out
}

#[test]
fn corrupt_index_fails_and_is_not_replaced() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let mut o = opts(&out);
    o.split = "all".into();
    o.lidar_sweeps = 0;
    run(&o).unwrap();
    let idx = out.join(layout::INDEX_FILE);
    std::fs::write(&idx, b"{\"version\": \"v1.0-synth\", \"samples\": [tru").unwrap();
    let err = run(&o).unwrap_err();
    assert!(matches!(err, PrepError::CorruptIndex { .. }), "{err}");
    let msg = err.to_string();
    assert!(
        msg.contains("index.json") && msg.contains("unreadable"),
        "{msg}"
    );
    assert_eq!(
        std::fs::read(&idx).unwrap(),
        b"{\"version\": \"v1.0-synth\", \"samples\": [tru"
    );
    // Another dataset version in the index is refused, not overwritten.
    std::fs::remove_file(&idx).unwrap();
    run(&o).unwrap();
    let mut ix = read_index(&idx);
    ix.version = "v1.0-trainval".into();
    std::fs::write(&idx, serde_json::to_vec(&ix).unwrap()).unwrap();
    let msg = run(&o).unwrap_err().to_string();
    assert!(
        msg.contains("v1.0-trainval") && msg.contains("v1.0-synth"),
        "{msg}"
    );
    assert_eq!(read_index(&idx).version, "v1.0-trainval");
}

#[test]
fn other_settings_are_refused_even_for_samples_not_yet_prepared() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let mut o = opts(&out);
    o.split = "train".into();
    let s = run(&o).unwrap();
    assert!(s.prepared > 0 && s.failed.is_empty(), "{s:?}");
    let ix = read_index(&out.join(layout::INDEX_FILE));
    assert_eq!(ix.settings["lidar_sweeps_k"], serde_json::json!(1));
    // Other samples (the test scenes), other K: before issue 10 only an already prepared
    // sample of this run was compared, so this mixed K = 1 and K = 3 in one folder.
    let mut o2 = opts(&out);
    o2.split = "test".into();
    o2.lidar_sweeps = 3;
    let err = run(&o2).unwrap_err();
    let msg = err.to_string();
    assert!(
        matches!(err, PrepError::SettingsMismatch { .. })
            && msg.contains("lidar_sweeps_k")
            && msg.contains("1 there")
            && msg.contains("3 now")
            && msg.contains("index.json"),
        "{msg}"
    );
    // Same settings: the test scenes join the index.
    o2.lidar_sweeps = 1;
    let s2 = run(&o2).unwrap();
    let ix2 = read_index(&out.join(layout::INDEX_FILE));
    assert_eq!(ix2.samples.len(), ix.samples.len() + s2.prepared);
}

#[test]
fn temp_folders_of_running_processes_are_left_alone() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    // pid 1 always runs; 4e9 is no process.
    let alive = out.join(".tmp-1-0123456789abcdef0123456789abcdef");
    let dead = out.join(".tmp-4000000000-0123456789abcdef0123456789abcdef");
    std::fs::create_dir_all(&alive).unwrap();
    std::fs::create_dir_all(&dead).unwrap();
    let mut o = opts(&out);
    o.lidar_sweeps = 0;
    o.split = "test".into();
    run(&o).unwrap();
    assert!(
        alive.exists(),
        "another process's work in progress was deleted"
    );
    assert!(!dead.exists());
    // The index lock is released: another process could take it at once.
    let _l = depthsense_base::lock::OutputLock::wait_exclusive(
        &out.join(layout::INDEX_LOCK_FILE),
        "test",
        std::time::Duration::ZERO,
    )
    .unwrap();
}

#[test]
fn three_shards_then_merge_equal_one_run() {
    let tmp = tempfile::tempdir().unwrap();
    let whole = tmp.path().join("whole");
    let s = run(&opts(&whole)).unwrap();
    assert_eq!((s.prepared, s.failed.len()), (10, 0), "{:?}", s.failed);
    let whole_index = read_index(&whole.join(layout::INDEX_FILE));

    // (a) Shards into one shared folder (a cluster file system), then merge in place.
    let shared = tmp.path().join("shared");
    let mut counts = Vec::new();
    for i in 0..3 {
        let mut o = opts(&shared);
        o.shard = Some(Shard { index: i, count: 3 });
        counts.push(run(&o).unwrap().prepared);
        if i == 1 {
            // Two of three: the merge refuses and names the missing part.
            let msg = merge(&shared, &[]).unwrap_err().to_string();
            assert!(msg.contains("index.shard-2-of-3.json"), "{msg}");
            assert!(!shared.join(layout::INDEX_FILE).exists());
        }
    }
    // By scene: 5 scenes → 2, 2, 1 scenes of 2 keyframes.
    assert_eq!(counts, vec![4, 4, 2]);
    // Another K cannot join the shard set.
    let mut bad = opts(&shared);
    bad.shard = Some(Shard { index: 0, count: 3 });
    bad.lidar_sweeps = 2;
    let msg = run(&bad).unwrap_err().to_string();
    assert!(msg.contains("lidar_sweeps_k"), "{msg}");
    let m = merge(&shared, &[]).unwrap();
    assert_eq!(m.samples, 10);
    assert_eq!(read_index(&shared.join(layout::INDEX_FILE)), whole_index);
    assert_eq!(
        std::fs::read(shared.join(layout::INDEX_FILE)).unwrap(),
        std::fs::read(whole.join(layout::INDEX_FILE)).unwrap()
    );
    assert_eq!(sample_files(&shared), sample_files(&whole));

    // (b) Shards in separate folders (one per machine), merged into a new one.
    let parts: Vec<PathBuf> = (0..3)
        .map(|i| tmp.path().join(format!("part{i}")))
        .collect();
    for (i, p) in parts.iter().enumerate() {
        let mut o = opts(p);
        o.shard = Some(Shard { index: i, count: 3 });
        run(&o).unwrap();
    }
    let merged = tmp.path().join("merged");
    let m = merge(&merged, &parts).unwrap();
    assert_eq!((m.samples, m.moved), (10, 10));
    assert_eq!(read_index(&merged.join(layout::INDEX_FILE)), whole_index);
    assert_eq!(sample_files(&merged), sample_files(&whole));
}

#[test]
fn shard_spec_parses_i_of_n() {
    assert_eq!(
        "3/16".parse::<Shard>().unwrap(),
        Shard {
            index: 3,
            count: 16
        }
    );
    for bad in ["16/16", "1", "a/3", "0/0"] {
        assert!(bad.parse::<Shard>().is_err(), "{bad}");
    }
}

/// `index merge` of two folders prepared differently names both index files and the first
/// difference (the dataset version, else a map setting), and moves nothing.
#[test]
fn merge_refuses_indexes_prepared_differently() {
    let tmp = tempfile::tempdir().unwrap();
    let folder = |name: &str, version: &str, k: i64| {
        let dir = tmp.path().join(name);
        std::fs::create_dir_all(&dir).unwrap();
        let mut ix = PreparedIndex {
            version: version.into(),
            ..Default::default()
        };
        ix.settings
            .insert("lidar_sweeps_k".into(), serde_json::json!(k));
        let json = serde_json::to_vec(&ix).unwrap();
        std::fs::write(dir.join(layout::INDEX_FILE), json).unwrap();
        dir
    };
    let (a, b) = (folder("a", "v1.0-mini", 1), folder("b", "v1.0-mini", 3));
    let c = folder("c", "v1.0-trainval", 1);
    let merged = tmp.path().join("merged");

    let err = merge(&merged, &[a.clone(), b.clone()]).unwrap_err();
    let PrepError::IndexesDisagree {
        path,
        against,
        what,
        old,
        new,
    } = &err
    else {
        panic!("{err}");
    };
    assert_eq!(path, &b.join(layout::INDEX_FILE));
    assert_eq!(against, &a.join(layout::INDEX_FILE));
    assert_eq!(
        (what.as_str(), old.as_str(), new.as_str()),
        ("lidar_sweeps_k", "1", "3")
    );
    let msg = err.to_string();
    assert!(msg.contains("lidar_sweeps_k is 3, but 1 in"), "{msg}");

    let err = merge(&merged, &[a, c]).unwrap_err();
    assert!(
        matches!(&err, PrepError::IndexesDisagree { what, .. } if what == "dataset version"),
        "{err}"
    );
    // Nothing left behind: the output folder the refused merges created is gone again.
    assert!(!merged.exists());
}
