//! `objslam score` reproduces `objslam run`'s metrics from a log of `objslam record` and
//! the files a run writes (trajectory, landmarks, associations), bit for bit, for a
//! position-only run and for a camera run; a run's output directory is itself a log, scored
//! with its decisions.jsonl; the CSV forms score as the JSON ones; and it refuses inputs
//! that do not fit the log.

use std::path::{Path, PathBuf};

use scenarios::run::{RunOptions, run};
use scenarios::scenario::Scenario;
use scenarios::score::log::{Estimate, LogScoring, score_log};

/// Keys of run metrics that only the method's insides carry: `objslam score` leaves them
/// out (or null), so they are not compared.
const METHOD_INTERNAL_MAP_KEYS: [&str; 2] = ["trees_judged", "missed_by_stage"];

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
        covariances: Some(run.join("trajectory_est_covariance.csv")),
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
    for key in ["unchecked", "poses_scored", "recall_basis", "trajectory_coverage", "warnings"] {
        scored.as_object_mut().unwrap().remove(key);
    }
    for key in METHOD_INTERNAL_MAP_KEYS {
        scored["map"].as_object_mut().unwrap().remove(key);
    }
    let compared: Vec<&String> = scored.as_object().unwrap().keys().collect();
    assert_eq!(compared.len(), 18, "the keys compared: {compared:?}");
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

/// The run's own output directory as the log, its decisions as the associations, and no
/// method name or recall basis given: the run's metrics again.
fn assert_run_directory_reproduces_itself(run_dir: &Path) -> scenarios::score::log::ScoredMetrics {
    let own = Estimate {
        trajectory: run_dir.join("trajectory_est.tum"),
        covariances: None,
        landmarks: Some(run_dir.join("landmarks.json")),
        associations: Some(run_dir.join("decisions.jsonl")),
        method: None,
        recall_basis: None,
    };
    let scored = score_log(run_dir, &own).unwrap();
    assert_reproduced(run_dir, &scored);
    scored
}

/// `rows` as CSV under `header` (null: an empty cell).
fn csv_of(header: &str, rows: impl Iterator<Item = Vec<serde_json::Value>>) -> String {
    let cell = |v: &serde_json::Value| if v.is_null() { String::new() } else { v.to_string() };
    let mut out = format!("{header}\n");
    for row in rows {
        out.push_str(&row.iter().map(cell).collect::<Vec<_>>().join(","));
        out.push('\n');
    }
    out
}

/// The CSV forms of a run's map and decisions score as their JSON forms (fusions, which CSV
/// cannot hold, left out of both).
fn assert_csv_forms_score_alike(run_dir: &Path) {
    let dir = run_dir.join("csv");
    std::fs::create_dir_all(&dir).unwrap();
    let landmarks: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("landmarks.json")).unwrap()).unwrap();
    let rows = landmarks.iter().map(|l| vec![l["id"].clone(), l["position"][0].clone(), l["position"][1].clone()]);
    std::fs::write(dir.join("landmarks.csv"), csv_of("id,x,y", rows)).unwrap();
    let lines: Vec<serde_json::Value> = std::fs::read_to_string(run_dir.join("decisions.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .filter(|v: &serde_json::Value| v.get("fusion").is_none())
        .collect();
    let json_lines: String = lines.iter().map(|v| v.to_string() + "\n").collect();
    std::fs::write(dir.join("decisions.jsonl"), json_lines).unwrap();
    let rows = lines.iter().map(|v| vec![v["t"].clone(), v["observation"].clone(), v["choice"]["landmark"].clone()]);
    std::fs::write(dir.join("decisions.csv"), csv_of("t,observation,landmark", rows)).unwrap();
    let by_beams: Vec<serde_json::Value> = std::fs::read_to_string(run_dir.join("associations.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let rows = by_beams.iter().flat_map(|v| {
        v["observations"]
            .as_array()
            .unwrap()
            .iter()
            .map(|o| vec![v["t"].clone(), o["first_beam"].clone(), o["last_beam"].clone(), o["landmark"].clone()])
    });
    std::fs::write(dir.join("associations.csv"), csv_of("t,first_beam,last_beam,landmark", rows)).unwrap();
    let score = |landmarks: &str, associations: &str| {
        let e = Estimate {
            trajectory: run_dir.join("trajectory_est.tum"),
            covariances: None,
            landmarks: Some(dir.join(landmarks)),
            associations: Some(dir.join(associations)),
            method: None,
            recall_basis: None,
        };
        serde_json::to_value(score_log(run_dir, &e).unwrap()).unwrap()
    };
    let json = score("../landmarks.json", "decisions.jsonl");
    assert!(json["associations"]["total"].as_u64().unwrap() > 0, "{json}");
    assert_eq!(score("landmarks.csv", "decisions.csv"), json);
    assert_eq!(score("landmarks.csv", "associations.csv"), json);
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

    // A trajectory alone: the trajectory's figures, the criteria on the pose and route
    // judged as with the map, and no verdict on the map's criteria.
    let alone = Estimate { landmarks: None, associations: None, covariances: None, ..estimate(&out, "jcbb") };
    let scored_alone = score_log(&log, &alone).unwrap();
    assert_eq!(scored_alone.ate_rmse_m.to_bits(), scored.ate_rmse_m.to_bits());
    assert!(scored_alone.map.is_none() && scored_alone.associations.is_none());
    assert!(!scored_alone.unchecked.is_empty(), "{scored_alone:?}");
    assert!(scored_alone.failures.iter().all(|f| scored.failures.contains(f)), "{scored_alone:?}");
    assert_eq!(scored_alone.passed, (!scored_alone.failures.is_empty()).then_some(false));
    assert!(scored_alone.anees.is_nan(), "no covariances given: no ANEES");

    let own = assert_run_directory_reproduces_itself(&out);
    assert_eq!(own.method, "jcbb", "a run's own trajectory is scored under its method's name");
    assert_csv_forms_score_alike(&out);
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
    // A record log whose camera index is gone or cut: an error, not a recall on other evidence.
    let index = log.join("camera.jsonl");
    let frames = std::fs::read_to_string(&index).unwrap();
    let cut: String = frames.lines().take(3).map(|l| format!("{l}\n")).collect();
    std::fs::write(&index, cut).unwrap();
    let e = score_log(&log, &estimate(&out, "combined")).expect_err("a cut camera index").to_string();
    assert!(e.contains("camera.jsonl") && e.contains("3 frames") && e.contains("summary.camera_frames"), "{e}");
    std::fs::remove_file(&index).unwrap();
    let e = score_log(&log, &estimate(&out, "combined")).expect_err("no camera index").to_string();
    assert!(e.contains("camera.jsonl") && e.contains("no frame"), "{e}");
    std::fs::write(&index, frames).unwrap();
    // Without its images: the beams its frames showed on their trees (trees_shown.jsonl).
    assert!(!out.join("camera.jsonl").exists());
    let own = assert_run_directory_reproduces_itself(&out);
    assert_eq!(own.map.unwrap().trees_in_view, map.trees_in_view);
    // Without that file the run's camera evidence is missing: an error, not another recall.
    std::fs::rename(out.join("trees_shown.jsonl"), dir.join("moved.jsonl")).unwrap();
    let own = Estimate { method: None, recall_basis: None, ..estimate(&out, "combined") };
    let e = score_log(&out, &own).expect_err("no trees_shown.jsonl").to_string();
    assert!(e.contains("trees_shown.jsonl"), "{e}");
    // Cut to its first line, it would count fewer trees in view than the run did.
    let shown = std::fs::read_to_string(dir.join("moved.jsonl")).unwrap();
    std::fs::write(out.join("trees_shown.jsonl"), shown.lines().next().unwrap().to_string() + "\n").unwrap();
    let e = score_log(&out, &own).expect_err("a cut trees_shown.jsonl").to_string();
    assert!(e.contains("trees_shown.jsonl") && e.contains("map.trees_in_view"), "{e}");
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
    let e = error(Estimate { trajectory: tum.clone(), ..estimate(&out, "x") });
    assert!(e.contains("late.tum") && e.contains("pose 2") && e.contains("outside"), "{e}");

    // A trajectory of the first few poses is scored, with how little of the log it covers;
    // one off the plane is scored in the plane and said to be; a byte-order mark is read past.
    let own = std::fs::read_to_string(out.join("trajectory_est.tum")).unwrap();
    let poses: Vec<&str> = own.lines().filter(|l| !l.starts_with('#')).collect();
    let trajectory_only = |trajectory: PathBuf| Estimate {
        trajectory,
        covariances: None,
        landmarks: None,
        associations: None,
        ..estimate(&out, "x")
    };
    let whole = score_log(&log, &trajectory_only(out.join("trajectory_est.tum"))).unwrap();
    assert_eq!((whole.trajectory_coverage, whole.warnings.len()), (1.0, 0), "{:?}", whole.warnings);
    let first: String = poses[..10].iter().map(|l| format!("{l}\n")).collect();
    std::fs::write(&tum, first).unwrap();
    // The pose criteria are checked with or without the map: so little cannot pass.
    let m = score_log(&log, &trajectory_only(tum.clone())).unwrap();
    assert!(m.trajectory_coverage > 0.0 && m.trajectory_coverage < 0.5, "{}", m.trajectory_coverage);
    assert_eq!(m.passed, Some(false), "{m:?}");
    assert!(m.failures.iter().any(|f| f.contains("the trajectory covers") && f.contains("90.0%")), "{:?}", m.failures);
    let m = score_log(&log, &Estimate { trajectory: tum.clone(), covariances: None, ..estimate(&out, "x") }).unwrap();
    assert_eq!(m.passed, Some(false), "{m:?}");
    assert!(m.failures.iter().any(|f| f.contains("the trajectory covers") && f.contains("90.0%")), "{:?}", m.failures);
    let lifted: String = poses
        .iter()
        .map(|l| {
            let mut v: Vec<&str> = l.split_whitespace().collect();
            v[3] = "0.5";
            v.join(" ") + "\n"
        })
        .collect();
    std::fs::write(&tum, format!("\u{feff}{lifted}")).unwrap();
    let m = score_log(&log, &trajectory_only(tum.clone())).unwrap();
    assert_eq!(m.ate_rmse_m, whole.ate_rmse_m, "z is not scored");
    assert!(m.warnings.iter().any(|w| w.contains("leaves the plane") && w.contains("0.500 m")), "{:?}", m.warnings);
    // A trajectory with a 2 s hole in it: the RPE's pairs over the hole are said to be longer.
    let t0: f64 = poses[0].split_whitespace().next().unwrap().parse().unwrap();
    let holed: String = poses
        .iter()
        .filter(|l| {
            let t: f64 = l.split_whitespace().next().unwrap().parse().unwrap();
            !(t0 + 2.0..t0 + 4.0).contains(&t)
        })
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(&tum, holed).unwrap();
    let m = score_log(&log, &trajectory_only(tum.clone())).unwrap();
    assert!(m.rpe_rmse_m.is_finite(), "{m:?}");
    assert!(m.warnings.iter().any(|w| w.contains("RPE") && w.contains("gaps in the trajectory")), "{:?}", m.warnings);

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

    // Observations of one scan that share a beam: a beam is one observation's at most.
    v["observations"] = serde_json::json!([
        {"first_beam": 296, "last_beam": 303, "landmark": 1},
        {"first_beam": 297, "last_beam": 303, "landmark": 1}
    ]);
    lines[1] = v.to_string();
    std::fs::write(&assoc, lines.join("\n")).unwrap();
    let e = error(Estimate { associations: Some(assoc.clone()), ..estimate(&out, "x") });
    assert!(e.contains("assoc.jsonl:2") && e.contains("overlap"), "{e}");
    v["observations"] = serde_json::json!([{"first_beam": 303, "last_beam": 296, "landmark": 1}]);
    lines[1] = v.to_string();
    std::fs::write(&assoc, lines.join("\n")).unwrap();
    let e = error(Estimate { associations: Some(assoc.clone()), ..estimate(&out, "x") });
    assert!(e.contains("assoc.jsonl:2") && e.contains("comes after the last"), "{e}");

    // A fusion of landmarks that no association has made.
    v["observations"] = serde_json::json!([]);
    v["fusions"] = serde_json::json!([{"kept": 999, "removed": 998}]);
    lines[1] = v.to_string();
    std::fs::write(&assoc, lines.join("\n")).unwrap();
    let e = error(Estimate { associations: Some(assoc.clone()), ..estimate(&out, "x") });
    assert!(e.contains("assoc.jsonl:2") && e.contains("landmark 999 is fused before"), "{e}");
    v.as_object_mut().unwrap().remove("fusions");

    // A landmark fused away, then associated again: refused at the later scan's line.
    let named_at = |line: &str| -> Vec<u64> {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        v["observations"].as_array().unwrap().iter().filter_map(|o| o["landmark"].as_u64()).collect()
    };
    let original: Vec<String> = text.lines().map(String::from).collect();
    let mut seen: Vec<u64> = Vec::new();
    let mut case = None;
    'search: for (i, line) in original.iter().enumerate() {
        for id in named_at(line) {
            if !seen.contains(&id) {
                seen.push(id);
            }
        }
        if seen.len() < 2 {
            continue;
        }
        let (kept, removed) = (seen[0], seen[1]);
        for (j, later) in original.iter().enumerate().skip(i + 1) {
            if named_at(later).contains(&removed) {
                case = Some((i, j, kept, removed));
                break 'search;
            }
        }
    }
    let (i, j, kept, removed) = case.expect("two landmarks, the second associated again later");
    let mut fused = original.clone();
    let mut at: serde_json::Value = serde_json::from_str(&fused[i]).unwrap();
    at["fusions"] = serde_json::json!([{"kept": kept, "removed": removed}]);
    fused[i] = at.to_string();
    std::fs::write(&assoc, fused.join("\n")).unwrap();
    let e = error(Estimate { associations: Some(assoc.clone()), ..estimate(&out, "x") });
    assert!(
        e.contains(&format!("assoc.jsonl:{}", j + 1))
            && e.contains(&format!("landmark {removed}, which was fused away")),
        "{e}"
    );

    // A scan time the log does not have.
    v["t"] = serde_json::json!(0.05);
    v["observations"] = serde_json::json!([]);
    lines[1] = v.to_string();
    std::fs::write(&assoc, lines.join("\n")).unwrap();
    let e = error(Estimate { associations: Some(assoc.clone()), ..estimate(&out, "x") });
    assert!(e.contains("assoc.jsonl:2") && e.contains("no scan"), "{e}");

    // A typo in a key.
    std::fs::write(&assoc, r#"{"t": 0.0, "observatons": []}"#).unwrap();
    let e = error(Estimate { associations: Some(assoc.clone()), ..estimate(&out, "x") });
    assert!(e.contains("assoc.jsonl:1") && e.contains("observatons"), "{e}");

    // By id: an observation the log's scan does not have, and a landmark that contradicts
    // the choice.
    std::fs::write(
        &assoc,
        "{\"t\": 0.0, \"observation\": 0, \"landmark\": 3}\n{\"t\": 0.0, \"observation\": 99, \"landmark\": 1}\n",
    )
    .unwrap();
    let e = error(Estimate { associations: Some(assoc.clone()), ..estimate(&out, "x") });
    assert!(e.contains("assoc.jsonl:2") && e.contains("observation 99") && e.contains("observations.jsonl"), "{e}");
    std::fs::write(&assoc, r#"{"t": 0.0, "observation": 0, "landmark": 3, "choice": {"kind": "new", "landmark": 4}}"#)
        .unwrap();
    let e = error(Estimate { associations: Some(assoc.clone()), ..estimate(&out, "x") });
    assert!(e.contains("assoc.jsonl:1") && e.contains("disagree"), "{e}");
    // A choice of no landmark that holds one, and a landmark new a second time.
    std::fs::write(&assoc, r#"{"t": 0.0, "observation": 0, "choice": {"kind": "rejected", "landmark": 3}}"#).unwrap();
    let e = error(Estimate { associations: Some(assoc.clone()), ..estimate(&out, "x") });
    assert!(e.contains("assoc.jsonl:1") && e.contains("names no landmark, yet holds `landmark`"), "{e}");
    std::fs::write(
        &assoc,
        "{\"t\": 0.0, \"observation\": 0, \"choice\": {\"kind\": \"new\", \"landmark\": 3}}\n\
         {\"t\": 0.0, \"observation\": 1, \"choice\": {\"kind\": \"new\", \"landmark\": 3}}\n",
    )
    .unwrap();
    let e = error(Estimate { associations: Some(assoc.clone()), ..estimate(&out, "x") });
    assert!(
        e.contains("assoc.jsonl:2") && e.contains("landmark 3 is chosen as new, but line 1 named it before"),
        "{e}"
    );

    // CSV: a header of neither form, and a cell that is not a number.
    let csv = bad.join("assoc.csv");
    std::fs::write(&csv, "t,obs,landmark\n0.0,0,1\n").unwrap();
    let e = error(Estimate { associations: Some(csv.clone()), ..estimate(&out, "x") });
    assert!(e.contains("assoc.csv:1") && e.contains("t,observation,landmark"), "{e}");
    std::fs::write(&csv, "t,observation,landmark\n0.0,0,1\n0.1,zero,1\n").unwrap();
    let e = error(Estimate { associations: Some(csv), ..estimate(&out, "x") });
    assert!(e.contains("assoc.csv:3") && e.contains("observation") && e.contains("zero"), "{e}");
    let lm_csv = bad.join("lm.csv");
    std::fs::write(&lm_csv, "id,x,y\n1,2.0\n").unwrap();
    let e = error(Estimate { landmarks: Some(lm_csv), ..estimate(&out, "x") });
    assert!(e.contains("lm.csv:2"), "{e}");

    // An observation of the log's that lies outside its scan.
    let observations = std::fs::read_to_string(log.join("observations.jsonl")).unwrap();
    let mut first: serde_json::Value = serde_json::from_str(observations.lines().next().unwrap()).unwrap();
    first["observations"] = serde_json::json!([{"first_beam": 5, "last_beam": 900}]);
    let edited = first.to_string() + "\n" + &observations.lines().skip(1).collect::<Vec<_>>().join("\n");
    std::fs::write(log.join("observations.jsonl"), edited).unwrap();
    std::fs::write(&assoc, "{\"t\": 0.0, \"observation\": 0, \"landmark\": 3}\n").unwrap();
    let e = error(Estimate { associations: Some(assoc.clone()), ..estimate(&out, "x") });
    assert!(e.contains("observations.jsonl:1") && e.contains("5..=900"), "{e}");
    std::fs::write(log.join("observations.jsonl"), observations).unwrap();

    // A covariance at a time the trajectory has no pose at.
    let cov = bad.join("cov.csv");
    std::fs::write(&cov, "t,xx,xy,xtheta,yy,ytheta,thetatheta\n0.0123,1,0,0,1,0,1\n").unwrap();
    let e = error(Estimate { covariances: Some(cov), ..estimate(&out, "x") });
    assert!(e.contains("cov.csv:2") && e.contains("no pose"), "{e}");

    // Covariances of which none is positive definite: no ANEES, and a warning that says so.
    let first_pose_t = poses[0].split_whitespace().next().unwrap();
    let negative = bad.join("negative.csv");
    std::fs::write(&negative, format!("t,xx,xy,xtheta,yy,ytheta,thetatheta\n{first_pose_t},-1,0,0,-1,0,-1\n")).unwrap();
    let m =
        score_log(&log, &Estimate { covariances: Some(negative), ..trajectory_only(out.join("trajectory_est.tum")) })
            .unwrap();
    assert!(m.anees.is_nan(), "{}", m.anees);
    assert!(m.warnings.iter().any(|w| w.contains("no ANEES") && w.contains("negative.csv")), "{:?}", m.warnings);

    // Covariances for part of the trajectory, one of them not positive definite: an ANEES
    // over the rest, with a warning that says how few.
    let second_pose_t = poses[1].split_whitespace().next().unwrap();
    let part = bad.join("part.csv");
    std::fs::write(
        &part,
        format!("t,xx,xy,xtheta,yy,ytheta,thetatheta\n{first_pose_t},1,0,0,1,0,1\n{second_pose_t},-1,0,0,-1,0,-1\n"),
    )
    .unwrap();
    let m = score_log(&log, &Estimate { covariances: Some(part), ..trajectory_only(out.join("trajectory_est.tum")) })
        .unwrap();
    assert!(m.anees.is_finite(), "{}", m.anees);
    let says = format!("the ANEES is over 1 of the trajectory's {} poses", poses.len());
    assert!(
        m.warnings.iter().any(|w| w.contains(&says)
            && w.contains("part.csv gives 2 of them a covariance (1 not positive definite)")),
        "{:?}",
        m.warnings
    );

    // Scans out of time order in the log are the log's fault, also when associations
    // (which follow the scans' times) are given.
    let laser = std::fs::read_to_string(log.join("laser.jsonl")).unwrap();
    let mut lines: Vec<&str> = laser.lines().collect();
    lines.swap(9, 10);
    std::fs::write(log.join("laser.jsonl"), lines.join("\n") + "\n").unwrap();
    let e = error(estimate(&out, "x"));
    assert!(e.contains("laser.jsonl:11") && e.contains("does not follow"), "{e}");
    std::fs::write(log.join("laser.jsonl"), laser).unwrap();

    // A damaged collisions.jsonl is an error naming its line, not a count of its lines.
    let collisions = std::fs::read_to_string(log.join("collisions.jsonl")).unwrap();
    std::fs::write(log.join("collisions.jsonl"), format!("{collisions}hello world\n")).unwrap();
    let e = error(estimate(&out, "x"));
    assert!(e.contains("collisions.jsonl:") && e.contains("expected"), "{e}");
    std::fs::write(log.join("collisions.jsonl"), collisions).unwrap();

    // The same landmark twice.
    let lm = bad.join("lm.json");
    std::fs::write(&lm, r#"[{"id": 4, "position": [1, 2]}, {"id": 4, "position": [3, 4]}]"#).unwrap();
    let e = error(Estimate { landmarks: Some(lm), ..estimate(&out, "x") });
    assert!(e.contains("lm.json") && e.contains("twice"), "{e}");

    // A robot log and a ROS 2 bag are named for what they are, with what reads them.
    let robot_log = dir.join("robot_log");
    std::fs::create_dir_all(&robot_log).unwrap();
    std::fs::write(robot_log.join(robotlog::format::MANIFEST), "").unwrap();
    let e = score_log(&robot_log, &estimate(&out, "x")).expect_err("a robot log").to_string();
    assert!(e.contains("robot_log") && e.contains("robot log") && e.contains("objslam replay"), "{e}");
    let bag = dir.join("bag");
    std::fs::create_dir_all(&bag).unwrap();
    std::fs::write(bag.join("metadata.yaml"), "").unwrap();
    let e = score_log(&bag, &estimate(&out, "x")).expect_err("a bag").to_string();
    assert!(e.contains("ROS 2 bag") && e.contains("metadata.json"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A recording replaces an earlier recording's files, never files of its names that no
/// recording wrote; a recording whose move into place was stopped is finished by the
/// next, so that two stops in a row leave a directory the next recording takes.
#[test]
fn a_recording_replaces_only_an_earlier_recording() {
    let dir = std::env::temp_dir().join(format!("objslam-record-over-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (mut sc, base) = Scenario::load("laser_only").unwrap();
    sc.sim.max_duration_s = Some(1.0);
    let world = sc.world(&base, 1).unwrap();
    let record = |out: &Path| {
        scenarios::record::record(
            &world,
            &sc.sim,
            1,
            &LogScoring::of_scenario(&sc, 1),
            out,
            scenarios::record::RecordFormat::Jsonl,
            |_, _| {},
        )
    };
    // Someone's own camera/ and world.toml.
    let mine = dir.join("mine");
    std::fs::create_dir_all(mine.join("camera")).unwrap();
    std::fs::write(mine.join("camera/photo.png"), "mine").unwrap();
    std::fs::write(mine.join("world.toml"), "mine").unwrap();
    // Another command's outputs stopped while moved in wait in the unfinished directory:
    // a refused recording leaves them there.
    std::fs::create_dir_all(mine.join(".unfinished")).unwrap();
    std::fs::write(mine.join(".unfinished/dataset.json"), "{}").unwrap();
    let e = record(&mine).expect_err("refused").to_string();
    assert!(e.contains("holds finished outputs stopped while") && e.contains("run `objslam dataset`"), "{e}");
    assert!(mine.join(".unfinished/dataset.json").is_file(), "another command's unfinished outputs are kept");
    // A draft cut short (a manifest written in part) is no finished move.
    std::fs::remove_file(mine.join(".unfinished/dataset.json")).unwrap();
    std::fs::write(mine.join(".unfinished/manifest.toml"), "").unwrap();
    let e = record(&mine).expect_err("refused").to_string();
    assert!(e.contains("holds camera, which a recording writes or removes, but no earlier recording"), "{e}");
    assert_eq!(std::fs::read_to_string(mine.join("camera/photo.png")).unwrap(), "mine");
    // A metadata.json of another command is no recording's either.
    let other = dir.join("other");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::write(other.join("metadata.json"), r#"{"tool": "objslam score"}"#).unwrap();
    let e = record(&other).expect_err("refused").to_string();
    assert!(e.contains("holds metadata.json"), "{e}");
    // An earlier recording is replaced; one stopped while moved in (its marker still in the
    // unfinished directory) is finished, then replaced.
    let log = dir.join("log");
    record(&log).unwrap();
    record(&log).unwrap();
    let recorded: Vec<_> = std::fs::read_dir(&log).unwrap().map(|f| f.unwrap().file_name()).collect();
    let unfinished = log.join(".unfinished");
    std::fs::create_dir_all(&unfinished).unwrap();
    for moved_last in ["laser.jsonl", "metadata.json"] {
        std::fs::rename(log.join(moved_last), unfinished.join(moved_last)).unwrap();
    }
    // The move's list of what it brings in, as a move writes it before it removes anything.
    let names: Vec<String> = recorded.iter().map(|n| n.to_string_lossy().into_owned()).collect();
    std::fs::write(unfinished.join(".moving.json"), serde_json::to_string(&names).unwrap()).unwrap();
    // Finished before the checks: a run's metrics.json found after it leaves the stopped
    // recording whole, what it had moved in kept.
    std::fs::write(log.join("metrics.json"), "{}").unwrap();
    let e = record(&log).expect_err("a run's outputs").to_string();
    assert!(e.contains("holds a run's outputs"), "{e}");
    std::fs::remove_file(log.join("metrics.json")).unwrap();
    for name in &recorded {
        assert!(log.join(name).exists(), "{name:?} is in place");
    }
    record(&log).unwrap();
    assert!(log.join("metadata.json").is_file() && !unfinished.exists());
    // Both kinds' markers go first when a recording replaces another.
    let names = scenarios::record::recording_files();
    assert_eq!(names[..2], ["manifest.toml", "metadata.json"]);
    let _ = std::fs::remove_dir_all(&dir);
}
