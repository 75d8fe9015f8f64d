//! Gradient all-reduce time per training step for a model preset's gradients:
//! `cargo run --release -p depthsense-train --example allreduce_bench -- tiny 2 10 [bucket_mb]`
//! (preset, processes, timed steps). Starts the processes itself (Gloo over loopback on CPU;
//! NCCL when CUDA and the `nccl` feature are there and `cuda` is the 5th argument) and prints
//! one JSON line from rank 0: gradient bytes, buckets, median / min seconds per step.

use std::time::Duration;

use depthsense_config::ModelConfig;
use depthsense_dist::launch::launch_local;
use depthsense_dist::{Backend, DistEnv, ProcessGroup};
use depthsense_model::DepthNet;
use tch::{nn::VarStore, Device, Kind, Tensor};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let preset = args.first().cloned().unwrap_or_else(|| "tiny".into());
    let nproc: usize = args.get(1).map_or(Ok(2), |s| s.parse())?;
    let steps: usize = args.get(2).map_or(Ok(10), |s| s.parse())?;
    let bucket_mb: f64 = args.get(3).map_or(Ok(25.0), |s| s.parse())?;
    let cuda = args.get(4).is_some_and(|s| s == "cuda");
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
    tch::manual_seed(0);
    let vs = VarStore::new(device);
    let _net = DepthNet::new(&vs.root(), &cfg)?;
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
    let buckets = depthsense_dist::GradBuckets::new(params, (bucket_mb * 1024.0 * 1024.0) as usize);
    buckets.all_reduce(&pg)?; // warm-up
    let mut secs = vec![];
    for _ in 0..steps {
        pg.barrier()?;
        let s = buckets.all_reduce(&pg)?;
        if cuda {
            tch::Cuda::synchronize(env.local_rank as i64);
        }
        secs.push(s.seconds);
    }
    secs.sort_by(f64::total_cmp);
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
