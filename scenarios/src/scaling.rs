//! Cost against world size: a park of `paper_park`'s ground and trees (with 4 posts, 1
//! palm and 3 people per 600 m², world seed 6000) scaled up to ten times (ten times is
//! `city_park`), each size run with
//! `jcbb` (no camera: physics and laser only) and `combined` (with the camera). Each stage's
//! cost is the wall-clock time spent in it per simulated second, in milliseconds, so 1,000
//! is real time (the stages run on threads of their own, so they overlap):
//! - physics and laser: the simulator thread of the `jcbb` run;
//! - the camera: the simulator thread of the `combined` run less that of the `jcbb` run,
//!   which is the rendering time the camera's own thread did not hide;
//! - each method's pipeline (clustering, segmentation, association, the filter).
//!
//! `cargo run --release -p scenarios --example world_scaling -- OUT_DIR` runs it and
//! writes `scaling.csv` and `scaling.png` (docs/performance.md).

use std::path::Path;

use serde::Serialize;
use slam::association::AssociationMethod;

use crate::run::{RunError, RunOptions, RunProgress};
use crate::scenario::Scenario;

/// The world sizes measured, as multiples of `paper_park`'s.
pub const FACTORS: [u32; 5] = [1, 2, 4, 7, 10];

/// One run: a world size and a method.
#[derive(Debug, Clone, Serialize)]
pub struct ScalingRow {
    pub factor: u32,
    pub area_m2: f64,
    pub trees: usize,
    /// Static objects of every class (trees, posts, palms, the wall's parts).
    pub objects: usize,
    pub people: usize,
    pub method: String,
    pub sim_seconds: f64,
    pub wall_seconds: f64,
    pub simulator_s: f64,
    pub pipeline_s: f64,
    pub scans: usize,
    pub mean_scan_ms: f64,
    pub landmarks: usize,
    pub rendered_fraction: f64,
}

/// `paper_park`'s park scaled `factor` times: ground and trees (12 per 600 m²) as
/// `paper_park`'s, posts (4), palms (1) and people (3) per 600 m², whose walks start over a
/// time that grows with the route.
pub fn scaled_park(factor: u32) -> Result<Scenario, RunError> {
    let (mut sc, _) = Scenario::load("paper_park")?;
    let k = factor as usize;
    let mut params = sc.world.params.clone().unwrap_or_default();
    params.area_m2 = 600.0 * factor as f64;
    params.trees = 12 * k;
    params.posts = 4 * k;
    params.palms = k;
    params.people = 3 * k;
    params.person_start_time_max_s = 100.0 * factor as f64;
    sc.world.params = Some(params);
    sc.world.seed = Some(6000);
    sc.name = format!("park_x{factor}");
    Ok(sc)
}

/// Runs every size in `factors` with `jcbb` and `combined`; `progress` hears of each run
/// as it starts (size, method).
pub fn measure(
    factors: &[u32],
    base_dir: &Path,
    mut progress: impl FnMut(u32, &str),
) -> Result<Vec<ScalingRow>, RunError> {
    let mut rows = Vec::new();
    for &factor in factors {
        let sc = scaled_park(factor)?;
        let world = sc.world(base_dir, sc.seed)?;
        for method in [AssociationMethod::Jcbb, AssociationMethod::Combined] {
            progress(factor, method.name());
            let options = RunOptions { method: Some(method), ..Default::default() };
            let m = crate::run::run(&sc, base_dir, &options, |_: RunProgress| {})?.metrics;
            rows.push(ScalingRow {
                factor,
                area_m2: world.ground.area_m2(),
                trees: world.objects.iter().filter(|o| o.class == worlds::ObjectClass::Tree).count(),
                objects: world.objects.len(),
                people: world.people.len(),
                method: m.method.clone(),
                sim_seconds: m.sim_seconds,
                wall_seconds: m.wall_seconds,
                simulator_s: m.timing.simulator_s,
                pipeline_s: m.timing.pipeline_s,
                scans: m.timing.scans,
                mean_scan_ms: m.timing.mean_scan_ms,
                landmarks: m.landmarks,
                rendered_fraction: m.timing.rendered_fraction,
            });
        }
    }
    Ok(rows)
}

/// Each stage's cost per size, in ms spent per simulated second, by tree count: physics and
/// laser, rendering, and each method's pipeline.
pub fn stage_costs(rows: &[ScalingRow]) -> Vec<(String, Vec<(f64, f64)>)> {
    let per_s = |s: f64, r: &ScalingRow| 1000.0 * s / r.sim_seconds.max(1e-9);
    let mut physics = vec![];
    let mut rendering = vec![];
    let mut jcbb = vec![];
    let mut combined = vec![];
    let mut jcbb_runs: Vec<&ScalingRow> = rows.iter().filter(|r| r.method == AssociationMethod::Jcbb.name()).collect();
    jcbb_runs.sort_by_key(|r| r.trees);
    for r in jcbb_runs {
        let x = r.trees as f64;
        physics.push((x, per_s(r.simulator_s, r)));
        jcbb.push((x, per_s(r.pipeline_s, r)));
        if let Some(c) = rows.iter().find(|c| c.factor == r.factor && c.method == AssociationMethod::Combined.name()) {
            rendering.push((x, per_s(c.simulator_s, c) - per_s(r.simulator_s, r)));
            combined.push((x, per_s(c.pipeline_s, c)));
        }
    }
    vec![
        ("physics and laser".into(), physics),
        ("camera (combined less jcbb)".into(), rendering),
        ("pipeline, jcbb".into(), jcbb),
        ("pipeline, combined".into(), combined),
    ]
}

/// Reads the rows back from a `scaling.csv` that [`write`] wrote (to draw its plot again);
/// a line that does not fit is an error naming it.
pub fn read_csv(file: &Path) -> Result<Vec<ScalingRow>, crate::plot::PlotError> {
    let bad = |message: String| crate::plot::PlotError { file: file.to_path_buf(), message };
    let text = std::fs::read_to_string(file).map_err(|e| bad(e.to_string()))?;
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate().skip(1).filter(|(_, l)| !l.trim().is_empty()) {
        let c: Vec<&str> = line.split(',').collect();
        let problem = || bad(format!("line {}: not a row of 14 values as written by this benchmark", i + 1));
        if c.len() != 14 {
            return Err(problem());
        }
        let f = |k: usize| c[k].parse::<f64>().map_err(|_| problem());
        let u = |k: usize| c[k].parse::<usize>().map_err(|_| problem());
        rows.push(ScalingRow {
            factor: c[0].parse().map_err(|_| problem())?,
            area_m2: f(1)?,
            trees: u(2)?,
            objects: u(3)?,
            people: u(4)?,
            method: c[5].to_string(),
            sim_seconds: f(6)?,
            wall_seconds: f(7)?,
            simulator_s: f(8)?,
            pipeline_s: f(9)?,
            scans: u(10)?,
            mean_scan_ms: f(11)?,
            landmarks: u(12)?,
            rendered_fraction: f(13)?,
        });
    }
    Ok(rows)
}

/// Writes `scaling.csv` (one row per run) and `scaling.png` (each stage's cost against the
/// tree count) in `dir`.
pub fn write(rows: &[ScalingRow], dir: &Path) -> Result<(), crate::plot::PlotError> {
    let io = |e: std::io::Error| crate::plot::PlotError { file: dir.to_path_buf(), message: e.to_string() };
    std::fs::create_dir_all(dir).map_err(io)?;
    let mut csv = String::from(
        "factor,area_m2,trees,objects,people,method,sim_seconds,wall_seconds,simulator_s,pipeline_s,scans,mean_scan_ms,landmarks,rendered_fraction\n",
    );
    for r in rows {
        csv.push_str(&format!(
            "{},{:.1},{},{},{},{},{:.2},{:.3},{:.3},{:.3},{},{:.3},{},{:.3}\n",
            r.factor,
            r.area_m2,
            r.trees,
            r.objects,
            r.people,
            r.method,
            r.sim_seconds,
            r.wall_seconds,
            r.simulator_s,
            r.pipeline_s,
            r.scans,
            r.mean_scan_ms,
            r.landmarks,
            r.rendered_fraction
        ));
    }
    std::fs::write(dir.join("scaling.csv"), csv).map_err(io)?;
    crate::plot::cost_plot(
        "Cost against world size (a park of paper_park's density, 1x to 10x)",
        "trees in the world",
        "ms spent per simulated second (1,000: real time)",
        &stage_costs(rows),
        &dir.join("scaling.png"),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaled_parks_grow_with_the_factor_and_stage_costs_pair_the_runs() {
        let one = scaled_park(1).unwrap();
        let ten = scaled_park(10).unwrap();
        let (p1, p10) = (one.world.params.unwrap(), ten.world.params.unwrap());
        assert_eq!((p10.trees, p10.posts, p10.palms, p10.people), (120, 40, 10, 30));
        assert_eq!(p10.area_m2, 10.0 * p1.area_m2);
        let row = |factor, method: &str, simulator_s, pipeline_s| ScalingRow {
            factor,
            area_m2: 0.0,
            trees: 12 * factor as usize,
            objects: 0,
            people: 0,
            method: method.into(),
            sim_seconds: 100.0,
            wall_seconds: 0.0,
            simulator_s,
            pipeline_s,
            scans: 0,
            mean_scan_ms: 0.0,
            landmarks: 0,
            rendered_fraction: 0.0,
        };
        // Paired by size, not by position; drawn in order of size.
        let rows = [row(2, "jcbb", 2.0, 4.0), row(1, "jcbb", 1.0, 2.0), row(1, "combined", 5.0, 3.0)];
        let costs = stage_costs(&rows);
        assert_eq!(costs[0].1, vec![(12.0, 10.0), (24.0, 20.0)]);
        assert_eq!(costs[2].1, vec![(12.0, 20.0), (24.0, 40.0)]);
        // Rendering and the combined pipeline only where both methods ran.
        assert_eq!(costs[1].1, vec![(12.0, 40.0)]);
        assert_eq!(costs[3].1, vec![(12.0, 30.0)]);
        // What is written reads back.
        let dir = std::env::temp_dir().join(format!("objslam-scaling-{}", std::process::id()));
        write(&rows, &dir).unwrap();
        let back = read_csv(&dir.join("scaling.csv")).unwrap();
        assert_eq!(stage_costs(&back), costs);
        assert!(dir.join("scaling.png").exists());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
