//! Vehicle motion models for the EKF prediction: the Pioneer's wheel odometry, and an
//! Ackermann model for car-like platforms (outdoor data sets such as Victoria Park).

use nalgebra::{DMatrix, Matrix3, Vector3};

use super::EkfError;
use crate::messages::wrap_angle;

/// A motion model: the predicted pose, its Jacobian with respect to the pose, and the
/// process noise in pose space.
pub trait MotionModel: Send + Sync {
    /// Control input dimension: the length of the slices `predict` takes.
    fn control_dims(&self) -> usize;
    /// Returns (predicted pose, F = d pose'/d pose, Q = process noise covariance); a
    /// control that is not `control_dims()` long is [`EkfError::ControlLength`] (see
    /// [`control_values`]).
    fn predict(&self, pose: &Vector3<f64>, control: &[f64]) -> Result<PosePrediction, EkfError>;

    /// Prior standard deviations of calibration parameters the filter should estimate
    /// alongside the pose (empty: none; the default).
    fn calibration_prior(&self) -> Vec<f64> {
        Vec::new()
    }

    /// Prediction with calibration parameters `calibration` applied to the control: also
    /// returns `d pose'/d calibration` (3 x `calibration.len()`). The default, for a model
    /// that estimates none, takes no calibration parameters ([`EkfError::CalibrationLength`]
    /// for any).
    fn predict_calibrated(
        &self,
        pose: &Vector3<f64>,
        calibration: &[f64],
        control: &[f64],
    ) -> Result<CalibratedPrediction, EkfError> {
        if !calibration.is_empty() {
            return Err(EkfError::CalibrationLength { calibration: calibration.len(), model: 0 });
        }
        uncalibrated(self, pose, control)
    }
}

/// `model`'s prediction for a filter that holds no calibration parameters.
fn uncalibrated(
    model: &(impl MotionModel + ?Sized),
    pose: &Vector3<f64>,
    control: &[f64],
) -> Result<CalibratedPrediction, EkfError> {
    let (pose, f, q) = model.predict(pose, control)?;
    Ok(CalibratedPrediction { pose, f, f_calibration: DMatrix::zeros(3, 0), q })
}

/// A prediction `(pose', F = d pose'/d pose, Q)`.
pub type PosePrediction = (Vector3<f64>, Matrix3<f64>, Matrix3<f64>);

/// A control's `N` values, or [`EkfError::ControlLength`] for a slice of another length:
/// how a [`MotionModel`] reads its control.
pub fn control_values<const N: usize>(control: &[f64]) -> Result<[f64; N], EkfError> {
    control.try_into().map_err(|_| EkfError::ControlLength { control: control.len(), model: N })
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

    fn predict(&self, pose: &Vector3<f64>, u: &[f64]) -> Result<PosePrediction, EkfError> {
        let [dx, dy, dth] = control_values(u)?;
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
        Ok((next, f, g * m * g.transpose()))
    }

    fn calibration_prior(&self) -> Vec<f64> {
        if self.estimates_calibration() {
            vec![self.scale_sigma, self.turn_scale_sigma, self.bias_sigma_rad_per_m]
        } else {
            Vec::new()
        }
    }

    /// Calibration parameters are none (not estimated) or the three of
    /// [`OdometryMotionModel::estimates_calibration`]; another count is
    /// [`EkfError::CalibrationLength`].
    fn predict_calibrated(
        &self,
        pose: &Vector3<f64>,
        calibration: &[f64],
        u: &[f64],
    ) -> Result<CalibratedPrediction, EkfError> {
        let [dx, dy, dth] = control_values(u)?;
        match calibration.len() {
            0 => return uncalibrated(self, pose, u),
            3 => {}
            n => return Err(EkfError::CalibrationLength { calibration: n, model: 3 }),
        }
        let (corrected, j) = Self::corrected(calibration, &[dx, dy, dth]);
        let (next, f, q) = self.predict(pose, &corrected)?;
        // d pose'/d corrected control is the rotation into the map frame.
        let (s, c) = pose.z.sin_cos();
        let g = Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
        let fc = g * j;
        Ok(CalibratedPrediction { pose: next, f, f_calibration: DMatrix::from_column_slice(3, 3, fc.as_slice()), q })
    }
}

/// A car-like vehicle (Ackermann steering): control (speed m/s, steering angle rad, dt s),
/// held over dt. The pose is the rear axle's centre, heading along the car. The speed may
/// come from a wheel `encoder_offset_m` to the side of that centre (Victoria Park: the rear
/// left wheel, 0.76 m): on a curve that wheel runs faster or slower than the centre, so
/// the centre's speed is `v / (1 - tan(steering) encoder_offset / wheelbase)`.
///
/// The noise is defined per metre driven and per second, not per message: the variances of
/// the distance, the sideways slip and the heading grow linearly with distance and time,
/// so splitting a drive into more, shorter steps gives the same uncertainty at its end and
/// the model holds at any message rate.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AckermannMotionModel {
    pub wheelbase_m: f64,
    /// Sideways offset of the wheel whose speed is measured from the rear axle's centre
    /// (positive to the left).
    pub encoder_offset_m: f64,
    /// Variance of the distance driven, per metre (m²/m).
    pub distance_var_per_m: f64,
    /// Variance of the sideways slip, per metre (m²/m).
    pub lateral_var_per_m: f64,
    /// Variance of the heading change, per metre driven (rad²/m): steering and slip.
    pub heading_var_per_m: f64,
    /// Variance of the heading change, per second (rad²/s): gyro-like drift, and what keeps
    /// a standing vehicle's covariance sane.
    pub heading_var_per_s: f64,
}

impl Default for AckermannMotionModel {
    fn default() -> Self {
        // A utility car on grass (Victoria Park's: wheelbase 2.83 m). Per 10 m driven, 1
        // sigma: 0.5 m along and across the track and 8 degrees of heading; wheel slip and
        // a steering sensor that reads off by degrees make a car's dead reckoning poor.
        // Chosen on the first half of Victoria Park, where anything from a tenth to three
        // times these gave the same accuracy (docs/results.md#victoria-park).
        AckermannMotionModel {
            wheelbase_m: 2.83,
            encoder_offset_m: 0.0,
            distance_var_per_m: 0.025,
            lateral_var_per_m: 0.025,
            heading_var_per_m: 0.002,
            heading_var_per_s: 1.0e-4,
        }
    }
}

impl AckermannMotionModel {
    /// The first setting that makes no sense, as (field, problem).
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        if !(self.wheelbase_m.is_finite() && self.wheelbase_m > 0.0) {
            return Err(("wheelbase_m", format!("must be finite and positive, got {}", self.wheelbase_m)));
        }
        if !(self.encoder_offset_m.is_finite() && self.encoder_offset_m.abs() < self.wheelbase_m) {
            return Err((
                "encoder_offset_m",
                format!("must be finite and smaller than the wheelbase, got {}", self.encoder_offset_m),
            ));
        }
        for (name, v) in [
            ("distance_var_per_m", self.distance_var_per_m),
            ("lateral_var_per_m", self.lateral_var_per_m),
            ("heading_var_per_m", self.heading_var_per_m),
            ("heading_var_per_s", self.heading_var_per_s),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err((name, format!("must be finite and not negative, got {v}")));
            }
        }
        Ok(())
    }

    /// The rear axle centre's speed from the measured wheel's.
    pub fn centre_speed(&self, measured: f64, steering: f64) -> f64 {
        let factor = 1.0 - steering.tan() * self.encoder_offset_m / self.wheelbase_m;
        // Steering so hard that the measured wheel would stand still is not a car's.
        if factor.abs() < 1e-3 { measured } else { measured / factor }
    }
}

impl MotionModel for AckermannMotionModel {
    fn control_dims(&self) -> usize {
        3
    }

    fn predict(&self, pose: &Vector3<f64>, u: &[f64]) -> Result<PosePrediction, EkfError> {
        let [speed, steer, dt] = control_values(u)?;
        let dt = dt.max(0.0);
        let d = self.centre_speed(speed, steer) * dt;
        let turn = d * steer.tan() / self.wheelbase_m;
        // Along the chord of the arc, at the mid-step heading: exact for a constant control,
        // so a long gap between controls is integrated as well as many short ones.
        let mid = pose.z + 0.5 * turn;
        let chord = if turn.abs() > 1e-9 { d * (0.5 * turn).sin() / (0.5 * turn) } else { d };
        let (s, c) = mid.sin_cos();
        let next = Vector3::new(pose.x + chord * c, pose.y + chord * s, wrap_angle(pose.z + turn));
        let f = Matrix3::new(1.0, 0.0, -chord * s, 0.0, 1.0, chord * c, 0.0, 0.0, 1.0);
        let dist = d.abs();
        let m = Matrix3::new(
            self.distance_var_per_m * dist + 1e-12,
            0.0,
            0.0,
            0.0,
            self.lateral_var_per_m * dist + 1e-12,
            0.0,
            0.0,
            0.0,
            self.heading_var_per_m * dist + self.heading_var_per_s * dt + 1e-12,
        );
        let g = Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
        Ok((next, f, g * m * g.transpose()))
    }
}

/// The vehicle model of `[pipeline.motion]`: `model = "odometry"` (the default: body-frame
/// odometry increments, as from a Pioneer's wheel encoders, with the remaining keys those
/// of [`OdometryMotionModel`]) or `model = "ackermann"` (speed and steering of a car-like
/// vehicle, keys of [`AckermannMotionModel`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MotionConfig {
    Odometry(OdometryMotionModel),
    Ackermann(AckermannMotionModel),
}

impl Default for MotionConfig {
    fn default() -> Self {
        MotionConfig::Odometry(OdometryMotionModel::default())
    }
}

impl MotionConfig {
    /// The `model` key's value.
    pub fn name(&self) -> &'static str {
        match self {
            MotionConfig::Odometry(_) => "odometry",
            MotionConfig::Ackermann(_) => "ackermann",
        }
    }

    /// The first setting that makes no sense, as (field, problem).
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        match self {
            MotionConfig::Odometry(m) => m.validate(),
            MotionConfig::Ackermann(m) => m.validate(),
        }
    }

    fn model(&self) -> &dyn MotionModel {
        match self {
            MotionConfig::Odometry(m) => m,
            MotionConfig::Ackermann(m) => m,
        }
    }
}

impl MotionModel for MotionConfig {
    fn control_dims(&self) -> usize {
        self.model().control_dims()
    }
    fn predict(&self, pose: &Vector3<f64>, control: &[f64]) -> Result<PosePrediction, EkfError> {
        self.model().predict(pose, control)
    }
    fn calibration_prior(&self) -> Vec<f64> {
        self.model().calibration_prior()
    }
    fn predict_calibrated(
        &self,
        pose: &Vector3<f64>,
        calibration: &[f64],
        control: &[f64],
    ) -> Result<CalibratedPrediction, EkfError> {
        self.model().predict_calibrated(pose, calibration, control)
    }
}

impl serde::Serialize for MotionConfig {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let fields = match self {
            MotionConfig::Odometry(m) => serde_json::to_value(m),
            MotionConfig::Ackermann(m) => serde_json::to_value(m),
        }
        .map_err(serde::ser::Error::custom)?;
        let mut map = serde_json::Map::new();
        map.insert("model".into(), self.name().into());
        if let serde_json::Value::Object(fields) = fields {
            map.extend(fields);
        }
        map.serialize(serializer)
    }
}

/// A value of `[pipeline.motion]` as read: the model's name, or a number kept exactly as
/// written (NaN and infinities included, which JSON cannot hold), so that `validate` names it.
#[derive(serde::Deserialize)]
#[serde(untagged)]
enum MotionValue {
    Name(String),
    Number(f64),
    Other(serde::de::IgnoredAny),
}

/// Hands a read value on to the model's own derived deserialiser, so that it reports an
/// unknown key (with the keys it expects) before a value of the wrong type.
impl<'de> serde::de::IntoDeserializer<'de, serde::de::value::Error> for MotionValue {
    type Deserializer = Self;
    fn into_deserializer(self) -> Self {
        self
    }
}

impl<'de> serde::Deserializer<'de> for MotionValue {
    type Error = serde::de::value::Error;

    fn deserialize_any<V: serde::de::Visitor<'de>>(self, visitor: V) -> Result<V::Value, Self::Error> {
        match self {
            MotionValue::Name(s) => visitor.visit_string(s),
            MotionValue::Number(v) => visitor.visit_f64(v),
            MotionValue::Other(_) => visitor.visit_unit(),
        }
    }

    serde::forward_to_deserialize_any! {
        bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes byte_buf option unit
        unit_struct newtype_struct seq tuple tuple_struct map struct enum identifier ignored_any
    }
}

impl<'de> serde::Deserialize<'de> for MotionConfig {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        use serde::de::Error;
        let mut map = std::collections::BTreeMap::<String, MotionValue>::deserialize(deserializer)?;
        let model = match map.remove("model") {
            None => "odometry".to_string(),
            Some(MotionValue::Name(s)) => s,
            Some(_) => return Err(D::Error::custom("`model` must be a string: \"odometry\" or \"ackermann\"")),
        };
        let fields = serde::de::value::MapDeserializer::<_, serde::de::value::Error>::new(map.into_iter());
        match model.as_str() {
            "odometry" => {
                OdometryMotionModel::deserialize(fields).map(MotionConfig::Odometry).map_err(D::Error::custom)
            }
            "ackermann" => {
                AckermannMotionModel::deserialize(fields).map(MotionConfig::Ackermann).map_err(D::Error::custom)
            }
            other => {
                Err(D::Error::custom(format!("unknown motion model `{other}`, expected `odometry` or `ackermann`")))
            }
        }
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
            let (a, _, _) = m.predict(&p, u).unwrap();
            let (b, _, _) = m.predict(&q, u).unwrap();
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
        let (_, f, q) = odo.predict(&pose, &[0.3, 0.05, 0.2]).unwrap();
        assert!((f - numeric_f(&odo, &pose, &[0.3, 0.05, 0.2])).norm() < 1e-6);
        assert!(q.symmetric_eigen().eigenvalues.iter().all(|e| *e > 0.0));
        let ack = AckermannMotionModel { encoder_offset_m: 0.76, ..Default::default() };
        let (_, f, q) = ack.predict(&pose, &[3.0, 0.1, 0.2]).unwrap();
        assert!((f - numeric_f(&ack, &pose, &[3.0, 0.1, 0.2])).norm() < 1e-6);
        assert!(q.symmetric_eigen().eigenvalues.iter().all(|e| *e > 0.0));
    }

    /// Drives `steps` equal steps of `total_s` seconds with `model`; the pose and its
    /// covariance (propagated as the filter does).
    fn drive(
        model: &dyn MotionModel,
        speed: f64,
        steering: f64,
        total_s: f64,
        steps: usize,
    ) -> (Vector3<f64>, Matrix3<f64>) {
        let (mut pose, mut p) = (Vector3::zeros(), Matrix3::zeros());
        for _ in 0..steps {
            let (next, f, q) = model.predict(&pose, &[speed, steering, total_s / steps as f64]).unwrap();
            p = f * p * f.transpose() + q;
            pose = next;
        }
        (pose, p)
    }

    #[test]
    fn ackermann_noise_and_path_do_not_depend_on_the_message_rate() {
        let m = AckermannMotionModel::default();
        // 10 s at 3 m/s on a constant curve: 4 Hz and 400 Hz agree.
        let (slow, p_slow) = drive(&m, 3.0, 0.1, 10.0, 40);
        let (fast, p_fast) = drive(&m, 3.0, 0.1, 10.0, 4000);
        assert!((slow - fast).norm() < 1e-3, "{slow} vs {fast}");
        // Heading noise added at the end of a long step reaches the position one step late:
        // an O(1/rate) difference, 3% between 4 Hz and 400 Hz (a per-message noise model
        // would differ a hundredfold).
        let rel = (p_slow - p_fast).norm() / p_fast.norm();
        assert!(rel < 0.05, "covariance differs by {rel}");
        // The circle of radius L / tan(steering): after a quarter of it the car faces north.
        let radius = m.wheelbase_m / 0.1f64.tan();
        let quarter = std::f64::consts::FRAC_PI_2 * radius / 3.0;
        for steps in [1, 1000] {
            // Along the chord: exact in one step as in a thousand.
            let (end, _) = drive(&m, 3.0, 0.1, quarter, steps);
            assert!(
                (end.x - radius).abs() < 1e-9
                    && (end.y - radius).abs() < 1e-9
                    && (end.z - std::f64::consts::FRAC_PI_2).abs() < 1e-9,
                "{steps} steps: {end}"
            );
        }
    }

    #[test]
    fn the_encoder_wheel_is_corrected_to_the_axle_centre() {
        let m = AckermannMotionModel { encoder_offset_m: 0.76, ..Default::default() };
        // Turning left, the left wheel is on the inside and runs slower than the centre.
        assert!(m.centre_speed(3.0, 0.2) > 3.0);
        assert!(m.centre_speed(3.0, -0.2) < 3.0);
        assert_eq!(m.centre_speed(3.0, 0.0), 3.0);
        let expected = 3.0 / (1.0 - 0.2f64.tan() * 0.76 / 2.83);
        assert!((m.centre_speed(3.0, 0.2) - expected).abs() < 1e-12);
    }

    #[test]
    fn motion_config_reads_either_model_and_names_mistakes() {
        let odo: MotionConfig = serde_json::from_str(r#"{"a_dd": 0.01}"#).unwrap();
        assert_eq!(odo, MotionConfig::Odometry(OdometryMotionModel { a_dd: 0.01, ..Default::default() }));
        let car: MotionConfig = serde_json::from_str(r#"{"model": "ackermann", "encoder_offset_m": 0.76}"#).unwrap();
        assert_eq!(car, MotionConfig::Ackermann(AckermannMotionModel { encoder_offset_m: 0.76, ..Default::default() }));
        // What is written reads back.
        let again: MotionConfig = serde_json::from_str(&serde_json::to_string(&car).unwrap()).unwrap();
        assert_eq!(again, car);
        let wrong = serde_json::from_str::<MotionConfig>(r#"{"model": "ackermann", "a_dd": 0.01}"#).unwrap_err();
        assert!(wrong.to_string().contains("unknown field `a_dd`"), "{wrong}");
        let unknown = serde_json::from_str::<MotionConfig>(r#"{"model": "bicycle"}"#).unwrap_err();
        assert!(unknown.to_string().contains("unknown motion model `bicycle`"), "{unknown}");
        // A misspelt key is an unknown key, whatever its value; a text where a number
        // belongs says so.
        let typo = serde_json::from_str::<MotionConfig>(r#"{"modl": "ackermann"}"#).unwrap_err();
        assert!(typo.to_string().contains("unknown field `modl`, expected one of"), "{typo}");
        let text = serde_json::from_str::<MotionConfig>(r#"{"a_dd": "0.01"}"#).unwrap_err();
        assert!(text.to_string().contains("invalid type: string"), "{text}");
        assert_eq!(
            AckermannMotionModel { encoder_offset_m: 3.0, ..Default::default() }.validate().unwrap_err().0,
            "encoder_offset_m"
        );
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
        let pred = m.predict_calibrated(&pose, &c, &u).unwrap();
        for k in 0..3 {
            let (mut a, mut b) = (c, c);
            a[k] += 1e-6;
            b[k] -= 1e-6;
            let (pa, pb) =
                (m.predict_calibrated(&pose, &a, &u).unwrap().pose, m.predict_calibrated(&pose, &b, &u).unwrap().pose);
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
        let plain = m.predict(&pose, &u).unwrap();
        let zero = m.predict_calibrated(&pose, &[0.0; 3], &u).unwrap();
        assert_eq!((zero.pose, zero.f, zero.q), plain);
        let d = (u[0] * u[0] + u[1] * u[1]).sqrt();
        let measured = [u[0] * (1.0 + c[0]), u[1] * (1.0 + c[0]), u[2] * (1.0 + c[1]) + c[2] * d];
        assert!((m.predict_calibrated(&pose, &c, &measured).unwrap().pose - plain.0).norm() < 1e-12);
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
            .predict(&Vector3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2), &[1.0, 0.0, 0.0])
            .unwrap();
        assert!((p.x).abs() < 1e-12 && (p.y - 1.0).abs() < 1e-12);
    }
}
