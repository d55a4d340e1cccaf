"""The model search against scikit-learn's BayesianGaussianMixture, end to end, on one CSV.

Fits the same training CSV with `objslam gmm fit --search prune` (all cores) and with
scikit-learn (n_components = the same upper limit, one BLAS thread, objslam's default prior:
alpha0 = 1, beta0 = 1, nu0 = D, m0 = the data mean, W0^-1 = the data covariance), then scores
both on a held-out CSV with one formula: the mean posterior predictive log-density per point,
the mixture of Student-t of PRML 10.81, computed here in NumPy from each fit's posterior.
objslam's own `objslam gmm score` figure is printed beside it as a cross-check.

    python3 slam/benches/sklearn_compare.py [--objslam target/release/objslam]
        [--train CSV --heldout CSV] [--out DIR] [--max-components 10] [--repeat 3] [--search prune|grow]

Without --train it draws its own data set into DIR: 25,000 points in 14 dimensions from 6
overlapping full-covariance Gaussians with uneven weights (NumPy seed 6), 20,000 to train on
and 5,000 held out. Needs numpy, scipy, scikit-learn and threadpoolctl.
"""
import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np
from scipy.special import gammaln, logsumexp
from sklearn.mixture import BayesianGaussianMixture
from threadpoolctl import threadpool_limits


def draw(out, n=25_000, d=14, k=6, seed=6):
    rng = np.random.default_rng(seed)
    weights = np.arange(1, k + 1, dtype=float)
    weights /= weights.sum()
    means = 4.0 * rng.standard_normal((k, d))
    mix = rng.uniform(-0.5, 0.5, (k, d, d))
    labels = rng.choice(k, size=n, p=weights)
    z = rng.standard_normal((n, d))
    x = means[labels] + np.einsum("nij,nj->ni", mix[labels], z) + 0.3 * z
    train, heldout = os.path.join(out, "train.csv"), os.path.join(out, "heldout.csv")
    np.savetxt(train, x[:20_000], delimiter=",", fmt="%.9e")
    np.savetxt(heldout, x[20_000:], delimiter=",", fmt="%.9e")
    return train, heldout


def predictive_log_density(x, alpha, beta, nu, means, w_inv):
    """Mean over the rows of x of ln sum_k pi_k St(x | m_k, L_k, nu_k + 1 - D), PRML 10.81."""
    d = x.shape[1]
    log_w = np.log(alpha / alpha.sum())
    terms = np.empty((x.shape[0], len(alpha)))
    for k in range(len(alpha)):
        dof = nu[k] + 1.0 - d
        # L = dof beta / (1 + beta) W, so L^-1 = (1 + beta) / (dof beta) W^-1.
        scale = w_inv[k] * (1.0 + beta[k]) / (dof * beta[k])
        chol = np.linalg.cholesky(scale)
        y = np.linalg.solve(chol, (x - means[k]).T)
        maha = (y * y).sum(axis=0)
        log_det_scale = 2.0 * np.log(np.diag(chol)).sum()
        log_norm = gammaln((dof + d) / 2) - gammaln(dof / 2) - 0.5 * d * np.log(dof * np.pi) - 0.5 * log_det_scale
        terms[:, k] = log_w[k] + log_norm - 0.5 * (dof + d) * np.log1p(maha / dof)
    return logsumexp(terms, axis=1).mean()


def matrix(v, rows, cols):
    # nalgebra serialises a matrix as [data (column-major), rows, cols].
    data = v[0] if isinstance(v[0], list) else v
    return np.array(data, dtype=float).reshape(rows, cols, order="F")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objslam", default="target/release/objslam")
    ap.add_argument("--train")
    ap.add_argument("--heldout")
    ap.add_argument("--out", default="sklearn_compare")
    ap.add_argument("--max-components", type=int, default=10)
    ap.add_argument("--repeat", type=int, default=3, help="timed fits per side; the fastest counts")
    ap.add_argument("--search", choices=["prune", "grow"], default="prune", help="objslam's model search")
    args = ap.parse_args()
    if args.repeat < 1:
        sys.exit("--repeat must be at least 1")
    os.makedirs(args.out, exist_ok=True)
    if args.train:
        if not args.heldout:
            sys.exit("--train needs --heldout")
        train, heldout = args.train, args.heldout
    else:
        train, heldout = draw(args.out)
    x = np.loadtxt(train, delimiter=",", ndmin=2)
    xh = np.loadtxt(heldout, delimiter=",", ndmin=2)
    n, d = x.shape
    print(f"{train}: {n} x {d}; held out {heldout}: {xh.shape[0]} points")

    model = os.path.join(args.out, "objslam_model.json")
    ours = []
    for _ in range(args.repeat):
        t = time.perf_counter()
        fit = subprocess.run(
            [args.objslam, "gmm", "fit", train, "--search", args.search, "--max-components", str(args.max_components),
             "--out", model],
            check=True, capture_output=True, text=True)
        ours.append(time.perf_counter() - t)
    m = json.load(open(model))
    comps = m["components"]
    ours_ll = predictive_log_density(
        xh,
        np.array([c["alpha"] for c in comps]),
        np.array([c["beta"] for c in comps]),
        np.array([c["nu"] for c in comps]),
        np.array([matrix(c["mean"], d, 1).reshape(-1) for c in comps]),
        np.array([matrix(c["w_inv"], d, d) for c in comps]),
    )
    own = subprocess.run([args.objslam, "gmm", "score", model, heldout], check=True, capture_output=True, text=True)
    iterations = next((l.split(":")[1].strip() for l in fit.stdout.splitlines() if "VBEM iterations" in l), "?")
    k_ours = int((np.array(m["counts"]) / n > 1e-3).sum())

    cov = np.cov(x, rowvar=False, bias=True)
    cov[np.diag_indices(d)] += 1e-6 * np.trace(cov) / d
    sk = []
    with threadpool_limits(limits=1):
        for _ in range(args.repeat):
            gm = BayesianGaussianMixture(
                n_components=args.max_components,
                covariance_type="full",
                weight_concentration_prior_type="dirichlet_distribution",
                weight_concentration_prior=1.0,
                mean_precision_prior=1.0,
                mean_prior=x.mean(axis=0),
                degrees_of_freedom_prior=float(d),
                covariance_prior=cov,
                max_iter=2000,
                random_state=0,
            )
            t = time.perf_counter()
            gm.fit(x)
            sk.append(time.perf_counter() - t)
    # sklearn keeps covariances_ = W^-1 / nu.
    sk_ll = predictive_log_density(
        xh, gm.weight_concentration_, gm.mean_precision_, gm.degrees_of_freedom_, gm.means_,
        gm.covariances_ * gm.degrees_of_freedom_[:, None, None])

    print(f"objslam gmm fit:  {min(ours):.3f} s (process, CSV read included; of {len(ours)}), "
          f"{iterations} VBEM iterations, K = {k_ours} above 1e-3")
    print(f"scikit-learn:     {min(sk):.3f} s (fit only, 1 BLAS thread; of {len(sk)}), "
          f"{gm.n_iter_} iterations, converged {gm.converged_}, K = {int((gm.weights_ > 1e-3).sum())} above 1e-3")
    print(f"speed-up: {min(sk) / min(ours):.2f}x")
    print(f"held-out predictive log-likelihood per point: objslam {ours_ll:.4f}, scikit-learn {sk_ll:.4f}, "
          f"difference {ours_ll - sk_ll:+.4f} nats")
    print(f"objslam gmm score says: {own.stdout.strip().splitlines()[-1] if own.stdout.strip() else '?'}")


if __name__ == "__main__":
    main()
