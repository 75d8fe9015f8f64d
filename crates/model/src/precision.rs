//! Mixed precision: bf16 (or fp16) autocast on CUDA, through `torch_ext::cuda_autocast` (the
//! device-typed libtorch API: `tch::autocast` logs a deprecation warning on every call and knows
//! only fp16).

use depthsense_config::flags::Precision;
use tch::Kind;

/// Runs `f` under CUDA autocast with the given dtype (fp32: none). Without a GPU the autocast
/// state is still set and restored — CPU kernels do not read it, so nothing changes — which
/// keeps the path that a GPU run takes exercised on the CPU (the dry run of gpu-check, `train
/// --amp` in the tests).
pub fn with_autocast<T>(precision: Precision, f: impl FnOnce() -> T) -> T {
    if precision == Precision::Fp32 {
        return f();
    }
    let dtype = if precision == Precision::Bf16 {
        Kind::BFloat16
    } else {
        Kind::Half
    };
    depthsense_torch_ext::cuda_autocast(dtype, f)
}

/// The same logical NCHW tensor with channels-last (NHWC) strides (tch has no memory-format
/// API; permute → contiguous → permute back gives the layout cuDNN's NHWC kernels use).
pub fn channels_last(t: &tch::Tensor) -> tch::Tensor {
    if t.dim() != 4 {
        return t.shallow_clone();
    }
    t.permute([0, 2, 3, 1]).contiguous().permute([0, 3, 1, 2])
}

/// The memory layout of the inference graph's folded conv weights
/// ([`crate::DepthNet::prepare_inference`]). A conv whose weight is channels-last runs
/// channels-last (libtorch follows the weight's layout as well as the input's), and its output
/// carries the layout on through the convs after it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InferenceLayout {
    /// The layout measured fastest on the weights' device: channels-last on the CPU (oneDNN;
    /// `paper`, batch 1, 350x800 on a 2-core EPYC: 700 → 632 ms, BENCHMARKS.md), NCHW on
    /// CUDA (its fp32 forward has not been measured channels-last).
    Fastest,
    /// NCHW everywhere: for a caller that runs backward through the inference graph
    /// (`explain`), since libtorch 2.11's CPU backward crashed with channels-last weights.
    Nchw,
}

impl InferenceLayout {
    /// Whether folded weights on `device` are stored channels-last.
    pub fn channels_last_on(self, device: tch::Device) -> bool {
        self == InferenceLayout::Fastest && device == tch::Device::Cpu
    }
}

/// Converts every 4-d variable (conv weights) of `vs` to channels-last storage in place.
/// Use on CUDA: libtorch 2.11's CPU backward crashed with channels-last weights at 175x400.
pub fn vs_to_channels_last(vs: &tch::nn::VarStore) {
    tch::no_grad(|| {
        for (_, mut v) in vs.variables() {
            if v.dim() == 4 {
                let cl = channels_last(&v);
                v.set_data(&cl);
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind, Tensor};

    #[test]
    fn bf16_autocast_runs_convolutions_in_bf16() {
        if !tch::Cuda::is_available() {
            eprintln!("skipped: bf16 autocast is CUDA-only and no CUDA device is present");
            return;
        }
        let x = Tensor::randn([1, 3, 8, 8], (Kind::Float, Device::Cuda(0)));
        let w = Tensor::randn([4, 3, 3, 3], (Kind::Float, Device::Cuda(0)));
        let y = with_autocast(Precision::Bf16, || {
            x.conv2d(&w, None::<Tensor>, [1], [1], [1], 1)
        });
        assert_eq!(y.kind(), Kind::BFloat16);
        let y = with_autocast(Precision::Fp32, || {
            x.conv2d(&w, None::<Tensor>, [1], [1], [1], 1)
        });
        assert_eq!(y.kind(), Kind::Float);
    }
}
