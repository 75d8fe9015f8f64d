//! `depthsense predict --dataroot D --token T1,T2,…` or `--tokens FILE`: a list of raw frames,
//! pipelined (`depthsense_eval::predict_frames`), each frame's outputs in OUT/<token>/.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use depthsense_cli::cmd::predict::Args;
use depthsense_cli::cmd::progress::progress_bar;
use depthsense_dataset::outputs::refuse_existing;
use depthsense_eval::predict::{
    input_from_tables, predict, trained_radar_settings, write_outputs, PredictInput, OUTPUT_FILES,
};
use depthsense_eval::predict_frames::{predict_frames, Stages};
use depthsense_infer::NetError;
use depthsense_model::precision::InferenceLayout;
use depthsense_nuscenes::depth_png::DepthMap;

/// Runs the list: every token checked against the dataroot's tables before the network loads.
pub fn run(a: &Args) -> anyhow::Result<ExitCode> {
    let tokens = token_list(a)?;
    let files: Vec<PathBuf> = tokens
        .iter()
        .flat_map(|t| OUTPUT_FILES.iter().map(move |f| a.out.join(t).join(f)))
        .collect();
    refuse_existing(&files, a.force, "predict")?;
    let device = depthsense_model::device::parse_device(&a.device.name)?;
    let loaded = super::model_source::load(&a.model, device, InferenceLayout::Fastest)?;
    let trained =
        trained_radar_settings(&loaded.extra).or_else(|| super::predict::sidecar_radar(a));
    let opts = super::predict::token_prepare_options(a, trained.as_ref())?;
    let nu = depthsense_nuscenes::tables::NuScenes::load(&opts.dataroot, &a.version)
        .with_context(|| format!("reading the tables of {}", opts.dataroot.display()))?;
    check_tokens(&nu, &tokens, &opts.dataroot, &a.version)?;
    let radar = loaded.config.radar_input_for(None)?;
    let pda = match &a.mer_checkpoint {
        Some(ck) => Some(depthsense_checkpoint::pda::load(ck, device)?),
        None => None,
    };
    let pb = progress_bar("predict");
    let stats = predict_frames(
        Stages {
            n: tokens.len(),
            loaders: depthsense_data::loader_threads(a.jobs),
            load: |i: usize| Ok(input_from_tables(&nu, tokens[i].as_str(), &opts)?),
            network: |input: &mut PredictInput| {
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
        "{} frames written to {}/<token>/ ({})",
        stats.images,
        a.out.display(),
        OUTPUT_FILES.join(", ")
    );
    eprintln!("{}", stats.summary(1));
    Ok(ExitCode::SUCCESS)
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
