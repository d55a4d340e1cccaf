//! Vehicle motion models for the EKF prediction: the Pioneer's wheel odometry, and an
//! Ackermann model for car-like platforms (outdoor data sets such as Victoria Park).

use nalgebra::{DMatrix, Matrix3, Matrix3x2, Vector3};

use crate::messages::wrap_angle;

/// A motion model: the predicted pose, its Jacobian with respect to the pose, and the
/// process noise in pose space.
pub trait MotionModel: Send + Sync {
    /// Control input dimension (documentation; controls are slices).
    fn control_dims(&self) -> usize;
    /// Returns (predicted pose, F = d pose'/d pose, Q = process noise covariance).
    fn predict(&self, pose: &Vector3<f64>, control: &[f64]) -> (Vector3<f64>, Matrix3<f64>, Matrix3<f64>);

    /// Prior standard deviations of calibration parameters the filter should estimate
    /// alongside the pose (empty: none; the default).
    fn calibration_prior(&self) -> Vec<f64> {
        Vec::new()
    }

    /// Prediction with calibration parameters `calibration` applied to the control: also
    /// returns `d pose'/d calibration` (3 x `calibration.len()`). The default ignores them.
    fn predict_calibrated(&self, pose: &Vector3<f64>, calibration: &[f64], control: &[f64]) -> CalibratedPrediction {
        let (pose, f, q) = self.predict(pose, control);
        CalibratedPrediction { pose, f, f_calibration: DMatrix::zeros(3, calibration.len()), q }
    }
}

/// A prediction with calibration parameters in the state.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibratedPrediction {
    pub pose: Vector3<f64>,
    /// d pose' / d pose.
    pub f: Matrix3<f64>,
    /// d pose' / d calibration (3 x number of calibration parameters).
    pub f_calibration: DMatrix<f64>,
    /// Process noise in pose space.
    pub q: Matrix3<f64>,
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
///
/// Better, where the errors are systematic: with any of `scale_sigma`, `turn_scale_sigma`,
/// `bias_sigma_rad_per_m` above zero the filter estimates the three calibration errors
/// (the simulator's own parametrisation: measured distance = true x (1 + scale), measured
/// turn = true turn x (1 + turn scale) + bias x distance) as states; re-observed landmarks
/// make them observable, so the heading stops drifting instead of only being admitted as
/// uncertain. The random walks then only need to cover what is not systematic.
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
    /// Prior standard deviation of the distance scale error (estimated if any of the three
    /// calibration sigmas is above zero).
    pub scale_sigma: f64,
    /// Prior standard deviation of the turn scale error.
    pub turn_scale_sigma: f64,
    /// Prior standard deviation of the heading bias (rad per metre driven).
    pub bias_sigma_rad_per_m: f64,
}

impl Default for OdometryMotionModel {
    fn default() -> Self {
        // White noise a little above the simulator's default odometry noise: an EKF fed its
        // exact noise is still optimistic over long runs (linearisation error). The
        // simulator's default calibration errors (1% scale, 2% turn scale, 0.002 rad/m
        // bias, one draw per run) are estimated as states with priors 1.5x those, so no
        // random walk is needed for them (calibration states against random walks:
        // docs/results.md).
        OdometryMotionModel {
            a_dd: 0.005,
            a_da: 0.0002,
            a_ad: 0.002,
            a_aa: 0.005,
            d_per_m: 0.0,
            a_per_m: 0.0,
            a_per_rad: 0.0,
            floor: 1e-8,
            scale_sigma: 0.015,
            turn_scale_sigma: 0.03,
            bias_sigma_rad_per_m: 0.003,
        }
    }
}

impl OdometryMotionModel {
    /// White per-step noise only, no calibration random walks: for odometry without
    /// systematic errors (synthetic tests).
    pub fn white(a_dd: f64, a_da: f64, a_ad: f64, a_aa: f64) -> Self {
        OdometryMotionModel {
            a_dd,
            a_da,
            a_ad,
            a_aa,
            d_per_m: 0.0,
            a_per_m: 0.0,
            a_per_rad: 0.0,
            floor: 1e-8,
            scale_sigma: 0.0,
            turn_scale_sigma: 0.0,
            bias_sigma_rad_per_m: 0.0,
        }
    }

    /// The first setting that makes no sense, as (field, problem): every term is a
    /// variance or a standard deviation, so finite and not negative.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        let fields = [
            ("a_dd", self.a_dd),
            ("a_da", self.a_da),
            ("a_ad", self.a_ad),
            ("a_aa", self.a_aa),
            ("d_per_m", self.d_per_m),
            ("a_per_m", self.a_per_m),
            ("a_per_rad", self.a_per_rad),
            ("floor", self.floor),
            ("scale_sigma", self.scale_sigma),
            ("turn_scale_sigma", self.turn_scale_sigma),
            ("bias_sigma_rad_per_m", self.bias_sigma_rad_per_m),
        ];
        match fields.into_iter().find(|(_, v)| !(v.is_finite() && *v >= 0.0)) {
            Some((name, v)) => Err((name, format!("must be finite and not negative, got {v}"))),
            None => Ok(()),
        }
    }

    /// Whether the filter estimates the calibration errors.
    pub fn estimates_calibration(&self) -> bool {
        self.scale_sigma > 0.0 || self.turn_scale_sigma > 0.0 || self.bias_sigma_rad_per_m > 0.0
    }

    /// The odometry increment with calibration errors (scale, turn scale, bias per metre)
    /// removed, and its Jacobian with respect to them.
    fn corrected(calibration: &[f64], u: &[f64]) -> ([f64; 3], nalgebra::Matrix3<f64>) {
        let (scale, turn, bias) = (calibration[0], calibration[1], calibration[2]);
        let (dx, dy, dth) = (u[0], u[1], u[2]);
        let d = (dx * dx + dy * dy).sqrt();
        let q = 1.0 / (1.0 + scale);
        let r = 1.0 / (1.0 + turn);
        let turn_c = (dth - bias * d * q) * r;
        let corrected = [dx * q, dy * q, turn_c];
        // Columns: d/d scale, d/d turn scale, d/d bias.
        let j =
            Matrix3::new(-dx * q * q, 0.0, 0.0, -dy * q * q, 0.0, 0.0, bias * d * q * q * r, -turn_c * r, -d * q * r);
        (corrected, j)
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

    fn calibration_prior(&self) -> Vec<f64> {
        if self.estimates_calibration() {
            vec![self.scale_sigma, self.turn_scale_sigma, self.bias_sigma_rad_per_m]
        } else {
            Vec::new()
        }
    }

    fn predict_calibrated(&self, pose: &Vector3<f64>, calibration: &[f64], u: &[f64]) -> CalibratedPrediction {
        if calibration.len() != 3 {
            let (pose, f, q) = self.predict(pose, u);
            return CalibratedPrediction { pose, f, f_calibration: DMatrix::zeros(3, calibration.len()), q };
        }
        let (corrected, j) = Self::corrected(calibration, u);
        let (next, f, q) = self.predict(pose, &corrected);
        // d pose'/d corrected control is the rotation into the map frame.
        let (s, c) = pose.z.sin_cos();
        let g = Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
        let fc = g * j;
        CalibratedPrediction { pose: next, f, f_calibration: DMatrix::from_column_slice(3, 3, fc.as_slice()), q }
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
        let next =
            Vector3::new(pose.x + v * dt * c, pose.y + v * dt * s, wrap_angle(pose.z + v * dt * steer.tan() / l));
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
    fn calibration_jacobian_matches_numeric_differentiation() {
        let m = OdometryMotionModel {
            scale_sigma: 0.01,
            turn_scale_sigma: 0.02,
            bias_sigma_rad_per_m: 0.002,
            ..Default::default()
        };
        let pose = Vector3::new(1.0, -2.0, 2.5);
        let u = [0.3, 0.05, 0.2];
        let c = [0.02, -0.03, 0.004];
        let pred = m.predict_calibrated(&pose, &c, &u);
        for k in 0..3 {
            let (mut a, mut b) = (c, c);
            a[k] += 1e-6;
            b[k] -= 1e-6;
            let (pa, pb) = (m.predict_calibrated(&pose, &a, &u).pose, m.predict_calibrated(&pose, &b, &u).pose);
            let mut d = (pa - pb) / 2e-6;
            d.z = wrap_angle(pa.z - pb.z) / 2e-6;
            assert!(
                (d - pred.f_calibration.column(k)).norm() < 1e-6,
                "column {k}: {d} vs {}",
                pred.f_calibration.column(k)
            );
        }
        // Zero calibration is the plain prediction; the calibration undoes the simulator's
        // error model exactly.
        let plain = m.predict(&pose, &u);
        let zero = m.predict_calibrated(&pose, &[0.0; 3], &u);
        assert_eq!((zero.pose, zero.f, zero.q), plain);
        let d = (u[0] * u[0] + u[1] * u[1]).sqrt();
        let measured = [u[0] * (1.0 + c[0]), u[1] * (1.0 + c[0]), u[2] * (1.0 + c[1]) + c[2] * d];
        assert!((m.predict_calibrated(&pose, &c, &measured).pose - plain.0).norm() < 1e-12);
    }

    #[test]
    fn nonsense_motion_settings_are_named() {
        assert!(OdometryMotionModel::default().validate().is_ok());
        assert_eq!(
            OdometryMotionModel { bias_sigma_rad_per_m: -0.1, ..Default::default() }.validate().unwrap_err().0,
            "bias_sigma_rad_per_m"
        );
        assert_eq!(OdometryMotionModel { a_dd: f64::NAN, ..Default::default() }.validate().unwrap_err().0, "a_dd");
    }

    #[test]
    fn odometry_composes_in_the_robot_frame() {
        let (p, _, _) = OdometryMotionModel::default()
            .predict(&Vector3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2), &[1.0, 0.0, 0.0]);
        assert!((p.x).abs() < 1e-12 && (p.y - 1.0).abs() < 1e-12);
    }
}
