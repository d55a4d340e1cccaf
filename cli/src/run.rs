//! `objslam run`, `replay` and `score`: the commands that score a run and write its
//! metrics.json.

use scenarios::files;
use std::path::PathBuf;

use anyhow::Result;
use slam::association::AssociationMethod;

use crate::args::{MethodArg, ReplayArgs, ReplayDataset, ScoreArgs};
use crate::progress;

/// `objslam run` (and the main job, with no command).
pub(crate) fn run_scenario(
    scenario: Option<&str>,
    seed: Option<u64>,
    method: Option<MethodArg>,
    out: Option<PathBuf>,
    full_frames: bool,
    bag: Option<PathBuf>,
) -> Result<()> {
    let name = scenario.unwrap_or(scenarios::scenario::DEFAULT_SCENARIO);
    let (sc, base) = scenarios::scenario::Scenario::load(name)?;
    for changed in scenarios::run::changed_inputs(std::path::Path::new(name), &sc, &base) {
        eprintln!("warning: {changed}");
    }
    let method = method.map(AssociationMethod::from);
    let seed = seed.unwrap_or(sc.seed);
    let out = out.unwrap_or_else(|| PathBuf::from(format!("runs/{}-{seed}", sc.name)));
    let mut bar = progress::RunBar::new(&sc.name);
    let options = scenarios::run::RunOptions {
        seed: Some(seed),
        method,
        out: Some(out.clone()),
        appearance: None,
        full_frames,
        bag,
    };
    let outcome = scenarios::run::run(&sc, &base, &options, |p| bar.show(p));
    bar.finish();
    let outcome = outcome?;
    if let Some(changed) =
        scenarios::run::changed_model(std::path::Path::new(name), outcome.metrics.appearance_model.as_ref())
    {
        eprintln!("warning: {changed}");
    }
    print!("{}", scenarios::run::summary_table(&outcome.metrics));
    println!("  outputs in {}", out.display());
    if !outcome.metrics.passed {
        std::process::exit(1);
    }
    Ok(())
}

/// Refuses a `LOG` directory that holds another output of objslam (a JSON-lines log, a
/// ROS 2 bag), saying what it is, rather than naming a `manifest.toml` that was never
/// there. (A file or a missing directory is the log reader's to refuse.)
fn check_robot_log_dir(dir: &std::path::Path) -> Result<()> {
    if !dir.is_dir() || dir.join(robotlog::format::MANIFEST).exists() {
        return Ok(());
    }
    let problem = if dir.join(files::METADATA).exists() {
        "a JSON-lines log of `objslam record` or a run's directory, which `objslam score --log` reads; \
         `objslam record --format log` writes a robot log for `objslam replay`"
    } else if dir.join("metadata.yaml").exists() {
        "a ROS 2 bag; `objslam replay` reads a robot log (docs/reference/robot-log.md), which \
         `objslam record --format log` writes"
    } else {
        return Ok(()); // The reader names the missing manifest.toml.
    };
    anyhow::bail!("{}: {problem}", dir.display())
}

/// `objslam replay`: a robot log, or a published data set.
pub(crate) fn replay(log: Option<PathBuf>, options: ReplayArgs, dataset: Option<ReplayDataset>) -> Result<()> {
    // The log's directory, and whether it is Victoria Park's files (else a robot log).
    let (log_dir, victoria_park, log, options): (PathBuf, bool, robotlog::stream::LogStream, _) = match (dataset, log) {
        (Some(ReplayDataset::VictoriaPark { data, options }), _) => {
            let log = robotlog::victoria_park::read(&data)?.into();
            (data, true, log, options.into())
        }
        (None, Some(dir)) => {
            check_robot_log_dir(&dir)?;
            let log = robotlog::format::open(&dir)?;
            (dir, false, log, options)
        }
        (None, None) => anyhow::bail!("give a log directory, or a data set: `objslam replay victoria-park --data DIR`"),
    };
    let method = options.method.map(AssociationMethod::from);
    let out = options.out.expect("clap requires --out");
    let robot_log = (!victoria_park).then_some(log_dir.as_path());
    let config = scenarios::replay::resolve_config(robot_log, &log.manifest, method, options.config.as_deref())?;
    // The model given, else the log's own for a camera method.
    let beside_log =
        robot_log.map(|d| d.join(files::APPEARANCE_MODEL)).filter(|f| config.method.uses_appearance() && f.is_file());
    let appearance = match options.appearance_model.as_ref().or(beside_log.as_ref()) {
        Some(file) => {
            println!("appearance model: {}", file.display());
            Some(slam::classifier::AppearanceModel::load(file)?)
        }
        None => None,
    };
    // The files read, the log's own model among them where it is read.
    let source = if victoria_park {
        scenarios::replay::LogSource::of(&log_dir, &robotlog::victoria_park::files_read(&log_dir))
    } else {
        scenarios::replay::LogSource::of_robot_log(&log_dir, options.appearance_model.is_none() && beside_log.is_some())
    };
    let result = scenarios::replay::replay_from(log, Some(&source), config, appearance, Some(&out))?;
    println!("{}", scenarios::replay::summary(&result.metrics));
    println!("  outputs in {}", out.display());
    Ok(())
}

/// `objslam score`: a system's estimate against a recorded log or a run's outputs.
pub(crate) fn score(args: ScoreArgs) -> Result<()> {
    if args.method.as_deref().is_some_and(|m| m.trim().is_empty()) {
        anyhow::bail!("--method: an empty name; give the system's name, or leave --method out");
    }
    // The log's own metrics.json (a run's) would be replaced by the system's.
    crate::paths::not_an_input("--out", &args.out, &[("log", &args.log)])?;
    let metrics = args.out.join(files::METRICS);
    let inputs =
        [Some(&args.trajectory), args.covariances.as_ref(), args.landmarks.as_ref(), args.associations.as_ref()];
    for input in inputs.into_iter().flatten() {
        crate::paths::not_an_input("--out", &metrics, &[("estimate file", input)])?;
    }
    // Nor the log, or a file of it through a link (its metadata.json, a run's metrics.json).
    crate::paths::not_inside("--out", &metrics, "log", &args.log)?;
    // Nor any other run's or log's directory: its metrics.json is that run's, and the
    // directory is read as a log by it.
    if args.out.join(files::METADATA).exists() {
        anyhow::bail!(
            "--out {}: holds the outputs of a run or a recorded log ({}), whose {} the score would replace; give a directory of its own",
            args.out.display(),
            files::METADATA,
            files::METRICS
        );
    }
    let estimate = scenarios::score::log::Estimate {
        trajectory: args.trajectory,
        covariances: args.covariances,
        landmarks: args.landmarks,
        associations: args.associations,
        method: args.method,
        recall_basis: args.recall_basis.map(Into::into),
    };
    let m = scenarios::score::log::score_log(&args.log, &estimate)?;
    scenarios::partial_files::make_output_dir(&args.out)?;
    let file = args.out.join(files::METRICS);
    crate::paths::write_whole(&file, serde_json::to_string_pretty(&m)? + "\n")?;
    print!("{}", scenarios::score::log::summary_table(&m));
    println!("  metrics in {}", file.display());
    if m.passed == Some(false) {
        std::process::exit(1);
    }
    Ok(())
}

/// `objslam config check`: what a run checks before its first step.
pub(crate) fn check(name: &str, method: Option<AssociationMethod>, seed: Option<u64>) -> Result<()> {
    let (sc, base) = scenarios::scenario::Scenario::load(name)?;
    // The settings and files it names are the scenario's: say which scenario, where the
    // message does not already.
    let found = scenarios::run::preflight(&sc, &base, method, seed).map_err(|e| {
        let e = anyhow::Error::from(e);
        if crate::report(&e).contains(name) { e } else { e.context(name.to_string()) }
    })?;
    println!("{name}: ok");
    println!("  method       {}", found.method.name());
    println!(
        "  world        {} objects, {} people (run seed {})",
        found.objects,
        found.people,
        seed.unwrap_or(sc.seed)
    );
    println!("  calibration  {}", found.calibration);
    if let Some(a) = &found.appearance {
        println!("  appearance   {a}");
    }
    Ok(())
}
