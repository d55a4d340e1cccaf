//! Structured fuzzing of every input parser: valid files with random edits (bytes deleted,
//! inserted or cut off, numbers replaced by absurd values) must give a result or an error,
//! never a panic or a hang. CI runs a bounded number of cases per parser;
//! `OBJSLAM_FUZZ_CASES=5000 cargo test --release -p objslam-tests --test fuzz` runs longer
//! (docs/guide/fuzzing.md).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};

/// Values that break parsers and validators: signs, zero, huge, tiny, non-finite, non-numbers.
const ABSURD: &[&str] = &[
    "-1",
    "0",
    "-0",
    "1e308",
    "-1e308",
    "1e-320",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "1e999",
    "18446744073709551616",
    "4294967296",
    "65536",
    "\"x\"",
    "[]",
    "{}",
    "true",
    "null",
    "",
];

/// One edit of a file.
#[derive(Debug, Clone)]
enum Edit {
    Delete {
        at: usize,
        len: usize,
    },
    Insert {
        at: usize,
        bytes: Vec<u8>,
    },
    /// Replaces the `index`-th number of the text (counted modulo their count).
    Number {
        index: usize,
        with: &'static str,
    },
    Truncate {
        at: usize,
    },
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        (any::<usize>(), 1..24usize).prop_map(|(at, len)| Edit::Delete { at, len }),
        (any::<usize>(), proptest::collection::vec(any::<u8>(), 1..8))
            .prop_map(|(at, bytes)| Edit::Insert { at, bytes }),
        (any::<usize>(), proptest::sample::select(ABSURD)).prop_map(|(index, with)| Edit::Number { index, with }),
        (any::<usize>(), proptest::sample::select(ABSURD)).prop_map(|(index, with)| Edit::Number { index, with }),
        any::<usize>().prop_map(|at| Edit::Truncate { at }),
    ]
}

/// Byte ranges of the numbers in `text`.
fn numbers(text: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < text.len() {
        let starts = text[i].is_ascii_digit() || (text[i] == b'-' && text.get(i + 1).is_some_and(u8::is_ascii_digit));
        if starts && (i == 0 || !(text[i - 1].is_ascii_alphanumeric() || text[i - 1] == b'_')) {
            let start = i;
            i += 1;
            while i < text.len() && (text[i].is_ascii_digit() || b".eE+-".contains(&text[i])) {
                i += 1;
            }
            out.push((start, i));
        } else {
            i += 1;
        }
    }
    out
}

fn apply(base: &[u8], edits: &[Edit]) -> Vec<u8> {
    let mut v = base.to_vec();
    for e in edits {
        let n = v.len().max(1);
        match e {
            Edit::Delete { at, len } => {
                let at = at % n;
                let end = (at + len).min(v.len());
                v.drain(at.min(v.len())..end);
            }
            Edit::Insert { at, bytes } => {
                let at = at % (v.len() + 1);
                v.splice(at..at, bytes.iter().copied());
            }
            Edit::Number { index, with } => {
                let found = numbers(&v);
                if !found.is_empty() {
                    let (a, b) = found[index % found.len()];
                    v.splice(a..b, with.bytes());
                }
            }
            Edit::Truncate { at } => v.truncate(at % n),
        }
    }
    v
}

fn cases() -> u32 {
    std::env::var("OBJSLAM_FUZZ_CASES").ok().and_then(|s| s.parse().ok()).unwrap_or(48)
}

/// Feeds `parse` edited copies of `base`; each must return within `limit`, saying whether
/// it accepted the input (an error is as good an answer as a result; a panic fails).
/// Prints the counts (`--nocapture` shows them).
fn fuzz(name: &str, base: &[u8], limit: Duration, parse: impl Fn(&[u8]) -> bool) {
    let accepted = std::cell::Cell::new(0usize);
    let tried = std::cell::Cell::new(0usize);
    let config = Config { cases: cases(), failure_persistence: None, ..Config::default() };
    let mut runner = TestRunner::new_with_rng(
        config,
        proptest::test_runner::TestRng::deterministic_rng(proptest::test_runner::RngAlgorithm::ChaCha),
    );
    let strategy = proptest::collection::vec(edit(), 1..6);
    let result = runner.run(&strategy, |edits| {
        let input = apply(base, &edits);
        let started = Instant::now();
        accepted.set(accepted.get() + parse(&input) as usize);
        tried.set(tried.get() + 1);
        let took = started.elapsed();
        prop_assert!(took < limit, "{name}: took {took:?} on edits {edits:?}");
        Ok(())
    });
    if let Err(e) = result {
        panic!("{name}: {e}");
    }
    eprintln!(
        "fuzz {name}: {} edited inputs, {} accepted, {} errors",
        tried.get(),
        accepted.get(),
        tried.get() - accepted.get()
    );
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Writes `bytes` to the file `name` in the test's scratch directory and returns its path.
fn file(dir: &tempfile::TempDir, name: &str, bytes: &[u8]) -> PathBuf {
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

fn park_world() -> worlds::World {
    worlds::generate::park(&Default::default(), 2).unwrap()
}

const SECOND: Duration = Duration::from_secs(1);

#[test]
fn world_files() {
    let base = park_world().to_toml();
    fuzz("world", base.as_bytes(), 5 * SECOND, |b| worlds::parse(&text(b), Path::new("fuzz.toml")).is_ok());
}

#[test]
fn generator_parameters() {
    let base = toml::to_string(&worlds::generate::ParkParams::default()).unwrap();
    fuzz("park params", base.as_bytes(), 5 * SECOND, |b| {
        match toml::from_str::<worlds::generate::ParkParams>(&text(b)) {
            Ok(p) => p.check().is_ok() && worlds::generate::park(&p, 1).is_ok(),
            Err(_) => false,
        }
    });
}

#[test]
fn scenario_files() {
    for (name, base) in scenarios::scenario::LIBRARY {
        fuzz(&format!("scenario {name}"), base.as_bytes(), 5 * SECOND, |b| {
            scenarios::scenario::Scenario::parse(&text(b), Path::new("fuzz.toml")).is_ok()
        });
    }
}

#[test]
fn simulator_settings() {
    let base = toml::to_string(&sim::SimConfig::default()).unwrap();
    fuzz("sim config", base.as_bytes(), 5 * SECOND, |b| {
        toml::from_str::<sim::SimConfig>(&text(b)).is_ok_and(|c| c.check().is_ok())
    });
}

#[test]
fn gltf_meshes() {
    // A small world: one of each static class.
    let mut world = park_world();
    world.objects.truncate(4);
    world.people.clear();
    let base = worlds::gltf_io::export_glb(&world);
    fuzz("glb", &base, 10 * SECOND, |b| worlds::gltf_io::import_mesh_slice(b).is_ok());
}

#[test]
fn calibration_files() {
    let base = br#"{"phi": [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]], "delta": [0.12, 0.0, 0.25]}"#;
    let dir = tempfile::tempdir().unwrap();
    fuzz("calibration.json", base, 5 * SECOND, |b| {
        scenarios::calibrate::load_extrinsics(&file(&dir, "calibration.json", b)).is_ok()
    });
}

#[test]
fn csv_files() {
    let base = b"x,y,z\n1.0,2.0,3.5\n-0.5,2.25,1e-3\n4,5,6\n0.1,0.2,0.3\n";
    let dir = tempfile::tempdir().unwrap();
    fuzz("csv", base, 5 * SECOND, |b| scenarios::train::read_csv(&file(&dir, "data.csv", b)).is_ok());
}

#[test]
fn tum_trajectories() {
    let base = b"# t x y z qx qy qz qw\n0 0 0 0 0 0 0 1\n0.1 0.5 0.01 0 0 0 0.0499792 0.9987503\n0.2 1.0 0.02 0 0 0 0.0998334 0.9950042\n";
    let dir = tempfile::tempdir().unwrap();
    fuzz("tum", base, 5 * SECOND, |b| scenarios::score::estimate::read_tum(&file(&dir, "est.tum", b)).is_ok());
}

/// A tiny appearance model, trained in a moment (its JSON is the seed of the model fuzzing).
fn tiny_model_json(dir: &tempfile::TempDir) -> String {
    let (mut sc, base) = scenarios::scenario::Scenario::load("paper_park").unwrap();
    sc.appearance.training_images = 2;
    sc.appearance.max_patches_per_class = 300;
    sc.appearance.max_components = 2;
    sc.appearance.pca_dims = 4;
    let cache = dir.path().join("models");
    let model = sc.appearance.resolve_in(&cache, &base, &sc.sim.camera, |_, _, _| {}).unwrap();
    serde_json::to_string(&model).unwrap()
}

#[test]
fn appearance_models_and_images() {
    let dir = tempfile::tempdir().unwrap();
    let base = tiny_model_json(&dir);
    fuzz("model json", base.as_bytes(), 20 * SECOND, |b| {
        slam::classifier::AppearanceModel::from_json(&text(b), "fuzz.json").is_ok()
    });
    // Images to segment: a small PNG, edited.
    let model = slam::classifier::AppearanceModel::from_json(&base, "model.json").unwrap();
    let img = image::RgbImage::from_fn(64, 48, |x, y| image::Rgb([(x * 4) as u8, (y * 5) as u8, 90]));
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).unwrap();
    fuzz("png", &png, 20 * SECOND, |b| {
        scenarios::train::segment_image(&model, &file(&dir, "image.png", b), &dir.path().join("segmented.png")).is_ok()
    });
}

#[test]
fn the_edits_reach_numbers() {
    let edited = apply(b"a = 1.5\nb = [2, -3e4]\nname_2 = \"x\"\n", &[Edit::Number { index: 2, with: "nan" }]);
    assert_eq!(text(&edited), "a = 1.5\nb = [2, nan]\nname_2 = \"x\"\n");
}
