//! `depthsense bench model`: forward and training-step time (and GPU memory) of a network. (the network side; its flags: `depthsense_cli::cmd::bench_model`).

use anyhow::Context;
use depthsense_cli::cmd::bench_model::Args;
use depthsense_config::flags::Precision;
use depthsense_config::{HeadKind, ModelConfig};
use depthsense_model::precision::{channels_last, vs_to_channels_last, with_autocast};
use depthsense_model::{device, report, DepthNet};
use serde::Serialize;
use std::process::ExitCode;
use std::time::Instant;
use tch::{nn, Device, Kind, Tensor};

#[derive(Serialize, Default)]
pub struct Timing {
    batch: i64,
    median_ms: f64,
    min_ms: f64,
    mean_ms: f64,
    images_per_s: f64,
    /// GPU memory of this process after the phase (nvidia-smi; the caching allocator keeps its
    /// peak reservation, so this is the peak reserved + CUDA context).
    gpu_memory_mib: Option<u64>,
}

#[derive(Serialize)]
struct Results {
    config: String,
    device: String,
    gpu: Option<String>,
    precision: String,
    channels_last: bool,
    cudnn_benchmark: bool,
    height: i64,
    width: i64,
    params: i64,
    macs_per_image: u64,
    threads: i32,
    warmup: usize,
    repeats: usize,
    /// Forward to the low-resolution head output.
    forward: Option<Timing>,
    /// Forward plus decoding to full-resolution depth.
    forward_decode: Option<Timing>,
    /// `--cuda-graph`: forward + decode through a CUDA graph captured for this batch shape
    /// (`model::graphed`), or eager when it cannot be (see `cuda_graph`).
    forward_decode_graph: Option<Timing>,
    /// `--cuda-graph`: "replayed", or why the graph row ran eagerly.
    cuda_graph: Option<String>,
    /// Whether this build has CUDA graphs (feature `cuda-graphs`).
    cuda_graphs_built: bool,
    train_step: Option<Timing>,
    /// Mixed precision vs fp32 on the same input: fraction of pixels whose decoded level moves
    /// by more than one bin, and by any amount.
    /// "trained" (`--config` was a checkpoint: its weights) or "random" (seed 0).
    weights: &'static str,
    /// "inference" (`--inference-graph`: BatchNorm folded, the fused decode) or "training"
    /// (the training graph in evaluation mode) for the forward phases.
    graph: &'static str,
    precision_check: Option<serde_json::Value>,
}

fn sync(d: Device) {
    if let Device::Cuda(i) = d {
        tch::Cuda::synchronize(i as i64);
    }
}

pub fn time_it(
    d: Device,
    warmup: usize,
    repeats: usize,
    batch: i64,
    mut f: impl FnMut(),
) -> Timing {
    for _ in 0..warmup {
        f();
    }
    sync(d);
    let mut ms = Vec::with_capacity(repeats);
    for _ in 0..repeats.max(1) {
        let t = Instant::now();
        f();
        sync(d);
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    summarise(batch, &ms)
}

/// Median, minimum and mean of some timed runs of `batch` images (milliseconds each).
pub fn summarise(batch: i64, ms: &[f64]) -> Timing {
    let mean = ms.iter().sum::<f64>() / ms.len() as f64;
    let mut s = ms.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    let median = if s.len() % 2 == 1 {
        s[s.len() / 2]
    } else {
        (s[s.len() / 2 - 1] + s[s.len() / 2]) / 2.0
    };
    Timing {
        batch,
        median_ms: median,
        min_ms: s[0],
        mean_ms: mean,
        images_per_s: batch as f64 / (median / 1e3),
        gpu_memory_mib: None,
    }
}

fn nvidia_smi(args: &[&str]) -> Option<String> {
    let out = std::process::Command::new("nvidia-smi")
        .args(args)
        .output()
        .ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
}

/// Device-wide used memory (MiB) of the GPU `d` (nvidia-smi `memory.used`).
fn gpu_used_total_mib(d: Device) -> Option<u64> {
    let Device::Cuda(i) = d else { return None };
    let s = nvidia_smi(&[
        "--query-gpu=memory.used",
        "--format=csv,noheader,nounits",
        &format!("--id={i}"),
    ])?;
    s.lines().next()?.trim().parse().ok()
}

/// GPU memory of this process in MiB: its `used_memory` in nvidia-smi's compute-apps list, or,
/// where PIDs are not visible (containers), the device-wide used memory minus `baseline`
/// (taken before this process touched CUDA).
fn gpu_memory_mib(d: Device, baseline: Option<u64>) -> Option<u64> {
    if !d.is_cuda() {
        return None;
    }
    let me = std::process::id().to_string();
    let per_pid = nvidia_smi(&[
        "--query-compute-apps=pid,used_memory",
        "--format=csv,noheader,nounits",
    ])
    .and_then(|s| {
        s.lines().find_map(|l| {
            let mut it = l.split(',').map(str::trim);
            (it.next()? == me)
                .then(|| it.next()?.parse().ok())
                .flatten()
        })
    });
    per_pid.or_else(|| Some(gpu_used_total_mib(d)?.saturating_sub(baseline.unwrap_or(0))))
}

fn inputs(
    cfg: &ModelConfig,
    b: i64,
    h: i64,
    w: i64,
    d: Device,
    cl: bool,
) -> (Tensor, Tensor, Tensor) {
    let img = Tensor::randn([b, 3, h, w], (Kind::Float, d));
    let mask = Tensor::rand([b, cfg.radar_channels, h, w], (Kind::Float, d)).lt(0.03);
    let radar = (Tensor::rand([b, cfg.radar_channels, h, w], (Kind::Float, d)) * 60.0 + 2.0) * mask;
    // sparse lidar-like target: ~8 % valid pixels
    let valid = Tensor::rand([b, 1, h, w], (Kind::Float, d)).lt(0.08);
    let target = (Tensor::rand([b, 1, h, w], (Kind::Float, d)) * 78.0 + 1.5) * valid;
    if cl {
        (channels_last(&img), channels_last(&radar), target)
    } else {
        (img, radar, target)
    }
}

/// The network under test and what every phase shares.
struct Bench {
    cfg: ModelConfig,
    dev: Device,
    vs: nn::VarStore,
    net: DepthNet,
    /// Device-wide used GPU memory (MiB) before this process touched CUDA.
    mem_baseline: Option<u64>,
    /// Channels-last layout in use (asked for, and on CUDA).
    channels_last: bool,
    /// The arithmetic in use (fp32 off CUDA).
    prec: Precision,
    /// The weights are a checkpoint's (`--config RUN/best.safetensors`), not random.
    trained: bool,
    /// Also time forward + decode through a CUDA graph (`--cuda-graph`).
    cuda_graph: bool,
    params: i64,
    macs_per_image: u64,
    height: i64,
    width: i64,
    warmup: usize,
    repeats: usize,
}

impl Bench {
    /// Resolve the network and device, set libtorch up, build the network (seed 0) in the
    /// layout and precision this device supports (a note on stderr for each one refused).
    fn new(args: &Args) -> anyhow::Result<Bench> {
        let cfg = depthsense_checkpoint::config::resolve(&args.config)?.with_options(&args.set)?;
        let dev = device::parse_device(&args.device.name)?;
        if let Some(n) = args.threads {
            tch::set_num_threads(n);
        }
        if dev.is_cuda() {
            tch::Cuda::cudnn_set_benchmark(args.cudnn_benchmark);
        }
        tch::manual_seed(0);
        let mem_baseline = gpu_used_total_mib(dev);
        let vs = nn::VarStore::new(dev);
        let net = DepthNet::new(&vs.root(), &cfg)?;
        let trained = load_trained_weights(&args.config, &vs)?;
        if args.inference_graph {
            net.prepare_inference(depthsense_model::precision::InferenceLayout::Fastest);
        }
        let channels_last = use_channels_last(args.channels_last, dev, args.batch_train > 0, &vs);
        let rep = report::model_report(&vs, &net, args.height, args.width);
        let asked = args.precision;
        let prec = precision_on(asked, dev);
        Ok(Bench {
            cfg,
            dev,
            vs,
            net,
            mem_baseline,
            channels_last,
            prec,
            trained,
            cuda_graph: args.cuda_graph,
            params: rep.total_params,
            macs_per_image: rep.total_macs,
            height: args.height,
            width: args.width,
            warmup: args.warmup_runs,
            repeats: args.repeats,
        })
    }

    /// The results before any phase ran.
    fn results(&self, args: &Args) -> Results {
        let dev = self.dev;
        Results {
            config: self.cfg.name.clone(),
            device: device::describe(dev),
            gpu: if dev.is_cuda() {
                nvidia_smi(&["--query-gpu=name", "--format=csv,noheader"])
            } else {
                None
            },
            precision: format!("{:?}", self.prec).to_lowercase(),
            channels_last: self.channels_last,
            cudnn_benchmark: args.cudnn_benchmark && dev.is_cuda(),
            height: self.height,
            width: self.width,
            params: self.params,
            macs_per_image: self.macs_per_image,
            threads: tch::get_num_threads(),
            warmup: self.warmup,
            repeats: self.repeats,
            forward: None,
            forward_decode: None,
            train_step: None,
            forward_decode_graph: None,
            cuda_graph: None,
            cuda_graphs_built: depthsense_model::graphed::built(),
            weights: if self.trained { "trained" } else { "random" },
            graph: if self.net.is_inference_graph() {
                "inference"
            } else {
                "training"
            },
            precision_check: None,
        }
    }

    /// Random inputs of `batch` images in this bench's size and layout.
    fn inputs(&self, batch: i64) -> (Tensor, Tensor, Tensor) {
        inputs(
            &self.cfg,
            batch,
            self.height,
            self.width,
            self.dev,
            self.channels_last,
        )
    }

    /// [`time_it`] with this bench's warm-up and repeats, then the GPU memory.
    fn time(&self, batch: i64, f: impl FnMut()) -> Timing {
        let mut t = time_it(self.dev, self.warmup, self.repeats, batch, f);
        t.gpu_memory_mib = gpu_memory_mib(self.dev, self.mem_baseline);
        t
    }

    /// The forward phases (head output, and decoded to full resolution) and, under mixed
    /// precision with the ordinal head, the check against fp32.
    fn forward(&self, batch: i64, res: &mut Results) {
        let (net, prec, (h, w)) = (&self.net, self.prec, (self.height, self.width));
        let (img, radar, _) = self.inputs(batch);
        let _guard = tch::no_grad_guard();
        res.forward = Some(self.time(batch, || {
            let _ = with_autocast(prec, || net.forward_t(&img, &radar, false));
        }));
        res.forward_decode = Some(self.time(batch, || {
            let _ = with_autocast(prec, || {
                net.decode_to(&net.forward_t(&img, &radar, false), h, w)
            });
        }));
        if self.cuda_graph {
            self.graph_row(&img, &radar, res);
        }
        if prec != Precision::Fp32 && self.cfg.head == HeadKind::Ordinal {
            res.precision_check = Some(self.precision_check(&img, &radar));
        }
    }

    /// The forward + decode row through a CUDA graph (fp32: autocast's cast cache and graph
    /// capture do not mix), and how it ran.
    fn graph_row(&self, img: &Tensor, radar: &Tensor, res: &mut Results) {
        let (net, (h, w)) = (&self.net, (self.height, self.width));
        let batch = img.size()[0];
        let mut graphed = depthsense_model::graphed::GraphedForward::new();
        let f = |i: &Tensor, r: &Tensor| net.decode_to(&net.forward_t(i, r, false), h, w);
        let fp32 = self.prec == Precision::Fp32;
        if !fp32 {
            eprintln!("cuda graph: fp32 only: eager");
        }
        res.forward_decode_graph = Some(self.time(batch, || {
            if !fp32 {
                let _ = f(img, radar);
            } else if let (_, Some(line)) = graphed.run(img, radar, f) {
                eprintln!("{line}");
            }
        }));
        use depthsense_model::graphed::Ran;
        res.cuda_graph = Some(match graphed.last() {
            _ if !fp32 => "fp32 only: eager".into(),
            Some(Ran::Eager(reason)) => format!("{reason}: eager"),
            Some(Ran::Captured | Ran::Replayed) => "replayed".into(),
            None => "not run".into(),
        });
    }

    /// Mixed precision vs fp32 on the same input: the fraction of pixels whose decoded level
    /// moves by more than one bin, and by any amount.
    fn precision_check(&self, img: &Tensor, radar: &Tensor) -> serde_json::Value {
        let (net, cfg, (h, w)) = (&self.net, &self.cfg, (self.height, self.width));
        let z32 = net.forward_t(img, radar, false);
        let zmp =
            with_autocast(self.prec, || net.forward_t(img, radar, false)).to_kind(Kind::Float);
        let l32 = depthsense_model::ordinal::ordinal_levels(&z32, h, w, cfg.align_corners);
        let lmp = depthsense_model::ordinal::ordinal_levels(&zmp, h, w, cfg.align_corners);
        let diff = (l32 - lmp).abs();
        let n = diff.numel() as f64;
        let more_than_one = diff.gt(1).sum(Kind::Int64).int64_value(&[]) as f64 / n;
        let any = diff.gt(0).sum(Kind::Int64).int64_value(&[]) as f64 / n;
        serde_json::json!({
            "frac_pixels_level_moved_gt_1": more_than_one,
            "frac_pixels_level_moved": any,
            "target_frac_gt_1": 0.001,
            "ok": more_than_one <= 0.001,
            "weights": if self.trained { "trained" } else { "random" },
            "note": if self.trained {
                "the checkpoint's trained weights, random inputs"
            } else {
                "random weights and inputs; re-check on a trained checkpoint"
            }
        })
    }

    /// The training-step phase: the step `train` runs ([`depthsense_train::step`]): forward
    /// and the ordinal loss on the sparse target under the run's precision, backward, and
    /// depthsense's SGD (SPEC §8: momentum 0.9, weight decay 1e-4) at lr 1e-3.
    fn train_step(&self, batch: i64) -> anyhow::Result<Timing> {
        let (img, radar, target) = self.inputs(batch);
        let bt = depthsense_infer::upload::BatchTensors {
            sparse: depthsense_model::ordinal::SparseTarget::from_dense(&target),
            image: img,
            radar,
            target_m: target,
        };
        let mut opt = depthsense_train::sgd::Sgd::new(&self.vs, 0.9, 1e-4);
        Ok(self.time(batch, || {
            let loss = depthsense_train::step::forward_loss(&self.net, &bt, self.prec);
            depthsense_train::step::backward_update(&mut opt, &loss, 1e-3);
        }))
    }
}

/// A depthsense checkpoint given as `--config` (`*.safetensors`): its trained weights copied
/// into `vs` (true). A preset or a config JSON: the random weights stay (false).
fn load_trained_weights(config: &str, vs: &nn::VarStore) -> anyhow::Result<bool> {
    let path = std::path::Path::new(config);
    if !(path.is_file() && path.extension().is_some_and(|e| e == "safetensors")) {
        return Ok(false);
    }
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let (tensors, _) = depthsense_checkpoint::host::parse_safetensors(path, &bytes)?;
    depthsense_checkpoint::copy_into(path, vs, &tensors)?;
    Ok(true)
}

/// Whether the channels-last layout is used (asked for, on CUDA, or on the CPU without a
/// training step); converts `vs` when it is.
fn use_channels_last(asked: bool, dev: Device, train_step: bool, vs: &nn::VarStore) -> bool {
    // libtorch 2.11's CPU backward crashed (heap corruption) with channels-last weights at
    // 175x400 in our tests, so a CPU run with a training step stays NCHW; a forward-only CPU
    // run takes the layout (the path the GPU takes, exercised by gpu-check's dry run).
    let channels_last_on = asked && (dev.is_cuda() || !train_step);
    if asked && !channels_last_on {
        eprintln!(
            "note: --channels-last with a training step is only used on CUDA; running NCHW on {}",
            device::describe(dev)
        );
    }
    if channels_last_on {
        vs_to_channels_last(vs);
    }
    channels_last_on
}

/// The arithmetic used on `dev`: `asked` on CUDA, fp32 elsewhere (with a note).
fn precision_on(asked: Precision, dev: Device) -> Precision {
    let prec = if dev.is_cuda() {
        asked
    } else {
        Precision::Fp32
    };
    if prec != asked {
        eprintln!(
            "note: --precision {:?} needs CUDA; running fp32 on {}",
            asked,
            device::describe(dev)
        );
    }
    prec
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let mut bench = Bench::new(&args)?;
    let mut res = bench.results(&args);
    if args.batch_forward > 0 {
        bench.forward(args.batch_forward, &mut res);
    }
    if args.batch_train > 0 {
        res.train_step = Some(bench.train_step(args.batch_train)?);
    }
    bench.vs.freeze();
    print_results(&res);
    if let Some(path) = &args.out {
        let text = serde_json::to_string_pretty(&res)?;
        depthsense_checkpoint::files::write_atomic(path, text.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(ExitCode::SUCCESS)
}

/// The results on stdout: the set-up line, a table of the phases, the precision check.
fn print_results(res: &Results) {
    println!(
        "{} on {}{} ({}, channels-last {}, cudnn.benchmark {}), {}x{}, {:.2} M params, {:.1} G MACs/image, {} threads",
        res.config,
        res.device,
        res.gpu.as_ref().map(|g| format!(" [{g}]")).unwrap_or_default(),
        res.precision,
        res.channels_last,
        res.cudnn_benchmark,
        res.height,
        res.width,
        res.params as f64 / 1e6,
        res.macs_per_image as f64 / 1e9,
        res.threads
    );
    println!(
        "{:<26} {:>6} {:>11} {:>11} {:>10} {:>10}",
        "phase", "batch", "median ms", "min ms", "img/s", "GPU MiB"
    );
    for (name, t) in [
        ("forward (head output)", &res.forward),
        ("forward + decode", &res.forward_decode),
        ("train step", &res.train_step),
    ] {
        if let Some(t) = t {
            let mem = t
                .gpu_memory_mib
                .map(|m| m.to_string())
                .unwrap_or_else(|| "-".into());
            println!(
                "{:<26} {:>6} {:>11.2} {:>11.2} {:>10.2} {:>10}",
                name, t.batch, t.median_ms, t.min_ms, t.images_per_s, mem
            );
        }
    }
    if let Some(t) = &res.forward_decode_graph {
        println!(
            "{:<26} {:>6} {:>11.2} {:>11.2} {:>10.2}   ({})",
            "forward + decode, graph",
            t.batch,
            t.median_ms,
            t.min_ms,
            t.images_per_s,
            res.cuda_graph.as_deref().unwrap_or("-")
        );
    }
    if let Some(p) = &res.precision_check {
        println!("precision check vs fp32: {p}");
    }
}
