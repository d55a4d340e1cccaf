//! `objslam record`, `dataset` and `calibrate`: the simulator's sensor data for other
//! systems, training images, and the laser-camera calibration session.

use scenarios::files;
use std::path::PathBuf;

use anyhow::Result;

use crate::progress;

/// What `objslam record` simulates.
pub(crate) enum RecordSource {
    World { input: String, sim_config: Option<PathBuf> },
    Scenario(String),
}

/// What a recording needs, resolved from its source: the world and simulator, how a log
/// of it is scored, and (for a scenario) what `objslam replay` of the log needs besides.
struct RecordingPlan {
    world: worlds::World,
    config: sim::SimConfig,
    sim_seed: u64,
    scoring: scenarios::score::log::LogScoring,
    /// A scenario's pipeline settings, carried by a log.
    pipeline: Option<slam::pipeline::PipelineConfig>,
    /// The calibration a run of the scenario is given, where the log has its camera.
    calibration: Option<slam::calibration::Extrinsics>,
    /// The appearance model a run of the scenario uses, where the log has its camera.
    model: Option<slam::classifier::AppearanceModel>,
}

impl RecordingPlan {
    fn resolve(
        source: RecordSource,
        seed: Option<u64>,
        format: scenarios::record::RecordFormat,
        no_camera: bool,
    ) -> Result<Self> {
        match source {
            RecordSource::World { input, sim_config } => {
                let seed = seed.unwrap_or(1);
                let config = match sim_config {
                    Some(path) => scenarios::scenario::read_sim_config(&path)?,
                    None => sim::SimConfig::default(),
                };
                Ok(RecordingPlan {
                    world: crate::world::load_world(&input, seed)?,
                    config,
                    sim_seed: seed,
                    scoring: scenarios::score::log::LogScoring::of_world(),
                    pipeline: None,
                    calibration: None,
                    model: None,
                })
            }
            RecordSource::Scenario(name) => {
                let (sc, base) = scenarios::scenario::Scenario::load(&name)?;
                let seed = seed.unwrap_or(sc.seed);
                // The world and simulator seeds a run of this scenario and seed uses; the
                // world first, so that a bad one is reported before any training.
                let world = sc.world(&base, seed)?;
                let pipeline = scenarios::run::pipeline_config(&sc, None)?;
                // A log's camera (its method's) comes with the calibration a run is given.
                let logs_camera = format == scenarios::record::RecordFormat::Log
                    && !no_camera
                    && scenarios::record::logs_camera(&sc.sim, Some(&pipeline));
                let calibration = logs_camera
                    .then(|| scenarios::run::resolve_calibration(&sc, &base, seed))
                    .transpose()?
                    .map(|c| c.extrinsics);
                // ... and with the appearance model a run uses (trained and cached if need
                // be), so that `objslam replay` of the log needs nothing more.
                let model = if logs_camera {
                    let bar = progress::training(&name);
                    let m = scenarios::run::resolve_appearance(&sc, &base, |stage, done, total| {
                        progress::set_training(&bar, stage, done, total)
                    })?;
                    bar.finish_and_clear();
                    Some(m)
                } else {
                    None
                };
                Ok(RecordingPlan {
                    world,
                    config: sc.sim.clone(),
                    sim_seed: sim::derive_seed(seed, "sim"),
                    scoring: scenarios::score::log::LogScoring::of_scenario(&sc, seed),
                    pipeline: Some(pipeline),
                    calibration,
                    model,
                })
            }
        }
    }
}

/// `objslam record`.
pub(crate) fn record(
    source: RecordSource,
    seed: Option<u64>,
    duration: Option<f64>,
    format: scenarios::record::RecordFormat,
    no_camera: bool,
    out: &std::path::Path,
) -> Result<()> {
    // A JSON-lines log and a robot log write the world they simulated as OUT/world.toml:
    // where that is the world file given, it would be replaced (its comments lost).
    if let RecordSource::World { input, sim_config } = &source
        && format != scenarios::record::RecordFormat::Ros2
    {
        let given = std::path::Path::new(input);
        crate::paths::not_an_input("--out", &out.join(files::WORLD), &[("world file", given)])
            .map_err(|_| anyhow::anyhow!("--out {}: the recording writes world.toml there, which is the world file given ({}); record into another directory", out.display(), given.display()))?;
        // Nor may the simulator settings be among what it replaces or removes there.
        let names = scenarios::record::recording_files();
        let settings = sim_config.iter().map(|f| ("--sim-config file", f.clone())).collect();
        if let Some((what, file)) = files::input_among_outputs(out, &names, settings) {
            anyhow::bail!(
                "--out {}: the {what} ({}) lies among the files the recording replaces or removes there; copy it elsewhere or record into another directory",
                out.display(),
                file.display()
            );
        }
    }
    // A scenario's input files among what the recording writes or removes there would be
    // replaced or deleted when it is published.
    if let RecordSource::Scenario(name) = &source
        && format != scenarios::record::RecordFormat::Ros2
    {
        let (sc, base) = scenarios::scenario::Scenario::load(name)?;
        let names = scenarios::record::recording_files();
        if let Some((what, file)) = files::input_among_outputs(out, &names, sc.input_files(&base)) {
            anyhow::bail!(
                "--out {}: the scenario's {what} ({}) lies among the files the recording replaces or removes there; copy it elsewhere or record into another directory",
                out.display(),
                file.display()
            );
        }
    }
    let RecordingPlan { world, mut config, sim_seed, scoring, pipeline, calibration, model } =
        RecordingPlan::resolve(source, seed, format, no_camera)?;
    if let Some(d) = duration {
        anyhow::ensure!(d > 0.0 && d.is_finite(), "--duration must be a positive number of seconds, not {d}");
        config.max_duration_s = Some(d);
    }
    if no_camera {
        config.camera.enabled = false;
    }
    let bar = progress::simulated("recording");
    let show = |t: f64, total: f64| progress::set_simulated(&bar, t, total);
    let summary = match format {
        // A scenario's log carries its pipeline settings, for `objslam replay`.
        scenarios::record::RecordFormat::Log => scenarios::record::record_log(
            &world,
            &config,
            sim_seed,
            scenarios::record::LogSettings {
                pipeline: pipeline.as_ref(),
                calibration: calibration.as_ref(),
                appearance_model: model.as_ref(),
                scoring: Some(&scoring),
            },
            out,
            show,
        )?,
        _ => scenarios::record::record(&world, &config, sim_seed, &scoring, out, format, show)?,
    };
    bar.finish_and_clear();
    println!(
        "recorded {} s in {:.2} s ({:.0}x real time): {} scans, {} odometry messages, {} camera frames, {} collisions -> {}",
        // A tenth of a second would print a recording of 0.04 s as "0.0 s".
        if summary.sim_seconds >= 1.0 {
            format!("{:.1}", summary.sim_seconds)
        } else {
            format!("{:.3}", summary.sim_seconds)
        },
        summary.wall_seconds,
        summary.sim_seconds / summary.wall_seconds.max(1e-9),
        summary.scans,
        summary.odometry,
        summary.camera_frames,
        summary.collisions,
        out.display()
    );
    Ok(())
}

/// `objslam dataset`.
pub(crate) fn dataset(
    world: Option<PathBuf>,
    preset: Option<String>,
    images: usize,
    seed: u64,
    classes: &str,
    patch_size: u32,
    out: &std::path::Path,
) -> Result<()> {
    let (w, name) = match (world, preset) {
        (Some(path), None) => {
            anyhow::ensure!(
                !scenarios::dataset::owns(out, &path),
                "--world {}: a file of the dataset in {}, which the new dataset replaces; copy it elsewhere first",
                path.display(),
                out.display()
            );
            let mut world = worlds::load(&path)?;
            world.resolve_mesh_paths(&path);
            (world, path.display().to_string())
        }
        (None, preset) => {
            let p = preset.unwrap_or_else(|| "park".into());
            (worlds::generate::preset(&p, None, seed)?, format!("preset {p}, seed {seed}"))
        }
        (Some(_), Some(_)) => anyhow::bail!("give either --world or --preset"),
    };
    let aimed = scenarios::dataset::AIMED_CLASSES.map(|c| c.name());
    let classes = classes
        .split(',')
        .map(|c| match worlds::ObjectClass::from_name(c.trim()) {
            Some(class) if scenarios::dataset::AIMED_CLASSES.contains(&class) => Ok(class),
            Some(_) => Err(anyhow::anyhow!(
                "--classes: {:?} is not aimed at (people and leaves are in the images and masks where they are); classes: {}",
                c.trim(),
                aimed.join(", ")
            )),
            None => Err(anyhow::anyhow!("--classes: unknown class {c:?}; classes: {}", aimed.join(", "))),
        })
        .collect::<Result<Vec<_>>>()?;
    if let Some(i) = (1..classes.len()).find(|&i| classes[..i].contains(&classes[i])) {
        anyhow::bail!("--classes: {:?} is named twice", classes[i].name());
    }
    let config = scenarios::dataset::DatasetConfig { images, seed, classes, patch_size, ..Default::default() };
    let bar = progress::images(images);
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

/// `objslam calibrate`.
pub(crate) fn calibrate(
    scenario: &str,
    poses: Option<usize>,
    seed: Option<u64>,
    out: &std::path::Path,
    images: Option<&std::path::Path>,
) -> Result<()> {
    // Before the session's work, not after it.
    if let Some(file) = out.parent().and_then(|d| d.ancestors().find(|a| a.is_file())) {
        anyhow::bail!("--out {}: {} is a file, not a directory", out.display(), file.display());
    }
    if out.is_dir() || out.as_os_str().to_string_lossy().ends_with(std::path::MAIN_SEPARATOR) {
        anyhow::bail!("--out {}: is a directory; give the path of the calibration file to write", out.display());
    }
    if let Some(dir) = images
        && scenarios::partial_files::same_path(out, dir)
    {
        anyhow::bail!(
            "--out {} and --images {}: one path; the calibration is a file, the pose images a directory beside it",
            out.display(),
            dir.display()
        );
    }
    // The pose images go into --images, replacing the earlier session's there.
    if let Some(dir) = images
        && scenarios::calibrate::is_pose_image_name(out)
        && scenarios::partial_files::same_path(
            out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(".".as_ref()),
            dir,
        )
    {
        anyhow::bail!(
            "--out {}: a pose image's name in --images {}, which the session writes or removes; give the calibration file another name",
            out.display(),
            dir.display()
        );
    }
    let (sc, base) = scenarios::scenario::Scenario::load(scenario)?;
    // The calibration file the scenario names is not read by a session: writing it anew is
    // what a user re-estimating it wants.
    let inputs: Vec<_> =
        sc.input_files(&base).into_iter().filter(|(what, _)| *what != scenarios::scenario::CALIBRATION_INPUT).collect();
    crate::paths::not_an_input(
        "--out",
        out,
        &inputs.iter().map(|(what, file)| (*what, file.as_path())).collect::<Vec<_>>(),
    )?;
    // A directory still to be made is made when the result is written.
    if out.parent().is_none_or(|d| d.as_os_str().is_empty() || d.is_dir()) {
        scenarios::partial_files::check_writable(out)?;
    }
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
