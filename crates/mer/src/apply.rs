//! `depthsense mer apply`: runs a trained PDA network on every prepared sample and writes the
//! enhanced radar maps (SPEC §5): per pixel the maximum association confidence over every
//! radar return whose window covers it, and that return's depth.
//!
//! Resumable and atomic like `prepare`: each file is written to a temporary sibling and
//! renamed; the confidence map first, the depth map last, so a sample is done iff its
//! `radar_mer_depth.png` exists. `O/mer.json` names the model (path and FNV-1a 64 of its
//! bytes); applying another model is refused unless `--force`, which first removes every MER
//! map so that an interrupted forced run cannot leave maps of two models behind.

use std::path::{Path, PathBuf};
use std::time::Instant;

use depthsense_base::fsutil::write_atomic;
use depthsense_config::pda::PdaConfig;
use depthsense_dataset::{decode_rgb, read_depth, Dataset};
use depthsense_infer::NetError;
use depthsense_model::pda::PdaNet;
use depthsense_nuscenes::depth_png::{encode_png16_fast, encode_value, DepthMap};
use depthsense_prep::layout::{IndexEntry, IMAGE_FILE, RADAR_HEIGHT_FILE, RADAR_RAW_FILE};
use depthsense_progress::Progress;
use rayon::prelude::*;
use tch::{Device, Tensor};

use super::labels::{load_input, neighbour, Grid, PdaInput, RadarPixel};
use depthsense_dataset::mer_maps::{
    conf_to_u16, derive_channels, file_fnv64, read_mer_maps, read_record, MerRecord,
    MER_RECORD_FILE, THRESHOLDS,
};
use depthsense_prep::layout::{MER_CONF_FILE, MER_DEPTH_FILE};

/// Options of `mer apply`.
#[derive(Debug, Clone)]
pub struct MerApplyOptions {
    pub data: PathBuf,
    pub checkpoint: PathBuf,
    pub device: String,
    /// Threads reading and encoding maps (0 = all cores).
    pub jobs: usize,
    /// Samples per forward pass.
    pub batch_size: usize,
    /// libtorch threads of the network on a CPU (0 = auto, see [`network_threads`]).
    pub network_threads: usize,
    /// Recompute every sample (and replace maps of another model).
    pub force: bool,
    /// Write preview pictures for this many samples (evenly spaced over the test samples, or
    /// over the index when it has none).
    pub preview: usize,
    /// Where previews go (default `<data>/mer_preview`).
    pub preview_dir: Option<PathBuf>,
}

impl Default for MerApplyOptions {
    fn default() -> Self {
        Self {
            data: PathBuf::from("prepared"),
            checkpoint: PathBuf::from("runs/mer/best.safetensors"),
            device: "auto".into(),
            jobs: 0,
            batch_size: 4,
            network_threads: 0,
            force: false,
            preview: 0,
            preview_dir: None,
        }
    }
}

/// What `mer apply` did.
#[derive(Debug, Clone)]
pub struct MerApplySummary {
    pub written: usize,
    pub skipped: usize,
    pub seconds: f64,
    /// Samples written per second (0 when none was written).
    pub samples_per_s: f64,
    /// Seconds spent in the network's forward passes (the rest is reading and writing).
    pub network_seconds: f64,
    pub record: MerRecord,
    pub previews: Vec<PathBuf>,
}

/// Enhanced maps on the grid from N radar pixels and their `[N, K]` association
/// probabilities: (depth, confidence). Where windows overlap the higher confidence wins, and
/// on equal confidence the nearer return (SPEC §5 "keeps, per pixel, the maximum affinity and
/// its depth").
pub fn mer_maps(
    pixels: &[RadarPixel],
    probs: &[f32],
    g: &Grid,
    cfg: &PdaConfig,
) -> (Vec<f32>, Vec<f32>) {
    let offsets = cfg.window.offsets();
    let k = offsets.len();
    let mut depth = vec![0f32; g.len()];
    let mut conf = vec![0f32; g.len()];
    for (i, p) in pixels.iter().enumerate() {
        for (j, &(dx, dy)) in offsets.iter().enumerate() {
            let Some(n) = neighbour(g, p.u, p.v, dx, dy) else {
                continue;
            };
            let c = probs[i * k + j];
            let better = c > conf[n] || (c == conf[n] && depth[n] > 0.0 && p.depth_m < depth[n]);
            if better && c > 0.0 {
                conf[n] = c;
                depth[n] = p.depth_m;
            }
        }
    }
    (depth, conf)
}

/// Association probabilities `[N_b, K]` of each sample's radar pixels, one forward pass.
pub fn predict_probs(
    net: &PdaNet,
    inputs: &[PdaInput],
    device: Device,
) -> Result<Vec<Vec<f32>>, NetError> {
    let g = inputs[0].grid;
    if let Some(s) = inputs.iter().find(|s| s.grid != g) {
        return Err(NetError::MerGridsDiffer {
            first: (g.w, g.h),
            other: (s.grid.w, s.grid.h),
        });
    }
    let (b, h, w) = (inputs.len() as i64, g.h as i64, g.w as i64);
    let image: Vec<f32> = inputs
        .iter()
        .flat_map(|s| s.image.iter().copied())
        .collect();
    let radar: Vec<f32> = inputs
        .iter()
        .flat_map(|s| s.radar.iter().copied())
        .collect();
    let idx: Vec<i64> = inputs
        .iter()
        .enumerate()
        .flat_map(|(bi, s)| {
            s.pixels
                .iter()
                .map(move |p| (bi * g.len() + p.v * g.w + p.u) as i64)
        })
        .collect();
    if idx.is_empty() {
        return Ok(vec![vec![]; inputs.len()]);
    }
    let probs = tch::no_grad(|| {
        let img = Tensor::from_slice(&image)
            .view([b, 3, h, w])
            .to_device(device);
        let rad = Tensor::from_slice(&radar)
            .view([b, 1, h, w])
            .to_device(device);
        let f = net.features_t(&img, &rad, false);
        let i = Tensor::from_slice(&idx).to_device(device);
        net.logits_at(&f, &i)
            .sigmoid()
            .to_device(Device::Cpu)
            .contiguous()
    });
    let flat = Vec::<f32>::try_from(probs.view([-1]))?;
    let k = net.config().window.len();
    let mut out = Vec::with_capacity(inputs.len());
    let mut at = 0;
    for s in inputs {
        let n = s.pixels.len() * k;
        out.push(flat[at..at + n].to_vec());
        at += n;
    }
    Ok(out)
}

/// Writes one sample's maps at the training-frame resolution: confidence, then depth.
fn write_sample(
    dir: &Path,
    input: &PdaInput,
    probs: &[f32],
    cfg: &PdaConfig,
) -> Result<(), NetError> {
    let g = &input.grid;
    let (depth, conf) = mer_maps(&input.pixels, probs, g, cfg);
    let (fw, fh) = (g.frame_w as u32, g.frame_h as u32);
    // stored values on the grid, then spread over the frame (4x fewer conversions)
    let conf_q: Vec<u16> = conf.iter().map(|&c| conf_to_u16(c)).collect();
    let depth_q: Vec<u16> = depth.iter().map(|&d| encode_value(d)).collect();
    let png = |q: &[u16]| encode_png16_fast(fw, fh, &g.to_frame(q)).map_err(NetError::from);
    let (conf_png, depth_png) = (png(&conf_q)?, png(&depth_q)?);
    for (name, bytes) in [(MER_CONF_FILE, conf_png), (MER_DEPTH_FILE, depth_png)] {
        let p = dir.join(name);
        write_atomic(&p, &bytes).map_err(|e| NetError::io(&p, e))?;
    }
    Ok(())
}

/// Checks `O/mer.json` against the model; with `force`, removes every MER map first. Writes
/// the new record.
fn prepare_record(
    ds: &Dataset,
    opts: &MerApplyOptions,
    record: &MerRecord,
) -> Result<(), NetError> {
    if let Some(old) = read_record(&ds.root)? {
        let same = old.checkpoint_fnv64 == record.checkpoint_fnv64;
        if !same && !opts.force {
            return Err(NetError::OtherMerMaps {
                record: ds.root.join(MER_RECORD_FILE),
                there: old.checkpoint.to_string(),
                there_fnv64: old.checkpoint_fnv64.to_string(),
                requested: opts.checkpoint.clone(),
            });
        }
    }
    if opts.force {
        for e in &ds.index.samples {
            for f in [MER_DEPTH_FILE, MER_CONF_FILE] {
                let p = ds.sample_dir(e).join(f);
                if p.exists() {
                    std::fs::remove_file(&p).map_err(|err| NetError::io(&p, err))?;
                }
            }
        }
    }
    let p = ds.root.join(MER_RECORD_FILE);
    let text = serde_json::to_string_pretty(record)?;
    write_atomic(&p, text.as_bytes()).map_err(|e| NetError::io(&p, e))
}

/// The `mer.json` of maps written by the PDA checkpoint of `opts` (its path and FNV-1a 64) of
/// config `cfg`.
fn mer_record(opts: &MerApplyOptions, cfg: &PdaConfig) -> Result<MerRecord, NetError> {
    Ok(MerRecord {
        checkpoint: opts.checkpoint.display().to_string(),
        checkpoint_fnv64: file_fnv64(&opts.checkpoint)?,
        pda: cfg.clone(),
        thresholds: THRESHOLDS.to_vec(),
        depth_file: MER_DEPTH_FILE.into(),
        conf_file: MER_CONF_FILE.into(),
    })
}

/// Run `mer apply` (see the module docs).
pub fn apply(opts: &MerApplyOptions, progress: &Progress) -> Result<MerApplySummary, NetError> {
    let started = Instant::now();
    // It writes the prepared dataset in place: no `prepare`, merge or other `mer apply` meanwhile.
    let _writing =
        depthsense_base::lock::OutputLock::exclusive(&opts.data, "depthsense mer apply")?;
    let device = depthsense_model::device::parse_device(&opts.device)?;
    let ds = Dataset::open(&opts.data)?;
    let loaded = depthsense_checkpoint::pda::load(&opts.checkpoint, device)?;
    let record = mer_record(opts, &loaded.config)?;
    prepare_record(&ds, opts, &record)?;
    let todo: Vec<&IndexEntry> = ds
        .index
        .samples
        .iter()
        .filter(|e| !ds.sample_dir(e).join(MER_DEPTH_FILE).exists())
        .collect();
    let skipped = ds.index.samples.len() - todo.len();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(if opts.jobs == 0 { 0 } else { opts.jobs })
        .build()
        .map_err(|e| depthsense_dataset::DataError::thread_start("MER threads", e))?;
    progress.set_length(todo.len() as u64);
    progress.println(format!(
        "{} samples of {} to enhance ({skipped} already done) on {}",
        todo.len(),
        ds.root.display(),
        depthsense_model::device::describe(device)
    ));
    let t0 = Instant::now();
    // libtorch's thread count is process-wide: set for the pipeline, then put back.
    let torch_threads = tch::get_num_threads();
    if device == Device::Cpu {
        let n = network_threads(opts.network_threads, &loaded.config);
        tch::set_num_threads(n as i32);
    }
    let ran = run_pipeline(&ds, &todo, &loaded.net, opts, &pool, device, progress);
    tch::set_num_threads(torch_threads);
    let network_seconds = ran?;
    let secs = t0.elapsed().as_secs_f64();
    let previews = write_previews(&ds, opts)?;
    Ok(MerApplySummary {
        written: todo.len(),
        skipped,
        seconds: started.elapsed().as_secs_f64(),
        samples_per_s: if todo.is_empty() {
            0.0
        } else {
            todo.len() as f64 / secs.max(1e-9)
        },
        network_seconds,
        record,
        previews,
    })
}

/// `--network-threads`: the number asked for, or by default all cores for a network at the
/// grid resolution (its forward pass is most of the work) and all cores but one for a folded
/// one (`input_stride` > 1), whose reading and writing threads then need a core of their own.
/// Measured on 2 cores (BENCHMARKS.md, MER): `tiny` 27 samples/s on 2 threads vs 19 on 1,
/// `fast` 57 on 1 vs 46 on 2.
pub fn network_threads(asked: usize, cfg: &PdaConfig) -> usize {
    if asked > 0 {
        return asked;
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    if cfg.input_stride > 1 {
        cores.saturating_sub(1).max(1)
    } else {
        cores
    }
}

/// The three stages of `mer apply` overlap: a loader thread decodes the next batch while the
/// network runs on this one and a writer thread encodes the previous one (the network keeps
/// libtorch's threads busy only part of the time on a CPU). Returns the network's seconds.
/// The first error of any stage stops the others and is returned.
fn run_pipeline(
    ds: &Dataset,
    todo: &[&IndexEntry],
    net: &PdaNet,
    opts: &MerApplyOptions,
    pool: &rayon::ThreadPool,
    device: Device,
    progress: &Progress,
) -> Result<f64, NetError> {
    use std::sync::mpsc::sync_channel;
    let cfg = net.config();
    std::thread::scope(|s| {
        let (load_tx, load_rx) = sync_channel::<LoadedBatch>(1);
        let (write_tx, write_rx) = sync_channel::<PredictedBatch>(1);
        s.spawn(move || load_batches(ds, todo, cfg, opts.batch_size, pool, load_tx));
        let writer = s.spawn(move || write_batches(ds, cfg, pool, progress, write_rx));
        let mut network_seconds = 0.0;
        let mut result = Ok(());
        for (chunk, inputs) in load_rx {
            let step = inputs.and_then(|inputs| {
                let tn = Instant::now();
                let probs = predict_probs(net, &inputs, device)?;
                network_seconds += tn.elapsed().as_secs_f64();
                Ok((inputs, probs))
            });
            match step {
                Ok((inputs, probs)) => {
                    if write_tx.send((chunk, inputs, probs)).is_err() {
                        break; // the writer failed: its error is reported below
                    }
                }
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
        }
        drop(write_tx);
        let written = writer.join().unwrap_or_else(|_| {
            Err(NetError::ThreadPanicked {
                thread: "MER writer",
            })
        });
        result.and(written).map(|()| network_seconds)
    })
}

/// A batch of samples and their inputs as read (or the first error reading them).
type LoadedBatch<'a> = (&'a [&'a IndexEntry], Result<Vec<PdaInput>, NetError>);
/// A batch of samples, their inputs and the network's association probabilities.
type PredictedBatch<'a> = (&'a [&'a IndexEntry], Vec<PdaInput>, Vec<Vec<f32>>);

/// The loader stage of [`run_pipeline`]: reads `todo` in batches of `batch_size` (on `pool`)
/// and sends each to the network; stops after the first batch that failed or when the network
/// stage is gone.
fn load_batches<'a>(
    ds: &Dataset,
    todo: &'a [&'a IndexEntry],
    cfg: &PdaConfig,
    batch_size: usize,
    pool: &rayon::ThreadPool,
    load_tx: std::sync::mpsc::SyncSender<LoadedBatch<'a>>,
) {
    for chunk in todo.chunks(batch_size.max(1)) {
        let inputs = pool.install(|| {
            chunk
                .par_iter()
                .map(|e| load_input(&ds.sample_dir(e), cfg, false))
                .collect::<Result<Vec<_>, _>>()
        });
        let failed = inputs.is_err();
        if load_tx.send((chunk, inputs)).is_err() || failed {
            break;
        }
    }
}

/// The writer stage of [`run_pipeline`]: writes the MER maps of every predicted batch (on
/// `pool`), counting its samples on `progress`; the first error stops it.
fn write_batches(
    ds: &Dataset,
    cfg: &PdaConfig,
    pool: &rayon::ThreadPool,
    progress: &Progress,
    write_rx: std::sync::mpsc::Receiver<PredictedBatch>,
) -> Result<(), NetError> {
    for (chunk, inputs, probs) in write_rx {
        pool.install(|| {
            chunk
                .par_iter()
                .zip(&inputs)
                .zip(&probs)
                .try_for_each(|((e, i), p)| write_sample(&ds.sample_dir(e), i, p, cfg))
        })?;
        progress.inc(chunk.len() as u64);
    }
    Ok(())
}

/// `--preview N`: for N samples, the image with raw radar, height-extended radar and MER at
/// θ = 0.5 and 0.9 overlaid, one colour map (0–80 m, near = red) with its bar in metres.
fn write_previews(ds: &Dataset, opts: &MerApplyOptions) -> Result<Vec<PathBuf>, NetError> {
    if opts.preview == 0 {
        return Ok(vec![]);
    }
    let dir = opts
        .preview_dir
        .clone()
        .unwrap_or_else(|| ds.root.join("mer_preview"));
    std::fs::create_dir_all(&dir).map_err(|e| NetError::io(&dir, e))?;
    // Test samples when the index has them (what a user evaluates on), else any.
    let test = ds.split("test");
    let pool = if test.is_empty() {
        ds.index.samples.clone()
    } else {
        test
    };
    let entries = depthsense_dataset::subsample(&pool, Some(opts.preview));
    let mut out = vec![];
    for e in &entries {
        let p = dir.join(format!("{}.png", e.sample_token));
        let bytes = preview_png(&ds.sample_dir(e))?;
        write_atomic(&p, &bytes).map_err(|err| NetError::io(&p, err))?;
        out.push(p);
    }
    Ok(out)
}

/// The preview picture of one sample directory (PNG bytes).
pub fn preview_png(dir: &Path) -> Result<Vec<u8>, NetError> {
    use depthsense_viz::plot::{overlay_points, picture_row_png};
    const MAX_M: f32 = 80.0;
    let img = decode_rgb(&dir.join(IMAGE_FILE))?;
    let raw = read_depth(&dir.join(RADAR_RAW_FILE))?;
    let height = read_depth(&dir.join(RADAR_HEIGHT_FILE))?;
    let (md, mc) = read_mer_maps(dir)?;
    let ch = derive_channels(&md.depth_m, &mc.depth_m);
    let n = md.depth_m.len();
    let plane = |t: f32| {
        let i = THRESHOLDS.iter().position(|x| *x == t).unwrap_or(0);
        &ch[i * n..(i + 1) * n]
    };
    let count = |v: &[f32]| v.iter().filter(|d| **d > 0.0).count();
    let panels = [
        (
            format!("raw radar ({} px)", count(&raw.depth_m)),
            overlay_points(&img, &raw.depth_m, MAX_M, 2),
        ),
        (
            format!("height-extended ({} px)", count(&height.depth_m)),
            overlay_points(&img, &height.depth_m, MAX_M, 0),
        ),
        (
            format!("MER conf > 0.5 ({} px)", count(plane(0.5))),
            overlay_points(&img, plane(0.5), MAX_M, 0),
        ),
        (
            format!("MER conf > 0.9 ({} px)", count(plane(0.9))),
            overlay_points(&img, plane(0.9), MAX_M, 0),
        ),
    ];
    let refs: Vec<(&str, image::RgbImage)> = panels
        .iter()
        .map(|(s, i)| (s.as_str(), i.clone()))
        .collect();
    Ok(picture_row_png(&refs, MAX_M)?)
}

/// The MER (depth, confidence) maps of one image and its raw radar map, computed with a PDA
/// network exactly as `mer apply` stores them (`predict --mer-checkpoint`, through
/// `predict::attach_mer`: sample tokens and raw files carry no MER maps of their own).
pub fn mer_maps_for_image(
    image: &image::RgbImage,
    radar_raw: &DepthMap,
    net: &PdaNet,
    device: Device,
) -> Result<(DepthMap, DepthMap), NetError> {
    let cfg = net.config();
    let pi = super::labels::pda_input(image, &radar_raw.depth_m, cfg, false);
    let probs = predict_probs(net, std::slice::from_ref(&pi), device)?;
    let g = &pi.grid;
    let (depth, conf) = mer_maps(&pi.pixels, &probs[0], g, cfg);
    let (w, h) = (g.frame_w as u32, g.frame_h as u32);
    // As `mer apply` stores them: confidence quantised to 16 bits (on the grid, then spread).
    let conf_q: Vec<f32> = conf
        .iter()
        .map(|&c| depthsense_dataset::mer_maps::quantise_conf(c))
        .collect();
    Ok((
        DepthMap {
            width: w,
            height: h,
            depth_m: g.to_frame(&depth),
        },
        DepthMap {
            width: w,
            height: h,
            depth_m: g.to_frame(&conf_q),
        },
    ))
}
