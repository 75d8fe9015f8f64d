//! `depthsense demo`: synthesise a small world → prepare it (`--split all`) → train an RGB-only
//! and a late-fusion network with the same seed → evaluate both on the held-out scenes →
//! `OUT/report/` with the tables, the curves and pictures of a few test samples.
//!
//! ```text
//! OUT/world/                 synthetic nuScenes-format dataroot
//! OUT/prepared/              prepare output
//! OUT/rgb/, OUT/fusion/      training runs (config.json, metrics.jsonl, curves.png, checkpoints)
//! OUT/report/README.md       summary: stage times, headline numbers, held-out scenes
//! OUT/report/tables.{md,csv,json}
//! OUT/report/curves_rgb.png, curves_fusion.png, val_rmse.png
//! OUT/report/samples/<token>/{image,radar,gt,pred_rgb,pred_fusion,err_rgb,err_fusion}.png
//! ```

use std::path::{Path, PathBuf};
use std::time::Instant;

use depthsense_base::fsutil::write_atomic;
use depthsense_base::lock::OutputLock;
use depthsense_checkpoint as checkpoint;
use depthsense_config::device::DeviceArg;
use depthsense_config::training::{
    CheckpointOptions, HardwareOptions, LoadingOptions, ScheduleOptions, ValidationOptions,
};
use depthsense_config::{Fusion, ModelConfig};
use depthsense_data::LoadOptions;
use depthsense_dataset::{partition, Dataset, Partition};
use depthsense_metrics::doc::Doc;
use depthsense_metrics::table::{Align, MdTable};
use depthsense_metrics::Report;
use depthsense_prep::layout::IndexEntry;
use depthsense_progress::{Board, Progress};
use serde::{Deserialize, Serialize};
use tch::Device;

use crate::ExperimentError;
use depthsense_dataset::outputs::{BEST_CKPT, METRICS_FILE};
use depthsense_dataset::subsample;
use depthsense_infer::run::evaluate_net;
use depthsense_infer::NetError;
use depthsense_score::tables::write_tables;
use depthsense_train::metrics_log::read_metrics;
use depthsense_train::trainer::{train, TrainOptions};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DemoOptions {
    pub out: PathBuf,
    /// auto | cpu | cuda | cuda:N. On CUDA a larger preset and more steps are used.
    pub device: String,
    /// A much smaller run (integration tests, < 90 s on 2 cores).
    pub quick: bool,
    pub seed: u64,
    /// Override the number of epochs of each training run.
    pub epochs: Option<usize>,
    /// Override the world's size: scenes, and keyframes per scene.
    #[serde(default)]
    pub scenes: Option<usize>,
    #[serde(default)]
    pub keyframes_per_scene: Option<usize>,
    /// Loader / prepare threads (0 = all cores).
    pub jobs: usize,
    /// Test samples drawn in the report.
    pub pictures: usize,
    /// Replace a demo already in `out` (its world, prepared data, runs and report);
    /// without it such a folder is refused ([`depthsense_dataset::outputs`]).
    #[serde(default)]
    pub force: bool,
    /// The invocation, recorded in `report/summary.json` and shown on the report page.
    #[serde(default)]
    pub command_line: Option<String>,
}

impl Default for DemoOptions {
    fn default() -> Self {
        Self {
            out: PathBuf::from("runs/demo"),
            device: "auto".into(),
            quick: false,
            seed: 7,
            epochs: None,
            scenes: None,
            keyframes_per_scene: None,
            jobs: 0,
            pictures: 4,
            force: false,
            command_line: None,
        }
    }
}

/// What the demo did.
#[derive(Debug, Clone, Serialize)]
pub struct DemoSummary {
    pub report_dir: PathBuf,
    pub stage_seconds: Vec<(String, f64)>,
    pub rgb_rmse: f64,
    pub fusion_rmse: f64,
    pub rgb_initial_rmse: f64,
    pub fusion_initial_rmse: f64,
    pub total_seconds: f64,
    pub device: String,
    pub preset: String,
    /// Scenes that selected the best epoch (validation) and that are reported (test).
    pub val_scenes: Vec<String>,
    pub test_scenes: Vec<String>,
    pub split_method: String,
    /// Distinct training images (the training scenes' keyframes) and the iterations each
    /// model trained: issue 34's curve chose their ratio.
    pub train_samples: usize,
    pub iterations: u64,
    /// The stages as separate depthsense commands with the demo's settings.
    pub commands: Vec<String>,
}

/// The plan of a demo: sizes chosen to fit the time budget on the device.
#[derive(Debug, Clone, Serialize)]
pub struct DemoPlan {
    pub scenes: usize,
    pub keyframes_per_scene: usize,
    /// The experiments' lean world (`synth --lean`): half-resolution camera rays, the sweeps
    /// `prepare` reads, no truth maps.
    pub lean: bool,
    pub lidar_sweeps: usize,
    pub preset: String,
    pub epochs: usize,
    /// Iterations per epoch (= per validation) whatever the training-set size (`train
    /// --epoch-iterations`); None: an epoch is one pass.
    pub epoch_iterations: Option<u64>,
    pub batch_size: usize,
    pub lr: f64,
    pub max_batches_per_epoch: Option<usize>,
    pub max_val_samples: Option<usize>,
    pub val_every_scene: usize,
    pub dropout: f64,
    /// Spatial attention in the fusion model.
    pub attention: bool,
    /// Input downscale factor of the network (model config `input_downscale`).
    pub input_downscale: i64,
}

pub fn plan(opts: &DemoOptions, cuda: bool) -> DemoPlan {
    let tiny = depthsense_config::ModelConfig::tiny();
    let mut p = DemoPlan {
        // The tiny network at half input resolution (decoded and scored at 800x350), 350
        // iterations of batch 4 spent on ≈ 420 distinct images (42 training scenes of a lean
        // 60-scene world, ≈ 3.3 passes): at matched compute RGB-only gained most from more
        // distinct images up to ≈ 3 passes (RESULTS.md, "Radar's margin against training-set
        // size"); the time is in BENCHMARKS.md ("demo budget").
        scenes: 60,
        keyframes_per_scene: 10,
        lean: true,
        lidar_sweeps: 2,
        preset: "tiny".into(),
        epochs: 10,
        epoch_iterations: Some(35),
        batch_size: 4,
        lr: 2e-3,
        max_batches_per_epoch: None,
        max_val_samples: None,
        val_every_scene: 5,
        dropout: tiny.dropout,
        attention: true,
        input_downscale: 2,
    };
    if cuda {
        // The same world, a larger network (`tiny` at twice the widths, a ResNet-34 encoder)
        // and 30 full passes (not measured here: no GPU on the development machine).
        p.preset = "tiny-wide".into();
        p.epochs = 30;
        p.epoch_iterations = None;
        p.batch_size = 8;
        p.max_val_samples = None;
        p.input_downscale = 1;
        p.dropout = depthsense_config::ModelConfig::dropout_for_head(128);
    }
    if opts.quick {
        p.scenes = p.scenes.min(5);
        p.keyframes_per_scene = p.keyframes_per_scene.min(4);
        p.lidar_sweeps = 1;
        p.epochs = 2;
        p.epoch_iterations = None;
        p.batch_size = 2;
        p.max_batches_per_epoch = Some(4);
        p.max_val_samples = Some(4);
    }
    if let Some(e) = opts.epochs {
        p.epochs = e.max(1);
    }
    if let Some(n) = opts.scenes {
        p.scenes = n.max(1);
    }
    if let Some(n) = opts.keyframes_per_scene {
        p.keyframes_per_scene = n.max(1);
    }
    p
}

fn stage_bar(mp: &Board, name: &str) -> Progress {
    mp.bar(name)
}

/// Run the demo. `mp` hosts one progress bar per stage (pass a hidden one in tests).
pub fn run_demo(opts: &DemoOptions, mp: &Board) -> Result<DemoSummary, ExperimentError> {
    let t0 = Instant::now();
    let device = depthsense_model::device::parse_device(&opts.device)?;
    let cuda = device.is_cuda();
    let plan = plan(opts, cuda);
    let out = &opts.out;
    // One demo per folder at a time, and an earlier one is replaced only when asked.
    let _writing = OutputLock::exclusive(out, "depthsense demo")?;
    clear_earlier_demo(opts)?;
    mp.println(announcement(&plan, device, out));
    let mut stages: Vec<(String, f64)> = vec![];
    let t = Instant::now();
    let (world, scfg) = synthesise(opts, &plan, mp)?;
    stages.push(("synth".into(), t.elapsed().as_secs_f64()));
    let t = Instant::now();
    let prepared = prepare_world(opts, &plan, &world, &scfg.version_name, mp)?;
    stages.push(("prepare".into(), t.elapsed().as_secs_f64()));
    let runs = train_both(opts, &plan, &prepared, mp, &mut stages)?;

    // 4. Evaluate both on the test scenes (never used for selection); pictures.
    let t = Instant::now();
    let (ds, part) = held_out(&prepared, &plan)?;
    let test = part.test.clone();
    let report_dir = out.join("report");
    std::fs::create_dir_all(&report_dir).map_err(|e| NetError::io(&report_dir, e))?;
    let reports = evaluate_both(opts, &plan, &ds, &test, &runs, &report_dir, device, mp)?;
    let models: Vec<(&str, &Report)> = reports.iter().map(|(n, r)| (n.as_str(), r)).collect();
    write_tables(&report_dir, &models)?;
    write_run_curves(&runs, &report_dir)?;
    stages.push(("eval".into(), t.elapsed().as_secs_f64()));

    let summary = DemoSummary {
        report_dir: report_dir.clone(),
        stage_seconds: stages,
        rgb_rmse: headline_rmse(&reports, "rgb"),
        fusion_rmse: headline_rmse(&reports, "fusion"),
        rgb_initial_rmse: runs[0].2,
        fusion_initial_rmse: runs[1].2,
        total_seconds: t0.elapsed().as_secs_f64(),
        device: depthsense_model::device::describe(device),
        preset: plan.preset.clone(),
        val_scenes: part.val_scenes.clone(),
        test_scenes: part.test_scenes.clone(),
        split_method: part.method.clone(),
        train_samples: part.train.len(),
        iterations: runs[0].4,
        commands: stage_commands(opts, &plan, &scfg.version_name),
    };
    write_readme(&report_dir, &summary, &plan, &models, &test, opts)?;
    write_page(&report_dir, opts)?;
    Ok(summary)
}

/// The line the demo starts with: the world, both networks, the schedule and the device.
fn announcement(plan: &DemoPlan, device: Device, out: &Path) -> String {
    format!(
        "demo: a world of {} scenes × {} keyframes, `{}` RGB-only and radar fusion, {} epochs{} \
         of batch {} on {} → {}",
        plan.scenes,
        plan.keyframes_per_scene,
        plan.preset,
        plan.epochs,
        plan.epoch_iterations
            .map_or(String::new(), |n| format!(" × {n} iterations")),
        plan.batch_size,
        depthsense_model::device::describe(device),
        out.display()
    )
}

/// The prepared folder and its partition, which must hold test scenes to report on.
fn held_out(prepared: &Path, plan: &DemoPlan) -> Result<(Dataset, Partition), ExperimentError> {
    let ds = Dataset::open(prepared)?;
    let part = partition(&ds, plan.val_every_scene)?;
    if part.test.is_empty() {
        return Err(ExperimentError::NoTestSamples {
            data: prepared.to_path_buf(),
            method: part.method.to_string(),
            experiment: "the demo",
        });
    }
    Ok((ds, part))
}

/// The headline test RMSE (m) of the model `name` among `reports`; NaN when it has none.
fn headline_rmse(reports: &[(String, Report)], name: &str) -> f64 {
    reports
        .iter()
        .find(|(n, _)| n == name)
        .and_then(|(_, r)| r.headline().map(|h| h.metrics.rmse))
        .unwrap_or(f64::NAN)
}

/// An earlier demo in `out` is refused unless `--force`; with it, its report folder goes.
fn clear_earlier_demo(opts: &DemoOptions) -> Result<(), ExperimentError> {
    let out = &opts.out;
    if let Some(what) = demo_in(out) {
        if !opts.force {
            return Err(ExperimentError::OutputExists {
                dir: out.to_path_buf(),
                what,
                advice:
                    "replace it with `depthsense demo --force` (`make demo DEMO_ARGS=--force`) \
                         or choose another --out"
                        .into(),
            });
        }
        eprintln!(
            "--force: replacing {what} in {} (world/, prepared/, rgb/, fusion/, report/)",
            out.display()
        );
        let report = out.join("report");
        if report.exists() {
            std::fs::remove_dir_all(&report).map_err(|e| NetError::io(&report, e))?;
        }
    }
    Ok(())
}

/// 1. Synthesise the world into OUT/world.
fn synthesise(
    opts: &DemoOptions,
    plan: &DemoPlan,
    mp: &Board,
) -> Result<(PathBuf, depthsense_synth::SynthConfig), ExperimentError> {
    let world = opts.out.join("world");
    let mut scfg = depthsense_synth::SynthConfig::demo();
    scfg.scenes = plan.scenes;
    scfg.keyframes_per_scene = plan.keyframes_per_scene;
    if plan.lean {
        scfg.apply_lean();
    }
    scfg.seed = opts.seed;
    scfg.jobs = opts.jobs;
    let pb = stage_bar(mp, "synth");
    let synth =
        depthsense_synth::generate(&world, &scfg, &pb).map_err(|e| ExperimentError::Stage {
            stage: "synth",
            source: Box::new(e),
        })?;
    pb.finish_with_message(format!("{} keyframes", synth.keyframes));
    Ok((world, scfg))
}

/// 2. Prepare (--split all: synthetic scenes match no shipped split list) into OUT/prepared.
fn prepare_world(
    opts: &DemoOptions,
    plan: &DemoPlan,
    world: &Path,
    version: &str,
    mp: &Board,
) -> Result<PathBuf, ExperimentError> {
    let prepared = opts.out.join("prepared");
    // The world was just regenerated: samples prepared from an earlier world (or by an older
    // `prepare` whose settings it now refuses) are stale, and preparing takes seconds.
    if prepared.exists() {
        std::fs::remove_dir_all(&prepared).map_err(|e| NetError::io(&prepared, e))?;
    }
    let popts = depthsense_prep::PrepareOptions {
        dataroot: world.to_path_buf(),
        version: version.to_string(),
        out: prepared.clone(),
        split: "all".into(),
        lidar_sweeps: plan.lidar_sweeps,
        jobs: opts.jobs,
        ..depthsense_prep::PrepareOptions::default()
    };
    let pb = stage_bar(mp, "prepare");
    let ps = depthsense_prep::prepare(&popts, &pb).map_err(|e| ExperimentError::Stage {
        stage: "prepare",
        source: Box::new(e),
    })?;
    if !ps.failed.is_empty() {
        return Err(ExperimentError::PrepareFailed {
            count: ps.failed.len(),
            first: ps.failed[0].0.to_string(),
            reason: ps.failed[0].1.to_string(),
        });
    }
    pb.finish_with_message(format!(
        "{} prepared, {} cached",
        ps.prepared, ps.skipped_existing
    ));
    Ok(prepared)
}

/// One trained run of the demo: name, folder, initial and best validation RMSE, and the
/// iterations the trainer ran.
type DemoRun = (&'static str, PathBuf, f64, f64, u64);

/// 3. Train RGB-only and late fusion with the same seed.
fn train_both(
    opts: &DemoOptions,
    plan: &DemoPlan,
    prepared: &Path,
    mp: &Board,
    stages: &mut Vec<(String, f64)>,
) -> Result<Vec<DemoRun>, ExperimentError> {
    let out = &opts.out;
    let base_cfg = demo_model(&plan.preset)?;
    let mut runs: Vec<DemoRun> = vec![];
    for (name, fusion) in [("rgb", Fusion::None), ("fusion", Fusion::Late)] {
        let t = Instant::now();
        let mut cfg = base_cfg.clone();
        // The preset's head dropout (scaled with head width for small presets) and the paper's
        // late fusion with the spatial attention module (SPEC §6).
        cfg.dropout = plan.dropout;
        cfg.fusion = fusion;
        cfg.attention = plan.attention && fusion == Fusion::Late;
        cfg.input_downscale = plan.input_downscale;
        let topts = run_options(opts, plan, prepared, name, cfg);
        let pb = stage_bar(mp, &format!("train {name}"));
        let s = train(&topts, &pb)?;
        pb.finish_with_message(format!("best val RMSE {:.2} m", s.best_val_rmse));
        let initial = s.val.first().map_or(f64::NAN, |v| v.rmse);
        runs.push((
            name,
            out.join(name),
            initial,
            s.best_val_rmse,
            s.total_iterations,
        ));
        stages.push((format!("train {name}"), t.elapsed().as_secs_f64()));
    }
    Ok(runs)
}

/// The training options of the demo's run `name` (`OUT/<name>`) of network `cfg` on the
/// prepared folder: the plan's schedule and validation, the demo's seed, jobs and device.
fn run_options(
    opts: &DemoOptions,
    plan: &DemoPlan,
    prepared: &Path,
    name: &str,
    cfg: ModelConfig,
) -> TrainOptions {
    TrainOptions {
        data: prepared.to_path_buf(),
        out: opts.out.join(name),
        model: cfg,
        schedule: ScheduleOptions {
            epochs: plan.epochs,
            epoch_iterations: plan.epoch_iterations,
            batch_size: plan.batch_size,
            lr: plan.lr,
            seed: opts.seed,
            max_batches_per_epoch: plan.max_batches_per_epoch,
            ..Default::default()
        },
        loading: LoadingOptions {
            jobs: opts.jobs,
            ..Default::default()
        },
        validation: ValidationOptions {
            max_val_samples: plan.max_val_samples,
            val_every_scene: plan.val_every_scene,
        },
        checkpointing: CheckpointOptions {
            force: opts.force,
            ..Default::default()
        },
        hardware: HardwareOptions {
            device: DeviceArg {
                name: opts.device.clone(),
            },
            ..Default::default()
        },
        ..TrainOptions::default()
    }
}

/// Both runs' best checkpoints on the test scenes, writing the sample pictures on the way.
#[allow(clippy::too_many_arguments)]
fn evaluate_both(
    opts: &DemoOptions,
    plan: &DemoPlan,
    ds: &Dataset,
    test: &[IndexEntry],
    runs: &[DemoRun],
    report_dir: &Path,
    device: Device,
    mp: &Board,
) -> Result<Vec<(String, Report)>, ExperimentError> {
    let pic_tokens: Vec<String> = subsample(test, Some(opts.pictures.max(1)))
        .iter()
        .map(|e| e.sample_token.clone())
        .collect();
    let mut reports: Vec<(String, Report)> = vec![];
    // the pictures' predictions, kept from the evaluation's batches and drawn after it
    let mut pictures: Vec<Picture> = vec![];
    let pb = stage_bar(mp, "eval");
    pb.set_length(2 * test.len() as u64);
    for (name, dir, ..) in runs {
        let loaded = checkpoint::load(&dir.join(BEST_CKPT), device)?;
        loaded
            .net
            .prepare_inference(depthsense_model::precision::InferenceLayout::Fastest);
        let load = load_options(&loaded.config)?;
        let rep = evaluate_net(
            &loaded.net,
            ds,
            test,
            &load,
            &Default::default(),
            plan.batch_size,
            opts.jobs,
            device,
            &pb,
            |batch, preds| {
                pictures.extend(Picture::of_batch(batch, preds, &pic_tokens));
                Ok(())
            },
        )?;
        for p in pictures.drain(..) {
            write_pictures(&report_dir.join("samples").join(&p.token), name, ds, &p)?;
        }
        reports.push((name.to_string(), rep));
    }
    pb.finish();
    for token in &pic_tokens {
        write_picture_row(&report_dir.join("samples").join(token))?;
    }
    Ok(reports)
}

/// What a network of `cfg` is fed on the test scenes: the radar input it was built for, or
/// none.
fn load_options(cfg: &ModelConfig) -> Result<LoadOptions, ExperimentError> {
    let radar = cfg.radar_input_for(None)?;
    Ok(LoadOptions {
        radar: radar.unwrap_or_default(),
        no_radar: radar.is_none(),
        ..LoadOptions::default()
    })
}

/// Each run's curves.png copied into the report, and both runs on one picture: training loss
/// (left) and validation RMSE (right).
fn write_run_curves(runs: &[DemoRun], report_dir: &Path) -> Result<(), ExperimentError> {
    for (name, dir, ..) in runs {
        let src = dir.join(depthsense_dataset::outputs::CURVES_FILE);
        if src.exists() {
            let dst = report_dir.join(format!("curves_{name}.png"));
            std::fs::copy(&src, &dst).map_err(|e| NetError::io(&dst, e))?;
        }
    }
    // Both runs on one picture: training loss (left) and validation RMSE (right).
    let mut losses = vec![];
    let mut val_series = vec![];
    for (name, dir, ..) in runs {
        let (l, val) = read_metrics(&dir.join(METRICS_FILE))?;
        losses.push((name.to_string(), l));
        val_series.push((
            name.to_string(),
            val.iter()
                .map(|v| (v.iteration, v.rmse))
                .collect::<Vec<_>>(),
        ));
    }
    let left: Vec<(&str, &[(u64, f64)])> = losses
        .iter()
        .map(|(n, s)| (n.as_str(), s.as_slice()))
        .collect();
    let right: Vec<(&str, &[(u64, f64)])> = val_series
        .iter()
        .map(|(n, s)| (n.as_str(), s.as_slice()))
        .collect();
    let png = depthsense_viz::plot::curves_png(&left, &right)?;
    let p = report_dir.join("val_rmse.png");
    write_atomic(&p, &png).map_err(|e| NetError::io(&p, e))?;
    Ok(())
}

/// What `out` holds of an earlier demo, if anything.
fn demo_in(out: &Path) -> Option<String> {
    let summary = out.join("report").join(depthsense_report::DEMO_SUMMARY);
    if let Ok(text) = std::fs::read_to_string(&summary) {
        let v: serde_json::Value = serde_json::from_str(&text).unwrap_or_default();
        let rmse = |k: &str| v["summary"][k].as_f64().unwrap_or(f64::NAN);
        return Some(format!(
            "a finished demo (test RMSE: RGB only {:.3} m, fusion {:.3} m)",
            rmse("rgb_rmse"),
            rmse("fusion_rmse")
        ));
    }
    let parts: Vec<&str> = ["world", "prepared", "rgb", "fusion", "report"]
        .into_iter()
        .filter(|d| out.join(d).exists())
        .collect();
    (!parts.is_empty()).then(|| format!("an unfinished demo ({}/)", parts.join("/, ")))
}

/// The demo's stages as separate commands with its settings (docs/guide/experiments.md, "The demo").
fn stage_commands(opts: &DemoOptions, plan: &DemoPlan, version: &str) -> Vec<String> {
    let out = opts.out.display();
    let mut v = vec![
        format!(
            "depthsense synth --out {out}/world --scenes {} --keyframes-per-scene {} --seed {}{}",
            plan.scenes,
            plan.keyframes_per_scene,
            opts.seed,
            if plan.lean { " --lean" } else { "" }
        ),
        format!(
            "depthsense prepare --dataroot {out}/world --version {version} --split all \
             --lidar-sweeps {} --out {out}/prepared",
            plan.lidar_sweeps
        ),
    ];
    let mut extra = String::new();
    if let Some(n) = plan.epoch_iterations {
        extra.push_str(&format!(" --epoch-iterations {n}"));
    }
    if let Some(m) = plan.max_batches_per_epoch {
        extra.push_str(&format!(" --max-batches-per-epoch {m}"));
    }
    if let Some(m) = plan.max_val_samples {
        extra.push_str(&format!(" --max-val-samples {m}"));
    }
    for (name, fusion) in [("rgb", "none"), ("fusion", "late")] {
        v.push(format!(
            "depthsense train --data {out}/prepared --config {} --fusion {fusion} --dropout {} \
             --set input-downscale={} --epochs {} --batch-size {} --lr {} --seed {} \
             --val-every-scene {} --device {}{extra} --out {out}/{name}",
            plan.preset,
            plan.dropout,
            plan.input_downscale,
            plan.epochs,
            plan.batch_size,
            plan.lr,
            opts.seed,
            plan.val_every_scene,
            opts.device
        ));
    }
    for name in ["rgb", "fusion"] {
        v.push(format!(
            "depthsense eval --checkpoint {out}/{name}/best.safetensors --data {out}/prepared \
             --val-every-scene {} --out {out}/eval-{name}",
            plan.val_every_scene
        ));
    }
    v
}

/// `report/report.html`: the demo's one self-contained page (README, tables, curves, every
/// sample row with its colour bar, the commands), built by `depthsense report`'s renderer.
fn write_page(report_dir: &Path, opts: &DemoOptions) -> Result<(), ExperimentError> {
    let ropts = depthsense_report::ReportOptions {
        runs: vec![report_dir.to_path_buf()],
        // Only rendered, never written as a folder; discovery skips `out`, so it must not be
        // the folder searched.
        out: report_dir.join("page-unused"),
        title: "depthsense demo".into(),
        max_depth: 0,
        command_line: opts.command_line.clone(),
        ..depthsense_report::ReportOptions::default()
    };
    let (_, page) = depthsense_report::render(&ropts).map_err(|e| ExperimentError::Stage {
        stage: "report",
        source: Box::new(e),
    })?;
    let p = report_dir.join("report.html");
    Ok(write_atomic(&p, page.as_bytes()).map_err(|e| NetError::io(&p, e))?)
}

/// The demo's network: a model preset ([`depthsense_config::presets`]).
pub fn demo_model(preset: &str) -> Result<ModelConfig, ExperimentError> {
    Ok(ModelConfig::preset(preset)?)
}

/// One test sample's prediction for the pictures, kept from an evaluation batch.
struct Picture {
    token: String,
    pred_m: Vec<f32>,
    gt_m: Vec<f32>,
    width: u32,
    height: u32,
}

impl Picture {
    /// The pictures among `batch`'s samples (`tokens`), with their predictions `preds_m`.
    fn of_batch(batch: &depthsense_data::Batch, preds_m: &[f32], tokens: &[String]) -> Vec<Self> {
        let hw = batch.width * batch.height;
        let samples = batch.samples.iter().enumerate();
        samples
            .filter(|(_, s)| tokens.contains(&s.token))
            .map(|(i, s)| Picture {
                token: s.token.clone(),
                pred_m: preds_m[i * hw..(i + 1) * hw].to_vec(),
                gt_m: s.sparse_m.clone(),
                width: batch.width as u32,
                height: batch.height as u32,
            })
            .collect()
    }
}

/// `model`'s panels of one picture sample into `dir` (the image, radar and ground-truth
/// panels once, by the first model).
fn write_pictures(
    dir: &Path,
    model: &str,
    ds: &Dataset,
    pic: &Picture,
) -> Result<(), ExperimentError> {
    use depthsense_viz::plot::{colorize_depth, encode_rgb, error_map, overlay_points};
    let save = |name: &str, img: &image::RgbImage| -> Result<(), ExperimentError> {
        let p = dir.join(name);
        Ok(write_atomic(&p, &encode_rgb(img)?).map_err(|e| NetError::io(&p, e))?)
    };
    let (token, pred, gt) = (pic.token.as_str(), &pic.pred_m, &pic.gt_m);
    let (w, h) = (pic.width, pic.height);
    let max_m = PICTURE_MAX_M;
    let e = ds
        .index
        .samples
        .iter()
        .find(|e| e.sample_token == token)
        .ok_or_else(|| ExperimentError::SampleNotInIndex(token.to_string()))?;
    let input = depthsense_eval::predict::input_from_prepared(&ds.sample_dir(e))?;
    if !dir.join("image.png").exists() {
        save("image.png", &input.image)?;
        save(
            "radar.png",
            &overlay_points(&input.image, &input.radar_raw.depth_m, max_m, 3),
        )?;
        save("gt.png", &overlay_points(&input.image, gt, max_m, 1))?;
    }
    save(
        &format!("pred_{model}.png"),
        &colorize_depth(pred, w, h, max_m),
    )?;
    save(
        &format!("err_{model}.png"),
        &error_map(pred, gt, w, h, 10.0),
    )?;
    Ok(())
}

/// `dir/row.png`: image, radar, GT, RGB-only and fusion predictions side by side with one
/// colour bar in metres (the panels written by [`write_pictures`]).
fn write_picture_row(dir: &Path) -> Result<(), ExperimentError> {
    let read = |name: &str| -> Result<image::RgbImage, ExperimentError> {
        Ok(depthsense_dataset::decode_rgb(&dir.join(name))?)
    };
    let panels = [
        ("image", read("image.png")?),
        ("radar (points, m)", read("radar.png")?),
        ("lidar GT (m)", read("gt.png")?),
        ("RGB only", read("pred_rgb.png")?),
        ("radar fusion + attention", read("pred_fusion.png")?),
    ];
    let png = depthsense_viz::plot::picture_row_png(&panels, PICTURE_MAX_M)?;
    let p = dir.join("row.png");
    Ok(write_atomic(&p, &png).map_err(|e| NetError::io(&p, e))?)
}

/// The demo's headline difference, said to be one seed: each model is trained once (README:
/// "One seed decides nothing"; the ablation over seeds is the comparison).
pub fn one_seed_difference(rgb_rmse: f64, fusion_rmse: f64) -> String {
    format!(
        "Radar fusion vs RGB only: RMSE {} % (one seed: not a finding; `depthsense experiment \
         ablation` compares the two over seeds).",
        crate::signed(100.0 * (fusion_rmse - rgb_rmse) / rgb_rmse, 1)
    )
}

/// Upper end of the colour map of every depth picture (metres).
const PICTURE_MAX_M: f32 = 80.0;

/// OUT/report/README.md and summary.json (the summary, the plan, the command line and the
/// README's document).
fn write_readme(
    dir: &Path,
    s: &DemoSummary,
    plan: &DemoPlan,
    models: &[(&str, &Report)],
    test: &[IndexEntry],
    opts: &DemoOptions,
) -> Result<(), ExperimentError> {
    let mut doc = Doc::new();
    doc.heading(1, "depthsense demo report");
    readme_setup(&mut doc, s, plan, test);
    doc.table(headline_table(s))
        .paragraph(one_seed_difference(s.rgb_rmse, s.fusion_rmse));
    doc.table(stage_table(s))
        .paragraph("The same stages as separate commands (same settings):")
        .code(s.commands.join("\n"));
    doc.blocks
        .extend(depthsense_metrics::tables::report_doc(models).blocks);
    doc.paragraph(
        "Pictures: `samples/<token>/row.png` (image, radar, GT, both predictions, one colour bar in metres) \
         and the single panels (image, radar overlay, GT, prediction and |error| per model); \
         curves: `curves_rgb.png`, `curves_fusion.png`, `val_rmse.png`.",
    );
    let p = dir.join("README.md");
    write_atomic(&p, doc.to_markdown().as_bytes()).map_err(|e| NetError::io(&p, e))?;
    let p = dir.join("summary.json");
    write_atomic(
        &p,
        serde_json::to_string_pretty(&serde_json::json!({
            "summary": s,
            "plan": plan,
            "command_line": opts.command_line,
            depthsense_metrics::doc::DOCUMENT_KEY: doc,
        }))?
        .as_bytes(),
    )
    .map_err(|e| NetError::io(&p, e))?;
    Ok(())
}

/// The README's setup paragraphs: device and schedule, the training set, and the split into
/// validation and test scenes.
fn readme_setup(doc: &mut Doc, s: &DemoSummary, plan: &DemoPlan, test: &[IndexEntry]) {
    let mut scenes: Vec<String> = test.iter().map(|e| e.scene_name.clone()).collect();
    scenes.dedup();
    doc.paragraph(format!(
        "Device `{}`, preset `{}`, {} epochs, batch {}, lr {} (synthetic world: {} scenes × {} keyframes{}).",
        s.device,
        s.preset,
        plan.epochs,
        plan.batch_size,
        plan.lr,
        plan.scenes,
        plan.keyframes_per_scene,
        if plan.lean { ", lean" } else { "" }
    ));
    doc.paragraph(format!(
        "Training set: **{} distinct images**; each model trained {} iterations of batch {} \
         ({:.1} passes over them).",
        s.train_samples,
        s.iterations,
        plan.batch_size,
        (s.iterations as f64 * plan.batch_size as f64) / s.train_samples.max(1) as f64
    ));
    doc.paragraph(format!(
        "Split ({}): validation scenes (select the best epoch → `best.safetensors`): {}; \
         test scenes (reported below, {} samples, never used for any choice): {}.",
        s.split_method,
        s.val_scenes.join(", "),
        test.len(),
        scenes.join(", ")
    ));
}

/// Both models' initial validation RMSE and test RMSE (m) of the epoch chosen on validation.
fn headline_table(s: &DemoSummary) -> MdTable {
    let mut headline = MdTable::new(&[
        ("model", Align::Left),
        ("initial RMSE (m, val)", Align::Right),
        ("test RMSE, epoch chosen on val (m)", Align::Right),
    ]);
    let m3 = |x: f64| format!("{x:.3}");
    headline
        .row(&["RGB only".into(), m3(s.rgb_initial_rmse), m3(s.rgb_rmse)])
        .row(&[
            "late fusion + spatial attention (radar)".into(),
            m3(s.fusion_initial_rmse),
            m3(s.fusion_rmse),
        ]);
    headline
}

/// The seconds of every stage of the demo, and the total.
fn stage_table(s: &DemoSummary) -> MdTable {
    let mut stages = MdTable::new(&[("stage", Align::Left), ("seconds", Align::Right)]);
    for (n, t) in &s.stage_seconds {
        stages.row(&[n.clone(), format!("{t:.1}")]);
    }
    stages.row(&["total".into(), format!("{:.1}", s.total_seconds)]);
    stages
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The headline difference carries the words "one seed" (issue 42).
    #[test]
    fn the_headline_difference_is_one_seed() {
        let t = one_seed_difference(10.0, 9.73);
        assert!(
            t.starts_with("Radar fusion vs RGB only: RMSE −2.7 % (one seed: not a finding;"),
            "{t}"
        );
        assert!(one_seed_difference(10.0, 10.5).contains("RMSE +5.0 % (one seed"));
    }
}
