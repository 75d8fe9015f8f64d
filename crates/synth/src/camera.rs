//! CAM_FRONT: a per-pixel ray caster with screen-space culling (each primitive is only tested
//! for the pixels inside its projected bounds), shaded for day, night and rain.
//! Also yields the exact z-depth of every pixel (the truth map).

use glam::{DMat3, DVec2, DVec3};

use crate::calib::{self, CAM_CX, CAM_CY, CAM_FX, CAM_FY, IMG_H, IMG_W};
use crate::geom::{Prim, Surface};
use crate::rng::{lattice, Rng};
use crate::world::{Ground, World, STATIC_OBJ_BASE};
use crate::Weather;

/// Depths beyond this are "no data" in the truth map (the 16-bit PNG saturates at 256 m).
pub const MAX_TRUTH_M: f64 = 250.0;
const FAR: f64 = 600.0;

/// A rendered camera frame.
pub struct CamFrame {
    /// RGB8, row-major, IMG_W × IMG_H.
    pub rgb: Vec<u8>,
    /// z-depth in metres (0 = sky / beyond [`MAX_TRUTH_M`]).
    pub depth_m: Vec<f32>,
}

/// The pixel grid rays are cast on: the full IMG_W × IMG_H image (`scale` 1), or a coarser
/// grid whose cells are `scale` × `scale` pixels, one ray through each cell's centre.
#[derive(Clone, Copy)]
struct Grid {
    w: usize,
    h: usize,
    scale: f64,
}

impl Grid {
    fn new(scale: u32) -> Grid {
        let s = scale.max(1);
        Grid {
            w: (IMG_W / s) as usize,
            h: (IMG_H / s) as usize,
            scale: s as f64,
        }
    }
}

/// Camera pose in the global frame: origin and rotation global_from_camera.
pub struct CamPose {
    pub origin: DVec3,
    pub rot: DMat3,
}

pub fn camera_pose(world: &World, t: f64) -> CamPose {
    let m = calib::cam_front();
    let (ep, eq) = world.ego_pose(t);
    CamPose {
        origin: ep + eq * m.translation(),
        rot: DMat3::from_quat(eq * m.rotation()),
    }
}

/// Un-normalised ray direction of pixel centre (u + 0.5, v + 0.5) in the camera frame:
/// its z is 1, so the ray parameter is the z-depth.
#[inline]
fn cam_dir(u: f64, v: f64) -> DVec3 {
    DVec3::new((u - CAM_CX) / CAM_FX, (v - CAM_CY) / CAM_FY, 1.0)
}

#[derive(Clone, Copy, PartialEq)]
enum Hit {
    Sky,
    Ground(Ground),
    Prim(u32),
}

struct Light {
    sun: DVec3,
    ambient: f64,
    direct: f64,
    haze_m: f64,
    sky_top: [f64; 3],
    sky_hor: [f64; 3],
}

fn light_of(weather: Weather, rng: &mut Rng) -> Light {
    let az = rng.range(0.0, std::f64::consts::TAU);
    let el = rng.range(0.5, 1.1);
    let sun = DVec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
    match weather {
        Weather::Day => Light {
            sun,
            ambient: 0.42,
            direct: 0.85,
            haze_m: 700.0,
            sky_top: [0.18, 0.36, 0.75],
            sky_hor: [0.70, 0.80, 0.92],
        },
        Weather::Rain => Light {
            sun,
            ambient: 0.40,
            direct: 0.12,
            haze_m: 160.0,
            sky_top: [0.30, 0.32, 0.35],
            sky_hor: [0.52, 0.54, 0.56],
        },
        Weather::Night => Light {
            sun,
            ambient: 0.012,
            direct: 0.0,
            haze_m: 400.0,
            sky_top: [0.004, 0.006, 0.015],
            sky_hor: [0.022, 0.018, 0.02],
        },
    }
}

/// The camera at one time: origin, rotation global_from_camera (and its columns),
/// camera_from_global, and the grid its rays are cast on.
struct View {
    o: DVec3,
    cx: DVec3,
    cy: DVec3,
    cz: DVec3,
    rt: DMat3,
    grid: Grid,
}

impl View {
    /// Global, un-normalised ray direction of grid cell (u, v) (a pixel at scale 1): its
    /// parameter is the z-depth.
    fn dir_at(&self, u: usize, v: usize) -> DVec3 {
        let s = self.grid.scale;
        let c = cam_dir((u as f64 + 0.5) * s, (v as f64 + 0.5) * s);
        self.cx * c.x + self.cy * c.y + self.cz * c.z
    }
}

/// Per pixel: nearest ray parameter (the z-depth), what was hit, and the ground normal.
struct Raster {
    best_t: Vec<f64>,
    hit: Vec<Hit>,
    normals: Vec<DVec3>,
}

/// What lights a frame besides the sky: the ego's headlight and the street lamps nearby.
struct Lights<'a> {
    light: &'a Light,
    night: bool,
    rain: bool,
    headlight: DVec3,
    fwd: DVec3,
    lamps: Vec<DVec3>,
}

/// Render CAM_FRONT at time `t` (s since scene start). `salt` seeds per-frame noise.
pub fn render(world: &World, t: f64, salt: u64) -> CamFrame {
    render_scaled(world, t, salt, 1)
}

/// The lights of the frame at time `t` (s) seen from the camera at `o`: the weather's, the
/// ego's headlight (3.8 m ahead, 0.7 m up) and the street lamps within 160 m.
fn lights_at<'a>(world: &World, t: f64, light: &'a Light, o: DVec3) -> Lights<'a> {
    let (ego_p, ego_q) = world.ego_pose(t);
    let fwd = ego_q * DVec3::X;
    Lights {
        light,
        night: world.weather == Weather::Night,
        rain: world.weather == Weather::Rain,
        headlight: ego_p + fwd * 3.8 + DVec3::new(0.0, 0.0, 0.7),
        fwd,
        lamps: world
            .lamps
            .iter()
            .copied()
            .filter(|l| (l.truncate() - o.truncate()).length() < 160.0)
            .collect(),
    }
}

/// [`render`] with one ray per `scale` × `scale` pixels (`synth --camera-scale`): each ray's
/// colour and depth fill its cell, so the image is still IMG_W × IMG_H and the 2×2 average of
/// the training frame (SPEC §3) is, at scale 2, the coarse render itself. Scale 1 is [`render`]
/// exactly.
pub fn render_scaled(world: &World, t: f64, salt: u64, scale: u32) -> CamFrame {
    let grid = Grid::new(scale);
    let pose = camera_pose(world, t);
    let o = pose.origin;
    let r = pose.rot;
    let mut rng = Rng::stream(salt, &[0xCA]);
    let mut light_rng = Rng::stream(world.scene_idx as u64, &[0x5C, 0x11]);
    let light = light_of(world.weather, &mut light_rng);
    let prims = world.snapshot(t, o.truncate(), MAX_TRUTH_M + 20.0);
    let rt = r.transpose();
    let view = View {
        o,
        cx: r.x_axis,
        cy: r.y_axis,
        cz: r.z_axis,
        rt,
        grid,
    };

    // Pass 1: ground for every pixel.
    let mut raster = ground_pass(world, &view);
    // Pass 2: primitives inside their projected bounds, nearest first, skipping pixels where
    // something nearer than the primitive's nearest possible depth was already found.
    let boxes = screen_boxes(&view, &prims);
    prim_pass(&view, &prims, &boxes, &mut raster);
    // Shading.
    let lights = lights_at(world, t, &light, o);
    let (mut lin, depth) = shade_pixels(world, &view, &prims, &raster, &lights);

    // Rain: wet-road reflections (mirror about the horizon row) and streaks.
    if lights.rain {
        rain_reflections(&view, &raster.hit, &mut lin);
        rain_streaks(&mut rng, &mut lin, grid);
        lower_contrast(&mut lin);
    }

    let rgb = tone_map(&lin, lights.night, &mut rng);
    if grid.scale == 1.0 {
        return CamFrame {
            rgb,
            depth_m: depth,
        };
    }
    CamFrame {
        rgb: upscale(&rgb, grid, 3),
        depth_m: upscale(&depth, grid, 1),
    }
}

/// A grid's values (`channels` per cell) repeated over each cell's pixels: IMG_W × IMG_H.
fn upscale<T: Copy + Default>(cells: &[T], grid: Grid, channels: usize) -> Vec<T> {
    let (w, h) = (IMG_W as usize, IMG_H as usize);
    let s = grid.scale as usize;
    let mut out = vec![T::default(); w * h * channels];
    for y in 0..h {
        let gy = (y / s).min(grid.h - 1);
        for x in 0..w {
            let gx = (x / s).min(grid.w - 1);
            let (o, c) = ((y * w + x) * channels, (gy * grid.w + gx) * channels);
            out[o..o + channels].copy_from_slice(&cells[c..c + channels]);
        }
    }
    out
}

/// Pass 1: the ground for every pixel.
fn ground_pass(world: &World, view: &View) -> Raster {
    let (w, h) = (view.grid.w, view.grid.h);
    let n = w * h;
    let mut best_t = vec![f64::INFINITY; n];
    let mut hit = vec![Hit::Sky; n];
    let mut normals = vec![DVec3::Z; n];
    for v in 0..h {
        for u in 0..w {
            let d = view.dir_at(u, v);
            if let Some((tg, nrm, kind)) = world.ground_hit(view.o, d, FAR) {
                let i = v * w + u;
                best_t[i] = tg;
                hit[i] = Hit::Ground(kind);
                normals[i] = nrm;
            }
        }
    }
    Raster {
        best_t,
        hit,
        normals,
    }
}

/// A primitive's nearest possible depth, its index and its pixel bounds [u0, u1) × [v0, v1).
type ScreenBox = (f64, usize, usize, usize, usize, usize);

/// The screen boxes of the primitives in view, nearest first (ties by index).
fn screen_boxes(view: &View, prims: &[Prim]) -> Vec<ScreenBox> {
    let mut boxes: Vec<ScreenBox> = Vec::with_capacity(prims.len());
    for (pi, p) in prims.iter().enumerate() {
        if let Some(b) = screen_box(view, pi, p) {
            boxes.push(b);
        }
    }
    boxes.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    boxes
}

/// The screen bounds of primitive `pi` (the whole image when it reaches behind the camera),
/// or None when it is wholly behind or off screen.
fn screen_box(view: &View, pi: usize, p: &Prim) -> Option<ScreenBox> {
    let (w, h) = (view.grid.w, view.grid.h);
    let s = view.grid.scale;
    let mut umin = f64::INFINITY;
    let mut umax = f64::NEG_INFINITY;
    let mut vmin = f64::INFINITY;
    let mut vmax = f64::NEG_INFINITY;
    let mut zmin = f64::INFINITY;
    let mut behind = 0;
    for c in p.hull_corners() {
        let q = view.rt * (c - view.o);
        zmin = zmin.min(q.z);
        if q.z < 0.05 {
            behind += 1;
            continue;
        }
        let u = (CAM_FX * q.x / q.z + CAM_CX) / s;
        let v = (CAM_FY * q.y / q.z + CAM_CY) / s;
        umin = umin.min(u);
        umax = umax.max(u);
        vmin = vmin.min(v);
        vmax = vmax.max(v);
    }
    if behind == 8 {
        return None;
    }
    // The box's corners bound its depth from below only when it is wholly in front.
    let znear = if behind > 0 { 0.0 } else { zmin.max(0.0) };
    let (u0, u1, v0, v1) = if behind > 0 {
        (0, w, 0, h)
    } else {
        if umax < 0.0 || vmax < 0.0 || umin > w as f64 || vmin > h as f64 {
            return None;
        }
        (
            (umin.floor().max(0.0)) as usize,
            ((umax.ceil() + 1.0).min(w as f64)) as usize,
            (vmin.floor().max(0.0)) as usize,
            ((vmax.ceil() + 1.0).min(h as f64)) as usize,
        )
    };
    Some((znear, pi, u0, u1, v0, v1))
}

/// Pass 2: intersect each primitive inside its screen box (boxes sorted nearest first).
fn prim_pass(view: &View, prims: &[Prim], boxes: &[ScreenBox], raster: &mut Raster) {
    let w = view.grid.w;
    for &(znear, pi, u0, u1, v0, v1) in boxes {
        let p = &prims[pi];
        for v in v0..v1 {
            for u in u0..u1 {
                let i = v * w + u;
                if znear >= raster.best_t[i] {
                    continue;
                }
                let d = view.dir_at(u, v);
                if let Some(tp) = p.intersect(view.o, d, 0.05, raster.best_t[i]) {
                    raster.best_t[i] = tp;
                    raster.hit[i] = Hit::Prim(pi as u32);
                }
            }
        }
    }
}

/// Linear colour (with haze) and truth depth of every pixel.
fn shade_pixels(
    world: &World,
    view: &View,
    prims: &[Prim],
    raster: &Raster,
    lights: &Lights,
) -> (Vec<[f32; 3]>, Vec<f32>) {
    let (w, h) = (view.grid.w, view.grid.h);
    let n = w * h;
    let light = lights.light;
    let mut lin = vec![[0f32; 3]; n];
    let mut depth = vec![0f32; n];
    for v in 0..h {
        for u in 0..w {
            let i = v * w + u;
            let d = view.dir_at(u, v);
            let (col, tt) = shade_hit(world, view, prims, raster, lights, i, d);
            let fog = if tt.is_finite() {
                1.0 - (-tt / light.haze_m).exp()
            } else {
                0.0
            };
            let mut c = [0f32; 3];
            for k in 0..3 {
                c[k] = (col[k] * (1.0 - fog) + light.sky_hor[k] * fog) as f32;
            }
            lin[i] = c;
            if tt.is_finite() && tt <= MAX_TRUTH_M {
                depth[i] = tt as f32;
            }
        }
    }
    (lin, depth)
}

/// Colour (before haze) and depth of pixel `i`, whose ray direction is `d`.
fn shade_hit(
    world: &World,
    view: &View,
    prims: &[Prim],
    raster: &Raster,
    lights: &Lights,
    i: usize,
    d: DVec3,
) -> ([f64; 3], f64) {
    let Lights {
        light,
        night,
        rain,
        headlight,
        fwd,
        ..
    } = *lights;
    let lamps = &lights.lamps;
    let o = view.o;
    let dn = d.normalize();
    match raster.hit[i] {
        Hit::Sky => (sky_colour(light, dn), f64::INFINITY),
        Hit::Ground(kind) => {
            let tg = raster.best_t[i];
            let p = o + d * tg;
            let (albedo, gloss) = ground_albedo(world, kind, p);
            let nrm = raster.normals[i];
            let c = shade(light, night, albedo, nrm, p, dn, headlight, fwd, lamps);
            let c = add_spec(c, gloss, light, nrm, dn, rain);
            (c, tg)
        }
        Hit::Prim(pi) => {
            let prim = &prims[pi as usize];
            let tp = raster.best_t[i];
            let p = o + d * tp;
            let nrm = prim.normal(p);
            let (albedo, emit) = prim_albedo(prim, p, nrm, night);
            let mut c = shade(light, night, albedo, nrm, p, dn, headlight, fwd, lamps);
            for k in 0..3 {
                c[k] += emit[k];
            }
            (c, tp)
        }
    }
}

/// Rain: wet-road reflections (mirror about the horizon row).
fn rain_reflections(view: &View, hit: &[Hit], lin: &mut [[f32; 3]]) {
    let (w, h) = (view.grid.w, view.grid.h);
    let s = view.grid.scale;
    let (cx, cy, cz) = (view.cx, view.cy, view.cz);
    let src = lin.to_vec();
    for v in 0..h {
        for u in 0..w {
            let i = v * w + u;
            if let Hit::Ground(Ground::Road | Ground::Marking) = hit[i] {
                // Horizon row in this column: d.z = 0.
                let xu = ((u as f64 + 0.5) * s - CAM_CX) / CAM_FX;
                let yv = -(cx.z * xu + cz.z) / cy.z;
                let vh = (yv * CAM_FY + CAM_CY) / s;
                let vm = (2.0 * vh - v as f64).round();
                if vm >= 0.0 && (vm as usize) < h {
                    let j = vm as usize * w + u;
                    let f = 0.32 + 0.1 * lattice(u as i64 / 3, v as i64 / 2, 0, 7) as f64;
                    for k in 0..3 {
                        lin[i][k] = (lin[i][k] as f64 * (1.0 - f) + src[j][k] as f64 * f) as f32;
                    }
                }
            }
        }
    }
}

/// Rain: 900 light streaks (their lengths in grid cells).
fn rain_streaks(rng: &mut Rng, lin: &mut [[f32; 3]], grid: Grid) {
    let (w, h) = (grid.w, grid.h);
    for _ in 0..900 {
        let x0 = rng.range(0.0, w as f64);
        let y0 = rng.range(0.0, h as f64);
        let len = rng.range(15.0, 60.0) / grid.scale;
        let slant = rng.range(0.12, 0.22);
        let a = rng.range(0.05, 0.14) as f32;
        let steps = len as usize;
        for s in 0..steps {
            let x = (x0 + slant * s as f64) as usize;
            let y = (y0 + s as f64) as usize;
            if x < w && y < h {
                let c = &mut lin[y * w + x];
                for ch in c.iter_mut() {
                    *ch = *ch * (1.0 - a) + 0.8 * a;
                }
            }
        }
    }
}

/// Rain: lower contrast.
fn lower_contrast(lin: &mut [[f32; 3]]) {
    for c in lin.iter_mut() {
        let m = (c[0] + c[1] + c[2]) / 3.0;
        for ch in c.iter_mut() {
            *ch = 0.75 * *ch + 0.25 * m * 0.9 + 0.02;
        }
    }
}

/// Tone map, sensor noise, 8-bit sRGB.
fn tone_map(lin: &[[f32; 3]], night: bool, rng: &mut Rng) -> Vec<u8> {
    let gain: f32 = if night { 2.2 } else { 1.0 };
    let noise_amp: f32 = if night { 0.035 } else { 0.008 };
    let lut = srgb_lut();
    let mut rgb = vec![0u8; lin.len() * 3];
    let fsalt = rng.next_u64();
    for (i, c) in lin.iter().enumerate() {
        let nz = (lattice(i as i64, 0, 0, fsalt) - 0.5) * 2.0 * noise_amp;
        for k in 0..3 {
            let x = (c[k] * gain).max(0.0);
            // Soft shoulder above 1.
            let x = if x > 0.8 {
                0.8 + (x - 0.8) / (1.0 + (x - 0.8) * 2.0)
            } else {
                x
            };
            let x = (x + nz).clamp(0.0, 1.0);
            rgb[i * 3 + k] = lut[(x * 4095.0) as usize];
        }
    }
    rgb
}

fn srgb_lut() -> Vec<u8> {
    (0..4096)
        .map(|i| {
            let x = i as f64 / 4095.0;
            let s = if x <= 0.003_130_8 {
                12.92 * x
            } else {
                1.055 * x.powf(1.0 / 2.4) - 0.055
            };
            (s * 255.0).round().clamp(0.0, 255.0) as u8
        })
        .collect()
}

fn sky_colour(l: &Light, d: DVec3) -> [f64; 3] {
    let e = d.z.clamp(0.0, 1.0).powf(0.6);
    let mut c = [0.0; 3];
    for k in 0..3 {
        c[k] = l.sky_hor[k] * (1.0 - e) + l.sky_top[k] * e;
    }
    c
}

fn noise2(p: DVec2, scale: f64, salt: u64) -> f32 {
    let x = p.x / scale;
    let y = p.y / scale;
    let (xi, yi) = (x.floor(), y.floor());
    let (fx, fy) = ((x - xi) as f32, (y - yi) as f32);
    let (xi, yi) = (xi as i64, yi as i64);
    let a = lattice(xi, yi, 0, salt);
    let b = lattice(xi + 1, yi, 0, salt);
    let c = lattice(xi, yi + 1, 0, salt);
    let d = lattice(xi + 1, yi + 1, 0, salt);
    let sx = fx * fx * (3.0 - 2.0 * fx);
    let sy = fy * fy * (3.0 - 2.0 * fy);
    (a * (1.0 - sx) + b * sx) * (1.0 - sy) + (c * (1.0 - sx) + d * sx) * sy
}

/// (albedo, glossiness) of the ground.
fn ground_albedo(world: &World, kind: Ground, p: DVec3) -> ([f64; 3], f64) {
    let q = p.truncate();
    let n = 0.75
        + 0.35 * noise2(q, 1.7, 11) as f64
        + 0.15 * lattice((q.x * 12.0) as i64, (q.y * 12.0) as i64, 0, 3) as f64;
    let base = match kind {
        Ground::Road => {
            let a = world.asphalt_rgb;
            [a[0] as f64, a[1] as f64, a[2] as f64]
        }
        Ground::Marking => [0.85, 0.85, 0.82],
        Ground::Sidewalk => [0.55, 0.53, 0.50],
        Ground::Kerb => [0.65, 0.64, 0.62],
        Ground::Verge => {
            let a = world.verge_rgb;
            [a[0] as f64, a[1] as f64, a[2] as f64]
        }
    };
    // Sidewalk slabs.
    let slab = if kind == Ground::Sidewalk {
        let gx = (q.x * 0.8).rem_euclid(1.0);
        let gy = (q.y * 0.8).rem_euclid(1.0);
        if gx < 0.03 || gy < 0.03 {
            0.7
        } else {
            1.0
        }
    } else {
        1.0
    };
    let gloss = match kind {
        Ground::Road | Ground::Marking => 1.0,
        Ground::Sidewalk | Ground::Kerb => 0.4,
        Ground::Verge => 0.1,
    };
    (
        [base[0] * n * slab, base[1] * n * slab, base[2] * n * slab],
        gloss,
    )
}

/// (albedo, emitted light) of a primitive at `p`.
fn prim_albedo(prim: &Prim, p: DVec3, nrm: DVec3, night: bool) -> ([f64; 3], [f64; 3]) {
    let base = [prim.rgb[0] as f64, prim.rgb[1] as f64, prim.rgb[2] as f64];
    let loc = prim.local(p);
    let mut emit = [0.0; 3];
    let salt = prim.obj as u64;
    let albedo = match prim.surface {
        Surface::Facade => facade_albedo(prim, loc, nrm, base, night, &mut emit),
        Surface::CarBody => car_body_albedo(prim, loc, base, night, &mut emit),
        Surface::CarGlass => {
            if nrm.z > 0.5 {
                base
            } else {
                [0.05, 0.06, 0.08]
            }
        }
        Surface::LampHead => {
            if night {
                emit = [3.0, 2.6, 1.8];
            }
            base
        }
        Surface::Foliage => {
            let n = 0.6
                + 0.6
                    * lattice(
                        (p.x * 4.0) as i64,
                        (p.y * 4.0) as i64,
                        (p.z * 4.0) as i64,
                        salt,
                    ) as f64;
            [base[0] * n, base[1] * n, base[2] * n]
        }
        _ => {
            let n = 0.9 + 0.2 * noise2(DVec2::new(p.x + p.y, p.z), 0.5, salt) as f64;
            [base[0] * n, base[1] * n, base[2] * n]
        }
    };
    let _ = STATIC_OBJ_BASE;
    (albedo, emit)
}

/// Face-aligned coordinate of a facade point: along the face (−1 on the roof).
fn facade_along(prim: &Prim, loc: DVec3, nrm: DVec3) -> f64 {
    if nrm.z.abs() > 0.5 {
        -1.0
    } else {
        // Which local axis lies along the face: the one not parallel to the normal.
        let lx = match prim.shape {
            crate::geom::Shape::Box { cos, sin, .. } => (nrm.x * cos + nrm.y * sin).abs(),
            _ => 0.0,
        };
        if lx > 0.5 {
            loc.y
        } else {
            loc.x
        }
    }
}

/// Albedo of a facade at local point `loc`: noisy wall with shop windows on the ground floor
/// and windows above (some lit at night: their light goes to `emit`).
fn facade_albedo(
    prim: &Prim,
    loc: DVec3,
    nrm: DVec3,
    base: [f64; 3],
    night: bool,
    emit: &mut [f64; 3],
) -> [f64; 3] {
    let salt = prim.obj as u64;
    // Face-aligned coordinate: along the face and height.
    let along = facade_along(prim, loc, nrm);
    let z = loc.z;
    let n = 0.85 + 0.25 * noise2(DVec2::new(along, z), 0.9, salt) as f64;
    if along >= 0.0 && z > 0.6 {
        let (col, row) = if z < 3.6 {
            ((along / 5.0).floor(), -1.0)
        } else {
            ((along / 3.1).floor(), ((z - 3.6) / 3.3).floor())
        };
        let fa = if z < 3.6 {
            (along / 5.0).fract()
        } else {
            (along / 3.1).fract()
        };
        let fz = if z < 3.6 {
            (z - 0.6) / 3.0
        } else {
            ((z - 3.6) / 3.3).fract()
        };
        let is_win = if z < 3.6 {
            fa > 0.08 && fa < 0.92 && fz > 0.05 && fz < 0.85
        } else {
            fa > 0.22 && fa < 0.78 && fz > 0.3 && fz < 0.8
        };
        if is_win {
            let lit = lattice(col as i64, row as i64, 0, salt);
            if night && lit < 0.35 {
                let k = 0.25 + 0.3 * lit as f64;
                *emit = [k * 1.0, k * 0.78, k * 0.45];
            }
            let g = 0.08 + 0.06 * lit as f64;
            [g, g * 1.1, g * 1.3]
        } else {
            [base[0] * n, base[1] * n, base[2] * n]
        }
    } else {
        [base[0] * n, base[1] * n, base[2] * n]
    }
}

/// Albedo of a car body at local point `loc`: head / tail lamps (lit at night: their light
/// goes to `emit`), a dark sill, else the paint.
fn car_body_albedo(
    prim: &Prim,
    loc: DVec3,
    base: [f64; 3],
    night: bool,
    emit: &mut [f64; 3],
) -> [f64; 3] {
    let hx = match prim.shape {
        crate::geom::Shape::Box { h, .. } => h,
        _ => DVec3::ONE,
    };
    let front = loc.x > 2.0 * hx.x - 0.01;
    let rear = loc.x < 0.01;
    // Head / tail lamps: 0.45 m wide at the corners, 0.25–0.5 m above the body bottom.
    let side_lamp = (loc.y > 0.08 && loc.y < 0.53
        || loc.y > 2.0 * hx.y - 0.53 && loc.y < 2.0 * hx.y - 0.08)
        && loc.z > 0.25
        && loc.z < 0.5;
    if (front || rear) && side_lamp {
        if night {
            *emit = if front {
                [2.5, 2.4, 2.1]
            } else {
                [1.2, 0.08, 0.05]
            };
        }
        if front {
            [0.9, 0.9, 0.85]
        } else {
            [0.6, 0.05, 0.04]
        }
    } else if loc.z < 0.12 * 2.0 * hx.z {
        [base[0] * 0.3, base[1] * 0.3, base[2] * 0.3]
    } else {
        base
    }
}

#[allow(clippy::too_many_arguments)]
fn shade(
    l: &Light,
    night: bool,
    albedo: [f64; 3],
    nrm: DVec3,
    p: DVec3,
    view: DVec3,
    headlight: DVec3,
    fwd: DVec3,
    lamps: &[DVec3],
) -> [f64; 3] {
    let n = if nrm.dot(view) > 0.0 { -nrm } else { nrm };
    let sky_amb = 0.7 + 0.3 * n.z;
    let mut e = l.ambient * sky_amb + l.direct * n.dot(l.sun).max(0.0);
    let mut warm = 0.0;
    if night {
        // Ego headlights: a cone along the road ahead.
        let dl = p - headlight;
        let dist = dl.length().max(0.5);
        let dir = dl / dist;
        let c = dir.dot(fwd);
        if c > 0.85 {
            let cone = ((c - 0.85) / 0.1).min(1.0);
            let down = if dir.z > 0.05 { 0.3 } else { 1.0 };
            e += 140.0 * cone * down * (-dir).dot(n).max(0.0) / (dist * dist + 4.0);
        }
        for lp in lamps {
            let dl = *lp - p;
            let d2 = dl.length_squared();
            if d2 > 45.0 * 45.0 {
                continue;
            }
            let dir = dl / d2.sqrt();
            let down = (-dir.z).max(0.0);
            let k = 40.0 * (0.04 + 0.96 * down * down) * dir.dot(n).max(0.0) / (d2 + 2.0);
            warm += k;
        }
    }
    [
        albedo[0] * (e + warm * 1.0),
        albedo[1] * (e + warm * 0.82),
        albedo[2] * (e + warm * 0.55),
    ]
}

fn add_spec(c: [f64; 3], gloss: f64, l: &Light, n: DVec3, view: DVec3, rain: bool) -> [f64; 3] {
    if l.direct <= 0.0 && !rain {
        return c;
    }
    let refl = view - n * 2.0 * view.dot(n);
    let s = refl.dot(l.sun).max(0.0).powf(if rain { 8.0 } else { 40.0 });
    let k = gloss * s * if rain { 0.25 } else { 0.15 } * (l.direct + 0.3);
    [c[0] + k, c[1] + k, c[2] + k]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_coarse_render_fills_each_cell_and_scale_one_is_the_full_render() {
        let world = World::build(3, 0, Weather::Day, 4.0);
        let full = render(&world, 1.0, 9);
        assert!(full.rgb == render_scaled(&world, 1.0, 9, 1).rgb);
        let coarse = render_scaled(&world, 1.0, 9, 2);
        let (w, h) = (IMG_W as usize, IMG_H as usize);
        assert_eq!((coarse.rgb.len(), coarse.depth_m.len()), (w * h * 3, w * h));
        for y in (0..h).step_by(2) {
            for x in (0..w).step_by(2) {
                let px = |dx: usize, dy: usize| {
                    let i = (y + dy) * w + x + dx;
                    (&coarse.rgb[3 * i..3 * i + 3], coarse.depth_m[i].to_bits())
                };
                assert!(px(1, 0) == px(0, 0) && px(0, 1) == px(0, 0) && px(1, 1) == px(0, 0));
            }
        }
        // The same scene: mean depth of the valid pixels within 2 %.
        let mean = |d: &[f32]| {
            let v: Vec<f64> = d.iter().filter(|x| **x > 0.0).map(|x| *x as f64).collect();
            v.iter().sum::<f64>() / v.len() as f64
        };
        let (a, b) = (mean(&full.depth_m), mean(&coarse.depth_m));
        assert!((a - b).abs() < 0.02 * a, "{a} vs {b}");
    }

    #[test]
    fn pixel_ray_depth_is_camera_z() {
        // A pixel ray's parameter is the camera z-depth, and its projection is the pixel centre.
        let d = cam_dir(100.5, 700.5);
        let p = d * 23.0;
        assert!((p.z - 23.0).abs() < 1e-12);
        let u = CAM_FX * p.x / p.z + CAM_CX;
        let v = CAM_FY * p.y / p.z + CAM_CY;
        assert!((u - 100.5).abs() < 1e-9 && (v - 700.5).abs() < 1e-9);
    }
}
