//! A pinned snapshot of `laser_only` seed 1's metrics (wall clock aside): any change of
//! behaviour, anywhere from the world generator to the scoring, shows here, so "identical
//! results" is checked by CI rather than by hand. A change that alters results on purpose
//! regenerates it (`OBJSLAM_UPDATE_SNAPSHOTS=1 cargo test -p objslam-tests --test snapshot`)
//! and says so in its commit.

use scenarios::run::{Metrics, RunOptions, run};
use scenarios::scenario::Scenario;

#[test]
fn laser_only_seed_1_metrics_match_the_pinned_snapshot() {
    let (sc, base) = Scenario::load("laser_only").unwrap();
    let m = run(&sc, &base, &RunOptions { seed: Some(1), ..Default::default() }, |_| {}).unwrap().metrics;
    let comparable = Metrics { timing: Default::default(), ..m.without_wall_clock() };
    let text = serde_json::to_string_pretty(&comparable).unwrap() + "\n";
    let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("snapshots/laser_only_seed1_metrics.json");
    if std::env::var_os("OBJSLAM_UPDATE_SNAPSHOTS").is_some() {
        std::fs::write(&file, &text).unwrap();
    }
    let pinned = std::fs::read_to_string(&file).unwrap_or_default();
    assert!(
        pinned == text,
        "laser_only seed 1 changed; if on purpose: OBJSLAM_UPDATE_SNAPSHOTS=1 cargo test -p objslam-tests --test snapshot\n--- pinned\n{pinned}\n--- now\n{text}"
    );
}
