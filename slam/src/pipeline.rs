//! The online pipeline: odometry predicts, each scan is clustered, clusters become
//! observations, association decides, the EKF updates and new landmarks are added.
//!
//! With a position-only method (`nn`, `jcbb`) every cluster whose size fits a trunk is an
//! observation: posts and people's legs can become landmarks, which is the failure the
//! paper argues against. Appearance methods take their observations from the laser-camera
//! segmentation instead (see [`Pipeline::on_scan_with_objects`]).

use nalgebra::{Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::association::{AssociationDecision, AssociationMethod, Candidate, Choice, chi2_quantile, jcbb::jcbb, nn::nearest_neighbour};
use crate::clustering::{Cluster, ClusteringConfig, cluster};
use crate::ekf::{Ekf, OdometryMotionModel, RangeBearingModel};
use crate::messages::{LaserScan, OdometryIncrement};

/// Pipeline settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PipelineConfig {
    pub method: AssociationMethod,
    pub clustering: ClusteringConfig,
    pub motion: OdometryMotionModel,
    pub sensor: RangeBearingModel,
    /// Probability of the chi-square gate for individual association (2 dof).
    pub gate_probability: f64,
    /// An unassociated observation starts a landmark only if its squared Mahalanobis
    /// distance to every landmark exceeds the chi-square quantile at this probability.
    pub new_landmark_probability: f64,
    /// Joint compatibility probability for JCBB.
    pub jcbb_probability: f64,
    /// Initial pose standard deviations (m, m, rad).
    pub initial_pose_sigma: [f64; 3],
}

impl Default for PipelineConfig {
    fn default() -> Self {
        PipelineConfig {
            method: AssociationMethod::Combined,
            clustering: ClusteringConfig::default(),
            motion: OdometryMotionModel::default(),
            sensor: RangeBearingModel::default(),
            gate_probability: 0.99,
            new_landmark_probability: 0.999,
            jcbb_probability: 0.99,
            initial_pose_sigma: [1e-3, 1e-3, 1e-3],
        }
    }
}

/// A mapped landmark.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Landmark {
    /// Stable id (creation order).
    pub id: u32,
    pub position: [f64; 2],
    /// 2x2 covariance, row-major.
    pub covariance: [[f64; 2]; 2],
    /// Class label given by the segmentation ("tree"), or "unknown" for position-only.
    pub class: String,
    pub observations: usize,
    /// Mean fitted diameter of the clusters associated with it.
    pub diameter_m: f64,
}

/// One estimated pose with its covariance.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseEstimate {
    pub t: f64,
    pub pose: [f64; 3],
    pub covariance: [[f64; 3]; 3],
}

/// What one scan produced: the observations (clusters) and what became of each.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanResult {
    pub t: f64,
    pub clusters: Vec<Cluster>,
    /// Per cluster: the landmark id it went to (existing or new), if any.
    pub assigned: Vec<Option<u32>>,
}

/// The online SLAM pipeline.
pub struct Pipeline {
    pub config: PipelineConfig,
    ekf: Ekf,
    landmarks: Vec<Landmark>,
    decisions: Vec<AssociationDecision>,
    poses: Vec<PoseEstimate>,
    t: f64,
}

impl Pipeline {
    /// Starts at `pose` (x, y, theta) in the map frame.
    pub fn new(config: PipelineConfig, pose: [f64; 3]) -> Self {
        let s = config.initial_pose_sigma;
        let ekf = Ekf::new(Vector3::from(pose), Matrix3::from_diagonal(&Vector3::new(s[0] * s[0], s[1] * s[1], s[2] * s[2])));
        let mut p = Pipeline { config, ekf, landmarks: Vec::new(), decisions: Vec::new(), poses: Vec::new(), t: 0.0 };
        p.record_pose();
        p
    }

    pub fn on_odometry(&mut self, o: &OdometryIncrement) {
        self.ekf.predict(&self.config.motion, &[o.dx, o.dy, o.dtheta]);
        self.t = o.t;
        self.record_pose();
    }

    /// Position-only processing of a scan: every size-compatible cluster is an observation.
    pub fn on_scan(&mut self, scan: &LaserScan) -> ScanResult {
        let clusters = cluster(scan, &self.config.clustering);
        let keep = vec![true; clusters.len()];
        self.on_scan_with_objects(scan.t, clusters, &keep, "unknown")
    }

    /// Processes clusters of which only those with `is_object[i]` are observations of
    /// objects of interest (labelled `class`).
    pub fn on_scan_with_objects(&mut self, t: f64, clusters: Vec<Cluster>, is_object: &[bool], class: &str) -> ScanResult {
        self.t = t;
        let idx: Vec<usize> = (0..clusters.len()).filter(|&i| is_object[i] && !clusters[i].occluded).collect();
        let zs: Vec<Vector2<f64>> = idx.iter().map(|&i| Vector2::new(clusters[i].range_m, clusters[i].bearing_rad)).collect();
        let gate = chi2_quantile(2, self.config.gate_probability);
        let new_gate = chi2_quantile(2, self.config.new_landmark_probability);
        let n_before = self.ekf.landmark_count();
        let distances: Vec<Vec<f64>> = zs.iter().map(|z| (0..n_before).map(|j| self.ekf.mahalanobis2(&self.config.sensor, j, z)).collect()).collect();
        let pairing: Vec<Option<usize>> = match self.config.method {
            AssociationMethod::Jcbb => jcbb(&self.ekf, &self.config.sensor, &zs, gate, self.config.jcbb_probability),
            // Appearance methods fall back to nearest neighbour on position until their
            // observations carry object models.
            _ => nearest_neighbour(&self.ekf, &self.config.sensor, &zs, gate).into_iter().map(|r| r.landmark).collect(),
        };
        let mut assigned = vec![None; clusters.len()];
        // Updates first (against the landmarks that existed before this scan), then new
        // landmarks, so the order of observations does not matter.
        let mut new_ones = Vec::new();
        for (k, &ci) in idx.iter().enumerate() {
            let candidates: Vec<Candidate> = distances[k]
                .iter()
                .enumerate()
                .filter(|(_, d)| **d < new_gate)
                .map(|(j, d)| Candidate { landmark: self.landmarks[j].id, mahalanobis2: *d, kl: None })
                .collect();
            let choice = match pairing[k] {
                Some(j) => {
                    if self.ekf.update(&self.config.sensor, j, &zs[k]).is_ok() {
                        let lm = &mut self.landmarks[j];
                        lm.diameter_m = (lm.diameter_m * lm.observations as f64 + clusters[ci].diameter_m) / (lm.observations + 1) as f64;
                        lm.observations += 1;
                        assigned[ci] = Some(lm.id);
                        Choice::Existing { landmark: lm.id }
                    } else {
                        Choice::Rejected
                    }
                }
                None if distances[k].iter().all(|d| *d > new_gate) => {
                    new_ones.push((k, ci));
                    Choice::Rejected // replaced below once the id exists
                }
                None => Choice::Rejected,
            };
            self.decisions.push(AssociationDecision { t, observation: ci, candidates, choice, method: self.config.method });
        }
        let first_decision = self.decisions.len() - idx.len();
        for (k, ci) in new_ones {
            let j = self.ekf.add_landmark(&self.config.sensor, &zs[k]);
            let id = self.landmarks.len() as u32;
            debug_assert_eq!(j, self.landmarks.len());
            self.landmarks.push(Landmark { id, position: [0.0; 2], covariance: [[0.0; 2]; 2], class: class.to_string(), observations: 1, diameter_m: clusters[ci].diameter_m });
            assigned[ci] = Some(id);
            self.decisions[first_decision + k].choice = Choice::New { landmark: id };
        }
        self.refresh_landmarks();
        self.record_pose();
        ScanResult { t, clusters, assigned }
    }

    fn refresh_landmarks(&mut self) {
        for (i, lm) in self.landmarks.iter_mut().enumerate() {
            let p = self.ekf.landmark(i);
            let c = self.ekf.landmark_covariance(i);
            lm.position = [p.x, p.y];
            lm.covariance = [[c[(0, 0)], c[(0, 1)]], [c[(1, 0)], c[(1, 1)]]];
        }
    }

    fn record_pose(&mut self) {
        let p = self.ekf.pose();
        let c = self.ekf.pose_covariance();
        let est = PoseEstimate { t: self.t, pose: [p.x, p.y, p.z], covariance: std::array::from_fn(|r| std::array::from_fn(|k| c[(r, k)])) };
        // One pose per time stamp: a scan at the same instant as odometry replaces it.
        match self.poses.last_mut() {
            Some(last) if last.t == est.t => *last = est,
            _ => self.poses.push(est),
        }
    }

    pub fn pose(&self) -> PoseEstimate {
        *self.poses.last().expect("a pose is recorded at construction")
    }

    pub fn landmarks(&self) -> &[Landmark] {
        &self.landmarks
    }

    pub fn decisions(&self) -> &[AssociationDecision] {
        &self.decisions
    }

    pub fn poses(&self) -> &[PoseEstimate] {
        &self.poses
    }

    pub fn ekf(&self) -> &Ekf {
        &self.ekf
    }
}
