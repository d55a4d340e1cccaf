//! The names of the files a simulated run or recording writes (docs/guide/runs-and-metrics.md
//! and docs/guide/simulator.md list them), in one place: `objslam record`, `objslam run` and
//! `objslam replay` write them and `objslam score` reads them, so a name changed in one
//! would otherwise break the others quietly. Users' scripts read these names: keep them.

/// The world the run simulated, as a world file.
pub const WORLD: &str = "world.toml";
/// The sensors' mounting and noise.
pub const SENSORS: &str = "sensors.json";
/// What the run was: scenario, seed, resolved configuration, versions.
pub const METADATA: &str = "metadata.json";
/// The scenario a run ran, every setting written out and its files named by absolute
/// path: `objslam run DIR/scenario.toml` runs it again.
pub const SCENARIO: &str = "scenario.toml";
/// A run's scores.
pub const METRICS: &str = "metrics.json";
/// Laser scans, one JSON line each.
pub const LASER: &str = "laser.jsonl";
/// Each beam's ground truth: what it hit and the true range.
pub const LASER_TRUTH: &str = "laser_truth.jsonl";
/// Object observations from the ground truth.
pub const OBSERVATIONS: &str = "observations.jsonl";
/// Odometry messages.
pub const ODOMETRY: &str = "odometry.jsonl";
/// Camera frames: times, poses and the image files.
pub const CAMERA_LOG: &str = "camera.jsonl";
/// The directory of a recording's camera images.
pub const CAMERA_DIR: &str = "camera";
/// The robot's collisions.
pub const COLLISIONS: &str = "collisions.jsonl";
/// A recording's true trajectory (TUM).
pub const GROUND_TRUTH: &str = "ground_truth.tum";
/// A run's true trajectory (TUM).
pub const TRAJECTORY_GT: &str = "trajectory_gt.tum";
/// The method's estimated trajectory (TUM).
pub const TRAJECTORY_EST: &str = "trajectory_est.tum";
/// The estimated pose's covariance at each pose of [`TRAJECTORY_EST`].
pub const TRAJECTORY_EST_COVARIANCE: &str = "trajectory_est_covariance.csv";
/// The method's map.
pub const LANDMARKS: &str = "landmarks.json";
/// The method's association of each observation.
pub const ASSOCIATIONS: &str = "associations.jsonl";
/// The pipeline's decisions (associations, new landmarks, merges, retractions).
pub const DECISIONS: &str = "decisions.jsonl";
/// The smoother's relinearisations.
pub const RELINEARISATIONS: &str = "relinearisations.jsonl";
/// The beams whose pixel showed their tree: the camera's part of `map.trees_in_view`.
pub const TREES_SHOWN: &str = "trees_shown.jsonl";
/// Each cluster's segmentation.
pub const SEGMENTATION: &str = "segmentation.jsonl";
/// The laser-camera calibration's result.
pub const CALIBRATION: &str = "calibration.json";
/// The object models: their pictures, [`OBJECT_MODELS`] and the appearance model they
/// were made with ([`APPEARANCE_MODEL`]).
pub const OBJECTS_DIR: &str = "objects";
/// The mapped objects' appearance models, in [`OBJECTS_DIR`].
pub const OBJECT_MODELS: &str = "models.json";
/// A robot log's record of how it was made (see [`crate::record::provenance`]).
pub const RECORDING: &str = "recording.json";
/// The pipeline settings a robot log's producer recommends, beside its data (optional;
/// `objslam record --format log` writes the scenario's).
pub const PIPELINE: &str = "pipeline.toml";
/// An appearance model: the one a robot log's producer recommends for the camera methods
/// (optional; `objslam record --format log` of a scenario whose method reads the camera
/// writes the model its run uses), taken when `objslam replay` is given none; and the one
/// a run's object models were made with, in [`OBJECTS_DIR`].
pub const APPEARANCE_MODEL: &str = "appearance_model.json";
/// Every stream in one MCAP file, for Foxglove.
pub const MCAP: &str = "run.mcap";
/// The map, drawn over the world.
pub const MAP: &str = "map.png";

/// The SHA-256 of a file's bytes in hex, `None` where it cannot be read: what outputs record
/// of the files they were made from.
pub fn sha256_hex(file: &std::path::Path) -> Option<String> {
    use sha2::{Digest, Sha256};
    let bytes = std::fs::read(file).ok()?;
    Some(Sha256::digest(&bytes).iter().map(|b| format!("{b:02x}")).collect())
}

/// The first of `names` that stands in `dir` (a file, a folder, or a link, even one to
/// nothing): what a command that writes those names there would replace or remove.
pub fn first_present<'a>(dir: &std::path::Path, names: &[&'a str]) -> Option<&'a str> {
    names.iter().copied().find(|name| dir.join(name).symlink_metadata().is_ok())
}

/// An input's path as a run records it (`metadata.json`, `scenario.toml`): absolute, with
/// `.`, `..` and links resolved in its directory where that is there (a scenario run from
/// another directory names its world through `..`). The file's own name is kept, link or
/// not: a world finds its meshes beside the name it was read by.
pub fn recorded_path(file: &std::path::Path) -> std::path::PathBuf {
    let absolute = std::path::absolute(file).unwrap_or_else(|_| file.to_path_buf());
    match (absolute.parent().map(std::fs::canonicalize), absolute.file_name()) {
        (Some(Ok(dir)), Some(name)) => dir.join(name),
        _ => absolute,
    }
}

/// The first of `inputs` (each with what it is) that lies in the directory `out` under one
/// of `names`, the outputs a command writes, replaces or removes there: publishing them
/// would replace or delete it.
pub fn input_among_outputs(
    out: &std::path::Path,
    names: &[&str],
    inputs: Vec<(&'static str, std::path::PathBuf)>,
) -> Option<(&'static str, std::path::PathBuf)> {
    inputs.into_iter().find(|(_, file)| lies_among(out, names, file))
}

/// Whether `file` lies in the directory `dir` under one of `names` (one of them, or
/// anything in such a folder). A file is judged both where its path puts it (a link in
/// `dir` would be replaced or removed) and where it leads (writing a link writes its
/// target).
pub fn lies_among(dir: &std::path::Path, names: &[&str], file: &std::path::Path) -> bool {
    use std::path::Path;
    let Ok(dir) = std::fs::canonicalize(dir) else { return false };
    let among = |path: &Path| {
        path.strip_prefix(&dir)
            .ok()
            .and_then(|rest| rest.components().next())
            .is_some_and(|c| names.iter().any(|name| c.as_os_str() == *name))
    };
    let parent = file.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let as_given = std::fs::canonicalize(parent).ok().zip(file.file_name()).map(|(dir, name)| dir.join(name));
    let target = std::fs::canonicalize(file).ok();
    [as_given, target].iter().flatten().any(|p| among(p))
}

/// Every name `objslam run` writes, replaces or removes directly in its output directory:
/// an input file there (a calibration the last run estimated, a world file) would be lost
/// to the next run into that directory, so the run refuses such an input first.
pub const RUN_OUTPUTS: &[&str] = &[
    WORLD,
    SENSORS,
    METADATA,
    SCENARIO,
    METRICS,
    LASER,
    LASER_TRUTH,
    OBSERVATIONS,
    ODOMETRY,
    COLLISIONS,
    TRAJECTORY_GT,
    TRAJECTORY_EST,
    TRAJECTORY_EST_COVARIANCE,
    LANDMARKS,
    ASSOCIATIONS,
    DECISIONS,
    RELINEARISATIONS,
    TREES_SHOWN,
    SEGMENTATION,
    CALIBRATION,
    OBJECTS_DIR,
    MCAP,
    MAP,
];
