//! `depthsense explain`: Grad-CAM++ maps by distance class (SPEC §10.6) of a checkpoint on
//! prepared samples, with and without radar (target and formulas: README "Grad-CAM++").

use std::path::PathBuf;
use std::process::ExitCode;

use depthsense_data::Dataset;
use depthsense_eval::evaluate::{load_model, select_split};
use depthsense_eval::explain::run_explain;

#[derive(clap::Args)]
pub struct Args {
    /// Checkpoint (depthsense .safetensors, or a .pth with --config).
    #[arg(long)]
    checkpoint: PathBuf,
    /// Architecture for a .pth: a preset or a model-config JSON.
    #[arg(long)]
    config: Option<String>,
    /// One prepared sample directory (repeatable).
    #[arg(long, conflicts_with = "data")]
    sample: Vec<PathBuf>,
    /// Or: a prepared data directory; its --split samples, at most --max-samples of them.
    #[arg(long)]
    data: Option<PathBuf>,
    /// With --data: held-out (test scenes), all, or a split name.
    #[arg(long, default_value = "held-out")]
    split: String,
    /// With --data: how many samples (evenly spaced).
    #[arg(long, default_value_t = 2)]
    max_samples: usize,
    /// Distance classes d in metres, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "35,55,70")]
    distances: Vec<f64>,
    /// Half-width of the band around d, as a fraction of d (0.1 = ±10 %).
    #[arg(long, default_value_t = 0.1)]
    band: f64,
    /// Layers, comma separated: rgb.layer1 … rgb.layer4, decoder, radar (late fusion).
    #[arg(long, value_delimiter = ',', default_value = "rgb.layer4,radar")]
    layer: Vec<String>,
    /// Output directory: overlays, grid.png, explain.{json,md}.
    #[arg(long)]
    out: PathBuf,
    /// Device: auto, cpu, cuda or cuda:N.
    #[arg(long, default_value = "auto")]
    device: String,
    /// Replace the results of an earlier `explain` in --out (its explain.json, explain.md,
    /// grid.png and overlays of the same names); without it they are refused.
    #[arg(long)]
    force: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let dirs = if let Some(data) = &a.data {
        let ds = Dataset::open(data)?;
        let e = depthsense_train::trainer::subsample(
            &select_split(&ds, &a.split, 5)?,
            Some(a.max_samples),
        );
        e.iter().map(|x| ds.sample_dir(x)).collect()
    } else {
        a.sample.clone()
    };
    if dirs.is_empty() {
        anyhow::bail!("give --sample DIR (repeatable) or --data P");
    }
    let own: Vec<PathBuf> = ["explain.json", "explain.md", "grid.png"]
        .iter()
        .map(|f| a.out.join(f))
        .collect();
    depthsense_train::outputs::refuse_existing(&own, a.force, "explain")?;
    let device = depthsense_model::device::parse_device(&a.device)?;
    let (loaded, _) = load_model(&a.checkpoint, a.config.as_deref(), &[], device)?;
    let r = run_explain(
        &loaded.net,
        &a.checkpoint,
        &dirs,
        &a.distances,
        a.band,
        &a.layer,
        &a.out,
        device,
        Some(std::env::args().collect::<Vec<_>>().join(" ")),
    )?;
    println!("{}", std::fs::read_to_string(a.out.join("explain.md"))?);
    eprintln!(
        "{} maps; grid {}",
        r.records.len(),
        a.out.join(&r.grid).display()
    );
    Ok(ExitCode::SUCCESS)
}
