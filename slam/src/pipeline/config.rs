//! The pipeline's settings: every knob, its default and its range.

use super::*;

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
    /// With `joint_loop_closing`: a joint closure is refused (the observations wait for the
    /// next scans) where, with the pose it corrects, a confirmed landmark it leaves unpaired
    /// lies in plain view, within the clustering range, where the scan's beams reach past
    /// it. In a park planted in rows, a constellation shifted by one tree spacing fits as
    /// well as the true one and pairs more observations; what the laser does not see tells
    /// them apart. Off by default until measured on every scenario; docs/results.md.
    pub joint_loop_free_space: bool,
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
    /// With `first_estimate_jacobians`: observation Jacobians at the latest estimates,
    /// constrained to keep the first estimates' unobservable directions unobservable (see
    /// [`crate::ekf::FirstEstimates::observability_constrained`]). First estimates alone
    /// linearise about a landmark's first position, wrong by up to metres for one first
    /// seen far off while the heading was unsure; measured in docs/results.md, on by
    /// default. With `first_estimate_jacobians = false` the Jacobians are the latest
    /// estimates' and this has nothing to constrain, so that setting alone turns both off
    /// (an error there would break every file written before this setting existed).
    pub observability_constrained: bool,
    /// Combined method: a candidate landmark whose trunk diameter (the mean of its laser
    /// clusters' circle fits) disagrees with the observation's is not that object.
    pub diameter: DiameterCheck,
    /// Fusing landmarks that turn out to be one object (duplicates made while the pose was
    /// too uncertain to associate, found once a loop closure shrinks the uncertainty).
    pub merge: MergeConfig,
    /// Combined method: after a scan that closes a loop jointly, the filter is relinearised
    /// by solving its whole history again (see [`crate::ekf::smoother`]), so landmarks
    /// not seen since before the loop move to where the closure says they are. The history
    /// keeps every pose, control and observation of the run, so its memory and each
    /// solve's cost grow with the run's length, unlike the rest of the pipeline's: for a
    /// log of hours, turn it off.
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

impl MergeConfig {
    /// The first setting that makes no sense, as (field, problem).
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        for (name, v) in [("max_sigma_m", self.max_sigma_m), ("noise_sigma_m", self.noise_sigma_m)] {
            if !(v.is_finite() && v > 0.0) {
                return Err((name, format!("must be finite and positive, got {v}")));
            }
        }
        Ok(())
    }
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
            joint_loop_free_space: false,
            defer_near_lookalike: true,
            diameter: DiameterCheck::default(),
            first_estimate_jacobians: true,
            observability_constrained: true,
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
        if let Some((i, s)) = self.initial_pose_sigma.iter().enumerate().find(|(_, s)| **s > crate::settings::MAX_SIGMA)
        {
            return Err(InvalidSetting::new(
                format!("initial_pose_sigma[{i}]"),
                format!("must be at most {:e}, got {s}", crate::settings::MAX_SIGMA),
            ));
        }
        if !(self.image_max_age_s.is_finite() && self.image_max_age_s >= 0.0) {
            return Err(InvalidSetting::new(
                "image_max_age_s",
                format!("must be zero or a positive number of seconds, got {}", self.image_max_age_s),
            ));
        }
        if !(1..=crate::settings::MAX_COUNT).contains(&self.confirm_observations) {
            return Err(InvalidSetting::new(
                "confirm_observations",
                format!(
                    "must be 1 to {} (1 confirms a landmark at its first observation), got {}",
                    crate::settings::MAX_COUNT,
                    self.confirm_observations
                ),
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
        if self.joint_loop_free_space && !self.joint_loop_closing {
            return Err(InvalidSetting::new("joint_loop_free_space", "only applies with joint_loop_closing = true"));
        }
        Ok(())
    }
}
