//! One run of variational Bayesian EM for a full-covariance Gaussian mixture with a fixed
//! set of components (PRML 10.2). The model search over the number of components lives in
//! [`super::search`].
//!
//! Priors: Dirichlet(alpha0) on the weights (the paper's lambda_0), Wishart(W0, nu0) on the
//! precisions (the paper's B_0 = W0^-1 and alpha_0 = nu0), Normal(m0, (beta0 Lambda)^-1) on
//! the means. The lower bound is the full PRML 10.70, constants included, so bounds of fits
//! with different numbers of components compare directly.

use nalgebra::{Cholesky, DMatrix, DVector, Dyn};
use serde::{Deserialize, Serialize};
use statrs::function::gamma::{digamma, ln_gamma};

use super::GmmError;

pub(crate) const LN_2PI: f64 = 1.837_877_066_409_345_5;
const LN_PI: f64 = 1.144_729_885_849_400_2;

/// The conjugate prior of the mixture (paper eq. 3; docs/design.md, paper symbols).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VbPrior {
    /// Symmetric Dirichlet concentration on the weights (paper lambda_0).
    pub alpha0: f64,
    /// Scale of the mean's precision relative to the component precision.
    pub beta0: f64,
    /// Wishart degrees of freedom (paper alpha_0); must exceed D - 1.
    pub nu0: f64,
    /// Prior mean of every component.
    pub m0: DVector<f64>,
    /// Inverse Wishart scale W0^-1 (paper B_0): roughly nu0 times the expected covariance.
    pub w0_inv: DMatrix<f64>,
}

impl VbPrior {
    /// The default prior for `data` (rows are points): alpha0 = 1, beta0 = 1, nu0 = D,
    /// m0 = the data mean, W0^-1 = the data covariance plus a small ridge (so duplicate or
    /// collinear points still give a positive definite scale). The same choice as
    /// scikit-learn's BayesianGaussianMixture apart from alpha0 (the paper's symmetric
    /// Dirichlet with lambda_0 = 1 rather than 1/K).
    pub fn from_data(data: &DMatrix<f64>) -> Result<VbPrior, GmmError> {
        check_data(data)?;
        let (n, d) = data.shape();
        let mean = DVector::from_iterator(d, data.column_iter().map(|c| c.sum() / n as f64));
        let mut cov = DMatrix::zeros(d, d);
        for i in 0..d {
            let ci = data.column(i).add_scalar(-mean[i]);
            for j in 0..=i {
                let cj = data.column(j).add_scalar(-mean[j]);
                let v = ci.dot(&cj) / n as f64;
                cov[(i, j)] = v;
                cov[(j, i)] = v;
            }
        }
        let scale = cov.trace() / d as f64;
        let ridge = if scale > 0.0 { 1e-6 * scale } else { 1e-6 * (1.0 + mean.norm_squared() / d as f64) };
        for i in 0..d {
            cov[(i, i)] += ridge;
        }
        Ok(VbPrior { alpha0: 1.0, beta0: 1.0, nu0: d as f64, m0: mean, w0_inv: cov })
    }

    /// A prior taken from another model (the paper's footnote 2): its overall mean and
    /// covariance, with `nu0` degrees of freedom of confidence.
    pub fn from_gmm(g: &super::Gmm, nu0: f64) -> Result<VbPrior, GmmError> {
        let d = g.dims();
        if d == 0 {
            return Err(GmmError::EmptyModel);
        }
        let (mean, cov) = g.moments()?;
        let prior = VbPrior { alpha0: 1.0, beta0: 1.0, nu0, m0: mean, w0_inv: cov * nu0.max(d as f64) / d as f64 };
        prior.check(d)?;
        Ok(prior)
    }

    pub fn dims(&self) -> usize {
        self.m0.len()
    }

    /// Checks that the prior is proper for data of dimension `d`.
    pub fn check(&self, d: usize) -> Result<(), GmmError> {
        if self.m0.len() != d {
            return Err(GmmError::Dimension { expected: d, found: self.m0.len() });
        }
        if self.w0_inv.shape() != (d, d) {
            let (rows, cols) = self.w0_inv.shape();
            return Err(GmmError::BadPrior(format!("W0^-1 is {rows} x {cols}; m0 has {d} dimensions")));
        }
        if !(self.alpha0 > 0.0 && self.beta0 > 0.0 && self.alpha0.is_finite() && self.beta0.is_finite()) {
            return Err(GmmError::BadPrior("alpha0 and beta0 must be positive".into()));
        }
        if !(self.nu0 > d as f64 - 1.0) || !self.nu0.is_finite() {
            return Err(GmmError::BadPrior(format!("nu0 = {} must exceed D - 1 = {}", self.nu0, d as f64 - 1.0)));
        }
        if self.m0.iter().chain(self.w0_inv.iter()).any(|v| !v.is_finite()) {
            return Err(GmmError::BadPrior("m0 and W0^-1 must be finite".into()));
        }
        if Cholesky::new(self.w0_inv.clone()).is_none() {
            return Err(GmmError::BadPrior("W0^-1 is not positive definite".into()));
        }
        Ok(())
    }
}

/// The variational posterior of one component: Dirichlet count `alpha`, mean precision
/// scale `beta`, mean `mean` (m_k), Wishart dof `nu` and inverse scale `w_inv` (W_k^-1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VbComponent {
    pub alpha: f64,
    pub beta: f64,
    pub nu: f64,
    pub mean: DVector<f64>,
    pub w_inv: DMatrix<f64>,
}

/// Responsibility-weighted statistics of the data for each component.
#[derive(Debug, Clone)]
pub(crate) struct Stats {
    pub nk: Vec<f64>,
    pub xbar: Vec<DVector<f64>>,
    pub s: Vec<DMatrix<f64>>,
    /// sum_n r_nk ln r_nk per component (the entropy term of q(Z)).
    pub r_ln_r: Vec<f64>,
}

/// Validates a data matrix: at least one point, at least one dimension, all finite, and
/// small enough that the fit's sums stay finite: every point's squared distance to every
/// other, summed over the points (k-means++ draws its seeds from such a sum), is at most
/// N times the squared extent of the data's bounding box, and each column's sum of
/// squares must be finite too. Values near 1e154 break this, fewer the more points.
pub(crate) fn check_data(data: &DMatrix<f64>) -> Result<(), GmmError> {
    if data.nrows() == 0 || data.ncols() == 0 {
        return Err(GmmError::NoData);
    }
    if let Some(pos) = data.iter().position(|v| !v.is_finite()) {
        let n = data.nrows();
        return Err(GmmError::NotFinite { row: pos % n, column: pos / n });
    }
    let n = data.nrows() as f64;
    let mut extent2 = 0.0;
    for (column, values) in data.column_iter().enumerate() {
        let sum_of_squares: f64 = values.iter().map(|v| v * v).sum();
        let range = values.max() - values.min();
        extent2 += range * range;
        if !(sum_of_squares.is_finite() && (n * extent2).is_finite()) {
            let largest = values.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            return Err(GmmError::TooLarge { column, largest });
        }
    }
    Ok(())
}

/// Refuses data to fit whose values differ, but by so little that the squares of their
/// differences underflow: the covariances would be the prior's alone, and the bound that
/// of other data. (Scored data need no spread.)
pub(crate) fn check_spread(data: &DMatrix<f64>) -> Result<(), GmmError> {
    for (column, values) in data.column_iter().enumerate() {
        let range = values.max() - values.min();
        if range > 0.0 && range * range < f64::MIN_POSITIVE {
            return Err(GmmError::TooSmall { column, range });
        }
    }
    Ok(())
}

/// Below this many responsibilities (N x K) a step runs on one thread: the online
/// phase's small per-observation fits would only pay the threads' overhead.
const PARALLEL_MIN_CELLS: usize = 1 << 16;

/// Whether a step over N points and K components is large enough for rayon's threads.
pub(crate) fn runs_in_parallel(n: usize, k: usize) -> bool {
    n * k >= PARALLEL_MIN_CELLS
}

/// Runs `f` for every component, on rayon's threads for large data. Components are
/// independent and each is computed the same way on any thread, so the results do not
/// depend on the thread count.
pub(crate) fn per_component<T: Send>(n: usize, k: usize, f: impl Fn(usize) -> T + Sync + Send) -> Vec<T> {
    use rayon::prelude::*;
    if runs_in_parallel(n, k) { (0..k).into_par_iter().map(f).collect() } else { (0..k).map(f).collect() }
}

/// M-step: sufficient statistics from responsibilities `r` (N x K), then the posterior.
pub(crate) fn m_step(data: &DMatrix<f64>, r: &DMatrix<f64>, prior: &VbPrior) -> (Vec<VbComponent>, Stats) {
    let (n, _) = data.shape();
    let k = r.ncols();
    collect(per_component(n, k, |kk| m_step_component(data, r, prior, kk)))
}

/// One component's M-step result: its posterior, N_k, xbar_k, S_k and sum r ln r.
pub(crate) type ComponentStep = (VbComponent, f64, DVector<f64>, DMatrix<f64>, f64);

/// The components' posteriors and the statistics, from the per-component results.
pub(crate) fn collect(per: Vec<ComponentStep>) -> (Vec<VbComponent>, Stats) {
    let k = per.len();
    let mut stats = Stats {
        nk: Vec::with_capacity(k),
        xbar: Vec::with_capacity(k),
        s: Vec::with_capacity(k),
        r_ln_r: Vec::with_capacity(k),
    };
    let mut comps = Vec::with_capacity(k);
    for (comp, nk, xbar, s, r_ln_r) in per {
        comps.push(comp);
        stats.nk.push(nk);
        stats.xbar.push(xbar);
        stats.s.push(s);
        stats.r_ln_r.push(r_ln_r);
    }
    (comps, stats)
}

/// One component's statistics (N_k, xbar_k, S_k, sum r ln r) and posterior.
fn m_step_component(data: &DMatrix<f64>, r: &DMatrix<f64>, prior: &VbPrior, kk: usize) -> ComponentStep {
    let (n, d) = data.shape();
    let rk = r.column(kk);
    let nk: f64 = rk.sum();
    let r_ln_r: f64 = rk.iter().map(|&v| if v > 0.0 { v * v.ln() } else { 0.0 }).sum();
    let (xbar, s) = if nk > 1e-300 {
        let xbar = data.tr_mul(&rk) / nk;
        // Z = diag(sqrt r) (X - 1 xbar^T): S = Z^T Z / N_k, accurate far from the origin.
        let sqrt_r: Vec<f64> = rk.iter().map(|v| v.sqrt()).collect();
        let mut values = Vec::with_capacity(n * d);
        for j in 0..d {
            let (column, mean) = (data.column(j), xbar[j]);
            values.extend(column.as_slice().iter().zip(&sqrt_r).map(|(&x, &w)| w * (x - mean)));
        }
        let z = DMatrix::from_vec(n, d, values);
        let mut s = gram(&z) / nk;
        s = (&s + s.transpose()) * 0.5;
        (xbar, s)
    } else {
        (prior.m0.clone(), DMatrix::zeros(d, d))
    };
    (posterior(prior, nk, &xbar, &s), nk, xbar, s, r_ln_r)
}

/// Z^T Z, bit for bit what `z.transpose() * &z` gives, without the transposed copy (with
/// the weighting around it, under a fifth of training's time): above 5 rows and columns
/// nalgebra 0.35 multiplies through matrixmultiply's blocked kernel, which packs its
/// operands whatever their strides, so handing it Z's own storage read as Z^T sums the
/// same numbers in the same order. Below, the operator itself, whose small-matrix loop
/// sums in another order.
pub(crate) fn gram(z: &DMatrix<f64>) -> DMatrix<f64> {
    let (n, d) = z.shape();
    if n <= 5 || d <= 5 {
        return z.transpose() * z;
    }
    let mut out = DMatrix::<f64>::zeros(d, d);
    // SAFETY: A (d x n) is z's n * d values read with row stride n and column stride 1,
    // B (n x d) is z as stored (strides 1 and n), C (d x d) is `out` as stored (1 and d):
    // every index the kernel forms is inside its buffer, and C does not overlap A or B.
    unsafe {
        matrixmultiply::dgemm(
            d,
            n,
            d,
            1.0,
            z.as_ptr(),
            n as isize,
            1,
            z.as_ptr(),
            1,
            n as isize,
            0.0,
            out.as_mut_ptr(),
            1,
            d as isize,
        );
    }
    out
}

/// A component's posterior (PRML 10.58-10.63) from its statistics N_k, xbar_k and S_k.
pub(crate) fn posterior(prior: &VbPrior, nk: f64, xbar: &DVector<f64>, s: &DMatrix<f64>) -> VbComponent {
    let beta = prior.beta0 + nk;
    let dx = xbar - &prior.m0;
    let w_inv = &prior.w0_inv + s * nk + &dx * dx.transpose() * (prior.beta0 * nk / beta);
    VbComponent {
        alpha: prior.alpha0 + nk,
        beta,
        nu: prior.nu0 + nk,
        mean: (&prior.m0 * prior.beta0 + xbar * nk) / beta,
        w_inv: (&w_inv + w_inv.transpose()) * 0.5,
    }
}

/// Per-component expectations the E-step and the bound share.
pub(crate) struct Expect {
    /// E[ln pi_k]
    pub ln_pi: f64,
    /// E[ln |Lambda_k|]
    pub ln_lambda: f64,
    /// ln |W_k|
    pub ln_w: f64,
    /// Cholesky factor of W_k^-1.
    pub chol: Cholesky<f64, Dyn>,
}

impl Expect {
    /// C^-1 with C C^T = W^-1, so that (x - m)^T W (x - m) = |C^-1 (x - m)|^2.
    pub fn whitening(&self, component: usize) -> Result<DMatrix<f64>, GmmError> {
        let d = self.chol.l_dirty().nrows();
        self.chol
            .l()
            .solve_lower_triangular(&DMatrix::identity(d, d))
            .ok_or(GmmError::NotPositiveDefinite { component })
    }

    /// The terms of ln rho_nk (PRML 10.46) that do not depend on the point.
    pub fn log_rho_base(&self, c: &VbComponent) -> f64 {
        let d = c.mean.len();
        self.ln_pi + 0.5 * self.ln_lambda - 0.5 * d as f64 * LN_2PI - 0.5 * d as f64 / c.beta
    }
}

pub(crate) fn expectations(comps: &[VbComponent]) -> Result<Vec<Expect>, GmmError> {
    let alpha_sum: f64 = comps.iter().map(|c| c.alpha).sum();
    let dig_sum = digamma(alpha_sum);
    comps
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let d = c.mean.len();
            let chol = Cholesky::new(c.w_inv.clone()).ok_or(GmmError::NotPositiveDefinite { component: k })?;
            let ln_w = -2.0 * chol.l_dirty().diagonal().iter().map(|v| v.ln()).sum::<f64>();
            let ln_lambda = (1..=d).map(|i| digamma((c.nu + 1.0 - i as f64) / 2.0)).sum::<f64>()
                + d as f64 * std::f64::consts::LN_2
                + ln_w;
            Ok(Expect { ln_pi: digamma(c.alpha) - dig_sum, ln_lambda, ln_w, chol })
        })
        .collect()
}

/// E-step: responsibilities r_nk by log-sum-exp of ln rho_nk (PRML 10.46-10.49).
pub(crate) fn e_step(data: &DMatrix<f64>, comps: &[VbComponent]) -> Result<DMatrix<f64>, GmmError> {
    let (n, d) = data.shape();
    let k = comps.len();
    let ex = expectations(comps)?;
    let columns = per_component(n, k, |kk| -> Result<Vec<f64>, GmmError> {
        let (c, e) = (&comps[kk], &ex[kk]);
        // (x - m)^T W (x - m) = |C^-1 (x - m)|^2: Y = X C^-T - 1 (C^-1 m)^T.
        let c_inv = e.whitening(kk)?;
        let y = data * c_inv.transpose();
        let shift = &c_inv * &c.mean;
        let mut quad = vec![0.0; n];
        for j in 0..d {
            let (col, s) = (y.column(j), shift[j]);
            for (q, &v) in quad.iter_mut().zip(col.as_slice()) {
                *q += (v - s) * (v - s);
            }
        }
        let base = e.log_rho_base(c);
        for q in &mut quad {
            *q = base - 0.5 * c.nu * *q;
        }
        Ok(quad)
    });
    normalise(n, columns)
}

/// Responsibilities from per-component columns of ln rho_nk: each row normalised in the
/// log domain, in column-wise passes over contiguous columns.
pub(crate) fn normalise(n: usize, columns: Vec<Result<Vec<f64>, GmmError>>) -> Result<DMatrix<f64>, GmmError> {
    let k = columns.len();
    let mut log_rho = DMatrix::<f64>::zeros(n, k);
    for (kk, col) in columns.into_iter().enumerate() {
        log_rho.column_mut(kk).as_mut_slice().copy_from_slice(&col?);
    }
    let mut r = log_rho;
    let mut mx = vec![f64::NEG_INFINITY; n];
    for col in r.column_iter() {
        for (m, &v) in mx.iter_mut().zip(col.as_slice()) {
            *m = m.max(v);
        }
    }
    // The exponentials, a third of the step, go column by column in parallel.
    {
        use rayon::prelude::*;
        let exp_column = |col: &mut [f64]| {
            for (v, &m) in col.iter_mut().zip(&mx) {
                *v = (*v - m).exp();
            }
        };
        let slice = r.as_mut_slice();
        if runs_in_parallel(n, k) {
            slice.par_chunks_mut(n).for_each(exp_column);
        } else {
            slice.chunks_mut(n).for_each(exp_column);
        }
    }
    let mut sum = vec![0.0; n];
    for col in r.column_iter() {
        for (s, &v) in sum.iter_mut().zip(col.as_slice()) {
            *s += v;
        }
    }
    for mut col in r.column_iter_mut() {
        for (v, &s) in col.as_mut_slice().iter_mut().zip(&sum) {
            *v /= s;
        }
    }
    Ok(r)
}

/// ln B(W, nu), the Wishart normaliser (PRML B.79), from ln |W|.
fn ln_wishart_norm(ln_w: f64, nu: f64, d: usize) -> f64 {
    let df = d as f64;
    -0.5 * nu * ln_w
        - (0.5 * nu * df * std::f64::consts::LN_2
            + 0.25 * df * (df - 1.0) * LN_PI
            + (1..=d).map(|i| ln_gamma((nu + 1.0 - i as f64) / 2.0)).sum::<f64>())
}

/// The full variational lower bound (PRML 10.70-10.77, constants included) and each
/// component's share of it (every term except the Dirichlet normalisers).
pub(crate) fn lower_bound(prior: &VbPrior, comps: &[VbComponent], stats: &Stats) -> Result<(f64, Vec<f64>), GmmError> {
    let d = prior.dims();
    let df = d as f64;
    let k = comps.len();
    let ex = expectations(comps)?;
    let prior_chol =
        Cholesky::new(prior.w0_inv.clone()).ok_or(GmmError::BadPrior("W0^-1 is not positive definite".into()))?;
    let ln_w0 = -2.0 * prior_chol.l_dirty().diagonal().iter().map(|v| v.ln()).sum::<f64>();
    let ln_b0 = ln_wishart_norm(ln_w0, prior.nu0, d);
    let mut shares = Vec::with_capacity(k);
    for (kk, (c, e)) in comps.iter().zip(&ex).enumerate() {
        let nk = stats.nk[kk];
        let tr_sw = e.chol.solve(&stats.s[kk]).trace();
        let dx = &stats.xbar[kk] - &c.mean;
        let q_x = dx.dot(&e.chol.solve(&dx));
        let dm = &c.mean - &prior.m0;
        let q_m = dm.dot(&e.chol.solve(&dm));
        let tr_w0w = e.chol.solve(&prior.w0_inv).trace();
        let mut l = 0.0;
        // 10.71 E[ln p(X | Z, mu, Lambda)]
        l += 0.5 * nk * (e.ln_lambda - df / c.beta - c.nu * tr_sw - c.nu * q_x - df * LN_2PI);
        // 10.72 E[ln p(Z | pi)]
        l += nk * e.ln_pi;
        // 10.73 E[ln p(pi)] without ln C(alpha0)
        l += (prior.alpha0 - 1.0) * e.ln_pi;
        // 10.74 E[ln p(mu, Lambda)]
        l += 0.5
            * (df * (prior.beta0 / (2.0 * std::f64::consts::PI)).ln() + e.ln_lambda
                - df * prior.beta0 / c.beta
                - prior.beta0 * c.nu * q_m)
            + ln_b0
            + 0.5 * (prior.nu0 - df - 1.0) * e.ln_lambda
            - 0.5 * c.nu * tr_w0w;
        // 10.75 -E[ln q(Z)]
        l -= stats.r_ln_r[kk];
        // 10.76 -E[ln q(pi)] without ln C(alpha)
        l -= (c.alpha - 1.0) * e.ln_pi;
        // 10.77 -E[ln q(mu, Lambda)]
        let entropy_wishart =
            -ln_wishart_norm(e.ln_w, c.nu, d) - 0.5 * (c.nu - df - 1.0) * e.ln_lambda + 0.5 * c.nu * df;
        l -= 0.5 * e.ln_lambda + 0.5 * df * (c.beta / (2.0 * std::f64::consts::PI)).ln() - 0.5 * df - entropy_wishart;
        shares.push(l);
    }
    let alpha_sum: f64 = comps.iter().map(|c| c.alpha).sum();
    let ln_c_alpha0 = ln_gamma(k as f64 * prior.alpha0) - k as f64 * ln_gamma(prior.alpha0);
    let ln_c_alpha = ln_gamma(alpha_sum) - comps.iter().map(|c| ln_gamma(c.alpha)).sum::<f64>();
    let total = shares.iter().sum::<f64>() + ln_c_alpha0 - ln_c_alpha;
    if !total.is_finite() {
        return Err(GmmError::Numerical("the lower bound is not finite".into()));
    }
    Ok((total, shares))
}

/// Result of running VBEM from given responsibilities.
#[derive(Debug, Clone)]
pub(crate) struct Run {
    pub comps: Vec<VbComponent>,
    pub stats: Stats,
    pub r: DMatrix<f64>,
    pub bound: f64,
    pub shares: Vec<f64>,
    pub iterations: usize,
    /// The bound after every iteration (for the monotonicity check).
    pub history: Vec<f64>,
}

/// Which implementation of the E- and M-steps a run uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Steps {
    /// [`e_step`] and [`m_step`]: what the growing search and fixed K have always used, kept
    /// so that trained models stay the same bit for bit.
    Reference,
    /// [`super::packed`]: the same quantities, summed in another order, about twice as fast.
    Packed,
}

/// When a run stops.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Control {
    pub steps: Steps,
    pub max_iterations: usize,
    /// Stop when the bound's relative gain in one iteration is below this.
    pub tolerance: f64,
    /// A search candidate's bar: stop as soon as the bound passes it (the bound only rises,
    /// so the candidate is kept whatever more iterations would do), or once the bound's
    /// geometric extrapolation says it will fall clearly short.
    pub target: Option<f64>,
}

/// Whether a run whose bounds so far are `history` will stay below `target`: the gains of
/// its last iterations shrink geometrically (ratio q) and even ten times their remaining sum
/// g q / (1 - q) would not reach the target. Needs three iterations of shrinking gains.
fn falls_short(history: &[f64], target: f64) -> bool {
    let [.., a, b, c] = history else { return false };
    let (g0, g1) = (b - a, c - b);
    if !(g0 > 0.0 && g1 >= 0.0 && g1 < 0.5 * g0) {
        return false;
    }
    let q = g1 / g0;
    c + 10.0 * g1 * q / (1.0 - q) < target
}

/// Runs VBEM from responsibilities `r` until `control` says stop.
pub(crate) fn run_with(
    data: &DMatrix<f64>,
    mut r: DMatrix<f64>,
    prior: &VbPrior,
    control: &Control,
) -> Result<Run, GmmError> {
    let max_iterations = control.max_iterations.max(1);
    let mut history: Vec<f64> = Vec::new();
    for it in 0..max_iterations {
        let (comps, stats) = match control.steps {
            Steps::Reference => m_step(data, &r, prior),
            Steps::Packed => super::packed::m_step(data, &r, prior),
        };
        let (bound, shares) = lower_bound(prior, &comps, &stats)?;
        let converged = history.last().is_some_and(|prev| bound - prev <= control.tolerance * bound.abs());
        history.push(bound);
        let decided = control.target.is_some_and(|t| bound > t || falls_short(&history, t));
        if converged || decided || it + 1 == max_iterations {
            let iterations = history.len();
            return Ok(Run { comps, stats, r, bound, shares, iterations, history });
        }
        r = match control.steps {
            Steps::Reference => e_step(data, &comps)?,
            Steps::Packed => super::packed::e_step(data, &comps)?,
        };
    }
    unreachable!("the last iteration returns")
}

/// The full lower bound of the posterior that responsibilities `r` (N x K) imply: one
/// M-step, then PRML 10.70. Lets another implementation's solution (e.g. scikit-learn's
/// `predict_proba`) be scored with the same bound.
pub fn bound_at_responsibilities(data: &DMatrix<f64>, r: &DMatrix<f64>, prior: &VbPrior) -> Result<f64, GmmError> {
    check_data(data)?;
    prior.check(data.ncols())?;
    if r.nrows() != data.nrows() {
        return Err(GmmError::Dimension { expected: data.nrows(), found: r.nrows() });
    }
    let (comps, stats) = m_step(data, r, prior);
    Ok(lower_bound(prior, &comps, &stats)?.0)
}
