//! The radar returns behind a sample's radar maps (`radar_points.bin`), so that the raw and
//! height-extended maps (SPEC §5) can be rebuilt without the dataroot: with some radars left
//! out (sensor failure, SPEC §10.8) or with a perturbed radar→camera extrinsic (calibration
//! perturbation, SPEC §10.7).
//!
//! What is stored: every return of every sweep of every radar channel that `prepare`
//! rasterised, after the SPEC §2 filters, velocity compensation and multi-sweep accumulation,
//! as the f32 **camera-frame** point (metres, x right, y down, z forward) that `prepare` fed to
//! [`crate::maps::radar_maps`] — bit for bit, so [`RadarPoints::rasterise`] (the one function
//! `prepare` itself rasterises with) rebuilds the stored maps exactly. Returns with camera
//! z ≤ 0 (behind the image plane; they can never reach the image under a perturbation of a few
//! degrees) are left out. Points are grouped per (channel, sweep), each group with that sweep's
//! radar origin in the camera frame (the translation of its cam_from_radar), the pivot of a
//! rotation perturbation ([`Perturbation`]). The full-resolution camera is stored too.
//!
//! Layout (little-endian): magic `DSRADPT\0`, version u32 = 1; camera fx, fy, cx, cy (f64),
//! width, height (u32); channel count u32, then per channel a u16 length and UTF-8 name;
//! group count u32, then per group channel u16, sweep u16, origin [f32; 3], point count u32;
//! then the points, [f32; 3] each, group after group. The file must end with the last point.

use std::path::{Path, PathBuf};

use depthsense_nuscenes::geometry::Camera;

use crate::maps::{radar_maps, Raster};

/// File name inside a sample folder.
pub const RADAR_POINTS_FILE: &str = "radar_points.bin";
const MAGIC: &[u8; 8] = b"DSRADPT\0";
const VERSION: u32 = 1;
/// Sanity limits on counts read from a file.
const MAX_CHANNELS: usize = 64;
const MAX_NAME_BYTES: usize = 256;
const MAX_GROUPS: usize = 1 << 16;

#[derive(Debug, thiserror::Error)]
pub enum RadarPointsError {
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "{path}: no per-radar points in this prepared sample (it predates them); re-run \
         depthsense prepare into a new --out to re-rasterise radar (perturbation, partial radar drop)"
    )]
    Missing { path: String },
    #[error("{path}: not a valid radar points file: {reason}")]
    Format { path: String, reason: String },
}

/// One sweep of one channel: `n_points` consecutive points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepGroup {
    /// Index into [`RadarPoints::channels`].
    pub channel: u16,
    /// 0 = the keyframe sweep, 1 = the one before, …
    pub sweep: u16,
    /// The radar's position at this sweep in the camera frame (metres).
    pub origin_cam: [f32; 3],
    pub n_points: u32,
}

/// A sample's radar returns in the camera frame (module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct RadarPoints {
    pub camera: Camera,
    pub channels: Vec<String>,
    pub groups: Vec<SweepGroup>,
    pub points_cam: Vec<[f32; 3]>,
}

/// The raw and height-extended radar maps (SPEC §5) of a [`RadarPoints`].
pub struct RadarRasters {
    pub raw: Raster,
    pub height: Raster,
}

/// Axis of a calibration perturbation, in the camera frame (x right, y down, z forward).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum PerturbAxis {
    /// Rotation about the camera's vertical (y) axis; + moves returns to the right.
    Yaw,
    /// Rotation about the camera's x axis; + moves returns down.
    Pitch,
    /// Rotation about the optical (z) axis; + turns x towards y (clockwise in the image).
    Roll,
    /// Translation along camera x (right), metres.
    X,
    /// Translation along camera y (down), metres.
    Y,
    /// Translation along camera z (forward), metres.
    Z,
}

impl depthsense_base::words::Words for PerturbAxis {
    const WHAT: &'static str = "axis";
    const WORDS: &'static [(&'static str, Self)] = &[
        ("yaw", PerturbAxis::Yaw),
        ("pitch", PerturbAxis::Pitch),
        ("roll", PerturbAxis::Roll),
        ("x", PerturbAxis::X),
        ("y", PerturbAxis::Y),
        ("z", PerturbAxis::Z),
    ];
}

impl PerturbAxis {
    pub const ALL: [PerturbAxis; 6] = [
        PerturbAxis::Yaw,
        PerturbAxis::Pitch,
        PerturbAxis::Roll,
        PerturbAxis::X,
        PerturbAxis::Y,
        PerturbAxis::Z,
    ];

    pub fn name(self) -> &'static str {
        depthsense_base::words::Words::word(self)
    }

    pub fn is_rotation(self) -> bool {
        matches!(
            self,
            PerturbAxis::Yaw | PerturbAxis::Pitch | PerturbAxis::Roll
        )
    }
}

/// A perturbed radar→camera extrinsic (SPEC §10.7): `amount` degrees of rotation about
/// `axis` (pivot: the radar's own position, so the radar turns on its mount), or `amount`
/// metres of translation along it. For a return p of a sweep whose radar sits at o (camera
/// frame): p' = o + R·(p − o) + t. Equivalently cam_from_radar' has rotation R·R_cr and
/// translation t_cr + t: the error sits in the mounting, expressed in camera axes.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Perturbation {
    pub axis: PerturbAxis,
    pub amount: f64,
}

impl Perturbation {
    /// (R, t) of this perturbation, f64.
    fn rotation_translation(&self) -> ([[f64; 3]; 3], [f64; 3]) {
        let mut r = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let mut t = [0.0; 3];
        let (s, c) = self.amount.to_radians().sin_cos();
        match self.axis {
            // x' = x cos + z sin, z' = −x sin + z cos
            PerturbAxis::Yaw => r = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]],
            // y' = y cos + z sin, z' = −y sin + z cos
            PerturbAxis::Pitch => r = [[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]],
            // x' = x cos − y sin, y' = x sin + y cos
            PerturbAxis::Roll => r = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]],
            PerturbAxis::X => t[0] = self.amount,
            PerturbAxis::Y => t[1] = self.amount,
            PerturbAxis::Z => t[2] = self.amount,
        }
        (r, t)
    }

    /// p' = o + R·(p − o) + t (f64 arithmetic; an amount of 0 returns p exactly).
    pub fn apply(&self, origin_cam: [f32; 3], p: [f32; 3]) -> [f32; 3] {
        let (r, t) = self.rotation_translation();
        let q = [0, 1, 2].map(|i| p[i] as f64 - origin_cam[i] as f64);
        [0, 1, 2].map(|i| {
            let rq = r[i][0] * q[0] + r[i][1] * q[1] + r[i][2] * q[2];
            (origin_cam[i] as f64 + rq + t[i]) as f32
        })
    }
}

impl RadarPoints {
    pub fn new(camera: Camera) -> RadarPoints {
        RadarPoints {
            camera,
            channels: Vec::new(),
            groups: Vec::new(),
            points_cam: Vec::new(),
        }
    }

    /// Add one sweep of `channel` (points in the camera frame; those with z ≤ 0 are skipped).
    pub fn push_sweep(
        &mut self,
        channel: &str,
        sweep: usize,
        origin_cam: [f32; 3],
        points_cam: &[[f32; 3]],
    ) {
        let ch = match self.channels.iter().position(|c| c == channel) {
            Some(i) => i,
            None => {
                self.channels.push(channel.to_string());
                self.channels.len() - 1
            }
        };
        let before = self.points_cam.len();
        self.points_cam
            .extend(points_cam.iter().filter(|p| p[2] > 0.0).copied());
        self.groups.push(SweepGroup {
            channel: ch as u16,
            sweep: sweep.min(u16::MAX as usize) as u16,
            origin_cam,
            n_points: (self.points_cam.len() - before) as u32,
        });
    }

    /// Groups with the range of their points in `points_cam`.
    pub fn group_ranges(&self) -> impl Iterator<Item = (&SweepGroup, std::ops::Range<usize>)> {
        let mut start = 0usize;
        self.groups.iter().map(move |g| {
            let r = start..start + g.n_points as usize;
            start = r.end;
            (g, r)
        })
    }

    /// The raw and height-extended maps (SPEC §5): `prepare` builds its stored maps with
    /// this very function, so an unchanged set of points reproduces them bit for bit.
    pub fn rasterise(&self) -> RadarRasters {
        let mut out = RadarRasters {
            raw: Raster::default(),
            height: Raster::default(),
        };
        radar_maps(
            &self.points_cam,
            &self.camera,
            &mut out.raw,
            &mut out.height,
        );
        out
    }

    /// The same returns without the channels for which `drop` is true.
    pub fn without_channels(&self, drop: impl Fn(&str) -> bool) -> RadarPoints {
        let mut out = RadarPoints {
            channels: self.channels.clone(),
            ..RadarPoints::new(self.camera)
        };
        for (g, r) in self.group_ranges() {
            let name = self.channels.get(g.channel as usize).map(String::as_str);
            if name.is_some_and(&drop) {
                continue;
            }
            out.points_cam.extend_from_slice(&self.points_cam[r]);
            out.groups.push(*g);
        }
        out
    }

    /// Every return moved by `p` about its own sweep's radar origin ([`Perturbation`]).
    pub fn perturbed(&self, p: &Perturbation) -> RadarPoints {
        let mut out = self.clone();
        let ranges: Vec<_> = self.group_ranges().map(|(g, r)| (*g, r)).collect();
        for (g, r) in ranges {
            for q in &mut out.points_cam[r] {
                *q = p.apply(g.origin_cam, *q);
            }
        }
        out
    }

    pub fn encode(&self) -> Vec<u8> {
        let mut b = Vec::with_capacity(64 + self.groups.len() * 24 + self.points_cam.len() * 12);
        b.extend_from_slice(MAGIC);
        b.extend_from_slice(&VERSION.to_le_bytes());
        let c = &self.camera;
        for v in [c.fx, c.fy, c.cx, c.cy] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        b.extend_from_slice(&c.width.to_le_bytes());
        b.extend_from_slice(&c.height.to_le_bytes());
        b.extend_from_slice(&(self.channels.len() as u32).to_le_bytes());
        for ch in &self.channels {
            b.extend_from_slice(&(ch.len() as u16).to_le_bytes());
            b.extend_from_slice(ch.as_bytes());
        }
        b.extend_from_slice(&(self.groups.len() as u32).to_le_bytes());
        for g in &self.groups {
            b.extend_from_slice(&g.channel.to_le_bytes());
            b.extend_from_slice(&g.sweep.to_le_bytes());
            for v in g.origin_cam {
                b.extend_from_slice(&v.to_le_bytes());
            }
            b.extend_from_slice(&g.n_points.to_le_bytes());
        }
        for p in &self.points_cam {
            for v in p {
                b.extend_from_slice(&v.to_le_bytes());
            }
        }
        b
    }

    /// Parse a file's bytes; `path` names the file in errors.
    pub fn decode(bytes: &[u8], path: &Path) -> Result<RadarPoints, RadarPointsError> {
        let fail = |reason: String| RadarPointsError::Format {
            path: path.display().to_string(),
            reason,
        };
        let mut r = Reader { b: bytes, pos: 0 };
        if r.take(8).map_err(&fail)? != MAGIC {
            return Err(fail("bad magic (expected DSRADPT)".into()));
        }
        let version = r.u32().map_err(&fail)?;
        if version != VERSION {
            return Err(fail(format!(
                "version {version}, this build reads {VERSION}"
            )));
        }
        let camera = read_camera(&mut r).map_err(&fail)?;
        let channels = read_channels(&mut r).map_err(&fail)?;
        let groups = read_groups(&mut r, channels.len()).map_err(&fail)?;
        let total = groups
            .iter()
            .try_fold(0usize, |acc, g| acc.checked_add(g.n_points as usize))
            .ok_or_else(|| fail("point count overflows".into()))?;
        let need = total
            .checked_mul(12)
            .ok_or_else(|| fail("point count overflows".into()))?;
        let rest = bytes.len() - r.pos;
        if rest != need {
            return Err(fail(format!(
                "{total} points need {need} bytes after the header, the file has {rest}"
            )));
        }
        let points_cam = bytes[r.pos..]
            .chunks_exact(12)
            .map(|c| [0, 4, 8].map(|o| f32::from_le_bytes([c[o], c[o + 1], c[o + 2], c[o + 3]])))
            .collect();
        Ok(RadarPoints {
            camera,
            channels,
            groups,
            points_cam,
        })
    }

    /// Read `dir`/[`RADAR_POINTS_FILE`]; [`RadarPointsError::Missing`] when absent.
    pub fn read_from_sample(dir: &Path) -> Result<RadarPoints, RadarPointsError> {
        let path: PathBuf = dir.join(RADAR_POINTS_FILE);
        match std::fs::read(&path) {
            Ok(b) => RadarPoints::decode(&b, &path),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(RadarPointsError::Missing {
                path: path.display().to_string(),
            }),
            Err(e) => Err(RadarPointsError::Io {
                path: path.to_path_buf(),
                source: e,
            }),
        }
    }
}

struct Reader<'a> {
    b: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|e| *e <= self.b.len())
            .ok_or_else(|| format!("truncated at byte {} (needs {n} more)", self.pos))?;
        let s = &self.b[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn arr<const N: usize>(&mut self) -> Result<[u8; N], String> {
        let s = self.take(N)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }
    fn u16(&mut self) -> Result<u16, String> {
        self.arr().map(u16::from_le_bytes)
    }
    fn u32(&mut self) -> Result<u32, String> {
        self.arr().map(u32::from_le_bytes)
    }
    fn f32(&mut self) -> Result<f32, String> {
        self.arr().map(f32::from_le_bytes)
    }
    fn f64(&mut self) -> Result<f64, String> {
        self.arr().map(f64::from_le_bytes)
    }
}

fn read_camera(r: &mut Reader) -> Result<Camera, String> {
    let [fx, fy, cx, cy] = [r.f64()?, r.f64()?, r.f64()?, r.f64()?];
    let (width, height) = (r.u32()?, r.u32()?);
    if ![fx, fy, cx, cy].iter().all(|v| v.is_finite()) || fx <= 0.0 || fy <= 0.0 {
        return Err(format!("bad camera intrinsics {fx} {fy} {cx} {cy}"));
    }
    if width == 0 || height == 0 || width > 1 << 16 || height > 1 << 16 {
        return Err(format!("bad camera size {width}x{height}"));
    }
    Ok(Camera {
        fx,
        fy,
        cx,
        cy,
        width,
        height,
    })
}

fn read_channels(r: &mut Reader) -> Result<Vec<String>, String> {
    let n = r.u32()? as usize;
    if n > MAX_CHANNELS {
        return Err(format!("{n} channels (at most {MAX_CHANNELS})"));
    }
    (0..n)
        .map(|_| {
            let len = r.u16()? as usize;
            if len > MAX_NAME_BYTES {
                return Err(format!("channel name of {len} bytes"));
            }
            String::from_utf8(r.take(len)?.to_vec()).map_err(|_| "channel name not UTF-8".into())
        })
        .collect()
}

fn read_groups(r: &mut Reader, n_channels: usize) -> Result<Vec<SweepGroup>, String> {
    let n = r.u32()? as usize;
    if n > MAX_GROUPS {
        return Err(format!("{n} sweep groups (at most {MAX_GROUPS})"));
    }
    (0..n)
        .map(|i| {
            let channel = r.u16()?;
            if channel as usize >= n_channels {
                return Err(format!("group {i} names channel {channel} of {n_channels}"));
            }
            let sweep = r.u16()?;
            let origin_cam = [r.f32()?, r.f32()?, r.f32()?];
            let n_points = r.u32()?;
            Ok(SweepGroup {
                channel,
                sweep,
                origin_cam,
                n_points,
            })
        })
        .collect()
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

    fn sample() -> RadarPoints {
        let mut rp = RadarPoints::new(cam());
        rp.push_sweep(
            "RADAR_FRONT",
            0,
            [0.0, 1.0, -1.5],
            &[[0.0, 0.5, 10.0], [1.0, 0.3, 20.0], [0.0, 0.0, -3.0]],
        );
        rp.push_sweep(
            "RADAR_FRONT_LEFT",
            0,
            [-0.5, 1.0, -1.0],
            &[[-3.0, 0.4, 15.0]],
        );
        rp.push_sweep("RADAR_FRONT", 1, [0.0, 1.0, -2.0], &[[2.0, 0.5, 30.0]]);
        rp
    }

    #[test]
    fn round_trip_and_behind_camera_points_skipped() {
        let rp = sample();
        assert_eq!(rp.points_cam.len(), 4);
        assert_eq!(rp.groups[0].n_points, 2);
        let b = rp.encode();
        let back = RadarPoints::decode(&b, Path::new("x.bin")).unwrap();
        assert_eq!(back, rp);
        assert_eq!(back.rasterise().raw.depth_m, rp.rasterise().raw.depth_m);
    }

    #[test]
    fn truncated_and_hostile_files_are_refused_with_the_path() {
        let b = sample().encode();
        let p = Path::new("s/radar_points.bin");
        for n in [0, 7, 12, 40, 60, b.len() - 1] {
            let e = RadarPoints::decode(&b[..n], p).unwrap_err().to_string();
            assert!(e.contains("s/radar_points.bin"), "{e}");
        }
        let mut extra = b.clone();
        extra.push(0);
        assert!(RadarPoints::decode(&extra, p).is_err());
        // point counts far beyond the file
        let groups_at = b.len() - 4 * 12 - 3 * 20;
        for g in 0..3 {
            let mut h = b.clone();
            let at = groups_at + g * 20 + 16;
            h[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
            let e = RadarPoints::decode(&h, p).unwrap_err().to_string();
            assert!(
                e.contains("bytes after the header") || e.contains("overflow"),
                "{e}"
            );
        }
        // channel index out of range, bad magic, huge channel count
        let mut h = b.clone();
        h[groups_at..groups_at + 2].copy_from_slice(&9u16.to_le_bytes());
        assert!(RadarPoints::decode(&h, p)
            .unwrap_err()
            .to_string()
            .contains("channel 9"));
        let mut h = b.clone();
        h[0] = b'X';
        assert!(RadarPoints::decode(&h, p)
            .unwrap_err()
            .to_string()
            .contains("magic"));
        let mut h = b.clone();
        h[52..56].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(RadarPoints::decode(&h, p)
            .unwrap_err()
            .to_string()
            .contains("channels"));
    }

    #[test]
    fn dropping_a_channel_keeps_exactly_the_others() {
        let rp = sample();
        let kept = rp.without_channels(|c| c == "RADAR_FRONT_LEFT");
        assert_eq!(kept.points_cam.len(), 3);
        assert!(kept.group_ranges().all(|(g, _)| g.channel == 0));
        assert!(kept.points_cam.iter().all(|p| p[0] != -3.0));
    }

    #[test]
    fn zero_perturbation_is_exact_and_yaw_follows_the_pinhole_model() {
        let rp = sample();
        for axis in PerturbAxis::ALL {
            let z = rp.perturbed(&Perturbation { axis, amount: 0.0 });
            assert_eq!(z.points_cam, rp.points_cam, "{axis:?}");
        }
        // a return on the optical axis, radar at the camera: u moves by fx·tan(δ)
        let p = Perturbation {
            axis: PerturbAxis::Yaw,
            amount: 2.0,
        };
        let q = p.apply([0.0; 3], [0.0, 0.0, 40.0]);
        let u = 1000.0 * q[0] as f64 / q[2] as f64;
        assert!((u - 1000.0 * 2f64.to_radians().tan()).abs() < 1e-3, "{u}");
    }
}
