//! Validation (SPEC §9): a network over a list of samples into the metrics, through the one
//! scorer [`score_image`] that `eval`, `eval --predictions` and every experiment use too.

use depthsense_data::{Batch, Dataset, EpochPlan, LoadOptions, Loader, TargetKind};
use depthsense_metrics::{EvalConfig, Evaluator, Report};
use depthsense_model::DepthNet;
use depthsense_prep::layout::IndexEntry;
use depthsense_progress::Progress;
use tch::{Device, Kind};

use crate::error::TrainError;
use crate::upload::upload_inputs;
pub use depthsense_score::{condition_names, score_image};

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
    mut on_batch: impl FnMut(&Batch, &[f32]) -> Result<(), TrainError>,
) -> Result<Report, TrainError> {
    let mut ev = Evaluator::new(eval_cfg.clone())?;
    let mut load = load.clone();
    load.eval_maps = true;
    load.target = TargetKind::Sparse;
    let run = RunPlan {
        batch_size,
        jobs,
        device,
    };
    run_net(net, ds, entries, &load, &run, progress, |batch, pred_v| {
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
    })?;
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
/// are all named at the end in one [`TrainError::Unreadable`].
pub fn run_net(
    net: &DepthNet,
    ds: &Dataset,
    entries: &[IndexEntry],
    load: &LoadOptions,
    run: &RunPlan,
    progress: &Progress,
    mut on_batch: impl FnMut(&Batch, &[f32]) -> Result<(), TrainError>,
) -> Result<(), TrainError> {
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
            Err(e @ TrainError::Unreadable { .. }) => {
                unreadable.push(e);
                continue;
            }
            Err(e) => return Err(e),
        };
        let pred_v = predict_batch(net, &batch, run.device)?;
        on_batch(&batch, &pred_v)?;
        progress.inc(batch.size as u64);
    }
    match TrainError::merged(unreadable) {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// The decoded depth of one batch, [B,H,W] metres row-major, on the host.
fn predict_batch(net: &DepthNet, batch: &Batch, device: Device) -> Result<Vec<f32>, TrainError> {
    let (image, radar) = upload_inputs(batch, device);
    let pred = tch::no_grad(|| {
        let out = net.forward_t(&image, &radar, false);
        net.decode(&out)
    });
    let pred = pred
        .to_device(Device::Cpu)
        .to_kind(Kind::Float)
        .contiguous();
    let hw = batch.width * batch.height;
    if pred.numel() != batch.size * hw {
        return Err(TrainError::Other(format!(
            "decoded prediction has shape {:?}, expected [{}, 1, {}, {}]",
            pred.size(),
            batch.size,
            batch.height,
            batch.width
        )));
    }
    Ok(Vec::<f32>::try_from(pred.view([-1]))?)
}
