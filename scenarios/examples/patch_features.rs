//! Writes every patch's feature row under a model's extractor (its PCA), with its grid
//! cell, object label fraction and majority class: for offline comparisons of what the
//! mixtures are fitted to (`scripts/nonlinear_reduction.py`), on the training dataset and
//! on datasets of other worlds alike.
//!
//! `cargo run --release -p scenarios --example patch_features -- MODEL DATASET OUT.csv`
use std::io::Write;
use std::path::Path;

use scenarios::train::{image_patches, read_manifest};
use slam::classifier::AppearanceModel;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let [_, model, dataset, out] = args.as_slice() else {
        return Err("usage: patch_features MODEL DATASET OUT.csv".into());
    };
    let model = AppearanceModel::load(Path::new(model))?;
    let dir = Path::new(dataset);
    let manifest = read_manifest(dir)?;
    let d = model.extractor.dims();
    let mut out = std::io::BufWriter::new(std::fs::File::create(out)?);
    let names: Vec<String> = (0..d).map(|k| format!("z{k}")).collect();
    writeln!(out, "image,col,row,{},fraction,class", names.join(","))?;
    for patches in image_patches(dir, &manifest, &model.extractor, 0..manifest.images.len())? {
        let p = patches?;
        for (k, &(c, r)) in p.cells.iter().enumerate() {
            let z: Vec<String> = p.features.z.row(k).iter().map(|v| format!("{v}")).collect();
            writeln!(out, "{},{c},{r},{},{},{}", p.index, z.join(","), p.fractions[k], p.classes[k])?;
        }
    }
    Ok(())
}
