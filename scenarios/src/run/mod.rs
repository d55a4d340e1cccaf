//! The runner: feeds the simulator's stream into the online pipeline, scores the result
//! against ground truth and writes the run's outputs.

//!
//! The files, by stage: `events` (the simulator's stream), `online` (each event to the
//! pipeline, its reports to the scorer and the logs), `metrics` (what `metrics.json` holds,
//! the pass criteria), `outputs` (the files a run writes). `run` itself is setup, loop,
//! finish and write.

mod events;
mod metrics;
mod online;
mod outputs;

pub use metrics::*;

use crate::files;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use serde_json::json;
use sim::Simulation;
use slam::association::AssociationMethod;
use slam::classifier::AppearanceModel;
use slam::pipeline::{Appearance, Pipeline, PipelineConfig};
use slam::segmentation::{CameraGeometry, merge_regions};

use crate::partial_files::{start_unfinished, unfinished_dir};
use crate::scenario::{Scenario, ScenarioError};
use crate::score::scorer::{MapLandmark, RecallBasis, RunScorer, VisibilitySettings};
use events::EventSource;
use online::RunLoop;
use outputs::{FinishedRun, finish_stopped_run, publish_outputs, write_outputs};

/// Errors of a run.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    #[error(transparent)]
    Sim(#[from] sim::SimError),
    /// A pipeline setting of a scenario changed after it was read (read from a file, it was
    /// checked then): named by its file, or its name when built in code.
    #[error("{scenario}: pipeline.{setting}")]
    Pipeline { scenario: String, setting: slam::settings::InvalidSetting },
    #[error("method {method}: {message}")]
    Method { method: String, message: String },
    /// A scenario's setting, or a file it names, that a run cannot use: the scenario and
    /// the key say where it was set.
    #[error("{scenario}: {key}: {message}")]
    NamedFile { scenario: String, key: &'static str, message: String },
    #[error(
        "{scenario}: sim.laser.mount_yaw_deg = {yaw}: the pipeline's range-bearing model has no mounting yaw, so runs need a forward-facing laser (0)"
    )]
    YawedLaser { scenario: String, yaw: f64 },
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
    #[error(transparent)]
    AppearanceSetup(#[from] slam::pipeline::AppearanceSetupError),
    #[error("the camera stopped during the run: {0}")]
    CameraStopped(String),
    #[error("{count} {what} in image regions the camera did not render (a bug; `--full-frames` renders whole frames)")]
    Unrendered { what: &'static str, count: usize },
    #[error(transparent)]
    Objects(#[from] crate::objects::ObjectsError),
    /// Several outputs at a run's end could not be written (each was tried).
    #[error("{} outputs could not be written: {}", .0.len(), join_errors(.0))]
    Outputs(Vec<RunError>),
    /// A run's outputs could not all be written, so none replaced the directory's own: those
    /// written are in `dir`, the earlier outputs are as they were.
    #[error("{source}; the outputs written are in {}, and the directory's earlier outputs are unchanged", dir.display())]
    Unpublished { dir: PathBuf, source: Box<RunError> },
    #[error("--bag {}: it is the run's output directory; a bag needs a directory of its own", .0.display())]
    BagInOutputs(PathBuf),
    #[error(
        "--bag {}: it lies in {}, where the run writes its outputs first and which each run starts anew; a bag needs a directory of its own",
        bag.display(),
        staging.display()
    )]
    BagInStaging { bag: PathBuf, staging: PathBuf },
    #[error("--out {}: it lies inside the bag's directory {}; a bag needs a directory of its own", out.display(), bag.display())]
    OutputsInBag { out: PathBuf, bag: PathBuf },
    #[error(
        "{}: the {what} lies among the outputs of {}, which this run replaces or removes; copy it elsewhere or choose another output directory",
        file.display(),
        out.display()
    )]
    InputInOutputs { what: &'static str, file: PathBuf, out: PathBuf },
    #[error(
        "{}: its metadata.json was written by {tool}, not by an objslam run, so its files are not a run's to replace; choose another output directory",
        out.display()
    )]
    NotARunsMetadata { out: PathBuf, tool: String },
    #[error(
        "{}: it cannot be read ({problem}), so whether the directory holds an earlier run's outputs is unknown; repair or remove it, or choose another output directory",
        file.display()
    )]
    UnreadableMetadata { file: PathBuf, problem: String },
    /// Files of a run's names where no run was published: someone's own (or what a run
    /// stopped while publishing left), which publishing would replace or delete.
    #[error(
        "{}: it holds {name}, which a run writes or removes there, but no earlier run ({} is missing): it would be replaced or deleted; move it, or choose another output directory (if a stopped run left it, remove it)",
        out.display(),
        files::METADATA
    )]
    UnownedOutputs { name: &'static str, out: PathBuf },
    /// A Monte Carlo study's directory: the run's files would sit among its records, and the
    /// directory read as both.
    #[error(
        "{}: it holds a Monte Carlo study (study.json), whose directory is not a run's; choose another output directory",
        out.display()
    )]
    HoldsStudy { out: PathBuf },
    #[error(transparent)]
    Calibration(#[from] crate::calibrate::CalibrateError),
    #[error(transparent)]
    Ros2(#[from] crate::ros2::Ros2Error),
}

/// Errors' messages, one after another.
pub(crate) fn join_errors(errors: &[impl std::fmt::Display]) -> String {
    errors.iter().map(|e| e.to_string()).collect::<Vec<_>>().join("; ")
}

/// No error, the one error, or all of them made one by `several`: what a step that tries
/// every file before reporting returns.
pub(crate) fn first_or_all<E>(mut errors: Vec<E>, several: impl FnOnce(Vec<E>) -> E) -> Result<(), E> {
    match errors.len() {
        0 => Ok(()),
        1 => Err(errors.remove(0)),
        _ => Err(several(errors)),
    }
}

impl From<crate::partial_files::PartialFileError> for RunError {
    fn from(e: crate::partial_files::PartialFileError) -> Self {
        RunError::Io { file: e.file, source: e.source }
    }
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
            let camera = scenario.sim.camera.intrinsics();
            let e = crate::calibrate::load_extrinsics_for(&file, &camera).map_err(|e| RunError::NamedFile {
                scenario: scenario.describe(),
                key: "calibration",
                message: e.to_string(),
            })?;
            ("file", Some(std::path::absolute(&file).unwrap_or(file)), e, None)
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
    /// Render whole camera frames, not only the pixel regions the pipeline reads: the same
    /// results, more slowly (for checking exactly that).
    pub full_frames: bool,
    /// Also write the run's sensor stream as a ROS 2 bag in this directory (see
    /// [`crate::ros2`]); its frames are then rendered whole.
    pub bag: Option<PathBuf>,
}

/// Result of a run, with what the reports need.
pub struct RunOutcome {
    pub metrics: Metrics,
    pub resolved: serde_json::Value,
}

/// The pipeline settings of a scenario, with a method override and the laser's mounting.
/// Scenarios read from files were checked when parsed; this checks again for ones built or
/// changed in code.
pub fn pipeline_config(scenario: &Scenario, method: Option<AssociationMethod>) -> Result<PipelineConfig, RunError> {
    let mut config = scenario.pipeline.clone();
    config.validate().map_err(|setting| RunError::Pipeline { scenario: scenario.describe(), setting })?;
    if let Some(m) = method {
        config.method = m;
    }
    // The laser's mounting is known to the robot: the observation model uses it.
    config.sensor.mount_x = scenario.sim.laser.mount_xyz_m[0];
    config.sensor.mount_y = scenario.sim.laser.mount_xyz_m[1];
    Ok(config)
}

/// [`pipeline_config`] for a run, which also needs a laser the pipeline can read: its
/// observation model has no yaw term, so a laser turned on its mount would be misread
/// (recording such a laser is fine).
pub fn run_config(scenario: &Scenario, method: Option<AssociationMethod>) -> Result<PipelineConfig, RunError> {
    if scenario.sim.laser.mount_yaw_deg != 0.0 {
        return Err(RunError::YawedLaser { scenario: scenario.describe(), yaw: scenario.sim.laser.mount_yaw_deg });
    }
    pipeline_config(scenario, method)
}

/// A camera method needs the camera. Checked per run, not with the settings: a study's
/// other methods still run when the scenario has no camera.
fn check_camera(scenario: &Scenario, method: AssociationMethod) -> Result<(), RunError> {
    if method.uses_appearance() && !scenario.sim.camera.enabled {
        return Err(RunError::NamedFile {
            scenario: scenario.describe(),
            key: "sim.camera.enabled",
            message: format!("false, but the method {} needs the camera", method.name()),
        });
    }
    check_method_needs(scenario, method)
}

/// What `method` needs of the scenario's settings beyond a camera: a camera large enough,
/// and object models of no more dimensions than the model it trains. Checked when the
/// scenario was read for its own method; a method given for the run (`--method`, a
/// study's `--methods`, before its first run) is checked here, so that a run stops before
/// training a model it could not use.
pub fn check_method_needs(scenario: &Scenario, method: AssociationMethod) -> Result<(), RunError> {
    match scenario.camera_too_small_for(method).or_else(|| scenario.object_models_too_wide_for(method)) {
        Some((key, message)) => Err(RunError::NamedFile { scenario: scenario.describe(), key, message }),
        None => Ok(()),
    }
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
    scenario.appearance.resolve(base_dir, &scenario.sim.camera, progress).map_err(|e| {
        match &scenario.appearance.model {
            Some(_) => {
                RunError::NamedFile { scenario: scenario.describe(), key: "appearance.model", message: e.to_string() }
            }
            None => e.into(),
        }
    })
}

/// What [`preflight`] found: a scenario a run would start on.
#[derive(Debug, Clone)]
pub struct Preflight {
    pub method: AssociationMethod,
    pub objects: usize,
    pub people: usize,
    pub calibration: String,
    /// Where the appearance model comes from, for camera methods: a file (loaded and
    /// checked), or training (not done here).
    pub appearance: Option<String>,
}

/// Everything a run of `scenario` checks before its first step, without running it: the
/// settings, the method's needs, the world, a calibration file, an appearance model file
/// and the pipeline built from them. A model the run would train is not trained, and an
/// `estimated` calibration's session is not run: their settings were checked when the
/// scenario was read.
pub fn preflight(
    scenario: &Scenario,
    base_dir: &Path,
    method: Option<AssociationMethod>,
    seed: Option<u64>,
) -> Result<Preflight, RunError> {
    let seed = seed.unwrap_or(scenario.seed);
    let config = run_config(scenario, method)?;
    let camera_method = config.method.uses_appearance();
    check_camera(scenario, config.method)?;
    let world = scenario.world(base_dir, seed)?;
    // The recall's denominator counts trees: with none in the world it is undefined, and
    // every run would fail the criterion.
    if scenario.pass.min_tree_recall.is_some()
        && !world.objects.iter().any(|o| o.class == worlds::description::ObjectClass::Tree)
    {
        return Err(RunError::NamedFile {
            scenario: scenario.describe(),
            key: "pass.min_tree_recall",
            message: "the world holds no tree, so the recall is undefined and no run could pass; \
                      leave the criterion out"
                .into(),
        });
    }
    // The landmark RMSE pairs landmarks with trees, posts and palms: with none of them it
    // is undefined in every run.
    if scenario.pass.max_landmark_rmse_m.is_some()
        && !world.objects.iter().any(|o| {
            use worlds::description::ObjectClass::{Palm, Post, Tree};
            matches!(o.class, Tree | Post | Palm)
        })
    {
        return Err(RunError::NamedFile {
            scenario: scenario.describe(),
            key: "pass.max_landmark_rmse_m",
            message: "the world holds no tree, post or palm, so the landmark RMSE is undefined and no run \
                      could pass; leave the criterion out"
                .into(),
        });
    }
    let calibration = match scenario.calibration.mode.as_str() {
        "estimated" => None,
        _ => Some(resolve_calibration(scenario, base_dir, seed)?),
    };
    let mut appearance = None;
    let mut model = None;
    if camera_method {
        match &scenario.appearance.model {
            Some(file) => {
                let path = base_dir.join(file);
                let loaded = AppearanceModel::load(&path).map_err(crate::appearance::AppearanceError::from)?;
                appearance = Some(format!("file {}", path.display()));
                model = Some(loaded);
            }
            None => appearance = Some("trained from generated images (or the cache)".into()),
        }
    }
    let extrinsics =
        calibration.as_ref().map(|c| c.extrinsics).unwrap_or_else(|| crate::calibrate::true_extrinsics(&scenario.sim));
    // A camera method's pipeline needs its model: without the file, only the settings were
    // checked (by run_config).
    if !camera_method || model.is_some() {
        let appearance = match model {
            Some(m) => Some(Appearance::new(m, camera_geometry(&scenario.sim, &extrinsics))?),
            None => None,
        };
        let start = world.robot.start;
        Pipeline::new(config.clone(), [start.x, start.y, start.yaw_rad()], appearance)?;
    }
    Ok(Preflight {
        method: config.method,
        objects: world.objects.len(),
        people: world.people.len(),
        calibration: scenario.calibration.mode.clone(),
        appearance,
    })
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
    if let Some(out) = &options.out {
        check_inputs_outside_outputs(scenario, base_dir, out)?;
    }
    if let Some(bag) = &options.bag {
        check_bag_beside_outputs(bag, options.out.as_deref())?;
    }
    // Held until the outputs are published or abandoned.
    let lock = options.out.as_deref().map(crate::partial_files::lock_output).transpose()?;
    let mut under_hold = || {
        if let Some(out) = &options.out {
            // An earlier run stopped while its outputs were moved in: finished first, so
            // that its outputs are whole before this run replaces them.
            if finish_stopped_run(out)? {
                progress(RunProgress::Warning(format!(
                    "{}: finished moving in the outputs of an earlier run stopped while they were moved",
                    out.display()
                )));
            }
            check_earlier_outputs_are_a_runs(out)?;
        }
        run_and_write(scenario, base_dir, options, &mut progress)
    };
    crate::partial_files::abandon_if_failed(lock, options.out.as_deref(), under_hold())
}

/// Refuses a `--bag` directory before the run sets anything up (a model trained, a world
/// built): one no bag can be written into, the run's output directory (the bag's files
/// would sit among the run's, and the next run could not write its bag), or one that holds
/// the output directory (which would make it a directory that is not empty).
fn check_bag_beside_outputs(bag: &Path, out: Option<&Path>) -> Result<(), RunError> {
    if let Some(out) = out {
        // The output directory, or the folder its outputs are written in first (which
        // each run starts anew).
        if crate::partial_files::same_path(out, bag) {
            return Err(RunError::BagInOutputs(bag.to_path_buf()));
        }
        let staging = crate::partial_files::unfinished_dir(out);
        if crate::partial_files::same_path(&staging, bag) || crate::partial_files::lies_inside(bag, &staging) {
            return Err(RunError::BagInStaging { bag: bag.to_path_buf(), staging });
        }
        if crate::partial_files::lies_inside(out, bag) {
            return Err(RunError::OutputsInBag { out: out.to_path_buf(), bag: bag.to_path_buf() });
        }
    }
    Ok(crate::ros2::check_bag_dir(bag)?)
}

/// Refuses a scenario whose input files (see [`Scenario::input_files`]) lie in `out` under
/// a name the run writes or removes there ([`files::RUN_OUTPUTS`]): publishing the run's
/// outputs would replace or delete them, and the next run of the scenario could not read
/// them (a calibration estimated by the last run into the same directory, reused).
fn check_inputs_outside_outputs(scenario: &Scenario, base_dir: &Path, out: &Path) -> Result<(), RunError> {
    match files::input_among_outputs(out, files::RUN_OUTPUTS, scenario.input_files(base_dir)) {
        Some((what, file)) => Err(RunError::InputInOutputs { what, file, out: out.to_path_buf() }),
        None => Ok(()),
    }
}

/// Refuses an output directory that holds a file or folder of a run's output names but no
/// earlier run's `metadata.json`: a run replaces and removes what an earlier run wrote, not
/// a user's own files that happen to have those names (an `objects/` folder of notes).
fn check_earlier_outputs_are_a_runs(out: &Path) -> Result<(), RunError> {
    // Another command's finished outputs waiting to be moved in would be lost when the
    // run starts the unfinished directory anew (a run's own are only replaced).
    crate::partial_files::check_no_other_stopped_move(out, &[crate::partial_files::StoppedMove::Run])?;
    if out.join(crate::montecarlo::STUDY_FILE).exists() {
        return Err(RunError::HoldsStudy { out: out.to_path_buf() });
    }
    // An earlier run's own `metadata.json` (one another command or a user wrote is not).
    let file = out.join(files::METADATA);
    if std::fs::symlink_metadata(&file).is_ok() {
        let metadata = read_metadata(out).map_err(|problem| RunError::UnreadableMetadata { file, problem })?;
        return match metadata.get("tool").and_then(|t| t.as_str()) {
            Some("objslam run") => Ok(()),
            other => Err(RunError::NotARunsMetadata {
                out: out.to_path_buf(),
                tool: other.map_or_else(|| "no objslam command".to_string(), |t| format!("`{t}`")),
            }),
        };
    }
    match files::first_present(out, files::RUN_OUTPUTS) {
        Some(name) => Err(RunError::UnownedOutputs { name, out: out.to_path_buf() }),
        None => Ok(()),
    }
}

fn run_and_write(
    scenario: &Scenario,
    base_dir: &Path,
    options: &RunOptions,
    mut progress: impl FnMut(RunProgress),
) -> Result<RunOutcome, RunError> {
    // Setup: the method and its model, the world, the calibration, the simulator.
    let seed = options.seed.unwrap_or(scenario.seed);
    let config = run_config(scenario, options.method)?;
    let camera_method = config.method.uses_appearance();
    // The world before the model: a world that cannot be read, or a mesh file among the
    // outputs, is refused before minutes of training.
    let world = scenario.world(base_dir, seed)?;
    // The world's mesh files are inputs too: known once the world is read.
    if let Some(out) = &options.out
        && let Some((what, file)) = files::input_among_outputs(out, files::RUN_OUTPUTS, mesh_files(&world))
    {
        return Err(RunError::InputInOutputs { what, file, out: out.clone() });
    }
    let appearance_model = appearance_for(scenario, base_dir, options, &config, &mut progress)?;
    let calibration = resolve_calibration(scenario, base_dir, seed)?;
    let started = std::time::Instant::now();
    let sim_config = simulated_for(scenario, &config);
    let mut sim = Simulation::new(&world, &sim_config, sim::derive_seed(seed, "sim"))?;
    // Where the images came from: results depend on the renderer (metrics.renderer, and
    // the model's training renderer in metadata.json).
    let renderer = sim.camera_adapter().map(|a| a.to_string());
    let nominal = scenario.sim.max_duration_s.unwrap_or_else(|| sim.nominal_duration_s());
    let start = world.robot.start;
    let appearance = match &appearance_model {
        Some(m) => Some(Appearance::new((**m).clone(), camera_geometry(&scenario.sim, &calibration.extrinsics))?),
        None => None,
    };
    let pipeline = Pipeline::new(config.clone(), [start.x, start.y, start.yaw_rad()], appearance)?;
    // Every ground-truth figure; the recall's denominators come from the camera's true
    // extrinsics, whatever the run's calibration.
    let true_camera = sim_config.camera.enabled.then(|| camera_geometry(&scenario.sim, &calibration.truth));
    let basis = RecallBasis::of_method(config.method);
    let mut scorer = RunScorer::new(&world, true_camera, VisibilitySettings::of(&config), basis);
    if camera_method {
        scorer = scorer.scoring_segmentation();
    }
    // A bag holds whole images.
    let whole_frames = options.full_frames || options.bag.is_some();
    if !whole_frames {
        render_only_read_regions(&mut sim, &pipeline, &scorer, &config, &sim_config);
    }
    let mut bag = match &options.bag {
        // Staged like `record --format ros2`: a failed or stopped run leaves no half bag.
        Some(dir) => {
            let mut bag = crate::ros2::StagedBag::create(dir, &sim_config)?;
            let scoring = crate::score::log::LogScoring::of_run(scenario, seed, &config);
            let sim_seed = sim::derive_seed(seed, "sim");
            bag.attach_provenance(
                &crate::record::provenance("objslam run", &world, &sim_config, sim_seed, Some(&scoring)),
                &world,
            )?;
            Some(bag)
        }
        None => None,
    };

    // The loop.
    let streams = match &options.out {
        Some(out) => Some(outputs::stream_outputs(&start_unfinished(out)?, sim_config.camera.enabled, camera_method)?),
        None => None,
    };
    let spent_frames = sim.camera_frame_pool();
    let mut online = RunLoop::new(pipeline, scorer, &world, streams, sim_config.physics_rate_hz, spent_frames);
    let mut last_progress = -1.0;
    let mut events = EventSource::start(sim, &mut |w| progress(RunProgress::Warning(w)));
    while let Some(event) = events.next() {
        if let Some(bag) = &mut bag {
            bag.write(&event)?;
        }
        let t = event.time();
        online.on_event(event)?;
        if t - last_progress >= 1.0 {
            progress(RunProgress::Simulated { t, total: nominal });
            last_progress = t;
        }
    }
    let (sim, sim_time) = events.finish();
    if let Some(bag) = bag {
        bag.finish()?;
    }
    check_complete(&sim, &online, camera_method)?;
    progress(RunProgress::Simulated { t: sim.time(), total: nominal });
    let wall = started.elapsed().as_secs_f64();

    // Finish: the scores.
    let RunLoop { pipeline, scorer, mut log, streams, .. } = online;
    log.collisions = sim.collisions().iter().map(|c| crate::record::collision_line(c) + "\n").collect();
    let map_landmarks: Vec<MapLandmark> =
        pipeline.mapped_landmarks().iter().map(|l| MapLandmark { id: l.id, position: l.position }).collect();
    let scored = scorer.finish(&map_landmarks);
    let model_provenance = appearance_model.as_deref().map(ModelProvenance::of);
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
        map: scored.map,
        landmarks: scored.landmarks,
        associations: scored.associations,
        duplicate_landmarks: scored.duplicate_landmarks,
        merged_landmarks: log.merged,
        relinearisations: log.solves.iter().filter(|(_, r)| r.is_ok()).count(),
        relinearisation_failures: log.solves.iter().filter(|(_, r)| r.is_err()).count(),
        retracted_landmarks: RetractionCounts { total: scored.retracted, trees: scored.retracted_trees },
        false_landmarks: scored.false_landmarks,
        segmentation: scored.patches.as_ref().map(SegmentationScore::of).unwrap_or_default(),
        calibration: Some(CalibrationScore {
            mode: calibration.mode.clone(),
            rotation_error_deg: calibration.rotation_error_deg,
            translation_error_m: calibration.translation_error_m,
        }),
        odometry_calibration: odometry_calibration_score(pipeline.ekf(), sim.odometry_errors()),
        anees: scored.anees,
        collisions: sim.collisions().len(),
        route_completed: sim.route_completed(),
        passed: false,
        failures: vec![],
        timing: Timing {
            simulator_s: sim_time,
            pipeline_s: log.event_s,
            scans: log.scans,
            mean_scan_ms: if log.scans > 0 { 1000.0 * log.scan_s / log.scans as f64 } else { 0.0 },
            rendered_fraction: if log.pixels_framed > 0 {
                log.pixels_rendered as f64 / log.pixels_framed as f64
            } else {
                0.0
            },
        },
        renderer,
        appearance_model: model_provenance,
    };
    metrics.failures = check_pass(&scenario.pass, &metrics.pass_figures());
    metrics.passed = metrics.failures.is_empty();
    // The scenario with the command line's seed and method written in, and the files it
    // names made absolute, so that it alone runs this run again.
    let mut as_run = scenario.with_absolute_paths(base_dir);
    as_run.seed = seed;
    as_run.pipeline.method = config.method;
    // A preset's parameters as generated, so that another build's defaults do not decide.
    if as_run.world.preset.as_deref() == Some("park") && as_run.world.params.is_none() {
        as_run.world.params = Some(worlds::generate::ParkParams::default());
    }
    let mut resolved = json!({
        "scenario": as_run,
        "seed": seed,
        "sim_seed": sim::derive_seed(seed, "sim"),
        "world": world,
        // The simulator as it ran: the scenario's, with the camera off for position-only
        // methods and without the depth image nobody reads.
        "sim": sim_config,
        // The limit the run stopped at, derived from the route where sim.max_duration_s is
        // not set.
        "time_limit_s": sim.time_limit_s(),
        "pipeline": config,
        "calibration": calibration,
    });
    if options.out.is_some() {
        // What the files the scenario names held, to tell a later run of it whether they
        // changed; read only for a run whose metadata records it (not for a study's runs).
        resolved["inputs"] = json!(input_digests(scenario, base_dir, &world));
    }

    // Write.
    if let Some(out) = &options.out {
        // Everything is written into the unfinished directory first and moved into `out`
        // only when all of it was written: a run stopped or failing here leaves `out`'s
        // earlier outputs whole, never a mix of two runs.
        let unfinished = unfinished_dir(out);
        if let Some(report) = &calibration.report {
            report.write(&unfinished.join(files::CALIBRATION))?;
        }
        let scoring = crate::score::log::LogScoring::of_run(scenario, seed, &config);
        let finished = FinishedRun {
            world: &world,
            pipeline: &pipeline,
            metrics: &metrics,
            resolved: &resolved,
            as_run: &as_run,
            log: &log,
            landmark_objects: &scored.landmark_objects,
            sim_config: &sim_config,
            scoring: &scoring,
        };
        write_outputs(&unfinished, &finished, streams.expect("a run with outputs streams them"))
            .map_err(|e| RunError::Unpublished { dir: unfinished.clone(), source: Box::new(e) })?;
        publish_outputs(&unfinished, out)?;
    }
    Ok(RunOutcome { metrics, resolved })
}

/// Each file a run of `scenario` in `world` reads, with what it is and its SHA-256 (`null`
/// where it cannot be read: the run has failed on it already, or it changed under the
/// run): the scenario's files and the world's mesh files.
fn input_digests(scenario: &Scenario, base_dir: &Path, world: &worlds::World) -> Vec<serde_json::Value> {
    let mut inputs: Vec<(&str, PathBuf)> = scenario.input_files(base_dir);
    for mesh in mesh_files(world) {
        if !inputs.iter().any(|(_, f)| *f == mesh.1) {
            inputs.push(mesh);
        }
    }
    inputs
        .into_iter()
        .map(|(what, file)| {
            let file = files::recorded_path(&file);
            json!({"what": what, "file": file, "sha256": files::sha256_hex(&file)})
        })
        .collect()
}

/// The mesh files `world`'s objects are drawn from (as the world file resolved them).
fn mesh_files(world: &worlds::World) -> Vec<(&'static str, PathBuf)> {
    world.objects.iter().filter_map(|o| o.mesh.as_ref()).map(|m| ("mesh file", PathBuf::from(m))).collect()
}

/// The `metadata.json` of the run that wrote `scenario_file`, where that is a run's
/// `scenario.toml` beside it; `None` for any other scenario file.
pub fn recorded_run(scenario_file: &Path) -> Option<serde_json::Value> {
    if scenario_file.file_name().is_none_or(|n| n != files::SCENARIO) {
        return None;
    }
    let metadata = read_metadata(scenario_file.parent()?).ok()?;
    (metadata["tool"] == "objslam run").then_some(metadata)
}

/// `dir`'s `metadata.json` as JSON, or why it cannot be read as such.
fn read_metadata(dir: &Path) -> Result<serde_json::Value, String> {
    let text = std::fs::read_to_string(dir.join(files::METADATA)).map_err(|e| e.to_string())?;
    serde_json::from_str(&text).map_err(|e| format!("not JSON: {e}"))
}

/// Where `scenario_file` is the `scenario.toml` a run wrote, the files that run read which
/// this run of `scenario` (read from it) reads too and which differ now from what the
/// run's `metadata.json` recorded, in words: this run may not repeat that one. Empty for
/// any other scenario file.
pub fn changed_inputs(scenario_file: &Path, scenario: &Scenario, base_dir: &Path) -> Vec<String> {
    let Some(metadata) = recorded_run(scenario_file) else { return Vec::new() };
    let named: Vec<PathBuf> =
        scenario.input_files(base_dir).into_iter().map(|(_, f)| files::recorded_path(&f)).collect();
    let recorded = metadata["configuration"]["inputs"].as_array().cloned().unwrap_or_default();
    recorded
        .iter()
        .filter(|input| input["what"] != "scenario file")
        .filter_map(|input| {
            let (what, file, then) = (input["what"].as_str()?, input["file"].as_str()?, input["sha256"].as_str()?);
            // A file the scenario no longer names is no longer this run's; a mesh is the world's.
            // Runs recorded before paths were resolved name them as given.
            if what != "mesh file" && !named.iter().any(|n| *n == files::recorded_path(Path::new(file))) {
                return None;
            }
            let by = scenario_file.display();
            match files::sha256_hex(Path::new(file)) {
                Some(now) if now == then => None,
                Some(now) => Some(format!(
                    "{what} {file} has changed since the run that wrote {by} read it (SHA-256 {} then, {} now): this run may not repeat that one",
                    &then[..then.len().min(12)],
                    &now[..12]
                )),
                None => Some(format!("{what} {file} cannot be read any more; the run that wrote {by} read it")),
            }
        })
        .collect()
}

/// Where `scenario_file` is a run's `scenario.toml`, whether the appearance model of a new
/// run of it (`now`, its digest) differs from the recorded run's: a trained model comes
/// from the cache, which the scenario does not pin.
pub fn changed_model(scenario_file: &Path, now: Option<&ModelProvenance>) -> Option<String> {
    let metadata = recorded_run(scenario_file)?;
    let then = metadata["appearance_model"]["digest"].as_str()?;
    let now = now?.digest.as_deref()?;
    (then != now).then(|| {
        format!(
            "the appearance model (digest {now}) is not the one the run that wrote {} used ({then}): another cache, renderer or build trained it; this run may not repeat that one",
            scenario_file.display()
        )
    })
}

/// The appearance model a camera method needs: the one given, or the scenario's (trained on
/// first use, reported to `progress`); `None` for the position-only methods.
fn appearance_for(
    scenario: &Scenario,
    base_dir: &Path,
    options: &RunOptions,
    config: &PipelineConfig,
    progress: &mut impl FnMut(RunProgress),
) -> Result<Option<std::sync::Arc<AppearanceModel>>, RunError> {
    if !config.method.uses_appearance() {
        return Ok(None);
    }
    check_camera(scenario, config.method)?;
    if let Some(m) = &options.appearance {
        return Ok(Some(m.clone()));
    }
    // Training reports through a shared reference; the run's callback is FnMut.
    let progress = std::cell::RefCell::new(progress);
    let model = resolve_appearance(scenario, base_dir, |stage, done, total| {
        (progress.borrow_mut())(RunProgress::Training { stage, done, total })
    })?;
    Ok(Some(std::sync::Arc::new(model)))
}

/// The simulator as a run of `config`'s method uses it: position-only methods never look at
/// images, so none are rendered; no method reads depth, so it is not rendered either.
fn simulated_for(scenario: &Scenario, config: &PipelineConfig) -> sim::SimConfig {
    let mut sim_config = scenario.sim.clone();
    if !config.method.uses_appearance() {
        sim_config.camera.enabled = false;
    }
    sim_config.camera.depth_image = false;
    sim_config
}

/// Has the camera render only the regions segmentation will read, chosen from the scan of
/// the frame's instant as the pipeline will cluster it (most of each frame is never read),
/// and the pixels the ground-truth tree count reads, so that the count does not depend on
/// what the method asked for. Only where no other scan can use the frame (one within
/// `image_max_age_s` of it): sensors fire on the first physics step at or after their
/// time, so two scans can be up to a step closer than the laser's period.
fn render_only_read_regions(
    sim: &mut Simulation,
    pipeline: &Pipeline,
    scorer: &RunScorer,
    config: &PipelineConfig,
    sim_config: &sim::SimConfig,
) {
    let frame_read_by_one_scan =
        config.image_max_age_s < 1.0 / sim_config.laser.rate_hz - 1.0 / sim_config.physics_rate_hz;
    if let Some(region) = pipeline.image_region().filter(|_| frame_read_by_one_scan) {
        let truth_pixels = scorer.visibility().clone();
        sim.render_camera_regions(Box::new(move |scan, beams| {
            merge_regions([region.regions(&slam_scan(scan)), truth_pixels.regions(scan, beams)].concat())
                .into_iter()
                .map(|r| render::Region { columns: r.columns, rows: r.rows })
                .collect()
        }));
    }
}

/// Refuses a run whose scores would not be the method's: a camera that stopped (a lost GPU
/// device) left a camera method blind for the rest of the run, or pixels were read where
/// none were rendered.
fn check_complete(sim: &Simulation, online: &RunLoop, camera_method: bool) -> Result<(), RunError> {
    if let Some(e) = sim.camera_error().filter(|_| camera_method) {
        return Err(RunError::CameraStopped(e.to_string()));
    }
    if online.pipeline.unrendered_reads() > 0 {
        return Err(RunError::Unrendered {
            what: "clusters were not segmented: they read pixels",
            count: online.pipeline.unrendered_reads(),
        });
    }
    if online.scorer.unrendered_reads() > 0 {
        return Err(RunError::Unrendered {
            what: "pixels read by the tree-recall count lie",
            count: online.scorer.unrendered_reads(),
        });
    }
    Ok(())
}
