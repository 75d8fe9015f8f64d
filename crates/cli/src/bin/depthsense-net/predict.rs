//! `depthsense predict`: depth for a prepared sample, a sample token of a dataroot, or raw (the network side; its flags: `depthsense_cli::cmd::predict`).

use depthsense_cli::cmd::predict::Args;
use depthsense_cli::cmd::progress::progress_bar;
use depthsense_dataset::outputs::refuse_existing;
use depthsense_eval::predict::{
    input_from_prepared, input_from_raw, input_from_token, predict, radar_warnings,
    trained_radar_settings, write_outputs, PredictInput, OUTPUT_FILES,
};
use depthsense_model::precision::InferenceLayout;
use depthsense_nuscenes::depth_png::DepthMap;
use depthsense_prep::calibration::RadarSettings;
use std::path::PathBuf;
use std::process::ExitCode;

fn run_dataset(a: &Args, data: &std::path::Path) -> anyhow::Result<ExitCode> {
    use depthsense_eval::evaluate::{write_predictions, EvalOptions};
    use depthsense_score::predictions::select_split;
    let formats = a.format.clone();
    let opts = EvalOptions {
        checkpoint: a.model.checkpoint.clone(),
        config: a.model.config.clone(),
        set: a.model.set.clone(),
        data: data.to_path_buf(),
        split: a.split.clone(),
        batch_size: a.batch_size,
        device: a.device.name.clone(),
        cuda_graph: a.cuda_graph,
        ..EvalOptions::default()
    };
    let ds = depthsense_dataset::Dataset::open(data)?;
    let files: Vec<PathBuf> = select_split(&ds, &opts.split, opts.val_every_scene)?
        .iter()
        .flat_map(|e| {
            formats
                .iter()
                .map(|f| a.out.join(format!("{}.{}", e.sample_token, f.ext())))
        })
        .collect();
    refuse_existing(&files, a.force, "predict")?;
    let device = depthsense_model::device::parse_device(&a.device.name)?;
    let loaded = super::model_source::load(&a.model, device, InferenceLayout::Fastest)?;
    let pb = progress_bar("predict");
    let (n, stats) = write_predictions(&opts, &loaded, &a.out, &formats, &pb)?;
    pb.finish_and_clear();
    eprintln!(
        "{n} predictions ({}) written to {}",
        formats
            .iter()
            .map(|f| f.ext())
            .collect::<Vec<_>>()
            .join(", "),
        a.out.display()
    );
    eprintln!("{}", stats.summary(opts.batch_size));
    Ok(ExitCode::SUCCESS)
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    if let Some(data) = a.data.clone() {
        return run_dataset(&a, &data);
    }
    if a.tokens.is_some() || a.token.len() > 1 || (a.image.is_none() && !a.calibration.is_empty()) {
        return super::predict_frames::run(&a);
    }
    let files: Vec<PathBuf> = OUTPUT_FILES.iter().map(|f| a.out.join(f)).collect();
    refuse_existing(&files, a.force, "predict")?;
    let device = depthsense_model::device::parse_device(&a.device.name)?;
    let loaded = super::model_source::load(&a.model, device, InferenceLayout::Fastest)?;
    let trained = trained_radar_settings(&loaded.extra).or_else(|| sidecar_radar(&a));
    let mut input = read_input(&a, trained.as_ref())?;
    for w in radar_warnings(trained.as_ref(), &input) {
        eprintln!("{w}");
    }
    let radar = loaded.config.radar_input_for(None)?;
    if let Some(ck) = &a.mer_checkpoint {
        let pda = depthsense_checkpoint::pda::load(ck, device)?;
        depthsense_eval::predict::attach_mer(&mut input, &pda.net, device)?;
    }
    let depth = predict(&loaded.net, &input, radar, device)?;
    let files = write_outputs(&a.out, &input, &depth, a.max_depth)?;
    print_summary(&input, &depth);
    for f in files {
        println!("{}", f.display());
    }
    Ok(ExitCode::SUCCESS)
}

/// The radar settings an export sidecar given as `--config` records (`trained_radar`).
pub fn sidecar_radar(a: &Args) -> Option<RadarSettings> {
    let path = std::path::Path::new(a.model.config.as_deref()?);
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(path).ok()?).ok()?;
    serde_json::from_value(json.get("trained_radar")?.clone()).ok()
}

/// The one input of the command line: a prepared sample, a sample token of a dataroot (its
/// maps computed like `prepare` computed the training data's, from `trained`), or raw files.
fn read_input(a: &Args, trained: Option<&RadarSettings>) -> anyhow::Result<PredictInput> {
    Ok(if let Some(dir) = &a.sample {
        input_from_prepared(dir)?
    } else if let Some(token) = a.token.first() {
        let opts = token_prepare_options(a, trained)?;
        input_from_token(&opts.dataroot, &a.version, token, &opts)?
    } else if let Some(jpeg) = &a.image {
        let calib = match a.calibration.as_slice() {
            [] => anyhow::bail!("--image needs --calibration"),
            [one] => one,
            _ => anyhow::bail!(
                "--image takes one --calibration; without --image each calibration is a frame \
                 that names its own image (`camera_file`)"
            ),
        };
        input_from_raw(jpeg, &a.radar, calib, !a.no_radar_filters)?
    } else {
        anyhow::bail!("give one input: --sample DIR, --data P, --token T --dataroot D, or --image J --radar P --calibration C");
    })
}

/// How a sample token's maps are computed: `prepare`'s options for --dataroot and --version
/// with the radar settings the network was `trained` on (and --no-radar-filters).
pub fn token_prepare_options(
    a: &Args,
    trained: Option<&RadarSettings>,
) -> anyhow::Result<depthsense_prep::PrepareOptions> {
    let dataroot = a
        .dataroot
        .as_ref()
        .ok_or_else(|| anyhow::anyhow!("--token needs --dataroot"))?;
    let mut opts = depthsense_prep::PrepareOptions {
        dataroot: dataroot.clone(),
        version: a.version.clone(),
        ..depthsense_prep::PrepareOptions::default()
    };
    if let Some(t) = trained {
        opts.radar_sweeps = t.radar_sweeps;
        opts.radar_channels = t.radar_channels.clone();
        opts.radar_filters = t.radar_filters;
        opts.radar_velocity_compensation = t.radar_velocity_compensation;
    }
    opts.radar_filters &= !a.no_radar_filters;
    Ok(opts)
}

/// The prediction's size, mean depth and radar pixels, and its RMSE against the lidar
/// ground truth where the input has one (stderr).
fn print_summary(input: &PredictInput, depth: &DepthMap) {
    let valid: Vec<f32> = depth.depth_m.iter().copied().filter(|d| *d > 0.0).collect();
    let mean = valid.iter().map(|d| *d as f64).sum::<f64>() / valid.len().max(1) as f64;
    eprintln!(
        "{}: {}x{} depth, mean {mean:.2} m, {} radar pixels",
        input.name,
        depth.width,
        depth.height,
        input.radar_raw.valid_count()
    );
    if let Some(gt) = &input.gt {
        let (mut n, mut se) = (0usize, 0f64);
        for (p, g) in depth.depth_m.iter().zip(&gt.depth_m) {
            if *g > 0.0 && *g <= 80.0 {
                n += 1;
                se += ((p.clamp(1.0, 80.0) - g) as f64).powi(2);
            }
        }
        if n > 0 {
            eprintln!(
                "RMSE against lidar ({n} px, ≤ 80 m): {:.3} m",
                (se / n as f64).sqrt()
            );
        }
    }
}
