//! Automotive radar (Continental ARS 408 style, as in nuScenes): sparse clusters with no
//! elevation (z = 0 in the sensor frame), range / azimuth noise, RCS by object type, Doppler and
//! ego-motion-compensated velocities, clutter and multipath ghosts, and the cluster states the
//! devkit filters act on. At most 125 points per sweep.

use std::collections::BTreeMap;

use depthsense_nuscenes::pcd::RadarPoint;
use glam::{DMat3, DVec2, DVec3};

use crate::calib::Mount;
use crate::geom::Surface;
use crate::rng::Rng;
use crate::world::{ActorKind, Motion, World, STATIC_OBJ_BASE};

/// Maximum clusters per sweep.
pub const MAX_POINTS: usize = 125;
/// Near scan: ±60° to 70 m; far scan: ±9° to 200 m.
pub const NEAR_FOV_DEG: f64 = 60.0;
pub const NEAR_RANGE_M: f64 = 70.0;
pub const FAR_FOV_DEG: f64 = 9.0;
pub const FAR_RANGE_M: f64 = 200.0;
/// Range noise 1σ: `RANGE_SIGMA_M + RANGE_SIGMA_REL · r`.
pub const RANGE_SIGMA_M: f64 = 0.12;
pub const RANGE_SIGMA_REL: f64 = 0.002;
/// Azimuth noise 1σ (degrees).
pub const AZ_SIGMA_DEG: f64 = 0.3;

/// Where a radar point comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Origin {
    /// A reflection off a surface of object `obj` (range and azimuth noise added).
    Surface {
        obj: u32,
    },
    /// A multipath ghost of object `obj`.
    Ghost {
        obj: u32,
    },
    Clutter,
}

pub struct RadarSweep {
    pub points: Vec<RadarPoint>,
    pub origins: Vec<Origin>,
}

/// Sensor pose global_from_radar at time t.
pub fn radar_pose(world: &World, m: &Mount, t: f64) -> (DVec3, DMat3) {
    let (ep, eq) = world.ego_pose(t);
    (
        ep + eq * m.translation(),
        DMat3::from_quat(eq * m.rotation()),
    )
}

struct Det {
    range: f64,
    az: f64,
    obj: u32,
    rcs: f64,
    v_obj: DVec3,
    origin: Origin,
    moving_actor: bool,
}

/// One radar sweep of mount `m` at time t.
pub fn scan(world: &World, m: &Mount, t: f64, salt: u64) -> RadarSweep {
    let (o, r) = radar_pose(world, m, t);
    let mut rng = Rng::stream(salt, &[0x5ADA]);
    let rt = r.transpose();
    // Only primitives reaching in front of the sensor can be seen (FOV ≤ ±60°).
    let prims: Vec<_> = world
        .snapshot(t, o.truncate(), FAR_RANGE_M + 5.0)
        .into_iter()
        .filter(|p| p.corners().iter().any(|c| (rt * (*c - o)).x > 0.0))
        .collect();
    let (ego_v, ego_w) = world.ego_motion(t);
    let (ep, _) = world.ego_pose(t);
    // Velocity of the sensor: ego velocity + ω × lever arm.
    let arm = o - ep;
    let v_sensor = ego_v + DVec3::new(-ego_w * arm.y, ego_w * arm.x, 0.0);

    // Fan of rays: near and far scans, two elevations each; hits grouped by object.
    let mut hits: BTreeMap<u32, Vec<(f64, f64)>> = BTreeMap::new();
    let fan = |fov: f64, step: f64, max_r: f64, hits: &mut BTreeMap<u32, Vec<(f64, f64)>>| {
        let n = (2.0 * fov / step).round() as i64;
        for k in 0..=n {
            let az = (-fov + step * k as f64).to_radians();
            for el in [0.0f64, 2.5] {
                let (se, ce) = el.to_radians().sin_cos();
                let ds = DVec3::new(ce * az.cos(), ce * az.sin(), se);
                let d = r * ds;
                let mut best = max_r;
                let mut who = None;
                for p in &prims {
                    if let Some(tp) = p.intersect(o, d, 0.5, best) {
                        best = tp;
                        who = Some(p.obj);
                    }
                }
                if let Some(obj) = who {
                    // Range in the horizontal plane (the radar reports no elevation).
                    hits.entry(obj).or_default().push((best * ce, az));
                }
            }
        }
    };
    fan(NEAR_FOV_DEG, 0.75, NEAR_RANGE_M, &mut hits);
    fan(FAR_FOV_DEG, 0.25, FAR_RANGE_M, &mut hits);

    let mut dets: Vec<Det> = Vec::new();
    for (&obj, hs) in &hits {
        let (kind, surface) = if obj < STATIC_OBJ_BASE {
            (Some(world.actors[obj as usize].kind), None)
        } else {
            let s = prims.iter().find(|p| p.obj == obj).map(|p| p.surface);
            (None, s)
        };
        let (v_obj, moving_actor) = if obj < STATIC_OBJ_BASE {
            let st = world.actor_state(obj as usize, t);
            let moving = !matches!(world.actors[obj as usize].motion, Motion::Parked { .. });
            (DVec3::new(st.vel.x, st.vel.y, 0.0), moving)
        } else {
            (DVec3::ZERO, false)
        };
        let nearest = hs.iter().map(|h| h.0).fold(f64::INFINITY, f64::min);
        let (base_rcs, p_det, max_k) = match (kind, surface) {
            (Some(ActorKind::Pedestrian), _) => (ActorKind::Pedestrian.rcs_dbsm(), 0.55, 1),
            (Some(k @ (ActorKind::Truck | ActorKind::Bus)), _) => (k.rcs_dbsm(), 0.95, 6),
            (Some(k), _) => (k.rcs_dbsm(), 0.92, 4),
            (None, Some(Surface::Facade)) => (12.0, 0.85, 8),
            (None, Some(Surface::Wall)) => (8.0, 0.75, 4),
            (None, Some(Surface::Pole | Surface::LampHead)) => (3.0, 0.8, 1),
            (None, Some(_)) => (-4.0, 0.35, 1),
            (None, None) => (0.0, 0.3, 1),
        };
        // Weak targets fade with range.
        let p = p_det
            * (1.0 - (nearest / FAR_RANGE_M).powf(1.5)).max(0.0)
            * if base_rcs < 0.0 && nearest > 40.0 {
                0.3
            } else {
                1.0
            };
        if !rng.chance(p) {
            continue;
        }
        // More clusters on objects that fill more of the beam.
        let k = ((hs.len() as f64 * rng.range(0.15, 0.35)).round() as usize).clamp(1, max_k);
        let mut used = Vec::new();
        for _ in 0..k {
            let j = rng.below(hs.len());
            if used.contains(&j) {
                continue;
            }
            used.push(j);
            let (range, az) = hs[j];
            dets.push(Det {
                range,
                az,
                obj,
                rcs: base_rcs + 2.5 * rng.normal(),
                v_obj,
                origin: Origin::Surface { obj },
                moving_actor,
            });
        }
    }
    // Multipath ghosts behind vehicles.
    let n_real = dets.len();
    for i in 0..n_real {
        if rng.chance(if dets[i].obj < STATIC_OBJ_BASE {
            0.2
        } else {
            0.05
        }) {
            let d = &dets[i];
            dets.push(Det {
                range: d.range * rng.range(1.3, 2.0),
                az: d.az + rng.normal() * 1.5f64.to_radians(),
                obj: d.obj,
                rcs: d.rcs - rng.range(6.0, 12.0),
                v_obj: d.v_obj,
                origin: Origin::Ghost { obj: d.obj },
                moving_actor: d.moving_actor,
            });
        }
    }
    // Clutter (at least one point: a radar file is never empty).
    let n_clutter = 6 + rng.below(25);
    for _ in 0..n_clutter {
        dets.push(Det {
            range: rng.range(3.0, NEAR_RANGE_M),
            az: rng.range(-NEAR_FOV_DEG, NEAR_FOV_DEG).to_radians(),
            obj: u32::MAX,
            rcs: -10.0 + 4.0 * rng.normal(),
            v_obj: DVec3::ZERO,
            origin: Origin::Clutter,
            moving_actor: false,
        });
    }
    // The sensor reports at most 125 clusters: keep the nearest.
    dets.sort_by(|a, b| a.range.total_cmp(&b.range));
    dets.truncate(MAX_POINTS);

    let mut out: Vec<(RadarPoint, Origin, f64)> = Vec::with_capacity(dets.len());
    for d in &dets {
        let sig_r = RANGE_SIGMA_M + RANGE_SIGMA_REL * d.range;
        let (rr, az) = match d.origin {
            Origin::Surface { .. } => (
                d.range + sig_r * rng.normal(),
                d.az + AZ_SIGMA_DEG.to_radians() * rng.normal(),
            ),
            _ => (d.range, d.az),
        };
        let los_s = DVec2::new(az.cos(), az.sin());
        let los_g = r * DVec3::new(los_s.x, los_s.y, 0.0);
        let v_rel = d.v_obj - v_sensor;
        let vr = v_rel.dot(los_g) + 0.1 * rng.normal();
        let vc = d.v_obj.dot(los_g) + 0.1 * rng.normal();
        let speed = d.v_obj.length();
        let (dyn_prop, ambig, invalid, pdh0) = match d.origin {
            Origin::Surface { .. } => {
                let dyn_prop = if speed > 0.5 {
                    let along = d.v_obj.dot(los_g) / speed;
                    if along > 0.5 {
                        0
                    } else if along < -0.5 {
                        2
                    } else {
                        6
                    }
                } else if d.moving_actor && rng.chance(0.6) {
                    7 // stopped
                } else {
                    *rng.pick(&[1, 1, 1, 1, 1, 1, 3, 3, 5])
                };
                let ambig = if rng.chance(0.04) {
                    1
                } else if speed < 0.5 && rng.chance(0.05) {
                    4
                } else {
                    3
                };
                let invalid = if rng.chance(0.05) {
                    *rng.pick(&[8, 9, 11, 16])
                } else {
                    0
                };
                (dyn_prop, ambig, invalid, 1)
            }
            Origin::Ghost { .. } => {
                let dyn_prop = if speed > 0.5 { 0 } else { 1 };
                let invalid = if rng.chance(0.5) { 6 } else { 0 };
                (dyn_prop, 3, invalid, 3 + rng.below(4) as i8)
            }
            Origin::Clutter => {
                let dyn_prop = *rng.pick(&[1, 3, 4, 5]);
                let invalid = if rng.chance(0.5) {
                    0
                } else {
                    *rng.pick(&[1, 2, 3, 7, 14])
                };
                let ambig = if rng.chance(0.7) {
                    3
                } else {
                    *rng.pick(&[0, 1, 4])
                };
                (dyn_prop, ambig, invalid, 2 + rng.below(6) as i8)
            }
        };
        let p = RadarPoint {
            x: (rr * los_s.x) as f32,
            y: (rr * los_s.y) as f32,
            z: 0.0,
            dyn_prop,
            id: 0,
            rcs: (d.rcs * 2.0).round() as f32 / 2.0,
            vx: (vr * los_s.x) as f32,
            vy: (vr * los_s.y) as f32,
            vx_comp: (vc * los_s.x) as f32,
            vy_comp: (vc * los_s.y) as f32,
            is_quality_valid: 1,
            ambig_state: ambig,
            x_rms: (3.0 + rr / 25.0).min(31.0) as i8,
            y_rms: (4.0 + rr / 15.0).min(31.0) as i8,
            invalid_state: invalid,
            pdh0,
            vx_rms: 4,
            vy_rms: 4,
        };
        out.push((p, d.origin, rr));
    }
    out.sort_by(|a, b| a.2.total_cmp(&b.2));
    let mut points = Vec::with_capacity(out.len());
    let mut origins = Vec::with_capacity(out.len());
    for (i, (mut p, og, _)) in out.into_iter().enumerate() {
        p.id = i as i16;
        points.push(p);
        origins.push(og);
    }
    RadarSweep { points, origins }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib;
    use crate::geom::Shape;
    use crate::Weather;

    /// Horizontal distance from `p` to the footprint outline of a primitive.
    fn footprint_dist(q: &crate::geom::Prim, p: DVec2) -> f64 {
        match q.shape {
            Shape::Box { c, h, cos, sin } => {
                let d = p - c.truncate();
                let l = DVec2::new(cos * d.x + sin * d.y, -sin * d.x + cos * d.y);
                let out = (l.abs() - h.truncate()).max(DVec2::ZERO);
                if out.length() > 0.0 {
                    out.length()
                } else {
                    (h.x - l.x.abs()).min(h.y - l.y.abs())
                }
            }
            Shape::Cyl { c, r, .. } => ((p - c).length() - r).abs(),
            Shape::Sphere { c, r } => ((p - c.truncate()).length() - r).max(0.0),
        }
    }

    #[test]
    fn surface_points_lie_on_their_objects_within_noise() {
        let w = World::build(3, 0, Weather::Day, 8.0);
        let mut n_surface = 0;
        let mut n_total = 0;
        for ch in calib::RADAR_CHANNELS {
            let m = calib::radar(ch);
            for k in 0..4 {
                let t = 1.0 + 1.5 * k as f64;
                let s = scan(&w, &m, t, k);
                assert!(!s.points.is_empty() && s.points.len() <= MAX_POINTS);
                let (o, r) = radar_pose(&w, &m, t);
                let prims = w.snapshot(t, o.truncate(), FAR_RANGE_M + 10.0);
                for (p, og) in s.points.iter().zip(&s.origins) {
                    assert_eq!(p.z, 0.0, "radar has no elevation");
                    n_total += 1;
                    if let Origin::Surface { obj } = og {
                        let g = o + r * DVec3::new(p.x as f64, p.y as f64, 0.0);
                        let range = (p.x as f64).hypot(p.y as f64);
                        let tol = 4.0 * (RANGE_SIGMA_M + RANGE_SIGMA_REL * range)
                            + range * 4.0 * AZ_SIGMA_DEG.to_radians()
                            + 0.05;
                        let d = prims
                            .iter()
                            .filter(|q| q.obj == *obj)
                            .map(|q| footprint_dist(q, g.truncate()))
                            .fold(f64::INFINITY, f64::min);
                        assert!(d < tol, "{ch} point at {range:.1} m is {d:.2} m off object {obj} (tol {tol:.2})");
                        n_surface += 1;
                    }
                }
            }
        }
        assert!(n_surface > 50, "only {n_surface} surface points");
        assert!(n_total > n_surface, "no clutter or ghosts");
    }

    #[test]
    fn doppler_of_static_world_is_ego_motion() {
        // For static surfaces the compensated radial velocity is ~0 and the raw one is minus
        // the sensor's own radial speed.
        let w = World::build(4, 1, Weather::Day, 8.0);
        let m = calib::radar(calib::RADAR_FRONT);
        let t = 3.0;
        let s = scan(&w, &m, t, 9);
        let mut checked = 0;
        for (p, og) in s.points.iter().zip(&s.origins) {
            if let Origin::Surface { obj } = og {
                if *obj >= STATIC_OBJ_BASE {
                    let vc = (p.vx_comp as f64).hypot(p.vy_comp as f64);
                    assert!(vc < 0.6, "static object with compensated speed {vc}");
                    checked += 1;
                }
            }
        }
        assert!(checked > 5);
    }
}
