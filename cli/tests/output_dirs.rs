//! Output directories as users meet them: one command writes into a directory at a time,
//! a stopped command leaves the earlier outputs whole, and a study's directory (not the
//! working directory) decides which scenario its jobs run.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn temp_root(name: &str) -> PathBuf {
    let root = std::env::temp_dir().join(format!("objslam-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(&root).unwrap();
    root
}

fn objslam(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_objslam")).current_dir(dir).args(args).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Every file under `dir` but the unfinished directory, with its bytes.
fn contents(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut found = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.file_name().is_some_and(|n| n == ".unfinished") {
                continue;
            }
            if path.is_dir() {
                todo.push(path);
            } else {
                found.push((path.strip_prefix(dir).unwrap().to_path_buf(), std::fs::read(&path).unwrap()));
            }
        }
    }
    found.sort();
    found
}

#[test]
fn a_directory_another_command_writes_into_is_refused() {
    let root = temp_root("held-out");
    let out = root.join("out");
    let held = scenarios::partial_files::lock_output(&out).unwrap();
    let out_arg = out.to_str().unwrap();
    for args in [
        vec!["run", "laser_only", "--out", out_arg],
        vec!["record", "park", "--duration", "1", "--no-camera", "--out", out_arg],
        vec!["record", "park", "--duration", "1", "--no-camera", "--format", "log", "--out", out_arg],
        vec!["record", "park", "--duration", "1", "--no-camera", "--format", "ros2", "--out", out_arg],
    ] {
        let o = objslam(&root, &args);
        assert!(!o.status.success(), "{args:?} ran into a held directory");
        let e = stderr(&o);
        assert!(e.contains(out_arg) && e.contains("another objslam command is writing into this directory"), "{e}");
        assert!(!e.contains("panicked"), "{e}");
    }
    let written: Vec<_> =
        std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().file_name()).filter(|n| n != ".objslam.lock").collect();
    assert!(written.is_empty(), "nothing was written: {written:?}");
    // Once the other command is done, the directory is free.
    drop(held);
    let log = root.join("log");
    let log_arg = log.to_str().unwrap();
    let o = objslam(&root, &["record", "park", "--duration", "1", "--no-camera", "--format", "log", "--out", log_arg]);
    assert!(o.status.success(), "{}", stderr(&o));
    // A replay is held off as a run is.
    let held = scenarios::partial_files::lock_output(&out).unwrap();
    let o = objslam(&root, &["replay", log_arg, "--method", "nn", "--out", out_arg]);
    assert!(!o.status.success() && stderr(&o).contains("another objslam command"), "{}", stderr(&o));
    drop(held);
    let o = objslam(&root, &["replay", log_arg, "--method", "nn", "--out", out_arg]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(out.join("trajectory_est.tum").is_file());
    let _ = std::fs::remove_dir_all(&root);
}

#[cfg(unix)]
#[test]
fn a_killed_recording_leaves_the_earlier_one_whole() {
    let root = temp_root("killed-record");
    let out = root.join("rec");
    let out_arg = out.to_str().unwrap();
    let o = objslam(&root, &["record", "park", "--seed", "1", "--duration", "2", "--no-camera", "--out", out_arg]);
    assert!(o.status.success(), "{}", stderr(&o));
    let earlier = contents(&out);
    assert!(earlier.iter().any(|(p, _)| p == Path::new("laser.jsonl")), "{:?}", earlier.len());

    // A long recording with camera frames, killed once it has written some of its log.
    let mut child = Command::new(env!("CARGO_BIN_EXE_objslam"))
        .args(["record", "park", "--seed", "2", "--duration", "60", "--out", out_arg])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let started = Instant::now();
    let writing = out.join(".unfinished/laser.jsonl");
    while std::fs::metadata(&writing).map(|m| m.len()).unwrap_or(0) == 0 {
        assert!(child.try_wait().unwrap().is_none(), "the recording ended before it could be stopped");
        assert!(started.elapsed() < Duration::from_secs(120), "the recording wrote nothing in 2 minutes");
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(child.try_wait().unwrap().is_none(), "the recording ended before it could be stopped");
    child.kill().unwrap();
    child.wait().unwrap();
    assert_eq!(contents(&out), earlier, "the earlier recording is as it was");

    // The next recording finds no trace of the killed one.
    let o = objslam(&root, &["record", "park", "--seed", "3", "--duration", "2", "--no-camera", "--out", out_arg]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!out.join(".unfinished").exists());
    let now = contents(&out);
    assert_eq!(now.iter().map(|(p, _)| p).collect::<Vec<_>>(), earlier.iter().map(|(p, _)| p).collect::<Vec<_>>());
    assert_ne!(now, earlier, "another seed, another recording");
    let _ = std::fs::remove_dir_all(&root);
}

/// A bag appears in its directory only once written whole: a killed recording leaves no
/// half bag there (a reader would find an MCAP file and no `metadata.yaml`) and does not
/// block the next recording into that directory.
#[cfg(unix)]
#[test]
fn a_killed_bag_recording_leaves_no_half_bag_and_no_blocked_directory() {
    let root = temp_root("killed-bag");
    let out = root.join("bag");
    let out_arg = out.to_str().unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_objslam"))
        .args(["record", "park", "--seed", "2", "--duration", "60", "--format", "ros2", "--out", out_arg])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let started = Instant::now();
    let writing = out.join(".unfinished/bag_0.mcap");
    while std::fs::metadata(&writing).map(|m| m.len()).unwrap_or(0) < 100_000 {
        assert!(child.try_wait().unwrap().is_none(), "the recording ended before it could be stopped");
        assert!(started.elapsed() < Duration::from_secs(120), "the recording wrote little in 2 minutes");
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(contents(&out).is_empty(), "only unfinished files: {:?}", contents(&out).len());

    let o = objslam(
        &root,
        &["record", "park", "--seed", "3", "--duration", "2", "--no-camera", "--format", "ros2", "--out", out_arg],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!out.join(".unfinished").exists());
    let mut names: Vec<_> = contents(&out).into_iter().map(|(p, _)| p).collect();
    names.sort();
    assert_eq!(names, [PathBuf::from("bag_0.mcap"), PathBuf::from("metadata.yaml")]);
    let yaml = std::fs::read_to_string(out.join("metadata.yaml")).unwrap();
    assert!(yaml.contains("bag_0.mcap"), "{yaml}");
    // A bag is written once: a finished one is not written over.
    let o = objslam(
        &root,
        &["record", "park", "--seed", "4", "--duration", "2", "--no-camera", "--format", "ros2", "--out", out_arg],
    );
    assert!(!o.status.success(), "recorded over a finished bag");
    assert!(stderr(&o).contains(out_arg), "{}", stderr(&o));
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn a_study_reruns_its_jobs_from_any_directory() {
    let root = temp_root("study-elsewhere");
    let begun_in = root.join("scenarios");
    std::fs::create_dir_all(&begun_in).unwrap();
    let (mut sc, _) = scenarios::scenario::Scenario::load("laser_only").unwrap();
    sc.name = "laser_only_short".into();
    sc.sim.max_duration_s = Some(8.0);
    sc.pass = Default::default();
    sc.sim.camera.enabled = false;
    std::fs::write(begun_in.join("short.toml"), toml::to_string(&sc).unwrap()).unwrap();
    let o = objslam(&begun_in, &["montecarlo", "short.toml", "--runs", "1", "--methods", "nn", "--out", "../study"]);
    assert!(o.status.success(), "{}", stderr(&o));
    // From the study's parent, where no short.toml is: the study's own record decides.
    let o = objslam(&root, &["montecarlo", "rerun", "study", "--job", "0", "--out", "rerun"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(root.join("rerun/metrics.json").is_file());
    // By its key, written as in runs.jsonl (no parameters: `;;`) or without the empty part.
    for key in ["method=nn;;run=0", "method=nn;run=0"] {
        let o = objslam(&root, &["montecarlo", "rerun", "study", "--job", key, "--out", "rerun-key"]);
        assert!(o.status.success(), "{key}: {}", stderr(&o));
    }
    // A short.toml here is another scenario: resuming the study from here is refused.
    sc.sim.max_duration_s = Some(7.0);
    std::fs::write(root.join("short.toml"), toml::to_string(&sc).unwrap()).unwrap();
    let o = objslam(&root, &["montecarlo", "short.toml", "--runs", "1", "--methods", "nn", "--out", "study"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("differ"), "{}", stderr(&o));
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn an_output_that_is_an_input_is_refused_and_the_input_kept() {
    let root = temp_root("out-is-in");
    let world = root.join("w.toml");
    let o = objslam(&root, &["world", "generate", "--preset", "park", "--out", "w.toml"]);
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::copy(&world, root.join("world.toml")).unwrap();
    std::fs::write(root.join("data.csv"), "x,y\n1,2\n3,4\n").unwrap();
    std::fs::write(root.join("image.png"), "not read").unwrap();
    std::fs::create_dir_all(root.join("run")).unwrap();
    std::fs::write(root.join("run/metrics.json"), "{}").unwrap();
    let o = objslam(&root, &["dataset", "--images", "1", "--out", "images"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = Command::new("cp").args(["-r", "images", "copy"]).current_dir(&root).output().unwrap();
    assert!(o.status.success());
    // Manifests edited by hand: an image listed twice (trained on twice, or trained on and
    // held out), another layout, a file outside the dataset.
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root.join("images/dataset.json")).unwrap()).unwrap();
    type Edit = fn(&mut serde_json::Value);
    let edits: [(&str, Edit); 3] = [
        ("dup_image", |m| {
            let first = m["images"][0].clone();
            m["images"].as_array_mut().unwrap().push(first);
        }),
        ("version", |m| m["format_version"] = 2.into()),
        ("outside", |m| m["images"][0]["image"] = "../copy/images/000000.png".into()),
    ];
    for (name, edit) in edits {
        let o = Command::new("cp").args(["-r", "images", name]).current_dir(&root).output().unwrap();
        assert!(o.status.success());
        let mut m = manifest.clone();
        edit(&mut m);
        std::fs::write(root.join(name).join("dataset.json"), m.to_string()).unwrap();
    }
    // A link to a dataset's file: writing it writes the file.
    std::os::unix::fs::symlink(root.join("images/dataset.json"), root.join("link.json")).unwrap();
    // A real robot's log, and simulator settings kept under a name a recording writes.
    std::fs::create_dir_all(root.join("robot")).unwrap();
    std::fs::write(root.join("robot/manifest.toml"), "source = \"my robot\"\n").unwrap();
    std::fs::create_dir_all(root.join("settings")).unwrap();
    std::fs::write(root.join("settings/odometry.csv"), "max_duration_s = 5.0\n").unwrap();
    // A folder of the user's own under a name a run writes, where no run was.
    std::fs::create_dir_all(root.join("notes/objects")).unwrap();
    std::fs::write(root.join("notes/objects/keep.txt"), "my notes").unwrap();
    std::fs::create_dir_all(root.join("linked")).unwrap();
    std::os::unix::fs::symlink(root.join("run/metrics.json"), root.join("linked/metrics.json")).unwrap();
    // Another run's directory, not the log scored.
    std::fs::create_dir_all(root.join("other_run")).unwrap();
    std::fs::write(root.join("other_run/metadata.json"), "{}").unwrap();
    std::fs::write(root.join("other_run/metrics.json"), "{\"method\": \"mine\"}").unwrap();
    let before = contents(&root);
    for (args, expect) in [
        (vec!["world", "export", "w.toml", "--out", "./w.toml"], "the world file given"),
        (
            vec!["world", "export", "w.toml", "--out", "w.gltf"],
            "the export is binary glTF; give a file name ending in .glb",
        ),
        (
            vec!["record", "park", "--duration", "1", "--no-camera", "--out", "robot"],
            "holds a robot log that objslam record did not write",
        ),
        (
            vec!["record", "park", "--sim-config", "settings/odometry.csv", "--format", "log", "--out", "settings"],
            "the --sim-config file (settings/odometry.csv) lies among the files the recording replaces or removes",
        ),
        (
            vec!["run", "laser_only", "--out", "notes"],
            "it holds objects, which a run writes or removes there, but no earlier run",
        ),
        // A recording writes OUT/world.toml: not over the world file it simulates.
        (vec!["record", "world.toml", "--duration", "1", "--out", "."], "the recording writes world.toml there"),
        (vec!["record", "./world.toml", "--format", "log", "--out", "./"], "which is the world file given"),
        (vec!["world", "plot", "w.toml", "--out", "w.toml"], "the world file given"),
        (vec!["world", "plot", "w.toml", "--out", "w.svg"], "w.svg: cannot draw plot: the map is drawn as PNG"),
        (vec!["segment", "--model", "model.json", "image.png", "--out", "image.png"], "the image given"),
        (vec!["gmm", "fit", "data.csv", "--out", "data.csv"], "the data given"),
        (vec!["score", "--log", "run", "--trajectory", "t.tum", "--out", "run/"], "the log given"),
        (vec!["score", "--log", "run", "--trajectory", "run/metrics.json", "--out", "run"], "the log given"),
        (vec!["score", "--log", "run", "--trajectory", "t.tum", "--out", "linked"], "is a file of the log given (run)"),
        (
            vec!["score", "--log", "run", "--trajectory", "t.tum", "--out", "other_run"],
            "--out other_run: holds the outputs of a run or a recorded log (metadata.json), whose metrics.json",
        ),
        (
            vec!["score", "--log", "run", "--trajectory", "t.tum", "--method", " ", "--out", "s"],
            "--method: an empty name",
        ),
        (vec!["train", "--dataset", "images", "--heldout-dataset", "images/", "--out", "m.json"], "it is the training"),
        (
            vec!["train", "--dataset", "images", "--heldout-dataset", "copy", "--out", "m.json"],
            "shows the world of the training dataset images",
        ),
        (vec!["train", "--dataset", "images", "--out", "link.json"], "--out link.json: a file of the dataset images"),
        (
            vec!["train", "--dataset", "images", "--out", "m.json", "--export-features", "link.json"],
            "--export-features link.json: a file of the dataset images",
        ),
        (
            vec!["train", "--dataset", "dup_image", "--out", "m.json"],
            "dup_image/dataset.json: images[1].id: 0 is listed twice",
        ),
        (vec!["train", "--dataset", "version", "--out", "m.json"], "format_version 2, this objslam reads version 1"),
        (
            vec!["train", "--dataset", "outside", "--out", "m.json"],
            "images[0].image: \"../copy/images/000000.png\" is not a path inside the dataset",
        ),
        // Refused before training, not when the model is saved.
        (vec!["train", "--dataset", "images", "--out", "run"], "--out run: is a directory"),
        (vec!["train", "--dataset", "images", "--out", "nowhere/m.json"], "the directory nowhere does not exist"),
        (
            vec!["train", "--dataset", "images", "--export-features", "run", "--out", "m.json"],
            "--export-features run: is a",
        ),
        (vec!["gmm", "fit", "data.csv", "--out", "run"], "--out run: is a directory"),
        // A training's outputs had replaced its own dataset's manifest, or each other.
        (vec!["train", "--dataset", "images", "--out", "images/dataset.json"], "a file of the dataset images"),
        (vec!["train", "--dataset", "images/dataset.json", "--out", "m.json"], "a dataset is given by its directory"),
        (vec!["train", "--dataset", "images", "--out", "images/labels/x.json"], "a file of the dataset images"),
        (
            vec![
                "train",
                "--dataset",
                "images",
                "--heldout-dataset",
                "copy",
                "--heldout-report",
                "copy/world.toml",
                "--out",
                "m.json",
            ],
            "a file of the dataset copy",
        ),
        (
            vec!["train", "--dataset", "images", "--export-features", "m.json", "--out", "m.json"],
            "--out writes there too",
        ),
        // A dataset had replaced the user's own folders and world file in a directory
        // that holds no dataset.
        (vec!["dataset", "--images", "1", "--out", "."], "but no dataset.json, so it is not an earlier dataset"),
        (
            vec!["dataset", "--world", "images/world.toml", "--images", "1", "--out", "images"],
            "a file of the dataset in images",
        ),
        (vec!["dataset", "--classes", "tree,post,tree", "--images", "1", "--out", "twice"], "\"tree\" is named twice"),
        (
            vec!["dataset", "--patch-size", "65", "--images", "1", "--out", "big"],
            "give 1 to 64 pixels (the largest patch the patch features describe)",
        ),
        (vec!["find", "--run", "run", "image.png", "--top", "0"], "--top must be at least 1"),
        (vec!["find", "--run", "nowhere", "image.png"], "--run nowhere: no such directory"),
        (vec!["calibrate", "--images", "run", "--out", "run/pose_00.png"], "a pose image's name in --images run"),
    ] {
        let o = objslam(&root, &args);
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(stderr(&o).contains(expect), "{args:?}: {}", stderr(&o));
    }
    assert_eq!(contents(&root), before, "every input is as it was; nothing was written");
    assert!(world.is_file());
    let _ = std::fs::remove_dir_all(&root);
}

/// A held-out dataset that cannot give held-out figures of the model is refused before
/// training, whatever its spelling: the training's world under another path, other
/// classes (scored against other labels), other patches (refused only after training,
/// the model written), and no image (read as precision, recall and F1 1).
#[test]
fn held_out_datasets_that_would_measure_nothing_held_out_are_refused_before_training() {
    let root = temp_root("heldout-checks");
    let made = |args: &[&str]| {
        let o = objslam(&root, args);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
    };
    made(&["world", "generate", "--preset", "park", "--out", "w.toml"]);
    made(&["dataset", "--world", "w.toml", "--images", "1", "--out", "tr"]);
    made(&["dataset", "--world", "./w.toml", "--images", "1", "--seed", "2", "--out", "same"]);
    made(&["dataset", "--preset", "park", "--seed", "7", "--images", "1", "--classes", "post", "--out", "post"]);
    made(&["dataset", "--preset", "park", "--seed", "7", "--images", "1", "--patch-size", "8", "--out", "p8"]);
    made(&["dataset", "--preset", "park", "--seed", "7", "--images", "1", "--out", "empty"]);
    let manifest = root.join("empty/dataset.json");
    let mut m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&manifest).unwrap()).unwrap();
    m["images"] = serde_json::json!([]);
    std::fs::write(&manifest, m.to_string()).unwrap();
    for (held_out, expect) in [
        (
            "same",
            "--heldout-dataset same: shows the world of the training dataset tr (w.toml: the same ground, objects and people)",
        ),
        ("post", "post/dataset.json: labelled for the classes post, and the training dataset tr for tree"),
        ("p8", "p8/dataset.json: patch_size is 8, the model's patches are 9 px"),
        ("empty", "empty/dataset.json: images: [] (no image): a held-out dataset with no image scores nothing"),
    ] {
        let o = objslam(&root, &["train", "--dataset", "tr", "--heldout-dataset", held_out, "--out", "m.json"]);
        assert!(!o.status.success(), "{held_out} was scored");
        assert!(stderr(&o).contains(expect), "{held_out}: {}", stderr(&o));
        assert!(!root.join("m.json").exists(), "{held_out}: refused after training");
    }
    let twice =
        ["train", "--dataset", "tr", "--heldout-dataset", "post", "--heldout-dataset", "./post/", "--out", "m.json"];
    let o = objslam(&root, &twice);
    assert!(stderr(&o).contains("--heldout-dataset ./post/: given twice (also as post)"), "{}", stderr(&o));
    assert!(!root.join("m.json").exists());
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn a_recording_never_replaces_a_ros2_bag() {
    // A bag is often a real robot's data: a log or JSON-lines recording into its directory
    // is refused, and the bag stays as it was.
    let root = temp_root("keeps-bag");
    let bag = root.join("bag");
    let bag_arg = bag.to_str().unwrap();
    let o = objslam(&root, &["record", "park", "--duration", "1", "--no-camera", "--format", "ros2", "--out", bag_arg]);
    assert!(o.status.success(), "{}", stderr(&o));
    let before = contents(&bag);
    for format in ["log", "jsonl"] {
        let args = ["record", "park", "--duration", "1", "--no-camera", "--format", format, "--out", bag_arg];
        let o = objslam(&root, &args);
        assert!(!o.status.success(), "{format} replaced a bag");
        let e = stderr(&o);
        assert!(e.contains(bag_arg) && e.contains("holds a ROS 2 bag (metadata.yaml)"), "{e}");
        assert!(!e.contains("panicked"), "{e}");
        assert_eq!(contents(&bag), before, "the bag is untouched");
    }
    // Nor a run's directory: its trajectory and map would stay beside another recording.
    let run = root.join("run");
    let run_arg = run.to_str().unwrap();
    std::fs::create_dir_all(&run).unwrap();
    std::fs::write(run.join("metrics.json"), "{}").unwrap();
    let o = objslam(&root, &["record", "park", "--duration", "1", "--no-camera", "--out", run_arg]);
    assert!(!o.status.success(), "a recording went into a run's directory");
    let e = stderr(&o);
    assert!(e.contains(run_arg) && e.contains("holds a run's outputs (metrics.json)"), "{e}");
    assert!(!run.join("metadata.json").exists());
    let _ = std::fs::remove_dir_all(&root);
}

/// A generalisation benchmark's directory and a study's keep apart: a benchmark refused
/// for a plan its directory does not hold writes nothing there (its worlds.json stays the
/// first command's), a study or merge into a benchmark's directory is refused, and a
/// benchmark into a study's directory too. A shard with no job writes the plans and runs
/// nothing, so none of this trains or runs.
#[test]
fn a_benchmark_directory_and_a_study_directory_are_not_taken_for_each_other() {
    let root = temp_root("benchmark-dirs");
    let ok = objslam(&root, &["montecarlo", "generalisation", "--runs", "1", "--shard", "5/6", "--out", "g"]);
    assert!(ok.status.success(), "{}", stderr(&ok));
    let worlds = std::fs::read(root.join("g/worlds.json")).unwrap();
    for (args, expect) in [
        (&["montecarlo", "generalisation", "--runs", "3", "--out", "g"][..], "holds a different study"),
        (&["montecarlo", "generalisation", "--split", "tune", "--runs", "1", "--out", "g"], "holds a different study"),
        (
            &["montecarlo", "laser_only", "--runs", "1", "--methods", "nn", "--out", "g"],
            "holds a generalisation benchmark",
        ),
        (&["montecarlo", "merge", "g/jcbb", "--out", "g"], "holds a generalisation benchmark"),
        (&["montecarlo", "generalisation", "--runs", "18446744073709551615", "--out", "x"], "more than 1000000 runs"),
    ] {
        let o = objslam(&root, args);
        assert!(!o.status.success() && stderr(&o).contains(expect), "{args:?}: {}", stderr(&o));
        assert_eq!(std::fs::read(root.join("g/worlds.json")).unwrap(), worlds, "{args:?} wrote worlds.json");
        assert!(!root.join("g/study.json").exists() && !root.join("g/summary.json").exists(), "{args:?}");
    }
    assert!(!root.join("x").exists(), "a refused plan made its directory");
    std::fs::create_dir_all(root.join("s")).unwrap();
    std::fs::write(root.join("s/study.json"), "{}").unwrap();
    let o = objslam(&root, &["montecarlo", "generalisation", "--runs", "1", "--shard", "5/6", "--out", "s"]);
    assert!(!o.status.success() && stderr(&o).contains("holds a Monte Carlo study"), "{}", stderr(&o));
    assert!(!root.join("s/worlds.json").exists());
    // Files of the report's names without a benchmark, another worlds.json, the built-in
    // study's directories: refused, nothing replaced.
    for (dir, file, expect) in [
        ("mine", "summary.json", "holds summary.json but no benchmark"),
        ("other", "worlds.json", "not the worlds this benchmark draws"),
        ("built_in", "odometry/study.json", "holds odometry but no benchmark"),
    ] {
        std::fs::create_dir_all(root.join(dir).join(file).parent().unwrap()).unwrap();
        std::fs::write(root.join(dir).join(file), "my own").unwrap();
        let o = objslam(&root, &["montecarlo", "generalisation", "--runs", "1", "--shard", "5/6", "--out", dir]);
        assert!(!o.status.success() && stderr(&o).contains(expect), "{dir}: {}", stderr(&o));
        assert_eq!(std::fs::read_to_string(root.join(dir).join(file)).unwrap(), "my own");
    }
    let o = objslam(&root, &["montecarlo", "study", "--runs", "1", "--out", "g"]);
    assert!(!o.status.success() && stderr(&o).contains("holds a generalisation benchmark"), "{}", stderr(&o));
    // A benchmark's directory given where one study's goes: said, with where its studies are.
    let o = objslam(&root, &["montecarlo", "merge", "g", "--out", "m"]);
    assert!(!o.status.success() && stderr(&o).contains("whose studies are its combined/ and jcbb/"), "{}", stderr(&o));
    assert!(!root.join("g/odometry").exists());
    let _ = std::fs::remove_dir_all(&root);
}

/// A recording refuses a scenario input among the files it replaces there, as a run does;
/// a calibration session may write the calibration file its scenario names (it does not
/// read it), but not the scenario file itself.
#[test]
fn inputs_among_a_recordings_outputs_are_refused_and_a_calibration_may_be_rewritten() {
    let root = temp_root("record-inputs");
    std::fs::create_dir_all(root.join("rd")).unwrap();
    let model = root.join("rd/appearance_model.json");
    std::fs::write(&model, "{}").unwrap();
    let scenario = "name = \"am\"\n[world]\npreset = \"park\"\n[appearance]\nmodel = \"rd/appearance_model.json\"\n";
    std::fs::write(root.join("am.toml"), scenario).unwrap();
    let o = objslam(&root, &["record", "--scenario", "am.toml", "--duration", "1", "--out", "rd"]);
    assert!(!o.status.success() && stderr(&o).contains("appearance model"), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(&model).unwrap(), "{}");
    let calibration = "name = \"cal\"\n[world]\npreset = \"park\"\n[calibration]\nmode = \"cal.json\"\n";
    std::fs::write(root.join("cal.toml"), calibration).unwrap();
    let o = objslam(&root, &["calibrate", "cal.toml", "--poses", "5", "--out", "cal.toml"]);
    assert!(!o.status.success() && stderr(&o).contains("scenario file"), "{}", stderr(&o));
    let o = objslam(&root, &["calibrate", "cal.toml", "--poses", "5", "--out", "cal.json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(std::fs::read_to_string(root.join("cal.json")).unwrap().contains("\"phi\""));
    let _ = std::fs::remove_dir_all(&root);
}

/// A run's output directory named as its built-in scenario (`--out laser_only`) does not
/// hide the scenario from the next command that names it.
#[test]
fn a_directory_named_as_a_built_in_scenario_does_not_hide_it() {
    let root = std::env::temp_dir().join(format!("objslam-builtin-dir-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(root.join("laser_only")).unwrap();
    let o = objslam(&root, &["config", "check", "laser_only"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let _ = std::fs::remove_dir_all(&root);
}
