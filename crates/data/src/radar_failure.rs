//! Sensor failure beyond random point drop (SPEC §10.8): whole radars absent, every return
//! beyond a range absent, clutter (ghost returns) added — applied to the prepared radar maps
//! as the loader reads them ([`RadarFailure::apply`]), so that `eval` and
//! `experiment failure` see exactly what a failing sensor would have given the network.
//!
//! Rules (documented in the docs/guide/experiments.md, "Sensor failure"):
//! - `drop_radars`: channel names (`RADAR_FRONT`, …, or `all`). A sample's channels are the
//!   keys of its `meta.json` `cam_from_radar` (a sample that lists none has one unnamed
//!   radar set that only `all` drops). When every channel of the sample is dropped, both
//!   radar maps become empty — exactly `--radar-drop 1.0`. Dropping a strict subset
//!   re-rasterises the sample's `radar_points.bin` (written by `prepare`, see
//!   [`depthsense_prep::radar_points`]) without those channels; samples prepared before that
//!   file existed are refused with a message asking to re-run `prepare`.
//! - `perturb` (calibration perturbation, SPEC §10.7): the radar returns are moved by a
//!   perturbed radar→camera extrinsic ([`Perturbation`]: rotation about the radar's own
//!   position with camera axes, or translation in camera axes) and re-rasterised with the
//!   function `prepare` uses. The sign of the amount is drawn per sample from
//!   `(seed, sample token)` (±1 with equal odds; the same sign for every axis and magnitude
//!   of that sample), so an evaluation averages both directions.
//!
//! Order in the loader: re-rasterisation ([`RadarFailure::reraster`]) first, then the random
//! point drop (`--radar-drop`), then [`RadarFailure::apply`] (all radars, range, clutter).
//! - `drop_beyond_m` R: every raw pixel with depth > R and every height-strip pixel with
//!   depth > R is cleared (strips carry their point's depth, so this is exact).
//! - `clutter` N: N ghost points per sample, drawn from `(seed, sample token)`: column u
//!   uniform over the width, depth d uniform in [2, 80] m (quantised like the maps, 1/256 m),
//!   row v = c_y + f_y·1.0/d (a return 1 m below the camera, i.e. near radar mounting
//!   height, SPEC §2 radar has no elevation); the raw pixel and its SPEC §5 height strip
//!   v − 1.5·f_y/d … v + 0.25·f_y/d (training-frame intrinsics) are drawn nearest-wins.

use std::collections::BTreeSet;
use std::path::Path;

use depthsense_nuscenes::depth_png::{decode_value, encode_value, DepthMap};
use depthsense_prep::layout::SampleMeta;
use depthsense_prep::maps::Raster;
use depthsense_prep::radar_points::{Perturbation, RadarPoints};
use serde::{Deserialize, Serialize};

use crate::Rng;
use depthsense_base::hash::splitmix64;
use depthsense_dataset::DataError;

/// Height above the radar point covered by its strip (SPEC §5 h_up).
const H_UP_M: f64 = 1.5;
/// Height below (SPEC §5 h_down).
const H_DOWN_M: f64 = 0.25;
/// Clutter depth range (metres).
const CLUTTER_MIN_M: f64 = 2.0;
const CLUTTER_MAX_M: f64 = 80.0;
/// Clutter returns sit this far below the camera's optical axis.
const CLUTTER_BELOW_CAMERA_M: f64 = 1.0;

/// What fails (all empty = nothing; see the module docs for the exact rules).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct RadarFailure {
    /// Radar channels removed (`all` = every channel).
    #[serde(default)]
    pub drop_radars: Vec<String>,
    /// Returns beyond this depth (metres) removed.
    #[serde(default)]
    pub drop_beyond_m: Option<f64>,
    /// Ghost points added per sample.
    #[serde(default)]
    pub clutter: usize,
    /// Calibration perturbation (SPEC §10.7); the sign is drawn per sample (module docs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub perturb: Option<Perturbation>,
}

impl RadarFailure {
    pub fn is_active(&self) -> bool {
        !self.drop_radars.is_empty()
            || self.drop_beyond_m.is_some()
            || self.clutter > 0
            || self.perturb.is_some()
    }

    /// Dropping every radar of the sample (`all`, or every channel it lists).
    fn drops_all(&self, meta: &SampleMeta) -> bool {
        let present: BTreeSet<&str> = meta.cam_from_radar.keys().map(String::as_str).collect();
        let dropped: BTreeSet<&str> = self.drop_radars.iter().map(String::as_str).collect();
        dropped.contains("all") || (!present.is_empty() && present.is_subset(&dropped))
    }

    /// Whether this sample's maps must be rebuilt from its radar points: a perturbation, or
    /// a strict subset of its radars dropped.
    pub fn needs_points(&self, meta: &SampleMeta) -> bool {
        let subset = !self.drops_all(meta)
            && meta
                .cam_from_radar
                .keys()
                .any(|c| self.drop_radars.contains(c));
        self.perturb.is_some() || subset
    }

    /// The sample's raw and height maps rebuilt from `dir`/radar_points.bin without the
    /// dropped channels and with the perturbation (sign from `seed`), quantised exactly like
    /// the stored PNGs (1/256 m); `None` when [`Self::needs_points`] is false.
    pub fn reraster(
        &self,
        dir: &Path,
        meta: &SampleMeta,
        seed: u64,
    ) -> Result<Option<(DepthMap, DepthMap)>, DataError> {
        if !self.needs_points(meta) {
            return Ok(None);
        }
        let points =
            RadarPoints::read_from_sample(dir).map_err(|source| DataError::SampleRadarPoints {
                sample: meta.sample_token.clone(),
                source,
            })?;
        let mut points = if self.drops_all(meta) {
            points.without_channels(|_| true)
        } else {
            points.without_channels(|c| self.drop_radars.iter().any(|d| d == c))
        };
        if let Some(p) = self.perturb {
            let sign = if splitmix64(seed ^ 0x5167) & 1 == 0 {
                1.0
            } else {
                -1.0
            };
            points = points.perturbed(&Perturbation {
                amount: sign * p.amount,
                ..p
            });
        }
        let maps = points.rasterise();
        Ok(Some((quantised(&maps.raw), quantised(&maps.height))))
    }

    /// Short label, e.g. "drop RADAR_FRONT", "beyond 30 m", "clutter 20", "none".
    pub fn label(&self) -> String {
        let mut parts = vec![];
        if !self.drop_radars.is_empty() {
            parts.push(format!("drop {}", self.drop_radars.join("+")));
        }
        if let Some(r) = self.drop_beyond_m {
            parts.push(format!("beyond {r} m"));
        }
        if self.clutter > 0 {
            parts.push(format!("clutter {}", self.clutter));
        }
        if let Some(p) = self.perturb {
            let unit = if p.axis.is_rotation() { "°" } else { " m" };
            parts.push(format!("{} ±{}{unit}", p.axis.name(), p.amount));
        }
        if parts.is_empty() {
            "none".into()
        } else {
            parts.join(", ")
        }
    }

    pub fn validate(&self) -> Result<(), DataError> {
        if let Some(r) = self.drop_beyond_m {
            if !(r.is_finite() && r > 0.0) {
                return Err(DataError::DropBeyondNotPositive { metres: r });
            }
        }
        if let Some(p) = self.perturb {
            if !(p.amount.is_finite() && p.amount >= 0.0) {
                return Err(DataError::NegativePerturbation { amount: p.amount });
            }
        }
        Ok(())
    }

    /// Apply to one sample's raw and height-extended maps (training frame): every radar
    /// dropped, the range cut, clutter. A strict subset of radars and the perturbation are
    /// [`Self::reraster`]'s (the loader calls it first). `seed` is the sample's draw (the
    /// loader mixes the run seed with the sample token).
    pub fn apply(
        &self,
        raw: &mut DepthMap,
        height: &mut DepthMap,
        meta: &SampleMeta,
        seed: u64,
    ) -> Result<(), DataError> {
        if !self.drop_radars.is_empty() && self.drops_all(meta) {
            raw.depth_m.iter_mut().for_each(|d| *d = 0.0);
            height.depth_m.iter_mut().for_each(|d| *d = 0.0);
        }
        if let Some(r) = self.drop_beyond_m {
            for m in [&mut *raw, &mut *height] {
                m.depth_m
                    .iter_mut()
                    .filter(|d| **d as f64 > r)
                    .for_each(|d| *d = 0.0);
            }
        }
        if self.clutter > 0 {
            add_clutter(raw, height, meta, self.clutter, seed);
        }
        Ok(())
    }
}

/// A raster as the loader reads its PNG: depth rounded to 1/256 m (SPEC §3 storage).
/// A raster as the loader reads its stored PNG (1/256 m steps).
pub(crate) fn quantised(r: &Raster) -> DepthMap {
    let mut m = r.to_depth_map();
    for d in &mut m.depth_m {
        *d = decode_value(encode_value(*d));
    }
    m
}

fn put_nearest(m: &mut DepthMap, u: usize, v: usize, d: f32) {
    let i = v * m.width as usize + u;
    if m.depth_m[i] <= 0.0 || d < m.depth_m[i] {
        m.depth_m[i] = d;
    }
}

/// Ghost returns (module docs), deterministic in `seed`.
pub fn add_clutter(
    raw: &mut DepthMap,
    height: &mut DepthMap,
    meta: &SampleMeta,
    n: usize,
    seed: u64,
) {
    let (w, h) = (raw.width as usize, raw.height as usize);
    let fy = meta.intrinsics_frame[1][1];
    let cy = meta.intrinsics_frame[1][2];
    let mut rng = Rng::new(splitmix64(seed ^ 0xc1u64));
    for _ in 0..n {
        let u = ((rng.uniform() * w as f64) as usize).min(w - 1);
        let d = decode_value(encode_value(rng.range(CLUTTER_MIN_M, CLUTTER_MAX_M) as f32));
        let dm = d as f64;
        let v = cy + fy * CLUTTER_BELOW_CAMERA_M / dm;
        if !(0.0..h as f64).contains(&v) {
            continue;
        }
        put_nearest(raw, u, v as usize, d);
        let top = (v - H_UP_M * fy / dm).floor().max(0.0) as usize;
        let bottom = ((v + H_DOWN_M * fy / dm).ceil() as usize).min(h - 1);
        for vv in top..=bottom {
            put_nearest(height, u, vv, d);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta(channels: &[&str]) -> SampleMeta {
        SampleMeta {
            sample_token: "t".into(),
            scene_token: "s".into(),
            scene_name: "n".into(),
            conditions: vec![],
            timestamp_us: 0,
            sample_data_tokens: Default::default(),
            intrinsics_frame: [[100.0, 0.0, 32.0], [0.0, 100.0, 10.0], [0.0, 0.0, 1.0]],
            intrinsics_full: [[0.0; 3]; 3],
            cam_from_lidar: [[0.0; 4]; 4],
            cam_from_radar: channels
                .iter()
                .map(|c| (c.to_string(), [[0.0; 4]; 4]))
                .collect(),
            counts: Default::default(),
            settings: serde_json::Value::Null,
        }
    }

    fn maps() -> (DepthMap, DepthMap) {
        let mut raw = DepthMap::zeros(64, 32);
        let mut height = DepthMap::zeros(64, 32);
        raw.depth_m[5 * 64 + 3] = 10.0;
        raw.depth_m[20 * 64 + 40] = 50.0;
        for v in 2..8 {
            height.depth_m[v * 64 + 3] = 10.0;
        }
        for v in 18..22 {
            height.depth_m[v * 64 + 40] = 50.0;
        }
        (raw, height)
    }

    #[test]
    fn beyond_range_clears_points_and_their_strips() {
        let (mut raw, mut height) = maps();
        let f = RadarFailure {
            drop_beyond_m: Some(30.0),
            ..Default::default()
        };
        f.apply(&mut raw, &mut height, &meta(&[]), 0).unwrap();
        assert_eq!(raw.valid_count(), 1);
        assert_eq!(height.valid_count(), 6);
        assert!(height.depth_m.iter().all(|d| *d == 0.0 || *d == 10.0));
    }

    #[test]
    fn dropping_every_channel_empties_the_maps_and_a_subset_needs_points() {
        let m = meta(&["RADAR_FRONT", "RADAR_FRONT_LEFT"]);
        let (mut raw, mut height) = maps();
        let f = RadarFailure {
            drop_radars: vec!["RADAR_FRONT_LEFT".into(), "RADAR_FRONT".into()],
            ..Default::default()
        };
        f.apply(&mut raw, &mut height, &m, 0).unwrap();
        assert_eq!((raw.valid_count(), height.valid_count()), (0, 0));
        let (mut raw, mut height) = maps();
        let sub = RadarFailure {
            drop_radars: vec!["RADAR_FRONT".into()],
            ..Default::default()
        };
        // a strict subset needs the sample's radar points: absent here
        assert!(sub.needs_points(&m) && !f.needs_points(&m));
        let tmp = std::env::temp_dir().join(format!("ds-failure-{}", std::process::id()));
        let e = sub.reraster(&tmp, &m, 0).unwrap_err();
        assert!(e.to_string().contains("re-run depthsense prepare"), "{e}");
        // a channel the sample does not have changes nothing
        let other = RadarFailure {
            drop_radars: vec!["RADAR_BACK_LEFT".into()],
            ..Default::default()
        };
        other.apply(&mut raw, &mut height, &m, 0).unwrap();
        assert_eq!(raw.valid_count(), 2);
    }

    #[test]
    fn clutter_is_deterministic_and_follows_the_strip_rule() {
        let m = meta(&[]);
        let f = RadarFailure {
            clutter: 5,
            ..Default::default()
        };
        let run = |seed| {
            let mut raw = DepthMap::zeros(64, 32);
            let mut height = DepthMap::zeros(64, 32);
            f.apply(&mut raw, &mut height, &m, seed).unwrap();
            (raw, height)
        };
        let (a, ah) = run(7);
        let (b, bh) = run(7);
        let (c, _) = run(8);
        assert_eq!(a.depth_m, b.depth_m);
        assert_eq!(ah.depth_m, bh.depth_m);
        assert_ne!(a.depth_m, c.depth_m);
        // every raw point sits at v = cy + fy·1/d and lies inside its strip
        for (i, d) in a.depth_m.iter().enumerate().filter(|(_, d)| **d > 0.0) {
            let v = i / 64;
            let want = 10.0 + 100.0 / *d as f64;
            assert!((v as f64 - want.floor()).abs() < 1.0, "v {v} vs {want}");
            assert!(ah.depth_m[i] > 0.0 && ah.depth_m[i] <= *d);
            assert_eq!(decode_value(encode_value(*d)), *d);
        }
        assert!(a.valid_count() > 0);
    }

    /// A range cut that is not a positive distance and a negative perturbation are refused
    /// with the value given; a sample without radar points is named by its token.
    #[test]
    fn refused_settings_and_missing_points_carry_their_values() {
        let cut = RadarFailure {
            drop_beyond_m: Some(-2.5),
            ..Default::default()
        };
        let e = cut.validate().unwrap_err();
        assert!(matches!(e, DataError::DropBeyondNotPositive { metres } if metres == -2.5));
        assert_eq!(
            e.to_string(),
            "configuration: --drop-beyond-m must be a positive number of metres, got -2.5"
        );
        let perturb = RadarFailure {
            perturb: Some(Perturbation {
                axis: depthsense_prep::radar_points::PerturbAxis::Yaw,
                amount: -1.0,
            }),
            ..Default::default()
        };
        let e = perturb.validate().unwrap_err();
        assert!(matches!(e, DataError::NegativePerturbation { amount } if amount == -1.0));
        assert_eq!(
            e.to_string(),
            "configuration: perturbation magnitude must be a non-negative number, got -1"
        );
        let sub = RadarFailure {
            drop_radars: vec!["RADAR_FRONT".into()],
            ..Default::default()
        };
        let dir = tempfile::tempdir().unwrap();
        let m = meta(&["RADAR_FRONT", "RADAR_FRONT_LEFT"]);
        let e = sub.reraster(dir.path(), &m, 0).unwrap_err();
        assert!(matches!(&e, DataError::SampleRadarPoints { sample, .. } if sample == "t"));
        assert!(e.to_string().starts_with("data: sample t: "), "{e}");
    }
}
