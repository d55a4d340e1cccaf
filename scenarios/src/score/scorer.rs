//! [`RunScorer`]: every ground-truth scoring rule of a run in one place, fed the same way
//! by `objslam run` (from the pipeline, as it runs) and by `objslam score` (from a sensor
//! log and files any SLAM system can write), so that both give the same figures.

use std::collections::{BTreeMap, BTreeSet, HashMap};

use serde::{Deserialize, Serialize};
use slam::clustering::Cluster;
use slam::pipeline::SegmentationRecord;
use slam::segmentation::CameraGeometry;
use worlds::{ObjectClass, World};

use super::segmentation::{ClassImage, SegmentationScorer};
use super::{AssociationCounts, AssociationLedger, MapContent};
use crate::visibility::{InstanceImage, TreeVisibility};

/// Which trees the recall counts as there to map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RecallBasis {
    /// Trees the camera showed where the laser hit them (`map.trees_in_view`): for methods
    /// that need the camera to map a tree.
    InView,
    /// Trees the laser hit (`map.trees_laser_seen`): for position-only methods.
    LaserSeen,
}

impl RecallBasis {
    /// The basis `objslam run` scores `method` on.
    pub fn of_method(method: slam::association::AssociationMethod) -> Self {
        if method.uses_appearance() { RecallBasis::InView } else { RecallBasis::LaserSeen }
    }
}

/// What makes a tree count as seen: the clustering's fewest points and range, and the
/// observations that confirm a landmark (see [`TreeVisibility`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VisibilitySettings {
    pub min_beams: usize,
    pub max_range_m: f64,
    pub frames_needed: usize,
}

impl VisibilitySettings {
    /// The settings a pipeline configuration implies.
    pub fn of(config: &slam::pipeline::PipelineConfig) -> Self {
        VisibilitySettings {
            min_beams: config.clustering.min_points,
            max_range_m: config.clustering.max_range_m,
            frames_needed: config.confirm_observations,
        }
    }
}

/// One laser observation of a scan as the system under test used it: the beams it spans
/// and the landmark it went to (a new or an existing one), if any.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScoredObservation {
    pub first_beam: usize,
    pub last_beam: usize,
    pub landmark: Option<u32>,
}

/// Two landmarks the system found to be one: `removed` was fused into `kept`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Fusion {
    pub kept: u32,
    pub removed: u32,
}

/// A mapped landmark as the scoring needs it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MapLandmark {
    pub id: u32,
    pub position: [f64; 2],
}

/// The ground-truth figures of a run.
#[derive(Debug, Clone)]
pub struct GroundTruthScore {
    pub ate_rmse_m: f64,
    /// Translational relative pose error over [`RPE_DELTA_S`] (NaN with too short a run).
    pub rpe_rmse_m: f64,
    pub landmark_rmse_m: Option<f64>,
    pub map: MapContent,
    pub landmarks: usize,
    pub associations: AssociationCounts,
    pub duplicate_landmarks: usize,
    pub false_landmarks: usize,
    /// Average NEES of the pose (NaN without covariances).
    pub anees: f64,
    /// The object each landmark stands on (0: none), from its observations.
    pub landmark_objects: HashMap<u32, u16>,
    /// Landmarks retracted, and how many of them were trees.
    pub retracted: usize,
    pub retracted_trees: usize,
    /// Patch decisions against the masks (when scoring segmentation).
    pub patches: Option<slam::classifier::PatchScores>,
}

/// The interval of the relative pose error, s.
pub const RPE_DELTA_S: f64 = 1.0;

/// A pose counts as [`RPE_DELTA_S`] after another when it is at most this much short of
/// it: poses at a fixed rate fall exactly on the interval, and whether an exact 1.0 s
/// comes out a hair under or over must not depend on how the timestamps were written (ROS
/// nanoseconds, six decimals, the last bit of a sum), or the same trajectory would pair
/// other poses. A millisecond is below the period of any odometry this scores (20-50 Hz
/// here, 40 Hz in Victoria Park); at 1 kHz and faster a pose a step short of the interval
/// would pair too, a harmless 0.1% change of the interval.
pub const RPE_TIME_TOLERANCE_S: f64 = 1e-3;

/// A pose as a TUM file holds it: the heading through its quaternion. Scoring poses this
/// way gives a run and the trajectory it wrote the same figures, to the last bit.
pub fn as_written_to_tum(pose: [f64; 3]) -> [f64; 3] {
    [pose[0], pose[1], yaw_of_quaternion(crate::foxglove::yaw_quaternion(pose[2]))]
}

/// The heading of a yaw-only unit quaternion [x, y, z, w].
pub fn yaw_of_quaternion(q: [f64; 4]) -> f64 {
    let [qx, qy, qz, qw] = q;
    (2.0 * (qw * qz + qx * qy)).atan2(1.0 - 2.0 * (qy * qy + qz * qz))
}

/// Root-mean-square translational relative pose error: for each pose i and the first pose
/// j at least `delta_s` later, the length of the difference between the estimated and the
/// true motion from i to j, each expressed in its own frame at i (the TUM RGB-D benchmark's
/// translational RPE, without alignment; "at least" within [`RPE_TIME_TOLERANCE_S`]). NaN
/// when no pair is that far apart.
pub fn rpe_rmse(times: &[f64], estimate: &[[f64; 3]], truth: &[[f64; 3]], delta_s: f64) -> f64 {
    let motion = |a: &[f64; 3], b: &[f64; 3]| {
        let (s, c) = a[2].sin_cos();
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        [c * dx + s * dy, -s * dx + c * dy]
    };
    let (mut sum, mut n) = (0.0, 0usize);
    for (i, j) in rpe_pairs(times, delta_s) {
        let (e, g) = (motion(&estimate[i], &estimate[j]), motion(&truth[i], &truth[j]));
        sum += (e[0] - g[0]).powi(2) + (e[1] - g[1]).powi(2);
        n += 1;
    }
    if n == 0 { f64::NAN } else { (sum / n as f64).sqrt() }
}

/// The pose pairs (i, j) of [`rpe_rmse`]: each pose and the first at least `delta_s` after it.
pub fn rpe_pairs(times: &[f64], delta_s: f64) -> impl Iterator<Item = (usize, usize)> + '_ {
    let mut j = 0;
    (0..times.len()).map_while(move |i| {
        j = j.max(i);
        while j < times.len() && times[j] < times[i] + delta_s - RPE_TIME_TOLERANCE_S {
            j += 1;
        }
        (j < times.len()).then_some((i, j))
    })
}

/// A pair of [`rpe_pairs`] spans more than this many times the interval where the
/// trajectory has a gap: the RPE there measures drift over a longer time.
pub const RPE_GAP_FACTOR: f64 = 1.5;

/// How many of the RPE's pairs there are, and how many of them span more than
/// [`RPE_GAP_FACTOR`] times `delta_s`.
pub fn rpe_pairs_over_gaps(times: &[f64], delta_s: f64) -> (usize, usize) {
    rpe_pairs(times, delta_s)
        .fold((0, 0), |(n, long), (i, j)| (n + 1, long + usize::from(times[j] - times[i] > RPE_GAP_FACTOR * delta_s)))
}

/// Which object a run of beams truly belongs to: the most frequent instance id among them
/// (0 if they hit nothing known; a real object wins a tie against nothing, then the
/// higher id).
pub fn true_object(hit_ids: &[u16], first: usize, last: usize) -> u16 {
    let mut counts: BTreeMap<u16, usize> = BTreeMap::new();
    for &id in hit_ids.get(first..=last).unwrap_or(&[]) {
        *counts.entry(id).or_default() += 1;
    }
    counts.into_iter().max_by_key(|(id, n)| (*n, *id != 0)).map(|(id, _)| id).unwrap_or(0)
}

/// Scores a run as it goes: poses, scans with their observations, then the final map.
pub struct RunScorer<'w> {
    world: &'w World,
    tree_ids: BTreeSet<u16>,
    visibility: TreeVisibility,
    basis: RecallBasis,
    ledger: AssociationLedger,
    /// Time of each scored pose.
    times: Vec<f64>,
    /// Scored poses (x, y, yaw), estimated and true.
    estimate: Vec<[f64; 3]>,
    truth: Vec<[f64; 3]>,
    nees_sum: f64,
    nees_n: usize,
    /// Camera methods: their segmentation against the masks (see [`RunScorer::scoring_segmentation`]).
    segmentation: Option<SegmentationScorer>,
    frames_needed: usize,
    /// Landmarks the system took off its map (see [`RunScorer::on_retraction`]).
    retracted: Vec<u32>,
}

impl<'w> RunScorer<'w> {
    /// `camera` carries the simulator's true extrinsics (absent without a camera).
    pub fn new(
        world: &'w World,
        camera: Option<CameraGeometry>,
        settings: VisibilitySettings,
        basis: RecallBasis,
    ) -> Self {
        let tree_ids: BTreeSet<u16> =
            world.objects.iter().filter(|o| o.class == ObjectClass::Tree).map(|o| o.id).collect();
        let visibility = TreeVisibility::new(
            tree_ids.clone(),
            camera,
            settings.min_beams,
            settings.max_range_m,
            settings.frames_needed,
        );
        RunScorer {
            world,
            tree_ids,
            visibility,
            basis,
            ledger: AssociationLedger::default(),
            times: Vec::new(),
            estimate: Vec::new(),
            truth: Vec::new(),
            nees_sum: 0.0,
            nees_n: 0,
            segmentation: None,
            frames_needed: settings.frames_needed,
            retracted: Vec::new(),
        }
    }

    /// The same scorer, scoring a camera method's segmentation records too
    /// ([`RunScorer::on_segmentation`]): patch precision and recall, and `map.trees_judged`.
    pub fn scoring_segmentation(mut self) -> Self {
        let tree = ObjectClass::Tree.id();
        self.segmentation = Some(SegmentationScorer::new(self.tree_ids.clone(), tree, self.frames_needed));
        self
    }

    /// One segmented image of a scan (see [`SegmentationScorer::on_record`]); returns each
    /// segmented cluster's true object.
    pub fn on_segmentation(
        &mut self,
        record: &SegmentationRecord,
        clusters: &[Cluster],
        beams: &sim::LaserTruth,
        frame: Option<&ClassImage>,
    ) -> Vec<u16> {
        match &mut self.segmentation {
            Some(s) => s.on_record(record, clusters, &beams.hit_ids, frame),
            None => record
                .clusters
                .iter()
                .map(|cs| true_object(&beams.hit_ids, clusters[cs.index].first_beam, clusters[cs.index].last_beam))
                .collect(),
        }
    }

    /// The tree counter, for a camera that must render the columns it reads.
    pub fn visibility(&self) -> &TreeVisibility {
        &self.visibility
    }

    /// Ids of the world's trees.
    pub fn tree_ids(&self) -> &BTreeSet<u16> {
        &self.tree_ids
    }

    /// Poses whose covariance gave a NEES (positive definite): the ANEES's count.
    pub fn nees_poses(&self) -> usize {
        self.nees_n
    }

    /// An estimated pose (x, y, theta) at time `t` with its covariance, if known, and the
    /// true pose of the same instant. A caller holding poses that were not read from TUM
    /// files passes them through [`as_written_to_tum`] first.
    pub fn on_pose(&mut self, t: f64, estimate: [f64; 3], covariance: Option<[[f64; 3]; 3]>, truth: [f64; 3]) {
        self.times.push(t);
        self.estimate.push(estimate);
        self.truth.push(truth);
        let e = [estimate[0] - truth[0], estimate[1] - truth[1], sim::wrap_angle(estimate[2] - truth[2])];
        if let Some(n) = covariance.and_then(|p| super::nees3(e, p)) {
            self.nees_sum += n;
            self.nees_n += 1;
        }
    }

    /// The beams of `scan` whose pixels in `frame`, the camera frame of its instant, show
    /// the tree they hit (see [`TreeVisibility::beams_shown`]): what [`RunScorer::on_scan`]
    /// takes of the frame.
    pub fn beams_shown(&mut self, scan: &sim::LaserScan, beams: &sim::LaserTruth, frame: &InstanceImage) -> Vec<usize> {
        self.visibility.beams_shown(scan, beams, frame)
    }

    /// A scan, its beams' truth, the beams a camera frame of the same instant showed on
    /// their trees (`None`: no frame then; see [`RunScorer::beams_shown`]), the
    /// observations the system made of it and the fusions it made after it.
    pub fn on_scan(
        &mut self,
        scan: &sim::LaserScan,
        beams: &sim::LaserTruth,
        shown: Option<&[usize]>,
        observations: &[ScoredObservation],
        fusions: &[Fusion],
    ) {
        for o in observations {
            if let Some(id) = o.landmark {
                self.ledger.observe(id, true_object(&beams.hit_ids, o.first_beam, o.last_beam));
            }
        }
        // A fusion associates every observation of the removed landmark with the kept one:
        // scored like any association (wrong if the objects differ).
        for f in fusions {
            self.ledger.fuse(f.kept, f.removed);
        }
        self.visibility.on_scan_shown(scan, beams, shown);
    }

    /// A landmark the system took off its map (a retraction): scored by what its
    /// observations truly were, so retracting a tree shows as `retracted_trees`.
    pub fn on_retraction(&mut self, landmark: u32) {
        self.retracted.push(landmark);
    }

    /// Pixels the tree count read in image columns the camera did not render (must be 0).
    pub fn unrendered_reads(&self) -> usize {
        self.visibility.unrendered_reads()
    }

    /// The figures, given the final map.
    pub fn finish(self, landmarks: &[MapLandmark]) -> GroundTruthScore {
        let landmark_objects = self.ledger.landmark_objects();
        let mut map = MapContent {
            trees_in_view: self.visibility.trees_in_view().map(|t| t.len()),
            trees_laser_seen: self.visibility.trees_laser_seen().len(),
            trees_judged: self.segmentation.as_ref().map(|s| s.trees_judged()),
            ..Default::default()
        };
        let mut per_object: BTreeMap<u16, usize> = BTreeMap::new();
        for lm in landmarks {
            let obj = landmark_objects.get(&lm.id).copied().unwrap_or(0);
            *per_object.entry(obj).or_default() += 1;
            match self.world.class_of(obj) {
                Some(ObjectClass::Tree) => {}
                Some(ObjectClass::Post) => map.posts += 1,
                Some(ObjectClass::Palm) => map.palms += 1,
                Some(ObjectClass::Person) => map.people += 1,
                Some(ObjectClass::Wall) => map.walls += 1,
                _ => map.nothing += 1,
            }
        }
        let trees_mapped: BTreeSet<u16> = per_object.keys().filter(|id| self.tree_ids.contains(id)).copied().collect();
        map.trees_mapped = trees_mapped.len();
        let to_map = match self.basis {
            RecallBasis::InView => self.visibility.trees_in_view(),
            RecallBasis::LaserSeen => Some(self.visibility.trees_laser_seen().clone()),
        };
        map.tree_recall = super::tree_recall(&trees_mapped, to_map.as_ref());
        map.missed_trees = to_map.map(|t| t.difference(&trees_mapped).copied().collect()).unwrap_or_default();
        map.missed_by_stage = self.segmentation.as_ref().map(|s| {
            let mut by_stage: BTreeMap<String, Vec<u16>> = BTreeMap::new();
            for &id in &map.missed_trees {
                by_stage.entry(s.stage_reached(id).key().to_string()).or_default().push(id);
            }
            by_stage
        });
        let duplicate_landmarks = per_object.iter().filter(|(id, _)| **id != 0).map(|(_, n)| n.saturating_sub(1)).sum();
        let false_landmarks = map.posts + map.palms + map.people + map.walls + map.nothing;
        let xy = |poses: &[[f64; 3]]| poses.iter().map(|p| [p[0], p[1]]).collect::<Vec<_>>();
        GroundTruthScore {
            ate_rmse_m: super::ate_rmse(&xy(&self.estimate), &xy(&self.truth)),
            rpe_rmse_m: rpe_rmse(&self.times, &self.estimate, &self.truth, RPE_DELTA_S),
            landmark_rmse_m: landmark_rmse(self.world, landmarks),
            map,
            landmarks: landmarks.len(),
            associations: self.ledger.counts(),
            duplicate_landmarks,
            false_landmarks,
            anees: if self.nees_n > 0 { self.nees_sum / self.nees_n as f64 } else { f64::NAN },
            retracted: self.retracted.len(),
            retracted_trees: self
                .retracted
                .iter()
                .filter(|id| landmark_objects.get(id).is_some_and(|o| self.tree_ids.contains(o)))
                .count(),
            landmark_objects,
            patches: self.segmentation.as_ref().map(|s| s.patches()),
        }
    }
}

/// The farthest a landmark may be from a static object's centre to be scored against it, m.
const LANDMARK_MATCH_GATE_M: f64 = 2.0;

/// Landmark RMSE after optimal assignment to the static objects' centres (trees, posts,
/// palms), pairs further apart than [`LANDMARK_MATCH_GATE_M`] left out; `None` when no
/// pair is that close.
pub fn landmark_rmse(world: &World, landmarks: &[MapLandmark]) -> Option<f64> {
    let statics: Vec<&worlds::StaticObject> = world
        .objects
        .iter()
        .filter(|o| matches!(o.class, ObjectClass::Tree | ObjectClass::Post | ObjectClass::Palm))
        .collect();
    let distance: Vec<Vec<f64>> = landmarks
        .iter()
        .map(|l| {
            statics
                .iter()
                .map(|o| ((l.position[0] - o.pose.x).powi(2) + (l.position[1] - o.pose.y).powi(2)).sqrt())
                .collect()
        })
        .collect();
    // A pair costs its squared distance, so that of the pairings the one with the least
    // RMS is chosen (the least total distance can have a larger RMS). Every pair beyond the
    // gate costs the same, more than all pairs within it together: the assignment then
    // makes as many pairs within the gate as it can, and a pair the gate will drop cannot
    // take a landmark's good match.
    let gate_cost = LANDMARK_MATCH_GATE_M * LANDMARK_MATCH_GATE_M;
    let beyond = gate_cost * (landmarks.len().min(statics.len()) + 1) as f64;
    let gated = |d: f64| if d <= LANDMARK_MATCH_GATE_M { d * d } else { beyond };
    let cost: Vec<Vec<f64>> = distance.iter().map(|row| row.iter().map(|&d| gated(d)).collect()).collect();
    let assignment = super::hungarian(&cost);
    let matched: Vec<f64> = assignment
        .iter()
        .enumerate()
        .filter_map(|(i, j)| j.map(|j| distance[i][j]))
        .filter(|d| *d <= LANDMARK_MATCH_GATE_M)
        .collect();
    (!matched.is_empty()).then(|| (matched.iter().map(|d| d * d).sum::<f64>() / matched.len() as f64).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_pose_error_sees_drift_per_second_not_an_offset() {
        let times: Vec<f64> = (0..=40).map(|i| 0.1 * i as f64).collect();
        let truth: Vec<[f64; 3]> = times.iter().map(|t| [*t, 0.0, 0.0]).collect();
        // A constant offset: no relative error at all.
        let shifted: Vec<[f64; 3]> = truth.iter().map(|p| [p[0] + 3.0, p[1] - 1.0, 0.0]).collect();
        assert!(rpe_rmse(&times, &shifted, &truth, 1.0) < 1e-12);
        // 10% too far: 0.1 m error per 1 m (1 s) of motion.
        let stretched: Vec<[f64; 3]> = truth.iter().map(|p| [1.1 * p[0], 0.0, 0.0]).collect();
        assert!((rpe_rmse(&times, &stretched, &truth, 1.0) - 0.1).abs() < 1e-9);
        assert!(rpe_rmse(&times[..5], &stretched[..5], &truth[..5], 1.0).is_nan(), "no pair 1 s apart");
        // Pairs over a gap in the poses are counted apart: they span more than 1.5 s.
        assert_eq!(rpe_pairs_over_gaps(&times, 1.0).1, 0);
        let gappy: Vec<f64> = times.iter().copied().filter(|t| !(2.0..2.8).contains(t)).collect();
        let (pairs, long) = rpe_pairs_over_gaps(&gappy, 1.0);
        assert!(long > 0 && long < pairs, "{long} of {pairs}");
    }

    #[test]
    fn relative_pose_error_pairs_the_same_poses_whatever_digits_the_times_were_written_with() {
        // 20 Hz by summation (times a hair off the decimal), and the same written with six
        // decimals and as ROS nanoseconds: poses exactly 1 s apart pair in all three.
        let mut summed = vec![0.0f64];
        for _ in 0..200 {
            summed.push(summed.last().unwrap() + 0.05);
        }
        let six: Vec<f64> = summed.iter().map(|t| format!("{t:.6}").parse().unwrap()).collect();
        let nanos: Vec<f64> = summed.iter().map(|t| (t * 1e9).round() / 1e9).collect();
        assert!(summed.iter().zip(&six).any(|(a, b)| a != b), "the test needs times that differ in their last bits");
        // A wobbling estimate, so that which poses pair changes the figure.
        let truth: Vec<[f64; 3]> = summed.iter().map(|t| [*t, 0.0, 0.0]).collect();
        let estimate: Vec<[f64; 3]> =
            summed.iter().enumerate().map(|(i, t)| [t * 1.05 + 0.01 * (i % 3) as f64, 0.0, 0.0]).collect();
        let rpe = |times: &[f64]| rpe_rmse(times, &estimate, &truth, RPE_DELTA_S);
        assert_eq!(rpe(&six).to_bits(), rpe(&summed).to_bits());
        assert_eq!(rpe(&nanos).to_bits(), rpe(&summed).to_bits());
    }

    /// A park of two trees and a post; the system sees them in one scan, maps a tree twice
    /// and the post once, then retracts the post and one of the tree's landmarks.
    #[test]
    fn a_run_is_scored_from_its_poses_observations_map_and_retractions() {
        let mut world = worlds::generate::preset("park", None, 3).unwrap();
        world.objects.retain(|o| o.class != ObjectClass::Wall);
        world.people.clear();
        let ids = |class| world.objects.iter().filter(|o| o.class == class).map(|o| o.id).collect::<Vec<_>>();
        let (trees, posts) = (ids(ObjectClass::Tree), ids(ObjectClass::Post));
        let (a, b, post) = (trees[0], trees[1], posts[0]);
        let settings = VisibilitySettings { min_beams: 3, max_range_m: 20.0, frames_needed: 1 };
        // Beams 0-3 on tree a, 4-7 on tree b, 8-11 on the post, all 5 m away.
        let hit_ids: Vec<u16> = [a; 4].into_iter().chain([b; 4]).chain([post; 4]).collect();
        let scan = sim::LaserScan {
            t: 1.0,
            angle_min: -0.1,
            angle_increment: 0.01,
            time_increment: 0.0,
            scan_time: 0.1,
            range_min: 0.1,
            range_max: 30.0,
            ranges: vec![5.0; 12],
        };
        let beams = sim::LaserTruth { hit_ids, true_ranges: vec![5.0; 12] };
        // The run scored against the final map `mapped`.
        let scored = |mapped: &[u32]| {
            let mut scorer = RunScorer::new(&world, None, settings, RecallBasis::LaserSeen);
            // Poses 0.1 m off in x: ATE 0.1 m.
            for k in 0..10 {
                let t = k as f64;
                scorer.on_pose(t, [t + 0.1, 0.0, 0.0], None, [t, 0.0, 0.0]);
            }
            // Landmarks 1 and 2 on tree a (a duplicate), 3 on tree b, 4 on the post.
            let obs = |first_beam, landmark| ScoredObservation {
                first_beam,
                last_beam: first_beam + 1,
                landmark: Some(landmark),
            };
            scorer.on_scan(&scan, &beams, None, &[obs(0, 1), obs(2, 2), obs(4, 3), obs(8, 4)], &[]);
            scorer.on_retraction(4);
            scorer.on_retraction(2);
            let map: Vec<MapLandmark> = mapped.iter().map(|&id| MapLandmark { id, position: [0.0; 2] }).collect();
            scorer.finish(&map)
        };
        // Had the system kept them all: one duplicate, one false landmark.
        let kept = scored(&[1, 2, 3, 4]);
        assert_eq!((kept.duplicate_landmarks, kept.false_landmarks, kept.map.posts), (1, 1, 1));
        let score = scored(&[1, 3]);
        assert!((score.ate_rmse_m - 0.1).abs() < 1e-12, "{}", score.ate_rmse_m);
        assert_eq!(score.map.trees_laser_seen, 2);
        assert_eq!((score.map.trees_mapped, score.map.tree_recall), (2, Some(1.0)));
        assert_eq!((score.false_landmarks, score.duplicate_landmarks), (0, 0));
        assert_eq!((score.retracted, score.retracted_trees), (2, 1));
        assert_eq!(score.associations.wrong, 0);
        assert!(score.anees.is_nan(), "no covariance given");
    }

    /// Regression: the assignment ran on raw distances and the gate came after it, so a pair
    /// the gate would drop took a landmark's good match (RMSE 1.9 m instead of 0.1 m).
    #[test]
    fn a_pair_beyond_the_match_gate_takes_no_landmark_its_match() {
        let mut world = worlds::generate::preset("park", None, 3).unwrap();
        world.objects.retain(|o| o.class == ObjectClass::Tree);
        world.objects.truncate(2);
        (world.objects[0].pose.x, world.objects[0].pose.y) = (0.0, 0.0);
        (world.objects[1].pose.x, world.objects[1].pose.y) = (2.4, 0.0);
        // Landmark 1 is 0.1 m from the first tree and 2.3 m from the second; landmark 2 is
        // 1.9 m from the first and 4.3 m from the second.
        let map = [MapLandmark { id: 1, position: [0.1, 0.0] }, MapLandmark { id: 2, position: [-1.9, 0.0] }];
        let rmse = landmark_rmse(&world, &map).unwrap();
        assert!((rmse - 0.1).abs() < 1e-9, "{rmse}");
        // A landmark far beyond any object, or at no place at all, matches nothing.
        let far = [MapLandmark { id: 3, position: [1e200, 0.0] }, MapLandmark { id: 4, position: [f64::NAN, 0.0] }];
        assert_eq!(landmark_rmse(&world, &far), None);
        // Of two pairings the one of least RMS, not of least total distance: trees at 0 and
        // 1.2 m; pairing landmark 5 with the first tree gives 1.942 m and 0.412 m (total
        // 2.354, RMS 1.404), with the second 1.603 m and 0.806 m (total 2.409, RMS 1.269).
        (world.objects[1].pose.x, world.objects[1].pose.y) = (1.2, 0.0);
        let map = [MapLandmark { id: 5, position: [1.1, 1.6] }, MapLandmark { id: 6, position: [0.8, -0.1] }];
        let rmse = landmark_rmse(&world, &map).unwrap();
        let least = ((1.603_121_954_188_14f64.powi(2) + 0.806_225_774_829_855f64.powi(2)) / 2.0).sqrt();
        assert!((rmse - least).abs() < 1e-9, "{rmse} against {least}");
    }

    #[test]
    fn a_run_of_beams_belongs_to_its_most_frequent_object_and_a_real_one_wins_a_tie() {
        assert_eq!(true_object(&[0, 3, 3, 5], 0, 3), 3);
        assert_eq!(true_object(&[0, 0, 7, 7], 0, 3), 7);
        assert_eq!(true_object(&[0, 0, 7], 0, 1), 0);
        assert_eq!(true_object(&[4, 9], 0, 1), 9, "a tie between objects goes to the higher id");
        assert_eq!(true_object(&[1, 2], 1, 5), 0, "beams past the scan's end belong to nothing");
    }
}
