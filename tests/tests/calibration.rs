//! Laser-camera extrinsic calibration (Zhang & Pless) in the simulator, end to end: the
//! checkerboard session, its accuracy against the simulator's extrinsics, skipped poses,
//! degenerate pose sets, and the runner using estimated or file extrinsics.

use std::path::Path;

use scenarios::calibrate::{self, CalibrationReport, SessionConfig};
use scenarios::run::{RunOptions, resolve_calibration, run};
use scenarios::scenario::Scenario;

fn session(sc: &Scenario, seed: u64) -> CalibrationReport {
    calibrate::run_session(sc, Path::new("."), seed, Some(20), None).unwrap_or_else(|e| panic!("seed {seed}: {e}"))
}

/// The goal of issue #9: with 20 board poses and the simulator's default noise (laser
/// sigma 1 cm quantised to 1 cm, 640x480 camera), rotation error < 0.3 deg and translation
/// error < 1 cm. Each pose averages 10 scans (the session's `scans_per_pose`). Over seeds
/// 1-12 the errors measured 0.03-0.17 deg and 0.8-4.8 mm; the images alone (noise-free
/// laser) give 0.03-0.15 deg and 0.1-4.4 mm.
#[test]
fn twenty_board_poses_calibrate_within_0_3_deg_and_1_cm() {
    let (sc, _) = Scenario::load("calibration").unwrap();
    for seed in [sc.seed, 2, 3] {
        let r = session(&sc, seed);
        let (rot, trans) = (r.rotation_error_deg.unwrap(), r.translation_error_m.unwrap());
        eprintln!(
            "seed {seed}: {rot:.3} deg, {trans:.4} m; {} of 20 poses, residual RMS {:.4} m",
            r.poses_used, r.rms_residual_m
        );
        assert!(rot < 0.3, "seed {seed}: rotation error {rot} deg");
        assert!(trans < 0.01, "seed {seed}: translation error {trans} m");
        assert_eq!(r.poses_requested, 20);
        assert!(r.poses_used >= 18, "seed {seed}: only {} poses used: {:?}", r.poses_used, r.warnings);
        assert!(r.warnings.iter().all(|w| w.starts_with("skipped")), "{:?}", r.warnings);
        // Averaged 1 cm noise over 10 scans, plus quantisation: a few millimetres.
        assert!(r.rms_residual_m > 0.001 && r.rms_residual_m < 0.006, "residual RMS {}", r.rms_residual_m);
        // The reported uncertainty is consistent with the error made.
        let rot_sigma = r.rotation_sigma_deg.iter().map(|s| s * s).sum::<f64>().sqrt();
        let trans_sigma = r.translation_sigma_m.iter().map(|s| s * s).sum::<f64>().sqrt();
        assert!(
            rot < 4.0 * rot_sigma && trans < 4.0 * trans_sigma,
            "seed {seed}: errors {rot}, {trans} vs sigmas {rot_sigma}, {trans_sigma}"
        );
        assert!(r.rotation_sigma_deg.iter().zip(&r.laser_rotation_sigma_deg).all(|(t, l)| t >= l));
        // Every used pose's plane is close to the truth.
        for p in r.poses.iter().filter(|p| p.skipped.is_none()) {
            assert!(p.truth_normal_error_deg.unwrap() < 0.3 && p.truth_distance_error_m.unwrap().abs() < 0.01, "{p:?}");
            assert!(p.laser_points >= 15, "{p:?}");
        }
    }
}

/// A camera mounted well behind the laser sees each board farther than the laser does, by
/// up to the distance between them: the board is still found in the scan, and the
/// calibration is as good (every pose had been skipped for the range mismatch).
#[test]
fn a_camera_far_from_the_laser_still_finds_its_boards() {
    let (mut sc, _) = Scenario::load("calibration").unwrap();
    sc.sim.camera.mount_xyz_m = [-0.6, 0.0, 0.55];
    let r = session(&sc, 1);
    assert!(r.poses_used >= 15, "{} of 20 poses used: {:?}", r.poses_used, r.warnings);
    assert!(r.rotation_error_deg.unwrap() < 0.3 && r.translation_error_m.unwrap() < 0.01, "{r:?}");
}

#[test]
fn the_session_is_deterministic_and_its_file_round_trips() {
    let (sc, _) = Scenario::load("calibration").unwrap();
    let config = SessionConfig { poses: 8, ..sc.calibration.session.clone() };
    let sim_config = &sc.sim;
    let stations = calibrate::plan_stations(&config, sim_config, 5);
    let world = calibrate::range_world(&stations, &worlds::generate::park(&Default::default(), 1).unwrap()).unwrap();
    let a = calibrate::calibrate_stations(&world, &stations, &config, sim_config, 5, None).unwrap();
    let b = calibrate::calibrate_stations(&world, &stations, &config, sim_config, 5, None).unwrap();
    assert_eq!(a, b);
    let dir = std::env::temp_dir().join(format!("objslam-calib-{}", std::process::id()));
    let file = dir.join("calibration.json");
    a.write(&file).unwrap();
    let back: CalibrationReport = serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    assert_eq!(back, a);
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    for key in [
        "phi",
        "delta",
        "rms_residual_m",
        "rotation_sigma_deg",
        "translation_sigma_m",
        "poses_used",
        "poses_skipped",
        "seed",
        "poses",
        "warnings",
    ] {
        assert!(json.get(key).is_some(), "calibration.json lacks {key}");
    }
    let e = calibrate::load_extrinsics(&file).unwrap();
    assert!(e.error_to(&a.extrinsics()).0 < 1e-6);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Boards turned away from the camera (their backs show no pattern) are reported and
/// skipped; the others still calibrate.
#[test]
fn images_without_the_board_are_reported_and_skipped() {
    let (sc, _) = Scenario::load("calibration").unwrap();
    let config = SessionConfig { poses: 12, ..sc.calibration.session.clone() };
    let mut stations = calibrate::plan_stations(&config, &sc.sim, 7);
    for k in [2, 9] {
        stations[k].board.pose.yaw_deg += 180.0;
    }
    let world = calibrate::range_world(&stations, &worlds::generate::park(&Default::default(), 1).unwrap()).unwrap();
    let r = calibrate::calibrate_stations(&world, &stations, &config, &sc.sim, 7, None).unwrap();
    assert_eq!(r.poses_skipped, 2, "{:?}", r.warnings);
    for k in [2, 9] {
        let reason = r.poses[k].skipped.as_deref().unwrap_or_default();
        assert!(reason.contains("not found in the image"), "pose {k}: {reason}");
        assert!(r.warnings.iter().any(|w| w.contains(&format!("pose {k}:"))), "{:?}", r.warnings);
    }
    assert!(r.rotation_error_deg.unwrap() < 0.5 && r.translation_error_m.unwrap() < 0.02);
}

/// Upright boards only: every normal is horizontal, so the camera's height over the laser
/// is not observable. The calibration must say so, not return a confident answer.
#[test]
fn degenerate_pose_sets_are_flagged() {
    let (sc, _) = Scenario::load("calibration").unwrap();
    let upright =
        SessionConfig { poses: 12, tilt_deg: [0.0, 0.0], turn_deg: [-3.0, 3.0], ..sc.calibration.session.clone() };
    let stations = calibrate::plan_stations(&upright, &sc.sim, 3);
    let world = calibrate::range_world(&stations, &worlds::generate::park(&Default::default(), 1).unwrap()).unwrap();
    match calibrate::calibrate_stations(&world, &stations, &upright, &sc.sim, 3, None) {
        Ok(r) => {
            assert!(r.warnings.iter().any(|w| w.contains("normals span too few directions")), "{:?}", r.warnings);
            assert!(r.warnings.iter().any(|w| w.contains("constrain the extrinsics poorly")), "{:?}", r.warnings);
        }
        Err(e) => assert!(e.to_string().contains("degenerate"), "{e}"),
    }
    // Too few poses: an error naming the minimum.
    let few = SessionConfig { poses: 4, ..sc.calibration.session.clone() };
    let stations = calibrate::plan_stations(&few, &sc.sim, 3);
    let world = calibrate::range_world(&stations, &worlds::generate::park(&Default::default(), 1).unwrap()).unwrap();
    // With pose images asked for: the earlier session's, which match its calibration file,
    // stay; this session's wait beside them, and the error says where.
    let dir = std::env::temp_dir().join(format!("objslam-pose-images-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    for k in [0, 19] {
        std::fs::write(dir.join(format!("pose_{k:02}.png")), "earlier").unwrap();
    }
    let e = calibrate::calibrate_stations(&world, &stations, &few, &sc.sim, 3, Some(&dir)).unwrap_err().to_string();
    assert!(e.contains("at least 5 board poses") && e.contains("4 of 4"), "{e}");
    assert!(e.contains("this session's pose images are in") && e.contains(".unfinished"), "{e}");
    for k in [0, 19] {
        assert_eq!(std::fs::read_to_string(dir.join(format!("pose_{k:02}.png"))).unwrap(), "earlier");
    }
    // A session that is solved replaces them all.
    let good = SessionConfig { poses: 6, ..sc.calibration.session.clone() };
    let stations = calibrate::plan_stations(&good, &sc.sim, 3);
    let world = calibrate::range_world(&stations, &worlds::generate::park(&Default::default(), 1).unwrap()).unwrap();
    calibrate::calibrate_stations(&world, &stations, &good, &sc.sim, 3, Some(&dir)).unwrap();
    let mut names: Vec<String> =
        std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    assert_eq!(names, (0..6).map(|k| format!("pose_{k:02}.png")).collect::<Vec<_>>());
    assert!(image::open(dir.join("pose_00.png")).is_ok());
    let _ = std::fs::remove_dir_all(&dir);
}

/// `calibration = "estimated"` runs the session first, the pipeline's camera geometry gets
/// the estimate, and metadata.json and metrics.json record it; a calibration file is read
/// relative to the scenario; a bad one is named with its field.
#[test]
fn the_runner_resolves_estimated_and_file_calibrations() {
    let (mut sc, base) = Scenario::load("calibration").unwrap();
    sc.sim.max_duration_s = Some(5.0);
    let dir = std::env::temp_dir().join(format!("objslam-calib-run-{}", std::process::id()));
    let out = dir.join("run");
    let m = run(&sc, &base, &RunOptions { out: Some(out.clone()), ..Default::default() }, |_| {}).unwrap().metrics;
    let c = m.calibration.as_ref().unwrap();
    assert_eq!(c.mode, "estimated");
    assert!(c.rotation_error_deg < 0.3 && c.translation_error_m < 0.01, "{c:?}");
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metadata.json")).unwrap()).unwrap();
    let cal = &meta["configuration"]["calibration"];
    assert_eq!(cal["mode"], "estimated");
    assert!(cal["extrinsics"]["phi"].is_array() && cal["truth"]["delta"].is_array());
    let written = calibrate::load_extrinsics(&out.join("calibration.json")).unwrap();
    let resolved: slam::calibration::Extrinsics = serde_json::from_value(cal["extrinsics"].clone()).unwrap();
    assert!(written.error_to(&resolved).0 < 1e-6);

    // The same extrinsics from the file, relative to the scenario's directory.
    let mut from_file = sc.clone();
    from_file.calibration.mode = "run/calibration.json".into();
    let r = resolve_calibration(&from_file, &dir, 1).unwrap();
    assert_eq!(r.mode, "file");
    assert!(r.extrinsics.error_to(&resolved).0 < 1e-6 && r.extrinsics.error_to(&resolved).1 < 1e-9);

    // The file of this camera, read by a run with another camera: refused, by field.
    let mut other_camera = from_file.clone();
    other_camera.sim.camera.hfov_deg += 10.0;
    let e = resolve_calibration(&other_camera, &dir, 1).unwrap_err().to_string();
    assert!(e.contains("calibration.json") && e.contains("camera.fx") && e.contains("another camera"), "{e}");

    // A broken file: the error names the file and the field.
    std::fs::write(dir.join("bad.json"), r#"{"phi": [[1, 0, 0], [0, 1, 0]], "delta": [0, 0, 0]}"#).unwrap();
    from_file.calibration.mode = "bad.json".into();
    let e = resolve_calibration(&from_file, &dir, 1).unwrap_err().to_string();
    assert!(e.contains("bad.json") && e.contains("phi"), "{e}");
    from_file.calibration.mode = "missing.json".into();
    let e = run(&from_file, &dir, &RunOptions::default(), |_| {}).err().unwrap().to_string();
    assert!(e.contains("missing.json"), "{e}");

    // Perturbed: seeded, and as far off as asked.
    let mut perturbed = sc.clone();
    perturbed.calibration.mode = "perturbed".into();
    perturbed.calibration.rotation_sigma_deg = 1.0;
    perturbed.calibration.translation_sigma_m = 0.02;
    let p1 = resolve_calibration(&perturbed, &base, 4).unwrap();
    assert_eq!(p1.extrinsics, resolve_calibration(&perturbed, &base, 4).unwrap().extrinsics);
    assert!(p1.rotation_error_deg > 0.05 && p1.translation_error_m > 0.001);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_calibration_settings_in_scenarios_are_named() {
    let base = "name = \"x\"\n[world]\npreset = \"park\"\n";
    let f = Path::new("bad_cal.toml");
    // The short spelling: just the mode.
    let sc =
        Scenario::parse(&format!("name = \"x\"\ncalibration = \"cal/calibration.json\"\n{}", &base[11..]), f).unwrap();
    assert_eq!(sc.calibration.mode, "cal/calibration.json");
    let e = Scenario::parse(&format!("name = \"x\"\ncalibration = 3\n{}", &base[11..]), f).unwrap_err().to_string();
    assert!(e.contains("bad_cal.toml") && e.contains("calibration"), "{e}");
    let e = Scenario::parse(
        &format!("{base}[calibration]\nmode = \"estimated\"\n[calibration.session]\nsquares = [8, 5]\n"),
        f,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("bad_cal.toml") && e.contains("calibration.session.squares"), "{e}");
    let e = Scenario::parse(
        &format!("{base}[calibration]\nmode = \"estimated\"\n[calibration.session]\ntilt_deg = [-90.0, 10.0]\n"),
        f,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("calibration.session.tilt_deg"), "{e}");
    let e = Scenario::parse(
        &format!("{base}[calibration]\nmode = \"estimated\"\n[calibration.session]\nboard_colour = 3\n"),
        f,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("board_colour"), "{e}");
    let e = Scenario::parse(&format!("{base}[calibration]\nmode = \"perturbed\"\nrotation_sigma_deg = -1.0\n"), f)
        .unwrap_err()
        .to_string();
    assert!(e.contains("calibration.rotation_sigma_deg"), "{e}");
    let e = Scenario::parse(&format!("{base}[calibration]\nmode = \"true\"\ntranslation_sigma_m = 0.1\n"), f)
        .unwrap_err()
        .to_string();
    assert!(e.contains("only apply to mode \\\"perturbed\\\"") || e.contains("perturbed"), "{e}");
}
