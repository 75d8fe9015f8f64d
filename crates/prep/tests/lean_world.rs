//! The lean world (`synth --lean`, issue 34): what it leaves out is what `prepare` does not read.
//! A world without the lidar and radar sweeps prepare skips and without truth maps prepares to
//! exactly the files of the full world (same seed); the lean world itself loads in the
//! official devkit.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use depthsense_prep::{prepare, PrepareOptions};
use depthsense_progress::Progress;
use depthsense_synth::{generate, SynthConfig};

fn files_under(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            if p.is_dir() {
                stack.push(p);
            } else if !name.starts_with('.') {
                out.insert(
                    p.strip_prefix(dir).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    out
}

fn prepared(tmp: &Path, name: &str, cfg: &SynthConfig) -> PathBuf {
    let root = tmp.join(name);
    let s = generate(&root, cfg, &Progress::hidden()).unwrap();
    eprintln!("{name}: {} sample_data, {} bytes", s.sample_data, s.bytes);
    let out = tmp.join(format!("{name}-prepared"));
    let opts = PrepareOptions {
        dataroot: root,
        version: cfg.version_name.clone(),
        out: out.clone(),
        lidar_sweeps: 2,
        radar_sweeps: 5,
        jobs: 1,
        ..Default::default()
    };
    let r = prepare(&opts, &Progress::hidden()).unwrap();
    assert!(r.failed.is_empty(), "{:?}", r.failed);
    out
}

#[test]
fn leaving_out_what_prepare_does_not_read_changes_no_prepared_byte() {
    let tmp = tempfile::tempdir().unwrap();
    let full = SynthConfig::tiny();
    let mut lean = SynthConfig::tiny();
    lean.apply_lean();
    // The camera as the full world's, to compare every prepared byte.
    (lean.camera_scale, lean.jpeg_420) = (1, false);
    let a = files_under(&prepared(tmp.path(), "full", &full));
    let b = files_under(&prepared(tmp.path(), "lean", &lean));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (p, bytes) in &a {
        if p == Path::new("index.json") {
            // It names the dataroot its split lists came from: the two folders differ there.
            let strip = |b: &[u8]| {
                let mut v: serde_json::Value = serde_json::from_slice(b).unwrap();
                v.as_object_mut().unwrap().remove("split_source");
                v
            };
            assert_eq!(strip(bytes), strip(&b[p]));
            continue;
        }
        assert!(b[p] == *bytes, "{} differs", p.display());
    }
    let size = |d: &str| {
        files_under(&tmp.path().join(d))
            .values()
            .map(Vec::len)
            .sum::<usize>()
    };
    assert!(size("lean") < size("full"), "the lean world is smaller");
}

#[test]
fn the_lean_world_loads_in_the_official_devkit() {
    let Some(py) = depthsense_testkit::python_with_devkit() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let mut cfg = SynthConfig::tiny();
    cfg.apply_lean();
    let root = tmp.path().join("lean");
    generate(&root, &cfg, &Progress::hidden()).unwrap();
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scripts/devkit_check.py");
    let out = std::process::Command::new(&py)
        .arg(&script)
        .arg("--dataroot")
        .arg(&root)
        .args(["--version", &cfg.version_name, "--samples", "6"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "devkit check failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(v["failures"].as_array().unwrap().len(), 0, "{v}");
    assert!(v["radar_points_in_image"].as_u64().unwrap() > 0, "{v}");
}
