//! Model selection: a birth-death search over the number of components driven by the
//! variational lower bound (as in ACFR's libcluster), and a fixed-K mode seeded by k-means++.

use nalgebra::{DMatrix, SymmetricEigen};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::vbem::{self, Control, Run, Steps, VbComponent, VbPrior, check_data};
use super::{GmmError, packed};

/// How a mixture is fitted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VbOptions {
    /// Upper limit on the number of components (the search stops growing there; the
    /// fixed-K mode uses exactly this many).
    pub max_components: usize,
    /// Fit exactly `max_components` components (k-means++ start) instead of searching.
    pub fixed_k: bool,
    /// VBEM stops when the bound's relative gain in one iteration is below this.
    pub tolerance: f64,
    pub max_iterations: usize,
    /// A split is kept when it raises the bound by more than this fraction of |bound|.
    pub split_gain: f64,
    /// Components with fewer than this many points' worth of responsibility are deleted.
    pub min_points: f64,
    /// Seed of the k-means++ start (fixed K and the pruning search; growing needs none).
    pub seed: u64,
    /// How the number of components is searched for (ignored with `fixed_k`). Left out of
    /// the serialised form at its default, like `component_cost_nats`, so that settings
    /// written before it existed (and the model cache keys made from them) stay the same.
    #[serde(skip_serializing_if = "Search::is_grow")]
    pub search: Search,
    /// What each component costs in the pruning search, in nats of the bound: a change is
    /// kept when the bound minus this cost per component rises by more than `split_gain`.
    /// One nat is a Bayes factor of e, Kass & Raftery's (1995) threshold of positive
    /// evidence; a component that raises the bound by less is noise in the sample (on 93
    /// points of one Gaussian, a second component raised the bound by 0.005 nats).
    #[serde(skip_serializing_if = "is_one_nat")]
    pub component_cost_nats: f64,
}

fn is_one_nat(v: &f64) -> bool {
    *v == 1.0
}

/// How the number of components is found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Search {
    /// Start from one component and split components while the bound rises (the search of
    /// ACFR's libcluster). The default, and what the trained appearance and object models
    /// use, so that they stay as they were.
    #[default]
    Grow,
    /// Start from `max_components` components (k-means++), let VBEM empty those the data do
    /// not need, then delete and split components while the bound rises. Several times
    /// faster than growing on data with many components (docs/performance.md); the same bar
    /// for keeping a change.
    Prune,
}

impl Search {
    fn is_grow(&self) -> bool {
        *self == Search::Grow
    }
}

impl Default for VbOptions {
    fn default() -> Self {
        VbOptions {
            max_components: 10,
            fixed_k: false,
            tolerance: 1e-7,
            max_iterations: 1000,
            split_gain: 1e-5,
            min_points: 1.0,
            seed: 0,
            search: Search::Grow,
            component_cost_nats: 1.0,
        }
    }
}

/// A fitted variational Bayesian GMM: the posterior over weights, means and precisions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VbGmm {
    pub prior: VbPrior,
    pub components: Vec<VbComponent>,
    /// The full lower bound on ln p(X) (PRML 10.70, constants included), in nats.
    pub lower_bound: f64,
    /// VBEM iterations summed over the whole search.
    pub iterations: usize,
    /// Number of training points.
    pub points: usize,
    /// The training data's responsibility-weighted counts per component (N_k).
    pub counts: Vec<f64>,
}

impl VbGmm {
    pub fn dims(&self) -> usize {
        self.prior.dims()
    }

    /// Expected mixing weights E[pi_k] = alpha_k / sum alpha.
    pub fn weights(&self) -> Vec<f64> {
        let s: f64 = self.components.iter().map(|c| c.alpha).sum();
        self.components.iter().map(|c| c.alpha / s).collect()
    }

    /// Components whose expected weight exceeds `min_weight`.
    pub fn effective_components(&self, min_weight: f64) -> usize {
        self.weights().iter().filter(|&&w| w > min_weight).count()
    }

    /// Checks a model read from a file: a proper prior, at least one component, every
    /// component of the prior's dimension with finite positive `alpha` and `beta`, `nu`
    /// above D - 1, a finite mean and a positive definite W^-1.
    pub fn check(&self) -> Result<(), GmmError> {
        self.predictive().map(|_| ())
    }

    /// Every component's mean and W^-1 of the prior's dimension D (D and D x D): what
    /// reading them needs before anything else is checked.
    pub(crate) fn check_shapes(&self) -> Result<(), GmmError> {
        let d = self.dims();
        for (k, c) in self.components.iter().enumerate() {
            if c.mean.len() != d {
                return Err(GmmError::BadModel(format!(
                    "component {k}: its mean has {} dimensions; the prior's m0 has {d}",
                    c.mean.len()
                )));
            }
            if c.w_inv.shape() != (d, d) {
                let (rows, cols) = c.w_inv.shape();
                return Err(GmmError::CovarianceShape { component: k, dims: d, rows, cols });
            }
        }
        Ok(())
    }

    /// The posterior predictive density of a model that passes [`VbGmm::check`], formed
    /// once: checking it forms it.
    fn predictive(&self) -> Result<super::StudentTMixture, GmmError> {
        let d = self.dims();
        self.prior.check(d)?;
        if self.components.is_empty() {
            return Err(GmmError::EmptyModel);
        }
        self.check_shapes()?;
        for (k, c) in self.components.iter().enumerate() {
            let finite = c.alpha.is_finite() && c.beta.is_finite() && c.nu.is_finite();
            if !(finite && c.alpha > 0.0 && c.beta > 0.0 && c.nu > d as f64 - 1.0) {
                return Err(GmmError::BadModel(format!(
                    "component {k}: alpha = {}, beta = {} and nu = {} must be finite, alpha and beta positive and nu above D - 1 = {}",
                    c.alpha,
                    c.beta,
                    c.nu,
                    d as f64 - 1.0
                )));
            }
            if c.mean.iter().chain(c.w_inv.iter()).any(|v| !v.is_finite()) {
                return Err(GmmError::BadModel(format!("component {k}: mean and W^-1 must be finite")));
            }
            // A scale matrix: symmetric (to rounding, relative to its largest entry; one
            // triangle alone would be read) and positive definite.
            let scale = c.w_inv.amax();
            if (0..d).any(|i| (0..i).any(|j| (c.w_inv[(i, j)] - c.w_inv[(j, i)]).abs() > 1e-9 * scale)) {
                return Err(GmmError::BadModel(format!("component {k}: W^-1 is not symmetric")));
            }
            if nalgebra::Cholesky::new(c.w_inv.clone()).is_none() {
                return Err(GmmError::BadModel(format!("component {k}: W^-1 is not positive definite")));
            }
        }
        // The weights are alpha over the alphas' sum: a sum past f64's range would make
        // every weight zero and the density a floor value, with no error.
        let alphas: f64 = self.components.iter().map(|c| c.alpha).sum();
        if !alphas.is_finite() {
            return Err(GmmError::BadModel(format!(
                "the components' alphas sum to {alphas}: past what a weight can be computed from"
            )));
        }
        if !self.counts.is_empty() && self.counts.len() != self.components.len() {
            return Err(GmmError::BadModel(format!(
                "{} counts for {} components",
                self.counts.len(),
                self.components.len()
            )));
        }
        if let Some(k) = self.counts.iter().position(|n| !(n.is_finite() && *n >= 0.0)) {
            return Err(GmmError::BadModel(format!("count {k} is {}; counts are numbers of points", self.counts[k])));
        }
        // Numbers each sound alone can still give no density (nu = 1e308 scales the
        // predictive's covariance to nothing): a fault of the model, found here rather
        // than when data are scored.
        super::StudentTMixture::new(self)
            .map_err(|e| GmmError::BadModel(format!("its predictive density cannot be formed: {e}")))
    }

    /// Mean over the rows of `data` of ln p(x | training data), the posterior predictive
    /// density (a mixture of Student-t, PRML 10.81): the held-out log-likelihood per point
    /// that compares models fitted to the same training data, whatever their K.
    pub fn mean_log_predictive(&self, data: &DMatrix<f64>) -> Result<f64, GmmError> {
        check_data(data)?;
        let predictive = self.predictive()?;
        if data.ncols() != self.dims() {
            return Err(GmmError::Dimension { expected: self.dims(), found: data.ncols() });
        }
        let total: f64 = data.row_iter().map(|row| predictive.log_density(&row.transpose())).sum::<Result<f64, _>>()?;
        Ok(total / data.nrows() as f64)
    }
}

/// Fits a VB-GMM to `data` (rows are points) with `prior` (default: [`VbPrior::from_data`]).
pub fn fit(data: &DMatrix<f64>, prior: Option<&VbPrior>, options: &VbOptions) -> Result<VbGmm, GmmError> {
    fit_with_history(data, prior, options).map(|(g, _)| g)
}

/// Like [`fit`], also returning the bound after every VBEM iteration of the final run.
pub fn fit_with_history(
    data: &DMatrix<f64>,
    prior: Option<&VbPrior>,
    options: &VbOptions,
) -> Result<(VbGmm, Vec<f64>), GmmError> {
    check_data(data)?;
    super::vbem::check_spread(data)?;
    if options.max_components == 0 {
        return Err(GmmError::BadOptions("max_components must be at least 1".into()));
    }
    let non_negative = [options.tolerance, options.split_gain, options.min_points, options.component_cost_nats];
    if !non_negative.iter().all(|v| *v >= 0.0 && v.is_finite()) {
        return Err(GmmError::BadOptions(
            "tolerance, split_gain, min_points and component_cost_nats must be finite and zero or positive".into(),
        ));
    }
    let prior = match prior {
        Some(p) => {
            p.check(data.ncols())?;
            p.clone()
        }
        None => VbPrior::from_data(data)?,
    };
    let run = match (options.fixed_k, options.search) {
        (true, _) => fixed_k(data, &prior, options)?,
        (false, Search::Grow) => birth_death(data, &prior, options)?,
        (false, Search::Prune) => prune_search(data, &prior, options)?,
    };
    let model = VbGmm {
        counts: run.stats.nk.clone(),
        components: run.comps,
        lower_bound: run.bound,
        iterations: run.iterations,
        points: data.nrows(),
        prior,
    };
    Ok((model, run.history))
}

/// Drops components whose responsibility mass is below `min_points` and renormalises.
fn prune(r: &DMatrix<f64>, min_points: f64) -> Option<DMatrix<f64>> {
    let keep: Vec<usize> = (0..r.ncols()).filter(|&k| r.column(k).sum() >= min_points).collect();
    if keep.len() == r.ncols() || keep.is_empty() {
        return None;
    }
    let mut out = r.select_columns(&keep);
    for i in 0..out.nrows() {
        let s: f64 = out.row(i).sum();
        if s > 0.0 {
            out.row_mut(i).unscale_mut(s);
        } else {
            out.row_mut(i).fill(1.0 / keep.len() as f64);
        }
    }
    Some(out)
}

/// Runs VBEM, deleting emptied components (and re-running) until none empties.
fn run_pruned(
    data: &DMatrix<f64>,
    r: DMatrix<f64>,
    prior: &VbPrior,
    options: &VbOptions,
    total_iterations: &mut usize,
) -> Result<Run, GmmError> {
    let control = Control {
        steps: Steps::Reference,
        max_iterations: options.max_iterations,
        tolerance: options.tolerance,
        target: None,
    };
    run_pruned_with(data, r, prior, options, &control, total_iterations)
}

/// [`run_pruned`] under a given [`Control`].
fn run_pruned_with(
    data: &DMatrix<f64>,
    r: DMatrix<f64>,
    prior: &VbPrior,
    options: &VbOptions,
    control: &Control,
    total_iterations: &mut usize,
) -> Result<Run, GmmError> {
    let mut run = vbem::run_with(data, r, prior, control)?;
    *total_iterations += run.iterations;
    while let Some(r) = prune(&run.r, options.min_points) {
        run = vbem::run_with(data, r, prior, control)?;
        *total_iterations += run.iterations;
    }
    Ok(run)
}

/// Splits component `c` along the principal axis of its covariance: its points (those
/// for which it is the most responsible component) on the positive side move to a new one.
fn split(data: &DMatrix<f64>, run: &Run, c: usize) -> Option<DMatrix<f64>> {
    let (n, k) = (data.nrows(), run.r.ncols());
    let eig = SymmetricEigen::new(run.stats.s[c].clone());
    let (axis, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .fold((0, f64::NEG_INFINITY), |(bi, bv), (i, &v)| if v > bv { (i, v) } else { (bi, bv) });
    let v = eig.eigenvectors.column(axis);
    let xbar = &run.stats.xbar[c];
    let mut r = run.r.clone().insert_column(k, 0.0);
    let (mut moved, mut stayed) = (0usize, 0usize);
    for i in 0..n {
        let row = run.r.row(i);
        let owner = row
            .iter()
            .enumerate()
            .fold((0, f64::NEG_INFINITY), |(bi, bv), (j, &x)| if x > bv { (j, x) } else { (bi, bv) })
            .0;
        if owner != c {
            continue;
        }
        let proj: f64 = (0..data.ncols()).map(|j| (data[(i, j)] - xbar[j]) * v[j]).sum();
        if proj > 0.0 {
            r[(i, k)] = r[(i, c)];
            r[(i, c)] = 0.0;
            moved += 1;
        } else {
            stayed += 1;
        }
    }
    (moved >= 2 && stayed >= 2).then_some(r)
}

/// Birth-death search: start with one component; try splitting components, worst share
/// of the bound first; keep a split when VBEM on all data raises the bound; stop when no
/// split is kept or `max_components` is reached.
fn birth_death(data: &DMatrix<f64>, prior: &VbPrior, options: &VbOptions) -> Result<Run, GmmError> {
    let mut total = 0usize;
    let mut best = run_pruned(data, DMatrix::from_element(data.nrows(), 1, 1.0), prior, options, &mut total)?;
    'grow: while best.comps.len() < options.max_components {
        let mut order: Vec<usize> = (0..best.comps.len()).collect();
        order.sort_by(|&a, &b| best.shares[a].total_cmp(&best.shares[b]).then(a.cmp(&b)));
        for c in order {
            let Some(r) = split(data, &best, c) else { continue };
            let candidate = run_pruned(data, r, prior, options, &mut total)?;
            if candidate.bound > best.bound + options.split_gain * best.bound.abs()
                && candidate.comps.len() > best.comps.len()
            {
                best = candidate;
                continue 'grow;
            }
        }
        break;
    }
    best.iterations = total;
    Ok(best)
}

/// Fixed-K mode: k-means++ seeds, a few Lloyd iterations, then VBEM from the hard labels.
fn fixed_k(data: &DMatrix<f64>, prior: &VbPrior, options: &VbOptions) -> Result<Run, GmmError> {
    let r = kmeans_start(data, options.max_components.min(data.nrows()), options.seed);
    let mut total = 0;
    let mut run = run_pruned(data, r, prior, options, &mut total)?;
    run.iterations = total;
    Ok(run)
}

/// The pruning search ([`Search::Prune`]): VBEM from `max_components` k-means++ clusters
/// empties the components the data do not need; then deleting a component (its points go to
/// the others by one E-step) and splitting one ([`split`]) are tried, smallest component and
/// worst share of the bound first. A change is kept when the bound minus
/// `component_cost_nats` per component rises by more than `split_gain` of the bound: a
/// strict rise of one score between converged models, so the search cannot cycle. A
/// candidate stops as soon as it passes that bar or clearly cannot ([`Control::target`]);
/// one that passes is run to the full tolerance before the next bar is set from it. (A
/// candidate that VBEM empties further is held to the bar of one component less: stricter
/// than its score needs.)
fn prune_search(data: &DMatrix<f64>, prior: &VbPrior, options: &VbOptions) -> Result<Run, GmmError> {
    let full = Control {
        steps: Steps::Packed,
        max_iterations: options.max_iterations,
        tolerance: options.tolerance,
        target: None,
    };
    // The bound a candidate with `delta` more components than a model of bound `bound` must beat.
    let bar = |bound: f64, delta: f64| bound + options.split_gain * bound.abs() + delta * options.component_cost_nats;
    let candidate = |target: f64| Control { target: Some(target), ..full };
    let mut total = 0usize;
    let start = kmeans_start(data, options.max_components.min(data.nrows()), options.seed);
    let mut best = run_pruned_with(data, start, prior, options, &full, &mut total)?;
    'deaths: while best.comps.len() > 1 {
        let mut order: Vec<usize> = (0..best.comps.len()).collect();
        order.sort_by(|&a, &b| best.stats.nk[a].total_cmp(&best.stats.nk[b]).then(a.cmp(&b)));
        for c in order {
            let mut comps = best.comps.clone();
            comps.remove(c);
            let r = packed::e_step(data, &comps)?;
            let target = bar(best.bound, -1.0);
            let run = run_pruned_with(data, r, prior, options, &candidate(target), &mut total)?;
            if run.bound > target {
                best = run_pruned_with(data, run.r, prior, options, &full, &mut total)?;
                continue 'deaths;
            }
        }
        break;
    }
    'births: while best.comps.len() < options.max_components {
        let mut order: Vec<usize> = (0..best.comps.len()).collect();
        order.sort_by(|&a, &b| best.shares[a].total_cmp(&best.shares[b]).then(a.cmp(&b)));
        for c in order {
            let Some(r) = split(data, &best, c) else { continue };
            let target = bar(best.bound, 1.0);
            let run = run_pruned_with(data, r, prior, options, &candidate(target), &mut total)?;
            if run.bound > target && run.comps.len() > best.comps.len() {
                best = run_pruned_with(data, run.r, prior, options, &full, &mut total)?;
                continue 'births;
            }
        }
        break;
    }
    best.iterations = total;
    Ok(best)
}

/// Hard responsibilities (N x k) from k-means++ seeds (seeded by `seed`) and ten Lloyd
/// iterations.
fn kmeans_start(data: &DMatrix<f64>, k: usize, seed: u64) -> DMatrix<f64> {
    let (n, d) = data.shape();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let dist2 = |i: usize, c: &[f64]| -> f64 { (0..d).map(|j| (data[(i, j)] - c[j]).powi(2)).sum() };
    let row = |i: usize| -> Vec<f64> { (0..d).map(|j| data[(i, j)]).collect() };
    let mut centres = vec![row(rng.random_range(0..n))];
    let mut nearest: Vec<f64> = (0..n).map(|i| dist2(i, &centres[0])).collect();
    while centres.len() < k {
        let total: f64 = nearest.iter().sum();
        let pick = if total > 0.0 {
            let mut u = rng.random_range(0.0..total);
            let mut idx = n - 1;
            for (i, &w) in nearest.iter().enumerate() {
                if u < w {
                    idx = i;
                    break;
                }
                u -= w;
            }
            idx
        } else {
            rng.random_range(0..n)
        };
        centres.push(row(pick));
        for (i, best) in nearest.iter_mut().enumerate() {
            *best = best.min(dist2(i, centres.last().expect("just pushed")));
        }
    }
    let mut labels = vec![0usize; n];
    let (mut dist, mut closest) = (vec![0.0; n], vec![0.0; n]);
    for _ in 0..10 {
        // Each point's squared distance summed over j in order, as dist2 does; the first
        // nearest centre wins ties.
        for (c, centre) in centres.iter().enumerate() {
            dist.fill(0.0);
            for (j, &cj) in centre.iter().enumerate() {
                for (t, &x) in dist.iter_mut().zip(data.column(j).iter()) {
                    *t += (x - cj).powi(2);
                }
            }
            for i in 0..n {
                if c == 0 || dist[i] < closest[i] {
                    closest[i] = dist[i];
                    labels[i] = c;
                }
            }
        }
        let mut sums = vec![vec![0.0; d]; k];
        let mut counts = vec![0usize; k];
        for (i, &l) in labels.iter().enumerate() {
            counts[l] += 1;
            for j in 0..d {
                sums[l][j] += data[(i, j)];
            }
        }
        for c in 0..k {
            if counts[c] > 0 {
                centres[c] = sums[c].iter().map(|s| s / counts[c] as f64).collect();
            }
        }
    }
    let mut r = DMatrix::zeros(n, k);
    for (i, &l) in labels.iter().enumerate() {
        r[(i, l)] = 1.0;
    }
    r
}
