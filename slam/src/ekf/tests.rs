use nalgebra::{Matrix3, Vector2, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use super::*;

fn numeric_observation_jacobians(m: &RangeBearingModel, pose: &Vector3<f64>, l: &Vector2<f64>) -> (nalgebra::Matrix2x3<f64>, Matrix2<f64>) {
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
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    // Noise drawn from the filter's own white model: no calibration random walks.
    let motion = OdometryMotionModel::white(0.005, 0.0002, 0.002, 0.005);
    let sensor = RangeBearingModel::default();
    let landmarks: Vec<Vector2<f64>> = (0..24)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / 24.0;
            let r = if k % 2 == 0 { 6.5 } else { 3.5 };
            Vector2::new(r * a.cos(), 5.0 + r * a.sin())
        })
        .collect();
    let mut truth = Vector3::new(0.0, 0.0, 0.0);
    let mut ekf = Ekf::new(truth, Matrix3::identity() * 1e-10);
    let mut mapped: Vec<Option<usize>> = vec![None; landmarks.len()];
    let std = |v: f64| Normal::new(0.0, v.max(0.0).sqrt()).unwrap();
    let mut nees = Vec::new();
    for _ in 0..steps {
        // True motion along a circle of radius 5 m, 0.1 m per step.
        let u_true = [0.1, 0.0, 0.02];
        let (next, _, _) = motion.predict(&truth, &u_true);
        truth = next;
        let d2 = u_true[0] * u_true[0];
        let a2 = u_true[2] * u_true[2];
        let var_d = motion.a_dd * d2 + motion.a_da * a2 + motion.floor;
        let var_a = motion.a_ad * d2 + motion.a_aa * a2 + motion.floor;
        let u = [
            u_true[0] + std(var_d).sample(&mut rng),
            u_true[1] + std(0.1 * var_d + motion.floor).sample(&mut rng),
            u_true[2] + std(var_a).sample(&mut rng),
        ];
        ekf.predict(&motion, &u);
        for (j, l) in landmarks.iter().enumerate() {
            let (z, _, _) = sensor.observe(&truth, l);
            if z.x > 7.0 || z.y.abs() > std::f64::consts::FRAC_PI_2 {
                continue;
            }
            let zn = Vector2::new(z.x + std(sensor.range_sigma_m.powi(2)).sample(&mut rng), z.y + std(sensor.bearing_sigma_rad.powi(2)).sample(&mut rng));
            match mapped[j] {
                Some(i) => ekf.update(&sensor, i, &zn).unwrap(),
                None => mapped[j] = Some(ekf.add_landmark(&sensor, &zn)),
            }
        }
        let e = ekf.pose() - truth;
        let e = Vector3::new(e.x, e.y, wrap_angle(e.z));
        let p = ekf.pose_covariance();
        nees.push((e.transpose() * p.try_inverse().unwrap() * e)[(0, 0)]);
    }
    (nees, ekf)
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
    let i = ekf.add_landmark(&m, &Vector2::new(2.0, 0.3));
    assert_eq!(ekf.update(&m, i, &Vector2::new(f64::NAN, 0.0)), Err(EkfError::NonFinite));
    ekf.remove_landmark(i);
    assert_eq!(ekf.landmark_count(), 0);
}

/// Guards the odometry calibration random walks: the heading variance gathered over a
/// metre must not depend on how finely the odometry is sampled (white per-step noise
/// alone vanishes as the rate rises, which left the filter overconfident).
#[test]
fn calibration_noise_does_not_vanish_with_the_odometry_rate() {
    let motion = OdometryMotionModel::default();
    let heading_variance = |steps: usize| {
        let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::zeros());
        for _ in 0..steps {
            ekf.predict(&motion, &[1.0 / steps as f64, 0.0, 0.0]);
        }
        ekf.pose_covariance()[(2, 2)]
    };
    let (coarse, fine) = (heading_variance(10), heading_variance(1000));
    // Finely sampled, the random walk alone remains: a_per_m per metre driven.
    assert!((fine / motion.a_per_m - 1.0).abs() < 0.1 && coarse >= fine, "1 m in 10 steps: {coarse}, in 1000: {fine}");
    let white = OdometryMotionModel::white(motion.a_dd, motion.a_da, motion.a_ad, motion.a_aa);
    let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::zeros());
    for _ in 0..1000 {
        ekf.predict(&white, &[0.001, 0.0, 0.0]);
    }
    assert!(ekf.pose_covariance()[(2, 2)] < 0.1 * fine, "white noise alone vanishes at a fine rate");
}
