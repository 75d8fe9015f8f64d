//! Initialisation matches PyTorch / torchvision (DEVELOPERS: initialisation is part of the
//! method). Each test fails on tch's defaults (BN γ ~ U(0,1), He-uniform convs, random gate).

use tch::{nn::VarStore, Device, Kind, Tensor};

use crate::DepthNet;
use depthsense_config::ModelConfig;

fn tiny_net() -> (VarStore, DepthNet) {
    tch::manual_seed(3);
    let vs = VarStore::new(Device::Cpu);
    let net = DepthNet::new(&vs.root(), &ModelConfig::tiny()).unwrap();
    (vs, net)
}

fn is_bn(name: &str) -> bool {
    let last = name.rsplit('.').nth(1).unwrap_or("");
    last.starts_with("bn") || name.contains("downsample.1")
}

#[test]
fn batchnorm_starts_at_gamma_one_beta_zero() {
    let (vs, _) = tiny_net();
    let mut n = 0;
    for (name, t) in vs.variables() {
        if is_bn(&name) && name.ends_with(".weight") {
            assert!(t.eq(1.0).all().int64_value(&[]) == 1, "{name} γ ≠ 1");
            n += 1;
        }
        if is_bn(&name) && name.ends_with(".bias") {
            assert!(t.eq(0.0).all().int64_value(&[]) == 1, "{name} β ≠ 0");
        }
    }
    assert!(n > 20, "found only {n} BatchNorm layers");
}

#[test]
fn convs_without_batchnorm_use_pytorch_bounds() {
    // nn.Conv2d: weight and bias ~ U(±1/√fan_in). tch's default reaches √6/√fan_in.
    let (vs, _) = tiny_net();
    let vars = vs.variables();
    let mut checked = 0;
    for (name, w) in &vars {
        let non_bn_conv = name.starts_with("decoder.") || name.starts_with("head.");
        if !non_bn_conv || !name.ends_with(".weight") || w.dim() != 4 {
            continue;
        }
        let s = w.size();
        let fan_in = (s[1] * s[2] * s[3]) as f64;
        let bound = 1.0 / fan_in.sqrt();
        let max = w.abs().max().double_value(&[]);
        assert!(
            max <= bound + 1e-7,
            "{name}: |w| max {max} > 1/√fan_in {bound}"
        );
        // A uniform draw of this many values comes close to the bound (not a constant init).
        if w.numel() >= 256 {
            assert!(max > 0.9 * bound, "{name}: |w| max {max} ≪ bound {bound}");
        }
        let b = &vars[&name.replace(".weight", ".bias")];
        let bmax = b.abs().max().double_value(&[]);
        assert!(
            bmax <= bound + 1e-7 && bmax > 0.0,
            "{name} bias: max {bmax}, bound {bound}"
        );
        checked += 1;
    }
    assert!(checked >= 8, "checked only {checked} convs");
}

#[test]
fn resnet_convs_follow_torchvision_fan_out_normal() {
    // torchvision ResNet: kaiming_normal(mode = fan_out, ReLU): std = √(2 / (cout·k·k)).
    let (vs, _) = tiny_net();
    let w = &vs.variables()["rgb.layer3.0.conv2.weight"];
    let s = w.size();
    let want = (2.0 / (s[0] * s[2] * s[3]) as f64).sqrt();
    let got = w.std(true).double_value(&[]);
    assert!((got / want - 1.0).abs() < 0.05, "std {got}, want {want}");
}

#[test]
fn attention_is_the_identity_at_initialisation() {
    let (_, net) = tiny_net();
    let f = Tensor::randn([2, 24, 5, 7], (Kind::Float, Device::Cpu)) * 3.0;
    let g = net.attend(&f);
    let diff = (&g - &f).abs().max().double_value(&[]);
    assert_eq!(
        diff, 0.0,
        "attention output differs from its input by {diff}"
    );
}

#[test]
fn bounded_gate_starts_as_the_identity_and_never_closes() {
    use depthsense_config::AttentionGate;
    let mut cfg = ModelConfig::tiny();
    cfg.attention_gate = AttentionGate::Bounded;
    let vs = VarStore::new(Device::Cpu);
    let net = DepthNet::new(&vs.root(), &cfg).unwrap();
    let f = Tensor::randn([2, 24, 5, 7], (Kind::Float, Device::Cpu)).abs() + 0.1;
    assert_eq!((net.attend(&f) - &f).abs().max().double_value(&[]), 0.0);
    // a conv that drives s → −∞ (as the collapsed MER runs learned): the bounded gate keeps
    // half of every feature, the double gate would switch them off
    tch::no_grad(|| {
        let _ = vs.variables()["attention.conv.weight"]
            .shallow_clone()
            .fill_(-50.0);
    });
    let ratio = (net.attend(&f) / &f).min().double_value(&[]);
    assert!((ratio - 0.5).abs() < 1e-4, "{ratio}");
    cfg.attention_gate = AttentionGate::Double;
    let vs2 = VarStore::new(Device::Cpu);
    let double = DepthNet::new(&vs2.root(), &cfg).unwrap();
    tch::no_grad(|| {
        let _ = vs2.variables()["attention.conv.weight"]
            .shallow_clone()
            .fill_(-50.0);
    });
    assert!(double.attend(&f).abs().max().double_value(&[]) < 1e-6);
    // the presets use the bounded gate; a config without the field (a checkpoint written
    // before it existed) reads back with the gate it was trained with
    assert_eq!(ModelConfig::tiny().attention_gate, AttentionGate::Bounded);
    let mut js = serde_json::to_value(ModelConfig::tiny()).unwrap();
    assert_eq!(js["attention_gate"], "bounded");
    js.as_object_mut().unwrap().remove("attention_gate");
    let old: ModelConfig = serde_json::from_value(js).unwrap();
    assert_eq!(old.attention_gate, AttentionGate::Double);
}
