//! A SICK LMS-style 2-D laser by raycasting: Gaussian range noise, the unit's range
//! quantisation, no return beyond the maximum range, and the instance id each beam hit.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;

use crate::config::LaserConfig;
use crate::messages::{LaserScan, LaserTruth, Pose2D};
use crate::physics::PhysicsScene;

/// Beams per rayon task: large enough that scheduling costs little against the casts.
const BEAMS_PER_TASK: usize = 64;

pub struct Laser {
    pub config: LaserConfig,
    rng: ChaCha8Rng,
    /// Unit direction of each beam in the laser frame, precomputed.
    directions: Vec<[f64; 2]>,
    noise: Vec<f64>,
}

impl Laser {
    pub fn new(config: &LaserConfig, seed: u64) -> Self {
        let n = config.beam_count();
        let (a0, da) = (config.angle_min_rad(), config.angle_increment_rad());
        let yaw = config.mount_yaw_deg.to_radians();
        let directions = (0..n)
            .map(|i| {
                let a = a0 + da * i as f64 + yaw;
                [a.cos(), a.sin()]
            })
            .collect();
        Laser { config: config.clone(), rng: ChaCha8Rng::seed_from_u64(seed), directions, noise: vec![0.0; n] }
    }

    /// The laser's pose in the world for a robot pose: (x, y, z, yaw).
    pub fn sensor_pose(&self, robot: &Pose2D) -> [f64; 4] {
        let [mx, my, mz] = self.config.mount_xyz_m;
        let (s, c) = robot.theta.sin_cos();
        [robot.x + c * mx - s * my, robot.y + s * mx + c * my, mz, robot.theta + self.config.mount_yaw_deg.to_radians()]
    }

    /// Takes one scan from `robot` (the true pose) at time `t`.
    pub fn scan(&mut self, scene: &PhysicsScene, robot: &Pose2D, t: f64) -> (LaserScan, LaserTruth) {
        let c = &self.config;
        // Noise is drawn in beam order before the (parallel) casts so the result does not
        // depend on the number of threads.
        if c.range_noise_sigma_m > 0.0 {
            let normal = Normal::new(0.0, c.range_noise_sigma_m).expect("sigma is finite and positive");
            for v in &mut self.noise {
                *v = normal.sample(&mut self.rng);
            }
        }
        let [ox, oy, oz, _] = self.sensor_pose(robot);
        let (s, co) = robot.theta.sin_cos();
        let max = c.max_range_m;
        let q = c.quantum_m();
        let mut ranges = vec![f64::INFINITY; self.directions.len()];
        let mut true_ranges = vec![f64::INFINITY; self.directions.len()];
        let mut hit_ids = vec![0u16; self.directions.len()];
        let dirs = &self.directions;
        let noise = &self.noise;
        let min = c.min_range_m;
        ranges
            .par_chunks_mut(BEAMS_PER_TASK)
            .zip(true_ranges.par_chunks_mut(BEAMS_PER_TASK))
            .zip(hit_ids.par_chunks_mut(BEAMS_PER_TASK))
            .enumerate()
            .for_each(|(chunk, ((r, tr), ids))| {
                for k in 0..r.len() {
                    let i = chunk * BEAMS_PER_TASK + k;
                    let d = dirs[i];
                    let world_dir = [co * d[0] - s * d[1], s * d[0] + co * d[1]];
                    if let Some((range, id)) = scene.cast([ox, oy, oz], world_dir, max) {
                        tr[k] = range;
                        ids[k] = id;
                        let measured = ((range + noise[i]) / q).round() * q;
                        if measured >= min && measured <= max {
                            r[k] = measured;
                        } else if measured < min {
                            // REP-117: a return too close to measure is -inf (no return, +inf).
                            r[k] = f64::NEG_INFINITY;
                        }
                    }
                }
            });
        let scan = LaserScan {
            t,
            angle_min: c.angle_min_rad(),
            angle_increment: c.angle_increment_rad(),
            time_increment: 0.0,
            scan_time: 1.0 / c.rate_hz,
            range_min: c.min_range_m,
            range_max: c.max_range_m,
            ranges,
        };
        (scan, LaserTruth { hit_ids, true_ranges })
    }
}
