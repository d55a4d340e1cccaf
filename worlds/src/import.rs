//! Bringing a user's mesh into a world as an object (`objslam world import`): the camera
//! renders the mesh, and a shape fitted to it gives the collider the laser sees.

use crate::description::{Appearance, LoadedMesh, Material, ObjectClass, Pose2, Shape, StaticObject, World};
use crate::mesh::TriMesh;

/// Height of the slice (m above the ground) whose footprint sizes a trunk or a post: the
/// part a laser a few decimetres up sees.
pub const BASE_SLICE_M: f64 = 1.0;

/// What the mesh's vertices say of its size, in its own frame (z up, origin on the ground
/// at the object's pose).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshExtent {
    /// Farthest vertex from the vertical axis, below [`BASE_SLICE_M`] (m).
    pub base_radius_m: f64,
    /// Farthest vertex from the vertical axis anywhere (m).
    pub radius_m: f64,
    /// Highest vertex (m).
    pub top_m: f64,
    /// Half extents along x and y (m), about the origin.
    pub half_x_m: f64,
    pub half_y_m: f64,
}

/// The mesh's extent; an error for a mesh with no vertex above the ground or none in the
/// base slice (a mesh not standing on its origin).
pub fn extent(mesh: &TriMesh) -> Result<MeshExtent, String> {
    let mut e =
        MeshExtent { base_radius_m: 0.0, radius_m: 0.0, top_m: f64::NEG_INFINITY, half_x_m: 0.0, half_y_m: 0.0 };
    let mut in_base = 0usize;
    for p in &mesh.positions {
        let [x, y, z] = p.map(f64::from);
        if !(x.is_finite() && y.is_finite() && z.is_finite()) {
            return Err("the mesh has a vertex that is not a finite number".into());
        }
        let r = x.hypot(y);
        e.radius_m = e.radius_m.max(r);
        e.top_m = e.top_m.max(z);
        e.half_x_m = e.half_x_m.max(x.abs());
        e.half_y_m = e.half_y_m.max(y.abs());
        if (0.0..=BASE_SLICE_M).contains(&z) {
            e.base_radius_m = e.base_radius_m.max(r);
            in_base += 1;
        }
    }
    if !(e.top_m > 0.0) {
        return Err("the mesh has no vertex above the ground (glTF's +y is up, the origin on the ground)".into());
    }
    if in_base == 0 {
        return Err(format!(
            "no vertex of the mesh lies within {BASE_SLICE_M} m of the ground: it must stand on its origin (z up)"
        ));
    }
    Ok(e)
}

/// The shape of an object of `class` fitted to the mesh: a trunk or post as wide as the
/// mesh's base, as tall as the mesh, a tree's canopy or a palm's crown as wide as the mesh;
/// a wall as its box.
pub fn fitted_shape(class: ObjectClass, e: &MeshExtent) -> Result<Shape, String> {
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
    let used = world.objects.iter().map(|o| o.id).chain(world.people.iter().map(|p| p.id));
    let id = used.max().unwrap_or(0).checked_add(1).ok_or("the world has no instance id left")?;
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

    /// A mesh of the given vertices (no triangles: the extent only reads vertices).
    fn points(p: &[[f32; 3]]) -> TriMesh {
        TriMesh { positions: p.to_vec(), ..Default::default() }
    }

    #[test]
    fn a_tree_mesh_gives_a_trunk_as_wide_as_its_base_and_a_canopy_as_wide_as_its_crown() {
        // A 0.25 m trunk to 4 m, crown 2 m wide up to 6 m.
        let m = points(&[[0.25, 0.0, 0.0], [0.0, -0.25, 0.9], [0.0, 0.2, 4.0], [2.0, 0.0, 5.0], [0.0, 0.0, 6.0]]);
        let e = extent(&m).unwrap();
        assert_eq!((e.base_radius_m, e.radius_m, e.top_m), (0.25, 2.0, 6.0));
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
        assert!(extent(&points(&[[0.0, 0.0, 2.0], [0.5, 0.0, 3.0]])).unwrap_err().contains("stand on its origin"));
        assert!(extent(&points(&[[0.0, 0.0, -1.0]])).unwrap_err().contains("above the ground"));
        assert!(extent(&points(&[[f32::NAN, 0.0, 0.5]])).is_err());
        assert!(extent(&TriMesh::default()).is_err());
    }
}
