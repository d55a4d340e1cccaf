//! Relinearising the filter after a loop closure: Gauss-Newton over its whole history.
//!
//! An EKF linearises every prediction and update once, at the estimate of the moment. When
//! a loop closes metres off, landmarks not seen since before the loop move only by the
//! correlations built up along it, a correction linear in heading errors of many degrees,
//! and are left where their re-observation no longer matches (`long_loop`'s wrong
//! associations and duplicates). [`History`] keeps what the filter was told (odometry
//! between the poses at which it observed, each observation with its landmark's id);
//! [`History::relinearise`] solves the whole problem again (every such pose, the odometry
//! calibration, every landmark) by Levenberg-Marquardt from the current estimates, and
//! hands the filter the current pose, calibration and map with their marginal covariance.
//! In a linear-Gaussian world that is the filter's own answer; here it is the answer with
//! every Jacobian taken where the loop closure says things are.
//!
//! The poses form a chain (odometry links only neighbours), the rest (current pose,
//! calibration, landmarks) a small dense border, so the normal equations are block
//! tridiagonal with a border: a block Cholesky of the chain and the border's Schur
//! complement solve them in O(poses x border²), and that Schur complement's inverse is the
//! filter's new covariance.

use std::ops::AddAssign;

use nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Matrix3xX, Vector2, Vector3};

use super::{Ekf, MotionModel, RangeBearingModel};
use crate::messages::wrap_angle;

/// Why a relinearisation was not applied (the filter is then left as it was).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SmootherError {
    #[error("the normal equations are not positive definite")]
    NotPositiveDefinite,
    #[error("landmark {0} of the filter was never observed in the history")]
    Unobserved(u32),
    #[error("the filter's state does not match the history ({0})")]
    Mismatch(&'static str),
    /// The motion model refused a prediction of the history: a control of another length
    /// than it takes, or calibration parameters it does not estimate.
    #[error("the motion model refused a prediction of the history: {0}")]
    Motion(#[from] super::EkfError),
}

/// One pose of the history: the odometry that led to it from the previous one, and the
/// observations made there.
#[derive(Debug, Clone, PartialEq)]
struct Node {
    controls: Vec<[f64; 3]>,
    observations: Vec<(u32, Vector2<f64>)>,
    estimate: Vector3<f64>,
}

/// What the filter was told, kept for [`History::relinearise`].
#[derive(Debug, Clone, PartialEq)]
pub struct History {
    start: Vector3<f64>,
    start_covariance: Matrix3<f64>,
    calibration_sigma: Vec<f64>,
    nodes: Vec<Node>,
}

/// What one relinearisation did.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Relinearisation {
    /// Poses solved for (the current one included).
    pub poses: usize,
    pub landmarks: usize,
    pub iterations: usize,
    /// Weighted squared residuals before and after.
    pub initial_cost: f64,
    pub final_cost: f64,
}

/// A factor's variable: pose `k` of the chain, or a slice of the border.
#[derive(Debug, Clone, Copy)]
enum Var {
    Chain(usize),
    Border(usize),
}

/// A solution of the normal equations: the chain's and the border's steps, and the
/// border's Schur complement (its inverse is the border's covariance when undamped).
struct Step {
    chain: Vec<Vector3<f64>>,
    border: DVector<f64>,
    schur: DMatrix<f64>,
}

/// The normal equations H dx = -g, split into the chain's block tridiagonal part, its
/// coupling to the border and the border's dense block.
struct Normal {
    diag: Vec<Matrix3<f64>>,
    /// `off[k]`: the block between chain poses k and k + 1 (row k, column k + 1).
    off: Vec<Matrix3<f64>>,
    /// `coupling[k]`: rows of chain pose k, columns of the border.
    coupling: Vec<Matrix3xX<f64>>,
    border: DMatrix<f64>,
    g_chain: Vec<Vector3<f64>>,
    g_border: DVector<f64>,
    cost: f64,
}

impl Normal {
    fn new(chain: usize, nb: usize) -> Self {
        Normal {
            diag: vec![Matrix3::zeros(); chain],
            off: vec![Matrix3::zeros(); chain.saturating_sub(1)],
            coupling: vec![Matrix3xX::zeros(nb); chain],
            border: DMatrix::zeros(nb, nb),
            g_chain: vec![Vector3::zeros(); chain],
            g_border: DVector::zeros(nb),
            cost: 0.0,
        }
    }

    /// Adds a factor with residual `r`, information `w` and Jacobian blocks `blocks`.
    fn add(&mut self, r: &DVector<f64>, w: &DMatrix<f64>, blocks: &[(Var, DMatrix<f64>)]) {
        self.cost += (r.transpose() * w * r)[(0, 0)];
        let wr = w * r;
        let wj: Vec<DMatrix<f64>> = blocks.iter().map(|(_, j)| w * j).collect();
        for (a, (va, ja)) in blocks.iter().enumerate() {
            let ga = ja.transpose() * &wr;
            match *va {
                Var::Chain(k) => self.g_chain[k] += Vector3::from_column_slice(ga.as_slice()),
                Var::Border(o) => self.g_border.rows_mut(o, ga.len()).add_assign(&ga),
            }
            for (b, (vb, _)) in blocks.iter().enumerate().skip(a) {
                let h = ja.transpose() * &wj[b];
                self.add_block(*va, *vb, &h);
            }
        }
    }

    /// H[a, b] += h (and H[b, a] += hᵀ when a and b differ).
    fn add_block(&mut self, a: Var, b: Var, h: &DMatrix<f64>) {
        match (a, b) {
            (Var::Chain(i), Var::Chain(j)) if i == j => self.diag[i] += Matrix3::from_column_slice(h.as_slice()),
            (Var::Chain(i), Var::Chain(j)) if j == i + 1 => self.off[i] += Matrix3::from_column_slice(h.as_slice()),
            (Var::Chain(i), Var::Chain(j)) if i == j + 1 => {
                self.off[j] += Matrix3::from_column_slice(h.transpose().as_slice())
            }
            (Var::Chain(_), Var::Chain(_)) => unreachable!("odometry links only neighbouring poses"),
            (Var::Chain(k), Var::Border(o)) => self.coupling[k].view_mut((0, o), (3, h.ncols())).add_assign(h),
            (Var::Border(o), Var::Chain(k)) => {
                self.coupling[k].view_mut((0, o), (3, h.nrows())).add_assign(&h.transpose())
            }
            (Var::Border(o1), Var::Border(o2)) => {
                self.border.view_mut((o1, o2), (h.nrows(), h.ncols())).add_assign(h);
                if o1 != o2 {
                    self.border.view_mut((o2, o1), (h.ncols(), h.nrows())).add_assign(&h.transpose());
                }
            }
        }
    }

    /// Solves (H + lambda diag(H)) dx = -g.
    fn solve(&self, lambda: f64) -> Result<Step, SmootherError> {
        let (n, nb) = (self.diag.len(), self.border.nrows());
        let damp3 = |m: &Matrix3<f64>| m + Matrix3::from_diagonal(&m.diagonal()) * lambda;
        // Block Cholesky of the chain: L[k][k] lower triangular (kept as its inverse),
        // L[k+1][k] = below[k].
        let mut l_inv: Vec<Matrix3<f64>> = Vec::with_capacity(n);
        let mut below: Vec<Matrix3<f64>> = Vec::with_capacity(n.saturating_sub(1));
        for k in 0..n {
            let mut d = damp3(&self.diag[k]);
            if k > 0 {
                let b: &Matrix3<f64> = &below[k - 1];
                d -= b * b.transpose();
            }
            let l = d.cholesky().ok_or(SmootherError::NotPositiveDefinite)?.l();
            let linv = l.try_inverse().ok_or(SmootherError::NotPositiveDefinite)?;
            if k + 1 < n {
                // below = H[k+1][k] L⁻ᵀ, with H[k+1][k] = off[k]ᵀ.
                below.push(self.off[k].transpose() * linv.transpose());
            }
            l_inv.push(linv);
        }
        // Forward substitution: Y = L⁻¹ Cᵀ (C = coupling), y = L⁻¹ g.
        let mut ys: Vec<Matrix3xX<f64>> = Vec::with_capacity(n);
        let mut yg: Vec<Vector3<f64>> = Vec::with_capacity(n);
        let mut schur = self.border.clone();
        for i in 0..nb {
            schur[(i, i)] += lambda * self.border[(i, i)];
        }
        let mut g_border = self.g_border.clone();
        for k in 0..n {
            let mut rhs = self.coupling[k].clone();
            let mut rg = self.g_chain[k];
            if k > 0 {
                rhs -= below[k - 1] * &ys[k - 1];
                rg -= below[k - 1] * yg[k - 1];
            }
            let y = l_inv[k] * rhs;
            let v = l_inv[k] * rg;
            schur.gemm_tr(-1.0, &y, &y, 1.0);
            g_border.gemv_tr(-1.0, &y, &v, 1.0);
            ys.push(y);
            yg.push(v);
        }
        let chol = schur.clone().cholesky().ok_or(SmootherError::NotPositiveDefinite)?;
        let step_border = -chol.solve(&g_border);
        // Back substitution: Lᵀ dx = -y - Y dx_border.
        let mut step_chain = vec![Vector3::zeros(); n];
        for k in (0..n).rev() {
            let mut rhs = -yg[k] - &ys[k] * &step_border;
            if k + 1 < n {
                rhs -= below[k].transpose() * step_chain[k + 1];
            }
            step_chain[k] = l_inv[k].transpose() * rhs;
        }
        Ok(Step { chain: step_chain, border: step_border, schur })
    }
}

impl History {
    /// A history starting at `start` with covariance `start_covariance`; the filter
    /// estimates calibration parameters with prior standard deviations `calibration_sigma`.
    pub fn new(start: Vector3<f64>, start_covariance: Matrix3<f64>, calibration_sigma: &[f64]) -> Self {
        History {
            start,
            start_covariance,
            calibration_sigma: calibration_sigma.to_vec(),
            nodes: vec![Node { controls: Vec::new(), observations: Vec::new(), estimate: start }],
        }
    }

    /// Odometry `u` moved the robot; `estimate` is the filter's pose after it.
    pub fn push_control(&mut self, u: [f64; 3], estimate: Vector3<f64>) {
        let last = self.nodes.len() - 1;
        if last > 0 && self.nodes[last].observations.is_empty() {
            self.nodes[last].controls.push(u);
            self.nodes[last].estimate = estimate;
        } else {
            self.nodes.push(Node { controls: vec![u], observations: Vec::new(), estimate });
        }
    }

    /// Landmark `id` was observed at `z` (range, bearing) from the current pose.
    pub fn observe(&mut self, id: u32, z: Vector2<f64>) {
        self.nodes.last_mut().expect("a history has a start").observations.push((id, z));
    }

    /// The filter's current pose after its updates.
    pub fn set_estimate(&mut self, estimate: Vector3<f64>) {
        self.nodes.last_mut().expect("a history has a start").estimate = estimate;
    }

    /// Landmark `from` was found to be landmark `to`: its observations become `to`'s.
    pub fn relabel(&mut self, from: u32, to: u32) {
        for node in &mut self.nodes {
            for (id, _) in &mut node.observations {
                if *id == from {
                    *id = to;
                }
            }
        }
    }

    /// Number of poses kept.
    pub fn poses(&self) -> usize {
        self.nodes.len()
    }

    /// Weighted squared residuals and the normal equations at `poses`, `calibration` and
    /// `landmarks` (ordered as `ids`).
    fn linearise(
        &self,
        motion: &dyn MotionModel,
        sensor: &RangeBearingModel,
        poses: &[Vector3<f64>],
        calibration: &DVector<f64>,
        landmarks: &[Vector2<f64>],
        slot: &impl Fn(u32) -> Option<usize>,
    ) -> Result<Normal, SmootherError> {
        let k_now = poses.len() - 1;
        let nc = calibration.len();
        let nb = 3 + nc + 2 * landmarks.len();
        let mut normal = Normal::new(k_now, nb);
        let pose_var = |k: usize| if k == k_now { Var::Border(0) } else { Var::Chain(k) };
        let landmark_var = |j: usize| Var::Border(3 + nc + 2 * j);
        // Priors: the start pose and the calibration.
        let mut r = poses[0] - self.start;
        r.z = wrap_angle(r.z);
        let w = self.start_covariance.try_inverse().unwrap_or_else(|| Matrix3::identity() * 1e12);
        normal.add(
            &DVector::from_column_slice(r.as_slice()),
            &DMatrix::from_column_slice(3, 3, w.as_slice()),
            &[(pose_var(0), DMatrix::identity(3, 3))],
        );
        if nc > 0 {
            let w = DMatrix::from_diagonal(&DVector::from_iterator(
                nc,
                self.calibration_sigma.iter().map(|s| 1.0 / (s * s).max(1e-12)),
            ));
            normal.add(calibration, &w, &[(Var::Border(3), DMatrix::identity(nc, nc))]);
        }
        let cal = calibration.as_slice();
        for (k, node) in self.nodes.iter().enumerate() {
            if k > 0 {
                // Odometry from pose k - 1: composed prediction, its Jacobians and noise.
                let mut pose = poses[k - 1];
                let mut phi = Matrix3::identity();
                let mut psi = Matrix3xX::zeros(nc);
                let mut q = Matrix3::zeros();
                for u in &node.controls {
                    let p = motion.predict_calibrated(&pose, cal, u)?;
                    psi = p.f * psi + &p.f_calibration;
                    phi = p.f * phi;
                    q = p.f * q * p.f.transpose() + p.q;
                    pose = p.pose;
                }
                let mut r = poses[k] - pose;
                r.z = wrap_angle(r.z);
                let w = q.try_inverse().unwrap_or_else(|| Matrix3::identity() * 1e12);
                let mut blocks = vec![
                    (pose_var(k), DMatrix::identity(3, 3)),
                    (pose_var(k - 1), -DMatrix::from_column_slice(3, 3, phi.as_slice())),
                ];
                if nc > 0 {
                    blocks.push((Var::Border(3), -DMatrix::from_column_slice(3, nc, psi.as_slice())));
                }
                normal.add(
                    &DVector::from_column_slice(r.as_slice()),
                    &DMatrix::from_column_slice(3, 3, w.as_slice()),
                    &blocks,
                );
            }
            for (id, z) in &node.observations {
                let Some(j) = slot(*id) else { continue };
                let (zp, hr, hl) = sensor.observe(&poses[k], &landmarks[j]);
                let r = DVector::from_column_slice(&[zp.x - z.x, wrap_angle(zp.y - z.y)]);
                let r_inv = sensor.noise_at(zp.x).try_inverse().unwrap_or_else(|| Matrix2::identity() * 1e12);
                let r_inv = DMatrix::from_column_slice(2, 2, r_inv.as_slice());
                normal.add(
                    &r,
                    &r_inv,
                    &[
                        (pose_var(k), DMatrix::from_column_slice(2, 3, hr.as_slice())),
                        (landmark_var(j), DMatrix::from_column_slice(2, 2, hl.as_slice())),
                    ],
                );
            }
        }
        Ok(normal)
    }

    /// Re-solves the history and replaces `ekf`'s state and covariance with the current
    /// pose, calibration and landmarks (`ids[j]` is the id of the filter's landmark j).
    /// Observations of landmarks no longer in the filter are left out. The past poses keep
    /// their new estimates as the next start. On error the filter is unchanged.
    ///
    /// The solver starts from the poses recorded (the current one as last predicted or set)
    /// and `before`, the filter's state before the updates that prompted this: that is the
    /// map those poses agree with. Started from the corrected map instead, the first steps
    /// move poses by tens of metres and can end in another minimum (`long_loop`: trees
    /// 7 m from where the filter had them right). Landmarks that `before` lacks (added
    /// since) start at the filter's estimates.
    pub fn relinearise(
        &mut self,
        ekf: &mut Ekf,
        before: &DVector<f64>,
        motion: &dyn MotionModel,
        sensor: &RangeBearingModel,
        ids: &[u32],
        max_iterations: usize,
    ) -> Result<Relinearisation, SmootherError> {
        let nc = ekf.vehicle_dims - 3;
        if nc != self.calibration_sigma.len() {
            return Err(SmootherError::Mismatch("calibration parameters"));
        }
        if ids.len() != ekf.landmark_count() {
            return Err(SmootherError::Mismatch("landmark count"));
        }
        for &id in ids {
            if !self.nodes.iter().any(|n| n.observations.iter().any(|(o, _)| *o == id)) {
                return Err(SmootherError::Unobserved(id));
            }
        }
        if before.len() < ekf.vehicle_dims {
            return Err(SmootherError::Mismatch("starting state"));
        }
        let slot = |id: u32| ids.iter().position(|&i| i == id);
        let mut poses: Vec<Vector3<f64>> = self.nodes.iter().map(|n| n.estimate).collect();
        let mut calibration = DVector::from_column_slice(&before.as_slice()[3..ekf.vehicle_dims]);
        let mut landmarks: Vec<Vector2<f64>> = ekf
            .landmarks()
            .enumerate()
            .map(|(j, now)| {
                let i = ekf.vehicle_dims + 2 * j;
                if i + 1 < before.len() { Vector2::new(before[i], before[i + 1]) } else { now }
            })
            .collect();
        let mut normal = self.linearise(motion, sensor, &poses, &calibration, &landmarks, &slot)?;
        let initial_cost = normal.cost;
        let mut lambda = 0.0;
        let mut iterations = 0;
        while iterations < max_iterations {
            iterations += 1;
            let Step { chain: step_chain, border: step_border, .. } = normal.solve(lambda)?;
            let mut trial_poses = poses.clone();
            for (p, s) in trial_poses.iter_mut().zip(&step_chain) {
                *p += s;
                p.z = wrap_angle(p.z);
            }
            let last = trial_poses.len() - 1;
            trial_poses[last] += Vector3::new(step_border[0], step_border[1], step_border[2]);
            trial_poses[last].z = wrap_angle(trial_poses[last].z);
            let trial_calibration = &calibration + step_border.rows(3, nc);
            let trial_landmarks: Vec<Vector2<f64>> = landmarks
                .iter()
                .enumerate()
                .map(|(j, l)| l + Vector2::new(step_border[3 + nc + 2 * j], step_border[3 + nc + 2 * j + 1]))
                .collect();
            let trial = self.linearise(motion, sensor, &trial_poses, &trial_calibration, &trial_landmarks, &slot)?;
            if trial.cost <= normal.cost {
                let size = step_border.amax().max(step_chain.iter().map(|s| s.amax()).fold(0.0, f64::max));
                (poses, calibration, landmarks, normal) = (trial_poses, trial_calibration, trial_landmarks, trial);
                lambda /= 10.0;
                // A tenth of a millimetre (or of a milliradian) is converged.
                if size < 1e-4 {
                    break;
                }
            } else {
                lambda = if lambda == 0.0 { 1e-4 } else { lambda * 10.0 };
                if lambda > 1e4 {
                    break;
                }
            }
        }
        let covariance = normal.solve(0.0)?.schur.cholesky().ok_or(SmootherError::NotPositiveDefinite)?.inverse();
        let now = poses[poses.len() - 1];
        let mut x = DVector::zeros(3 + nc + 2 * landmarks.len());
        x.rows_mut(0, 3).copy_from(&now);
        x.rows_mut(3, nc).copy_from(&calibration);
        for (j, l) in landmarks.iter().enumerate() {
            x[3 + nc + 2 * j] = l.x;
            x[3 + nc + 2 * j + 1] = l.y;
        }
        ekf.x = x;
        // The inverse of a symmetric matrix, made exactly symmetric.
        ekf.p = (&covariance + covariance.transpose()) * 0.5;
        if ekf.first_estimates.is_some() {
            ekf.use_first_estimates();
        }
        for (node, p) in self.nodes.iter_mut().zip(&poses) {
            node.estimate = *p;
        }
        Ok(Relinearisation {
            poses: poses.len(),
            landmarks: landmarks.len(),
            iterations,
            initial_cost,
            final_cost: normal.cost,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ekf::synthetic::{self, Drive, Route};
    use crate::ekf::{EkfError, PosePrediction, control_values};

    /// `steps` 0.1 m steps turning `turn` rad each, landmarks seen out to 7 m every fifth
    /// step; the odometry reads `scale` long and turns `turn_scale` more.
    fn drive(steps: usize, turn: f64, landmarks: &[Vector2<f64>], scale: f64, turn_scale: f64) -> Drive {
        synthetic::drive(
            &Route { steps, step_m: 0.1, turn, scale, turn_scale, observe_every: 5, max_range_m: 7.0 },
            landmarks,
        )
        .unwrap()
    }

    fn square() -> Drive {
        drive(
            120,
            0.02,
            &[Vector2::new(5.0, 3.0), Vector2::new(5.0, -3.0), Vector2::new(12.0, 2.0), Vector2::new(2.0, 9.0)],
            0.0,
            0.0,
        )
    }

    /// Once round a circle of radius 10 m, seeing landmarks only near the start and on the
    /// far side, and on past the first ones: the loop closes after ~35 m unseen with the
    /// heading ~0.3 rad off.
    fn circle() -> Drive {
        let landmarks = [
            Vector2::new(3.0, -3.0),
            Vector2::new(-2.0, -4.0),
            Vector2::new(4.0, 3.0),
            Vector2::new(3.0, 23.0),
            Vector2::new(-2.0, 24.0),
            Vector2::new(-4.0, 17.0),
        ];
        drive(700, 0.01, &landmarks, 0.02, 0.05)
    }

    fn landmark_rmse(d: &Drive) -> f64 {
        let sum: f64 =
            d.landmarks.iter().enumerate().map(|(j, l)| (d.ekf.landmark(j).unwrap() - l).norm_squared()).sum();
        (sum / d.landmarks.len() as f64).sqrt()
    }

    #[test]
    fn a_history_with_nothing_to_relinearise_is_left_where_the_filter_put_it() {
        let mut d = square();
        let before = d.ekf.clone();
        let start = d.ekf.x.clone();
        let report = d.history.relinearise(&mut d.ekf, &start, &d.motion, &d.sensor, &d.ids, 10).unwrap();
        assert!(report.initial_cost < 1e-6, "exact data fit exactly: {report:?}");
        assert!((d.ekf.pose() - d.truth).amax() < 1e-6);
        assert!(landmark_rmse(&d) < 1e-6);
        // The covariance is the filter's up to linearisation points: close.
        for j in 0..d.ids.len() {
            let (a, b) = (before.landmark_covariance(j).unwrap(), d.ekf.landmark_covariance(j).unwrap());
            assert!((a - b).amax() <= 0.05 * a.amax(), "landmark {j}: {a} vs {b}");
        }
        let (a, b) = (before.pose_covariance(), d.ekf.pose_covariance());
        assert!((a - b).amax() <= 0.05 * a.amax(), "pose: {a} vs {b}");
    }

    #[test]
    fn a_loop_closed_with_biased_odometry_is_relinearised_towards_the_truth() {
        let mut d = circle();
        let (filter_pose, filter_map) = ((d.ekf.pose() - d.truth).xy().norm(), landmark_rmse(&d));
        let start = d.ekf.x.clone();
        let report = d.history.relinearise(&mut d.ekf, &start, &d.motion, &d.sensor, &d.ids, 20).unwrap();
        let (smoothed_pose, smoothed_map) = ((d.ekf.pose() - d.truth).xy().norm(), landmark_rmse(&d));
        eprintln!(
            "{report:?}; pose error {filter_pose:.4} -> {smoothed_pose:.4} m, map RMSE {filter_map:.4} -> {smoothed_map:.4} m; calibration {:?}",
            d.ekf.calibration()
        );
        // The filter closed the loop far from its own model (cost ~3,700 against a few);
        // the solution fits, and lies within centimetres of the truth.
        assert!(report.final_cost < 0.01 * report.initial_cost, "{report:?}");
        assert!(
            smoothed_map < 0.05 && smoothed_pose < 0.05,
            "map RMSE {filter_map} -> {smoothed_map}, pose {filter_pose} -> {smoothed_pose}"
        );
        // It is a minimum: solving again from it moves nothing.
        let solved = d.ekf.clone();
        let start = d.ekf.x.clone();
        let again = d.history.relinearise(&mut d.ekf, &start, &d.motion, &d.sensor, &d.ids, 20).unwrap();
        assert!((again.initial_cost - report.final_cost).abs() < 1e-9 * report.final_cost.max(1.0), "{again:?}");
        assert!((&d.ekf.x - &solved.x).amax() < 1e-6);
        // The covariance is a symmetric positive definite matrix.
        assert!(d.ekf.p.clone().cholesky().is_some());
        assert_eq!(d.ekf.p, d.ekf.p.transpose());
    }

    #[test]
    fn a_landmark_missing_from_the_history_is_an_error_and_changes_nothing() {
        let mut d = square();
        let mut ids = d.ids.clone();
        ids[0] = 7;
        let before = d.ekf.clone();
        let start = d.ekf.x.clone();
        assert_eq!(
            d.history.relinearise(&mut d.ekf, &start, &d.motion, &d.sensor, &ids, 10),
            Err(SmootherError::Unobserved(7))
        );
        assert_eq!(d.ekf, before);
        let start = d.ekf.x.clone();
        assert_eq!(
            d.history.relinearise(&mut d.ekf, &start, &d.motion, &d.sensor, &ids[1..], 10),
            Err(SmootherError::Mismatch("landmark count"))
        );
        assert_eq!(d.ekf, before);
    }

    /// A motion model of two-value controls that estimates no calibration: not the one
    /// the history was recorded with.
    struct TwoValues;

    impl MotionModel for TwoValues {
        fn control_dims(&self) -> usize {
            2
        }
        fn predict(&self, pose: &Vector3<f64>, control: &[f64]) -> Result<PosePrediction, EkfError> {
            let [dx, dth] = control_values(control)?;
            Ok((pose + Vector3::new(dx, 0.0, dth), Matrix3::identity(), Matrix3::identity() * 1e-4))
        }
    }

    #[test]
    fn a_motion_model_that_refuses_the_history_is_an_error_and_changes_nothing() {
        let mut d = square();
        let before = d.ekf.clone();
        let start = d.ekf.x.clone();
        let e = d.history.relinearise(&mut d.ekf, &start, &TwoValues, &d.sensor, &d.ids, 10).unwrap_err();
        // The drive's filter estimates the odometry's three calibration errors, which a
        // model that estimates none refuses before it reads a control.
        assert_eq!(e, SmootherError::Motion(EkfError::CalibrationLength { calibration: 3, model: 0 }));
        assert_eq!(d.ekf, before);
    }
}
