//! Writes every patch's feature row under a model's extractor (its PCA), with its grid
//! cell, object label fraction and majority class: for offline comparisons of what the
//! mixtures are fitted to (`scripts/nonlinear_reduction.py`), on the training dataset and
//! on datasets of other worlds alike.
//!
//! `cargo run --release -p scenarios --example patch_features -- MODEL DATASET OUT.csv`
use std::io::Write;
use std::path::Path;

use scenarios::train::{load_image, majority_class, read_manifest};
use slam::classifier::AppearanceModel;
use slam::features::ImageRef;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let [_, model, dataset, out] = args.as_slice() else {
        return Err("usage: patch_features MODEL DATASET OUT.csv".into());
    };
    let model = AppearanceModel::load(Path::new(model))?;
    let dir = Path::new(dataset);
    let manifest = read_manifest(dir)?;
    let l = model.extractor.config.patch_size;
    let d = model.extractor.dims();
    let mut out = std::io::BufWriter::new(std::fs::File::create(out)?);
    let names: Vec<String> = (0..d).map(|k| format!("z{k}")).collect();
    writeln!(out, "image,col,row,{},fraction,class", names.join(","))?;
    for i in 0..manifest.images.len() {
        let img = load_image(dir, &manifest, i)?;
        let class = image::open(dir.join(&manifest.images[i].class))?.to_luma8();
        let image = ImageRef::new(img.width, img.height, &img.rgb)?;
        let f = model.extractor.features(&image, None)?;
        let (cols, _) = image.grid(l);
        for k in 0..f.z.nrows() {
            let (c, r) = f.rect.patch(k);
            let id = majority_class(&class, c, r, l);
            let z: Vec<String> = f.z.row(k).iter().map(|v| format!("{v}")).collect();
            writeln!(out, "{i},{c},{r},{},{},{id}", z.join(","), img.fractions[(r * cols + c) as usize])?;
        }
    }
    Ok(())
}
