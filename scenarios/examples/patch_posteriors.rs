//! Writes every patch's posterior (with the column context where the model has one), its
//! foliage probability, grid cell, object label fraction and majority class, for the offline
//! comparison in `scripts/patch_context.py`.
//!
//! `cargo run --release -p scenarios --example patch_posteriors -- MODEL DATASET OUT.csv`
use std::io::Write;
use std::path::Path;

use scenarios::train::{image_patches, read_manifest};
use slam::classifier::{AppearanceModel, PatchClassifier};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let [_, model, dataset, out] = args.as_slice() else {
        return Err("usage: patch_posteriors MODEL DATASET OUT.csv".into());
    };
    let model = AppearanceModel::load(Path::new(model))?;
    let dir = Path::new(dataset);
    let manifest = read_manifest(dir)?;
    let classifier = PatchClassifier::new(&model)?;
    let mut out = std::io::BufWriter::new(std::fs::File::create(out)?);
    writeln!(out, "image,col,row,posterior,foliage_p,fraction,class")?;
    for patches in image_patches(dir, &manifest, &model.extractor, 0..manifest.images.len())? {
        let p = patches?;
        for (k, posterior) in classifier.posteriors(&p.features)?.iter().enumerate() {
            let (c, r) = p.cells[k];
            let foliage = classifier.foliage_probability(p.features.z.row(k).transpose().as_slice())?.unwrap_or(0.0);
            writeln!(out, "{},{c},{r},{posterior},{foliage},{},{}", p.index, p.fractions[k], p.classes[k])?;
        }
    }
    Ok(())
}
