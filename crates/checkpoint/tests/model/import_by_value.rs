//! Weight import by value (issue 23): the state dict is written by PyTorch from a module tree
//! with the peers' attribute names — torchvision's ResNet (`torchvision_reference.py`) and the
//! authors' RVMDE (`released_reference.py`, `"fill": "distinct"`) — and every tensor j holds
//! j + 1 + (i mod 4096)/8192 at flat index i. Each of our variables must then hold exactly the
//! values of the source tensor that the peers' layout names for it: a swap of two same-shaped
//! tensors, a transposed copy or a wrong prefix fails.
//!
//! The expected source of each variable is written here from the peers' module trees (their
//! key = our name without the `rgb.` prefix for torchvision; `retinanet.backbone.*`,
//! `resnet_radar.backbone.*`, top-level `conv_radar.*` and `concat_process.{1,4}.*` for the
//! authors'), not taken from `weights::released_key`.

use crate::support::reference;

use std::collections::BTreeMap;
use std::path::Path;

use depthsense_checkpoint::weights;
use depthsense_config::{Fusion, ModelConfig};
use depthsense_model::DepthNet;
use tch::{nn, Device, Kind, Tensor};

/// Source key → (j, shape).
type Keys = BTreeMap<String, (usize, Vec<i64>)>;

/// `keys.json`: the state dict's (key, shape) in PyTorch's order; the index is j.
fn source_keys(dir: &Path) -> Keys {
    let v: Vec<(String, Vec<i64>)> =
        serde_json::from_slice(&std::fs::read(dir.join("keys.json")).unwrap()).unwrap();
    v.into_iter()
        .enumerate()
        .map(|(j, (k, s))| (k, (j, s)))
        .collect()
}

/// The values the scripts write into state-dict entry `j`.
fn filled(j: usize, shape: &[i64]) -> Tensor {
    let n: i64 = shape.iter().product();
    let i = Tensor::arange(n, (Kind::Double, Device::Cpu));
    (i.remainder(4096) / 8192.0 + (j + 1) as f64)
        .to_kind(Kind::Float)
        .view(shape)
}

fn net(cfg: &ModelConfig) -> nn::VarStore {
    let vs = nn::VarStore::new(Device::Cpu);
    DepthNet::new(&vs.root(), cfg).unwrap();
    vs
}

/// Every variable `our name → source key` must equal the source tensor exactly; returns the
/// source keys used (each at most once).
fn assert_by_value(
    vs: &nn::VarStore,
    keys: &Keys,
    source_of: impl Fn(&str) -> Option<String>,
) -> Vec<String> {
    let mut used = Vec::new();
    for (name, var) in vs.variables() {
        let Some(key) = source_of(&name) else {
            continue;
        };
        let (j, shape) = keys
            .get(&key)
            .unwrap_or_else(|| panic!("{name}: the source has no {key}"));
        assert_eq!(var.size(), *shape, "{name} ← {key}: shape");
        assert!(
            var.equal(&filled(*j, shape)),
            "{name} does not hold {key} (entry {j}): first values {:?}",
            Vec::<f32>::try_from(var.flatten(0, -1).narrow(0, 0, var.numel().min(4) as i64))
                .unwrap()
        );
        used.push(key);
    }
    let n = used.len();
    used.sort();
    used.dedup();
    assert_eq!(used.len(), n, "a source tensor fills two variables");
    used
}

fn torchvision_file(depth: u32, width: i64) -> Option<(tempfile::TempDir, Keys)> {
    let dir = tempfile::tempdir().unwrap();
    reference::run_torchvision(
        dir.path(),
        &serde_json::json!({"depth": depth, "width": width}),
    )?;
    let keys = source_keys(dir.path());
    Some((dir, keys))
}

fn narrow(cfg: ModelConfig, extra: &[&str]) -> ModelConfig {
    cfg.with_options(&[
        "width=8",
        "decoder-channels=16",
        "head-channels=16",
        "radar-width=8",
    ])
    .unwrap()
    .with_options(extra)
    .unwrap()
}

/// torchvision → the paper's RGB encoder (torchvision stem): ResNet-18 (basic blocks) and
/// ResNet-50 (bottlenecks). Every `rgb.*` variable holds the file's tensor of the same key
/// without `rgb.`; every file tensor but `fc.*` and the BN counters is used.
#[test]
fn torchvision_resnets_load_tensor_for_tensor() {
    for (depth, cfg) in [
        (18, narrow(ModelConfig::paper(), &["backbone=18"])),
        (50, narrow(ModelConfig::paper(), &["backbone=50"])),
    ] {
        let Some((dir, keys)) = torchvision_file(depth, 8) else {
            return;
        };
        let mut vs = net(&cfg);
        let report =
            weights::load_torchvision_resnet(&mut vs, &dir.path().join("weights.pth")).unwrap();
        assert!(report.partial.is_empty(), "{report}");
        let used = assert_by_value(&vs, &keys, |n| n.strip_prefix("rgb.").map(str::to_string));
        let expected: Vec<&String> = keys
            .keys()
            .filter(|k| !k.starts_with("fc.") && !k.ends_with("num_batches_tracked"))
            .collect();
        assert_eq!(
            used.len(),
            expected.len(),
            "ResNet-{depth}: file tensors left unused"
        );
    }
}

/// Early fusion: the RGB filters of `conv1` come from the file, the radar input channels are
/// zero. The deep-stem network (`released`): the file's torchvision stem is not used (the deep
/// stem keeps its own values) and the first bottleneck's two convs take the file's w input
/// channels into their first w of 2w, the rest zero (SPEC §6.1).
#[test]
fn partial_loads_copy_the_right_channels() {
    let Some((dir, keys)) = torchvision_file(18, 8) else {
        return;
    };
    let file = dir.path().join("weights.pth");
    let early = narrow(ModelConfig::paper(), &["backbone=18"]);
    let early = ModelConfig {
        fusion: Fusion::Early,
        ..early
    };
    let mut vs = net(&early);
    weights::load_torchvision_resnet(&mut vs, &file).unwrap();
    let w = &vs.variables()["rgb.conv1.weight"];
    let (j, shape) = &keys["conv1.weight"];
    assert!(w.narrow(1, 0, 3).equal(&filled(*j, shape)));
    assert_eq!(
        w.narrow(1, 3, w.size()[1] - 3)
            .abs()
            .sum(Kind::Double)
            .double_value(&[]),
        0.0
    );
    assert_by_value(&vs, &keys, |n| {
        (n.starts_with("rgb.") && n != "rgb.conv1.weight").then(|| n["rgb.".len()..].to_string())
    });

    let Some((dir101, keys101)) = torchvision_file(101, 8) else {
        return;
    };
    let mut released = ModelConfig::released();
    released.backbone_width = 8;
    let mut vs = net(&released);
    let before = vs.variables()["rgb.conv1.weight"].copy();
    weights::load_torchvision_resnet(&mut vs, &dir101.path().join("weights.pth")).unwrap();
    let vars = vs.variables();
    assert!(
        vars["rgb.conv1.weight"].equal(&before),
        "the deep stem was overwritten"
    );
    for name in ["layer1.0.conv1.weight", "layer1.0.downsample.0.weight"] {
        let v = &vars[&format!("rgb.{name}")];
        let (j, shape) = &keys101[name];
        assert_eq!(v.size()[1], 2 * shape[1], "{name}: 2w input channels");
        assert!(v.narrow(1, 0, shape[1]).equal(&filled(*j, shape)), "{name}");
        assert_eq!(
            v.narrow(1, shape[1], shape[1])
                .abs()
                .sum(Kind::Double)
                .double_value(&[]),
            0.0
        );
    }
    let stem = [
        "rgb.conv1.",
        "rgb.bn1.",
        "rgb.conv2.",
        "rgb.bn2.",
        "rgb.conv3.",
        "rgb.bn3.",
    ];
    assert_by_value(&vs, &keys101, |n| {
        let partial = n == "rgb.layer1.0.conv1.weight" || n == "rgb.layer1.0.downsample.0.weight";
        let stem = stem.iter().any(|p| n.starts_with(p));
        (n.starts_with("rgb.") && !partial && !stem).then(|| n["rgb.".len()..].to_string())
    });
}

/// The authors' RVMDE names (MI-Hussain/RVMDE `model/rvmde.py`, `model/radar_retinanet.py`) for
/// our variable: the image path and FPN under `retinanet.backbone`, the radar ResNet under
/// `resnet_radar.backbone`, the two 1x1 radar convs on the top level (`conv_radar.0/2`), the
/// head = `concat_process` = Sequential(Dropout2d, Conv 1x1, ReLU, Dropout2d, Conv 1x1).
fn authors_key(ours: &str) -> String {
    let (module, rest) = ours.split_once('.').unwrap();
    match module {
        "rgb" | "decoder" => format!("retinanet.backbone.{rest}"),
        "radar" => match rest.strip_prefix("conv_radar.") {
            Some(r) => format!("conv_radar.{r}"),
            None => format!("resnet_radar.backbone.{rest}"),
        },
        "head" => {
            let (conv, param) = rest.split_once('.').unwrap();
            let index = match conv {
                "conv1" => 1,
                "conv2" => 4,
                other => panic!("head.{other}: not in concat_process"),
            };
            format!("concat_process.{index}.{param}")
        }
        other => panic!("{ours}: module {other} is not in the released network"),
    }
}

#[test]
fn the_authors_checkpoint_loads_tensor_for_tensor() {
    let mut cfg = ModelConfig::released();
    cfg.backbone_width = 8;
    cfg.radar_width = 8;
    cfg.decoder_channels = 16;
    cfg.head_channels = 16;
    cfg.radar_out_channels = 16;
    let dir = tempfile::tempdir().unwrap();
    let params = serde_json::json!({
        "fill": "distinct",
        "seed": 7,
        "width": cfg.backbone_width,
        "blocks": [3, 4, 23, 3],
        "decoder_channels": cfg.decoder_channels,
        "radar_width": cfg.radar_width,
        "radar_channels": cfg.radar_channels,
        "radar_out_channels": cfg.radar_out_channels,
        "head_channels": cfg.head_channels,
        "bins": cfg.sid.bins,
        "height": 64,
        "width_px": 128,
        "bn_spread": 0.3,
        "head_gain": 1.0,
    });
    let Some(_) = reference::run_reference(dir.path(), &params) else {
        return;
    };
    let keys = source_keys(dir.path());
    let mut vs = net(&cfg);
    let report =
        weights::load_released_checkpoint(&mut vs, &dir.path().join("weights.pth")).unwrap();
    assert!(
        report.partial.is_empty() && report.left_random.is_empty(),
        "{report}"
    );
    let used = assert_by_value(&vs, &keys, |n| Some(authors_key(n)));
    assert_eq!(used.len(), vs.variables().len());
    let unused: Vec<&String> = keys
        .keys()
        .filter(|k| !k.ends_with("num_batches_tracked") && !used.contains(k))
        .collect();
    assert!(
        unused.is_empty(),
        "the authors' tensors left unused: {unused:?}"
    );
}
