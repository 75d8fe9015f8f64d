//! The network's configuration (SPEC §6, §6.1, §7) lives in the torch-free `depthsense-config`
//! — its presets and `--set` keys are the one registry every command parses with — and is
//! reached there; [`resolve`] adds what needs this crate: reading a checkpoint's config.

use depthsense_config::{presets, ModelConfig};
use depthsense_model::ModelError;

/// Resolves `--config`: a preset name ([`presets::PRESETS`]), a JSON file holding a
/// `ModelConfig` (or an export sidecar, whose `model_config` it is), or a depthsense checkpoint
/// (`.safetensors`, its stored config).
pub fn resolve(spec: &str) -> Result<ModelConfig, ModelError> {
    let path = std::path::Path::new(spec);
    if !path.is_file() {
        if spec.contains('/') || spec.contains('.') {
            return Err(ModelError::format(
                path,
                format!(
                    "no such file; --config takes a preset ({}) or the path of a model-config \
                     JSON, an export sidecar or a depthsense checkpoint",
                    presets::names().join(", ")
                ),
            ));
        }
        return Ok(ModelConfig::preset(spec)?);
    }
    if path.extension().is_some_and(|e| e == "safetensors") {
        return Ok(crate::read_config(path)?.0);
    }
    let text = std::fs::read_to_string(path).map_err(|e| ModelError::io(path, e))?;
    let mut json: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| ModelError::format(path, format!("not a model config JSON: {e}")))?;
    // An export sidecar (FILE.json beside `export`'s FILE) holds the config as `model_config`.
    if let Some(inner) = json.get_mut("model_config") {
        json = inner.take();
    }
    let cfg: ModelConfig = serde_json::from_value(json)
        .map_err(|e| ModelError::format(path, format!("not a model config JSON: {e}")))?;
    cfg.validate()?;
    Ok(cfg)
}
