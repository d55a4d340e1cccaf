//! Bringing a user's mesh into a world as an object (`objslam world import`): the camera
//! renders the mesh, and a shape fitted to it gives the collider the laser sees.

use crate::description::{Appearance, LoadedMesh, Material, ObjectClass, Pose2, Shape, StaticObject, World};
use crate::mesh::TriMesh;

/// Height of the slice (m above the ground) whose footprint sizes a trunk or a post: the
/// part a laser a few decimetres up sees.
pub const BASE_SLICE_M: f64 = 1.0;

/// Triangles whose area is at most this fraction of their longest edge squared are left
/// out of a mesh's extent: three points on a line (a modelling slip), which the
/// single-precision vertices of a file leave about 1e-7 of an edge off the line, draw
/// nothing, and would size the collider with a surface no camera sees. A blade of grass
/// 1 m long and 1 mm wide is 5e-4 of its edge squared.
const MIN_TRIANGLE_AREA_PER_EDGE2: f64 = 1e-6;

/// What the mesh's surface says of its size, in its own frame (z up, origin on the ground
/// at the object's pose): only triangles with area count, so vertices no triangle uses
/// and triangles of no area change nothing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshExtent {
    /// Farthest point of the surface from the vertical axis between the ground and
    /// [`BASE_SLICE_M`] (m): the triangles are cut to that slice, so a trunk sunk a little
    /// into the ground, whose vertices lie only below and far above it, is measured too.
    pub base_radius_m: f64,
    /// Farthest point of the surface from the vertical axis anywhere (m).
    pub radius_m: f64,
    /// Highest point (m).
    pub top_m: f64,
    /// Half extents along x and y (m), about the origin.
    pub half_x_m: f64,
    pub half_y_m: f64,
}

/// The mesh's extent; an error for a mesh with no surface, none above the ground or none
/// in the base slice (a mesh not standing on its origin).
pub fn extent(mesh: &TriMesh) -> Result<MeshExtent, String> {
    if mesh.positions.iter().flatten().any(|v| !v.is_finite()) {
        return Err("the mesh has a vertex that is not a finite number".into());
    }
    let mut e =
        MeshExtent { base_radius_m: 0.0, radius_m: 0.0, top_m: f64::NEG_INFINITY, half_x_m: 0.0, half_y_m: 0.0 };
    let (mut surfaces, mut in_base) = (0usize, false);
    for t in mesh.indices.chunks_exact(3) {
        let mut triangle = [[0.0f64; 3]; 3];
        for (corner, &i) in triangle.iter_mut().zip(t) {
            let p = mesh.positions.get(i as usize).ok_or_else(|| format!("the mesh's index {i} names no vertex"))?;
            *corner = p.map(f64::from);
        }
        let [a, b, c] = triangle;
        let edge2 = |p: [f64; 3], q: [f64; 3]| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>();
        let longest2 = edge2(a, b).max(edge2(b, c)).max(edge2(c, a));
        if area(&triangle) <= MIN_TRIANGLE_AREA_PER_EDGE2 * longest2 {
            continue;
        }
        surfaces += 1;
        for [x, y, z] in triangle {
            e.radius_m = e.radius_m.max(x.hypot(y));
            e.top_m = e.top_m.max(z);
            e.half_x_m = e.half_x_m.max(x.abs());
            e.half_y_m = e.half_y_m.max(y.abs());
        }
        for [x, y, _] in clip_to_heights(&triangle, 0.0, BASE_SLICE_M) {
            e.base_radius_m = e.base_radius_m.max(x.hypot(y));
            in_base = true;
        }
    }
    if surfaces == 0 {
        return Err("the mesh has no triangle of any area: nothing for a camera or a laser to see".into());
    }
    if !(e.top_m > 0.0) {
        return Err("no part of the mesh is above the ground (glTF's +y is up, the origin on the ground)".into());
    }
    if !in_base || e.base_radius_m <= 0.0 {
        return Err(format!(
            "no part of the mesh lies within {BASE_SLICE_M} m of the ground away from its axis: it must stand on its origin (z up)"
        ));
    }
    Ok(e)
}

/// A triangle's area (m²).
fn area([a, b, c]: &[[f64; 3]; 3]) -> f64 {
    let (u, v) = ([b[0] - a[0], b[1] - a[1], b[2] - a[2]], [c[0] - a[0], c[1] - a[1], c[2] - a[2]]);
    let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
    0.5 * (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt()
}

/// The corners of the part of `triangle` between heights `low` and `high` (a convex
/// polygon, empty where the triangle misses the slice).
fn clip_to_heights(triangle: &[[f64; 3]; 3], low: f64, high: f64) -> Vec<[f64; 3]> {
    // Sutherland-Hodgman against each of the two planes.
    let clip = |polygon: Vec<[f64; 3]>, inside: &dyn Fn(f64) -> bool, plane: f64| {
        let mut out = Vec::with_capacity(polygon.len() + 1);
        for (k, &p) in polygon.iter().enumerate() {
            let q = polygon[(k + 1) % polygon.len()];
            if inside(p[2]) {
                out.push(p);
            }
            if inside(p[2]) != inside(q[2]) {
                let s = (plane - p[2]) / (q[2] - p[2]);
                out.push([p[0] + s * (q[0] - p[0]), p[1] + s * (q[1] - p[1]), plane]);
            }
        }
        out
    };
    let above = clip(triangle.to_vec(), &|z| z >= low, low);
    if above.is_empty() {
        return above;
    }
    clip(above, &|z| z <= high, high)
}

/// The shape of an object of `class` fitted to the mesh: a trunk or post as wide as the
/// mesh's base, as tall as the mesh, a tree's canopy or a palm's crown as wide as the mesh;
/// a wall as its box.
pub fn fitted_shape(class: ObjectClass, e: &MeshExtent) -> Result<Shape, String> {
    // To the micrometre: a mesh's single-precision vertices would write 0.30000001192092896.
    let um = |m: f64| (m * 1e6).round() / 1e6;
    let e = &MeshExtent {
        base_radius_m: um(e.base_radius_m),
        radius_m: um(e.radius_m),
        top_m: um(e.top_m),
        half_x_m: um(e.half_x_m),
        half_y_m: um(e.half_y_m),
    };
    Ok(match class {
        ObjectClass::Tree => {
            // The canopy fills the upper third, centred on the trunk's top.
            let canopy_height_m = e.top_m / 3.0;
            let height_m = e.top_m - canopy_height_m / 2.0;
            Shape::Trunk {
                radius_m: e.base_radius_m,
                height_m,
                canopy_radius_m: e.radius_m.max(e.base_radius_m),
                canopy_height_m,
            }
        }
        ObjectClass::Palm => Shape::Palm {
            radius_m: e.base_radius_m,
            height_m: e.top_m,
            crown_radius_m: e.radius_m.max(e.base_radius_m),
        },
        ObjectClass::Post => Shape::Post { radius_m: e.base_radius_m, height_m: e.top_m },
        ObjectClass::Wall => {
            Shape::Wall { length_m: 2.0 * e.half_x_m, thickness_m: 2.0 * e.half_y_m, height_m: e.top_m }
        }
        other => return Err(format!("cannot import a mesh as a {}: use tree, palm, post or wall", other.name())),
    })
}

/// The look of an imported object: its class's material, in a mid colour of the
/// generator's range (the mesh is textured with it).
pub fn default_appearance(class: ObjectClass) -> Appearance {
    let (material, colour) = match class {
        ObjectClass::Palm => (Material::PalmBark, [0.51, 0.46, 0.35]),
        ObjectClass::Post => (Material::Paint, [0.25, 0.2, 0.16]),
        ObjectClass::Wall => (Material::Brick, [0.41, 0.28, 0.21]),
        _ => (Material::Bark, [0.35, 0.27, 0.19]),
    };
    Appearance { material, colour, texture_seed: 1 }
}

/// Adds `mesh` (read from the file named `mesh_file`, as the world file will name it) to
/// `world` as an object of `class` at `pose`, under the next free instance id; returns the
/// id. The world is not validated here: save and load it to check it.
pub fn add_object(
    world: &mut World,
    mesh: TriMesh,
    mesh_file: &str,
    class: ObjectClass,
    pose: Pose2,
) -> Result<u16, String> {
    let shape = fitted_shape(class, &extent(&mesh)?)?;
    // The id after the largest, or where that is the ground's, the first one free.
    let used: std::collections::BTreeSet<u16> =
        world.objects.iter().map(|o| o.id).chain(world.people.iter().map(|p| p.id)).collect();
    let after_largest = used.last().map_or(1, |m| m.saturating_add(1));
    let id = if after_largest < crate::validate::GROUND_INSTANCE_ID {
        after_largest
    } else {
        (1..crate::validate::GROUND_INSTANCE_ID)
            .find(|id| !used.contains(id))
            .ok_or("the world has no instance id left")?
    };
    world.objects.push(StaticObject {
        id,
        class,
        pose,
        shape,
        appearance: default_appearance(class),
        mesh: Some(mesh_file.to_string()),
        mesh_data: LoadedMesh(Some(std::sync::Arc::new(mesh))),
    });
    Ok(id)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A surface of revolution through `(radius, height)` rings of `sections` vertices,
    /// the first vertex of each ring on the +x axis, closed by a vertex on the axis where a
    /// radius is 0.
    fn lathe(profile: &[(f32, f32)], sections: u32) -> TriMesh {
        let mut m = TriMesh::default();
        for &(r, z) in profile {
            for k in 0..sections {
                let a = std::f32::consts::TAU * k as f32 / sections as f32;
                m.positions.push([r * a.cos(), r * a.sin(), z]);
            }
        }
        for ring in 0..profile.len() as u32 - 1 {
            for k in 0..sections {
                let (a, b) = (ring * sections + k, ring * sections + (k + 1) % sections);
                m.indices.extend([a, b, b + sections, a, b + sections, a + sections]);
            }
        }
        m
    }

    /// A world whose largest id is the last before the ground's takes the first free one.
    #[test]
    fn an_added_object_takes_a_free_id_when_the_next_is_the_grounds() {
        let mut w = crate::generate::park(&crate::generate::ParkParams::default(), 11).unwrap();
        let post = lathe(&[(0.1, 0.0), (0.1, 1.0), (0.0, 1.0)], 12);
        let at = Pose2 { x: 0.0, y: 0.0, yaw_deg: 0.0 };
        let next = w.objects.iter().map(|o| o.id).chain(w.people.iter().map(|p| p.id)).max().unwrap() + 1;
        assert_eq!(add_object(&mut w.clone(), post.clone(), "m.glb", ObjectClass::Post, at).unwrap(), next);
        w.objects[0].id = crate::validate::GROUND_INSTANCE_ID - 1;
        let first_free =
            (1..).find(|id| !w.objects.iter().any(|o| o.id == *id) && !w.people.iter().any(|p| p.id == *id));
        assert_eq!(add_object(&mut w, post, "m.glb", ObjectClass::Post, at).ok(), first_free);
    }

    #[test]
    fn a_tree_mesh_gives_a_trunk_as_wide_as_its_base_and_a_canopy_as_wide_as_its_crown() {
        // A 0.25 m trunk to 4 m, crown 2 m wide up to 6 m.
        let m = lathe(&[(0.25, 0.0), (0.25, 4.0), (2.0, 5.0), (0.0, 6.0)], 4);
        let mut e = extent(&m).unwrap();
        // Single-precision vertices: off the axes, a radius is exact to about 1e-14; the
        // fitted shape is given to the micrometre.
        let near = |a: f64, b: f64| (a - b).abs() < 1e-12;
        assert!(near(e.base_radius_m, 0.25) && near(e.radius_m, 2.0) && e.top_m == 6.0, "{e:?}");
        (e.base_radius_m, e.radius_m) = (0.25 + 1e-9, 2.0 - 1e-9);
        let Shape::Trunk { radius_m, height_m, canopy_radius_m, canopy_height_m } =
            fitted_shape(ObjectClass::Tree, &e).unwrap()
        else {
            panic!("a tree is a trunk")
        };
        assert_eq!((radius_m, canopy_radius_m, canopy_height_m), (0.25, 2.0, 2.0));
        assert_eq!(height_m + canopy_height_m / 2.0, 6.0, "the canopy's top is the mesh's");
        assert_eq!(fitted_shape(ObjectClass::Post, &e).unwrap(), Shape::Post { radius_m: 0.25, height_m: 6.0 });
        assert!(fitted_shape(ObjectClass::Person, &e).is_err());
    }

    #[test]
    fn a_mesh_that_does_not_stand_on_its_origin_is_refused() {
        let e = extent(&lathe(&[(0.5, 2.0), (0.5, 3.0)], 8)).unwrap_err();
        assert!(e.contains("stand on its origin"), "{e}");
        assert!(extent(&lathe(&[(0.5, -2.0), (0.5, -1.0)], 8)).unwrap_err().contains("above the ground"));
        let mut nan = lathe(&[(0.5, 0.0), (0.5, 1.0)], 8);
        nan.positions[3][0] = f32::NAN;
        assert!(extent(&nan).unwrap_err().contains("not a finite number"));
        assert!(extent(&TriMesh::default()).unwrap_err().contains("no triangle of any area"));
    }

    /// The extent is the drawn surface's: a trunk sunk into the ground is measured where it
    /// crosses the base slice, not by stray vertices; unused vertices and triangles of no
    /// area change nothing.
    #[test]
    fn the_extent_is_measured_on_the_surface_that_is_drawn() {
        // Vertices only at -5 cm and 3.95 m: the slice cuts the sides.
        let sunk = lathe(&[(0.3, -0.05), (0.3, 3.95)], 16);
        let e = extent(&sunk).unwrap();
        assert!((e.base_radius_m - 0.3).abs() < 1e-6 && (e.top_m - 3.95).abs() < 1e-6, "{e:?}");
        // A small knot inside the trunk does not make it thin.
        let mut knot = sunk.clone();
        knot.append(&lathe(&[(0.05, 0.4), (0.05, 0.6)], 4));
        assert_eq!(extent(&knot).unwrap().base_radius_m, e.base_radius_m);
        // A vertex no triangle uses, and slivers of three points on a line far out: exactly,
        // and as single-precision vertices leave them.
        let mut stray = sunk.clone();
        stray.positions.push([5.0, 4.0, 0.0]);
        let n = stray.positions.len() as u32;
        stray.positions.extend([[0.0, 3.0, 1.0], [3.0, 3.0, 1.0], [1.5, 3.0, 1.0]]);
        stray.positions.extend([[5.0, 4.0, 0.3], [0.1, 0.7, 0.9], [-4.8, -2.6, 1.5]]);
        stray.indices.extend([n, n + 1, n + 2, n + 3, n + 4, n + 5]);
        assert_eq!(extent(&stray).unwrap(), e);
        let flat = TriMesh {
            positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 1.0], [2.0, 0.0, 2.0]],
            indices: vec![0, 1, 2],
            ..Default::default()
        };
        assert!(extent(&flat).unwrap_err().contains("no triangle of any area"));
    }
}
