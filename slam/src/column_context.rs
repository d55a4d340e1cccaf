//! Spatial context of the patch labels along image columns: the paper's future work of
//! correlating neighbouring patches, as a stacked classifier learnt from data.
//!
//! The mixtures judge each patch alone. A trunk is a vertical run of bark; a post is a short
//! one with sky or grass above it; a patch of bark colour in a hedge or on a person has few
//! bark patches above and below. So a patch's label is decided again from its own log-odds
//! and those of its column: the patch right above, the one right below, and the mean over
//! the patches 2 to `reach` above and below. The weights come from a logistic regression on
//! labelled images the mixtures were not fitted to (the mixtures' log-odds on their own
//! training patches are overconfident, and weights fitted there trust them too much).
//! Neighbours across the columns were tried and left out: their weights came out near zero.
//!
//! A pairwise Markov random field over the patch grid (Potts coupling, fitted by
//! pseudo-likelihood, mean-field inference) was measured first: it raised the held-out
//! world's patch recall but lowered its precision, calling more of the posts' patches
//! object (docs/results.md#spatial-context-of-patch-labels).

use serde::{Deserialize, Serialize};

/// Log-odds are clamped at this magnitude (probabilities 1e-12 from 0 or 1): in 10 or more
/// dimensions the mixtures' density ratios reach e^100 and beyond in their tails, which
/// says where a patch lies against the training data's spread, not how sure a label is.
pub const MAX_LOG_ODDS: f64 = 27.631021115928547;

/// How far up and down the column the means reach, in patches: 12 patches of 9 px are a
/// quarter of a 480-px image. Reaches of 6 and 12 scored within 0.01 of each other in patch
/// precision and recall on a held-out world (docs/results.md#spatial-context-of-patch-labels).
pub const DEFAULT_REACH: u32 = 12;

/// Number of weights: own log-odds, a constant, the patch above, the patch below, the mean
/// of the patches 2..=reach above, and of those below.
pub const WEIGHTS: usize = 6;

/// The learnt column context.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColumnContext {
    /// How many patches up and down the column the means reach.
    pub reach: u32,
    /// Weights of the terms listed at [`WEIGHTS`].
    pub weights: [f64; WEIGHTS],
    /// Images and patches the weights were fitted on.
    pub images: usize,
    pub patches: usize,
}

/// One image's patch grid (row-major, `cols` x `rows`) with the mixtures' log-odds and the
/// ground-truth labels, to fit the context on.
#[derive(Debug, Clone)]
pub struct LabelledGrid {
    pub log_odds: Vec<f64>,
    pub object: Vec<bool>,
    pub cols: usize,
    pub rows: usize,
}

/// Why the context could not be fitted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ContextError {
    #[error("the column context needs patches of both classes to fit on ({object} object, {background} background)")]
    OneClass { object: usize, background: usize },
    #[error("the column context's fit did not converge (weights not finite)")]
    NotFinite,
    /// A grid whose labels or log-odds are not one per patch, or a reach below 2.
    #[error("{0}")]
    Input(String),
}

impl ColumnContext {
    /// Checks a loaded context: (field, problem).
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        if self.reach < 2 {
            return Err(("reach", format!("must be at least 2, got {}", self.reach)));
        }
        if let Some(w) = self.weights.iter().find(|w| !w.is_finite()) {
            return Err(("weights", format!("must be finite, got {w}")));
        }
        Ok(())
    }

    /// Probabilities that each patch of a `cols` x `rows` grid (row-major) is object, from
    /// the mixtures' log-odds of every patch; log-odds that are not one per patch are
    /// [`ContextError::Input`].
    pub fn apply(&self, log_odds: &[f64], cols: usize, rows: usize) -> Result<Vec<f64>, ContextError> {
        if cols.checked_mul(rows) != Some(log_odds.len()) {
            return Err(ContextError::Input(format!("{} log-odds for a {cols}x{rows} grid", log_odds.len())));
        }
        Ok(self.apply_prechecked(log_odds, cols, rows))
    }

    /// [`ColumnContext::apply`] to log-odds the caller has checked are one per patch.
    pub(crate) fn apply_prechecked(&self, log_odds: &[f64], cols: usize, rows: usize) -> Vec<f64> {
        let terms = terms(log_odds, cols, rows, self.reach as usize);
        terms.iter().map(|t| sigmoid(dot(&self.weights, t))).collect()
    }

    /// Fits the weights on the labelled patch grids of images.
    pub fn fit(grids: &[LabelledGrid], reach: u32) -> Result<ColumnContext, ContextError> {
        if reach < 2 {
            return Err(ContextError::Input(format!("reach must be at least 2 patches, got {reach}")));
        }
        let mut x: Vec<[f64; WEIGHTS]> = Vec::new();
        let mut y: Vec<bool> = Vec::new();
        for (k, grid) in grids.iter().enumerate() {
            let patches = grid.cols * grid.rows;
            if grid.log_odds.len() != patches || grid.object.len() != patches {
                return Err(ContextError::Input(format!(
                    "grid {k}: {} log-odds and {} labels for {}x{} patches",
                    grid.log_odds.len(),
                    grid.object.len(),
                    grid.cols,
                    grid.rows
                )));
            }
            x.extend(terms(&grid.log_odds, grid.cols, grid.rows, reach as usize));
            y.extend(&grid.object);
        }
        let object = y.iter().filter(|&&o| o).count();
        if object == 0 || object == y.len() {
            return Err(ContextError::OneClass { object, background: y.len() - object });
        }
        let weights = logistic_regression(&x, &y)?;
        Ok(ColumnContext { reach, weights, images: grids.len(), patches: y.len() })
    }
}

fn sigmoid(z: f64) -> f64 {
    1.0 / (1.0 + (-z).exp())
}

fn dot(a: &[f64; WEIGHTS], b: &[f64; WEIGHTS]) -> f64 {
    a.iter().zip(b).map(|(a, b)| a * b).sum()
}

/// The regression's terms of every patch. A neighbour past the grid's edge counts as
/// log-odds 0 (no evidence either way), and a mean over no patches is 0. `log_odds`
/// holds one per patch (the callers check).
fn terms(log_odds: &[f64], cols: usize, rows: usize, reach: usize) -> Vec<[f64; WEIGHTS]> {
    let lo = |c: usize, r: usize| log_odds[r * cols + c].clamp(-MAX_LOG_ODDS, MAX_LOG_ODDS);
    let mut out = vec![[0.0; WEIGHTS]; cols * rows];
    // Prefix sums down each column: sum[r] = rows 0..r.
    let mut sum = vec![0.0; rows + 1];
    for c in 0..cols {
        for r in 0..rows {
            sum[r + 1] = sum[r] + lo(c, r);
        }
        let mean = |from: usize, to: usize| if from < to { (sum[to] - sum[from]) / (to - from) as f64 } else { 0.0 };
        for r in 0..rows {
            let t = &mut out[r * cols + c];
            t[0] = lo(c, r);
            t[1] = 1.0;
            t[2] = if r >= 1 { lo(c, r - 1) } else { 0.0 };
            t[3] = if r + 1 < rows { lo(c, r + 1) } else { 0.0 };
            // Above: rows r-reach ..= r-2; below: rows r+2 ..= r+reach.
            t[4] = mean(r.saturating_sub(reach), r.saturating_sub(1));
            t[5] = mean((r + 2).min(rows), (r + reach + 1).min(rows));
        }
    }
    out
}

/// Maximum-likelihood logistic regression by Newton's method (iteratively reweighted least
/// squares), with a tiny ridge so a separable feature cannot send a weight to infinity.
fn logistic_regression(x: &[[f64; WEIGHTS]], y: &[bool]) -> Result<[f64; WEIGHTS], ContextError> {
    use nalgebra::{SMatrix, SVector};
    let mut w = SVector::<f64, WEIGHTS>::zeros();
    for _ in 0..50 {
        let mut g = SVector::<f64, WEIGHTS>::zeros();
        let mut h = SMatrix::<f64, WEIGHTS, WEIGHTS>::identity() * 1e-6;
        for (xi, &yi) in x.iter().zip(y) {
            let v = SVector::<f64, WEIGHTS>::from_row_slice(xi);
            let p = sigmoid(w.dot(&v));
            g += v * (yi as u8 as f64 - p);
            h += v * v.transpose() * (p * (1.0 - p));
        }
        let step = h.cholesky().ok_or(ContextError::NotFinite)?.solve(&g);
        w += step;
        if step.amax() < 1e-9 {
            break;
        }
    }
    if w.iter().all(|v| v.is_finite()) { Ok(w.into()) } else { Err(ContextError::NotFinite) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn terms_read_the_column_and_stop_at_the_edges() {
        // 2 columns x 5 rows; column 0 holds 0..5, column 1 holds 10..15.
        let lo: Vec<f64> = (0..5).flat_map(|r| [r as f64, 10.0 + r as f64]).collect();
        let t = terms(&lo, 2, 5, 3);
        // Row 3 of column 0: above 2, below 4; rows 0..=1 above (reach 3), none 2 below.
        assert_eq!(t[3 * 2], [3.0, 1.0, 2.0, 4.0, 0.5, 0.0]);
        // Row 0 of column 1: nothing above; below 11; rows 2..=3 below.
        assert_eq!(t[1], [10.0, 1.0, 0.0, 11.0, 0.0, 12.5]);
        // Clamped.
        let t = terms(&[1e6, -1e6], 1, 2, 2);
        assert_eq!((t[0][0], t[1][0], t[0][3]), (MAX_LOG_ODDS, -MAX_LOG_ODDS, -MAX_LOG_ODDS));
    }

    /// Columns of object patches whose own log-odds are noisy: the context learns to trust
    /// the column, and fixes patches the mixtures alone got wrong.
    #[test]
    fn the_fitted_context_trusts_a_columns_evidence_over_a_noisy_patch() {
        let mut state = 7u64;
        let mut noise = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 8.0
        };
        let (cols, rows) = (12, 30);
        let mut grids = Vec::new();
        for image in 0..6 {
            let (mut lo, mut labels) = (Vec::new(), Vec::new());
            for _r in 0..rows {
                for c in 0..cols {
                    let object = c % 4 == image % 4;
                    lo.push(if object { 1.0 } else { -1.0 } + noise());
                    labels.push(object);
                }
            }
            grids.push(LabelledGrid { log_odds: lo, object: labels, cols, rows });
        }
        let (train, test) = grids.split_at(4);
        let context = ColumnContext::fit(train, 6).unwrap();
        context.check().unwrap();
        assert!(context.weights[4] > 0.0 && context.weights[5] > 0.0, "{:?}", context.weights);
        let errors = |decide: &dyn Fn(&LabelledGrid) -> Vec<bool>| -> usize {
            test.iter().map(|g| decide(g).iter().zip(&g.object).filter(|(p, t)| p != t).count()).sum()
        };
        let alone = errors(&|g| g.log_odds.iter().map(|&l| l > 0.0).collect());
        let with_context =
            errors(&|g| context.apply(&g.log_odds, g.cols, g.rows).unwrap().iter().map(|&p| p > 0.5).collect());
        assert!(alone > 100, "the patches alone err often ({alone})");
        assert!(with_context * 4 < alone, "{with_context} errors with the context, {alone} without");
    }

    #[test]
    fn one_class_and_bad_values_are_errors() {
        let grid = LabelledGrid { log_odds: vec![1.0; 4], object: vec![true; 4], cols: 2, rows: 2 };
        assert!(matches!(ColumnContext::fit(&[grid], 3), Err(ContextError::OneClass { object: 4, background: 0 })));
        let bad = ColumnContext { reach: 1, weights: [0.0; WEIGHTS], images: 1, patches: 1 };
        assert_eq!(bad.check().unwrap_err().0, "reach");
        let bad = ColumnContext { reach: 4, weights: [f64::NAN; WEIGHTS], images: 1, patches: 1 };
        assert_eq!(bad.check().unwrap_err().0, "weights");
    }
}
