//! The landmarks' lifecycle: confirmation, deletion of tentative ones, retraction,
//! fusion of duplicates, relinearisation.

use super::*;

impl Pipeline {
    /// Retracts the landmarks whose place nearer frames judge not an object: a palm taken
    /// for a tree from 8-12 m, where the camera cannot tell its trunk from bark.
    pub(super) fn retract_landmarks(&mut self) {
        let (evidence, config) = (&self.evidence, &self.config.evidence);
        let gone = self.table.remove_where(&mut self.ekf, |_, place| {
            place.and_then(|p| evidence.judge(p)).is_some_and(|jd| jd.retracts(config))
        });
        let t = self.t;
        self.retractions.extend(gone.into_iter().map(|l| LandmarkRetraction { t, landmark: l.id }));
    }

    pub(super) fn refresh_landmarks(&mut self) -> Result<(), PipelineError> {
        // Confirm landmarks seen often enough; delete tentative ones that timed out.
        let (need, window, t) = (self.config.confirm_observations, self.config.confirm_window_s, self.t);
        self.table.confirm_and_expire(&mut self.ekf, need, window, t);
        if self.config.merge.enabled {
            self.merge_duplicates()?;
            self.prune_co_observed();
        }
        self.table.refresh(&self.ekf);
        Ok(())
    }

    /// Drops the co-observed pairs of landmarks no longer in the map, once the pairs have
    /// doubled since the last pruning: ids are never reused, so a gone landmark's pairs
    /// decide nothing, yet a long log's short-lived tentative landmarks would grow them
    /// without bound. Amortised O(1) a pair.
    fn prune_co_observed(&mut self) {
        if self.co_observed.len() <= 2 * self.co_observed_kept.max(4096) {
            return;
        }
        let live: HashSet<u32> = self.table.meta().iter().map(|l| l.id).collect();
        self.co_observed.retain(|(a, b)| live.contains(a) && live.contains(b));
        self.co_observed_kept = self.co_observed.len();
    }

    pub(super) fn note_co_observed(&mut self, assigned: &[Option<u32>]) {
        // Only fusion reads it.
        if !self.config.merge.enabled {
            return;
        }
        let ids: Vec<u32> = assigned.iter().flatten().copied().collect();
        for (k, &a) in ids.iter().enumerate() {
            for &b in &ids[k + 1..] {
                self.co_observed.insert((a.min(b), a.max(b)));
            }
        }
    }

    /// Fuses pairs of confirmed landmarks that are one object (see [`MergeConfig`]), the
    /// older one staying, until no pair qualifies. Models that cannot be compared, or a
    /// fusion the filter refuses, stop it with the error rather than leave the pair apart
    /// in silence.
    pub(super) fn merge_duplicates(&mut self) -> Result<(), PipelineError> {
        let cfg = self.config.merge.clone();
        let gate = chi2_quantile(2, self.config.gate_probability).expect(CHECKED_GATE);
        // Past the gate and the sigma bound, two positions are at most this far apart.
        let reach = gate.sqrt() * cfg.max_sigma_m * std::f64::consts::SQRT_2;
        loop {
            // Pairs of confirmed landmarks within reach, found by a sweep along x rather
            // than over all pairs (the map holds hundreds on a real log), then taken in
            // (i, j) order as a search over all pairs would meet them.
            let mut order: Vec<(f64, usize)> = (0..self.table.len())
                .filter(|&i| self.table.get(i).confirmed)
                .map(|i| (self.ekf.landmark(i).expect(MAPPED).x, i))
                .collect();
            order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let mut near = Vec::new();
            for (k, &(xa, a)) in order.iter().enumerate() {
                let la = self.ekf.landmark(a).expect(MAPPED);
                for &(xb, b) in &order[k + 1..] {
                    if xb - xa > reach {
                        break;
                    }
                    if (self.ekf.landmark(b).expect(MAPPED) - la).norm() <= reach {
                        near.push((a.min(b), a.max(b)));
                    }
                }
            }
            near.sort_unstable();
            let mut pair = None;
            for (i, j) in near {
                let (a, b) = (self.table.get(i).id, self.table.get(j).id);
                if self.co_observed.contains(&(a.min(b), a.max(b))) {
                    continue;
                }
                let (m2, c) = self.ekf.landmark_difference(i, j).expect(MAPPED);
                let widest = c.symmetric_eigenvalues().max();
                if m2 <= gate
                    && widest <= cfg.max_sigma_m * cfg.max_sigma_m
                    && self.look_alike(i, j).map_err(|source| PipelineError::Fusion {
                        t: self.t,
                        first: a,
                        second: b,
                        source,
                    })?
                {
                    pair = Some((i, j));
                    break;
                }
            }
            let Some((i, j)) = pair else { return Ok(()) };
            let gone = self
                .table
                .merge(&mut self.ekf, i, j, cfg.noise_sigma_m)
                .map_err(|source| PipelineError::Filter { t: self.t, source })?;
            let kept = self.table.get_mut(i);
            kept.diameter_m = (kept.diameter_m * kept.observations as f64 + gone.diameter_m * gone.observations as f64)
                / (kept.observations + gone.observations).max(1) as f64;
            kept.observations += gone.observations;
            // The fused landmark is never fused with what either was seen beside.
            let partners: Vec<u32> = self
                .co_observed
                .iter()
                .filter_map(|&(a, b)| {
                    if a == gone.id {
                        Some(b)
                    } else if b == gone.id {
                        Some(a)
                    } else {
                        None
                    }
                })
                .collect();
            let kept_id = kept.id;
            for p in partners {
                self.co_observed.insert((kept_id.min(p), kept_id.max(p)));
            }
            self.merges.push(LandmarkMerge { t: self.t, kept: kept_id, removed: gone.id });
            if let Some(h) = &mut self.history {
                h.relabel(gone.id, kept_id);
            }
        }
    }

    /// Solves the history again and gives the filter the result (see
    /// [`PipelineConfig::relinearise_loop_closures`]); a failed solve leaves the filter as
    /// it was.
    pub(super) fn relinearise(&mut self, before: &DVector<f64>) {
        let Some(history) = &mut self.history else { return };
        self.relinearised_at = self.t;
        let ids: Vec<u32> = self.table.meta().iter().map(|l| l.id).collect();
        let solved = history.relinearise(&mut self.ekf, before, &self.config.motion, &self.config.sensor, &ids, 10);
        self.relinearisations.push(solved);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cluster_at(range: f64, bearing: f64) -> Cluster {
        Cluster {
            first_beam: 0,
            last_beam: 3,
            points: vec![],
            centre: [range * bearing.cos(), range * bearing.sin()],
            diameter_m: 0.3,
            range_m: range,
            bearing_rad: bearing,
            occluded: false,
        }
    }

    /// Two landmarks, seen in one scan or in two, then landmark 1 moved to 2 cm from
    /// landmark 0 (as if a loop closure had pulled a duplicate onto its original).
    fn pair(seen_together: bool, extra_variance: f64, merge: bool) -> Pipeline {
        let merge = MergeConfig { enabled: merge, ..Default::default() };
        let config =
            PipelineConfig { method: AssociationMethod::Nn, confirm_observations: 1, merge, ..Default::default() };
        let mut p = Pipeline::new(config, [0.0; 3], None).unwrap();
        let (a, b) = (cluster_at(5.0, 0.0), cluster_at(5.0, 0.5));
        if seen_together {
            p.on_scan_with_objects(0.1, vec![a, b], &[true, true], "tree").unwrap();
        } else {
            p.on_scan_with_objects(0.1, vec![a], &[true], "tree").unwrap();
            p.on_scan_with_objects(0.2, vec![b], &[true], "tree").unwrap();
        }
        assert_eq!(p.landmarks().len(), 2);
        let (l0, l1) = (p.ekf.landmark_offset(), p.ekf.landmark_offset() + 2);
        p.ekf.x[l1] = p.ekf.x[l0] + 0.02;
        p.ekf.x[l1 + 1] = p.ekf.x[l0 + 1];
        p.ekf.p[(l1, l1)] += extra_variance;
        p.ekf.p[(l1 + 1, l1 + 1)] += extra_variance;
        p.refresh_landmarks().unwrap();
        p
    }

    #[test]
    fn a_duplicate_is_fused_into_the_older_landmark() {
        let p = pair(false, 0.0, true);
        assert_eq!(p.landmarks().len(), 1);
        assert_eq!(p.landmarks()[0].id, 0);
        assert_eq!(p.landmarks()[0].observations, 2);
        assert_eq!(p.merges, [LandmarkMerge { t: 0.2, kept: 0, removed: 1 }]);
        assert_eq!(p.ekf().landmark_count(), 1);
        let c = p.ekf().landmark_covariance(0).unwrap();
        assert!(c.symmetric_eigenvalues().min() > 0.0);
    }

    /// Two appearance-method landmarks about to be fused whose object models are of other
    /// feature spaces (7 and 5 dimensions): the fusion cannot compare them.
    #[test]
    fn landmarks_whose_models_cannot_be_compared_stop_fusion_with_an_error() {
        let mut p = pair(false, 0.0, false);
        assert_eq!(p.landmarks().len(), 2);
        let model = |dims: usize| ObjectModel {
            gmm: Gmm {
                components: vec![crate::gmm::Component {
                    weight: 1.0,
                    mean: DVector::zeros(dims),
                    covariance: DMatrix::identity(dims, dims),
                }],
            },
            patches: 20.0,
            observations: 1,
            mosaic: crate::object_model::MosaicView { cells: vec![], appearance: vec![], pixels: vec![] },
        };
        p.table.set_object(0, model(7));
        p.table.set_object(1, model(5));
        p.config.method = AssociationMethod::Combined;
        p.config.merge.enabled = true;
        let e = p.refresh_landmarks().unwrap_err();
        assert!(
            matches!(
                &e,
                PipelineError::Fusion {
                    first: 0,
                    second: 1,
                    source: ObjectModelError::Dimension { observation: 5, model: 7 },
                    ..
                }
            ),
            "{e:?}"
        );
        assert_eq!(p.landmarks().len(), 2, "nothing was fused");
        // Models of one feature space are compared, and these look alike: fused.
        p.table.set_object(1, model(7));
        p.refresh_landmarks().unwrap();
        assert_eq!(p.landmarks().len(), 1);
    }

    #[test]
    fn landmarks_seen_in_one_scan_are_never_fused() {
        let p = pair(true, 0.0, true);
        assert_eq!(p.landmarks().len(), 2);
        assert!(p.merges.is_empty());
    }

    /// Tentative landmarks that come and go leave no pairs behind: the pairs stay bounded
    /// by the live map, not by the log's length.
    #[test]
    fn pairs_of_landmarks_gone_are_dropped() {
        let config = PipelineConfig {
            method: AssociationMethod::Nn,
            confirm_observations: 3,
            confirm_window_s: 0.15,
            ..Default::default()
        };
        let mut p = Pipeline::new(config, [0.0; 3], None).unwrap();
        let mut most = 0;
        for k in 0..3000 {
            // Twenty objects each scan, 0.2 m from where the previous scan's were (many
            // sigmas of range noise): each is a new tentative landmark that expires.
            let range = 2.0 + (k % 50) as f64 * 0.2;
            let clusters: Vec<Cluster> = (0..20).map(|i| cluster_at(range, -1.0 + 0.1 * i as f64)).collect();
            p.on_scan_with_objects(0.1 * (k + 1) as f64, clusters, &[true; 20], "tree").unwrap();
            most = most.max(p.co_observed.len());
        }
        // The scans did make tens of thousands of landmarks (ids are never reused: 10 a
        // scan) ...
        let newest = p.table.meta().iter().map(|l| l.id).max().unwrap();
        assert!(newest >= 25_000, "newest id {newest}");
        // ... whose pairs would number 285,000 without the pruning.
        assert!(most <= 2 * 4096 + 190, "{most} pairs at most");
    }

    #[test]
    fn landmarks_too_uncertain_to_tell_apart_are_not_fused() {
        let p = pair(false, 0.5, true);
        assert_eq!(p.landmarks().len(), 2);
        // Disabled, a pair that would qualify stays apart too.
        let q = pair(false, 0.0, false);
        assert_eq!(q.landmarks().len(), 2);
        assert!(q.merges.is_empty());
    }
}
