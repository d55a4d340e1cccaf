"""Fits scikit-learn's BayesianGaussianMixture to the VBEM benchmark data with objslam's
prior, on one thread, and writes its responsibilities for scoring with objslam's full
bound. See slam/examples/vbem_compare.rs for the three steps."""
import json
import sys
import time

import numpy as np
from sklearn.mixture import BayesianGaussianMixture
from threadpoolctl import threadpool_limits

d = sys.argv[1] if len(sys.argv) > 1 else "vbem_compare"
X = np.loadtxt(f"{d}/data.csv", delimiter=",")
prior = json.load(open(f"{d}/prior.json"))
D = X.shape[1]


def matrix(v, rows, cols):
    # nalgebra serialises a matrix as [data (column-major), rows, cols].
    data = v[0] if isinstance(v[0], list) else v
    return np.array(data, dtype=float).reshape(rows, cols, order="F")


m0 = matrix(prior["m0"], D, 1).reshape(-1)
w0_inv = matrix(prior["w0_inv"], D, D)
with threadpool_limits(limits=1):
    gm = BayesianGaussianMixture(
        n_components=10,
        covariance_type="full",
        weight_concentration_prior_type="dirichlet_distribution",
        weight_concentration_prior=prior["alpha0"],
        mean_precision_prior=prior["beta0"],
        mean_prior=m0,
        degrees_of_freedom_prior=prior["nu0"],
        covariance_prior=w0_inv,
        max_iter=2000,
        random_state=0,
    )
    t = time.perf_counter()
    gm.fit(X)
    elapsed = time.perf_counter() - t
    resp = gm.predict_proba(X)
print(f"scikit-learn: {elapsed:.3f} s, {gm.n_iter_} iterations ({1000 * elapsed / gm.n_iter_:.1f} ms each), "
      f"converged {gm.converged_}, {int((gm.weights_ > 1e-3).sum())} components above 1e-3, its own lower_bound_ {gm.lower_bound_:.3f}")
np.savetxt(f"{d}/sklearn_resp.csv", resp, delimiter=",")
