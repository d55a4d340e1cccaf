#!/usr/bin/env python3
"""Turns a ROS 2 system's estimate, recorded with `ros2 bag record`, into the files that
`objslam score` reads (docs/guide/scoring.md#from-ros-2). Needs `pip install rosbags`.

    python3 scripts/ros2_estimate.py BAG --trajectory-topic /slam/odom \\
        [--landmarks-topic /slam/landmarks] [--associations-topic /slam/associations] --out DIR

- trajectory: nav_msgs/msg/Odometry, geometry_msgs/msg/PoseStamped or
  geometry_msgs/msg/PoseWithCovarianceStamped; every message, by its header stamp, to
  DIR/trajectory.tum;
- landmarks: visualization_msgs/msg/MarkerArray, one marker per landmark (`id`,
  `pose.position`); the last message, markers with action DELETE or DELETEALL left out, to
  DIR/landmarks.csv;
- associations: std_msgs/msg/String, each `data` one JSON line of objslam's association
  forms; every message in order, to DIR/associations.jsonl.

Exit status 2 with a message naming the topic when a topic is missing or has another type.
"""
import argparse
import json
import sys
from pathlib import Path

from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

POSE_TYPES = {
    "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
}
DELETE, DELETEALL = 2, 3


def fail(message):
    print(f"ros2_estimate: {message}", file=sys.stderr)
    sys.exit(2)


def messages(reader, topic, types):
    connections = [c for c in reader.connections if c.topic == topic]
    if not connections:
        fail(f"{topic}: no such topic in the bag (topics: {sorted({c.topic for c in reader.connections})})")
    for c in connections:
        if c.msgtype not in types:
            fail(f"{topic}: type {c.msgtype}, expected {' or '.join(sorted(types))}")
    for c, _, raw in reader.messages(connections=connections):
        yield c.msgtype, reader.deserialize(raw, c.msgtype)


def pose_of(msgtype, m):
    if msgtype == "geometry_msgs/msg/PoseStamped":
        return m.pose
    return m.pose.pose  # Odometry and PoseWithCovarianceStamped


def stamp(header):
    # Integer nanoseconds to seconds with one rounding, so 0.05 s reads back as 0.05.
    return (header.stamp.sec * 1_000_000_000 + header.stamp.nanosec) / 1e9


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("bag", type=Path)
    p.add_argument("--trajectory-topic", required=True)
    p.add_argument("--landmarks-topic")
    p.add_argument("--associations-topic")
    p.add_argument("--out", type=Path, required=True)
    a = p.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    with AnyReader([a.bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        poses = []
        for msgtype, m in messages(reader, a.trajectory_topic, POSE_TYPES):
            pose = pose_of(msgtype, m)
            q, t = pose.orientation, pose.position
            poses.append((stamp(m.header), f"{t.x!r} {t.y!r} {t.z!r} {q.x!r} {q.y!r} {q.z!r} {q.w!r}"))
        poses.sort(key=lambda p: p[0])
        with open(a.out / "trajectory.tum", "w") as f:
            f.write("# timestamp tx ty tz qx qy qz qw\n")
            for t, rest in poses:
                f.write(f"{t!r} {rest}\n")
        if a.landmarks_topic:
            last = None
            for _, m in messages(reader, a.landmarks_topic, {"visualization_msgs/msg/MarkerArray"}):
                last = m
            if last is None:
                fail(f"{a.landmarks_topic}: no message")
            with open(a.out / "landmarks.csv", "w") as f:
                f.write("id,x,y\n")
                for marker in last.markers:
                    if marker.action not in (DELETE, DELETEALL):
                        f.write(f"{marker.id},{marker.pose.position.x!r},{marker.pose.position.y!r}\n")
        if a.associations_topic:
            with open(a.out / "associations.jsonl", "w") as f:
                for k, (_, m) in enumerate(messages(reader, a.associations_topic, {"std_msgs/msg/String"})):
                    try:
                        json.loads(m.data)
                    except json.JSONDecodeError as e:
                        fail(f"{a.associations_topic}: message {k + 1} is not one JSON line: {e}")
                    f.write(m.data.strip() + "\n")
    print(f"{len(poses)} poses -> {a.out}")


if __name__ == "__main__":
    main()
