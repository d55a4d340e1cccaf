//! `objslam montecarlo`: studies, the built-in ones, merging shards, and their summaries.

use std::path::PathBuf;

use anyhow::{Context, Result};

use crate::args::{MethodArg, MontecarloArgs, MontecarloCommand, SplitArg};
use crate::progress;

/// `objslam montecarlo`: a study of a scenario, or one of the subcommands.
pub(crate) fn montecarlo(args: MontecarloArgs) -> Result<()> {
    use scenarios::montecarlo as mc;
    const MAX_RUN_TIMEOUT_S: f64 = 3.2e7;
    const DEFAULT_RUN_TIMEOUT_S: f64 = 1800.0;
    // Merging and rerunning run no study: settings of how a study runs would be ignored.
    if matches!(args.command, Some(MontecarloCommand::Merge { .. } | MontecarloCommand::Rerun { .. })) {
        let given = [
            args.jobs.map(|_| "--jobs"),
            args.in_process.then_some("--in-process"),
            args.run_timeout.map(|_| "--run-timeout"),
        ];
        if let Some(flag) = given.into_iter().flatten().next() {
            anyhow::bail!("{flag} says how a study's runs are run; `montecarlo merge` and `rerun` run no study");
        }
    }
    if args.in_process && args.run_timeout.is_some() {
        anyhow::bail!(
            "--run-timeout limits worker processes, and --in-process runs on threads, which cannot be killed"
        );
    }
    // Refused rather than honoured: in-process runs share rayon's one pool with the
    // trainings and the rendering inside each run, so a count of threads would not be a
    // count of runs (RAYON_NUM_THREADS sizes that pool).
    if args.in_process && args.jobs.is_some() {
        anyhow::bail!(
            "--jobs counts worker processes, and --in-process runs on this process's threads (RAYON_NUM_THREADS sets how many)"
        );
    }
    let run_timeout = args.run_timeout.unwrap_or(DEFAULT_RUN_TIMEOUT_S);
    let workers = if args.in_process {
        mc::Workers::Threads
    } else {
        let count = args.jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
        anyhow::ensure!(count > 0, "--jobs must be at least 1");
        // A year at most: longer is no limit at all, and far past it (1.8e19 s) the
        // conversion to a Duration would fail.
        anyhow::ensure!(
            run_timeout.is_finite() && (0.0..=MAX_RUN_TIMEOUT_S).contains(&run_timeout),
            "--run-timeout must be a number of seconds from 0 (no limit) to {MAX_RUN_TIMEOUT_S:e}, not {run_timeout}"
        );
        mc::Workers::Processes {
            exe: std::env::current_exe().context("cannot find the objslam executable to start worker processes")?,
            count,
            run_timeout: (run_timeout > 0.0).then(|| std::time::Duration::from_secs_f64(run_timeout)),
        }
    };
    if let Some(MontecarloCommand::Merge { dirs, out }) = args.command {
        let (plan, runs) = mc::merge(&dirs, &out)?;
        print_summary(&plan, &runs);
        let missing = mc::missing_runs(&plan, &runs);
        let planned = mc::jobs(&plan).len();
        println!(
            "merged {} of the plan's {planned} runs from {} into {}",
            planned - missing,
            count(dirs.len(), "directory", "directories"),
            out.display()
        );
        if missing > 0 {
            eprintln!(
                "warning: {missing} planned runs are in none of the directories (a shard not given, or runs not done yet, or to be retried); the summary covers the {} merged",
                planned - missing
            );
        }
        return Ok(());
    }
    if let Some(MontecarloCommand::Rerun { dir, job, out, scenario }) = args.command {
        return rerun(&dir, &job, &out, scenario.as_deref());
    }
    if let Some(MontecarloCommand::Study { runs, seed, shard, out }) = args.command {
        let shard = match &shard {
            Some(s) => mc::Shard::parse(s)?,
            None => mc::Shard::from_env(|k| std::env::var(k).ok(), None)?.unwrap_or(mc::Shard::all()),
        };
        let mut retry = Retry::default();
        let studies = mc::builtin_study(runs, seed);
        if out.is_file() {
            anyhow::bail!("--out {}: is a file, not a directory", out.display());
        }
        // Its studies go in subdirectories, beside no benchmark's report.
        if out.join(mc::BENCHMARK_WORLDS).exists() {
            anyhow::bail!(
                "--out {}: holds a generalisation benchmark ({}); the built-in study needs a directory of its own",
                out.display(),
                mc::BENCHMARK_WORLDS
            );
        }
        // Each study's directory is checked before the first runs: a later one holding
        // another study would otherwise be found only after the earlier ones' runs.
        for (name, plan) in &studies {
            mc::check_study_dir(plan, &out.join(name))?;
        }
        for (name, plan) in studies {
            println!("study {name}: {} = {:?}", plan.vary[0].param, plan.vary[0].values);
            retry.add(run_plan(&plan, shard, &out.join(name), &workers)?);
        }
        return retry.into_result();
    }
    if let Some(MontecarloCommand::Generalisation { split, runs, seed, shard, out }) = args.command {
        let split = match split {
            SplitArg::Tune => mc::generalisation::Split::Tune,
            SplitArg::Test => mc::generalisation::Split::Test,
        };
        return generalisation(split, runs, seed, shard.as_deref(), &out, &workers);
    }
    let scenario = args.scenario.expect("clap requires a scenario without a subcommand");
    // Spaces around the names and empty items are allowed ("nn, jcbb,"); an unknown name is
    // refused with the list, and a plan with no method by the plan's own check.
    let methods = args
        .methods
        .split(',')
        .map(str::trim)
        .filter(|m| !m.is_empty())
        .map(|m| {
            <MethodArg as clap::ValueEnum>::from_str(m, false)
                .map(|a| slam::association::AssociationMethod::from(a).name().to_string())
                .map_err(|_| anyhow::anyhow!("--methods: unknown method {m:?}; use combined, nn, jcbb or appearance"))
        })
        .collect::<Result<Vec<String>>>()?;
    let vary = args.vary.iter().map(|v| mc::Vary::parse(v)).collect::<Result<Vec<_>, _>>()?;
    // Check the scenario and every parameter value before starting hundreds of runs.
    let (sc, _) = scenarios::scenario::Scenario::load(&scenario)?;
    for v in &vary {
        for x in &v.values {
            mc::apply_param(&sc, &v.param, *x)?;
        }
    }
    let shard = match &args.shard {
        Some(s) => mc::Shard::parse(s)?,
        None => mc::Shard::from_env(|k| std::env::var(k).ok(), args.shard_count)?.unwrap_or(mc::Shard::all()),
    };
    let plan = mc::StudyPlan { scenario: scenario.clone(), base_seed: args.seed, runs: args.runs, methods, vary };
    plan.check()?;
    let out = args.out.unwrap_or_else(|| PathBuf::from(format!("runs/montecarlo-{}-{}", sc.name, args.seed)));
    run_plan(&plan, shard, &out, &workers)?.into_result()
}

/// `objslam montecarlo generalisation`: runs (or resumes) its two studies, then writes and
/// prints the report of what they hold.
fn generalisation(
    split: scenarios::montecarlo::generalisation::Split,
    worlds: usize,
    seed: u64,
    shard: Option<&str>,
    out: &std::path::Path,
    workers: &scenarios::montecarlo::Workers,
) -> Result<()> {
    use scenarios::montecarlo as mc;
    let shard = match shard {
        Some(s) => mc::Shard::parse(s)?,
        None => mc::Shard::from_env(|k| std::env::var(k).ok(), None)?.unwrap_or(mc::Shard::all()),
    };
    let plans = mc::generalisation::plans(split, worlds, seed)?;
    // The benchmark's directory is held for the whole command, as a study holds its own:
    // its worlds.json and report are written only by the one command running there.
    let _held = scenarios::partial_files::lock_output(out)?;
    if out.join("study.json").exists() || out.join("runs.jsonl").exists() {
        anyhow::bail!(
            "--out {}: holds a Monte Carlo study (study.json, runs.jsonl), whose summary the benchmark's report would replace; use a new directory",
            out.display()
        );
    }
    // Every plan must be sound, fit what the directory holds, and every world draw, before
    // anything is written or run; the draws are written down, so a failure can be traced
    // to its world.
    for (name, plan) in &plans {
        mc::check_study_dir(plan, &out.join(name))?;
    }
    let mut drawn = Vec::new();
    for i in 0..worlds {
        let params = mc::generalisation::world_params(split, i)?;
        let seed = mc::generalisation::world_seed(split, i);
        drawn.push(serde_json::json!({ "index": i, "seed": seed, "params": params }));
    }
    let drawn = serde_json::to_string_pretty(&drawn)?;
    // What the directory holds must be this benchmark's, begun (the same draws, to the
    // byte) or not: not someone's files of the report's names, nor the built-in study.
    let worlds_file = out.join(mc::BENCHMARK_WORLDS);
    let as_json = |text: &str| serde_json::from_str::<serde_json::Value>(text).ok();
    match std::fs::read_to_string(&worlds_file) {
        // Compared as JSON: the same draws with other line ends or spacing are the same.
        Ok(text) if as_json(&text).is_none() || as_json(&text) != as_json(&drawn) => anyhow::bail!(
            "{}: not the worlds this benchmark draws ({} {}); use a new --out directory",
            worlds_file.display(),
            worlds,
            if worlds == 1 { format!("{} world", split.name()) } else { format!("{} worlds", split.name()) }
        ),
        Ok(_) => {}
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            anyhow::bail!("{}: cannot read: {e}; use a new --out directory", worlds_file.display())
        }
        Err(_) => {
            if let Some(name) = ["summary.json", "generalisation.png", "odometry", "post_distance"]
                .into_iter()
                .find(|n| std::fs::symlink_metadata(out.join(n)).is_ok())
            {
                anyhow::bail!(
                    "--out {}: holds {name} but no benchmark (no {}): someone's files or the built-in study's, which the benchmark's report would sit among or replace; use a new --out directory",
                    out.display(),
                    mc::BENCHMARK_WORLDS
                );
            }
        }
    }
    mc::write_atomically(&worlds_file, &drawn)?;
    let mut retry = Retry::default();
    for (name, plan) in &plans {
        println!(
            "generalisation {name}: {} {}, {}",
            worlds,
            if worlds == 1 { format!("{} world", split.name()) } else { format!("{} worlds", split.name()) },
            count(mc::jobs(plan).len(), "run", "runs")
        );
        retry.add(run_plan(plan, shard, &out.join(name), workers)?);
    }
    // The report would leave the runs to retry out: they come first.
    retry.into_result()?;
    if shard != mc::Shard::all() {
        println!(
            "shard {}/{} done; the report needs every shard: merge each of {}/combined and {}/jcbb with `objslam montecarlo merge`, then rerun this command, without --shard, on the merged directory",
            shard.index,
            shard.count,
            out.display(),
            out.display()
        );
        return Ok(());
    }
    let read = |name: &str| mc::read_runs(&out.join(name).join("runs.jsonl"));
    let (combined, jcbb) = (read("combined")?, read("jcbb")?);
    let report = mc::generalisation::report(split, worlds, &combined, &jcbb);
    mc::write_atomically(&out.join("summary.json"), &serde_json::to_string_pretty(&report)?)?;
    let points = [mc::generalisation::recall_points(split, &combined), mc::generalisation::recall_points(split, &jcbb)];
    scenarios::plot::generalisation_plot(&report, &points[0], &points[1], &out.join("generalisation.png"))?;
    print!("{}", mc::generalisation::report_text(&report));
    println!("report in {} (summary.json, generalisation.png; the worlds drawn in worlds.json)", out.display());
    Ok(())
}

/// Runs whose worker died or timed out, over one or more studies: not results, so the
/// command ends with an error saying how to retry them once every study has run.
#[derive(Default)]
struct Retry {
    runs: usize,
    first: Option<String>,
}

impl Retry {
    fn add(&mut self, other: Retry) {
        self.runs += other.runs;
        self.first = self.first.take().or(other.first);
    }

    fn into_result(self) -> Result<()> {
        match self.first {
            None => Ok(()),
            Some(first) => anyhow::bail!(
                "{} runs to retry, their worker having died, timed out or refused (first: {first}); the summaries leave them out: run the same command again to retry them",
                self.runs
            ),
        }
    }
}

/// Runs (or resumes) one study with a progress bar (the study writes its summary), then
/// prints the summary;
/// returns the runs to retry.
fn run_plan(
    plan: &scenarios::montecarlo::StudyPlan,
    shard: scenarios::montecarlo::Shard,
    out: &std::path::Path,
    workers: &scenarios::montecarlo::Workers,
) -> Result<Retry> {
    use scenarios::montecarlo as mc;
    let bar = progress::StudyBar::new();
    let records = mc::run_study_with(plan, shard, out, workers, |p| bar.show(p))?;
    bar.finish();
    print_summary(plan, &records);
    let (retry, finished): (Vec<_>, Vec<_>) = records.iter().partition(|r| r.retryable);
    let errors = finished.iter().filter(|r| r.error.is_some()).count();
    // A resumed study's earlier runs are counted, but not as run in this command's time.
    let before = bar.done_before().min(finished.len());
    let ran = match before {
        0 => String::new(),
        n => format!(", {n} of them done before this command ({} run now)", finished.len() - n),
    };
    println!(
        "{} ({} with errors{ran}) in {:.1} s; shard {}/{}; results in {}",
        count(finished.len(), "run", "runs"),
        errors,
        bar.elapsed_s(),
        shard.index,
        shard.count,
        out.display()
    );
    if let Some(e) = finished.iter().find_map(|r| r.error.as_ref()) {
        println!("first error: {e}");
    }
    // Runs whose worker died are not results: the study is not finished until they are.
    Ok(Retry {
        runs: retry.len(),
        first: retry.first().map(|r| format!("job {}: {}", r.key, r.error.as_deref().unwrap_or("no message"))),
    })
}

/// Counted words: `1 run`, `2 runs`.
fn count(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

/// The summary table, and the builds that made the runs where there are several (a study
/// resumed or merged after a rebuild: `summary.json`'s `builds` counts their runs).
fn print_summary(plan: &scenarios::montecarlo::StudyPlan, runs: &[scenarios::montecarlo::RunRecord]) {
    print_rows(&scenarios::montecarlo::summarise(plan, runs));
    let builds = scenarios::montecarlo::builds(runs);
    if builds.len() > 1 {
        let each: Vec<String> = builds
            .iter()
            .map(|(b, n)| {
                let which = b.as_ref().map_or("a build that did not record itself".to_string(), |b| b.describe());
                format!("{which}: {}", count(*n, "run", "runs"))
            })
            .collect();
        println!("note: these runs were made by {} builds: {}", builds.len(), each.join("; "));
    }
}

fn print_rows(rows: &[scenarios::montecarlo::SummaryRow]) {
    println!(
        "{:<12} {:<32} {:>5} {:>8} {:>16} {:>8} {:>8} {:>8} {:>12}",
        "method", "parameters", "runs", "fail", "95% CI", "wrong", "false", "ATE m", "recall (min)"
    );
    for r in rows {
        let params: Vec<String> = r
            .params
            .iter()
            .map(|(p, v)| format!("{}={}", p.rsplit('.').next().unwrap_or(p), scenarios::montecarlo::short_number(*v)))
            .collect();
        let ci = format!("{:.1}-{:.1}%", 100.0 * r.failure_rate_ci95.0, 100.0 * r.failure_rate_ci95.1);
        println!(
            "{:<12} {:<32} {:>5} {:>7.1}% {:>16} {:>8.2} {:>8.2} {:>8.3} {:>5.2} ({:.2})",
            r.method,
            params.join(" "),
            r.runs,
            100.0 * r.failure_rate,
            ci,
            r.mean_wrong_associations,
            r.mean_false_landmarks,
            r.mean_ate_rmse_m,
            r.mean_tree_recall,
            r.min_tree_recall
        );
    }
}

/// `objslam montecarlo rerun`: one job again, with its outputs, against the study's record.
fn rerun(dir: &std::path::Path, job: &str, out: &std::path::Path, scenario: Option<&str>) -> Result<()> {
    let rerun = scenarios::montecarlo::rerun(dir, job, out, scenario)?;
    println!("job {} ({}), seed {}", rerun.job.index, rerun.job.key(), rerun.job.seed);
    let failed = match (&rerun.record.metrics, &rerun.record.error) {
        (Some(m), _) => {
            print!("{}", scenarios::run::summary_table(m));
            println!("  outputs in {}", out.display());
            false
        }
        (None, error) => {
            println!("  the run failed: {}", error.as_deref().unwrap_or("no metrics and no error"));
            true
        }
    };
    match rerun.repeats_record() {
        Some(true) => println!("  the same as the study's record in {}", dir.join("runs.jsonl").display()),
        // A run that failed (a refused output directory, say) has no figures to set beside the record's.
        Some(false) if failed => println!(
            "  so nothing is compared with the study's record in {}, which {}",
            dir.join("runs.jsonl").display(),
            match rerun.recorded.as_ref().is_some_and(|r| r.metrics.is_some()) {
                true => "has figures for this job",
                false => "records another failure for this job",
            }
        ),
        Some(false) => {
            println!(
                "  NOT the figures the study recorded in {} (same build, renderer and settings?); they differ in {}",
                dir.join("runs.jsonl").display(),
                rerun.differences().join(", ")
            );
            std::process::exit(1);
        }
        None => println!("  the study has no record of this job yet"),
    }
    if failed {
        std::process::exit(1);
    }
    Ok(())
}
