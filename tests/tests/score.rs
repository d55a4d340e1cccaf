//! `objslam score` reproduces `objslam run`'s metrics from a log of `objslam record` and
//! the files a run writes (trajectory, landmarks, associations), bit for bit, for a
//! position-only run and for a camera run; and it refuses inputs that do not fit the log.

use std::path::{Path, PathBuf};

use scenarios::run::{RunOptions, run};
use scenarios::scenario::Scenario;
use scenarios::score::log::{Estimate, LogScoring, score_log};

/// Keys of run metrics that only the method's insides carry: `objslam score` leaves them
/// out (or null), so they are not compared.
const METHOD_INTERNAL_MAP_KEYS: [&str; 1] = ["trees_judged"];

fn record_and_run(name: &str, seed: u64, duration: f64, camera: bool, dir: &Path) -> (PathBuf, PathBuf) {
    let (mut sc, base) = Scenario::load(name).unwrap();
    sc.sim.max_duration_s = Some(duration);
    sc.sim.camera.enabled = camera;
    let (log, out) = (dir.join("log"), dir.join("run"));
    let world = sc.world(&base, seed).unwrap();
    scenarios::record::record(
        &world,
        &sc.sim,
        sim::derive_seed(seed, "sim"),
        &LogScoring::of_scenario(&sc, seed),
        &log,
        scenarios::record::RecordFormat::Jsonl,
        |_, _| {},
    )
    .unwrap();
    run(&sc, &base, &RunOptions { seed: Some(seed), out: Some(out.clone()), ..Default::default() }, |_| {}).unwrap();
    (log, out)
}

fn estimate(run: &Path, method: &str) -> Estimate {
    Estimate {
        trajectory: run.join("trajectory_est.tum"),
        landmarks: Some(run.join("landmarks.json")),
        associations: Some(run.join("associations.jsonl")),
        method: Some(method.into()),
        recall_basis: None,
    }
}

/// Every key the score has, the run has with the identical value.
fn assert_reproduced(run_dir: &Path, scored: &scenarios::score::log::ScoredMetrics) -> serde_json::Value {
    let run: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("metrics.json")).unwrap()).unwrap();
    let mut scored = serde_json::to_value(scored).unwrap();
    for key in ["unchecked", "poses_scored", "recall_basis"] {
        scored.as_object_mut().unwrap().remove(key);
    }
    for key in METHOD_INTERNAL_MAP_KEYS {
        scored["map"].as_object_mut().unwrap().remove(key);
    }
    let compared: Vec<&String> = scored.as_object().unwrap().keys().collect();
    assert_eq!(compared.len(), 17, "the keys compared: {compared:?}");
    for (key, value) in scored.as_object().unwrap() {
        let expected = if key == "map" {
            let mut m = run["map"].clone();
            for k in METHOD_INTERNAL_MAP_KEYS {
                m.as_object_mut().unwrap().remove(k);
            }
            m
        } else {
            run[key].clone()
        };
        assert!(!value.is_null() || expected.is_null(), "{key}: scored null, the run has {expected}");
        assert_eq!(value, &expected, "{key} differs");
    }
    run
}

#[test]
fn score_reproduces_a_position_only_run_bit_for_bit() {
    let dir = std::env::temp_dir().join(format!("objslam-score-jcbb-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (log, out) = record_and_run("laser_only", 3, 40.0, false, &dir);
    let scored = score_log(&log, &estimate(&out, "jcbb")).unwrap();
    let run = assert_reproduced(&out, &scored);
    assert!(run["associations"]["total"].as_u64().unwrap() > 100, "too short a run to test anything: {run}");
    assert!(run["false_landmarks"].as_u64().unwrap() > 0, "the baseline maps look-alikes within 40 s: {run}");
    assert_eq!(scored.map.as_ref().unwrap().trees_in_view, None);

    // A trajectory alone: the trajectory's figures, and no verdict on the map's criteria.
    let alone = Estimate { landmarks: None, associations: None, ..estimate(&out, "jcbb") };
    let scored_alone = score_log(&log, &alone).unwrap();
    assert_eq!(scored_alone.ate_rmse_m.to_bits(), scored.ate_rmse_m.to_bits());
    assert!(scored_alone.map.is_none() && scored_alone.associations.is_none());
    assert!(scored_alone.passed.is_none() && !scored_alone.unchecked.is_empty());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn score_reproduces_a_camera_run_with_its_trees_in_view() {
    let dir = std::env::temp_dir().join(format!("objslam-score-combined-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (log, out) = record_and_run("paper_park", 2, 30.0, true, &dir);
    let scored = score_log(&log, &estimate(&out, "combined")).unwrap();
    assert_reproduced(&out, &scored);
    let map = scored.map.unwrap();
    assert!(map.trees_in_view.is_some_and(|n| n >= 1), "{map:?}");
    assert!(map.trees_laser_seen > map.trees_in_view.unwrap(), "{map:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn inputs_that_do_not_fit_the_log_are_errors_naming_file_and_line() {
    let dir = std::env::temp_dir().join(format!("objslam-score-bad-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (log, out) = record_and_run("laser_only", 3, 5.0, false, &dir);
    let bad = dir.join("bad");
    std::fs::create_dir_all(&bad).unwrap();
    let error = |e: Estimate| score_log(&log, &e).expect_err("an error").to_string();

    // A pose after the log ends.
    let tum = bad.join("late.tum");
    std::fs::write(&tum, "0 0 0 0 0 0 0 1\n99 0 0 0 0 0 0 1\n").unwrap();
    let e = error(Estimate { trajectory: tum, ..estimate(&out, "x") });
    assert!(e.contains("late.tum") && e.contains("pose 2") && e.contains("outside"), "{e}");

    // An observation past the scan's last beam, on line 2.
    let text = std::fs::read_to_string(out.join("associations.jsonl")).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let mut v: serde_json::Value = serde_json::from_str(&lines[1]).unwrap();
    v["observations"] = serde_json::json!([{"first_beam": 300, "last_beam": 400, "landmark": 1}]);
    lines[1] = v.to_string();
    let assoc = bad.join("assoc.jsonl");
    std::fs::write(&assoc, lines.join("\n")).unwrap();
    let e = error(Estimate { associations: Some(assoc.clone()), ..estimate(&out, "x") });
    assert!(e.contains("assoc.jsonl:2") && e.contains("300..=400"), "{e}");

    // A scan time the log does not have.
    v["t"] = serde_json::json!(0.05);
    v["observations"] = serde_json::json!([]);
    lines[1] = v.to_string();
    std::fs::write(&assoc, lines.join("\n")).unwrap();
    let e = error(Estimate { associations: Some(assoc.clone()), ..estimate(&out, "x") });
    assert!(e.contains("assoc.jsonl:2") && e.contains("no scan"), "{e}");

    // A typo in a key.
    std::fs::write(&assoc, r#"{"t": 0.0, "observatons": []}"#).unwrap();
    let e = error(Estimate { associations: Some(assoc), ..estimate(&out, "x") });
    assert!(e.contains("assoc.jsonl:1") && e.contains("observatons"), "{e}");

    // The same landmark twice.
    let lm = bad.join("lm.json");
    std::fs::write(&lm, r#"[{"id": 4, "position": [1, 2]}, {"id": 4, "position": [3, 4]}]"#).unwrap();
    let e = error(Estimate { landmarks: Some(lm), ..estimate(&out, "x") });
    assert!(e.contains("lm.json") && e.contains("twice"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
