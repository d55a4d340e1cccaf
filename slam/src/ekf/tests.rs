use nalgebra::{Matrix3, Vector2, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use super::*;

fn numeric_observation_jacobians(
    m: &RangeBearingModel,
    pose: &Vector3<f64>,
    l: &Vector2<f64>,
) -> (nalgebra::Matrix2x3<f64>, Matrix2<f64>) {
    let h = 1e-6;
    let mut hr = nalgebra::Matrix2x3::zeros();
    for k in 0..3 {
        let (mut p, mut q) = (*pose, *pose);
        p[k] += h;
        q[k] -= h;
        let (a, _, _) = m.observe(&p, l);
        let (b, _, _) = m.observe(&q, l);
        hr[(0, k)] = (a.x - b.x) / (2.0 * h);
        hr[(1, k)] = wrap_angle(a.y - b.y) / (2.0 * h);
    }
    let mut hl = Matrix2::zeros();
    for k in 0..2 {
        let (mut p, mut q) = (*l, *l);
        p[k] += h;
        q[k] -= h;
        let (a, _, _) = m.observe(pose, &p);
        let (b, _, _) = m.observe(pose, &q);
        hl[(0, k)] = (a.x - b.x) / (2.0 * h);
        hl[(1, k)] = wrap_angle(a.y - b.y) / (2.0 * h);
    }
    (hr, hl)
}

#[test]
fn observation_jacobians_match_numeric_ones() {
    let m = RangeBearingModel { mount_x: 0.16, mount_y: 0.05, ..Default::default() };
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for _ in 0..50 {
        let pose = Vector3::new(rng.random_range(-5.0..5.0), rng.random_range(-5.0..5.0), rng.random_range(-3.1..3.1));
        let l = Vector2::new(rng.random_range(-10.0..10.0), rng.random_range(-10.0..10.0));
        let (_, hr, hl) = m.observe(&pose, &l);
        let (nr, nl) = numeric_observation_jacobians(&m, &pose, &l);
        assert!((hr - nr).norm() < 1e-5, "robot Jacobian {hr} vs {nr}");
        assert!((hl - nl).norm() < 1e-5, "landmark Jacobian {hl} vs {nl}");
        // The inverse model inverts the observation.
        let (z, _, _) = m.observe(&pose, &l);
        let (back, gr, gz) = m.inverse(&pose, &z);
        assert!((back - l).norm() < 1e-9);
        // Inverse Jacobians, numerically.
        for k in 0..3 {
            let (mut p, mut q) = (pose, pose);
            p[k] += 1e-6;
            q[k] -= 1e-6;
            let d = (m.inverse(&p, &z).0 - m.inverse(&q, &z).0) / 2e-6;
            assert!((d - gr.column(k)).norm() < 1e-5);
        }
        for k in 0..2 {
            let (mut p, mut q) = (z, z);
            p[k] += 1e-6;
            q[k] -= 1e-6;
            let d = (m.inverse(&pose, &p).0 - m.inverse(&pose, &q).0) / 2e-6;
            assert!((d - gz.column(k)).norm() < 1e-5);
        }
    }
}

/// A synthetic run with known association: the robot drives a circle among landmarks;
/// odometry and observation noise are drawn from the filter's own models. Returns the
/// pose NEES at each step and the final filter.
fn synthetic_run(seed: u64, steps: usize) -> (Vec<f64>, Ekf) {
    // Noise drawn from the filter's own white model: no calibration random walks.
    let motion = OdometryMotionModel::white(0.005, 0.0002, 0.002, 0.005);
    let (nees, ekf, _) = synthetic_run_with(seed, steps, &motion, &motion, [0.0; 3], 0.0);
    (nees, ekf)
}

/// [`synthetic_run`] with the odometry's systematic errors `errors` (scale, turn scale,
/// heading bias per metre, as the simulator draws them), per-step noise from `noise`'s
/// white terms, and the filter's model `motion`; the turn rate swings by `turn_swing`
/// (rad per step) around the circle's. Also returns the true final pose.
fn synthetic_run_with(
    seed: u64,
    steps: usize,
    motion: &OdometryMotionModel,
    noise: &OdometryMotionModel,
    errors: [f64; 3],
    turn_swing: f64,
) -> (Vec<f64>, Ekf, Vector3<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let sensor = RangeBearingModel::default();
    let landmarks: Vec<Vector2<f64>> = (0..24)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / 24.0;
            let r = if k % 2 == 0 { 6.5 } else { 3.5 };
            Vector2::new(r * a.cos(), 5.0 + r * a.sin())
        })
        .collect();
    let mut truth = Vector3::new(0.0, 0.0, 0.0);
    let mut ekf = Ekf::with_calibration(truth, Matrix3::identity() * 1e-10, &motion.calibration_prior());
    let mut mapped: Vec<Option<usize>> = vec![None; landmarks.len()];
    let std = |v: f64| Normal::new(0.0, v.max(0.0).sqrt()).unwrap();
    let mut nees = Vec::new();
    for step in 0..steps {
        // True motion along a circle of radius 5 m, 0.1 m per step.
        let u_true = [0.1, 0.0, 0.02 + turn_swing * (std::f64::consts::TAU * step as f64 / 157.0).sin()];
        let (next, _, _) = motion.predict(&truth, &u_true).unwrap();
        truth = next;
        let d2 = u_true[0] * u_true[0];
        let a2 = u_true[2] * u_true[2];
        let var_d = noise.a_dd * d2 + noise.a_da * a2 + noise.floor;
        let var_a = noise.a_ad * d2 + noise.a_aa * a2 + noise.floor;
        let [scale, turn, bias] = errors;
        let u = [
            u_true[0] * (1.0 + scale) + std(var_d).sample(&mut rng),
            u_true[1] * (1.0 + scale) + std(0.1 * var_d + noise.floor).sample(&mut rng),
            u_true[2] * (1.0 + turn) + bias * u_true[0] + std(var_a).sample(&mut rng),
        ];
        ekf.predict(motion, &u).unwrap();
        for (j, l) in landmarks.iter().enumerate() {
            let (z, _, _) = sensor.observe(&truth, l);
            if z.x > 7.0 || z.y.abs() > std::f64::consts::FRAC_PI_2 {
                continue;
            }
            let zn = Vector2::new(
                z.x + std(sensor.range_sigma_m.powi(2)).sample(&mut rng),
                z.y + std(sensor.bearing_sigma_rad.powi(2)).sample(&mut rng),
            );
            match mapped[j] {
                Some(i) => ekf.update(&sensor, i, &zn).unwrap(),
                None => mapped[j] = Some(ekf.add_landmark(&sensor, &zn).unwrap()),
            }
        }
        let e = ekf.pose() - truth;
        let e = Vector3::new(e.x, e.y, wrap_angle(e.z));
        let p = ekf.pose_covariance();
        nees.push((e.transpose() * p.try_inverse().unwrap() * e)[(0, 0)]);
    }
    (nees, ekf, truth)
}

#[test]
fn nees_is_inside_the_95_percent_band_over_50_runs() {
    let runs = 50;
    let steps = 300;
    let all: Vec<Vec<f64>> = (0..runs).map(|s| synthetic_run(s, steps).0).collect();
    // ANEES at the end and averaged over the second half of the run: the 50-run 95%
    // chi-square band for 3 dof is [2.36, 3.72].
    let final_anees = all.iter().map(|n| n[steps - 1]).sum::<f64>() / runs as f64;
    assert!((2.36..=3.72).contains(&final_anees), "final ANEES {final_anees}");
    let mut within = 0;
    let checkpoints: Vec<usize> = (steps / 2..steps).step_by(10).collect();
    for &k in &checkpoints {
        let anees = all.iter().map(|n| n[k]).sum::<f64>() / runs as f64;
        if (2.36..=3.72).contains(&anees) {
            within += 1;
        }
    }
    // At 95% per checkpoint, nearly all checkpoints fall inside.
    assert!(within as f64 >= 0.8 * checkpoints.len() as f64, "{within}/{} checkpoints in band", checkpoints.len());
}

#[test]
fn covariance_stays_symmetric_positive_definite_over_long_runs() {
    let (_, ekf) = synthetic_run(7, 3000);
    let p = &ekf.p;
    assert!((p - p.transpose()).norm() < 1e-12);
    let eig = p.clone().symmetric_eigen();
    let min = eig.eigenvalues.iter().cloned().fold(f64::INFINITY, f64::min);
    assert!(min > 0.0, "smallest eigenvalue {min}");
    assert_eq!(ekf.landmark_count(), 24);
}

#[test]
fn update_rejects_unknown_landmarks_and_non_finite_observations() {
    let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::identity() * 0.01);
    let m = RangeBearingModel::default();
    assert_eq!(ekf.update(&m, 0, &Vector2::new(1.0, 0.0)), Err(EkfError::UnknownLandmark(0)));
    let i = ekf.add_landmark(&m, &Vector2::new(2.0, 0.3)).unwrap();
    assert_eq!(ekf.update(&m, i, &Vector2::new(f64::NAN, 0.0)), Err(EkfError::NonFinite));
    ekf.remove_landmark(i).unwrap();
    assert_eq!(ekf.landmark_count(), 0);
}

/// Guards the odometry calibration random walks: the heading variance gathered over a
/// metre must not depend on how finely the odometry is sampled (white per-step noise
/// alone vanishes as the rate rises, which left the filter overconfident).
#[test]
fn calibration_noise_does_not_vanish_with_the_odometry_rate() {
    let motion = OdometryMotionModel {
        d_per_m: 0.004,
        a_per_m: 0.0003,
        a_per_rad: 0.003,
        ..OdometryMotionModel::white(0.005, 0.0002, 0.002, 0.005)
    };
    let heading_variance = |steps: usize| {
        let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::zeros());
        for _ in 0..steps {
            ekf.predict(&motion, &[1.0 / steps as f64, 0.0, 0.0]).unwrap();
        }
        ekf.pose_covariance()[(2, 2)]
    };
    let (coarse, fine) = (heading_variance(10), heading_variance(1000));
    // Finely sampled, the random walk alone remains: a_per_m per metre driven.
    assert!((fine / motion.a_per_m - 1.0).abs() < 0.1 && coarse >= fine, "1 m in 10 steps: {coarse}, in 1000: {fine}");
    let white = OdometryMotionModel::white(motion.a_dd, motion.a_da, motion.a_ad, motion.a_aa);
    let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::zeros());
    for _ in 0..1000 {
        ekf.predict(&white, &[0.001, 0.0, 0.0]).unwrap();
    }
    assert!(ekf.pose_covariance()[(2, 2)] < 0.1 * fine, "white noise alone vanishes at a fine rate");
}

/// Guards the calibration states: with systematic odometry errors, a filter estimating them
/// recovers them from re-observed landmarks (within 3 sigma, and far tighter than its
/// prior), and its pose stays consistent; the random-walk filter drifts further.
#[test]
fn estimated_odometry_calibration_converges_to_the_true_errors() {
    let errors = [0.02, -0.04, 0.005];
    let white = OdometryMotionModel::white(0.005, 0.0002, 0.002, 0.005);
    let calibrated =
        OdometryMotionModel { scale_sigma: 0.03, turn_scale_sigma: 0.06, bias_sigma_rad_per_m: 0.006, ..white };
    // A swinging turn rate separates the turn scale from the heading bias (on a circle only
    // their sum is observable).
    let (nees, ekf, truth) = synthetic_run_with(3, 1500, &calibrated, &white, errors, 0.06);
    assert_eq!(ekf.vehicle_dims, 6);
    assert!(ekf.landmark_count() >= 12, "{} landmarks seen", ekf.landmark_count());
    let (estimate, sigma) = (ekf.calibration(), ekf.calibration_sigma());
    for k in 0..3 {
        assert!(
            (estimate[k] - errors[k]).abs() < 3.0 * sigma[k],
            "parameter {k}: {} +- {} vs {}",
            estimate[k],
            sigma[k],
            errors[k]
        );
        assert!(
            sigma[k] < 0.3 * calibrated.calibration_prior()[k],
            "parameter {k} barely observed: sigma {}",
            sigma[k]
        );
    }
    // The pose NEES stays under the 99.9% chi-square quantile (3 dof: 16.27) at the end.
    assert!(nees[nees.len() - 1] < 16.27, "final pose NEES {}", nees[nees.len() - 1]);
    // The same data through a filter without calibration states (random walks sized for
    // these errors) ends further from the true pose.
    let walks = OdometryMotionModel { d_per_m: 0.036, a_per_m: 0.0027, a_per_rad: 0.027, ..white };
    let (_, plain, plain_truth) = synthetic_run_with(3, 1500, &walks, &white, errors, 0.06);
    assert_eq!(plain_truth, truth);
    let err = |e: &Ekf| (e.pose().xy() - truth.xy()).norm();
    assert!(err(&ekf) < err(&plain), "calibrated {} m vs random walk {} m", err(&ekf), err(&plain));
}

#[test]
fn a_filter_without_calibration_parameters_has_the_plain_layout() {
    let motion = OdometryMotionModel {
        scale_sigma: 0.0,
        turn_scale_sigma: 0.0,
        bias_sigma_rad_per_m: 0.0,
        ..Default::default()
    };
    assert!(!motion.estimates_calibration() && motion.calibration_prior().is_empty());
    let a = Ekf::with_calibration(Vector3::new(1.0, 2.0, 0.3), Matrix3::identity() * 0.01, &motion.calibration_prior());
    assert_eq!(a, Ekf::new(Vector3::new(1.0, 2.0, 0.3), Matrix3::identity() * 0.01));
    assert!(a.calibration().is_empty());
    // With calibration, landmarks sit after the vehicle block and removal keeps it.
    let mut b = Ekf::with_calibration(Vector3::zeros(), Matrix3::identity() * 0.01, &[0.01, 0.02, 0.003]);
    let m = RangeBearingModel::default();
    let i = b.add_landmark(&m, &Vector2::new(2.0, 0.3)).unwrap();
    let j = b.add_landmark(&m, &Vector2::new(3.0, -0.3)).unwrap();
    assert_eq!((i, j, b.landmark_offset(), b.x.len()), (0, 1, 6, 10));
    let lj = b.landmark(j).unwrap();
    b.remove_landmark(i).unwrap();
    assert_eq!(b.landmark(0).unwrap(), lj);
    assert_eq!(b.calibration(), &[0.0, 0.0, 0.0]);
}

/// Guards landmark fusion: the constraint pulls the two estimates together (their
/// correlated pose moves with them), the kept landmark's variance shrinks, and the state
/// loses the removed one's rows with the covariance still symmetric positive definite.
#[test]
fn merging_two_estimates_of_one_point_fuses_them() {
    let m = RangeBearingModel::default();
    let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::identity() * 1e-4);
    let a = ekf.add_landmark(&m, &Vector2::new(5.0, 0.1)).unwrap();
    let other = ekf.add_landmark(&m, &Vector2::new(4.0, -0.6)).unwrap();
    // The same point seen again after the pose grew uncertain, a little off.
    ekf.predict(&OdometryMotionModel::white(0.05, 0.0, 0.01, 0.05), &[0.5, 0.0, 0.0]).unwrap();
    let b = ekf.add_landmark(&m, &Vector2::new(4.5, 0.11)).unwrap();
    let (before_a, before_b) = (ekf.landmark(a).unwrap(), ekf.landmark(b).unwrap());
    let var_before = ekf.landmark_covariance(a).unwrap().trace();
    let (m2, _) = ekf.landmark_difference(a, b).unwrap();
    assert!(m2.is_finite() && m2 > 0.0);
    let other_before = ekf.landmark(other).unwrap();
    ekf.merge_landmarks(a, b, 0.01).unwrap();
    assert_eq!(ekf.landmark_count(), 2);
    let fused = ekf.landmark(a).unwrap();
    // Between the two estimates, and no less certain than before.
    assert!((fused - before_a).norm() <= (before_b - before_a).norm() + 1e-12);
    assert!(ekf.landmark_covariance(a).unwrap().trace() <= var_before + 1e-12);
    assert!(
        ekf.landmark(other).unwrap().iter().all(|v| v.is_finite())
            && (ekf.landmark(other).unwrap() - other_before).norm() < 0.5
    );
    assert!((&ekf.p - ekf.p.transpose()).norm() < 1e-12);
    assert!(ekf.p.clone().symmetric_eigen().eigenvalues.iter().all(|e| *e > 0.0));
    assert_eq!(ekf.merge_landmarks(0, 0, 0.01), Err(EkfError::UnknownLandmark(0)));
    assert_eq!(ekf.merge_landmarks(0, 7, 0.01), Err(EkfError::UnknownLandmark(7)));
}

/// Guards the iterated update: one iteration is the plain update, bit for bit; with a
/// large pose error, iterating lands closer to the state that fits the observation than a
/// single linearisation does, and the covariance stays symmetric positive definite.
#[test]
fn iterated_update_relinearises_large_corrections() {
    let m = RangeBearingModel {
        mount_x: 0.0,
        mount_y: 0.0,
        range_sigma_m: 0.01,
        range_sigma_per_m: 0.0,
        bearing_sigma_rad: 0.001,
    };
    let build = || {
        let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::identity() * 1e-6);
        ekf.add_landmark(&m, &Vector2::new(4.0, 0.0)).unwrap();
        // The pose then becomes very uncertain, as after a long drift.
        ekf.p[(0, 0)] += 4.0;
        ekf.p[(1, 1)] += 4.0;
        ekf.p[(2, 2)] += 0.2;
        ekf
    };
    // Truly the robot stands at (1.5, 1.0) facing 0.3 rad; it sees the landmark from there.
    let truth = Vector3::new(1.5, 1.0, 0.3);
    let (z, _, _) = m.observe(&truth, &Vector2::new(4.0, 0.0));
    let (mut plain, mut once, mut iterated) = (build(), build(), build());
    plain.update(&m, 0, &z).unwrap();
    once.update_iterated(&m, 0, &z, 1).unwrap();
    assert_eq!(plain, once);
    iterated.update_iterated(&m, 0, &z, 10).unwrap();
    let residual = |e: &Ekf| {
        let (zp, _, _) = m.observe(&e.pose(), &e.landmark(0).unwrap());
        Vector2::new(z.x - zp.x, wrap_angle(z.y - zp.y)).norm()
    };
    assert!(
        residual(&iterated) < 0.5 * residual(&plain),
        "iterated residual {} vs plain {}",
        residual(&iterated),
        residual(&plain)
    );
    assert!((&iterated.p - iterated.p.transpose()).norm() == 0.0);
    assert!(iterated.p.clone().symmetric_eigen().eigenvalues.iter().all(|e| *e > 0.0));
}

/// Guards first-estimate Jacobians: nothing the robot sees tells it its global heading, so
/// the heading's variance must not fall below its starting value however often landmarks
/// are re-observed. With Jacobians at the latest estimates it does fall (the EKF-SLAM
/// inconsistency); with first estimates it does not.
#[test]
fn first_estimates_keep_the_global_heading_unobservable() {
    #[derive(Clone, Copy)]
    enum Jacobians {
        Latest,
        FirstEstimates,
        ObservabilityConstrained,
    }
    let heading_variance_ratio = |jacobians: Jacobians| {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let motion = OdometryMotionModel::white(0.005, 0.0002, 0.002, 0.005);
        let sensor = RangeBearingModel::default();
        let start_var = 0.01;
        let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::from_diagonal(&Vector3::new(1e-6, 1e-6, start_var)));
        match jacobians {
            Jacobians::Latest => {}
            Jacobians::FirstEstimates => ekf.use_first_estimates(),
            Jacobians::ObservabilityConstrained => ekf.use_observability_constraints(),
        }
        let landmarks = [Vector2::new(4.0, 1.0), Vector2::new(5.0, -1.5), Vector2::new(3.0, 3.0)];
        let mut truth = Vector3::zeros();
        let std = |v: f64| Normal::new(0.0, v.sqrt()).unwrap();
        for (i, l) in landmarks.iter().enumerate() {
            let (z, _, _) = sensor.observe(&truth, l);
            assert_eq!(ekf.add_landmark(&sensor, &z).unwrap(), i);
        }
        for step in 0..400 {
            // Back and forth along x, turning a little, odometry noisy.
            let u_true = [if (step / 50) % 2 == 0 { 0.02 } else { -0.02 }, 0.0, 0.004 * ((step as f64) * 0.1).sin()];
            truth = motion.predict(&truth, &u_true).unwrap().0;
            let u = [u_true[0] + std(1e-6).sample(&mut rng), u_true[1], u_true[2] + std(1e-6).sample(&mut rng)];
            ekf.predict(&motion, &u).unwrap();
            for (i, l) in landmarks.iter().enumerate() {
                let (z, _, _) = sensor.observe(&truth, l);
                let zn = Vector2::new(
                    z.x + std(sensor.range_sigma_m.powi(2)).sample(&mut rng),
                    z.y + std(sensor.bearing_sigma_rad.powi(2)).sample(&mut rng),
                );
                ekf.update(&sensor, i, &zn).unwrap();
            }
        }
        ekf.pose_covariance()[(2, 2)] / start_var
    };
    let standard = heading_variance_ratio(Jacobians::Latest);
    let first = heading_variance_ratio(Jacobians::FirstEstimates);
    let constrained = heading_variance_ratio(Jacobians::ObservabilityConstrained);
    assert!(first > 0.99, "first estimates: heading variance fell to {first} of its start");
    assert!(constrained > 0.99, "observability-constrained: heading variance fell to {constrained} of its start");
    // Measured: 0.07 with the latest estimates, 1.002 with first estimates.
    assert!(standard < 0.5, "latest estimates: heading variance only fell to {standard} of its start");
}

/// The constrained Jacobian sees nothing of the whole map's translation or its rotation
/// about the first estimates, and where the first estimates are the latest ones it is the
/// latest Jacobian unchanged (which is already blind to those motions there).
#[test]
fn observability_constrained_jacobians_are_blind_to_the_unobservable_motions() {
    let m = RangeBearingModel { mount_x: 0.16, mount_y: 0.05, ..Default::default() };
    let (pose, landmark) = (Vector3::new(1.0, -2.0, 0.4), Vector2::new(5.0, 1.5));
    let (_, hr, hl) = m.observe(&pose, &landmark);
    let (same_r, same_l) = observability_constrained(&hr, &hl, &pose, &landmark);
    assert!((same_r - hr).amax() < 1e-12 && (same_l - hl).amax() < 1e-12);
    // First estimates 0.8 m and 0.1 rad away from the latest ones.
    let (first_pose, first_landmark) = (Vector3::new(1.3, -2.4, 0.5), Vector2::new(5.6, 1.2));
    let (cr, cl) = observability_constrained(&hr, &hl, &first_pose, &first_landmark);
    let (dx, dy) = (first_landmark.x - first_pose.x, first_landmark.y - first_pose.y);
    for motion in [[1.0, 0.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 0.0, 1.0], [0.0, 0.0, 1.0, -dy, dx]] {
        let seen = cr * Vector3::new(motion[0], motion[1], motion[2]) + cl * Vector2::new(motion[3], motion[4]);
        assert!(seen.amax() < 1e-12, "{motion:?} is seen: {seen}");
    }
    // Not blind to what the observation does tell: the range still changes with distance.
    assert!((cl[(0, 0)] - hl[(0, 0)]).abs() < 0.2 && cl[(0, 0)] > 0.5);
}

/// A filter with `count` landmarks around the robot, correlated through a few updates.
fn filter_with_landmarks(count: usize) -> (Ekf, RangeBearingModel) {
    let m = RangeBearingModel { range_sigma_per_m: 0.01, ..Default::default() };
    let mut ekf = Ekf::new(Vector3::new(1.0, 2.0, 0.3), Matrix3::from_diagonal(&Vector3::new(0.04, 0.04, 0.01)));
    for k in 0..count {
        let a = k as f64 * 0.7;
        ekf.add_landmark(&m, &Vector2::new(3.0 + (k % 5) as f64, a.sin() * 1.4)).unwrap();
    }
    ekf.predict(&OdometryMotionModel::default(), &[0.5, 0.0, 0.05]).unwrap();
    (ekf, m)
}

#[test]
fn adding_landmarks_together_equals_adding_them_one_by_one() {
    let (base, m) = filter_with_landmarks(4);
    let zs = [Vector2::new(4.0, 0.2), Vector2::new(7.5, -1.1), Vector2::new(2.0, 2.5)];
    let mut one_by_one = base.clone();
    for z in &zs {
        one_by_one.add_landmark(&m, z).unwrap();
    }
    let mut together = base.clone();
    assert_eq!(together.add_landmarks(&m, &zs).unwrap(), 4..7);
    assert!((&together.x - &one_by_one.x).amax() < 1e-12);
    assert!((&together.p - &one_by_one.p).amax() < 1e-12, "{}", (&together.p - &one_by_one.p).amax());
    // Nothing to add changes nothing.
    assert_eq!(together.clone().add_landmarks(&m, &[]).unwrap(), 7..7);
}

#[test]
fn batched_update_agrees_with_sequential_updates() {
    let (base, m) = filter_with_landmarks(12);
    // Observations of five landmarks, a little off their predictions.
    let pairs: Vec<(usize, Vector2<f64>)> = [1usize, 3, 4, 8, 11]
        .iter()
        .enumerate()
        .map(|(k, &i)| {
            let (z, _, _, _) = base.predict_observation(&m, i).unwrap();
            (i, z + Vector2::new(0.03 * (k as f64 - 2.0), 0.004 * k as f64))
        })
        .collect();
    let sequential_of = |pairs: &[(usize, Vector2<f64>)]| {
        let mut e = base.clone();
        for (i, z) in pairs {
            e.update(&m, *i, z).unwrap();
        }
        e
    };
    // Observations exactly as predicted leave the linearisation points where they were:
    // then the batch is the sequential updates to rounding.
    let exact: Vec<_> = pairs.iter().map(|&(i, _)| (i, base.predict_observation(&m, i).unwrap().0)).collect();
    let mut batched = base.clone();
    batched.update_batch(&m, &exact).unwrap();
    let sequential = sequential_of(&exact);
    assert!((&batched.x - &sequential.x).amax() < 1e-12);
    assert!((&batched.p - &sequential.p).amax() < 1e-12, "{}", (&batched.p - &sequential.p).amax());
    // With innovations the later sequential updates linearise elsewhere: close, not equal.
    let mut batched = base.clone();
    batched.update_batch(&m, &pairs).unwrap();
    let sequential = sequential_of(&pairs);
    assert!((&batched.x - &sequential.x).amax() < 2e-3, "{}", (&batched.x - &sequential.x).amax());
    let asymmetry = |p: &DMatrix<f64>| (p - p.transpose()).amax();
    assert!(asymmetry(&batched.p) <= asymmetry(&base.p), "the update adds no asymmetry");
    assert!(batched.p.clone().cholesky().is_some());
    // One observation: the batch is the plain update.
    let mut single = base.clone();
    single.update_batch(&m, &pairs[..1]).unwrap();
    let mut plain = base.clone();
    plain.update(&m, pairs[0].0, &pairs[0].1).unwrap();
    assert!((&single.x - &plain.x).amax() < 1e-12 && (&single.p - &plain.p).amax() < 1e-12);
    // Misuse is an error that leaves the filter as it was.
    let mut bad = base.clone();
    assert_eq!(bad.update_batch(&m, &[(12, Vector2::new(1.0, 0.0))]), Err(EkfError::UnknownLandmark(12)));
    assert_eq!(bad.update_batch(&m, &[(0, Vector2::new(f64::NAN, 0.0))]), Err(EkfError::NonFinite));
    assert!(bad == base);
}

#[test]
fn range_dependent_noise_widens_far_observations() {
    let m = RangeBearingModel { range_sigma_m: 0.05, range_sigma_per_m: 0.01, ..Default::default() };
    assert!((m.noise_at(0.0)[(0, 0)] - 0.0025).abs() < 1e-15);
    assert!((m.noise_at(40.0)[(0, 0)] - 0.45f64.powi(2)).abs() < 1e-12);
    assert_eq!(m.noise_at(40.0)[(1, 1)], m.noise_at(0.0)[(1, 1)]);
    assert_eq!(RangeBearingModel { range_sigma_per_m: -1.0, ..m }.validate().unwrap_err().0, "range_sigma_per_m");
    // Degrees given for radians.
    let (field, problem) = RangeBearingModel { bearing_sigma_rad: 10.0, ..m }.validate().unwrap_err();
    assert!(field == "bearing_sigma_rad" && problem.contains("radians, not degrees"), "{problem}");
    // A noise whose square and products overflow is refused at the setting.
    let (field, problem) = RangeBearingModel { range_sigma_per_m: 1e300, ..m }.validate().unwrap_err();
    assert!(field == "range_sigma_per_m" && problem.contains("at most 1e6"), "{problem}");
    let config = crate::pipeline::PipelineConfig { initial_pose_sigma: [1e-3, 1e200, 1e-3], ..Default::default() };
    let e = config.validate().unwrap_err();
    assert!(e.path == "initial_pose_sigma[1]" && e.problem.contains("at most 1e6"), "{e:?}");
}
