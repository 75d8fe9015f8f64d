//! Our own checkpoints: one safetensors file whose `__metadata__` holds the model config
//! (JSON) and free-form extra JSON (epoch, metrics…), written atomically.

use std::collections::BTreeMap;
use std::path::Path;

use tch::{nn::VarStore, Device, Kind, Tensor};

use crate::{DepthNet, ModelError, ShapeMismatch};
use depthsense_config::ModelConfig;

/// Named tensors and the string metadata of a safetensors file.
pub type Parsed = (Vec<(String, Tensor)>, BTreeMap<String, String>);

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

fn dtype_name(kind: Kind) -> Option<(&'static str, usize)> {
    Some(match kind {
        Kind::Float => ("F32", 4),
        Kind::Double => ("F64", 8),
        Kind::Half => ("F16", 2),
        Kind::BFloat16 => ("BF16", 2),
        Kind::Int64 => ("I64", 8),
        Kind::Int => ("I32", 4),
        Kind::Int16 => ("I16", 2),
        Kind::Int8 => ("I8", 1),
        Kind::Uint8 => ("U8", 1),
        Kind::Bool => ("BOOL", 1),
        _ => return None,
    })
}

fn kind_of(name: &str) -> Option<(Kind, usize)> {
    Some(match name {
        "F32" => (Kind::Float, 4),
        "F64" => (Kind::Double, 8),
        "F16" => (Kind::Half, 2),
        "BF16" => (Kind::BFloat16, 2),
        "I64" => (Kind::Int64, 8),
        "I32" => (Kind::Int, 4),
        "I16" => (Kind::Int16, 2),
        "I8" => (Kind::Int8, 1),
        "U8" => (Kind::Uint8, 1),
        "BOOL" => (Kind::Bool, 1),
        _ => return None,
    })
}

/// Serialises named tensors to safetensors bytes with string metadata.
pub fn safetensors_bytes(
    tensors: &[(String, Tensor)],
    metadata: &BTreeMap<String, String>,
) -> Result<Vec<u8>, ModelError> {
    let mut header = serde_json::Map::new();
    header.insert(
        "__metadata__".into(),
        serde_json::to_value(metadata).unwrap_or_default(),
    );
    let mut blobs = Vec::with_capacity(tensors.len());
    let mut offset = 0usize;
    let mut sorted: Vec<&(String, Tensor)> = tensors.iter().collect();
    sorted.sort_by(|a, b| a.0.cmp(&b.0));
    for (name, t) in sorted {
        let t = t.detach().to_device(Device::Cpu).contiguous();
        let (dt, es) = dtype_name(t.kind()).ok_or_else(|| {
            ModelError::InvalidConfig(format!(
                "tensor {name}: dtype {:?} cannot be saved",
                t.kind()
            ))
        })?;
        let numel = t.numel();
        let mut buf = vec![0u8; numel * es];
        t.f_copy_data_u8(&mut buf, numel)?;
        header.insert(
            name.clone(),
            serde_json::json!({"dtype": dt, "shape": t.size(), "data_offsets": [offset, offset + buf.len()]}),
        );
        offset += buf.len();
        blobs.push(buf);
    }
    let mut h = serde_json::to_vec(&serde_json::Value::Object(header)).unwrap_or_default();
    while !h.len().is_multiple_of(8) {
        h.push(b' ');
    }
    let mut out = Vec::with_capacity(8 + h.len() + offset);
    out.extend_from_slice(&(h.len() as u64).to_le_bytes());
    out.extend_from_slice(&h);
    for b in blobs {
        out.extend_from_slice(&b);
    }
    Ok(out)
}

/// The JSON header of safetensors `bytes` and the data section after it.
fn split_safetensors<'b>(
    path: &Path,
    bytes: &'b [u8],
) -> Result<(serde_json::Map<String, serde_json::Value>, &'b [u8]), ModelError> {
    let bad = |m: String| ModelError::format(path, m);
    if bytes.len() < 8 {
        return Err(bad(format!(
            "not a safetensors file ({} bytes)",
            bytes.len()
        )));
    }
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap_or([0; 8])) as usize;
    if n > bytes.len() - 8 || n > 100 << 20 {
        return Err(bad(format!(
            "not a safetensors file or truncated: header length {n} but the file has {} bytes",
            bytes.len()
        )));
    }
    let header: serde_json::Map<String, serde_json::Value> =
        serde_json::from_slice(&bytes[8..8 + n])
            .map_err(|e| bad(format!("not a safetensors file: header is not JSON ({e})")))?;
    Ok((header, &bytes[8 + n..]))
}

/// Tensor `name` of a safetensors header: its entry `v` checked against the `data` section.
fn safetensors_tensor(
    path: &Path,
    name: &str,
    v: &serde_json::Value,
    data: &[u8],
) -> Result<Tensor, ModelError> {
    let bad = |m: String| ModelError::format(path, m);
    let dtype = v.get("dtype").and_then(|d| d.as_str()).unwrap_or("");
    let (kind, es) =
        kind_of(dtype).ok_or_else(|| bad(format!("tensor {name}: unsupported dtype `{dtype}`")))?;
    // Every dimension must be a non-negative integer; the element count and byte length
    // are computed in checked arithmetic (issue 10: sizes come from the file).
    let shape: Vec<i64> = v
        .get("shape")
        .and_then(|s| s.as_array())
        .and_then(|a| {
            a.iter()
                .map(|x| x.as_i64().filter(|&d| d >= 0))
                .collect::<Option<Vec<i64>>>()
        })
        .ok_or_else(|| {
            bad(format!(
                "tensor {name}: no shape, or a dimension that is not a non-negative integer"
            ))
        })?;
    let offs: Vec<usize> = v
        .get("data_offsets")
        .and_then(|s| s.as_array())
        .map(|a| {
            a.iter()
                .filter_map(|x| x.as_u64().map(|u| u as usize))
                .collect()
        })
        .unwrap_or_default();
    if offs.len() != 2 || offs[0] > offs[1] {
        return Err(bad(format!("tensor {name}: bad data_offsets")));
    }
    let nbytes = shape
        .iter()
        .try_fold(es as u64, |a, &d| a.checked_mul(d as u64))
        .ok_or_else(|| bad(format!("tensor {name}: shape {shape:?} overflows")))?;
    if (offs[1] - offs[0]) as u64 != nbytes {
        return Err(bad(format!(
            "tensor {name}: {} bytes for shape {shape:?} {dtype}",
            offs[1] - offs[0]
        )));
    }
    if offs[1] > data.len() {
        return Err(bad(format!(
            "truncated: tensor {name} ends at byte {} of the data section but it holds only {} bytes",
            offs[1],
            data.len()
        )));
    }
    Ok(Tensor::f_from_data_size(
        &data[offs[0]..offs[1]],
        &shape,
        kind,
    )?)
}

/// Parses safetensors bytes: (tensors in file order of offsets, metadata). Every length and
/// offset is checked, so truncated or foreign files give a clear error.
pub fn parse_safetensors(path: &Path, bytes: &[u8]) -> Result<Parsed, ModelError> {
    let (header, data) = split_safetensors(path, bytes)?;
    let mut meta = BTreeMap::new();
    let mut out = Vec::new();
    for (name, v) in &header {
        if name == "__metadata__" {
            if let Some(m) = v.as_object() {
                for (k, v) in m {
                    meta.insert(k.clone(), v.as_str().unwrap_or_default().to_string());
                }
            }
            continue;
        }
        let t = safetensors_tensor(path, name, v, data)?;
        out.push((name.clone(), t));
    }
    Ok((out, meta))
}

/// Writes `bytes` to `path` atomically: the workspace's one atomic write
/// (`depthsense_base::fsutil::write_atomic`: temporary sibling, fsync, rename), with the
/// error as a [`ModelError`] naming `path`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), ModelError> {
    // The folder first, so that its failure names the folder (as before).
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| ModelError::io(dir, e))?;
    depthsense_base::fsutil::write_atomic(path, bytes).map_err(|e| ModelError::io(path, e))
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
    meta.insert(
        KEY_CONFIG.to_string(),
        serde_json::to_string(cfg).unwrap_or_default(),
    );
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

/// Reads only the config and extra JSON of a checkpoint.
pub fn read_config(path: &Path) -> Result<(ModelConfig, serde_json::Value), ModelError> {
    let bytes = std::fs::read(path).map_err(|e| ModelError::io(path, e))?;
    let (_, meta) = parse_safetensors(path, &bytes)?;
    config_of(path, &meta)
}

fn config_of(
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

/// `path` exists; otherwise an error that says what the flag takes (`what`) and lists the
/// checkpoints in the folder it names, if any.
pub fn require_file(path: &Path, what: &str) -> Result<(), ModelError> {
    if path.exists() {
        return Ok(());
    }
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let mut near: Vec<String> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.flatten()
                .map(|e| e.path())
                .filter(|p| {
                    p.extension()
                        .is_some_and(|x| x == "safetensors" || x == "pth" || x == "pt")
                })
                .map(|p| p.display().to_string())
                .collect()
        })
        .unwrap_or_default();
    near.sort();
    let beside = if near.is_empty() {
        String::new()
    } else {
        format!("; checkpoints in {}: {}", dir.display(), near.join(", "))
    };
    Err(ModelError::format(
        path,
        format!("no such file ({what}){beside}"),
    ))
}

/// Is `path` a `torch.save` file (zip or legacy pickle) rather than a safetensors file?
/// Decided by content: zip files start with `PK\x03\x04`, legacy `torch.save` pickles with
/// the protocol opcode 0x80; a safetensors file starts with its header length.
pub fn is_torch_file(path: &Path) -> Result<bool, ModelError> {
    use std::io::Read;
    let mut head = [0u8; 9];
    let mut f = std::fs::File::open(path).map_err(|e| ModelError::io(path, e))?;
    let len = f.metadata().map_err(|e| ModelError::io(path, e))?.len();
    let n = f.read(&mut head).map_err(|e| ModelError::io(path, e))?;
    // A safetensors file first: its header length (little-endian u64) may well start with the
    // byte 0x80 (a header of 128 + 256·k bytes), the legacy pickle's first opcode.
    let header_len = u64::from_le_bytes([
        head[0], head[1], head[2], head[3], head[4], head[5], head[6], head[7],
    ]);
    if n == 9 && head[8] == b'{' && header_len >= 2 && header_len <= len.saturating_sub(8) {
        return Ok(false);
    }
    let zip = n >= 4 && head[..4] == *b"PK\x03\x04";
    // PROTO 2..5: what torch.save's legacy format starts with.
    let legacy_pickle = n >= 2 && head[0] == 0x80 && (2..=5).contains(&head[1]);
    Ok(zip || legacy_pickle)
}

/// Loads a network for inference from either
/// - a depthsense checkpoint (safetensors, written by [`save`]): the network is built from the
///   stored config, or from `config` when given (every tensor must then match its shapes), or
/// - a PyTorch file (`torch.save` of a state dict, e.g. the authors' `paper_weights_rvmde.pth`;
///   zip or legacy format, `module.`/`state_dict.` wrappers removed): such a file carries no
///   architecture, so `config` is required (normally the `released` preset, SPEC §6.1). The
///   keys are mapped with [`crate::weights::released_key`] and must cover every variable.
///
/// The format is recognised by content ([`is_torch_file`]), not by extension. Returns the
/// network and, for a PyTorch file, the import report (the `extra` JSON records the source).
pub fn load_any(
    path: &Path,
    config: Option<&ModelConfig>,
    device: Device,
) -> Result<(Loaded, Option<crate::weights::LoadReport>), ModelError> {
    require_file(
        path,
        "--checkpoint takes RUN/best.safetensors or RUN/last.safetensors of `depthsense train`, \
         or a PyTorch .pth with --config",
    )?;
    if !is_torch_file(path)? {
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
