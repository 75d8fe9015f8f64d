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
    let run = RunPlan::eager(batch_size, jobs, device);
    evaluate_net_on(net, ds, entries, load, eval_cfg, &run, progress, on_batch)
}

/// [`evaluate_net`] as `run` says (its `cuda_graph`: every batch's forward and decode replayed
/// from a CUDA graph where it can be, [`depthsense_model::graphed`]).
#[allow(clippy::too_many_arguments)]
pub fn evaluate_net_on(
    net: &DepthNet,
    ds: &Dataset,
    entries: &[IndexEntry],
    load: &LoadOptions,
    eval_cfg: &EvalConfig,
    run: &RunPlan,
    progress: &Progress,
    on_batch: impl FnMut(&Batch, &[f32]) -> Result<(), NetError>,
) -> Result<Report, NetError> {
    score_net(
        net,
        ds,
        entries,
        load,
        eval_cfg,
        run,
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
    let run = RunPlan::eager(batch_size, jobs, device);
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

/// Where the time of a [`run_net`] went: the images, the wall time from the loader's start,
/// and every batch's network time (upload, forward, decode, the copy back to the host) — what
/// the network alone would take.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunStats {
    pub images: usize,
    pub wall_s: f64,
    /// Per batch, in order: milliseconds in the network.
    pub batch_ms: Vec<f64>,
}

impl RunStats {
    /// Images per second of the whole run (loading, the network and `on_batch`).
    pub fn images_per_s(&self) -> f64 {
        self.images as f64 / self.wall_s.max(1e-9)
    }

    /// Images per second of the network alone (the sum of the batches' network times).
    pub fn network_images_per_s(&self) -> f64 {
        self.images as f64 / (self.batch_ms.iter().sum::<f64>() / 1e3).max(1e-9)
    }

    /// The `q`-quantile (0..=1, nearest rank) of the batches' network milliseconds.
    pub fn latency_ms(&self, q: f64) -> Option<f64> {
        let mut v = self.batch_ms.clone();
        v.sort_by(f64::total_cmp);
        let i = ((q.clamp(0.0, 1.0) * v.len() as f64).ceil() as usize).max(1) - 1;
        v.get(i).copied()
    }

    /// One line: the rate, the network-alone rate and the share of it reached, the latency.
    pub fn summary(&self, batch_size: usize) -> String {
        let f = |x: Option<f64>| x.map_or("–".into(), |v| format!("{v:.1}"));
        format!(
            "{} images in {:.1} s: {:.2} images/s, the network alone {:.2} images/s ({:.0} %); \
             network time per batch of {batch_size}: median {} ms, p99 {} ms",
            self.images,
            self.wall_s,
            self.images_per_s(),
            self.network_images_per_s(),
            100.0 * self.images_per_s() / self.network_images_per_s().max(1e-9),
            f(self.latency_ms(0.5)),
            f(self.latency_ms(0.99)),
        )
    }
}

/// How [`run_net`] batches and where it runs.
#[derive(Debug, Clone, Copy)]
pub struct RunPlan {
    pub batch_size: usize,
    /// Loader threads (0 = all cores).
    pub jobs: usize,
    pub device: Device,
    /// Replay every batch's forward and decode from a CUDA graph captured for its shape (a
    /// build with the feature `cuda-graphs`, fp32, CUDA); otherwise eager, said once.
    pub cuda_graph: bool,
}

impl RunPlan {
    /// Batches of `batch_size` on `device`, `jobs` loader threads, every forward eager.
    pub fn eager(batch_size: usize, jobs: usize, device: Device) -> RunPlan {
        RunPlan {
            batch_size,
            jobs,
            device,
            cuda_graph: false,
        }
    }
}

/// Run `net` over `entries` in order (no augmentation; the maps `load` asks for, so no ground
/// truth unless `load.eval_maps`) and hand every batch with its decoded predictions ([B,H,W]
/// metres, row-major) to `on_batch`. Samples that cannot be read do not stop the others: they
/// are all named at the end in one [`DataError::Unreadable`]. The samples are read and
/// rasterised on the loader's threads while the network runs (two batches ahead).
pub fn run_net(
    net: &DepthNet,
    ds: &Dataset,
    entries: &[IndexEntry],
    load: &LoadOptions,
    run: &RunPlan,
    progress: &Progress,
    on_batch: impl FnMut(&Batch, &[f32]) -> Result<(), NetError>,
) -> Result<RunStats, NetError> {
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
) -> Result<RunStats, NetError> {
    let started = std::time::Instant::now();
    let mut stats = RunStats::default();
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
    let mut graphed = run
        .cuda_graph
        .then(depthsense_model::graphed::GraphedForward::new);
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
        let t = std::time::Instant::now();
        let pred_v = predict_batch(net, &batch, run.device, decode, graphed.as_mut(), progress)?;
        stats.batch_ms.push(t.elapsed().as_secs_f64() * 1e3);
        stats.images += batch.size;
        on_batch(&batch, &pred_v)?;
        progress.inc(batch.size as u64);
    }
    stats.wall_s = started.elapsed().as_secs_f64();
    match DataError::merged(unreadable) {
        Some(e) => Err(e.into()),
        None => Ok(stats),
    }
}

/// The decoded depth of one batch, [B,H,W] metres row-major, on the host (0 where `decode`
/// leaves a pixel out).
fn predict_batch(
    net: &DepthNet,
    batch: &Batch,
    device: Device,
    decode: Decode,
    graphed: Option<&mut depthsense_model::graphed::GraphedForward>,
    progress: &Progress,
) -> Result<Vec<f32>, NetError> {
    let (image, radar) = upload_inputs(batch, device);
    let hw = batch.width * batch.height;
    if decode == Decode::AtGroundTruth {
        return predict_at_ground_truth(net, batch, &image, &radar, device);
    }
    let forward = |i: &Tensor, r: &Tensor| net.decode(&net.forward_t(i, r, false));
    let pred = tch::no_grad(|| match graphed {
        Some(g) => {
            let (pred, line) = g.run(&image, &radar, forward);
            if let Some(l) = line {
                progress.println(l);
            }
            pred
        }
        None => forward(&image, &radar),
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

#[cfg(test)]
mod tests {
    use super::RunStats;

    #[test]
    fn run_stats_rates_and_nearest_rank_latencies() {
        let s = RunStats {
            images: 8,
            wall_s: 2.0,
            batch_ms: vec![400.0, 100.0, 300.0, 200.0],
        };
        assert_eq!(s.images_per_s(), 4.0);
        assert_eq!(
            s.network_images_per_s(),
            8.0,
            "8 images in 1 s of network time"
        );
        assert_eq!(s.latency_ms(0.5), Some(200.0));
        assert_eq!(s.latency_ms(0.99), Some(400.0));
        assert_eq!(s.latency_ms(0.0), Some(100.0));
        assert!(s.summary(2).contains("(50 %)"), "{}", s.summary(2));
        assert_eq!(RunStats::default().latency_ms(0.5), None);
    }
}
