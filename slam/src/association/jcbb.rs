//! Joint compatibility branch and bound (Neira & Tardos 2001), position only.
//!
//! Searches pairings of observations with landmarks, extending a hypothesis only with
//! individually compatible pairs and keeping it only while the whole set is jointly
//! compatible: its stacked innovation's squared Mahalanobis distance under the joint
//! innovation covariance (which includes the correlations through the robot pose) is
//! below chi2(2k). The hypothesis with most pairings wins (ties: smallest distance).

use nalgebra::{DMatrix, DVector, Matrix2, Matrix2x3, Vector2};

use super::chi2_quantile_in_domain;
use crate::ekf::{Ekf, RangeBearingModel};
use crate::messages::wrap_angle;

/// Per-observation landmark index (`None`: unpaired).
pub type Hypothesis = Vec<Option<usize>>;

/// Why JCBB could not search.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum JcbbError {
    /// The joint test's probability must lie strictly between 0 and 1: at 1 every joint
    /// gate is infinite, at 0 empty (a percentage, 99, given for 0.99).
    #[error("confidence {0}: the joint test needs a probability strictly between 0 and 1 (0.99, not 99)")]
    Confidence(f64),
    #[error("{rows} rows of allowed pairs for {observations} observations: one row per observation")]
    AllowedRows { rows: usize, observations: usize },
}

struct Prepared {
    /// Innovation of observation i against landmark j (predicted observation and
    /// Jacobians are per landmark; innovations per pair).
    pred: Vec<(Vector2<f64>, Matrix2x3<f64>, Matrix2<f64>)>,
    individual: Vec<Vec<bool>>,
}

/// Runs JCBB; `individual_gate` is the 2-dof squared-distance gate for single pairs and
/// `confidence` the probability for the joint test (e.g. 0.99).
pub fn jcbb(
    ekf: &Ekf,
    model: &RangeBearingModel,
    observations: &[Vector2<f64>],
    individual_gate: f64,
    confidence: f64,
) -> Result<Hypothesis, JcbbError> {
    let allowed: Vec<Vec<bool>> = observations
        .iter()
        .map(|z| ekf.mahalanobis2_to_all(model, z).into_iter().map(|m2| m2 < individual_gate).collect())
        .collect();
    jcbb_with(ekf, model, observations, &allowed, confidence)
}

/// JCBB over the pairs `allowed[i][j]` (observation i may be landmark j) chosen by the
/// caller, e.g. individually gated and alike in appearance. A row shorter than the map
/// allows none of the landmarks past its end (a caller may stop a row at its last allowed
/// landmark); entries past the map are ignored. `allowed` needs one row per observation.
pub fn jcbb_with(
    ekf: &Ekf,
    model: &RangeBearingModel,
    observations: &[Vector2<f64>],
    allowed: &[Vec<bool>],
    confidence: f64,
) -> Result<Hypothesis, JcbbError> {
    let m = observations.len();
    if allowed.len() != m {
        return Err(JcbbError::AllowedRows { rows: allowed.len(), observations: m });
    }
    if !(confidence > 0.0 && confidence < 1.0) {
        return Err(JcbbError::Confidence(confidence));
    }
    let n = ekf.landmark_count();
    if m == 0 {
        return Ok(vec![]);
    }
    let pred: Vec<_> = ekf.landmarks().map(|l| model.observe(&ekf.pose(), &l)).collect();
    let individual = allowed.iter().map(|row| (0..n).map(|j| row.get(j).copied().unwrap_or(false)).collect()).collect();
    let prep = Prepared { pred, individual };
    let mut search = Search {
        ekf,
        model,
        obs: observations,
        prep: &prep,
        confidence,
        best: vec![None; m],
        best_pairs: 0,
        best_d2: f64::INFINITY,
        nodes: 0,
    };
    search.run();
    Ok(search.best)
}

/// The JCBB hypothesis over `allowed` if no other hypothesis pairs as many observations:
/// for each of its pairs, the search without that pair must find fewer pairs. `None` when
/// it pairs nothing or a rival exists (two constellations fit: wait for more evidence).
pub fn unambiguous_jcbb(
    ekf: &Ekf,
    model: &RangeBearingModel,
    observations: &[Vector2<f64>],
    allowed: &[Vec<bool>],
    confidence: f64,
) -> Result<Option<Hypothesis>, JcbbError> {
    let best = jcbb_with(ekf, model, observations, allowed, confidence)?;
    let pairs = |h: &Hypothesis| h.iter().flatten().count();
    let k = pairs(&best);
    if k == 0 {
        return Ok(None);
    }
    for (i, j) in best.iter().enumerate() {
        let Some(j) = *j else { continue };
        let mut without = allowed.to_vec();
        without[i][j] = false;
        if pairs(&jcbb_with(ekf, model, observations, &without, confidence)?) >= k {
            return Ok(None);
        }
    }
    Ok(Some(best))
}

struct Search<'a> {
    ekf: &'a Ekf,
    model: &'a RangeBearingModel,
    obs: &'a [Vector2<f64>],
    prep: &'a Prepared,
    confidence: f64,
    best: Hypothesis,
    best_pairs: usize,
    best_d2: f64,
    nodes: usize,
}

/// Bound on explored nodes: pathological inputs degrade to the best found so far.
const MAX_NODES: usize = 200_000;

/// A node of the search: observation `i`, and the next landmark to try for it (`n`: the
/// unpaired branch is next; past `n`: done).
struct Node {
    i: usize,
    next: usize,
}

impl Search<'_> {
    /// Depth first over observations, each paired with every allowed unused landmark in
    /// turn while the set stays jointly compatible, then left unpaired if that can still
    /// beat the best. The stack is the search's own, not the thread's: a scan of tens of
    /// thousands of detections goes as deep as it has observations.
    fn run(&mut self) {
        let (m, n) = (self.obs.len(), self.ekf.landmark_count());
        // The hypothesis at the top node: its pairs (observation, landmark) in observation
        // order, and which landmarks they use.
        let mut made: Vec<(usize, usize)> = Vec::new();
        let mut used = vec![false; n];
        let mut stack: Vec<Node> = Vec::new();
        self.enter(&mut stack, &made, 0);
        while let Some(node) = stack.last_mut() {
            let i = node.i;
            // Back from a branch that paired observation i: unpair it.
            if let Some(&(last, j)) = made.last()
                && last == i
            {
                used[j] = false;
                made.pop();
            }
            let mut descend = false;
            while node.next < n && !descend {
                let j = node.next;
                node.next += 1;
                if !self.prep.individual[i][j] || used[j] {
                    continue;
                }
                made.push((i, j));
                let gate = chi2_quantile_in_domain(2 * made.len(), self.confidence);
                if self.joint_d2(&made).is_some_and(|d2| d2 < gate) {
                    used[j] = true;
                    descend = true;
                } else {
                    made.pop();
                }
            }
            if !descend && node.next == n {
                node.next = n + 1;
                descend = made.len() + (m - i - 1) >= self.best_pairs.max(1);
            }
            if descend {
                self.enter(&mut stack, &made, i + 1);
            } else {
                stack.pop();
            }
        }
    }

    /// Visits observation `i`'s node: past the last observation, the hypothesis `made` is
    /// complete and compared with the best; otherwise a node to search from, within the
    /// node bound.
    fn enter(&mut self, stack: &mut Vec<Node>, made: &[(usize, usize)], i: usize) {
        self.nodes += 1;
        if i == self.obs.len() {
            let k = made.len();
            if k > self.best_pairs || (k == self.best_pairs && k > 0) {
                let d2 = self.joint_d2(made).unwrap_or(f64::INFINITY);
                if k > self.best_pairs || d2 < self.best_d2 {
                    self.best = vec![None; self.obs.len()];
                    for &(o, j) in made {
                        self.best[o] = Some(j);
                    }
                    self.best_pairs = k;
                    self.best_d2 = d2;
                }
            }
            return;
        }
        if self.nodes > MAX_NODES {
            return;
        }
        stack.push(Node { i, next: 0 });
    }

    /// Joint squared Mahalanobis distance of `pairs` (observation, landmark).
    fn joint_d2(&self, pairs: &[(usize, usize)]) -> Option<f64> {
        let k = pairs.len();
        if k == 0 {
            return Some(0.0);
        }
        let mut nu = DVector::zeros(2 * k);
        let mut s = DMatrix::zeros(2 * k, 2 * k);
        let p = &self.ekf.p;
        for (a, &(i, j)) in pairs.iter().enumerate() {
            let (zp, _, _) = &self.prep.pred[j];
            nu[2 * a] = self.obs[i].x - zp.x;
            nu[2 * a + 1] = wrap_angle(self.obs[i].y - zp.y);
        }
        // S_ab = H_a P H_bᵀ with H_a nonzero on the robot and landmark j_a columns.
        for (a, &(_, ja)) in pairs.iter().enumerate() {
            let (_, hra, hla) = &self.prep.pred[ja];
            for (b, &(_, jb)) in pairs.iter().enumerate().skip(a) {
                let (_, hrb, hlb) = &self.prep.pred[jb];
                let (la, lb) = (self.ekf.landmark_offset() + 2 * ja, self.ekf.landmark_offset() + 2 * jb);
                let prr = p.fixed_view::<3, 3>(0, 0);
                let prl_b = p.fixed_view::<3, 2>(0, lb);
                let pla_r = p.fixed_view::<2, 3>(la, 0);
                let pla_lb = p.fixed_view::<2, 2>(la, lb);
                let block = hra * prr * hrb.transpose()
                    + hra * prl_b * hlb.transpose()
                    + hla * pla_r * hrb.transpose()
                    + hla * pla_lb * hlb.transpose();
                let block = if a == b { block + self.model.noise_at(self.prep.pred[ja].0.x) } else { block };
                s.view_mut((2 * a, 2 * b), (2, 2)).copy_from(&block);
                if a != b {
                    s.view_mut((2 * b, 2 * a), (2, 2)).copy_from(&block.transpose());
                }
            }
        }
        let chol = s.cholesky()?;
        let x = chol.solve(&nu);
        Some(nu.dot(&x))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::association::nn::nearest_neighbour;
    use nalgebra::{Matrix3, Vector3};
    use proptest::prelude::*;

    /// A laser at the robot's origin with 2 cm and 0.002 rad of noise.
    fn precise_model() -> RangeBearingModel {
        RangeBearingModel {
            mount_x: 0.0,
            mount_y: 0.0,
            range_sigma_m: 0.02,
            bearing_sigma_rad: 0.002,
            ..Default::default()
        }
    }

    #[test]
    fn jcbb_finds_the_jointly_compatible_hypothesis_where_nn_fails() {
        // Three precisely mapped landmarks at bearings 0, 0.20 and 0.28 rad, 5 m away. The
        // robot's heading is uncertain (sigma 0.14 rad) and really 0.12 rad off, so it sees
        // b and c at 0.08 and 0.16. Individually nearest: a and b, implying heading errors
        // of 0.08 and 0.04 at once, impossible with 0.002 rad bearing noise. Jointly, only
        // (b, c) fits one common heading error.
        let model = precise_model();
        let mut ekf =
            Ekf::new(Vector3::new(0.0, 0.0, 0.0), Matrix3::new(1e-6, 0.0, 0.0, 0.0, 1e-6, 0.0, 0.0, 0.0, 0.02));
        for bearing in [0.0f64, 0.20, 0.28] {
            ekf.add_landmark(&model, &Vector2::new(5.0, bearing)).unwrap();
        }
        for i in 3..ekf.x.len() {
            for k in 0..ekf.x.len() {
                if k != i {
                    ekf.p[(i, k)] = 0.0;
                    ekf.p[(k, i)] = 0.0;
                }
            }
            ekf.p[(i, i)] = 1e-6;
        }
        let obs = vec![Vector2::new(5.0, 0.20 - 0.12), Vector2::new(5.0, 0.28 - 0.12)];
        let nn: Vec<Option<usize>> = nearest_neighbour(&ekf, &model, &obs, 9.21).iter().map(|r| r.landmark).collect();
        assert_eq!(nn, vec![Some(0), Some(1)], "nearest neighbour takes the individually closest");
        let h = jcbb(&ekf, &model, &obs, 9.21, 0.99).unwrap();
        assert_eq!(h, vec![Some(1), Some(2)], "JCBB pairs with the common heading error");
    }

    #[test]
    fn jcbb_leaves_spurious_observations_unpaired() {
        let model = RangeBearingModel { bearing_sigma_rad: 0.01, ..precise_model() };
        let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::identity() * 1e-4);
        ekf.add_landmark(&model, &Vector2::new(4.0, 0.5)).unwrap();
        ekf.add_landmark(&model, &Vector2::new(6.0, -0.5)).unwrap();
        let obs = vec![Vector2::new(4.01, 0.5), Vector2::new(3.0, 1.2), Vector2::new(6.0, -0.49)];
        assert_eq!(jcbb(&ekf, &model, &obs, 9.21, 0.99).unwrap(), vec![Some(0), None, Some(1)]);
    }

    /// Guards the loop-closing test: a constellation that fits one way is taken, one that
    /// fits two ways (a symmetric map, a large heading uncertainty) is not.
    #[test]
    fn an_ambiguous_constellation_is_refused() {
        let model = precise_model();
        // Heading sigma 0.5 rad: both observations gate with every landmark.
        let pose_cov = Matrix3::new(1e-6, 0.0, 0.0, 0.0, 1e-6, 0.0, 0.0, 0.0, 0.25);
        let place = |bearings: &[f64]| {
            let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::zeros());
            for &b in bearings {
                ekf.add_landmark(&model, &Vector2::new(5.0, b)).unwrap();
            }
            ekf.p.view_mut((0, 0), (3, 3)).copy_from(&pose_cov);
            ekf
        };
        let obs = vec![Vector2::new(5.0, 0.1), Vector2::new(5.0, 0.4)];
        let all = |ekf: &Ekf| vec![vec![true; ekf.landmark_count()]; 2];
        // Landmarks at 0, 0.3 and 0.9 rad: only (0, 0.3) is 0.3 rad apart like the pair seen.
        let unique = place(&[0.0, 0.3, 0.9]);
        assert_eq!(unambiguous_jcbb(&unique, &model, &obs, &all(&unique), 0.99).unwrap(), Some(vec![Some(0), Some(1)]));
        // Landmarks at 0, 0.3, 0.6: (0, 0.3) and (0.3, 0.6) fit alike.
        let twice = place(&[0.0, 0.3, 0.6]);
        assert_eq!(jcbb_with(&twice, &model, &obs, &all(&twice), 0.99).unwrap().iter().flatten().count(), 2);
        assert_eq!(unambiguous_jcbb(&twice, &model, &obs, &all(&twice), 0.99).unwrap(), None);
        // The caller's mask rules pairs out: without landmark 2 the pair is unique again.
        let mut masked = all(&twice);
        masked[0][2] = false;
        masked[1][2] = false;
        assert_eq!(unambiguous_jcbb(&twice, &model, &obs, &masked, 0.99).unwrap(), Some(vec![Some(0), Some(1)]));
    }

    /// The search as first written, recursively: the reference the explicit stack must
    /// follow pair for pair.
    fn recursive_reference(
        ekf: &Ekf,
        model: &RangeBearingModel,
        obs: &[Vector2<f64>],
        allowed: &[Vec<bool>],
    ) -> Hypothesis {
        fn recurse(s: &mut Search, i: usize, h: &mut Hypothesis, pairs: usize) {
            let made = |h: &Hypothesis| -> Vec<(usize, usize)> {
                h.iter().enumerate().filter_map(|(i, j)| j.map(|j| (i, j))).collect()
            };
            s.nodes += 1;
            if i == s.obs.len() {
                if pairs > s.best_pairs || (pairs == s.best_pairs && pairs > 0) {
                    let d2 = s.joint_d2(&made(h)).unwrap_or(f64::INFINITY);
                    if pairs > s.best_pairs || d2 < s.best_d2 {
                        (s.best, s.best_pairs, s.best_d2) = (h.clone(), pairs, d2);
                    }
                }
                return;
            }
            if s.nodes > MAX_NODES {
                return;
            }
            for j in 0..s.ekf.landmark_count() {
                if !s.prep.individual[i][j] || h.contains(&Some(j)) {
                    continue;
                }
                h[i] = Some(j);
                if s.joint_d2(&made(h)).is_some_and(|d2| d2 < chi2_quantile_in_domain(2 * (pairs + 1), s.confidence)) {
                    recurse(s, i + 1, h, pairs + 1);
                }
                h[i] = None;
            }
            if pairs + (s.obs.len() - i - 1) >= s.best_pairs.max(1) {
                recurse(s, i + 1, h, pairs);
            }
        }
        let pred = ekf.landmarks().map(|l| model.observe(&ekf.pose(), &l)).collect();
        let prep = Prepared { pred, individual: allowed.to_vec() };
        let mut s = Search {
            ekf,
            model,
            obs,
            prep: &prep,
            confidence: 0.99,
            best: vec![None; obs.len()],
            best_pairs: 0,
            best_d2: f64::INFINITY,
            nodes: 0,
        };
        recurse(&mut s, 0, &mut vec![None; obs.len()], 0);
        s.best
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Random maps and scans under a loose pose: the explicit stack pairs exactly as
        /// the recursion did.
        #[test]
        fn the_search_pairs_as_the_recursion_did(
            landmarks in prop::collection::vec((2.0f64..8.0, -1.0f64..1.0), 0..6),
            seen in prop::collection::vec((2.0f64..8.0, -1.0f64..1.0), 0..6),
            heading_var in 0.0001f64..0.3,
            mask in prop::collection::vec(any::<bool>(), 36),
        ) {
            let model = RangeBearingModel { bearing_sigma_rad: 0.02, ..precise_model() };
            let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::new(0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, heading_var));
            for &(r, b) in &landmarks {
                ekf.add_landmark(&model, &Vector2::new(r, b)).unwrap();
            }
            let obs: Vec<Vector2<f64>> = seen.iter().map(|&(r, b)| Vector2::new(r, b)).collect();
            let allowed: Vec<Vec<bool>> =
                (0..obs.len()).map(|i| (0..landmarks.len()).map(|j| mask[i * 6 + j]).collect()).collect();
            let expected = recursive_reference(&ekf, &model, &obs, &allowed);
            prop_assert_eq!(jcbb_with(&ekf, &model, &obs, &allowed, 0.99).unwrap(), expected);
        }
    }

    /// A scan of far more detections than a laser gives (a log's, malformed or not) is
    /// searched on the search's own stack, not the thread's: no overflow, one pair made.
    #[test]
    fn tens_of_thousands_of_observations_do_not_overflow_the_stack() {
        let model = precise_model();
        let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::identity() * 1e-4);
        ekf.add_landmark(&model, &Vector2::new(5.0, 0.0)).unwrap();
        let obs = vec![Vector2::new(5.0, 0.0); 50_000];
        let run = move || jcbb(&ekf, &model, &obs, 9.21, 0.99).unwrap();
        // A thread of rayon's or the test harness's size (2 MiB), where the recursion
        // overflowed.
        let h = std::thread::Builder::new().stack_size(2 << 20).spawn(run).unwrap().join().unwrap();
        assert_eq!(h.len(), 50_000);
        assert_eq!(h.iter().flatten().count(), 1);
    }
}
