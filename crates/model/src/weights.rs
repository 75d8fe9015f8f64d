//! Importing PyTorch weights: torchvision ImageNet ResNets into the RGB encoder (SPEC §8) and
//! the authors' released checkpoint into the `released` preset (SPEC §6.1).

use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::path::Path;

use tch::{nn::VarStore, Tensor};

use crate::{pickle, ModelError, ShapeMismatch};

/// What an import did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LoadReport {
    /// Network variables overwritten from the file.
    pub loaded: Vec<String>,
    /// Network variables filled partly (e.g. the first 3 input channels of an early-fusion
    /// `conv1`; the radar input channels are zeroed).
    pub partial: Vec<String>,
    /// File tensors deliberately not used (torchvision `fc.*`, the stem of a deep-stem
    /// network, `num_batches_tracked`), with the reason.
    pub skipped: Vec<(String, String)>,
    /// File tensors with no counterpart in the network.
    pub unused: Vec<String>,
    /// Network variables left at their random initialisation.
    pub left_random: Vec<String>,
}

impl fmt::Display for LoadReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "loaded {} tensors, partly loaded {}, skipped {}, unused {}, left random {}",
            self.loaded.len(),
            self.partial.len(),
            self.skipped.len(),
            self.unused.len(),
            self.left_random.len()
        )?;
        for p in &self.partial {
            writeln!(f, "  partly loaded: {p}")?;
        }
        for (k, why) in &self.skipped {
            writeln!(f, "  skipped: {k} ({why})")?;
        }
        for k in &self.unused {
            writeln!(f, "  unused file tensor: {k}")?;
        }
        // Group left-random variables by module for a readable report.
        let mut groups: BTreeMap<String, usize> = BTreeMap::new();
        for k in &self.left_random {
            let g = k.split('.').take(2).collect::<Vec<_>>().join(".");
            *groups.entry(g).or_default() += 1;
        }
        for (g, n) in groups {
            writeln!(f, "  left random: {g}.* ({n} tensors)")?;
        }
        Ok(())
    }
}

fn strip_wrappers(name: &str) -> &str {
    let mut n = name;
    loop {
        let before = n;
        for p in ["state_dict.", "model.", "module.", "net."] {
            if let Some(rest) = n.strip_prefix(p) {
                n = rest;
            }
        }
        if n == before {
            return n;
        }
    }
}

/// Copies mapped file tensors into `vs`. `map` turns a file key into a network variable name
/// (or a skip reason). Shape mismatches are collected and reported all at once.
fn import(
    path: &Path,
    vs: &VarStore,
    file: Vec<(String, Tensor)>,
    map: impl Fn(&str) -> Result<String, String>,
) -> Result<LoadReport, ModelError> {
    let vars = vs.variables();
    let mut report = LoadReport::default();
    let mut mismatches = Vec::new();
    let mut assignments: Vec<(String, Tensor, bool)> = Vec::new();
    let mut done = BTreeSet::new();
    for (key, t) in file {
        if key.ends_with("num_batches_tracked") {
            report.skipped.push((key, "BN batch counter".into()));
            continue;
        }
        let target = match map(&key) {
            Ok(t) => t,
            Err(why) => {
                report.skipped.push((key, why));
                continue;
            }
        };
        let Some(var) = vars.get(&target) else {
            report.unused.push(key);
            continue;
        };
        let (vsz, fsz) = (var.size(), t.size());
        if vsz == fsz {
            assignments.push((target.clone(), t, false));
        } else if target.ends_with("rgb.conv1.weight")
            && vsz.len() == 4
            && fsz.len() == 4
            && vsz[0] == fsz[0]
            && vsz[2..] == fsz[2..]
            && vsz[1] > fsz[1]
        {
            // Early fusion: ImageNet filters for the RGB channels, zeros for radar channels.
            assignments.push((target.clone(), t, true));
        } else {
            mismatches.push(ShapeMismatch {
                name: format!("{target} (file: {key})"),
                expected: vsz,
                found: fsz,
            });
            continue;
        }
        done.insert(target);
    }
    if !mismatches.is_empty() {
        return Err(ModelError::ShapeMismatch {
            path: path.to_path_buf(),
            mismatches,
        });
    }
    if assignments.is_empty() {
        return Err(ModelError::format(
            path,
            format!(
                "no tensor of the file matches the network ({} unused, {} skipped)",
                report.unused.len(),
                report.skipped.len()
            ),
        ));
    }
    tch::no_grad(|| -> Result<(), ModelError> {
        for (name, src, partial) in &assignments {
            let mut var = vars[name].shallow_clone();
            let src = src.to_kind(var.kind()).to_device(var.device());
            if *partial {
                let c = src.size()[1];
                let _ = var.f_zero_()?;
                var.f_narrow(1, 0, c)?.f_copy_(&src)?;
                report.partial.push(name.clone());
            } else {
                var.f_copy_(&src)?;
                report.loaded.push(name.clone());
            }
        }
        Ok(())
    })?;
    report.loaded.sort();
    let mut left: Vec<String> = vars
        .keys()
        .filter(|k| !done.contains(*k))
        .cloned()
        .collect();
    left.sort();
    report.left_random = left;
    Ok(report)
}

/// Loads a torchvision ResNet state dict (`resnet18/34/50/101-*.pth`, zip format) into the RGB
/// encoder (`rgb.*`). `fc.*` is skipped; with the deep stem (`released`), torchvision's
/// `conv1`/`bn1` are skipped as the authors' code does (SPEC §6.1); with early fusion the
/// RGB filters of `conv1` are copied and the radar filters zeroed. `module.` prefixes are
/// removed. Any other shape mismatch is an error naming every offending tensor.
pub fn load_torchvision_resnet(vs: &mut VarStore, path: &Path) -> Result<LoadReport, ModelError> {
    let file = pickle::read_torch_file(path)?;
    // The deep stem has conv1..conv3 directly under `rgb.`; torchvision's has conv1 only.
    let deep_stem = vs.variables().contains_key("rgb.conv3.weight");
    import(path, vs, file, |key| {
        let k = strip_wrappers(key);
        if k.starts_with("fc.") {
            return Err("classifier".into());
        }
        if deep_stem && (k.starts_with("conv1.") || k.starts_with("bn1.")) {
            return Err("torchvision stem; this network has the deep stem".into());
        }
        Ok(format!("rgb.{k}"))
    })
}

/// Maps a key of the authors' released checkpoint (SPEC §6.1) to our variable name.
pub fn released_key(key: &str) -> Option<String> {
    let k = strip_wrappers(key);
    if let Some(r) = k.strip_prefix("retinanet.backbone.") {
        if r.starts_with("fpn.") || r.starts_with("convfeat") {
            return Some(format!("decoder.{r}"));
        }
        return Some(format!("rgb.{r}"));
    }
    if let Some(r) = k
        .strip_prefix("resnet_radar.backbone.")
        .or_else(|| k.strip_prefix("resnet_radar."))
    {
        return Some(format!("radar.{r}"));
    }
    match k {
        "concat_process.1.weight" => Some("head.conv1.weight".into()),
        "concat_process.1.bias" => Some("head.conv1.bias".into()),
        "concat_process.4.weight" => Some("head.conv2.weight".into()),
        "concat_process.4.bias" => Some("head.conv2.bias".into()),
        _ => None,
    }
}

/// Loads the authors' released PyTorch checkpoint (a state dict, `{"state_dict": …}` or a
/// pickled module; `module.` prefixes removed) into a network built with the `released`
/// preset. Every network variable must be covered; missing and mismatching tensors are all
/// named in the error.
pub fn load_released_checkpoint(vs: &mut VarStore, path: &Path) -> Result<LoadReport, ModelError> {
    let file = pickle::read_torch_file(path)?;
    let report = import(path, vs, file, |key| {
        released_key(key).ok_or_else(|| "not part of the released network".into())
    })?;
    let missing: Vec<String> = report.left_random.clone();
    if !missing.is_empty() {
        return Err(ModelError::MissingTensors {
            path: path.to_path_buf(),
            names: missing,
        });
    }
    Ok(report)
}
