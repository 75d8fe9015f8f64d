//! `depthsense eval`: the paper's tables (SPEC §10 items 1–3) for a checkpoint, or for any
//! method's predictions on disk (`--predictions DIR`), through the same scorer.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use depthsense_dataset::outputs::refuse_existing;
use depthsense_metrics::EvalConfig;
use depthsense_score::predictions::{run_eval_predictions, PredictionsOptions};
use depthsense_score::tables::{table_paths, write_tables_with_command};

use super::progress::progress_bar;

use crate::cmd::heading as h;

/// `eval --help`'s examples (each parsed by the docs test through docs/guide/cli.md).
const EXAMPLES: &str = "Examples:
  depthsense eval --checkpoint runs/paper/best.safetensors --data data/prepared
  depthsense eval --checkpoint paper_weights_rvmde.pth --config released --data data/prepared --out runs/released/eval
  depthsense eval --checkpoint runs/paper/best.safetensors --data data/prepared --radar-drop 1.0 --out runs/paper/eval-no-radar
  depthsense eval --predictions preds/other --data data/prepared --protocol radarnet --caps 50,70,80
(docs/guide/evaluate.md: splits, protocols, sensor failure, other methods' predictions)";

#[derive(clap::Args)]
#[command(after_help = EXAMPLES)]
#[command(group(clap::ArgGroup::new("what").required(true).args(["checkpoint", "predictions"])))]
pub struct Args {
    /// Checkpoint written by `train` (e.g. RUN/best.safetensors), or a PyTorch state dict
    /// such as the authors' paper_weights_rvmde.pth together with `--config released`.
    #[arg(long, help_heading = h::MODEL)]
    pub checkpoint: Option<PathBuf>,
    /// Instead of a checkpoint: a folder of another method's predictions, one per sample
    /// token, in the 800x350 training frame: <token>.png (16-bit, depth×256, KITTI
    /// convention) or <token>.npy (float32 metres), or <token>/depth.{npy,png}. Scored with
    /// exactly the same protocol, caps, GT and tables as --checkpoint.
    #[arg(long, help_heading = h::MODEL, conflicts_with_all = ["checkpoint", "config", "set", "radar_drop", "radar_input", "drop_radars", "drop_beyond_m", "clutter"])]
    pub predictions: Option<PathBuf>,
    /// With --predictions: score the samples that have a file and list the others, instead
    /// of failing when some are missing.
    #[arg(long, help_heading = h::MODEL, requires = "predictions")]
    pub allow_missing: bool,
    #[arg(long, help_heading = h::MODEL, value_parser = depthsense_config::cli::parse_config_spec,
          help = depthsense_config::cli::config_help("Architecture", ", a model-config JSON or an export sidecar (FILE.json \
                     of `export`). Required for a PyTorch .pth; for a depthsense checkpoint it \
                     replaces the stored config"))]
    pub config: Option<String>,
    #[arg(long = "set", help_heading = h::MODEL, value_name = "KEY=VALUE", value_parser = depthsense_config::cli::parse_set,
          help = crate::cmd::SET_HELP)]
    pub set: Vec<String>,
    /// Prepared data directory (holds index.json).
    #[arg(long, help_heading = h::DATA)]
    pub data: PathBuf,
    /// Output directory for tables.md, tables.csv and tables.json
    /// (default: an `eval/` folder beside the checkpoint).
    #[arg(long, help_heading = h::OUTPUT)]
    pub out: Option<PathBuf>,
    /// Samples: held-out (the `test` split, or the scenes `train` held out), all, or a split
    /// name of the index (test-day, test-night, official-val, …).
    #[arg(long, help_heading = h::DATA, default_value = "held-out")]
    pub split: String,
    /// Scene modulo `train` used to hold scenes out when no split lists matched.
    #[arg(long, help_heading = h::DATA, default_value_t = 5)]
    pub val_every_scene: usize,
    /// Fraction of radar points removed at random (1.0 = radar absent): sensor failure.
    #[arg(long, help_heading = h::FAILURE, default_value_t = 0.0)]
    pub radar_drop: f64,
    /// Radars absent (sensor failure): channel names, comma separated (e.g.
    /// RADAR_FRONT_LEFT,RADAR_FRONT_RIGHT), or `all`. Dropping only some of a sample's radars
    /// re-rasterises its radar_points.bin without them (samples prepared before that file
    /// existed are refused: re-run `depthsense prepare`).
    #[arg(long, help_heading = h::FAILURE, value_delimiter = ',')]
    pub drop_radars: Vec<String>,
    /// Remove every radar return (and its height strip) deeper than this many metres.
    #[arg(long, help_heading = h::FAILURE)]
    pub drop_beyond_m: Option<f64>,
    /// Add this many ghost radar points per sample (deterministic in --seed; the rule:
    /// docs/guide/evaluate.md, "Sensor failure at test time").
    #[arg(long, help_heading = h::FAILURE, default_value_t = 0)]
    pub clutter: usize,
    /// Seed of the radar drop and of the clutter.
    #[arg(long, help_heading = h::FAILURE, default_value_t = 0)]
    pub seed: u64,
    #[command(flatten, next_help_heading = h::SCORING)]
    pub scoring: crate::cmd::scoring_args::ScoringArgs,
    /// Depth caps in metres (comma-separated).
    #[arg(long, help_heading = h::SCORING, value_delimiter = ',', default_value = "50,70,80")]
    pub caps: Vec<f64>,
    #[command(flatten, next_help_heading = h::INFERENCE)]
    pub run: crate::cmd::inference_args::InferenceArgs,
    /// Radar map(s): height, raw, raw-height or mer (default: from the checkpoint's config).
    #[arg(long, help_heading = h::DATA, value_parser = depthsense_config::cli::parse_value("radar-input"))]
    pub radar_input: Option<String>,
    /// Model name in the tables (default: the checkpoint's run folder, e.g. `rgb` for
    /// runs/demo/rgb/best.safetensors; a checkpoint outside a run folder: its file name without
    /// the extension; with --predictions: the folder's name).
    #[arg(long, help_heading = h::OUTPUT)]
    pub name: Option<String>,
    /// Replace tables an earlier `eval` wrote in the output folder (only tables.md, tables.csv
    /// and tables.json); without it they are refused before anything is computed.
    #[arg(long, help_heading = h::OUTPUT)]
    pub force: bool,
}

/// The model's name in the tables: `--name`, else [`default_name`] of the checkpoint or the
/// predictions folder.
pub fn model_name(a: &Args) -> String {
    if let Some(n) = &a.name {
        return n.clone();
    }
    match (&a.checkpoint, &a.predictions) {
        (Some(c), _) => default_name(c),
        (None, Some(dir)) => dir_name(dir).unwrap_or_else(|| "model".into()),
        (None, None) => "model".into(),
    }
}

/// A checkpoint's name: its run folder's (the folder of a run's checkpoint file —
/// `best.safetensors`, `last.safetensors` — or of a folder holding the run's `config.json`),
/// else its file name without the extension (`paper_weights_rvmde.pth` →
/// `paper_weights_rvmde`).
pub fn default_name(checkpoint: &Path) -> String {
    use depthsense_dataset::outputs::{BEST_CKPT, CONFIG_FILE, LAST_CKPT};
    let file = checkpoint.file_name().and_then(|n| n.to_str());
    let parent = checkpoint.parent().filter(|p| !p.as_os_str().is_empty());
    let in_run = file.is_some_and(|f| f == BEST_CKPT || f == LAST_CKPT)
        || parent.is_some_and(|p| p.join(CONFIG_FILE).is_file());
    if in_run {
        if let Some(run) = parent.and_then(dir_name) {
            return run;
        }
    }
    checkpoint
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "model".into())
}

/// The last component of a folder's path (`runs/demo/rgb` → `rgb`; `.` and `..` through the
/// folder they name).
fn dir_name(dir: &Path) -> Option<String> {
    let name = |d: &Path| d.file_name().map(|n| n.to_string_lossy().into_owned());
    name(dir).or_else(|| name(&std::fs::canonicalize(dir).ok()?))
}

/// The metrics settings of the command line.
pub fn eval_config(a: &Args) -> anyhow::Result<EvalConfig> {
    Ok(EvalConfig {
        caps_m: a.caps.clone(),
        protocol: a.scoring.protocol,
        aggregate: a.scoring.aggregate,
        ..EvalConfig::default()
    })
}

/// `eval --predictions DIR` (torch-free: `depthsense` runs it itself).
pub fn run_predictions(a: Args, dir: PathBuf) -> anyhow::Result<ExitCode> {
    let out = a.out.clone().unwrap_or_else(|| dir.join("eval"));
    refuse_existing(&table_paths(&out), a.force, "eval")?;
    let opts = PredictionsOptions {
        dir,
        data: a.data.clone(),
        split: a.split.clone(),
        val_every_scene: a.val_every_scene,
        eval: eval_config(&a)?,
        max_samples: a.run.max_samples,
        allow_missing: a.allow_missing,
    };
    let pb = progress_bar("eval");
    let (report, sum) = run_eval_predictions(&opts, &pb)?;
    pb.finish_and_clear();
    let name = model_name(&a);
    let models = [(name.as_str(), &report)];
    write_tables_with_command(&out, &models, Some(&crate::command_line()))?;
    println!("{}", depthsense_metrics::tables::markdown_report(&models));
    eprintln!(
        "{} predictions scored ({} png, {} npy), {} samples without a file; tables written to \
         {}/tables.{{md,csv,json}}",
        sum.scored,
        sum.png,
        sum.npy,
        sum.missing.len(),
        out.display()
    );
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run's checkpoint is named after its run folder; any other file after its stem.
    #[test]
    fn the_default_name_is_the_run_folder() {
        assert_eq!(
            default_name(Path::new("runs/demo/rgb/best.safetensors")),
            "rgb"
        );
        assert_eq!(
            default_name(Path::new("runs/abl/late-sam/last.safetensors")),
            "late-sam"
        );
        assert_eq!(
            default_name(Path::new("paper_weights_rvmde.pth")),
            "paper_weights_rvmde"
        );
        assert_eq!(default_name(Path::new("best.safetensors")), "best");
        assert_eq!(
            default_name(Path::new("weights/fusion.safetensors")),
            "fusion"
        );
        // A checkpoint of another name inside a run folder (one holding config.json).
        let tmp = tempfile::tempdir().unwrap();
        let run = tmp.path().join("fusion-long");
        std::fs::create_dir_all(&run).unwrap();
        std::fs::write(run.join("config.json"), "{}").unwrap();
        assert_eq!(default_name(&run.join("epoch3.safetensors")), "fusion-long");
        assert_eq!(
            dir_name(Path::new("runs/other-method/")).as_deref(),
            Some("other-method")
        );
    }
}
