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

use std::path::{Path, PathBuf};
use std::time::Instant;

use robotlog::stream::{LogStream, MotionMessage, ObservationMessage};
use robotlog::{Manifest, ReferenceKind, ReferencePoint, ReferenceSample};
use serde::Serialize;
use serde_json::json;
use slam::association::{AssociationDecision, AssociationMethod, Choice};
use slam::classifier::AppearanceModel;
use slam::ekf::{AckermannMotionModel, MotionConfig, OdometryMotionModel, RangeBearingModel};
use slam::pipeline::{Appearance, Pipeline, PipelineConfig};

use crate::partial_files::PartialFiles;

/// Errors of a replay.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error(transparent)]
    Log(#[from] robotlog::LogError),
    #[error("{}:{line}: {problem}", file.display())]
    Config { file: PathBuf, line: usize, problem: String },
    #[error("{}: {setting}", file.display())]
    Setting { file: PathBuf, setting: slam::settings::InvalidSetting },
    #[error("replay at t = {t} s: {source}")]
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
    #[error("method {method} segments camera images: the log has no camera (a [camera] table and camera.csv)")]
    NoCamera { method: &'static str },
    #[error("method {method} segments camera images: the log's camera.csv lists no frame")]
    NoFrames { method: &'static str },
    #[error(
        "method {method} needs an appearance model (`objslam replay --appearance-model FILE`, from `objslam train`, or the log's own appearance_model.json); `--method nn` or `jcbb` needs none"
    )]
    NoAppearanceModel { method: &'static str },
    #[error("the appearance model: {0}")]
    Appearance(#[from] slam::gmm::GmmError),
}

impl From<crate::partial_files::PartialFileError> for ReplayError {
    fn from(e: crate::partial_files::PartialFileError) -> Self {
        ReplayError::Io { file: e.file, source: e.source }
    }
}

/// The pipeline settings a log's producer recommends, beside its data (optional; `objslam
/// record --format log` writes the scenario's).
pub const PIPELINE_FILE: &str = "pipeline.toml";

/// The appearance model a log's producer recommends for the camera methods (optional;
/// `objslam record --format log` of a scenario whose method reads the camera writes the
/// model its run uses), taken when `objslam replay` is given none.
pub const APPEARANCE_MODEL_FILE: &str = "appearance_model.json";

/// Highest speed a GPS fix may imply from both its neighbours before it is taken for a
/// spike (m/s): far above what a vehicle in a park drives (Victoria Park's car: 6.6 m/s
/// at most), far below the spikes' hundreds of m/s.
pub const GPS_SPIKE_SPEED_MPS: f64 = 15.0;

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
    let mut files = Vec::new();
    if let Some(dir) = log_dir
        && dir.join(PIPELINE_FILE).exists()
    {
        files.push(dir.join(PIPELINE_FILE));
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
        // Another motion model replaces the whole table: the two models' keys differ.
        let new_model = table.get("motion").and_then(|m| m.get("model")).cloned();
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

/// The estimate against the log's reference.
#[derive(Debug, Clone, Serialize)]
pub struct ReferenceScore {
    pub kind: ReferenceKind,
    pub point: ReferencePoint,
    pub samples: usize,
    /// GPS fixes dropped as spikes (see [`gps_spikes`]), decided from the GPS alone.
    pub spikes_removed: usize,
    /// Samples inside the estimate's time span, scored.
    pub samples_scored: usize,
    /// "rigid 2-D" (GPS) or "none" (ground truth in the estimate's frame).
    pub alignment: String,
    pub alignment_rotation_rad: f64,
    pub alignment_translation_m: [f64; 2],
    pub ate_rmse_m: f64,
    pub ate_max_m: f64,
}

/// What `metrics.json` of a replay holds (docs/guide/real-logs.md).
#[derive(Debug, Clone, Serialize)]
pub struct ReplayMetrics {
    pub log: String,
    pub method: String,
    pub log_seconds: f64,
    pub motion_messages: usize,
    pub scans: usize,
    pub detections: usize,
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
    // Held until the outputs are published or abandoned.
    let lock = out.map(crate::partial_files::lock_output).transpose()?;
    crate::partial_files::abandon_if_failed(lock, out, replay_and_write(log.into(), config, appearance, out))
}

fn replay_and_write(
    log: LogStream,
    config: PipelineConfig,
    appearance: Option<AppearanceModel>,
    out: Option<&Path>,
) -> Result<Replay, ReplayError> {
    let started = Instant::now();
    let mut log = log;
    let first_motion = robotlog::stream::next_time(&mut log.motion, MotionMessage::time)?;
    let first_observation = robotlog::stream::next_time(&mut log.observations, ObservationMessage::time)?;
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
    let frames: &[robotlog::CameraFrameFile] = if camera.is_some() { &log.camera } else { &[] };
    let mut pipeline = Pipeline::new(config.clone(), log.manifest.vehicle.start_pose, appearance)
        .map_err(|source| ReplayError::Pipeline { t: start, source })?
        .starting_at(start);
    // Every output is written in the unfinished directory and moved into `out` when all are.
    let unfinished = out.map(crate::partial_files::start_unfinished).transpose()?;
    let mut streams = match &unfinished {
        Some(dir) => Some(PartialFiles::create(
            dir,
            &[(Stream::Trajectory, "trajectory_est.tum"), (Stream::Decisions, "decisions.jsonl")],
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
    let spikes = reference_spikes(&log.manifest, &log.reference);
    let scored: &[ReferenceSample] = if log.manifest.reference.is_some() { &log.reference } else { &[] };
    let mut reference = ReferencePairs::new(scored, &spikes);
    let mut path = ThinnedPath::default();
    let mut nis = NisSums::default();
    let mut scan_ms = ScanTimeHistogram::default();
    let yaw = log.manifest.sensor.yaw_rad;
    let (mut detections, mut motion_messages, mut scans, mut end) = (0, 0, 0, start);
    let mut f = 0;
    // The time of the trajectory's last pose.
    let mut last_written: Option<f64> = None;
    let error = |t: f64| move |source| ReplayError::Pipeline { t, source };
    loop {
        // At equal times: motion, then the frame, then the scan.
        let tm = robotlog::stream::next_time(&mut log.motion, MotionMessage::time)?;
        let tf = frames.get(f).map(|frame| frame.t);
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
        } else if let (Some(tf), true) = (tf, first(tf, to)) {
            let camera = camera.expect("frames only with a camera");
            let image = robotlog::format::read_frame(&frames[f], camera)?;
            pipeline.on_image(tf, image.width, image.height, image.rgb).map_err(error(tf))?;
            f += 1;
            // A frame moves no pose: nothing to write.
            continue;
        } else {
            let Some(Ok(message)) = log.observations.next() else { unreachable!("peeked a message") };
            let t = message.time();
            let tick = Instant::now();
            let report = match message {
                // Beams in the vehicle's frame: the laser may look sideways.
                ObservationMessage::Scan(scan) => {
                    let turned = slam::messages::LaserScan { angle_min: scan.angle_min + yaw, ..scan };
                    pipeline.on_scan(&turned).map_err(error(t))?
                }
                ObservationMessage::Detections(scan) => {
                    detections += scan.detections.len();
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
        reference.on_pose(p.t, [pose[0], pose[1]]);
        path.push([pose[0], pose[1]]);
        // One pose a time (a TUM file's times increase): at a time of motion and a scan,
        // the pose after the motion, as `objslam run` writes it; the scan moves the next.
        if let Some(s) = streams.as_mut().filter(|_| last_written.is_none_or(|t| t < p.t)) {
            s.write(Stream::Trajectory, &(crate::record::tum_line(p.t, pose[0], pose[1], pose[2]) + "\n"))?;
            last_written = Some(p.t);
        }
    }
    let wall_seconds = started.elapsed().as_secs_f64();
    let log_seconds = end - start;
    let landmarks = pipeline.mapped_landmarks();
    let metrics = ReplayMetrics {
        log: log.manifest.name.clone(),
        method: config.method.name().to_string(),
        log_seconds,
        motion_messages,
        scans,
        detections,
        camera_frames: frames.len(),
        appearance_model: model_provenance,
        landmarks: landmarks.len(),
        reference: score_reference(&log.manifest, &log.reference, &reference.pairs, spikes.len()),
        nis: nis.finish(),
        time_per_scan_ms: scan_ms.finish(),
        wall_seconds,
        real_time_factor: log_seconds / wall_seconds.max(1e-9),
        peak_memory_mb: peak_memory_mb(),
    };
    let result = Replay { metrics, landmarks, config, path: path.points() };
    if let (Some(dir), Some(unfinished), Some(streams)) = (out, unfinished, streams) {
        streams.finish()?;
        write_outputs(&unfinished, &log.manifest, &log.reference, &result, &spikes)
            .map_err(|e| ReplayError::Unpublished { dir: unfinished.clone(), source: Box::new(e) })?;
        crate::partial_files::publish(&unfinished, dir, &[]).map_err(ReplayError::Publish)?;
    }
    Ok(result)
}

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

/// The reference samples scored (spikes left out) paired, as the poses come, with the
/// estimate at their times: linear between the last pose before and the first at or after.
struct ReferencePairs<'a> {
    samples: Vec<&'a ReferenceSample>,
    next: usize,
    last_pose: Option<(f64, [f64; 2])>,
    /// (estimate, reference) per sample scored.
    pairs: Vec<([f64; 2], [f64; 2])>,
}

impl<'a> ReferencePairs<'a> {
    fn new(samples: &'a [ReferenceSample], spikes: &[usize]) -> Self {
        debug_assert!(samples.windows(2).all(|w| w[0].t <= w[1].t), "readers sort the reference by time");
        let samples =
            samples.iter().enumerate().filter(|(k, _)| spikes.binary_search(k).is_err()).map(|(_, s)| s).collect();
        ReferencePairs { samples, next: 0, last_pose: None, pairs: Vec::new() }
    }

    fn on_pose(&mut self, t: f64, p: [f64; 2]) {
        while let Some(s) = self.samples.get(self.next).filter(|s| s.t <= t) {
            match self.last_pose {
                // Before the first pose, only a sample at its very time is scored.
                None => {
                    if s.t == t {
                        self.pairs.push((p, [s.x, s.y]));
                    }
                }
                Some((t0, p0)) => {
                    let a = if t > t0 { (s.t - t0) / (t - t0) } else { 1.0 };
                    self.pairs.push(([p0[0] + a * (p[0] - p0[0]), p0[1] + a * (p[1] - p0[1])], [s.x, s.y]));
                }
            }
            self.next += 1;
        }
        self.last_pose = Some((t, p));
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
        let q95 = slam::association::chi2_quantile(2, 0.95);
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

/// Most consecutive GPS fixes one spike may hold.
pub const GPS_SPIKE_MAX_FIXES: usize = 3;

/// Indices of GPS fixes that are spikes, decided from the GPS alone, never from the
/// estimate being scored, for a vehicle that stays under `max_speed` (m/s). A spike is a
/// run of 1 to [`GPS_SPIKE_MAX_FIXES`] fixes, each reached from the last fix kept before
/// the run and left to the fix after it at more than `max_speed`, while those two agree
/// with each other. Then, at either end of the log, where one neighbour is missing, a
/// single fix is a spike when the two kept fixes on its one side agree (more fixes there
/// may as well be where the GPS went on to).
pub fn gps_spikes(samples: &[ReferenceSample], max_speed: f64) -> Vec<usize> {
    let speed = |a: usize, b: usize| {
        let (a, b) = (&samples[a], &samples[b]);
        (b.x - a.x).hypot(b.y - a.y) / (b.t - a.t).abs().max(1e-3)
    };
    let n = samples.len();
    let mut spike = vec![false; n];
    // Inside the log: the fix before a run is the last one kept, never a dropped spike.
    let mut before = 0;
    let mut i = 1;
    while i + 1 < n {
        let found = (1..=GPS_SPIKE_MAX_FIXES).map(|len| i + len - 1).take_while(|&j| j + 1 < n).find(|&j| {
            let after = j + 1;
            (i..=j).all(|k| speed(k, before) > max_speed && speed(k, after) > max_speed)
                && speed(before, after) <= max_speed
        });
        match found {
            Some(j) => {
                spike[i..=j].iter_mut().for_each(|s| *s = true);
                i = j + 1;
            }
            None => {
                before = i;
                i += 1;
            }
        }
    }
    // The ends, against the two nearest kept fixes on their one side.
    let kept: Vec<usize> = (0..n).filter(|&k| !spike[k]).collect();
    if kept.len() >= 3 {
        for (end, a, b) in
            [(kept[0], kept[1], kept[2]), (kept[kept.len() - 1], kept[kept.len() - 2], kept[kept.len() - 3])]
        {
            if (end == 0 || end == n - 1)
                && speed(end, a) > max_speed
                && speed(end, b) > max_speed
                && speed(a, b) <= max_speed
            {
                spike[end] = true;
            }
        }
    }
    (0..n).filter(|&k| spike[k]).collect()
}

/// The rotation and translation that best map `from` onto `to` (least squares, 2-D, no
/// scale): `to ≈ R(theta) from + t`.
pub fn rigid_alignment(from: &[[f64; 2]], to: &[[f64; 2]]) -> (f64, [f64; 2]) {
    let n = from.len().max(1) as f64;
    let mean = |v: &[[f64; 2]]| {
        let s = v.iter().fold([0.0, 0.0], |a, p| [a[0] + p[0], a[1] + p[1]]);
        [s[0] / n, s[1] / n]
    };
    let (mf, mt) = (mean(from), mean(to));
    let (mut sxx, mut sxy) = (0.0, 0.0);
    for (f, t) in from.iter().zip(to) {
        let (fx, fy, tx, ty) = (f[0] - mf[0], f[1] - mf[1], t[0] - mt[0], t[1] - mt[1]);
        sxx += fx * tx + fy * ty;
        sxy += fx * ty - fy * tx;
    }
    let theta = sxy.atan2(sxx);
    let (s, c) = theta.sin_cos();
    (theta, [mt[0] - (c * mf[0] - s * mf[1]), mt[1] - (s * mf[0] + c * mf[1])])
}

/// The GPS fixes scoring leaves out (none for ground truth or without a reference).
fn reference_spikes(manifest: &Manifest, reference: &[ReferenceSample]) -> Vec<usize> {
    match &manifest.reference {
        Some(r) if r.kind == ReferenceKind::Gps => gps_spikes(reference, GPS_SPIKE_SPEED_MPS),
        _ => Vec::new(),
    }
}

/// The estimate against the reference, from the (estimate, reference) pairs of the samples
/// scored: aligned by a rigid 2-D fit for GPS, as it is for ground truth.
fn score_reference(
    manifest: &Manifest,
    reference: &[ReferenceSample],
    pairs: &[([f64; 2], [f64; 2])],
    spikes: usize,
) -> Option<ReferenceScore> {
    let r = manifest.reference.as_ref()?;
    if reference.is_empty() {
        return None;
    }
    let (est, truth): (Vec<[f64; 2]>, Vec<[f64; 2]>) = pairs.iter().copied().unzip();
    let (theta, t) = match r.kind {
        ReferenceKind::Gps => rigid_alignment(&est, &truth),
        ReferenceKind::GroundTruth => (0.0, [0.0, 0.0]),
    };
    let (s, c) = theta.sin_cos();
    let errors: Vec<f64> = est
        .iter()
        .zip(&truth)
        .map(|(e, g)| (c * e[0] - s * e[1] + t[0] - g[0]).hypot(s * e[0] + c * e[1] + t[1] - g[1]))
        .collect();
    let n = errors.len();
    Some(ReferenceScore {
        kind: r.kind,
        point: r.point,
        samples: reference.len(),
        spikes_removed: spikes,
        samples_scored: n,
        alignment: match r.kind {
            ReferenceKind::Gps => "rigid 2-D".into(),
            ReferenceKind::GroundTruth => "none".into(),
        },
        alignment_rotation_rad: theta,
        alignment_translation_m: t,
        ate_rmse_m: if n > 0 { (errors.iter().map(|e| e * e).sum::<f64>() / n as f64).sqrt() } else { f64::NAN },
        ate_max_m: errors.iter().copied().fold(0.0, f64::max),
    })
}

/// Writes a replay's outputs into `out` beside the streamed ones: `metrics.json`,
/// `metadata.json` (the resolved settings), `landmarks.json` and `map.png`.
fn write_outputs(
    out: &Path,
    manifest: &Manifest,
    reference_samples: &[ReferenceSample],
    replay: &Replay,
    spikes: &[usize],
) -> Result<(), ReplayError> {
    let write = |name: &str, text: String| {
        let file = out.join(name);
        std::fs::write(&file, text).map_err(|source| ReplayError::Io { file, source })
    };
    write("metrics.json", serde_json::to_string_pretty(&replay.metrics).expect("JSON"))?;
    write(
        "metadata.json",
        serde_json::to_string_pretty(&json!({
            "tool": "objslam replay",
            "version": env!("CARGO_PKG_VERSION"),
            "log": manifest,
            "configuration": replay.config,
            "appearance_model": replay.metrics.appearance_model,
        }))
        .expect("JSON"),
    )?;
    write("landmarks.json", serde_json::to_string_pretty(&replay.landmarks).expect("JSON"))?;
    // The map in the reference's frame: the estimate moved by the alignment.
    let (theta, t) = replay
        .metrics
        .reference
        .as_ref()
        .map_or((0.0, [0.0, 0.0]), |r| (r.alignment_rotation_rad, r.alignment_translation_m));
    let (s, c) = theta.sin_cos();
    let moved = |p: [f64; 2]| [c * p[0] - s * p[1] + t[0], s * p[0] + c * p[1] + t[1]];
    let path: Vec<[f64; 2]> = replay.path.iter().map(|p| moved(*p)).collect();
    let marks: Vec<[f64; 2]> = replay.landmarks.iter().map(|l| moved(l.position)).collect();
    // The fixes scoring dropped as spikes are drawn as such, the others as the reference.
    let (mut reference, mut dropped) = (Vec::new(), Vec::new());
    for (k, r) in reference_samples.iter().enumerate() {
        if spikes.binary_search(&k).is_ok() { &mut dropped } else { &mut reference }.push([r.x, r.y]);
    }
    let title = format!(
        "{}: {} ({} landmarks{})",
        if manifest.name.is_empty() { "log" } else { &manifest.name },
        replay.metrics.method,
        marks.len(),
        replay.metrics.reference.as_ref().map_or(String::new(), |r| format!(", ATE {:.2} m", r.ate_rmse_m))
    );
    crate::plot::draw_replay_map(&title, &path, &reference, &dropped, &marks, &out.join("map.png"))?;
    Ok(())
}

/// One line for the terminal.
pub fn summary(m: &ReplayMetrics) -> String {
    let reference = m.reference.as_ref().map_or("no reference to score against".to_string(), |r| {
        format!(
            "ATE {:.3} m against {} ({} of {} samples, {} spikes removed, alignment {})",
            r.ate_rmse_m,
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
    format!(
        "{} with {}: {} landmarks; {reference}; NIS mean {:.2} ({:.0}% within 95%); {:.2} ms per scan (p95 {:.2}); {:.1} s wall, {:.0}x real time",
        m.log,
        m.method,
        m.landmarks,
        m.nis.mean,
        100.0 * m.nis.within_95,
        m.time_per_scan_ms.mean,
        m.time_per_scan_ms.p95,
        m.wall_seconds,
        m.real_time_factor
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rigid_alignment_recovers_a_rotation_and_translation() {
        let from: Vec<[f64; 2]> = (0..20).map(|k| [k as f64, (k as f64 * 0.3).sin() * 4.0]).collect();
        let (s, c) = 0.7f64.sin_cos();
        let to: Vec<[f64; 2]> = from.iter().map(|p| [c * p[0] - s * p[1] + 5.0, s * p[0] + c * p[1] - 2.0]).collect();
        let (theta, t) = rigid_alignment(&from, &to);
        assert!((theta - 0.7).abs() < 1e-12 && (t[0] - 5.0).abs() < 1e-9 && (t[1] + 2.0).abs() < 1e-9);
    }

    #[test]
    fn gps_spikes_are_found_from_the_gps_alone() {
        let mut samples: Vec<ReferenceSample> =
            (0..10).map(|k| ReferenceSample { t: k as f64, x: 3.0 * k as f64, y: 0.0, theta: None }).collect();
        samples[4].y = 137.0;
        assert_eq!(gps_spikes(&samples, GPS_SPIKE_SPEED_MPS), vec![4]);
        // A jump that stays (a re-acquired fix in a new place) is not a spike.
        for s in &mut samples[7..] {
            s.x += 100.0;
        }
        assert_eq!(gps_spikes(&samples, GPS_SPIKE_SPEED_MPS), vec![4]);
        // Two and three fixes in a row, and one at either end.
        let mut samples: Vec<ReferenceSample> =
            (0..30).map(|k| ReferenceSample { t: k as f64, x: 3.0 * k as f64, y: 0.0, theta: None }).collect();
        for k in [0, 8, 9, 20, 21, 22, 29] {
            samples[k].y = 90.0 + k as f64;
        }
        assert_eq!(gps_spikes(&samples, GPS_SPIKE_SPEED_MPS), vec![0, 8, 9, 20, 21, 22, 29]);
        // Two at an end may be where the GPS went on to: not dropped.
        samples[28].y = 118.0;
        assert_eq!(gps_spikes(&samples, GPS_SPIKE_SPEED_MPS), vec![0, 8, 9, 20, 21, 22]);
        samples[28].y = 0.0;
        // Four in a row, off from both neighbours, are not a spike but a place the GPS
        // stayed; three there would be.
        for s in &mut samples[12..16] {
            s.y = 150.0;
        }
        assert_eq!(gps_spikes(&samples, GPS_SPIKE_SPEED_MPS), vec![0, 8, 9, 20, 21, 22, 29]);
        samples[15].y = 0.0;
        assert_eq!(gps_spikes(&samples, GPS_SPIKE_SPEED_MPS), vec![0, 8, 9, 12, 13, 14, 20, 21, 22, 29]);
        // A spike next to the start, and real fixes between two spikes at one false place,
        // are judged against kept fixes: the real ones stay.
        let mut samples: Vec<ReferenceSample> =
            (0..12).map(|k| ReferenceSample { t: k as f64, x: 3.0 * k as f64, y: 0.0, theta: None }).collect();
        for k in [1, 2, 6, 8] {
            samples[k].y = 200.0;
        }
        assert_eq!(gps_spikes(&samples, GPS_SPIKE_SPEED_MPS), vec![1, 2, 6, 8]);
    }

    /// The estimate paired with each reference sample as the poses come: interpolated
    /// between the poses around it, at the first pose only at its very time, never after
    /// the last pose.
    #[test]
    fn reference_samples_pair_with_the_estimate_interpolated_inside_it_only() {
        let samples: Vec<ReferenceSample> =
            [0.5, 1.0, 1.5, 2.5].iter().map(|&t| ReferenceSample { t, x: 10.0 * t, y: 0.0, theta: None }).collect();
        let mut pairs = ReferencePairs::new(&samples, &[]);
        pairs.on_pose(1.0, [0.0, 0.0]);
        pairs.on_pose(2.0, [2.0, 4.0]);
        assert_eq!(pairs.pairs, vec![([0.0, 0.0], [10.0, 0.0]), ([1.0, 2.0], [15.0, 0.0])]);
        // Two poses at one time: the first of them ends the interval; a sample before the
        // first pose is dropped.
        let mut twice = ReferencePairs::new(&samples, &[]);
        twice.on_pose(1.0, [0.0, 0.0]);
        twice.on_pose(1.5, [1.0, 0.0]);
        twice.on_pose(1.5, [9.0, 9.0]);
        assert_eq!(twice.pairs, vec![([0.0, 0.0], [10.0, 0.0]), ([1.0, 0.0], [15.0, 0.0])]);
        let mut skipping = ReferencePairs::new(&samples, &[1]);
        skipping.on_pose(1.0, [0.0, 0.0]);
        skipping.on_pose(2.0, [2.0, 4.0]);
        assert_eq!(skipping.pairs, vec![([1.0, 2.0], [15.0, 0.0])], "a spike is not scored");
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
