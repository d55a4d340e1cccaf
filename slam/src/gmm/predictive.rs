//! The predictive density of a VB-GMM: a mixture of Student-t (PRML 10.81), and the
//! moment-matched Gaussian mixture the classifier and the KL association use.

use nalgebra::{Cholesky, DMatrix, DVector, Dyn};
use statrs::function::gamma::ln_gamma;

use super::{Component, Gmm, GmmError, VbGmm};

/// One Student-t component: weight, location, precision matrix L and degrees of freedom.
#[derive(Debug, Clone)]
pub struct StudentT {
    pub weight: f64,
    pub mean: DVector<f64>,
    pub precision: DMatrix<f64>,
    pub dof: f64,
    chol: Cholesky<f64, Dyn>,
    log_norm: f64,
}

impl StudentT {
    /// ln St(x | mean, L, dof); a point of another dimension is [`GmmError::Dimension`].
    pub fn log_density(&self, x: &DVector<f64>) -> Result<f64, GmmError> {
        if x.len() != self.mean.len() {
            return Err(GmmError::Dimension { expected: self.mean.len(), found: x.len() });
        }
        Ok(self.log_density_prechecked(x))
    }

    fn log_density_prechecked(&self, x: &DVector<f64>) -> f64 {
        let d = self.mean.len() as f64;
        let dx = x - &self.mean;
        // dx^T L dx with L = U^T U from the Cholesky factor of L (L = C C^T).
        let y = self.chol.l().transpose() * &dx;
        let maha = y.norm_squared();
        if maha.is_finite() {
            return self.log_norm - 0.5 * (self.dof + d) * (maha / self.dof).ln_1p();
        }
        // A point so far out that its squared distance overflows: ln(1 + q) from ln q,
        // with q's square root taken apart from its scale, so the density stays finite.
        let scale = y.amax();
        let ln_q = 2.0 * (scale.ln() + (&y / scale).norm().ln()) - self.dof.ln();
        self.log_norm - 0.5 * (self.dof + d) * (ln_q + (-ln_q).exp().ln_1p())
    }
}

/// The predictive density p(x | data) = sum_k alpha_k / alpha_hat St(x | m_k, L_k, nu_k + 1 - D)
/// with L_k = ((nu_k + 1 - D) beta_k / (1 + beta_k)) W_k.
#[derive(Debug, Clone)]
pub struct StudentTMixture {
    pub components: Vec<StudentT>,
}

impl StudentTMixture {
    /// The predictive density of `model`; components whose mean or W^-1 is not of the
    /// prior's dimension, or a W^-1 that is not positive definite, are an error (a model
    /// read from a file passes [`VbGmm::check`] first, which checks its numbers too).
    pub fn new(model: &VbGmm) -> Result<Self, GmmError> {
        model.check_shapes()?;
        let d = model.dims();
        let df = d as f64;
        let weights = model.weights();
        let mut components = Vec::with_capacity(model.components.len());
        for (k, (c, weight)) in model.components.iter().zip(weights).enumerate() {
            let dof = c.nu + 1.0 - df;
            let w_chol = Cholesky::new(c.w_inv.clone()).ok_or(GmmError::NotPositiveDefinite { component: k })?;
            let w = w_chol.inverse();
            let precision = w * (dof * c.beta / (1.0 + c.beta));
            let precision = (&precision + precision.transpose()) * 0.5;
            let chol = Cholesky::new(precision.clone()).ok_or(GmmError::NotPositiveDefinite { component: k })?;
            let ln_det_l = 2.0 * chol.l_dirty().diagonal().iter().map(|v| v.ln()).sum::<f64>();
            let log_norm = ln_gamma((dof + df) / 2.0) - ln_gamma(dof / 2.0) + 0.5 * ln_det_l
                - 0.5 * df * (dof * std::f64::consts::PI).ln();
            components.push(StudentT {
                weight: w_weight(weight),
                mean: c.mean.clone(),
                precision,
                dof,
                chol,
                log_norm,
            });
        }
        Ok(StudentTMixture { components })
    }

    /// ln p(x | data), by log-sum-exp over the components; a point of another dimension
    /// is [`GmmError::Dimension`].
    pub fn log_density(&self, x: &DVector<f64>) -> Result<f64, GmmError> {
        let terms = self.components.iter().map(|c| Ok(c.weight.ln() + c.log_density(x)?));
        Ok(super::log_sum_exp(&terms.collect::<Result<Vec<f64>, GmmError>>()?))
    }

    /// The moment-matched Gaussian mixture: each Student-t becomes a Gaussian with its
    /// covariance L^-1 dof / (dof - 2) (for dof <= 2, where the covariance is infinite, L^-1).
    pub fn gaussian_approximation(&self) -> Result<Gmm, GmmError> {
        let mut components = Vec::with_capacity(self.components.len());
        for c in &self.components {
            let scale = if c.dof > 2.0 { c.dof / (c.dof - 2.0) } else { 1.0 };
            let cov = c.chol.inverse() * scale;
            components.push(Component {
                weight: c.weight,
                mean: c.mean.clone(),
                covariance: (&cov + cov.transpose()) * 0.5,
            });
        }
        Ok(Gmm { components })
    }
}

/// Keeps weights strictly positive so their logarithms stay finite.
fn w_weight(w: f64) -> f64 {
    w.max(f64::MIN_POSITIVE)
}
