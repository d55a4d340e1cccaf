//! Path following for the Pioneer: pure pursuit along the world's route, driven `laps`
//! times, with speed and turn-rate limits and a safety stop for things in the way.

use worlds::RobotSpec;

use crate::config::RobotConfig;
use crate::messages::{LaserScan, Pose2D};

pub struct PathFollower {
    /// The route unrolled over all laps, as a polyline.
    path: Vec<[f64; 2]>,
    /// Cumulative arc length at each vertex.
    arc: Vec<f64>,
    /// Progress along the path (m), only ever increases.
    progress: f64,
    config: RobotConfig,
    /// How far ahead of the base's centre the laser sits (m): the safety stop's distances
    /// are the laser's.
    laser_forward_m: f64,
}

impl PathFollower {
    pub fn new(spec: &RobotSpec, config: &RobotConfig, laser_forward_m: f64) -> Self {
        let mut path = vec![[spec.start.x, spec.start.y]];
        for _ in 0..spec.laps {
            for (_, b) in spec.route.segments() {
                path.push(b);
            }
        }
        if !spec.route.looping {
            path = std::iter::once([spec.start.x, spec.start.y]).chain(spec.route.waypoints.iter().copied()).collect();
        }
        let mut arc = vec![0.0];
        for w in path.windows(2) {
            let d = ((w[1][0] - w[0][0]).powi(2) + (w[1][1] - w[0][1]).powi(2)).sqrt();
            arc.push(arc.last().unwrap() + d);
        }
        PathFollower { path, arc, progress: 0.0, config: config.clone(), laser_forward_m }
    }

    pub fn total_length(&self) -> f64 {
        *self.arc.last().unwrap()
    }

    pub fn progress(&self) -> f64 {
        self.progress
    }

    pub fn finished(&self) -> bool {
        self.progress >= self.total_length() - 0.15
    }

    fn point_at(&self, s: f64) -> [f64; 2] {
        let s = s.clamp(0.0, self.total_length());
        let k = self.arc.partition_point(|&a| a <= s).clamp(1, self.path.len() - 1);
        let (a, b) = (self.path[k - 1], self.path[k]);
        let l = self.arc[k] - self.arc[k - 1];
        let t = if l > 0.0 { (s - self.arc[k - 1]) / l } else { 0.0 };
        [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]
    }

    /// Advances progress to the closest point of the path within a window ahead.
    fn update_progress(&mut self, p: [f64; 2]) {
        let window = 2.0;
        let mut best = (f64::INFINITY, self.progress);
        let steps = 40;
        for i in 0..=steps {
            let s = self.progress + window * i as f64 / steps as f64;
            let q = self.point_at(s);
            let d = (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2);
            if d < best.0 {
                best = (d, s);
            }
        }
        self.progress = best.1.min(self.total_length());
    }

    /// Forward speed and turn rate for the current pose; `scan` (if any) triggers the
    /// safety stop when something is closer than `safety_stop_m` in front.
    pub fn command(&mut self, pose: &Pose2D, scan: Option<&LaserScan>) -> (f64, f64) {
        self.update_progress([pose.x, pose.y]);
        if self.finished() {
            return (0.0, 0.0);
        }
        let target = self.point_at(self.progress + self.config.lookahead_m);
        let (s, c) = pose.theta.sin_cos();
        let (dx, dy) = (target[0] - pose.x, target[1] - pose.y);
        let (lx, ly) = (c * dx + s * dy, -s * dx + c * dy);
        let alpha = ly.atan2(lx);
        let ld = (lx * lx + ly * ly).sqrt().max(1e-6);
        let max_turn = self.config.max_turn_rate_dps.to_radians();
        // Slow down for sharp turns; turn on the spot if the target is behind.
        let mut v = self.config.cruise_speed_mps * alpha.cos().max(0.0).powi(2);
        let remaining = self.total_length() - self.progress;
        v = v.min(0.3 + remaining).min(self.config.max_speed_mps);
        let omega = if alpha.abs() > 1.2 {
            max_turn * alpha.signum()
        } else {
            (2.0 * v.max(0.15) * alpha.sin() / ld).clamp(-max_turn, max_turn)
        };
        if let Some(scan) = scan
            && blocked(scan, self.config.safety_stop_m + self.config.length_m / 2.0 - self.laser_forward_m)
        {
            return (0.0, 0.0);
        }
        (v, omega)
    }
}

/// True if a return within `dist` lies in the ±30 deg cone ahead.
fn blocked(scan: &LaserScan, dist: f64) -> bool {
    scan.ranges.iter().enumerate().any(|(i, r)| {
        let a = scan.angle_min + scan.angle_increment * i as f64;
        a.abs() < 30f64.to_radians() && *r < dist
    })
}
