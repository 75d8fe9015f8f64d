//! `depthsense predict --dataroot D --token T1,T2,…`, `--tokens FILE` or `--calibration
//! C1.json C2.json …` (without --image): a list of raw frames, pipelined
//! (`depthsense_eval::predict_frames`), each frame's outputs in OUT/<token or calibration>/.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use depthsense_cli::cmd::predict::Args;
use depthsense_cli::cmd::progress::progress_bar;
use depthsense_dataset::outputs::refuse_existing;
use depthsense_eval::predict::{
    input_from_raw, input_from_tables, predict, radar_warnings, trained_radar_settings,
    write_outputs, PredictInput, OUTPUT_FILES,
};
use depthsense_eval::predict_frames::{predict_frames, Stages};
use depthsense_infer::NetError;
use depthsense_model::precision::InferenceLayout;
use depthsense_nuscenes::depth_png::DepthMap;
use depthsense_prep::calibration::RadarSettings;

/// Where a list's frames come from.
enum Frames {
    /// Sample tokens of a dataroot, its tables loaded once.
    Tokens {
        nu: Box<depthsense_nuscenes::tables::NuScenes>,
        tokens: Vec<String>,
        opts: depthsense_prep::PrepareOptions,
    },
    /// Calibration JSONs, each naming its camera image and radar files.
    Calibrations(Vec<(String, PathBuf, PathBuf)>),
}

impl Frames {
    fn len(&self) -> usize {
        match self {
            Frames::Tokens { tokens, .. } => tokens.len(),
            Frames::Calibrations(c) => c.len(),
        }
    }

    /// Frame `i`'s input, named as its output folder.
    fn load(&self, i: usize, radar_filters: bool) -> Result<PredictInput, NetError> {
        Ok(match self {
            Frames::Tokens { nu, tokens, opts } => input_from_tables(nu, tokens[i].as_str(), opts)?,
            Frames::Calibrations(c) => {
                let (name, jpeg, calib) = &c[i];
                let mut input = input_from_raw(jpeg, &[], calib, radar_filters)?;
                input.name = name.clone();
                input
            }
        })
    }

    /// The output folder names, in order.
    fn names(&self) -> Vec<String> {
        match self {
            Frames::Tokens { tokens, .. } => tokens.clone(),
            Frames::Calibrations(c) => c.iter().map(|(n, ..)| n.clone()).collect(),
        }
    }

    /// Token frames are built with the radar settings the network was trained with (known once
    /// it is loaded; calibrations name their radar files themselves).
    fn trained_with(&mut self, a: &Args, trained: Option<&RadarSettings>) -> anyhow::Result<()> {
        if let Frames::Tokens { opts, .. } = self {
            *opts = super::predict::token_prepare_options(a, trained)?;
        }
        Ok(())
    }
}

/// Runs the list: every frame checked (tokens against the dataroot's tables, calibrations
/// for their image) before the network loads.
pub fn run(a: &Args) -> anyhow::Result<ExitCode> {
    let device = depthsense_model::device::parse_device(&a.device.name)?;
    let mut frames = frames_of(a)?;
    let loaded = super::model_source::load(&a.model, device, InferenceLayout::Fastest)?;
    let trained =
        trained_radar_settings(&loaded.extra).or_else(|| super::predict::sidecar_radar(a));
    frames.trained_with(a, trained.as_ref())?;
    let files: Vec<PathBuf> = frames
        .names()
        .iter()
        .flat_map(|t| OUTPUT_FILES.iter().map(move |f| a.out.join(t).join(f)))
        .collect();
    refuse_existing(&files, a.force, "predict")?;
    let radar = loaded.config.radar_input_for(None)?;
    let pda = match &a.mer_checkpoint {
        Some(ck) => Some(depthsense_checkpoint::pda::load(ck, device)?),
        None => None,
    };
    let pb = progress_bar("predict");
    // Radar settings that differ from the training's: each warning said once.
    let mut warned = std::collections::HashSet::new();
    let stats = predict_frames(
        Stages {
            n: frames.len(),
            loaders: depthsense_data::loader_threads(a.jobs),
            load: |i: usize| frames.load(i, !a.no_radar_filters),
            network: |input: &mut PredictInput| {
                for w in radar_warnings(trained.as_ref(), input) {
                    if warned.insert(w.clone()) {
                        pb.println(w);
                    }
                }
                if let Some(p) = &pda {
                    depthsense_eval::predict::attach_mer(input, &p.net, device)?;
                }
                predict(&loaded.net, input, radar, device)
            },
            write: |input: &PredictInput, depth: &DepthMap| -> Result<(), NetError> {
                write_outputs(&a.out.join(&input.name), input, depth, a.max_depth).map(drop)
            },
        },
        &pb,
    )?;
    pb.finish_and_clear();
    eprintln!(
        "{} frames written to {}/<frame>/ ({})",
        stats.images,
        a.out.display(),
        OUTPUT_FILES.join(", ")
    );
    eprintln!("{}", stats.summary(1));
    Ok(ExitCode::SUCCESS)
}

/// The list the command line names, checked before the network loads: tokens (against the
/// dataroot's tables) or calibrations (which take no --radar).
fn frames_of(a: &Args) -> anyhow::Result<Frames> {
    if a.calibration.is_empty() {
        return token_frames(a);
    }
    if !a.radar.is_empty() {
        anyhow::bail!(
            "--radar picks the radar files of one --image; a list of calibrations uses every \
             file each one names"
        );
    }
    Ok(Frames::Calibrations(calibration_frames(&a.calibration)?))
}

/// The token list of --token / --tokens, checked against the dataroot's tables (the radar
/// settings: `Frames::trained_with`).
fn token_frames(a: &Args) -> anyhow::Result<Frames> {
    let tokens = token_list(a)?;
    let opts = super::predict::token_prepare_options(a, None)?;
    let nu = depthsense_nuscenes::tables::NuScenes::load(&opts.dataroot, &a.version)
        .with_context(|| format!("reading the tables of {}", opts.dataroot.display()))?;
    check_tokens(&nu, &tokens, &opts.dataroot, &a.version)?;
    Ok(Frames::Tokens {
        nu: Box::new(nu),
        tokens,
        opts,
    })
}

/// Each calibration with its image (`camera_file`) and its output folder's name (the file's
/// stem, unique in the list); the ones that name no image, or a missing one, named at once.
fn calibration_frames(list: &[PathBuf]) -> anyhow::Result<Vec<(String, PathBuf, PathBuf)>> {
    let mut frames = vec![];
    let mut problems = vec![];
    let mut seen = std::collections::HashSet::new();
    for c in list {
        let name = c
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        if !seen.insert(name.clone()) {
            anyhow::bail!(
                "two calibrations named {name} would write one folder OUT/{name}/: give each \
                 frame once, with distinct file names"
            );
        }
        let calib = depthsense_prep::calibration::read(c)?;
        match depthsense_prep::calibration::camera_file_of(c, &calib) {
            Some(jpeg) if jpeg.is_file() => frames.push((name, jpeg, c.clone())),
            Some(jpeg) => problems.push(format!(
                "{}: its image {} does not exist",
                c.display(),
                jpeg.display()
            )),
            None => problems.push(format!("{}: names no image (camera_file)", c.display())),
        }
    }
    if !problems.is_empty() {
        anyhow::bail!(
            "{} of {} calibrations cannot be used:\n  {}\nfor one frame give its image with \
             --image; `depthsense calibration` writes camera_file",
            problems.len(),
            list.len(),
            problems.join("\n  ")
        );
    }
    Ok(frames)
}

/// --token (repeatable, comma-separated) then the lines of --tokens, in order; a token named
/// twice is refused (its outputs would be written twice into one folder).
fn token_list(a: &Args) -> anyhow::Result<Vec<String>> {
    let mut tokens = a.token.clone();
    if let Some(f) = &a.tokens {
        tokens.extend(read_token_file(f)?);
    }
    let mut seen = std::collections::HashSet::new();
    if let Some(t) = tokens.iter().find(|t| !seen.insert(t.as_str())) {
        anyhow::bail!("sample token {t} is listed twice: give each frame once");
    }
    if tokens.is_empty() {
        anyhow::bail!(
            "{}: no sample tokens in it (one a line; blank lines and # comments are skipped)",
            a.tokens
                .as_deref()
                .unwrap_or(Path::new("--token"))
                .display()
        );
    }
    Ok(tokens)
}

/// The tokens of a list file: one a line, blank lines and `#` comments skipped.
fn read_token_file(path: &Path) -> anyhow::Result<Vec<String>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading the token list {}", path.display()))?;
    Ok(text
        .lines()
        .map(|l| l.split('#').next().unwrap_or("").trim())
        .filter(|l| !l.is_empty())
        .map(String::from)
        .collect())
}

/// Every token is a sample of the dataroot: all unknown ones named at once, before any work.
fn check_tokens(
    nu: &depthsense_nuscenes::tables::NuScenes,
    tokens: &[String],
    dataroot: &Path,
    version: &str,
) -> anyhow::Result<()> {
    let known: std::collections::HashSet<String> =
        nu.sample.iter().map(|s| s.token.to_string()).collect();
    let unknown: Vec<&str> = tokens
        .iter()
        .filter(|t| !known.contains(t.as_str()))
        .map(String::as_str)
        .collect();
    if !unknown.is_empty() {
        anyhow::bail!(
            "{}/{version}: no sample with token {} (of {} listed); the sample tokens are the \
             \"token\" fields of {version}/sample.json",
            dataroot.display(),
            unknown.join(", "),
            tokens.len()
        );
    }
    Ok(())
}
