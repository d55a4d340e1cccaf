//! `objslam world`: generate, check, export and plot worlds.

use anyhow::{Context, Result};

use crate::args::WorldCommand;

/// `objslam world`.
pub(crate) fn world(cmd: WorldCommand) -> Result<()> {
    match cmd {
        WorldCommand::Generate { preset, seed, params, out } => {
            if let (Some(out), Some(params)) = (&out, &params) {
                crate::paths::not_an_input("--out", out, &[("--params file", params)])?;
            }
            let params = params.map(|path| scenarios::scenario::read_park_params(&path)).transpose()?;
            let world = worlds::generate::preset(&preset, params.as_ref(), seed)?;
            match out {
                Some(path) => {
                    crate::paths::write_whole(&path, world.to_toml())?;
                    eprintln!(
                        "wrote {} ({} objects, {} people)",
                        path.display(),
                        world.objects.len(),
                        world.people.len()
                    );
                }
                None => print!("{}", world.to_toml()),
            }
        }
        WorldCommand::Check { file } => {
            let w = worlds::load(&file)?;
            let mut counts = std::collections::BTreeMap::new();
            for o in &w.objects {
                *counts.entry(o.class.name()).or_insert(0) += 1;
            }
            println!("{}: ok", file.display());
            println!("  ground   {:.1} m²", w.ground.area_m2());
            for (class, n) in counts {
                println!("  {class:<8} {n}");
            }
            println!("  people   {}", w.people.len());
            println!("  route    {:.1} m x {} laps", w.robot.route.length_m(), w.robot.laps);
        }
        WorldCommand::Export { file, out } => {
            crate::paths::not_an_input("--out", &out, &[("world file", &file)])?;
            // What is written is binary glTF: a `.gltf` name promises JSON glTF.
            if !out.extension().is_some_and(|e| e.eq_ignore_ascii_case("glb")) {
                anyhow::bail!("--out {}: the export is binary glTF; give a file name ending in .glb", out.display());
            }
            let w = worlds::load(&file)?;
            not_a_mesh_of("--out", &out, &file, &w)?;
            crate::paths::write_whole(&out, worlds::gltf_io::export_glb(&w))?;
            eprintln!("wrote {}", out.display());
        }
        WorldCommand::Import { mesh, world, class, at, yaw_deg, out } => {
            import(&mesh, &world, &class, &at, yaw_deg, &out)?;
        }
        WorldCommand::Plot { file, out } => {
            crate::paths::not_an_input("--out", &out, &[("world file", &file)])?;
            let w = worlds::load(&file)?;
            not_a_mesh_of("--out", &out, &file, &w)?;
            let title = format!("{} (seed {}): {:.0} m²", w.name, w.seed, w.ground.area_m2());
            scenarios::plot::draw_map(
                &w,
                &scenarios::plot::Overlays { title, routes: true, ..Default::default() },
                &out,
            )?;
            eprintln!("wrote {}", out.display());
        }
    }
    Ok(())
}

/// A world from a file path, or generated from a preset name with the seed.
pub(crate) fn load_world(input: &str, seed: u64) -> Result<worlds::World> {
    let path = std::path::Path::new(input);
    if !path.exists() && worlds::generate::PRESETS.contains(&input) {
        return Ok(worlds::generate::preset(input, None, seed)?);
    }
    // A scenario's name where a world goes: say how to give a scenario.
    if !path.exists() && scenarios::scenario::LIBRARY.iter().any(|(n, _)| *n == input.trim_end_matches(".toml")) {
        anyhow::bail!(
            "{input} is a scenario, not a world file or a preset ({}): give it as `--scenario {input}`",
            worlds::generate::PRESETS.join(", ")
        );
    }
    // A bare word that names no file: most likely a preset misspelt.
    if !path.exists() && path.extension().is_none() && path.components().count() == 1 {
        anyhow::bail!(
            "{input}: no such world file, and not a preset ({}) or a scenario (give a scenario as `--scenario NAME`)",
            worlds::generate::PRESETS.join(", ")
        );
    }
    let mut world = worlds::load(path)?;
    // A recording's world.toml is read from the recording's directory.
    world.resolve_mesh_paths(path);
    Ok(world)
}

/// `objslam world import`: the world with the mesh added, checked as any world file is
/// before it is written.
fn import(
    mesh: &std::path::Path,
    world_file: &std::path::Path,
    class: &str,
    at: &str,
    yaw_deg: f64,
    out: &std::path::Path,
) -> Result<()> {
    let class = worlds::ObjectClass::from_name(class)
        .ok_or_else(|| anyhow::anyhow!("unknown class {class:?}; use tree, palm, post or wall"))?;
    let bad_at = || anyhow::anyhow!("--at takes X,Y in metres, got {at:?}");
    let xy: Vec<f64> =
        at.split(',').map(|v| v.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|_| bad_at())?;
    let &[x, y] = xy.as_slice() else { return Err(bad_at()) };
    anyhow::ensure!(x.is_finite() && y.is_finite() && yaw_deg.is_finite(), "--at and --yaw-deg must be finite numbers");
    // The output may be the world file itself (the mesh added in place), never a mesh.
    let buffers = worlds::gltf_io::buffer_files(mesh);
    let mut inputs = vec![("MESH", mesh)];
    inputs.extend(buffers.iter().map(|b| ("buffer file of MESH", b.as_path())));
    crate::paths::not_an_input("--out", out, &inputs)?;
    let mut w = worlds::load(world_file)?;
    not_a_mesh_of("--out", out, world_file, &w)?;
    let triangles = worlds::gltf_io::import_mesh(mesh)
        .map_err(|e| anyhow::anyhow!("{}: not a readable glTF/.glb mesh: {e}", mesh.display()))?;
    // The world file names the mesh relative to itself where it can.
    let out_dir = directory_of(out)?;
    let mesh_abs = std::fs::canonicalize(mesh).with_context(|| format!("{}: cannot read", mesh.display()))?;
    // A world file is UTF-8 text: a path that is not cannot be written into it as it is.
    if let Some(path) = [&mesh_abs, &out_dir].into_iter().find(|p| p.to_str().is_none()) {
        anyhow::bail!(
            "{}: the path is not UTF-8 text, and a world file names its meshes in UTF-8; rename the file or its directory",
            path.display()
        );
    }
    let relative_to_out = |p: &std::path::Path| p.strip_prefix(&out_dir).unwrap_or(p).to_string_lossy().into_owned();
    let named = relative_to_out(&mesh_abs);
    // The meshes the world already names, relative to its own file, as the new file
    // must name them.
    let world_dir = directory_of(world_file)?;
    for o in &mut w.objects {
        if let Some(m) = &o.mesh
            && std::path::Path::new(m).is_relative()
        {
            o.mesh = Some(relative_to_out(&world_dir.join(m)));
        }
    }
    let pose = worlds::Pose2 { x, y, yaw_deg };
    let id = worlds::import::add_object(&mut w, triangles, &named, class, pose)
        .map_err(|e| anyhow::anyhow!("{}: {e}", mesh.display()))?;
    let text = w.to_toml();
    worlds::parse(&text, out).context("the world with the mesh added is not valid; nothing was written")?;
    crate::paths::write_whole(out, text)?;
    let added = w.objects.last().expect("just added");
    eprintln!("added {} {id} at ({x}, {y}), {} -> {}", class.name(), added.shape.describe(), out.display());
    Ok(())
}

/// Refuses an output `out` that is one of the meshes `world` (read from `world_file`)
/// names, or a buffer file such a mesh names: writing it would change what the world
/// renders, and the mesh would be lost.
fn not_a_mesh_of(flag: &str, out: &std::path::Path, world_file: &std::path::Path, world: &worlds::World) -> Result<()> {
    let base = world_file.parent().unwrap_or(std::path::Path::new("."));
    let mut meshes: Vec<(String, std::path::PathBuf)> = Vec::new();
    for o in &world.objects {
        let Some(m) = &o.mesh else { continue };
        let mesh = base.join(m);
        let what = format!("mesh of object {} in {}", o.id, world_file.display());
        for buffer in worlds::gltf_io::buffer_files(&mesh) {
            meshes.push((format!("buffer of the {what}"), buffer));
        }
        meshes.push((what, mesh));
    }
    let inputs: Vec<(&str, &std::path::Path)> = meshes.iter().map(|(what, p)| (what.as_str(), p.as_path())).collect();
    crate::paths::not_an_input(flag, out, &inputs)
}

/// The absolute directory that holds `file` (the working directory for a bare name).
fn directory_of(file: &std::path::Path) -> Result<std::path::PathBuf> {
    let dir = file.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(".".as_ref());
    std::fs::canonicalize(dir).with_context(|| format!("{}: its directory does not exist", file.display()))
}
