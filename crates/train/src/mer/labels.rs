//! Association labels of MER (SPEC §5) from `prepare` output, and the network inputs on the
//! MER grid.
//!
//! Grid: the training frame (800x350, SPEC §3) divided by `PdaConfig::grid_scale` (2 →
//! 400x175). SPEC §5's window (2 px left/right, 30 up, 5 down) is given "at 1/4 resolution",
//! which in RC-PDA is 1/4 of the 1600x900 camera image; our training frame is already 1/2 of
//! it, so the same window covers the same part of the scene on a grid of 1/2 the training frame.
//! Radar and lidar are reduced to the grid keeping the nearest depth of each cell (SPEC §4–5:
//! nearest wins); the image is averaged.
//!
//! Labels: for each radar pixel r (depth d_r ≤ 50 m) and each neighbour n of its window,
//! 1 when the accumulated lidar depth d_l at n (≤ 50 m) satisfies |d_l − d_r| < 1 m and
//! |d_l − d_r| / d_l < 5 %, 0 when lidar is there but outside the thresholds, and
//! [`UNLABELLED`] when n lies outside the image, has no lidar or lidar beyond 50 m.

use std::path::Path;

use depthsense_model::pda::PdaConfig;
use depthsense_prep::layout::{IMAGE_FILE, LIDAR_DENSE_FILE, META_FILE, RADAR_RAW_FILE};

use crate::data::{decode_rgb, normalise_image, read_depth, Augment};
use crate::error::TrainError;

/// Label of a neighbour without lidar, outside the image, or beyond the depth limit.
pub const UNLABELLED: i8 = -1;

/// The MER grid: `w`x`h` cells of `scale`x`scale` training-frame pixels (the last row/column
/// of cells may be partial).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Grid {
    pub w: usize,
    pub h: usize,
    pub scale: usize,
    /// The training frame it covers.
    pub frame_w: usize,
    pub frame_h: usize,
}

impl Grid {
    pub fn new(frame_w: usize, frame_h: usize, scale: usize) -> Self {
        let scale = scale.max(1);
        Grid {
            w: frame_w.div_ceil(scale),
            h: frame_h.div_ceil(scale),
            scale,
            frame_w,
            frame_h,
        }
    }

    pub fn len(&self) -> usize {
        self.w * self.h
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Grid cell of each frame pixel, row-major over the frame.
    fn cell(&self, u: usize, v: usize) -> usize {
        (v / self.scale) * self.w + u / self.scale
    }

    /// Nearest non-zero depth of each cell (0 = none).
    pub fn nearest_depth(&self, frame: &[f32]) -> Vec<f32> {
        let mut out = vec![0f32; self.len()];
        for v in 0..self.frame_h {
            for u in 0..self.frame_w {
                let d = frame[v * self.frame_w + u];
                let c = &mut out[self.cell(u, v)];
                if d > 0.0 && (*c == 0.0 || d < *c) {
                    *c = d;
                }
            }
        }
        out
    }

    /// Mean of each cell of `planes` channel-major `[C, frame_h, frame_w]` → `[C, h, w]`.
    pub fn mean_planes(&self, planes: &[f32], channels: usize) -> Vec<f32> {
        let fplane = self.frame_w * self.frame_h;
        let mut out = vec![0f32; channels * self.len()];
        let mut count = vec![0f32; self.len()];
        for v in 0..self.frame_h {
            for u in 0..self.frame_w {
                count[self.cell(u, v)] += 1.0;
            }
        }
        for c in 0..channels {
            let src = &planes[c * fplane..(c + 1) * fplane];
            let dst = &mut out[c * self.len()..(c + 1) * self.len()];
            for v in 0..self.frame_h {
                for u in 0..self.frame_w {
                    dst[self.cell(u, v)] += src[v * self.frame_w + u];
                }
            }
            for (d, n) in dst.iter_mut().zip(&count) {
                *d /= n.max(1.0);
            }
        }
        out
    }

    /// A grid map back on the frame: every frame pixel takes its cell's value.
    pub fn to_frame(&self, grid: &[f32]) -> Vec<f32> {
        let mut out = vec![0f32; self.frame_w * self.frame_h];
        for v in 0..self.frame_h {
            for u in 0..self.frame_w {
                out[v * self.frame_w + u] = grid[self.cell(u, v)];
            }
        }
        out
    }
}

/// One radar pixel of the grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RadarPixel {
    pub u: usize,
    pub v: usize,
    pub depth_m: f32,
}

/// Radar pixels of a grid map in raster order, those beyond `max_depth_m` dropped (SPEC §5).
pub fn radar_pixels(radar: &[f32], g: &Grid, max_depth_m: f64) -> Vec<RadarPixel> {
    radar
        .iter()
        .enumerate()
        .filter(|(_, &d)| d > 0.0 && d as f64 <= max_depth_m)
        .map(|(i, &d)| RadarPixel {
            u: i % g.w,
            v: i / g.w,
            depth_m: d,
        })
        .collect()
}

/// The label of one (radar depth, lidar depth) pair (SPEC §5).
pub fn pair_label(d_radar: f32, d_lidar: f32, cfg: &PdaConfig) -> i8 {
    let (dr, dl) = (d_radar as f64, d_lidar as f64);
    if dl <= 0.0 || dl > cfg.max_depth_m {
        return UNLABELLED;
    }
    let diff = (dl - dr).abs();
    i8::from(diff < cfg.abs_threshold_m && diff / dl < cfg.rel_threshold)
}

/// Grid index of the neighbour at offset (dx, dy) of (u, v), None outside the grid.
pub fn neighbour(g: &Grid, u: usize, v: usize, dx: i64, dy: i64) -> Option<usize> {
    let (x, y) = (u as i64 + dx, v as i64 + dy);
    (x >= 0 && y >= 0 && (x as usize) < g.w && (y as usize) < g.h)
        .then(|| y as usize * g.w + x as usize)
}

/// Labels `[N, K]` (row-major) of N radar pixels against the grid lidar map.
pub fn labels(pixels: &[RadarPixel], lidar: &[f32], g: &Grid, cfg: &PdaConfig) -> Vec<i8> {
    let offsets = cfg.window.offsets();
    let mut out = Vec::with_capacity(pixels.len() * offsets.len());
    for p in pixels {
        for &(dx, dy) in &offsets {
            out.push(match neighbour(g, p.u, p.v, dx, dy) {
                Some(n) => pair_label(p.depth_m, lidar[n], cfg),
                None => UNLABELLED,
            });
        }
    }
    out
}

/// The network input of one sample on the MER grid.
#[derive(Debug, Clone)]
pub struct PdaInput {
    pub grid: Grid,
    /// `[3, h, w]` ImageNet-normalised, averaged per cell.
    pub image: Vec<f32>,
    /// `[h, w]` nearest radar depth per cell (all depths; the network sees every return).
    pub radar: Vec<f32>,
    /// Radar pixels with labels (≤ max depth), raster order.
    pub pixels: Vec<RadarPixel>,
}

fn flip_grid(v: &mut [f32], w: usize) {
    for row in v.chunks_mut(w) {
        row.reverse();
    }
}

/// Builds a [`PdaInput`] from frame-resolution RGB and raw radar, optionally flipped.
pub fn pda_input(
    rgb: &image::RgbImage,
    radar_raw: &[f32],
    cfg: &PdaConfig,
    flip: bool,
) -> PdaInput {
    let (fw, fh) = (rgb.width() as usize, rgb.height() as usize);
    let g = Grid::new(fw, fh, cfg.grid_scale as usize);
    let mut image = g.mean_planes(&normalise_image(rgb, &Augment::NONE), 3);
    let mut radar = g.nearest_depth(radar_raw);
    if flip {
        for c in 0..3 {
            flip_grid(&mut image[c * g.len()..(c + 1) * g.len()], g.w);
        }
        flip_grid(&mut radar, g.w);
    }
    let pixels = radar_pixels(&radar, &g, cfg.max_depth_m);
    PdaInput {
        grid: g,
        image,
        radar,
        pixels,
    }
}

/// Reads a prepared sample's image and raw radar → [`PdaInput`].
pub fn load_input(dir: &Path, cfg: &PdaConfig, flip: bool) -> Result<PdaInput, TrainError> {
    if !dir.join(META_FILE).exists() {
        return Err(TrainError::Data(format!(
            "{}: incomplete sample directory (no {META_FILE})",
            dir.display()
        )));
    }
    let rgb = decode_rgb(&dir.join(IMAGE_FILE))?;
    let rp = dir.join(RADAR_RAW_FILE);
    let raw = read_depth(&rp)?;
    if (raw.width, raw.height) != rgb.dimensions() {
        return Err(TrainError::Data(format!(
            "{}: {}x{} but the image is {}x{}",
            rp.display(),
            raw.width,
            raw.height,
            rgb.width(),
            rgb.height()
        )));
    }
    Ok(pda_input(&rgb, &raw.depth_m, cfg, flip))
}

/// SPEC §4–5: labels need the accumulated lidar (`prepare --lidar-sweeps K`, K > 0). A sample
/// whose meta.json records K = 0 is refused; one without the setting is taken as it is.
pub fn check_accumulated(dir: &Path) -> Result<(), TrainError> {
    let p = dir.join(META_FILE);
    let bytes = std::fs::read(&p).map_err(|e| TrainError::io(&p, e))?;
    let meta: serde_json::Value =
        serde_json::from_slice(&bytes).map_err(|e| TrainError::Parse {
            path: p.display().to_string(),
            reason: e.to_string(),
        })?;
    if meta["settings"]["lidar_sweeps_k"].as_u64() == Some(0) {
        return Err(TrainError::Data(format!(
            "{}: prepared with --lidar-sweeps 0; MER association labels need the accumulated \
             lidar of `depthsense prepare --lidar-sweeps K` with K > 0 (SPEC §4–5)",
            p.display()
        )));
    }
    Ok(())
}

/// A labelled training sample: input and `[N, K]` labels.
pub fn load_labelled(
    dir: &Path,
    cfg: &PdaConfig,
    flip: bool,
) -> Result<(PdaInput, Vec<i8>), TrainError> {
    check_accumulated(dir)?;
    let input = load_input(dir, cfg, flip)?;
    let lp = dir.join(LIDAR_DENSE_FILE);
    if !lp.exists() {
        return Err(TrainError::Data(format!(
            "{}: missing; MER labels need the accumulated lidar map of `depthsense prepare \
             --lidar-sweeps K` (K > 0, SPEC §5)",
            lp.display()
        )));
    }
    let dense = read_depth(&lp)?;
    let g = input.grid;
    if (dense.width as usize, dense.height as usize) != (g.frame_w, g.frame_h) {
        return Err(TrainError::Data(format!(
            "{}: {}x{} but the image is {}x{}",
            lp.display(),
            dense.width,
            dense.height,
            g.frame_w,
            g.frame_h
        )));
    }
    let mut lidar = g.nearest_depth(&dense.depth_m);
    if flip {
        flip_grid(&mut lidar, g.w);
    }
    let l = labels(&input.pixels, &lidar, &g, cfg);
    Ok((input, l))
}
