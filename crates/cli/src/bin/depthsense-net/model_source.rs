//! Loading the network a command names (`depthsense_cli::cmd::model_source::ModelSource`:
//! `--checkpoint`, `--config`, `--set`), as `predict`, `export`, `explain` and
//! `experiment failure|perturb` take it.

use depthsense_checkpoint::Loaded;
use depthsense_cli::cmd::model_source::ModelSource;
use depthsense_eval::evaluate::load_model_in;
use depthsense_model::precision::InferenceLayout;

/// Loads the network on `device` as the inference graph, its folded weights in `layout`
/// (`InferenceLayout::Fastest`, or `Nchw` for `explain`, which runs backward through it); a
/// PyTorch file's import report goes to stderr.
pub fn load(
    source: &ModelSource,
    device: tch::Device,
    layout: InferenceLayout,
) -> anyhow::Result<Loaded> {
    let (loaded, report) = load_model_in(
        &source.checkpoint,
        source.config.as_deref(),
        &source.set,
        device,
        layout,
    )?;
    if let Some(r) = &report {
        eprint!("{}: {r}", source.checkpoint.display());
    }
    Ok(loaded)
}
