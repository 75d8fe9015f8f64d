//! `depthsense export`: a trained network as ONNX, TorchScript or a PyTorch state dict, with a
//! sidecar JSON (crates/export; README "Deploying a trained model").

use std::path::PathBuf;
use std::process::ExitCode;

use depthsense_export::{export, Batch, ExportOptions, Format, Precision};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    model: super::model_source::ModelSource,
    /// onnx (opset 17: onnxruntime, TensorRT), torchscript (torch.jit.load, libtorch) or
    /// pytorch (a state dict for python/depthsense_torch.py).
    #[arg(long)]
    format: String,
    /// The file to write; its sidecar is FILE.json.
    #[arg(long)]
    out: PathBuf,
    /// Batch axis of the graph: `dynamic` (one file for every N) or a fixed N.
    #[arg(long, default_value = "dynamic")]
    batch: String,
    /// Arithmetic inside the graph: fp32 (fp16 is refused for now: plain half precision
    /// overflows in this network).
    #[arg(long, default_value = "fp32")]
    precision: String,
    /// Replace an existing FILE and FILE.json.
    #[arg(long)]
    force: bool,
    /// The Python (with torch; onnx for ONNX) that runs the conversion. Default:
    /// $DEPTHSENSE_PYTHON, the active virtual environment, the checkout's .venv, python3.
    #[arg(long)]
    python: Option<PathBuf>,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let opts = ExportOptions {
        checkpoint: a.model.checkpoint,
        config: a.model.config,
        set: a.model.set,
        format: Format::parse(&a.format)?,
        out: a.out,
        batch: Batch::parse(&a.batch)?,
        precision: Precision::parse(&a.precision)?,
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
