//! `objslam record` output: every file exists, parses, and agrees with the others.

use std::collections::BTreeMap;

/// The park of seed 2 recorded as JSON lines into `dir` (simulator seed 4).
fn record_park(config: &sim::SimConfig, dir: &std::path::Path) -> scenarios::record::RecordSummary {
    let world = worlds::generate::park(&Default::default(), 2).unwrap();
    let scoring = scenarios::score::log::LogScoring::of_world();
    scenarios::record::record(&world, config, 4, &scoring, dir, scenarios::record::RecordFormat::Jsonl, |_, _| {})
        .unwrap()
}

#[test]
fn record_writes_a_readable_consistent_log() {
    let dir = std::env::temp_dir().join(format!("objslam-record-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let config = sim::SimConfig { max_duration_s: Some(10.0), ..Default::default() };
    let summary = record_park(&config, &dir);
    let world = worlds::generate::park(&Default::default(), 2).unwrap();
    assert!((summary.sim_seconds - 10.0).abs() < 0.02);

    let laser = std::fs::read_to_string(dir.join("laser.jsonl")).unwrap();
    let scans: Vec<sim::LaserScan> = laser.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(scans.len(), 101, "10 s at 10 Hz, first scan at t = 0");
    assert!(scans.iter().all(|s| s.ranges.len() == 361));
    assert!(scans.windows(2).all(|w| w[1].t > w[0].t));
    assert!(scans.iter().any(|s| s.ranges.iter().any(|r| r.is_finite())), "the laser saw nothing");

    let odo = std::fs::read_to_string(dir.join("odometry.jsonl")).unwrap();
    assert_eq!(odo.lines().count(), 201);
    let tum = std::fs::read_to_string(dir.join("ground_truth.tum")).unwrap();
    let rows: Vec<Vec<f64>> = tum
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split(' ').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 201);
    assert!(rows.iter().all(|r| r.len() == 8));
    // Unit quaternions.
    assert!(rows.iter().all(|r| ((r[4] * r[4] + r[5] * r[5] + r[6] * r[6] + r[7] * r[7]) - 1.0).abs() < 1e-6));

    let sensors: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("sensors.json")).unwrap()).unwrap();
    assert_eq!(sensors["laser"]["beams"], 361);
    let copy = worlds::load(&dir.join("world.toml")).unwrap();
    assert_eq!(copy, world);
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("metadata.json")).unwrap()).unwrap();
    assert_eq!(meta["seed"], 4);

    // Camera frames: 5 Hz, each with aligned instance, class and depth images.
    let cam = std::fs::read_to_string(dir.join("camera.jsonl")).unwrap();
    let frames: Vec<serde_json::Value> = cam.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(frames.len(), 51);
    assert_eq!(summary.camera_frames, 51);
    let f = &frames[10];
    let rgb = image::open(dir.join(f["image"].as_str().unwrap())).unwrap().to_rgb8();
    let inst = image::open(dir.join(f["instance"].as_str().unwrap())).unwrap().to_luma16();
    let class = image::open(dir.join(f["class"].as_str().unwrap())).unwrap().to_luma8();
    assert_eq!((rgb.width(), rgb.height()), (640, 480));
    assert_eq!((inst.width(), inst.height()), (640, 480));
    for (i, c) in inst.pixels().zip(class.pixels()) {
        let id = i.0[0];
        let expected = match id {
            0 => 0,
            worlds::validate::GROUND_INSTANCE_ID => worlds::ObjectClass::Ground.id(),
            id => world.class_of(id).expect("ids from the world").id(),
        };
        assert_eq!(c.0[0], expected);
    }
    assert!(inst.pixels().any(|p| p.0[0] != 0 && p.0[0] != worlds::validate::GROUND_INSTANCE_ID), "no object in view");
    assert_eq!(f["K"][0][0].as_f64().unwrap(), sensors["camera"]["K"][0][0].as_f64().unwrap());
    assert!(sensors["camera"]["laser_from_camera"]["Phi"].is_array());

    // The MCAP file reads back with Foxglove schemas on the expected topics.
    let bytes = std::fs::read(dir.join("run.mcap")).unwrap();
    let mut per_topic: BTreeMap<String, (String, usize)> = BTreeMap::new();
    let mut clouds = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let schema = m.channel.schema.as_ref().unwrap().name.clone();
        let e = per_topic.entry(m.channel.topic.clone()).or_insert((schema, 0));
        e.1 += 1;
        let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        if m.channel.topic == "/laser/points" {
            clouds.push(v);
        }
    }
    // The laser's returns only, as points in its frame: Foxglove draws nothing for a beam
    // without a return.
    assert_eq!(per_topic["/laser/points"], ("foxglove.PointCloud".to_string(), 101));
    let scans: Vec<sim::LaserScan> = std::fs::read_to_string(dir.join("laser.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    for (cloud, scan) in clouds.iter().zip(&scans) {
        use base64::Engine;
        let data = base64::engine::general_purpose::STANDARD.decode(cloud["data"].as_str().unwrap()).unwrap();
        let returns: Vec<(usize, f64)> =
            scan.ranges.iter().copied().enumerate().filter(|(_, r)| r.is_finite()).collect();
        assert_eq!(cloud["point_stride"], 16);
        assert_eq!(
            data.len(),
            16 * returns.len(),
            "one point per return, none for the {} beams without",
            scan.ranges.len() - returns.len()
        );
        for (point, (i, r)) in data.chunks(16).zip(returns) {
            let f = |k: usize| f32::from_le_bytes(point[4 * k..4 * k + 4].try_into().unwrap()) as f64;
            let a = scan.angle_min + i as f64 * scan.angle_increment;
            assert!((f(0) - r * a.cos()).abs() < 1e-4 && (f(1) - r * a.sin()).abs() < 1e-4 && (f(3) - r).abs() < 1e-4);
        }
    }
    assert!(scans.iter().any(|s| s.ranges.iter().any(|r| !r.is_finite())), "no scan without returns to leave out");
    assert_eq!(per_topic["/tf"], ("foxglove.FrameTransform".to_string(), 201));
    assert_eq!(per_topic["/odom"], ("foxglove.PosesInFrame".to_string(), 201));
    assert_eq!(per_topic["/tf_static"].1, 2, "base_link -> laser and -> camera_optical");
    assert_eq!(per_topic["/ground_truth/pose"].0, "foxglove.PosesInFrame");
    assert_eq!(per_topic["/camera/image"], ("foxglove.CompressedImage".to_string(), 51));
    assert_eq!(per_topic["/camera/calibration"].0, "foxglove.CameraCalibration");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A little-endian CDR reader, written apart from the writer, for reading bags back.
struct Cdr<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Cdr<'a> {
    fn new(message: &'a [u8]) -> Self {
        assert_eq!(&message[..2], &[0, 1], "CDR little-endian encapsulation");
        Cdr { data: &message[4..], pos: 0 }
    }
    fn align(&mut self, n: usize) {
        self.pos = self.pos.div_ceil(n) * n;
    }
    fn u32(&mut self) -> u32 {
        self.align(4);
        let v = u32::from_le_bytes(self.data[self.pos..self.pos + 4].try_into().unwrap());
        self.pos += 4;
        v
    }
    fn f32(&mut self) -> f32 {
        f32::from_bits(self.u32())
    }
    fn f64(&mut self) -> f64 {
        self.align(8);
        let v = f64::from_le_bytes(self.data[self.pos..self.pos + 8].try_into().unwrap());
        self.pos += 8;
        v
    }
    fn string(&mut self) -> String {
        let n = self.u32() as usize;
        let s = String::from_utf8(self.data[self.pos..self.pos + n - 1].to_vec()).unwrap();
        self.pos += n;
        s
    }
    /// A std_msgs/Header: (seconds, frame).
    fn header(&mut self) -> (f64, String) {
        let sec = self.u32() as i32 as f64;
        let nanosec = self.u32() as f64;
        (sec + nanosec * 1e-9, self.string())
    }
}

/// The ROS 2 bag of a recording holds the same scans as its JSON lines (ranges to the
/// float, no return as +inf), the noisy odometry, the camera, the static transforms, and
/// the ground truth on topics of its own.
#[test]
fn a_ros2_bag_holds_what_the_json_lines_hold_in_standard_messages() {
    let root = std::env::temp_dir().join(format!("objslam-record-ros2-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let world = worlds::generate::park(&Default::default(), 2).unwrap();
    let config = sim::SimConfig { max_duration_s: Some(3.0), ..Default::default() };
    use scenarios::record::{RecordFormat, record};
    record(
        &world,
        &config,
        4,
        &scenarios::score::log::LogScoring::of_world(),
        &root.join("jsonl"),
        RecordFormat::Jsonl,
        |_, _| {},
    )
    .unwrap();
    let bag = root.join("bag");
    let summary =
        record(&world, &config, 4, &scenarios::score::log::LogScoring::of_world(), &bag, RecordFormat::Ros2, |_, _| {})
            .unwrap();

    let metadata = std::fs::read_to_string(bag.join("metadata.yaml")).unwrap();
    assert!(
        metadata.contains("storage_identifier: mcap") && metadata.contains("sensor_msgs/msg/LaserScan"),
        "{metadata}"
    );
    let bytes = std::fs::read(bag.join("bag_0.mcap")).unwrap();
    let summary_section = mcap::read::Summary::read(&bytes).unwrap().expect("an MCAP summary");
    // How it was made travels as attachments: the same as the JSON-lines log's metadata,
    // its wall-clock summary apart, and the world.
    let attachment = |name: &str| {
        let index = summary_section.attachment_indexes.iter().find(|a| a.name == name).expect(name);
        mcap::read::attachment(&bytes, index).unwrap().data.into_owned()
    };
    let recording: serde_json::Value = serde_json::from_slice(&attachment("recording.json")).unwrap();
    let mut metadata_json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root.join("jsonl/metadata.json")).unwrap()).unwrap();
    metadata_json.as_object_mut().unwrap().remove("summary");
    assert_eq!(recording, metadata_json);
    assert_eq!(recording["seed"], 4);
    assert_eq!(String::from_utf8(attachment("world.toml")).unwrap(), world.to_toml());
    let mut topics: BTreeMap<String, (String, String)> = BTreeMap::new();
    for c in summary_section.channels.values() {
        let schema = c.schema.as_ref().expect("schema");
        assert_eq!((c.message_encoding.as_str(), schema.encoding.as_str()), ("cdr", "ros2msg"));
        topics.insert(c.topic.clone(), (schema.name.clone(), c.message_encoding.clone()));
    }
    for (topic, ty) in [
        ("/scan", "sensor_msgs/msg/LaserScan"),
        ("/odom", "nav_msgs/msg/Odometry"),
        ("/tf", "tf2_msgs/msg/TFMessage"),
        ("/tf_static", "tf2_msgs/msg/TFMessage"),
        ("/camera/image_raw", "sensor_msgs/msg/Image"),
        ("/camera/camera_info", "sensor_msgs/msg/CameraInfo"),
        ("/ground_truth/pose", "geometry_msgs/msg/PoseStamped"),
        ("/ground_truth/path", "nav_msgs/msg/Path"),
    ] {
        assert_eq!(topics.get(topic).map(|t| t.0.as_str()), Some(ty), "{topic}: {topics:?}");
    }

    let scans: Vec<sim::LaserScan> = std::fs::read_to_string(root.join("jsonl/laser.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let odometry: Vec<sim::Odometry> = std::fs::read_to_string(root.join("jsonl/odometry.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let (mut bag_scans, mut bag_odom, mut frames, mut static_frames) = (Vec::new(), Vec::new(), 0, Vec::new());
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let mut r = Cdr::new(&m.data);
        match m.channel.topic.as_str() {
            "/scan" => {
                let (t, frame) = r.header();
                assert_eq!(frame, "laser");
                let fields: Vec<f32> = (0..7).map(|_| r.f32()).collect();
                let ranges: Vec<f32> = (0..r.u32()).map(|_| r.f32()).collect();
                assert_eq!(m.log_time, (t * 1e9).round() as u64);
                bag_scans.push((t, fields, ranges));
            }
            "/odom" => {
                let (t, frame) = r.header();
                assert_eq!((frame.as_str(), r.string().as_str()), ("odom", "base_link"));
                bag_odom.push((t, [r.f64(), r.f64()]));
            }
            "/camera/image_raw" => {
                let _ = r.header();
                assert_eq!((r.u32(), r.u32(), r.string()), (480, 640, "rgb8".to_string()));
                frames += 1;
            }
            "/camera/camera_info" => {
                let _ = r.header();
                assert_eq!((r.u32(), r.u32(), r.string()), (480, 640, "plumb_bob".to_string()));
                (0..r.u32()).for_each(|_| assert_eq!(r.f64(), 0.0));
                let k: Vec<f64> = (0..9).map(|_| r.f64()).collect();
                // ROS puts pixel centres at whole coordinates: the image's centre is
                // (319.5, 239.5) there, (320, 240) in the simulator's own convention.
                let own = config.camera.intrinsics();
                assert_eq!((k[0], k[2], k[4], k[5]), (own.fx, 319.5, own.fy, 239.5));
                assert_eq!((own.cx, own.cy), (320.0, 240.0));
            }
            "/tf_static" => {
                for _ in 0..r.u32() {
                    let (_, parent) = r.header();
                    static_frames.push((parent, r.string()));
                    (0..7).for_each(|_| {
                        r.f64();
                    });
                }
            }
            _ => {}
        }
    }
    assert_eq!(bag_scans.len(), scans.len());
    for (s, (t, fields, ranges)) in scans.iter().zip(&bag_scans) {
        assert!((s.t - t).abs() < 1e-9);
        assert_eq!(fields[0], s.angle_min as f32);
        assert_eq!(fields[2], s.angle_increment as f32);
        assert_eq!(ranges.len(), s.ranges.len());
        for (a, b) in s.ranges.iter().zip(ranges) {
            assert!(if a.is_finite() { *b == *a as f32 } else { *b == f32::INFINITY }, "{a} against {b}");
        }
    }
    assert!(
        bag_scans.iter().any(|s| s.2.iter().any(|r| r.is_infinite()))
            && bag_scans.iter().any(|s| s.2.iter().any(|r| r.is_finite()))
    );
    // The odometry integrates the noisy increments from the origin of `odom`.
    assert_eq!(bag_odom.len(), odometry.len());
    let (mut x, mut y, mut th) = (0.0f64, 0.0f64, 0.0f64);
    for (o, (t, p)) in odometry.iter().zip(&bag_odom) {
        x += th.cos() * o.dx - th.sin() * o.dy;
        y += th.sin() * o.dx + th.cos() * o.dy;
        th += o.dtheta;
        assert!((o.t - t).abs() < 1e-9 && (p[0] - x).abs() < 1e-9 && (p[1] - y).abs() < 1e-9, "{p:?} against {x}, {y}");
    }
    assert_eq!(frames, summary.camera_frames);
    assert_eq!(
        static_frames,
        vec![("base_link".to_string(), "laser".to_string()), ("base_link".to_string(), "camera_optical".to_string())]
    );
    // Refuses to write over an earlier bag.
    assert!(
        record(&world, &config, 4, &scenarios::score::log::LogScoring::of_world(), &bag, RecordFormat::Ros2, |_, _| {})
            .is_err()
    );
    let _ = std::fs::remove_dir_all(&root);
}

/// A camera that renders no depth records its frames without a depth image (it panicked
/// on the empty depth buffer).
/// Without a camera a bag names no camera frame: tools would look for images that are not
/// there.
#[test]
fn a_bag_without_a_camera_has_no_camera_frame() {
    let root = std::env::temp_dir().join(format!("objslam-record-ros2-nocam-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let world = worlds::generate::park(&Default::default(), 2).unwrap();
    let mut config = sim::SimConfig { max_duration_s: Some(1.0), ..Default::default() };
    config.camera.enabled = false;
    let bag = root.join("bag");
    use scenarios::record::{RecordFormat, record};
    record(&world, &config, 4, &scenarios::score::log::LogScoring::of_world(), &bag, RecordFormat::Ros2, |_, _| {})
        .unwrap();
    let bytes = std::fs::read(bag.join("bag_0.mcap")).unwrap();
    let mut static_frames = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        assert!(!m.channel.topic.starts_with("/camera"), "{}", m.channel.topic);
        if m.channel.topic == "/tf_static" {
            let mut r = Cdr::new(&m.data);
            for _ in 0..r.u32() {
                let (_, parent) = r.header();
                static_frames.push((parent, r.string()));
                (0..7).for_each(|_| {
                    r.f64();
                });
            }
        }
    }
    assert_eq!(static_frames, vec![("base_link".to_string(), "laser".to_string())]);
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn a_camera_without_depth_records_frames_without_a_depth_image() {
    let dir = std::env::temp_dir().join(format!("objslam-record-nodepth-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut config = sim::SimConfig { max_duration_s: Some(0.5), ..Default::default() };
    config.camera.depth_image = false;
    record_park(&config, &dir);
    let frames: Vec<serde_json::Value> = std::fs::read_to_string(dir.join("camera.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert!(!frames.is_empty());
    for f in &frames {
        assert!(f["depth_mm"].is_null(), "{f}");
        assert!(dir.join(f["image"].as_str().unwrap()).exists() && dir.join(f["class"].as_str().unwrap()).exists());
    }
    let depth_pngs = std::fs::read_dir(dir.join("camera"))
        .unwrap()
        .filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().ends_with("_depth.png"))
        .count();
    assert_eq!(depth_pngs, 0);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A directory holds one recording: a robot log recorded over a JSON-lines log (they share
/// `world.toml` and `camera/`) leaves none of the other's files, and the other way round.
#[test]
fn a_recording_over_another_kind_of_log_leaves_none_of_its_files() {
    use scenarios::record::{RecordFormat, record};
    let dir = std::env::temp_dir().join(format!("objslam-record-kinds-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let world = worlds::generate::park(&Default::default(), 2).unwrap();
    let config = sim::SimConfig { max_duration_s: Some(1.0), ..Default::default() };
    let scoring = scenarios::score::log::LogScoring::of_world();
    let names = || {
        let mut n: Vec<String> =
            std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        n.sort();
        n
    };
    record(&world, &config, 4, &scoring, &dir, RecordFormat::Jsonl, |_, _| {}).unwrap();
    let jsonl = names();
    assert!(jsonl.contains(&"laser.jsonl".to_string()) && jsonl.contains(&"metadata.json".to_string()), "{jsonl:?}");
    record(&world, &config, 4, &scoring, &dir, RecordFormat::Log, |_, _| {}).unwrap();
    let log = names();
    assert!(log.contains(&"manifest.toml".to_string()), "{log:?}");
    assert!(!log.iter().any(|n| n.ends_with(".jsonl") || n == "metadata.json" || n == "run.mcap"), "{log:?}");
    record(&world, &config, 4, &scoring, &dir, RecordFormat::Jsonl, |_, _| {}).unwrap();
    assert_eq!(names(), jsonl, "the robot log's files are gone again");
    std::fs::remove_dir_all(&dir).unwrap();
}
