//! `depthsense demo --quick` end to end: synth → prepare → train RGB-only and fusion → eval →
//! report files.

use crate::common;

use depthsense_experiments::demo::{run_demo, DemoOptions};
use depthsense_progress::Board;

#[test]
fn quick_demo_writes_the_report() {
    let _torch = crate::torch_lock();
    let tmp = tempfile::tempdir().unwrap();
    let opts = DemoOptions {
        out: tmp.path().join("demo"),
        device: "cpu".into(),
        quick: true,
        // 20 epochs of 4 batches of 2 instead of --quick's 2: enough to beat the constant-depth
        // baseline (measured: RMSE 9.7 m RGB, 10.6 m fusion against 14.2 m; with 2 or 8
        // epochs neither model beats it)
        epochs: Some(20),
        jobs: 2,
        pictures: 1,
        ..DemoOptions::default()
    };
    let mp = Board::hidden();
    let s = run_demo(&opts, &mp).unwrap();
    let r = &s.report_dir;
    for f in [
        "README.md",
        "summary.json",
        "tables.md",
        "tables.csv",
        "tables.json",
        "curves_rgb.png",
        "curves_fusion.png",
        "val_rmse.png",
    ] {
        assert!(r.join(f).exists(), "{f} missing");
    }
    let baseline = common::constant_depth_rmse(&opts.out.join("prepared"), &s.test_scenes);
    eprintln!(
        "RMSE: rgb {} m (untrained {} m), fusion {} m (untrained {} m), constant-depth baseline {baseline} m",
        s.rgb_rmse, s.rgb_initial_rmse, s.fusion_rmse, s.fusion_initial_rmse
    );
    assert!(s.rgb_rmse < baseline && s.fusion_rmse < baseline);
    // The training-set size and the iterations are in the summary: 20 epochs of at most 4
    // batches of 2.
    assert!(s.train_samples > 0);
    assert_eq!(
        s.iterations,
        20 * s.train_samples.div_ceil(2).min(4) as u64,
        "{s:?}"
    );
    let readme = std::fs::read_to_string(r.join("README.md")).unwrap();
    assert!(
        readme.contains(&format!("{} distinct images", s.train_samples)),
        "{readme}"
    );
    // Selected on val, reported on test: two disjoint, non-empty scene lists in summary.json.
    let sj: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(r.join("summary.json")).unwrap()).unwrap();
    let names =
        |k: &str| -> Vec<String> { serde_json::from_value(sj["summary"][k].clone()).unwrap() };
    let (val, test) = (names("val_scenes"), names("test_scenes"));
    assert!(!val.is_empty() && !test.is_empty(), "{sj}");
    assert!(
        val.iter().all(|v| !test.contains(v)),
        "val {val:?} test {test:?}"
    );
    let md = std::fs::read_to_string(r.join("tables.md")).unwrap();
    assert!(
        md.contains("| rgb | combined |") && md.contains("| fusion | combined |"),
        "{md}"
    );
    let samples: Vec<_> = std::fs::read_dir(r.join("samples")).unwrap().collect();
    assert_eq!(samples.len(), 1);
    let dir = samples[0].as_ref().unwrap().path();
    for f in [
        "image.png",
        "radar.png",
        "gt.png",
        "pred_rgb.png",
        "pred_fusion.png",
        "err_rgb.png",
        "err_fusion.png",
        "row.png",
    ] {
        assert!(dir.join(f).exists(), "{f} missing");
    }
    // One self-contained page: the demo's README (headline, commands, tables), the curves
    // and every sample row, with the invocation.
    let html = std::fs::read_to_string(r.join("report.html")).unwrap();
    assert!(
        html.contains("Demo: RGB-only vs radar fusion"),
        "no demo section"
    );
    assert!(
        html.contains("depthsense train --data"),
        "stage commands missing"
    );
    assert!(
        html.contains("| model |") || html.contains("<table"),
        "tables missing"
    );
    let images = html.matches("<img src=\"data:image/png;base64,").count();
    assert_eq!(images, 3 + 1, "val_rmse, two curves and one sample row");
    assert!(!html.contains("src=\"http") && !html.contains("src=\"img/"));
    // The page's section comes from the same discovery `depthsense report` uses.
    let page = depthsense_report::render(&depthsense_report::ReportOptions {
        runs: vec![tmp.path().join("demo")],
        out: tmp.path().join("page"),
        ..Default::default()
    })
    .unwrap();
    let kinds: Vec<_> = page.0.sections.iter().map(|s| s.kind).collect();
    assert_eq!(
        kinds,
        [
            depthsense_report::Kind::Models,
            depthsense_report::Kind::Demo
        ]
    );
    // Its two models on the test scenes and its two runs' validations, in separate tables; the
    // headline difference is said to be one seed (issue 42).
    let models = page.0.sections[0].doc.to_markdown();
    let (test, val) = models
        .split_once("# Validation")
        .expect("a validation table");
    assert!(
        test.contains("| rgb | demo | ") && test.contains("| fusion | demo | "),
        "{models}"
    );
    assert!(test.contains("one seed: not a finding"), "{models}");
    assert_eq!(val.matches(" | finished | ").count(), 2, "{models}");
    assert!(readme.contains("(one seed: not a finding;"), "{readme}");

    // A second demo into the same folder is refused and changes nothing.
    let before = std::fs::read(r.join("summary.json")).unwrap();
    let e = run_demo(&opts, &mp).unwrap_err().to_string();
    assert!(
        e.contains("already holds a finished demo") && e.contains("--force"),
        "{e}"
    );
    assert_eq!(std::fs::read(r.join("summary.json")).unwrap(), before);
}

#[test]
fn demo_plans_fit_the_device() {
    let _torch = crate::torch_lock();
    use depthsense_experiments::demo::{demo_model, plan};
    let cpu = plan(&DemoOptions::default(), false);
    // A lean 60-scene world and 10 × 35 = 350 iterations whatever its training-set size
    // (issue 34's choice of distinct images over repeats).
    assert_eq!(
        (
            cpu.preset.as_str(),
            cpu.scenes,
            cpu.epochs,
            cpu.epoch_iterations
        ),
        ("tiny", 60, 10, Some(35))
    );
    assert!(cpu.lean);
    // The paper's fusion model: attention on, the preset's (width-scaled) head dropout.
    assert!(cpu.attention && cpu.dropout > 0.0);
    assert_eq!(cpu.dropout, depthsense_config::ModelConfig::tiny().dropout);
    let gpu = plan(&DemoOptions::default(), true);
    assert!(gpu.scenes >= cpu.scenes && gpu.epochs > cpu.epochs);
    // The wide variant builds (names and shapes valid).
    let cfg = demo_model(&gpu.preset).unwrap();
    assert_eq!(cfg.backbone_depth, 34);
    let vs = tch::nn::VarStore::new(tch::Device::Cpu);
    depthsense_model::DepthNet::new(&vs.root(), &cfg).unwrap();
    let quick = plan(
        &DemoOptions {
            quick: true,
            ..DemoOptions::default()
        },
        false,
    );
    assert!(quick.scenes * quick.keyframes_per_scene <= 20);
    // --scenes / --keyframes-per-scene override the plan (also a quick one)
    let sized = plan(
        &DemoOptions {
            quick: true,
            scenes: Some(20),
            keyframes_per_scene: Some(12),
            ..DemoOptions::default()
        },
        false,
    );
    assert_eq!((sized.scenes, sized.keyframes_per_scene), (20, 12));
}
