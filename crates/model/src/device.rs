//! Device selection (`--device auto|cpu|cuda|cuda:N`).

use depthsense_config::device::{DeviceSpec, InvalidDevice};
use tch::{Cuda, Device};

use crate::ModelError;

/// Parses `auto` (CUDA device 0 when libtorch sees a GPU, else CPU), `cpu`, `cuda` (= `cuda:0`)
/// or `cuda:N`. Asking for CUDA explicitly without a usable GPU is an error, not a silent
/// fall-back to the CPU.
pub fn parse_device(s: &str) -> Result<Device, ModelError> {
    let spec = DeviceSpec::parse(s).ok_or_else(|| InvalidDevice::of(s))?;
    let idx = match spec {
        DeviceSpec::Auto => return Ok(Device::cuda_if_available()),
        DeviceSpec::Cpu => return Ok(Device::Cpu),
        DeviceSpec::Cuda(idx) => idx,
    };
    let count = if Cuda::is_available() {
        Cuda::device_count()
    } else {
        0
    };
    if (idx as i64) >= count {
        return Err(ModelError::CudaUnavailable(
            s.trim().to_ascii_lowercase(),
            count,
        ));
    }
    Ok(Device::Cuda(idx))
}

/// A short human description (`cpu`, `cuda:0`).
pub fn describe(device: Device) -> String {
    match device {
        Device::Cpu => "cpu".to_string(),
        Device::Cuda(i) => format!("cuda:{i}"),
        other => format!("{other:?}").to_ascii_lowercase(),
    }
}

/// Turns cuDNN autotuning (`cudnn.benchmark`) on for a CUDA `device`: training, evaluation and
/// prediction run one fixed input size, so the per-shape algorithm search of the first
/// iteration pays back on every later one. Nothing on the CPU.
pub fn autotune_fixed_size(device: Device) {
    if device.is_cuda() {
        Cuda::cudnn_set_benchmark(true);
    }
}
