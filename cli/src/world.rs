//! `objslam world`: generate, check, export and plot worlds.

use anyhow::{Context, Result};

use crate::args::WorldCommand;

/// `objslam world`.
pub(crate) fn world(cmd: WorldCommand) -> Result<()> {
    match cmd {
        WorldCommand::Generate { preset, seed, params, out } => {
            let params = match params {
                Some(path) => {
                    let text =
                        std::fs::read_to_string(&path).with_context(|| format!("{}: cannot read", path.display()))?;
                    Some(
                        toml::from_str::<worlds::generate::ParkParams>(&text)
                            .with_context(|| format!("{}: bad generator parameters", path.display()))?,
                    )
                }
                None => None,
            };
            let world = worlds::generate::preset(&preset, params.as_ref(), seed)?;
            match out {
                Some(path) => {
                    worlds::save(&world, &path)?;
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
            let w = worlds::load(&file)?;
            worlds::gltf_io::export_glb_file(&w, &out)?;
            eprintln!("wrote {}", out.display());
        }
        WorldCommand::Plot { file, out } => {
            let w = worlds::load(&file)?;
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
    Ok(worlds::load(path)?)
}
