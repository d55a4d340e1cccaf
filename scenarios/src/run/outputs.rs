//! The files a run writes: metrics, trajectories, the map, decisions, logs and plots.

use crate::files;
use std::collections::HashMap;
use std::path::Path;

use serde_json::json;
use slam::pipeline::Pipeline;
use worlds::ObjectClass;

use super::online::RunLog;
use super::{Metrics, RunError};
use crate::partial_files::PartialFiles;
use crate::score::log::LogScoring;
use crate::score::scorer::{Fusion, ScoredObservation};

/// One line of segmentation.jsonl: how a cluster of the scan at `t_scan` was judged in the
/// image of `t_image`, with the object it truly was.
pub(super) fn segmentation_line(
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

/// One line of `associations.jsonl`: a scan's time, what each of its laser clusters went
/// to, and the fusions made after it (the format `objslam score --associations` reads).
pub(super) fn association_line(t: f64, observations: &[ScoredObservation], fusions: &[Fusion]) -> String {
    serde_json::to_string(&json!({"t": t, "observations": observations, "fusions": fusions})).expect("JSON") + "\n"
}

/// One line of `trees_shown.jsonl`: a scan's time and the beams whose pixels, in the camera
/// frame of its instant, show the tree they hit (what `map.trees_in_view` counts).
pub(super) fn trees_shown_line(t: f64, beams: &[usize]) -> String {
    serde_json::to_string(&json!({"t": t, "beams": beams})).expect("JSON") + "\n"
}

/// The outputs a run writes line by line as it goes (see [`PartialFiles`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Stream {
    Laser,
    LaserTruth,
    Odometry,
    Observations,
    Associations,
    /// Runs with a camera.
    TreesShown,
    /// Camera methods.
    Segmentation,
}

/// A run's streamed outputs.
pub(super) type StreamedOutputs = PartialFiles<Stream>;

/// Opens the streams of a run with or without a camera and a camera method.
pub(super) fn stream_outputs(out: &Path, camera: bool, camera_method: bool) -> Result<StreamedOutputs, RunError> {
    let mut streams = vec![
        (Stream::Laser, files::LASER),
        (Stream::LaserTruth, files::LASER_TRUTH),
        (Stream::Odometry, files::ODOMETRY),
        (Stream::Observations, files::OBSERVATIONS),
        (Stream::Associations, files::ASSOCIATIONS),
    ];
    if camera {
        streams.push((Stream::TreesShown, files::TREES_SHOWN));
    }
    if camera_method {
        streams.push((Stream::Segmentation, files::SEGMENTATION));
    }
    Ok(PartialFiles::create(out, &streams)?)
}

/// Outputs that only some runs write (camera methods, estimated calibrations): removed from
/// a reused output directory when a run's outputs are moved in, so none is left from an
/// earlier run to be taken for this one's. The other outputs every run rewrites.
const CONDITIONAL_OUTPUTS: [&str; 4] =
    [files::CALIBRATION, files::SEGMENTATION, files::OBJECTS_DIR, files::TREES_SHOWN];

/// Moves a finished run's outputs from `unfinished` into `out` (see
/// [`crate::partial_files::publish`]), after removing an earlier run's conditional ones.
pub(super) fn publish_outputs(unfinished: &Path, out: &Path) -> Result<(), RunError> {
    crate::partial_files::publish(unfinished, out, &CONDITIONAL_OUTPUTS, files::METADATA).map_err(move_failed)
}

/// A move's failures as the run's error: the one, or all of them.
fn move_failed(errors: Vec<crate::partial_files::PartialFileError>) -> RunError {
    let errors: Vec<RunError> = errors.into_iter().map(RunError::from).collect();
    super::first_or_all(errors, RunError::Outputs).expect_err("publish fails with errors")
}

/// Finishes the move of a run's finished outputs into `out` that a stop cut short (a
/// publish had begun: its list waits beside them), before anything else looks at `out`,
/// which then holds that run whole; true where it did. Called under `out`'s hold.
pub(super) fn finish_stopped_run(out: &Path) -> Result<bool, RunError> {
    use crate::partial_files::{StoppedMove, finish_publish, stopped_move, unfinished_dir};
    if stopped_move(out) != Some(StoppedMove::Run) {
        return Ok(false);
    }
    finish_publish(&unfinished_dir(out), out, &CONDITIONAL_OUTPUTS, files::METADATA).map_err(move_failed)?;
    Ok(true)
}

/// What a finished run writes out.
pub(super) struct FinishedRun<'a> {
    pub world: &'a worlds::World,
    pub pipeline: &'a Pipeline,
    pub metrics: &'a Metrics,
    /// The resolved configuration (metadata.json's `configuration`).
    pub resolved: &'a serde_json::Value,
    /// The scenario as run: seed and method written in, files named by absolute path.
    pub as_run: &'a crate::scenario::Scenario,
    pub log: &'a RunLog,
    pub landmark_objects: &'a HashMap<u32, u16>,
    /// The simulator as it ran, and how `objslam score` is to score the directory as a log.
    pub sim_config: &'a sim::SimConfig,
    pub scoring: &'a LogScoring,
}

/// Writes a finished run's outputs into `out`, the streamed ones given their final names.
pub(super) fn write_outputs(out: &Path, run: &FinishedRun, streams: StreamedOutputs) -> Result<(), RunError> {
    streams.finish()?;
    // Three independent groups of files, written at once: a short run's end is otherwise
    // one core's work. A file that cannot be written stops no other; every failure is
    // reported.
    let (mut errors, (objects, map_and_mcap)) = rayon::join(
        || write_texts(out, run),
        || rayon::join(|| crate::objects::write_objects(out, run.pipeline), || write_map_and_mcap(out, run)),
    );
    errors.extend(objects.err().map(RunError::from));
    errors.extend(map_and_mcap);
    super::first_or_all(errors, RunError::Outputs)
}

/// metrics.json, the log's own files (world, sensors, collisions, metadata), the
/// trajectories, decisions, solves and landmarks; the files that could not be written.
fn write_texts(out: &Path, run: &FinishedRun) -> Vec<RunError> {
    let FinishedRun { world, pipeline, metrics, resolved, as_run, log, landmark_objects, sim_config, scoring } = *run;
    let (est, gt) = (&log.estimate, &log.truth);
    let solves = &log.solves;
    let errors = std::cell::RefCell::new(Vec::new());
    let write = |name: &str, text: &str| {
        let file = out.join(name);
        if let Err(source) = std::fs::write(&file, text) {
            errors.borrow_mut().push(RunError::Io { file, source });
        }
    };
    write(files::METRICS, &serde_json::to_string_pretty(metrics).expect("JSON"));
    // The directory is also a sensor log with its truth, which `objslam score --log` reads
    // (the same files as `objslam record` writes, camera images aside).
    write(files::WORLD, &world.to_toml());
    write(files::SENSORS, &serde_json::to_string_pretty(&crate::record::sensors_json(sim_config)).expect("JSON"));
    write(files::COLLISIONS, &log.collisions);
    write(
        files::METADATA,
        &serde_json::to_string_pretty(&json!({
            "tool": "objslam run",
            "version": env!("CARGO_PKG_VERSION"),
            "build": crate::build::current(),
            "seed": metrics.seed,
            "renderer": metrics.renderer,
            "appearance_model": metrics.appearance_model,
            "sim_config": sim_config,
            "summary": {"method": metrics.method, "sim_seconds": metrics.sim_seconds, "route_completed": metrics.route_completed},
            "scoring": scoring,
            "configuration": resolved,
        }))
        .expect("JSON"),
    );
    match scenario_file(as_run) {
        Ok(text) => write(files::SCENARIO, &text),
        Err(message) => errors.borrow_mut().push(RunError::NamedFile {
            scenario: as_run.describe(),
            key: "scenario.toml",
            message: format!("cannot be written as TOML: {message}"),
        }),
    }
    let tum = |path: &[(f64, [f64; 3])]| {
        let mut s = String::from(crate::record::TUM_HEADER);
        for (t, p) in path {
            s.push_str(&crate::record::tum_line(*t, p[0], p[1], p[2]));
            s.push('\n');
        }
        s
    };
    write(files::TRAJECTORY_EST, &tum(est));
    let mut covariances = crate::score::estimate::covariance_header() + "\n";
    for ((t, _), p) in est.iter().zip(&log.covariances) {
        covariances.push_str(&crate::score::estimate::covariance_line(*t, p));
        covariances.push('\n');
    }
    write(files::TRAJECTORY_EST_COVARIANCE, &covariances);
    write(files::TRAJECTORY_GT, &tum(gt));
    // Each decision with the ground truth beside it: the observation's true object and the
    // true object of every candidate landmark. After a scan's decisions, the fusions made
    // after that scan: `{"t": .., "fusion": {"kept": .., "removed": ..}}`.
    let mut decisions = String::new();
    let mut fusions = log.fusions.iter().peekable();
    let fusion_line =
        |(t, f): &(f64, Fusion)| serde_json::to_string(&json!({"t": t, "fusion": f})).expect("JSON") + "\n";
    for (d, truth) in &log.decisions {
        while let Some(f) = fusions.next_if(|(t, _)| *t < d.t) {
            decisions.push_str(&fusion_line(f));
        }
        let mut v = serde_json::to_value(d).expect("JSON");
        v["true_object"] = json!(truth);
        if let Some(cands) = v["candidates"].as_array_mut() {
            for c in cands {
                let id = c["landmark"].as_u64().unwrap_or(u64::MAX) as u32;
                c["true_object"] = json!(landmark_objects.get(&id).copied().unwrap_or(0));
            }
        }
        decisions.push_str(&(serde_json::to_string(&v).expect("JSON") + "\n"));
    }
    for f in fusions {
        decisions.push_str(&fusion_line(f));
    }
    write(files::DECISIONS, &decisions);
    // Each solve of the smoother (combined method): what it solved and how far the cost
    // fell, or why it failed (the filter then carried on as it was).
    write(
        files::RELINEARISATIONS,
        &solves
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
    );
    let landmarks: Vec<_> = pipeline
        .mapped_landmarks()
        .iter()
        .map(|l| {
            let obj = landmark_objects.get(&l.id).copied().unwrap_or(0);
            let mut v = serde_json::to_value(l).expect("JSON");
            v["true_object"] = json!(obj);
            v["true_class"] = json!(world.class_of(obj).map(|c| c.name()).unwrap_or("nothing"));
            v
        })
        .collect();
    write(files::LANDMARKS, &serde_json::to_string_pretty(&landmarks).expect("JSON"));
    errors.into_inner()
}

/// map.png and run.mcap, each written even if the other cannot be; their failures.
fn write_map_and_mcap(out: &Path, run: &FinishedRun) -> Vec<RunError> {
    let FinishedRun { world, pipeline, metrics, log, landmark_objects, .. } = *run;
    let (est, gt, people_tracks) = (&log.estimate, &log.truth, &log.people_tracks);
    // The map picture: ground truth by class, landmarks with 2-sigma ellipses (red when
    // on something other than a tree), both trajectories and people's tracks.
    let marks = pipeline
        .mapped_landmarks()
        .iter()
        .map(|l| {
            let obj = landmark_objects.get(&l.id).copied().unwrap_or(0);
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
    let map = crate::plot::draw_map(world, &overlays, &out.join("map.png")).map_err(RunError::from);
    [map, write_mcap(out, run)].into_iter().filter_map(Result::err).collect()
}

/// run.mcap: both paths and the final map, for Foxglove.
fn write_mcap(out: &Path, run: &FinishedRun) -> Result<(), RunError> {
    let FinishedRun { pipeline, log, .. } = *run;
    let (est, gt) = (&log.estimate, &log.truth);

    let mut mcap = crate::foxglove::McapWriter::create(&out.join(files::MCAP))?;
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

/// `scenario.toml`: the scenario as run, runnable as it is, after a header saying so.
fn scenario_file(as_run: &crate::scenario::Scenario) -> Result<String, String> {
    let body = toml::to_string(as_run).map_err(|e| e.to_string())?;
    Ok(format!(
        "# The scenario of the run in this directory, with its seed and method, every setting written out and\n\
         # its files named by absolute path: `objslam run scenario.toml --out NEW` runs that run again.\n\
         # metadata.json's configuration.inputs gives the SHA-256 each of those files had then.\n\
         # Written by objslam {}.\n\n{body}",
        crate::build::describe()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run stopped while its outputs were moved in (the earlier run's marker gone, some
    /// of its files still there, the new run whole in the unfinished directory with the
    /// move's list) is finished by the next run into the directory, not thrown away; a
    /// draft (a run stopped while still writing, no list) is not moved in.
    #[test]
    fn a_run_stopped_while_moved_in_is_finished_by_the_next() {
        let out = std::env::temp_dir().join(format!("objslam-stopped-run-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join("metrics.json"), "old").unwrap();
        std::fs::write(out.join("world.toml"), "old").unwrap();
        let unfinished = crate::partial_files::unfinished_dir(&out);
        std::fs::create_dir_all(&unfinished).unwrap();
        std::fs::write(unfinished.join("metrics.json"), "new").unwrap();
        std::fs::write(unfinished.join(files::METADATA), r#"{"tool": "objslam run"}"#).unwrap();
        // A draft: nothing moved, nothing lost, and the directory is no earlier run's.
        assert!(!finish_stopped_run(&out).unwrap());
        assert_eq!(std::fs::read_to_string(out.join("metrics.json")).unwrap(), "old");
        assert!(super::super::check_earlier_outputs_are_a_runs(&out).is_err());
        // The move had begun: its list names what it brings in, world.toml already moved.
        std::fs::write(unfinished.join(".moving.json"), r#"["metrics.json", "world.toml", "metadata.json"]"#).unwrap();
        std::fs::remove_file(out.join("world.toml")).unwrap();
        std::fs::write(out.join("world.toml"), "new").unwrap();
        assert!(finish_stopped_run(&out).unwrap());
        for name in ["metrics.json", "world.toml"] {
            assert_eq!(std::fs::read_to_string(out.join(name)).unwrap(), "new", "{name}");
        }
        assert!(out.join(files::METADATA).is_file() && !unfinished.exists());
        super::super::check_earlier_outputs_are_a_runs(&out).unwrap();
        assert!(!finish_stopped_run(&out).unwrap(), "nothing more to finish");
        let _ = std::fs::remove_dir_all(&out);
    }

    /// A study's directory is no run's, and a run's no study's: neither writes among the
    /// other's files.
    #[test]
    fn runs_and_studies_keep_out_of_each_others_directories() {
        let out = std::env::temp_dir().join(format!("objslam-run-or-study-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join(crate::montecarlo::STUDY_FILE), "{}").unwrap();
        let e = super::super::check_earlier_outputs_are_a_runs(&out).unwrap_err().to_string();
        assert!(e.contains("holds a Monte Carlo study"), "{e}");
        std::fs::remove_file(out.join(crate::montecarlo::STUDY_FILE)).unwrap();
        std::fs::write(out.join(files::METADATA), r#"{"tool": "objslam run"}"#).unwrap();
        let e = crate::montecarlo::refuse_run_dir(&out).unwrap_err().to_string();
        assert!(e.contains("holds a run's or a recording's outputs"), "{e}");
        let _ = std::fs::remove_dir_all(&out);
    }

    #[test]
    fn finished_outputs_replace_the_earlier_ones_whole_and_a_directory_in_the_way_is_named() {
        let out = std::env::temp_dir().join(format!("objslam-publish-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        // An earlier camera run's outputs, and a file of the user's.
        std::fs::create_dir_all(out.join("objects")).unwrap();
        for (name, text) in
            [("metrics.json", "old"), ("segmentation.jsonl", "old"), ("objects/a.png", "old"), ("notes.txt", "mine")]
        {
            std::fs::write(out.join(name), text).unwrap();
        }
        // This run (no camera method): written whole into the unfinished directory first.
        let unfinished = crate::partial_files::start_unfinished(&out).unwrap();
        std::fs::write(unfinished.join("metrics.json"), "new").unwrap();
        std::fs::write(unfinished.join("landmarks.json"), "new").unwrap();
        assert_eq!(std::fs::read_to_string(out.join("metrics.json")).unwrap(), "old", "unchanged until published");
        publish_outputs(&unfinished, &out).unwrap();
        assert_eq!(std::fs::read_to_string(out.join("metrics.json")).unwrap(), "new");
        assert_eq!(std::fs::read_to_string(out.join("landmarks.json")).unwrap(), "new");
        assert!(
            !out.join("segmentation.jsonl").exists() && !out.join("objects").exists(),
            "an earlier run's own outputs go"
        );
        assert_eq!(std::fs::read_to_string(out.join("notes.txt")).unwrap(), "mine");
        assert!(!unfinished.exists());
        // A directory where a file goes: named before anything moves, so the outputs stay
        // the earlier run's, all of them.
        let unfinished = crate::partial_files::start_unfinished(&out).unwrap();
        std::fs::create_dir_all(out.join("map.png")).unwrap();
        std::fs::write(unfinished.join("map.png"), "picture").unwrap();
        std::fs::write(unfinished.join("metrics.json"), "newer").unwrap();
        let e = publish_outputs(&unfinished, &out).unwrap_err().to_string();
        assert!(e.contains("map.png") && e.contains("a directory stands where"), "{e}");
        assert_eq!(std::fs::read_to_string(out.join("metrics.json")).unwrap(), "new");
        assert_eq!(std::fs::read_to_string(unfinished.join("metrics.json")).unwrap(), "newer");
        assert_eq!(std::fs::read_to_string(unfinished.join("map.png")).unwrap(), "picture");
        std::fs::remove_dir_all(&out).ok();
    }
}
