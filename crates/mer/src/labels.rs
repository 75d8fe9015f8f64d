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

use depthsense_config::pda::PdaConfig;
use depthsense_data::{IMAGENET_MEAN, IMAGENET_STD};
use depthsense_dataset::{decode_rgb, read_depth, DataError};
use depthsense_prep::layout::{IMAGE_FILE, LIDAR_DENSE_FILE, META_FILE, RADAR_RAW_FILE};

use depthsense_infer::NetError;

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

    /// Grid column of each frame column (rows go the same way: v / scale).
    fn cell_columns(&self) -> Vec<usize> {
        (0..self.frame_w).map(|u| u / self.scale).collect()
    }

    /// Nearest non-zero depth of each cell (0 = none).
    pub fn nearest_depth(&self, frame: &[f32]) -> Vec<f32> {
        let cols = self.cell_columns();
        let mut out = vec![0f32; self.len()];
        for (v, row) in frame
            .chunks_exact(self.frame_w)
            .take(self.frame_h)
            .enumerate()
        {
            let gv = v / self.scale;
            let dst = &mut out[gv * self.w..(gv + 1) * self.w];
            for (&d, &gu) in row.iter().zip(&cols) {
                let c = &mut dst[gu];
                if d > 0.0 && (*c == 0.0 || d < *c) {
                    *c = d;
                }
            }
        }
        out
    }

    /// The ImageNet-normalised image averaged over each cell → `[3, h, w]` channel-major:
    /// the mean of [`depthsense_data::normalise_image`] over the cell, computed as the normalised
    /// mean of the 8-bit values (normalisation is affine: the two agree to float rounding).
    pub fn mean_image(&self, rgb: &image::RgbImage) -> Vec<f32> {
        let cols = self.cell_columns();
        let mut sum = vec![0u32; 3 * self.len()];
        for (v, row) in rgb.rows().enumerate().take(self.frame_h) {
            let base = (v / self.scale) * self.w;
            for (px, &gu) in row.zip(&cols) {
                let cell = base + gu;
                for c in 0..3 {
                    sum[c * self.len() + cell] += u32::from(px.0[c]);
                }
            }
        }
        // frame pixels per cell: (columns in the cell) × (rows in the cell)
        let n = |g: usize, len: usize| (len.min((g + 1) * self.scale) - g * self.scale) as f32;
        sum.iter()
            .enumerate()
            .map(|(i, &s)| {
                let (c, cell) = (i / self.len(), i % self.len());
                let count = n(cell % self.w, self.frame_w) * n(cell / self.w, self.frame_h);
                (s as f32 / (255.0 * count) - IMAGENET_MEAN[c]) / IMAGENET_STD[c]
            })
            .collect()
    }

    /// A grid map back on the frame: every frame pixel takes its cell's value.
    pub fn to_frame<T: Copy + Default>(&self, grid: &[T]) -> Vec<T> {
        let cols = self.cell_columns();
        let mut out = vec![T::default(); self.frame_w * self.frame_h];
        for (v, row) in out.chunks_exact_mut(self.frame_w).enumerate() {
            let src = &grid[(v / self.scale) * self.w..(v / self.scale + 1) * self.w];
            for (o, &gu) in row.iter_mut().zip(&cols) {
                *o = src[gu];
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
    let mut image = g.mean_image(rgb);
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

/// What the accumulated lidar is needed for here, in the data errors.
const MER_LABELS: &str = "MER association labels";

/// Reads a prepared sample's image and raw radar → [`PdaInput`].
pub fn load_input(dir: &Path, cfg: &PdaConfig, flip: bool) -> Result<PdaInput, NetError> {
    if !dir.join(META_FILE).exists() {
        return Err(DataError::IncompleteSample {
            dir: dir.to_path_buf(),
        }
        .into());
    }
    let rgb = decode_rgb(&dir.join(IMAGE_FILE))?;
    let rp = dir.join(RADAR_RAW_FILE);
    let raw = read_depth(&rp)?;
    if (raw.width, raw.height) != rgb.dimensions() {
        return Err(DataError::MapSize {
            path: rp,
            size: (raw.width as usize, raw.height as usize),
            image: (rgb.width() as usize, rgb.height() as usize),
        }
        .into());
    }
    Ok(pda_input(&rgb, &raw.depth_m, cfg, flip))
}

/// SPEC §4–5: labels need the accumulated lidar (`prepare --lidar-sweeps K`, K > 0). A sample
/// whose meta.json records K = 0 is refused; one without the setting is taken as it is.
pub fn check_accumulated(dir: &Path) -> Result<(), NetError> {
    let p = dir.join(META_FILE);
    let bytes = std::fs::read(&p).map_err(|e| NetError::io(&p, e))?;
    let meta: serde_json::Value = serde_json::from_slice(&bytes).map_err(|e| NetError::Parse {
        path: p.to_path_buf(),
        reason: e.to_string(),
    })?;
    if meta["settings"]["lidar_sweeps_k"].as_u64() == Some(0) {
        return Err(DataError::NotAccumulated {
            meta: p,
            needs: MER_LABELS,
        }
        .into());
    }
    Ok(())
}

/// A labelled training sample: input and `[N, K]` labels.
pub fn load_labelled(
    dir: &Path,
    cfg: &PdaConfig,
    flip: bool,
) -> Result<(PdaInput, Vec<i8>), NetError> {
    check_accumulated(dir)?;
    let input = load_input(dir, cfg, flip)?;
    let lp = dir.join(LIDAR_DENSE_FILE);
    if !lp.exists() {
        return Err(DataError::NoAccumulatedLidar {
            path: lp,
            needs: MER_LABELS,
        }
        .into());
    }
    let dense = read_depth(&lp)?;
    let g = input.grid;
    if (dense.width as usize, dense.height as usize) != (g.frame_w, g.frame_h) {
        return Err(DataError::MapSize {
            path: lp,
            size: (dense.width as usize, dense.height as usize),
            image: (g.frame_w, g.frame_h),
        }
        .into());
    }
    let mut lidar = g.nearest_depth(&dense.depth_m);
    if flip {
        flip_grid(&mut lidar, g.w);
    }
    let l = labels(&input.pixels, &lidar, &g, cfg);
    Ok((input, l))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The per-pixel definitions, for frames whose size is not a multiple of the scale.
    #[test]
    fn grid_maps_match_their_per_pixel_definition() {
        let (fw, fh, s) = (11usize, 7usize, 3usize);
        let g = Grid::new(fw, fh, s);
        assert_eq!((g.w, g.h), (4, 3));
        let frame: Vec<f32> = (0..fw * fh)
            .map(|i| ((i * 37 % 17) as f32 - 6.0).max(0.0) * 1.5)
            .collect();
        let rgb = image::RgbImage::from_fn(fw as u32, fh as u32, |u, v| {
            image::Rgb([
                (u * 23 + v * 7) as u8,
                (u * v * 31) as u8,
                (255 - u * 9) as u8,
            ])
        });
        let planes = depthsense_data::normalise_image(&rgb, &depthsense_data::Augment::NONE);
        let cell = |u: usize, v: usize| (v / s) * g.w + u / s;
        let (mut sum, mut n, mut near) = (
            vec![0f32; 3 * g.len()],
            vec![0f32; g.len()],
            vec![0f32; g.len()],
        );
        for v in 0..fh {
            for u in 0..fw {
                let c = cell(u, v);
                n[c] += 1.0;
                for ch in 0..3 {
                    sum[ch * g.len() + c] += planes[ch * fw * fh + v * fw + u];
                }
                let d = frame[v * fw + u];
                if d > 0.0 && (near[c] == 0.0 || d < near[c]) {
                    near[c] = d;
                }
            }
        }
        let mean: Vec<f32> = sum
            .iter()
            .enumerate()
            .map(|(i, x)| x / n[i % g.len()])
            .collect();
        let got = g.mean_image(&rgb);
        assert!(
            got.iter().zip(&mean).all(|(a, b)| (a - b).abs() < 1e-5),
            "{got:?} vs {mean:?}"
        );
        assert_eq!(g.nearest_depth(&frame), near);
        let back = g.to_frame(&near);
        for v in 0..fh {
            for u in 0..fw {
                assert_eq!(back[v * fw + u], near[cell(u, v)]);
            }
        }
    }
}
