//! What a run measured (`metrics.json`), the scenario's pass criteria checked against it,
//! and its summary for the terminal.

use serde::{Deserialize, Serialize};

use crate::score::scorer::RecallBasis;
use crate::score::{AssociationCounts, MapContent};

/// Segmentation quality against the rendered masks (absent without a camera).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SegmentationScore {
    pub precision: Option<f64>,
    pub recall: Option<f64>,
}

impl SegmentationScore {
    /// The scores of a camera method's patches: each null where undefined (no patch called
    /// tree, or none was tree), as in a run too short to classify any, not a perfect 1.
    pub fn of(patches: &slam::classifier::PatchScores) -> Self {
        SegmentationScore { precision: patches.defined_precision(), recall: patches.defined_recall() }
    }
}

/// Everything `metrics.json` holds. Field meanings: docs/guide/runs-and-metrics.md.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    pub scenario: String,
    pub seed: u64,
    pub method: String,
    pub sim_seconds: f64,
    pub wall_seconds: f64,
    #[serde(with = "crate::score::nan_as_null")]
    pub realtime_factor: f64,
    #[serde(with = "crate::score::nan_as_null")]
    pub ate_rmse_m: f64,
    /// Translational relative pose error over 1 s (`score::scorer::rpe_rmse`); null when
    /// the run is shorter, and in records written before it was measured.
    #[serde(default = "crate::score::nan", with = "crate::score::nan_as_null")]
    pub rpe_rmse_m: f64,
    pub landmark_rmse_m: Option<f64>,
    pub map: MapContent,
    pub landmarks: usize,
    pub associations: AssociationCounts,
    pub duplicate_landmarks: usize,
    /// Pairs of landmarks the pipeline fused into one (see `pipeline.merge`).
    #[serde(default)]
    pub merged_landmarks: usize,
    /// Times the filter was relinearised after a loop closure (see
    /// `pipeline.relinearise_loop_closures`).
    #[serde(default)]
    pub relinearisations: usize,
    /// Relinearisations that failed and left the filter as it was.
    #[serde(default)]
    pub relinearisation_failures: usize,
    /// Landmarks taken off the map when nearer frames judged their place not an object
    /// (see `pipeline.evidence.retract`), and how many of them were on trees (those
    /// retractions were mistakes).
    #[serde(default)]
    pub retracted_landmarks: RetractionCounts,
    /// Landmarks on posts, palms, people, walls or nothing.
    pub false_landmarks: usize,
    pub segmentation: SegmentationScore,
    /// The extrinsics the pipeline was given, against the simulator's (absent in runs
    /// recorded before calibration was scored).
    #[serde(default)]
    pub calibration: Option<CalibrationScore>,
    /// The odometry calibration the filter estimated, against the simulator's (absent when
    /// the filter does not estimate it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub odometry_calibration: Option<OdometryCalibrationScore>,
    /// Average NEES of the robot pose over the run (3 dof: consistent near 3).
    #[serde(with = "crate::score::nan_as_null")]
    pub anees: f64,
    pub collisions: usize,
    pub route_completed: bool,
    pub passed: bool,
    /// Which pass criteria failed, in words.
    pub failures: Vec<String>,
    /// Where the wall-clock time went.
    #[serde(default)]
    pub timing: Timing,
    /// The graphics adapter that rendered the camera's images (absent without a camera):
    /// renderers differ in their last bits, and so can results (docs/results.md, "On a GPU").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub renderer: Option<String>,
    /// The appearance model the camera methods classified with (absent otherwise): a
    /// model's training draws its borderline, so results depend on it too.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub appearance_model: Option<ModelProvenance>,
}

/// Where an appearance model came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelProvenance {
    pub training_seed: u64,
    pub training_images: usize,
    /// The graphics adapter that rendered its training images (absent for models trained
    /// before that was recorded).
    pub training_renderer: Option<String>,
    /// The first 16 hex digits of the SHA-256 of the model's JSON: which model it was, even
    /// between two trained alike by different builds (absent in older metrics).
    #[serde(default)]
    pub digest: Option<String>,
}

impl ModelProvenance {
    /// The provenance of `model`.
    pub fn of(model: &slam::classifier::AppearanceModel) -> ModelProvenance {
        use sha2::{Digest, Sha256};
        let json = serde_json::to_string(model).expect("a model serialises");
        let digest = Sha256::digest(json.as_bytes());
        ModelProvenance {
            training_seed: model.training.seed,
            training_images: model.training.images,
            training_renderer: model.training.renderer.clone(),
            digest: Some(digest.iter().take(8).map(|b| format!("{b:02x}")).collect()),
        }
    }
}

impl Metrics {
    /// The metrics with every wall-clock figure zeroed: what must be identical between two
    /// runs of the same scenario and seed.
    pub fn without_wall_clock(&self) -> Metrics {
        Metrics {
            wall_seconds: 0.0,
            realtime_factor: 0.0,
            timing: Timing { simulator_s: 0.0, pipeline_s: 0.0, mean_scan_ms: 0.0, ..self.timing.clone() },
            ..self.clone()
        }
    }
}

/// The odometry's systematic errors, each as (distance scale, turn scale, heading bias in
/// rad per metre): the filter's final estimate, its standard deviation, and the truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OdometryCalibrationScore {
    pub estimated: [f64; 3],
    pub sigma: [f64; 3],
    pub truth: [f64; 3],
}

/// How far the run's laser <- camera extrinsics are from the simulator's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationScore {
    pub mode: String,
    pub rotation_error_deg: f64,
    pub translation_error_m: f64,
}

/// Wall-clock split of a run: the simulator (physics, laser, rendering) against the online
/// pipeline (clustering, segmentation, object models, association, EKF).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Timing {
    pub simulator_s: f64,
    pub pipeline_s: f64,
    pub scans: usize,
    /// Mean pipeline time per scan (with its image, for the camera methods), ms.
    pub mean_scan_ms: f64,
    /// Fraction of the camera frames' pixels rendered: below 1 when only the columns the
    /// pipeline reads are (the default for camera methods), 0 without a camera (and in
    /// records written before it was measured).
    #[serde(default)]
    pub rendered_fraction: f64,
}

/// Retracted landmarks (see [`Metrics::retracted_landmarks`]).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct RetractionCounts {
    pub total: usize,
    pub trees: usize,
}

pub(super) fn odometry_calibration_score(ekf: &slam::ekf::Ekf, truth: [f64; 3]) -> Option<OdometryCalibrationScore> {
    let (estimated, sigma) = (ekf.calibration(), ekf.calibration_sigma());
    (estimated.len() == 3).then(|| OdometryCalibrationScore {
        estimated: [estimated[0], estimated[1], estimated[2]],
        sigma: [sigma[0], sigma[1], sigma[2]],
        truth,
    })
}

/// Checks the scenario's pass criteria; returns the failures in words.
/// The figures the pass criteria judge: a run's ([`Metrics::pass_figures`]) or those
/// `objslam score` can score.
pub struct PassFigures<'a> {
    pub wrong_associations: usize,
    pub false_landmarks: usize,
    pub duplicate_landmarks: usize,
    pub map: &'a MapContent,
    /// The trees `map`'s recall counts, for its words.
    pub recall_basis: RecallBasis,
    pub ate_rmse_m: f64,
    pub landmark_rmse_m: Option<f64>,
    pub collisions: usize,
    /// Absent: no calibration criterion can be judged.
    pub calibration: Option<&'a CalibrationScore>,
    pub route_completed: bool,
}

impl Metrics {
    /// The trees the run's recall counts: its method's basis, which a camera run of a
    /// position-only method does not share with the camera; for a method this build does
    /// not know, trees in view where they were counted.
    pub fn recall_basis(&self) -> RecallBasis {
        match slam::association::AssociationMethod::from_name(&self.method) {
            Some(method) => RecallBasis::of_method(method),
            None if self.map.trees_in_view.is_some() => RecallBasis::InView,
            None => RecallBasis::LaserSeen,
        }
    }

    /// What the pass criteria judge of this run.
    pub fn pass_figures(&self) -> PassFigures<'_> {
        PassFigures {
            wrong_associations: self.associations.wrong,
            false_landmarks: self.false_landmarks,
            duplicate_landmarks: self.duplicate_landmarks,
            map: &self.map,
            recall_basis: self.recall_basis(),
            ate_rmse_m: self.ate_rmse_m,
            landmark_rmse_m: self.landmark_rmse_m,
            collisions: self.collisions,
            calibration: self.calibration.as_ref(),
            route_completed: self.route_completed,
        }
    }
}

pub fn check_pass(p: &crate::scenario::PassCriteria, m: &PassFigures) -> Vec<String> {
    let mut f = Vec::new();
    if let Some(max) = p.max_wrong_associations
        && m.wrong_associations > max
    {
        f.push(format!("{} wrong associations (max {max})", m.wrong_associations));
    }
    if let Some(max) = p.max_false_landmarks
        && m.false_landmarks > max
    {
        f.push(format!("{} false landmarks (max {max})", m.false_landmarks));
    }
    if let Some(min) = p.min_false_landmarks
        && m.false_landmarks < min
    {
        f.push(format!("{} false landmarks (expected at least {min})", m.false_landmarks));
    }
    if let Some(max) = p.max_duplicate_landmarks
        && m.duplicate_landmarks > max
    {
        f.push(format!("{} duplicate landmarks (max {max})", m.duplicate_landmarks));
    }
    if let Some(min) = p.min_tree_recall {
        match m.map.tree_recall {
            Some(recall) if recall >= min => {}
            Some(recall) => {
                f.push(format!("tree recall {recall:.2} ({}; min {min})", m.map.recall_in_words(m.recall_basis)))
            }
            None => f.push(format!("tree recall undefined: {} (min {min})", m.map.recall_in_words(m.recall_basis))),
        }
    }
    if let Some(max) = p.max_ate_rmse_m
        && !(m.ate_rmse_m <= max)
    {
        f.push(format!("ATE RMSE {:.3} m (max {max})", m.ate_rmse_m));
    }
    // Like the recall, an RMSE over no landmark is undefined, and fails its bound.
    if let Some(max) = p.max_landmark_rmse_m {
        match m.landmark_rmse_m {
            Some(r) if r <= max => {}
            Some(r) => f.push(format!("landmark RMSE {r:.3} m (max {max})")),
            None => f.push(format!(
                "landmark RMSE undefined: no mapped landmark within 2 m of a tree, post or palm (max {max})"
            )),
        }
    }
    if let Some(max) = p.max_collisions
        && m.collisions > max
    {
        f.push(format!("{} collisions (max {max})", m.collisions));
    }
    if let Some(c) = m.calibration {
        if let Some(max) = p.max_calibration_rotation_error_deg
            && (c.rotation_error_deg.is_nan() || c.rotation_error_deg > max)
        {
            f.push(format!("calibration rotation error {:.3} deg (max {max})", c.rotation_error_deg));
        }
        if let Some(max) = p.max_calibration_translation_error_m
            && (c.translation_error_m.is_nan() || c.translation_error_m > max)
        {
            f.push(format!("calibration translation error {:.4} m (max {max})", c.translation_error_m));
        }
    }
    if !m.route_completed {
        f.push("the robot did not complete its route".into());
    }
    f
}

/// A figure with no bound (an ANEES from a covariance near singular can be 1e300) with
/// `decimals` places, in scientific form from a million on so that it stays one word.
pub fn unbounded_figure(v: f64, decimals: usize) -> String {
    if v.abs() < 1e6 { format!("{v:.decimals$}") } else { format!("{v:.3e}") }
}

/// `map.missed_by_stage` for people: "never segmented: tree 12; never fully judged: trees
/// 9 14", in the pipeline's order.
pub fn missed_in_words(by_stage: &std::collections::BTreeMap<String, Vec<u16>>) -> String {
    crate::score::segmentation::MissedStage::ALL
        .iter()
        .filter_map(|stage| {
            let ids = by_stage.get(stage.key())?;
            let names: Vec<String> = ids.iter().map(|id| id.to_string()).collect();
            let trees = if ids.len() == 1 { "tree" } else { "trees" };
            Some(format!("{}: {trees} {}", stage.in_words(), names.join(" ")))
        })
        .collect::<Vec<_>>()
        .join("; ")
}

/// Short summary table for the terminal.
pub fn summary_table(m: &Metrics) -> String {
    let mut s = String::new();
    s.push_str(&format!("scenario {}  method {}  seed {}\n", m.scenario, m.method, m.seed));
    s.push_str(&format!(
        "  simulated {:.1} s in {:.2} s ({:.0}x real time; simulator {:.1} s, pipeline {:.1} s, {:.2} ms per scan)\n",
        m.sim_seconds,
        m.wall_seconds,
        m.realtime_factor,
        m.timing.simulator_s,
        m.timing.pipeline_s,
        m.timing.mean_scan_ms
    ));
    if let Some(renderer) = &m.renderer {
        s.push_str(&format!("  rendered by       {renderer}\n"));
    }
    let recall = m.map.tree_recall.map_or("undefined".to_string(), |r| format!("{:.0}%", 100.0 * r));
    s.push_str(&format!("  tree recall       {recall:>4} ({})\n", m.map.recall_in_words(m.recall_basis())));
    if let Some(judged) = m.map.trees_judged {
        s.push_str(&format!("  trees judged      {judged:>4} (by the method's own segmentation, in enough frames)\n"));
    }
    if let Some(by_stage) = m.map.missed_by_stage.as_ref().filter(|b| !b.is_empty()) {
        s.push_str(&format!("  trees missed      {:>4} ({})\n", m.map.missed_trees.len(), missed_in_words(by_stage)));
    }
    s.push_str(&format!("  false landmarks   {:>4} (posts {}, palms {}, people {}, walls {}, nothing {}; {} retracted, {} of them trees)\n", m.false_landmarks, m.map.posts, m.map.palms, m.map.people, m.map.walls, m.map.nothing, m.retracted_landmarks.total, m.retracted_landmarks.trees));
    s.push_str(&format!("  duplicates        {:>4} ({} fused)\n", m.duplicate_landmarks, m.merged_landmarks));
    if m.relinearisations + m.relinearisation_failures > 0 {
        s.push_str(&format!(
            "  relinearised      {:>4} times after loop closures ({} failed)\n",
            m.relinearisations, m.relinearisation_failures
        ));
    }
    s.push_str(&format!("  associations      {:>4} ({} wrong)\n", m.associations.total, m.associations.wrong));
    s.push_str(&format!("  ATE RMSE          {:>8.3} m\n", m.ate_rmse_m));
    if m.rpe_rmse_m.is_finite() {
        s.push_str(&format!(
            "  RPE RMSE          {:>8.3} m over {:.0} s\n",
            m.rpe_rmse_m,
            crate::score::scorer::RPE_DELTA_S
        ));
    } else {
        // As metrics.json's null says, and as `objslam score` prints it.
        s.push_str(&format!(
            "  RPE RMSE          undefined (no poses {:.0} s apart)\n",
            crate::score::scorer::RPE_DELTA_S
        ));
    }
    if let Some(r) = m.landmark_rmse_m {
        s.push_str(&format!("  landmark RMSE     {r:>8.3} m\n"));
    }
    s.push_str(&format!("  ANEES             {:>8}\n", unbounded_figure(m.anees, 2)));
    if let Some(c) = m.calibration.as_ref().filter(|c| c.mode != "true") {
        s.push_str(&format!(
            "  calibration       {} extrinsics off by {:.3} deg, {:.4} m\n",
            c.mode, c.rotation_error_deg, c.translation_error_m
        ));
    }
    if let Some(c) = &m.odometry_calibration {
        s.push_str(&format!(
            "  odometry errors   scale {:+.4} ({:+.4}), turn scale {:+.4} ({:+.4}), bias {:+.5} ({:+.5}) rad/m: estimate (truth)\n",
            c.estimated[0], c.truth[0], c.estimated[1], c.truth[1], c.estimated[2], c.truth[2]
        ));
    }
    s.push_str(&format!("  collisions        {:>4}\n", m.collisions));
    s.push_str(&format!(
        "  {}\n",
        if m.passed { "PASSED".to_string() } else { format!("FAILED: {}", m.failures.join("; ")) }
    ));
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unbounded_figure_stays_one_short_word() {
        assert_eq!(unbounded_figure(1.23456, 2), "1.23");
        assert_eq!(unbounded_figure(-2.5e300, 2), "-2.500e300");
        assert_eq!(unbounded_figure(999_999.0, 1), "999999.0");
        assert_eq!(unbounded_figure(f64::NAN, 2), "NaN");
    }

    /// Regression: the run's summary printed "NaN m" for an RPE that metrics.json writes as
    /// null; `objslam score` says "undefined".
    #[test]
    fn an_undefined_rpe_is_summarised_as_undefined() {
        let mut m: Metrics = serde_json::from_str(include_str!("../../tests/data/metrics_sample.json")).unwrap();
        assert!(summary_table(&m).contains("RPE RMSE             0.037 m over 1 s"), "{}", summary_table(&m));
        m.rpe_rmse_m = f64::NAN;
        let s = summary_table(&m);
        assert!(
            s.contains("RPE RMSE          undefined (no poses 1 s apart)") && !s.contains("RPE RMSE          NaN"),
            "{s}"
        );
    }

    /// Regression: a camera run that classified no patch (0.5 s) wrote precision and recall 1.
    #[test]
    fn segmentation_over_no_patch_is_null_in_metrics_json() {
        let json = |p: slam::classifier::PatchScores| serde_json::to_value(SegmentationScore::of(&p)).unwrap();
        assert_eq!(json(Default::default()), serde_json::json!({"precision": null, "recall": null}));
        let some = slam::classifier::PatchScores { true_positives: 3, false_positives: 1, ..Default::default() };
        assert_eq!(json(some), serde_json::json!({"precision": 0.75, "recall": 1.0}));
    }

    /// A position-only method's recall counts the trees the laser saw, camera or not.
    #[test]
    fn a_position_only_run_with_a_camera_words_its_recall_on_the_trees_the_laser_saw() {
        let mut m: Metrics = serde_json::from_str(include_str!("../../tests/data/metrics_sample.json")).unwrap();
        let pass = crate::scenario::PassCriteria { min_tree_recall: Some(1.0), ..Default::default() };
        let recall_failure =
            |m: &Metrics| check_pass(&pass, &m.pass_figures()).into_iter().find(|f| f.contains("recall"));
        assert!(recall_failure(&m).is_some_and(|f| f.contains("89 of 117 trees in view mapped")));
        m.method = "jcbb".into();
        m.map.missed_trees = vec![1, 2, 3];
        assert!(recall_failure(&m).is_some_and(|f| f.contains("117 of 120 trees seen by the laser mapped")));
        assert!(summary_table(&m).contains("117 of 120 trees seen by the laser mapped"));
    }

    /// An RMSE over no landmark is undefined and fails its bound, as a recall over no tree
    /// does.
    #[test]
    fn undefined_landmark_rmse_fails_its_bound() {
        let mut m: Metrics = serde_json::from_str(include_str!("../../tests/data/metrics_sample.json")).unwrap();
        let pass = crate::scenario::PassCriteria { max_landmark_rmse_m: Some(0.2), ..Default::default() };
        m.landmark_rmse_m = Some(0.1);
        assert!(check_pass(&pass, &m.pass_figures()).iter().all(|f| !f.contains("landmark RMSE")));
        m.landmark_rmse_m = Some(0.3);
        assert!(check_pass(&pass, &m.pass_figures()).iter().any(|f| f.contains("landmark RMSE 0.300 m")));
        m.landmark_rmse_m = None;
        assert!(check_pass(&pass, &m.pass_figures()).iter().any(|f| f.contains("landmark RMSE undefined")));
    }
}
