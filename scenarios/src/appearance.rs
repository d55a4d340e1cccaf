//! Where a run's appearance model comes from: a model file named by the scenario, or one
//! trained from generated images and cached, so `objslam run` needs nothing prepared.
//!
//! The cached model is trained on a park generated with a different seed from the
//! scenario's world (unseen trees, as a real robot meets them), rendered with the
//! scenario's camera. The cache key hashes everything that shapes the model, so changing
//! the camera or the training settings trains a new one.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use slam::classifier::{AppearanceModel, MODEL_FORMAT_VERSION, TrainingOptions};
use slam::gmm::VbOptions;

use crate::dataset::DatasetConfig;

/// The scenario's `[appearance]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AppearanceSource {
    /// A model file from `objslam train` (relative to the scenario file); when absent a
    /// model is trained from generated images and cached.
    pub model: Option<String>,
    /// World generator preset and seed of the training images.
    pub training_preset: String,
    pub training_world_seed: u64,
    /// Worlds the training images are spread over. 1: the preset's park of
    /// `training_world_seed`. More: that many parks drawn, from `training_world_seed`, from
    /// the generalisation benchmark's distribution (trunks, trees, posts and crowds of
    /// every size it holds), none of them a benchmark world; the paper's first lever
    /// against a model that knows only one park.
    pub training_worlds: usize,
    pub training_images: usize,
    pub training_seed: u64,
    pub max_patches_per_class: usize,
    pub max_components: usize,
    pub pca_dims: usize,
    /// Fit the distractors (posts, palms, walls, people) apart from the rest of the
    /// background (`slam::classifier::TrainingOptions::distractors`).
    pub distractors: bool,
    /// Learn the column context (`slam::classifier::TrainingOptions::context`).
    pub context: bool,
}

/// The run's model is smaller than `objslam train`'s default (d = 10 and 10 components
/// against 20 and 20): twice as fast, and the larger model's better held-out patch F1
/// did not give a better map (docs/results.md).
impl Default for AppearanceSource {
    fn default() -> Self {
        AppearanceSource {
            model: None,
            training_preset: "park".into(),
            training_world_seed: 1001,
            training_worlds: 1,
            training_images: 60,
            training_seed: 1,
            max_patches_per_class: 10_000,
            max_components: 10,
            pca_dims: 10,
            distractors: false,
            context: false,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum AppearanceError {
    #[error(transparent)]
    Model(#[from] slam::classifier::ModelError),
    #[error(transparent)]
    Train(#[from] crate::train::TrainError),
    #[error(transparent)]
    Dataset(#[from] crate::dataset::DatasetError),
    #[error(transparent)]
    World(#[from] worlds::WorldError),
    #[error("{}: {source}", file.display())]
    Io { file: PathBuf, source: std::io::Error },
}

/// The cache directory: `$OBJSLAM_CACHE`, else `runs/cache` under the working directory.
pub fn cache_dir() -> PathBuf {
    std::env::var_os("OBJSLAM_CACHE").map(PathBuf::from).unwrap_or_else(|| PathBuf::from("runs").join("cache"))
}

impl AppearanceSource {
    /// The training settings' ranges, checked when a scenario is read rather than when a
    /// model is first trained: (field, problem).
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        if !worlds::generate::PRESETS.contains(&self.training_preset.as_str()) {
            let known = worlds::generate::PRESETS.join(", ");
            return Err(("training_preset", format!("unknown preset {:?}; available: {known}", self.training_preset)));
        }
        for (field, value, max) in [
            ("training_images", self.training_images, 100_000),
            ("max_patches_per_class", self.max_patches_per_class, 10_000_000),
            ("max_components", self.max_components, 100),
            ("pca_dims", self.pca_dims, 1000),
            ("training_worlds", self.training_worlds, 1000),
        ] {
            if !(1..=max).contains(&value) {
                return Err((field, format!("must be 1 to {max}, got {value}")));
            }
        }
        if self.training_worlds > self.training_images {
            return Err((
                "training_worlds",
                format!(
                    "{} worlds for {} training images: each world needs an image at least",
                    self.training_worlds, self.training_images
                ),
            ));
        }
        // Every training world laid out now, not when the model is first trained.
        if self.model.is_none()
            && let Some(k) = self.training_worlds_drawn().iter().position(Option::is_none)
        {
            return Err((
                "training_worlds",
                format!("training world {k} of seed {} has no layout that fits its ground", self.training_world_seed),
            ));
        }
        // A model file is read as it is: a training setting beside it would be silently
        // unused (a study varying it would vary nothing).
        if self.model.is_some() {
            let d = AppearanceSource::default();
            let given = [
                ("training_preset", self.training_preset != d.training_preset),
                ("training_world_seed", self.training_world_seed != d.training_world_seed),
                ("training_worlds", self.training_worlds != d.training_worlds),
                ("training_images", self.training_images != d.training_images),
                ("training_seed", self.training_seed != d.training_seed),
                ("max_patches_per_class", self.max_patches_per_class != d.max_patches_per_class),
                ("max_components", self.max_components != d.max_components),
                ("pca_dims", self.pca_dims != d.pca_dims),
                ("distractors", self.distractors != d.distractors),
                ("context", self.context != d.context),
            ];
            if let Some((field, _)) = given.iter().find(|(_, changed)| *changed) {
                return Err((
                    field,
                    "only applies to a model trained by the run; with appearance.model the file is read as it is"
                        .into(),
                ));
            }
        }
        Ok(())
    }

    /// The training worlds as (layout seed, parameters), `None` for one that cannot be laid
    /// out; empty with one training world (the preset's park).
    fn training_worlds_drawn(&self) -> Vec<Option<(u64, worlds::generate::ParkParams)>> {
        if self.training_worlds <= 1 {
            return Vec::new();
        }
        (0..self.training_worlds)
            .map(|k| crate::montecarlo::generalisation::training_world(self.training_world_seed, k))
            .collect()
    }

    fn training_options(&self) -> TrainingOptions {
        TrainingOptions {
            pca_dims: self.pca_dims,
            max_patches_per_class: self.max_patches_per_class,
            seed: self.training_seed,
            distractors: self.distractors,
            context: self.context,
            vb: VbOptions { max_components: self.max_components, ..Default::default() },
            ..Default::default()
        }
    }

    fn dataset_config(&self, camera: &sim::camera::CameraConfig) -> DatasetConfig {
        DatasetConfig {
            images: self.training_images,
            seed: self.training_seed,
            camera: camera.clone(),
            ..Default::default()
        }
    }

    /// The cache file name for this source and camera.
    pub fn cache_key(&self, camera: &sim::camera::CameraConfig) -> String {
        /// The source as hashed: without the model file, and `distractors`, `context` and
        /// `training_worlds` only when not their defaults, so models cached before those
        /// settings existed keep their keys.
        #[derive(Serialize)]
        struct Key<'a> {
            model: Option<&'a str>,
            training_preset: &'a str,
            training_world_seed: u64,
            #[serde(skip_serializing_if = "is_one")]
            training_worlds: usize,
            /// The worlds themselves, so that a change to the distribution they are drawn
            /// from trains anew rather than reusing models of other worlds.
            #[serde(skip_serializing_if = "Vec::is_empty")]
            drawn_worlds: Vec<Option<(u64, worlds::generate::ParkParams)>>,
            training_images: usize,
            training_seed: u64,
            max_patches_per_class: usize,
            max_components: usize,
            pca_dims: usize,
            #[serde(skip_serializing_if = "std::ops::Not::not")]
            distractors: bool,
            #[serde(skip_serializing_if = "std::ops::Not::not")]
            context: bool,
        }
        // Destructured without `..`, so a field added to the source fails to compile here
        // until it is hashed too.
        let AppearanceSource {
            model: _,
            training_preset,
            training_world_seed,
            training_worlds,
            training_images,
            training_seed,
            max_patches_per_class,
            max_components,
            pca_dims,
            distractors,
            context,
        } = self;
        let key = Key {
            model: None,
            training_preset,
            training_world_seed: *training_world_seed,
            training_worlds: *training_worlds,
            drawn_worlds: self.training_worlds_drawn(),
            training_images: *training_images,
            training_seed: *training_seed,
            max_patches_per_class: *max_patches_per_class,
            max_components: *max_components,
            pca_dims: *pca_dims,
            distractors: *distractors,
            context: *context,
        };
        let (dataset, training) = (self.dataset_config(camera), self.training_options());
        // A noisy camera's images changed when a spread of 0 began to take its draw (the
        // exposure's, the pixel noise's seed): models trained on them before are not
        // reused. Noiseless cameras keep their keys.
        let text = if camera.noise_sigma > 0.0 || camera.exposure_sigma > 0.0 {
            serde_json::to_string(&(MODEL_FORMAT_VERSION, key, dataset, training, "camera noise streams 2"))
        } else {
            serde_json::to_string(&(MODEL_FORMAT_VERSION, key, dataset, training))
        }
        .expect("JSON");
        let digest = Sha256::digest(text.as_bytes());
        format!("appearance-{}.json", digest.iter().take(8).map(|b| format!("{b:02x}")).collect::<String>())
    }

    /// Loads the named model, or the cached one, training and caching it first if needed.
    /// `progress(stage, done, total)` reports training.
    pub fn resolve(
        &self,
        base_dir: &Path,
        camera: &sim::camera::CameraConfig,
        progress: impl Fn(&str, usize, usize),
    ) -> Result<AppearanceModel, AppearanceError> {
        self.resolve_in(&cache_dir(), base_dir, camera, progress)
    }

    /// [`resolve`](Self::resolve) with the cache in `dir`.
    ///
    /// Runs on several threads of one process (the tests, a study's runs) may ask for the
    /// same uncached model at once: training is serialised within the process and the
    /// cache looked at again once the lock is held, so the model is trained once and the
    /// later callers load it. Other processes write under their own temporary names and
    /// rename into place, so nobody reads a half-written model.
    pub fn resolve_in(
        &self,
        dir: &Path,
        base_dir: &Path,
        camera: &sim::camera::CameraConfig,
        progress: impl Fn(&str, usize, usize),
    ) -> Result<AppearanceModel, AppearanceError> {
        static TRAINING: std::sync::Mutex<()> = std::sync::Mutex::new(());
        if let Some(file) = &self.model {
            return Ok(AppearanceModel::load(&base_dir.join(file))?);
        }
        // Whenever the cache is used, not only when it trains: a cache whose models are
        // all trained would otherwise keep a killed training's scratch for good.
        remove_stale_scratch(dir);
        let key = self.cache_key(camera);
        let path = dir.join(&key);
        if path.exists() {
            return Ok(AppearanceModel::load(&path)?);
        }
        // A panic while training elsewhere leaves nothing half-done in the cache, so a
        // poisoned lock is still good to take.
        let _training = TRAINING.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        if path.exists() {
            return Ok(AppearanceModel::load(&path)?);
        }
        std::fs::create_dir_all(dir).map_err(|e| AppearanceError::Io { file: dir.to_path_buf(), source: e })?;
        let scratch = dir.join(format!("training-{}-{}", std::process::id(), self.training_world_seed));
        // Held while this training lives: the sign to other processes' cleaning that it is.
        let _scratch_held = crate::partial_files::lock_output(&scratch)
            .map_err(|e| AppearanceError::Io { file: e.file, source: e.source })?;
        let datasets = self.write_training_datasets(camera, &scratch, &progress);
        let trained = datasets
            .and_then(|dirs| Ok(crate::train::train_from_datasets(&dirs, &self.training_options(), &progress)?));
        let _ = std::fs::remove_dir_all(&scratch);
        let model = trained?;
        // Write then rename, so parallel runs never read a half-written model.
        let tmp = dir.join(format!(".{}.{key}", std::process::id()));
        model.save(&tmp)?;
        std::fs::rename(&tmp, &path).map_err(|e| AppearanceError::Io { file: path.clone(), source: e })?;
        Ok(model)
    }

    /// Renders the training images into `scratch` (held by the caller): one dataset, or
    /// with several training worlds one dataset per world in `scratch/world-<k>`, the
    /// images shared out as evenly as they go. Returns the datasets' directories.
    fn write_training_datasets(
        &self,
        camera: &sim::camera::CameraConfig,
        scratch: &Path,
        progress: &impl Fn(&str, usize, usize),
    ) -> Result<Vec<PathBuf>, AppearanceError> {
        let config = self.dataset_config(camera);
        if self.training_worlds <= 1 {
            let world = worlds::generate::preset(&self.training_preset, None, self.training_world_seed)?;
            crate::dataset::check_config(&world, &config)?;
            // Straight into the scratch this training holds, not staged within it.
            crate::dataset::write_dataset(
                &world,
                &format!("preset {}, seed {}", self.training_preset, self.training_world_seed),
                &config,
                scratch,
                |done, total| progress("rendering", done, total),
            )?;
            return Ok(vec![scratch.to_path_buf()]);
        }
        let n = self.training_worlds;
        let mut dirs = Vec::with_capacity(n);
        let mut done_before = 0;
        for (k, drawn) in self.training_worlds_drawn().into_iter().enumerate() {
            let (seed, params) = drawn.ok_or_else(|| {
                AppearanceError::Dataset(crate::dataset::DatasetError::Config(format!(
                    "appearance.training_worlds: training world {k} of seed {} has no layout that fits its ground",
                    self.training_world_seed
                )))
            })?;
            let world = worlds::generate::park(&params, seed)?;
            let images = self.training_images / n + usize::from(k < self.training_images % n);
            let config = DatasetConfig {
                images,
                seed: sim::derive_seed(self.training_seed, &format!("training-world-{k}")),
                ..config.clone()
            };
            crate::dataset::check_config(&world, &config)?;
            let dir = scratch.join(format!("world-{k}"));
            crate::dataset::write_dataset(
                &world,
                &format!("training world {k} of seed {}", self.training_world_seed),
                &config,
                &dir,
                |done, _| progress("rendering", done_before + done, self.training_images),
            )?;
            done_before += images;
            dirs.push(dir);
        }
        Ok(dirs)
    }
}

fn is_one(n: &usize) -> bool {
    *n == 1
}

/// Removes what trainings killed midway left in the cache `dir`: their scratch datasets
/// (`training-<pid>-<seed>/`, about 15 MB each), which a live training holds locked (the
/// lock ends with its process, however it ends), and half-written models (`.<pid>.<key>`),
/// where process `pid` no longer runs here and the file has not changed for an hour (a
/// cache shared between machines may hold another machine's live training, whose pid
/// means nothing here; where that cannot be known, no `/proc`, they are kept).
pub(crate) fn remove_stale_scratch(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let idle = entry.metadata().and_then(|m| m.modified()).ok().and_then(|t| t.elapsed().ok());
        let path = entry.path();
        if name.starts_with("training-") {
            // A scratch made a moment ago may not be locked yet.
            if idle.is_some_and(|d| d >= SCRATCH_UNLOCKED_GRACE)
                && let Ok(_dead) = crate::partial_files::lock_output(&path)
            {
                let _ = std::fs::remove_dir_all(&path);
            }
            continue;
        }
        let pid =
            name.strip_prefix('.').and_then(|rest| rest.split('.').next()).and_then(|pid| pid.parse::<u32>().ok());
        let Some(pid) = pid else { continue };
        if pid == std::process::id() || !process_ended(pid) || idle.is_none_or(|d| d < SCRATCH_IDLE) {
            continue;
        }
        let _ = std::fs::remove_file(&path);
    }
}

/// How old an unlocked scratch dataset must be to be removed: a training makes its
/// directory and then locks it.
const SCRATCH_UNLOCKED_GRACE: std::time::Duration = std::time::Duration::from_secs(60);

/// How long a dead training's files stay untouched before they are removed.
const SCRATCH_IDLE: std::time::Duration = std::time::Duration::from_secs(3600);

/// Whether process `pid` has certainly ended.
fn process_ended(pid: u32) -> bool {
    let proc = Path::new("/proc");
    proc.join("self").exists() && !proc.join(pid.to_string()).exists()
}

#[cfg(test)]
mod scratch_tests {
    use super::*;

    #[test]
    fn the_cache_key_holds_every_training_setting_and_distractors_and_context_only_when_set() {
        let camera = sim::camera::CameraConfig::default();
        let base = AppearanceSource::default();
        // The key of the default source as it was before `distractors` existed.
        assert_eq!(base.cache_key(&camera), "appearance-bdf80a1814484af2.json");
        let split = AppearanceSource { distractors: true, ..base.clone() };
        let named = AppearanceSource { model: Some("m.json".into()), ..base.clone() };
        let other_seed = AppearanceSource { training_seed: 2, ..base.clone() };
        assert_ne!(split.cache_key(&camera), base.cache_key(&camera));
        let context = AppearanceSource { context: true, ..base.clone() };
        assert_ne!(context.cache_key(&camera), base.cache_key(&camera));
        assert_ne!(context.cache_key(&camera), split.cache_key(&camera));
        assert_ne!(other_seed.cache_key(&camera), base.cache_key(&camera));
        assert_eq!(named.cache_key(&camera), base.cache_key(&camera), "the model file is not hashed");
    }

    #[test]
    fn what_a_killed_training_left_is_removed_and_nothing_else() {
        let dir = std::env::temp_dir().join(format!("objslam-cache-scratch-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        // A killed training's scratch: nobody holds it. Pid 999999999 is above Linux's
        // largest: no such process runs.
        let dead_scratch = dir.join("training-999999999-1");
        std::fs::create_dir_all(dead_scratch.join("images")).unwrap();
        let dead_model = dir.join(".999999999.appearance-0123.json");
        std::fs::write(&dead_model, "{").unwrap();
        // A live training's, however old, is held.
        let live = dir.join("training-999999997-1");
        let held = crate::partial_files::lock_output(&live).unwrap();
        let model = dir.join("appearance-0123.json");
        std::fs::write(&model, "{}").unwrap();
        // One made a moment ago, not locked yet.
        let new = dir.join("training-999999998-1");
        std::fs::create_dir_all(&new).unwrap();
        let two_hours_ago = std::time::SystemTime::now() - std::time::Duration::from_secs(7200);
        for old in [&dead_scratch, &dead_model, &live] {
            std::fs::File::open(old).unwrap().set_modified(two_hours_ago).unwrap();
        }
        remove_stale_scratch(&dir);
        assert!(!dead_scratch.exists(), "a dead training's scratch is left");
        if Path::new("/proc/self").exists() {
            assert!(!dead_model.exists(), "a dead training's model is left");
        }
        assert!(live.exists() && model.exists() && new.exists(), "a live training's scratch or a model was removed");
        drop(held);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
