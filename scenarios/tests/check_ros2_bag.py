#!/usr/bin/env python3
"""Checks an `objslam record --format ros2` bag with rosbags, a third-party reader, against the
JSON lines of the same recording. Run by hand (it needs `pip install rosbags numpy`):

    objslam record park --seed 2 --format ros2 --out runs/bag
    objslam record park --seed 2 --out runs/rec
    python3 scenarios/tests/check_ros2_bag.py runs/bag runs/rec

It prints every topic with its type and count, and how many scan ranges differ from
laser.jsonl (as float32). laser.jsonl writes null for no return and "-inf" for a return
closer than range_min, which the bag keeps as +inf and -inf (REP-117); a null from an older
recording, which wrote null for both, may be an infinity of either sign. Exit status 1 on
any difference.
"""
import json
import math
import sys
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader

bag, log = Path(sys.argv[1]), Path(sys.argv[2])
scans = [json.loads(line) for line in open(log / "laser.jsonl")]
mismatched = 0
with AnyReader([bag]) as reader:
    for c in reader.connections:
        print(f"{c.topic}: {c.msgtype} x{c.msgcount}")
    n = 0
    for c, _, raw in reader.messages(connections=[c for c in reader.connections if c.topic == "/scan"]):
        m = reader.deserialize(raw, c.msgtype)
        s = scans[n]
        n += 1
        mismatched += abs(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 - s["t"]) > 1e-9
        for a, b in zip(s["ranges"], m.ranges):
            mismatched += not math.isinf(b) if a is None else np.float32(float(a)) != b
print(f"scans compared: {n} of {len(scans)}; mismatched values: {mismatched}")
sys.exit(1 if mismatched or n != len(scans) else 0)
