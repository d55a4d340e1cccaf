#!/usr/bin/env python3
"""The pooled evidence thresholds, learned from drives through training worlds.

`[pipeline.evidence] min_hit_fraction` and `min_above_fraction` decide a place on the
mean, over its fully judged frames, of the fraction of laser patches that are object
patches and of the band's object patches. This reads the `segmentation.jsonl` of runs of
`combined` through appearance training worlds (parks that no benchmark split holds), takes
each true object's means over its fully judged frames (objects judged in at least
MIN_FRAMES frames, the pipeline's `min_frames`), and learns the pair of thresholds that
maximises Youden's J (trees admitted minus other objects admitted, each as a fraction of
its kind) on a 0.01 grid; of the pairs that tie, the one nearest their centroid. It prints
the learned pair and, for it and for the settings given, how many objects of each class
pass.

Usage (docs/results.md#learning-the-pooled-thresholds-from-training-drives-measured-not-adopted):
  cargo run --release -p scenarios --example training_drives -- 1001 8 D training_seed=1
  for k in 0 1 2 3 4 5 6 7; do objslam run D/training-world-$k.toml --out D/out-$k; done
  python3 scripts/pooled_thresholds.py D/out-*/segmentation.jsonl
Standard library only.
"""
import json
import sys
from collections import defaultdict

MIN_FRAMES = 4
SETTINGS = (0.7, 0.6)
CLASSES = ("tree", "post", "palm", "person", "wall")


def objects(path):
    """(class, mean hit fraction, mean band fraction) of each object judged often enough."""
    frames = defaultdict(list)
    classes = {}
    with open(path) as f:
        for line in f:
            r = json.loads(line)
            if r["band_visible"] and not r["at_image_edge"] and r["true_class"] != "nothing":
                frames[r["true_object"]].append((r["hit_fraction"], r["above_fraction"]))
                classes[r["true_object"]] = r["true_class"]
    out = []
    for k, v in frames.items():
        if len(v) >= MIN_FRAMES:
            out.append((classes[k], sum(h for h, _ in v) / len(v), sum(a for _, a in v) / len(v)))
    return out


def passing(objs, th, ta):
    return sum(h >= th and a >= ta for _, h, a in objs)


def learn(objs):
    trees = [o for o in objs if o[0] == "tree"]
    others = [o for o in objs if o[0] != "tree"]
    if not trees or not others:
        sys.exit("need trees and other objects judged in enough frames")
    grid = [i / 100 for i in range(101)]
    best, ties = None, []
    for th in grid:
        for ta in grid:
            j = passing(trees, th, ta) / len(trees) - passing(others, th, ta) / len(others)
            if best is None or j > best + 1e-12:
                best, ties = j, [(th, ta)]
            elif abs(j - best) <= 1e-12:
                ties.append((th, ta))
    cx = sum(t[0] for t in ties) / len(ties)
    cy = sum(t[1] for t in ties) / len(ties)
    return min(ties, key=lambda t: (t[0] - cx) ** 2 + (t[1] - cy) ** 2)


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    objs = [o for path in sys.argv[1:] for o in objects(path)]
    learned = learn(objs)
    for name, (th, ta) in (("learned", learned), ("settings", SETTINGS)):
        counts = ", ".join(
            f"{c} {passing([o for o in objs if o[0] == c], th, ta)} of {sum(o[0] == c for o in objs)}" for c in CLASSES
        )
        print(f"{name}: min_hit_fraction {th:.2f}, min_above_fraction {ta:.2f}: {counts}")


if __name__ == "__main__":
    main()
