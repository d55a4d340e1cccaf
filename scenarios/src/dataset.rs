//! `objslam dataset`: training images with exact labels for the paper's offline phase.
//!
//! Viewpoints at varied distances, heights and angles around objects of the wanted
//! classes, plus background views, under varied sun and exposure. Per image: the RGB PNG,
//! 16-bit instance and 8-bit class masks, per-patch labels (the fraction of each L x L
//! patch covered by the wanted classes), K and the camera pose; `dataset.json` lists them
//! and `annotations.json` holds COCO instance annotations with RLE masks.

use crate::files;
use std::path::{Path, PathBuf};

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use serde_json::json;
use sim::camera::{CameraConfig, CameraSensor, Rigid};
use worlds::{ObjectClass, World};

use crate::record::{RecordError, write_png};

/// Version of `dataset.json`.
pub const DATASET_FORMAT_VERSION: u32 = 1;

#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{0}")]
    Config(String),
    #[error(transparent)]
    Camera(#[from] sim::camera::CameraError),
    #[error(transparent)]
    Write(#[from] RecordError),
    #[error("{}: {source}", file.display())]
    Io { file: PathBuf, source: std::io::Error },
    /// The dataset was written whole, but some of its files could not be moved into place.
    #[error("{}", crate::run::join_errors(.0))]
    Publish(Vec<crate::partial_files::PartialFileError>),
}

impl From<crate::partial_files::PartialFileError> for DatasetError {
    fn from(e: crate::partial_files::PartialFileError) -> Self {
        DatasetError::Io { file: e.file, source: e.source }
    }
}

/// Dataset settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DatasetConfig {
    pub images: usize,
    pub seed: u64,
    /// Classes whose pixels are labelled positive in the patch labels.
    pub classes: Vec<ObjectClass>,
    pub patch_size: u32,
    /// Fraction of background views (no wanted object targeted).
    pub background_fraction: f64,
    /// Fraction of background views aimed at a distractor (a post, palm, wall or person)
    /// rather than anywhere: the hard negatives a classifier must learn.
    #[serde(default = "default_distractor_fraction")]
    pub distractor_fraction: f64,
    pub camera: CameraConfig,
    /// Camera distance from the targeted object (m).
    pub distance_m: [f64; 2],
    /// Camera height above the ground (m).
    pub height_m: [f64; 2],
}

impl Default for DatasetConfig {
    fn default() -> Self {
        DatasetConfig {
            images: 100,
            seed: 1,
            classes: vec![ObjectClass::Tree],
            patch_size: 9,
            background_fraction: 0.3,
            distractor_fraction: default_distractor_fraction(),
            camera: CameraConfig::default(),
            distance_m: [1.5, 8.0],
            height_m: [0.4, 1.6],
        }
    }
}

fn default_distractor_fraction() -> f64 {
    0.7
}

/// The classes a dataset aims its camera at, and so may label: standing objects. People
/// and leaves are in the images and masks where they are, but are not aimed at.
pub const AIMED_CLASSES: [ObjectClass; 5] =
    [ObjectClass::Tree, ObjectClass::Palm, ObjectClass::Post, ObjectClass::Wall, ObjectClass::Checkerboard];

/// One image's entry in `dataset.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImageEntry {
    pub id: usize,
    pub image: String,
    pub instance: String,
    pub class: String,
    pub patches: String,
    /// "object" (aimed at an object of a wanted class) or "background".
    pub kind: String,
    pub target_instance: Option<u16>,
    /// World <- camera optical frame.
    pub world_from_camera: Rigid,
    pub sun_direction: [f32; 3],
    pub exposure: f32,
    /// Time at which people were posed.
    pub people_time_s: f64,
}

/// The manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub format_version: u32,
    pub seed: u64,
    pub world: String,
    pub classes: Vec<ObjectClass>,
    pub patch_size: u32,
    pub width: u32,
    pub height: u32,
    pub k: [[f64; 3]; 3],
    pub renderer: String,
    pub images: Vec<ImageEntry>,
}

impl Manifest {
    /// What a manifest edited by hand could get wrong that no file it names would show: its
    /// layout, its classes, an image listed twice (trained on twice, or both trained on and
    /// held out), and files outside the dataset (another world's pictures read against this
    /// one's masks).
    pub fn check(&self) -> Result<(), String> {
        let manifest = self;
        let version = DATASET_FORMAT_VERSION;
        if manifest.format_version != version {
            return Err(format!("format_version {}, this objslam reads version {version}", manifest.format_version));
        }
        if manifest.classes.is_empty() {
            return Err("classes: none; a dataset labels the patches of at least one class".into());
        }
        if let Some(c) = manifest.classes.iter().enumerate().find(|(i, c)| manifest.classes[..*i].contains(c)) {
            return Err(format!("classes: {} is named twice", c.1.name()));
        }
        if let Some(c) = manifest.classes.iter().find(|c| !AIMED_CLASSES.contains(c)) {
            return Err(format!(
                "classes: {} is not a class a dataset aims at and labels ({})",
                c.name(),
                AIMED_CLASSES.map(|c| c.name()).join(", ")
            ));
        }
        if manifest.width == 0 || manifest.height == 0 {
            return Err(format!("width and height: {}x{} is no image", manifest.width, manifest.height));
        }
        let mut ids = std::collections::BTreeSet::new();
        let mut files = std::collections::BTreeSet::new();
        for (i, entry) in manifest.images.iter().enumerate() {
            if !ids.insert(entry.id) {
                return Err(format!("images[{i}].id: {} is listed twice", entry.id));
            }
            if entry.kind != "object" && entry.kind != "background" {
                return Err(format!(
                    "images[{i}].kind: {:?}, where an image is \"object\" or \"background\"",
                    entry.kind
                ));
            }
            for (key, file) in [
                ("image", &entry.image),
                ("instance", &entry.instance),
                ("class", &entry.class),
                ("patches", &entry.patches),
            ] {
                let inside = Path::new(file).components().all(|c| matches!(c, std::path::Component::Normal(_)));
                if !inside || file.is_empty() {
                    return Err(format!("images[{i}].{key}: {file:?} is not a path inside the dataset"));
                }
                if !files.insert(file.as_str()) {
                    return Err(format!("images[{i}].{key}: {file} is listed twice"));
                }
            }
        }
        Ok(())
    }
}

/// Per-patch labels of one image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PatchLabels {
    pub patch_size: u32,
    pub rows: u32,
    pub cols: u32,
    /// Row-major fractions in [0, 1] of each patch's pixels that belong to a wanted class.
    pub fractions: Vec<f32>,
}

/// Fraction of each `l` x `l` patch whose class is one of `wanted` (partial patches at the
/// right and bottom edges are dropped, as the paper's 640/9 x 480/9 grid does).
pub fn patch_labels(class: &[u8], width: u32, height: u32, l: u32, wanted: &[u8]) -> PatchLabels {
    let (cols, rows) = (width / l, height / l);
    let mut fractions = vec![0.0f32; (rows * cols) as usize];
    for r in 0..rows {
        for c in 0..cols {
            let mut n = 0u32;
            for y in r * l..(r + 1) * l {
                for x in c * l..(c + 1) * l {
                    n += wanted.contains(&class[(y * width + x) as usize]) as u32;
                }
            }
            fractions[(r * cols + c) as usize] = n as f32 / (l * l) as f32;
        }
    }
    PatchLabels { patch_size: l, rows, cols, fractions }
}

/// COCO run-length encoding (uncompressed): counts of alternating runs of 0 and 1 in
/// column-major order, starting with 0s.
pub fn rle_encode(mask: &[bool], width: u32, height: u32) -> Vec<u32> {
    let mut counts = Vec::new();
    let mut current = false;
    let mut run = 0u32;
    for x in 0..width {
        for y in 0..height {
            let v = mask[(y * width + x) as usize];
            if v != current {
                counts.push(run);
                run = 0;
                current = v;
            }
            run += 1;
        }
    }
    counts.push(run);
    counts
}

/// Decodes [`rle_encode`]'s counts back into a row-major mask.
pub fn rle_decode(counts: &[u32], width: u32, height: u32) -> Vec<bool> {
    let mut mask = vec![false; (width * height) as usize];
    let mut i = 0u32;
    let mut value = false;
    for &c in counts {
        for k in i..i + c {
            let (x, y) = (k / height, k % height);
            mask[(y * width + x) as usize] = value;
        }
        i += c;
        value = !value;
    }
    mask
}

/// A camera at `eye` looking at `target`, image rows level.
pub fn look_at(eye: [f64; 3], target: [f64; 3]) -> Rigid {
    let sub = [target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]];
    let norm = |v: [f64; 3]| {
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-12);
        [v[0] / l, v[1] / l, v[2] / l]
    };
    let cross =
        |a: [f64; 3], b: [f64; 3]| [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    let z = norm(sub);
    let x = norm(cross(z, [0.0, 0.0, 1.0]));
    let y = cross(z, x);
    Rigid { r: [[x[0], y[0], z[0]], [x[1], y[1], z[1]], [x[2], y[2], z[2]]], t: eye }
}

/// Makes a dataset of `world` in `out`. `progress(done, total)` after each image. `out` is
/// held against other commands while the dataset is written in its unfinished directory,
/// and the dataset replaces what `out` held only once written whole, its `dataset.json`
/// last: two datasets given one `out`, or one stopped on the way, never leave a manifest
/// over another dataset's images.
pub fn make_dataset(
    world: &World,
    world_name: &str,
    config: &DatasetConfig,
    out: &Path,
    progress: impl Fn(usize, usize),
) -> Result<Manifest, DatasetError> {
    use crate::partial_files as staging;
    check_config(world, config)?;
    // Under the hold, before the unfinished directory is started anew.
    let check = || {
        finish_stopped_publish(out)?;
        crate::partial_files::check_no_other_stopped_move(out, &[])?;
        check_out(out)
    };
    let (manifest, _held) =
        staging::write_unfinished(out, check, |dir| write_dataset(world, world_name, config, dir, progress))?;
    // The manifest is the marker: the earlier one removed first, this one moved in last,
    // so a publish stopped midway leaves no manifest, not a mix.
    staging::publish(&staging::unfinished_dir(out), out, &[], "dataset.json").map_err(DatasetError::Publish)?;
    Ok(manifest)
}

/// The names a dataset writes in its directory, each replaced whole by the next dataset's.
pub const OUTPUTS: &[&str] = &["dataset.json", "annotations.json", files::WORLD, "images", "masks", "labels"];

/// Refuses an `out` that holds a name a dataset replaces but is no earlier dataset (it has
/// no `dataset.json`): a user's own `images/` or `world.toml` would be lost.
fn check_out(out: &Path) -> Result<(), DatasetError> {
    // An earlier dataset, or one stopped while it was moved in (its manifest still waits
    // in the unfinished directory, where it goes last).
    let unfinished = crate::partial_files::unfinished_dir(out);
    let manifest = out.join("dataset.json");
    if is_dataset_manifest(&manifest) || is_dataset_manifest(&unfinished.join("dataset.json")) {
        return Ok(());
    }
    if manifest.symlink_metadata().is_ok() {
        return Err(DatasetError::Config(format!(
            "--out {}: holds a dataset.json that is no objslam dataset's manifest, and a dataset would replace it \
             and the images/, masks/ and labels/ beside it; give a new or empty directory",
            out.display()
        )));
    }
    match files::first_present(out, OUTPUTS) {
        Some(name) => Err(DatasetError::Config(format!(
            "--out {}: holds {name} but no dataset.json, so it is not an earlier dataset, and a dataset would replace \
             it; give a new or empty directory",
            out.display()
        ))),
        None => Ok(()),
    }
}

/// Whether `file` reads as an objslam dataset's manifest (a `dataset.json` another tool
/// wrote beside its own `images/` does not).
fn is_dataset_manifest(file: &Path) -> bool {
    std::fs::read(file).is_ok_and(|bytes| serde_json::from_slice::<Manifest>(&bytes).is_ok())
}

/// Finishes moving in a dataset whose move into `out` was stopped (its manifest, which
/// goes last, still waits in the unfinished directory): the next dataset starts its
/// unfinished directory anew, and without this a second stop would leave `out` with a
/// dataset's files and no manifest, which no dataset command would take again.
fn finish_stopped_publish(out: &Path) -> Result<(), DatasetError> {
    // Called under the hold: no dataset is in `out`, and a whole manifest waits.
    let unfinished = crate::partial_files::unfinished_dir(out);
    if !out.join("dataset.json").exists() && is_dataset_manifest(&unfinished.join("dataset.json")) {
        crate::partial_files::finish_publish(&unfinished, out, &[], "dataset.json").map_err(DatasetError::Publish)?;
    }
    Ok(())
}

/// Whether `file` is one of the files of the dataset in `dir`: a name of [`OUTPUTS`] there,
/// or anything in its folders (so that no other output of a command overwrites it), by its
/// path or where a link leads.
pub fn owns(dir: &Path, file: &Path) -> bool {
    crate::files::lies_among(dir, OUTPUTS, file)
}

/// Refuses settings no dataset of `world` can be made with, before anything is written.
pub(crate) fn check_config(world: &World, config: &DatasetConfig) -> Result<(), DatasetError> {
    // Each image is written as it is made (memory stays flat), but the COCO annotations
    // are gathered for one file: a million images is far beyond any training run here.
    if !(1..=1_000_000).contains(&config.images) {
        return Err(DatasetError::Config(format!("--images must be 1..1000000, got {}", config.images)));
    }
    // A dataset is made to be trained on: patches no model can describe would be found
    // out only by `objslam train`. One limit, the tighter of the two, said once.
    let features_max = slam::features::FeatureConfig::MAX_PATCH_SIZE;
    let image_max = config.camera.width.min(config.camera.height);
    if config.patch_size == 0 || config.patch_size > features_max.min(image_max) {
        let why = if image_max < features_max {
            format!("the {}x{} image's shorter side", config.camera.width, config.camera.height)
        } else {
            "the largest patch the patch features describe".to_string()
        };
        return Err(DatasetError::Config(format!(
            "--patch-size {}: give 1 to {} pixels ({why})",
            config.patch_size,
            features_max.min(image_max)
        )));
    }
    if !world.objects.iter().any(|o| config.classes.contains(&o.class)) && config.background_fraction < 1.0 {
        return Err(DatasetError::Config(format!(
            "the world has no object of the classes {:?}",
            config.classes.iter().map(|c| c.name()).collect::<Vec<_>>()
        )));
    }
    Ok(())
}

/// Writes a dataset of `world` straight into `out`, which the caller holds (see
/// [`make_dataset`], or a training's own scratch directory), with a `config` the caller
/// has checked ([`check_config`], before taking `out`).
pub(crate) fn write_dataset(
    world: &World,
    world_name: &str,
    config: &DatasetConfig,
    out: &Path,
    progress: impl Fn(usize, usize),
) -> Result<Manifest, DatasetError> {
    let targets: Vec<&worlds::StaticObject> =
        world.objects.iter().filter(|o| config.classes.contains(&o.class)).collect();
    crate::partial_files::make_output_dir(out)?;
    clear_earlier_images(out)?;
    for dir in ["images", "masks", "labels"] {
        std::fs::create_dir_all(out.join(dir)).map_err(|e| DatasetError::Io { file: out.join(dir), source: e })?;
    }
    let mut cam = CameraSensor::new(world, &config.camera, sim::derive_seed(config.seed, "dataset-camera"))?;
    let base_lighting = cam.lighting;
    let k = config.camera.intrinsics();
    let (w, h) = (config.camera.width, config.camera.height);
    let wanted: Vec<u8> = config.classes.iter().map(|c| c.id()).collect();
    let footprints: Vec<worlds::Footprint> = world.objects.iter().map(|o| o.shape.footprint(&o.pose)).collect();
    let g = &world.ground;
    let mut entries = Vec::new();
    let mut coco_images = Vec::new();
    let mut coco_annotations = Vec::new();
    for i in 0..config.images {
        let mut rng = ChaCha8Rng::seed_from_u64(sim::derive_seed(config.seed, &format!("dataset-image-{i}")));
        let background = targets.is_empty() || rng.random_range(0.0..1.0) < config.background_fraction;
        let people_time = rng.random_range(0.0..120.0);
        let people: Vec<sim::PersonState> =
            world.people.iter().map(|p| sim::people::person_state(p, people_time)).collect();
        // Distractors: static objects of other classes, and people where they stand now.
        let distractor = (background && rng.random_range(0.0..1.0) < config.distractor_fraction).then(|| {
            let mut spots: Vec<([f64; 2], f64)> = world
                .objects
                .iter()
                .filter(|o| !config.classes.contains(&o.class) && o.class != ObjectClass::Wall)
                .map(|o| ([o.pose.x, o.pose.y], o.shape.top_m().min(2.0)))
                .collect();
            spots.extend(people.iter().map(|p| ([p.x, p.y], 1.2)));
            spots.extend(
                world.objects.iter().filter(|o| o.class == ObjectClass::Wall).map(|o| ([o.pose.x, o.pose.y], 1.0)),
            );
            spots
        });
        // An object view is redrawn from another viewpoint when its target is hidden
        // behind something else (up to 20 tries).
        let mut tries = 0;
        let (frame, pose, sun, exposure, target_id) = loop {
            // Pick a viewpoint clear of every object and inside the ground.
            let mut chosen = None;
            for _ in 0..1000 {
                let height = rng.random_range(config.height_m[0]..=config.height_m[1]);
                let (eye, target, target_id) = if let Some(spots) = distractor.as_ref().filter(|s| !s.is_empty()) {
                    let (p, top) = spots[rng.random_range(0..spots.len())];
                    let d = rng.random_range(config.distance_m[0]..=config.distance_m[1]);
                    let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                    let eye = [p[0] + d * a.cos(), p[1] + d * a.sin(), height];
                    (eye, [p[0], p[1], rng.random_range(0.3..top.max(0.4))], None)
                } else if background {
                    let eye =
                        [rng.random_range(g.min_m[0]..g.max_m[0]), rng.random_range(g.min_m[1]..g.max_m[1]), height];
                    let yaw: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                    (eye, [eye[0] + yaw.cos(), eye[1] + yaw.sin(), height - rng.random_range(0.0..0.3)], None)
                } else {
                    let o = targets[rng.random_range(0..targets.len())];
                    let d = rng.random_range(config.distance_m[0]..=config.distance_m[1]);
                    let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                    let eye = [o.pose.x + d * a.cos(), o.pose.y + d * a.sin(), height];
                    let aim_h = rng.random_range(0.3..o.shape.top_m().clamp(0.4, 2.5));
                    let jitter = 0.15 * d;
                    let target = [
                        o.pose.x + rng.random_range(-jitter..=jitter) * 0.3,
                        o.pose.y + rng.random_range(-jitter..=jitter) * 0.3,
                        aim_h,
                    ];
                    (eye, target, Some(o.id))
                };
                let inside = eye[0] > g.min_m[0] + 0.3
                    && eye[0] < g.max_m[0] - 0.3
                    && eye[1] > g.min_m[1] + 0.3
                    && eye[1] < g.max_m[1] - 0.3;
                if inside && footprints.iter().all(|f| f.distance_to_point([eye[0], eye[1]]) > 0.3) {
                    chosen = Some((eye, target, target_id));
                    break;
                }
            }
            let Some((eye, target, target_id)) = chosen else {
                return Err(DatasetError::Config(format!(
                    "no free viewpoint found for image {i}; the world is too crowded"
                )));
            };
            // Lighting variation: sun azimuth and elevation, exposure.
            let az: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let el: f64 = rng.random_range(0.3..1.3);
            let sun = [(-el.cos() * az.cos()) as f32, (-el.cos() * az.sin()) as f32, (-el.sin()) as f32];
            let exposure = rng.random_range(0.75..1.25) as f32;
            cam.lighting = render::Lighting { sun_direction: sun, exposure, ..base_lighting };
            cam.pose_people(&people);
            let pose = look_at(eye, target);
            let frame = cam.render_from(0.0, pose)?;
            tries += 1;
            let hidden = target_id.is_some_and(|id| !frame.image.instance.contains(&id));
            if !hidden || tries >= 20 {
                break (frame, pose, sun, exposure, target_id);
            }
        };
        let img = &frame.image;

        let stem = format!("{i:06}");
        let names = [
            format!("images/{stem}.png"),
            format!("masks/{stem}_instance.png"),
            format!("masks/{stem}_class.png"),
            format!("labels/{stem}_patches.json"),
        ];
        write_png(&out.join(&names[0]), w, h, image::ExtendedColorType::Rgb8, &img.rgb)?;
        let inst: Vec<u8> = img.instance.iter().flat_map(|v| v.to_ne_bytes()).collect();
        write_png(&out.join(&names[1]), w, h, image::ExtendedColorType::L16, &inst)?;
        write_png(&out.join(&names[2]), w, h, image::ExtendedColorType::L8, &img.class)?;
        let labels = patch_labels(&img.class, w, h, config.patch_size, &wanted);
        std::fs::write(out.join(&names[3]), serde_json::to_string(&labels).expect("JSON"))
            .map_err(|e| DatasetError::Io { file: out.join(&names[3]), source: e })?;

        // COCO: one annotation per visible part of an object instance, by the class image:
        // a tree's trunk is a `tree` annotation and its canopy a `foliage` one with the
        // same `instance_id` (likewise a palm's trunk and crown), so that each category
        // means what it means in the class masks. Ground and sky are not annotated.
        coco_images.push(json!({"id": i, "file_name": names[0], "width": w, "height": h}));
        let mut parts: Vec<(u16, u8)> = img
            .instance
            .iter()
            .zip(&img.class)
            .filter(|(id, _)| **id != 0 && **id != worlds::validate::GROUND_INSTANCE_ID)
            .map(|(id, class)| (*id, *class))
            .collect();
        parts.sort_unstable();
        parts.dedup();
        for (id, class) in parts {
            let mask: Vec<bool> = img.instance.iter().zip(&img.class).map(|(v, c)| *v == id && *c == class).collect();
            let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
            let mut area = 0u32;
            for y in 0..h {
                for x in 0..w {
                    if mask[(y * w + x) as usize] {
                        x0 = x0.min(x);
                        y0 = y0.min(y);
                        x1 = x1.max(x);
                        y1 = y1.max(y);
                        area += 1;
                    }
                }
            }
            coco_annotations.push(json!({
                "id": coco_annotations.len() + 1,
                "image_id": i,
                "category_id": class,
                "instance_id": id,
                "bbox": [x0, y0, x1 - x0 + 1, y1 - y0 + 1],
                "area": area,
                "iscrowd": 0,
                "segmentation": {"counts": rle_encode(&mask, w, h), "size": [h, w]},
            }));
        }
        entries.push(ImageEntry {
            id: i,
            image: names[0].clone(),
            instance: names[1].clone(),
            class: names[2].clone(),
            patches: names[3].clone(),
            kind: if background { "background".into() } else { "object".into() },
            target_instance: target_id,
            world_from_camera: pose,
            sun_direction: sun,
            exposure,
            people_time_s: people_time,
        });
        progress(i + 1, config.images);
    }
    let manifest = Manifest {
        format_version: DATASET_FORMAT_VERSION,
        seed: config.seed,
        world: world_name.into(),
        classes: config.classes.clone(),
        patch_size: config.patch_size,
        width: w,
        height: h,
        k: k.k(),
        renderer: cam.adapter().to_string(),
        images: entries,
    };
    let write = |name: &str, v: &serde_json::Value| {
        std::fs::write(out.join(name), serde_json::to_string_pretty(v).expect("JSON"))
            .map_err(|e| DatasetError::Io { file: out.join(name), source: e })
    };
    let categories: Vec<_> = ObjectClass::ALL
        .iter()
        .filter(|c| **c != ObjectClass::Ground)
        .map(|c| json!({"id": c.id(), "name": c.name(), "supercategory": "object"}))
        .collect();
    write(
        "annotations.json",
        &json!({"info": {"description": format!("objslam dataset of {world_name}"), "version": "1.0"}, "images": coco_images, "annotations": coco_annotations, "categories": categories}),
    )?;
    std::fs::write(out.join(files::WORLD), world.to_toml())
        .map_err(|e| DatasetError::Io { file: out.join(files::WORLD), source: e })?;
    // The manifest last: it marks the dataset whole, so one stopped before it is never
    // taken for a finished one.
    write("dataset.json", &serde_json::to_value(&manifest).expect("JSON"))?;
    Ok(manifest)
}

/// Removes the per-image files an earlier dataset in `out` wrote (named from a six-digit
/// image number), so that none is left beside this one's and read as its own: a dataset of
/// fewer images written over one of more kept the surplus. Other files are left alone.
fn clear_earlier_images(out: &Path) -> Result<(), DatasetError> {
    let io = |file: &Path, e| DatasetError::Io { file: file.to_path_buf(), source: e };
    for dir in ["images", "masks", "labels"] {
        let dir = out.join(dir);
        let entries = match std::fs::read_dir(&dir) {
            Ok(entries) => entries,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(io(&dir, e)),
        };
        for entry in entries {
            let path = entry.map_err(|e| io(&dir, e))?.path();
            let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            let numbered = name.len() > 6 && name.as_bytes()[..6].iter().all(u8::is_ascii_digit);
            if numbered && path.is_file() {
                std::fs::remove_file(&path).map_err(|e| io(&path, e))?;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An `--out` holding a dataset's names is taken only as a dataset: one with its
    /// manifest, or one stopped while moved in (its manifest still unfinished).
    #[test]
    fn only_a_dataset_directory_is_written_over() {
        let out = std::env::temp_dir().join(format!("objslam-dataset-out-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        std::fs::create_dir_all(out.join("images")).unwrap();
        std::fs::write(out.join("notes.txt"), "mine").unwrap();
        let e = check_out(&out).unwrap_err().to_string();
        assert!(e.contains("holds images but no dataset.json"), "{e}");
        let unfinished = crate::partial_files::unfinished_dir(&out);
        std::fs::create_dir_all(&unfinished).unwrap();
        let manifest = Manifest {
            format_version: DATASET_FORMAT_VERSION,
            seed: 1,
            world: "w".into(),
            classes: vec![ObjectClass::Tree],
            patch_size: 9,
            width: 64,
            height: 48,
            k: [[50.0, 0.0, 32.0], [0.0, 50.0, 24.0], [0.0, 0.0, 1.0]],
            renderer: "r".into(),
            images: Vec::new(),
        };
        let manifest = serde_json::to_string(&manifest).unwrap();
        std::fs::write(unfinished.join("dataset.json"), &manifest).unwrap();
        check_out(&out).unwrap();
        // A stopped move is finished before the next dataset starts its own.
        std::fs::create_dir_all(unfinished.join("masks")).unwrap();
        finish_stopped_publish(&out).unwrap();
        assert!(out.join("masks").is_dir() && out.join("dataset.json").is_file() && !unfinished.exists());
        check_out(&out).unwrap();
        // Another tool's dataset.json beside its images is no earlier dataset.
        std::fs::write(out.join("dataset.json"), "{\"name\": \"my own data\"}").unwrap();
        let e = check_out(&out).unwrap_err().to_string();
        assert!(e.contains("holds a dataset.json that is no objslam dataset's manifest"), "{e}");
        finish_stopped_publish(&out).unwrap();
        assert!(out.join("masks").is_dir(), "nothing moved");
        std::fs::remove_dir_all(&out).unwrap();
        // Unrelated files alone are no dataset's names.
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join("notes.txt"), "mine").unwrap();
        check_out(&out).unwrap();
        std::fs::remove_dir_all(&out).unwrap();
    }

    /// A manifest edited by hand is read as written or refused: an unknown key (a typo of
    /// an optional one), a class no dataset aims at, an image of no kind.
    #[test]
    fn a_manifest_with_keys_classes_or_kinds_it_cannot_hold_is_refused() {
        let entry = serde_json::json!({
            "id": 0, "image": "images/0.png", "instance": "masks/0_instance.png", "class": "masks/0_class.png",
            "patches": "labels/0_patches.json", "kind": "object", "target_instance": 3,
            "world_from_camera": {"r": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "t": [0.0, 0.0, 0.0]},
            "sun_direction": [0.0, 0.0, -1.0], "exposure": 1.0, "people_time_s": 0.0
        });
        let manifest = serde_json::json!({
            "format_version": DATASET_FORMAT_VERSION, "seed": 1, "world": "w", "classes": ["tree"], "patch_size": 9,
            "width": 64, "height": 48, "k": [[50.0, 0.0, 32.0], [0.0, 50.0, 24.0], [0.0, 0.0, 1.0]],
            "renderer": "r", "images": [entry]
        });
        let read = |m: &serde_json::Value| {
            serde_json::from_value::<Manifest>(m.clone()).map_err(|e| e.to_string()).and_then(|m| m.check())
        };
        read(&manifest).unwrap();
        let mut typo = manifest.clone();
        typo["bogus"] = serde_json::json!(1);
        assert!(read(&typo).unwrap_err().contains("unknown field `bogus`"));
        let mut typo = manifest.clone();
        typo["images"][0]["exposur"] = serde_json::json!(1.0);
        assert!(read(&typo).unwrap_err().contains("unknown field `exposur`"));
        let mut person = manifest.clone();
        person["classes"] = serde_json::json!(["person"]);
        let e = read(&person).unwrap_err();
        assert!(e.contains("classes: person is not a class a dataset aims at"), "{e}");
        let mut kind = manifest.clone();
        kind["images"][0]["kind"] = serde_json::json!("bogus");
        let e = read(&kind).unwrap_err();
        assert!(e.contains("images[0].kind: \"bogus\""), "{e}");
        let labels = serde_json::json!({"patch_size": 9, "rows": 1, "cols": 1, "fractions": [0.5], "extra": 1});
        assert!(serde_json::from_value::<PatchLabels>(labels).is_err());
    }

    #[test]
    fn an_earlier_datasets_image_files_are_removed_and_other_files_kept() {
        let out = std::env::temp_dir().join(format!("objslam-dataset-clear-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        for (dir, name) in [("images", "000005.png"), ("masks", "000005_class.png"), ("labels", "000005_patches.json")]
        {
            std::fs::create_dir_all(out.join(dir)).unwrap();
            std::fs::write(out.join(dir).join(name), "earlier").unwrap();
        }
        std::fs::write(out.join("images/README.txt"), "mine").unwrap();
        clear_earlier_images(&out).unwrap();
        assert!(!out.join("images/000005.png").exists() && !out.join("masks/000005_class.png").exists());
        assert!(!out.join("labels/000005_patches.json").exists());
        assert!(out.join("images/README.txt").exists());
        clear_earlier_images(&out.join("nowhere")).unwrap();
        std::fs::remove_dir_all(&out).ok();
    }

    #[test]
    fn rle_round_trips_column_major() {
        let (w, h) = (5, 3);
        let mask: Vec<bool> = (0..15).map(|i| [1, 2, 7, 8, 12].contains(&i)).collect();
        let counts = rle_encode(&mask, w, h);
        assert_eq!(rle_decode(&counts, w, h), mask);
        // Column-major: the first column (rows 0, 1, 2) is pixels 0, 5, 10: all false.
        assert!(counts[0] >= 3);
        assert_eq!(counts.iter().sum::<u32>(), 15);
    }

    #[test]
    fn patch_labels_count_wanted_pixels() {
        let (w, h) = (6, 3);
        let mut class = vec![0u8; 18];
        for y in 0..3 {
            class[y * 6] = 2; // first column is tree
            class[y * 6 + 4] = 4; // a post pixel column
        }
        let l = patch_labels(&class, w, h, 3, &[2]);
        assert_eq!((l.rows, l.cols), (1, 2));
        assert!((l.fractions[0] - 1.0 / 3.0).abs() < 1e-6);
        assert_eq!(l.fractions[1], 0.0);
    }

    #[test]
    fn look_at_points_the_optical_axis_at_the_target() {
        let r = look_at([0.0, 0.0, 1.0], [5.0, 0.0, 1.0]);
        // Optical z (third column) along +x, x (first column) along -y, y along -z.
        assert!((r.r[0][2] - 1.0).abs() < 1e-12 && (r.r[1][0] + 1.0).abs() < 1e-12 && (r.r[2][1] + 1.0).abs() < 1e-12);
    }
}
