//! Position-only association (`nn`, `jcbb`) and the filter's update for a scan.

use super::*;

/// The index of the smallest distance under `gate` (the first of equals), if any.
fn nearest_within(distances: &[f64], gate: f64) -> Option<usize> {
    distances.iter().enumerate().filter(|(_, d)| **d < gate).min_by(|a, b| a.1.total_cmp(b.1)).map(|(i, _)| i)
}

/// A landmark's mean diameter after one more observation; detections without a diameter
/// (NaN) leave it as it was.
fn mean_diameter(mean: f64, observations: usize, diameter: f64) -> f64 {
    if !diameter.is_finite() {
        mean
    } else if !mean.is_finite() {
        diameter
    } else {
        (mean * observations as f64 + diameter) / (observations + 1) as f64
    }
}

impl Pipeline {
    /// Processes clusters of which only those with `is_object[i]` are observations of
    /// objects of interest (labelled `class`), for the position-only association.
    pub fn on_scan_with_objects(
        &mut self,
        t: f64,
        clusters: Vec<Cluster>,
        is_object: &[bool],
        class: &str,
    ) -> Result<ScanReport, PipelineError> {
        if is_object.len() != clusters.len() {
            return Err(PipelineError::ObjectFlags { given: is_object.len(), clusters: clusters.len() });
        }
        self.check_time("scan", t)?;
        // Where a cluster is: a value not finite would become a landmark that is not, and
        // stop the pipeline as if it had diverged. A diameter may be NaN (unknown, as
        // `Detection::as_cluster` writes it), not infinite or negative.
        if clusters.iter().any(|c| {
            ![c.range_m, c.bearing_rad, c.centre[0], c.centre[1]].iter().all(|v| v.is_finite())
                || c.diameter_m.is_infinite()
        }) {
            return Err(PipelineError::NonFinite { input: "clusters", t });
        }
        if clusters.iter().any(|c| c.diameter_m < 0.0) {
            return Err(PipelineError::NegativeDiameter { input: "clusters", t });
        }
        if clusters.iter().any(|c| c.range_m < 0.0) {
            return Err(PipelineError::NegativeRange { input: "clusters", t });
        }
        self.advance_to(t)?;
        let report = self.observe_positions(t, clusters, is_object, class)?;
        self.check_state(t)?;
        Ok(report)
    }

    /// Position-only association and the filter's update for one scan's clusters.
    pub(super) fn observe_positions(
        &mut self,
        t: f64,
        clusters: Vec<Cluster>,
        is_object: &[bool],
        class: &str,
    ) -> Result<ScanReport, PipelineError> {
        self.t = t;
        let idx: Vec<usize> = (0..clusters.len()).filter(|&i| is_object[i] && !clusters[i].occluded).collect();
        let zs: Vec<Vector2<f64>> =
            idx.iter().map(|&i| Vector2::new(clusters[i].range_m, clusters[i].bearing_rad)).collect();
        let gate = chi2_quantile(2, self.config.gate_probability).expect(CHECKED_GATE);
        let new_gate = chi2_quantile(2, self.config.new_landmark_probability).expect(CHECKED_GATE);
        let n_before = self.ekf.landmark_count();
        let diameter = &self.config.diameter;
        let use_diameter = diameter.for_position_methods;
        // Each landmark's predicted observation and inverse innovation covariance, once a
        // scan rather than once an observation (the same numbers as Ekf::mahalanobis2).
        let predicted: Vec<(Vector2<f64>, Option<Matrix2<f64>>)> = if zs.is_empty() {
            Vec::new()
        } else {
            (0..n_before)
                .map(|j| {
                    let (zp, _, _, s) = self.ekf.predict_observation(&self.config.sensor, j).expect(MAPPED);
                    (zp, s.try_inverse())
                })
                .collect()
        };
        let distances: Vec<Vec<f64>> = zs
            .iter()
            .zip(&idx)
            .map(|(z, &ci)| {
                predicted
                    .iter()
                    .enumerate()
                    .map(|(j, (zp, s_inv))| {
                        let lm = self.table.get(j);
                        if use_diameter
                            && !diameter.compatible(clusters[ci].diameter_m, z.x, lm.diameter_m, lm.observations)
                        {
                            return f64::INFINITY;
                        }
                        let nu = Vector2::new(z.x - zp.x, crate::messages::wrap_angle(z.y - zp.y));
                        match s_inv {
                            Some(si) => (nu.transpose() * si * nu)[(0, 0)],
                            None => f64::INFINITY,
                        }
                    })
                    .collect()
            })
            .collect();
        for &d in distances.iter().flatten() {
            self.note_distance(d);
        }
        let pairing: Vec<Option<usize>> = match self.config.method {
            AssociationMethod::Jcbb => {
                let allowed: Vec<Vec<bool>> =
                    distances.iter().map(|row| row.iter().map(|d| *d < gate).collect()).collect();
                jcbb_with(&self.ekf, &self.config.sensor, &zs, &allowed, self.config.jcbb_probability)
                    .expect("a row per observation, and a probability the settings' check keeps within (0, 1)")
            }
            // Nearest neighbour; appearance methods fall back to it until their
            // observations carry object models.
            _ => distances.iter().map(|row| nearest_within(row, gate)).collect(),
        };
        let mut assigned = vec![None; clusters.len()];
        // Updates first (against the landmarks that existed before this scan), then new
        // landmarks, so the order of observations does not matter.
        let updated: Vec<bool> = if self.config.batch_updates {
            let pairs: Vec<(usize, Vector2<f64>)> =
                pairing.iter().zip(&zs).filter_map(|(j, z)| j.map(|j| (j, *z))).collect();
            match self.ekf.update_batch(&self.config.sensor, &pairs) {
                Ok(()) => pairing.iter().map(|j| j.is_some()).collect(),
                // A stacked innovation covariance that is not positive definite: the
                // observations one by one, each accepted or refused on its own.
                Err(_) => pairing
                    .iter()
                    .zip(&zs)
                    .map(|(j, z)| j.is_some_and(|j| self.ekf.update(&self.config.sensor, j, z).is_ok()))
                    .collect(),
            }
        } else {
            pairing
                .iter()
                .zip(&zs)
                .map(|(j, z)| j.is_some_and(|j| self.ekf.update(&self.config.sensor, j, z).is_ok()))
                .collect()
        };
        let mut new_ones = Vec::new();
        for (k, &ci) in idx.iter().enumerate() {
            let candidates: Vec<Candidate> = distances[k]
                .iter()
                .enumerate()
                .filter(|(_, d)| **d < new_gate)
                .map(|(j, d)| Candidate { landmark: self.table.get(j).id, mahalanobis2: *d, kl: None })
                .collect();
            let choice = match pairing[k] {
                Some(j) if updated[k] => {
                    let lm = self.table.get_mut(j);
                    lm.diameter_m = mean_diameter(lm.diameter_m, lm.observations, clusters[ci].diameter_m);
                    lm.observations += 1;
                    assigned[ci] = Some(lm.id);
                    if let Some(h) = &mut self.history {
                        h.observe(lm.id, zs[k]);
                    }
                    Choice::Existing { landmark: lm.id }
                }
                Some(_) => Choice::Rejected,
                None if distances[k].iter().all(|d| *d > new_gate) => {
                    new_ones.push((k, ci));
                    Choice::Rejected // replaced below once the id exists
                }
                None => Choice::Rejected,
            };
            self.decisions.push(AssociationDecision {
                t,
                observation: ci,
                candidates,
                choice,
                method: self.config.method,
            });
        }
        let first_decision = self.decisions.len() - idx.len();
        let new: Vec<NewLandmark> = new_ones
            .iter()
            .map(|&(k, ci)| NewLandmark { z: zs[k], class, diameter_m: clusters[ci].diameter_m, place: None })
            .collect();
        let added = self.table.add(
            &mut self.ekf,
            &self.config.sensor,
            t,
            &new,
            self.config.batch_updates,
            self.config.confirm_observations,
        );
        for ((k, ci), (id, _)) in new_ones.into_iter().zip(added) {
            assigned[ci] = Some(id);
            self.decisions[first_decision + k].choice = Choice::New { landmark: id };
            if let Some(h) = &mut self.history {
                h.observe(id, zs[k]);
            }
        }
        self.finish_scan(t, clusters, assigned)
    }
}
