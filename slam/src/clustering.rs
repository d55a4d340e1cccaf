//! Laser clustering: split a scan at range discontinuities and fit each cluster's centre
//! and diameter (a circle fit, since the objects of interest are trunks).
//!
//! Breakpoints use an adaptive threshold (Borges & Aldon): consecutive points further
//! apart than `r sin(dphi) / sin(lambda - dphi) + 3 sigma_r` belong to different objects,
//! so the threshold grows with range as beams spread.

use serde::{Deserialize, Serialize};

use crate::messages::{BEAM, LaserScan};

/// Clustering settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ClusteringConfig {
    /// Incidence angle below which a surface is considered a new object (deg).
    pub lambda_deg: f64,
    pub range_sigma_m: f64,
    pub min_points: usize,
    /// Keep clusters with diameter in this range (trunks are 0.2-0.8 m).
    pub min_diameter_m: f64,
    pub max_diameter_m: f64,
    /// Ignore clusters further than this (too few beams to fit).
    pub max_range_m: f64,
}

impl Default for ClusteringConfig {
    fn default() -> Self {
        ClusteringConfig {
            lambda_deg: 10.0,
            range_sigma_m: 0.01,
            min_points: 3,
            min_diameter_m: 0.15,
            max_diameter_m: 1.0,
            max_range_m: 12.0,
        }
    }
}

impl ClusteringConfig {
    /// The first setting that makes no sense, as (field, problem).
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        // Incidence angles beyond 90 degrees do not exist; at 0 every beam would split.
        if !(self.lambda_deg > 0.0 && self.lambda_deg < 90.0) {
            return Err((
                "lambda_deg",
                format!("must be between 0 and 90 degrees (exclusive), got {}", self.lambda_deg),
            ));
        }
        if !(self.range_sigma_m.is_finite() && self.range_sigma_m >= 0.0) {
            return Err(("range_sigma_m", format!("must be finite and not negative, got {}", self.range_sigma_m)));
        }
        // A circle needs three points to be fitted.
        if !(3..=crate::settings::MAX_COUNT).contains(&self.min_points) {
            return Err((
                "min_points",
                format!(
                    "must be 3 (a circle fit needs three points) to {}, got {}",
                    crate::settings::MAX_COUNT,
                    self.min_points
                ),
            ));
        }
        if !(self.min_diameter_m.is_finite() && self.min_diameter_m >= 0.0) {
            return Err(("min_diameter_m", format!("must be finite and not negative, got {}", self.min_diameter_m)));
        }
        if !(self.max_diameter_m.is_finite() && self.max_diameter_m > self.min_diameter_m) {
            return Err((
                "max_diameter_m",
                format!(
                    "must be finite and above min_diameter_m ({}), got {}",
                    self.min_diameter_m, self.max_diameter_m
                ),
            ));
        }
        if !(self.max_range_m.is_finite() && self.max_range_m > 0.0) {
            return Err(("max_range_m", format!("must be a positive number of metres, got {}", self.max_range_m)));
        }
        Ok(())
    }
}

/// A cluster of consecutive beams and its circle fit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Cluster {
    /// Beam indices (consecutive).
    pub first_beam: usize,
    pub last_beam: usize,
    /// Points in the laser frame (m).
    pub points: Vec<[f64; 2]>,
    /// Fitted circle centre in the laser frame.
    pub centre: [f64; 2],
    pub diameter_m: f64,
    /// Range and bearing of the centre from the laser.
    pub range_m: f64,
    pub bearing_rad: f64,
    /// Whether a neighbouring beam is closer (the object may be partly hidden, so its
    /// size is a lower bound).
    pub occluded: bool,
}

/// Splits a scan into clusters at breakpoints (every cluster, before filtering).
pub fn segment(scan: &LaserScan, config: &ClusteringConfig) -> Vec<(usize, usize)> {
    let n = scan.ranges.len();
    let mut out = Vec::new();
    let lambda = config.lambda_deg.to_radians();
    let dphi = scan.angle_increment.abs();
    let mut start: Option<usize> = None;
    for i in 0..n {
        if !scan.valid(i) {
            if let Some(s) = start.take() {
                out.push((s, i - 1));
            }
            continue;
        }
        match start {
            None => start = Some(i),
            Some(s) => {
                let (prev, cur) = (scan.point(i - 1).expect(BEAM), scan.point(i).expect(BEAM));
                let gap = ((cur[0] - prev[0]).powi(2) + (cur[1] - prev[1]).powi(2)).sqrt();
                let threshold = scan.ranges[i - 1] * dphi.sin() / (lambda - dphi).sin() + 3.0 * config.range_sigma_m;
                if gap > threshold {
                    out.push((s, i - 1));
                    start = Some(i);
                }
            }
        }
    }
    if let Some(s) = start {
        out.push((s, n - 1));
    }
    out
}

/// Clusters a scan and keeps those whose size fits an object of interest.
pub fn cluster(scan: &LaserScan, config: &ClusteringConfig) -> Vec<Cluster> {
    segment(scan, config)
        .into_iter()
        .filter_map(|(a, b)| {
            if b + 1 - a < config.min_points {
                return None;
            }
            let c = fit(scan, a, b);
            let keep = c.diameter_m >= config.min_diameter_m
                && c.diameter_m <= config.max_diameter_m
                && c.range_m <= config.max_range_m;
            keep.then_some(c)
        })
        .collect()
}

/// Fits a circle to beams `a..=b` of the scan (`a <= b <` the beam count): the diameter
/// from the visible chord (a trunk seen from a distance shows almost its full width) plus
/// one beam spacing for the edges that fall between beams; the centre by least squares on
/// the distances to that circle.
fn fit(scan: &LaserScan, a: usize, b: usize) -> Cluster {
    let points: Vec<[f64; 2]> = (a..=b).map(|i| scan.point(i).expect(BEAM)).collect();
    let (p0, p1) = (points[0], points[points.len() - 1]);
    let chord = ((p1[0] - p0[0]).powi(2) + (p1[1] - p0[1]).powi(2)).sqrt();
    let mean_range = (a..=b).map(|i| scan.ranges[i]).sum::<f64>() / points.len() as f64;
    let diameter = chord + mean_range * scan.angle_increment.abs();
    let radius = diameter / 2.0;
    // Start behind the closest point, along the cluster's mean bearing.
    let mid_bearing = 0.5 * (scan.angle(a) + scan.angle(b));
    let min_range = (a..=b).map(|i| scan.ranges[i]).fold(f64::INFINITY, f64::min);
    let mut c = [(min_range + radius) * mid_bearing.cos(), (min_range + radius) * mid_bearing.sin()];
    // Gauss-Newton on sum (|p - c| - r)^2 with r fixed; a few iterations suffice.
    if points.len() >= 3 {
        for _ in 0..10 {
            let (mut jtj, mut jtr) = ([[0.0f64; 2]; 2], [0.0f64; 2]);
            for p in &points {
                let (dx, dy) = (c[0] - p[0], c[1] - p[1]);
                let d = (dx * dx + dy * dy).sqrt().max(1e-9);
                let res = d - radius;
                let j = [dx / d, dy / d];
                for r in 0..2 {
                    jtr[r] += j[r] * res;
                    for k in 0..2 {
                        jtj[r][k] += j[r] * j[k];
                    }
                }
            }
            // Levenberg damping keeps flat arcs (rank-deficient along the view) stable.
            let damp = 1e-3 * (jtj[0][0] + jtj[1][1]) + 1e-9;
            let (a11, a12, a22) = (jtj[0][0] + damp, jtj[0][1], jtj[1][1] + damp);
            let det = a11 * a22 - a12 * a12;
            let step = [-(a22 * jtr[0] - a12 * jtr[1]) / det, -(-a12 * jtr[0] + a11 * jtr[1]) / det];
            c = [c[0] + step[0], c[1] + step[1]];
            if step[0].abs() + step[1].abs() < 1e-6 {
                break;
            }
        }
    }
    // The centre must lie behind the surface seen; if the fit wandered, fall back.
    let centre_range = (c[0] * c[0] + c[1] * c[1]).sqrt();
    if !(centre_range > min_range - 1e-3 && centre_range < min_range + diameter) {
        c = [(min_range + radius) * mid_bearing.cos(), (min_range + radius) * mid_bearing.sin()];
    }
    let occluded = (a > 0 && scan.valid(a - 1) && scan.ranges[a - 1] < scan.ranges[a])
        || (b + 1 < scan.ranges.len() && scan.valid(b + 1) && scan.ranges[b + 1] < scan.ranges[b]);
    Cluster {
        first_beam: a,
        last_beam: b,
        range_m: (c[0] * c[0] + c[1] * c[1]).sqrt(),
        bearing_rad: c[1].atan2(c[0]),
        centre: c,
        diameter_m: diameter,
        points,
        occluded,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// Ray-traces circles (centre, radius) into a 361-beam scan with range noise.
    fn synthetic_scan(circles: &[([f64; 2], f64)], noise: f64, seed: u64) -> LaserScan {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let normal = Normal::new(0.0, noise.max(1e-12)).unwrap();
        let inc = 0.5f64.to_radians();
        let ranges = (0..361)
            .map(|i| {
                let a = -std::f64::consts::FRAC_PI_2 + inc * i as f64;
                let d = [a.cos(), a.sin()];
                let mut best = f64::INFINITY;
                for (c, r) in circles {
                    let b = d[0] * c[0] + d[1] * c[1];
                    let q = c[0] * c[0] + c[1] * c[1] - r * r;
                    let disc = b * b - q;
                    if disc >= 0.0 && b - disc.sqrt() > 0.0 {
                        best = best.min(b - disc.sqrt());
                    }
                }
                if best.is_finite() && noise > 0.0 { best + normal.sample(&mut rng) } else { best }
            })
            .collect();
        LaserScan {
            t: 0.0,
            angle_min: -std::f64::consts::FRAC_PI_2,
            angle_increment: inc,
            range_min: 0.05,
            range_max: 80.0,
            ranges,
        }
    }

    #[test]
    fn finds_known_circles_with_their_centres_and_diameters() {
        let circles = [([4.0, 1.0], 0.3), ([6.0, -3.0], 0.15), ([3.0, -1.0], 0.25), ([8.0, 3.0], 0.4)];
        for seed in 0..10 {
            let scan = synthetic_scan(&circles, 0.01, seed);
            let found = cluster(&scan, &ClusteringConfig::default());
            assert_eq!(found.len(), circles.len(), "seed {seed}: {found:?}");
            for (c, r) in &circles {
                let best = found
                    .iter()
                    .min_by(|a, b| {
                        let da = (a.centre[0] - c[0]).hypot(a.centre[1] - c[1]);
                        let db = (b.centre[0] - c[0]).hypot(b.centre[1] - c[1]);
                        da.partial_cmp(&db).unwrap()
                    })
                    .unwrap();
                let err = (best.centre[0] - c[0]).hypot(best.centre[1] - c[1]);
                assert!(err < 0.08, "seed {seed}: centre off by {err} for {c:?}");
                assert!(
                    (best.diameter_m - 2.0 * r).abs() < 0.1,
                    "seed {seed}: diameter {} for radius {r}",
                    best.diameter_m
                );
            }
        }
    }

    #[test]
    fn touching_objects_at_different_depths_are_split() {
        // A post 0.6 m in front of a tree, overlapping in bearing.
        let scan = synthetic_scan(&[([5.0, 0.0], 0.3), ([4.0, 0.2], 0.12)], 0.0, 1);
        let parts = segment(&scan, &ClusteringConfig::default());
        assert!(parts.len() >= 2);
        let found = cluster(&scan, &ClusteringConfig::default());
        assert!(found.iter().any(|c| c.occluded), "the partly hidden trunk is flagged");
    }

    #[test]
    fn walls_and_tiny_clusters_are_discarded() {
        // A wall: many collinear points spanning metres.
        let inc = 0.5f64.to_radians();
        let ranges = (0..361)
            .map(|i| {
                let a = -std::f64::consts::FRAC_PI_2 + inc * i as f64;
                if a.abs() < 0.6 { 5.0 / a.cos() } else { f64::INFINITY }
            })
            .collect();
        let wall = LaserScan {
            t: 0.0,
            angle_min: -std::f64::consts::FRAC_PI_2,
            angle_increment: inc,
            range_min: 0.05,
            range_max: 80.0,
            ranges,
        };
        assert!(cluster(&wall, &ClusteringConfig::default()).is_empty());
        let tiny = synthetic_scan(&[([5.0, 0.0], 0.03)], 0.0, 1);
        assert!(cluster(&tiny, &ClusteringConfig::default()).is_empty());
    }
}
