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
    /// Whether beam `i` returned a valid range.
    pub fn valid(&self, i: usize) -> bool {
        let r = self.ranges[i];
        r.is_finite() && r >= self.range_min && r <= self.range_max
    }

    pub fn angle(&self, i: usize) -> f64 {
        self.angle_min + self.angle_increment * i as f64
    }

    /// Beam i's end point in the laser frame.
    pub fn point(&self, i: usize) -> [f64; 2] {
        let (s, c) = self.angle(i).sin_cos();
        [self.ranges[i] * c, self.ranges[i] * s]
    }
}

/// Wheel odometry: motion since the previous message in the robot frame at that message.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OdometryIncrement {
    pub t: f64,
    pub dx: f64,
    pub dy: f64,
    pub dtheta: f64,
}

/// Wraps an angle to (-pi, pi].
pub fn wrap_angle(a: f64) -> f64 {
    let mut a = a.rem_euclid(std::f64::consts::TAU);
    if a > std::f64::consts::PI {
        a -= std::f64::consts::TAU;
    }
    a
}
