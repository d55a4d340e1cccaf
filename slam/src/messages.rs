//! Plain sensor inputs, as a real robot delivers them (SI units, REP-103 frames).

use serde::{Deserialize, Serialize};

/// A 2-D laser scan like ROS `sensor_msgs/LaserScan`: beam i points at
/// `angle_min + i * angle_increment` in the laser frame; a range outside
/// [`range_min`, `range_max`] or not finite is no return.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LaserScan {
    pub t: f64,
    pub angle_min: f64,
    pub angle_increment: f64,
    pub range_min: f64,
    pub range_max: f64,
    pub ranges: Vec<f64>,
}

impl LaserScan {
    /// Whether the scan's angles and range limits describe beams: finite angles, a step
    /// that is not zero, `0 <= range_min <= range_max` (`range_max` may be infinite).
    pub fn check(&self) -> Result<(), String> {
        if !(self.angle_min.is_finite() && self.angle_increment.is_finite()) || self.angle_increment == 0.0 {
            return Err(format!(
                "angle_min {} and angle_increment {}: the angles must be finite and the increment not zero",
                self.angle_min, self.angle_increment
            ));
        }
        if !(self.range_min >= 0.0 && self.range_min.is_finite() && self.range_max >= self.range_min) {
            return Err(format!(
                "range_min {} and range_max {}: need 0 <= range_min <= range_max",
                self.range_min, self.range_max
            ));
        }
        Ok(())
    }

    /// Whether beam `i` returned a valid range (a beam past the scan's last did not).
    pub fn valid(&self, i: usize) -> bool {
        self.ranges.get(i).is_some_and(|&r| r.is_finite() && r >= self.range_min && r <= self.range_max)
    }

    pub fn angle(&self, i: usize) -> f64 {
        self.angle_min + self.angle_increment * i as f64
    }

    /// Beam i's end point in the laser frame; `None` past the scan's last beam (see
    /// [`BEAM`]).
    pub fn point(&self, i: usize) -> Option<[f64; 2]> {
        let r = *self.ranges.get(i)?;
        let (s, c) = self.angle(i).sin_cos();
        Some([r * c, r * s])
    }
}

/// Why a beam index the library took from a scan's own range is one of its beams.
pub(crate) const BEAM: &str = "an index below the scan's beam count";

/// Wheel odometry: motion since the previous message in the robot frame at that message.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OdometryIncrement {
    pub t: f64,
    pub dx: f64,
    pub dy: f64,
    pub dtheta: f64,
}

/// A vehicle's control, held until the next input: what a car's CAN bus or a
/// differential drive's controller reports, where no odometry increments exist.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Control {
    /// Forward speed (m/s) and turn rate (rad/s), for the `odometry` motion model.
    Differential { v: f64, omega: f64 },
    /// Speed (m/s) and steering angle (rad, positive left), for the `ackermann` model.
    Ackermann { speed: f64, steering: f64 },
}

/// A point feature extracted from a scan by the robot's own detector: range (m) and
/// bearing (rad, counter-clockwise from the sensor's forward axis, REP-103) from the
/// sensor, and the object's diameter (m) where the detector measures one.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Detection {
    pub range_m: f64,
    pub bearing_rad: f64,
    pub diameter_m: Option<f64>,
}

impl Detection {
    /// The detection as the pipeline's cluster (index `k` stands for its beams; no points;
    /// an unknown diameter is NaN).
    pub fn as_cluster(&self, k: usize) -> crate::clustering::Cluster {
        let (s, c) = self.bearing_rad.sin_cos();
        crate::clustering::Cluster {
            first_beam: k,
            last_beam: k,
            points: Vec::new(),
            centre: [self.range_m * c, self.range_m * s],
            diameter_m: self.diameter_m.unwrap_or(f64::NAN),
            range_m: self.range_m,
            bearing_rad: self.bearing_rad,
            occluded: false,
        }
    }
}

/// Wraps an angle to (-pi, pi].
pub fn wrap_angle(a: f64) -> f64 {
    let mut a = a.rem_euclid(std::f64::consts::TAU);
    if a > std::f64::consts::PI {
        a -= std::f64::consts::TAU;
    }
    a
}
