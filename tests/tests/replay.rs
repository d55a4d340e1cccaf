//! `objslam replay`: a log that `objslam record --format log` wrote replays to the estimate
//! `objslam run` makes of the same scenario; a car-like log in Victoria Park's published
//! form (made here, the data set itself is never shipped) is read and mapped with the
//! car's motion model and scored against its GPS, spikes and all.

use std::f64::consts::{FRAC_PI_2, PI};
use std::path::Path;

use robotlog::{DetectionScan, Log, Motion, Observations, ReferenceSample};
use scenarios::replay::{replay, resolve_config};
use scenarios::run::{RunOptions, run};
use scenarios::scenario::Scenario;
use slam::association::AssociationMethod;
use slam::messages::{Control, Detection};

fn temp_dir(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("objslam-replay-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn read_tum(file: &Path) -> Vec<[f64; 3]> {
    std::fs::read_to_string(file)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            [v[0], v[1], v[2]]
        })
        .collect()
}

#[test]
fn a_recorded_log_replays_to_the_runs_estimate() {
    let dir = temp_dir("record");
    let (mut sc, base) = Scenario::load("laser_only").unwrap();
    sc.sim.max_duration_s = Some(30.0);
    let seed = 3;
    let world = sc.world(&base, seed).unwrap();
    let pipeline = scenarios::run::pipeline_config(&sc, None).unwrap();
    let scoring = scenarios::score::log::LogScoring::of_scenario(&sc, seed);
    scenarios::record::record_log(
        &world,
        &sc.sim,
        sim::derive_seed(seed, "sim"),
        scenarios::record::LogSettings { pipeline: Some(&pipeline), scoring: Some(&scoring), ..Default::default() },
        &dir.join("log"),
        |_, _| {},
    )
    .unwrap();
    // How the log was made, enough to make it again.
    let recording: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("log/recording.json")).unwrap()).unwrap();
    assert_eq!(recording["seed"], sim::derive_seed(seed, "sim"));
    assert_eq!(
        (recording["scoring"]["scenario"].as_str(), recording["scoring"]["run_seed"].as_u64()),
        (Some("laser_only"), Some(seed))
    );
    assert_eq!(recording["sim_config"]["max_duration_s"], 30.0);
    assert_eq!(std::fs::read_to_string(dir.join("log/world.toml")).unwrap(), world.to_toml());
    let out = dir.join("run");
    run(&sc, &base, &RunOptions { seed: Some(seed), out: Some(out.clone()), ..Default::default() }, |_| {}).unwrap();

    // Read as it is replayed, a message at a time.
    let log = robotlog::format::open(&dir.join("log")).unwrap();
    let config = resolve_config(Some(&dir.join("log")), &log.manifest, None, None).unwrap();
    assert_eq!(config, pipeline, "the log's pipeline.toml is the scenario's settings");
    // A mounting other than the log's own would filter one point and write another.
    let moved = dir.join("moved.toml");
    std::fs::write(&moved, "[pipeline.sensor]\nmount_x = 0.5\n").unwrap();
    let e = resolve_config(Some(&dir.join("log")), &log.manifest, None, Some(&moved)).unwrap_err().to_string();
    assert!(
        e.contains("moved.toml") && e.contains("sensor.mount_x = 0.5 disagrees with the log's manifest.toml"),
        "{e}"
    );
    let replayed = replay(log, config.clone(), None, Some(&dir.join("replay"))).unwrap();
    assert_same_estimate(&out, &dir.join("replay"), &replayed);
    assert!(!dir.join("replay/.unfinished").exists(), "every output moved into place");
    assert!(replayed.metrics.returns_in_range.is_some_and(|n| n > 1000), "{:?}", replayed.metrics.returns_in_range);
    // The same ranges in millimetres: every beam beyond the laser's range, said so.
    let mut millimetres = robotlog::format::read(&dir.join("log")).unwrap();
    let robotlog::Observations::Scans(scans) = &mut millimetres.observations else { panic!("whole scans") };
    for scan in scans {
        scan.ranges.iter_mut().for_each(|r| *r *= 1000.0);
    }
    // A log may leave its name empty: the summary still names it.
    millimetres.manifest.name = String::new();
    let m = replay(millimetres, config, None, None).unwrap().metrics;
    assert_eq!(m.returns_in_range, Some(0));
    let line = scenarios::replay::summary(&m);
    assert!(line.contains("ranges in millimetres") && line.starts_with("the log with "), "{line}");
    let mut written: Vec<String> = std::fs::read_dir(dir.join("replay"))
        .unwrap()
        .map(|f| f.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    written.sort();
    let expected =
        ["decisions.jsonl", "landmarks.json", "map.png", "metadata.json", "metrics.json", "trajectory_est.tum"];
    assert_eq!(written, expected, "the outputs, and no file the scoring kept on the way");
    // Scored against the log's ground truth, no alignment: the run's own ATE.
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    let reference = replayed.metrics.reference.as_ref().unwrap();
    assert_eq!(reference.alignment, "none");
    let run_ate = metrics["ate_rmse_m"].as_f64().unwrap();
    assert!((reference.ate_rmse_m - run_ate).abs() < 0.02 * run_ate + 1e-3, "{} vs {run_ate}", reference.ate_rmse_m);
    std::fs::remove_dir_all(&dir).ok();
}

/// The replay in `replay_dir` estimated what the run in `run_dir` did: the same pose at
/// each of the run's instants, and the same landmarks.
fn assert_same_estimate(run_dir: &Path, replay_dir: &Path, replayed: &scenarios::replay::Replay) {
    // The run writes a pose per odometry message; the replay one per instant of input,
    // after the odometry where a scan comes at the same time. Each of the run's poses is
    // the replay's at its instant, and the replay's times increase, as TUM's must (so
    // that `objslam score` and evo read it).
    let run_path = read_tum(&run_dir.join("trajectory_est.tum"));
    let replay_path = read_tum(&replay_dir.join("trajectory_est.tum"));
    assert!(run_path.len() > 100);
    assert!(replay_path.windows(2).all(|w| w[0][0] < w[1][0]), "the replay's times increase");
    scenarios::score::estimate::read_tum(&replay_dir.join("trajectory_est.tum")).expect("score reads it");
    let mut k = 0;
    for p in &run_path {
        while replay_path[k][0] < p[0] {
            k += 1;
        }
        let q = replay_path[k];
        assert_eq!(q[0], p[0]);
        assert_eq!([q[1], q[2]], [p[1], p[2]], "at t = {}", q[0]);
    }
    let run_landmarks: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("landmarks.json")).unwrap()).unwrap();
    assert_eq!(run_landmarks.as_array().unwrap().len(), replayed.landmarks.len());
    for (a, b) in run_landmarks.as_array().unwrap().iter().zip(&replayed.landmarks) {
        assert_eq!(a["position"][0].as_f64().unwrap(), b.position[0]);
        assert_eq!(a["position"][1].as_f64().unwrap(), b.position[1]);
    }
}

#[test]
fn a_recorded_log_with_camera_frames_replays_to_the_combined_runs_estimate() {
    // The paper's method on a log of paper_park's first 15 s: the frames come from the
    // log's PNGs, the camera model from its manifest.
    let dir = temp_dir("camera");
    let (mut sc, base) = Scenario::load("paper_park").unwrap();
    sc.sim.max_duration_s = Some(15.0);
    // A calibration off the truth: the log's manifest must carry the run's, not the truth.
    sc.calibration.mode = "perturbed".into();
    sc.calibration.rotation_sigma_deg = 0.3;
    sc.calibration.translation_sigma_m = 0.01;
    let seed = 2;
    let world = sc.world(&base, seed).unwrap();
    let pipeline = scenarios::run::pipeline_config(&sc, None).unwrap();
    assert_eq!(pipeline.method, AssociationMethod::Combined);
    let calibration = scenarios::run::resolve_calibration(&sc, &base, seed).unwrap().extrinsics;
    scenarios::record::record_log(
        &world,
        &sc.sim,
        sim::derive_seed(seed, "sim"),
        scenarios::record::LogSettings {
            pipeline: Some(&pipeline),
            calibration: Some(&calibration),
            appearance_model: None,
            scoring: None,
        },
        &dir.join("log"),
        |_, _| {},
    )
    .unwrap();
    let model = scenarios::run::resolve_appearance(&sc, &base, |_, _, _| {}).unwrap();
    let out = dir.join("run");
    let options = RunOptions {
        seed: Some(seed),
        out: Some(out.clone()),
        appearance: Some(std::sync::Arc::new(model.clone())),
        ..Default::default()
    };
    let run_metrics = run(&sc, &base, &options, |_| {}).unwrap().metrics;
    assert!(run_metrics.associations.total > 10, "{:?}", run_metrics.associations);

    let log = robotlog::format::read(&dir.join("log")).unwrap();
    assert!(log.camera.len() > 20, "{} frames", log.camera.len());
    let truth = scenarios::calibrate::true_extrinsics(&sc.sim);
    let camera = log.manifest.camera.as_ref().unwrap();
    assert_eq!((camera.rotation, camera.translation_m), (calibration.phi, calibration.delta));
    assert_ne!(camera.rotation, truth.phi);
    let config = resolve_config(Some(&dir.join("log")), &log.manifest, None, None).unwrap();
    assert_eq!(config, pipeline);
    // Without a model the camera method is refused, naming what it needs.
    let e = replay(log.clone(), config.clone(), None, None).err().expect("refused without a model").to_string();
    assert!(e.contains("--appearance-model"), "{e}");
    let replayed = replay(log.clone(), config, Some(model), Some(&dir.join("replay"))).unwrap();
    assert_eq!(replayed.metrics.camera_frames, log.camera.len());
    assert!(!replayed.landmarks.is_empty());
    assert_same_estimate(&out, &dir.join("replay"), &replayed);
    // The replay records which model it used, as the run does: the same model, the same
    // provenance, in metrics.json and metadata.json.
    let used = replayed.metrics.appearance_model.as_ref().expect("a camera method records its model");
    assert_eq!(Some(used), run_metrics.appearance_model.as_ref());
    assert_eq!(used.digest.as_ref().map(String::len), Some(16));
    let metadata: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("replay/metadata.json")).unwrap()).unwrap();
    assert_eq!(metadata["appearance_model"]["digest"].as_str(), used.digest.as_deref());
    // A position method reads no frame of the same log.
    let jcbb = resolve_config(Some(&dir.join("log")), &log.manifest, Some(AssociationMethod::Jcbb), None).unwrap();
    let position_only = replay(log, jcbb, None, None).unwrap().metrics;
    assert_eq!((position_only.camera_frames, position_only.appearance_model), (0, None));
    std::fs::remove_dir_all(&dir).ok();
}

/// Trees on a grid with jitter, a car driving a loop among them at 3 m/s (rear axle's
/// path), controls at 40 Hz from its rear left wheel with a 2% scale error, a laser 3.78 m
/// ahead detecting trees within 30 m at 4.7 Hz, GPS at 5 Hz with two spikes: Victoria
/// Park's form, made here.
fn synthetic_park() -> Log {
    let mut trees = Vec::new();
    let mut s = 7u64;
    let mut rand = || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    for gx in -6..=6 {
        for gy in -6..=6 {
            trees.push([
                gx as f64 * 12.0 + 6.0 * (rand() - 0.5),
                gy as f64 * 12.0 + 6.0 * (rand() - 0.5),
                0.2 + 0.6 * rand(),
            ]);
        }
    }
    let (wheelbase, encoder, ax, ay) = (2.83, 0.76, 3.78, 0.5);
    let (mut x, mut y, mut th): (f64, f64, f64) = (-30.0, -40.0, 0.0);
    let mut controls = Vec::new();
    let mut scans = Vec::new();
    let mut gps = Vec::new();
    let dt = 0.025;
    let mut noise = || rand() - 0.5;
    for step in 0..(240.0 / dt) as usize {
        let t = step as f64 * dt;
        // A rounded rectangle: straight, then turn left for a quarter circle.
        let phase = t % 60.0;
        let steering: f64 = if phase > 45.0 { (wheelbase / 14.0f64).atan() * 1.0 } else { 0.0 };
        let v = 3.0;
        let measured = v * (1.0 - steering.tan() * encoder / wheelbase) * 1.02;
        controls
            .push((t, Control::Ackermann { speed: measured + 0.02 * noise(), steering: steering + 0.002 * noise() }));
        if step % 8 == 0 && step > 0 {
            // Laser position and its detections.
            let (sn, cs) = th.sin_cos();
            let (lx, ly) = (x + cs * ax - sn * ay, y + sn * ax + cs * ay);
            let mut detections = Vec::new();
            for tr in &trees {
                let (dx, dy) = (tr[0] - lx, tr[1] - ly);
                let r = dx.hypot(dy);
                let b = (dy.atan2(dx) - th + PI).rem_euclid(2.0 * PI) - PI;
                if r < 30.0 && b.abs() < FRAC_PI_2 {
                    detections.push(Detection {
                        range_m: r + 0.05 * noise(),
                        bearing_rad: b + 0.01 * noise(),
                        diameter_m: Some(tr[2] + 0.02 * noise()),
                    });
                }
            }
            if !detections.is_empty() {
                scans.push(DetectionScan { t: t + 0.004, detections });
            }
        }
        if step % 8 == 4 {
            let (sn, cs) = th.sin_cos();
            let spike = if step == 1604 || step == 5004 { 137.0 } else { 0.0 };
            // GPS in its own frame: rotated by 0.5 rad and moved.
            let (px, py) = (x + cs * ax - sn * ay, y + sn * ax + cs * ay + spike);
            let (gs, gc) = 0.5f64.sin_cos();
            gps.push(ReferenceSample {
                t,
                x: gc * px - gs * py + 100.0 + 0.1 * noise(),
                y: gs * px + gc * py - 50.0 + 0.1 * noise(),
                theta: None,
            });
        }
        th += v * dt * steering.tan() / wheelbase;
        x += v * dt * th.cos();
        y += v * dt * th.sin();
    }
    let mut log = Log {
        manifest: robotlog::Manifest {
            format_version: 1,
            name: "victoria_park".into(),
            source: String::new(),
            vehicle: Default::default(),
            sensor: robotlog::manifest::Sensor {
                x_m: ax,
                y_m: ay,
                yaw_rad: 0.0,
                range_sigma_m: None,
                range_sigma_per_m: None,
                bearing_sigma_rad: None,
            },
            laser: None,
            reference: None,
            camera: None,
        },
        motion: Motion::Controls(controls),
        observations: Observations::Detections(scans),
        reference: gps,
        camera: Vec::new(),
    };
    log.manifest.vehicle.motion = "ackermann".into();
    log
}

#[test]
fn victoria_park_form_is_read_and_mapped_with_the_car_model() {
    let dir = temp_dir("vp");
    std::fs::create_dir_all(&dir).unwrap();
    let made = synthetic_park();
    robotlog::victoria_park::write_detections_form(&dir, &made).unwrap();
    let log = robotlog::victoria_park::read(&dir).unwrap();
    // The published form's conventions: bearings 0..pi read back as REP-103 bearings,
    // GPS in seconds, the car's geometry in the manifest.
    let (Observations::Detections(read), Observations::Detections(written)) = (&log.observations, &made.observations)
    else {
        panic!("detections")
    };
    assert_eq!(read.len(), written.len());
    assert!((read[3].detections[0].bearing_rad - written[3].detections[0].bearing_rad).abs() < 1e-12);
    assert_eq!(log.manifest.vehicle.encoder_offset_m, Some(0.76));
    assert_eq!(log.manifest.sensor.x_m, 3.78);
    assert_eq!(log.reference.len(), made.reference.len());

    let config = resolve_config(None, &log.manifest, Some(AssociationMethod::Nn), None).unwrap();
    // Outputs among the data set's files would read as one with them.
    let e = replay(log.clone(), config.clone(), None, Some(&dir)).err().expect("refused").to_string();
    assert!(e.contains("holds a data set's files (VictoriaParkSinSincronizar.mat)"), "{e}");
    let result = replay(log.clone(), config, None, Some(&dir.join("replay"))).unwrap();
    let m = &result.metrics;
    let reference = m.reference.as_ref().unwrap();
    assert_eq!(reference.spikes_removed, 2, "the two GPS spikes, found from the GPS alone");
    assert_eq!(reference.alignment, "rigid 2-D");
    assert!((reference.alignment_rotation_rad - 0.5).abs() < 0.05, "{}", reference.alignment_rotation_rad);
    assert!(reference.ate_rmse_m < 1.0, "ATE {} m", reference.ate_rmse_m);
    assert!(m.nis.mean.is_finite() && m.nis.mean < 4.0, "NIS {}", m.nis.mean);
    // Trees seen: each mapped about once.
    assert!(m.landmarks > 60 && m.landmarks < 200, "{} landmarks", m.landmarks);
    let path = read_tum(&dir.join("replay/trajectory_est.tum"));
    assert!(path.len() > 1000 && path.iter().all(|p| p.iter().all(|v| v.is_finite())));
    // The ATE is the trajectory file's: each fix kept against the written path
    // interpolated at its time (never past the path's ends), after the rigid fit.
    let spikes = scenarios::replay::gps_spikes(&log.reference, scenarios::replay::GPS_SPIKE_SPEED_MPS);
    let (mut est, mut gps) = (Vec::new(), Vec::new());
    for s in log.reference.iter().enumerate().filter(|(k, _)| !spikes.contains(k)).map(|(_, s)| s) {
        let Some(i) = path.iter().position(|p| p[0] >= s.t) else { continue };
        let at = if path[i][0] == s.t {
            [path[i][1], path[i][2]]
        } else if i > 0 {
            let (a, b) = (path[i - 1], path[i]);
            let f = (s.t - a[0]) / (b[0] - a[0]);
            [a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2])]
        } else {
            continue;
        };
        est.push(at);
        gps.push([s.x, s.y]);
    }
    assert_eq!(est.len(), reference.samples_scored);
    let (theta, t) = scenarios::replay::rigid_alignment(&est, &gps);
    let (sn, cs) = theta.sin_cos();
    let squares: f64 = est
        .iter()
        .zip(&gps)
        .map(|(e, g)| (cs * e[0] - sn * e[1] + t[0] - g[0]).powi(2) + (sn * e[0] + cs * e[1] + t[1] - g[1]).powi(2))
        .sum();
    let from_file = (squares / est.len() as f64).sqrt();
    assert!((from_file - reference.ate_rmse_m).abs() < 1e-5, "{from_file} against {}", reference.ate_rmse_m);
    std::fs::remove_dir_all(&dir).ok();
}

/// A reference that the estimate's time span does not reach, or too few GPS fixes for a
/// rigid fit to leave an error, gives an undefined ATE (null), never a perfect one.
#[test]
fn too_little_reference_gives_an_undefined_ate() {
    let mut log = synthetic_park();
    log.manifest.reference = Some(robotlog::manifest::Reference {
        kind: robotlog::ReferenceKind::Gps,
        point: robotlog::ReferencePoint::Sensor,
    });
    log.manifest.vehicle.wheelbase_m = Some(2.83);
    log.manifest.vehicle.encoder_offset_m = Some(0.76);
    let config = resolve_config(None, &log.manifest, Some(AssociationMethod::Nn), None).unwrap();
    let mut late = log.clone();
    late.reference.iter_mut().for_each(|r| r.t += 10_000.0);
    let mut two = log.clone();
    two.reference.truncate(2);
    for (case, log, scored) in [("late", late, 0), ("two fixes", two, 2)] {
        let m = replay(log, config.clone(), None, None).unwrap().metrics;
        let r = m.reference.as_ref().unwrap();
        assert_eq!(r.samples_scored, scored, "{case}");
        let json = serde_json::to_value(r).unwrap();
        for key in ["ate_rmse_m", "ate_max_m", "alignment_rotation_rad"] {
            assert!(json[key].is_null(), "{case}: {key} is {}", json[key]);
        }
        let line = scenarios::replay::summary(&m);
        assert!(line.contains("ATE undefined"), "{case}: {line}");
    }
}

/// The synthetic park's log as a car's (wheelbase and encoder offset given) with its
/// reference read as GPS at the sensor.
fn synthetic_car_with_gps() -> Log {
    let mut log = synthetic_park();
    log.manifest.vehicle.wheelbase_m = Some(2.83);
    log.manifest.vehicle.encoder_offset_m = Some(0.76);
    log.manifest.reference = Some(robotlog::manifest::Reference {
        kind: robotlog::ReferenceKind::Gps,
        point: robotlog::ReferencePoint::Sensor,
    });
    log
}

/// Ground truth in another frame (UTM) is scored as given, and the summary says that a
/// rigid fit would take the error away.
#[test]
fn ground_truth_in_another_frame_is_named() {
    let mut log = synthetic_car_with_gps();
    let config = resolve_config(None, &log.manifest, Some(AssociationMethod::Nn), None).unwrap();
    // The synthetic GPS is in a frame of its own: brought into the estimate's by the
    // inverse of the fit, it is ground truth there.
    let fit = replay(log.clone(), config.clone(), None, None).unwrap().metrics.reference.unwrap();
    let (s, c) = fit.alignment_rotation_rad.sin_cos();
    let t = fit.alignment_translation_m;
    log.reference.iter_mut().for_each(|g| {
        let (dx, dy) = (g.x - t[0], g.y - t[1]);
        (g.x, g.y) = (c * dx + s * dy, -s * dx + c * dy);
    });
    log.manifest.reference.as_mut().unwrap().kind = robotlog::ReferenceKind::GroundTruth;
    let m = replay(log.clone(), config.clone(), None, None).unwrap().metrics;
    let r = m.reference.as_ref().unwrap();
    assert!(r.ate_rmse_m < 10.0 && !r.in_another_frame(), "{r:?}");
    assert!(!scenarios::replay::summary(&m).contains("another frame"));
    log.reference.iter_mut().for_each(|s| {
        s.x += 334_000.0;
        s.y += 6_252_000.0;
    });
    let m = replay(log, config, None, None).unwrap().metrics;
    let r = m.reference.as_ref().unwrap();
    assert!(r.ate_rmse_m > 1e6 && r.in_another_frame(), "{r:?}");
    let line = scenarios::replay::summary(&m);
    assert!(line.contains("ground truth in another frame") && line.contains("kind = \"gps\""), "{line}");
}

/// Detections in millimetres are replayed as given, and the metrics and summary say how
/// many lie beyond any mapping laser's reach or any trunk's width.
#[test]
fn detections_in_millimetres_are_counted_and_named() {
    let mut log = synthetic_park();
    log.manifest.vehicle.wheelbase_m = Some(2.83);
    let config = resolve_config(None, &log.manifest, Some(AssociationMethod::Nn), None).unwrap();
    let m = replay(log.clone(), config.clone(), None, None).unwrap().metrics;
    assert_eq!(m.detections_beyond_reach, Some(0));
    assert!(!scenarios::replay::summary(&m).contains("millimetres"));
    let Observations::Detections(scans) = &mut log.observations else { panic!("detections") };
    let last = scans.last_mut().unwrap();
    last.detections.iter_mut().for_each(|d| d.diameter_m = d.diameter_m.map(|w| w * 1000.0));
    last.detections[0].range_m *= 1000.0;
    let wide = last.detections.iter().filter(|d| d.diameter_m.is_some_and(|w| w > 20.0) || d.range_m > 1000.0).count();
    assert!(wide > 0, "the last scan holds a detection with a diameter or a far one");
    let m = replay(log, config, None, None).unwrap().metrics;
    assert_eq!(m.detections_beyond_reach, Some(wide));
    let line = scenarios::replay::summary(&m);
    assert!(line.contains(&format!("{wide} of {} detections lie beyond 1000 m", m.detections)), "{line}");
}

#[test]
fn a_fault_found_mid_replay_names_its_row_and_leaves_earlier_outputs_whole() {
    // The log directory is read as the replay goes: a bad last row stops it there.
    let dir = temp_dir("fault");
    let mut log = synthetic_park();
    log.manifest.vehicle.wheelbase_m = Some(2.83);
    log.manifest.reference = Some(robotlog::manifest::Reference {
        kind: robotlog::ReferenceKind::Gps,
        point: robotlog::ReferencePoint::Sensor,
    });
    robotlog::format::write(&dir.join("log"), &log).unwrap();
    let detections = dir.join("log/detections.csv");
    let mut text = std::fs::read_to_string(&detections).unwrap();
    let rows = text.lines().count();
    text.push_str("1000,abc,0.1,\n");
    std::fs::write(&detections, text).unwrap();
    let out = dir.join("replay");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("trajectory_est.tum"), "an earlier replay's\n").unwrap();
    std::fs::write(out.join("metadata.json"), r#"{"tool": "objslam replay"}"#).unwrap();

    let stream = robotlog::format::open(&dir.join("log")).unwrap();
    let config = resolve_config(None, &stream.manifest, Some(AssociationMethod::Nn), None).unwrap();
    let e = replay(stream, config, None, Some(&out)).err().expect("the bad row stops the replay").to_string();
    assert!(e.contains(&format!("detections.csv:{}: column `range_m`: `abc` is not a number", rows + 1)), "{e}");
    assert_eq!(std::fs::read_to_string(out.join("trajectory_est.tum")).unwrap(), "an earlier replay's\n");
    let mut left: Vec<_> = std::fs::read_dir(&out).unwrap().map(|f| f.unwrap().file_name()).collect();
    left.sort();
    assert_eq!(left, ["metadata.json", "trajectory_est.tum"].map(std::ffi::OsString::from), "no partial or new output");
    std::fs::remove_dir_all(&dir).ok();
}

/// A log whose motion stops while its sensors go on (an odometry file cut short) is
/// refused, not replayed as a vehicle standing still.
#[test]
fn motion_cut_short_is_refused() {
    let mut log = synthetic_park();
    log.manifest.vehicle.wheelbase_m = Some(2.83);
    let config = resolve_config(None, &log.manifest, Some(AssociationMethod::Nn), None).unwrap();
    let last_scan = match &log.observations {
        Observations::Detections(d) => d.last().unwrap().t,
        Observations::Scans(s) => s.last().unwrap().t,
    };
    let Motion::Controls(controls) = &mut log.motion else { panic!("a car's controls") };
    controls.retain(|(t, _)| *t < last_scan - 5.0);
    let motion_end = controls.last().unwrap().0;
    let e = replay(log, config, None, None).err().expect("cut motion is refused").to_string();
    assert!(e.contains(&format!("the motion ends at t = {motion_end} s while observations go on")), "{e}");
}

/// The synthetic park driven by a car of 2.83 m wheelbase, and the `nn` settings for it.
fn car_park_for_nn() -> (Log, slam::pipeline::PipelineConfig) {
    let mut log = synthetic_park();
    log.manifest.vehicle.wheelbase_m = Some(2.83);
    let config = resolve_config(None, &log.manifest, Some(AssociationMethod::Nn), None).unwrap();
    (log, config)
}

/// The times of `log`'s scans, whole or of detections.
fn scan_times(log: &Log) -> Vec<f64> {
    match &log.observations {
        Observations::Detections(d) => d.iter().map(|s| s.t).collect(),
        Observations::Scans(s) => s.iter().map(|s| s.t).collect(),
    }
}

/// A log most of whose observations come before its motion's first row (odometry on
/// another clock) is refused; a few seconds of scans before it (a laser started while
/// the vehicle stood) are replayed from the start pose and counted.
#[test]
fn motion_starting_after_most_observations_is_refused() {
    let (log, config) = car_park_for_nn();
    let scan_times = scan_times(&log);
    let late = |after: f64| {
        let mut log = log.clone();
        let Motion::Controls(controls) = &mut log.motion else { panic!("a car's controls") };
        controls.retain(|(t, _)| *t > after);
        (controls[0].0, log)
    };
    let (motion_start, most_before) = late(scan_times[scan_times.len() * 2 / 3]);
    let e = replay(most_before, config.clone(), None, None).err().expect("late motion is refused").to_string();
    let before = scan_times.iter().filter(|&&t| t < motion_start).count();
    assert!(
        e.contains(&format!(
            "{before} of the {} observations come before the motion's first row at t = {motion_start} s",
            scan_times.len()
        )),
        "{e}"
    );
    let (motion_start, few_before) = late(scan_times[0] + 3.0);
    let m = replay(few_before, config, None, None).expect("a laser started early replays").metrics;
    assert_eq!(m.scans_before_motion, scan_times.iter().filter(|&&t| t < motion_start).count());
    assert!(m.scans_before_motion > 0);
    assert!(
        scenarios::replay::summary(&m).contains("scans before the motion's first row, replayed from the start pose")
    );
}

/// Scans in a gap of the motion's middle (rows lost, or a control held for seconds) are
/// counted and named in the summary: the replay cannot tell the two apart, the user can.
#[test]
fn scans_in_a_gap_of_the_motion_are_counted() {
    let (mut log, config) = car_park_for_nn();
    let whole = replay(log.clone(), config.clone(), None, None).unwrap().metrics;
    assert_eq!(whole.scans_in_motion_gaps, 0);
    assert!(!scenarios::replay::summary(&whole).contains("after the motion row before"));
    let scan_times = scan_times(&log);
    let from = scan_times[scan_times.len() / 2];
    let Motion::Controls(controls) = &mut log.motion else { panic!("a car's controls") };
    controls.retain(|(t, _)| !(from..from + 3.0).contains(t));
    let last_before = controls.iter().map(|c| c.0).filter(|&t| t < from).fold(f64::NEG_INFINITY, f64::max);
    let first_after = controls.iter().map(|c| c.0).find(|&t| t >= from).expect("controls after the gap");
    let m = replay(log, config, None, None).unwrap().metrics;
    // At equal times the motion comes first: a scan at the first row after the gap is past it.
    let expected = scan_times.iter().filter(|&&t| t > last_before + 1.0 && t < first_after).count();
    assert!(expected > 0);
    assert_eq!(m.scans_in_motion_gaps, expected);
    let summary = scenarios::replay::summary(&m);
    assert!(summary.contains(&format!("{expected} scans more than 1 s after the motion row before")), "{summary}");
}

/// Motion in milliseconds beside observations in seconds lasts a thousand times as long:
/// refused, not replayed from poses parked between its rows. Controls held for seconds
/// between rows (a row written when a control changes) are sound.
#[test]
fn motion_in_milliseconds_is_refused_and_held_controls_are_not() {
    let mut log = synthetic_park();
    log.manifest.vehicle.wheelbase_m = Some(2.83);
    let config = resolve_config(None, &log.manifest, Some(AssociationMethod::Nn), None).unwrap();
    let mut held = log.clone();
    let Motion::Controls(controls) = &mut log.motion else { panic!("a car's controls") };
    let first = controls[0].0;
    for (t, _) in controls.iter_mut() {
        *t = first + (*t - first) * 1000.0;
    }
    let e = replay(log, config.clone(), None, None).err().expect("refused").to_string();
    assert!(
        e.contains("more than 100 times the observations'") && e.contains("must be on the observations' clock"),
        "{e}"
    );
    // One control row in every 5 s, and the last (a log of held controls closes with a
    // row, or it reads as cut short): each observation falls in a gap of seconds.
    let Motion::Controls(controls) = &mut held.motion else { panic!("a car's controls") };
    let last = *controls.last().unwrap();
    let mut next = f64::NEG_INFINITY;
    controls.retain(|(t, _)| {
        let keep = *t >= next;
        if keep {
            next = t + 5.0;
        }
        keep
    });
    if controls.last() != Some(&last) {
        controls.push(last);
    }
    replay(held, config, None, None).expect("held controls replay");
}

/// A reference of a longer session, or in milliseconds, of which fewer than a tenth of
/// the samples fall within the replayed poses' times: scored, and the summary says so.
#[test]
fn a_reference_mostly_outside_the_log_is_named() {
    let mut log = synthetic_car_with_gps();
    let config = resolve_config(None, &log.manifest, Some(AssociationMethod::Nn), None).unwrap();
    let whole = replay(log.clone(), config.clone(), None, None).unwrap().metrics;
    assert!(!scenarios::replay::summary(&whole).contains("fewer than a tenth"));
    for sample in &mut log.reference {
        sample.t *= 1000.0;
    }
    let m = replay(log, config, None, None).unwrap().metrics;
    let r = m.reference.as_ref().unwrap();
    assert!(r.samples_scored > 0 && 10 * r.samples_scored < r.samples, "{} of {}", r.samples_scored, r.samples);
    let line = scenarios::replay::summary(&m);
    assert!(line.contains("fewer than a tenth of the samples lie within the estimate's time span"), "{line}");
}

/// A settings file given to a replay (`--config`, or a log's `pipeline.toml`) is refused at
/// the line of the key that is wrong, bare or under `[pipeline]`, arrays longer than their
/// field included.
#[test]
fn a_replays_settings_file_is_refused_at_the_line_of_its_bad_key() {
    let dir = temp_dir("settings");
    std::fs::create_dir_all(&dir).unwrap();
    let manifest = synthetic_park().manifest;
    let file = dir.join("settings.toml");
    for (text, expect) in [
        ("# c\n# c\n[pipeline]\ngate_probability = 0.9\nbatch_updates = \"yes\"\n", ":5: batch_updates: invalid type"),
        ("[pipeline]\n\ninitial_pose_sigma = [0.1, 0.1, 0.1, 0.1]\n", ":3: initial_pose_sigma: 4 elements, more than"),
        ("\ninitial_pose_sigma = [0.1, 0.1, 0.1, 0.1]\n", ":2: initial_pose_sigma: 4 elements, more than"),
        ("[pipeline.clustering]\n\nmin_pints = 3\n", ":3: clustering.min_pints: unknown field `min_pints`"),
        // A scenario's other tables are named where they stand, not [pipeline].
        (
            "[pipeline]\ngate_probability = 0.9\n\n[world]\npreset = \"park\"\n",
            ":4: world: a replay reads pipeline settings only",
        ),
        // A motion model that cannot read the log's motion, before the replay starts.
        (
            "[pipeline.motion]\nmodel = \"odometry\"\n",
            ":2: pipeline.motion.model = \"odometry\" cannot read this log's motion: its manifest.toml says vehicle.motion = \"ackermann\" (speed and steering controls)",
        ),
        ("\n[motion]\nmodel = \"odometry\"\n", ":3: pipeline.motion.model = \"odometry\" cannot read"),
    ] {
        std::fs::write(&file, text).unwrap();
        let e = resolve_config(None, &manifest, None, Some(&file)).unwrap_err().to_string();
        assert!(e.contains(&format!("settings.toml{expect}")), "{text}: {e}");
    }
    std::fs::remove_dir_all(&dir).ok();
}
