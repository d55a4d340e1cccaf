//! Per-object models (paper section 4.2): an object's segmented patches, their features
//! augmented with the patches' global positions, and a VB-GMM over them (docs/design.md, paper symbols: `p_L`).
//!
//! Positions are stored relative to the object's landmark (x, y in the map frame, metres;
//! h, the height above the laser plane), so a model stays attached to its landmark when the
//! EKF moves it. When an observation is compared with a landmark, the observation's
//! positions are shifted into the landmark's frame and their x-y covariance is widened by
//! the uncertainty of that offset (pose, landmark and measurement), so the KL divergence
//! weighs position exactly as much as the filter can know it.

use nalgebra::{DMatrix, DVector, Matrix2};
use serde::{Deserialize, Serialize};

use crate::features::{FeatureError, FeatureExtractor};
use crate::gmm::{self, Component, Gmm, GmmError, StudentTMixture, VbOptions, VbPrior};
use crate::kl::{self, KlError, PreparedGmm};

/// How object models are learnt and compared.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ObjectModelConfig {
    /// Components per object model (fixed K is faster than the search; the paper's
    /// footnote 2). 0 searches by birth-death.
    pub components: usize,
    /// Standard deviation (m) added to the x-y spread of both densities when they are
    /// compared: the patches of one view lie in one plane, the object has depth (about a
    /// trunk's radius). 0.1 m left views from a new side 100+ nats away.
    pub position_floor_m: f64,
    /// An observation joins the candidate with the smallest KL below this (nats).
    pub kl_threshold: f64,
    /// Leading appearance dimensions (PCA coordinates) the model uses; a few strong
    /// directions estimate far better from one view's patches than all of them.
    pub appearance_dims: usize,
    /// A former key that nothing read: read only to be refused with what to do (files
    /// written from older `objslam config defaults` output, or older logs, hold it).
    #[serde(skip_serializing)]
    pub mosaic_patches: Option<usize>,
}

impl Default for ObjectModelConfig {
    fn default() -> Self {
        ObjectModelConfig {
            components: 1,
            position_floor_m: 0.3,
            kl_threshold: 80.0,
            appearance_dims: 4,
            mosaic_patches: None,
        }
    }
}

/// Most appearance dimensions an object model may use (the most PCA dimensions a trained
/// appearance model may have).
pub const MAX_APPEARANCE_DIMS: usize = 1000;

/// Most mixture components an object model may have: a model of one view's few hundred
/// patches cannot support more.
pub const MAX_OBJECT_COMPONENTS: usize = 32;

impl ObjectModelConfig {
    /// The first setting that makes no sense, as (field, problem).
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        if self.mosaic_patches.is_some() {
            return Err((
                "mosaic_patches",
                "is no longer a setting (nothing ever read it: a mosaic keeps its object's largest view whole); \
                 delete this line"
                    .into(),
            ));
        }
        if self.components > MAX_OBJECT_COMPONENTS {
            return Err((
                "components",
                format!("must be at most {MAX_OBJECT_COMPONENTS} (0 searches), got {}", self.components),
            ));
        }
        if !(self.position_floor_m.is_finite() && self.position_floor_m >= 0.0) {
            return Err((
                "position_floor_m",
                format!("must be finite and not negative, got {}", self.position_floor_m),
            ));
        }
        if !(self.kl_threshold.is_finite() && self.kl_threshold > 0.0) {
            return Err(("kl_threshold", format!("must be a positive number of nats, got {}", self.kl_threshold)));
        }
        if !(1..=MAX_APPEARANCE_DIMS).contains(&self.appearance_dims) {
            return Err((
                "appearance_dims",
                format!(
                    "must be 1 to {MAX_APPEARANCE_DIMS} (and at most the appearance model's), got {}",
                    self.appearance_dims
                ),
            ));
        }
        Ok(())
    }
}

/// One segmented object observation: feature rows (appearance z, then x, y relative to the
/// observation's centre, then h) and where each patch sits in the image grid.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectObservation {
    /// Map-frame position of the observed object's centre.
    pub centre: [f64; 2],
    /// Rows: [leading appearance dims | dx | dy | h].
    pub rows: DMatrix<f64>,
    /// Full PCA coordinates z_A of each patch (for the mosaic).
    pub appearance: Vec<Vec<f64>>,
    /// (col, row) of each patch in the image's patch grid.
    pub cells: Vec<(u32, u32)>,
    /// Each patch's pixels as the camera saw them (L x L RGB, row-major), for the mosaic.
    pub pixels: Vec<Vec<u8>>,
    /// Covariance of `centre` (2x2, map frame).
    pub centre_covariance: Matrix2<f64>,
}

impl ObjectObservation {
    /// The appearance columns: those before the 3 of the position (none in rows that
    /// hold fewer).
    pub fn appearance_dims(&self) -> usize {
        self.rows.ncols().saturating_sub(3)
    }
}

/// The appearance patches kept for the mosaic of figure 3: z_A per cell of one view.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MosaicView {
    pub cells: Vec<(u32, u32)>,
    /// PCA coordinates z_A (d values) per cell.
    pub appearance: Vec<Vec<f64>>,
    /// The pixels of each cell as seen (L x L RGB); empty in models saved before they were
    /// kept.
    #[serde(default)]
    pub pixels: Vec<Vec<u8>>,
}

/// A mapped object's model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObjectModel {
    /// Density over [z | x, y relative to the landmark | h].
    pub gmm: Gmm,
    /// Patches merged into the model so far (N of eq. 5).
    pub patches: f64,
    pub observations: usize,
    /// The view with the most object patches.
    pub mosaic: MosaicView,
}

#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ObjectModelError {
    #[error(transparent)]
    Gmm(#[from] GmmError),
    #[error(transparent)]
    Kl(#[from] KlError),
    #[error("observation has {0} patches; an object model needs at least 2")]
    TooFewPatches(usize),
    /// Rows hold the appearance coordinates and then dx, dy and h: at least 4 columns.
    #[error("observation rows have {0} columns; an object model needs the 3 of a position and more")]
    TooFewColumns(usize),
    /// An observation fitted in another feature space than the model's (another
    /// appearance model's PCA): a divergence between them would compare unlike numbers.
    #[error("observation of {observation} dimensions against an object model of {model}")]
    Dimension { observation: usize, model: usize },
}

/// Fits the density of one observation (rows with positions relative to its centre).
/// `general` (the classifier's object model, appearance only) supplies the appearance
/// block of the prior (the paper's footnote 2).
pub fn fit_observation(
    obs: &ObjectObservation,
    general: Option<&Gmm>,
    config: &ObjectModelConfig,
) -> Result<Gmm, ObjectModelError> {
    let n = obs.rows.nrows();
    if n < 2 {
        return Err(ObjectModelError::TooFewPatches(n));
    }
    let d = obs.rows.ncols();
    if d <= 3 {
        return Err(ObjectModelError::TooFewColumns(d));
    }
    let mut prior = VbPrior::from_data(&obs.rows)?;
    if let Some(g) = general {
        let da = g.dims().min(d - 3);
        let (_, cov) = g.moments()?;
        for i in 0..da {
            for j in 0..da {
                prior.w0_inv[(i, j)] = cov[(i, j)];
            }
            // Decouple the appearance block from positions in the prior.
            for j in da..d {
                prior.w0_inv[(i, j)] = 0.0;
                prior.w0_inv[(j, i)] = 0.0;
            }
        }
        prior.check(d)?;
    }
    let options = VbOptions {
        // 0: a search by birth and death, up to as many components as a model may have.
        max_components: if config.components == 0 { MAX_OBJECT_COMPONENTS } else { config.components }.min(n).max(1),
        fixed_k: config.components > 0,
        max_iterations: 200,
        tolerance: 1e-6,
        seed: 0,
        ..Default::default()
    };
    let vb = gmm::fit(&obs.rows, Some(&prior), &options)?;
    let mut g = StudentTMixture::new(&vb)?.gaussian_approximation()?;
    // Drop components without weight: they add nothing and slow the KL.
    g.components.retain(|c| c.weight > 1e-3);
    let s: f64 = g.components.iter().map(|c| c.weight).sum();
    g.components.iter_mut().for_each(|c| c.weight /= s);
    Ok(g)
}

/// `g` with `floor_m`² added to the variance of its x-y dimensions (at `xy`, `xy + 1`).
fn with_position_floor(g: &Gmm, xy: usize, floor_m: f64) -> Gmm {
    shifted(g, xy, [0.0, 0.0], &(Matrix2::identity() * floor_m * floor_m))
}

/// `g` with its x-y dimensions (at `xy`, `xy + 1`) shifted by `shift` and widened by `extra`.
fn shifted(g: &Gmm, xy: usize, shift: [f64; 2], extra: &Matrix2<f64>) -> Gmm {
    let mut out = g.clone();
    for c in &mut out.components {
        c.mean[xy] += shift[0];
        c.mean[xy + 1] += shift[1];
        for i in 0..2 {
            for j in 0..2 {
                c.covariance[(xy + i, xy + j)] += extra[(i, j)];
            }
        }
    }
    out
}

/// The mixture's marginal over its first `dims` dimensions; a component of fewer is
/// [`GmmError::Dimension`].
pub fn marginal(g: &Gmm, dims: usize) -> Result<Gmm, GmmError> {
    let short = |c: &Component| c.mean.len().min(c.covariance.nrows()).min(c.covariance.ncols());
    if let Some(found) = g.components.iter().map(short).find(|&n| n < dims) {
        return Err(GmmError::Dimension { expected: dims, found });
    }
    Ok(Gmm {
        components: g
            .components
            .iter()
            .map(|c| Component {
                weight: c.weight,
                mean: c.mean.rows(0, dims).into_owned(),
                covariance: c.covariance.view((0, 0), (dims, dims)).into_owned(),
            })
            .collect(),
    })
}

impl ObjectModel {
    /// A new object's model from its first observation (`fitted` from [`fit_observation`]).
    pub fn new(obs: &ObjectObservation, fitted: Gmm, pca_dims: usize) -> Self {
        ObjectModel {
            gmm: fitted,
            patches: obs.rows.nrows() as f64,
            observations: 1,
            mosaic: mosaic_view(obs, pca_dims),
        }
    }

    /// KL(observation || this model) with the observation placed relative to a landmark at
    /// `landmark` whose offset from the observation has covariance `offset_covariance`
    /// (the observation is widened by it).
    /// With `appearance_only`, positions are marginalised out of both densities.
    ///
    /// The position floor is added to both densities here, not stored in the model: the
    /// model's sufficient statistics stay those of the patches, so merging observations
    /// (eq. 5) never dilutes the floor, and a trunk seen from a new side (its patches in a
    /// plane turned against the earlier views') still matches.
    pub fn kl_from(
        &self,
        fitted_obs: &Gmm,
        obs_centre: [f64; 2],
        landmark: [f64; 2],
        offset_covariance: &Matrix2<f64>,
        config: &ObjectModelConfig,
        appearance_only: bool,
    ) -> Result<f64, ObjectModelError> {
        self.gmm.check_shapes()?;
        fitted_obs.check_shapes()?;
        let d = self.gmm.dims();
        if fitted_obs.dims() != d {
            return Err(ObjectModelError::Dimension { observation: fitted_obs.dims(), model: d });
        }
        if d <= 3 {
            return Err(ObjectModelError::TooFewColumns(d));
        }
        let (f, g) = if appearance_only {
            (marginal(fitted_obs, d - 3)?, marginal(&self.gmm, d - 3)?)
        } else {
            // The offset's uncertainty widens the observation, not the model. KL(f || g)
            // punishes an f wider than g, so the less the filter knows where the object is,
            // the less readily an observation joins it: after a long drift this makes
            // duplicates rather than wrong associations. (Widening the model instead leaves
            // the decision to appearance, and the trees' appearances are too alike.)
            let obs = shifted(
                fitted_obs,
                d - 3,
                [obs_centre[0] - landmark[0], obs_centre[1] - landmark[1]],
                offset_covariance,
            );
            (
                with_position_floor(&obs, d - 3, config.position_floor_m),
                with_position_floor(&self.gmm, d - 3, config.position_floor_m),
            )
        };
        Ok(kl::kl_variational(&PreparedGmm::new(&f)?, &PreparedGmm::new(&g)?)?)
    }

    /// Merges an associated observation (eq. 5 on sufficient statistics): each patch is
    /// shared among this model's components by responsibility; per component the counts,
    /// means and second moments add up:
    /// pi_s <- (M pi_s^new + N pi_s) / (M + N), mu_s <- (M_s mu_s^new + N_s mu_s) / (M_s + N_s),
    /// Gamma_s from the summed second moments.
    pub fn update(
        &mut self,
        obs: &ObjectObservation,
        landmark: [f64; 2],
        pca_dims: usize,
    ) -> Result<(), ObjectModelError> {
        let d = self.gmm.dims();
        if obs.rows.ncols() != d {
            return Err(ObjectModelError::Dimension { observation: obs.rows.ncols(), model: d });
        }
        if d < 4 {
            return Err(ObjectModelError::TooFewColumns(d));
        }
        let (xy, m) = (d - 3, obs.rows.nrows());
        let shift = [obs.centre[0] - landmark[0], obs.centre[1] - landmark[1]];
        let eval = self.gmm.evaluator()?;
        let k = self.gmm.components.len();
        let mut mass = vec![0.0; k];
        let mut sum = vec![DVector::zeros(d); k];
        let mut sq = vec![DMatrix::zeros(d, d); k];
        let mut x = vec![0.0; d];
        let mut terms = vec![0.0; k];
        for i in 0..m {
            for (j, v) in x.iter_mut().enumerate() {
                *v = obs.rows[(i, j)];
            }
            x[xy] += shift[0];
            x[xy + 1] += shift[1];
            eval.log_terms_prechecked(&x, &mut terms);
            let total = crate::gmm::log_sum_exp(&terms);
            for s in 0..k {
                let r = (terms[s] - total).exp();
                if r > 0.0 {
                    mass[s] += r;
                    for (acc, xj) in sum[s].iter_mut().zip(&x) {
                        *acc += xj * r;
                    }
                    // The rank-one update x x^T r in place (no temporaries per patch).
                    let sq = &mut sq[s];
                    for (b, xb) in x.iter().enumerate() {
                        for (a, xa) in x.iter().enumerate() {
                            sq[(a, b)] += (xa * xb) * r;
                        }
                    }
                }
            }
        }
        let n = self.patches;
        for (s, c) in self.gmm.components.iter_mut().enumerate() {
            let ns = c.weight * n;
            let ms = mass[s];
            if ms <= 0.0 {
                c.weight = ns / (n + m as f64);
                continue;
            }
            let second_old = (&c.covariance + &c.mean * c.mean.transpose()) * ns;
            let mean = (&c.mean * ns + &sum[s]) / (ns + ms);
            let second = (second_old + &sq[s]) / (ns + ms);
            let cov = second - &mean * mean.transpose();
            c.covariance = (&cov + cov.transpose()) * 0.5;
            c.mean = mean;
            c.weight = (ns + ms) / (n + m as f64);
        }
        self.patches = n + m as f64;
        self.observations += 1;
        if obs.rows.nrows() > self.mosaic.cells.len() {
            self.mosaic = mosaic_view(obs, pca_dims);
        }
        Ok(())
    }
}

fn mosaic_view(obs: &ObjectObservation, _pca_dims: usize) -> MosaicView {
    MosaicView { cells: obs.cells.clone(), appearance: obs.appearance.clone(), pixels: obs.pixels.clone() }
}

/// Figure 3 (right): the mosaic's patches back-projected through the PCA eigenvectors into
/// RGB, laid out as they were seen. Returns (width, height, RGB8); empty cells are black.
/// A view whose cells and appearance vectors do not pair up, or whose vectors are shorter
/// than the extractor's PCA dimension, is a [`FeatureError`].
pub fn render_mosaic(view: &MosaicView, extractor: &FeatureExtractor) -> Result<(u32, u32, Vec<u8>), FeatureError> {
    let (pca, patch_size, channels) = (&extractor.pca, extractor.config.patch_size, 3 + extractor.config.bank.len());
    let gains = extractor.config.gains();
    if view.cells.len() != view.appearance.len() {
        return Err(FeatureError::Mosaic { cells: view.cells.len(), appearance: view.appearance.len() });
    }
    // An extractor built field by field: its PCA must give the patches its settings cut.
    if pca.input_dims() != extractor.config.raw_dims() {
        return Err(FeatureError::PcaMismatch { expected: pca.input_dims(), found: extractor.config.raw_dims() });
    }
    if view.cells.is_empty() {
        return Ok((0, 0, Vec::new()));
    }
    let l = patch_size as usize;
    let (c0, c1) =
        (view.cells.iter().map(|c| c.0).min().unwrap_or(0), view.cells.iter().map(|c| c.0).max().unwrap_or(0));
    let (r0, r1) =
        (view.cells.iter().map(|c| c.1).min().unwrap_or(0), view.cells.iter().map(|c| c.1).max().unwrap_or(0));
    let (w, h) = (((c1 - c0) as usize + 1) * l, ((r1 - r0) as usize + 1) * l);
    let mut rgb = vec![0u8; w * h * 3];
    for (cell, z) in view.cells.iter().zip(&view.appearance) {
        let raw = pca.back_project(z)?;
        let (ox, oy) = ((cell.0 - c0) as usize * l, (cell.1 - r0) as usize * l);
        for py in 0..l {
            for px in 0..l {
                let base = (py * l + px) * channels;
                let o = ((oy + py) * w + ox + px) * 3;
                for ch in 0..3 {
                    rgb[o + ch] = ((raw[base + ch] / gains[ch] as f64).clamp(0.0, 1.0) * 255.0).round() as u8;
                }
            }
        }
    }
    Ok((w as u32, h as u32, rgb))
}

/// The mosaic's patches as the camera saw them, laid out as [`render_mosaic`] lays out
/// their reconstructions; `None` for models saved without pixels.
pub fn render_mosaic_as_seen(view: &MosaicView, patch_size: u32) -> Option<(u32, u32, Vec<u8>)> {
    let l = patch_size as usize;
    if view.cells.is_empty()
        || view.pixels.len() != view.cells.len()
        || view.pixels.iter().any(|p| p.len() != l * l * 3)
    {
        return None;
    }
    let (c0, c1) = (view.cells.iter().map(|c| c.0).min()?, view.cells.iter().map(|c| c.0).max()?);
    let (r0, r1) = (view.cells.iter().map(|c| c.1).min()?, view.cells.iter().map(|c| c.1).max()?);
    let (w, h) = (((c1 - c0) as usize + 1) * l, ((r1 - r0) as usize + 1) * l);
    let mut rgb = vec![0u8; w * h * 3];
    for (cell, patch) in view.cells.iter().zip(&view.pixels) {
        let (ox, oy) = ((cell.0 - c0) as usize * l, (cell.1 - r0) as usize * l);
        for py in 0..l {
            let o = ((oy + py) * w + ox) * 3;
            rgb[o..o + l * 3].copy_from_slice(&patch[py * l * 3..(py + 1) * l * 3]);
        }
    }
    Some((w as u32, h as u32, rgb))
}

/// "Find objects that look like this": mapped objects ranked by the appearance-only KL
/// from an example's density (smallest first).
pub fn rank_by_appearance(example: &Gmm, objects: &[(u32, &ObjectModel)]) -> Result<Vec<(u32, f64)>, ObjectModelError> {
    let da = example.dims();
    let f = PreparedGmm::new(example)?;
    let mut out = Vec::with_capacity(objects.len());
    for (id, m) in objects {
        let g = marginal(&m.gmm, da)?;
        out.push((*id, kl::kl_variational(&f, &PreparedGmm::new(&g)?)?));
    }
    out.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// An observation of an object with appearance centred on `look` (3-D here), patches
    /// spread over 0.3 m width and 1.5 m height, centred at `centre`.
    fn observation(seed: u64, look: [f64; 3], centre: [f64; 2], n: usize) -> ObjectObservation {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, 0.3).unwrap();
        let rows = DMatrix::from_fn(n, 6, |i, j| match j {
            0..=2 => look[j] + noise.sample(&mut rng),
            3 => 0.1 * noise.sample(&mut rng),
            4 => 0.3 * ((i % 5) as f64 / 4.0 - 0.5),
            _ => 1.5 * (i as f64 / n as f64),
        });
        let appearance = (0..n).map(|i| rows.row(i).columns(0, 3).iter().copied().collect()).collect();
        ObjectObservation {
            centre,
            rows,
            appearance,
            cells: (0..n as u32).map(|i| (i % 5, i / 5)).collect(),
            pixels: vec![],
            centre_covariance: Matrix2::identity() * 0.01,
        }
    }

    /// `components = 0` searches: two looks far apart in one observation become two
    /// components (the cap of one component had kept every search at one).
    #[test]
    fn zero_components_searches_for_more_than_one() {
        let (a, b) =
            (observation(21, [3.0, 0.0, 0.0], [0.0, 0.0], 80), observation(22, [-3.0, 0.0, 0.0], [0.0, 0.0], 80));
        let mut both = a.clone();
        both.rows = DMatrix::from_fn(160, 6, |i, j| if i < 80 { a.rows[(i, j)] } else { b.rows[(i - 80, j)] });
        let searched =
            fit_observation(&both, None, &ObjectModelConfig { components: 0, ..Default::default() }).unwrap();
        assert!(searched.components.len() >= 2, "{} components", searched.components.len());
        let one = fit_observation(&both, None, &ObjectModelConfig { components: 1, ..Default::default() }).unwrap();
        assert_eq!(one.components.len(), 1);
    }

    #[test]
    fn kl_is_small_for_the_same_object_and_large_for_another() {
        let config = ObjectModelConfig::default();
        let tree = observation(1, [1.0, 0.0, 0.0], [5.0, 2.0], 60);
        let model = ObjectModel::new(&tree, fit_observation(&tree, None, &config).unwrap(), 3);
        let again = observation(2, [1.0, 0.0, 0.0], [5.1, 2.05], 50);
        let post = observation(3, [-1.0, 1.5, 0.5], [5.1, 2.05], 50);
        let cov = Matrix2::identity() * 0.02;
        let same = model
            .kl_from(&fit_observation(&again, None, &config).unwrap(), again.centre, [5.0, 2.0], &cov, &config, false)
            .unwrap();
        let other = model
            .kl_from(&fit_observation(&post, None, &config).unwrap(), post.centre, [5.0, 2.0], &cov, &config, false)
            .unwrap();
        assert!(same < 10.0 && other > 2.0 * same + 10.0, "same {same}, other {other}");
        // The same object far from the landmark is far in KL too (position counts)...
        let far = model
            .kl_from(&fit_observation(&again, None, &config).unwrap(), [9.0, 2.0], [5.0, 2.0], &cov, &config, false)
            .unwrap();
        assert!(far > 2.0 * same + 10.0, "far {far}");
        // ...unless positions are marginalised out.
        let far_app = model
            .kl_from(&fit_observation(&again, None, &config).unwrap(), [9.0, 2.0], [5.0, 2.0], &cov, &config, true)
            .unwrap();
        assert!(far_app < same.max(1.0) * 2.0, "appearance only {far_app}");
    }

    /// Guards the position floor against eq. 5: merged observations used to dilute a floor
    /// stored in the model, so a trunk seen from a new side (its patch plane turned 90 deg)
    /// ended hundreds of nats from its own model and started a duplicate landmark.
    #[test]
    fn a_well_known_object_seen_from_a_new_side_still_matches() {
        let config = ObjectModelConfig::default();
        let first = observation(10, [1.0, 0.0, 0.0], [5.0, 2.0], 60);
        let mut model = ObjectModel::new(&first, fit_observation(&first, None, &config).unwrap(), 3);
        for k in 0..30 {
            model.update(&observation(11 + k, [1.0, 0.0, 0.0], [5.0, 2.0], 60), [5.0, 2.0], 3).unwrap();
        }
        let mut side = observation(50, [1.0, 0.0, 0.0], [5.0, 2.0], 60);
        side.rows.swap_columns(3, 4);
        let cov = Matrix2::identity() * 0.02;
        let kl = model
            .kl_from(&fit_observation(&side, None, &config).unwrap(), side.centre, [5.0, 2.0], &cov, &config, false)
            .unwrap();
        // 0.2 nats now; 16 when the floor lived in the model.
        assert!(kl < 3.0, "KL from a new side {kl}");
    }

    #[test]
    fn update_merges_sufficient_statistics() {
        let config = ObjectModelConfig { components: 1, position_floor_m: 0.0, ..Default::default() };
        let a = observation(4, [1.0, 0.0, 0.0], [0.0, 0.0], 40);
        let b = observation(5, [2.0, 0.0, 0.0], [0.0, 0.0], 60);
        let mut model = ObjectModel::new(&a, fit_observation(&a, None, &config).unwrap(), 3);
        let before = model.gmm.components[0].mean[0];
        model.update(&b, [0.0, 0.0], 3).unwrap();
        let after = model.gmm.components[0].mean[0];
        // With one component every patch joins it: the mean is the count-weighted mean.
        let mean_b = b.rows.column(0).mean();
        assert!(((after - (40.0 * before + 60.0 * mean_b) / 100.0) / after).abs() < 1e-9, "{after}");
        assert_eq!(model.patches, 100.0);
        assert_eq!(model.observations, 2);
        assert!((model.gmm.components[0].weight - 1.0).abs() < 1e-12);
        // The mosaic keeps the larger view.
        assert_eq!(model.mosaic.cells.len(), 60);
    }

    #[test]
    fn ranking_puts_the_look_alike_first() {
        let config = ObjectModelConfig::default();
        let objs: Vec<ObjectObservation> = vec![
            observation(6, [1.0, 0.0, 0.0], [0.0, 0.0], 50),
            observation(7, [-2.0, 1.0, 0.0], [3.0, 0.0], 50),
            observation(8, [0.0, 3.0, 1.0], [6.0, 0.0], 50),
        ];
        let models: Vec<ObjectModel> =
            objs.iter().map(|o| ObjectModel::new(o, fit_observation(o, None, &config).unwrap(), 3)).collect();
        let example = observation(9, [-2.0, 1.0, 0.0], [0.0, 0.0], 40);
        let ex = marginal(&fit_observation(&example, None, &config).unwrap(), 3).unwrap();
        let refs: Vec<(u32, &ObjectModel)> = models.iter().enumerate().map(|(i, m)| (i as u32, m)).collect();
        let ranked = rank_by_appearance(&ex, &refs).unwrap();
        assert_eq!(ranked[0].0, 1);
    }
}
