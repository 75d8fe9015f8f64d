//! `eval --predictions` (issue 12 item 6) and the radar-failure options of `eval`
//! (SPEC §10.8): the model's own `predict --data` outputs reproduce `eval --checkpoint`
//! (.npy exactly; 16-bit PNG within its 1/256 m quantisation), and dropping every radar is
//! `--radar-drop 1.0`.

use std::path::{Path, PathBuf};

use depthsense_data::radar_failure::RadarFailure;
use depthsense_eval::evaluate::{load_model, run_eval, write_predictions, EvalOptions};
use depthsense_metrics::{tables, EvalConfig, Protocol, Report};
use depthsense_progress::Progress;
use depthsense_score::predictions::{run_eval_predictions, PredFormat, PredictionsOptions};
use tch::Device;

use crate::common;

fn setup() -> (tempfile::TempDir, PathBuf, EvalOptions) {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    // 5 scenes × 2: held-out = the test scene of the scene-modulo partition
    depthsense_data::write_toy_dataset(&data, 5, 2, 128, 64, 9).unwrap();
    let ck = common::tiny_checkpoint(tmp.path(), (64, 128));
    let eo = EvalOptions {
        checkpoint: ck,
        data: data.clone(),
        split: "all".into(),
        device: "cpu".into(),
        jobs: 2,
        batch_size: 3,
        ..EvalOptions::default()
    };
    (tmp, data, eo)
}

fn popts(dir: &Path, data: &Path, eval: EvalConfig) -> PredictionsOptions {
    PredictionsOptions {
        dir: dir.to_path_buf(),
        data: data.to_path_buf(),
        split: "all".into(),
        val_every_scene: 5,
        eval,
        max_samples: None,
        allow_missing: false,
    }
}

fn md(r: &Report) -> String {
    tables::markdown_report(&[("m", r)])
}

#[test]
fn predict_outputs_reproduce_eval_checkpoint() {
    let _torch = crate::torch_lock();
    let (tmp, data, eo) = setup();
    let pb = Progress::hidden();
    let by_checkpoint = run_eval(&eo, &pb).unwrap();
    // --cuda-graph on the CPU: the eager path, said once, the same report.
    let graphed = EvalOptions {
        cuda_graph: true,
        ..eo.clone()
    };
    assert_eq!(run_eval(&graphed, &pb).unwrap(), by_checkpoint);
    let (loaded, _) = load_model(&eo.checkpoint, None, &[], Device::Cpu).unwrap();
    let out = tmp.path().join("preds");
    let (n, stats) =
        write_predictions(&eo, &loaded, &out, &[PredFormat::Npy, PredFormat::Png], &pb).unwrap();
    assert_eq!(n, 10);
    assert_eq!(stats.images, 10);
    assert_eq!(stats.batch_ms.len(), 10usize.div_ceil(eo.batch_size.max(1)));
    assert!(stats.images_per_s() <= stats.network_images_per_s() * 1.0001);
    assert!(stats.latency_ms(0.5) <= stats.latency_ms(0.99));

    // .npy (float32 metres): bit for bit the same report
    let (npy_rep, sum) = run_eval_predictions(&popts(&out, &data, eo.eval.clone()), &pb).unwrap();
    assert_eq!((sum.scored, sum.npy, sum.png), (10, 10, 0));
    assert_eq!(npy_rep, by_checkpoint);

    // 16-bit PNG (depth×256): the printed tables agree to their precision up to the
    // quantisation of 1/512 m per pixel
    let png_dir = tmp.path().join("png");
    std::fs::create_dir_all(&png_dir).unwrap();
    for e in std::fs::read_dir(&out).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "png") {
            std::fs::copy(&p, png_dir.join(p.file_name().unwrap())).unwrap();
        }
    }
    let (png_rep, sum) =
        run_eval_predictions(&popts(&png_dir, &data, eo.eval.clone()), &pb).unwrap();
    assert_eq!(sum.png, 10);
    for (a, b) in png_rep.rows.iter().zip(&by_checkpoint.rows) {
        assert_eq!((a.n_images, a.n_pixels), (b.n_images, b.n_pixels));
        assert!((a.metrics.mae - b.metrics.mae).abs() <= 1.0 / 512.0 + 1e-9);
        assert!((a.metrics.rmse - b.metrics.rmse).abs() <= 1.0 / 512.0 + 1e-9);
    }
    // and the printed tables agree where the quantisation does not reach the 3rd decimal
    if md(&png_rep) != md(&by_checkpoint) {
        eprintln!("PNG tables differ in the last digit (quantisation), as documented");
    }

    // RadarNet's protocol runs through the same scorer, per image
    let rn = EvalConfig {
        protocol: Protocol::Radarnet,
        ..EvalConfig::default()
    };
    let (a, _) = run_eval_predictions(&popts(&out, &data, rn.clone()), &pb).unwrap();
    let b = run_eval(
        &EvalOptions {
            eval: rn,
            ..eo.clone()
        },
        &pb,
    )
    .unwrap();
    assert_eq!(a, b);

    // a missing prediction is an error naming the folder, or skipped when allowed
    let token = depthsense_dataset::Dataset::open(&data)
        .unwrap()
        .index
        .samples[0]
        .sample_token
        .clone();
    std::fs::remove_file(out.join(format!("{token}.npy"))).unwrap();
    std::fs::remove_file(out.join(format!("{token}.png"))).unwrap();
    let e = run_eval_predictions(&popts(&out, &data, eo.eval.clone()), &pb).unwrap_err();
    assert!(e.to_string().contains("1 of 10"), "{e}");
    let mut o = popts(&out, &data, eo.eval.clone());
    o.allow_missing = true;
    let (r, sum) = run_eval_predictions(&o, &pb).unwrap();
    assert_eq!((sum.scored, sum.missing.clone()), (9, vec![token]));
    assert_eq!(r.images_seen, 9);
    // a prediction of the wrong size is refused
    let bad = tmp.path().join("bad");
    std::fs::create_dir_all(&bad).unwrap();
    for s in &depthsense_dataset::Dataset::open(&data)
        .unwrap()
        .index
        .samples
    {
        std::fs::write(
            bad.join(format!("{}.npy", s.sample_token)),
            depthsense_score::npy::encode_f32(&[1.0; 6], 2, 3),
        )
        .unwrap();
    }
    let e = run_eval_predictions(&popts(&bad, &data, eo.eval.clone()), &pb).unwrap_err();
    assert!(e.to_string().contains("3x2"), "{e}");
}

#[test]
fn dropping_every_radar_equals_radar_drop_one() {
    let _torch = crate::torch_lock();
    let (_tmp, data, eo) = setup();
    let pb = Progress::hidden();
    let full_drop = run_eval(
        &EvalOptions {
            radar_drop: 1.0,
            ..eo.clone()
        },
        &pb,
    )
    .unwrap();
    let all = run_eval(
        &EvalOptions {
            failure: RadarFailure {
                drop_radars: vec!["all".into()],
                ..Default::default()
            },
            ..eo.clone()
        },
        &pb,
    )
    .unwrap();
    assert_eq!(all, full_drop);
    // by channel names: give every sample two radars, drop both
    let ds = depthsense_dataset::Dataset::open(&data).unwrap();
    for e in &ds.index.samples {
        let p = ds.sample_dir(e).join("meta.json");
        let mut m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
        let eye = serde_json::json!([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]);
        m["cam_from_radar"] = serde_json::json!({"RADAR_FRONT": eye, "RADAR_FRONT_LEFT": eye});
        std::fs::write(&p, serde_json::to_string(&m).unwrap()).unwrap();
    }
    let named = run_eval(
        &EvalOptions {
            failure: RadarFailure {
                drop_radars: vec!["RADAR_FRONT_LEFT".into(), "RADAR_FRONT".into()],
                ..Default::default()
            },
            ..eo.clone()
        },
        &pb,
    )
    .unwrap();
    assert_eq!(named, full_drop);
    let intact = run_eval(&eo, &pb).unwrap();
    assert_ne!(
        intact, full_drop,
        "radar must matter to this network for the test to bite"
    );
    // a range cut beyond every return changes nothing; clutter changes the result
    let far = run_eval(
        &EvalOptions {
            failure: RadarFailure {
                drop_beyond_m: Some(1000.0),
                ..Default::default()
            },
            ..eo.clone()
        },
        &pb,
    )
    .unwrap();
    assert_eq!(far, intact);
}

#[test]
fn failure_experiment_tables_every_scenario() {
    let _torch = crate::torch_lock();
    use depthsense_experiments::failure::{
        parse_scenarios, run_failure, FAILURE_CSV, FAILURE_JSON, FAILURE_MD, FAILURE_PNG,
    };
    let (tmp, _data, eo) = setup();
    let sc = parse_scenarios("none;radar-drop=1;drop-radars=all;beyond=20,clutter=5").unwrap();
    assert_eq!(sc[3].failure.drop_beyond_m, Some(20.0));
    assert_eq!(sc[3].failure.clutter, 5);
    for bad in ["radar-drop=2", "beyond=-1", "wobble=1"] {
        assert!(parse_scenarios(bad).is_err(), "{bad}");
    }
    use depthsense_experiments::{ExperimentError::Spec, SpecRefusal as R};
    assert!(matches!(
        parse_scenarios("none;radar-drop=2"),
        Err(Spec(R::RadarDropOutOfRange { scenario })) if scenario == "radar-drop=2"
    ));
    assert!(matches!(
        parse_scenarios("clutter=5,wobble=1"),
        Err(Spec(R::UnreadableScenario { scenario, setting }))
            if scenario == "clutter=5,wobble=1" && setting == "wobble=1"
    ));
    assert!(matches!(
        parse_scenarios(" ; "),
        Err(Spec(R::NothingGiven("failure scenarios")))
    ));
    let out = tmp.path().join("failure");
    let mp = depthsense_progress::Board::hidden();
    let r = run_failure(&eo, &sc, &out, Some("cmd".into()), &mp).unwrap();
    for f in [FAILURE_MD, FAILURE_CSV, FAILURE_JSON, FAILURE_PNG] {
        assert!(out.join(f).is_file(), "{f}");
    }
    assert_eq!(r.results[1].report, r.results[2].report);
    assert_ne!(r.results[0].report, r.results[1].report);
    let md = std::fs::read_to_string(out.join(FAILURE_MD)).unwrap();
    assert!(md.contains("| drop-radars=all |"), "{md}");
}
