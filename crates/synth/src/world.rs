//! The world of one scene: a road network with lanes, markings, sidewalks and kerbs; buildings,
//! walls, poles, street lamps and trees; parked and moving cars, trucks, buses and pedestrians;
//! and the ego vehicle's drive (urban speeds, turns, stops).
//!
//! Frames: global x, y horizontal, z up (metres); ego x forward, y left, z up (SPEC §2).

use glam::{DQuat, DVec2, DVec3};

use crate::geom::{Prim, Shape, Surface};
use crate::rng::Rng;
use crate::Weather;

/// Kerb / sidewalk height above the road (m).
pub const KERB_H: f64 = 0.15;
/// Lane width (m): one driving lane each way, then a parking strip.
pub const LANE_W: f64 = 3.5;
/// Road half width: lane + parking strip.
pub const ROAD_HW: f64 = 6.0;
/// Sidewalk width.
pub const SIDEWALK_W: f64 = 3.5;
/// Ego lane centre: right-hand traffic, ego drives at l = −LANE_W/2.
pub const EGO_LANE_L: f64 = -LANE_W / 2.0;
/// Id offset of static objects (actors use their index).
pub const STATIC_OBJ_BASE: u32 = 1_000_000;

/// A straight road with sidewalks on both sides.
#[derive(Debug, Clone)]
pub struct RoadSeg {
    pub a: DVec2,
    pub dir: DVec2,
    pub len: f64,
    pub hw: f64,
    pub sw: f64,
}

impl RoadSeg {
    /// (s along, l to the left).
    #[inline]
    pub fn local(&self, p: DVec2) -> (f64, f64) {
        let q = p - self.a;
        (q.dot(self.dir), self.dir.perp_dot(q))
    }
    pub fn point(&self, s: f64, l: f64) -> DVec2 {
        self.a + self.dir * s + self.dir.perp() * l
    }
    pub fn yaw(&self) -> f64 {
        self.dir.y.atan2(self.dir.x)
    }
}

/// What the ground is at a point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ground {
    Road,
    /// White paint (lane lines, crosswalks).
    Marking,
    Sidewalk,
    /// Kerb face between road and sidewalk.
    Kerb,
    /// Beyond the sidewalk (plots between buildings).
    Verge,
}

/// A polyline parameterised by arc length.
#[derive(Debug, Clone)]
pub struct Path {
    pub pts: Vec<DVec2>,
    pub s: Vec<f64>,
}

impl Path {
    pub fn new(pts: Vec<DVec2>) -> Path {
        let mut s = Vec::with_capacity(pts.len());
        let mut acc = 0.0;
        for i in 0..pts.len() {
            if i > 0 {
                acc += (pts[i] - pts[i - 1]).length();
            }
            s.push(acc);
        }
        Path { pts, s }
    }
    pub fn len(&self) -> f64 {
        *self.s.last().unwrap_or(&0.0)
    }
    pub fn is_empty(&self) -> bool {
        self.pts.len() < 2
    }
    /// Position and heading (rad) at arc length `s` (clamped); heading is interpolated
    /// between segment directions for a smooth drive through the arcs.
    pub fn at(&self, s: f64) -> (DVec2, f64) {
        let n = self.pts.len();
        let s = s.clamp(0.0, self.len());
        let i = match self.s.binary_search_by(|x| x.total_cmp(&s)) {
            Ok(i) => i.min(n - 2),
            Err(i) => i.saturating_sub(1).min(n - 2),
        };
        let seg = self.pts[i + 1] - self.pts[i];
        let l = (self.s[i + 1] - self.s[i]).max(1e-9);
        let f = ((s - self.s[i]) / l).clamp(0.0, 1.0);
        let pos = self.pts[i] + seg * f;
        let h_here = seg.y.atan2(seg.x);
        // Blend towards the neighbouring segment's heading around vertices.
        let h = if f > 0.5 && i + 2 < n {
            let nx = self.pts[i + 2] - self.pts[i + 1];
            let hn = nx.y.atan2(nx.x);
            h_here + wrap_angle(hn - h_here) * (f - 0.5)
        } else if f < 0.5 && i > 0 {
            let pv = self.pts[i] - self.pts[i - 1];
            let hp = pv.y.atan2(pv.x);
            h_here + wrap_angle(hp - h_here) * (0.5 - f)
        } else {
            h_here
        };
        (pos, h)
    }
}

pub fn wrap_angle(a: f64) -> f64 {
    let mut a = a % std::f64::consts::TAU;
    if a > std::f64::consts::PI {
        a -= std::f64::consts::TAU;
    } else if a < -std::f64::consts::PI {
        a += std::f64::consts::TAU;
    }
    a
}

/// The ego's arc length along its path, sampled every `dt`.
#[derive(Debug, Clone)]
pub struct EgoDrive {
    pub dt: f64,
    pub s: Vec<f64>,
}

impl EgoDrive {
    pub fn s_at(&self, t: f64) -> f64 {
        let x = (t / self.dt).max(0.0);
        let i = (x.floor() as usize).min(self.s.len() - 2);
        let f = (x - i as f64).min(1.0);
        self.s[i] + (self.s[i + 1] - self.s[i]) * f
    }
    pub fn speed_at(&self, t: f64) -> f64 {
        (self.s_at(t + 0.01) - self.s_at(t - 0.01)) / 0.02
    }
}

/// Kinds of actors (annotated objects).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ActorKind {
    Car,
    Truck,
    Bus,
    Pedestrian,
}

impl ActorKind {
    /// nuScenes category name.
    pub fn category(self) -> &'static str {
        match self {
            ActorKind::Car => "vehicle.car",
            ActorKind::Truck => "vehicle.truck",
            ActorKind::Bus => "vehicle.bus.rigid",
            ActorKind::Pedestrian => "human.pedestrian.adult",
        }
    }
    /// Typical radar cross-section (dBsm).
    pub fn rcs_dbsm(self) -> f64 {
        match self {
            ActorKind::Car => 8.0,
            ActorKind::Truck => 16.0,
            ActorKind::Bus => 18.0,
            ActorKind::Pedestrian => -6.0,
        }
    }
}

/// How an actor moves.
#[derive(Debug, Clone, Copy)]
pub enum Motion {
    /// Standing still at a pose.
    Parked { pos: DVec2, yaw: f64 },
    /// Along road segment `seg` at lateral offset `l`, wrapping within [s_min, s_max].
    Lane {
        seg: usize,
        l: f64,
        s0: f64,
        v: f64,
        s_min: f64,
        s_max: f64,
    },
    /// Ahead of the ego on its path by a slowly varying gap.
    Lead {
        gap: f64,
        amp: f64,
        w: f64,
        phase: f64,
    },
}

#[derive(Debug, Clone)]
pub struct Actor {
    pub kind: ActorKind,
    pub motion: Motion,
    /// Length, width, height (m).
    pub size: DVec3,
    pub rgb: [f32; 3],
    pub clothes2: [f32; 3],
}

/// Position, heading and velocity of an actor at a time.
#[derive(Debug, Clone, Copy)]
pub struct ActorState {
    pub pos: DVec2,
    pub yaw: f64,
    pub vel: DVec2,
}

/// The world of one scene.
#[derive(Debug, Clone)]
pub struct World {
    pub scene_idx: usize,
    pub weather: Weather,
    pub segs: Vec<RoadSeg>,
    pub ego_path: Path,
    pub ego: EgoDrive,
    pub statics: Vec<Prim>,
    pub actors: Vec<Actor>,
    /// Street-lamp light positions.
    pub lamps: Vec<DVec3>,
    /// Scene duration (s).
    pub duration: f64,
    pub description: String,
    /// Verge colour (grass or paving).
    pub verge_rgb: [f32; 3],
    pub asphalt_rgb: [f32; 3],
}

const CAR_COLOURS: [[f32; 3]; 10] = [
    [0.85, 0.85, 0.86],
    [0.08, 0.08, 0.09],
    [0.55, 0.56, 0.58],
    [0.62, 0.08, 0.07],
    [0.10, 0.18, 0.45],
    [0.75, 0.72, 0.64],
    [0.20, 0.30, 0.22],
    [0.35, 0.36, 0.38],
    [0.90, 0.90, 0.92],
    [0.70, 0.45, 0.10],
];
const FACADES: [[f32; 3]; 8] = [
    [0.72, 0.66, 0.56],
    [0.55, 0.33, 0.25],
    [0.80, 0.78, 0.74],
    [0.45, 0.47, 0.50],
    [0.62, 0.55, 0.45],
    [0.85, 0.82, 0.70],
    [0.38, 0.40, 0.44],
    [0.66, 0.70, 0.72],
];

impl World {
    /// Build the world of scene `scene_idx` deterministically from `seed`.
    pub fn build(seed: u64, scene_idx: usize, weather: Weather, duration: f64) -> World {
        let mut rng = Rng::stream(seed, &[0x57_4f_52_4c_44, scene_idx as u64]);
        // Scenes lie on a grid of 1 km tiles of the synthetic city.
        let origin = DVec2::new(
            500.0 + 1000.0 * (scene_idx % 8) as f64,
            500.0 + 1000.0 * (scene_idx / 8) as f64,
        );
        let rot = rng.range(0.0, std::f64::consts::FRAC_PI_2);
        let v_cruise = rng.range(6.0, 11.0);
        let need = v_cruise * duration + 40.0 + 160.0;

        let legs = ego_legs(&mut rng, origin, rot, need);
        let segs = road_segs(&mut rng, &legs);

        // Ego path: the legs offset into the right lane, with filleted corners.
        let ego_path = Path::new(ego_path_pts(&legs));
        let turn_s = turn_midpoints(&ego_path);

        // Speed profile: cruise, slow through turns, maybe a stop (traffic light).
        let s_start = 40.0;
        let stops = plan_stops(&mut rng, &turn_s, s_start, v_cruise, duration);
        let ego = drive(&mut rng, &turn_s, &stops, s_start, v_cruise, duration);

        let mut world = World {
            scene_idx,
            weather,
            segs,
            ego_path,
            ego,
            statics: Vec::new(),
            actors: Vec::new(),
            lamps: Vec::new(),
            duration,
            description: String::new(),
            verge_rgb: if rng.chance(0.5) {
                [0.28, 0.36, 0.18]
            } else {
                [0.52, 0.50, 0.47]
            },
            asphalt_rgb: {
                let g = rng.range(0.22, 0.32) as f32;
                [g, g, g * 1.03]
            },
        };
        world.populate(&mut rng, &legs, v_cruise);
        world.describe(&mut rng, &stops, turn_s.len());
        world
    }

    fn describe(&mut self, rng: &mut Rng, stops: &[(f64, f64)], turns: usize) {
        let mut parts: Vec<String> = Vec::new();
        match self.weather {
            Weather::Night => parts.push("Night".into()),
            Weather::Rain => parts.push("Rain".into()),
            Weather::Day => {}
        }
        let peds = self
            .actors
            .iter()
            .filter(|a| a.kind == ActorKind::Pedestrian)
            .count();
        let parked = self
            .actors
            .iter()
            .filter(|a| {
                matches!(a.motion, Motion::Parked { .. }) && a.kind != ActorKind::Pedestrian
            })
            .count();
        let opts = [
            "synthetic city",
            "downtown",
            "residential street",
            "commercial area",
        ];
        parts.push(rng.pick(&opts).to_string());
        if parked > 0 {
            parts.push("parked cars".into());
        }
        if peds > 10 {
            parts.push("many peds".into());
        } else if peds > 0 {
            parts.push("peds on sidewalk".into());
        }
        if turns > 0 {
            parts.push("turns at intersections".into());
        }
        if !stops.is_empty() {
            parts.push("wait at intersection".into());
        }
        if self
            .actors
            .iter()
            .any(|a| matches!(a.motion, Motion::Lead { .. }))
        {
            parts.push("following a vehicle".into());
        }
        // nuScenes style: "Night, ..." / "Rain, ..." (SPEC §2 derives conditions from this).
        self.description = parts.join(", ");
    }

    fn populate(&mut self, rng: &mut Rng, legs: &[(DVec2, DVec2, f64)], v_cruise: f64) {
        let mut statics = StaticsBuf {
            prims: Vec::new(),
            obj: STATIC_OBJ_BASE,
        };
        let segs = self.segs.clone();
        let night = self.weather == Weather::Night;
        let _ = night;
        for (si, seg) in segs.iter().enumerate() {
            for side in [-1.0f64, 1.0] {
                self.place_buildings(rng, seg, side, &mut statics);
                self.place_lamps(rng, seg, si, side, &mut statics);
                self.place_signs(rng, seg, si, side, &mut statics);
                self.place_trees(rng, seg, si, side, &mut statics);
                self.place_parked(rng, seg, si, side);
                self.place_pedestrians(rng, seg, si, side);
            }
            self.place_traffic(rng, seg, si, legs);
        }
        self.place_lead(rng);
        let _ = v_cruise;
        // Remove parked / lane actors that would sit on the ego's own path.
        let path = self.ego_path.clone();
        self.actors.retain(|a| match a.motion {
            Motion::Parked { pos, .. } => dist_to_path(&path, pos) > 2.6,
            _ => true,
        });
        self.statics = statics.prims;
    }

    /// Buildings / walls along one side of `seg`.
    fn place_buildings(&self, rng: &mut Rng, seg: &RoadSeg, side: f64, statics: &mut StaticsBuf) {
        let mut s = rng.range(-5.0, 5.0);
        while s < seg.len {
            let w = rng.range(8.0, 28.0);
            let gap = if rng.chance(0.35) {
                rng.range(2.0, 9.0)
            } else {
                0.3
            };
            let depth = rng.range(10.0, 22.0);
            // Open streets: forecourts, car parks and plazas set many buildings far
            // back from the sidewalk. Real RADAR_FRONT kept points lie at 16.0 / 47.0 /
            // 91.1 m (p10/p50/p90) and off-axis ones reach far (|az| 20–30°: p90
            // 82 m), which a canyon of facades 10 m from the lane cannot produce
            // (a facade at 10 m lateral offset is at 8° already at 70 m). Real off-axis
            // returns sit ≈ 20 m to the side (median range 37 m at |az| 30–40°,
            // 25 m at 50–60°).
            let setback = if rng.chance(0.7) {
                rng.range(10.0, 40.0)
            } else {
                rng.range(0.0, 3.0)
            };
            let lot = Lot {
                sc: s + w / 2.0,
                w,
                depth,
                setback,
            };
            let lc = side * (seg.hw + seg.sw + lot.setback + lot.depth / 2.0);
            let c = seg.point(lot.sc, lc);
            let fp_ok = self.footprint_clear(c, seg.dir, w, depth);
            if fp_ok {
                let obj = statics.next_obj();
                statics.prims.push(building(rng, seg, side, &lot, c, obj));
            }
            s += w + gap;
        }
    }

    /// Street lamps / poles at the kerb along one side of `seg`.
    fn place_lamps(
        &mut self,
        rng: &mut Rng,
        seg: &RoadSeg,
        si: usize,
        side: f64,
        statics: &mut StaticsBuf,
    ) {
        let mut s = rng.range(5.0, 25.0);
        while s < seg.len {
            let l = side * (seg.hw + 0.5);
            let p = seg.point(s, l);
            if self.ground_kind(p) == Ground::Sidewalk && self.clear_of_other_roads(p, si, 2.0) {
                let obj = statics.next_obj();
                let h = rng.range(7.0, 9.0);
                statics.prims.push(Prim::new(
                    Shape::Cyl {
                        c: p,
                        r: 0.11,
                        z0: 0.0,
                        z1: h,
                    },
                    Surface::Pole,
                    [0.35, 0.36, 0.37],
                    obj,
                ));
                // Arm reaching over the road and the lamp head.
                let arm_c = seg.point(s, l - side * 0.9);
                statics.prims.push(Prim::oriented_box(
                    DVec3::new(arm_c.x, arm_c.y, h - 0.1),
                    DVec3::new(0.15, 1.8, 0.12),
                    seg.yaw(),
                    Surface::Pole,
                    [0.35, 0.36, 0.37],
                    obj,
                ));
                let head = seg.point(s, l - side * 1.7);
                statics.prims.push(Prim::oriented_box(
                    DVec3::new(head.x, head.y, h - 0.25),
                    DVec3::new(0.5, 0.7, 0.18),
                    seg.yaw(),
                    Surface::LampHead,
                    [0.8, 0.8, 0.75],
                    obj,
                ));
                self.lamps.push(DVec3::new(head.x, head.y, h - 0.4));
            }
            s += rng.range(26.0, 36.0);
        }
    }

    /// Street furniture at the kerb between the lamps: sign posts with a metal
    /// plate. Real RADAR_FRONT kept points are mostly static (dyn_prop 1: 68 %,
    /// 3: 22 %) and spread evenly in range from 10 to 80 m (12–14 % per 10 m bin
    /// up to 60 m, 8–10 % beyond), the signature of many small roadside targets
    /// at regular spacing.
    fn place_signs(
        &self,
        rng: &mut Rng,
        seg: &RoadSeg,
        si: usize,
        side: f64,
        statics: &mut StaticsBuf,
    ) {
        let mut s = rng.range(4.0, 16.0);
        while s < seg.len {
            let l = side * (seg.hw + 0.35);
            let p = seg.point(s, l);
            if self.ground_kind(p) == Ground::Sidewalk
                && self.clear_of_other_roads(p, si, 2.0)
                && !self.lamps.iter().any(|q| (q.truncate() - p).length() < 3.0)
            {
                let obj = statics.next_obj();
                let h = rng.range(2.4, 3.0);
                statics.prims.push(Prim::new(
                    Shape::Cyl {
                        c: p,
                        r: 0.04,
                        z0: 0.0,
                        z1: h,
                    },
                    Surface::Pole,
                    [0.55, 0.56, 0.57],
                    obj,
                ));
                let rgb = *rng.pick(&[[0.75, 0.10, 0.10], [0.10, 0.25, 0.65], [0.85, 0.85, 0.85]]);
                statics.prims.push(Prim::oriented_box(
                    DVec3::new(p.x, p.y, h - 0.35),
                    DVec3::new(0.05, 0.6, 0.6),
                    seg.yaw(),
                    Surface::Pole,
                    rgb,
                    obj,
                ));
            }
            s += rng.range(8.0, 16.0);
        }
    }

    /// Trees on the back of the sidewalk along one side of `seg`.
    fn place_trees(
        &self,
        rng: &mut Rng,
        seg: &RoadSeg,
        si: usize,
        side: f64,
        statics: &mut StaticsBuf,
    ) {
        let mut s = rng.range(3.0, 15.0);
        while s < seg.len {
            let p = seg.point(s, side * (seg.hw + seg.sw - 0.9));
            if rng.chance(0.6)
                && self.ground_kind(p) == Ground::Sidewalk
                && self.clear_of_other_roads(p, si, 3.0)
            {
                let obj = statics.next_obj();
                let th = rng.range(1.8, 3.2);
                let cr = rng.range(1.4, 2.6);
                statics.prims.push(Prim::new(
                    Shape::Cyl {
                        c: p,
                        r: rng.range(0.12, 0.22),
                        z0: 0.0,
                        z1: th + cr * 0.5,
                    },
                    Surface::Bark,
                    [0.30, 0.22, 0.15],
                    obj,
                ));
                let g = rng.range(0.8, 1.15) as f32;
                statics.prims.push(Prim::new(
                    Shape::Sphere {
                        c: DVec3::new(p.x, p.y, th + cr * 0.8),
                        r: cr,
                    },
                    Surface::Foliage,
                    [0.16 * g, 0.32 * g, 0.10 * g],
                    obj,
                ));
            }
            s += rng.range(10.0, 22.0);
        }
    }

    /// Parked vehicles in the parking strip along one side of `seg`.
    fn place_parked(&mut self, rng: &mut Rng, seg: &RoadSeg, si: usize, side: f64) {
        let mut s = rng.range(8.0, 14.0);
        while s < seg.len - 8.0 {
            let l = side * (seg.hw - 1.25);
            let p = seg.point(s, l);
            if rng.chance(0.4) && self.clear_of_other_roads(p, si, 9.0) {
                let kind = if rng.chance(0.08) {
                    ActorKind::Truck
                } else {
                    ActorKind::Car
                };
                let yaw = seg.yaw()
                    + if side > 0.0 {
                        std::f64::consts::PI
                    } else {
                        0.0
                    };
                let size = vehicle_size(rng, kind);
                self.actors.push(Actor {
                    kind,
                    motion: Motion::Parked { pos: p, yaw },
                    size,
                    rgb: *rng.pick(&CAR_COLOURS),
                    clothes2: [0.0; 3],
                });
                s += size.x + rng.range(1.0, 3.0);
            } else {
                s += rng.range(5.0, 8.0);
            }
        }
    }

    /// Pedestrians on the sidewalk along one side of `seg`.
    fn place_pedestrians(&mut self, rng: &mut Rng, seg: &RoadSeg, si: usize, side: f64) {
        let n_ped = (seg.len / 30.0 * rng.range(0.3, 1.3)) as usize;
        for _ in 0..n_ped {
            let l = side * (seg.hw + rng.range(1.0, seg.sw - 0.6));
            let v = if rng.chance(0.2) {
                0.0
            } else {
                rng.range(1.0, 1.7) * if rng.chance(0.5) { 1.0 } else { -1.0 }
            };
            let s0 = rng.range(5.0, seg.len - 5.0);
            let h = rng.range(1.55, 1.95);
            let motion = if v == 0.0 {
                let p = seg.point(s0, l);
                if !self.clear_of_other_roads(p, si, 1.0) {
                    continue;
                }
                Motion::Parked {
                    pos: p,
                    yaw: seg.yaw() + rng.range(-3.0, 3.0),
                }
            } else {
                Motion::Lane {
                    seg: si,
                    l,
                    s0,
                    v,
                    s_min: 5.0,
                    s_max: seg.len - 5.0,
                }
            };
            self.actors.push(Actor {
                kind: ActorKind::Pedestrian,
                motion,
                size: DVec3::new(0.55, 0.65, h),
                rgb: *rng.pick(&[
                    [0.10, 0.12, 0.20],
                    [0.55, 0.10, 0.10],
                    [0.85, 0.82, 0.75],
                    [0.20, 0.35, 0.55],
                    [0.15, 0.15, 0.15],
                    [0.80, 0.60, 0.20],
                ]),
                clothes2: *rng.pick(&[[0.15, 0.15, 0.30], [0.20, 0.20, 0.20], [0.45, 0.40, 0.35]]),
            });
        }
    }

    /// Moving traffic: oncoming lane on every road, own direction on non-ego roads.
    fn place_traffic(
        &mut self,
        rng: &mut Rng,
        seg: &RoadSeg,
        si: usize,
        legs: &[(DVec2, DVec2, f64)],
    ) {
        let is_ego_leg = legs
            .iter()
            .any(|&(_, d, _)| d.dot(seg.dir) > 0.999 && self.on_leg_line(seg, legs));
        for dir_sign in [1.0f64, -1.0] {
            if dir_sign > 0.0 && is_ego_leg {
                continue;
            }
            let n = (seg.len / 45.0 * rng.range(0.4, 1.2)).round() as usize;
            for _ in 0..n {
                let kind = if rng.chance(0.06) {
                    ActorKind::Bus
                } else if rng.chance(0.08) {
                    ActorKind::Truck
                } else {
                    ActorKind::Car
                };
                let v = dir_sign * rng.range(6.0, 13.0);
                self.actors.push(Actor {
                    kind,
                    motion: Motion::Lane {
                        seg: si,
                        l: dir_sign * EGO_LANE_L,
                        s0: rng.range(0.0, seg.len),
                        v,
                        s_min: 0.0,
                        s_max: seg.len,
                    },
                    size: vehicle_size(rng, kind),
                    rgb: *rng.pick(&CAR_COLOURS),
                    clothes2: [0.0; 3],
                });
            }
        }
    }

    /// A vehicle ahead of the ego in its lane.
    fn place_lead(&mut self, rng: &mut Rng) {
        if rng.chance(0.7) {
            let kind = if rng.chance(0.15) {
                ActorKind::Truck
            } else {
                ActorKind::Car
            };
            self.actors.push(Actor {
                kind,
                motion: Motion::Lead {
                    gap: rng.range(14.0, 30.0),
                    amp: rng.range(2.0, 6.0),
                    w: rng.range(0.2, 0.5),
                    phase: rng.range(0.0, std::f64::consts::TAU),
                },
                size: vehicle_size(rng, kind),
                rgb: *rng.pick(&CAR_COLOURS),
                clothes2: [0.0; 3],
            });
        }
    }

    fn on_leg_line(&self, seg: &RoadSeg, legs: &[(DVec2, DVec2, f64)]) -> bool {
        legs.iter().any(|&(a, d, _)| {
            d.dot(seg.dir) > 0.999 && {
                let (_, l) = seg.local(a);
                l.abs() < 0.5
            }
        })
    }

    /// True when a building footprint stays off every road and sidewalk.
    fn footprint_clear(&self, c: DVec2, dir: DVec2, w: f64, depth: f64) -> bool {
        let n = dir.perp();
        for fx in [-0.5, -0.25, 0.0, 0.25, 0.5] {
            for fy in [-0.5, 0.0, 0.5] {
                let p = c + dir * (fx * w) + n * (fy * depth);
                if self.ground_kind(p) != Ground::Verge {
                    return false;
                }
            }
        }
        true
    }

    /// True when `p` is at least `margin` beyond the sidewalks of every road but `own`.
    fn clear_of_other_roads(&self, p: DVec2, own: usize, margin: f64) -> bool {
        self.segs.iter().enumerate().all(|(i, s)| {
            if i == own {
                return true;
            }
            let (ss, l) = s.local(p);
            !(ss > -margin && ss < s.len + margin && l.abs() < s.hw + s.sw + margin)
        })
    }

    /// Ground kind at a point (z ignored); kerb faces are resolved by [`World::ground_hit`].
    pub fn ground_kind(&self, p: DVec2) -> Ground {
        let mut roads = 0;
        let mut road_local = (0usize, 0.0, 0.0);
        let mut sidewalk = 0;
        let mut sidewalk_of: usize = usize::MAX;
        for (i, seg) in self.segs.iter().enumerate() {
            let (s, l) = seg.local(p);
            if s < 0.0 || s > seg.len {
                continue;
            }
            let al = l.abs();
            if al < seg.hw {
                roads += 1;
                road_local = (i, s, l);
            } else if al < seg.hw + seg.sw {
                sidewalk += 1;
                sidewalk_of = i;
            }
        }
        if roads == 0 {
            return if sidewalk > 0 {
                Ground::Sidewalk
            } else {
                Ground::Verge
            };
        }
        if roads > 1 {
            return Ground::Road;
        }
        let (i, s, l) = road_local;
        if sidewalk > 0 {
            // Where another road's sidewalk continues across this road: a crosswalk.
            if sidewalk_of != i {
                let seg = &self.segs[i];
                let lw = l + seg.hw;
                let (_, lo) = self.segs[sidewalk_of].local(p);
                let edge = (lo.abs() - self.segs[sidewalk_of].hw).min(seg.sw);
                if lw.rem_euclid(1.2) < 0.6 && edge > 0.6 && edge < seg.sw - 0.6 {
                    return Ground::Marking;
                }
            }
            return Ground::Road;
        }
        let al = l.abs();
        // Centre line: dashed; lane / parking strip line: solid.
        if (al < 0.08 && s.rem_euclid(9.0) < 4.0) || (al - LANE_W).abs() < 0.07 {
            return Ground::Marking;
        }
        Ground::Road
    }

    /// Ray against the ground height field (road z = 0, sidewalks z = KERB_H, kerb faces).
    /// Returns (t, normal, kind).
    pub fn ground_hit(&self, o: DVec3, d: DVec3, t_max: f64) -> Option<(f64, DVec3, Ground)> {
        if d.z >= -1e-9 {
            return None;
        }
        if o.z > KERB_H {
            let t1 = (KERB_H - o.z) / d.z;
            if t1 > t_max {
                return None;
            }
            let p1 = o + d * t1;
            if self.ground_kind(p1.truncate()) == Ground::Sidewalk {
                return Some((t1, DVec3::Z, Ground::Sidewalk));
            }
            let t0 = -o.z / d.z;
            if t0 > t_max {
                return None;
            }
            let p0 = o + d * t0;
            let k0 = self.ground_kind(p0.truncate());
            if k0 != Ground::Sidewalk {
                return Some((t0, DVec3::Z, k0));
            }
            // The ray enters a sidewalk through its kerb face: bisect for the face.
            let (mut a, mut b) = (t1, t0);
            for _ in 0..12 {
                let m = 0.5 * (a + b);
                if self.ground_kind((o + d * m).truncate()) == Ground::Sidewalk {
                    b = m;
                } else {
                    a = m;
                }
            }
            let n = DVec3::new(-d.x, -d.y, 0.0).normalize_or(DVec3::X);
            Some((b, n, Ground::Kerb))
        } else {
            let t0 = -o.z / d.z;
            if t0 > t_max {
                return None;
            }
            Some((t0, DVec3::Z, self.ground_kind((o + d * t0).truncate())))
        }
    }

    /// Ego pose at time t: position (z = 0) and yaw.
    pub fn ego_pose(&self, t: f64) -> (DVec3, DQuat) {
        let (p, yaw) = self.ego_path.at(self.ego.s_at(t));
        (DVec3::new(p.x, p.y, 0.0), DQuat::from_rotation_z(yaw))
    }

    /// Ego velocity (global, m/s) and yaw rate (rad/s) at time t.
    pub fn ego_motion(&self, t: f64) -> (DVec3, f64) {
        let h = 0.02;
        let (p0, q0) = self.ego_pose(t - h);
        let (p1, q1) = self.ego_pose(t + h);
        let y0 = q0.to_euler(glam::EulerRot::ZYX).0;
        let y1 = q1.to_euler(glam::EulerRot::ZYX).0;
        ((p1 - p0) / (2.0 * h), wrap_angle(y1 - y0) / (2.0 * h))
    }

    /// State of actor `i` at time t.
    pub fn actor_state(&self, i: usize, t: f64) -> ActorState {
        let a = &self.actors[i];
        match a.motion {
            Motion::Parked { pos, yaw } => ActorState {
                pos,
                yaw,
                vel: DVec2::ZERO,
            },
            Motion::Lane {
                seg,
                l,
                s0,
                v,
                s_min,
                s_max,
            } => {
                let sg = &self.segs[seg];
                let range = (s_max - s_min).max(1.0);
                let s = s_min + (s0 + v * t - s_min).rem_euclid(range);
                let yaw = sg.yaw() + if v < 0.0 { std::f64::consts::PI } else { 0.0 };
                ActorState {
                    pos: sg.point(s, l),
                    yaw,
                    vel: sg.dir * v,
                }
            }
            Motion::Lead { gap, amp, w, phase } => {
                let f = |t: f64| {
                    let s = self.ego.s_at(t) + gap + amp * (w * t + phase).sin();
                    self.ego_path.at(s)
                };
                let (p, yaw) = f(t);
                let (p0, _) = f(t - 0.02);
                let (p1, _) = f(t + 0.02);
                ActorState {
                    pos: p,
                    yaw,
                    vel: (p1 - p0) / 0.04,
                }
            }
        }
    }

    /// Primitives of actor `i` in state `st`.
    pub fn actor_prims(&self, i: usize, st: &ActorState, out: &mut Vec<Prim>) {
        let a = &self.actors[i];
        let frame = ActorFrame {
            pos: st.pos,
            fwd: DVec2::from_angle(st.yaw),
            yaw: st.yaw,
            obj: i as u32,
        };
        match a.kind {
            ActorKind::Car => car_prims(a, &frame, out),
            ActorKind::Truck | ActorKind::Bus => heavy_vehicle_prims(a, &frame, out),
            ActorKind::Pedestrian => pedestrian_prims(a, &frame, out),
        }
    }

    /// True when actor `i` in state `st` would overlap the ego vehicle at time t (traffic
    /// crossing the ego's path is not simulated): such an actor is left out of that frame.
    pub fn actor_hidden(&self, i: usize, st: &ActorState, t: f64) -> bool {
        if matches!(self.actors[i].motion, Motion::Lead { .. }) {
            return false;
        }
        let (ep, eq) = self.ego_pose(t);
        // The ego body (≈ 4.8 x 1.9 m) is centred ≈ 1.4 m ahead of the ego origin.
        let c = ep + eq * DVec3::new(1.4, 0.0, 0.0);
        (st.pos - c.truncate()).length() < self.actors[i].size.x / 2.0 + 3.2
    }

    /// All primitives whose bounds come within `radius` (xy) of `centre` at time t.
    pub fn snapshot(&self, t: f64, centre: DVec2, radius: f64) -> Vec<Prim> {
        let mut out: Vec<Prim> = self
            .statics
            .iter()
            .filter(|p| p.dist_xy(centre) < radius)
            .copied()
            .collect();
        let mut tmp = Vec::new();
        for i in 0..self.actors.len() {
            let st = self.actor_state(i, t);
            if (st.pos - centre).length() > radius + 15.0 || self.actor_hidden(i, &st, t) {
                continue;
            }
            tmp.clear();
            self.actor_prims(i, &st, &mut tmp);
            out.extend(tmp.iter().filter(|p| p.dist_xy(centre) < radius));
        }
        out
    }
}

fn vehicle_size(rng: &mut Rng, kind: ActorKind) -> DVec3 {
    match kind {
        ActorKind::Car => {
            let k = rng.below(4);
            match k {
                0 => DVec3::new(
                    rng.range(3.8, 4.3),
                    rng.range(1.65, 1.8),
                    rng.range(1.4, 1.55),
                ),
                1 => DVec3::new(
                    rng.range(4.4, 4.9),
                    rng.range(1.8, 1.9),
                    rng.range(1.45, 1.6),
                ),
                2 => DVec3::new(
                    rng.range(4.6, 5.0),
                    rng.range(1.9, 2.05),
                    rng.range(1.7, 1.9),
                ),
                _ => DVec3::new(
                    rng.range(5.0, 5.6),
                    rng.range(1.95, 2.1),
                    rng.range(2.0, 2.5),
                ),
            }
        }
        ActorKind::Truck => DVec3::new(
            rng.range(6.5, 9.5),
            rng.range(2.3, 2.55),
            rng.range(2.9, 3.6),
        ),
        ActorKind::Bus => DVec3::new(
            rng.range(10.5, 12.5),
            rng.range(2.5, 2.6),
            rng.range(3.0, 3.4),
        ),
        ActorKind::Pedestrian => DVec3::new(0.55, 0.65, 1.75),
    }
}

/// An actor's pose for placing its parts: position and heading, and its object id.
struct ActorFrame {
    pos: DVec2,
    /// Unit heading.
    fwd: DVec2,
    yaw: f64,
    obj: u32,
}

impl ActorFrame {
    /// Global point at `x` forward, `y` left of the actor's centre, at height `z` (m).
    fn at(&self, x: f64, y: f64, z: f64) -> DVec3 {
        let p = self.pos + self.fwd * x + self.fwd.perp() * y;
        DVec3::new(p.x, p.y, z)
    }
}

/// Wheel colour.
const WHEEL_RGB: [f32; 3] = [0.05, 0.05, 0.05];

/// A car: body, glasshouse and four wheels.
fn car_prims(a: &Actor, f: &ActorFrame, out: &mut Vec<Prim>) {
    let (l, w, h) = (a.size.x, a.size.y, a.size.z);
    let obj = f.obj;
    let dark = WHEEL_RGB;
    let body_top = 0.25 + 0.5 * (h - 0.25);
    out.push(Prim::oriented_box(
        f.at(0.0, 0.0, (0.25 + body_top) / 2.0),
        DVec3::new(l, w, body_top - 0.25),
        f.yaw,
        Surface::CarBody,
        a.rgb,
        obj,
    ));
    out.push(Prim::oriented_box(
        f.at(-0.06 * l, 0.0, (body_top + h) / 2.0),
        DVec3::new(0.55 * l, 0.88 * w, h - body_top),
        f.yaw,
        Surface::CarGlass,
        a.rgb,
        obj,
    ));
    for (sx, sy) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
        out.push(Prim::oriented_box(
            f.at(sx * 0.32 * l, sy * (w / 2.0 - 0.13), 0.31),
            DVec3::new(0.62, 0.24, 0.62),
            f.yaw,
            Surface::Wheel,
            dark,
            obj,
        ));
    }
}

/// A truck (cab and a light cargo box) or a bus (one body), on four large wheels.
fn heavy_vehicle_prims(a: &Actor, f: &ActorFrame, out: &mut Vec<Prim>) {
    let (l, w, h) = (a.size.x, a.size.y, a.size.z);
    let obj = f.obj;
    let dark = WHEEL_RGB;
    let (cab_l, cargo_rgb) = if a.kind == ActorKind::Truck {
        (2.3, [0.82, 0.82, 0.80])
    } else {
        (0.0, a.rgb)
    };
    if cab_l > 0.0 {
        out.push(Prim::oriented_box(
            f.at(l / 2.0 - cab_l / 2.0, 0.0, (0.5 + 0.8 * h) / 2.0),
            DVec3::new(cab_l, w, 0.8 * h - 0.5),
            f.yaw,
            Surface::CarBody,
            a.rgb,
            obj,
        ));
    }
    let cl = l - cab_l - if cab_l > 0.0 { 0.3 } else { 0.0 };
    out.push(Prim::oriented_box(
        f.at(-l / 2.0 + cl / 2.0, 0.0, (0.55 + h) / 2.0),
        DVec3::new(cl, w, h - 0.55),
        f.yaw,
        Surface::CarBody,
        cargo_rgb,
        obj,
    ));
    for sx in [0.36, -0.36] {
        for sy in [1.0, -1.0] {
            out.push(Prim::oriented_box(
                f.at(sx * l, sy * (w / 2.0 - 0.16), 0.5),
                DVec3::new(1.0, 0.3, 1.0),
                f.yaw,
                Surface::Wheel,
                dark,
                obj,
            ));
        }
    }
}

/// A pedestrian: legs, torso and head.
fn pedestrian_prims(a: &Actor, f: &ActorFrame, out: &mut Vec<Prim>) {
    let h = a.size.z;
    let obj = f.obj;
    let leg_h = 0.47 * h;
    out.push(Prim::oriented_box(
        f.at(0.0, 0.0, leg_h / 2.0),
        DVec3::new(0.25, 0.38, leg_h),
        f.yaw,
        Surface::Person,
        a.clothes2,
        obj,
    ));
    let torso_top = h - 0.25;
    out.push(Prim::oriented_box(
        f.at(0.0, 0.0, (leg_h + torso_top) / 2.0),
        DVec3::new(0.28, 0.5, torso_top - leg_h),
        f.yaw,
        Surface::Person,
        a.rgb,
        obj,
    ));
    out.push(Prim::new(
        Shape::Sphere {
            c: f.at(0.0, 0.0, h - 0.12),
            r: 0.12,
        },
        Surface::Skin,
        [0.62, 0.47, 0.38],
        obj,
    ));
}

/// Static prims of a world under construction and the last static object id given out.
struct StaticsBuf {
    prims: Vec<Prim>,
    obj: u32,
}

impl StaticsBuf {
    /// The id of the next static object.
    fn next_obj(&mut self) -> u32 {
        self.obj += 1;
        self.obj
    }
}

/// A building lot along a road: centre `sc` along the road, width `w` along it, `depth`
/// across, set back `setback` behind the sidewalk (m).
struct Lot {
    sc: f64,
    w: f64,
    depth: f64,
    setback: f64,
}

/// A low wall at the front of the lot (12 %) or a building centred at `c`.
fn building(rng: &mut Rng, seg: &RoadSeg, side: f64, lot: &Lot, c: DVec2, obj: u32) -> Prim {
    let Lot {
        sc,
        w,
        depth,
        setback,
    } = *lot;
    if rng.chance(0.12) {
        let h = rng.range(1.8, 3.0);
        let rgb = *rng.pick(&[[0.60, 0.58, 0.55], [0.50, 0.30, 0.24], [0.70, 0.70, 0.68]]);
        let wl = seg.point(sc, side * (seg.hw + seg.sw + setback + 0.15));
        Prim::oriented_box(
            DVec3::new(wl.x, wl.y, h / 2.0),
            DVec3::new(w, 0.3, h),
            seg.yaw(),
            Surface::Wall,
            rgb,
            obj,
        )
    } else {
        let h = if rng.chance(0.2) {
            rng.range(20.0, 45.0)
        } else {
            rng.range(5.0, 18.0)
        };
        let base = *rng.pick(&FACADES);
        let k = rng.range(0.85, 1.1) as f32;
        Prim::oriented_box(
            DVec3::new(c.x, c.y, h / 2.0),
            DVec3::new(w, depth, h),
            seg.yaw(),
            Surface::Facade,
            [base[0] * k, base[1] * k, base[2] * k],
            obj,
        )
    }
}

/// Radius of the ego's turns (m).
const R_TURN: f64 = 11.0;

/// Ego legs (start, direction, length) covering at least `need` metres: alternate left/right
/// 90° turns (a staircase never crosses itself).
fn ego_legs(rng: &mut Rng, origin: DVec2, rot: f64, need: f64) -> Vec<(DVec2, DVec2, f64)> {
    let mut legs: Vec<(DVec2, DVec2, f64)> = Vec::new();
    let mut p = origin;
    let mut heading = rot + (rng.below(4) as f64) * std::f64::consts::FRAC_PI_2;
    let mut total = 0.0;
    let mut turn_left = rng.chance(0.5);
    while total < need {
        // The first leg is long (the ego looks down it for most of a short scene): real
        // RADAR_FRONT kept points reach 47 m (median) and 91 m (p90), so the view ahead
        // must stay open well beyond 100 m.
        let len = if legs.is_empty() {
            rng.range(160.0, 260.0)
        } else {
            rng.range(70.0, 150.0)
        };
        let dir = DVec2::from_angle(heading);
        legs.push((p, dir, len));
        p += dir * len;
        total += len;
        heading += if turn_left { 1.0 } else { -1.0 } * std::f64::consts::FRAC_PI_2;
        turn_left = !turn_left;
    }
    legs
}

/// The roads: one along each ego leg (extended past its corners) and a crossing street in
/// the middle of some long legs.
fn road_segs(rng: &mut Rng, legs: &[(DVec2, DVec2, f64)]) -> Vec<RoadSeg> {
    let ext = ROAD_HW + SIDEWALK_W;
    let mut segs = Vec::new();
    for (i, &(a, dir, len)) in legs.iter().enumerate() {
        let (a0, l0) = if i == 0 {
            (a - dir * 60.0, len + 60.0)
        } else {
            (a - dir * 45.0, len + 45.0)
        };
        let l1 = if i + 1 == legs.len() { 150.0 } else { 45.0 };
        segs.push(RoadSeg {
            a: a0,
            dir,
            len: l0 + l1,
            hw: ROAD_HW,
            sw: SIDEWALK_W,
        });
        // A crossing street in the middle of long legs.
        if len > 100.0 && rng.chance(0.6) {
            let s = rng.range(40.0, len - 40.0);
            let c = a + dir * s;
            let n = dir.perp();
            segs.push(RoadSeg {
                a: c - n * 70.0,
                dir: n,
                len: 140.0,
                hw: ROAD_HW,
                sw: SIDEWALK_W,
            });
        }
    }
    let _ = ext;
    segs
}

/// Vertices of the ego path: the legs offset into the right lane, with filleted corners.
fn ego_path_pts(legs: &[(DVec2, DVec2, f64)]) -> Vec<DVec2> {
    let mut pts: Vec<DVec2> = Vec::new();
    let r_turn = R_TURN;
    let first = legs[0];
    let off = |dir: DVec2| -dir.perp() * (-EGO_LANE_L);
    pts.push(first.0 - first.1 * 40.0 + off(first.1));
    for i in 0..legs.len() {
        let (a, dir, len) = legs[i];
        let corner = a + dir * len;
        if i + 1 < legs.len() {
            let nd = legs[i + 1].1;
            // Offset lines intersect at corner + offsets of both legs (perpendicular legs).
            let oc = corner + off(dir) + off(nd);
            let t1 = oc - dir * r_turn;
            let t2 = oc + nd * r_turn;
            pts.push(t1);
            let turn_sign = dir.perp_dot(nd).signum();
            let centre = t1 + dir.perp() * (turn_sign * r_turn);
            let steps = 16;
            let a0 = (t1 - centre).to_angle();
            for k in 1..steps {
                let ang = a0 + turn_sign * std::f64::consts::FRAC_PI_2 * k as f64 / steps as f64;
                pts.push(centre + DVec2::from_angle(ang) * r_turn);
            }
            pts.push(t2);
        } else {
            pts.push(corner + dir * 140.0 + off(dir));
        }
    }
    pts
}

/// Arc lengths of the turn midpoints.
fn turn_midpoints(ego_path: &Path) -> Vec<f64> {
    let r_turn = R_TURN;
    let mut turn_s: Vec<f64> = Vec::new();
    for i in 1..ego_path.pts.len().saturating_sub(1) {
        let a = ego_path.pts[i] - ego_path.pts[i - 1];
        let b = ego_path.pts[i + 1] - ego_path.pts[i];
        if a.perp_dot(b).abs() > 1e-6 * a.length() * b.length()
            && (turn_s.is_empty() || ego_path.s[i] - turn_s[turn_s.len() - 1] > 5.0)
        {
            turn_s.push(ego_path.s[i] + r_turn * std::f64::consts::FRAC_PI_4 - 1.0);
        }
    }
    turn_s
}

/// Maybe (45 %) one stop (arc length, wait s): at the stop line before the first reachable
/// intersection, else mid-block.
fn plan_stops(
    rng: &mut Rng,
    turn_s: &[f64],
    s_start: f64,
    v_cruise: f64,
    duration: f64,
) -> Vec<(f64, f64)> {
    let r_turn = R_TURN;
    let mut stops: Vec<(f64, f64)> = Vec::new();
    if rng.chance(0.45) {
        // Wait at the stop line before the first reachable intersection, else mid-block.
        let reach = s_start + (v_cruise * duration * 0.7).max(20.0);
        let before_turn = turn_s.iter().map(|&ts| {
            ts - r_turn * std::f64::consts::FRAC_PI_4 + r_turn - ROAD_HW - SIDEWALK_W - 3.0
        });
        let s_stop = before_turn
            .into_iter()
            .find(|&s| s > s_start + 10.0 && s < reach)
            .unwrap_or_else(|| s_start + rng.range(15.0, (v_cruise * duration * 0.6).max(20.0)));
        stops.push((s_stop, rng.range(1.5, 4.0)));
    }
    stops
}

/// The ego's arc length every 10 ms: cruise, slow through turns, wait at the stops (and
/// maybe, 10 %, at the start).
fn drive(
    rng: &mut Rng,
    turn_s: &[f64],
    stops: &[(f64, f64)],
    s_start: f64,
    v_cruise: f64,
    duration: f64,
) -> EgoDrive {
    let start_stopped = rng.chance(0.1);
    let dt = 0.01;
    let n = (duration / dt).ceil() as usize + 3;
    let mut s_hist = Vec::with_capacity(n);
    let (mut s, mut v) = (s_start, if start_stopped { 0.0 } else { v_cruise });
    let mut hold = if start_stopped {
        rng.range(1.0, 3.0)
    } else {
        0.0
    };
    let mut stop_i = 0;
    for _ in 0..n {
        s_hist.push(s);
        if hold > 0.0 {
            hold -= dt;
            v = 0.0;
            continue;
        }
        let mut target = v_cruise;
        for &ts in turn_s {
            target = target.min((16.0 + 2.0 * 1.6 * (s - ts).abs()).sqrt());
        }
        if stop_i < stops.len() {
            let (ss, hs) = stops[stop_i];
            let dist = ss - s;
            if dist <= 0.05 {
                hold = hs;
                stop_i += 1;
                v = 0.0;
                continue;
            }
            target = target.min((2.0 * 2.0 * dist).sqrt());
        }
        let dv = (target - v).clamp(-3.0 * dt, 1.5 * dt);
        v = (v + dv).max(0.0);
        s += v * dt;
    }
    EgoDrive { dt, s: s_hist }
}

fn dist_to_path(path: &Path, p: DVec2) -> f64 {
    let mut best = f64::INFINITY;
    for w in path.pts.windows(2) {
        let ab = w[1] - w[0];
        let t = ((p - w[0]).dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
        best = best.min((w[0] + ab * t - p).length());
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn world_is_deterministic_and_ego_stays_on_road() {
        let a = World::build(5, 1, Weather::Day, 12.0);
        let b = World::build(5, 1, Weather::Day, 12.0);
        assert_eq!(a.statics.len(), b.statics.len());
        assert_eq!(a.actors.len(), b.actors.len());
        assert_eq!(a.description, b.description);
        assert!(!a.statics.is_empty() && !a.actors.is_empty());
        let mut moved = 0.0;
        let mut last = a.ego_pose(0.0).0;
        for k in 0..=120 {
            let t = k as f64 * 0.1;
            let (p, _) = a.ego_pose(t);
            assert!(a.ground_kind(p.truncate()) != Ground::Sidewalk, "t={t}");
            assert!(matches!(
                a.ground_kind(p.truncate()),
                Ground::Road | Ground::Marking
            ));
            moved += (p - last).length();
            last = p;
            let (v, _) = a.ego_motion(t);
            assert!(v.length() < 14.0, "speed {}", v.length());
        }
        assert!(moved > 20.0, "ego moved {moved} m");
        // No building stands on a road.
        for p in &a.statics {
            if p.surface == Surface::Facade {
                let c = (p.lo + p.hi) * 0.5;
                assert_eq!(a.ground_kind(c.truncate()), Ground::Verge);
            }
        }
    }

    #[test]
    fn night_and_rain_descriptions() {
        let n = World::build(1, 0, Weather::Night, 5.0);
        assert!(n.description.starts_with("Night, "), "{}", n.description);
        let r = World::build(1, 0, Weather::Rain, 5.0);
        assert!(r.description.starts_with("Rain, "), "{}", r.description);
        let d = World::build(1, 0, Weather::Day, 5.0);
        let dl = d.description.to_lowercase();
        assert!(
            !dl.contains("night") && !dl.contains("rain"),
            "{}",
            d.description
        );
    }
}
