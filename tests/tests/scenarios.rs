//! End-to-end regression tests: library scenarios against their pass criteria, and run
//! determinism.

use scenarios::run::{RunOptions, run};
use scenarios::scenario::Scenario;

fn run_named(name: &str, seed: Option<u64>, max_duration: Option<f64>) -> scenarios::run::Metrics {
    let (mut sc, base) = Scenario::load(name).unwrap();
    if max_duration.is_some() {
        sc.sim.max_duration_s = max_duration;
    }
    run(&sc, &base, &RunOptions { seed, ..Default::default() }, |_| {}).unwrap().metrics
}

/// Guards the paper's argument: on the paper's world a position-only method maps posts
/// and people as landmarks.
#[test]
fn laser_only_baseline_maps_posts_and_people() {
    let m = run_named("laser_only", None, None);
    assert!(m.passed, "{:?}", m.failures);
    assert!(m.map.posts >= 1, "no post mapped: {:?}", m.map);
    assert!(m.map.people >= 1, "no person mapped: {:?}", m.map);
    assert!(m.route_completed && m.collisions == 0);
    assert_eq!(m.map.tree_recall, Some(1.0), "the baseline still maps every tree the laser sees: {:?}", m.map);
    assert_eq!(m.map.trees_in_view, None, "a run without a camera has no trees in view");
    assert!(m.ate_rmse_m < 0.5, "ATE {}", m.ate_rmse_m);
    // The filter learns the odometry's calibration errors from the re-observed landmarks:
    // each estimate within 3 sigma of the simulator's truth, each sigma well under its
    // prior (scale 0.015, turn scale 0.03, bias 0.003 rad/m).
    let c = m.odometry_calibration.expect("the default filter estimates the odometry's calibration");
    for (k, prior) in [0.015, 0.03, 0.003].into_iter().enumerate() {
        assert!((c.estimated[k] - c.truth[k]).abs() < 3.0 * c.sigma[k], "parameter {k}: {c:?}");
        assert!(c.sigma[k] < 0.5 * prior, "parameter {k} barely learned: {c:?}");
    }
}

/// Same scenario and seed: identical metrics (but wall time) and trajectories.
#[test]
fn runs_are_deterministic() {
    let dir = std::env::temp_dir().join(format!("objslam-determinism-{}", std::process::id()));
    let (mut sc, base) = Scenario::load("laser_only").unwrap();
    sc.sim.max_duration_s = Some(40.0);
    let mut outs = Vec::new();
    for k in 0..2 {
        let out = dir.join(format!("run{k}"));
        let m = run(&sc, &base, &RunOptions { seed: Some(9), out: Some(out.clone()), ..Default::default() }, |_| {})
            .unwrap()
            .metrics;
        outs.push((
            m,
            std::fs::read_to_string(out.join("trajectory_est.tum")).unwrap(),
            std::fs::read_to_string(out.join("decisions.jsonl")).unwrap(),
        ));
    }
    let strip = |m: &scenarios::run::Metrics| m.without_wall_clock();
    assert_eq!(strip(&outs[0].0), strip(&outs[1].0));
    assert_eq!(outs[0].1, outs[1].1, "estimated trajectories differ");
    assert_eq!(outs[0].2, outs[1].2, "association logs differ");
    let other = run(&sc, &base, &RunOptions { seed: Some(10), ..Default::default() }, |_| {}).unwrap().metrics;
    assert_ne!(strip(&other), strip(&outs[0].0), "the seed must matter");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A run's metrics without wall-clock fields, and its estimated path, association log and
/// segmentation log.
type RunLogs = (scenarios::run::Metrics, String, String, String);

/// A run into `out`, read back for comparing runs that must agree.
fn run_and_read(sc: &Scenario, base: &std::path::Path, options: RunOptions, out: &std::path::Path) -> RunLogs {
    let m = run(sc, base, &RunOptions { out: Some(out.to_path_buf()), ..options }, |_| {}).unwrap().metrics;
    let read = |name: &str| std::fs::read_to_string(out.join(name)).unwrap();
    (m.without_wall_clock(), read("trajectory_est.tum"), read("decisions.jsonl"), read("segmentation.jsonl"))
}

fn assert_same_run(a: &RunLogs, b: &RunLogs) {
    assert_eq!(a.0, b.0);
    assert_eq!(a.1, b.1, "estimated trajectories differ");
    assert_eq!(a.2, b.2, "association logs differ");
    assert_eq!(a.3, b.3, "segmentation logs differ");
}

/// The paper's method segments a scan's clusters in parallel: the first 30 s of
/// paper_park on one thread and on four give the same metrics, path, association and
/// segmentation logs.
#[test]
fn combined_runs_are_identical_whatever_the_thread_count() {
    let dir = std::env::temp_dir().join(format!("objslam-threads-{}", std::process::id()));
    let (mut sc, base) = Scenario::load("paper_park").unwrap();
    sc.sim.max_duration_s = Some(30.0);
    let on = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| run_and_read(&sc, &base, RunOptions::default(), &dir.join(format!("threads{threads}"))))
    };
    let (one, four) = (on(1), on(4));
    assert!(one.3.lines().count() > 20, "too few segmented clusters to compare");
    assert_same_run(&one, &four);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The camera renders only the image regions the pipeline will read (chosen from the
/// scan of the frame's instant): the first 60 s of paper_park give the same metrics, path,
/// association and segmentation logs as with whole frames, from a fraction of the pixels.
#[test]
fn rendering_only_the_regions_the_pipeline_reads_changes_no_result() {
    let dir = std::env::temp_dir().join(format!("objslam-regions-{}", std::process::id()));
    let (mut sc, base) = Scenario::load("paper_park").unwrap();
    sc.sim.max_duration_s = Some(60.0);
    let with = |full_frames: bool| {
        run_and_read(
            &sc,
            &base,
            RunOptions { full_frames, ..Default::default() },
            &dir.join(format!("full{full_frames}")),
        )
    };
    let (mut regions, whole) = (with(false), with(true));
    assert_eq!(whole.0.timing.rendered_fraction, 1.0);
    let fraction = regions.0.timing.rendered_fraction;
    assert!(fraction > 0.02 && fraction < 0.5, "rendered fraction {fraction}");
    regions.0.timing.rendered_fraction = 1.0;
    assert!(whole.3.lines().count() > 50, "too few segmented clusters to compare");
    assert_same_run(&regions, &whole);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A pipeline that may segment a scan in an older frame (image_max_age_s as long as the
/// laser's period less a physics step: scans fire on the step at or after their time) could
/// read regions chosen for another scan: the camera then renders whole frames.
#[test]
fn frames_that_later_scans_may_read_are_rendered_whole() {
    let (mut sc, base) = Scenario::load("paper_park").unwrap();
    sc.sim.max_duration_s = Some(20.0);
    for age in [0.15, 0.095] {
        sc.pipeline.image_max_age_s = age;
        let m = run(&sc, &base, &RunOptions::default(), |_| {}).unwrap().metrics;
        assert_eq!(m.timing.rendered_fraction, 1.0, "image_max_age_s {age}");
        assert!(m.associations.total > 20 && m.associations.wrong == 0, "{:?}", m.associations);
    }
}

/// The scenario a run writes (`scenario.toml`) is the run's, command-line seed and method
/// written in and files named by absolute path: run alone, it gives the same run; once a
/// file it names has changed, running it again says so.
#[test]
fn recorded_scenario_runs_the_run_again() {
    let dir = std::env::temp_dir().join(format!("objslam-as-run-{}", std::process::id()));
    let inputs = dir.join("inputs");
    std::fs::create_dir_all(&inputs).unwrap();
    let world_file = inputs.join("w.toml");
    std::fs::write(&world_file, worlds::generate::park(&Default::default(), 5).unwrap().to_toml()).unwrap();
    let (mut sc, _) = Scenario::load("laser_only").unwrap();
    sc.world = scenarios::scenario::WorldSource { preset: None, file: Some("w.toml".into()), seed: None, params: None };
    sc.sim.max_duration_s = Some(20.0);
    let out = dir.join("run");
    let options = RunOptions {
        seed: Some(3),
        method: Some(slam::association::AssociationMethod::Nn),
        out: Some(out.clone()),
        ..Default::default()
    };
    // Given through `..`, the inputs are recorded by their own paths.
    let first = run(&sc, &inputs.join("../inputs"), &options, |_| {}).unwrap().metrics;
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metadata.json")).unwrap()).unwrap();
    let recorded_world = meta["configuration"]["inputs"].as_array().unwrap().iter().find(|i| i["what"] == "world file");
    assert_eq!(recorded_world.unwrap()["file"], world_file.canonicalize().unwrap().to_str().unwrap());
    let written = out.join("scenario.toml");
    let (recorded, base) = Scenario::load(written.to_str().unwrap()).unwrap();
    assert_eq!((recorded.seed, recorded.pipeline.method), (3, slam::association::AssociationMethod::Nn));
    assert_eq!(recorded.world.file.as_deref(), Some(std::path::absolute(&world_file).unwrap().to_str().unwrap()));
    let again = run(&recorded, &base, &RunOptions::default(), |_| {}).unwrap().metrics;
    let figures =
        |m: &scenarios::run::Metrics| (m.seed, m.method.clone(), m.ate_rmse_m, m.landmarks, m.associations.total);
    assert_eq!(figures(&again), figures(&first));
    assert_ne!(first.seed, sc.seed, "the test must override the scenario's seed");
    assert_eq!(scenarios::run::changed_inputs(&written, &recorded, &base), Vec::<String>::new());
    std::fs::write(&world_file, std::fs::read_to_string(&world_file).unwrap() + "# moved a tree\n").unwrap();
    let changed = scenarios::run::changed_inputs(&written, &recorded, &base);
    assert!(
        changed.len() == 1 && changed[0].starts_with("world file ") && changed[0].contains("has changed"),
        "{changed:?}"
    );
    // A run recorded before paths were resolved named its inputs as given, `..` and all.
    let mut meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metadata.json")).unwrap()).unwrap();
    for input in meta["configuration"]["inputs"].as_array_mut().unwrap() {
        if input["what"] == "world file" {
            input["file"] = serde_json::json!(inputs.join("../inputs/w.toml"));
        }
    }
    std::fs::write(out.join("metadata.json"), meta.to_string()).unwrap();
    let again = scenarios::run::changed_inputs(&written, &recorded, &base);
    assert!(again.len() == 1 && again[0].contains("/inputs/../inputs/w.toml has changed"), "{again:?}");
    // The model a camera run used is compared after the new run: another cache's is named.
    let mut meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metadata.json")).unwrap()).unwrap();
    meta["appearance_model"] = serde_json::json!({"digest": "10e8c1e8666dffa0"});
    std::fs::write(out.join("metadata.json"), meta.to_string()).unwrap();
    let model = |digest: &str| scenarios::run::ModelProvenance {
        training_seed: 1,
        training_images: 60,
        training_renderer: None,
        digest: Some(digest.into()),
    };
    assert_eq!(scenarios::run::changed_model(&written, Some(&model("10e8c1e8666dffa0"))), None);
    let warned = scenarios::run::changed_model(&written, Some(&model("2d4b3d4e231dadc2"))).unwrap();
    assert!(warned.contains("digest 2d4b3d4e231dadc2") && warned.contains("(10e8c1e8666dffa0)"), "{warned}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Every output file of `objslam run` is written and parses.
#[test]
fn run_writes_every_output() {
    let dir = std::env::temp_dir().join(format!("objslam-outputs-{}", std::process::id()));
    // A reused directory: an earlier camera run's outputs, which this run does not write,
    // must not be left to be taken for its own.
    std::fs::create_dir_all(dir.join("objects")).unwrap();
    std::fs::write(dir.join("segmentation.jsonl"), "{}\n").unwrap();
    std::fs::write(dir.join("objects/models.json"), "[]").unwrap();
    // Its mark of a finished run (without it the directory is refused: see
    // `files_of_a_runs_names_where_no_run_was_are_refused`).
    std::fs::write(dir.join("metadata.json"), r#"{"tool": "objslam run"}"#).unwrap();
    let (mut sc, base) = Scenario::load("laser_only").unwrap();
    sc.sim.max_duration_s = Some(20.0);
    let m = run(&sc, &base, &RunOptions { seed: Some(3), out: Some(dir.clone()), ..Default::default() }, |_| {})
        .unwrap()
        .metrics;
    assert!(!dir.join("segmentation.jsonl").exists() && !dir.join("objects").exists(), "stale outputs left");
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("metrics.json")).unwrap()).unwrap();
    for key in [
        "scenario",
        "seed",
        "method",
        "sim_seconds",
        "wall_seconds",
        "realtime_factor",
        "ate_rmse_m",
        "landmark_rmse_m",
        "map",
        "associations",
        "duplicate_landmarks",
        "merged_landmarks",
        "retracted_landmarks",
        "segmentation",
        "odometry_calibration",
        "anees",
        "passed",
    ] {
        assert!(metrics.get(key).is_some(), "metrics.json lacks {key}");
    }
    for key in ["trees_in_view", "trees_laser_seen", "tree_recall", "trees_mapped", "posts", "palms", "people", "walls"]
    {
        assert!(metrics["map"].get(key).is_some(), "metrics.json map lacks {key}");
    }
    assert_eq!(metrics["seed"], 3);
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("metadata.json")).unwrap()).unwrap();
    assert_eq!(meta["configuration"]["seed"], 3);
    assert!(meta["configuration"]["world"]["objects"].is_array());
    // The simulator as it ran: no camera for a position-only method, so no renderer.
    assert_eq!(meta["configuration"]["sim"]["camera"]["enabled"], false);
    // The time limit the run ran under (the scenario's here; derived from the route where
    // none is set, `sim::Simulation::time_limit_s`).
    assert_eq!(meta["configuration"]["time_limit_s"], 20.0);
    assert!(
        meta.get("renderer").is_some_and(|r| r.is_null()) && meta.get("appearance_model").is_some_and(|r| r.is_null())
    );
    assert!(metrics.get("renderer").is_none() && m.renderer.is_none());
    let est = std::fs::read_to_string(dir.join("trajectory_est.tum")).unwrap();
    let gt = std::fs::read_to_string(dir.join("trajectory_gt.tum")).unwrap();
    assert_eq!(est.lines().count(), gt.lines().count());
    assert!(est.lines().filter(|l| !l.starts_with('#')).all(|l| l.split(' ').count() == 8));
    let img = image::open(dir.join("map.png")).unwrap();
    assert!(img.width() > 500);
    let decisions = std::fs::read_to_string(dir.join("decisions.jsonl")).unwrap();
    assert!(decisions.lines().count() >= m.associations.total);
    assert!(std::fs::metadata(dir.join("run.mcap")).unwrap().len() > 1000);
    // The list of what a run writes, which guards its inputs, names every output.
    for entry in std::fs::read_dir(&dir).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        assert!(
            name.starts_with('.') || scenarios::files::RUN_OUTPUTS.contains(&name.as_str()),
            "{name} is not in files::RUN_OUTPUTS"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// An input the run would replace or remove in its output directory (a calibration an
/// earlier run estimated there, reused; a world file) is refused before anything runs,
/// and stays as it was; one elsewhere in the directory is not in the way.
#[test]
fn an_input_among_the_run_outputs_is_refused_and_kept() {
    let dir = std::env::temp_dir().join(format!("objslam-input-in-outputs-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("mine")).unwrap();
    let (mut sc, base) = Scenario::load("laser_only").unwrap();
    sc.sim.max_duration_s = Some(2.0);
    let truth = scenarios::calibrate::true_extrinsics(&sc.sim);
    let calibration = serde_json::json!({"phi": truth.phi, "delta": truth.delta}).to_string();
    let options = RunOptions { out: Some(dir.clone()), ..Default::default() };
    for (key, name) in [("calibration", "calibration.json"), ("world", "world.toml")] {
        let mut sc = sc.clone();
        let file = dir.join(name);
        if key == "calibration" {
            std::fs::write(&file, &calibration).unwrap();
            sc.calibration.mode = file.to_string_lossy().into_owned();
        } else {
            worlds::save(&sc.world(&base, 1).unwrap(), &file).unwrap();
            (sc.world.preset, sc.world.seed) = (None, None);
            sc.world.file = Some(file.to_string_lossy().into_owned());
        }
        let before = std::fs::read(&file).unwrap();
        let e = run(&sc, &base, &options, |_| {}).err().expect("refused").to_string();
        assert!(e.contains(name) && e.contains(&format!("the {key}")) && e.contains("copy it elsewhere"), "{e}");
        assert_eq!(std::fs::read(&file).unwrap(), before, "{name} changed");
        assert!(!dir.join("metadata.json").exists(), "the run went ahead");
        // Under a name the run does not write, the same file is read and kept.
        let kept = dir.join("mine").join(name);
        std::fs::rename(&file, &kept).unwrap();
        if key == "calibration" {
            sc.calibration.mode = kept.to_string_lossy().into_owned();
        } else {
            sc.world.file = Some(kept.to_string_lossy().into_owned());
        }
        run(&sc, &base, &options, |_| {}).unwrap();
        assert_eq!(std::fs::read(&kept).unwrap(), before);
        // The run's outputs go, so that the next refusal is seen to write nothing.
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.file_name().is_some_and(|n| n != "mine") {
                if path.is_dir() { std::fs::remove_dir_all(&path) } else { std::fs::remove_file(&path) }.unwrap();
            }
        }
        // A link there to the file elsewhere would be removed all the same.
        #[cfg(unix)]
        {
            let link = dir.join(name);
            // The run just made wrote its own copy there (the world it simulated).
            let _ = std::fs::remove_file(&link);
            std::os::unix::fs::symlink(&kept, &link).unwrap();
            let mut sc = sc.clone();
            if key == "calibration" {
                sc.calibration.mode = link.to_string_lossy().into_owned();
            } else {
                sc.world.file = Some(link.to_string_lossy().into_owned());
            }
            let e = run(&sc, &base, &options, |_| {}).err().expect("refused").to_string();
            assert!(e.contains("copy it elsewhere"), "{e}");
            assert!(link.exists(), "the link was removed");
            std::fs::remove_file(&link).unwrap();
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A file that cannot be moved into place at a run's end (a directory stands there) is
/// named in the error, and when several cannot be, each is; nothing is moved then, so the
/// directory never holds a mix of two runs, and every output waits, whole, in
/// `.unfinished/`.
#[test]
fn an_output_that_cannot_be_written_is_named_and_the_others_are_kept() {
    let outputs = [
        "metrics.json",
        "world.toml",
        "sensors.json",
        "metadata.json",
        "trajectory_est.tum",
        "trajectory_est_covariance.csv",
        "trajectory_gt.tum",
        "decisions.jsonl",
        "landmarks.json",
        "map.png",
        "run.mcap",
    ];
    let (mut sc, base) = Scenario::load("laser_only").unwrap();
    sc.sim.max_duration_s = Some(10.0);
    for blocked in [&["metrics.json"][..], &["map.png"], &["run.mcap"], &["landmarks.json", "run.mcap"]] {
        let dir = std::env::temp_dir().join(format!("objslam-outputs-fault-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        // A directory where each blocked file should go, in the directory of an earlier run.
        for name in blocked {
            std::fs::create_dir_all(dir.join(name)).unwrap();
        }
        let earlier = r#"{"tool": "objslam run"}"#;
        std::fs::write(dir.join("metadata.json"), earlier).unwrap();
        let err = run(&sc, &base, &RunOptions { seed: Some(3), out: Some(dir.clone()), ..Default::default() }, |_| {})
            .err()
            .unwrap_or_else(|| panic!("{blocked:?} cannot be written"));
        let message = err.to_string();
        assert!(blocked.iter().all(|name| message.contains(name)), "{blocked:?}: {message}");
        for name in outputs {
            let kept = dir.join(".unfinished").join(name);
            assert!(std::fs::metadata(&kept).is_ok_and(|m| m.is_file() && m.len() > 0), "{name} lost");
            if name == "metadata.json" {
                let marker = std::fs::read_to_string(dir.join(name)).unwrap();
                assert_eq!(marker, earlier, "the earlier run's mark was replaced beside a blocked output");
            } else {
                assert!(blocked.contains(&name) || !dir.join(name).exists(), "{name} moved beside a blocked output");
            }
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// Files of a run's output names in a directory where no run was (no `metadata.json`) are
/// the user's own: refused before the run, and kept.
#[test]
fn files_of_a_runs_names_where_no_run_was_are_refused() {
    let dir = std::env::temp_dir().join(format!("objslam-unowned-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("objects")).unwrap();
    std::fs::write(dir.join("objects/keep.txt"), "my notes").unwrap();
    std::fs::write(dir.join("trees_shown.jsonl"), "mine").unwrap();
    let (mut sc, base) = Scenario::load("laser_only").unwrap();
    sc.sim.max_duration_s = Some(2.0);
    let options = RunOptions { out: Some(dir.clone()), ..Default::default() };
    let e = run(&sc, &base, &options, |_| {}).err().expect("refused").to_string();
    assert!(e.contains("it holds trees_shown.jsonl") && e.contains("no earlier run"), "{e}");
    assert_eq!(std::fs::read_to_string(dir.join("objects/keep.txt")).unwrap(), "my notes");
    assert_eq!(std::fs::read_to_string(dir.join("trees_shown.jsonl")).unwrap(), "mine");
    assert!(!dir.join("metadata.json").exists() && !dir.join(".unfinished").exists(), "the run went ahead");
    // A metadata.json another command (or a user) wrote marks no earlier run.
    std::fs::write(dir.join("metadata.json"), r#"{"tool": "objslam record"}"#).unwrap();
    let e = run(&sc, &base, &options, |_| {}).err().expect("refused").to_string();
    assert!(e.contains("written by `objslam record`, not by an objslam run"), "{e}");
    std::fs::write(dir.join("metadata.json"), r#"{"my": "data"}"#).unwrap();
    let e = run(&sc, &base, &options, |_| {}).err().expect("refused").to_string();
    assert!(e.contains("written by no objslam command"), "{e}");
    std::fs::write(dir.join("metadata.json"), "{\"tool\": \"objslam ru").unwrap();
    let e = run(&sc, &base, &options, |_| {}).err().expect("refused").to_string();
    assert!(e.contains("metadata.json: it cannot be read (not JSON: EOF"), "{e}");
    assert_eq!(std::fs::read_to_string(dir.join("trees_shown.jsonl")).unwrap(), "mine");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A mesh file the world reads, kept among an earlier run's outputs (its `objects/`), is
/// refused: the run would remove it and could not be repeated.
#[test]
fn a_mesh_file_among_the_outputs_is_refused() {
    let dir = std::env::temp_dir().join(format!("objslam-mesh-in-outputs-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = dir.join("out");
    std::fs::create_dir_all(out.join("objects")).unwrap();
    std::fs::write(out.join("metadata.json"), r#"{"tool": "objslam run"}"#).unwrap();
    let mut world = worlds::generate::park(&Default::default(), 1).unwrap();
    let post = world.objects.iter_mut().find(|o| o.class == worlds::ObjectClass::Post).unwrap();
    let parts = worlds::mesh::object_parts(post);
    std::fs::write(out.join("objects/post.glb"), worlds::gltf_io::parts_to_glb(&parts)).unwrap();
    post.mesh = Some("out/objects/post.glb".into());
    std::fs::write(dir.join("w.toml"), world.to_toml()).unwrap();
    // A camera method whose model is missing: the mesh is refused first, as it would be
    // before a model is trained.
    let settings = "name = \"m\"\n[world]\nfile = \"w.toml\"\n[appearance]\nmodel = \"missing.json\"\n";
    std::fs::write(dir.join("s.toml"), settings).unwrap();
    let (mut sc, base) = Scenario::load(dir.join("s.toml").to_str().unwrap()).unwrap();
    sc.sim.max_duration_s = Some(2.0);
    let e = run(&sc, &base, &RunOptions { out: Some(out.clone()), ..Default::default() }, |_| {})
        .err()
        .expect("refused")
        .to_string();
    assert!(e.contains("post.glb: the mesh file lies among the outputs"), "{e}");
    assert!(out.join("objects/post.glb").is_file(), "the mesh is kept");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A bag in the run's own output directory is refused before anything is written (its
/// files would sit among the run's, and the next run could not write its bag).
#[test]
fn a_bag_in_the_runs_output_directory_is_refused() {
    let dir = std::env::temp_dir().join(format!("objslam-run-bag-out-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (mut sc, base) = Scenario::load("laser_only").unwrap();
    sc.sim.max_duration_s = Some(2.0);
    let same = RunOptions { out: Some(dir.clone()), bag: Some(dir.join(".")), ..Default::default() };
    let e = run(&sc, &base, &same, |_| {}).err().expect("refused").to_string();
    assert!(e.contains("--bag") && e.contains("output directory"), "{e}");
    assert!(!dir.exists(), "nothing written");
    // Nor the folder the run writes its outputs in first.
    let staged = RunOptions { out: Some(dir.clone()), bag: Some(dir.join(".unfinished/bag")), ..Default::default() };
    let e = run(&sc, &base, &staged, |_| {}).err().expect("refused").to_string();
    assert!(e.contains("--bag") && e.contains("where the run writes its outputs first"), "{e}");
    assert!(!dir.exists(), "nothing written");
    // The outputs inside a new bag directory: named as such, and nothing is left.
    let inside = RunOptions { out: Some(dir.join("run")), bag: Some(dir.clone()), ..Default::default() };
    let e = run(&sc, &base, &inside, |_| {}).err().expect("refused").to_string();
    assert!(e.contains("--out") && e.contains("lies inside the bag's directory"), "{e}");
    assert!(!dir.exists(), "nothing written");
    // A bag directory that holds a file: refused before the run sets up, the path said once.
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("notes.txt"), "mine").unwrap();
    let elsewhere = dir.with_extension("out");
    let taken = RunOptions { out: Some(elsewhere.clone()), bag: Some(dir.clone()), ..Default::default() };
    let e = run(&sc, &base, &taken, |_| {}).err().expect("refused").to_string();
    assert!(e.contains("bag directory exists and is not empty"), "{e}");
    assert_eq!(e.matches(&*dir.display().to_string()).count(), 1, "{e}");
    assert!(!elsewhere.exists(), "nothing written");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A run's bag is staged like `record --format ros2`'s: a bag directory holding only a
/// stopped recording's unfinished files takes the new bag, which appears whole; a finished
/// bag is never written over, and the run refused for it leaves it as it was.
#[test]
fn a_runs_bag_appears_only_whole_and_is_written_once() {
    let root = std::env::temp_dir().join(format!("objslam-run-bag-staged-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let (mut sc, base) = Scenario::load("laser_only").unwrap();
    sc.sim.max_duration_s = Some(2.0);
    let bag = root.join("bag");
    std::fs::create_dir_all(bag.join(".unfinished")).unwrap();
    std::fs::write(bag.join(".unfinished/bag_0.mcap"), b"half a bag").unwrap();
    let options = RunOptions { bag: Some(bag.clone()), ..Default::default() };
    run(&sc, &base, &options, |_| {}).unwrap();
    let mut names: Vec<String> =
        std::fs::read_dir(&bag).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    assert_eq!(names, ["bag_0.mcap", "metadata.yaml"]);
    let written = std::fs::read(bag.join("bag_0.mcap")).unwrap();
    assert!(written.len() > 1000, "{} bytes", written.len());
    let e = run(&sc, &base, &options, |_| {}).err().expect("a bag is written once").to_string();
    assert!(e.contains("bag"), "{e}");
    assert_eq!(std::fs::read(bag.join("bag_0.mcap")).unwrap(), written);
    assert!(!bag.join(".unfinished").exists());
    let _ = std::fs::remove_dir_all(&root);
}

/// `objslam run --bag` writes the run's own sensor stream as a ROS 2 bag: a scan message
/// per scan the pipeline took, whole camera frames, and the same metrics as without it.
#[test]
fn a_run_writes_its_sensor_stream_as_a_ros2_bag() {
    let dir = std::env::temp_dir().join(format!("objslam-run-bag-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (mut sc, base) = Scenario::load("paper_park").unwrap();
    sc.sim.max_duration_s = Some(6.0);
    let plain = run(&sc, &base, &RunOptions::default(), |_| {}).unwrap().metrics;
    let bagged =
        run(&sc, &base, &RunOptions { bag: Some(dir.join("bag")), ..Default::default() }, |_| {}).unwrap().metrics;
    assert_eq!(bagged.timing.rendered_fraction, 1.0, "a bag holds whole frames");
    let same =
        |m: &scenarios::run::Metrics| scenarios::run::Metrics { timing: Default::default(), ..m.without_wall_clock() };
    assert_eq!(same(&plain), same(&bagged));
    let metadata = std::fs::read_to_string(dir.join("bag/metadata.yaml")).unwrap();
    let count = |topic: &str| -> usize {
        let at = metadata.find(&format!("name: {topic}\n")).unwrap_or_else(|| panic!("{topic} missing: {metadata}"));
        let rest = &metadata[at..];
        let line = rest.lines().find(|l| l.trim_start().starts_with("message_count:")).unwrap();
        line.split(':').nth(1).unwrap().trim().parse().unwrap()
    };
    assert_eq!(count("/scan"), bagged.timing.scans);
    assert!(count("/camera/image_raw") >= 30 && count("/odom") >= 120, "{metadata}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn combined_method_runs_end_to_end_with_camera_segmentation() {
    // The paper's method on the first 40 s of paper_park: the appearance model is trained
    // from generated images (and cached), images are segmented, and only camera-confirmed
    // objects are observed.
    let (mut sc, base) = Scenario::load("paper_park").unwrap();
    sc.sim.max_duration_s = Some(40.0);
    let out = std::env::temp_dir().join(format!("objslam-combined-{}", std::process::id()));
    let m = run(&sc, &base, &RunOptions { out: Some(out.clone()), ..Default::default() }, |_| {}).unwrap().metrics;
    assert_eq!(m.method, "combined");
    let (p, r) = (m.segmentation.precision.expect("scored"), m.segmentation.recall.expect("scored"));
    assert!(p > 0.5 && r > 0.7, "segmentation precision {p}, recall {r}");
    assert!(m.associations.total > 20, "{:?}", m.associations);
    assert_eq!(m.associations.wrong, 0);
    assert!(m.map.trees_mapped >= 1, "{:?}", m.map);
    // Every association decision carries KL scores for its candidates.
    let decisions = std::fs::read_to_string(out.join("decisions.jsonl")).unwrap();
    let with_kl = decisions.lines().filter(|l| l.contains("\"kl\":") && !l.contains("\"kl\":null")).count();
    assert!(with_kl > 0);
    // Every segmented cluster's decision is logged with its ground truth.
    let seg = std::fs::read_to_string(out.join("segmentation.jsonl")).unwrap();
    let lines: Vec<serde_json::Value> = seg.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert!(lines.iter().any(|l| l["is_object"] == true && l["true_class"] == "tree"));
    assert!(lines.iter().all(|l| l["hit_fraction"].is_f64() && l["above_fraction"].is_f64()));
    // The renderer that made the images is recorded: results depend on it.
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metadata.json")).unwrap()).unwrap();
    assert!(meta["renderer"].as_str().is_some_and(|r| !r.is_empty()), "{}", meta["renderer"]);
    assert_eq!(
        m.renderer.as_deref(),
        meta["renderer"].as_str(),
        "metrics.json and metadata.json name the same renderer"
    );
    assert!(meta["appearance_model"].get("training_renderer").is_some());
    // The mapped objects' models and pictures: a picture for each of some modelled
    // landmarks, none for a landmark without a model, and the appearance model beside them.
    let models: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("objects/models.json")).unwrap()).unwrap();
    let modelled: Vec<u64> = models["objects"].as_array().unwrap().iter().map(|o| o[0].as_u64().unwrap()).collect();
    assert!(!modelled.is_empty() && models["format_version"] == 1, "{models}");
    let pictures: Vec<u64> = std::fs::read_dir(out.join("objects"))
        .unwrap()
        .filter_map(|e| {
            let name = e.unwrap().file_name().into_string().unwrap();
            name.strip_prefix("landmark_")?.strip_suffix(".png")?.parse().ok()
        })
        .collect();
    assert!(!pictures.is_empty() && pictures.iter().all(|id| modelled.contains(id)), "{pictures:?} {modelled:?}");
    let picture = image::open(out.join(format!("objects/landmark_{}.png", pictures[0]))).unwrap();
    assert!(picture.width() > 0 && picture.height() > 48, "a caption and a picture");
    slam::classifier::AppearanceModel::load(&out.join("objects/appearance_model.json")).unwrap();
    let _ = std::fs::remove_dir_all(&out);
}

/// Every pass criterion but the tree recall holds, and the recall is at least `floor`.
///
/// Against ground-truth denominators the camera methods miss trees the camera had in view
/// (docs/results.md, "Honest recall"), so the scenarios' recall criteria fail; the floor,
/// the recall measured when the denominators changed, catches a regression meanwhile.
fn passes_all_but_recall(m: &scenarios::run::Metrics, floor: f64) {
    let others: Vec<&String> = m.failures.iter().filter(|f| !f.starts_with("tree recall")).collect();
    assert!(others.is_empty(), "{others:?}");
    assert!(m.map.tree_recall.is_some_and(|r| r >= floor), "recall below {floor}: {:?}", m.map);
}

/// Guards the paper's claim on its own experiment, the whole default run: only trees are
/// mapped (no post, palm, wall or person), each once, and no association is wrong.
#[test]
fn paper_park_maps_only_trees_each_once_with_no_wrong_association() {
    let m = run_named("paper_park", None, None);
    passes_all_but_recall(&m, 0.8);
    assert_eq!((m.map.posts, m.map.palms, m.map.people, m.map.walls, m.map.nothing), (0, 0, 0, 0, 0), "{:?}", m.map);
    assert!(m.map.trees_in_view.is_some_and(|n| n >= 6), "{:?}", m.map);
    assert_eq!((m.associations.wrong, m.duplicate_landmarks), (0, 0));
    assert!(m.route_completed);
}

/// Runs job `index` of the generalisation benchmark's `combined` (0) or `jcbb` (1) study
/// on the test split, as the benchmark runs it.
fn generalisation_job(study: usize, index: usize) -> scenarios::run::Metrics {
    generalisation_job_with(study, index, 1, |_| {})
}

/// [`generalisation_job`] among the benchmark's first `worlds` worlds, with the scenario
/// changed by `edit` first.
fn generalisation_job_with(
    study: usize,
    index: usize,
    worlds: usize,
    edit: impl FnOnce(&mut Scenario),
) -> scenarios::run::Metrics {
    use scenarios::montecarlo::{generalisation, job_scenario, jobs};
    let plans = generalisation::plans(generalisation::Split::Test, worlds, 1).unwrap();
    let job = &jobs(&plans[study].1)[index];
    let (base_scenario, base) = Scenario::load(generalisation::BASE_SCENARIO).unwrap();
    let mut sc = job_scenario(&base_scenario, job).unwrap();
    edit(&mut sc);
    let method = slam::association::AssociationMethod::from_name(&job.method);
    run(&sc, &base, &RunOptions { seed: Some(job.seed), method, ..Default::default() }, |_| {}).unwrap().metrics
}

/// Guards the measured level on a world nobody tuned on: world 0 of the generalisation
/// benchmark's test split (385 s, 21 trees in view), trained model seed 1, recorded
/// 2026-12-02 with recall 0.76 and no false landmark. The paper's claim (recall 0.95) does
/// not hold there yet (docs/results.md#generalisation); what holds must keep holding, and
/// jcbb on the same world must show the failure the paper argues against.
#[test]
fn a_test_split_world_keeps_its_measured_level() {
    let m = generalisation_job(0, 0);
    assert_eq!((m.associations.wrong, m.duplicate_landmarks, m.false_landmarks), (0, 0, 0), "{:?}", m.map);
    assert!(m.map.trees_in_view.is_some_and(|n| n >= 15), "{:?}", m.map);
    assert!(m.map.tree_recall.is_some_and(|r| r >= 0.7), "{:?}", m.map);
    let jcbb = generalisation_job(1, 0);
    assert!(jcbb.map.posts + jcbb.map.people >= 1, "{:?}", jcbb.map);
    assert_eq!(jcbb.map.tree_recall, Some(1.0), "{:?}", jcbb.map);
}

/// Guards the foliage in the band test on a world of short trees nobody tuned on: world 4
/// of the generalisation benchmark's test split (trees 3.1-4.2 m tall, whose canopies come
/// down into the band), trained model seed 1. Recorded 2026-12-02: 12 of 30 trees in view
/// mapped counting the band's leaves, 9 of 30 without, no false landmark either way.
#[test]
fn short_trees_are_judged_by_the_leaves_on_their_trunks() {
    // Jobs are world-major, 5 training seeds each: job 20 is world 4 with seed 1.
    let job = |counts_foliage: bool| {
        generalisation_job_with(0, 20, 5, |sc| sc.pipeline.segmentation.band_counts_foliage = counts_foliage)
    };
    let with = job(true);
    let without = job(false);
    for m in [&with, &without] {
        assert_eq!((m.associations.wrong, m.duplicate_landmarks, m.false_landmarks), (0, 0, 0), "{:?}", m.map);
        assert_eq!(m.map.trees_in_view, Some(30), "{:?}", m.map);
    }
    assert!(with.map.trees_mapped >= 11, "{:?}", with.map);
    assert!(without.map.trees_mapped + 2 <= with.map.trees_mapped, "{:?} against {:?}", without.map, with.map);
}

/// Guards the pooled tree-versus-post evidence: posts half a metre to a metre from trees,
/// whose laser patches look like bark, stay out of the map while every tree goes in.
#[test]
fn posts_near_trees_keeps_posts_out_of_the_map() {
    let m = run_named("posts_near_trees", None, None);
    assert!(m.passed, "{:?}", m.failures);
    assert_eq!((m.map.posts, m.map.palms, m.map.people), (0, 0, 0), "{:?}", m.map);
    assert_eq!(m.associations.wrong, 0);
    assert!(m.map.trees_in_view.is_some_and(|n| n >= 8), "{:?}", m.map);
}

/// Guards against people becoming landmarks when many walk between the robot and the trees.
#[test]
fn crowd_maps_no_person_and_no_wrong_association() {
    let m = run_named("crowd", None, None);
    passes_all_but_recall(&m, 0.87);
    assert_eq!((m.map.people, m.map.posts, m.map.palms), (0, 0, 0), "{:?}", m.map);
    assert_eq!(m.associations.wrong, 0);
    assert!(m.map.trees_in_view.is_some_and(|n| n >= 5), "{:?}", m.map);
}

/// Guards loop closing after a long drift (trunk diameters, deferral beside look-alikes,
/// joint loop closing, relinearising after it) and the retraction of palms accepted from far: the robot returns
/// 2 m off to its first trees, beside which a tree and a palm stand like them shifted by
/// 3.8 m.
#[test]
fn long_loop_closes_its_loop_without_wrong_associations_or_duplicates() {
    let m = run_named("long_loop", None, None);
    passes_all_but_recall(&m, 0.85);
    assert_eq!(m.associations.wrong, 0);
    assert!(m.duplicate_landmarks <= 1, "{} duplicates: the loop did not close", m.duplicate_landmarks);
    // Closed, the second lap re-observes the first lap's trees: about 1950 associations;
    // without closing, about 950.
    assert!(m.associations.total > 1500, "{:?}", m.associations);
    assert_eq!((m.map.posts, m.map.palms, m.map.people, m.map.walls), (0, 0, 0, 0), "{:?}", m.map);
    assert!(m.retracted_landmarks.total >= 1 && m.retracted_landmarks.trees == 0, "{:?}", m.retracted_landmarks);
    assert!(m.ate_rmse_m < 1.2, "ATE {}", m.ate_rmse_m);
    assert!(m.route_completed);
    // The closure relinearises the filter, which puts the first lap's trees where the
    // closure says they are: landmark RMSE 0.147 m (0.203 m without).
    assert!(
        m.relinearisations >= 1 && m.relinearisation_failures == 0,
        "relinearised {} times, {} failed",
        m.relinearisations,
        m.relinearisation_failures
    );
    assert!(m.landmark_rmse_m.is_some_and(|r| r < 0.18), "landmark RMSE {:?}", m.landmark_rmse_m);
}

/// Regression: the first relinearisation started from the map the loop closure had just
/// corrected while the recorded poses still agreed with the old one; from there the solver
/// ended in another minimum with two first-lap trees 7 m off, and the second lap started
/// 7 duplicates. Started from the map the poses agree with, it converges in 5 iterations
/// and the run passes. (A Monte Carlo seed of `long_loop`; cut after the second lap's
/// first duplicates would have come.)
#[test]
fn long_loop_relinearises_from_the_map_its_poses_agree_with() {
    let m = run_named("long_loop", Some(6734981651720448964), Some(300.0));
    assert!(
        m.relinearisations >= 1 && m.relinearisation_failures == 0,
        "relinearised {} times, {} failed",
        m.relinearisations,
        m.relinearisation_failures
    );
    assert_eq!(m.duplicate_landmarks, 0, "{:?}", m.failures);
    assert_eq!(m.associations.wrong, 0);
    assert!(m.landmark_rmse_m.is_some_and(|r| r < 0.3), "landmark RMSE {:?}", m.landmark_rmse_m);
}

/// `relinearise_every_s` relinearises on schedule, before any loop closes.
#[test]
fn relinearising_every_30_s_happens_on_schedule() {
    let (mut sc, base) = Scenario::load("long_loop").unwrap();
    sc.sim.max_duration_s = Some(100.0);
    sc.pipeline.relinearise_every_s = Some(30.0);
    let out = std::env::temp_dir().join(format!("objslam-relinearise-{}", std::process::id()));
    let m = run(&sc, &base, &RunOptions { out: Some(out.clone()), ..Default::default() }, |_| {}).unwrap().metrics;
    assert_eq!((m.relinearisations, m.relinearisation_failures), (3, 0), "at 30, 60 and 90 s");
    assert_eq!(m.associations.wrong, 0);
    // Each solve is written out: when, what it solved, and a cost that did not rise.
    let solves: Vec<serde_json::Value> = std::fs::read_to_string(out.join("relinearisations.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let times: Vec<f64> = solves.iter().map(|v| v["t"].as_f64().unwrap()).collect();
    assert!(
        times.len() == 3 && times.iter().zip([30.0, 60.0, 90.0]).all(|(t, due)| (t - due).abs() < 0.2),
        "{times:?}"
    );
    for v in &solves {
        assert!(
            v["poses"].as_u64().unwrap() > 10
                && v["landmarks"].as_u64().unwrap() > 0
                && v["iterations"].as_u64().unwrap() >= 1,
            "{v}"
        );
        assert!(v["final_cost"].as_f64().unwrap() <= v["initial_cost"].as_f64().unwrap(), "{v}");
    }
    let _ = std::fs::remove_dir_all(&out);
}

/// The smoother and the scheduled solves give the same run on one thread and on four: the
/// first 100 s of long_loop relinearised every 30 s.
#[test]
fn relinearising_runs_are_identical_whatever_the_thread_count() {
    let dir = std::env::temp_dir().join(format!("objslam-relinearise-threads-{}", std::process::id()));
    let (mut sc, base) = Scenario::load("long_loop").unwrap();
    sc.sim.max_duration_s = Some(100.0);
    sc.pipeline.relinearise_every_s = Some(30.0);
    let on = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| run_and_read(&sc, &base, RunOptions::default(), &dir.join(format!("threads{threads}"))))
    };
    let (one, four) = (on(1), on(4));
    assert_eq!(one.0.relinearisations, 3);
    assert_same_run(&one, &four);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn camera_methods_without_a_camera_fail_clearly() {
    let (mut sc, base) = Scenario::load("paper_park").unwrap();
    sc.sim.camera.enabled = false;
    let err = run(&sc, &base, &RunOptions::default(), |_| {}).err().expect("combined needs the camera").to_string();
    assert!(err.contains("combined") && err.contains("sim.camera.enabled") && err.contains("paper_park"), "{err}");
}

/// Nonsense pipeline settings are errors when the scenario is read, naming the file, the
/// line and the setting: none is silently clamped or turned into an empty map.
#[test]
fn nonsense_pipeline_settings_are_named_with_their_line() {
    let bad = [
        ("evidence", "radius_m = -1.0"),
        ("motion", "bias_sigma_rad_per_m = -0.002"),
        ("merge", "max_sigma_m = 0.0"),
        ("diameter", "max_sigmas = -3.0"),
        ("evidence", "retract_range_m = -1.0"),
        ("clustering", "max_range_m = -1.0"),
        ("clustering", "min_points = 0"),
        ("sensor", "range_sigma_m = 0.0"),
        ("segmentation", "above_band_m = 1.0"),
        ("object_model", "components = 1000"),
    ];
    for (table, field) in bad {
        let text = format!("name = \"x\"\n[world]\npreset = \"park\"\n[pipeline.{table}]\n{field}\n");
        let e = Scenario::parse(&text, std::path::Path::new("x.toml")).unwrap_err().to_string();
        let name = field.split(' ').next().unwrap();
        assert!(e.contains("x.toml: line 5:") && e.contains(&format!("pipeline.{table}.{name}")), "{e}");
    }
    for field in [
        "relinearise_every_s = 0.0",
        "gate_probability = 1.5",
        "gate_probability = 1.0",
        "gate_probability = nan",
        "image_max_age_s = -1.0",
        "confirm_observations = 0",
        "initial_pose_sigma = [0.001, nan, 0.001]",
    ] {
        let text = format!("name = \"x\"\n[world]\npreset = \"park\"\n[pipeline]\n{field}\n");
        let e = Scenario::parse(&text, std::path::Path::new("x.toml")).unwrap_err().to_string();
        let name = field.split(' ').next().unwrap();
        assert!(e.contains("x.toml: line 5:") && e.contains(&format!("pipeline.{name}")), "{field}: {e}");
    }
    // Turning first estimates off alone, as files written before observability_constrained
    // did, stays valid although the constraint's default is on.
    let text = "name = \"x\"\n[world]\npreset = \"park\"\n[pipeline]\nfirst_estimate_jacobians = false\n";
    let sc = Scenario::parse(text, std::path::Path::new("x.toml")).unwrap();
    assert!(!sc.pipeline.first_estimate_jacobians && sc.pipeline.observability_constrained);
    // The free-space test of joint closures acts only on joint closures.
    let text = "name = \"x\"\n[world]\npreset = \"park\"\n[pipeline]\njoint_loop_closing = false\njoint_loop_free_space = true\n";
    let e = Scenario::parse(text, std::path::Path::new("x.toml")).unwrap_err().to_string();
    assert!(e.contains("x.toml: line 6:") && e.contains("pipeline.joint_loop_free_space"), "{e}");
    // Unknown keys, in every table, are errors with their line.
    for table in ["pipeline", "pipeline.evidence", "pipeline.clustering", "pipeline.sensor"] {
        let text = format!("name = \"x\"\n[world]\npreset = \"park\"\n[{table}]\nradius = 1.0\n");
        let e = Scenario::parse(&text, std::path::Path::new("x.toml")).unwrap_err().to_string();
        assert!(e.contains("radius") && e.contains("line 5"), "{table}: {e}");
    }
    // Settings changed in code are checked again before a run.
    let (mut sc, _) = Scenario::load("paper_park").unwrap();
    sc.pipeline.confirm_observations = 0;
    let e = scenarios::run::pipeline_config(&sc, None).unwrap_err().to_string();
    assert!(e.contains("paper_park") && e.contains("pipeline.confirm_observations"), "{e}");
}

/// A camera run's object pictures are readable: each mapped object's patches as the camera
/// saw them (bark brown: more red than green) beside their PCA reconstruction, enlarged,
/// under a caption.
#[test]
fn object_pictures_show_the_patches_as_seen_beside_their_reconstruction() {
    let dir = std::env::temp_dir().join(format!("objslam-objects-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (mut sc, base) = Scenario::load("paper_park").unwrap();
    sc.sim.max_duration_s = Some(30.0);
    let m = run(&sc, &base, &RunOptions { seed: Some(2), out: Some(dir.clone()), ..Default::default() }, |_| {})
        .unwrap()
        .metrics;
    assert!(m.landmarks >= 1, "{:?}", m.map);
    let pictures: Vec<_> = std::fs::read_dir(dir.join("objects"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    assert_eq!(pictures.len(), m.landmarks);
    for p in pictures {
        let img = image::open(&p).unwrap().to_rgb8();
        assert!(img.width() >= 320 && img.height() > 100, "{}: {:?}", p.display(), img.dimensions());
        // The left panel (as seen), below the caption: the bark's mean colour.
        let (mut sum, mut n) = ([0.0f64; 3], 0.0);
        for y in 60..img.height() - 12 {
            for x in 12..img.width() / 2 - 12 {
                let px = img.get_pixel(x, y).0;
                let grid_or_empty = px == [40, 40, 40] || px == [0, 0, 0] || px == [255, 255, 255];
                if !grid_or_empty {
                    for c in 0..3 {
                        sum[c] += px[c] as f64;
                    }
                    n += 1.0;
                }
            }
        }
        assert!(n > 100.0 && sum[0] > sum[1], "{}: mean colour {:?}", p.display(), sum.map(|s| s / n));
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A file a scenario names that cannot be read is reported with the scenario and the key
/// that named it.
#[test]
fn a_missing_file_a_scenario_names_is_reported_with_its_key() {
    let (mut sc, base) = Scenario::load("paper_park").unwrap();
    sc.appearance.model = Some("nowhere_model.json".into());
    let e = run(&sc, &base, &RunOptions::default(), |_| {}).err().expect("refused").to_string();
    assert!(e.starts_with("<built-in>/paper_park.toml: appearance.model: ") && e.contains("nowhere_model.json"), "{e}");
    let (mut sc, base) = Scenario::load("laser_only").unwrap();
    sc.calibration.mode = "nowhere_calibration.json".into();
    let e = run(&sc, &base, &RunOptions::default(), |_| {}).err().expect("refused").to_string();
    assert!(
        e.starts_with("<built-in>/laser_only.toml: calibration: ") && e.contains("nowhere_calibration.json"),
        "{e}"
    );
}
