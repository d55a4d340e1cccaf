//! A synthetic drive for the smoother's tests and benchmark: a robot moving in fixed steps
//! past point landmarks, exact range-bearing measurements, the filter run alongside (with
//! first-estimate Jacobians and calibration states, as the pipeline runs it) and its
//! history recorded.

use nalgebra::{Matrix3, Vector2, Vector3};

use super::smoother::History;
use super::{Ekf, EkfError, MotionModel, OdometryMotionModel, RangeBearingModel};
use crate::messages::wrap_angle;

/// The route and what the odometry gets wrong.
#[derive(Debug, Clone, PartialEq)]
pub struct Route {
    pub steps: usize,
    pub step_m: f64,
    /// Turn per step (rad).
    pub turn: f64,
    /// The odometry reads `scale` long and turns `turn_scale` more than the robot did.
    pub scale: f64,
    pub turn_scale: f64,
    /// Landmarks are observed every this many steps (0: never), out to `max_range_m`.
    pub observe_every: usize,
    pub max_range_m: f64,
}

/// The drive's outcome.
#[derive(Debug, Clone)]
pub struct Drive {
    pub ekf: Ekf,
    pub history: History,
    /// Id of each filter landmark (the index of the true landmark).
    pub ids: Vec<u32>,
    pub motion: OdometryMotionModel,
    pub sensor: RangeBearingModel,
    /// The true position of each filter landmark, in the filter's order.
    pub landmarks: Vec<Vector2<f64>>,
    /// The true final pose.
    pub truth: Vector3<f64>,
}

/// Drives `route` from the origin past `landmarks`; a route or landmark the filter refuses
/// (not finite) is its error.
pub fn drive(route: &Route, landmarks: &[Vector2<f64>]) -> Result<Drive, EkfError> {
    let motion = OdometryMotionModel::default();
    let sensor = RangeBearingModel::default();
    let (start, cov) = (Vector3::zeros(), Matrix3::identity() * 1e-6);
    let sigma = motion.calibration_prior();
    let mut ekf = Ekf::with_calibration(start, cov, &sigma);
    ekf.use_first_estimates();
    let mut history = History::new(start, cov, &sigma);
    let mut ids: Vec<u32> = Vec::new();
    let mut truth = start;
    for step in 0..route.steps {
        let u = [route.step_m * (1.0 + route.scale), 0.0, route.turn * (1.0 + route.turn_scale)];
        let (s, c) = truth.z.sin_cos();
        truth = Vector3::new(truth.x + c * route.step_m, truth.y + s * route.step_m, wrap_angle(truth.z + route.turn));
        ekf.predict(&motion, &u)?;
        history.push_control(u, ekf.pose());
        if route.observe_every > 0 && step % route.observe_every == route.observe_every - 1 {
            for (j, l) in landmarks.iter().enumerate() {
                let (z, _, _) = sensor.observe(&truth, l);
                if z.x > route.max_range_m {
                    continue;
                }
                let id = j as u32;
                match ids.iter().position(|&i| i == id) {
                    Some(slot) => ekf.update(&sensor, slot, &z)?,
                    None => {
                        ekf.add_landmark(&sensor, &z)?;
                        ids.push(id);
                    }
                }
                history.observe(id, z);
            }
            history.set_estimate(ekf.pose());
        }
    }
    let order = ids.iter().map(|id| landmarks[*id as usize]).collect();
    Ok(Drive { ekf, history, ids, motion, sensor, landmarks: order, truth })
}
