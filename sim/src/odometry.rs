//! Wheel odometry with an error model: systematic per-run errors plus per-step noise that
//! grows with distance and turn (see [`crate::config::OdometryConfig`]).

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::config::OdometryConfig;
use crate::messages::{Odometry, Pose2D};

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

fn gaussian(rng: &mut ChaCha8Rng, sigma: f64) -> f64 {
    if sigma > 0.0 { Normal::new(0.0, sigma).expect("sigma is finite and positive").sample(rng) } else { 0.0 }
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
        let nd = gaussian(&mut self.rng, sigma_d);
        let na = gaussian(&mut self.rng, sigma_a);
        let scale = 1.0 + self.scale_error;
        let (mdx, mdy) = if d > 0.0 { (dx * scale + nd * dx / d, dy * scale + nd * dy / d) } else { (0.0, 0.0) };
        let mdth = dth * (1.0 + self.turn_scale_error) + self.heading_bias_rad_per_m * d + na;
        Odometry { t, dx: mdx, dy: mdy, dtheta: mdth }
    }
}
