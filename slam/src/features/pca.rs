//! Principal component analysis of raw patch vectors (the paper's dimensionality
//! reduction), with back-projection for the appearance mosaics of figure 3.

use nalgebra::{DMatrix, DVector, SymmetricEigen};
use serde::{Deserialize, Serialize};

use super::FeatureError;

/// A fitted PCA: `mean` (D) and the leading eigenvectors as columns of `basis` (D x d).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Pca {
    pub mean: DVector<f64>,
    pub basis: DMatrix<f64>,
    /// Variance along each kept direction.
    pub variances: Vec<f64>,
    /// Fraction of the total variance the kept directions explain.
    pub explained_variance: f64,
}

impl Pca {
    /// Fits on `data` (rows are samples) keeping `dims` directions.
    pub fn fit(data: &DMatrix<f64>, dims: usize) -> Result<Pca, FeatureError> {
        let (n, d) = data.shape();
        if n < 2 {
            return Err(FeatureError::Training("PCA needs at least two samples".into()));
        }
        if dims == 0 || dims > d {
            return Err(FeatureError::Training(format!("PCA dimension {dims} must be between 1 and {d}")));
        }
        if let Some(k) = data.iter().position(|v| !v.is_finite()) {
            // Column-major: index k is row k % n of column k / n.
            return Err(FeatureError::Training(format!(
                "PCA data at row {}, column {} is not a finite number",
                k % n,
                k / n
            )));
        }
        let mean = DVector::from_iterator(d, data.column_iter().map(|c| c.sum() / n as f64));
        let mut centred = data.clone();
        for (j, mut col) in centred.column_iter_mut().enumerate() {
            col.add_scalar_mut(-mean[j]);
        }
        let cov = centred.tr_mul(&centred) / (n as f64 - 1.0);
        let eig = SymmetricEigen::new(cov);
        let mut order: Vec<usize> = (0..d).collect();
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]).then(a.cmp(&b)));
        let total: f64 = eig.eigenvalues.iter().map(|v| v.max(0.0)).sum();
        let mut basis = DMatrix::zeros(d, dims);
        let mut variances = Vec::with_capacity(dims);
        for (k, &i) in order.iter().take(dims).enumerate() {
            let mut v = eig.eigenvectors.column(i).into_owned();
            // Sign convention: the largest-magnitude entry is positive (reproducible files).
            let imax = v.iamax();
            if v[imax] < 0.0 {
                v.neg_mut();
            }
            basis.set_column(k, &v);
            variances.push(eig.eigenvalues[i].max(0.0));
        }
        // Directions the data do not vary in (to rounding) would give every patch the same
        // coordinate there, and the mixtures fitted on them a singular covariance: blank
        // training images, or more dimensions than the patches have.
        if !(total > 0.0) {
            return Err(FeatureError::Training(
                "the data do not vary: every sample is the same (are the training images blank?)".into(),
            ));
        }
        if let Some(k) = variances.iter().position(|v| *v <= 1e-10 * variances[0]) {
            let directions = if k == 1 { "direction" } else { "directions" };
            return Err(FeatureError::Training(format!(
                "the data vary in only {k} {directions}; a PCA of {dims} dimensions needs as many (give {k} or fewer)"
            )));
        }
        let explained_variance = variances.iter().sum::<f64>() / total;
        Ok(Pca { mean, basis, variances, explained_variance })
    }

    pub fn input_dims(&self) -> usize {
        self.mean.len()
    }

    pub fn dims(&self) -> usize {
        self.basis.ncols()
    }

    /// [`FeatureError::PcaMismatch`] unless the basis has a row per value of the mean (a
    /// PCA put together field by field may not): cheap enough for every projection.
    fn check_basis(&self) -> Result<(), FeatureError> {
        if self.basis.nrows() != self.mean.len() {
            return Err(FeatureError::PcaMismatch { expected: self.mean.len(), found: self.basis.nrows() });
        }
        Ok(())
    }

    /// Checks a PCA read from a file: shapes that agree, a mean within f32's range (the
    /// raw features are single-precision numbers, so no mean of them lies beyond it) and a
    /// basis of orthonormal columns, as eigenvectors are (a larger entry would also be
    /// infinite in the single-precision projection); (field, problem).
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        if self.basis.nrows() != self.mean.len() {
            return Err(("basis", format!("has {} rows for a {}-long mean", self.basis.nrows(), self.mean.len())));
        }
        if self.variances.len() != self.dims() {
            return Err(("variances", format!("has {} entries for {} directions", self.variances.len(), self.dims())));
        }
        if self.mean.iter().chain(self.basis.iter()).any(|v| !v.is_finite()) {
            return Err(("basis", "mean and basis must be finite".into()));
        }
        if let Some(v) = self.mean.iter().find(|v| v.abs() > f32::MAX as f64) {
            return Err(("mean", format!("{v:e} lies beyond single precision's range")));
        }
        // Orthonormal to well within what the f64 text of a trained basis keeps.
        const ORTHONORMAL_TOLERANCE: f64 = 1e-6;
        let gram = self.basis.tr_mul(&self.basis);
        for ((i, j), g) in gram.iter().enumerate().map(|(k, g)| ((k % gram.nrows(), k / gram.nrows()), g)) {
            let expected = if i == j { 1.0 } else { 0.0 };
            if (g - expected).abs() > ORTHONORMAL_TOLERANCE {
                return Err((
                    "basis",
                    format!(
                        "columns {i} and {j} have a dot product of {g:e}, not {expected}: a PCA basis is orthonormal (its eigenvectors)"
                    ),
                ));
            }
        }
        if self.variances.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err(("variances", "must be finite and not negative".into()));
        }
        Ok(())
    }

    /// Projects rows of `data` (N x D) to N x d; rows of another length than D are
    /// [`FeatureError::PcaMismatch`].
    pub fn project(&self, data: &DMatrix<f64>) -> Result<DMatrix<f64>, FeatureError> {
        self.check_basis()?;
        if data.ncols() != self.input_dims() {
            return Err(FeatureError::PcaMismatch { expected: self.input_dims(), found: data.ncols() });
        }
        let mut out = data * &self.basis;
        let shift = self.basis.tr_mul(&self.mean);
        for (j, mut col) in out.column_iter_mut().enumerate() {
            col.add_scalar_mut(-shift[j]);
        }
        Ok(out)
    }

    /// Projects `n` row-major f32 raw vectors (the feature extractor's fast path: one
    /// single-precision matrix product) to N x d; `rows` holds `n` x D values.
    pub(crate) fn project_rows_f32(&self, rows: &[f32], n: usize) -> DMatrix<f64> {
        let dims = self.input_dims();
        debug_assert_eq!(rows.len(), n * dims);
        let x = nalgebra::DMatrixView::<f32>::from_slice(rows, dims, n);
        let basis_t = DMatrix::<f32>::from_fn(self.dims(), dims, |i, j| self.basis[(j, i)] as f32);
        let zt = basis_t * x;
        let shift = self.basis.tr_mul(&self.mean);
        DMatrix::from_fn(n, self.dims(), |i, j| zt[(j, i)] as f64 - shift[j])
    }

    /// Maps an appearance vector back to a raw patch vector: its first d values (a patch's
    /// feature row, which carries neighbour norms after them, will do). One shorter than d
    /// is [`FeatureError::AppearanceLength`].
    pub fn back_project(&self, z: &[f64]) -> Result<DVector<f64>, FeatureError> {
        self.check_basis()?;
        let Some(z) = z.get(..self.dims()) else {
            return Err(FeatureError::AppearanceLength { expected: self.dims(), found: z.len() });
        };
        Ok(&self.mean + &self.basis * DVector::from_column_slice(z))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fitted PCA passes its own check; a hand-edited one whose values the single-precision
    /// projection would make infinite, or whose basis is no longer orthonormal, does not
    /// (it had classified every patch as background without a word).
    #[test]
    fn a_pca_edited_past_what_it_can_be_is_refused() {
        let data = DMatrix::from_fn(40, 5, |i, j| ((i * 7 + j * 3) % 11) as f64 + 0.1 * (i * j) as f64);
        let pca = Pca::fit(&data, 3).unwrap();
        pca.check().unwrap();
        let mut wide = pca.clone();
        wide.basis[(0, 0)] = 1e39;
        assert_eq!(wide.check().unwrap_err().0, "basis");
        let mut far = pca.clone();
        far.mean[1] = 1e300;
        let (field, problem) = far.check().unwrap_err();
        assert_eq!(field, "mean", "{problem}");
        let mut skewed = pca.clone();
        skewed.basis[(2, 1)] += 0.01;
        let (field, problem) = skewed.check().unwrap_err();
        assert!(field == "basis" && problem.contains("orthonormal"), "{problem}");
    }
}
