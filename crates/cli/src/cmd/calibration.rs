//! `depthsense calibration`: the calibration JSON of `predict --image` for a sample of a
//! nuScenes dataroot — the camera intrinsics and every radar sweep `prepare` would read, each
//! with its channel, sweep index, time and sweep-sensor → keyframe-camera transform
//! (`depthsense_prep::calibration`). Torch-free.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use depthsense_nuscenes::tables::{NuScenes, Token};
use depthsense_prep::calibration::{for_sample, write};
use depthsense_prep::PrepareOptions;

#[derive(clap::Args)]
pub struct Args {
    /// nuScenes dataroot (holds samples/, sweeps/ and the version folder).
    #[arg(long)]
    pub dataroot: PathBuf,
    /// Version folder inside the dataroot.
    #[arg(long, default_value = "v1.0-mini")]
    pub version: String,
    /// The sample (keyframe) token.
    #[arg(long)]
    pub token: String,
    #[command(flatten)]
    pub radar: super::radar_args::RadarArgs,
    /// The calibration JSON to write (the radar files are listed with absolute paths).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace an existing --out.
    #[arg(long)]
    pub force: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    if a.out.exists() && !a.force {
        anyhow::bail!(
            "{} exists; nothing was changed: pass --force to replace it or choose another --out",
            a.out.display()
        );
    }
    let root = std::fs::canonicalize(&a.dataroot).unwrap_or(a.dataroot.clone());
    let nu = NuScenes::load(&root, &a.version)?;
    let want = Token::parse(&a.token);
    let sample = nu
        .sample
        .iter()
        .find(|s| s.token == want)
        .with_context(|| {
            format!(
                "{}/{}: no sample with token {} (`depthsense inspect {}/{}` lists the scenes)",
                a.dataroot.display(),
                a.version,
                a.token,
                a.dataroot.display(),
                a.version
            )
        })?;
    let mut opts = PrepareOptions::default();
    a.radar.apply(&mut opts);
    let c = for_sample(&nu, sample, &opts)?;
    write(&a.out, &c)?;
    eprintln!(
        "{} radar files ({} channel(s), up to {} sweeps each) → {}",
        c.radar.len(),
        c.settings.radar_channels.len(),
        c.settings.radar_sweeps,
        a.out.display()
    );
    println!(
        "depthsense predict --checkpoint CHECKPOINT --image {} --calibration {} --out OUT",
        c.camera_file.as_deref().unwrap_or("CAM_FRONT.jpg"),
        a.out.display()
    );
    Ok(ExitCode::SUCCESS)
}
