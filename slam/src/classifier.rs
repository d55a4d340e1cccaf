//! The patch classifier (paper section 3.3) and the appearance model file that carries it.
//!
//! Two VB-GMMs are learnt on patch features: one for object patches, one for everything
//! else. Each is used through the Gaussian approximation of its Student-t predictive
//! density; a patch z is an object patch when
//! R = w_obj p(z | obj) / (w_obj p(z | obj) + w_bg p(z | bg)) exceeds a threshold (0.5),
//! with w the classes' proportions in the training data.
//!
//! A third mixture, fitted to the background patches that are leaves (canopies and palm
//! crowns), tells foliage from the rest of the background: segmentation uses it to see
//! where a trunk ends in its canopy.
//!
//! The background may be split in two: the distractors (posts, palms, walls, people: the
//! things that look like the object) and the rest, each with its own mixture, so that
//! p(z | bg) = w_dis p(z | dis) + (1 - w_dis) p(z | rest). Fitted as one, the background's
//! few components go to sky, grass and leaves, which are most of its patches, and a
//! post's patches are explained better by the trunk model than by the background's.
//!
//! A model may also carry a learnt column context ([`ColumnContext`]) that decides each
//! patch again from its own log-odds and those of the patches above and below it.

use std::path::Path;

use nalgebra::DMatrix;
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::column_context::{self, ColumnContext, LabelledGrid};
use crate::features::{
    FeatureConfig, FeatureError, FeatureExtractor, IN_RECT, ImageRef, PatchFeatures, PatchRect, Pca, raw_patches,
};
use crate::gmm::{self, GmmError, GmmEvaluator, StudentTMixture, VbGmm, VbOptions};

/// Version of the appearance model file layout; files with another version are refused.
pub const MODEL_FORMAT_VERSION: u32 = 1;

#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ModelError {
    #[error("{file}: {source}")]
    Io { file: String, source: std::io::Error },
    #[error("{file}: not an appearance model: {message}")]
    Parse { file: String, message: String },
    #[error("{file}: model format_version {found}, this objslam reads version {expected}; retrain the model")]
    Version { file: String, found: u32, expected: u32 },
    #[error("{file}: inconsistent model: {message}")]
    Inconsistent { file: String, message: String },
    #[error(transparent)]
    Feature(#[from] FeatureError),
    #[error(transparent)]
    Gmm(#[from] GmmError),
    #[error("training: {0}")]
    Training(String),
    #[error(transparent)]
    Classify(#[from] ClassifyError),
}

/// Patch features that do not fit a classifier: another feature space's, or rows that are
/// not one per patch of their rectangle.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ClassifyError {
    #[error("features of {found} dimensions for a classifier of {expected}")]
    Dimension { expected: usize, found: usize },
    #[error("{rows} feature rows for a rectangle of {patches} patches")]
    Rows { rows: usize, patches: usize },
}

/// Patch precision, recall and F1 against ground-truth labels.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PatchScores {
    pub true_positives: u64,
    pub false_positives: u64,
    pub false_negatives: u64,
    pub true_negatives: u64,
}

impl PatchScores {
    pub fn add(&mut self, predicted: bool, truth: bool) {
        match (predicted, truth) {
            (true, true) => self.true_positives += 1,
            (true, false) => self.false_positives += 1,
            (false, true) => self.false_negatives += 1,
            (false, false) => self.true_negatives += 1,
        }
    }
    /// TP / (TP + FP); 1 when nothing was predicted positive.
    pub fn precision(&self) -> f64 {
        self.defined_precision().unwrap_or(1.0)
    }
    /// TP / (TP + FN); 1 when there was nothing to find.
    pub fn recall(&self) -> f64 {
        self.defined_recall().unwrap_or(1.0)
    }
    /// TP / (TP + FP); `None` when nothing was predicted positive: a run that classified
    /// nothing has no precision, not a perfect one.
    pub fn defined_precision(&self) -> Option<f64> {
        let p = self.true_positives + self.false_positives;
        (p > 0).then(|| self.true_positives as f64 / p as f64)
    }
    /// TP / (TP + FN); `None` when there was nothing to find.
    pub fn defined_recall(&self) -> Option<f64> {
        let p = self.true_positives + self.false_negatives;
        (p > 0).then(|| self.true_positives as f64 / p as f64)
    }
    pub fn f1(&self) -> f64 {
        let (p, r) = (self.precision(), self.recall());
        if p + r == 0.0 { 0.0 } else { 2.0 * p * r / (p + r) }
    }
    /// The harmonic mean of precision and recall; `None` when either is undefined.
    pub fn defined_f1(&self) -> Option<f64> {
        let (p, r) = (self.defined_precision()?, self.defined_recall()?);
        Some(if p + r == 0.0 { 0.0 } else { 2.0 * p * r / (p + r) })
    }
}

/// A score for people to read: three decimals, or "undefined" (see
/// [`PatchScores::defined_precision`]).
pub fn score_text(score: Option<f64>) -> String {
    score.map_or_else(|| "undefined".to_string(), |s| format!("{s:.3}"))
}

/// How a model was trained, recorded in the file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainingSummary {
    pub images: usize,
    pub object_patches: usize,
    pub background_patches: usize,
    /// Patches used to fit each mixture (a deterministic subsample).
    pub fitted_object_patches: usize,
    pub fitted_background_patches: usize,
    pub pca_explained_variance: f64,
    pub seed: u64,
    /// Held-out scores, when the trainer had held-out images.
    pub heldout: Option<PatchScores>,
    /// The graphics adapter that rendered the training images, where known. Renderers
    /// differ in their last bits (texture filtering, rasterisation), and a model trained on
    /// one classifies borderline patches differently from one trained on another.
    #[serde(default)]
    pub renderer: Option<String>,
    /// Background patches that were foliage (0 in models trained without foliage labels).
    #[serde(default)]
    pub foliage_patches: usize,
    /// Held-out scores of the foliage decision (P(foliage | z) > 0.5), when the model has a
    /// foliage model and the trainer had held-out images.
    #[serde(default)]
    pub foliage_heldout: Option<PatchScores>,
    /// Background patches that were distractors, when the model fits them apart (0
    /// otherwise).
    #[serde(default)]
    pub distractor_patches: usize,
}

/// A part of the background (foliage, distractors): its mixture and its share of the
/// background patches.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BackgroundPart {
    pub gmm: VbGmm,
    /// The part's share of the background patches (w_fol|bg, w_dis|bg).
    pub weight: f64,
}

/// The output of the offline phase: features, both class models and their proportions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AppearanceModel {
    pub format_version: u32,
    /// Name of the object class the model finds ("tree").
    pub object_class: String,
    pub extractor: FeatureExtractor,
    pub object: VbGmm,
    pub background: VbGmm,
    /// w_obj: the object class's share of the training patches.
    pub object_weight: f64,
    /// R above this is an object patch.
    pub threshold: f64,
    pub training: TrainingSummary,
    /// The foliage model; absent in models trained without foliage labels.
    #[serde(default)]
    pub foliage: Option<BackgroundPart>,
    /// The distractors' model; with it `background` is fitted to the rest of the
    /// background only. Absent in models trained without distractor labels.
    #[serde(default)]
    pub distractors: Option<BackgroundPart>,
    /// The column context; absent in models trained without it (and then not written, so
    /// such models keep their bytes and digests).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub context: Option<ColumnContext>,
}

impl AppearanceModel {
    /// Reads a model file; a missing, corrupt or other-version file is a clear error.
    pub fn load(path: &Path) -> Result<Self, ModelError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| ModelError::Io { file: file.clone(), source: e })?;
        Self::from_json(&text, &file)
    }

    /// Parses a model from JSON text; `file` names it in errors.
    pub fn from_json(text: &str, file: &str) -> Result<Self, ModelError> {
        #[derive(Deserialize)]
        #[serde(expecting = "an appearance model (a JSON object with a format_version)")]
        struct VersionOnly {
            format_version: Option<u32>,
        }
        let v: VersionOnly =
            serde_json::from_str(text).map_err(|e| ModelError::Parse { file: file.into(), message: e.to_string() })?;
        match v.format_version {
            Some(MODEL_FORMAT_VERSION) => {}
            Some(found) => {
                return Err(ModelError::Version { file: file.into(), found, expected: MODEL_FORMAT_VERSION });
            }
            None => {
                return Err(ModelError::Parse { file: file.into(), message: "missing field `format_version`".into() });
            }
        }
        let model: AppearanceModel =
            crate::settings::from_json(text).map_err(|message| ModelError::Parse { file: file.into(), message })?;
        model.check().map_err(|message| ModelError::Inconsistent { file: file.into(), message })?;
        Ok(model)
    }

    /// Whether the model's parts fit together (what [`AppearanceModel::from_json`] checks
    /// of a file, for a model made in code); the message names the part at fault.
    pub fn check(&self) -> Result<(), String> {
        self.check_parts()?;
        PatchClassifier::new(self).map_err(|e| e.to_string())?;
        Ok(())
    }

    /// [`AppearanceModel::check`] short of building the classifier, for a caller that builds
    /// it next anyway.
    pub(crate) fn check_parts(&self) -> Result<(), String> {
        self.extractor.config.validate().map_err(|e| format!("extractor.config.{e}"))?;
        self.extractor.pca.check().map_err(|(field, problem)| format!("extractor.pca.{field}: {problem}"))?;
        for (name, class) in [("object", &self.object), ("background", &self.background)]
            .into_iter()
            .chain(self.foliage.as_ref().map(|f| ("foliage.gmm", &f.gmm)))
            .chain(self.distractors.as_ref().map(|f| ("distractors.gmm", &f.gmm)))
        {
            class.check().map_err(|e| format!("{name}: {e}"))?;
        }
        let d = self.extractor.dims();
        if self.extractor.pca.input_dims() != self.extractor.config.raw_dims() {
            return Err("the PCA does not match the patch size and filter bank".into());
        }
        if self.object.dims() != d || self.background.dims() != d {
            return Err(format!(
                "class models are {}- and {}-dimensional, features are {d}-dimensional",
                self.object.dims(),
                self.background.dims()
            ));
        }
        if !(self.object_weight > 0.0 && self.object_weight < 1.0) || !(0.0..=1.0).contains(&self.threshold) {
            return Err("object_weight must lie in (0, 1) and threshold in [0, 1]".into());
        }
        for (name, part, max) in [("foliage", &self.foliage, 1.0), ("distractors", &self.distractors, 0.999)] {
            let Some(f) = part else { continue };
            if f.gmm.dims() != d {
                return Err(format!("{name}.gmm is {}-dimensional, features are {d}-dimensional", f.gmm.dims()));
            }
            if !(f.weight > 0.0 && f.weight <= max) {
                return Err(format!("{name}.weight must lie in (0, {max}], got {}", f.weight));
            }
        }
        if let Some(c) = &self.context {
            c.check().map_err(|(field, problem)| format!("context.{field}: {problem}"))?;
        }
        Ok(())
    }

    /// The model as JSON, as [`AppearanceModel::save`] writes it.
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).expect("a model serialises")
    }

    /// Writes the model as JSON (into a file of the caller's staging: a command that
    /// replaces a user's file writes it beside and renames it).
    pub fn save(&self, path: &Path) -> Result<(), ModelError> {
        std::fs::write(path, self.to_json()).map_err(|e| ModelError::Io { file: path.display().to_string(), source: e })
    }
}

/// The classifier ready to run: both predictive densities prepared for evaluation.
#[derive(Debug, Clone)]
pub struct PatchClassifier {
    object: GmmEvaluator,
    background: GmmEvaluator,
    /// The distractors' density and ln w_dis|bg; `background` is then the rest's, weighted
    /// by `ln_w_rest`.
    distractors: Option<(GmmEvaluator, f64)>,
    ln_w_rest: f64,
    ln_w_obj: f64,
    ln_w_bg: f64,
    pub threshold: f64,
    /// The foliage density and ln w_fol|bg, when the model has them.
    foliage: Option<(GmmEvaluator, f64)>,
    context: Option<ColumnContext>,
}

impl PatchClassifier {
    pub fn new(model: &AppearanceModel) -> Result<Self, GmmError> {
        // A model built in code rather than loaded (which checks it) is checked here: one
        // whose parts disagree would panic at the first patch, or give NaN.
        model.check_parts().map_err(GmmError::BadModel)?;
        let object = StudentTMixture::new(&model.object)?.gaussian_approximation()?.evaluator()?;
        let background = StudentTMixture::new(&model.background)?.gaussian_approximation()?.evaluator()?;
        let distractors = match &model.distractors {
            Some(f) => Some((StudentTMixture::new(&f.gmm)?.gaussian_approximation()?.evaluator()?, f.weight.ln())),
            None => None,
        };
        Ok(PatchClassifier {
            object,
            background,
            ln_w_rest: model.distractors.as_ref().map_or(0.0, |f| (1.0 - f.weight).ln()),
            distractors,
            ln_w_obj: model.object_weight.ln(),
            ln_w_bg: (1.0 - model.object_weight).ln(),
            threshold: model.threshold,
            foliage: match &model.foliage {
                Some(f) => Some((StudentTMixture::new(&f.gmm)?.gaussian_approximation()?.evaluator()?, f.weight.ln())),
                None => None,
            },
            context: model.context.clone(),
        })
    }

    /// Whether the model can tell foliage from the rest of the background.
    pub fn has_foliage(&self) -> bool {
        self.foliage.is_some()
    }

    /// P(foliage | z), `None` without a foliage model. Foliage is part of the background,
    /// so P(fol | z) = P(bg | z) P(fol | bg, z), with P(fol | bg, z) = w_fol|bg p(z | fol) /
    /// p(z | bg) capped at 1 (the two densities are fitted apart, so their ratio can pass it).
    /// A row of another dimension is [`ClassifyError::Dimension`].
    pub fn foliage_probability(&self, z: &[f64]) -> Result<Option<f64>, ClassifyError> {
        self.check_dims(z.len())?;
        Ok(self.foliage_probability_prechecked(z))
    }

    /// [`PatchClassifier::foliage_probability`] of a row the caller has checked is the
    /// classifier's dimension.
    pub(crate) fn foliage_probability_prechecked(&self, z: &[f64]) -> Option<f64> {
        let (foliage, ln_w_fol) = self.foliage.as_ref()?;
        let a = self.ln_w_obj + self.object.log_density_prechecked(z);
        let ln_p_bg = self.background_log_density(z);
        let b = self.ln_w_bg + ln_p_bg;
        let p_bg = 1.0 / (1.0 + (a - b).exp());
        let within = (ln_w_fol + foliage.log_density_prechecked(z) - ln_p_bg).min(0.0).exp();
        Some(p_bg * within)
    }

    /// The dimension of the feature rows the classifier takes (the model's parts share it).
    pub fn dims(&self) -> usize {
        self.object.dims()
    }

    fn check_dims(&self, found: usize) -> Result<(), ClassifyError> {
        if found == self.dims() { Ok(()) } else { Err(ClassifyError::Dimension { expected: self.dims(), found }) }
    }

    /// ln p(z | bg): the background's density, with its distractors' part when it has one.
    fn background_log_density(&self, z: &[f64]) -> f64 {
        self.mix_background(
            self.background.log_density_prechecked(z),
            self.distractors.as_ref().map(|(d, _)| d.log_density_prechecked(z)),
        )
    }

    /// ln p(z | bg) from the rest's ln density and the distractors' (`None` where the model
    /// has none).
    fn mix_background(&self, ln_p_rest: f64, ln_p_dis: Option<f64>) -> f64 {
        match (&self.distractors, ln_p_dis) {
            (Some((_, ln_w)), Some(dis)) => gmm::log_sum_exp(&[self.ln_w_rest + ln_p_rest, ln_w + dis]),
            _ => ln_p_rest,
        }
    }

    /// R for one feature row, from the mixtures alone (without the column context, which
    /// needs the patch's column). A row of another dimension is
    /// [`ClassifyError::Dimension`].
    pub fn posterior(&self, z: &[f64]) -> Result<f64, ClassifyError> {
        self.check_dims(z.len())?;
        let a = self.ln_w_obj + self.object.log_density_prechecked(z);
        let b = self.ln_w_bg + self.background_log_density(z);
        Ok(1.0 / (1.0 + (b - a).exp()))
    }

    /// R for every patch of `features`: with a column context, the context's probability
    /// over the rectangle's columns; without, the values [`PatchClassifier::posterior`]
    /// gives. Features of another dimension, or not one row per patch of their
    /// rectangle, are a [`ClassifyError`].
    pub fn posteriors(&self, features: &PatchFeatures) -> Result<Vec<f64>, ClassifyError> {
        self.check_dims(features.z.ncols())?;
        let (rows, patches) = (features.z.nrows(), features.rect.len());
        if rows != patches {
            return Err(ClassifyError::Rows { rows, patches });
        }
        let minus_log_odds = self.minus_log_odds(features);
        Ok(match &self.context {
            None => minus_log_odds.into_iter().map(|m| 1.0 / (1.0 + m.exp())).collect(),
            Some(context) => {
                let log_odds: Vec<f64> = minus_log_odds.into_iter().map(|m| -m).collect();
                context.apply_prechecked(&log_odds, features.rect.cols() as usize, features.rect.rows() as usize)
            }
        })
    }

    /// The mixtures' ln(w_bg p(z | bg)) - ln(w_obj p(z | obj)) of every row, four rows at a
    /// time (see [`GmmEvaluator::log_terms_lanes`]).
    fn minus_log_odds(&self, features: &PatchFeatures) -> Vec<f64> {
        const LANES: usize = 4;
        let (n, d) = features.z.shape();
        let mut x = vec![[0.0f64; LANES]; d];
        let mut object = vec![[0.0f64; LANES]; self.object.component_count()];
        let mut background = vec![[0.0f64; LANES]; self.background.component_count()];
        let mut distractors = vec![[0.0f64; LANES]; self.distractors.as_ref().map_or(0, |(d, _)| d.component_count())];
        let mut lane_terms = Vec::new();
        let mut density = |terms: &[[f64; LANES]], l: usize| {
            lane_terms.clear();
            lane_terms.extend(terms.iter().map(|t| t[l]));
            gmm::log_sum_exp(&lane_terms)
        };
        let mut out = Vec::with_capacity(n);
        for first in (0..n).step_by(LANES) {
            // The last group repeats its last row in the lanes past the end.
            for (j, xj) in x.iter_mut().enumerate() {
                for (l, v) in xj.iter_mut().enumerate() {
                    *v = features.z[((first + l).min(n - 1), j)];
                }
            }
            self.object.log_terms_lanes_prechecked(&x, &mut object);
            self.background.log_terms_lanes_prechecked(&x, &mut background);
            if let Some((d, _)) = &self.distractors {
                d.log_terms_lanes_prechecked(&x, &mut distractors);
            }
            for l in 0..LANES.min(n - first) {
                let a = self.ln_w_obj + density(&object, l);
                let rest = density(&background, l);
                let b = self.ln_w_bg
                    + self.mix_background(rest, self.distractors.as_ref().map(|_| density(&distractors, l)));
                out.push(b - a);
            }
        }
        out
    }

    /// Object / background decision for every row (checked as
    /// [`PatchClassifier::posteriors`] checks).
    pub fn classify(&self, features: &PatchFeatures) -> Result<Vec<bool>, ClassifyError> {
        Ok(self.posteriors(features)?.into_iter().map(|r| r > self.threshold).collect())
    }
}

/// One training image: pixels and the fraction of each patch (row-major over the grid)
/// that belongs to the object class, and that is foliage.
pub struct LabelledImage {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
    /// Foliage fraction of each patch, like `fractions`; empty when the labels do not say.
    pub foliage: Vec<f32>,
    /// Distractor fraction of each patch (posts, palms, walls, people), like `fractions`;
    /// empty when the labels do not say.
    pub distractors: Vec<f32>,
    pub fractions: Vec<f32>,
}

/// Training settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainingOptions {
    pub features: FeatureConfig,
    /// PCA dimension d.
    pub pca_dims: usize,
    /// Raw patches sampled (evenly over the images) to fit the PCA.
    pub pca_samples: usize,
    /// Patches per class given to VBEM (a deterministic random subsample).
    pub max_patches_per_class: usize,
    /// A patch is an object patch when at least this fraction of it is object.
    pub label_fraction: f64,
    pub vb: VbOptions,
    pub threshold: f64,
    pub seed: u64,
    /// Name recorded in the model for the object class.
    pub object_class: String,
    /// Also fit the foliage model, from the images that carry foliage labels.
    pub foliage: bool,
    /// Fit the distractors apart from the rest of the background, from the images that
    /// carry distractor labels (see the module's documentation). Off by default: it
    /// halves the posts' patches called object on held-out worlds, but the trunks' patches
    /// lose more of their posterior and runs map fewer trees (docs/results.md). Written
    /// only when set, so settings from before it existed keep their digests.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub distractors: bool,
    /// Learn a column context ([`ColumnContext`]): every 5th training image is then kept
    /// from the PCA and the mixtures, and the context is fitted on those images instead.
    /// Written only when set, like `distractors`.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub context: bool,
}

impl Default for TrainingOptions {
    fn default() -> Self {
        TrainingOptions {
            features: FeatureConfig::default(),
            pca_dims: 20,
            pca_samples: 20_000,
            max_patches_per_class: 20_000,
            label_fraction: 0.5,
            vb: VbOptions { max_components: 20, ..VbOptions::default() },
            threshold: 0.5,
            seed: 1,
            object_class: "tree".into(),
            foliage: true,
            distractors: false,
            context: false,
        }
    }
}

/// Trains an appearance model. `images` is called with an index and returns that image
/// (so they need not all be in memory); `progress` gets (stage, done, total).
pub fn train(
    count: usize,
    images: impl Fn(usize) -> Result<LabelledImage, ModelError>,
    options: &TrainingOptions,
    progress: impl Fn(&str, usize, usize),
) -> Result<AppearanceModel, ModelError> {
    if count == 0 {
        return Err(ModelError::Training("no training images".into()));
    }
    let cfg = &options.features;
    cfg.validate().map_err(|e| ModelError::Training(format!("features.{e}")))?;
    let l = cfg.patch_size;
    // The images the mixtures are fitted to, and those the column context is.
    let (mixture_ids, context_ids): (Vec<usize>, Vec<usize>) =
        (0..count).partition(|i| !options.context || i % CONTEXT_EVERY != CONTEXT_EVERY - 1);
    if options.context && context_ids.is_empty() {
        return Err(ModelError::Training(format!(
            "the column context is fitted on every {CONTEXT_EVERY}th training image: at least {CONTEXT_EVERY} images needed, got {count}"
        )));
    }
    let n_mix = mixture_ids.len();
    // Pass 1: sample raw patches for the PCA.
    let per_image = options.pca_samples.div_ceil(n_mix).max(1);
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let mut sample_rows: Vec<f64> = Vec::new();
    let mut sampled = 0usize;
    for (k, &i) in mixture_ids.iter().enumerate() {
        progress("pca", k, n_mix);
        let img = images(i)?;
        let image = ImageRef::new(img.width, img.height, &img.rgb)?;
        let rect = PatchRect::whole(&image, l);
        let raw = raw_patches(&image, cfg, &rect)?;
        let mut idx: Vec<usize> = (0..raw.nrows()).collect();
        idx.shuffle(&mut rng);
        for &r in idx.iter().take(per_image) {
            sample_rows.extend(raw.row(r).iter());
            sampled += 1;
        }
    }
    // Equalise the channels' variances (see `FeatureConfig::channel_gain`).
    let stride = 3 + cfg.bank.len();
    let mut gains = Vec::with_capacity(stride);
    for ch in 0..stride {
        let vals = sample_rows.iter().skip(ch).step_by(stride);
        let (n, sum, sq) = vals.fold((0.0f64, 0.0f64, 0.0f64), |(n, s, q), &v| (n + 1.0, s + v, q + v * v));
        let var = (sq / n - (sum / n).powi(2)).max(0.0);
        gains.push(if var > 1e-12 { (1.0 / var.sqrt()) as f32 } else { 1.0 });
    }
    for (i, v) in sample_rows.iter_mut().enumerate() {
        *v *= gains[i % stride] as f64;
    }
    let mut cfg = cfg.clone();
    cfg.channel_gain = gains;
    let pca = Pca::fit(&DMatrix::from_row_slice(sampled, cfg.raw_dims(), &sample_rows), options.pca_dims)?;
    drop(sample_rows);
    let extractor = FeatureExtractor::new(cfg, pca)?;
    // Pass 2: features of every patch, split by label.
    let (mut obj, mut fol): (Vec<f64>, Vec<f64>) = (Vec::new(), Vec::new());
    // The background's patches: the distractors' (with distractor labels) and the rest.
    let (mut dis, mut rest): (Vec<f64>, Vec<f64>) = (Vec::new(), Vec::new());
    let d = extractor.dims();
    for (k, &i) in mixture_ids.iter().enumerate() {
        progress("features", k, n_mix);
        let img = images(i)?;
        let (f, cols) = labelled_features(&extractor, &img, i)?;
        let foliage_labels = options.foliage && !img.foliage.is_empty();
        if foliage_labels && img.foliage.len() != img.fractions.len() {
            return Err(ModelError::Training(format!(
                "image {i}: {} foliage labels for {} patches",
                img.foliage.len(),
                img.fractions.len()
            )));
        }
        let distractor_labels = options.distractors && !img.distractors.is_empty();
        if distractor_labels && img.distractors.len() != img.fractions.len() {
            return Err(ModelError::Training(format!(
                "image {i}: {} distractor labels for {} patches",
                img.distractors.len(),
                img.fractions.len()
            )));
        }
        for k in 0..f.z.nrows() {
            let (c, r) = f.rect.patch(k).expect(IN_RECT);
            let cell = (r * cols + c) as usize;
            if img.fractions[cell] as f64 >= options.label_fraction {
                obj.extend(f.z.row(k).iter());
            } else {
                if distractor_labels && img.distractors[cell] as f64 >= options.label_fraction {
                    dis.extend(f.z.row(k).iter());
                } else {
                    rest.extend(f.z.row(k).iter());
                }
                if foliage_labels && img.foliage[cell] as f64 >= options.label_fraction {
                    fol.extend(f.z.row(k).iter());
                }
            }
        }
    }
    let (n_obj, n_bg) = (obj.len() / d, (dis.len() + rest.len()) / d);
    if n_obj < d + 1 || n_bg < d + 1 {
        return Err(ModelError::Training(format!(
            "need at least {} patches of each class, found {n_obj} object and {n_bg} background",
            d + 1
        )));
    }
    let subsample = |rows: &[f64], n: usize, rng: &mut ChaCha8Rng| -> DMatrix<f64> {
        let mut idx: Vec<usize> = (0..n).collect();
        idx.shuffle(rng);
        idx.truncate(options.max_patches_per_class.max(1));
        idx.sort_unstable();
        let flat: Vec<f64> = idx.iter().flat_map(|&i| rows[i * d..(i + 1) * d].iter().copied()).collect();
        DMatrix::from_row_slice(idx.len(), d, &flat)
    };
    let (n_dis, n_rest) = (dis.len() / d, rest.len() / d);
    let split = n_dis > d && n_rest > d;
    let obj_data = subsample(&obj, n_obj, &mut rng);
    if !split {
        // Too few of either to fit apart: one background, as without distractor labels.
        rest.append(&mut dis);
    }
    let bg_data = subsample(&rest, rest.len() / d, &mut rng);
    drop(rest);
    progress("object model", 0, 3);
    let object = gmm::fit(&obj_data, None, &options.vb)?;
    progress("background model", 1, 3);
    let background = gmm::fit(&bg_data, None, &options.vb)?;
    // Drawn after the other two, so they are what they were before foliage was modelled.
    let n_fol = fol.len() / d;
    let foliage = if n_fol > d {
        progress("foliage model", 2, 3);
        let fol_data = subsample(&fol, n_fol, &mut rng);
        Some(BackgroundPart { gmm: gmm::fit(&fol_data, None, &options.vb)?, weight: n_fol as f64 / n_bg as f64 })
    } else {
        None
    };
    let distractors = if split {
        progress("distractor model", 2, 3);
        let dis_data = subsample(&dis, n_dis, &mut rng);
        Some(BackgroundPart { gmm: gmm::fit(&dis_data, None, &options.vb)?, weight: n_dis as f64 / n_bg as f64 })
    } else {
        None
    };
    let mut model = AppearanceModel {
        format_version: MODEL_FORMAT_VERSION,
        object_class: options.object_class.clone(),
        object_weight: n_obj as f64 / (n_obj + n_bg) as f64,
        threshold: options.threshold,
        training: TrainingSummary {
            images: n_mix,
            object_patches: n_obj,
            background_patches: n_bg,
            fitted_object_patches: obj_data.nrows(),
            fitted_background_patches: bg_data.nrows(),
            pca_explained_variance: extractor.pca.explained_variance,
            seed: options.seed,
            heldout: None,
            renderer: None,
            foliage_patches: n_fol,
            distractor_patches: if split { n_dis } else { 0 },
            foliage_heldout: None,
        },
        extractor,
        object,
        background,
        foliage,
        distractors,
        context: None,
    };
    if options.context {
        progress("column context", 0, context_ids.len());
        model.context = Some(fit_context(&model, &context_ids, &images, options.label_fraction)?);
    }
    progress("done", 3, 3);
    Ok(model)
}

/// The features of training image `i` and its patch grid's width, checked to have one
/// label per patch.
fn labelled_features(
    extractor: &FeatureExtractor,
    img: &LabelledImage,
    i: usize,
) -> Result<(PatchFeatures, u32), ModelError> {
    let image = ImageRef::new(img.width, img.height, &img.rgb)?;
    let f = extractor.features(&image, None)?;
    if img.fractions.len() != f.z.nrows() {
        return Err(ModelError::Training(format!(
            "image {i}: {} patch labels for {} patches",
            img.fractions.len(),
            f.z.nrows()
        )));
    }
    Ok((f, image.grid(extractor.config.patch_size).0))
}

/// Every how many training images one is kept for the column context.
pub const CONTEXT_EVERY: usize = 5;

/// Fits the column context on images `ids`, which the model's mixtures were not fitted to.
fn fit_context(
    model: &AppearanceModel,
    ids: &[usize],
    images: &impl Fn(usize) -> Result<LabelledImage, ModelError>,
    label_fraction: f64,
) -> Result<ColumnContext, ModelError> {
    let classifier = PatchClassifier::new(model)?;
    let mut grids = Vec::with_capacity(ids.len());
    for &i in ids {
        let img = images(i)?;
        let (f, cols) = labelled_features(&model.extractor, &img, i)?;
        let log_odds: Vec<f64> = classifier.minus_log_odds(&f).into_iter().map(|m| -m).collect();
        let object: Vec<bool> = (0..f.z.nrows())
            .map(|k| {
                let (c, r) = f.rect.patch(k).expect(IN_RECT);
                img.fractions[(r * cols + c) as usize] as f64 >= label_fraction
            })
            .collect();
        grids.push(LabelledGrid { log_odds, object, cols: f.rect.cols() as usize, rows: f.rect.rows() as usize });
    }
    ColumnContext::fit(&grids, column_context::DEFAULT_REACH).map_err(|e| ModelError::Training(e.to_string()))
}

/// Scores a model's foliage decisions (more probably foliage than not) on labelled images
/// with foliage labels; `None` for a model without a foliage model.
pub fn evaluate_foliage(
    model: &AppearanceModel,
    count: usize,
    images: impl Fn(usize) -> Result<LabelledImage, ModelError>,
    label_fraction: f64,
) -> Result<Option<PatchScores>, ModelError> {
    let classifier = PatchClassifier::new(model)?;
    if !classifier.has_foliage() {
        return Ok(None);
    }
    let mut scores = PatchScores::default();
    for i in 0..count {
        let img = images(i)?;
        if img.foliage.len() != img.fractions.len() {
            return Err(ModelError::Training(format!("image {i}: no foliage label for every patch")));
        }
        let (f, cols) = labelled_features(&model.extractor, &img, i)?;
        for k in 0..f.z.nrows() {
            let (c, r) = f.rect.patch(k).expect(IN_RECT);
            let p = classifier.foliage_probability(f.z.row(k).transpose().as_slice())?.expect("has foliage");
            scores.add(p > 0.5, img.foliage[(r * cols + c) as usize] as f64 >= label_fraction);
        }
    }
    Ok(Some(scores))
}

/// Scores a model's patch decisions on labelled images.
pub fn evaluate(
    model: &AppearanceModel,
    count: usize,
    images: impl Fn(usize) -> Result<LabelledImage, ModelError>,
    label_fraction: f64,
) -> Result<PatchScores, ModelError> {
    let classifier = PatchClassifier::new(model)?;
    let mut scores = PatchScores::default();
    for i in 0..count {
        let img = images(i)?;
        let (f, cols) = labelled_features(&model.extractor, &img, i)?;
        for (k, predicted) in classifier.classify(&f)?.into_iter().enumerate() {
            let (c, r) = f.rect.patch(k).expect(IN_RECT);
            scores.add(predicted, img.fractions[(r * cols + c) as usize] as f64 >= label_fraction);
        }
    }
    Ok(scores)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Synthetic scenes: brown vertically striped "trunks" on green textured "grass".
    fn scene(seed: u64, w: u32, h: u32) -> LabelledImage {
        let mut s = seed.wrapping_mul(2654435761).wrapping_add(1);
        let mut next = move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 33) as u32
        };
        let x0 = next() % (w / 2);
        let tw = 18 + next() % 30;
        let mut rgb = Vec::with_capacity((w * h * 3) as usize);
        let mut mask = vec![false; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                let n = (next() % 30) as u8;
                if x >= x0 && x < x0 + tw {
                    mask[(y * w + x) as usize] = true;
                    let stripe = if (x - x0) % 4 < 2 { 0 } else { 25 };
                    rgb.extend([90 + stripe + n, 60 + stripe / 2 + n / 2, 35 + n / 3]);
                } else {
                    rgb.extend([40 + n / 2, 110 + n, 40 + n / 3]);
                }
            }
        }
        let l = 9;
        let (cols, rows) = (w / l, h / l);
        let mut fractions = vec![0.0f32; (cols * rows) as usize];
        for r in 0..rows {
            for c in 0..cols {
                let mut k = 0;
                for y in r * l..(r + 1) * l {
                    for x in c * l..(c + 1) * l {
                        k += mask[(y * w + x) as usize] as u32;
                    }
                }
                fractions[(r * cols + c) as usize] = k as f32 / 81.0;
            }
        }
        LabelledImage { width: w, height: h, rgb, fractions, foliage: Vec::new(), distractors: Vec::new() }
    }

    #[test]
    fn trains_and_separates_synthetic_trunks_from_grass() {
        let options = TrainingOptions {
            pca_dims: 6,
            max_patches_per_class: 3000,
            vb: VbOptions { max_components: 4, ..Default::default() },
            ..Default::default()
        };
        let model = train(6, |i| Ok(scene(i as u64, 160, 120)), &options, |_, _, _| {}).unwrap();
        let scores = evaluate(&model, 4, |i| Ok(scene(100 + i as u64, 160, 120)), 0.5).unwrap();
        assert!(scores.f1() > 0.9, "{scores:?}: F1 {}", scores.f1());
        assert!(model.object_weight > 0.05 && model.object_weight < 0.5);
    }

    #[test]
    fn posteriors_of_many_rows_equal_the_posterior_of_each_bit_for_bit() {
        let options = TrainingOptions {
            pca_dims: 6,
            max_patches_per_class: 2000,
            vb: VbOptions { max_components: 4, ..Default::default() },
            ..Default::default()
        };
        let model = train(3, |i| Ok(scene(i as u64, 120, 90)), &options, |_, _, _| {}).unwrap();
        let classifier = PatchClassifier::new(&model).unwrap();
        let image = scene(50, 120, 90);
        let features = model.extractor.features(&ImageRef::new(120, 90, &image.rgb).unwrap(), None).unwrap();
        // 13 x 10 patches: 130 rows, not a multiple of the four lanes.
        assert_eq!(features.z.nrows() % 4, 2);
        let together = classifier.posteriors(&features).unwrap();
        let one_by_one: Vec<f64> = (0..features.z.nrows())
            .map(|i| classifier.posterior(features.z.row(i).transpose().as_slice()).unwrap())
            .collect();
        assert_eq!(together.len(), one_by_one.len());
        for (i, (a, b)) in together.iter().zip(&one_by_one).enumerate() {
            assert_eq!(a.to_bits(), b.to_bits(), "row {i}: {a} against {b}");
        }
        assert!(together.iter().any(|&r| r > 0.9) && together.iter().any(|&r| r < 0.1), "both classes present");
        // Features that do not fit the classifier are named, not read out of bounds.
        let d = features.z.ncols();
        let narrow = PatchFeatures { rect: features.rect, z: features.z.columns(0, d - 1).into_owned() };
        let wrong = ClassifyError::Dimension { expected: d, found: d - 1 };
        assert_eq!(classifier.posteriors(&narrow), Err(wrong.clone()));
        assert_eq!(classifier.classify(&narrow), Err(wrong.clone()));
        assert_eq!(classifier.posterior(&vec![0.0; d - 1]), Err(wrong.clone()));
        assert_eq!(
            classifier.foliage_probability(&vec![0.0; d + 1]),
            Err(ClassifyError::Dimension { expected: d, found: d + 1 })
        );
        let fewer = PatchFeatures { rect: features.rect, z: features.z.rows(0, 7).into_owned() };
        assert_eq!(classifier.posteriors(&fewer), Err(ClassifyError::Rows { rows: 7, patches: 130 }));
    }

    #[test]
    fn model_files_round_trip_and_bad_files_are_clear_errors() {
        let options = TrainingOptions {
            pca_dims: 4,
            max_patches_per_class: 1000,
            vb: VbOptions { max_components: 2, ..Default::default() },
            ..Default::default()
        };
        let model = train(2, |i| Ok(scene(i as u64, 90, 63)), &options, |_, _, _| {}).unwrap();
        let text = serde_json::to_string(&model).unwrap();
        assert_eq!(AppearanceModel::from_json(&text, "m.json").unwrap(), model);
        let old = text.replacen("\"format_version\":1", "\"format_version\":99", 1);
        let err = AppearanceModel::from_json(&old, "m.json").unwrap_err().to_string();
        assert!(err.contains("m.json") && err.contains("99"), "{err}");
        let err = AppearanceModel::from_json(&text[..text.len() / 2], "cut.json").unwrap_err().to_string();
        assert!(err.starts_with("cut.json"), "{err}");
        let err = AppearanceModel::from_json("{\"format_version\":1}", "empty.json").unwrap_err().to_string();
        assert!(err.contains("empty.json") && err.contains("missing field"), "{err}");
        let err = AppearanceModel::from_json("[]", "list.json").unwrap_err().to_string();
        assert!(err.contains("expected an appearance model") && !err.contains("VersionOnly"), "{err}");
        // A file that cannot be read keeps the I/O error as its source.
        let err = AppearanceModel::load(Path::new("/nonexistent/model.json")).unwrap_err();
        let source = std::error::Error::source(&err).and_then(|s| s.downcast_ref::<std::io::Error>());
        assert_eq!(source.map(|e| e.kind()), Some(std::io::ErrorKind::NotFound), "{err}");
        // Values that parse but make no model: each named.
        let json: serde_json::Value = serde_json::from_str(&text).unwrap();
        let edit = |f: &dyn Fn(&mut serde_json::Value)| {
            let mut v = json.clone();
            f(&mut v);
            AppearanceModel::from_json(&v.to_string(), "m.json").unwrap_err().to_string()
        };
        // A key the model does not have (a typo of an optional one) is refused, not dropped.
        let err = edit(&|v| v["contxt"] = serde_json::Value::Null);
        assert!(err.contains("m.json") && err.contains("unknown field `contxt`"), "{err}");
        let err = edit(&|v| v["object"]["bogus"] = 1.into());
        assert!(err.contains("unknown field `bogus`"), "{err}");
        let err = edit(&|v| v["object"]["prior"]["nu0"] = (-1.0).into());
        assert!(err.contains("object") && err.contains("nu0"), "{err}");
        let err = edit(&|v| v["background"]["prior"]["beta0"] = 0.0.into());
        assert!(err.contains("background") && err.contains("beta0"), "{err}");
        let err = edit(&|v| {
            v["extractor"]["pca"]["variances"].as_array_mut().unwrap().pop();
        });
        assert!(err.contains("extractor.pca.variances"), "{err}");
        let err = edit(&|v| v["extractor"]["pca"]["variances"][0] = "x".into());
        assert!(err.contains("extractor.pca.variances[0]: invalid type"), "{err}");
        // A foliage model must match the features and carry a share in (0, 1].
        assert!(model.foliage.is_none(), "trained without foliage labels");
        // The model with a background part (`foliage`, `distractors`) added.
        let with_part = |part: &str, weight: f64, gmm: &VbGmm| {
            let mut v = json.clone();
            v[part] = serde_json::json!({ "gmm": gmm, "weight": weight });
            AppearanceModel::from_json(&v.to_string(), "m.json")
        };
        let with_foliage = |weight: f64, gmm: &VbGmm| with_part("foliage", weight, gmm);
        let loaded = with_foliage(0.3, &model.background).unwrap();
        assert!(PatchClassifier::new(&loaded).unwrap().has_foliage());
        let err = with_foliage(0.0, &model.background).unwrap_err().to_string();
        assert!(err.contains("foliage.weight"), "{err}");
        let other = train(
            2,
            |i| Ok(scene(i as u64, 90, 63)),
            &TrainingOptions { pca_dims: 3, ..options.clone() },
            |_, _, _| {},
        )
        .unwrap();
        let err = with_foliage(0.3, &other.background).unwrap_err().to_string();
        assert!(err.contains("foliage.gmm is"), "{err}");

        // A distractors' part: the background then mixes it with the rest, so a patch the
        // distractors' density explains is less of an object patch.
        assert!(model.distractors.is_none(), "trained without distractor labels");
        let with_distractors = |weight: f64, gmm: &VbGmm| with_part("distractors", weight, gmm);
        let loaded = with_distractors(0.5, &model.object).unwrap();
        let (plain, split) = (PatchClassifier::new(&model).unwrap(), PatchClassifier::new(&loaded).unwrap());
        let img = scene(1, 90, 63);
        let f = model.extractor.features(&ImageRef::new(90, 63, &img.rgb).unwrap(), None).unwrap();
        let (r_plain, r_split) = (plain.posteriors(&f).unwrap(), split.posteriors(&f).unwrap());
        let mut object_patches = 0;
        for (k, (&a, &b)) in r_plain.iter().zip(&r_split).enumerate() {
            // Where the object's density is the higher (every object patch, as w_obj < w_bg).
            if a > 0.5 {
                assert!(b < a, "patch {k}: R {b} with an object-like distractor part, {a} without");
                object_patches += 1;
            }
            assert!((split.posterior(f.z.row(k).transpose().as_slice()).unwrap() - b).abs() < 1e-9);
        }
        assert!(object_patches > 0);
        for weight in [0.0, 1.0] {
            let err = with_distractors(weight, &model.background).unwrap_err().to_string();
            assert!(err.contains("distractors.weight"), "{err}");
        }
        let err = with_distractors(0.3, &other.background).unwrap_err().to_string();
        assert!(err.contains("distractors.gmm is"), "{err}");
    }

    #[test]
    fn the_column_context_is_fitted_on_images_the_mixtures_did_not_see() {
        let options = TrainingOptions {
            pca_dims: 6,
            max_patches_per_class: 2000,
            vb: VbOptions { max_components: 4, ..Default::default() },
            context: true,
            ..Default::default()
        };
        let model = train(10, |i| Ok(scene(i as u64, 120, 90)), &options, |_, _, _| {}).unwrap();
        let context = model.context.as_ref().expect("trained with a context");
        // Images 4 and 9 fit the context; the other 8 the PCA and the mixtures.
        assert_eq!((model.training.images, context.images), (8, 2));
        assert_eq!(context.patches, 2 * 13 * 10);
        assert!(context.weights[0] > 0.0, "a patch's own log-odds count for it: {:?}", context.weights);
        let scores = evaluate(&model, 4, |i| Ok(scene(100 + i as u64, 120, 90)), 0.5).unwrap();
        assert!(scores.f1() > 0.9, "{scores:?}");
        // The context is part of the model file, and checked when read.
        let text = serde_json::to_string(&model).unwrap();
        assert_eq!(AppearanceModel::from_json(&text, "m.json").unwrap(), model);
        let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
        v["context"]["reach"] = 1.into();
        let err = AppearanceModel::from_json(&v.to_string(), "m.json").unwrap_err().to_string();
        assert!(err.contains("m.json") && err.contains("context.reach"), "{err}");
        // Without the context nothing is held back, and the file has no `context` key.
        let plain = train(
            10,
            |i| Ok(scene(i as u64, 120, 90)),
            &TrainingOptions { context: false, ..options.clone() },
            |_, _, _| {},
        )
        .unwrap();
        assert_eq!(plain.training.images, 10);
        assert!(!serde_json::to_string(&plain).unwrap().contains("\"context\""));
        // An image with a label missing is an error, not a panic, when scored.
        let short = |_| {
            let mut img = scene(7, 120, 90);
            img.fractions.pop();
            Ok(img)
        };
        let err = evaluate(&model, 1, short, 0.5).unwrap_err().to_string();
        assert!(err.contains("image 0") && err.contains("patch labels"), "{err}");
        // Too few images to keep one back is a clear error.
        let err = train(4, |i| Ok(scene(i as u64, 120, 90)), &options, |_, _, _| {}).unwrap_err().to_string();
        assert!(err.contains("at least 5 images"), "{err}");
    }

    #[test]
    fn scores_count_correctly() {
        let mut s = PatchScores::default();
        for (p, t) in [(true, true), (true, true), (true, false), (false, true), (false, false)] {
            s.add(p, t);
        }
        assert!((s.precision() - 2.0 / 3.0).abs() < 1e-12 && (s.recall() - 2.0 / 3.0).abs() < 1e-12);
        assert!((s.f1() - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!((s.defined_precision(), s.defined_recall()), (Some(s.precision()), Some(s.recall())));
    }

    /// Regression: with nothing classified, precision and recall came out perfect (1).
    #[test]
    fn precision_and_recall_over_no_patch_are_undefined() {
        let none = PatchScores::default();
        assert_eq!((none.defined_precision(), none.defined_recall()), (None, None));
        let negatives = PatchScores { true_negatives: 5, ..Default::default() };
        assert_eq!((negatives.defined_precision(), negatives.defined_recall()), (None, None));
        let missed = PatchScores { false_negatives: 2, ..Default::default() };
        assert_eq!((missed.defined_precision(), missed.defined_recall()), (None, Some(0.0)));
        let wrong = PatchScores { false_positives: 2, ..Default::default() };
        assert_eq!((wrong.defined_precision(), wrong.defined_recall()), (Some(0.0), None));
        // F1 is undefined with either; a held-out world with no tree patch had scored 1.000.
        assert_eq!((negatives.defined_f1(), missed.defined_f1(), wrong.defined_f1()), (None, None, None));
        assert_eq!(score_text(negatives.defined_f1()), "undefined");
        let half = PatchScores { true_positives: 1, false_positives: 1, false_negatives: 1, true_negatives: 0 };
        assert_eq!(half.defined_f1(), Some(0.5));
        assert_eq!(score_text(half.defined_f1()), "0.500");
    }
}
