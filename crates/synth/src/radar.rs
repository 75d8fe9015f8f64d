//! Automotive radar (Continental ARS 408 style, as in nuScenes): sparse clusters with no
//! elevation (z = 0 in the sensor frame), range / azimuth noise, RCS by object type, Doppler and
//! ego-motion-compensated velocities, clutter and multipath ghosts, and the cluster states the
//! devkit filters act on. At most 125 points per sweep.

use std::collections::BTreeMap;

use depthsense_nuscenes::pcd::RadarPoint;
use glam::{DMat3, DVec2, DVec3};

use crate::calib::Mount;
use crate::geom::{Prim, Surface};
use crate::rng::Rng;
use crate::world::{ActorKind, Motion, World, STATIC_OBJ_BASE};

/// Maximum clusters per sweep. Real RADAR_FRONT files (404 keyframes of v1.0-mini) hold 52–125
/// points, median 125: 75 % of the files saturate this budget.
pub const MAX_POINTS: usize = 125;
/// Near scan: ±60° to 125 m; far scan: ±9° to 250 m. The ranges follow the real RADAR_FRONT
/// envelope (v1.0-mini): outside ±10° azimuth real points reach 117–130 m (max per 10° bin),
/// inside ±10° they reach 252–258 m. (The earlier 70 m near range, from the ARS 408 brochure,
/// cut off the 25 % of real kept points that lie beyond 70 m, most of them off the far beam.)
pub const NEAR_FOV_DEG: f64 = 60.0;
pub const NEAR_RANGE_M: f64 = 125.0;
pub const FAR_FOV_DEG: f64 = 9.0;
pub const FAR_RANGE_M: f64 = 250.0;
/// Range noise 1σ: `RANGE_SIGMA_M + RANGE_SIGMA_REL · r`.
pub const RANGE_SIGMA_M: f64 = 0.12;
pub const RANGE_SIGMA_REL: f64 = 0.002;
/// Azimuth noise 1σ (degrees).
pub const AZ_SIGMA_DEG: f64 = 0.3;
/// Range resolution (m) of the near scan (to 70 m) and of the far scan (ARS 408-21 data
/// sheet), used to count the clusters of an extended object.
pub const NEAR_RANGE_CELL_M: f64 = 0.39;
pub const FAR_RANGE_CELL_M: f64 = 1.79;
const NEAR_CELL_LIMIT_M: f64 = 70.0;

/// Range resolution cells spanned by [r_lo, r_hi] (m).
fn range_cells(r_lo: f64, r_hi: f64) -> f64 {
    let near = (r_hi.min(NEAR_CELL_LIMIT_M) - r_lo.min(NEAR_CELL_LIMIT_M)).max(0.0);
    let far = (r_hi.max(NEAR_CELL_LIMIT_M) - r_lo.max(NEAR_CELL_LIMIT_M)).max(0.0);
    near / NEAR_RANGE_CELL_M + far / FAR_RANGE_CELL_M
}
/// Spread (1σ, dB) of a cluster's RCS about its object's typical value: aspect-angle and
/// multipath fluctuation. Real kept RCS spans 0.0 / 6.5 / 18.5 dBsm (p10/p50/p90, 18.5 dB
/// p10–p90); with ±2.5 dB per class the synthetic span was 22.5 dB but clustered on the class
/// values (−7.5 / 9.0 / 15.0).
pub const RCS_SIGMA_DB: f64 = 4.0;

/// Real `invalid_state` codes of flagged RADAR_FRONT points (v1.0-mini, share of all flagged
/// points, which are 48.4 % of all points): 11 no local maximum 25.6 %, 4 low RCS 22.1 %,
/// 9 high child probability 17.6 %, 16 14.0 %, 7 outside the FOV 11.6 %, 15 suspicious angle
/// 4.8 %, 3 far cluster not confirmed in near range 2.1 %, 10 1.4 %, 12 0.4 %, 6 mirror 0.2 %.
/// Weights in per mille of flagged points (code 4 is drawn separately for weak clusters).
const INVALID_CODES: [(i8, u32); 9] = [
    (11, 256),
    (9, 176),
    (16, 140),
    (7, 116),
    (15, 48),
    (3, 21),
    (10, 14),
    (12, 4),
    (6, 2),
];
/// Probability that a surface cluster is flagged (`invalid_state != 0`). Real: 48.4 % of all
/// points are flagged; clutter and ghosts (a minority of points) are flagged more often, so
/// surfaces get slightly less (the sum is measured by `tests/radar_stats.rs`).
const P_INVALID_SURFACE: f64 = 0.45;
/// Clutter (spurious clusters with no object behind them) is drawn within this range.
const CLUTTER_RANGE_M: f64 = 70.0;
/// Same for multipath ghosts and for clutter.
const P_INVALID_GHOST: f64 = 0.6;
const P_INVALID_CLUTTER: f64 = 0.75;

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

/// Weakest cluster (dBsm) reported at range `r_m`: the radar equation's r⁻⁴ loss, partly
/// offset by the sensor's range-dependent gain. Fitted to the real RADAR_FRONT files: kept RCS
/// p10 rises from −3.0 dBsm below 30 m to +1.0 (30–60 m) and +1.5 dBsm beyond 60 m.
pub fn rcs_min_dbsm(r_m: f64) -> f64 {
    -10.0 + 12.0 * (r_m.max(1.0) / 10.0).log10()
}

/// Azimuth resolution (degrees) of the near scan at azimuth `az_rad`: 3.2° at boresight,
/// 4.5° at ±45°, 12.3° at ±60° (ARS 408-21 data sheet), linear in between. Wider cells merge
/// the returns of an extended object into fewer clusters; this is what thins out the real
/// points off boresight (see [`antenna_loss_db`] for the measured azimuth distribution).
pub fn az_resolution_deg(az_rad: f64) -> f64 {
    let a = az_rad.to_degrees().abs();
    if a <= 45.0 {
        3.2 + (4.5 - 3.2) * a / 45.0
    } else {
        4.5 + (12.3 - 4.5) * ((a - 45.0) / 15.0).min(1.0)
    }
}

/// Two-way antenna gain loss (dB) off boresight, `az_rad` in the sensor frame. Real kept
/// RADAR_FRONT points thin out with azimuth: 14.8 / 16.1 / 25.8 / 18.3 / 13.6 / 8.0 / 3.1 / 0.3 %
/// in the |az| bins 0–5–10–20–30–40–50–60–90°, although a street scene offers the most surface
/// at high azimuth (the synthetic radar without this loss put 26 % of its kept points at
/// 40–60°, real 11 %).
pub fn antenna_loss_db(az_rad: f64) -> f64 {
    12.0 * (az_rad.to_degrees() / NEAR_FOV_DEG).powi(2)
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

/// Hits (horizontal range m, azimuth rad in the sensor frame) grouped by object.
type Hits = BTreeMap<u32, Vec<(f64, f64)>>;

/// The sensor at one time: origin and global_from_radar rotation, and the primitives it can
/// see.
struct RadarView {
    o: DVec3,
    r: DMat3,
    prims: Vec<Prim>,
    /// Per primitive, the azimuths (rad, sensor frame) its hull spans; (−∞, ∞) when part of
    /// it is not in front of the sensor. A ray of another azimuth cannot hit it.
    az_spans: Vec<(f64, f64)>,
}

impl RadarView {
    fn new(o: DVec3, r: DMat3, prims: Vec<Prim>) -> RadarView {
        let rt = r.transpose();
        let az_spans = prims
            .iter()
            .map(|p| {
                let mut span = (f64::INFINITY, f64::NEG_INFINITY);
                for c in p.hull_corners() {
                    let l = rt * (c - o);
                    if l.x <= 0.0 {
                        return (f64::NEG_INFINITY, f64::INFINITY);
                    }
                    let az = l.y.atan2(l.x);
                    span = (span.0.min(az), span.1.max(az));
                }
                // A margin far above rounding, far below the fan's steps.
                (span.0 - 1e-6, span.1 + 1e-6)
            })
            .collect();
        RadarView {
            o,
            r,
            prims,
            az_spans,
        }
    }

    /// [`RadarView::nearest_hit`] for a ray of azimuth `az` (sensor frame): the primitives
    /// whose azimuth span leaves it out are not tested (the same result, fewer tests).
    fn nearest_hit_at(&self, d: DVec3, az: f64, max_r: f64) -> (f64, Option<u32>) {
        let mut best = max_r;
        let mut who = None;
        for (p, &(lo, hi)) in self.prims.iter().zip(&self.az_spans) {
            if az < lo || az > hi {
                continue;
            }
            if let Some(tp) = p.intersect(self.o, d, 0.5, best) {
                best = tp;
                who = Some(p.obj);
            }
        }
        (best, who)
    }

    /// Nearest primitive hit along global direction `d` within `max_r`: (distance, object).
    fn nearest_hit(&self, d: DVec3, max_r: f64) -> (f64, Option<u32>) {
        let mut best = max_r;
        let mut who = None;
        for p in &self.prims {
            if let Some(tp) = p.intersect(self.o, d, 0.5, best) {
                best = tp;
                who = Some(p.obj);
            }
        }
        (best, who)
    }

    /// Fan of rays over ±`fov` degrees every `step` degrees, two elevations.
    fn fan(&self, fov: f64, step: f64, max_r: f64, hits: &mut Hits) {
        let n = (2.0 * fov / step).round() as i64;
        for k in 0..=n {
            let az = (-fov + step * k as f64).to_radians();
            for el in [0.0f64, 2.5] {
                let (se, ce) = el.to_radians().sin_cos();
                let ds = DVec3::new(ce * az.cos(), ce * az.sin(), se);
                let d = self.r * ds;
                let (best, who) = self.nearest_hit_at(d, az, max_r);
                if let Some(obj) = who {
                    // Range in the horizontal plane (the radar reports no elevation).
                    hits.entry(obj).or_default().push((best * ce, az));
                }
            }
        }
    }

    /// Thin vertical targets (poles, sign posts): the radar beam (degrees wide) always covers
    /// them, but a 0.75° / 0.25° ray fan misses most of them beyond 20 m. Aim one ray at each
    /// one's axis at 1.0 m, 2.2 m and near its top (the elevation beam is several degrees
    /// wide: it sees over parked cars and under tree crowns); it counts when one of these rays
    /// hits nothing else first.
    fn pole_hits(&self, hits: &mut Hits) {
        let (o, rt) = (self.o, self.r.transpose());
        for p in &self.prims {
            let crate::geom::Shape::Cyl { c, r: rad, z0, z1 } = p.shape else {
                continue;
            };
            if p.surface != Surface::Pole || z0 > 0.5 || z1 < 2.3 || hits.contains_key(&p.obj) {
                continue;
            }
            let flat = DVec3::new(c.x - o.x, c.y - o.y, 0.0);
            let ls = rt * flat;
            let az = ls.y.atan2(ls.x);
            let az_deg = az.to_degrees().abs();
            let dist_h = flat.length();
            let in_fov = (az_deg <= NEAR_FOV_DEG && dist_h < NEAR_RANGE_M)
                || (az_deg <= FAR_FOV_DEG && dist_h < FAR_RANGE_M);
            if !in_fov || dist_h < 1.0 {
                continue;
            }
            for z in [1.0, 2.2, z1 - 0.2] {
                let to = DVec3::new(flat.x, flat.y, z - o.z);
                let dist = to.length();
                let d = to / dist;
                let mut best = dist;
                let mut who = None;
                for q in &self.prims {
                    if let Some(tq) = q.intersect(o, d, 0.5, best + rad) {
                        if tq < best {
                            best = tq;
                            who = Some(q.obj);
                        }
                    }
                }
                if who == Some(p.obj) {
                    // Range in the horizontal plane (the radar reports no elevation).
                    hits.entry(p.obj)
                        .or_default()
                        .push((best * d.truncate().length(), az));
                    break;
                }
            }
        }
    }
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
    let view = RadarView::new(o, r, prims);
    let (ego_v, ego_w) = world.ego_motion(t);
    let (ep, _) = world.ego_pose(t);
    // Velocity of the sensor: ego velocity + ω × lever arm.
    let arm = o - ep;
    let v_sensor = ego_v + DVec3::new(-ego_w * arm.y, ego_w * arm.x, 0.0);

    // Fan of rays: near and far scans, two elevations each; hits grouped by object.
    let mut hits: Hits = BTreeMap::new();
    view.fan(NEAR_FOV_DEG, 0.75, NEAR_RANGE_M, &mut hits);
    view.fan(FAR_FOV_DEG, 0.25, FAR_RANGE_M, &mut hits);
    view.pole_hits(&mut hits);
    let mut dets: Vec<Det> = Vec::new();
    for (&obj, hs) in &hits {
        object_clusters(world, t, &view, obj, hs, &mut rng, &mut dets);
    }
    add_ghosts(&mut dets, &mut rng);
    add_clutter(&mut dets, &mut rng);
    // The sensor reports at most 125 clusters: keep the nearest.
    dets.sort_by(|a, b| a.range.total_cmp(&b.range));
    dets.truncate(MAX_POINTS);

    let mut out: Vec<(RadarPoint, Origin, f64)> = Vec::with_capacity(dets.len());
    for d in &dets {
        out.push(radar_point(d, &r, v_sensor, &mut rng));
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

/// How object `obj` reflects: typical RCS (dBsm), detection probability, most clusters,
/// velocity (global) and whether it is an actor that moves.
struct Reflector {
    base_rcs: f64,
    p_det: f64,
    max_k: usize,
    v_obj: DVec3,
    moving_actor: bool,
}

/// The reflection properties of object `obj` at time `t`.
fn reflector(world: &World, t: f64, prims: &[Prim], obj: u32) -> Reflector {
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
    let (base_rcs, p_det, max_k) = match (kind, surface) {
        (Some(ActorKind::Pedestrian), _) => (ActorKind::Pedestrian.rcs_dbsm(), 0.55, 1),
        (Some(k @ (ActorKind::Truck | ActorKind::Bus)), _) => (k.rcs_dbsm(), 0.95, 8),
        (Some(k), _) => (k.rcs_dbsm(), 0.92, 4),
        // Extended facades return many resolution cells along their length.
        (None, Some(Surface::Facade)) => (12.0, 0.85, 24),
        (None, Some(Surface::Wall)) => (8.0, 0.75, 8),
        (None, Some(Surface::Pole | Surface::LampHead)) => (5.0, 0.85, 1),
        // Trees: trunk and crown, a volume scatterer a few resolution cells wide.
        (None, Some(_)) => (-2.0, 0.6, 3),
        (None, None) => (0.0, 0.3, 1),
    };
    Reflector {
        base_rcs,
        p_det,
        max_k,
        v_obj,
        moving_actor,
    }
}

/// Clusters on an object: one per resolution cell it fills, in azimuth (cells widen off
/// boresight, see `az_resolution_deg`) and in range (1.79 m, the far scan's range
/// resolution: a facade seen at a grazing angle spans many range cells). Returns the hits'
/// azimuth span (rad) and the number of cells.
fn resolution_cells(hs: &[(f64, f64)]) -> (f64, f64, f64) {
    let (mut az_lo, mut az_hi, mut r_lo, mut r_hi) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for h in hs {
        az_lo = az_lo.min(h.1);
        az_hi = az_hi.max(h.1);
        r_lo = r_lo.min(h.0);
        r_hi = r_hi.max(h.0);
    }
    let cells = (az_hi - az_lo).to_degrees() / az_resolution_deg(0.5 * (az_lo + az_hi))
        + range_cells(r_lo, r_hi)
        + 1.0;
    (az_lo, az_hi, cells)
}

/// The clusters of object `obj` from its fan hits `hs` (none when it is not detected).
fn object_clusters(
    world: &World,
    t: f64,
    view: &RadarView,
    obj: u32,
    hs: &[(f64, f64)],
    rng: &mut Rng,
    dets: &mut Vec<Det>,
) {
    let refl = reflector(world, t, &view.prims, obj);
    let nearest = hs.iter().map(|h| h.0).fold(f64::INFINITY, f64::min);
    // Targets fade towards the end of the far beam.
    let p = refl.p_det * (1.0 - (nearest / FAR_RANGE_M).powf(1.5)).max(0.0);
    if !rng.chance(p) {
        return;
    }
    let (az_lo, az_hi, cells) = resolution_cells(hs);
    let k = ((cells * rng.range(0.75, 1.25)).round() as usize).clamp(1, refl.max_k);
    let mut used = Vec::new();
    for i in 0..k {
        let (range, az) = if i < hs.len() {
            let j = rng.below(hs.len());
            if used.contains(&j) {
                continue;
            }
            used.push(j);
            hs[j]
        } else {
            // More cells than fan rays (a far facade at a grazing angle): aim a
            // horizontal ray into the object's azimuth span; it counts only when it hits
            // this object first, so the cluster lies on its surface.
            let az = rng.range(az_lo, az_hi);
            let d = view.r * DVec3::new(az.cos(), az.sin(), 0.0);
            let (best, who) = view.nearest_hit(d, FAR_RANGE_M);
            if who != Some(obj) {
                continue;
            }
            (best, az)
        };
        let rcs = refl.base_rcs + RCS_SIGMA_DB * rng.normal();
        // Clusters below the sensitivity at their range and azimuth are not reported.
        if rcs - antenna_loss_db(az) < rcs_min_dbsm(range) {
            continue;
        }
        dets.push(Det {
            range,
            az,
            obj,
            rcs,
            v_obj: refl.v_obj,
            origin: Origin::Surface { obj },
            moving_actor: refl.moving_actor,
        });
    }
}

/// Multipath ghosts behind vehicles.
fn add_ghosts(dets: &mut Vec<Det>, rng: &mut Rng) {
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
}

/// Clutter (at least one point: a radar file is never empty).
fn add_clutter(dets: &mut Vec<Det>, rng: &mut Rng) {
    let n_clutter = 6 + rng.below(25);
    for _ in 0..n_clutter {
        dets.push(Det {
            range: rng.range(3.0, CLUTTER_RANGE_M),
            az: rng.range(-NEAR_FOV_DEG, NEAR_FOV_DEG).to_radians(),
            obj: u32::MAX,
            rcs: -10.0 + 4.0 * rng.normal(),
            v_obj: DVec3::ZERO,
            origin: Origin::Clutter,
            moving_actor: false,
        });
    }
}

/// The reported point of detection `d` (noise, Doppler, cluster states) with its origin and
/// noisy range; `r` is global_from_radar, `v_sensor` the sensor's velocity (global).
fn radar_point(d: &Det, r: &DMat3, v_sensor: DVec3, rng: &mut Rng) -> (RadarPoint, Origin, f64) {
    let sig_r = RANGE_SIGMA_M + RANGE_SIGMA_REL * d.range;
    let (rr, az) = match d.origin {
        Origin::Surface { .. } => (
            d.range + sig_r * rng.normal(),
            d.az + AZ_SIGMA_DEG.to_radians() * rng.normal(),
        ),
        _ => (d.range, d.az),
    };
    let los_s = DVec2::new(az.cos(), az.sin());
    let los_g = *r * DVec3::new(los_s.x, los_s.y, 0.0);
    let v_rel = d.v_obj - v_sensor;
    let vr = v_rel.dot(los_g) + 0.1 * rng.normal();
    let vc = d.v_obj.dot(los_g) + 0.1 * rng.normal();
    let speed = d.v_obj.length();
    // Cluster states (SPEC §2 filters act on them). Rates from the real RADAR_FRONT files
    // (v1.0-mini, 404 keyframes): invalid_state ≠ 0 48.4 %, ambig_state ≠ 3 9.6 %
    // (0: 6.7 %, almost all with invalid_state 7 or 3; 1: 2.3 %; 2: 0.6 %; never 4),
    // dyn_prop 7 0.5 %; together 50.0 % pass the devkit filters.
    let invalid = invalid_state(d, rng);
    let ambig = ambig_state(invalid, rng);
    let dyn_prop = dyn_prop(d, los_g, speed, rng);
    let pdh0 = match d.origin {
        Origin::Surface { .. } => 1,
        Origin::Ghost { .. } => 3 + rng.below(4) as i8,
        Origin::Clutter => 2 + rng.below(6) as i8,
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
    (p, d.origin, rr)
}

/// `invalid_state` of a cluster: 0 (valid) or a flag code drawn with the real rates.
fn invalid_state(d: &Det, rng: &mut Rng) -> i8 {
    let p_invalid = match d.origin {
        Origin::Surface { .. } => P_INVALID_SURFACE,
        Origin::Ghost { .. } => P_INVALID_GHOST,
        Origin::Clutter => P_INVALID_CLUTTER,
    };
    if !rng.chance(p_invalid) {
        0
    } else if matches!(d.origin, Origin::Ghost { .. }) && rng.chance(0.3) {
        6 // high mirror probability
    } else if d.rcs < rcs_min_dbsm(d.range) + 4.0 && rng.chance(0.6) {
        // "valid cluster with low RCS": real flagged points have lower RCS
        // (p50 2.0 dBsm against 6.5 for kept points).
        4
    } else {
        let total: u32 = INVALID_CODES.iter().map(|c| c.1).sum();
        let mut x = rng.below(total as usize) as u32;
        let mut code = INVALID_CODES[0].0;
        for &(c, w) in &INVALID_CODES {
            if x < w {
                code = c;
                break;
            }
            x -= w;
        }
        code
    }
}

/// `ambig_state` of a cluster with `invalid_state` `invalid`.
fn ambig_state(invalid: i8, rng: &mut Rng) -> i8 {
    if matches!(invalid, 7 | 3) && rng.chance(0.95) {
        0
    } else if rng.chance(0.025) {
        1
    } else if rng.chance(0.006) {
        2
    } else {
        3
    }
}

/// `dyn_prop` of a cluster: from the object's motion along the line of sight `los_g`
/// (global), `speed` its speed (m/s).
fn dyn_prop(d: &Det, los_g: DVec3, speed: f64, rng: &mut Rng) -> i8 {
    match d.origin {
        Origin::Surface { .. } | Origin::Ghost { .. } => {
            if speed > 0.5 {
                let along = d.v_obj.dot(los_g) / speed;
                if along > 0.5 {
                    0
                } else if along < -0.5 {
                    2
                } else {
                    6
                }
            } else if d.moving_actor && rng.chance(0.2) {
                7 // stopped (real: 0.5 % of all points)
            } else {
                // Real kept static points: dyn_prop 1 68 %, 3 22 %, 5 0.6 %.
                *rng.pick(&[1, 1, 1, 1, 1, 1, 1, 3, 3, 3, 5])
            }
        }
        // Clutter: stationary, stationary candidate or unknown (real dyn_prop 4 = 5.7 %).
        Origin::Clutter => *rng.pick(&[1, 3, 4, 4]),
    }
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
