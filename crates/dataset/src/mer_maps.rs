//! MER maps on disk (SPEC §5): the files `mer apply` writes next to `prepare`'s maps, and
//! what the loader derives from them. Written by `depthsense_mer`; read here, below it, so
//! that the loader and `predict` need no MER training code.
//!
//! Files (next to `prepare`'s maps, `depthsense_prep::layout`):
//! ```text
//! O/mer.json                         MerRecord: the PDA checkpoint that wrote the maps
//! O/<token>/radar_mer_conf.png       16-bit, max association confidence × 65535 (written first)
//! O/<token>/radar_mer_depth.png      16-bit, depth × 256 of that radar return (written last)
//! ```
//! The 6 MER channels d·[conf > θ], θ ∈ [`THRESHOLDS`], are derived when loading
//! ([`derive_channels`]); the network's radar input is then raw + 6 MER = 7 channels.

use std::path::Path;

use depthsense_nuscenes::depth_png::{decode_png, encode_png16_fast, DepthMap};

use depthsense_config::pda::PdaConfig;
use serde::{Deserialize, Serialize};

use crate::error::DataError;

// Per sample: depth × 256 of the most confident associated radar return (SPEC §5), and that
// confidence × 65535: file names of the prepared layout (depthsense_prep::layout).
use depthsense_prep::layout::{MER_CONF_FILE, MER_DEPTH_FILE};
/// In the prepared root: which PDA model wrote the MER maps.
pub const MER_RECORD_FILE: &str = "mer.json";
/// MER thresholds θ of the 6 channels d·[conf > θ] (SPEC §5).
pub const THRESHOLDS: [f32; 6] = [0.5, 0.6, 0.7, 0.8, 0.9, 0.95];

/// Stored 16-bit value of a confidence in [0, 1].
pub fn conf_to_u16(c: f32) -> u16 {
    (c.clamp(0.0, 1.0) * 65535.0).round() as u16
}

/// A confidence as it reads back from its 16-bit value.
pub fn quantise_conf(c: f32) -> f32 {
    conf_to_u16(c) as f32 / 65535.0
}

/// PNG bytes of a confidence map (16-bit, conf × 65535, [`conf_to_u16`]), written as the
/// depth maps are ([`encode_png16_fast`]).
pub fn encode_conf_png(conf: &[f32], w: u32, h: u32) -> Result<Vec<u8>, DataError> {
    let values: Vec<u16> = conf.iter().map(|&c| conf_to_u16(c)).collect();
    Ok(encode_png16_fast(w, h, &values)?)
}

/// Reads a confidence map written by [`encode_conf_png`] → (width, height, conf in [0, 1]).
pub fn read_conf_png(path: &Path) -> Result<DepthMap, DataError> {
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    let mut m = decode_png(&bytes, &path.display().to_string())?;
    for v in m.depth_m.iter_mut() {
        *v = (*v * 256.0).round() / 65535.0;
    }
    Ok(m)
}

/// The 6 MER channels (SPEC §5), channel-major `[6, H, W]`: plane i = depth where
/// conf > THRESHOLDS[i], else 0.
pub fn derive_channels(depth_m: &[f32], conf: &[f32]) -> Vec<f32> {
    let n = depth_m.len();
    let mut out = vec![0f32; THRESHOLDS.len() * n];
    for (i, t) in THRESHOLDS.iter().enumerate() {
        let plane = &mut out[i * n..(i + 1) * n];
        for ((o, &d), &c) in plane.iter_mut().zip(depth_m).zip(conf) {
            if c > *t {
                *o = d;
            }
        }
    }
    out
}

/// FNV-1a 64 of a file's bytes, hex.
pub fn file_fnv64(path: &Path) -> Result<String, DataError> {
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    Ok(format!("{:016x}", depthsense_base::hash::fnv1a64(&bytes)))
}

/// The depth and confidence maps of a prepared sample directory, with a clear error when
/// `mer apply` has not been run on it.
pub fn read_mer_maps(dir: &Path) -> Result<(DepthMap, DepthMap), DataError> {
    let dp = dir.join(MER_DEPTH_FILE);
    let cp = dir.join(MER_CONF_FILE);
    for p in [&dp, &cp] {
        if !p.exists() {
            return Err(DataError::NoMerMap { path: p.clone() });
        }
    }
    let depth = crate::read_depth(&dp)?;
    let conf = read_conf_png(&cp)?;
    if (depth.width, depth.height) != (conf.width, conf.height) {
        return Err(DataError::MerMapSizes {
            conf: cp,
            conf_size: (conf.width, conf.height),
            depth: dp,
            depth_size: (depth.width, depth.height),
        });
    }
    Ok((depth, conf))
}

/// `O/mer.json`: the model behind the MER maps of a prepared directory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MerRecord {
    /// Checkpoint path as given to `mer apply`.
    pub checkpoint: String,
    /// FNV-1a 64 of the checkpoint bytes (hex): the identity of the model.
    pub checkpoint_fnv64: String,
    /// The PDA config stored in the checkpoint.
    pub pda: PdaConfig,
    pub thresholds: Vec<f32>,
    pub depth_file: String,
    pub conf_file: String,
}

/// Reads `O/mer.json` when present.
pub fn read_record(root: &Path) -> Result<Option<MerRecord>, DataError> {
    let p = root.join(MER_RECORD_FILE);
    if !p.exists() {
        return Ok(None);
    }
    let bytes = std::fs::read(&p).map_err(|e| DataError::io(&p, e))?;
    serde_json::from_slice(&bytes)
        .map(Some)
        .map_err(|e| DataError::Parse {
            path: p.to_path_buf(),
            reason: e.to_string(),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conf_png_round_trip_is_exact_on_stored_values() {
        let dir = tempfile::tempdir().unwrap();
        let conf: Vec<f32> = (0..12).map(|i| i as f32 / 11.0).collect();
        let p = dir.path().join(MER_CONF_FILE);
        std::fs::write(&p, encode_conf_png(&conf, 4, 3).unwrap()).unwrap();
        let back = read_conf_png(&p).unwrap();
        assert_eq!((back.width, back.height), (4, 3));
        for (a, b) in conf.iter().zip(&back.depth_m) {
            assert_eq!(quantise_conf(*a), *b);
        }
    }

    /// A sample without its MER maps, or with a confidence map of another size than its depth
    /// map, is refused naming the files and sizes.
    #[test]
    fn missing_or_mismatched_mer_maps_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let (dp, cp) = (
            dir.path().join(MER_DEPTH_FILE),
            dir.path().join(MER_CONF_FILE),
        );
        let e = read_mer_maps(dir.path()).unwrap_err();
        assert!(matches!(&e, DataError::NoMerMap { path } if path == &dp));
        assert_eq!(
            e.to_string(),
            format!(
                "data: {}: missing; radar input `mer` needs `depthsense mer apply --checkpoint \
                 PDA.safetensors --data <prepared>` first (SPEC §5)",
                dp.display()
            )
        );
        let depth = depthsense_nuscenes::depth_png::encode_png(&DepthMap::zeros(4, 2)).unwrap();
        std::fs::write(&dp, depth).unwrap();
        std::fs::write(&cp, encode_conf_png(&[0.5; 4], 2, 2).unwrap()).unwrap();
        let e = read_mer_maps(dir.path()).unwrap_err();
        assert!(matches!(
            e,
            DataError::MerMapSizes {
                conf_size: (2, 2),
                depth_size: (4, 2),
                ..
            }
        ));
        assert_eq!(
            e.to_string(),
            format!("data: {}: 2x2 but {} is 4x2", cp.display(), dp.display())
        );
    }
}
