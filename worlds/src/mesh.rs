//! Procedural triangle meshes for every class, in each object's model frame (origin on the
//! ground at the object's pose, z up), with UVs in texture tiles so textures keep a
//! physical scale (see [`crate::texture::tile_size_m`]).

use std::f64::consts::{PI, TAU};

use crate::description::*;
use crate::texture::tile_size_m;

/// An indexed triangle mesh with per-vertex normals and UVs.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriMesh {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    /// Counter-clockwise triangles seen from outside.
    pub indices: Vec<u32>,
}

impl TriMesh {
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// Appends another mesh.
    pub fn append(&mut self, other: &TriMesh) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&other.positions);
        self.normals.extend_from_slice(&other.normals);
        self.uvs.extend_from_slice(&other.uvs);
        self.indices.extend(other.indices.iter().map(|i| i + base));
    }

    /// Axis-aligned bounds (min, max); zeros for an empty mesh.
    pub fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        if self.positions.is_empty() {
            return ([0.0; 3], [0.0; 3]);
        }
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in &self.positions {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        (lo, hi)
    }

    /// Rotates about z by `yaw` and translates, in place.
    pub fn transform(&mut self, yaw: f64, t: [f64; 3]) {
        let (s, c) = (yaw.sin() as f32, yaw.cos() as f32);
        for p in &mut self.positions {
            let (x, y) = (p[0], p[1]);
            *p = [c * x - s * y + t[0] as f32, s * x + c * y + t[1] as f32, p[2] + t[2] as f32];
        }
        for n in &mut self.normals {
            let (x, y) = (n[0], n[1]);
            *n = [c * x - s * y, s * x + c * y, n[2]];
        }
    }

    /// Rotates by `r` (row-major) about the origin, then translates by `t`, in place.
    pub fn rigid(&mut self, r: &[[f64; 3]; 3], t: [f64; 3]) {
        let rot = |v: [f32; 3]| -> [f64; 3] {
            std::array::from_fn(|i| r[i][0] * v[0] as f64 + r[i][1] * v[1] as f64 + r[i][2] * v[2] as f64)
        };
        for p in &mut self.positions {
            let q = rot(*p);
            *p = [(q[0] + t[0]) as f32, (q[1] + t[1]) as f32, (q[2] + t[2]) as f32];
        }
        for n in &mut self.normals {
            let q = rot(*n);
            *n = [q[0] as f32, q[1] as f32, q[2] as f32];
        }
    }

    fn push(&mut self, p: [f64; 3], n: [f64; 3], uv: [f64; 2]) -> u32 {
        self.positions.push([p[0] as f32, p[1] as f32, p[2] as f32]);
        let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt().max(1e-12);
        self.normals.push([(n[0] / l) as f32, (n[1] / l) as f32, (n[2] / l) as f32]);
        self.uvs.push([uv[0] as f32, uv[1] as f32]);
        (self.positions.len() - 1) as u32
    }
}

/// A (possibly tapered) cylinder along z from `z0` to `z0 + height`, with caps.
/// `tile` is the texture tile size (m) so UVs keep a physical scale.
pub fn cylinder(r_bottom: f64, r_top: f64, z0: f64, height: f64, segments: usize, tile: [f64; 2]) -> TriMesh {
    let mut m = TriMesh::default();
    let slope = (r_bottom - r_top) / height;
    let circumference = TAU * r_bottom.max(r_top);
    // Round the number of tiles around so the seam matches.
    let u_tiles = (circumference / tile[0]).round().max(1.0);
    for i in 0..=segments {
        let a = TAU * i as f64 / segments as f64;
        let (s, c) = a.sin_cos();
        let n = [c, s, slope];
        let u = u_tiles * i as f64 / segments as f64;
        m.push([r_bottom * c, r_bottom * s, z0], n, [u, 0.0]);
        m.push([r_top * c, r_top * s, z0 + height], n, [u, -height / tile[1]]);
    }
    for i in 0..segments as u32 {
        let (b0, t0, b1, t1) = (2 * i, 2 * i + 1, 2 * i + 2, 2 * i + 3);
        m.indices.extend_from_slice(&[b0, b1, t1, b0, t1, t0]);
    }
    // Caps: top always, bottom only when lifted off the ground.
    let caps: &[(f64, f64, f64)] =
        if z0 > 1e-6 { &[(z0 + height, r_top, 1.0), (z0, r_bottom, -1.0)] } else { &[(z0 + height, r_top, 1.0)] };
    for &(z, r, dir) in caps {
        let centre = m.push([0.0, 0.0, z], [0.0, 0.0, dir], [0.5, 0.5]);
        let first = m.positions.len() as u32;
        for i in 0..=segments {
            let a = TAU * i as f64 / segments as f64;
            let (s, c) = a.sin_cos();
            m.push([r * c, r * s, z], [0.0, 0.0, dir], [0.5 + 0.5 * c, 0.5 + 0.5 * s]);
        }
        for i in 0..segments as u32 {
            if dir > 0.0 {
                m.indices.extend_from_slice(&[centre, first + i, first + i + 1]);
            } else {
                m.indices.extend_from_slice(&[centre, first + i + 1, first + i]);
            }
        }
    }
    m
}

/// An ellipsoid centred at `c` with semi-axes `r`.
pub fn ellipsoid(c: [f64; 3], r: [f64; 3], segments: usize, rings: usize, tile: [f64; 2]) -> TriMesh {
    let mut m = TriMesh::default();
    for j in 0..=rings {
        let phi = PI * j as f64 / rings as f64;
        for i in 0..=segments {
            let theta = TAU * i as f64 / segments as f64;
            let d = [phi.sin() * theta.cos(), phi.sin() * theta.sin(), phi.cos()];
            let p = [c[0] + r[0] * d[0], c[1] + r[1] * d[1], c[2] + r[2] * d[2]];
            let n = [d[0] / r[0], d[1] / r[1], d[2] / r[2]];
            m.push(p, n, [theta * r[0] / tile[0], phi * r[2] / tile[1]]);
        }
    }
    let w = segments as u32 + 1;
    for j in 0..rings as u32 {
        for i in 0..segments as u32 {
            let (a, b, c2, d) = (j * w + i, j * w + i + 1, (j + 1) * w + i, (j + 1) * w + i + 1);
            // At a pole a ring is one point: of each quad only the triangle that spans the
            // next ring has an area (the other would be a zero-area sliver in an export).
            if j + 1 < rings as u32 {
                m.indices.extend_from_slice(&[a, c2, d]);
            }
            if j > 0 {
                m.indices.extend_from_slice(&[a, d, b]);
            }
        }
    }
    m
}

/// An axis-aligned box centred at `c` with half extents `h`.
pub fn cuboid(c: [f64; 3], h: [f64; 3], tile: [f64; 2]) -> TriMesh {
    let mut m = TriMesh::default();
    // (normal, u axis, v axis) per face; v axis points down so textures stand upright.
    let faces: [([f64; 3], [f64; 3], [f64; 3]); 6] = [
        ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]),
        ([-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]),
        ([0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]),
        ([0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]),
        ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]),
        ([0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
    ];
    for (n, u, v) in faces {
        let base = m.positions.len() as u32;
        for (su, sv) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
            let p: [f64; 3] = std::array::from_fn(|k| c[k] + h[k] * (n[k] + su * u[k] + sv * v[k]));
            let extent_u: f64 = (0..3).map(|k| (h[k] * u[k]).abs()).sum();
            let extent_v: f64 = (0..3).map(|k| (h[k] * v[k]).abs()).sum();
            m.push(p, n, [su * extent_u / tile[0], sv * extent_v / tile[1]]);
        }
        // The corners run clockwise seen from outside (u right, v down), so the triangles
        // take them in reverse to be counter-clockwise.
        m.indices.extend_from_slice(&[base, base + 2, base + 1, base, base + 3, base + 2]);
    }
    m
}

/// One renderable part of an object: geometry, look and the ids masks carry.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshPart {
    pub name: String,
    pub mesh: TriMesh,
    pub appearance: Appearance,
    pub class: ObjectClass,
    pub instance_id: u16,
}

/// Segments around a trunk; 48 keeps silhouettes round at 640x480 from 1 m.
const TRUNK_SEGMENTS: usize = 48;

/// The procedural mesh parts of a static object, in its model frame.
pub fn object_parts(o: &StaticObject) -> Vec<MeshPart> {
    // A user mesh replaces the procedural parts whole, in the object's class (a tree's
    // leaves are then labelled tree too).
    if let Some(m) = &o.mesh_data.0 {
        return vec![MeshPart {
            name: format!("{}_{}_mesh", o.class.name(), o.id),
            mesh: (**m).clone(),
            appearance: o.appearance.clone(),
            class: o.class,
            instance_id: o.id,
        }];
    }
    // Canopies and crowns keep their object's instance id but take the foliage class, so
    // class images label the trunk the laser sees (the paper's object) apart from leaves.
    let part = |name: &str, mesh: TriMesh, appearance: Appearance| MeshPart {
        name: format!("{}_{}_{}", o.class.name(), o.id, name),
        class: if appearance.material == Material::Foliage { ObjectClass::Foliage } else { o.class },
        mesh,
        appearance,
        instance_id: o.id,
    };
    let a = o.appearance.clone();
    match o.shape {
        Shape::Trunk { radius_m, height_m, canopy_radius_m, canopy_height_m } => {
            let trunk = trunk_mesh(radius_m, 0.8, height_m, tile_size_m(Material::Bark));
            let foliage = Appearance {
                material: Material::Foliage,
                colour: [0.20 + 0.1 * (a.colour[0] - 0.3), 0.36, 0.14],
                texture_seed: a.texture_seed.wrapping_add(1),
            };
            let canopy = ellipsoid(
                [0.0, 0.0, height_m],
                [canopy_radius_m, canopy_radius_m, canopy_height_m / 2.0],
                24,
                12,
                tile_size_m(Material::Foliage),
            );
            vec![part("trunk", trunk, a), part("canopy", canopy, foliage)]
        }
        Shape::Palm { radius_m, height_m, crown_radius_m } => {
            let trunk = trunk_mesh(radius_m, 0.85, height_m, tile_size_m(Material::PalmBark));
            let mut crown = TriMesh::default();
            let fronds = 9;
            for k in 0..fronds {
                let yaw = TAU * k as f64 / fronds as f64;
                crown.append(&frond(crown_radius_m, height_m, yaw));
            }
            let foliage = Appearance {
                material: Material::Foliage,
                colour: [0.22, 0.40, 0.12],
                texture_seed: a.texture_seed.wrapping_add(1),
            };
            vec![part("trunk", trunk, a), part("crown", crown, foliage)]
        }
        Shape::Post { radius_m, height_m } => {
            vec![part(
                "post",
                cylinder(radius_m, radius_m, 0.0, height_m, TRUNK_SEGMENTS, tile_size_m(Material::Paint)),
                a,
            )]
        }
        Shape::Wall { length_m, thickness_m, height_m } => {
            let tile = tile_size_m(a.material);
            vec![part(
                "wall",
                cuboid([0.0, 0.0, height_m / 2.0], [length_m / 2.0, thickness_m / 2.0, height_m / 2.0], tile),
                a,
            )]
        }
        Shape::Board { width_m, height_m, squares, .. } => {
            // Built facing +x about the origin, then turned and placed by the board's frame.
            // The checker texture holds 2 x 2 squares, so the front face's UVs run over
            // squares/2 repeats to show squares[0] x squares[1] squares exactly; the back
            // and the edges are plain.
            let frame = o.shape.board_frame().expect("a board");
            let mut board =
                cuboid([0.0; 3], [BOARD_THICKNESS_M / 2.0, width_m / 2.0, height_m / 2.0], [width_m, height_m]);
            for (k, uv) in board.uvs.iter_mut().enumerate() {
                if k < 4 {
                    // The front (+x) face. With the tile equal to the face's size, cuboid
                    // UVs span [-0.5, 0.5].
                    uv[0] = (uv[0] + 0.5) * squares[0] as f32 / 2.0;
                    uv[1] = (uv[1] + 0.5) * squares[1] as f32 / 2.0;
                } else {
                    // Back and edges: plain, the colour of the light squares.
                    *uv = [0.25, 0.25];
                }
            }
            board.rigid(&frame.rotation, frame.centre_m);
            let mut parts = vec![part("board", board, a)];
            // The stand: a post from the ground to the board's lowest corner.
            let lowest = frame.lowest_m();
            if lowest > 0.0 {
                let stand = cuboid([0.0, 0.0, lowest / 2.0], [0.02, 0.02, lowest / 2.0], [1.0, 1.0]);
                let grey = Appearance { material: Material::Concrete, colour: [0.4, 0.4, 0.4], texture_seed: 0 };
                parts.push(part("stand", stand, grey));
            }
            parts
        }
    }
}

/// Height up to which trunks are straight cylinders of their nominal radius, so the
/// physics collider (a cylinder) and the rendered mesh agree where the laser and the
/// camera see them; above it the trunk tapers.
pub const STRAIGHT_TRUNK_M: f64 = 1.5;

/// A trunk: straight up to [`STRAIGHT_TRUNK_M`], then tapering to `top_ratio` x radius.
fn trunk_mesh(radius: f64, top_ratio: f64, height: f64, tile: [f64; 2]) -> TriMesh {
    let straight = STRAIGHT_TRUNK_M.min(height);
    let mut m = cylinder(radius, radius, 0.0, straight, TRUNK_SEGMENTS, tile);
    if height > straight {
        let mut upper = cylinder(radius, radius * top_ratio, straight, height - straight, TRUNK_SEGMENTS, tile);
        // Continue the texture where the lower part ends.
        let dv = -straight / tile[1];
        for uv in &mut upper.uvs {
            uv[1] += dv as f32;
        }
        m.append(&upper);
    }
    m
}

/// One drooping palm frond: a strip of quads arching out from the crown.
fn frond(length: f64, top: f64, yaw: f64) -> TriMesh {
    let mut m = TriMesh::default();
    let steps = 6;
    for i in 0..=steps {
        let t = i as f64 / steps as f64;
        let r = length * t;
        let z = top + 0.4 * length * (t * PI * 0.8).sin() - 0.3 * length * t * t;
        let half_w = 0.25 * length * (t * PI).sin().max(0.05);
        let (s, c) = yaw.sin_cos();
        let centre = [r * c, r * s, z];
        let side = [-s * half_w, c * half_w, 0.0];
        m.push([centre[0] + side[0], centre[1] + side[1], centre[2]], [0.0, 0.0, 1.0], [0.0, t * 3.0]);
        m.push([centre[0] - side[0], centre[1] - side[1], centre[2]], [0.0, 0.0, 1.0], [1.0, t * 3.0]);
    }
    // Fronds are seen from above and below: the underside is a second sheet on the same
    // vertices with downward normals and the opposite winding, so each side is lit as itself.
    let under = m.positions.len() as u32;
    for k in 0..under as usize {
        let (p, uv) = (m.positions[k], m.uvs[k]);
        m.positions.push(p);
        m.normals.push([0.0, 0.0, -1.0]);
        m.uvs.push(uv);
    }
    for i in 0..steps as u32 {
        let (a, b, c2, d) = (2 * i, 2 * i + 1, 2 * i + 2, 2 * i + 3);
        m.indices.extend_from_slice(&[a, b, d, a, d, c2]);
        let [a, b, c2, d] = [a, b, c2, d].map(|v| v + under);
        m.indices.extend_from_slice(&[a, d, b, a, c2, d]);
    }
    m
}

/// A person's meshes: each leg in a hip frame (origin at the hip joint, leg hanging
/// along -z) so the simulator can swing it, and the upper body in the person's frame.
#[derive(Debug, Clone, PartialEq)]
pub struct PersonParts {
    pub left_leg: MeshPart,
    pub right_leg: MeshPart,
    pub body: MeshPart,
    pub head: MeshPart,
    /// Hip joint height above the ground.
    pub hip_height_m: f64,
}

/// Hip height as a fraction of body height (anthropometric average).
pub const HIP_FRACTION: f64 = 0.5;

pub fn person_parts(p: &Person) -> PersonParts {
    let h = p.height_m;
    let hip = HIP_FRACTION * h;
    let leg = cylinder(p.leg_radius_m * 0.85, p.leg_radius_m, -hip, hip, 16, tile_size_m(Material::Clothes));
    let mut torso = cylinder(0.13 * h * 0.75, 0.13 * h, hip - 0.02, 0.32 * h, 20, tile_size_m(Material::Clothes));
    // Arms hang beside the torso.
    for side in [-1.0, 1.0] {
        let mut arm = cylinder(0.025 * h, 0.03 * h, hip - 0.02 * h, 0.33 * h, 10, tile_size_m(Material::Clothes));
        arm.transform(0.0, [0.0, side * 0.165 * h, 0.0]);
        torso.append(&arm);
    }
    let head = ellipsoid([0.0, 0.0, 0.9 * h], [0.06 * h, 0.055 * h, 0.07 * h], 16, 10, tile_size_m(Material::Skin));
    let mk = |name: &str, mesh: TriMesh, appearance: Appearance| MeshPart {
        name: format!("person_{}_{}", p.id, name),
        mesh,
        appearance,
        class: ObjectClass::Person,
        instance_id: p.id,
    };
    let skin = Appearance { material: Material::Skin, colour: [0.75, 0.58, 0.46], texture_seed: p.shirt.texture_seed };
    PersonParts {
        left_leg: mk("left_leg", leg.clone(), p.trousers.clone()),
        right_leg: mk("right_leg", leg, p.trousers.clone()),
        body: mk("body", torso, p.shirt.clone()),
        head: mk("head", head, skin),
        hip_height_m: hip,
    }
}

/// The ground plane, tiled with grass; instance id [`crate::validate::GROUND_INSTANCE_ID`].
pub fn ground_part(g: &Ground) -> MeshPart {
    let mut m = TriMesh::default();
    let tile = tile_size_m(g.appearance.material);
    let corners =
        [[g.min_m[0], g.min_m[1]], [g.max_m[0], g.min_m[1]], [g.max_m[0], g.max_m[1]], [g.min_m[0], g.max_m[1]]];
    for c in corners {
        m.push([c[0], c[1], 0.0], [0.0, 0.0, 1.0], [c[0] / tile[0], -c[1] / tile[1]]);
    }
    m.indices.extend_from_slice(&[0, 1, 2, 0, 2, 3]);
    MeshPart {
        name: "ground".into(),
        mesh: m,
        appearance: g.appearance.clone(),
        class: ObjectClass::Ground,
        instance_id: crate::validate::GROUND_INSTANCE_ID,
    }
}

/// Every static part of a world in world coordinates (people are posed by the simulator).
pub fn static_world_parts(w: &World) -> Vec<MeshPart> {
    let mut parts = vec![ground_part(&w.ground)];
    for o in &w.objects {
        for mut p in object_parts(o) {
            p.mesh.transform(o.pose.yaw_rad(), [o.pose.x, o.pose.y, 0.0]);
            parts.push(p);
        }
    }
    parts
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The normal of triangle (a, b, c) by its winding (counter-clockwise: towards the viewer).
    fn winding_normal(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> [f64; 3] {
        let e1: [f64; 3] = std::array::from_fn(|k| (b[k] - a[k]) as f64);
        let e2: [f64; 3] = std::array::from_fn(|k| (c[k] - a[k]) as f64);
        [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]]
    }

    /// A 0.8 x 0.6 m board of 8 x 6 squares at the origin, turned up 20 deg and rolled 15.
    fn tilted_board(id: u16, yaw_deg: f64) -> StaticObject {
        StaticObject {
            id,
            class: ObjectClass::Checkerboard,
            pose: Pose2 { x: 0.0, y: 0.0, yaw_deg },
            shape: Shape::Board {
                width_m: 0.8,
                height_m: 0.6,
                bottom_m: 0.4,
                squares: [8, 6],
                tilt_deg: -20.0,
                roll_deg: 15.0,
            },
            appearance: Appearance { material: Material::Checker, colour: [0.9; 3], texture_seed: 0 },
            mesh: None,
            mesh_data: Default::default(),
        }
    }

    #[test]
    fn cylinder_surface_points_are_on_the_radius() {
        let m = cylinder(0.3, 0.3, 0.0, 2.0, 32, [1.0, 1.0]);
        for p in &m.positions {
            let r = (p[0] * p[0] + p[1] * p[1]).sqrt();
            assert!(r < 1e-6 || (r - 0.3).abs() < 1e-6, "radius {r}");
        }
        let (lo, hi) = m.bounds();
        assert!((hi[2] - 2.0).abs() < 1e-6 && lo[2].abs() < 1e-6);
    }

    #[test]
    fn cylinder_triangles_face_outwards() {
        let m = cylinder(0.5, 0.5, 0.0, 1.0, 16, [1.0, 1.0]);
        for t in m.indices.chunks(3).take(32) {
            let [a, b, c] = [t[0], t[1], t[2]].map(|i| m.positions[i as usize]);
            let n = winding_normal(a, b, c);
            let centre = [(a[0] + b[0] + c[0]) as f64 / 3.0, (a[1] + b[1] + c[1]) as f64 / 3.0];
            assert!(n[0] * centre[0] + n[1] * centre[1] > 0.0, "inward-facing side triangle");
        }
    }

    #[test]
    fn a_tilted_board_mesh_lies_on_its_plane() {
        let o = tilted_board(9, 0.0);
        let f = o.shape.board_frame().unwrap();
        let n = f.normal();
        let parts = object_parts(&o);
        let board = &parts[0].mesh;
        // The front face's vertices (normal = n) lie half a thickness in front of the centre.
        let mut on_face = 0;
        for (p, vn) in board.positions.iter().zip(&board.normals) {
            if (0..3).map(|k| vn[k] as f64 * n[k]).sum::<f64>() > 0.999 {
                let d: f64 = (0..3).map(|k| (p[k] as f64 - f.centre_m[k]) * n[k]).sum();
                assert!((d - BOARD_THICKNESS_M / 2.0).abs() < 1e-6, "{d}");
                on_face += 1;
            }
        }
        assert_eq!(on_face, 4);
        // The stand reaches the lowest corner.
        let (_, hi) = parts[1].mesh.bounds();
        assert!((hi[2] as f64 - f.lowest_m()).abs() < 1e-6);
    }

    /// Renderers may skip back faces of these meshes and light the rest with their normals
    /// as given (see `render::MeshData::cull_back_faces`): every triangle must be
    /// counter-clockwise seen from the side its vertex normals point to, and have an area.
    fn assert_wound_outwards(m: &TriMesh, name: &str) {
        for t in m.indices.chunks(3) {
            let t = [t[0], t[1], t[2]];
            let [a, b, c] = t.map(|i| m.positions[i as usize]);
            let n = winding_normal(a, b, c);
            let area2 = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            // A zero-area triangle covers no pixel, but an exported mesh should hold none.
            assert!(area2 > 1e-9, "{name}: triangle {t:?} has no area");
            let vn: [f64; 3] = std::array::from_fn(|k| t.iter().map(|&i| m.normals[i as usize][k] as f64).sum());
            let agree = n[0] * vn[0] + n[1] * vn[1] + n[2] * vn[2] > 0.0;
            assert!(agree, "{name}: triangle {t:?} is wound against its normals");
        }
    }

    #[test]
    fn every_part_is_wound_counter_clockwise_from_outside() {
        let mut w = crate::generate::park(&Default::default(), 1).unwrap();
        w.objects.push(tilted_board(900, 30.0));
        let parts = static_world_parts(&w);
        for kind in ["ground", "tree", "palm", "post", "wall", "checkerboard"] {
            assert!(parts.iter().any(|p| p.name.starts_with(kind)), "the test world has no {kind}");
        }
        for p in &parts {
            assert_wound_outwards(&p.mesh, &p.name);
        }
        let person = person_parts(&w.people[0]);
        for p in [&person.left_leg, &person.right_leg, &person.body, &person.head] {
            assert_wound_outwards(&p.mesh, &p.name);
        }
    }

    #[test]
    fn person_legs_reach_laser_height() {
        let p = crate::generate::park(&Default::default(), 1).unwrap().people[0].clone();
        let parts = person_parts(&p);
        let (lo, hi) = parts.left_leg.mesh.bounds();
        // Leg in hip frame spans [-hip, 0]; the laser at 0.4 m sees it.
        assert!(lo[2] as f64 + parts.hip_height_m < 0.05 && hi[2] as f64 + parts.hip_height_m > 0.5);
    }
}
