//! Range-bearing observation of point landmarks by a sensor mounted on the robot.

use nalgebra::{Matrix2, Matrix2x3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::messages::wrap_angle;

/// A range-bearing sensor at `(mount_x, mount_y)` in the robot frame, bearings measured
/// from the robot's heading. The range noise may grow with range (`range_sigma_per_m`): a
/// tree's centre from a circle fit at 40 m is worse than at 4 m, as the beams spread.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RangeBearingModel {
    pub mount_x: f64,
    pub mount_y: f64,
    pub range_sigma_m: f64,
    /// Added to `range_sigma_m` per metre of range.
    pub range_sigma_per_m: f64,
    pub bearing_sigma_rad: f64,
}

impl Default for RangeBearingModel {
    fn default() -> Self {
        // Cluster centres are noisier than single beams: a few centimetres and about a
        // degree, covering the circle fit and the laser's angular resolution.
        RangeBearingModel {
            mount_x: 0.16,
            mount_y: 0.0,
            range_sigma_m: 0.05,
            range_sigma_per_m: 0.0,
            bearing_sigma_rad: 1.0f64.to_radians(),
        }
    }
}

impl RangeBearingModel {
    /// The first setting that makes no sense, as (field, problem): a zero sigma makes the
    /// filter certain of every observation, so its gates and consistency break.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        for (name, v) in [("mount_x", self.mount_x), ("mount_y", self.mount_y)] {
            if !v.is_finite() {
                return Err((name, format!("must be finite, got {v}")));
            }
        }
        for (name, v) in [("range_sigma_m", self.range_sigma_m), ("bearing_sigma_rad", self.bearing_sigma_rad)] {
            if !(v.is_finite() && v > 0.0) {
                return Err((name, format!("must be finite and positive, got {v}")));
            }
        }
        // A bearing error of more than half a turn says nothing: degrees given for radians.
        if self.bearing_sigma_rad > std::f64::consts::PI {
            return Err((
                "bearing_sigma_rad",
                format!("must be at most pi (radians, not degrees), got {}", self.bearing_sigma_rad),
            ));
        }
        if !(self.range_sigma_per_m.is_finite() && self.range_sigma_per_m >= 0.0) {
            return Err((
                "range_sigma_per_m",
                format!("must be finite and not negative, got {}", self.range_sigma_per_m),
            ));
        }
        for (name, v) in [("range_sigma_m", self.range_sigma_m), ("range_sigma_per_m", self.range_sigma_per_m)] {
            if v > crate::settings::MAX_SIGMA {
                return Err((name, format!("must be at most {:e}, got {v}", crate::settings::MAX_SIGMA)));
            }
        }
        Ok(())
    }

    /// The observation noise of a landmark at `range_m`.
    pub fn noise_at(&self, range_m: f64) -> Matrix2<f64> {
        let sigma_r = self.range_sigma_m + self.range_sigma_per_m * range_m.abs();
        Matrix2::new(sigma_r * sigma_r, 0.0, 0.0, self.bearing_sigma_rad.powi(2))
    }

    fn sensor(&self, pose: &Vector3<f64>) -> (f64, f64) {
        let (s, c) = pose.z.sin_cos();
        (pose.x + c * self.mount_x - s * self.mount_y, pose.y + s * self.mount_x + c * self.mount_y)
    }

    /// Predicted (range, bearing) of landmark `l` and the Jacobians with respect to the
    /// robot pose (2x3) and the landmark (2x2).
    pub fn observe(&self, pose: &Vector3<f64>, l: &Vector2<f64>) -> (Vector2<f64>, Matrix2x3<f64>, Matrix2<f64>) {
        let (sx, sy) = self.sensor(pose);
        let (dx, dy) = (l.x - sx, l.y - sy);
        let q = (dx * dx + dy * dy).max(1e-12);
        let r = q.sqrt();
        let z = Vector2::new(r, wrap_angle(dy.atan2(dx) - pose.z));
        let (s, c) = pose.z.sin_cos();
        // d(sensor)/d(theta)
        let dsx = -s * self.mount_x - c * self.mount_y;
        let dsy = c * self.mount_x - s * self.mount_y;
        let hl = Matrix2::new(dx / r, dy / r, -dy / q, dx / q);
        let hr = Matrix2x3::new(
            -dx / r,
            -dy / r,
            -(dx * dsx + dy * dsy) / r,
            dy / q,
            -dx / q,
            (dy * dsx - dx * dsy) / q - 1.0,
        );
        (z, hr, hl)
    }

    /// Landmark position from an observation, with Jacobians w.r.t. pose (2x3) and z (2x2).
    pub fn inverse(&self, pose: &Vector3<f64>, z: &Vector2<f64>) -> (Vector2<f64>, Matrix2x3<f64>, Matrix2<f64>) {
        let (sx, sy) = self.sensor(pose);
        let a = pose.z + z.y;
        let (sa, ca) = a.sin_cos();
        let l = Vector2::new(sx + z.x * ca, sy + z.x * sa);
        let (s, c) = pose.z.sin_cos();
        let dsx = -s * self.mount_x - c * self.mount_y;
        let dsy = c * self.mount_x - s * self.mount_y;
        let gr = Matrix2x3::new(1.0, 0.0, dsx - z.x * sa, 0.0, 1.0, dsy + z.x * ca);
        let gz = Matrix2::new(ca, -z.x * sa, sa, z.x * ca);
        (l, gr, gz)
    }
}
