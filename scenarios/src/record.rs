//! `objslam record`: a sensor log that other SLAM systems can read (schema in docs/guide/simulator.md).
//!
//! - `laser.jsonl`: one scan per line, like ROS LaserScan (`null` = no return, `"-inf"` =
//!   too close to measure);
//! - `odometry.jsonl`: incremental odometry (t, dx, dy, dtheta) in the previous robot frame;
//! - `ground_truth.tum`: the robot base pose in TUM format at the odometry rate;
//! - `laser_truth.jsonl`: per scan, the instance id each beam hit and its noise-free range
//!   (scoring only);
//! - `observations.jsonl`: per scan, the laser clusters as the scenario's pipeline makes
//!   them, whose ids a system may use to report its associations to `objslam score`;
//! - `sensors.json`: sensor mountings and rates; `world.toml`: the world;
//! - `collisions.jsonl`: robot contacts; `metadata.json`: seed, configuration, versions;
//! - `run.mcap`: the same with Foxglove schemas (PointCloud of the laser's returns,
//!   FrameTransform, PosesInFrame, images):
//!   `/tf` is odom -> base_link from the noisy odometry, `/odom` its poses, `/tf_static`
//!   base_link -> laser and camera_optical; the truth is on `/ground_truth/*` only.

use crate::files;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use serde_json::json;
use sim::{SensorEvent, SimConfig, Simulation};

use crate::foxglove::{McapWriter, pose_json, timestamp, yaw_quaternion};

/// Errors while recording.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error("{}: {source}", file.display())]
    Io { file: PathBuf, source: std::io::Error },
    #[error(transparent)]
    Sim(#[from] sim::SimError),
    #[error(transparent)]
    Mcap(#[from] crate::foxglove::McapError),
    #[error(transparent)]
    Ros2(#[from] crate::ros2::Ros2Error),
    #[error(transparent)]
    Log(#[from] robotlog::LogError),
    #[error("the camera stopped during the recording, so the log would lack its later frames: {0}")]
    CameraStopped(String),
    #[error(transparent)]
    Output(#[from] crate::partial_files::PartialFileError),
    /// Files that could not be moved into the output directory (each was tried); the
    /// recording's others are in place.
    #[error("{}", crate::run::join_errors(.0))]
    Publish(Vec<crate::partial_files::PartialFileError>),
    #[error(transparent)]
    Model(#[from] slam::classifier::ModelError),
    /// A ROS 2 bag is often data brought from elsewhere (a real robot's): a recording of
    /// another kind replaces an earlier one's files, but never removes a bag.
    #[error(
        "{} holds a ROS 2 bag ({}): a directory holds one recording, and a bag is not replaced; record into another directory or remove the bag first",
        dir.display(),
        ros2bag::METADATA_FILE
    )]
    HoldsBag { dir: PathBuf },
    /// A run's directory holds its estimate beside its log: a recording there would leave
    /// the run's trajectory and map beside another world's truth, to be scored as one.
    #[error(
        "{} holds a run's outputs ({}): a directory holds one recording or one run; record into another directory",
        dir.display(),
        files::METRICS
    )]
    HoldsRun { dir: PathBuf },
    /// A robot log that no recording wrote (a real robot's, written by hand or by a
    /// converter): the recording would replace or remove its files.
    #[error(
        "{} holds a robot log that objslam record did not write ({} but no {}): its files would be replaced or removed; record into another directory",
        dir.display(),
        robotlog::format::MANIFEST,
        files::RECORDING
    )]
    HoldsRobotLog { dir: PathBuf },
    /// Files of a recording's names where no recording was made (a user's `camera/`, another
    /// command's `world.toml`): the recording would replace or remove them.
    #[error(
        "{} holds {name}, which a recording writes or removes, but no earlier recording (no {} of objslam record, no {}): it would be replaced or removed; record into another directory",
        dir.display(),
        files::METADATA,
        files::RECORDING
    )]
    HoldsOtherFiles { dir: PathBuf, name: &'static str },
}

/// What `objslam record` writes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum RecordFormat {
    /// JSON lines, TUM, PNG images and a Foxglove MCAP in one directory.
    #[default]
    Jsonl,
    /// A ROS 2 bag: the directory holds `metadata.yaml` and one MCAP of CDR messages.
    Ros2,
    /// A robot log (docs/reference/robot-log.md): plain CSV files that `objslam replay`
    /// reads, as it reads a real robot's.
    Log,
}

/// What a recording contains.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RecordSummary {
    pub sim_seconds: f64,
    pub wall_seconds: f64,
    pub scans: usize,
    pub odometry: usize,
    pub camera_frames: usize,
    /// The adapter that rendered the camera frames.
    pub renderer: Option<String>,
    pub collisions: usize,
    /// Whether the robot finished its route (the rule `objslam run` scores).
    pub route_completed: bool,
}

struct Out {
    file: PathBuf,
    w: BufWriter<File>,
}

impl Out {
    fn create(dir: &Path, name: &str) -> Result<Self, RecordError> {
        let file = dir.join(name);
        let f = File::create(&file).map_err(|source| RecordError::Io { file: file.clone(), source })?;
        Ok(Out { file, w: BufWriter::new(f) })
    }

    fn line(&mut self, s: &str) -> Result<(), RecordError> {
        writeln!(self.w, "{s}").map_err(|source| RecordError::Io { file: self.file.clone(), source })
    }

    fn finish(mut self) -> Result<(), RecordError> {
        self.w.flush().map_err(|source| RecordError::Io { file: self.file.clone(), source })
    }
}

/// Standard base64 for embedding PNGs in JSON messages.
pub fn base64(bytes: &[u8]) -> String {
    use base64::Engine;
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

/// The pose `pose` (x, y, theta) moved by the odometry increment `o`, which is given in
/// the robot frame at `pose`: how the `odom` frame's pose is integrated.
pub fn integrate_odometry(pose: [f64; 3], o: &sim::Odometry) -> [f64; 3] {
    let (s, c) = pose[2].sin_cos();
    [pose[0] + c * o.dx - s * o.dy, pose[1] + s * o.dx + c * o.dy, sim::wrap_angle(pose[2] + o.dtheta)]
}

/// A rotation matrix (row-major) as a unit quaternion [x, y, z, w].
pub fn rotation_quaternion(r: &[[f64; 3]; 3]) -> [f64; 4] {
    let q = nalgebra::UnitQuaternion::from_matrix(&nalgebra::Matrix3::from_fn(|i, j| r[i][j]));
    [q.i, q.j, q.k, q.w]
}

/// The header line of a TUM trajectory file, with its newline.
pub const TUM_HEADER: &str = "# timestamp tx ty tz qx qy qz qw\n";

/// A TUM trajectory line: `timestamp tx ty tz qx qy qz qw`, each number written with as
/// many digits as it takes to read back the same `f64` (so that `objslam score` sees
/// exactly what `objslam run` scored).
pub fn tum_line(t: f64, x: f64, y: f64, yaw: f64) -> String {
    let q = yaw_quaternion(yaw);
    format!("{t} {x} {y} 0 {} {} {} {}", q[0], q[1], q[2], q[3])
}

/// An odometry message's line of `odometry.jsonl`.
pub fn odometry_line(o: &sim::Odometry) -> String {
    serde_json::to_string(o).expect("JSON")
}

/// A contact's line of `collisions.jsonl`.
pub fn collision_line(c: &sim::Collision) -> String {
    serde_json::to_string(c).expect("JSON")
}

/// A scan's line of `laser.jsonl`.
pub fn laser_line(scan: &sim::LaserScan) -> String {
    serde_json::to_string(scan).expect("JSON")
}

/// A scan's line of `laser_truth.jsonl`: the instance id each beam hit and its noise-free
/// range, with the scan's time.
pub fn laser_truth_line(t: f64, beams: &sim::LaserTruth) -> String {
    let mut line = serde_json::to_value(beams).expect("JSON");
    line["t"] = json!(t);
    serde_json::to_string(&line).expect("JSON")
}

/// A scan's line of `observations.jsonl`: the laser clusters the pipeline's clustering makes
/// of it, in order. An observation's index in the list is its id within the scan, the id
/// that `decisions.jsonl` and `objslam score --associations` refer to.
pub fn observations_line(t: f64, clusters: &[slam::clustering::Cluster]) -> String {
    let observations: Vec<_> = clusters
        .iter()
        .map(|c| {
            json!({"first_beam": c.first_beam, "last_beam": c.last_beam, "range_m": c.range_m,
                   "bearing_rad": c.bearing_rad, "diameter_m": c.diameter_m, "occluded": c.occluded})
        })
        .collect();
    serde_json::to_string(&json!({"t": t, "observations": observations})).expect("JSON")
}

/// The sensor mountings as written to `sensors.json`.
pub fn sensors_json(config: &SimConfig) -> serde_json::Value {
    let l = &config.laser;
    json!({
        "base_frame": "base_link",
        "laser": {
            "frame_id": "laser",
            "parent_frame_id": "base_link",
            "translation_m": l.mount_xyz_m,
            "yaw_deg": l.mount_yaw_deg,
            "fov_deg": l.fov_deg,
            "resolution_deg": l.resolution_deg.degrees(),
            "beams": l.beam_count(),
            "angle_min_rad": l.angle_min_rad(),
            "angle_increment_rad": l.angle_increment_rad(),
            "range_min_m": l.min_range_m,
            "range_max_m": l.max_range_m,
            "range_noise_sigma_m": l.range_noise_sigma_m,
            "range_quantum_m": l.quantum_m(),
            "rate_hz": l.rate_hz
        },
        "odometry": {"frame_id": "base_link", "rate_hz": config.odometry.rate_hz, "error_model": config.odometry},
        "camera": camera_json(config),
        "robot": config.robot,
    })
}

/// The camera's mounting, intrinsics and the laser <- camera extrinsics for `sensors.json`.
pub fn camera_json(config: &SimConfig) -> serde_json::Value {
    let c = &config.camera;
    let k = c.intrinsics();
    let base = c.base_from_camera();
    let e = c.laser_from_camera(&config.laser);
    json!({
        "enabled": c.enabled,
        "frame_id": "camera_optical",
        "parent_frame_id": "base_link",
        "convention": "optical frame: z forward, x right, y down",
        "width": c.width,
        "height": c.height,
        "K": k.k(),
        "rate_hz": c.rate_hz,
        "mount_xyz_m": c.mount_xyz_m,
        "mount_pitch_deg": c.mount_pitch_deg,
        "mount_yaw_deg": c.mount_yaw_deg,
        "base_from_camera": {"rotation": base.r, "translation_m": base.t},
        "laser_from_camera": {"description": "P_laser = Phi P_camera + Delta (the paper's extrinsics)", "Phi": e.r, "Delta_m": e.t},
    })
}

/// Fast PNG encoding (recordings write many frames).
pub fn write_png(
    path: &Path,
    width: u32,
    height: u32,
    color: image::ExtendedColorType,
    bytes: &[u8],
) -> Result<Vec<u8>, RecordError> {
    use image::ImageEncoder;
    let io = |e: std::io::Error| RecordError::Io { file: path.to_path_buf(), source: e };
    let mut png = Vec::new();
    let enc = image::codecs::png::PngEncoder::new_with_quality(
        &mut png,
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Sub,
    );
    enc.write_image(bytes, width, height, color).map_err(|e| io(std::io::Error::other(e.to_string())))?;
    std::fs::write(path, &png).map_err(io)?;
    Ok(png)
}

/// The images of one camera frame as written: names relative to the camera directory's
/// parent.
pub struct FrameFiles {
    pub image: String,
    pub instance: String,
    pub class: String,
    /// `None` when the camera renders no depth.
    pub depth: Option<String>,
    /// The colour PNG's bytes (for the MCAP).
    pub colour_png: Vec<u8>,
}

/// Writes a camera frame's images: colour, 16-bit instance ids, 8-bit classes and, when the
/// camera renders depth (`sim.camera.depth_image`), 16-bit depth in millimetres (0 =
/// nothing). Returns the files written.
pub fn write_camera_frame(
    dir: &Path,
    index: usize,
    frame: &sim::camera::CameraFrame,
) -> Result<FrameFiles, RecordError> {
    let img = &frame.image;
    let names = [
        format!("camera/{index:06}.png"),
        format!("camera/{index:06}_instance.png"),
        format!("camera/{index:06}_class.png"),
    ];
    let depth_name = (!img.depth_m.is_empty()).then(|| format!("camera/{index:06}_depth.png"));
    let root = dir.parent().unwrap_or(dir);
    // The image crate takes 16-bit samples in native byte order (it writes PNG's big-endian).
    let inst: Vec<u8> = img.instance.iter().flat_map(|v| v.to_ne_bytes()).collect();
    let depth: Vec<u8> = img
        .depth_m
        .iter()
        .flat_map(|d| (if d.is_finite() { (d * 1000.0).round().clamp(1.0, 65535.0) as u16 } else { 0 }).to_ne_bytes())
        .collect();
    // Encoding dominates recording time: the four images in parallel.
    let mut jobs: Vec<(&String, image::ExtendedColorType, &[u8])> = vec![
        (&names[0], image::ExtendedColorType::Rgb8, &img.rgb),
        (&names[1], image::ExtendedColorType::L16, &inst),
        (&names[2], image::ExtendedColorType::L8, &img.class),
    ];
    if let Some(name) = &depth_name {
        jobs.push((name, image::ExtendedColorType::L16, &depth));
    }
    use rayon::prelude::*;
    let mut pngs = jobs
        .par_iter()
        .map(|(name, color, bytes)| write_png(&root.join(name), img.width, img.height, *color, bytes))
        .collect::<Result<Vec<Vec<u8>>, RecordError>>()?;
    let colour_png = pngs.swap_remove(0);
    let [image, instance, class] = names;
    Ok(FrameFiles { image, instance, class, depth: depth_name, colour_png })
}

/// Records a run of `world` into `out` in `format`, the simulator seeded with `seed`.
/// `scoring` says how `objslam score` is to score systems on a JSON-lines log. `progress`
/// is called with (sim time, nominal duration) now and then. A JSON-lines log or robot log
/// replaces what `out` held only when written whole (see [`staged`]); a ROS 2 bag needs a
/// new or empty directory, and appears in it only when written whole
/// ([`record_ros2_staged`]).
pub fn record(
    world: &worlds::World,
    config: &SimConfig,
    seed: u64,
    scoring: &crate::score::log::LogScoring,
    out: &Path,
    format: RecordFormat,
    progress: impl FnMut(f64, f64),
) -> Result<RecordSummary, RecordError> {
    match format {
        RecordFormat::Jsonl => staged(out, |dir| record_jsonl(world, config, seed, scoring, dir, progress)),
        RecordFormat::Ros2 => record_ros2_staged(world, config, seed, scoring, out, progress),
        RecordFormat::Log => {
            record_log(world, config, seed, LogSettings { scoring: Some(scoring), ..Default::default() }, out, progress)
        }
    }
}

/// Files of either kind of log, those of a robot log and those of a JSON-lines log, that
/// not every recording writes: removed from `out` when a recording's own are moved in, so
/// that what `out` holds afterwards is never an earlier log's data mixed with the new
/// one's. The two kinds share names (`camera/`, `world.toml`), so a recording of one kind
/// clears the other's files too: a directory holds one recording.
pub fn recording_files() -> [&'static str; 21] {
    use robotlog::format as f;
    [
        // Both kinds' markers first: a move stopped after them leaves no marker over a mix.
        f::MANIFEST,
        files::METADATA,
        f::ODOMETRY,
        f::SCANS,
        f::DETECTIONS,
        f::REFERENCE,
        f::CAMERA,
        files::CAMERA_DIR,
        files::PIPELINE,
        files::APPEARANCE_MODEL,
        files::RECORDING,
        files::WORLD,
        files::SENSORS,
        files::LASER,
        files::LASER_TRUTH,
        files::OBSERVATIONS,
        files::ODOMETRY,
        files::GROUND_TRUTH,
        files::MCAP,
        files::CAMERA_LOG,
        files::COLLISIONS,
    ]
}

/// Runs `write` on `out`'s unfinished directory, holding `out` against other commands, and
/// moves what it wrote into `out` only when it succeeded: a recording stopped or failing on
/// the way leaves `out`'s earlier recording whole. A failed recording's files are removed;
/// where the move itself fails, they stay in the unfinished directory, which the error names.
fn staged(
    out: &Path,
    write: impl FnOnce(&Path) -> Result<RecordSummary, RecordError>,
) -> Result<RecordSummary, RecordError> {
    use crate::partial_files as staging;
    // Checked under the hold, before the unfinished directory is started anew: a refused
    // recording leaves what another command left there.
    let check = || {
        finish_stopped_recording(out)?;
        staging::check_no_other_stopped_move(out, &[])?;
        if out.join(ros2bag::METADATA_FILE).exists() {
            return Err(RecordError::HoldsBag { dir: out.to_path_buf() });
        }
        if out.join(files::METRICS).exists() {
            return Err(RecordError::HoldsRun { dir: out.to_path_buf() });
        }
        if out.join(robotlog::format::MANIFEST).exists() && !out.join(files::RECORDING).exists() {
            return Err(RecordError::HoldsRobotLog { dir: out.to_path_buf() });
        }
        // Files of a recording's names with no recording's marker are someone's own.
        if !holds_recording(out)
            && let Some(name) = files::first_present(out, &recording_files())
        {
            return Err(RecordError::HoldsOtherFiles { dir: out.to_path_buf(), name });
        }
        Ok(())
    };
    let (summary, _held) = staging::write_unfinished(out, check, write)?;
    publish_recording(out, false)?;
    Ok(summary)
}

/// Moves a finished recording from `out`'s unfinished directory into `out`, after removing
/// the earlier recording's names there; `finishing`, one whose move was stopped. A robot
/// log is marked finished by its manifest, a JSON-lines log by its metadata, and the
/// marker goes last.
fn publish_recording(out: &Path, finishing: bool) -> Result<(), RecordError> {
    use crate::partial_files::{finish_publish, publish, unfinished_dir};
    let unfinished = unfinished_dir(out);
    let marker =
        if unfinished.join(robotlog::format::MANIFEST).exists() { robotlog::format::MANIFEST } else { files::METADATA };
    let move_in = if finishing { finish_publish } else { publish };
    move_in(&unfinished, out, &recording_files(), marker).map_err(RecordError::Publish)
}

/// Whether `dir` holds a recording's marker: a JSON-lines log's `metadata.json` written by
/// `objslam record`, or a robot log's manifest with the `recording.json` that record writes.
fn holds_recording(dir: &Path) -> bool {
    let by_record = std::fs::read(dir.join(files::METADATA))
        .ok()
        .and_then(|bytes| serde_json::from_slice::<serde_json::Value>(&bytes).ok())
        .is_some_and(|m| m["tool"] == "objslam record");
    by_record || (dir.join(robotlog::format::MANIFEST).is_file() && dir.join(files::RECORDING).is_file())
}

/// Finishes moving in a recording whose move into `out` was stopped (its marker, which goes
/// last, still waits in the unfinished directory, and `out` has none): the next recording
/// starts the unfinished directory anew, and without this a second stop would leave `out`
/// with a recording's files and no marker, which no recording would take again.
fn finish_stopped_recording(out: &Path) -> Result<(), RecordError> {
    // Called under the hold: no recording is in `out`, and a whole marker waits (a robot
    // log's `recording.json` may have been moved in already; a marker cut short by a stop
    // while written is no finished move). The move's list of what it brings in tells the
    // earlier outputs' leftovers from what it moved in already.
    use crate::partial_files::{StoppedMove, stopped_move};
    if !holds_recording(out) && stopped_move(out) == Some(StoppedMove::Recording) {
        publish_recording(out, true)?;
    }
    Ok(())
}

/// What a robot log recorded from a scenario carries beside the sensor data, so that
/// `objslam replay` estimates what `objslam run` does.
#[derive(Debug, Clone, Copy, Default)]
pub struct LogSettings<'a> {
    /// The scenario's pipeline settings, written as `pipeline.toml`.
    pub pipeline: Option<&'a slam::pipeline::PipelineConfig>,
    /// The laser <- camera extrinsics the run gives its pipeline (the true ones if `None`).
    pub calibration: Option<&'a slam::calibration::Extrinsics>,
    /// The appearance model the run uses, written as `appearance_model.json` where the log
    /// has camera frames.
    pub appearance_model: Option<&'a slam::classifier::AppearanceModel>,
    /// The scenario and run seed it was recorded for, written into `recording.json`.
    pub scoring: Option<&'a crate::score::log::LogScoring>,
}

/// How a recording was made, enough to make it again: the command (`tool`), the simulator seed, the world's name
/// and seed, the simulator settings and the scenario with its run seed (`scoring`). A
/// JSON-lines log's `metadata.json` holds it with a summary; a robot log has it as
/// `recording.json` and a ROS 2 bag as an MCAP attachment of that name, each without the
/// summary's wall clock, so that the same recording gives the same bytes.
pub fn provenance(
    tool: &str,
    world: &worlds::World,
    config: &SimConfig,
    seed: u64,
    scoring: Option<&crate::score::log::LogScoring>,
) -> serde_json::Value {
    json!({
        "tool": tool,
        "version": env!("CARGO_PKG_VERSION"),
        "build": crate::build::current(),
        "seed": seed,
        "world": {"name": world.name, "seed": world.seed},
        "sim_config": config,
        "scoring": scoring,
    })
}

/// Whether [`record_log`] writes camera frames: where the camera is enabled and, for a
/// scenario (`pipeline` its settings), where its method reads them, as a run renders them.
pub fn logs_camera(config: &SimConfig, pipeline: Option<&slam::pipeline::PipelineConfig>) -> bool {
    config.camera.enabled && pipeline.is_none_or(|p| p.method.uses_appearance())
}

/// The simulation's stream as a robot log in `out` (see [`robotlog::format`]): the noisy
/// odometry, the raw laser scans, the camera's frames where the camera is enabled (for a
/// scenario, where its method also reads them, as a run renders them), and the robot's
/// true pose as the reference, with the scenario's `settings` beside them. The log replaces
/// what `out` held only when written whole.
pub fn record_log(
    world: &worlds::World,
    config: &SimConfig,
    seed: u64,
    settings: LogSettings,
    out: &Path,
    progress: impl FnMut(f64, f64),
) -> Result<RecordSummary, RecordError> {
    staged(out, |dir| write_log(world, config, seed, settings, dir, progress))
}

fn write_log(
    world: &worlds::World,
    config: &SimConfig,
    seed: u64,
    settings: LogSettings,
    out: &Path,
    mut progress: impl FnMut(f64, f64),
) -> Result<RecordSummary, RecordError> {
    let LogSettings { pipeline, calibration, appearance_model, scoring } = settings;
    let started = std::time::Instant::now();
    // A robot's camera gives colour: no depth is rendered. (The camera's noise is a stream
    // of its own: the other sensors' messages are the same with or without it.)
    let mut as_logged = config.clone();
    as_logged.camera.depth_image = false;
    as_logged.camera.enabled = logs_camera(config, pipeline);
    let config = &as_logged;
    let mut sim = Simulation::new(world, config, seed)?;
    let nominal = config.max_duration_s.unwrap_or_else(|| sim.nominal_duration_s());
    let (mut increments, mut scans, mut reference, mut frames) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut last_progress = -1.0;
    while let Some(event) = sim.next_event() {
        let t = event.time();
        match event {
            SensorEvent::Odometry { odometry: o, truth } => {
                increments.push(slam::messages::OdometryIncrement { t: o.t, dx: o.dx, dy: o.dy, dtheta: o.dtheta });
                let r = truth.robot;
                reference.push(robotlog::ReferenceSample { t: o.t, x: r.x, y: r.y, theta: Some(r.theta) });
            }
            SensorEvent::Laser { scan, .. } => scans.push(crate::run::slam_scan(&scan)),
            SensorEvent::Camera { frame, .. } => {
                let image =
                    robotlog::RgbImage { width: frame.image.width, height: frame.image.height, rgb: frame.image.rgb };
                frames.push(robotlog::format::write_frame(out, frames.len(), frame.t, &image)?);
            }
        }
        if t - last_progress >= 1.0 {
            progress(t, nominal);
            last_progress = t;
        }
    }
    if let Some(e) = sim.camera_error().filter(|_| config.camera.enabled) {
        return Err(RecordError::CameraStopped(e.to_string()));
    }
    let start = world.robot.start;
    let [mx, my, _] = config.laser.mount_xyz_m;
    let laser = scans.first().map(|s: &slam::messages::LaserScan| robotlog::manifest::LaserGeometry {
        angle_min_rad: s.angle_min,
        angle_increment_rad: s.angle_increment,
        range_min_m: s.range_min,
        range_max_m: s.range_max,
    });
    let sensor = pipeline.map(|p| p.sensor);
    let log = robotlog::Log {
        manifest: robotlog::Manifest {
            format_version: 1,
            name: world.name.clone(),
            source: format!("objslam record, simulator seed {seed}"),
            vehicle: robotlog::manifest::Vehicle {
                motion: "odometry".into(),
                wheelbase_m: None,
                encoder_offset_m: None,
                start_pose: [start.x, start.y, start.yaw_rad()],
            },
            sensor: robotlog::manifest::Sensor {
                x_m: mx,
                y_m: my,
                // Scans are in the laser's own frame: a replay turns them by its yaw.
                yaw_rad: config.laser.mount_yaw_deg.to_radians(),
                range_sigma_m: sensor.map(|s| s.range_sigma_m),
                range_sigma_per_m: sensor.map(|s| s.range_sigma_per_m),
                bearing_sigma_rad: sensor.map(|s| s.bearing_sigma_rad),
            },
            laser,
            reference: Some(robotlog::manifest::Reference {
                kind: robotlog::ReferenceKind::GroundTruth,
                point: robotlog::ReferencePoint::Vehicle,
            }),
            camera: (!frames.is_empty()).then(|| {
                let k = config.camera.intrinsics();
                let e = calibration.copied().unwrap_or_else(|| crate::calibrate::true_extrinsics(config));
                let (cx, cy) = k.principal_point_ros();
                robotlog::manifest::Camera {
                    width: k.width,
                    height: k.height,
                    fx: k.fx,
                    fy: k.fy,
                    cx,
                    cy,
                    rotation: e.phi,
                    translation_m: e.delta,
                }
            }),
        },
        motion: robotlog::Motion::Increments(increments),
        observations: robotlog::Observations::Scans(scans),
        reference,
        camera: frames,
    };
    let write = |name: &str, text: String| {
        let file = out.join(name);
        std::fs::write(&file, text).map_err(|source| RecordError::Io { file, source })
    };
    // The settings as recorded (camera as logged), not as asked for.
    write(
        files::RECORDING,
        serde_json::to_string_pretty(&provenance("objslam record", world, config, seed, scoring)).expect("JSON"),
    )?;
    write(files::WORLD, world.to_toml())?;
    if let Some(p) = pipeline {
        let file = out.join(files::PIPELINE);
        let text =
            toml::to_string(p).map_err(|e| RecordError::Io { file: file.clone(), source: std::io::Error::other(e) })?;
        std::fs::write(&file, format!("# The pipeline settings of the scenario this log was recorded from.\n{text}"))
            .map_err(|source| RecordError::Io { file, source })?;
    }
    // Only beside frames: a recording too short for one has no camera to segment.
    if let Some(m) = appearance_model.filter(|_| !log.camera.is_empty()) {
        m.save(&out.join(files::APPEARANCE_MODEL))?;
    }
    // The log itself last, its manifest last of all: the manifest marks a log finished, so
    // one stopped before it is never taken for a whole recording.
    robotlog::format::write(out, &log)?;
    progress(sim.time(), nominal);
    Ok(RecordSummary {
        sim_seconds: sim.time(),
        wall_seconds: started.elapsed().as_secs_f64(),
        scans: log.observations.len(),
        odometry: log.motion.len(),
        camera_frames: log.camera.len(),
        renderer: sim.camera_adapter().map(|a| a.to_string()),
        collisions: sim.collisions().len(),
        route_completed: sim.route_completed(),
    })
}

/// A ROS 2 bag recorded into `out` (see [`crate::ros2::StagedBag`]: staged, and moved in
/// only when whole).
fn record_ros2_staged(
    world: &worlds::World,
    config: &SimConfig,
    seed: u64,
    scoring: &crate::score::log::LogScoring,
    out: &Path,
    progress: impl FnMut(f64, f64),
) -> Result<RecordSummary, RecordError> {
    let mut bag = crate::ros2::StagedBag::create(out, config)?;
    bag.attach_provenance(&provenance("objslam record", world, config, seed, Some(scoring)), world)?;
    let summary = record_ros2(world, config, seed, &mut bag, progress)?;
    bag.finish()?;
    Ok(summary)
}

/// The simulation's stream written to `bag` (see [`crate::ros2`]).
fn record_ros2(
    world: &worlds::World,
    config: &SimConfig,
    seed: u64,
    bag: &mut crate::ros2::StagedBag,
    mut progress: impl FnMut(f64, f64),
) -> Result<RecordSummary, RecordError> {
    let started = std::time::Instant::now();
    let mut sim = Simulation::new(world, config, seed)?;
    let nominal = config.max_duration_s.unwrap_or_else(|| sim.nominal_duration_s());
    let (mut scans, mut odometry, mut camera_frames) = (0, 0, 0);
    let mut last_progress = -1.0;
    while let Some(event) = sim.next_event() {
        bag.write(&event)?;
        let t = event.time();
        match event {
            SensorEvent::Odometry { .. } => odometry += 1,
            SensorEvent::Laser { .. } => scans += 1,
            SensorEvent::Camera { .. } => camera_frames += 1,
        }
        if t - last_progress >= 1.0 {
            progress(t, nominal);
            last_progress = t;
        }
    }
    progress(sim.time(), nominal);
    Ok(RecordSummary {
        sim_seconds: sim.time(),
        wall_seconds: started.elapsed().as_secs_f64(),
        scans,
        odometry,
        camera_frames,
        renderer: sim.camera_adapter().map(|a| a.to_string()),
        collisions: sim.collisions().len(),
        route_completed: sim.route_completed(),
    })
}

fn record_jsonl(
    world: &worlds::World,
    config: &SimConfig,
    seed: u64,
    scoring: &crate::score::log::LogScoring,
    out: &Path,
    mut progress: impl FnMut(f64, f64),
) -> Result<RecordSummary, RecordError> {
    let started = std::time::Instant::now();
    let mut sim = Simulation::new(world, config, seed)?;
    let nominal = config.max_duration_s.unwrap_or_else(|| sim.nominal_duration_s());

    let write_file = |name: &str, text: String| {
        let file = out.join(name);
        std::fs::write(&file, text).map_err(|source| RecordError::Io { file, source })
    };
    write_file(files::WORLD, world.to_toml())?;
    write_file(files::SENSORS, serde_json::to_string_pretty(&sensors_json(config)).expect("JSON"))?;

    let mut laser = Out::create(out, files::LASER)?;
    let mut laser_truth = Out::create(out, files::LASER_TRUTH)?;
    let mut observations = Out::create(out, files::OBSERVATIONS)?;
    let mut odometry = Out::create(out, files::ODOMETRY)?;
    let mut tum = Out::create(out, files::GROUND_TRUTH)?;
    tum.line("# objslam ground truth: robot base pose in the world frame; timestamp tx ty tz qx qy qz qw")?;
    let mut mcap = McapWriter::create(&out.join(files::MCAP))?;
    let mut camera_log = Out::create(out, files::CAMERA_LOG)?;
    let camera_dir = out.join(files::CAMERA_DIR);
    if config.camera.enabled {
        std::fs::create_dir_all(&camera_dir).map_err(|source| RecordError::Io { file: camera_dir.clone(), source })?;
    }
    let mut frames = 0usize;
    let [mx, my, mz] = config.laser.mount_xyz_m;
    let laser_q = yaw_quaternion(config.laser.mount_yaw_deg.to_radians());

    let camera = config.camera.base_from_camera();
    let camera_q = rotation_quaternion(&camera.r);
    // The noisy odometry integrated from the origin of `odom`: what a robot's /tf says.
    let mut odom = [0.0f64; 3];

    let (mut scans, mut odos) = (0, 0);
    let mut last_progress = -1.0;
    while let Some(event) = sim.next_event() {
        match &event {
            SensorEvent::Odometry { odometry: o, truth } => {
                odos += 1;
                odometry.line(&odometry_line(o))?;
                let r = truth.robot;
                tum.line(&tum_line(o.t, r.x, r.y, r.theta))?;
                odom = integrate_odometry(odom, o);
                let oq = yaw_quaternion(odom[2]);
                mcap.write(
                    "/tf",
                    "foxglove.FrameTransform",
                    o.t,
                    &json!({"timestamp": timestamp(o.t), "parent_frame_id": "odom", "child_frame_id": "base_link",
                            "translation": {"x": odom[0], "y": odom[1], "z": 0.0}, "rotation": {"x": oq[0], "y": oq[1], "z": oq[2], "w": oq[3]}}),
                )?;
                mcap.write(
                    "/odom",
                    "foxglove.PosesInFrame",
                    o.t,
                    &json!({"timestamp": timestamp(o.t), "frame_id": "odom", "poses": [pose_json(odom[0], odom[1], 0.0, oq)]}),
                )?;
                let q = yaw_quaternion(r.theta);
                mcap.write(
                    "/ground_truth/pose",
                    "foxglove.PosesInFrame",
                    o.t,
                    &json!({"timestamp": timestamp(o.t), "frame_id": "world", "poses": [pose_json(r.x, r.y, 0.0, q)]}),
                )?;
            }
            SensorEvent::Laser { scan, beams, truth } => {
                scans += 1;
                laser.line(&laser_line(scan))?;
                laser_truth.line(&laser_truth_line(scan.t, beams))?;
                let clusters = slam::clustering::cluster(&crate::run::slam_scan(scan), &scoring.clustering);
                observations.line(&observations_line(scan.t, &clusters))?;
                mcap.write("/laser/points", "foxglove.PointCloud", scan.t, &crate::foxglove::laser_points_json(scan))?;
                if scans == 1 {
                    mcap.write(
                        "/tf_static",
                        "foxglove.FrameTransform",
                        scan.t,
                        &json!({"timestamp": timestamp(scan.t), "parent_frame_id": "base_link", "child_frame_id": "laser",
                                "translation": {"x": mx, "y": my, "z": mz}, "rotation": {"x": laser_q[0], "y": laser_q[1], "z": laser_q[2], "w": laser_q[3]}}),
                    )?;
                    // The camera's optical frame (z forward, x right, y down), so images can
                    // be placed in 3-D.
                    mcap.write(
                        "/tf_static",
                        "foxglove.FrameTransform",
                        scan.t,
                        &json!({"timestamp": timestamp(scan.t), "parent_frame_id": "base_link", "child_frame_id": "camera_optical",
                                "translation": {"x": camera.t[0], "y": camera.t[1], "z": camera.t[2]},
                                "rotation": {"x": camera_q[0], "y": camera_q[1], "z": camera_q[2], "w": camera_q[3]}}),
                    )?;
                }
                let people: Vec<_> =
                    truth.people.iter().map(|p| pose_json(p.x, p.y, 0.0, yaw_quaternion(p.heading))).collect();
                mcap.write(
                    "/ground_truth/people",
                    "foxglove.PosesInFrame",
                    scan.t,
                    &json!({"timestamp": timestamp(scan.t), "frame_id": "world", "poses": people}),
                )?;
            }
            SensorEvent::Camera { frame, .. } => {
                let files = write_camera_frame(&camera_dir, frames, frame)?;
                let k = frame.intrinsics;
                let pose = frame.world_from_camera;
                camera_log.line(
                    &serde_json::to_string(&json!({
                        "t": frame.t, "image": files.image, "instance": files.instance, "class": files.class, "depth_mm": files.depth,
                        "K": k.k(), "width": k.width, "height": k.height,
                        "world_from_camera": {"rotation": pose.r, "translation_m": pose.t}
                    }))
                    .expect("JSON"),
                )?;
                mcap.write("/camera/image", "foxglove.CompressedImage", frame.t, &json!({"timestamp": timestamp(frame.t), "frame_id": "camera_optical", "format": "png", "data": base64(&files.colour_png)}))?;
                // Foxglove, as ROS, puts pixel centres at whole coordinates.
                let (cx, cy) = k.principal_point_ros();
                mcap.write(
                    "/camera/calibration",
                    "foxglove.CameraCalibration",
                    frame.t,
                    &json!({"timestamp": timestamp(frame.t), "frame_id": "camera_optical", "width": k.width, "height": k.height, "distortion_model": "plumb_bob",
                            "D": [0.0, 0.0, 0.0, 0.0, 0.0], "K": [k.fx, 0.0, cx, 0.0, k.fy, cy, 0.0, 0.0, 1.0],
                            "R": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], "P": [k.fx, 0.0, cx, 0.0, 0.0, k.fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]}),
                )?;
                frames += 1;
            }
        }
        let t = event.time();
        if t - last_progress >= 1.0 {
            progress(t, nominal);
            last_progress = t;
        }
    }
    progress(sim.time(), nominal);
    let mut collisions = Out::create(out, files::COLLISIONS)?;
    for c in sim.collisions() {
        collisions.line(&collision_line(c))?;
    }
    collisions.finish()?;
    for f in [laser, laser_truth, observations, odometry, tum, camera_log] {
        f.finish()?;
    }
    mcap.finish()?;
    let summary = RecordSummary {
        sim_seconds: sim.time(),
        wall_seconds: started.elapsed().as_secs_f64(),
        scans,
        odometry: odos,
        camera_frames: frames,
        renderer: sim.camera_adapter().map(|a| a.to_string()),
        collisions: sim.collisions().len(),
        route_completed: sim.route_completed(),
    };
    let mut metadata = provenance("objslam record", world, config, seed, Some(scoring));
    metadata["summary"] = json!(summary);
    write_file(files::METADATA, serde_json::to_string_pretty(&metadata).expect("JSON"))?;
    Ok(summary)
}
