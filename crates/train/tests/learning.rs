//! The network learns (issue: sound initialisation): the tiny preset *with* the spatial
//! attention module and its head dropout leaves the label marginal (one depth everywhere)
//! within its first epoch, and the radar input a model was trained on travels with it.

use depthsense_config::device::DeviceArg;
use depthsense_config::training::{HardwareOptions, LoadingOptions, ScheduleOptions};
use std::path::Path;

use depthsense_checkpoint as checkpoint;
use depthsense_config::{ModelConfig, RadarInput};
use depthsense_data::LoadOptions;
use depthsense_dataset::outputs::{BEST_CKPT, LAST_CKPT};
use depthsense_dataset::{partition, Dataset};
use depthsense_infer::run::evaluate_net;
use depthsense_progress::Progress;
use depthsense_train::trainer::{train, TrainOptions};

/// libtorch's generator is process-wide: tests that train hold this lock so that each run's
/// initial weights come from its own seed.
static TORCH_RNG: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn torch_rng() -> std::sync::MutexGuard<'static, ()> {
    TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner())
}

const W: u32 = 128;
const H: u32 = 64;

fn toy(dir: &Path, scenes: usize, per_scene: usize) -> Dataset {
    depthsense_data::write_toy_dataset(dir, scenes, per_scene, W, H, 4).unwrap();
    Dataset::open(dir).unwrap()
}

/// One step of a narrow tiny network on a toy dataset of 3 scenes × 2 samples in `dir`, on the
/// CPU: a run to check what is stored and refused, not what is learnt.
fn one_step_run(dir: &Path) -> TrainOptions {
    let data = dir.join("data");
    toy(&data, 3, 2);
    let mut model = ModelConfig::tiny();
    model.backbone_width = 8;
    model.radar_width = 8;
    TrainOptions {
        data,
        out: dir.join("run"),
        model,
        schedule: ScheduleOptions {
            epochs: 1,
            batch_size: 2,
            max_batches_per_epoch: Some(1),
            ..Default::default()
        },
        loading: LoadingOptions {
            jobs: 1,
            ..Default::default()
        },
        hardware: HardwareOptions {
            device: DeviceArg { name: "cpu".into() },
            ..Default::default()
        },
        ..TrainOptions::default()
    }
}

/// Per-image standard deviation of `v` over `mask`.
fn std_over(v: &[f32], mask: &[bool]) -> f64 {
    let x: Vec<f64> = v
        .iter()
        .zip(mask)
        .filter(|(_, m)| **m)
        .map(|(a, _)| *a as f64)
        .collect();
    let n = x.len().max(1) as f64;
    let mean = x.iter().sum::<f64>() / n;
    (x.iter().map(|a| (a - mean).powi(2)).sum::<f64>() / n).sqrt()
}

#[test]
fn tiny_network_with_attention_leaves_the_label_marginal_in_its_first_epoch() {
    let _rng = torch_rng();
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let ds = toy(&data, 20, 8);
    let model = ModelConfig::tiny(); // late fusion + attention, the preset's head dropout
    assert!(model.attention && model.dropout > 0.0);
    let opts = TrainOptions {
        data: data.clone(),
        out: tmp.path().join("run"),
        model,
        schedule: ScheduleOptions {
            epochs: 1,
            batch_size: 4,
            lr: 3e-3,
            seed: 0,
            ..Default::default()
        },
        loading: LoadingOptions {
            jobs: 2,
            prefetch: 2,
            ..Default::default()
        },
        hardware: HardwareOptions {
            device: DeviceArg { name: "cpu".into() },
            ..Default::default()
        },
        ..TrainOptions::default()
    };
    train(&opts, &Progress::hidden()).unwrap();
    let loaded = checkpoint::load(&opts.out.join(LAST_CKPT), tch::Device::Cpu).unwrap();
    let part = partition(&ds, opts.validation.val_every_scene).unwrap();
    let radar = loaded.config.radar_input_for(None).unwrap();
    let load = LoadOptions {
        radar: radar.unwrap_or_default(),
        no_radar: radar.is_none(),
        ..LoadOptions::default()
    };
    // Spread of the predicted depth within each image against the spread of the truth: a
    // network on the label marginal predicts (nearly) one depth everywhere.
    let mut ratios = vec![];
    evaluate_net(
        &loaded.net,
        &ds,
        &part.val,
        &load,
        &Default::default(),
        4,
        2,
        tch::Device::Cpu,
        &Progress::hidden(),
        |batch, preds| {
            let hw = batch.width * batch.height;
            for (i, s) in batch.samples.iter().enumerate() {
                let mask: Vec<bool> = s.sparse_m.iter().map(|d| *d > 0.0).collect();
                let p = &preds[i * hw..(i + 1) * hw];
                ratios.push(std_over(p, &mask) / std_over(&s.sparse_m, &mask).max(1e-6));
            }
            Ok(())
        },
    )
    .unwrap();
    let mean_ratio = ratios.iter().sum::<f64>() / ratios.len() as f64;
    assert!(
        mean_ratio > 0.3,
        "predicted depth spread is {mean_ratio:.3} of the truth's after one epoch: \
         the network sits on the label marginal"
    );
}

#[test]
fn the_radar_input_is_stored_with_the_model_and_used_by_eval() {
    let _rng = torch_rng();
    let tmp = tempfile::tempdir().unwrap();
    let mut opts = one_step_run(tmp.path());
    opts.radar_input = Some(RadarInput::Raw);
    opts.schedule.seed = 1;
    train(&opts, &Progress::hidden()).unwrap();
    let loaded = checkpoint::load(&opts.out.join(BEST_CKPT), tch::Device::Cpu).unwrap();
    assert_eq!(loaded.config.radar_input, RadarInput::Raw);
    // eval / predict / demo derive the input from the checkpoint: raw, not height-extended.
    assert_eq!(
        loaded.config.radar_input_for(None).unwrap(),
        Some(RadarInput::Raw)
    );
    // An explicit request with the wrong channel count is refused, naming both.
    let err = loaded
        .config
        .radar_input_for(Some(RadarInput::RawHeight))
        .unwrap_err();
    assert!(err.to_string().contains("raw-height"), "{err}");
}

/// A continued run is refused with the values at fault, as typed refusals a caller can match:
/// another schedule on `--resume`, no more epochs on `--extend`, nothing to extend.
#[test]
fn a_continued_run_is_refused_with_the_values_at_fault() {
    use depthsense_config::refusal::TrainingRefusal as R;
    use depthsense_config::training::{CheckpointOptions, ExtendOptions};
    use depthsense_infer::NetError;
    let _rng = torch_rng();
    let tmp = tempfile::tempdir().unwrap();
    let opts = one_step_run(tmp.path());
    let refusal = |o: &TrainOptions| match train(o, &Progress::hidden()) {
        Err(NetError::Refused(r)) => r,
        other => panic!("not refused: {other:?}"),
    };
    let extend = |o: &TrainOptions| TrainOptions {
        extension: ExtendOptions { extend: true },
        ..o.clone()
    };
    assert!(matches!(refusal(&extend(&opts)), R::NothingToExtend { .. }));
    train(&opts, &Progress::hidden()).unwrap();
    let mut other_lr = opts.clone();
    other_lr.schedule.lr = 0.5;
    other_lr.checkpointing = CheckpointOptions {
        resume: true,
        ..Default::default()
    };
    match refusal(&other_lr) {
        R::OtherSchedule {
            stored, requested, ..
        } => assert_eq!((stored.lr, requested.lr), (opts.schedule.lr, 0.5)),
        r => panic!("{r}"),
    }
    assert_eq!(
        refusal(&extend(&opts)),
        R::ExtendWithoutMoreEpochs {
            checkpoint: opts.out.join(LAST_CKPT),
            epochs: 1
        }
    );
}
