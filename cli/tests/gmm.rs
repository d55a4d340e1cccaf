//! `objslam gmm fit` and `objslam gmm score` from the command line: both searches fit the
//! same mixture, the score is the model's held-out log-likelihood, and bad files are errors
//! naming the file.

use std::path::Path;
use std::process::Command;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `n` points from two Gaussians in 2-D, centres 10 apart, as CSV text.
fn two_clusters(seed: u64, n: usize) -> String {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut text = String::from("x,y\n");
    for i in 0..n {
        let centre = if i % 3 == 0 { (10.0, 0.0) } else { (0.0, 0.0) };
        // Sums of uniforms: near-Gaussian, and no extra crate.
        let mut g = || (0..12).map(|_| rng.random_range(0.0..1.0)).sum::<f64>() - 6.0;
        text.push_str(&format!("{},{}\n", centre.0 + g(), centre.1 + 0.5 * g()));
    }
    text
}

fn objslam(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_objslam")).args(args).output().expect("objslam runs")
}

fn path(p: &Path) -> &str {
    p.to_str().expect("a UTF-8 temporary path")
}

fn score_of(stdout: &[u8]) -> f64 {
    let text = String::from_utf8_lossy(stdout);
    let line = text.lines().find(|l| l.starts_with("mean held-out log-likelihood:")).expect("a score line");
    line.split_whitespace().nth(3).and_then(|v| v.parse().ok()).expect("a number")
}

#[test]
fn both_searches_fit_the_same_mixture_and_score_it_on_held_out_points() {
    let dir = std::env::temp_dir().join(format!("objslam-gmm-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let (train, heldout) = (dir.join("train.csv"), dir.join("heldout.csv"));
    std::fs::write(&train, two_clusters(1, 900)).unwrap();
    std::fs::write(&heldout, two_clusters(2, 300)).unwrap();
    let mut scores = Vec::new();
    for search in ["prune", "grow"] {
        let model = dir.join(format!("{search}.json"));
        let fit = objslam(&["gmm", "fit", path(&train), "--search", search, "--out", path(&model)]);
        assert!(fit.status.success(), "{search}: {}", String::from_utf8_lossy(&fit.stderr));
        let fitted = scenarios::train::gmm_of_model_file(&std::fs::read_to_string(&model).unwrap()).unwrap();
        assert_eq!(fitted.effective_components(0.02), 2, "{search}");
        // The file says how it was fitted: the same data and options fit it again.
        let file: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&model).unwrap()).unwrap();
        let options: slam::gmm::VbOptions = serde_json::from_value(file["fit"]["options"].clone()).unwrap();
        assert_eq!(file["fit"]["data"], path(&train));
        assert_eq!(file["format_version"], 1, "{search}");
        let digest: String = <sha2::Sha256 as sha2::Digest>::digest(std::fs::read(&train).unwrap())
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        assert_eq!(file["fit"]["data_sha256"], digest.as_str());
        assert_eq!(scenarios::train::gmm_fit_csv(&train, &options).unwrap(), (fitted.clone(), digest), "{search}");
        let score = objslam(&["gmm", "score", path(&model), path(&heldout)]);
        assert!(score.status.success(), "{search}: {}", String::from_utf8_lossy(&score.stderr));
        let printed = score_of(&score.stdout);
        let data = scenarios::train::read_csv(&heldout).unwrap();
        let direct = fitted.mean_log_predictive(&data).unwrap();
        assert!((printed - direct).abs() < 1e-5, "{search}: printed {printed}, computed {direct}");
        scores.push(printed);
    }
    // Variances 1 and 0.25: a one-Gaussian fit of the pair scores far lower than this.
    assert!((-3.5..-2.0).contains(&scores[0]), "{scores:?}");
    assert!((scores[0] - scores[1]).abs() < 0.01, "{scores:?}");

    // Bad files: each error names the file and the problem.
    let model = dir.join("prune.json");
    let wide = dir.join("wide.csv");
    std::fs::write(&wide, "1,2,3\n4,5,6\n").unwrap();
    let out = objslam(&["gmm", "score", path(&model), path(&wide)]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("wide.csv") && e.contains("3 columns"), "{e}");
    let broken = dir.join("broken.json");
    let mut json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&model).unwrap()).unwrap();
    json["components"][0]["nu"] = (-1.0).into();
    std::fs::write(&broken, json.to_string()).unwrap();
    let out = objslam(&["gmm", "score", path(&broken), path(&heldout)]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("broken.json") && e.contains("nu"), "{e}");
    // A damaged model is named as the fault, in words that say what is wrong, not the data.
    for (damage, named) in [
        (serde_json::json!({"components": {"0": {"nu": 1e308}}}), "its predictive density cannot be formed"),
        (serde_json::json!({"prior": {"m0": [[1.0, 2.0, 3.0], 3, null]}}), "W0^-1 is 2 x 2; m0 has 3 dimensions"),
        (serde_json::json!({"counts": {"0": -5.0}}), "count 0 is -5"),
        (serde_json::json!({"components": {"0": {"extra": 1}}}), "unknown field `extra`"),
    ] {
        let mut json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&model).unwrap()).unwrap();
        // Each damage names one value by its path: objects' keys, arrays' indices.
        let mut at = &mut json;
        let mut change = &damage;
        while let Some((key, inner)) = change.as_object().and_then(|o| o.iter().next()) {
            at = match key.parse::<usize>() {
                Ok(i) => &mut at[i],
                Err(_) => &mut at[key.as_str()],
            };
            change = inner;
        }
        *at = change.clone();
        std::fs::write(&broken, json.to_string()).unwrap();
        let out = objslam(&["gmm", "score", path(&broken), path(&heldout)]);
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && e.contains("broken.json") && e.contains(named), "{damage}: {e}");
        assert!(!e.contains("heldout"), "the data are not at fault: {e}");
    }
    // Alphas each finite whose sum is not: every weight would be zero, the score a floor.
    let mut json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&model).unwrap()).unwrap();
    let components = json["components"].as_array_mut().unwrap();
    assert!(components.len() >= 2, "the fit found {} components", components.len());
    for c in components {
        c["alpha"] = 1e308.into();
    }
    std::fs::write(&broken, json.to_string()).unwrap();
    let out = objslam(&["gmm", "score", path(&broken), path(&heldout)]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("broken.json") && e.contains("alphas sum to inf"), "{e}");
    // A damaged record of how the model was fitted is refused too, not passed over.
    for (key, bad, named) in [
        ("data_sha256", serde_json::json!(12345), "fit.data_sha256"),
        ("data_sha256", serde_json::json!("abc"), "fit.data_sha256"),
        ("options", serde_json::json!({"max_components": "x"}), "fit.options.max_components"),
        ("surprise", serde_json::json!(1), "surprise"),
        ("data_sha256", serde_json::Value::Null, "fit.data_sha256: null"),
    ] {
        let mut json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&model).unwrap()).unwrap();
        json["fit"][key] = bad;
        std::fs::write(&broken, json.to_string()).unwrap();
        let out = objslam(&["gmm", "score", path(&broken), path(&heldout)]);
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && e.contains("broken.json") && e.contains(named), "{key}: {e}");
    }
    // A field every version writes, missing, is damage, not a default.
    let mut json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&model).unwrap()).unwrap();
    json["fit"]["options"].as_object_mut().unwrap().remove("seed");
    std::fs::write(&broken, json.to_string()).unwrap();
    let out = objslam(&["gmm", "score", path(&broken), path(&heldout)]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("broken.json") && e.contains("fit.options.seed: missing"), "{e}");
    // Another version of the file is refused by its version; a file from before the
    // version was kept (no `format_version`) is read.
    for (bad, named) in [
        (serde_json::json!(2), "format_version 2: this objslam reads version 1"),
        (serde_json::json!("1"), "format_version: \"1\", where a version number belongs"),
    ] {
        let mut json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&model).unwrap()).unwrap();
        json["format_version"] = bad;
        std::fs::write(&broken, json.to_string()).unwrap();
        let out = objslam(&["gmm", "score", path(&broken), path(&heldout)]);
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && e.contains("broken.json") && e.contains(named), "{e}");
    }
    let mut json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&model).unwrap()).unwrap();
    json.as_object_mut().unwrap().remove("format_version");
    let unversioned = dir.join("unversioned.json");
    std::fs::write(&unversioned, json.to_string()).unwrap();
    let out = objslam(&["gmm", "score", path(&unversioned), path(&heldout)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // A record from before the digest was kept is whole.
    let mut json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&model).unwrap()).unwrap();
    let fit = json["fit"].as_object_mut().unwrap();
    fit.remove("data_sha256");
    fit.remove("data_absolute");
    let older = dir.join("older.json");
    std::fs::write(&older, json.to_string()).unwrap();
    let out = objslam(&["gmm", "score", path(&older), path(&heldout)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // ... but one of the two without the other is not.
    json["fit"]["data_absolute"] = serde_json::json!("/data/points.csv");
    std::fs::write(&broken, json.to_string()).unwrap();
    let out = objslam(&["gmm", "score", path(&broken), path(&heldout)]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("broken.json") && e.contains("come together"), "{e}");
    std::fs::write(&broken, "{\"not\": \"a model\"}").unwrap();
    let out = objslam(&["gmm", "score", path(&broken), path(&heldout)]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("broken.json") && e.contains("not an objslam gmm fit model"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Data at the edges of floating point: a point so far out that its squared distance
/// overflows scores a finite log-likelihood; values whose differences' squares underflow
/// are refused for fitting; a byte-order mark before the first field is no part of it.
#[test]
fn extreme_scales_score_finite_or_are_refused() {
    let dir = std::env::temp_dir().join(format!("objslam-gmm-scales-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (train, model, far) = (dir.join("train.csv"), dir.join("model.json"), dir.join("far.csv"));
    // Points a thousandth apart, as a mixture of them is narrow.
    let small: String = two_clusters(3, 200)
        .lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|f| f.parse::<f64>().unwrap() * 1e-3).collect();
            format!("{},{}\n", v[0], v[1])
        })
        .collect();
    std::fs::write(&train, format!("\u{feff}{small}")).unwrap();
    let out = objslam(&["gmm", "fit", path(&train), "--out", path(&model)]);
    assert!(out.status.success(), "a byte-order mark is read past: {}", String::from_utf8_lossy(&out.stderr));
    std::fs::write(&far, "1e153,0\n0,0\n").unwrap();
    let out = objslam(&["gmm", "score", path(&model), path(&far)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let score = score_of(&out.stdout);
    assert!(score.is_finite() && score < -1e4, "{score}");
    let tiny: String = small
        .lines()
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|f| f.parse::<f64>().unwrap() * 1e-167).collect();
            format!("{:e},{:e}\n", v[0], v[1])
        })
        .collect();
    std::fs::write(&train, tiny).unwrap();
    let out = objslam(&["gmm", "fit", path(&train), "--out", path(&model)]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("train.csv") && e.contains("underflow"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
