//! Shared by the multi-process tests of the binary: a child that is killed when a test fails,
//! and waits with a deadline.
#![allow(dead_code)] // each test binary uses its own part

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Child, Command, ExitStatus};
use std::time::Duration;

/// Kills the child when dropped (a failing assertion must not leave it running).
pub struct Guard(pub Option<Child>);

impl Guard {
    pub fn new(c: Child) -> Self {
        Guard(Some(c))
    }

    pub fn child(&mut self) -> &mut Child {
        self.0.as_mut().expect("the child was taken")
    }

    /// Whether it has ended.
    pub fn ended(&mut self) -> bool {
        self.child().try_wait().unwrap().is_some()
    }

    /// Wait for the end, at most `limit` (then kill it and fail).
    pub fn wait(mut self, limit: Duration) -> ExitStatus {
        let mut c = self.0.take().unwrap();
        depthsense_testkit::wait_within(&mut c, limit)
            .unwrap_or_else(|| panic!("child did not finish within {limit:?}"))
    }

    /// SIGKILL and reap.
    pub fn kill(mut self) {
        let mut c = self.0.take().unwrap();
        let _ = c.kill();
        let _ = c.wait();
    }
}

impl Drop for Guard {
    fn drop(&mut self) {
        if let Some(c) = self.0.as_mut() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// How the tests prepare a synthetic world `world` (v1.0-synth, no lidar sweeps) into
/// `prepared`.
pub const PREPARE: [&str; 9] = [
    "prepare",
    "--dataroot",
    "world",
    "--version",
    "v1.0-synth",
    "--lidar-sweeps",
    "0",
    "--out",
    "prepared",
];

/// `depthsense synth` of a world `world` in `cwd` (`scenes` × `keyframes`), prepared into
/// `prepared` as PREPARE does.
pub fn synth_and_prepare(cwd: &Path, scenes: u32, keyframes: u32) {
    let (scenes, keyframes) = (scenes.to_string(), keyframes.to_string());
    let synth = [
        "synth",
        "--out",
        "world",
        "--scenes",
        &scenes,
        "--keyframes-per-scene",
        &keyframes,
    ];
    ok(&run(&synth, cwd));
    ok(&run(&PREPARE, cwd));
}

/// Asserts that a command succeeded (its stderr in the message); its stderr.
pub fn ok(o: &std::process::Output) -> String {
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{err}");
    err
}

/// `depthsense ARGS` in `cwd`, without the distributed environment; its output.
pub fn run(args: &[&str], cwd: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_depthsense"))
        .args(args)
        .current_dir(cwd)
        .env_remove("WORLD_SIZE")
        .env_remove("RANK")
        .output()
        .unwrap()
}

/// `depthsense train` of a narrow `tiny` network on `data` (a toy dataset), batch 2, on one CPU
/// thread of the loader, validating on 2 samples; without the distributed environment.
pub fn tiny_train(data: &Path, out: &Path, epochs: u32) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_depthsense"));
    c.args(["train", "--data"])
        .arg(data)
        .arg("--out")
        .arg(out)
        .args([
            "--config",
            "tiny",
            "--set",
            "width=8",
            "--set",
            "decoder-channels=16",
        ])
        .args(["--set", "head-channels=16", "--set", "radar-width=8"])
        .args(["--batch-size", "2", "--device", "cpu", "--jobs", "1"])
        .args(["--max-val-samples", "2", "--epochs"])
        .arg(epochs.to_string())
        .env_remove("WORLD_SIZE")
        .env_remove("RANK");
    c
}

/// The tensors of a safetensors checkpoint.
pub fn tensors(p: &Path) -> BTreeMap<String, Vec<u8>> {
    let bytes = std::fs::read(p).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let data = &bytes[8 + n..];
    header
        .as_object()
        .unwrap()
        .iter()
        .filter(|(k, _)| *k != "__metadata__")
        .map(|(k, v)| {
            let o = &v["data_offsets"];
            let (a, b) = (
                o[0].as_u64().unwrap() as usize,
                o[1].as_u64().unwrap() as usize,
            );
            (k.clone(), data[a..b].to_vec())
        })
        .collect()
}
