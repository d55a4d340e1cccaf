//! Gaussian mixture models: the plain density ([`Gmm`]) shared by the classifier, the object
//! models and the KL association, and (in submodules) its variational Bayesian learning.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

/// One Gaussian component of a mixture: weight `pi_s`, mean `mu_s`, covariance `Gamma_s`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Component {
    pub weight: f64,
    pub mean: DVector<f64>,
    pub covariance: DMatrix<f64>,
}

/// A Gaussian mixture density (paper eq. 1). Weights sum to one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Gmm {
    pub components: Vec<Component>,
}

impl Gmm {
    /// Dimension of the space the mixture lives in (0 for an empty mixture).
    pub fn dims(&self) -> usize {
        self.components.first().map_or(0, |c| c.mean.len())
    }
}
