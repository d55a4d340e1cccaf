#!/usr/bin/env python3
# Usage: python3 scripts/circling_log.py SECONDS OUT_DIR  (needs numpy)
# A robot circling 12 m around a park of 30 trees for T seconds: a raw-laser robot log
# whose map stops growing after one lap, to measure replay memory against log length.
import sys, math, os, numpy as np
T = float(sys.argv[1]); out = sys.argv[2]
os.makedirs(out, exist_ok=True)
rng = np.random.default_rng(1)
trees = []
while len(trees) < 30:
    r = rng.uniform(3, 22); a = rng.uniform(0, 2*math.pi)
    x, y = r*math.cos(a), r*math.sin(a)
    if abs(math.hypot(x, y) - 12) > 2.0: trees.append((x, y, rng.uniform(0.15, 0.4)))
trees = np.array(trees)
R, v = 12.0, 1.0; w = v / R; lap = 2*math.pi/w
beams = np.radians(np.arange(-90, 90.5, 0.5))
def pose(t):
    a = w*t
    return R*math.cos(a), R*math.sin(a), a + math.pi/2
# One lap of scans at 10 Hz, repeated.
n_lap = int(round(lap*10))
lap_scans = []
for k in range(n_lap):
    x, y, th = pose(k/10)
    d = np.stack([np.cos(th+beams), np.sin(th+beams)], 1)
    rng_ = np.full(len(beams), np.inf)
    for tx, ty, tr in trees:
        ox, oy = x-tx, y-ty
        b = d[:,0]*ox + d[:,1]*oy
        c = ox*ox + oy*oy - tr*tr
        disc = b*b - c
        hit = disc >= 0
        s = -b - np.sqrt(np.where(hit, disc, 0))
        ok = hit & (s > 0)
        rng_ = np.where(ok & (s < rng_), s, rng_)
    rng_[rng_ > 30] = np.inf
    lap_scans.append(rng_)
with open(f"{out}/manifest.toml", "w") as f:
    f.write('''format_version = 1
name = "circling"
source = "synthetic: a robot circling a park of 30 trees"
[vehicle]
motion = "odometry"
start_pose = [12.0, 0.0, 1.5707963267948966]
[sensor]
x_m = 0.0
y_m = 0.0
range_sigma_m = 0.05
bearing_sigma_rad = 0.01
[laser]
angle_min_rad = -1.5707963267948966
angle_increment_rad = 0.008726646259971648
range_min_m = 0.1
range_max_m = 30.0
[reference]
kind = "ground_truth"
point = "vehicle"
''')
n = int(T*10)
with open(f"{out}/scans.csv", "w") as f:
    f.write("t," + ",".join(f"r{i}" for i in range(len(beams))) + "\n")
    for k in range(1, n):
        r = lap_scans[k % n_lap] + rng.normal(0, 0.02, len(beams))
        f.write(f"{k/10:.1f}," + ",".join("inf" if not math.isfinite(v) else f"{v:.3f}" for v in r) + "\n")
with open(f"{out}/odometry.csv", "w") as f, open(f"{out}/reference.csv", "w") as g:
    f.write("t,v,omega\n"); g.write("t,x,y,theta\n")
    for k in range(int(T*20)):
        t = k/20
        f.write(f"{t:.2f},{v*(1+rng.normal(0,0.01)):.5f},{w+rng.normal(0,0.002):.6f}\n")
        x, y, th = pose(t); g.write(f"{t:.2f},{x:.4f},{y:.4f},{th:.5f}\n")
