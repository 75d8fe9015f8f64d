//! The released architecture against PyTorch (SPEC §6.1, §7): `released_reference.py` builds the
//! authors' network in plain PyTorch at a narrow width (random weights, fixed seed, random BN
//! statistics, eval mode), saves `torch.save(model.state_dict())` under the authors' key names
//! and decodes a fixed input with their conventions. We load the `.pth` through
//! `checkpoint::load_any` (the `predict`/`eval --checkpoint FILE.pth --config released` path) and
//! compare the decoded SID levels pixel by pixel. Skips when the workspace `.venv` (torch) is
//! absent.

use std::path::Path;

use crate::support::reference;

use depthsense_checkpoint as checkpoint;
use depthsense_config::ModelConfig;
use depthsense_model::ordinal;
use tch::{Device, Kind, Tensor};

const H: i64 = 64;
const W: i64 = 128;

/// The narrow `released` config the Python side builds too (ResNet-101 layout, widths /8).
fn narrow_released() -> ModelConfig {
    let mut c = ModelConfig::released();
    c.backbone_width = 8;
    c.radar_width = 8;
    c.decoder_channels = 16;
    c.head_channels = 16;
    c.radar_out_channels = 16;
    c.out_height = H;
    c.out_width = W;
    c
}

fn read_f32(p: &Path, shape: &[i64]) -> Tensor {
    let b = std::fs::read(p).unwrap();
    let v: Vec<f32> = b
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    Tensor::from_slice(&v).view(shape)
}

fn read_i64(p: &Path, shape: &[i64]) -> Tensor {
    let b = std::fs::read(p).unwrap();
    let v: Vec<i64> = b
        .chunks_exact(8)
        .map(|c| i64::from_le_bytes(c.try_into().unwrap()))
        .collect();
    Tensor::from_slice(&v).view(shape)
}

/// (fraction of pixels with the same level, fraction within one level, max |Δlevel|).
fn agreement(ours: &Tensor, theirs: &Tensor) -> (f64, f64, i64) {
    let d = (ours - theirs).abs();
    let n = d.numel() as f64;
    (
        d.eq(0).sum(Kind::Int64).int64_value(&[]) as f64 / n,
        d.le(1).sum(Kind::Int64).int64_value(&[]) as f64 / n,
        d.max().int64_value(&[]),
    )
}

#[test]
fn released_pth_written_by_pytorch_decodes_like_pytorch() {
    let cfg = narrow_released();
    let dir = tempfile::tempdir().unwrap();
    let params = serde_json::json!({
        "seed": 7,
        "width": cfg.backbone_width,
        "blocks": [3, 4, 23, 3], // ResNet-101
        "decoder_channels": cfg.decoder_channels,
        "radar_width": cfg.radar_width,
        "radar_channels": cfg.radar_channels,
        "radar_out_channels": cfg.radar_out_channels,
        "head_channels": cfg.head_channels,
        "bins": cfg.sid.bins,
        "height": H,
        "width_px": W,
        "bn_spread": 0.3,
        "head_gain": 20.0,
        "radar_strips": 40,
        "alpha": cfg.sid.alpha_m,
        "beta": cfg.sid.beta_m,
        "decode_offset": cfg.sid.decode_offset_m,
    });
    let Some(info) = reference::run_reference(dir.path(), &params) else {
        return;
    };

    // Load the authors'-format .pth through the predict/eval path.
    let pth = dir.path().join("weights.pth");
    let (loaded, report) = checkpoint::load_any(&pth, Some(&cfg), Device::Cpu).unwrap();
    let report = report.expect("a PyTorch file gives an import report");
    eprint!("{report}");
    assert!(report.left_random.is_empty() && report.partial.is_empty());
    assert!(report.unused.is_empty(), "{:?}", report.unused);
    let n_vars = loaded.vs.variables().len();
    assert_eq!(report.loaded.len(), n_vars);
    assert_eq!(
        report.loaded.len() + report.skipped.len(),
        info["keys"].as_u64().unwrap() as usize
    );
    assert!(report
        .skipped
        .iter()
        .all(|(k, _)| k.ends_with("num_batches_tracked")));

    let image = read_f32(&dir.path().join("image.f32"), &[1, 3, H, W]);
    let radar = read_f32(&dir.path().join("radar.f32"), &[1, 1, H, W]);
    let theirs = read_i64(&dir.path().join("levels.i64"), &[1, 1, H, W]);
    let their_depth = read_f32(&dir.path().join("depth.f32"), &[1, 1, H, W]);
    let net = &loaded.net;
    let z = tch::no_grad(|| net.forward_t(&image, &radar, false));
    assert_eq!(z.size(), [1, cfg.sid.bins, H, W], "clamped z at full res");
    let ours = ordinal::ordinal_levels(&z, H, W, cfg.align_corners);
    let (same, within1, maxd) = agreement(&ours, &theirs);
    eprintln!(
        "agreement with PyTorch: {:.4} % same level, {:.4} % within one bin, max |Δlevel| {maxd}",
        100.0 * same,
        100.0 * within1
    );
    assert!(within1 >= 0.995, "only {within1} within one bin");
    let depth = tch::no_grad(|| net.decode(&z));
    let mask = ours.eq_tensor(&theirs);
    let dd = ((&depth - &their_depth).abs() * mask.to_kind(Kind::Float))
        .max()
        .double_value(&[]);
    assert!(dd < 1e-3, "decoded depth differs by {dd} m at equal levels");
    let offset_ok = (&their_depth - &depth).abs().max().double_value(&[]);
    eprintln!("max |Δdepth| over all pixels: {offset_ok:.4} m");

    // The test can fail: without the clamp or with radar scaled by 1/β the network decodes
    // differently from the reference.
    for (what, set) in [
        ("clamp-logits=off", "clamp-logits=off"),
        ("radar-in-metres=off", "radar-in-metres=off"),
    ] {
        let c = cfg.clone().with_options(&[set]).unwrap();
        let (l, _) = checkpoint::load_any(&pth, Some(&c), Device::Cpu).unwrap();
        let z = tch::no_grad(|| l.net.forward_t(&image, &radar, false));
        let lv = ordinal::ordinal_levels(&z, H, W, c.align_corners);
        let (s, w1, m) = agreement(&lv, &theirs);
        eprintln!(
            "{what}: {:.2} % same level, {:.2} % within one bin, max |Δlevel| {m}",
            100.0 * s,
            100.0 * w1
        );
        assert!(s < same, "{what} should decode differently");
    }
}

fn build(cfg: &ModelConfig) -> (tch::nn::VarStore, depthsense_model::DepthNet) {
    let vs = tch::nn::VarStore::new(Device::Cpu);
    let net = depthsense_model::DepthNet::new(&vs.root(), cfg).unwrap();
    (vs, net)
}

#[test]
fn clamped_pairs_equal_the_pairwise_softmax_after_upsampling() {
    tch::manual_seed(5);
    let opts = (Kind::Float, Device::Cpu);
    let logits = Tensor::randn([2, 160, 3, 5], opts) * 2.0;
    let (h, w) = (13, 21);
    // Naive: upsample all 2K channels, clamp, softmax over each pair, count P_k ≥ 0.5.
    let up = logits.upsample_bilinear2d([h, w], true, None, None);
    let pairs = up.view([2, 80, 2, h, w]).clamp(1e-8, 1e8);
    let p1 = pairs.softmax(2, Kind::Float).select(2, 1);
    let naive = p1.ge(0.5).sum_dim_intlist(1, true, Kind::Int64);
    let z = ordinal::clamped_pair_differences(&logits, h, w, true);
    assert_eq!(z.size(), [2, 80, h, w]);
    assert!(z.sigmoid().allclose(&p1, 1e-6, 1e-6, false));
    let ours = ordinal::ordinal_levels(&z, h, w, true);
    assert!(ours.equal(&naive));
    // The clamp matters: the efficient unclamped form decodes differently.
    let plain = ordinal::ordinal_levels(&ordinal::pair_differences(&logits), h, w, true);
    assert!(!plain.equal(&naive));
}

#[test]
fn radar_in_metres_skips_the_one_over_beta_scaling() {
    let on = narrow_released();
    let off = on.clone().with_options(&["radar-in-metres=off"]).unwrap();
    let (vs_on, net_on) = build(&on);
    let (mut vs_off, net_off) = build(&off);
    vs_off.copy(&vs_on).unwrap();
    let opts = (Kind::Float, Device::Cpu);
    tch::manual_seed(2);
    let image = Tensor::randn([1, 3, H, W], opts);
    let radar_m = Tensor::rand([1, 1, H, W], opts).lt(0.05) * 40.0;
    let a = tch::no_grad(|| net_on.forward_logits_t(&image, &(&radar_m / on.sid.beta_m), false));
    let b = tch::no_grad(|| net_off.forward_logits_t(&image, &radar_m, false));
    assert!(a.allclose(&b, 1e-5, 1e-5, false));
    let c = tch::no_grad(|| net_on.forward_logits_t(&image, &radar_m, false));
    assert!(!c.allclose(&b, 1e-5, 1e-5, false));
}

/// The RGB-encoder variables of `cfg` under torchvision names (`rgb.` removed), plus `fc.*`.
fn imagenet_file(cfg: &ModelConfig, path: &Path) -> Vec<(String, Tensor)> {
    tch::manual_seed(13);
    let (vs, _) = build(cfg);
    let mut sd: Vec<(String, Tensor)> = vs
        .variables()
        .into_iter()
        .filter_map(|(k, v)| {
            k.strip_prefix("rgb.")
                .map(|s| (s.to_string(), v.detach() + 0.25))
        })
        .collect();
    sd.sort_by(|a, b| a.0.cmp(&b.0));
    let fc_in = 32 * cfg.backbone_width;
    sd.push((
        "fc.weight".into(),
        Tensor::zeros([1000, fc_in], (Kind::Float, Device::Cpu)),
    ));
    sd.push((
        "fc.bias".into(),
        Tensor::zeros([1000], (Kind::Float, Device::Cpu)),
    ));
    sd.push(("bn1.num_batches_tracked".into(), Tensor::from(5i64)));
    depthsense_weights::pth_writer::write_torch_state_dict(
        path,
        &depthsense_checkpoint::host::all_to_host(&sd).unwrap(),
    )
    .unwrap();
    sd
}

#[test]
fn torchvision_and_deep_stem_imagenet_files_load_into_released() {
    let dir = tempfile::tempdir().unwrap();
    let released = narrow_released(); // deep stem, ResNet-101, w = 8 (layer1 input 16)
    let tv = released
        .clone()
        .with_options(&["stem=torchvision"])
        .unwrap();
    let get = |sd: &[(String, Tensor)], k: &str| {
        sd.iter()
            .find(|x| x.0 == k)
            .map(|x| x.1.shallow_clone())
            .unwrap()
    };

    // 1. A torchvision file (7x7 stem, layer1 input 8) into the deep stem: never an error.
    let tv_path = dir.path().join("resnet101-tv.pth");
    let tv_sd = imagenet_file(&tv, &tv_path);
    let (mut vs, _) = build(&released);
    let rep = depthsense_checkpoint::weights::load_torchvision_resnet(&mut vs, &tv_path).unwrap();
    let text = rep.to_string();
    eprint!("{text}");
    let partial: Vec<&str> = rep.partial.iter().map(|p| p.0.as_str()).collect();
    assert_eq!(
        partial,
        [
            "rgb.layer1.0.conv1.weight",
            "rgb.layer1.0.downsample.0.weight"
        ]
    );
    assert!(
        rep.partial[0].1.contains("0..8 copied, 8..16 zeroed"),
        "{text}"
    );
    let vars = vs.variables();
    for name in ["layer1.0.conv1.weight", "layer1.0.downsample.0.weight"] {
        let v = &vars[&format!("rgb.{name}")];
        assert!(v.narrow(1, 0, 8).equal(&get(&tv_sd, name)));
        assert_eq!(
            v.narrow(1, 8, 8).abs().sum(Kind::Double).double_value(&[]),
            0.0
        );
    }
    assert!(vars["rgb.layer3.22.conv3.weight"].equal(&get(&tv_sd, "layer3.22.conv3.weight")));
    // the file's conv1/bn1 skipped (5 tensors), fc (2) and the BN counter
    let skipped_stem = rep
        .skipped
        .iter()
        .filter(|(_, why)| why.contains("torchvision stem"))
        .count();
    assert_eq!(skipped_stem, 5);
    assert_eq!(rep.skipped.len(), 8);
    assert!(rep.unused.is_empty());
    for k in [
        "rgb.conv1.weight",
        "rgb.conv2.weight",
        "rgb.bn3.running_var",
    ] {
        assert!(rep.left_random.iter().any(|x| x == k), "{k} left random");
    }
    assert!(rep.left_random.iter().all(|k| !k.starts_with("rgb.layer")));
    // a short summary, not a list of every tensor
    assert!(text.lines().count() < 30, "{text}");
    assert!(text.contains("rgb.layer1 "), "{text}");
    assert!(text.contains("partly loaded: rgb.layer1.0.downsample.0.weight"));
    assert!(
        text.contains("left random: rgb.bn1, rgb.bn2, rgb.bn3, rgb.conv1, rgb.conv2, rgb.conv3")
    );
    assert!(text.contains("radar.layer3.* (14 modules)"), "{text}");

    // 2. A deep-stem ImageNet file (conv1/conv2/conv3 + bn1..bn3) loads into the deep stem.
    let deep_path = dir.path().join("resnet101-deep.pth");
    let deep_sd = imagenet_file(&released, &deep_path);
    let (mut vs, _) = build(&released);
    let rep = depthsense_checkpoint::weights::load_torchvision_resnet(&mut vs, &deep_path).unwrap();
    assert!(rep.partial.is_empty(), "{rep}");
    assert!(
        rep.left_random.iter().all(|k| !k.starts_with("rgb.")),
        "{rep}"
    );
    let vars = vs.variables();
    for name in [
        "conv1.weight",
        "conv3.weight",
        "bn2.running_mean",
        "layer1.0.conv1.weight",
    ] {
        assert!(
            vars[&format!("rgb.{name}")].equal(&get(&deep_sd, name)),
            "{name}"
        );
    }
    assert_eq!(rep.skipped.len(), 3, "fc.weight, fc.bias, the BN counter");

    // 3. The deep-stem file into a torchvision-stem network: stem skipped, the first 8 of the
    //    file's 16 layer1 input channels copied.
    let (mut vs, _) = build(&tv);
    let rep = depthsense_checkpoint::weights::load_torchvision_resnet(&mut vs, &deep_path).unwrap();
    assert_eq!(rep.partial.len(), 2, "{rep}");
    assert!(rep.partial[0].1.contains("first 8 of 16"), "{rep}");
    let v = &vs.variables()["rgb.layer1.0.conv1.weight"];
    assert!(v.equal(&get(&deep_sd, "layer1.0.conv1.weight").narrow(1, 0, 8)));
    assert_eq!(
        rep.skipped
            .iter()
            .filter(|(_, why)| why.contains("deep stem"))
            .count(),
        15,
        "conv1..3 + bn1..3"
    );
}
