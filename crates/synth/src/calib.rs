//! Sensor mounts, intrinsics and rates of the synthetic vehicle.
//!
//! The CAM_FRONT, LIDAR_TOP and RADAR_FRONT values are the real nuScenes calibration of
//! vehicle n015 (v1.0-mini `calibrated_sensor.json`, log n015-2018-07-24-11-22-45+0800, as in
//! `../shared/fixtures/nuscenes-kf0`); nuScenes calibration values are facts, embedded here so
//! that the generator needs no fixture. The fixture does not carry RADAR_FRONT_LEFT/RIGHT: their
//! mounts follow the nuScenes sensor layout (corner radars at x = 2.42 m, y = ±0.80 m,
//! z ≈ 0.78 m, looking sideways, yaw ≈ ±90°).
//! Quaternions are (w, x, y, z) as in the nuScenes tables (SPEC §2).

use glam::{DQuat, DVec3};

pub const CAM_FRONT: &str = "CAM_FRONT";
pub const LIDAR_TOP: &str = "LIDAR_TOP";
pub const RADAR_FRONT: &str = "RADAR_FRONT";
pub const RADAR_FRONT_LEFT: &str = "RADAR_FRONT_LEFT";
pub const RADAR_FRONT_RIGHT: &str = "RADAR_FRONT_RIGHT";
pub const RADAR_CHANNELS: [&str; 3] = [RADAR_FRONT, RADAR_FRONT_LEFT, RADAR_FRONT_RIGHT];

/// Image size of CAM_FRONT (SPEC §2).
pub const IMG_W: u32 = 1600;
pub const IMG_H: u32 = 900;

/// CAM_FRONT intrinsics (fx = fy, cx, cy).
pub const CAM_FX: f64 = 1266.417203046554;
pub const CAM_FY: f64 = 1266.417203046554;
pub const CAM_CX: f64 = 816.2670197447984;
pub const CAM_CY: f64 = 491.50706579294757;

/// A sensor mount: ego_from_sensor as translation + rotation (w, x, y, z).
#[derive(Debug, Clone, Copy)]
pub struct Mount {
    pub channel: &'static str,
    pub modality: &'static str,
    pub translation: [f64; 3],
    pub rotation_wxyz: [f64; 4],
}

impl Mount {
    pub fn rotation(&self) -> DQuat {
        let [w, x, y, z] = self.rotation_wxyz;
        DQuat::from_xyzw(x, y, z, w).normalize()
    }
    pub fn translation(&self) -> DVec3 {
        DVec3::from_array(self.translation)
    }
    /// Sensor → ego.
    pub fn to_ego(&self, p: DVec3) -> DVec3 {
        self.rotation() * p + self.translation()
    }
}

/// Corner-radar yaw (degrees), see module docs.
const CORNER_YAW_DEG: f64 = 89.0;

fn yaw_quat(deg: f64) -> [f64; 4] {
    let h = deg.to_radians() / 2.0;
    [h.cos(), 0.0, 0.0, h.sin()]
}

pub fn cam_front() -> Mount {
    Mount {
        channel: CAM_FRONT,
        modality: "camera",
        translation: [1.70079118954, 0.0159456324149, 1.51095763913],
        rotation_wxyz: [
            0.4998015430569128,
            -0.5030316162024876,
            0.4997798114386805,
            -0.49737083824542755,
        ],
    }
}

pub fn lidar_top() -> Mount {
    Mount {
        channel: LIDAR_TOP,
        modality: "lidar",
        translation: [0.943713, 0.0, 1.84023],
        rotation_wxyz: [
            0.7077955119163518,
            -0.006492242056004365,
            0.010646214713995808,
            -0.7063073142877817,
        ],
    }
}

pub fn radar(channel: &str) -> Mount {
    match channel {
        RADAR_FRONT_LEFT => Mount {
            channel: RADAR_FRONT_LEFT,
            modality: "radar",
            translation: [2.422, 0.8, 0.78],
            rotation_wxyz: yaw_quat(CORNER_YAW_DEG),
        },
        RADAR_FRONT_RIGHT => Mount {
            channel: RADAR_FRONT_RIGHT,
            modality: "radar",
            translation: [2.422, -0.8, 0.77],
            rotation_wxyz: yaw_quat(-CORNER_YAW_DEG),
        },
        _ => Mount {
            channel: RADAR_FRONT,
            modality: "radar",
            translation: [3.412, 0.0, 0.5],
            rotation_wxyz: [0.9999984769132877, 0.0, 0.0, 0.0017453283658983088],
        },
    }
}

/// All mounts in table order.
pub fn all_mounts() -> Vec<Mount> {
    vec![
        cam_front(),
        lidar_top(),
        radar(RADAR_FRONT),
        radar(RADAR_FRONT_LEFT),
        radar(RADAR_FRONT_RIGHT),
    ]
}

/// Rates (nuScenes): keyframes 2 Hz, LIDAR_TOP 20 Hz, radar ≈ 13 Hz, camera 12 Hz.
pub const KEYFRAME_PERIOD_S: f64 = 0.5;
pub const LIDAR_PERIOD_S: f64 = 0.05;
pub const RADAR_PERIOD_S: f64 = 1.0 / 13.0;
/// The camera of a keyframe fires this long before the keyframe's lidar sweep (nuScenes
/// triggers the camera as the spinning lidar passes the camera's field of view).
pub const CAM_OFFSET_S: f64 = -0.012;

/// HDL-32E beam elevations: 32 beams from −30.67° to +10.67° (ring 0 = lowest).
pub fn lidar_elevations_deg() -> [f64; 32] {
    let mut e = [0.0; 32];
    for (i, v) in e.iter_mut().enumerate() {
        *v = -30.67 + (10.67 + 30.67) * i as f64 / 31.0;
    }
    e
}
/// Azimuth steps per revolution (34,688 / 32 ≈ 1084 in nuScenes).
pub const LIDAR_AZIMUTHS: usize = 1084;
/// Lidar maximum range (m).
pub const LIDAR_MAX_RANGE_M: f64 = 100.0;
