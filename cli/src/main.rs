//! `objslam`: the command line. Only argument handling, progress bars and printing live
//! here; the work is done by the library crates, which return errors and warnings to it.

mod appearance;
mod args;
mod paths;
mod progress;
mod run;
mod sensors;
mod study;
mod world;

use anyhow::Result;
use clap::Parser;

use crate::args::{Cli, Command, ConfigCommand, GmmCommand};

fn main() {
    quiet_on_closed_stdout();
    if let Some(commit) = option_env!("OBJSLAM_COMMIT") {
        scenarios::build::set(commit, option_env!("OBJSLAM_MODIFIED") == Some("true"));
    }
    let cli = Cli::parse();
    if let Err(e) = dispatch(cli) {
        eprintln!("error: {}", report(&e));
        std::process::exit(2);
    }
}

/// Ends the program quietly, as a closed pipe's signal would, when what reads its output
/// or its messages stops reading (`objslam gmm fit ... | head -2`, `objslam run 2>&1 |
/// head`): Rust ignores that signal, which a study's worker pipes need, so printing to a
/// closed stdout or stderr panics instead.
fn quiet_on_closed_stdout() {
    let report = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let message = payload.downcast_ref::<String>().map(String::as_str).or(payload.downcast_ref::<&str>().copied());
        let printing =
            |m: &str| m.starts_with("failed printing to stdout") || m.starts_with("failed printing to stderr");
        if message.is_some_and(|m| printing(m) && m.contains("Broken pipe")) {
            // 128 + SIGPIPE: what a shell reports for a program its pipe ended.
            std::process::exit(141);
        }
        report(info)
    }));
}

/// Most mixture components `--max-components` may ask for: far more than any search here
/// can fit in reasonable time, few enough that a typo is caught.
const MAX_COMPONENTS: usize = 1000;

fn check_components(max_components: usize) -> Result<()> {
    if !(1..=MAX_COMPONENTS).contains(&max_components) {
        anyhow::bail!("--max-components must be 1 to {MAX_COMPONENTS}, got {max_components}");
    }
    Ok(())
}

/// The error and its causes on one line, each cause once: the library's errors often say
/// their cause in their own message already (so that a message stored in a study record is
/// complete), and the chain would repeat it.
fn report(e: &anyhow::Error) -> String {
    let mut text = e.to_string();
    for cause in e.chain().skip(1) {
        let cause = cause.to_string();
        if !text.contains(&cause) {
            text.push_str(": ");
            text.push_str(&cause);
        }
    }
    text
}

fn dispatch(cli: Cli) -> Result<()> {
    match cli.command {
        // The main job: the paper's experiment with its method (trains the appearance model
        // from generated images on first use and caches it).
        None => {
            eprintln!("no command given: running the paper's experiment, scenario paper_park (see `objslam --help`)");
            run::run_scenario(Some("paper_park"), None, None, None, false, None)
        }
        Some(Command::World(cmd)) => world::world(cmd),
        Some(Command::Run { scenario, seed, method, out, full_frames, bag }) => {
            run::run_scenario(scenario.as_deref(), seed, method, out, full_frames, bag)
        }
        Some(Command::Montecarlo(args)) => study::montecarlo(args),
        Some(Command::MontecarloWorker) => {
            Ok(scenarios::montecarlo::serve_worker(std::io::stdin().lock(), std::io::stdout().lock())?)
        }
        Some(Command::Dataset { world, preset, images, seed, classes, patch_size, out }) => {
            sensors::dataset(world, preset, images, seed, &classes, patch_size, &out)
        }
        Some(Command::Record { input, scenario, seed, duration, sim_config, format, no_camera, out }) => {
            let source = match (scenario, input) {
                (Some(name), _) => sensors::RecordSource::Scenario(name),
                (None, Some(input)) => sensors::RecordSource::World { input, sim_config },
                (None, None) => unreachable!("clap requires one of them"),
            };
            sensors::record(source, seed, duration, format.into(), no_camera, &out)
        }
        Some(Command::Score(args)) => run::score(args),
        Some(Command::Replay { log, options, dataset }) => run::replay(log, options, dataset),
        Some(Command::Calibrate { scenario, poses, seed, out, images }) => {
            sensors::calibrate(scenario.as_deref().unwrap_or("calibration"), poses, seed, &out, images.as_deref())
        }
        Some(Command::Train(args)) => {
            check_components(args.max_components)?;
            if args.pca_dims == 0 {
                anyhow::bail!("--pca-dims must be at least 1");
            }
            appearance::train(&args)
        }
        Some(Command::Segment { model, image, out }) => appearance::segment(&model, &image, &out),
        Some(Command::Find { run, image, model, top }) => appearance::find(&run, &image, model.as_deref(), top),
        Some(Command::Gmm(GmmCommand::Fit { data, max_components, fixed_k, search, seed, out })) => {
            check_components(max_components)?;
            let options =
                slam::gmm::VbOptions { max_components, fixed_k, seed, search: search.into(), ..Default::default() };
            appearance::gmm_fit(&data, &options, &out)
        }
        Some(Command::Gmm(GmmCommand::Score { model, data })) => appearance::gmm_score(&model, &data),
        Some(Command::Config(ConfigCommand::Defaults { table })) => {
            print!("{}", scenarios::scenario::Scenario::defaults_toml(table.as_deref())?);
            Ok(())
        }
        Some(Command::Config(ConfigCommand::Check { scenario, method, seed })) => {
            run::check(&scenario, method.map(Into::into), seed)
        }
    }
}
