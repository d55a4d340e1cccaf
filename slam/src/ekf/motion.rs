//! Vehicle motion models for the EKF prediction: the Pioneer's wheel odometry, and an
//! Ackermann model for car-like platforms (outdoor data sets such as Victoria Park).

use nalgebra::{Matrix3, Matrix3x2, Vector3};

use crate::messages::wrap_angle;

/// A motion model: the predicted pose, its Jacobian with respect to the pose, and the
/// process noise in pose space.
pub trait MotionModel: Send + Sync {
    /// Control input dimension (documentation; controls are slices).
    fn control_dims(&self) -> usize;
    /// Returns (predicted pose, F = d pose'/d pose, Q = process noise covariance).
    fn predict(&self, pose: &Vector3<f64>, control: &[f64]) -> (Vector3<f64>, Matrix3<f64>, Matrix3<f64>);
}

/// Incremental odometry (dx, dy, dtheta) in the robot frame, with noise growing with the
/// increment: sigma_d² = a_dd d² + d_per_m |d|, sigma_a² = a_ad d² + a_aa a² + a_per_m |d|
/// + a_per_rad |a| (+ a_da a² on the distance, + floor on both).
///
/// The `*_per_m` and `a_per_rad` terms are random walks standing in for a wheel odometry's
/// calibration errors (wheel scale, turn scale, heading bias): those stay fixed over a run,
/// so their variance grows with the square of the distance, which per-step white noise
/// (variance proportional to the step squared, vanishing as the rate rises) cannot follow.
/// A random walk matched over ~20 m between re-observations keeps the filter consistent
/// where trees are sparse.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OdometryMotionModel {
    pub a_dd: f64,
    pub a_da: f64,
    pub a_ad: f64,
    pub a_aa: f64,
    /// Distance variance per metre driven (m²/m).
    pub d_per_m: f64,
    /// Heading variance per metre driven (rad²/m).
    pub a_per_m: f64,
    /// Heading variance per radian turned (rad²/rad).
    pub a_per_rad: f64,
    /// Added to both variances per step so a stationary robot keeps a sane covariance.
    pub floor: f64,
}

impl Default for OdometryMotionModel {
    fn default() -> Self {
        // A little above the simulator's default odometry noise: an EKF fed its exact
        // noise is still optimistic over long runs (linearisation error). The random walks
        // cover the simulator's default calibration errors (1% scale, 2% turn scale,
        // 0.002 rad/m bias) over about 20 m, with a factor 2 of margin.
        OdometryMotionModel { a_dd: 0.005, a_da: 0.0002, a_ad: 0.002, a_aa: 0.005, d_per_m: 0.004, a_per_m: 0.0003, a_per_rad: 0.003, floor: 1e-8 }
    }
}

impl OdometryMotionModel {
    /// White per-step noise only, no calibration random walks: for odometry without
    /// systematic errors (synthetic tests).
    pub fn white(a_dd: f64, a_da: f64, a_ad: f64, a_aa: f64) -> Self {
        OdometryMotionModel { a_dd, a_da, a_ad, a_aa, d_per_m: 0.0, a_per_m: 0.0, a_per_rad: 0.0, floor: 1e-8 }
    }
}

impl MotionModel for OdometryMotionModel {
    fn control_dims(&self) -> usize {
        3
    }

    fn predict(&self, pose: &Vector3<f64>, u: &[f64]) -> (Vector3<f64>, Matrix3<f64>, Matrix3<f64>) {
        let (dx, dy, dth) = (u[0], u[1], u[2]);
        let (s, c) = pose.z.sin_cos();
        let next = Vector3::new(pose.x + c * dx - s * dy, pose.y + s * dx + c * dy, wrap_angle(pose.z + dth));
        let f = Matrix3::new(1.0, 0.0, -s * dx - c * dy, 0.0, 1.0, c * dx - s * dy, 0.0, 0.0, 1.0);
        // Noise on (dx, dy, dtheta) in the robot frame, mapped through G = d pose'/d u.
        let d2 = dx * dx + dy * dy;
        let a2 = dth * dth;
        let (d, a) = (d2.sqrt(), dth.abs());
        let var_d = self.a_dd * d2 + self.a_da * a2 + self.d_per_m * d + self.floor;
        let var_a = self.a_ad * d2 + self.a_aa * a2 + self.a_per_m * d + self.a_per_rad * a + self.floor;
        // Along-track noise on the translation's direction, a small lateral part.
        let m = Matrix3::new(var_d, 0.0, 0.0, 0.0, 0.1 * var_d + self.floor, 0.0, 0.0, 0.0, var_a);
        let g = Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
        (next, f, g * m * g.transpose())
    }
}

/// A car-like vehicle: control (speed m/s, steering angle rad, dt s); rear-axle
/// reference point, wheelbase `wheelbase_m`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AckermannMotionModel {
    pub wheelbase_m: f64,
    pub speed_sigma_mps: f64,
    pub steer_sigma_rad: f64,
}

impl Default for AckermannMotionModel {
    fn default() -> Self {
        AckermannMotionModel { wheelbase_m: 2.83, speed_sigma_mps: 0.2, steer_sigma_rad: 2f64.to_radians() }
    }
}

impl MotionModel for AckermannMotionModel {
    fn control_dims(&self) -> usize {
        3
    }

    fn predict(&self, pose: &Vector3<f64>, u: &[f64]) -> (Vector3<f64>, Matrix3<f64>, Matrix3<f64>) {
        let (v, steer, dt) = (u[0], u[1], u[2]);
        let (s, c) = pose.z.sin_cos();
        let l = self.wheelbase_m;
        let next = Vector3::new(pose.x + v * dt * c, pose.y + v * dt * s, wrap_angle(pose.z + v * dt * steer.tan() / l));
        let f = Matrix3::new(1.0, 0.0, -v * dt * s, 0.0, 1.0, v * dt * c, 0.0, 0.0, 1.0);
        let sec2 = 1.0 / steer.cos().powi(2);
        let g = Matrix3x2::new(dt * c, 0.0, dt * s, 0.0, dt * steer.tan() / l, v * dt * sec2 / l);
        let m = nalgebra::Matrix2::new(self.speed_sigma_mps.powi(2), 0.0, 0.0, self.steer_sigma_rad.powi(2));
        (next, f, g * m * g.transpose() + Matrix3::identity() * 1e-10)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn numeric_f(m: &dyn MotionModel, pose: &Vector3<f64>, u: &[f64]) -> Matrix3<f64> {
        let mut f = Matrix3::zeros();
        for k in 0..3 {
            let h = 1e-6;
            let (mut p, mut q) = (*pose, *pose);
            p[k] += h;
            q[k] -= h;
            let (a, _, _) = m.predict(&p, u);
            let (b, _, _) = m.predict(&q, u);
            let mut d = (a - b) / (2.0 * h);
            d.z = wrap_angle(a.z - b.z) / (2.0 * h);
            f.set_column(k, &d);
        }
        f
    }

    #[test]
    fn jacobians_match_numeric_differentiation() {
        let pose = Vector3::new(1.0, -2.0, 2.5);
        let odo = OdometryMotionModel::default();
        let (_, f, q) = odo.predict(&pose, &[0.3, 0.05, 0.2]);
        assert!((f - numeric_f(&odo, &pose, &[0.3, 0.05, 0.2])).norm() < 1e-6);
        assert!(q.symmetric_eigen().eigenvalues.iter().all(|e| *e > 0.0));
        let ack = AckermannMotionModel::default();
        let (_, f, _) = ack.predict(&pose, &[3.0, 0.1, 0.2]);
        assert!((f - numeric_f(&ack, &pose, &[3.0, 0.1, 0.2])).norm() < 1e-6);
    }

    #[test]
    fn odometry_composes_in_the_robot_frame() {
        let (p, _, _) = OdometryMotionModel::default().predict(&Vector3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2), &[1.0, 0.0, 0.0]);
        assert!((p.x).abs() < 1e-12 && (p.y - 1.0).abs() < 1e-12);
    }
}
