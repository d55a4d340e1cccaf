//! The generalisation benchmark (`objslam montecarlo generalisation`): the paper's claim on
//! park worlds nobody tuned on, with appearance models of several training seeds.
//!
//! Each world is `paper_park` with its world replaced by a draw from a distribution much
//! wider than the `park` generator's defaults ([`world_params`]). The draws of the `tune`
//! and `test` splits come from disjoint seeds: settings are chosen on `tune` and reported on
//! `test`. `combined` runs once on every world with each of [`TRAINING_SEEDS`], and `jcbb`,
//! which uses no appearance, once on every world for reference. Both are ordinary studies
//! (`DIR/combined`, `DIR/jcbb`): resumable, shardable and mergeable.
//!
//! The claim for one run: no false landmark, no wrong association, no duplicate, and a
//! tree recall (of the trees in the camera's view, from ground truth) of at least 0.95.

use std::collections::BTreeMap;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use worlds::generate::ParkParams;

use super::{RunRecord, StudyError, StudyPlan, Vary};
use crate::scenario::Scenario;
use crate::score::wilson_interval;

/// Appearance training seeds every world is crossed with.
pub const TRAINING_SEEDS: [u64; 5] = [1, 2, 3, 4, 5];

/// The scenario the benchmark's runs start from (its world is replaced by each draw).
pub const BASE_SCENARIO: &str = "paper_park";

/// Tree recall a run needs for the claim to hold.
pub const CLAIM_MIN_TREE_RECALL: f64 = 0.95;

/// Which world draws: tuning and reporting use disjoint seeds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    Tune,
    Test,
}

impl Split {
    pub fn name(self) -> &'static str {
        match self {
            Split::Tune => "tune",
            Split::Test => "test",
        }
    }

    /// The study parameter whose value is a world's index in this split.
    pub fn world_param(self) -> &'static str {
        match self {
            Split::Tune => "generalisation.tune_world",
            Split::Test => "generalisation.test_world",
        }
    }

    /// The split whose world parameter `param` is, if it is one.
    pub fn of_param(param: &str) -> Option<Split> {
        [Split::Tune, Split::Test].into_iter().find(|s| s.world_param() == param)
    }
}

/// Seed of world `index` of `split`: the layout generator's seed, from which its
/// parameters are drawn too. Derived from the split's name, so the splits never share one;
/// 63 bits, so a scenario file (TOML integers are signed) can hold it.
pub fn world_seed(split: Split, index: usize) -> u64 {
    sim::derive_seed(0x6e6e_7261_6c69_7365, &format!("generalisation-{}-world-{index}", split.name()))
        & (i64::MAX as u64)
}

/// Draws of parameters tried for one world before giving up (a draw fails when the
/// generator cannot place all its objects).
const DRAW_ATTEMPTS: usize = 64;

/// The generator parameters of world `index` of `split`. Per world, drawn uniformly:
/// - ground area 300-2,000 m², aspect 1.2-2;
/// - trees: 12 per 600 m² (the paper's density) times 0.6-1.3, at least 4; trunk radius a
///   range of width 0.02-0.15 m starting at 0.08-0.35 m (within 0.08-0.5); height a range of
///   width 0.5-3 m from 3-9 m (within 3-12); canopy radius a range of width 0.2-1 m from
///   0.8-2.2 m;
/// - look-alike posts: 0.2-0.6 per tree; height a range of width 0.1-1 m from 0.8-3.5 m
///   (within 0.8-4); radius width 0.01-0.1 m from 0.05-0.3 m (within 0.05-0.35); distance
///   from their tree width 0.1-1 m from 0.3-2.5 m (within 0.3-3);
/// - palms 0-4; a wall with probability 0.7; people 0-16, starting their walks within the
///   first 30-200 s.
///
/// A draw the generator cannot lay out is drawn again from the same stream, so every index
/// names one valid world.
pub fn world_params(split: Split, index: usize) -> Result<ParkParams, StudyError> {
    params_of_seed(world_seed(split, index)).ok_or_else(|| StudyError::Job {
        key: format!("{}={index}", split.world_param()),
        message: format!("no layout of {DRAW_ATTEMPTS} parameter draws fits its ground"),
    })
}

/// The parameters of the world of layout seed `seed` drawn from the benchmark's
/// distribution ([`world_params`]); `None` where no draw fits its ground.
fn params_of_seed(seed: u64) -> Option<ParkParams> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x9e37_79b9_7f4a_7c15);
    (0..DRAW_ATTEMPTS).map(|_| draw(&mut rng)).find(|p| worlds::generate::park(p, seed).is_ok())
}

/// Training world `index` of the worlds drawn from `base_seed` (an appearance source's
/// `training_world_seed`): a park from the same distribution as the benchmark's worlds
/// ([`world_params`]), as (layout seed, parameters). Its seeds are derived under another
/// name than the splits', so no training world is a `tune` or `test` world: a model
/// trained on them meets the benchmark's worlds unseen. `None` where no draw fits.
pub fn training_world(base_seed: u64, index: usize) -> Option<(u64, ParkParams)> {
    let seed = sim::derive_seed(base_seed, &format!("appearance-training-world-{index}")) & (i64::MAX as u64);
    params_of_seed(seed).map(|p| (seed, p))
}

/// A range of width `width` starting at `lo`, capped at `max`.
fn range(lo: f64, width: f64, max: f64) -> [f64; 2] {
    let r3 = |v: f64| (v * 1000.0).round() / 1000.0;
    [r3(lo), r3((lo + width).min(max))]
}

fn draw(rng: &mut ChaCha8Rng) -> ParkParams {
    let mut u = |lo: f64, hi: f64| rng.random_range(lo..hi);
    let area_m2 = (u(300.0, 2000.0)).round();
    let aspect = u(1.2, 2.0);
    let trees = ((area_m2 / 600.0 * 12.0 * u(0.6, 1.3)).round() as usize).max(4);
    let tree_radius_m = range(u(0.08, 0.35), u(0.02, 0.15), 0.5);
    let tree_height_m = range(u(3.0, 9.0), u(0.5, 3.0), 12.0);
    let canopy_radius_m = range(u(0.8, 2.2), u(0.2, 1.0), 3.2);
    let posts = (trees as f64 * u(0.2, 0.6)).round() as usize;
    let post_height_m = range(u(0.8, 3.5), u(0.1, 1.0), 4.0);
    let post_radius_m = range(u(0.05, 0.3), u(0.01, 0.1), 0.35);
    let post_distance_m = range(u(0.3, 2.5), u(0.1, 1.0), 3.0);
    let person_start_time_max_s = u(30.0, 200.0).round();
    let palms = rng.random_range(0..=4usize);
    let wall = rng.random_bool(0.7);
    let people = rng.random_range(0..=16usize);
    ParkParams {
        area_m2,
        aspect: (aspect * 100.0).round() / 100.0,
        trees,
        tree_radius_m,
        tree_height_m,
        canopy_radius_m,
        posts,
        post_height_m,
        post_radius_m,
        post_distance_m,
        palms,
        wall,
        people,
        person_start_time_max_s,
        ..ParkParams::default()
    }
}

/// `scenario` with its world replaced by world `index` of `split`.
pub fn with_world(scenario: &Scenario, split: Split, index: f64) -> Result<Scenario, StudyError> {
    if !(index >= 0.0 && index.fract() == 0.0 && index < 1e9) {
        return Err(StudyError::VaryValue {
            spec: format!("{}={index}", split.world_param()),
            message: "a world index is a whole number from 0".into(),
        });
    }
    let index = index as usize;
    let mut s = scenario.clone();
    s.world.preset = Some("park".into());
    s.world.file = None;
    s.world.seed = Some(world_seed(split, index));
    s.world.params = Some(world_params(split, index)?);
    s.name = format!("{}-{}-world-{index}", scenario.name, split.name());
    Ok(s)
}

/// The benchmark's two studies, as (name, plan): `combined` on `worlds` worlds of `split`
/// crossed with the training seeds, and `jcbb` on the same worlds. Refuses a count of
/// worlds no study could hold before making its values.
pub fn plans(split: Split, worlds: usize, base_seed: u64) -> Result<Vec<(&'static str, StudyPlan)>, StudyError> {
    if worlds == 0 {
        return Err(StudyError::Plan("--runs must be at least 1 world".into()));
    }
    if worlds.checked_mul(TRAINING_SEEDS.len()).is_none_or(|jobs| jobs > super::MAX_JOBS) {
        return Err(StudyError::Plan(format!(
            "{worlds} worlds x {} training seeds: more than {} runs planned; split the study",
            TRAINING_SEEDS.len(),
            super::MAX_JOBS
        )));
    }
    let world = Vary { param: split.world_param().into(), values: (0..worlds).map(|i| i as f64).collect() };
    let training =
        Vary { param: "appearance.training_seed".into(), values: TRAINING_SEEDS.iter().map(|&s| s as f64).collect() };
    let plan = |method: &str, vary: Vec<Vary>| StudyPlan {
        scenario: BASE_SCENARIO.into(),
        base_seed,
        runs: 1,
        methods: vec![method.into()],
        vary,
    };
    Ok(vec![("combined", plan("combined", vec![world.clone(), training])), ("jcbb", plan("jcbb", vec![world]))])
}

/// A count of runs out of `runs`, with its rate and 95% Wilson interval.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Proportion {
    pub count: usize,
    pub runs: usize,
    /// `count / runs`; null without runs.
    pub rate: Option<f64>,
    pub ci95: (f64, f64),
}

impl Proportion {
    fn of(count: usize, runs: usize) -> Self {
        Proportion {
            count,
            runs,
            rate: (runs > 0).then(|| count as f64 / runs as f64),
            ci95: wilson_interval(count, runs, 1.96),
        }
    }
}

/// Landmarks on things that are not trees, summed over runs.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FalseByClass {
    pub posts: usize,
    pub palms: usize,
    pub people: usize,
    pub walls: usize,
    pub nothing: usize,
}

/// One method's results over all its runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MethodTotals {
    pub runs: usize,
    /// Runs that ended in an error (not counted in anything else).
    pub errors: usize,
    /// Trees mapped of the trees in view, summed over runs (camera methods only).
    pub recall_in_view: Option<f64>,
    /// Trees mapped of the trees the laser saw, summed over runs.
    pub recall_laser_seen: Option<f64>,
    pub false_landmarks: FalseByClass,
    pub runs_with_false_landmarks: Proportion,
    pub runs_with_wrong_associations: Proportion,
    pub wrong_associations: usize,
    pub associations: usize,
    pub runs_with_duplicates: Proportion,
    pub duplicates: usize,
    /// Camera methods: the missed trees of all runs by the last stage of the pipeline
    /// each reached (`map.missed_by_stage`), where the recall is lost.
    #[serde(default)]
    pub missed_by_stage: Option<BTreeMap<String, usize>>,
}

/// What `DIR/summary.json` holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GeneralisationReport {
    pub split: Split,
    pub worlds: usize,
    pub training_seeds: Vec<u64>,
    /// `combined` runs where the claim holds, of those with trees to map.
    pub claim: Proportion,
    /// `combined` runs with no tree in view, where the claim is undefined.
    pub claim_undefined: usize,
    /// The claim per training seed: its spread over trained models.
    pub claim_by_training_seed: Vec<(u64, Proportion)>,
    pub combined: MethodTotals,
    pub jcbb: MethodTotals,
}

/// Whether the claim holds on one run; `None` when it had no tree in view.
pub fn claim_holds(m: &crate::run::Metrics) -> Option<bool> {
    let recall = m.map.tree_recall?;
    Some(
        m.false_landmarks == 0
            && m.associations.wrong == 0
            && m.duplicate_landmarks == 0
            && recall >= CLAIM_MIN_TREE_RECALL,
    )
}

fn totals(records: &[RunRecord]) -> MethodTotals {
    let metrics: Vec<&crate::run::Metrics> = records.iter().filter_map(|r| r.metrics.as_ref()).collect();
    let runs = metrics.len();
    let ratio = |num: usize, den: usize| (den > 0).then(|| num as f64 / den as f64);
    // Camera methods name their missed trees among those in view, the others among those the
    // laser saw; a landmark's tree was always seen by the laser.
    let (mut in_view, mut in_view_mapped, mut laser, mut laser_mapped) = (0, 0, 0, 0);
    let mut false_landmarks = FalseByClass::default();
    for m in &metrics {
        match m.recall_basis() {
            // Whether or not the run counted its trees in view, its laser-seen recall is what
            // it mapped: its missed trees are named among those in view, not those seen.
            crate::score::scorer::RecallBasis::InView => {
                if let Some(n) = m.map.trees_in_view {
                    in_view += n;
                    in_view_mapped += n.saturating_sub(m.map.missed_trees.len());
                }
                laser_mapped += m.map.trees_mapped.min(m.map.trees_laser_seen);
            }
            _ => laser_mapped += m.map.trees_laser_seen.saturating_sub(m.map.missed_trees.len()),
        }
        laser += m.map.trees_laser_seen;
        false_landmarks.posts += m.map.posts;
        false_landmarks.palms += m.map.palms;
        false_landmarks.people += m.map.people;
        false_landmarks.walls += m.map.walls;
        false_landmarks.nothing += m.map.nothing;
    }
    let with = |f: &dyn Fn(&crate::run::Metrics) -> bool| Proportion::of(metrics.iter().filter(|m| f(m)).count(), runs);
    MethodTotals {
        runs,
        errors: records.len() - runs,
        recall_in_view: ratio(in_view_mapped, in_view),
        recall_laser_seen: ratio(laser_mapped, laser),
        false_landmarks,
        runs_with_false_landmarks: with(&|m| m.false_landmarks > 0),
        runs_with_wrong_associations: with(&|m| m.associations.wrong > 0),
        wrong_associations: metrics.iter().map(|m| m.associations.wrong).sum(),
        associations: metrics.iter().map(|m| m.associations.total).sum(),
        runs_with_duplicates: with(&|m| m.duplicate_landmarks > 0),
        duplicates: metrics.iter().map(|m| m.duplicate_landmarks).sum(),
        missed_by_stage: metrics.iter().filter_map(|m| m.map.missed_by_stage.as_ref()).fold(None, |sum, by_stage| {
            let mut sum: BTreeMap<String, usize> = sum.unwrap_or_default();
            for (stage, ids) in by_stage {
                *sum.entry(stage.clone()).or_default() += ids.len();
            }
            Some(sum)
        }),
    }
}

/// The training seed a record's run used (a parameter of the `combined` study).
fn training_seed(r: &RunRecord) -> Option<u64> {
    r.job.params.iter().find(|(p, _)| p == "appearance.training_seed").map(|(_, v)| *v as u64)
}

/// The benchmark's report from the records of its two studies.
pub fn report(split: Split, worlds: usize, combined: &[RunRecord], jcbb: &[RunRecord]) -> GeneralisationReport {
    let claim_of = |records: &[&RunRecord]| {
        let outcomes: Vec<bool> = records.iter().filter_map(|r| r.metrics.as_ref()).filter_map(claim_holds).collect();
        Proportion::of(outcomes.iter().filter(|&&h| h).count(), outcomes.len())
    };
    let all: Vec<&RunRecord> = combined.iter().collect();
    let claim = claim_of(&all);
    let scored = combined.iter().filter(|r| r.metrics.is_some()).count();
    let claim_by_training_seed = TRAINING_SEEDS
        .iter()
        .map(|&s| {
            let of_seed: Vec<&RunRecord> = combined.iter().filter(|r| training_seed(r) == Some(s)).collect();
            (s, claim_of(&of_seed))
        })
        .collect();
    GeneralisationReport {
        split,
        worlds,
        training_seeds: TRAINING_SEEDS.to_vec(),
        claim_undefined: scored - claim.runs,
        claim,
        claim_by_training_seed,
        combined: totals(combined),
        jcbb: totals(jcbb),
    }
}

/// The report in words, as `objslam montecarlo generalisation` prints it.
pub fn report_text(r: &GeneralisationReport) -> String {
    let pct = |p: &Proportion| match p.rate {
        Some(rate) => format!(
            "{:.0}% ({} of {}; 95% CI {:.0}-{:.0}%)",
            100.0 * rate,
            p.count,
            p.runs,
            100.0 * p.ci95.0,
            100.0 * p.ci95.1
        ),
        None => "no runs".into(),
    };
    let share = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{:.3}", v));
    let mut out = format!(
        "generalisation, {} split: {} worlds x {} training seeds\n  claim holds      {}\n",
        r.split.name(),
        r.worlds,
        r.training_seeds.len(),
        pct(&r.claim)
    );
    if r.claim_undefined > 0 {
        out += &format!("                   ({} runs had no tree in view and are not counted)\n", r.claim_undefined);
    }
    if r.combined.errors > 0 {
        // Not among the runs the claim counts, held or failed: said here, not only below.
        out += &format!(
            "                   ({} combined runs ended in an error and are not counted; their errors are in combined/runs.jsonl)\n",
            r.combined.errors
        );
    }
    let by_seed: Vec<String> = r
        .claim_by_training_seed
        .iter()
        .map(|(s, p)| format!("{s}: {}", p.rate.map_or("-".into(), |v| format!("{:.0}%", 100.0 * v))))
        .collect();
    out += &format!("  by training seed {}\n", by_seed.join(", "));
    for (name, t) in [("combined", &r.combined), ("jcbb", &r.jcbb)] {
        let f = &t.false_landmarks;
        out += &format!(
            "  {name:<9} {} runs ({} errors): tree recall {} of trees in view, {} of trees laser-seen; false landmarks posts {} palms {} people {} walls {} nothing {} (runs with any: {}); wrong associations {} of {} (runs with any: {}); duplicates {} (runs with any: {})\n",
            t.runs,
            t.errors,
            share(t.recall_in_view),
            share(t.recall_laser_seen),
            f.posts,
            f.palms,
            f.people,
            f.walls,
            f.nothing,
            pct(&t.runs_with_false_landmarks),
            t.wrong_associations,
            t.associations,
            pct(&t.runs_with_wrong_associations),
            t.duplicates,
            pct(&t.runs_with_duplicates),
        );
        if let Some(by_stage) = &t.missed_by_stage {
            let stages: Vec<String> = crate::score::segmentation::MissedStage::ALL
                .iter()
                .map(|stage| {
                    let n = by_stage.get(stage.key()).copied().unwrap_or(0);
                    format!("{} {n}", stage.in_words())
                })
                .collect();
            out += &format!("  {:<9} trees missed, by the last stage reached: {}\n", "", stages.join(", "));
        }
    }
    out
}

/// One point of the benchmark's plot: a run's world, training seed (none for `jcbb`),
/// tree recall, and whether the claim held.
#[derive(Debug, Clone, PartialEq)]
pub struct RecallPoint {
    pub world: usize,
    pub training_seed: Option<u64>,
    pub recall: f64,
    pub claim: bool,
}

/// The plot's points from the records of one study.
pub fn recall_points(split: Split, records: &[RunRecord]) -> Vec<RecallPoint> {
    records
        .iter()
        .filter_map(|r| {
            let m = r.metrics.as_ref()?;
            let world = r.job.params.iter().find(|(p, _)| p == split.world_param())?.1 as usize;
            Some(RecallPoint {
                world,
                training_seed: training_seed(r),
                recall: m.map.tree_recall?,
                claim: claim_holds(m) == Some(true),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splits_draw_disjoint_valid_worlds_within_the_documented_ranges() {
        let tune: std::collections::BTreeSet<u64> = (0..2000).map(|i| world_seed(Split::Tune, i)).collect();
        let test: std::collections::BTreeSet<u64> = (0..2000).map(|i| world_seed(Split::Test, i)).collect();
        assert_eq!(tune.len(), 2000);
        assert!(tune.is_disjoint(&test), "a world seed in both splits");
        for split in [Split::Tune, Split::Test] {
            for i in 0..16 {
                let p = world_params(split, i).unwrap();
                assert_eq!(p, world_params(split, i).unwrap(), "a draw is a function of split and index");
                let world = worlds::generate::park(&p, world_seed(split, i)).unwrap();
                let problems = worlds::validate::validate(&world, std::path::Path::new("."));
                assert!(problems.is_empty(), "{} world {i}: {problems:?}", split.name());
                assert!((300.0..=2000.0).contains(&p.area_m2), "{p:?}");
                assert!(p.tree_radius_m[0] >= 0.08 && p.tree_radius_m[1] <= 0.5, "{p:?}");
                assert!(p.tree_height_m[0] >= 3.0 && p.tree_height_m[1] <= 12.0, "{p:?}");
                assert!(p.post_height_m[0] >= 0.8 && p.post_height_m[1] <= 4.0, "{p:?}");
                assert!(p.post_radius_m[0] >= 0.05 && p.post_radius_m[1] <= 0.35, "{p:?}");
                assert!(p.post_distance_m[0] >= 0.3 && p.post_distance_m[1] <= 3.0, "{p:?}");
                assert!(p.palms <= 4 && p.people <= 16 && p.trees >= 4, "{p:?}");
            }
        }
        // Wider than the defaults: some worlds have posts taller than any default tree band
        // and trunks thinner than the default's thinnest.
        let draws: Vec<ParkParams> = (0..40).map(|i| world_params(Split::Tune, i).unwrap()).collect();
        assert!(draws.iter().any(|p| p.post_height_m[1] > 3.0));
        assert!(draws.iter().any(|p| p.tree_radius_m[0] < 0.1));
        assert!(draws.iter().any(|p| p.area_m2 > 1500.0) && draws.iter().any(|p| p.area_m2 < 600.0));
    }

    #[test]
    fn plans_cross_combined_with_the_training_seeds_and_run_jcbb_once_a_world() {
        let plans = plans(Split::Test, 3, 7).unwrap();
        assert_eq!(plans.len(), 2);
        let (combined, jcbb) = (&plans[0].1, &plans[1].1);
        assert_eq!(super::super::jobs(combined).len(), 3 * TRAINING_SEEDS.len());
        assert_eq!(super::super::jobs(jcbb).len(), 3);
        let (base, _) = Scenario::load(BASE_SCENARIO).unwrap();
        for job in super::super::jobs(combined).iter().chain(&super::super::jobs(jcbb)) {
            let s = super::super::job_scenario(&base, job).unwrap();
            let index = job.params[0].1 as usize;
            assert_eq!(s.world.seed, Some(world_seed(Split::Test, index)));
            assert_eq!(s.world.params, Some(world_params(Split::Test, index).unwrap()));
            if let Some(seed) = job.params.get(1) {
                assert_eq!(s.appearance.training_seed, seed.1 as u64);
            }
        }
        let e = super::super::apply_param(&base, Split::Tune.world_param(), 1.5).unwrap_err().to_string();
        assert!(e.contains("whole number"), "{e}");
        // Counts no study could hold are refused before any value is made.
        for worlds in [0, 1_000_000_000, usize::MAX] {
            let e = super::plans(Split::Test, worlds, 7).unwrap_err().to_string();
            assert!(e.contains("at least 1 world") || e.contains("more than 1000000 runs"), "{worlds}: {e}");
        }
    }

    fn record(world: usize, seed: Option<u64>, f: impl Fn(&mut crate::run::Metrics)) -> RunRecord {
        let mut params = vec![(Split::Test.world_param().to_string(), world as f64)];
        if let Some(s) = seed {
            params.push(("appearance.training_seed".into(), s as f64));
        }
        let job = super::super::Job { index: 0, method: "combined".into(), params, run: 0, seed: 1 };
        let mut m: crate::run::Metrics = serde_json::from_str(include_str!("../../tests/data/metrics_sample.json"))
            .expect("the sample metrics parse");
        f(&mut m);
        RunRecord { key: job.key(), job, metrics: Some(m), error: None, retryable: false, build: None }
    }

    #[test]
    fn the_report_counts_the_claim_recall_and_failures_from_ground_truth_terms() {
        let good = |m: &mut crate::run::Metrics| {
            m.map.trees_in_view = Some(10);
            m.map.trees_laser_seen = 12;
            m.map.trees_mapped = 10;
            m.map.missed_trees = vec![];
            m.map.tree_recall = Some(1.0);
            m.false_landmarks = 0;
            m.map.posts = 0;
            m.associations.wrong = 0;
            m.duplicate_landmarks = 0;
        };
        let combined = vec![
            record(0, Some(1), good),
            record(0, Some(2), |m| {
                good(m);
                m.map.missed_trees = vec![3, 4];
                m.map.missed_by_stage =
                    Some([("never_segmented".into(), vec![3]), ("judged_not_a_tree".into(), vec![4])].into());
                m.map.trees_mapped = 8;
                m.map.tree_recall = Some(0.8);
            }),
            record(1, Some(1), |m| {
                good(m);
                m.false_landmarks = 1;
                m.map.posts = 1;
            }),
            record(1, Some(2), |m| {
                good(m);
                m.map.trees_in_view = Some(0);
                m.map.tree_recall = None;
            }),
        ];
        // A position-only run with a camera names its missed trees among those the laser
        // saw: its trees in view do not make an in-view recall.
        let jcbb = vec![record(0, None, |m| {
            good(m);
            m.method = "jcbb".into();
            m.map.missed_trees = vec![5];
            m.map.trees_mapped = 11;
        })];
        let r = report(Split::Test, 2, &combined, &jcbb);
        assert_eq!((r.jcbb.recall_in_view, r.jcbb.recall_laser_seen), (None, Some(11.0 / 12.0)));
        assert_eq!((r.claim.count, r.claim.runs, r.claim_undefined), (1, 3, 1));
        let (lo, hi) = r.claim.ci95;
        assert!(lo < 1.0 / 3.0 && 1.0 / 3.0 < hi);
        assert_eq!(r.claim_by_training_seed[0], (1, Proportion::of(1, 2)));
        assert_eq!(r.claim_by_training_seed[1], (2, Proportion::of(0, 1)));
        // 10 + 8 + 10 + 0 mapped of 10 + 10 + 10 + 0 in view; 38 of 48 laser-seen.
        assert_eq!(r.combined.recall_in_view, Some(28.0 / 30.0));
        assert_eq!(r.combined.recall_laser_seen, Some(38.0 / 48.0));
        assert_eq!(r.combined.false_landmarks.posts, 1);
        assert_eq!(r.combined.runs_with_false_landmarks, Proportion::of(1, 4));
        assert_eq!(r.jcbb.runs, 1);
        // Where the recall was lost, summed over the runs that name it.
        let stages = r.combined.missed_by_stage.as_ref().expect("a camera run names its stages");
        assert_eq!((stages["never_segmented"], stages["judged_not_a_tree"], stages.len()), (1, 1, 2));
        assert_eq!(r.jcbb.missed_by_stage, None);
        let text = report_text(&r);
        assert!(text.contains("never segmented 1, never fully judged 0"), "{text}");
        assert!(!text.contains("ended in an error"), "{text}");

        // An errored run is named beside the claim it is left out of.
        let mut errored = combined.clone();
        errored.push(RunRecord { metrics: None, error: Some("boom".into()), ..record(2, Some(1), good) });
        let r = report(Split::Test, 3, &errored, &jcbb);
        assert_eq!((r.claim.runs, r.combined.errors), (3, 1));
        let text = report_text(&r);
        assert!(text.contains("(1 combined runs ended in an error and are not counted"), "{text}");

        // A camera run that counted no trees in view (null) still mapped only what it
        // mapped of the trees the laser saw: none of its 12 is credited.
        let mut uncounted = combined.clone();
        uncounted.push(record(2, Some(1), |m| {
            good(m);
            m.map.trees_in_view = None;
            m.map.tree_recall = None;
            m.map.trees_mapped = 0;
        }));
        let r = report(Split::Test, 3, &uncounted, &jcbb);
        assert_eq!(r.combined.recall_in_view, Some(28.0 / 30.0));
        assert_eq!(r.combined.recall_laser_seen, Some(38.0 / 60.0));
    }
}
