//! The offline phase from an `objslam dataset` directory: train the appearance model with
//! held-out scoring, export the feature matrix, draw classified patches over an image, and
//! fit a VB-GMM to any numeric CSV.

use std::path::{Path, PathBuf};

use nalgebra::DMatrix;
use slam::classifier::{self, AppearanceModel, LabelledImage, ModelError, PatchClassifier, TrainingOptions};
use slam::features::{FeatureExtractor, ImageRef, PatchFeatures, feature_names};
use slam::gmm::{self, VbGmm, VbOptions};

use crate::dataset::{Manifest, PatchLabels};

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error("{}: {message}", file.display())]
    File { file: PathBuf, message: String },
    #[error("{}: line {line}: {message}", file.display())]
    Csv { file: PathBuf, line: usize, message: String },
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(transparent)]
    Gmm(#[from] gmm::GmmError),
}

fn file_err(file: &Path, message: impl ToString) -> TrainError {
    TrainError::File { file: file.to_path_buf(), message: message.to_string() }
}

/// The classes a model may fit apart from the rest of the background (see
/// `slam::classifier`), less the dataset's wanted classes.
const DISTRACTORS: [worlds::ObjectClass; 4] =
    [worlds::ObjectClass::Post, worlds::ObjectClass::Palm, worlds::ObjectClass::Wall, worlds::ObjectClass::Person];

/// Reads `DIR/dataset.json`.
pub fn read_manifest(dir: &Path) -> Result<Manifest, TrainError> {
    // The manifest itself given for its directory: say which to give.
    if dir.is_file() {
        return Err(file_err(
            dir,
            "a file; a dataset is given by its directory (the one holding dataset.json, images/ and labels/)",
        ));
    }
    let path = dir.join("dataset.json");
    let text = std::fs::read_to_string(&path).map_err(|e| file_err(&path, e))?;
    let manifest: Manifest = slam::settings::from_json(&text)
        .map_err(|e| file_err(&path, format!("not an objslam dataset manifest: {e}")))?;
    manifest.check().map_err(|problem| file_err(&path, problem))?;
    Ok(manifest)
}

/// Loads image `i` of a dataset with its patch labels.
pub fn load_image(dir: &Path, manifest: &Manifest, i: usize) -> Result<LabelledImage, TrainError> {
    Ok(load_image_and_class(dir, manifest, i)?.0)
}

/// Refuses the dataset in `dir` (its `manifest`) where its patches are not `l` px, the
/// model's: every label it holds would describe other patches. (Each labels file is
/// checked against the manifest as it is read, by [`load_image`].)
fn check_patch_size(dir: &Path, manifest: &Manifest, l: u32) -> Result<(), TrainError> {
    if manifest.patch_size == l {
        return Ok(());
    }
    Err(file_err(
        &dir.join("dataset.json"),
        format!("patch_size is {}, the model's patches are {l} px", manifest.patch_size),
    ))
}

/// [`load_image`], with the image's class mask.
fn load_image_and_class(
    dir: &Path,
    manifest: &Manifest,
    i: usize,
) -> Result<(LabelledImage, image::GrayImage), TrainError> {
    let entry = &manifest.images[i];
    let img_path = dir.join(&entry.image);
    let opened = image::open(&img_path).map_err(|e| file_err(&img_path, e))?;
    let rgb = colour_pixels(&img_path, opened)?;
    if rgb.dimensions() != (manifest.width, manifest.height) {
        let (w, h) = rgb.dimensions();
        return Err(file_err(
            &img_path,
            format!("the image is {w}x{h}; the dataset's dataset.json says {}x{}", manifest.width, manifest.height),
        ));
    }
    let labels_path = dir.join(&entry.patches);
    let text = std::fs::read_to_string(&labels_path).map_err(|e| file_err(&labels_path, e))?;
    let labels: PatchLabels = slam::settings::from_json(&text).map_err(|e| file_err(&labels_path, e))?;
    let (w, h) = rgb.dimensions();
    if labels.patch_size == 0 {
        return Err(file_err(&labels_path, "patch_size: must be at least 1 pixel"));
    }
    if labels.patch_size != manifest.patch_size {
        return Err(file_err(
            &labels_path,
            format!(
                "patch_size: {} px, and the dataset's dataset.json says {} px: the file is another dataset's",
                labels.patch_size, manifest.patch_size
            ),
        ));
    }
    if labels.cols != w / labels.patch_size || labels.rows != h / labels.patch_size {
        return Err(file_err(
            &labels_path,
            format!(
                "a {}x{} grid of {} px patches does not fit the {w}x{h} image",
                labels.cols, labels.rows, labels.patch_size
            ),
        ));
    }
    if labels.fractions.len() != (labels.cols * labels.rows) as usize {
        return Err(file_err(
            &labels_path,
            format!(
                "fractions: {} values for a {}x{} grid of patches ({})",
                labels.fractions.len(),
                labels.cols,
                labels.rows,
                labels.cols * labels.rows
            ),
        ));
    }
    if let Some(i) = labels.fractions.iter().position(|f| !(0.0..=1.0).contains(f)) {
        return Err(file_err(
            &labels_path,
            format!("fractions[{i}] is {}: a patch's fraction lies in [0, 1]", labels.fractions[i]),
        ));
    }
    // Foliage labels come from the class mask (a dataset's labels file holds only the
    // object classes' fractions).
    let class_path = dir.join(&entry.class);
    let class = image::open(&class_path).map_err(|e| file_err(&class_path, e))?;
    // Class ids are 8-bit grey values: another format would be converted, and 16-bit ids
    // divided by 257 read as 0, the sky.
    if class.color() != image::ColorType::L8 {
        return Err(file_err(
            &class_path,
            format!("stored as {:?}; a class mask is an 8-bit greyscale image of class ids", class.color()),
        ));
    }
    let class = class.into_luma8();
    if class.dimensions() != (w, h) {
        let (cw, ch) = class.dimensions();
        return Err(file_err(&class_path, format!("the class mask is {cw}x{ch}, its image {w}x{h}")));
    }
    // 0 is nothing (the sky); anything else must be a class, or its patches would be
    // labelled as none.
    if let Some((k, v)) =
        class.as_raw().iter().enumerate().find(|(_, v)| **v != 0 && worlds::ObjectClass::from_id(**v).is_none())
    {
        return Err(file_err(
            &class_path,
            format!(
                "pixel ({}, {}) holds {v}, which is no class id (0 to {})",
                k as u32 % w,
                k as u32 / w,
                worlds::ObjectClass::ALL.iter().map(|c| c.id()).max().unwrap_or(0)
            ),
        ));
    }
    // The labels are the class mask's, patch by patch: a labels file of another image (or
    // edited) would score and train on what the image does not show.
    let wanted: Vec<u8> = manifest.classes.iter().map(|c| c.id()).collect();
    let from_mask = crate::dataset::patch_labels(class.as_raw(), w, h, labels.patch_size, &wanted).fractions;
    if let Some(k) = from_mask.iter().zip(&labels.fractions).position(|(a, b)| (a - b).abs() > 1e-5) {
        return Err(file_err(
            &labels_path,
            format!(
                "fractions[{k}] (patch column {}, row {}) is {}, where the class mask {} gives {}: the labels are not this image's",
                k as u32 % labels.cols,
                k as u32 / labels.cols,
                labels.fractions[k],
                class_path.display(),
                from_mask[k]
            ),
        ));
    }
    let foliage =
        crate::dataset::patch_labels(class.as_raw(), w, h, labels.patch_size, &[worlds::ObjectClass::Foliage.id()])
            .fractions;
    // Distractors: the things that stand up like the wanted objects and are not of their
    // classes.
    let distractor_ids: Vec<u8> =
        DISTRACTORS.iter().filter(|c| !manifest.classes.contains(c)).map(|c| c.id()).collect();
    let distractors = crate::dataset::patch_labels(class.as_raw(), w, h, labels.patch_size, &distractor_ids).fractions;
    let image =
        LabelledImage { width: w, height: h, rgb: rgb.into_raw(), fractions: labels.fractions, foliage, distractors };
    Ok((image, class))
}

/// A dataset image's patches under a model's feature extractor, with what each patch is:
/// what held-out scoring classifies and the exports of patch features and posteriors write.
pub struct ImagePatches {
    /// The image's place in the manifest.
    pub index: usize,
    pub features: PatchFeatures,
    /// Per feature row: the patch's (column, row) in the image's grid.
    pub cells: Vec<(u32, u32)>,
    /// Per feature row: the patch's object label fraction.
    pub fractions: Vec<f32>,
    /// Per feature row: the class id most of the patch's pixels have ([`majority_class`]).
    pub classes: Vec<u8>,
}

/// Images `ids` of the dataset in `dir` (its `manifest`), in that order, as [`ImagePatches`];
/// refused at once where the dataset's patches are not the extractor's.
pub fn image_patches<'a>(
    dir: &'a Path,
    manifest: &'a Manifest,
    extractor: &'a FeatureExtractor,
    ids: impl IntoIterator<Item = usize> + 'a,
) -> Result<impl Iterator<Item = Result<ImagePatches, TrainError>> + 'a, TrainError> {
    let l = extractor.config.patch_size;
    check_patch_size(dir, manifest, l)?;
    Ok(ids.into_iter().map(move |index| {
        let (img, class) = load_image_and_class(dir, manifest, index)?;
        let image = ImageRef::new(img.width, img.height, &img.rgb).map_err(ModelError::from)?;
        let features = extractor.features(&image, None).map_err(ModelError::from)?;
        let (cols, _) = image.grid(l);
        let cells: Vec<(u32, u32)> =
            (0..features.z.nrows()).map(|k| features.rect.patch(k).expect(slam::features::IN_RECT)).collect();
        let fractions = cells.iter().map(|&(c, r)| img.fractions[(r * cols + c) as usize]).collect();
        let classes = cells.iter().map(|&(c, r)| majority_class(&class, c, r, l)).collect();
        Ok(ImagePatches { index, features, cells, fractions, classes })
    }))
}

/// `options` with the patches of the dataset in `dir` (its `manifest`): its labels are per
/// patch of that size. Refused, naming the dataset, where no model of such patches can be
/// made.
fn options_for_dataset(
    dir: &Path,
    manifest: &Manifest,
    options: &TrainingOptions,
) -> Result<TrainingOptions, TrainError> {
    // The model's object class is what the dataset labelled positive: a run names the
    // landmarks it maps after it.
    let options = TrainingOptions {
        features: slam::features::FeatureConfig { patch_size: manifest.patch_size, ..options.features.clone() },
        object_class: object_class_of(manifest),
        ..options.clone()
    };
    options.features.validate().map_err(|e| {
        file_err(
            &dir.join("dataset.json"),
            format!("patch_size: a model of {} px patches cannot be made ({})", manifest.patch_size, e.problem),
        )
    })?;
    Ok(options)
}

/// The name of a dataset's positive classes, as a model's `object_class`: `tree`, or
/// `post+palm` for several.
fn object_class_of(manifest: &Manifest) -> String {
    // In one order whatever order `--classes` gave them in.
    let mut names: Vec<&str> = manifest.classes.iter().map(|c| c.name()).collect();
    names.sort_unstable();
    names.join("+")
}

fn model_error(e: TrainError) -> ModelError {
    match e {
        TrainError::Model(m) => m,
        other => ModelError::Training(other.to_string()),
    }
}

/// Trains on a dataset, holding out every `heldout_every`-th image (0: none) for scoring:
/// the model, its `training.heldout` scores set, and per true class (each patch's majority
/// class) the held-out patches and those called object, which shows the distractors it
/// confuses (empty with nothing held out).
pub fn train_from_dataset(
    dir: &Path,
    options: &TrainingOptions,
    heldout_every: usize,
    progress: impl Fn(&str, usize, usize),
) -> Result<(AppearanceModel, ClassTable), TrainError> {
    let manifest = read_manifest(dir)?;
    let options = &options_for_dataset(dir, &manifest, options)?;
    let (train_ids, test_ids): (Vec<usize>, Vec<usize>) =
        (0..manifest.images.len()).partition(|i| heldout_every == 0 || i % heldout_every != heldout_every - 1);
    // Say why no image is left to train on, where the learner could only say that none is.
    if manifest.images.is_empty() {
        return Err(file_err(&dir.join("dataset.json"), "images: the dataset lists no image"));
    }
    if train_ids.is_empty() {
        return Err(file_err(
            dir,
            format!("--heldout-every {heldout_every} holds out every image of the dataset, leaving none to train on"),
        ));
    }
    let load = |k: usize| load_image(dir, &manifest, train_ids[k]).map_err(model_error);
    let mut model = classifier::train(train_ids.len(), load, options, &progress)?;
    model.training.renderer = Some(manifest.renderer.clone());
    let mut classes = ClassTable::default();
    if !test_ids.is_empty() {
        progress("held-out scoring", 0, 1);
        let (scores, table) = score_images(dir, &manifest, &model, &test_ids, options.label_fraction)?;
        model.training.heldout = Some(scores);
        classes = table;
        let load = |k: usize| load_image(dir, &manifest, test_ids[k]).map_err(model_error);
        model.training.foliage_heldout =
            classifier::evaluate_foliage(&model, test_ids.len(), load, options.label_fraction)?;
    }
    Ok((model, classes))
}

/// Trains on every image of the datasets in `dirs` together, holding none out: the model a
/// run trains on images of several worlds. The datasets must share their patch size and
/// image size (one camera rendered them all); the first one's patch size is the model's.
pub fn train_from_datasets(
    dirs: &[PathBuf],
    options: &TrainingOptions,
    progress: impl Fn(&str, usize, usize),
) -> Result<AppearanceModel, TrainError> {
    let [first, rest @ ..] = dirs else {
        return Err(file_err(Path::new("."), "no dataset to train on"));
    };
    if rest.is_empty() {
        return Ok(train_from_dataset(first, options, 0, progress)?.0);
    }
    let manifests = dirs.iter().map(|d| read_manifest(d)).collect::<Result<Vec<_>, _>>()?;
    let lead = &manifests[0];
    for (dir, m) in dirs.iter().zip(&manifests) {
        check_patch_size(dir, m, lead.patch_size)?;
        if (m.width, m.height) != (lead.width, lead.height) {
            return Err(file_err(
                &dir.join("dataset.json"),
                format!(
                    "{}x{} images, where {} holds {}x{}",
                    m.width,
                    m.height,
                    first.display(),
                    lead.width,
                    lead.height
                ),
            ));
        }
    }
    // One model learns one set of classes: datasets that label others cannot be pooled.
    for (dir, m) in dirs.iter().zip(&manifests) {
        if object_class_of(m) != object_class_of(lead) {
            return Err(file_err(
                &dir.join("dataset.json"),
                format!(
                    "classes: {}, where {} labels {}; a model learns one set of classes",
                    object_class_of(m),
                    first.display(),
                    object_class_of(lead)
                ),
            ));
        }
    }
    let options = &options_for_dataset(first, lead, options)?;
    let images: Vec<(usize, usize)> =
        manifests.iter().enumerate().flat_map(|(d, m)| (0..m.images.len()).map(move |i| (d, i))).collect();
    if images.is_empty() {
        return Err(file_err(&first.join("dataset.json"), "images: the datasets list no image"));
    }
    let load = |k: usize| {
        let (d, i) = images[k];
        load_image(&dirs[d], &manifests[d], i).map_err(model_error)
    };
    let mut model = classifier::train(images.len(), load, options, &progress)?;
    model.training.renderer = Some(lead.renderer.clone());
    Ok(model)
}

/// Largest image `objslam segment` and `objslam find` classify: 16 megapixels, under 1 GB
/// of features.
pub const MAX_SEGMENT_PIXELS: u64 = 16_000_000;

/// Reads an image whose patches are to be classified; one larger than
/// [`MAX_SEGMENT_PIXELS`] is refused before it is decoded (features take about 50 bytes a
/// pixel), naming the file.
pub fn open_image_to_classify(path: &Path) -> Result<image::RgbImage, TrainError> {
    if path.is_dir() {
        return Err(file_err(path, "a directory, not an image file"));
    }
    use image::ImageDecoder;
    // The format from the file's bytes, not its name (a PNG named .jpg), and the picture
    // the way up its EXIF orientation says, as a viewer shows it.
    let reader = image::ImageReader::open(path).and_then(|r| r.with_guessed_format()).map_err(|e| file_err(path, e))?;
    let mut decoder = reader.into_decoder().map_err(|e| file_err(path, e))?;
    let (w, h) = decoder.dimensions();
    if u64::from(w) * u64::from(h) > MAX_SEGMENT_PIXELS {
        return Err(file_err(path, format!("{w}x{h} is more than {MAX_SEGMENT_PIXELS} pixels; crop or scale it down")));
    }
    let orientation = decoder.orientation().map_err(|e| file_err(path, e))?;
    let mut image = image::DynamicImage::from_decoder(decoder).map_err(|e| file_err(path, e))?;
    image.apply_orientation(orientation);
    colour_pixels(path, image)
}

/// The RGB pixels of `image`, read from `path`: refused if it is stored as greyscale. A
/// patch's features hold its colour, so a grey image, read as colour, would be judged (or
/// trained on) by colours it does not have.
fn colour_pixels(path: &Path, image: image::DynamicImage) -> Result<image::RgbImage, TrainError> {
    if !image.color().has_color() {
        return Err(file_err(
            path,
            "stored as a greyscale image; the appearance model's features include each pixel's colour, so give a \
             colour image",
        ));
    }
    Ok(image.to_rgb8())
}

/// True class -> (patches, patches called object).
pub type ClassTable = std::collections::BTreeMap<String, (usize, usize)>;

/// A model scored on every image of a dataset it was not trained on: patch precision and
/// recall for the object class, and per true class the patches called object.
#[derive(Debug, Clone, serde::Serialize)]
pub struct HeldoutWorld {
    pub dataset: PathBuf,
    /// The world the dataset's images show (its manifest's `world`).
    pub world: String,
    pub images: usize,
    /// `None` (null) where undefined: no patch was called object (precision), or the
    /// images hold no object patch (recall); F1 where either is.
    pub precision: Option<f64>,
    pub recall: Option<f64>,
    pub f1: Option<f64>,
    /// True class -> (patches, patches called object).
    pub by_class: ClassTable,
}

/// Reads the manifest of the held-out dataset in `dir`, refusing, before any training, a
/// dataset whose figures would not be held-out figures of a model trained on the dataset
/// in `training` (its manifest `trained_on`) with `patch_size` px patches: the training
/// dataset itself, or one of its world however the world was named (their `world.toml`
/// files the same; by name and seed for datasets made before they held one), one labelled
/// for other classes (the model's object would be scored against another's labels), one
/// of other patches, and one with no image (it scores nothing, and read as perfect).
pub fn read_heldout_manifest(
    dir: &Path,
    training: &Path,
    trained_on: &Manifest,
    patch_size: u32,
) -> Result<Manifest, TrainError> {
    let manifest = read_manifest(dir)?;
    let another_world = "held-out images must come from another world";
    if crate::partial_files::same_path(dir, training) {
        return Err(file_err(
            dir,
            format!(
                "it is the training dataset {} ({}; dataset seed {}); {another_world}",
                training.display(),
                trained_on.world,
                trained_on.seed
            ),
        ));
    }
    // The world as read, not its bytes: a comment or a name changes no image.
    let scene = |w: worlds::World| (w.ground, w.objects, w.people);
    let same_world =
        match (worlds::load(&dir.join(crate::files::WORLD)), worlds::load(&training.join(crate::files::WORLD))) {
            (Ok(held_out), Ok(trained)) => {
                (scene(held_out) == scene(trained)).then_some("the same ground, objects and people")
            }
            _ => (manifest.world == trained_on.world && manifest.seed == trained_on.seed)
                .then_some("the same world and seed"),
        };
    if let Some(how) = same_world {
        return Err(file_err(
            dir,
            format!(
                "shows the world of the training dataset {} ({}: {how}); {another_world}",
                training.display(),
                trained_on.world
            ),
        ));
    }
    let names = |m: &Manifest| {
        let mut ids: Vec<u8> = m.classes.iter().map(|c| c.id()).collect();
        ids.sort_unstable();
        ids.dedup();
        ids.iter().filter_map(|&id| worlds::ObjectClass::from_id(id)).map(|c| c.name()).collect::<Vec<_>>().join(",")
    };
    if names(&manifest) != names(trained_on) {
        return Err(file_err(
            &dir.join("dataset.json"),
            format!(
                "labelled for the classes {}, and the training dataset {} for {}: the model would be scored against other objects' labels; make it with --classes {}",
                names(&manifest),
                training.display(),
                names(trained_on),
                names(trained_on)
            ),
        ));
    }
    check_patch_size(dir, &manifest, patch_size)?;
    check_not_empty(dir, &manifest)?;
    Ok(manifest)
}

/// Refuses a dataset with no image to score: its precision and recall would read 1.
fn check_not_empty(dir: &Path, manifest: &Manifest) -> Result<(), TrainError> {
    if manifest.images.is_empty() {
        return Err(file_err(
            &dir.join("dataset.json"),
            "images: [] (no image): a held-out dataset with no image scores nothing",
        ));
    }
    Ok(())
}

/// Scores `model` on every image of the dataset in `dir` (another world's, for how the
/// model generalises), with the training's rule for which patches are object.
pub fn score_on_dataset(dir: &Path, model: &AppearanceModel, label_fraction: f64) -> Result<HeldoutWorld, TrainError> {
    let manifest = read_manifest(dir)?;
    check_not_empty(dir, &manifest)?;
    let n = manifest.images.len();
    let ids: Vec<usize> = (0..n).collect();
    let (scores, by_class) = score_images(dir, &manifest, model, &ids, label_fraction)?;
    Ok(HeldoutWorld {
        dataset: dir.to_path_buf(),
        world: manifest.world.clone(),
        images: n,
        precision: scores.defined_precision(),
        recall: scores.defined_recall(),
        f1: scores.defined_f1(),
        by_class,
    })
}

/// The images `ids` of a dataset, each classified once: patch scores against the labels
/// (object when at least `label_fraction` of a patch is, as in training), and per true
/// class (each patch's majority class) the patches and those called object.
fn score_images(
    dir: &Path,
    manifest: &Manifest,
    model: &AppearanceModel,
    ids: &[usize],
    label_fraction: f64,
) -> Result<(classifier::PatchScores, ClassTable), TrainError> {
    let classifier = PatchClassifier::new(model).map_err(ModelError::from)?;
    let mut scores = classifier::PatchScores::default();
    let mut out = ClassTable::default();
    for patches in image_patches(dir, manifest, &model.extractor, ids.iter().copied())? {
        let p = patches?;
        for (k, predicted) in classifier.classify(&p.features).map_err(ModelError::from)?.into_iter().enumerate() {
            scores.add(predicted, p.fractions[k] as f64 >= label_fraction);
            let id = p.classes[k];
            let name = worlds::ObjectClass::from_id(id).map_or_else(
                || if id == 0 { "sky".to_string() } else { format!("class {id}") },
                |c| c.name().to_string(),
            );
            let e = out.entry(name).or_default();
            e.0 += 1;
            e.1 += predicted as usize;
        }
    }
    Ok((scores, out))
}

/// The class id most of patch (`col`, `row`)'s pixels have in a class mask of `l`-pixel
/// patches (the highest id among equals).
pub fn majority_class(class: &image::GrayImage, col: u32, row: u32, l: u32) -> u8 {
    let mut counts = [0usize; 256];
    for y in row * l..(row + 1) * l {
        for x in col * l..(col + 1) * l {
            counts[class.get_pixel(x, y)[0] as usize] += 1;
        }
    }
    (0..256).max_by_key(|&i| counts[i]).unwrap_or(0) as u8
}

/// Writes every patch's feature row with its label fraction and label to a CSV file,
/// written beside it and renamed into place once whole: a failure (a full disk) leaves an
/// earlier file as it was. As with [`crate::partial_files::write_whole`], a link is
/// followed (the file it names is replaced) and a device or pipe is written into as it is.
pub fn export_features(
    dir: &Path,
    model: &AppearanceModel,
    label_fraction: f64,
    out: &Path,
) -> Result<usize, TrainError> {
    use std::io::Write;
    let manifest = read_manifest(dir)?;
    let target = std::fs::canonicalize(out).unwrap_or_else(|_| out.to_path_buf());
    let partial = |e: crate::partial_files::PartialFileError| file_err(&e.file, e.source);
    enum Sink {
        Staged(crate::partial_files::PartialFiles<()>),
        Device(std::io::BufWriter<std::fs::File>),
    }
    let mut sink = if std::fs::metadata(&target).is_ok_and(|m| !m.is_file()) {
        Sink::Device(std::io::BufWriter::new(std::fs::File::create(&target).map_err(|e| file_err(out, e))?))
    } else {
        let name = target.file_name().and_then(|n| n.to_str()).ok_or_else(|| file_err(out, "not a file name"))?;
        let parent = target.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        Sink::Staged(crate::partial_files::PartialFiles::create(parent, &[((), name)]).map_err(partial)?)
    };
    let mut line = |text: &str| match &mut sink {
        Sink::Staged(csv) => csv.write((), text).map_err(partial),
        Sink::Device(w) => w.write_all(text.as_bytes()).map_err(|e| file_err(out, e)),
    };
    let names = feature_names(model.extractor.pca.dims());
    line(&format!("image,col,row,{},fraction,label\n", names.join(",")))?;
    let mut rows = 0;
    for patches in image_patches(dir, &manifest, &model.extractor, 0..manifest.images.len())? {
        let p = patches?;
        for (k, (&(c, r), &frac)) in p.cells.iter().zip(&p.fractions).enumerate() {
            let values: Vec<String> = p.features.z.row(k).iter().map(|v| format!("{v}")).collect();
            let label = (frac as f64 >= label_fraction) as u8;
            line(&format!("{},{c},{r},{},{frac},{label}\n", p.index, values.join(",")))?;
            rows += 1;
        }
    }
    match sink {
        Sink::Staged(csv) => csv.finish().map_err(partial)?,
        Sink::Device(mut w) => w.flush().map_err(|e| file_err(out, e))?,
    }
    Ok(rows)
}

/// Classifies every patch of an image and draws the object patches over it (tinted, with
/// their outlines). Returns (object patches, all patches).
pub fn segment_image(model: &AppearanceModel, image_path: &Path, out: &Path) -> Result<(usize, usize), TrainError> {
    // The picture's file, checked before the work: its extension says the format.
    if out.is_dir() {
        return Err(file_err(out, "a directory; give the picture's file name (.png or .jpg)"));
    }
    let format = image::ImageFormat::from_path(out).map_err(|_| {
        file_err(out, "its extension names no image format; give the picture's file name (.png or .jpg)")
    })?;
    let mut rgb = open_image_to_classify(image_path)?;
    let (w, h) = rgb.dimensions();
    let classifier = PatchClassifier::new(model).map_err(ModelError::from)?;
    let f = {
        let image = ImageRef::new(w, h, rgb.as_raw()).map_err(ModelError::from)?;
        model.extractor.features(&image, None).map_err(|e| file_err(image_path, e))?
    };
    let l = model.extractor.config.patch_size;
    let decisions = classifier.classify(&f).map_err(|e| file_err(image_path, e))?;
    for (k, &object) in decisions.iter().enumerate() {
        if !object {
            continue;
        }
        let (c, r) = f.rect.patch(k).expect(slam::features::IN_RECT);
        for y in r * l..(r + 1) * l {
            for x in c * l..(c + 1) * l {
                let p = rgb.get_pixel_mut(x, y);
                let edge = x == c * l || y == r * l || x + 1 == (c + 1) * l || y + 1 == (r + 1) * l;
                *p = if edge {
                    image::Rgb([255, 40, 40])
                } else {
                    image::Rgb([((p[0] as u16 + 255) / 2) as u8, p[1] / 2, p[2] / 2])
                };
            }
        }
    }
    // Encoded in the format its name asks for, then written whole: a failed write leaves no
    // cut picture under the name.
    let mut bytes = std::io::Cursor::new(Vec::new());
    rgb.write_to(&mut bytes, format).map_err(|e| file_err(out, e))?;
    crate::partial_files::write_whole(out, bytes.get_ref()).map_err(|e| file_err(out, e.source))?;
    Ok((decisions.iter().filter(|&&d| d).count(), decisions.len()))
}

/// Reads a numeric CSV (an optional header row of non-numbers; blank lines skipped).
pub fn read_csv(path: &Path) -> Result<DMatrix<f64>, TrainError> {
    Ok(read_csv_with_digest(path)?.0)
}

/// [`read_csv`], with the SHA-256 (hex) of the bytes it parsed: read once, so the digest a
/// fitted model records is that of the data it was fitted to, even if the file changes.
pub fn read_csv_with_digest(path: &Path) -> Result<(DMatrix<f64>, String), TrainError> {
    use sha2::{Digest, Sha256};
    let bytes = std::fs::read(path).map_err(|e| file_err(path, e))?;
    let digest = Sha256::digest(&bytes).iter().map(|b| format!("{b:02x}")).collect();
    let text = String::from_utf8(bytes).map_err(|e| {
        let valid = &e.as_bytes()[..e.utf8_error().valid_up_to()];
        let line = valid.iter().filter(|&&b| b == b'\n').count() + 1;
        TrainError::Csv { file: path.into(), line, message: "not UTF-8 text".into() }
    })?;
    // Spreadsheets' "CSV UTF-8" starts with a byte-order mark, which is no part of a field.
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    Ok((parse_csv(path, text)?, digest))
}

/// Parses `text`, the contents of the numeric CSV `path` (named in errors).
fn parse_csv(path: &Path, text: &str) -> Result<DMatrix<f64>, TrainError> {
    let mut values = Vec::new();
    let mut cols = None;
    let mut rows = 0;
    let mut first = true;
    // The header's line and its number of names, which the rows must match.
    let mut header: Option<(usize, usize)> = None;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        // A field may be quoted ("1.5"), as spreadsheets write them.
        let fields: Vec<&str> = line
            .split(',')
            .map(str::trim)
            .map(|f| f.strip_prefix('"').and_then(|f| f.strip_suffix('"')).unwrap_or(f))
            .collect();
        let parsed: Result<Vec<f64>, _> = fields.iter().map(|f| f.parse::<f64>()).collect();
        // Only the first row may be a header.
        let may_be_header = std::mem::take(&mut first);
        let row = match parsed {
            Ok(r) => r,
            Err(_) if may_be_header && fields.iter().all(|f| f.parse::<f64>().is_err()) => {
                header = Some((i + 1, fields.len()));
                continue;
            }
            Err(_) => {
                let bad = fields.iter().position(|f| f.parse::<f64>().is_err()).unwrap_or(0);
                return Err(TrainError::Csv {
                    file: path.into(),
                    line: i + 1,
                    message: format!("field {} ({:?}) is not a number", bad + 1, fields[bad]),
                });
            }
        };
        if let Some(bad) = row.iter().position(|v| !v.is_finite()) {
            return Err(TrainError::Csv {
                file: path.into(),
                line: i + 1,
                message: format!("field {} is not finite", bad + 1),
            });
        }
        match cols {
            None => {
                if let Some((line, names)) = header.filter(|(_, names)| *names != row.len()) {
                    return Err(TrainError::Csv {
                        file: path.into(),
                        line,
                        message: format!("the header names {names} columns, and the rows have {} fields", row.len()),
                    });
                }
                cols = Some(row.len())
            }
            Some(c) if c != row.len() => {
                return Err(TrainError::Csv {
                    file: path.into(),
                    line: i + 1,
                    message: format!("{} fields, earlier rows have {c}", row.len()),
                });
            }
            _ => {}
        }
        values.extend(row);
        rows += 1;
    }
    let cols = cols.ok_or_else(|| file_err(path, "no numeric rows"))?;
    Ok(DMatrix::from_row_slice(rows, cols, &values))
}

/// Fits a VB-GMM to a CSV file; returns it with the SHA-256 (hex) of the bytes it was
/// fitted to.
pub fn gmm_fit_csv(path: &Path, options: &VbOptions) -> Result<(VbGmm, String), TrainError> {
    let (data, digest) = read_csv_with_digest(path)?;
    let model = gmm::fit(&data, None, options).map_err(|e| match e {
        // A problem of the data is the file's.
        gmm::GmmError::TooLarge { .. } | gmm::GmmError::TooSmall { .. } | gmm::GmmError::NotFinite { .. } => {
            file_err(path, e)
        }
        e => e.into(),
    })?;
    Ok((model, digest))
}

/// The version of the file `objslam gmm fit` writes (its `format_version`). Files written
/// before the key was kept have none and are read as this version: their layout is the same.
pub const GMM_FILE_FORMAT_VERSION: u32 = 1;

/// The text of a model file of `objslam gmm fit`: the mixture, its `format_version` and,
/// under `fit`, how it was fitted.
pub fn gmm_model_file(model: &VbGmm, record: &GmmFitRecord) -> String {
    let mut file = serde_json::to_value(model).expect("a mixture is JSON");
    file["format_version"] = GMM_FILE_FORMAT_VERSION.into();
    file["fit"] = serde_json::to_value(record).expect("a fit record is JSON");
    serde_json::to_string_pretty(&file).expect("JSON")
}

/// The file [`gmm_model_file`] writes, as read: the mixture's own keys beside its
/// `format_version` and `fit`, and no other (a typo is refused, not dropped).
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct GmmModelFile {
    prior: gmm::VbPrior,
    components: Vec<gmm::VbComponent>,
    lower_bound: f64,
    iterations: usize,
    points: usize,
    counts: Vec<f64>,
    #[serde(default)]
    #[allow(dead_code)]
    format_version: Option<serde_json::Value>,
    #[serde(default)]
    #[allow(dead_code)]
    fit: Option<serde_json::Value>,
}

/// The mixture of a model file of `objslam gmm fit` (see [`gmm_model_file`]); the keys
/// beside it are checked by [`check_gmm_file_version`] and [`GmmFitRecord::of_model`].
pub fn gmm_of_model_file(text: &str) -> Result<VbGmm, String> {
    let f: GmmModelFile = slam::settings::from_json(text)?;
    Ok(VbGmm {
        prior: f.prior,
        components: f.components,
        lower_bound: f.lower_bound,
        iterations: f.iterations,
        points: f.points,
        counts: f.counts,
    })
}

/// A model file's `format_version`, where it has one, is the version this build reads:
/// another layout read as this one would score the wrong numbers.
fn check_gmm_file_version(text: &str) -> Result<(), String> {
    let raw: serde_json::Value = serde_json::from_str(text).map_err(|e| e.to_string())?;
    match raw.get("format_version") {
        None => Ok(()),
        Some(v) if v.as_u64() == Some(u64::from(GMM_FILE_FORMAT_VERSION)) => Ok(()),
        Some(v) if v.is_u64() => Err(format!(
            "format_version {v}: this objslam reads version {GMM_FILE_FORMAT_VERSION}; fit the model again with this version (`objslam gmm fit`)"
        )),
        Some(v) => Err(format!("format_version: {v}, where a version number belongs")),
    }
}

/// How `objslam gmm fit` fitted a model, kept in the model file under `fit`: the same data
/// and options fit the same model again. Read back only to check it, so that a damaged
/// record is not passed over as if it said how the model was made.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GmmFitRecord {
    /// "objslam gmm fit".
    pub tool: String,
    /// The objslam version that fitted it.
    pub version: String,
    /// The data file as given on the command line.
    pub data: String,
    /// The data file's absolute path (null where it could not be resolved; absent from
    /// files of versions before it was recorded).
    #[serde(default)]
    pub data_absolute: Option<String>,
    /// SHA-256 (hex) of the bytes fitted (absent from files of versions before it was
    /// recorded).
    #[serde(default)]
    pub data_sha256: Option<String>,
    pub options: VbOptions,
}

impl GmmFitRecord {
    pub fn new(data: &Path, data_sha256: String, options: &VbOptions) -> GmmFitRecord {
        let data_sha256 = Some(data_sha256);
        GmmFitRecord {
            tool: "objslam gmm fit".into(),
            version: env!("CARGO_PKG_VERSION").into(),
            data: data.display().to_string(),
            data_absolute: std::fs::canonicalize(data).ok().map(|p| p.display().to_string()),
            data_sha256,
            options: options.clone(),
        }
    }

    /// Reads the `fit` record of a model file's text, if it has one.
    fn of_model(text: &str) -> Result<Option<GmmFitRecord>, String> {
        #[derive(serde::Deserialize)]
        struct FitOnly {
            #[serde(default)]
            fit: Option<GmmFitRecord>,
        }
        let fit = slam::settings::from_json::<FitOnly>(text)?.fit;
        // What the types let through: `gmm fit` writes no null, and wrote the digest and
        // the absolute path together from the version that first kept them.
        let raw: serde_json::Value = serde_json::from_str(text).map_err(|e| e.to_string())?;
        match raw.get("fit") {
            Some(serde_json::Value::Null) => {
                return Err("fit: null, where the record of how the model was fitted belongs".into());
            }
            Some(serde_json::Value::Object(record)) => {
                if record.get("data_sha256").is_some_and(serde_json::Value::is_null) {
                    return Err("fit.data_sha256: null, where a SHA-256 (64 hex digits) belongs".into());
                }
                if record.contains_key("data_sha256") != record.contains_key("data_absolute") {
                    return Err("fit: data_sha256 and data_absolute come together (both, or neither in files of versions before them): the record is damaged".into());
                }
                // Every version wrote these; a default read in their place would describe
                // another fit (`search` and `component_cost_nats` are left out at their
                // defaults, so their absence says what they were).
                if let Some(serde_json::Value::Object(options)) = record.get("options") {
                    const WRITTEN: [&str; 7] = [
                        "max_components",
                        "fixed_k",
                        "tolerance",
                        "max_iterations",
                        "split_gain",
                        "min_points",
                        "seed",
                    ];
                    if let Some(key) = WRITTEN.iter().find(|k| !options.contains_key(**k)) {
                        return Err(format!(
                            "fit.options.{key}: missing; every `gmm fit` writes it, so the record is damaged"
                        ));
                    }
                }
            }
            _ => {}
        }
        if let Some(digest) = fit.as_ref().and_then(|f| f.data_sha256.as_ref())
            && !(digest.len() == 64 && digest.bytes().all(|b| b.is_ascii_hexdigit()))
        {
            return Err(format!("fit.data_sha256: {digest:?} is not a SHA-256 (64 hex digits)"));
        }
        Ok(fit)
    }
}

/// Reads a model written by `objslam gmm fit` and a CSV of held-out points; returns the mean
/// posterior predictive log-likelihood per point ([`VbGmm::mean_log_predictive`]) and the
/// number of points.
pub fn gmm_score_csv(model: &Path, path: &Path) -> Result<(f64, usize), TrainError> {
    let text = std::fs::read_to_string(model).map_err(|e| file_err(model, e))?;
    // The version first: a model of another layout would fail below with a message about
    // a field, not about its version.
    if serde_json::from_str::<serde_json::Value>(&text).is_ok() {
        check_gmm_file_version(&text).map_err(|e| file_err(model, e))?;
    }
    let fitted = gmm_of_model_file(&text).map_err(|e| file_err(model, format!("not an objslam gmm fit model: {e}")))?;
    fitted.check().map_err(|e| file_err(model, e))?;
    GmmFitRecord::of_model(&text).map_err(|e| file_err(model, e))?;
    let data = read_csv(path)?;
    if data.ncols() != fitted.dims() {
        return Err(file_err(
            path,
            format!("{} columns, but the model {} has {} dimensions", data.ncols(), model.display(), fitted.dims()),
        ));
    }
    // The data's own problems (values too large to score) name the CSV.
    let mean = fitted.mean_log_predictive(&data).map_err(|e| file_err(path, e))?;
    Ok((mean, data.nrows()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An image to classify must hold colour, which the features read; a colour image is
    /// read as it is.
    #[test]
    fn a_greyscale_image_to_classify_is_refused() {
        let dir = std::env::temp_dir().join(format!("objslam-grey-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let grey = dir.join("grey.png");
        image::GrayImage::from_pixel(20, 10, image::Luma([90])).save(&grey).unwrap();
        let e = open_image_to_classify(&grey).unwrap_err().to_string();
        assert!(e.contains("grey.png") && e.contains("stored as a greyscale image"), "{e}");
        let colour = dir.join("colour.png");
        image::RgbImage::from_pixel(20, 10, image::Rgb([90, 90, 90])).save(&colour).unwrap();
        assert_eq!(open_image_to_classify(&colour).unwrap().dimensions(), (20, 10));
        // Its format is read from its bytes: a PNG named .jpg, or named without an extension.
        for name in ["png_named.jpg", "no_extension"] {
            std::fs::copy(&colour, dir.join(name)).unwrap();
            assert_eq!(open_image_to_classify(&dir.join(name)).unwrap().dimensions(), (20, 10), "{name}");
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A CSV's errors name its line: bytes that are not UTF-8 as well as fields that are
    /// not numbers; a good file gives its values and the digest of its bytes.
    #[test]
    fn csv_errors_name_the_line() {
        let dir = std::env::temp_dir().join(format!("objslam-train-csv-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("points.csv");
        std::fs::write(&file, b"x,y\n1,2\n3,\xff\n").unwrap();
        let e = read_csv(&file).unwrap_err().to_string();
        assert!(e.contains("points.csv: line 3: not UTF-8 text"), "{e}");
        std::fs::write(&file, "x,y\n1,2\n3,four\n").unwrap();
        let e = read_csv(&file).unwrap_err().to_string();
        assert!(e.contains("points.csv: line 3: field 2"), "{e}");
        std::fs::write(&file, "x,y\n1,2\n3,4\n").unwrap();
        let (values, digest) = read_csv_with_digest(&file).unwrap();
        assert_eq!(values, DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 3.0, 4.0]));
        // sha256sum of "x,y\n1,2\n3,4\n".
        assert_eq!(digest, "2a2b86e74ffd5e6a9b75e52a105cf9d02920837179f8e8961aa15411d380f7a3");
        // Quoted fields are numbers too, and only the first row may be a header: a quoted
        // first row of data had been dropped as a second header.
        std::fs::write(&file, "x,y\n\"1\",\"2\"\n3,4\n").unwrap();
        assert_eq!(read_csv(&file).unwrap(), DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 3.0, 4.0]));
        std::fs::write(&file, "x,y\na,b\n3,4\n").unwrap();
        let e = read_csv(&file).unwrap_err().to_string();
        assert!(e.contains("points.csv: line 2: field 1"), "{e}");
        // A header of more (or fewer) names than the rows' fields: columns mislabelled.
        std::fs::write(&file, "x,y,z\n1,2\n3,4\n").unwrap();
        let e = read_csv(&file).unwrap_err().to_string();
        assert!(e.contains("points.csv: line 1: the header names 3 columns, and the rows have 2 fields"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
