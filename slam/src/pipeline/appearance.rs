//! The appearance methods: segmentation of the scan's clusters in the camera image,
//! object models, KL association, joint loop closing.

use super::*;

/// One observation of the appearance methods, planned against the landmarks that existed
/// before the scan.
pub(super) struct Plan {
    /// The index of its cluster in the scan.
    cluster: usize,
    observation: ObjectObservation,
    /// Its fitted appearance density.
    fitted: Gmm,
    /// (range, bearing).
    z: Vector2<f64>,
    candidates: Vec<Candidate>,
    /// The KL test's choice: the landmark's (id, index).
    best: Option<(u32, usize)>,
    /// Whether the camera could judge it fully (see `observe_objects`).
    fully_judged: bool,
}

/// What the appearance methods need: the trained model, ready to classify, and the camera.
#[derive(Clone)]
pub struct Appearance {
    /// Read-only outside the crate ([`Appearance::model`]): the classifier and the prior
    /// below are made from it, and it was checked.
    pub(crate) model: AppearanceModel,
    classifier: PatchClassifier,
    /// The classifier's object density (appearance only): prior for object models.
    general: Gmm,
    /// Read-only outside the crate ([`Appearance::camera`]): it was checked.
    pub(crate) camera: CameraGeometry,
}

/// Why an [`Appearance`] could not be made of a model and a camera.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AppearanceSetupError {
    /// The model's parts do not fit together (see [`AppearanceModel::check`]).
    #[error("appearance model: {0}")]
    Model(String),
    /// See [`CameraGeometry::check`].
    #[error("camera geometry: {0}")]
    Camera(String),
    #[error("appearance model: {0}")]
    Mixture(#[from] crate::gmm::GmmError),
}

impl Appearance {
    /// Checks the model and the camera as a file's would be checked: a model or camera
    /// made in code skips no check by not coming from a file.
    pub fn new(model: AppearanceModel, camera: CameraGeometry) -> Result<Self, AppearanceSetupError> {
        model.check_parts().map_err(AppearanceSetupError::Model)?;
        camera.check().map_err(AppearanceSetupError::Camera)?;
        let classifier = PatchClassifier::new(&model)?;
        let general = StudentTMixture::new(&model.object)?.gaussian_approximation()?;
        Ok(Appearance { model, classifier, general, camera })
    }

    /// The appearance model the classifier and the object models' prior were made from.
    pub fn model(&self) -> &AppearanceModel {
        &self.model
    }

    /// The camera's geometry, which segmentation projects clusters with.
    pub fn camera(&self) -> &CameraGeometry {
        &self.camera
    }
}

fn patch_pixels(rgb: &[u8], width: u32, col: u32, row: u32, l: u32) -> Vec<u8> {
    let (w, l) = (width as usize, l as usize);
    let (x0, y0) = (col as usize * l, row as usize * l);
    let mut pixels = Vec::with_capacity(l * l * 3);
    for y in y0..y0 + l {
        pixels.extend_from_slice(&rgb[(y * w + x0) * 3..(y * w + x0 + l) * 3]);
    }
    pixels
}

impl Pipeline {
    /// Segments the clusters in the stored image and builds object observations, each with
    /// its cluster's index and whether the segmentation could judge it fully
    /// ([`SegmentedCluster::fully_judged`](crate::segmentation::SegmentedCluster::fully_judged)).
    ///
    /// A cluster that cannot be segmented in an image the pipeline took (a model or
    /// settings the checks let through that the features refuse) stops the scan with
    /// [`PipelineError::Segmentation`] before anything is pooled: dropping it would leave
    /// an object unobserved with no word of why.
    pub(super) fn observe_objects(
        &mut self,
        t: f64,
        clusters: &[Cluster],
    ) -> Result<Vec<(usize, ObjectObservation, bool)>, PipelineError> {
        let (Some(app), Some(img)) = (&self.appearance, &self.image) else { return Ok(Vec::new()) };
        if (t - img.t).abs() > self.config.image_max_age_s {
            return Ok(Vec::new());
        }
        let image = ImageRef::new(img.width, img.height, &img.rgb).map_err(|source| PipelineError::Segmentation {
            t,
            cluster: None,
            source,
        })?;
        let extractor = &app.model.extractor;
        let l = extractor.config.patch_size;
        let mut record = SegmentationRecord { t_image: img.t, patch_size: l, cells: Vec::new(), clusters: Vec::new() };
        let mut out = Vec::new();
        // Each cluster's segmentation depends on nothing but the image and the cluster: they
        // run in parallel and are used in order, so results do not depend on the threads.
        let seg_config = &self.config.segmentation;
        /// What became of one cluster.
        enum Segmented {
            Done(Box<SegmentedCluster>),
            /// Occluded, or outside the image.
            NotInImage,
            /// Its pixels were not rendered (counted in `unrendered_reads`).
            Unrendered,
            Failed(FeatureError),
        }
        let segmentations: Vec<Segmented> = clusters
            .par_iter()
            .map(|c| {
                if c.occluded {
                    return Segmented::NotInImage;
                }
                let Some(located) = locate_cluster(c, &app.camera, image.width, image.height, l, seg_config) else {
                    return Segmented::NotInImage;
                };
                if let Some(regions) = &img.regions
                    && !regions_cover(regions, &extractor.config.pixels_read(&located.rect, image.width, image.height))
                {
                    return Segmented::Unrendered;
                }
                match segment_located(c, located, &image, extractor, &app.classifier, &app.camera, seg_config) {
                    Ok(seg) => Segmented::Done(Box::new(seg)),
                    Err(e) => Segmented::Failed(e),
                }
            })
            .collect();
        // The first failure in cluster order, whatever the threads did first.
        let mut unrendered = 0;
        let mut segmented = Vec::with_capacity(segmentations.len());
        for (i, s) in segmentations.into_iter().enumerate() {
            segmented.push(match s {
                Segmented::Done(seg) => Some(seg),
                Segmented::NotInImage => None,
                Segmented::Unrendered => {
                    unrendered += 1;
                    None
                }
                Segmented::Failed(source) => {
                    return Err(PipelineError::Segmentation { t, cluster: Some(i), source });
                }
            });
        }
        self.unrendered_reads += unrendered;
        for (ci, (c, seg)) in clusters.iter().zip(segmented).enumerate() {
            let Some(seg) = seg else { continue };
            for (i, &o) in seg.object.iter().enumerate() {
                let (col, row) = seg.rect.patch(i).expect(IN_RECT);
                if !record.cells.iter().any(|&(a, b, _)| a == col && b == row) {
                    record.cells.push((col, row, o));
                }
            }
            let hit_rows = (
                seg.hit_patches.iter().map(|h| h.1).min().unwrap_or(0),
                seg.hit_patches.iter().map(|h| h.1).max().unwrap_or(0),
            );
            let (centre, rot) = self.to_map(c.centre);
            // Pooling: a frame the camera judged fully adds to its place's evidence; one it
            // could not judge takes its place's judgement, or its own where no place is yet
            // (and then only re-observes confirmed landmarks). A place with fewer than
            // `min_frames` judged frames is undecided: rejected, or judged frame by frame
            // with `undecided_by_frame` (see EvidenceConfig for the trade-off).
            let seg_cfg = &self.config.segmentation;
            let enough_patches = seg.object.iter().filter(|&&o| o).count() >= seg_cfg.min_object_patches;
            let (place, _) = self.laser_point_in(&self.odometry_pose, c.centre);
            let pooled = self.config.evidence.pooled.then(|| {
                if seg.fully_judged() {
                    Some(self.evidence.add(t, place, c.range_m, seg.hit_fraction, seg.above_fraction))
                } else {
                    self.evidence.judge(place)
                }
            });
            let observed = match pooled {
                Some(Some(j))
                    if j.frames >= self.config.evidence.min_frames || !self.config.evidence.undecided_by_frame =>
                {
                    j.is_object && enough_patches
                }
                _ => seg.is_object,
            };
            record.clusters.push(ClusterSegmentation {
                index: ci,
                is_object: seg.is_object,
                hit_fraction: seg.hit_fraction,
                above_fraction: seg.above_fraction,
                band_foliage_patches: seg.band_foliage_patches,
                pooled: pooled.flatten(),
                observed,
                band_visible: seg.band_visible,
                at_image_edge: seg.at_image_edge,
                row_profile: seg.row_profile.clone(),
                columns: (seg.rect.col0, seg.rect.col1),
                hit_rows,
                posteriors: seg.posteriors.iter().map(|&r| r as f32).collect(),
            });
            if !observed {
                continue;
            }
            let rows_idx = seg.object_rows();
            let da = self.config.object_model.appearance_dims.min(seg.features.z.ncols());
            let pca_dims = extractor.pca.dims();
            let mut appearance = Vec::with_capacity(rows_idx.len());
            let mut rows = DMatrix::zeros(rows_idx.len(), da + 3);
            let mut cells = Vec::with_capacity(rows_idx.len());
            let mut pixels = Vec::with_capacity(rows_idx.len());
            let mut n = 0;
            for &i in &rows_idx {
                let (col, row) = seg.rect.patch(i).expect(IN_RECT);
                let (u, v) = ((col as f64 + 0.5) * l as f64, (row as f64 + 0.5) * l as f64);
                let Some(p) = app.camera.point_on_object_plane(u, v, c.centre) else { continue };
                let d = rot * Vector2::new(p.x - c.centre[0], p.y - c.centre[1]);
                for j in 0..da {
                    rows[(n, j)] = seg.features.z[(i, j)];
                }
                rows[(n, da)] = d.x;
                rows[(n, da + 1)] = d.y;
                rows[(n, da + 2)] = p.z;
                appearance.push(seg.features.z.row(i).columns(0, pca_dims).iter().copied().collect());
                cells.push((col, row));
                pixels.push(patch_pixels(&img.rgb, img.width, col, row, l));
                n += 1;
            }
            if n < 2 {
                continue;
            }
            let rows = rows.rows(0, n).into_owned();
            // A place the pooled evidence calls an object was judged in earlier frames: a
            // frame too close to judge on its own may then start and confirm landmarks.
            let judged = seg.fully_judged() || matches!(pooled, Some(Some(j)) if j.is_object);
            out.push((
                ci,
                ObjectObservation { centre, rows, appearance, cells, pixels, centre_covariance: Matrix2::zeros() },
                judged,
            ));
        }
        self.evidence.forget_before(t);
        self.segmentations.push(record);
        Ok(out)
    }

    /// Observations the KL test left without a landmark, paired by joint compatibility
    /// where that is unambiguous (see [`PipelineConfig::joint_loop_closing`]): per plan, the
    /// (id, index) of its landmark, `None` where the KL test decides. `t` is the scan's.
    pub(super) fn close_loop_jointly(
        &self,
        t: f64,
        plans: &[Plan],
        cfg: &ObjectModelConfig,
        scan: &LaserScan,
    ) -> Result<Vec<Option<(u32, usize)>>, PipelineError> {
        let none = vec![None; plans.len()];
        let n = self.ekf.landmark_count();
        // KL-associated observations keep their landmark (or stay out); the others may take
        // any confirmed, gated candidate that looks alike.
        let mut orphans = 0;
        let allowed: Vec<Vec<bool>> = plans
            .iter()
            .map(|p| {
                let mut row = vec![false; n];
                if let Some((_, j)) = p.best {
                    row[j] = true;
                    return Ok(row);
                }
                for j in self.confirmed_lookalikes((t, p.cluster), &p.observation, &p.fitted, &p.candidates, cfg)? {
                    row[j] = true;
                }
                orphans += row.iter().any(|a| *a) as usize;
                Ok(row)
            })
            .collect::<Result<_, PipelineError>>()?;
        if orphans == 0 || plans.len() < 2 {
            return Ok(none);
        }
        let zs: Vec<Vector2<f64>> = plans.iter().map(|p| p.z).collect();
        let searched = unambiguous_jcbb(&self.ekf, &self.config.sensor, &zs, &allowed, self.config.jcbb_probability);
        let Some(h) = searched.expect("a row per plan, and a probability the settings' check keeps within (0, 1)")
        else {
            return Ok(none);
        };
        // Two or more of the unexplained observations must pair: one alone is only
        // individually gated, and a new tree near an uncertain old one would pass.
        if h.iter().zip(plans).filter(|(j, p)| j.is_some() && p.best.is_none()).count() < 2 {
            return Ok(none);
        }
        if self.config.joint_loop_free_space && self.sees_past_a_landmark(&h, &zs, scan) {
            return Ok(none);
        }
        Ok(h.iter()
            .zip(plans)
            .map(|(j, p)| if p.best.is_some() { None } else { j.map(|j| (self.table.get(j).id, j)) })
            .collect())
    }

    /// Whether, with the pose corrected by hypothesis `h` (observations `zs`), a confirmed
    /// landmark that `h` leaves unpaired is predicted in plain view within the clustering
    /// range where `scan` sees past it (see [`PipelineConfig::joint_loop_free_space`] and
    /// [`free_space_probability`]). The tentative filter costs a copy of the covariance,
    /// made only for a closure about to be accepted. Where the filter refuses a pairing of
    /// `h` (an innovation covariance it cannot invert), the corrected pose is unknown and
    /// the test cannot clear the closure: it counts as seeing past, and the closure is
    /// refused.
    fn sees_past_a_landmark(&self, h: &[Option<usize>], zs: &[Vector2<f64>], scan: &LaserScan) -> bool {
        let mut trial = self.ekf.clone();
        for (i, j) in h.iter().enumerate() {
            if let Some(j) = *j
                && trial.update_iterated(&self.config.sensor, j, &zs[i], 1).is_err()
            {
                return true;
            }
        }
        let n = trial.landmark_count();
        for k in 0..n {
            if h.contains(&Some(k)) || !self.table.get(k).confirmed {
                continue;
            }
            let (zp, _, _, s) = trial.predict_observation(&self.config.sensor, k).expect(MAPPED);
            let (r, b) = (zp.x, zp.y);
            if !(r > MIN_FREE_SPACE_RANGE_M && r <= self.config.clustering.max_range_m) {
                continue;
            }
            let radius = 0.5 * self.table.get(k).diameter_m;
            if free_space_probability(scan, r, b, &s, radius).is_some_and(|p| p >= FREE_SPACE_PROBABILITY) {
                return true;
            }
        }
        false
    }

    /// Indices of the confirmed candidates whose object model looks like the observation
    /// (appearance KL under the threshold).
    /// A divergence that cannot be computed is the pipeline's error (see
    /// [`PipelineError::ObjectModel`]), not a landmark that looks unlike.
    pub(super) fn confirmed_lookalikes(
        &self,
        (t, cluster): (f64, usize),
        obs: &ObjectObservation,
        fitted: &Gmm,
        candidates: &[Candidate],
        cfg: &ObjectModelConfig,
    ) -> Result<Vec<usize>, PipelineError> {
        let mut alike = Vec::new();
        for c in candidates {
            let Some(j) = self.table.index_of(c.landmark) else { continue };
            let Some(model) = self.table.object(j).filter(|_| self.table.get(j).confirmed) else { continue };
            let kl = model
                .kl_from(fitted, obs.centre, [0.0; 2], &Matrix2::zeros(), cfg, true)
                .map_err(|source| PipelineError::ObjectModel { t, cluster, landmark: Some(c.landmark), source })?;
            if kl.is_finite() && kl < cfg.kl_threshold {
                alike.push(j);
            }
        }
        Ok(alike)
    }

    /// Whether a confirmed landmark that looks like the observation lies within its
    /// new-landmark gate (`candidates` holds those).
    pub(super) fn near_lookalike(
        &self,
        at: (f64, usize),
        obs: &ObjectObservation,
        fitted: &Gmm,
        candidates: &[Candidate],
        cfg: &ObjectModelConfig,
    ) -> Result<bool, PipelineError> {
        Ok(!self.confirmed_lookalikes(at, obs, fitted, candidates, cfg)?.is_empty())
    }

    /// Covariance (map frame) of the offset between an observation at (range, bearing) and
    /// landmark `j`: the innovation covariance mapped through the polar-to-Cartesian Jacobian.
    pub(super) fn offset_covariance(&self, j: usize, z: &Vector2<f64>) -> Matrix2<f64> {
        let (_, _, _, s) = self.ekf.predict_observation(&self.config.sensor, j).expect(MAPPED);
        let theta = self.ekf.pose().z;
        let (r, b) = (z.x, z.y);
        let (sb, cb) = b.sin_cos();
        let (st, ct) = theta.sin_cos();
        let polar = Matrix2::new(cb, -r * sb, sb, r * cb);
        let jz = Matrix2::new(ct, -st, st, ct) * polar;
        jz * s * jz.transpose()
    }

    /// Appearance methods: segmentation, object models and KL association.
    pub(super) fn on_scan_with_appearance(
        &mut self,
        scan: &LaserScan,
        clusters: Vec<Cluster>,
    ) -> Result<ScanReport, PipelineError> {
        let t = scan.t;
        self.t = t;
        // The state the recorded poses agree with, where a relinearisation starts.
        let before = self.history.as_ref().map(|_| self.ekf.x.clone());
        let observations = self.observe_objects(t, &clusters)?;
        let mut assigned = vec![None; clusters.len()];
        let method = self.config.method;
        let cfg = self.config.object_model.clone();
        let gate = chi2_quantile(2, self.config.new_landmark_probability).expect(CHECKED_GATE);
        let assoc_gate = chi2_quantile(2, self.config.gate_probability).expect(CHECKED_GATE);
        let pca_dims = self.appearance.as_ref().map_or(0, |a| a.model.extractor.pca.dims());
        // Decide every observation against the landmarks that existed before this scan.
        let mut plans = Vec::new();
        let general = self.appearance.as_ref().map(|a| a.general.clone());
        for (ci, obs, fully_judged) in observations {
            let fitted = fit_observation(&obs, general.as_ref(), &cfg)
                .map_err(|source| PipelineError::ObjectModel { t, cluster: ci, landmark: None, source })?;
            let z = Vector2::new(clusters[ci].range_m, clusters[ci].bearing_rad);
            let mut candidates = Vec::new();
            for (j, m2) in self.ekf.mahalanobis2_to_all(&self.config.sensor, &z).into_iter().enumerate() {
                self.note_distance(m2);
                if method == AssociationMethod::Combined && m2 > gate {
                    continue;
                }
                let Some(model) = self.table.object(j) else { continue };
                let known = self.table.get(j);
                if method == AssociationMethod::Combined
                    && !self.config.diameter.compatible(
                        clusters[ci].diameter_m,
                        z.x,
                        known.diameter_m,
                        known.observations,
                    )
                {
                    continue;
                }
                // A cluster too close for the camera to tell a trunk from a post may only
                // re-observe a confirmed landmark, never start or confirm one.
                if !fully_judged && !known.confirmed {
                    continue;
                }
                let lm = self.ekf.landmark(j).expect(MAPPED);
                let kl = model
                    .kl_from(
                        &fitted,
                        obs.centre,
                        [lm.x, lm.y],
                        &self.offset_covariance(j, &z),
                        &cfg,
                        method == AssociationMethod::Appearance,
                    )
                    .map_err(|source| PipelineError::ObjectModel {
                        t,
                        cluster: ci,
                        landmark: Some(known.id),
                        source,
                    })?;
                candidates.push(Candidate { landmark: known.id, mahalanobis2: m2, kl: Some(kl) });
            }
            // The combined method's candidates lie within the new-landmark gate (for the
            // deferral and the joint test); to join one by KL, an observation must also be
            // within the association gate, as for the position-only methods.
            let best = candidates
                .iter()
                .filter(|c| method != AssociationMethod::Combined || c.mahalanobis2 <= assoc_gate)
                .filter_map(|c| c.kl.filter(|k| k.is_finite() && *k < cfg.kl_threshold).map(|k| (c.landmark, k)))
                .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
            let best = best.and_then(|(id, _)| self.table.index_of(id).map(|j| (id, j)));
            plans.push(Plan { cluster: ci, observation: obs, fitted, z, candidates, best, fully_judged });
        }
        let joint = if method == AssociationMethod::Combined && self.config.joint_loop_closing {
            self.close_loop_jointly(t, &plans, &cfg, scan)?
        } else {
            vec![None; plans.len()]
        };
        let mut new_ones = Vec::new();
        let mut closed_jointly = false;
        for (plan, joint) in plans.into_iter().zip(joint) {
            let Plan { cluster: ci, observation: obs, fitted, z, candidates, best, fully_judged } = plan;
            // A loop closed jointly corrects the pose by metres. With latest-estimate
            // Jacobians the closing update itself is iterated; first-estimate ones stay
            // where they are, and the smoother relinearises after the scan.
            let closes_jointly = best.is_none() && joint.is_some();
            let iterations = if closes_jointly && !self.config.first_estimate_jacobians { 10 } else { 1 };
            let best = best.or(joint);
            let choice = match best {
                Some((id, j)) => {
                    if self.ekf.update_iterated(&self.config.sensor, j, &z, iterations).is_ok() {
                        self.update_object_model(t, ci, j, &obs, pca_dims)?;
                        let place = self.laser_point_in(&self.odometry_pose, clusters[ci].centre).0;
                        self.table.set_place(j, place);
                        let l = self.table.get_mut(j);
                        l.diameter_m = (l.diameter_m * l.observations as f64 + clusters[ci].diameter_m)
                            / (l.observations + 1) as f64;
                        l.observations += 1;
                        assigned[ci] = Some(id);
                        closed_jointly |= closes_jointly;
                        if let Some(h) = &mut self.history {
                            h.observe(id, z);
                        }
                        Choice::Existing { landmark: id }
                    } else {
                        Choice::Rejected
                    }
                }
                None if !fully_judged => Choice::Rejected,
                None if method == AssociationMethod::Combined
                    && self.config.defer_near_lookalike
                    && self.near_lookalike((t, ci), &obs, &fitted, &candidates, &cfg)? =>
                {
                    Choice::Deferred
                }
                None => {
                    new_ones.push((ci, self.decisions.len(), obs, fitted, z));
                    Choice::Rejected // replaced below once the id exists
                }
            };
            self.decisions.push(AssociationDecision { t, observation: ci, candidates, choice, method });
        }
        let class = self.appearance.as_ref().map_or("object".to_string(), |a| a.model.object_class.clone());
        for (ci, decision, obs, fitted, z) in new_ones {
            let place = self.laser_point_in(&self.odometry_pose, clusters[ci].centre).0;
            let new = NewLandmark { z, class: &class, diameter_m: clusters[ci].diameter_m, place: Some(place) };
            let (id, j) =
                self.table.add(&mut self.ekf, &self.config.sensor, t, &[new], false, self.config.confirm_observations)
                    [0];
            let lm = self.ekf.landmark(j).expect(MAPPED);
            // Re-centre the model's positions on the landmark estimate.
            let mut model = ObjectModel::new(&obs, fitted, pca_dims);
            let d = model.gmm.dims();
            for c in &mut model.gmm.components {
                c.mean[d - 3] += obs.centre[0] - lm.x;
                c.mean[d - 2] += obs.centre[1] - lm.y;
            }
            self.table.set_object(j, model);
            assigned[ci] = Some(id);
            self.decisions[decision].choice = Choice::New { landmark: id };
            if let Some(h) = &mut self.history {
                h.observe(id, z);
            }
        }
        let due = self.config.relinearise_every_s.is_some_and(|every| t - self.relinearised_at >= every);
        if (closed_jointly || due)
            && let Some(before) = &before
        {
            self.relinearise(before);
        }
        if self.config.evidence.pooled {
            self.retract_landmarks();
        }
        self.finish_scan(t, clusters, assigned)
    }

    /// Folds observation `obs` of cluster `ci` into the object model of landmark slot `j`,
    /// at the landmark's updated position.
    fn update_object_model(
        &mut self,
        t: f64,
        ci: usize,
        j: usize,
        obs: &ObjectObservation,
        pca_dims: usize,
    ) -> Result<(), PipelineError> {
        let lm = self.ekf.landmark(j).expect(MAPPED);
        let id = self.table.get(j).id;
        match self.table.object_mut(j) {
            Some(m) => m.update(obs, [lm.x, lm.y], pca_dims).map_err(|source| PipelineError::ObjectModel {
                t,
                cluster: ci,
                landmark: Some(id),
                source,
            }),
            None => Ok(()),
        }
    }

    /// Whether landmarks `i` and `j` may be one object by their appearance: always for the
    /// position-only methods; for the appearance methods when both have object models whose
    /// appearance KL is under the association threshold.
    pub(super) fn look_alike(&self, i: usize, j: usize) -> Result<bool, ObjectModelError> {
        if !self.config.method.uses_appearance() {
            return Ok(true);
        }
        let (Some(a), Some(b)) = (self.table.object(i), self.table.object(j)) else { return Ok(false) };
        let cfg = &self.config.object_model;
        let kl = a.kl_from(&b.gmm, [0.0; 2], [0.0; 2], &Matrix2::zeros(), cfg, true)?;
        Ok(kl.is_finite() && kl < cfg.kl_threshold)
    }
}

/// Probability that a landmark's bearing falls on beams that see past it, above which a
/// joint closure is refused: the confidence of the joint compatibility test itself.
const FREE_SPACE_PROBABILITY: f64 = 0.95;

/// A landmark predicted closer than this to the laser would stand inside the robot (the
/// Pioneer is 0.63 m long): a broken prediction, not something the scan could confirm.
const MIN_FREE_SPACE_RANGE_M: f64 = 0.5;

/// The probability that a landmark predicted at range `r` and bearing `b` (laser frame),
/// with innovation covariance `s` and trunk radius `radius`, lies where `scan` sees past
/// it; `None` where its bearing's three-sigma window leaves the scan's field of view. The
/// bearing is taken as Gaussian (the innovation's bearing variance plus the trunk's own
/// angular width); each beam in the window is weighted by that density, and sees past the
/// landmark when it has no return or returns beyond `r` by three sigma of range and a
/// trunk's diameter. A closer return (something in front) does not.
pub(super) fn free_space_probability(scan: &LaserScan, r: f64, b: f64, s: &Matrix2<f64>, radius: f64) -> Option<f64> {
    let sigma = (s[(1, 1)].max(0.0) + (radius / r).powi(2)).sqrt();
    let margin = 3.0 * s[(0, 0)].max(0.0).sqrt() + 2.0 * radius;
    let lo = ((b - 3.0 * sigma - scan.angle_min) / scan.angle_increment).ceil();
    let hi = ((b + 3.0 * sigma - scan.angle_min) / scan.angle_increment).floor();
    if !(lo >= 0.0 && hi <= scan.ranges.len() as f64 - 1.0 && lo <= hi) {
        return None;
    }
    let (mut free, mut all) = (0.0, 0.0);
    for i in lo as usize..=hi as usize {
        let a = scan.angle_min + i as f64 * scan.angle_increment;
        let w = (-0.5 * ((a - b) / sigma).powi(2)).exp();
        let ri = scan.ranges[i];
        all += w;
        // No return (+inf) passes; one too close to measure (-inf, REP-117) is in the way.
        if ri == f64::INFINITY || ri > scan.range_max || (scan.valid(i) && ri > r + margin) {
            free += w;
        }
    }
    (all > 0.0).then(|| free / all)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gmm::Component;
    use crate::object_model::MosaicView;
    use nalgebra::DVector;

    /// A one-component density over [4 appearance dims | x, y | h] with appearance mean `a`.
    fn density(a: f64) -> Gmm {
        let mut mean = DVector::zeros(7);
        mean.rows_mut(0, 4).fill(a);
        mean[6] = 1.0;
        Gmm { components: vec![Component { weight: 1.0, mean, covariance: DMatrix::identity(7, 7) * 0.04 }] }
    }

    /// One tree landmark 5 m ahead with an object model of appearance 0.
    fn one_landmark(confirm_observations: usize) -> Pipeline {
        let config = PipelineConfig { method: AssociationMethod::Nn, confirm_observations, ..Default::default() };
        let mut p = Pipeline::new(config, [0.0; 3], None).unwrap();
        let c = Cluster {
            first_beam: 0,
            last_beam: 3,
            points: vec![],
            centre: [5.0, 0.0],
            diameter_m: 0.3,
            range_m: 5.0,
            bearing_rad: 0.0,
            occluded: false,
        };
        p.on_scan_with_objects(0.1, vec![c], &[true], "tree").unwrap();
        p.table.set_object(
            0,
            ObjectModel {
                gmm: density(0.0),
                patches: 20.0,
                observations: 1,
                mosaic: MosaicView { cells: vec![], appearance: vec![], pixels: vec![] },
            },
        );
        p
    }

    fn observation() -> ObjectObservation {
        ObjectObservation {
            centre: [5.2, 0.1],
            rows: DMatrix::zeros(0, 7),
            appearance: vec![],
            cells: vec![],
            pixels: vec![],
            centre_covariance: Matrix2::zeros(),
        }
    }

    #[test]
    fn an_observation_beside_a_confirmed_lookalike_is_deferred() {
        let p = one_landmark(1);
        let cfg = ObjectModelConfig::default();
        let candidate = [Candidate { landmark: 0, mahalanobis2: 1.0, kl: Some(500.0) }];
        let at = (1.5, 2);
        assert!(p.near_lookalike(at, &observation(), &density(0.05), &candidate, &cfg).unwrap(), "same appearance");
        assert!(
            !p.near_lookalike(at, &observation(), &density(5.0), &candidate, &cfg).unwrap(),
            "another kind of object starts its own landmark"
        );
        assert!(!p.near_lookalike(at, &observation(), &density(0.05), &[], &cfg).unwrap(), "nothing in the gate");
        // A tentative landmark (maybe a person) never holds a new tree back.
        let q = one_landmark(8);
        assert!(!q.near_lookalike(at, &observation(), &density(0.05), &candidate, &cfg).unwrap());
    }

    #[test]
    fn a_lookalike_that_cannot_be_compared_is_an_error_not_an_unlike_landmark() {
        let p = one_landmark(1);
        let cfg = ObjectModelConfig::default();
        let candidate = [Candidate { landmark: 0, mahalanobis2: 1.0, kl: Some(500.0) }];
        // A fitted density of 5 dimensions against the landmark's model of 7.
        let mut other = density(0.05);
        other.components[0].mean = DVector::zeros(5);
        other.components[0].covariance = DMatrix::identity(5, 5);
        let e = p.near_lookalike((1.5, 2), &observation(), &other, &candidate, &cfg).unwrap_err();
        assert!(
            matches!(
                &e,
                PipelineError::ObjectModel {
                    cluster: 2,
                    landmark: Some(0),
                    source: crate::object_model::ObjectModelError::Dimension { observation: 5, model: 7 },
                    ..
                }
            ),
            "{e:?}"
        );
    }

    #[test]
    fn an_observation_the_object_model_cannot_take_is_refused_with_the_landmark_named() {
        let mut p = one_landmark(1);
        let before = p.table.object(0).cloned();
        // Rows of 5 columns against a model of 7: another feature space.
        let obs = ObjectObservation { rows: DMatrix::zeros(4, 5), ..observation() };
        let e = p.update_object_model(2.5, 3, 0, &obs, 4).unwrap_err();
        assert!(
            matches!(
                &e,
                PipelineError::ObjectModel {
                    t,
                    cluster: 3,
                    landmark: Some(0),
                    source: crate::object_model::ObjectModelError::Dimension { observation: 5, model: 7 }
                } if *t == 2.5
            ),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            "the object model of cluster 3 against landmark 0 at t = 2.5 s: observation of 5 dimensions against an object model of 7"
        );
        assert_eq!(p.table.object(0).cloned(), before, "a refused update changed the model");
        // One it can take is folded in.
        let obs = ObjectObservation { rows: DMatrix::from_element(4, 7, 0.1), ..observation() };
        p.update_object_model(2.6, 3, 0, &obs, 4).unwrap();
        assert_eq!(p.table.object(0).map(|m| m.observations), Some(2));
    }

    #[test]
    fn trunk_diameters_tell_apart_trees_of_different_girth() {
        let check = DiameterCheck::default();
        // long_loop, seed 1: a 0.64 m trunk 11 m away was paired with a 0.45 m one.
        assert!(!check.compatible(0.64, 11.0, 0.446, 54));
        // The spread measured between single clusters and their landmark: 3 sigma in, at
        // every range, with few or many observations behind the landmark.
        for (range, spread) in [(4.0, 0.05), (8.0, 0.08), (11.0, 0.12)] {
            assert!(check.compatible(0.45 + spread, range, 0.45, 50), "{range} m");
            assert!(check.compatible(0.45 - spread, range, 0.45, 1), "{range} m");
        }
        assert!(!check.compatible(0.45 + 0.1, 4.0, 0.45, 50));
        let off = DiameterCheck { enabled: false, ..Default::default() };
        assert!(off.compatible(1.0, 5.0, 0.2, 10));
        assert!(check.validate().is_ok());
        assert_eq!(DiameterCheck { max_sigmas: 0.0, ..Default::default() }.validate().unwrap_err().0, "max_sigmas");
        assert_eq!(
            DiameterCheck { sigma_per_m: f64::NAN, ..Default::default() }.validate().unwrap_err().0,
            "sigma_per_m"
        );
        assert_eq!(
            DiameterCheck { sigma_m: 0.0, sigma_per_m: 0.0, ..Default::default() }.validate().unwrap_err().0,
            "sigma_m"
        );
    }

    /// A 180-degree scan of 361 beams, 0.5 degrees apart, every beam reading `range`.
    fn scan_reading(range: f64) -> LaserScan {
        LaserScan {
            t: 0.0,
            angle_min: -std::f64::consts::FRAC_PI_2,
            angle_increment: 0.5f64.to_radians(),
            range_min: 0.05,
            range_max: 80.0,
            ranges: vec![range; 361],
        }
    }

    #[test]
    fn free_space_is_where_the_laser_sees_past_a_landmark() {
        // A trunk of 0.2 m radius predicted 7 m ahead, 2 degrees of bearing sigma.
        let s = Matrix2::new(0.1, 0.0, 0.0, 2f64.to_radians().powi(2));
        let p = |scan: &LaserScan| free_space_probability(scan, 7.0, 0.0, &s, 0.2).unwrap();
        // No return anywhere: the landmark would have been seen.
        assert_eq!(p(&scan_reading(f64::INFINITY)), 1.0);
        // Returns far beyond it: the same.
        assert_eq!(p(&scan_reading(20.0)), 1.0);
        // Returns at its range (the trunk is there), or something in front: not free.
        assert_eq!(p(&scan_reading(7.1)), 0.0);
        assert_eq!(p(&scan_reading(3.0)), 0.0);
        // A reading below the laser's minimum is no sight past it either.
        assert_eq!(p(&scan_reading(0.01)), 0.0);
        // Within range sigma and a trunk's diameter of the prediction is not past it.
        let margin = 3.0 * 0.1f64.sqrt() + 0.4;
        assert_eq!(p(&scan_reading(7.0 + margin - 0.01)), 0.0);
        // One close return at the window's edge (a person 3 sigma off) leaves most of the
        // bearing's probability free; one where the trunk is predicted does not.
        let mut edge = scan_reading(f64::INFINITY);
        let i = |deg: f64| ((deg.to_radians() + std::f64::consts::FRAC_PI_2) / 0.5f64.to_radians()).round() as usize;
        edge.ranges[i(-6.0)] = 2.7;
        assert!(p(&edge) > 0.95, "{}", p(&edge));
        let mut centre = scan_reading(f64::INFINITY);
        for deg in [-1.0, -0.5, 0.0, 0.5, 1.0] {
            centre.ranges[i(deg)] = 7.0;
        }
        assert!(p(&centre) < 0.95, "{}", p(&centre));
        // A window that leaves the field of view says nothing.
        assert!(free_space_probability(&scan_reading(20.0), 7.0, 89f64.to_radians(), &s, 0.2).is_none());
    }
}
