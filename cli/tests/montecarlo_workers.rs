//! Monte Carlo runs in worker processes: the same records as runs on threads, and a worker
//! that dies costs only its run.

use std::path::{Path, PathBuf};

use scenarios::montecarlo::{self as mc, RunRecord, Shard, StudyPlan, Workers};

/// A 12 s copy of the laser_only scenario (no camera) in `dir`.
fn short_scenario(dir: &Path) -> String {
    std::fs::create_dir_all(dir).unwrap();
    let (mut sc, _) = scenarios::scenario::Scenario::load("laser_only").unwrap();
    sc.name = "laser_only_short".into();
    sc.sim.max_duration_s = Some(12.0);
    sc.pass = Default::default();
    sc.sim.camera.enabled = false;
    let path = dir.join("laser_only_short.toml");
    std::fs::write(&path, toml::to_string(&sc).unwrap()).unwrap();
    path.to_string_lossy().into_owned()
}

/// Records without the wall-clock fields, which legitimately differ between runs.
fn comparable(runs: &[RunRecord]) -> Vec<String> {
    runs.iter().map(|r| serde_json::to_string(&r.without_wall_clock()).unwrap()).collect()
}

fn temp_root(name: &str) -> PathBuf {
    let root = std::env::temp_dir().join(format!("objslam-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(&root).unwrap();
    root
}

fn plan(scenario: String) -> StudyPlan {
    // `combined` needs the camera the scenario lacks: its runs error, in the workers too.
    StudyPlan {
        scenario,
        base_seed: 9,
        runs: 3,
        methods: vec!["nn".into(), "jcbb".into(), "combined".into()],
        vary: vec![],
    }
}

#[test]
fn worker_processes_give_the_records_threads_give() {
    let root = temp_root("mc-workers");
    let plan = plan(short_scenario(&root));
    let threads = mc::run_study(&plan, Shard::all(), &root.join("threads"), |_| {}).unwrap();
    let workers = Workers::Processes { exe: env!("CARGO_BIN_EXE_objslam").into(), count: 2, run_timeout: None };
    let processes = mc::run_study_with(&plan, Shard::all(), &root.join("processes"), &workers, |_| {}).unwrap();
    assert_eq!(processes.len(), 9);
    assert_eq!(processes.iter().filter(|r| r.metrics.is_some()).count(), 6);
    assert_eq!(comparable(&processes), comparable(&threads));
    // runs.jsonl holds every run once.
    let lines = std::fs::read_to_string(root.join("processes/runs.jsonl")).unwrap();
    assert_eq!(lines.lines().count(), 9);
    let _ = std::fs::remove_dir_all(&root);
}

/// A worker program whose first start runs `first` (a shell command) on its first job;
/// every later start is a real worker, fed the plan and the job the script has read.
#[cfg(unix)]
fn first_worker_then_real(root: &Path, name: &str, first: &str) -> PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let marker = root.join(format!("{name}-started"));
    let script = root.join(format!("{name}-worker.sh"));
    std::fs::write(
        &script,
        format!(
            "#!/bin/sh\nread plan\nread job\nif mkdir {marker:?} 2>/dev/null; then {first}; fi\n{{ echo \"$plan\"; echo \"$job\"; cat; }} | exec {exe:?} \"$1\"\n",
            exe = env!("CARGO_BIN_EXE_objslam")
        ),
    )
    .unwrap();
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    script
}

#[cfg(unix)]
#[test]
fn a_worker_that_dies_costs_only_its_run() {
    let root = temp_root("mc-dying-worker");
    let plan = plan(short_scenario(&root));
    let script = first_worker_then_real(&root, "dying", "echo 'simulated crash' >&2; exit 3");
    let workers = Workers::Processes { exe: script, count: 1, run_timeout: None };
    let records = mc::run_study_with(&plan, Shard::all(), &root.join("study"), &workers, |_| {}).unwrap();
    assert_eq!(records.len(), 9);
    let died: Vec<&RunRecord> =
        records.iter().filter(|r| r.error.as_deref().is_some_and(|e| e.contains("worker process failed"))).collect();
    assert_eq!(died.len(), 1, "{records:#?}");
    let error = died[0].error.as_deref().unwrap();
    assert!(error.contains("exit status: 3") && error.contains("simulated crash"), "{error}");
    // The other runs went on: the position-only ones have metrics.
    assert_eq!(records.iter().filter(|r| r.metrics.is_some()).count(), 5);
    // The death was the infrastructure's, not the run's: resuming runs that job again, and
    // the file then holds one record per job, the new one.
    assert!(died[0].retryable);
    let key = died[0].key.clone();
    let resumed = mc::run_study(&plan, Shard::all(), &root.join("study"), |_| {}).unwrap();
    assert_eq!(resumed.len(), 9);
    let again = resumed.iter().find(|r| r.key == key).unwrap();
    assert!(
        !again.retryable && again.error.as_deref().is_none_or(|e| !e.contains("worker process failed")),
        "{again:?}"
    );
    let on_file = mc::read_runs(&root.join("study/runs.jsonl")).unwrap();
    assert_eq!(on_file.len(), 9);
    assert!(on_file.iter().all(|r| !r.retryable));
    let _ = std::fs::remove_dir_all(&root);
}

/// A worker stuck in a run is killed after the run timeout, its run recorded as retryable,
/// and the study goes on with a new worker.
#[cfg(unix)]
#[test]
fn a_stuck_worker_is_killed_after_the_run_timeout() {
    let root = temp_root("mc-stuck-worker");
    let plan = plan(short_scenario(&root));
    let script = first_worker_then_real(&root, "stuck", "exec sleep 600");
    let workers = Workers::Processes { exe: script, count: 1, run_timeout: Some(std::time::Duration::from_secs(20)) };
    let started = std::time::Instant::now();
    let records = mc::run_study_with(&plan, Shard::all(), &root.join("study"), &workers, |_| {}).unwrap();
    assert!(started.elapsed().as_secs() < 300, "the study waited for the stuck worker");
    assert_eq!(records.len(), 9);
    let stuck: Vec<&RunRecord> =
        records.iter().filter(|r| r.error.as_deref().is_some_and(|e| e.contains("--run-timeout"))).collect();
    assert_eq!(stuck.len(), 1, "{records:#?}");
    assert!(stuck[0].retryable);
    assert_eq!(records.iter().filter(|r| r.metrics.is_some()).count(), 5, "the other runs went on");
    let _ = std::fs::remove_dir_all(&root);
}

/// A study that varies the appearance model's training gets each setting's own model, in
/// threads and in worker processes alike (the varied value was once ignored: every run
/// classified with the base scenario's model).
#[test]
fn a_study_varying_the_appearance_training_uses_each_settings_model() {
    let root = temp_root("mc-models");
    let (mut sc, _) = scenarios::scenario::Scenario::load("paper_park").unwrap();
    sc.name = "paper_park_tiny_models".into();
    sc.sim.max_duration_s = Some(6.0);
    sc.pass = Default::default();
    // Tiny models, trained in a moment.
    sc.appearance.training_images = 2;
    sc.appearance.max_patches_per_class = 400;
    sc.appearance.max_components = 2;
    sc.appearance.pca_dims = 4;
    let path = root.join("paper_park_tiny_models.toml");
    std::fs::write(&path, toml::to_string(&sc).unwrap()).unwrap();
    let plan = StudyPlan {
        scenario: path.to_string_lossy().into_owned(),
        base_seed: 1,
        runs: 1,
        methods: vec!["combined".into()],
        vary: vec![mc::Vary::parse("appearance.training_seed=3..4:2").unwrap()],
    };
    let seeds = |runs: &[RunRecord]| -> Vec<(f64, u64)> {
        runs.iter()
            .map(|r| {
                (
                    r.job.params[0].1,
                    r.metrics
                        .as_ref()
                        .unwrap_or_else(|| panic!("{:?}", r.error))
                        .appearance_model
                        .as_ref()
                        .expect("a camera method's model")
                        .training_seed,
                )
            })
            .collect()
    };
    let threads = mc::run_study(&plan, Shard::all(), &root.join("threads"), |_| {}).unwrap();
    assert_eq!(seeds(&threads), vec![(3.0, 3), (4.0, 4)]);
    let exe = PathBuf::from(env!("CARGO_BIN_EXE_objslam"));
    let processes = mc::run_study_with(
        &plan,
        Shard::all(),
        &root.join("processes"),
        &Workers::Processes { exe, count: 2, run_timeout: None },
        |_| {},
    )
    .unwrap();
    assert_eq!(seeds(&processes), vec![(3.0, 3), (4.0, 4)]);
    let _ = std::fs::remove_dir_all(&root);
}
