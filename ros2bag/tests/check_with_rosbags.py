#!/usr/bin/env python3
"""Reads the ros2bag crate's sample bag with third-party ROS 2 bag readers.

Not part of `cargo test` (it needs Python packages); run it by hand after changing the
encoder, the message definitions or metadata.yaml:

    python3 -m venv /tmp/ros2bag-venv
    /tmp/ros2bag-venv/bin/pip install rosbags mcap mcap-ros2-support
    cd ros2bag
    /tmp/ros2bag-venv/bin/python tests/check_with_rosbags.py          # runs cargo, then checks
    /tmp/ros2bag-venv/bin/python tests/check_with_rosbags.py BAG_DIR  # checks a bag already made

Without BAG_DIR it runs `cargo test --test write_bag` with ROS2BAG_SAMPLE_DIR set to a fresh
temporary directory (the test writes the sample bag there too); the environment, such as
CARGO_TARGET_DIR, is passed through. BAG_DIR must hold the sample bag of tests/write_bag.rs,
since the expected values below mirror it.

What it checks:
1. rosbags.highlevel.AnyReader: opens the directory through metadata.yaml, builds its types
   from the definitions stored in the bag, checks the stored RIHS01 type hashes against them
   (and here against Jazzy's), and deserialises every message; values checked.
2. rosbags' stock ROS 2 Humble and Jazzy type stores: the bag's stored definitions equal
   theirs, each raw message deserialises with them, and re-serialising gives the same bytes.
3. mcap_ros2.reader.read_ros2_messages over the .mcap file alone (profile, encodings, values).
Exit status 0 and a final "N passed, 0 failed" line when everything holds.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from mcap.reader import make_reader
from mcap_ros2.reader import read_ros2_messages
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosDurability
from rosbags.rosbag2 import Reader as Rosbag2Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

T0_SEC = 1_700_000_000
T0 = T0_SEC * 1_000_000_000
MS = 1_000_000

EXPECTED_TOPICS = {
    '/scan': ('sensor_msgs/msg/LaserScan', 3),
    '/odom': ('nav_msgs/msg/Odometry', 2),
    '/camera/image_raw': ('sensor_msgs/msg/Image', 1),
    '/camera/camera_info': ('sensor_msgs/msg/CameraInfo', 1),
    '/tf': ('tf2_msgs/msg/TFMessage', 2),
    '/tf_static': ('tf2_msgs/msg/TFMessage', 1),
    '/ground_truth/pose': ('geometry_msgs/msg/PoseStamped', 2),
    '/ground_truth/path': ('nav_msgs/msg/Path', 1),
}
TOTAL = sum(n for _, n in EXPECTED_TOPICS.values())

passed = 0
failed = 0


def check(cond: bool, what: str) -> None:
    global passed, failed
    if cond:
        passed += 1
    else:
        failed += 1
        print(f'FAIL: {what}')


def close(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12)


def check_stamp(header, ns: int, frame: str, what: str) -> None:
    check(header.stamp.sec == ns // 1_000_000_000, f'{what}: stamp.sec {header.stamp.sec}')
    check(
        header.stamp.nanosec == ns % 1_000_000_000,
        f'{what}: stamp.nanosec {header.stamp.nanosec}',
    )
    check(header.frame_id == frame, f'{what}: frame_id {header.frame_id!r}')


def check_yaw(q, yaw: float, what: str) -> None:
    want = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    got = (q.x, q.y, q.z, q.w)
    check(all(close(a, b) for a, b in zip(got, want)), f'{what}: quaternion {got} != {want}')


def check_pose(pose, i: int, what: str) -> None:
    p = pose.position
    check((p.x, p.y, p.z) == (1.0 + i, 2.0, 0.0), f'{what}: position {(p.x, p.y, p.z)}')
    check_yaw(pose.orientation, 0.5 * i, what)


def check_message(topic: str, index: int, log_time: int, msg, what: str) -> None:
    """Checks one decoded message against the sample written by tests/write_bag.rs."""
    i = index
    if topic == '/scan':
        ns = T0 + i * 100 * MS
        check(log_time == ns, f'{what}: log time {log_time}')
        check_stamp(msg.header, ns, 'laser', what)
        fields = (
            msg.angle_min, msg.angle_max, msg.angle_increment, msg.time_increment,
            msg.scan_time, msg.range_min, msg.range_max,
        )
        check(fields == (-1.5, 1.5, 0.75, 0.0, 0.125, 0.125, 30.0), f'{what}: scan fields {fields}')
        r = [float(x) for x in msg.ranges]
        check(len(r) == 5, f'{what}: {len(r)} ranges')
        check(r[0] == 1.0 + i and r[2] == 2.5, f'{what}: ranges {r}')
        check(r[1] == math.inf, f'{what}: REP-117 +inf range read back as {r[1]}')
        check(r[3] == -math.inf, f'{what}: REP-117 -inf range read back as {r[3]}')
        check(math.isnan(r[4]), f'{what}: NaN range read back as {r[4]}')
        check([float(x) for x in msg.intensities] == [100, 0, 50, 0, 0], f'{what}: intensities')
    elif topic == '/odom':
        ns = T0 + i * 500 * MS
        check(log_time == ns, f'{what}: log time {log_time}')
        check_stamp(msg.header, ns, 'odom', what)
        check(msg.child_frame_id == 'base_link', f'{what}: child_frame_id')
        check_pose(msg.pose.pose, i, what)
        check([float(x) for x in msg.pose.covariance] == [float(k) for k in range(36)],
              f'{what}: pose covariance')
        t = msg.twist.twist
        check((t.linear.x, t.linear.y, t.linear.z) == (0.5, 0.0, 0.0), f'{what}: linear')
        check((t.angular.x, t.angular.y, t.angular.z) == (0.0, 0.0, 0.25 * i), f'{what}: angular')
        check([float(x) for x in msg.twist.covariance] == [-float(k) for k in range(36)],
              f'{what}: twist covariance')
    elif topic == '/camera/image_raw':
        check_stamp(msg.header, T0 + 50 * MS, 'camera', what)
        check((msg.height, msg.width, msg.encoding, msg.is_bigendian, msg.step)
              == (3, 4, 'rgb8', 0, 12), f'{what}: image fields')
        check(bytes(msg.data) == bytes(range(36)), f'{what}: image data')
    elif topic == '/camera/camera_info':
        check_stamp(msg.header, T0 + 50 * MS, 'camera', what)
        check((msg.height, msg.width, msg.distortion_model) == (3, 4, 'plumb_bob'),
              f'{what}: size/model')
        check([float(x) for x in msg.d] == [0.1, -0.2, 0.001, 0.002, 0.0], f'{what}: d')
        check([float(x) for x in msg.k] == [100, 0, 2, 0, 100, 1.5, 0, 0, 1], f'{what}: k')
        check([float(x) for x in msg.r] == [1, 0, 0, 0, 1, 0, 0, 0, 1], f'{what}: r')
        check([float(x) for x in msg.p] == [100, 0, 2, 0, 0, 100, 1.5, 0, 0, 0, 1, 0],
              f'{what}: p')
        check((msg.binning_x, msg.binning_y) == (1, 1), f'{what}: binning')
        roi = msg.roi
        check((roi.x_offset, roi.y_offset, roi.height, roi.width, bool(roi.do_rectify))
              == (1, 2, 3, 4, True), f'{what}: roi')
    elif topic == '/tf':
        ns = T0 + i * 500 * MS
        check(log_time == ns, f'{what}: log time {log_time}')
        check(len(msg.transforms) == 2, f'{what}: {len(msg.transforms)} transforms')
        a, b = msg.transforms
        check_stamp(a.header, ns, 'odom', what)
        check(a.child_frame_id == 'base_link', f'{what}: child')
        check(a.transform.translation.x == 1.0 + i, f'{what}: translation')
        check_yaw(a.transform.rotation, 0.5 * i, what)
        check_stamp(b.header, ns, 'base_link', what)
        check((b.child_frame_id, b.transform.translation.x) == ('laser', 0.2), f'{what}: laser tf')
    elif topic == '/tf_static':
        (t,) = msg.transforms
        check_stamp(t.header, T0, 'base_link', what)
        check((t.child_frame_id, t.transform.translation.x) == ('camera', 0.1), f'{what}: static')
        check_yaw(t.transform.rotation, 0.0, what)
    elif topic == '/ground_truth/pose':
        ns = T0 + i * 500 * MS
        check_stamp(msg.header, ns, 'map', what)
        check_pose(msg.pose, i, what)
    elif topic == '/ground_truth/path':
        check_stamp(msg.header, T0 + 1000 * MS, 'map', what)
        check(len(msg.poses) == 3, f'{what}: {len(msg.poses)} poses')
        for k, p in enumerate(msg.poses):
            check_stamp(p.header, T0 + k * 500 * MS, 'map', f'{what} pose {k}')
            check_pose(p.pose, k, f'{what} pose {k}')
    else:
        check(False, f'{what}: unexpected topic {topic}')


def check_with_anyreader(bag: Path) -> None:
    print(f'rosbags.highlevel.AnyReader on {bag}')
    humble = get_typestore(Stores.ROS2_HUMBLE)
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    with AnyReader([bag], default_typestore=humble) as reader:
        topics = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
        check(topics == EXPECTED_TOPICS, f'connections {topics}')
        for c in reader.connections:
            check(c.msgdef.data != '', f'{c.topic}: definition stored in the bag')
            # AnyReader has already verified the hash against the stored definition; this ties
            # it to the stock Jazzy type.
            check(c.digest == jazzy.hash_rihs01(c.msgtype), f'{c.topic}: type hash {c.digest}')
            qos = c.ext.offered_qos_profiles
            if c.topic == '/tf_static':
                check(len(qos) == 1 and qos[0].durability == QosDurability.TRANSIENT_LOCAL,
                      f'/tf_static offered QoS {qos}')
            else:
                check(qos == [], f'{c.topic}: offered QoS {qos}')

            # The stored definition names exactly the stock Humble/Jazzy fields.
            stored = get_types_from_msg(c.msgdef.data, c.msgtype)
            for name, fields in stored.items():
                for store, label in ((humble, 'humble'), (jazzy, 'jazzy')):
                    check(store.fielddefs.get(name) == fields,
                          f'{c.topic}: stored definition of {name} differs from {label}')

        seen: dict[str, int] = {}
        count = 0
        for conn, timestamp, raw in reader.messages():
            i = seen.get(conn.topic, 0)
            seen[conn.topic] = i + 1
            count += 1
            what = f'AnyReader {conn.topic}[{i}]'
            check_message(conn.topic, i, timestamp, reader.deserialize(raw, conn.msgtype), what)
            for store, label in ((humble, 'humble'), (jazzy, 'jazzy')):
                msg = store.deserialize_cdr(raw, conn.msgtype)
                check_message(conn.topic, i, timestamp, msg, f'{what} ({label} store)')
                again = bytes(store.serialize_cdr(msg, conn.msgtype))
                check(again == bytes(raw),
                      f'{what}: {label} re-serialisation differs ({len(again)} vs {len(raw)} B)')
        check(count == TOTAL, f'AnyReader read {count} messages')
        print(f'  {count} messages on {len(seen)} topics: ' +
              ', '.join(f'{t} x{n}' for t, n in sorted(seen.items())))

    with Rosbag2Reader(bag) as reader:
        check(reader.message_count == TOTAL, f'metadata message_count {reader.message_count}')
        check(reader.start_time == T0, f'metadata start {reader.start_time}')
        # rosbags reports the end as exclusive: last log time + 1
        check(reader.end_time == T0 + 1000 * MS + 1, f'metadata end {reader.end_time}')
        print(f'  rosbags.rosbag2.Reader: {reader.message_count} messages, '
              f'start {reader.start_time} ns, duration {reader.duration} ns (end exclusive)')


def check_with_mcap_ros2(bag: Path) -> None:
    (mcap_file,) = sorted(bag.glob('*.mcap'))
    print(f'mcap_ros2.reader.read_ros2_messages on {mcap_file.name}')
    with mcap_file.open('rb') as f:
        reader = make_reader(f, validate_crcs=True)
        header = reader.get_header()
        check(header.profile == 'ros2', f'MCAP profile {header.profile!r}')
        summary = reader.get_summary()
        for ch in summary.channels.values():
            schema = summary.schemas[ch.schema_id]
            check(ch.message_encoding == 'cdr', f'{ch.topic}: encoding {ch.message_encoding}')
            check(schema.encoding == 'ros2msg', f'{schema.name}: schema encoding')
            check(EXPECTED_TOPICS[ch.topic][0] == schema.name, f'{ch.topic}: schema {schema.name}')
        crc_checked = sum(1 for _ in reader.iter_messages())
        check(crc_checked == TOTAL, f'{crc_checked} messages read with CRC validation')
        print(f'  profile {header.profile!r}, library {header.library!r}, '
              f'{len(summary.channels)} channels, {len(summary.schemas)} schemas')
    seen: dict[str, int] = {}
    count = 0
    for m in read_ros2_messages(mcap_file):
        topic = m.channel.topic
        i = seen.get(topic, 0)
        seen[topic] = i + 1
        count += 1
        check_message(topic, i, m.log_time_ns, m.ros_msg, f'mcap_ros2 {topic}[{i}]')
    check(count == TOTAL, f'mcap_ros2 read {count} messages')
    print(f'  {count} messages decoded: ' +
          ', '.join(f'{t} x{n}' for t, n in sorted(seen.items())))


def make_sample() -> Path:
    out = Path(tempfile.mkdtemp(prefix='ros2bag-sample-')) / 'sample'
    crate = Path(__file__).resolve().parent.parent
    print(f'writing the sample bag to {out} (cargo test --test write_bag)')
    subprocess.run(
        ['cargo', 'test', '--quiet', '--test', 'write_bag', 'sample_bag_reads_back'],
        cwd=crate,
        env={**os.environ, 'ROS2BAG_SAMPLE_DIR': str(out)},
        check=True,
    )
    return out


def main() -> int:
    bag = Path(sys.argv[1]) if len(sys.argv) > 1 else make_sample()
    print('metadata.yaml:')
    print((bag / 'metadata.yaml').read_text().rstrip())
    check_with_anyreader(bag)
    check_with_mcap_ros2(bag)
    print(f'{passed} passed, {failed} failed')
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
