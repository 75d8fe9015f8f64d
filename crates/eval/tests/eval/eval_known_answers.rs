//! The evaluation wiring against answers known without our scorer (issue 23): predictions that
//! are the ground truth, the ground truth + 1 m, and a network whose output is a known constant.
//! The expected numbers and every pixel count are computed here straight from the prepared PNG
//! files (read with the `image` crate, depth = value/256, SPEC §3), per condition and for the
//! low-height mask (SPEC §4, §9): so the sparse and dense targets, or the mask, cannot be
//! swapped unseen.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use depthsense_checkpoint as checkpoint;
use depthsense_config::ModelConfig;
use depthsense_eval::evaluate::{run_eval, EvalOptions};
use depthsense_metrics::{EvalConfig, Report, CONDITIONS};
use depthsense_model::{sid, DepthNet};
use depthsense_progress::Progress;
use depthsense_score::predictions::{
    run_eval_predictions, write_prediction, PredFormat, PredictionsOptions,
};
use tch::{nn::VarStore, Device};

const W: u32 = 128;
const H: u32 = 64;

/// One prepared sample as read here: conditions, sparse GT (m), low-height mask.
struct Truth {
    token: String,
    conditions: Vec<String>,
    sparse_m: Vec<f64>,
    low: Vec<bool>,
}

fn read_png16_m(p: &Path) -> Vec<f64> {
    let img = image::open(p).unwrap().into_luma16();
    img.pixels().map(|px| px.0[0] as f64 / 256.0).collect()
}

/// The toy dataset (5 scenes × 2, conditions day/night/rain cycling) and its truth, read
/// from the files: `index.json`, `lidar_sparse.png`, `lowheight_mask.png`.
fn dataset(root: &Path) -> Vec<Truth> {
    depthsense_data::write_toy_dataset(root, 5, 2, W, H, 9).unwrap();
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(root.join("index.json")).unwrap()).unwrap();
    let samples = index["samples"].as_array().unwrap();
    samples
        .iter()
        .map(|s| {
            let dir = root.join(s["dir"].as_str().unwrap());
            let sparse_m = read_png16_m(&dir.join("lidar_sparse.png"));
            let dense = read_png16_m(&dir.join("lidar_dense.png"));
            // the two targets must differ for the test to tell them apart
            assert!(
                dense.iter().filter(|d| **d > 0.0).count()
                    > sparse_m.iter().filter(|d| **d > 0.0).count()
            );
            let low = image::open(dir.join("lowheight_mask.png"))
                .unwrap()
                .into_luma8()
                .pixels()
                .map(|p| p.0[0] > 127)
                .collect();
            Truth {
                token: s["sample_token"].as_str().unwrap().to_string(),
                conditions: s["conditions"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|c| c.as_str().unwrap().to_lowercase())
                    .collect(),
                sparse_m,
                low,
            }
        })
        .collect()
}

/// Per (condition, region, cap): images, pixels and the per-image-averaged MAE, RMSE and
/// AbsRel of prediction `pred(truth, pixel)` (SPEC §9, mask protocol, per-image aggregation,
/// prediction clipped to [1, 80] m).
type Expected = BTreeMap<RowKey, (u64, u64, f64, f64, f64)>;
/// (condition, region, cap in m).
type RowKey = (String, String, u64);

fn expected(truth: &[Truth], caps: &[f64], pred: impl Fn(&Truth, usize) -> f64) -> Expected {
    let mut acc = Expected::new();
    for t in truth {
        for region in ["full", "lowheight"] {
            for cap in caps {
                let (mut n, mut ae, mut se, mut rel) = (0u64, 0.0, 0.0, 0.0);
                for (i, gt) in t.sparse_m.iter().enumerate() {
                    if *gt <= 0.0 || *gt > *cap || (region == "lowheight" && !t.low[i]) {
                        continue;
                    }
                    let p = pred(t, i).clamp(1.0, 80.0);
                    n += 1;
                    ae += (p - gt).abs();
                    se += (p - gt) * (p - gt);
                    rel += (p - gt).abs() / gt;
                }
                if n == 0 {
                    continue;
                }
                let nf = n as f64;
                for c in std::iter::once("combined".to_string()).chain(t.conditions.clone()) {
                    let e = acc.entry((c, region.into(), *cap as u64)).or_default();
                    e.0 += 1;
                    e.1 += n;
                    e.2 += ae / nf;
                    e.3 += (se / nf).sqrt();
                    e.4 += rel / nf;
                }
            }
        }
    }
    for v in acc.values_mut() {
        let k = v.0 as f64;
        (v.2, v.3, v.4) = (v.2 / k, v.3 / k, v.4 / k);
    }
    acc
}

/// Every row of `report` with data equals the expectation (counts exactly, metrics to 1e-9 m),
/// and every expected row is in the report.
fn check(report: &Report, want: &Expected) {
    let mut seen = 0;
    for r in &report.rows {
        let key = (r.condition.clone(), r.region.clone(), r.cap_m as u64);
        let Some((imgs, px, mae, rmse, rel)) = want.get(&key) else {
            assert_eq!(r.n_pixels, 0, "row {key:?} has pixels the files do not");
            continue;
        };
        seen += 1;
        assert_eq!(
            (r.n_images, r.n_pixels),
            (*imgs, *px),
            "row {key:?}: images, pixels"
        );
        let m = &r.metrics;
        assert!(
            (m.mae - mae).abs() < 1e-9,
            "row {key:?}: MAE {} vs {mae}",
            m.mae
        );
        assert!(
            (m.rmse - rmse).abs() < 1e-9,
            "row {key:?}: RMSE {} vs {rmse}",
            m.rmse
        );
        assert!(
            (m.abs_rel - rel).abs() < 1e-9,
            "row {key:?}: AbsRel {} vs {rel}",
            m.abs_rel
        );
    }
    assert_eq!(seen, want.len(), "rows missing from the report");
    // all four condition rows and the low-height region are exercised
    for c in CONDITIONS {
        if c != "rain" || want.keys().any(|k| k.0 == "rain") {
            assert!(want.keys().any(|k| k.0 == c && k.1 == "lowheight"), "{c}");
        }
    }
}

fn popts(dir: &Path, data: &Path) -> PredictionsOptions {
    PredictionsOptions {
        dir: dir.to_path_buf(),
        data: data.to_path_buf(),
        split: "all".into(),
        val_every_scene: 5,
        eval: EvalConfig::default(),
        max_samples: None,
        allow_missing: false,
    }
}

#[test]
fn ground_truth_as_prediction_scores_zero_error() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let truth = dataset(&data);
    let preds = tmp.path().join("preds");
    std::fs::create_dir_all(&preds).unwrap();
    for t in &truth {
        let dir = data.join(&t.token);
        std::fs::copy(
            dir.join("lidar_sparse.png"),
            preds.join(format!("{}.png", t.token)),
        )
        .unwrap();
    }
    let (report, sum) = run_eval_predictions(&popts(&preds, &data), &Progress::hidden()).unwrap();
    assert_eq!(sum.png, truth.len());
    let want = expected(&truth, &[50.0, 70.0, 80.0], |t, i| t.sparse_m[i]);
    check(&report, &want);
    for r in report.rows.iter().filter(|r| r.n_pixels > 0) {
        assert_eq!((r.metrics.rmse, r.metrics.mae), (0.0, 0.0), "{r:?}");
        assert_eq!(r.metrics.delta1, 1.0, "{r:?}");
    }
}

#[test]
fn ground_truth_plus_one_metre_has_mae_one() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let truth = dataset(&data);
    let preds = tmp.path().join("preds");
    std::fs::create_dir_all(&preds).unwrap();
    for t in &truth {
        // + 1 m where there is ground truth (the toy GT stays ≤ 79 m, so no clipping at 80)
        let p: Vec<f32> = t
            .sparse_m
            .iter()
            .map(|d| if *d > 0.0 { (*d + 1.0) as f32 } else { 0.0 })
            .collect();
        write_prediction(
            &preds,
            &t.token,
            &p,
            W as usize,
            H as usize,
            PredFormat::Npy,
        )
        .unwrap();
    }
    let (report, sum) = run_eval_predictions(&popts(&preds, &data), &Progress::hidden()).unwrap();
    assert_eq!(sum.npy, truth.len());
    let want = expected(&truth, &[50.0, 70.0, 80.0], |t, i| t.sparse_m[i] + 1.0);
    check(&report, &want);
    for r in report.rows.iter().filter(|r| r.n_pixels > 0) {
        assert_eq!((r.metrics.mae, r.metrics.rmse), (1.0, 1.0), "{r:?}");
    }
}

/// A network whose output is known: the ordinal head's last conv has zero weights and biases
/// a_k = 0, b_k = +1 for k < 40, −1 beyond, so every pixel decodes to level 40, i.e.
/// (t_40 + t_41)/2 = (√80 + 80^(41/80))/2 = 9.196068 m (SPEC §7).
fn constant_checkpoint(dir: &Path) -> (PathBuf, f64) {
    let cfg = ModelConfig::tiny()
        .with_options(&[
            "width=8",
            "decoder-channels=16",
            "head-channels=16",
            "radar-width=8",
            "out-height=64",
            "out-width=128",
        ])
        .unwrap();
    let vs = VarStore::new(Device::Cpu);
    let _net = DepthNet::new(&vs.root(), &cfg).unwrap();
    let vars = vs.variables();
    let k = cfg.sid.bins;
    let bias: Vec<f32> = (0..k)
        .flat_map(|i| [0.0, if i < 40 { 1.0 } else { -1.0 }])
        .collect();
    tch::no_grad(|| {
        let _ = vars["head.conv2.weight"].shallow_clone().zero_();
        vars["head.conv2.bias"]
            .shallow_clone()
            .copy_(&tch::Tensor::from_slice(&bias));
    });
    let p = dir.join("constant.safetensors");
    checkpoint::save(&p, &vs, &cfg, &serde_json::Value::Null).unwrap();
    let depth = (80f64.sqrt() + 80f64.powf(41.0 / 80.0)) / 2.0;
    assert!((depth - sid::depth_of_level(&cfg.sid, 40)).abs() < 1e-12);
    (p, depth)
}

#[test]
fn a_constant_network_scores_what_the_files_say() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let truth = dataset(&data);
    let (ck, depth_m) = constant_checkpoint(tmp.path());
    let opts = EvalOptions {
        checkpoint: ck,
        data: data.clone(),
        split: "all".into(),
        device: "cpu".into(),
        jobs: 2,
        batch_size: 3,
        ..EvalOptions::default()
    };
    let report = run_eval(&opts, &Progress::hidden()).unwrap();
    // the network computes in float32: its constant is 9.196068 m to float precision
    let c = depth_m as f32 as f64;
    let want = expected(&truth, &[50.0, 70.0, 80.0], |_, _| c);
    check(&report, &want);
}
