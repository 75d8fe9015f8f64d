//! Depth metrics and report tables (SPEC §9, §10). Pure Rust, no torch.
//!
//! [`table`] is the one Markdown table / CSV row writer (the paper tables of [`tables`] and
//! every experiment's), with one rendering of a missing value per format.
//!
//! One accumulator, [`Evaluator`], computes every metric for every report row; training
//! validation and `depthsense eval` both go through it. Rows are
//! condition (combined / day / night / rain) × region (full image / low-height) × cap
//! (50 / 70 / 80 m by default).
//!
//! Conventions (SPEC §9):
//! - valid pixels: sparse GT > 0 (and, under the default `mask` protocol, GT ≤ cap);
//! - the prediction is clipped to [α, β] (SID range, 1–80 m by default) before anything else;
//! - `clamp` protocol (peers'): no pixel is dropped for being beyond the cap; GT and prediction
//!   are both clamped to the cap instead;
//! - δ_n = fraction with max(ŷ/y, y/ŷ) < 1.25^n; AbsRel = mean |y−ŷ|/y; SqRel = mean (y−ŷ)²/y;
//!   RMSE = sqrt(mean (y−ŷ)²); RMSE_log = sqrt(mean (ln y − ln ŷ)²); MAE = mean |y−ŷ|;
//! - aggregation `image` (default, RadarNet): metrics per image, then the mean over images that
//!   have at least one valid pixel; `pooled` (DORN): one mean over all valid pixels.

pub mod doc;
pub mod table;
pub mod tables;

use depthsense_base::words::{UnknownWord, Words};
use serde::{Deserialize, Serialize};

/// How pixels beyond the cap are treated (SPEC §9).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Protocol {
    /// Drop pixels whose GT exceeds the cap (default).
    #[default]
    Mask,
    /// Keep every GT pixel; clamp both GT and prediction to the cap (peers' protocol).
    Clamp,
    /// RadarNet's evaluation (Singh et al., CVPR 2023, `nesl/radar-camera-fusion-depth`,
    /// `src/fusionnet_main.py` `run`/`validate`): pixels with 0 < GT < cap (strict), the
    /// prediction used as the network gave it (no clip to [α, β]; non-finite values still
    /// count as the clip maximum), metrics per image then the mean over images (`pooled` is
    /// refused). GT is whatever sparse map is scored: their test GT is the single keyframe
    /// lidar sweep, as ours (docs/guide/evaluate.md, "RadarNet's protocol").
    Radarnet,
}

impl Words for Protocol {
    const WHAT: &'static str = "protocol";
    const WORDS: &'static [(&'static str, Self)] = &[
        ("mask", Self::Mask),
        ("clamp", Self::Clamp),
        ("radarnet", Self::Radarnet),
    ];
}

impl std::str::FromStr for Protocol {
    type Err = MetricsError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(Self::parse_word(s)?)
    }
}

impl Protocol {
    /// The (GT, prediction) pair scored under `cap`, or `None` when the pixel is dropped:
    /// `mask` drops GT > cap, `radarnet` GT ≥ cap, `clamp` clamps both to the cap.
    #[inline]
    fn capped(self, y: f64, p: f64, cap: f64) -> Option<(f64, f64)> {
        match self {
            Protocol::Mask => {
                if y > cap {
                    return None;
                }
                Some((y, p))
            }
            Protocol::Clamp => Some((y.min(cap), p.min(cap))),
            Protocol::Radarnet => {
                if y >= cap {
                    return None;
                }
                Some((y, p))
            }
        }
    }
}

/// How per-pixel errors are averaged (SPEC §9).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Aggregate {
    /// Metrics per image, then averaged over images (RadarNet; default).
    #[default]
    Image,
    /// One average over every valid pixel of every image (DORN).
    Pooled,
}

impl Words for Aggregate {
    const WHAT: &'static str = "aggregation";
    const WORDS: &'static [(&'static str, Self)] =
        &[("image", Self::Image), ("pooled", Self::Pooled)];
}

impl std::str::FromStr for Aggregate {
    type Err = MetricsError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(Self::parse_word(s)?)
    }
}

#[derive(Debug, thiserror::Error)]
pub enum MetricsError {
    /// A protocol or aggregation word outside its vocabulary.
    #[error(transparent)]
    BadName(#[from] UnknownWord),
    #[error(
        "image {index}: prediction has {pred} values, ground truth {gt}, low-height mask {mask}"
    )]
    SizeMismatch {
        index: usize,
        pred: usize,
        gt: usize,
        mask: usize,
    },

    // --- The settings of an evaluation ([`EvalConfig`]) ---
    /// Depth caps (`caps`, metres) that are none, or one of them not a positive finite number.
    #[error("invalid metric settings: caps must be positive and finite, got {caps:?}")]
    BadCaps { caps: Vec<f64> },
    /// A clip range [`min`, `max`] (metres) that is not 0 < min < max.
    #[error("invalid metric settings: clip range must satisfy 0 < min < max, got [{min}, {max}]")]
    BadClipRange { min: f64, max: f64 },
    /// The `radarnet` protocol asked for with the `pooled` aggregation: it averages per image.
    #[error(
        "invalid metric settings: the radarnet protocol averages per image: it cannot be pooled"
    )]
    PooledRadarnet,
}

/// Settings of an evaluation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalConfig {
    /// Depth caps in metres (SPEC §9: 50, 70, 80).
    pub caps_m: Vec<f64>,
    pub protocol: Protocol,
    pub aggregate: Aggregate,
    /// Predictions are clipped to [clip_min_m, clip_max_m] (SPEC §9: [α, β] = [1, 80]).
    pub clip_min_m: f64,
    pub clip_max_m: f64,
}

impl Default for EvalConfig {
    fn default() -> Self {
        Self {
            caps_m: vec![50.0, 70.0, 80.0],
            protocol: Protocol::Mask,
            aggregate: Aggregate::Image,
            clip_min_m: 1.0,
            clip_max_m: 80.0,
        }
    }
}

impl EvalConfig {
    fn validate(&self) -> Result<(), MetricsError> {
        if self.caps_m.is_empty() || self.caps_m.iter().any(|c| !(c.is_finite() && *c > 0.0)) {
            return Err(MetricsError::BadCaps {
                caps: self.caps_m.clone(),
            });
        }
        if !(self.clip_min_m > 0.0 && self.clip_max_m > self.clip_min_m) {
            return Err(MetricsError::BadClipRange {
                min: self.clip_min_m,
                max: self.clip_max_m,
            });
        }
        if self.protocol == Protocol::Radarnet && self.aggregate == Aggregate::Pooled {
            return Err(MetricsError::PooledRadarnet);
        }
        Ok(())
    }

    /// The largest cap (the "headline" cap, 80 m by default).
    pub fn main_cap(&self) -> f64 {
        self.caps_m.iter().copied().fold(f64::MIN, f64::max)
    }
}

/// The metrics of SPEC §9. Depth errors in metres (the distance table converts to mm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct Metrics {
    pub delta1: f64,
    pub delta2: f64,
    pub delta3: f64,
    pub abs_rel: f64,
    pub sq_rel: f64,
    pub rmse: f64,
    pub rmse_log: f64,
    pub mae: f64,
}

/// Per-pixel sums from which [`Metrics`] follow.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Sums {
    n: u64,
    d1: f64,
    d2: f64,
    d3: f64,
    abs_rel: f64,
    sq_rel: f64,
    sq: f64,
    sq_log: f64,
    abs: f64,
}

impl Sums {
    #[inline]
    fn add_pixel(&mut self, y: f64, p: f64) {
        let ratio = (p / y).max(y / p);
        let diff = y - p;
        self.n += 1;
        self.d1 += (ratio < 1.25) as u8 as f64;
        self.d2 += (ratio < 1.25f64.powi(2)) as u8 as f64;
        self.d3 += (ratio < 1.25f64.powi(3)) as u8 as f64;
        self.abs_rel += diff.abs() / y;
        self.sq_rel += diff * diff / y;
        self.sq += diff * diff;
        let dl = y.ln() - p.ln();
        self.sq_log += dl * dl;
        self.abs += diff.abs();
    }

    fn add(&mut self, o: &Sums) {
        self.n += o.n;
        self.d1 += o.d1;
        self.d2 += o.d2;
        self.d3 += o.d3;
        self.abs_rel += o.abs_rel;
        self.sq_rel += o.sq_rel;
        self.sq += o.sq;
        self.sq_log += o.sq_log;
        self.abs += o.abs;
    }

    fn metrics(&self) -> Metrics {
        if self.n == 0 {
            return Metrics::default();
        }
        let n = self.n as f64;
        Metrics {
            delta1: self.d1 / n,
            delta2: self.d2 / n,
            delta3: self.d3 / n,
            abs_rel: self.abs_rel / n,
            sq_rel: self.sq_rel / n,
            rmse: (self.sq / n).sqrt(),
            rmse_log: (self.sq_log / n).sqrt(),
            mae: self.abs / n,
        }
    }
}

/// Running state of one report row.
#[derive(Debug, Clone, Default)]
struct RowAcc {
    pooled: Sums,
    /// Sum over images of the per-image metrics (for `image` aggregation).
    image_sum: Metrics,
    n_images: u64,
}

impl RowAcc {
    fn add_image(&mut self, s: &Sums) {
        if s.n == 0 {
            return;
        }
        self.pooled.add(s);
        let m = s.metrics();
        let t = &mut self.image_sum;
        t.delta1 += m.delta1;
        t.delta2 += m.delta2;
        t.delta3 += m.delta3;
        t.abs_rel += m.abs_rel;
        t.sq_rel += m.sq_rel;
        t.rmse += m.rmse;
        t.rmse_log += m.rmse_log;
        t.mae += m.mae;
        self.n_images += 1;
    }

    fn finish(&self, agg: Aggregate) -> Metrics {
        match agg {
            Aggregate::Pooled => self.pooled.metrics(),
            Aggregate::Image => {
                if self.n_images == 0 {
                    return Metrics::default();
                }
                let n = self.n_images as f64;
                let t = &self.image_sum;
                Metrics {
                    delta1: t.delta1 / n,
                    delta2: t.delta2 / n,
                    delta3: t.delta3 / n,
                    abs_rel: t.abs_rel / n,
                    sq_rel: t.sq_rel / n,
                    rmse: t.rmse / n,
                    rmse_log: t.rmse_log / n,
                    mae: t.mae / n,
                }
            }
        }
    }
}

/// Condition rows of the report (SPEC §9, §10.1).
pub const CONDITIONS: [&str; 4] = ["combined", "day", "night", "rain"];
/// Region rows of the report (SPEC §4 low-height region): the keys of the JSON files.
pub const REGIONS: [&str; 2] = ["full", "lowheight"];

/// How tables and pictures print a region key: `full`, `low-height`.
pub fn region_label(region: &str) -> &str {
    match region {
        "lowheight" => "low-height",
        other => other,
    }
}

/// One row of a report: a condition × region × cap and its metrics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Row {
    /// "combined", "day", "night" or "rain".
    pub condition: String,
    /// "full" or "lowheight".
    pub region: String,
    pub cap_m: f64,
    /// Images with at least one valid pixel in this row.
    pub n_images: u64,
    /// Valid pixels behind this row.
    pub n_pixels: u64,
    pub metrics: Metrics,
}

/// Every row of an evaluation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub config: EvalConfig,
    /// Images given to the evaluator (including those without valid pixels).
    pub images_seen: u64,
    pub rows: Vec<Row>,
}

impl Report {
    /// The row for a condition, region and cap (cap compared to 1e-9).
    pub fn row(&self, condition: &str, region: &str, cap_m: f64) -> Option<&Row> {
        self.rows.iter().find(|r| {
            r.condition == condition && r.region == region && (r.cap_m - cap_m).abs() < 1e-9
        })
    }

    /// The headline row: combined, full image, largest cap.
    pub fn headline(&self) -> Option<&Row> {
        self.row("combined", "full", self.config.main_cap())
    }
}

/// One image handed to the [`Evaluator`].
#[derive(Debug, Clone, Copy)]
pub struct EvalImage<'a> {
    /// Predicted depth in metres, row-major (any value; clipped to the clip range).
    pub pred_m: &'a [f32],
    /// Sparse ground truth in metres, 0 (or non-finite) = no data.
    pub gt_m: &'a [f32],
    /// Low-height mask (true where the GT point is in the low-height region); `None` when
    /// unavailable (the image then contributes nothing to the low-height rows).
    pub lowheight: Option<&'a [bool]>,
    /// Conditions of the image's scene: any of "day", "night", "rain".
    pub conditions: &'a [&'a str],
}

/// Accumulates images and produces a [`Report`]. The only place metrics are computed.
#[derive(Debug, Clone)]
pub struct Evaluator {
    cfg: EvalConfig,
    /// Indexed [condition][region][cap].
    acc: Vec<RowAcc>,
    images_seen: u64,
}

impl Evaluator {
    pub fn new(cfg: EvalConfig) -> Result<Self, MetricsError> {
        cfg.validate()?;
        let n = CONDITIONS.len() * REGIONS.len() * cfg.caps_m.len();
        Ok(Self {
            cfg,
            acc: vec![RowAcc::default(); n],
            images_seen: 0,
        })
    }

    pub fn config(&self) -> &EvalConfig {
        &self.cfg
    }

    fn slot(&self, cond: usize, region: usize, cap: usize) -> usize {
        (cond * REGIONS.len() + region) * self.cfg.caps_m.len() + cap
    }

    /// Add one image to every row it belongs to.
    pub fn add(&mut self, img: &EvalImage<'_>) -> Result<(), MetricsError> {
        self.check_sizes(img)?;
        self.images_seen += 1;
        let sums = self.image_sums(img);
        self.add_image_sums(img, &sums);
        Ok(())
    }

    /// Prediction, ground truth and low-height mask must have one value per pixel.
    fn check_sizes(&self, img: &EvalImage<'_>) -> Result<(), MetricsError> {
        let n = img.gt_m.len();
        let mask_len = img.lowheight.map_or(n, |m| m.len());
        if img.pred_m.len() != n || mask_len != n {
            return Err(MetricsError::SizeMismatch {
                index: self.images_seen as usize,
                pred: img.pred_m.len(),
                gt: n,
                mask: mask_len,
            });
        }
        Ok(())
    }

    /// The image's per-pixel sums, indexed `[region][cap]` (`region * ncaps + cap`).
    fn image_sums(&self, img: &EvalImage<'_>) -> Vec<Sums> {
        let n = img.gt_m.len();
        let ncaps = self.cfg.caps_m.len();
        // sums[region][cap]
        let mut sums = vec![Sums::default(); REGIONS.len() * ncaps];
        for i in 0..n {
            let y = img.gt_m[i] as f64;
            if !(y.is_finite() && y > 0.0) {
                continue;
            }
            let p = self.clipped_prediction(img.pred_m[i] as f64);
            let low = img.lowheight.is_some_and(|m| m[i]);
            for (c, &cap) in self.cfg.caps_m.iter().enumerate() {
                let Some((yy, pp)) = self.cfg.protocol.capped(y, p, cap) else {
                    continue;
                };
                sums[c].add_pixel(yy, pp);
                if low {
                    sums[ncaps + c].add_pixel(yy, pp);
                }
            }
        }
        sums
    }

    /// The prediction as scored: clipped to the clip range (except under `radarnet`).
    #[inline]
    fn clipped_prediction(&self, p_raw: f64) -> f64 {
        let (lo, hi) = (self.cfg.clip_min_m, self.cfg.clip_max_m);
        // A non-finite prediction counts as the far clip value: never silently dropped.
        match (p_raw.is_finite(), self.cfg.protocol) {
            (false, _) => hi,
            (true, Protocol::Radarnet) => p_raw,
            (true, _) => p_raw.clamp(lo, hi),
        }
    }

    /// Add an image's sums to its rows: combined and each of its conditions, full image,
    /// and low-height when the image has a mask.
    fn add_image_sums(&mut self, img: &EvalImage<'_>, sums: &[Sums]) {
        let ncaps = self.cfg.caps_m.len();
        let mut conds: Vec<usize> = vec![0];
        for (k, name) in CONDITIONS.iter().enumerate().skip(1) {
            if img.conditions.contains(name) {
                conds.push(k);
            }
        }
        for &cond in &conds {
            for region in 0..REGIONS.len() {
                if region == 1 && img.lowheight.is_none() {
                    continue;
                }
                for c in 0..ncaps {
                    let slot = self.slot(cond, region, c);
                    self.acc[slot].add_image(&sums[region * ncaps + c]);
                }
            }
        }
    }
    /// All rows (condition × region × cap), including empty ones (zero images).
    pub fn finish(&self) -> Report {
        let mut rows = Vec::with_capacity(self.acc.len());
        for (ci, cond) in CONDITIONS.iter().enumerate() {
            for (ri, region) in REGIONS.iter().enumerate() {
                for (ki, &cap) in self.cfg.caps_m.iter().enumerate() {
                    let a = &self.acc[self.slot(ci, ri, ki)];
                    rows.push(Row {
                        condition: cond.to_string(),
                        region: region.to_string(),
                        cap_m: cap,
                        n_images: a.n_images,
                        n_pixels: a.pooled.n,
                        metrics: a.finish(self.cfg.aggregate),
                    });
                }
            }
        }
        Report {
            config: self.cfg.clone(),
            images_seen: self.images_seen,
            rows,
        }
    }
}

/// Convenience: evaluate a set of images in one call.
pub fn evaluate(images: &[EvalImage<'_>], cfg: &EvalConfig) -> Result<Report, MetricsError> {
    let mut ev = Evaluator::new(cfg.clone())?;
    for img in images {
        ev.add(img)?;
    }
    Ok(ev.finish())
}

#[cfg(test)]
mod tests;

#[cfg(test)]
mod word_tests {
    use super::*;

    #[test]
    fn protocol_and_aggregate_words() {
        depthsense_base::words::check_vocabulary::<Protocol>().unwrap();
        depthsense_base::words::check_vocabulary::<Aggregate>().unwrap();
        assert_eq!("radarnet".parse::<Protocol>().unwrap(), Protocol::Radarnet);
        assert_eq!(
            "sum".parse::<Aggregate>().unwrap_err().to_string(),
            "unknown aggregation \"sum\" (allowed: image, pooled)"
        );
    }
}

#[cfg(test)]
mod settings_tests {
    use super::*;

    /// Refused settings carry the values at fault and read as the strings they replaced did.
    #[test]
    fn refused_settings_name_their_values() {
        let refusal = |cfg: EvalConfig| Evaluator::new(cfg).unwrap_err();
        let e = refusal(EvalConfig {
            caps_m: vec![50.0, -1.0],
            ..EvalConfig::default()
        });
        assert!(
            matches!(&e, MetricsError::BadCaps { caps } if caps == &[50.0, -1.0]),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            "invalid metric settings: caps must be positive and finite, got [50.0, -1.0]"
        );
        let e = refusal(EvalConfig {
            clip_min_m: 2.0,
            clip_max_m: 1.5,
            ..EvalConfig::default()
        });
        assert!(
            matches!(e, MetricsError::BadClipRange { min, max } if min == 2.0 && max == 1.5),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            "invalid metric settings: clip range must satisfy 0 < min < max, got [2, 1.5]"
        );
        let e = refusal(EvalConfig {
            protocol: Protocol::Radarnet,
            aggregate: Aggregate::Pooled,
            ..EvalConfig::default()
        });
        assert!(matches!(e, MetricsError::PooledRadarnet), "{e:?}");
        assert_eq!(
            e.to_string(),
            "invalid metric settings: the radarnet protocol averages per image: it cannot be \
             pooled"
        );
    }
}
