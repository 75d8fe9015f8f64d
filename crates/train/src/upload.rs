//! A batch onto the device: images, radar maps and targets as tensors, through pinned host
//! memory on CUDA (the training step and validation share it).

use tch::{Device, Kind, Tensor};

use depthsense_data::Batch;
use depthsense_model::ordinal::SparseTarget;

/// Tensors of a batch on `device`: (image [B,3,H,W], radar [B,C,H,W] (C ≥ 1; zeros when the
/// batch has no radar), target [B,1,H,W]).
pub fn batch_tensors(b: &Batch, device: Device) -> (Tensor, Tensor, Tensor) {
    let t = upload_batch(b, device);
    (t.image, t.radar, t.target_m)
}

/// A batch on the training device, with the target's valid pixels gathered on the host.
pub struct BatchTensors {
    /// [B,3,H,W]
    pub image: Tensor,
    /// [B,C,H,W], C ≥ 1 (zeros when the batch has no radar).
    pub radar: Tensor,
    /// [B,1,H,W] metres, 0 = invalid.
    pub target_m: Tensor,
    /// The valid pixels of `target_m` (the ordinal loss then needs no host synchronisation).
    pub sparse: SparseTarget,
}

/// [`batch_tensors`] plus the sparse target. One host copy per buffer: on the CPU into the
/// tensor; on CUDA into pinned memory, then a non-blocking host→device copy that the host
/// does not wait for (it overlaps the previous step's kernels still in the queue).
pub fn upload_batch(b: &Batch, device: Device) -> BatchTensors {
    let (n, h, w) = (b.size as i64, b.height as i64, b.width as i64);
    let (image, radar) = upload_inputs(b, device);
    let target_m = host_to_device(&b.target_m, &[n, 1, h, w], device);
    // Gathered on the host for CUDA (no `nonzero` sync); on the CPU `nonzero` costs no sync
    // and is faster than the host gather (BENCHMARKS.md, issue 9 item 3). Equal either way.
    let sparse = if device.is_cuda() {
        SparseTarget::from_host(&b.target_m, (n, h, w), device)
    } else {
        SparseTarget::from_dense(&target_m)
    };
    BatchTensors {
        image,
        radar,
        target_m,
        sparse,
    }
}

/// The network inputs of a batch (image, radar) on `device`, as in [`upload_batch`].
pub fn upload_inputs(b: &Batch, device: Device) -> (Tensor, Tensor) {
    let (n, h, w) = (b.size as i64, b.height as i64, b.width as i64);
    let image = host_to_device(&b.image, &[n, 3, h, w], device);
    let radar = if b.radar_channels == 0 {
        Tensor::zeros([n, 1, h, w], (Kind::Float, device))
    } else {
        host_to_device(&b.radar, &[n, b.radar_channels as i64, h, w], device)
    };
    (image, radar)
}

/// `data` as a `shape` f32 tensor on `device` with one host copy (see [`upload_batch`]).
fn host_to_device(data: &[f32], shape: &[i64], device: Device) -> Tensor {
    if !device.is_cuda() {
        return Tensor::from_slice(data).view(shape).to_device(device);
    }
    // SAFETY: the view borrows `data` (len × 4 bytes, f32-aligned, contiguous) only until
    // `pin_memory` has copied it into a freshly allocated pinned buffer; it is dropped at the
    // end of this statement while `data` is still borrowed.
    let pinned = unsafe {
        Tensor::from_blob(
            data.as_ptr().cast::<u8>(),
            shape,
            &[],
            Kind::Float,
            Device::Cpu,
        )
    }
    .pin_memory(device);
    // Non-blocking from pinned memory: the host returns at once. The caching host allocator
    // keeps the pinned block alive until the copy on the stream has finished.
    pinned.to_device_(device, Kind::Float, true, false)
}
