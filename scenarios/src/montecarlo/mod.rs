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
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use rayon::prelude::*;
use slam::association::AssociationMethod;

use crate::run::{Metrics, RunOptions};
use crate::scenario::{BUILT_IN_PREFIX, Scenario};
use crate::score::wilson_interval;

pub mod generalisation;
mod merge;
mod plan;
mod records;
mod rerun;
mod summary;
mod workers;
pub use merge::*;
pub use plan::*;
pub use records::*;
pub use rerun::*;
pub use summary::*;
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
/// Returns every record of this shard's jobs; the summary covers every record the
/// directory holds (a whole study resumed as one shard keeps its whole summary).
pub fn run_study_with(
    plan: &StudyPlan,
    shard: Shard,
    out: &Path,
    workers: &Workers,
    progress: impl Fn(StudyProgress) + Sync,
) -> Result<Vec<RunRecord>, StudyError> {
    plan.check()?;
    // The plan against its scenario, before anything is made.
    let (pin, base_scenario, base_dir) = pin_scenario(&plan.scenario)?;
    check_varied_settings_are_read(plan, &base_scenario)?;
    check_values_differ(plan, &base_scenario)?;
    // One study at a time per directory, as for any output directory: the hold goes with
    // the process, however it ends.
    let held = hold(out)?;
    // A study refused before its first run leaves no directory it made.
    let studied = (|| -> Result<Vec<RunRecord>, StudyError> {
        let plan_file = out.join("study.json");
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
        // Every job is checked before the first model is trained.
        let mut scenarios = Vec::with_capacity(todo.len());
        for job in &todo {
            let scenario = job_scenario(&base_scenario, job)?;
            let method = AssociationMethod::from_name(&job.method).ok_or_else(|| StudyError::Job {
                key: job.key(),
                message: format!("unknown method {:?}", job.method),
            })?;
            crate::run::run_config(&scenario, Some(method))
                .and_then(|_| crate::run::check_method_needs(&scenario, method))
                .map_err(|e| StudyError::Job { key: job.key(), message: e.to_string() })?;
            scenarios.push(scenario);
        }
        for (job, scenario) in todo.iter().zip(&scenarios) {
            if job_needs_appearance(job, scenario) {
                models
                    .resolve(scenario, |stage, done, total| progress(StudyProgress::Training { stage, done, total }))
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
        // Each run reads the scenario's world, calibration and model files as it begins (a
        // worker process the scenario too): a record is kept only while they are still the
        // ones pinned, so that a file edited mid-study stops the study there rather than
        // pooling two worlds' runs under one setting.
        let record_finished = |record: &RunRecord| -> Result<(), StudyError> {
            still_pinned(
                plan,
                &pin,
                ": the study stopped there, keeping the runs recorded before; restore the scenario and run the same \
                 command again, or start a new study",
            )?;
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
            Ok(())
        };
        let new: Vec<RunRecord> = match workers {
            Workers::Threads => {
                let changed: Mutex<Option<StudyError>> = Mutex::new(None);
                let new: Vec<RunRecord> = todo
                    .par_iter()
                    .filter_map(|job| {
                        if changed.lock().unwrap_or_else(|p| p.into_inner()).is_some() {
                            return None;
                        }
                        let record = run_job(&base_scenario, &base_dir, job, &models);
                        match record_finished(&record) {
                            Ok(()) => Some(record),
                            Err(e) => {
                                changed.lock().unwrap_or_else(|p| p.into_inner()).get_or_insert(e);
                                None
                            }
                        }
                    })
                    .collect();
                if let Some(e) = changed.into_inner().unwrap_or_else(|p| p.into_inner()) {
                    return Err(e);
                }
                new
            }
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
        // The summary covers every run the directory holds, this shard's and any other's it
        // was given (a whole study resumed as one shard): a summary of part of the file would
        // read as all of it. The caller gets this shard's.
        let mut all: Vec<RunRecord> = existing.into_iter().chain(new).collect();
        all.sort_by_key(|r| r.job.index);
        let keys: BTreeSet<String> = mine.iter().map(|j| j.key()).collect();
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
        Ok(all.into_iter().filter(|r| keys.contains(&r.key)).collect())
    })();
    match studied {
        Ok(all) => Ok(all),
        Err(e) => {
            held.release_failed();
            Err(e)
        }
    }
}

/// Whether the scenario `plan` names (its file, world file, model and calibration files)
/// is still the one `pin` recorded when the study began; if not, the words of what
/// changed followed by `then`, what the study did about it.
pub(super) fn still_pinned(plan: &StudyPlan, pin: &ScenarioPin, then: &str) -> Result<(), StudyError> {
    let (now, _, _) = pin_scenario(&plan.scenario)?;
    match pin.changed_to(&plan.scenario, &now) {
        Some(changed) => Err(StudyError::Plan(format!("{changed}{then}"))),
        None => Ok(()),
    }
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

/// What [`write_summary`] writes beside a study's `study.json` and `runs.jsonl`.
const SUMMARY_FILES: &[&str] = &["summary.csv", "summary.json", "failure_rate.png", "failure_rate.svg"];

/// Refuses a directory without a study that holds files of a summary's names: someone's
/// own, which the study's summary would replace.
pub(super) fn refuse_unowned_summary(out: &Path) -> Result<(), StudyError> {
    match crate::files::first_present(out, SUMMARY_FILES) {
        Some(name) => Err(StudyError::File {
            file: out.join(name),
            message: "a study writes this file, but the directory holds no study (no study.json); move it away or \
                      use a new --out directory"
                .into(),
        }),
        None => Ok(()),
    }
}

/// A study's plan, in its directory.
pub const STUDY_FILE: &str = "study.json";

/// Refuses a directory holding a run's or a recording's outputs (their `metadata.json`):
/// a study's records and summaries would sit among them, and the directory read as both.
pub(crate) fn refuse_run_dir(out: &Path) -> Result<(), StudyError> {
    let file = out.join(crate::files::METADATA);
    match std::fs::symlink_metadata(&file) {
        Ok(_) => Err(StudyError::File {
            file,
            message: "the directory holds a run's or a recording's outputs, not a study's; use a new --out directory"
                .into(),
        }),
        Err(_) => Ok(()),
    }
}

/// Whether `out` holds `plan`'s study already (`false`: it holds none); an error where it
/// holds another, runs without their plan, a run's outputs, or a generalisation benchmark.
fn existing_study(plan: &StudyPlan, pin: &ScenarioPin, out: &Path) -> Result<bool, StudyError> {
    refuse_benchmark_dir(out)?;
    refuse_run_dir(out)?;
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
            refuse_unowned_summary(out)?;
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
        // The refused value came from --vary, not a line of the scenario file.
        let e = apply_param(&s, "sim.odometry.scale_sigma", -0.05).unwrap_err().to_string();
        assert!(e.contains("sim.odometry.scale_sigma: must be finite and not negative"), "{e}");
        assert!(!e.contains("line "), "{e}");
        // A value the setting's type cannot hold: the reader's words, not its quote of the
        // generated text.
        let e = apply_param(&s, "pipeline.confirm_observations", -2.0).unwrap_err().to_string();
        assert!(!e.contains("line ") && !e.contains("|"), "{e}");
    }

    /// A method a study gives is held to what it needs of the settings before any run or
    /// training, as the scenario's own method is when it is read.
    #[test]
    fn a_study_method_is_checked_against_the_settings_it_needs() {
        let (mut s, _) = Scenario::load("laser_only").unwrap();
        s.appearance.pca_dims = 2;
        let e = crate::run::check_method_needs(&s, AssociationMethod::Combined).unwrap_err().to_string();
        assert!(
            e.contains("pipeline.object_model.appearance_dims: 4 is more than the trained appearance model's appearance.pca_dims = 2"),
            "{e}"
        );
        crate::run::check_method_needs(&s, AssociationMethod::Nn).unwrap();
        let root = std::env::temp_dir().join(format!("objslam-mc-needs-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(&root).unwrap();
        let file = root.join("small.toml");
        let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/laser_only.toml")).unwrap();
        std::fs::write(&file, format!("{text}\n[appearance]\npca_dims = 2\n")).unwrap();
        let plan = StudyPlan {
            scenario: file.display().to_string(),
            base_seed: 1,
            runs: 1,
            methods: vec!["nn".into(), "combined".into()],
            vary: vec![],
        };
        let e = run_study(&plan, Shard::all(), &root.join("out"), |_| {}).unwrap_err().to_string();
        assert!(e.contains("appearance_dims"), "{e}");
        assert!(!root.join("out/runs.jsonl").exists(), "no run was made");
        let _ = std::fs::remove_dir_all(&root);
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
        assert!(!out.exists(), "refused before the study began, leaving no directory");
        let _ = std::fs::remove_dir_all(&out);
        check_values_differ(&plan("world.seed=5..6:2"), &s).unwrap();
        let e = check_values_differ(&plan("sim.odometry.scale_sigma=0.01..0.0100000000000001:2"), &s)
            .unwrap_err()
            .to_string();
        assert!(e.contains("differ only beyond twelve significant digits"), "{e}");
        check_values_differ(&plan("sim.odometry.scale_sigma=0..0.02:3"), &s).unwrap();
        // A camera setting where no method reads the camera: every value's runs alike.
        let e =
            check_varied_settings_are_read(&plan("sim.camera.exposure_sigma=0..0.2:2"), &s).unwrap_err().to_string();
        assert!(e.contains("--vary sim.camera.exposure_sigma: no method of the study (nn) reads the camera"), "{e}");
        let with_camera =
            StudyPlan { methods: vec!["nn".into(), "combined".into()], ..plan("appearance.training_seed=1..2:2") };
        check_varied_settings_are_read(&with_camera, &s).unwrap();
        // Other settings a position-only study never reads.
        for key in [
            "pipeline.object_model.kl_threshold=10..80:2",
            "pipeline.evidence.min_frames=2..4:2",
            "pipeline.image_max_age_s=0.01..0.05:2",
        ] {
            let e = check_varied_settings_are_read(&plan(key), &s).unwrap_err().to_string();
            assert!(e.contains("no method of the study (nn) reads the camera"), "{e}");
        }
        let e =
            check_varied_settings_are_read(&plan("pipeline.diameter.max_sigmas=1..3:2"), &s).unwrap_err().to_string();
        assert!(e.contains("use the trunk diameter only with pipeline.diameter.for_position_methods = true"), "{e}");
        let mut diameter = s.clone();
        diameter.pipeline.diameter.for_position_methods = true;
        check_varied_settings_are_read(&plan("pipeline.diameter.max_sigmas=1..3:2"), &diameter).unwrap();
        // JCBB's probability: read by jcbb, and by combined where it closes loops jointly.
        let jcbb_p = |methods: &[&str]| StudyPlan {
            methods: methods.iter().map(|m| m.to_string()).collect(),
            ..plan("pipeline.jcbb_probability=0.9..0.99:2")
        };
        let e = check_varied_settings_are_read(&jcbb_p(&["nn"]), &s).unwrap_err().to_string();
        assert!(e.contains("only the jcbb method and the combined method's joint loop closing read it"), "{e}");
        check_varied_settings_are_read(&jcbb_p(&["nn", "jcbb"]), &s).unwrap();
        check_varied_settings_are_read(&jcbb_p(&["combined"]), &s).unwrap();
        let mut no_joint = s.clone();
        no_joint.pipeline.joint_loop_closing = false;
        let e = check_varied_settings_are_read(&jcbb_p(&["combined"]), &no_joint).unwrap_err().to_string();
        assert!(e.contains("with pipeline.joint_loop_closing = false"), "{e}");
        let session = StudyPlan { methods: vec!["combined".into()], ..plan("calibration.session.poses=5..10:2") };
        let e = check_varied_settings_are_read(&session, &s).unwrap_err().to_string();
        assert!(e.contains("runs only with calibration mode \"estimated\", and this scenario's is \"true\""), "{e}");
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
        // A count too large to hold is named as such, not as no number.
        let e = Shard::parse("1/99999999999999999999999").unwrap_err().to_string();
        assert!(e.contains("N is too large"), "{e}");
        assert!(Shard::parse("x/2").unwrap_err().to_string().contains("K is not a whole number"));
        let e = Vary::parse("odometry.noise=0..1:99999999999999999999999").unwrap_err().to_string();
        assert!(e.contains(&format!("STEPS is too large (at most {})", MAX_VARY_STEPS)), "{e}");
        let e = Shard::from_env(env(&[("JOB_COMPLETION_INDEX", "1e3")]), Some(3)).unwrap_err().to_string();
        assert!(e.contains("JOB_COMPLETION_INDEX=1e3") && e.contains("the value is not a whole number"), "{e}");
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
        let job = Job { index: 0, method: "combined".into(), params: vec![], run: 0, seed: 1 };
        let metrics: Metrics = serde_json::from_str(include_str!("../../tests/data/metrics_sample.json")).unwrap();
        let mut other_seed = metrics.clone();
        other_seed.seed = 2;
        let mut other_method = metrics.clone();
        other_method.method = "nn".into();
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
            (record(Some(other_seed), None, false), "metrics.seed 2 is not its job's seed 1"),
            (record(Some(other_method), None, false), "metrics.method \"nn\" is not its job's method \"combined\""),
        ] {
            std::fs::write(&f, format!("{line}\n{}\n", serde_json::to_string(&bad).unwrap())).unwrap();
            let e = read_runs(&f).unwrap_err().to_string();
            assert!(e.contains("line 2: ") && e.contains(expect), "{e}");
        }
        std::fs::write(&f, format!("{}\n", serde_json::to_string(&record(Some(metrics), None, false)).unwrap()))
            .unwrap();
        assert_eq!(read_runs(&f).unwrap().len(), 1);
    }

    /// Records appended as runs finished are put in job order, byte for byte, one per job:
    /// a retried run's record replaces the retryable one before it.
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
        assert_eq!(std::fs::read_to_string(&f).unwrap(), [a.as_str(), b2.as_str(), c.as_str()].concat());
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
                serde_json::from_str(include_str!("../../tests/data/metrics_sample.json")).expect("the sample parses");
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
