//! Reduced training data (SPEC §10.5): `--exclude` withholds exactly the documented scenes
//! (docs/guide/experiments.md, "Reduced training data"), and `experiment reduced-data` trains, tests and tables
//! its grid, resumably.

use crate::common;
use depthsense_config::device::DeviceArg;
use depthsense_config::training::HardwareOptions;

use std::collections::BTreeSet;

use depthsense_base::hash::splitmix64;
use depthsense_data::exclusion::{parse_exclusions, withheld_scenes};
use depthsense_dataset::outputs::CONFIG_FILE;
use depthsense_dataset::{partition, Dataset};
use depthsense_experiments::reduced_data::{
    parse_grid, run_reduced_data, ReducedDataOptions, CSV_FILE, JSON_FILE, MD_FILE, PNG_FILE,
};
use depthsense_train::trainer::{TrainOptions, Trainer};

use common::{constant_depth_rmse, hidden, mtime, quick_runs, small_model};

/// The documented order key, written out independently of the library.
fn key(name: &str) -> (u64, String) {
    let mut h: u64 = 0xcbf29ce484222325;
    for b in name.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x100000001b3);
    }
    (splitmix64(h), name.to_string())
}

#[test]
fn exclude_withholds_exactly_the_documented_scenes() {
    let _torch = crate::torch_lock();
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    // 15 scenes cycling day / night / rain, 2 samples each, no split lists
    depthsense_data::write_toy_dataset(&data, 15, 2, 64, 32, 1).unwrap();
    let ds = Dataset::open(&data).unwrap();
    let part = partition(&ds, 5).unwrap();
    let train_scenes = |cond: &str| -> Vec<String> {
        let set: BTreeSet<String> = part
            .train
            .iter()
            .filter(|e| serde_json::to_string(&e.conditions).unwrap().contains(cond))
            .map(|e| e.scene_name.clone())
            .collect();
        set.into_iter().collect()
    };
    let night = train_scenes("night");
    let mut rain = train_scenes("rain");
    assert!(night.len() >= 2 && rain.len() >= 3, "{night:?} {rain:?}");
    rain.sort_by_key(|n| key(n));
    let half = (0.5 * rain.len() as f64).round() as usize;
    let mut expected: Vec<String> = night.clone();
    expected.extend(rain[..half].iter().cloned());
    expected.sort();

    let ex = parse_exclusions("night=1.0,rain=0.5").unwrap();
    assert_eq!(withheld_scenes(&part.train, &ex), expected);
    // fraction 0 withholds nothing; the rule ignores the seed and the other scenes
    assert!(withheld_scenes(&part.train, &parse_exclusions("rain=0").unwrap()).is_empty());
    assert_eq!(
        withheld_scenes(
            &part.train[..part.train.len() / 2],
            &parse_exclusions("night=1").unwrap()
        )
        .len(),
        night
            .iter()
            .filter(|n| part.train[..part.train.len() / 2]
                .iter()
                .any(|e| &e.scene_name == *n))
            .count()
    );
    for bad in ["night", "dusk=1", "rain=1.5", "night=x"] {
        assert!(parse_exclusions(bad).is_err(), "{bad}");
    }

    // the trainer withholds them: its config.json records the smaller training set and names
    let opts = TrainOptions {
        data: data.clone(),
        out: tmp.path().join("run"),
        model: depthsense_config::ModelConfig::tiny()
            .with_options(&small_model())
            .unwrap(),
        exclude: ex,
        hardware: HardwareOptions {
            device: DeviceArg { name: "cpu".into() },
            ..Default::default()
        },
        ..TrainOptions::default()
    };
    let _t = Trainer::open(&opts).unwrap();
    let cfg: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(opts.out.join(CONFIG_FILE)).unwrap())
            .unwrap();
    let n_train = cfg["partition"]["train_samples"].as_u64().unwrap() as usize;
    assert_eq!(n_train, part.train.len() - 2 * expected.len());
    let method = cfg["partition"]["method"].as_str().unwrap();
    assert!(
        expected.iter().all(|s| method.contains(s.as_str())),
        "{method}"
    );
    // and the options round-trip through config.json (resume compares them)
    assert_eq!(
        cfg["train"]["exclude"][0],
        serde_json::json!({"condition": "night", "fraction": 1.0})
    );
    // without --exclude the key is absent (older runs keep their fingerprint)
    let plain = serde_json::to_value(TrainOptions::default()).unwrap();
    assert!(plain.get("exclude").is_none());
}

#[test]
fn reduced_data_grid_trains_tables_and_resumes() {
    let _torch = crate::torch_lock();
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    depthsense_data::write_toy_dataset(&data, 10, 2, 64, 32, 2).unwrap();
    let out = tmp.path().join("rd");
    let opts = ReducedDataOptions {
        run: quick_runs(&data),
        out: out.clone(),
        grid: parse_grid("full;night=1").unwrap(),
        seeds: vec![0],
        eval: Default::default(),
        command_line: Some("test".into()),
    };
    let r = run_reduced_data(&opts, &hidden()).unwrap();
    for f in [MD_FILE, CSV_FILE, JSON_FILE, PNG_FILE] {
        assert!(out.join(f).is_file(), "{f}");
    }
    assert_eq!(r.runs.len(), 2);
    assert!(r.cells[1].train_samples < r.cells[0].train_samples);
    assert!(!r.cells[1].withheld_scenes.is_empty());
    let md = std::fs::read_to_string(out.join(MD_FILE)).unwrap();
    assert!(
        md.contains("| night=1 |") && md.contains("| full |"),
        "{md}"
    );
    let baseline = constant_depth_rmse(&data, &r.partition.test_scenes);
    for cell in ["full", "night=1"] {
        let rmse = r.row(cell, "combined").and_then(|x| x.rmse).unwrap().mean;
        eprintln!("{cell}: RMSE {rmse} m, constant-depth baseline {baseline} m");
        assert!(
            rmse > 0.0 && rmse < baseline,
            "{cell}: {rmse} vs {baseline}"
        );
    }
    // second invocation: every run is read back from its eval.json
    let eval_json = r.runs[1].run_dir.join("eval.json");
    let before = mtime(&eval_json);
    let again = run_reduced_data(&opts, &hidden()).unwrap();
    assert_eq!(mtime(&eval_json), before);
    let rm = |x: &depthsense_experiments::reduced_data::ReducedDataResult, c: &str| {
        x.row(c, "combined").and_then(|r| r.rmse).unwrap().mean
    };
    for c in ["full", "night=1"] {
        assert!((rm(&again, c) - rm(&r, c)).abs() < 1e-12);
    }
}
