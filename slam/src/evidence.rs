//! Object evidence pooled over camera frames at one place of the map.
//!
//! One frame's segmentation of a cluster is noisy: a thin or distant trunk fills two of
//! three laser patches in one frame and all three in the next, and its band above the
//! laser is mostly but not always object. Judged frame by frame, a threshold that accepts
//! such trees also accepts palms and posts on their lucky frames. Pooled over the frames in
//! which the camera judged the same place, trees and look-alikes separate (the measured
//! means are in docs/results.md).

use serde::{Deserialize, Serialize};

/// Pooling settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvidenceConfig {
    /// Decide on the pooled evidence (true) or on each frame alone (false: the
    /// segmentation's own per-frame thresholds).
    pub pooled: bool,
    /// A frame joins the place whose centre (the mean of its frames' cluster centres, in
    /// the odometry frame, which does not jump when the filter corrects the map) is nearest
    /// and within this distance (m); otherwise it starts a new place.
    /// Under the distance between a post and the tree beside it.
    pub radius_m: f64,
    /// A place not judged for this long (s) is forgotten; odometry drift would otherwise
    /// leave old places where the object no longer appears.
    pub forget_after_s: f64,
    /// Fewest judged frames before a place's means decide.
    pub min_frames: usize,
    /// Until then: false, the place is not observed; true, each frame's own judgement
    /// decides (as in the paper). True gives look-alikes short-lived tentative landmarks,
    /// which steady the heading through turns where trees are few but take tree
    /// observations when a post stands beside its tree (`objslam montecarlo study`
    /// compares the two; docs/results.md).
    pub undecided_by_frame: bool,
    /// Mean fraction of laser patches that are object patches.
    pub min_hit_fraction: f64,
    /// A landmark is retracted when at least `retract_min_frames` frames of its place
    /// judged from nearer than `retract_range_m` have a mean hit fraction under
    /// `retract_max_hit_fraction` (see `Pipeline::retractions`): from 8-12 m a palm's trunk
    /// passes for bark, from nearer it does not (measured separation in docs/results.md).
    /// Palms first accepted from far are the usual false landmarks of the combined method
    /// on a long run (long_loop).
    pub retract: bool,
    pub retract_range_m: f64,
    pub retract_min_frames: usize,
    pub retract_max_hit_fraction: f64,
    /// Mean fraction of object patches in the band above the laser (see
    /// [`SegmentationConfig::above_band_from_m`](crate::segmentation::SegmentationConfig)).
    pub min_above_fraction: f64,
}

impl Default for EvidenceConfig {
    fn default() -> Self {
        EvidenceConfig {
            pooled: true,
            radius_m: 0.3,
            forget_after_s: 5.0,
            min_frames: 4,
            undecided_by_frame: false,
            retract: true,
            retract_range_m: 7.5,
            retract_min_frames: 8,
            retract_max_hit_fraction: 0.5,
            min_hit_fraction: 0.7,
            min_above_fraction: 0.6,
        }
    }
}

impl EvidenceConfig {
    /// The first setting that makes no sense, as (field, problem).
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        if !self.radius_m.is_finite() || self.radius_m <= 0.0 {
            return Err(("radius_m", format!("must be finite and positive, got {}", self.radius_m)));
        }
        if !(self.forget_after_s.is_finite() && self.forget_after_s > 0.0) {
            return Err(("forget_after_s", format!("must be finite and positive, got {}", self.forget_after_s)));
        }
        let max = crate::settings::MAX_COUNT;
        for (name, v) in [("min_frames", self.min_frames), ("retract_min_frames", self.retract_min_frames)] {
            if !(1..=max).contains(&v) {
                return Err((name, format!("must be 1 to {max}, got {v}")));
            }
        }
        if !self.retract_range_m.is_finite() || self.retract_range_m <= 0.0 {
            return Err(("retract_range_m", format!("must be finite and positive, got {}", self.retract_range_m)));
        }
        for (name, v) in [
            ("min_hit_fraction", self.min_hit_fraction),
            ("min_above_fraction", self.min_above_fraction),
            ("retract_max_hit_fraction", self.retract_max_hit_fraction),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err((name, format!("must be in [0, 1], got {v}")));
            }
        }
        Ok(())
    }
}

/// What the frames at one place say.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Judgement {
    pub frames: usize,
    pub mean_hit_fraction: f64,
    pub mean_above_fraction: f64,
    /// Enough frames, and both means at or above their thresholds.
    pub is_object: bool,
    /// Frames judged from nearer than `retract_range_m`, and their mean hit fraction.
    #[serde(default)]
    pub near_frames: usize,
    #[serde(default)]
    pub mean_near_hit_fraction: f64,
}

impl Judgement {
    /// Whether the frames from near enough say the place is not an object after all.
    pub fn retracts(&self, config: &EvidenceConfig) -> bool {
        config.retract
            && self.near_frames >= config.retract_min_frames
            && self.mean_near_hit_fraction < config.retract_max_hit_fraction
    }
}

#[derive(Debug, Clone, PartialEq)]
struct Place {
    centre: [f64; 2],
    frames: usize,
    hit_sum: f64,
    above_sum: f64,
    near_frames: usize,
    near_hit_sum: f64,
    last_t: f64,
}

/// The places judged recently and their pooled evidence.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ObjectEvidence {
    config: EvidenceConfig,
    places: Vec<Place>,
}

impl ObjectEvidence {
    pub fn new(config: EvidenceConfig) -> Self {
        ObjectEvidence { config, places: Vec::new() }
    }

    /// Adds one frame in which the camera judged the cluster at `centre` (odometry frame),
    /// `range_m` away (fractions as in
    /// [`SegmentedCluster`](crate::segmentation::SegmentedCluster)), and returns its
    /// place's judgement.
    pub fn add(&mut self, t: f64, centre: [f64; 2], range_m: f64, hit_fraction: f64, above_fraction: f64) -> Judgement {
        let i = match self.nearest(centre) {
            Some(i) => i,
            None => {
                self.places.push(Place {
                    centre,
                    frames: 0,
                    hit_sum: 0.0,
                    above_sum: 0.0,
                    near_frames: 0,
                    near_hit_sum: 0.0,
                    last_t: t,
                });
                self.places.len() - 1
            }
        };
        let p = &mut self.places[i];
        let n = p.frames as f64;
        p.centre = [(p.centre[0] * n + centre[0]) / (n + 1.0), (p.centre[1] * n + centre[1]) / (n + 1.0)];
        p.frames += 1;
        p.hit_sum += hit_fraction;
        p.above_sum += above_fraction;
        if range_m < self.config.retract_range_m {
            p.near_frames += 1;
            p.near_hit_sum += hit_fraction;
        }
        p.last_t = t;
        self.judgement(i)
    }

    /// The judgement of the place at `centre`, without adding a frame (for frames in which
    /// the camera could not judge the cluster); `None` where no place is.
    pub fn judge(&self, centre: [f64; 2]) -> Option<Judgement> {
        self.nearest(centre).map(|i| self.judgement(i))
    }

    /// Forgets the places not judged since `t - forget_after_s`.
    pub fn forget_before(&mut self, t: f64) {
        let horizon = t - self.config.forget_after_s;
        self.places.retain(|p| p.last_t >= horizon);
    }

    /// Number of places remembered (for the tests).
    #[cfg(test)]
    fn len(&self) -> usize {
        self.places.len()
    }

    fn nearest(&self, centre: [f64; 2]) -> Option<usize> {
        let d2 = |p: &Place| (p.centre[0] - centre[0]).powi(2) + (p.centre[1] - centre[1]).powi(2);
        let r2 = self.config.radius_m * self.config.radius_m;
        // Ties go to the older place (lower index), so the result does not depend on
        // anything but the order of frames.
        (0..self.places.len())
            .filter(|&i| d2(&self.places[i]) <= r2)
            .min_by(|&a, &b| d2(&self.places[a]).total_cmp(&d2(&self.places[b])).then(a.cmp(&b)))
    }

    fn judgement(&self, i: usize) -> Judgement {
        let p = &self.places[i];
        let n = p.frames.max(1) as f64;
        let (h, a) = (p.hit_sum / n, p.above_sum / n);
        let c = &self.config;
        let near = p.near_hit_sum / p.near_frames.max(1) as f64;
        Judgement {
            frames: p.frames,
            mean_hit_fraction: h,
            mean_above_fraction: a,
            is_object: p.frames >= c.min_frames && h >= c.min_hit_fraction && a >= c.min_above_fraction,
            near_frames: p.near_frames,
            mean_near_hit_fraction: near,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> EvidenceConfig {
        EvidenceConfig { min_frames: 3, ..EvidenceConfig::default() }
    }

    #[test]
    fn a_place_decides_only_after_enough_frames() {
        let mut e = ObjectEvidence::new(config());
        assert!(!e.add(0.0, [5.0, 1.0], 10.0, 1.0, 1.0).is_object);
        assert!(!e.add(0.2, [5.05, 1.0], 10.0, 1.0, 1.0).is_object);
        let j = e.add(0.4, [5.0, 1.05], 10.0, 1.0, 1.0);
        assert!(j.is_object);
        assert_eq!(j.frames, 3);
    }

    #[test]
    fn noisy_frames_of_a_trunk_pool_to_a_tree_and_a_posts_do_not() {
        let mut e = ObjectEvidence::new(config());
        // A thin trunk: two of three laser patches in most frames, the band mostly object.
        let trunk = [(0.67, 0.5), (1.0, 0.83), (0.67, 0.56), (0.67, 1.0), (1.0, 0.5)];
        // A post 0.6 m away: its laser patches look like bark, above it is background.
        let post = [(1.0, 0.0), (0.75, 0.0), (1.0, 0.25), (1.0, 0.0), (1.0, 0.0)];
        let (mut tree_j, mut post_j) = (None, None);
        for (k, (t, p)) in trunk.iter().zip(&post).enumerate() {
            tree_j = Some(e.add(k as f64 * 0.2, [6.0, 0.0], 10.0, t.0, t.1));
            post_j = Some(e.add(k as f64 * 0.2, [6.0, 0.6], 10.0, p.0, p.1));
        }
        assert_eq!(e.len(), 2, "the post and the tree are separate places");
        let (tree_j, post_j) = (tree_j.unwrap(), post_j.unwrap());
        assert!(tree_j.is_object, "{tree_j:?}");
        assert!(!post_j.is_object, "{post_j:?}");
        // Judged frame by frame with the segmentation's thresholds (0.75 hits, 0.6 band),
        // only one of the trunk's five frames would pass.
        assert_eq!(trunk.iter().filter(|(h, a)| *h >= 0.75 && *a >= 0.6).count(), 1);
    }

    #[test]
    fn places_not_judged_for_a_while_are_forgotten() {
        let mut e = ObjectEvidence::new(config());
        e.add(0.0, [1.0, 1.0], 10.0, 1.0, 1.0);
        e.add(4.0, [3.0, 1.0], 10.0, 1.0, 1.0);
        e.forget_before(5.5);
        assert_eq!(e.len(), 1);
        assert!(e.judge([1.0, 1.0]).is_none());
        assert_eq!(e.judge([3.1, 1.0]).map(|j| j.frames), Some(1));
    }

    #[test]
    fn nonsense_settings_are_named() {
        assert_eq!(EvidenceConfig { radius_m: 0.0, ..config() }.validate().unwrap_err().0, "radius_m");
        assert_eq!(EvidenceConfig { min_frames: 0, ..config() }.validate().unwrap_err().0, "min_frames");
        assert_eq!(
            EvidenceConfig { min_above_fraction: 1.5, ..config() }.validate().unwrap_err().0,
            "min_above_fraction"
        );
        assert!(config().validate().is_ok());
    }

    #[test]
    fn only_enough_frames_from_near_can_retract_a_place() {
        let config = EvidenceConfig::default();
        let mut e = ObjectEvidence::new(config.clone());
        // Far off the place looks like a trunk, then from nearer it does not.
        for k in 0..30 {
            assert!(!e.add(k as f64 * 0.2, [10.0, 0.0], 11.0, 1.0, 0.8).retracts(&config));
        }
        let mut j = None;
        for k in 0..config.retract_min_frames {
            j = Some(e.add(6.0 + k as f64 * 0.2, [10.0, 0.0], 6.0, 0.3, 0.2));
            assert_eq!(j.unwrap().retracts(&config), k + 1 == config.retract_min_frames, "frame {k}");
        }
        let j = j.unwrap();
        assert_eq!(j.near_frames, config.retract_min_frames);
        assert!((j.mean_near_hit_fraction - 0.3).abs() < 1e-12);
        // A trunk seen from near stays.
        let mut t = ObjectEvidence::new(config.clone());
        for k in 0..40 {
            assert!(!t.add(k as f64 * 0.2, [10.0, 0.0], 5.0, 0.7, 0.8).retracts(&config));
        }
        // Switched off, nothing retracts.
        let off = EvidenceConfig { retract: false, ..config };
        assert!(!j.retracts(&off));
    }
}
