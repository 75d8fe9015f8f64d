//! The inference graph ([`DepthNet::prepare_inference`]: BatchNorm folded, the fused decode)
//! against the training graph in evaluation mode (issue 44): the same decoded bin on
//! ≥ 99.99 % of pixels, for networks whose BatchNorms hold trained-like statistics.

use tch::{nn::VarStore, Device, Kind, Tensor};

use crate::precision::InferenceLayout;
use crate::test_rng::uniform;
use crate::DepthNet;
use depthsense_config::ModelConfig;

/// A network of `cfg` with deterministic weights: every variable redrawn, the conv weights
/// U(±1/√fan_in) and the 1-d ones (BatchNorm γ, β, running mean and variance, conv biases)
/// away from their initial values, as training leaves them.
fn trained_like(cfg: &ModelConfig) -> (VarStore, DepthNet) {
    let vs = VarStore::new(Device::Cpu);
    let net = DepthNet::new(&vs.root(), cfg).unwrap();
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let mut vars: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
    vars.sort_by(|a, b| a.0.cmp(&b.0));
    tch::no_grad(|| {
        for (name, mut t) in vars {
            let size = t.size();
            if t.dim() != 1 {
                let fan_in: i64 = size[1..].iter().product();
                let bound = 1.0 / (fan_in.max(1) as f64).sqrt();
                t.copy_(&((uniform(&size, &mut seed) * 2.0 - 1.0) * bound));
                continue;
            }
            let r = uniform(&size, &mut seed);
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
fn agreement(cfg: &ModelConfig, h: i64, w: i64, layout: InferenceLayout) -> (f64, f64) {
    let (_vs, net) = trained_like(cfg);
    let mut seed = 5u64 << 32 | 7;
    let img = (uniform(&[2, 3, h, w], &mut seed) - 0.5) * 4.0;
    let keep = uniform(&[2, 1, h, w], &mut seed).lt(0.02);
    let radar = (uniform(&[2, 1, h, w], &mut seed) * 60.0 + 2.0) * keep.to_kind(Kind::Float);
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
    net.prepare_inference(layout);
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
    let layouts = [InferenceLayout::Fastest, InferenceLayout::Nchw];
    let cases = [
        ("tiny", ModelConfig::tiny()),
        (
            "tiny, rgb only",
            ModelConfig::tiny()
                .with_options(&["fusion=none".to_string()])
                .unwrap(),
        ),
    ];
    for ((name, cfg), layout) in cases.iter().flat_map(|c| layouts.map(|l| (c, l))) {
        let (same, dz) = agreement(cfg, 64, 128, layout);
        assert!(
            same >= 0.9999,
            "{name}, {layout:?}: the same bin on {same} of the pixels"
        );
        assert!(dz < 1e-3, "{name}, {layout:?}: head outputs differ by {dz}");
        assert!(
            dz > 0.0 || same == 1.0,
            "{name}, {layout:?}: compared something"
        );
    }
}

/// On the CPU the fastest layout stores the folded weights channels-last, and the head's
/// output comes out channels-last (the layout travelled through the graph).
#[test]
fn the_cpu_inference_graph_runs_channels_last() {
    let cfg = ModelConfig::tiny();
    for (layout, want) in [
        (InferenceLayout::Fastest, true),
        (InferenceLayout::Nchw, false),
    ] {
        let (_vs, net) = trained_like(&cfg);
        net.prepare_inference(layout);
        let img = Tensor::zeros([1, 3, 32, 64], (Kind::Float, Device::Cpu));
        let radar = Tensor::zeros([1, cfg.radar_channels, 32, 64], (Kind::Float, Device::Cpu));
        let z = tch::no_grad(|| net.forward_logits_t(&img, &radar, false));
        let (c, h, w) = (z.size()[1], z.size()[2], z.size()[3]);
        let nhwc = z.stride() == [h * w * c, 1, w * c, c];
        assert_eq!(
            nhwc,
            want,
            "{layout:?}: head output strides {:?}",
            z.stride()
        );
    }
}

#[test]
fn folding_changes_nothing_in_training_mode() {
    let (_vs, net) = trained_like(&ModelConfig::tiny());
    net.prepare_inference(InferenceLayout::Fastest);
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

/// Weights loaded after `prepare_inference` (a `copy_` into the variables, as loading does):
/// the inference graph folds them again, so that it computes what a network prepared after
/// the load computes, not the weights it first folded.
#[test]
fn weights_loaded_after_preparing_are_folded_again() {
    let cfg = ModelConfig::tiny();
    let (vs, net) = trained_like(&cfg);
    net.prepare_inference(InferenceLayout::Fastest);
    let mut seed = 11u64;
    let img = (uniform(&[1, 3, 32, 64], &mut seed) - 0.5) * 4.0;
    let radar = Tensor::zeros([1, cfg.radar_channels, 32, 64], (Kind::Float, Device::Cpu));
    let run = |net: &DepthNet| tch::no_grad(|| net.forward_logits_t(&img, &radar, false));
    let before = run(&net);
    tch::no_grad(|| {
        for (name, mut t) in vs.variables() {
            if name.ends_with("running_var") || name.contains("conv") {
                let changed = &t * 1.5;
                t.copy_(&changed);
            }
        }
    });
    let after = run(&net);
    let mut vs2 = VarStore::new(Device::Cpu);
    let fresh = DepthNet::new(&vs2.root(), &cfg).unwrap();
    vs2.copy(&vs).unwrap();
    fresh.prepare_inference(InferenceLayout::Fastest);
    let want = run(&fresh);
    let moved = (&after - &before).abs().max().double_value(&[]);
    let off = (&after - &want).abs().max().double_value(&[]);
    assert!(moved > 1e-3, "the new weights changed nothing ({moved})");
    assert!(off < 1e-5, "stale folded weights: {off} from a fresh fold");
}
