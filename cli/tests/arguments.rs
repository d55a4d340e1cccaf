//! Bad command-line values get an error naming the flag and the value, never clap's
//! "unexpected argument" for a negative number or a run that starts anyway.

use std::process::Command;

fn stderr_of(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_objslam")).args(args).output().expect("objslam runs");
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn negative_numbers_are_values_checked_like_any_other() {
    let out = std::env::temp_dir().join(format!("objslam-negative-{}", std::process::id()));
    let a_file = std::env::temp_dir().join(format!("objslam-a-file-{}", std::process::id()));
    std::fs::write(&a_file, "").unwrap();
    let under_a_file = a_file.join("c.json").to_str().expect("a UTF-8 temporary path").to_string();
    let out = out.to_str().expect("a UTF-8 temporary path");
    for (args, expect) in [
        (
            vec!["record", "park", "--duration", "-5", "--out", out],
            "--duration must be a positive number of seconds, not -5",
        ),
        (vec!["train", "--dataset", out, "--out", out, "--threshold", "-1"], "--threshold must lie in [0, 1], got -1"),
        // A report of nothing was written as `[]`.
        (
            vec!["train", "--dataset", out, "--out", out, "--heldout-report", out],
            "the following required arguments were not provided:\n  --heldout-dataset <HELDOUT_DATASET>",
        ),
        (vec!["run", "--seed", "-1"], "invalid value '-1' for '--seed <SEED>'"),
        // A scenario's name where a world goes: the error says how to give one.
        (vec!["record", "paper_park", "--out", out], "paper_park is a scenario, not a world file or a preset (park"),
        (vec!["record", "forest", "--out", out], "forest: no such world file, and not a preset (park"),
        // Settings of how a study runs, where no study runs.
        (vec!["montecarlo", "merge", out, "--out", out, "--jobs", "3"], "--jobs says how a study's runs are run"),
        (vec!["montecarlo", "rerun", out, "--job", "0", "--out", out, "--in-process"], "--in-process says how"),
        (vec!["montecarlo", "laser_only", "--in-process", "--run-timeout", "60", "--out", out], "--run-timeout limits"),
        // Ignored before, even 0 (the bad method only stops the study that would have run).
        (
            vec!["montecarlo", "laser_only", "--in-process", "--jobs", "0", "--methods", "bogus", "--out", out],
            "--jobs counts worker processes, and --in-process runs on this process's threads",
        ),
        (vec!["montecarlo", "laser_only", "--runs", "-3"], "invalid value '-3' for '--runs <RUNS>'"),
        (vec!["run", "--method", "bogus"], "invalid value 'bogus' for '--method <METHOD>'"),
        (vec!["calibrate", "calibration", "--poses", "0", "--out", out], "--poses 0: must be 5..10000"),
        (
            vec!["calibrate", "calibration", "--poses", "4", "--out", out],
            "--poses 4: must be 5..10000 (a calibration needs at least 5",
        ),
        // Refused under the scenario's station_spacing_m before, a key the user never gave.
        (
            vec!["calibrate", "calibration", "--poses", "400", "--out", out],
            "--poses 400: the stations would stand in a line 4788 m long",
        ),
        (vec!["calibrate", "calibration", "--out", &under_a_file], "is a file, not a directory"),
        (
            vec!["calibrate", "calibration", "--out", "c9.json", "--images", "./c9.json"],
            "--out c9.json and --images ./c9.json: one path",
        ),
        (
            vec!["dataset", "--images", "1", "--classes", "tree,person", "--out", out],
            "--classes: \"person\" is not aimed at",
        ),
        (vec!["dataset", "--images", "1", "--classes", "oak", "--out", out], "--classes: unknown class \"oak\""),
        (vec!["montecarlo", "laser_only", "--methods", "nn, bogus", "--out", out], "unknown method \"bogus\""),
        (vec!["montecarlo", "rerun", out, "--job", "-1", "--out", out], "study.json"),
        // Ignored without a word before: --fixed-k does not search.
        (
            vec!["gmm", "fit", out, "--fixed-k", "--search", "grow", "--out", out],
            "'--fixed-k' cannot be used with '--search <SEARCH>'",
        ),
        // Dropped without a word before: --shard gives its own count.
        (
            vec!["montecarlo", "laser_only", "--shard", "0/2", "--shard-count", "3", "--out", out],
            "'--shard <SHARD>' cannot be used with '--shard-count <SHARD_COUNT>'",
        ),
    ] {
        let (ok, err) = stderr_of(&args);
        assert!(!ok, "{args:?} succeeded");
        assert!(err.contains(expect), "{args:?}: {err}");
        assert!(!err.contains("unexpected argument"), "{args:?}: {err}");
    }
    let _ = std::fs::remove_file(&a_file);
    assert!(!std::path::Path::new(out).exists(), "nothing was written");
}

#[test]
fn settings_files_given_on_the_command_line_are_checked_naming_file_line_and_field() {
    let dir = std::env::temp_dir().join(format!("objslam-settings-files-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let sim = dir.join("sim.toml");
    std::fs::write(&sim, "physics_rate_hz = 100.0\n[laser]\nrate_hz = -3.0\n").unwrap();
    let params = dir.join("params.toml");
    std::fs::write(&params, "trees = 3\n\ntree_radius_m = [0.5, 0.1]\n").unwrap();
    let out = dir.join("out");
    let (sim_s, params_s, out_s) = (sim.to_str().unwrap(), params.to_str().unwrap(), out.to_str().unwrap());
    for (args, expect) in [
        (vec!["record", "park", "--sim-config", sim_s, "--out", out_s], format!("{sim_s}: line 3: laser.rate_hz")),
        (vec!["world", "generate", "--params", params_s], format!("{params_s}: line 3: tree_radius_m")),
    ] {
        let (ok, err) = stderr_of(&args);
        assert!(!ok, "{args:?} succeeded");
        assert!(err.contains(&expect), "{args:?}: {err}");
    }
    assert!(!out.exists(), "nothing was recorded");
    // A scenario's check names the scenario where the problem is a file or setting it
    // names, and once where the message names it already.
    let scenario = dir.join("modelled.toml");
    std::fs::write(
        &scenario,
        "name = \"modelled\"\n[world]\npreset = \"park\"\n[appearance]\nmodel = \"nosuch.json\"\n",
    )
    .unwrap();
    let (ok, err) = stderr_of(&["config", "check", scenario.to_str().unwrap()]);
    assert!(!ok && err.contains(&format!("{}: ", scenario.display())) && err.contains("nosuch.json"), "{err}");
    std::fs::write(&scenario, "name = \"modelled\"\n[world]\npreset = \"park\"\n[pipeline]\ngate_probability = 2.0\n")
        .unwrap();
    let (ok, err) = stderr_of(&["config", "check", scenario.to_str().unwrap()]);
    assert!(!ok && err.matches("modelled.toml").count() == 1, "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_scenarios_log_carries_its_camera_unless_told_not_to_and_camera_replays_need_a_model() {
    let dir = std::env::temp_dir().join(format!("objslam-camera-log-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (with, without) = (dir.join("with"), dir.join("without"));
    let record = |out: &std::path::Path, extra: &[&str]| {
        let out = out.to_str().expect("a UTF-8 temporary path");
        let mut args = vec!["record", "--scenario", "paper_park", "--format", "log", "--duration", "1", "--out", out];
        args.extend(extra);
        let (ok, err) = stderr_of(&args);
        assert!(ok, "{args:?}: {err}");
    };
    record(&with, &[]);
    record(&without, &["--no-camera"]);
    assert!(with.join("camera.csv").is_file() && with.join("camera/000000.png").is_file());
    assert!(!without.join("camera.csv").exists() && !without.join("camera").exists());
    // paper_park's method is combined: its log replays with it, with the model its run
    // uses, which the recording put beside the log.
    assert!(with.join("appearance_model.json").is_file() && !without.join("appearance_model.json").exists());
    let replay_out = dir.join("replay");
    let (ok, err) = stderr_of(&["replay", with.to_str().unwrap(), "--out", replay_out.to_str().unwrap()]);
    assert!(ok, "{err}");
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(replay_out.join("metrics.json")).unwrap()).unwrap();
    // 1 s of the camera at 5 Hz: frames at 0, 0.2, ..., 1.0 s.
    assert_eq!((metrics["method"].as_str(), metrics["camera_frames"].as_u64()), (Some("combined"), Some(6)));
    // Without it, a camera method needs one named.
    std::fs::remove_file(with.join("appearance_model.json")).unwrap();
    let (ok, err) = stderr_of(&["replay", with.to_str().unwrap(), "--out", replay_out.to_str().unwrap()]);
    assert!(!ok && err.contains("--appearance-model FILE"), "{err}");
    let (ok, err) = stderr_of(&["replay", without.to_str().unwrap(), "--out", replay_out.to_str().unwrap()]);
    assert!(!ok && err.contains("the log has no camera") && err.contains("--method nn"), "{err}");
    let missing = dir.join("no-model.json");
    let (ok, err) = stderr_of(&[
        "replay",
        with.to_str().unwrap(),
        "--appearance-model",
        missing.to_str().unwrap(),
        "--out",
        replay_out.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("no-model.json"), "{err}");
    let (ok, err) =
        stderr_of(&["replay", with.to_str().unwrap(), "--method", "nn", "--out", replay_out.to_str().unwrap()]);
    assert!(ok, "{err}");
    // Recording again into the same directory leaves nothing of the earlier log's camera.
    record(&with, &[]);
    assert!(with.join("appearance_model.json").is_file());
    record(&with, &["--no-camera"]);
    for gone in ["camera.csv", "camera", "appearance_model.json"] {
        assert!(!with.join(gone).exists(), "{gone} left behind");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// A log of the wrong kind, or a file where a log directory goes, is named for what it is.
#[test]
fn a_log_of_another_kind_is_named_for_what_it_is() {
    let root = std::env::temp_dir().join(format!("objslam-log-kinds-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    for (dir, file) in [("jsonl", "metadata.json"), ("bag", "metadata.yaml")] {
        std::fs::create_dir_all(root.join(dir)).unwrap();
        std::fs::write(root.join(dir).join(file), "").unwrap();
    }
    std::fs::write(root.join("a.tum"), "").unwrap();
    let p = |name: &str| root.join(name).to_str().expect("a UTF-8 temporary path").to_string();
    let out = p("out");
    for (args, expect) in [
        (vec!["replay".to_string(), p("jsonl"), "--out".into(), out.clone()], "a JSON-lines log of `objslam record`"),
        (
            vec!["replay".into(), p("bag"), "--out".into(), out.clone()],
            "a ROS 2 bag; `objslam replay` reads a robot log",
        ),
        (vec!["replay".into(), p("a.tum"), "--out".into(), out.clone()], "a.tum: not a directory"),
        (vec!["replay".into(), p("nowhere"), "--out".into(), out.clone()], "nowhere: no such directory"),
        (
            vec!["replay".into(), "victoria-park".into(), "--data".into(), p("nowhere"), "--out".into(), out.clone()],
            "nowhere: no such directory: give the directory that holds the data set's files",
        ),
        (
            vec![
                "replay".into(),
                "victoria-park".into(),
                "--data".into(),
                p("a.tum"),
                "--method".into(),
                "combined".into(),
                "--out".into(),
                out.clone(),
            ],
            "invalid value 'combined' for '--method <METHOD>'",
        ),
        (
            vec![
                "score".into(),
                "--log".into(),
                p("a.tum"),
                "--trajectory".into(),
                p("a.tum"),
                "--out".into(),
                out.clone(),
            ],
            "a.tum: not a directory: `--log` takes the directory",
        ),
    ] {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let (ok, e) = stderr_of(&args);
        assert!(!ok && e.contains(expect), "{args:?}: {e}");
    }
    assert!(!root.join("out").exists());
    let _ = std::fs::remove_dir_all(&root);
}

/// A published data set file cut short makes the parser, a third-party crate, panic: the
/// user reads one clean error naming the file, and no crash report above it.
#[test]
fn a_cut_mat_file_is_an_error_without_a_crash_report() {
    let root = std::env::temp_dir().join(format!("objslam-cut-mat-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let data = root.join("vp");
    std::fs::create_dir_all(&data).unwrap();
    // A level-5 MAT-file header (116 bytes of text, subsystem offset, version 0x0100,
    // little-endian), then a matrix element whose tag promises 1000 bytes and holds 8.
    let mut header = b"MATLAB 5.0 MAT-file, cut short".to_vec();
    header.resize(116, b' ');
    header.extend([0u8; 8]);
    header.extend([0x00, 0x01, b'I', b'M']);
    header.extend(14u32.to_le_bytes());
    header.extend(1000u32.to_le_bytes());
    header.extend([0u8; 8]);
    std::fs::write(data.join("aa3_dr.mat"), header).unwrap();
    std::fs::write(data.join("aa3_lsr2.mat"), b"").unwrap();
    let out = root.join("out");
    let args = ["replay", "victoria-park", "--data", data.to_str().unwrap(), "--out", out.to_str().unwrap()];
    let (ok, e) = stderr_of(&args);
    assert!(!ok && e.contains("aa3_dr.mat") && e.contains("not a readable MAT-file"), "{e}");
    assert!(!e.contains("panicked"), "{e}");
    let _ = std::fs::remove_dir_all(&root);
}

/// Output or messages into a pipe whose reader has gone end the program as the pipe's
/// signal would (141), not in a panic (101): `objslam config defaults | head -2`,
/// `objslam world check bad.toml 2>&1 >/dev/null | true`.
#[test]
fn a_closed_pipe_ends_the_program_quietly() {
    let closed = || {
        let (reader, writer) = std::io::pipe().expect("a pipe");
        drop(reader);
        writer
    };
    let objslam = || Command::new(env!("CARGO_BIN_EXE_objslam"));
    let printing =
        objslam().args(["config", "defaults"]).stdout(closed()).stderr(std::process::Stdio::piped()).output();
    let printing = printing.expect("objslam runs");
    assert_eq!(printing.status.code(), Some(141), "{}", String::from_utf8_lossy(&printing.stderr));
    let failing = objslam()
        .args(["world", "check", "no-such-world.toml"])
        .stdout(std::process::Stdio::null())
        .stderr(closed())
        .status()
        .expect("objslam runs");
    assert_eq!(failing.code(), Some(141));
}

/// A model trained on a dataset of posts is a model of posts: a run names the landmarks it
/// maps after the model's class (it had been saved as "tree" whatever the dataset held).
#[test]
fn a_model_is_of_the_classes_its_dataset_labelled() {
    let root = std::env::temp_dir().join(format!("objslam-post-model-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(&root).unwrap();
    let path = |name: &str| root.join(name).to_string_lossy().into_owned();
    let (data, model) = (path("posts"), path("posts.json"));
    let (ok, e) = stderr_of(&["dataset", "--images", "3", "--seed", "3", "--classes", "post", "--out", &data]);
    assert!(ok, "{e}");
    let train = ["train", "--dataset", &data, "--out", &model, "--pca-dims", "4", "--max-components", "2"];
    // The features' CSV is written beside its place and moved in whole.
    let features = path("features.csv");
    std::fs::write(&features, "earlier").unwrap();
    let (ok, e) = stderr_of(&[&train[..], &["--heldout-every", "0", "--export-features", &features]].concat());
    assert!(ok, "{e}");
    let saved: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&model).unwrap()).unwrap();
    assert_eq!(saved["object_class"], "post");
    let csv = std::fs::read_to_string(&features).unwrap();
    assert!(csv.starts_with("image,col,row,") && csv.lines().count() > 100, "{}", &csv[..csv.len().min(200)]);
    assert!(!root.join("features.csv.partial").exists());
    // A device is written into as it is (nothing can be made beside /dev/null), and a link
    // is followed, the file it names replaced and the link kept.
    let (ok, e) = stderr_of(&[&train[..], &["--heldout-every", "0", "--export-features", "/dev/null"]].concat());
    assert!(ok, "{e}");
    let link = root.join("link.csv");
    std::os::unix::fs::symlink(&features, &link).unwrap();
    std::fs::write(&features, "earlier").unwrap();
    let link_arg = link.to_string_lossy().into_owned();
    let (ok, e) = stderr_of(&[&train[..], &["--heldout-every", "0", "--export-features", &link_arg]].concat());
    assert!(ok, "{e}");
    assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink(), "the link is kept");
    assert!(std::fs::read_to_string(&features).unwrap().starts_with("image,col,row,"));
    let _ = std::fs::remove_dir_all(&root);
}
