//! MER's association network's configuration without libtorch (SPEC §5): [`MerWindow`] and
//! [`PdaConfig`] with its presets (`paper`, `tiny`, `fast`, `test`). Here rather than in
//! `depthsense-model` (which builds [`PdaConfig`]'s network) so that the torch-free data layer
//! reads `mer.json` and the command line parses `--config` without libtorch.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// A PDA config that is unknown, unreadable or that no network can be built with (the same
/// messages as the model's config errors).
#[derive(Debug, thiserror::Error)]
pub enum PdaConfigError {
    /// Neither a preset nor a file.
    #[error(
        "invalid model config: unknown PDA preset `{0}` (paper, tiny, fast, test, or a PDA \
         config JSON file)"
    )]
    UnknownPreset(String),
    /// A field no PDA network can be built with: which one, and why.
    #[error("invalid model config: PDA: {0}")]
    Invalid(String),
    /// The config file cannot be read.
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The config file is not a PDA config's JSON.
    #[error("{}: not a PDA config JSON: {source}", .path.display())]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
}

/// The association window around a radar pixel, in grid pixels (SPEC §5: 2 left, 2 right,
/// 30 up, 5 down → 5 × 36 = 180 neighbours, the radar pixel itself included).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct MerWindow {
    pub left: i64,
    pub right: i64,
    pub up: i64,
    pub down: i64,
}

impl MerWindow {
    /// SPEC §5.
    pub const PAPER: MerWindow = MerWindow {
        left: 2,
        right: 2,
        up: 30,
        down: 5,
    };

    /// Number of neighbours (= logits per pixel).
    pub fn len(&self) -> usize {
        ((self.left + self.right + 1) * (self.up + self.down + 1)) as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Offsets (dx, dy) in channel order: k = (dy + up)·(left + right + 1) + (dx + left),
    /// dy from −up (above) to +down, dx from −left to +right.
    pub fn offsets(&self) -> Vec<(i64, i64)> {
        let mut out = Vec::with_capacity(self.len());
        for dy in -self.up..=self.down {
            for dx in -self.left..=self.right {
                out.push((dx, dy));
            }
        }
        out
    }
}

/// The PDA network and the MER conventions it was trained with.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct PdaConfig {
    /// Preset name (informational).
    pub name: String,
    /// Channels of each U-Net level; level 0 runs at 1/`input_stride` of the grid, level i at
    /// 1/(`input_stride`·2^i).
    pub widths: Vec<i64>,
    /// 1: level 0 runs at the grid resolution (RC-PDA). s = 2 or 4: the 5 input channels are
    /// folded s×s into 5·s² channels (space to depth, the grid zero-padded to a
    /// multiple of s), every level runs s times coarser, and the head predicts the K logits
    /// for each of the s² positions inside a cell — the inverse fold (pixel shuffle), computed
    /// only at the radar pixels. The labels, the window and the grid are those of SPEC §5
    /// either way; only the network's cost changes (the `fast` preset, docs/guide/mer.md).
    #[serde(default = "crate::one", skip_serializing_if = "crate::is_one")]
    pub input_stride: i64,
    pub window: MerWindow,
    /// MER grid = training frame / `grid_scale` (2: 400x175, RC-PDA's 1/4 of the 1600x900
    /// camera image, so that the window spans what SPEC §5's "1/4 resolution" window spans).
    pub grid_scale: i64,
    /// Radar and lidar beyond this depth are dropped (SPEC §5: 50 m).
    pub max_depth_m: f64,
    /// Association label: |Δd| < `abs_threshold_m` (1 m) and |Δd|/d < `rel_threshold` (5 %).
    pub abs_threshold_m: f64,
    pub rel_threshold: f64,
    /// The network sees radar depth / `radar_scale_m` and a radar-present mask.
    pub radar_scale_m: f64,
    /// Channels E of the appearance-affinity term (0 = none: RC-PDA's plain 1x1 head). With
    /// E > 0 the logit of neighbour n of radar pixel p is the 1x1 head at p plus
    /// ⟨W_q f(p), W_k f(n)⟩ / √E, f = the U-Net's level-0 features: the head keeps the
    /// per-offset prior, the dot product says whether n looks like p's surroundings — the
    /// "same object" question that the plain head has to answer through 180 fixed channels.
    /// Not in RC-PDA and off in every preset: measured no better (docs/guide/mer.md).
    #[serde(default)]
    pub affinity_channels: i64,
}

impl PdaConfig {
    /// RC-PDA-sized: four levels 32/64/128/256 (receptive field > the 36-row window).
    pub fn paper() -> Self {
        PdaConfig {
            name: "paper".into(),
            widths: vec![32, 64, 128, 256],
            window: MerWindow::PAPER,
            grid_scale: 2,
            max_depth_m: 50.0,
            abs_threshold_m: 1.0,
            rel_threshold: 0.05,
            radar_scale_m: 80.0,
            affinity_channels: 0,
            input_stride: 1,
        }
    }

    /// For CPU runs and demos: four levels 8/16/32/64.
    pub fn tiny() -> Self {
        PdaConfig {
            name: "tiny".into(),
            widths: vec![8, 16, 32, 64],
            ..Self::paper()
        }
    }

    /// `tiny`'s levels on the grid folded 2x2 (`input_stride` 2): level 0 at 200x88. For CPUs
    /// and `mer apply` at `prepare`'s rate (BENCHMARKS.md, MER).
    pub fn fast() -> Self {
        PdaConfig {
            name: "fast".into(),
            input_stride: 2,
            ..Self::tiny()
        }
    }

    /// For tests only: three levels 4/8/8.
    pub fn test() -> Self {
        PdaConfig {
            name: "test".into(),
            widths: vec![4, 8, 8],
            ..Self::paper()
        }
    }

    /// `paper`, `tiny` or `test`, or a PDA config JSON file.
    pub fn resolve(spec: &str) -> Result<Self, PdaConfigError> {
        match spec.trim().to_ascii_lowercase().as_str() {
            "paper" => return Ok(Self::paper()),
            "tiny" => return Ok(Self::tiny()),
            "fast" => return Ok(Self::fast()),
            "test" => return Ok(Self::test()),
            _ => {}
        }
        let path = Path::new(spec);
        if !path.is_file() {
            return Err(PdaConfigError::UnknownPreset(spec.to_string()));
        }
        let text = std::fs::read_to_string(path).map_err(|source| PdaConfigError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let cfg: Self = serde_json::from_str(&text).map_err(|source| PdaConfigError::Json {
            path: path.to_path_buf(),
            source,
        })?;
        cfg.validate()?;
        Ok(cfg)
    }

    pub fn validate(&self) -> Result<(), PdaConfigError> {
        let bad = |m: String| Err(PdaConfigError::Invalid(m));
        if self.widths.is_empty() || self.widths.iter().any(|&w| w < 1) {
            return bad(format!(
                "widths {:?} (need ≥ 1 level, each ≥ 1)",
                self.widths
            ));
        }
        let w = &self.window;
        if w.left < 0 || w.right < 0 || w.up < 0 || w.down < 0 {
            return bad(format!("window {w:?} has a negative side"));
        }
        if !(0..=256).contains(&self.affinity_channels) {
            return bad(format!(
                "affinity_channels {} (0..=256)",
                self.affinity_channels
            ));
        }
        if ![1, 2, 4].contains(&self.input_stride) {
            return bad(format!("input_stride {} (1, 2 or 4)", self.input_stride));
        }
        if !(1..=8).contains(&self.grid_scale) {
            return bad(format!("grid_scale {} (1..=8)", self.grid_scale));
        }
        let positive = [
            self.max_depth_m,
            self.abs_threshold_m,
            self.rel_threshold,
            self.radar_scale_m,
        ];
        // `x > 0.0` is false for NaN too.
        if positive
            .iter()
            .any(|x| x.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater))
        {
            return bad(format!(
                "max_depth_m, abs_threshold_m, rel_threshold and radar_scale_m must be > 0 \
                 (got {positive:?})"
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn window_has_180_offsets_in_channel_order() {
        let w = MerWindow::PAPER;
        let o = w.offsets();
        assert_eq!(o.len(), 180);
        assert_eq!(o[0], (-2, -30));
        assert_eq!(o[4], (2, -30));
        assert_eq!(o[30 * 5 + 2], (0, 0), "the radar pixel itself");
        assert_eq!(o[179], (2, 5));
    }

    #[test]
    fn presets_resolve_and_errors_say_what_is_wrong() {
        assert_eq!(PdaConfig::resolve(" Tiny ").unwrap(), PdaConfig::tiny());
        assert_eq!(PdaConfig::resolve("fast").unwrap().input_stride, 2);
        let e = PdaConfig::resolve("huge").unwrap_err();
        assert_eq!(
            e.to_string(),
            "invalid model config: unknown PDA preset `huge` (paper, tiny, fast, test, or a PDA \
             config JSON file)"
        );
        let bad = PdaConfig {
            input_stride: 3,
            ..PdaConfig::test()
        };
        assert_eq!(
            bad.validate().unwrap_err().to_string(),
            "invalid model config: PDA: input_stride 3 (1, 2 or 4)"
        );
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("pda.json");
        std::fs::write(&p, "{").unwrap();
        let e = PdaConfig::resolve(p.to_str().unwrap()).unwrap_err();
        assert!(matches!(e, PdaConfigError::Json { .. }), "{e}");
        assert!(e.to_string().contains("not a PDA config JSON"), "{e}");
        std::fs::write(&p, serde_json::to_string(&PdaConfig::fast()).unwrap()).unwrap();
        assert_eq!(
            PdaConfig::resolve(p.to_str().unwrap()).unwrap(),
            PdaConfig::fast()
        );
    }
}
