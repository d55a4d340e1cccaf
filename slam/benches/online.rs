//! Online-phase benchmarks: one EKF update with 100 and 1,000 landmarks; one scan's
//! updates (7 observations) at 500 landmarks, one by one and batched; one KL
//! association of an observation model against 50 mapped object models, and one
//! relinearisation after a loop closure (800 poses, 20 landmarks: `long_loop`'s size).
//! `cargo bench -p slam --bench online`
use divan::Bencher;
use nalgebra::{DMatrix, DVector, Matrix3, Vector2, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use slam::ekf::synthetic::{Drive, Route, drive};
use slam::ekf::{Ekf, RangeBearingModel};
use slam::gmm::{Component, Gmm};
use slam::kl::{PreparedGmm, kl_variational};

fn main() {
    divan::main();
}

fn filter_with(n: usize) -> (Ekf, RangeBearingModel) {
    let model = RangeBearingModel::default();
    let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::identity() * 0.01);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for _ in 0..n {
        ekf.add_landmark(&model, &Vector2::new(rng.random_range(2.0..30.0), rng.random_range(-3.0..3.0))).unwrap();
    }
    (ekf, model)
}

#[divan::bench(args = [100, 1000])]
fn ekf_update(bencher: Bencher, n: usize) {
    let (ekf, model) = filter_with(n);
    bencher.with_inputs(|| ekf.clone()).bench_local_values(|mut e| {
        let (z, _, _, _) = e.predict_observation(&model, n / 2).unwrap();
        e.update(&model, n / 2, &Vector2::new(z.x + 0.01, z.y)).unwrap();
        e
    });
}

/// One scan of a real log at 500 landmarks (Victoria Park's median is 7 trees a scan):
/// seven observations, each its own update, or one stacked update.
#[divan::bench(args = [false, true])]
fn scan_update_500_landmarks(bencher: Bencher, batched: bool) {
    let (ekf, model) = filter_with(500);
    let landmarks = [10, 80, 150, 220, 290, 360, 430];
    let pairs: Vec<(usize, Vector2<f64>)> = landmarks
        .iter()
        .map(|&i| {
            let (z, _, _, _) = ekf.predict_observation(&model, i).unwrap();
            (i, Vector2::new(z.x + 0.01, z.y))
        })
        .collect();
    bencher.with_inputs(|| ekf.clone()).bench_local_values(|mut e| {
        if batched {
            e.update_batch(&model, &pairs).unwrap();
        } else {
            for (i, z) in &pairs {
                e.update(&model, *i, z).unwrap();
            }
        }
        e
    });
}

fn gmm(rng: &mut ChaCha8Rng, d: usize) -> Gmm {
    let components = (0..3)
        .map(|_| {
            let a = DMatrix::from_fn(d, d, |_, _| rng.random_range(-0.3..0.3));
            Component {
                weight: 1.0 / 3.0,
                mean: DVector::from_fn(d, |_, _| rng.random_range(-2.0..2.0)),
                covariance: &a * a.transpose() + DMatrix::identity(d, d),
            }
        })
        .collect();
    Gmm { components }
}

/// An observation's model against 50 mapped objects (16 dims: appearance + position, 3
/// components each), models prepared (Cholesky factors) beforehand as the map keeps them.
#[divan::bench]
fn kl_association_50_objects(bencher: Bencher) {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let mapped: Vec<PreparedGmm> = (0..50).map(|_| PreparedGmm::new(&gmm(&mut rng, 16)).unwrap()).collect();
    let obs = PreparedGmm::new(&gmm(&mut rng, 16)).unwrap();
    bencher.bench_local(|| {
        mapped.iter().map(|m| kl_variational(&obs, m).unwrap()).enumerate().min_by(|a, b| a.1.total_cmp(&b.1))
    });
}

/// Twice round a circle of radius 15 m (0.1 m steps, odometry 2% long and turning 5% more)
/// past 20 landmarks on a ring of radius 19 m, seen out to 8 m every fourth step: about 800
/// observing poses, the loop closing on the second lap.
fn loop_drive() -> Drive {
    let landmarks: Vec<Vector2<f64>> = (0..20)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / 20.0;
            Vector2::new(19.0 * a.sin(), 15.0 - 19.0 * a.cos())
        })
        .collect();
    drive(
        &Route {
            steps: 3200,
            step_m: 0.1,
            turn: 0.1 / 15.0,
            scale: 0.02,
            turn_scale: 0.05,
            observe_every: 4,
            max_range_m: 8.0,
        },
        &landmarks,
    )
    .expect("a finite route")
}

#[divan::bench(sample_count = 10)]
fn relinearise_800_poses_20_landmarks(bencher: Bencher) {
    let d = loop_drive();
    assert!(d.history.poses() > 700, "{} poses", d.history.poses());
    let before = d.ekf.state().clone();
    bencher.with_inputs(|| (d.ekf.clone(), d.history.clone())).bench_local_values(|(mut e, mut h)| {
        h.relinearise(&mut e, &before, &d.motion, &d.sensor, &d.ids, 10).unwrap();
        e
    });
}
