//! depthsense-data (layer 4, ARCHITECTURE.md): everything between `depthsense prepare`'s output
//! and a batch — withheld scenes ([`exclusion`]), SPEC §8 augmentation, radar corruption
//! ([`radar_failure`]) and the prefetching loader. Without libtorch: a batch is host memory
//! (`Vec<f32>`), its errors are `depthsense_dataset::DataError`; the dataset, index, partition,
//! a sample's readers and the MER maps on disk are `depthsense_dataset`'s (reached there). No
//! training code: the training engine (`depthsense-train`) uploads the batches.
//!
//! The data loader: reads `depthsense prepare` output (`depthsense_prep::layout`), applies the
//! SPEC §8 augmentation, normalises images (SPEC §6 ImageNet statistics) and assembles batches
//! on a background thread pool that fills a bounded channel (prefetch).
//!
//! Everything random is derived from `(seed, epoch, sample position)` by a counter-based hash,
//! so a batch is identical whatever the number of threads or the timing (reproducible, and
//! resumable from `(epoch, iteration)` alone).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, Receiver};
use std::thread::JoinHandle;

use depthsense_base::hash::{fnv1a64, splitmix64, SplitMix64, GOLDEN_GAMMA};
use depthsense_nuscenes::depth_png::DepthMap;
use depthsense_prep::layout::{
    Condition, IndexEntry, PreparedIndex, IMAGE_FILE, INDEX_FILE, LIDAR_DENSE_FILE,
    LIDAR_SPARSE_FILE, LOWHEIGHT_MASK_FILE, META_FILE, RADAR_HEIGHT_FILE, RADAR_RAW_FILE,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

pub mod exclusion;
pub mod net_input;
pub mod radar_failure;
pub mod radar_oracle;

// The torch-free part (index, partition, a sample's files, MER maps on disk) lives in
// depthsense-dataset and is reached there (one path per item).
use depthsense_dataset::index::Dataset;
use depthsense_dataset::maps::{
    check_size, decode_rgb, read_depth, read_lowheight_mask, read_meta,
};

use depthsense_dataset::DataError;

pub use depthsense_config::training::{is_default, TargetKind};

/// ImageNet mean (SPEC §6).
pub const IMAGENET_MEAN: [f32; 3] = [0.485, 0.456, 0.406];
/// ImageNet standard deviation (SPEC §6).
pub const IMAGENET_STD: [f32; 3] = [0.229, 0.224, 0.225];

use depthsense_config::RadarInput;

/// How samples are read and augmented.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LoadOptions {
    pub radar: RadarInput,
    pub target: TargetKind,
    /// SPEC §8 augmentation (flip, brightness / colour / gamma jitter).
    pub augment: bool,
    /// Also read the sparse GT and low-height mask (evaluation).
    pub eval_maps: bool,
    /// Skip reading radar maps (RGB-only networks): radar tensors are zero-channel.
    pub no_radar: bool,
    /// Fraction of radar points removed at random (sensor-failure ablation, SPEC §10.8).
    pub radar_drop: f64,
    /// Seed of the augmentation and radar-drop draws.
    pub seed: u64,
    /// Whole radars absent, returns beyond a range absent, clutter added (SPEC §10.8).
    #[serde(default)]
    pub failure: crate::radar_failure::RadarFailure,
    /// Training augmentation (not in the paper): each sample loses a fraction U(0, p) of its
    /// radar returns (with their height-extended strips), drawn from the sample's random
    /// stream, so that a network cannot read "no return here" as a depth cue. 0 = off (no
    /// draw is made: runs without it are unchanged).
    #[serde(default, skip_serializing_if = "crate::is_default")]
    pub train_radar_drop: f64,
    /// The oracle radar ([`radar_oracle`]): every return's depth replaced by the training
    /// target's. false = the sensor's returns (absent from the JSON).
    #[serde(default, skip_serializing_if = "crate::is_default")]
    pub radar_oracle: bool,
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            radar: RadarInput::Height,
            target: TargetKind::Dense,
            augment: false,
            eval_maps: false,
            no_radar: false,
            radar_drop: 0.0,
            seed: 0,
            failure: Default::default(),
            train_radar_drop: 0.0,
            radar_oracle: false,
        }
    }
}

/// One decoded, augmented, normalised sample (CPU, channel-major).
#[derive(Debug, Clone)]
pub struct Sample {
    pub token: String,
    pub conditions: Vec<Condition>,
    pub width: usize,
    pub height: usize,
    /// [3, H, W] ImageNet-normalised.
    pub image: Vec<f32>,
    /// [C, H, W] radar depth in metres, 0 = no radar (C = 0 when radar is not read).
    pub radar: Vec<f32>,
    pub radar_channels: usize,
    /// [H, W] training target in metres, 0 = invalid.
    pub target_m: Vec<f32>,
    /// [H, W] sparse GT (only with `eval_maps`).
    pub sparse_m: Vec<f32>,
    /// [H, W] low-height mask (only with `eval_maps`; empty when the file is absent).
    pub lowheight: Vec<bool>,
    /// Whether the sample was flipped horizontally.
    pub flipped: bool,
}

/// A small deterministic generator: the SplitMix64 stream whose first draw is
/// `splitmix64(splitmix64(seed) + γ)` (the loader's draws since issue 5; the synthetic world's `Rng`
/// starts from the seed itself — the two seedings differ and each keeps its stream).
#[derive(Debug, Clone)]
pub struct Rng(SplitMix64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(SplitMix64::from_state(
            splitmix64(seed).wrapping_add(GOLDEN_GAMMA),
        ))
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        self.0.next_f64()
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
}

fn hash_str(s: &str) -> u64 {
    fnv1a64(s.as_bytes())
}

/// The order of samples in an epoch: a Fisher–Yates shuffle seeded by (seed, epoch).
pub fn epoch_order(n: usize, seed: u64, epoch: u64, shuffle: bool) -> Vec<usize> {
    let mut v: Vec<usize> = (0..n).collect();
    if shuffle {
        let mut rng = Rng::new(seed ^ splitmix64(epoch.wrapping_add(0x5eed)));
        for i in (1..n).rev() {
            let j = (rng.next_u64() % (i as u64 + 1)) as usize;
            v.swap(i, j);
        }
    }
    v
}

/// SPEC §8 augmentation parameters of one sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Augment {
    pub flip: bool,
    /// Multiplier of all channels (1 = unchanged).
    pub brightness: f32,
    /// Per-channel multipliers (1 = unchanged).
    pub colour: [f32; 3],
    /// Exponent applied to [0,1] intensities (1 = unchanged).
    pub gamma: f32,
}

impl Augment {
    pub const NONE: Augment = Augment {
        flip: false,
        brightness: 1.0,
        colour: [1.0; 3],
        gamma: 1.0,
    };

    /// Draw: flip with p = 0.5; with p = 0.5 brightness, colour and gamma each uniform in
    /// [0.9, 1.1] (SPEC §8).
    pub fn draw(rng: &mut Rng) -> Self {
        let flip = rng.uniform() < 0.5;
        let mut a = Augment { flip, ..Self::NONE };
        if rng.uniform() < 0.5 {
            a.brightness = rng.range(0.9, 1.1) as f32;
            a.colour = [
                rng.range(0.9, 1.1) as f32,
                rng.range(0.9, 1.1) as f32,
                rng.range(0.9, 1.1) as f32,
            ];
            a.gamma = rng.range(0.9, 1.1) as f32;
        }
        a
    }
}

fn flip_rows<T: Copy>(v: &mut [T], w: usize) {
    for row in v.chunks_mut(w) {
        row.reverse();
    }
}

/// Remove a fraction `p` of radar points (SPEC §10.8). A point is a pixel of the raw map;
/// its height-extended strip is the set of pixels of the same column holding the same
/// stored depth value, removed with it. `p >= 1` removes everything.
pub fn drop_radar(raw: &mut DepthMap, height: Option<&mut DepthMap>, p: f64, seed: u64) {
    if p <= 0.0 {
        return;
    }
    if p >= 1.0 {
        raw.depth_m.iter_mut().for_each(|d| *d = 0.0);
        if let Some(h) = height {
            h.depth_m.iter_mut().for_each(|d| *d = 0.0);
        }
        return;
    }
    let w = raw.width as usize;
    let mut dropped: BTreeSet<(usize, u32)> = BTreeSet::new();
    for (i, d) in raw.depth_m.iter_mut().enumerate() {
        if *d > 0.0 {
            let r = splitmix64(seed ^ splitmix64(i as u64 + 1));
            if ((r >> 11) as f64 / (1u64 << 53) as f64) < p {
                dropped.insert((i % w, d.to_bits()));
                *d = 0.0;
            }
        }
    }
    if let Some(h) = height {
        let hw = h.width as usize;
        for (i, d) in h.depth_m.iter_mut().enumerate() {
            if *d > 0.0 && dropped.contains(&(i % hw, d.to_bits())) {
                *d = 0.0;
            }
        }
    }
}

/// The MER (depth, confidence) maps of a sample (`radar_mer_depth.png` /
/// `radar_mer_conf.png`, SPEC §5) for its raw map `raw`. A MER pixel carries the exact depth of
/// one raw return, so MER pixels whose depth is no longer among the raw returns (dropped by
/// `radar_drop` or a failure mode) are removed with them.
fn kept_mer_maps(dir: &Path, raw: &DepthMap) -> Result<(DepthMap, DepthMap), DataError> {
    let (mut depth, conf) = depthsense_dataset::mer_maps::read_mer_maps(dir)?;
    let mp = dir.join(depthsense_prep::layout::MER_DEPTH_FILE);
    check_size(&depth, raw.width as usize, raw.height as usize, &mp)?;
    let kept: BTreeSet<u32> = raw.depth_m.iter().map(|d| d.to_bits()).collect();
    for d in depth.depth_m.iter_mut() {
        if *d > 0.0 && !kept.contains(&d.to_bits()) {
            *d = 0.0;
        }
    }
    Ok((depth, conf))
}

/// Read one sample directory. `draw` is the sample's random stream (augmentation). A file that
/// is missing, truncated or corrupt is a [`DataError::Unreadable`] naming the sample and how to
/// rebuild it.
pub fn load_sample(
    ds: &Dataset,
    entry: &IndexEntry,
    opts: &LoadOptions,
    rng: &mut Rng,
) -> Result<Sample, DataError> {
    let unreadable = |why: String| DataError::Unreadable {
        root: ds.root.display().to_string(),
        samples: vec![(entry.sample_token.clone(), why)],
    };
    read_sample(ds, entry, opts, rng).map_err(|e| match e.unreadable_reason() {
        Some(why) => unreadable(why),
        None => e,
    })
}

fn read_sample(
    ds: &Dataset,
    entry: &IndexEntry,
    opts: &LoadOptions,
    rng: &mut Rng,
) -> Result<Sample, DataError> {
    let dir = ds.sample_dir(entry);
    if !dir.join(META_FILE).exists() {
        return Err(DataError::IncompleteSample { dir });
    }
    let rgb = decode_rgb(&dir.join(IMAGE_FILE))?;
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let draws = SampleDraws::draw(opts, rng);
    let image = normalise_image(&rgb, &draws.aug);

    let target_m = read_target(&dir, opts.target, w, h)?;
    let (radar, radar_channels) = if opts.no_radar {
        (Vec::new(), 0)
    } else {
        let maps = match opts.radar_oracle {
            true => oracle_radar_maps(&dir, &target_m, w, h)?,
            false => read_radar_maps(&dir, w, h)?,
        };
        let (raw, height) = corrupt_radar(&dir, entry, opts, draws.train_drop, maps)?;
        (
            sample_radar_planes(&dir, opts.radar, &raw, &height)?,
            opts.radar.channels(),
        )
    };
    let (sparse_m, lowheight) = if opts.eval_maps {
        read_eval_maps(&dir, w, h)?
    } else {
        (Vec::new(), Vec::new())
    };

    let mut sample = Sample {
        token: entry.sample_token.clone(),
        conditions: entry.conditions.clone(),
        width: w,
        height: h,
        image,
        radar,
        radar_channels,
        target_m,
        sparse_m,
        lowheight,
        flipped: draws.aug.flip,
    };
    if draws.aug.flip {
        flip_sample(&mut sample);
    }
    Ok(sample)
}

/// The draws of one sample from its random stream, in stream order.
struct SampleDraws {
    /// SPEC §8 augmentation ([`Augment::NONE`] without `augment`: no draw).
    aug: Augment,
    /// Training radar drop: (fraction, seed), drawn only when `train_radar_drop` is on.
    train_drop: Option<(f64, u64)>,
}

impl SampleDraws {
    /// Augmentation first, then the training radar drop.
    fn draw(opts: &LoadOptions, rng: &mut Rng) -> Self {
        let aug = if opts.augment {
            Augment::draw(rng)
        } else {
            Augment::NONE
        };
        // Drawn after the SPEC §8 augmentation so that its draws are those of runs without it.
        let train_drop = (opts.train_radar_drop > 0.0 && !opts.no_radar)
            .then(|| (rng.range(0.0, opts.train_radar_drop), rng.next_u64()));
        Self { aug, train_drop }
    }
}

/// The training target (metres): the dense map when asked for and present, else the sparse.
fn read_target(dir: &Path, kind: TargetKind, w: usize, h: usize) -> Result<Vec<f32>, DataError> {
    let dense_path = dir.join(LIDAR_DENSE_FILE);
    let sparse_path = dir.join(LIDAR_SPARSE_FILE);
    let target_path = match kind {
        TargetKind::Dense if dense_path.exists() => dense_path,
        _ => sparse_path,
    };
    let target = read_depth(&target_path)?;
    check_size(&target, w, h, &target_path)?;
    Ok(target.depth_m)
}

/// A sample's stored radar maps, checked against the image size.
struct RadarMaps {
    raw: DepthMap,
    height: DepthMap,
    /// Path of the raw map (named in size errors of re-rasterised maps).
    raw_path: PathBuf,
    width: usize,
    height_px: usize,
}

impl RadarMaps {
    /// The raw and height-extended maps of the sample in `dir`, checked against the image
    /// size (a size error names the sample's stored file of that map).
    fn checked(
        dir: &Path,
        raw: DepthMap,
        height: DepthMap,
        w: usize,
        h: usize,
    ) -> Result<RadarMaps, DataError> {
        let raw_path = dir.join(RADAR_RAW_FILE);
        check_size(&raw, w, h, &raw_path)?;
        check_size(&height, w, h, &dir.join(RADAR_HEIGHT_FILE))?;
        Ok(RadarMaps {
            raw,
            height,
            raw_path,
            width: w,
            height_px: h,
        })
    }
}

/// Read the raw and height-extended radar maps of a sample.
fn read_radar_maps(dir: &Path, w: usize, h: usize) -> Result<RadarMaps, DataError> {
    let raw = read_depth(&dir.join(RADAR_RAW_FILE))?;
    let height = read_depth(&dir.join(RADAR_HEIGHT_FILE))?;
    RadarMaps::checked(dir, raw, height, w, h)
}

/// The oracle radar maps ([`radar_oracle`]) in place of the stored ones (which are not read),
/// checked against the image size like them.
fn oracle_radar_maps(
    dir: &Path,
    target_m: &[f32],
    w: usize,
    h: usize,
) -> Result<RadarMaps, DataError> {
    let (raw, height) = radar_oracle::oracle_maps(dir, target_m, w, h)?;
    RadarMaps::checked(dir, raw, height, w, h)
}

/// Radar corruption in the loader's order: failure re-rasterisation, `radar_drop`, the
/// training drop, then the failure modes (SPEC §10.7/§10.8) → (raw, height).
fn corrupt_radar(
    dir: &Path,
    entry: &IndexEntry,
    opts: &LoadOptions,
    train_drop: Option<(f64, u64)>,
    maps: RadarMaps,
) -> Result<(DepthMap, DepthMap), DataError> {
    let RadarMaps {
        mut raw,
        mut height,
        raw_path,
        width: w,
        height_px: h,
    } = maps;
    if opts.radar_oracle && (opts.failure.is_active() || opts.radar == RadarInput::Mer) {
        return Err(DataError::OracleRadarCombined);
    }
    let failure_seed = opts.seed ^ hash_str(&entry.sample_token) ^ 0xfa11;
    let meta = match opts.failure.is_active() {
        true => Some(read_meta(dir)?),
        false => None,
    };
    // SPEC §10.7/§10.8: perturbed calibration or a subset of radars, from the points.
    if opts.radar == RadarInput::Mer && opts.failure.perturb.is_some() {
        return Err(DataError::MerPerturbation);
    }
    if let Some(meta) = &meta {
        if let Some((r, hm)) = opts.failure.reraster(dir, meta, failure_seed)? {
            check_size(&r, w, h, &raw_path)?;
            (raw, height) = (r, hm);
        }
    }
    if opts.radar_drop > 0.0 {
        let seed = opts.seed ^ hash_str(&entry.sample_token) ^ 0xd20b;
        drop_radar(&mut raw, Some(&mut height), opts.radar_drop, seed);
    }
    if let Some((fraction, seed)) = train_drop {
        drop_radar(&mut raw, Some(&mut height), fraction, seed);
    }
    if let Some(meta) = &meta {
        opts.failure
            .apply(&mut raw, &mut height, meta, failure_seed)?;
    }
    Ok((raw, height))
}

/// The network's radar planes [C, H, W] for input `radar` from the (corrupted) maps of a
/// prepared sample `dir`.
fn sample_radar_planes(
    dir: &Path,
    radar: RadarInput,
    raw: &DepthMap,
    height: &DepthMap,
) -> Result<Vec<f32>, DataError> {
    if radar == RadarInput::Mer {
        let (depth, conf) = kept_mer_maps(dir, raw)?;
        return Ok(radar_planes(
            radar,
            raw,
            height,
            Some((&depth.depth_m, &conf.depth_m)),
        ));
    }
    Ok(radar_planes(radar, raw, height, None))
}

/// The network's radar planes [C, H, W] for input `radar` (SPEC §5), in metres, 0 = no
/// return: the height-extended map, the raw map, raw then height-extended, or for MER the raw
/// map then the 6 channels of the MER (depth, confidence) maps `mer`
/// (`mer_maps::derive_channels`; all 0 when `mer` is None). Training's loader and every
/// network input ([`net_input::net_inputs`]: `predict`, the Python module) build them here.
pub fn radar_planes(
    radar: RadarInput,
    raw: &DepthMap,
    height: &DepthMap,
    mer: Option<(&[f32], &[f32])>,
) -> Vec<f32> {
    let mut planes = Vec::new();
    match radar {
        RadarInput::Height => planes.extend_from_slice(&height.depth_m),
        RadarInput::Raw => planes.extend_from_slice(&raw.depth_m),
        RadarInput::RawHeight => {
            planes.extend_from_slice(&raw.depth_m);
            planes.extend_from_slice(&height.depth_m);
        }
        RadarInput::Mer => {
            planes.extend_from_slice(&raw.depth_m);
            match mer {
                Some((depth, conf)) => planes
                    .extend_from_slice(&depthsense_dataset::mer_maps::derive_channels(depth, conf)),
                None => planes.resize(planes.len() * RadarInput::Mer.channels(), 0.0),
            }
        }
    }
    planes
}

/// The evaluation maps: sparse GT (metres) and the low-height mask (empty when absent).
fn read_eval_maps(dir: &Path, w: usize, h: usize) -> Result<(Vec<f32>, Vec<bool>), DataError> {
    let sparse_path = dir.join(LIDAR_SPARSE_FILE);
    let s = read_depth(&sparse_path)?;
    check_size(&s, w, h, &sparse_path)?;
    Ok((s.depth_m, read_lowheight_mask(dir, w, h)?))
}

/// SPEC §8 horizontal flip of every map of a sample (image, radar, target, eval maps).
fn flip_sample(s: &mut Sample) {
    let w = s.width;
    let plane = s.width * s.height;
    for c in 0..3 {
        flip_rows(&mut s.image[c * plane..(c + 1) * plane], w);
    }
    for c in 0..s.radar_channels {
        flip_rows(&mut s.radar[c * plane..(c + 1) * plane], w);
    }
    flip_rows(&mut s.target_m, w);
    if !s.sparse_m.is_empty() {
        flip_rows(&mut s.sparse_m, w);
    }
    if !s.lowheight.is_empty() {
        flip_rows(&mut s.lowheight, w);
    }
}

/// [3, H, W] ImageNet-normalised planes of an RGB image, after the colour jitter of `aug`
/// applied to [0,1] intensities (SPEC §6, §8). The flip is not applied here.
pub fn normalise_image(rgb: &image::RgbImage, aug: &Augment) -> Vec<f32> {
    let plane = rgb.width() as usize * rgb.height() as usize;
    let mut image = vec![0f32; 3 * plane];
    let jitter = *aug
        != Augment {
            flip: aug.flip,
            ..Augment::NONE
        };
    for (i, px) in rgb.pixels().enumerate() {
        for c in 0..3 {
            let mut x = px.0[c] as f32 / 255.0;
            if jitter {
                x = (x * aug.brightness * aug.colour[c]).clamp(0.0, 1.0);
                x = x.powf(aug.gamma);
            }
            image[c * plane + i] = normalise_value(x, c);
        }
    }
    image
}

/// One value of channel `c` in [0, 1] as the network takes it (SPEC §6): less the ImageNet
/// mean, over the ImageNet standard deviation — the first operation of an exported graph.
#[inline]
pub fn normalise_value(x: f32, c: usize) -> f32 {
    (x - IMAGENET_MEAN[c]) / IMAGENET_STD[c]
}

/// An RGB8 image as `[3, H, W]` values in [0, 1] (each value / 255): the input of an exported
/// graph ([`net_input::NetInputs::image`]); [`normalise_image`] without augmentation is
/// [`normalise_value`] of it, bit for bit.
pub fn rgb01(rgb: &image::RgbImage) -> Vec<f32> {
    let plane = rgb.width() as usize * rgb.height() as usize;
    let mut image = vec![0f32; 3 * plane];
    for (i, px) in rgb.pixels().enumerate() {
        for c in 0..3 {
            image[c * plane + i] = px.0[c] as f32 / 255.0;
        }
    }
    image
}

/// A batch of samples stacked channel-major: shapes in the field docs.
#[derive(Debug, Clone)]
pub struct Batch {
    /// Position of the batch in its epoch.
    pub index: usize,
    pub size: usize,
    pub width: usize,
    pub height: usize,
    /// [B, 3, H, W]
    pub image: Vec<f32>,
    /// [B, C, H, W]
    pub radar: Vec<f32>,
    pub radar_channels: usize,
    /// [B, 1, H, W]
    pub target_m: Vec<f32>,
    /// The samples' other fields (tokens, conditions, eval maps); image/radar/target moved out.
    pub samples: Vec<Sample>,
}

impl Batch {
    fn stack(index: usize, mut samples: Vec<Sample>) -> Result<Batch, DataError> {
        let (w, h, c) = (
            samples[0].width,
            samples[0].height,
            samples[0].radar_channels,
        );
        if let Some(s) = samples
            .iter()
            .find(|s| s.width != w || s.height != h || s.radar_channels != c)
        {
            return Err(DataError::BatchMismatch {
                sample: s.token.clone(),
                shape: (s.width, s.height, s.radar_channels),
                batch: (w, h, c),
            });
        }
        let b = samples.len();
        let mut image = Vec::with_capacity(b * 3 * w * h);
        let mut radar = Vec::with_capacity(b * c * w * h);
        let mut target_m = Vec::with_capacity(b * w * h);
        for s in samples.iter_mut() {
            image.append(&mut s.image);
            radar.append(&mut s.radar);
            target_m.append(&mut s.target_m);
        }
        Ok(Batch {
            index,
            size: b,
            width: w,
            height: h,
            image,
            radar,
            radar_channels: c,
            target_m,
            samples,
        })
    }
}

/// Draw stream of the sample at position `pos` of epoch `epoch`.
pub fn sample_rng(seed: u64, epoch: u64, pos: usize) -> Rng {
    Rng::new(
        seed ^ splitmix64(epoch.wrapping_mul(0x1_0000_0001)) ^ splitmix64(pos as u64 ^ 0xa5a5_0000),
    )
}

/// The batches of one epoch, decoded in parallel on `jobs` threads and prefetched
/// `prefetch` batches ahead through a bounded channel. Iterating yields them in order.
pub struct Loader {
    rx: Option<Receiver<Result<Batch, DataError>>>,
    handle: Option<JoinHandle<()>>,
    pub batches: usize,
}

/// Parameters of one epoch of loading.
#[derive(Debug, Clone)]
pub struct EpochPlan {
    pub entries: Vec<IndexEntry>,
    pub batch_size: usize,
    pub epoch: u64,
    pub shuffle: bool,
    /// Drop the last incomplete batch (training) or keep it (evaluation).
    pub drop_last: bool,
    /// Skip the first `skip_batches` batches (exact resume mid-epoch).
    pub skip_batches: usize,
    /// Decoding threads (0 = all cores).
    pub jobs: usize,
    /// Batches decoded ahead.
    pub prefetch: usize,
}

impl Loader {
    pub fn start(ds: &Dataset, opts: &LoadOptions, plan: &EpochPlan) -> Result<Loader, DataError> {
        Self::start_shard(ds, opts, plan, 0, 1)
    }

    /// [`Loader::start`] for rank `rank` of `world` data-parallel ranks: the global batches
    /// (of `plan.batch_size`) are those of one process, whatever `world` is, and this rank
    /// gets the contiguous slice `[rank·B/world, (rank+1)·B/world)` of each. Per-sample draws
    /// depend on the sample's position in the epoch only, so augmentation is too.
    pub fn start_shard(
        ds: &Dataset,
        opts: &LoadOptions,
        plan: &EpochPlan,
        rank: usize,
        world: usize,
    ) -> Result<Loader, DataError> {
        if plan.batch_size == 0 {
            return Err(DataError::ZeroBatchSize);
        }
        let groups = batch_groups(opts, plan, rank, world)?;
        let batches = groups.len();
        let groups: Vec<(usize, Vec<usize>)> = groups
            .into_iter()
            .enumerate()
            .skip(plan.skip_batches)
            .collect();
        let pool = loader_pool(plan.jobs)?;
        let (tx, rx) = sync_channel(plan.prefetch.max(1));
        let ds = ds.clone();
        let opts = opts.clone();
        let entries = plan.entries.clone();
        let epoch = plan.epoch;
        let handle = std::thread::Builder::new()
            .name("loader".into())
            .spawn(move || {
                for (bi, group) in groups {
                    let res: Vec<Result<Sample, DataError>> = pool.install(|| {
                        group
                            .par_iter()
                            .map(|&pos| {
                                let mut rng = sample_rng(opts.seed, epoch, pos);
                                load_sample(&ds, &entries[pos], &opts, &mut rng)
                            })
                            .collect()
                    });
                    let (ok, bad): (Vec<_>, Vec<_>) = res.into_iter().partition(Result::is_ok);
                    let batch = match DataError::merged(
                        bad.into_iter().filter_map(Result::err).collect(),
                    ) {
                        None => Batch::stack(bi, ok.into_iter().filter_map(Result::ok).collect()),
                        Some(e) => Err(e),
                    };
                    // Past unreadable samples the stream goes on (a consumer that stops at
                    // the first error drops the loader); any other error ends it.
                    let stop =
                        matches!(&batch, Err(e) if !matches!(e, DataError::Unreadable { .. }));
                    if tx.send(batch).is_err() || stop {
                        break;
                    }
                }
            })
            .map_err(|e| DataError::thread_start("loader thread", e))?;
        Ok(Loader {
            rx: Some(rx),
            handle: Some(handle),
            batches,
        })
    }
}

/// The epoch's batches as sample positions: the epoch order in chunks of `plan.batch_size`
/// (the last incomplete one dropped with `drop_last`), each cut to rank `rank`'s slice of
/// `world`.
fn batch_groups(
    opts: &LoadOptions,
    plan: &EpochPlan,
    rank: usize,
    world: usize,
) -> Result<Vec<Vec<usize>>, DataError> {
    let order = epoch_order(plan.entries.len(), opts.seed, plan.epoch, plan.shuffle);
    let mut groups: Vec<Vec<usize>> = order.chunks(plan.batch_size).map(|c| c.to_vec()).collect();
    if plan.drop_last && groups.last().is_some_and(|g| g.len() < plan.batch_size) {
        groups.pop();
    }
    if world > 1 {
        for g in groups.iter_mut() {
            let n = g.len();
            if n < world {
                return Err(DataError::BatchNotShared {
                    batch: n,
                    ranks: world,
                });
            }
            *g = g[rank * n / world..(rank + 1) * n / world].to_vec();
        }
    }
    Ok(groups)
}

/// The threads of `--jobs N`: N, or every core for 0 (2 when the count is unknown).
pub fn loader_threads(jobs: usize) -> usize {
    match jobs {
        0 => std::thread::available_parallelism().map_or(2, |n| n.get()),
        n => n,
    }
}

/// The decoding thread pool: `jobs` threads (0 = all cores).
fn loader_pool(jobs: usize) -> Result<rayon::ThreadPool, DataError> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(loader_threads(jobs))
        .thread_name(|i| format!("loader-{i}"))
        .build()
        .map_err(|e| DataError::thread_start("loader threads", e))
}

impl Iterator for Loader {
    type Item = Result<Batch, DataError>;
    fn next(&mut self) -> Option<Self::Item> {
        self.rx.as_ref()?.recv().ok()
    }
}

impl Drop for Loader {
    fn drop(&mut self) {
        // Closing the receiver makes the producer's next send fail, so it stops.
        self.rx.take();
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// Build a tiny prepared dataset (for tests, benchmarks and examples): `scenes` scenes of
/// `per_scene` samples of `w`x`h` pixels, a ground plane whose depth grows towards the
/// horizon, radar strips at the true depth, conditions cycling day / night / rain.
pub fn write_toy_dataset(
    root: &Path,
    scenes: usize,
    per_scene: usize,
    w: u32,
    h: u32,
    seed: u64,
) -> Result<(), DataError> {
    use depthsense_base::fsutil::write_atomic;
    let mut index = PreparedIndex {
        version: "v1.0-toy".into(),
        samples: vec![],
        frame_size: Some([w, h]),
        ..PreparedIndex::default()
    };
    let mut rng = Rng::new(seed);
    for s in 0..scenes {
        let cond = [Condition::Day, Condition::Night, Condition::Rain][s % 3];
        for k in 0..per_scene {
            let token = format!("toy{s:03}{k:03}{:016x}", rng.next_u64());
            let dir = root.join(&token);
            std::fs::create_dir_all(&dir).map_err(|e| DataError::io(&dir, e))?;
            let offset = rng.range(0.8, 1.25) as f32;
            let mut maps = ToyMaps::ground(w, h, offset, cond);
            maps.add_radar(&mut rng);
            maps.write(&dir)?;
            let meta = toy_meta(&token, s, k, cond, w, h);
            let meta_bytes = serde_json::to_vec_pretty(&meta)
                .map_err(|e| DataError::encode(&dir.join(META_FILE), e))?;
            let p = dir.join(META_FILE);
            write_atomic(&p, &meta_bytes).map_err(|e| DataError::io(&p, e))?;
            index.samples.push(IndexEntry {
                sample_token: token.clone(),
                scene_token: format!("scene{s:04}"),
                scene_name: format!("toy-{s:04}"),
                splits: vec!["all".into()],
                conditions: vec![cond],
                dir: token,
            });
        }
    }
    let p = root.join(INDEX_FILE);
    let bytes = serde_json::to_vec_pretty(&index).map_err(|e| DataError::encode(&p, e))?;
    write_atomic(&p, &bytes).map_err(|e| DataError::io(&p, e))
}

/// The maps and image of one toy sample (see [`write_toy_dataset`]).
struct ToyMaps {
    dense: DepthMap,
    sparse: DepthMap,
    raw: DepthMap,
    height: DepthMap,
    low: image::GrayImage,
    img: image::RgbImage,
}

impl ToyMaps {
    /// The ground plane (depth scaled by `offset`, growing towards the horizon at 0.3·h),
    /// every third pixel as sparse GT, the low-height mask below 0.6·h and the image of the
    /// depth (darker at night); no radar yet.
    fn ground(w: u32, h: u32, offset: f32, cond: Condition) -> ToyMaps {
        let horizon = h as f32 * 0.3;
        let mut m = ToyMaps {
            dense: DepthMap::zeros(w, h),
            sparse: DepthMap::zeros(w, h),
            raw: DepthMap::zeros(w, h),
            height: DepthMap::zeros(w, h),
            low: image::GrayImage::new(w, h),
            img: image::RgbImage::new(w, h),
        };
        for v in 0..h {
            for u in 0..w {
                let i = (v * w + u) as usize;
                let d = if (v as f32) > horizon {
                    (offset * 4.0 * h as f32 / (v as f32 - horizon + 1.0)).min(79.0)
                } else {
                    79.0
                };
                m.dense.depth_m[i] = d;
                if (u + v) % 3 == 0 {
                    m.sparse.depth_m[i] = d;
                    if v as f32 > h as f32 * 0.6 {
                        m.low.put_pixel(u, v, image::Luma([255]));
                    }
                }
                let g = (255.0 * (1.0 - d / 80.0)) as u8;
                let night = cond == Condition::Night;
                m.img.put_pixel(
                    u,
                    v,
                    image::Rgb([
                        if night { g / 3 } else { g },
                        ((u * 7) % 255) as u8 / 2 + g / 2,
                        if night { 20 } else { 128 },
                    ]),
                );
            }
        }
        m
    }

    /// Four radar returns at the true depth, each with a height strip 6 px up and 1 down.
    fn add_radar(&mut self, rng: &mut Rng) {
        let (w, h) = (self.dense.width, self.dense.height);
        for _ in 0..4 {
            let u = (rng.uniform() * w as f64) as u32 % w;
            let v = (h as f64 * rng.range(0.5, 0.95)) as u32 % h;
            let d = self.dense.depth_m[(v * w + u) as usize];
            self.raw.depth_m[(v * w + u) as usize] = d;
            for vv in v.saturating_sub(6)..(v + 2).min(h) {
                self.height.depth_m[(vv * w + u) as usize] = d;
            }
        }
    }

    /// Write the four depth maps, the image and the low-height mask into `dir`.
    fn write(&self, dir: &Path) -> Result<(), DataError> {
        use depthsense_base::fsutil::write_atomic;
        use depthsense_nuscenes::depth_png::encode_png;
        let write = |name: &str, bytes: &[u8]| {
            let p = dir.join(name);
            write_atomic(&p, bytes).map_err(|e| DataError::io(&p, e))
        };
        let depth = |name: &str, m: &DepthMap| {
            write(
                name,
                &encode_png(m).map_err(|e| DataError::encode(&dir.join(name), e))?,
            )
        };
        depth(LIDAR_DENSE_FILE, &self.dense)?;
        depth(LIDAR_SPARSE_FILE, &self.sparse)?;
        depth(RADAR_RAW_FILE, &self.raw)?;
        depth(RADAR_HEIGHT_FILE, &self.height)?;
        let mut buf = std::io::Cursor::new(Vec::new());
        self.img
            .write_to(&mut buf, image::ImageFormat::Png)
            .map_err(|e| DataError::encode(&dir.join(IMAGE_FILE), e))?;
        write(IMAGE_FILE, buf.get_ref())?;
        let mut buf = std::io::Cursor::new(Vec::new());
        self.low
            .write_to(&mut buf, image::ImageFormat::Png)
            .map_err(|e| DataError::encode(&dir.join(LOWHEIGHT_MASK_FILE), e))?;
        write(LOWHEIGHT_MASK_FILE, buf.get_ref())
    }
}

/// `meta.json` of toy sample `k` of scene `s`: training-frame intrinsics with f = w at the
/// image centre, a full-resolution camera twice as large, identity lidar extrinsic.
fn toy_meta(
    token: &str,
    s: usize,
    k: usize,
    cond: Condition,
    w: u32,
    h: u32,
) -> depthsense_prep::layout::SampleMeta {
    let f = w as f64;
    depthsense_prep::layout::SampleMeta {
        sample_token: token.to_string(),
        scene_token: format!("scene{s:04}"),
        scene_name: format!("toy-{s:04}"),
        conditions: vec![cond],
        timestamp_us: (s * 1000 + k) as i64,
        sample_data_tokens: Default::default(),
        intrinsics_frame: [[f, 0.0, f / 2.0], [0.0, f, h as f64 / 2.0], [0.0, 0.0, 1.0]],
        intrinsics_full: [
            [2.0 * f, 0.0, f],
            [0.0, 2.0 * f, h as f64 + 200.0],
            [0.0, 0.0, 1.0],
        ],
        cam_from_lidar: identity4(),
        cam_from_radar: Default::default(),
        counts: Default::default(),
        settings: serde_json::json!({"toy": true}),
    }
}

pub(crate) fn identity4() -> [[f64; 4]; 4] {
    let mut m = [[0.0; 4]; 4];
    for (i, row) in m.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The loader's stream as it has been since issue 5 (every augmentation, radar corruption
    /// and toy dataset depends on it): state splitmix64(seed); each draw adds γ and returns
    /// splitmix64(state), i.e. the finaliser of state + 2γ on the first draw. Values from a Python
    /// transcription of that formula.
    #[test]
    fn the_loader_stream_is_unchanged() {
        let mut r = Rng::new(7);
        assert_eq!(r.next_u64(), 11984929618412882174);
        assert_eq!(r.next_u64(), 10134167572453724827);
    }

    fn entry(token: &str) -> IndexEntry {
        IndexEntry {
            sample_token: token.into(),
            scene_token: "t0".into(),
            scene_name: "scene-0".into(),
            splits: vec![],
            conditions: vec![],
            dir: token.into(),
        }
    }

    fn plan(samples: usize, batch_size: usize) -> EpochPlan {
        EpochPlan {
            entries: (0..samples).map(|i| entry(&format!("s{i}"))).collect(),
            batch_size,
            epoch: 0,
            shuffle: false,
            drop_last: false,
            skip_batches: 0,
            jobs: 1,
            prefetch: 1,
        }
    }

    /// A batch size of 0, and a batch of fewer samples than ranks, are refused with the sizes.
    #[test]
    fn batches_that_cannot_be_made_are_refused_with_their_sizes() {
        let opts = LoadOptions::default();
        // 5 samples in batches of 4: the last batch of 1 cannot be shared by 2 ranks.
        let e = batch_groups(&opts, &plan(5, 4), 0, 2).unwrap_err();
        assert!(matches!(
            e,
            DataError::BatchNotShared { batch: 1, ranks: 2 }
        ));
        assert_eq!(
            e.to_string(),
            "configuration: a batch of 1 sample(s) cannot be shared by 2 ranks"
        );
        assert_eq!(
            batch_groups(&opts, &plan(4, 4), 1, 2).unwrap(),
            [vec![2, 3]]
        );
        let ds = Dataset {
            root: "toy".into(),
            index: Default::default(),
        };
        let e = Loader::start(&ds, &opts, &plan(1, 0)).err().unwrap();
        assert!(matches!(e, DataError::ZeroBatchSize));
        assert_eq!(
            e.to_string(),
            "configuration: batch size must be at least 1"
        );
    }

    /// Samples of another frame or radar than their batch's are refused, naming the sample.
    #[test]
    fn a_sample_of_another_shape_than_its_batch_is_named() {
        let sample = |token: &str, width: usize, radar_channels: usize| Sample {
            token: token.into(),
            conditions: vec![],
            width,
            height: 2,
            image: vec![0.0; 3 * width * 2],
            radar: vec![0.0; radar_channels * width * 2],
            radar_channels,
            target_m: vec![0.0; width * 2],
            sparse_m: vec![],
            lowheight: vec![],
            flipped: false,
        };
        assert!(Batch::stack(0, vec![sample("a", 4, 1), sample("b", 4, 1)]).is_ok());
        let e = Batch::stack(0, vec![sample("a", 4, 1), sample("b", 4, 2)]).unwrap_err();
        assert!(matches!(
            &e,
            DataError::BatchMismatch {
                sample,
                shape: (4, 2, 2),
                batch: (4, 2, 1),
            } if sample == "b"
        ));
        assert_eq!(
            e.to_string(),
            "data: sample b is 4x2 with 2 radar channels, but the batch is 4x2 with 1"
        );
    }

    /// A sample folder that `prepare` did not finish (no meta.json) is an unreadable sample,
    /// named with its reason, like a truncated file.
    #[test]
    fn an_incomplete_sample_is_an_unreadable_one() {
        let d = tempfile::tempdir().unwrap();
        std::fs::create_dir(d.path().join("s0")).unwrap();
        let ds = Dataset {
            root: d.path().to_path_buf(),
            index: Default::default(),
        };
        let mut rng = Rng::new(0);
        let e = load_sample(&ds, &entry("s0"), &LoadOptions::default(), &mut rng).unwrap_err();
        let DataError::Unreadable { root, samples } = e else {
            panic!("{e}");
        };
        assert_eq!(root, d.path().display().to_string());
        let why = format!(
            "{}: incomplete sample directory (no {META_FILE})",
            d.path().join("s0").display()
        );
        assert_eq!(samples, [("s0".to_string(), why)]);
    }
}
