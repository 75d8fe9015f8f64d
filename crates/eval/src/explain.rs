//! Grad-CAM++ by distance class (SPEC §10.6), `depthsense explain`.
//!
//! **Target.** For a distance d (metres) and a band half-width b (default 0.1, i.e. ±10 %):
//! - the thresholds at d are the SID thresholds t_i (SPEC §7, i = 1..K) with
//!   t_i ∈ [(1 − b)·d, (1 + b)·d], or the single t_i nearest d when none is;
//! - the ordinal evidence "depth beyond t_i" is the logit difference z_{i−1} = b − a of the
//!   pair whose probability is P(label ≥ i) = P(depth ≥ t_i), upsampled bilinearly to the
//!   output resolution (exact: upsampling is linear, SPEC §7);
//! - the band B_d is the set of pixels whose sparse lidar GT lies in [(1 − b)·d, (1 + b)·d];
//! - the target is S_d = Σ_{p ∈ B_d} Σ_{i at d} z_{i−1}(p).
//!
//! **Grad-CAM++** (Chattopadhyay et al., 2018, with the exponential target so that higher
//! derivatives are powers of the first): for activations A^c (channel c of the chosen layer,
//! h×w) and g = ∂S_d/∂A,
//! α^c_xy = g² / (2 g² + Σ_ab A^c_ab · g³)  (0 where the denominator is 0),
//! w_c = Σ_xy α^c_xy · relu(g^c_xy),  L = relu(Σ_c w_c A^c),
//! upsampled bilinearly to the image and divided by its maximum (heat in [0, 1]).
//!
//! **Heat inside the band**: of the heat on pixels that have lidar GT, the fraction on pixels
//! of B_d (Σ_{B_d} L / Σ_{GT > 0} L); compare with |B_d| / |GT > 0|, the fraction a heat map
//! spread evenly would give ("chance").
//!
//! Layers: `rgb.layer1` … `rgb.layer4` (RGB encoder C1..C4), `decoder`, and `radar` (the
//! radar branch output, late fusion). Fusion models are explained with radar and with radar
//! zeroed.

use std::path::{Path, PathBuf};

use depthsense_base::fsutil::write_atomic;
use depthsense_config::refusal::ExplainRefusal;
use depthsense_config::{HeadKind, SidConfig};
use depthsense_data::{normalise_image, Augment};
use depthsense_dataset::DataError;
use depthsense_infer::NetError;
use depthsense_metrics::doc::{Doc, Documented};
use depthsense_metrics::table::{md_num, Align, MdTable};
use depthsense_model::{ordinal, sid, DepthNet};
use depthsense_nuscenes::depth_png::DepthMap;
use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Tensor};

use crate::predict::PredictInput;

/// Grad-CAM++ map of activations `a` `[C,h,w]` for gradients `g` = ∂S/∂A `[C,h,w]` → `[h,w]`
/// (module docs; not normalised).
pub fn gradcam_pp(a: &Tensor, g: &Tensor) -> Tensor {
    let g2 = g.pow_tensor_scalar(2);
    let g3 = g.pow_tensor_scalar(3);
    let sum_a = a.sum_dim_intlist([1i64, 2].as_slice(), true, a.kind());
    let denom = &g2 * 2.0 + sum_a * &g3;
    let nonzero = denom.ne(0.0);
    let safe = denom.where_self(&nonzero, &denom.ones_like());
    let alpha = (&g2 / safe) * nonzero.to_kind(a.kind());
    let w = (alpha * g.relu()).sum_dim_intlist([1i64, 2].as_slice(), true, a.kind());
    (w * a)
        .sum_dim_intlist([0i64].as_slice(), false, Kind::Float)
        .relu()
}

/// Ordinal channels k = i − 1 of the thresholds at `d` (module docs).
pub fn channels_at(s: &SidConfig, d: f64, band: f64) -> Vec<i64> {
    let t = sid::thresholds_m(s); // t_0..t_K
    let mut ks: Vec<i64> = (1..t.len())
        .filter(|&i| t[i] >= (1.0 - band) * d && t[i] <= (1.0 + band) * d)
        .map(|i| i as i64 - 1)
        .collect();
    if ks.is_empty() {
        let i = (1..t.len())
            .min_by(|&a, &b| (t[a] - d).abs().total_cmp(&(t[b] - d).abs()))
            .unwrap_or(1);
        ks.push(i as i64 - 1);
    }
    ks
}

/// Band mask `[H,W]` (float 0/1) of the GT `[H,W]` around `d`.
pub fn band_mask(gt: &Tensor, d: f64, band: f64) -> Tensor {
    (gt.ge((1.0 - band) * d)
        .logical_and(&gt.le((1.0 + band) * d)))
    .to_kind(Kind::Float)
}

/// S_d of full-resolution logit differences `z` `[1,K,H,W]`.
pub fn evidence(z: &Tensor, mask: &Tensor, channels: &[i64]) -> Tensor {
    let idx = Tensor::from_slice(channels).to_device(z.device());
    let zk = z
        .index_select(1, &idx)
        .sum_dim_intlist([1i64].as_slice(), false, Kind::Float);
    (zk.squeeze_dim(0) * mask).sum(z.kind())
}

/// One Grad-CAM++ map.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CamRecord {
    pub sample: String,
    pub distance_m: f64,
    pub layer: String,
    pub radar: bool,
    pub channels: Vec<i64>,
    pub band_pixels: u64,
    pub gt_pixels: u64,
    /// Σ_{B_d} heat / Σ_{GT>0} heat (None when no heat on GT pixels).
    pub heat_in_band: Option<f64>,
    /// |B_d| / |GT > 0|.
    pub chance: f64,
    pub target: f64,
    pub overlay: PathBuf,
}

/// One map of [`explain_image`]: (heat `[H,W]` in [0,1], distance, layer, ordinal channels,
/// target S_d).
pub type CamMap = (Vec<f32>, f64, String, Vec<i64>, f64);

/// Grad-CAM++ maps of `layers` for `distances`, one image: returns (heat `[H,W]` in
/// [0,1], record) per (distance, layer). `radar` zeroed when `with_radar` is false.
#[allow(clippy::too_many_arguments)]
pub fn explain_image(
    net: &DepthNet,
    image: &Tensor,
    radar: &Tensor,
    gt: &Tensor,
    distances: &[f64],
    band: f64,
    layers: &[String],
    with_radar: bool,
) -> Result<Vec<CamMap>, NetError> {
    let cfg = net.config();
    if cfg.head != HeadKind::Ordinal || cfg.clamp_logits {
        return Err(ExplainRefusal::NotOrdinal.into());
    }
    let (h, w) = (cfg.out_height, cfg.out_width);
    let radar = if with_radar {
        radar.shallow_clone()
    } else {
        radar.zeros_like()
    };
    let mut out = vec![];
    for &d in distances {
        let mut taps: Vec<(String, Tensor)> = vec![];
        let logits = net.forward_logits_tap(image, &radar, false, &mut |n, t| {
            if layers.iter().any(|l| l == n) {
                taps.push((n.to_string(), t.shallow_clone()));
            }
        });
        let z = ordinal::upsample(&ordinal::pair_differences(&logits), h, w, cfg.align_corners);
        let mask = band_mask(gt, d, band);
        let ch = channels_at(&cfg.sid, d, band);
        let s = evidence(&z, &mask, &ch);
        if taps.is_empty() {
            return Err(ExplainRefusal::NoSuchLayers(layers.to_vec()).into());
        }
        let inputs: Vec<&Tensor> = taps.iter().map(|(_, t)| t).collect();
        let grads = Tensor::run_backward(&[&s], &inputs, false, false);
        for ((name, a), g) in taps.iter().zip(&grads) {
            let cam = gradcam_pp(&a.get(0).detach(), &g.get(0));
            let up = cam
                .unsqueeze(0)
                .unsqueeze(0)
                .upsample_bilinear2d([h, w], false, None, None)
                .squeeze();
            let mx = up.max().double_value(&[]);
            let up = if mx > 0.0 { up / mx } else { up };
            let v: Vec<f32> =
                Vec::<f32>::try_from(up.to_device(Device::Cpu).contiguous().view([-1]))?;
            out.push((v, d, name.clone(), ch.clone(), s.double_value(&[])));
        }
    }
    Ok(out)
}

/// Heat inside the band and chance (module docs) of `heat` for GT `gt_m` at `d`.
pub fn heat_fraction(
    heat: &[f32],
    gt_m: &[f32],
    d: f64,
    band: f64,
) -> (Option<f64>, f64, u64, u64) {
    let (mut in_b, mut on_gt, mut nb, mut ng) = (0f64, 0f64, 0u64, 0u64);
    for (hv, g) in heat.iter().zip(gt_m) {
        if *g > 0.0 {
            ng += 1;
            on_gt += *hv as f64;
            let g = *g as f64;
            if g >= (1.0 - band) * d && g <= (1.0 + band) * d {
                nb += 1;
                in_b += *hv as f64;
            }
        }
    }
    let frac = (on_gt > 0.0).then(|| in_b / on_gt);
    (frac, nb as f64 / ng.max(1) as f64, nb, ng)
}

/// Image blended with the heat (turbo) and the band's GT pixels in white.
pub fn overlay(
    img: &image::RgbImage,
    heat: &[f32],
    gt_m: &[f32],
    d: f64,
    band: f64,
) -> image::RgbImage {
    let mut o = img.clone();
    for (i, p) in o.pixels_mut().enumerate() {
        let c = colorous::TURBO.eval_continuous(heat[i].clamp(0.0, 1.0) as f64);
        let a = 0.5;
        for (k, v) in [c.r, c.g, c.b].into_iter().enumerate() {
            p.0[k] = ((1.0 - a) * p.0[k] as f32 + a * v as f32) as u8;
        }
        let g = gt_m[i] as f64;
        if g >= (1.0 - band) * d && g <= (1.0 + band) * d {
            p.0 = [255, 255, 255];
        }
    }
    o
}

/// Everything `explain` wrote (= explain.json).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ExplainResult {
    pub checkpoint: PathBuf,
    pub band: f64,
    pub records: Vec<CamRecord>,
    pub grid: PathBuf,
    pub command_line: Option<String>,
}

/// Explain prepared samples `dirs`; writes overlays, `grid.png`, `explain.json`, `explain.md`.
#[allow(clippy::too_many_arguments)]
pub fn run_explain(
    net: &DepthNet,
    checkpoint: &Path,
    dirs: &[PathBuf],
    distances: &[f64],
    band: f64,
    layers: &[String],
    out: &Path,
    device: Device,
    command_line: Option<String>,
) -> Result<ExplainResult, NetError> {
    std::fs::create_dir_all(out).map_err(|e| NetError::io(out, e))?;
    let cfg = net.config().clone();
    let radar_input = cfg.radar_input_for(None)?;
    let mut records = vec![];
    let mut tiles: Vec<Vec<image::RgbImage>> = vec![];
    for dir in dirs {
        let input = crate::predict::input_from_prepared(dir)?;
        let gt = input.gt.clone().ok_or_else(|| DataError::NoGroundTruth {
            dir: dir.to_path_buf(),
            needs: "explain",
        })?;
        let (img, radar, gt_t) = sample_tensors(&input, &gt, radar_input, device)?;
        let states: &[bool] = if radar_input.is_some() {
            &[true, false]
        } else {
            &[false]
        };
        let mut row_tiles = vec![];
        for &with_radar in states {
            let maps = explain_image(
                net, &img, &radar, &gt_t, distances, band, layers, with_radar,
            )?;
            for map in maps {
                let (ov, record) = record_map(out, &input, &gt.depth_m, band, with_radar, map)?;
                row_tiles.push(ov);
                records.push(record);
            }
        }
        tiles.push(row_tiles);
    }
    let r = ExplainResult {
        checkpoint: checkpoint.to_path_buf(),
        band,
        records,
        grid: PathBuf::from("grid.png"),
        command_line,
    };
    write_results(out, &r, &tiles)?;
    Ok(r)
}

/// One map of a sample: its overlay written to `out` (`<sample>_<d>m_<layer>_<radar>.png`)
/// and returned with its record (heat inside the band of ±`band` around the distance, chance).
fn record_map(
    out: &Path,
    input: &PredictInput,
    gt_m: &[f32],
    band: f64,
    with_radar: bool,
    (heat, d, layer, ch, target): CamMap,
) -> Result<(image::RgbImage, CamRecord), NetError> {
    let (frac, chance, nb, ng) = heat_fraction(&heat, gt_m, d, band);
    let ov = overlay(&input.image, &heat, gt_m, d, band);
    let name = format!(
        "{}_{}m_{}_{}.png",
        input.name,
        d,
        layer,
        if with_radar { "radar" } else { "noradar" }
    );
    let p = out.join(&name);
    write_atomic(&p, &depthsense_viz::plot::encode_rgb(&ov)?).map_err(|e| NetError::io(&p, e))?;
    let record = CamRecord {
        sample: input.name.clone(),
        distance_m: d,
        layer,
        radar: with_radar,
        channels: ch,
        band_pixels: nb,
        gt_pixels: ng,
        heat_in_band: frac,
        chance,
        target,
        overlay: PathBuf::from(name),
    };
    Ok((ov, record))
}

/// One sample as the network sees it: image [1,3,H,W], radar [1,1,H,W] (raw or height map;
/// zeros without radar) and lidar GT [H,W] metres, on `device`.
fn sample_tensors(
    input: &PredictInput,
    gt: &DepthMap,
    radar_input: Option<depthsense_config::RadarInput>,
    device: Device,
) -> Result<(Tensor, Tensor, Tensor), NetError> {
    let (w, h) = input.image.dimensions();
    let img = Tensor::from_slice(&normalise_image(&input.image, &Augment::NONE))
        .view([1, 3, h as i64, w as i64])
        .to_device(device);
    let planes: Vec<f32> = match radar_input {
        None => vec![0.0; (w * h) as usize],
        Some(depthsense_config::RadarInput::Raw) => input.radar_raw.depth_m.clone(),
        Some(depthsense_config::RadarInput::Height) => input.radar_height.depth_m.clone(),
        Some(r) => return Err(ExplainRefusal::RadarInput(r).into()),
    };
    let radar = Tensor::from_slice(&planes)
        .view([1, 1, h as i64, w as i64])
        .to_device(device);
    let gt_t = Tensor::from_slice(&gt.depth_m)
        .view([h as i64, w as i64])
        .to_device(device);
    Ok((img, radar, gt_t))
}

/// grid.png (every overlay, one row per sample), explain.json and explain.md.
fn write_results(
    out: &Path,
    r: &ExplainResult,
    tiles: &[Vec<image::RgbImage>],
) -> Result<(), NetError> {
    let grid = out.join("grid.png");
    write_atomic(
        &grid,
        &depthsense_viz::plot::encode_rgb(&grid_image(tiles))?,
    )
    .map_err(|e| NetError::io(&grid, e))?;
    let doc = document(r);
    let json = serde_json::to_string_pretty(&Documented {
        record: r,
        document: &doc,
    })?;
    let jp = out.join("explain.json");
    write_atomic(&jp, json.as_bytes()).map_err(|e| NetError::io(&jp, e))?;
    let mp = out.join("explain.md");
    write_atomic(&mp, doc.to_markdown().as_bytes()).map_err(|e| NetError::io(&mp, e))?;
    Ok(())
}

/// Tiles in rows (one row per sample), a heat colour bar (0 → 1, turbo) at the bottom.
fn grid_image(rows: &[Vec<image::RgbImage>]) -> image::RgbImage {
    let (tw, th) = rows
        .iter()
        .flatten()
        .next()
        .map_or((1, 1), |t| (t.width(), t.height()));
    let cols = rows.iter().map(|r| r.len()).max().unwrap_or(1).max(1) as u32;
    let bar = 12u32;
    let mut g = image::RgbImage::from_pixel(
        cols * tw,
        rows.len() as u32 * th + bar,
        image::Rgb([255, 255, 255]),
    );
    for (ri, r) in rows.iter().enumerate() {
        for (ci, t) in r.iter().enumerate() {
            image::imageops::replace(&mut g, t, (ci as u32 * tw) as i64, (ri as u32 * th) as i64);
        }
    }
    let y0 = rows.len() as u32 * th;
    for x in 0..g.width() {
        let c = colorous::TURBO.eval_continuous(x as f64 / (g.width().max(2) - 1) as f64);
        for y in y0..y0 + bar {
            g.put_pixel(x, y, image::Rgb([c.r, c.g, c.b]));
        }
    }
    g
}

/// The heat table with its reading (explain.md, and the report's section).
fn document(r: &ExplainResult) -> Doc {
    let mut doc = Doc::new();
    doc.heading(1, "Grad-CAM++ by distance class (SPEC §10.6)")
        .paragraph(
            "Target, band and heat fraction: docs/guide/experiments.md, \"Grad-CAM++ by distance \
         class\". Heat in band vs chance (the fraction an even heat map would give).",
        );
    let mut t = MdTable::new(&[
        ("sample", Align::Left),
        ("d (m)", Align::Right),
        ("layer", Align::Left),
        ("radar", Align::Left),
        ("band px", Align::Right),
        ("heat in band", Align::Right),
        ("chance", Align::Right),
    ]);
    for x in &r.records {
        t.row(&[
            x.sample.to_string(),
            x.distance_m.to_string(),
            x.layer.to_string(),
            (if x.radar { "yes" } else { "zeroed" }).to_string(),
            x.band_pixels.to_string(),
            md_num(x.heat_in_band, 3),
            format!("{:.3}", x.chance),
        ]);
    }
    doc.table(t)
        .paragraph(format!(
            "Grid (`{}`): one row per sample; columns: for each radar state (with, then zeroed), \
             for each distance, each layer; white = lidar pixels in the band; colour bar: heat 0 \
             → 1 (turbo).",
            r.grid.display()
        ))
        .command(r.command_line.as_deref());
    doc
}

#[cfg(test)]
mod tests;
