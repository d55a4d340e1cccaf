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

    /// A scene of upright and tilted cylinders, a box, a ball and an excluded body, crossed
    /// by a fan of rays: the same collider as rapier's own cast, at the same time up to
    /// parry's GJK tolerance on cylinders (exactly elsewhere), and nothing of the excluded
    /// body.
    #[test]
    fn the_first_hit_is_rapiers_but_for_the_time_on_cylinders() {
        let mut world = PhysicsWorld::new();
        let fixed = world.insert_body(RigidBodyBuilder::fixed());
        let upright = Rotation::from_rotation_x(std::f32::consts::FRAC_PI_2);
        let shapes = [
            ColliderBuilder::cylinder(1.0, 0.3).position(Pose::from_parts(Vector::new(4.0, 0.5, 1.0), upright)),
            ColliderBuilder::cylinder(2.0, 0.1).position(Pose::from_parts(Vector::new(7.0, -1.0, 2.0), upright)),
            ColliderBuilder::cylinder(1.0, 0.4)
                .position(Pose::from_parts(Vector::new(6.0, 2.0, 0.5), Rotation::from_rotation_y(0.4) * upright)),
            ColliderBuilder::cuboid(0.5, 0.5, 1.0).translation(Vector::new(5.0, -3.0, 1.0)),
            ColliderBuilder::ball(0.6).translation(Vector::new(9.0, 0.0, 0.4)),
        ];
        for shape in shapes {
            world.insert_collider(shape, Some(fixed));
        }
        let excluded = world.insert_body(RigidBodyBuilder::fixed().translation(Vector::new(3.0, -0.5, 0.0)));
        world.insert_collider(
            ColliderBuilder::cylinder(1.0, 0.2).position(Pose::from_parts(Vector::new(0.0, 0.0, 1.0), upright)),
            Some(excluded),
        );
        world.step();
        let filter = QueryFilter::default().exclude_rigid_body(excluded);
        let query = world.query_pipeline_with_filter(filter);
        let (mut hits, mut on_cylinders) = (0, 0);
        for k in 0..=720 {
            let a = (k as f64 / 720.0 - 0.5) * 2.0;
            let (origin, dir) = ([0.0, 0.0, 0.4 + 0.1 * (k % 13) as f64], [a.cos(), a.sin(), 0.0]);
            let v = |p: [f64; 3]| Vector::new(p[0] as f32, p[1] as f32, p[2] as f32);
            let theirs = query.cast_ray(&Ray::new(v(origin), v(dir)), 30.0, true);
            let ours = first_hit(&query, origin, dir, 30.0);
            match (theirs, ours) {
                (Some((h, a)), Some((g, b))) => {
                    assert_eq!(h, g, "ray {k}: another collider");
                    let cylinder = world.colliders[h].shape().as_cylinder().is_some();
                    let tolerance = if cylinder { 3e-3 } else { 1e-5 };
                    assert!((a as f64 - b).abs() < tolerance, "ray {k}: {a} against {b}");
                    assert_ne!(world.colliders[h].parent(), Some(excluded));
                    hits += 1;
                    on_cylinders += cylinder as usize;
                }
                (None, None) => {}
                (a, b) => panic!("ray {k}: rapier {a:?}, closed form {b:?}"),
            }
        }
        assert!(
            hits > 200 && on_cylinders > 100 && hits > on_cylinders + 50,
            "{hits} hits, {on_cylinders} on cylinders"
        );
    }

    proptest! {
        // A fixed seed: the same cases on every run.
        #![proptest_config(ProptestConfig {
            cases: 2000,
            rng_seed: proptest::test_runner::RngSeed::Fixed(20261204),
            ..ProptestConfig::default()
        })]
        /// The closed form finds the surface itself where the ray enters (parry's GJK cast
        /// stops within its tolerance, a millimetre or two off it, more along a slanting
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
            // Signed: negative inside.
            let off = |t: f64| cylinder.distance_to_point(&pose, at(t), false);
            let outside = |t: f64| cylinder.distance_to_point(&pose, at(t), true) > 0.0;
            let ray = Ray::new(at(0.0), Vector::new(dir[0] as f32, dir[1] as f32, dir[2] as f32));
            let theirs = cylinder.cast_ray(&pose, &ray, 100.0, true).map(f64::from);
            let ours = cast_cylinder(&pose, &cylinder, origin, dir, 100.0);
            if let Some(t) = ours.filter(|&t| t > 0.0) {
                prop_assert!(off(t).abs() < 1e-4, "the hit at {t} is {} m off the surface", off(t));
                prop_assert!(outside(t - 1e-3), "inside before the hit at {t}");
            }
            // How deep the ray goes into the cylinder after `t` (0 if it does not enter).
            let depth_after = |t: f64| (1..=2000).map(|k| off(t + 1e-3 * k as f64)).fold(0.0f32, f32::min).abs();
            match (theirs, ours) {
                (Some(a), Some(b)) => {
                    // The same entry: parry's point lies within its tolerance of the
                    // surface, and so does every point between the two.
                    prop_assert!(off(a).abs() < 2.5e-3, "parry's hit at {a} is {} m off the surface", off(a));
                    let (lo, hi) = (a.min(b), a.max(b));
                    let worst = (0..=10).map(|k| off(lo + (hi - lo) * k as f64 / 10.0).abs()).fold(0.0f32, f32::max);
                    prop_assert!(worst < 2.5e-3, "parry {a}, closed form {b}: {worst} m off the surface between");
                }
                (None, None) => {}
                (Some(a), None) => {
                    // parry's hit on a ray that misses: it passes within its tolerance.
                    prop_assert!(off(a) > 0.0 && off(a) < 2.5e-3, "parry {a} on a miss, {} m off", off(a));
                }
                (None, Some(b)) => {
                    // parry misses a ray that enters: the ray only grazes the cylinder.
                    prop_assert!(depth_after(b) < 2.5e-3, "parry misses a ray {} m deep", depth_after(b));
                }
            }
        }
    }
}
