//! The synthetic nuScenes-format world (the embedded default dataset).
//!
//! [`generate`] writes a complete dataroot in the exact nuScenes format — the 13 tables of
//! `<version>/`, CAM_FRONT JPEGs, LIDAR_TOP `.pcd.bin` sweeps at 20 Hz, RADAR_FRONT /
//! _FRONT_LEFT / _FRONT_RIGHT binary PCDs at ≈13 Hz — plus the exact per-pixel depth of every
//! CAM_FRONT keyframe in `truth/<sample_data_token>.png` (16-bit, depth × 256, SPEC §3).
//! Train / val / test scene lists go to `<version>/splits/{train,val,test}_scenes.txt`
//! (see [`splits`]).
//! The same seed gives byte-identical output, whatever the number of threads.

// Colour math indexes RGB channels with a shared index across several arrays.
#![allow(clippy::needless_range_loop)]

pub mod calib;
pub mod camera;
pub mod contact;
pub mod generate;
pub mod geom;
pub mod lidar;
pub mod radar;
pub mod radar_stats;
pub mod rng;
pub mod splits;
pub mod tables;
pub mod world;

use std::path::{Path, PathBuf};

pub use contact::contact_sheet;
pub use generate::{profile_stages, StageTimes, MARKER_FILE, TRUTH_DIR};

/// Weather / light condition of a synthetic scene. The scene description starts with
/// "Night, " or "Rain, " as in nuScenes (SPEC §2), day scenes carry neither word.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Weather {
    Day = 0,
    Night = 1,
    Rain = 2,
}

impl depthsense_base::words::Words for Weather {
    const WHAT: &'static str = "weather";
    const WORDS: &'static [(&'static str, Self)] = &[
        ("day", Weather::Day),
        ("night", Weather::Night),
        ("rain", Weather::Rain),
    ];
}

impl Weather {
    pub fn parse(s: &str) -> Option<Weather> {
        <Self as depthsense_base::words::Words>::from_word(s)
    }
    pub fn name(self) -> &'static str {
        depthsense_base::words::Words::word(self)
    }
}

/// What to generate.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthConfig {
    pub scenes: usize,
    /// Keyframes (2 Hz samples) per scene.
    pub keyframes_per_scene: usize,
    pub seed: u64,
    /// Condition mix: (condition, weight); scenes are allocated in proportion, deterministically.
    pub conditions: Vec<(Weather, f64)>,
    /// Name of the version folder ("v1.0-synth").
    pub version_name: String,
    /// Worker threads (0 = all cores). Output does not depend on it.
    pub jobs: usize,
    /// CAM_FRONT rays per pixel: 1 = one ray per pixel (default); 2 = one ray per 2×2 pixels,
    /// its colour and depth filling them (4× fewer rays; the training frame, a 2×2 average of
    /// the image, then equals that coarse render). `synth --camera-scale`.
    pub camera_scale: u32,
    /// LIDAR_TOP sweeps written: every 20 Hz sweep (None, default: nuScenes-complete), or the
    /// keyframe sweeps and the K sweeps on each side of them (Some(K): what `prepare
    /// --lidar-sweeps K` reads; the others are left out of the files and the tables, and the
    /// sweeps kept are those of the full world). `synth --lidar-sweeps`.
    pub lidar_sweeps: Option<usize>,
    /// Write the exact camera depth of every camera frame (`truth/`, not a nuScenes file; used
    /// by tests and the contact sheet). `synth --no-truth` leaves it out.
    pub truth: bool,
    /// Radar sweeps written per radar: every ≈13 Hz sweep (None, default), or only the N
    /// sweeps up to each keyframe (Some(N): what `prepare --radar-sweeps N` reads).
    pub radar_sweeps: Option<usize>,
    /// Encode CAM_FRONT as 4:2:0 JPEG (as nuScenes' own images are) with the `jpeg-encoder`
    /// crate, four times faster; default false: 4:4:4 by the `image` crate, the encoder of every
    /// world made before this option.
    pub jpeg_420: bool,
}

impl Default for SynthConfig {
    fn default() -> Self {
        SynthConfig {
            scenes: 10,
            keyframes_per_scene: 20,
            seed: 0,
            conditions: vec![
                (Weather::Day, 0.5),
                (Weather::Night, 0.25),
                (Weather::Rain, 0.25),
            ],
            version_name: "v1.0-synth".into(),
            jobs: 0,
            camera_scale: 1,
            lidar_sweeps: None,
            truth: true,
            radar_sweeps: None,
            jpeg_420: false,
        }
    }
}

impl SynthConfig {
    /// Small and fast, for `depthsense demo`: 8 scenes × 10 keyframes (4 day, 2 night, 2 rain).
    pub fn demo() -> Self {
        SynthConfig {
            scenes: 8,
            keyframes_per_scene: 10,
            ..SynthConfig::default()
        }
    }

    /// The lean world of the experiments (`synth --lean`): one camera ray per 2×2 pixels, the
    /// lidar sweeps `prepare --lidar-sweeps 2` reads and the radar sweeps `prepare` reads by
    /// default (5), no truth maps, 4:2:0 JPEG.
    pub fn apply_lean(&mut self) {
        self.camera_scale = 2;
        self.lidar_sweeps = Some(2);
        self.radar_sweeps = Some(5);
        self.truth = false;
        self.jpeg_420 = true;
    }

    /// Tiny, for tests: 3 scenes (day, night, rain) × 2 keyframes.
    pub fn tiny() -> Self {
        SynthConfig {
            scenes: 3,
            keyframes_per_scene: 2,
            conditions: vec![
                (Weather::Day, 1.0),
                (Weather::Night, 1.0),
                (Weather::Rain, 1.0),
            ],
            ..SynthConfig::default()
        }
    }

    /// Parse a condition mix such as "day,night,rain" or "day=0.5,night=0.3,rain=0.2".
    pub fn parse_conditions(s: &str) -> Result<Vec<(Weather, f64)>, SynthError> {
        let mut out = Vec::new();
        for part in s.split(',').filter(|p| !p.trim().is_empty()) {
            let (name, w) = match part.split_once(['=', ':']) {
                Some((n, w)) => {
                    let w: f64 = w.trim().parse().map_err(|_| {
                        SynthError::Config(format!(
                            "condition weight {w:?} in {part:?} is not a number"
                        ))
                    })?;
                    (n, w)
                }
                None => (part, 1.0),
            };
            let c = Weather::parse(name).ok_or_else(|| {
                SynthError::Config(format!("unknown condition {name:?} (use day, night, rain)"))
            })?;
            if !(w.is_finite() && w >= 0.0) {
                return Err(SynthError::Config(format!(
                    "condition weight of {name} must be ≥ 0"
                )));
            }
            out.push((c, w));
        }
        if out.is_empty() || out.iter().all(|c| c.1 <= 0.0) {
            return Err(SynthError::Config(format!(
                "no condition with a positive weight in {s:?}"
            )));
        }
        Ok(out)
    }

    pub fn validate(&self) -> Result<(), SynthError> {
        if self.scenes == 0 {
            return Err(SynthError::Config("scenes must be ≥ 1".into()));
        }
        if self.keyframes_per_scene == 0 {
            return Err(SynthError::Config("keyframes per scene must be ≥ 1".into()));
        }
        if self.keyframes_per_scene > 400 {
            return Err(SynthError::Config(
                "keyframes per scene must be ≤ 400 (200 s)".into(),
            ));
        }
        if self.conditions.is_empty() || self.conditions.iter().all(|c| c.1.is_nan() || c.1 <= 0.0)
        {
            return Err(SynthError::Config(
                "the condition mix has no positive weight".into(),
            ));
        }
        if self.version_name.is_empty()
            || self.version_name.contains(['/', '\\'])
            || self.version_name.starts_with('.')
        {
            return Err(SynthError::Config(format!(
                "bad version name {:?}",
                self.version_name
            )));
        }
        Ok(())
    }
}

/// What was generated.
#[derive(Debug, Clone)]
pub struct SynthSummary {
    pub keyframes: usize,
    pub scenes: usize,
    /// Scenes per condition: [day, night, rain].
    pub conditions: [usize; 3],
    pub sample_data: usize,
    pub files: usize,
    pub bytes: u64,
    pub version_dir: PathBuf,
    pub seconds: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("invalid synth configuration: {0}")]
    Config(String),
    #[error("{0} exists, is not empty and is not a synthetic world (no {MARKER_FILE}); choose another output folder")]
    Exists(String),
    #[error("encoding failed: {0}")]
    Encode(String),
    #[error("{0}")]
    Data(String),
}

/// Generate the synthetic world into the dataroot `out` (created; a previous synthetic world
/// there is replaced, anything else is refused). The dataroot is assembled in a temporary
/// sibling folder and renamed into place, so it is never half-written.
pub fn generate(
    out: &Path,
    cfg: &SynthConfig,
    progress: &depthsense_progress::Progress,
) -> Result<SynthSummary, SynthError> {
    generate::generate(out, cfg, progress)
}
