//! The pipeline's records of its landmarks, kept index-aligned with the filter's: entry j
//! of the table belongs to the filter's landmark j. Every landmark enters and leaves the
//! filter through this table, so the alignment is kept in one place.

use nalgebra::Vector2;

use super::records::Landmark;
use crate::ekf::{Ekf, EkfError, RangeBearingModel};
use crate::object_model::ObjectModel;

/// A landmark to start from an observation.
pub(super) struct NewLandmark<'a> {
    /// The observation (range, bearing) that places it.
    pub z: Vector2<f64>,
    pub class: &'a str,
    pub diameter_m: f64,
    /// Where later camera frames may judge it (odometry frame); see `Pipeline::places`.
    pub place: Option<[f64; 2]>,
}

/// Per landmark: what the pipeline knows of it, its object model (appearance methods) and
/// its evidence place (odometry frame) of its latest camera observation.
#[derive(Clone, Default)]
pub(super) struct LandmarkTable {
    meta: Vec<Landmark>,
    objects: Vec<Option<ObjectModel>>,
    places: Vec<Option<[f64; 2]>>,
    /// Id of the next landmark (ids are never reused after a tentative one is deleted).
    next_id: u32,
}

impl LandmarkTable {
    pub fn len(&self) -> usize {
        self.meta.len()
    }

    /// Every landmark, tentative ones included, in the filter's order.
    pub fn meta(&self) -> &[Landmark] {
        &self.meta
    }

    pub fn get(&self, j: usize) -> &Landmark {
        &self.meta[j]
    }

    pub fn get_mut(&mut self, j: usize) -> &mut Landmark {
        &mut self.meta[j]
    }

    pub fn object(&self, j: usize) -> Option<&ObjectModel> {
        self.objects[j].as_ref()
    }

    pub fn object_mut(&mut self, j: usize) -> Option<&mut ObjectModel> {
        self.objects[j].as_mut()
    }

    pub fn set_object(&mut self, j: usize, object: ObjectModel) {
        self.objects[j] = Some(object);
    }

    pub fn set_place(&mut self, j: usize, place: [f64; 2]) {
        self.places[j] = Some(place);
    }

    /// The filter index of landmark `id`.
    pub fn index_of(&self, id: u32) -> Option<usize> {
        self.meta.iter().position(|l| l.id == id)
    }

    /// Starts landmarks at `new` in the filter (in one augmentation when `together`, else
    /// one by one) and in the table, under fresh ids; a landmark is confirmed at once when
    /// one observation confirms. Returns each one's (id, filter index).
    pub fn add(
        &mut self,
        ekf: &mut Ekf,
        sensor: &RangeBearingModel,
        t: f64,
        new: &[NewLandmark],
        together: bool,
        confirm_observations: usize,
    ) -> Vec<(u32, usize)> {
        // The pipeline refuses observations that are not finite before any association.
        const FINITE: &str = "the pipeline adds only observations it has checked finite";
        if together {
            let zs: Vec<Vector2<f64>> = new.iter().map(|n| n.z).collect();
            ekf.add_landmarks(sensor, &zs).expect(FINITE);
        } else {
            for n in new {
                ekf.add_landmark(sensor, &n.z).expect(FINITE);
            }
        }
        let added = new
            .iter()
            .map(|n| {
                let id = self.next_id;
                self.next_id += 1;
                self.meta.push(Landmark {
                    id,
                    position: [0.0; 2],
                    covariance: [[0.0; 2]; 2],
                    class: n.class.to_string(),
                    observations: 1,
                    diameter_m: n.diameter_m,
                    created_t: t,
                    confirmed: confirm_observations <= 1,
                });
                self.objects.push(None);
                self.places.push(n.place);
                (id, self.meta.len() - 1)
            })
            .collect();
        self.check(ekf);
        added
    }

    /// Takes landmark `j` out of the filter and the table.
    pub fn remove(&mut self, ekf: &mut Ekf, j: usize) -> Landmark {
        ekf.remove_landmark(j).expect(super::MAPPED);
        self.forget(j, ekf)
    }

    /// Fuses landmark `j` into `i` in the filter (see [`Ekf::merge_landmarks`]) and takes
    /// `j` out of the table; returns it. The filter refusing leaves both as they were.
    pub fn merge(&mut self, ekf: &mut Ekf, i: usize, j: usize, noise_sigma_m: f64) -> Result<Landmark, EkfError> {
        ekf.merge_landmarks(i, j, noise_sigma_m)?;
        Ok(self.forget(j, ekf))
    }

    /// Removes, from the filter and the table, every landmark for which `gone(landmark,
    /// place)` holds; returns them in their former order.
    pub fn remove_where(&mut self, ekf: &mut Ekf, gone: impl Fn(&Landmark, Option<[f64; 2]>) -> bool) -> Vec<Landmark> {
        let mut removed = Vec::new();
        let mut j = 0;
        while j < self.meta.len() {
            if gone(&self.meta[j], self.places[j]) {
                removed.push(self.remove(ekf, j));
            } else {
                j += 1;
            }
        }
        removed
    }

    /// Confirms the landmarks seen at least `need` times, then deletes the tentative ones
    /// older than `window_s` at `t`.
    pub fn confirm_and_expire(&mut self, ekf: &mut Ekf, need: usize, window_s: f64, t: f64) {
        for lm in &mut self.meta {
            if !lm.confirmed && lm.observations >= need {
                lm.confirmed = true;
            }
        }
        self.remove_where(ekf, |lm, _| !lm.confirmed && t - lm.created_t > window_s);
    }

    /// Copies the filter's positions and covariances into the landmarks' records.
    pub fn refresh(&mut self, ekf: &Ekf) {
        for (i, lm) in self.meta.iter_mut().enumerate() {
            let p = ekf.landmark(i).expect(super::MAPPED);
            let c = ekf.landmark_covariance(i).expect(super::MAPPED);
            lm.position = [p.x, p.y];
            lm.covariance = [[c[(0, 0)], c[(0, 1)]], [c[(1, 0)], c[(1, 1)]]];
        }
    }

    /// Drops entry `j`, which the filter has just let go of.
    fn forget(&mut self, j: usize, ekf: &Ekf) -> Landmark {
        self.objects.remove(j);
        self.places.remove(j);
        let gone = self.meta.remove(j);
        self.check(ekf);
        gone
    }

    fn check(&self, ekf: &Ekf) {
        debug_assert_eq!(ekf.landmark_count(), self.meta.len(), "the table and the filter disagree");
        debug_assert!(self.objects.len() == self.meta.len() && self.places.len() == self.meta.len());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Vector3};

    fn filter() -> (Ekf, RangeBearingModel) {
        (Ekf::new(Vector3::zeros(), Matrix3::identity() * 1e-4), RangeBearingModel::default())
    }

    fn at(range: f64, bearing: f64) -> NewLandmark<'static> {
        NewLandmark { z: Vector2::new(range, bearing), class: "tree", diameter_m: 0.3, place: Some([range, 0.0]) }
    }

    /// Every removal path leaves entry j describing the filter's landmark j.
    #[test]
    fn removals_keep_the_table_aligned_with_the_filter() {
        let (mut ekf, sensor) = filter();
        let mut table = LandmarkTable::default();
        let added = table.add(&mut ekf, &sensor, 0.0, &[at(5.0, 0.0), at(6.0, 1.0), at(7.0, -1.0)], true, 2);
        assert_eq!(added, [(0, 0), (1, 1), (2, 2)]);
        assert!(table.meta().iter().all(|l| !l.confirmed));
        let seven = ekf.landmark(2).unwrap();
        let gone = table.remove(&mut ekf, 1);
        assert_eq!(gone.id, 1);
        assert_eq!(table.index_of(2), Some(1));
        assert_eq!(ekf.landmark_count(), 2);
        // The record at index 1 is the filter's landmark 1: the one observed at 7 m.
        assert_eq!(ekf.landmark(1).unwrap(), seven);
        assert_eq!(table.places[1], Some([7.0, 0.0]));
        // Ids are never reused.
        let again = table.add(&mut ekf, &sensor, 1.0, &[at(8.0, 0.5)], false, 2);
        assert_eq!(again, [(3, 2)]);
        let eight = ekf.landmark(2).unwrap();
        table.get_mut(0).observations = 2;
        table.confirm_and_expire(&mut ekf, 2, 0.5, 1.2);
        // Landmark 0 was confirmed; landmark 2 (from t = 0) timed out; landmark 3 is young.
        let ids: Vec<u32> = table.meta().iter().map(|l| l.id).collect();
        assert_eq!(ids, [0, 3]);
        assert!(table.get(0).confirmed);
        assert_eq!(ekf.landmark_count(), 2);
        assert_eq!(ekf.landmark(1).unwrap(), eight);
        table.refresh(&ekf);
        assert_eq!(table.get(1).position, [eight.x, eight.y]);
        let fused = table.merge(&mut ekf, 0, 1, 0.05).unwrap();
        assert_eq!((fused.id, table.len(), ekf.landmark_count()), (3, 1, 1));
        assert!(table.merge(&mut ekf, 0, 0, 0.05).is_err());
        assert_eq!(table.len(), 1);
    }

    /// Landmarks added together or one by one give the same filter and the same table; a
    /// removal by place (a retraction) takes the right one out of both.
    #[test]
    fn adding_together_or_one_by_one_agrees_and_removal_by_place_keeps_alignment() {
        let new = [at(5.0, 0.0), at(6.0, 1.0), at(7.0, -1.0)];
        let (mut together, sensor) = filter();
        let mut a = LandmarkTable::default();
        a.add(&mut together, &sensor, 0.0, &new, true, 1);
        let (mut singly, _) = filter();
        let mut b = LandmarkTable::default();
        b.add(&mut singly, &sensor, 0.0, &new, false, 1);
        assert_eq!(a.meta(), b.meta());
        assert!((&together.x - &singly.x).amax() < 1e-12 && (&together.p - &singly.p).amax() < 1e-12);
        assert!(a.meta().iter().all(|l| l.confirmed), "one observation confirms");
        let seven = together.landmark(2).unwrap();
        let gone = a.remove_where(&mut together, |_, place| place == Some([6.0, 0.0]));
        assert_eq!(gone.iter().map(|l| l.id).collect::<Vec<_>>(), [1]);
        assert_eq!((a.len(), together.landmark_count()), (2, 2));
        assert_eq!((a.index_of(2), together.landmark(1).unwrap()), (Some(1), seven));
        assert_eq!(a.places[1], Some([7.0, 0.0]));
    }
}
