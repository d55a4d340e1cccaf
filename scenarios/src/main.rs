//! `objslam`: the command-line front end. Only argument handling and printing live here;
//! the work is done by the library crates.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "objslam", version, about = "Simulation harness for object-recognition SLAM (Ramos, Nieto & Durrant-Whyte)")]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Generate, check, export and plot worlds.
    #[command(subcommand)]
    World(WorldCommand),
    /// Run a scenario (default: the paper's experiment) and score it against ground truth.
    Run {
        /// A scenario file or built-in name (paper_park, posts_near_trees, crowd,
        /// long_loop, laser_only).
        scenario: Option<String>,
        #[arg(long)]
        seed: Option<u64>,
        /// Association method: combined (the paper), nn, jcbb or appearance.
        #[arg(long)]
        method: Option<String>,
        /// Output directory (default runs/<scenario>-<seed>).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Simulate a world and write a sensor log (JSON lines, TUM, MCAP) that other SLAM
    /// systems can read.
    Record {
        /// A world file, or the name of a preset (`park`).
        input: String,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Stop after this many simulated seconds (default: when the route is done).
        #[arg(long)]
        duration: Option<f64>,
        /// TOML file of simulator settings (see `sim::SimConfig`).
        #[arg(long)]
        sim_config: Option<PathBuf>,
        #[arg(long)]
        out: PathBuf,
    },
}

#[derive(Subcommand)]
enum WorldCommand {
    /// Generate a world from a preset; TOML to stdout unless --out is given.
    Generate {
        #[arg(long, default_value = "park")]
        preset: String,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// TOML file of generator parameters (see `worlds::generate::ParkParams`).
        #[arg(long)]
        params: Option<PathBuf>,
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Validate a world file; prints a summary or every problem found.
    Check { file: PathBuf },
    /// Export a world as one glTF 2.0 binary (.glb).
    Export {
        file: PathBuf,
        #[arg(long)]
        out: PathBuf,
    },
    /// Draw a top view of a world, coloured by class, with routes and a scale bar.
    Plot {
        file: PathBuf,
        #[arg(long)]
        out: PathBuf,
    },
}

fn main() {
    let cli = Cli::parse();
    if let Err(e) = run(cli) {
        eprintln!("error: {e:#}");
        std::process::exit(2);
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        // The main job. The paper's default scenario needs the camera pipeline, which is
        // not built yet; until then run the position-only baseline on the paper's world.
        None => {
            eprintln!("no command given: running the built-in scenario laser_only (see `objslam --help`)");
            run_scenario(Some("laser_only"), None, None, None)
        }
        Some(Command::World(cmd)) => world(cmd),
        Some(Command::Run { scenario, seed, method, out }) => run_scenario(scenario.as_deref(), seed, method.as_deref(), out),
        Some(Command::Record { input, seed, duration, sim_config, out }) => record(&input, seed, duration, sim_config, &out),
    }
}

/// A world from a file path, or generated from a preset name with the seed.
fn load_world(input: &str, seed: u64) -> Result<worlds::World> {
    let path = std::path::Path::new(input);
    if !path.exists() && worlds::generate::PRESETS.contains(&input) {
        return Ok(worlds::generate::preset(input, None, seed)?);
    }
    Ok(worlds::load(path)?)
}

fn progress_bar(len: u64, what: &str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} s simulated, {elapsed} elapsed, ETA {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}

fn parse_method(name: &str) -> Result<slam::association::AssociationMethod> {
    slam::association::AssociationMethod::from_name(name)
        .ok_or_else(|| anyhow::anyhow!("unknown method {name:?}; use one of combined, nn, jcbb, appearance"))
}

fn run_scenario(scenario: Option<&str>, seed: Option<u64>, method: Option<&str>, out: Option<PathBuf>) -> Result<()> {
    let name = scenario.unwrap_or(scenarios::scenario::DEFAULT_SCENARIO);
    let (sc, base) = scenarios::scenario::Scenario::load(name)?;
    let method = method.map(parse_method).transpose()?;
    let seed = seed.unwrap_or(sc.seed);
    let out = out.unwrap_or_else(|| PathBuf::from(format!("runs/{}-{seed}", sc.name)));
    let bar = progress_bar(0, &format!("running {}", sc.name));
    let options = scenarios::run::RunOptions { seed: Some(seed), method, out: Some(out.clone()) };
    let outcome = scenarios::run::run(&sc, &base, &options, |t, total| {
        bar.set_length(total.ceil() as u64);
        bar.set_position((t.floor() as u64).min(total.ceil() as u64));
    })?;
    bar.finish_and_clear();
    print!("{}", scenarios::run::summary_table(&outcome.metrics));
    println!("  outputs in {}", out.display());
    if !outcome.metrics.passed {
        std::process::exit(1);
    }
    Ok(())
}

fn record(input: &str, seed: u64, duration: Option<f64>, sim_config: Option<PathBuf>, out: &std::path::Path) -> Result<()> {
    let world = load_world(input, seed)?;
    let mut config = match sim_config {
        Some(path) => {
            let text = std::fs::read_to_string(&path).with_context(|| format!("{}: cannot read", path.display()))?;
            toml::from_str::<sim::SimConfig>(&text).with_context(|| format!("{}: bad simulator settings", path.display()))?
        }
        None => sim::SimConfig::default(),
    };
    if duration.is_some() {
        config.max_duration_s = duration;
    }
    let bar = progress_bar(0, "recording");
    let summary = scenarios::record::record(&world, &config, seed, out, |t, total| {
        bar.set_length(total.ceil() as u64);
        bar.set_position((t.floor() as u64).min(total.ceil() as u64));
    })?;
    bar.finish_and_clear();
    println!(
        "recorded {:.1} s in {:.2} s ({:.0}x real time): {} scans, {} odometry messages, {} collisions -> {}",
        summary.sim_seconds,
        summary.wall_seconds,
        summary.sim_seconds / summary.wall_seconds.max(1e-9),
        summary.scans,
        summary.odometry,
        summary.collisions,
        out.display()
    );
    Ok(())
}

fn world(cmd: WorldCommand) -> Result<()> {
    match cmd {
        WorldCommand::Generate { preset, seed, params, out } => {
            let params = match params {
                Some(path) => {
                    let text = std::fs::read_to_string(&path).with_context(|| format!("{}: cannot read", path.display()))?;
                    Some(toml::from_str::<worlds::generate::ParkParams>(&text).with_context(|| format!("{}: bad generator parameters", path.display()))?)
                }
                None => None,
            };
            let world = worlds::generate::preset(&preset, params.as_ref(), seed)?;
            match out {
                Some(path) => {
                    worlds::save(&world, &path)?;
                    eprintln!("wrote {} ({} objects, {} people)", path.display(), world.objects.len(), world.people.len());
                }
                None => print!("{}", world.to_toml()),
            }
        }
        WorldCommand::Check { file } => {
            let w = worlds::load(&file)?;
            let mut counts = std::collections::BTreeMap::new();
            for o in &w.objects {
                *counts.entry(o.class.name()).or_insert(0) += 1;
            }
            println!("{}: ok", file.display());
            println!("  ground   {:.1} m²", w.ground.area_m2());
            for (class, n) in counts {
                println!("  {class:<8} {n}");
            }
            println!("  people   {}", w.people.len());
            println!("  route    {:.1} m x {} laps", w.robot.route.length_m(), w.robot.laps);
        }
        WorldCommand::Export { file, out } => {
            let w = worlds::load(&file)?;
            worlds::gltf_io::export_glb_file(&w, &out)?;
            eprintln!("wrote {}", out.display());
        }
        WorldCommand::Plot { file, out } => {
            let w = worlds::load(&file)?;
            let title = format!("{} (seed {}): {:.0} m²", w.name, w.seed, w.ground.area_m2());
            scenarios::plot::draw_map(&w, &scenarios::plot::Overlays { title, routes: true, ..Default::default() }, &out)?;
            eprintln!("wrote {}", out.display());
        }
    }
    Ok(())
}
