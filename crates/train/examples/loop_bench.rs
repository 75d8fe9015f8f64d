//! CPU micro-benchmark of the training loop's pieces changed by issue 9 item 3:
//! `cargo run -p depthsense-train --example loop_bench -- [REPEATS]`.
//!
//! 1. batch upload: the old three `from_slice` vs `upload_batch` (which also gathers the
//!    target's valid pixels on the host);
//! 2. ordinal loss forward + backward: `nonzero` on the device vs host indices;
//! 3. the SGD step of the `paper` network (per parameter, as `Sgd::step`) against the same six
//!    element-wise operations over one flat buffer of all parameters (the floor that a
//!    flattened / foreach step could reach; tch 0.24 has no `_foreach_*` ops).

use std::error::Error;
use std::path::Path;
use std::time::Instant;

use depthsense_config::{ModelConfig, SidConfig};
use depthsense_data::{Batch, EpochPlan, LoadOptions, Loader};
use depthsense_dataset::Dataset;
use depthsense_infer::upload::{upload_batch, BatchTensors};
use depthsense_model::ordinal::{ordinal_loss, ordinal_loss_at, SparseTarget};
use depthsense_model::DepthNet;
use depthsense_train::optim::Optimizer;
use depthsense_train::sgd::Sgd;
use tch::{nn::VarStore, Device, Kind, Tensor};

/// Median seconds of `reps` runs of `f`.
fn median_s(reps: usize, mut f: impl FnMut()) -> f64 {
    f();
    let mut t: Vec<f64> = (0..reps)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[reps / 2]
}

/// Writes a toy dataset (2 scenes × 4 samples at 800×350) into `dir` and loads its first
/// shuffled batch of 8.
fn load_toy_batch(dir: &Path) -> Result<Batch, Box<dyn Error>> {
    depthsense_data::write_toy_dataset(dir, 2, 4, 800, 350, 1)?;
    let ds = Dataset::open(dir)?;
    let plan = EpochPlan {
        entries: ds.split("all"),
        batch_size: 8,
        epoch: 0,
        shuffle: true,
        drop_last: true,
        skip_batches: 0,
        jobs: 2,
        prefetch: 1,
    };
    let load = LoadOptions::default();
    let b = Loader::start(&ds, &load, &plan)?
        .next()
        .ok_or("no batch")??;
    Ok(b)
}

/// Times and prints the old three-`from_slice` upload of `b` against `upload_batch` and the
/// host gather of the valid target pixels; returns the uploaded batch with its sparse target
/// gathered on the host.
fn bench_upload(reps: usize, b: &Batch) -> BatchTensors {
    let (n, h, w) = (b.size as i64, b.height as i64, b.width as i64);
    let old_s = median_s(reps, || {
        let _ = Tensor::from_slice(&b.image).view([n, 3, h, w]);
        let _ = Tensor::from_slice(&b.radar).view([n, b.radar_channels as i64, h, w]);
        let _ = Tensor::from_slice(&b.target_m).view([n, 1, h, w]);
    });
    let new_s = median_s(reps, || {
        let _ = upload_batch(b, Device::Cpu);
    });
    let gather_s = median_s(reps, || {
        let _ = SparseTarget::from_host(&b.target_m, (n, h, w), Device::Cpu);
    });
    let mut bt = upload_batch(b, Device::Cpu);
    println!(
        "upload, batch 8 at 800x350 ({} valid target pixels): old {:.2} ms, new {:.2} ms; \
         host gather of the valid pixels (the CUDA path) {:.2} ms",
        bt.sparse.count,
        old_s * 1e3,
        new_s * 1e3,
        gather_s * 1e3
    );
    bt.sparse = SparseTarget::from_host(&b.target_m, (n, h, w), Device::Cpu);
    bt
}

/// Times and prints the ordinal loss forward + backward over a random `[n,80,44,100]` logit
/// tensor: `nonzero` on the device against the host-gathered indices of `bt`.
fn bench_ordinal_loss(reps: usize, n: i64, bt: &BatchTensors) {
    let sid = SidConfig::default();
    let z0 = Tensor::randn([n, 80, 44, 100], (Kind::Float, Device::Cpu));
    let loss_time_s = |sparse: bool| {
        median_s(reps, || {
            let z = z0.detach().set_requires_grad(true);
            let l = if sparse {
                ordinal_loss_at(&z, &bt.sparse, &sid, false)
            } else {
                ordinal_loss(&z, &bt.target_m, &sid, false)
            };
            l.backward();
        })
    };
    println!(
        "ordinal loss fwd+bwd, z [8,80,44,100]: nonzero {:.2} ms, host indices {:.2} ms",
        loss_time_s(false) * 1e3,
        loss_time_s(true) * 1e3
    );
}

/// Median seconds of the six element-wise operations of an SGD step with momentum 0.9 and
/// weight decay 1e-4 over one flat buffer of `numel` random parameters.
fn flat_sgd_step_s(reps: usize, numel: i64) -> f64 {
    let mut p = Tensor::randn([numel], (Kind::Float, Device::Cpu));
    let g = Tensor::randn([numel], (Kind::Float, Device::Cpu));
    let mut buf = Tensor::randn([numel], (Kind::Float, Device::Cpu));
    median_s(reps, || {
        tch::no_grad(|| {
            let g = &g + &p * 1e-4;
            let _ = buf.g_mul_scalar_(0.9);
            let _ = buf.g_add_(&g);
            let _ = p.g_sub_(&(&buf * 1e-3));
        })
    })
}

/// Times and prints the per-parameter `Sgd::step` of the `paper` network (output `h`×`w`)
/// against the same step over one flat buffer of all its parameters.
fn bench_sgd_step(reps: usize, h: i64, w: i64) -> Result<(), Box<dyn Error>> {
    let mut cfg = ModelConfig::paper();
    cfg.out_height = h;
    cfg.out_width = w;
    let vs = VarStore::new(Device::Cpu);
    let _net = DepthNet::new(&vs.root(), &cfg)?;
    let vars: Vec<Tensor> = vs.trainable_variables();
    for v in &vars {
        let mut g = v.grad();
        if !g.defined() {
            // A gradient of the parameter's shape: `sum(p·c)` with c random.
            (v * Tensor::randn_like(v)).sum(Kind::Float).backward();
            g = v.grad();
        }
        let _ = g;
    }
    let mut sgd = Sgd::new(&vs, 0.9, 1e-4);
    sgd.step(1e-3); // allocates the momentum buffers
    let per_param_s = median_s(reps, || sgd.step(1e-3));
    let numel: i64 = vars.iter().map(|v| v.numel() as i64).sum();
    let flat_s = flat_sgd_step_s(reps, numel);
    println!(
        "SGD step, paper preset ({} tensors, {:.1} M parameters): per parameter {:.1} ms, \
         one flat buffer {:.1} ms",
        vars.len(),
        numel as f64 / 1e6,
        per_param_s * 1e3,
        flat_s * 1e3
    );
    Ok(())
}

fn main() -> Result<(), Box<dyn Error>> {
    let reps: usize = std::env::args().nth(1).map_or(Ok(5), |s| s.parse())?;
    let tmp = tempfile::tempdir()?;
    let b = load_toy_batch(tmp.path())?;
    let (n, h, w) = (b.size as i64, b.height as i64, b.width as i64);
    let bt = bench_upload(reps, &b);
    bench_ordinal_loss(reps, n, &bt);
    bench_sgd_step(reps, h, w)
}
