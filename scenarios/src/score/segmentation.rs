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
    patches: PatchScores,
}

impl SegmentationScorer {
    pub fn new(tree_ids: BTreeSet<u16>, tree_class: u8, frames_needed: usize) -> Self {
        SegmentationScorer {
            tree_ids,
            tree_class,
            frames_needed,
            judged_frames: BTreeMap::new(),
            judged: BTreeSet::new(),
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
                // A tree counts in frames where the segmentation could judge its cluster:
                // its band in the image, not cut by the image's edge.
                if self.tree_ids.contains(&obj) && cs.band_visible && !cs.at_image_edge {
                    let n = self.judged_frames.entry(obj).or_insert(0);
                    *n += 1;
                    if *n >= self.frames_needed {
                        self.judged.insert(obj);
                    }
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
}
