//! `depthsense`, the torch-free front: it never loads libtorch, runs the data commands alone
//! (no `depthsense-net` beside it) and hands the network commands over unchanged.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const FRONT: &str = env!("CARGO_BIN_EXE_depthsense");
const NET: &str = env!("CARGO_BIN_EXE_depthsense-net");

fn run(bin: &Path, args: &[&str]) -> Output {
    Command::new(bin)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", bin.display()))
}

/// The shared libraries the dynamic loader maps for `bin` (glibc's `ldd` mechanism).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn loaded_libraries(bin: &str) -> String {
    let o = Command::new(bin)
        .env("LD_TRACE_LOADED_OBJECTS", "1")
        .output()
        .unwrap();
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[test]
fn the_front_does_not_link_libtorch_and_the_network_binary_does() {
    let front = loaded_libraries(FRONT);
    assert!(front.contains("libc.so"), "no loader trace: {front}");
    for lib in ["libtorch", "libc10", "libcuda", "libgomp"] {
        assert!(!front.contains(lib), "depthsense loads {lib}:\n{front}");
    }
    assert!(loaded_libraries(NET).contains("libtorch_cpu"));
}

/// A copy of the front alone in a folder: whatever it runs, it runs without depthsense-net.
fn lone_front(dir: &Path) -> PathBuf {
    let bin = dir.join("depthsense");
    std::fs::copy(FRONT, &bin).unwrap();
    bin
}

#[test]
fn data_commands_run_without_the_network_binary() {
    let tmp = tempfile::tempdir().unwrap();
    let front = lone_front(tmp.path());
    let data = tmp.path().join("data");
    depthsense_data::write_toy_dataset(&data, 3, 2, 64, 32, 5).unwrap();

    // Another method's predictions: the sparse GT itself, so every error is exactly zero.
    let preds = tmp.path().join("preds");
    std::fs::create_dir_all(&preds).unwrap();
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(data.join("index.json")).unwrap()).unwrap();
    for s in index["samples"].as_array().unwrap() {
        let (token, dir) = (
            s["sample_token"].as_str().unwrap(),
            s["dir"].as_str().unwrap(),
        );
        let gt = data.join(dir).join("lidar_sparse.png");
        std::fs::copy(gt, preds.join(format!("{token}.png"))).unwrap();
    }
    let d = data.to_str().unwrap();
    let p = preds.to_str().unwrap();
    // `eval --predictions` with `bin`, into `out`: tables.json.
    let eval = |bin: &Path, out: &Path| -> serde_json::Value {
        let args = [
            "eval",
            "--predictions",
            p,
            "--data",
            d,
            "--split",
            "all",
            "--out",
        ];
        let o = Command::new(bin).args(args).arg(out).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&std::fs::read(out.join("tables.json")).unwrap()).unwrap()
    };
    let out = tmp.path().join("eval");
    let tables = eval(&front, &out);
    let mut rmse = vec![];
    collect(&tables["models"], "rmse", &mut rmse);
    assert!(!rmse.is_empty(), "no rmse in tables.json");
    assert!(rmse.iter().all(|v| *v == 0.0), "{rmse:?}");
    // The same scoring through depthsense-net: the same report.
    let tables_net = eval(Path::new(NET), &tmp.path().join("eval-net"));
    assert_eq!(tables["models"], tables_net["models"]);

    // `report` over it, and some help texts (`train`'s is parsed by the front itself).
    let page = tmp.path().join("page");
    let o = run(
        &front,
        &[
            "report",
            "--runs",
            out.to_str().unwrap(),
            "--out",
            page.to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(page.join("report.html").is_file());
    for args in [
        &["--help"][..],
        &["bench", "data", "--help"],
        &["train", "--help"],
    ] {
        let o = run(&front, args);
        assert!(
            o.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
    // `mer report` runs here too: this toy folder has no MER maps, so it fails naming the file.
    let o = run(&front, &["mer", "report", "--data", d, "--split", "all"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success()
            && err.contains("radar_mer_depth.png")
            && !err.contains("depthsense-net"),
        "{err}"
    );
}

fn collect(v: &serde_json::Value, key: &str, out: &mut Vec<f64>) {
    match v {
        serde_json::Value::Object(m) => {
            for (k, x) in m {
                match x.as_f64() {
                    Some(f) if k == key => out.push(f),
                    _ => collect(x, key, out),
                }
            }
        }
        serde_json::Value::Array(a) => a.iter().for_each(|x| collect(x, key, out)),
        _ => {}
    }
}

#[test]
fn network_commands_are_handed_to_depthsense_net() {
    // Alone, the front names the missing binary and how to get it.
    let tmp = tempfile::tempdir().unwrap();
    let front = lone_front(tmp.path());
    let o = run(&front, &["model-info", "--config", "tiny"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("depthsense-net: not found") && err.contains("make build"),
        "{err}"
    );

    // Beside it, the output and the exit code are the network binary's own.
    let via_front = run(Path::new(FRONT), &["model-info", "--config", "tiny"]);
    let direct = run(Path::new(NET), &["model-info", "--config", "tiny"]);
    assert!(via_front.status.success());
    assert_eq!(via_front.stdout, direct.stdout);
    let bad_front = run(
        Path::new(FRONT),
        &["model-info", "--config", "no-such-preset"],
    );
    let bad_net = run(
        Path::new(NET),
        &["model-info", "--config", "no-such-preset"],
    );
    assert_eq!(bad_front.status.code(), bad_net.status.code());
    assert_ne!(bad_front.status.code(), Some(0));
    assert_eq!(bad_front.stderr, bad_net.stderr);
}
