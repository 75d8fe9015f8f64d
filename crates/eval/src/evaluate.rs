//! `depthsense eval`: a checkpoint on prepared data → the tables of SPEC §10 items 1–3 as
//! Markdown, CSV and JSON, with the number of images and pixels behind each row; radar drop
//! for the sensor-failure ablation (SPEC §10.8).
//!
//! Every score goes through [`score_image`] (one image into the metrics [`Evaluator`]):
//! `eval --checkpoint` (via `trainer::evaluate_net`) and `eval --predictions` (any method's
//! depth maps on disk, [`run_eval_predictions`]) therefore share protocol, caps, GT,
//! conditions and tables exactly.

use std::path::{Path, PathBuf};

use depthsense_checkpoint::weights::LoadReport;
use depthsense_checkpoint::{self as checkpoint, Loaded};
use depthsense_config::RadarInput;
use depthsense_data::radar_failure::RadarFailure;
use depthsense_data::LoadOptions;
use depthsense_dataset::Dataset;
use depthsense_metrics::{EvalConfig, Report};
use depthsense_model::precision::InferenceLayout;
use depthsense_progress::Progress;
use serde::{Deserialize, Serialize};

use depthsense_dataset::subsample;
use depthsense_infer::run::evaluate_net_on;
use depthsense_infer::run::{run_net, RunPlan, RunStats};
use depthsense_infer::NetError;
use depthsense_prep::layout::IndexEntry;
// Scoring files on disk is torch-free (depthsense-score), so `depthsense` runs
// `eval --predictions` without libtorch; the network side's users reach it there.
use depthsense_score::predictions::{select_split, write_prediction, PredFormat, HELD_OUT};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalOptions {
    /// A depthsense checkpoint (`.safetensors`) or a PyTorch state dict (`.pth`, e.g. the
    /// authors' released weights; needs `config`).
    pub checkpoint: PathBuf,
    /// Architecture: a preset name or a model-config JSON. Required for a PyTorch file;
    /// overrides the stored config of a depthsense checkpoint.
    #[serde(default)]
    pub config: Option<String>,
    /// `key=value` overrides of the config (`ModelConfig::set_option`).
    #[serde(default)]
    pub set: Vec<String>,
    pub data: PathBuf,
    /// "held-out" (default: the `test` split, or the scenes `train` held out), "all", or a
    /// split name of the index (test-night, official-val, …).
    pub split: String,
    /// Scene modulo used by `train` when no split lists match (must equal train's).
    pub val_every_scene: usize,
    pub eval: EvalConfig,
    /// Fraction of radar points removed (1.0 = radar absent).
    pub radar_drop: f64,
    /// Whole radars / far returns removed, clutter added (SPEC §10.8).
    #[serde(default)]
    pub failure: RadarFailure,
    pub seed: u64,
    pub batch_size: usize,
    pub device: String,
    pub jobs: usize,
    pub max_samples: Option<usize>,
    /// Radar map(s) (None = derived from the model config).
    pub radar_input: Option<RadarInput>,
    /// Model name in the tables.
    pub name: String,
    /// Replay each batch's forward and decode from a CUDA graph (`--cuda-graph`).
    #[serde(default)]
    pub cuda_graph: bool,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            checkpoint: PathBuf::from("runs/train/best.safetensors"),
            config: None,
            set: Vec::new(),
            data: PathBuf::from("prepared"),
            split: HELD_OUT.into(),
            val_every_scene: 5,
            eval: EvalConfig::default(),
            radar_drop: 0.0,
            failure: RadarFailure::default(),
            seed: 0,
            batch_size: 4,
            device: "auto".into(),
            jobs: 0,
            max_samples: None,
            radar_input: None,
            name: "model".into(),
            cuda_graph: false,
        }
    }
}

/// Loads a network for `eval` / `predict`: a depthsense checkpoint, or a PyTorch state dict
/// (the authors' released weights) with `config` naming the architecture (preset name or
/// model-config JSON; SPEC §6.1). `set` holds `key=value` overrides applied to `config` (or,
/// without `config`, to the checkpoint's stored config). Returns the import report for a
/// PyTorch file.
pub fn load_model(
    checkpoint_path: &Path,
    config: Option<&str>,
    set: &[String],
    device: tch::Device,
) -> Result<(Loaded, Option<LoadReport>), NetError> {
    let layout = InferenceLayout::Fastest;
    load_model_in(checkpoint_path, config, set, device, layout)
}

/// [`load_model`] with the inference graph's weights in `layout`: `explain`, which runs
/// backward through the graph, takes [`InferenceLayout::Nchw`].
pub fn load_model_in(
    checkpoint_path: &Path,
    config: Option<&str>,
    set: &[String],
    device: tch::Device,
    layout: InferenceLayout,
) -> Result<(Loaded, Option<LoadReport>), NetError> {
    let cfg = match (config, set.is_empty()) {
        (Some(c), _) => Some(depthsense_checkpoint::config::resolve(c)?.with_options(set)?),
        (None, true) => None,
        (None, false)
            if !depthsense_weights::torch_file::is_torch_file(checkpoint_path)
                .map_err(depthsense_model::ModelError::from)? =>
        {
            Some(
                checkpoint::read_config(checkpoint_path)?
                    .0
                    .with_options(set)?,
            )
        }
        (None, false) => None, // load_any names the missing --config
    };
    let (loaded, report) = checkpoint::load_any(checkpoint_path, cfg.as_ref(), device)?;
    // The inference graph: BatchNorm folded, the fused decode (issue 44).
    loaded.net.prepare_inference(layout);
    Ok((loaded, report))
}

/// Evaluate a checkpoint (see [`load_model`] for what `opts.checkpoint` may be). Returns the
/// report (every row).
pub fn run_eval(opts: &EvalOptions, progress: &Progress) -> Result<Report, NetError> {
    let device = depthsense_model::device::parse_device(&opts.device)?;
    let (loaded, _) = load_model(&opts.checkpoint, opts.config.as_deref(), &opts.set, device)?;
    run_eval_loaded(opts, &loaded, progress)
}

/// Evaluate an already loaded network (`opts.checkpoint`, `config` and `set` are not read).
pub fn run_eval_loaded(
    opts: &EvalOptions,
    loaded: &Loaded,
    progress: &Progress,
) -> Result<Report, NetError> {
    eval_with(opts, loaded, progress, |_, _| Ok(()))
}

/// What [`eval_with`] and [`write_predictions`] run over: the prepared folder, the samples of
/// the split and how they are loaded (the checkpoint's radar input, radar drop and failures).
fn eval_inputs(
    opts: &EvalOptions,
    loaded: &Loaded,
    progress: &Progress,
) -> Result<(Dataset, Vec<IndexEntry>, LoadOptions), NetError> {
    if !(0.0..=1.0).contains(&opts.radar_drop) {
        return Err(NetError::RadarDropNotAFraction(opts.radar_drop));
    }
    let ds = Dataset::open(&opts.data)?;
    let entries = subsample(
        &select_split(&ds, &opts.split, opts.val_every_scene)?,
        opts.max_samples,
    );
    let radar = loaded.config.radar_input_for(opts.radar_input)?;
    let load = LoadOptions {
        radar: radar.unwrap_or_default(),
        no_radar: radar.is_none(),
        radar_drop: opts.radar_drop,
        failure: opts.failure.clone(),
        seed: opts.seed,
        ..LoadOptions::default()
    };
    opts.failure.validate()?;
    progress.set_length(entries.len() as u64);
    progress.println(format!(
        "{} samples of {} (split {}) through {} on {}",
        entries.len(),
        opts.data.display(),
        opts.split,
        opts.checkpoint.display(),
        depthsense_model::device::describe(loaded.vs.device())
    ));
    Ok((ds, entries, load))
}

/// [`run_eval_loaded`] with a callback on every batch and its predictions.
fn eval_with(
    opts: &EvalOptions,
    loaded: &Loaded,
    progress: &Progress,
    on_batch: impl FnMut(&depthsense_data::Batch, &[f32]) -> Result<(), NetError>,
) -> Result<Report, NetError> {
    let (ds, entries, load) = eval_inputs(opts, loaded, progress)?;
    let run = run_plan(opts, loaded);
    evaluate_net_on(
        &loaded.net,
        &ds,
        &entries,
        &load,
        &opts.eval,
        &run,
        progress,
        on_batch,
    )
}

/// How `opts` runs the network.
fn run_plan(opts: &EvalOptions, loaded: &Loaded) -> RunPlan {
    RunPlan {
        batch_size: opts.batch_size,
        jobs: opts.jobs,
        device: loaded.vs.device(),
        cuda_graph: opts.cuda_graph,
    }
}

/// Writes the predictions of `opts`'s samples into `out` (`<token>.<ext>` per format) and says
/// how many, with where the time went. The files are encoded and written on a thread of their
/// own while the network runs on the next batch (the loader reads and rasterises ahead on its
/// threads): the network waits for neither.
pub fn write_predictions(
    opts: &EvalOptions,
    loaded: &Loaded,
    out: &Path,
    formats: &[PredFormat],
    progress: &Progress,
) -> Result<(usize, RunStats), NetError> {
    let (ds, entries, load) = eval_inputs(opts, loaded, progress)?;
    std::fs::create_dir_all(out).map_err(|e| NetError::io(out, e))?;
    let run = run_plan(opts, loaded);
    // (token, depth m, width, height) of one sample; a few batches may wait to be written.
    let (tx, rx) = std::sync::mpsc::sync_channel::<(String, Vec<f32>, usize, usize)>(
        4 * opts.batch_size.max(1),
    );
    std::thread::scope(|scope| {
        let writer = scope.spawn(move || -> Result<usize, NetError> {
            let mut n = 0usize;
            for (token, pred, w, h) in rx {
                for &f in formats {
                    write_prediction(out, &token, &pred, w, h, f)?;
                }
                n += 1;
            }
            Ok(n)
        });
        let stats = run_net(
            &loaded.net,
            &ds,
            &entries,
            &load,
            &run,
            progress,
            |b, pred| {
                let hw = b.width * b.height;
                for (i, s) in b.samples.iter().enumerate() {
                    let depth = pred[i * hw..(i + 1) * hw].to_vec();
                    // A closed channel: the writer stopped on an error, which join reports.
                    if tx
                        .send((s.token.clone(), depth, b.width, b.height))
                        .is_err()
                    {
                        break;
                    }
                }
                Ok(())
            },
        );
        drop(tx);
        let written = writer.join().map_err(|_| NetError::ThreadPanicked {
            thread: "prediction writer",
        })?;
        let stats = stats?;
        Ok((written?, stats))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use depthsense_config::ModelConfig;
    use depthsense_model::DepthNet;
    use tch::{nn::VarStore, Device, Tensor};

    fn narrow_released() -> ModelConfig {
        ModelConfig::released()
            .with_options(&[
                "width=8",
                "radar-width=8",
                "decoder-channels=16",
                "head-channels=16",
                "out-height=64",
                "out-width=128",
            ])
            .unwrap()
    }

    #[test]
    fn load_model_takes_a_pytorch_state_dict_with_config_and_our_checkpoints() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = narrow_released();
        let vs = VarStore::new(Device::Cpu);
        let _net = DepthNet::new(&vs.root(), &cfg).unwrap();
        // the authors' key names (SPEC §6.1), as `torch.save(model.state_dict())` writes them
        let theirs = |k: &str| -> String {
            if let Some(r) = k.strip_prefix("rgb.").or(k.strip_prefix("decoder.")) {
                format!("retinanet.backbone.{r}")
            } else if let Some(r) = k.strip_prefix("radar.conv_radar.") {
                format!("conv_radar.{r}")
            } else if let Some(r) = k.strip_prefix("radar.") {
                format!("resnet_radar.backbone.{r}")
            } else {
                k.replace("head.conv1", "concat_process.1")
                    .replace("head.conv2", "concat_process.4")
            }
        };
        let sd: Vec<(String, Tensor)> = vs
            .variables()
            .into_iter()
            .map(|(k, v)| (theirs(&k), v.detach() * 1.5))
            .collect();
        let pth = dir.path().join("paper_weights.pth");
        depthsense_weights::pth_writer::write_torch_state_dict(
            &pth,
            &depthsense_checkpoint::host::all_to_host(&sd).unwrap(),
        )
        .unwrap();

        // a .pth needs --config
        let e = load_model(&pth, None, &[], Device::Cpu)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("paper_weights.pth") && e.contains("--config"),
            "{e}"
        );
        // a JSON config works as well as a preset name; --set applies on top
        let json = dir.path().join("released-narrow.json");
        std::fs::write(&json, serde_json::to_string(&cfg).unwrap()).unwrap();
        let (l, rep) = load_model(
            &pth,
            Some(json.to_str().unwrap()),
            &["decode-offset=0.5".into()],
            Device::Cpu,
        )
        .unwrap();
        let rep = rep.unwrap();
        assert_eq!(rep.loaded.len(), sd.len());
        assert_eq!(l.config.sid.decode_offset_m, 0.5);
        assert!(l.config.clamp_logits && l.config.radar_in_metres);
        let k = "rgb.layer3.0.conv2.weight";
        assert!(l.vs.variables()[k].equal(&sd.iter().find(|x| x.0 == theirs(k)).unwrap().1));
        assert!(rep.to_string().starts_with("weights: "));
        // the wrong architecture names every mismatch
        let e = load_model(&pth, Some("released"), &[], Device::Cpu)
            .unwrap_err()
            .to_string();
        assert!(e.contains("mismatching shapes"), "{e}");

        // our checkpoints load as before; --set overrides the stored config
        let ck = dir.path().join("ck.safetensors");
        checkpoint::save(&ck, &l.vs, &l.config, &serde_json::Value::Null).unwrap();
        let (l2, rep2) = load_model(&ck, None, &[], Device::Cpu).unwrap();
        assert!(rep2.is_none());
        assert_eq!(l2.config, l.config);
        let (l3, _) = load_model(&ck, None, &["decode-offset=0".into()], Device::Cpu).unwrap();
        assert_eq!(l3.config.sid.decode_offset_m, 0.0);
    }
}
