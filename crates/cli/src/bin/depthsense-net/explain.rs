//! `depthsense explain`: Grad-CAM++ maps by distance class (SPEC §10.6) of a checkpoint on (the network side; its flags: `depthsense_cli::cmd::explain`).

use depthsense_cli::cmd::explain::Args;
use depthsense_dataset::Dataset;
use depthsense_eval::explain::run_explain;
use depthsense_model::precision::InferenceLayout;
use depthsense_score::predictions::select_split;
use std::path::PathBuf;
use std::process::ExitCode;

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let dirs = if let Some(data) = &a.data {
        let ds = Dataset::open(data)?;
        let e =
            depthsense_dataset::subsample(&select_split(&ds, &a.split, 5)?, Some(a.max_samples));
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
    depthsense_dataset::outputs::refuse_existing(&own, a.force, "explain")?;
    let device = depthsense_model::device::parse_device(&a.device.name)?;
    let loaded = super::model_source::load(&a.model, device, InferenceLayout::Nchw)?;
    let r = run_explain(
        &loaded.net,
        &a.model.checkpoint,
        &dirs,
        &a.distances,
        a.band,
        &a.layer,
        &a.out,
        device,
        Some(depthsense_cli::command_line()),
    )?;
    println!("{}", std::fs::read_to_string(a.out.join("explain.md"))?);
    eprintln!(
        "{} maps; grid {}",
        r.records.len(),
        a.out.join(&r.grid).display()
    );
    Ok(ExitCode::SUCCESS)
}
