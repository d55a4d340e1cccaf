//! Simulator settings, with the published facts of the sensors and robot (SICK LMS2xx,
//! Pioneer 2-AT) as defaults, and their checks.

use serde::{Deserialize, Serialize};

use crate::SimError;

/// Everything the simulator needs besides the world and the seed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// Fixed physics rate. Sensor messages are stamped with the first physics step at or
    /// after their nominal time, so timestamps jitter by less than one physics period.
    pub physics_rate_hz: f64,
    pub robot: RobotConfig,
    pub laser: LaserConfig,
    pub odometry: OdometryConfig,
    pub camera: crate::camera_model::CameraConfig,
    /// Stop after this much simulated time even if the route is not finished.
    pub max_duration_s: Option<f64>,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            physics_rate_hz: 100.0,
            robot: RobotConfig::default(),
            laser: LaserConfig::default(),
            odometry: OdometryConfig::default(),
            camera: crate::camera_model::CameraConfig::default(),
            max_duration_s: None,
        }
    }
}

/// The Pioneer 2-AT's top speed (m/s) and turn rate (deg/s), from ARIA's p2at.p.
pub const PIONEER_MAX_SPEED_MPS: f64 = 1.2;
pub const PIONEER_MAX_TURN_RATE_DPS: f64 = 300.0;

/// The Pioneer 2-AT (ARIA p2at.p) and its path-following controller.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobotConfig {
    /// Body length x width (m).
    pub length_m: f64,
    pub width_m: f64,
    pub body_height_m: f64,
    pub max_speed_mps: f64,
    /// Turn rate limit of the path follower (deg/s); the default is 1.5 rad/s exactly.
    pub max_turn_rate_dps: f64,
    pub cruise_speed_mps: f64,
    /// Pure-pursuit look-ahead distance.
    pub lookahead_m: f64,
    /// Stop while something ahead is closer than this to the robot's front (people
    /// crossing): the laser, mounted behind the front, sees it that much further away.
    pub safety_stop_m: f64,
}

impl Default for RobotConfig {
    fn default() -> Self {
        RobotConfig {
            length_m: 0.626,
            width_m: 0.505,
            body_height_m: 0.28,
            max_speed_mps: 1.2,
            max_turn_rate_dps: 85.94366926962348,
            cruise_speed_mps: 0.5,
            lookahead_m: 0.8,
            safety_stop_m: 0.7,
        }
    }
}

/// Resolution of a SICK LMS2xx scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum AngularResolution {
    #[serde(rename = "0.25")]
    Quarter,
    #[serde(rename = "0.5")]
    Half,
    #[serde(rename = "1")]
    One,
}

impl AngularResolution {
    pub fn degrees(self) -> f64 {
        match self {
            AngularResolution::Quarter => 0.25,
            AngularResolution::Half => 0.5,
            AngularResolution::One => 1.0,
        }
    }
}

/// A SICK LMS-style 2-D laser.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LaserConfig {
    pub fov_deg: f64,
    pub resolution_deg: AngularResolution,
    /// 8, 16 or 32 m (mm units) or 80 m (cm units), as the LMS2xx range modes.
    pub max_range_m: f64,
    pub min_range_m: f64,
    pub range_noise_sigma_m: f64,
    pub rate_hz: f64,
    /// Mounting on the robot (base frame, REP-103): forward, left, height.
    pub mount_xyz_m: [f64; 3],
    pub mount_yaw_deg: f64,
}

impl Default for LaserConfig {
    fn default() -> Self {
        LaserConfig {
            fov_deg: 180.0,
            resolution_deg: AngularResolution::Half,
            max_range_m: 80.0,
            min_range_m: 0.05,
            range_noise_sigma_m: 0.01,
            rate_hz: 10.0,
            mount_xyz_m: [0.16, 0.0, 0.4],
            mount_yaw_deg: 0.0,
        }
    }
}

impl LaserConfig {
    pub fn beam_count(&self) -> usize {
        (self.fov_deg / self.resolution_deg.degrees()).round() as usize + 1
    }

    pub fn angle_min_rad(&self) -> f64 {
        -self.fov_deg.to_radians() / 2.0
    }

    pub fn angle_increment_rad(&self) -> f64 {
        self.resolution_deg.degrees().to_radians()
    }

    /// Range quantisation of the unit: millimetres up to 32 m, centimetres in 80 m mode.
    pub fn quantum_m(&self) -> f64 {
        if self.max_range_m > 32.0 { 0.01 } else { 0.001 }
    }
}

/// Wheel odometry and its error model.
///
/// Per run, systematic errors are drawn once (as Stage does): a distance scale error
/// `N(0, scale_sigma)`, a turn scale error `N(0, turn_scale_sigma)` and a heading drift per
/// metre `N(0, bias_sigma_rad_per_m)`. Per step, Gaussian noise grows with the step's
/// distance d and turn a: sigma_d^2 = a_dd d^2 + a_da a^2, sigma_a^2 = a_ad d^2 + a_aa a^2,
/// spelled as the filter's odometry model spells them (`[pipeline.motion]`), so one
/// scenario can state the truth and the filter's belief side by side. Files written with
/// the former spelling (`k_dd`, ...) still read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OdometryConfig {
    pub rate_hz: f64,
    pub scale_sigma: f64,
    pub turn_scale_sigma: f64,
    pub bias_sigma_rad_per_m: f64,
    /// Per-step noise coefficients (variance per squared metre / radian).
    #[serde(alias = "k_dd")]
    pub a_dd: f64,
    #[serde(alias = "k_da")]
    pub a_da: f64,
    #[serde(alias = "k_ad")]
    pub a_ad: f64,
    #[serde(alias = "k_aa")]
    pub a_aa: f64,
}

impl Default for OdometryConfig {
    fn default() -> Self {
        OdometryConfig {
            rate_hz: 20.0,
            scale_sigma: 0.01,
            turn_scale_sigma: 0.02,
            bias_sigma_rad_per_m: 0.002,
            a_dd: 0.0025,
            a_da: 0.0001,
            a_ad: 0.0005,
            a_aa: 0.0025,
        }
    }
}

impl OdometryConfig {
    /// The per-step coefficients' former names (serde aliases) and today's.
    pub const FORMER_SPELLINGS: [(&'static str, &'static str); 4] =
        [("k_dd", "a_dd"), ("k_da", "a_da"), ("k_ad", "a_ad"), ("k_aa", "a_aa")];

    /// No error at all: integrates to the ground-truth path.
    pub fn noiseless() -> Self {
        OdometryConfig {
            scale_sigma: 0.0,
            turn_scale_sigma: 0.0,
            bias_sigma_rad_per_m: 0.0,
            a_dd: 0.0,
            a_da: 0.0,
            a_ad: 0.0,
            a_aa: 0.0,
            ..Default::default()
        }
    }
}

/// Fastest physics step rate a simulation may be set to.
pub const MAX_PHYSICS_RATE_HZ: f64 = 10_000.0;

/// Largest body of the simulated robot, each dimension.
pub const MAX_ROBOT_SIZE_M: f64 = 5.0;

impl SimConfig {
    /// Checks every setting; the error names the field.
    pub fn check(&self) -> Result<(), SimError> {
        let bad = |field: &str, message: String| Err(SimError::Config { field: field.into(), message });
        let positive = [
            ("physics_rate_hz", self.physics_rate_hz),
            ("laser.rate_hz", self.laser.rate_hz),
            ("laser.fov_deg", self.laser.fov_deg),
            ("laser.max_range_m", self.laser.max_range_m),
            ("odometry.rate_hz", self.odometry.rate_hz),
            ("robot.length_m", self.robot.length_m),
            ("robot.width_m", self.robot.width_m),
            ("robot.body_height_m", self.robot.body_height_m),
            ("robot.max_speed_mps", self.robot.max_speed_mps),
            ("robot.max_turn_rate_dps", self.robot.max_turn_rate_dps),
            ("robot.cruise_speed_mps", self.robot.cruise_speed_mps),
            ("robot.lookahead_m", self.robot.lookahead_m),
        ];
        for (field, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return bad(field, format!("must be finite and positive, got {v}"));
            }
        }
        let non_negative = [
            ("laser.min_range_m", self.laser.min_range_m),
            ("laser.range_noise_sigma_m", self.laser.range_noise_sigma_m),
            ("robot.safety_stop_m", self.robot.safety_stop_m),
            ("odometry.scale_sigma", self.odometry.scale_sigma),
            ("odometry.turn_scale_sigma", self.odometry.turn_scale_sigma),
            ("odometry.bias_sigma_rad_per_m", self.odometry.bias_sigma_rad_per_m),
            ("odometry.a_dd", self.odometry.a_dd),
            ("odometry.a_da", self.odometry.a_da),
            ("odometry.a_ad", self.odometry.a_ad),
            ("odometry.a_aa", self.odometry.a_aa),
        ];
        for (field, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return bad(field, format!("must be finite and not negative, got {v}"));
            }
        }
        // Rapier's contacts are stable from about 60 Hz; past a few kHz a run only burns time
        // (1e7 Hz would take days for the park's loop).
        if self.physics_rate_hz > MAX_PHYSICS_RATE_HZ {
            return bad(
                "physics_rate_hz",
                format!("must be at most {MAX_PHYSICS_RATE_HZ} Hz, got {}", self.physics_rate_hz),
            );
        }
        // Named by the sensor's key, as the camera's is: that is the setting a user raised.
        for (field, rate) in [("laser.rate_hz", self.laser.rate_hz), ("odometry.rate_hz", self.odometry.rate_hz)] {
            if rate > self.physics_rate_hz {
                return bad(
                    field,
                    format!(
                        "{rate} Hz is faster than physics (physics_rate_hz {} Hz); sensors cannot outpace it",
                        self.physics_rate_hz
                    ),
                );
            }
        }
        if ![8.0, 16.0, 32.0, 80.0].contains(&self.laser.max_range_m) {
            return bad(
                "laser.max_range_m",
                format!("the LMS2xx range modes are 8, 16, 32 and 80 m, got {}", self.laser.max_range_m),
            );
        }
        if self.laser.fov_deg > 180.0 {
            return bad("laser.fov_deg", format!("an LMS2xx sees at most 180 deg, got {}", self.laser.fov_deg));
        }
        if self.laser.beam_count() < 2 {
            return bad("laser.fov_deg", "fewer than 2 beams".into());
        }
        // The beams span the field of view from edge to edge, a whole number of steps apart:
        // another field of view would be rounded to one, and the scan not centred.
        let steps = self.laser.fov_deg / self.laser.resolution_deg.degrees();
        if (steps - steps.round()).abs() > 1e-6 {
            return bad(
                "laser.fov_deg",
                format!(
                    "{} deg is not a whole number of {} deg steps",
                    self.laser.fov_deg,
                    self.laser.resolution_deg.degrees()
                ),
            );
        }
        // A Pioneer-class ground robot: a body of metres is another vehicle, or a typo (1e300
        // m left the f32 physics unable to move it).
        for (field, v) in [
            ("robot.length_m", self.robot.length_m),
            ("robot.width_m", self.robot.width_m),
            ("robot.body_height_m", self.robot.body_height_m),
        ] {
            if v > MAX_ROBOT_SIZE_M {
                return bad(field, format!("at most {MAX_ROBOT_SIZE_M} m for the simulated ground robot, got {v}"));
            }
        }
        // The stop watches the laser's returns: beyond its range it would see an obstacle in
        // every beam without one and never drive.
        if self.robot.safety_stop_m >= self.laser.max_range_m {
            return bad(
                "robot.safety_stop_m",
                format!(
                    "{} m is not within the laser's range ({} m), which it watches",
                    self.robot.safety_stop_m, self.laser.max_range_m
                ),
            );
        }
        if self.laser.min_range_m >= self.laser.max_range_m {
            return bad("laser.min_range_m", "must be below max_range_m".into());
        }
        // The robot is a Pioneer 2-AT (ARIA's p2at.p): up to 1.2 m/s and 300 deg/s. More is
        // another robot, or a typo, and makes the follower turn on the spot bang-bang.
        if self.robot.max_turn_rate_dps > PIONEER_MAX_TURN_RATE_DPS {
            return bad(
                "robot.max_turn_rate_dps",
                format!(
                    "must be at most the Pioneer 2-AT's {PIONEER_MAX_TURN_RATE_DPS} deg/s, got {}",
                    self.robot.max_turn_rate_dps
                ),
            );
        }
        if self.robot.max_speed_mps > PIONEER_MAX_SPEED_MPS {
            return bad(
                "robot.max_speed_mps",
                format!(
                    "must be at most the Pioneer 2-AT's {PIONEER_MAX_SPEED_MPS} m/s, got {}",
                    self.robot.max_speed_mps
                ),
            );
        }
        if self.robot.cruise_speed_mps > self.robot.max_speed_mps {
            return bad("robot.cruise_speed_mps", format!("exceeds max_speed_mps {}", self.robot.max_speed_mps));
        }
        if let Err((field, message)) = self.camera.check() {
            return bad(&format!("camera.{field}"), message);
        }
        let laser = &self.laser;
        if !laser.mount_xyz_m.iter().all(|v| v.is_finite()) || laser.mount_xyz_m[2] <= 0.0 {
            return bad(
                "laser.mount_xyz_m",
                format!("must be finite, with z above the ground, got {:?}", laser.mount_xyz_m),
            );
        }
        if !(laser.mount_yaw_deg.abs() <= 180.0) {
            return bad("laser.mount_yaw_deg", format!("must be within +-180 deg, got {}", laser.mount_yaw_deg));
        }
        if self.camera.rate_hz > self.physics_rate_hz {
            return bad("camera.rate_hz", format!("{} Hz is faster than physics", self.camera.rate_hz));
        }
        if let Some(d) = self.max_duration_s
            && !(d.is_finite() && d > 0.0)
        {
            return bad("max_duration_s", format!("must be finite and positive, got {d}"));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The per-step coefficients read under the filter's spelling and the former one, not
    /// under both at once.
    #[test]
    fn odometry_coefficients_read_under_either_spelling() {
        let new: OdometryConfig = toml::from_str("a_dd = 0.1\na_aa = 0.2\n").unwrap();
        let old: OdometryConfig = toml::from_str("k_dd = 0.1\nk_aa = 0.2\n").unwrap();
        assert_eq!(new, old);
        assert_eq!((new.a_dd, new.a_aa, new.a_da), (0.1, 0.2, OdometryConfig::default().a_da));
        assert!(toml::from_str::<OdometryConfig>("a_dd = 0.1\nk_dd = 0.1\n").is_err());
    }
}
