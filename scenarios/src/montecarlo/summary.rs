//! A study's summary: failure rates with Wilson intervals per method and parameter
//! values, the builds that made the runs, `summary.json` and the plot.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::*;

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
pub(super) fn builds_json(runs: &[RunRecord]) -> serde_json::Value {
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
