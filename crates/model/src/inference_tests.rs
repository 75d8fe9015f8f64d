//! The inference graph ([`DepthNet::prepare_inference`]: BatchNorm folded, the fused decode)
//! against the training graph in evaluation mode (issue 44): the same decoded bin on
//! ≥ 99.99 % of pixels, for networks whose BatchNorms hold trained-like statistics.

use tch::{nn::VarStore, Device, Kind, Tensor};

use crate::DepthNet;
use depthsense_config::ModelConfig;

/// A network of `cfg` whose 1-d variables (BatchNorm γ, β, running mean and variance, conv
/// biases) are drawn away from their initial values, as training leaves them.
fn trained_like(cfg: &ModelConfig) -> (VarStore, DepthNet) {
    tch::manual_seed(11);
    let vs = VarStore::new(Device::Cpu);
    let net = DepthNet::new(&vs.root(), cfg).unwrap();
    tch::no_grad(|| {
        for (name, mut t) in vs.variables() {
            if t.dim() != 1 {
                continue;
            }
            let n = t.size()[0];
            let r = Tensor::rand([n], (Kind::Float, Device::Cpu));
            let v = if name.ends_with("running_var") {
                r * 1.5 + 0.5
            } else if name.ends_with("running_mean") {
                (r - 0.5) * 0.4
            } else if name.ends_with(".weight") {
                r * 0.8 + 0.6
            } else {
                (r - 0.5) * 0.2
            };
            t.copy_(&v);
        }
    });
    (vs, net)
}

/// Fraction of pixels whose decoded depth is the same in both graphs, and the largest
/// difference of the head output.
fn agreement(cfg: &ModelConfig, h: i64, w: i64) -> (f64, f64) {
    let (_vs, net) = trained_like(cfg);
    tch::manual_seed(5);
    let img = Tensor::randn([2, 3, h, w], (Kind::Float, Device::Cpu));
    let keep = Tensor::rand([2, 1, h, w], (Kind::Float, Device::Cpu)).lt(0.02);
    let radar = (Tensor::rand([2, 1, h, w], (Kind::Float, Device::Cpu)) * 60.0 + 2.0)
        * keep.to_kind(Kind::Float);
    let channels = cfg.radar_channels;
    let radar = radar.repeat([1, channels, 1, 1]);
    let run = || {
        tch::no_grad(|| {
            let z = net.forward_t(&img, &radar, false);
            (net.decode_to(&z, h, w), z)
        })
    };
    let (d_train, z_train) = run();
    assert!(!net.is_inference_graph());
    net.prepare_inference();
    let (d_inf, z_inf) = run();
    let same = d_train
        .eq_tensor(&d_inf)
        .to_kind(Kind::Double)
        .mean(Kind::Double)
        .double_value(&[]);
    let dz = (z_train - z_inf).abs().max().double_value(&[]);
    (same, dz)
}

#[test]
fn the_inference_graph_decodes_the_training_graphs_bins() {
    for (name, cfg) in [
        ("tiny", ModelConfig::tiny()),
        (
            "tiny, rgb only",
            ModelConfig::tiny()
                .with_options(&["fusion=none".to_string()])
                .unwrap(),
        ),
    ] {
        let (same, dz) = agreement(&cfg, 64, 128);
        assert!(
            same >= 0.9999,
            "{name}: the same bin on {same} of the pixels"
        );
        assert!(dz < 1e-3, "{name}: head outputs differ by {dz}");
        assert!(dz > 0.0 || same == 1.0, "{name}: compared something");
    }
}

#[test]
fn folding_changes_nothing_in_training_mode() {
    let (_vs, net) = trained_like(&ModelConfig::tiny());
    net.prepare_inference();
    tch::manual_seed(2);
    let img = Tensor::randn([2, 3, 32, 64], (Kind::Float, Device::Cpu));
    let radar = Tensor::zeros(
        [2, ModelConfig::tiny().radar_channels, 32, 64],
        (Kind::Float, Device::Cpu),
    );
    // Training mode normalises with the batch's statistics: the folded (running-statistics)
    // conv would give another output; the graph must not take it.
    let z = net.forward_t(&img, &radar, true);
    assert!(
        z.requires_grad(),
        "the training graph keeps its BatchNorm parameters"
    );
}
