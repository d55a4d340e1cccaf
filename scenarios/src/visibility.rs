//! Which trees a run could have mapped, from ground truth alone: the denominators of
//! `map.tree_recall`.
//!
//! A recall whose denominator comes from the method under test cannot show a recall
//! failure (a tree its segmentation never judged would simply not count), so both
//! denominators here are computed from the simulator's truth, whatever any method decides:
//! - *laser-seen*: a tree hit by at least `min_beams` beams within the clustering range at
//!   some scan (what a position-only method needs);
//! - *in view*: the same, at scans whose camera frame of the same instant shows that tree,
//!   in its ground-truth instance image, at the pixels those beams project to; in at least
//!   `frames_needed` such scans (what a camera method needs to confirm a landmark).

use std::collections::{BTreeMap, BTreeSet};

use nalgebra::Vector3;
use slam::features::PixelRegion;
use slam::segmentation::{CameraGeometry, merge_regions};

/// Counts, scan by scan, the trees the laser saw and the trees the camera showed where the
/// laser hit them.
#[derive(Clone)]
pub struct TreeVisibility {
    /// The camera with the simulator's exact extrinsics (absent without a camera).
    camera: Option<CameraGeometry>,
    /// Beams a tree needs in one scan: the fewest points that make a laser cluster.
    min_beams: usize,
    /// Beams count only within this true range (the clustering's range).
    max_range_m: f64,
    /// Scans a tree must be in view in: the observations a landmark needs to be confirmed.
    frames_needed: usize,
    tree_ids: BTreeSet<u16>,
    laser_seen: BTreeSet<u16>,
    in_view_scans: BTreeMap<u16, usize>,
    /// Pixels read in columns the camera did not render: must stay 0 (see `columns`).
    unrendered_reads: usize,
}

/// The ground-truth images of the latest camera frame, as [`TreeVisibility`] reads them.
pub struct InstanceImage<'a> {
    pub t: f64,
    pub width: u32,
    pub height: u32,
    /// Instance id per pixel, row-major.
    pub instance: &'a [u16],
    /// Regions rendered (`None`: all the image); outside them it holds no instance.
    pub regions: Option<&'a [render::Region]>,
}

impl TreeVisibility {
    /// `camera` carries the simulator's true laser <- camera extrinsics, never the run's
    /// calibration: what the camera shows is a fact of the world, not of the method.
    pub fn new(
        tree_ids: BTreeSet<u16>,
        camera: Option<CameraGeometry>,
        min_beams: usize,
        max_range_m: f64,
        frames_needed: usize,
    ) -> Self {
        TreeVisibility {
            camera,
            min_beams,
            max_range_m,
            frames_needed,
            tree_ids,
            laser_seen: BTreeSet::new(),
            in_view_scans: BTreeMap::new(),
            unrendered_reads: 0,
        }
    }

    /// The beams of `scan` that truly hit a tree within range: the beam's index, the
    /// tree's id and the point the beam hit in the laser frame.
    fn tree_beams<'a>(
        &'a self,
        angle_min: f64,
        angle_increment: f64,
        truth: &'a sim::LaserTruth,
    ) -> impl Iterator<Item = (usize, u16, Vector3<f64>)> + 'a {
        truth
            .hit_ids
            .iter()
            .zip(&truth.true_ranges)
            .enumerate()
            .filter(|(_, (id, r))| self.tree_ids.contains(id) && **r <= self.max_range_m)
            .map(move |(i, (id, r))| {
                let a = angle_min + i as f64 * angle_increment;
                (i, *id, Vector3::new(r * a.cos(), r * a.sin(), 0.0))
            })
    }

    /// The pixel a laser point projects to, if inside the image.
    fn pixel(camera: &CameraGeometry, p: &Vector3<f64>) -> Option<(u32, u32)> {
        let [u, v] = camera.project(p)?;
        (u >= 0.0 && v >= 0.0 && u < camera.width as f64 && v < camera.height as f64).then_some((u as u32, v as u32))
    }

    /// The pixels that [`TreeVisibility::on_scan`] will read in the frame of `scan`'s
    /// instant: a camera that renders only some regions must render these too, so that the
    /// count does not depend on which regions a method asked for.
    pub fn regions(&self, scan: &sim::LaserScan, truth: &sim::LaserTruth) -> Vec<PixelRegion> {
        let Some(camera) = &self.camera else { return vec![] };
        merge_regions(
            self.tree_beams(scan.angle_min, scan.angle_increment, truth)
                .filter_map(|(_, _, p)| Self::pixel(camera, &p))
                .map(|(u, v)| PixelRegion { columns: (u, u + 1), rows: (v, v + 1) })
                .collect(),
        )
    }

    /// Counts one scan; `frame` is the camera frame of the same instant, if there is one.
    pub fn on_scan(&mut self, scan: &sim::LaserScan, truth: &sim::LaserTruth, frame: Option<&InstanceImage>) {
        let shown = frame.map(|f| self.beams_shown(scan, truth, f));
        self.on_scan_shown(scan, truth, shown.as_deref());
    }

    /// The beams of `scan` that hit a tree within range and whose pixel in `frame` (the
    /// camera frame of the scan's instant) shows that same tree, in increasing order: the
    /// camera's part of the count, which a run writes to `trees_shown.jsonl` so that its
    /// output directory can be scored without its images. Empty without a camera.
    pub fn beams_shown(&mut self, scan: &sim::LaserScan, truth: &sim::LaserTruth, frame: &InstanceImage) -> Vec<usize> {
        let Some(camera) = &self.camera else { return vec![] };
        let mut shown = Vec::new();
        let mut unrendered = 0;
        for (i, id, p) in self.tree_beams(scan.angle_min, scan.angle_increment, truth) {
            let Some((u, v)) = Self::pixel(camera, &p) else { continue };
            if !frame.regions.is_none_or(|r| r.iter().any(|r| r.contains(u, v))) {
                unrendered += 1;
            } else if frame.instance[(v * frame.width + u) as usize] == id {
                shown.push(i);
            }
        }
        self.unrendered_reads += unrendered;
        shown
    }

    /// Counts one scan given the beams [`TreeVisibility::beams_shown`] found in the frame
    /// of its instant (`None`: no frame then).
    pub fn on_scan_shown(&mut self, scan: &sim::LaserScan, truth: &sim::LaserTruth, shown: Option<&[usize]>) {
        let mut beams: BTreeMap<u16, usize> = BTreeMap::new();
        for (_, id, _) in self.tree_beams(scan.angle_min, scan.angle_increment, truth) {
            *beams.entry(id).or_default() += 1;
        }
        for (id, n) in beams {
            if n >= self.min_beams {
                self.laser_seen.insert(id);
            }
        }
        if self.camera.is_none() {
            return;
        }
        let mut in_view: BTreeMap<u16, usize> = BTreeMap::new();
        // Only beams that count at all: on a tree, within range.
        for &i in shown.unwrap_or_default() {
            let (Some(id), Some(r)) = (truth.hit_ids.get(i), truth.true_ranges.get(i)) else { continue };
            if self.tree_ids.contains(id) && *r <= self.max_range_m {
                *in_view.entry(*id).or_default() += 1;
            }
        }
        for (id, n) in in_view {
            if n >= self.min_beams {
                *self.in_view_scans.entry(id).or_default() += 1;
            }
        }
    }

    /// Pixels the count needed from columns the camera did not render: a run with any
    /// would have a denominator that depends on what the method asked to render.
    pub fn unrendered_reads(&self) -> usize {
        self.unrendered_reads
    }

    /// Trees hit by enough beams within range at some scan.
    pub fn trees_laser_seen(&self) -> &BTreeSet<u16> {
        &self.laser_seen
    }

    /// Trees in the camera's view where the laser hit them in enough scans; `None` without
    /// a camera.
    pub fn trees_in_view(&self) -> Option<BTreeSet<u16>> {
        self.camera.as_ref()?;
        Some(self.in_view_scans.iter().filter(|(_, n)| **n >= self.frames_needed).map(|(id, _)| *id).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam::calibration::Extrinsics;

    /// A camera looking along the laser's x axis from the laser's origin (optical z forward,
    /// x right, y down), 100 px square, 90 degrees across.
    fn forward_camera() -> CameraGeometry {
        let phi = nalgebra::Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0);
        let laser_from_camera = Extrinsics::from_parts(&phi, &Vector3::zeros());
        CameraGeometry { fx: 50.0, fy: 50.0, cx: 50.0, cy: 50.0, width: 100, height: 100, laser_from_camera }
    }

    /// Five beams straight ahead (-2..2 degrees), the middle three hitting tree 7 at 3 m.
    fn scan_and_truth() -> (sim::LaserScan, sim::LaserTruth) {
        let inc = 1f64.to_radians();
        let scan = sim::LaserScan {
            t: 1.0,
            angle_min: -2.0 * inc,
            angle_increment: inc,
            time_increment: 0.0,
            scan_time: 0.1,
            range_min: 0.1,
            range_max: 80.0,
            ranges: vec![f64::INFINITY; 5],
        };
        let truth = sim::LaserTruth {
            hit_ids: vec![0, 7, 7, 7, 0],
            true_ranges: vec![f64::INFINITY, 3.0, 3.0, 3.0, f64::INFINITY],
        };
        (scan, truth)
    }

    fn image_of(id: u16) -> Vec<u16> {
        vec![id; 100 * 100]
    }

    fn whole(instance: &[u16]) -> InstanceImage<'_> {
        InstanceImage { t: 1.0, width: 100, height: 100, instance, regions: None }
    }

    #[test]
    fn a_tree_counts_in_view_only_where_its_instance_shows_at_the_beams() {
        let (scan, truth) = scan_and_truth();
        let mut v = TreeVisibility::new([7].into(), Some(forward_camera()), 3, 12.0, 2);
        let tree = image_of(7);
        let person = image_of(9);
        v.on_scan(&scan, &truth, Some(&whole(&person)));
        v.on_scan(&scan, &truth, Some(&whole(&tree)));
        assert_eq!(v.trees_in_view(), Some(BTreeSet::new()), "one scan in view of two needed");
        v.on_scan(&scan, &truth, None);
        assert_eq!(v.trees_in_view(), Some(BTreeSet::new()), "a scan without a frame of its instant shows nothing");
        v.on_scan(&scan, &truth, Some(&whole(&tree)));
        assert_eq!(v.trees_in_view(), Some([7].into()));
        assert_eq!(v.trees_laser_seen(), &BTreeSet::from([7]));
    }

    #[test]
    fn beams_beyond_the_range_or_too_few_do_not_count() {
        let (scan, truth) = scan_and_truth();
        let mut far = TreeVisibility::new([7].into(), None, 3, 2.5, 1);
        far.on_scan(&scan, &truth, None);
        assert!(far.trees_laser_seen().is_empty());
        assert_eq!(far.trees_in_view(), None, "no camera: undefined, not empty");
        let mut four = TreeVisibility::new([7].into(), None, 4, 12.0, 1);
        four.on_scan(&scan, &truth, None);
        assert!(four.trees_laser_seen().is_empty());
    }

    #[test]
    fn the_pixels_read_are_those_the_tree_beams_project_to() {
        let (scan, truth) = scan_and_truth();
        let v = TreeVisibility::new([7].into(), Some(forward_camera()), 3, 12.0, 1);
        let regions = v.regions(&scan, &truth);
        // Beams at -1, 0, +1 degrees: u = 50 - 50 tan(a) (y left is image left), all in
        // the laser's row.
        assert_eq!(regions.len(), 1, "{regions:?}");
        let r = regions[0];
        assert!(r.columns.0 >= 48 && r.columns.1 <= 52 && r.rows.1 == r.rows.0 + 1, "{regions:?}");
        // Only those pixels rendered: the count is the same as with the whole frame.
        let img = image_of(7);
        let mut all_pixels = TreeVisibility::new([7].into(), Some(forward_camera()), 3, 12.0, 1);
        let mut some_pixels = TreeVisibility::new([7].into(), Some(forward_camera()), 3, 12.0, 1);
        all_pixels.on_scan(&scan, &truth, Some(&whole(&img)));
        let mut masked = vec![0u16; 100 * 100];
        for v in r.rows.0..r.rows.1 {
            for u in r.columns.0..r.columns.1 {
                masked[(v * 100 + u) as usize] = 7;
            }
        }
        let rendered = [render::Region { columns: r.columns, rows: r.rows }];
        some_pixels.on_scan(
            &scan,
            &truth,
            Some(&InstanceImage { t: 1.0, width: 100, height: 100, instance: &masked, regions: Some(&rendered) }),
        );
        assert_eq!(some_pixels.unrendered_reads(), 0);
        assert_eq!(all_pixels.trees_in_view(), some_pixels.trees_in_view());
        assert_eq!(all_pixels.trees_in_view(), Some([7].into()));
    }
}
