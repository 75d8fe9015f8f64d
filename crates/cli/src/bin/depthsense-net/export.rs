//! `depthsense export`: a trained network as ONNX, TorchScript or a PyTorch state dict, with a (the network side; its flags: `depthsense_cli::cmd::export`).

use depthsense_cli::cmd::export::Args;
use depthsense_export::{export, Batch, ExportOptions};
use std::process::ExitCode;

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let opts = ExportOptions {
        checkpoint: a.model.checkpoint,
        config: a.model.config,
        set: a.model.set,
        format: a.format,
        out: a.out,
        batch: Batch::parse(&a.batch)?,
        precision: a.precision,
        force: a.force,
        python: a.python,
    };
    let done = export(&opts)?;
    let inputs: Vec<String> = done
        .info
        .inputs
        .iter()
        .map(|t| format!("{} [{}]", t.name, dims(&t.shape)))
        .collect();
    println!(
        "exported {} ({}, batch {}, {}): inputs {}; output depth [{}] in metres; sidecar {}",
        done.out.display(),
        done.info.format,
        done.info.batch,
        done.info.precision,
        inputs.join(", "),
        dims(&done.info.output.shape),
        done.sidecar.display()
    );
    Ok(ExitCode::SUCCESS)
}

/// `N, 3, 350, 800` from the sidecar's shape.
fn dims(shape: &[serde_json::Value]) -> String {
    let d: Vec<String> = shape
        .iter()
        .map(|v| v.as_str().map_or_else(|| v.to_string(), str::to_string))
        .collect();
    d.join(", ")
}
