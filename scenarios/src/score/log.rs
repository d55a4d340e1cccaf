//! `objslam score`: scores any SLAM system's output against a sensor log written by
//! `objslam record`, with the rules `objslam run` applies to its own pipeline
//! ([`RunScorer`]).
//!
//! The system under test writes, from the log's sensor data alone:
//! - a trajectory in TUM format (`timestamp tx ty tz qx qy qz qw`, world frame), required;
//! - its map, `--landmarks`: a JSON array of `{"id": 3, "position": [x, y]}` (other keys
//!   are ignored, so `objslam run`'s `landmarks.json` is read as it is);
//! - what each laser cluster went to, `--associations`: JSON lines of
//!   `{"t": scan time, "observations": [{"first_beam", "last_beam", "landmark"}], "fusions": [{"kept", "removed"}]}`,
//!   as `objslam run` writes `associations.jsonl`.
//!
//! Figures that only the system's insides carry (segmentation scores, relinearisations,
//! NEES, calibration) are not scored. Docs: docs/guide/scoring.md.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::scorer::{Fusion, MapLandmark, RecallBasis, RunScorer, ScoredObservation, VisibilitySettings};
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

fn invalid(file: &Path, line: Option<usize>, message: impl Into<String>) -> ScoreError {
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
}

impl LogScoring {
    /// A scenario's: its pipeline's clustering and confirmation, and its criteria.
    pub fn of_scenario(scenario: &crate::scenario::Scenario, run_seed: u64) -> Self {
        LogScoring {
            scenario: Some(scenario.name.clone()),
            run_seed: Some(run_seed),
            visibility: VisibilitySettings::of(&scenario.pipeline),
            pass: Some(scenario.pass.clone()),
        }
    }

    /// A plain world's: the default pipeline's settings, no criteria.
    pub fn of_world() -> Self {
        LogScoring {
            scenario: None,
            run_seed: None,
            visibility: VisibilitySettings::of(&slam::pipeline::PipelineConfig::default()),
            pass: None,
        }
    }
}

/// The system's outputs to score.
#[derive(Debug, Clone, Default)]
pub struct Estimate {
    pub trajectory: PathBuf,
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
    pub recall_basis: RecallBasis,
}

/// The parts of a log's `metadata.json` that scoring reads.
struct LogMetadata {
    seed: u64,
    sim: sim::SimConfig,
    route_completed: bool,
    sim_seconds: f64,
    scoring: LogScoring,
}

fn read_text(file: &Path) -> Result<String, ScoreError> {
    std::fs::read_to_string(file).map_err(|error| ScoreError::Io { file: file.to_path_buf(), error })
}

fn field<T: serde::de::DeserializeOwned>(file: &Path, v: &serde_json::Value, path: &str) -> Result<T, ScoreError> {
    let mut at = v;
    for key in path.split('.') {
        at = at
            .get(key)
            .ok_or_else(|| invalid(file, None, format!("no field `{path}` (not a log of `objslam record`?)")))?;
    }
    serde_json::from_value(at.clone()).map_err(|e| invalid(file, None, format!("field `{path}`: {e}")))
}

fn read_metadata(log: &Path) -> Result<LogMetadata, ScoreError> {
    let file = log.join("metadata.json");
    let v: serde_json::Value =
        serde_json::from_str(&read_text(&file)?).map_err(|e| invalid(&file, Some(e.line()), e.to_string()))?;
    let tool: String = field(&file, &v, "tool")?;
    if tool != "objslam record" {
        return Err(invalid(&file, None, format!("written by `{tool}`, not `objslam record`")));
    }
    // Logs recorded before scoring settings were written: those of a plain world.
    let scoring = match v.get("scoring") {
        Some(_) => field(&file, &v, "scoring")?,
        None => LogScoring::of_world(),
    };
    Ok(LogMetadata {
        seed: field(&file, &v, "seed")?,
        sim: field(&file, &v, "sim_config")?,
        route_completed: field(&file, &v, "summary.route_completed")?,
        sim_seconds: field(&file, &v, "summary.sim_seconds")?,
        scoring,
    })
}

/// A TUM trajectory: (t, x, y, yaw) per pose, in file order.
pub fn read_tum(file: &Path) -> Result<Vec<(f64, [f64; 3])>, ScoreError> {
    let mut poses: Vec<(f64, [f64; 3])> = Vec::new();
    for (i, line) in read_text(file)?.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let values: Vec<f64> = line
            .split_whitespace()
            .map(|w| w.parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|e| invalid(file, Some(i + 1), format!("not a number: {e}")))?;
        let [t, x, y, _z, qx, qy, qz, qw] = values[..] else {
            return Err(invalid(
                file,
                Some(i + 1),
                format!("{} values where TUM has 8 (timestamp tx ty tz qx qy qz qw)", values.len()),
            ));
        };
        if values.iter().any(|v| !v.is_finite()) {
            return Err(invalid(file, Some(i + 1), "a value is not finite"));
        }
        if let Some((last, _)) = poses.last()
            && t <= *last
        {
            return Err(invalid(file, Some(i + 1), format!("timestamp {t} does not follow {last}")));
        }
        poses.push((t, [x, y, super::scorer::yaw_of_quaternion([qx, qy, qz, qw])]));
    }
    if poses.is_empty() {
        return Err(invalid(file, None, "no pose"));
    }
    Ok(poses)
}

/// The true pose at `t`: the recorded one at that time, else linear between its
/// neighbours; `None` outside the recording.
fn truth_at(truth: &[(f64, [f64; 3])], t: f64) -> Option<[f64; 3]> {
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

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AssociationLine {
    t: f64,
    observations: Vec<ScoredObservation>,
    #[serde(default)]
    fusions: Vec<Fusion>,
}

/// Per scan time, the observations and fusions (and the line they came from).
fn read_associations(file: &Path) -> Result<Vec<(usize, AssociationLine)>, ScoreError> {
    let mut lines = Vec::new();
    for (i, line) in read_text(file)?.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let a: AssociationLine = serde_json::from_str(line).map_err(|e| invalid(file, Some(i + 1), e.to_string()))?;
        if let Some((_, last)) = lines.last().map(|(n, a): &(usize, AssociationLine)| (*n, a.t))
            && a.t <= last
        {
            return Err(invalid(file, Some(i + 1), format!("scan time {} does not follow {last}", a.t)));
        }
        lines.push((i + 1, a));
    }
    Ok(lines)
}

fn read_landmarks(file: &Path) -> Result<Vec<MapLandmark>, ScoreError> {
    let text = read_text(file)?;
    let landmarks: Vec<MapLandmark> = slam::settings::from_json(&text).map_err(|e| invalid(file, None, e))?;
    let mut seen = std::collections::HashSet::new();
    for l in &landmarks {
        if !l.position.iter().all(|v| v.is_finite()) {
            return Err(invalid(file, None, format!("landmark {}: position is not finite", l.id)));
        }
        if !seen.insert(l.id) {
            return Err(invalid(file, None, format!("landmark id {} appears twice", l.id)));
        }
    }
    Ok(landmarks)
}

/// A camera frame of the log: its time and instance image file.
struct LogFrame {
    t: f64,
    instance: PathBuf,
}

fn read_frames(log: &Path) -> Result<Vec<LogFrame>, ScoreError> {
    let file = log.join("camera.jsonl");
    if !file.exists() {
        return Ok(vec![]);
    }
    let mut frames = Vec::new();
    for (i, line) in read_text(&file)?.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let v: serde_json::Value =
            serde_json::from_str(line).map_err(|e| invalid(&file, Some(i + 1), e.to_string()))?;
        let (Some(t), Some(instance)) = (v["t"].as_f64(), v["instance"].as_str()) else {
            return Err(invalid(&file, Some(i + 1), "a frame needs `t` and `instance`"));
        };
        frames.push(LogFrame { t, instance: log.join(instance) });
    }
    Ok(frames)
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

/// Scores `estimate` against the log in `log`.
pub fn score_log(log: &Path, estimate: &Estimate) -> Result<ScoredMetrics, ScoreError> {
    let meta = read_metadata(log)?;
    let world = worlds::load(&log.join("world.toml"))?;
    let frames = read_frames(log)?;
    let basis =
        estimate.recall_basis.unwrap_or(if frames.is_empty() { RecallBasis::LaserSeen } else { RecallBasis::InView });
    let camera = (!frames.is_empty())
        .then(|| crate::run::camera_geometry(&meta.sim, &crate::calibrate::true_extrinsics(&meta.sim)));
    if basis == RecallBasis::InView && camera.is_none() {
        return Err(invalid(
            &log.join("camera.jsonl"),
            None,
            "no camera frames: the recall of trees in view needs them (--recall-basis laser-seen)",
        ));
    }
    let mut scorer = RunScorer::new(&world, camera.clone(), meta.scoring.visibility, basis);

    let truth = read_tum(&log.join("ground_truth.tum"))?;
    let trajectory = read_tum(&estimate.trajectory)?;
    for (i, (t, pose)) in trajectory.iter().enumerate() {
        let Some(true_pose) = truth_at(&truth, *t) else {
            return Err(invalid(
                &estimate.trajectory,
                None,
                format!(
                    "pose {} at t = {t} s lies outside the log's ground truth ({} to {} s)",
                    i + 1,
                    truth[0].0,
                    truth[truth.len() - 1].0
                ),
            ));
        };
        scorer.on_pose(*t, *pose, None, true_pose);
    }

    let associations = match &estimate.associations {
        Some(file) => Some((file, read_associations(file)?)),
        None => None,
    };
    let mut next_association = 0usize;
    let mut merged = 0usize;
    let same_instant_s = 0.5 / meta.sim.physics_rate_hz;
    let mut next_frame = 0usize;
    let (laser_file, truth_file) = (log.join("laser.jsonl"), log.join("laser_truth.jsonl"));
    let (laser_text, truth_text) = (read_text(&laser_file)?, read_text(&truth_file)?);
    let mut truth_lines = truth_text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
    for (i, line) in laser_text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let scan: sim::LaserScan =
            serde_json::from_str(line).map_err(|e| invalid(&laser_file, Some(i + 1), e.to_string()))?;
        let Some((j, truth_line)) = truth_lines.next() else {
            return Err(invalid(&truth_file, None, format!("ends before scan {} of {}", i + 1, laser_file.display())));
        };
        #[derive(Deserialize)]
        struct TruthLine {
            t: f64,
            #[serde(flatten)]
            beams: sim::LaserTruth,
        }
        let beams: TruthLine =
            serde_json::from_str(truth_line).map_err(|e| invalid(&truth_file, Some(j + 1), e.to_string()))?;
        if beams.t != scan.t || beams.beams.hit_ids.len() != scan.ranges.len() {
            return Err(invalid(&truth_file, Some(j + 1), format!("does not match scan at t = {} s", scan.t)));
        }
        let (observations, fusions): (&[ScoredObservation], &[Fusion]) = match &associations {
            Some((file, lines)) => match lines.get(next_association) {
                Some((n, a)) if (a.t - scan.t).abs() < 1e-6 => {
                    next_association += 1;
                    if let Some(o) =
                        a.observations.iter().find(|o| o.first_beam > o.last_beam || o.last_beam >= scan.ranges.len())
                    {
                        return Err(invalid(
                            file,
                            Some(*n),
                            format!(
                                "beams {}..={} are not within the scan's {} beams",
                                o.first_beam,
                                o.last_beam,
                                scan.ranges.len()
                            ),
                        ));
                    }
                    (&a.observations, &a.fusions)
                }
                Some((n, a)) if a.t < scan.t => {
                    return Err(invalid(file, Some(*n), format!("no scan of the log at t = {} s", a.t)));
                }
                _ => (&[], &[]),
            },
            None => (&[], &[]),
        };
        merged += fusions.len();
        // The frame of the scan's instant, if the camera fired with it.
        while next_frame < frames.len() && frames[next_frame].t < scan.t - same_instant_s {
            next_frame += 1;
        }
        let frame = frames.get(next_frame).filter(|f| (f.t - scan.t).abs() < same_instant_s);
        let camera_geometry = camera.as_ref();
        let image = match (frame, camera_geometry) {
            (Some(f), Some(c)) => Some((f.t, read_instance(&f.instance, c.width, c.height)?)),
            _ => None,
        };
        let instance = image.as_ref().zip(camera_geometry).map(|((t, pixels), c)| InstanceImage {
            t: *t,
            width: c.width,
            height: c.height,
            instance: pixels,
            columns: None,
        });
        scorer.on_scan(&scan, &beams.beams, instance.as_ref(), observations, fusions);
    }
    if let Some((file, lines)) = &associations
        && let Some((n, a)) = lines.get(next_association)
    {
        return Err(invalid(file, Some(*n), format!("no scan of the log at t = {} s", a.t)));
    }

    let collisions_file = log.join("collisions.jsonl");
    let collisions = read_text(&collisions_file)?.lines().filter(|l| !l.trim().is_empty()).count();
    let landmarks = match &estimate.landmarks {
        Some(file) => Some(read_landmarks(file)?),
        None => None,
    };
    let scored = scorer.finish(landmarks.as_deref().unwrap_or(&[]));
    let have_map = landmarks.is_some();
    let have_associations = associations.is_some();
    let mut metrics = ScoredMetrics {
        scenario: meta.scoring.scenario.clone(),
        seed: meta.scoring.run_seed.unwrap_or(meta.seed),
        method: estimate.method.clone().unwrap_or_else(|| "external".into()),
        sim_seconds: meta.sim_seconds,
        ate_rmse_m: scored.ate_rmse_m,
        rpe_rmse_m: scored.rpe_rmse_m,
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
        poses_scored: trajectory.len(),
        recall_basis: basis,
    };
    if let Some(pass) = &meta.scoring.pass {
        check(pass, &mut metrics, &scored.map);
    }
    Ok(metrics)
}

/// Checks the criteria these inputs can check; the others are listed as unchecked and
/// leave `passed` null.
fn check(pass: &PassCriteria, m: &mut ScoredMetrics, map: &MapContent) {
    let mut unchecked = Vec::new();
    if pass.max_calibration_rotation_error_deg.is_some() || pass.max_calibration_translation_error_m.is_some() {
        unchecked.push("calibration errors (a system's extrinsics are not an input)".to_string());
    }
    let (Some(associations), Some(duplicates), Some(false_landmarks)) =
        (&m.associations, m.duplicate_landmarks, m.false_landmarks)
    else {
        unchecked.push("map and association criteria (needs --landmarks and --associations)".to_string());
        m.unchecked = unchecked;
        return;
    };
    let as_run = crate::run::Metrics {
        scenario: m.scenario.clone().unwrap_or_default(),
        seed: m.seed,
        method: m.method.clone(),
        sim_seconds: m.sim_seconds,
        wall_seconds: 0.0,
        realtime_factor: 0.0,
        ate_rmse_m: m.ate_rmse_m,
        rpe_rmse_m: m.rpe_rmse_m,
        landmark_rmse_m: m.landmark_rmse_m,
        map: map.clone(),
        landmarks: m.landmarks.unwrap_or(0),
        associations: associations.clone(),
        duplicate_landmarks: duplicates,
        merged_landmarks: m.merged_landmarks.unwrap_or(0),
        relinearisations: 0,
        relinearisation_failures: 0,
        retracted_landmarks: Default::default(),
        false_landmarks,
        segmentation: Default::default(),
        calibration: None,
        odometry_calibration: None,
        anees: f64::NAN,
        collisions: m.collisions,
        route_completed: m.route_completed,
        passed: false,
        failures: vec![],
        timing: Default::default(),
        renderer: None,
        appearance_model: None,
    };
    m.failures = crate::run::check_pass(pass, &as_run);
    m.passed = unchecked.is_empty().then_some(m.failures.is_empty());
    if !m.failures.is_empty() {
        m.passed = Some(false);
    }
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
    s.push_str(&format!("  RPE RMSE          {:>8.3} m over {:.0} s\n", m.rpe_rmse_m, super::scorer::RPE_DELTA_S));
    if let Some(map) = &m.map {
        let recall = map.tree_recall.map_or("undefined".to_string(), |r| format!("{:.0}%", 100.0 * r));
        s.push_str(&format!("  tree recall       {recall:>4} ({})\n", map.recall_in_words()));
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
    }

    #[test]
    fn a_tum_file_with_a_bad_line_is_an_error_naming_the_line() {
        let dir = std::env::temp_dir().join(format!("objslam-tum-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("bad.tum");
        std::fs::write(&file, "# t x y z qx qy qz qw\n0 0 0 0 0 0 0 1\n1 2 3\n").unwrap();
        let e = read_tum(&file).unwrap_err().to_string();
        assert!(e.contains("bad.tum:3") && e.contains("3 values"), "{e}");
        std::fs::write(&file, "1 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n").unwrap();
        let e = read_tum(&file).unwrap_err().to_string();
        assert!(e.contains("bad.tum:2") && e.contains("does not follow"), "{e}");
        std::fs::write(&file, "0 1.5 -2 0 0 0 0.7071067811865476 0.7071067811865476\n").unwrap();
        let poses = read_tum(&file).unwrap();
        assert_eq!(poses[0].1[0..2], [1.5, -2.0]);
        assert!((poses[0].1[2] - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        std::fs::remove_dir_all(&dir).ok();
    }
}
