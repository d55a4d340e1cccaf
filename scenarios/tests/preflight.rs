//! `objslam config check`'s checks (`run::preflight`): every built-in scenario passes, and
//! what a run would only find at its start (a calibration file, an appearance model file,
//! a yawed laser) is found without running.

use std::path::Path;

use scenarios::scenario::{LIBRARY, Scenario};

#[test]
fn every_built_in_scenario_passes_preflight() {
    for (name, _) in LIBRARY {
        let (sc, base) = Scenario::load(name).unwrap();
        let found = scenarios::run::preflight(&sc, &base, None, None).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(found.objects > 0, "{name}");
        assert_eq!(found.appearance.is_some(), found.method.uses_appearance(), "{name}");
    }
}

#[test]
fn files_a_run_reads_at_its_start_are_checked_without_running() {
    let dir = std::env::temp_dir().join(format!("objslam-preflight-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let write = |name: &str, text: &str| {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path
    };
    let check = |path: &Path| {
        let (sc, base) = Scenario::load(path.to_str().unwrap()).unwrap();
        scenarios::run::preflight(&sc, &base, None, None).map(|_| ()).map_err(|e| e.to_string())
    };
    write("cal.json", r#"{"phi": [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], "delta": [1e300, 0, 0]}"#);
    let e = check(&write("cal.toml", "name = \"cal\"\ncalibration = \"cal.json\"\n[world]\npreset = \"park\"\n"))
        .unwrap_err();
    assert!(e.contains("cal.json") && e.contains("delta"), "{e}");
    write("model.json", "{\"format_version\": 1}");
    let e =
        check(&write("model.toml", "name = \"m\"\n[world]\npreset = \"park\"\n[appearance]\nmodel = \"model.json\"\n"))
            .unwrap_err();
    assert!(e.contains("model.json") && e.contains("missing field"), "{e}");
    // The same scenario with a position-only method needs no model.
    let (sc, base) = Scenario::load(dir.join("model.toml").to_str().unwrap()).unwrap();
    scenarios::run::preflight(&sc, &base, Some(slam::association::AssociationMethod::Jcbb), None).unwrap();
    let yawed = write("yawed.toml", "name = \"y\"\n[world]\npreset = \"park\"\n[sim.laser]\nmount_yaw_deg = 5.0\n");
    let e = check(&yawed).unwrap_err();
    assert!(e.contains("yawed.toml") && e.contains("mount_yaw_deg"), "{e}");
    // A calibration file of a version this build does not read, and one that gives none.
    write("v7.json", r#"{"format_version": 7, "phi": [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], "delta": [0, 0, 0]}"#);
    let e =
        check(&write("v7.toml", "name = \"v\"\ncalibration = \"v7.json\"\n[world]\npreset = \"park\"\n")).unwrap_err();
    assert!(e.contains("v7.json") && e.contains("format_version") && e.contains("is 7"), "{e}");
    write("v1.json", r#"{"format_version": 1, "phi": [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], "delta": [0, 0, 0]}"#);
    check(&write("v1.toml", "name = \"v\"\ncalibration = \"v1.json\"\n[world]\npreset = \"park\"\n")).unwrap();
    // A recall criterion in a world without trees: no run could meet it.
    let treeless = "name = \"t\"\n[world]\npreset = \"park\"\n[world.params]\ntrees = 0\nposts = 0\n";
    check(&write("treeless.toml", treeless)).unwrap();
    let e = check(&write("treeless_recall.toml", &format!("{treeless}[pass]\nmin_tree_recall = 0.9\n"))).unwrap_err();
    assert!(e.contains("treeless_recall.toml") && e.contains("pass.min_tree_recall") && e.contains("no tree"), "{e}");
    // A landmark RMSE bound with nothing a landmark could be paired with.
    let bare = format!("{treeless}palms = 0\n");
    let e = check(&write("bare_rmse.toml", &format!("{bare}[pass]\nmax_landmark_rmse_m = 0.2\n"))).unwrap_err();
    assert!(
        e.contains("bare_rmse.toml") && e.contains("pass.max_landmark_rmse_m") && e.contains("no tree, post or palm"),
        "{e}"
    );
    check(&write("palms_rmse.toml", &format!("{treeless}[pass]\nmax_landmark_rmse_m = 0.2\n"))).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}
