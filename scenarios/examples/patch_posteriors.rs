//! Writes every patch's posterior (with the column context where the model has one), its
//! foliage probability, grid cell, object label fraction and majority class, for the offline
//! comparison in `scripts/patch_context.py`.
//!
//! `cargo run --release -p scenarios --example patch_posteriors -- MODEL DATASET OUT.csv`
use std::io::Write;
use std::path::Path;

use scenarios::train::{load_image, majority_class, read_manifest};
use slam::classifier::{AppearanceModel, PatchClassifier};
use slam::features::ImageRef;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let [_, model, dataset, out] = args.as_slice() else {
        return Err("usage: patch_posteriors MODEL DATASET OUT.csv".into());
    };
    let model = AppearanceModel::load(Path::new(model))?;
    let dir = Path::new(dataset);
    let manifest = read_manifest(dir)?;
    let classifier = PatchClassifier::new(&model)?;
    let l = model.extractor.config.patch_size;
    let mut out = std::io::BufWriter::new(std::fs::File::create(out)?);
    writeln!(out, "image,col,row,posterior,foliage_p,fraction,class")?;
    for i in 0..manifest.images.len() {
        let img = load_image(dir, &manifest, i)?;
        let class = image::open(dir.join(&manifest.images[i].class))?.to_luma8();
        let image = ImageRef::new(img.width, img.height, &img.rgb)?;
        let f = model.extractor.features(&image, None)?;
        let (cols, _) = image.grid(l);
        for (k, p) in classifier.posteriors(&f).iter().enumerate() {
            let (c, r) = f.rect.patch(k);
            let id = majority_class(&class, c, r, l);
            let foliage = classifier.foliage_probability(f.z.row(k).transpose().as_slice()).unwrap_or(0.0);
            writeln!(out, "{i},{c},{r},{p},{foliage},{},{id}", img.fractions[(r * cols + c) as usize])?;
        }
    }
    Ok(())
}
