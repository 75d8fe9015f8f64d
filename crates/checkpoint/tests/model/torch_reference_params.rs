//! `scripts/torch_reference.py` (the PyTorch eager reference of issue 9, timed side by side with
//! `depthsense bench model`) builds the same networks as `DepthNet`: for every preset its
//! trainable parameters and conv multiply-adds at 350x800 equal ours exactly. The script counts
//! on PyTorch's meta device (nothing allocated); we build each preset on the CPU. And with the
//! same weights it computes the same head output: our VarStore loads into it under our own
//! variable names (every key and shape equal) and the outputs agree to fp32 rounding. Skips when
//! the workspace `.venv` (torch) is absent or torch does not import (exit code 77).

use std::path::{Path, PathBuf};
use std::process::Command;

use depthsense_config::ModelConfig;
use depthsense_model::{report, DepthNet};
use tch::{nn, Device, Kind, Tensor};

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The venv's Python with torch: a failure under DEPTHSENSE_REQUIRE_TORCH=1, else a counted skip.
fn python() -> Option<PathBuf> {
    depthsense_testkit::python_with_torch()
}

const PRESETS: [&str; 4] = ["released", "paper", "tiny", "tiny-wide"];

/// (preset, params, macs_per_image) from the Python reference (one process for all presets), or
/// None (skip) without torch.
fn torch_counts(py: &Path) -> Option<Vec<(String, i64, u64)>> {
    let script = workspace().join("scripts/torch_reference.py");
    let out = Command::new(py)
        .arg(&script)
        .args([
            "--params-only",
            "--threads",
            "1",
            "--config",
            &PRESETS.join(","),
        ])
        .output()
        .expect("running scripts/torch_reference.py");
    if out.status.code() == Some(77) {
        let why = format!(
            "torch is not importable in .venv: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        return depthsense_testkit::unavailable(depthsense_testkit::REQUIRE_TORCH, &why);
    }
    assert!(
        out.status.success(),
        "torch_reference.py --params-only failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("not JSON ({e}): {}", String::from_utf8_lossy(&out.stdout)));
    let runs = v["runs"].as_array().expect("{\"runs\": [...]}");
    Some(
        runs.iter()
            .map(|r| {
                assert_eq!(
                    (r["height"].as_i64(), r["width"].as_i64()),
                    (Some(350), Some(800))
                );
                (
                    r["config"].as_str().expect("config").to_string(),
                    r["params"].as_i64().expect("params"),
                    r["macs_per_image"].as_u64().expect("macs_per_image"),
                )
            })
            .collect(),
    )
}

#[test]
fn torch_reference_builds_our_presets_parameter_for_parameter() {
    let Some(py) = python() else { return };
    let Some(counts) = torch_counts(&py) else {
        return;
    };
    let names: Vec<&str> = counts.iter().map(|c| c.0.as_str()).collect();
    assert_eq!(names, PRESETS, "one row per preset, in order");
    for (preset, params, macs) in counts {
        let preset = preset.as_str();
        let cfg = ModelConfig::preset(preset).unwrap();
        let vs = nn::VarStore::new(Device::Cpu);
        let net = DepthNet::new(&vs.root(), &cfg).unwrap();
        let rep = report::model_report(&vs, &net, 350, 800);
        eprintln!(
            "{preset}: ours {} params {} MACs, PyTorch {params} params {macs} MACs",
            rep.total_params, rep.total_macs
        );
        assert_eq!(
            rep.total_params, params,
            "{preset}: parameters, ours vs PyTorch"
        );
        assert_eq!(
            rep.total_macs, macs,
            "{preset}: multiply-adds per image, ours vs PyTorch"
        );
        if preset == "released" {
            assert_eq!(params, 68_399_904, "SPEC §6.1");
        }
    }
}

fn write_f32(path: &Path, t: &Tensor) {
    let v = Vec::<f32>::try_from(t.flatten(0, -1)).unwrap();
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    std::fs::write(path, bytes).unwrap();
}

/// Random BatchNorm affine parameters and statistics, and a non-zero attention conv, so that
/// every module changes the output (the attention conv starts at zero: identity gate).
fn randomise(vs: &nn::VarStore) {
    tch::no_grad(|| {
        for (name, mut v) in vs.variables() {
            let r = Tensor::rand_like(&v);
            if name.ends_with("running_var") {
                v.copy_(&(r * 0.7 + 0.8));
            } else if name.ends_with("running_mean") || name.contains("attention") {
                v.copy_(&((r - 0.5) * 0.2));
            } else if v.dim() == 1 && name.contains(".bn") || name.contains("downsample.1") {
                if name.ends_with("weight") {
                    v.copy_(&(r * 0.4 + 0.8));
                } else {
                    v.copy_(&((r - 0.5) * 0.2));
                }
            }
        }
    })
}

/// The same weights give the same head output: our VarStore (saved as safetensors) loads into
/// the PyTorch reference under our own variable names — every key and shape must match — and
/// `DepthNet::forward_t` in eval mode equals the reference's forward in fp32 on the CPU, for the
/// paper layout (tiny), a narrow released layout (deep stem, FPN decoder, bottleneck radar
/// branch, clamped logits at full resolution) and an early-fusion ResNet-50 with input
/// downscaling.
#[test]
fn torch_reference_computes_what_depthnet_computes() {
    let Some(py) = python() else { return };
    let (b, h, w) = (2i64, 64i64, 128i64);
    let narrow = [
        "width=8",
        "decoder-channels=16",
        "head-channels=16",
        "radar-width=8",
    ];
    let mut released = ModelConfig::released().with_options(&narrow).unwrap();
    released.radar_out_channels = 16;
    released.out_height = h;
    released.out_width = w;
    let early = ModelConfig::paper()
        .with_options(&narrow)
        .unwrap()
        .with_options(&[
            "backbone=50",
            "fusion=early",
            "attention=off",
            "input-downscale=2",
        ])
        .unwrap();
    // The presets' bounded attention gate with both radar options; and the 2σ(s) gate.
    let tiny_radar = ModelConfig::tiny()
        .with_options(&["input-downscale=2", "radar-downscale=1", "radar-skip=8"])
        .unwrap();
    let tiny_double = ModelConfig::tiny()
        .with_options(&["attention-gate=double"])
        .unwrap();
    // RGB only, the regression heads, and MER's 7 radar channels.
    let tiny_with = |o: &str| ModelConfig::tiny().with_options(&[o]).unwrap();
    let small = [
        tiny_with("fusion=none"),
        tiny_with("head=l1"),
        tiny_with("head=l2"),
        tiny_with("radar-input=mer"),
    ];
    for mut cfg in [
        ModelConfig::tiny(),
        tiny_radar,
        tiny_double,
        released,
        early,
    ]
    .into_iter()
    .chain(small)
    {
        // Depth is decoded at the input's size here.
        (cfg.out_height, cfg.out_width) = (h, w);
        tch::manual_seed(3);
        let vs = nn::VarStore::new(Device::Cpu);
        let net = DepthNet::new(&vs.root(), &cfg).unwrap();
        randomise(&vs);
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        vs.save(d.join("weights.safetensors")).unwrap();
        std::fs::write(d.join("config.json"), serde_json::to_string(&cfg).unwrap()).unwrap();
        std::fs::write(
            d.join("shape.json"),
            serde_json::json!({"batch": b, "height": h, "width": w}).to_string(),
        )
        .unwrap();
        let image = Tensor::randn([b, 3, h, w], (Kind::Float, Device::Cpu));
        let rc = cfg.radar_channels;
        let mask = Tensor::rand([b, rc, h, w], (Kind::Float, Device::Cpu)).lt(0.05);
        let radar = (Tensor::rand([b, rc, h, w], (Kind::Float, Device::Cpu)) * 60.0 + 2.0) * mask;
        write_f32(&d.join("image.f32"), &image);
        write_f32(&d.join("radar.f32"), &radar);
        let out = Command::new(&py)
            .arg(workspace().join("scripts/torch_reference.py"))
            .args(["--threads", "1", "--check"])
            .arg(d)
            .output()
            .expect("running scripts/torch_reference.py --check");
        if out.status.code() == Some(77) {
            let why = "torch is not importable in .venv (exit code 77)";
            let _: Option<()> =
                depthsense_testkit::unavailable(depthsense_testkit::REQUIRE_TORCH, why);
            return;
        }
        let report = String::from_utf8_lossy(&out.stdout).to_string();
        assert!(
            out.status.success(),
            "{}: --check failed: {report} {}",
            cfg.name,
            String::from_utf8_lossy(&out.stderr)
        );
        let ours = tch::no_grad(|| net.forward_t(&image, &radar, false));
        let bytes = std::fs::read(d.join("z.f32")).unwrap();
        let theirs: Vec<f32> = bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        let theirs = Tensor::from_slice(&theirs).view(ours.size().as_slice());
        let scale = ours.abs().max().double_value(&[]).max(1e-6);
        let diff = (&ours - &theirs).abs().max().double_value(&[]);
        eprintln!(
            "{} ({:?} decoder, {:?} radar, fusion {:?}): z {:?}, max |z| {scale:.3}, max |Δ| {diff:.2e}; {report}",
            cfg.name,
            cfg.decoder,
            cfg.radar_branch,
            cfg.fusion,
            ours.size()
        );
        assert!(
            diff <= 1e-4 * scale,
            "{}: head outputs differ by {diff} (max |z| {scale})",
            cfg.name
        );
        // Not a constant map: the comparison means something.
        assert!(ours.std(true).double_value(&[]) > 1e-3 * scale);
        assert_same_depth(&cfg, &net.decode(&ours), &d.join("depth.f32"));
    }
}

/// The deployment contract's depth (python/depthsense_torch.py `DepthSense`, image in [0, 1])
/// against `DepthNet::decode`: within 1 mm on ≥ 99.9 % of the pixels and within one SID bin
/// everywhere (a difference in the last bits of z may move a level where z_k ≈ 0).
fn assert_same_depth(cfg: &ModelConfig, ours: &Tensor, theirs: &Path) {
    let bytes = std::fs::read(theirs).unwrap();
    let theirs: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    let ours = Vec::<f32>::try_from(ours.flatten(0, -1)).unwrap();
    assert_eq!(ours.len(), theirs.len(), "{}: depth sizes", cfg.name);
    let sid = &cfg.sid;
    let bin = ((sid.beta_m / sid.alpha_m).ln() / sid.bins as f64).exp() - 1.0;
    let mut close = 0;
    for (&a, &b) in ours.iter().zip(&theirs) {
        let diff = (a as f64 - b as f64).abs();
        close += usize::from(diff <= 1e-3);
        let one_bin = (a.max(b) as f64 + sid.decode_offset_m) * bin * 1.01 + 1e-3;
        assert!(diff <= one_bin, "{}: depth {a} vs {b} m", cfg.name);
    }
    // Not a constant map: several levels (or metres) occur (the weights are random: 9 to 24
    // levels seen).
    let mut distinct: Vec<u32> = ours.iter().map(|x| x.to_bits()).collect();
    distinct.sort_unstable();
    distinct.dedup();
    assert!(
        distinct.len() >= 5,
        "{}: {} depth values",
        cfg.name,
        distinct.len()
    );
    let share = close as f64 / ours.len() as f64;
    eprintln!(
        "{}: {} depth values, within 1 mm on {:.4} % of the pixels",
        cfg.name,
        distinct.len(),
        100.0 * share
    );
    assert!(share >= 0.999, "{}: {share}", cfg.name);
}
