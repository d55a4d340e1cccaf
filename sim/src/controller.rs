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
    /// Where the laser sits on the base: forward and left of its centre (m), and turned
    /// (rad). The safety stop's distances are the laser's, its cone the base's heading.
    laser_mount: LaserMount,
}

/// The laser's place on the base, as the safety stop needs it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LaserMount {
    pub forward_m: f64,
    pub left_m: f64,
    pub yaw_rad: f64,
}

impl PathFollower {
    pub fn new(spec: &RobotSpec, config: &RobotConfig, laser_mount: LaserMount) -> Self {
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
        PathFollower { path, arc, progress: 0.0, config: config.clone(), laser_mount }
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
            && blocked(
                scan,
                &self.laser_mount,
                self.config.safety_stop_m + self.config.length_m / 2.0 - self.laser_mount.forward_m,
            )
        {
            return (0.0, 0.0);
        }
        (v, omega)
    }
}

/// True if a return lies within `dist` of the point on the base's axis level with the
/// laser, in the ±30 deg cone ahead of it along the base's heading: a laser turned or set
/// off the axis still guards the way the robot drives.
fn blocked(scan: &LaserScan, mount: &LaserMount, dist: f64) -> bool {
    let (sin_yaw, cos_yaw) = mount.yaw_rad.sin_cos();
    let cone = 30f64.to_radians();
    scan.ranges.iter().enumerate().any(|(i, r)| {
        let a = scan.angle_min + scan.angle_increment * i as f64;
        if mount.yaw_rad == 0.0 && mount.left_m == 0.0 {
            // The laser on the axis, facing ahead: its own bearings are the base's.
            return a.abs() < cone && *r < dist;
        }
        let (sin_a, cos_a) = a.sin_cos();
        let (x, y) = (r * cos_a, r * sin_a);
        let (x, y) = (cos_yaw * x - sin_yaw * y, sin_yaw * x + cos_yaw * y + mount.left_m);
        x > 0.0 && y.atan2(x).abs() < cone && x.hypot(y) < dist
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 180 degree scan, one beam a degree, with one return at `range` along laser
    /// bearing `bearing_deg` and nothing elsewhere.
    fn scan_with_return(bearing_deg: i32, range: f64) -> LaserScan {
        let mut ranges = vec![f64::INFINITY; 181];
        ranges[(bearing_deg + 90) as usize] = range;
        LaserScan {
            t: 0.0,
            angle_min: -std::f64::consts::FRAC_PI_2,
            angle_increment: 1f64.to_radians(),
            time_increment: 0.0,
            scan_time: 0.1,
            range_min: 0.05,
            range_max: 80.0,
            ranges,
        }
    }

    #[test]
    fn the_safety_cone_follows_the_base_heading_whatever_the_laser_mount() {
        let ahead = LaserMount { forward_m: 0.2, ..Default::default() };
        assert!(blocked(&scan_with_return(0, 0.5), &ahead, 0.6));
        assert!(blocked(&scan_with_return(-25, 0.5), &ahead, 0.6));
        assert!(!blocked(&scan_with_return(40, 0.5), &ahead, 0.6));
        assert!(!blocked(&scan_with_return(0, 0.7), &ahead, 0.6));
        // Turned 60 degrees left: what is straight ahead of the base is at -60 degrees in
        // the laser's scan, and what the laser sees at 0 lies well to the left.
        let turned = LaserMount { yaw_rad: 60f64.to_radians(), ..ahead };
        assert!(blocked(&scan_with_return(-60, 0.5), &turned, 0.6));
        assert!(!blocked(&scan_with_return(0, 0.5), &turned, 0.6));
        // Set 0.3 m to the left of the axis: a return 0.5 m ahead of the laser lies 31
        // degrees off the axis, outside the cone; one 0.3 m to the laser's right is on it.
        let aside = LaserMount { left_m: 0.3, ..ahead };
        assert!(!blocked(&scan_with_return(0, 0.5), &aside, 0.6));
        let on_axis = -(0.3f64.atan2(0.4).to_degrees().round() as i32);
        assert!(blocked(&scan_with_return(on_axis, 0.5), &aside, 0.6));
    }
}
