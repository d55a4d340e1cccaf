//! A study's plan: the varied parameters, the methods, the jobs they make, the scenario
//! pinned when the study began, and the shards that split the jobs.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::*;

/// One varied parameter: a dotted path into the scenario and its values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Vary {
    pub param: String,
    pub values: Vec<f64>,
}

/// `text` as a count, or why it is none, naming it `what`: a number too large to count
/// is not called "not a whole number", and is told the most it may be, `most`.
fn whole_number(text: &str, what: &str, most: usize) -> Result<usize, String> {
    text.trim().parse().map_err(|e: std::num::ParseIntError| match e.kind() {
        std::num::IntErrorKind::PosOverflow => format!("{what} is too large (at most {most})"),
        _ => format!("{what} is not a whole number"),
    })
}

impl Vary {
    /// Parses `PARAM=A..B:STEPS` (STEPS values evenly spaced from A to B inclusive).
    pub fn parse(spec: &str) -> Result<Vary, StudyError> {
        let bad = |message: &str| StudyError::Vary { spec: spec.into(), message: message.into() };
        let (param, range) = spec.split_once('=').ok_or_else(|| bad("missing '='"))?;
        let (range, steps) = range.split_once(':').ok_or_else(|| bad("missing ':STEPS'"))?;
        let (a, b) = range.split_once("..").ok_or_else(|| bad("missing 'A..B'"))?;
        let a: f64 = a.trim().parse().map_err(|_| bad("A is not a number"))?;
        let b: f64 = b.trim().parse().map_err(|_| bad("B is not a number"))?;
        let steps = whole_number(steps, "STEPS", MAX_VARY_STEPS).map_err(|m| bad(&m))?;
        if steps == 0 || !a.is_finite() || !b.is_finite() || !(b - a).is_finite() {
            return Err(bad("STEPS must be at least 1 and A, B finite (and B - A too)"));
        }
        if steps > MAX_VARY_STEPS {
            return Err(bad(&format!("at most {MAX_VARY_STEPS} steps")));
        }
        if param.trim().is_empty() {
            return Err(bad("empty parameter name"));
        }
        // One value cannot run from A to B: taking A alone would drop B unsaid.
        if steps == 1 && a != b {
            return Err(bad("one step cannot go from A to B: give A..A:1 for one value, or 2 or more steps"));
        }
        // The last value is B itself, not A plus the steps (0.2..1:4 gave
        // 1.0000000000000002, which a setting of at most 1 refused); the others are as
        // they always were, so the job keys of studies begun before stay the same.
        let values =
            (0..steps).map(|i| if i + 1 == steps { b } else { a + (b - a) * i as f64 / (steps - 1) as f64 }).collect();
        Ok(Vary { param: param.trim().into(), values })
    }
}

/// A parameter's value as people read it: twelve significant digits at most, so `0.01`
/// where a range's step gave 0.009999999999999998 (job keys keep the exact value) while
/// distinct settings stay distinct; `1e-7` and `2.5e15` where plain digits would run long.
pub fn short_number(v: f64) -> String {
    let rounded: f64 = format!("{v:.11e}").parse().unwrap_or(v);
    if rounded != 0.0 && !(1e-4..1e15).contains(&rounded.abs()) { format!("{rounded:e}") } else { rounded.to_string() }
}

/// Most values one varied parameter may take.
pub const MAX_VARY_STEPS: usize = 1000;
/// Most jobs a study may plan: each needs its record in memory and a line in runs.jsonl
/// (a million is days of runs on a cluster).
pub const MAX_JOBS: usize = 1_000_000;

/// The plan of a study: everything that determines its jobs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StudyPlan {
    pub scenario: String,
    pub base_seed: u64,
    pub runs: usize,
    pub methods: Vec<String>,
    pub vary: Vec<Vary>,
}

/// What a study's scenario was when the study began, kept in `study.json` beside the plan:
/// a resumed study, a merge of its shards and a rerun of one of its jobs check that the
/// scenario they read is still that one, so that no study mixes runs of two.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScenarioPin {
    /// The scenario file's absolute path (`<built-in>/NAME` for a built-in scenario), so
    /// that a rerun from another directory reads the same file.
    pub file: String,
    /// SHA-256 of the scenario's settings and of the files they name: the world file (as
    /// loaded, its glTF buffers too), the appearance model, the calibration.
    pub sha256: String,
}

impl ScenarioPin {
    /// `None` where `now` (the scenario `named` reads today) is the one this pin was taken
    /// of; else the words of what changed, for each caller to wrap with its own remedy.
    pub fn changed_to(&self, named: &str, now: &ScenarioPin) -> Option<String> {
        (self.sha256 != now.sha256).then(|| {
            if now.file == self.file {
                format!(
                    "the study's scenario {} has changed since the study began (its files or settings differ)",
                    self.file
                )
            } else {
                format!(
                    "the study began with scenario {}, and {named} now reads {}, whose files or settings differ",
                    self.file, now.file
                )
            }
        })
    }
}

/// `study.json`: the plan, and the scenario it was begun with (studies begun before the
/// scenario was recorded have none).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(super) struct StudyFile {
    #[serde(flatten)]
    pub(super) plan: StudyPlan,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(super) scenario_pin: Option<ScenarioPin>,
    /// The build that began the study; runs resumed or merged later may be another's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(super) build: Option<crate::build::Build>,
}

/// [`read_study_file`] of `dir`'s `study.json`, for a command given a study's directory
/// (`merge`, `rerun`): a directory of several studies (the generalisation benchmark's, the
/// built-in study's) is named as such, with where its studies are.
pub(super) fn read_study_dir(dir: &Path) -> Result<StudyFile, StudyError> {
    let file = dir.join("study.json");
    read_study_file(&file, "").map_err(|e| {
        let holds = |names: [&str; 2]| names.iter().any(|n| dir.join(n).join("study.json").is_file());
        let studies = if dir.join(super::BENCHMARK_WORLDS).is_file() || holds(["combined", "jcbb"]) {
            Some("a generalisation benchmark's, whose studies are its combined/ and jcbb/")
        } else if holds(["odometry", "post_distance"]) {
            Some("the built-in study's, whose studies are its odometry/ and post_distance/")
        } else {
            None
        };
        match (&e, studies) {
            (StudyError::Io { source, .. }, Some(studies)) if source.kind() == std::io::ErrorKind::NotFound => {
                StudyError::File {
                    file: dir.into(),
                    message: format!("no study.json: the directory is {studies}; give one of them"),
                }
            }
            _ => e,
        }
    })
}

/// Reads `file`, a `study.json`; `hint` is added to the message where it is not a plan.
pub(super) fn read_study_file(file: &Path, hint: &str) -> Result<StudyFile, StudyError> {
    let bytes = std::fs::read(file).map_err(|e| StudyError::Io { file: file.into(), source: e })?;
    let study: StudyFile = serde_json::from_slice(&bytes)
        .map_err(|e| StudyError::File { file: file.into(), message: format!("not a study plan ({e}){hint}") })?;
    // A plan no study could run (edited by hand) is named by its file, before its runs are
    // read against it.
    study
        .plan
        .check()
        .map_err(|e| StudyError::File { file: file.into(), message: format!("not a plan that can run: {e}{hint}") })?;
    Ok(study)
}

/// Loads the scenario `name_or_path` names (a file, else a built-in one) and pins it: where
/// it was read from, and the digest of what its runs read.
pub fn pin_scenario(name_or_path: &str) -> Result<(ScenarioPin, Scenario, PathBuf), StudyError> {
    use sha2::{Digest, Sha256};
    let (scenario, base_dir) = Scenario::load(name_or_path)?;
    let file = match scenario.built_in() {
        Some(name) => format!("{BUILT_IN_PREFIX}{name}"),
        None => {
            let path = &scenario.source.0;
            std::fs::canonicalize(path)
                .map_err(|e| StudyError::Io { file: path.clone(), source: e })?
                .display()
                .to_string()
        }
    };
    let mut digest = Sha256::new();
    // Words for people only: a mended description changes no run.
    let settings = Scenario { description: String::new(), ..scenario.clone() };
    digest.update(serde_json::to_string(&settings).expect("a scenario is JSON").as_bytes());
    if scenario.world.file.is_some() {
        // As loaded, so that a glTF world's buffers count; a file world ignores the seed.
        let world = scenario.world(&base_dir, 0)?;
        digest.update(serde_json::to_string(&world).expect("a world is JSON").as_bytes());
        // The JSON names an object's mesh file; what the camera draws is the triangles read.
        for mesh in world.objects.iter().filter_map(|o| o.mesh_data.0.as_deref()) {
            digest_mesh(&mut digest, mesh);
        }
    }
    let calibration_file = scenario.calibration_file();
    for named in [scenario.appearance.model.as_deref(), calibration_file].into_iter().flatten() {
        // One that cannot be read is the runs' error to report, in their own words.
        match std::fs::read(base_dir.join(named)) {
            Ok(bytes) => digest.update(Sha256::digest(&bytes)),
            Err(e) => digest.update(format!("unreadable: {:?}", e.kind()).as_bytes()),
        }
    }
    let sha256 = digest.finalize().iter().map(|b| format!("{b:02x}")).collect();
    Ok((ScenarioPin { file, sha256 }, scenario, base_dir))
}

/// Feeds `mesh`'s vertices and triangles to `digest`, so that a mesh file edited under a
/// study changes its pin.
fn digest_mesh(digest: &mut sha2::Sha256, mesh: &worlds::mesh::TriMesh) {
    use sha2::Digest;
    for len in [mesh.positions.len(), mesh.normals.len(), mesh.uvs.len(), mesh.indices.len()] {
        digest.update((len as u64).to_le_bytes());
    }
    for v in mesh.positions.iter().chain(&mesh.normals) {
        v.iter().for_each(|x| digest.update(x.to_le_bytes()));
    }
    for uv in &mesh.uvs {
        uv.iter().for_each(|x| digest.update(x.to_le_bytes()));
    }
    mesh.indices.iter().for_each(|i| digest.update(i.to_le_bytes()));
}

/// Loads the scenario of a study whose `study.json` is `plan_file`: from the file it was
/// begun with where that was recorded (so that the study's directory, not the working
/// directory, decides), or from `moved_to` where the user says it went, checked to be
/// unchanged.
pub(super) fn pinned_scenario(
    plan_file: &Path,
    study: &StudyFile,
    moved_to: Option<&str>,
) -> Result<(Scenario, PathBuf), StudyError> {
    let Some(pin) = &study.scenario_pin else {
        if moved_to.is_some() {
            return Err(StudyError::File {
                file: plan_file.into(),
                message: "this study began before studies recorded their scenario, so a --scenario given cannot be checked to be its own: rerun from the directory it began in, without --scenario".into(),
            });
        }
        return Scenario::load(&study.plan.scenario).map_err(|e| StudyError::File {
            file: plan_file.into(),
            message: format!("{e} (this study began before studies recorded their scenario: its scenario is read from the working directory, so rerun from the directory it began in)"),
        });
    };
    let built_in = pin.file.starts_with(BUILT_IN_PREFIX);
    let source = match moved_to {
        Some(file) => file,
        // The built-in itself, not a file of its name in the working directory.
        None if built_in => pin.file.as_str(),
        None if !Path::new(&pin.file).exists() => {
            return Err(StudyError::File {
                file: plan_file.into(),
                message: format!(
                    "the study's scenario {} is not there any more: give where it is now with --scenario FILE",
                    pin.file
                ),
            });
        }
        None => pin.file.as_str(),
    };
    let (now, scenario, base_dir) = pin_scenario(source)?;
    if let Some(changed) = pin.changed_to(source, &now) {
        let remedy = match moved_to {
            Some(_) => {
                "give the study's own scenario file to --scenario, with the files it names by relative path moved with it to the same places beside it"
            }
            None => "restore it, or give a copy of the study's own scenario with --scenario FILE",
        };
        return Err(StudyError::File {
            file: plan_file.into(),
            message: format!("{changed}, so its runs would not be the study's: {remedy}"),
        });
    }
    Ok((scenario, base_dir))
}

/// The built-in study of the paper's argument on `paper_park`, as (name, plan) pairs: the
/// association-failure rate of the combined method and the position-only baselines against
/// odometry heading drift (the simulator's per-run heading bias, 0 to 5x its default:
/// position-only association is expected to fail as the pose grows uncertain) and against
/// the distance of the look-alike posts from their trees (0.5 to 3 m, centre to centre:
/// the nearer, the more a position gate confuses them).
pub fn builtin_study(runs: usize, base_seed: u64) -> Vec<(&'static str, StudyPlan)> {
    let methods: Vec<String> = ["combined", "nn", "jcbb"].iter().map(|m| m.to_string()).collect();
    let plan = |param: &str, values: Vec<f64>| StudyPlan {
        scenario: "paper_park".into(),
        base_seed,
        runs,
        methods: methods.clone(),
        vary: vec![Vary { param: param.into(), values }],
    };
    vec![
        ("odometry", plan("sim.odometry.bias_sigma_rad_per_m", vec![0.0, 0.002, 0.005, 0.01])),
        ("post_distance", plan("world.params.post_distance_m", vec![0.5, 1.0, 2.0, 3.0])),
    ]
}

/// One job of a study.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Job {
    /// Position in the study's full job list.
    pub index: usize,
    pub method: String,
    /// (parameter, value) for each varied parameter.
    pub params: Vec<(String, f64)>,
    pub run: usize,
    pub seed: u64,
}

impl Job {
    /// The index of the first job of this one's setting (method and parameter values): the
    /// runs of one setting are consecutive jobs.
    pub fn setting(&self) -> usize {
        self.index - self.run
    }

    /// Stable identity of a job across processes and shards.
    pub fn key(&self) -> String {
        let params: Vec<String> = self.params.iter().map(|(p, v)| format!("{p}={v}")).collect();
        format!("method={};{};run={}", self.method, params.join(";"), self.run)
    }
}

impl StudyPlan {
    /// Whether the plan can run: runs and methods given, methods known and not repeated,
    /// and not more jobs than [`MAX_JOBS`] (checked before any is made).
    pub fn check(&self) -> Result<(), StudyError> {
        let bad = |message: String| StudyError::Plan(message);
        if self.runs == 0 {
            return Err(bad("--runs must be at least 1".into()));
        }
        if self.methods.is_empty() {
            return Err(bad("no method given (--methods combined,nn,jcbb,appearance)".into()));
        }
        for (i, m) in self.methods.iter().enumerate() {
            if AssociationMethod::from_name(m).is_none() {
                return Err(bad(format!("unknown method {m:?}; use combined, nn, jcbb or appearance")));
            }
            if self.methods[..i].contains(m) {
                return Err(bad(format!("method {m:?} given twice")));
            }
        }
        for (i, v) in self.vary.iter().enumerate() {
            if self.vary[..i].iter().any(|w| todays_spelling(&w.param) == todays_spelling(&v.param)) {
                return Err(bad(format!("--vary {} given twice (one --vary per parameter)", v.param)));
            }
            // Jobs are known by their values: two equal ones would be one job run twice.
            if let Some(x) = v.values.iter().enumerate().find_map(|(k, x)| v.values[..k].contains(x).then_some(x)) {
                return Err(bad(format!(
                    "--vary {}: the value {x} comes twice (a range of one value takes :1)",
                    v.param
                )));
            }
        }
        let jobs = self
            .vary
            .iter()
            .try_fold(self.runs.saturating_mul(self.methods.len()), |n, v| n.checked_mul(v.values.len()));
        match jobs {
            Some(n) if n <= MAX_JOBS => Ok(()),
            _ => Err(bad(format!("more than {MAX_JOBS} runs planned; split the study"))),
        }
    }
}

/// Every job of a plan, in order: parameter values (outer), methods, then runs (inner).
pub fn jobs(plan: &StudyPlan) -> Vec<Job> {
    let mut combos: Vec<Vec<(String, f64)>> = vec![vec![]];
    for v in &plan.vary {
        combos = combos
            .into_iter()
            .flat_map(|c| {
                v.values.iter().map(move |x| {
                    let mut c = c.clone();
                    c.push((v.param.clone(), *x));
                    c
                })
            })
            .collect();
    }
    let mut out = Vec::new();
    for params in &combos {
        for method in &plan.methods {
            for run in 0..plan.runs {
                out.push(Job {
                    index: out.len(),
                    method: method.clone(),
                    params: params.clone(),
                    run,
                    seed: sim::derive_seed(plan.base_seed, &format!("run-{run}")),
                });
            }
        }
    }
    out
}

/// Refuses a plan that varies a setting none of its methods reads (or `base` makes unread):
/// every value's runs would be alike.
pub(super) fn check_varied_settings_are_read(plan: &StudyPlan, base: &Scenario) -> Result<(), StudyError> {
    // Settings that only a method reading the camera uses: the position-only methods run
    // without the camera, its calibration, segmentation, evidence and object models, and
    // train no appearance model.
    const CAMERA_ONLY: [&str; 7] = [
        "appearance.",
        "sim.camera.",
        "calibration.",
        "pipeline.segmentation.",
        "pipeline.evidence.",
        "pipeline.object_model.",
        "pipeline.image_max_age_s",
    ];
    // The combined method's alone: its joint loop closing, the relinearisation after it,
    // and its deferral of look-alikes.
    const COMBINED_ONLY: [&str; 5] = [
        "pipeline.joint_loop_closing",
        "pipeline.joint_loop_free_space",
        "pipeline.defer_near_lookalike",
        "pipeline.relinearise_loop_closures",
        "pipeline.relinearise_every_s",
    ];
    let methods: Vec<slam::association::AssociationMethod> = if plan.methods.is_empty() {
        vec![base.pipeline.method]
    } else {
        plan.methods.iter().filter_map(|m| slam::association::AssociationMethod::from_name(m)).collect()
    };
    let names: Vec<&str> = methods.iter().map(|m| m.name()).collect();
    let camera_method = methods.iter().any(|m| m.uses_appearance());
    let unread = |param: &str, why: String| {
        StudyError::Plan(format!("--vary {param}: {why}, so every value's runs would be alike; vary another setting"))
    };
    for v in &plan.vary {
        let p = v.param.as_str();
        if CAMERA_ONLY.iter().any(|prefix| p.starts_with(prefix)) && !camera_method {
            return Err(unread(
                p,
                format!(
                    "no method of the study ({}) reads the camera (add a camera method: --methods combined,...)",
                    names.join(", ")
                ),
            ));
        }
        if COMBINED_ONLY.iter().any(|prefix| p.starts_with(prefix))
            && !methods.contains(&slam::association::AssociationMethod::Combined)
        {
            return Err(unread(
                p,
                format!("only the combined method reads it, and the study runs {}", names.join(", ")),
            ));
        }
        // JCBB's joint test: the jcbb method's, and the combined method's joint loop closing.
        if p == "pipeline.jcbb_probability" {
            use slam::association::AssociationMethod::{Combined, Jcbb};
            let combined_closes = methods.contains(&Combined) && base.pipeline.joint_loop_closing;
            if !methods.contains(&Jcbb) && !combined_closes {
                return Err(unread(
                    p,
                    format!(
                        "only the jcbb method and the combined method's joint loop closing read it, and the study runs {}{}",
                        names.join(", "),
                        if methods.contains(&Combined) { " with pipeline.joint_loop_closing = false" } else { "" }
                    ),
                ));
            }
        }
        if p.starts_with("calibration.session.") && base.calibration.mode != "estimated" {
            return Err(unread(
                p,
                format!(
                    "the calibration session runs only with calibration mode \"estimated\", and this scenario's is \"{}\"",
                    base.calibration.mode
                ),
            ));
        }
        if p.starts_with("pipeline.diameter.") && !camera_method && !base.pipeline.diameter.for_position_methods {
            return Err(unread(
                p,
                format!(
                    "the study's methods ({}) use the trunk diameter only with pipeline.diameter.for_position_methods = true",
                    names.join(", ")
                ),
            ));
        }
    }
    Ok(())
}

/// Refuses a plan two of whose values of one parameter give `base` the same settings: a
/// whole-number setting takes 5.000000001 as 5 (to rounding in a range's steps), so
/// values that differ as typed could be one job run twice under two keys. A value the
/// scenario refuses is left to the check of each job, which names it.
pub(super) fn check_values_differ(plan: &StudyPlan, base: &Scenario) -> Result<(), StudyError> {
    // Tables and plots name a value by twelve significant digits: two values that differ only
    // beyond them would read as one setting, and share a plot's series.
    for v in &plan.vary {
        let mut labels: BTreeMap<String, f64> = BTreeMap::new();
        for &x in &v.values {
            if let Some(first) = labels.insert(short_number(x), x) {
                return Err(StudyError::Plan(format!(
                    "--vary {}: the values {first} and {x} differ only beyond twelve significant digits, so tables and plots would show them as one ({}); give values that differ more",
                    v.param,
                    short_number(x)
                )));
            }
        }
    }
    for v in &plan.vary {
        let mut seen: BTreeMap<String, f64> = BTreeMap::new();
        for &x in &v.values {
            let Ok(scenario) = apply_param(base, &v.param, x) else { continue };
            let settings = serde_json::to_string(&scenario).map_err(|e| StudyError::Plan(e.to_string()))?;
            if let Some(first) = seen.insert(settings, x) {
                return Err(StudyError::Plan(format!(
                    "--vary {}: the values {first} and {x} set it alike (a whole-number setting takes the nearest whole number), so their runs would be one job run twice; give values that differ by a whole number",
                    v.param
                )));
            }
        }
    }
    Ok(())
}

/// Sets a dotted path (`sim.odometry.scale_sigma`) in the scenario to `value`. A 2-element
/// range (such as `world.params.post_distance_m`) is set to `[value, value]`. The
/// generalisation benchmark's world parameters (`generalisation.test_world`, ...) replace the
/// whole world (preset, seed and parameters) by a drawn one, so a study should not vary
/// `world.*` beside them.
pub fn apply_param(scenario: &Scenario, path: &str, value: f64) -> Result<Scenario, StudyError> {
    if let Some(split) = generalisation::Split::of_param(path) {
        return generalisation::with_world(scenario, split, value);
    }
    let bad = |message: String| StudyError::VaryValue { spec: format!("{path}={value}"), message };
    // Each run's seed comes from the study's --seed and the run's index: a varied one
    // would change nothing.
    if path == "seed" {
        return Err(bad("each run's seed is derived from --seed and the run; vary world.seed, or a setting".into()));
    }
    // Spell out the generator's defaults so a parameter the scenario left out has its type.
    let mut scenario = scenario.clone();
    if path.starts_with("world.params.") && scenario.world.params.is_none() && scenario.world.preset.is_some() {
        scenario.world.params = Some(Default::default());
    }
    let path = todays_spelling(path);
    if !Scenario::is_setting(&path) {
        return Err(StudyError::VaryValue {
            spec: path,
            message: "no such setting (`objslam config defaults` prints every setting of a scenario)".into(),
        });
    }
    let root = toml::Value::try_from(&scenario).map_err(|e| bad(e.to_string()))?;
    let parts: Vec<&str> = path.split('.').collect();
    let with = |new_integer: bool| {
        let mut root = root.clone();
        set_path(&mut root, &parts, value, new_integer).map_err(&bad)?;
        let text = toml::to_string(&root).map_err(|e| bad(e.to_string()))?;
        // The text is generated, so a line of it would point into no file the user has.
        Scenario::parse(&text, Path::new(&format!("{}[{path}={value}]", scenario.name))).map_err(|e| match e {
            crate::scenario::ScenarioError::Invalid { file, field, message, .. } => {
                bad(crate::scenario::ScenarioError::Invalid { file, line: None, field, message }.to_string())
            }
            // The TOML reader's rendering quotes the generated text; its last line says what
            // is wrong with the value (e.g. "invalid value: integer `-1`, expected u64").
            crate::scenario::ScenarioError::Parse { message, .. } => {
                bad(message.lines().rev().find(|l| !l.trim().is_empty()).unwrap_or_default().trim().to_string())
            }
            other => bad(other.to_string()),
        })
    };
    // A setting the scenario leaves out has no type to follow: a number, unless only a
    // whole one will do (a count the scenario did not set). Where the whole number is
    // refused too, its reason is the one to give: the first attempt's is only that a
    // count is no float.
    with(false).or_else(|e| if value.fract() == 0.0 && value.abs() < 9.2e18 { with(true) } else { Err(e) })
}

/// A parameter's path under today's spelling: a key read under a former spelling is
/// written under today's (studies planned with the former resume).
pub(super) fn todays_spelling(path: &str) -> String {
    let former = path
        .strip_prefix("sim.odometry.")
        .and_then(|key| sim::OdometryConfig::FORMER_SPELLINGS.iter().find(|(old, _)| *old == key).map(|(_, new)| *new));
    former.map_or_else(|| path.to_string(), |new| format!("sim.odometry.{new}"))
}

/// Sets the number at `parts` to `value`, in the type of the value there; one not there
/// is added as a float, or as an integer with `new_integer`.
pub(super) fn set_path(node: &mut toml::Value, parts: &[&str], value: f64, new_integer: bool) -> Result<(), String> {
    let table = node.as_table_mut().ok_or_else(|| format!("{} is not a table", parts[0]))?;
    if parts.len() == 1 {
        let new = match table.get(parts[0]) {
            Some(toml::Value::Array(a)) if a.len() == 2 => {
                toml::Value::Array(vec![toml::Value::Float(value), toml::Value::Float(value)])
            }
            // A whole-number setting takes whole numbers (to rounding in the range's steps).
            Some(toml::Value::Integer(_)) if (value - value.round()).abs() > 1e-9 * value.abs().max(1.0) => {
                return Err(format!("{} takes whole numbers, not {value}", parts[0]));
            }
            // Past i64 the conversion would saturate: every such value the same setting.
            Some(toml::Value::Integer(_)) if !(value.round().abs() < 9.2e18) => {
                return Err(format!("{} takes whole numbers within 9.2e18, not {value}", parts[0]));
            }
            Some(toml::Value::Integer(_)) => toml::Value::Integer(value.round() as i64),
            None if new_integer => toml::Value::Integer(value as i64),
            Some(toml::Value::Float(_)) | None => toml::Value::Float(value),
            Some(other) => {
                let kind = other.type_str();
                let article = if kind.starts_with(['a', 'e', 'i', 'o', 'u']) { "an" } else { "a" };
                return Err(format!("{} is {article} {kind}, not a number", parts[0]));
            }
        };
        table.insert(parts[0].to_string(), new);
        return Ok(());
    }
    let child = table.entry(parts[0].to_string()).or_insert_with(|| toml::Value::Table(Default::default()));
    set_path(child, &parts[1..], value, new_integer).map_err(|m| format!("{}.{m}", parts[0]))
}

/// Which slice of the jobs this process runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl Shard {
    pub fn all() -> Self {
        Shard { index: 0, count: 1 }
    }

    pub fn parse(spec: &str) -> Result<Shard, StudyError> {
        let bad = |message: &str| StudyError::Shard { spec: spec.into(), message: message.into() };
        let (k, n) = spec.split_once('/').ok_or_else(|| bad("missing '/'"))?;
        let index = whole_number(k, "K", usize::MAX).map_err(|m| bad(&m))?;
        let count = whole_number(n, "N", usize::MAX).map_err(|m| bad(&m))?;
        Shard::numbered(index, count).map_err(|m| bad(&m))
    }

    /// Shard `index` of `count`, or why there is none (the one bounds check of
    /// [`Shard::parse`] and [`Shard::from_env`]).
    fn numbered(index: usize, count: usize) -> Result<Shard, String> {
        match count {
            0 => Err("no shards to run (a count of 0)".into()),
            _ if index >= count => {
                Err(format!("makes shard {index} of {count}, and shards are numbered 0 to {}", count - 1))
            }
            _ => Ok(Shard { index, count }),
        }
    }

    /// The shard from a batch scheduler's environment: Slurm job arrays
    /// (`SLURM_ARRAY_TASK_ID`, `SLURM_ARRAY_TASK_MIN`, `SLURM_ARRAY_TASK_COUNT`) or
    /// Kubernetes Indexed Jobs (`JOB_COMPLETION_INDEX`, with the count from `count`).
    pub fn from_env(env: impl Fn(&str) -> Option<String>, count: Option<usize>) -> Result<Option<Shard>, StudyError> {
        let num = |name: &str| -> Result<Option<usize>, StudyError> {
            env(name)
                .map(|v| {
                    whole_number(&v, "the value", usize::MAX)
                        .map_err(|message| StudyError::ShardEnv { spec: format!("{name}={v}"), message })
                })
                .transpose()
        };
        let shard = |index: usize, count: usize, spec: String| {
            Shard::numbered(index, count).map(Some).map_err(|message| StudyError::ShardEnv { spec, message })
        };
        if let Some(id) = num("SLURM_ARRAY_TASK_ID")? {
            let bad = |message: String| StudyError::ShardEnv { spec: format!("SLURM_ARRAY_TASK_ID={id}"), message };
            let min = num("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
            // A stepped array (--array=0-8:2) numbers its tasks min, min + step, ...
            let step = num("SLURM_ARRAY_TASK_STEP")?.unwrap_or(1).max(1);
            let from_env = num("SLURM_ARRAY_TASK_COUNT")?;
            let n = from_env.or(count).ok_or_else(|| bad("no SLURM_ARRAY_TASK_COUNT and no --shard-count".into()))?;
            if id < min || (id - min) % step != 0 {
                return Err(bad(format!("not a task of the array from SLURM_ARRAY_TASK_MIN={min} in steps of {step}")));
            }
            let of =
                if from_env.is_some() { format!("SLURM_ARRAY_TASK_COUNT={n}") } else { format!("--shard-count {n}") };
            return shard((id - min) / step, n, format!("SLURM_ARRAY_TASK_ID={id} with {of}"));
        }
        if let Some(id) = num("JOB_COMPLETION_INDEX")? {
            let n = count.ok_or_else(|| StudyError::ShardEnv {
                spec: format!("JOB_COMPLETION_INDEX={id}"),
                message: format!(
                    "Kubernetes does not say how many indexes there are: give --shard {id}/N (N the Job's completions), or --shard-count N for a study of one scenario"
                ),
            })?;
            return shard(id, n, format!("JOB_COMPLETION_INDEX={id} with --shard-count {n}"));
        }
        if let Some(n) = count {
            return Err(StudyError::ShardEnv {
                spec: format!("--shard-count {n}"),
                message: "goes with a scheduler's index (JOB_COMPLETION_INDEX or SLURM_ARRAY_TASK_ID), and there is none: give --shard K/N".into(),
            });
        }
        Ok(None)
    }

    pub fn contains(&self, job: &Job) -> bool {
        job.index % self.count == self.index
    }
}
