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

/// Cast one sweep at time t (s since scene start).
pub fn scan(world: &World, t: f64, salt: u64) -> LidarSweep {
    let (o, r) = lidar_pose(world, t);
    let rt = r.transpose();
    let mut rng = Rng::stream(salt, &[0x11DA]);
    let prims = world.snapshot(t, o.truncate(), LIDAR_MAX_RANGE_M + 5.0);
    let n_az = LIDAR_AZIMUTHS;
    let two_pi = std::f64::consts::TAU;
    // Column lists: which primitives can be hit in each azimuth column.
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
    let elev = calib::lidar_elevations_deg();
    let rain = world.weather == Weather::Rain;
    let base_drop = if rain { 0.07 } else { 0.02 };
    let mut points = Vec::with_capacity(n_az * 32);
    let mut objs = Vec::with_capacity(n_az * 32);
    let az_jitter = rng.range(0.0, 1.0);
    for (ci, col) in cols.iter().enumerate() {
        let az = -std::f64::consts::PI + (ci as f64 + az_jitter) * two_pi / n_az as f64;
        let (sa, ca) = az.sin_cos();
        for (ring, &e) in elev.iter().enumerate() {
            let (se, ce) = e.to_radians().sin_cos();
            let ds = DVec3::new(ce * ca, ce * sa, se);
            let d = r * ds;
            let mut best = LIDAR_MAX_RANGE_M;
            let mut what: Option<(f64, u32)> = None;
            let mut gnd: Option<(DVec3, Ground)> = None;
            if let Some((tg, n, g)) = world.ground_hit(o, d, best) {
                best = tg;
                gnd = Some((n, g));
            }
            for &pi in col {
                let p: &Prim = &prims[pi as usize];
                if let Some(tp) = p.intersect(o, d, 0.3, best) {
                    best = tp;
                    what = Some((tp, pi));
                }
            }
            let (range, refl, nrm, obj) = if let Some((tp, pi)) = what {
                let p = &prims[pi as usize];
                let n = p.normal(o + d * tp);
                (tp, reflectivity(p.surface), n, p.obj)
            } else if let Some((n, g)) = gnd {
                (best, ground_reflectivity(g), n, u32::MAX)
            } else {
                if rain && rng.chance(0.004) {
                    // Spurious return from a rain drop close to the sensor.
                    let rr = rng.range(1.5, 6.0);
                    let q = ds * rr;
                    points.push([
                        q.x as f32,
                        q.y as f32,
                        q.z as f32,
                        rng.range(0.0, 3.0) as f32,
                        ring as f32,
                    ]);
                    objs.push(u32::MAX);
                }
                continue;
            };
            let cos_i = nrm.dot(-d).abs().max(0.05);
            let drop = base_drop
                + (range / LIDAR_MAX_RANGE_M).powi(2) * 0.25
                + if refl < 8.0 { 0.15 } else { 0.0 };
            if rng.chance(drop) {
                continue;
            }
            let rr = range + RANGE_SIGMA_M * rng.normal();
            let q = ds * rr;
            let inten = (refl * (0.35 + 0.65 * cos_i) * rng.range(0.85, 1.15))
                .clamp(0.0, 255.0)
                .round();
            points.push([
                q.x as f32,
                q.y as f32,
                q.z as f32,
                inten as f32,
                ring as f32,
            ]);
            objs.push(obj);
        }
    }
    LidarSweep { points, objs }
}
