//! The online pipeline: odometry predicts, each scan is clustered, clusters become
//! observations, association decides, the EKF updates and new landmarks are added.
//!
//! With a position-only method (`nn`, `jcbb`) every cluster whose size fits a trunk is an
//! observation: posts and people's legs can become landmarks, which is the failure the
//! paper argues against. The appearance methods (`combined`, the paper's, and
//! `appearance`) take their observations from the laser-camera segmentation of the latest
//! camera image: only clusters segmented as objects are observed, each with an object
//! model, and association compares models by KL divergence.
//!
//! The files, by stage: `config` (settings), `inputs` (odometry, controls, scans,
//! detections, images), `position` and `appearance` (association and the filter's
//! update, by method family), `landmarks` (confirmation, retraction, fusion,
//! relinearisation), `records` (what a scan reports), `table` (the per-landmark records,
//! which every landmark enters and leaves the filter through, so they stay index-aligned
//! with it).
//!
//! # From a robot's own code
//!
//! A car's speed and steering and a tree detector's range and bearing, fed as they
//! arrive (what `objslam replay` does from a log's files). Inputs come in time order
//! (equal times are fine, and images may lag the scans); a malformed one is refused with
//! a [`PipelineError`] and changes nothing. An input that breaks the filter is reported
//! (`Diverged`, `Indefinite`): one whose prediction the filter refuses changes nothing,
//! one that breaks it in an update is applied first; either way every later input is
//! refused.
//!
//! ```
//! use nalgebra::{Vector2, Vector3};
//! use slam::association::AssociationMethod;
//! use slam::ekf::{AckermannMotionModel, MotionConfig, MotionModel};
//! use slam::messages::{Control, Detection};
//! use slam::pipeline::{Pipeline, PipelineConfig};
//!
//! let car = AckermannMotionModel::default();
//! let config = PipelineConfig {
//!     method: AssociationMethod::Nn,
//!     motion: MotionConfig::Ackermann(car),
//!     ..Default::default()
//! };
//! let t0 = 1000.0; // the log's clock: the first pose is stamped then
//! let mut slam = Pipeline::new(config.clone(), [0.0; 3], None)?.starting_at(t0)?;
//! // Made up for the example: twelve trees on a ring, the car circling inside it at a
//! // constant speed and steering, and detections without noise within 11 m.
//! let trees: Vec<Vector2<f64>> = (0..12)
//!     .map(|k| {
//!         let a = k as f64 * std::f64::consts::PI / 6.0;
//!         Vector2::new(15.0 * a.cos(), 8.0 + 15.0 * a.sin())
//!     })
//!     .collect();
//! let (speed, steering, dt) = (3.0, 0.3, 0.2);
//! slam.on_control(t0, Control::Ackermann { speed, steering })?; // held until changed
//! let mut truth = Vector3::zeros();
//! for step in 1..=150 {
//!     truth = car.predict(&truth, &[speed, steering, dt])?.0;
//!     let seen: Vec<Detection> = trees
//!         .iter()
//!         .map(|tree| config.sensor.observe(&truth, tree).0)
//!         .filter(|z| z.x < 11.0)
//!         .map(|z| Detection { range_m: z.x, bearing_rad: z.y, diameter_m: Some(0.4) })
//!         .collect();
//!     let report = slam.on_detections(t0 + step as f64 * dt, &seen)?;
//!     assert_eq!(report.decisions.len(), seen.len()); // one decision per detection
//! }
//! let estimate = slam.pose();
//! assert!((estimate.pose[0] - truth.x).hypot(estimate.pose[1] - truth.y) < 0.1);
//! assert_eq!(slam.landmarks().len(), trees.len());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod appearance;
mod config;
mod inputs;
mod landmarks;
mod position;
mod records;
mod table;

/// Why an index the pipeline takes from its own table is in the filter's map: the table
/// and the filter add and remove landmarks together.
const MAPPED: &str = "the pipeline's landmark table and its filter hold the same landmarks";

pub use appearance::{Appearance, AppearanceSetupError};
pub use config::{DiameterCheck, MergeConfig, PipelineConfig};
pub use records::{
    ClusterSegmentation, Landmark, LandmarkMerge, LandmarkRetraction, PoseEstimate, ScanReport, SegmentationRecord,
};

use std::collections::HashSet;

use nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::association::{
    AssociationDecision, AssociationMethod, CHECKED_GATE, Candidate, Choice, chi2_quantile, jcbb::jcbb_with,
    jcbb::unambiguous_jcbb,
};
use crate::classifier::{AppearanceModel, PatchClassifier};
use crate::clustering::{Cluster, ClusteringConfig, cluster};
use crate::ekf::smoother::{History, Relinearisation, SmootherError};
use crate::ekf::{Ekf, EkfError, MotionConfig, MotionModel, RangeBearingModel};
use crate::evidence::{EvidenceConfig, Judgement, ObjectEvidence};
use crate::features::{FeatureError, IN_RECT, ImageRef, PixelRegion};
use crate::gmm::{Gmm, StudentTMixture};
use crate::messages::{Control, Detection, LaserScan, OdometryIncrement};
use crate::object_model::{ObjectModel, ObjectModelConfig, ObjectModelError, ObjectObservation, fit_observation};
use crate::segmentation::{
    CameraGeometry, ImageRegion, SegmentationConfig, SegmentedCluster, locate_cluster, regions_cover, segment_located,
};
use crate::settings::InvalidSetting;
use rayon::prelude::*;
use table::{LandmarkTable, NewLandmark};

/// The latest camera image.
#[derive(Clone)]
struct StoredImage {
    t: f64,
    width: u32,
    height: u32,
    rgb: Vec<u8>,
    /// The pixel regions that hold the scene (`None`: all of the image).
    regions: Option<Vec<PixelRegion>>,
}

/// The online SLAM pipeline. Cloning it forks a run (benchmarks, what-if studies).
#[derive(Clone)]
pub struct Pipeline {
    /// Checked when the pipeline is made, and fixed from then on.
    config: PipelineConfig,
    ekf: Ekf,
    /// Per landmark of the filter: its record, object model (appearance methods) and the
    /// evidence place (odometry frame) of its latest camera observation, where later frames
    /// may judge it not an object.
    table: LandmarkTable,
    /// Made during the current scan, handed over in its [`ScanReport`].
    retractions: Vec<LandmarkRetraction>,
    /// Made during the current scan (indexed while it lasts), handed over in its report.
    decisions: Vec<AssociationDecision>,
    /// The latest pose estimate.
    pose: PoseEstimate,
    t: f64,
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
    /// Pairs of landmark ids (smaller first) seen in one scan: never fused. Pairs of
    /// landmarks gone (expired, retracted, fused) are dropped now and then.
    co_observed: HashSet<(u32, u32)>,
    /// How many pairs `co_observed` kept when it was last pruned.
    co_observed_kept: usize,
    merges: Vec<LandmarkMerge>,
    /// What the filter was told, when loop closures are relinearised.
    history: Option<History>,
    relinearisations: Vec<Result<Relinearisation, SmootherError>>,
    /// When the latest relinearisation was tried.
    relinearised_at: f64,
    /// The latest control and the time it was given: it holds until the next input.
    control: Option<(f64, Control)>,
    /// When the filter's state stopped being finite, or its covariance positive definite,
    /// and which: every later input is refused.
    diverged_at: Option<(f64, Divergence)>,
    /// A squared Mahalanobis distance came out negative in the scan being processed.
    indefinite: bool,
}

/// Errors of the online pipeline.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PipelineError {
    #[error("association method `{0}` needs camera images and an appearance model; give the pipeline an `Appearance`")]
    NeedsAppearance(&'static str),
    #[error("image is {width}x{height} with {found} bytes; RGB needs {expected}")]
    Image { width: u32, height: u32, expected: usize, found: usize },
    /// Images may come after scans of later times (a camera's latency), not before the
    /// image they replace.
    #[error(
        "image at t = {t} s comes before the previous image at t = {previous} s: images must be in time order (they may lag the scans)"
    )]
    ImageTimeReversed { t: f64, previous: f64 },
    /// A diameter below zero (NaN, where allowed, means unknown).
    #[error("{input} at t = {t} s holds a negative diameter")]
    NegativeDiameter { input: &'static str, t: f64 },
    /// A range below zero: no sensor measures one; a landmark would be put behind the
    /// sensor, where no later observation can reach it.
    #[error("{input} at t = {t} s holds a negative range")]
    NegativeRange { input: &'static str, t: f64 },
    /// A start pose or start time that is not finite.
    #[error("the start {0} holds a value that is not finite")]
    StartNotFinite(&'static str),
    /// An image whose size is not the camera's: segmentation would read the wrong pixels.
    #[error("image is {width}x{height}; the camera's geometry is {}x{}", camera.0, camera.1)]
    ImageSize { width: u32, height: u32, camera: (u32, u32) },
    /// A scan whose angles or range limits cannot describe beams.
    #[error("scan at t = {t} s: {problem}")]
    Scan { t: f64, problem: String },
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
    /// An input far outside what the motion and sensor models describe (a speed of 1e300
    /// m/s, finite but absurd) overflowed the filter: nothing estimated after it means
    /// anything, so this input and every later one are refused.
    #[error(
        "the filter's estimate stopped being finite at t = {t} s, or would have (an input far outside what the motion and sensor models describe); nothing after it can be estimated"
    )]
    Diverged { t: f64 },
    /// A squared Mahalanobis distance or a variance came out negative: the covariance is no
    /// longer positive definite (a corrupt odometry row of kilometres broke it while the
    /// state stayed finite), so every later gate, distance and NIS would be meaningless.
    #[error(
        "the filter's covariance stopped being positive definite at t = {t} s (a squared Mahalanobis distance or a variance came out negative after an input far outside what the motion and sensor models describe, such as an odometry step of kilometres); nothing after it can be estimated"
    )]
    Indefinite { t: f64 },
    /// A cluster the segmentation could not judge in an image the pipeline took (`None`:
    /// the image itself): a model or settings the checks let through that the features
    /// refuse. The scan is refused before its evidence is pooled.
    #[error("segmenting {} of the scan at t = {t} s: {source}", .cluster.map_or("the image".to_string(), |c| format!("cluster {c}")))]
    Segmentation { t: f64, cluster: Option<usize>, source: FeatureError },
    /// The filter refused what the pipeline gave it (a control or calibration of another
    /// size than the motion model's), the filter unchanged.
    #[error("the filter at t = {t} s: {source}")]
    Filter { t: f64, source: EkfError },
    /// An object model that could not be fitted to an observation, compared with one, or
    /// updated by one (`landmark`: the mapped object's, where one was involved). Models
    /// and observations the pipeline makes always can be; one that cannot is a model or
    /// setting the checks let through, and skipping it would drop an observation, or
    /// leave a landmark's appearance behind its position, with no word of why. Refused
    /// while fitting or comparing, no observation of the scan has reached the filter;
    /// refused while updating the landmark's model, the filter holds that observation.
    #[error(
        "the object model of cluster {cluster}{} at t = {t} s: {source}",
        .landmark.map_or(String::new(), |l| format!(" against landmark {l}"))
    )]
    ObjectModel { t: f64, cluster: usize, landmark: Option<u32>, source: ObjectModelError },
    /// Two landmarks near enough to be one object whose object models could not be
    /// compared (see [`MergeConfig`]): fusing them anyway, or leaving them apart, would
    /// be a decision no model made. The scan's observations are in the filter.
    #[error("comparing the object models of landmarks {first} and {second} for fusion at t = {t} s: {source}")]
    Fusion { t: f64, first: u32, second: u32, source: ObjectModelError },
}

impl PipelineError {
    /// The input time the message names, where it names one: a caller that prefixes its
    /// own time need not say it twice.
    pub fn time(&self) -> Option<f64> {
        match self {
            PipelineError::ImageTimeReversed { t, .. }
            | PipelineError::NegativeDiameter { t, .. }
            | PipelineError::NegativeRange { t, .. }
            | PipelineError::Scan { t, .. }
            | PipelineError::TimeReversed { t, .. }
            | PipelineError::NonFinite { t, .. }
            | PipelineError::Diverged { t }
            | PipelineError::Indefinite { t }
            | PipelineError::Segmentation { t, .. }
            | PipelineError::Filter { t, .. }
            | PipelineError::ObjectModel { t, .. }
            | PipelineError::Fusion { t, .. } => Some(*t),
            _ => None,
        }
    }
}

/// How the filter broke (see [`PipelineError::Diverged`] and [`PipelineError::Indefinite`]).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Divergence {
    NotFinite,
    Indefinite,
}

impl Divergence {
    fn error(self, t: f64) -> PipelineError {
        match self {
            Divergence::NotFinite => PipelineError::Diverged { t },
            Divergence::Indefinite => PipelineError::Indefinite { t },
        }
    }
}

impl Pipeline {
    /// A pipeline at `pose` (x, y, theta) in the map frame, for any method: the settings
    /// are checked, and the appearance methods need `appearance`.
    pub fn new(config: PipelineConfig, pose: [f64; 3], appearance: Option<Appearance>) -> Result<Self, PipelineError> {
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
        if !pose.iter().all(|v| v.is_finite()) {
            return Err(PipelineError::StartNotFinite("pose"));
        }
        let mut p = Pipeline::unchecked(config, pose);
        p.appearance = appearance;
        Ok(p)
    }

    /// [`Pipeline::new`] without its checks.
    fn unchecked(config: PipelineConfig, pose: [f64; 3]) -> Self {
        let s = config.initial_pose_sigma;
        let mut ekf = Ekf::with_calibration(
            Vector3::from(pose),
            Matrix3::from_diagonal(&Vector3::new(s[0] * s[0], s[1] * s[1], s[2] * s[2])),
            &config.motion.calibration_prior(),
        );
        if config.first_estimate_jacobians && config.observability_constrained {
            ekf.use_observability_constraints();
        } else if config.first_estimate_jacobians {
            ekf.use_first_estimates();
        }
        let evidence = ObjectEvidence::new(config.evidence.clone());
        let history = (config.relinearise_loop_closures && config.method == AssociationMethod::Combined)
            .then(|| History::new(ekf.pose(), ekf.pose_covariance(), &config.motion.calibration_prior()));
        let mut p = Pipeline {
            config,
            ekf,
            table: LandmarkTable::default(),
            retractions: Vec::new(),
            decisions: Vec::new(),
            pose: PoseEstimate { t: 0.0, pose, covariance: [[0.0; 3]; 3] },
            t: 0.0,
            appearance: None,
            image: None,
            segmentations: Vec::new(),
            unrendered_reads: 0,
            evidence,
            odometry_pose: pose,
            co_observed: HashSet::new(),
            co_observed_kept: 0,
            merges: Vec::new(),
            history,
            relinearisations: Vec::new(),
            relinearised_at: 0.0,
            diverged_at: None,
            indefinite: false,
            control: None,
        };
        p.record_pose();
        p
    }

    /// The same pipeline with its clock starting at `t` (a log's first instant), so the
    /// first pose is stamped `t` rather than 0 and earlier inputs are errors.
    pub fn starting_at(mut self, t: f64) -> Result<Self, PipelineError> {
        if !t.is_finite() {
            return Err(PipelineError::StartNotFinite("time"));
        }
        self.t = t;
        self.relinearised_at = t;
        self.record_pose();
        Ok(self)
    }

    /// The time of the latest input.
    pub fn time(&self) -> f64 {
        self.t
    }

    /// Refuses an input stamped before the previous one, and any input once the filter
    /// has diverged.
    fn check_time(&self, input: &'static str, t: f64) -> Result<(), PipelineError> {
        self.check_running(input, t)?;
        if t < self.t {
            return Err(PipelineError::TimeReversed { input, t, previous: self.t });
        }
        Ok(())
    }

    /// Refuses any input once the filter has diverged, and an input whose time is not
    /// finite (what every input is checked for, whatever its order rule).
    fn check_running(&self, input: &'static str, t: f64) -> Result<(), PipelineError> {
        if let Some((at, how)) = self.diverged_at {
            return Err(how.error(at));
        }
        if !t.is_finite() {
            return Err(PipelineError::NonFinite { input, t });
        }
        Ok(())
    }

    /// Refuses to go on once the filter's state is no longer finite or its covariance no
    /// longer positive definite (see [`PipelineError::Diverged`] and
    /// [`PipelineError::Indefinite`]); `t` is the input that made it so.
    fn check_state(&mut self, t: f64) -> Result<(), PipelineError> {
        if self.diverged_at.is_none() {
            if !self.ekf.is_finite() {
                self.diverged_at = Some((t, Divergence::NotFinite));
            } else if self.indefinite || self.ekf.has_negative_variance() {
                self.diverged_at = Some((t, Divergence::Indefinite));
            }
        }
        match self.diverged_at {
            Some((at, how)) => Err(how.error(at)),
            None => Ok(()),
        }
    }

    /// Notes a squared Mahalanobis distance that is negative (see
    /// [`PipelineError::Indefinite`]); infinities (a landmark ruled out) are fine.
    fn note_distance(&mut self, d2: f64) {
        self.indefinite |= d2 < 0.0;
    }

    /// The report of the scan at `t`: its observations and what it did, handed over.
    /// What every scan ends with, whichever association ran: the co-observation counts,
    /// the landmarks' records, the history's estimate, the pose log, and the report.
    fn finish_scan(
        &mut self,
        t: f64,
        clusters: Vec<Cluster>,
        assigned: Vec<Option<u32>>,
    ) -> Result<ScanReport, PipelineError> {
        self.note_co_observed(&assigned);
        self.refresh_landmarks()?;
        if let Some(h) = &mut self.history {
            h.set_estimate(self.ekf.pose());
        }
        self.record_pose();
        Ok(self.report(t, clusters, assigned))
    }

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
        self.table.object(self.table.index_of(id)?)
    }

    pub fn appearance(&self) -> Option<&Appearance> {
        self.appearance.as_ref()
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
        self.table.meta()
    }

    /// The map: confirmed landmarks only.
    pub fn mapped_landmarks(&self) -> Vec<Landmark> {
        self.table.meta().iter().filter(|l| l.confirmed).cloned().collect()
    }

    /// The settings it runs with.
    pub fn config(&self) -> &PipelineConfig {
        &self.config
    }

    pub fn ekf(&self) -> &Ekf {
        &self.ekf
    }
}
