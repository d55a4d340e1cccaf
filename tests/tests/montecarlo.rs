//! Monte Carlo studies: sharding, merging, resuming and fault isolation.

use std::path::{Path, PathBuf};

use scenarios::montecarlo::{self as mc, RunRecord, Shard, StudyPlan, Vary};

/// A short copy of the laser_only scenario in a temporary directory.
fn short_scenario(dir: &Path) -> String {
    std::fs::create_dir_all(dir).unwrap();
    let (mut sc, _) = scenarios::scenario::Scenario::load("laser_only").unwrap();
    sc.name = "laser_only_short".into();
    sc.sim.max_duration_s = Some(12.0);
    // A 12 s run does not finish the route; only check what a short run can show.
    sc.pass = Default::default();
    // Without a camera the camera methods cannot run: their runs must fail cleanly.
    sc.sim.camera.enabled = false;
    let path = dir.join("laser_only_short.toml");
    std::fs::write(&path, toml::to_string(&sc).unwrap()).unwrap();
    path.to_string_lossy().into_owned()
}

fn assert_same(a: &[String], b: &[String]) {
    assert_eq!(a.len(), b.len(), "different numbers of runs");
    for (x, y) in a.iter().zip(b) {
        assert_eq!(x, y, "runs differ");
    }
}

/// Records without the wall-clock fields, which legitimately differ between runs.
fn comparable(runs: &[RunRecord]) -> Vec<String> {
    runs.iter().map(|r| serde_json::to_string(&r.without_wall_clock()).unwrap()).collect()
}

#[test]
fn sharded_merged_study_equals_the_unsharded_one_and_resumes() {
    let root: PathBuf = std::env::temp_dir().join(format!("objslam-mc-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let scenario = short_scenario(&root);
    // `combined` cannot run without the camera: its runs must be recorded as errors while
    // the others go on.
    let plan = StudyPlan {
        scenario,
        base_seed: 5,
        runs: 3,
        methods: vec!["nn".into(), "jcbb".into(), "combined".into()],
        vary: vec![Vary::parse("sim.odometry.scale_sigma=0.0..0.03:2").unwrap()],
    };
    let whole = mc::run_study(&plan, Shard::all(), &root.join("whole"), |_| {}).unwrap();
    assert_eq!(whole.len(), 18);
    assert_eq!(whole.iter().filter(|r| r.error.is_some()).count(), 6, "the combined runs error");
    assert!(whole.iter().filter_map(|r| r.error.as_deref()).all(|e| e.contains("needs the camera")));
    assert!(whole.iter().filter(|r| r.job.method != "combined").all(|r| r.metrics.is_some()));

    // Resuming a finished study runs nothing new.
    let lines_before = std::fs::read_to_string(root.join("whole/runs.jsonl")).unwrap().lines().count();
    let again = mc::run_study(&plan, Shard::all(), &root.join("whole"), |_| {}).unwrap();
    assert_same(&comparable(&again), &comparable(&whole));
    assert_eq!(std::fs::read_to_string(root.join("whole/runs.jsonl")).unwrap().lines().count(), lines_before);
    // Resumed as one shard, it still summarises every run it holds, not the shard's half.
    let summary_before = std::fs::read_to_string(root.join("whole/summary.csv")).unwrap();
    let half = Shard { index: 0, count: 2 };
    let as_shard = mc::run_study(&plan, half, &root.join("whole"), |_| {}).unwrap();
    let shard_of_whole: Vec<RunRecord> = whole
        .iter()
        .filter(|r| mc::jobs(&plan).iter().any(|j| j.key() == r.key && half.contains(j)))
        .cloned()
        .collect();
    assert!(!as_shard.is_empty() && as_shard.len() < whole.len());
    assert_same(&comparable(&as_shard), &comparable(&shard_of_whole));
    assert_eq!(std::fs::read_to_string(root.join("whole/summary.csv")).unwrap(), summary_before);

    // Three shards, merged, give the same runs and the same summary.
    let dirs: Vec<PathBuf> = (0..3).map(|k| root.join(format!("shard-{k}"))).collect();
    for (k, d) in dirs.iter().enumerate() {
        mc::run_study(&plan, Shard { index: k, count: 3 }, d, |_| {}).unwrap();
    }
    let (merged_plan, merged) = mc::merge(&dirs, &root.join("merged")).unwrap();
    assert_eq!(merged_plan, plan);
    assert_eq!(mc::missing_runs(&plan, &merged), 0);
    // A shard of another study (another base seed) is named with what differs.
    let other = StudyPlan { base_seed: 6, ..plan.clone() };
    mc::run_study(&other, Shard { index: 0, count: 3 }, &root.join("other-0"), |_| {}).unwrap();
    let e = mc::merge(&[dirs[0].clone(), root.join("other-0")], &root.join("merged-other")).unwrap_err().to_string();
    assert!(
        e.contains("other-0/study.json: this shard holds another study") && e.contains("differ in base_seed"),
        "{e}"
    );
    assert!(!e.contains("use a new --out"), "{e}");
    // Two of the three shards: the third's runs are missing, and said to be.
    let (_, two) = mc::merge(&dirs[..2], &root.join("merged-two")).unwrap();
    let third = mc::jobs(&plan).iter().filter(|j| Shard { index: 2, count: 3 }.contains(j)).count();
    assert!(third > 0 && two.len() + third == merged.len());
    assert_eq!(mc::missing_runs(&plan, &two), third);
    // Its plot says how many runs its points hold, not the plan's 3.
    let svg = std::fs::read_to_string(root.join("merged-two/failure_rate.svg")).unwrap();
    assert!(svg.contains("runs per point") && !svg.contains("(3 runs per point"), "{}", &svg[..svg.len().min(600)]);
    let svg = std::fs::read_to_string(root.join("whole/failure_rate.svg")).unwrap();
    assert!(svg.contains("(3 runs per point"));
    assert_same(&comparable(&merged), &comparable(&whole));
    let a = mc::summarise(&plan, &whole);
    let b = mc::summarise(&plan, &merged);
    assert_eq!(serde_json::to_string(&a).unwrap(), serde_json::to_string(&b).unwrap());
    // The study and the merge write their summaries themselves, while they hold the
    // directory, and the two say the same.
    for dir in ["whole", "merged"] {
        for f in ["summary.csv", "summary.json", "failure_rate.png", "failure_rate.svg"] {
            assert!(root.join(dir).join(f).exists(), "{dir}/{f} missing");
        }
    }
    assert_eq!(
        std::fs::read_to_string(root.join("whole/summary.csv")).unwrap(),
        std::fs::read_to_string(root.join("merged/summary.csv")).unwrap()
    );
    let csv = std::fs::read_to_string(root.join("merged/summary.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 6, "{csv}");

    // A study interrupted mid-way (simulated by deleting lines) finishes the rest.
    let partial = root.join("partial");
    std::fs::create_dir_all(&partial).unwrap();
    std::fs::copy(root.join("whole/study.json"), partial.join("study.json")).unwrap();
    let text = std::fs::read_to_string(root.join("whole/runs.jsonl")).unwrap();
    let keep: String = text.lines().take(7).map(|l| format!("{l}\n")).collect::<String>() + "{\"key\":\"trunc";
    std::fs::write(partial.join("runs.jsonl"), keep).unwrap();
    let resumed = mc::run_study(&plan, Shard::all(), &partial, |_| {}).unwrap();
    assert_same(&comparable(&resumed), &comparable(&whole));

    // A different plan in the same directory is refused.
    let other = StudyPlan { runs: 4, ..plan.clone() };
    assert!(mc::run_study(&other, Shard::all(), &root.join("whole"), |_| {}).is_err());

    // A job recorded twice, identically, counts once; differently, it is an error naming
    // both lines; a merge of shards that disagree is refused.
    let twice = root.join("twice");
    std::fs::create_dir_all(&twice).unwrap();
    std::fs::copy(root.join("whole/study.json"), twice.join("study.json")).unwrap();
    // The first record with metrics (runs finish in any order; combined's are errors).
    let first_line = 1 + text.lines().position(|l| l.contains("\"metrics\"")).unwrap();
    let first = text.lines().nth(first_line - 1).unwrap();
    std::fs::write(twice.join("runs.jsonl"), format!("{text}{first}\n")).unwrap();
    assert_same(&comparable(&mc::run_study(&plan, Shard::all(), &twice, |_| {}).unwrap()), &comparable(&whole));
    let mut changed: RunRecord = serde_json::from_str(first).unwrap();
    changed.metrics.as_mut().expect("a position-only run").ate_rmse_m += 1.0;
    let conflicting = format!("{text}{}\n", serde_json::to_string(&changed).unwrap());
    std::fs::write(twice.join("runs.jsonl"), &conflicting).unwrap();
    let e = mc::run_study(&plan, Shard::all(), &twice, |_| {}).unwrap_err().to_string();
    assert!(e.contains("runs.jsonl") && e.contains(&format!("lines {first_line} and 19")), "{e}");
    // Any job runs again with its outputs and repeats its record, found by index or key;
    // a record that the run does not repeat is told apart.
    let rerun = mc::rerun(&root.join("whole"), "1", &root.join("rerun"), None).unwrap();
    assert_eq!((rerun.job.index, rerun.repeats_record()), (1, Some(true)));
    for f in ["trajectory_est.tum", "metrics.json", "metadata.json", "landmarks.json"] {
        assert!(root.join("rerun").join(f).is_file(), "{f} missing");
    }
    let edited = root.join("edited");
    std::fs::create_dir_all(&edited).unwrap();
    std::fs::copy(root.join("whole/study.json"), edited.join("study.json")).unwrap();
    let rerun = mc::rerun(&edited, &changed.key, &root.join("rerun2"), None).unwrap();
    assert_eq!((rerun.job.key(), rerun.repeats_record()), (changed.key.clone(), None), "no record yet");
    // The study's file may hold blank lines and a line being written, which stays as it is.
    let runs = format!("\n{}\n{{\"key\":\"torn", serde_json::to_string(&changed).unwrap());
    std::fs::write(edited.join("runs.jsonl"), &runs).unwrap();
    let rerun = mc::rerun(&edited, &changed.key, &root.join("rerun2"), None).unwrap();
    assert_eq!((rerun.repeats_record(), rerun.differences()), (Some(false), vec!["metrics.ate_rmse_m".to_string()]));
    assert_eq!(std::fs::read_to_string(edited.join("runs.jsonl")).unwrap(), runs);
    let e = mc::rerun(&edited, "18", &root.join("rerun3"), None).err().expect("no job 18").to_string();
    assert!(e.contains("study.json") && e.contains("0 to 17"), "{e}");
    std::fs::write(dirs[0].join("runs.jsonl"), format!("{}\n", serde_json::to_string(&changed).unwrap())).unwrap();
    let e = mc::merge(&[root.join("whole"), dirs[0].clone()], &root.join("merged2")).unwrap_err().to_string();
    assert!(e.contains("recorded differently"), "{e}");

    // The study keeps which scenario it began with: once the scenario file changes, a
    // resume and a rerun are refused rather than mix its runs with the study's.
    let scenario_file = PathBuf::from(&plan.scenario);
    let original = std::fs::read_to_string(&scenario_file).unwrap();
    let study: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root.join("whole/study.json")).unwrap()).unwrap();
    let pinned = std::fs::canonicalize(&scenario_file).unwrap();
    assert_eq!(study["scenario_pin"]["file"], pinned.to_string_lossy().as_ref(), "{study}");
    assert_eq!(study["scenario_pin"]["sha256"].as_str().map(str::len), Some(64), "{study}");
    let mut edited_scenario: scenarios::scenario::Scenario = toml::from_str(&original).unwrap();
    edited_scenario.description = "words only".into();
    std::fs::write(&scenario_file, toml::to_string(&edited_scenario).unwrap()).unwrap();
    assert!(mc::run_study(&plan, Shard::all(), &root.join("whole"), |_| {}).is_ok(), "a description is no setting");
    edited_scenario.sim.max_duration_s = Some(11.0);
    std::fs::write(&scenario_file, toml::to_string(&edited_scenario).unwrap()).unwrap();
    let e = mc::run_study(&plan, Shard::all(), &root.join("whole"), |_| {}).unwrap_err().to_string();
    assert!(e.contains("different study") && e.contains("differ") && e.contains("laser_only_short.toml"), "{e}");
    let e =
        mc::rerun(&root.join("whole"), "1", &root.join("rerun4"), None).err().expect("a changed scenario").to_string();
    assert!(e.contains("study.json") && e.contains("has changed since the study began"), "{e}");
    assert!(!root.join("rerun4").exists(), "nothing was run");
    std::fs::write(&scenario_file, &original).unwrap();

    // A scenario file moved since the study began: a rerun says so, and takes its new place
    // with --scenario, the same scenario checked.
    let moved = root.join("moved.toml");
    std::fs::rename(&scenario_file, &moved).unwrap();
    let e = mc::rerun(&root.join("whole"), "1", &root.join("rerun5"), None).err().expect("moved").to_string();
    assert!(e.contains("study.json") && e.contains("not there any more") && e.contains("--scenario"), "{e}");
    let again = mc::rerun(&root.join("whole"), "1", &root.join("rerun5"), Some(&moved.to_string_lossy())).unwrap();
    assert_eq!(again.repeats_record(), Some(true), "the moved scenario repeats the study's run");
    std::fs::write(&moved, toml::to_string(&edited_scenario).unwrap()).unwrap();
    let e = mc::rerun(&root.join("whole"), "1", &root.join("rerun6"), Some(&moved.to_string_lossy()))
        .err()
        .expect("another scenario")
        .to_string();
    assert!(e.contains("files or settings differ") && e.contains("give the study's own scenario file"), "{e}");
    std::fs::write(&scenario_file, &original).unwrap();
    // A study begun before studies recorded their scenario cannot check a --scenario.
    let unpinned = root.join("unpinned");
    std::fs::create_dir_all(&unpinned).unwrap();
    let mut study: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root.join("whole/study.json")).unwrap()).unwrap();
    study.as_object_mut().unwrap().remove("scenario_pin");
    std::fs::write(unpinned.join("study.json"), study.to_string()).unwrap();
    let e = mc::rerun(&unpinned, "1", &root.join("rerun7"), Some(&moved.to_string_lossy())).err().expect("unchecked");
    assert!(e.to_string().contains("cannot be checked"), "{e}");

    // A study.json that is not a plan (a torn first write of an older version) is refused
    // with what to do, not overwritten.
    let torn = root.join("torn");
    std::fs::create_dir_all(&torn).unwrap();
    std::fs::write(torn.join("study.json"), [0xff, 0xfe, 0x00]).unwrap();
    let e = mc::run_study(&plan, Shard::all(), &torn, |_| {}).unwrap_err().to_string();
    assert!(e.contains("study.json") && e.contains("remove"), "{e}");
    assert_eq!(std::fs::read(torn.join("study.json")).unwrap(), [0xff, 0xfe, 0x00]);

    // A second study in a directory a running one holds is refused.
    let lock = scenarios::partial_files::lock_output(&root.join("whole")).unwrap();
    let e = mc::run_study(&plan, Shard::all(), &root.join("whole"), |_| {}).unwrap_err().to_string();
    assert!(e.contains("another study is running"), "{e}");
    drop(lock);
    assert!(mc::run_study(&plan, Shard::all(), &root.join("whole"), |_| {}).is_ok());
    let _ = std::fs::remove_dir_all(&root);
}

/// A study whose scenario or method is bad for some job fails before its first run,
/// naming the job, instead of recording an error for every run and exiting 0.
#[test]
fn bad_jobs_fail_the_study_before_any_run() {
    let root: PathBuf = std::env::temp_dir().join(format!("objslam-mc-bad-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let scenario = short_scenario(&root);
    let bad_method = StudyPlan {
        scenario: scenario.clone(),
        base_seed: 5,
        runs: 2,
        methods: vec!["nn".into(), "bogus".into()],
        vary: vec![],
    };
    let e = mc::run_study(&bad_method, Shard::all(), &root.join("a"), |_| {}).unwrap_err().to_string();
    assert!(e.contains("bogus"), "{e}");
    let bad_value = StudyPlan {
        vary: vec![Vary::parse("pipeline.gate_probability=0.5..1.5:2").unwrap()],
        methods: vec!["nn".into()],
        ..bad_method
    };
    let e = mc::run_study(&bad_value, Shard::all(), &root.join("b"), |_| {}).unwrap_err().to_string();
    assert!(e.contains("gate_probability"), "{e}");
    // An appearance model that cannot be had fails the study as that, with the run's
    // error (naming the file) inside it.
    let (mut sc, _) = scenarios::scenario::Scenario::load("paper_park").unwrap();
    sc.name = "no_model".into();
    sc.appearance.model = Some("no_such_model.json".into());
    std::fs::write(root.join("no_model.toml"), toml::to_string(&sc).unwrap()).unwrap();
    let no_model = StudyPlan {
        scenario: root.join("no_model.toml").to_string_lossy().into_owned(),
        methods: vec!["combined".into()],
        vary: vec![],
        ..bad_value
    };
    let e = mc::run_study(&no_model, Shard::all(), &root.join("c"), |_| {}).unwrap_err();
    assert!(matches!(e, mc::StudyError::Appearance(_)), "{e:?}");
    assert!(e.to_string().contains("no_such_model.json"), "{e}");
    for dir in ["a", "b", "c"] {
        assert!(mc::read_runs(&root.join(dir).join("runs.jsonl")).unwrap().is_empty(), "no run was made");
    }
    let _ = std::fs::remove_dir_all(&root);
}

/// A study's runs are never mixed with another study's nor lost to one: a merge into a
/// directory of another study is refused, into a held one waits for nobody, runs left
/// without their plan are not taken up by a new study, a record of another plan is named,
/// and a plan whose values repeat is refused before it runs.
#[test]
fn studies_of_different_plans_are_never_mixed() {
    let root: PathBuf = std::env::temp_dir().join(format!("objslam-mc-mix-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let scenario = short_scenario(&root);
    let plan = |seed: u64| StudyPlan {
        scenario: scenario.clone(),
        base_seed: seed,
        runs: 1,
        methods: vec!["nn".into()],
        vary: vec![],
    };
    let (a, b) = (root.join("a"), root.join("b"));
    let kept = mc::run_study(&plan(3), Shard::all(), &a, |_| {}).unwrap();
    mc::run_study(&plan(5), Shard::all(), &b, |_| {}).unwrap();
    let runs_of_a = std::fs::read_to_string(a.join("runs.jsonl")).unwrap();

    let e = mc::merge(std::slice::from_ref(&b), &a).unwrap_err().to_string();
    assert!(e.contains("holds another study"), "{e}");
    assert_eq!(std::fs::read_to_string(a.join("runs.jsonl")).unwrap(), runs_of_a, "the study's runs are kept");
    // Merged into itself (its own directory as the output), a study keeps its runs.
    let (_, merged) = mc::merge(std::slice::from_ref(&a), &a).unwrap();
    assert_same(&comparable(&merged), &comparable(&kept));

    let held = scenarios::partial_files::lock_output(&a).unwrap();
    let e = mc::merge(std::slice::from_ref(&a), &a).unwrap_err().to_string();
    assert!(e.contains("another study is running in this directory"), "{e}");
    // A rerun into a held directory is refused before it runs.
    let e = mc::rerun(&a, "0", &a, None).err().expect("refused").to_string();
    assert!(e.contains("another study is running in this directory"), "{e}");
    drop(held);

    // A record of another plan (another seed) is named by its line, on resume and merge.
    let foreign = std::fs::read_to_string(b.join("runs.jsonl")).unwrap();
    std::fs::write(a.join("runs.jsonl"), &foreign).unwrap();
    for e in [
        mc::run_study(&plan(3), Shard::all(), &a, |_| {}).unwrap_err().to_string(),
        mc::merge(std::slice::from_ref(&a), &root.join("c")).unwrap_err().to_string(),
    ] {
        assert!(e.contains("runs.jsonl") && e.contains("line 1") && e.contains("another study"), "{e}");
    }
    assert!(!root.join("c").exists(), "a refused merge leaves no directory it made");
    // Runs left without their plan are not taken as a new study's.
    std::fs::remove_file(a.join("study.json")).unwrap();
    let e = mc::run_study(&plan(5), Shard::all(), &a, |_| {}).unwrap_err().to_string();
    assert!(e.contains("study.json is gone"), "{e}");
    // A summary of a study's name where no study is: the user's, not replaced.
    let mine = root.join("mine");
    std::fs::create_dir_all(&mine).unwrap();
    std::fs::write(mine.join("summary.csv"), "my table").unwrap();
    let e = mc::run_study(&plan(5), Shard::all(), &mine, |_| {}).unwrap_err().to_string();
    assert!(e.contains("summary.csv") && e.contains("holds no study"), "{e}");
    let e = mc::merge(std::slice::from_ref(&b), &mine).unwrap_err().to_string();
    assert!(e.contains("summary.csv") && e.contains("holds no study"), "{e}");
    assert_eq!(std::fs::read_to_string(mine.join("summary.csv")).unwrap(), "my table");

    let repeated = StudyPlan { vary: vec![Vary::parse("sim.odometry.scale_sigma=0.01..0.01:3").unwrap()], ..plan(3) };
    assert!(repeated.check().unwrap_err().to_string().contains("comes twice"));
    std::fs::remove_dir_all(&root).ok();
}

/// A world file edited while a study runs stops the study at the next finished run: the
/// runs recorded before are kept, no run of the edited world is pooled with them, and the
/// study resumes once the file is restored.
#[test]
fn a_world_file_edited_mid_study_stops_it_without_pooling_two_worlds() {
    let root: PathBuf = std::env::temp_dir().join(format!("objslam-mc-edited-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let scenario = short_scenario(&root);
    let (mut sc, _) = scenarios::scenario::Scenario::load(&scenario).unwrap();
    let world = |seed| worlds::generate::park(&Default::default(), seed).unwrap().to_toml();
    std::fs::write(root.join("w.toml"), world(1)).unwrap();
    sc.world.preset = None;
    sc.world.seed = None;
    sc.world.params = None;
    sc.world.file = Some("w.toml".into());
    std::fs::write(&scenario, toml::to_string(&sc).unwrap()).unwrap();
    let plan = StudyPlan { scenario, base_seed: 5, runs: 3, methods: vec!["nn".into()], vary: vec![] };
    let out = root.join("study");
    // One thread, so that the edit after the first run falls before the second is recorded.
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let edit = |p: mc::StudyProgress| {
        if let mc::StudyProgress::Runs { done: 1, .. } = p {
            std::fs::write(root.join("w.toml"), world(2)).unwrap();
        }
    };
    let e = one.install(|| mc::run_study(&plan, Shard::all(), &out, edit)).unwrap_err().to_string();
    assert!(e.contains("has changed") && e.contains("the study stopped there"), "{e}");
    let recorded = std::fs::read_to_string(out.join("runs.jsonl")).unwrap();
    assert_eq!(recorded.lines().count(), 1, "only the run before the edit: {recorded}");
    // Restored, the study resumes and finishes on the world it began with.
    std::fs::write(root.join("w.toml"), world(1)).unwrap();
    let all = one.install(|| mc::run_study(&plan, Shard::all(), &out, |_| {})).unwrap();
    assert_eq!(all.len(), 3);
    assert!(all.iter().all(|r| r.error.is_none()), "{:?}", all.iter().map(|r| &r.error).collect::<Vec<_>>());
    let _ = std::fs::remove_dir_all(&root);
}

/// A study's pin covers the mesh files its world draws objects from: a mesh edited during
/// a study changes what the camera sees, so the study must see it as another scenario.
#[test]
fn the_scenario_pin_covers_the_worlds_mesh_files() {
    let dir = std::env::temp_dir().join(format!("objslam-pin-mesh-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut world = worlds::generate::park(&Default::default(), 1).unwrap();
    let mut posts = world.objects.iter().filter(|o| o.class == worlds::ObjectClass::Post);
    let first = posts.next().unwrap().clone();
    let glb = |o: &worlds::StaticObject| worlds::gltf_io::parts_to_glb(&worlds::mesh::object_parts(o));
    std::fs::write(dir.join("post.glb"), glb(&first)).unwrap();
    world.objects.iter_mut().find(|o| o.id == first.id).unwrap().mesh = Some("post.glb".into());
    std::fs::write(dir.join("w.toml"), world.to_toml()).unwrap();
    std::fs::write(dir.join("s.toml"), "name = \"m\"\n[world]\nfile = \"w.toml\"\n[pipeline]\nmethod = \"nn\"\n")
        .unwrap();
    let scenario = dir.join("s.toml").to_string_lossy().into_owned();
    let (pin, _, _) = mc::pin_scenario(&scenario).unwrap();
    assert_eq!(mc::pin_scenario(&scenario).unwrap().0, pin, "the same files give the same pin");
    // A taller post in the same file: the world file itself is unchanged.
    let mut other = first.clone();
    other.shape = match other.shape {
        worlds::Shape::Post { radius_m, height_m } => worlds::Shape::Post { radius_m, height_m: height_m + 0.5 },
        shape => panic!("a post is a post, not {shape:?}"),
    };
    std::fs::write(dir.join("post.glb"), glb(&other)).unwrap();
    let (now, _, _) = mc::pin_scenario(&scenario).unwrap();
    assert_ne!(now.sha256, pin.sha256, "an edited mesh changes the pin");
    assert!(pin.changed_to(&scenario, &now).is_some());
    let _ = std::fs::remove_dir_all(&dir);
}
