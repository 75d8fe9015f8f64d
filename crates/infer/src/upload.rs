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
    // `to_device_nonblocking` has read it (into a pinned buffer, or by a blocking copy); it is
    // dropped at the end of this function while `data` is still borrowed.
    let view = unsafe {
        Tensor::from_blob(
            data.as_ptr().cast::<u8>(),
            shape,
            &[],
            Kind::Float,
            Device::Cpu,
        )
    };
    depthsense_torch_ext::to_device_nonblocking(&view, device)
}

#[cfg(test)]
mod tests {
    use super::*;
    use depthsense_data::{Batch, EpochPlan, LoadOptions, Loader, TargetKind};
    use depthsense_dataset::Dataset;
    use depthsense_model::ordinal::SparseTarget;
    use tch::{Device, Kind, Tensor};

    /// The tensors of the loader's batches as `batch_tensors` built them before issue 9
    /// item 3: `from_slice` of each stacked buffer.
    fn old_path(b: &Batch) -> (Tensor, Tensor, Tensor) {
        let (n, h, w) = (b.size as i64, b.height as i64, b.width as i64);
        let radar = if b.radar_channels == 0 {
            Tensor::zeros([n, 1, h, w], (Kind::Float, Device::Cpu))
        } else {
            Tensor::from_slice(&b.radar).view([n, b.radar_channels as i64, h, w])
        };
        (
            Tensor::from_slice(&b.image).view([n, 3, h, w]),
            radar,
            Tensor::from_slice(&b.target_m).view([n, 1, h, w]),
        )
    }

    #[test]
    fn upload_batch_delivers_the_old_tensors_and_the_nonzero_sparse_target() {
        let tmp = tempfile::tempdir().unwrap();
        depthsense_data::write_toy_dataset(tmp.path(), 2, 3, 64, 32, 7).unwrap();
        let ds = Dataset::open(tmp.path()).unwrap();
        for (no_radar, target) in [(false, TargetKind::Sparse), (true, TargetKind::Dense)] {
            let load = LoadOptions {
                no_radar,
                target,
                augment: true,
                seed: 3,
                ..LoadOptions::default()
            };
            let plan = EpochPlan {
                entries: ds.split("all"),
                batch_size: 4,
                epoch: 0,
                shuffle: true,
                drop_last: false,
                skip_batches: 0,
                jobs: 1,
                prefetch: 1,
            };
            let mut seen = 0;
            for b in Loader::start(&ds, &load, &plan).unwrap() {
                let b = b.unwrap();
                let new = upload_batch(&b, Device::Cpu);
                let (image, radar, target_m) = old_path(&b);
                // `equal`: same shape, dtype and every bit.
                assert!(new.image.equal(&image));
                assert!(new.radar.equal(&radar));
                assert!(new.target_m.equal(&target_m));
                // The host gather (used on CUDA) equals `nonzero` on the device (used on the CPU).
                let (n, h, w) = (b.size as i64, b.height as i64, b.width as i64);
                let host = SparseTarget::from_host(&b.target_m, (n, h, w), Device::Cpu);
                let nz = SparseTarget::from_dense(&target_m);
                for s in [&new.sparse, &host] {
                    assert_eq!(s.count, nz.count);
                    assert!(s.count > 0);
                    assert!(s.index.equal(&nz.index));
                    assert!(s.depth_m.equal(&nz.depth_m));
                    assert_eq!(s.shape, nz.shape);
                }
                let (i2, r2, t2) = batch_tensors(&b, Device::Cpu);
                assert!(i2.equal(&image) && r2.equal(&radar) && t2.equal(&target_m));
                seen += 1;
            }
            assert_eq!(seen, 2);
        }
    }
}
