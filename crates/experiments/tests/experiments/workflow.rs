//! Loader, training (resume, non-finite loss, config mismatch), evaluation and prediction on
//! a small generated prepared dataset (128x64 frames, the `tiny` preset).

use depthsense_config::device::DeviceArg;
use depthsense_config::training::{HardwareOptions, LoadingOptions, ScheduleOptions};
use std::path::Path;

use depthsense_checkpoint as checkpoint;
use depthsense_config::{Fusion, HeadKind, ModelConfig};
use depthsense_data::{drop_radar, load_sample, Augment, EpochPlan, LoadOptions, Loader, Rng};
use depthsense_dataset::outputs::{BEST_CKPT, LAST_CKPT};
use depthsense_dataset::{partition, Dataset};
use depthsense_eval::evaluate::{run_eval, EvalOptions};
use depthsense_infer::NetError;
use depthsense_progress::Progress;
use depthsense_score::tables::write_tables;
use depthsense_train::metrics_log::read_metrics;
use depthsense_train::trainer::{train, TrainOptions};

const W: u32 = 128;
const H: u32 = 64;

fn toy(dir: &Path, scenes: usize, per_scene: usize) -> Dataset {
    depthsense_data::write_toy_dataset(dir, scenes, per_scene, W, H, 11).unwrap();
    Dataset::open(dir).unwrap()
}

fn opts(data: &Path, out: &Path, fusion: Fusion) -> TrainOptions {
    let mut model = ModelConfig::tiny();
    // Dropout2d(0.5) keeps a from-scratch tiny network from learning within a few dozen
    // steps; the short runs here switch it off (a config field).
    model.dropout = 0.0;
    model.fusion = fusion;
    if fusion != Fusion::Late {
        model.attention = false;
    }
    TrainOptions {
        data: data.to_path_buf(),
        out: out.to_path_buf(),
        model,
        schedule: ScheduleOptions {
            epochs: 10,
            batch_size: 4,
            lr: 3e-3,
            seed: 5,
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
    }
}

#[test]
fn loader_is_reproducible_whatever_the_thread_count() {
    let _torch = crate::torch_lock();
    let tmp = tempfile::tempdir().unwrap();
    let ds = toy(tmp.path(), 2, 3);
    let load = LoadOptions {
        augment: true,
        seed: 3,
        ..LoadOptions::default()
    };
    let run = |jobs: usize, seed: u64, epoch: u64| {
        let plan = EpochPlan {
            entries: ds.split("all"),
            batch_size: 2,
            epoch,
            shuffle: true,
            drop_last: false,
            skip_batches: 0,
            jobs,
            prefetch: 1,
        };
        let l = LoadOptions {
            seed,
            ..load.clone()
        };
        Loader::start(&ds, &l, &plan)
            .unwrap()
            .map(|b| {
                let b = b.unwrap();
                (
                    b.samples
                        .iter()
                        .map(|s| s.token.clone())
                        .collect::<Vec<_>>(),
                    b.image,
                    b.radar,
                    b.target_m,
                )
            })
            .collect::<Vec<_>>()
    };
    let a = run(1, 3, 0);
    assert_eq!(a.len(), 3);
    assert_eq!(a, run(2, 3, 0), "same seed, other thread count");
    assert_ne!(
        a,
        run(2, 4, 0),
        "another seed draws another order / augmentation"
    );
    assert_ne!(a, run(2, 3, 1), "another epoch draws another order");
    // Skipping batches (resume mid-epoch) yields the tail of the same epoch.
    let plan = EpochPlan {
        entries: ds.split("all"),
        batch_size: 2,
        epoch: 0,
        shuffle: true,
        drop_last: false,
        skip_batches: 1,
        jobs: 2,
        prefetch: 1,
    };
    let tail: Vec<Vec<f32>> = Loader::start(&ds, &load, &plan)
        .unwrap()
        .map(|b| b.unwrap().image)
        .collect();
    assert_eq!(tail, a[1..].iter().map(|x| x.1.clone()).collect::<Vec<_>>());
}

#[test]
fn flip_is_applied_to_image_and_every_map_alike() {
    let _torch = crate::torch_lock();
    let tmp = tempfile::tempdir().unwrap();
    let ds = toy(tmp.path(), 1, 1);
    let e = &ds.split("all")[0];
    // A draw with a flip and no colour jitter.
    let seed = (0..1000u64)
        .find(|s| {
            let a = Augment::draw(&mut Rng::new(*s));
            a.flip && a.gamma == 1.0
        })
        .unwrap();
    let base = LoadOptions {
        eval_maps: true,
        ..LoadOptions::default()
    };
    let plain = load_sample(&ds, e, &base, &mut Rng::new(seed)).unwrap();
    let aug = LoadOptions {
        augment: true,
        ..base
    };
    let flipped = load_sample(&ds, e, &aug, &mut Rng::new(seed)).unwrap();
    assert!(flipped.flipped && !plain.flipped);
    let w = W as usize;
    let mirror = |v: &[f32]| -> Vec<f32> {
        v.chunks(w)
            .flat_map(|r| r.iter().rev().copied().collect::<Vec<_>>())
            .collect()
    };
    assert_eq!(flipped.image, mirror(&plain.image));
    assert_eq!(flipped.radar, mirror(&plain.radar));
    assert_eq!(flipped.target_m, mirror(&plain.target_m));
    assert_eq!(flipped.sparse_m, mirror(&plain.sparse_m));
    assert_ne!(flipped.image, plain.image, "the toy image is not symmetric");
    // ImageNet normalisation: pixel value 128 in channel 0 → (128/255 − 0.485)/0.229.
    let jitter = Augment {
        flip: false,
        brightness: 1.1,
        colour: [1.0; 3],
        gamma: 1.0,
    };
    let img = image::RgbImage::from_pixel(2, 1, image::Rgb([128, 0, 255]));
    let n = depthsense_data::normalise_image(&img, &Augment::NONE);
    assert!((n[0] - (128.0 / 255.0 - 0.485) / 0.229).abs() < 1e-6);
    assert!((n[4] - (1.0 - 0.406) / 0.225).abs() < 1e-6);
    let j = depthsense_data::normalise_image(&img, &jitter);
    assert!((j[0] - (128.0 * 1.1 / 255.0 - 0.485) / 0.229).abs() < 1e-5);
    assert!((j[4] - n[4]).abs() < 1e-6, "brightness saturates at 1");
}

#[test]
fn radar_drop_removes_points_with_their_strips() {
    let _torch = crate::torch_lock();
    use depthsense_nuscenes::depth_png::DepthMap;
    let mut raw = DepthMap::zeros(8, 6);
    let mut height = DepthMap::zeros(8, 6);
    for u in 0..8u32 {
        let d = 5.0 + u as f32;
        raw.depth_m[(4 * 8 + u) as usize] = d;
        for v in 1..5u32 {
            height.depth_m[(v * 8 + u) as usize] = d;
        }
    }
    let (r0, h0) = (raw.clone(), height.clone());
    drop_radar(&mut raw, Some(&mut height), 0.5, 42);
    let kept = raw.valid_count();
    assert!(kept > 0 && kept < 8, "kept {kept} of 8");
    for u in 0..8usize {
        let alive = raw.depth_m[4 * 8 + u] > 0.0;
        for v in 1..5usize {
            assert_eq!(height.depth_m[v * 8 + u] > 0.0, alive, "column {u}");
        }
    }
    // Same seed, same draw; p = 1 removes everything; p = 0 nothing.
    let (mut r2, mut h2) = (r0.clone(), h0.clone());
    drop_radar(&mut r2, Some(&mut h2), 0.5, 42);
    assert_eq!(r2, raw);
    let (mut r3, mut h3) = (r0.clone(), h0.clone());
    drop_radar(&mut r3, Some(&mut h3), 1.0, 1);
    assert_eq!((r3.valid_count(), h3.valid_count()), (0, 0));
    let (mut r4, mut h4) = (r0.clone(), h0.clone());
    drop_radar(&mut r4, Some(&mut h4), 0.0, 1);
    assert_eq!((r4, h4), (r0, h0));
}

#[test]
fn train_radar_drop_removes_a_random_subset_and_leaves_the_augmentation_alone() {
    let _torch = crate::torch_lock();
    let tmp = tempfile::tempdir().unwrap();
    let ds = toy(tmp.path(), 1, 2);
    let e = &ds.split("all")[0];
    let aug = LoadOptions {
        augment: true,
        ..LoadOptions::default()
    };
    let dropping = LoadOptions {
        train_radar_drop: 0.9,
        ..aug.clone()
    };
    let mut counts = std::collections::BTreeSet::new();
    for seed in 0..8u64 {
        let plain = load_sample(&ds, e, &aug, &mut Rng::new(seed)).unwrap();
        let dropped = load_sample(&ds, e, &dropping, &mut Rng::new(seed)).unwrap();
        // the SPEC §8 draws come first: image, target and flip are those of a run without it
        assert_eq!(dropped.image, plain.image);
        assert_eq!(dropped.target_m, plain.target_m);
        assert_eq!(dropped.flipped, plain.flipped);
        // radar: a subset of the returns (a kept pixel keeps its exact depth)
        for (d, p) in dropped.radar.iter().zip(&plain.radar) {
            assert!(*d == 0.0 || d == p);
        }
        let n = dropped.radar.iter().filter(|d| **d > 0.0).count();
        assert!(n <= plain.radar.iter().filter(|d| **d > 0.0).count());
        counts.insert(n);
    }
    assert!(
        counts.len() > 1,
        "the fraction is drawn per sample: {counts:?}"
    );
    // it takes exactly two draws (fraction, seed) after the augmentation's; off, none
    let (mut a, mut b) = (Rng::new(3), Rng::new(3));
    load_sample(&ds, e, &aug, &mut a).unwrap();
    load_sample(&ds, e, &dropping, &mut b).unwrap();
    a.next_u64();
    a.next_u64();
    assert_eq!(a.next_u64(), b.next_u64());
}

#[test]
fn scene_modulo_partition_is_deterministic() {
    let _torch = crate::torch_lock();
    let tmp = tempfile::tempdir().unwrap();
    let ds = toy(tmp.path(), 10, 1);
    let p = partition(&ds, 5).unwrap();
    assert_eq!(p.test_scenes, vec!["toy-0004", "toy-0009"]);
    assert_eq!(p.val_scenes, vec!["toy-0003", "toy-0008"]);
    assert_eq!((p.train.len(), p.val.len(), p.test.len()), (6, 2, 2));
    assert!(p.method.starts_with("scene-modulo"));
    assert_eq!(partition(&ds, 5).unwrap(), p, "deterministic");
}

fn retag(ds: &mut Dataset, f: impl Fn(usize) -> Vec<&'static str>) {
    let mut scenes = ds.scenes();
    scenes.sort();
    for e in ds.index.samples.iter_mut() {
        let i = scenes.iter().position(|s| *s == e.scene_name).unwrap();
        e.splits = f(i).into_iter().map(String::from).collect();
    }
}

/// Validation never overlaps test, whichever split information the index carries.
#[test]
fn validation_and_test_scenes_are_disjoint_in_every_split_mode() {
    let _torch = crate::torch_lock();
    let tmp = tempfile::tempdir().unwrap();
    let mut ds = toy(tmp.path(), 12, 1);
    let check = |ds: &Dataset, mode: &str| {
        let p = partition(ds, 5).unwrap();
        let names = |v: &[depthsense_prep::layout::IndexEntry]| {
            v.iter()
                .map(|e| e.scene_name.clone())
                .collect::<std::collections::BTreeSet<_>>()
        };
        let (tr, va, te) = (names(&p.train), names(&p.val), names(&p.test));
        assert!(!va.is_empty() && !tr.is_empty(), "{mode}: {p:?}");
        assert!(va.is_disjoint(&te), "{mode}: val {va:?} test {te:?}");
        assert!(va.is_disjoint(&tr) && tr.is_disjoint(&te), "{mode}");
        p
    };
    // 1. No split lists (`--split all`): three-way scene modulo.
    let p = check(&ds, "scene-modulo");
    assert!(!p.test.is_empty());
    // 2. train / test lists only (an index prepared before validation lists existed): val
    // comes out of train, test stays test.
    retag(&mut ds, |i| {
        if i % 4 == 3 {
            vec!["test", "test-day"]
        } else {
            vec!["train"]
        }
    });
    let p = check(&ds, "train/test");
    assert!(p
        .test
        .iter()
        .all(|e| e.splits.contains(&"test".to_string())));
    assert!(p.val.iter().all(|e| e.splits == ["train"]));
    // 3. train / val / test lists (prepare of a synthetic world or the shipped lists).
    retag(&mut ds, |i| match i % 4 {
        3 => vec!["test"],
        2 => vec!["val"],
        _ => vec!["train"],
    });
    let p = check(&ds, "train/val/test");
    assert_eq!((p.train.len(), p.val.len(), p.test.len()), (6, 3, 3));
}

/// Resume continues exactly; a short run lowers the validation RMSE; RUN/ holds its files;
/// a checkpoint of another config is refused naming the tensors; eval and predict work.
#[test]
fn train_resume_mismatch_eval_predict() {
    let _torch = crate::torch_lock();
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    // 6 scenes of 4: test toy-0004, validation toy-0003, 16 train samples (4 batches of 4).
    toy(&data, 6, 4);
    let pb = Progress::hidden();

    // Uninterrupted: 10 epochs × 4 iterations.
    let full = train(&opts(&data, &tmp.path().join("a"), Fusion::Late), &pb).unwrap();
    assert_eq!(full.total_iterations, 40);
    assert_eq!(full.losses.len(), 40);
    assert!(!full.interrupted);
    let (first, last) = (full.val[0].rmse, full.val.last().unwrap().rmse);
    assert_eq!(full.val.len(), 11, "initial + 10 epochs");
    // The wall time splits into training steps, validation passes and the rest.
    assert!(full.train_seconds > 0.0 && full.val_seconds > 0.0);
    assert!(
        full.train_seconds + full.val_seconds <= full.seconds,
        "{} + {} > {}",
        full.train_seconds,
        full.val_seconds,
        full.seconds
    );
    let rate = 40.0 * 4.0 / full.train_seconds;
    assert!((full.train_images_per_s - rate).abs() <= 1e-9 * rate);
    // Each epoch line's own rate covers that epoch's 16 images: together they add up to the
    // training time.
    let metrics = std::fs::read_to_string(tmp.path().join("a/metrics.jsonl")).unwrap();
    let epoch_secs: f64 = metrics
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|v| v["kind"] == "epoch")
        .map(|v| 16.0 / v["epoch_images_per_s"].as_f64().unwrap())
        .sum();
    assert!(
        (epoch_secs - full.train_seconds).abs() <= 1e-6 * full.train_seconds,
        "{epoch_secs} vs {}",
        full.train_seconds
    );
    // A short run lowers both the training loss and the validation RMSE.
    assert!(last < first, "validation RMSE {first} → {last}");
    let (l0, l1) = (full.losses[0].1, full.losses.last().unwrap().1);
    assert!(l1 < 0.85 * l0, "training loss {l0} → {l1}");
    for f in [
        "config.json",
        "metrics.jsonl",
        "curves.png",
        LAST_CKPT,
        BEST_CKPT,
    ] {
        assert!(tmp.path().join("a").join(f).exists(), "{f}");
    }
    let png = image::open(tmp.path().join("a/curves.png")).unwrap();
    assert_eq!((png.width(), png.height()), (1200, 450));
    let (logged, _) = read_metrics(&tmp.path().join("a/metrics.jsonl")).unwrap();
    assert_eq!(logged.len(), full.losses.len());
    for ((i, a), (j, b)) in logged.iter().zip(&full.losses) {
        assert!(
            i == j && (a - b).abs() <= 1e-12 * b.abs(),
            "{i}: {a} vs {b}"
        );
    }

    // Interrupted mid-epoch at iteration 18, then resumed.
    let b_dir = tmp.path().join("b");
    let mut o = opts(&data, &b_dir, Fusion::Late);
    o.checkpointing.stop_after = Some(18);
    let part1 = train(&o, &pb).unwrap();
    assert!(part1.interrupted);
    assert_eq!(part1.iterations_done, 18);
    o.checkpointing.stop_after = None;
    o.checkpointing.resume = true;
    let part2 = train(&o, &pb).unwrap();
    assert_eq!(part2.iterations_done, 40);
    let mut joined = part1.losses.clone();
    joined.extend(part2.losses.iter().copied());
    assert_eq!(joined.len(), full.losses.len());
    for ((i, a), (j, b)) in full.losses.iter().zip(&joined) {
        assert_eq!(i, j);
        assert!(
            (a - b).abs() <= 1e-6 * a.abs().max(1.0),
            "iteration {i}: {a} vs {b}"
        );
    }
    let (logged_b, _) = read_metrics(&b_dir.join("metrics.jsonl")).unwrap();
    assert_eq!(
        logged_b.len(),
        40,
        "metrics.jsonl holds each iteration once"
    );

    // Interrupted inside the first epoch (no validation yet), then resumed.
    let c_dir = tmp.path().join("c");
    let mut o = opts(&data, &c_dir, Fusion::Late);
    o.schedule.epochs = 1;
    o.checkpointing.stop_after = Some(2);
    assert!(train(&o, &pb).unwrap().interrupted);
    o.checkpointing.stop_after = None;
    o.checkpointing.resume = true;
    let c = train(&o, &pb).unwrap();
    assert_eq!(c.losses.len(), 2);
    assert_eq!(c.iterations_done, 4);
    assert!(c.best_val_rmse.is_finite());

    // Resuming into another configuration: error naming the tensors with both shapes.
    let mut other = opts(&data, &b_dir, Fusion::Late);
    other.checkpointing.resume = true;
    other.model.head = HeadKind::L1;
    let err = train(&other, &pb).expect_err("mismatch must fail");
    let msg = err.to_string();
    assert!(matches!(err, NetError::Model(_)), "{msg}");
    assert!(msg.contains("mismatching shapes"), "{msg}");
    assert!(
        msg.contains("[1, 64, 1, 1]") || msg.contains("network ["),
        "{msg}"
    );

    // Eval on the test scene (never the validation scene that chose the checkpoint), with and
    // without radar.
    let eo = EvalOptions {
        checkpoint: tmp.path().join("a").join(BEST_CKPT),
        data: data.clone(),
        device: "cpu".into(),
        jobs: 2,
        ..EvalOptions::default()
    };
    let rep = run_eval(&eo, &pb).unwrap();
    let head = rep.headline().unwrap();
    assert_eq!(head.n_images, 4);
    assert!(head.n_pixels > 1000);
    assert!(head.metrics.rmse.is_finite() && head.metrics.rmse < 80.0);
    let test_part = partition(&Dataset::open(&data).unwrap(), 5).unwrap();
    assert_eq!(test_part.test_scenes, vec!["toy-0004"]);
    assert_eq!(test_part.val_scenes, vec!["toy-0003"]);
    let dropped = run_eval(
        &EvalOptions {
            radar_drop: 1.0,
            ..eo.clone()
        },
        &pb,
    )
    .unwrap();
    // The GT behind the rows does not change when radar is dropped.
    let dh = dropped.headline().unwrap();
    assert_eq!((dh.n_images, dh.n_pixels), (head.n_images, head.n_pixels));
    let ds_check = Dataset::open(&data).unwrap();
    let e0 = &ds_check.split("all")[0];
    let gone = load_sample(
        &ds_check,
        e0,
        &LoadOptions {
            radar_drop: 1.0,
            ..LoadOptions::default()
        },
        &mut Rng::new(0),
    )
    .unwrap();
    assert!(gone.radar.iter().all(|d| *d == 0.0));
    let out = tmp.path().join("eval");
    write_tables(
        &out,
        &[("fusion", &rep), ("fusion, radar dropped", &dropped)],
    )
    .unwrap();
    let md = std::fs::read_to_string(out.join("tables.md")).unwrap();
    assert!(md.contains("| fusion | combined | 4 |"), "{md}");
    assert!(out.join("tables.csv").exists() && out.join("tables.json").exists());

    // Predict on a prepared sample.
    let ds = Dataset::open(&data).unwrap();
    let e = &ds.split("all")[0];
    let input = depthsense_eval::predict::input_from_prepared(&ds.sample_dir(e)).unwrap();
    let loaded = checkpoint::load(&tmp.path().join("a").join(BEST_CKPT), tch::Device::Cpu).unwrap();
    let radar = loaded.config.radar_input_for(None).unwrap();
    let depth =
        depthsense_eval::predict::predict(&loaded.net, &input, radar, tch::Device::Cpu).unwrap();
    assert_eq!((depth.width, depth.height), (W, H));
    assert!(depth.depth_m.iter().all(|d| (1.0..=80.0).contains(d)));
    let files =
        depthsense_eval::predict::write_outputs(&tmp.path().join("pred"), &input, &depth, 80.0)
            .unwrap();
    assert_eq!(files.len(), 4);
    let back = depthsense_nuscenes::depth_png::read_depth_png(&files[0]).unwrap();
    assert_eq!((back.width, back.height), (W, H));
    assert!((back.depth_m[100] - depth.depth_m[100]).abs() <= 0.5 / 256.0 + 1e-6);
}

#[test]
fn non_finite_loss_stops_and_keeps_the_last_good_checkpoint() {
    let _torch = crate::torch_lock();
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    toy(&data, 5, 4);
    let run = tmp.path().join("run");
    let mut o = opts(&data, &run, Fusion::None);
    o.schedule.epochs = 50;
    o.schedule.lr = 1e30; // diverges within a few steps: a real non-finite loss
    o.checkpointing.checkpoint_every = 1;
    o.validation.max_val_samples = Some(1);
    let err = train(&o, &Progress::hidden()).expect_err("must stop");
    let msg = err.to_string();
    let NetError::NonFiniteLoss { iteration, .. } = err else {
        panic!("expected a non-finite-loss error, got {msg}");
    };
    assert!(msg.contains("training stopped"), "{msg}");
    assert!(iteration >= 1);
    // The checkpoint of the last good iteration is kept, finite, and loads.
    assert!(run.join(LAST_CKPT).exists(), "{msg}");
    {
        let l = checkpoint::load(&run.join(LAST_CKPT), tch::Device::Cpu).unwrap();
        for (n, t) in l.vs.variables() {
            if t.is_floating_point() {
                assert_eq!(t.isfinite().all().int64_value(&[]), 1, "{n}");
            }
        }
        let it = l.extra["train_state"]["iteration"].as_u64().unwrap();
        assert!(it < iteration, "checkpoint at {it}, failure at {iteration}");
    }
}

/// Deferred loss reads (issue 9 item 3): with `loss_read_every` = 4 the losses are read every
/// fourth iteration, yet the first non-finite one is reported with its own iteration, before
/// any checkpoint can be written, and the metrics logged before it are those of a run that
/// reads every loss.
#[test]
fn deferred_loss_read_reports_the_first_non_finite_iteration() {
    let _torch = crate::torch_lock();
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    toy(&data, 5, 4);
    let run_with = |every: u64, checkpoint_every: u64| {
        let run = tmp.path().join(format!("run{every}-{checkpoint_every}"));
        let mut o = opts(&data, &run, Fusion::None);
        o.schedule.epochs = 50;
        o.schedule.lr = 1e30; // diverges within a few steps
        o.validation.max_val_samples = Some(1);
        o.hardware.loss_read_every = every;
        o.checkpointing.checkpoint_every = checkpoint_every;
        let err = train(&o, &Progress::hidden()).expect_err("must stop");
        let NetError::NonFiniteLoss { iteration, .. } = err else {
            panic!("expected a non-finite-loss error, got {err}");
        };
        (iteration, run)
    };
    let (k, every1) = run_with(1, 0);
    assert!(
        k >= 2,
        "diverged at iteration {k}: too early to test the deferral"
    );
    let (k4, every4) = run_with(4, 0);
    assert_eq!(k4, k, "deferred read: the first non-finite iteration");
    let logged = |run: &Path| read_metrics(&run.join("metrics.jsonl")).unwrap();
    assert_eq!(logged(&every4), logged(&every1));
    assert!(logged(&every4)
        .0
        .iter()
        .all(|(it, l)| *it < k && l.is_finite()));
    // A checkpoint due at or after the non-finite step is never written: the losses are read
    // (and checked) first, so the error names iteration k, not the checkpoint's.
    let (kc, ckpt) = run_with(4, k);
    assert_eq!(kc, k);
    assert!(
        !ckpt.join(LAST_CKPT).exists() || {
            let l = checkpoint::load(&ckpt.join(LAST_CKPT), tch::Device::Cpu).unwrap();
            l.extra["train_state"]["iteration"].as_u64().unwrap() < k
        }
    );
}

/// A finite run reads its losses every 3 iterations and trains exactly as one that reads them
/// every iteration: the same logged losses and the same weights.
#[test]
fn deferred_loss_read_trains_identically() {
    let _torch = crate::torch_lock();
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    toy(&data, 5, 4);
    let run_with = |every: u64| {
        let run = tmp.path().join(format!("run{every}"));
        let mut o = opts(&data, &run, Fusion::Late);
        o.schedule.epochs = 2;
        o.validation.max_val_samples = Some(2);
        o.hardware.loss_read_every = every;
        let s = train(&o, &Progress::hidden()).unwrap();
        let l = checkpoint::load(&run.join(LAST_CKPT), tch::Device::Cpu).unwrap();
        let mut w: Vec<(String, Vec<f32>)> =
            l.vs.variables()
                .into_iter()
                .map(|(n, t)| {
                    (
                        n,
                        Vec::<f32>::try_from(t.to_kind(tch::Kind::Float).flatten(0, -1)).unwrap(),
                    )
                })
                .collect();
        w.sort_by(|a, b| a.0.cmp(&b.0));
        (
            s.losses,
            read_metrics(&run.join("metrics.jsonl")).unwrap().0,
            w,
        )
    };
    let a = run_with(1);
    let b = run_with(3);
    assert!(a.0.len() >= 4, "{} iterations", a.0.len());
    assert_eq!(a, b);
}
