//! LIDAR_TOP: a spinning 32-beam lidar (HDL-32E pattern) cast against the world, with range
//! noise, intensity from surface reflectivity and incidence, and dropouts.
//! Points are in the sensor frame at the sweep's timestamp (motion-compensated, as nuScenes).

use glam::{DMat3, DVec3};

use crate::calib::{self, LIDAR_AZIMUTHS, LIDAR_MAX_RANGE_M};
use crate::geom::{Prim, Surface};
use crate::rng::Rng;
use crate::world::{Ground, World};
use crate::Weather;

/// Range noise (1σ, m).
pub const RANGE_SIGMA_M: f64 = 0.015;

/// One sweep: points (x, y, z, intensity, ring) in the sensor frame, and for each point the
/// object it hit (`u32::MAX` for ground / spurious returns).
pub struct LidarSweep {
    pub points: Vec<[f32; 5]>,
    pub objs: Vec<u32>,
}

/// Sensor pose (global_from_lidar) at time t.
pub fn lidar_pose(world: &World, t: f64) -> (DVec3, DMat3) {
    let m = calib::lidar_top();
    let (ep, eq) = world.ego_pose(t);
    (
        ep + eq * m.translation(),
        DMat3::from_quat(eq * m.rotation()),
    )
}

fn reflectivity(s: Surface) -> f64 {
    match s {
        Surface::Facade => 25.0,
        Surface::Wall => 30.0,
        Surface::CarBody => 45.0,
        Surface::CarGlass => 8.0,
        Surface::Wheel => 6.0,
        Surface::Person => 18.0,
        Surface::Skin => 20.0,
        Surface::Pole => 40.0,
        Surface::LampHead => 60.0,
        Surface::Bark => 15.0,
        Surface::Foliage => 22.0,
    }
}

fn ground_reflectivity(g: Ground) -> f64 {
    match g {
        Ground::Road => 6.0,
        Ground::Marking => 90.0,
        Ground::Sidewalk => 14.0,
        Ground::Kerb => 18.0,
        Ground::Verge => 10.0,
    }
}

/// The ego car's roof in the LIDAR_TOP frame (x right, y forward, z up; the nuScenes
/// mount): a plane `EGO_ROOF_DROP_M` below the sensor over x ∈ ±`EGO_ROOF_HALF_WIDTH_M`,
/// y ∈ [`EGO_ROOF_REAR_M`, `EGO_ROOF_FRONT_M`]. Rays of the lower beams that meet it return
/// from the roof (as in the real kf0 scan: 8,274 of 34,688 points with |x| < 1 m and
/// |y| < 1 m, the roof at z ≈ −0.35 m, x within ±0.56 m, y from −1.0 to +0.63 m), and the
/// world behind it is hidden. `prepare` must remove these returns (devkit `remove_close`).
pub const EGO_ROOF_DROP_M: f64 = 0.35;
pub const EGO_ROOF_HALF_WIDTH_M: f64 = 0.58;
pub const EGO_ROOF_REAR_M: f64 = -0.98;
pub const EGO_ROOF_FRONT_M: f64 = 0.63;
/// Roof returns that the sensor drops (fraction).
const EGO_ROOF_DROPOUT: f64 = 0.15;

/// What a beam does at the ego car's roof.
enum Roof {
    /// The beam passes the roof.
    Miss,
    /// The roof blocks the beam and the return is dropped.
    Blocked,
    /// The roof blocks the beam and returns this point.
    Return([f32; 5]),
}

/// The ego car's roof for beam direction `ds` (sensor frame).
fn ego_roof(rng: &mut Rng, ds: DVec3, ring: usize) -> Roof {
    if ds.z >= -1e-6 {
        return Roof::Miss;
    }
    let t = EGO_ROOF_DROP_M / -ds.z;
    let hit = ds * t;
    let on_roof = hit.x.abs() <= EGO_ROOF_HALF_WIDTH_M
        && (EGO_ROOF_REAR_M..=EGO_ROOF_FRONT_M).contains(&hit.y);
    if !on_roof {
        return Roof::Miss;
    }
    if rng.chance(EGO_ROOF_DROPOUT) {
        return Roof::Blocked;
    }
    let q = ds * (t + RANGE_SIGMA_M * rng.normal());
    let inten = (reflectivity(Surface::CarBody) * rng.range(0.2, 1.0)).round();
    Roof::Return([
        q.x as f32,
        q.y as f32,
        q.z as f32,
        inten as f32,
        ring as f32,
    ])
}

/// The "no return" point the sensor reports for a beam that hit nothing: within half a metre
/// of the origin, just below it, in one azimuth sector (as the real scan has them: ranges
/// 0.05–0.45 m, z ≈ −0.01 m, azimuth −135° … −90°).
fn no_return_point(rng: &mut Rng, ring: usize) -> [f32; 5] {
    let r = rng.range(0.05, 0.45);
    let az = rng.range(-130.0f64, -95.0).to_radians();
    let z = -rng.range(0.002, 0.014);
    [
        (r * az.cos()) as f32,
        (r * az.sin()) as f32,
        z as f32,
        0.0,
        ring as f32,
    ]
}

/// A world surface's return along `ds` at `range` (None when the sensor drops it).
#[allow(clippy::too_many_arguments)]
fn surface_return(
    rng: &mut Rng,
    ds: DVec3,
    ring: usize,
    range: f64,
    refl: f64,
    nrm: DVec3,
    d: DVec3,
    obj: u32,
    base_drop: f64,
) -> Option<([f32; 5], u32)> {
    let cos_i = nrm.dot(-d).abs().max(0.05);
    let drop = base_drop
        + (range / LIDAR_MAX_RANGE_M).powi(2) * 0.25
        + if refl < 8.0 { 0.15 } else { 0.0 };
    if rng.chance(drop) {
        return None;
    }
    let rr = range + RANGE_SIGMA_M * rng.normal();
    let q = ds * rr;
    let inten = (refl * (0.35 + 0.65 * cos_i) * rng.range(0.85, 1.15))
        .clamp(0.0, 255.0)
        .round();
    Some((
        [
            q.x as f32,
            q.y as f32,
            q.z as f32,
            inten as f32,
            ring as f32,
        ],
        obj,
    ))
}

/// Cast one sweep at time t (s since scene start).
pub fn scan(world: &World, t: f64, salt: u64) -> LidarSweep {
    let (o, r) = lidar_pose(world, t);
    let rt = r.transpose();
    let mut rng = Rng::stream(salt, &[0x11DA]);
    let prims = world.snapshot(t, o.truncate(), LIDAR_MAX_RANGE_M + 5.0);
    let n_az = LIDAR_AZIMUTHS;
    let two_pi = std::f64::consts::TAU;
    let cols = azimuth_columns(&prims, o, rt);
    let elev = calib::lidar_elevations_deg();
    let rain = world.weather == Weather::Rain;
    let caster = Caster {
        world,
        o,
        r,
        prims: &prims,
        rain,
        base_drop: if rain { 0.07 } else { 0.02 },
    };
    let mut points = Vec::with_capacity(n_az * 32);
    let mut objs = Vec::with_capacity(n_az * 32);
    let az_jitter = rng.range(0.0, 1.0);
    let mut ego_rng = Rng::stream(salt, &[0x11DA, 0xE60]);
    for (ci, col) in cols.iter().enumerate() {
        let az = -std::f64::consts::PI + (ci as f64 + az_jitter) * two_pi / n_az as f64;
        let (sa, ca) = az.sin_cos();
        for (ring, &e) in elev.iter().enumerate() {
            let (se, ce) = e.to_radians().sin_cos();
            let ds = DVec3::new(ce * ca, ce * sa, se);
            let (world_return, sky) = caster.world_return(&mut rng, ds, ring, col);
            // The ego car's own returns draw from their own random stream, and the world's
            // return is drawn even where the roof hides it, so that every other point is the
            // same with or without them.
            let ret = match ego_roof(&mut ego_rng, ds, ring) {
                Roof::Return(p) => Some((p, u32::MAX)),
                Roof::Blocked => None,
                Roof::Miss => match world_return {
                    Some(r) => Some(r),
                    // A ray that hit nothing reports the sensor's "no return" point near
                    // the origin (a dropped-out hit reports nothing, as before).
                    None if sky => Some((no_return_point(&mut ego_rng, ring), u32::MAX)),
                    None => None,
                },
            };
            if let Some((p, obj)) = ret {
                points.push(p);
                objs.push(obj);
            }
        }
    }
    LidarSweep { points, objs }
}

/// Column lists: which primitives can be hit in each azimuth column (sensor at `o`,
/// `rt` = lidar_from_global).
fn azimuth_columns(prims: &[Prim], o: DVec3, rt: DMat3) -> Vec<Vec<u32>> {
    let n_az = LIDAR_AZIMUTHS;
    let two_pi = std::f64::consts::TAU;
    let mut cols: Vec<Vec<u32>> = vec![Vec::new(); n_az];
    let col_of =
        |a: f64| -> i64 { ((a + std::f64::consts::PI) / two_pi * n_az as f64).floor() as i64 };
    for (pi, p) in prims.iter().enumerate() {
        if p.dist_xy(o.truncate()) < 0.3 {
            for c in cols.iter_mut() {
                c.push(pi as u32);
            }
            continue;
        }
        let cen = rt * ((p.lo + p.hi) * 0.5 - o);
        let ac = cen.y.atan2(cen.x);
        let (mut dmin, mut dmax) = (0.0f64, 0.0f64);
        for c in p.corners() {
            let q = rt * (c - o);
            let d = crate::world::wrap_angle(q.y.atan2(q.x) - ac);
            dmin = dmin.min(d);
            dmax = dmax.max(d);
        }
        let c0 = col_of(ac + dmin) - 1;
        let c1 = col_of(ac + dmax) + 1;
        for c in c0..=c1 {
            cols[c.rem_euclid(n_az as i64) as usize].push(pi as u32);
        }
    }
    cols
}

/// A primitive hit: distance (m) and primitive index.
type PrimHit = (f64, u32);
/// A ground hit: normal and ground kind.
type GroundHit = (DVec3, Ground);

/// The sensor in the world at one time: origin, global_from_lidar, the primitives near it,
/// and the weather's dropout.
struct Caster<'a> {
    world: &'a World,
    o: DVec3,
    r: DMat3,
    prims: &'a [Prim],
    rain: bool,
    base_drop: f64,
}

impl Caster<'_> {
    /// The world's return for beam `ds` (sensor frame) among the primitives of column `col`
    /// (None when dropped or nothing was hit), and whether the beam hit nothing at all.
    fn world_return(
        &self,
        rng: &mut Rng,
        ds: DVec3,
        ring: usize,
        col: &[u32],
    ) -> (Option<([f32; 5], u32)>, bool) {
        let (o, prims, base_drop) = (self.o, self.prims, self.base_drop);
        let d = self.r * ds;
        let (best, what, gnd) = self.cast(d, col);
        let sky = what.is_none() && gnd.is_none();
        let world_return: Option<([f32; 5], u32)> = if let Some((tp, pi)) = what {
            let p = &prims[pi as usize];
            let n = p.normal(o + d * tp);
            let refl = reflectivity(p.surface);
            surface_return(rng, ds, ring, tp, refl, n, d, p.obj, base_drop)
        } else if let Some((n, g)) = gnd {
            let refl = ground_reflectivity(g);
            surface_return(rng, ds, ring, best, refl, n, d, u32::MAX, base_drop)
        } else if self.rain && rng.chance(0.004) {
            Some(rain_drop_return(rng, ds, ring))
        } else {
            None
        };
        (world_return, sky)
    }

    /// Nearest hit along global direction `d`: distance, primitive (distance, index) if a
    /// primitive is nearest, ground (normal, kind) if the ground was hit.
    fn cast(&self, d: DVec3, col: &[u32]) -> (f64, Option<PrimHit>, Option<GroundHit>) {
        let o = self.o;
        let mut best = LIDAR_MAX_RANGE_M;
        let mut what: Option<(f64, u32)> = None;
        let mut gnd: Option<(DVec3, Ground)> = None;
        if let Some((tg, n, g)) = self.world.ground_hit(o, d, best) {
            best = tg;
            gnd = Some((n, g));
        }
        for &pi in col {
            let p: &Prim = &self.prims[pi as usize];
            if let Some(tp) = p.intersect(o, d, 0.3, best) {
                best = tp;
                what = Some((tp, pi));
            }
        }
        (best, what, gnd)
    }
}

/// Spurious return from a rain drop close to the sensor.
fn rain_drop_return(rng: &mut Rng, ds: DVec3, ring: usize) -> ([f32; 5], u32) {
    let rr = rng.range(1.5, 6.0);
    let q = ds * rr;
    (
        [
            q.x as f32,
            q.y as f32,
            q.z as f32,
            rng.range(0.0, 3.0) as f32,
            ring as f32,
        ],
        u32::MAX,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The scan carries the ego car's own returns as the real kf0 scan does (8,274 of 34,688
    /// points with |x| < 1 m and |y| < 1 m): a few thousand, on the roof or at the origin,
    /// and deterministic.
    #[test]
    fn scan_has_the_ego_cars_own_returns() {
        for weather in [Weather::Day, Weather::Rain] {
            let world = World::build(7, 0, weather, 4.0);
            let s = scan(&world, 1.0, 3);
            let near: Vec<&[f32; 5]> = s
                .points
                .iter()
                .filter(|p| p[0].abs() < 1.0 && p[1].abs() < 1.0)
                .collect();
            let roof = near.iter().filter(|p| p[2] < -0.2).count();
            eprintln!(
                "{weather:?}: {} points, {} near the sensor ({roof} on the roof)",
                s.points.len(),
                near.len()
            );
            assert!(
                (2000..15000).contains(&near.len()),
                "{} near-sensor points of {}",
                near.len(),
                s.points.len()
            );
            assert!(roof > 1000, "{roof} roof returns");
            assert!(near
                .iter()
                .all(|p| (p[0].hypot(p[1]) < 1.2) && p[2] > -0.45 && p[2] < 0.0));
            let again = scan(&world, 1.0, 3);
            assert_eq!(s.points, again.points);
        }
    }
}
