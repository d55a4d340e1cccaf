//! The files a run writes: metrics, trajectories, the map, decisions, logs and plots.

use std::collections::HashMap;
use std::path::Path;

use serde_json::json;
use slam::pipeline::Pipeline;
use worlds::ObjectClass;

use super::online::RunLog;
use super::{Metrics, RunError};
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

/// Outputs that only some runs write (camera methods, estimated calibrations): removed from
/// a reused output directory first, so none is left from an earlier run to be taken for
/// this one's. The other outputs every run rewrites.
const CONDITIONAL_OUTPUTS: [&str; 3] = ["calibration.json", "segmentation.jsonl", "objects"];

pub(super) fn clear_stale_outputs(out: &Path) -> Result<(), RunError> {
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

pub(super) fn write_outputs(
    out: &Path,
    world: &worlds::World,
    pipeline: &Pipeline,
    metrics: &Metrics,
    resolved: &serde_json::Value,
    log: &RunLog,
    landmark_object: &HashMap<u32, u16>,
) -> Result<(), RunError> {
    let (est, gt, people_tracks) = (&log.estimate, &log.truth, &log.people_tracks);
    let (decisions, solves) = (&log.decisions, &log.solves);
    std::fs::create_dir_all(out).map_err(|source| RunError::Io { file: out.to_path_buf(), source })?;
    let write = |name: &str, text: String| {
        let file = out.join(name);
        std::fs::write(&file, text).map_err(|source| RunError::Io { file, source })
    };
    write("associations.jsonl", log.associations.clone())?;
    if pipeline.config().method.uses_appearance() {
        write("segmentation.jsonl", log.segmentation.clone())?;
    }
    write("metrics.json", serde_json::to_string_pretty(metrics).expect("JSON"))?;
    write(
        "metadata.json",
        serde_json::to_string_pretty(&json!({
            "tool": "objslam run",
            "version": env!("CARGO_PKG_VERSION"),
            "seed": metrics.seed,
            "renderer": metrics.renderer,
            "appearance_model": metrics.appearance_model,
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
