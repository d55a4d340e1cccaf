//! Laser rays against the scene: the collider tree prunes as rapier's own query does, and
//! each candidate answers by its shape. Cylinders (trunks, posts, palms, people's legs and
//! bodies: most of what a park's beams reach) are solved in closed form: parry casts rays
//! on them by GJK, an iteration that stops within its tolerance (a millimetre or two off the
//! surface) and cost the laser most of its time. The closed form is exact up to rounding.

use std::cell::Cell;

use rapier3d::parry::shape::{Cylinder, TypedCompositeShape};
use rapier3d::prelude::*;

/// The first hit of `ray` (origin and direction in f64, the direction of any length: times
/// are in its units, as parry's) within `max_toi`, as (collider, time of impact). Solid
/// shapes: a ray starting inside one hits it at 0.
pub(crate) fn first_hit(
    query: &QueryPipeline<'_>,
    origin: [f64; 3],
    dir: [f64; 3],
    max_toi: f64,
) -> Option<(ColliderHandle, f64)> {
    let v = |p: [f64; 3]| Vector::new(p[0] as f32, p[1] as f32, p[2] as f32);
    let ray = Ray::new(v(origin), v(dir));
    let best: Cell<Option<(u32, f64)>> = Cell::new(None);
    // The tree orders and prunes by the f32 times it is given; the exact f64 time of the
    // best hit so far is kept beside it, so no rounding decides which hit is first.
    let _ = query.bvh.cast_ray(&ray, max_toi as f32, |leaf, _| {
        let toi = query.map_typed_part_at(leaf, |pose, shape, _| {
            let pose = pose.copied().unwrap_or(Pose::IDENTITY);
            let limit = best.get().map_or(max_toi, |(_, t)| t);
            match shape.as_cylinder() {
                Some(c) => cast_cylinder(&pose, c, origin, dir, limit),
                None => shape.cast_ray(&pose, &ray, limit as f32, true).map(f64::from),
            }
        })??;
        if best.get().is_none_or(|(_, t)| toi < t) {
            best.set(Some((leaf, toi)));
        }
        Some(toi as f32)
    });
    let (leaf, toi) = best.get().filter(|&(_, t)| t < max_toi)?;
    query.colliders.get_unknown_gen(leaf).map(|(_, handle)| (handle, toi))
}

/// Where a ray first meets a solid cylinder (parry's: along its local y axis, centred on
/// its origin) placed at `pose`, if within `max_toi`.
fn cast_cylinder(pose: &Pose, c: &Cylinder, origin: [f64; 3], dir: [f64; 3], max_toi: f64) -> Option<f64> {
    // Into the cylinder's frame, in f64: p = R^T (x - t).
    let r = pose.rotation;
    let axes = [r * Vector::X, r * Vector::Y, r * Vector::Z].map(|a| [a.x as f64, a.y as f64, a.z as f64]);
    let t = [pose.translation.x as f64, pose.translation.y as f64, pose.translation.z as f64];
    let rel = [origin[0] - t[0], origin[1] - t[1], origin[2] - t[2]];
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let o = axes.map(|a| dot(a, rel));
    let d = axes.map(|a| dot(a, dir));
    let (radius, half) = (c.radius as f64, c.half_height as f64);
    let toi = ray_solid_cylinder([o[0], o[2]], o[1], [d[0], d[2]], d[1], radius, half)?;
    (toi <= max_toi).then_some(toi)
}

/// The first time t >= 0 at which o + t d is in the solid cylinder x^2 + z^2 <= r^2,
/// |y| <= h, given the ray's (x, z) and y parts apart.
fn ray_solid_cylinder(o_xz: [f64; 2], o_y: f64, d_xz: [f64; 2], d_y: f64, r: f64, h: f64) -> Option<f64> {
    // The times inside the infinite cylinder.
    let a = d_xz[0] * d_xz[0] + d_xz[1] * d_xz[1];
    let b = o_xz[0] * d_xz[0] + o_xz[1] * d_xz[1];
    let c = o_xz[0] * o_xz[0] + o_xz[1] * o_xz[1] - r * r;
    let (mut t_in, mut t_out) = if a == 0.0 {
        if c > 0.0 {
            return None;
        }
        (f64::NEG_INFINITY, f64::INFINITY)
    } else {
        let disc = b * b - a * c;
        if disc < 0.0 {
            return None;
        }
        // The root far from cancellation first, the other from the roots' product c / a.
        let q = -(b + b.signum() * disc.sqrt());
        if q == 0.0 {
            (0.0, 0.0)
        } else {
            let (t0, t1) = (q / a, c / q);
            (t0.min(t1), t0.max(t1))
        }
    };
    // The times between the caps.
    if d_y == 0.0 {
        if o_y.abs() > h {
            return None;
        }
    } else {
        let (t0, t1) = ((-h - o_y) / d_y, (h - o_y) / d_y);
        t_in = t_in.max(t0.min(t1));
        t_out = t_out.min(t0.max(t1));
    }
    (t_in <= t_out && t_out >= 0.0).then_some(t_in.max(0.0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use rapier3d::parry::query::{PointQuery, RayCast};

    #[test]
    fn a_horizontal_ray_meets_an_upright_cylinder_where_geometry_says() {
        // Axis along y: a ray along x at height 0.5, 3 m from the axis, radius 0.4.
        let hit = ray_solid_cylinder([-3.0, 0.0], 0.5, [1.0, 0.0], 0.0, 0.4, 1.0).unwrap();
        assert!((hit - 2.6).abs() < 1e-12, "{hit}");
        // Offset sideways by 0.3: enters at 3 - sqrt(0.16 - 0.09).
        let hit = ray_solid_cylinder([-3.0, 0.3], 0.5, [1.0, 0.0], 0.0, 0.4, 1.0).unwrap();
        assert!((hit - (3.0 - 0.07f64.sqrt())).abs() < 1e-12, "{hit}");
        // Above the top, beside it, behind the origin: no hit.
        assert_eq!(ray_solid_cylinder([-3.0, 0.0], 1.2, [1.0, 0.0], 0.0, 0.4, 1.0), None);
        assert_eq!(ray_solid_cylinder([-3.0, 0.5], 0.0, [1.0, 0.0], 0.0, 0.4, 1.0), None);
        assert_eq!(ray_solid_cylinder([3.0, 0.0], 0.0, [1.0, 0.0], 0.0, 0.4, 1.0), None);
        // From inside: 0. Down the axis from above: the top cap.
        assert_eq!(ray_solid_cylinder([0.1, 0.0], 0.0, [1.0, 0.0], 0.0, 0.4, 1.0), Some(0.0));
        assert_eq!(ray_solid_cylinder([0.0, 0.0], 3.0, [0.0, 0.0], -2.0, 0.4, 1.0), Some(1.0));
        // Through a cap at a slant: enters by the bottom cap at y = -1.
        let hit = ray_solid_cylinder([-0.2, 0.0], -2.0, [0.1, 0.0], 1.0, 0.4, 1.0).unwrap();
        assert!((hit - 1.0).abs() < 1e-12, "{hit}");
    }

    proptest! {
        /// The closed form finds the surface itself (parry's GJK cast stops within its
        /// tolerance, up to a millimetre or two off it, more along a slanting
        /// ray), finds the entry parry finds on cylinders in any pose, and judges hit or
        /// miss as parry does except for rays that graze the surface.
        #[test]
        fn the_closed_form_finds_the_surface_and_agrees_with_parry(
            radius in 0.05f32..1.0,
            half in 0.2f32..5.0,
            centre in prop::array::uniform3(-20.0f32..20.0),
            tilt in prop::array::uniform3(-0.3f32..0.3),
            from in prop::array::uniform3(-30.0f32..30.0),
            aim in prop::array::uniform3(-1.5f32..1.5),
        ) {
            let cylinder = Cylinder::new(half, radius);
            let pose = Pose::from_parts(
                Vector::new(centre[0], centre[1], centre[2]),
                Rotation::from_scaled_axis(Vector::new(std::f32::consts::FRAC_PI_2 + tilt[0], tilt[1], tilt[2])),
            );
            // Aimed near the cylinder, so most rays hit it and some graze it.
            let dir: [f32; 3] = std::array::from_fn(|k| centre[k] + aim[k] - from[k]);
            let length = dir.iter().map(|v| v * v).sum::<f32>().sqrt();
            prop_assume!(length > 0.1);
            let dir = dir.map(|v| (v / length) as f64);
            let origin = from.map(f64::from);
            let at = |t: f64| -> Vector {
                let p: [f64; 3] = std::array::from_fn(|k| origin[k] + t * dir[k]);
                Vector::new(p[0] as f32, p[1] as f32, p[2] as f32)
            };
            let ray = Ray::new(at(0.0), Vector::new(dir[0] as f32, dir[1] as f32, dir[2] as f32));
            let theirs = cylinder.cast_ray(&pose, &ray, 100.0, true).map(f64::from);
            let ours = cast_cylinder(&pose, &cylinder, origin, dir, 100.0);
            if let Some(t) = ours.filter(|&t| t > 0.0) {
                let off = cylinder.distance_to_point(&pose, at(t), false);
                prop_assert!(off < 1e-4, "the hit at {t} is {off} m off the surface");
                prop_assert!(cylinder.distance_to_point(&pose, at(t - 1e-3), true) > 0.0, "inside before the hit at {t}");
            }
            match (theirs, ours) {
                (Some(a), Some(b)) => {
                    // The same entry: parry's point and the middle between the two lie
                    // within its tolerance of the surface (along a slanting ray that can
                    // be millimetres apart).
                    let off = |t: f64| cylinder.distance_to_point(&pose, at(t), false);
                    prop_assert!(off(a) < 2e-3 && off(0.5 * (a + b)) < 2e-3, "parry {a}, closed form {b}");
                }
                (None, None) => {}
                (a, b) => {
                    // A grazing ray: where one of the two hits, it is within GJK's
                    // tolerance of the surface.
                    let t = a.or(b).expect("one hit");
                    let off = cylinder.distance_to_point(&pose, at(t), false);
                    prop_assert!(off < 2e-3, "parry {a:?}, closed form {b:?}, {off} m off the surface");
                }
            }
        }
    }
}
