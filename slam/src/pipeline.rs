//! The online pipeline: odometry predicts, each scan is clustered, clusters become
//! observations, association decides, the EKF updates and new landmarks are added.
//!
//! With a position-only method (`nn`, `jcbb`) every cluster whose size fits a trunk is an
//! observation: posts and people's legs can become landmarks, which is the failure the
//! paper argues against. The appearance methods (`combined`, the paper's, and
//! `appearance`) take their observations from the laser-camera segmentation of the latest
//! camera image: only clusters segmented as objects are observed, each with an object
//! model, and association compares models by KL divergence.

use std::collections::HashSet;

use nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::association::{
    AssociationDecision, AssociationMethod, Candidate, Choice, chi2_quantile, jcbb::jcbb_with, jcbb::unambiguous_jcbb,
};
use crate::classifier::{AppearanceModel, PatchClassifier};
use crate::clustering::{Cluster, ClusteringConfig, cluster};
use crate::ekf::smoother::{History, Relinearisation, SmootherError};
use crate::ekf::{Ekf, MotionConfig, MotionModel, RangeBearingModel};
use crate::evidence::{EvidenceConfig, Judgement, ObjectEvidence};
use crate::features::ImageRef;
use crate::gmm::{Gmm, StudentTMixture};
use crate::messages::{Control, Detection, LaserScan, OdometryIncrement};
use crate::object_model::{ObjectModel, ObjectModelConfig, ObjectObservation, fit_observation};
use crate::segmentation::{
    CameraGeometry, ImageRegion, SegmentationConfig, SegmentedCluster, locate_cluster, segment_located, spans_cover,
};
use crate::settings::InvalidSetting;
use rayon::prelude::*;

/// Pipeline settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PipelineConfig {
    pub method: AssociationMethod,
    pub clustering: ClusteringConfig,
    /// The vehicle model (`model = "odometry"` or `"ackermann"`, see [`MotionConfig`]).
    pub motion: MotionConfig,
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
    pub segmentation: SegmentationConfig,
    /// Pooling of the segmentation's evidence over frames (camera methods).
    pub evidence: EvidenceConfig,
    pub object_model: ObjectModelConfig,
    /// A scan is segmented with the latest image only if that image is at most this old (s).
    pub image_max_age_s: f64,
    /// A new landmark is tentative until observed this many times (1: at once); ...
    pub confirm_observations: usize,
    /// ...and is deleted if that has not happened within this many seconds. Walking
    /// people never stay where they were seen, so they never become landmarks.
    pub confirm_window_s: f64,
    /// Combined method: observations the KL test would start new landmarks with are paired
    /// with existing ones when two or more of them in one scan fit the map jointly
    /// (JCBB over gated candidates that look alike and have the same trunk diameter) and no
    /// other pairing fits as well. After a long drift the filter is too unsure of the pose
    /// for the KL test of any single observation (it widens the observation by the offset's
    /// uncertainty), while the constellation of the trees seen together still tells where
    /// the robot is. Off, `long_loop`'s loop never closes; measured effect in
    /// docs/results.md.
    pub joint_loop_closing: bool,
    /// Combined method: an observation the KL test leaves without a landmark starts none
    /// while a confirmed landmark that looks alike (appearance KL, trunk diameter) lies
    /// within its new-landmark gate ([`Choice::Deferred`]). The position-only methods
    /// have the same rule (`new_landmark_probability`). Without it a drifted return starts
    /// duplicates (docs/results.md).
    pub defer_near_lookalike: bool,
    /// First-estimate Jacobians in the filter (see [`crate::ekf::FirstEstimates`]): they
    /// keep the filter from gaining information it does not have (lower ATE and ANEES,
    /// docs/results.md).
    pub first_estimate_jacobians: bool,
    /// Combined method: a candidate landmark whose trunk diameter (the mean of its laser
    /// clusters' circle fits) disagrees with the observation's is not that object.
    pub diameter: DiameterCheck,
    /// Fusing landmarks that turn out to be one object (duplicates made while the pose was
    /// too uncertain to associate, found once a loop closure shrinks the uncertainty).
    pub merge: MergeConfig,
    /// Combined method: after a scan that closes a loop jointly, the filter is relinearised
    /// by solving its whole history again (see [`crate::ekf::smoother`]), so landmarks
    /// not seen since before the loop move to where the closure says they are.
    pub relinearise_loop_closures: bool,
    /// With `relinearise_loop_closures`: also relinearise once this many seconds have
    /// passed since the last time (or the start). Off by default: before a loop closes the
    /// data hardly constrain the odometry's calibration, and the batch solution can move
    /// the pose further off than the filter had it (docs/results.md).
    pub relinearise_every_s: Option<f64>,
    /// Position-only methods: update the filter once per scan with all its associated
    /// observations stacked, instead of once per observation. At hundreds of landmarks the
    /// filter's cost is the passes over its covariance, one per update; the stacked update
    /// makes one. The estimate differs from the sequential one only in linearisation points.
    pub batch_updates: bool,
}

/// The laser's trunk diameter as an association cue: an observation is compatible with a
/// landmark when |d_obs - d_landmark| <= `max_sigmas` sigma, sigma = (`sigma_m` +
/// `sigma_per_m` x range) x sqrt(1 + 1/n) for a landmark seen n times. The defaults follow
/// the measured spread of single clusters about their landmark's mean, which grows with
/// range as the beams spread (docs/results.md). Trees differ in girth; look-alike
/// neighbours at a loop closure often do not.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DiameterCheck {
    pub enabled: bool,
    /// Also a cue for the position-only methods (`nn`, `jcbb`): a landmark whose diameter
    /// disagrees is not a candidate. Off by default, where the simulator's figures were
    /// measured without it; real logs whose detections carry a diameter turn it on.
    pub for_position_methods: bool,
    pub sigma_m: f64,
    pub sigma_per_m: f64,
    pub max_sigmas: f64,
}

impl Default for DiameterCheck {
    fn default() -> Self {
        DiameterCheck { enabled: true, for_position_methods: false, sigma_m: 0.01, sigma_per_m: 0.003, max_sigmas: 3.0 }
    }
}

impl DiameterCheck {
    /// Whether a cluster of `diameter_m` at `range_m` may be a landmark of mean diameter
    /// `landmark_m` from `observations` clusters.
    pub fn compatible(&self, diameter_m: f64, range_m: f64, landmark_m: f64, observations: usize) -> bool {
        // A detection without a diameter (NaN) fits any landmark.
        if !self.enabled || !diameter_m.is_finite() || !landmark_m.is_finite() {
            return true;
        }
        let sigma = (self.sigma_m + self.sigma_per_m * range_m) * (1.0 + 1.0 / observations.max(1) as f64).sqrt();
        (diameter_m - landmark_m).abs() <= self.max_sigmas * sigma
    }

    /// The first setting that makes no sense, as (field, problem).
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        for (name, v, positive) in [
            ("sigma_m", self.sigma_m, false),
            ("sigma_per_m", self.sigma_per_m, false),
            ("max_sigmas", self.max_sigmas, true),
        ] {
            if !(v.is_finite() && v >= 0.0) || (positive && v <= 0.0) {
                return Err((
                    name,
                    format!("must be {}, got {v}", if positive { "positive" } else { "zero or positive" }),
                ));
            }
        }
        if self.sigma_m + self.sigma_per_m <= 0.0 {
            return Err(("sigma_m", "sigma_m and sigma_per_m cannot both be 0".into()));
        }
        Ok(())
    }
}

/// When two mapped landmarks are fused into one.
///
/// A pair is fused when the filter is sure enough where both are (each axis of their
/// difference's covariance under `max_sigma_m`), their positions agree (squared Mahalanobis
/// distance of the difference within the association gate), they were never seen in the
/// same scan (two objects seen at once are two objects), and, for the appearance methods,
/// their object models look alike (appearance KL under the association threshold).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MergeConfig {
    pub enabled: bool,
    /// Largest standard deviation (m) of the difference of the two positions.
    pub max_sigma_m: f64,
    /// Noise (m per axis) of the constraint that fuses them.
    pub noise_sigma_m: f64,
}

impl Default for MergeConfig {
    fn default() -> Self {
        MergeConfig { enabled: true, max_sigma_m: 0.25, noise_sigma_m: 0.05 }
    }
}

/// One observation of the appearance methods, planned against the landmarks before the
/// scan: cluster index, observation, its fitted density, (range, bearing), candidates,
/// the KL test's choice (id, index) and whether the camera could judge it fully.
type Plan = (usize, ObjectObservation, Gmm, Vector2<f64>, Vec<Candidate>, Option<(u32, usize)>, bool);

impl MergeConfig {
    /// The first setting that makes no sense, as (field, problem).
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        for (name, v) in [("max_sigma_m", self.max_sigma_m), ("noise_sigma_m", self.noise_sigma_m)] {
            if !(v.is_finite() && v > 0.0) {
                return Err((name, format!("must be positive, got {v}")));
            }
        }
        Ok(())
    }
}

/// A landmark taken off the map (and out of the filter) because frames of its place from
/// near enough judge it not an object (see [`EvidenceConfig::retract`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LandmarkRetraction {
    pub t: f64,
    pub landmark: u32,
}

/// Two landmarks fused into one.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LandmarkMerge {
    pub t: f64,
    /// The older landmark, which stays.
    pub kept: u32,
    /// The landmark fused into it, gone from the map.
    pub removed: u32,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        PipelineConfig {
            method: AssociationMethod::Combined,
            clustering: ClusteringConfig::default(),
            motion: MotionConfig::default(),
            sensor: RangeBearingModel::default(),
            gate_probability: 0.99,
            new_landmark_probability: 0.999,
            jcbb_probability: 0.99,
            initial_pose_sigma: [1e-3, 1e-3, 1e-3],
            segmentation: SegmentationConfig::default(),
            evidence: EvidenceConfig::default(),
            object_model: ObjectModelConfig::default(),
            image_max_age_s: 0.02,
            confirm_observations: 8,
            confirm_window_s: 4.0,
            joint_loop_closing: true,
            defer_near_lookalike: true,
            diameter: DiameterCheck::default(),
            first_estimate_jacobians: true,
            merge: MergeConfig::default(),
            relinearise_loop_closures: true,
            relinearise_every_s: None,
            batch_updates: false,
        }
    }
}

impl PipelineConfig {
    /// The first setting that makes no sense, with its dotted path. Every knob has a range
    /// here, so that no value is silently clamped, ignored or turned into NaN gates.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        self.clustering.validate().map_err(|e| InvalidSetting::in_table("clustering", e))?;
        self.motion.validate().map_err(|e| InvalidSetting::in_table("motion", e))?;
        self.sensor.validate().map_err(|e| InvalidSetting::in_table("sensor", e))?;
        self.segmentation.validate().map_err(|e| InvalidSetting::in_table("segmentation", e))?;
        self.evidence.validate().map_err(|e| InvalidSetting::in_table("evidence", e))?;
        self.object_model.validate().map_err(|e| InvalidSetting::in_table("object_model", e))?;
        self.merge.validate().map_err(|e| InvalidSetting::in_table("merge", e))?;
        self.diameter.validate().map_err(|e| InvalidSetting::in_table("diameter", e))?;
        // Chi-square quantiles exist for probabilities strictly between 0 and 1: at 1 every
        // gate is infinite (everything associates), at 0 empty.
        for (name, p) in [
            ("gate_probability", self.gate_probability),
            ("new_landmark_probability", self.new_landmark_probability),
            ("jcbb_probability", self.jcbb_probability),
        ] {
            if !(p > 0.0 && p < 1.0) {
                return Err(InvalidSetting::new(
                    name,
                    format!("must be a probability between 0 and 1 (exclusive), got {p}"),
                ));
            }
        }
        if let Some((i, s)) = self.initial_pose_sigma.iter().enumerate().find(|(_, s)| !(s.is_finite() && **s > 0.0)) {
            return Err(InvalidSetting::new(
                format!("initial_pose_sigma[{i}]"),
                format!("must be a positive standard deviation, got {s}"),
            ));
        }
        if !(self.image_max_age_s.is_finite() && self.image_max_age_s >= 0.0) {
            return Err(InvalidSetting::new(
                "image_max_age_s",
                format!("must be zero or a positive number of seconds, got {}", self.image_max_age_s),
            ));
        }
        if self.confirm_observations == 0 {
            return Err(InvalidSetting::new(
                "confirm_observations",
                "must be at least 1 (1 confirms a landmark at its first observation)",
            ));
        }
        if !(self.confirm_window_s.is_finite() && self.confirm_window_s > 0.0) {
            return Err(InvalidSetting::new(
                "confirm_window_s",
                format!("must be a positive number of seconds, got {}", self.confirm_window_s),
            ));
        }
        if let Some(every) = self.relinearise_every_s
            && !(every.is_finite() && every > 0.0)
        {
            return Err(InvalidSetting::new(
                "relinearise_every_s",
                format!("must be a positive number of seconds, got {every}"),
            ));
        }
        if self.relinearise_every_s.is_some() && !self.relinearise_loop_closures {
            return Err(InvalidSetting::new(
                "relinearise_every_s",
                "only applies with relinearise_loop_closures = true",
            ));
        }
        Ok(())
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
    /// Time the landmark was created.
    #[serde(default)]
    pub created_t: f64,
    /// Whether it has been observed often enough to count as mapped.
    #[serde(default)]
    pub confirmed: bool,
}

/// One estimated pose with its covariance.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseEstimate {
    pub t: f64,
    pub pose: [f64; 3],
    pub covariance: [[f64; 3]; 3],
}

/// What one scan did: its observations (clusters) and what became of each, with every
/// decision, fusion, retraction, segmentation and relinearisation made since the previous
/// scan. The pipeline keeps none of these: a caller that wants the history keeps the
/// reports (a pipeline on a robot runs for hours).
#[derive(Debug, Clone)]
pub struct ScanReport {
    pub t: f64,
    pub clusters: Vec<Cluster>,
    /// Per cluster: the landmark id it went to (existing or new), if any.
    pub assigned: Vec<Option<u32>>,
    /// The association decisions, in the order they were made.
    pub decisions: Vec<AssociationDecision>,
    /// Landmarks fused into others.
    pub merges: Vec<LandmarkMerge>,
    /// Landmarks taken off the map because nearer frames judged their place not an object.
    pub retractions: Vec<LandmarkRetraction>,
    /// The segmented images' patch decisions (appearance methods).
    pub segmentations: Vec<SegmentationRecord>,
    /// Solves of the smoother after a loop closure: what each did, or why it failed (the
    /// filter then carried on as it was).
    pub relinearisations: Vec<Result<Relinearisation, SmootherError>>,
}

/// What the appearance methods need: the trained model, ready to classify, and the camera.
#[derive(Clone)]
pub struct Appearance {
    pub model: AppearanceModel,
    classifier: PatchClassifier,
    /// The classifier's object density (appearance only): prior for object models.
    general: Gmm,
    pub camera: CameraGeometry,
}

impl Appearance {
    pub fn new(model: AppearanceModel, camera: CameraGeometry) -> Result<Self, crate::gmm::GmmError> {
        let classifier = PatchClassifier::new(&model)?;
        let general = StudentTMixture::new(&model.object)?.gaussian_approximation()?;
        Ok(Appearance { model, classifier, general, camera })
    }
}

/// The latest camera image.
#[derive(Clone)]
struct StoredImage {
    t: f64,
    width: u32,
    height: u32,
    rgb: Vec<u8>,
    /// The pixel columns that hold the scene (`None`: all of them).
    columns: Option<Vec<(u32, u32)>>,
}

/// The patch decisions of one segmented image, for scoring against masks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SegmentationRecord {
    /// Time of the image.
    pub t_image: f64,
    pub patch_size: u32,
    /// (col, row, classified as object) for every patch classified.
    pub cells: Vec<(u32, u32, bool)>,
    /// Per segmented cluster: how it was decided.
    pub clusters: Vec<ClusterSegmentation>,
}

/// Why one cluster was or was not taken as an object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClusterSegmentation {
    /// Index of the cluster in its scan.
    pub index: usize,
    pub is_object: bool,
    /// Fraction of the patches its laser points fall in that are object patches.
    pub hit_fraction: f64,
    pub above_fraction: f64,
    /// The pooled evidence of the cluster's place (see [`crate::evidence`]), when pooling.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pooled: Option<Judgement>,
    /// Whether the cluster became an object observation (the pooled judgement when
    /// pooling, else `is_object`).
    #[serde(default)]
    pub observed: bool,
    pub band_visible: bool,
    pub at_image_edge: bool,
    /// See [`SegmentedCluster::row_profile`].
    pub row_profile: Vec<(f64, f64)>,
    /// Patch columns classified, [first, last).
    pub columns: (u32, u32),
    /// Patch rows the laser points fall in, [first, last].
    pub hit_rows: (u32, u32),
    /// Object posterior R of every classified patch, row-major over `columns` (kept in
    /// memory, not written: it would dominate a run's log).
    #[serde(skip_serializing, default)]
    pub posteriors: Vec<f32>,
}

/// The L x L RGB pixels (row-major) of patch (`col`, `row`) of an image `width` pixels wide.
/// The index of the smallest distance under `gate` (the first of equals), if any.
fn nearest_within(distances: &[f64], gate: f64) -> Option<usize> {
    distances.iter().enumerate().filter(|(_, d)| **d < gate).min_by(|a, b| a.1.total_cmp(b.1)).map(|(i, _)| i)
}

/// A landmark's mean diameter after one more observation; detections without a diameter
/// (NaN) leave it as it was.
fn mean_diameter(mean: f64, observations: usize, diameter: f64) -> f64 {
    if !diameter.is_finite() {
        mean
    } else if !mean.is_finite() {
        diameter
    } else {
        (mean * observations as f64 + diameter) / (observations + 1) as f64
    }
}

fn patch_pixels(rgb: &[u8], width: u32, col: u32, row: u32, l: u32) -> Vec<u8> {
    let (w, l) = (width as usize, l as usize);
    let (x0, y0) = (col as usize * l, row as usize * l);
    (y0..y0 + l).flat_map(|y| rgb[(y * w + x0) * 3..(y * w + x0 + l) * 3].iter().copied()).collect()
}

/// The online SLAM pipeline. Cloning it forks a run (benchmarks, what-if studies).
#[derive(Clone)]
pub struct Pipeline {
    pub config: PipelineConfig,
    ekf: Ekf,
    landmarks: Vec<Landmark>,
    /// Object model per landmark (appearance methods).
    objects: Vec<Option<ObjectModel>>,
    /// Per landmark: the evidence place (odometry frame) of its latest camera observation,
    /// where later frames may judge it not an object (see [`Pipeline::retractions`]).
    places: Vec<Option<[f64; 2]>>,
    /// Made during the current scan, handed over in its [`ScanReport`].
    retractions: Vec<LandmarkRetraction>,
    /// Made during the current scan (indexed while it lasts), handed over in its report.
    decisions: Vec<AssociationDecision>,
    /// The latest pose estimate.
    pose: PoseEstimate,
    t: f64,
    /// Id of the next landmark (ids are never reused after a tentative one is deleted).
    next_id: u32,
    appearance: Option<Appearance>,
    image: Option<StoredImage>,
    segmentations: Vec<SegmentationRecord>,
    /// See [`Pipeline::unrendered_reads`].
    unrendered_reads: usize,
    evidence: ObjectEvidence,
    /// Dead-reckoned pose (x, y, theta): the frame of the evidence's places. Odometry is
    /// smooth over the seconds a place lives, while the filter's pose jumps when a loop
    /// closes, which would split one object's place or join a post to a tree's.
    odometry_pose: [f64; 3],
    /// Pairs of landmark ids (smaller first) seen in one scan: never fused.
    co_observed: HashSet<(u32, u32)>,
    merges: Vec<LandmarkMerge>,
    /// What the filter was told, when loop closures are relinearised.
    history: Option<History>,
    relinearisations: Vec<Result<Relinearisation, SmootherError>>,
    /// When the latest relinearisation was tried.
    relinearised_at: f64,
    /// The latest control and the time it was given: it holds until the next input.
    control: Option<(f64, Control)>,
}

/// Errors of the online pipeline.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error("association method `{0}` needs camera images and an appearance model; give the pipeline an `Appearance`")]
    NeedsAppearance(&'static str),
    #[error("image is {width}x{height} with {found} bytes; RGB needs {expected}")]
    Image { width: u32, height: u32, expected: usize, found: usize },
    #[error("pipeline settings: {0}")]
    Invalid(#[from] InvalidSetting),
    #[error("{input} at t = {t} s comes before the previous input at t = {previous} s: inputs must be in time order")]
    TimeReversed { input: &'static str, t: f64, previous: f64 },
    #[error("{input} at t = {t} s holds a value that is not finite")]
    NonFinite { input: &'static str, t: f64 },
    #[error("the `{model}` motion model cannot use {input}")]
    MotionInput { model: &'static str, input: &'static str },
    #[error("association method `{0}` observes objects in camera images: it cannot use point detections")]
    DetectionsNeedPositionMethod(&'static str),
    #[error("{given} object flags for {clusters} clusters")]
    ObjectFlags { given: usize, clusters: usize },
}

impl Pipeline {
    /// Starts at `pose` (x, y, theta) in the map frame.
    pub fn new(config: PipelineConfig, pose: [f64; 3]) -> Self {
        let s = config.initial_pose_sigma;
        let mut ekf = Ekf::with_calibration(
            Vector3::from(pose),
            Matrix3::from_diagonal(&Vector3::new(s[0] * s[0], s[1] * s[1], s[2] * s[2])),
            &config.motion.calibration_prior(),
        );
        if config.first_estimate_jacobians {
            ekf.use_first_estimates();
        }
        let evidence = ObjectEvidence::new(config.evidence.clone());
        let history = (config.relinearise_loop_closures && config.method == AssociationMethod::Combined)
            .then(|| History::new(ekf.pose(), ekf.pose_covariance(), &config.motion.calibration_prior()));
        let mut p = Pipeline {
            config,
            ekf,
            landmarks: Vec::new(),
            objects: Vec::new(),
            places: Vec::new(),
            retractions: Vec::new(),
            decisions: Vec::new(),
            pose: PoseEstimate { t: 0.0, pose, covariance: [[0.0; 3]; 3] },
            t: 0.0,
            next_id: 0,
            appearance: None,
            image: None,
            segmentations: Vec::new(),
            unrendered_reads: 0,
            evidence,
            odometry_pose: pose,
            co_observed: HashSet::new(),
            merges: Vec::new(),
            history,
            relinearisations: Vec::new(),
            relinearised_at: 0.0,
            control: None,
        };
        p.record_pose();
        p
    }

    /// The same pipeline with its clock starting at `t` (a log's first instant), so the
    /// first pose is stamped `t` rather than 0 and earlier inputs are errors.
    pub fn starting_at(mut self, t: f64) -> Self {
        self.t = t;
        self.relinearised_at = t;
        self.record_pose();
        self
    }

    /// The time of the latest input.
    pub fn time(&self) -> f64 {
        self.t
    }

    /// Refuses an input stamped before the previous one.
    fn check_time(&self, input: &'static str, t: f64) -> Result<(), PipelineError> {
        if !t.is_finite() {
            return Err(PipelineError::NonFinite { input, t });
        }
        if t < self.t {
            return Err(PipelineError::TimeReversed { input, t, previous: self.t });
        }
        Ok(())
    }

    /// A pipeline for any method; the appearance methods need `appearance`.
    pub fn with_appearance(
        config: PipelineConfig,
        pose: [f64; 3],
        appearance: Option<Appearance>,
    ) -> Result<Self, PipelineError> {
        config.validate()?;
        if config.method.uses_appearance() && appearance.is_none() {
            return Err(PipelineError::NeedsAppearance(config.method.name()));
        }
        // The object models use the leading PCA coordinates: more than the model has would
        // be silently fewer.
        if let Some(app) = &appearance
            && config.object_model.appearance_dims > app.model.extractor.pca.dims()
        {
            let problem = format!(
                "must be at most the appearance model's {} PCA dimensions, got {}",
                app.model.extractor.pca.dims(),
                config.object_model.appearance_dims
            );
            return Err(InvalidSetting::new("object_model.appearance_dims", problem).into());
        }
        let mut p = Pipeline::new(config, pose);
        p.appearance = appearance;
        Ok(p)
    }

    /// Stores a camera image (8-bit RGB, row-major) for the next scans to segment.
    pub fn on_image(&mut self, t: f64, width: u32, height: u32, rgb: Vec<u8>) -> Result<(), PipelineError> {
        self.on_image_columns(t, width, height, rgb, None)
    }

    /// [`Pipeline::on_image`] for an image rendered only in the pixel columns `columns`
    /// (`start..end`, sorted and disjoint; see [`Pipeline::image_region`]). A cluster whose
    /// segmentation would read outside them is not segmented and is counted in
    /// [`Pipeline::unrendered_reads`].
    pub fn on_image_columns(
        &mut self,
        t: f64,
        width: u32,
        height: u32,
        rgb: Vec<u8>,
        columns: Option<Vec<(u32, u32)>>,
    ) -> Result<(), PipelineError> {
        let expected = width as usize * height as usize * 3;
        if rgb.len() != expected {
            return Err(PipelineError::Image { width, height, expected, found: rgb.len() });
        }
        self.image = Some(StoredImage { t, width, height, rgb, columns });
        Ok(())
    }

    /// The pixel columns this pipeline's segmentation reads, scan by scan (appearance
    /// methods only): a camera that renders just those gives it the same results.
    pub fn image_region(&self) -> Option<ImageRegion> {
        let app = self.appearance.as_ref()?;
        Some(ImageRegion {
            clustering: self.config.clustering,
            segmentation: self.config.segmentation.clone(),
            features: app.model.extractor.config.clone(),
            camera: app.camera.clone(),
        })
    }

    /// Clusters left unsegmented because their image was not rendered where segmentation
    /// reads: non-zero only when a camera's columns disagree with [`Pipeline::image_region`].
    pub fn unrendered_reads(&self) -> usize {
        self.unrendered_reads
    }

    /// The report of the scan at `t`: its observations and what it did, handed over.
    fn report(&mut self, t: f64, clusters: Vec<Cluster>, assigned: Vec<Option<u32>>) -> ScanReport {
        ScanReport {
            t,
            clusters,
            assigned,
            decisions: std::mem::take(&mut self.decisions),
            merges: std::mem::take(&mut self.merges),
            retractions: std::mem::take(&mut self.retractions),
            segmentations: std::mem::take(&mut self.segmentations),
            relinearisations: std::mem::take(&mut self.relinearisations),
        }
    }

    /// Object model of landmark `id`, if it has one.
    pub fn object_model(&self, id: u32) -> Option<&ObjectModel> {
        let j = self.landmarks.iter().position(|l| l.id == id)?;
        self.objects.get(j).and_then(|o| o.as_ref())
    }

    pub fn appearance(&self) -> Option<&Appearance> {
        self.appearance.as_ref()
    }

    /// Odometry: the motion since the previous message, in the robot frame (the `odometry`
    /// motion model).
    pub fn on_odometry(&mut self, o: &OdometryIncrement) -> Result<(), PipelineError> {
        self.check_time("odometry", o.t)?;
        if ![o.dx, o.dy, o.dtheta].iter().all(|v| v.is_finite()) {
            return Err(PipelineError::NonFinite { input: "odometry", t: o.t });
        }
        if !matches!(self.config.motion, MotionConfig::Odometry(_)) {
            return Err(PipelineError::MotionInput { model: self.config.motion.name(), input: "odometry increments" });
        }
        self.predict([o.dx, o.dy, o.dtheta], o.t);
        Ok(())
    }

    /// A control (speeds, or speed and steering) that holds from `t` until the next input:
    /// the pipeline first moves on to `t` with the control held so far, so odometry needs no
    /// splitting at scan times.
    pub fn on_control(&mut self, t: f64, control: Control) -> Result<(), PipelineError> {
        self.check_time("control", t)?;
        let finite = match control {
            Control::Differential { v, omega } => v.is_finite() && omega.is_finite(),
            Control::Ackermann { speed, steering } => speed.is_finite() && steering.is_finite(),
        };
        if !finite {
            return Err(PipelineError::NonFinite { input: "control", t });
        }
        match (control, self.config.motion) {
            (Control::Differential { .. }, MotionConfig::Odometry(_))
            | (Control::Ackermann { .. }, MotionConfig::Ackermann(_)) => {}
            (Control::Differential { .. }, m) => {
                return Err(PipelineError::MotionInput { model: m.name(), input: "differential-drive controls" });
            }
            (Control::Ackermann { .. }, m) => {
                return Err(PipelineError::MotionInput { model: m.name(), input: "speed and steering controls" });
            }
        }
        self.advance_to(t);
        self.control = Some((t, control));
        Ok(())
    }

    /// Moves the filter on to `t` with the control held since the previous input (nothing
    /// when there is none, as with odometry increments).
    fn advance_to(&mut self, t: f64) {
        let Some((_, control)) = self.control else { return };
        let dt = t - self.t;
        if dt <= 0.0 {
            return;
        }
        let u = match control {
            // Along the arc of constant speeds, in the robot frame at the start.
            Control::Differential { v, omega } => {
                let turn = omega * dt;
                let (dx, dy) = if turn.abs() < 1e-9 {
                    (v * dt, 0.5 * v * dt * turn)
                } else {
                    (v / omega * turn.sin(), v / omega * (1.0 - turn.cos()))
                };
                [dx, dy, turn]
            }
            Control::Ackermann { speed, steering } => [speed, steering, dt],
        };
        self.predict(u, t);
    }

    /// The prediction with control `u` of the motion model, up to time `t`.
    fn predict(&mut self, u: [f64; 3], t: f64) {
        self.ekf.predict(&self.config.motion, &u);
        if let Some(h) = &mut self.history {
            h.push_control(u, self.ekf.pose());
        }
        // The dead-reckoned pose follows the same model, without the filter's corrections.
        let (next, _, _) = self.config.motion.predict(&Vector3::from(self.odometry_pose), &u);
        self.odometry_pose = [next.x, next.y, next.z];
        self.t = t;
        self.record_pose();
    }

    /// Point features already extracted from a scan (range, bearing and, where known,
    /// diameter, as in Victoria Park's tree detections), for the position-only methods.
    pub fn on_detections(&mut self, t: f64, detections: &[Detection]) -> Result<ScanReport, PipelineError> {
        self.check_time("detections", t)?;
        if self.config.method.uses_appearance() {
            return Err(PipelineError::DetectionsNeedPositionMethod(self.config.method.name()));
        }
        if detections.iter().any(|d| {
            !(d.range_m.is_finite() && d.bearing_rad.is_finite()) || d.diameter_m.is_some_and(|v| !v.is_finite())
        }) {
            return Err(PipelineError::NonFinite { input: "detections", t });
        }
        self.advance_to(t);
        let clusters: Vec<Cluster> = detections.iter().enumerate().map(|(k, d)| d.as_cluster(k)).collect();
        let keep = vec![true; clusters.len()];
        Ok(self.observe_positions(t, clusters, &keep, "unknown"))
    }

    /// Processes a scan. Position-only methods: every size-compatible cluster is an
    /// observation. Appearance methods: the clusters are segmented in the latest image (if
    /// it is recent enough) and only objects are observed.
    pub fn on_scan(&mut self, scan: &LaserScan) -> Result<ScanReport, PipelineError> {
        self.check_time("scan", scan.t)?;
        self.advance_to(scan.t);
        let clusters = cluster(scan, &self.config.clustering);
        if self.config.method.uses_appearance() {
            return Ok(self.on_scan_with_appearance(scan.t, clusters));
        }
        let keep = vec![true; clusters.len()];
        Ok(self.observe_positions(scan.t, clusters, &keep, "unknown"))
    }

    /// Map-frame position of a laser-frame point, and the rotation robot -> map.
    fn to_map(&self, p: [f64; 2]) -> ([f64; 2], Matrix2<f64>) {
        let pose = self.ekf.pose();
        self.laser_point_in(&[pose.x, pose.y, pose.z], p)
    }

    /// Position of a laser-frame point in the frame of `pose` (the robot's pose in it), and
    /// the rotation robot -> that frame.
    fn laser_point_in(&self, pose: &[f64; 3], p: [f64; 2]) -> ([f64; 2], Matrix2<f64>) {
        let (s, c) = pose[2].sin_cos();
        let (lx, ly) = (self.config.sensor.mount_x + p[0], self.config.sensor.mount_y + p[1]);
        ([pose[0] + c * lx - s * ly, pose[1] + s * lx + c * ly], Matrix2::new(c, -s, s, c))
    }

    /// Segments the clusters in the stored image and builds object observations, each with
    /// its cluster's index and whether the segmentation could judge it fully
    /// ([`SegmentedCluster::fully_judged`](crate::segmentation::SegmentedCluster::fully_judged)).
    fn observe_objects(&mut self, t: f64, clusters: &[Cluster]) -> Vec<(usize, ObjectObservation, bool)> {
        let (Some(app), Some(img)) = (&self.appearance, &self.image) else { return Vec::new() };
        if (t - img.t).abs() > self.config.image_max_age_s {
            return Vec::new();
        }
        let Ok(image) = ImageRef::new(img.width, img.height, &img.rgb) else { return Vec::new() };
        let extractor = &app.model.extractor;
        let l = extractor.config.patch_size;
        let mut record = SegmentationRecord { t_image: img.t, patch_size: l, cells: Vec::new(), clusters: Vec::new() };
        let mut out = Vec::new();
        // Each cluster's segmentation depends on nothing but the image and the cluster: they
        // run in parallel and are used in order, so results do not depend on the threads.
        let seg_config = &self.config.segmentation;
        // Per cluster: its segmentation, or whether it was skipped for lack of rendered pixels.
        let segmentations: Vec<Result<Option<SegmentedCluster>, ()>> = clusters
            .par_iter()
            .map(|c| {
                if c.occluded {
                    return Ok(None);
                }
                let Some(located) = locate_cluster(c, &app.camera, image.width, image.height, l, seg_config) else {
                    return Ok(None);
                };
                if let Some(columns) = &img.columns
                    && !spans_cover(columns, extractor.config.columns_read(&located.rect, image.width))
                {
                    return Err(());
                }
                Ok(segment_located(c, located, &image, extractor, &app.classifier, &app.camera, seg_config).ok())
            })
            .collect();
        self.unrendered_reads += segmentations.iter().filter(|s| s.is_err()).count();
        let segmentations = segmentations.into_iter().map(|s| s.ok().flatten());
        for (ci, (c, seg)) in clusters.iter().zip(segmentations).enumerate() {
            let Some(seg) = seg else { continue };
            for (i, &o) in seg.object.iter().enumerate() {
                let (col, row) = seg.rect.patch(i);
                if !record.cells.iter().any(|&(a, b, _)| a == col && b == row) {
                    record.cells.push((col, row, o));
                }
            }
            let hit_rows = (
                seg.hit_patches.iter().map(|h| h.1).min().unwrap_or(0),
                seg.hit_patches.iter().map(|h| h.1).max().unwrap_or(0),
            );
            let (centre, rot) = self.to_map(c.centre);
            // Pooling: a frame the camera judged fully adds to its place's evidence; one it
            // could not judge takes its place's judgement, or its own where no place is yet
            // (and then only re-observes confirmed landmarks). A place with fewer than
            // `min_frames` judged frames is undecided: rejected, or judged frame by frame
            // with `undecided_by_frame` (see EvidenceConfig for the trade-off).
            let seg_cfg = &self.config.segmentation;
            let enough_patches = seg.object.iter().filter(|&&o| o).count() >= seg_cfg.min_object_patches;
            let (place, _) = self.laser_point_in(&self.odometry_pose, c.centre);
            let pooled = self.config.evidence.pooled.then(|| {
                if seg.fully_judged() {
                    Some(self.evidence.add(t, place, c.range_m, seg.hit_fraction, seg.above_fraction))
                } else {
                    self.evidence.judge(place)
                }
            });
            let observed = match pooled {
                Some(Some(j))
                    if j.frames >= self.config.evidence.min_frames || !self.config.evidence.undecided_by_frame =>
                {
                    j.is_object && enough_patches
                }
                _ => seg.is_object,
            };
            record.clusters.push(ClusterSegmentation {
                index: ci,
                is_object: seg.is_object,
                hit_fraction: seg.hit_fraction,
                above_fraction: seg.above_fraction,
                pooled: pooled.flatten(),
                observed,
                band_visible: seg.band_visible,
                at_image_edge: seg.at_image_edge,
                row_profile: seg.row_profile.clone(),
                columns: (seg.rect.col0, seg.rect.col1),
                hit_rows,
                posteriors: seg.posteriors.iter().map(|&r| r as f32).collect(),
            });
            if !observed {
                continue;
            }
            let rows_idx = seg.object_rows();
            let da = self.config.object_model.appearance_dims.min(seg.features.z.ncols());
            let pca_dims = extractor.pca.dims();
            let mut appearance = Vec::with_capacity(rows_idx.len());
            let mut rows = DMatrix::zeros(rows_idx.len(), da + 3);
            let mut cells = Vec::with_capacity(rows_idx.len());
            let mut pixels = Vec::with_capacity(rows_idx.len());
            let mut n = 0;
            for &i in &rows_idx {
                let (col, row) = seg.rect.patch(i);
                let (u, v) = ((col as f64 + 0.5) * l as f64, (row as f64 + 0.5) * l as f64);
                let Some(p) = app.camera.point_on_object_plane(u, v, c.centre) else { continue };
                let d = rot * Vector2::new(p.x - c.centre[0], p.y - c.centre[1]);
                for j in 0..da {
                    rows[(n, j)] = seg.features.z[(i, j)];
                }
                rows[(n, da)] = d.x;
                rows[(n, da + 1)] = d.y;
                rows[(n, da + 2)] = p.z;
                appearance.push(seg.features.z.row(i).columns(0, pca_dims).iter().copied().collect());
                cells.push((col, row));
                pixels.push(patch_pixels(&img.rgb, img.width, col, row, l));
                n += 1;
            }
            if n < 2 {
                continue;
            }
            let rows = rows.rows(0, n).into_owned();
            // A place the pooled evidence calls an object was judged in earlier frames: a
            // frame too close to judge on its own may then start and confirm landmarks.
            let judged = seg.fully_judged() || matches!(pooled, Some(Some(j)) if j.is_object);
            out.push((
                ci,
                ObjectObservation { centre, rows, appearance, cells, pixels, centre_covariance: Matrix2::zeros() },
                judged,
            ));
        }
        self.evidence.forget_before(t);
        self.segmentations.push(record);
        out
    }

    /// Observations the KL test left without a landmark, paired by joint compatibility
    /// where that is unambiguous (see [`PipelineConfig::joint_loop_closing`]): per plan, the
    /// (id, index) of its landmark, `None` where the KL test decides.
    fn close_loop_jointly(&self, plans: &[Plan], cfg: &ObjectModelConfig) -> Vec<Option<(u32, usize)>> {
        let none = vec![None; plans.len()];
        let n = self.ekf.landmark_count();
        // KL-associated observations keep their landmark (or stay out); the others may take
        // any confirmed, gated candidate that looks alike.
        let mut orphans = 0;
        let allowed: Vec<Vec<bool>> = plans
            .iter()
            .map(|(_, obs, fitted, _, candidates, best, _)| {
                let mut row = vec![false; n];
                if let Some((_, j)) = best {
                    row[*j] = true;
                    return row;
                }
                for j in self.confirmed_lookalikes(obs, fitted, candidates, cfg) {
                    row[j] = true;
                }
                orphans += row.iter().any(|a| *a) as usize;
                row
            })
            .collect();
        if orphans == 0 || plans.len() < 2 {
            return none;
        }
        let zs: Vec<Vector2<f64>> = plans.iter().map(|p| p.3).collect();
        let Some(h) = unambiguous_jcbb(&self.ekf, &self.config.sensor, &zs, &allowed, self.config.jcbb_probability)
        else {
            return none;
        };
        // Two or more of the unexplained observations must pair: one alone is only
        // individually gated, and a new tree near an uncertain old one would pass.
        if h.iter().zip(plans).filter(|(j, p)| j.is_some() && p.5.is_none()).count() < 2 {
            return none;
        }
        h.iter()
            .zip(plans)
            .map(|(j, p)| if p.5.is_some() { None } else { j.map(|j| (self.landmarks[j].id, j)) })
            .collect()
    }

    /// Indices of the confirmed candidates whose object model looks like the observation
    /// (appearance KL under the threshold).
    fn confirmed_lookalikes<'a>(
        &'a self,
        obs: &'a ObjectObservation,
        fitted: &'a Gmm,
        candidates: &'a [Candidate],
        cfg: &'a ObjectModelConfig,
    ) -> impl Iterator<Item = usize> + 'a {
        candidates.iter().filter_map(move |c| {
            let j = self.landmarks.iter().position(|l| l.id == c.landmark)?;
            let model = self.objects[j].as_ref().filter(|_| self.landmarks[j].confirmed)?;
            model
                .kl_from(fitted, obs.centre, [0.0; 2], &Matrix2::zeros(), cfg, true)
                .is_ok_and(|kl| kl.is_finite() && kl < cfg.kl_threshold)
                .then_some(j)
        })
    }

    /// Whether a confirmed landmark that looks like the observation lies within its
    /// new-landmark gate (`candidates` holds those).
    fn near_lookalike(
        &self,
        obs: &ObjectObservation,
        fitted: &Gmm,
        candidates: &[Candidate],
        cfg: &ObjectModelConfig,
    ) -> bool {
        self.confirmed_lookalikes(obs, fitted, candidates, cfg).next().is_some()
    }

    /// Covariance (map frame) of the offset between an observation at (range, bearing) and
    /// landmark `j`: the innovation covariance mapped through the polar-to-Cartesian Jacobian.
    fn offset_covariance(&self, j: usize, z: &Vector2<f64>) -> Matrix2<f64> {
        let (_, _, _, s) = self.ekf.predict_observation(&self.config.sensor, j);
        let theta = self.ekf.pose().z;
        let (r, b) = (z.x, z.y);
        let (sb, cb) = b.sin_cos();
        let (st, ct) = theta.sin_cos();
        let polar = Matrix2::new(cb, -r * sb, sb, r * cb);
        let jz = Matrix2::new(ct, -st, st, ct) * polar;
        jz * s * jz.transpose()
    }

    /// Appearance methods: segmentation, object models and KL association.
    fn on_scan_with_appearance(&mut self, t: f64, clusters: Vec<Cluster>) -> ScanReport {
        self.t = t;
        // The state the recorded poses agree with, where a relinearisation starts.
        let before = self.history.as_ref().map(|_| self.ekf.x.clone());
        let observations = self.observe_objects(t, &clusters);
        let mut assigned = vec![None; clusters.len()];
        let method = self.config.method;
        let cfg = self.config.object_model.clone();
        let gate = chi2_quantile(2, self.config.new_landmark_probability);
        let assoc_gate = chi2_quantile(2, self.config.gate_probability);
        let n_before = self.ekf.landmark_count();
        let pca_dims = self.appearance.as_ref().map_or(0, |a| a.model.extractor.pca.dims());
        // Decide every observation against the landmarks that existed before this scan.
        let mut plans = Vec::new();
        let general = self.appearance.as_ref().map(|a| a.general.clone());
        for (ci, obs, fully_judged) in observations {
            let Ok(fitted) = fit_observation(&obs, general.as_ref(), &cfg) else { continue };
            let z = Vector2::new(clusters[ci].range_m, clusters[ci].bearing_rad);
            let mut candidates = Vec::new();
            for j in 0..n_before {
                let m2 = self.ekf.mahalanobis2(&self.config.sensor, j, &z);
                if method == AssociationMethod::Combined && m2 > gate {
                    continue;
                }
                let Some(model) = &self.objects[j] else { continue };
                if method == AssociationMethod::Combined
                    && !self.config.diameter.compatible(
                        clusters[ci].diameter_m,
                        z.x,
                        self.landmarks[j].diameter_m,
                        self.landmarks[j].observations,
                    )
                {
                    continue;
                }
                // A cluster too close for the camera to tell a trunk from a post may only
                // re-observe a confirmed landmark, never start or confirm one.
                if !fully_judged && !self.landmarks[j].confirmed {
                    continue;
                }
                let lm = self.ekf.landmark(j);
                let kl = model
                    .kl_from(
                        &fitted,
                        obs.centre,
                        [lm.x, lm.y],
                        &self.offset_covariance(j, &z),
                        &cfg,
                        method == AssociationMethod::Appearance,
                    )
                    .ok();
                candidates.push(Candidate { landmark: self.landmarks[j].id, mahalanobis2: m2, kl });
            }
            // The combined method's candidates lie within the new-landmark gate (for the
            // deferral and the joint test); to join one by KL, an observation must also be
            // within the association gate, as for the position-only methods.
            let best = candidates
                .iter()
                .filter(|c| method != AssociationMethod::Combined || c.mahalanobis2 <= assoc_gate)
                .filter_map(|c| c.kl.filter(|k| k.is_finite() && *k < cfg.kl_threshold).map(|k| (c.landmark, k)))
                .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
            let best = best.and_then(|(id, _)| self.landmarks.iter().position(|l| l.id == id).map(|j| (id, j)));
            plans.push((ci, obs, fitted, z, candidates, best, fully_judged));
        }
        let joint = if method == AssociationMethod::Combined && self.config.joint_loop_closing {
            self.close_loop_jointly(&plans, &cfg)
        } else {
            vec![None; plans.len()]
        };
        let mut new_ones = Vec::new();
        let mut closed_jointly = false;
        for ((ci, obs, fitted, z, candidates, best, fully_judged), joint) in plans.into_iter().zip(joint) {
            // A loop closed jointly corrects the pose by metres. With latest-estimate
            // Jacobians the closing update itself is iterated; first-estimate ones stay
            // where they are, and the smoother relinearises after the scan.
            let closes_jointly = best.is_none() && joint.is_some();
            let iterations = if closes_jointly && !self.config.first_estimate_jacobians { 10 } else { 1 };
            let best = best.or(joint);
            let choice = match best {
                Some((id, j)) => {
                    if self.ekf.update_iterated(&self.config.sensor, j, &z, iterations).is_ok() {
                        let lm = self.ekf.landmark(j);
                        if let Some(m) = self.objects[j].as_mut() {
                            let _ = m.update(&obs, [lm.x, lm.y], pca_dims);
                        }
                        self.places[j] = Some(self.laser_point_in(&self.odometry_pose, clusters[ci].centre).0);
                        let l = &mut self.landmarks[j];
                        l.diameter_m = (l.diameter_m * l.observations as f64 + clusters[ci].diameter_m)
                            / (l.observations + 1) as f64;
                        l.observations += 1;
                        assigned[ci] = Some(id);
                        closed_jointly |= closes_jointly;
                        if let Some(h) = &mut self.history {
                            h.observe(id, z);
                        }
                        Choice::Existing { landmark: id }
                    } else {
                        Choice::Rejected
                    }
                }
                None if !fully_judged => Choice::Rejected,
                None if method == AssociationMethod::Combined
                    && self.config.defer_near_lookalike
                    && self.near_lookalike(&obs, &fitted, &candidates, &cfg) =>
                {
                    Choice::Deferred
                }
                None => {
                    new_ones.push((ci, self.decisions.len(), obs, fitted, z));
                    Choice::Rejected // replaced below once the id exists
                }
            };
            self.decisions.push(AssociationDecision { t, observation: ci, candidates, choice, method });
        }
        let class = self.appearance.as_ref().map_or("object".to_string(), |a| a.model.object_class.clone());
        for (ci, decision, obs, fitted, z) in new_ones {
            let j = self.ekf.add_landmark(&self.config.sensor, &z);
            let id = self.next_id;
            self.next_id += 1;
            debug_assert_eq!(j, self.landmarks.len());
            let lm = self.ekf.landmark(j);
            // Re-centre the model's positions on the landmark estimate.
            let mut model = ObjectModel::new(&obs, fitted, pca_dims);
            let d = model.gmm.dims();
            for c in &mut model.gmm.components {
                c.mean[d - 3] += obs.centre[0] - lm.x;
                c.mean[d - 2] += obs.centre[1] - lm.y;
            }
            self.landmarks.push(Landmark {
                id,
                position: [0.0; 2],
                covariance: [[0.0; 2]; 2],
                class: class.clone(),
                observations: 1,
                diameter_m: clusters[ci].diameter_m,
                created_t: t,
                confirmed: self.config.confirm_observations <= 1,
            });
            self.objects.push(Some(model));
            self.places.push(Some(self.laser_point_in(&self.odometry_pose, clusters[ci].centre).0));
            assigned[ci] = Some(id);
            self.decisions[decision].choice = Choice::New { landmark: id };
            if let Some(h) = &mut self.history {
                h.observe(id, z);
            }
        }
        let due = self.config.relinearise_every_s.is_some_and(|every| t - self.relinearised_at >= every);
        if (closed_jointly || due)
            && let Some(before) = &before
        {
            self.relinearise(before);
        }
        if self.config.evidence.pooled {
            self.retract_landmarks();
        }
        self.note_co_observed(&assigned);
        self.refresh_landmarks();
        if let Some(h) = &mut self.history {
            h.set_estimate(self.ekf.pose());
        }
        self.record_pose();
        self.report(t, clusters, assigned)
    }

    /// Processes clusters of which only those with `is_object[i]` are observations of
    /// objects of interest (labelled `class`), for the position-only association.
    pub fn on_scan_with_objects(
        &mut self,
        t: f64,
        clusters: Vec<Cluster>,
        is_object: &[bool],
        class: &str,
    ) -> Result<ScanReport, PipelineError> {
        if is_object.len() != clusters.len() {
            return Err(PipelineError::ObjectFlags { given: is_object.len(), clusters: clusters.len() });
        }
        self.check_time("scan", t)?;
        self.advance_to(t);
        Ok(self.observe_positions(t, clusters, is_object, class))
    }

    /// Position-only association and the filter's update for one scan's clusters.
    fn observe_positions(&mut self, t: f64, clusters: Vec<Cluster>, is_object: &[bool], class: &str) -> ScanReport {
        self.t = t;
        let idx: Vec<usize> = (0..clusters.len()).filter(|&i| is_object[i] && !clusters[i].occluded).collect();
        let zs: Vec<Vector2<f64>> =
            idx.iter().map(|&i| Vector2::new(clusters[i].range_m, clusters[i].bearing_rad)).collect();
        let gate = chi2_quantile(2, self.config.gate_probability);
        let new_gate = chi2_quantile(2, self.config.new_landmark_probability);
        let n_before = self.ekf.landmark_count();
        let diameter = &self.config.diameter;
        let use_diameter = diameter.for_position_methods;
        // Each landmark's predicted observation and inverse innovation covariance, once a
        // scan rather than once an observation (the same numbers as Ekf::mahalanobis2).
        let predicted: Vec<(Vector2<f64>, Option<Matrix2<f64>>)> = if zs.is_empty() {
            Vec::new()
        } else {
            (0..n_before)
                .map(|j| {
                    let (zp, _, _, s) = self.ekf.predict_observation(&self.config.sensor, j);
                    (zp, s.try_inverse())
                })
                .collect()
        };
        let distances: Vec<Vec<f64>> = zs
            .iter()
            .zip(&idx)
            .map(|(z, &ci)| {
                predicted
                    .iter()
                    .enumerate()
                    .map(|(j, (zp, s_inv))| {
                        let lm = &self.landmarks[j];
                        if use_diameter
                            && !diameter.compatible(clusters[ci].diameter_m, z.x, lm.diameter_m, lm.observations)
                        {
                            return f64::INFINITY;
                        }
                        let nu = Vector2::new(z.x - zp.x, crate::messages::wrap_angle(z.y - zp.y));
                        match s_inv {
                            Some(si) => (nu.transpose() * si * nu)[(0, 0)],
                            None => f64::INFINITY,
                        }
                    })
                    .collect()
            })
            .collect();
        let pairing: Vec<Option<usize>> = match self.config.method {
            AssociationMethod::Jcbb => {
                let allowed: Vec<Vec<bool>> =
                    distances.iter().map(|row| row.iter().map(|d| *d < gate).collect()).collect();
                jcbb_with(&self.ekf, &self.config.sensor, &zs, &allowed, self.config.jcbb_probability)
            }
            // Nearest neighbour; appearance methods fall back to it until their
            // observations carry object models.
            _ => distances.iter().map(|row| nearest_within(row, gate)).collect(),
        };
        let mut assigned = vec![None; clusters.len()];
        // Updates first (against the landmarks that existed before this scan), then new
        // landmarks, so the order of observations does not matter.
        let updated: Vec<bool> = if self.config.batch_updates {
            let pairs: Vec<(usize, Vector2<f64>)> =
                pairing.iter().zip(&zs).filter_map(|(j, z)| j.map(|j| (j, *z))).collect();
            match self.ekf.update_batch(&self.config.sensor, &pairs) {
                Ok(()) => pairing.iter().map(|j| j.is_some()).collect(),
                // A stacked innovation covariance that is not positive definite: the
                // observations one by one, each accepted or refused on its own.
                Err(_) => pairing
                    .iter()
                    .zip(&zs)
                    .map(|(j, z)| j.is_some_and(|j| self.ekf.update(&self.config.sensor, j, z).is_ok()))
                    .collect(),
            }
        } else {
            pairing
                .iter()
                .zip(&zs)
                .map(|(j, z)| j.is_some_and(|j| self.ekf.update(&self.config.sensor, j, z).is_ok()))
                .collect()
        };
        let mut new_ones = Vec::new();
        for (k, &ci) in idx.iter().enumerate() {
            let candidates: Vec<Candidate> = distances[k]
                .iter()
                .enumerate()
                .filter(|(_, d)| **d < new_gate)
                .map(|(j, d)| Candidate { landmark: self.landmarks[j].id, mahalanobis2: *d, kl: None })
                .collect();
            let choice = match pairing[k] {
                Some(j) if updated[k] => {
                    let lm = &mut self.landmarks[j];
                    lm.diameter_m = mean_diameter(lm.diameter_m, lm.observations, clusters[ci].diameter_m);
                    lm.observations += 1;
                    assigned[ci] = Some(lm.id);
                    if let Some(h) = &mut self.history {
                        h.observe(lm.id, zs[k]);
                    }
                    Choice::Existing { landmark: lm.id }
                }
                Some(_) => Choice::Rejected,
                None if distances[k].iter().all(|d| *d > new_gate) => {
                    new_ones.push((k, ci));
                    Choice::Rejected // replaced below once the id exists
                }
                None => Choice::Rejected,
            };
            self.decisions.push(AssociationDecision {
                t,
                observation: ci,
                candidates,
                choice,
                method: self.config.method,
            });
        }
        let first_decision = self.decisions.len() - idx.len();
        if self.config.batch_updates {
            let new_zs: Vec<Vector2<f64>> = new_ones.iter().map(|&(k, _)| zs[k]).collect();
            self.ekf.add_landmarks(&self.config.sensor, &new_zs);
        } else {
            for &(k, _) in &new_ones {
                self.ekf.add_landmark(&self.config.sensor, &zs[k]);
            }
        }
        for (k, ci) in new_ones {
            let id = self.next_id;
            self.next_id += 1;
            self.landmarks.push(Landmark {
                id,
                position: [0.0; 2],
                covariance: [[0.0; 2]; 2],
                class: class.to_string(),
                observations: 1,
                diameter_m: clusters[ci].diameter_m,
                created_t: t,
                confirmed: self.config.confirm_observations <= 1,
            });
            self.objects.push(None);
            self.places.push(None);
            assigned[ci] = Some(id);
            self.decisions[first_decision + k].choice = Choice::New { landmark: id };
            if let Some(h) = &mut self.history {
                h.observe(id, zs[k]);
            }
        }
        debug_assert_eq!(self.ekf.landmark_count(), self.landmarks.len());
        self.note_co_observed(&assigned);
        self.refresh_landmarks();
        if let Some(h) = &mut self.history {
            h.set_estimate(self.ekf.pose());
        }
        self.record_pose();
        self.report(t, clusters, assigned)
    }

    /// Takes landmark `j` out of the pipeline's per-landmark lists (not the filter's state).
    fn forget_landmark(&mut self, j: usize) -> Landmark {
        self.objects.remove(j);
        self.places.remove(j);
        self.landmarks.remove(j)
    }

    /// Retracts the landmarks whose place nearer frames judge not an object: a palm taken
    /// for a tree from 8-12 m, where the camera cannot tell its trunk from bark.
    fn retract_landmarks(&mut self) {
        let mut j = 0;
        while j < self.landmarks.len() {
            if self.places[j].and_then(|p| self.evidence.judge(p)).is_some_and(|jd| jd.retracts(&self.config.evidence))
            {
                self.ekf.remove_landmark(j);
                let gone = self.forget_landmark(j);
                self.retractions.push(LandmarkRetraction { t: self.t, landmark: gone.id });
            } else {
                j += 1;
            }
        }
    }

    fn refresh_landmarks(&mut self) {
        // Confirm landmarks seen often enough; delete tentative ones that timed out.
        let (need, window, t) = (self.config.confirm_observations, self.config.confirm_window_s, self.t);
        for lm in &mut self.landmarks {
            if !lm.confirmed && lm.observations >= need {
                lm.confirmed = true;
            }
        }
        let mut j = 0;
        while j < self.landmarks.len() {
            let lm = &self.landmarks[j];
            if !lm.confirmed && t - lm.created_t > window {
                self.ekf.remove_landmark(j);
                self.forget_landmark(j);
            } else {
                j += 1;
            }
        }
        if self.config.merge.enabled {
            self.merge_duplicates();
        }
        for (i, lm) in self.landmarks.iter_mut().enumerate() {
            let p = self.ekf.landmark(i);
            let c = self.ekf.landmark_covariance(i);
            lm.position = [p.x, p.y];
            lm.covariance = [[c[(0, 0)], c[(0, 1)]], [c[(1, 0)], c[(1, 1)]]];
        }
    }

    fn note_co_observed(&mut self, assigned: &[Option<u32>]) {
        // Only fusion reads it.
        if !self.config.merge.enabled {
            return;
        }
        let ids: Vec<u32> = assigned.iter().flatten().copied().collect();
        for (k, &a) in ids.iter().enumerate() {
            for &b in &ids[k + 1..] {
                self.co_observed.insert((a.min(b), a.max(b)));
            }
        }
    }

    /// Fuses pairs of confirmed landmarks that are one object (see [`MergeConfig`]), the
    /// older one staying, until no pair qualifies.
    fn merge_duplicates(&mut self) {
        let cfg = self.config.merge.clone();
        let gate = chi2_quantile(2, self.config.gate_probability);
        // Past the gate and the sigma bound, two positions are at most this far apart.
        let reach = gate.sqrt() * cfg.max_sigma_m * std::f64::consts::SQRT_2;
        loop {
            // Pairs of confirmed landmarks within reach, found by a sweep along x rather
            // than over all pairs (the map holds hundreds on a real log), then taken in
            // (i, j) order as a search over all pairs would meet them.
            let mut order: Vec<(f64, usize)> = (0..self.landmarks.len())
                .filter(|&i| self.landmarks[i].confirmed)
                .map(|i| (self.ekf.landmark(i).x, i))
                .collect();
            order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let mut near = Vec::new();
            for (k, &(xa, a)) in order.iter().enumerate() {
                let la = self.ekf.landmark(a);
                for &(xb, b) in &order[k + 1..] {
                    if xb - xa > reach {
                        break;
                    }
                    if (self.ekf.landmark(b) - la).norm() <= reach {
                        near.push((a.min(b), a.max(b)));
                    }
                }
            }
            near.sort_unstable();
            let pair = near.into_iter().find(|&(i, j)| {
                let (a, b) = (self.landmarks[i].id, self.landmarks[j].id);
                if self.co_observed.contains(&(a.min(b), a.max(b))) {
                    return false;
                }
                let (m2, c) = self.ekf.landmark_difference(i, j);
                let widest = c.symmetric_eigenvalues().max();
                m2 <= gate && widest <= cfg.max_sigma_m * cfg.max_sigma_m && self.look_alike(i, j)
            });
            let Some((i, j)) = pair else { break };
            if self.ekf.merge_landmarks(i, j, cfg.noise_sigma_m).is_err() {
                break;
            }
            let gone = self.forget_landmark(j);
            let kept = &mut self.landmarks[i];
            kept.diameter_m = (kept.diameter_m * kept.observations as f64 + gone.diameter_m * gone.observations as f64)
                / (kept.observations + gone.observations).max(1) as f64;
            kept.observations += gone.observations;
            // The fused landmark is never fused with what either was seen beside.
            let partners: Vec<u32> = self
                .co_observed
                .iter()
                .filter_map(|&(a, b)| {
                    if a == gone.id {
                        Some(b)
                    } else if b == gone.id {
                        Some(a)
                    } else {
                        None
                    }
                })
                .collect();
            let kept_id = kept.id;
            for p in partners {
                self.co_observed.insert((kept_id.min(p), kept_id.max(p)));
            }
            self.merges.push(LandmarkMerge { t: self.t, kept: kept_id, removed: gone.id });
            if let Some(h) = &mut self.history {
                h.relabel(gone.id, kept_id);
            }
        }
    }

    /// Whether landmarks `i` and `j` may be one object by their appearance: always for the
    /// position-only methods; for the appearance methods when both have object models whose
    /// appearance KL is under the association threshold.
    fn look_alike(&self, i: usize, j: usize) -> bool {
        if !self.config.method.uses_appearance() {
            return true;
        }
        let (Some(a), Some(b)) = (&self.objects[i], &self.objects[j]) else { return false };
        let cfg = &self.config.object_model;
        a.kl_from(&b.gmm, [0.0; 2], [0.0; 2], &Matrix2::zeros(), cfg, true)
            .is_ok_and(|kl| kl.is_finite() && kl < cfg.kl_threshold)
    }

    /// Solves the history again and gives the filter the result (see
    /// [`PipelineConfig::relinearise_loop_closures`]); a failed solve leaves the filter as
    /// it was.
    fn relinearise(&mut self, before: &DVector<f64>) {
        let Some(history) = &mut self.history else { return };
        self.relinearised_at = self.t;
        let ids: Vec<u32> = self.landmarks.iter().map(|l| l.id).collect();
        let solved = history.relinearise(&mut self.ekf, before, &self.config.motion, &self.config.sensor, &ids, 10);
        self.relinearisations.push(solved);
    }

    fn record_pose(&mut self) {
        let p = self.ekf.pose();
        let c = self.ekf.pose_covariance();
        let est = PoseEstimate {
            t: self.t,
            pose: [p.x, p.y, p.z],
            covariance: std::array::from_fn(|r| std::array::from_fn(|k| c[(r, k)])),
        };
        self.pose = est;
    }

    /// The latest pose estimate.
    pub fn pose(&self) -> PoseEstimate {
        self.pose
    }

    /// Every landmark in the filter, tentative ones included.
    pub fn landmarks(&self) -> &[Landmark] {
        &self.landmarks
    }

    /// The map: confirmed landmarks only.
    pub fn mapped_landmarks(&self) -> Vec<Landmark> {
        self.landmarks.iter().filter(|l| l.confirmed).cloned().collect()
    }

    pub fn ekf(&self) -> &Ekf {
        &self.ekf
    }
}

#[cfg(test)]
mod merge_tests {
    use super::*;

    fn cluster_at(range: f64, bearing: f64) -> Cluster {
        Cluster {
            first_beam: 0,
            last_beam: 3,
            points: vec![],
            centre: [range * bearing.cos(), range * bearing.sin()],
            diameter_m: 0.3,
            range_m: range,
            bearing_rad: bearing,
            occluded: false,
        }
    }

    /// Two landmarks, seen in one scan or in two, then landmark 1 moved to 2 cm from
    /// landmark 0 (as if a loop closure had pulled a duplicate onto its original).
    fn pair(seen_together: bool, extra_variance: f64, merge: bool) -> Pipeline {
        let merge = MergeConfig { enabled: merge, ..Default::default() };
        let config =
            PipelineConfig { method: AssociationMethod::Nn, confirm_observations: 1, merge, ..Default::default() };
        let mut p = Pipeline::new(config, [0.0; 3]);
        let (a, b) = (cluster_at(5.0, 0.0), cluster_at(5.0, 0.5));
        if seen_together {
            p.on_scan_with_objects(0.1, vec![a, b], &[true, true], "tree").unwrap();
        } else {
            p.on_scan_with_objects(0.1, vec![a], &[true], "tree").unwrap();
            p.on_scan_with_objects(0.2, vec![b], &[true], "tree").unwrap();
        }
        assert_eq!(p.landmarks().len(), 2);
        let (l0, l1) = (p.ekf.landmark_offset(), p.ekf.landmark_offset() + 2);
        p.ekf.x[l1] = p.ekf.x[l0] + 0.02;
        p.ekf.x[l1 + 1] = p.ekf.x[l0 + 1];
        p.ekf.p[(l1, l1)] += extra_variance;
        p.ekf.p[(l1 + 1, l1 + 1)] += extra_variance;
        p.refresh_landmarks();
        p
    }

    #[test]
    fn a_duplicate_is_fused_into_the_older_landmark() {
        let p = pair(false, 0.0, true);
        assert_eq!(p.landmarks().len(), 1);
        assert_eq!(p.landmarks()[0].id, 0);
        assert_eq!(p.landmarks()[0].observations, 2);
        assert_eq!(p.merges, [LandmarkMerge { t: 0.2, kept: 0, removed: 1 }]);
        assert_eq!(p.ekf().landmark_count(), 1);
        let c = p.ekf().landmark_covariance(0);
        assert!(c.symmetric_eigenvalues().min() > 0.0);
    }

    #[test]
    fn landmarks_seen_in_one_scan_are_never_fused() {
        let p = pair(true, 0.0, true);
        assert_eq!(p.landmarks().len(), 2);
        assert!(p.merges.is_empty());
    }

    #[test]
    fn landmarks_too_uncertain_to_tell_apart_are_not_fused() {
        let p = pair(false, 0.5, true);
        assert_eq!(p.landmarks().len(), 2);
        // Disabled, a pair that would qualify stays apart too.
        let q = pair(false, 0.0, false);
        assert_eq!(q.landmarks().len(), 2);
        assert!(q.merges.is_empty());
    }
}

#[cfg(test)]
mod association_rule_tests {
    use super::*;
    use crate::gmm::Component;
    use crate::object_model::MosaicView;
    use nalgebra::DVector;

    /// A one-component density over [4 appearance dims | x, y | h] with appearance mean `a`.
    fn density(a: f64) -> Gmm {
        let mut mean = DVector::zeros(7);
        mean.rows_mut(0, 4).fill(a);
        mean[6] = 1.0;
        Gmm { components: vec![Component { weight: 1.0, mean, covariance: DMatrix::identity(7, 7) * 0.04 }] }
    }

    /// One tree landmark 5 m ahead with an object model of appearance 0.
    fn one_landmark(confirm_observations: usize) -> Pipeline {
        let config = PipelineConfig { method: AssociationMethod::Nn, confirm_observations, ..Default::default() };
        let mut p = Pipeline::new(config, [0.0; 3]);
        let c = Cluster {
            first_beam: 0,
            last_beam: 3,
            points: vec![],
            centre: [5.0, 0.0],
            diameter_m: 0.3,
            range_m: 5.0,
            bearing_rad: 0.0,
            occluded: false,
        };
        p.on_scan_with_objects(0.1, vec![c], &[true], "tree").unwrap();
        p.objects[0] = Some(ObjectModel {
            gmm: density(0.0),
            patches: 20.0,
            observations: 1,
            mosaic: MosaicView { cells: vec![], appearance: vec![], pixels: vec![] },
        });
        p
    }

    fn observation() -> ObjectObservation {
        ObjectObservation {
            centre: [5.2, 0.1],
            rows: DMatrix::zeros(0, 7),
            appearance: vec![],
            cells: vec![],
            pixels: vec![],
            centre_covariance: Matrix2::zeros(),
        }
    }

    #[test]
    fn an_observation_beside_a_confirmed_lookalike_is_deferred() {
        let p = one_landmark(1);
        let cfg = ObjectModelConfig::default();
        let candidate = [Candidate { landmark: 0, mahalanobis2: 1.0, kl: Some(500.0) }];
        assert!(p.near_lookalike(&observation(), &density(0.05), &candidate, &cfg), "same appearance, in the gate");
        assert!(
            !p.near_lookalike(&observation(), &density(5.0), &candidate, &cfg),
            "another kind of object starts its own landmark"
        );
        assert!(!p.near_lookalike(&observation(), &density(0.05), &[], &cfg), "nothing in the gate");
        // A tentative landmark (maybe a person) never holds a new tree back.
        let q = one_landmark(8);
        assert!(!q.near_lookalike(&observation(), &density(0.05), &candidate, &cfg));
    }

    #[test]
    fn trunk_diameters_tell_apart_trees_of_different_girth() {
        let check = DiameterCheck::default();
        // long_loop, seed 1: a 0.64 m trunk 11 m away was paired with a 0.45 m one.
        assert!(!check.compatible(0.64, 11.0, 0.446, 54));
        // The spread measured between single clusters and their landmark: 3 sigma in, at
        // every range, with few or many observations behind the landmark.
        for (range, spread) in [(4.0, 0.05), (8.0, 0.08), (11.0, 0.12)] {
            assert!(check.compatible(0.45 + spread, range, 0.45, 50), "{range} m");
            assert!(check.compatible(0.45 - spread, range, 0.45, 1), "{range} m");
        }
        assert!(!check.compatible(0.45 + 0.1, 4.0, 0.45, 50));
        let off = DiameterCheck { enabled: false, ..Default::default() };
        assert!(off.compatible(1.0, 5.0, 0.2, 10));
        assert!(check.validate().is_ok());
        assert_eq!(DiameterCheck { max_sigmas: 0.0, ..Default::default() }.validate().unwrap_err().0, "max_sigmas");
        assert_eq!(
            DiameterCheck { sigma_per_m: f64::NAN, ..Default::default() }.validate().unwrap_err().0,
            "sigma_per_m"
        );
        assert_eq!(
            DiameterCheck { sigma_m: 0.0, sigma_per_m: 0.0, ..Default::default() }.validate().unwrap_err().0,
            "sigma_m"
        );
    }
}

#[cfg(test)]
mod input_tests {
    use super::*;
    use crate::ekf::AckermannMotionModel;

    fn car_config(method: AssociationMethod) -> PipelineConfig {
        PipelineConfig {
            method,
            motion: MotionConfig::Ackermann(AckermannMotionModel::default()),
            confirm_observations: 1,
            ..Default::default()
        }
    }

    fn detection(range_m: f64, bearing_rad: f64, diameter_m: f64) -> Detection {
        Detection { range_m, bearing_rad, diameter_m: Some(diameter_m) }
    }

    #[test]
    fn inputs_out_of_time_order_are_errors() {
        let mut p = Pipeline::new(PipelineConfig { method: AssociationMethod::Nn, ..Default::default() }, [0.0; 3])
            .starting_at(100.0);
        assert_eq!(p.pose().t, 100.0, "the first pose is stamped at the log's start");
        let early = OdometryIncrement { t: 99.0, dx: 0.1, dy: 0.0, dtheta: 0.0 };
        assert!(matches!(p.on_odometry(&early), Err(PipelineError::TimeReversed { t: 99.0, previous: 100.0, .. })));
        p.on_odometry(&OdometryIncrement { t: 101.0, ..early }).unwrap();
        let bad = p.on_detections(100.5, &[]).unwrap_err();
        assert!(bad.to_string().contains("t = 100.5 s comes before the previous input at t = 101 s"), "{bad}");
        let nan = OdometryIncrement { t: 102.0, dx: f64::NAN, dy: 0.0, dtheta: 0.0 };
        assert!(matches!(p.on_odometry(&nan), Err(PipelineError::NonFinite { .. })));
        assert!(matches!(
            p.on_scan_with_objects(103.0, vec![detection(5.0, 0.0, 0.3).as_cluster(0)], &[], "tree"),
            Err(PipelineError::ObjectFlags { given: 0, clusters: 1 })
        ));
        // A car's controls do not fit the odometry model, nor increments the car model.
        assert!(matches!(
            p.on_control(104.0, Control::Ackermann { speed: 1.0, steering: 0.0 }),
            Err(PipelineError::MotionInput { model: "odometry", .. })
        ));
        let mut car = Pipeline::new(car_config(AssociationMethod::Nn), [0.0; 3]);
        assert!(matches!(
            car.on_odometry(&OdometryIncrement { t: 1.0, ..early }),
            Err(PipelineError::MotionInput { .. })
        ));
        let mut combined = Pipeline::new(PipelineConfig::default(), [0.0; 3]);
        assert!(matches!(combined.on_detections(1.0, &[]), Err(PipelineError::DetectionsNeedPositionMethod(_))));
    }

    #[test]
    fn a_held_control_moves_the_car_up_to_each_detection() {
        let mut p = Pipeline::new(car_config(AssociationMethod::Nn), [0.0; 3]);
        p.on_control(0.0, Control::Ackermann { speed: 2.0, steering: 0.0 }).unwrap();
        // No further control: the detections at 1.5 s find the car 3 m on.
        p.on_detections(1.5, &[]).unwrap();
        assert!((p.pose().pose[0] - 3.0).abs() < 1e-12 && p.pose().t == 1.5);
        p.on_control(2.0, Control::Ackermann { speed: 0.0, steering: 0.0 }).unwrap();
        assert!((p.pose().pose[0] - 4.0).abs() < 1e-12);
        // A differential drive's speeds through the odometry model: a quarter circle.
        let mut robot = Pipeline::new(PipelineConfig { method: AssociationMethod::Nn, ..Default::default() }, [0.0; 3]);
        robot.on_control(0.0, Control::Differential { v: 1.0, omega: std::f64::consts::FRAC_PI_2 }).unwrap();
        robot.on_detections(1.0, &[]).unwrap();
        let r = 2.0 / std::f64::consts::PI;
        let [x, y, th] = robot.pose().pose;
        assert!((x - r).abs() < 1e-9 && (y - r).abs() < 1e-9 && (th - std::f64::consts::FRAC_PI_2).abs() < 1e-9);
    }

    #[test]
    fn the_diameter_cue_keeps_a_thin_post_off_a_thick_tree() {
        // A thick tree mapped at 10 m; then, from the same place, a thin one 0.4 m beside
        // it, well inside the position gate of a filter this unsure.
        let run = |for_position_methods: bool| {
            let config = PipelineConfig {
                diameter: DiameterCheck { for_position_methods, ..Default::default() },
                sensor: RangeBearingModel { range_sigma_m: 0.3, bearing_sigma_rad: 0.05, ..Default::default() },
                ..car_config(AssociationMethod::Nn)
            };
            let mut p = Pipeline::new(config, [0.0; 3]);
            p.on_detections(0.1, &[detection(10.0, 0.0, 0.8)]).unwrap();
            let report = p.on_detections(0.2, &[detection(10.0, 0.04, 0.2)]).unwrap();
            report.decisions[0].choice
        };
        assert_eq!(run(false), Choice::Existing { landmark: 0 }, "position alone takes the tree");
        assert!(!matches!(run(true), Choice::Existing { .. }), "the diameter refuses it");
        // Without a diameter the detection fits any landmark.
        let d = DiameterCheck::default();
        assert!(d.compatible(f64::NAN, 10.0, 0.8, 3) && d.compatible(0.2, 10.0, f64::NAN, 1));
    }

    #[test]
    fn batched_updates_make_the_same_associations() {
        // A car driving along a row of trees, detections with a little noise: the batched
        // and sequential filters associate identically and end within centimetres.
        let trees: Vec<[f64; 2]> = (0..12).map(|k| [4.0 * k as f64, if k % 2 == 0 { 6.0 } else { -5.0 }]).collect();
        let run = |batch_updates: bool| {
            let mut p = Pipeline::new(PipelineConfig { batch_updates, ..car_config(AssociationMethod::Nn) }, [0.0; 3]);
            let mut choices = Vec::new();
            for step in 0..100 {
                let t = step as f64 * 0.25;
                p.on_control(t, Control::Ackermann { speed: 2.0 * 1.01, steering: 0.002 }).unwrap();
                let truth = [2.0 * t, 0.0];
                let dets: Vec<Detection> = trees
                    .iter()
                    .enumerate()
                    .filter_map(|(k, tr)| {
                        let (dx, dy) = (tr[0] - truth[0] - 0.16, tr[1] - truth[1]);
                        let r = dx.hypot(dy);
                        let noise = ((step * 7 + k * 3) % 5) as f64 * 0.004 - 0.008;
                        (r < 15.0).then(|| detection(r + noise, dy.atan2(dx) + noise * 0.1, 0.3))
                    })
                    .collect();
                let report = p.on_detections(t + 0.1, &dets).unwrap();
                choices.extend(report.decisions.into_iter().map(|d| d.choice));
            }
            (choices, p.pose().pose)
        };
        let (seq_choices, seq_pose) = run(false);
        let (batch_choices, batch_pose) = run(true);
        assert_eq!(seq_choices, batch_choices);
        assert!(seq_choices.iter().filter(|c| matches!(c, Choice::Existing { .. })).count() > 300);
        assert!((seq_pose[0] - batch_pose[0]).hypot(seq_pose[1] - batch_pose[1]) < 0.02, "{seq_pose:?} {batch_pose:?}");
    }
}
