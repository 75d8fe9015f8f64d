//! `predict` over a list of raw frames (`--tokens FILE`, repeated `--token`, or calibration
//! JSONs naming their images; issue 44): each frame's outputs equal those of `predict --token`
//! for it alone, byte for byte; the run says its rate and latency; unknown and repeated tokens,
//! and calibrations without their image, are refused before any work, all named at once; a
//! second run into the same folder is refused without --force.

use std::path::Path;
use std::process::Output;

use crate::common::{ok, run, synth_and_prepare, tiny_train};

fn predict(args: &[&str], cwd: &Path) -> Output {
    let base = [
        "predict",
        "--checkpoint",
        "run/best.safetensors",
        "--dataroot",
        "world",
        "--version",
        "v1.0-synth",
        "--device",
        "cpu",
    ];
    run(&[&base[..], args].concat(), cwd)
}

#[test]
fn a_token_list_gives_each_frame_what_predict_gives_it_alone() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path();
    synth_and_prepare(t, 2, 2);
    let mut c = tiny_train(&t.join("prepared"), &t.join("run"), 1);
    ok(&c.args(["--max-batches-per-epoch", "1"]).output().unwrap());
    let samples: serde_json::Value =
        serde_json::from_slice(&std::fs::read(t.join("world/v1.0-synth/sample.json")).unwrap())
            .unwrap();
    let tokens: Vec<&str> = samples
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["token"].as_str().unwrap())
        .collect();
    assert_eq!(tokens.len(), 4);
    let list = format!("# frames\n{}\n\n{}  # a comment\n", tokens[0], tokens[1]);
    std::fs::write(t.join("tokens.txt"), list).unwrap();

    // Three frames: two from the file, one from --token.
    let err = ok(&predict(
        &[
            "--tokens",
            "tokens.txt",
            "--token",
            tokens[2],
            "--jobs",
            "2",
            "--out",
            "frames",
        ],
        t,
    ));
    assert!(err.contains("3 frames written"), "{err}");
    assert!(
        err.contains("images/s") && err.contains("median") && err.contains("p99"),
        "{err}"
    );
    for tok in &tokens[..3] {
        let alone = format!("alone-{tok}");
        ok(&predict(&["--token", tok, "--out", &alone], t));
        for f in [
            "depth.png",
            "depth_color.png",
            "radar_overlay.png",
            "image.png",
        ] {
            let a = std::fs::read(t.join(&alone).join(f)).unwrap();
            let b = std::fs::read(t.join("frames").join(tok).join(f)).unwrap();
            assert!(a == b, "{tok}/{f} differs from predict --token alone");
        }
    }
    assert!(!t.join("frames").join(tokens[3]).exists());

    // Again into the same folder: refused, nothing rewritten; --force writes it again.
    let o = predict(&["--tokens", "tokens.txt", "--out", "frames"], t);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--force"));
    ok(&predict(
        &["--tokens", "tokens.txt", "--out", "frames", "--force"],
        t,
    ));

    // Unknown tokens: all named at once, before the network runs; a token listed twice.
    let o = predict(
        &["--token", "nope1,nope2", "--token", tokens[0], "--out", "x"],
        t,
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("no sample with token nope1, nope2 (of 3 listed)"),
        "{err}"
    );
    assert!(!t.join("x").exists(), "a refused list wrote x/");
    // Checked before the network loads: with no checkpoint there, the tokens are still the error.
    let o = run(
        &[
            "predict",
            "--checkpoint",
            "missing.safetensors",
            "--dataroot",
            "world",
            "--version",
            "v1.0-synth",
            "--token",
            "nope1",
            "--token",
            tokens[0],
            "--out",
            "x",
        ],
        t,
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("no sample with token nope1 (of 2 listed)"),
        "{err}"
    );
    assert!(!err.contains("missing.safetensors"), "{err}");
    let o = predict(
        &["--token", tokens[0], "--tokens", "tokens.txt", "--out", "y"],
        t,
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("listed twice"), "{err}");

    // Raw files without a dataroot: calibration JSONs naming their image, several after one
    // flag; each frame as its token gave it (raw files and tokens give one input).
    for (i, tok) in tokens[..2].iter().enumerate() {
        let c = format!("c{i}.json");
        let args = [
            "calibration",
            "--dataroot",
            "world",
            "--version",
            "v1.0-synth",
        ];
        ok(&run(
            &[&args[..], &["--token", tok, "--out", &c]].concat(),
            t,
        ));
    }
    let base = [
        "predict",
        "--checkpoint",
        "run/best.safetensors",
        "--device",
        "cpu",
    ];
    let calib = [&base[..], &["--calibration", "c0.json", "c1.json"]].concat();
    let err = ok(&run(&[&calib[..], &["--out", "raw"]].concat(), t));
    assert!(err.contains("2 frames written"), "{err}");
    for (i, tok) in tokens[..2].iter().enumerate() {
        let a = std::fs::read(t.join(format!("raw/c{i}/depth.png"))).unwrap();
        let b = std::fs::read(t.join("frames").join(tok).join("depth.png")).unwrap();
        assert!(a == b, "c{i}.json's depth differs from its token's");
    }
    // A calibration whose image is gone: named, with the way out, before any work.
    let mut c1: serde_json::Value =
        serde_json::from_slice(&std::fs::read(t.join("c1.json")).unwrap()).unwrap();
    c1["camera_file"] = "gone.jpg".into();
    std::fs::write(t.join("c2.json"), c1.to_string()).unwrap();
    let calib = [&base[..], &["--calibration", "c0.json,c2.json"]].concat();
    let o = run(&[&calib[..], &["--out", "raw2"]].concat(), t);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("1 of 2 calibrations cannot be used") && err.contains("gone.jpg"),
        "{err}"
    );
    assert!(err.contains("--image"), "{err}");
    assert!(!t.join("raw2").exists());
    // --radar belongs to one --image: with a list it is refused, not ignored.
    let calib = [&base[..], &["--calibration", "c0.json", "--radar", "a.pcd"]].concat();
    let o = run(&[&calib[..], &["--out", "raw3"]].concat(), t);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("--radar picks"),
        "{err}"
    );
}
