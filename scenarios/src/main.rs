//! `objslam`: the command-line front end. Only argument handling and printing live here;
//! the work is done by the library crates.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "objslam",
    version,
    about = "Simulation harness for object-recognition SLAM (Ramos, Nieto & Durrant-Whyte)"
)]
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
        /// long_loop, laser_only, calibration, city_park).
        scenario: Option<String>,
        #[arg(long)]
        seed: Option<u64>,
        /// Association method: combined (the paper), nn, jcbb or appearance.
        #[arg(long)]
        method: Option<String>,
        /// Output directory (default runs/<scenario>-<seed>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Render whole camera frames, not only the image columns the pipeline reads (the
        /// same results, more slowly).
        #[arg(long)]
        full_frames: bool,
        /// Also write the run's sensor stream as a ROS 2 bag in this directory (frames are
        /// then rendered whole).
        #[arg(long)]
        bag: Option<PathBuf>,
    },
    /// Monte Carlo association-failure studies (parallel, resumable, shardable).
    Montecarlo(MontecarloArgs),
    /// Make training images with exact masks, patch labels, a manifest and COCO annotations.
    Dataset {
        /// A world file...
        #[arg(long, conflicts_with = "preset")]
        world: Option<PathBuf>,
        /// ... or a generator preset (its world seed is --seed).
        #[arg(long)]
        preset: Option<String>,
        #[arg(long, default_value_t = 100)]
        images: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Comma-separated classes labelled positive.
        #[arg(long, default_value = "tree")]
        classes: String,
        /// Patch side L in pixels.
        #[arg(long, default_value_t = 9)]
        patch_size: u32,
        #[arg(long)]
        out: PathBuf,
    },
    /// Serves Monte Carlo jobs on stdin/stdout for a parent `objslam montecarlo`.
    #[command(hide = true)]
    MontecarloWorker,
    /// Simulate a world and write a sensor log (JSON lines, TUM, MCAP) that other SLAM
    /// systems can read.
    Record {
        /// A world file, or the name of a preset (`park`).
        #[arg(required_unless_present = "scenario", conflicts_with = "scenario")]
        input: Option<String>,
        /// Record a scenario's world and simulator as `objslam run` simulates them for the
        /// same seed, with its pass criteria for `objslam score` (a file or built-in name).
        #[arg(long)]
        scenario: Option<String>,
        /// World and simulator seed (default: 1, or the scenario's seed).
        #[arg(long)]
        seed: Option<u64>,
        /// Stop after this many simulated seconds (default: when the route is done).
        #[arg(long)]
        duration: Option<f64>,
        /// TOML file of simulator settings (see `sim::SimConfig`).
        #[arg(long, conflicts_with = "scenario")]
        sim_config: Option<PathBuf>,
        /// `jsonl`: JSON lines, TUM, PNGs and a Foxglove MCAP; `ros2`: a ROS 2 bag
        /// (`ros2 bag play OUT`); `log`: a robot log for `objslam replay`.
        #[arg(long, value_enum, default_value_t = scenarios::record::RecordFormat::Jsonl)]
        format: scenarios::record::RecordFormat,
        #[arg(long)]
        out: PathBuf,
    },
    /// Run the `slam` pipeline on a recorded log: a real robot's (docs/reference/robot-log.md),
    /// one that `objslam record --format log` wrote, or a published data set
    /// (`objslam replay victoria-park --data DIR`). Writes what `objslam run` writes, where
    /// it applies, scored against the log's ground truth or GPS.
    #[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
    Replay {
        /// The log directory.
        #[arg(required = true)]
        log: Option<PathBuf>,
        #[command(flatten)]
        options: ReplayArgs,
        #[command(subcommand)]
        dataset: Option<ReplayDataset>,
    },
    /// Laser-camera extrinsic calibration (Zhang & Pless) on a scenario's checkerboard
    /// session; prints the errors against the simulator's true extrinsics.
    Calibrate {
        /// A scenario file or built-in name (default: calibration).
        scenario: Option<String>,
        /// Number of board poses (default: the scenario's session).
        #[arg(long)]
        poses: Option<usize>,
        /// Session seed (default: the scenario's seed).
        #[arg(long)]
        seed: Option<u64>,
        #[arg(long, default_value = "calibration.json")]
        out: PathBuf,
        /// Write each pose's camera image here, detected corners marked.
        #[arg(long)]
        images: Option<PathBuf>,
    },
    /// Learn the appearance model (PCA, object and background VB-GMMs) from an
    /// `objslam dataset` directory; prints held-out patch precision, recall and F1.
    Train {
        #[arg(long)]
        dataset: PathBuf,
        #[arg(long)]
        out: PathBuf,
        /// Also write every patch's feature row and label to this CSV file.
        #[arg(long)]
        export_features: Option<PathBuf>,
        /// PCA dimension d.
        #[arg(long, default_value_t = 20)]
        pca_dims: usize,
        /// Most mixture components per class.
        #[arg(long, default_value_t = 20)]
        max_components: usize,
        /// Hold out every N-th image for scoring (0: none).
        #[arg(long, default_value_t = 5)]
        heldout_every: usize,
        /// A patch is object when R = w_obj p_obj / (w_obj p_obj + w_bg p_bg) exceeds this.
        #[arg(long, default_value_t = 0.5)]
        threshold: f64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Classify an image's patches with a model and draw the object patches over it.
    Segment {
        #[arg(long)]
        model: PathBuf,
        image: PathBuf,
        #[arg(long)]
        out: PathBuf,
    },
    /// Find objects that look like this: rank a run's mapped objects by the KL divergence
    /// of their appearance from an example image's object patches.
    Find {
        /// A run directory written by `objslam run` (its objects/ holds the models).
        #[arg(long)]
        run: PathBuf,
        image: PathBuf,
        /// Appearance model (default: the one the run used, objects/appearance_model.json).
        #[arg(long)]
        model: Option<PathBuf>,
        /// How many to list.
        #[arg(long, default_value_t = 5)]
        top: usize,
    },
    /// Variational Bayesian Gaussian mixtures on any numeric CSV.
    #[command(subcommand)]
    Gmm(GmmCommand),
    /// Score any SLAM system's trajectory (and map and associations) against a log of
    /// `objslam record`, by the rules `objslam run` scores its own runs with.
    Score(ScoreArgs),
    /// Settings: print every scenario setting at its default.
    #[command(subcommand)]
    Config(ConfigCommand),
}

#[derive(clap::Args)]
struct ScoreArgs {
    /// The log directory `objslam record` wrote.
    #[arg(long)]
    log: PathBuf,
    /// The estimated trajectory, TUM format, world frame.
    #[arg(long)]
    trajectory: PathBuf,
    /// The estimated map: a JSON array of {"id", "position": [x, y]}.
    #[arg(long)]
    landmarks: Option<PathBuf>,
    /// What each laser cluster of each scan went to (JSON lines, as `objslam run` writes
    /// associations.jsonl).
    #[arg(long)]
    associations: Option<PathBuf>,
    /// The system's name in the report.
    #[arg(long)]
    method: Option<String>,
    /// The recall's denominator (default: trees in view when the log has camera frames).
    #[arg(long, value_enum)]
    recall_basis: Option<scenarios::score::scorer::RecallBasis>,
    /// Where to write metrics.json.
    #[arg(long)]
    out: PathBuf,
}

#[derive(Subcommand)]
enum ConfigCommand {
    /// Print the complete default scenario as TOML, from the code's defaults (or one
    /// table of it, e.g. `pipeline.evidence`).
    Defaults { table: Option<String> },
}

/// `objslam gmm fit --search`.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum SearchArg {
    Prune,
    Grow,
}

impl From<SearchArg> for slam::gmm::Search {
    fn from(s: SearchArg) -> Self {
        match s {
            SearchArg::Prune => slam::gmm::Search::Prune,
            SearchArg::Grow => slam::gmm::Search::Grow,
        }
    }
}

#[derive(Subcommand)]
enum GmmCommand {
    /// Fit a VB-GMM (searching for the number of components up to --max-components, or
    /// fixed K).
    Fit {
        data: PathBuf,
        #[arg(long, default_value_t = 10)]
        max_components: usize,
        /// Use exactly --max-components components instead of searching.
        #[arg(long)]
        fixed_k: bool,
        /// How to search for the number of components: `prune` starts from
        /// --max-components and lets VBEM empty and delete components (fast); `grow` starts
        /// from one and splits (what `objslam train` uses).
        #[arg(long, value_enum, default_value_t = SearchArg::Prune)]
        search: SearchArg,
        /// Seed of the k-means++ start (`--fixed-k` and `--search prune`).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        #[arg(long)]
        out: PathBuf,
    },
    /// Print a fitted model's mean held-out log-likelihood per point on a CSV (the
    /// posterior predictive density), to compare models fitted to the same data.
    Score { model: PathBuf, data: PathBuf },
}

#[derive(clap::Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
struct MontecarloArgs {
    #[command(subcommand)]
    command: Option<MontecarloCommand>,
    /// Scenario file or built-in name.
    #[arg(required = true)]
    scenario: Option<String>,
    /// Runs per method and parameter value.
    #[arg(long, default_value_t = 100)]
    runs: usize,
    /// Comma-separated association methods.
    #[arg(long, default_value = "combined,nn,jcbb,appearance")]
    methods: String,
    /// PARAM=A..B:STEPS, a dotted path into the scenario (repeatable), e.g.
    /// sim.odometry.scale_sigma=0.0..0.05:6 or world.params.post_distance_m=0.5..3:6.
    #[arg(long)]
    vary: Vec<String>,
    /// Base seed: run r gets a seed derived from (seed, r).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Run only slice K of N (0-based); defaults to the Slurm array / Kubernetes index
    /// from the environment when present.
    #[arg(long)]
    shard: Option<String>,
    /// Number of shards when the index comes from JOB_COMPLETION_INDEX.
    #[arg(long)]
    shard_count: Option<usize>,
    #[arg(long)]
    out: Option<PathBuf>,
    /// Runs at a time, each in its own worker process (default: one per core).
    #[arg(long, global = true)]
    jobs: Option<usize>,
    /// Run on threads of this process instead of worker processes (slower: runs in one
    /// process share the software renderer's locks; no --run-timeout).
    #[arg(long, global = true)]
    in_process: bool,
    /// Seconds a worker process may spend on one run before it is killed and the run
    /// recorded as retryable (resuming the study runs it again); 0: no limit.
    #[arg(long, global = true, default_value_t = 1800.0, allow_negative_numbers = true)]
    run_timeout: f64,
}

#[derive(Subcommand)]
enum MontecarloCommand {
    /// Merge shard directories into one study.
    Merge {
        dirs: Vec<PathBuf>,
        #[arg(long)]
        out: PathBuf,
    },
    /// The built-in study of the paper's argument on paper_park: failure rate of combined,
    /// nn and jcbb against odometry heading drift (DIR/odometry) and against post-to-tree
    /// distance (DIR/post_distance). Resumable and shardable like any study.
    Study {
        /// Runs per method and parameter value.
        #[arg(long, default_value_t = 10)]
        runs: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Run only slice K of N of each sub-study (0-based).
        #[arg(long)]
        shard: Option<String>,
        #[arg(long, default_value = "runs/study")]
        out: PathBuf,
    },
    /// The generalisation benchmark: the paper's claim on park worlds drawn from a wide
    /// distribution (docs/guide/monte-carlo.md), combined with 5 appearance training seeds
    /// (DIR/combined) and jcbb for reference (DIR/jcbb); writes DIR/summary.json and
    /// DIR/generalisation.png. Resumable and shardable like any study.
    Generalisation {
        /// Which worlds: `tune` to choose settings on, `test` to report (disjoint seeds).
        #[arg(long, value_enum, default_value_t = SplitArg::Test)]
        split: SplitArg,
        /// Worlds to draw (each run with every training seed).
        #[arg(long, default_value_t = 10)]
        runs: usize,
        /// Base seed of the runs' simulations.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Run only slice K of N of each of the two studies (0-based).
        #[arg(long)]
        shard: Option<String>,
        #[arg(long, default_value = "runs/generalisation")]
        out: PathBuf,
    },
}

/// `objslam montecarlo generalisation --split`.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum SplitArg {
    Tune,
    Test,
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
        // The main job: the paper's experiment with its method (trains the appearance model
        // from generated images on first use and caches it).
        None => {
            eprintln!("no command given: running the paper's experiment, scenario paper_park (see `objslam --help`)");
            run_scenario(Some("paper_park"), None, None, None, false, None)
        }
        Some(Command::World(cmd)) => world(cmd),
        Some(Command::Run { scenario, seed, method, out, full_frames, bag }) => {
            run_scenario(scenario.as_deref(), seed, method.as_deref(), out, full_frames, bag)
        }
        Some(Command::Montecarlo(args)) => montecarlo(args),
        Some(Command::MontecarloWorker) => {
            Ok(scenarios::montecarlo::serve_worker(std::io::stdin().lock(), std::io::stdout().lock())?)
        }
        Some(Command::Dataset { world, preset, images, seed, classes, patch_size, out }) => {
            dataset(world, preset, images, seed, &classes, patch_size, &out)
        }
        Some(Command::Record { input, scenario, seed, duration, sim_config, format, out }) => {
            let source = match (scenario, input) {
                (Some(name), _) => RecordSource::Scenario(name),
                (None, Some(input)) => RecordSource::World { input, sim_config },
                (None, None) => unreachable!("clap requires one of them"),
            };
            record(source, seed, duration, format, &out)
        }
        Some(Command::Score(args)) => score(args),
        Some(Command::Replay { log, options, dataset }) => replay(log, options, dataset),
        Some(Command::Calibrate { scenario, poses, seed, out, images }) => {
            calibrate(scenario.as_deref().unwrap_or("calibration"), poses, seed, &out, images.as_deref())
        }
        Some(Command::Train {
            dataset,
            out,
            export_features,
            pca_dims,
            max_components,
            heldout_every,
            threshold,
            seed,
        }) => {
            train(&dataset, &out, export_features.as_deref(), pca_dims, max_components, heldout_every, threshold, seed)
        }
        Some(Command::Segment { model, image, out }) => segment(&model, &image, &out),
        Some(Command::Find { run, image, model, top }) => find(&run, &image, model.as_deref(), top),
        Some(Command::Gmm(GmmCommand::Fit { data, max_components, fixed_k, search, seed, out })) => {
            let options =
                slam::gmm::VbOptions { max_components, fixed_k, seed, search: search.into(), ..Default::default() };
            gmm_fit(&data, &options, &out)
        }
        Some(Command::Gmm(GmmCommand::Score { model, data })) => {
            let (mean, points) = scenarios::train::gmm_score_csv(&model, &data)?;
            println!("{points} points of {} under {}", data.display(), model.display());
            println!("mean held-out log-likelihood: {mean:.6} nats per point (posterior predictive, PRML 10.81)");
            Ok(())
        }
        Some(Command::Config(ConfigCommand::Defaults { table })) => {
            print!("{}", scenarios::scenario::Scenario::defaults_toml(table.as_deref())?);
            Ok(())
        }
    }
}

/// What every replay takes.
#[derive(clap::Args, Debug)]
struct ReplayArgs {
    /// Association method: `nn` or `jcbb` (the camera methods need images; default `nn`).
    #[arg(long)]
    method: Option<String>,
    /// A TOML file of pipeline settings (`[pipeline]` keys, as in a scenario) over the
    /// replay's defaults and the log's own `pipeline.toml`.
    #[arg(long)]
    config: Option<PathBuf>,
    #[arg(long, required = true)]
    out: Option<PathBuf>,
}

/// Published data sets that `objslam replay` reads as they are published.
#[derive(Subcommand, Debug)]
enum ReplayDataset {
    /// Victoria Park (ACFR, University of Sydney: Guivant & Nebot). DIR holds the published
    /// files: `VictoriaParkSinSincronizar.mat` (tree detections), or `aa3_dr.mat` with
    /// `aa3_lsr2.mat`; and `aa3_gpsx.mat` for GPS.
    VictoriaPark {
        #[arg(long)]
        data: PathBuf,
        #[command(flatten)]
        options: ReplayArgs,
    },
}

fn replay(log: Option<PathBuf>, options: ReplayArgs, dataset: Option<ReplayDataset>) -> Result<()> {
    let (log_dir, log, options) = match (dataset, log) {
        (Some(ReplayDataset::VictoriaPark { data, options }), _) => {
            (None, robotlog::victoria_park::read(&data)?, options)
        }
        (None, Some(dir)) => {
            let log = robotlog::format::read(&dir)?;
            (Some(dir), log, options)
        }
        (None, None) => anyhow::bail!("give a log directory, or a data set: `objslam replay victoria-park --data DIR`"),
    };
    let method = options.method.as_deref().map(parse_method).transpose()?;
    let out = options.out.expect("clap requires --out");
    let config = scenarios::replay::resolve_config(log_dir.as_deref(), &log, method, options.config.as_deref())?;
    let result = scenarios::replay::replay(&log, config)?;
    scenarios::replay::write_outputs(&out, &log, &result)?;
    println!("{}", scenarios::replay::summary(&result.metrics));
    println!("  outputs in {}", out.display());
    Ok(())
}

fn score(args: ScoreArgs) -> Result<()> {
    let estimate = scenarios::score::log::Estimate {
        trajectory: args.trajectory,
        landmarks: args.landmarks,
        associations: args.associations,
        method: args.method,
        recall_basis: args.recall_basis,
    };
    let m = scenarios::score::log::score_log(&args.log, &estimate)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("{}: cannot create", args.out.display()))?;
    let file = args.out.join("metrics.json");
    std::fs::write(&file, serde_json::to_string_pretty(&m)? + "\n")
        .with_context(|| format!("{}: cannot write", file.display()))?;
    print!("{}", scenarios::score::log::summary_table(&m));
    println!("  metrics in {}", file.display());
    if m.passed == Some(false) {
        std::process::exit(1);
    }
    Ok(())
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
        indicatif::ProgressStyle::with_template(
            "{msg} [{bar:40}] {pos}/{len} s simulated, {elapsed} elapsed, ETA {eta}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}

fn dataset(
    world: Option<PathBuf>,
    preset: Option<String>,
    images: usize,
    seed: u64,
    classes: &str,
    patch_size: u32,
    out: &std::path::Path,
) -> Result<()> {
    let (w, name) = match (world, preset) {
        (Some(path), None) => (worlds::load(&path)?, path.display().to_string()),
        (None, preset) => {
            let p = preset.unwrap_or_else(|| "park".into());
            (worlds::generate::preset(&p, None, seed)?, format!("preset {p}, seed {seed}"))
        }
        (Some(_), Some(_)) => anyhow::bail!("give either --world or --preset"),
    };
    let classes = classes
        .split(',')
        .map(|c| {
            worlds::ObjectClass::from_name(c.trim()).ok_or_else(|| {
                anyhow::anyhow!("unknown class {c:?}; classes: tree, palm, post, wall, person, checkerboard")
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let config = scenarios::dataset::DatasetConfig { images, seed, classes, patch_size, ..Default::default() };
    let bar = indicatif::ProgressBar::new(images as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("dataset [{bar:40}] {pos}/{len} images, {elapsed} elapsed, ETA {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let started = std::time::Instant::now();
    let manifest = scenarios::dataset::make_dataset(&w, &name, &config, out, |done, _| bar.set_position(done as u64))?;
    bar.finish_and_clear();
    println!(
        "{} images ({}x{}) in {:.1} s on {} -> {}",
        manifest.images.len(),
        manifest.width,
        manifest.height,
        started.elapsed().as_secs_f64(),
        manifest.renderer,
        out.display()
    );
    Ok(())
}

fn montecarlo(args: MontecarloArgs) -> Result<()> {
    use scenarios::montecarlo as mc;
    let workers = if args.in_process {
        mc::Workers::Threads
    } else {
        let count = args.jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
        anyhow::ensure!(count > 0, "--jobs must be at least 1");
        anyhow::ensure!(
            args.run_timeout.is_finite() && args.run_timeout >= 0.0,
            "--run-timeout must be a number of seconds, 0 or more (0: no limit), not {}",
            args.run_timeout
        );
        mc::Workers::Processes {
            exe: std::env::current_exe().context("cannot find the objslam executable to start worker processes")?,
            count,
            run_timeout: (args.run_timeout > 0.0).then(|| std::time::Duration::from_secs_f64(args.run_timeout)),
        }
    };
    if let Some(MontecarloCommand::Merge { dirs, out }) = args.command {
        let (plan, runs) = mc::merge(&dirs, &out)?;
        let rows = mc::summarise(&plan, &runs);
        mc::write_summary(&plan, &rows, &out)?;
        print_summary(&rows);
        println!("merged {} runs from {} directories into {}", runs.len(), dirs.len(), out.display());
        return Ok(());
    }
    if let Some(MontecarloCommand::Study { runs, seed, shard, out }) = args.command {
        let shard = match &shard {
            Some(s) => mc::Shard::parse(s)?,
            None => mc::Shard::from_env(|k| std::env::var(k).ok(), None)?.unwrap_or(mc::Shard::all()),
        };
        for (name, plan) in mc::builtin_study(runs, seed) {
            println!("study {name}: {} = {:?}", plan.vary[0].param, plan.vary[0].values);
            run_plan(&plan, shard, &out.join(name), &workers)?;
        }
        return Ok(());
    }
    if let Some(MontecarloCommand::Generalisation { split, runs, seed, shard, out }) = args.command {
        let split = match split {
            SplitArg::Tune => mc::generalisation::Split::Tune,
            SplitArg::Test => mc::generalisation::Split::Test,
        };
        return generalisation(split, runs, seed, shard.as_deref(), &out, &workers);
    }
    let scenario = args.scenario.expect("clap requires a scenario without a subcommand");
    let methods: Vec<String> =
        args.methods.split(',').map(|m| m.trim().to_string()).filter(|m| !m.is_empty()).collect();
    for m in &methods {
        parse_method(m)?;
    }
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
    run_plan(&plan, shard, &out, &workers)
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
    let plans = mc::generalisation::plans(split, worlds, seed);
    if worlds == 0 {
        anyhow::bail!("--runs must be at least 1 world");
    }
    // Every plan must be sound and every world draw before the first run; the draws are
    // written down, so a failure can be traced to its world.
    for (_, plan) in &plans {
        plan.check()?;
    }
    let mut drawn = Vec::new();
    for i in 0..worlds {
        let params = mc::generalisation::world_params(split, i)?;
        let seed = mc::generalisation::world_seed(split, i);
        drawn.push(serde_json::json!({ "index": i, "seed": seed, "params": params }));
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    mc::write_atomically(&out.join("worlds.json"), &serde_json::to_string_pretty(&drawn)?)?;
    for (name, plan) in &plans {
        println!("generalisation {name}: {worlds} {} worlds, {} runs", split.name(), mc::jobs(plan).len());
        run_plan(plan, shard, &out.join(name), workers)?;
    }
    if shard != mc::Shard::all() {
        println!(
            "shard {}/{} done; the report needs every shard: merge each of {}/combined and {}/jcbb with `objslam montecarlo merge`, then rerun this command on the merged directory",
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

/// Runs (or resumes) one study with a progress bar, then writes and prints its summary.
fn run_plan(
    plan: &scenarios::montecarlo::StudyPlan,
    shard: scenarios::montecarlo::Shard,
    out: &std::path::Path,
    workers: &scenarios::montecarlo::Workers,
) -> Result<()> {
    use scenarios::montecarlo as mc;
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "study [{bar:40}] {pos}/{len} runs, {msg}, {elapsed} elapsed, ETA {eta}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    let started = std::time::Instant::now();
    let first_done = std::sync::Mutex::new(None::<usize>);
    let records = mc::run_study_with(plan, shard, out, workers, |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
        let mut first = first_done.lock().unwrap_or_else(|p| p.into_inner());
        let base = *first.get_or_insert(done);
        let minutes = started.elapsed().as_secs_f64() / 60.0;
        if minutes > 0.0 {
            bar.set_message(format!("{:.1} runs/min", (done - base) as f64 / minutes));
        }
    })?;
    bar.finish_and_clear();
    let rows = mc::summarise(plan, &records);
    mc::write_summary(plan, &rows, out)?;
    print_summary(&rows);
    let errors = records.iter().filter(|r| r.error.is_some()).count();
    println!(
        "{} runs ({} with errors) in {:.1} s; shard {}/{}; results in {}",
        records.len(),
        errors,
        started.elapsed().as_secs_f64(),
        shard.index,
        shard.count,
        out.display()
    );
    if let Some(e) = records.iter().find_map(|r| r.error.as_ref()) {
        println!("first error: {e}");
    }
    Ok(())
}

fn print_summary(rows: &[scenarios::montecarlo::SummaryRow]) {
    println!(
        "{:<12} {:<32} {:>5} {:>8} {:>16} {:>8} {:>8} {:>8} {:>12}",
        "method", "parameters", "runs", "fail", "95% CI", "wrong", "false", "ATE m", "recall (min)"
    );
    for r in rows {
        let params: Vec<String> =
            r.params.iter().map(|(p, v)| format!("{}={v:.3}", p.rsplit('.').next().unwrap_or(p))).collect();
        println!(
            "{:<12} {:<32} {:>5} {:>7.1}% {:>7.1}-{:<7.1}% {:>8.2} {:>8.2} {:>8.3} {:>5.2} ({:.2})",
            r.method,
            params.join(" "),
            r.runs,
            100.0 * r.failure_rate,
            100.0 * r.failure_rate_ci95.0,
            100.0 * r.failure_rate_ci95.1,
            r.mean_wrong_associations,
            r.mean_false_landmarks,
            r.mean_ate_rmse_m,
            r.mean_tree_recall,
            r.min_tree_recall
        );
    }
}

fn parse_method(name: &str) -> Result<slam::association::AssociationMethod> {
    slam::association::AssociationMethod::from_name(name)
        .ok_or_else(|| anyhow::anyhow!("unknown method {name:?}; use one of combined, nn, jcbb, appearance"))
}

fn run_scenario(
    scenario: Option<&str>,
    seed: Option<u64>,
    method: Option<&str>,
    out: Option<PathBuf>,
    full_frames: bool,
    bag: Option<PathBuf>,
) -> Result<()> {
    let name = scenario.unwrap_or(scenarios::scenario::DEFAULT_SCENARIO);
    let (sc, base) = scenarios::scenario::Scenario::load(name)?;
    let method = method.map(parse_method).transpose()?;
    let seed = seed.unwrap_or(sc.seed);
    let out = out.unwrap_or_else(|| PathBuf::from(format!("runs/{}-{seed}", sc.name)));
    let bar = progress_bar(0, &format!("running {}", sc.name));
    let options = scenarios::run::RunOptions {
        seed: Some(seed),
        method,
        out: Some(out.clone()),
        appearance: None,
        full_frames,
        bag,
    };
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

fn calibrate(
    scenario: &str,
    poses: Option<usize>,
    seed: Option<u64>,
    out: &std::path::Path,
    images: Option<&std::path::Path>,
) -> Result<()> {
    let (sc, base) = scenarios::scenario::Scenario::load(scenario)?;
    let seed = seed.unwrap_or(sc.seed);
    let started = std::time::Instant::now();
    let report = scenarios::calibrate::run_session(&sc, &base, seed, poses, images)?;
    report.write(out)?;
    let (rs, ts) = (report.rotation_sigma_deg, report.translation_sigma_m);
    println!(
        "calibration of {} (seed {seed}): {} of {} board poses used, {} laser points, {:.1} s on {}",
        sc.name,
        report.poses_used,
        report.poses_requested,
        report.points_used,
        started.elapsed().as_secs_f64(),
        report.renderer
    );
    println!("  residuals         RMS {:.4} m, max {:.4} m", report.rms_residual_m, report.max_residual_m);
    println!(
        "  1-sigma           rotation ({:.3}, {:.3}, {:.3}) deg, translation ({:.4}, {:.4}, {:.4}) m",
        rs[0], rs[1], rs[2], ts[0], ts[1], ts[2]
    );
    if let (Some(r), Some(t)) = (report.rotation_error_deg, report.translation_error_m) {
        println!("  rotation error    {r:.3} deg (against the simulator's extrinsics)");
        println!("  translation error {t:.4} m");
    }
    for w in &report.warnings {
        println!("  warning: {w}");
    }
    println!("  written to {}", out.display());
    Ok(())
}

/// What `objslam record` simulates.
enum RecordSource {
    World { input: String, sim_config: Option<PathBuf> },
    Scenario(String),
}

fn record(
    source: RecordSource,
    seed: Option<u64>,
    duration: Option<f64>,
    format: scenarios::record::RecordFormat,
    out: &std::path::Path,
) -> Result<()> {
    let (world, mut config, sim_seed, scoring, pipeline) = match source {
        RecordSource::World { input, sim_config } => {
            let seed = seed.unwrap_or(1);
            let config = match sim_config {
                Some(path) => {
                    let text =
                        std::fs::read_to_string(&path).with_context(|| format!("{}: cannot read", path.display()))?;
                    toml::from_str::<sim::SimConfig>(&text)
                        .with_context(|| format!("{}: bad simulator settings", path.display()))?
                }
                None => sim::SimConfig::default(),
            };
            (load_world(&input, seed)?, config, seed, scenarios::score::log::LogScoring::of_world(), None)
        }
        RecordSource::Scenario(name) => {
            let (sc, base) = scenarios::scenario::Scenario::load(&name)?;
            let seed = seed.unwrap_or(sc.seed);
            // The world and simulator seeds a run of this scenario and seed uses.
            let world = sc.world(&base, seed)?;
            (
                world,
                sc.sim.clone(),
                sim::derive_seed(seed, "sim"),
                scenarios::score::log::LogScoring::of_scenario(&sc, seed),
                Some(scenarios::run::pipeline_config(&sc, None)?),
            )
        }
    };
    if duration.is_some() {
        config.max_duration_s = duration;
    }
    let bar = progress_bar(0, "recording");
    let show = |t: f64, total: f64| {
        bar.set_length(total.ceil() as u64);
        bar.set_position((t.floor() as u64).min(total.ceil() as u64));
    };
    let summary = match format {
        // A scenario's log carries its pipeline settings, for `objslam replay`.
        scenarios::record::RecordFormat::Log => {
            scenarios::record::record_log(&world, &config, sim_seed, pipeline.as_ref(), out, show)?
        }
        _ => scenarios::record::record(&world, &config, sim_seed, &scoring, out, format, show)?,
    };
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
                    let text =
                        std::fs::read_to_string(&path).with_context(|| format!("{}: cannot read", path.display()))?;
                    Some(
                        toml::from_str::<worlds::generate::ParkParams>(&text)
                            .with_context(|| format!("{}: bad generator parameters", path.display()))?,
                    )
                }
                None => None,
            };
            let world = worlds::generate::preset(&preset, params.as_ref(), seed)?;
            match out {
                Some(path) => {
                    worlds::save(&world, &path)?;
                    eprintln!(
                        "wrote {} ({} objects, {} people)",
                        path.display(),
                        world.objects.len(),
                        world.people.len()
                    );
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
            scenarios::plot::draw_map(
                &w,
                &scenarios::plot::Overlays { title, routes: true, ..Default::default() },
                &out,
            )?;
            eprintln!("wrote {}", out.display());
        }
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn train(
    dataset: &std::path::Path,
    out: &std::path::Path,
    export: Option<&std::path::Path>,
    pca_dims: usize,
    max_components: usize,
    heldout_every: usize,
    threshold: f64,
    seed: u64,
) -> Result<()> {
    anyhow::ensure!((0.0..=1.0).contains(&threshold), "--threshold must lie in [0, 1], got {threshold}");
    let options = slam::classifier::TrainingOptions {
        pca_dims,
        seed,
        threshold,
        vb: slam::gmm::VbOptions { max_components, ..Default::default() },
        ..Default::default()
    };
    let bar = indicatif::ProgressBar::new(1);
    bar.set_style(
        indicatif::ProgressStyle::with_template("train {msg:>18} [{bar:40}] {pos}/{len}, {elapsed} elapsed")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let started = std::time::Instant::now();
    let model = scenarios::train::train_from_dataset(dataset, &options, heldout_every, |stage, done, total| {
        bar.set_message(stage.to_string());
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })?;
    bar.finish_and_clear();
    model.save(out)?;
    let t = &model.training;
    println!("trained on {} images in {:.1} s -> {}", t.images, started.elapsed().as_secs_f64(), out.display());
    println!(
        "  PCA: {} -> {} dimensions, {:.1}% of the variance",
        model.extractor.config.raw_dims(),
        model.extractor.pca.dims(),
        100.0 * t.pca_explained_variance
    );
    println!(
        "  object: {} patches ({} fitted), {} components; background: {} patches ({} fitted), {} components; w_obj = {:.3}",
        t.object_patches,
        t.fitted_object_patches,
        model.object.effective_components(1e-3),
        t.background_patches,
        t.fitted_background_patches,
        model.background.effective_components(1e-3),
        model.object_weight
    );
    match &t.heldout {
        Some(s) => println!(
            "  held-out patches: precision {:.3}, recall {:.3}, F1 {:.3} ({} object patches of {})",
            s.precision(),
            s.recall(),
            s.f1(),
            s.true_positives + s.false_negatives,
            s.true_positives + s.false_negatives + s.false_positives + s.true_negatives
        ),
        None => println!("  no held-out images (--heldout-every 0)"),
    }
    if heldout_every > 0 {
        let table = scenarios::train::confusion_by_class(dataset, &model, heldout_every)?;
        let parts: Vec<String> = table
            .iter()
            .map(|(name, (n, obj))| format!("{name} {obj}/{n} ({:.1}%)", 100.0 * *obj as f64 / (*n).max(1) as f64))
            .collect();
        println!("  held-out patches called object, by true class: {}", parts.join(", "));
    }
    if let Some(csv) = export {
        let rows = scenarios::train::export_features(dataset, &model, options.label_fraction, csv)?;
        println!("  {rows} feature rows -> {}", csv.display());
    }
    Ok(())
}

fn segment(model: &std::path::Path, image: &std::path::Path, out: &std::path::Path) -> Result<()> {
    let model = slam::classifier::AppearanceModel::load(model)?;
    let (objects, total) = scenarios::train::segment_image(&model, image, out)?;
    println!("{objects} of {total} patches classified as object -> {}", out.display());
    Ok(())
}

fn gmm_fit(data: &std::path::Path, options: &slam::gmm::VbOptions, out: &std::path::Path) -> Result<()> {
    let started = std::time::Instant::now();
    let model = scenarios::train::gmm_fit_csv(data, options)?;
    let secs = started.elapsed().as_secs_f64();
    std::fs::write(out, serde_json::to_string_pretty(&model)?).with_context(|| format!("writing {}", out.display()))?;
    println!("{} points x {} dimensions, fitted in {secs:.2} s", model.points, model.dims());
    println!(
        "  lower bound: {:.6} nats (full PRML 10.70 bound on ln p(X), all constant terms included; {:.6} per point)",
        model.lower_bound,
        model.lower_bound / model.points as f64
    );
    println!(
        "  components: {} with weight above 1e-3 ({} kept)",
        model.effective_components(1e-3),
        model.components.len()
    );
    println!("  VBEM iterations: {}", model.iterations);
    println!("  -> {}", out.display());
    Ok(())
}

fn find(run: &std::path::Path, image: &std::path::Path, model: Option<&std::path::Path>, top: usize) -> Result<()> {
    let model_path =
        model.map(std::path::Path::to_path_buf).unwrap_or_else(|| run.join("objects").join("appearance_model.json"));
    let model = slam::classifier::AppearanceModel::load(&model_path)?;
    let dims = slam::object_model::ObjectModelConfig::default().appearance_dims;
    let ranked = scenarios::objects::find_similar(run, &model, image, dims)?;
    println!("mapped objects most like {} (appearance KL, nats):", image.display());
    for (id, kl) in ranked.iter().take(top) {
        println!(
            "  landmark {id:>4}  KL {kl:>10.2}  {}",
            run.join("objects").join(format!("landmark_{id}.png")).display()
        );
    }
    Ok(())
}
