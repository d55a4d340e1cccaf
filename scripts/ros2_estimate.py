#!/usr/bin/env python3
"""Turns a ROS 2 system's estimate, recorded with `ros2 bag record`, into the files that
`objslam score` reads (docs/guide/scoring.md#from-ros-2). Needs `pip install rosbags`.

    python3 scripts/ros2_estimate.py BAG --trajectory-topic /slam/odom \\
        [--landmarks-topic /slam/landmarks] [--associations-topic /slam/associations] --out DIR

- trajectory: nav_msgs/msg/Odometry, geometry_msgs/msg/PoseStamped or
  geometry_msgs/msg/PoseWithCovarianceStamped; every message, by its header stamp, to
  DIR/trajectory.tum, and the x, y and yaw covariance of the types that carry one (unless
  all zero) to DIR/trajectory_covariance.csv, for `--covariances`;
- landmarks: visualization_msgs/msg/MarkerArray, one marker per landmark (`id`,
  `pose.position`); the map that the messages leave, in order (ADD/MODIFY sets a marker,
  DELETE removes it, DELETEALL clears its namespace, or all of them with an empty one), to
  DIR/landmarks.csv;
- associations: std_msgs/msg/String, each `data` one JSON line of objslam's association
  forms; every message in order, to DIR/associations.jsonl.

Every message must be in one of the frames given by --frames (default `world,map`: the
log's world frame). Exit status 2 with a message naming the topic when a topic is
missing, has another type or another frame.
"""
import argparse
import json
import sys
from pathlib import Path

from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.typesys import Stores, get_typestore

POSE_TYPES = {
    "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
}
# visualization_msgs/msg/Marker actions: ADD and MODIFY are both 0.
ADD_OR_MODIFY, DELETE, DELETEALL = 0, 2, 3


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


def check_frame(topic, frame, frames):
    if frame not in frames:
        fail(f"{topic}: frame `{frame}`, expected one of {sorted(frames)} (the log's world frame)")


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
    p.add_argument("--frames", default="world,map", help="frames taken as the log's world frame")
    p.add_argument("--out", type=Path, required=True)
    a = p.parse_args()
    frames = set(a.frames.split(","))
    a.out.mkdir(parents=True, exist_ok=True)
    try:
        convert(a, frames)
    except (AnyReaderError, OSError) as e:
        # A bag cut short (a recorder killed before it wrote the MCAP's end) or missing
        # its metadata.yaml: one line naming the bag, not a traceback.
        hint = " (a recording cut short can be mended with `ros2 bag reindex`)" if "magic" in str(e) else ""
        fail(f"{a.bag}: cannot read the bag: {e}{hint}")


def convert(a, frames):
    """Writes the estimate's files from the bag `a.bag`."""
    with AnyReader([a.bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        poses, covariances = [], []
        for msgtype, m in messages(reader, a.trajectory_topic, POSE_TYPES):
            check_frame(a.trajectory_topic, m.header.frame_id, frames)
            pose = pose_of(msgtype, m)
            q, t = pose.orientation, pose.position
            poses.append((stamp(m.header), f"{t.x!r} {t.y!r} {t.z!r} {q.x!r} {q.y!r} {q.z!r} {q.w!r}"))
            if msgtype != "geometry_msgs/msg/PoseStamped":
                # Row-major 6x6 over (x, y, z, roll, pitch, yaw): x, y and yaw.
                c = [float(v) for v in m.pose.covariance]
                covariances.append((stamp(m.header), [c[0], c[1], c[5], c[7], c[11], c[35]]))
        poses.sort(key=lambda p: p[0])
        with open(a.out / "trajectory.tum", "w") as f:
            f.write("# timestamp tx ty tz qx qy qz qw\n")
            for t, rest in poses:
                f.write(f"{t!r} {rest}\n")
        covariance_file = a.out / "trajectory_covariance.csv"
        covariance_file.unlink(missing_ok=True)  # none from an earlier conversion
        if any(any(v != 0.0 for v in c) for _, c in covariances):
            covariances.sort(key=lambda c: c[0])
            with open(covariance_file, "w") as f:
                f.write("t,xx,xy,xtheta,yy,ytheta,thetatheta\n")
                for t, c in covariances:
                    f.write(",".join(repr(v) for v in [t, *c]) + "\n")
        if a.landmarks_topic:
            markers = {}  # (namespace, id) -> (x, y)
            seen = False
            for _, m in messages(reader, a.landmarks_topic, {"visualization_msgs/msg/MarkerArray"}):
                seen = True
                for marker in m.markers:
                    key = (marker.ns, marker.id)
                    if marker.action == DELETEALL:
                        # As rviz2 does: an empty namespace clears them all.
                        markers = {k: v for k, v in markers.items() if marker.ns and k[0] != marker.ns}
                    elif marker.action == DELETE:
                        markers.pop(key, None)
                    elif marker.action == ADD_OR_MODIFY:
                        check_frame(a.landmarks_topic, marker.header.frame_id, frames)
                        markers[key] = (marker.pose.position.x, marker.pose.position.y)
            if not seen:
                fail(f"{a.landmarks_topic}: no message")
            with open(a.out / "landmarks.csv", "w") as f:
                f.write("id,x,y\n")
                # One id in two namespaces is one id twice: objslam score names it.
                for (_, i), (x, y) in sorted(markers.items(), key=lambda kv: kv[0][1]):
                    f.write(f"{i},{x!r},{y!r}\n")
        if a.associations_topic:
            with open(a.out / "associations.jsonl", "w") as f:
                for k, (_, m) in enumerate(messages(reader, a.associations_topic, {"std_msgs/msg/String"})):
                    try:
                        value = json.loads(m.data)
                    except json.JSONDecodeError as e:
                        fail(f"{a.associations_topic}: message {k + 1} is not JSON: {e}")
                    f.write(json.dumps(value) + "\n")
    print(f"{len(poses)} poses -> {a.out}")


if __name__ == "__main__":
    main()
