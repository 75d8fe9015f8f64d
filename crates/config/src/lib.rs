//! The network's configuration without libtorch (ARCHITECTURE.md, "config"): [`ModelConfig`]
//! and its enums (SPEC §6, §6.1, §7), and the two registries every command reads — so that
//! `train`, `model-info`, `eval`, `predict`, `export`, the experiments, the benches and their
//! `--help` texts accept exactly the same words:
//!
//! - [`presets`]: the named networks (`paper`, `released`, `tiny`, `tiny-wide`);
//! - [`options`]: every `--set KEY=VALUE` key, its aliases, the values it takes and what it
//!   sets;
//! - [`cli`]: the value parsers and help texts the command line builds from them;
//! - [`device`]: the words of `--device`; [`flags`]: those of the other network flags
//!   (precision, export format); [`variant`]: the ablation's network variants;
//! - [`training`]: the option groups of training (schedule, data loading, validation,
//!   checkpoints, device and precision, data-parallel), each defined once with its flags,
//!   ranges ([`ranges`]), help heading ([`heading`]) and defaults; the command line flattens
//!   them and the trainer holds them; [`mer_training`]: `mer train`'s own groups (its Adam
//!   schedule, its loading); [`refusal`]: what a training run refuses before it trains, in
//!   those groups' terms; [`words_parser`]: the value parser of every enum flag.
//!
//! The depthsense binary parses every command without libtorch, so these live here rather than
//! in `depthsense-model`, which builds the network from a [`ModelConfig`].

pub mod cli;
pub mod device;
pub mod flags;
pub mod heading;
pub mod mer_training;
mod model_config;
pub mod options;
pub mod pda;
pub mod presets;
pub mod ranges;
pub mod refusal;
pub mod training;
pub mod variant;
pub mod words_parser;

pub use model_config::{
    is_one, one, AttentionGate, DecoderKind, Fusion, HeadKind, ModelConfig, RadarBranchKind,
    RadarInput, SidConfig, StemKind,
};

/// A preset name or an option that no network can be built with.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    /// [`ModelConfig::preset`] got a name that is not in [`presets::PRESETS`].
    #[error(
        "unknown model preset `{0}` (presets: {known}; or the path of a model-config JSON, an \
         export sidecar or a depthsense checkpoint)",
        known = presets::names().join(", ")
    )]
    UnknownPreset(String),
    /// A field has a value the network cannot be built with, or an option is unknown.
    #[error("invalid model config: {0}")]
    Invalid(String),
    /// A radar input asked of a model whose radar channels differ
    /// ([`ModelConfig::radar_input_for`]).
    #[error(
        "radar input {} has {} channel(s) but the model expects radar_channels = {expected}",
        .input.name(),
        .input.channels()
    )]
    RadarChannels { input: RadarInput, expected: i64 },
    /// A word that names no ablation variant ([`variant::Variant`]).
    #[error(
        "unknown ablation variant {0:?} ({words})",
        words = <variant::Variant as depthsense_base::words::Words>::words().join(", ")
    )]
    UnknownVariant(String),
}
