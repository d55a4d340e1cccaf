//! Wheel odometry with an error model: systematic per-run errors plus per-step noise that
//! grows with distance and turn (see [`crate::config::OdometryConfig`]).

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use crate::config::OdometryConfig;
use crate::messages::{Odometry, Pose2D};

/// The covariance of an odometry increment (dx, dy, dtheta) in the robot frame, as the
/// error model gives it for a measured step of that size (what an odometry driver's data
/// sheet gives): the per-step noise along the direction of travel and in the turn, and the
/// per-run errors (scale, turn scale, heading bias) with their spreads, taken as if drawn
/// afresh each step. Those last hold for a whole run, so a covariance summed over many
/// steps understates the drift they cause; there is no lateral slip in the model.
pub fn increment_covariance(config: &OdometryConfig, dx: f64, dy: f64, dtheta: f64) -> [[f64; 3]; 3] {
    let c = config;
    let d = dx.hypot(dy);
    let along = c.a_dd * d * d + c.a_da * dtheta * dtheta + (c.scale_sigma * d).powi(2);
    let turn = c.a_ad * d * d
        + c.a_aa * dtheta * dtheta
        + (c.turn_scale_sigma * dtheta).powi(2)
        + (c.bias_sigma_rad_per_m * d).powi(2);
    let (ux, uy) = if d > 0.0 { (dx / d, dy / d) } else { (1.0, 0.0) };
    [[along * ux * ux, along * ux * uy, 0.0], [along * ux * uy, along * uy * uy, 0.0], [0.0, 0.0, turn]]
}

/// The covariance of a pose integrated by odometry after one more increment (dx, dy) with
/// covariance `q` (robot frame), from the pose's `p` and heading `theta` before it: the
/// first-order propagation through the composition of the two.
pub fn propagate_pose_covariance(
    p: &[[f64; 3]; 3],
    theta: f64,
    (dx, dy): (f64, f64),
    q: &[[f64; 3]; 3],
) -> [[f64; 3]; 3] {
    let (s, c) = theta.sin_cos();
    // d(pose after) / d(pose before) and d(pose after) / d(increment).
    let f = [[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]];
    let g = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]];
    let abat = |a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]| -> [[f64; 3]; 3] {
        std::array::from_fn(|i| {
            std::array::from_fn(|j| (0..3).map(|k| (0..3).map(|l| a[i][k] * b[k][l] * a[j][l]).sum::<f64>()).sum())
        })
    };
    let (fp, gq) = (abat(&f, p), abat(&g, q));
    // Exactly symmetric, whatever the order of the sums.
    let sum = |i: usize, j: usize| fp[i][j] + gq[i][j];
    std::array::from_fn(|i| std::array::from_fn(|j| 0.5 * (sum(i, j) + sum(j, i))))
}

/// Turns true motion increments into odometry messages.
#[derive(Debug, Clone)]
pub struct OdometryModel {
    config: OdometryConfig,
    rng: ChaCha8Rng,
    /// Per-run systematic errors, drawn once.
    pub scale_error: f64,
    pub turn_scale_error: f64,
    pub heading_bias_rad_per_m: f64,
    last_truth: Option<Pose2D>,
}

/// A draw of N(0, sigma²), taken from the stream even when `sigma` is 0: the draws after it
/// are then the same whatever the spreads, so a study that varies a spread down to 0 keeps
/// its common random numbers. (The same value as `Normal::new(0, sigma).sample` for
/// positive `sigma`.)
fn gaussian(rng: &mut ChaCha8Rng, sigma: f64) -> f64 {
    let z: f64 = rng.sample(StandardNormal);
    0.0 + sigma * z
}

impl OdometryModel {
    pub fn new(config: &OdometryConfig, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let scale_error = gaussian(&mut rng, config.scale_sigma);
        let turn_scale_error = gaussian(&mut rng, config.turn_scale_sigma);
        let heading_bias_rad_per_m = gaussian(&mut rng, config.bias_sigma_rad_per_m);
        OdometryModel {
            config: config.clone(),
            rng,
            scale_error,
            turn_scale_error,
            heading_bias_rad_per_m,
            last_truth: None,
        }
    }

    /// The odometry message for the motion from the previous call's true pose to `truth`.
    pub fn measure(&mut self, t: f64, truth: Pose2D) -> Odometry {
        let Some(prev) = self.last_truth.replace(truth) else {
            return Odometry { t, dx: 0.0, dy: 0.0, dtheta: 0.0 };
        };
        let (dx, dy, dth) = prev.between(&truth);
        let d = (dx * dx + dy * dy).sqrt();
        let c = &self.config;
        let sigma_d = (c.a_dd * d * d + c.a_da * dth * dth).sqrt();
        let sigma_a = (c.a_ad * d * d + c.a_aa * dth * dth).sqrt();
        // A robot standing still reads no motion and takes no draw (the same for every
        // spread: whether it moved is the true path's); one that moved takes both draws,
        // whatever the spreads.
        let (nd, na) = if d > 0.0 || dth != 0.0 {
            (gaussian(&mut self.rng, sigma_d), gaussian(&mut self.rng, sigma_a))
        } else {
            (0.0, 0.0)
        };
        let scale = 1.0 + self.scale_error;
        let (mdx, mdy) = if d > 0.0 { (dx * scale + nd * dx / d, dy * scale + nd * dy / d) } else { (0.0, 0.0) };
        let mdth = dth * (1.0 + self.turn_scale_error) + self.heading_bias_rad_per_m * d + na;
        Odometry { t, dx: mdx, dy: mdy, dtheta: mdth }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A spread set to 0 leaves every other error as it was (common random numbers across a
    /// study's values): its draw is still taken from the stream.
    #[test]
    fn a_spread_of_zero_leaves_the_other_errors_alone() {
        let drive = |config: &OdometryConfig| {
            let mut model = OdometryModel::new(config, 7);
            let mut p = Pose2D { x: 0.0, y: 0.0, theta: 0.0 };
            let mut turns = Vec::new();
            for _ in 0..20 {
                p = p.compose(0.05, 0.0, 0.01);
                turns.push(model.measure(0.0, p).dtheta);
            }
            (model.turn_scale_error, model.heading_bias_rad_per_m, turns)
        };
        let all = drive(&OdometryConfig::default());
        let no_scale = drive(&OdometryConfig { scale_sigma: 0.0, ..Default::default() });
        assert_eq!(no_scale, all, "the per-run scale's spread moved the turn errors");
        // No noise along the travel: the turn's per-step noise is the same draw.
        let no_travel_noise = drive(&OdometryConfig { a_dd: 0.0, a_da: 0.0, ..Default::default() });
        assert_eq!(no_travel_noise, all, "the travel's per-step spread moved the turn's noise");
        assert_ne!(drive(&OdometryConfig { a_aa: 0.0, a_ad: 0.0, ..Default::default() }).2, all.2);
    }

    /// The covariance propagated increment by increment matches the spread of the poses
    /// that many runs of the model integrate, with the per-step noise alone (per-run errors
    /// hold for a whole run, which a per-step covariance does not describe; see
    /// `one_increments_covariance_matches_the_model_with_its_per_run_errors`).
    #[test]
    fn propagated_covariance_matches_the_spread_of_integrated_poses() {
        let config =
            OdometryConfig { scale_sigma: 0.0, turn_scale_sigma: 0.0, bias_sigma_rad_per_m: 0.0, ..Default::default() };
        // A curving drive at 20 Hz: 0.05 m and 0.01 rad a step for 100 steps.
        let mut truth = vec![Pose2D { x: 0.0, y: 0.0, theta: 0.0 }];
        for _ in 0..100 {
            let p = truth[truth.len() - 1];
            truth.push(p.compose(0.05, 0.0, 0.01));
        }
        let compose = |p: [f64; 3], o: &Odometry| {
            let (s, c) = p[2].sin_cos();
            [p[0] + c * o.dx - s * o.dy, p[1] + s * o.dx + c * o.dy, p[2] + o.dtheta]
        };
        let runs = 4000;
        let mut ends = Vec::with_capacity(runs);
        for seed in 0..runs as u64 {
            let mut model = OdometryModel::new(&config, seed);
            let mut pose = [0.0; 3];
            for (k, t) in truth.iter().enumerate() {
                pose = compose(pose, &model.measure(k as f64 * 0.05, *t));
            }
            ends.push(pose);
        }
        // The covariance along the true drive (the first-order point of expansion).
        let mut p = [[0.0; 3]; 3];
        for w in truth.windows(2) {
            let (dx, dy, dth) = w[0].between(&w[1]);
            p = propagate_pose_covariance(&p, w[0].theta, (dx, dy), &increment_covariance(&config, dx, dy, dth));
        }
        assert_sample_covariance(&ends, &p, 0.1);
        assert!(p[0][0] > 0.0 && p[1][1] > 0.0 && p[2][2] > 0.0);
    }

    /// Over one increment the per-run errors are drawn once, as the covariance takes them:
    /// the spread of one measured step over many runs of the full default model matches it.
    #[test]
    fn one_increments_covariance_matches_the_model_with_its_per_run_errors() {
        let config = OdometryConfig::default();
        let (from, to) = (Pose2D { x: 0.0, y: 0.0, theta: 0.0 }, Pose2D { x: 0.3, y: 0.05, theta: 0.2 });
        let runs = 20_000;
        let steps: Vec<[f64; 3]> = (0..runs as u64)
            .map(|seed| {
                let mut model = OdometryModel::new(&config, seed);
                model.measure(0.0, from);
                let o = model.measure(0.05, to);
                [o.dx, o.dy, o.dtheta]
            })
            .collect();
        let (dx, dy, dth) = from.between(&to);
        let q = increment_covariance(&config, dx, dy, dth);
        assert_sample_covariance(&steps, &q, 0.05);
    }

    /// Each entry (i, j) of the sample covariance of `samples` is within
    /// `tolerance` x sqrt(model_ii model_jj) of `model`'s.
    fn assert_sample_covariance(samples: &[[f64; 3]], model: &[[f64; 3]; 3], tolerance: f64) {
        let n = samples.len() as f64;
        let mean: [f64; 3] = std::array::from_fn(|i| samples.iter().map(|e| e[i]).sum::<f64>() / n);
        for i in 0..3 {
            for j in 0..3 {
                let sample = samples.iter().map(|e| (e[i] - mean[i]) * (e[j] - mean[j])).sum::<f64>() / (n - 1.0);
                let scale = (model[i][i] * model[j][j]).sqrt();
                assert!(
                    (sample - model[i][j]).abs() < tolerance * scale,
                    "({i}, {j}): sample {sample:.3e}, model {:.3e}",
                    model[i][j]
                );
            }
        }
    }

    #[test]
    fn an_increments_covariance_lies_along_the_travel_and_holds_the_per_run_errors() {
        let c = OdometryConfig::default();
        let q = increment_covariance(&c, 0.3, 0.4, 0.1);
        let along = c.a_dd * 0.25 + c.a_da * 0.01 + (c.scale_sigma * 0.5f64).powi(2);
        assert!((q[0][0] - along * 0.36).abs() < 1e-15 && (q[1][1] - along * 0.64).abs() < 1e-15);
        assert!((q[0][1] - along * 0.48).abs() < 1e-15 && q[0][1] == q[1][0]);
        let turn = c.a_ad * 0.25
            + c.a_aa * 0.01
            + (c.turn_scale_sigma * 0.1f64).powi(2)
            + (c.bias_sigma_rad_per_m * 0.5f64).powi(2);
        assert!((q[2][2] - turn).abs() < 1e-15);
        assert_eq!(increment_covariance(&c, 0.0, 0.0, 0.0), [[0.0; 3]; 3], "standing still");
    }
}
