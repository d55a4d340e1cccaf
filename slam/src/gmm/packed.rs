//! The VBEM steps of the pruning search, written for speed. They compute what
//! [`super::vbem::e_step`] and [`super::vbem::m_step`] compute, in another order, so results
//! differ in the last bits; the growing search keeps the reference steps so that trained
//! models stay as they were.
//!
//! - E-step: the quadratic form |C^-1 (x - m)|^2 through the packed lower triangle of C^-1
//!   (D (D + 1) / 2 products a point instead of D^2), eight points side by side so the
//!   compiler vectorises across points.
//! - M-step: the scatter matrix's lower triangle from blocks of rows small enough to stay in
//!   the L1 cache, instead of an N x D copy of the data per component and a full product.
//!
//! Every point and every component is computed the same way on any thread, so the results do
//! not depend on the thread count.

use nalgebra::{DMatrix, DVector};

use super::GmmError;
use super::vbem::{self, Stats, VbComponent, VbPrior, per_component};

/// Points computed side by side in the E-step.
const LANES: usize = 8;

/// Rows per block of the M-step's scatter sums: two arrays of D x 128 values, 28 KiB at 14
/// dimensions, within a 32 KiB L1 cache up to D = 16.
const BLOCK_ROWS: usize = 128;

/// E-step: responsibilities r_nk (PRML 10.46-10.49).
pub(crate) fn e_step(data: &DMatrix<f64>, comps: &[VbComponent]) -> Result<DMatrix<f64>, GmmError> {
    let (n, d) = data.shape();
    let k = comps.len();
    let ex = vbem::expectations(comps)?;
    let columns: Vec<&[f64]> = (0..d).map(|j| column(data, j)).collect();
    let out = per_component(n, k, |kk| -> Result<Vec<f64>, GmmError> {
        let (c, e) = (&comps[kk], &ex[kk]);
        let c_inv = e.whitening(kk)?;
        let packed: Vec<f64> = (0..d).flat_map(|i| (0..=i).map(move |j| (i, j))).map(|(i, j)| c_inv[(i, j)]).collect();
        let base = e.log_rho_base(c);
        let mut log_rho = vec![0.0; n];
        mahalanobis(&columns, c.mean.as_slice(), &packed, &mut log_rho);
        for v in &mut log_rho {
            *v = base - 0.5 * c.nu * *v;
        }
        Ok(log_rho)
    });
    vbem::normalise(n, out)
}

/// `out[n]` = |C^-1 (x_n - mean)|^2 for every point, C^-1 given by its lower triangle packed
/// row by row.
fn mahalanobis(columns: &[&[f64]], mean: &[f64], packed: &[f64], out: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the processor has AVX, checked just above.
        return unsafe { mahalanobis_avx(columns, mean, packed, out) };
    }
    mahalanobis_body(columns, mean, packed, out)
}

/// The same loops compiled for AVX's 4-wide registers. Without FMA every product and sum is
/// rounded as in the baseline code, so results are bit-identical on every x86-64 processor.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn mahalanobis_avx(columns: &[&[f64]], mean: &[f64], packed: &[f64], out: &mut [f64]) {
    mahalanobis_body(columns, mean, packed, out)
}

#[inline(always)]
fn mahalanobis_body(columns: &[&[f64]], mean: &[f64], packed: &[f64], out: &mut [f64]) {
    let (n, d) = (out.len(), columns.len());
    let mut diff = vec![[0.0f64; LANES]; d];
    let mut start = 0;
    while start < n {
        let lanes = LANES.min(n - start);
        for (j, dj) in diff.iter_mut().enumerate() {
            let x = &columns[j][start..start + lanes];
            for l in 0..LANES {
                dj[l] = if l < lanes { x[l] - mean[j] } else { 0.0 };
            }
        }
        let mut maha = [0.0f64; LANES];
        let mut at = 0;
        for i in 0..d {
            let row = &packed[at..at + i + 1];
            let mut y = [0.0f64; LANES];
            for (wij, dj) in row.iter().zip(&diff) {
                for l in 0..LANES {
                    y[l] += wij * dj[l];
                }
            }
            for l in 0..LANES {
                maha[l] += y[l] * y[l];
            }
            at += i + 1;
        }
        out[start..start + lanes].copy_from_slice(&maha[..lanes]);
        start += lanes;
    }
}

/// M-step: sufficient statistics from responsibilities `r` (N x K), then the posterior.
pub(crate) fn m_step(data: &DMatrix<f64>, r: &DMatrix<f64>, prior: &VbPrior) -> (Vec<VbComponent>, Stats) {
    let (n, d) = data.shape();
    let k = r.ncols();
    let columns: Vec<&[f64]> = (0..d).map(|j| column(data, j)).collect();
    vbem::collect(per_component(n, k, |kk| {
        let rk = column(r, kk);
        let nk: f64 = rk.iter().sum();
        let r_ln_r: f64 = rk.iter().map(|&v| if v > 0.0 { v * v.ln() } else { 0.0 }).sum();
        let (xbar, s) = if nk > 1e-300 { moments(&columns, rk, nk) } else { (prior.m0.clone(), DMatrix::zeros(d, d)) };
        (vbem::posterior(prior, nk, &xbar, &s), nk, xbar, s, r_ln_r)
    }))
}

/// The responsibility-weighted mean xbar = sum_n r_n x_n / N_k and scatter
/// S = sum_n r_n (x_n - xbar)(x_n - xbar)^T / N_k, symmetric, from its lower triangle.
fn moments(columns: &[&[f64]], r: &[f64], nk: f64) -> (DVector<f64>, DMatrix<f64>) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the processor has AVX, checked just above.
        return unsafe { moments_avx(columns, r, nk) };
    }
    moments_body(columns, r, nk)
}

/// [`moments`] compiled for AVX, bit-identical as [`mahalanobis_avx`] is.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn moments_avx(columns: &[&[f64]], r: &[f64], nk: f64) -> (DVector<f64>, DMatrix<f64>) {
    moments_body(columns, r, nk)
}

#[inline(always)]
fn moments_body(columns: &[&[f64]], r: &[f64], nk: f64) -> (DVector<f64>, DMatrix<f64>) {
    let xbar = DVector::from_iterator(columns.len(), columns.iter().map(|x| dot(x, r) / nk));
    let s = scatter(columns, r, &xbar) / nk;
    (xbar, s)
}

/// sum_n r_n (x_n - xbar)(x_n - xbar)^T from its lower triangle: within a block of rows,
/// u_j = x_j - xbar_j and v_j = r u_j, and entry (i, j) is the dot product of v_i and u_j.
#[inline(always)]
fn scatter(columns: &[&[f64]], r: &[f64], xbar: &DVector<f64>) -> DMatrix<f64> {
    let d = columns.len();
    let n = r.len();
    // Per entry of the lower triangle, four running sums (rows t = l mod 4), added together
    // once at the end: no reduction inside the loops, and four entries at a time so the
    // additions need not wait on each other.
    let mut acc = vec![[0.0f64; 4]; d * (d + 1) / 2];
    // u_j and v_j for one block of rows; rows past the data stay zero and add nothing.
    let (mut u, mut v) = (vec![0.0; d * BLOCK_ROWS], vec![0.0; d * BLOCK_ROWS]);
    let mut start = 0;
    while start < n {
        let rows = BLOCK_ROWS.min(n - start);
        let padded = rows.div_ceil(4) * 4;
        for (j, x) in columns.iter().enumerate() {
            let (uj, vj) = (&mut u[j * BLOCK_ROWS..(j + 1) * BLOCK_ROWS], &mut v[j * BLOCK_ROWS..(j + 1) * BLOCK_ROWS]);
            for (((ou, ov), &xv), &rv) in
                uj.iter_mut().zip(vj.iter_mut()).zip(&x[start..start + rows]).zip(&r[start..start + rows])
            {
                *ou = xv - xbar[j];
                *ov = rv * *ou;
            }
            uj[rows..].fill(0.0);
            vj[rows..].fill(0.0);
        }
        let block = |j: usize| &u[j * BLOCK_ROWS..j * BLOCK_ROWS + padded];
        let mut at = 0;
        for i in 0..d {
            let zi = &v[i * BLOCK_ROWS..i * BLOCK_ROWS + padded];
            let mut j = 0;
            while j + 4 <= i + 1 {
                let mut sums = [acc[at], acc[at + 1], acc[at + 2], acc[at + 3]];
                let quads = zi
                    .chunks_exact(4)
                    .zip(block(j).chunks_exact(4))
                    .zip(block(j + 1).chunks_exact(4))
                    .zip(block(j + 2).chunks_exact(4))
                    .zip(block(j + 3).chunks_exact(4));
                for ((((a, b0), b1), b2), b3) in quads {
                    for l in 0..4 {
                        sums[0][l] += a[l] * b0[l];
                        sums[1][l] += a[l] * b1[l];
                        sums[2][l] += a[l] * b2[l];
                        sums[3][l] += a[l] * b3[l];
                    }
                }
                acc[at..at + 4].copy_from_slice(&sums);
                at += 4;
                j += 4;
            }
            while j <= i {
                let mut sum = acc[at];
                for (a, b) in zi.chunks_exact(4).zip(block(j).chunks_exact(4)) {
                    for l in 0..4 {
                        sum[l] += a[l] * b[l];
                    }
                }
                acc[at] = sum;
                at += 1;
                j += 1;
            }
        }
        start += rows;
    }
    let mut s = DMatrix::zeros(d, d);
    let mut at = 0;
    for i in 0..d {
        for j in 0..=i {
            let sum = (acc[at][0] + acc[at][1]) + (acc[at][2] + acc[at][3]);
            s[(i, j)] = sum;
            s[(j, i)] = sum;
            at += 1;
        }
    }
    s
}

/// a . b with two vectors of four running sums, so the additions need not wait on each other.
#[inline(always)]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let (mut lo, mut hi) = ([0.0f64; 4], [0.0f64; 4]);
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ta, tb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for l in 0..4 {
            lo[l] += x[l] * y[l];
            hi[l] += x[4 + l] * y[4 + l];
        }
    }
    for l in 0..4 {
        lo[l] += hi[l];
    }
    let tail: f64 = ta.iter().zip(tb).map(|(x, y)| x * y).sum();
    (lo[0] + lo[1]) + (lo[2] + lo[3]) + tail
}

/// Column `j` of a matrix as one contiguous slice (nalgebra stores columns contiguously).
fn column(m: &DMatrix<f64>, j: usize) -> &[f64] {
    let n = m.nrows();
    &m.as_slice()[j * n..(j + 1) * n]
}
