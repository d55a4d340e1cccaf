//! Monte Carlo studies of association failures: many seeded runs per method and parameter
//! value, in parallel, resumable, fault-isolated and shardable across batch schedulers.
//!
//! A study is an ordered list of jobs (parameter values x methods x run index). Run `r`
//! gets seed `derive(base seed, r)` whatever the method and parameter values (common random
//! numbers make the comparison sharper), so a study gives the same results however it is
//! split into shards. Each finished run is appended to `runs.jsonl` as one line written in
//! one call; a study started again skips the jobs already there, and a truncated last line
//! (a killed process) is dropped. Once its runs are done the file is put in job order, so
//! that it does not depend on how many workers ran them.

use std::collections::{BTreeMap, BTreeSet};
use std::fs::OpenOptions;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use slam::association::AssociationMethod;

use crate::run::{Metrics, RunOptions};
use crate::scenario::{BUILT_IN_PREFIX, Scenario};
use crate::score::wilson_interval;

pub mod generalisation;
mod workers;
pub use workers::serve_worker;

/// Errors of a study.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    #[error("--vary {spec:?}: {message} (expected PARAM=A..B:STEPS, e.g. sim.odometry.scale_sigma=0.0..0.05:6)")]
    Vary { spec: String, message: String },
    /// A `--vary` well written whose value the scenario cannot take.
    #[error("--vary {spec:?}: {message}")]
    VaryValue { spec: String, message: String },
    #[error("--shard {spec:?}: {message} (expected K/N with 0 <= K < N)")]
    Shard { spec: String, message: String },
    /// A shard a scheduler's environment (or `--shard-count`) gave: `spec` says which
    /// variables or flag, since the user typed no `--shard`.
    #[error("{spec}: {message}")]
    ShardEnv { spec: String, message: String },
    #[error("{}: {message}", file.display())]
    File { file: PathBuf, message: String },
    #[error("{}: {source}", file.display())]
    Io { file: PathBuf, source: std::io::Error },
    #[error("{}: this directory's study.json holds a different study ({message}); use a new --out directory", dir.display())]
    Mismatch { dir: PathBuf, message: String },
    #[error(
        "{}: holds a generalisation benchmark (worlds.json; its studies are in combined/ and jcbb/), whose report a study's summary would replace; use a new --out directory",
        .0.display()
    )]
    Benchmark(PathBuf),
    #[error(transparent)]
    Scenario(#[from] crate::scenario::ScenarioError),
    #[error(transparent)]
    Plot(#[from] crate::plot::PlotError),
    /// An appearance model the jobs need could not be loaded or trained.
    #[error(transparent)]
    Appearance(Box<crate::run::RunError>),
    #[error("{0}")]
    Worker(String),
    #[error("{}: another study is running in this directory, or another objslam command writes into it; wait for it, or use another --out", file.display())]
    Locked { file: PathBuf },
    #[error("job {key}: {message}")]
    Job { key: String, message: String },
    /// A plan that cannot run, or a study that cannot go on (its scenario changed).
    #[error("{0}")]
    Plan(String),
    #[error("{}: {count} finished runs could not be appended ({message}); they are not in the file: run the same command again to redo them", file.display())]
    Append { file: PathBuf, count: usize, message: String },
}

/// One varied parameter: a dotted path into the scenario and its values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Vary {
    pub param: String,
    pub values: Vec<f64>,
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
        let steps: usize = steps.trim().parse().map_err(|_| bad("STEPS is not a whole number"))?;
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
    pub(crate) fn changed_to(&self, named: &str, now: &ScenarioPin) -> Option<String> {
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
struct StudyFile {
    #[serde(flatten)]
    plan: StudyPlan,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    scenario_pin: Option<ScenarioPin>,
    /// The build that began the study; runs resumed or merged later may be another's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    build: Option<crate::build::Build>,
}

/// Reads `file`, a `study.json`; `hint` is added to the message where it is not a plan.
fn read_study_file(file: &Path, hint: &str) -> Result<StudyFile, StudyError> {
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

/// Loads the scenario of a study whose `study.json` is `plan_file`: from the file it was
/// begun with where that was recorded (so that the study's directory, not the working
/// directory, decides), or from `moved_to` where the user says it went, checked to be
/// unchanged.
fn pinned_scenario(
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

/// One line of `runs.jsonl`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    pub key: String,
    pub job: Job,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub metrics: Option<Metrics>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// The run ended through the infrastructure (its worker process died or could not
    /// start), not through the run itself: a resumed study runs it again.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub retryable: bool,
    /// The build that made the run (none in records of older builds and of runs to
    /// retry): a study resumed or merged after a rebuild holds runs of several.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub build: Option<crate::build::Build>,
}

impl RunRecord {
    /// The record with its metrics' wall-clock figures zeroed and without its build: what
    /// must be identical however and wherever the run was made.
    pub fn without_wall_clock(&self) -> RunRecord {
        RunRecord { metrics: self.metrics.as_ref().map(|m| m.without_wall_clock()), build: None, ..self.clone() }
    }

    /// Whether the record is one a study could have written: a run's metrics or its error,
    /// never both or neither, only an error to retry, and a recall that is a fraction.
    fn check(&self) -> Result<(), String> {
        match (&self.metrics, &self.error) {
            (Some(_), Some(_)) => return Err("a run record with both metrics and an error".into()),
            (None, None) => return Err("a run record with neither metrics nor an error".into()),
            (Some(_), None) if self.retryable => return Err("a run to retry that has metrics".into()),
            _ => {}
        }
        if let Some(r) = self.metrics.as_ref().and_then(|m| m.map.tree_recall)
            && !(0.0..=1.0).contains(&r)
        {
            return Err(format!("map.tree_recall {r} is not a fraction"));
        }
        Ok(())
    }

    /// An association failure: one or more wrong associations or false landmarks.
    pub fn failed_association(&self) -> Option<bool> {
        self.metrics.as_ref().map(|m| m.associations.wrong > 0 || m.false_landmarks > 0)
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

/// Refuses a plan two of whose values of one parameter give `base` the same settings: a
/// whole-number setting takes 5.000000001 as 5 (to rounding in a range's steps), so
/// values that differ as typed could be one job run twice under two keys. A value the
/// scenario refuses is left to the check of each job, which names it.
fn check_values_differ(plan: &StudyPlan, base: &Scenario) -> Result<(), StudyError> {
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
        Scenario::parse(&text, Path::new(&format!("{}[{path}={value}]", scenario.name))).map_err(|e| bad(e.to_string()))
    };
    // A setting the scenario leaves out has no type to follow: a number, unless only a
    // whole one will do (a count the scenario did not set). Where the whole number is
    // refused too, its reason is the one to give: the first attempt's is only that a
    // count is no float.
    with(false).or_else(|e| if value.fract() == 0.0 && value.abs() < 9.2e18 { with(true) } else { Err(e) })
}

/// A parameter's path under today's spelling: a key read under a former spelling is
/// written under today's (studies planned with the former resume).
fn todays_spelling(path: &str) -> String {
    let former = path
        .strip_prefix("sim.odometry.")
        .and_then(|key| sim::OdometryConfig::FORMER_SPELLINGS.iter().find(|(old, _)| *old == key).map(|(_, new)| *new));
    former.map_or_else(|| path.to_string(), |new| format!("sim.odometry.{new}"))
}

/// Sets the number at `parts` to `value`, in the type of the value there; one not there
/// is added as a float, or as an integer with `new_integer`.
fn set_path(node: &mut toml::Value, parts: &[&str], value: f64, new_integer: bool) -> Result<(), String> {
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
            Some(other) => return Err(format!("{} is a {}, not a number", parts[0], other.type_str())),
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
        let index: usize = k.trim().parse().map_err(|_| bad("K is not a whole number"))?;
        let count: usize = n.trim().parse().map_err(|_| bad("N is not a whole number"))?;
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
                    v.trim().parse::<usize>().map_err(|_| StudyError::ShardEnv {
                        spec: format!("{name}={v}"),
                        message: "not a whole number".into(),
                    })
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

/// Reads `runs.jsonl`, dropping a truncated last line (and truncating the file to the last
/// complete line so appends start clean). A job recorded twice keeps one record: a final
/// record wins over a retryable one, the later retryable one over an earlier; two final
/// records that differ (wall clock aside) are an error naming both lines.
pub fn read_runs(path: &Path) -> Result<Vec<RunRecord>, StudyError> {
    Ok(one_record_per_job(path, read_run_lines(path)?)?.into_iter().map(|(_, r)| r).collect())
}

/// `records` (line, record) of the file `path` with one record per job, as [`read_runs`]
/// keeps them, each with its line.
fn one_record_per_job(path: &Path, records: Vec<(usize, RunRecord)>) -> Result<Vec<(usize, RunRecord)>, StudyError> {
    let mut kept: Vec<(usize, RunRecord)> = Vec::new();
    let mut by_key: BTreeMap<String, usize> = BTreeMap::new();
    for (line, record) in records {
        match by_key.get(&record.key) {
            None => {
                by_key.insert(record.key.clone(), kept.len());
                kept.push((line, record));
            }
            Some(&i) => {
                let (first_line, first) = &kept[i];
                if first.retryable {
                    kept[i] = (line, record);
                } else if !record.retryable && first.without_wall_clock() != record.without_wall_clock() {
                    return Err(StudyError::File {
                        file: path.into(),
                        message: format!(
                            "lines {first_line} and {line} record job {} differently; remove the one that is wrong",
                            record.key
                        ),
                    });
                }
            }
        }
    }
    Ok(kept)
}

/// The records of `runs.jsonl` with their line numbers, repairing a torn last line.
fn read_run_lines(path: &Path) -> Result<Vec<(usize, RunRecord)>, StudyError> {
    let (complete, torn) = complete_lines(path)?;
    if torn {
        let f =
            OpenOptions::new().write(true).open(path).map_err(|e| StudyError::Io { file: path.into(), source: e })?;
        f.set_len(complete.len() as u64).map_err(|e| StudyError::Io { file: path.into(), source: e })?;
    }
    parse_run_lines(path, &complete)
}

/// The text of `path` up to its last newline (empty if there is none or no file), and
/// whether more (a line being written, or torn by a crash) follows it.
fn complete_lines(path: &Path) -> Result<(String, bool), StudyError> {
    let mut bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok((String::new(), false)),
        Err(e) => return Err(StudyError::Io { file: path.into(), source: e }),
    };
    let length = bytes.len();
    bytes.truncate(bytes.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1));
    let torn = bytes.len() != length;
    let text = String::from_utf8(bytes).map_err(|e| {
        let valid = e.utf8_error().valid_up_to();
        let line = e.as_bytes()[..valid].iter().filter(|&&b| b == b'\n').count() + 1;
        StudyError::File {
            file: path.into(),
            message: format!("line {line}: not UTF-8 text; remove the line to go on"),
        }
    })?;
    Ok((text, torn))
}

/// The records of the complete lines `complete` of `path`, with their line numbers.
fn parse_run_lines(path: &Path, complete: &str) -> Result<Vec<(usize, RunRecord)>, StudyError> {
    complete
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            let bad = |problem: String| StudyError::File {
                file: path.into(),
                message: format!("line {}: {problem}; remove the line to go on", i + 1),
            };
            let r: RunRecord = serde_json::from_str(l).map_err(|e| bad(format!("not a run record ({e})")))?;
            r.check().map_err(bad)?;
            Ok((i + 1, r))
        })
        .collect()
}

/// Writes `text` to `file` whole or not at all (see [`crate::partial_files::write_whole`]).
pub fn write_atomically(file: &Path, text: &str) -> Result<(), StudyError> {
    crate::partial_files::write_whole(file, text.as_bytes())
        .map_err(|e| StudyError::Io { file: e.file, source: e.source })
}

/// Rewrites `runs.jsonl` at `path` with its lines in job order (a job's lines keeping
/// their order), where they are not already: runs are appended as they finish, in an order
/// that depends on how many workers ran them, and a study's files are to be the same
/// whatever ran it. Done by the study that holds the directory, after its last append.
fn put_in_job_order(path: &Path) -> Result<(), StudyError> {
    let (text, _) = complete_lines(path)?;
    let records = parse_run_lines(path, &text)?;
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    let mut order: Vec<(usize, &str)> = records.iter().map(|(_, r)| r.job.index).zip(lines).collect();
    if order.is_sorted_by_key(|(index, _)| *index) {
        return Ok(());
    }
    order.sort_by_key(|(index, _)| *index);
    write_atomically(path, &order.iter().map(|(_, line)| format!("{line}\n")).collect::<String>())
}

/// Appends one record as a whole line and syncs it; on failure the file is cut back to its
/// length before the write, so no torn line is left for the next record to join.
fn append_record(f: &mut std::fs::File, record: &RunRecord) -> std::io::Result<()> {
    let line = serde_json::to_string(record).expect("JSON") + "\n";
    let before = f.metadata()?.len();
    let written = f.write_all(line.as_bytes()).and_then(|_| f.sync_data());
    if written.is_err() {
        let _ = f.set_len(before);
    }
    written
}

/// Where a study's runs execute.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Workers {
    /// On rayon's threads in this process.
    Threads,
    /// In `count` child processes of `exe`, which must be the `objslam` binary (it serves
    /// jobs with its hidden `montecarlo-worker` command, see [`serve_worker`]). Runs in
    /// one process share the software renderer's locks: 8 `paper_park` runs on 2 cores
    /// took 63 s on threads and 49 s in two processes. A child that dies costs only the
    /// run it had, recorded as an error with the end of its stderr; so does one that takes
    /// longer than `run_timeout` over a run (`None`: no limit), which is killed. Both are
    /// retried when the study resumes.
    Processes { exe: PathBuf, count: usize, run_timeout: Option<std::time::Duration> },
}

/// What a study tells its caller while it goes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StudyProgress<'a> {
    /// An appearance model the jobs need is being trained (before the first run): a
    /// stage, and how far it has come.
    Training { stage: &'a str, done: usize, total: usize },
    /// Runs of this shard finished (those of earlier starts included), of its total.
    Runs { done: usize, total: usize },
}

/// Runs (the remaining jobs of) a study into `out` on this process's threads. See
/// [`run_study_with`].
pub fn run_study(
    plan: &StudyPlan,
    shard: Shard,
    out: &Path,
    progress: impl Fn(StudyProgress) + Sync,
) -> Result<Vec<RunRecord>, StudyError> {
    run_study_with(plan, shard, out, &Workers::Threads, progress)
}

/// Runs (the remaining jobs of) a study into `out` on `workers`, then writes its summary
/// ([`write_summary`]) there. `progress` hears of trainings and of runs as they finish.
/// Returns every record of this shard's jobs.
pub fn run_study_with(
    plan: &StudyPlan,
    shard: Shard,
    out: &Path,
    workers: &Workers,
    progress: impl Fn(StudyProgress) + Sync,
) -> Result<Vec<RunRecord>, StudyError> {
    plan.check()?;
    // One study at a time per directory, as for any output directory: the hold goes with
    // the process, however it ends.
    let held = hold(out)?;
    let plan_file = out.join("study.json");
    let (pin, base_scenario, base_dir) = pin_scenario(&plan.scenario)?;
    check_values_differ(plan, &base_scenario)?;
    if !existing_study(plan, &pin, out)? {
        let study =
            StudyFile { plan: plan.clone(), scenario_pin: Some(pin.clone()), build: Some(crate::build::current()) };
        write_atomically(&plan_file, &serde_json::to_string_pretty(&study).expect("JSON"))?
    }
    let models = StudyModels::new(&base_dir);
    let runs_file = out.join("runs.jsonl");
    let existing: Vec<RunRecord> =
        read_runs_of(&runs_file, plan, Repair::TornLastLine)?.into_iter().filter(|r| !r.retryable).collect();
    let done: BTreeSet<String> = existing.iter().map(|r| r.key.clone()).collect();
    let mine: Vec<Job> = jobs(plan).into_iter().filter(|j| shard.contains(j)).collect();
    let todo: Vec<&Job> = mine.iter().filter(|j| !done.contains(&j.key())).collect();
    // Every job's scenario and method are checked before the first run, so a bad setting
    // fails the study at once instead of every run. Every appearance model the jobs need
    // (one per setting of the training and the camera a study varies) is resolved here
    // too, trained and cached if need be, so runs and worker processes only load them.
    for job in &todo {
        let scenario = job_scenario(&base_scenario, job)?;
        let method = AssociationMethod::from_name(&job.method)
            .ok_or_else(|| StudyError::Job { key: job.key(), message: format!("unknown method {:?}", job.method) })?;
        crate::run::run_config(&scenario, Some(method))
            .map_err(|e| StudyError::Job { key: job.key(), message: e.to_string() })?;
        if let Some((setting, problem)) = scenario.camera_too_small_for(method) {
            let message = format!("{}: {setting}: {problem}", scenario.describe());
            return Err(StudyError::Job { key: job.key(), message });
        }
        if job_needs_appearance(job, &scenario) {
            models
                .resolve(&scenario, |stage, done, total| progress(StudyProgress::Training { stage, done, total }))
                .map_err(|e| StudyError::Appearance(Box::new(e)))?;
        }
    }
    let total = mine.len();
    let finished = std::sync::atomic::AtomicUsize::new(total - todo.len());
    progress(StudyProgress::Runs { done: finished.load(std::sync::atomic::Ordering::Relaxed), total });
    let file = Mutex::new(
        OpenOptions::new()
            .create(true)
            .append(true)
            .open(&runs_file)
            .map_err(|e| StudyError::Io { file: runs_file.clone(), source: e })?,
    );
    // Appends a finished run at once, in one synced write of the whole line: a kill leaves
    // at most one partial line, which the next start drops; a failed write is cut back and
    // fails the study once the other runs are done (the run is redone on resume).
    let append_failures: Mutex<(usize, String)> = Mutex::new((0, String::new()));
    let record_finished = |record: &RunRecord| {
        {
            let mut f = file.lock().unwrap_or_else(|p| p.into_inner());
            if let Err(e) = append_record(&mut f, record) {
                let mut failed = append_failures.lock().unwrap_or_else(|p| p.into_inner());
                failed.0 += 1;
                failed.1 = e.to_string();
            }
        }
        let n = finished.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        progress(StudyProgress::Runs { done: n, total });
    };
    let new: Vec<RunRecord> = match workers {
        Workers::Threads => todo
            .par_iter()
            .map(|job| {
                let record = run_job(&base_scenario, &base_dir, job, &models);
                record_finished(&record);
                record
            })
            .collect(),
        Workers::Processes { exe, count, run_timeout } => {
            // Workers load the scenario themselves: they are told which one the study pinned.
            let start = StudyFile { plan: plan.clone(), scenario_pin: Some(pin.clone()), build: None };
            workers::run_in_processes(&start, &todo, exe, *count, *run_timeout, &record_finished)?
        }
    };
    let (count, message) = append_failures.into_inner().unwrap_or_else(|p| p.into_inner());
    if count > 0 {
        return Err(StudyError::Append { file: runs_file, count, message });
    }
    // The append handle goes before its file is replaced. A failure here loses nothing:
    // every run is on file, in the order the runs finished.
    drop(file);
    put_in_job_order(&runs_file).map_err(|e| StudyError::File {
        file: runs_file.clone(),
        message: format!(
            "every run is recorded here, in the order the runs finished, but putting them in job order failed ({e}); run the same command again to finish"
        ),
    })?;
    let keys: BTreeSet<String> = mine.iter().map(|j| j.key()).collect();
    let mut all: Vec<RunRecord> = existing.into_iter().filter(|r| keys.contains(&r.key)).chain(new).collect();
    all.sort_by_key(|r| r.job.index);
    // The summary is the study's too: written while the directory is still held, so that
    // another study starting there cannot write its own between.
    if let Err(e) = one_model_per_setting(&all, &runs_file) {
        // An earlier summary no longer describes the runs beside it.
        for name in ["summary.csv", "summary.json"] {
            let _ = std::fs::remove_file(out.join(name));
        }
        return Err(e);
    }
    write_summary(plan, &all, out)?;
    drop(held);
    Ok(all)
}

/// Refuses runs of one setting (method and parameter values) made with different
/// appearance models: a study resumed, or shards run, where another model was cached
/// (another `OBJSLAM_CACHE`, renderer or build trained it) would pool two models' runs as
/// one setting's. `file` names the runs in the error.
fn one_model_per_setting(runs: &[RunRecord], file: &Path) -> Result<(), StudyError> {
    let mut models: BTreeMap<(usize, &str), BTreeMap<&str, Vec<usize>>> = BTreeMap::new();
    for r in runs {
        let digest = r.metrics.as_ref().and_then(|m| m.appearance_model.as_ref()).and_then(|p| p.digest.as_deref());
        if let Some(digest) = digest {
            let setting = (r.job.setting(), r.job.method.as_str());
            models.entry(setting).or_default().entry(digest).or_default().push(r.job.index);
        }
    }
    let Some((_, by_digest)) = models.iter().find(|(_, by_digest)| by_digest.len() > 1) else { return Ok(()) };
    let used: Vec<String> = by_digest
        .iter()
        .map(|(digest, jobs)| {
            let shown: Vec<String> = jobs.iter().take(5).map(|j| j.to_string()).collect();
            let more = if jobs.len() > 5 { format!(" and {} more", jobs.len() - 5) } else { String::new() };
            format!("model {digest} in jobs {}{more}", shown.join(", "))
        })
        .collect();
    Err(StudyError::File {
        file: file.into(),
        message: format!(
            "runs of one setting used different appearance models ({}): the study was resumed, or its shards run, where \
             another model was cached (another OBJSLAM_CACHE, renderer or build); keep the runs of one model and run \
             the others again",
            used.join("; ")
        ),
    })
}

/// Whether `out` can take `plan`'s study, without writing anything: `plan` is sound, and
/// `out` is new, or holds the same study begun (to resume), and is no generalisation
/// benchmark's directory. A command running several studies checks each before the first
/// runs.
pub fn check_study_dir(plan: &StudyPlan, out: &Path) -> Result<(), StudyError> {
    plan.check()?;
    let (pin, _, _) = pin_scenario(&plan.scenario)?;
    existing_study(plan, &pin, out).map(|_| ())
}

/// Whether `out` holds `plan`'s study already (`false`: it holds none); an error where it
/// holds another, runs without their plan, or a generalisation benchmark.
fn existing_study(plan: &StudyPlan, pin: &ScenarioPin, out: &Path) -> Result<bool, StudyError> {
    refuse_benchmark_dir(out)?;
    let plan_file = out.join("study.json");
    match read_study_file(&plan_file, "; remove the directory, or this file if runs.jsonl is empty, to start again") {
        Ok(existing) => {
            if !same_plan(&existing, plan) {
                return Err(StudyError::Mismatch {
                    dir: out.into(),
                    message: format!("it was started as {}", serde_json::to_string(&existing.plan).unwrap_or_default()),
                });
            }
            if let Some(changed) = existing.scenario_pin.and_then(|began| began.changed_to(&plan.scenario, pin)) {
                return Err(StudyError::Mismatch { dir: out.into(), message: changed });
            }
            Ok(true)
        }
        Err(StudyError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {
            // Runs left without their plan are another study's as far as anyone can tell.
            if has_runs(&out.join("runs.jsonl"))? {
                return Err(StudyError::File {
                    file: out.join("runs.jsonl"),
                    message: "runs of a study whose study.json is gone: move them away or use a new --out directory"
                        .into(),
                });
            }
            Ok(false)
        }
        Err(StudyError::Io { source, .. }) => {
            Err(StudyError::File { file: plan_file, message: format!("cannot read the study plan: {source}") })
        }
        Err(e) => Err(e),
    }
}

/// The file a generalisation benchmark's directory holds beside its two studies.
pub const BENCHMARK_WORLDS: &str = "worlds.json";

/// Refuses a generalisation benchmark's top directory as a study's: its `summary.json` is
/// the benchmark's report, which a study's summary would replace.
fn refuse_benchmark_dir(out: &Path) -> Result<(), StudyError> {
    if out.join(BENCHMARK_WORLDS).exists() {
        return Err(StudyError::Benchmark(out.into()));
    }
    Ok(())
}

/// Whether the job's method needs an appearance model and its scenario has the camera it
/// needs.
fn job_needs_appearance(job: &Job, scenario: &Scenario) -> bool {
    scenario.sim.camera.enabled && AssociationMethod::from_name(&job.method).is_some_and(|m| m.uses_appearance())
}

/// The base scenario with the job's parameters applied.
pub fn job_scenario(base: &Scenario, job: &Job) -> Result<Scenario, StudyError> {
    let mut scenario = base.clone();
    for (p, v) in &job.params {
        scenario = apply_param(&scenario, p, *v)?;
    }
    Ok(scenario)
}

/// A study's appearance models, one per source: the scenario's `[appearance]` table and
/// camera as a job's parameters leave them (a study may vary the training or the camera).
/// Each is resolved (loaded, or trained and cached) the first time a job asks for it.
pub struct StudyModels {
    base_dir: PathBuf,
    models: Mutex<BTreeMap<String, std::sync::Arc<slam::classifier::AppearanceModel>>>,
}

impl StudyModels {
    pub fn new(base_dir: &Path) -> Self {
        StudyModels { base_dir: base_dir.to_path_buf(), models: Mutex::new(BTreeMap::new()) }
    }

    /// The model `scenario` asks for.
    pub fn get(
        &self,
        scenario: &Scenario,
    ) -> Result<std::sync::Arc<slam::classifier::AppearanceModel>, crate::run::RunError> {
        self.resolve(scenario, |_, _, _| {})
    }

    /// [`StudyModels::get`], with `progress(stage, done, total)` following a training.
    pub fn resolve(
        &self,
        scenario: &Scenario,
        progress: impl Fn(&str, usize, usize),
    ) -> Result<std::sync::Arc<slam::classifier::AppearanceModel>, crate::run::RunError> {
        let key = match &scenario.appearance.model {
            Some(file) => format!("file {file}"),
            None => scenario.appearance.cache_key(&scenario.sim.camera),
        };
        // Held while a model trains. Training runs on rayon's threads, so it must not start
        // inside a rayon worker that another job could then wait here on: run_study resolves
        // every model before the parallel runs, which only load them.
        let mut models = self.models.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(model) = models.get(&key) {
            return Ok(model.clone());
        }
        let model = std::sync::Arc::new(crate::run::resolve_appearance(scenario, &self.base_dir, progress)?);
        models.insert(key, model.clone());
        Ok(model)
    }
}

/// Runs one job, with the appearance model of its own scenario; errors and panics become
/// the record's error.
pub fn run_job(base: &Scenario, base_dir: &Path, job: &Job, models: &StudyModels) -> RunRecord {
    run_job_into(base, base_dir, job, models, None)
}

/// [`run_job`], writing the run's outputs into `out` when given.
fn run_job_into(base: &Scenario, base_dir: &Path, job: &Job, models: &StudyModels, out: Option<&Path>) -> RunRecord {
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| -> Result<Metrics, String> {
        let scenario = job_scenario(base, job).map_err(|e| e.to_string())?;
        let method =
            AssociationMethod::from_name(&job.method).ok_or_else(|| format!("unknown method {:?}", job.method))?;
        let appearance = if job_needs_appearance(job, &scenario) {
            Some(models.get(&scenario).map_err(|e| e.to_string())?)
        } else {
            None
        };
        let options = RunOptions {
            seed: Some(job.seed),
            method: Some(method),
            out: out.map(Path::to_path_buf),
            appearance,
            full_frames: false,
            bag: None,
        };
        crate::run::run(&scenario, base_dir, &options, |_| {}).map(|o| o.metrics).map_err(|e| e.to_string())
    }));
    let (metrics, error) = match result {
        Ok(Ok(m)) => (Some(m), None),
        Ok(Err(e)) => (None, Some(e)),
        Err(panic) => {
            let msg = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "panic".into());
            (None, Some(format!("panicked: {msg}")))
        }
    };
    RunRecord {
        key: job.key(),
        job: job.clone(),
        metrics,
        error,
        retryable: false,
        build: Some(crate::build::current()),
    }
}

/// A study's job run again with its outputs, beside what the study recorded for it.
pub struct Rerun {
    pub job: Job,
    /// The run just made.
    pub record: RunRecord,
    /// The study's record of the job, if it has one.
    pub recorded: Option<RunRecord>,
    /// The record's line as written: which figures the recording build wrote.
    recorded_line: Option<serde_json::Value>,
}

impl Rerun {
    /// Whether the run repeats the study's record (wall-clock figures aside); `None` when
    /// the study has no record of the job. Only the figures the record's line holds are
    /// compared: one that the rerun has and the line lacks (a newer build's key, or an
    /// optional figure left out when empty) is not.
    pub fn repeats_record(&self) -> Option<bool> {
        self.recorded.as_ref().map(|_| self.differences().is_empty())
    }

    /// The recorded figures the run does not repeat, as dotted paths (`metrics.map.posts`);
    /// empty without a record.
    pub fn differences(&self) -> Vec<String> {
        let value = |r: &RunRecord| serde_json::to_value(r.without_wall_clock()).expect("a record serialises");
        let mut out = Vec::new();
        if let (Some(r), Some(line)) = (&self.recorded, &self.recorded_line) {
            let mut recorded = value(r);
            keep_keys_of(&mut recorded, line);
            differences_from_record(&recorded, &value(&self.record), "", &mut out);
        }
        out
    }
}

/// Removes from `value` the object keys that `like` lacks, at every depth: a record read
/// back gets defaults for figures its build did not write, and those are not figures.
fn keep_keys_of(value: &mut serde_json::Value, like: &serde_json::Value) {
    if let (serde_json::Value::Object(v), serde_json::Value::Object(l)) = (value, like) {
        v.retain(|k, _| l.contains_key(k));
        for (k, x) in v.iter_mut() {
            keep_keys_of(x, &l[k]);
        }
    }
}

/// Pushes to `out` the paths where `new` lacks or differs from a value of `recorded`:
/// objects compared key by key over `recorded`'s keys, other values by equality.
fn differences_from_record(recorded: &serde_json::Value, new: &serde_json::Value, path: &str, out: &mut Vec<String>) {
    match (recorded, new) {
        (serde_json::Value::Object(a), serde_json::Value::Object(b)) => {
            for (k, v) in a {
                let here = if path.is_empty() { k.clone() } else { format!("{path}.{k}") };
                match b.get(k) {
                    Some(w) => differences_from_record(v, w, &here, out),
                    None => out.push(here),
                }
            }
        }
        _ if recorded != new => out.push(path.to_string()),
        _ => {}
    }
}

/// Runs a job of the study in `dir` (its `study.json`) again, writing every output of
/// `objslam run` into `out`, so that a run a study found failing can be looked into. `job`
/// is the job's index or its key, as `runs.jsonl` gives them (`job.index`, `key`).
/// `scenario` is where the study's scenario file is now, if it moved since the study began
/// (it must still be the same scenario).
pub fn rerun(dir: &Path, job: &str, out: &Path, scenario: Option<&str>) -> Result<Rerun, StudyError> {
    let plan_file = dir.join("study.json");
    let study = read_study_file(&plan_file, "")?;
    let plan = &study.plan;
    plan.check()
        .map_err(|e| StudyError::File { file: plan_file.clone(), message: format!("not a plan that can run ({e})") })?;
    let all = jobs(plan);
    if all.is_empty() {
        return Err(StudyError::File { file: plan_file, message: "this study has no jobs".into() });
    }
    let job = match job.trim().parse::<usize>() {
        Ok(index) => all.get(index),
        // A study without --vary keys its jobs `method=nn;;run=0` (no parameters between):
        // the key typed without the empty part is the same job.
        Err(_) => all.iter().find(|j| j.key() == job || j.key().replace(";;", ";") == job.trim()),
    }
    .cloned()
    .ok_or_else(|| StudyError::File {
        file: plan_file.clone(),
        message: format!(
            "no job {job:?} in this study: give an index from 0 to {} or a key from runs.jsonl",
            all.len().saturating_sub(1)
        ),
    })?;
    let (base, base_dir) = pinned_scenario(&plan_file, &study, scenario)?;
    let (recorded, recorded_line) = recorded_run(&dir.join("runs.jsonl"), &job.key())?.unzip();
    // A directory another command holds is refused here, not reported as the run failing.
    drop(hold(out)?);
    let record = run_job_into(&base, &base_dir, &job, &StudyModels::new(&base_dir), Some(out));
    Ok(Rerun { job, record, recorded, recorded_line })
}

/// The record of the job `key` in a study's `runs.jsonl` as the study keeps it (a final
/// one; records that disagree are an error), with its line as written. The file is read
/// without being touched: a study may be appending to it.
fn recorded_run(file: &Path, key: &str) -> Result<Option<(RunRecord, serde_json::Value)>, StudyError> {
    let (complete, _) = complete_lines(file)?;
    let records = one_record_per_job(file, parse_run_lines(file, &complete)?)?;
    let Some((line, record)) = records.into_iter().find(|(_, r)| r.key == key && !r.retryable) else {
        return Ok(None);
    };
    let text = complete.lines().nth(line - 1).expect("a parsed line is in the text");
    let value = serde_json::from_str(text)
        .map_err(|e| StudyError::File { file: file.into(), message: format!("line {line}: not a run record ({e})") })?;
    Ok(Some((record, value)))
}

/// Shards run on other machines read the scenario from other paths: the same study has
/// the same plan and the same scenario digest.
fn digest(study: &StudyFile) -> Option<&str> {
    study.scenario_pin.as_ref().map(|pin| pin.sha256.as_str())
}

/// Merges shard directories into `out`: runs de-duplicated by job and ordered by job index.
/// `out` is held as a study holds it; one that already holds this study's runs has them
/// merged too, and one that holds another study's (or runs without a plan) is refused.
/// Writes the merged summary there.
pub fn merge(dirs: &[PathBuf], out: &Path) -> Result<(StudyPlan, Vec<RunRecord>), StudyError> {
    let held = hold(out)?;
    let merged = merge_held(dirs, out);
    // A refused merge leaves no directory it made.
    if merged.is_err() {
        held.release_failed();
    }
    merged
}

/// [`merge`] once `out` is held.
fn merge_held(dirs: &[PathBuf], out: &Path) -> Result<(StudyPlan, Vec<RunRecord>), StudyError> {
    let mut dirs = dirs.to_vec();
    refuse_benchmark_dir(out)?;
    let out_plan = out.join("study.json");
    if out_plan.exists() {
        if !dirs.iter().any(|d| crate::partial_files::same_path(d, out)) {
            dirs.push(out.to_path_buf());
        }
    } else if has_runs(&out.join("runs.jsonl"))? {
        return Err(StudyError::File {
            file: out.join("runs.jsonl"),
            message: "runs without a study.json beside them: move them away or merge into a new directory".into(),
        });
    }
    let mut plan: Option<StudyFile> = None;
    let mut by_key: BTreeMap<String, RunRecord> = BTreeMap::new();
    for d in &dirs {
        let f = d.join("study.json");
        let p = read_study_file(&f, "")?;
        match &plan {
            Some(existing) if !same_study(existing, &p) => {
                let what = if crate::partial_files::same_path(d, out) { "the output directory" } else { "this shard" };
                return Err(StudyError::Mismatch {
                    dir: d.clone(),
                    message: format!(
                        "{what} holds another study than {}; shards of different studies cannot be merged",
                        dirs[0].display()
                    ),
                });
            }
            _ => plan = Some(p),
        }
        let study = plan.as_ref().expect("set above");
        // A shard's study may still be appending: its file is read, never repaired.
        for r in read_runs_of(&d.join("runs.jsonl"), &study.plan, Repair::No)? {
            match by_key.get(&r.key) {
                None => {
                    by_key.insert(r.key.clone(), r);
                }
                Some(kept) if kept.retryable => {
                    by_key.insert(r.key.clone(), r);
                }
                Some(kept) if !r.retryable && kept.without_wall_clock() != r.without_wall_clock() => {
                    return Err(StudyError::File {
                        file: d.join("runs.jsonl"),
                        message: format!(
                            "job {} is recorded differently in another shard; merge without one of them",
                            r.key
                        ),
                    });
                }
                Some(_) => {}
            }
        }
    }
    let study =
        plan.ok_or_else(|| StudyError::File { file: out.into(), message: "no shard directories given".into() })?;
    let mut runs: Vec<RunRecord> = by_key.into_values().collect();
    runs.sort_by_key(|r| r.job.index);
    one_model_per_setting(&runs, out)?;
    write_atomically(&out.join("study.json"), &serde_json::to_string_pretty(&study).expect("JSON"))?;
    let lines: String = runs.iter().map(|r| serde_json::to_string(r).expect("JSON") + "\n").collect();
    write_atomically(&out.join("runs.jsonl"), &lines)?;
    write_summary(&study.plan, &runs, out)?;
    Ok((study.plan, runs))
}

/// Whether two `study.json`s are of one study: the same plan ([`same_plan`]) and the same
/// scenario digest.
fn same_study(a: &StudyFile, b: &StudyFile) -> bool {
    same_plan(a, &b.plan) && b.scenario_pin.is_some() == a.scenario_pin.is_some() && digest(a) == digest(b)
}

/// Whether `plan` is the plan of `study`: where the study pinned the scenario it began
/// with, the scenario may be typed otherwise (from another working directory), and the
/// digest decides; without a pin, the plans must be equal as typed.
fn same_plan(study: &StudyFile, plan: &StudyPlan) -> bool {
    let untyped = |p: &StudyPlan| StudyPlan { scenario: String::new(), ..p.clone() };
    match study.scenario_pin {
        Some(_) => untyped(&study.plan) == untyped(plan),
        None => study.plan == *plan,
    }
}

/// Holds `out` for one command, as every command writing there does.
fn hold(out: &Path) -> Result<crate::partial_files::OutputLock, StudyError> {
    crate::partial_files::lock_output(out).map_err(|e| match e.source.kind() {
        std::io::ErrorKind::ResourceBusy => StudyError::Locked { file: e.file },
        _ => StudyError::Io { file: e.file, source: e.source },
    })
}

/// Whether `runs.jsonl` at `path` holds a line of text.
fn has_runs(path: &Path) -> Result<bool, StudyError> {
    match std::fs::read(path) {
        Ok(bytes) => Ok(bytes.iter().any(|b| !b.is_ascii_whitespace())),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(false),
        Err(e) => Err(StudyError::Io { file: path.into(), source: e }),
    }
}

/// Whether reading `runs.jsonl` cuts a torn last line off the file: only a study holding
/// its directory may (another's may be writing that line).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Repair {
    TornLastLine,
    No,
}

/// [`read_runs`], each record checked to be one of `plan`'s jobs as the plan makes it: a
/// record of another study (another scenario or seed, or a job the plan does not have) is
/// an error naming its line.
pub fn read_runs_of(path: &Path, plan: &StudyPlan, repair: Repair) -> Result<Vec<RunRecord>, StudyError> {
    let planned: BTreeMap<String, Job> = jobs(plan).into_iter().map(|j| (j.key(), j)).collect();
    let lines = match repair {
        Repair::TornLastLine => read_run_lines(path)?,
        Repair::No => parse_run_lines(path, &complete_lines(path)?.0)?,
    };
    let records = one_record_per_job(path, lines)?;
    for (line, r) in &records {
        let problem = match planned.get(&r.key) {
            None => format!("job {} is not one of this study's jobs", r.key),
            Some(job) if *job != r.job => format!(
                "job {} is recorded as {}, where this study plans {}",
                r.key,
                serde_json::to_string(&r.job).unwrap_or_default(),
                serde_json::to_string(job).unwrap_or_default()
            ),
            Some(_) => continue,
        };
        return Err(StudyError::File {
            file: path.into(),
            message: format!("line {line}: {problem}: a record of another study; remove it, or use a new directory"),
        });
    }
    Ok(records.into_iter().map(|(_, r)| r).collect())
}

/// How many of `plan`'s runs are not among `runs` (a merge of some of a study's shards,
/// or of a study not finished).
pub fn missing_runs(plan: &StudyPlan, runs: &[RunRecord]) -> usize {
    // A run recorded as retryable is to be run again: not done.
    let present: std::collections::HashSet<&str> =
        runs.iter().filter(|r| !r.retryable).map(|r| r.key.as_str()).collect();
    jobs(plan).iter().filter(|j| !present.contains(j.key().as_str())).count()
}

/// One summary row: a method at one set of parameter values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SummaryRow {
    pub method: String,
    pub params: Vec<(String, f64)>,
    pub runs: usize,
    pub errors: usize,
    /// Runs with one or more wrong associations or false landmarks.
    pub failures: usize,
    #[serde(with = "crate::score::nan_as_null")]
    pub failure_rate: f64,
    pub failure_rate_ci95: (f64, f64),
    #[serde(with = "crate::score::nan_as_null")]
    pub mean_wrong_associations: f64,
    #[serde(with = "crate::score::nan_as_null")]
    pub mean_false_landmarks: f64,
    #[serde(with = "crate::score::nan_as_null")]
    pub mean_ate_rmse_m: f64,
    /// Mean and lowest `map.tree_recall` over the runs where it is defined.
    #[serde(default, with = "crate::score::nan_as_null")]
    pub mean_tree_recall: f64,
    #[serde(default, with = "crate::score::nan_as_null")]
    pub min_tree_recall: f64,
}

/// Summarises runs per method and parameter values, in plan order. Runs recorded as
/// retryable (their worker died or timed out) are not figures of the method: left out,
/// to be run again.
pub fn summarise(plan: &StudyPlan, runs: &[RunRecord]) -> Vec<SummaryRow> {
    let mut groups: BTreeMap<(usize, String), Vec<&RunRecord>> = BTreeMap::new();
    let all = jobs(plan);
    for r in runs.iter().filter(|r| !r.retryable) {
        // Group by the index of the job's first run in the plan, which orders groups as
        // the plan does.
        let first = r.job.setting();
        groups.entry((first, r.job.method.clone())).or_default().push(r);
    }
    groups
        .into_iter()
        .map(|((first, method), rs)| {
            let ok: Vec<&Metrics> = rs.iter().filter_map(|r| r.metrics.as_ref()).collect();
            let failures = rs.iter().filter(|r| r.failed_association() == Some(true)).count();
            let n = ok.len();
            let mean = |f: &dyn Fn(&Metrics) -> f64| {
                if n == 0 { f64::NAN } else { ok.iter().map(|m| f(m)).sum::<f64>() / n as f64 }
            };
            SummaryRow {
                method,
                params: all[first].params.clone(),
                runs: rs.len(),
                errors: rs.len() - n,
                failures,
                failure_rate: if n == 0 { f64::NAN } else { failures as f64 / n as f64 },
                failure_rate_ci95: wilson_interval(failures, n, 1.96),
                mean_wrong_associations: mean(&|m| m.associations.wrong as f64),
                mean_false_landmarks: mean(&|m| m.false_landmarks as f64),
                mean_ate_rmse_m: mean(&|m| m.ate_rmse_m),
                mean_tree_recall: {
                    let r: Vec<f64> = ok.iter().filter_map(|m| m.map.tree_recall).collect();
                    if r.is_empty() { f64::NAN } else { r.iter().sum::<f64>() / r.len() as f64 }
                },
                min_tree_recall: ok.iter().filter_map(|m| m.map.tree_recall).fold(f64::NAN, f64::min),
            }
        })
        .collect()
}

/// `summary.json`'s `builds`: `[{"build": {...} or null, "runs": N}]`, as [`builds`] gives
/// them.
fn builds_json(runs: &[RunRecord]) -> serde_json::Value {
    builds(runs).into_iter().map(|(build, runs)| serde_json::json!({"build": build, "runs": runs})).collect()
}

/// The builds that made `runs` (runs to retry aside), each with its number of runs, in
/// the order they first appear; `None` for runs whose records name no build (written by
/// a build before runs recorded theirs).
pub fn builds(runs: &[RunRecord]) -> Vec<(Option<crate::build::Build>, usize)> {
    let mut out: Vec<(Option<crate::build::Build>, usize)> = Vec::new();
    for b in runs.iter().filter(|r| !r.retryable).map(|r| &r.build) {
        match out.iter_mut().find(|(known, _)| known == b) {
            Some((_, n)) => *n += 1,
            None => out.push((b.clone(), 1)),
        }
    }
    out
}

/// Writes `summary.csv`, `summary.json` and the failure-rate plots (PNG and SVG).
pub fn write_summary(plan: &StudyPlan, runs: &[RunRecord], out: &Path) -> Result<(), StudyError> {
    let rows = summarise(plan, runs);
    let mut csv = String::from("method");
    for v in &plan.vary {
        csv.push(',');
        csv.push_str(&v.param);
    }
    csv.push_str(",runs,errors,failures,failure_rate,failure_rate_ci95_low,failure_rate_ci95_high,mean_wrong_associations,mean_false_landmarks,mean_ate_rmse_m,mean_tree_recall,min_tree_recall\n");
    for r in &rows {
        csv.push_str(&r.method);
        for (_, v) in &r.params {
            csv.push_str(&format!(",{v}"));
        }
        csv.push_str(&format!(
            ",{},{},{},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6}\n",
            r.runs,
            r.errors,
            r.failures,
            r.failure_rate,
            r.failure_rate_ci95.0,
            r.failure_rate_ci95.1,
            r.mean_wrong_associations,
            r.mean_false_landmarks,
            r.mean_ate_rmse_m,
            r.mean_tree_recall,
            r.min_tree_recall
        ));
    }
    // Each file whole or not at all (a kill midway had left a CSV of one summary beside
    // the JSON of another); the same command writes them all again.
    write_atomically(&out.join("summary.csv"), &csv)?;
    write_atomically(
        &out.join("summary.json"),
        &serde_json::to_string_pretty(&serde_json::json!({"study": plan, "rows": rows, "builds": builds_json(runs)}))
            .expect("JSON"),
    )?;
    let svg = crate::plot::failure_rate_plot(plan, &rows, &out.join("failure_rate.png"))?;
    write_atomically(&out.join("failure_rate.svg"), &svg)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rerun_is_compared_on_the_figures_its_record_holds() {
        let recorded = serde_json::json!({"map": {"trees_mapped": 3, "posts": 0}, "model": {"seed": 1}});
        let differences = |new: serde_json::Value| {
            let mut out = Vec::new();
            differences_from_record(&recorded, &new, "", &mut out);
            out
        };
        let newer = serde_json::json!({"map": {"trees_mapped": 3, "posts": 0, "palms": 0}, "model": {"seed": 1, "digest": "ab"}});
        assert!(differences(newer).is_empty(), "keys only the newer build records are left out");
        let differs = serde_json::json!({"map": {"trees_mapped": 2, "posts": 0}, "model": {"seed": 1}});
        assert_eq!(differences(differs), ["map.trees_mapped"]);
        let lacks = serde_json::json!({"map": {"trees_mapped": 3}, "model": {"seed": 1}});
        assert_eq!(differences(lacks), ["map.posts"], "a recorded figure the rerun lacks is a difference");
        // A record read back gets defaults for what its build did not write; those go.
        let mut read_back = serde_json::json!({"model": {"seed": 1, "digest": null}, "map": {"posts": 0}});
        keep_keys_of(&mut read_back, &serde_json::json!({"model": {"seed": 1}, "map": {"posts": 0}}));
        assert_eq!(read_back, serde_json::json!({"model": {"seed": 1}, "map": {"posts": 0}}));
    }

    /// Every value of the built-in study makes a valid scenario whose world generates.
    #[test]
    fn builtin_study_values_make_valid_scenarios() {
        let (sc, base) = Scenario::load("paper_park").unwrap();
        for (name, plan) in builtin_study(3, 1) {
            assert_eq!(jobs(&plan).len(), 3 * 3 * plan.vary[0].values.len(), "{name}");
            for &x in &plan.vary[0].values {
                let varied = apply_param(&sc, &plan.vary[0].param, x).unwrap();
                varied.world(&base, 1).unwrap_or_else(|e| panic!("{name}={x}: {e}"));
            }
        }
    }

    #[test]
    fn vary_specs_parse_or_fail_clearly() {
        let v = Vary::parse("sim.odometry.scale_sigma=0.0..0.04:5").unwrap();
        assert_eq!(v.param, "sim.odometry.scale_sigma");
        assert_eq!(v.values, vec![0.0, 0.01, 0.02, 0.03, 0.04]);
        for bad in ["x", "x=1..2", "x=1:3", "x=a..2:3", "=1..2:3", "x=1..2:0"] {
            assert!(Vary::parse(bad).is_err(), "{bad}");
        }
    }

    /// The builds of a study's runs are counted, runs to retry aside and records of older
    /// builds as one unknown build, and a run's build is no figure: a rerun or another shard's record of the same
    /// job by another build repeats it.
    #[test]
    fn runs_name_their_build_which_is_counted_and_no_figure() {
        let build = |commit: &str| crate::build::Build {
            version: "0.1.0".into(),
            source: Some(crate::build::Source { commit: commit.into(), modified: false }),
        };
        let record = |index: usize, b: Option<crate::build::Build>, retryable: bool| {
            let job = Job { index, method: "nn".into(), params: vec![], run: index, seed: 1 };
            RunRecord { key: job.key(), job, metrics: None, error: Some("e".into()), retryable, build: b }
        };
        let runs = [
            record(0, Some(build("aaa")), false),
            record(1, Some(build("bbb")), false),
            record(2, Some(build("aaa")), false),
            record(3, None, false),
            record(4, Some(build("ccc")), true),
        ];
        assert_eq!(builds(&runs), vec![(Some(build("aaa")), 2), (Some(build("bbb")), 1), (None, 1)]);
        let json = builds_json(&runs);
        assert_eq!(json[1]["build"]["source"]["commit"], "bbb");
        assert!(json[2]["build"].is_null() && json[2]["runs"] == 1, "{json}");
        assert_eq!(runs[0].without_wall_clock(), record(0, Some(build("other")), false).without_wall_clock());
        let line = serde_json::to_string(&runs[0]).unwrap();
        assert!(line.contains(r#""build":{"version":"0.1.0","source":{"commit":"aaa""#), "{line}");
        assert_eq!(serde_json::from_str::<RunRecord>(&line).unwrap(), runs[0]);
        assert!(!serde_json::to_string(&runs[3]).unwrap().contains("build"), "an older build's record stays as it was");
    }

    /// People read a range's values without its rounding, and no two values as one.
    #[test]
    fn parameter_values_read_short_and_stay_distinct() {
        let v = Vary::parse("x=0.005..0.03:6").unwrap();
        assert_eq!(v.values[1], 0.009999999999999998, "the rounding the display hides");
        let shown: Vec<String> = v.values.iter().map(|&x| short_number(x)).collect();
        assert_eq!(shown, ["0.005", "0.01", "0.015", "0.02", "0.025", "0.03"]);
        assert_eq!(short_number(1.0), "1");
        assert_eq!(short_number(-2.5), "-2.5");
        assert_eq!(short_number(0.0), "0");
        assert_eq!(short_number(1e-7), "1e-7");
        assert_eq!(short_number(2.5e15), "2.5e15");
        assert_ne!(short_number(1.0000001), short_number(1.0));
    }

    /// A range ends on B exactly (0.2..1:4 ended on 1.0000000000000002, which a setting of
    /// at most 1 refused), its other values as before; one step from A to another B is
    /// refused, not taken as A alone.
    #[test]
    fn a_range_ends_on_its_end_and_one_step_is_one_value() {
        let v = Vary::parse("pass.min_tree_recall=0.2..1:4").unwrap();
        assert_eq!(v.values[3], 1.0);
        assert_eq!(v.values[..3], [0.2, 0.2 + 0.8 * 1.0 / 3.0, 0.2 + 0.8 * 2.0 / 3.0], "interior values as before");
        assert_eq!(Vary::parse("x=0.06..0.9:2").unwrap().values, [0.06, 0.9]);
        let (s, _) = Scenario::load("laser_only").unwrap();
        for &x in &v.values {
            apply_param(&s, "pass.min_tree_recall", x).unwrap();
        }
        let e = Vary::parse("x=0..0.02:1").unwrap_err().to_string();
        assert!(e.contains("--vary \"x=0..0.02:1\"") && e.contains("one step cannot go from A to B"), "{e}");
        assert_eq!(Vary::parse("x=0.5..0.5:1").unwrap().values, [0.5]);
    }

    /// A whole-number setting's refusal gives its own reason (laser_only asks for at least
    /// one false landmark), not that a float is no count.
    #[test]
    fn a_whole_number_settings_refusal_gives_its_reason() {
        let (s, _) = Scenario::load("laser_only").unwrap();
        let e = apply_param(&s, "pass.max_false_landmarks", 0.0).unwrap_err().to_string();
        assert!(e.contains("is above pass.max_false_landmarks = 0"), "{e}");
        assert!(!e.contains("float"), "{e}");
    }

    /// Values that differ as typed but set a whole-number setting alike would be one job
    /// run twice: refused before a run, with the two values.
    #[test]
    fn values_that_set_a_setting_alike_are_refused() {
        let (s, _) = Scenario::load("laser_only").unwrap();
        let plan = |spec: &str| StudyPlan {
            scenario: "laser_only".into(),
            base_seed: 1,
            runs: 1,
            methods: vec!["nn".into()],
            vary: vec![Vary::parse(spec).unwrap()],
        };
        let alike = plan("world.seed=5..5.000000001:2");
        alike.check().unwrap();
        let e = check_values_differ(&alike, &s).unwrap_err().to_string();
        assert!(e.contains("--vary world.seed: the values 5 and 5.000000001 set it alike"), "{e}");
        let out = std::env::temp_dir().join(format!("objslam-mc-alike-{}", std::process::id()));
        let e = run_study(&alike, Shard::all(), &out, |_| {}).unwrap_err().to_string();
        assert!(e.contains("set it alike"), "{e}");
        assert!(!out.join("runs.jsonl").exists() && !out.join("study.json").exists(), "refused before the study began");
        let _ = std::fs::remove_dir_all(&out);
        check_values_differ(&plan("world.seed=5..6:2"), &s).unwrap();
        check_values_differ(&plan("sim.odometry.scale_sigma=0..0.02:3"), &s).unwrap();
    }

    #[test]
    fn shards_partition_the_jobs() {
        let plan = StudyPlan {
            scenario: "laser_only".into(),
            base_seed: 1,
            runs: 7,
            methods: vec!["nn".into(), "jcbb".into()],
            vary: vec![Vary::parse("sim.odometry.scale_sigma=0..0.02:3").unwrap()],
        };
        let all = jobs(&plan);
        assert_eq!(all.len(), 42);
        let mut seen = BTreeSet::new();
        for k in 0..4 {
            let s = Shard { index: k, count: 4 };
            for j in all.iter().filter(|j| s.contains(j)) {
                assert!(seen.insert(j.key()), "job in two shards");
            }
        }
        assert_eq!(seen.len(), all.len());
        // The run's seed depends on the run index only.
        assert_eq!(all[0].seed, all[7].seed);
        assert_ne!(all[0].seed, all[1].seed);
    }

    #[test]
    fn shard_from_scheduler_environment() {
        let env = |pairs: &'static [(&'static str, &'static str)]| {
            move |k: &str| pairs.iter().find(|(n, _)| *n == k).map(|(_, v)| v.to_string())
        };
        assert_eq!(
            Shard::from_env(
                env(&[("SLURM_ARRAY_TASK_ID", "4"), ("SLURM_ARRAY_TASK_MIN", "1"), ("SLURM_ARRAY_TASK_COUNT", "8")]),
                None
            )
            .unwrap(),
            Some(Shard { index: 3, count: 8 })
        );
        assert_eq!(
            Shard::from_env(env(&[("JOB_COMPLETION_INDEX", "2")]), Some(5)).unwrap(),
            Some(Shard { index: 2, count: 5 })
        );
        assert!(Shard::from_env(env(&[("JOB_COMPLETION_INDEX", "2")]), None).is_err());
        assert_eq!(Shard::from_env(env(&[]), None).unwrap(), None);
        // Both forms say the same of a shard out of bounds.
        let e = Shard::parse("3/3").unwrap_err().to_string();
        assert!(e.contains("makes shard 3 of 3, and shards are numbered 0 to 2"), "{e}");
        assert!(Shard::parse("0/0").unwrap_err().to_string().contains("a count of 0"));
        let e = Shard::from_env(env(&[("JOB_COMPLETION_INDEX", "3")]), Some(3)).unwrap_err().to_string();
        assert!(e.contains("makes shard 3 of 3, and shards are numbered 0 to 2"), "{e}");
        // A stepped array (--array=0-4:2: tasks 0, 2, 4) gives shards 0, 1, 2 of 3.
        const STEPPED: &[(&str, &str)] =
            &[("SLURM_ARRAY_TASK_ID", "4"), ("SLURM_ARRAY_TASK_STEP", "2"), ("SLURM_ARRAY_TASK_COUNT", "3")];
        assert_eq!(Shard::from_env(env(STEPPED), None).unwrap(), Some(Shard { index: 2, count: 3 }));
        // A task below the array's first, or between its steps, and a count with no index.
        const BELOW: &[(&str, &str)] =
            &[("SLURM_ARRAY_TASK_ID", "0"), ("SLURM_ARRAY_TASK_MIN", "1"), ("SLURM_ARRAY_TASK_COUNT", "8")];
        assert!(Shard::from_env(env(BELOW), None).is_err());
        const BETWEEN: &[(&str, &str)] =
            &[("SLURM_ARRAY_TASK_ID", "3"), ("SLURM_ARRAY_TASK_STEP", "2"), ("SLURM_ARRAY_TASK_COUNT", "3")];
        assert!(Shard::from_env(env(BETWEEN), None).is_err());
        let e = Shard::from_env(env(&[]), Some(2)).unwrap_err().to_string();
        assert!(e.contains("--shard-count 2") && e.contains("give --shard K/N"), "{e}");
        // A task beyond the count is named by the variables that gave it, not as a --shard
        // the user did not type.
        let e = Shard::from_env(env(&[("SLURM_ARRAY_TASK_ID", "3"), ("SLURM_ARRAY_TASK_COUNT", "2")]), None)
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "SLURM_ARRAY_TASK_ID=3 with SLURM_ARRAY_TASK_COUNT=2: makes shard 3 of 2, and shards are numbered 0 to 1"
        );
        let e = Shard::from_env(env(&[("JOB_COMPLETION_INDEX", "5")]), Some(5)).unwrap_err().to_string();
        assert!(e.starts_with("JOB_COMPLETION_INDEX=5 with --shard-count 5: makes shard 5 of 5"), "{e}");
        let e = Shard::from_env(env(&[("JOB_COMPLETION_INDEX", "0")]), Some(0)).unwrap_err().to_string();
        assert!(e.contains("no shards to run") && !e.contains("--shard \""), "{e}");
    }

    #[test]
    fn parameters_apply_to_the_scenario() {
        let (s, _) = Scenario::load("laser_only").unwrap();
        let s2 = apply_param(&s, "sim.odometry.scale_sigma", 0.07).unwrap();
        assert_eq!(s2.sim.odometry.scale_sigma, 0.07);
        let s3 = apply_param(&s, "world.params.post_distance_m", 1.25).unwrap();
        assert_eq!(s3.world.params.unwrap().post_distance_m, [1.25, 1.25]);
        assert!(apply_param(&s, "sim.laser.rate_hz", -1.0).is_err());
        // A whole-number setting the scenario leaves out takes a whole number.
        assert_eq!(apply_param(&s, "pass.max_false_landmarks", 2.0).unwrap().pass.max_false_landmarks, Some(2));
        assert!(apply_param(&s, "pass.max_false_landmarks", 2.5).is_err());
        let e = apply_param(&s, "foo.bar", 1.0).unwrap_err().to_string();
        assert_eq!(
            e,
            "--vary \"foo.bar\": no such setting (`objslam config defaults` prints every setting of a scenario)"
        );
        assert!(apply_param(&s, "name.x", 1.0).is_err());
        // A coefficient varied under its former spelling sets today's.
        let s4 = apply_param(&s, "sim.odometry.k_dd", 0.3).unwrap();
        assert_eq!(s4.sim.odometry.a_dd, 0.3);
        assert_eq!(apply_param(&s, "sim.odometry.a_dd", 0.3).unwrap(), s4);
        // A whole-number setting takes whole numbers only (1.5 was rounded to 2 before).
        assert_eq!(apply_param(&s, "pipeline.confirm_observations", 3.0).unwrap().pipeline.confirm_observations, 3);
        let e = apply_param(&s, "pipeline.confirm_observations", 1.5).unwrap_err().to_string();
        assert!(e.contains("confirm_observations takes whole numbers, not 1.5"), "{e}");
        // Past i64 every value would be the same setting.
        let e = apply_param(&s, "world.seed", 1e19).unwrap_err().to_string();
        assert!(e.contains("within 9.2e18") && !e.contains("expected PARAM"), "a value, not the syntax: {e}");
        assert!(apply_param(&s, "seed", 2.0).unwrap_err().to_string().contains("vary world.seed"));
    }

    #[test]
    fn a_parameter_varied_twice_is_refused() {
        let plan = StudyPlan {
            scenario: "laser_only".into(),
            base_seed: 1,
            runs: 1,
            methods: vec!["nn".into()],
            vary: vec![
                Vary::parse("sim.odometry.scale_sigma=0..0.05:2").unwrap(),
                Vary::parse("sim.odometry.scale_sigma=0..0.1:2").unwrap(),
            ],
        };
        let e = plan.check().unwrap_err().to_string();
        assert!(e.contains("--vary sim.odometry.scale_sigma given twice"), "{e}");
        // Under a former spelling and today's, it is one parameter.
        let vary = vec![
            Vary::parse("sim.odometry.k_dd=0..0.1:2").unwrap(),
            Vary::parse("sim.odometry.a_dd=0..0.2:2").unwrap(),
        ];
        let e = StudyPlan { vary, ..plan }.check().unwrap_err().to_string();
        assert!(e.contains("--vary sim.odometry.a_dd given twice"), "{e}");
    }

    #[test]
    fn truncated_last_line_is_dropped() {
        let scratch = tempfile::tempdir().unwrap();
        let dir = scratch.path();
        let f = dir.join("runs.jsonl");
        let job = Job { index: 0, method: "nn".into(), params: vec![], run: 0, seed: 1 };
        let rec =
            RunRecord { key: job.key(), job, metrics: None, error: Some("x".into()), retryable: false, build: None };
        let line = serde_json::to_string(&rec).unwrap();
        std::fs::write(&f, format!("{line}\n{}", &line[..20])).unwrap();
        let runs = read_runs(&f).unwrap();
        assert_eq!(runs.len(), 1);
        assert_eq!(std::fs::read_to_string(&f).unwrap(), format!("{line}\n"));
        // Bytes that are not text are named by their line.
        std::fs::write(&f, [format!("{line}\n{line}\n").as_bytes(), b"\xff\xfe\n"].concat()).unwrap();
        let e = read_runs(&f).unwrap_err().to_string();
        assert!(e.contains("line 3: not UTF-8 text"), "{e}");
        // Records no study writes are refused by their line, not counted.
        let job = Job { index: 0, method: "nn".into(), params: vec![], run: 0, seed: 1 };
        let metrics: Metrics = serde_json::from_str(include_str!("../tests/data/metrics_sample.json")).unwrap();
        let record = |metrics: Option<Metrics>, error: Option<&str>, retryable: bool| RunRecord {
            key: job.key(),
            job: job.clone(),
            metrics,
            error: error.map(str::to_owned),
            retryable,
            build: None,
        };
        let mut beyond = metrics.clone();
        beyond.map.tree_recall = Some(7.5);
        for (bad, expect) in [
            (record(None, None, false), "neither metrics nor an error"),
            (record(Some(metrics.clone()), Some("x"), false), "both metrics and an error"),
            (record(Some(metrics.clone()), None, true), "a run to retry that has metrics"),
            (record(Some(beyond), None, false), "map.tree_recall 7.5 is not a fraction"),
        ] {
            std::fs::write(&f, format!("{line}\n{}\n", serde_json::to_string(&bad).unwrap())).unwrap();
            let e = read_runs(&f).unwrap_err().to_string();
            assert!(e.contains("line 2: ") && e.contains(expect), "{e}");
        }
        std::fs::write(&f, format!("{}\n", serde_json::to_string(&record(Some(metrics), None, false)).unwrap()))
            .unwrap();
        assert_eq!(read_runs(&f).unwrap().len(), 1);
    }

    /// Records appended as runs finished are put in job order, a job's lines in the order
    /// they were written (a retried run after its retryable record), byte for byte.
    #[test]
    fn finished_runs_file_is_put_in_job_order() {
        let scratch = tempfile::tempdir().unwrap();
        let dir = scratch.path();
        let f = dir.join("runs.jsonl");
        let line = |index: usize, error: &str, retryable: bool| {
            let job = Job { index, method: "nn".into(), params: vec![], run: index, seed: 1 };
            let rec =
                RunRecord { key: job.key(), job, metrics: None, error: Some(error.into()), retryable, build: None };
            serde_json::to_string(&rec).unwrap() + "\n"
        };
        let (a, b1, b2, c) = (line(0, "a", false), line(1, "died", true), line(1, "b", false), line(2, "c", false));
        std::fs::write(&f, [c.as_str(), b1.as_str(), a.as_str(), b2.as_str()].concat()).unwrap();
        put_in_job_order(&f).unwrap();
        assert_eq!(std::fs::read_to_string(&f).unwrap(), [a.as_str(), b1.as_str(), b2.as_str(), c.as_str()].concat());
        assert!(!dir.join("runs.jsonl.partial").exists());
        // A file in order is left as it is: not replaced (a rewrite is a rename, which
        // gives the path another inode).
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            let inode = std::fs::metadata(&f).unwrap().ino();
            put_in_job_order(&f).unwrap();
            assert_eq!(std::fs::metadata(&f).unwrap().ino(), inode, "a file in order was rewritten");
            std::fs::write(&f, [c.as_str(), a.as_str()].concat()).unwrap();
            let inode = std::fs::metadata(&f).unwrap().ino();
            put_in_job_order(&f).unwrap();
            assert_ne!(std::fs::metadata(&f).unwrap().ino(), inode, "the check above could not fail");
        }
    }

    /// A run whose worker died is to be run again, not a figure: the summary leaves it out.
    #[test]
    fn retryable_runs_are_not_summarised() {
        let plan = StudyPlan { scenario: "x".into(), base_seed: 1, runs: 2, methods: vec!["nn".into()], vary: vec![] };
        let all = jobs(&plan);
        let record = |k: usize, retryable: bool| RunRecord {
            key: all[k].key(),
            job: all[k].clone(),
            metrics: None,
            error: Some("x".into()),
            retryable,
            build: None,
        };
        let rows = summarise(&plan, &[record(0, false), record(1, true)]);
        assert_eq!((rows.len(), rows[0].runs, rows[0].errors), (1, 1, 1));
        assert_eq!(missing_runs(&plan, &[record(0, false), record(1, true)]), 1);
    }

    /// Runs of one setting made with two appearance models are refused; each setting may
    /// have its own (a varied training seed trains another).
    #[test]
    fn runs_of_one_setting_with_two_models_are_refused() {
        let plan = StudyPlan {
            scenario: "x".into(),
            base_seed: 1,
            runs: 2,
            methods: vec!["combined".into()],
            vary: vec![Vary { param: "appearance.training_seed".into(), values: vec![1.0, 2.0] }],
        };
        let all = jobs(&plan);
        let record = |k: usize, digest: &str| {
            let mut m: Metrics =
                serde_json::from_str(include_str!("../tests/data/metrics_sample.json")).expect("the sample parses");
            m.appearance_model = Some(crate::run::ModelProvenance {
                training_seed: 1,
                training_images: 1,
                training_renderer: None,
                digest: Some(digest.into()),
            });
            RunRecord {
                key: all[k].key(),
                job: all[k].clone(),
                metrics: Some(m),
                error: None,
                retryable: false,
                build: None,
            }
        };
        let file = Path::new("runs.jsonl");
        // Jobs 0 and 1 are one setting's two runs, 2 and 3 the other's.
        assert!(one_model_per_setting(&[record(0, "a"), record(1, "a"), record(2, "b"), record(3, "b")], file).is_ok());
        let e = one_model_per_setting(&[record(0, "a"), record(1, "c"), record(2, "b")], file).unwrap_err().to_string();
        assert!(e.contains("model a in jobs 0; model c in jobs 1"), "{e}");
        assert!(e.starts_with("runs.jsonl: runs of one setting used different appearance models"), "{e}");
    }
}
