//! Scoring against ground truth: trajectory error, landmark error after optimal
//! assignment, map content per class, wrong associations, duplicates, NEES.

pub mod estimate;
pub mod log;
pub mod scorer;
pub mod segmentation;

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// Root-mean-square of the position differences of time-aligned pose pairs (ATE without
/// alignment: both trajectories live in the world frame, starting from the same pose).
pub fn ate_rmse(estimate: &[[f64; 2]], truth: &[[f64; 2]]) -> f64 {
    let n = estimate.len().min(truth.len());
    if n == 0 {
        return f64::NAN;
    }
    let s: f64 = (0..n).map(|i| (estimate[i][0] - truth[i][0]).powi(2) + (estimate[i][1] - truth[i][1]).powi(2)).sum();
    (s / n as f64).sqrt()
}

/// The largest cost magnitude [`hungarian`] works with: larger ones count as it, so that the
/// potentials (sums of costs) stay finite.
const MAX_ASSIGNMENT_COST: f64 = 1e100;

/// Minimum-cost assignment of rows to columns (rows <= columns or not; unassigned rows get
/// `None`), by the Hungarian algorithm (Kuhn-Munkres with potentials). It runs on the
/// shorter side, in O(short^2 * long): a score's few landmarks against a large world's
/// thousands of objects cost what the landmarks need, not the cube of the objects (padding
/// the problem square did). A non-finite cost (a distance that overflowed) counts as the
/// large cost of a dummy cell, and one beyond ±[`MAX_ASSIGNMENT_COST`] as that bound: with
/// an infinite or NaN potential no column would ever be found and the search would not end.
pub fn hungarian(cost: &[Vec<f64>]) -> Vec<Option<usize>> {
    let rows = cost.len();
    if rows == 0 {
        return vec![];
    }
    let cols = cost[0].len();
    if cols == 0 {
        return vec![None; rows];
    }
    let bounded = |c: f64| c.is_finite().then(|| c.clamp(-MAX_ASSIGNMENT_COST, MAX_ASSIGNMENT_COST));
    let big = cost.iter().flatten().filter_map(|&c| bounded(c)).fold(0.0f64, |m, c| m.max(c.abs())) * 10.0 + 1.0;
    let c = |i: usize, j: usize| cost[i].get(j).and_then(|&c| bounded(c)).unwrap_or(big);
    let mut result = vec![None; rows];
    if rows <= cols {
        for (i, j) in assign_short_side(rows, cols, c).into_iter().enumerate() {
            result[i] = Some(j);
        }
    } else {
        for (j, i) in assign_short_side(cols, rows, |j, i| c(i, j)).into_iter().enumerate() {
            result[i] = Some(j);
        }
    }
    result
}

/// The column of each of `n` rows in a minimum-cost assignment to `m >= n` columns.
fn assign_short_side(n: usize, m: usize, c: impl Fn(usize, usize) -> f64) -> Vec<usize> {
    // Potentials formulation with 1-based indices (row 0 / column 0 are sentinels).
    let mut u = vec![0.0; n + 1];
    let mut v = vec![0.0; m + 1];
    let mut p = vec![0usize; m + 1];
    let mut way = vec![0usize; m + 1];
    let mut minv = vec![f64::INFINITY; m + 1];
    let mut used = vec![false; m + 1];
    for i in 1..=n {
        p[0] = i;
        let mut j0 = 0;
        minv.fill(f64::INFINITY);
        used.fill(false);
        loop {
            used[j0] = true;
            let i0 = p[j0];
            let mut delta = f64::INFINITY;
            let mut j1 = 0;
            for j in 1..=m {
                if !used[j] {
                    let cur = c(i0 - 1, j - 1) - u[i0] - v[j];
                    if cur < minv[j] {
                        minv[j] = cur;
                        way[j] = j0;
                    }
                    if minv[j] < delta {
                        delta = minv[j];
                        j1 = j;
                    }
                }
            }
            for j in 0..=m {
                if used[j] {
                    u[p[j]] += delta;
                    v[j] -= delta;
                } else {
                    minv[j] -= delta;
                }
            }
            j0 = j1;
            if p[j0] == 0 {
                break;
            }
        }
        loop {
            let j1 = way[j0];
            p[j0] = p[j1];
            j0 = j1;
            if j0 == 0 {
                break;
            }
        }
    }
    let mut column = vec![0; n];
    for (j, &i) in p.iter().enumerate().skip(1) {
        if i >= 1 {
            column[i - 1] = j - 1;
        }
    }
    column
}

/// Counts of mapped landmarks by the class of the object they truly belong to, and the
/// trees there were to map (denominators from ground truth: see `crate::visibility`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MapContent {
    /// Trees the laser hit with enough beams within the clustering range, at scans whose
    /// camera frame of the same instant shows the tree at those beams' pixels, in enough
    /// scans to confirm a landmark; `None` for runs without a camera.
    #[serde(default)]
    pub trees_in_view: Option<usize>,
    /// Trees the laser hit with enough beams within the clustering range at some scan.
    #[serde(default)]
    pub trees_laser_seen: usize,
    /// Camera methods: trees whose cluster the method's own segmentation judged in enough
    /// frames. It depends on the method, so it explains misses and is no denominator.
    #[serde(default)]
    pub trees_judged: Option<usize>,
    /// Share of the trees in view mapped for camera methods, of the trees seen by the laser
    /// for the others; `None` when there was no tree to map.
    #[serde(default)]
    pub tree_recall: Option<f64>,
    /// Distinct trees with at least one landmark on them.
    pub trees_mapped: usize,
    /// Ids of the trees in the recall's denominator that carry no landmark: where to look.
    #[serde(default)]
    pub missed_trees: Vec<u16>,
    /// Camera methods: `missed_trees` by the last stage of the method's pipeline each
    /// reached (`never_segmented`, `never_fully_judged`, `judged_too_rarely`,
    /// `judged_not_a_tree`, `observed_not_mapped`; see
    /// [`segmentation::MissedStage`]). Explains the recall lost; `None` for others.
    #[serde(default)]
    pub missed_by_stage: Option<BTreeMap<String, Vec<u16>>>,
    pub posts: usize,
    pub palms: usize,
    pub people: usize,
    pub walls: usize,
    /// Landmarks on nothing at all (spurious), or on no single object: none has a
    /// majority of their observations.
    pub nothing: usize,
}

impl MapContent {
    /// The recall's terms on `basis`, the one it was computed on (`missed_trees` names trees
    /// of that basis), e.g. "8 of 10 trees in view mapped; 12 seen by the laser".
    pub fn recall_in_words(&self, basis: scorer::RecallBasis) -> String {
        // Saturating: counts read back from a metrics.json need not agree.
        let missed = self.missed_trees.len();
        match (basis, self.trees_in_view) {
            (scorer::RecallBasis::InView, Some(n)) => format!(
                "{} of {n} trees in view mapped; {} seen by the laser",
                n.saturating_sub(missed),
                self.trees_laser_seen
            ),
            (scorer::RecallBasis::InView, None) => {
                format!("no trees in view counted (no camera); {} seen by the laser", self.trees_laser_seen)
            }
            (scorer::RecallBasis::LaserSeen, _) => format!(
                "{} of {} trees seen by the laser mapped",
                self.trees_laser_seen.saturating_sub(missed),
                self.trees_laser_seen
            ),
        }
    }
}

/// Share of the trees there were to map that were mapped (a mapped tree outside that set
/// adds nothing: recall never exceeds 1); undefined (`None`) without a denominator or with
/// none to map, so that a criterion cannot pass on a run that had nothing to find.
pub fn tree_recall(
    mapped: &std::collections::BTreeSet<u16>,
    to_map: Option<&std::collections::BTreeSet<u16>>,
) -> Option<f64> {
    to_map.filter(|t| !t.is_empty()).map(|t| t.intersection(mapped).count() as f64 / t.len() as f64)
}

#[cfg(test)]
mod recall_tests {
    use super::*;

    #[test]
    fn recall_counts_only_trees_there_were_to_map_and_is_undefined_without_any() {
        let mapped = [1, 2, 9].into();
        assert_eq!(tree_recall(&mapped, Some(&[1, 2, 3, 4].into())), Some(0.5));
        assert_eq!(tree_recall(&mapped, Some(&[1, 2].into())), Some(1.0), "tree 9 was mapped but not there to map");
        assert_eq!(tree_recall(&mapped, Some(&Default::default())), None);
        assert_eq!(tree_recall(&mapped, None), None);
    }

    /// Regression: the words followed whether the run had a camera, not the basis the
    /// recall was computed on, so a laser-seen recall of a camera log was worded as trees
    /// in view, and an empty map wrapped below zero ("18446744073709551614 of 10").
    #[test]
    fn recall_is_worded_on_the_basis_it_was_computed_on() {
        use scorer::RecallBasis::{InView, LaserSeen};
        // An empty map scored on the 12 trees the laser saw, 10 of them in view.
        let map = MapContent {
            trees_in_view: Some(10),
            trees_laser_seen: 12,
            missed_trees: (1..=12).collect(),
            ..Default::default()
        };
        assert_eq!(map.recall_in_words(LaserSeen), "0 of 12 trees seen by the laser mapped");
        // Counts that disagree (an edited metrics.json) give no wrapped figure.
        assert_eq!(map.recall_in_words(InView), "0 of 10 trees in view mapped; 12 seen by the laser");
        let map = MapContent { trees_in_view: Some(10), trees_laser_seen: 12, missed_trees: vec![3, 4], ..map };
        assert_eq!(map.recall_in_words(InView), "8 of 10 trees in view mapped; 12 seen by the laser");
        let map = MapContent { trees_in_view: None, ..map };
        assert_eq!(map.recall_in_words(LaserSeen), "10 of 12 trees seen by the laser mapped");
    }
}

/// Association outcome counts.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct AssociationCounts {
    /// Observations associated with an existing landmark.
    pub total: usize,
    /// Of those, ones whose true object differs from the landmark's object.
    pub wrong: usize,
}

/// Which true object each landmark's observations came from, for scoring associations.
///
/// A fusion (the pipeline finding two landmarks to be one) associates every observation
/// of the removed landmark with the kept one: its earlier associations are relabelled, and
/// the observation that started it becomes one more association, so the total stays the
/// number of observations that did not start a landmark.
#[derive(Debug, Clone, Default)]
pub struct AssociationLedger {
    /// Per landmark, the true object (0: none) of each of its observations.
    observed: std::collections::HashMap<u32, Vec<u16>>,
    /// Associations with an existing landmark: (landmark id, the observation's object).
    associations: Vec<(u32, u16)>,
    /// Fused landmarks: removed id -> kept id.
    fused: std::collections::HashMap<u32, u32>,
}

impl AssociationLedger {
    /// Landmark `landmark` took an observation of `object` (its first starts it).
    pub fn observe(&mut self, landmark: u32, object: u16) {
        let objects = self.observed.entry(landmark).or_default();
        if !objects.is_empty() {
            self.associations.push((landmark, object));
        }
        objects.push(object);
    }

    /// Landmark `removed` was fused into `kept`.
    pub fn fuse(&mut self, kept: u32, removed: u32) {
        let moved = self.observed.remove(&removed).unwrap_or_default();
        for a in &mut self.associations {
            if a.0 == removed {
                a.0 = kept;
            }
        }
        if let Some(&first) = moved.first() {
            self.associations.push((kept, first));
        }
        self.observed.entry(kept).or_default().extend(moved);
        for k in self.fused.values_mut() {
            if *k == removed {
                *k = kept;
            }
        }
        self.fused.insert(removed, kept);
    }

    /// The object each landmark stands on: the object of more than half of its
    /// observations, or none (0) where no object has a majority. A landmark fed a quarter
    /// by one tree and the rest by its neighbours is not that tree's landmark: counted as
    /// on nothing, it is a false landmark and its associations are wrong. A fused landmark
    /// stands on its keeper's.
    pub fn landmark_objects(&self) -> std::collections::HashMap<u32, u16> {
        let mut out: std::collections::HashMap<u32, u16> = self
            .observed
            .iter()
            .map(|(id, objects)| {
                let mut counts: std::collections::BTreeMap<u16, usize> = std::collections::BTreeMap::new();
                for o in objects {
                    *counts.entry(*o).or_default() += 1;
                }
                let majority = counts.into_iter().find(|(_, n)| 2 * n > objects.len()).map_or(0, |(o, _)| o);
                (*id, majority)
            })
            .collect();
        for (removed, kept) in &self.fused {
            if let Some(&o) = out.get(kept) {
                out.insert(*removed, o);
            }
        }
        out
    }

    /// Associations, and those whose observation's object is not the landmark's.
    pub fn counts(&self) -> AssociationCounts {
        let objects = self.landmark_objects();
        AssociationCounts {
            total: self.associations.len(),
            wrong: self.associations.iter().filter(|(id, o)| objects.get(id) != Some(o)).count(),
        }
    }
}

/// Wilson score interval for a binomial proportion (95% for z = 1.96).
pub fn wilson_interval(successes: usize, n: usize, z: f64) -> (f64, f64) {
    if n == 0 {
        return (0.0, 1.0);
    }
    let n_f = n as f64;
    let p = successes as f64 / n_f;
    let denom = 1.0 + z * z / n_f;
    let centre = (p + z * z / (2.0 * n_f)) / denom;
    let half = z * ((p * (1.0 - p) / n_f) + z * z / (4.0 * n_f * n_f)).sqrt() / denom;
    ((centre - half).max(0.0), (centre + half).min(1.0))
}

/// Normalised estimation error squared of a pose error `e` (x, y, theta) with covariance
/// `p` (3x3 row-major); `None` if `p` is not positive definite.
pub fn nees3(e: [f64; 3], p: [[f64; 3]; 3]) -> Option<f64> {
    // Solve P x = e by Cholesky.
    let mut l = [[0.0f64; 3]; 3];
    for i in 0..3 {
        for j in 0..=i {
            let s = p[i][j] - (0..j).map(|k| l[i][k] * l[j][k]).sum::<f64>();
            if i == j {
                if s <= 0.0 {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    let mut y = [0.0; 3];
    for i in 0..3 {
        let mut s = e[i];
        for k in 0..i {
            s -= l[i][k] * y[k];
        }
        y[i] = s / l[i][i];
    }
    Some(y.iter().map(|v| v * v).sum())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: the associations a landmark took before it was fused into another stayed
    /// under its id, which then had no object, so a correct fusion of two landmarks on one
    /// tree counted every one of them wrong (`long_loop`, 36 "wrong" associations).
    #[test]
    fn a_correct_fusion_makes_no_association_wrong() {
        let mut ledger = AssociationLedger::default();
        for _ in 0..4 {
            ledger.observe(8, 7);
        }
        for _ in 0..3 {
            ledger.observe(10, 7);
        }
        ledger.observe(9, 11);
        ledger.fuse(8, 10);
        // Seven observations of tree 7 on one landmark: six associations, none wrong.
        assert_eq!(ledger.counts(), AssociationCounts { total: 6, wrong: 0 });
        let objects = ledger.landmark_objects();
        assert_eq!((objects[&8], objects[&10], objects[&9]), (7, 7, 11));
    }

    #[test]
    fn fusing_two_objects_makes_the_minority_wrong() {
        let mut ledger = AssociationLedger::default();
        for _ in 0..5 {
            ledger.observe(1, 3);
        }
        for _ in 0..2 {
            ledger.observe(2, 4);
        }
        ledger.observe(2, 3);
        ledger.fuse(1, 2);
        // Landmark 1 stands on object 3 (6 of 8); object 4's two observations are wrong.
        assert_eq!(ledger.counts(), AssociationCounts { total: 7, wrong: 2 });
        // Fused again into a third: the chain follows.
        ledger.observe(5, 3);
        ledger.fuse(5, 1);
        let objects = ledger.landmark_objects();
        assert_eq!((objects[&1], objects[&2], objects[&5]), (3, 3, 3));
        assert_eq!(ledger.counts(), AssociationCounts { total: 8, wrong: 2 });
    }

    /// Regression: a landmark fed 24% by one tree and the rest by its neighbours counted
    /// as that tree's, with no false landmark (`--method appearance` on `paper_park`).
    #[test]
    fn a_landmark_stands_on_an_object_only_with_a_majority_of_its_observations() {
        let mut ledger = AssociationLedger::default();
        for (object, n) in [(4, 3), (3, 2), (13, 2), (5, 2)] {
            for _ in 0..n {
                ledger.observe(0, object);
            }
        }
        for (object, n) in [(6, 3), (7, 2)] {
            for _ in 0..n {
                ledger.observe(1, object);
            }
        }
        let objects = ledger.landmark_objects();
        // 3 of 9 is a plurality, not a majority; 3 of 5 is.
        assert_eq!((objects[&0], objects[&1]), (0, 6));
        // All 8 associations of landmark 0 are wrong (its first observation started it),
        // and landmark 1's 2 of 4 (the two of object 7).
        assert_eq!(ledger.counts(), AssociationCounts { total: 12, wrong: 10 });
    }

    #[test]
    fn hungarian_finds_the_optimal_assignment() {
        let cost = vec![vec![4.0, 1.0, 3.0], vec![2.0, 0.0, 5.0], vec![3.0, 2.0, 2.0]];
        let a = hungarian(&cost);
        let total: f64 = a.iter().enumerate().map(|(i, j)| cost[i][j.unwrap()]).sum();
        assert_eq!(total, 5.0); // 1 + 2 + 2
        // Brute force over all permutations agrees.
        let perms = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
        let best = perms.iter().map(|p| (0..3).map(|i| cost[i][p[i]]).sum::<f64>()).fold(f64::INFINITY, f64::min);
        assert_eq!(total, best);
    }

    /// Wide and tall problems, solved on their short side, give the least total cost that
    /// trying every assignment finds, with each column used at most once.
    #[test]
    fn hungarian_is_optimal_on_wide_and_tall_problems() {
        /// The least cost of assigning every row of a wide problem (rows <= columns).
        fn best(cost: &[Vec<f64>], row: usize, used: &mut Vec<bool>) -> f64 {
            if row == cost.len() {
                return 0.0;
            }
            let mut least = f64::INFINITY;
            for j in 0..cost[row].len() {
                if !used[j] {
                    used[j] = true;
                    least = least.min(cost[row][j] + best(cost, row + 1, used));
                    used[j] = false;
                }
            }
            least
        }
        let mut state = 7u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 33) as f64 / (1u64 << 31) as f64 * 10.0
        };
        for (rows, cols) in [(1, 6), (2, 5), (3, 3), (3, 6), (5, 2), (6, 3), (4, 1)] {
            for _ in 0..20 {
                let cost: Vec<Vec<f64>> = (0..rows).map(|_| (0..cols).map(|_| next()).collect()).collect();
                let a = hungarian(&cost);
                assert_eq!(a.iter().flatten().count(), rows.min(cols));
                let columns: std::collections::BTreeSet<usize> = a.iter().flatten().copied().collect();
                assert_eq!(columns.len(), rows.min(cols), "a column used twice: {a:?}");
                let total: f64 = a.iter().enumerate().filter_map(|(i, j)| j.map(|j| cost[i][j])).sum();
                let wide: Vec<Vec<f64>> = if rows <= cols {
                    cost.clone()
                } else {
                    (0..cols).map(|j| (0..rows).map(|i| cost[i][j]).collect()).collect()
                };
                let least = best(&wide, 0, &mut vec![false; wide[0].len()]);
                assert!((total - least).abs() < 1e-9, "{rows}x{cols}: {total} against {least}");
            }
        }
        // A score's few landmarks against a large world's objects: quick, and each landmark
        // takes its own object.
        let objects = 20_000;
        let cost: Vec<Vec<f64>> =
            (0..10).map(|i| (0..objects).map(|j| if j == 1000 * i + 7 { 0.5 } else { 30.0 }).collect()).collect();
        let a = hungarian(&cost);
        assert_eq!(a, (0..10).map(|i| Some(1000 * i + 7)).collect::<Vec<_>>());
    }

    #[test]
    fn hungarian_handles_rectangular_problems() {
        let cost = vec![vec![1.0, 9.0], vec![9.0, 1.0], vec![5.0, 5.0]];
        let a = hungarian(&cost);
        assert_eq!(a.iter().filter(|x| x.is_some()).count(), 2);
        assert_eq!(a[0], Some(0));
        assert_eq!(a[1], Some(1));
        assert_eq!(a[2], None);
    }

    /// Regression: an infinite or NaN cost (a distance that overflowed) never ended.
    #[test]
    fn hungarian_ends_on_non_finite_and_huge_costs() {
        let cost = vec![vec![f64::INFINITY, 1.0], vec![f64::NAN, 2.0]];
        assert_eq!(hungarian(&cost), [Some(1), Some(0)]);
        let cost = vec![vec![f64::MAX, f64::NEG_INFINITY, 1e300], vec![f64::NAN; 3]];
        let a = hungarian(&cost);
        assert_eq!(a.iter().flatten().count(), 2, "{a:?}");
    }

    #[test]
    fn wilson_interval_contains_the_proportion() {
        let (lo, hi) = wilson_interval(5, 100, 1.96);
        assert!(lo < 0.05 && hi > 0.05 && lo > 0.0 && hi < 0.15);
        let (lo, hi) = wilson_interval(0, 20, 1.96);
        assert_eq!(lo, 0.0);
        assert!(hi > 0.1 && hi < 0.2);
    }

    #[test]
    fn nees_of_identity_covariance_is_squared_norm() {
        let n = nees3([1.0, 2.0, 2.0], [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).unwrap();
        assert!((n - 9.0).abs() < 1e-12);
        let n = nees3([2.0, 0.0, 0.0], [[4.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).unwrap();
        assert!((n - 1.0).abs() < 1e-12);
        assert!(nees3([1.0, 0.0, 0.0], [[0.0; 3]; 3]).is_none());
    }
}

/// Serde helpers for figures that may be undefined: NaN is written as `null` (JSON has no
/// NaN) and read back as NaN.
/// NaN, for fields absent from older records.
pub fn nan() -> f64 {
    f64::NAN
}

pub mod nan_as_null {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() { s.serialize_f64(*v) } else { s.serialize_none() }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
    }
}
