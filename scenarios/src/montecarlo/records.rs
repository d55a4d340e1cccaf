//! `runs.jsonl`: one record per finished run, appended whole, read back with a torn last
//! line repaired, and put in job order once a study's runs are done.

use std::collections::BTreeMap;
use std::fs::OpenOptions;
use std::io::Write;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::*;

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
    /// never both or neither, only an error to retry, metrics of its job's seed and method,
    /// and a recall that is a fraction.
    pub(super) fn check(&self) -> Result<(), String> {
        match (&self.metrics, &self.error) {
            (Some(_), Some(_)) => return Err("a run record with both metrics and an error".into()),
            (None, None) => return Err("a run record with neither metrics nor an error".into()),
            (Some(_), None) if self.retryable => return Err("a run to retry that has metrics".into()),
            _ => {}
        }
        // The metrics are the run of its job: the same seed and method.
        if let Some(m) = &self.metrics {
            if m.seed != self.job.seed {
                return Err(format!("metrics.seed {} is not its job's seed {}", m.seed, self.job.seed));
            }
            if m.method != self.job.method {
                return Err(format!("metrics.method {:?} is not its job's method {:?}", m.method, self.job.method));
            }
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

/// Reads `runs.jsonl`, dropping a truncated last line (and truncating the file to the last
/// complete line so appends start clean). A job recorded twice keeps one record: a final
/// record wins over a retryable one, the later retryable one over an earlier; two final
/// records that differ (wall clock aside) are an error naming both lines.
pub fn read_runs(path: &Path) -> Result<Vec<RunRecord>, StudyError> {
    Ok(one_record_per_job(path, read_run_lines(path)?)?.into_iter().map(|(_, r)| r).collect())
}

/// `records` (line, record) of the file `path` with one record per job, as [`read_runs`]
/// keeps them, each with its line.
pub(super) fn one_record_per_job(
    path: &Path,
    records: Vec<(usize, RunRecord)>,
) -> Result<Vec<(usize, RunRecord)>, StudyError> {
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
pub(super) fn read_run_lines(path: &Path) -> Result<Vec<(usize, RunRecord)>, StudyError> {
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
pub(super) fn complete_lines(path: &Path) -> Result<(String, bool), StudyError> {
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
pub(super) fn parse_run_lines(path: &Path, complete: &str) -> Result<Vec<(usize, RunRecord)>, StudyError> {
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

/// Rewrites `runs.jsonl` at `path` with one line per job (the record [`read_runs`] keeps:
/// a retried run's, not the retryable one before it) in job order, where it is not so
/// already: runs are appended as they finish, in an order that depends on how many workers
/// ran them and on whether the study was stopped and resumed, and a study's files are to
/// be the same whatever ran it. Done by the study that holds the directory, after its last
/// append.
pub(super) fn put_in_job_order(path: &Path) -> Result<(), StudyError> {
    let (text, _) = complete_lines(path)?;
    let records = parse_run_lines(path, &text)?;
    let written = records.len();
    let kept = one_record_per_job(path, records)?;
    let lines: Vec<&str> = text.lines().collect();
    let mut order: Vec<(usize, &str)> = kept.iter().map(|(line, r)| (r.job.index, lines[line - 1])).collect();
    if kept.len() == written && order.is_sorted_by_key(|(index, _)| *index) {
        return Ok(());
    }
    order.sort_by_key(|(index, _)| *index);
    write_atomically(path, &order.iter().map(|(_, line)| format!("{line}\n")).collect::<String>())
}

/// Appends one record as a whole line and syncs it; on failure the file is cut back to its
/// length before the write, so no torn line is left for the next record to join.
pub(super) fn append_record(f: &mut std::fs::File, record: &RunRecord) -> std::io::Result<()> {
    let line = serde_json::to_string(record).expect("JSON") + "\n";
    let before = f.metadata()?.len();
    let written = f.write_all(line.as_bytes()).and_then(|_| f.sync_data());
    if written.is_err() {
        let _ = f.set_len(before);
    }
    written
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
