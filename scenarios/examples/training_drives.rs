//! Writes a scenario file per appearance training world (the parks a model trained with
//! `training_worlds` would see, none of them a benchmark world), each driven by `combined`
//! with the appearance settings given, for the offline study of the pooled evidence
//! thresholds in `scripts/pooled_thresholds.py`.
//!
//! `cargo run --release -p scenarios --example training_drives -- BASE_SEED WORLDS OUT_DIR
//! [KEY=VALUE ...]`, each KEY=VALUE a line of the files' `[appearance]` table
//! (`training_seed=2`, `distractors=true`).
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let usage = "usage: training_drives BASE_SEED WORLDS OUT_DIR [KEY=VALUE ...]";
    let [_, base, worlds, out, appearance @ ..] = args.as_slice() else { return Err(usage.into()) };
    let (base, worlds): (u64, usize) = (base.parse()?, worlds.parse()?);
    std::fs::create_dir_all(out)?;
    for k in 0..worlds {
        let (seed, params) = scenarios::montecarlo::generalisation::training_world(base, k)
            .ok_or_else(|| format!("training world {k} of seed {base} has no layout that fits its ground"))?;
        let mut world = toml::Table::new();
        world.insert("preset".into(), "park".into());
        world.insert("seed".into(), toml::Value::Integer(i64::try_from(seed)?));
        world.insert("params".into(), toml::Value::try_from(&params)?);
        let mut table = toml::Table::new();
        table.insert("name".into(), format!("training-world-{k}").into());
        table.insert("world".into(), toml::Value::Table(world));
        let text = toml::to_string(&table)?;
        let lines: Vec<String> = appearance
            .iter()
            .map(|kv| kv.split_once('=').map(|(k, v)| format!("{k} = {v}\n")).ok_or(usage))
            .collect::<Result<_, _>>()?;
        let file = Path::new(out).join(format!("training-world-{k}.toml"));
        std::fs::write(
            &file,
            format!("{text}\n[pipeline]\nmethod = \"combined\"\n\n[appearance]\n{}", lines.concat()),
        )?;
        println!("{}", file.display());
    }
    Ok(())
}
