//! Laser-camera segmentation (paper section 4.1): a laser cluster's points are projected
//! into the image with K and the extrinsics (P_l = Phi P_c + Delta); the patches at those
//! points and all patches in the same image columns are classified; the cluster is an
//! object of interest when enough of the patches its points fall in are object patches.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::calibration::Extrinsics;
use crate::classifier::PatchClassifier;
use crate::clustering::Cluster;
use crate::features::{FeatureError, FeatureExtractor, ImageRef, PatchFeatures, PatchRect};

/// The camera as the pipeline knows it: pinhole intrinsics K and the laser <- camera
/// extrinsics (Phi, Delta). The camera frame is optical: z forward, x right, y down.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraGeometry {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
    pub laser_from_camera: Extrinsics,
}

impl CameraGeometry {
    /// Pixel (u, v) of a laser-frame point, if it lies in front of the camera.
    pub fn project(&self, p_laser: &Vector3<f64>) -> Option<[f64; 2]> {
        let p = self.laser_from_camera.laser_to_camera(p_laser);
        (p.z > 1e-6).then(|| [self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy])
    }

    /// The ray through pixel (u, v) in the laser frame: origin and unit direction.
    pub fn ray(&self, u: f64, v: f64) -> (Vector3<f64>, Vector3<f64>) {
        let d_cam = Vector3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0);
        let d = (self.laser_from_camera.phi() * d_cam).normalize();
        (self.laser_from_camera.delta(), d)
    }

    /// Where the ray through (u, v) meets the vertical plane through the laser-frame point
    /// `centre` facing the laser (the object's visible face, to first order).
    pub fn point_on_object_plane(&self, u: f64, v: f64, centre: [f64; 2]) -> Option<Vector3<f64>> {
        let (o, d) = self.ray(u, v);
        let r = (centre[0].powi(2) + centre[1].powi(2)).sqrt();
        if r < 1e-9 {
            return None;
        }
        let n = Vector3::new(centre[0] / r, centre[1] / r, 0.0);
        let denom = n.dot(&d);
        (denom > 1e-6).then(|| o + d * ((r - n.dot(&o)) / denom))
    }
}

/// Segmentation settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SegmentationConfig {
    /// A cluster is an object when at least this fraction of the patches its laser points
    /// fall in are object patches...
    pub min_hit_fraction: f64,
    /// ...and at least this many object patches lie in its columns...
    pub min_object_patches: usize,
    /// ...and at least this fraction of the patches above the laser's rows in its columns,
    /// up to `above_band_m`, are object patches: a trunk goes on up the image, while posts,
    /// people and most look-alikes end near the laser plane with background above them.
    pub min_above_fraction: f64,
    /// Height above the laser plane (m), at the cluster's range, up to which the patches
    /// above it are judged; higher rows (a far tree's canopy) are not. 2.6 m reaches half a
    /// metre above the park's tallest post (2.5 m from the ground, laser at 0.4 m) and
    /// stays below most canopies.
    pub above_band_m: f64,
    /// Extra patch columns classified on each side of the projected points.
    pub column_margin: u32,
    /// A patch is an object patch when R exceeds this; absent: the classifier's own threshold.
    /// Deciding a cluster wants confident patches: 0.85 rather than the classifier's 0.5
    /// halved the frames in which a look-alike post passed on paper_park.
    pub patch_threshold: Option<f64>,
}

impl Default for SegmentationConfig {
    fn default() -> Self {
        SegmentationConfig { min_hit_fraction: 0.75, min_object_patches: 4, min_above_fraction: 0.6, above_band_m: 2.6, column_margin: 0, patch_threshold: Some(0.85) }
    }
}

/// The segmentation of one cluster.
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentedCluster {
    /// The classified columns (whole image height).
    pub rect: PatchRect,
    pub features: PatchFeatures,
    /// R per patch of `rect` (row-major).
    pub posteriors: Vec<f64>,
    /// Object decision per patch of `rect`.
    pub object: Vec<bool>,
    /// Distinct patches (col, row) the cluster's laser points project into.
    pub hit_patches: Vec<(u32, u32)>,
    pub hit_fraction: f64,
    /// Fraction of object patches above the highest laser row, in the classified columns.
    pub above_fraction: f64,
    pub is_object: bool,
}

impl SegmentedCluster {
    /// Indices (into `features.z` rows) of the object patches.
    pub fn object_rows(&self) -> Vec<usize> {
        (0..self.object.len()).filter(|&i| self.object[i]).collect()
    }
}

/// Segments one cluster. Returns `Ok(None)` when none of its points projects into the
/// image (the cluster is outside the camera's field of view).
pub fn segment_cluster(cluster: &Cluster, image: &ImageRef, extractor: &FeatureExtractor, classifier: &PatchClassifier, geometry: &CameraGeometry, config: &SegmentationConfig) -> Result<Option<SegmentedCluster>, FeatureError> {
    let l = extractor.config.patch_size;
    let (cols, rows) = image.grid(l);
    let mut hits: Vec<(u32, u32)> = Vec::new();
    for p in &cluster.points {
        if let Some([u, v]) = geometry.project(&Vector3::new(p[0], p[1], 0.0)) {
            if u >= 0.0 && v >= 0.0 && u < (cols * l) as f64 && v < (rows * l) as f64 {
                let cell = ((u / l as f64) as u32, (v / l as f64) as u32);
                if !hits.contains(&cell) {
                    hits.push(cell);
                }
            }
        }
    }
    if hits.is_empty() {
        return Ok(None);
    }
    let c0 = hits.iter().map(|h| h.0).min().expect("non-empty").saturating_sub(config.column_margin);
    let c1 = (hits.iter().map(|h| h.0).max().expect("non-empty") + 1 + config.column_margin).min(cols);
    let rect = PatchRect::columns(image, l, c0, c1);
    let features = extractor.features(image, Some(rect))?;
    let posteriors = classifier.posteriors(&features);
    let threshold = config.patch_threshold.unwrap_or(classifier.threshold);
    let object: Vec<bool> = posteriors.iter().map(|&r| r > threshold).collect();
    let hit_objects = hits.iter().filter(|&&(c, r)| features.index(c, r).is_some_and(|i| object[i])).count();
    let hit_fraction = hit_objects as f64 / hits.len() as f64;
    let n_object = object.iter().filter(|&&o| o).count();
    let top_hit_row = hits.iter().map(|h| h.1).min().expect("non-empty");
    // The image row of the band's top above the cluster's centre (rows grow downwards).
    let band_top_row = geometry.project(&Vector3::new(cluster.centre[0], cluster.centre[1], config.above_band_m)).map_or(0.0, |[_, v]| (v / l as f64).floor().max(0.0)) as u32;
    let above: Vec<bool> = (0..object.len()).filter(|&i| (band_top_row..top_hit_row).contains(&rect.patch(i).1)).map(|i| object[i]).collect();
    // A cluster hit in the top row has nothing above it to judge by: its hits decide alone.
    let above_fraction = if above.is_empty() { hit_fraction } else { above.iter().filter(|&&o| o).count() as f64 / above.len() as f64 };
    let is_object = hit_fraction >= config.min_hit_fraction && n_object >= config.min_object_patches && above_fraction >= config.min_above_fraction;
    Ok(Some(SegmentedCluster { rect, features, posteriors, object, hit_patches: hits, hit_fraction, above_fraction, is_object }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;

    /// Camera looking along the laser's x axis, 0.3 m above it: optical z = laser x,
    /// optical x = -laser y, optical y = -laser z.
    fn geometry() -> CameraGeometry {
        let phi = Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0);
        CameraGeometry { fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0, width: 640, height: 480, laser_from_camera: Extrinsics::from_parts(&phi, &Vector3::new(0.0, 0.0, 0.3)) }
    }

    #[test]
    fn projection_and_ray_are_inverse() {
        let g = geometry();
        let p = Vector3::new(4.0, 0.5, -0.1);
        let [u, v] = g.project(&p).unwrap();
        // A point straight ahead at the laser's height lands below the image centre.
        let [_, v0] = g.project(&Vector3::new(5.0, 0.0, 0.0)).unwrap();
        assert!(v0 > 240.0);
        let (o, d) = g.ray(u, v);
        let t = (p - o).norm();
        assert!((o + d * t - p).norm() < 1e-9);
        assert!(g.project(&Vector3::new(-3.0, 0.0, 0.0)).is_none(), "behind the camera");
    }

    #[test]
    fn object_plane_point_recovers_a_point_on_the_plane() {
        let g = geometry();
        let centre = [5.0, 1.0];
        let p = Vector3::new(5.0 - 0.2 * 1.0 / 26f64.sqrt(), 1.0 + 0.2 * 5.0 / 26f64.sqrt(), 0.7); // on the plane, 0.2 m sideways
        let [u, v] = g.project(&p).unwrap();
        let q = g.point_on_object_plane(u, v, centre).unwrap();
        assert!((q - p).norm() < 1e-9, "{q} vs {p}");
    }
}
