//! `manifest.toml`: the facts about the vehicle and its sensor that the data files do not
//! carry, and what the reference path describes.

use serde::{Deserialize, Serialize};

/// The log's manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// 1 for this format.
    pub format_version: u32,
    /// A name for the log (output files and summaries carry it).
    #[serde(default)]
    pub name: String,
    /// Where the data came from and whom to credit.
    #[serde(default)]
    pub source: String,
    #[serde(default)]
    pub vehicle: Vehicle,
    pub sensor: Sensor,
    /// Only for `scans.csv`: the beams' geometry.
    #[serde(default)]
    pub laser: Option<LaserGeometry>,
    #[serde(default)]
    pub reference: Option<Reference>,
    /// Only for `camera.csv`: the camera's intrinsics and its pose on the range sensor.
    #[serde(default)]
    pub camera: Option<Camera>,
}

/// The vehicle's kinematics, as the motion model needs them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Vehicle {
    /// `"odometry"` (increments, or a differential drive's v and omega) or `"ackermann"`
    /// (a car's speed and steering).
    pub motion: String,
    /// Ackermann: distance between the axles (m).
    pub wheelbase_m: Option<f64>,
    /// Ackermann: sideways offset of the wheel whose speed is logged from the rear axle's
    /// centre (m, positive left).
    pub encoder_offset_m: Option<f64>,
    /// The vehicle's pose at the first instant, in the frame the estimate is reported in.
    pub start_pose: [f64; 3],
}

impl Default for Vehicle {
    fn default() -> Self {
        Vehicle { motion: "odometry".into(), wheelbase_m: None, encoder_offset_m: None, start_pose: [0.0; 3] }
    }
}

/// The range sensor's mounting in the vehicle frame (the rear axle's centre for a car) and
/// its noise as a landmark observation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sensor {
    pub x_m: f64,
    pub y_m: f64,
    /// The sensor's forward axis against the vehicle's (rad); bearings are the sensor's.
    #[serde(default)]
    pub yaw_rad: f64,
    /// Noise of a detection's range (m), growing by `range_sigma_per_m` per metre.
    pub range_sigma_m: Option<f64>,
    pub range_sigma_per_m: Option<f64>,
    pub bearing_sigma_rad: Option<f64>,
}

/// The beams of `scans.csv`: beam i points at `angle_min_rad + i * angle_increment_rad`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaserGeometry {
    pub angle_min_rad: f64,
    pub angle_increment_rad: f64,
    pub range_min_m: f64,
    pub range_max_m: f64,
}

/// A pinhole camera whose frames `camera.csv` lists, and where it sits on the range
/// sensor: the camera methods project laser returns into its images.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    /// Image size (pixels); every frame must have it.
    pub width: u32,
    pub height: u32,
    /// Focal lengths and principal point (pixels), for undistorted images, as ROS's
    /// CameraInfo and OpenCV give them: pixel centres at whole coordinates.
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// Rows of the rotation that takes a direction in the camera's optical frame (z
    /// forward, x right, y down) into the range sensor's frame (x forward, y left, z up).
    pub rotation: [[f64; 3]; 3],
    /// The camera's optical centre in the range sensor's frame (m).
    pub translation_m: [f64; 3],
}

/// What `reference.csv` holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Reference {
    pub kind: ReferenceKind,
    /// The point of the vehicle its positions describe.
    pub point: ReferencePoint,
}

/// Ground truth shares the estimate's frame; GPS has its own, so scoring first aligns the
/// estimate to it (a rigid 2-D fit).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ReferenceKind {
    GroundTruth,
    Gps,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ReferencePoint {
    /// The vehicle frame's origin (the robot's base; a car's rear axle centre).
    Vehicle,
    /// The range sensor (Victoria Park's GPS is compared with the laser's path).
    Sensor,
}

impl Camera {
    fn validate(&self) -> Result<(), (String, String)> {
        for (name, v) in [("width", self.width), ("height", self.height)] {
            if v == 0 {
                return Err((format!("camera.{name}"), "must be at least 1 pixel".into()));
            }
        }
        for (name, v) in [("fx", self.fx), ("fy", self.fy)] {
            if !(v.is_finite() && v > 0.0) {
                return Err((format!("camera.{name}"), format!("must be finite and positive, got {v}")));
            }
            // Ten million pixels see 0.004 degrees across a 640-pixel image: a focal length
            // in another unit, not a lens.
            if v > MAX_FOCAL_LENGTH_PX {
                return Err((format!("camera.{name}"), format!("{v:e} pixels: at most {MAX_FOCAL_LENGTH_PX:e}")));
            }
        }
        for (name, v) in [("cx", self.cx), ("cy", self.cy)] {
            if !v.is_finite() {
                return Err((format!("camera.{name}"), format!("must be finite, got {v}")));
            }
        }
        if let Some(v) = self.translation_m.iter().find(|v| !v.is_finite()) {
            return Err(("camera.translation_m".into(), format!("must be finite, got {v}")));
        }
        // As far from the laser as a sensor from the vehicle: farther is another unit.
        if let Some(v) = self.translation_m.iter().find(|v| v.abs() > MAX_SENSOR_OFFSET_M) {
            return Err((
                "camera.translation_m".into(),
                format!("{v:e} m from the laser: at most {MAX_SENSOR_OFFSET_M} m (metres, not millimetres)"),
            ));
        }
        let r = &self.rotation;
        if let Some(v) = r.iter().flatten().find(|v| !v.is_finite()) {
            return Err(("camera.rotation".into(), format!("must be finite, got {v}")));
        }
        // Orthonormal with determinant +1, to a tolerance that matrices printed to six
        // decimals meet (their rows' products are off by up to about 3e-6); 1e-5 turns a
        // direction by at most 0.0006 degrees.
        let mut worst: f64 = 0.0;
        for a in 0..3 {
            for b in 0..3 {
                let dot: f64 = (0..3).map(|k| r[a][k] * r[b][k]).sum();
                worst = worst.max((dot - if a == b { 1.0 } else { 0.0 }).abs());
            }
        }
        let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1]) - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
            + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
        if !(worst < 1e-5 && det > 0.0) {
            return Err((
                "camera.rotation".into(),
                format!(
                    "must be a rotation (orthonormal rows, determinant +1); rows' dot products are off by {worst:.2e}, the determinant is {det:.6}"
                ),
            ));
        }
        Ok(())
    }
}

/// How far the pipeline's pixel coordinates run ahead of the manifest's: ROS and OpenCV
/// put a pixel's centre at whole coordinates, the pipeline at half-integers.
const ROS_PIXEL_OFFSET: f64 = 0.5;

/// Farthest a sensor may sit from the vehicle's reference point (m), per axis: longer than
/// any road vehicle (Victoria Park's laser is 3.78 m ahead of the rear axle).
pub const MAX_SENSOR_OFFSET_M: f64 = 50.0;

/// Largest focal length a camera may have, in pixels.
pub const MAX_FOCAL_LENGTH_PX: f64 = 1e7;

impl Manifest {
    /// The first fact that makes no sense, as (field, problem).
    pub fn validate(&self) -> Result<(), (String, String)> {
        if self.format_version != 1 {
            return Err((
                "format_version".into(),
                format!("this objslam reads version 1, the file is version {}", self.format_version),
            ));
        }
        match self.vehicle.motion.as_str() {
            "odometry" => {
                for (name, v) in
                    [("wheelbase_m", self.vehicle.wheelbase_m), ("encoder_offset_m", self.vehicle.encoder_offset_m)]
                {
                    if v.is_some() {
                        return Err((format!("vehicle.{name}"), "only applies with motion = \"ackermann\"".into()));
                    }
                }
            }
            "ackermann" => {
                let Some(wheelbase) = self.vehicle.wheelbase_m else {
                    return Err(("vehicle.wheelbase_m".into(), "is needed with motion = \"ackermann\"".into()));
                };
                if !(wheelbase.is_finite() && wheelbase > 0.0) {
                    return Err((
                        "vehicle.wheelbase_m".into(),
                        format!("must be finite and positive, got {wheelbase}"),
                    ));
                }
                // Like the sensor's offset: longer than any vehicle is millimetres for metres.
                if wheelbase > MAX_SENSOR_OFFSET_M {
                    return Err((
                        "vehicle.wheelbase_m".into(),
                        format!("{wheelbase} m: at most {MAX_SENSOR_OFFSET_M} m (metres, not millimetres)"),
                    ));
                }
                let offset = self.vehicle.encoder_offset_m.unwrap_or(0.0);
                if !(offset.is_finite() && offset.abs() < wheelbase) {
                    return Err((
                        "vehicle.encoder_offset_m".into(),
                        format!("must be finite and smaller than the wheelbase, got {offset}"),
                    ));
                }
            }
            other => {
                return Err((
                    "vehicle.motion".into(),
                    format!("must be \"odometry\" or \"ackermann\", got \"{other}\""),
                ));
            }
        }
        if let Some((i, v)) = self.vehicle.start_pose.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err((format!("vehicle.start_pose[{i}]"), format!("must be finite, got {v}")));
        }
        // On Earth, as reference positions are: 1e15 m had cost the filter its precision.
        let max = crate::format::MAX_COORDINATE_M;
        if let Some((i, v)) = self.vehicle.start_pose[..2].iter().enumerate().find(|(_, v)| v.abs() > max) {
            return Err((format!("vehicle.start_pose[{i}]"), format!("{v:e} m lies beyond {max:e} m")));
        }
        for (name, v) in [("x_m", self.sensor.x_m), ("y_m", self.sensor.y_m), ("yaw_rad", self.sensor.yaw_rad)] {
            if !v.is_finite() {
                return Err((format!("sensor.{name}"), format!("must be finite, got {v}")));
            }
        }
        // A sensor is on the vehicle: a mounting further off than a vehicle is long is a
        // unit mistake (millimetres for metres).
        for (name, v) in [("x_m", self.sensor.x_m), ("y_m", self.sensor.y_m)] {
            if v.abs() > MAX_SENSOR_OFFSET_M {
                return Err((
                    format!("sensor.{name}"),
                    format!(
                        "{v:e} m from the vehicle's reference point: at most {MAX_SENSOR_OFFSET_M} m (metres, not millimetres)"
                    ),
                ));
            }
        }
        // Beyond a turn either way an angle is a unit mistake (degrees for radians).
        let turn = std::f64::consts::TAU;
        for (name, v) in
            [("vehicle.start_pose[2]", self.vehicle.start_pose[2]), ("sensor.yaw_rad", self.sensor.yaw_rad)]
        {
            if v.abs() > turn {
                return Err((name.into(), format!("must be within a turn (radians, not degrees), got {v}")));
            }
        }
        // The filter divides by the noise at any range: the range and bearing terms must be
        // positive; the per-metre term adds to the range term and may be zero.
        for (name, v, zero_allowed) in [
            ("range_sigma_m", self.sensor.range_sigma_m, false),
            ("range_sigma_per_m", self.sensor.range_sigma_per_m, true),
            ("bearing_sigma_rad", self.sensor.bearing_sigma_rad, false),
        ] {
            if let Some(v) = v
                && !(v.is_finite() && (v > 0.0 || (zero_allowed && v == 0.0)))
            {
                let what = if zero_allowed { "finite and not negative" } else { "finite and positive" };
                return Err((format!("sensor.{name}"), format!("must be {what}, got {v}")));
            }
            // As the filter's observation model bounds it (its square must not overflow), but
            // named here, in the manifest (the bearing's tighter bound follows).
            if let Some(v) = v.filter(|v| name != "bearing_sigma_rad" && *v > slam::settings::MAX_SIGMA) {
                return Err((
                    format!("sensor.{name}"),
                    format!("must be at most {:e}, got {v:e}", slam::settings::MAX_SIGMA),
                ));
            }
        }
        // As the filter's observation model checks it, but named here, in the manifest.
        if let Some(v) = self.sensor.bearing_sigma_rad.filter(|v| *v > std::f64::consts::PI) {
            return Err((
                "sensor.bearing_sigma_rad".into(),
                format!("must be at most pi (radians, not degrees), got {v:e}"),
            ));
        }
        if let Some(l) = &self.laser {
            // Beyond a turn either way an angle is a unit mistake (degrees for radians).
            let turn = std::f64::consts::TAU;
            if !(l.angle_min_rad.is_finite() && l.angle_min_rad.abs() <= turn) {
                return Err((
                    "laser.angle_min_rad".into(),
                    format!("must be finite and within a turn (radians), got {}", l.angle_min_rad),
                ));
            }
            if !(l.angle_increment_rad.is_finite()
                && l.angle_increment_rad != 0.0
                && l.angle_increment_rad.abs() <= turn)
            {
                return Err((
                    "laser.angle_increment_rad".into(),
                    format!("must be finite, not zero and within a turn (radians), got {}", l.angle_increment_rad),
                ));
            }
            if !(l.range_min_m.is_finite() && l.range_min_m >= 0.0) {
                return Err((
                    "laser.range_min_m".into(),
                    format!("must be finite and not negative, got {}", l.range_min_m),
                ));
            }
            if !(l.range_max_m > l.range_min_m && l.range_max_m.is_finite()) {
                return Err((
                    "laser.range_max_m".into(),
                    format!("must be finite and above range_min_m ({}), got {}", l.range_min_m, l.range_max_m),
                ));
            }
        }
        if let Some(c) = &self.camera {
            c.validate()?;
        }
        Ok(())
    }

    /// The camera as the pipeline's segmentation sees it. The pipeline takes laser returns
    /// in the vehicle's heading (a replay turns them by the sensor's yaw), so the camera's
    /// pose is turned with them.
    pub fn camera_geometry(&self) -> Option<slam::segmentation::CameraGeometry> {
        let c = self.camera.as_ref()?;
        let (s, co) = self.sensor.yaw_rad.sin_cos();
        let yaw = [[co, -s, 0.0], [s, co, 0.0], [0.0, 0.0, 1.0]];
        let turn = |v: [f64; 3]| -> [f64; 3] { std::array::from_fn(|r| (0..3).map(|k| yaw[r][k] * v[k]).sum()) };
        let phi: [[f64; 3]; 3] =
            std::array::from_fn(|r| std::array::from_fn(|col| (0..3).map(|k| yaw[r][k] * c.rotation[k][col]).sum()));
        Some(slam::segmentation::CameraGeometry {
            fx: c.fx,
            fy: c.fy,
            // The pipeline puts pixel centres at half-integers.
            cx: c.cx + ROS_PIXEL_OFFSET,
            cy: c.cy + ROS_PIXEL_OFFSET,
            width: c.width,
            height: c.height,
            laser_from_camera: slam::calibration::Extrinsics { phi, delta: turn(c.translation_m) },
        })
    }

    /// The sensor as the filter's observation model: mounting from here, noise from here
    /// where given, else from `defaults`.
    pub fn observation_model(&self, defaults: &slam::ekf::RangeBearingModel) -> slam::ekf::RangeBearingModel {
        slam::ekf::RangeBearingModel {
            mount_x: self.sensor.x_m,
            mount_y: self.sensor.y_m,
            range_sigma_m: self.sensor.range_sigma_m.unwrap_or(defaults.range_sigma_m),
            range_sigma_per_m: self.sensor.range_sigma_per_m.unwrap_or(defaults.range_sigma_per_m),
            bearing_sigma_rad: self.sensor.bearing_sigma_rad.unwrap_or(defaults.bearing_sigma_rad),
        }
    }
}
