//! Regression tests for inputs that once crashed, hung or allocated without bound: each is
//! now a clear error naming the file or setting.

use scenarios::montecarlo::{StudyPlan, Vary};

#[test]
fn a_dataset_with_zero_pixel_patches_is_an_error_not_a_division_by_zero() {
    let dir = std::env::temp_dir().join(format!("objslam-bad-dataset-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let world = worlds::generate::park(&Default::default(), 4).unwrap();
    let mut config = scenarios::dataset::DatasetConfig { images: 1, seed: 2, ..Default::default() };
    config.camera.width = 90;
    config.camera.height = 72;
    let manifest = scenarios::dataset::make_dataset(&world, "park", &config, &dir, |_, _| {}).unwrap();
    let labels = dir.join(&manifest.images[0].patches);
    let mut l: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&labels).unwrap()).unwrap();
    l["patch_size"] = 0.into();
    std::fs::write(&labels, l.to_string()).unwrap();
    let e = scenarios::train::load_image(&dir, &manifest, 0).err().expect("an error").to_string();
    assert!(e.contains("_patches.json") && e.contains("patch_size"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn study_plans_that_cannot_run_are_refused_before_any_job_is_made() {
    let plan = |methods: &[&str], runs: usize, vary: Vec<Vary>| StudyPlan {
        scenario: "laser_only".into(),
        base_seed: 1,
        runs,
        methods: methods.iter().map(|m| m.to_string()).collect(),
        vary,
    };
    for (p, words) in [
        (plan(&[], 3, vec![]), "no method"),
        (plan(&["nn", "bogus"], 3, vec![]), "bogus"),
        (plan(&["nn", "nn"], 3, vec![]), "twice"),
        (plan(&["nn"], 0, vec![]), "at least 1"),
        (plan(&["nn"], 1_000_000_000, vec![]), "more than"),
        (plan(&["nn"], 1001, vec![Vary::parse("sim.odometry.scale_sigma=0..0.1:1000").unwrap()]), "more than"),
    ] {
        let e = p.check().unwrap_err().to_string();
        assert!(e.contains(words), "{words}: {e}");
    }
    assert!(plan(&["nn", "jcbb"], 100, vec![]).check().is_ok());
    // Ranges wider than f64 and step counts without bound are errors, not endless plots.
    for spec in ["sim.odometry.scale_sigma=-1e308..1e308:3", "sim.odometry.scale_sigma=0..1:1000000000"] {
        assert!(Vary::parse(spec).is_err(), "{spec}");
    }
}

#[test]
fn absurd_rates_and_filter_widths_are_errors() {
    let sim = sim::SimConfig { physics_rate_hz: 1e7, ..Default::default() };
    let e = sim.check().unwrap_err().to_string();
    assert!(e.contains("physics_rate_hz"), "{e}");
    // A sensor faster than physics is named by its own key.
    let mut sim = sim::SimConfig::default();
    sim.laser.rate_hz = 200.0;
    let e = sim.check().unwrap_err().to_string();
    assert!(e.contains("laser.rate_hz") && e.contains("200 Hz is faster than physics"), "{e}");
    let mut sim = sim::SimConfig::default();
    sim.robot.length_m = 1e300;
    let e = sim.check().unwrap_err().to_string();
    assert!(e.contains("robot.length_m") && e.contains("at most 5 m"), "{e}");
    let mut sim = sim::SimConfig::default();
    sim.robot.safety_stop_m = 1000.0;
    let e = sim.check().unwrap_err().to_string();
    assert!(e.contains("robot.safety_stop_m") && e.contains("not within the laser's range"), "{e}");
    let mut sim = sim::SimConfig::default();
    sim.laser.fov_deg = 100.3;
    let e = sim.check().unwrap_err().to_string();
    assert!(e.contains("laser.fov_deg") && e.contains("not a whole number of"), "{e}");
    let mut features = slam::features::FeatureConfig::default();
    features.bank.filters[0].sigma_px = 1e6;
    let e = features.validate().unwrap_err().to_string();
    assert!(e.contains("bank.filters[0].sigma_px"), "{e}");
    features.bank.filters[0].sigma_px = 2.0;
    features.bank.filters[1].lambda_px = 0.0;
    assert!(features.validate().unwrap_err().to_string().contains("lambda_px"));
    let features = slam::features::FeatureConfig { patch_size: 0, ..Default::default() };
    assert!(features.validate().unwrap_err().to_string().contains("patch_size"));
    let features = slam::features::FeatureConfig { channel_gain: vec![1.0; 3], ..Default::default() };
    assert!(features.validate().unwrap_err().to_string().contains("channel_gain"));
}

#[test]
fn criteria_no_run_could_pass_are_errors_naming_the_line() {
    let base = "name = \"x\"\n[world]\npreset = \"park\"\n[pass]\n";
    for (criteria, field) in [
        ("min_false_landmarks = 3\nmax_false_landmarks = 1\n", "pass.min_false_landmarks"),
        ("max_ate_rmse_m = -0.5\n", "pass.max_ate_rmse_m"),
        ("max_landmark_rmse_m = 0.0\n", "pass.max_landmark_rmse_m"),
        ("max_calibration_rotation_error_deg = -1.0\n", "pass.max_calibration_rotation_error_deg"),
    ] {
        let text = format!("{base}{criteria}");
        let e = scenarios::scenario::Scenario::parse(&text, std::path::Path::new("x.toml"))
            .expect_err("a criterion no run could pass")
            .to_string();
        assert!(e.contains("x.toml") && e.contains(field) && e.contains("no run could pass"), "{e}");
    }
}

#[test]
fn a_covariance_of_the_wrong_shape_says_so_rather_than_a_dimension_mismatch_of_equal_numbers() {
    use nalgebra::{DMatrix, DVector};
    let g = slam::gmm::Gmm {
        components: vec![slam::gmm::Component {
            weight: 1.0,
            mean: DVector::zeros(7),
            covariance: DMatrix::identity(7, 6),
        }],
    };
    let Err(e) = slam::gmm::GmmEvaluator::new(&g) else { panic!("a 7x6 covariance was accepted") };
    let e = e.to_string();
    assert!(e.contains("7x6") && e.contains("7 dimensions"), "{e}");
    let Err(e) = slam::kl::PreparedGmm::new(&g) else { panic!("a 7x6 covariance was accepted") };
    let e = e.to_string();
    assert!(e.contains("7x6") && e.contains("7 dimensions"), "{e}");
}
