//! The fixed data set of the VBEM benchmark (and of the scikit-learn comparison in
//! `slam/benches/sklearn_compare.py`): 20,000 points in 14 dimensions from 8 overlapping
//! full-covariance Gaussians with uneven weights, drawn from a seeded generator, and 5,000
//! more points of the same draw held out for scoring.

use nalgebra::{DMatrix, DVector};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    StandardNormal.sample(rng)
}

/// The 20,000 training points.
pub fn mixture_20000x14() -> DMatrix<f64> {
    mixture_14d(20_000)
}

/// 5,000 held-out points from the same mixture (the draw continued past the training points).
pub fn heldout_5000x14() -> DMatrix<f64> {
    let all = mixture_14d(25_000);
    all.rows(20_000, 5_000).into_owned()
}

/// The first `n` points of the seeded draw.
fn mixture_14d(n: usize) -> DMatrix<f64> {
    let (d, k) = (14, 8);
    let mut rng = ChaCha8Rng::seed_from_u64(2006);
    let weights: Vec<f64> = (0..k).map(|i| 1.0 + i as f64).collect();
    let total: f64 = weights.iter().sum();
    let comps: Vec<(DVector<f64>, DMatrix<f64>)> = (0..k)
        .map(|_| {
            let mean = DVector::from_fn(d, |_, _| 4.0 * normal(&mut rng));
            let a = DMatrix::from_fn(d, d, |_, _| rng.random_range(-0.5..0.5));
            (mean, a)
        })
        .collect();
    let mut data = DMatrix::zeros(n, d);
    for i in 0..n {
        let mut u = rng.random_range(0.0..total);
        let mut c = k - 1;
        for (j, w) in weights.iter().enumerate() {
            if u < *w {
                c = j;
                break;
            }
            u -= w;
        }
        let z = DVector::from_fn(d, |_, _| normal(&mut rng));
        let x = &comps[c].0 + &comps[c].1 * &z + z.map(|v| 0.3 * v);
        data.set_row(i, &x.transpose());
    }
    data
}
