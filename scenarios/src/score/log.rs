//! `objslam score`: scores any SLAM system's output against a sensor log, with the rules
//! `objslam run` applies to its own pipeline ([`RunScorer`]). The log is one that
//! `objslam record` wrote, or an `objslam run` output directory, which holds the same log
//! without its camera images (their part of the truth is in `trees_shown.jsonl`).
//!
//! What the system under test gives (a trajectory, and optionally its pose covariances,
//! map and associations) is read by [`super::estimate`]. Figures that only the system's
//! insides carry (segmentation scores, relinearisations, calibration) are not scored.
//! Docs: docs/guide/scoring.md.

use crate::files;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

pub use super::estimate::read_tum;
use super::estimate::{
    Observations, ScanAssociations, beams_outside, check_map_is_associated, read_associations, read_covariances,
    read_landmarks, scan_observations,
};
use super::scorer::{Fusion, RecallBasis, RunScorer, ScoredObservation, VisibilitySettings};
use super::{AssociationCounts, MapContent};
use crate::scenario::PassCriteria;
use crate::visibility::InstanceImage;

/// Errors of `objslam score`: each names the file, and the line where there is one.
#[derive(Debug, thiserror::Error)]
pub enum ScoreError {
    /// The I/O error is in the message, not a `source()`: printed as a chain it would repeat.
    #[error("{}: {error}", file.display())]
    Io { file: PathBuf, error: std::io::Error },
    #[error("{}{}: {message}", file.display(), line.map(|l| format!(":{l}")).unwrap_or_default())]
    Invalid { file: PathBuf, line: Option<usize>, message: String },
    #[error(transparent)]
    World(#[from] worlds::WorldError),
}

pub(super) fn invalid(file: &Path, line: Option<usize>, message: impl Into<String>) -> ScoreError {
    ScoreError::Invalid { file: file.to_path_buf(), line, message: message.into() }
}

/// How a log is to be scored, as `objslam record` writes it into `metadata.json`: the
/// scenario it was recorded from, what makes a tree count as seen, and the pass criteria.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LogScoring {
    pub scenario: Option<String>,
    /// The scenario's run seed the log was simulated for (its simulator seed derives from
    /// it, as in `objslam run`).
    pub run_seed: Option<u64>,
    pub visibility: VisibilitySettings,
    pub pass: Option<PassCriteria>,
    /// How the log's `observations.jsonl` clusters each scan (logs written before it was
    /// recorded have the default).
    #[serde(default)]
    pub clustering: slam::clustering::ClusteringConfig,
}

impl LogScoring {
    /// A scenario's: its pipeline's clustering and confirmation, and its criteria.
    pub fn of_scenario(scenario: &crate::scenario::Scenario, run_seed: u64) -> Self {
        Self::of_run(scenario, run_seed, &scenario.pipeline)
    }

    /// A plain world's: the default pipeline's settings, no criteria.
    pub fn of_world() -> Self {
        let pipeline = slam::pipeline::PipelineConfig::default();
        LogScoring {
            scenario: None,
            run_seed: None,
            visibility: VisibilitySettings::of(&pipeline),
            pass: None,
            clustering: pipeline.clustering,
        }
    }

    /// A run's: the scenario as run, with the pipeline configuration the run used.
    pub fn of_run(
        scenario: &crate::scenario::Scenario,
        run_seed: u64,
        pipeline: &slam::pipeline::PipelineConfig,
    ) -> Self {
        LogScoring {
            scenario: Some(scenario.name.clone()),
            run_seed: Some(run_seed),
            visibility: VisibilitySettings::of(pipeline),
            pass: Some(scenario.pass.clone()),
            clustering: pipeline.clustering,
        }
    }
}

/// The system's outputs to score.
#[derive(Debug, Clone, Default)]
pub struct Estimate {
    pub trajectory: PathBuf,
    /// The pose covariance at the trajectory's times (CSV), for ANEES. Scoring a run's own
    /// trajectory reads the run's `trajectory_est_covariance.csv` without it.
    pub covariances: Option<PathBuf>,
    pub landmarks: Option<PathBuf>,
    pub associations: Option<PathBuf>,
    /// A name for the system in the report (default `external`).
    pub method: Option<String>,
    /// The recall's denominator (default: trees in view when the log has camera frames).
    pub recall_basis: Option<RecallBasis>,
}

/// What `objslam score` writes to `metrics.json`: the keys of `objslam run`'s metrics that
/// ground truth can score from these inputs, with the same meanings. Keys whose input was
/// not given are null.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScoredMetrics {
    pub scenario: Option<String>,
    pub seed: u64,
    pub method: String,
    pub sim_seconds: f64,
    #[serde(with = "super::nan_as_null")]
    pub ate_rmse_m: f64,
    #[serde(with = "super::nan_as_null")]
    pub rpe_rmse_m: f64,
    /// Average NEES of the pose over the poses given a covariance (null without any).
    #[serde(with = "super::nan_as_null")]
    pub anees: f64,
    pub landmark_rmse_m: Option<f64>,
    pub map: Option<MapContent>,
    pub landmarks: Option<usize>,
    pub associations: Option<AssociationCounts>,
    pub duplicate_landmarks: Option<usize>,
    pub merged_landmarks: Option<usize>,
    pub false_landmarks: Option<usize>,
    pub collisions: usize,
    pub route_completed: bool,
    /// Whether the scenario's criteria hold (null: not all of them could be checked).
    pub passed: Option<bool>,
    pub failures: Vec<String>,
    /// Criteria that these inputs cannot check, in words.
    pub unchecked: Vec<String>,
    /// Poses of the trajectory scored (each against the truth at its time).
    pub poses_scored: usize,
    /// The share of the log's true poses with a pose of the trajectory within
    /// [`COVERAGE_WINDOW_S`]: a trajectory of a few poses scores a small ATE over little.
    pub trajectory_coverage: f64,
    /// What the user should know about these figures (a trajectory off the plane, one
    /// that covers little of the log).
    pub warnings: Vec<String>,
    pub recall_basis: RecallBasis,
}

/// How near in time a pose of the trajectory must be to a true pose to cover it.
pub const COVERAGE_WINDOW_S: f64 = 1.0;

/// The least coverage of the log by the trajectory with which a scenario's criteria can
/// pass: an estimate of part of the route is not one of the route.
pub const MIN_PASS_COVERAGE: f64 = 0.9;

/// Height and tilt above which the trajectory is said to leave the plane (the scoring is
/// planar: x, y and heading).
const OFF_PLANE_Z_M: f64 = 0.1;
const OFF_PLANE_TILT_DEG: f64 = 5.0;

/// How a trajectory was scored: its poses, its coverage of the log, and what of it the
/// plane leaves out.
struct PoseScore {
    poses: usize,
    coverage: f64,
    off_plane: super::estimate::OffPlane,
    /// The RPE's pose pairs, and how many of them span a gap (see `rpe_pairs_over_gaps`).
    rpe_pairs: (usize, usize),
    /// Poses given a covariance, and of those the ones positive definite (the ANEES's).
    covariances: (usize, usize),
}

/// The share of `truth`'s times with one of `times` (increasing) within the window.
fn coverage(truth: &[(f64, [f64; 3])], times: &[f64]) -> f64 {
    let covered = truth
        .iter()
        .filter(|(t, _)| {
            let k = times.partition_point(|s| s < t);
            [k.checked_sub(1), Some(k)]
                .into_iter()
                .flatten()
                .filter_map(|k| times.get(k))
                .any(|s| (s - t).abs() <= COVERAGE_WINDOW_S)
        })
        .count();
    covered as f64 / truth.len().max(1) as f64
}

/// The parts of a log's `metadata.json` that scoring reads.
struct LogMetadata {
    seed: u64,
    sim: sim::SimConfig,
    route_completed: bool,
    sim_seconds: f64,
    scoring: LogScoring,
    /// For the output directory of `objslam run`: the method it ran.
    run_method: Option<String>,
    /// For a log of `objslam record`: the camera frames it wrote (absent in logs from
    /// before the summary said).
    camera_frames: Option<usize>,
}

pub(super) fn read_text(file: &Path) -> Result<String, ScoreError> {
    std::fs::read_to_string(file).map_err(|error| ScoreError::Io { file: file.to_path_buf(), error })
}

fn field<T: serde::de::DeserializeOwned>(file: &Path, v: &serde_json::Value, path: &str) -> Result<T, ScoreError> {
    let mut at = v;
    for key in path.split('.') {
        at = at.get(key).ok_or_else(|| invalid(file, None, format!("no field `{path}`")))?;
    }
    serde_json::from_value(at.clone()).map_err(|e| invalid(file, None, format!("field `{path}`: {e}")))
}

fn read_metadata(log: &Path) -> Result<LogMetadata, ScoreError> {
    if !log.is_dir() {
        let what = if log.exists() { "not a directory" } else { "no such directory" };
        return Err(invalid(
            log,
            None,
            format!("{what}: `--log` takes the directory of a JSON-lines log of `objslam record` or of a run"),
        ));
    }
    let file = log.join(files::METADATA);
    if !file.exists() {
        // Other outputs of objslam that hold a log, named so the user knows what to use.
        let other = if log.join(robotlog::format::MANIFEST).exists() {
            Some(format!(
                "a robot log ({}); `objslam replay` estimates on it and scores against its reference",
                robotlog::format::MANIFEST
            ))
        } else if log.join("metadata.yaml").exists() {
            Some("a ROS 2 bag (metadata.yaml); record the JSON-lines log beside it (`objslam record`, the default format) to score a system".into())
        } else if crate::partial_files::unfinished_dir(log).exists() {
            Some(format!(
                "no finished run or recording: its metadata.json, moved in last, is missing, and {} holds what an objslam command stopped before finishing",
                crate::partial_files::unfinished_dir(log).display()
            ))
        } else {
            None
        };
        if let Some(other) = other {
            return Err(invalid(
                log,
                None,
                format!(
                    "{other}. `--log` takes a JSON-lines log of `objslam record` or a run's directory, with their metadata.json"
                ),
            ));
        }
    }
    let v: serde_json::Value =
        serde_json::from_str(&read_text(&file)?).map_err(|e| invalid(&file, Some(e.line()), e.to_string()))?;
    let tool: String = field(&file, &v, "tool")?;
    let (scoring, run_method) = match tool.as_str() {
        // Logs recorded before scoring settings were written: those of a plain world.
        "objslam record" => match v.get("scoring") {
            Some(_) => (field(&file, &v, "scoring")?, None),
            None => (LogScoring::of_world(), None),
        },
        "objslam run" if v.get("scoring").is_none() => {
            return Err(invalid(
                &file,
                None,
                "a run's output from before runs wrote their log: run it again to score it",
            ));
        }
        "objslam run" => (field(&file, &v, "scoring")?, Some(field(&file, &v, "summary.method")?)),
        other => {
            return Err(invalid(&file, None, format!("written by `{other}`, not `objslam record` or `objslam run`")));
        }
    };
    Ok(LogMetadata {
        seed: field(&file, &v, "seed")?,
        sim: field(&file, &v, "sim_config")?,
        route_completed: field(&file, &v, "summary.route_completed")?,
        sim_seconds: field(&file, &v, "summary.sim_seconds")?,
        scoring,
        run_method,
        camera_frames: v.pointer("/summary/camera_frames").and_then(|n| n.as_u64()).map(|n| n as usize),
    })
}

/// The true pose at `t`: the recorded one at that time, else linear between its
/// neighbours; `None` outside the recording (by more than a microsecond).
fn truth_at(truth: &[(f64, [f64; 3])], t: f64) -> Option<[f64; 3]> {
    // Within a microsecond of either end (times summed in steps of 0.05 s end at
    // 258.9000000000246) is at that end, as covariances and associations are matched.
    let (first, last) = (truth.first()?, truth.last()?);
    if t < first.0 && first.0 - t <= 1e-6 {
        return Some(first.1);
    }
    if t > last.0 && t - last.0 <= 1e-6 {
        return Some(last.1);
    }
    let i = truth.partition_point(|(ti, _)| *ti < t);
    let (t1, p1) = truth.get(i)?;
    if *t1 == t {
        return Some(*p1);
    }
    let (t0, p0) = truth.get(i.checked_sub(1)?)?;
    let a = (t - t0) / (t1 - t0);
    let dtheta = sim::wrap_angle(p1[2] - p0[2]);
    Some([p0[0] + a * (p1[0] - p0[0]), p0[1] + a * (p1[1] - p0[1]), sim::wrap_angle(p0[2] + a * dtheta)])
}

/// A camera frame of the log: its time and instance image file.
struct LogFrame {
    t: f64,
    instance: PathBuf,
}

/// What a log holds of its camera, for `map.trees_in_view`.
enum CameraTruth {
    /// No camera.
    None,
    /// A log of `objslam record`: each frame's instance image (camera.jsonl).
    Frames(Vec<LogFrame>),
    /// The output of `objslam run`: per scan, the beams whose pixels showed the tree they
    /// hit (trees_shown.jsonl), with the line each came from.
    Shown(Vec<(usize, f64, Vec<usize>)>),
}

fn read_frames(log: &Path) -> Result<Vec<LogFrame>, ScoreError> {
    let file = log.join(files::CAMERA_LOG);
    if !file.exists() {
        return Ok(vec![]);
    }
    let mut frames = Vec::new();
    for (n, line) in numbered_lines(&read_text(&file)?) {
        let v: serde_json::Value = serde_json::from_str(line).map_err(|e| invalid(&file, Some(n), e.to_string()))?;
        let (Some(t), Some(instance)) = (v["t"].as_f64(), v["instance"].as_str()) else {
            return Err(invalid(&file, Some(n), "a frame needs `t` and `instance`"));
        };
        // The scans take frames with a cursor that only moves forward: a frame out of
        // order would be skipped, and the trees in view counted on fewer frames.
        if let Some(last) = frames.last().map(|f: &LogFrame| f.t)
            && t <= last
        {
            return Err(invalid(&file, Some(n), format!("frame time {t} does not follow {last}")));
        }
        frames.push(LogFrame { t, instance: log.join(instance) });
    }
    Ok(frames)
}

/// A record log's camera is its frames (camera.jsonl, if any); a run's, when it had one, is
/// its trees_shown.jsonl, which it must then have.
fn read_camera_truth(log: &Path, meta: &LogMetadata) -> Result<CameraTruth, ScoreError> {
    if meta.run_method.is_none() {
        let frames = read_frames(log)?;
        // A missing or cut camera index would score `trees_in_view` on fewer frames, or
        // the recall on the laser alone, without a word.
        if let Some(written) = meta.camera_frames
            && written != frames.len()
        {
            return Err(invalid(
                &log.join(files::CAMERA_LOG),
                None,
                format!(
                    "{} where metadata.json's summary.camera_frames says the recording wrote {written}: the camera index is missing or cut, so the trees in view cannot be counted",
                    match frames.len() {
                        0 => "no frame".to_string(),
                        1 => "1 frame".to_string(),
                        n => format!("{n} frames"),
                    }
                ),
            ));
        }
        return Ok(if frames.is_empty() { CameraTruth::None } else { CameraTruth::Frames(frames) });
    }
    if !meta.sim.camera.enabled {
        return Ok(CameraTruth::None);
    }
    #[derive(Deserialize)]
    #[serde(deny_unknown_fields)]
    struct ShownLine {
        t: f64,
        beams: Vec<usize>,
    }
    let file = log.join(files::TREES_SHOWN);
    let mut shown: Vec<(usize, f64, Vec<usize>)> = Vec::new();
    for (n, line) in numbered_lines(&read_text(&file)?) {
        let s: ShownLine = serde_json::from_str(line).map_err(|e| invalid(&file, Some(n), e.to_string()))?;
        if let Some((_, last, _)) = shown.last()
            && s.t <= *last
        {
            return Err(invalid(&file, Some(n), format!("scan time {} does not follow {last}", s.t)));
        }
        if s.beams.windows(2).any(|w| w[0] >= w[1]) {
            return Err(invalid(&file, Some(n), "beams must be listed in increasing order, each once"));
        }
        shown.push((n, s.t, s.beams));
    }
    Ok(CameraTruth::Shown(shown))
}

/// Refuses a run directory whose ground truth no longer gives the trees its run counted:
/// the denominators come from the truth alone, whatever the method, so they must be the
/// run's own. A cut `trees_shown.jsonl` (it has lines only for scans that showed a tree,
/// so its length proves nothing) or laser truth would otherwise score another recall.
fn check_trees_to_map(log: &Path, map: &MapContent) -> Result<(), ScoreError> {
    let file = log.join(files::METRICS);
    // A run stopped before it wrote its metrics has no count to hold the truth to.
    let text = match std::fs::read_to_string(&file) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        read => read.map_err(|error| ScoreError::Io { file: file.clone(), error })?,
    };
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| invalid(&file, Some(e.line()), e.to_string()))?;
    let counted = |key: &str| v.pointer(&format!("/map/{key}")).and_then(|n| n.as_u64()).map(|n| n as usize);
    let mismatch = match (counted("trees_in_view"), counted("trees_laser_seen")) {
        (Some(run), _) if map.trees_in_view != Some(run) => {
            Some(("trees_in_view", run, map.trees_in_view.unwrap_or(0), files::TREES_SHOWN))
        }
        (_, Some(run)) if map.trees_laser_seen != run => {
            Some(("trees_laser_seen", run, map.trees_laser_seen, files::LASER_TRUTH))
        }
        _ => None,
    };
    match mismatch {
        None => Ok(()),
        Some((key, run, now, source)) => Err(invalid(
            &log.join(source),
            None,
            format!(
                "gives {now} for map.{key} where the run counted {run} (metrics.json): the run's ground truth was changed or cut"
            ),
        )),
    }
}

fn read_instance(file: &Path, width: u32, height: u32) -> Result<Vec<u16>, ScoreError> {
    let img = image::open(file).map_err(|e| invalid(file, None, e.to_string()))?;
    let image::DynamicImage::ImageLuma16(img) = img else {
        return Err(invalid(file, None, "an instance image must be 16-bit grey"));
    };
    if img.dimensions() != (width, height) {
        return Err(invalid(
            file,
            None,
            format!("{}x{} where the camera gives {width}x{height}", img.width(), img.height()),
        ));
    }
    Ok(img.into_raw())
}

/// The log's observations of a scan (`observations.jsonl`): the beams of each, in id order.
fn observation_beams(
    file: &Path,
    line: usize,
    text: &str,
    scan: &sim::LaserScan,
) -> Result<Vec<(usize, usize)>, ScoreError> {
    #[derive(Deserialize)]
    struct Observation {
        first_beam: usize,
        last_beam: usize,
    }
    #[derive(Deserialize)]
    struct ObservationsLine {
        t: f64,
        observations: Vec<Observation>,
    }
    let o: ObservationsLine = serde_json::from_str(text).map_err(|e| invalid(file, Some(line), e.to_string()))?;
    if o.t != scan.t {
        return Err(invalid(file, Some(line), format!("t = {} s where the scan of this line has {} s", o.t, scan.t)));
    }
    let beams: Vec<(usize, usize)> = o.observations.iter().map(|o| (o.first_beam, o.last_beam)).collect();
    if let Some((k, problem)) = beams.iter().enumerate().find_map(|(k, (a, b))| Some((k, beams_outside(*a, *b, scan)?)))
    {
        return Err(invalid(file, Some(line), format!("observation {k}: {problem}")));
    }
    Ok(beams)
}

/// The contacts `collisions.jsonl` records: each line read as one, so that a damaged
/// file is an error rather than a count of its lines.
fn read_collisions(file: &Path) -> Result<usize, ScoreError> {
    let text = read_text(file)?;
    let mut count = 0;
    for (n, line) in numbered_lines(&text) {
        serde_json::from_str::<sim::Collision>(line).map_err(|e| invalid(file, Some(n), e.to_string()))?;
        count += 1;
    }
    Ok(count)
}

/// The file's only non-empty lines, numbered from 1.
pub(super) fn numbered_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()).map(|(i, l)| (i + 1, l))
}

/// The entry of a time-ordered list at the scan's time `t` (within `tolerance`), moving
/// `next` past it; `Err` with an entry before `t` that no scan took.
fn entry_at<'a, T>(
    items: &'a [T],
    next: &mut usize,
    time: impl Fn(&T) -> f64,
    t: f64,
    tolerance: f64,
) -> Result<Option<&'a T>, &'a T> {
    match items.get(*next) {
        Some(e) if (time(e) - t).abs() < tolerance => {
            *next += 1;
            Ok(Some(e))
        }
        Some(e) if time(e) < t => Err(e),
        _ => Ok(None),
    }
}

/// The error for an entry at a time when the log has no scan.
fn no_scan_at(file: &Path, line: usize, t: f64) -> ScoreError {
    invalid(file, Some(line), format!("no scan of the log at t = {t} s"))
}

/// Scores `estimate` against the log in `log`: a log of `objslam record`, or the output
/// directory of `objslam run`.
pub fn score_log(log: &Path, estimate: &Estimate) -> Result<ScoredMetrics, ScoreError> {
    let meta = read_metadata(log)?;
    let is_run = meta.run_method.is_some();
    let world = worlds::load(&log.join(files::WORLD))?;
    let camera_truth = read_camera_truth(log, &meta)?;
    let has_camera = !matches!(camera_truth, CameraTruth::None);
    let basis = estimate.recall_basis.unwrap_or(if has_camera { RecallBasis::InView } else { RecallBasis::LaserSeen });
    let camera =
        has_camera.then(|| crate::run::camera_geometry(&meta.sim, &crate::calibrate::true_extrinsics(&meta.sim)));
    if basis == RecallBasis::InView && camera.is_none() {
        return Err(invalid(
            &log.join(if is_run { files::METADATA } else { files::CAMERA_LOG }),
            None,
            "no camera: the recall of trees in view needs one (--recall-basis laser-seen)",
        ));
    }
    let mut scorer = RunScorer::new(&world, camera.clone(), meta.scoring.visibility, basis);

    // A run's own trajectory: its covariances (and its method's name) come with it.
    let own_trajectory =
        is_run && crate::partial_files::same_path(&estimate.trajectory, &log.join(files::TRAJECTORY_EST));
    let covariances = estimate
        .covariances
        .clone()
        .or_else(|| own_trajectory.then(|| log.join(files::TRAJECTORY_EST_COVARIANCE)).filter(|f| f.exists()));
    let truth = log.join(if is_run { files::TRAJECTORY_GT } else { files::GROUND_TRUTH });
    let pose_score = score_poses(&mut scorer, &truth, &estimate.trajectory, covariances.as_deref())?;

    let associations = match &estimate.associations {
        Some(file) => Some((file.as_path(), read_associations(file)?)),
        None => None,
    };
    let associations_given = associations.as_ref().map(|(f, a)| (*f, &a[..]));
    let merged = score_scans(log, &meta, &mut scorer, &camera_truth, camera.as_ref(), associations_given)?;

    let collisions = read_collisions(&log.join(files::COLLISIONS))?;
    let landmarks = match &estimate.landmarks {
        Some(file) => Some(read_landmarks(file)?),
        None => None,
    };
    if let (Some(map), Some(map_file), Some((file, scans))) = (&landmarks, &estimate.landmarks, &associations) {
        check_map_is_associated(map_file, map, file, scans)?;
    }
    let scored = scorer.finish(landmarks.as_deref().unwrap_or(&[]));
    if is_run {
        check_trees_to_map(log, &scored.map)?;
    }
    let have_map = landmarks.is_some();
    let have_associations = associations.is_some();
    // A run's own trajectory is scored under the run's method's name.
    let run_method = meta.run_method.clone().filter(|_| own_trajectory);
    let mut metrics = ScoredMetrics {
        scenario: meta.scoring.scenario.clone(),
        seed: meta.scoring.run_seed.unwrap_or(meta.seed),
        method: estimate.method.clone().or(run_method).unwrap_or_else(|| "external".into()),
        sim_seconds: meta.sim_seconds,
        ate_rmse_m: scored.ate_rmse_m,
        rpe_rmse_m: scored.rpe_rmse_m,
        anees: scored.anees,
        landmark_rmse_m: scored.landmark_rmse_m.filter(|_| have_map),
        // Which landmark stands on which object comes from the associations.
        map: (have_map && have_associations).then(|| scored.map.clone()),
        landmarks: landmarks.as_ref().map(|l| l.len()),
        associations: have_associations.then(|| scored.associations.clone()),
        duplicate_landmarks: (have_map && have_associations).then_some(scored.duplicate_landmarks),
        merged_landmarks: have_associations.then_some(merged),
        false_landmarks: (have_map && have_associations).then_some(scored.false_landmarks),
        collisions,
        route_completed: meta.route_completed,
        passed: None,
        failures: vec![],
        unchecked: vec![],
        poses_scored: pose_score.poses,
        trajectory_coverage: pose_score.coverage,
        warnings: vec![],
        recall_basis: basis,
    };
    if let Some(pass) = &meta.scoring.pass {
        check(pass, &mut metrics, &scored.map);
    }
    let share = |c: f64| format!("{:.1}%", 100.0 * c);
    if pose_score.coverage < MIN_PASS_COVERAGE {
        let words = format!(
            "the trajectory covers {} of the log (true poses with one of its poses within {COVERAGE_WINDOW_S} s)",
            share(pose_score.coverage)
        );
        // Whatever else is unchecked, the pose criteria are judged, and so little of the
        // log cannot pass them.
        if meta.scoring.pass.is_some() {
            metrics.failures.push(format!("{words}, less than the {} a pass needs", share(MIN_PASS_COVERAGE)));
            metrics.passed = Some(false);
        } else {
            metrics.warnings.push(words);
        }
    }
    if let Some(file) = &covariances {
        let (given, definite) = pose_score.covariances;
        if !metrics.anees.is_finite() {
            metrics.warnings.push(format!(
                "no ANEES: no covariance in {} is positive definite at a pose of the trajectory",
                file.display()
            ));
        } else if definite < pose_score.poses {
            // An ANEES over part of the trajectory reads like one over all of it.
            metrics.warnings.push(format!(
                "the ANEES is over {definite} of the trajectory's {} poses: {} gives {} a covariance{}",
                pose_score.poses,
                file.display(),
                if given == pose_score.poses { "every pose".to_string() } else { format!("{given} of them") },
                if definite < given { format!(" ({} not positive definite)", given - definite) } else { String::new() }
            ));
        }
    }
    let (pairs, over_gaps) = pose_score.rpe_pairs;
    if over_gaps > 0 {
        metrics.warnings.push(format!(
            "{over_gaps} of the RPE's {pairs} pose pairs span more than {:.1} s (gaps in the trajectory): the RPE there is over a longer time than {:.0} s",
            super::scorer::RPE_GAP_FACTOR * super::scorer::RPE_DELTA_S,
            super::scorer::RPE_DELTA_S
        ));
    }
    let off = pose_score.off_plane;
    if off.max_abs_z_m > OFF_PLANE_Z_M || off.max_tilt_deg > OFF_PLANE_TILT_DEG {
        metrics.warnings.push(format!(
            "the trajectory leaves the plane (|z| up to {:.3} m, tilt up to {:.1} deg); it is scored in x, y and heading only",
            off.max_abs_z_m, off.max_tilt_deg
        ));
    }
    Ok(metrics)
}

/// Scores each pose of `trajectory` against the true pose of its time in `truth_file`, with
/// its covariance where `covariances` gives one; returns the poses scored.
fn score_poses(
    scorer: &mut RunScorer,
    truth_file: &Path,
    trajectory_file: &Path,
    covariances_file: Option<&Path>,
) -> Result<PoseScore, ScoreError> {
    let truth = read_tum(truth_file)?;
    let (trajectory, off_plane) = super::estimate::read_tum_3d(trajectory_file)?;
    let covariances = match covariances_file {
        Some(f) => read_covariances(f)?,
        None => vec![],
    };
    let (mut next_covariance, mut given) = (0usize, 0usize);
    let no_pose_at = |line: usize, t: f64| {
        invalid(
            covariances_file.expect("rows come from a file"),
            Some(line),
            format!("no pose of the trajectory at t = {t} s"),
        )
    };
    for (i, (t, pose)) in trajectory.iter().enumerate() {
        let Some(true_pose) = truth_at(&truth, *t) else {
            return Err(invalid(
                trajectory_file,
                None,
                format!(
                    "pose {} at t = {t} s lies outside the log's ground truth ({} to {} s)",
                    i + 1,
                    truth[0].0,
                    truth[truth.len() - 1].0
                ),
            ));
        };
        let covariance = entry_at(&covariances, &mut next_covariance, |c| c.1, *t, 1e-6)
            .map_err(|(line, tc, _)| no_pose_at(*line, *tc))?
            .map(|(_, _, p)| *p);
        given += usize::from(covariance.is_some());
        scorer.on_pose(*t, *pose, covariance, true_pose);
    }
    if let Some((line, tc, _)) = covariances.get(next_covariance) {
        return Err(no_pose_at(*line, *tc));
    }
    let times: Vec<f64> = trajectory.iter().map(|(t, _)| *t).collect();
    let rpe_pairs = super::scorer::rpe_pairs_over_gaps(&times, super::scorer::RPE_DELTA_S);
    Ok(PoseScore {
        poses: trajectory.len(),
        coverage: coverage(&truth, &times),
        off_plane,
        rpe_pairs,
        covariances: (given, scorer.nees_poses()),
    })
}

/// The scans of the log, with their truth, the camera's evidence and the system's
/// observations and fusions; returns the fusions counted.
fn score_scans(
    log: &Path,
    meta: &LogMetadata,
    scorer: &mut RunScorer,
    camera_truth: &CameraTruth,
    camera: Option<&slam::segmentation::CameraGeometry>,
    associations: Option<(&Path, &[ScanAssociations])>,
) -> Result<usize, ScoreError> {
    // Observations given by id need the log's observations (read with the scans).
    let by_id = associations.is_some_and(|(_, a)| a.iter().any(|s| matches!(s.observations, Observations::Ids(_))));
    let observations_file = log.join(files::OBSERVATIONS);
    let observations_text = if by_id { Some(read_text(&observations_file)?) } else { None };
    let mut observation_lines = observations_text.as_deref().map(numbered_lines);
    let (laser_file, truth_file) = (log.join(files::LASER), log.join(files::LASER_TRUTH));
    let (laser_text, truth_text) = (read_text(&laser_file)?, read_text(&truth_file)?);
    let mut truth_lines = numbered_lines(&truth_text);
    let shown_file = log.join(files::TREES_SHOWN);
    let same_instant_s = 0.5 / meta.sim.physics_rate_hz;
    let (mut next_association, mut next_frame, mut merged) = (0usize, 0usize, 0usize);
    let mut fused_away = std::collections::HashSet::new();
    // Landmarks that an association has named so far.
    let mut named = std::collections::HashSet::new();
    // The log's own order first: a fault there would otherwise show as an association at a
    // time the log has no scan for, and be blamed on the associations' file.
    let mut last_t = f64::NEG_INFINITY;
    for (n, line) in numbered_lines(&laser_text) {
        #[derive(Deserialize)]
        struct ScanTime {
            t: f64,
        }
        let t = serde_json::from_str::<ScanTime>(line).map_err(|e| invalid(&laser_file, Some(n), e.to_string()))?.t;
        if t <= last_t {
            return Err(invalid(&laser_file, Some(n), format!("scan time {t} does not follow {last_t}")));
        }
        last_t = t;
    }
    for (n, line) in numbered_lines(&laser_text) {
        let scan: sim::LaserScan =
            serde_json::from_str(line).map_err(|e| invalid(&laser_file, Some(n), e.to_string()))?;
        let Some((j, truth_line)) = truth_lines.next() else {
            return Err(invalid(&truth_file, None, format!("ends before the scan of {}:{n}", laser_file.display())));
        };
        #[derive(Deserialize)]
        struct TruthLine {
            t: f64,
            #[serde(flatten)]
            beams: sim::LaserTruth,
        }
        let beams: TruthLine =
            serde_json::from_str(truth_line).map_err(|e| invalid(&truth_file, Some(j), e.to_string()))?;
        let n_beams = scan.ranges.len();
        if beams.t != scan.t || beams.beams.hit_ids.len() != n_beams || beams.beams.true_ranges.len() != n_beams {
            return Err(invalid(&truth_file, Some(j), format!("does not match the scan at t = {} s", scan.t)));
        }
        let log_observations = match &mut observation_lines {
            Some(lines) => {
                let Some((k, text)) = lines.next() else {
                    return Err(invalid(
                        &observations_file,
                        None,
                        format!("ends before the scan of {}:{n}", laser_file.display()),
                    ));
                };
                observation_beams(&observations_file, k, text, &scan)?
            }
            None => vec![],
        };
        let (observations, fusions): (Vec<ScoredObservation>, &[Fusion]) = match associations {
            Some((file, scans)) => match entry_at(scans, &mut next_association, |a| a.t, scan.t, 1e-6) {
                Ok(Some(a)) => {
                    let observations = scan_observations(file, a, &scan, &log_observations, &observations_file)?;
                    // A landmark fused away at an earlier scan takes no more observations.
                    if let Some(id) = observations.iter().filter_map(|o| o.landmark).find(|id| fused_away.contains(id))
                    {
                        return Err(invalid(
                            file,
                            Some(a.line),
                            format!("an observation is associated with landmark {id}, which was fused away before"),
                        ));
                    }
                    named.extend(observations.iter().filter_map(|o| o.landmark));
                    // A fusion joins two landmarks that exist: both were made from
                    // associated observations (this scan's included), neither fused away.
                    for f in &a.fusions {
                        let problem = if !fused_away.insert(f.removed) {
                            Some(format!("landmark {} is fused away a second time", f.removed))
                        } else if fused_away.contains(&f.kept) {
                            Some(format!("landmark {} is kept by a fusion after it was fused away", f.kept))
                        } else {
                            [f.kept, f.removed].into_iter().find(|id| !named.contains(id)).map(|id| {
                                format!("landmark {id} is fused before any observation was associated with it")
                            })
                        };
                        if let Some(problem) = problem {
                            return Err(invalid(file, Some(a.line), problem));
                        }
                    }
                    (observations, &a.fusions)
                }
                Ok(None) => (vec![], &[]),
                Err(a) => return Err(no_scan_at(file, a.line, a.t)),
            },
            None => (vec![], &[]),
        };
        merged += fusions.len();
        let shown = match camera_truth {
            CameraTruth::None => None,
            CameraTruth::Frames(frames) => {
                // The frame of the scan's instant, if the camera fired with it.
                while next_frame < frames.len() && frames[next_frame].t < scan.t - same_instant_s {
                    next_frame += 1;
                }
                match (frames.get(next_frame).filter(|f| (f.t - scan.t).abs() < same_instant_s), camera) {
                    (Some(f), Some(c)) => {
                        let pixels = read_instance(&f.instance, c.width, c.height)?;
                        let image = InstanceImage {
                            t: f.t,
                            width: c.width,
                            height: c.height,
                            instance: &pixels,
                            regions: None,
                        };
                        Some(scorer.beams_shown(&scan, &beams.beams, &image))
                    }
                    _ => None,
                }
            }
            CameraTruth::Shown(lines) => match entry_at(lines, &mut next_frame, |l| l.1, scan.t, 1e-9) {
                Ok(Some((k, _, shown))) => {
                    if let Some(b) = shown.iter().find(|b| **b >= n_beams) {
                        let message = format!("beam {b} is not within the scan's {n_beams} beams");
                        return Err(invalid(&shown_file, Some(*k), message));
                    }
                    Some(shown.clone())
                }
                Ok(None) => None,
                Err((k, t, _)) => return Err(no_scan_at(&shown_file, *k, *t)),
            },
        };
        scorer.on_scan(&scan, &beams.beams, shown.as_deref(), &observations, fusions);
    }
    // Whatever is left names a time the log has no scan at.
    if let Some((j, _)) = truth_lines.next() {
        return Err(invalid(&truth_file, Some(j), format!("more lines than {} has scans", laser_file.display())));
    }
    if let Some((k, _)) = observation_lines.as_mut().and_then(|l| l.next()) {
        return Err(invalid(
            &observations_file,
            Some(k),
            format!("more lines than {} has scans", laser_file.display()),
        ));
    }
    if let Some((file, scans)) = associations
        && let Some(a) = scans.get(next_association)
    {
        return Err(no_scan_at(file, a.line, a.t));
    }
    if let CameraTruth::Shown(lines) = camera_truth
        && let Some((k, t, _)) = lines.get(next_frame)
    {
        return Err(no_scan_at(&shown_file, *k, *t));
    }
    Ok(merged)
}

/// Checks the criteria these inputs can check; the others are listed as unchecked and
/// leave `passed` null, unless a criterion that was checked fails. A trajectory alone
/// still answers the criteria on the pose (ATE, collisions, the route completed), and
/// landmarks without associations the landmark RMSE: a poor trajectory is never left
/// unjudged because no map came with it.
fn check(pass: &PassCriteria, m: &mut ScoredMetrics, map: &MapContent) {
    let mut unchecked = Vec::new();
    if pass.max_calibration_rotation_error_deg.is_some() || pass.max_calibration_translation_error_m.is_some() {
        unchecked.push("calibration errors (a system's extrinsics are not an input)".to_string());
    }
    let (checked, figures) = match (&m.associations, m.duplicate_landmarks, m.false_landmarks) {
        (Some(associations), Some(duplicates), Some(false_landmarks)) => {
            (pass.clone(), (associations.wrong, false_landmarks, duplicates))
        }
        _ => {
            let landmarks_given = m.landmarks.is_some();
            let (judged, needs_map) = pass.for_trajectory(landmarks_given);
            if needs_map {
                unchecked.push("map and association criteria (needs --landmarks and --associations)".to_string());
            }
            if pass.max_landmark_rmse_m.is_some() && !landmarks_given {
                unchecked.push("landmark RMSE (needs --landmarks)".to_string());
            }
            (judged, (0, 0, 0))
        }
    };
    let (wrong_associations, false_landmarks, duplicate_landmarks) = figures;
    let figures = crate::run::PassFigures {
        wrong_associations,
        false_landmarks,
        duplicate_landmarks,
        map,
        recall_basis: m.recall_basis,
        ate_rmse_m: m.ate_rmse_m,
        landmark_rmse_m: m.landmark_rmse_m,
        collisions: m.collisions,
        calibration: None,
        route_completed: m.route_completed,
    };
    m.failures = crate::run::check_pass(&checked, &figures);
    m.passed = if !m.failures.is_empty() { Some(false) } else { unchecked.is_empty().then_some(true) };
    m.unchecked = unchecked;
}

/// Short summary of a score for the terminal.
pub fn summary_table(m: &ScoredMetrics) -> String {
    let mut s = format!(
        "log of {} (seed {}), scored as {}: {} poses over {:.1} s\n",
        m.scenario.as_deref().unwrap_or("a world"),
        m.seed,
        m.method,
        m.poses_scored,
        m.sim_seconds
    );
    s.push_str(&format!("  ATE RMSE          {:>8.3} m\n", m.ate_rmse_m));
    if m.rpe_rmse_m.is_finite() {
        s.push_str(&format!("  RPE RMSE          {:>8.3} m over {:.0} s\n", m.rpe_rmse_m, super::scorer::RPE_DELTA_S));
    } else {
        // As metrics.json's null says: the trajectory has no two poses that far apart.
        s.push_str(&format!("  RPE RMSE          undefined (no poses {:.0} s apart)\n", super::scorer::RPE_DELTA_S));
    }
    if m.anees.is_finite() {
        let anees = crate::run::unbounded_figure(m.anees, 2);
        s.push_str(&format!("  ANEES             {anees:>8} (pose, 3 dof: consistent near 3)\n"));
    }
    if let Some(map) = &m.map {
        let recall = map.tree_recall.map_or("undefined".to_string(), |r| format!("{:.0}%", 100.0 * r));
        s.push_str(&format!("  tree recall       {recall:>4} ({})\n", map.recall_in_words(m.recall_basis)));
        s.push_str(&format!(
            "  false landmarks   {:>4} (posts {}, palms {}, people {}, walls {}, nothing {})\n",
            m.false_landmarks.unwrap_or(0),
            map.posts,
            map.palms,
            map.people,
            map.walls,
            map.nothing
        ));
        s.push_str(&format!("  duplicates        {:>4}\n", m.duplicate_landmarks.unwrap_or(0)));
    }
    if let Some(a) = &m.associations {
        s.push_str(&format!("  associations      {:>4} ({} wrong)\n", a.total, a.wrong));
    }
    if let Some(r) = m.landmark_rmse_m {
        s.push_str(&format!("  landmark RMSE     {r:>8.3} m\n"));
    }
    s.push_str(&format!("  collisions        {:>4}\n", m.collisions));
    for u in &m.unchecked {
        s.push_str(&format!("  not checked: {u}\n"));
    }
    for w in &m.warnings {
        s.push_str(&format!("  warning: {w}\n"));
    }
    s.push_str(&match m.passed {
        Some(true) => "  PASSED\n".to_string(),
        Some(false) => format!("  FAILED: {}\n", m.failures.join("; ")),
        None => "  no verdict: not every criterion could be checked\n".to_string(),
    });
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn truth_between_recorded_poses_is_interpolated_and_outside_them_absent() {
        let truth = [(1.0, [0.0, 0.0, 3.1]), (2.0, [2.0, 4.0, -3.1])];
        assert_eq!(truth_at(&truth, 1.0), Some([0.0, 0.0, 3.1]));
        let mid = truth_at(&truth, 1.5).unwrap();
        assert_eq!([mid[0], mid[1]], [1.0, 2.0]);
        assert!(mid[2].abs() > 3.1, "the heading goes the short way round: {}", mid[2]);
        assert_eq!(truth_at(&truth, 0.5), None);
        assert_eq!(truth_at(&truth, 2.5), None);
        // A rounding error past either end is that end.
        assert_eq!(truth_at(&truth, 2.000_000_000_024_6), Some([2.0, 4.0, -3.1]));
        assert_eq!(truth_at(&truth, 1.0 - 1e-9), Some([0.0, 0.0, 3.1]));
        assert_eq!(truth_at(&truth, 2.000_01), None);
    }

    /// Regression: frames out of time order were skipped by the scans' cursor without a
    /// word, and the trees in view (the recall's denominator) counted on fewer frames.
    #[test]
    fn camera_frames_out_of_time_order_are_an_error_naming_the_line() {
        let dir = std::env::temp_dir().join(format!("objslam-frames-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let frame = |t: f64| format!("{{\"t\": {t}, \"instance\": \"camera/{t}_instance.png\"}}\n");
        let read = |lines: &[f64]| {
            std::fs::write(dir.join(files::CAMERA_LOG), lines.iter().map(|t| frame(*t)).collect::<String>()).unwrap();
            read_frames(&dir).map(|f| f.len()).map_err(|e| e.to_string())
        };
        assert_eq!(read(&[0.1, 0.2, 0.3]), Ok(3));
        let e = read(&[0.1, 0.3, 0.2]);
        assert!(e.as_ref().is_err_and(|e| e.contains("camera.jsonl:3") && e.contains("does not follow")), "{e:?}");
        let e = read(&[0.1, 0.1]);
        assert!(e.as_ref().is_err_and(|e| e.contains("camera.jsonl:2") && e.contains("does not follow")), "{e:?}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
