//! Writes a bag with every message type, then reads it back with the `mcap` crate and a small
//! CDR decoder written here, independently of the crate's encoder.
//!
//! Set `ROS2BAG_SAMPLE_DIR=/some/new/dir` to also leave the sample bag there for the
//! third-party readers in `tests/check_with_rosbags.py`.

use std::collections::BTreeMap;
use std::path::{Path as FsPath, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use ros2bag::{
    BagWriter, CameraInfo, Error, Header, Image, LaserScan, Odometry, Path, Point, Pose, PoseStamped,
    PoseWithCovariance, Quaternion, RegionOfInterest, RosMessage, TfMessage, Time, Transform, TransformStamped, Twist,
    TwistWithCovariance, Vector3,
};

/// First log time of the sample, ns since the epoch (2023-11-14).
const T0: u64 = 1_700_000_000_000_000_000;
const MS: u64 = 1_000_000;

/// A fresh, not yet existing directory under the system temp dir.
fn temp_bag_dir(tag: &str) -> PathBuf {
    static N: AtomicUsize = AtomicUsize::new(0);
    let n = N.fetch_add(1, Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!("ros2bag-test-{}-{tag}-{n}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn stamp(ns: u64) -> Time {
    Time::from_nanos(ns).unwrap()
}

fn sample_scan(i: u64) -> LaserScan {
    LaserScan {
        header: Header::new(stamp(T0 + i * 100 * MS), "laser"),
        angle_min: -1.5,
        angle_max: 1.5,
        angle_increment: 0.75,
        time_increment: 0.0,
        scan_time: 0.125,
        range_min: 0.125,
        range_max: 30.0,
        // REP 117: +inf = no return within range, -inf = too close, NaN = invalid
        ranges: vec![1.0 + i as f32, f32::INFINITY, 2.5, f32::NEG_INFINITY, f32::NAN],
        intensities: vec![100.0, 0.0, 50.0, 0.0, 0.0],
    }
}

fn sample_odom(i: u64) -> Odometry {
    let mut pose_cov = [0.0; 36];
    let mut twist_cov = [0.0; 36];
    for k in 0..36 {
        pose_cov[k] = k as f64;
        twist_cov[k] = -(k as f64);
    }
    Odometry {
        header: Header::new(stamp(T0 + i * 500 * MS), "odom"),
        child_frame_id: "base_link".into(),
        pose: PoseWithCovariance {
            pose: Pose {
                position: Point { x: 1.0 + i as f64, y: 2.0, z: 0.0 },
                orientation: Quaternion::from_yaw(0.5 * i as f64),
            },
            covariance: pose_cov,
        },
        twist: TwistWithCovariance {
            twist: Twist {
                linear: Vector3 { x: 0.5, y: 0.0, z: 0.0 },
                angular: Vector3 { x: 0.0, y: 0.0, z: 0.25 * i as f64 },
            },
            covariance: twist_cov,
        },
    }
}

fn tf(ns: u64, parent: &str, child: &str, x: f64, yaw: f64) -> TransformStamped {
    TransformStamped {
        header: Header::new(stamp(ns), parent),
        child_frame_id: child.into(),
        transform: Transform { translation: Vector3 { x, y: 0.0, z: 0.0 }, rotation: Quaternion::from_yaw(yaw) },
    }
}

fn ground_truth(i: u64) -> PoseStamped {
    PoseStamped {
        header: Header::new(stamp(T0 + i * 500 * MS), "map"),
        pose: Pose {
            position: Point { x: 1.0 + i as f64, y: 2.0, z: 0.0 },
            orientation: Quaternion::from_yaw(0.5 * i as f64),
        },
    }
}

/// The sample bag `check_with_rosbags.py` expects: 13 messages on 8 topics.
fn write_sample(dir: &FsPath) -> Result<(), Error> {
    let mut bag = BagWriter::create(dir)?;
    for i in 0..3 {
        bag.write("/scan", T0 + i * 100 * MS, &sample_scan(i))?;
    }
    for i in 0..2 {
        bag.write("/odom", T0 + i * 500 * MS, &sample_odom(i))?;
    }
    let header = Header::new(stamp(T0 + 50 * MS), "camera");
    let image = Image {
        header: header.clone(),
        height: 3,
        width: 4,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: 12,
        data: (0u8..36).collect(),
    };
    bag.write("/camera/image_raw", T0 + 50 * MS, &image)?;
    let mut info = CameraInfo::pinhole(header, 4, 3, 100.0, 100.0, 2.0, 1.5);
    info.d = vec![0.1, -0.2, 0.001, 0.002, 0.0];
    info.binning_x = 1;
    info.binning_y = 1;
    info.roi = RegionOfInterest { x_offset: 1, y_offset: 2, height: 3, width: 4, do_rectify: true };
    bag.write("/camera/camera_info", T0 + 50 * MS, &info)?;
    for i in 0..2 {
        let ns = T0 + i * 500 * MS;
        let msg = TfMessage {
            transforms: vec![
                tf(ns, "odom", "base_link", 1.0 + i as f64, 0.5 * i as f64),
                tf(ns, "base_link", "laser", 0.2, 0.0),
            ],
        };
        bag.write("/tf", ns, &msg)?;
    }
    let statics = TfMessage { transforms: vec![tf(T0, "base_link", "camera", 0.1, 0.0)] };
    bag.write("/tf_static", T0, &statics)?;
    for i in 0..2 {
        bag.write("/ground_truth/pose", T0 + i * 500 * MS, &ground_truth(i))?;
    }
    let path = Path { header: Header::new(stamp(T0 + 1000 * MS), "map"), poses: (0..3).map(ground_truth).collect() };
    bag.write("/ground_truth/path", T0 + 1000 * MS, &path)?;
    bag.finish()
}

/// Reads CDR back, as a reader that knows only the wire rules would.
struct CdrReader<'a> {
    payload: &'a [u8],
    pos: usize,
}

impl<'a> CdrReader<'a> {
    fn new(data: &'a [u8]) -> Self {
        assert_eq!(&data[..4], &[0, 1, 0, 0], "CDR_LE encapsulation header");
        Self { payload: &data[4..], pos: 0 }
    }
    fn take(&mut self, n: usize, align: usize) -> &'a [u8] {
        self.pos = self.pos.div_ceil(align) * align;
        let s = &self.payload[self.pos..self.pos + n];
        self.pos += n;
        s
    }
    fn u8(&mut self) -> u8 {
        self.take(1, 1)[0]
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take(4, 4).try_into().unwrap())
    }
    fn i32(&mut self) -> i32 {
        i32::from_le_bytes(self.take(4, 4).try_into().unwrap())
    }
    fn f32(&mut self) -> f32 {
        f32::from_le_bytes(self.take(4, 4).try_into().unwrap())
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take(8, 8).try_into().unwrap())
    }
    fn string(&mut self) -> String {
        let n = self.u32() as usize;
        let bytes = self.take(n, 1);
        assert_eq!(bytes.last(), Some(&0), "NUL terminator");
        String::from_utf8(bytes[..n - 1].to_vec()).unwrap()
    }
    fn f32_seq(&mut self) -> Vec<f32> {
        let n = self.u32();
        (0..n).map(|_| self.f32()).collect()
    }
    fn f64s<const N: usize>(&mut self) -> [f64; N] {
        std::array::from_fn(|_| self.f64())
    }
    fn done(&self) {
        assert_eq!(self.pos, self.payload.len(), "trailing bytes");
    }

    fn header(&mut self) -> Header {
        let sec = self.i32();
        let nanosec = self.u32();
        Header { stamp: Time { sec, nanosec }, frame_id: self.string() }
    }
    fn pose(&mut self) -> Pose {
        let [x, y, z] = self.f64s::<3>();
        let [qx, qy, qz, qw] = self.f64s::<4>();
        Pose { position: Point { x, y, z }, orientation: Quaternion { x: qx, y: qy, z: qz, w: qw } }
    }
    fn vector3(&mut self) -> Vector3 {
        let [x, y, z] = self.f64s::<3>();
        Vector3 { x, y, z }
    }
}

fn decode_scan(data: &[u8]) -> LaserScan {
    let mut r = CdrReader::new(data);
    let scan = LaserScan {
        header: r.header(),
        angle_min: r.f32(),
        angle_max: r.f32(),
        angle_increment: r.f32(),
        time_increment: r.f32(),
        scan_time: r.f32(),
        range_min: r.f32(),
        range_max: r.f32(),
        ranges: r.f32_seq(),
        intensities: r.f32_seq(),
    };
    r.done();
    scan
}

fn decode_odom(data: &[u8]) -> Odometry {
    let mut r = CdrReader::new(data);
    let odom = Odometry {
        header: r.header(),
        child_frame_id: r.string(),
        pose: PoseWithCovariance { pose: r.pose(), covariance: r.f64s::<36>() },
        twist: TwistWithCovariance {
            twist: Twist { linear: r.vector3(), angular: r.vector3() },
            covariance: r.f64s::<36>(),
        },
    };
    r.done();
    odom
}

fn decode_path(data: &[u8]) -> Path {
    let mut r = CdrReader::new(data);
    let header = r.header();
    let n = r.u32();
    let poses = (0..n).map(|_| PoseStamped { header: r.header(), pose: r.pose() }).collect();
    r.done();
    Path { header, poses }
}

fn decode_camera_info(data: &[u8]) -> CameraInfo {
    let mut r = CdrReader::new(data);
    let header = r.header();
    let (height, width) = (r.u32(), r.u32());
    let distortion_model = r.string();
    let nd = r.u32();
    let d = (0..nd).map(|_| r.f64()).collect();
    let info = CameraInfo {
        header,
        height,
        width,
        distortion_model,
        d,
        k: r.f64s::<9>(),
        r: r.f64s::<9>(),
        p: r.f64s::<12>(),
        binning_x: r.u32(),
        binning_y: r.u32(),
        roi: RegionOfInterest {
            x_offset: r.u32(),
            y_offset: r.u32(),
            height: r.u32(),
            width: r.u32(),
            do_rectify: r.u8() != 0,
        },
    };
    r.done();
    info
}

/// Bitwise float comparison, so that NaN equals NaN and -inf is told from +inf.
fn same_bits(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

#[test]
fn sample_bag_reads_back() {
    let dir = temp_bag_dir("sample");
    write_sample(&dir).unwrap();
    if let Some(keep) = std::env::var_os("ROS2BAG_SAMPLE_DIR") {
        write_sample(FsPath::new(&keep)).unwrap();
    }

    let name = dir.file_name().unwrap().to_str().unwrap().to_owned();
    let mcap_name = format!("{name}_0.mcap");
    let mut files: Vec<String> =
        std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    files.sort();
    let mut want = [mcap_name.clone(), "metadata.yaml".to_owned()];
    want.sort();
    assert_eq!(files, want);

    let bytes = std::fs::read(dir.join(&mcap_name)).unwrap();

    // Header profile, and the rosbag2 metadata record.
    let mut profile = None;
    let mut rosbag2_record = None;
    for rec in mcap::read::LinearReader::new(&bytes).unwrap() {
        match rec.unwrap() {
            mcap::records::Record::Header(h) => profile = Some(h.profile),
            mcap::records::Record::Metadata(m) if m.name == "rosbag2" => {
                rosbag2_record = m.metadata.get("serialized_metadata").cloned()
            }
            _ => {}
        }
    }
    assert_eq!(profile.as_deref(), Some("ros2"));
    let serialized = rosbag2_record.expect("rosbag2 metadata record");
    assert!(serialized.starts_with("version: 8\nstorage_identifier: mcap\n"), "{serialized}");

    // Channels and schemas.
    let summary = mcap::read::Summary::read(&bytes).unwrap().expect("summary section");
    let mut topics: BTreeMap<String, String> = BTreeMap::new();
    for ch in summary.channels.values() {
        assert_eq!(ch.message_encoding, "cdr");
        let schema = ch.schema.as_ref().expect("schema");
        assert_eq!(schema.encoding, "ros2msg");
        topics.insert(ch.topic.clone(), schema.name.clone());
        let qos = &ch.metadata["offered_qos_profiles"];
        if ch.topic == "/tf_static" {
            assert!(qos.contains("durability: 1"), "{qos}");
        } else {
            assert_eq!(qos, "");
        }
    }
    let expected_topics = BTreeMap::from(
        [
            ("/camera/camera_info", CameraInfo::TYPE_NAME),
            ("/camera/image_raw", Image::TYPE_NAME),
            ("/ground_truth/path", Path::TYPE_NAME),
            ("/ground_truth/pose", PoseStamped::TYPE_NAME),
            ("/odom", Odometry::TYPE_NAME),
            ("/scan", LaserScan::TYPE_NAME),
            ("/tf", TfMessage::TYPE_NAME),
            ("/tf_static", TfMessage::TYPE_NAME),
        ]
        .map(|(a, b)| (a.to_owned(), b.to_owned())),
    );
    assert_eq!(topics, expected_topics);
    // /tf and /tf_static share one schema record.
    assert_eq!(summary.schemas.len(), 7);
    let scan_schema = summary.schemas.values().find(|s| s.name == LaserScan::TYPE_NAME).unwrap();
    let text = std::str::from_utf8(&scan_schema.data).unwrap();
    assert!(text.starts_with("std_msgs/Header header\nfloat32 angle_min\n"));
    assert!(text.contains(&format!("{}\nMSG: builtin_interfaces/Time\n", "=".repeat(80))));

    // Messages: counts, and decoded values.
    let stats = summary.stats.as_ref().unwrap();
    assert_eq!(stats.message_count, 13);
    assert_eq!(stats.message_start_time, T0);
    assert_eq!(stats.message_end_time, T0 + 1000 * MS);
    let (mut scans, mut odoms) = (0, 0);
    for msg in mcap::MessageStream::new(&bytes).unwrap() {
        let msg = msg.unwrap();
        match msg.channel.topic.as_str() {
            "/scan" => {
                let got = decode_scan(&msg.data);
                let want = sample_scan(scans);
                assert_eq!(msg.log_time, T0 + scans * 100 * MS);
                assert_eq!(got.header, want.header);
                assert!(same_bits(&got.ranges, &want.ranges), "{:?}", got.ranges);
                assert_eq!(got.ranges[1], f32::INFINITY);
                assert_eq!(got.intensities, want.intensities);
                assert_eq!(
                    (got.angle_min, got.angle_max, got.angle_increment, got.range_max),
                    (want.angle_min, want.angle_max, want.angle_increment, want.range_max)
                );
                scans += 1;
            }
            "/odom" => {
                assert_eq!(decode_odom(&msg.data), sample_odom(odoms));
                odoms += 1;
            }
            "/ground_truth/path" => {
                let path = decode_path(&msg.data);
                assert_eq!(path.poses.len(), 3);
                assert_eq!(path.poses[2], ground_truth(2));
            }
            "/camera/camera_info" => {
                let info = decode_camera_info(&msg.data);
                assert_eq!(info.d, [0.1, -0.2, 0.001, 0.002, 0.0]);
                assert_eq!(info.k, [100.0, 0.0, 2.0, 0.0, 100.0, 1.5, 0.0, 0.0, 1.0]);
                assert!(info.roi.do_rectify);
            }
            _ => {}
        }
    }
    assert_eq!((scans, odoms), (3, 2));

    let yaml = std::fs::read_to_string(dir.join("metadata.yaml")).unwrap();
    for line in [
        "rosbag2_bagfile_information:",
        "  version: 8",
        "  storage_identifier: mcap",
        "  message_count: 13",
        "    nanoseconds: 1000000000",
        "    nanoseconds_since_epoch: 1700000000000000000",
        "        name: /tf_static",
        "        type: sensor_msgs/msg/LaserScan",
        "        serialization_format: cdr",
        "        type_description_hash: \
         RIHS01_64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828",
        &format!("    - {mcap_name}"),
        &format!("    - path: {mcap_name}"),
        "  custom_data: ~",
    ] {
        assert!(yaml.lines().any(|l| l == line), "missing {line:?} in\n{yaml}");
    }
    assert!(yaml.contains("      message_count: 3\n"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn refuses_a_non_empty_directory_and_a_file() {
    let dir = temp_bag_dir("nonempty");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("old.txt"), "x").unwrap();
    let err = BagWriter::create(&dir).unwrap_err();
    assert!(matches!(err, Error::DirectoryNotEmpty { .. }), "{err}");
    assert!(err.to_string().contains("not empty"));
    let file = dir.join("old.txt");
    assert!(matches!(BagWriter::create(&file), Err(Error::NotADirectory { .. })));
    // Left as it was.
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_existing_empty_directory_is_fine() {
    let dir = temp_bag_dir("empty");
    std::fs::create_dir_all(&dir).unwrap();
    BagWriter::create(&dir).unwrap().finish().unwrap();
    let yaml = std::fs::read_to_string(dir.join("metadata.yaml")).unwrap();
    assert!(yaml.contains("  message_count: 0\n  topics_with_message_count: []\n"), "{yaml}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_input_is_an_error_and_the_bag_stays_consistent() {
    let dir = temp_bag_dir("bad");
    let mut bag = BagWriter::create(&dir).unwrap();
    let scan = sample_scan(0);
    assert!(matches!(bag.write("scan", T0, &scan), Err(Error::InvalidTopicName { .. })));
    bag.write("/scan", T0, &scan).unwrap();
    let err = bag.write("/scan", T0, &sample_odom(0)).unwrap_err();
    assert!(matches!(err, Error::TopicTypeMismatch { .. }), "{err}");
    let mut bad = sample_scan(1);
    bad.header.frame_id = "la\0ser".into();
    let err = bag.write("/scan", T0 + MS, &bad).unwrap_err();
    assert!(matches!(err, Error::Encode { .. }), "{err}");
    // Registering again with the same type is fine; with another QoS it is not.
    bag.add_topic::<LaserScan>("/scan").unwrap();
    assert!(matches!(
        bag.add_topic_with_qos::<LaserScan>("/scan", ros2bag::TopicQos::TransientLocal),
        Err(Error::TopicQosMismatch { .. })
    ));
    bag.add_topic::<Image>("/camera/unused").unwrap();
    bag.finish().unwrap();

    let yaml = std::fs::read_to_string(dir.join("metadata.yaml")).unwrap();
    assert!(yaml.contains("  message_count: 1\n"), "{yaml}");
    assert!(yaml.contains("        name: /camera/unused\n"), "{yaml}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn dropping_without_finish_still_leaves_a_bag() {
    let dir = temp_bag_dir("dropped");
    {
        let mut bag = BagWriter::create(&dir).unwrap();
        bag.write("/scan", T0, &sample_scan(0)).unwrap();
    }
    let yaml = std::fs::read_to_string(dir.join("metadata.yaml")).unwrap();
    assert!(yaml.contains("  message_count: 1\n"), "{yaml}");
    let name = dir.file_name().unwrap().to_str().unwrap();
    let bytes = std::fs::read(dir.join(format!("{name}_0.mcap"))).unwrap();
    assert_eq!(mcap::MessageStream::new(&bytes).unwrap().count(), 1);
    std::fs::remove_dir_all(&dir).unwrap();
}
