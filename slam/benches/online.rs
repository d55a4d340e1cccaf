//! Online-phase benchmarks: one EKF update with 100 and 1,000 landmarks, and one KL
//! association of an observation model against 50 mapped object models.
//! `cargo bench -p slam --bench online`
use divan::Bencher;
use nalgebra::{DMatrix, DVector, Matrix3, Vector2, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
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
        ekf.add_landmark(&model, &Vector2::new(rng.random_range(2.0..30.0), rng.random_range(-3.0..3.0)));
    }
    (ekf, model)
}

#[divan::bench(args = [100, 1000])]
fn ekf_update(bencher: Bencher, n: usize) {
    let (ekf, model) = filter_with(n);
    bencher.with_inputs(|| ekf.clone()).bench_local_values(|mut e| {
        let (z, _, _, _) = e.predict_observation(&model, n / 2);
        e.update(&model, n / 2, &Vector2::new(z.x + 0.01, z.y)).unwrap();
        e
    });
}

fn gmm(rng: &mut ChaCha8Rng, d: usize) -> Gmm {
    let components = (0..3)
        .map(|_| {
            let a = DMatrix::from_fn(d, d, |_, _| rng.random_range(-0.3..0.3));
            Component { weight: 1.0 / 3.0, mean: DVector::from_fn(d, |_, _| rng.random_range(-2.0..2.0)), covariance: &a * a.transpose() + DMatrix::identity(d, d) }
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
    bencher.bench_local(|| mapped.iter().map(|m| kl_variational(&obs, m).unwrap()).enumerate().min_by(|a, b| a.1.total_cmp(&b.1)));
}
