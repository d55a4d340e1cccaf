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
    /// How the log's `observations.jsonl` clusters each scan (logs written before it was
    /// recorded have the default).
    #[serde(default)]
    pub clustering: slam::clustering::ClusteringConfig,
}

impl LogScoring {
    /// A scenario's: its pipeline's clustering and confirmation, and its criteria.
    pub fn of_scenario(scenario: &crate::scenario::Scenario, run_seed: u64) -> Self {
        LogScoring {
            scenario: Some(scenario.name.clone()),
            run_seed: Some(run_seed),
            visibility: VisibilitySettings::of(&scenario.pipeline),
            pass: Some(scenario.pass.clone()),
            clustering: scenario.pipeline.clustering,
        }
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
    /// For the output directory of `objslam run`: the method it ran.
    run_method: Option<String>,
}

fn read_text(file: &Path) -> Result<String, ScoreError> {
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
    let file = log.join("metadata.json");
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

/// What a system did with one scan: its observations of it, each with the landmark it
/// went to, and the fusions it made after it.
#[derive(Debug)]
struct ScanAssociations {
    /// The file's line where the scan's entries start.
    line: usize,
    t: f64,
    observations: Observations,
    fusions: Vec<Fusion>,
}

/// A scan's observations, given by their beams or by their ids in the log's
/// `observations.jsonl` (the index in the scan's list).
#[derive(Debug)]
enum Observations {
    Beams(Vec<ScoredObservation>),
    /// (line, observation id, landmark).
    Ids(Vec<(usize, usize, Option<u32>)>),
}

/// A line of the beams form: a scan's observations by their beams, and its fusions.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct BeamsLine {
    t: f64,
    observations: Vec<ScoredObservation>,
    #[serde(default)]
    fusions: Vec<Fusion>,
}

/// A line of the decision form (as `decisions.jsonl` writes it): one observation, by its id
/// within the scan, and the landmark it went to.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DecisionLine {
    t: f64,
    observation: usize,
    #[serde(default)]
    landmark: Option<u32>,
    /// The landmark as `decisions.jsonl` gives it: `new` or `existing` name one.
    #[serde(default)]
    choice: Option<slam::association::Choice>,
    // What decisions.jsonl writes beside them, which scoring does not read.
    #[serde(default, rename = "candidates")]
    _candidates: serde::de::IgnoredAny,
    #[serde(default, rename = "method")]
    _method: serde::de::IgnoredAny,
    #[serde(default, rename = "true_object")]
    _true_object: serde::de::IgnoredAny,
}

impl DecisionLine {
    fn landmark(&self) -> Result<Option<u32>, String> {
        use slam::association::Choice;
        let chosen = match self.choice {
            Some(Choice::New { landmark } | Choice::Existing { landmark }) => Some(landmark),
            _ => None,
        };
        match (self.landmark, self.choice) {
            (Some(a), Some(_)) if chosen != Some(a) => {
                Err(format!("`landmark` {a} and `choice` {:?} disagree", self.choice.unwrap()))
            }
            (Some(a), _) => Ok(Some(a)),
            (None, _) => Ok(chosen),
        }
    }
}

/// A fusion line of the decision form: after the scan at `t`, `removed` was fused into `kept`.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FusionLine {
    t: f64,
    fusion: Fusion,
}

/// One entry of an associations file, before entries are grouped by scan.
enum AssociationEntry {
    Beams(Vec<ScoredObservation>, Vec<Fusion>),
    Decision(usize, Option<u32>),
    Fusion(Fusion),
}

/// The scans of an associations file (JSON lines, or CSV when its name ends in `.csv`), in
/// time order; entries of one scan share its time (to 1 us).
fn read_associations(file: &Path) -> Result<Vec<ScanAssociations>, ScoreError> {
    let entries = if file.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv")) {
        read_association_csv(file)?
    } else {
        read_association_lines(file)?
    };
    let mut scans: Vec<ScanAssociations> = Vec::new();
    for (line, t, entry) in entries {
        if !t.is_finite() {
            return Err(invalid(file, Some(line), "the time is not finite"));
        }
        let same_scan = scans.last().is_some_and(|s| (t - s.t).abs() < 1e-6);
        if let Some(last) = scans.last()
            && !same_scan
            && t < last.t
        {
            return Err(invalid(file, Some(line), format!("scan time {t} does not follow {}", last.t)));
        }
        if !same_scan {
            let (observations, fusions) = match entry {
                AssociationEntry::Beams(o, f) => (Observations::Beams(o), f),
                AssociationEntry::Decision(id, landmark) => (Observations::Ids(vec![(line, id, landmark)]), vec![]),
                AssociationEntry::Fusion(f) => (Observations::Ids(vec![]), vec![f]),
            };
            scans.push(ScanAssociations { line, t, observations, fusions });
            continue;
        }
        let scan = scans.last_mut().expect("same scan");
        match (entry, &mut scan.observations) {
            (AssociationEntry::Beams(..), _) => {
                return Err(invalid(
                    file,
                    Some(line),
                    format!("a second entry for the scan at t = {t} s (a line by beams holds the whole scan)"),
                ));
            }
            (AssociationEntry::Decision(..), Observations::Beams(_)) => {
                return Err(invalid(file, Some(line), "observations by id and by beams for one scan"));
            }
            (AssociationEntry::Decision(..), Observations::Ids(_)) if !scan.fusions.is_empty() => {
                return Err(invalid(file, Some(line), "an observation after its scan's fusions"));
            }
            (AssociationEntry::Decision(id, landmark), Observations::Ids(all)) => all.push((line, id, landmark)),
            (AssociationEntry::Fusion(f), _) => scan.fusions.push(f),
        }
    }
    Ok(scans)
}

/// JSON lines: `{"t", "observations": [...], "fusions": [...]}` (beams), or one decision
/// `{"t", "observation", "landmark" | "choice"}` or fusion `{"t", "fusion"}` per line.
fn read_association_lines(file: &Path) -> Result<Vec<(usize, f64, AssociationEntry)>, ScoreError> {
    let mut entries = Vec::new();
    for (i, line) in read_text(file)?.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let bad = |e: serde_json::Error| invalid(file, Some(i + 1), e.to_string());
        let v: serde_json::Value = serde_json::from_str(line).map_err(bad)?;
        let entry = if v.get("observations").is_some() {
            let b: BeamsLine = serde_json::from_value(v).map_err(bad)?;
            (b.t, AssociationEntry::Beams(b.observations, b.fusions))
        } else if v.get("observation").is_some() {
            let d: DecisionLine = serde_json::from_value(v).map_err(bad)?;
            let landmark = d.landmark().map_err(|m| invalid(file, Some(i + 1), m))?;
            (d.t, AssociationEntry::Decision(d.observation, landmark))
        } else if v.get("fusion").is_some() {
            let f: FusionLine = serde_json::from_value(v).map_err(bad)?;
            (f.t, AssociationEntry::Fusion(f.fusion))
        } else {
            let keys: Vec<String> = v.as_object().map_or(vec![], |o| o.keys().map(|k| format!("`{k}`")).collect());
            return Err(invalid(
                file,
                Some(i + 1),
                format!(
                    "keys {}: a line needs `observations` (by beams), `observation` (by id) or `fusion`",
                    keys.join(", ")
                ),
            ));
        };
        entries.push((i + 1, entry.0, entry.1));
    }
    Ok(entries)
}

fn csv_invalid(file: &Path, e: csv::Error) -> ScoreError {
    let line = e.position().map(|p| p.line() as usize);
    match e.into_kind() {
        csv::ErrorKind::Io(error) => ScoreError::Io { file: file.to_path_buf(), error },
        kind => invalid(file, line, format!("{kind:?}")),
    }
}

/// A CSV row: its line and its numbers (an empty cell is `None`).
type CsvRow = (usize, Vec<Option<f64>>);

/// A CSV file's rows, and which of `headers` it has.
fn read_csv_numbers(file: &Path, headers: &[&[&str]]) -> Result<(usize, Vec<CsvRow>), ScoreError> {
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .trim(csv::Trim::All)
        .from_path(file)
        .map_err(|e| csv_invalid(file, e))?;
    let found: Vec<String> = reader.headers().map_err(|e| csv_invalid(file, e))?.iter().map(str::to_string).collect();
    let which = headers.iter().position(|h| h.iter().eq(found.iter())).ok_or_else(|| {
        let expected: Vec<String> = headers.iter().map(|h| format!("`{}`", h.join(","))).collect();
        invalid(file, Some(1), format!("header `{}`; expected {}", found.join(","), expected.join(" or ")))
    })?;
    let mut rows = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| csv_invalid(file, e))?;
        let line = record.position().map_or(0, |p| p.line() as usize);
        let values = record
            .iter()
            .zip(headers[which])
            .map(|(cell, name)| match cell {
                "" => Ok(None),
                _ => cell
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .map(Some)
                    .ok_or_else(|| invalid(file, Some(line), format!("`{name}`: `{cell}` is not a finite number"))),
            })
            .collect::<Result<Vec<_>, _>>()?;
        rows.push((line, values));
    }
    Ok((which, rows))
}

/// A whole non-negative number from a CSV cell.
fn csv_count(file: &Path, line: usize, name: &str, v: Option<f64>) -> Result<usize, ScoreError> {
    v.filter(|v| *v >= 0.0 && v.fract() == 0.0 && *v <= u32::MAX as f64)
        .map(|v| v as usize)
        .ok_or_else(|| invalid(file, Some(line), format!("`{name}` must be a whole number, 0 or more")))
}

const CSV_BY_BEAMS: &[&str] = &["t", "first_beam", "last_beam", "landmark"];
const CSV_BY_ID: &[&str] = &["t", "observation", "landmark"];

/// CSV: `t,first_beam,last_beam,landmark` or `t,observation,landmark`, a row per
/// observation (an empty `landmark`: none). Fusions need the JSON-lines form.
fn read_association_csv(file: &Path) -> Result<Vec<(usize, f64, AssociationEntry)>, ScoreError> {
    let (form, rows) = read_csv_numbers(file, &[CSV_BY_BEAMS, CSV_BY_ID])?;
    let mut entries: Vec<(usize, f64, AssociationEntry)> = Vec::new();
    for (line, row) in rows {
        let t = row[0].ok_or_else(|| invalid(file, Some(line), "`t` is empty"))?;
        let landmark = match row[row.len() - 1] {
            None => None,
            v => Some(csv_count(file, line, "landmark", v)? as u32),
        };
        if form == 0 {
            let o = ScoredObservation {
                first_beam: csv_count(file, line, "first_beam", row[1])?,
                last_beam: csv_count(file, line, "last_beam", row[2])?,
                landmark,
            };
            // Rows of one scan make its one entry.
            match entries.last_mut() {
                Some((_, last_t, AssociationEntry::Beams(all, _))) if (*last_t - t).abs() < 1e-6 => all.push(o),
                _ => entries.push((line, t, AssociationEntry::Beams(vec![o], vec![]))),
            }
        } else {
            entries.push((
                line,
                t,
                AssociationEntry::Decision(csv_count(file, line, "observation", row[1])?, landmark),
            ));
        }
    }
    Ok(entries)
}

/// A map: JSON (`[{"id", "position": [x, y]}]`, other keys ignored) or CSV (`id,x,y`).
fn read_landmarks(file: &Path) -> Result<Vec<MapLandmark>, ScoreError> {
    let landmarks: Vec<MapLandmark> = if file.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv")) {
        let (_, rows) = read_csv_numbers(file, &[&["id", "x", "y"]])?;
        rows.into_iter()
            .map(|(line, row)| {
                let id = csv_count(file, line, "id", row[0])? as u32;
                let (Some(x), Some(y)) = (row[1], row[2]) else {
                    return Err(invalid(file, Some(line), "`x` and `y` are needed"));
                };
                Ok(MapLandmark { id, position: [x, y] })
            })
            .collect::<Result<_, _>>()?
    } else {
        slam::settings::from_json(&read_text(file)?).map_err(|e| invalid(file, None, e))?
    };
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

fn read_camera_truth(log: &Path) -> Result<CameraTruth, ScoreError> {
    let file = log.join("trees_shown.jsonl");
    if !file.exists() {
        let frames = read_frames(log)?;
        return Ok(if frames.is_empty() { CameraTruth::None } else { CameraTruth::Frames(frames) });
    }
    #[derive(Deserialize)]
    #[serde(deny_unknown_fields)]
    struct ShownLine {
        t: f64,
        beams: Vec<usize>,
    }
    let mut shown: Vec<(usize, f64, Vec<usize>)> = Vec::new();
    for (i, line) in read_text(&file)?.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let s: ShownLine = serde_json::from_str(line).map_err(|e| invalid(&file, Some(i + 1), e.to_string()))?;
        if let Some((_, last, _)) = shown.last()
            && s.t <= *last
        {
            return Err(invalid(&file, Some(i + 1), format!("scan time {} does not follow {last}", s.t)));
        }
        shown.push((i + 1, s.t, s.beams));
    }
    Ok(CameraTruth::Shown(shown))
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
fn observation_beams(file: &Path, line: usize, text: &str, scan_t: f64) -> Result<Vec<(usize, usize)>, ScoreError> {
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
    if o.t != scan_t {
        return Err(invalid(file, Some(line), format!("t = {} s where the scan of this line has {scan_t} s", o.t)));
    }
    Ok(o.observations.iter().map(|o| (o.first_beam, o.last_beam)).collect())
}

/// The file's only non-empty lines, numbered from 1.
fn numbered_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()).map(|(i, l)| (i + 1, l))
}

/// Whether two paths name the same existing file.
fn same_file(a: &Path, b: &Path) -> bool {
    matches!((a.canonicalize(), b.canonicalize()), (Ok(a), Ok(b)) if a == b)
}

/// Scores `estimate` against the log in `log`: a log of `objslam record`, or the output
/// directory of `objslam run`.
pub fn score_log(log: &Path, estimate: &Estimate) -> Result<ScoredMetrics, ScoreError> {
    let meta = read_metadata(log)?;
    let world = worlds::load(&log.join("world.toml"))?;
    let camera_truth = read_camera_truth(log)?;
    let has_camera = !matches!(camera_truth, CameraTruth::None);
    let basis = estimate.recall_basis.unwrap_or(if has_camera { RecallBasis::InView } else { RecallBasis::LaserSeen });
    let camera =
        has_camera.then(|| crate::run::camera_geometry(&meta.sim, &crate::calibrate::true_extrinsics(&meta.sim)));
    if basis == RecallBasis::InView && camera.is_none() {
        return Err(invalid(
            &log.join("camera.jsonl"),
            None,
            "no camera frames: the recall of trees in view needs them (--recall-basis laser-seen)",
        ));
    }
    let mut scorer = RunScorer::new(&world, camera.clone(), meta.scoring.visibility, basis);

    // A run's output directory names its true path trajectory_gt.tum.
    let truth_file = [log.join("ground_truth.tum"), log.join("trajectory_gt.tum")]
        .into_iter()
        .find(|f| f.exists())
        .unwrap_or_else(|| log.join("ground_truth.tum"));
    let truth = read_tum(&truth_file)?;
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
    // Observations given by id need the log's observations (read with the scans).
    let by_id =
        associations.as_ref().is_some_and(|(_, a)| a.iter().any(|s| matches!(s.observations, Observations::Ids(_))));
    let observations_file = log.join("observations.jsonl");
    let observations_text = if by_id { Some(read_text(&observations_file)?) } else { None };
    let mut observation_lines = observations_text.as_deref().map(numbered_lines);
    let mut next_association = 0usize;
    let mut merged = 0usize;
    let same_instant_s = 0.5 / meta.sim.physics_rate_hz;
    let mut next_frame = 0usize;
    let (laser_file, truth_file) = (log.join("laser.jsonl"), log.join("laser_truth.jsonl"));
    let (laser_text, truth_text) = (read_text(&laser_file)?, read_text(&truth_file)?);
    let mut truth_lines = numbered_lines(&truth_text);
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
        if beams.t != scan.t || beams.beams.hit_ids.len() != scan.ranges.len() {
            return Err(invalid(&truth_file, Some(j), format!("does not match scan at t = {} s", scan.t)));
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
                observation_beams(&observations_file, k, text, scan.t)?
            }
            None => vec![],
        };
        let (observations, fusions): (Vec<ScoredObservation>, &[Fusion]) = match &associations {
            Some((file, scans)) => match scans.get(next_association) {
                Some(a) if (a.t - scan.t).abs() < 1e-6 => {
                    next_association += 1;
                    (scan_observations(file, a, &scan, &log_observations, &observations_file)?, &a.fusions)
                }
                Some(a) if a.t < scan.t => {
                    return Err(invalid(file, Some(a.line), format!("no scan of the log at t = {} s", a.t)));
                }
                _ => (vec![], &[]),
            },
            None => (vec![], &[]),
        };
        merged += fusions.len();
        let shown = match &camera_truth {
            CameraTruth::None => None,
            CameraTruth::Frames(frames) => {
                // The frame of the scan's instant, if the camera fired with it.
                while next_frame < frames.len() && frames[next_frame].t < scan.t - same_instant_s {
                    next_frame += 1;
                }
                match (frames.get(next_frame).filter(|f| (f.t - scan.t).abs() < same_instant_s), &camera) {
                    (Some(f), Some(c)) => {
                        let pixels = read_instance(&f.instance, c.width, c.height)?;
                        let image = InstanceImage {
                            t: f.t,
                            width: c.width,
                            height: c.height,
                            instance: &pixels,
                            columns: None,
                        };
                        Some(scorer.beams_shown(&scan, &beams.beams, &image))
                    }
                    _ => None,
                }
            }
            CameraTruth::Shown(lines) => match lines.get(next_frame) {
                Some((k, t, shown)) if *t == scan.t => {
                    next_frame += 1;
                    if let Some(b) = shown.iter().find(|b| **b >= scan.ranges.len()) {
                        return Err(invalid(
                            &log.join("trees_shown.jsonl"),
                            Some(*k),
                            format!("beam {b} is not within the scan's {} beams", scan.ranges.len()),
                        ));
                    }
                    Some(shown.clone())
                }
                Some((k, t, _)) if *t < scan.t => {
                    return Err(invalid(
                        &log.join("trees_shown.jsonl"),
                        Some(*k),
                        format!("no scan of the log at t = {t} s"),
                    ));
                }
                _ => None,
            },
        };
        scorer.on_scan(&scan, &beams.beams, shown.as_deref(), &observations, fusions);
    }
    if let Some((file, scans)) = &associations
        && let Some(a) = scans.get(next_association)
    {
        return Err(invalid(file, Some(a.line), format!("no scan of the log at t = {} s", a.t)));
    }
    if let CameraTruth::Shown(lines) = &camera_truth
        && let Some((k, t, _)) = lines.get(next_frame)
    {
        return Err(invalid(&log.join("trees_shown.jsonl"), Some(*k), format!("no scan of the log at t = {t} s")));
    }

    let collisions_file = log.join("collisions.jsonl");
    let collisions = numbered_lines(&read_text(&collisions_file)?).count();
    let landmarks = match &estimate.landmarks {
        Some(file) => Some(read_landmarks(file)?),
        None => None,
    };
    let scored = scorer.finish(landmarks.as_deref().unwrap_or(&[]));
    let have_map = landmarks.is_some();
    let have_associations = associations.is_some();
    // A run's own trajectory is scored under the run's method's name.
    let run_method =
        meta.run_method.clone().filter(|_| same_file(&estimate.trajectory, &log.join("trajectory_est.tum")));
    let mut metrics = ScoredMetrics {
        scenario: meta.scoring.scenario.clone(),
        seed: meta.scoring.run_seed.unwrap_or(meta.seed),
        method: estimate.method.clone().or(run_method).unwrap_or_else(|| "external".into()),
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

/// A scan's observations as the scorer takes them: given by beams, checked against the
/// scan; given by id, looked up in the log's observations of the scan.
fn scan_observations(
    file: &Path,
    a: &ScanAssociations,
    scan: &sim::LaserScan,
    log_observations: &[(usize, usize)],
    observations_file: &Path,
) -> Result<Vec<ScoredObservation>, ScoreError> {
    match &a.observations {
        Observations::Beams(all) => {
            if let Some(o) = all.iter().find(|o| o.first_beam > o.last_beam || o.last_beam >= scan.ranges.len()) {
                return Err(invalid(
                    file,
                    Some(a.line),
                    format!(
                        "beams {}..={} are not within the scan's {} beams",
                        o.first_beam,
                        o.last_beam,
                        scan.ranges.len()
                    ),
                ));
            }
            Ok(all.clone())
        }
        Observations::Ids(ids) => {
            let mut sorted = ids.clone();
            sorted.sort_by_key(|(_, id, _)| *id);
            if let Some(w) = sorted.windows(2).find(|w| w[0].1 == w[1].1) {
                return Err(invalid(file, Some(w[1].0), format!("observation {} of this scan a second time", w[1].1)));
            }
            sorted
                .into_iter()
                .map(|(line, id, landmark)| match log_observations.get(id) {
                    Some(&(first_beam, last_beam)) => Ok(ScoredObservation { first_beam, last_beam, landmark }),
                    None => Err(invalid(
                        file,
                        Some(line),
                        format!(
                            "observation {id}: the scan at t = {} s has {} ({})",
                            scan.t,
                            log_observations.len(),
                            observations_file.display()
                        ),
                    )),
                })
                .collect()
        }
    }
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
    fn decisions_and_fusions_group_by_scan_and_out_of_order_entries_are_errors() {
        let dir = std::env::temp_dir().join(format!("objslam-assoc-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("decisions.jsonl");
        let read = |text: &str| {
            std::fs::write(&file, text).unwrap();
            read_associations(&file).map_err(|e| e.to_string())
        };
        let scans = read(concat!(
            r#"{"t": 0.1, "observation": 1, "choice": {"kind": "new", "landmark": 5}, "candidates": [], "method": "nn", "true_object": 3}"#,
            "\n",
            r#"{"t": 0.1, "observation": 0, "landmark": 2}"#,
            "\n",
            r#"{"t": 0.1, "fusion": {"kept": 2, "removed": 5}}"#,
            "\n",
            r#"{"t": 0.2, "observation": 0, "choice": {"kind": "rejected"}}"#,
            "\n"
        ))
        .unwrap();
        assert_eq!(scans.len(), 2);
        let Observations::Ids(first) = &scans[0].observations else { panic!("by id") };
        assert_eq!(first, &[(1, 1, Some(5)), (2, 0, Some(2))]);
        assert_eq!(scans[0].fusions, [Fusion { kept: 2, removed: 5 }]);
        let Observations::Ids(second) = &scans[1].observations else { panic!("by id") };
        assert_eq!(second, &[(4, 0, None)]);

        let e = read(
            "{\"t\": 0.1, \"fusion\": {\"kept\": 2, \"removed\": 5}}\n{\"t\": 0.1, \"observation\": 0, \"landmark\": 2}\n",
        );
        assert!(e.as_ref().is_err_and(|e| e.contains(":2") && e.contains("after its scan's fusions")), "{e:?}");
        let e = read(
            "{\"t\": 0.2, \"observation\": 0, \"landmark\": 2}\n{\"t\": 0.1, \"observation\": 0, \"landmark\": 2}\n",
        );
        assert!(e.as_ref().is_err_and(|e| e.contains(":2") && e.contains("does not follow")), "{e:?}");
        let e = read("{\"t\": 0.1, \"observations\": []}\n{\"t\": 0.1, \"observations\": []}\n");
        assert!(e.as_ref().is_err_and(|e| e.contains(":2") && e.contains("second entry")), "{e:?}");
        let e = read("{\"t\": 0.1, \"observation\": 0, \"landmark\": 2, \"weight\": 1}\n");
        assert!(e.as_ref().is_err_and(|e| e.contains(":1") && e.contains("weight")), "{e:?}");
        std::fs::remove_dir_all(&dir).ok();
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
