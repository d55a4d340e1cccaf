//! How a camera method's segmentation did against the rendered masks: patch precision and
//! recall, and the trees its own segmentation could judge (`map.trees_judged`, a count
//! that depends on the method, kept to explain misses; the recall's denominators do not).

use std::collections::{BTreeMap, BTreeSet};

use slam::classifier::PatchScores;
use slam::clustering::Cluster;
use slam::pipeline::SegmentationRecord;

use super::scorer::true_object;

/// The class image of a camera frame, as rendered.
pub struct ClassImage<'a> {
    pub t: f64,
    pub width: u32,
    /// One class id per pixel, row-major.
    pub class: &'a [u8],
}

/// Whether most (at least half) of the `l` x `l` patch at (`col`, `row`) shows class `tree`.
pub fn patch_is_tree(image: &ClassImage, col: u32, row: u32, l: u32, tree: u8) -> bool {
    let w = image.width;
    let mut n = 0u32;
    for y in row * l..(row + 1) * l {
        for x in col * l..(col + 1) * l {
            n += (image.class[(y * w + x) as usize] == tree) as u32;
        }
    }
    n * 2 >= l * l
}

/// Scores the segmentation records of a run as they come.
pub struct SegmentationScorer {
    tree_ids: BTreeSet<u16>,
    tree_class: u8,
    /// Frames a tree must be judged in to count as judged: the observations that confirm a
    /// landmark.
    frames_needed: usize,
    judged_frames: BTreeMap<u16, usize>,
    judged: BTreeSet<u16>,
    /// Per tree: frames its cluster was segmented in, and frames it was observed as an
    /// object where it could start a landmark (see [`MissedStage`]).
    segmented_frames: BTreeMap<u16, usize>,
    observed_frames: BTreeMap<u16, usize>,
    patches: PatchScores,
}

/// How far along the camera method's pipeline a tree it did not map got: where to look
/// for the recall lost (`map.missed_by_stage`). In the pipeline's order; each tree is
/// named at the last stage it reached.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum MissedStage {
    /// No frame segmented its cluster: hidden in part behind a nearer object whenever the
    /// laser saw it (such clusters are not judged), merged with another object into one
    /// cluster, or outside the image.
    NeverSegmented,
    /// Segmented, but never with the band above the laser in the image and clear of the
    /// image's edge: seen only from close by, or at the edge.
    NeverFullyJudged,
    /// Fully judged in fewer frames than confirm a landmark.
    JudgedTooRarely,
    /// Judged in enough frames, never observed as an object where it could start a
    /// landmark: the segmentation called it something else.
    JudgedNotATree,
    /// Observed as an object, yet no landmark is on it at the end: not confirmed, fused
    /// into another landmark, or retracted.
    ObservedNotMapped,
}

impl MissedStage {
    /// Its key in `map.missed_by_stage`.
    pub fn key(self) -> &'static str {
        match self {
            MissedStage::NeverSegmented => "never_segmented",
            MissedStage::NeverFullyJudged => "never_fully_judged",
            MissedStage::JudgedTooRarely => "judged_too_rarely",
            MissedStage::JudgedNotATree => "judged_not_a_tree",
            MissedStage::ObservedNotMapped => "observed_not_mapped",
        }
    }

    /// Its key for people: "never fully judged".
    pub fn in_words(self) -> String {
        self.key().replace('_', " ")
    }

    /// In the pipeline's order.
    pub const ALL: [MissedStage; 5] = [
        MissedStage::NeverSegmented,
        MissedStage::NeverFullyJudged,
        MissedStage::JudgedTooRarely,
        MissedStage::JudgedNotATree,
        MissedStage::ObservedNotMapped,
    ];
}

impl SegmentationScorer {
    pub fn new(tree_ids: BTreeSet<u16>, tree_class: u8, frames_needed: usize) -> Self {
        SegmentationScorer {
            tree_ids,
            tree_class,
            frames_needed,
            judged_frames: BTreeMap::new(),
            judged: BTreeSet::new(),
            segmented_frames: BTreeMap::new(),
            observed_frames: BTreeMap::new(),
            patches: PatchScores::default(),
        }
    }

    /// One segmented image: `clusters` are its scan's, `hit_ids` that scan's beams' truth,
    /// `frame` the class image of the latest frame (its patches are scored when it is the
    /// image segmented). Returns each segmented cluster's true object, in the record's order.
    pub fn on_record(
        &mut self,
        record: &SegmentationRecord,
        clusters: &[Cluster],
        hit_ids: &[u16],
        frame: Option<&ClassImage>,
    ) -> Vec<u16> {
        let objects: Vec<u16> = record
            .clusters
            .iter()
            .map(|cs| {
                let c = &clusters[cs.index];
                let obj = true_object(hit_ids, c.first_beam, c.last_beam);
                if !self.tree_ids.contains(&obj) {
                    return obj;
                }
                *self.segmented_frames.entry(obj).or_insert(0) += 1;
                // A tree counts in frames where the segmentation could judge its cluster:
                // its band in the image, not cut by the image's edge.
                let fully_judged = cs.band_visible && !cs.at_image_edge;
                if fully_judged {
                    let n = self.judged_frames.entry(obj).or_insert(0);
                    *n += 1;
                    if *n >= self.frames_needed {
                        self.judged.insert(obj);
                    }
                }
                // As the pipeline lets an observation start a landmark: judged fully, or
                // at a place the pooled evidence calls an object.
                if cs.observed && (fully_judged || cs.pooled.as_ref().is_some_and(|j| j.is_object)) {
                    *self.observed_frames.entry(obj).or_insert(0) += 1;
                }
                obj
            })
            .collect();
        if let Some(image) = frame.filter(|f| f.t == record.t_image) {
            for &(col, row, predicted) in &record.cells {
                self.patches.add(predicted, patch_is_tree(image, col, row, record.patch_size, self.tree_class));
            }
        }
        objects
    }

    /// Trees judged in enough frames.
    pub fn trees_judged(&self) -> usize {
        self.judged.len()
    }

    /// The last stage tree `id` reached (meant for trees that were not mapped).
    pub fn stage_reached(&self, id: u16) -> MissedStage {
        let count = |m: &BTreeMap<u16, usize>| m.get(&id).copied().unwrap_or(0);
        if count(&self.observed_frames) > 0 {
            MissedStage::ObservedNotMapped
        } else if self.judged.contains(&id) {
            MissedStage::JudgedNotATree
        } else if count(&self.judged_frames) > 0 {
            MissedStage::JudgedTooRarely
        } else if count(&self.segmented_frames) > 0 {
            MissedStage::NeverFullyJudged
        } else {
            MissedStage::NeverSegmented
        }
    }

    /// Patch precision and recall against the masks.
    pub fn patches(&self) -> PatchScores {
        self.patches
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam::pipeline::ClusterSegmentation;

    fn cluster(first_beam: usize, last_beam: usize) -> Cluster {
        Cluster {
            first_beam,
            last_beam,
            points: vec![],
            centre: [5.0, 0.0],
            diameter_m: 0.3,
            range_m: 5.0,
            bearing_rad: 0.0,
            occluded: false,
        }
    }

    fn judged(index: usize, band_visible: bool, at_image_edge: bool) -> ClusterSegmentation {
        ClusterSegmentation {
            index,
            is_object: true,
            hit_fraction: 1.0,
            above_fraction: 0.0,
            band_foliage_patches: 0,
            pooled: None,
            observed: true,
            band_visible,
            at_image_edge,
            row_profile: vec![],
            columns: (0, 1),
            hit_rows: (0, 0),
            posteriors: vec![],
        }
    }

    #[test]
    fn a_patch_is_tree_when_at_least_half_of_it_is() {
        // 4 x 2 pixels, patches of 2: the left patch all tree (class 1), the right one half.
        let class = [1, 1, 1, 0, 1, 1, 1, 0];
        let image = ClassImage { t: 0.0, width: 4, class: &class };
        assert!(patch_is_tree(&image, 0, 0, 2, 1));
        assert!(patch_is_tree(&image, 1, 0, 2, 1));
        // The left patch three quarters tree, the right one a quarter.
        let class = [1, 1, 1, 0, 1, 0, 0, 0];
        let image = ClassImage { t: 0.0, width: 4, class: &class };
        assert!(patch_is_tree(&image, 0, 0, 2, 1));
        assert!(!patch_is_tree(&image, 1, 0, 2, 1));
    }

    /// Trees count once judged in `frames_needed` frames, and only in frames where their
    /// band was visible and not at the image's edge; patches are scored only against the
    /// image the record segmented.
    #[test]
    fn trees_are_judged_in_enough_usable_frames_and_patches_against_their_own_image() {
        let mut s = SegmentationScorer::new([7, 8].into(), 1, 2);
        // Beams 0-2 hit tree 7, beams 3-5 tree 8, beams 6-7 a post (9).
        let hits = [7, 7, 7, 8, 8, 8, 9, 9];
        let clusters = [cluster(0, 2), cluster(3, 5), cluster(6, 7)];
        let class = [1, 1, 1, 1];
        let frame = ClassImage { t: 1.0, width: 2, class: &class };
        let record = |t_image: f64, edge_for_8: bool| SegmentationRecord {
            t_image,
            patch_size: 2,
            cells: vec![(0, 0, true)],
            clusters: vec![judged(0, true, false), judged(1, true, edge_for_8), judged(2, true, false)],
        };
        assert_eq!(s.on_record(&record(1.0, true), &clusters, &hits, Some(&frame)), [7, 8, 9]);
        assert_eq!(s.trees_judged(), 0);
        s.on_record(&record(2.0, true), &clusters, &hits, Some(&frame));
        // Tree 7 in two usable frames; tree 8 was at the image's edge in both.
        assert_eq!(s.trees_judged(), 1);
        s.on_record(&record(3.0, false), &clusters, &hits, None);
        assert_eq!(s.trees_judged(), 1);
        s.on_record(&record(4.0, false), &clusters, &hits, None);
        assert_eq!(s.trees_judged(), 2);
        // Only the first record's image was the frame given.
        assert_eq!(s.patches(), PatchScores { true_positives: 1, ..Default::default() });
    }

    /// Each unmapped tree is named at the last stage it reached: never segmented, only at
    /// the edge, judged once, judged enough but called something else, observed.
    #[test]
    fn missed_trees_are_named_by_the_last_stage_they_reached() {
        let mut s = SegmentationScorer::new([1, 2, 3, 4, 5].into(), 1, 2);
        // Trees 2-5 each hit by two beams; tree 1 never segmented.
        let hits = [2, 2, 3, 3, 4, 4, 5, 5];
        let clusters = [cluster(0, 1), cluster(2, 3), cluster(4, 5), cluster(6, 7)];
        let not_a_tree = |c: ClusterSegmentation| ClusterSegmentation { observed: false, is_object: false, ..c };
        for k in 0..2 {
            let record = SegmentationRecord {
                t_image: k as f64,
                patch_size: 2,
                cells: vec![],
                clusters: vec![
                    // 2: only at the image's edge (observed, but not where it could start a landmark).
                    judged(0, true, true),
                    // 3: fully judged in the first frame only, and called something else.
                    not_a_tree(judged(1, k == 0, false)),
                    // 4: fully judged in both, called something else in both.
                    not_a_tree(judged(2, true, false)),
                    // 5: observed in a fully judged frame.
                    judged(3, true, false),
                ],
            };
            s.on_record(&record, &clusters, &hits, None);
        }
        let stages: Vec<MissedStage> = (1..=5).map(|id| s.stage_reached(id)).collect();
        assert_eq!(stages, MissedStage::ALL);
    }
}
