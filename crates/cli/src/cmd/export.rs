//! `depthsense export`: a trained network as ONNX, TorchScript or a PyTorch state dict, with a
//! sidecar JSON (crates/export; docs/guide/deploy.md).

use std::path::PathBuf;

use crate::cmd::heading as h;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten, next_help_heading = h::MODEL)]
    pub model: super::model_source::ModelSource,
    /// onnx (opset 17: onnxruntime, TensorRT), torchscript (torch.jit.load, libtorch) or
    /// pytorch (a state dict for python/depthsense_torch.py).
    #[arg(long, help_heading = h::OUTPUT, value_parser = crate::cmd::words::words::<depthsense_config::flags::ExportFormat>())]
    pub format: depthsense_config::flags::ExportFormat,
    /// The file to write; its sidecar is FILE.json.
    #[arg(long, help_heading = h::OUTPUT)]
    pub out: PathBuf,
    /// Batch axis of the graph: `dynamic` (one file for every N) or a fixed N.
    #[arg(long, help_heading = h::OUTPUT, default_value = "dynamic")]
    pub batch: String,
    /// Arithmetic inside the graph: fp32, or fp16 (half precision between float32 inputs and
    /// output; the radar pooling and the decode stay float32). onnx and torchscript only.
    #[arg(long, help_heading = h::OUTPUT, default_value = "fp32",
          value_parser = crate::cmd::words::words::<depthsense_config::flags::ExportPrecision>())]
    pub precision: depthsense_config::flags::ExportPrecision,
    /// Replace an existing FILE and FILE.json.
    #[arg(long, help_heading = h::OUTPUT)]
    pub force: bool,
    /// The Python (with torch; onnx for ONNX) that runs the conversion. Default:
    /// $DEPTHSENSE_PYTHON, the active virtual environment, the checkout's .venv, python3.
    #[arg(long, help_heading = h::OUTPUT)]
    pub python: Option<PathBuf>,
}
