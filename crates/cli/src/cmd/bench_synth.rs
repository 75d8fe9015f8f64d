//! `depthsense bench synth`: synthetic world generation throughput (keyframes per second,
//! including every sweep and file) and the single-thread time of each stage.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use depthsense_synth::{StageTimes, SynthConfig, SynthSummary, Weather};

#[derive(clap::Args)]
pub struct Args {
    /// Where the JSON report is written (also printed).
    #[arg(long, default_value = "bench-synth.json")]
    out: PathBuf,
    /// Scenes of the generated world.
    #[arg(long, default_value_t = 10)]
    scenes: usize,
    /// Keyframes per scene.
    #[arg(long, default_value_t = 20)]
    keyframes_per_scene: usize,
    /// Seed of the world.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    jobs: usize,
    /// Frames per stage for the single-thread stage timings (0 skips them).
    #[arg(long, default_value_t = 4)]
    profile_frames: usize,
    /// Scratch directory for the generated world (default: the system temp dir); the world is
    /// removed afterwards unless --keep is given.
    #[arg(long)]
    work: Option<PathBuf>,
    /// Keep the generated world.
    #[arg(long)]
    keep: bool,
    /// The lean world of the experiments (`synth --lean`) instead of the full one.
    #[arg(long)]
    lean: bool,
}

/// Process CPU time (user + system) in seconds from /proc/self/stat (Linux, USER_HZ = 100).
fn cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ut: f64 = f.get(11)?.parse().ok()?;
    let st: f64 = f.get(12)?.parse().ok()?;
    Some((ut + st) / 100.0)
}

/// A generated world with its timings.
struct TimedWorld {
    /// Where it was generated (removed by then unless --keep).
    root: PathBuf,
    summary: SynthSummary,
    wall_s: f64,
    /// Process CPU seconds of the generation (`None` off Linux).
    cpu_s: Option<f64>,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let mut cfg = SynthConfig {
        scenes: a.scenes,
        keyframes_per_scene: a.keyframes_per_scene,
        seed: a.seed,
        jobs: a.jobs,
        ..SynthConfig::default()
    };
    if a.lean {
        cfg.apply_lean();
    }
    let world = generate_timed(&a, &cfg)?;
    let stages = if a.profile_frames > 0 {
        Some(depthsense_synth::profile_stages(a.seed, a.profile_frames)?)
    } else {
        None
    };
    let report = report_json(&a, &world, stages);
    let text = serde_json::to_string_pretty(&report)?;
    depthsense_base::fsutil::write_atomic(&a.out, text.as_bytes())
        .with_context(|| format!("writing {}", a.out.display()))?;
    println!("{text}");
    Ok(ExitCode::SUCCESS)
}

/// Generate the world under --work (or the temp dir), timed; removed afterwards unless --keep.
fn generate_timed(a: &Args, cfg: &SynthConfig) -> anyhow::Result<TimedWorld> {
    let base = a.work.clone().unwrap_or_else(std::env::temp_dir);
    std::fs::create_dir_all(&base).with_context(|| format!("creating {}", base.display()))?;
    let root = base.join(format!("depthsense-bench-synth-{}", std::process::id()));
    let pb = depthsense_progress::Progress::new("bench synth");
    let cpu0 = cpu_seconds();
    let t = Instant::now();
    let summary = depthsense_synth::generate(&root, cfg, &pb)?;
    let wall_s = t.elapsed().as_secs_f64();
    let cpu_s = match (cpu0, cpu_seconds()) {
        (Some(a), Some(b)) => Some(b - a),
        _ => None,
    };
    pb.finish_and_clear();
    if !a.keep {
        std::fs::remove_dir_all(&root).with_context(|| format!("removing {}", root.display()))?;
    }
    Ok(TimedWorld {
        root,
        summary,
        wall_s,
        cpu_s,
    })
}

/// The JSON report: machine, configuration, world size, throughput and stage times.
fn report_json(a: &Args, world: &TimedWorld, stages: Option<StageTimes>) -> serde_json::Value {
    let s = &world.summary;
    let wall = world.wall_s;
    let threads = if a.jobs == 0 {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    } else {
        a.jobs
    };
    serde_json::json!({
        "benchmark": "synth",
        "machine": {
            "threads": threads,
            "available_parallelism": std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
            "os": std::env::consts::OS,
            "arch": std::env::consts::ARCH,
            "profile": if cfg!(debug_assertions) { "debug" } else { "release" },
        },
        "config": {
            "scenes": s.scenes,
            "keyframes_per_scene": a.keyframes_per_scene,
            "seed": a.seed,
            "lean": a.lean,
            "conditions": {
                "day": s.conditions[Weather::Day as usize],
                "night": s.conditions[Weather::Night as usize],
                "rain": s.conditions[Weather::Rain as usize],
            },
        },
        "keyframes": s.keyframes,
        "sample_data": s.sample_data,
        "files": s.files,
        "bytes": s.bytes,
        "wall_s": wall,
        "process_cpu_s": world.cpu_s,
        "keyframes_per_s": s.keyframes as f64 / wall,
        "bytes_per_keyframe": s.bytes as f64 / s.keyframes.max(1) as f64,
        "target": if a.lean {
            "the lean world: >= 10 keyframes/s on 2 cores (issue 34)"
        } else {
            "10 scenes x 20 keyframes in < 120 s on 2 cores"
        },
        "stages_single_thread_ms": stages,
        "kept": if a.keep { Some(world.root.display().to_string()) } else { None },
    })
}
