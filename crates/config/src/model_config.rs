//! Network configuration with named presets (SPEC §6, §6.1, §7).

use depthsense_base::words::Words;
use serde::{Deserialize, Serialize};

use crate::ConfigError;

/// How radar enters the network (SPEC §6 "Variants").
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[serde(rename_all = "lowercase")]
pub enum Fusion {
    /// Separate radar branch, features concatenated before the head (paper, released).
    Late,
    /// Radar channels concatenated to the RGB input of one encoder.
    Early,
    /// RGB only; the radar tensor is ignored.
    None,
}

/// Output head and its loss (SPEC §7 and the ablation of §10.4).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[serde(rename_all = "lowercase")]
pub enum HeadKind {
    /// DORN ordinal regression over SID bins (2K channels, pairs (a_k, b_k)).
    Ordinal,
    /// One channel, depth in metres, L1 loss.
    L1,
    /// One channel, depth in metres, L2 loss (scaled as e²/(2β): `depthsense_model::ordinal::RegressionLoss`).
    L2,
}

/// Stem of a ResNet encoder.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[serde(rename_all = "lowercase")]
pub enum StemKind {
    /// torchvision: 7x7/2 conv, BN, ReLU, 3x3/2 max-pool; layer1 input = width.
    Torchvision,
    /// DORN deep stem (SPEC §6.1 image path): 3x3/2 (→w), 3x3 (→w), 3x3 (→2w), 3x3/2 max-pool.
    Deep,
    /// The released radar stem (SPEC §6.1 radar path): 3x3/2, 3x3, 3x3, 7x7/2 (→2w), 7x7/4 max-pool.
    Radar,
}

/// Image decoder over C2..C4 (SPEC §6).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[serde(rename_all = "lowercase")]
pub enum DecoderKind {
    /// Paper: top-down pyramid, levels upsampled to stride 8 and concatenated (3·ch).
    Topdown,
    /// Released: FPN levels reduced to stride 32 by 7x7/4, 3x3/2, 3x3/1 convs (3·ch).
    Released,
}

/// Radar branch of late fusion (SPEC §6 / §6.1).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[serde(rename_all = "lowercase")]
pub enum RadarBranchKind {
    /// Paper: ResNet-18 basic blocks [2,2,2,2], torchvision stem, layer4 upsampled.
    Basic,
    /// Released: radar stem, bottlenecks [2,2,2,2] strides 1/2/1/1 dilations 1/1/2/4, then
    /// `conv_radar` 1x1 convs to `radar_out_channels`.
    Bottleneck,
}

/// The spatial attention module's gate on its logit s (SPEC §6, CBAM; the 7x7 conv starts at
/// zero, so s = 0 at initialisation and both gates start as the identity). The presets use
/// `Bounded`; a config without the field (checkpoints written before it existed) is `Double`.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[serde(rename_all = "lowercase")]
pub enum AttentionGate {
    /// f·2σ(s), range (0, 2): CBAM's σ(s) times 2 (the head's linear 1x1 conv absorbs the
    /// constant). Can close to 0 everywhere: measured, with MER input the module learns to
    /// close and the network collapses to the label marginal (docs/guide/mer.md).
    #[default]
    Double,
    /// f·(½ + σ(s)), range (½, 3⁄2): the same monotone gate shifted so that it can re-weight
    /// positions by up to 3× but never switch the features (and their gradients) off.
    Bounded,
}

impl Words for Fusion {
    const WHAT: &'static str = "fusion";
    /// `rgb` = `none` (RGB only).
    const WORDS: &'static [(&'static str, Self)] = &[
        ("late", Self::Late),
        ("early", Self::Early),
        ("none", Self::None),
        ("rgb", Self::None),
    ];
}

impl Words for HeadKind {
    const WHAT: &'static str = "head";
    const WORDS: &'static [(&'static str, Self)] = &[
        ("ordinal", Self::Ordinal),
        ("l1", Self::L1),
        ("l2", Self::L2),
    ];
}

impl Words for StemKind {
    const WHAT: &'static str = "stem";
    /// The stems an RGB encoder can take: `radar` (the radar branch's own) is not a setting.
    const WORDS: &'static [(&'static str, Self)] =
        &[("torchvision", Self::Torchvision), ("deep", Self::Deep)];
}

impl Words for DecoderKind {
    const WHAT: &'static str = "decoder";
    const WORDS: &'static [(&'static str, Self)] =
        &[("topdown", Self::Topdown), ("released", Self::Released)];
}

impl Words for RadarBranchKind {
    const WHAT: &'static str = "radar branch";
    const WORDS: &'static [(&'static str, Self)] =
        &[("basic", Self::Basic), ("bottleneck", Self::Bottleneck)];
}

impl Words for AttentionGate {
    const WHAT: &'static str = "attention gate";
    const WORDS: &'static [(&'static str, Self)] =
        &[("double", Self::Double), ("bounded", Self::Bounded)];
}

impl Words for RadarInput {
    const WHAT: &'static str = "radar input";
    const WORDS: &'static [(&'static str, Self)] = &[
        ("height", Self::Height),
        ("raw", Self::Raw),
        ("raw-height", Self::RawHeight),
        ("mer", Self::Mer),
    ];
}

/// Which prepared radar map(s) feed the radar channels (SPEC §5). Stored with the model so that
/// `eval` and `predict` feed a network the input it was trained on.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[serde(rename_all = "kebab-case")]
pub enum RadarInput {
    /// Height-extended strips (SPEC §5, the paper's default input): 1 channel.
    #[default]
    Height,
    /// One pixel per radar point (SPEC §5 raw): 1 channel.
    Raw,
    /// Raw then height-extended: 2 channels.
    RawHeight,
    /// MER (SPEC §5): raw, then the 6 channels d·[conf > θ], θ ∈ {0.5, 0.6, 0.7, 0.8, 0.9,
    /// 0.95}, derived when loading from `radar_mer_depth.png` / `radar_mer_conf.png`
    /// (`depthsense mer apply`): 7 channels.
    Mer,
}

impl RadarInput {
    /// Number of radar channels this input produces.
    pub fn channels(self) -> usize {
        match self {
            Self::Height | Self::Raw => 1,
            Self::RawHeight => 2,
            Self::Mer => 7,
        }
    }

    /// The input for a network with `c` radar channels (0/1 → height, 2 → raw + height).
    pub fn for_channels(c: i64) -> Result<Self, ConfigError> {
        match c {
            0 | 1 => Ok(Self::Height),
            2 => Ok(Self::RawHeight),
            7 => Ok(Self::Mer),
            other => Err(ConfigError::Invalid(format!(
                "no radar input has {other} channels (1 = height-extended or raw, \
                 2 = raw + height-extended, 7 = raw + 6 MER)"
            ))),
        }
    }

    /// The name used on the command line and in JSON ([`Words::word`]).
    pub fn name(self) -> &'static str {
        self.word()
    }
}

impl std::str::FromStr for RadarInput {
    type Err = ConfigError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::from_word(s).ok_or_else(|| {
            ConfigError::Invalid(format!(
                "unknown radar input {:?} ({})",
                s.trim().to_ascii_lowercase(),
                Self::words().join(", ")
            ))
        })
    }
}

/// Spacing-increasing discretisation (SPEC §7).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
pub struct SidConfig {
    /// K, the number of ordinal bins (80).
    pub bins: i64,
    /// α, the first threshold in metres (1).
    pub alpha_m: f64,
    /// β, the last threshold in metres (80).
    pub beta_m: f64,
    /// Subtracted from decoded depths (DORN-radar uses 0.3 m; 0 by default). SPEC §7.
    pub decode_offset_m: f64,
}

impl Default for SidConfig {
    fn default() -> Self {
        SidConfig {
            bins: 80,
            alpha_m: 1.0,
            beta_m: 80.0,
            decode_offset_m: 0.0,
        }
    }
}

/// The whole network description. Every variant is a field here (CONTRIBUTING).
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct ModelConfig {
    /// Preset this config started from (informational).
    pub name: String,
    /// RGB encoder depth: 18, 34, 50 or 101 (SPEC §6).
    pub backbone_depth: u32,
    /// Base width of the RGB encoder (64 = torchvision).
    pub backbone_width: i64,
    /// Stem of the RGB encoder.
    pub stem: StemKind,
    /// Image decoder.
    pub decoder: DecoderKind,
    /// Channels of each decoder level (256 in SPEC §6).
    pub decoder_channels: i64,
    /// Radar fusion.
    pub fusion: Fusion,
    /// CBAM spatial attention on the fused features (SPEC §6 "Fusion (paper)").
    pub attention: bool,
    /// The attention module's gate (presets: `bounded`; absent from the JSON when `double`,
    /// which configs written before the field existed therefore read back as).
    #[serde(default, skip_serializing_if = "is_default")]
    pub attention_gate: AttentionGate,
    /// Output head.
    pub head: HeadKind,
    /// Hidden channels of the head's first 1x1 conv.
    pub head_channels: i64,
    /// Dropout2d before the head's first 1x1 conv as well (released: yes; paper: no).
    pub head_pre_dropout: bool,
    /// Dropout2d probability in the head (0.5).
    pub dropout: f64,
    /// Radar input channels: 1 (height-extended or raw) or 7 (raw + 6 MER), SPEC §5.
    pub radar_channels: i64,
    /// Which prepared radar map(s) the radar channels carry (SPEC §5). Set by `train`, read by
    /// `eval` and `predict`. Absent in old checkpoints: height-extended.
    #[serde(default)]
    pub radar_input: RadarInput,
    /// Radar enters the network in metres as the authors' code feeds it (released), instead of
    /// scaled by 1/β (our default, SPEC §6). Absent in old checkpoints: false.
    #[serde(default)]
    pub radar_in_metres: bool,
    /// Clamp the 2K logits to [1e-8, 1e8] before the pairwise softmax — the peers' bug of
    /// SPEC §7, needed only to reproduce the authors' released weights (`released` preset).
    #[serde(default)]
    pub clamp_logits: bool,
    /// Radar branch architecture (late fusion).
    pub radar_branch: RadarBranchKind,
    /// Base width of the radar branch (64 in SPEC §6).
    pub radar_width: i64,
    /// Channels of the radar features entering fusion (released `conv_radar`: 512; for the
    /// basic branch this is fixed by the branch: 8·radar_width, and the field is ignored).
    pub radar_out_channels: i64,
    /// Ordinal discretisation and decoding.
    pub sid: SidConfig,
    /// align_corners of the bilinear upsampling of head outputs (released: true). SPEC §6.
    pub align_corners: bool,
    /// The network sees its inputs downscaled by this integer factor (image: s×s average; radar:
    /// nearest depth per s×s cell) and still decodes at `out_height`×`out_width`, where the loss
    /// and the metrics are computed. 1 = full resolution (paper); small CPU presets use 2.
    #[serde(default = "one")]
    pub input_downscale: i64,
    /// The radar map's own downscale factor before the radar branch (late fusion), when it
    /// differs from `input_downscale` (None = the same). The branch's stride-32 output is
    /// resized to the decoder's resolution anyway (SPEC §6), so `radar-downscale=1` with an
    /// image downscaled for the CPU keeps the paper's radar resolution (stride 32 of 800x350)
    /// instead of doubling the radar's cell size with the image's. Early fusion concatenates
    /// radar and image, so it needs the image's factor.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radar_downscale: Option<i64>,
    /// Late fusion only (ignored otherwise): channels of a high-resolution radar path (0 =
    /// none, the paper). The radar map is reduced to the head's resolution keeping the nearest
    /// return per cell (SPEC §5) and passed through two 3x3 convs + ReLU; the result is
    /// concatenated with the image and radar-branch features before the attention module. The paper's radar branch ends
    /// at stride 32, where one cell of the branch spans 32 columns and several depths; this
    /// path hands the head the radar depth at its own resolution (stride 8).
    #[serde(default, skip_serializing_if = "is_default")]
    pub radar_skip_channels: i64,
    /// Full-resolution output height (350, SPEC §3).
    pub out_height: i64,
    /// Full-resolution output width (800, SPEC §3).
    pub out_width: i64,
}

impl ModelConfig {
    /// The radar input this model is fed (None for RGB-only): `requested` when given (it must
    /// have the model's channel count), else the input it was trained on (SPEC §5). Training,
    /// evaluation, prediction and export all ask here, so what deployment feeds a model is
    /// what training fed it.
    pub fn radar_input_for(
        &self,
        requested: Option<RadarInput>,
    ) -> Result<Option<RadarInput>, crate::ConfigError> {
        if self.fusion == Fusion::None {
            return Ok(None);
        }
        let input = requested.unwrap_or(self.radar_input);
        if input.channels() as i64 != self.radar_channels {
            return Err(crate::ConfigError::RadarChannels {
                input,
                expected: self.radar_channels,
            });
        }
        Ok(Some(input))
    }

    /// The paper's network (SPEC §6): ResNet-101, top-down decoder over C2–C4, ResNet-18
    /// radar branch, late fusion with spatial attention, ordinal head K = 80.
    pub fn paper() -> Self {
        ModelConfig {
            name: "paper".into(),
            backbone_depth: 101,
            backbone_width: 64,
            stem: StemKind::Torchvision,
            decoder: DecoderKind::Topdown,
            decoder_channels: 256,
            fusion: Fusion::Late,
            attention: true,
            attention_gate: AttentionGate::Bounded,
            head: HeadKind::Ordinal,
            head_channels: 512,
            head_pre_dropout: false,
            dropout: 0.5,
            radar_channels: 1,
            radar_input: RadarInput::Height,
            radar_in_metres: false,
            clamp_logits: false,
            radar_branch: RadarBranchKind::Basic,
            radar_width: 64,
            radar_out_channels: 512,
            sid: SidConfig::default(),
            align_corners: true,
            input_downscale: 1,
            radar_downscale: None,
            radar_skip_channels: 0,
            out_height: 350,
            out_width: 800,
        }
    }

    /// The authors' released architecture, parameter for parameter (SPEC §6.1):
    /// 68,399,904 trainable parameters.
    pub fn released() -> Self {
        ModelConfig {
            name: "released".into(),
            backbone_depth: 101,
            backbone_width: 64,
            stem: StemKind::Deep,
            decoder: DecoderKind::Released,
            decoder_channels: 256,
            fusion: Fusion::Late,
            attention: false,
            attention_gate: AttentionGate::Double,
            head: HeadKind::Ordinal,
            head_channels: 2048,
            head_pre_dropout: true,
            dropout: 0.5,
            radar_channels: 1,
            // The authors' conventions (their code): radar in metres, clamped logits,
            // decoded depth = SID bin centre − 0.3 m (SPEC §7).
            radar_input: RadarInput::Height,
            radar_in_metres: true,
            clamp_logits: true,
            radar_branch: RadarBranchKind::Bottleneck,
            radar_width: 64,
            radar_out_channels: 512,
            sid: SidConfig {
                decode_offset_m: 0.3,
                ..SidConfig::default()
            },
            align_corners: true,
            input_downscale: 1,
            radar_downscale: None,
            radar_skip_channels: 0,
            out_height: 350,
            out_width: 800,
        }
    }

    /// A small network for tests and CPU demos: the paper's layout (ResNet-18 RGB encoder,
    /// top-down decoder, ResNet-18 radar branch, late fusion, attention, ordinal K = 80) at
    /// base width 16 (RGB) / 8 (radar) with 32-channel decoder and head: about 1 M parameters
    /// and 0.9 G multiply-adds per 350x800 image, so that a batch-4 training step at 350x800
    /// takes about a second on two CPU cores. `--set width=32 --set decoder-channels=64
    /// --set head-channels=64 --set radar-width=16` gives a 3.7 M-parameter variant.
    pub fn tiny() -> Self {
        ModelConfig {
            name: "tiny".into(),
            backbone_depth: 18,
            backbone_width: 16,
            decoder_channels: 32,
            head_channels: 32,
            radar_width: 8,
            radar_out_channels: 64,
            dropout: Self::dropout_for_head(32),
            ..Self::paper()
        }
    }

    /// `tiny` with a ResNet-34 encoder and doubled widths: the network of the GPU demo and of
    /// the experiments' wider runs (`experiment ablation --config tiny-wide`). Keeps `tiny`'s
    /// head dropout (the demo sets its own).
    pub fn tiny_wide() -> Self {
        let mut c = ModelConfig::tiny();
        c.name = "tiny-wide".into();
        c.backbone_depth = 34;
        c.backbone_width = 64;
        c.decoder_channels = 128;
        c.head_channels = 128;
        c.radar_width = 32;
        c.radar_out_channels = 256;
        c
    }

    /// Head Dropout2d probability scaled with the head's width: the paper's 0.5 at its 512+
    /// channels, p = 0.5·C/512 below. Dropout2d(0.5) on a 32-channel head zeroes 16 of 32
    /// feature maps of the whole image each step, and the tiny network then collapses to a
    /// constant depth even with the fixed initialisation (measured,
    /// ../shared/notes/training-init-evidence.md); at 0.5·32/512 ≈ 0.03 it drops about one
    /// map per image, the same *number* of maps relative to the paper's redundancy.
    pub fn dropout_for_head(head_channels: i64) -> f64 {
        0.5 * (head_channels as f64 / 512.0).clamp(0.0, 1.0)
    }

    /// Number of channels the head produces at low resolution (2K ordinal, 1 regression).
    pub fn head_out_channels(&self) -> i64 {
        match self.head {
            HeadKind::Ordinal => 2 * self.sid.bins,
            HeadKind::L1 | HeadKind::L2 => 1,
        }
    }

    /// Checks every field; the network constructor calls it.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |m: String| Err(ConfigError::Invalid(m));
        if ![18, 34, 50, 101].contains(&self.backbone_depth) {
            return bad(format!(
                "backbone_depth {} (expected 18, 34, 50 or 101)",
                self.backbone_depth
            ));
        }
        if self.backbone_width < 1 || self.decoder_channels < 1 || self.head_channels < 1 {
            return bad("backbone_width, decoder_channels and head_channels must be ≥ 1".into());
        }
        if self.stem == StemKind::Radar {
            return bad("stem `radar` is only used inside the released radar branch".into());
        }
        if self.fusion != Fusion::None && self.radar_channels < 1 {
            return bad(format!(
                "radar_channels {} with fusion {:?}",
                self.radar_channels, self.fusion
            ));
        }
        if self.fusion == Fusion::Late && (self.radar_width < 1 || self.radar_out_channels < 1) {
            return bad("radar_width and radar_out_channels must be ≥ 1".into());
        }
        if !(0.0..1.0).contains(&self.dropout) {
            return bad(format!("dropout {} (expected 0 ≤ p < 1)", self.dropout));
        }
        let s = &self.sid;
        let ordered = s.alpha_m > 0.0 && s.beta_m > s.alpha_m; // false for NaN too
        if s.bins < 1 || !ordered {
            return bad(format!("sid {s:?}: need bins ≥ 1 and 0 < alpha_m < beta_m"));
        }
        if !(1..=8).contains(&self.input_downscale) {
            return bad(format!(
                "input_downscale {} (expected 1..=8)",
                self.input_downscale
            ));
        }
        if let Some(r) = self.radar_downscale {
            if !(1..=8).contains(&r) {
                return bad(format!("radar_downscale {r} (expected 1..=8)"));
            }
            if self.fusion == Fusion::Early && r != self.input_downscale {
                return bad(format!(
                    "radar_downscale {r} with early fusion: radar and image are concatenated, \
                     so it must equal input_downscale {}",
                    self.input_downscale
                ));
            }
        }
        if !(0..=256).contains(&self.radar_skip_channels) {
            return bad(format!(
                "radar_skip_channels {} (expected 0..=256)",
                self.radar_skip_channels
            ));
        }
        if self.out_height < 1 || self.out_width < 1 {
            return bad("out_height and out_width must be ≥ 1".into());
        }
        Ok(())
    }
}

pub fn one() -> i64 {
    1
}

pub fn is_one(v: &i64) -> bool {
    *v == 1
}

/// serde `skip_serializing_if` for options at their default (configs written before the
/// option existed read back unchanged, and new configs that do not use it look the same).
fn is_default<T: Default + PartialEq>(v: &T) -> bool {
    *v == T::default()
}

#[cfg(test)]
mod radar_input_tests {
    use super::*;

    #[test]
    fn a_model_is_fed_the_radar_input_it_was_trained_on() {
        let mut cfg = ModelConfig::tiny();
        cfg.fusion = Fusion::None;
        assert_eq!(cfg.radar_input_for(Some(RadarInput::Raw)), Ok(None));
        cfg.fusion = Fusion::Late;
        assert_eq!(cfg.radar_input_for(None), Ok(Some(cfg.radar_input)));
        // a request with the model's channel count is honoured, another is refused naming both
        let same = RadarInput::Raw;
        assert_eq!(same.channels() as i64, cfg.radar_channels);
        assert_eq!(cfg.radar_input_for(Some(same)), Ok(Some(same)));
        let e = cfg
            .radar_input_for(Some(RadarInput::RawHeight))
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(
                "radar input raw-height has 2 channel(s) but the model expects radar_channels = {}",
                cfg.radar_channels
            )
        );
    }
}
