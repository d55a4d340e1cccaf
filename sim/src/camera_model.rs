//! The camera's geometry: intrinsics K, its mounting on the robot, and the laser <- camera
//! extrinsics (the paper's Phi and Delta: `P_laser = Phi P_camera + Delta`).
//!
//! Frames: robot base and laser are REP-103 (x forward, y left, z up); the camera's optical
//! frame has z forward, x right, y down.

use serde::{Deserialize, Serialize};

use crate::config::LaserConfig;
use crate::messages::Pose2D;

/// Camera settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CameraConfig {
    /// Whether the simulator renders camera frames at all (position-only runs skip them).
    pub enabled: bool,
    pub width: u32,
    pub height: u32,
    /// Horizontal field of view; fx = fy from it, principal point at the image centre.
    pub hfov_deg: f64,
    pub rate_hz: f64,
    /// Mounting on the robot base: forward, left, up (m).
    pub mount_xyz_m: [f64; 3],
    /// Downward tilt of the optical axis (deg).
    pub mount_pitch_deg: f64,
    pub mount_yaw_deg: f64,
    /// Gaussian pixel noise (grey levels, 0-255 scale); 0 = off.
    pub noise_sigma: f64,
    /// Per-frame exposure varies by a factor N(1, this); 0 = off.
    pub exposure_sigma: f64,
    /// Whether frames carry the depth image (an extra render target; scenario runs, whose
    /// pipeline never reads depth, turn it off).
    pub depth_image: bool,
}

impl Default for CameraConfig {
    fn default() -> Self {
        CameraConfig {
            enabled: true,
            width: 640,
            height: 480,
            hfov_deg: 60.0,
            rate_hz: 5.0,
            mount_xyz_m: [0.10, 0.0, 0.55],
            mount_pitch_deg: 3.0,
            mount_yaw_deg: 0.0,
            noise_sigma: 0.0,
            exposure_sigma: 0.0,
            depth_image: true,
        }
    }
}

/// How far this project's pixel coordinates run ahead of ROS's and OpenCV's (see
/// [`Intrinsics::principal_point_ros`]).
pub const ROS_PIXEL_OFFSET: f64 = 0.5;

/// Pinhole intrinsics in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

impl Intrinsics {
    /// The principal point as ROS, OpenCV and Foxglove give it. They put a pixel's centre
    /// at whole coordinates; this project (its renderer and pipeline) at half-integers,
    /// pixel (i, j) spanning [i, i + 1) x [j, j + 1). Exchange formats use theirs.
    pub fn principal_point_ros(&self) -> (f64, f64) {
        (self.cx - ROS_PIXEL_OFFSET, self.cy - ROS_PIXEL_OFFSET)
    }

    /// K as a row-major 3x3.
    pub fn k(&self) -> [[f64; 3]; 3] {
        [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]]
    }

    /// Projects a camera-frame point to continuous pixel coordinates (pixel (i, j) covers
    /// [i, i+1) x [j, j+1)); `None` behind the camera.
    pub fn project(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        (p[2] > 1e-9).then(|| [self.fx * p[0] / p[2] + self.cx, self.fy * p[1] / p[2] + self.cy])
    }
}

/// A rigid transform: rotation (row-major) and translation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rigid {
    pub r: [[f64; 3]; 3],
    pub t: [f64; 3],
}

impl Rigid {
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|i| self.r[i][0] * p[0] + self.r[i][1] * p[1] + self.r[i][2] * p[2] + self.t[i])
    }

    pub fn inverse(&self) -> Rigid {
        let rt: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| self.r[j][i]));
        let t = std::array::from_fn(|i| -(rt[i][0] * self.t[0] + rt[i][1] * self.t[1] + rt[i][2] * self.t[2]));
        Rigid { r: rt, t }
    }

    pub fn compose(&self, other: &Rigid) -> Rigid {
        let r = std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| self.r[i][k] * other.r[k][j]).sum()));
        Rigid { r, t: self.apply(other.t) }
    }

    /// Column-major 4x4 in f32, for the renderer.
    pub fn to_mat4(&self) -> [[f32; 4]; 4] {
        let mut m: [[f32; 4]; 4] =
            std::array::from_fn(|c| std::array::from_fn(|r| if c < 3 && r < 3 { self.r[r][c] as f32 } else { 0.0 }));
        m[3] = [self.t[0] as f32, self.t[1] as f32, self.t[2] as f32, 1.0];
        m
    }
}

fn rot_z(a: f64) -> [[f64; 3]; 3] {
    let (s, c) = a.sin_cos();
    [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
}

fn rot_y(a: f64) -> [[f64; 3]; 3] {
    let (s, c) = a.sin_cos();
    [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
}

fn mul(a: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

/// Optical frame axes expressed in a REP-103 body frame: optical z = body x, optical x =
/// -body y, optical y = -body z.
const BODY_FROM_OPTICAL: [[f64; 3]; 3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]];

impl CameraConfig {
    pub fn intrinsics(&self) -> Intrinsics {
        let fx = (self.width as f64 / 2.0) / (self.hfov_deg.to_radians() / 2.0).tan();
        Intrinsics {
            fx,
            fy: fx,
            cx: self.width as f64 / 2.0,
            cy: self.height as f64 / 2.0,
            width: self.width,
            height: self.height,
        }
    }

    /// Robot base <- camera optical frame.
    pub fn base_from_camera(&self) -> Rigid {
        // Yaw, then pitch down (a positive rotation about the body's y axis tilts x down).
        let r = mul(
            mul(rot_z(self.mount_yaw_deg.to_radians()), rot_y(self.mount_pitch_deg.to_radians())),
            BODY_FROM_OPTICAL,
        );
        Rigid { r, t: self.mount_xyz_m }
    }

    /// World <- camera optical frame for a robot pose.
    pub fn world_from_camera(&self, robot: &Pose2D) -> Rigid {
        base_pose(robot).compose(&self.base_from_camera())
    }

    /// The laser <- camera extrinsics: `P_laser = Phi P_camera + Delta`.
    pub fn laser_from_camera(&self, laser: &LaserConfig) -> Rigid {
        let base_from_laser = Rigid { r: rot_z(laser.mount_yaw_deg.to_radians()), t: laser.mount_xyz_m };
        base_from_laser.inverse().compose(&self.base_from_camera())
    }

    /// Checks the settings; the error names the field (within `camera`).
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        if self.width == 0 || self.width > 8192 {
            return Err(("width", format!("must be 1..8192 pixels, got {}", self.width)));
        }
        if self.height == 0 || self.height > 8192 {
            return Err(("height", format!("must be 1..8192 pixels, got {}", self.height)));
        }
        if !(self.hfov_deg > 1.0 && self.hfov_deg < 170.0) {
            return Err(("hfov_deg", format!("must be in (1, 170), got {}", self.hfov_deg)));
        }
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0) {
            return Err(("rate_hz", format!("must be finite and positive, got {}", self.rate_hz)));
        }
        for (field, v) in [("noise_sigma", self.noise_sigma), ("exposure_sigma", self.exposure_sigma)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err((field, format!("must be finite and not negative, got {v}")));
            }
        }
        // The exposure's factor is drawn from N(1, sigma), floored at 0.1: at sigma 1
        // nearly a fifth of the frames are already at that floor, and far beyond it the
        // factor overflows the renderer's numbers.
        if self.exposure_sigma > 1.0 {
            return Err((
                "exposure_sigma",
                format!("must be at most 1 (a spread of 100%), got {}", self.exposure_sigma),
            ));
        }
        if !self.mount_xyz_m.iter().all(|v| v.is_finite()) || self.mount_xyz_m[2] <= 0.0 {
            return Err((
                "mount_xyz_m",
                format!("must be finite, with z above the ground, got {:?}", self.mount_xyz_m),
            ));
        }
        if !(self.mount_pitch_deg.abs() < 90.0) {
            return Err(("mount_pitch_deg", format!("must be within +-90 deg, got {}", self.mount_pitch_deg)));
        }
        if !(self.mount_yaw_deg.abs() <= 180.0) {
            return Err(("mount_yaw_deg", format!("must be within +-180 deg, got {}", self.mount_yaw_deg)));
        }
        Ok(())
    }
}

/// World <- robot base for a planar pose.
pub fn base_pose(robot: &Pose2D) -> Rigid {
    Rigid { r: rot_z(robot.theta), t: [robot.x, robot.y, 0.0] }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_intrinsics_give_60_degrees() {
        let k = CameraConfig::default().intrinsics();
        assert!((2.0 * (320.0 / k.fx).atan() - 60f64.to_radians()).abs() < 1e-12);
        assert_eq!((k.cx, k.cy), (320.0, 240.0));
    }

    #[test]
    fn level_camera_looks_along_the_robot_x_axis() {
        let cam = CameraConfig { mount_pitch_deg: 0.0, ..Default::default() };
        let t = cam.base_from_camera();
        // A point 5 m ahead of the camera at its height projects to the image centre.
        let p_base = [0.10 + 5.0, 0.0, 0.55];
        let p_cam = t.inverse().apply(p_base);
        let px = cam.intrinsics().project(p_cam).unwrap();
        assert!((px[0] - 320.0).abs() < 1e-9 && (px[1] - 240.0).abs() < 1e-9);
        // A point to the robot's left lands on the image's left half, one above on the top.
        assert!(cam.intrinsics().project(t.inverse().apply([5.0, 1.0, 0.55])).unwrap()[0] < 320.0);
        assert!(cam.intrinsics().project(t.inverse().apply([5.0, 0.0, 1.5])).unwrap()[1] < 240.0);
    }

    #[test]
    fn extrinsics_map_camera_points_to_the_laser_frame() {
        let cam = CameraConfig::default();
        let laser = LaserConfig::default();
        let e = cam.laser_from_camera(&laser);
        // A point on the laser's x axis 4 m out, seen from the camera, maps back exactly.
        let base_from_laser = Rigid { r: rot_z(0.0), t: laser.mount_xyz_m };
        let p_laser = [4.0, 0.3, 0.0];
        let p_cam = cam.base_from_camera().inverse().apply(base_from_laser.apply(p_laser));
        let back = e.apply(p_cam);
        for k in 0..3 {
            assert!((back[k] - p_laser[k]).abs() < 1e-12);
        }
        // Phi is a rotation.
        let r = e.r;
        let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1]) - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
            + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
        assert!((det - 1.0).abs() < 1e-12);
    }
}
