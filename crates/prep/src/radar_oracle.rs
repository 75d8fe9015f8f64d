//! The oracle radar (issue 34): an upper bound on what radar could give the network if every
//! return's *depth* were right. Each return keeps its image position (its pixel in the
//! training frame); its depth is replaced by the lidar target's depth at that pixel, or at
//! the nearest valid target pixel within [`ORACLE_RADIUS_PX`] (Euclidean distance in frame
//! pixels; ties go to the first in row-major order). Returns with no valid target pixel that
//! close — and returns outside the training frame, which have no target pixel — are dropped.
//! The kept returns are moved along their viewing ray (camera-frame point × d_lidar / z, so
//! u and v are unchanged) and rasterised by [`RadarPoints::rasterise`], the function
//! `prepare` uses: the raw map and the SPEC §5 height strips are drawn for the new depth.

use depthsense_nuscenes::geometry::to_frame;

use crate::radar_points::RadarPoints;

/// Search radius for a valid target pixel around a return's pixel (training-frame pixels).
pub const ORACLE_RADIUS_PX: i64 = 3;

/// What [`oracle_points`] did with a sample's returns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct OracleCounts {
    /// Returns given a lidar depth.
    pub kept: usize,
    /// Returns dropped (outside the frame, or no valid target pixel within the radius).
    pub dropped: usize,
}

/// The lidar depth (metres) for frame pixel (x, y): the pixel's own when valid, else the
/// nearest valid one within [`ORACLE_RADIUS_PX`]. `target_m` is row-major `width × height`,
/// 0 = invalid.
pub fn target_depth_near(
    target_m: &[f32],
    width: usize,
    height: usize,
    x: u32,
    y: u32,
) -> Option<f32> {
    let r = ORACLE_RADIUS_PX;
    let mut best: Option<(i64, f32)> = None;
    for dy in -r..=r {
        for dx in -r..=r {
            let d2 = dx * dx + dy * dy;
            if d2 > r * r || best.is_some_and(|(b, _)| d2 >= b) {
                continue;
            }
            let (xx, yy) = (x as i64 + dx, y as i64 + dy);
            if xx < 0 || yy < 0 || xx >= width as i64 || yy >= height as i64 {
                continue;
            }
            let d = target_m[yy as usize * width + xx as usize];
            if d > 0.0 && d.is_finite() {
                best = Some((d2, d));
            }
        }
    }
    best.map(|(_, d)| d)
}

/// The oracle version of `points` (module docs) against the frame-sized lidar target
/// `target_m` (`width × height`, metres, 0 = invalid), and what happened to the returns.
/// Groups keep their channel, sweep and origin; their counts shrink by the dropped returns.
pub fn oracle_points(
    points: &RadarPoints,
    target_m: &[f32],
    width: usize,
    height: usize,
) -> (RadarPoints, OracleCounts) {
    let mut out = RadarPoints {
        channels: points.channels.clone(),
        ..RadarPoints::new(points.camera)
    };
    let mut counts = OracleCounts::default();
    for (g, range) in points.group_ranges() {
        let before = out.points_cam.len();
        for p in &points.points_cam[range] {
            let depth = points
                .camera
                .project(*p)
                .and_then(|(u, v, _)| to_frame(u, v))
                .and_then(|(x, y)| target_depth_near(target_m, width, height, x, y));
            match depth {
                Some(d) => {
                    let s = d / p[2];
                    out.points_cam.push([p[0] * s, p[1] * s, d]);
                    counts.kept += 1;
                }
                None => counts.dropped += 1,
            }
        }
        let mut group = *g;
        group.n_points = (out.points_cam.len() - before) as u32;
        out.groups.push(group);
    }
    (out, counts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::{FRAME_H, FRAME_W};
    use depthsense_nuscenes::geometry::Camera;

    fn camera() -> Camera {
        Camera {
            fx: 1266.0,
            fy: 1266.0,
            cx: 816.0,
            cy: 491.0,
            width: 1600,
            height: 900,
        }
    }

    /// A camera-frame point at depth z whose full-resolution projection is (u, v).
    fn at(cam: &Camera, u: f64, v: f64, z: f64) -> [f32; 3] {
        [
            ((u - cam.cx) * z / cam.fx) as f32,
            ((v - cam.cy) * z / cam.fy) as f32,
            z as f32,
        ]
    }

    #[test]
    fn returns_take_the_lidar_depth_nearby_or_are_dropped() {
        let cam = camera();
        let (w, h) = (FRAME_W as usize, FRAME_H as usize);
        let mut target = vec![0.0f32; w * h];
        // Frame pixel (100, 50) ↔ full-res u ∈ [200, 202), v ∈ [300, 302).
        target[50 * w + 100] = 12.5;
        // (300, 80): nothing at the pixel, a valid one 2 px right and one 3 px up (farther).
        target[80 * w + 302] = 20.0;
        target[77 * w + 300] = 30.0;
        let mut pts = RadarPoints::new(cam);
        pts.push_sweep(
            "RADAR_FRONT",
            0,
            [0.0, 0.5, -1.0],
            &[
                at(&cam, 201.0, 301.0, 40.0), // on the pixel → 12.5 m
                at(&cam, 601.0, 361.0, 7.0),  // (300, 80) → nearest valid: 20 m (2 px)
                at(&cam, 1001.0, 601.0, 9.0), // (500, 200): nothing within 3 px → dropped
                at(&cam, 201.0, 101.0, 9.0),  // above the frame crop → dropped
            ],
        );
        let (o, counts) = oracle_points(&pts, &target, w, h);
        assert_eq!(
            counts,
            OracleCounts {
                kept: 2,
                dropped: 2
            }
        );
        assert_eq!(o.groups.len(), 1);
        assert_eq!(o.groups[0].n_points, 2);
        assert_eq!(o.groups[0].origin_cam, [0.0, 0.5, -1.0]);
        let want = [(201.0, 301.0, 12.5), (601.0, 361.0, 20.0)];
        for (p, (u, v, d)) in o.points_cam.iter().zip(want) {
            let (pu, pv, pd) = cam.project(*p).unwrap();
            assert!((pu - u).abs() < 1e-3 && (pv - v).abs() < 1e-3, "{pu} {pv}");
            assert_eq!(pd, d);
        }
        // Rasterised as prepare does: the raw pixel holds the lidar depth.
        let maps = o.rasterise();
        assert_eq!(maps.raw.depth_m[50 * w + 100], 12.5);
        assert_eq!(maps.raw.depth_m[80 * w + 300], 20.0);
        assert_eq!(maps.raw.valid(), 2);
    }

    #[test]
    fn the_nearest_valid_pixel_wins_and_the_radius_is_euclidean() {
        let (w, h) = (20usize, 20usize);
        let mut t = vec![0.0f32; w * h];
        t[10 * w + 13] = 5.0; // 3 px right: inside
        assert_eq!(target_depth_near(&t, w, h, 10, 10), Some(5.0));
        t[12 * w + 12] = 6.0; // √8 ≈ 2.83 px: nearer
        assert_eq!(target_depth_near(&t, w, h, 10, 10), Some(6.0));
        let mut t = vec![0.0f32; w * h];
        t[13 * w + 13] = 5.0; // √18 ≈ 4.24 px: outside
        assert_eq!(target_depth_near(&t, w, h, 10, 10), None);
        // At the border: no out-of-range reads.
        t[0] = 2.0;
        assert_eq!(target_depth_near(&t, w, h, 0, 0), Some(2.0));
    }
}
