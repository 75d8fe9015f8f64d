//! Rotations, rigid transforms, the sensor → camera chain and pinhole projection (SPEC §2–3).

use crate::error::{NuError, Result};
use crate::tables::{NuScenes, SampleData};

/// Largest accepted deviation of a stored quaternion's norm from 1.
pub const QUAT_NORM_TOL: f64 = 1e-3;

/// Rotation matrix of a unit quaternion stored **w, x, y, z** (SPEC §2). A quaternion whose
/// norm is off by more than [`QUAT_NORM_TOL`] is an error naming `record`; a nearly-unit one
/// is renormalised.
pub fn rotation_from_wxyz(q: [f64; 4], record: &str) -> Result<[[f64; 3]; 3]> {
    let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !norm.is_finite() || (norm - 1.0).abs() > QUAT_NORM_TOL {
        return Err(NuError::NonUnitQuaternion {
            record: record.to_string(),
            q,
            norm,
        });
    }
    let [w, x, y, z] = q.map(|v| v / norm);
    Ok([
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ])
}

/// A rigid transform `p' = R p + t` (`dst_from_src`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rigid {
    pub r: [[f64; 3]; 3],
    pub t: [f64; 3],
}

impl Rigid {
    pub const IDENTITY: Rigid = Rigid {
        r: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        t: [0.0; 3],
    };

    /// From a nuScenes record (rotation w,x,y,z + translation): `parent_from_child`.
    pub fn from_record(rotation: [f64; 4], translation: [f64; 3], record: &str) -> Result<Rigid> {
        Ok(Rigid {
            r: rotation_from_wxyz(rotation, record)?,
            t: translation,
        })
    }

    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        let r = &self.r;
        [
            r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2] + self.t[0],
            r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2] + self.t[1],
            r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2] + self.t[2],
        ]
    }

    /// Rotation only (for velocities).
    pub fn rotate(&self, p: [f64; 3]) -> [f64; 3] {
        let r = &self.r;
        [
            r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2],
            r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2],
            r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2],
        ]
    }

    /// `self ∘ other`: first `other`, then `self`.
    pub fn compose(&self, other: &Rigid) -> Rigid {
        let mut r = [[0.0; 3]; 3];
        for (i, row) in r.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = (0..3).map(|k| self.r[i][k] * other.r[k][j]).sum();
            }
        }
        Rigid {
            r,
            t: self.apply(other.t),
        }
    }

    pub fn inverse(&self) -> Rigid {
        let mut r = [[0.0; 3]; 3];
        for (i, row) in r.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = self.r[j][i];
            }
        }
        let t = [
            -(r[0][0] * self.t[0] + r[0][1] * self.t[1] + r[0][2] * self.t[2]),
            -(r[1][0] * self.t[0] + r[1][1] * self.t[1] + r[1][2] * self.t[2]),
            -(r[2][0] * self.t[0] + r[2][1] * self.t[1] + r[2][2] * self.t[2]),
        ];
        Rigid { r, t }
    }

    /// 4x4 row-major homogeneous matrix.
    /// The rotation and translation of a 4x4 row-major rigid transform (its last row is not
    /// read); `Rigid::from_mat4(&r.to_mat4()) == r` exactly.
    pub fn from_mat4(m: &[[f64; 4]; 4]) -> Rigid {
        let mut r = Rigid::IDENTITY;
        for (i, row) in m.iter().take(3).enumerate() {
            r.r[i].copy_from_slice(&row[..3]);
            r.t[i] = row[3];
        }
        r
    }

    pub fn to_mat4(&self) -> [[f64; 4]; 4] {
        let mut m = [[0.0; 4]; 4];
        for (i, row) in m.iter_mut().take(3).enumerate() {
            row[..3].copy_from_slice(&self.r[i]);
            row[3] = self.t[i];
        }
        m[3][3] = 1.0;
        m
    }

    /// f32 3x4 copy for transforming many points.
    pub fn to_f32(&self) -> [[f32; 4]; 3] {
        let mut m = [[0f32; 4]; 3];
        for (i, row) in m.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().take(3).enumerate() {
                *v = self.r[i][j] as f32;
            }
            row[3] = self.t[i] as f32;
        }
        m
    }
}

/// Apply an f32 3x4 transform to a point.
#[inline]
pub fn apply_f32(m: &[[f32; 4]; 3], p: [f32; 3]) -> [f32; 3] {
    [
        m[0][0] * p[0] + m[0][1] * p[1] + m[0][2] * p[2] + m[0][3],
        m[1][0] * p[0] + m[1][1] * p[1] + m[1][2] * p[2] + m[1][3],
        m[2][0] * p[0] + m[2][1] * p[1] + m[2][2] * p[2] + m[2][3],
    ]
}

/// `ego_from_sensor` of a sample_data row (its calibrated_sensor).
pub fn ego_from_sensor(nu: &NuScenes, sd: &SampleData) -> Result<Rigid> {
    let cs = nu.get_calibrated_sensor(
        sd.calibrated_sensor_token,
        "sample_data",
        sd.token,
        "calibrated_sensor_token",
    )?;
    Rigid::from_record(
        cs.rotation,
        cs.translation,
        &format!("calibrated_sensor {}", cs.token),
    )
}

/// `global_from_ego` at the capture time of a sample_data row (its ego_pose).
pub fn global_from_ego(nu: &NuScenes, sd: &SampleData) -> Result<Rigid> {
    let ep = nu.get_ego_pose(sd.ego_pose_token, "sample_data", sd.token, "ego_pose_token")?;
    Rigid::from_record(
        ep.rotation,
        ep.translation,
        &format!("ego_pose {}", ep.token),
    )
}

/// The full chain of SPEC §2: sensor → ego(t_s) → global → ego(t_c) → camera.
pub fn cam_from_sensor(
    nu: &NuScenes,
    sd_points: &SampleData,
    sd_cam: &SampleData,
) -> Result<Rigid> {
    let global_from_sensor =
        global_from_ego(nu, sd_points)?.compose(&ego_from_sensor(nu, sd_points)?);
    let global_from_cam = global_from_ego(nu, sd_cam)?.compose(&ego_from_sensor(nu, sd_cam)?);
    Ok(global_from_cam.inverse().compose(&global_from_sensor))
}

/// Pinhole camera with the full-resolution image size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

/// Minimum depth of a kept point (SPEC §2).
pub const MIN_DEPTH_M: f32 = 1.0;

impl Camera {
    pub fn from_intrinsic(k: &[[f64; 3]; 3], width: u32, height: u32) -> Camera {
        Camera {
            fx: k[0][0],
            fy: k[1][1],
            cx: k[0][2],
            cy: k[1][2],
            width,
            height,
        }
    }

    /// Project a camera-frame point: `(u, v, depth)` when depth > 1 m and
    /// 1 < u < W−1, 1 < v < H−1 (SPEC §2), else `None`.
    #[inline]
    pub fn project(&self, p: [f32; 3]) -> Option<(f32, f32, f32)> {
        let z = p[2];
        if z.is_nan() || z <= MIN_DEPTH_M {
            return None;
        }
        let u = self.fx as f32 * p[0] / z + self.cx as f32;
        let v = self.fy as f32 * p[1] / z + self.cy as f32;
        if u > 1.0 && u < self.width as f32 - 1.0 && v > 1.0 && v < self.height as f32 - 1.0 {
            Some((u, v, z))
        } else {
            None
        }
    }

    /// Training-frame intrinsics (SPEC §3): ×0.5 and cy −= 100, row-major 3x3.
    pub fn frame_intrinsics(&self) -> [[f64; 3]; 3] {
        [
            [self.fx * 0.5, 0.0, self.cx * 0.5],
            [0.0, self.fy * 0.5, self.cy * 0.5 - 100.0],
            [0.0, 0.0, 1.0],
        ]
    }

    pub fn intrinsics(&self) -> [[f64; 3]; 3] {
        [
            [self.fx, 0.0, self.cx],
            [0.0, self.fy, self.cy],
            [0.0, 0.0, 1.0],
        ]
    }
}

/// Training frame (SPEC §3): width, height, top crop at half resolution.
pub const FRAME_W: u32 = 800;
pub const FRAME_H: u32 = 350;
pub const FRAME_CROP_TOP: i64 = 100;

/// Full-resolution (u, v) → training-frame pixel (⌊u/2⌋, ⌊v/2⌋ − 100) (SPEC §3), or `None`
/// when it falls in the cropped rows or outside.
#[inline]
pub fn to_frame(u: f32, v: f32) -> Option<(u32, u32)> {
    let x = (u * 0.5).floor() as i64;
    let y = (v * 0.5).floor() as i64 - FRAME_CROP_TOP;
    if x >= 0 && x < FRAME_W as i64 && y >= 0 && y < FRAME_H as i64 {
        Some((x as u32, y as u32))
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tables::Token;

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn quaternion_order_is_wxyz() {
        // 90° about z: w = cos45, z = sin45. Maps x → y.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let r = Rigid::from_record([s, 0.0, 0.0, s], [0.0; 3], "q").unwrap();
        let p = r.apply([1.0, 0.0, 0.0]);
        assert!(close(p[0], 0.0, 1e-12) && close(p[1], 1.0, 1e-12), "{p:?}");
        // Read as x,y,z,w it would be a 180° turn about (1,0,0)+… : not the same.
        let wrong = Rigid::from_record([0.0, 0.0, s, s], [0.0; 3], "q").unwrap();
        assert!(!close(wrong.apply([1.0, 0.0, 0.0])[1], 1.0, 1e-3));
    }

    #[test]
    fn non_unit_quaternion_is_an_error() {
        let err = Rigid::from_record([1.0, 1.0, 0.0, 0.0], [0.0; 3], "ego_pose abc")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("ego_pose abc") && err.contains("not unit"),
            "{err}"
        );
        assert!(Rigid::from_record([f64::NAN, 0.0, 0.0, 0.0], [0.0; 3], "x").is_err());
    }

    #[test]
    fn inverse_and_compose_round_trip() {
        let a = Rigid::from_record(
            [
                0.5720320396729045,
                -0.0016977771610471074,
                0.011798001930183783,
                -0.8201446642457809,
            ],
            [411.3, 1180.9, 0.2],
            "a",
        )
        .unwrap();
        let id = a.inverse().compose(&a);
        let p = id.apply([3.0, -4.0, 5.0]);
        assert!(close(p[0], 3.0, 1e-9) && close(p[1], -4.0, 1e-9) && close(p[2], 5.0, 1e-9));
    }

    #[test]
    fn frame_mapping_and_crop_edges() {
        assert_eq!(to_frame(0.5, 200.0), Some((0, 0)));
        assert_eq!(to_frame(0.5, 199.9), None); // cropped top row
        assert_eq!(to_frame(1599.0, 899.0), Some((799, 349)));
        assert_eq!(to_frame(21.0, 401.0), Some((10, 100))); // u → column, v → row
        let cam = Camera {
            fx: 1000.0,
            fy: 1000.0,
            cx: 800.0,
            cy: 450.0,
            width: 1600,
            height: 900,
        };
        assert_eq!(cam.project([0.0, 0.0, 0.9]), None);
        let (u, v, d) = cam.project([1.0, 0.5, 10.0]).unwrap();
        assert!((u - 900.0).abs() < 1e-3 && (v - 500.0).abs() < 1e-3 && d == 10.0);
        assert_eq!(cam.project([8.0, 0.0, 10.0]), None); // u = 1600 > W-1
        let k = cam.frame_intrinsics();
        assert_eq!(k[1][2], 125.0);
    }

    /// The camera-from-lidar transform of the fixture keyframe against values computed
    /// independently (numpy, pyquaternion conventions) from the same rows: both ego poses.
    #[test]
    fn kf0_cam_from_lidar_golden() {
        let Some(root) = crate::tables::tests::kf0() else {
            return;
        };
        let nu = NuScenes::load(&root, "v1.0-mini").unwrap();
        let st = Token::parse("ca9a282c9e77460f8360f564131a8af5");
        let cam = nu.keyframe(st, "CAM_FRONT").unwrap();
        let lidar = nu.keyframe(st, "LIDAR_TOP").unwrap();
        let m = cam_from_sensor(&nu, lidar, cam).unwrap().to_mat4();
        let golden = GOLDEN_CAM_FROM_LIDAR;
        for i in 0..4 {
            for j in 0..4 {
                assert!(
                    close(m[i][j], golden[i][j], 1e-6),
                    "[{i}][{j}] {} vs {}",
                    m[i][j],
                    golden[i][j]
                );
            }
        }
        // Omitting the ego-pose step changes the translation by centimetres to decimetres.
        let no_ego = ego_from_sensor(&nu, cam)
            .unwrap()
            .inverse()
            .compose(&ego_from_sensor(&nu, lidar).unwrap())
            .to_mat4();
        let dt: f64 = (0..3)
            .map(|i| (no_ego[i][3] - m[i][3]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(dt > 0.1, "ego-pose step had no effect: {dt}");
    }

    const GOLDEN_CAM_FROM_LIDAR: [[f64; 4]; 4] = include!("../tests/golden_cam_from_lidar.txt");
}
