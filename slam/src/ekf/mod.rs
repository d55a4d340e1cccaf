//! EKF-SLAM over the robot pose (x, y, theta) and 2-D point landmarks.
//!
//! State layout: `[x, y, theta, c1..ck, l1x, l1y, l2x, l2y, ...]`, where `c` are the
//! motion model's calibration parameters, if it estimates any (the vehicle block is the
//! pose and those). Prediction touches only the
//! vehicle block and its cross-covariances (O(n)); an update uses the sparsity of the
//! observation Jacobian (O(n²) per observation, one pass over P), and a scan's
//! observations can be stacked into one update ([`Ekf::update_batch`], one pass over P for
//! them all). Landmarks are added a scan at a time and removed in place, without copies
//! of P. Single updates are in Joseph
//! form, expanded as `P - K(HP) - (HP)ᵀKᵀ + K S Kᵀ`, which equals
//! `(I-KH)P(I-KH)ᵀ + KRKᵀ` for any gain, evaluated so that P stays exactly symmetric.
//! Jacobians can be taken at first estimates ([`FirstEstimates`]), or at the latest
//! estimates constrained by the first ones, which keeps the global heading unobservable as
//! it truly is.

pub mod motion;
pub mod observation;
pub mod smoother;
pub mod synthetic;

use nalgebra::{DMatrix, DVector, Matrix2, Matrix2x3, Matrix3, SMatrix, Vector2, Vector3};
use serde::{Deserialize, Serialize};

pub use motion::{
    AckermannMotionModel, CalibratedPrediction, MotionConfig, MotionModel, OdometryMotionModel, PosePrediction,
    control_values,
};
pub use observation::RangeBearingModel;

use crate::messages::wrap_angle;

/// Errors from the filter.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum EkfError {
    #[error("innovation covariance is not positive definite")]
    NotPositiveDefinite,
    #[error("no landmark with index {0}")]
    UnknownLandmark(usize),
    /// An observation or control that is not finite, or a prediction that would make the
    /// pose not finite: refused, the filter left as it was.
    #[error("an observation or control is not finite, or the pose it predicts would not be")]
    NonFinite,
    /// A control whose length is not the motion model's (`MotionModel::control_dims`).
    #[error("a control of {control} values for a motion model of {model}")]
    ControlLength { control: usize, model: usize },
    /// Calibration parameters of another count than the motion model estimates.
    #[error("{calibration} calibration parameters for a motion model that estimates {model}")]
    CalibrationLength { calibration: usize, model: usize },
    /// A filter whose parts disagree (read from a file, or put together field by field).
    #[error("an inconsistent filter: {0}")]
    Inconsistent(String),
}

/// The filter state. One read from a file is checked ([`Ekf::check`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "EkfParts")]
pub struct Ekf {
    /// The parts are read through [`Ekf::state`], [`Ekf::covariance`] and the methods:
    /// their shapes must agree ([`Ekf::check`]), and only the crate changes them.
    pub(crate) x: DVector<f64>,
    pub(crate) p: DMatrix<f64>,
    /// Size of the vehicle block: the pose (3) and the calibration parameters after it.
    #[serde(default = "pose_dims")]
    pub(crate) vehicle_dims: usize,
    /// First-estimate Jacobians, when enabled ([`Ekf::use_first_estimates`]).
    #[serde(default)]
    pub(crate) first_estimates: Option<FirstEstimates>,
}

/// The linearisation points of first-estimate Jacobians (Huang, Mourikis & Roumeliotis
/// 2008): the propagation Jacobian takes its position terms from consecutive predicted
/// poses, the observation Jacobians are evaluated at the predicted pose and at each
/// landmark's first estimate. Jacobians that use the latest estimates give the filter
/// information about its global heading that the observations do not hold, which makes
/// EKF-SLAM overconfident once the heading is uncertain; these keep the unobservable
/// directions unobservable.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FirstEstimates {
    /// The pose as last predicted (before any update of that step).
    pub predicted_pose: Vector3<f64>,
    /// Each landmark's position when it was added.
    pub landmarks: Vec<Vector2<f64>>,
    /// Observability-constrained Jacobians (Huang, Mourikis & Roumeliotis 2010): the
    /// observation Jacobians are taken at the latest estimates, as accurate as the filter
    /// knows, and then changed as little as possible (least squares) so that they still
    /// see nothing along the directions the first estimates leave unobservable. First
    /// estimates alone linearise at a landmark's first position: one first seen far away
    /// with the heading unsure can be metres off by the time the robot passes it, and then
    /// its updates pull the heading wrong.
    #[serde(default)]
    pub observability_constrained: bool,
}

fn pose_dims() -> usize {
    3
}

/// An [`Ekf`] as read, before [`Ekf::check`].
#[derive(Deserialize)]
struct EkfParts {
    x: DVector<f64>,
    p: DMatrix<f64>,
    #[serde(default = "pose_dims")]
    vehicle_dims: usize,
    #[serde(default)]
    first_estimates: Option<FirstEstimates>,
}

impl TryFrom<EkfParts> for Ekf {
    type Error = EkfError;

    fn try_from(parts: EkfParts) -> Result<Self, EkfError> {
        let EkfParts { x, p, vehicle_dims, first_estimates } = parts;
        let ekf = Ekf { x, p, vehicle_dims, first_estimates };
        ekf.check()?;
        Ok(ekf)
    }
}

impl Ekf {
    /// A filter at `pose` with covariance `pose_cov` and no landmarks.
    pub fn new(pose: Vector3<f64>, pose_cov: Matrix3<f64>) -> Self {
        Self::with_calibration(pose, pose_cov, &[])
    }

    /// A filter that also estimates calibration parameters, starting at zero with
    /// standard deviations `calibration_sigma` (see [`MotionModel::calibration_prior`]).
    pub fn with_calibration(pose: Vector3<f64>, pose_cov: Matrix3<f64>, calibration_sigma: &[f64]) -> Self {
        let vd = 3 + calibration_sigma.len();
        let mut p = DMatrix::zeros(vd, vd);
        p.view_mut((0, 0), (3, 3)).copy_from(&pose_cov);
        for (k, s) in calibration_sigma.iter().enumerate() {
            p[(3 + k, 3 + k)] = s * s;
        }
        let mut x = DVector::zeros(vd);
        x.rows_mut(0, 3).copy_from(&pose);
        Ekf { x, p, vehicle_dims: vd, first_estimates: None }
    }

    /// [`EkfError::Inconsistent`] unless the parts agree: a vehicle block of the pose and
    /// more, landmarks of two values each after it, a square covariance of the state's
    /// size, and first estimates (if on) for every landmark. A filter made by the methods
    /// always passes, and one read from a file is checked as it is read (the parts are
    /// not public, so nothing else can put one together).
    pub fn check(&self) -> Result<(), EkfError> {
        let n = self.x.len();
        let problem = if self.vehicle_dims < 3 || self.vehicle_dims > n {
            Some(format!("a vehicle block of {} values in a state of {n}", self.vehicle_dims))
        } else if !(n - self.vehicle_dims).is_multiple_of(2) {
            Some(format!("{} values after the vehicle block, not two per landmark", n - self.vehicle_dims))
        } else if self.p.shape() != (n, n) {
            Some(format!("a {}x{} covariance for a state of {n}", self.p.nrows(), self.p.ncols()))
        } else {
            self.first_estimates.as_ref().filter(|fe| fe.landmarks.len() != self.landmark_count()).map(|fe| {
                format!("first estimates of {} landmarks for a map of {}", fe.landmarks.len(), self.landmark_count())
            })
        };
        problem.map_or(Ok(()), |p| Err(EkfError::Inconsistent(p)))
    }

    /// Switches to first-estimate Jacobians (see [`FirstEstimates`]), or restarts them:
    /// the pose and the landmarks already in the state take their current positions as
    /// first estimates. Observability constraints, if on, stay on.
    pub fn use_first_estimates(&mut self) {
        let landmarks = self.landmarks().collect();
        let observability_constrained = self.first_estimates.as_ref().is_some_and(|fe| fe.observability_constrained);
        self.first_estimates =
            Some(FirstEstimates { predicted_pose: self.pose(), landmarks, observability_constrained });
    }

    /// Switches to observability-constrained Jacobians (see
    /// [`FirstEstimates::observability_constrained`]), with first estimates at the current
    /// state.
    pub fn use_observability_constraints(&mut self) {
        self.use_first_estimates();
        if let Some(fe) = &mut self.first_estimates {
            fe.observability_constrained = true;
        }
    }

    /// The propagation Jacobian's position terms from consecutive predicted poses, when
    /// first estimates are on (and records `next` as the latest predicted pose).
    fn first_estimate_transition(&mut self, next: &Vector3<f64>, f: &mut Matrix3<f64>) {
        if let Some(fe) = &mut self.first_estimates {
            f[(0, 2)] = -(next.y - fe.predicted_pose.y);
            f[(1, 2)] = next.x - fe.predicted_pose.x;
            fe.predicted_pose = *next;
        }
    }

    /// Whether every number of the state and every variance is finite. An input far
    /// outside what the models describe overflows them, and nothing estimated afterwards
    /// means anything.
    pub fn is_finite(&self) -> bool {
        self.x.iter().all(|v| v.is_finite()) && (0..self.p.nrows()).all(|i| self.p[(i, i)].is_finite())
    }

    /// Whether a variance on P's diagonal is negative: a covariance that is certainly no
    /// longer positive definite (cancellation after an absurd input), found in O(n).
    pub fn has_negative_variance(&self) -> bool {
        (0..self.p.nrows()).any(|i| self.p[(i, i)] < 0.0)
    }

    /// The state: the vehicle block (pose, then calibration parameters), then two values
    /// per landmark.
    pub fn state(&self) -> &DVector<f64> {
        &self.x
    }

    /// The state's covariance.
    pub fn covariance(&self) -> &DMatrix<f64> {
        &self.p
    }

    /// Size of the vehicle block: the pose (3) and the calibration parameters after it.
    pub fn vehicle_dims(&self) -> usize {
        self.vehicle_dims
    }

    /// The linearisation points of first-estimate Jacobians, when they are on.
    pub fn first_estimates(&self) -> Option<&FirstEstimates> {
        self.first_estimates.as_ref()
    }

    pub fn landmark_count(&self) -> usize {
        (self.x.len() - self.vehicle_dims) / 2
    }

    /// Index of landmark 0's x in the state.
    pub fn landmark_offset(&self) -> usize {
        self.vehicle_dims
    }

    /// The calibration parameters' estimates (empty if the filter has none).
    pub fn calibration(&self) -> &[f64] {
        &self.x.as_slice()[3..self.vehicle_dims]
    }

    /// Their standard deviations.
    pub fn calibration_sigma(&self) -> Vec<f64> {
        (3..self.vehicle_dims).map(|k| self.p[(k, k)].max(0.0).sqrt()).collect()
    }

    pub fn pose(&self) -> Vector3<f64> {
        Vector3::new(self.x[0], self.x[1], self.x[2])
    }

    pub fn pose_covariance(&self) -> Matrix3<f64> {
        self.p.fixed_view::<3, 3>(0, 0).into_owned()
    }

    /// The state index of landmark `i`'s x, or [`EkfError::UnknownLandmark`].
    fn landmark_index(&self, i: usize) -> Result<usize, EkfError> {
        if i < self.landmark_count() { Ok(self.vehicle_dims + 2 * i) } else { Err(EkfError::UnknownLandmark(i)) }
    }

    /// Landmark `i`'s position, or [`EkfError::UnknownLandmark`].
    pub fn landmark(&self, i: usize) -> Result<Vector2<f64>, EkfError> {
        Ok(self.landmark_at(self.landmark_index(i)?))
    }

    /// Every landmark's position, in index order.
    pub fn landmarks(&self) -> impl Iterator<Item = Vector2<f64>> + '_ {
        (0..self.landmark_count()).map(|i| self.landmark_at(self.vehicle_dims + 2 * i))
    }

    /// The landmark whose x is at state index `li` (a valid landmark's).
    fn landmark_at(&self, li: usize) -> Vector2<f64> {
        Vector2::new(self.x[li], self.x[li + 1])
    }

    /// Landmark `i`'s covariance, or [`EkfError::UnknownLandmark`].
    pub fn landmark_covariance(&self, i: usize) -> Result<Matrix2<f64>, EkfError> {
        let li = self.landmark_index(i)?;
        Ok(self.p.fixed_view::<2, 2>(li, li).into_owned())
    }

    /// Prediction with a motion model and its control. Only the pose rows change,
    /// `P_p* <- [F Fc] P_v*` (calibration parameters, if any, are constant), and the pose
    /// block gets the process noise.
    ///
    /// A control that is not finite, or one whose predicted pose, Jacobians, noise or
    /// covariance are not (a motion model of zero wheelbase, a speed of 1e300 m/s), is
    /// refused with [`EkfError::NonFinite`], the filter left as it was. A control that is
    /// not `model.control_dims()` long is refused with [`EkfError::ControlLength`], and a
    /// filter whose calibration parameters are not the model's with
    /// [`EkfError::CalibrationLength`], also leaving the filter as it was.
    pub fn predict(&mut self, model: &dyn MotionModel, control: &[f64]) -> Result<(), EkfError> {
        if control.len() != model.control_dims() {
            return Err(EkfError::ControlLength { control: control.len(), model: model.control_dims() });
        }
        if !control.iter().all(|v| v.is_finite()) {
            return Err(EkfError::NonFinite);
        }
        let vd = self.vehicle_dims;
        let n = self.x.len();
        let calibration = self.calibration().to_vec();
        let mut pred = model.predict_calibrated(&self.pose(), &calibration, control)?;
        let finite = pred.pose.iter().chain(pred.f.iter()).chain(pred.f_calibration.iter()).chain(pred.q.iter());
        if !finite.copied().all(f64::is_finite) {
            return Err(EkfError::NonFinite);
        }
        let linearised_at = self.first_estimates.as_ref().map(|fe| fe.predicted_pose);
        self.first_estimate_transition(&pred.pose, &mut pred.f);
        // The pose rows of the vehicle transition [F Fc; 0 I].
        let mut fv = DMatrix::zeros(3, vd);
        fv.view_mut((0, 0), (3, 3)).copy_from(&pred.f);
        fv.view_mut((0, 3), (3, vd - 3)).copy_from(&pred.f_calibration);
        // New pose rows over all columns: [F Fc] P_v*; then the pose-pose block also needs
        // the transition on the right: P_pp' = ([F Fc] P_vv) [F Fc]ᵀ + Q.
        let new_rows = &fv * self.p.view((0, 0), (vd, n));
        let new_pp = new_rows.view((0, 0), (3, vd)) * fv.transpose() + pred.q;
        // A covariance the prediction would overflow: refused, the filter as it was.
        if !new_rows.iter().chain(new_pp.iter()).all(|v| v.is_finite()) {
            if let (Some(fe), Some(at)) = (&mut self.first_estimates, linearised_at) {
                fe.predicted_pose = at;
            }
            return Err(EkfError::NonFinite);
        }
        self.x[0] = pred.pose.x;
        self.x[1] = pred.pose.y;
        self.x[2] = pred.pose.z;
        self.p.view_mut((0, 0), (3, n)).copy_from(&new_rows);
        self.p.view_mut((0, 0), (n, 3)).copy_from(&new_rows.transpose());
        self.p.view_mut((0, 0), (3, 3)).copy_from(&(0.5 * (new_pp + new_pp.transpose())));
        Ok(())
    }

    /// Predicted observation of landmark `i`, its Jacobians (robot 2x3, landmark 2x2) and
    /// innovation covariance `S`, or [`EkfError::UnknownLandmark`].
    pub fn predict_observation(&self, model: &RangeBearingModel, i: usize) -> Result<PredictedObservation, EkfError> {
        let li = self.landmark_index(i)?;
        Ok(self.predict_observation_at(model, i, li))
    }

    /// [`Ekf::predict_observation`] of landmark `i`, whose x is at state index `li`.
    fn predict_observation_at(&self, model: &RangeBearingModel, i: usize, li: usize) -> PredictedObservation {
        let (z, mut hr, mut hl) = model.observe(&self.pose(), &self.landmark_at(li));
        if let Some(fe) = &self.first_estimates {
            if fe.observability_constrained {
                (hr, hl) = observability_constrained(&hr, &hl, &fe.predicted_pose, &fe.landmarks[i]);
            } else {
                (_, hr, hl) = model.observe(&fe.predicted_pose, &fe.landmarks[i]);
            }
        }
        let prr = self.pose_covariance();
        let pll = self.p.fixed_view::<2, 2>(li, li).into_owned();
        let prl = self.p.fixed_view::<3, 2>(0, li).into_owned();
        let s = hr * prr * hr.transpose()
            + hr * prl * hl.transpose()
            + hl * prl.transpose() * hr.transpose()
            + hl * pll * hl.transpose()
            + model.noise_at(z.x);
        (z, hr, hl, s)
    }

    /// Squared Mahalanobis distance of observation `z` to landmark `i`, or
    /// [`EkfError::UnknownLandmark`].
    pub fn mahalanobis2(&self, model: &RangeBearingModel, i: usize, z: &Vector2<f64>) -> Result<f64, EkfError> {
        let li = self.landmark_index(i)?;
        Ok(self.mahalanobis2_at(model, i, li, z))
    }

    /// Squared Mahalanobis distance of observation `z` to every landmark, in index order.
    pub fn mahalanobis2_to_all(&self, model: &RangeBearingModel, z: &Vector2<f64>) -> Vec<f64> {
        (0..self.landmark_count()).map(|i| self.mahalanobis2_at(model, i, self.vehicle_dims + 2 * i, z)).collect()
    }

    /// [`Ekf::mahalanobis2`] to landmark `i`, whose x is at state index `li`.
    fn mahalanobis2_at(&self, model: &RangeBearingModel, i: usize, li: usize, z: &Vector2<f64>) -> f64 {
        let (zp, _, _, s) = self.predict_observation_at(model, i, li);
        let nu = Vector2::new(z.x - zp.x, wrap_angle(z.y - zp.y));
        match s.try_inverse() {
            Some(si) => (nu.transpose() * si * nu)[(0, 0)],
            None => f64::INFINITY,
        }
    }

    /// Updates with observation `z` (range, bearing) of landmark `i`.
    pub fn update(&mut self, model: &RangeBearingModel, i: usize, z: &Vector2<f64>) -> Result<(), EkfError> {
        self.update_iterated(model, i, z, 1)
    }

    /// An iterated EKF update (Gauss-Newton on the observation): up to `iterations`
    /// linearisations, each about the previous one's estimate, the covariance updated with
    /// the last. One iteration is the plain update. For corrections large against the
    /// observation model's curvature, such as closing a loop metres off, where a single
    /// linearisation at the predicted pose leaves the filter overconfident. With first
    /// estimates on, the Jacobians stay at those and only the prediction moves, so use one
    /// iteration there.
    pub fn update_iterated(
        &mut self,
        model: &RangeBearingModel,
        i: usize,
        z: &Vector2<f64>,
        iterations: usize,
    ) -> Result<(), EkfError> {
        let li = self.landmark_index(i)?;
        if !(z.x.is_finite() && z.y.is_finite()) {
            return Err(EkfError::NonFinite);
        }
        let n = self.x.len();
        let prior = self.x.clone();
        let mut last = None;
        for _ in 0..iterations.max(1) {
            // Prediction and Jacobians at the current linearisation point (self.x); the
            // covariance is the prior's throughout.
            let (zp, hr, hl, s) = self.predict_observation_at(model, i, li);
            let mut nu = Vector2::new(z.x - zp.x, wrap_angle(z.y - zp.y));
            if last.is_some() {
                // z - h(x_i) - H (x_prior - x_i).
                let dp = Vector3::new(prior[0] - self.x[0], prior[1] - self.x[1], wrap_angle(prior[2] - self.x[2]));
                let dl = Vector2::new(prior[li] - self.x[li], prior[li + 1] - self.x[li + 1]);
                nu -= hr * dp + hl * dl;
                nu.y = wrap_angle(nu.y);
            }
            // P Hᵀ from the five columns H touches.
            let mut pht = DMatrix::zeros(n, 2);
            for r in 0..n {
                for k in 0..2 {
                    let mut acc = 0.0;
                    for c in 0..3 {
                        acc += self.p[(r, c)] * hr[(k, c)];
                    }
                    for c in 0..2 {
                        acc += self.p[(r, li + c)] * hl[(k, c)];
                    }
                    pht[(r, k)] = acc;
                }
            }
            let Some(s_chol) = s.cholesky() else {
                self.x = prior;
                return Err(EkfError::NotPositiveDefinite);
            };
            let s_inv = s_chol.inverse();
            let k = &pht * s_inv; // n x 2
            let mut next = &prior + &k * nu;
            next[2] = wrap_angle(next[2]);
            let step = (&next - &self.x).amax();
            self.x = next;
            last = Some((k, pht, s));
            if step < 1e-9 {
                break;
            }
        }
        let (k, pht, s) = last.expect("at least one iteration");
        // Joseph form, expanded: P - K (HP) - (HP)ᵀ Kᵀ + K S Kᵀ, with HP = (PHᵀ)ᵀ = Wᵀ.
        // One pass over P: entry (i, j) gets g(i, j) + g(j, i) with
        // g(i, j) = -K_i·W_j + ½ (KS)_i·K_j, a sum that is bitwise the same at (j, i), so P
        // stays exactly symmetric without a separate symmetrisation pass.
        let ks = &k * s;
        let kr: Vec<[f64; 2]> = (0..n).map(|r| [k[(r, 0)], k[(r, 1)]]).collect();
        let wr: Vec<[f64; 2]> = (0..n).map(|r| [pht[(r, 0)], pht[(r, 1)]]).collect();
        let ksr: Vec<[f64; 2]> = (0..n).map(|r| [ks[(r, 0)], ks[(r, 1)]]).collect();
        for j in 0..n {
            let (kj, wj, ksj) = (kr[j], wr[j], ksr[j]);
            let col = &mut self.p.as_mut_slice()[j * n..(j + 1) * n];
            for (((pij, ki), wi), ksi) in col.iter_mut().zip(&kr).zip(&wr).zip(&ksr) {
                let gij = -(ki[0] * wj[0] + ki[1] * wj[1]) + 0.5 * (ksi[0] * kj[0] + ksi[1] * kj[1]);
                let gji = -(kj[0] * wi[0] + kj[1] * wi[1]) + 0.5 * (ksj[0] * ki[0] + ksj[1] * ki[1]);
                *pij += gij + gji;
            }
        }
        Ok(())
    }

    /// Updates with several observations at once, `(landmark, z)` pairs, as one stacked
    /// observation: one pass over P for the whole scan where [`Ekf::update`] makes one per
    /// observation, which is what costs at hundreds of landmarks. The result differs from
    /// the sequential updates only in where the later observations are linearised (at the
    /// prior rather than at the estimate after the earlier ones).
    pub fn update_batch(&mut self, model: &RangeBearingModel, pairs: &[(usize, Vector2<f64>)]) -> Result<(), EkfError> {
        if let Some(&(i, _)) = pairs.iter().find(|(i, _)| *i >= self.landmark_count()) {
            return Err(EkfError::UnknownLandmark(i));
        }
        if pairs.iter().any(|(_, z)| !(z.x.is_finite() && z.y.is_finite())) {
            return Err(EkfError::NonFinite);
        }
        let n = self.x.len();
        let m = 2 * pairs.len();
        if m == 0 {
            return Ok(());
        }
        let rows: Vec<_> = pairs
            .iter()
            .map(|(i, z)| {
                let li = self.vehicle_dims + 2 * i;
                let (zp, hr, hl, _) = self.predict_observation_at(model, *i, li);
                (li, Vector2::new(z.x - zp.x, wrap_angle(z.y - zp.y)), hr, hl, zp.x)
            })
            .collect();
        // W = P Hᵀ (n x m, column-major), from the five columns of P each observation touches.
        let pcol = |c: usize| &self.p.as_slice()[c * n..(c + 1) * n];
        let mut w = vec![0.0; n * m];
        for (a, (li, _, hr, hl, _)) in rows.iter().enumerate() {
            for k in 0..2 {
                let col = &mut w[(2 * a + k) * n..(2 * a + k + 1) * n];
                let terms = [
                    (pcol(0), hr[(k, 0)]),
                    (pcol(1), hr[(k, 1)]),
                    (pcol(2), hr[(k, 2)]),
                    (pcol(*li), hl[(k, 0)]),
                    (pcol(li + 1), hl[(k, 1)]),
                ];
                for (src, h) in terms {
                    for (o, v) in col.iter_mut().zip(src) {
                        *o += v * h;
                    }
                }
            }
        }
        // S = H W + R.
        let mut s = DMatrix::zeros(m, m);
        for (a, (li, _, hr, hl, range)) in rows.iter().enumerate() {
            for col in 0..m {
                let wc = &w[col * n..(col + 1) * n];
                for k in 0..2 {
                    s[(2 * a + k, col)] = hr[(k, 0)] * wc[0]
                        + hr[(k, 1)] * wc[1]
                        + hr[(k, 2)] * wc[2]
                        + hl[(k, 0)] * wc[*li]
                        + hl[(k, 1)] * wc[li + 1];
                }
            }
            let r = model.noise_at(*range);
            for (k, l) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                s[(2 * a + k, 2 * a + l)] += r[(k, l)];
            }
        }
        let s = 0.5 * (&s + s.transpose());
        let chol = s.cholesky().ok_or(EkfError::NotPositiveDefinite)?;
        let nu = DVector::from_iterator(m, rows.iter().flat_map(|r| [r.1.x, r.1.y]));
        // V = W L⁻ᵀ (S = L Lᵀ) first: nothing changes if it fails.
        let wt = DMatrix::from_fn(m, n, |r, c| w[r * n + c]);
        let vt = chol.l().solve_lower_triangular(&wt).ok_or(EkfError::NotPositiveDefinite)?; // m x n
        // x += W S⁻¹ ν.
        let s_inv_nu = chol.solve(&nu);
        for (col, c) in s_inv_nu.iter().enumerate() {
            for (xr, wr) in self.x.iter_mut().zip(&w[col * n..(col + 1) * n]) {
                *xr += wr * c;
            }
        }
        self.x[2] = wrap_angle(self.x[2]);
        // P -= W S⁻¹ Wᵀ = V Vᵀ.
        let vcols: Vec<Vec<f64>> = (0..m).map(|k| vt.row(k).iter().copied().collect()).collect();
        subtract_outer_product(self.p.as_mut_slice(), n, &vcols);
        Ok(())
    }

    /// Adds a landmark from observation `z` with full cross-covariances; returns its index.
    /// An observation that is not finite is refused ([`EkfError::NonFinite`]).
    pub fn add_landmark(&mut self, model: &RangeBearingModel, z: &Vector2<f64>) -> Result<usize, EkfError> {
        Ok(self.add_landmarks(model, std::slice::from_ref(z))?.start)
    }

    /// Adds one landmark per observation in `zs`, all seen from the current pose, with one
    /// growth of the covariance (adding them one by one copies it once each); returns their
    /// indices. The result is the same as adding them one at a time, to rounding.
    /// An observation that is not finite is refused ([`EkfError::NonFinite`]), none added.
    pub fn add_landmarks(
        &mut self,
        model: &RangeBearingModel,
        zs: &[Vector2<f64>],
    ) -> Result<std::ops::Range<usize>, EkfError> {
        let first = self.landmark_count();
        if !zs.iter().all(|z| z.iter().all(|v| v.is_finite())) {
            return Err(EkfError::NonFinite);
        }
        if zs.is_empty() {
            return Ok(first..first);
        }
        let n = self.x.len();
        let m = 2 * zs.len();
        let pose = self.pose();
        let prr = self.pose_covariance();
        let jacobians: Vec<_> = zs.iter().map(|z| (model.inverse(&pose, z), z.x)).collect();
        // Grow in place: the old entries keep their place in the top-left block.
        let mut p = std::mem::replace(&mut self.p, DMatrix::zeros(0, 0)).resize(n + m, n + m, 0.0);
        let prx = p.view((0, 0), (3, n)).into_owned();
        for (a, ((l, gr, gz), range)) in jacobians.iter().enumerate() {
            let la = n + 2 * a;
            // P_lx = Gr P_rx (x: the old state and the landmarks added before this one);
            // P_ll = Gr P_rr Grᵀ + Gz R Gzᵀ.
            let plx = gr * &prx;
            p.view_mut((la, 0), (2, n)).copy_from(&plx);
            p.view_mut((0, la), (n, 2)).copy_from(&plx.transpose());
            for (b, ((_, gr_b, _), _)) in jacobians[..a].iter().enumerate() {
                let lb = n + 2 * b;
                let cross = gr * prr * gr_b.transpose();
                p.view_mut((la, lb), (2, 2)).copy_from(&cross);
                p.view_mut((lb, la), (2, 2)).copy_from(&cross.transpose());
            }
            let pll = gr * prr * gr.transpose() + gz * model.noise_at(*range) * gz.transpose();
            p.view_mut((la, la), (2, 2)).copy_from(&pll);
            if let Some(fe) = &mut self.first_estimates {
                fe.landmarks.push(*l);
            }
        }
        let mut x = std::mem::replace(&mut self.x, DVector::zeros(0)).resize_vertically(n + m, 0.0);
        for (a, ((l, _, _), _)) in jacobians.iter().enumerate() {
            x[n + 2 * a] = l.x;
            x[n + 2 * a + 1] = l.y;
        }
        self.x = x;
        self.p = p;
        Ok(first..self.landmark_count())
    }

    /// Squared Mahalanobis distance between landmarks `i` and `j` (the covariance of their
    /// difference, cross terms included) and that covariance, or
    /// [`EkfError::UnknownLandmark`].
    pub fn landmark_difference(&self, i: usize, j: usize) -> Result<(f64, Matrix2<f64>), EkfError> {
        let (li, lj) = (self.landmark_index(i)?, self.landmark_index(j)?);
        let block = |r: usize, c: usize| self.p.fixed_view::<2, 2>(r, c).into_owned();
        let pij = block(li, lj);
        let c = block(li, li) + block(lj, lj) - pij - pij.transpose();
        let d = self.landmark_at(li) - self.landmark_at(lj);
        let m2 = c.try_inverse().map_or(f64::INFINITY, |ci| (d.transpose() * ci * d)[(0, 0)]);
        Ok((m2, c))
    }

    /// Fuses landmark `remove` into `keep`: the constraint `l_keep - l_remove = 0`, with
    /// noise `noise_sigma_m` per axis, as an update (so the whole map and the pose move by
    /// their correlations), then `remove` leaves the state. Indices after `remove` shift
    /// down by one.
    pub fn merge_landmarks(&mut self, keep: usize, remove: usize, noise_sigma_m: f64) -> Result<(), EkfError> {
        let count = self.landmark_count();
        if keep >= count || remove >= count || keep == remove {
            return Err(EkfError::UnknownLandmark(remove.max(keep)));
        }
        let (lk, lr) = (self.vehicle_dims + 2 * keep, self.vehicle_dims + 2 * remove);
        let n = self.x.len();
        // W = P Hᵀ with H = [.. I .. -I ..].
        let mut w = DMatrix::zeros(n, 2);
        for r in 0..n {
            for k in 0..2 {
                w[(r, k)] = self.p[(r, lk + k)] - self.p[(r, lr + k)];
            }
        }
        let (_, c) = self.landmark_difference(keep, remove)?;
        let s = c + Matrix2::identity() * noise_sigma_m * noise_sigma_m;
        let s_inv = s.cholesky().ok_or(EkfError::NotPositiveDefinite)?.inverse();
        let nu = -(self.landmark_at(lk) - self.landmark_at(lr));
        let g = &w * s_inv; // the gain, n x 2
        self.x += &g * nu;
        self.x[2] = wrap_angle(self.x[2]);
        // P <- P - K S Kᵀ = P - G Wᵀ, formed symmetrically.
        for j in 0..n {
            for i in 0..n {
                let a = g[(i, 0)] * w[(j, 0)] + g[(i, 1)] * w[(j, 1)];
                let b = g[(j, 0)] * w[(i, 0)] + g[(j, 1)] * w[(i, 1)];
                self.p[(i, j)] -= 0.5 * (a + b);
            }
        }
        self.remove_landmark(remove)
    }

    /// Removes landmark `i` (its rows and columns), shifting later indices down, or
    /// returns [`EkfError::UnknownLandmark`].
    pub fn remove_landmark(&mut self, i: usize) -> Result<(), EkfError> {
        let li = self.landmark_index(i)?;
        // Shrunk in place, not copied.
        self.x = std::mem::replace(&mut self.x, DVector::zeros(0)).remove_rows(li, 2);
        self.p = std::mem::replace(&mut self.p, DMatrix::zeros(0, 0)).remove_rows(li, 2).remove_columns(li, 2);
        if let Some(fe) = &mut self.first_estimates {
            fe.landmarks.remove(i);
        }
        Ok(())
    }
}

/// A predicted observation `(z, H_robot, H_landmark, S)`: range and bearing, the
/// Jacobians (robot 2x3, landmark 2x2) and the innovation covariance.
pub type PredictedObservation = (Vector2<f64>, Matrix2x3<f64>, Matrix2<f64>, Matrix2<f64>);

/// The observation Jacobian `[hr hl]` (robot pose, landmark) changed as little as possible,
/// in the least-squares sense, so that it is blind to the motions of the whole map that
/// nothing observes: translating robot and landmark together, and rotating them together
/// about the robot, as the first estimates (`pose`, `landmark`) place them. With those
/// points the filter's propagation keeps the same directions unobservable (first-estimate
/// propagation), so the global heading gains no information it does not have.
fn observability_constrained(
    hr: &Matrix2x3<f64>,
    hl: &Matrix2<f64>,
    pose: &Vector3<f64>,
    landmark: &Vector2<f64>,
) -> (Matrix2x3<f64>, Matrix2<f64>) {
    let h = SMatrix::<f64, 2, 5>::from_columns(&[
        hr.column(0).into_owned(),
        hr.column(1).into_owned(),
        hr.column(2).into_owned(),
        hl.column(0).into_owned(),
        hl.column(1).into_owned(),
    ]);
    // The unobservable directions: x and y translation, and rotation about the robot.
    let (dx, dy) = (landmark.x - pose.x, landmark.y - pose.y);
    let n = SMatrix::<f64, 5, 3>::from_row_slice(&[
        1.0, 0.0, 0.0, //
        0.0, 1.0, 0.0, //
        0.0, 0.0, 1.0, //
        1.0, 0.0, -dy, //
        0.0, 1.0, dx,
    ]);
    // NᵀN is positive definite whatever the points (the pose's rows alone make it so).
    let ntn_inv = (n.transpose() * n).try_inverse().unwrap_or_else(SMatrix::zeros);
    let constrained = h - h * n * ntn_inv * n.transpose();
    (constrained.fixed_columns::<3>(0).into_owned(), constrained.fixed_columns::<2>(3).into_owned())
}

/// `p` (n x n, column-major) minus `V Vᵀ`, where `v[k]` is column k of V (n long). Every
/// entry is computed, column by column, so `p` is written in one stream (computing only
/// the lower triangle and mirroring it costs more in scattered writes than it saves in
/// arithmetic); entry (i, j) and entry (j, i) add the same products in the same order, so
/// `p` stays exactly as symmetric as it was.
fn subtract_outer_product(p: &mut [f64], n: usize, v: &[Vec<f64>]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the processor has AVX, checked just above.
        return unsafe { subtract_outer_product_avx(p, n, v) };
    }
    subtract_outer_product_body(p, n, v)
}

/// The same loops compiled for AVX's 4-wide f64 registers (the baseline x86-64 target has
/// 2-wide SSE). Without FMA every product and sum is rounded as in the baseline code, so
/// results are bit-identical on every x86-64 processor.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn subtract_outer_product_avx(p: &mut [f64], n: usize, v: &[Vec<f64>]) {
    subtract_outer_product_body(p, n, v)
}

/// A tile of rows x columns whose sums stay in registers over all of V's columns: each
/// value of V loaded serves four columns.
const TILE_ROWS: usize = 8;
const TILE_COLS: usize = 4;

#[inline(always)]
fn subtract_outer_product_body(p: &mut [f64], n: usize, v: &[Vec<f64>]) {
    let mut w = vec![[0.0; TILE_COLS]; v.len()];
    let mut j = 0;
    while j + TILE_COLS <= n {
        for (wk, vk) in w.iter_mut().zip(v) {
            wk.copy_from_slice(&vk[j..j + TILE_COLS]);
        }
        let cols = &mut p[j * n..(j + TILE_COLS) * n];
        let mut r = 0;
        while r + TILE_ROWS <= n {
            let sums = outer_tile(v, &w, r);
            for (c, s) in sums.iter().enumerate() {
                for (pij, a) in cols[c * n + r..c * n + r + TILE_ROWS].iter_mut().zip(s) {
                    *pij -= a;
                }
            }
            r += TILE_ROWS;
        }
        for c in 0..TILE_COLS {
            for i in r..n {
                cols[c * n + i] -= outer_entry(v, i, j + c);
            }
        }
        j += TILE_COLS;
    }
    for jj in j..n {
        for i in 0..n {
            p[jj * n + i] -= outer_entry(v, i, jj);
        }
    }
}

/// Sums over k of v_k[i0 + r] v_k[j + c] for a tile, added in k order from zero, as
/// [`outer_entry`] adds them.
#[inline(always)]
fn outer_tile(v: &[Vec<f64>], w: &[[f64; TILE_COLS]], i0: usize) -> [[f64; TILE_ROWS]; TILE_COLS] {
    let mut acc = [[0.0f64; TILE_ROWS]; TILE_COLS];
    for (vk, wk) in v.iter().zip(w) {
        let s = &vk[i0..i0 + TILE_ROWS];
        for c in 0..TILE_COLS {
            for r in 0..TILE_ROWS {
                acc[c][r] += s[r] * wk[c];
            }
        }
    }
    acc
}

/// Sum over k of v_k[i] v_k[j], added in k order from zero.
#[inline(always)]
fn outer_entry(v: &[Vec<f64>], i: usize, j: usize) -> f64 {
    let mut a = 0.0;
    for vk in v {
        a += vk[i] * vk[j];
    }
    a
}

#[cfg(test)]
mod tests;
