//! PDA checkpoints (`mer train`'s RUN/*.safetensors): one safetensors file whose metadata
//! holds the PDA config and the run's extra JSON, written atomically.

use std::collections::BTreeMap;
use std::path::Path;

use depthsense_config::pda::PdaConfig;
use depthsense_model::pda::PdaNet;
use depthsense_model::ModelError;
use tch::{nn, Device, Tensor};

use crate::copy_into;
use crate::files::{require_file, write_atomic};
use crate::host::{parse_safetensors, safetensors_bytes};

/// Format tag of a PDA checkpoint's metadata.
pub const FORMAT: &str = "depthsense-pda-v1";
const KEY_FORMAT: &str = "format";
const KEY_CONFIG: &str = "depthsense.pda_config";
const KEY_EXTRA: &str = "depthsense.extra";

/// A loaded PDA checkpoint.
pub struct LoadedPda {
    pub vs: nn::VarStore,
    pub net: PdaNet,
    pub config: PdaConfig,
    pub extra: serde_json::Value,
}

/// Saves every variable of `vs` with `cfg` and `extra`, atomically (one safetensors file).
pub fn save(
    path: &Path,
    vs: &nn::VarStore,
    cfg: &PdaConfig,
    extra: &serde_json::Value,
) -> Result<(), ModelError> {
    let tensors: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
    let mut meta = BTreeMap::new();
    meta.insert(KEY_FORMAT.to_string(), FORMAT.to_string());
    let cfg_s = serde_json::to_string(cfg).map_err(|source| ModelError::ConfigJson { source })?;
    meta.insert(KEY_CONFIG.to_string(), cfg_s);
    meta.insert(
        KEY_EXTRA.to_string(),
        serde_json::to_string(extra).unwrap_or_else(|_| "null".into()),
    );
    write_atomic(path, &safetensors_bytes(&tensors, &meta)?)
}

/// Loads a checkpoint written by [`save`], building the network from its stored config.
pub fn load(path: &Path, device: Device) -> Result<LoadedPda, ModelError> {
    let path = &require_file(
        path,
        "a PDA checkpoint is RUN/best.safetensors of `depthsense mer train`",
    )?;
    let bytes = std::fs::read(path).map_err(|e| ModelError::io(path, e))?;
    let (tensors, meta) = parse_safetensors(path, &bytes)?;
    if meta.get(KEY_FORMAT).map(String::as_str) != Some(FORMAT) {
        return Err(ModelError::format(
            path,
            format!(
                "not a PDA checkpoint (no `{FORMAT}` tag; `mer apply` needs the output of \
                 `depthsense mer train`)"
            ),
        ));
    }
    let cfg_s = meta
        .get(KEY_CONFIG)
        .ok_or_else(|| ModelError::format(path, "PDA checkpoint has no config"))?;
    let config: PdaConfig = serde_json::from_str(cfg_s)
        .map_err(|e| ModelError::format(path, format!("stored PDA config is invalid: {e}")))?;
    let extra = meta
        .get(KEY_EXTRA)
        .and_then(|s| serde_json::from_str(s).ok())
        .unwrap_or(serde_json::Value::Null);
    let vs = nn::VarStore::new(device);
    let net = PdaNet::new(&vs.root(), &config)?;
    copy_into(path, &vs, &tensors)?;
    Ok(LoadedPda {
        vs,
        net,
        config,
        extra,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use depthsense_model::pda::parameter_count;

    #[test]
    fn save_load_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("pda.safetensors");
        let vs = nn::VarStore::new(Device::Cpu);
        let net = PdaNet::new(&vs.root(), &PdaConfig::test()).unwrap();
        save(&p, &vs, net.config(), &serde_json::json!({"epoch": 1})).unwrap();
        let l = load(&p, Device::Cpu).unwrap();
        assert_eq!(l.config, PdaConfig::test());
        assert_eq!(l.extra["epoch"], 1);
        assert_eq!(parameter_count(&l.vs), parameter_count(&vs));
        let a = vs.variables();
        for (k, v) in l.vs.variables() {
            assert!(v.equal(&a[&k]), "{k}");
        }
    }
}
