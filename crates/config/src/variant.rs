//! The network variants of the ablation (SPEC §6 "Variants", §10.4): each sets the fusion, the
//! attention module and the head of a [`ModelConfig`]. Torch-free, so that the command line
//! refuses an unknown variant while it is parsed (`experiment ablation --variants`), and the
//! experiments (ablation, data-scale arms, cost) build their configs from it.

use depthsense_base::words::Words;
use serde::{Deserialize, Serialize};

use crate::{ConfigError, Fusion, HeadKind, ModelConfig, RadarInput};

/// A network variant: the three config fields it sets (SPEC §6 "Variants", §10.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Variant {
    /// RGB only (fusion none).
    Rgb,
    /// Early fusion: radar channels concatenated to the RGB input, one encoder.
    Early,
    /// Late fusion without the spatial attention module (the released model's form).
    Late,
    /// Late fusion with spatial attention (the paper's model), ordinal head.
    LateSam,
    /// The paper's model with an L1 depth head (loss ablation).
    L1,
    /// The paper's model with an L2 depth head (loss ablation).
    L2,
    /// The paper's model on MER radar (raw + 6 MER channels, SPEC §5; the prepared data needs
    /// `depthsense mer apply` first).
    LateSamMer,
}

impl Words for Variant {
    const WHAT: &'static str = "ablation variant";
    const WORDS: &'static [(&'static str, Self)] = &[
        ("rgb", Variant::Rgb),
        ("early", Variant::Early),
        ("late", Variant::Late),
        ("late-sam", Variant::LateSam),
        ("l1", Variant::L1),
        ("l2", Variant::L2),
        ("late-sam-mer", Variant::LateSamMer),
    ];
}

impl Variant {
    pub const ALL: [Variant; 7] = [
        Variant::Rgb,
        Variant::Early,
        Variant::Late,
        Variant::LateSam,
        Variant::L1,
        Variant::L2,
        Variant::LateSamMer,
    ];

    pub fn name(self) -> &'static str {
        Words::word(self)
    }

    /// (fusion, attention, head) of the variant.
    pub fn fields(self) -> (Fusion, bool, HeadKind) {
        match self {
            Variant::Rgb => (Fusion::None, false, HeadKind::Ordinal),
            Variant::Early => (Fusion::Early, false, HeadKind::Ordinal),
            Variant::Late => (Fusion::Late, false, HeadKind::Ordinal),
            Variant::LateSam => (Fusion::Late, true, HeadKind::Ordinal),
            Variant::L1 => (Fusion::Late, true, HeadKind::L1),
            Variant::L2 => (Fusion::Late, true, HeadKind::L2),
            Variant::LateSamMer => (Fusion::Late, true, HeadKind::Ordinal),
        }
    }

    /// Set the variant's fields on a config.
    pub fn apply(self, cfg: &mut ModelConfig) {
        let (fusion, attention, head) = self.fields();
        cfg.fusion = fusion;
        cfg.attention = attention;
        cfg.head = head;
        if self == Variant::LateSamMer {
            cfg.radar_input = RadarInput::Mer;
            cfg.radar_channels = cfg.radar_input.channels() as i64;
        }
        // Options of parts the variant does not have are reset to their defaults, so that a
        // `--set attention-gate=…` or `radar-skip=…` leaves e.g. the rgb runs' configs (and
        // the finished runs an `--out` already holds) unchanged.
        if !attention {
            cfg.attention_gate = Default::default();
        }
        if fusion != Fusion::Late {
            cfg.radar_skip_channels = 0;
        }
    }

    pub fn describe(self) -> &'static str {
        match self {
            Variant::Rgb => "RGB only (no radar)",
            Variant::Early => "early fusion (radar channels on the RGB input)",
            Variant::Late => "late fusion, no attention (released model's form)",
            Variant::LateSam => "late fusion + spatial attention (paper), ordinal head",
            Variant::L1 => "late-sam with an L1 depth head",
            Variant::L2 => "late-sam with an L2 depth head",
            Variant::LateSamMer => "late-sam on MER radar (raw + 6 MER channels)",
        }
    }
}

impl std::str::FromStr for Variant {
    type Err = ConfigError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::from_word(s).ok_or_else(|| ConfigError::UnknownVariant(s.trim().to_ascii_lowercase()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn variants_parse_and_set_their_fields() {
        depthsense_base::words::check_vocabulary::<Variant>().unwrap();
        for v in Variant::ALL {
            assert_eq!(v.name().parse::<Variant>().unwrap(), v);
        }
        assert_eq!(
            "sam".parse::<Variant>().unwrap_err().to_string(),
            "unknown ablation variant \"sam\" (rgb, early, late, late-sam, l1, l2, late-sam-mer)"
        );
        let mut c = ModelConfig::tiny();
        Variant::Rgb.apply(&mut c);
        assert_eq!((c.fusion, c.attention), (Fusion::None, false));
        Variant::L2.apply(&mut c);
        assert_eq!(
            (c.fusion, c.attention, c.head),
            (Fusion::Late, true, HeadKind::L2)
        );
        Variant::LateSamMer.apply(&mut c);
        assert_eq!((c.radar_input, c.radar_channels), (RadarInput::Mer, 7));
    }
}
