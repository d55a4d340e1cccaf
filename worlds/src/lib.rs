//! # worlds — what a world *is*
//!
//! World descriptions (serde + TOML), the seeded `park` generator for the paper's scene,
//! procedural meshes and textures for every class, glTF import/export and validation.
//! This crate depends on no other crate of the workspace.
//!
//! ```
//! use worlds::{generate::{park, ParkParams}, validate::validate};
//! let world = park(&ParkParams::default(), 7).unwrap();
//! assert!(validate(&world, std::path::Path::new(".")).is_empty());
//! let text = world.to_toml();
//! let again = worlds::parse(&text, "park.toml".as_ref()).unwrap();
//! assert_eq!(world, again);
//! ```

pub mod description;
pub mod error;
pub mod generate;
pub mod gltf_io;
pub mod import;
pub mod mesh;
pub mod texture;
pub mod validate;

use std::path::Path;

pub use description::*;
pub use error::{Problem, WorldError};

/// Most laps a robot may drive its route: the path follower holds every lap's waypoints,
/// and a thousand laps of the paper's park are 14 simulated hours.
pub const MAX_LAPS: u32 = 1000;

/// Parses and validates world TOML text, and reads the objects' `mesh` files; `file` names
/// the source in errors and resolves relative mesh paths.
pub fn parse(text: &str, file: &Path) -> Result<World, WorldError> {
    let mut world: World = toml_strict::from_str(text)
        .map_err(|e| WorldError::Parse { file: file.to_path_buf(), message: e.to_string().trim_end().to_string() })?;
    let base = file.parent().unwrap_or(Path::new("."));
    let mut problems = validate::validate(&world, base);
    if problems.is_empty() {
        for o in &mut world.objects {
            if let Some(mesh) = &o.mesh {
                let triangles = gltf_io::import_object_mesh(file, mesh)?;
                o.mesh_data = LoadedMesh(Some(std::sync::Arc::new(triangles)));
            }
        }
        Ok(world)
    } else {
        for p in &mut problems {
            p.line = validate::locate_line(text, &p.field);
        }
        Err(WorldError::Invalid { file: file.to_path_buf(), problems })
    }
}

/// Largest world file read (bytes): a park of the generator's most objects is about 1 MiB
/// of TOML; a larger file is something else (a device such as /dev/zero never ends), and
/// no more than this is read of it.
pub const MAX_WORLD_FILE_BYTES: u64 = 16 << 20;

/// Reads, parses and validates a world file.
pub fn load(path: &Path) -> Result<World, WorldError> {
    use std::io::Read;
    let read = |source| WorldError::Read { file: path.to_path_buf(), source };
    let mut bytes = Vec::new();
    std::fs::File::open(path).map_err(read)?.take(MAX_WORLD_FILE_BYTES + 1).read_to_end(&mut bytes).map_err(read)?;
    if bytes.len() as u64 > MAX_WORLD_FILE_BYTES {
        return Err(read(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("larger than {} MiB: not a world file", MAX_WORLD_FILE_BYTES >> 20),
        )));
    }
    let text = String::from_utf8(bytes)
        .map_err(|e| read(std::io::Error::new(std::io::ErrorKind::InvalidData, format!("not UTF-8 text: {e}"))))?;
    parse(&text, path)
}

/// Writes a world as TOML.
pub fn save(world: &World, path: &Path) -> Result<(), WorldError> {
    std::fs::write(path, world.to_toml()).map_err(|source| WorldError::Write { file: path.to_path_buf(), source })
}
