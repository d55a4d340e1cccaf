//! The command line's arguments, as clap reads them. Value enums here mirror the library's
//! types, so that the libraries need no clap.

use std::path::PathBuf;

use clap::{Parser, Subcommand};
use scenarios::record::RecordFormat;
use scenarios::score::scorer::RecallBasis;
use slam::association::AssociationMethod;
use slam::gmm::Search;

#[derive(Parser)]
#[command(
    name = "objslam",
    version,
    about = "Simulation harness for object-recognition SLAM (Ramos, Nieto & Durrant-Whyte)"
)]
pub(crate) struct Cli {
    #[command(subcommand)]
    pub(crate) command: Option<Command>,
}

#[derive(Subcommand)]
pub(crate) enum Command {
    /// Generate, check, export and plot worlds.
    #[command(subcommand)]
    World(WorldCommand),
    /// Run a scenario (default: the paper's experiment) and score it against ground truth.
    Run {
        /// A scenario file or built-in name (paper_park, posts_near_trees, crowd,
        /// long_loop, laser_only, calibration, city_park).
        scenario: Option<String>,
        /// Run seed (default: the scenario's): the simulator's noise, and the world where the
        /// scenario gives no world seed.
        #[arg(long, allow_negative_numbers = true)]
        seed: Option<u64>,
        /// Association method (default: the scenario's, combined unless it says otherwise).
        #[arg(long, value_enum)]
        method: Option<MethodArg>,
        /// Output directory (default runs/<scenario>-<seed>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Render whole camera frames, not only the image regions the pipeline reads (the
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
        /// Images to render, each aimed at an object from a random viewpoint.
        #[arg(long, default_value_t = 100, allow_negative_numbers = true)]
        images: usize,
        /// Seed of the viewpoints (and of the preset's world).
        #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
        seed: u64,
        /// Comma-separated classes labelled positive.
        #[arg(long, default_value = "tree")]
        classes: String,
        /// Patch side L in pixels.
        #[arg(long, default_value_t = 9, allow_negative_numbers = true)]
        patch_size: u32,
        /// The dataset's directory (images, masks, patch labels, manifest, COCO annotations).
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
        #[arg(long, allow_negative_numbers = true)]
        seed: Option<u64>,
        /// Stop after this many simulated seconds (default: when the route is done).
        #[arg(long, allow_negative_numbers = true)]
        duration: Option<f64>,
        /// TOML file of simulator settings (see `sim::SimConfig`).
        #[arg(long, conflicts_with = "scenario")]
        sim_config: Option<PathBuf>,
        /// `jsonl`: JSON lines, TUM, PNGs and a Foxglove MCAP; `ros2`: a ROS 2 bag
        /// (`ros2 bag play OUT`); `log`: a robot log for `objslam replay`.
        #[arg(long, value_enum, default_value_t = FormatArg::Jsonl)]
        format: FormatArg,
        /// Record no camera frames. By default they are recorded where the simulator's
        /// camera is enabled (its default), and for `--format log` of a scenario where its
        /// method reads them; rendering them is most of a recording's time.
        #[arg(long)]
        no_camera: bool,
        /// The log's directory.
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
        #[arg(long, allow_negative_numbers = true)]
        poses: Option<usize>,
        /// Session seed (default: the scenario's seed).
        #[arg(long, allow_negative_numbers = true)]
        seed: Option<u64>,
        /// Where to write the calibration (JSON: the estimate and its errors).
        #[arg(long, default_value = "calibration.json")]
        out: PathBuf,
        /// Write each pose's camera image here, detected corners marked.
        #[arg(long)]
        images: Option<PathBuf>,
    },
    /// Learn the appearance model (PCA, object and background VB-GMMs) from an
    /// `objslam dataset` directory; prints held-out patch precision, recall and F1.
    Train(TrainArgs),
    /// Classify an image's patches with a model and draw the object patches over it.
    Segment {
        /// The appearance model (JSON, as `objslam train` writes).
        #[arg(long)]
        model: PathBuf,
        /// The image to classify (PNG or JPEG).
        image: PathBuf,
        /// The picture to write (PNG or JPEG, by its extension), the object patches drawn
        /// over the image.
        #[arg(long)]
        out: PathBuf,
    },
    /// Find objects that look like this: rank a run's mapped objects by the KL divergence
    /// of their appearance from an example image's object patches.
    Find {
        /// A run directory written by `objslam run` (its objects/ holds the models).
        #[arg(long)]
        run: PathBuf,
        /// An example image of the object sought (its object patches are compared).
        image: PathBuf,
        /// Appearance model (default: the one the run used, objects/appearance_model.json).
        #[arg(long)]
        model: Option<PathBuf>,
        /// How many to list.
        #[arg(long, default_value_t = 5, allow_negative_numbers = true)]
        top: usize,
    },
    /// Variational Bayesian Gaussian mixtures on any numeric CSV.
    #[command(subcommand)]
    Gmm(GmmCommand),
    /// Score any SLAM system's trajectory (and covariances, map and associations) against a
    /// log of `objslam record` or an `objslam run` output directory, by the rules `objslam
    /// run` scores its own runs with.
    Score(ScoreArgs),
    /// Settings: print every scenario setting at its default, or check a scenario.
    #[command(subcommand)]
    Config(ConfigCommand),
}

#[derive(clap::Args)]
pub(crate) struct ScoreArgs {
    /// The log: a directory `objslam record` wrote, or an `objslam run` output directory.
    #[arg(long)]
    pub(crate) log: PathBuf,
    /// The estimated trajectory, TUM format, world frame.
    #[arg(long)]
    pub(crate) trajectory: PathBuf,
    /// The pose covariance at the trajectory's times, for ANEES: CSV
    /// `t,xx,xy,xtheta,yy,ytheta,thetatheta` (a run's trajectory_est_covariance.csv, which is
    /// read without this flag when the trajectory is the run's own).
    #[arg(long)]
    pub(crate) covariances: Option<PathBuf>,
    /// The estimated map: a JSON array of {"id", "position": [x, y]}, or CSV `id,x,y`.
    #[arg(long)]
    pub(crate) landmarks: Option<PathBuf>,
    /// What each observation of each scan went to: JSON lines by observation id (as
    /// `objslam run` writes decisions.jsonl) or by beams (associations.jsonl), or CSV
    /// `t,observation,landmark` or `t,first_beam,last_beam,landmark`.
    #[arg(long)]
    pub(crate) associations: Option<PathBuf>,
    /// The system's name in the report.
    #[arg(long)]
    pub(crate) method: Option<String>,
    /// The recall's denominator (default: trees in view when the log has camera frames).
    #[arg(long, value_enum)]
    pub(crate) recall_basis: Option<RecallBasisArg>,
    /// Where to write metrics.json.
    #[arg(long)]
    pub(crate) out: PathBuf,
}

/// `objslam train`'s arguments.
#[derive(clap::Args)]
pub(crate) struct TrainArgs {
    /// A directory `objslam dataset` wrote.
    #[arg(long)]
    pub(crate) dataset: PathBuf,
    /// Where to write the model (JSON).
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// Also write every patch's feature row and label to this CSV file.
    #[arg(long)]
    pub(crate) export_features: Option<PathBuf>,
    /// PCA dimension d.
    #[arg(long, default_value_t = 20, allow_negative_numbers = true)]
    pub(crate) pca_dims: usize,
    /// Most mixture components per class.
    #[arg(long, default_value_t = 20, allow_negative_numbers = true)]
    pub(crate) max_components: usize,
    /// Hold out every N-th image for scoring (0: none).
    #[arg(long, default_value_t = 5, allow_negative_numbers = true)]
    pub(crate) heldout_every: usize,
    /// Also score the model on every image of this dataset, of another world (repeat for
    /// more): patch precision and recall, and per true class the patches called object.
    #[arg(long)]
    pub(crate) heldout_dataset: Vec<PathBuf>,
    /// Write the scores on the --heldout-dataset worlds to this JSON file.
    #[arg(long, requires = "heldout_dataset")]
    pub(crate) heldout_report: Option<PathBuf>,
    /// A patch is object when R = w_obj p_obj / (w_obj p_obj + w_bg p_bg) exceeds this.
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true)]
    pub(crate) threshold: f64,
    /// Seed of the training's sampling of patches and of its mixtures' starts.
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    pub(crate) seed: u64,
    /// Fit posts, palms, walls and people (the distractors) with their own mixture, apart
    /// from the rest of the background.
    #[arg(long)]
    pub(crate) distractors: bool,
    /// Learn a column context that decides each patch again from the patches above and
    /// below it (fitted on every 5th training image, which the mixtures then do not see).
    #[arg(long)]
    pub(crate) context: bool,
}

#[derive(Subcommand)]
pub(crate) enum ConfigCommand {
    /// Print the complete default scenario as TOML, from the code's defaults, each key after
    /// a comment saying what it means (or one table of it and those below it, e.g.
    /// `pipeline.evidence`).
    Defaults {
        /// One table, as a dotted path (`pipeline.evidence`); default: every table.
        table: Option<String>,
    },
    /// Check a scenario without running it: every setting, the method's needs, the world, a
    /// calibration file, an appearance model file and the pipeline built from them, as a
    /// run checks them before its first step. Exits with an error naming the file, line and
    /// field of the first problem.
    Check {
        /// A scenario file or built-in name.
        scenario: String,
        /// Association method (default: the scenario's).
        #[arg(long, value_enum)]
        method: Option<MethodArg>,
        /// Run seed (default: the scenario's); it picks the world when the scenario's does not.
        #[arg(long)]
        seed: Option<u64>,
    },
}

/// `objslam gmm fit --search`.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub(crate) enum SearchArg {
    Prune,
    Grow,
}

impl From<SearchArg> for Search {
    fn from(s: SearchArg) -> Self {
        match s {
            SearchArg::Prune => Search::Prune,
            SearchArg::Grow => Search::Grow,
        }
    }
}

#[derive(Subcommand)]
pub(crate) enum GmmCommand {
    /// Fit a VB-GMM (searching for the number of components up to --max-components, or
    /// fixed K).
    Fit {
        /// A CSV of numbers, one point a row (a first row of names, blank lines and lines starting with `#` are skipped; fields may be quoted).
        data: PathBuf,
        /// Most components the search may keep (the components VBEM starts from with
        /// --fixed-k).
        #[arg(long, default_value_t = 10, allow_negative_numbers = true)]
        max_components: usize,
        /// Start VBEM from --max-components components and do not search: no split or
        /// deletion is tried, but components VBEM leaves with too few points to fit are
        /// removed (variational Bayes empties what the data do not need), so at most K.
        #[arg(long, conflicts_with = "search")]
        fixed_k: bool,
        /// How to search for the number of components: `prune` starts from
        /// --max-components and lets VBEM empty and delete components (fast); `grow` starts
        /// from one and splits (what `objslam train` uses).
        #[arg(long, value_enum, default_value_t = SearchArg::Prune)]
        search: SearchArg,
        /// Seed of the k-means++ start (`--fixed-k` and `--search prune`).
        #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
        seed: u64,
        /// Where to write the model (JSON: the mixture, and under `fit` how it was fitted).
        #[arg(long)]
        out: PathBuf,
    },
    /// Print a fitted model's mean held-out log-likelihood per point on a CSV (the
    /// posterior predictive density), to compare models fitted to the same data.
    Score {
        /// A model file `objslam gmm fit` wrote.
        model: PathBuf,
        /// A CSV of held-out points, with the model's number of columns.
        data: PathBuf,
    },
}

#[derive(clap::Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub(crate) struct MontecarloArgs {
    #[command(subcommand)]
    pub(crate) command: Option<MontecarloCommand>,
    /// Scenario file or built-in name.
    #[arg(required = true)]
    pub(crate) scenario: Option<String>,
    /// Runs per method and parameter value.
    #[arg(long, default_value_t = 100, allow_negative_numbers = true)]
    pub(crate) runs: usize,
    /// Comma-separated association methods (combined, nn, jcbb, appearance).
    #[arg(long, default_value = "combined,nn,jcbb,appearance")]
    pub(crate) methods: String,
    /// PARAM=A..B:STEPS, a dotted path into the scenario (repeatable), e.g.
    /// sim.odometry.scale_sigma=0.0..0.05:6 or world.params.post_distance_m=0.5..3:6.
    #[arg(long)]
    pub(crate) vary: Vec<String>,
    /// Base seed: run r gets a seed derived from (seed, r).
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    pub(crate) seed: u64,
    /// Run only slice K of N (0-based); defaults to the Slurm array / Kubernetes index
    /// from the environment when present.
    #[arg(long)]
    pub(crate) shard: Option<String>,
    /// Number of shards when the index comes from JOB_COMPLETION_INDEX (--shard K/N
    /// gives its own).
    #[arg(long, allow_negative_numbers = true, conflicts_with = "shard")]
    pub(crate) shard_count: Option<usize>,
    /// The study's directory (default runs/montecarlo-<scenario>-<seed>).
    #[arg(long)]
    pub(crate) out: Option<PathBuf>,
    /// Runs at a time, each in its own worker process (default: one per core).
    #[arg(long, global = true, allow_negative_numbers = true)]
    pub(crate) jobs: Option<usize>,
    /// Run on threads of this process instead of worker processes (slower: runs in one
    /// process share the software renderer's locks; no --jobs or --run-timeout).
    #[arg(long, global = true)]
    pub(crate) in_process: bool,
    /// Seconds a worker process may spend on one run before it is killed and the run
    /// recorded as retryable (resuming the study runs it again); 0: no limit (default 1800).
    #[arg(long, global = true, allow_negative_numbers = true)]
    pub(crate) run_timeout: Option<f64>,
}

#[derive(Subcommand)]
pub(crate) enum MontecarloCommand {
    /// Merge shard directories into one study.
    Merge {
        /// The shards' directories (each with the same study's study.json).
        dirs: Vec<PathBuf>,
        /// The merged study's directory (may be one of the shards').
        #[arg(long)]
        out: PathBuf,
    },
    /// Run one job of a study again with all of `objslam run`'s outputs, to look into a run
    /// the study found failing, and say whether it repeats the study's record (exit status
    /// 1 if it does not).
    Rerun {
        /// The study's directory (its study.json; a benchmark's DIR/combined or DIR/jcbb).
        dir: PathBuf,
        /// The job: its index (`job.index` in runs.jsonl) or its key (`key`).
        #[arg(long, allow_negative_numbers = true)]
        job: String,
        /// Where the run's outputs go.
        #[arg(long)]
        out: PathBuf,
        /// Where the study's scenario file is now, if it was moved since the study began
        /// (it must be the same scenario: its settings and files are checked, so files it
        /// names by relative path must move with it to the same places beside it).
        #[arg(long)]
        scenario: Option<String>,
    },
    /// The built-in study of the paper's argument on paper_park: failure rate of combined,
    /// nn and jcbb against odometry heading drift (DIR/odometry) and against post-to-tree
    /// distance (DIR/post_distance). Resumable and shardable like any study.
    Study {
        /// Runs per method and parameter value.
        #[arg(long, default_value_t = 10, allow_negative_numbers = true)]
        runs: usize,
        /// Base seed: run r gets a seed derived from (seed, r).
        #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
        seed: u64,
        /// Run only slice K of N of each sub-study (0-based).
        #[arg(long)]
        shard: Option<String>,
        /// The study's directory (its sub-studies in DIR/odometry and DIR/post_distance).
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
        #[arg(long, default_value_t = 10, allow_negative_numbers = true)]
        runs: usize,
        /// Base seed of the runs' simulations.
        #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
        seed: u64,
        /// Run only slice K of N of each of the two studies (0-based).
        #[arg(long)]
        shard: Option<String>,
        /// The benchmark's directory (DIR/combined, DIR/jcbb, DIR/worlds.json).
        #[arg(long, default_value = "runs/generalisation")]
        out: PathBuf,
    },
}

/// `objslam montecarlo generalisation --split`.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub(crate) enum SplitArg {
    Tune,
    Test,
}

#[derive(Subcommand)]
pub(crate) enum WorldCommand {
    /// Generate a world from a preset; TOML to stdout unless --out is given.
    Generate {
        /// The generator (park).
        #[arg(long, default_value = "park")]
        preset: String,
        /// World seed: the same preset, parameters and seed give the same world.
        #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
        seed: u64,
        /// TOML file of generator parameters (see `worlds::generate::ParkParams`).
        #[arg(long)]
        params: Option<PathBuf>,
        /// The world file to write (TOML).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Validate a world file; prints a summary or every problem found.
    Check {
        /// The world file (TOML).
        file: PathBuf,
    },
    /// Export a world as one glTF 2.0 binary (.glb).
    Export {
        /// The world file (TOML).
        file: PathBuf,
        /// The .glb file to write.
        #[arg(long)]
        out: PathBuf,
    },
    /// Add a glTF/.glb mesh to a world as an object: the camera renders the mesh, and a
    /// shape fitted to it (trunk or post as wide as its lowest metre, reaching the mesh's top)
    /// is the collider the laser sees. The mesh stands on its origin, in metres, with
    /// glTF's up (+y) turned to the world's z.
    Import {
        /// The glTF/.glb file.
        mesh: PathBuf,
        /// The world file to add it to.
        #[arg(long)]
        world: PathBuf,
        /// tree, palm, post or wall.
        #[arg(long, default_value = "tree")]
        class: String,
        /// Where it stands: X,Y in metres.
        #[arg(long, allow_hyphen_values = true)]
        at: String,
        /// Its heading (deg, counter-clockwise, -360 to 360).
        #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
        yaw_deg: f64,
        /// The new world file (may be --world itself).
        #[arg(long)]
        out: PathBuf,
    },
    /// Draw a top view of a world, coloured by class, with routes and a scale bar.
    Plot {
        /// The world file (TOML).
        file: PathBuf,
        /// The picture to write (PNG).
        #[arg(long)]
        out: PathBuf,
    },
}

/// What every replay takes.
#[derive(clap::Args, Debug)]
pub(crate) struct ReplayArgs {
    /// Association method (default: the log's `pipeline.toml`, else `nn`). The camera
    /// methods (`combined`, `appearance`) need a log with camera frames and an appearance
    /// model.
    #[arg(long, value_enum)]
    pub(crate) method: Option<MethodArg>,
    /// The appearance model of the camera methods: a JSON file `objslam train` wrote
    /// (default: the log's `appearance_model.json`, if it has one).
    #[arg(long)]
    pub(crate) appearance_model: Option<PathBuf>,
    /// A TOML file of pipeline settings (`[pipeline]` keys, as in a scenario) over the
    /// replay's defaults and the log's own `pipeline.toml`.
    #[arg(long)]
    pub(crate) config: Option<PathBuf>,
    /// The output directory (what `objslam run` writes, where it applies).
    #[arg(long, required = true)]
    pub(crate) out: Option<PathBuf>,
}

/// Published data sets that `objslam replay` reads as they are published.
#[derive(Subcommand, Debug)]
pub(crate) enum ReplayDataset {
    /// Victoria Park (ACFR, University of Sydney: Guivant & Nebot). DIR holds the published
    /// files: `VictoriaParkSinSincronizar.mat` (tree detections), or `aa3_dr.mat` with
    /// `aa3_lsr2.mat`; and `aa3_gpsx.mat` for GPS.
    VictoriaPark {
        /// The directory holding the published files, as published.
        #[arg(long)]
        data: PathBuf,
        #[command(flatten)]
        options: DetectionReplayArgs,
    },
}

/// A replay of a data set of laser detections, without a camera: the position-only methods.
#[derive(clap::Args, Debug)]
pub(crate) struct DetectionReplayArgs {
    /// Association method (default: `nn`).
    #[arg(long, value_enum)]
    pub(crate) method: Option<PositionMethodArg>,
    /// A TOML file of pipeline settings (`[pipeline]` keys, as in a scenario) over the
    /// replay's defaults.
    #[arg(long)]
    pub(crate) config: Option<PathBuf>,
    /// The output directory (what `objslam run` writes, where it applies).
    #[arg(long, required = true)]
    pub(crate) out: Option<PathBuf>,
}

/// The association methods that need no camera.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum PositionMethodArg {
    /// Nearest neighbour with a chi-square gate.
    Nn,
    /// Joint compatibility branch and bound.
    Jcbb,
}

impl From<DetectionReplayArgs> for ReplayArgs {
    fn from(a: DetectionReplayArgs) -> Self {
        let method = a.method.map(|m| match m {
            PositionMethodArg::Nn => MethodArg::Nn,
            PositionMethodArg::Jcbb => MethodArg::Jcbb,
        });
        ReplayArgs { method, appearance_model: None, config: a.config, out: a.out }
    }
}

/// `--method` and `--methods`: the association methods.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum MethodArg {
    /// The paper's: a position gate selects candidates, appearance (KL divergence) decides.
    Combined,
    /// Position-only nearest neighbour with a chi-square gate.
    Nn,
    /// Position-only joint compatibility branch and bound.
    Jcbb,
    /// Appearance only: the KL divergence between object models decides.
    Appearance,
}

impl From<MethodArg> for AssociationMethod {
    fn from(m: MethodArg) -> Self {
        match m {
            MethodArg::Combined => AssociationMethod::Combined,
            MethodArg::Nn => AssociationMethod::Nn,
            MethodArg::Jcbb => AssociationMethod::Jcbb,
            MethodArg::Appearance => AssociationMethod::Appearance,
        }
    }
}

/// `objslam record --format`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum FormatArg {
    /// JSON lines, TUM, PNG images and a Foxglove MCAP in one directory.
    Jsonl,
    /// A ROS 2 bag: `metadata.yaml` and one MCAP of CDR messages.
    Ros2,
    /// A robot log (docs/reference/robot-log.md) that `objslam replay` reads.
    Log,
}

impl From<FormatArg> for RecordFormat {
    fn from(f: FormatArg) -> Self {
        match f {
            FormatArg::Jsonl => RecordFormat::Jsonl,
            FormatArg::Ros2 => RecordFormat::Ros2,
            FormatArg::Log => RecordFormat::Log,
        }
    }
}

/// `objslam score --recall-basis`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum RecallBasisArg {
    /// Trees the camera showed where the laser hit them (`map.trees_in_view`).
    InView,
    /// Trees the laser hit (`map.trees_laser_seen`).
    LaserSeen,
}

impl From<RecallBasisArg> for RecallBasis {
    fn from(b: RecallBasisArg) -> Self {
        match b {
            RecallBasisArg::InView => RecallBasis::InView,
            RecallBasisArg::LaserSeen => RecallBasis::LaserSeen,
        }
    }
}
