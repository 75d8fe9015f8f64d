//! `depthsense eval`: a checkpoint on prepared data → the tables of SPEC §10 items 1–3 as
//! Markdown, CSV and JSON, with the number of images and pixels behind each row; radar drop
//! for the sensor-failure ablation (SPEC §10.8).
//!
//! Every score goes through [`score_image`] (one image into the metrics [`Evaluator`]):
//! `eval --checkpoint` (via `trainer::evaluate_net`) and `eval --predictions` (any method's
//! depth maps on disk, [`run_eval_predictions`]) therefore share protocol, caps, GT,
//! conditions and tables exactly.

pub mod npy;

use std::path::{Path, PathBuf};

use depthsense_data::radar_failure::RadarFailure;
use depthsense_data::{partition, read_depth, Dataset, LoadOptions, RadarInput};
use depthsense_metrics::{tables, EvalConfig, Evaluator, Report};
use depthsense_model::checkpoint::{self, Loaded};
use depthsense_model::weights::LoadReport;
use depthsense_model::ModelConfig;
use depthsense_nuscenes::fsutil::write_atomic;
use depthsense_prep::layout::{IndexEntry, LIDAR_SPARSE_FILE};
use indicatif::ProgressBar;
use serde::{Deserialize, Serialize};

use depthsense_data::error::TrainError;
use depthsense_train::trainer::{evaluate_net, radar_input_for, subsample};
pub use depthsense_train::validate::{condition_names, score_image};

/// Which samples to evaluate.
pub const HELD_OUT: &str = "held-out";

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
        }
    }
}

/// Samples of a split name (see [`EvalOptions::split`]).
pub fn select_split(
    ds: &Dataset,
    split: &str,
    every: usize,
) -> Result<Vec<IndexEntry>, TrainError> {
    let v = if split == HELD_OUT {
        // The test scenes: never the validation scenes that selected the checkpoint.
        partition(ds, every)?.test
    } else {
        ds.split(split)
    };
    if v.is_empty() {
        return Err(TrainError::Data(format!(
            "{}: split {split:?} has no samples (splits present: {:?})",
            ds.root.display(),
            ds.split_names()
        )));
    }
    Ok(v)
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
) -> Result<(Loaded, Option<LoadReport>), TrainError> {
    let cfg = match (config, set.is_empty()) {
        (Some(c), _) => Some(ModelConfig::resolve(c)?.with_options(set)?),
        (None, true) => None,
        (None, false) if !checkpoint::is_torch_file(checkpoint_path)? => Some(
            checkpoint::read_config(checkpoint_path)?
                .0
                .with_options(set)?,
        ),
        (None, false) => None, // load_any names the missing --config
    };
    Ok(checkpoint::load_any(checkpoint_path, cfg.as_ref(), device)?)
}

/// Evaluate a checkpoint (see [`load_model`] for what `opts.checkpoint` may be). Returns the
/// report (every row).
pub fn run_eval(opts: &EvalOptions, progress: &ProgressBar) -> Result<Report, TrainError> {
    let device = depthsense_model::device::parse_device(&opts.device)?;
    let (loaded, _) = load_model(&opts.checkpoint, opts.config.as_deref(), &opts.set, device)?;
    run_eval_loaded(opts, &loaded, progress)
}

/// Evaluate an already loaded network (`opts.checkpoint`, `config` and `set` are not read).
pub fn run_eval_loaded(
    opts: &EvalOptions,
    loaded: &Loaded,
    progress: &ProgressBar,
) -> Result<Report, TrainError> {
    eval_with(opts, loaded, progress, |_, _| Ok(()))
}

/// [`run_eval_loaded`] with a callback on every batch and its predictions.
fn eval_with(
    opts: &EvalOptions,
    loaded: &Loaded,
    progress: &ProgressBar,
    on_batch: impl FnMut(&depthsense_data::Batch, &[f32]) -> Result<(), TrainError>,
) -> Result<Report, TrainError> {
    if !(0.0..=1.0).contains(&opts.radar_drop) {
        return Err(TrainError::Config(format!(
            "--radar-drop must be within [0, 1], got {}",
            opts.radar_drop
        )));
    }
    let device = loaded.vs.device();
    let ds = Dataset::open(&opts.data)?;
    let entries = subsample(
        &select_split(&ds, &opts.split, opts.val_every_scene)?,
        opts.max_samples,
    );
    let radar = radar_input_for(&loaded.config, opts.radar_input)?;
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
    evaluate_net(
        &loaded.net,
        &ds,
        &entries,
        &load,
        &opts.eval,
        opts.batch_size,
        opts.jobs,
        device,
        progress,
        on_batch,
    )
}

/// What the scorer needs of a prepared sample: sparse GT and low-height mask.
#[derive(Debug, Clone)]
pub struct GroundTruth {
    pub width: usize,
    pub height: usize,
    pub sparse_m: Vec<f32>,
    /// Empty when the sample has no mask file.
    pub lowheight: Vec<bool>,
}

/// Read a sample's sparse GT and low-height mask (what `load_sample` reads with `eval_maps`).
pub fn load_ground_truth(ds: &Dataset, e: &IndexEntry) -> Result<GroundTruth, TrainError> {
    let dir = ds.sample_dir(e);
    let gt = read_depth(&dir.join(LIDAR_SPARSE_FILE))?;
    let (w, h) = (gt.width as usize, gt.height as usize);
    let lowheight = depthsense_data::read_lowheight_mask(&dir, w, h)?;
    Ok(GroundTruth {
        width: w,
        height: h,
        sparse_m: gt.depth_m,
        lowheight,
    })
}

/// File formats of predictions on disk.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PredFormat {
    /// 16-bit PNG, depth × 256, 0 = no prediction (KITTI convention, SPEC §3).
    Png,
    /// NumPy float32 metres.
    Npy,
}

impl PredFormat {
    pub fn ext(self) -> &'static str {
        match self {
            PredFormat::Png => "png",
            PredFormat::Npy => "npy",
        }
    }
}

impl std::str::FromStr for PredFormat {
    type Err = TrainError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "png" => Ok(Self::Png),
            "npy" => Ok(Self::Npy),
            o => Err(TrainError::Config(format!(
                "unknown prediction format {o:?} (png, npy)"
            ))),
        }
    }
}

/// The prediction file of a sample in `dir`: `<token>.npy`, `<token>.png`,
/// `<token>/depth.npy` or `<token>/depth.png` (first found, in that order).
pub fn find_prediction(dir: &Path, token: &str) -> Option<(PathBuf, PredFormat)> {
    [
        (dir.join(format!("{token}.npy")), PredFormat::Npy),
        (dir.join(format!("{token}.png")), PredFormat::Png),
        (dir.join(token).join("depth.npy"), PredFormat::Npy),
        (dir.join(token).join("depth.png"), PredFormat::Png),
    ]
    .into_iter()
    .find(|(p, _)| p.is_file())
}

/// Read one prediction file as (values in metres, width, height).
pub fn read_prediction(path: &Path, f: PredFormat) -> Result<(Vec<f32>, usize, usize), TrainError> {
    match f {
        PredFormat::Png => {
            let m = read_depth(path)?;
            Ok((m.depth_m, m.width as usize, m.height as usize))
        }
        PredFormat::Npy => {
            let bytes = std::fs::read(path).map_err(|e| TrainError::io(path, e))?;
            let (v, h, w) = npy::decode(&bytes, path)?;
            Ok((v, w, h))
        }
    }
}

/// Write one prediction (metres, `w`x`h`) as `<dir>/<token>.<ext>`.
pub fn write_prediction(
    dir: &Path,
    token: &str,
    pred: &[f32],
    w: usize,
    h: usize,
    f: PredFormat,
) -> Result<PathBuf, TrainError> {
    let p = dir.join(format!("{token}.{}", f.ext()));
    let bytes = match f {
        PredFormat::Npy => npy::encode_f32(pred, h, w),
        PredFormat::Png => {
            depthsense_nuscenes::depth_png::encode_png(&depthsense_nuscenes::depth_png::DepthMap {
                width: w as u32,
                height: h as u32,
                depth_m: pred.to_vec(),
            })
            .map_err(|e| TrainError::Data(e.to_string()))?
        }
    };
    write_atomic(&p, &bytes).map_err(|e| TrainError::io(&p, e))?;
    Ok(p)
}

/// `eval --predictions`: another method's depth maps, one per sample token.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PredictionsOptions {
    /// Folder of `<token>.png` / `<token>.npy` (see [`find_prediction`]).
    pub dir: PathBuf,
    pub data: PathBuf,
    pub split: String,
    pub val_every_scene: usize,
    pub eval: EvalConfig,
    pub max_samples: Option<usize>,
    /// Samples of the split without a prediction file: an error (false) or skipped and
    /// counted (true).
    pub allow_missing: bool,
}

/// What was scored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PredictionsSummary {
    pub scored: usize,
    pub png: usize,
    pub npy: usize,
    /// Tokens of the split without a prediction file.
    pub missing: Vec<String>,
}

/// Score prediction files with exactly the `eval --checkpoint` protocol ([`score_image`]).
pub fn run_eval_predictions(
    opts: &PredictionsOptions,
    progress: &ProgressBar,
) -> Result<(Report, PredictionsSummary), TrainError> {
    let ds = Dataset::open(&opts.data)?;
    let entries = subsample(
        &select_split(&ds, &opts.split, opts.val_every_scene)?,
        opts.max_samples,
    );
    let mut ev = Evaluator::new(opts.eval.clone())?;
    let mut sum = PredictionsSummary {
        scored: 0,
        png: 0,
        npy: 0,
        missing: vec![],
    };
    progress.set_length(entries.len() as u64);
    for e in &entries {
        progress.inc(1);
        let Some((path, fmt)) = find_prediction(&opts.dir, &e.sample_token) else {
            sum.missing.push(e.sample_token.clone());
            continue;
        };
        let gt = load_ground_truth(&ds, e)?;
        let (pred, w, h) = read_prediction(&path, fmt)?;
        if (w, h) != (gt.width, gt.height) {
            return Err(TrainError::Data(format!(
                "{}: prediction is {w}x{h} but the ground truth of the training frame is {}x{} \
                 (SPEC §3: predictions must be in the 800x350 frame `prepare` writes)",
                path.display(),
                gt.width,
                gt.height
            )));
        }
        score_image(&mut ev, &gt.sparse_m, &gt.lowheight, &e.conditions, &pred)?;
        sum.scored += 1;
        match fmt {
            PredFormat::Png => sum.png += 1,
            PredFormat::Npy => sum.npy += 1,
        }
    }
    if !sum.missing.is_empty() && !opts.allow_missing {
        return Err(TrainError::Data(format!(
            "{}: {} of {} samples of split {:?} have no prediction (e.g. {}.png / .npy); pass \
             --allow-missing to score the others",
            opts.dir.display(),
            sum.missing.len(),
            entries.len(),
            opts.split,
            sum.missing[0]
        )));
    }
    Ok((ev.finish(), sum))
}

/// Run a network over the samples of `opts` (as `eval` would) and write each prediction as
/// `<out>/<token>.<ext>` for every format in `formats`; returns the report and the count.
pub fn write_predictions(
    opts: &EvalOptions,
    loaded: &Loaded,
    out: &Path,
    formats: &[PredFormat],
    progress: &ProgressBar,
) -> Result<(Report, usize), TrainError> {
    std::fs::create_dir_all(out).map_err(|e| TrainError::io(out, e))?;
    let mut n = 0usize;
    let report = eval_with(opts, loaded, progress, |b, pred| {
        let hw = b.width * b.height;
        for (i, s) in b.samples.iter().enumerate() {
            for &f in formats {
                write_prediction(
                    out,
                    &s.token,
                    &pred[i * hw..(i + 1) * hw],
                    b.width,
                    b.height,
                    f,
                )?;
            }
            n += 1;
        }
        Ok(())
    })?;
    Ok((report, n))
}

/// The files [`write_tables`] writes.
pub const TABLE_FILES: [&str; 3] = ["tables.md", "tables.csv", "tables.json"];

/// [`TABLE_FILES`] in `dir`.
pub fn table_paths(dir: &Path) -> Vec<PathBuf> {
    TABLE_FILES.iter().map(|f| dir.join(f)).collect()
}

/// Write `tables.md`, `tables.csv` and `tables.json` (every row of every report plus the
/// three rendered tables) into `dir`.
pub fn write_tables(dir: &Path, models: &[(&str, &Report)]) -> Result<(), TrainError> {
    write_tables_with_command(dir, models, None)
}

/// [`write_tables`], recording the invocation as `command_line` in tables.json and as a last
/// "Command:" line of tables.md (`depthsense report` shows it).
pub fn write_tables_with_command(
    dir: &Path,
    models: &[(&str, &Report)],
    command_line: Option<&str>,
) -> Result<(), TrainError> {
    std::fs::create_dir_all(dir).map_err(|e| TrainError::io(dir, e))?;
    let mut md = tables::markdown_report(models);
    md.push_str(&depthsense_metrics::table::md_command_line(command_line));
    let csv = tables::csv_report(models);
    let json = serde_json::json!({
        "models": models.iter().map(|(n, r)| serde_json::json!({"name": n, "report": r})).collect::<Vec<_>>(),
        "tables": tables::all_tables(models),
        "command_line": command_line,
    });
    let w = |name: &str, bytes: &[u8]| {
        let p = dir.join(name);
        write_atomic(&p, bytes).map_err(|e| TrainError::io(&p, e))
    };
    w("tables.md", md.as_bytes())?;
    w("tables.csv", csv.as_bytes())?;
    w(
        "tables.json",
        serde_json::to_string_pretty(&json)
            .map_err(|e| TrainError::Other(e.to_string()))?
            .as_bytes(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use depthsense_model::{pickle, DepthNet};
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
        pickle::write_torch_state_dict(&pth, &sd).unwrap();

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
