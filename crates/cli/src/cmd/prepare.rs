//! `depthsense prepare`: raw nuScenes → training-frame maps (SPEC §3–5).

use std::path::PathBuf;
use std::process::ExitCode;

use depthsense_prep::{prepare, PrepareOptions, PrepareSummary, Shard};
use depthsense_progress::Progress;

use crate::cmd::heading as h;

/// `prepare --help`'s examples (each parsed by the docs test through docs/guide/cli.md).
const EXAMPLES: &str = "Examples:
  depthsense prepare --dataroot data/nuscenes --version v1.0-mini --out data/prepared
  depthsense prepare --dataroot data/nuscenes --version v1.0-trainval --lidar-sweeps 10 --out data/prepared
  depthsense prepare --dataroot data/nuscenes --version v1.0-trainval --lidar-sweeps 10 --out data/prepared --shard 3/16
  depthsense prepare --dataroot data/synth --version v1.0-synth --lidar-sweeps 2 --out data/synth-prepared
(docs/guide/prepare.md: splits, sweeps, sharding, verifying)";

#[derive(clap::Args)]
#[command(after_help = EXAMPLES)]
pub struct Args {
    /// nuScenes dataroot (holds samples/, sweeps/ and the version folder).
    #[arg(long, help_heading = h::DATA)]
    dataroot: PathBuf,
    /// Version folder inside the dataroot: v1.0-mini, v1.0-trainval, v1.0-test, v1.0-synth, …
    #[arg(long, help_heading = h::DATA, default_value = "v1.0-mini")]
    version: String,
    /// Output directory: one sub-directory per keyframe plus index.json.
    #[arg(long, help_heading = h::OUTPUT)]
    out: PathBuf,
    /// Scene split: train, test, test-day, test-night, test-rain, official-train,
    /// official-val or all (synthetic worlds have their own scene tokens: use all).
    #[arg(long, help_heading = h::DATA, default_value = "all")]
    split: String,
    #[command(flatten, next_help_heading = h::RADAR)]
    radar: super::radar_args::RadarArgs,
    /// K: the dense lidar target accumulates the keyframe sweep ±K sweeps (0 = keyframe only).
    #[arg(long, help_heading = h::DATA, default_value_t = 0)]
    lidar_sweeps: usize,
    /// Worker threads (0 = all cores).
    #[arg(long, help_heading = h::DEVICE, default_value_t = 0)]
    jobs: usize,
    /// Exit with status 0 even when some samples failed (they are still listed).
    #[arg(long, help_heading = h::OUTPUT)]
    keep_going: bool,
    /// Prepare only part I of N (0-based; by scene, disjoint and deterministic), e.g.
    /// `--shard $SLURM_ARRAY_TASK_ID/16`. The part's index goes to
    /// OUT/index.shard-I-of-N.json; combine the parts with `depthsense index merge OUT`.
    #[arg(long, help_heading = h::OUTPUT, value_name = "I/N")]
    shard: Option<String>,
    /// Re-read every sample already in --out (each PNG, meta.json, radar_points.bin) and
    /// prepare the broken ones again (a truncated copy, a disk error); the others are kept.
    /// Add it to the command that wrote the folder when `train`, `eval` or `predict` report an
    /// unreadable sample.
    #[arg(long, help_heading = h::OUTPUT)]
    verify: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let shard = a.shard.as_deref().map(str::parse::<Shard>).transpose()?;
    let mut opts = PrepareOptions {
        dataroot: a.dataroot,
        version: a.version,
        out: a.out,
        split: a.split,
        lidar_sweeps: a.lidar_sweeps,
        jobs: a.jobs,
        keep_going: a.keep_going,
        shard,
        verify: a.verify,
        ..PrepareOptions::default()
    };
    a.radar.apply(&mut opts);
    let pb = Progress::new("prepare");
    pb.enable_steady_tick(std::time::Duration::from_millis(200));
    let t = std::time::Instant::now();
    let s = prepare(&opts, &pb)?;
    pb.finish_and_clear();
    let secs = t.elapsed().as_secs_f64();
    print_summary(&opts, &s, secs);
    if !s.failed.is_empty() && !opts.keep_going {
        eprintln!("(use --keep-going to exit 0 despite failed samples)");
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}

/// What `prepare` did: the failed samples, the verified ones, the counts and seconds, and for
/// a shard where its index went.
fn print_summary(opts: &PrepareOptions, s: &PrepareSummary, secs: f64) {
    for (token, reason) in &s.failed {
        eprintln!("failed {token}: {reason}");
    }
    if opts.verify {
        eprintln!(
            "verified {} samples already there: {} broken, prepared again{}",
            s.verified,
            s.rebuilt.len(),
            if s.mer_lost > 0 {
                format!(
                    " ({} of them had MER maps: run `depthsense mer apply --checkpoint PDA --data {}` again)",
                    s.mer_lost,
                    opts.out.display()
                )
            } else {
                String::new()
            }
        );
    }
    eprintln!(
        "prepared {} keyframes in {secs:.1} s ({:.1}/s), {} already done, {} failed → {}",
        s.prepared,
        s.prepared as f64 / secs.max(1e-9),
        s.skipped_existing,
        s.failed.len(),
        opts.out.display()
    );
    if let Some(sh) = opts.shard {
        eprintln!(
            "shard {sh}: index in {}; when every shard is done: depthsense index merge {}",
            opts.out
                .join(depthsense_prep::layout::shard_index_file(
                    sh.index, sh.count
                ))
                .display(),
            opts.out.display()
        );
    }
}
