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

use depthsense_nuscenes::depth_png::DepthPngError;
use depthsense_nuscenes::{NuError, Token};

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
                    let w: f64 =
                        w.trim()
                            .parse()
                            .map_err(|_| SynthError::ConditionWeightNotANumber {
                                weight: w.to_string(),
                                part: part.to_string(),
                            })?;
                    (n, w)
                }
                None => (part, 1.0),
            };
            let c = Weather::parse(name).ok_or_else(|| SynthError::UnknownCondition {
                name: name.to_string(),
            })?;
            if !(w.is_finite() && w >= 0.0) {
                return Err(SynthError::BadConditionWeight {
                    name: name.to_string(),
                    weight: w,
                });
            }
            out.push((c, w));
        }
        if out.is_empty() || out.iter().all(|c| c.1 <= 0.0) {
            return Err(SynthError::NoPositiveWeight {
                mix: Some(s.to_string()),
            });
        }
        Ok(out)
    }

    pub fn validate(&self) -> Result<(), SynthError> {
        if self.scenes == 0 {
            return Err(SynthError::ZeroScenes);
        }
        if self.keyframes_per_scene == 0 || self.keyframes_per_scene > MAX_KEYFRAMES_PER_SCENE {
            return Err(SynthError::KeyframesPerScene {
                keyframes: self.keyframes_per_scene,
            });
        }
        if self.conditions.is_empty() || self.conditions.iter().all(|c| c.1.is_nan() || c.1 <= 0.0)
        {
            return Err(SynthError::NoPositiveWeight { mix: None });
        }
        if self.version_name.is_empty()
            || self.version_name.contains(['/', '\\'])
            || self.version_name.starts_with('.')
        {
            return Err(SynthError::BadVersionName {
                name: self.version_name.clone(),
            });
        }
        Ok(())
    }
}

/// The most keyframes a scene may have (200 s at 2 Hz).
pub const MAX_KEYFRAMES_PER_SCENE: usize = 400;

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

/// Why a synthetic world, its timing or a contact sheet could not be made: each names the
/// setting, file, scene or sample at fault.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The output folder exists, holds files and is not a synthetic world (no marker file):
    /// it is not replaced.
    #[error(
        "{} exists, is not empty and is not a synthetic world (no {MARKER_FILE}); choose \
         another output folder",
        .0.display()
    )]
    Exists(PathBuf),

    // --- The configuration: the condition mix (`synth --conditions`), the world's sizes ---
    /// A condition weight (`weight`, as written in the part `part` of the mix) that is not a
    /// number.
    #[error(
        "invalid synth configuration: condition weight {weight:?} in {part:?} is not a number"
    )]
    ConditionWeightNotANumber { weight: String, part: String },
    /// A condition name (`name`, as written in the mix) that is not day, night or rain.
    #[error("invalid synth configuration: unknown condition {name:?} (use day, night, rain)")]
    UnknownCondition { name: String },
    /// The weight (`weight`) of condition `name` (as written in the mix) that is negative or
    /// not finite.
    #[error("invalid synth configuration: condition weight of {name} must be ≥ 0")]
    BadConditionWeight { name: String, weight: f64 },
    /// A condition mix in which no condition has a positive weight: the text `mix` of
    /// `synth --conditions`, or (`None`) a configuration's parsed mix.
    #[error("invalid synth configuration: {}", no_positive_weight_text(.mix.as_deref()))]
    NoPositiveWeight { mix: Option<String> },
    /// A world of no scenes.
    #[error("invalid synth configuration: scenes must be ≥ 1")]
    ZeroScenes,
    /// Scenes of `keyframes` keyframes: none, or more than [`MAX_KEYFRAMES_PER_SCENE`].
    #[error("invalid synth configuration: {}", keyframes_per_scene_text(*.keyframes))]
    KeyframesPerScene { keyframes: usize },
    /// A version folder name (`name`) that is empty, hidden or not one folder.
    #[error("invalid synth configuration: bad version name {name:?}")]
    BadVersionName { name: String },
    /// The `jobs` worker threads (0: one per core) that the system would not start.
    #[error("invalid synth configuration: thread pool: {source}")]
    ThreadPool {
        jobs: usize,
        #[source]
        source: rayon::ThreadPoolBuildError,
    },

    // --- Encoding the world's files ---
    /// The 13 tables that cannot be written as JSON.
    #[error("encoding failed: tables: {source}")]
    Tables {
        #[source]
        source: serde_json::Error,
    },
    /// The marker file's configuration that cannot be written as JSON.
    #[error("encoding failed: {source}")]
    Marker {
        #[source]
        source: serde_json::Error,
    },
    /// A CAM_FRONT frame (`file`, relative to the dataroot) that cannot be encoded as JPEG.
    #[error("encoding failed: {}: {source}", .file.display())]
    CameraJpeg {
        file: PathBuf,
        #[source]
        source: JpegError,
    },
    /// The exact depth of a CAM_FRONT frame (`file`, relative to the dataroot) that cannot be
    /// encoded as a 16-bit PNG.
    #[error("encoding failed: {}: {source}", .file.display())]
    TruthPng {
        file: PathBuf,
        #[source]
        source: DepthPngError,
    },
    /// The city map's pixels that do not fill its `width` x `height` image.
    #[error("encoding failed: map buffer size")]
    MapBuffer { width: u32, height: u32 },
    /// The city map that cannot be encoded as PNG.
    #[error("encoding failed: map png: {source}")]
    MapPng {
        #[source]
        source: image::ImageError,
    },
    /// A contact sheet that cannot be encoded as PNG.
    #[error("encoding failed: contact sheet: {source}")]
    ContactSheetPng {
        #[source]
        source: image::ImageError,
    },
    /// A camera frame that cannot be encoded as JPEG while its stages are timed.
    #[error("encoding failed: {source}")]
    ProfileJpeg {
        #[source]
        source: image::ImageError,
    },
    /// A depth map that cannot be encoded as PNG while its stages are timed.
    #[error("encoding failed: {source}")]
    ProfilePng {
        #[source]
        source: DepthPngError,
    },

    // --- Reading a dataroot (the contact sheet) ---
    /// A table or sensor file of the dataroot that cannot be read.
    #[error("{0}")]
    NuScenes(#[from] NuError),
    /// A dataroot (`dataroot`) whose version has no scene to show.
    #[error("{}: no scenes", .dataroot.display())]
    NoScenes { dataroot: PathBuf },
    /// A scene (token `scene`) without samples.
    #[error("scene {scene} has no samples")]
    SceneWithoutSamples { scene: Token },
    /// A sample (token `sample`) without a keyframe of sensor channel `channel`.
    #[error("sample {sample} has no {channel} keyframe")]
    NoKeyframe {
        sample: Token,
        channel: &'static str,
    },
    /// The CAM_FRONT calibration (calibrated_sensor token `calibrated_sensor`) without its
    /// camera matrix.
    #[error("calibrated_sensor {calibrated_sensor}: CAM_FRONT has no 3x3 camera_intrinsic")]
    NoCameraIntrinsic { calibrated_sensor: Token },
    /// A CAM_FRONT image (`path`) that cannot be read or decoded.
    #[error("{}: {source}", .path.display())]
    CameraImage {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    /// A keyframe's exact depth map (in `truth/`) that cannot be read.
    #[error("{source}")]
    TruthMap {
        #[source]
        source: DepthPngError,
    },
}

/// Why a CAM_FRONT frame cannot be encoded as JPEG: the error of the encoder asked for.
#[derive(Debug, thiserror::Error)]
pub enum JpegError {
    /// `jpeg-encoder`'s (4:2:0).
    #[error(transparent)]
    Subsampled(#[from] jpeg_encoder::EncodingError),
    /// The `image` crate's (4:4:4).
    #[error(transparent)]
    Full(#[from] image::ImageError),
}

fn no_positive_weight_text(mix: Option<&str>) -> String {
    match mix {
        Some(mix) => format!("no condition with a positive weight in {mix:?}"),
        None => "the condition mix has no positive weight".into(),
    }
}

fn keyframes_per_scene_text(keyframes: usize) -> String {
    if keyframes == 0 {
        "keyframes per scene must be ≥ 1".into()
    } else {
        format!("keyframes per scene must be ≤ {MAX_KEYFRAMES_PER_SCENE} (200 s)")
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A refused configuration carries the words and numbers at fault, and reads as the
    /// strings it replaced did.
    #[test]
    fn configuration_refusals_carry_what_is_wrong() {
        let e = SynthConfig::parse_conditions("day=x,rain").unwrap_err();
        assert!(
            matches!(&e, SynthError::ConditionWeightNotANumber { weight, part }
                if weight == "x" && part == "day=x"),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            "invalid synth configuration: condition weight \"x\" in \"day=x\" is not a number"
        );
        let e = SynthConfig::parse_conditions("fog").unwrap_err();
        assert!(
            matches!(&e, SynthError::UnknownCondition { name } if name == "fog"),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            "invalid synth configuration: unknown condition \"fog\" (use day, night, rain)"
        );
        let e = SynthConfig::parse_conditions("day=-1").unwrap_err();
        assert!(
            matches!(&e, SynthError::BadConditionWeight { name, weight }
                if name == "day" && *weight == -1.0),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            "invalid synth configuration: condition weight of day must be ≥ 0"
        );
        let e = SynthConfig::parse_conditions("day=0").unwrap_err();
        assert!(
            matches!(&e, SynthError::NoPositiveWeight { mix: Some(m) } if m == "day=0"),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            "invalid synth configuration: no condition with a positive weight in \"day=0\""
        );
        let refusal = |cfg: SynthConfig| cfg.validate().unwrap_err();
        let e = refusal(SynthConfig {
            keyframes_per_scene: 401,
            ..SynthConfig::default()
        });
        assert!(
            matches!(e, SynthError::KeyframesPerScene { keyframes: 401 }),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            "invalid synth configuration: keyframes per scene must be ≤ 400 (200 s)"
        );
        let e = refusal(SynthConfig {
            keyframes_per_scene: 0,
            ..SynthConfig::default()
        });
        assert_eq!(
            e.to_string(),
            "invalid synth configuration: keyframes per scene must be ≥ 1"
        );
        let e = refusal(SynthConfig {
            scenes: 0,
            ..SynthConfig::default()
        });
        assert!(matches!(e, SynthError::ZeroScenes), "{e:?}");
        assert_eq!(
            e.to_string(),
            "invalid synth configuration: scenes must be ≥ 1"
        );
        let e = refusal(SynthConfig {
            conditions: vec![(Weather::Day, 0.0), (Weather::Rain, f64::NAN)],
            ..SynthConfig::default()
        });
        assert!(
            matches!(e, SynthError::NoPositiveWeight { mix: None }),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            "invalid synth configuration: the condition mix has no positive weight"
        );
        let e = refusal(SynthConfig {
            version_name: "../x".into(),
            ..SynthConfig::default()
        });
        assert!(
            matches!(&e, SynthError::BadVersionName { name } if name == "../x"),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            "invalid synth configuration: bad version name \"../x\""
        );
    }

    /// The refusals of an output folder, an encoder and a dataroot read as they always have.
    #[test]
    fn output_encoding_and_dataroot_messages() {
        let token = Token::parse;
        let cases = [
            (
                SynthError::Exists(PathBuf::from("out/world")),
                format!(
                    "out/world exists, is not empty and is not a synthetic world (no \
                     {MARKER_FILE}); choose another output folder"
                ),
            ),
            (
                SynthError::MapBuffer {
                    width: 4,
                    height: 2,
                },
                "encoding failed: map buffer size".into(),
            ),
            (
                SynthError::TruthPng {
                    file: "truth/abc.png".into(),
                    source: DepthPngError::Size {
                        width: 2,
                        height: 1,
                        got: 1,
                        want: 2,
                    },
                },
                "encoding failed: truth/abc.png: depth map has 1 values but 2x1 needs 2".into(),
            ),
            (
                SynthError::NoScenes {
                    dataroot: "nu".into(),
                },
                "nu: no scenes".into(),
            ),
            (
                SynthError::NoKeyframe {
                    sample: token("0123456789abcdef0123456789abcdef"),
                    channel: "LIDAR_TOP",
                },
                "sample 0123456789abcdef0123456789abcdef has no LIDAR_TOP keyframe".into(),
            ),
            (
                SynthError::SceneWithoutSamples {
                    scene: token("1000000000000000000000000000000a"),
                },
                "scene 1000000000000000000000000000000a has no samples".into(),
            ),
            (
                SynthError::NoCameraIntrinsic {
                    calibrated_sensor: token("2000000000000000000000000000000b"),
                },
                "calibrated_sensor 2000000000000000000000000000000b: CAM_FRONT has no 3x3 \
                 camera_intrinsic"
                    .into(),
            ),
        ];
        for (e, text) in cases {
            assert_eq!(e.to_string(), text);
        }
    }

    /// A dataroot that cannot be read is the reader's own error, its message and cause kept.
    #[test]
    fn contact_sheet_of_a_missing_dataroot_is_the_readers_error() {
        let dir = tempfile::tempdir().unwrap();
        let e = contact_sheet(
            &dir.path().join("nowhere"),
            "v1.0-synth",
            &dir.path().join("sheet.png"),
        )
        .unwrap_err();
        let SynthError::NuScenes(nu) = &e else {
            panic!("{e:?}")
        };
        assert_eq!(e.to_string(), nu.to_string());
        assert!(!dir.path().join("sheet.png").exists());
    }
}
