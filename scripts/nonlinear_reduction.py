#!/usr/bin/env python3
"""Linear against non-linear reduction of the patch features, with one mixture classifier.

Usage:
  python3 scripts/nonlinear_reduction.py TRAIN.csv HELDOUT.csv [HELDOUT.csv ...] [--dims D] [--seeds S]

Each CSV is written by `cargo run --release -p scenarios --example patch_features -- MODEL
DATASET OUT.csv` with one model (trained with a large `--pca-dims`, e.g. 40) for every
dataset: TRAIN from the training world, HELDOUT from other worlds. The paper reduces the
Gabor features linearly (PCA) and names non-linear reduction as future work; this asks
whether a kernel PCA (RBF, Nystroem approximation) of the same features separates trunks
from the rest better than the linear PCA does, held out on other worlds.

For each reduction: the first D principal components (what a D-dimensional model uses),
all of the CSV's components, and kernel PCA of them to D dimensions fitted (unsupervised)
on the training patches. As in objslam's features, each reduced row is followed by the
norms of the reduced rows of its four neighbours (the patch's own at the image's edge). Each class gets a variational Gaussian mixture (scikit-learn's, up to 10
components); a patch is object when its posterior with the training class prior exceeds
0.5. Training uses images i % 5 != 4 of TRAIN; the others are the same world held out.
Needs numpy and scikit-learn.
"""
import argparse
import sys

import numpy as np
from sklearn.decomposition import PCA
from sklearn.kernel_approximation import Nystroem
from sklearn.mixture import BayesianGaussianMixture
from sklearn.pipeline import make_pipeline

POST, PALM, PERSON = 4, 3, 6


def load(path):
    with open(path) as f:
        header = f.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    # The principal components; the last four z columns are neighbour norms, recomputed
    # here for each reduction.
    z = [k for k, name in enumerate(header) if name.startswith("z")][:-4]
    image, col, row = (data[:, k].astype(int) for k in range(3))
    at = {key: i for i, key in enumerate(zip(image, col, row))}
    own = np.arange(len(data))
    neighbours = np.stack(
        [
            [at.get((m, c + dc, r + dr), i) for i, (m, c, r) in enumerate(zip(image, col, row))]
            for dc, dr in ((0, -1), (0, 1), (-1, 0), (1, 0))
        ],
        axis=1,
    )
    assert neighbours.shape == (len(own), 4)
    return {
        "image": image,
        "z": data[:, z],
        "neighbours": neighbours,
        "object": data[:, header.index("fraction")] >= 0.5,
        "class": data[:, header.index("class")].astype(int),
    }


def with_norms(reduced, part):
    norms = np.linalg.norm(reduced, axis=1)
    return np.hstack([reduced, norms[part["neighbours"]]])


def subsample(rows, n, rng):
    idx = rng.permutation(len(rows))[:n]
    return rows[np.sort(idx)]


def fit_classifier(x, y, seed):
    models = []
    for label in (True, False):
        rows = subsample(x[y == label], 20000, np.random.default_rng(seed))
        g = BayesianGaussianMixture(n_components=10, covariance_type="full", max_iter=300, random_state=seed)
        models.append(g.fit(rows))
    prior = y.mean()
    return models, prior


def classify(models, prior, x):
    obj = models[0].score_samples(x) + np.log(prior)
    bg = models[1].score_samples(x) + np.log(1.0 - prior)
    return obj > bg


def scores(pred, part):
    truth = part["object"]
    tp = np.sum(pred & truth)
    precision = tp / max(np.sum(pred), 1)
    recall = tp / max(np.sum(truth), 1)
    f1 = 2 * precision * recall / max(precision + recall, 1e-12)
    shares = []
    for name, cid in (("posts", POST), ("palms", PALM), ("people", PERSON)):
        of = part["class"] == cid
        if of.sum():
            shares.append(f"{name} {pred[of].mean():.0%} of {of.sum()}")
    return precision, recall, f1, ", ".join(shares)


def select(part, mask):
    """The rows of `part` where `mask`, with their neighbours' indices renumbered (a
    neighbour outside the selection, which whole images never have, becomes the row itself)."""
    keep = np.flatnonzero(mask)
    new = np.full(len(mask), -1)
    new[keep] = np.arange(len(keep))
    out = {k: v[mask] for k, v in part.items() if k != "neighbours"}
    nb = new[part["neighbours"][mask]]
    out["neighbours"] = np.where(nb >= 0, nb, np.arange(len(keep))[:, None])
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("train")
    ap.add_argument("heldout", nargs="+")
    ap.add_argument("--dims", type=int, default=10)
    ap.add_argument("--seeds", type=int, default=3)
    a = ap.parse_args()
    train = load(a.train)
    if a.dims > train["z"].shape[1]:
        sys.exit(f"--dims {a.dims}: the CSVs hold {train['z'].shape[1]} components")
    fit_part = select(train, train["image"] % 5 != 4)
    tests = [("same world, held-out images", select(train, train["image"] % 5 == 4))]
    tests += [(path, load(path)) for path in a.heldout]
    d, full = a.dims, train["z"].shape[1]
    for seed in range(1, a.seeds + 1):
        rng = np.random.default_rng(seed)
        sample = subsample(fit_part["z"], 20000, rng)
        # RBF width from the median squared distance between sampled patches.
        pairs = subsample(sample, 2000, rng)
        sq = ((pairs[:1000, None, :] - pairs[None, 1000:, :]) ** 2).sum(-1)
        gamma = 1.0 / np.median(sq)
        kernel = make_pipeline(
            Nystroem(kernel="rbf", gamma=gamma, n_components=1000, random_state=seed),
            PCA(n_components=d, random_state=seed),
        ).fit(sample)
        reductions = [
            (f"linear PCA, first {d}", lambda z: z[:, :d]),
            (f"linear PCA, all {full}", lambda z: z),
            (f"kernel PCA (RBF) to {d}", kernel.transform),
        ]
        for name, reduce in reductions:
            features = lambda part: with_norms(reduce(part["z"]), part)
            models, prior = fit_classifier(features(fit_part), fit_part["object"], seed)
            for test_name, part in tests:
                p, r, f1, shares = scores(classify(models, prior, features(part)), part)
                print(f"seed {seed} | {name:26} | {test_name}: precision {p:.3f}, recall {r:.3f}, F1 {f1:.3f}; called object: {shares}")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
