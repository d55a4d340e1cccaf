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
        for (name, v) in [("x_m", self.sensor.x_m), ("y_m", self.sensor.y_m), ("yaw_rad", self.sensor.yaw_rad)] {
            if !v.is_finite() {
                return Err((format!("sensor.{name}"), format!("must be finite, got {v}")));
            }
        }
        for (name, v) in [
            ("range_sigma_m", self.sensor.range_sigma_m),
            ("range_sigma_per_m", self.sensor.range_sigma_per_m),
            ("bearing_sigma_rad", self.sensor.bearing_sigma_rad),
        ] {
            if let Some(v) = v
                && !(v.is_finite() && v >= 0.0)
            {
                return Err((format!("sensor.{name}"), format!("must be finite and not negative, got {v}")));
            }
        }
        if let Some(l) = &self.laser {
            if !l.angle_min_rad.is_finite() {
                return Err(("laser.angle_min_rad".into(), format!("must be finite, got {}", l.angle_min_rad)));
            }
            if !(l.angle_increment_rad.is_finite() && l.angle_increment_rad != 0.0) {
                return Err(("laser.angle_increment_rad".into(), "must be finite and not zero".into()));
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
        Ok(())
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
