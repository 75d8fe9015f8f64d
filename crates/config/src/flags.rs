//! The words of the network commands' flags that are not model-config fields, without
//! libtorch, so that the `depthsense` front parses (and refuses) them like every other flag:
//! the arithmetic of a forward pass ([`Precision`]: `bench model`, training's AMP) and what
//! `export` writes ([`ExportFormat`], [`ExportPrecision`]). Each enum's words are its
//! [`Words`] list, written once.

use depthsense_base::words::Words;

/// Autocast dtype on CUDA (`depthsense_model::precision::with_autocast`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Precision {
    /// No autocast.
    Fp32,
    /// CUDA autocast to bfloat16.
    Bf16,
    /// CUDA autocast to float16.
    Fp16,
}

impl Words for Precision {
    const WHAT: &'static str = "precision";
    /// `f32`, `float`, `bfloat16`, `f16` and `half` are aliases.
    const WORDS: &'static [(&'static str, Self)] = &[
        ("fp32", Precision::Fp32),
        ("f32", Precision::Fp32),
        ("float", Precision::Fp32),
        ("bf16", Precision::Bf16),
        ("bfloat16", Precision::Bf16),
        ("fp16", Precision::Fp16),
        ("f16", Precision::Fp16),
        ("half", Precision::Fp16),
    ];
}

/// What an export writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExportFormat {
    /// ONNX (opset 17): onnxruntime, TensorRT.
    Onnx,
    /// A TorchScript archive: `torch.jit.load`, libtorch C++.
    TorchScript,
    /// `{"format", "config", "state_dict"}` for `python/depthsense_torch.py` (`torch.load`).
    PyTorch,
}

impl Words for ExportFormat {
    const WHAT: &'static str = "export format";
    const WORDS: &'static [(&'static str, Self)] = &[
        ("onnx", Self::Onnx),
        ("torchscript", Self::TorchScript),
        ("pytorch", Self::PyTorch),
    ];
}

impl ExportFormat {
    /// The name on the command line and in the sidecar.
    pub fn name(self) -> &'static str {
        self.word()
    }
}

/// Arithmetic precision of an exported network (inputs and output stay float32).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExportPrecision {
    Fp32,
    Fp16,
}

impl Words for ExportPrecision {
    const WHAT: &'static str = "export precision";
    const WORDS: &'static [(&'static str, Self)] = &[("fp32", Self::Fp32), ("fp16", Self::Fp16)];
}

impl ExportPrecision {
    /// The name on the command line and in the sidecar.
    pub fn name(self) -> &'static str {
        self.word()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use depthsense_base::words::check_vocabulary;

    #[test]
    fn vocabularies_hold_together() {
        check_vocabulary::<Precision>().unwrap();
        check_vocabulary::<ExportFormat>().unwrap();
        check_vocabulary::<ExportPrecision>().unwrap();
        assert_eq!(Precision::names(), ["fp32", "bf16", "fp16"]);
        assert_eq!(Precision::from_word("HALF"), Some(Precision::Fp16));
        assert_eq!(Precision::from_word("fp8"), None);
        assert_eq!(ExportFormat::TorchScript.name(), "torchscript");
        assert_eq!(
            ExportPrecision::from_word("FP16"),
            Some(ExportPrecision::Fp16)
        );
    }
}
