//! Training-frame maps (SPEC §3–5): image, sparse/dense lidar, low-height mask, radar raw
//! and height-extended. Pure functions over points and transforms; the pipeline does I/O.

use depthsense_nuscenes::depth_png::DepthMap;
use depthsense_nuscenes::geometry::{apply_f32, to_frame, Camera, Rigid};
use depthsense_nuscenes::pcd::RadarPoint;

use crate::layout::{FRAME_CROP_TOP, FRAME_H, FRAME_W};

/// Low-height band above the ground, metres (SPEC §4).
pub const LOW_HEIGHT_MIN_M: f32 = 0.3;
pub const LOW_HEIGHT_MAX_M: f32 = 2.0;
/// Height extension of radar points (SPEC §5).
pub const RADAR_H_UP_M: f32 = 1.5;
pub const RADAR_H_DOWN_M: f32 = 0.25;

/// Depth-consistency tolerance of the dense target (SPEC §4): depth `d` is behind depth `s`
/// when `d > OCC_REL · s + OCC_ABS_M`.
pub const OCC_REL: f32 = 1.1;
pub const OCC_ABS_M: f32 = 0.5;
/// Half-width (columns) of the band in which [`KeyframeSurface`] looks for keyframe returns.
pub const OCC_RX: i64 = 2;
/// Rows up and down that [`KeyframeSurface`] searches for a bracketing keyframe return: more
/// than the gap between two LIDAR_TOP rings in the training frame (1.33° ≈ 15 rows).
pub const OCC_MAX_GAP_ROWS: i64 = 24;

/// Near-sensor radius (m) of the ego car's own returns: nuscenes-devkit
/// `LidarPointCloud.remove_close(1.0)`, applied by its `from_file_multisweep` to every sweep.
pub const NEAR_SENSOR_M: f32 = 1.0;

/// Drop the ego car's own returns (roof, the no-return points at the origin) from a sensor-frame
/// LIDAR_TOP scan, exactly as nuscenes-devkit `LidarPointCloud.remove_close(radius)`: a point
/// goes when |x| < radius **and** |y| < radius in the sensor frame (a square, not a disc; z is
/// not looked at). SPEC §4: the dense target accumulates the world, not the car. Returns the
/// kept points (x, y, z) and how many were dropped.
pub fn remove_close(points_sensor: &[[f32; 5]], radius_m: f32) -> (Vec<[f32; 3]>, u64) {
    let mut kept = Vec::with_capacity(points_sensor.len());
    for p in points_sensor {
        if !(p[0].abs() < radius_m && p[1].abs() < radius_m) {
            kept.push([p[0], p[1], p[2]]);
        }
    }
    let dropped = (points_sensor.len() - kept.len()) as u64;
    (kept, dropped)
}

/// The ego car's body as a box in the **ego frame** (x forward from the rear axle, y left, z up
/// from the ground; metres), removed from every non-keyframe sweep of the dense target in
/// addition to the devkit's 1 m square (SPEC §4: the target accumulates the world, not the
/// car). The radius misses the returns of the car beyond 1 m of the sensor — bonnet, roof
/// rails, mirrors — which ride along with the car and, in a sweep taken metres away from the
/// keyframe, land in front of the camera.
///
/// Measured on the real keyframe (`../shared/fixtures/nuscenes-kf0`, docs/guide/prepare.md, "The
/// dense target"): every return above the ground within 3 m of the lidar is the car — roof
/// x −0.19…1.57 m, z 1.35…1.84 m; bonnet x 2.25…2.73 m, z 0.88…1.02 m; |y| ≤ 0.64 m — and the
/// nearest world return is ground 3.03 m from the lidar. The box is the car (Renault Zoe,
/// 4.08 × 1.73 m, ≈ 1.95 m wide with mirrors; the ego origin is the rear axle) around those
/// returns with margin; it reaches 2.1 m up (the lidar sits at 1.84 m) and has no floor
/// (nothing under the car is visible).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct EgoBox {
    pub x_min_m: f32,
    pub x_max_m: f32,
    pub y_half_m: f32,
    pub z_max_m: f32,
}

/// The nuScenes data-collection car (see [`EgoBox`]).
pub const EGO_BOX: EgoBox = EgoBox {
    x_min_m: -1.0,
    x_max_m: 3.3,
    y_half_m: 1.0,
    z_max_m: 2.1,
};

impl EgoBox {
    /// Whether a point in the ego frame lies on the car.
    pub fn contains(&self, p_ego: [f32; 3]) -> bool {
        p_ego[0] > self.x_min_m
            && p_ego[0] < self.x_max_m
            && p_ego[1].abs() < self.y_half_m
            && p_ego[2] < self.z_max_m
    }
}

/// What the keyframe surface says about a point of another sweep (SPEC §4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Visibility {
    /// Between the keyframe returns that bracket its pixel (or at their depth): kept.
    Consistent,
    /// Behind both bracketing keyframe returns: hidden from the keyframe's view, dropped.
    Hidden,
    /// In front of both bracketing keyframe returns: in space the keyframe beam crossed
    /// freely (an unannotated mover, a ghost), dropped.
    FreeSpace,
    /// No keyframe return above or below it within [`OCC_MAX_GAP_ROWS`]: no evidence, kept.
    NoEvidence,
}

/// The keyframe sweep's own surface in the training frame, for judging points of other sweeps
/// (SPEC §4: "remove points that are hidden behind the single-sweep surface").
///
/// The keyframe scan is dense along a ring (a return every ~4 columns) and sparse across rings
/// (~15 rows apart), so a pixel is judged against the two keyframe returns that bracket it in
/// its column band (±[`OCC_RX`] columns): the nearest keyframe row at or above it and at or
/// below it, each within [`OCC_MAX_GAP_ROWS`]. With `near`/`far` the smallest/largest keyframe
/// depth of those two band rows, a point at depth d is
/// - [`Visibility::Hidden`] when `d > OCC_REL·far + OCC_ABS_M` (behind everything the keyframe
///   saw there),
/// - [`Visibility::FreeSpace`] when `OCC_REL·d + OCC_ABS_M < near` (in front of it),
/// - otherwise consistent. Inverse depth is linear in the row on a plane, so ground and walls
///   between two rings are consistent; a depth edge between the rings keeps both sides.
///
/// Keyframe pixels themselves are never judged: the dense target keeps every one of them.
pub struct KeyframeSurface {
    /// Per pixel (row-major): (near, far) of the bracketing band row above and below;
    /// 0 = none within reach.
    above: Vec<(f32, f32)>,
    below: Vec<(f32, f32)>,
}

impl KeyframeSurface {
    pub fn new(keyframe_depth_m: &[f32]) -> KeyframeSurface {
        let w = FRAME_W as i64;
        let h = FRAME_H as i64;
        // Band rows: nearest and farthest keyframe depth within ±OCC_RX columns (built from
        // the few thousand keyframe pixels, not by scanning every pixel's window).
        let mut band = vec![(f32::INFINITY, 0f32); N];
        for (i, &d) in keyframe_depth_m.iter().enumerate().take(N) {
            if d <= 0.0 {
                continue;
            }
            let (y, x) = ((i as i64) / w, (i as i64) % w);
            for xx in (x - OCC_RX).max(0)..=(x + OCC_RX).min(w - 1) {
                let b = &mut band[(y * w + xx) as usize];
                b.0 = b.0.min(d);
                b.1 = b.1.max(d);
            }
        }
        let mut above = vec![(0f32, 0f32); N];
        let mut below = vec![(0f32, 0f32); N];
        for x in 0..w {
            let mut last: Option<((f32, f32), i64)> = None;
            for y in 0..h {
                let i = (y * w + x) as usize;
                if band[i].1 > 0.0 {
                    last = Some((band[i], y));
                }
                if let Some((v, yy)) = last {
                    if y - yy <= OCC_MAX_GAP_ROWS {
                        above[i] = v;
                    }
                }
            }
            let mut last: Option<((f32, f32), i64)> = None;
            for y in (0..h).rev() {
                let i = (y * w + x) as usize;
                if band[i].1 > 0.0 {
                    last = Some((band[i], y));
                }
                if let Some((v, yy)) = last {
                    if yy - y <= OCC_MAX_GAP_ROWS {
                        below[i] = v;
                    }
                }
            }
        }
        KeyframeSurface { above, below }
    }

    /// Judge depth `depth_m` at training-frame pixel (x, y).
    #[inline]
    pub fn judge(&self, x: u32, y: u32, depth_m: f32) -> Visibility {
        let i = y as usize * FRAME_W as usize + x as usize;
        let (a, b) = (self.above[i], self.below[i]);
        if a.1 <= 0.0 || b.1 <= 0.0 {
            return Visibility::NoEvidence;
        }
        let near = a.0.min(b.0);
        let far = a.1.max(b.1);
        if depth_m > OCC_REL * far + OCC_ABS_M {
            Visibility::Hidden
        } else if OCC_REL * depth_m + OCC_ABS_M < near {
            Visibility::FreeSpace
        } else {
            Visibility::Consistent
        }
    }
}

/// Counts of [`add_sweep_points`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SweepCounts {
    /// Points that landed in the frame.
    pub in_frame: u64,
    /// Landed on a keyframe pixel (the keyframe depth stands).
    pub on_keyframe_pixel: u64,
    pub hidden: u64,
    pub free_space: u64,
    pub kept: u64,
}

/// Add points of a non-keyframe sweep (already in the frame `cam_from_points` maps from) to the
/// dense target `dense`, judged against the keyframe surface (SPEC §4, [`KeyframeSurface`]).
/// `keyframe_depth_m` is the keyframe's own map: its pixels are never changed. Among the other
/// sweeps' points the nearest wins.
pub fn add_sweep_points(
    dense: &mut Raster,
    keyframe_depth_m: &[f32],
    surface: &KeyframeSurface,
    points: &[[f32; 3]],
    cam_from_points: &Rigid,
    cam: &Camera,
) -> SweepCounts {
    let m = cam_from_points.to_f32();
    let mut c = SweepCounts::default();
    for p in points {
        let pc = apply_f32(&m, *p);
        let Some((u, v, d)) = cam.project(pc) else {
            continue;
        };
        let Some((x, y)) = to_frame(u, v) else {
            continue;
        };
        c.in_frame += 1;
        dense.in_frame += 1;
        if keyframe_depth_m[y as usize * FRAME_W as usize + x as usize] > 0.0 {
            c.on_keyframe_pixel += 1;
            continue;
        }
        match surface.judge(x, y, d) {
            Visibility::Hidden => c.hidden += 1,
            Visibility::FreeSpace => c.free_space += 1,
            Visibility::Consistent | Visibility::NoEvidence => {
                c.kept += 1;
                dense.splat(x, y, d, 0.0);
            }
        }
    }
    c
}

const N: usize = (FRAME_W * FRAME_H) as usize;

/// Nearest-wins raster in the training frame plus a per-pixel payload (e.g. height).
#[derive(Debug, Clone)]
pub struct Raster {
    pub depth_m: Vec<f32>,
    pub payload: Vec<f32>,
    /// Points that landed in the frame (before nearest-wins).
    pub in_frame: u64,
}

impl Default for Raster {
    fn default() -> Self {
        Raster {
            depth_m: vec![0.0; N],
            payload: vec![0.0; N],
            in_frame: 0,
        }
    }
}

impl Raster {
    /// Put depth `d` at pixel (x, y) if the pixel is empty or holds a farther depth
    /// (nearest wins, SPEC §4).
    #[inline]
    pub fn splat(&mut self, x: u32, y: u32, d: f32, payload: f32) {
        let i = y as usize * FRAME_W as usize + x as usize;
        let cur = self.depth_m[i];
        if cur == 0.0 || d < cur {
            self.depth_m[i] = d;
            self.payload[i] = payload;
        }
    }

    pub fn to_depth_map(&self) -> DepthMap {
        DepthMap {
            width: FRAME_W,
            height: FRAME_H,
            depth_m: self.depth_m.clone(),
        }
    }

    pub fn valid(&self) -> u64 {
        self.depth_m.iter().filter(|d| **d > 0.0).count() as u64
    }
}

/// Project sensor-frame points through `cam_from_sensor` into the training frame, nearest
/// wins. `height` gives the per-point payload (e.g. ego-frame z). Returns the raster.
pub fn project_points(
    points: &[[f32; 3]],
    cam_from_sensor: &Rigid,
    cam: &Camera,
    payload: impl Fn(usize) -> f32,
) -> Raster {
    let mut r = Raster::default();
    project_into(&mut r, points, cam_from_sensor, cam, payload);
    r
}

/// Like [`project_points`] but adds to an existing raster.
pub fn project_into(
    r: &mut Raster,
    points: &[[f32; 3]],
    cam_from_sensor: &Rigid,
    cam: &Camera,
    payload: impl Fn(usize) -> f32,
) {
    let m = cam_from_sensor.to_f32();
    for (i, p) in points.iter().enumerate() {
        let pc = apply_f32(&m, *p);
        if let Some((u, v, d)) = cam.project(pc) {
            if let Some((x, y)) = to_frame(u, v) {
                r.in_frame += 1;
                r.splat(x, y, d, payload(i));
            }
        }
    }
}

/// Low-height mask (SPEC §4): 255 where the winning point's ego-frame height is in
/// [0.3, 2.0] m, else 0. `r.payload` must hold the heights.
pub fn lowheight_mask(r: &Raster) -> Vec<u8> {
    r.depth_m
        .iter()
        .zip(&r.payload)
        .map(|(d, h)| {
            if *d > 0.0 && (LOW_HEIGHT_MIN_M..=LOW_HEIGHT_MAX_M).contains(h) {
                255
            } else {
                0
            }
        })
        .collect()
}

/// Radar raw and height-extended maps (SPEC §5) from camera-frame radar points.
pub fn radar_maps(points_cam: &[[f32; 3]], cam: &Camera, raw: &mut Raster, height: &mut Raster) {
    for p in points_cam {
        let Some((u, v, d)) = cam.project(*p) else {
            continue;
        };
        if let Some((x, y)) = to_frame(u, v) {
            raw.in_frame += 1;
            raw.splat(x, y, d, 0.0);
        }
        // Vertical strip v − h_up·fy/d … v + h_down·fy/d at full resolution, nearest wins,
        // reduced to the frame rows it covers.
        let fy = cam.fy as f32;
        let v0 = (v - RADAR_H_UP_M * fy / d).max(0.0);
        let v1 = (v + RADAR_H_DOWN_M * fy / d).min(cam.height as f32 - 1.0);
        let x = (u * 0.5).floor() as i64;
        if x < 0 || x >= FRAME_W as i64 {
            continue;
        }
        let y0 = ((v0 * 0.5).floor() as i64 - FRAME_CROP_TOP as i64).max(0);
        let y1 = ((v1 * 0.5).floor() as i64 - FRAME_CROP_TOP as i64).min(FRAME_H as i64 - 1);
        if y0 <= y1 {
            height.in_frame += 1;
        }
        for y in y0..=y1 {
            height.splat(x as u32, y as u32, d, 0.0);
        }
    }
}

/// Sensor-frame radar positions, optionally velocity-compensated by `dt_s` seconds
/// (x += vx_comp·dt, y += vy_comp·dt; SPEC §2).
pub fn radar_positions(points: &[RadarPoint], dt_s: Option<f32>) -> Vec<[f32; 3]> {
    points
        .iter()
        .map(|p| match dt_s {
            Some(dt) => [p.x + p.vx_comp * dt, p.y + p.vy_comp * dt, p.z],
            None => [p.x, p.y, p.z],
        })
        .collect()
}

/// 1600x900 RGB8 → 800x350 (SPEC §3): 2x2 box average to 800x450, then the top 100 rows
/// are cropped. `rgb` is row-major RGB8 of `w`x`h`; `w`, `h` must be 1600x900.
pub fn image_to_frame(rgb: &[u8], w: u32, h: u32) -> Option<Vec<u8>> {
    if w != 2 * FRAME_W || h != 2 * (FRAME_H + FRAME_CROP_TOP) || rgb.len() != (w * h * 3) as usize
    {
        return None;
    }
    let fw = FRAME_W as usize;
    let stride = w as usize * 3;
    let mut out = vec![0u8; fw * FRAME_H as usize * 3];
    for y in 0..FRAME_H as usize {
        let sy = 2 * (y + FRAME_CROP_TOP as usize);
        let r0 = &rgb[sy * stride..(sy + 1) * stride];
        let r1 = &rgb[(sy + 1) * stride..(sy + 2) * stride];
        let o = &mut out[y * fw * 3..(y + 1) * fw * 3];
        for x in 0..fw {
            for c in 0..3 {
                let a = r0[6 * x + c] as u16 + r0[6 * x + 3 + c] as u16;
                let b = r1[6 * x + c] as u16 + r1[6 * x + 3 + c] as u16;
                o[3 * x + c] = ((a + b + 2) / 4) as u8;
            }
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera {
            fx: 1000.0,
            fy: 1000.0,
            cx: 800.0,
            cy: 450.0,
            width: 1600,
            height: 900,
        }
    }

    #[test]
    fn nearest_wins_regardless_of_order() {
        // Two points on the same ray: far first, then near; and the reverse.
        let pts = [[1.0, 0.5, 20.0], [0.5, 0.25, 10.0]];
        for order in [[0, 1], [1, 0]] {
            let p: Vec<[f32; 3]> = order.iter().map(|&i| pts[i]).collect();
            let r = project_points(&p, &Rigid::IDENTITY, &cam(), |_| 0.0);
            // u = 850, v = 475 → frame (425, 137)
            let i = 137 * 800 + 425;
            assert_eq!(r.depth_m[i], 10.0);
            assert_eq!(r.valid(), 1);
        }
    }

    #[test]
    fn u_is_column_and_v_is_row() {
        // x to the right → column, y downward → row.
        let r = project_points(&[[2.0, 0.0, 10.0]], &Rigid::IDENTITY, &cam(), |_| 0.0);
        // u = 1000, v = 450 → (500, 125)
        assert_eq!(r.depth_m[125 * 800 + 500], 10.0);
    }

    #[test]
    fn radar_height_strip_extent_and_nearest() {
        let mut raw = Raster::default();
        let mut hm = Raster::default();
        // d = 10: strip from v−150 to v+25 at full res → frame rows 125−75 … 125+12.
        radar_maps(
            &[[0.0, 0.0, 10.0], [0.0, 0.0, 20.0]],
            &cam(),
            &mut raw,
            &mut hm,
        );
        let col = 400;
        let rows: Vec<usize> = (0..350)
            .filter(|y| hm.depth_m[y * 800 + col] > 0.0)
            .collect();
        // The far point's strip is shorter; the near one covers rows 50..=137.
        assert_eq!(*rows.first().unwrap(), 50);
        assert_eq!(*rows.last().unwrap(), 137);
        assert!(rows.iter().all(|y| hm.depth_m[y * 800 + col] == 10.0));
        assert_eq!(raw.depth_m[125 * 800 + 400], 10.0);
        assert_eq!(raw.valid(), 1);
    }

    #[test]
    fn image_reduction_crop_offset() {
        let (w, h) = (1600u32, 900u32);
        let mut rgb = vec![0u8; (w * h * 3) as usize];
        // Mark full-res rows 200,201 (→ frame row 0) and 198,199 (cropped).
        for x in 0..w as usize {
            for c in 0..3 {
                rgb[(200 * w as usize + x) * 3 + c] = 100;
                rgb[(201 * w as usize + x) * 3 + c] = 200;
                rgb[(199 * w as usize + x) * 3 + c] = 255;
            }
        }
        let f = image_to_frame(&rgb, w, h).unwrap();
        assert_eq!(f.len(), 800 * 350 * 3);
        assert_eq!(f[0], 150);
        assert_eq!(f[800 * 3], 0);
        assert!(image_to_frame(&rgb[..10], 5, 2).is_none());
    }

    #[test]
    fn keyframe_surface_brackets_and_verdicts() {
        // Two keyframe "rings" 15 rows apart: row 100 at 20 m, row 115 at 10 m (ground-like:
        // nearer below), every 4th column; a wall at 8 m over columns 400..420 on both rings.
        let mut kf = vec![0f32; N];
        for x in (0..800).step_by(4) {
            let wall = (400..420).contains(&x);
            kf[100 * 800 + x] = if wall { 8.0 } else { 20.0 };
            kf[115 * 800 + x] = if wall { 8.0 } else { 10.0 };
        }
        let s = KeyframeSurface::new(&kf);
        // Ground between the rings: consistent.
        assert_eq!(s.judge(201, 107, 14.0), Visibility::Consistent);
        // Behind the wall: hidden; in front of the ground: free space.
        assert_eq!(s.judge(409, 107, 20.0), Visibility::Hidden);
        assert_eq!(s.judge(201, 107, 5.0), Visibility::FreeSpace);
        // Above the top ring there is nothing to bracket with.
        assert_eq!(s.judge(201, 90, 50.0), Visibility::NoEvidence);
        // Sweep points never touch keyframe pixels; judged points fill the gaps.
        let mut dense = Raster {
            depth_m: kf.clone(),
            payload: vec![0.0; N],
            in_frame: 0,
        };
        let c = cam();
        // Camera points landing at frame (201, 107) → full-res (402.x, 414.x).
        let at = |x: f32, y: f32, d: f32| {
            [
                ((2.0 * x + 0.5) - 800.0) * d / 1000.0,
                ((2.0 * (y + 100.0) + 0.5) - 450.0) * d / 1000.0,
                d,
            ]
        };
        let pts = [
            at(201.0, 107.0, 14.0),
            at(409.0, 107.0, 20.0),
            at(200.0, 100.0, 3.0),
        ];
        let n = add_sweep_points(&mut dense, &kf, &s, &pts, &Rigid::IDENTITY, &c);
        assert_eq!(
            (n.kept, n.hidden, n.on_keyframe_pixel, n.free_space),
            (1, 1, 1, 0)
        );
        assert!((dense.depth_m[107 * 800 + 201] - 14.0).abs() < 1e-3);
        assert_eq!(dense.depth_m[100 * 800 + 200], 20.0);
    }

    #[test]
    fn remove_close_is_the_devkit_square() {
        let pts = [
            [0.5, 0.5, -0.3, 0.0, 0.0],  // roof: dropped
            [0.99, -0.2, 5.0, 0.0, 0.0], // any z: dropped
            [1.0, 0.0, 0.0, 0.0, 0.0],   // |x| = 1: kept (strict <)
            [0.0, -1.0, 0.0, 0.0, 0.0],  // |y| = 1: kept (strict <)
            [0.2, 3.0, 0.0, 0.0, 0.0],   // ahead: kept
        ];
        let (kept, dropped) = remove_close(&pts, NEAR_SENSOR_M);
        assert_eq!(dropped, 2);
        assert_eq!(
            kept,
            vec![[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.2, 3.0, 0.0]]
        );
    }

    #[test]
    fn radar_velocity_compensation_moves_along_v_comp() {
        let p = RadarPoint {
            x: 10.0,
            y: 2.0,
            vx_comp: 4.0,
            vy_comp: -2.0,
            ..Default::default()
        };
        assert_eq!(radar_positions(&[p], None), vec![[10.0, 2.0, 0.0]]);
        assert_eq!(radar_positions(&[p], Some(0.25)), vec![[11.0, 1.5, 0.0]]);
    }

    #[test]
    fn lowheight_band() {
        let mut r = Raster::default();
        r.splat(0, 0, 5.0, 0.1);
        r.splat(1, 0, 5.0, 1.0);
        r.splat(2, 0, 5.0, 2.5);
        let m = lowheight_mask(&r);
        assert_eq!(&m[..3], &[0, 255, 0]);
    }

    // Added after the mutation run of issue 23: the exact thresholds of the depth-consistency
    // test, the ego box's faces, and which full-resolution pixels the 2x2 reduction averages.

    #[test]
    fn consistency_thresholds_by_hand() {
        // Column 100: 10 m at row 50, 20 m at row 60 → at (100, 55) near 10, far 20:
        // hidden when d > 1.1·20 + 0.5 = 22.5, free space when 1.1·d + 0.5 < 10 (d < 8.64).
        // Column 200: 6 m at row 50, 20 m at row 60: 1.1·5 + 0.5 = 6 is not < 6.
        let mut kf = vec![0f32; N];
        kf[50 * 800 + 100] = 10.0;
        kf[60 * 800 + 100] = 20.0;
        kf[50 * 800 + 200] = 6.0;
        kf[60 * 800 + 200] = 20.0;
        let s = KeyframeSurface::new(&kf);
        let v = |x, y, d| s.judge(x, y, d);
        assert_eq!(
            v(100, 55, 22.5),
            Visibility::Consistent,
            "22.5 is not > 22.5"
        );
        assert_eq!(v(100, 55, 22.51), Visibility::Hidden);
        assert_eq!(v(100, 55, 22.0), Visibility::Consistent);
        assert_eq!(
            v(100, 55, 8.5),
            Visibility::FreeSpace,
            "1.1·8.5 + 0.5 = 9.85 < 10"
        );
        assert_eq!(
            v(100, 55, 9.0),
            Visibility::Consistent,
            "1.1·9 + 0.5 = 10.4"
        );
        assert_eq!(v(200, 55, 5.0), Visibility::Consistent, "6 is not < 6");
        assert_eq!(v(200, 55, 4.9), Visibility::FreeSpace);
        // evidence within ±2 columns (OCC_RX)
        assert_eq!(v(102, 55, 30.0), Visibility::Hidden);
        assert_eq!(v(103, 55, 30.0), Visibility::NoEvidence);
        // a return must bracket the pixel on both sides within 24 rows (OCC_MAX_GAP_ROWS):
        // column 300 has them 24 rows above and below row 74, column 400 the lower one 25 below
        kf[50 * 800 + 300] = 10.0;
        kf[98 * 800 + 300] = 20.0;
        kf[50 * 800 + 400] = 10.0;
        kf[99 * 800 + 400] = 20.0;
        let s = KeyframeSurface::new(&kf);
        assert_eq!(s.judge(300, 74, 30.0), Visibility::Hidden);
        assert_eq!(s.judge(400, 74, 30.0), Visibility::NoEvidence);
    }

    #[test]
    fn ego_box_faces_are_outside() {
        let b = EGO_BOX;
        assert!(b.contains([0.0, 0.0, 0.0]));
        assert!(b.contains([-0.99, 0.99, 2.09]));
        for p in [
            [-1.0, 0.0, 0.0],
            [3.3, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 0.0, 2.1],
        ] {
            assert!(
                !b.contains(p),
                "{p:?} lies on a face: outside (strict bounds)"
            );
        }
    }

    #[test]
    fn image_reduction_averages_each_2x2_block_per_channel() {
        // Full-res pixel (X, Y): R = X, G = Y, B = 255 − X (mod 256). Frame pixel (x, y)
        // averages X ∈ {2x, 2x+1}, Y ∈ {2(y+100), 2(y+100)+1} with rounding (sum + 2)/4:
        // R = (8x + 2 + 2)/4 = 2x + 1, G = 2y + 201, B = (4·(255 − 2x) − 2 + 2)/4 = 255 − 2x.
        let (w, h) = (1600usize, 900usize);
        let mut rgb = vec![0u8; w * h * 3];
        for y in 0..h {
            for x in 0..w {
                let o = (y * w + x) * 3;
                rgb[o] = (x % 256) as u8;
                rgb[o + 1] = (y % 256) as u8;
                rgb[o + 2] = (255 - x % 256) as u8;
            }
        }
        let f = image_to_frame(&rgb, w as u32, h as u32).unwrap();
        for (x, y) in [(0usize, 0usize), (5, 10), (100, 27), (127, 3)] {
            let o = (y * 800 + x) * 3;
            assert_eq!(
                [f[o], f[o + 1], f[o + 2]],
                [(2 * x + 1) as u8, (2 * y + 201) as u8, (255 - 2 * x) as u8],
                "frame pixel ({x}, {y})"
            );
        }
        // only 1600x900 RGB8 is accepted
        assert!(image_to_frame(&rgb, 1600, 899).is_none());
        assert!(image_to_frame(&rgb, 1599, 900).is_none());
        assert!(image_to_frame(&rgb[..rgb.len() - 3], 1600, 900).is_none());
        // a buffer that fits another size is still refused
        assert!(image_to_frame(&rgb[..1599 * 900 * 3], 1599, 900).is_none());
        assert!(image_to_frame(&rgb[..1600 * 899 * 3], 1600, 899).is_none());
    }
}
