//! `objslam find` compares an example's appearance with a run's object models only in the
//! feature space they were described in.

use std::process::Command;

#[test]
fn find_refuses_a_model_other_than_the_runs_and_a_run_without_objects() {
    let root = std::env::temp_dir().join(format!("objslam-find-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let objects = root.join("run/objects");
    std::fs::create_dir_all(&objects).unwrap();
    // A tiny model, trained in moments, as the run's; another whose PCA differs.
    let (mut sc, base) = scenarios::scenario::Scenario::load("paper_park").unwrap();
    sc.appearance.training_images = 2;
    sc.appearance.max_patches_per_class = 300;
    sc.appearance.max_components = 2;
    sc.appearance.pca_dims = 4;
    let model = sc.appearance.resolve_in(&root.join("cache"), &base, &sc.sim.camera, |_, _, _| {}).unwrap();
    model.save(&objects.join("appearance_model.json")).unwrap();
    let mut other = model.clone();
    other.extractor.pca.mean[0] += 1.0;
    other.save(&root.join("other.json")).unwrap();
    std::fs::write(objects.join("models.json"), r#"{"format_version": 1, "objects": []}"#).unwrap();
    image::RgbImage::from_pixel(64, 48, image::Rgb([90, 70, 50])).save(root.join("example.png")).unwrap();
    let find = |run: &str, model: Option<&str>| {
        let mut args = vec!["find".to_string(), "--run".into(), root.join(run).display().to_string()];
        args.push(root.join("example.png").display().to_string());
        if let Some(m) = model {
            args.extend(["--model".to_string(), root.join(m).display().to_string()]);
        }
        let out = Command::new(env!("CARGO_BIN_EXE_objslam")).args(&args).output().expect("objslam runs");
        (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
    };
    let (ok, e) = find("run", Some("other.json"));
    assert!(!ok && e.contains("not the model whose features describe the run's objects"), "{e}");
    // The run's own model, named or not, gets past the check (to the example's patches).
    for model in [None, Some("run/objects/appearance_model.json")] {
        let (_, e) = find("run", model);
        assert!(!e.contains("not the model whose features"), "{e}");
    }
    // The run's object models are read as written, checked, in their own dimensions.
    let object = |id: u32, dims: usize| {
        let identity: Vec<String> =
            (0..dims * dims).map(|k| if k % (dims + 1) == 0 { "1.0" } else { "0.0" }.to_string()).collect();
        format!(
            r#"[{id}, {{"gmm": {{"components": [{{"weight": 1.0, "mean": [[{}], {dims}, null], "covariance": [[{}], {dims}, {dims}]}}]}}, "patches": 10.0, "observations": 2, "mosaic": {{"cells": [], "appearance": []}}}}]"#,
            vec!["0.0"; dims].join(", "),
            identity.join(", ")
        )
    };
    let models = |version: u32, objects: &[String]| {
        let text = format!(r#"{{"format_version": {version}, "objects": [{}]}}"#, objects.join(", "));
        std::fs::write(objects_file(&root), text).unwrap();
    };
    fn objects_file(root: &std::path::Path) -> std::path::PathBuf {
        root.join("run/objects/models.json")
    }
    for (version, listed, expect) in [
        (9, vec![object(0, 5)], "format_version 9, this objslam reads version 1"),
        (1, vec![object(0, 5), object(3, 3)], "landmark 3: a mixture of 3 dimensions"),
        (
            1,
            vec![object(0, 5), object(3, 6)],
            "landmark 3: 3 appearance dimensions where the landmarks before it have 2",
        ),
        (1, vec![object(0, 5), object(0, 5)], "landmark 0: listed twice"),
        (1, vec![object(1, 9)], "describe 6 appearance coordinates; the appearance model's PCA has 4"),
    ] {
        models(version, &listed);
        let (ok, e) = find("run", None);
        assert!(!ok && e.contains("models.json") && e.contains(expect), "{expect}: {e}");
    }
    // Sound models of 2 appearance coordinates (a run's `appearance_dims` other than the
    // default) get past the checks, to the example's patches.
    models(1, &[object(0, 5), object(4, 5)]);
    let (ok, e) = find("run", None);
    assert!(!ok && e.contains("example.png") && e.contains("patches look like the object class"), "{e}");

    std::fs::remove_dir_all(&objects).unwrap();
    let (ok, e) = find("run", None);
    assert!(
        !ok && e.contains("no objects/models.json: give the directory of an `objslam run` of a camera method"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&root);
}
