//! depthsense-checkpoint (layer 3, ARCHITECTURE.md): network weights on disk, on libtorch's
//! side of the torch-free byte formats of `depthsense-weights` — so that `depthsense-model`
//! holds the paper's boxes and no file I/O.
//!
//! - this module's root: our own checkpoints, one safetensors file whose `__metadata__` holds
//!   the model config (JSON) and free-form extra JSON (epoch, metrics…), written atomically,
//!   and the "load anything" entry ([`load_any`]);
//! - [`weights`]: torchvision / the authors' released weights into a network;
//! - [`host`]: the edge between `depthsense_weights::HostTensor` and `tch`;
//! - [`files`]: the atomic write and the missing-checkpoint advice;
//! - [`config`]: a model config from a preset, a JSON, a sidecar or a checkpoint;
//! - [`pda`]: the MER PDA network's checkpoints.

pub mod config;
pub mod files;
pub mod host;
pub mod pda;
pub mod weights;

use std::collections::BTreeMap;
use std::path::Path;

use tch::{nn::VarStore, Device, Tensor};

use crate::files::{require_file, write_atomic};
use crate::host::{parse_safetensors, safetensors_bytes};
use depthsense_config::ModelConfig;
use depthsense_model::{DepthNet, ModelError, ShapeMismatch};

/// Format tag stored in the metadata.
pub const FORMAT: &str = "depthsense-checkpoint-v1";
const KEY_FORMAT: &str = "format";
const KEY_CONFIG: &str = "depthsense.config";
const KEY_EXTRA: &str = "depthsense.extra";

/// A loaded checkpoint: the variables, the network built from the stored config, the config
/// and the extra JSON.
pub struct Loaded {
    /// Variables (on the requested device).
    pub vs: VarStore,
    /// The network, its variables in `vs`.
    pub net: DepthNet,
    /// The stored configuration.
    pub config: ModelConfig,
    /// The stored extra JSON (`null` when none).
    pub extra: serde_json::Value,
}

/// Saves every variable of `vs` (trainable and BN running statistics) with `cfg` and `extra`
/// as one safetensors file, atomically.
pub fn save(
    path: &Path,
    vs: &VarStore,
    cfg: &ModelConfig,
    extra: &serde_json::Value,
) -> Result<(), ModelError> {
    let tensors: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
    let mut meta = BTreeMap::new();
    meta.insert(KEY_FORMAT.to_string(), FORMAT.to_string());
    let config_json =
        serde_json::to_string(cfg).map_err(|source| ModelError::ConfigJson { source })?;
    meta.insert(KEY_CONFIG.to_string(), config_json);
    meta.insert(
        KEY_EXTRA.to_string(),
        serde_json::to_string(extra).unwrap_or_else(|_| "null".into()),
    );
    let bytes = safetensors_bytes(&tensors, &meta)?;
    write_atomic(path, &bytes)
}

impl std::fmt::Debug for Loaded {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Loaded")
            .field("config", &self.config)
            .field("extra", &self.extra)
            .finish_non_exhaustive()
    }
}

/// Reads only the config and extra JSON of a checkpoint: its header, not its tensors (a
/// `paper` checkpoint's 229 MB stay on disk).
pub fn read_config(path: &Path) -> Result<(ModelConfig, serde_json::Value), ModelError> {
    let path = &if path.is_dir() {
        require_file(path, "a depthsense checkpoint or run folder")?
    } else {
        path.to_path_buf()
    };
    let meta = depthsense_weights::safetensors::read_metadata(path)?;
    config_of(path, &meta)
}

/// The model config and extra JSON of a checkpoint's metadata, already read (the metadata of
/// `host::parse_safetensors` or `weights::safetensors::read_metadata`); `path` names the file.
pub fn config_of(
    path: &Path,
    meta: &BTreeMap<String, String>,
) -> Result<(ModelConfig, serde_json::Value), ModelError> {
    if meta.get(KEY_FORMAT).map(String::as_str) != Some(FORMAT) {
        return Err(ModelError::format(
            path,
            format!("safetensors file without the `{FORMAT}` tag: not a depthsense checkpoint"),
        ));
    }
    let cfg_s = meta
        .get(KEY_CONFIG)
        .ok_or_else(|| ModelError::format(path, "checkpoint has no model config"))?;
    let cfg: ModelConfig = serde_json::from_str(cfg_s)
        .map_err(|e| ModelError::format(path, format!("stored model config is invalid: {e}")))?;
    let extra = meta
        .get(KEY_EXTRA)
        .and_then(|s| serde_json::from_str(s).ok())
        .unwrap_or(serde_json::Value::Null);
    Ok((cfg, extra))
}

/// Copies named tensors into the variables of `vs`; every variable must be present with its
/// exact shape, otherwise the error lists every missing or mismatching tensor.
pub fn copy_into(
    path: &Path,
    vs: &VarStore,
    tensors: &[(String, Tensor)],
) -> Result<(), ModelError> {
    let src: BTreeMap<&str, &Tensor> = tensors.iter().map(|(n, t)| (n.as_str(), t)).collect();
    let mut vars: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
    vars.sort_by(|a, b| a.0.cmp(&b.0));
    let mut missing = Vec::new();
    let mut mismatches = Vec::new();
    for (name, var) in &vars {
        match src.get(name.as_str()) {
            None => missing.push(name.clone()),
            Some(t) if t.size() != var.size() => mismatches.push(ShapeMismatch {
                name: name.clone(),
                expected: var.size(),
                found: t.size(),
            }),
            Some(_) => {}
        }
    }
    if !mismatches.is_empty() {
        return Err(ModelError::ShapeMismatch {
            path: path.to_path_buf(),
            mismatches,
        });
    }
    if !missing.is_empty() {
        return Err(ModelError::MissingTensors {
            path: path.to_path_buf(),
            names: missing,
        });
    }
    tch::no_grad(|| -> Result<(), ModelError> {
        for (name, var) in &vars {
            let mut v = var.shallow_clone();
            v.f_copy_(
                &src[name.as_str()]
                    .to_kind(var.kind())
                    .to_device(var.device()),
            )?;
        }
        Ok(())
    })
}

/// Loads a checkpoint written by [`save`] onto `device`, building the network from the
/// stored config.
pub fn load(path: &Path, device: Device) -> Result<Loaded, ModelError> {
    let bytes = std::fs::read(path).map_err(|e| ModelError::io(path, e))?;
    let (tensors, meta) = parse_safetensors(path, &bytes)?;
    let (config, extra) = config_of(path, &meta)?;
    let vs = VarStore::new(device);
    let net = DepthNet::new(&vs.root(), &config)?;
    copy_into(path, &vs, &tensors)?;
    Ok(Loaded {
        vs,
        net,
        config,
        extra,
    })
}

/// Loads a network for inference from either
/// - a depthsense checkpoint (safetensors, written by [`save`]): the network is built from the
///   stored config, or from `config` when given (every tensor must then match its shapes), or
/// - a PyTorch file (`torch.save` of a state dict, e.g. the authors' `paper_weights_rvmde.pth`;
///   zip or legacy format, `module.`/`state_dict.` wrappers removed): such a file carries no
///   architecture, so `config` is required (normally the `released` preset, SPEC §6.1). The
///   keys are mapped with [`crate::weights::released_key`] and must cover every variable.
///
/// The format is recognised by content (`depthsense_weights::torch_file::is_torch_file`), not by extension. Returns the
/// network and, for a PyTorch file, the import report (the `extra` JSON records the source).
pub fn load_any(
    path: &Path,
    config: Option<&ModelConfig>,
    device: Device,
) -> Result<(Loaded, Option<crate::weights::LoadReport>), ModelError> {
    let path = &require_file(
        path,
        "--checkpoint takes RUN/best.safetensors or RUN/last.safetensors of `depthsense train`, \
         or a PyTorch .pth with --config",
    )?;
    if !depthsense_weights::torch_file::is_torch_file(path)? {
        let Some(cfg) = config else {
            return Ok((load(path, device)?, None));
        };
        let bytes = std::fs::read(path).map_err(|e| ModelError::io(path, e))?;
        let (tensors, meta) = parse_safetensors(path, &bytes)?;
        let (_, extra) = config_of(path, &meta)?;
        let vs = VarStore::new(device);
        let net = DepthNet::new(&vs.root(), cfg)?;
        copy_into(path, &vs, &tensors)?;
        let loaded = Loaded {
            vs,
            net,
            config: cfg.clone(),
            extra,
        };
        return Ok((loaded, None));
    }
    let cfg = config.ok_or_else(|| {
        ModelError::format(
            path,
            "a PyTorch state dict carries no architecture: name it with --config \
             (`released` for the authors' paper_weights_rvmde.pth, another preset, or a \
             model-config JSON)",
        )
    })?;
    let mut vs = VarStore::new(device);
    let net = DepthNet::new(&vs.root(), cfg)?;
    let report = crate::weights::load_released_checkpoint(&mut vs, path)?;
    let extra = serde_json::json!({
        "source": "pytorch state dict",
        "file": path.display().to_string(),
        "tensors_loaded": report.loaded.len(),
    });
    let loaded = Loaded {
        vs,
        net,
        config: cfg.clone(),
        extra,
    };
    Ok((loaded, Some(report)))
}
