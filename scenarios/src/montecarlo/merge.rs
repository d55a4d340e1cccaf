//! `objslam montecarlo merge`: shard directories merged into one study.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::*;

/// Shards run on other machines read the scenario from other paths: the same study has
/// the same plan and the same scenario digest.
pub(super) fn digest(study: &StudyFile) -> Option<&str> {
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
pub(super) fn merge_held(dirs: &[PathBuf], out: &Path) -> Result<(StudyPlan, Vec<RunRecord>), StudyError> {
    let mut dirs = dirs.to_vec();
    refuse_benchmark_dir(out)?;
    super::refuse_run_dir(out)?;
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
    } else {
        super::refuse_unowned_summary(out)?;
    }
    let mut plan: Option<StudyFile> = None;
    let mut by_key: BTreeMap<String, RunRecord> = BTreeMap::new();
    for d in &dirs {
        let p = super::plan::read_study_dir(d)?;
        match &plan {
            Some(existing) if !same_study(existing, &p) => {
                let what = if crate::partial_files::same_path(d, out) { "the output directory" } else { "this shard" };
                // What differs, in study.json's own keys: the one thing to look at.
                let (a, b) = (serde_json::to_value(existing), serde_json::to_value(&p));
                let differ: Vec<String> = match (a, b) {
                    (Ok(serde_json::Value::Object(a)), Ok(serde_json::Value::Object(b))) => {
                        let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
                        // A pinned scenario may be typed otherwise from another directory:
                        // its digest (the pin) decides, not its spelling.
                        let pinned = existing.scenario_pin.is_some() && p.scenario_pin.is_some();
                        keys.into_iter()
                            .filter(|k| *k != "build" && !(pinned && *k == "scenario") && a.get(*k) != b.get(*k))
                            .cloned()
                            .collect()
                    }
                    _ => Vec::new(),
                };
                return Err(StudyError::File {
                    file: d.join("study.json"),
                    message: format!(
                        "{what} holds another study than {} (they differ in {}); shards of different studies cannot be merged: give the shards of one study",
                        dirs[0].display(),
                        if differ.is_empty() { "the scenario's contents".to_string() } else { differ.join(", ") }
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
pub(super) fn same_study(a: &StudyFile, b: &StudyFile) -> bool {
    same_plan(a, &b.plan) && b.scenario_pin.is_some() == a.scenario_pin.is_some() && digest(a) == digest(b)
}

/// Whether `plan` is the plan of `study`: where the study pinned the scenario it began
/// with, the scenario may be typed otherwise (from another working directory), and the
/// digest decides; without a pin, the plans must be equal as typed.
pub(super) fn same_plan(study: &StudyFile, plan: &StudyPlan) -> bool {
    let untyped = |p: &StudyPlan| StudyPlan { scenario: String::new(), ..p.clone() };
    match study.scenario_pin {
        Some(_) => untyped(&study.plan) == untyped(plan),
        None => study.plan == *plan,
    }
}
