#!/usr/bin/env python3
"""How far Victoria Park's GPS can be trusted as the reference of `objslam replay
victoria-park`, from the data set's own files. Run by hand (it needs numpy and scipy):

    python3 scripts/victoria_park_gps.py DIR [OUT ...]

DIR holds `aa3_gpsx.mat` and `VictoriaParkSinSincronizar.mat` as published. It prints how
often the GPS moves, within one fix interval (0.2 s), further than the car's wheel
encoder says the car went: such a step means a GPS error of at least the excess on one
side of it. For each replay output directory OUT it prints the ATE against the GPS (the
replay's rigid 2-D fit, recomputed, fixes more than 30 m off dropped as spikes), the mean
residual in 10 s windows of the stretch 1030-1110 s after the first fix, the ATE with
that stretch left out, and the ATE if the GPS antenna stood elsewhere on the car than the
laser: the body-frame offset (forward, left; a 0.05 m grid within 1 m) whose point fits
the GPS best, with its ATE. A GPS compared with the wrong point of the car would show as
an offset that fits much better than none.
"""
import sys
from pathlib import Path

import numpy as np
import scipy.io as sio

data = Path(sys.argv[1])
gps = sio.loadmat(data / "aa3_gpsx.mat")
tg = gps["timeGps"].ravel() / 1000.0
g = np.stack([gps["Lo_m"].ravel(), gps["La_m"].ravel()], 1)
log = sio.loadmat(data / "VictoriaParkSinSincronizar.mat")
t_odo, speed = log["time"].ravel(), np.abs(log["u"][0])

step = np.hypot(*np.diff(g, axis=0).T)
dt = np.diff(tg)
wheel = np.interp(tg[1:], t_odo, speed) * dt
one_interval = dt < 0.25
print(f"{len(tg)} GPS fixes; steps within one fix interval beyond the wheels' travel:")
for excess in (1.0, 2.0, 3.0):
    print(f"  by more than {excess:.0f} m: {int(((step - wheel > excess) & one_interval).sum())}")


def fit(a, b, w):
    """Residuals of a after the rigid 2-D motion that best fits a[w] to b[w]."""
    ca, cb = a[w].mean(0), b[w].mean(0)
    u, _, vt = np.linalg.svd((a[w] - ca).T @ (b[w] - cb))
    r = vt.T @ u.T
    if np.linalg.det(r) < 0:
        vt[-1] *= -1
        r = vt.T @ u.T
    return (a - ca) @ r.T + cb - b


for out in sys.argv[2:]:
    est = np.loadtxt(Path(out) / "trajectory_est.tum")
    inside = (tg >= est[0, 0]) & (tg <= est[-1, 0])
    t = tg[inside] - tg[0]
    a = np.stack([np.interp(tg[inside], est[:, 0], est[:, k]) for k in (1, 2)], 1)
    b = g[inside]
    keep = np.hypot(*fit(a, b, np.ones(len(a), bool)).T) < 30.0
    res = fit(a, b, keep)
    err = np.hypot(*res.T)
    print(f"{out}: ATE {np.sqrt((err[keep] ** 2).mean()):.3f} m over {keep.sum()} fixes")
    for start in range(1030, 1110, 10):
        w = keep & (t >= start) & (t < start + 10)
        if w.any():
            m = res[w].mean(0)
            print(f"  {start}-{start + 10} s: {w.sum():3d} fixes, mean residual ({m[0]:+.2f}, {m[1]:+.2f}) m")
    rest = keep & ~((t > 1042) & (t < 1101.7))
    err = np.hypot(*fit(a, b, rest).T)
    print(f"  without 1042-1101.7 s: ATE {np.sqrt((err[rest] ** 2).mean()):.3f} m over {rest.sum()} fixes")
    heading = np.unwrap(2.0 * np.arctan2(est[:, 6], est[:, 7]))
    phi = np.interp(tg[inside], est[:, 0], heading)
    c, s = np.cos(phi), np.sin(phi)

    def ate_at(fwd, left):
        p = a + np.stack([fwd * c - left * s, fwd * s + left * c], 1)
        err = np.hypot(*fit(p, b, keep).T)
        return np.sqrt((err[keep] ** 2).mean())

    grid = np.round(np.arange(-1.0, 1.0001, 0.05), 2)
    best = min((ate_at(f, l), f, l) for f in grid for l in grid)
    print(f"  best antenna offset ({best[1]:+.2f} m forward, {best[2]:+.2f} m left): ATE {best[0]:.3f} m")
