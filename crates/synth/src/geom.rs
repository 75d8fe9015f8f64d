//! Analytic primitives of the world and exact ray intersections (global frame, z up).

use glam::{DVec2, DVec3};

/// Surface kinds, used for shading, lidar reflectivity and radar cross-section.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Surface {
    Facade,
    Wall,
    CarBody,
    CarGlass,
    Wheel,
    Person,
    Skin,
    Pole,
    LampHead,
    Bark,
    Foliage,
}

/// Shape of a primitive. Boxes rotate about z only (yaw).
#[derive(Debug, Clone, Copy)]
pub enum Shape {
    /// Oriented box: centre, half extents (along its local x, y, z), yaw as (cos, sin).
    Box {
        c: DVec3,
        h: DVec3,
        cos: f64,
        sin: f64,
    },
    /// Vertical cylinder with a top cap.
    Cyl {
        c: DVec2,
        r: f64,
        z0: f64,
        z1: f64,
    },
    Sphere {
        c: DVec3,
        r: f64,
    },
}

/// A coloured primitive belonging (optionally) to an object.
#[derive(Debug, Clone, Copy)]
pub struct Prim {
    pub shape: Shape,
    pub surface: Surface,
    pub rgb: [f32; 3],
    /// Object index in the world (actor or static object), `u32::MAX` for none.
    pub obj: u32,
    /// Axis-aligned bounds.
    pub lo: DVec3,
    pub hi: DVec3,
}

impl Prim {
    pub fn new(shape: Shape, surface: Surface, rgb: [f32; 3], obj: u32) -> Prim {
        let (lo, hi) = match shape {
            Shape::Box { c, h, cos, sin } => {
                let ex = (h.x * cos).abs() + (h.y * sin).abs();
                let ey = (h.x * sin).abs() + (h.y * cos).abs();
                let e = DVec3::new(ex, ey, h.z);
                (c - e, c + e)
            }
            Shape::Cyl { c, r, z0, z1 } => (
                DVec3::new(c.x - r, c.y - r, z0),
                DVec3::new(c.x + r, c.y + r, z1),
            ),
            Shape::Sphere { c, r } => (c - DVec3::splat(r), c + DVec3::splat(r)),
        };
        Prim {
            shape,
            surface,
            rgb,
            obj,
            lo,
            hi,
        }
    }

    /// An oriented box from centre, full size (length along heading, width, height) and yaw.
    pub fn oriented_box(
        c: DVec3,
        size_lwh: DVec3,
        yaw: f64,
        surface: Surface,
        rgb: [f32; 3],
        obj: u32,
    ) -> Prim {
        Prim::new(
            Shape::Box {
                c,
                h: size_lwh * 0.5,
                cos: yaw.cos(),
                sin: yaw.sin(),
            },
            surface,
            rgb,
            obj,
        )
    }

    /// Nearest hit distance `t` in (t_min, t_max) of the ray o + t·d, if any.
    #[inline]
    pub fn intersect(&self, o: DVec3, d: DVec3, t_min: f64, t_max: f64) -> Option<f64> {
        let ray = Ray { o, d, t_min, t_max };
        match self.shape {
            Shape::Box { c, h, cos, sin } => box_hit(c, h, cos, sin, &ray),
            Shape::Cyl { c, r, z0, z1 } => cyl_hit(c, r, z0, z1, &ray),
            Shape::Sphere { c, r } => sphere_hit(c, r, &ray),
        }
    }

    /// Outward unit normal at a surface point `p`.
    pub fn normal(&self, p: DVec3) -> DVec3 {
        match self.shape {
            Shape::Box { c, h, cos, sin } => {
                let q = p - c;
                let l = DVec3::new(cos * q.x + sin * q.y, -sin * q.x + cos * q.y, q.z);
                let r = (l / h).abs();
                if r.z >= r.x && r.z >= r.y {
                    DVec3::new(0.0, 0.0, l.z.signum())
                } else if r.x >= r.y {
                    let s = l.x.signum();
                    DVec3::new(s * cos, s * sin, 0.0)
                } else {
                    let s = l.y.signum();
                    DVec3::new(-s * sin, s * cos, 0.0)
                }
            }
            Shape::Cyl { c, z1, .. } => {
                if (p.z - z1).abs() < 1e-6 {
                    DVec3::Z
                } else {
                    DVec3::new(p.x - c.x, p.y - c.y, 0.0).normalize_or(DVec3::X)
                }
            }
            Shape::Sphere { c, .. } => (p - c).normalize_or(DVec3::Z),
        }
    }

    /// Local coordinates of `p` on a box (along, across, height above the box bottom); for
    /// other shapes (0, 0, z − bottom).
    pub fn local(&self, p: DVec3) -> DVec3 {
        match self.shape {
            Shape::Box { c, h, cos, sin } => {
                let q = p - c;
                DVec3::new(
                    cos * q.x + sin * q.y + h.x,
                    -sin * q.x + cos * q.y + h.y,
                    q.z + h.z,
                )
            }
            _ => DVec3::new(0.0, 0.0, p.z - self.lo.z),
        }
    }

    /// Distance from `p` (xy) to the primitive's bounds, for culling.
    pub fn dist_xy(&self, p: DVec2) -> f64 {
        let dx = (self.lo.x - p.x).max(p.x - self.hi.x).max(0.0);
        let dy = (self.lo.y - p.y).max(p.y - self.hi.y).max(0.0);
        (dx * dx + dy * dy).sqrt()
    }

    /// The 8 corners of the primitive's own box: an oriented box's corners (tighter than its
    /// axis-aligned bounds when it is turned), the bounds' corners for the other shapes. The
    /// primitive lies in their convex hull.
    pub fn hull_corners(&self) -> [DVec3; 8] {
        let Shape::Box { c, h, cos, sin } = self.shape else {
            return self.corners();
        };
        let mut out = [DVec3::ZERO; 8];
        for (i, o) in out.iter_mut().enumerate() {
            let sx = if i & 1 == 0 { -h.x } else { h.x };
            let sy = if i & 2 == 0 { -h.y } else { h.y };
            let sz = if i & 4 == 0 { -h.z } else { h.z };
            *o = c + DVec3::new(cos * sx - sin * sy, sin * sx + cos * sy, sz);
        }
        out
    }

    /// The 8 corners of the bounds.
    pub fn corners(&self) -> [DVec3; 8] {
        let (a, b) = (self.lo, self.hi);
        [
            DVec3::new(a.x, a.y, a.z),
            DVec3::new(b.x, a.y, a.z),
            DVec3::new(a.x, b.y, a.z),
            DVec3::new(b.x, b.y, a.z),
            DVec3::new(a.x, a.y, b.z),
            DVec3::new(b.x, a.y, b.z),
            DVec3::new(a.x, b.y, b.z),
            DVec3::new(b.x, b.y, b.z),
        ]
    }
}

/// A ray o + t·d and the open interval (t_min, t_max) of accepted hits.
#[derive(Clone, Copy)]
struct Ray {
    o: DVec3,
    d: DVec3,
    t_min: f64,
    t_max: f64,
}

/// Ray o + t·d against the box of centre `c`, half extents `h`, yaw (cos, sin): the entry
/// distance in (t_min, t_max), if any (slab test in the box frame).
#[inline]
fn box_hit(c: DVec3, h: DVec3, cos: f64, sin: f64, ray: &Ray) -> Option<f64> {
    let Ray { o, d, t_min, t_max } = *ray;
    let p = o - c;
    let lo = DVec3::new(cos * p.x + sin * p.y, -sin * p.x + cos * p.y, p.z);
    let ld = DVec3::new(cos * d.x + sin * d.y, -sin * d.x + cos * d.y, d.z);
    let inv = ld.recip();
    let t1 = (-h - lo) * inv;
    let t2 = (h - lo) * inv;
    let tn = t1.min(t2).max_element();
    let tf = t1.max(t2).min_element();
    if tn <= tf && tn > t_min && tn < t_max {
        Some(tn)
    } else {
        None
    }
}

/// Ray o + t·d against the vertical cylinder of axis `c`, radius `r` over z ∈ [z0, z1]:
/// the nearest hit of its side or its top in (t_min, t_max), if any.
#[inline]
fn cyl_hit(c: DVec2, r: f64, z0: f64, z1: f64, ray: &Ray) -> Option<f64> {
    let Ray { o, d, t_min, t_max } = *ray;
    let mut best: Option<f64> = None;
    let px = o.x - c.x;
    let py = o.y - c.y;
    let a = d.x * d.x + d.y * d.y;
    if a > 1e-12 {
        let b = px * d.x + py * d.y;
        let cc = px * px + py * py - r * r;
        let disc = b * b - a * cc;
        if disc >= 0.0 {
            let t = (-b - disc.sqrt()) / a;
            if t > t_min && t < t_max {
                let z = o.z + t * d.z;
                if z >= z0 && z <= z1 {
                    best = Some(t);
                }
            }
        }
    }
    if d.z.abs() > 1e-12 {
        let t = (z1 - o.z) / d.z;
        if t > t_min && t < best.unwrap_or(t_max) {
            let x = px + t * d.x;
            let y = py + t * d.y;
            if x * x + y * y <= r * r {
                best = Some(t);
            }
        }
    }
    best
}

/// Ray o + t·d against the sphere of centre `c`, radius `r`: the entry distance in
/// (t_min, t_max), if any.
#[inline]
fn sphere_hit(c: DVec3, r: f64, ray: &Ray) -> Option<f64> {
    let Ray { o, d, t_min, t_max } = *ray;
    let p = o - c;
    let b = p.dot(d);
    let cc = p.length_squared() - r * r;
    let a = d.length_squared();
    let disc = b * b - a * cc;
    if disc < 0.0 {
        return None;
    }
    let t = (-b - disc.sqrt()) / a;
    if t > t_min && t < t_max {
        Some(t)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_hit_distance_and_normal() {
        let p = Prim::oriented_box(
            DVec3::new(10.0, 0.0, 1.0),
            DVec3::new(2.0, 2.0, 2.0),
            0.3,
            Surface::Wall,
            [1.0; 3],
            0,
        );
        // Ray along +x at z = 1 hits the rotated box's face.
        let t = p
            .intersect(DVec3::new(0.0, 0.0, 1.0), DVec3::X, 0.0, 100.0)
            .unwrap();
        // Face at local x = -1: world distance 10 - 1/cos(0.3).
        assert!((t - (10.0 - 1.0 / 0.3f64.cos())).abs() < 1e-9, "{t}");
        let n = p.normal(DVec3::new(t, 0.0, 1.0));
        assert!((n - DVec3::new(-(0.3f64).cos(), -(0.3f64).sin(), 0.0)).length() < 1e-9);
        assert!(p
            .intersect(DVec3::new(0.0, 5.0, 1.0), DVec3::X, 0.0, 100.0)
            .is_none());
    }

    #[test]
    fn cylinder_and_sphere() {
        let c = Prim::new(
            Shape::Cyl {
                c: DVec2::new(5.0, 0.0),
                r: 0.5,
                z0: 0.0,
                z1: 3.0,
            },
            Surface::Pole,
            [1.0; 3],
            0,
        );
        let t = c
            .intersect(DVec3::new(0.0, 0.0, 1.0), DVec3::X, 0.0, 50.0)
            .unwrap();
        assert!((t - 4.5).abs() < 1e-12);
        assert!(c
            .intersect(DVec3::new(0.0, 0.0, 4.0), DVec3::X, 0.0, 50.0)
            .is_none());
        // From above onto the cap.
        let t = c
            .intersect(DVec3::new(5.0, 0.0, 10.0), -DVec3::Z, 0.0, 50.0)
            .unwrap();
        assert!((t - 7.0).abs() < 1e-12);
        let s = Prim::new(
            Shape::Sphere {
                c: DVec3::new(0.0, 10.0, 0.0),
                r: 2.0,
            },
            Surface::Foliage,
            [1.0; 3],
            0,
        );
        let t = s.intersect(DVec3::ZERO, DVec3::Y, 0.0, 50.0).unwrap();
        assert!((t - 8.0).abs() < 1e-12);
    }
}
