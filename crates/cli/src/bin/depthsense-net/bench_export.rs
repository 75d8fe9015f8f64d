//! `depthsense bench export` (the network side; its flags: `depthsense_cli::cmd::bench_export`):
//! random weights (seed 0) → a checkpoint → `export --format onnx` → onnxruntime's CPU latency,
//! and depthsense's own forward + decode on the same inputs with the same threads: the training
//! graph in evaluation mode, then the inference graph (BatchNorm folded, fused decode).

use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use depthsense_checkpoint as checkpoint;
use depthsense_cli::cmd::bench_export::Args;
use depthsense_config::flags::{ExportFormat, ExportPrecision};
use depthsense_config::{Fusion, ModelConfig};
use depthsense_data::{IMAGENET_MEAN, IMAGENET_STD};
use depthsense_export::ort_bench::{time_onnxruntime, GraphInput};
use depthsense_export::{export, Batch, ExportOptions};
use depthsense_model::{report, DepthNet};
use serde::Serialize;
use tch::{nn, Device, Kind, Tensor};

use super::bench_model::{summarise, time_it, Timing};

#[derive(Serialize)]
struct Results {
    config: String,
    params: i64,
    height: usize,
    width: usize,
    batch: usize,
    threads: usize,
    warmup: usize,
    repeats: usize,
    /// depthsense (libtorch, this process): forward and decode to full-resolution depth, the
    /// training graph in evaluation mode.
    depthsense: Timing,
    /// The same network as the inference graph (`DepthNet::prepare_inference`: BatchNorm
    /// folded into the convs, the fused ordinal decode), the same inputs, in the same run.
    folded: Timing,
    /// Fraction of pixels where the inference graph's depth equals the training graph's
    /// (the same decoded bin).
    folded_frac_same_depth: f64,
    /// onnxruntime on the exported graph (image normalisation and decode inside it).
    onnxruntime: Timing,
    onnxruntime_version: String,
    onnxruntime_providers: Vec<String>,
    /// Seconds of `export --format onnx` (trace, conversion, full check).
    export_s: f64,
    onnx_bytes: u64,
    /// The two depth maps on the same input: largest |Δ| and the fraction within 1 mm.
    max_abs_diff_m: f64,
    frac_within_1mm: f64,
    /// The same for the inference graph's depth map against onnxruntime's.
    folded_frac_within_1mm: f64,
}

/// Random inputs as the graph takes them: RGB in [0, 1] and sparse radar in metres.
fn inputs(cfg: &ModelConfig, batch: usize) -> (Tensor, Tensor) {
    let (b, h, w) = (batch as i64, cfg.out_height, cfg.out_width);
    let image = Tensor::rand([b, 3, h, w], (Kind::Float, Device::Cpu));
    let c = cfg.radar_channels;
    let mask = Tensor::rand([b, c, h, w], (Kind::Float, Device::Cpu)).lt(0.03);
    let radar = (Tensor::rand([b, c, h, w], (Kind::Float, Device::Cpu)) * 60.0 + 2.0) * mask;
    (image, radar)
}

fn values(t: &Tensor) -> anyhow::Result<Vec<f32>> {
    Ok(Vec::<f32>::try_from(t.contiguous().view([-1]))?)
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let cfg = depthsense_checkpoint::config::resolve(&a.config)?.with_options(&a.set)?;
    if let Some(n) = a.threads {
        tch::set_num_threads(n as i32);
    }
    let threads = tch::get_num_threads().max(1) as usize;
    tch::manual_seed(0);
    let vs = nn::VarStore::new(Device::Cpu);
    let net = DepthNet::new(&vs.root(), &cfg)?;
    // The graph's frame: the config's output size (SPEC §3: 350x800 for every preset).
    let (height, width) = (cfg.out_height, cfg.out_width);
    let params = report::model_report(&vs, &net, height, width).total_params;

    let work = tempfile::tempdir().context("temporary folder")?;
    eprintln!("exporting {} ({params} parameters) to ONNX …", cfg.name);
    let (onnx, export_s, onnx_bytes) = export_random(&vs, &cfg, work.path(), &a)?;

    let (image, radar) = inputs(&cfg, a.batch);
    let _guard = tch::no_grad_guard();
    let (ours, ours_depth) = time_depthsense(&net, &image, &radar, (height, width), &a)?;
    net.prepare_inference(depthsense_model::precision::InferenceLayout::Fastest);
    let (folded, folded_depth) = time_depthsense(&net, &image, &radar, (height, width), &a)?;
    let same = ours_depth
        .iter()
        .zip(&folded_depth)
        .filter(|(a, b)| a == b)
        .count();

    eprintln!("timing onnxruntime …");
    let (image_v, radar_v) = (values(&image)?, values(&radar)?);
    let graph_inputs = graph_inputs(&cfg, a.batch, &image_v, &radar_v);
    let ort = time_onnxruntime(
        a.python.as_deref(),
        &onnx,
        &graph_inputs,
        "CPUExecutionProvider",
        threads,
        a.warmup_runs,
        a.repeats,
    )?;
    let diffs = abs_diffs_m(&ort.depth_m, &ours_depth)?;
    let folded_diffs = abs_diffs_m(&ort.depth_m, &folded_depth)?;
    let res = Results {
        config: cfg.name.clone(),
        params,
        height: height as usize,
        width: width as usize,
        batch: a.batch,
        threads,
        warmup: a.warmup_runs,
        repeats: a.repeats,
        depthsense: ours,
        folded,
        folded_frac_same_depth: same as f64 / ours_depth.len().max(1) as f64,
        onnxruntime: summarise(a.batch as i64, &ort.ms),
        onnxruntime_version: ort.onnxruntime_version,
        onnxruntime_providers: ort.providers,
        export_s,
        onnx_bytes,
        max_abs_diff_m: diffs.iter().copied().fold(0.0, f64::max),
        frac_within_1mm: frac_within_1mm(&diffs),
        folded_frac_within_1mm: frac_within_1mm(&folded_diffs),
    };
    print_results(&res, a.out.as_deref())?;
    Ok(ExitCode::SUCCESS)
}

/// The results as JSON on stdout, and into `out` (atomically) when given.
fn print_results(res: &Results, out: Option<&std::path::Path>) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(res)?;
    println!("{text}");
    if let Some(p) = out {
        depthsense_base::fsutil::write_atomic(p, format!("{text}\n").as_bytes())
            .with_context(|| p.display().to_string())?;
    }
    Ok(())
}

/// depthsense's latency on `image` and `radar` (normalised here, forward and decode to the
/// `(height, width)` frame, without gradients) and its depth map (m) of the same inputs.
fn time_depthsense(
    net: &DepthNet,
    image: &Tensor,
    radar: &Tensor,
    (height, width): (i64, i64),
    a: &Args,
) -> anyhow::Result<(Timing, Vec<f32>)> {
    let mean = Tensor::from_slice(&IMAGENET_MEAN).view([1, 3, 1, 1]);
    let std = Tensor::from_slice(&IMAGENET_STD).view([1, 3, 1, 1]);
    let normalised = (image - &mean) / &std;
    let forward = || net.decode_to(&net.forward_t(&normalised, radar, false), height, width);
    let graph = if net.is_inference_graph() {
        "the inference graph"
    } else {
        "the training graph"
    };
    eprintln!("timing depthsense, {graph} …");
    let ours = time_it(
        Device::Cpu,
        a.warmup_runs,
        a.repeats,
        a.batch as i64,
        || {
            let _ = forward();
        },
    );
    let ours_depth = values(&forward().to_kind(Kind::Float))?;
    Ok((ours, ours_depth))
}

/// The fraction of `diffs` (m) within 1 mm.
fn frac_within_1mm(diffs: &[f64]) -> f64 {
    diffs.iter().filter(|d| **d <= 1e-3).count() as f64 / diffs.len().max(1) as f64
}

/// |Δ| (m) of the two depth maps, value by value; an error when their sizes differ.
fn abs_diffs_m(ort_depth_m: &[f32], ours_depth_m: &[f32]) -> anyhow::Result<Vec<f64>> {
    anyhow::ensure!(
        ort_depth_m.len() == ours_depth_m.len(),
        "onnxruntime returned {} depth values, depthsense {}",
        ort_depth_m.len(),
        ours_depth_m.len()
    );
    Ok(ort_depth_m
        .iter()
        .zip(ours_depth_m)
        .map(|(x, y)| (x - y).abs() as f64)
        .collect())
}

/// The network in `vs` saved as a checkpoint in `work` and exported to ONNX there: the graph's
/// path, the export's seconds and its size in bytes.
fn export_random(
    vs: &nn::VarStore,
    cfg: &depthsense_config::ModelConfig,
    work: &std::path::Path,
    a: &Args,
) -> anyhow::Result<(std::path::PathBuf, f64, u64)> {
    let ckpt = work.join("random.safetensors");
    checkpoint::save(&ckpt, vs, cfg, &serde_json::Value::Null)?;
    let onnx = work.join("model.onnx");
    let t = Instant::now();
    export(&ExportOptions {
        checkpoint: ckpt,
        config: None,
        set: vec![],
        format: ExportFormat::Onnx,
        out: onnx.clone(),
        batch: Batch::Dynamic,
        precision: ExportPrecision::Fp32,
        force: true,
        python: a.python.clone(),
    })?;
    let export_s = t.elapsed().as_secs_f64();
    let bytes = std::fs::metadata(&onnx)?.len();
    Ok((onnx, export_s, bytes))
}

/// The exported graph's inputs: the image, and the radar unless the model is RGB-only.
fn graph_inputs<'v>(
    cfg: &depthsense_config::ModelConfig,
    batch: usize,
    image: &'v [f32],
    radar: &'v [f32],
) -> Vec<GraphInput<'v>> {
    let (h, w) = (cfg.out_height as usize, cfg.out_width as usize);
    let mut inputs = vec![GraphInput {
        name: "image",
        values: image,
        shape: vec![batch, 3, h, w],
    }];
    if cfg.fusion != Fusion::None {
        inputs.push(GraphInput {
            name: "radar",
            values: radar,
            shape: vec![batch, cfg.radar_channels as usize, h, w],
        });
    }
    inputs
}
