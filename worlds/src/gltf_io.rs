//! glTF 2.0: export a whole world as one binary `.glb` that opens in any viewer, and
//! import user meshes through the `gltf` crate.
//!
//! glTF is y-up; our worlds are z-up (REP-103). Export puts every part under one root node
//! rotated -90 deg about x; import applies node transforms and maps y-up back to z-up, so
//! an export/import round trip returns the original coordinates.

use std::io::Cursor;
use std::path::Path;

use serde_json::{Value, json};

use crate::description::World;
use crate::error::WorldError;
use crate::mesh::{MeshPart, TriMesh, person_parts, static_world_parts};
use crate::texture;

/// Builds the `.glb` bytes of a world (people standing at their routes' starts).
pub fn export_glb(world: &World) -> Vec<u8> {
    let mut parts = static_world_parts(world);
    for p in &world.people {
        let pp = person_parts(p);
        let start = p.route.waypoints[0];
        let next = p.route.waypoints.get(1).copied().unwrap_or(start);
        let yaw = (next[1] - start[1]).atan2(next[0] - start[0]);
        for (mut part, lateral, lift) in [
            (pp.left_leg, p.hip_half_width_m, pp.hip_height_m),
            (pp.right_leg, -p.hip_half_width_m, pp.hip_height_m),
            (pp.body, 0.0, 0.0),
            (pp.head, 0.0, 0.0),
        ] {
            part.mesh.transform(0.0, [0.0, lateral, lift]);
            part.mesh.transform(yaw, [start[0], start[1], 0.0]);
            parts.push(part);
        }
    }
    parts_to_glb(&parts)
}

/// Writes a world's `.glb` file.
pub fn export_glb_file(world: &World, path: &Path) -> Result<(), WorldError> {
    std::fs::write(path, export_glb(world)).map_err(|source| WorldError::Write { file: path.to_path_buf(), source })
}

/// Packs mesh parts into a `.glb`; each part becomes a node with its instance id and
/// class in `extras`.
pub fn parts_to_glb(parts: &[MeshPart]) -> Vec<u8> {
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut meshes = Vec::new();
    let mut nodes = Vec::new();
    let mut materials = Vec::new();
    let mut images = Vec::new();
    let mut textures = Vec::new();

    let mut push_view = |bin: &mut Vec<u8>, bytes: &[u8], target: Option<u32>| -> usize {
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let offset = bin.len();
        bin.extend_from_slice(bytes);
        let mut v = json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        views.push(v);
        views.len() - 1
    };

    for part in parts {
        let m = &part.mesh;
        let (lo, hi) = m.bounds();
        let pos = push_view(&mut bin, &f32_bytes(m.positions.iter().flatten()), Some(34962));
        accessors.push(json!({"bufferView": pos, "componentType": 5126, "count": m.positions.len(), "type": "VEC3", "min": lo, "max": hi}));
        let pos_acc = accessors.len() - 1;
        let nrm = push_view(&mut bin, &f32_bytes(m.normals.iter().flatten()), Some(34962));
        accessors.push(json!({"bufferView": nrm, "componentType": 5126, "count": m.normals.len(), "type": "VEC3"}));
        let nrm_acc = accessors.len() - 1;
        let uv = push_view(&mut bin, &f32_bytes(m.uvs.iter().flatten()), Some(34962));
        accessors.push(json!({"bufferView": uv, "componentType": 5126, "count": m.uvs.len(), "type": "VEC2"}));
        let uv_acc = accessors.len() - 1;
        let idx_bytes: Vec<u8> = m.indices.iter().flat_map(|i| i.to_le_bytes()).collect();
        let idx = push_view(&mut bin, &idx_bytes, Some(34963));
        accessors.push(json!({"bufferView": idx, "componentType": 5125, "count": m.indices.len(), "type": "SCALAR"}));
        let idx_acc = accessors.len() - 1;

        let tex = texture::generate(&part.appearance);
        let png = encode_png(&tex);
        let img_view = push_view(&mut bin, &png, None);
        images.push(json!({"bufferView": img_view, "mimeType": "image/png"}));
        textures.push(json!({"source": images.len() - 1, "sampler": 0}));
        materials.push(json!({
            "name": format!("{}_material", part.name),
            "pbrMetallicRoughness": {"baseColorTexture": {"index": textures.len() - 1}, "metallicFactor": 0.0, "roughnessFactor": 0.9},
            "doubleSided": true
        }));
        meshes.push(json!({
            "name": part.name,
            "primitives": [{
                "attributes": {"POSITION": pos_acc, "NORMAL": nrm_acc, "TEXCOORD_0": uv_acc},
                "indices": idx_acc,
                "material": materials.len() - 1
            }]
        }));
        nodes.push(json!({
            "name": part.name,
            "mesh": meshes.len() - 1,
            "extras": {"instance_id": part.instance_id, "class": part.class.name()}
        }));
    }
    let children: Vec<usize> = (0..nodes.len()).collect();
    let h = std::f64::consts::FRAC_1_SQRT_2;
    nodes.push(json!({"name": "world_z_up", "rotation": [-h, 0.0, 0.0, h], "children": children}));
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let root = json!({
        "asset": {"version": "2.0", "generator": concat!("objslam worlds ", env!("CARGO_PKG_VERSION"))},
        "scene": 0,
        "scenes": [{"nodes": [nodes.len() - 1]}],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "textures": textures,
        "images": images,
        "samplers": [{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}]
    });
    glb_bytes(&root, &bin)
}

fn f32_bytes<'a>(v: impl Iterator<Item = &'a f32>) -> Vec<u8> {
    v.flat_map(|x| x.to_le_bytes()).collect()
}

fn encode_png(t: &texture::Texture) -> Vec<u8> {
    let img = image::RgbaImage::from_raw(t.width, t.height, t.rgba.clone()).expect("texture buffer matches its size");
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).expect("PNG encoding to memory cannot fail");
    out.into_inner()
}

/// GLB container: 12-byte header, JSON chunk padded with spaces, BIN chunk padded with 0.
fn glb_bytes(root: &Value, bin: &[u8]) -> Vec<u8> {
    let mut json = serde_json::to_vec(root).expect("JSON values always serialise");
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(bin);
    out
}

/// Loads every triangle primitive of a glTF/.glb file into one z-up mesh, applying the
/// node transforms. Errors are strings for embedding in [`WorldError`].
pub fn import_mesh(path: &Path) -> Result<TriMesh, String> {
    check_files(path)?;
    let (doc, buffers, _images) = gltf::import(path).map_err(|e| e.to_string())?;
    import_document(&doc, &buffers)
}

/// Refuses a mesh file, or a buffer it names, that is not a regular file (a device such
/// as /dev/zero is read without end) or that is shorter than the buffer's `byteLength`.
fn check_files(path: &Path) -> Result<(), String> {
    let regular = |p: &Path| std::fs::metadata(p).map(|m| m.is_file().then_some(m.len()));
    match regular(path) {
        Ok(Some(_)) => {}
        Ok(None) => return Err("not a regular file".into()),
        Err(e) => return Err(e.to_string()),
    }
    // The JSON (or the .glb's JSON chunk) alone, to see which files its buffers name.
    let gltf = gltf::Gltf::open(path).map_err(|e| e.to_string())?;
    let base = path.parent().unwrap_or(Path::new("."));
    for buffer in gltf.buffers() {
        let gltf::buffer::Source::Uri(uri) = buffer.source() else { continue };
        // Embedded data, or a percent-encoded name (which the importer decodes): left to it.
        if uri.starts_with("data:") || uri.contains('%') {
            continue;
        }
        let file = base.join(uri);
        match regular(&file) {
            Ok(Some(len)) if len >= buffer.length() as u64 => {}
            Ok(Some(len)) => {
                return Err(format!(
                    "buffer {} ({uri}): the file holds {len} bytes, the buffer's byteLength says {}",
                    buffer.index(),
                    buffer.length()
                ));
            }
            Ok(None) => return Err(format!("buffer {} ({uri}): not a regular file", buffer.index())),
            Err(e) => return Err(format!("buffer {} ({uri}): {e}", buffer.index())),
        }
    }
    Ok(())
}

/// Like [`import_mesh`] for bytes already in memory.
pub fn import_mesh_slice(bytes: &[u8]) -> Result<TriMesh, String> {
    let (doc, buffers, _images) = gltf::import_slice(bytes).map_err(|e| e.to_string())?;
    import_document(&doc, &buffers)
}

/// Imports a mesh for a world object, naming the world file in errors.
pub fn import_object_mesh(world_file: &Path, mesh: &str) -> Result<TriMesh, WorldError> {
    let path = world_file.parent().unwrap_or(Path::new(".")).join(mesh);
    import_mesh(&path).map_err(|message| WorldError::Mesh { file: world_file.to_path_buf(), mesh: path, message })
}

fn import_document(doc: &gltf::Document, buffers: &[gltf::buffer::Data]) -> Result<TriMesh, String> {
    let scene = doc.default_scene().or_else(|| doc.scenes().next()).ok_or("the file has no scene")?;
    let mut out = TriMesh::default();
    let identity = [[1.0f32, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];
    // Depth first with a stack of our own, not recursion: a file's node graph may be
    // deep enough to overflow the thread's stack, or (against the spec) hold a cycle.
    let mut seen = vec![false; doc.nodes().len()];
    let mut stack: Vec<(gltf::Node, [[f32; 4]; 4], usize)> = scene.nodes().map(|n| (n, identity, 1)).collect();
    stack.reverse();
    while let Some((node, parent, depth)) = stack.pop() {
        if depth > MAX_NODE_DEPTH {
            return Err(format!("node {} is nested more than {MAX_NODE_DEPTH} levels deep", node.index()));
        }
        let Some(seen) = seen.get_mut(node.index()) else {
            return Err(format!("node {} does not exist", node.index()));
        };
        if std::mem::replace(seen, true) {
            return Err(format!(
                "node {} is reached twice: the node graph is not a tree (a cycle, or a shared child)",
                node.index()
            ));
        }
        let world = add_node_meshes(&node, parent, buffers, &mut out)?;
        let children: Vec<gltf::Node> = node.children().collect();
        stack.extend(children.into_iter().rev().map(|c| (c, world, depth + 1)));
    }
    if out.positions.is_empty() {
        return Err("the file has no triangle meshes".into());
    }
    // y-up (glTF) to z-up (ours): (x, y, z) -> (x, -z, y).
    for p in &mut out.positions {
        *p = [p[0], -p[2], p[1]];
    }
    for n in &mut out.normals {
        *n = [n[0], -n[2], n[1]];
    }
    Ok(out)
}

fn mat_mul(a: [[f32; 4]; 4], b: [[f32; 4]; 4]) -> [[f32; 4]; 4] {
    // Column-major: (a * b)[c][r] = sum_k a[k][r] * b[c][k].
    let mut m = [[0.0f32; 4]; 4];
    for c in 0..4 {
        for r in 0..4 {
            m[c][r] = (0..4).map(|k| a[k][r] * b[c][k]).sum();
        }
    }
    m
}

/// Deepest node nesting a mesh file may have (real scenes nest a few levels).
pub const MAX_NODE_DEPTH: usize = 256;

/// Appends `node`'s own triangles, placed by `parent`'s transform and its own; returns its
/// world transform for its children.
fn add_node_meshes(
    node: &gltf::Node,
    parent: [[f32; 4]; 4],
    buffers: &[gltf::buffer::Data],
    out: &mut TriMesh,
) -> Result<[[f32; 4]; 4], String> {
    let world = mat_mul(parent, node.transform().matrix());
    if let Some(mesh) = node.mesh() {
        for prim in mesh.primitives() {
            if prim.mode() != gltf::mesh::Mode::Triangles {
                continue;
            }
            let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            let positions: Vec<[f32; 3]> =
                reader.read_positions().ok_or("a primitive has no POSITION attribute")?.collect();
            let n = positions.len();
            let normals: Vec<[f32; 3]> =
                reader.read_normals().map(|r| r.collect()).unwrap_or_else(|| vec![[0.0, 0.0, 1.0]; n]);
            let uvs: Vec<[f32; 2]> =
                reader.read_tex_coords(0).map(|r| r.into_f32().collect()).unwrap_or_else(|| vec![[0.0, 0.0]; n]);
            let indices: Vec<u32> = match reader.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..n as u32).collect(),
            };
            if let Some(bad) = indices.iter().find(|&&i| i as usize >= n) {
                return Err(format!("index {bad} out of range for {n} vertices"));
            }
            let base = out.positions.len() as u32;
            for (p, nrm) in positions.iter().zip(&normals) {
                let tp: [f32; 3] =
                    std::array::from_fn(|r| world[0][r] * p[0] + world[1][r] * p[1] + world[2][r] * p[2] + world[3][r]);
                let tn: [f32; 3] =
                    std::array::from_fn(|r| world[0][r] * nrm[0] + world[1][r] * nrm[1] + world[2][r] * nrm[2]);
                out.positions.push(tp);
                out.normals.push(tn);
            }
            out.uvs.extend(uvs);
            out.indices.extend(indices.iter().map(|i| i + base));
        }
    }
    Ok(world)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::generate::{ParkParams, park};

    /// A glTF document whose node `i` has the children `children(i)`, scene root node 0.
    fn gltf_with_nodes(n: usize, children: impl Fn(usize) -> Vec<usize>) -> Vec<u8> {
        let nodes: Vec<serde_json::Value> = (0..n).map(|i| serde_json::json!({"children": children(i)})).collect();
        serde_json::to_vec(
            &serde_json::json!({"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": nodes}),
        )
        .unwrap()
    }

    #[test]
    fn node_cycles_and_deep_nesting_are_errors_not_stack_overflows() {
        let cycle = gltf_with_nodes(2, |i| vec![1 - i]);
        let e = import_mesh_slice(&cycle).unwrap_err();
        assert!(e.contains("reached twice") || e.contains("cycle") || e.contains("invalid"), "{e}");
        let deep = gltf_with_nodes(200_000, |i| if i + 1 < 200_000 { vec![i + 1] } else { vec![] });
        let e = import_mesh_slice(&deep).unwrap_err();
        assert!(e.contains("levels deep"), "{e}");
    }

    #[test]
    fn glb_export_then_import_keeps_vertex_counts_and_bounds() {
        let world = park(&ParkParams::default(), 3).unwrap();
        let bytes = export_glb(&world);
        let imported = import_mesh_slice(&bytes).unwrap();
        let mut expected = TriMesh::default();
        for p in static_world_parts(&world) {
            expected.append(&p.mesh);
        }
        // People add four parts each.
        let people_vertices: usize = world
            .people
            .iter()
            .map(|p| {
                let pp = person_parts(p);
                pp.left_leg.mesh.vertex_count()
                    + pp.right_leg.mesh.vertex_count()
                    + pp.body.mesh.vertex_count()
                    + pp.head.mesh.vertex_count()
            })
            .sum();
        assert_eq!(imported.vertex_count(), expected.vertex_count() + people_vertices);
        let (lo, hi) = expected.bounds();
        let (ilo, ihi) = imported.bounds();
        for k in 0..3 {
            assert!((lo[k] - ilo[k]).abs() < 1e-3 || k == 2, "min[{k}] {} vs {}", lo[k], ilo[k]);
            assert!((hi[k] - ihi[k]).abs() < 1e-3, "max[{k}] {} vs {}", hi[k], ihi[k]);
        }
    }

    #[test]
    fn a_buffer_that_is_not_a_regular_file_or_shorter_than_declared_is_refused() {
        let dir = std::env::temp_dir().join(format!("objslam-gltf-buffers-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("mesh.gltf");
        let with_buffer = |uri: &str, length: usize| {
            let doc = serde_json::json!({"asset": {"version": "2.0"}, "buffers": [{"uri": uri, "byteLength": length}]});
            std::fs::write(&file, serde_json::to_vec(&doc).unwrap()).unwrap();
            import_mesh(&file).unwrap_err()
        };
        // A device is read without end (it took memory until killed).
        let e = with_buffer("/dev/zero", 1_000_000_000);
        assert!(e.contains("buffer 0 (/dev/zero): not a regular file"), "{e}");
        std::fs::write(dir.join("small.bin"), [0u8; 10]).unwrap();
        let e = with_buffer("small.bin", 1000);
        assert!(e.contains("holds 10 bytes") && e.contains("1000"), "{e}");
        assert_eq!(import_mesh(&dir).unwrap_err(), "not a regular file");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn not_a_gltf_file_is_a_clear_error() {
        let err = import_mesh_slice(b"solid cube\nfacet normal 0 0 1\n").unwrap_err();
        assert!(!err.is_empty());
    }
}
