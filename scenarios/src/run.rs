//! The runner: feeds the simulator's stream into the online pipeline, scores the result
//! against ground truth and writes the run's outputs.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use serde_json::json;
use sim::{SensorEvent, Simulation};
use slam::association::AssociationMethod;
use slam::classifier::AppearanceModel;
use slam::pipeline::{Appearance, Pipeline, PipelineConfig};
use slam::segmentation::CameraGeometry;
use worlds::ObjectClass;

use crate::scenario::{Scenario, ScenarioError};
use crate::score::scorer::{
    Fusion, MapLandmark, RecallBasis, RunScorer, ScoredObservation, VisibilitySettings, as_written_to_tum, true_object,
};
use crate::score::segmentation::ClassImage;
use crate::score::{AssociationCounts, MapContent};
use crate::visibility::InstanceImage;
use slam::segmentation::merge_spans;

/// Errors of a run.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    #[error(transparent)]
    Sim(#[from] sim::SimError),
    #[error("scenario {scenario}: pipeline.{setting}")]
    Pipeline { scenario: String, setting: slam::settings::InvalidSetting },
    #[error("method {method}: {message}")]
    Method { method: String, message: String },
    #[error("{}: {source}", file.display())]
    Io { file: PathBuf, source: std::io::Error },
    #[error(transparent)]
    Plot(#[from] crate::plot::PlotError),
    #[error(transparent)]
    Mcap(#[from] crate::foxglove::McapError),
    #[error("appearance model: {0}")]
    Appearance(#[from] crate::appearance::AppearanceError),
    #[error("pipeline: {0}")]
    Filter(#[from] slam::pipeline::PipelineError),
    #[error("appearance model: {0}")]
    Mixture(#[from] slam::gmm::GmmError),
    #[error("the camera stopped during the run: {0}")]
    CameraStopped(String),
    #[error("{count} {what} in image columns the camera did not render (a bug; `--full-frames` renders whole frames)")]
    Unrendered { what: &'static str, count: usize },
    #[error(transparent)]
    Objects(#[from] crate::objects::ObjectsError),
    #[error(transparent)]
    Calibration(#[from] crate::calibrate::CalibrateError),
    #[error(transparent)]
    Ros2(#[from] crate::ros2::Ros2Error),
}

/// Segmentation quality against the rendered masks (absent without a camera).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SegmentationScore {
    pub precision: Option<f64>,
    pub recall: Option<f64>,
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

/// The laser <- camera extrinsics a run gives its pipeline, and where they came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResolvedCalibration {
    /// `true`, `perturbed`, `estimated` or `file`.
    pub mode: String,
    /// The calibration file read (mode `file`), resolved against the scenario's directory.
    pub file: Option<PathBuf>,
    /// What the pipeline uses: `P_laser = phi P_camera + delta`.
    pub extrinsics: slam::calibration::Extrinsics,
    /// The simulator's exact extrinsics.
    pub truth: slam::calibration::Extrinsics,
    pub rotation_error_deg: f64,
    pub translation_error_m: f64,
    /// The calibration session's report (mode `estimated`).
    pub report: Option<Box<crate::calibrate::CalibrationReport>>,
}

/// Resolves the scenario's `[calibration]` for a run seed: the simulator's extrinsics
/// (`true`), those with seeded errors (`perturbed`), a calibration session run with the
/// same seed (`estimated`, as `objslam calibrate SCENARIO --seed SEED` runs it), or a
/// calibration file relative to the scenario's directory.
pub fn resolve_calibration(scenario: &Scenario, base_dir: &Path, seed: u64) -> Result<ResolvedCalibration, RunError> {
    let c = &scenario.calibration;
    let truth = crate::calibrate::true_extrinsics(&scenario.sim);
    let (mode, file, extrinsics, report) = match c.mode.as_str() {
        "true" => ("true", None, truth, None),
        "perturbed" => (
            "perturbed",
            None,
            crate::calibrate::perturb(&truth, c.rotation_sigma_deg, c.translation_sigma_m, seed),
            None,
        ),
        "estimated" => {
            let report = crate::calibrate::run_session(scenario, base_dir, seed, None, None)?;
            ("estimated", None, report.extrinsics(), Some(Box::new(report)))
        }
        path => {
            let file = base_dir.join(path);
            let e = crate::calibrate::load_extrinsics(&file)?;
            ("file", Some(file), e, None)
        }
    };
    let (rotation_error_deg, translation_error_m) = extrinsics.error_to(&truth);
    Ok(ResolvedCalibration {
        mode: mode.into(),
        file,
        extrinsics,
        truth,
        rotation_error_deg,
        translation_error_m,
        report,
    })
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

/// The simulator's event stream, with the time spent producing it.
///
/// A run started outside a rayon pool simulates on its own thread, a bounded queue ahead of
/// the pipeline, so the two halves overlap. Inside a pool (Monte Carlo runs, which already
/// fill the cores) it simulates inline: a pool worker blocked on the queue would starve
/// the laser's own rayon tasks and deadlock. The pipeline sees the same event sequence
/// either way.
enum EventSource {
    Inline { sim: Box<Simulation>, sim_time: f64 },
    Threaded { events: std::sync::mpsc::Receiver<SensorEvent>, producer: std::thread::JoinHandle<(Simulation, f64)> },
}

impl EventSource {
    /// Starts the stream; a camera thread that cannot start is reported to `warn`, and the
    /// camera then renders on the simulator's thread.
    fn start(mut sim: Simulation, warn: &mut dyn FnMut(String)) -> Self {
        if rayon::current_thread_index().is_some() {
            return EventSource::Inline { sim: Box::new(sim), sim_time: 0.0 };
        }
        // A core is free for the physics while the camera renders (see
        // Simulation::render_camera_on_thread); if the thread cannot start, render inline.
        if let Err(e) = sim.render_camera_on_thread() {
            warn(format!("{e}; the camera renders on the simulator's thread"));
        }
        let (tx, events) = std::sync::mpsc::sync_channel::<SensorEvent>(64);
        let producer = std::thread::spawn(move || {
            let mut sim_time = 0.0f64;
            loop {
                let tick = std::time::Instant::now();
                let Some(event) = sim.next_event() else { break };
                sim_time += tick.elapsed().as_secs_f64();
                if tx.send(event).is_err() {
                    break;
                }
            }
            (sim, sim_time)
        });
        EventSource::Threaded { events, producer }
    }

    fn next(&mut self) -> Option<SensorEvent> {
        match self {
            EventSource::Inline { sim, sim_time } => {
                let tick = std::time::Instant::now();
                let event = sim.next_event();
                *sim_time += tick.elapsed().as_secs_f64();
                event
            }
            EventSource::Threaded { events, .. } => events.recv().ok(),
        }
    }

    /// The simulator once the stream has ended, and its time (s).
    fn finish(self) -> (Simulation, f64) {
        match self {
            EventSource::Inline { sim, sim_time } => (*sim, sim_time),
            EventSource::Threaded { events, producer } => {
                drop(events);
                match producer.join() {
                    Ok(done) => done,
                    Err(panic) => std::panic::resume_unwind(panic),
                }
            }
        }
    }
}

/// Options of one run.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    pub seed: Option<u64>,
    pub method: Option<AssociationMethod>,
    /// Where to write outputs; `None` writes nothing (Monte Carlo runs).
    pub out: Option<PathBuf>,
    /// An appearance model already loaded (Monte Carlo studies resolve it once); `None`
    /// resolves the scenario's `[appearance]` source when the method needs it.
    pub appearance: Option<std::sync::Arc<AppearanceModel>>,
    /// Render whole camera frames, not only the pixel columns the pipeline reads: the same
    /// results, more slowly (for checking exactly that).
    pub full_frames: bool,
    /// Also write the run's sensor stream as a ROS 2 bag in this directory (see
    /// [`crate::ros2`]); its frames are then rendered whole.
    pub bag: Option<PathBuf>,
}

/// A solve of the smoother after a loop closure, at a scan's time: what it did, or why it
/// failed.
type Solve = (f64, Result<slam::ekf::smoother::Relinearisation, slam::ekf::smoother::SmootherError>);

/// Result of a run, with what the reports need.
pub struct RunOutcome {
    pub metrics: Metrics,
    pub resolved: serde_json::Value,
}

/// The ground-truth images of the latest camera frame (moved, not copied: about 1 MB).
struct TruthImages {
    t: f64,
    width: u32,
    height: u32,
    class: Vec<u8>,
    instance: Vec<u16>,
    columns: Option<Vec<(u32, u32)>>,
}

/// One line of segmentation.jsonl: how a cluster of the scan at `t_scan` was judged in the
/// image of `t_image`, with the object it truly was.
fn segmentation_line(
    t_scan: f64,
    t_image: f64,
    judged: &slam::pipeline::ClusterSegmentation,
    cluster: &slam::clustering::Cluster,
    object: u16,
    world: &worlds::World,
) -> String {
    let mut line = serde_json::to_value(judged).expect("JSON");
    line["t_scan"] = json!(t_scan);
    line["t_image"] = json!(t_image);
    line["range_m"] = json!(cluster.range_m);
    line["true_object"] = json!(object);
    line["true_class"] = json!(world.class_of(object).map(|c| c.name()).unwrap_or("nothing"));
    serde_json::to_string(&line).expect("JSON") + "\n"
}

/// The pipeline settings of a scenario, with a method override and the laser's mounting.
/// Scenarios read from files were checked when parsed; this checks again for ones built or
/// changed in code.
pub fn pipeline_config(scenario: &Scenario, method: Option<AssociationMethod>) -> Result<PipelineConfig, RunError> {
    let mut config = scenario.pipeline.clone();
    config.validate().map_err(|setting| RunError::Pipeline { scenario: scenario.name.clone(), setting })?;
    if let Some(m) = method {
        config.method = m;
    }
    // The laser's mounting is known to the robot: the observation model uses it.
    config.sensor.mount_x = scenario.sim.laser.mount_xyz_m[0];
    config.sensor.mount_y = scenario.sim.laser.mount_xyz_m[1];
    Ok(config)
}

/// The simulator's scan as the pipeline's plain message (the one place the two meet).
pub fn slam_scan(scan: &sim::LaserScan) -> slam::messages::LaserScan {
    slam::messages::LaserScan {
        t: scan.t,
        angle_min: scan.angle_min,
        angle_increment: scan.angle_increment,
        range_min: scan.range_min,
        range_max: scan.range_max,
        ranges: scan.ranges.clone(),
    }
}

/// The camera as the pipeline is told it: K and the laser <- camera extrinsics (the
/// run's resolved calibration, see [`resolve_calibration`]).
pub fn camera_geometry(
    sim_config: &sim::SimConfig,
    laser_from_camera: &slam::calibration::Extrinsics,
) -> CameraGeometry {
    let k = sim_config.camera.intrinsics();
    CameraGeometry {
        fx: k.fx,
        fy: k.fy,
        cx: k.cx,
        cy: k.cy,
        width: k.width,
        height: k.height,
        laser_from_camera: *laser_from_camera,
    }
}

/// The scenario's appearance model (a named file, or trained once and cached);
/// `progress(stage, done, total)` follows a training.
pub fn resolve_appearance(
    scenario: &Scenario,
    base_dir: &Path,
    progress: impl Fn(&str, usize, usize),
) -> Result<AppearanceModel, RunError> {
    Ok(scenario.appearance.resolve(base_dir, &scenario.sim.camera, progress)?)
}

/// What a run tells its caller while it goes (see [`run`]).
#[derive(Debug, Clone, PartialEq)]
pub enum RunProgress<'a> {
    /// The appearance model is being trained (first use of a scenario's settings): a
    /// stage, and how far it has come.
    Training { stage: &'a str, done: usize, total: usize },
    /// Simulated seconds so far, of the route's nominal duration.
    Simulated { t: f64, total: f64 },
    /// Something the user should know; the run goes on.
    Warning(String),
}

/// Runs a scenario once; `progress` hears of a training, the simulated time and warnings.
pub fn run(
    scenario: &Scenario,
    base_dir: &Path,
    options: &RunOptions,
    mut progress: impl FnMut(RunProgress),
) -> Result<RunOutcome, RunError> {
    let seed = options.seed.unwrap_or(scenario.seed);
    let config = pipeline_config(scenario, options.method)?;
    if config.method.uses_appearance() && !scenario.sim.camera.enabled {
        return Err(RunError::Method {
            method: config.method.name().into(),
            message: "needs the camera, which the scenario disables (sim.camera.enabled = false)".into(),
        });
    }
    let appearance_model = if config.method.uses_appearance() {
        Some(match &options.appearance {
            Some(m) => m.clone(),
            None => {
                // Training reports through a shared reference; the run's callback is FnMut.
                let progress = std::cell::RefCell::new(&mut progress);
                std::sync::Arc::new(resolve_appearance(scenario, base_dir, |stage, done, total| {
                    (progress.borrow_mut())(RunProgress::Training { stage, done, total })
                })?)
            }
        })
    } else {
        None
    };
    let world = scenario.world(base_dir, seed)?;
    let calibration = resolve_calibration(scenario, base_dir, seed)?;
    let started = std::time::Instant::now();
    // Position-only methods never look at images: skip rendering them.
    let mut sim_config = scenario.sim.clone();
    if !config.method.uses_appearance() {
        sim_config.camera.enabled = false;
    }
    // Nor does any method read depth: render without it.
    sim_config.camera.depth_image = false;
    let mut sim = Simulation::new(&world, &sim_config, sim::derive_seed(seed, "sim"))?;
    // Where the images came from: results depend on the renderer (metrics.renderer, and
    // the model's training renderer in metadata.json).
    let renderer = sim.camera_adapter().map(|a| a.to_string());
    let model_provenance = appearance_model.as_ref().map(|m| ModelProvenance {
        training_seed: m.training.seed,
        training_images: m.training.images,
        training_renderer: m.training.renderer.clone(),
    });
    let nominal = scenario.sim.max_duration_s.unwrap_or_else(|| sim.nominal_duration_s());
    let start = world.robot.start;
    let appearance = match &appearance_model {
        Some(m) => Some(Appearance::new((**m).clone(), camera_geometry(&scenario.sim, &calibration.extrinsics))?),
        None => None,
    };
    let mut pipeline = Pipeline::new(config.clone(), [start.x, start.y, start.yaw_rad()], appearance)?;
    // The camera renders only the columns segmentation will read, chosen from the scan of
    // the frame's instant as the pipeline will cluster it: most of each frame is never read.
    // Only where no other scan can use the frame (one within image_max_age_s of it): sensors
    // fire on the first physics step at or after their time, so two scans can be up to a
    // step closer than the laser's period.
    let frame_read_by_one_scan =
        config.image_max_age_s < 1.0 / sim_config.laser.rate_hz - 1.0 / sim_config.physics_rate_hz;
    // Every ground-truth figure; the recall's denominators come from the camera's true
    // extrinsics, whatever the run's calibration.
    let true_camera = sim_config.camera.enabled.then(|| camera_geometry(&scenario.sim, &calibration.truth));
    let camera_method = config.method.uses_appearance();
    let basis = if camera_method { RecallBasis::InView } else { RecallBasis::LaserSeen };
    let mut scorer = RunScorer::new(&world, true_camera, VisibilitySettings::of(&config), basis);
    if camera_method {
        scorer = scorer.scoring_segmentation();
    }
    let tree_ids = scorer.tree_ids().clone();
    // A bag holds whole images.
    let whole_frames = options.full_frames || options.bag.is_some();
    if let Some(region) = pipeline.image_region().filter(|_| !whole_frames && frame_read_by_one_scan) {
        // The columns the ground-truth count reads are rendered too, so that it does not
        // depend on the columns the method asked for.
        let truth_columns = scorer.visibility().clone();
        sim.render_camera_columns(Box::new(move |scan, beams| {
            merge_spans([region.columns(&slam_scan(scan)), truth_columns.columns(scan, beams)].concat())
        }));
    }
    // A scan and the frame of its instant fire on the same physics step.
    let same_instant_s = 0.5 / sim_config.physics_rate_hz;
    let (mut pixels_rendered, mut pixels_framed) = (0u64, 0u64);
    // The latest frame's ground-truth images, for scoring the segmentation and the recall.
    let mut last_frame: Option<TruthImages> = None;
    // Each association decision with its observation's true object (runs that write
    // outputs), the smoother's solves, retracted landmarks and the count of fusions: what
    // the scan reports say, kept here (the pipeline keeps no history).
    let mut decisions: Vec<(slam::association::AssociationDecision, u16)> = Vec::new();
    let mut solves: Vec<Solve> = Vec::new();
    let mut retractions: Vec<slam::pipeline::LandmarkRetraction> = Vec::new();
    let mut merged = 0usize;

    let mut est_path: Vec<(f64, [f64; 3])> = Vec::new();
    let mut gt_path: Vec<(f64, [f64; 3])> = Vec::new();
    // What the pipeline did with each scan, as `objslam score` reads it (associations.jsonl).
    let mut association_log = String::new();
    // One line per segmented cluster (camera methods): why it was or was not an object.
    let mut segmentation_log = String::new();
    let mut people_tracks: BTreeMap<u16, Vec<[f64; 2]>> = BTreeMap::new();
    let mut last_progress = -1.0;

    let (mut pipe_time, mut scan_time, mut scans) = (0.0f64, 0.0f64, 0usize);
    let mut bag = match &options.bag {
        Some(dir) => Some(crate::ros2::Ros2Recorder::create(dir, &sim_config)?),
        None => None,
    };
    let mut events = EventSource::start(sim, &mut |w| progress(RunProgress::Warning(w)));
    while let Some(event) = events.next() {
        if let Some(bag) = &mut bag {
            bag.write(&event)?;
        }
        let tick = std::time::Instant::now();
        let t = event.time();
        match event {
            SensorEvent::Odometry { odometry, truth } => {
                pipeline.on_odometry(&slam::messages::OdometryIncrement {
                    t: odometry.t,
                    dx: odometry.dx,
                    dy: odometry.dy,
                    dtheta: odometry.dtheta,
                })?;
                let est = pipeline.pose();
                let r = truth.robot;
                est_path.push((odometry.t, est.pose));
                gt_path.push((odometry.t, [r.x, r.y, r.theta]));
                scorer.on_pose(
                    odometry.t,
                    as_written_to_tum(est.pose),
                    Some(est.covariance),
                    as_written_to_tum([r.x, r.y, r.theta]),
                );
            }
            SensorEvent::Laser { scan, beams, truth } => {
                let s = slam_scan(&scan);
                let scan_tick = std::time::Instant::now();
                let mut result = pipeline.on_scan(&s)?;
                scan_time += scan_tick.elapsed().as_secs_f64();
                scans += 1;
                // Only runs that write outputs keep the decisions (not Monte Carlo runs).
                if options.out.is_some() {
                    for d in std::mem::take(&mut result.decisions) {
                        let c = &result.clusters[d.observation];
                        let truth = true_object(&beams.hit_ids, c.first_beam, c.last_beam);
                        decisions.push((d, truth));
                    }
                }
                solves.extend(result.relinearisations.drain(..).map(|r| (s.t, r)));
                retractions.append(&mut result.retractions);
                merged += result.merges.len();
                for rec in &result.segmentations {
                    let frame = last_frame.as_ref().map(|f| ClassImage { t: f.t, width: f.width, class: &f.class });
                    let objects = scorer.on_segmentation(rec, &result.clusters, &beams, frame.as_ref());
                    // Only runs that write outputs keep the log (not Monte Carlo runs).
                    if options.out.is_some() {
                        for (cs, obj) in rec.clusters.iter().zip(objects) {
                            let c = &result.clusters[cs.index];
                            segmentation_log.push_str(&segmentation_line(s.t, rec.t_image, cs, c, obj, &world));
                        }
                    }
                }
                let observations: Vec<ScoredObservation> = result
                    .clusters
                    .iter()
                    .zip(&result.assigned)
                    .map(|(c, landmark)| ScoredObservation {
                        first_beam: c.first_beam,
                        last_beam: c.last_beam,
                        landmark: *landmark,
                    })
                    .collect();
                let fusions: Vec<Fusion> =
                    result.merges.iter().map(|m| Fusion { kept: m.kept, removed: m.removed }).collect();
                let frame =
                    last_frame.as_ref().filter(|f| (f.t - scan.t).abs() < same_instant_s).map(|f| InstanceImage {
                        t: f.t,
                        width: f.width,
                        height: f.height,
                        instance: &f.instance,
                        columns: f.columns.as_deref(),
                    });
                scorer.on_scan(&scan, &beams, frame.as_ref(), &observations, &fusions);
                if options.out.is_some() {
                    association_log.push_str(&association_line(scan.t, &observations, &fusions));
                }
                for p in &truth.people {
                    people_tracks.entry(p.id).or_default().push([p.x, p.y]);
                }
            }
            SensorEvent::Camera { frame, .. } => {
                // Moved, not copied: a frame is about 1.5 MB.
                let img = frame.image;
                let columns_rendered = img.columns.as_ref().map_or(img.width, |c| c.iter().map(|(a, b)| b - a).sum());
                pixels_rendered += columns_rendered as u64 * img.height as u64;
                pixels_framed += img.width as u64 * img.height as u64;
                pipeline.on_image_columns(frame.t, img.width, img.height, img.rgb, img.columns.clone())?;
                last_frame = Some(TruthImages {
                    t: frame.t,
                    width: img.width,
                    height: img.height,
                    class: img.class,
                    instance: img.instance,
                    columns: img.columns,
                });
            }
        }
        pipe_time += tick.elapsed().as_secs_f64();
        if t - last_progress >= 1.0 {
            progress(RunProgress::Simulated { t, total: nominal });
            last_progress = t;
        }
    }
    let (sim, sim_time) = events.finish();
    if let Some(bag) = bag {
        bag.finish()?;
    }
    // A camera that stopped (a lost GPU device) leaves a camera method blind for the rest of
    // the run: its scores would not be the method's.
    if let Some(e) = sim.camera_error().filter(|_| camera_method) {
        return Err(RunError::CameraStopped(e.to_string()));
    }
    if pipeline.unrendered_reads() > 0 {
        return Err(RunError::Unrendered {
            what: "clusters were not segmented: they read pixels",
            count: pipeline.unrendered_reads(),
        });
    }
    if scorer.unrendered_reads() > 0 {
        return Err(RunError::Unrendered {
            what: "pixels read by the tree-recall count lie",
            count: scorer.unrendered_reads(),
        });
    }
    progress(RunProgress::Simulated { t: sim.time(), total: nominal });
    let wall = started.elapsed().as_secs_f64();

    let lms = pipeline.mapped_landmarks();
    let map_landmarks: Vec<MapLandmark> = lms.iter().map(|l| MapLandmark { id: l.id, position: l.position }).collect();
    let scored = scorer.finish(&map_landmarks);
    let landmark_object = scored.landmark_objects;
    let map = scored.map;

    let mut metrics = Metrics {
        scenario: scenario.name.clone(),
        seed,
        method: config.method.name().into(),
        sim_seconds: sim.time(),
        wall_seconds: wall,
        realtime_factor: sim.time() / wall.max(1e-9),
        ate_rmse_m: scored.ate_rmse_m,
        rpe_rmse_m: scored.rpe_rmse_m,
        landmark_rmse_m: scored.landmark_rmse_m,
        map,
        landmarks: scored.landmarks,
        associations: scored.associations,
        duplicate_landmarks: scored.duplicate_landmarks,
        merged_landmarks: merged,
        relinearisations: solves.iter().filter(|(_, r)| r.is_ok()).count(),
        relinearisation_failures: solves.iter().filter(|(_, r)| r.is_err()).count(),
        retracted_landmarks: RetractionCounts {
            total: retractions.len(),
            trees: retractions
                .iter()
                .filter(|r| landmark_object.get(&r.landmark).is_some_and(|o| tree_ids.contains(o)))
                .count(),
        },
        false_landmarks: scored.false_landmarks,
        segmentation: scored
            .patches
            .map(|p| SegmentationScore { precision: Some(p.precision()), recall: Some(p.recall()) })
            .unwrap_or_default(),
        calibration: Some(CalibrationScore {
            mode: calibration.mode.clone(),
            rotation_error_deg: calibration.rotation_error_deg,
            translation_error_m: calibration.translation_error_m,
        }),
        odometry_calibration: odometry_calibration_score(pipeline.ekf(), sim.odometry_errors()),
        anees: scored.anees,
        collisions: sim.collisions().len(),
        route_completed: sim.route_progress() > 0.99,
        passed: false,
        failures: vec![],
        timing: Timing {
            simulator_s: sim_time,
            pipeline_s: pipe_time,
            scans,
            mean_scan_ms: if scans > 0 { 1000.0 * scan_time / scans as f64 } else { 0.0 },
            rendered_fraction: if pixels_framed > 0 { pixels_rendered as f64 / pixels_framed as f64 } else { 0.0 },
        },
        renderer,
        appearance_model: model_provenance.clone(),
    };
    metrics.failures = check_pass(&scenario.pass, &metrics);
    metrics.passed = metrics.failures.is_empty();

    let resolved = json!({
        "scenario": scenario,
        "seed": seed,
        "sim_seed": sim::derive_seed(seed, "sim"),
        "world": world,
        // The simulator as it ran: the scenario's, with the camera off for position-only
        // methods and without the depth image nobody reads.
        "sim": sim_config,
        "pipeline": config,
        "calibration": calibration,
    });

    if let Some(out) = &options.out {
        clear_stale_outputs(out)?;
        if let Some(report) = &calibration.report {
            report.write(&out.join("calibration.json"))?;
        }
        write_outputs(
            out,
            &world,
            &pipeline,
            &metrics,
            &resolved,
            &json!(model_provenance),
            &est_path,
            &gt_path,
            &people_tracks,
            &landmark_object,
            &decisions,
            &solves,
        )?;
        let file = out.join("associations.jsonl");
        std::fs::write(&file, association_log).map_err(|source| RunError::Io { file, source })?;
        if camera_method {
            let file = out.join("segmentation.jsonl");
            std::fs::write(&file, segmentation_log).map_err(|source| RunError::Io { file, source })?;
        }
    }
    Ok(RunOutcome { metrics, resolved })
}

/// One line of `associations.jsonl`: a scan's time, what each of its laser clusters went
/// to, and the fusions made after it (the format `objslam score --associations` reads).
fn association_line(t: f64, observations: &[ScoredObservation], fusions: &[Fusion]) -> String {
    serde_json::to_string(&json!({"t": t, "observations": observations, "fusions": fusions})).expect("JSON") + "\n"
}

/// Outputs that only some runs write (camera methods, estimated calibrations): removed from
/// a reused output directory first, so none is left from an earlier run to be taken for
/// this one's. The other outputs every run rewrites.
const CONDITIONAL_OUTPUTS: [&str; 3] = ["calibration.json", "segmentation.jsonl", "objects"];

fn clear_stale_outputs(out: &Path) -> Result<(), RunError> {
    for name in CONDITIONAL_OUTPUTS {
        let path = out.join(name);
        let removed = if path.is_dir() { std::fs::remove_dir_all(&path) } else { std::fs::remove_file(&path) };
        match removed {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(RunError::Io { file: path, source: e }),
            _ => {}
        }
    }
    Ok(())
}

/// Checks the scenario's pass criteria; returns the failures in words.
pub fn check_pass(p: &crate::scenario::PassCriteria, m: &Metrics) -> Vec<String> {
    let mut f = Vec::new();
    if let Some(max) = p.max_wrong_associations
        && m.associations.wrong > max
    {
        f.push(format!("{} wrong associations (max {max})", m.associations.wrong));
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
            Some(recall) => f.push(format!("tree recall {recall:.2} ({}; min {min})", m.map.recall_in_words())),
            None => f.push(format!("tree recall undefined: {} (min {min})", m.map.recall_in_words())),
        }
    }
    if let Some(max) = p.max_ate_rmse_m
        && !(m.ate_rmse_m <= max)
    {
        f.push(format!("ATE RMSE {:.3} m (max {max})", m.ate_rmse_m));
    }
    if let Some(max) = p.max_landmark_rmse_m
        && m.landmark_rmse_m.is_some_and(|r| r > max)
    {
        f.push(format!("landmark RMSE {:.3} m (max {max})", m.landmark_rmse_m.unwrap_or(f64::NAN)));
    }
    if let Some(max) = p.max_collisions
        && m.collisions > max
    {
        f.push(format!("{} collisions (max {max})", m.collisions));
    }
    if let Some(c) = &m.calibration {
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

#[allow(clippy::too_many_arguments)]
fn write_outputs(
    out: &Path,
    world: &worlds::World,
    pipeline: &Pipeline,
    metrics: &Metrics,
    resolved: &serde_json::Value,
    model_provenance: &serde_json::Value,
    est: &[(f64, [f64; 3])],
    gt: &[(f64, [f64; 3])],
    people_tracks: &BTreeMap<u16, Vec<[f64; 2]>>,
    landmark_object: &HashMap<u32, u16>,
    decisions: &[(slam::association::AssociationDecision, u16)],
    solves: &[Solve],
) -> Result<(), RunError> {
    std::fs::create_dir_all(out).map_err(|source| RunError::Io { file: out.to_path_buf(), source })?;
    let write = |name: &str, text: String| {
        let file = out.join(name);
        std::fs::write(&file, text).map_err(|source| RunError::Io { file, source })
    };
    write("metrics.json", serde_json::to_string_pretty(metrics).expect("JSON"))?;
    write(
        "metadata.json",
        serde_json::to_string_pretty(&json!({
            "tool": "objslam run",
            "version": env!("CARGO_PKG_VERSION"),
            "seed": metrics.seed,
            "renderer": metrics.renderer,
            "appearance_model": model_provenance,
            "configuration": resolved,
        }))
        .expect("JSON"),
    )?;
    let tum = |path: &[(f64, [f64; 3])]| {
        let mut s = String::from("# timestamp tx ty tz qx qy qz qw\n");
        for (t, p) in path {
            s.push_str(&crate::record::tum_line(*t, p[0], p[1], p[2]));
            s.push('\n');
        }
        s
    };
    write("trajectory_est.tum", tum(est))?;
    write("trajectory_gt.tum", tum(gt))?;
    // Each decision with the ground truth beside it: the observation's true object and the
    // true object of every candidate landmark.
    let decisions: String = decisions
        .iter()
        .map(|(d, truth)| {
            let mut v = serde_json::to_value(d).expect("JSON");
            v["true_object"] = json!(truth);
            if let Some(cands) = v["candidates"].as_array_mut() {
                for c in cands {
                    let id = c["landmark"].as_u64().unwrap_or(u64::MAX) as u32;
                    c["true_object"] = json!(landmark_object.get(&id).copied().unwrap_or(0));
                }
            }
            serde_json::to_string(&v).expect("JSON") + "\n"
        })
        .collect();
    write("decisions.jsonl", decisions)?;
    // Each solve of the smoother (combined method): what it solved and how far the cost
    // fell, or why it failed (the filter then carried on as it was).
    write(
        "relinearisations.jsonl",
        solves
            .iter()
            .map(|(t, solve)| {
                let mut v = match solve {
                    Ok(r) => json!(r),
                    Err(e) => json!({"error": e.to_string()}),
                };
                v["t"] = json!(t);
                serde_json::to_string(&v).expect("JSON") + "\n"
            })
            .collect::<String>(),
    )?;
    let landmarks: Vec<_> = pipeline
        .mapped_landmarks()
        .iter()
        .map(|l| {
            let obj = landmark_object.get(&l.id).copied().unwrap_or(0);
            let mut v = serde_json::to_value(l).expect("JSON");
            v["true_object"] = json!(obj);
            v["true_class"] = json!(world.class_of(obj).map(|c| c.name()).unwrap_or("nothing"));
            v
        })
        .collect();
    write("landmarks.json", serde_json::to_string_pretty(&landmarks).expect("JSON"))?;
    crate::objects::write_objects(out, pipeline)?;

    // The map picture: ground truth by class, landmarks with 2-sigma ellipses (red when
    // on something other than a tree), both trajectories and people's tracks.
    let marks = pipeline
        .mapped_landmarks()
        .iter()
        .map(|l| {
            let obj = landmark_object.get(&l.id).copied().unwrap_or(0);
            let flagged = world.class_of(obj) != Some(ObjectClass::Tree);
            crate::plot::LandmarkMark {
                position: l.position,
                covariance: l.covariance,
                label: format!("L{}", l.id),
                flagged,
            }
        })
        .collect();
    let overlays = crate::plot::Overlays {
        title: format!(
            "{} / {} / seed {}: {} landmarks, {} wrong associations, {} false, {} duplicates",
            metrics.scenario,
            metrics.method,
            metrics.seed,
            metrics.landmarks,
            metrics.associations.wrong,
            metrics.false_landmarks,
            metrics.duplicate_landmarks
        ),
        landmarks: marks,
        trajectories: vec![
            ("true path".into(), plotters::style::RGBColor(0, 0, 200), gt.iter().map(|(_, p)| [p[0], p[1]]).collect()),
            (
                "estimated path".into(),
                plotters::style::RGBColor(230, 120, 0),
                est.iter().map(|(_, p)| [p[0], p[1]]).collect(),
            ),
        ],
        people_tracks: people_tracks.values().cloned().collect(),
        routes: false,
    };
    crate::plot::draw_map(world, &overlays, &out.join("map.png"))?;

    let mut mcap = crate::foxglove::McapWriter::create(&out.join("run.mcap"))?;
    for ((t, e), (_, g)) in est.iter().zip(gt) {
        use crate::foxglove::{pose_json, timestamp, yaw_quaternion};
        mcap.write("/estimate/pose", "foxglove.PosesInFrame", *t, &json!({"timestamp": timestamp(*t), "frame_id": "world", "poses": [pose_json(e[0], e[1], 0.0, yaw_quaternion(e[2]))]}))?;
        mcap.write("/ground_truth/pose", "foxglove.PosesInFrame", *t, &json!({"timestamp": timestamp(*t), "frame_id": "world", "poses": [pose_json(g[0], g[1], 0.0, yaw_quaternion(g[2]))]}))?;
    }
    let t_end = est.last().map_or(0.0, |(t, _)| *t);
    let lm_poses: Vec<_> = pipeline
        .mapped_landmarks()
        .iter()
        .map(|l| crate::foxglove::pose_json(l.position[0], l.position[1], 0.0, [0.0, 0.0, 0.0, 1.0]))
        .collect();
    mcap.write(
        "/estimate/landmarks",
        "foxglove.PosesInFrame",
        t_end,
        &json!({"timestamp": crate::foxglove::timestamp(t_end), "frame_id": "world", "poses": lm_poses}),
    )?;
    mcap.finish()?;
    Ok(())
}

fn odometry_calibration_score(ekf: &slam::ekf::Ekf, truth: [f64; 3]) -> Option<OdometryCalibrationScore> {
    let (estimated, sigma) = (ekf.calibration(), ekf.calibration_sigma());
    (estimated.len() == 3).then(|| OdometryCalibrationScore {
        estimated: [estimated[0], estimated[1], estimated[2]],
        sigma: [sigma[0], sigma[1], sigma[2]],
        truth,
    })
}

/// Retracted landmarks (see [`Metrics::retracted_landmarks`]).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct RetractionCounts {
    pub total: usize,
    pub trees: usize,
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
    s.push_str(&format!("  tree recall       {recall:>4} ({})\n", m.map.recall_in_words()));
    if let Some(judged) = m.map.trees_judged {
        s.push_str(&format!("  trees judged      {judged:>4} (by the method's own segmentation, in enough frames)\n"));
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
    s.push_str(&format!("  RPE RMSE          {:>8.3} m over 1 s\n", m.rpe_rmse_m));
    if let Some(r) = m.landmark_rmse_m {
        s.push_str(&format!("  landmark RMSE     {r:>8.3} m\n"));
    }
    s.push_str(&format!("  ANEES             {:>8.2}\n", m.anees));
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
