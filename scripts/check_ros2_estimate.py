#!/usr/bin/env python3
"""Checks scripts/ros2_estimate.py end to end, the way a ROS 2 user's estimate reaches
`objslam score`: publishes an `objslam run` directory's estimate as ROS 2 messages into a
bag written by rosbags (a third-party writer), turns the bag back into files with
ros2_estimate.py, scores them and compares with the run's metrics.json. Run by hand (it
needs `pip install rosbags`):

    objslam run paper_park --out runs/pp
    python3 scripts/check_ros2_estimate.py runs/pp target/release/objslam

Exit status 1 when a scored key differs from the run's by more than 1e-9 (relative).
"""
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

run, objslam = Path(sys.argv[1]), sys.argv[2]
ts = get_typestore(Stores.ROS2_HUMBLE)
T = ts.types
Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
Point, Quaternion, Pose = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Pose"]
Vector3 = T["geometry_msgs/msg/Vector3"]
import numpy as np


def header(t_ns):
    return Header(stamp=Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000), frame_id="map")


def pose(x, y, z, qx, qy, qz, qw):
    return Pose(position=Point(x=x, y=y, z=z), orientation=Quaternion(x=qx, y=qy, z=qz, w=qw))


work = Path(tempfile.mkdtemp(prefix="objslam-ros2-estimate-"))
bag = work / "estimate"
poses = [list(map(float, l.split())) for l in open(run / "trajectory_est.tum") if not l.startswith("#")]
# The run's pose covariances (x, y, heading) into the 6x6 of each Odometry message.
covariance_rows = [list(map(float, l.split(","))) for l in list(open(run / "trajectory_est_covariance.csv"))[1:]]
assert len(covariance_rows) == len(poses)
with Writer(bag, version=8) as w:
    odom_c = w.add_connection("/slam/odom", "nav_msgs/msg/Odometry", typestore=ts)
    lm_c = w.add_connection("/slam/landmarks", "visualization_msgs/msg/MarkerArray", typestore=ts)
    as_c = w.add_connection("/slam/associations", "std_msgs/msg/String", typestore=ts)
    zero6 = np.zeros(36)
    for (t, x, y, z, qx, qy, qz, qw), (_, xx, xy, xt, yy, yt, tt) in zip(poses, covariance_rows):
        t_ns = round(t * 1e9)
        c = np.zeros(36)
        for (i, j), v in {(0, 0): xx, (0, 1): xy, (0, 5): xt, (1, 1): yy, (1, 5): yt, (5, 5): tt}.items():
            c[6 * i + j] = c[6 * j + i] = v
        m = T["nav_msgs/msg/Odometry"](
            header=header(t_ns),
            child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose(x, y, z, qx, qy, qz, qw), covariance=c),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=Vector3(x=0.0, y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=0.0)),
                covariance=zero6,
            ),
        )
        w.write(odom_c, t_ns, ts.serialize_cdr(m, "nav_msgs/msg/Odometry"))
    for line in open(run / "decisions.jsonl"):
        t_ns = round(json.loads(line)["t"] * 1e9)
        w.write(as_c, t_ns, ts.serialize_cdr(T["std_msgs/msg/String"](data=line.strip()), "std_msgs/msg/String"))
    markers = []
    end_ns = round(poses[-1][0] * 1e9)
    for l in json.load(open(run / "landmarks.json")):
        markers.append(
            T["visualization_msgs/msg/Marker"](
                header=header(end_ns), ns="landmarks", id=l["id"], type=3, action=0,
                pose=pose(l["position"][0], l["position"][1], 0.0, 0.0, 0.0, 0.0, 1.0),
                scale=Vector3(x=0.3, y=0.3, z=1.0), color=T["std_msgs/msg/ColorRGBA"](r=0.0, g=0.8, b=0.0, a=1.0),
                lifetime=T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0), frame_locked=False,
                points=[], colors=[], texture_resource="", texture=T["sensor_msgs/msg/CompressedImage"](
                    header=header(end_ns), format="", data=np.zeros(0, dtype=np.uint8)),
                uv_coordinates=[], text="", mesh_resource="",
                mesh_file=T["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, dtype=np.uint8)),
                mesh_use_embedded_materials=False,
            )
        )
    w.write(lm_c, end_ns, ts.serialize_cdr(T["visualization_msgs/msg/MarkerArray"](markers=markers), "visualization_msgs/msg/MarkerArray"))

here = Path(__file__).parent
subprocess.run([sys.executable, here / "ros2_estimate.py", bag, "--trajectory-topic", "/slam/odom",
                "--landmarks-topic", "/slam/landmarks", "--associations-topic", "/slam/associations",
                "--out", work / "files"], check=True)
f = work / "files"
subprocess.run([objslam, "score", "--log", run, "--trajectory", f / "trajectory.tum",
                "--covariances", f / "trajectory_covariance.csv", "--landmarks", f / "landmarks.csv",
                "--associations", f / "associations.jsonl", "--method", json.load(open(run / "metrics.json"))["method"],
                "--out", work / "score"], stdout=subprocess.DEVNULL)
scored = json.load(open(work / "score" / "metrics.json"))
expected = json.load(open(run / "metrics.json"))


def close(a, b):
    if isinstance(a, dict) and isinstance(b, dict):
        return all(close(a.get(k), b.get(k)) for k in a if k != "trees_judged")
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)
    return a == b


bad = 0
for key, value in scored.items():
    if key in expected and key not in ("unchecked",):
        same = close(value, expected[key])
        bad += not same
        print(f"{'same' if same else 'DIFFERS'}: {key} {value if not same else ''}")
print(f"{bad} keys differ; files in {work}")
sys.exit(1 if bad else 0)
