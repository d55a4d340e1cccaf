#!/usr/bin/env python3
"""Spatial context of patch labels, measured offline on dumped posteriors.

Compares, on another world's images, the mixtures' patch decisions alone with two ways of
using the neighbouring patches, both fitted on images the mixtures were not trained on:
  - a pairwise Markov random field over the patch grid (Ising/Potts coupling, separate
    vertical and horizontal strengths, fitted by pseudo-likelihood on the true labels,
    decided by mean-field inference);
  - the column context `objslam train --context` learns (a logistic regression on a
    patch's own log-odds and its column's), for reference against the Rust implementation.

Usage (docs/results.md#spatial-context-of-patch-labels):
  objslam train --dataset A --out m.json --pca-dims 10 --max-components 10
  cargo run --release -p scenarios --example patch_posteriors -- m.json A a.csv
  cargo run --release -p scenarios --example patch_posteriors -- m.json B b.csv
  python3 scripts/patch_context.py a.csv b.csv
The fit uses A's held-out images (every 5th, which `objslam train` kept from the mixtures).
Needs numpy.
"""
import sys

import numpy as np

NAMES = {0: "sky", 1: "ground", 2: "tree", 3: "palm", 4: "post", 5: "wall", 6: "person", 8: "foliage"}
MAX_LOG_ODDS = 27.631021115928547


def load(path):
    d = np.genfromtxt(path, delimiter=",", skip_header=1)
    grids = {}
    for i in np.unique(d[:, 0]).astype(int):
        s = d[d[:, 0] == i]
        cols, rows = int(s[:, 1].max()) + 1, int(s[:, 2].max()) + 1
        p, y, k = np.full((rows, cols), 0.5), np.zeros((rows, cols)), np.zeros((rows, cols), int)
        c, r = s[:, 1].astype(int), s[:, 2].astype(int)
        p[r, c], y[r, c], k[r, c] = s[:, 3], s[:, 5] >= 0.5, s[:, 6]
        grids[i] = (p, y, k)
    return grids


def logit(p):
    p = np.clip(p, 1e-12, 1 - 1e-12)
    return np.clip(np.log(p) - np.log1p(-p), -MAX_LOG_ODDS, MAX_LOG_ODDS)


def shift(m, dr, dc):
    """m moved by (dr, dc): out[r, c] = m[r + dr, c + dc], 0 past the edges."""
    out = np.zeros_like(m)
    rows, cols = m.shape
    out[max(-dr, 0):rows - max(dr, 0), max(-dc, 0):cols - max(dc, 0)] = m[max(dr, 0):rows - max(-dr, 0), max(dc, 0):cols - max(-dc, 0)]
    return out


def neighbours(m):
    return shift(m, -1, 0) + shift(m, 1, 0), shift(m, 0, -1) + shift(m, 0, 1)


def fit_logistic(x, y):
    w = np.zeros(x.shape[1])
    for _ in range(50):
        p = 1 / (1 + np.exp(-(x @ w)))
        step = np.linalg.solve((x * (p * (1 - p))[:, None]).T @ x + 1e-6 * np.eye(len(w)), x.T @ (y - p))
        w += step
        if np.abs(step).max() < 1e-9:
            break
    return w


def mrf_terms(p, y):
    v, h = neighbours(2 * y - 1)
    return np.stack([logit(p).ravel(), np.ones(p.size), v.ravel(), h.ravel()], 1)


def mean_field(p, w, iterations=10):
    field = w[0] * logit(p) + w[1]
    q = 1 / (1 + np.exp(-field))
    for _ in range(iterations):
        v, h = neighbours(2 * q - 1)
        q = 0.5 * q + 0.5 / (1 + np.exp(-(field + w[2] * v + w[3] * h)))
    return q


def column_terms(p, reach=12):
    lo = logit(p)
    rows = lo.shape[0]
    cum = np.vstack([np.zeros((1, lo.shape[1])), np.cumsum(lo, 0)])
    above, below = np.zeros_like(lo), np.zeros_like(lo)
    for r in range(rows):
        a0, a1 = max(r - reach, 0), max(r - 1, 0)
        b0, b1 = min(r + 2, rows), min(r + reach + 1, rows)
        if a0 < a1:
            above[r] = (cum[a1] - cum[a0]) / (a1 - a0)
        if b0 < b1:
            below[r] = (cum[b1] - cum[b0]) / (b1 - b0)
    t = [lo, np.ones_like(lo), shift(lo, -1, 0), shift(lo, 1, 0), above, below]
    return np.stack([x.ravel() for x in t], 1)


def score(grids, decide):
    tp = fp = fn = 0
    by_class = {}
    for p, y, k in grids.values():
        called = decide(p) > 0.5
        tp += np.sum(called & (y == 1))
        fp += np.sum(called & (y == 0))
        fn += np.sum(~called & (y == 1))
        for c in np.unique(k):
            n = by_class.setdefault(NAMES.get(c, str(c)), [0, 0])
            n[0] += np.sum(k == c)
            n[1] += np.sum(called[k == c])
    shares = ", ".join(f"{c} {100 * n[1] / n[0]:.1f}%" for c, n in sorted(by_class.items()))
    return f"precision {tp / (tp + fp):.3f}, recall {tp / (tp + fn):.3f}; called object: {shares}"


def main():
    train, other = load(sys.argv[1]), load(sys.argv[2])
    fit_on = {i: g for i, g in train.items() if i % 5 == 4}
    print("mixtures alone:", score(other, lambda p: p))
    x = np.vstack([mrf_terms(p, y) for p, y, _ in fit_on.values()])
    w = fit_logistic(x, np.concatenate([y.ravel() for _, y, _ in fit_on.values()]))
    print(f"MRF weights (own log-odds, constant, vertical, horizontal): {np.round(w, 3)}")
    print("MRF, mean field:", score(other, lambda p: mean_field(p, w)))
    x = np.vstack([column_terms(p) for p, _, _ in fit_on.values()])
    w = fit_logistic(x, np.concatenate([y.ravel() for _, y, _ in fit_on.values()]))
    print(f"column context weights: {np.round(w, 3)}")
    print("column context:", score(other, lambda p: (1 / (1 + np.exp(-(column_terms(p) @ w)))).reshape(p.shape)))


if __name__ == "__main__":
    main()
