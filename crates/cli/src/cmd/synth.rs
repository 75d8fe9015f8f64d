//! `depthsense synth`: generate the synthetic nuScenes-format world.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use depthsense_synth::{SynthConfig, SynthSummary, Weather};

use crate::cmd::heading as h;

#[derive(clap::Args)]
pub struct Args {
    /// Output dataroot (created; a synthetic world already there is refused unless --force,
    /// any other non-empty folder always).
    #[arg(long, help_heading = h::OUTPUT)]
    out: Option<PathBuf>,
    /// Number of scenes.
    #[arg(long, help_heading = h::WORLD, default_value_t = 10)]
    scenes: usize,
    /// Keyframes (2 Hz samples) per scene; a scene lasts (keyframes − 1) × 0.5 s.
    #[arg(long, help_heading = h::WORLD, default_value_t = 20)]
    keyframes_per_scene: usize,
    /// Random seed; the same seed gives byte-identical output.
    #[arg(long, help_heading = h::WORLD, default_value_t = 0)]
    seed: u64,
    /// Condition mix: comma-separated day, night, rain, optionally weighted
    /// (e.g. "day=0.5,night=0.25,rain=0.25"); scenes are allocated in proportion.
    #[arg(long, help_heading = h::WORLD, default_value = "day=0.5,night=0.25,rain=0.25")]
    conditions: String,
    /// Name of the version folder holding the tables.
    #[arg(long, help_heading = h::OUTPUT, default_value = "v1.0-synth")]
    version_name: String,
    /// Worker threads (0 = all cores); does not change the output.
    #[arg(long, help_heading = h::DEVICE, default_value_t = 0)]
    jobs: usize,
    /// Use the small demo preset (8 scenes × 10 keyframes) instead of --scenes/--keyframes-per-scene.
    #[arg(long, help_heading = h::WORLD)]
    demo: bool,
    /// Also (or only, with --from-dataroot) write a contact sheet PNG: day / night / rain
    /// keyframes with lidar and radar points overlaid, coloured by depth.
    #[arg(long, help_heading = h::OUTPUT)]
    contact_sheet: Option<PathBuf>,
    /// Make the contact sheet from this existing dataroot instead of generating a world.
    #[arg(long, help_heading = h::OUTPUT, requires = "contact_sheet")]
    from_dataroot: Option<PathBuf>,
    /// Replace a synthetic world already in --out (without it, it is refused; any other
    /// non-empty folder is always refused).
    #[arg(long, help_heading = h::OUTPUT)]
    force: bool,
    /// CAM_FRONT rays per pixel side: 2 casts one ray per 2×2 pixels (4× fewer; the training
    /// frame, a 2×2 average, then equals that coarse render). Default 1: every pixel.
    #[arg(long, help_heading = h::OUTPUT, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=4))]
    camera_scale: u32,
    /// Write only the lidar keyframe sweeps and the K sweeps on each side of them (what
    /// `prepare --lidar-sweeps K` reads) instead of every 20 Hz sweep.
    #[arg(long, help_heading = h::OUTPUT, value_name = "K")]
    lidar_sweeps: Option<usize>,
    /// Leave out the exact camera depth maps (`truth/`: not a nuScenes file; the contact
    /// sheet and some tests read it).
    #[arg(long, help_heading = h::OUTPUT)]
    no_truth: bool,
    /// Write only the N radar sweeps up to each keyframe (what `prepare --radar-sweeps N`
    /// reads) instead of every ≈13 Hz sweep.
    #[arg(long, help_heading = h::OUTPUT, value_name = "N")]
    radar_sweeps: Option<usize>,
    /// Encode CAM_FRONT as 4:2:0 JPEG, as nuScenes' own images are (four times faster than the
    /// default 4:4:4 encoder, which made every world so far).
    #[arg(long, help_heading = h::OUTPUT)]
    jpeg_420: bool,
    /// The lean world of the experiments: --camera-scale 2 --lidar-sweeps 2 --radar-sweeps 5
    /// --no-truth --jpeg-420 (what prepare reads with its defaults and --lidar-sweeps ≤ 2; about
    /// three times faster; still devkit-loadable). docs/guide/prepare.md.
    #[arg(long, help_heading = h::OUTPUT, conflicts_with_all = ["camera_scale", "lidar_sweeps", "no_truth", "radar_sweeps", "jpeg_420"])]
    lean: bool,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if let Some(root) = &args.from_dataroot {
        let sheet = args
            .contact_sheet
            .as_ref()
            .context("--contact-sheet is required")?;
        depthsense_synth::contact_sheet(root, &args.version_name, sheet)?;
        println!("contact sheet: {}", sheet.display());
        return Ok(ExitCode::SUCCESS);
    }
    let out = args
        .out
        .clone()
        .context("--out is required (the dataroot to write)")?;
    if out.join(depthsense_synth::generate::MARKER_FILE).exists() && !args.force {
        anyhow::bail!(
            "{} already holds a synthetic world; nothing was changed: pass --force to replace it \
             or choose another --out",
            out.display()
        );
    }
    let cfg = synth_config(&args)?;
    let pb = depthsense_progress::Progress::new("synth");
    pb.println(format!(
        "{} scenes × {} keyframes, seed {}, version {} → {}",
        cfg.scenes,
        cfg.keyframes_per_scene,
        cfg.seed,
        cfg.version_name,
        out.display()
    ));
    let s = depthsense_synth::generate(&out, &cfg, &pb)
        .with_context(|| format!("generating the synthetic world into {}", out.display()))?;
    pb.finish_and_clear();
    print_summary(&s, &out, &cfg.version_name);
    if let Some(sheet) = &args.contact_sheet {
        depthsense_synth::contact_sheet(&out, &cfg.version_name, sheet)?;
        println!("contact sheet: {}", sheet.display());
    }
    Ok(ExitCode::SUCCESS)
}

/// The world's configuration: the demo preset or --scenes/--keyframes-per-scene, with the
/// seed, condition mix, version name and threads of the command line.
fn synth_config(args: &Args) -> anyhow::Result<SynthConfig> {
    let mut cfg = if args.demo {
        SynthConfig::demo()
    } else {
        SynthConfig {
            scenes: args.scenes,
            keyframes_per_scene: args.keyframes_per_scene,
            ..SynthConfig::default()
        }
    };
    cfg.seed = args.seed;
    cfg.conditions = SynthConfig::parse_conditions(&args.conditions)?;
    cfg.version_name = args.version_name.clone();
    cfg.jobs = args.jobs;
    if args.lean {
        cfg.apply_lean();
    } else {
        (cfg.camera_scale, cfg.lidar_sweeps, cfg.truth) =
            (args.camera_scale, args.lidar_sweeps, !args.no_truth);
        (cfg.radar_sweeps, cfg.jpeg_420) = (args.radar_sweeps, args.jpeg_420);
    }
    Ok(cfg)
}

/// What was generated, where, and the `prepare` command that comes next (stdout).
fn print_summary(s: &SynthSummary, out: &Path, version_name: &str) {
    let per_s = s.keyframes as f64 / s.seconds.max(1e-9);
    println!(
        "{} scenes ({} day, {} night, {} rain), {} keyframes, {} sample_data, {:.1} MB in {:.1} s ({:.2} keyframes/s incl. all sweeps)",
        s.scenes,
        s.conditions[Weather::Day as usize],
        s.conditions[Weather::Night as usize],
        s.conditions[Weather::Rain as usize],
        s.keyframes,
        s.sample_data,
        s.bytes as f64 / 1e6,
        s.seconds,
        per_s
    );
    println!("dataroot: {}  version: {}", out.display(), version_name);
    println!(
        "next: depthsense prepare --dataroot {} --version {} --split all --out <prepared>",
        out.display(),
        version_name
    );
}
