//! CPU micro-benchmark of the training loop's pieces changed by issue 9 item 3:
//! `cargo run -p depthsense-train --example loop_bench -- [REPEATS]`.
//!
//! 1. batch upload: the old three `from_slice` vs `upload_batch` (which also gathers the
//!    target's valid pixels on the host);
//! 2. ordinal loss forward + backward: `nonzero` on the device vs host indices;
//! 3. the SGD step of the `paper` network (per parameter, as `Sgd::step`) against the same six
//!    element-wise operations over one flat buffer of all parameters (the floor that a
//!    flattened / foreach step could reach; tch 0.24 has no `_foreach_*` ops).

use std::time::Instant;

use depthsense_config::{ModelConfig, SidConfig};
use depthsense_data::{EpochPlan, LoadOptions, Loader};
use depthsense_dataset::Dataset;
use depthsense_infer::upload::upload_batch;
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

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let reps: usize = std::env::args().nth(1).map_or(Ok(5), |s| s.parse())?;
    let tmp = tempfile::tempdir()?;
    depthsense_data::write_toy_dataset(tmp.path(), 2, 4, 800, 350, 1)?;
    let ds = Dataset::open(tmp.path())?;
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
    let (n, h, w) = (b.size as i64, b.height as i64, b.width as i64);
    let old = median_s(reps, || {
        let _ = Tensor::from_slice(&b.image).view([n, 3, h, w]);
        let _ = Tensor::from_slice(&b.radar).view([n, b.radar_channels as i64, h, w]);
        let _ = Tensor::from_slice(&b.target_m).view([n, 1, h, w]);
    });
    let new = median_s(reps, || {
        let _ = upload_batch(&b, Device::Cpu);
    });
    let gather = median_s(reps, || {
        let _ = SparseTarget::from_host(&b.target_m, (n, h, w), Device::Cpu);
    });
    let mut bt = upload_batch(&b, Device::Cpu);
    println!(
        "upload, batch 8 at 800x350 ({} valid target pixels): old {:.2} ms, new {:.2} ms; \
         host gather of the valid pixels (the CUDA path) {:.2} ms",
        bt.sparse.count,
        old * 1e3,
        new * 1e3,
        gather * 1e3
    );
    bt.sparse = SparseTarget::from_host(&b.target_m, (n, h, w), Device::Cpu);

    let sid = SidConfig::default();
    let z0 = Tensor::randn([n, 80, 44, 100], (Kind::Float, Device::Cpu));
    let loss_time = |sparse: bool| {
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
        loss_time(false) * 1e3,
        loss_time(true) * 1e3
    );

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
    let per_param = median_s(reps, || sgd.step(1e-3));
    let numel: i64 = vars.iter().map(|v| v.numel() as i64).sum();
    let mut p = Tensor::randn([numel], (Kind::Float, Device::Cpu));
    let g = Tensor::randn([numel], (Kind::Float, Device::Cpu));
    let mut buf = Tensor::randn([numel], (Kind::Float, Device::Cpu));
    let flat = median_s(reps, || {
        tch::no_grad(|| {
            let g = &g + &p * 1e-4;
            let _ = buf.g_mul_scalar_(0.9);
            let _ = buf.g_add_(&g);
            let _ = p.g_sub_(&(&buf * 1e-3));
        })
    });
    println!(
        "SGD step, paper preset ({} tensors, {:.1} M parameters): per parameter {:.1} ms, \
         one flat buffer {:.1} ms",
        vars.len(),
        numel as f64 / 1e6,
        per_param * 1e3,
        flat * 1e3
    );
    Ok(())
}
