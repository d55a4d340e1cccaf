//! Gaussian mixture models: the plain density ([`Gmm`]) shared by the classifier, the object
//! models and the KL association; its variational Bayesian learning ([`vbem`], with the
//! model search in [`search`]); and the Student-t predictive density ([`predictive`]).
//!
//! ```
//! use nalgebra::DMatrix;
//! use slam::gmm::{fit, VbOptions};
//! // Two well separated 1-D clusters.
//! let data = DMatrix::from_fn(200, 1, |i, _| if i % 2 == 0 { (i % 7) as f64 * 0.1 } else { 10.0 + (i % 5) as f64 * 0.1 });
//! let model = fit(&data, None, &VbOptions::default()).unwrap();
//! assert_eq!(model.effective_components(0.01), 2);
//! ```

pub mod bench_data;
mod packed;
pub mod predictive;
pub mod search;
pub mod vbem;

use nalgebra::{Cholesky, DMatrix, DVector};
use serde::{Deserialize, Serialize};

pub use predictive::{StudentT, StudentTMixture};
pub use search::{Search, VbGmm, VbOptions, fit, fit_with_history};
pub use vbem::{VbComponent, VbPrior};

/// What can go wrong fitting or evaluating a mixture.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum GmmError {
    #[error("no data: a mixture needs at least one point with at least one dimension")]
    NoData,
    #[error("data value at row {row}, column {column} is not a finite number")]
    NotFinite { row: usize, column: usize },
    #[error(
        "data values of column {column} (up to {largest:e} in size) are too large: their squares and distances overflow; rescale the data"
    )]
    TooLarge { column: usize, largest: f64 },
    #[error(
        "data values of column {column} differ by at most {range:e}: the squares of their differences underflow; rescale the data"
    )]
    TooSmall { column: usize, range: f64 },
    #[error("dimension mismatch: expected {expected}, found {found}")]
    Dimension { expected: usize, found: usize },
    /// A buffer for per-component terms that holds fewer slots than the mixture has
    /// components.
    #[error("{slots} slots for the terms of a mixture of {components} components")]
    TermSlots { slots: usize, components: usize },
    #[error("component {component}: a {rows}x{cols} covariance for a mean of {dims} dimensions")]
    CovarianceShape { component: usize, dims: usize, rows: usize, cols: usize },
    #[error("bad prior: {0}")]
    BadPrior(String),
    #[error("bad options: {0}")]
    BadOptions(String),
    #[error("bad model: {0}")]
    BadModel(String),
    #[error("the mixture has no components")]
    EmptyModel,
    #[error("component {component}: matrix is not positive definite")]
    NotPositiveDefinite { component: usize },
    #[error("numerical failure: {0}")]
    Numerical(String),
}

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

    /// [`GmmError::Dimension`] or [`GmmError::CovarianceShape`] unless every component has
    /// a mean of the mixture's dimension D and a D x D covariance.
    pub fn check_shapes(&self) -> Result<(), GmmError> {
        let d = self.dims();
        for (k, c) in self.components.iter().enumerate() {
            if c.mean.len() != d {
                return Err(GmmError::Dimension { expected: d, found: c.mean.len() });
            }
            if c.covariance.shape() != (d, d) {
                let (rows, cols) = c.covariance.shape();
                return Err(GmmError::CovarianceShape { component: k, dims: d, rows, cols });
            }
        }
        Ok(())
    }

    /// Mean and covariance of the whole mixture; components of other shapes are an error
    /// ([`Gmm::check_shapes`]).
    pub fn moments(&self) -> Result<(DVector<f64>, DMatrix<f64>), GmmError> {
        self.check_shapes()?;
        let d = self.dims();
        let total: f64 = self.components.iter().map(|c| c.weight).sum();
        let mut mean = DVector::zeros(d);
        for c in &self.components {
            mean += &c.mean * (c.weight / total);
        }
        let mut cov = DMatrix::zeros(d, d);
        for c in &self.components {
            let dm = &c.mean - &mean;
            cov += (&c.covariance + &dm * dm.transpose()) * (c.weight / total);
        }
        Ok((mean, cov))
    }

    /// Prepares the mixture for fast repeated density evaluation.
    pub fn evaluator(&self) -> Result<GmmEvaluator, GmmError> {
        GmmEvaluator::new(self)
    }
}

/// A mixture with each component's Cholesky-whitening matrix and log normaliser, for
/// evaluating ln p(x) at many points.
#[derive(Debug, Clone)]
pub struct GmmEvaluator {
    dims: usize,
    /// Per component: ln w - D/2 ln 2 pi - 1/2 ln |Gamma|.
    log_norm: Vec<f64>,
    /// Per component its mean, D values, one after the other.
    means: Vec<f64>,
    /// Per component C^-1 with C C^T = Gamma (|C^-1 (x - mu)|^2 is the Mahalanobis
    /// distance), its lower triangle packed row by row: D (D + 1) / 2 values. Packed so the
    /// inner loop, which runs for every patch of every frame, reads memory in order.
    whiten: Vec<f64>,
}

/// Dimensions up to which a point's offsets from a mean are kept on the stack (beyond, in
/// a vector made for the call): the features are 10-20 dimensions.
const STACK_DIMS: usize = 64;

impl GmmEvaluator {
    pub fn new(g: &Gmm) -> Result<Self, GmmError> {
        if g.components.is_empty() {
            return Err(GmmError::EmptyModel);
        }
        g.check_shapes()?;
        let d = g.dims();
        let mut out = GmmEvaluator { dims: d, log_norm: vec![], means: vec![], whiten: vec![] };
        for (k, c) in g.components.iter().enumerate() {
            if !(c.weight.is_finite() && c.weight >= 0.0) || !c.mean.iter().all(|v| v.is_finite()) {
                return Err(GmmError::BadModel(format!(
                    "component {k}: its weight ({}) must be finite and not negative, and its mean finite",
                    c.weight
                )));
            }
            let chol = Cholesky::new(c.covariance.clone()).ok_or(GmmError::NotPositiveDefinite { component: k })?;
            let ln_det = 2.0 * chol.l_dirty().diagonal().iter().map(|v| v.ln()).sum::<f64>();
            let whiten = chol
                .l()
                .solve_lower_triangular(&DMatrix::identity(d, d))
                .ok_or(GmmError::NotPositiveDefinite { component: k })?;
            out.log_norm.push(
                c.weight.max(f64::MIN_POSITIVE).ln()
                    - 0.5 * d as f64 * (2.0 * std::f64::consts::PI).ln()
                    - 0.5 * ln_det,
            );
            out.means.extend(c.mean.iter());
            for i in 0..d {
                out.whiten.extend((0..=i).map(|j| whiten[(i, j)]));
            }
        }
        // All weights zero (each checked above) would make every density the floor used
        // for a zero weight, silently: no mixture.
        if !g.components.iter().any(|c| c.weight > 0.0) {
            return Err(GmmError::BadModel("every component's weight is zero".into()));
        }
        Ok(out)
    }

    pub fn dims(&self) -> usize {
        self.dims
    }

    /// Number of components.
    pub fn component_count(&self) -> usize {
        self.log_norm.len()
    }

    /// Per component c, ln (w_c N(x; mu_c, Gamma_c)), written to `terms` (one per
    /// component); `x` has length D. Their log-sum-exp is ln p(x), and
    /// exp(terms[c] - ln p(x)) the responsibility of component c. A point that is not D
    /// long, or fewer slots than components, is [`GmmError::Dimension`] or
    /// [`GmmError::TermSlots`].
    pub fn log_terms(&self, x: &[f64], terms: &mut [f64]) -> Result<(), GmmError> {
        self.check_shape(x.len(), terms.len())?;
        self.log_terms_prechecked(x, terms);
        Ok(())
    }

    /// A point of `dims` coordinates and `slots` term slots, or the error that says which
    /// does not fit the mixture.
    fn check_shape(&self, dims: usize, slots: usize) -> Result<(), GmmError> {
        if dims != self.dims {
            return Err(GmmError::Dimension { expected: self.dims, found: dims });
        }
        if slots < self.component_count() {
            return Err(GmmError::TermSlots { slots, components: self.component_count() });
        }
        Ok(())
    }

    /// [`GmmEvaluator::log_terms`] where the caller has checked the shapes.
    pub(crate) fn log_terms_prechecked(&self, x: &[f64], terms: &mut [f64]) {
        let d = self.dims;
        let packed = d * (d + 1) / 2;
        let mut diff = [0.0f64; STACK_DIMS];
        let mut heap = Vec::new();
        let diff: &mut [f64] = if d <= diff.len() {
            &mut diff[..d]
        } else {
            heap.resize(d, 0.0);
            &mut heap
        };
        for (c, slot) in terms.iter_mut().enumerate().take(self.component_count()) {
            for ((v, xj), mj) in diff.iter_mut().zip(x).zip(&self.means[c * d..(c + 1) * d]) {
                *v = xj - mj;
            }
            let w = &self.whiten[c * packed..(c + 1) * packed];
            let mut maha = 0.0;
            let mut start = 0;
            for i in 0..d {
                let row = &w[start..start + i + 1];
                let mut y = 0.0;
                for (wij, dj) in row.iter().zip(diff.iter()) {
                    y += wij * dj;
                }
                maha += y * y;
                start += i + 1;
            }
            *slot = self.log_norm[c] - 0.5 * maha;
        }
    }

    /// [`GmmEvaluator::log_terms`] of `LANES` points at once: `x[j][l]` is coordinate j of
    /// point l, `terms[c][l]` gets component c's term for point l. Each point's sums run
    /// in the same order as in `log_terms`, so the values are identical; the points side by
    /// side let the compiler use SIMD across them instead of one long chain of dependent
    /// additions per point. Shapes are checked as in `log_terms`.
    pub fn log_terms_lanes<const LANES: usize>(
        &self,
        x: &[[f64; LANES]],
        terms: &mut [[f64; LANES]],
    ) -> Result<(), GmmError> {
        self.check_shape(x.len(), terms.len())?;
        self.log_terms_lanes_prechecked(x, terms);
        Ok(())
    }

    /// [`GmmEvaluator::log_terms_lanes`] where the caller has checked the shapes.
    pub(crate) fn log_terms_lanes_prechecked<const LANES: usize>(
        &self,
        x: &[[f64; LANES]],
        terms: &mut [[f64; LANES]],
    ) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx") {
            // SAFETY: the processor has AVX, checked just above.
            return unsafe { self.log_terms_lanes_avx(x, terms) };
        }
        self.log_terms_lanes_body(x, terms)
    }

    /// The same loops compiled for AVX: the classifier's four lanes of f64 fill one
    /// register, where the baseline x86-64 target needs two. Without FMA every product and
    /// sum is rounded as in the baseline code, so the values are identical on every x86-64
    /// processor.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    unsafe fn log_terms_lanes_avx<const LANES: usize>(&self, x: &[[f64; LANES]], terms: &mut [[f64; LANES]]) {
        self.log_terms_lanes_body(x, terms)
    }

    #[inline(always)]
    fn log_terms_lanes_body<const LANES: usize>(&self, x: &[[f64; LANES]], terms: &mut [[f64; LANES]]) {
        let d = self.dims;
        let packed = d * (d + 1) / 2;
        // The points' offsets from a mean.
        let mut stack = [[0.0f64; LANES]; STACK_DIMS];
        let mut heap = Vec::new();
        let diff: &mut [[f64; LANES]] = if d <= stack.len() {
            &mut stack[..d]
        } else {
            heap.resize(d, [0.0f64; LANES]);
            &mut heap
        };
        for (c, slot) in terms.iter_mut().enumerate().take(self.component_count()) {
            for ((v, xj), mj) in diff.iter_mut().zip(x).zip(&self.means[c * d..(c + 1) * d]) {
                for l in 0..LANES {
                    v[l] = xj[l] - mj;
                }
            }
            let w = &self.whiten[c * packed..(c + 1) * packed];
            let mut maha = [0.0f64; LANES];
            let mut start = 0;
            for i in 0..d {
                let row = &w[start..start + i + 1];
                let mut y = [0.0f64; LANES];
                for (wij, dj) in row.iter().zip(diff.iter()) {
                    for l in 0..LANES {
                        y[l] += wij * dj[l];
                    }
                }
                for l in 0..LANES {
                    maha[l] += y[l] * y[l];
                }
                start += i + 1;
            }
            for l in 0..LANES {
                slot[l] = self.log_norm[c] - 0.5 * maha[l];
            }
        }
    }

    /// ln p(x) for one point given as a slice of length D; a point of another length (of
    /// another feature space) is [`GmmError::Dimension`].
    pub fn log_density(&self, x: &[f64]) -> Result<f64, GmmError> {
        self.check_shape(x.len(), self.component_count())?;
        Ok(self.log_density_prechecked(x))
    }

    /// [`GmmEvaluator::log_density`] of a point the caller has checked is D long.
    pub(crate) fn log_density_prechecked(&self, x: &[f64]) -> f64 {
        let mut terms = [0.0f64; 64];
        let mut heap = Vec::new();
        let k = self.component_count();
        let buf: &mut [f64] = if k <= terms.len() {
            &mut terms[..k]
        } else {
            heap.resize(k, 0.0);
            &mut heap
        };
        self.log_terms_prechecked(x, buf);
        log_sum_exp(buf)
    }
}

/// ln sum exp(v), stable for large negative values; -inf for an empty slice.
pub fn log_sum_exp(v: &[f64]) -> f64 {
    let mx = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !mx.is_finite() {
        return mx;
    }
    mx + v.iter().map(|x| (x - mx).exp()).sum::<f64>().ln()
}

#[cfg(test)]
mod tests;
