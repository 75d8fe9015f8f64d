//! Gradient all-reduce time per training step for a model preset's gradients:
//! `cargo run --release -p depthsense-train --example allreduce_bench -- tiny 2 10 [bucket_mb]`
//! (preset, processes, timed steps). Starts the processes itself (Gloo over loopback on CPU;
//! NCCL when CUDA and the `nccl` feature are there and `cuda` is the 5th argument) and prints
//! one JSON line from rank 0: gradient bytes, buckets, median / min seconds per step.

use std::error::Error;
use std::time::Duration;

use depthsense_config::ModelConfig;
use depthsense_dist::launch::launch_local;
use depthsense_dist::{Backend, DistEnv, GradBuckets, ProcessGroup};
use depthsense_model::DepthNet;
use tch::{nn::VarStore, Device, Kind, Tensor};

/// The command line: `[preset] [processes] [timed steps] [bucket_mb] [cuda]`.
struct BenchArgs {
    preset: String,
    nproc: usize,
    steps: usize,
    bucket_mb: f64,
    cuda: bool,
}

impl BenchArgs {
    /// Parses the process's arguments, with the defaults `tiny 2 10 25` on the CPU.
    fn parse() -> Result<Self, Box<dyn Error>> {
        let args: Vec<String> = std::env::args().skip(1).collect();
        let preset = args.first().cloned().unwrap_or_else(|| "tiny".into());
        let nproc: usize = args.get(1).map_or(Ok(2), |s| s.parse())?;
        let steps: usize = args.get(2).map_or(Ok(10), |s| s.parse())?;
        let bucket_mb: f64 = args.get(3).map_or(Ok(25.0), |s| s.parse())?;
        let cuda = args.get(4).is_some_and(|s| s == "cuda");
        Ok(Self {
            preset,
            nproc,
            steps,
            bucket_mb,
            cuda,
        })
    }
}

/// The trainable parameters of a network of `cfg` on `device` (seed 0), sorted by name, with
/// random gradients from an ordinary backward.
fn params_with_random_grads(
    cfg: &ModelConfig,
    device: Device,
) -> Result<Vec<Tensor>, Box<dyn Error>> {
    tch::manual_seed(0);
    let vs = VarStore::new(device);
    let _net = DepthNet::new(&vs.root(), cfg)?;
    let mut named: Vec<(String, Tensor)> = vs
        .variables()
        .into_iter()
        .filter(|(_, t)| t.requires_grad())
        .collect();
    named.sort_by(|a, b| a.0.cmp(&b.0));
    let params: Vec<Tensor> = named.into_iter().map(|(_, t)| t).collect();
    // Random gradients through an ordinary backward.
    let loss = params
        .iter()
        .map(|p| (p * p.randn_like()).sum(Kind::Float))
        .fold(Tensor::zeros([], (Kind::Float, device)), |a, b| a + b);
    loss.backward();
    Ok(params)
}

/// Seconds of each of `steps` all-reduces of `buckets` after one warm-up, sorted ascending;
/// each step starts at a barrier and, on CUDA device `cuda_index`, ends with a synchronize.
fn timed_all_reduce_s(
    buckets: &GradBuckets,
    pg: &ProcessGroup,
    steps: usize,
    cuda_index: Option<usize>,
) -> Result<Vec<f64>, Box<dyn Error>> {
    buckets.all_reduce(pg)?; // warm-up
    let mut secs = vec![];
    for _ in 0..steps {
        pg.barrier()?;
        let s = buckets.all_reduce(pg)?;
        if let Some(index) = cuda_index {
            tch::Cuda::synchronize(index as i64);
        }
        secs.push(s.seconds);
    }
    secs.sort_by(f64::total_cmp);
    Ok(secs)
}

fn main() -> Result<(), Box<dyn Error>> {
    let BenchArgs {
        preset,
        nproc,
        steps,
        bucket_mb,
        cuda,
    } = BenchArgs::parse()?;
    let Some(env) = DistEnv::from_env()? else {
        let fwd: Vec<std::ffi::OsString> = std::env::args_os().skip(1).collect();
        launch_local(nproc, &fwd, None, Duration::from_secs(60))?;
        return Ok(());
    };
    let device = if cuda {
        Device::Cuda(env.local_rank)
    } else {
        Device::Cpu
    };
    let backend = Backend::for_device(device);
    let index = cuda.then_some(env.local_rank);
    let pg = ProcessGroup::new(&env, backend, index, Duration::from_secs(300))?;
    let cfg = ModelConfig::preset(&preset)?;
    let params = params_with_random_grads(&cfg, device)?;
    let buckets = GradBuckets::new(params, (bucket_mb * 1024.0 * 1024.0) as usize);
    let secs = timed_all_reduce_s(&buckets, &pg, steps, index)?;
    let bytes: usize = buckets.bucket_bytes().iter().sum();
    if pg.is_main() {
        let median = secs[secs.len() / 2];
        println!(
            "{}",
            serde_json::json!({
                "preset": preset, "ranks": pg.world_size(), "backend": pg.backend_name(),
                "device": format!("{device:?}"), "grad_bytes": bytes,
                "grad_mb": bytes as f64 / 1048576.0,
                "buckets": buckets.bucket_bytes().len(), "bucket_mb": bucket_mb,
                "steps": steps, "median_s": median, "min_s": secs[0],
                "algbw_gb_s": bytes as f64 / median / 1e9,
                "threads": tch::get_num_threads(),
            })
        );
    }
    pg.barrier()?;
    Ok(())
}
