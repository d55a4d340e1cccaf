//! Laser-camera extrinsic calibration after Zhang & Pless (IROS 2004).
//!
//! The extrinsics map camera points to the laser frame: `P_l = Phi P_c + Delta`. A
//! checkerboard seen by the camera gives its plane in the camera frame as the vector
//! `N` (unit normal times distance), so points on it satisfy `N . P_c = |N|^2`. A laser
//! point on the board, `P_l = (x, y, 0)` in the laser's scan plane, therefore satisfies
//! `N . Phi^-1 (P_l - Delta) = |N|^2`, which is linear in `H = Phi^-1 [e_x e_y -Delta]`:
//! `N^T H (x, y, 1)^T = |N|^2`. A least-squares solution of H gives the initial estimate;
//! Levenberg-Marquardt on the point-to-plane distances refines it. The reported 1-sigma
//! uncertainty is the laser's share (the Gauss-Newton covariance scaled by the residual
//! variance) plus each board plane's covariance carried through the solution; warnings
//! flag few poses, board normals spanning too few directions and poorly constrained
//! results. [`segment_board`] finds a board's points in a scan.

use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, SMatrix, SVD, Vector3};
use serde::{Deserialize, Serialize};

use crate::messages::BEAM;

/// Laser <- camera extrinsics: `P_laser = phi * P_camera + delta` (the paper's Phi, Delta).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Extrinsics {
    /// Rotation matrix Phi, row-major.
    pub phi: [[f64; 3]; 3],
    /// Translation Delta (m).
    pub delta: [f64; 3],
}

impl Extrinsics {
    pub fn from_parts(phi: &Matrix3<f64>, delta: &Vector3<f64>) -> Self {
        Extrinsics {
            phi: std::array::from_fn(|r| std::array::from_fn(|c| phi[(r, c)])),
            delta: [delta.x, delta.y, delta.z],
        }
    }

    pub fn phi(&self) -> Matrix3<f64> {
        Matrix3::from_fn(|r, c| self.phi[r][c])
    }

    pub fn delta(&self) -> Vector3<f64> {
        Vector3::from(self.delta)
    }

    /// Maps a camera-frame point into the laser frame.
    pub fn camera_to_laser(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.phi() * p + self.delta()
    }

    /// Maps a laser-frame point into the camera frame.
    pub fn laser_to_camera(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.phi().transpose() * (p - self.delta())
    }

    /// Rotation angle (deg) and translation distance (m) between two calibrations.
    pub fn error_to(&self, other: &Extrinsics) -> (f64, f64) {
        let r = self.phi().transpose() * other.phi();
        let angle = ((r.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees();
        (angle, (self.delta() - other.delta()).norm())
    }
}

/// One board pose: its plane in the camera frame and the laser points on it.
#[derive(Debug, Clone, PartialEq)]
pub struct BoardObservation {
    /// Plane vector N = unit normal * distance from the camera centre.
    pub plane: Vector3<f64>,
    /// Laser points on the board, in the laser's scan plane (x, y).
    pub laser_points: Vec<[f64; 2]>,
    /// Covariance of `plane` (m²), when known (the camera's board fit gives it): it is
    /// carried into the reported uncertainty.
    pub plane_covariance: Option<Matrix3<f64>>,
}

/// Result of a calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationResult {
    pub extrinsics: Extrinsics,
    /// The linear estimate before refinement.
    pub initial: Extrinsics,
    /// RMS point-to-plane distance after refinement (m).
    pub rms_residual_m: f64,
    /// One-sigma uncertainty: rotation (deg, about the laser's x, y, z axes) and
    /// translation (m). The Gauss-Newton covariance (JᵀJ)⁻¹ scaled by the residual
    /// variance (the laser's noise), plus the board planes' covariances carried through
    /// the solution to first order (the camera's share), where the observations give them.
    pub rotation_sigma_deg: [f64; 3],
    pub translation_sigma_m: [f64; 3],
    /// The laser's share alone (the Gauss-Newton covariance).
    pub laser_rotation_sigma_deg: [f64; 3],
    pub laser_translation_sigma_m: [f64; 3],
    pub poses_used: usize,
    pub points_used: usize,
    pub iterations: usize,
    /// Warnings about the pose set (too few, too similar).
    pub warnings: Vec<String>,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CalibrationError {
    #[error(
        "calibration needs at least 5 board poses with laser points (each pose constrains 2 of the 9 unknowns of the linear estimate), got {0}"
    )]
    TooFewPoses(usize),
    #[error("the board poses do not constrain the extrinsics (degenerate geometry): {0}")]
    Degenerate(String),
}

/// Fewest board poses for the linear estimate: each pose's laser points lie on a line, so
/// it constrains only two directions of the 9-dimensional H.
pub const MIN_POSES: usize = 5;
/// Poses below which the result is usually too uncertain to trust.
pub const RECOMMENDED_POSES: usize = 10;
/// Smallest ratio of the board normals' scatter eigenvalues (smallest to largest) without
/// a warning: about +-14 deg of uniformly spread tilt or turn.
pub const MIN_NORMAL_SPREAD: f64 = 0.02;
/// One-sigma uncertainties above which the result is flagged as poorly constrained.
pub const WARN_ROTATION_SIGMA_DEG: f64 = 0.5;
pub const WARN_TRANSLATION_SIGMA_M: f64 = 0.02;

/// Solves for the extrinsics from board observations.
pub fn calibrate(observations: &[BoardObservation]) -> Result<CalibrationResult, CalibrationError> {
    // A plane covariance that is not finite would make the reported uncertainty zero.
    let finite = |o: &BoardObservation| {
        o.plane.iter().all(|v| v.is_finite())
            && o.laser_points.iter().flatten().all(|v| v.is_finite())
            && o.plane_covariance.is_none_or(|c| c.iter().all(|v| v.is_finite()))
    };
    let used: Vec<&BoardObservation> =
        observations.iter().filter(|o| !o.laser_points.is_empty() && o.plane.norm() > 1e-9 && finite(o)).collect();
    if used.len() < MIN_POSES {
        return Err(CalibrationError::TooFewPoses(used.len()));
    }
    let mut warnings = Vec::new();
    if used.len() < RECOMMENDED_POSES {
        warnings.push(format!(
            "only {} board poses; at least {RECOMMENDED_POSES} are recommended for sub-degree accuracy",
            used.len()
        ));
    }
    // Spread of the board normals: if they all point the same way, rotation about them is
    // poorly determined.
    let mut scatter = Matrix3::zeros();
    for o in &used {
        let n = o.plane.normalize();
        scatter += n * n.transpose();
    }
    let eig = scatter.symmetric_eigen();
    let mut ev: Vec<f64> = eig.eigenvalues.iter().copied().collect();
    ev.sort_by(f64::total_cmp);
    if ev[0] / ev[2] < MIN_NORMAL_SPREAD {
        warnings.push(format!(
            "board normals span too few directions (scatter eigenvalues {:.2e}, {:.2e}, {:.2e}; the smallest should be at least {MIN_NORMAL_SPREAD} of the largest): tilt and turn the board more",
            ev[0], ev[1], ev[2]
        ));
    }

    let initial = linear_estimate(&used)?;
    let (extrinsics, iterations, rms, cov) = refine(&used, &initial);
    let points_used: usize = used.iter().map(|o| o.laser_points.len()).sum();
    // A NaN variance stays unknown (`f64::max` would turn it into a certain 0).
    let sd = |c: &Option<DMatrix<f64>>, i: usize| {
        c.as_ref().map_or(f64::NAN, |c| if c[(i, i)].is_nan() { f64::NAN } else { c[(i, i)].max(0.0).sqrt() })
    };
    let laser_cov = cov.as_ref().map(|c| c.laser.clone());
    let total_cov = cov.as_ref().map(|c| c.total.clone());
    let rotation_sigma_deg =
        [sd(&total_cov, 0).to_degrees(), sd(&total_cov, 1).to_degrees(), sd(&total_cov, 2).to_degrees()];
    let translation_sigma_m = [sd(&total_cov, 3), sd(&total_cov, 4), sd(&total_cov, 5)];
    let worst_rot = rotation_sigma_deg.iter().cloned().fold(0.0, f64::max);
    let worst_trans = translation_sigma_m.iter().cloned().fold(0.0, f64::max);
    let unknown = rotation_sigma_deg.iter().chain(&translation_sigma_m).any(|s| s.is_nan());
    if unknown || worst_rot > WARN_ROTATION_SIGMA_DEG || worst_trans > WARN_TRANSLATION_SIGMA_M {
        warnings.push(format!(
            "the poses constrain the extrinsics poorly (1-sigma up to {worst_rot:.2} deg, {worst_trans:.3} m): use more poses with more varied tilts and turns"
        ));
    }
    Ok(CalibrationResult {
        extrinsics,
        initial,
        rms_residual_m: rms,
        rotation_sigma_deg,
        translation_sigma_m,
        laser_rotation_sigma_deg: [
            sd(&laser_cov, 0).to_degrees(),
            sd(&laser_cov, 1).to_degrees(),
            sd(&laser_cov, 2).to_degrees(),
        ],
        laser_translation_sigma_m: [sd(&laser_cov, 3), sd(&laser_cov, 4), sd(&laser_cov, 5)],
        poses_used: used.len(),
        points_used,
        iterations,
        warnings,
    })
}

/// The linear initialisation: least squares for the 9 entries of H.
fn linear_estimate(obs: &[&BoardObservation]) -> Result<Extrinsics, CalibrationError> {
    let rows: usize = obs.iter().map(|o| o.laser_points.len()).sum();
    let mut a = DMatrix::zeros(rows, 9);
    let mut b = DVector::zeros(rows);
    let mut r = 0;
    for o in obs {
        let n = o.plane;
        for p in &o.laser_points {
            let q = [p[0], p[1], 1.0];
            // N^T H q = sum_ij N_i H_ij q_j
            for i in 0..3 {
                for j in 0..3 {
                    a[(r, 3 * i + j)] = n[i] * q[j];
                }
            }
            b[r] = n.norm_squared();
            r += 1;
        }
    }
    let svd = SVD::new(a, true, true);
    let sv = &svd.singular_values;
    let (max, min) = (sv.max(), sv.min());
    if !(min > 1e-9 * max) {
        return Err(CalibrationError::Degenerate(format!(
            "the linear system has condition number {:.1e}",
            max / min.max(1e-300)
        )));
    }
    let h = svd.solve(&b, 1e-12).map_err(|e| CalibrationError::Degenerate(e.to_string()))?;
    let hm = Matrix3::from_fn(|i, j| h[3 * i + j]);
    // H = Phi^-1 [e_x e_y -Delta]: its first two columns are the first two columns of the
    // rotation Phi^-1 (up to noise); complete and orthonormalise with an SVD.
    let (c1, c2) = (hm.column(0).into_owned(), hm.column(1).into_owned());
    let approx = Matrix3::from_columns(&[c1, c2, c1.cross(&c2)]);
    let svd = approx.svd(true, true);
    let (u, vt) = (svd.u.expect("u"), svd.v_t.expect("v_t"));
    let mut phi_inv = u * vt;
    if phi_inv.determinant() < 0.0 {
        let mut u2 = u;
        u2.column_mut(2).neg_mut();
        phi_inv = u2 * vt;
    }
    let phi = phi_inv.transpose();
    // Third column of H is -Phi^-1 Delta, scaled like the first two columns.
    let scale = (c1.norm() + c2.norm()) / 2.0;
    let delta = -(phi * hm.column(2).into_owned()) / scale.max(1e-12);
    Ok(Extrinsics::from_parts(&phi, &delta))
}

/// Signed point-to-plane distances (m) of an observation's laser points under `ext`.
pub fn point_plane_residuals(ext: &Extrinsics, o: &BoardObservation) -> Vec<f64> {
    let len = o.plane.norm();
    let n = o.plane / len.max(1e-300);
    o.laser_points.iter().map(|p| n.dot(&ext.laser_to_camera(&Vector3::new(p[0], p[1], 0.0))) - len).collect()
}

/// Signed distances of the laser points to their boards for parameters (rotation vector
/// of Phi, Delta).
fn residuals(obs: &[&BoardObservation], params: &[f64; 6]) -> Vec<f64> {
    let phi = Rotation3::new(Vector3::new(params[0], params[1], params[2]));
    let delta = Vector3::new(params[3], params[4], params[5]);
    let phi_inv = phi.inverse();
    let mut out = Vec::new();
    for o in obs {
        let len = o.plane.norm();
        let n = o.plane / len;
        for p in &o.laser_points {
            let pc = phi_inv * (Vector3::new(p[0], p[1], 0.0) - delta);
            out.push(n.dot(&pc) - len);
        }
    }
    out
}

/// Parameter covariances of a refinement: the laser's share and the total.
struct Covariances {
    laser: DMatrix<f64>,
    total: DMatrix<f64>,
}

/// Levenberg-Marquardt over (rotation vector, Delta); returns the estimate, iterations,
/// RMS residual and the 6x6 parameter covariances.
///
/// The laser's share is σ²(JᵀJ)⁻¹ with σ² the residual variance. A board's plane error
/// dN moves the solution by -(JᵀJ)⁻¹ Jᵀ (∂r/∂N) dN to first order; with the plane's
/// covariance, each board adds that map's Σ_N-weighted square.
fn refine(obs: &[&BoardObservation], init: &Extrinsics) -> (Extrinsics, usize, f64, Option<Covariances>) {
    let rv = Rotation3::from_matrix_unchecked(init.phi()).scaled_axis();
    let x0 = [rv.x, rv.y, rv.z, init.delta[0], init.delta[1], init.delta[2]];
    let fit = levenberg_marquardt(x0, |x| residuals(obs, x));
    let n = fit.residuals;
    let sigma2 = if n > 6 { fit.rss / (n - 6) as f64 } else { f64::NAN };
    let x = fit.x;
    let phi = Rotation3::new(Vector3::new(x[0], x[1], x[2]));
    let ext = Extrinsics::from_parts(phi.matrix(), &Vector3::new(x[3], x[4], x[5]));
    let cov = fit.jtj.try_inverse().map(|inv| {
        let laser = inv * sigma2;
        let mut total = laser;
        // Rows of J per board, and ∂r/∂N per point.
        let jac = numeric_jacobian(&x, |x| residuals(obs, x));
        let mut row = 0;
        for o in obs {
            let m = o.laser_points.len();
            if let Some(cn) = o.plane_covariance {
                let len = o.plane.norm();
                let nu = o.plane / len;
                let mut jt_b = SMatrix::<f64, 6, 3>::zeros();
                for (k, p) in o.laser_points.iter().enumerate() {
                    let pc = ext.laser_to_camera(&Vector3::new(p[0], p[1], 0.0));
                    // r = N.pc / |N| - |N|
                    let dr_dn = pc / len - nu * (nu.dot(&pc) / len) - nu;
                    for a in 0..6 {
                        for b in 0..3 {
                            jt_b[(a, b)] += jac[(row + k, a)] * dr_dn[b];
                        }
                    }
                }
                let sens = -(inv * jt_b);
                total += sens * cn * sens.transpose();
            }
            row += m;
        }
        // From the rotation vector's errors to rotations about the laser's axes.
        let mut to_laser_axes = SMatrix::<f64, 6, 6>::identity();
        to_laser_axes.fixed_view_mut::<3, 3>(0, 0).copy_from(&left_jacobian(&Vector3::new(x[0], x[1], x[2])));
        let (laser, total) =
            (to_laser_axes * laser * to_laser_axes.transpose(), to_laser_axes * total * to_laser_axes.transpose());
        Covariances {
            laser: DMatrix::from_fn(6, 6, |r, c| laser[(r, c)]),
            total: DMatrix::from_fn(6, 6, |r, c| total[(r, c)]),
        }
    });
    (ext, fit.iterations, (fit.rss / n.max(1) as f64).sqrt(), cov)
}

/// The left Jacobian of SO(3) at rotation vector `w`: a small change `dw` of the rotation
/// vector turns `exp(w)` by `exp(J dw)` on its left, so `J dw` is the change as a rotation
/// about the axes of the frame `exp(w)` maps into (the laser's, for `phi`). The
/// refinement's covariance is over `w`, whose components are not rotations about those
/// axes once `w` is large (the default camera's `phi` turns 120 degrees).
fn left_jacobian(w: &Vector3<f64>) -> Matrix3<f64> {
    let t = w.norm();
    let k = w.cross_matrix();
    if t < 1e-6 {
        return Matrix3::identity() + k * 0.5;
    }
    Matrix3::identity() + k * ((1.0 - t.cos()) / (t * t)) + k * k * ((t - t.sin()) / (t * t * t))
}

/// Central-difference Jacobian of `f` at `x`.
fn numeric_jacobian(x: &[f64; 6], f: impl Fn(&[f64; 6]) -> Vec<f64>) -> DMatrix<f64> {
    let n = f(x).len();
    let mut j = DMatrix::zeros(n, 6);
    for k in 0..6 {
        let h = 1e-7;
        let (mut xp, mut xm) = (*x, *x);
        xp[k] += h;
        xm[k] -= h;
        let (rp, rm) = (f(&xp), f(&xm));
        for i in 0..n {
            j[(i, k)] = (rp[i] - rm[i]) / (2.0 * h);
        }
    }
    j
}

/// Result of [`levenberg_marquardt`].
pub(crate) struct LmFit {
    pub x: [f64; 6],
    /// JᵀJ at the solution (the Gauss-Newton information matrix before scaling).
    pub jtj: SMatrix<f64, 6, 6>,
    /// Residual sum of squares at the solution.
    pub rss: f64,
    pub residuals: usize,
    pub iterations: usize,
}

/// Levenberg-Marquardt (Marquardt's diagonal scaling, central-difference Jacobian) for
/// six parameters.
pub(crate) fn levenberg_marquardt(x0: [f64; 6], f: impl Fn(&[f64; 6]) -> Vec<f64>) -> LmFit {
    let mut x = x0;
    let cost = |x: &[f64; 6]| f(x).iter().map(|r| r * r).sum::<f64>();
    let jacobian = |x: &[f64; 6]| (numeric_jacobian(x, &f), DVector::from_vec(f(x)));
    let mut lambda = 1e-3;
    let mut current = cost(&x);
    let mut iterations = 0;
    for _ in 0..100 {
        iterations += 1;
        let (j, r) = jacobian(&x);
        let jtj = j.transpose() * &j;
        let g = j.transpose() * &r;
        let mut improved = false;
        for _ in 0..10 {
            let mut a = jtj.clone();
            for d in 0..6 {
                a[(d, d)] += lambda * jtj[(d, d)].max(1e-12);
            }
            let Some(step) = a.cholesky().map(|c| c.solve(&(-&g))) else {
                lambda *= 10.0;
                continue;
            };
            let cand: [f64; 6] = std::array::from_fn(|k| x[k] + step[k]);
            let c = cost(&cand);
            if c < current {
                let gain = current - c;
                x = cand;
                current = c;
                lambda = (lambda / 10.0).max(1e-12);
                improved = gain > 1e-15 * current.max(1e-30);
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    let (j, r) = jacobian(&x);
    let jtj = j.transpose() * &j;
    LmFit { x, jtj: SMatrix::from_fn(|a, b| jtj[(a, b)]), rss: r.norm_squared(), residuals: r.len(), iterations }
}

/// Where and how to look for the board in a scan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BoardSegmentation {
    /// Bearings (rad, laser frame) the board can be at: the camera's field of view.
    pub bearing_rad: [f64; 2],
    /// Ranges (m) the board can be at.
    pub range_m: [f64; 2],
    /// Length (m) of the board's cut by the scan plane, from first to last point: the
    /// board's width for an upright or tilted board, up to its diagonal when rolled.
    pub length_m: [f64; 2],
    /// Consecutive points further apart than this, or than 5 beam spacings at their
    /// range, belong to different objects (m).
    pub jump_m: f64,
    /// Largest distance of a board point from the fitted line (m): 3 sigma of the range
    /// noise plus range quantisation.
    pub inlier_m: f64,
    /// Points dropped at each end of the board's cut (mixed returns at edges).
    pub trim: usize,
    /// Largest difference (m) between the cut's mean range and the board's distance seen
    /// by the camera (when given); covers the laser-camera lever arm.
    pub camera_range_tolerance_m: f64,
}

impl Default for BoardSegmentation {
    fn default() -> Self {
        BoardSegmentation {
            bearing_rad: [-0.6, 0.6],
            range_m: [0.5, 6.0],
            length_m: [0.4, 1.2],
            jump_m: 0.1,
            inlier_m: 0.04,
            trim: 1,
            camera_range_tolerance_m: 0.5,
        }
    }
}

impl BoardSegmentation {
    /// Checks the settings (see [`crate::settings`]): ordered, finite ranges, positive
    /// widths and tolerances.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        for (field, r, min) in [
            ("bearing_rad", self.bearing_rad, -std::f64::consts::PI),
            ("range_m", self.range_m, 0.0),
            ("length_m", self.length_m, 0.0),
        ] {
            if !(r[0].is_finite() && r[1].is_finite() && min <= r[0] && r[0] <= r[1]) {
                return Err((
                    field,
                    format!("must be a finite range [low, high] with {min:.4} <= low <= high, got {r:?}"),
                ));
            }
        }
        if self.bearing_rad[1] > std::f64::consts::PI {
            return Err(("bearing_rad", format!("must lie within +-pi, got {:?}", self.bearing_rad)));
        }
        for (field, v) in [("jump_m", self.jump_m), ("inlier_m", self.inlier_m)] {
            if !(v.is_finite() && v > 0.0) {
                return Err((field, format!("must be finite and positive, got {v}")));
            }
        }
        if !(self.camera_range_tolerance_m.is_finite() && self.camera_range_tolerance_m >= 0.0) {
            return Err((
                "camera_range_tolerance_m",
                format!("must be finite and not negative, got {}", self.camera_range_tolerance_m),
            ));
        }
        // A board's cut holds a few dozen points; trimming more leaves none.
        if self.trim > MAX_TRIM {
            return Err(("trim", format!("must be at most {MAX_TRIM}, got {}", self.trim)));
        }
        Ok(())
    }
}

/// Most points [`BoardSegmentation::trim`] may drop at each end.
pub const MAX_TRIM: usize = 50;

/// Why no board was found in a scan.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SegmentationError {
    #[error("no straight stretch of board length ({min:.2}-{max:.2} m) in the expected region of the scan")]
    NoCandidate { min: f64, max: f64 },
    #[error(
        "no board-like stretch at the range the camera sees the board ({expected:.2} m; nearest candidate {nearest:.2} m)"
    )]
    RangeMismatch { expected: f64, nearest: f64 },
    /// Settings that make no sense (see [`BoardSegmentation::validate`]).
    #[error("board segmentation setting {field}: {problem}")]
    Setting { field: &'static str, problem: String },
}

/// A stretch of the scan taken for the board: the points (laser frame) and the fitted line.
#[derive(Debug, Clone, PartialEq)]
pub struct BoardCut {
    pub points: Vec<[f64; 2]>,
    /// Beam indices of the first and last point kept.
    pub beams: (usize, usize),
    /// RMS distance of the points to their line (m).
    pub line_rms_m: f64,
    pub length_m: f64,
    pub mean_range_m: f64,
}

/// Finds the laser points on the calibration board in one scan.
///
/// The scan is split into runs of consecutive returns without range jumps, inside the
/// expected bearings and ranges. In each run a robust line fit (the line through two of
/// its points with the most points within `inlier_m`, refitted by total least squares)
/// keeps the longest unbroken stretch of inliers; stretches whose length fits the board
/// are candidates. With `camera_range_m` (the board centre's distance from the camera,
/// from the image), the candidate nearest that range wins and must be within
/// `camera_range_tolerance_m`; without it, the longest candidate. Other objects beside the
/// board (posts, people's legs, other boards) fail the length or line tests or the range.
pub fn segment_board(
    scan: &crate::messages::LaserScan,
    cfg: &BoardSegmentation,
    camera_range_m: Option<f64>,
) -> Result<BoardCut, SegmentationError> {
    cfg.validate().map_err(|(field, problem)| SegmentationError::Setting { field, problem })?;
    let n = scan.ranges.len();
    let usable = |i: usize| {
        let a = scan.angle(i);
        scan.valid(i)
            && a >= cfg.bearing_rad[0]
            && a <= cfg.bearing_rad[1]
            && scan.ranges[i] >= cfg.range_m[0]
            && scan.ranges[i] <= cfg.range_m[1]
    };
    // Runs of consecutive usable beams without jumps.
    let mut runs: Vec<Vec<usize>> = Vec::new();
    let mut current: Vec<usize> = Vec::new();
    for i in 0..n {
        if !usable(i) {
            if !current.is_empty() {
                runs.push(std::mem::take(&mut current));
            }
            continue;
        }
        if let Some(&prev) = current.last() {
            let (p, q) = (scan.point(prev).expect(BEAM), scan.point(i).expect(BEAM));
            let gap = (p[0] - q[0]).hypot(p[1] - q[1]);
            let allowed = cfg.jump_m.max(5.0 * scan.ranges[i] * scan.angle_increment.abs());
            if prev + 1 != i || gap > allowed {
                runs.push(std::mem::take(&mut current));
            }
        }
        current.push(i);
    }
    if !current.is_empty() {
        runs.push(current);
    }
    let mut candidates: Vec<BoardCut> = Vec::new();
    for run in runs.iter().filter(|r| r.len() >= 2 * cfg.trim + 3) {
        let pts: Vec<[f64; 2]> = run.iter().map(|&i| scan.point(i).expect(BEAM)).collect();
        let Some((c, d)) = robust_line(&pts, cfg.inlier_m) else { continue };
        let dist = |p: &[f64; 2]| ((p[0] - c[0]) * -d[1] + (p[1] - c[1]) * d[0]).abs();
        // Longest unbroken stretch of inliers.
        let (mut best, mut start) = ((0usize, 0usize), None::<usize>);
        for k in 0..=pts.len() {
            let inlier = k < pts.len() && dist(&pts[k]) <= cfg.inlier_m;
            match (inlier, start) {
                (true, None) => start = Some(k),
                (false, Some(s0)) => {
                    if k - s0 > best.1 - best.0 {
                        best = (s0, k);
                    }
                    start = None;
                }
                _ => {}
            }
        }
        let (a, b) = best;
        if b - a < 2 * cfg.trim + 3 {
            continue;
        }
        let (pa, pb) = (pts[a], pts[b - 1]);
        let length = (pa[0] - pb[0]).hypot(pa[1] - pb[1]);
        if length < cfg.length_m[0] || length > cfg.length_m[1] {
            continue;
        }
        let kept: Vec<[f64; 2]> = pts[a + cfg.trim..b - cfg.trim].to_vec();
        let Some((c2, d2)) = tls_line(&kept) else { continue };
        let rms = (kept.iter().map(|p| ((p[0] - c2[0]) * -d2[1] + (p[1] - c2[1]) * d2[0]).powi(2)).sum::<f64>()
            / kept.len() as f64)
            .sqrt();
        let mean_range = kept.iter().map(|p| p[0].hypot(p[1])).sum::<f64>() / kept.len() as f64;
        candidates.push(BoardCut {
            points: kept,
            beams: (run[a + cfg.trim], run[b - cfg.trim - 1]),
            line_rms_m: rms,
            length_m: length,
            mean_range_m: mean_range,
        });
    }
    if candidates.is_empty() {
        return Err(SegmentationError::NoCandidate { min: cfg.length_m[0], max: cfg.length_m[1] });
    }
    match camera_range_m {
        Some(expected) => {
            let best = candidates
                .into_iter()
                .min_by(|a, b| (a.mean_range_m - expected).abs().total_cmp(&(b.mean_range_m - expected).abs()))
                .expect("non-empty");
            if (best.mean_range_m - expected).abs() > cfg.camera_range_tolerance_m {
                return Err(SegmentationError::RangeMismatch { expected, nearest: best.mean_range_m });
            }
            Ok(best)
        }
        None => Ok(candidates.into_iter().max_by(|a, b| a.length_m.total_cmp(&b.length_m)).expect("non-empty")),
    }
}

/// The line (point, unit direction) through two of the points with the most points within
/// `tolerance` of it (every pair is tried: runs are short), refitted to those points.
fn robust_line(pts: &[[f64; 2]], tolerance: f64) -> Option<([f64; 2], [f64; 2])> {
    let mut best: Option<(usize, usize, usize)> = None;
    for i in 0..pts.len() {
        for j in i + 1..pts.len() {
            let (dx, dy) = (pts[j][0] - pts[i][0], pts[j][1] - pts[i][1]);
            let len = dx.hypot(dy);
            if len < 1e-6 {
                continue;
            }
            let (ux, uy) = (dx / len, dy / len);
            let count =
                pts.iter().filter(|p| ((p[0] - pts[i][0]) * -uy + (p[1] - pts[i][1]) * ux).abs() <= tolerance).count();
            if best.is_none_or(|b| count > b.0) {
                best = Some((count, i, j));
            }
        }
    }
    let (_, i, j) = best?;
    let (dx, dy) = (pts[j][0] - pts[i][0], pts[j][1] - pts[i][1]);
    let len = dx.hypot(dy);
    let (ux, uy) = (dx / len, dy / len);
    let inliers: Vec<[f64; 2]> = pts
        .iter()
        .copied()
        .filter(|p| ((p[0] - pts[i][0]) * -uy + (p[1] - pts[i][1]) * ux).abs() <= tolerance)
        .collect();
    tls_line(&inliers)
}

/// Total least squares line: (centroid, unit direction).
fn tls_line(pts: &[[f64; 2]]) -> Option<([f64; 2], [f64; 2])> {
    if pts.len() < 2 {
        return None;
    }
    let n = pts.len() as f64;
    let (mx, my) = (pts.iter().map(|p| p[0]).sum::<f64>() / n, pts.iter().map(|p| p[1]).sum::<f64>() / n);
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in pts {
        let (x, y) = (p[0] - mx, p[1] - my);
        sxx += x * x;
        sxy += x * y;
        syy += y * y;
    }
    // Direction of largest spread.
    let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    Some(([mx, my], [angle.cos(), angle.sin()]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// The camera looking forward from above the laser: camera z (optical axis) = laser x,
    /// camera x = -laser y, camera y = -laser z; camera 0.2 m above and 0.05 m behind.
    fn truth() -> Extrinsics {
        let phi = Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0);
        let tweak = Rotation3::from_euler_angles(0.02, -0.03, 0.01);
        Extrinsics::from_parts(&(tweak.matrix() * phi), &Vector3::new(-0.05, 0.01, 0.2))
    }

    /// Boards in front of the laser at random tilts; laser points where the scan plane cuts
    /// them, with range noise.
    fn synthetic(poses: usize, noise_m: f64, seed: u64) -> Vec<BoardObservation> {
        let t = truth();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, noise_m.max(1e-12)).unwrap();
        (0..poses)
            .map(|_| {
                // Board centre in the laser frame, normal facing back towards the sensor.
                let centre = Vector3::new(rng.random_range(1.5..3.0), rng.random_range(-0.8..0.8), 0.0);
                let yaw: f64 = rng.random_range(-0.6..0.6);
                let tilt: f64 = rng.random_range(-0.8..0.8);
                let n_l = Vector3::new(-(yaw.cos()) * tilt.cos(), -(yaw.sin()) * tilt.cos(), tilt.sin()).normalize();
                // Plane in the camera frame: n_c = Phi^T n_l, through centre mapped to camera.
                let c_cam = t.laser_to_camera(&centre);
                let n_c = t.phi().transpose() * n_l;
                let d = n_c.dot(&c_cam);
                let plane = n_c * d;
                // Scan line: points on the plane with z = 0 in the laser frame.
                let along = n_l.cross(&Vector3::z()).normalize();
                let pts = (0..40)
                    .map(|k| {
                        let s = -0.45 + 0.9 * k as f64 / 39.0;
                        let p = centre + along * s;
                        let range = p.norm();
                        let r = range + if noise_m > 0.0 { noise.sample(&mut rng) } else { 0.0 };
                        [p.x * r / range, p.y * r / range]
                    })
                    .collect();
                BoardObservation { plane, laser_points: pts, plane_covariance: None }
            })
            .collect()
    }

    #[test]
    fn exact_data_recovers_the_extrinsics() {
        let result = calibrate(&synthetic(8, 0.0, 1)).unwrap();
        let (rot, trans) = result.extrinsics.error_to(&truth());
        assert!(rot < 1e-4 && trans < 1e-6, "rotation {rot} deg, translation {trans} m");
        let (rot0, trans0) = result.initial.error_to(&truth());
        assert!(rot0 < 1e-3 && trans0 < 1e-4, "linear estimate off by {rot0} deg, {trans0} m");
    }

    #[test]
    fn noisy_data_with_20_poses_is_accurate_and_reports_uncertainty() {
        // 1 cm range noise on 0.9 m wide boards 1.5-3 m away tilted up to 46 deg, exact
        // planes: the laser part of the error budget alone. (With tilts of only 29 deg the
        // out-of-plane translation sigma grows to ~4 mm and 1 cm errors occur.)
        for seed in 0..5 {
            let result = calibrate(&synthetic(20, 0.01, seed)).unwrap();
            let (rot, trans) = result.extrinsics.error_to(&truth());
            assert!(rot < 0.3 && trans < 0.01, "seed {seed}: rotation {rot} deg, translation {trans} m");
            // The reported uncertainty is consistent with the error made.
            let rot_sigma = result.rotation_sigma_deg.iter().map(|s| s * s).sum::<f64>().sqrt();
            assert!(rot < 4.0 * rot_sigma, "seed {seed}: error {rot} deg vs sigma {rot_sigma}");
        }
        let result = calibrate(&synthetic(20, 0.01, 2)).unwrap();
        assert!(result.rms_residual_m > 0.005 && result.rms_residual_m < 0.02);
        assert!(result.translation_sigma_m.iter().all(|s| *s > 0.0 && *s < 0.02));
        assert!(result.warnings.is_empty(), "{:?}", result.warnings);
    }

    #[test]
    fn the_left_jacobian_turns_rotation_vector_changes_into_rotations_about_the_target_axes() {
        for w in [Vector3::new(0.0, 0.0, 0.0), Vector3::new(1.2, -0.9, 1.1), Vector3::new(-2.5, 0.3, 0.8)] {
            let j = left_jacobian(&w);
            for dw in [Vector3::new(1e-5, 0.0, 0.0), Vector3::new(0.0, -1e-5, 0.0), Vector3::new(0.0, 0.0, 1e-5)] {
                let turned = Rotation3::new(w + dw) * Rotation3::new(w).inverse();
                let about = turned.scaled_axis();
                // First order: to 0.1% of the change (the identity is off by tens of %).
                assert!(
                    (about - j * dw).norm() < 1e-3 * dw.norm(),
                    "w {w:?}, dw {dw:?}: {about:?} against {:?}",
                    j * dw
                );
            }
        }
    }

    /// Over many noisy calibrations the reported sigmas match the errors made about each
    /// of the laser's axes (the camera's rotation is 120 degrees from the laser's, so the
    /// rotation vector's own components would not).
    #[test]
    fn rotation_sigmas_are_about_the_laser_axes() {
        let mut chi2 = [0.0; 3];
        let seeds = 60;
        for seed in 0..seeds {
            let result = calibrate(&synthetic(20, 0.01, 100 + seed)).unwrap();
            let error = (truth().phi() * result.extrinsics.phi().transpose()).into_owned();
            let about = Rotation3::from_matrix_unchecked(error).scaled_axis();
            for a in 0..3 {
                chi2[a] += (about[a] / result.rotation_sigma_deg[a].to_radians()).powi(2) / seeds as f64;
            }
        }
        // A mean of 60 squared unit normals lies within 0.55-1.55 with probability above 0.99.
        assert!(chi2.iter().all(|c| (0.55..1.55).contains(c)), "normalised squared errors per axis {chi2:?}");
    }

    #[test]
    fn plane_uncertainty_adds_to_the_reported_sigmas() {
        let mut obs = synthetic(20, 0.01, 6);
        let laser_only = calibrate(&obs).unwrap();
        assert_eq!(laser_only.rotation_sigma_deg, laser_only.laser_rotation_sigma_deg);
        for o in &mut obs {
            // 2 mm of plane distance error, 0.001 rad of normal error (at 2 m: 2 mm).
            o.plane_covariance = Some(Matrix3::identity() * 0.002f64.powi(2));
        }
        let with_planes = calibrate(&obs).unwrap();
        for a in 0..3 {
            assert!(with_planes.rotation_sigma_deg[a] > with_planes.laser_rotation_sigma_deg[a]);
            assert!(with_planes.translation_sigma_m[a] > with_planes.laser_translation_sigma_m[a]);
        }
        assert_eq!(with_planes.extrinsics, laser_only.extrinsics, "the covariance does not change the estimate");
        // A pose whose plane covariance is not finite is not used: it would have made the
        // reported uncertainty zero.
        obs[0].plane_covariance = Some(Matrix3::identity() * f64::NAN);
        let without = calibrate(&obs).unwrap();
        assert_eq!(without.poses_used, 19);
        assert!(without.rotation_sigma_deg.iter().all(|s| s.is_finite() && *s > 0.0), "{without:?}");
    }

    /// A scan of a board (0.8 m, 1.9 m away, turned), a post beside it, a long wall in the
    /// view and legs further out.
    fn scene_scan(noise_m: f64, seed: u64) -> crate::messages::LaserScan {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, noise_m.max(1e-12)).unwrap();
        let segments: [([f64; 2], [f64; 2]); 3] = [
            ([1.95, -0.35], [1.75, 0.42]), // the board
            ([3.5, -2.5], [3.5, -0.7]),    // a wall, 1.8 m long
            ([0.9, -0.9], [0.95, -0.92]),  // a 5 cm edge of something
        ];
        let circles: [([f64; 2], f64); 2] = [([2.6, 0.75], 0.1), ([1.2, 1.1], 0.06)];
        let n = 361;
        let (a0, da) = (-std::f64::consts::FRAC_PI_2, std::f64::consts::PI / 360.0);
        let ranges = (0..n)
            .map(|i| {
                let a = a0 + da * i as f64;
                let d = [a.cos(), a.sin()];
                let mut best = 8.0f64;
                for (p, q) in segments {
                    // Ray-segment intersection.
                    let e = [q[0] - p[0], q[1] - p[1]];
                    let den = d[0] * e[1] - d[1] * e[0];
                    if den.abs() < 1e-12 {
                        continue;
                    }
                    let t = (p[0] * e[1] - p[1] * e[0]) / den;
                    let u = (p[0] * d[1] - p[1] * d[0]) / den;
                    if t > 0.0 && (0.0..=1.0).contains(&u) {
                        best = best.min(t);
                    }
                }
                for (c, r) in circles {
                    let b = d[0] * c[0] + d[1] * c[1];
                    let disc = b * b - (c[0] * c[0] + c[1] * c[1] - r * r);
                    if disc >= 0.0 && b - disc.sqrt() > 0.0 {
                        best = best.min(b - disc.sqrt());
                    }
                }
                best + if noise_m > 0.0 { noise.sample(&mut rng) } else { 0.0 }
            })
            .collect();
        crate::messages::LaserScan {
            t: 0.0,
            angle_min: a0,
            angle_increment: da,
            range_min: 0.05,
            range_max: 80.0,
            ranges,
        }
    }

    #[test]
    fn the_board_is_segmented_from_a_cluttered_scan() {
        let cfg = BoardSegmentation { range_m: [0.5, 6.0], length_m: [0.4, 1.0], ..Default::default() };
        let (p, q) = ([1.95f64, -0.35f64], [1.75f64, 0.42f64]);
        let len = (q[0] - p[0]).hypot(q[1] - p[1]);
        let line_dist = |x: &[f64; 2]| ((x[0] - p[0]) * (q[1] - p[1]) - (x[1] - p[1]) * (q[0] - p[0])).abs() / len;
        for seed in 0..3 {
            let scan = scene_scan(0.01, seed);
            let cut = segment_board(&scan, &cfg, Some(1.9)).unwrap();
            assert!(cut.points.len() >= 35, "{} points", cut.points.len());
            assert!(cut.points.iter().all(|x| line_dist(x) < 0.05), "a point off the board");
            assert!((cut.length_m - len).abs() < 0.1, "length {}", cut.length_m);
            assert!(cut.line_rms_m < 0.02);
            // Without the camera's range: the longest candidate, still the board.
            assert_eq!(segment_board(&scan, &cfg, None).unwrap().points, cut.points);
        }
        // The camera sees the board at 3.5 m: nothing board-like there.
        let e = segment_board(&scene_scan(0.01, 1), &cfg, Some(3.5)).unwrap_err();
        assert!(matches!(e, SegmentationError::RangeMismatch { .. }), "{e}");
        // Outside the bearing window: nothing.
        let narrow = BoardSegmentation { bearing_rad: [0.6, 1.0], ..cfg.clone() };
        assert!(matches!(
            segment_board(&scene_scan(0.01, 1), &narrow, None),
            Err(SegmentationError::NoCandidate { .. })
        ));
        // An empty scan is no board, not a panic.
        let mut empty = scene_scan(0.0, 1);
        empty.ranges.iter_mut().for_each(|r| *r = f64::INFINITY);
        assert!(segment_board(&empty, &cfg, Some(2.0)).is_err());
    }

    #[test]
    fn too_few_or_degenerate_poses_are_reported() {
        assert_eq!(calibrate(&synthetic(4, 0.0, 3)).unwrap_err(), CalibrationError::TooFewPoses(4));
        let r = calibrate(&synthetic(6, 0.0, 3)).unwrap();
        assert!(r.warnings.iter().any(|w| w.contains("recommended")));
        // The same board pose repeated: no rotation information about its normal.
        let one = synthetic(1, 0.0, 4).remove(0);
        let same = vec![one.clone(), one.clone(), one.clone(), one.clone(), one];
        assert!(calibrate(&same).is_err() || !calibrate(&same).unwrap().warnings.is_empty());
    }
}
