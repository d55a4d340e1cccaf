//! `objslam replay`: the `slam` pipeline on a recorded log (a real robot's, or one that
//! `objslam record --format log` wrote), scored against the log's reference path.
//!
//! Inputs are fed in time order; at equal times motion comes first, then the camera's
//! frame, then the scan (as the simulator emits them). Camera frames are read from disk
//! one at a time, and only by the camera methods.
//!
//! Against ground truth the estimate is scored as it is; against GPS, which has its own
//! frame, after the rigid 2-D motion (rotation and translation, no scale) that best fits
//! the estimate to it, once GPS spikes are removed (see [`gps_spikes`]).

mod reference;

use crate::files;
use std::path::{Path, PathBuf};
use std::time::Instant;

pub use reference::{
    GPS_SPIKE_MAX_FIXES, GPS_SPIKE_SPEED_MPS, GpsSpikeFinder, MIN_ALIGNED_SAMPLES, ReferenceScore, gps_spikes,
    rigid_alignment, too_little_within,
};
use reference::{PairStore, ReferencePairs, score_reference};

use robotlog::stream::{LogStream, MotionMessage, ObservationMessage};
use robotlog::{Manifest, ReferenceKind, ReferencePoint};
use serde::Serialize;
use serde_json::json;
use slam::association::{AssociationDecision, AssociationMethod, Choice};
use slam::classifier::AppearanceModel;
use slam::ekf::{AckermannMotionModel, MotionConfig, OdometryMotionModel, RangeBearingModel};
use slam::pipeline::{Appearance, Pipeline, PipelineConfig};

use crate::partial_files::PartialFiles;

/// The longest an observation may come after the log's last motion message (s): see
/// [`ReplayError::MotionEnded`].
const MOTION_GAP_S: f64 = 1.0;

/// Most times as long as the observations (at least 1 s of them) that the motion may last
/// (see [`ReplayError::MotionOutlastsObservations`]): a unit off by a thousand is caught,
/// a laser stopped a while before the odometry is not.
const MOTION_SPAN_RATIO: f64 = 100.0;

/// Errors of a replay.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error(transparent)]
    Log(#[from] robotlog::LogError),
    #[error("{}: holds {what}; a replay's outputs need a directory of their own (or an earlier replay's)", dir.display())]
    HoldsOther { dir: PathBuf, what: String },
    #[error(
        "{}: its frames span {:.3}-{:.3} s and the scans {:.3}-{:.3} s; {outside} of the {count} frames lie outside the scans' times, and a scan is segmented only in a frame at most image_max_age_s ({max_age_s} s) before it. Times on another clock or in another unit need mending; a camera not triggered with the laser needs pipeline.image_max_age_s raised (--config)",
        file.display(), frames.0, frames.1, scans.0, scans.1
    )]
    FramesReachNoScan {
        file: PathBuf,
        frames: (f64, f64),
        scans: (f64, f64),
        outside: usize,
        count: usize,
        max_age_s: f64,
    },
    #[error("{}:{line}: {problem}", file.display())]
    Config { file: PathBuf, line: usize, problem: String },
    #[error("{}: {setting}", file.display())]
    Setting { file: PathBuf, setting: slam::settings::InvalidSetting },
    /// `t` is the log's time when the refusal came; the message names it once.
    #[error("replay{}: {source}", if source.time().is_some() { String::new() } else { format!(" at t = {t} s") })]
    Pipeline { t: f64, source: slam::pipeline::PipelineError },
    #[error("{}: {source}", file.display())]
    Io { file: PathBuf, source: std::io::Error },
    /// The outputs could not all be written, so none replaced the directory's own.
    #[error("{source}; the outputs written are in {}, and the directory's earlier outputs are unchanged", dir.display())]
    Unpublished { dir: PathBuf, source: Box<ReplayError> },
    /// Outputs that could not be moved into the output directory (each was tried).
    #[error("{}", crate::run::join_errors(.0))]
    Publish(Vec<crate::partial_files::PartialFileError>),
    #[error(transparent)]
    Plot(#[from] crate::plot::PlotError),
    #[error(
        "method {method} segments camera images: the log has no camera (a [camera] table and camera.csv); replay it with a method that needs none (--method nn or --method jcbb)"
    )]
    NoCamera { method: &'static str },
    #[error(
        "method {method} segments camera images: the log's camera.csv lists no frame; replay it with a method that needs none (--method nn or --method jcbb)"
    )]
    NoFrames { method: &'static str },
    /// A fault of the log as a whole (its motion against its observations), with the
    /// log's directory.
    #[error("{}: {source}", dir.display())]
    InLog { dir: PathBuf, source: Box<ReplayError> },
    /// Motion that stops while the sensors go on is a cut file, not a vehicle standing
    /// still: odometry comes at tens of hertz, so a second without it is no jitter.
    #[error(
        "the motion ends at t = {motion_end} s while observations go on to t = {t} s (and maybe beyond): a log's motion (a robot log's odometry.csv; Victoria Park's `time` and speeds) must cover what it saw (is the motion file cut short, or are the observations' times on another clock or in milliseconds?)"
    )]
    MotionEnded { motion_end: f64, t: f64 },
    /// Most observations before the motion's first row is motion on another clock or in
    /// another unit: replayed, each would be seen from the start pose. (A laser started a
    /// few seconds before the odometry, the vehicle standing, is no error.)
    #[error(
        "{before} of the {observations} observations come before the motion's first row at t = {motion_start} s: a log's motion (a robot log's odometry.csv; Victoria Park's `time` and speeds) must cover what it saw (are its files on one clock, in seconds?)"
    )]
    MotionStartsLate { before: usize, observations: usize, motion_start: f64 },
    /// Motion that lasts a hundred times as long as the observations is motion in another
    /// unit (odometry in ms beside scans in s: a thousand times): replayed, every
    /// observation would be seen from a pose parked between two of its rows.
    #[error(
        "the motion lasts {motion_s} s (t = {motion_from} to {motion_to} s), more than {MOTION_SPAN_RATIO} times the observations' {observed_s} s (t = {observed_from} to {observed_to} s): a log's motion (a robot log's odometry.csv; Victoria Park's `time` and speeds) must be on the observations' clock, in seconds"
    )]
    MotionOutlastsObservations {
        motion_s: f64,
        motion_from: f64,
        motion_to: f64,
        observed_s: f64,
        observed_from: f64,
        observed_to: f64,
    },
    #[error(
        "method {method} needs an appearance model (`objslam replay --appearance-model FILE`, from `objslam train`, or the log's own appearance_model.json); `--method nn` or `jcbb` needs none"
    )]
    NoAppearanceModel { method: &'static str },
    #[error(transparent)]
    Appearance(#[from] slam::pipeline::AppearanceSetupError),
}

impl From<crate::partial_files::PartialFileError> for ReplayError {
    fn from(e: crate::partial_files::PartialFileError) -> Self {
        ReplayError::Io { file: e.file, source: e.source }
    }
}

/// The settings a replay starts from, before the log's `pipeline.toml` and `--config`:
/// the pipeline's defaults with the log's vehicle and sensor, and the rules a real sensor
/// at tens of metres needs (a landmark confirmed by three sightings within five seconds,
/// new landmarks only far from every known one, one filter update per scan). The
/// detectors' diameters stay off as a cue: on Victoria Park's first half they changed
/// nothing (docs/results.md#victoria-park).
pub fn default_config(manifest: &Manifest, method: AssociationMethod) -> PipelineConfig {
    let vehicle = &manifest.vehicle;
    let motion = match vehicle.motion.as_str() {
        "ackermann" => {
            let d = AckermannMotionModel::default();
            MotionConfig::Ackermann(AckermannMotionModel {
                wheelbase_m: vehicle.wheelbase_m.unwrap_or(d.wheelbase_m),
                encoder_offset_m: vehicle.encoder_offset_m.unwrap_or(d.encoder_offset_m),
                ..d
            })
        }
        _ => MotionConfig::Odometry(OdometryMotionModel::default()),
    };
    // Outdoor trees at up to 30 m from a detector's circle fit: decimetres and a degree
    // and a half.
    let sensor_defaults = RangeBearingModel {
        range_sigma_m: 0.3,
        range_sigma_per_m: 0.0,
        bearing_sigma_rad: 1.5f64.to_radians(),
        ..Default::default()
    };
    PipelineConfig {
        method,
        motion,
        sensor: manifest.observation_model(&sensor_defaults),
        new_landmark_probability: 0.9999,
        confirm_observations: 3,
        confirm_window_s: 5.0,
        batch_updates: true,
        ..Default::default()
    }
}

/// The replay's settings: [`default_config`], then the log's `pipeline.toml` if it has one,
/// then `overrides` (a TOML file of `[pipeline]` keys, as in a scenario), each replacing
/// only the keys it names.
pub fn resolve_config(
    log_dir: Option<&Path>,
    manifest: &Manifest,
    method: Option<AssociationMethod>,
    overrides: Option<&Path>,
) -> Result<PipelineConfig, ReplayError> {
    let base = default_config(manifest, method.unwrap_or(AssociationMethod::Nn));
    let mut value = toml::Value::try_from(&base).map_err(|e| ReplayError::Config {
        file: log_dir.map_or_else(|| PathBuf::from("manifest.toml"), |d| d.join("manifest.toml")),
        line: 1,
        problem: format!("the settings it gives cannot be written: {e}"),
    })?;
    // Where the motion model was last set: a model that cannot read the log's motion is
    // that file's error, found before the replay starts.
    let mut motion_set_in: Option<(PathBuf, usize)> = None;
    // Where each of the sensor's mounting keys was last set: it must be the log's own,
    // which places the path written and scored.
    let mut mount_set_in: [Option<(PathBuf, usize)>; 2] = [None, None];
    let mut files = Vec::new();
    if let Some(dir) = log_dir
        && dir.join(files::PIPELINE).exists()
    {
        // One of the log's data files: a pipe or a device there would never end.
        robotlog::format::regular_file(&dir.join(files::PIPELINE))?;
        files.push(dir.join(files::PIPELINE));
    }
    files.extend(overrides.map(Path::to_path_buf));
    for file in &files {
        let text = std::fs::read_to_string(file).map_err(|source| ReplayError::Io { file: file.clone(), source })?;
        let table: toml::Table = toml::from_str(&text).map_err(|e| ReplayError::Config {
            file: file.clone(),
            line: e.span().map_or(1, |s| text[..s.start].matches('\n').count() + 1),
            problem: e.message().to_string(),
        })?;
        // A scenario-style file holds the keys under [pipeline]; a bare file at the top.
        let (table, under): (_, &[&str]) = match table.get("pipeline") {
            Some(toml::Value::Table(t)) => {
                if let Some(other) = table.keys().find(|k| *k != "pipeline") {
                    return Err(ReplayError::Config {
                        file: file.clone(),
                        line: toml_strict::line_of(&text, other).unwrap_or(1),
                        problem: format!(
                            "{other}: a replay reads pipeline settings only, so a file with [pipeline] may hold nothing else (a scenario's other tables describe its simulation)"
                        ),
                    });
                }
                (t.clone(), &["pipeline"])
            }
            _ => (table, &[]),
        };
        for (k, key) in ["mount_x", "mount_y"].into_iter().enumerate() {
            if table.get("sensor").and_then(|s| s.get(key)).is_some() {
                let at: Vec<&str> = under.iter().copied().chain(["sensor", key]).collect();
                mount_set_in[k] = Some((file.clone(), toml_strict::line_of_path(&text, &at).unwrap_or(1)));
            }
        }
        // Another motion model replaces the whole table: the two models' keys differ.
        let new_model = table.get("motion").and_then(|m| m.get("model")).cloned();
        if new_model.is_some() {
            let at: Vec<&str> = under.iter().copied().chain(["motion", "model"]).collect();
            motion_set_in = Some((file.clone(), toml_strict::line_of_path(&text, &at).unwrap_or(1)));
        }
        if let (Some(new), Some(motion)) = (new_model, value.get_mut("motion"))
            && motion.get("model") != Some(&new)
        {
            *motion = toml::Value::Table(toml::Table::new());
        }
        merge(&mut value, toml::Value::Table(table));
        let config: PipelineConfig =
            toml_strict::from_value(value.clone(), &text, under).map_err(|e| ReplayError::Config {
                file: file.clone(),
                line: e.line.unwrap_or(1),
                problem: match e.key {
                    Some(key) => format!("{key}: {}", e.message),
                    None => e.message,
                },
            })?;
        config.validate().map_err(|setting| ReplayError::Setting { file: file.clone(), setting })?;
    }
    let mut config: PipelineConfig = value.try_into().expect("checked above");
    let mounts = [
        ("mount_x", config.sensor.mount_x, "x_m", manifest.sensor.x_m),
        ("mount_y", config.sensor.mount_y, "y_m", manifest.sensor.y_m),
    ];
    for ((key, set, manifest_key, logged), set_in) in mounts.into_iter().zip(mount_set_in) {
        if let Some((file, line)) = set_in.filter(|_| (set - logged).abs() > 1e-9) {
            return Err(ReplayError::Config {
                file,
                line,
                problem: format!(
                    "sensor.{key} = {set} disagrees with the log's manifest.toml, whose [sensor] {manifest_key} = {logged}: the mounting is the log's, which also places the path written and scored; leave it out or mend the manifest"
                ),
            });
        }
    }
    let car_log = manifest.vehicle.motion == "ackermann";
    if let Some((file, line)) = motion_set_in.filter(|_| matches!(config.motion, MotionConfig::Ackermann(_)) != car_log)
    {
        return Err(ReplayError::Config {
            file,
            line,
            problem: format!(
                "pipeline.motion.model = \"{}\" cannot read this log's motion: its manifest.toml says vehicle.motion = \"{}\" ({}); leave the model out to use the log's",
                config.motion.name(),
                manifest.vehicle.motion,
                if car_log {
                    "speed and steering controls"
                } else {
                    "odometry increments or a differential drive's controls"
                }
            ),
        });
    }
    if let Some(m) = method {
        config.method = m;
    }
    Ok(config)
}

/// Replaces the keys of `base` that `over` names, table by table.
fn merge(base: &mut toml::Value, over: toml::Value) {
    match (base, over) {
        (toml::Value::Table(b), toml::Value::Table(o)) => {
            for (k, v) in o {
                match b.get_mut(&k) {
                    Some(existing @ toml::Value::Table(_)) if v.is_table() => merge(existing, v),
                    _ => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (b, o) => *b = o,
    }
}

/// Time per scan (ms).
#[derive(Debug, Clone, Serialize)]
pub struct ScanTimes {
    pub mean: f64,
    pub p50: f64,
    pub p95: f64,
    pub max: f64,
}

/// The filter's consistency on its own associations: the normalised innovation squared of
/// each observation paired with a landmark (2 dof: 2 on average when consistent).
#[derive(Debug, Clone, Serialize)]
pub struct Nis {
    pub observations: usize,
    pub mean: f64,
    /// Fraction under the chi-square 95% quantile (0.95 when consistent).
    pub within_95: f64,
}

/// What `metrics.json` of a replay holds (docs/guide/real-logs.md).
#[derive(Debug, Clone, Serialize)]
pub struct ReplayMetrics {
    pub log: String,
    pub method: String,
    pub log_seconds: f64,
    pub motion_messages: usize,
    pub scans: usize,
    /// Scans (or detection sets) before the motion's first row, replayed from the start
    /// pose: a laser started before the odometry, with the vehicle standing, or not.
    pub scans_before_motion: usize,
    /// Scans (or detection sets) more than [`MOTION_GAP_S`] after the motion row before
    /// them, with motion rows after them: a gap in the motion, which the next row bridges
    /// (a control held, an increment over the whole gap) or which is rows lost.
    pub scans_in_motion_gaps: usize,
    pub detections: usize,
    /// Beams of whole scans that returned within the laser's `[range_min_m, range_max_m]`
    /// (null for a log of detections): 0 over every scan is ranges in another unit, or a
    /// sensor that saw nothing.
    pub returns_in_range: Option<usize>,
    /// Detections farther than [`DETECTION_REACH_M`] or wider than [`TRUNK_DIAMETER_MAX_M`]
    /// (null for a log of whole scans): more than none is ranges or diameters in another
    /// unit (millimetres), which the filter would take as metres.
    pub detections_beyond_reach: Option<usize>,
    /// Camera frames given to the pipeline (the camera methods'; 0 for the others).
    pub camera_frames: usize,
    /// The appearance model the camera methods used (null for the others).
    pub appearance_model: Option<crate::run::ModelProvenance>,
    pub landmarks: usize,
    pub reference: Option<ReferenceScore>,
    pub nis: Nis,
    pub time_per_scan_ms: ScanTimes,
    pub wall_seconds: f64,
    pub real_time_factor: f64,
    /// Peak resident memory of the process (MB; Linux), or null.
    pub peak_memory_mb: Option<f64>,
}

/// A replay's figures and map. Its trajectory and decisions are not kept: with an output
/// directory they go to `trajectory_est.tum` and `decisions.jsonl` as the replay goes, so
/// that its memory does not grow with the log's length.
pub struct Replay {
    pub metrics: ReplayMetrics,
    pub landmarks: Vec<slam::pipeline::Landmark>,
    pub config: PipelineConfig,
    /// The path of the reference point, thinned for the map picture (see [`ThinnedPath`]).
    pub path: Vec<[f64; 2]>,
}

/// The outputs a replay writes as it goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stream {
    Trajectory,
    Decisions,
}

/// Runs `config`'s pipeline over `log`; with `out`, writes the replay's outputs there
/// (`metrics.json`, `metadata.json`, `trajectory_est.tum`, `landmarks.json`,
/// `decisions.jsonl`, `map.png`). The camera methods need the log's camera and an
/// `appearance` model; the others ignore both. The log's motion and scans are taken a
/// message at a time ([`robotlog::format::open`] reads them from disk as they come).
pub fn replay(
    log: impl Into<LogStream>,
    config: PipelineConfig,
    appearance: Option<AppearanceModel>,
    out: Option<&Path>,
) -> Result<Replay, ReplayError> {
    replay_from(log, None, config, appearance, out)
}

/// [`replay`] of a log read from `source`, which `metadata.json` names so that the replay
/// can be traced to its data.
pub fn replay_from(
    log: impl Into<LogStream>,
    source: Option<&LogSource>,
    config: PipelineConfig,
    appearance: Option<AppearanceModel>,
    out: Option<&Path>,
) -> Result<Replay, ReplayError> {
    if let Some(dir) = out {
        refuse_other_outputs(dir)?;
    }
    // Held until the outputs are published or abandoned.
    let lock = out.map(crate::partial_files::lock_output).transpose()?;
    let replayed = replay_and_write(log.into(), source, config, appearance, out);
    crate::partial_files::abandon_if_failed(lock, out, replayed)
}

/// Where a replayed log was read: its directory and the data files read there, each with
/// its SHA-256 as the replay found it (`None`: unreadable).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LogSource {
    pub dir: PathBuf,
    pub files: Vec<SourceFile>,
}

/// A file of a [`LogSource`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SourceFile {
    pub name: String,
    pub sha256: Option<String>,
}

impl LogSource {
    /// The files of `names` that `dir` holds, with their digests.
    pub fn of(dir: &Path, names: &[&str]) -> LogSource {
        let files = names
            .iter()
            .filter(|name| dir.join(name).is_file())
            .map(|name| SourceFile { name: name.to_string(), sha256: files::sha256_hex(&dir.join(name)) })
            .collect();
        LogSource { dir: std::path::absolute(dir).unwrap_or_else(|_| dir.to_path_buf()), files }
    }

    /// The files of a robot log that a replay reads: the log's own, its `pipeline.toml`,
    /// and its appearance model where `own_model` (a camera method given no other); camera
    /// images apart, which `camera.csv` names. A recording's other files are not read.
    pub fn of_robot_log(dir: &Path, own_model: bool) -> LogSource {
        use robotlog::format as f;
        let mut names =
            vec![f::MANIFEST, f::ODOMETRY, f::SCANS, f::DETECTIONS, f::REFERENCE, f::CAMERA, files::PIPELINE];
        if own_model {
            names.push(files::APPEARANCE_MODEL);
        }
        Self::of(dir, &names)
    }
}

/// Every name a replay writes in its output directory.
const REPLAY_OUTPUTS: &[&str] =
    &[files::METRICS, files::METADATA, files::LANDMARKS, files::TRAJECTORY_EST, files::DECISIONS, files::MAP];

/// Refuses an output directory that holds a robot log, or another command's outputs (a
/// run's, a recording's): the replay's files would sit among theirs, and read as one.
/// An earlier replay's outputs are replaced as usual.
fn refuse_other_outputs(dir: &Path) -> Result<(), ReplayError> {
    let holds = |what: String| Err(ReplayError::HoldsOther { dir: dir.to_path_buf(), what });
    if dir.join(robotlog::format::MANIFEST).exists() {
        return holds("a robot log (manifest.toml)".into());
    }
    if let Some(name) = files::first_present(dir, robotlog::victoria_park::FILES) {
        return holds(format!("a data set's files ({name})"));
    }
    // Outputs whose marker is not a metadata.json.
    if dir.join("metadata.yaml").exists() {
        return holds("a ROS 2 bag (metadata.yaml)".into());
    }
    if dir.join("dataset.json").exists() {
        return holds("the images of `objslam dataset` (dataset.json)".into());
    }
    if std::fs::symlink_metadata(dir.join(files::METADATA)).is_err() {
        // Files of a replay's names with no replay's marker are someone's own.
        return match files::first_present(dir, REPLAY_OUTPUTS) {
            Some(name) => holds(format!(
                "{name}, which a replay writes, but no earlier replay ({} is missing): it would be replaced (if a stopped replay left it, remove it)",
                files::METADATA
            )),
            None => Ok(()),
        };
    }
    let Ok(text) = std::fs::read_to_string(dir.join(files::METADATA)) else { return Ok(()) };
    let tool = serde_json::from_str::<serde_json::Value>(&text)
        .ok()
        .and_then(|v| v.get("tool").and_then(|t| t.as_str()).map(str::to_owned));
    match tool.as_deref() {
        Some(REPLAY_TOOL) => Ok(()),
        Some(other) => holds(format!("the outputs of `{other}` (metadata.json)")),
        None => holds("another command's outputs (a metadata.json of no replay)".into()),
    }
}

/// Refuses camera frames that a camera method could not have used: none came within
/// `max_age_s` before any scan (a camera not triggered with the laser needs the setting
/// raised), or most lie outside the scans' times (camera.csv on another clock or in
/// another unit). Either would replay to an empty map with no word of why.
fn check_frame_times(
    file: &Path,
    frames: &[f64],
    scans: Option<(f64, f64)>,
    scans_with_frame: usize,
    max_age_s: f64,
) -> Result<(), ReplayError> {
    let (Some(&first), Some(&last), Some((from, to))) = (frames.first(), frames.last(), scans) else { return Ok(()) };
    let outside = frames.iter().filter(|&&t| t < from - max_age_s || t > to + max_age_s).count();
    if scans_with_frame == 0 || 2 * outside > frames.len() {
        return Err(ReplayError::FramesReachNoScan {
            file: file.to_path_buf(),
            frames: (first, last),
            scans: (from, to),
            outside,
            count: frames.len(),
            max_age_s,
        });
    }
    Ok(())
}

/// `e` with the directory of the log it is about, where the log came from one.
fn in_log(source: Option<&LogSource>, e: ReplayError) -> ReplayError {
    match source {
        Some(s) => ReplayError::InLog { dir: s.dir.clone(), source: Box::new(e) },
        None => e,
    }
}

/// The `tool` a replay's `metadata.json` names.
const REPLAY_TOOL: &str = "objslam replay";

fn replay_and_write(
    log: LogStream,
    source: Option<&LogSource>,
    config: PipelineConfig,
    appearance: Option<AppearanceModel>,
    out: Option<&Path>,
) -> Result<Replay, ReplayError> {
    let started = Instant::now();
    let mut log = log;
    // The observations first: a fault in their first rows is the log's first fault, and
    // the motion's first row is read against their start.
    let first_observation = robotlog::stream::next_time(&mut log.observations, ObservationMessage::time)?;
    let first_motion = robotlog::stream::next_time(&mut log.motion, MotionMessage::time)?;
    // The log's first instant: its first motion message or scan.
    let start = match (first_motion, first_observation) {
        (Some(a), Some(b)) => a.min(b),
        (a, b) => a.or(b).unwrap_or(0.0),
    };
    let camera = match config.method.uses_appearance() {
        true => {
            let method = config.method.name();
            let (Some(geometry), Some(camera)) = (log.manifest.camera_geometry(), log.manifest.camera.as_ref()) else {
                return Err(ReplayError::NoCamera { method });
            };
            if log.camera.is_empty() {
                return Err(ReplayError::NoFrames { method });
            }
            let model = appearance.ok_or(ReplayError::NoAppearanceModel { method })?;
            let provenance = crate::run::ModelProvenance::of(&model);
            Some(((Appearance::new(model, geometry)?, provenance), camera))
        }
        false => None,
    };
    let (appearance, camera) = camera.unzip();
    let (appearance, model_provenance) = appearance.unzip();
    // Frames only reach the methods that read them.
    let (mut frames, camera_frames): (robotlog::stream::Messages<robotlog::CameraFrameFile>, usize) = match camera {
        Some(_) => (log.camera.rows()?.peekable(), log.camera.len()),
        None => (robotlog::stream::Rows::peekable(Box::new(std::iter::empty())), 0),
    };
    let mut pipeline = Pipeline::new(config.clone(), log.manifest.vehicle.start_pose, appearance)
        .and_then(|p| p.starting_at(start))
        .map_err(|source| ReplayError::Pipeline { t: start, source })?;
    // Every output is written in the unfinished directory and moved into `out` when all are
    // (another command's finished outputs waiting there are not dropped for it).
    if let Some(out) = out {
        crate::partial_files::check_no_other_stopped_move(out, &[])?;
    }
    let unfinished = out.map(crate::partial_files::start_unfinished).transpose()?;
    let mut streams = match &unfinished {
        Some(dir) => Some(PartialFiles::create(
            dir,
            &[(Stream::Trajectory, files::TRAJECTORY_EST), (Stream::Decisions, files::DECISIONS)],
        )?),
        None => None,
    };
    if let Some(s) = &mut streams {
        s.write(Stream::Trajectory, crate::record::TUM_HEADER)?;
    }
    let point = log.manifest.reference.as_ref().map_or(ReferencePoint::Vehicle, |r| r.point);
    let mount = [log.manifest.sensor.x_m, log.manifest.sensor.y_m];
    let at_point = |p: [f64; 3]| match point {
        ReferencePoint::Vehicle => p,
        ReferencePoint::Sensor => {
            let (s, c) = p[2].sin_cos();
            [p[0] + c * mount[0] - s * mount[1], p[1] + s * mount[0] + c * mount[1], p[2]]
        }
    };
    // The reference is read twice: now for its spikes, then as the poses reach it.
    let scored = log.manifest.reference.as_ref().filter(|_| !log.reference.is_empty());
    let spikes = match scored {
        Some(r) if r.kind == ReferenceKind::Gps => {
            let mut finder = GpsSpikeFinder::new(GPS_SPIKE_SPEED_MPS);
            for sample in log.reference.rows()? {
                finder.push(sample?);
            }
            finder.finish()
        }
        _ => Vec::new(),
    };
    let spikes_removed = spikes.len();
    let pairs = match &unfinished {
        Some(dir) => PairStore::on_disk(&dir.join(PAIRS_FILE))?,
        None => PairStore::in_memory(),
    };
    let samples = match scored {
        Some(_) => log.reference.rows()?,
        None => Box::new(std::iter::empty()),
    };
    let mut reference = ReferencePairs::new(samples, spikes, pairs);
    let mut path = ThinnedPath::default();
    let mut nis = NisSums::default();
    let mut scan_ms = ScanTimeHistogram::default();
    let yaw = log.manifest.sensor.yaw_rad;
    let (mut detections, mut motion_messages, mut scans, mut end) = (0, 0, 0, start);
    let mut returns_in_range: Option<usize> = None;
    let mut detections_beyond_reach: Option<usize> = None;
    let mut motion_end = start;
    // Whether the motion is on the observations' clock (see MotionStartsLate and
    // MotionOutlastsObservations, with the observations' span below): observations before
    // its first row, and its first row's time.
    let (mut before_motion, mut first_motion, mut in_motion_gaps) = (0usize, None::<f64>, 0usize);
    // The time of the trajectory's last pose (written to its file where there is one).
    let mut last_written: Option<f64> = None;
    // The frames' and scans' times, and the scans a frame was recent enough for: frames on
    // another clock or in another unit reach no scan, which a camera method cannot tell
    // from a camera that saw nothing.
    let (mut frame_times, mut scan_span): (Vec<f64>, Option<(f64, f64)>) = (Vec::new(), None);
    let (mut last_frame_t, mut scans_with_frame) = (None::<f64>, 0usize);
    let error = |t: f64| move |source| ReplayError::Pipeline { t, source };
    loop {
        // At equal times: motion, then the frame, then the scan.
        let tm = robotlog::stream::next_time(&mut log.motion, MotionMessage::time)?;
        let tf = robotlog::stream::next_time(&mut frames, |frame| frame.t)?;
        let to = robotlog::stream::next_time(&mut log.observations, ObservationMessage::time)?;
        if tm.is_none() && tf.is_none() && to.is_none() {
            break;
        }
        // Whether input a comes before input b (None: its stream is done).
        let first = |a: Option<f64>, b: Option<f64>| match (a, b) {
            (Some(a), Some(b)) => a <= b,
            (a, b) => a.is_some() || b.is_none(),
        };
        if tm.is_some() && first(tm, tf) && first(tm, to) {
            let Some(Ok(message)) = log.motion.next() else { unreachable!("peeked a message") };
            let t = message.time();
            match message {
                MotionMessage::Increment(o) => pipeline.on_odometry(&o).map_err(error(t))?,
                MotionMessage::Control { t, control } => pipeline.on_control(t, control).map_err(error(t))?,
            }
            motion_messages += 1;
            end = end.max(t);
            motion_end = t;
            first_motion.get_or_insert(t);
        } else if let (Some(tf), true) = (tf, first(tf, to)) {
            let camera = camera.expect("frames only with a camera");
            let Some(Ok(frame)) = frames.next() else { unreachable!("peeked a frame") };
            let image = robotlog::format::read_frame(&frame, camera)?;
            pipeline.on_image(tf, image.width, image.height, image.rgb).map_err(error(tf))?;
            frame_times.push(tf);
            last_frame_t = Some(tf);
            // A frame moves no pose: nothing to write.
            continue;
        } else {
            let Some(Ok(message)) = log.observations.next() else { unreachable!("peeked a message") };
            let t = message.time();
            if tm.is_none() && motion_messages > 0 && t > motion_end + MOTION_GAP_S {
                return Err(in_log(source, ReplayError::MotionEnded { motion_end, t }));
            }
            if motion_messages == 0 && tm.is_some_and(|first| t < first) {
                before_motion += 1;
            }
            if motion_messages > 0 && tm.is_some() && t > motion_end + MOTION_GAP_S {
                in_motion_gaps += 1;
            }
            let tick = Instant::now();
            let report = match message {
                // Beams in the vehicle's frame: the laser may look sideways.
                ObservationMessage::Scan(scan) => {
                    let returned =
                        scan.ranges.iter().filter(|r| r.is_finite() && (scan.range_min..=scan.range_max).contains(*r));
                    *returns_in_range.get_or_insert(0) += returned.count();
                    let turned = slam::messages::LaserScan { angle_min: scan.angle_min + yaw, ..scan };
                    pipeline.on_scan(&turned).map_err(error(t))?
                }
                ObservationMessage::Detections(scan) => {
                    detections += scan.detections.len();
                    let beyond = scan.detections.iter().filter(|d| {
                        d.range_m > DETECTION_REACH_M || d.diameter_m.is_some_and(|w| w > TRUNK_DIAMETER_MAX_M)
                    });
                    *detections_beyond_reach.get_or_insert(0) += beyond.count();
                    // Bearings in the vehicle's frame: the sensor may look sideways.
                    let turned: Vec<_> = scan
                        .detections
                        .iter()
                        .map(|d| slam::messages::Detection { bearing_rad: d.bearing_rad + yaw, ..*d })
                        .collect();
                    pipeline.on_detections(t, &turned).map_err(error(t))?
                }
            };
            scan_ms.add(tick.elapsed().as_secs_f64() * 1e3);
            scan_span = Some(scan_span.map_or((t, t), |(a, b): (f64, f64)| (a.min(t), b.max(t))));
            scans_with_frame += usize::from(last_frame_t.is_some_and(|f| t - f <= config.image_max_age_s));
            nis.add(&report.decisions);
            if let Some(s) = &mut streams {
                for d in &report.decisions {
                    s.write(Stream::Decisions, &(serde_json::to_string(d).expect("JSON") + "\n"))?;
                }
            }
            scans += 1;
            end = end.max(t);
        }
        let p = pipeline.pose();
        let pose = at_point(p.pose);
        // One pose a time (a TUM file's times increase): at a time of motion and a scan,
        // the pose after the motion, as `objslam run` writes it; the scan moves the next.
        // The reference is scored against the poses written, so that the ATE is the
        // trajectory file's.
        if last_written.is_none_or(|t| t < p.t) {
            reference.on_pose(p.t, [pose[0], pose[1]])?;
            path.push([pose[0], pose[1]]);
            if let Some(s) = &mut streams {
                s.write(Stream::Trajectory, &(crate::record::tum_line(p.t, pose[0], pose[1], pose[2]) + "\n"))?;
            }
            last_written = Some(p.t);
        }
    }
    if let Some(motion_start) = first_motion
        && 2 * before_motion > scans
    {
        return Err(in_log(
            source,
            ReplayError::MotionStartsLate { before: before_motion, observations: scans, motion_start },
        ));
    }
    if let (Some(motion_from), Some((observed_from, observed_to))) = (first_motion, scan_span) {
        let (motion_s, observed_s) = (motion_end - motion_from, observed_to - observed_from);
        if motion_s > MOTION_SPAN_RATIO * observed_s.max(1.0) {
            return Err(in_log(
                source,
                ReplayError::MotionOutlastsObservations {
                    motion_s,
                    motion_from,
                    motion_to: motion_end,
                    observed_s,
                    observed_from,
                    observed_to,
                },
            ));
        }
    }
    let camera_file = log.camera.file().unwrap_or(Path::new("camera.csv"));
    check_frame_times(camera_file, &frame_times, scan_span, scans_with_frame, config.image_max_age_s)?;
    let mut paired = reference.finish()?;
    let wall_seconds = started.elapsed().as_secs_f64();
    let log_seconds = end - start;
    let landmarks = pipeline.mapped_landmarks();
    let metrics = ReplayMetrics {
        log: log.manifest.name.clone(),
        method: config.method.name().to_string(),
        log_seconds,
        motion_messages,
        scans,
        scans_before_motion: before_motion,
        scans_in_motion_gaps: in_motion_gaps,
        detections,
        returns_in_range,
        detections_beyond_reach,
        camera_frames,
        appearance_model: model_provenance,
        landmarks: landmarks.len(),
        reference: match scored {
            Some(r) => Some(score_reference(r.kind, r.point, log.reference.len(), spikes_removed, &mut paired.pairs)?),
            None => None,
        },
        nis: nis.finish(),
        time_per_scan_ms: scan_ms.finish(),
        wall_seconds,
        real_time_factor: log_seconds / wall_seconds.max(1e-9),
        peak_memory_mb: peak_memory_mb(),
    };
    // The pairs' file goes before the outputs are published.
    drop(paired.pairs);
    let result = Replay { metrics, landmarks, config, path: path.points() };
    if let (Some(dir), Some(unfinished), Some(streams)) = (out, unfinished, streams) {
        streams.finish()?;
        write_outputs(&unfinished, &log.manifest, source, (&paired.drawn, &paired.dropped), &result)
            .map_err(|e| ReplayError::Unpublished { dir: unfinished.clone(), source: Box::new(e) })?;
        crate::partial_files::publish(&unfinished, dir, &[], files::METADATA).map_err(ReplayError::Publish)?;
    }
    Ok(result)
}

/// The file in a replay's unfinished directory that holds the (estimate, reference) pairs
/// until they are scored (removed before the outputs are published).
const PAIRS_FILE: &str = "reference_pairs.scratch";

/// Most points of the path kept for the map picture.
const MAP_PATH_POINTS: usize = 20_000;

/// A path thinned as it comes, so that a log of any length keeps at most
/// [`MAP_PATH_POINTS`]: a point is kept when it lies `step` from the last kept, and when
/// too many are kept, every other one goes and `step` doubles. Starting at 1 cm, a path of
/// 200 m keeps every centimetre; Victoria Park's 4 km, every 20 cm or so, far below a
/// picture's pixel.
struct ThinnedPath {
    kept: Vec<[f64; 2]>,
    step: f64,
    last: Option<[f64; 2]>,
}

impl Default for ThinnedPath {
    fn default() -> Self {
        ThinnedPath { kept: Vec::new(), step: 0.01, last: None }
    }
}

impl ThinnedPath {
    fn push(&mut self, p: [f64; 2]) {
        self.last = Some(p);
        if let Some(k) = self.kept.last()
            && (p[0] - k[0]).hypot(p[1] - k[1]) < self.step
        {
            return;
        }
        self.kept.push(p);
        if self.kept.len() > MAP_PATH_POINTS {
            let mut i = 0;
            self.kept.retain(|_| {
                i += 1;
                i % 2 == 1
            });
            self.step *= 2.0;
        }
    }

    /// The kept points and the path's last point.
    fn points(mut self) -> Vec<[f64; 2]> {
        if let Some(p) = self.last
            && self.kept.last() != Some(&p)
        {
            self.kept.push(p);
        }
        self.kept
    }
}

/// The running NIS of the filter's own associations.
#[derive(Default)]
struct NisSums {
    n: usize,
    sum: f64,
    within_95: usize,
}

impl NisSums {
    fn add(&mut self, decisions: &[AssociationDecision]) {
        let q95 = slam::association::chi2_quantile(2, 0.95).expect("a quantile at 2 dof and 0.95 exists");
        for d in decisions {
            if let Choice::Existing { landmark } = d.choice
                && let Some(c) = d.candidates.iter().find(|c| c.landmark == landmark)
            {
                self.n += 1;
                self.sum += c.mahalanobis2;
                self.within_95 += (c.mahalanobis2 <= q95) as usize;
            }
        }
    }

    fn finish(&self) -> Nis {
        let n = self.n;
        Nis {
            observations: n,
            mean: if n > 0 { self.sum / n as f64 } else { f64::NAN },
            within_95: if n > 0 { self.within_95 as f64 / n as f64 } else { f64::NAN },
        }
    }
}

/// Times per scan in bins 2% wide from 1 us up, so that a log of any length takes the same
/// memory: the mean and the maximum are exact, the quantiles to 2%.
struct ScanTimeHistogram {
    bins: Vec<u64>,
    n: u64,
    sum: f64,
    max: f64,
}

/// The histogram's first bin starts here (ms); each is this factor wider than the last.
const SCAN_TIME_FLOOR_MS: f64 = 1e-3;
const SCAN_TIME_BIN_RATIO: f64 = 1.02;

impl Default for ScanTimeHistogram {
    fn default() -> Self {
        // Up to 1e8 times the floor: 100 s.
        let bins = (1e8f64.ln() / SCAN_TIME_BIN_RATIO.ln()).ceil() as usize + 1;
        ScanTimeHistogram { bins: vec![0; bins], n: 0, sum: 0.0, max: 0.0 }
    }
}

impl ScanTimeHistogram {
    fn add(&mut self, ms: f64) {
        let bin = ((ms.max(SCAN_TIME_FLOOR_MS) / SCAN_TIME_FLOOR_MS).ln() / SCAN_TIME_BIN_RATIO.ln()) as usize;
        let last = self.bins.len() - 1;
        self.bins[bin.min(last)] += 1;
        self.n += 1;
        self.sum += ms;
        self.max = self.max.max(ms);
    }

    /// The `p` quantile: the geometric middle of its bin, at most the maximum.
    fn quantile(&self, p: f64) -> f64 {
        let rank = ((self.n - 1) as f64 * p).round() as u64;
        let mut seen = 0;
        for (i, count) in self.bins.iter().enumerate() {
            seen += count;
            if seen > rank {
                return (SCAN_TIME_FLOOR_MS * SCAN_TIME_BIN_RATIO.powf(i as f64 + 0.5)).min(self.max);
            }
        }
        self.max
    }

    fn finish(&self) -> ScanTimes {
        if self.n == 0 {
            return ScanTimes { mean: 0.0, p50: 0.0, p95: 0.0, max: 0.0 };
        }
        ScanTimes { mean: self.sum / self.n as f64, p50: self.quantile(0.5), p95: self.quantile(0.95), max: self.max }
    }
}

/// Peak resident memory (VmHWM) of this process, in MB.
fn peak_memory_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// Writes a replay's outputs into `out` beside the streamed ones: `metrics.json`,
/// `metadata.json` (the resolved settings), `landmarks.json` and `map.png`.
fn write_outputs(
    out: &Path,
    manifest: &Manifest,
    source: Option<&LogSource>,
    (reference, dropped): (&[[f64; 2]], &[[f64; 2]]),
    replay: &Replay,
) -> Result<(), ReplayError> {
    let write = |name: &str, text: String| {
        let file = out.join(name);
        std::fs::write(&file, text).map_err(|source| ReplayError::Io { file, source })
    };
    write(files::METRICS, serde_json::to_string_pretty(&replay.metrics).expect("JSON"))?;
    write(
        files::METADATA,
        serde_json::to_string_pretty(&json!({
            "tool": REPLAY_TOOL,
            "version": env!("CARGO_PKG_VERSION"),
            "build": crate::build::current(),
            "log": manifest,
            "source": source,
            "configuration": replay.config,
            "appearance_model": replay.metrics.appearance_model,
        }))
        .expect("JSON"),
    )?;
    write(files::LANDMARKS, serde_json::to_string_pretty(&replay.landmarks).expect("JSON"))?;
    // The map in the reference's frame: the estimate moved by the alignment (as it is
    // where no alignment could be fitted).
    let (theta, t) = replay
        .metrics
        .reference
        .as_ref()
        .filter(|r| r.alignment_rotation_rad.is_finite())
        .map_or((0.0, [0.0, 0.0]), |r| (r.alignment_rotation_rad, r.alignment_translation_m));
    let (s, c) = theta.sin_cos();
    let moved = |p: [f64; 2]| [c * p[0] - s * p[1] + t[0], s * p[0] + c * p[1] + t[1]];
    let path: Vec<[f64; 2]> = replay.path.iter().map(|p| moved(*p)).collect();
    let marks: Vec<[f64; 2]> = replay.landmarks.iter().map(|l| moved(l.position)).collect();
    // The fixes scoring dropped as spikes are drawn as such, the others as the reference.
    let title = format!(
        "{}: {} ({} landmarks{})",
        shown_name(&manifest.name),
        replay.metrics.method,
        marks.len(),
        replay
            .metrics
            .reference
            .as_ref()
            .filter(|r| r.ate_rmse_m.is_finite())
            .map_or(String::new(), |r| format!(", ATE {:.2} m", r.ate_rmse_m))
    );
    crate::plot::draw_replay_map(&title, &path, reference, dropped, &marks, &out.join(files::MAP))?;
    Ok(())
}

/// One line for the terminal.
pub fn summary(m: &ReplayMetrics) -> String {
    let reference = m.reference.as_ref().map_or("no reference to score against".to_string(), |r| {
        let ate = if r.ate_rmse_m.is_finite() {
            format!("ATE {:.3} m", r.ate_rmse_m)
        } else if r.samples_scored == 0 {
            "ATE undefined: no reference sample within the estimate's time span".to_string()
        } else {
            format!("ATE undefined: a rigid fit needs {MIN_ALIGNED_SAMPLES} samples")
        };
        let few = if too_little_within(r.samples_scored, r.samples - r.spikes_removed) {
            " (fewer than a tenth of the samples lie within the estimate's time span: a reference of a longer \
             session, or one on another clock or in another unit?)"
        } else {
            ""
        };
        let frame = match (r.in_another_frame(), r.ate_rmse_if_aligned_m) {
            (true, Some(aligned)) => format!(
                " (a rigid fit takes it to {aligned:.3} m: ground truth in another frame, a map's or UTM? declare it \
                 kind = \"gps\" in manifest.toml to have it aligned)"
            ),
            _ => String::new(),
        };
        format!(
            "{ate} against {} ({} of {} samples, {} spikes removed, alignment {}){few}{frame}",
            match r.kind {
                ReferenceKind::Gps => "GPS",
                ReferenceKind::GroundTruth => "ground truth",
            },
            r.samples_scored,
            r.samples,
            r.spikes_removed,
            r.alignment
        )
    });
    let before = match m.scans_before_motion {
        0 => String::new(),
        1 => "; 1 scan before the motion's first row, replayed from the start pose".to_string(),
        n => format!("; {n} scans before the motion's first row, replayed from the start pose"),
    };
    let gaps = match m.scans_in_motion_gaps {
        0 => String::new(),
        n => format!(
            "; {n} scan{} more than {MOTION_GAP_S} s after the motion row before (a control held that long, or rows lost?)",
            if n == 1 { "" } else { "s" }
        ),
    };
    let no_return = if m.returns_in_range == Some(0) {
        "; no beam of any scan returned within the laser's range_min_m to range_max_m (ranges in millimetres, or in \
         another unit?)"
    } else {
        ""
    };
    let beyond = match m.detections_beyond_reach {
        Some(n) if n > 0 => format!(
            "; {n} of {} detections lie beyond {DETECTION_REACH_M} m or are wider than {TRUNK_DIAMETER_MAX_M} m \
             (ranges or diameters in millimetres, or in another unit?)",
            m.detections
        ),
        _ => String::new(),
    };
    let nis = if m.nis.mean.is_finite() {
        format!("NIS mean {:.2} ({:.0}% within 95%)", m.nis.mean, 100.0 * m.nis.within_95)
    } else {
        "NIS undefined (no observation was associated)".to_string()
    };
    format!(
        "{} with {}: {} landmarks; {reference}{before}{gaps}{no_return}{beyond}; {nis}; {:.2} ms per scan (p95 {:.2}); {:.1} s wall, {:.0}x real time",
        shown_name(&m.log),
        m.method,
        m.landmarks,
        m.time_per_scan_ms.mean,
        m.time_per_scan_ms.p95,
        m.wall_seconds,
        m.real_time_factor
    )
}

/// Farther than any laser used for mapping sees a trunk (a SICK LMS reaches 80 m, a
/// long-range lidar a few hundred metres): a detection beyond it is in another unit.
pub const DETECTION_REACH_M: f64 = 1000.0;

/// Wider than any tree's trunk (the widest known are about 11 m across): a detection's
/// diameter beyond it is in another unit.
pub const TRUNK_DIAMETER_MAX_M: f64 = 20.0;

/// The manifest's `name` as summaries show it: a log may leave it empty.
fn shown_name(name: &str) -> &str {
    if name.trim().is_empty() { "the log" } else { name }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A log's source names its data files with their digests, and nothing else.
    #[test]
    fn a_logs_source_names_its_files_with_their_digests() {
        let dir = std::env::temp_dir().join(format!("objslam-log-source-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("camera.csv")).unwrap();
        std::fs::write(dir.join("manifest.toml"), "abc").unwrap();
        std::fs::write(dir.join("notes.txt"), "not the log's").unwrap();
        // A recording's own record of itself, and a model no method reads, are not read.
        std::fs::write(dir.join(files::RECORDING), "{}").unwrap();
        std::fs::write(dir.join(files::APPEARANCE_MODEL), "abc").unwrap();
        let source = LogSource::of_robot_log(&dir, false);
        assert!(source.dir.is_absolute());
        // sha256sum of "abc"; a directory of a data file's name and other files are left out.
        let expected = "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad";
        let manifest = SourceFile { name: "manifest.toml".into(), sha256: Some(expected.into()) };
        assert_eq!(source.files, vec![manifest.clone()]);
        let model = SourceFile { name: files::APPEARANCE_MODEL.into(), sha256: Some(expected.into()) };
        assert_eq!(LogSource::of_robot_log(&dir, true).files, vec![manifest, model]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A refusal that names its input's time says it once; one that names none gets the
    /// log's time.
    #[test]
    fn a_pipeline_refusal_names_its_time_once() {
        use slam::pipeline::PipelineError;
        let reversed = PipelineError::TimeReversed { input: "scan", t: 12.5, previous: 13.0 };
        let e = ReplayError::Pipeline { t: 12.5, source: reversed }.to_string();
        assert_eq!(e.matches("12.5").count(), 1, "{e}");
        assert!(e.starts_with("replay: scan at t = 12.5 s"), "{e}");
        let e = ReplayError::Pipeline { t: 3.0, source: PipelineError::StartNotFinite("pose") }.to_string();
        assert_eq!(e, "replay at t = 3 s: the start pose holds a value that is not finite");
    }

    /// Frames a camera method could not use are refused, naming camera.csv: none within
    /// the age limit of any scan, or most outside the scans' times; frames that reach
    /// some scans pass.
    #[test]
    fn frames_on_another_clock_or_never_reaching_a_scan_are_refused() {
        let file = Path::new("log/camera.csv");
        let scans = Some((0.0, 40.0));
        let at_scans: Vec<f64> = (0..200).map(|k| k as f64 * 0.2).collect();
        check_frame_times(file, &at_scans, scans, 200, 0.02).unwrap();
        // A camera started late, over the last half of the log: accepted.
        let late: Vec<f64> = at_scans.iter().map(|t| t + 20.0).filter(|t| *t <= 40.0).collect();
        check_frame_times(file, &late, scans, 100, 0.02).unwrap();
        let milliseconds: Vec<f64> = at_scans.iter().map(|t| t * 1000.0).collect();
        let e = check_frame_times(file, &milliseconds, scans, 1, 0.02).unwrap_err().to_string();
        assert!(e.starts_with("log/camera.csv: ") && e.contains("199 of the 200 frames lie outside"), "{e}");
        let e = check_frame_times(file, &at_scans, scans, 0, 0.02).unwrap_err().to_string();
        assert!(e.contains("image_max_age_s raised"), "{e}");
        // Without frames or scans there is nothing to check.
        check_frame_times(file, &[], scans, 0, 0.02).unwrap();
        check_frame_times(file, &at_scans, None, 0, 0.02).unwrap();
    }

    /// A replay's --out may hold an earlier replay's outputs, not a log or a run's.
    #[test]
    fn a_replay_refuses_a_directory_holding_a_log_or_a_run() {
        let dir = std::env::temp_dir().join(format!("objslam-replay-out-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        refuse_other_outputs(&dir).unwrap();
        std::fs::write(dir.join(files::METADATA), r#"{"tool": "objslam replay"}"#).unwrap();
        refuse_other_outputs(&dir).unwrap();
        std::fs::write(dir.join(files::METADATA), r#"{"tool": "objslam run"}"#).unwrap();
        let e = refuse_other_outputs(&dir).unwrap_err().to_string();
        assert!(e.contains("the outputs of `objslam run`"), "{e}");
        std::fs::write(dir.join(files::METADATA), "not json").unwrap();
        assert!(refuse_other_outputs(&dir).is_err());
        std::fs::remove_file(dir.join(files::METADATA)).unwrap();
        std::fs::write(dir.join(robotlog::format::MANIFEST), "").unwrap();
        let e = refuse_other_outputs(&dir).unwrap_err().to_string();
        assert!(e.contains("a robot log"), "{e}");
        std::fs::remove_file(dir.join(robotlog::format::MANIFEST)).unwrap();
        // A bag and a data set, with a replay's metadata.json beside them all the same.
        std::fs::write(dir.join(files::METADATA), r#"{"tool": "objslam replay"}"#).unwrap();
        for (marker, says) in [("metadata.yaml", "a ROS 2 bag"), ("dataset.json", "`objslam dataset`")] {
            std::fs::write(dir.join(marker), "").unwrap();
            let e = refuse_other_outputs(&dir).unwrap_err().to_string();
            assert!(e.contains(says), "{e}");
            std::fs::remove_file(dir.join(marker)).unwrap();
        }
        refuse_other_outputs(&dir).unwrap();
        // A user's files of a replay's names, where no replay was: kept, not replaced.
        std::fs::remove_file(dir.join(files::METADATA)).unwrap();
        std::fs::write(dir.join(files::LANDMARKS), "notes").unwrap();
        let e = refuse_other_outputs(&dir).unwrap_err().to_string();
        assert!(e.contains("landmarks.json, which a replay writes, but no earlier replay"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_map_path_stays_bounded_and_keeps_its_ends() {
        let mut path = ThinnedPath::default();
        let n = 10 * MAP_PATH_POINTS;
        for i in 0..n {
            path.push([0.003 * i as f64, 0.0]);
        }
        let kept = path.points();
        assert!(kept.len() <= MAP_PATH_POINTS + 1, "{}", kept.len());
        assert!(kept.len() > MAP_PATH_POINTS / 4, "{}", kept.len());
        assert_eq!(kept[0], [0.0, 0.0]);
        assert_eq!(*kept.last().unwrap(), [0.003 * (n - 1) as f64, 0.0]);
        let widest = kept.windows(2).map(|w| w[1][0] - w[0][0]).fold(0.0, f64::max);
        assert!(widest < 3.0 * 0.003 * n as f64 / MAP_PATH_POINTS as f64, "gaps stay even: {widest}");
    }

    #[test]
    fn scan_time_quantiles_are_within_two_percent_and_mean_and_max_exact() {
        let mut h = ScanTimeHistogram::default();
        let times: Vec<f64> = (1..=1000).map(|i| 0.01 * i as f64).collect();
        for t in &times {
            h.add(*t);
        }
        let s = h.finish();
        assert!((s.mean - times.iter().sum::<f64>() / 1000.0).abs() < 1e-12);
        assert_eq!(s.max, 10.0);
        assert!((s.p50 / 5.0 - 1.0).abs() < 0.02, "{}", s.p50);
        assert!((s.p95 / 9.5 - 1.0).abs() < 0.02, "{}", s.p95);
    }
}
