//! What the pipeline reports: landmarks, poses, and what each scan did.

use super::*;

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
    /// Of the band's patches counted in `above_fraction`, those that were foliage on top of
    /// the trunk (see [`crate::segmentation::SegmentationConfig::band_counts_foliage`]).
    #[serde(default)]
    pub band_foliage_patches: usize,
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
