//! glTF 2.0: export a whole world as one binary `.glb` that opens in any viewer, and
//! import user meshes through the `gltf` crate.
//!
//! glTF is y-up; our worlds are z-up (REP-103). Export puts every part under one root node
//! rotated -90 deg about x; import applies node transforms and maps y-up back to z-up, so
//! an export/import round trip returns the original coordinates.

use std::io::Cursor;
use std::path::Path;

use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::Mode;
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
            // Single-sided: the parts are closed and wound outwards wherever they can be
            // seen, and carry both windings where both sides show (mesh.rs), so a viewer
            // may cull back faces, and importing the file again does not double them.
            "doubleSided": false
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
/// node transforms. Errors are strings for embedding in [`WorldError`]. Only the buffers
/// are read: images are neither read nor decoded (a world's look comes from its classes).
pub fn import_mesh(path: &Path) -> Result<TriMesh, String> {
    let gltf = open_checked(path)?;
    let base = path.parent().unwrap_or(Path::new("."));
    let buffers = gltf::import_buffers(&gltf.document, Some(base), gltf.blob)
        .map_err(|e| format!("a buffer could not be read: {e}"))?;
    import_document(&gltf.document, &buffers)
}

/// Why a file could not be opened as glTF, in a user's terms: the parser says only what
/// it met ("failed to fill whole buffer", a JSON position), not what the file is.
fn unreadable(path: &Path, e: gltf::Error) -> String {
    use std::io::Read;
    let mut head = [0u8; 4];
    let read = std::fs::File::open(path).and_then(|mut f| f.read(&mut head)).unwrap_or(0);
    let head = &head[..read];
    if head == b"glTF" {
        format!("a binary glTF (.glb) that cannot be read, cut short or damaged: {e}")
    } else if head.first().is_some_and(|b| *b == b'{') {
        format!("not glTF 2.0 JSON: {e}")
    } else {
        format!("not a glTF 2.0 file (JSON .gltf or binary .glb; OBJ, STL and PLY are not read): {e}")
    }
}

/// Opens a glTF/.glb file after refusing one, or a buffer it names, that is not a regular
/// file (a device such as /dev/zero is read without end) or that is shorter than the
/// buffer's `byteLength`, and a buffer URI that does not decode to a file name (the
/// importer panics on one).
fn open_checked(path: &Path) -> Result<gltf::Gltf, String> {
    let regular = |p: &Path| std::fs::metadata(p).map(|m| m.is_file().then_some(m.len()));
    match regular(path) {
        Ok(Some(_)) => {}
        Ok(None) => return Err("not a regular file".into()),
        Err(e) => return Err(e.to_string()),
    }
    // The JSON (or the .glb's JSON chunk and its binary chunk).
    let gltf = gltf::Gltf::open(path).map_err(|e| unreadable(path, e))?;
    let base = path.parent().unwrap_or(Path::new("."));
    for buffer in gltf.buffers() {
        let gltf::buffer::Source::Uri(uri) = buffer.source() else { continue };
        let named = || format!("buffer {} ({uri})", buffer.index());
        let file = match buffer_file(base, uri) {
            Some(Ok(file)) => file,
            Some(Err(problem)) => return Err(format!("{}: {problem}", named())),
            None => continue,
        };
        match regular(&file) {
            Ok(Some(len)) if len >= buffer.length() as u64 => {}
            Ok(Some(len)) => {
                return Err(format!(
                    "{}: the file holds {len} bytes, the buffer's byteLength says {}",
                    named(),
                    buffer.length()
                ));
            }
            Ok(None) => return Err(format!("{}: not a regular file", named())),
            Err(e) => return Err(format!("{}: {}: {e}", named(), file.display())),
        }
    }
    Ok(gltf)
}

/// The file a buffer's `uri` names, resolved as the importer resolves it: `file:` names
/// as written, other names relative to the glTF file's directory `base`, percent-decoded.
/// `None` for other schemes (data URIs), which are the importer's to read or refuse.
fn buffer_file(base: &Path, uri: &str) -> Option<Result<std::path::PathBuf, String>> {
    if let Some(rest) = uri.strip_prefix("file://").or_else(|| uri.strip_prefix("file:")) {
        Some(Ok(std::path::PathBuf::from(rest)))
    } else if uri.contains(':') {
        None
    } else {
        Some(
            urlencoding::decode(uri)
                .map(|decoded| base.join(&*decoded))
                .map_err(|_| "its percent-encoded name is not UTF-8 text".to_string()),
        )
    }
}

/// The files beside a glTF file that its buffers name (a `.gltf` with a `.bin`), which a
/// world holding the mesh needs as much as the mesh file itself; empty for a file that
/// cannot be opened as glTF.
pub fn buffer_files(path: &Path) -> Vec<std::path::PathBuf> {
    let Ok(gltf) = gltf::Gltf::open(path) else { return Vec::new() };
    let base = path.parent().unwrap_or(Path::new("."));
    gltf.buffers()
        .filter_map(|b| match b.source() {
            gltf::buffer::Source::Uri(uri) => buffer_file(base, uri)?.ok(),
            gltf::buffer::Source::Bin => None,
        })
        .collect()
}

/// Like [`import_mesh`] for bytes already in memory (buffers must be embedded).
pub fn import_mesh_slice(bytes: &[u8]) -> Result<TriMesh, String> {
    let gltf = gltf::Gltf::from_slice(bytes).map_err(|e| e.to_string())?;
    let buffers = gltf::import_buffers(&gltf.document, None, gltf.blob).map_err(|e| e.to_string())?;
    import_document(&gltf.document, &buffers)
}

/// Imports a mesh for a world object, naming the world file in errors.
pub fn import_object_mesh(world_file: &Path, mesh: &str) -> Result<TriMesh, WorldError> {
    let path = world_file.parent().unwrap_or(Path::new(".")).join(mesh);
    import_mesh(&path).map_err(|message| WorldError::Mesh { file: world_file.to_path_buf(), mesh: path, message })
}

/// Refuses what glTF 2.0 forbids and a file could still hold, which would be read as
/// some other placement: another version, a node with both a matrix and
/// translation/rotation/scale (the matrix would win silently), a matrix that is not affine,
/// a rotation that is not a unit quaternion.
fn check_document(doc: &gltf::Document) -> Result<(), String> {
    let json = doc.as_json();
    if !json.asset.version.starts_with("2.") {
        return Err(format!("asset.version is {:?}; glTF 2.0 files are read", json.asset.version));
    }
    for (i, node) in json.nodes.iter().enumerate() {
        if let Some(m) = node.matrix {
            if node.translation.is_some() || node.rotation.is_some() || node.scale.is_some() {
                return Err(format!(
                    "node {i}: both a matrix and translation, rotation or scale; glTF allows one or the other"
                ));
            }
            if [m[3], m[7], m[11], m[15]] != [0.0, 0.0, 0.0, 1.0] {
                return Err(format!("node {i}: the matrix's last row is not (0, 0, 0, 1)"));
            }
        }
        if let Some(q) = &node.rotation {
            let length = q.0.iter().map(|v| v * v).sum::<f32>().sqrt();
            // Exporters write unit quaternions to single precision.
            if !((length - 1.0).abs() <= 1e-3) {
                return Err(format!("node {i}: rotation {:?} is not a unit quaternion (length {length})", q.0));
            }
        }
    }
    Ok(())
}

fn import_document(doc: &gltf::Document, buffers: &[gltf::buffer::Data]) -> Result<TriMesh, String> {
    check_document(doc)?;
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
    if world.iter().flatten().any(|v| !v.is_finite()) {
        return Err(format!("node {}: its transform is not finite", node.index()));
    }
    let Some(mesh) = node.mesh() else { return Ok(world) };
    for prim in mesh.primitives() {
        let at = || format!("mesh {} primitive {}", mesh.index(), prim.index());
        // Points and lines have no surface for a laser or a camera to meet.
        let mode = prim.mode();
        if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
            continue;
        }
        let position =
            prim.get(&gltf::Semantic::Positions).ok_or_else(|| format!("{}: no POSITION attribute", at()))?;
        let n = check_accessor(&position, &format!("{}: POSITION", at()), Dimensions::Vec3, &[FLOAT], buffers)?;
        let normal = prim.get(&gltf::Semantic::Normals);
        if let Some(a) = &normal {
            check_same_count(a, n, &format!("{}: NORMAL", at()), Dimensions::Vec3, &[FLOAT], buffers)?;
        }
        let uv = prim.get(&gltf::Semantic::TexCoords(0));
        if let Some(a) = &uv {
            check_same_count(a, n, &format!("{}: TEXCOORD_0", at()), Dimensions::Vec2, TEXCOORD_TYPES, buffers)?;
        }
        let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
        let unread = |what: &str| format!("{}: its {what} accessor could not be read", at());
        let positions: Vec<[f32; 3]> = reader.read_positions().ok_or_else(|| unread("POSITION"))?.collect();
        let normals: Option<Vec<[f32; 3]>> = match normal {
            Some(_) => Some(reader.read_normals().ok_or_else(|| unread("NORMAL"))?.collect()),
            None => None,
        };
        let uvs: Vec<[f32; 2]> = match uv {
            Some(_) => reader.read_tex_coords(0).ok_or_else(|| unread("TEXCOORD_0"))?.into_f32().collect(),
            None => vec![[0.0, 0.0]; n],
        };
        // The renderer refuses them later, naming no file; a .glb may not hold them.
        if let Some(k) = uvs.iter().position(|uv| uv.iter().any(|v| !v.is_finite())) {
            return Err(format!("{}: TEXCOORD_0 value {k} is not finite ({:?})", at(), uvs[k]));
        }
        let vertices: Vec<u32> = match prim.indices() {
            Some(a) => {
                check_accessor(&a, &format!("{}: indices", at()), Dimensions::Scalar, INDEX_TYPES, buffers)?;
                reader.read_indices().ok_or_else(|| unread("indices"))?.into_u32().collect()
            }
            None => (0..n as u32).collect(),
        };
        if positions.len() != n || normals.as_ref().is_some_and(|v| v.len() != n) || uvs.len() != n {
            return Err(format!("{}: its attributes read {} positions for a count of {n}", at(), positions.len()));
        }
        if let Some(bad) = vertices.iter().find(|&&i| i as usize >= n) {
            return Err(format!("{}: index {bad} out of range for {n} vertices", at()));
        }
        let mut indices = triangle_list(mode, &vertices).map_err(|e| format!("{}: {e}", at()))?;
        // A mirroring transform turns the triangles' winding inside out: wind them back, so
        // that their front faces still face out.
        let linear = [
            [world[0][0], world[0][1], world[0][2]],
            [world[1][0], world[1][1], world[1][2]],
            [world[2][0], world[2][1], world[2][2]],
        ];
        let det = determinant(&linear);
        if det < 0.0 {
            indices.chunks_exact_mut(3).for_each(|t| t.swap(1, 2));
        }
        let mut tps = Vec::with_capacity(n);
        for p in &positions {
            let tp: [f32; 3] =
                std::array::from_fn(|r| world[0][r] * p[0] + world[1][r] * p[1] + world[2][r] * p[2] + world[3][r]);
            if tp.iter().any(|v| !v.is_finite()) {
                return Err(format!("{}: a position is not finite ({p:?})", at()));
            }
            tps.push(tp);
        }
        let base = out.positions.len() as u32;
        let first_index = out.indices.len();
        match normals {
            Some(normals) => {
                // Normals go by the inverse transpose (the cofactors, signed by the
                // determinant), so a non-uniform scale keeps them perpendicular to the faces.
                let cof = cofactors(&linear);
                for nrm in &normals {
                    let tn: [f32; 3] = std::array::from_fn(|r| {
                        det.signum() * (cof[0][r] * nrm[0] + cof[1][r] * nrm[1] + cof[2][r] * nrm[2])
                    });
                    let length = (tn[0] * tn[0] + tn[1] * tn[1] + tn[2] * tn[2]).sqrt();
                    if !(length.is_finite() && length > 0.0) {
                        return Err(format!("{}: a normal is not finite or is zero once placed ({nrm:?})", at()));
                    }
                    out.normals.push(tn.map(|v| v / length));
                }
                out.positions.extend(tps);
                out.uvs.extend(uvs);
                out.indices.extend(indices.iter().map(|i| i + base));
            }
            None => {
                // glTF: without normals, a primitive is drawn with flat normals, one per
                // triangle, so each triangle gets vertices of its own.
                for (k, t) in indices.chunks_exact(3).enumerate() {
                    let [a, b, c] = [t[0], t[1], t[2]].map(|i| tps[i as usize]);
                    let (u, v) = ([b[0] - a[0], b[1] - a[1], b[2] - a[2]], [c[0] - a[0], c[1] - a[1], c[2] - a[2]]);
                    let face = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
                    let length = (face[0] * face[0] + face[1] * face[1] + face[2] * face[2]).sqrt();
                    // A triangle of no area has no side to light: any unit normal will do.
                    let unit = if length > 0.0 { face.map(|f| f / length) } else { [0.0, 0.0, 1.0] };
                    for &i in t {
                        out.positions.push(tps[i as usize]);
                        out.normals.push(unit);
                        out.uvs.push(uvs[i as usize]);
                    }
                    out.indices.extend([0, 1, 2].map(|j| base + 3 * k as u32 + j));
                }
            }
        }
        if prim.material().double_sided() {
            add_back_faces(out, base as usize, first_index);
        }
    }
    Ok(world)
}

/// A double-sided material is seen from both sides (glTF 2.0, 3.9.5), where a mesh's
/// back faces may be culled: its triangles from vertex `first_vertex` and index
/// `first_index` on get twins wound the other way, with their normals turned over, as
/// the procedural meshes carry both windings where both sides show.
fn add_back_faces(out: &mut TriMesh, first_vertex: usize, first_index: usize) {
    let shift = (out.positions.len() - first_vertex) as u32;
    for k in first_vertex..out.positions.len() {
        out.positions.push(out.positions[k]);
        out.normals.push(out.normals[k].map(|v| -v));
        out.uvs.push(out.uvs[k]);
    }
    let back: Vec<u32> = out.indices[first_index..].chunks_exact(3).flat_map(|t| [t[0], t[2], t[1]]).collect();
    out.indices.extend(back.iter().map(|i| i + shift));
}

fn determinant(m: &[[f32; 3]; 3]) -> f32 {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[1][0] * (m[0][1] * m[2][2] - m[0][2] * m[2][1])
        + m[2][0] * (m[0][1] * m[1][2] - m[0][2] * m[1][1])
}

/// The cofactor matrix of `m` (same column-major layout): det(m) times its inverse
/// transpose, defined even where `m` is singular.
fn cofactors(m: &[[f32; 3]; 3]) -> [[f32; 3]; 3] {
    // Columns c0, c1, c2: the cofactor matrix's columns are c1 x c2, c2 x c0, c0 x c1.
    let cross =
        |a: [f32; 3], b: [f32; 3]| [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    [cross(m[1], m[2]), cross(m[2], m[0]), cross(m[0], m[1])]
}

/// Component types an attribute may have: the type, and whether it is normalized.
type ComponentTypes = &'static [(DataType, bool)];
const FLOAT: (DataType, bool) = (DataType::F32, false);
const TEXCOORD_TYPES: ComponentTypes = &[FLOAT, (DataType::U8, true), (DataType::U16, true)];
const INDEX_TYPES: ComponentTypes = &[(DataType::U8, false), (DataType::U16, false), (DataType::U32, false)];

/// Checks that an accessor has a type glTF allows for `what` and that its elements lie
/// inside its buffer view and the view inside its buffer; returns its count. The `gltf`
/// crate's reader assumes all of it: it reads a VEC2 or byte accessor as three floats,
/// reports data past a view's end as a missing attribute, and panics on float indices.
fn check_accessor(
    a: &gltf::Accessor,
    what: &str,
    dims: Dimensions,
    types: ComponentTypes,
    buffers: &[gltf::buffer::Data],
) -> Result<usize, String> {
    let named = format!("{what} (accessor {})", a.index());
    let kind = (a.data_type(), a.normalized());
    if a.dimensions() != dims || !types.contains(&kind) {
        let allowed: Vec<String> = types.iter().map(|&t| component_name(t)).collect();
        return Err(format!(
            "{named} is {} of {}; glTF allows {} of {}",
            dimensions_name(a.dimensions()),
            component_name(kind),
            dimensions_name(dims),
            allowed.join(" or ")
        ));
    }
    if a.sparse().is_some() {
        return Err(format!("{named} is sparse, which objslam does not read: write its values out in a buffer view"));
    }
    let Some(view) = a.view() else {
        return Err(format!("{named} has no bufferView (all its values would be zero)"));
    };
    let count = a.count();
    if count == 0 {
        return Err(format!("{named} has no elements (count 0)"));
    }
    let size = a.size();
    let stride = view.stride().unwrap_or(size);
    if stride < size {
        return Err(format!(
            "{named}: buffer view {}'s byteStride {stride} is less than an element's {size} bytes",
            view.index()
        ));
    }
    let buffer = view.buffer().index();
    let data_len = buffers.get(buffer).map_or(0, |d| d.0.len());
    if view.offset().checked_add(view.length()).is_none_or(|end| end > data_len) {
        return Err(format!(
            "buffer view {} (byteOffset {}, byteLength {}) runs past the end of buffer {buffer} ({data_len} bytes)",
            view.index(),
            view.offset(),
            view.length()
        ));
    }
    let end = (count - 1).checked_mul(stride).and_then(|b| b.checked_add(size)).and_then(|b| b.checked_add(a.offset()));
    if end.is_none_or(|end| end > view.length()) {
        return Err(format!(
            "{named}: {count} elements of {size} bytes from byteOffset {} run past the end of buffer view {} ({} bytes)",
            a.offset(),
            view.index(),
            view.length()
        ));
    }
    Ok(count)
}

/// [`check_accessor`] for a vertex attribute beside POSITION, which must have as many
/// elements as there are vertices.
fn check_same_count(
    a: &gltf::Accessor,
    vertices: usize,
    what: &str,
    dims: Dimensions,
    types: ComponentTypes,
    buffers: &[gltf::buffer::Data],
) -> Result<(), String> {
    let count = check_accessor(a, what, dims, types, buffers)?;
    if count != vertices {
        return Err(format!("{what} (accessor {}) has {count} elements for {vertices} vertices", a.index()));
    }
    Ok(())
}

fn dimensions_name(d: Dimensions) -> String {
    format!("{d:?}").to_uppercase()
}

fn component_name((t, normalized): (DataType, bool)) -> String {
    let name = match t {
        DataType::I8 => "signed byte",
        DataType::U8 => "unsigned byte",
        DataType::I16 => "signed short",
        DataType::U16 => "unsigned short",
        DataType::U32 => "unsigned int",
        DataType::F32 => "float",
    };
    if normalized { format!("normalized {name}") } else { name.to_string() }
}

/// The vertex indices of a primitive's triangles, one triple each, from a list, strip or
/// fan (glTF 2.0, section 3.7.2.1: strips alternate so that every triangle keeps the
/// winding of the first).
fn triangle_list(mode: Mode, v: &[u32]) -> Result<Vec<u32>, String> {
    match mode {
        Mode::Triangles if v.len().is_multiple_of(3) => Ok(v.to_vec()),
        Mode::Triangles => Err(format!("{} vertex indices do not make whole triangles", v.len())),
        _ if v.len() < 3 => Err(format!("a triangle strip or fan of {} vertices has no triangle", v.len())),
        Mode::TriangleStrip => Ok((0..v.len() - 2)
            .flat_map(|i| if i % 2 == 0 { [v[i], v[i + 1], v[i + 2]] } else { [v[i], v[i + 2], v[i + 1]] })
            .collect()),
        Mode::TriangleFan => Ok((0..v.len() - 2).flat_map(|i| [v[i + 1], v[i + 2], v[0]]).collect()),
        _ => Err(format!("{mode:?} is not a triangle mode")),
    }
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
        // Names are resolved as the importer resolves them: percent-decoded, or `file:`.
        let e = with_buffer("%2Fdev%2Fzero", 1_000_000_000);
        assert!(e.contains("buffer 0 (%2Fdev%2Fzero): not a regular file"), "{e}");
        let e = with_buffer("file:///dev/zero", 1_000_000_000);
        assert!(e.contains("buffer 0 (file:///dev/zero): not a regular file"), "{e}");
        // The importer panicked on a name that decodes to bytes that are not UTF-8.
        let e = with_buffer("%FF.bin", 10);
        assert!(e.contains("buffer 0 (%FF.bin): its percent-encoded name is not UTF-8 text"), "{e}");
        // Images are not read: one that names a missing file does not stop the mesh.
        let triangle = f32_bytes([0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0].iter());
        std::fs::write(dir.join("tri.bin"), triangle).unwrap();
        let doc = serde_json::json!({
            "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, -1], "max": [1, 0, 0]}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}], "buffers": [{"uri": "tri.bin", "byteLength": 36}],
            "images": [{"uri": "missing.png"}]
        });
        std::fs::write(&file, serde_json::to_vec(&doc).unwrap()).unwrap();
        assert_eq!(import_mesh(&file).unwrap().indices, vec![0, 1, 2]);
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A `.glb` with one mesh of one primitive over `bin`: accessors, views (into the one
    /// buffer) and the primitive as given.
    fn glb_with(
        bin: &[u8],
        views: serde_json::Value,
        accessors: serde_json::Value,
        primitive: serde_json::Value,
    ) -> Vec<u8> {
        let root = serde_json::json!({
            "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [primitive]}], "accessors": accessors, "bufferViews": views,
            "buffers": [{"byteLength": bin.len()}]
        });
        glb_bytes(&root, bin)
    }

    /// Four vertices of a unit square in glTF's x-z plane (y up), as floats.
    fn square() -> Vec<u8> {
        f32_bytes([0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, -1.0].iter())
    }

    fn positions(count: usize) -> serde_json::Value {
        serde_json::json!({"bufferView": 0, "componentType": 5126, "count": count, "type": "VEC3", "min": [0, 0, -1], "max": [1, 0, 0]})
    }

    #[test]
    fn attributes_of_a_type_gltf_does_not_allow_are_refused_by_name() {
        let bin = square();
        let view = serde_json::json!([{"buffer": 0, "byteLength": 48}]);
        let vec2 = serde_json::json!([{"bufferView": 0, "componentType": 5126, "count": 6, "type": "VEC2", "min": [0, 0, 0], "max": [1, 1, 1]}]);
        let e =
            import_mesh_slice(&glb_with(&bin, view.clone(), vec2, serde_json::json!({"attributes": {"POSITION": 0}})))
                .unwrap_err();
        assert_eq!(e, "mesh 0 primitive 0: POSITION (accessor 0) is VEC2 of float; glTF allows VEC3 of float");
        let bytes = serde_json::json!([{"bufferView": 0, "componentType": 5121, "count": 12, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 1]}]);
        let e =
            import_mesh_slice(&glb_with(&bin, view.clone(), bytes, serde_json::json!({"attributes": {"POSITION": 0}})))
                .unwrap_err();
        assert!(e.ends_with("is VEC3 of unsigned byte; glTF allows VEC3 of float"), "{e}");
        // Float indices made the reader panic.
        let mut with_indices = bin.clone();
        with_indices.extend(f32_bytes([0.0f32, 1.0, 2.0].iter()));
        let views =
            serde_json::json!([{"buffer": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 12}]);
        let accessors =
            serde_json::json!([positions(4), {"bufferView": 1, "componentType": 5126, "count": 3, "type": "SCALAR"}]);
        let e = import_mesh_slice(&glb_with(
            &with_indices,
            views,
            accessors,
            serde_json::json!({"attributes": {"POSITION": 0}, "indices": 1}),
        ))
        .unwrap_err();
        assert!(e.contains("indices (accessor 1) is SCALAR of float; glTF allows SCALAR of unsigned byte or unsigned short or unsigned int"), "{e}");
        // A normal per vertex, or none: three normals for four vertices once let an index
        // point past the vertices kept.
        let mut with_normals = bin.clone();
        with_normals.extend(f32_bytes([0.0f32, 1.0, 0.0].repeat(3).iter()));
        let views =
            serde_json::json!([{"buffer": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 36}]);
        let accessors =
            serde_json::json!([positions(4), {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC3"}]);
        let e = import_mesh_slice(&glb_with(
            &with_normals,
            views,
            accessors,
            serde_json::json!({"attributes": {"POSITION": 0, "NORMAL": 1}, "mode": 5}),
        ))
        .unwrap_err();
        assert_eq!(e, "mesh 0 primitive 0: NORMAL (accessor 1) has 3 elements for 4 vertices");
    }

    #[test]
    fn accessors_past_their_data_are_refused_not_read_as_missing() {
        let bin = square();
        let primitive = serde_json::json!({"attributes": {"POSITION": 0}, "mode": 5});
        let view = serde_json::json!([{"buffer": 0, "byteLength": 48}]);
        let e = import_mesh_slice(&glb_with(
            &bin,
            view.clone(),
            serde_json::json!([positions(1_000_000_000)]),
            primitive.clone(),
        ))
        .unwrap_err();
        assert!(e.contains("POSITION (accessor 0): 1000000000 elements of 12 bytes from byteOffset 0 run past the end of buffer view 0 (48 bytes)"), "{e}");
        let long_view = serde_json::json!([{"buffer": 0, "byteOffset": 4, "byteLength": 48}]);
        let e = import_mesh_slice(&glb_with(&bin, long_view, serde_json::json!([positions(4)]), primitive.clone()))
            .unwrap_err();
        assert!(
            e.contains("buffer view 0 (byteOffset 4, byteLength 48) runs past the end of buffer 0 (48 bytes)"),
            "{e}"
        );
        let no_view = serde_json::json!([{"componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [0, 0, 0]}]);
        // The glTF reader's validation refuses this one before the accessor checks.
        let e = import_mesh_slice(&glb_with(&bin, view, no_view, primitive)).unwrap_err();
        assert!(e.contains("bufferView"), "{e}");
    }

    #[test]
    fn strips_and_fans_become_triangles_and_a_partial_triangle_is_refused() {
        // With normals, so the vertices stay shared and the indices show the triangles.
        let mut bin = square();
        bin.extend(f32_bytes([0.0f32, 1.0, 0.0].iter().cycle().take(12)));
        let view = serde_json::json!([{"buffer": 0, "byteLength": 96}]);
        let normals =
            serde_json::json!({"bufferView": 0, "byteOffset": 48, "componentType": 5126, "count": 4, "type": "VEC3"});
        let import = |mode: u32| {
            import_mesh_slice(&glb_with(
                &bin,
                view.clone(),
                serde_json::json!([positions(4), normals]),
                serde_json::json!({"attributes": {"POSITION": 0, "NORMAL": 1}, "mode": mode}),
            ))
        };
        // The strip's second triangle keeps the first's winding.
        assert_eq!(import(5).unwrap().indices, vec![0, 1, 2, 1, 3, 2]);
        assert_eq!(import(6).unwrap().indices, vec![1, 2, 0, 2, 3, 0]);
        assert_eq!(import(4).unwrap_err(), "mesh 0 primitive 0: 4 vertex indices do not make whole triangles");
        // Lines have no surface: with nothing else the file has no triangles.
        assert_eq!(import(1).unwrap_err(), "the file has no triangle meshes");
    }

    /// A node's mirroring or non-uniform scale keeps faces facing out and normals
    /// perpendicular to them; a primitive without normals gets flat ones (glTF's rule).
    #[test]
    fn transforms_keep_normals_on_their_faces_and_missing_normals_are_flat() {
        // One triangle in glTF's x-z plane, its normal up (+y) and declared.
        let mut bin = f32_bytes([0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0].iter());
        bin.extend(f32_bytes([0.0f32, 1.0, 0.0].iter().cycle().take(9)));
        let import = |node: serde_json::Value, with_normals: bool| {
            let attributes = if with_normals {
                serde_json::json!({"POSITION": 0, "NORMAL": 1})
            } else {
                serde_json::json!({"POSITION": 0})
            };
            let root = serde_json::json!({
                "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [node],
                "meshes": [{"primitives": [{"attributes": attributes}]}],
                "accessors": [
                    {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, -1], "max": [1, 0, 0]},
                    {"bufferView": 0, "byteOffset": 36, "componentType": 5126, "count": 3, "type": "VEC3"}
                ],
                "bufferViews": [{"buffer": 0, "byteLength": 72}], "buffers": [{"byteLength": 72}]
            });
            import_mesh_slice(&glb_bytes(&root, &bin)).unwrap()
        };
        // The face's normal from its vertices as wound, and the stored normal.
        let face_and_stored = |m: &TriMesh| {
            let [a, b, c] = [0, 1, 2].map(|k| m.positions[m.indices[k] as usize]);
            let (u, v) = ([b[0] - a[0], b[1] - a[1], b[2] - a[2]], [c[0] - a[0], c[1] - a[1], c[2] - a[2]]);
            let f = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
            let l = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
            (f.map(|x| x / l), m.normals[m.indices[0] as usize])
        };
        let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-5);
        let plain = import(serde_json::json!({"mesh": 0}), true);
        let (face, stored) = face_and_stored(&plain);
        assert!(close(face, stored), "the test's triangle faces its normal: {face:?} {stored:?}");
        // Mirrored: the winding is turned back, so the face still faces its normal.
        let mirrored = import(serde_json::json!({"mesh": 0, "scale": [-1.0, 1.0, 1.0]}), true);
        let (face, stored) = face_and_stored(&mirrored);
        assert!(close(face, stored), "mirrored: {face:?} {stored:?}");
        // Turned 45 degrees about y and stretched three times along x: the normal stays
        // perpendicular to the face (the transform itself would tilt it).
        let (s, c) = (std::f32::consts::FRAC_PI_8.sin(), std::f32::consts::FRAC_PI_8.cos());
        let sheared = serde_json::json!({"children": [1], "scale": [3.0, 1.0, 1.0]});
        let turned = serde_json::json!({"mesh": 0, "rotation": [s, 0.0, 0.0, c]});
        let two = {
            let r = serde_json::json!({
                "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [sheared, turned],
                "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}}]}],
                "accessors": [
                    {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, -1], "max": [1, 0, 0]},
                    {"bufferView": 0, "byteOffset": 36, "componentType": 5126, "count": 3, "type": "VEC3"}
                ],
                "bufferViews": [{"buffer": 0, "byteLength": 72}], "buffers": [{"byteLength": 72}]
            });
            import_mesh_slice(&glb_bytes(&r, &bin)).unwrap()
        };
        let (face, stored) = face_and_stored(&two);
        assert!(close(face, stored), "stretched: {face:?} {stored:?}");
        // Without normals: each triangle's own, facing as it is wound.
        let flat = import(serde_json::json!({"mesh": 0}), false);
        let (face, stored) = face_and_stored(&flat);
        assert!(close(face, stored), "flat: {face:?} {stored:?}");
    }

    #[test]
    fn double_sided_materials_are_seen_from_both_sides() {
        // One triangle, normal +y (glTF), with and without normals, single- or double-sided.
        let mut bin = f32_bytes([0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0].iter());
        bin.extend(f32_bytes([0.0f32, 1.0, 0.0].iter().cycle().take(9)));
        let import = |double_sided: Option<bool>, with_normals: bool| {
            let attributes = if with_normals {
                serde_json::json!({"POSITION": 0, "NORMAL": 1})
            } else {
                serde_json::json!({"POSITION": 0})
            };
            let mut primitive = serde_json::json!({"attributes": attributes});
            let mut root = serde_json::json!({
                "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
                "accessors": [
                    {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, -1], "max": [1, 0, 0]},
                    {"bufferView": 0, "byteOffset": 36, "componentType": 5126, "count": 3, "type": "VEC3"}
                ],
                "bufferViews": [{"buffer": 0, "byteLength": 72}], "buffers": [{"byteLength": 72}]
            });
            if let Some(d) = double_sided {
                root["materials"] = serde_json::json!([{"doubleSided": d}]);
                primitive["material"] = serde_json::json!(0);
            }
            root["meshes"] = serde_json::json!([{"primitives": [primitive]}]);
            import_mesh_slice(&glb_bytes(&root, &bin)).unwrap()
        };
        // The default material and an explicit single side: the triangle once.
        for single in [None, Some(false)] {
            assert_eq!(import(single, true).triangle_count(), 1);
        }
        for with_normals in [true, false] {
            let m = import(Some(true), with_normals);
            assert_eq!(m.triangle_count(), 2, "normals given: {with_normals}");
            // Every triangle faces the way its normals point: the twin faces down (-z up).
            let mut facing = Vec::new();
            for t in m.indices.chunks_exact(3) {
                let [a, b, c] = [t[0], t[1], t[2]].map(|i| m.positions[i as usize]);
                let (u, v) = ([b[0] - a[0], b[1] - a[1], b[2] - a[2]], [c[0] - a[0], c[1] - a[1], c[2] - a[2]]);
                let f = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
                let n = m.normals[t[0] as usize];
                assert!(f[0] * n[0] + f[1] * n[1] + f[2] * n[2] > 0.0, "{t:?} wound against its normal {n:?}");
                facing.push(n[2].signum());
            }
            assert_eq!(facing, [1.0, -1.0], "normals given: {with_normals}");
        }
    }

    #[test]
    fn non_finite_positions_are_refused() {
        let mut bin = square();
        bin[0..4].copy_from_slice(&f32::NAN.to_le_bytes());
        let view = serde_json::json!([{"buffer": 0, "byteLength": 48}]);
        let e = import_mesh_slice(&glb_with(
            &bin,
            view,
            serde_json::json!([positions(4)]),
            serde_json::json!({"attributes": {"POSITION": 0}, "mode": 5}),
        ))
        .unwrap_err();
        assert!(e.starts_with("mesh 0 primitive 0: a position is not finite"), "{e}");
    }

    #[test]
    fn node_transforms_gltf_forbids_are_refused() {
        let with_node = |node: serde_json::Value, version: &str| {
            let root = serde_json::json!({
                "asset": {"version": version}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [node],
                "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "mode": 5}]}],
                "accessors": [positions(4)], "bufferViews": [{"buffer": 0, "byteLength": 48}],
                "buffers": [{"byteLength": 48}]
            });
            import_mesh_slice(&glb_bytes(&root, &square()))
        };
        let identity = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1];
        with_node(serde_json::json!({"mesh": 0, "matrix": identity}), "2.0").unwrap();
        with_node(serde_json::json!({"mesh": 0, "rotation": [0, 0.6, 0, 0.8]}), "2.0").unwrap();
        let e = with_node(serde_json::json!({"mesh": 0, "matrix": identity, "translation": [1, 0, 0]}), "2.0");
        assert!(e.unwrap_err().contains("node 0: both a matrix and translation"));
        let w0 = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0];
        let e = with_node(serde_json::json!({"mesh": 0, "matrix": w0}), "2.0");
        assert!(e.unwrap_err().contains("the matrix's last row is not (0, 0, 0, 1)"));
        let e = with_node(serde_json::json!({"mesh": 0, "rotation": [0, 0, 0, 0]}), "2.0");
        assert!(e.unwrap_err().contains("is not a unit quaternion"));
        let e = with_node(serde_json::json!({"mesh": 0}), "1.0");
        assert!(e.unwrap_err().contains("asset.version is \"1.0\"; glTF 2.0 files are read"));
    }

    #[test]
    fn non_finite_texture_coordinates_are_refused() {
        let mut bin = square();
        let uv: Vec<f32> = vec![0.0, 0.0, 1.0, 0.0, f32::NAN, 1.0, 1.0, 1.0];
        bin.extend(f32_bytes(uv.iter()));
        let views =
            serde_json::json!([{"buffer": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 32}]);
        let uvs = serde_json::json!({"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"});
        let e = import_mesh_slice(&glb_with(
            &bin,
            views,
            serde_json::json!([positions(4), uvs]),
            serde_json::json!({"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "mode": 5}),
        ))
        .unwrap_err();
        assert!(e.starts_with("mesh 0 primitive 0: TEXCOORD_0 value 2 is not finite"), "{e}");
    }

    #[test]
    fn not_a_gltf_file_is_a_clear_error() {
        let err = import_mesh_slice(b"solid cube\nfacet normal 0 0 1\n").unwrap_err();
        assert!(!err.is_empty());
        // From a file: what it is, not only where the parser stopped.
        let dir = std::env::temp_dir().join(format!("objslam-gltf-unreadable-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let stl = dir.join("cube.stl");
        std::fs::write(&stl, b"solid cube\nfacet normal 0 0 1\n").unwrap();
        let e = import_mesh(&stl).unwrap_err();
        assert!(e.starts_with("not a glTF 2.0 file (JSON .gltf or binary .glb; OBJ, STL and PLY are not read)"), "{e}");
        let glb = glb_with(
            &square(),
            serde_json::json!([{"buffer": 0, "byteLength": 48}]),
            serde_json::json!([positions(4)]),
            serde_json::json!({"attributes": {"POSITION": 0}, "mode": 5}),
        );
        let cut = dir.join("cut.glb");
        std::fs::write(&cut, &glb[..glb.len() - 10]).unwrap();
        let e = import_mesh(&cut).unwrap_err();
        assert!(e.starts_with("a binary glTF (.glb) that cannot be read, cut short or damaged"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
