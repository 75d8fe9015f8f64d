//! depthsense-export (layer 8, ARCHITECTURE.md): `depthsense export` — a trained network out of
//! depthsense as ONNX, TorchScript or a PyTorch state dict, with a sidecar JSON that says how to
//! feed it.
//!
//! Route: the network is loaded as `predict` loads it ([`depthsense_eval::evaluate::load_model`]:
//! a depthsense checkpoint, or a PyTorch `.pth` with `--config`), its variables and config are
//! handed to `python/depthsense_export.py` (embedded in the binary, run by a Python with torch),
//! which builds the same network in `python/depthsense_torch.py` — the module PyTorch users
//! fine-tune — traces it and writes the file (ONNX through torch.onnx, opset 17, checked with
//! `onnx.checker`). One PyTorch implementation serves all three formats, and tests compare each
//! with depthsense's own decode (crates/export/tests/export.rs).
//!
//! Nothing half-written: the file is written to a temporary sibling and renamed; the sidecar
//! (`FILE.json`) last, atomically. An existing `--out` (or its sidecar) is refused without
//! `force`.

pub mod ort_bench;
pub mod python;
pub mod sidecar;

use depthsense_config::flags::{ExportFormat as Format, ExportPrecision as Precision};
use std::path::{Path, PathBuf};

use depthsense_base::fsutil::{temp_sibling, write_atomic};
use depthsense_infer::NetError;

pub use sidecar::Sidecar;

/// The batch axis of the graph.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Batch {
    /// Any N (the default).
    Dynamic,
    /// Exactly N.
    Fixed(u32),
}

impl Batch {
    /// Parses `dynamic` or a positive number.
    pub fn parse(s: &str) -> Result<Self, ExportError> {
        match s.trim() {
            "dynamic" => Ok(Self::Dynamic),
            n => match n.parse::<u32>() {
                Ok(n) if n > 0 => Ok(Self::Fixed(n)),
                _ => Err(ExportError::BadBatch {
                    batch: n.to_string(),
                }),
            },
        }
    }

    /// The value of the Python exporter's `--batch`.
    pub fn arg(self) -> String {
        match self {
            Self::Dynamic => "dynamic".into(),
            Self::Fixed(n) => n.to_string(),
        }
    }
}

/// Everything `depthsense export` is told.
#[derive(Debug, Clone)]
pub struct ExportOptions {
    /// A depthsense checkpoint, or a PyTorch state dict with `config`.
    pub checkpoint: PathBuf,
    /// A preset name or a model-config JSON (required for a `.pth`).
    pub config: Option<String>,
    /// `key=value` config overrides.
    pub set: Vec<String>,
    pub format: Format,
    pub out: PathBuf,
    pub batch: Batch,
    pub precision: Precision,
    /// Replace an existing `out` (and its sidecar).
    pub force: bool,
    /// The Python that runs the conversion (None: [`python::find_python`]).
    pub python: Option<PathBuf>,
}

/// Why an export failed; every message names the file concerned.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The checkpoint or config could not be loaded (or do not fit together).
    #[error(transparent)]
    Load(#[from] NetError),

    // --- What `depthsense export` is told ---
    /// `--batch` (`batch`, as written) that is neither `dynamic` nor a positive number.
    #[error("--batch {batch}: a positive number or 'dynamic'")]
    BadBatch { batch: String },
    /// `--precision fp16` asked for a PyTorch state dict, which is stored in float32.
    #[error(
        "--precision fp16 applies to the onnx and torchscript graphs; a pytorch state dict is \
         stored in float32 (`.half()` it in PyTorch)"
    )]
    Fp16StateDict,
    /// An export of one target that produced no file.
    #[error("nothing was exported")]
    NothingExported,

    // --- The files handed to the Python exporter, and the sidecar ---
    /// The network's variables that cannot be written (`path`) for the Python exporter.
    #[error("{}: {source}", .path.display())]
    StageWeights {
        path: PathBuf,
        #[source]
        source: tch::TchError,
    },
    /// The network's config that cannot be written as JSON for the Python exporter.
    #[error("{source}")]
    StageConfig {
        #[source]
        source: serde_json::Error,
    },
    /// A sidecar whose record cannot be built or encoded (the record's error names the file).
    #[error("{source}")]
    Sidecar {
        #[source]
        source: depthsense_records::RecordError,
    },

    // --- Writing the files: the targets, the conversion in Python ---
    #[error("{}: exists (a file of an earlier export); --force replaces it", .path.display())]
    Exists { path: PathBuf },
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The conversion in Python failed; `detail` is its stderr's end.
    #[error("exporting {out} with {python}: {detail}")]
    Python {
        python: String,
        out: String,
        detail: String,
    },
}

impl ExportError {
    pub(crate) fn io(path: &Path, e: std::io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            source: e,
        }
    }
}

/// What was written.
#[derive(Debug, Clone)]
pub struct Exported {
    pub out: PathBuf,
    pub sidecar: PathBuf,
    pub info: Sidecar,
}

/// `FILE.json` beside `FILE`.
pub fn sidecar_path(out: &Path) -> PathBuf {
    let mut name = out.file_name().unwrap_or_default().to_os_string();
    name.push(".json");
    out.with_file_name(name)
}

/// Exports `opts.checkpoint` (see the module docs).
pub fn export(opts: &ExportOptions) -> Result<Exported, ExportError> {
    let mut done = export_many(opts, &[(opts.format, opts.out.clone())])?;
    done.pop().ok_or(ExportError::NothingExported)
}

/// Exports `opts.checkpoint` once into every `(format, file)` of `targets` — one load, one
/// Python, one trace for all graph formats — each with its sidecar; `opts.format` and
/// `opts.out` are ignored. Every file is checked before anything is written, and on a failure
/// none of the targets is left half-written.
pub fn export_many(
    opts: &ExportOptions,
    targets: &[(Format, PathBuf)],
) -> Result<Vec<Exported>, ExportError> {
    let per_target: Vec<ExportOptions> = targets
        .iter()
        .map(|(format, out)| ExportOptions {
            format: *format,
            out: out.clone(),
            ..opts.clone()
        })
        .collect();
    for o in &per_target {
        check_target(o)?;
    }
    let (loaded, _) = depthsense_eval::evaluate::load_model(
        &opts.checkpoint,
        opts.config.as_deref(),
        &opts.set,
        tch::Device::Cpu,
    )?;
    let infos = per_target
        .iter()
        .map(|o| {
            Sidecar::new(
                o,
                &loaded.config,
                depthsense_eval::predict::trained_radar_settings(&loaded.extra),
            )
        })
        .collect::<Result<Vec<_>, _>>()?;
    let work = tempfile::tempdir().map_err(|e| ExportError::io(&std::env::temp_dir(), e))?;
    let (weights, config) = stage_network(&loaded.vs, &loaded.config, work.path())?;
    let tmps = reserve_temps(&per_target)?;
    if let Err(e) = python::convert(opts, work.path(), &weights, &config, &tmps) {
        remove_temps(&tmps);
        return Err(name_targets(e, targets));
    }
    let mut done = vec![];
    for ((o, info), (_, tmp)) in per_target.into_iter().zip(infos).zip(&tmps) {
        done.push(finish_target(o, info, tmp, &tmps)?);
    }
    Ok(done)
}

/// Writes the network's variables (`weights.safetensors`) and config (`config.json`) into
/// `work`, the folder the Python exporter reads; returns (weights, config) paths.
fn stage_network(
    vs: &tch::nn::VarStore,
    cfg: &depthsense_config::ModelConfig,
    work: &Path,
) -> Result<(PathBuf, PathBuf), ExportError> {
    let weights = work.join("weights.safetensors");
    vs.save(&weights)
        .map_err(|source| ExportError::StageWeights {
            path: weights.clone(),
            source,
        })?;
    let config = work.join("config.json");
    let cfg_json =
        serde_json::to_string_pretty(cfg).map_err(|source| ExportError::StageConfig { source })?;
    std::fs::write(&config, cfg_json).map_err(|e| ExportError::io(&config, e))?;
    Ok((weights, config))
}

/// An empty temporary sibling of every target, in order. The temporary files go where the
/// results go: an unwritable folder fails here, naming it (and the siblings made are removed).
fn reserve_temps(per_target: &[ExportOptions]) -> Result<Vec<(Format, PathBuf)>, ExportError> {
    let mut tmps: Vec<(Format, PathBuf)> = vec![];
    for o in per_target {
        let tmp = temp_sibling(&o.out);
        if let Err(e) = std::fs::write(&tmp, b"") {
            remove_temps(&tmps);
            return Err(ExportError::io(&o.out, e));
        }
        tmps.push((o.format, tmp));
    }
    Ok(tmps)
}

/// Removes every temporary sibling of `tmps`, ignoring those already gone.
fn remove_temps(tmps: &[(Format, PathBuf)]) {
    for (_, t) in tmps {
        let _ = std::fs::remove_file(t);
    }
}

/// A failed conversion's error naming the files asked for, not their temporary siblings.
fn name_targets(e: ExportError, targets: &[(Format, PathBuf)]) -> ExportError {
    match e {
        ExportError::Python { python, detail, .. } => ExportError::Python {
            python,
            out: targets
                .iter()
                .map(|(_, p)| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
            detail,
        },
        e => e,
    }
}

/// Moves one converted temporary file `tmp` onto its target and writes its sidecar last; a
/// failed rename removes every temporary sibling of `tmps`.
fn finish_target(
    o: ExportOptions,
    info: Sidecar,
    tmp: &Path,
    tmps: &[(Format, PathBuf)],
) -> Result<Exported, ExportError> {
    depthsense_base::fsutil::sync_and_rename(tmp, &o.out).map_err(|e| {
        remove_temps(tmps);
        ExportError::io(&o.out, e)
    })?;
    let sidecar = sidecar_path(&o.out);
    let text = info
        .to_json(&sidecar)
        .map_err(|source| ExportError::Sidecar { source })?;
    write_atomic(&sidecar, text.as_bytes()).map_err(|e| ExportError::io(&sidecar, e))?;
    Ok(Exported {
        out: o.out,
        sidecar,
        info,
    })
}

/// A target that may be written: not there (or `--force`), a precision its format takes.
fn check_target(opts: &ExportOptions) -> Result<(), ExportError> {
    if !opts.force {
        for p in [&opts.out, &sidecar_path(&opts.out)] {
            if p.exists() {
                return Err(ExportError::Exists { path: p.clone() });
            }
        }
    }
    if opts.precision == Precision::Fp16 && opts.format == Format::PyTorch {
        return Err(ExportError::Fp16StateDict);
    }
    Ok(())
}
