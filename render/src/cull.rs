//! Frustum culling: bounding spheres of meshes and the view volume of the camera (or of
//! some of its pixels), to skip instances that cannot be seen.

use crate::math::{dot, dot3, normalised, rigid_inverse, sub, transform_point};
use crate::{Camera, Region};

/// The camera's view volume as planes through the optical centre (and near/far), in the
/// camera frame, to skip instances that cannot be seen (software rasterisers pay for them).
pub(crate) struct Frustum {
    camera_from_world: [[f32; 4]; 4],
    /// Unit inward normals of the four side planes, which pass through the origin.
    sides: [[f32; 3]; 4],
    near_m: f32,
    far_m: f32,
}

impl Frustum {
    pub(crate) fn new(c: &Camera, width: u32, height: u32) -> Self {
        Frustum::of_region(c, &Region::whole(width, height))
    }

    /// The view through the pixels of `region` only.
    pub(crate) fn of_region(c: &Camera, region: &Region) -> Self {
        let (u0, u1) = (region.columns.0 as f32, region.columns.1 as f32);
        let (v0, v1) = (region.rows.0 as f32, region.rows.1 as f32);
        // u >= u0: fx X + (cx - u0) Z >= 0; u <= u1: -fx X + (u1 - cx) Z >= 0; likewise for v.
        let sides = [[c.fx, 0.0, c.cx - u0], [-c.fx, 0.0, u1 - c.cx], [0.0, c.fy, c.cy - v0], [0.0, -c.fy, v1 - c.cy]]
            .map(|n| normalised(n).unwrap_or([0.0, 0.0, 1.0]));
        Frustum { camera_from_world: rigid_inverse(&c.world_from_camera), sides, near_m: c.near_m, far_m: c.far_m }
    }

    /// `None` if the bounding sphere is surely outside the view, else a near-to-far sort
    /// key: the z-distance of its nearest point, or `f32::MAX` for objects around the
    /// camera (ground, walls), which are large and best drawn last, behind the rest.
    pub(crate) fn distance_if_visible(
        &self,
        world_from_model: &[[f32; 4]; 4],
        centre: [f32; 3],
        radius: f32,
    ) -> Option<f32> {
        let scale = (0..3).map(|c| dot3(&world_from_model[c], &world_from_model[c]).sqrt()).fold(0.0f32, f32::max);
        let r = radius * scale;
        let p = transform_point(&self.camera_from_world, transform_point(world_from_model, centre));
        if !(r.is_finite() && p.iter().all(|v| v.is_finite())) {
            return Some(f32::MAX); // let the GPU decide; draw last
        }
        let visible = p[2] > self.near_m - r && p[2] < self.far_m + r && self.sides.iter().all(|n| dot(*n, p) > -r);
        let nearest = p[2] - r;
        visible.then_some(if nearest < self.near_m { f32::MAX } else { nearest })
    }
}

/// A sphere around all points (centre of the bounding box, max distance).
pub(crate) fn bounding_sphere(points: &[[f32; 3]]) -> ([f32; 3], f32) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let centre = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    let radius = points.iter().map(|p| dot(sub(*p, centre), sub(*p, centre))).fold(0.0f32, f32::max).sqrt();
    (centre, radius)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::tests::pose;

    #[test]
    fn frustum_rejects_what_is_behind_or_beside_the_camera() {
        let cam = Camera::look_at(50.0, 50.0, 50.0, 50.0, [0.0, 0.0, 1.0], [1.0, 0.0, 1.0]);
        let f = Frustum::new(&cam, 100, 100);
        let at = |x, y| pose(0.0, [x, y, 1.0]);
        let seen = |x, y| f.distance_if_visible(&at(x, y), [0.0; 3], 0.5);
        assert!((seen(5.0, 0.0).unwrap() - 4.5).abs() < 1e-5);
        assert_eq!(seen(-5.0, 0.0), None);
        // 45 degrees half field of view: y = 5 at x = 5 is at the edge; 8 is well outside.
        assert!(seen(5.0, 5.2).is_some());
        assert_eq!(seen(5.0, 8.0), None);
    }
}
