//! The named networks: the one list that every command's `--config` (and `experiment cost
//! --configs`) accepts and that their `--help` texts print.

use crate::{ConfigError, ModelConfig};

/// One named network.
pub struct Preset {
    /// The name on the command line and in `ModelConfig::name`.
    pub name: &'static str,
    /// What it is, for help texts.
    pub about: &'static str,
    /// Builds it.
    pub build: fn() -> ModelConfig,
}

/// Every preset, in the order help texts list them.
pub const PRESETS: &[Preset] = &[
    Preset {
        name: "paper",
        about:
            "the paper's network: ResNet-101, top-down decoder, late fusion + attention (SPEC §6)",
        build: ModelConfig::paper,
    },
    Preset {
        name: "released",
        about: "the authors' released architecture, parameter for parameter (SPEC §6.1)",
        build: ModelConfig::released,
    },
    Preset {
        name: "tiny",
        about: "the paper's layout at width 16: ≈ 1 M parameters, for CPUs and tests",
        build: ModelConfig::tiny,
    },
    Preset {
        name: "tiny-wide",
        about: "tiny with a ResNet-34 encoder and 4x the widths (the GPU demo's network)",
        build: ModelConfig::tiny_wide,
    },
];

/// The preset names, in [`PRESETS`] order.
pub fn names() -> Vec<&'static str> {
    PRESETS.iter().map(|p| p.name).collect()
}

/// The preset called `name` (ASCII case and surrounding blanks ignored).
pub fn find(name: &str) -> Option<&'static Preset> {
    let n = name.trim().to_ascii_lowercase();
    PRESETS.iter().find(|p| p.name == n)
}

impl ModelConfig {
    /// A preset by name ([`PRESETS`]).
    pub fn preset(name: &str) -> Result<ModelConfig, ConfigError> {
        find(name)
            .map(|p| (p.build)())
            .ok_or_else(|| ConfigError::UnknownPreset(name.trim().to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_preset_builds_a_valid_config_under_its_own_name() {
        for p in PRESETS {
            let c = ModelConfig::preset(p.name).unwrap();
            assert_eq!(c.name, p.name);
            c.validate().unwrap();
        }
        assert_eq!(
            ModelConfig::preset(" Tiny-Wide ").unwrap().name,
            "tiny-wide"
        );
        let err = ModelConfig::preset("huge").unwrap_err().to_string();
        assert!(err.contains("`huge`") && err.contains("paper, released, tiny, tiny-wide"));
    }
}
