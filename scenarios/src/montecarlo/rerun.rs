//! `objslam montecarlo rerun`: one job of a study run again, compared with its record.

use std::path::Path;

use super::*;

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
pub(super) fn keep_keys_of(value: &mut serde_json::Value, like: &serde_json::Value) {
    if let (serde_json::Value::Object(v), serde_json::Value::Object(l)) = (value, like) {
        v.retain(|k, _| l.contains_key(k));
        for (k, x) in v.iter_mut() {
            keep_keys_of(x, &l[k]);
        }
    }
}

/// Pushes to `out` the paths where `new` lacks or differs from a value of `recorded`:
/// objects compared key by key over `recorded`'s keys, other values by equality.
pub(super) fn differences_from_record(
    recorded: &serde_json::Value,
    new: &serde_json::Value,
    path: &str,
    out: &mut Vec<String>,
) {
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
    let study = super::plan::read_study_dir(dir)?;
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
pub(super) fn recorded_run(file: &Path, key: &str) -> Result<Option<(RunRecord, serde_json::Value)>, StudyError> {
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
