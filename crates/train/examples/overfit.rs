//! Overfit one batch of the toy dataset: a sanity check of model + loss + optimiser.
use depthsense_config::{Fusion, ModelConfig};
use depthsense_data::*;
use depthsense_dataset::Dataset;
use depthsense_model::DepthNet;
use depthsense_train::optim::Optimizer;
use tch::nn::OptimizerConfig;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let mine = args.get(1).map(String::as_str) != Some("tch");
    let lr: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1e-2);
    let tmp = tempfile::tempdir().unwrap();
    write_toy_dataset(tmp.path(), 1, 4, 128, 64, 11).unwrap();
    let ds = Dataset::open(tmp.path()).unwrap();
    let plan = EpochPlan {
        entries: ds.split("all"),
        batch_size: 4,
        epoch: 0,
        shuffle: false,
        drop_last: false,
        skip_batches: 0,
        jobs: 1,
        prefetch: 1,
    };
    let b = Loader::start(
        &ds,
        &LoadOptions {
            no_radar: true,
            ..Default::default()
        },
        &plan,
    )
    .unwrap()
    .next()
    .unwrap()
    .unwrap();
    let (img, rad, tgt) = depthsense_infer::upload::batch_tensors(&b, tch::Device::Cpu);
    println!(
        "img mean {:.3} std {:.3} tgt mean {:.2}",
        img.mean(tch::Kind::Float).double_value(&[]),
        img.std(true).double_value(&[]),
        tgt.mean(tch::Kind::Float).double_value(&[])
    );
    let mut cfg = ModelConfig::tiny();
    cfg.fusion = Fusion::None;
    cfg.attention = false;
    if std::env::var("HEAD").is_ok() {
        cfg.head = depthsense_config::HeadKind::L1;
    }
    if std::env::var("NODROP").is_ok() {
        cfg.dropout = 0.0;
    }
    cfg.out_height = 64;
    cfg.out_width = 128;
    tch::manual_seed(0);
    let vs = tch::nn::VarStore::new(tch::Device::Cpu);
    let net = DepthNet::new(&vs.root(), &cfg).unwrap();
    let mut sgd = depthsense_train::sgd::Sgd::new(&vs, 0.9, 1e-4);
    let mut opt = tch::nn::Sgd {
        momentum: 0.9,
        dampening: 0.0,
        wd: 1e-4,
        nesterov: false,
    }
    .build(&vs, lr)
    .unwrap();
    println!("trainable {}", sgd.len());
    for i in 0..40 {
        let out = net.forward_t(&img, &rad, true);
        let loss = net.loss(&out, &tgt);
        if mine {
            sgd.zero_grad();
            loss.backward();
            sgd.step(lr);
        } else {
            opt.backward_step(&loss);
        }
        if i % 5 == 0 {
            let d = tch::no_grad(|| net.decode(&net.forward_t(&img, &rad, false)));
            let dt = tch::no_grad(|| net.decode(&net.forward_t(&img, &rad, true)));
            let rm = |d: &tch::Tensor| {
                ((d - &tgt).square().mean(tch::Kind::Float))
                    .sqrt()
                    .double_value(&[])
            };
            println!(
                "{i}: loss {:.3} rmse eval {:.2} train-mode {:.2} pred std {:.2}",
                loss.double_value(&[]),
                rm(&d),
                rm(&dt),
                dt.std(true).double_value(&[])
            );
        }
    }
}
