//! Position-only nearest neighbour: each observation takes the landmark with the smallest
//! Mahalanobis distance if it is inside the gate; observations far from every landmark
//! start new ones; those in between are rejected as ambiguous.

use nalgebra::Vector2;

use crate::ekf::{Ekf, RangeBearingModel};

/// Result for one observation: `Some(i)` landmark index, or `None` with the smallest
/// squared distance seen (for the new-landmark rule).
#[derive(Debug, Clone, PartialEq)]
pub struct NnResult {
    pub landmark: Option<usize>,
    /// Squared Mahalanobis distances to every landmark (index order).
    pub distances: Vec<f64>,
}

/// Nearest neighbour with a chi-square gate on the squared Mahalanobis distance.
/// Observations are treated independently (two may take the same landmark).
pub fn nearest_neighbour(
    ekf: &Ekf,
    model: &RangeBearingModel,
    observations: &[Vector2<f64>],
    gate: f64,
) -> Vec<NnResult> {
    observations
        .iter()
        .map(|z| {
            let distances = ekf.mahalanobis2_to_all(model, z);
            let best = distances
                .iter()
                .enumerate()
                .filter(|(_, d)| **d < gate)
                .min_by(|a, b| a.1.total_cmp(b.1))
                .map(|(i, _)| i);
            NnResult { landmark: best, distances }
        })
        .collect()
}
