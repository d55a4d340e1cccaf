//! `objslam record` output: every file exists, parses, and agrees with the others.

use std::collections::BTreeMap;

#[test]
fn record_writes_a_readable_consistent_log() {
    let dir = std::env::temp_dir().join(format!("objslam-record-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let world = worlds::generate::park(&Default::default(), 2).unwrap();
    let config = sim::SimConfig { max_duration_s: Some(10.0), ..Default::default() };
    let summary = scenarios::record::record(&world, &config, 4, &dir, |_, _| {}).unwrap();
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
    let rows: Vec<Vec<f64>> = tum.lines().filter(|l| !l.starts_with('#')).map(|l| l.split(' ').map(|v| v.parse().unwrap()).collect()).collect();
    assert_eq!(rows.len(), 201);
    assert!(rows.iter().all(|r| r.len() == 8));
    // Unit quaternions.
    assert!(rows.iter().all(|r| ((r[4] * r[4] + r[5] * r[5] + r[6] * r[6] + r[7] * r[7]) - 1.0).abs() < 1e-6));

    let sensors: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("sensors.json")).unwrap()).unwrap();
    assert_eq!(sensors["laser"]["beams"], 361);
    let copy = worlds::load(&dir.join("world.toml")).unwrap();
    assert_eq!(copy, world);
    let meta: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("metadata.json")).unwrap()).unwrap();
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
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let schema = m.channel.schema.as_ref().unwrap().name.clone();
        let e = per_topic.entry(m.channel.topic.clone()).or_insert((schema, 0));
        e.1 += 1;
        let _: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
    }
    assert_eq!(per_topic["/laser"], ("foxglove.LaserScan".to_string(), 101));
    assert_eq!(per_topic["/tf"].0, "foxglove.FrameTransform");
    assert_eq!(per_topic["/ground_truth/pose"].0, "foxglove.PosesInFrame");
    assert_eq!(per_topic["/camera/image"], ("foxglove.CompressedImage".to_string(), 51));
    assert_eq!(per_topic["/camera/calibration"].0, "foxglove.CameraCalibration");
    let _ = std::fs::remove_dir_all(&dir);
}
