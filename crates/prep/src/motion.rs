//! Moving-object boxes for the dense target (SPEC §4: "remove points inside annotated moving
//! boxes").
//!
//! Rule (docs/guide/prepare.md, "The dense target"): a sweep taken at time t loses its points inside the box of
//! every moving instance **at time t**. The box at t is interpolated between the instance's
//! two annotations that bracket t as nuscenes-devkit `NuScenes.get_boxes` does for sweeps —
//! linear centre, slerp of the rotation, the later annotation's size — when they are at most
//! [`MAX_TIME_DIFF_S`] apart (the devkit's `box_velocity` `max_time_diff`). Outside the
//! annotated span (or across a longer gap) the nearest annotation is moved by its devkit
//! velocity for at most [`MAX_TIME_DIFF_S`]; without a velocity it stays where it was annotated.
//! Every box is grown by the fixed [`BOX_MARGIN_M`] on each side.
//!
//! An annotation is moving when its devkit velocity exceeds [`MOVING_SPEED_MPS`] or when it
//! carries an attribute whose name ends in ".moving" or is "cycle.with_rider"; an instance is
//! moving at t when either bracketing annotation is.

use glam::{DQuat, DVec3};

/// Speed above which an annotated object counts as moving (m/s).
pub const MOVING_SPEED_MPS: f64 = 0.5;
/// Margin added to every side of a moving box before removing points (m): annotation and
/// interpolation slack (lidar returns sit on the box surface), small enough that a kerb,
/// a parked car or the road 1 m beside a mover stays.
pub const BOX_MARGIN_M: f64 = 0.2;
/// nuscenes-devkit `box_velocity` `max_time_diff` (s): annotations further apart than this
/// are not interpolated between, and no box is extrapolated further than this.
pub const MAX_TIME_DIFF_S: f64 = 1.5;

/// One annotation of an instance, in the global frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackPoint {
    pub timestamp_us: i64,
    pub center_m: [f64; 3],
    /// global_from_box, (w, x, y, z).
    pub rotation_wxyz: [f64; 4],
    /// Width, length, height (devkit order; the box x axis is the length).
    pub size_wlh_m: [f64; 3],
    /// Devkit velocity (m/s, global), `None` where the devkit gives NaN.
    pub velocity_mps: Option<[f64; 3]>,
    pub moving: bool,
}

/// A moving box at one time, with the margin applied.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxAt {
    pub center_m: DVec3,
    /// box_from_global.
    pub box_from_global: DQuat,
    /// Half extents along the box's x (length), y (width), z (height), margin included.
    pub half_m: DVec3,
    radius_sq: f64,
}

impl BoxAt {
    pub fn new(
        center_m: DVec3,
        global_from_box: DQuat,
        size_wlh_m: [f64; 3],
        margin_m: f64,
    ) -> BoxAt {
        let half_m = DVec3::new(
            size_wlh_m[1] / 2.0 + margin_m,
            size_wlh_m[0] / 2.0 + margin_m,
            size_wlh_m[2] / 2.0 + margin_m,
        );
        BoxAt {
            center_m,
            box_from_global: global_from_box.inverse(),
            half_m,
            radius_sq: half_m.length_squared(),
        }
    }

    /// Whether the global point lies inside the box (margin included).
    #[inline]
    pub fn contains(&self, point_global: [f32; 3]) -> bool {
        let d = DVec3::new(
            point_global[0] as f64,
            point_global[1] as f64,
            point_global[2] as f64,
        ) - self.center_m;
        if d.length_squared() > self.radius_sq {
            return false;
        }
        let l = self.box_from_global * d;
        l.x.abs() <= self.half_m.x && l.y.abs() <= self.half_m.y && l.z.abs() <= self.half_m.z
    }
}

fn quat(wxyz: [f64; 4]) -> DQuat {
    DQuat::from_xyzw(wxyz[1], wxyz[2], wxyz[3], wxyz[0]).normalize()
}

/// The box of a moving instance at `t_us` (see the module docs), or `None` when the instance
/// is not moving then or not known within [`MAX_TIME_DIFF_S`]. `track` is sorted by time.
pub fn box_at(track: &[TrackPoint], t_us: i64, margin_m: f64) -> Option<BoxAt> {
    let max_us = (MAX_TIME_DIFF_S * 1e6) as i64;
    let after = track.partition_point(|p| p.timestamp_us < t_us);
    // Exactly on an annotation.
    if let Some(p) = track.get(after).filter(|p| p.timestamp_us == t_us) {
        return p.moving.then(|| {
            BoxAt::new(
                DVec3::from(p.center_m),
                quat(p.rotation_wxyz),
                p.size_wlh_m,
                margin_m,
            )
        });
    }
    let prev = after.checked_sub(1).and_then(|i| track.get(i));
    let next = track.get(after);
    if let (Some(a), Some(b)) = (prev, next) {
        if b.timestamp_us - a.timestamp_us <= max_us {
            if !(a.moving || b.moving) {
                return None;
            }
            let s = (t_us - a.timestamp_us) as f64 / (b.timestamp_us - a.timestamp_us) as f64;
            let c = DVec3::from(a.center_m).lerp(DVec3::from(b.center_m), s);
            let r = quat(a.rotation_wxyz).slerp(quat(b.rotation_wxyz), s);
            return Some(BoxAt::new(c, r, b.size_wlh_m, margin_m));
        }
    }
    // Extrapolate from the nearer annotation.
    let p = match (prev, next) {
        (Some(a), Some(b)) => {
            if t_us - a.timestamp_us <= b.timestamp_us - t_us {
                a
            } else {
                b
            }
        }
        (Some(a), None) => a,
        (None, Some(b)) => b,
        (None, None) => return None,
    };
    let dt_us = t_us - p.timestamp_us;
    if !p.moving || dt_us.abs() > max_us {
        return None;
    }
    let v = p.velocity_mps.map(DVec3::from).unwrap_or(DVec3::ZERO);
    let c = DVec3::from(p.center_m) + v * (dt_us as f64 * 1e-6);
    Some(BoxAt::new(c, quat(p.rotation_wxyz), p.size_wlh_m, margin_m))
}

/// nuscenes-devkit `box_velocity`: (next − prev) / (t_next − t_prev) over the annotation's
/// neighbours (itself where one is missing); `None` without neighbours or when they are more
/// than `MAX_TIME_DIFF_S` apart (twice that for a centred difference).
pub fn devkit_velocity(
    prev: Option<(i64, [f64; 3])>,
    this: (i64, [f64; 3]),
    next: Option<(i64, [f64; 3])>,
) -> Option<[f64; 3]> {
    if prev.is_none() && next.is_none() {
        return None;
    }
    let first = prev.unwrap_or(this);
    let last = next.unwrap_or(this);
    let dt_s = (last.0 - first.0) as f64 * 1e-6;
    let max = if prev.is_some() && next.is_some() {
        2.0 * MAX_TIME_DIFF_S
    } else {
        MAX_TIME_DIFF_S
    };
    if dt_s <= 0.0 || dt_s > max {
        return None;
    }
    Some([
        (last.1[0] - first.1[0]) / dt_s,
        (last.1[1] - first.1[1]) / dt_s,
        (last.1[2] - first.1[2]) / dt_s,
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A car (4.5 m long, 1.8 m wide) driving along +x at 10 m/s, annotated at 0 and 0.5 s.
    fn car() -> Vec<TrackPoint> {
        let p = |t_s: f64, x: f64| TrackPoint {
            timestamp_us: (t_s * 1e6) as i64,
            center_m: [x, 0.0, 1.0],
            rotation_wxyz: [1.0, 0.0, 0.0, 0.0],
            size_wlh_m: [1.8, 4.5, 1.5],
            velocity_mps: Some([10.0, 0.0, 0.0]),
            moving: true,
        };
        vec![p(0.0, 100.0), p(0.5, 105.0)]
    }

    #[test]
    fn box_is_interpolated_to_the_sweep_time_with_a_small_margin() {
        // Sweep at 0.25 s: the car is at x = 102.5, not at either annotation.
        let b = box_at(&car(), 250_000, BOX_MARGIN_M).unwrap();
        assert!((b.center_m.x - 102.5).abs() < 1e-9);
        assert!(b.contains([102.5, 0.0, 1.0]));
        assert!(b.contains([104.6, 0.9, 1.6]), "on the front corner");
        // Static points 1 m beside the interpolated box survive: left/right of it, ahead of and
        // behind it, on the road under it 1 m down. (The old rule — nearest annotation grown
        // by 0.25 m + 10 m/s·0.25 s on all axes — removed them all.)
        for p in [
            [102.5, 0.9 + 1.0, 1.0],
            [102.5, -(0.9 + 1.0), 1.0],
            [102.5 + 2.25 + 1.0, 0.0, 1.0],
            [102.5 - 2.25 - 1.0, 0.0, 1.0],
            [102.5, 0.0, 1.0 - 0.75 - 1.0],
        ] {
            assert!(
                !b.contains([p[0] as f32, p[1] as f32, p[2] as f32]),
                "{p:?}"
            );
        }
    }

    #[test]
    fn rotation_is_slerped_and_gaps_are_respected() {
        let mut t = car();
        // Turning 90° between the annotations: halfway, the box is at 45°.
        let h = std::f64::consts::FRAC_PI_4;
        t[1].rotation_wxyz = [h.cos(), 0.0, 0.0, h.sin()];
        let b = box_at(&t, 250_000, 0.0).unwrap();
        let x_axis = b.box_from_global.inverse() * DVec3::X;
        assert!((x_axis.y.atan2(x_axis.x) - h).abs() < 1e-9);
        // Annotations 2 s apart are not interpolated: the nearer one is extrapolated ≤ 1.5 s.
        let mut far = car();
        far[1].timestamp_us = 2_000_000;
        let b = box_at(&far, 300_000, 0.0).unwrap();
        assert!((b.center_m.x - 103.0).abs() < 1e-9, "{}", b.center_m.x);
        assert!(
            box_at(&car(), 2_100_000, 0.0).is_none(),
            "1.6 s past the last"
        );
        // A parked car is no mover.
        let mut parked = car();
        for p in &mut parked {
            p.moving = false;
        }
        assert!(box_at(&parked, 250_000, 0.0).is_none());
    }

    #[test]
    fn devkit_velocity_and_its_max_time_diff() {
        let v = devkit_velocity(None, (0, [0.0; 3]), Some((500_000, [5.0, 0.0, 0.0])));
        assert_eq!(v, Some([10.0, 0.0, 0.0]));
        assert_eq!(devkit_velocity(None, (0, [0.0; 3]), None), None);
        assert_eq!(
            devkit_velocity(None, (0, [0.0; 3]), Some((1_600_000, [5.0, 0.0, 0.0]))),
            None
        );
        // Centred differences may span twice the limit.
        assert!(devkit_velocity(
            Some((-1_400_000, [0.0; 3])),
            (0, [1.0; 3]),
            Some((1_400_000, [5.0, 0.0, 0.0]))
        )
        .is_some());
    }
}
