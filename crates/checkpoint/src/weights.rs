//! Importing PyTorch weights: torchvision ImageNet ResNets into the RGB encoder (SPEC §8) and
//! the authors' released checkpoint into the `released` preset (SPEC §6.1).

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::fmt;
use std::path::Path;

use tch::{nn::VarStore, Tensor};

use crate::files::require_file;
use crate::host::{parse_safetensors, read_torch_file};
use depthsense_model::{ModelError, ShapeMismatch};

/// What an import did. `Display` prints a short summary (counts per module, the partly loaded
/// tensors and the modules left random); `Debug` lists every name.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LoadReport {
    /// Network variables overwritten from the file.
    pub loaded: Vec<String>,
    /// Network variables filled partly, with how: the input channels both have are copied
    /// (an early-fusion `conv1`'s radar channels, or the 128-input `layer1.0` convs of a
    /// deep-stem network filled from a 64-channel torchvision stem), the rest zeroed.
    pub partial: Vec<(String, String)>,
    /// File tensors deliberately not used (torchvision `fc.*`, a stem the network does not
    /// have, `num_batches_tracked`), with the reason.
    pub skipped: Vec<(String, String)>,
    /// File tensors with no counterpart in the network.
    pub unused: Vec<String>,
    /// Network variables left at their random initialisation.
    pub left_random: Vec<String>,
}

/// Report group of a variable: `rgb.layer1`, `rgb.stem` (conv1..4 / bn1..4), `decoder.fpn`…
fn group_of(name: &str) -> String {
    let parts: Vec<&str> = name.split('.').collect();
    if parts.len() == 3
        && (parts[0] == "rgb" || parts[0] == "radar")
        && (parts[1].starts_with("conv") || parts[1].starts_with("bn"))
        && parts[1].ends_with(|c: char| c.is_ascii_digit())
    {
        return format!("{}.stem", parts[0]);
    }
    parts[..parts.len().min(2)].join(".")
}

/// Module of a variable (`rgb.bn2.running_mean` → `rgb.bn2`).
fn module_of(name: &str) -> &str {
    name.rsplit_once('.').map_or(name, |(m, _)| m)
}

/// `a, b, c` when at most `max` names, else `a, b, … (n in all)`.
fn short_list(names: &[&str], max: usize) -> String {
    if names.len() <= max {
        names.join(", ")
    } else {
        format!("{}, … ({} in all)", names[..max].join(", "), names.len())
    }
}

impl LoadReport {
    /// The `loaded:` line (counts per group) and one `partly loaded:` line per tensor.
    fn fmt_loaded(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut loaded: BTreeMap<String, usize> = BTreeMap::new();
        for k in &self.loaded {
            *loaded.entry(group_of(k)).or_default() += 1;
        }
        if !loaded.is_empty() {
            let parts: Vec<String> = loaded.iter().map(|(g, n)| format!("{g} {n}")).collect();
            writeln!(f, "  loaded: {}", parts.join(", "))?;
        }
        for (k, how) in &self.partial {
            writeln!(f, "  partly loaded: {k} ({how})")?;
        }
        Ok(())
    }

    /// The `left random:` lines.
    fn fmt_left_random(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Left random, one line per top-level part (rgb, decoder, radar, head): the modules
        // when few, else per group the modules or their count.
        let mut parts: BTreeMap<&str, BTreeMap<String, BTreeSet<&str>>> = BTreeMap::new();
        let mut tensors: BTreeMap<&str, usize> = BTreeMap::new();
        for k in &self.left_random {
            let top = k.split('.').next().unwrap_or_default();
            parts
                .entry(top)
                .or_default()
                .entry(group_of(k))
                .or_default()
                .insert(module_of(k));
            *tensors.entry(top).or_default() += 1;
        }
        for (top, groups) in &parts {
            let n_modules: usize = groups.values().map(BTreeSet::len).sum();
            let items: Vec<String> = if n_modules <= 8 {
                groups.values().flatten().map(|m| m.to_string()).collect()
            } else {
                groups
                    .iter()
                    .flat_map(|(g, ms)| {
                        if ms.len() <= 3 {
                            ms.iter().map(|m| m.to_string()).collect::<Vec<_>>()
                        } else {
                            vec![format!("{g}.* ({} modules)", ms.len())]
                        }
                    })
                    .collect()
            };
            writeln!(
                f,
                "  left random: {} ({} tensors)",
                items.join(", "),
                tensors[top]
            )?;
        }
        Ok(())
    }

    /// The `skipped (reason):` lines and the `unused file tensors:` line.
    fn fmt_skipped_unused(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut reasons: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
        for (k, why) in &self.skipped {
            reasons.entry(why).or_default().push(k);
        }
        for (why, keys) in reasons {
            writeln!(f, "  skipped ({why}): {}", short_list(&keys, 6))?;
        }
        if !self.unused.is_empty() {
            let u: Vec<&str> = self.unused.iter().map(String::as_str).collect();
            writeln!(f, "  unused file tensors: {}", short_list(&u, 10))?;
        }
        Ok(())
    }
}

impl fmt::Display for LoadReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "weights: {} tensors loaded, {} partly loaded, {} left random; file tensors: {} \
             skipped, {} unused",
            self.loaded.len(),
            self.partial.len(),
            self.left_random.len(),
            self.skipped.len(),
            self.unused.len()
        )?;
        self.fmt_loaded(f)?;
        self.fmt_left_random(f)?;
        self.fmt_skipped_unused(f)
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

/// May a file tensor of shape `fsz` fill a variable of shape `vsz` partly? Only 4-d conv
/// weights that differ in their input channels alone qualify, and only where the caller says
/// so (stem-dependent tensors).
fn input_channels_differ(vsz: &[i64], fsz: &[i64]) -> bool {
    vsz.len() == 4 && fsz.len() == 4 && vsz[0] == fsz[0] && vsz[2..] == fsz[2..] && vsz[1] != fsz[1]
}

/// File tensors matched to network variables, before anything is copied.
#[derive(Default)]
struct ImportPlan {
    /// The report so far: skipped and unused file tensors.
    report: LoadReport,
    /// Shape mismatches (reported all at once).
    mismatches: Vec<ShapeMismatch>,
    /// (variable, file tensor, partly).
    assignments: Vec<(String, Tensor, bool)>,
    /// Variables an assignment fills.
    done: BTreeSet<String>,
}

/// Matches every file tensor to a network variable of `vars` through `map` and `partial_ok`
/// (see [`import`]).
fn plan_import(
    vars: &HashMap<String, Tensor>,
    file: Vec<(String, Tensor)>,
    map: impl Fn(&str) -> Result<String, String>,
    partial_ok: impl Fn(&str, &[i64], &[i64]) -> bool,
) -> ImportPlan {
    let mut plan = ImportPlan::default();
    let report = &mut plan.report;
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
            plan.assignments.push((target.clone(), t, false));
        } else if input_channels_differ(&vsz, &fsz) && partial_ok(&target, &vsz, &fsz) {
            plan.assignments.push((target.clone(), t, true));
        } else {
            plan.mismatches.push(ShapeMismatch {
                name: format!("{target} (file: {key})"),
                expected: vsz,
                found: fsz,
            });
            continue;
        }
        plan.done.insert(target);
    }
    plan
}

/// Copies file tensor `src` into variable `name` (`var`), wholly or, when `partial`, the input
/// channels both have (the network's others zeroed); records it in `report`.
fn copy_into_var(
    name: &str,
    var: &Tensor,
    src: &Tensor,
    partial: bool,
    report: &mut LoadReport,
) -> Result<(), ModelError> {
    let mut var = var.shallow_clone();
    let src = src.to_kind(var.kind()).to_device(var.device());
    if partial {
        let (cv, cf) = (var.size()[1], src.size()[1]);
        let c = cv.min(cf);
        let how = if cv > cf {
            let _ = var.f_zero_()?;
            format!(
                "file {:?} into network {:?}: input channels 0..{c} copied, \
                 {c}..{cv} zeroed",
                src.size(),
                var.size()
            )
        } else {
            format!(
                "file {:?} into network {:?}: the file's first {c} of {cf} input \
                 channels copied",
                src.size(),
                var.size()
            )
        };
        var.f_narrow(1, 0, c)?.f_copy_(&src.f_narrow(1, 0, c)?)?;
        report.partial.push((name.to_string(), how));
    } else {
        var.f_copy_(&src)?;
        report.loaded.push(name.to_string());
    }
    Ok(())
}

/// Copies mapped file tensors into `vs`. `map` turns a file key into a network variable name
/// (or a skip reason); `partial_ok(target, network shape, file shape)` allows a conv weight
/// whose input channels differ to be filled partly (common input channels copied, the
/// network's other input channels zeroed). Other shape mismatches are collected and reported
/// all at once.
fn import(
    path: &Path,
    vs: &VarStore,
    file: Vec<(String, Tensor)>,
    map: impl Fn(&str) -> Result<String, String>,
    partial_ok: impl Fn(&str, &[i64], &[i64]) -> bool,
) -> Result<LoadReport, ModelError> {
    let vars = vs.variables();
    let ImportPlan {
        mut report,
        mismatches,
        assignments,
        done,
    } = plan_import(&vars, file, map, partial_ok);
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
            copy_into_var(name, &vars[name], src, *partial, &mut report)?;
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

/// Stem of an ImageNet ResNet file or of the network's RGB encoder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stem {
    /// torchvision: `conv1` 7x7 3→64, `bn1`; layer1 starts from 64 channels.
    Torchvision,
    /// DORN deep stem: `conv1` 3→64 s2, `conv2` 64→64, `conv3` 64→128 (+ `bn1..bn3`);
    /// layer1 starts from 128 channels (SPEC §6.1).
    Deep,
}

/// Is `k` (wrappers stripped) a stem tensor (`conv1..3.*`, `bn1..3.*` at the top level)?
fn is_stem_key(k: &str) -> bool {
    ["conv1.", "conv2.", "conv3.", "bn1.", "bn2.", "bn3."]
        .iter()
        .any(|p| k.starts_with(p))
}

/// Loads an ImageNet ResNet state dict into the RGB encoder (`rgb.*`): a torchvision file
/// (`resnet18/34/50/101-*.pth`, stem `conv1` 7x7 + `bn1`) or a deep-stem file as DORN-style
/// code uses (`conv1`/`conv2`/`conv3` 3→64 s2, 64→64, 64→128 + `bn1..bn3`), zip or legacy
/// format; `module.` prefixes are removed, `fc.*` is skipped.
///
/// - Same stem in file and network: everything is loaded. With early fusion the RGB filters
///   of `conv1` are copied and the radar input channels zeroed (partly loaded).
/// - Torchvision file, deep-stem network (`released`, SPEC §6.1): the file's `conv1`/`bn1` are
///   skipped, as the authors' initialisation does, and the deep stem stays random.
///   `layer1.0.conv1` and `layer1.0.downsample.0` take 2w = 128 input channels in the network
///   but w = 64 in the file: they are loaded partly — the file's 64 input channels into the
///   first 64, the other 64 zeroed (as for early fusion's radar channels) — and named in the
///   report, never an error.
/// - Deep-stem file, torchvision-stem network: the file's stem is skipped, and those two
///   `layer1.0` convs get the file's first 64 of 128 input channels.
///
/// Any other shape mismatch is an error naming every offending tensor.
pub fn load_torchvision_resnet(vs: &mut VarStore, path: &Path) -> Result<LoadReport, ModelError> {
    let file = read_torch_file(path)?;
    // The deep stem has conv1..conv3 directly under `rgb.`; torchvision's has conv1 only.
    let net_stem = if vs.variables().contains_key("rgb.conv3.weight") {
        Stem::Deep
    } else {
        Stem::Torchvision
    };
    let file_stem = if file
        .iter()
        .any(|(k, _)| strip_wrappers(k) == "conv3.weight")
    {
        Stem::Deep
    } else {
        Stem::Torchvision
    };
    let same_stem = net_stem == file_stem;
    import(
        path,
        vs,
        file,
        |key| {
            let k = strip_wrappers(key);
            if k.starts_with("fc.") {
                return Err("classifier".into());
            }
            if !same_stem && is_stem_key(k) {
                return Err(match file_stem {
                    Stem::Torchvision => {
                        "torchvision stem; this network has the deep stem (SPEC §6.1)".into()
                    }
                    Stem::Deep => "deep stem; this network has the torchvision stem".into(),
                });
            }
            Ok(format!("rgb.{k}"))
        },
        |target, vsz, fsz| match target {
            // Early fusion: ImageNet filters for the RGB channels, zeros for the radar ones.
            "rgb.conv1.weight" => same_stem && vsz[1] > fsz[1],
            // The first bottleneck's input width follows the stem (w vs 2w).
            "rgb.layer1.0.conv1.weight" | "rgb.layer1.0.downsample.0.weight" => !same_stem,
            _ => false,
        },
    )
}

/// Maps a key of the authors' released checkpoint (SPEC §6.1) to our variable name. The names
/// are those of their public `RVMDE` module (MI-Hussain/RVMDE `model/rvmde.py`,
/// `model/radar_retinanet.py`): `retinanet.backbone.*` (image path, FPN and `convfeat*`),
/// `resnet_radar.backbone.*` (radar ResNet), `conv_radar.{0,2}.*` — the two 1x1 radar convs are
/// an attribute of the top-level network, not of the radar backbone (a nested
/// `resnet_radar.backbone.conv_radar.*` is accepted too) — and `concat_process.{1,4}.*`.
pub fn released_key(key: &str) -> Option<String> {
    let k = strip_wrappers(key);
    if let Some(r) = k.strip_prefix("conv_radar.") {
        return Some(format!("radar.conv_radar.{r}"));
    }
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

/// Fine-tuning (`train --init-from`): copies into `vs` the tensors of `path` that belong to the
/// network — a depthsense checkpoint (safetensors), a state dict under depthsense's names
/// (`export --format pytorch`) or the authors' released `.pth` (its keys mapped with
/// [`released_key`]). Network variables the file lacks keep their initialisation (the report's
/// `left random`: the new parts); file tensors the network lacks are reported unused. The
/// first conv of the RGB encoder or the radar branch may differ in its input channels (early
/// fusion, another radar input): the channels both have are copied. Any other shape mismatch is
/// an error naming every offending tensor.
pub fn init_from(vs: &mut VarStore, path: &Path) -> Result<LoadReport, ModelError> {
    let path = &require_file(
        path,
        "--init-from takes a depthsense checkpoint (RUN/best.safetensors), an `export --format \
         pytorch` .pth or the authors' released .pth",
    )?;
    let file = if depthsense_weights::torch_file::is_torch_file(path)? {
        read_torch_file(path)?
    } else {
        let bytes = std::fs::read(path).map_err(|e| ModelError::io(path, e))?;
        parse_safetensors(path, &bytes)?.0
    };
    let ours: std::collections::HashSet<String> = vs.variables().into_keys().collect();
    import(
        path,
        vs,
        file,
        |key| {
            let k = strip_wrappers(key);
            if ours.contains(k) {
                return Ok(k.to_string());
            }
            released_key(key).ok_or_else(|| "not a variable of this network".into())
        },
        |target, _, _| matches!(target, "rgb.conv1.weight" | "radar.conv1.weight"),
    )
    .map_err(|e| match e {
        ModelError::ShapeMismatch { path, mismatches } => ModelError::Format {
            msg: format!(
                "{} tensor(s) differ in shape from this network:{}\n--init-from copies the \
                 tensors of the same name and shape: build the network the file holds (for a \
                 depthsense checkpoint, --config {}) and add only --set options that add \
                 tensors (attention=on, radar-skip changes the head: not one of them)",
                mismatches.len(),
                mismatches
                    .iter()
                    .map(|m| format!(
                        "\n  {}: network {:?}, file {:?}",
                        m.name, m.expected, m.found
                    ))
                    .collect::<String>(),
                path.display()
            ),
            path,
        },
        other => other,
    })
}

/// Loads the authors' released PyTorch checkpoint (a state dict, `{"state_dict": …}` or a
/// pickled module; `module.` prefixes removed) into a network built with the `released`
/// preset — or any PyTorch state dict under depthsense's own variable names (what
/// `export --format pytorch` writes) into the network of its config. Every network variable must be covered; missing and mismatching tensors are all
/// named in the error.
pub fn load_released_checkpoint(vs: &mut VarStore, path: &Path) -> Result<LoadReport, ModelError> {
    let file = read_torch_file(path)?;
    // depthsense's own names are accepted as well: `export --format pytorch` writes
    // `{"config", "state_dict": {rgb.…, decoder.…, radar.…, head.…}}` (python/depthsense_torch.py).
    let ours: std::collections::HashSet<String> = vs.variables().into_keys().collect();
    let report = import(
        path,
        vs,
        file,
        |key| {
            released_key(key)
                .or_else(|| {
                    let k = strip_wrappers(key);
                    ours.contains(k).then(|| k.to_string())
                })
                .ok_or_else(|| "not part of the released network".into())
        },
        |_, _, _| false,
    )?;
    let missing: Vec<String> = report.left_random.clone();
    if !missing.is_empty() {
        return Err(ModelError::MissingTensors {
            path: path.to_path_buf(),
            names: missing,
        });
    }
    Ok(report)
}
