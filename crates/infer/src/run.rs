//! Validation (SPEC §9): a network over a list of samples into the metrics, through the one
//! scorer [`score_image`] that `eval`, `eval --predictions` and every experiment use too.

use depthsense_data::{Batch, EpochPlan, LoadOptions, Loader, TargetKind};
use depthsense_dataset::DataError;
use depthsense_dataset::Dataset;
use depthsense_metrics::{EvalConfig, Evaluator, Report};
use depthsense_model::ordinal::SparseTarget;
use depthsense_model::DepthNet;
use depthsense_prep::layout::IndexEntry;
use depthsense_progress::Progress;
use tch::{Device, Kind, Tensor};

use crate::error::NetError;
use crate::upload::upload_inputs;
use depthsense_score::score_image;

/// Run `net` over `entries` and feed the decoded depth to the metrics (SPEC §9). `on_batch`
/// sees every batch with its predictions ([B,H,W] metres, row-major).
#[allow(clippy::too_many_arguments)]
pub fn evaluate_net(
    net: &DepthNet,
    ds: &Dataset,
    entries: &[IndexEntry],
    load: &LoadOptions,
    eval_cfg: &EvalConfig,
    batch_size: usize,
    jobs: usize,
    device: Device,
    progress: &Progress,
    on_batch: impl FnMut(&Batch, &[f32]) -> Result<(), NetError>,
) -> Result<Report, NetError> {
    let run = RunPlan {
        batch_size,
        jobs,
        device,
    };
    score_net(
        net,
        ds,
        entries,
        load,
        eval_cfg,
        &run,
        Decode::Every,
        progress,
        on_batch,
    )
}

/// [`evaluate_net`] decoding the depth only at the pixels the scorer reads (valid ground
/// truth, [`DepthNet::decode_at`]): the same report up to float rounding of the bilinear
/// interpolation (tested), without the full-resolution `[B,K,H,W]` ordinal tensor — the
/// validation of training and the test runs of the experiments.
#[allow(clippy::too_many_arguments)]
pub fn validate_net(
    net: &DepthNet,
    ds: &Dataset,
    entries: &[IndexEntry],
    load: &LoadOptions,
    eval_cfg: &EvalConfig,
    batch_size: usize,
    jobs: usize,
    device: Device,
    progress: &Progress,
) -> Result<Report, NetError> {
    let run = RunPlan {
        batch_size,
        jobs,
        device,
    };
    let decode = Decode::AtGroundTruth;
    score_net(
        net,
        ds,
        entries,
        load,
        eval_cfg,
        &run,
        decode,
        progress,
        |_, _| Ok(()),
    )
}

/// Which pixels of a batch are decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Decode {
    /// Every pixel: [`DepthNet::decode`].
    Every,
    /// The valid ground-truth pixels only ([`DepthNet::decode_at`]); the others stay 0.
    AtGroundTruth,
}

#[allow(clippy::too_many_arguments)]
fn score_net(
    net: &DepthNet,
    ds: &Dataset,
    entries: &[IndexEntry],
    load: &LoadOptions,
    eval_cfg: &EvalConfig,
    run: &RunPlan,
    decode: Decode,
    progress: &Progress,
    mut on_batch: impl FnMut(&Batch, &[f32]) -> Result<(), NetError>,
) -> Result<Report, NetError> {
    let mut ev = Evaluator::new(eval_cfg.clone())?;
    let mut load = load.clone();
    load.eval_maps = true;
    load.target = TargetKind::Sparse;
    run_batches(
        net,
        ds,
        entries,
        &load,
        run,
        decode,
        progress,
        |batch, pred_v| {
            let hw = batch.width * batch.height;
            for (i, s) in batch.samples.iter().enumerate() {
                // The one scorer, shared with `eval --predictions`.
                score_image(
                    &mut ev,
                    &s.sparse_m,
                    &s.lowheight,
                    &s.conditions,
                    &pred_v[i * hw..(i + 1) * hw],
                )?;
            }
            on_batch(batch, pred_v)
        },
    )?;
    Ok(ev.finish())
}

/// How [`run_net`] batches and where it runs.
#[derive(Debug, Clone, Copy)]
pub struct RunPlan {
    pub batch_size: usize,
    /// Loader threads (0 = all cores).
    pub jobs: usize,
    pub device: Device,
}

/// Run `net` over `entries` in order (no augmentation; the maps `load` asks for, so no ground
/// truth unless `load.eval_maps`) and hand every batch with its decoded predictions ([B,H,W]
/// metres, row-major) to `on_batch`. Samples that cannot be read do not stop the others: they
/// are all named at the end in one [`DataError::Unreadable`].
pub fn run_net(
    net: &DepthNet,
    ds: &Dataset,
    entries: &[IndexEntry],
    load: &LoadOptions,
    run: &RunPlan,
    progress: &Progress,
    on_batch: impl FnMut(&Batch, &[f32]) -> Result<(), NetError>,
) -> Result<(), NetError> {
    run_batches(
        net,
        ds,
        entries,
        load,
        run,
        Decode::Every,
        progress,
        on_batch,
    )
}

#[allow(clippy::too_many_arguments)]
fn run_batches(
    net: &DepthNet,
    ds: &Dataset,
    entries: &[IndexEntry],
    load: &LoadOptions,
    run: &RunPlan,
    decode: Decode,
    progress: &Progress,
    mut on_batch: impl FnMut(&Batch, &[f32]) -> Result<(), NetError>,
) -> Result<(), NetError> {
    let mut load = load.clone();
    load.augment = false;
    let plan = EpochPlan {
        entries: entries.to_vec(),
        batch_size: run.batch_size.max(1),
        epoch: 0,
        shuffle: false,
        drop_last: false,
        skip_batches: 0,
        jobs: run.jobs,
        prefetch: 2,
    };
    depthsense_model::device::autotune_fixed_size(run.device);
    let mut unreadable = vec![];
    for batch in Loader::start(ds, &load, &plan)? {
        let batch = match batch {
            Ok(b) => b,
            Err(e @ DataError::Unreadable { .. }) => {
                unreadable.push(e);
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        let pred_v = predict_batch(net, &batch, run.device, decode)?;
        on_batch(&batch, &pred_v)?;
        progress.inc(batch.size as u64);
    }
    match DataError::merged(unreadable) {
        Some(e) => Err(e.into()),
        None => Ok(()),
    }
}

/// The decoded depth of one batch, [B,H,W] metres row-major, on the host (0 where `decode`
/// leaves a pixel out).
fn predict_batch(
    net: &DepthNet,
    batch: &Batch,
    device: Device,
    decode: Decode,
) -> Result<Vec<f32>, NetError> {
    let (image, radar) = upload_inputs(batch, device);
    let hw = batch.width * batch.height;
    if decode == Decode::AtGroundTruth {
        return predict_at_ground_truth(net, batch, &image, &radar, device);
    }
    let pred = tch::no_grad(|| {
        let out = net.forward_t(&image, &radar, false);
        net.decode(&out)
    });
    let pred = pred
        .to_device(Device::Cpu)
        .to_kind(Kind::Float)
        .contiguous();
    if pred.numel() != batch.size * hw {
        return Err(NetError::OutputShape {
            what: "decoded prediction",
            got: pred.size(),
            want: [batch.size, 1, batch.height, batch.width]
                .map(|d| d as i64)
                .to_vec(),
        });
    }
    Ok(Vec::<f32>::try_from(pred.view([-1]))?)
}

/// [`predict_batch`] at the samples' valid ground-truth pixels only (the rest 0).
fn predict_at_ground_truth(
    net: &DepthNet,
    batch: &Batch,
    image: &Tensor,
    radar: &Tensor,
    device: Device,
) -> Result<Vec<f32>, NetError> {
    let hw = batch.width * batch.height;
    let mut gt: Vec<f32> = Vec::with_capacity(batch.size * hw);
    for s in &batch.samples {
        if s.sparse_m.len() != hw {
            return Err(NetError::GroundTruthSize {
                sample: s.token.clone(),
                got: s.sparse_m.len(),
                want: hw,
            });
        }
        gt.extend(
            s.sparse_m
                .iter()
                .map(|&d| if d.is_finite() { d } else { 0.0 }),
        );
    }
    let shape = (batch.size as i64, batch.height as i64, batch.width as i64);
    let at = SparseTarget::from_host(&gt, shape, device);
    let depth = tch::no_grad(|| {
        let out = net.forward_t(image, radar, false);
        net.decode_at(&out, &at)
    });
    let depth = Vec::<f32>::try_from(depth.to_device(Device::Cpu).to_kind(Kind::Float))?;
    if depth.len() as i64 != at.count {
        return Err(NetError::DecodedAtGroundTruth {
            got: depth.len(),
            want: at.count,
        });
    }
    let mut pred = vec![0f32; batch.size * hw];
    let valid = gt
        .iter()
        .enumerate()
        .filter(|(_, &d)| d > 0.0)
        .map(|(i, _)| i);
    for (i, d) in valid.zip(depth) {
        pred[i] = d;
    }
    Ok(pred)
}
