//! The log directory format: what is written reads back the same, and every malformed
//! file is an error naming the file and line.

use std::path::{Path, PathBuf};

use proptest::prelude::*;
use robotlog::manifest::{Camera, LaserGeometry, Reference, Sensor, Vehicle};
use robotlog::{
    DetectionScan, Log, LogError, Manifest, Motion, Observations, ReferenceKind, ReferencePoint, ReferenceSample,
    RgbImage,
};
use slam::messages::{Control, Detection, LaserScan, OdometryIncrement};

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("robotlog-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn manifest(motion: &str, laser: bool) -> Manifest {
    Manifest {
        format_version: 1,
        name: "test".into(),
        source: String::new(),
        vehicle: Vehicle { motion: motion.into(), ..Default::default() },
        sensor: Sensor {
            x_m: 0.2,
            y_m: 0.0,
            yaw_rad: 0.0,
            range_sigma_m: Some(0.05),
            range_sigma_per_m: None,
            bearing_sigma_rad: None,
        },
        laser: laser.then_some(LaserGeometry {
            angle_min_rad: -1.5,
            angle_increment_rad: 0.5,
            range_min_m: 0.1,
            range_max_m: 30.0,
        }),
        reference: Some(Reference { kind: ReferenceKind::GroundTruth, point: ReferencePoint::Vehicle }),
        camera: None,
    }
}

fn scan_log(ranges: Vec<Vec<f64>>, odometry: Vec<[f64; 3]>) -> Log {
    Log {
        manifest: manifest("odometry", true),
        motion: Motion::Increments(
            odometry
                .iter()
                .enumerate()
                .map(|(k, o)| OdometryIncrement { t: (k + 1) as f64 * 0.1, dx: o[0], dy: o[1], dtheta: o[2] })
                .collect(),
        ),
        observations: Observations::Scans(
            ranges
                .into_iter()
                .enumerate()
                .map(|(k, r)| LaserScan {
                    t: k as f64 * 0.2,
                    angle_min: -1.5,
                    angle_increment: 0.5,
                    range_min: 0.1,
                    range_max: 30.0,
                    ranges: r,
                })
                .collect(),
        ),
        reference: vec![ReferenceSample { t: 0.0, x: 1.0, y: 2.0, theta: Some(0.3) }],
        camera: Vec::new(),
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]
    /// Any finite numbers, no returns and returns too close to measure survive writing and
    /// reading bit for bit: a too-close return (-inf) stays apart from no return (+inf).
    #[test]
    fn logs_read_back_as_written(
        ranges in proptest::collection::vec(
            proptest::collection::vec(prop_oneof![0.1f64..30.0, Just(f64::INFINITY), Just(f64::NEG_INFINITY)], 7),
            1..5,
        ),
        odometry in proptest::collection::vec([-1.0f64..1.0, -0.1f64..0.1, -0.5f64..0.5], 1..20),
    ) {
        let d = dir("roundtrip");
        let log = scan_log(ranges, odometry);
        robotlog::format::write(&d, &log).unwrap();
        prop_assert_eq!(robotlog::format::read(&d).unwrap(), log);
        std::fs::remove_dir_all(&d).ok();
    }
}

#[test]
fn controls_and_detections_read_back_as_written() {
    let d = dir("detections");
    let log = Log {
        manifest: Manifest {
            vehicle: Vehicle {
                motion: "ackermann".into(),
                wheelbase_m: Some(2.83),
                encoder_offset_m: Some(0.76),
                start_pose: [1.0, 2.0, 0.5],
            },
            reference: Some(Reference { kind: ReferenceKind::Gps, point: ReferencePoint::Sensor }),
            ..manifest("ackermann", false)
        },
        motion: Motion::Controls(vec![
            (0.0, Control::Ackermann { speed: 2.0, steering: 0.1 }),
            (0.025, Control::Ackermann { speed: 2.1, steering: -0.05 }),
        ]),
        observations: Observations::Detections(vec![
            DetectionScan {
                t: 0.01,
                detections: vec![
                    Detection { range_m: 10.0, bearing_rad: 0.3, diameter_m: Some(0.4) },
                    Detection { range_m: 5.5, bearing_rad: -1.0, diameter_m: None },
                ],
            },
            DetectionScan { t: 0.3, detections: vec![Detection { range_m: 7.0, bearing_rad: 0.0, diameter_m: None }] },
        ]),
        reference: vec![ReferenceSample { t: 0.1, x: 5.0, y: 6.0, theta: None }],
        camera: Vec::new(),
    };
    robotlog::format::write(&d, &log).unwrap();
    assert_eq!(robotlog::format::read(&d).unwrap(), log);
    // A range no laser measures, however finite: refused at its line (it had reached the
    // filter and stopped the replay with an error naming no file).
    std::fs::write(d.join("detections.csv"), "t,range_m,bearing_rad,diameter_m\n0.01,1e300,0.1,0.3\n").unwrap();
    let e = robotlog::format::read(&d).unwrap_err().to_string();
    assert!(e.contains("detections.csv:2: `range_m` 1e300 lies beyond 1e9 m"), "{e}");
    std::fs::remove_dir_all(&d).ok();
}

/// Spaces or tabs on a file's last lines are blank lines at its end, which are fine.
#[test]
fn lines_of_spaces_at_a_files_end_are_blank_lines() {
    let d = dir("trailing-spaces");
    robotlog::format::write(&d, &scan_log(vec![vec![1.0; 7], vec![2.0; 7]], vec![[0.1, 0.0, 0.0]; 3])).unwrap();
    let before = robotlog::format::read(&d).unwrap();
    let odometry = d.join("odometry.csv");
    let text = std::fs::read_to_string(&odometry).unwrap();
    std::fs::write(&odometry, text + " \n\t\n").unwrap();
    assert_eq!(robotlog::format::read(&d).unwrap().motion, before.motion);
    std::fs::remove_dir_all(&d).ok();
}

/// Writes a valid scan log, replaces `file` with `text`, and returns the read error.
fn error_with(file: &str, text: &str) -> String {
    let d = dir(&format!("bad-{}", file.replace('.', "-")));
    robotlog::format::write(&d, &scan_log(vec![vec![1.0; 7], vec![2.0; 7]], vec![[0.1, 0.0, 0.0]; 3])).unwrap();
    std::fs::write(d.join(file), text).unwrap();
    let e = robotlog::format::read(&d).unwrap_err();
    std::fs::remove_dir_all(&d).ok();
    e.to_string()
}

#[test]
fn malformed_files_are_errors_that_name_file_and_line() {
    let cases = [
        (
            "odometry.csv",
            "t,dx,dy,dtheta\n0,0,0,0\n-1,0.1,0,0\n",
            "odometry.csv:3: t = -1 s comes before the previous row's 0 s",
        ),
        ("odometry.csv", "t,dx,dy\n0,1,2\n", "odometry.csv:1: header `t,dx,dy`"),
        ("odometry.csv", "t,dx,dy,dtheta\n0,abc,0,0\n", "odometry.csv:2: column `dx`: `abc` is not a number"),
        ("odometry.csv", "t,dx,dy,dtheta\n0,NaN,0,0\n", "odometry.csv:2: `dx` must be finite"),
        ("odometry.csv", "t,dx,dy,dtheta\n0,1,0\n", "odometry.csv:2: 3 columns, the header has 4"),
        // A header alone, a blank line where a row was, bytes that are not text.
        ("odometry.csv", "t,dx,dy,dtheta\n", "odometry.csv: a header and no row"),
        ("odometry.csv", "t,dx,dy,dtheta\n0,0,0,0\n\n0.2,1,0,0\n", "odometry.csv:3: a blank line before the last row"),
        ("odometry.csv", "t,dx,dy,dtheta\n\n0,1,0,0\n", "odometry.csv:2: a blank line before the last row"),
        // Lines ended by a lone carriage return, or by CR LF, as the CSV reader ends them.
        ("odometry.csv", "t,dx,dy,dtheta\r0,0,0,0\r\r0.2,1,0,0\r", "odometry.csv:3: a blank line before the last row"),
        ("odometry.csv", "t,dx,dy,dtheta\r\n0,0,0,0\r\n\r\n0.2,1,0,0\r\n", "odometry.csv:3: a blank line"),
        // Errors name the line whatever the line endings.
        ("odometry.csv", "t,dx,dy,dtheta\r\n0,0,0,0\r\n0.1,NaN,0,0\r\n", "odometry.csv:3: `dx` must be finite"),
        ("odometry.csv", "t,dx,dy,dtheta\r0,0,0,0\r0.1,NaN,0,0\r", "odometry.csv:3: `dx` must be finite"),
        // An empty quoted cell is a row of one column, not a blank line, wherever it stands.
        ("odometry.csv", "t,dx,dy,dtheta\n0,0,0,0\n\"\"\n0.2,1,0,0\n", "odometry.csv:3: 1 columns, the header has 4"),
        // Values no odometry gives: corrupt data, which would overflow the filter.
        ("odometry.csv", "t,dx,dy,dtheta\n0,1e300,0,0\n", "odometry.csv:2: a step of (1e300, 0e0) m is beyond 1e9 m"),
        ("odometry.csv", "t,v,omega\n0,0.5,0\n0.1,-1000,0\n", "odometry.csv:3: speed -1e3 m/s is beyond 343 m/s"),
        // The first row's motion is since the log's start (here its own time, with the
        // first scan's): a step there is one in no time, or as fast over the time since.
        (
            "odometry.csv",
            "t,dx,dy,dtheta\n0,1000,0,0\n",
            "odometry.csv:2: a step of 1000.000 m and 0 rad in no time: the first row's motion is since the log's start",
        ),
        (
            "odometry.csv",
            "t,dx,dy,dtheta\n0.5,1000,0,0\n",
            "odometry.csv:2: a step of 1000.000 m in 0.5 s is 2e3 m/s, beyond 343 m/s (the first row's motion: since the log's start at t = 0 s)",
        ),
        // An increment as fast, over the time since the row before.
        (
            "odometry.csv",
            "t,dx,dy,dtheta\n0,0,0,0\n0.05,30,40,0\n",
            "odometry.csv:3: a step of 50.000 m in 0.05 s is 1e3 m/s, beyond 343 m/s",
        ),
        // A step at a repeated time: a teleport, whatever its length.
        (
            "odometry.csv",
            "t,dx,dy,dtheta\n0,0,0,0\n2.45,0.02,0,0\n2.45,100,0,0\n",
            "odometry.csv:4: a step of 100.000 m and 0 rad in no time",
        ),
        // Turns in degrees read as radians.
        (
            "odometry.csv",
            "t,dx,dy,dtheta\n0,0,0,0\n0.05,0.02,0,45\n",
            "odometry.csv:3: dtheta 45 rad is more than half a turn in one step",
        ),
        ("odometry.csv", "t,v,omega\n0,0.5,45\n", "odometry.csv:2: omega 45 rad/s is beyond two turns a second"),
        // Huge but finite: a time, a range, a mounting (they had reached the filter).
        ("odometry.csv", "t,dx,dy,dtheta\n0,0,0,0\n1e300,0.1,0,0\n", "odometry.csv:3: t = 1e300 s lies beyond 1e10 s"),
        ("odometry.csv", "t,dx,dy,dtheta\n-1e300,0.1,0,0\n", "odometry.csv:2: t = -1e300 s lies beyond"),
        (
            "manifest.toml",
            "format_version = 1\n[sensor]\nx_m = 1e300\ny_m = 0\n",
            "sensor.x_m: 1e300 m from the vehicle's reference point: at most 50 m",
        ),
        (
            "manifest.toml",
            "format_version = 1\n[sensor]\nx_m = 0\ny_m = 0\nyaw_rad = 90.0\n",
            "sensor.yaw_rad: must be within a turn",
        ),
        (
            "manifest.toml",
            "format_version = 1\n[sensor]\nx_m = 0\ny_m = 0\nrange_sigma_m = 1e200\n",
            "sensor.range_sigma_m: must be at most 1e6, got 1e200",
        ),
        ("scans.csv", "t,r0\n", "scans.csv: a header and no row"),
        ("scans.csv", "t\n0\n", "scans.csv:1: no beam column after `t`"),
        ("odometry.csv", "t,speed,steering\n0,1,0\n", "needs `t,dx,dy,dtheta` or `t,v,omega`"),
        ("scans.csv", "t,r0,r1\n0,1,NaN\n", "scans.csv:2: a range is NaN"),
        ("scans.csv", "t,r0,r1\n0,1,1\n0.2,-2.5,1\n", "scans.csv:3: a range of -2.5 m is negative"),
        ("reference.csv", "t,x,y\n0,1,inf\n", "reference.csv:2: `y` must be finite"),
        (
            "manifest.toml",
            "format_version = 2\n[sensor]\nx_m = 0\ny_m = 0\n",
            "format_version: this objslam reads version 1, the file is version 2",
        ),
        (
            "manifest.toml",
            "format_version = 1\nbogus = 3\n[sensor]\nx_m = 0\ny_m = 0\n",
            "manifest.toml:2: unknown field `bogus`",
        ),
        (
            "manifest.toml",
            "format_version = 1\n[vehicle]\nstart_pose = [0.0, 1.0, 2.0, 3.0]\n[sensor]\nx_m = 0\ny_m = 0\n",
            "manifest.toml:3: vehicle.start_pose: 4 elements, more than it takes",
        ),
        (
            "manifest.toml",
            "format_version = 1\n[vehicle]\nmotion = \"tank\"\n[sensor]\nx_m = 0\ny_m = 0\n",
            "vehicle.motion: must be \"odometry\" or \"ackermann\"",
        ),
        (
            "manifest.toml",
            "format_version = 1\n[vehicle]\nmotion = \"ackermann\"\n[sensor]\nx_m = 0\ny_m = 0\n",
            "vehicle.wheelbase_m: is needed",
        ),
        (
            "manifest.toml",
            "format_version = 1\n[vehicle]\nmotion = \"ackermann\"\nwheelbase_m = 2830.0\n[sensor]\nx_m = 0\ny_m = 0\n",
            "vehicle.wheelbase_m: 2830 m: at most 50 m (metres, not millimetres)",
        ),
        (
            "manifest.toml",
            "format_version = 1\n[vehicle]\nstart_pose = [1e15, -6.0, 0.0]\n[sensor]\nx_m = 0\ny_m = 0\n",
            "vehicle.start_pose[0]: 1e15 m lies beyond 1e9 m",
        ),
        (
            "manifest.toml",
            "format_version = 1\n[sensor]\nx_m = 0\ny_m = 0\nbearing_sigma_rad = 4.0\n",
            "sensor.bearing_sigma_rad: must be at most pi (radians, not degrees), got 4e0",
        ),
        (
            "manifest.toml",
            "format_version = 1\n[vehicle]\nmotion = \"ackermann\"\nwheelbase_m = nan\n[sensor]\nx_m = 0\ny_m = 0\n",
            "vehicle.wheelbase_m: must be finite and positive",
        ),
        (
            "manifest.toml",
            "format_version = 1\n[sensor]\nx_m = 0\ny_m = 0\nrange_sigma_m = nan\n",
            "sensor.range_sigma_m: must be finite",
        ),
        (
            "manifest.toml",
            "format_version = 1\n[sensor]\nx_m = 0\ny_m = 0\nrange_sigma_m = 0.0\n",
            "sensor.range_sigma_m: must be finite and positive, got 0",
        ),
        (
            "manifest.toml",
            "format_version = 1\n[sensor]\nx_m = 0\ny_m = 0\n[laser]\nangle_min_rad = -90.0\nangle_increment_rad = 0.5\nrange_min_m = 0.1\nrange_max_m = 30.0\n",
            "laser.angle_min_rad: must be finite and within a turn (radians), got -90",
        ),
        (
            "manifest.toml",
            "format_version = 1\n[sensor]\nx_m = 0\ny_m = 0\n[laser]\nangle_min_rad = -1.5\nangle_increment_rad = 1.5\nrange_min_m = 0.1\nrange_max_m = 30.0\n",
            "laser.angle_increment_rad 1.5 over the 7 beams of scans.csv sweeps 9.00 rad, more than a turn",
        ),
    ];
    for (file, text, expected) in cases {
        let e = error_with(file, text);
        assert!(e.contains(expected), "{file} with {text:?}: {e}");
        assert!(e.contains(file), "{e} names the file");
    }
}

/// A log opened to be replayed reads the first odometry row against the log's start as a
/// log read whole does; a data file that is a link to nothing is named as such.
#[test]
fn the_first_odometry_row_is_the_motion_since_the_logs_start_however_the_log_is_read() {
    let d = dir("first-row");
    // The motion starts 0.1 s after the first scan: its first step is over that time.
    robotlog::format::write(&d, &scan_log(vec![vec![1.0; 7], vec![2.0; 7]], vec![[0.1, 0.0, 0.0]; 3])).unwrap();
    let mut log = robotlog::format::open(&d).unwrap();
    assert!(log.motion.all(|m| m.is_ok()));
    robotlog::format::read(&d).unwrap();
    std::fs::write(d.join("odometry.csv"), "t,dx,dy,dtheta\n0,5,0,0\n0.1,0.1,0,0\n").unwrap();
    let mut log = robotlog::format::open(&d).unwrap();
    let opened = log.motion.next().expect("a row").expect_err("a first row moving at the log's start").to_string();
    let read = robotlog::format::read(&d).unwrap_err().to_string();
    for e in [opened, read] {
        assert!(e.contains("odometry.csv:2: a step of 5.000 m and 0 rad in no time"), "{e}");
    }
    #[cfg(unix)]
    {
        std::fs::remove_file(d.join("reference.csv")).unwrap();
        std::os::unix::fs::symlink(d.join("nowhere.csv"), d.join("reference.csv")).unwrap();
        let e = robotlog::format::read(&d).unwrap_err().to_string();
        assert!(e.contains("reference.csv") && e.contains("a link to nothing"), "{e}");
    }
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn bytes_that_are_not_text_a_missing_reference_and_an_empty_log_are_errors() {
    let d = dir("not-text");
    let log = scan_log(vec![vec![1.0; 7], vec![2.0; 7]], vec![[0.1, 0.0, 0.0]; 3]);
    robotlog::format::write(&d, &log).unwrap();
    std::fs::write(d.join("odometry.csv"), b"t,dx,dy,dtheta\n0,0,0,0\n0.99,\xff\xfe,0,0\n").unwrap();
    let e = robotlog::format::read(&d).unwrap_err().to_string();
    assert!(e.contains("odometry.csv:3: field 2 is not UTF-8 text"), "{e}");
    std::fs::remove_dir_all(&d).ok();
    // The manifest says a reference is there; the file is not.
    let d = dir("no-reference");
    let mut with_reference = log.clone();
    with_reference.manifest.reference = Some(Reference { kind: ReferenceKind::Gps, point: ReferencePoint::Sensor });
    with_reference.reference = vec![ReferenceSample { t: 0.1, x: 5.0, y: 6.0, theta: None }];
    robotlog::format::write(&d, &with_reference).unwrap();
    std::fs::remove_file(d.join("reference.csv")).unwrap();
    let e = robotlog::format::read(&d).unwrap_err().to_string();
    assert!(e.contains("manifest.toml") && e.contains("no reference.csv"), "{e}");
    std::fs::remove_dir_all(&d).ok();
    // Nothing is written that would be refused on reading: no motion, nothing seen.
    let d = dir("empty");
    let no_motion = Log { motion: Motion::Increments(vec![]), ..log.clone() };
    let e = robotlog::format::write(&d, &no_motion).unwrap_err().to_string();
    assert!(e.contains("odometry.csv") && e.contains("no motion message"), "{e}");
    let nothing_seen = Log { observations: Observations::Scans(vec![]), ..log.clone() };
    let e = robotlog::format::write(&d, &nothing_seen).unwrap_err().to_string();
    assert!(e.contains("scans.csv") && e.contains("no scan or detection"), "{e}");
    let no_beams = scan_log(vec![vec![], vec![]], vec![[0.1, 0.0, 0.0]; 3]);
    let e = robotlog::format::write(&d, &no_beams).unwrap_err().to_string();
    assert!(e.contains("scans.csv") && e.contains("no beam"), "{e}");
    let no_samples = Log { reference: vec![], ..log };
    assert!(no_samples.manifest.reference.is_some());
    let e = robotlog::format::write(&d, &no_samples).unwrap_err().to_string();
    assert!(e.contains("reference.csv") && e.contains("no reference sample"), "{e}");
    assert!(!d.exists(), "nothing written");
}

/// A 4x3 camera looking forward from 0.1 m above the sensor: optical z along the sensor's
/// x, optical x along its -y, optical y along its -z.
fn camera() -> Camera {
    Camera {
        width: 4,
        height: 3,
        fx: 2.0,
        fy: 2.0,
        cx: 2.0,
        cy: 1.5,
        rotation: [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]],
        translation_m: [0.0, 0.0, 0.1],
    }
}

/// A scan log with a camera and `frames` frames written as the recorder writes them.
fn camera_log(d: &Path, frames: usize) -> Log {
    let mut log = scan_log(vec![vec![1.0; 7], vec![2.0; 7]], vec![[0.1, 0.0, 0.0]; 3]);
    log.manifest.camera = Some(camera());
    log.camera = (0..frames)
        .map(|k| {
            let rgb = (0..36).map(|v| (v * 7 + k) as u8).collect();
            robotlog::format::write_frame(d, k, 0.1 * k as f64, &RgbImage { width: 4, height: 3, rgb }).unwrap()
        })
        .collect();
    robotlog::format::write(d, &log).unwrap();
    log
}

#[test]
fn camera_frames_read_back_pixel_for_pixel() {
    let d = dir("camera");
    let written = camera_log(&d, 3);
    let read = robotlog::format::read(&d).unwrap();
    assert_eq!(read.manifest, written.manifest);
    assert_eq!(read.camera.len(), 3);
    for (k, f) in read.camera.iter().enumerate() {
        assert_eq!(f.t, 0.1 * k as f64);
        assert_eq!(f.file, d.join(format!("camera/{k:06}.png")));
        let image = robotlog::format::read_frame(f, &camera()).unwrap();
        assert_eq!((image.width, image.height), (4, 3));
        assert_eq!(image.rgb, (0..36).map(|v| (v * 7 + k) as u8).collect::<Vec<u8>>());
    }
    // A frame of another size than the manifest's is refused, naming the image.
    let small = Camera { width: 5, ..camera() };
    let e = robotlog::format::read_frame(&read.camera[0], &small).unwrap_err().to_string();
    assert!(e.contains("000000.png") && e.contains("4x3") && e.contains("5x3"), "{e}");
    std::fs::remove_dir_all(&d).ok();
    // A camera that gave no frame reads back as one.
    let empty = camera_log(&d, 0);
    assert_eq!(robotlog::format::read(&d).unwrap(), empty);
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn jpeg_and_grey_frames_are_read_as_rgb() {
    let d = dir("camera-jpeg");
    let mut log = camera_log(&d, 0);
    // A flat grey JPEG (lossy, so a flat image: its pixels decode to the value written)
    // and an 8-bit grey PNG.
    std::fs::create_dir_all(d.join("camera")).unwrap();
    let jpeg = d.join("camera/grey.jpg");
    image::save_buffer(&jpeg, &[128u8; 12], 4, 3, image::ExtendedColorType::L8).unwrap();
    let png = d.join("camera/grey.png");
    image::save_buffer(&png, &[0u8, 50, 100, 150, 200, 250, 1, 2, 3, 4, 5, 6], 4, 3, image::ExtendedColorType::L8)
        .unwrap();
    log.camera = vec![
        robotlog::CameraFrameFile { t: 0.0, file: "camera/grey.jpg".into() },
        robotlog::CameraFrameFile { t: 0.1, file: "camera/grey.png".into() },
    ];
    robotlog::format::write(&d, &log).unwrap();
    let read = robotlog::format::read(&d).unwrap();
    let jpeg = robotlog::format::read_frame(&read.camera[0], &camera()).unwrap();
    assert!(jpeg.rgb.len() == 36 && jpeg.rgb.iter().all(|&v| v.abs_diff(128) <= 2), "{:?}", jpeg.rgb);
    let png = robotlog::format::read_frame(&read.camera[1], &camera()).unwrap();
    assert_eq!(&png.rgb[..6], &[0, 0, 0, 50, 50, 50]);
    // Something that is no image is an error naming the file.
    std::fs::write(d.join("camera/grey.png"), "not a picture").unwrap();
    let e = robotlog::format::read_frame(&read.camera[1], &camera()).unwrap_err().to_string();
    assert!(e.contains("grey.png"), "{e}");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn camera_files_and_tables_that_do_not_agree_are_errors() {
    let d = dir("camera-bad");
    camera_log(&d, 2);
    let read_error = || robotlog::format::read(&d).unwrap_err().to_string();
    let csv = std::fs::read_to_string(d.join("camera.csv")).unwrap();
    for (text, expected) in [
        ("t,image\n0,camera/000000.png\n", "camera.csv:1: header `t,image`; expected `t,file`"),
        ("t,file\n0.1,camera/000001.png\n0,camera/000000.png\n", "camera.csv:3: t = 0 s comes before"),
        ("t,file\nabc,camera/000000.png\n", "camera.csv:2: column `t`: `abc` is not a number"),
        ("t,file\ninf,camera/000000.png\n", "camera.csv:2: `t` must be finite"),
        ("t,file\n0,camera/missing.png\n", "camera.csv:2: no image file"),
        ("t,file\n0,\n", "camera.csv:2: `file` is empty"),
    ] {
        std::fs::write(d.join("camera.csv"), text).unwrap();
        let e = read_error();
        assert!(e.contains(expected), "{text:?}: {e}");
    }
    std::fs::write(d.join("camera.csv"), &csv).unwrap();
    let manifest = std::fs::read_to_string(d.join("manifest.toml")).unwrap();
    // The table without the frames, and the frames without the table.
    std::fs::remove_file(d.join("camera.csv")).unwrap();
    assert!(read_error().contains("no camera.csv lists its frames"));
    std::fs::write(d.join("camera.csv"), &csv).unwrap();
    let without_table = manifest.split("[camera]").next().unwrap().to_string();
    std::fs::write(d.join("manifest.toml"), without_table).unwrap();
    assert!(read_error().contains("no [camera] table"));
    // A rotation that is not one, and an empty image size.
    for (from, to, expected) in [
        ("rotation = [[0.0, 0.0, 1.0]", "rotation = [[0.0, 0.0, 2.0]", "camera.rotation: must be a rotation"),
        ("rotation = [[0.0, 0.0, 1.0]", "rotation = [[0.0, 0.0, nan]", "camera.rotation: must be finite"),
        ("width = 4", "width = 0", "camera.width: must be at least 1 pixel"),
        ("height = 3", "height = 0", "camera.height: must be at least 1 pixel"),
        ("fx = 2.0", "fx = -2.0", "camera.fx: must be finite and positive"),
        ("fx = 2.0", "fx = 1e308", "camera.fx: 1e308 pixels: at most 1e7"),
        ("translation_m = [0.0, 0.0, 0.1]", "translation_m = [-60.0, 0.0, 150.0]", "camera.translation_m: -6e1 m"),
    ] {
        assert!(manifest.contains(from), "{manifest}");
        std::fs::write(d.join("manifest.toml"), manifest.replace(from, to)).unwrap();
        let e = read_error();
        assert!(e.contains(expected) && e.contains("manifest.toml"), "{to}: {e}");
    }
    // A rotation printed to six decimals is one (a yaw of 9 and a pitch of 18 degrees).
    let printed =
        "rotation = [[0.156434, -0.305212, 0.939347], [-0.987688, -0.048341, 0.148778], [0.0, -0.951057, -0.309017]]";
    let rotation_line = manifest.lines().find(|l| l.starts_with("rotation = ")).unwrap();
    std::fs::write(d.join("manifest.toml"), manifest.replace(rotation_line, printed)).unwrap();
    robotlog::format::read(&d).unwrap();
    // A mirror (determinant -1) is no rotation either.
    let mirrored = manifest.replace("[-1.0, 0.0, 0.0]", "[1.0, 0.0, 0.0]");
    assert_ne!(mirrored, manifest);
    std::fs::write(d.join("manifest.toml"), mirrored).unwrap();
    let e = read_error();
    assert!(e.contains("manifest.toml") && e.contains("camera.rotation") && e.contains("determinant is -1"), "{e}");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn a_turned_sensor_turns_the_camera_with_its_returns() {
    // The pipeline takes returns in the vehicle's heading; a point straight ahead of a
    // sensor yawed 90 degrees is to the vehicle's left, and still on the camera's axis.
    // The camera sits 0.2 m ahead of and 0.1 m left of the sensor, 0.1 m up. A point 5 m
    // ahead of the camera and 1 m to its right (optical +x) projects to u = cx + fx/5, plus
    // the half pixel by which the pipeline's pixel centres run ahead of the manifest's
    // (ROS's) whole-number ones.
    let mut m = manifest("odometry", true);
    m.camera = Some(Camera { translation_m: [0.2, 0.1, 0.1], ..camera() });
    let expected = [2.0 + 2.0 / 5.0 + 0.5, 1.5 + 0.5];
    let sensor_point = [5.2, 0.1 - 1.0, 0.1];
    let pixel = m.camera_geometry().unwrap().project(&nalgebra::Vector3::from(sensor_point)).unwrap();
    assert!((pixel[0] - expected[0]).abs() < 1e-9 && (pixel[1] - expected[1]).abs() < 1e-9, "{pixel:?}");
    // Turned 90 degrees, the same point lies at (-y, x) in the vehicle's heading.
    m.sensor.yaw_rad = std::f64::consts::FRAC_PI_2;
    let turned = nalgebra::Vector3::new(-sensor_point[1], sensor_point[0], sensor_point[2]);
    let pixel = m.camera_geometry().unwrap().project(&turned).unwrap();
    assert!((pixel[0] - expected[0]).abs() < 1e-9 && (pixel[1] - expected[1]).abs() < 1e-9, "{pixel:?}");
}

#[test]
fn missing_or_doubled_observation_files_are_errors() {
    let d = dir("missing");
    robotlog::format::write(&d, &scan_log(vec![vec![1.0; 7]], vec![[0.1, 0.0, 0.0]])).unwrap();
    std::fs::write(d.join("detections.csv"), "t,range_m,bearing_rad,diameter_m\n").unwrap();
    assert!(robotlog::format::read(&d).unwrap_err().to_string().contains("both scans.csv and detections.csv"));
    std::fs::remove_file(d.join("detections.csv")).unwrap();
    std::fs::remove_file(d.join("scans.csv")).unwrap();
    assert!(matches!(robotlog::format::read(&d), Err(LogError::Missing { .. })));
    assert!(matches!(robotlog::format::read(Path::new("/nonexistent/log")),
        Err(LogError::File { problem, .. }) if problem.starts_with("no such directory")));
    std::fs::remove_dir_all(&d).ok();
}

/// A reference or frame list read again as a replay goes, changed since the log was
/// opened (cut, grown, replaced), is an error naming it, never what it now holds.
#[test]
fn a_reread_file_changed_after_opening_is_an_error() {
    let d = dir("reread");
    let mut log = scan_log(vec![vec![1.0; 7], vec![2.0; 7]], vec![[0.1, 0.0, 0.0]; 3]);
    log.manifest.reference = Some(Reference { kind: ReferenceKind::GroundTruth, point: ReferencePoint::Vehicle });
    log.reference = (0..50).map(|k| ReferenceSample { t: 0.01 * k as f64, x: k as f64, y: 0.0, theta: None }).collect();
    robotlog::format::write(&d, &log).unwrap();
    let file = d.join("reference.csv");
    let whole = std::fs::read_to_string(&file).unwrap();
    let read_all = |stream: &robotlog::stream::LogStream| -> Result<usize, LogError> {
        let mut n = 0;
        for row in stream.reference.rows()? {
            row?;
            n += 1;
        }
        Ok(n)
    };
    let stream = robotlog::format::open(&d).unwrap();
    assert_eq!((stream.reference.len(), read_all(&stream).unwrap(), read_all(&stream).unwrap()), (50, 50, 50));
    let cut: String = whole.lines().take(30).map(|l| format!("{l}\n")).collect();
    let grown = format!("{whole}0.5,50,0\n");
    for changed in [cut, grown] {
        let stream = robotlog::format::open(&d).unwrap();
        std::fs::write(&file, &changed).unwrap();
        let e = read_all(&stream).unwrap_err().to_string();
        assert!(e.contains("reference.csv") && e.contains("changed after the log was opened"), "{e}");
        std::fs::write(&file, &whole).unwrap();
    }
    // Replaced by another file of the same bytes: another file all the same.
    let stream = robotlog::format::open(&d).unwrap();
    std::fs::write(d.join("other.csv"), &whole).unwrap();
    std::fs::rename(d.join("other.csv"), &file).unwrap();
    assert!(read_all(&stream).unwrap_err().to_string().contains("changed after the log was opened"));
    // Changed while a pass reads it: grown after its first rows were read, the pass ends
    // in the error; cut, the row the reader meets no more is called a change, not bad.
    for edit in ["grow", "cut"] {
        std::fs::write(&file, &whole).unwrap();
        let stream = robotlog::format::open(&d).unwrap();
        let mut rows = stream.reference.rows().unwrap();
        for _ in 0..5 {
            rows.next().unwrap().unwrap();
        }
        let text = match edit {
            "grow" => format!("{whole}0.5,50,0\n"),
            _ => whole.lines().take(3).map(|l| format!("{l}\n")).collect(),
        };
        std::fs::OpenOptions::new().write(true).truncate(true).open(&file).unwrap();
        std::fs::write(&file, text).unwrap();
        let e = rows.find_map(Result::err).expect("the change is found").to_string();
        assert!(e.contains("changed after the log was opened"), "{edit}: {e}");
    }
    // Gone: changed as well, not a bare I/O error.
    let stream = robotlog::format::open(&d).unwrap();
    std::fs::remove_file(&file).unwrap();
    assert!(read_all(&stream).unwrap_err().to_string().contains("changed after the log was opened"));
    std::fs::remove_dir_all(&d).ok();
}

/// A data file that is not a regular file (a device, a pipe) is refused before it is read:
/// it could block or never end. A reference beyond 1e9 m is refused, and a [laser] table
/// in a log of detections.
#[test]
fn devices_far_references_and_a_laser_table_without_scans_are_errors() {
    let d = dir("device");
    let mut log = scan_log(vec![vec![1.0; 7], vec![2.0; 7]], vec![[0.1, 0.0, 0.0]; 3]);
    log.manifest.reference = Some(Reference { kind: ReferenceKind::Gps, point: ReferencePoint::Vehicle });
    log.reference = vec![ReferenceSample { t: 0.0, x: 1.0, y: 2.0, theta: None }];
    robotlog::format::write(&d, &log).unwrap();
    std::fs::remove_file(d.join("reference.csv")).unwrap();
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink("/dev/zero", d.join("reference.csv")).unwrap();
        let e = robotlog::format::open(&d).err().expect("refused").to_string();
        assert!(e.contains("reference.csv") && e.contains("not a regular file"), "{e}");
        std::fs::remove_file(d.join("reference.csv")).unwrap();
    }
    std::fs::write(d.join("reference.csv"), "t,x,y\n0,1e300,2\n").unwrap();
    let e = robotlog::format::open(&d).err().expect("refused").to_string();
    assert!(e.contains("reference.csv:2") && e.contains("beyond 1e9 m"), "{e}");
    std::fs::remove_dir_all(&d).ok();

    let mut detections = scan_log(vec![vec![1.0; 7]], vec![[0.1, 0.0, 0.0]]);
    detections.observations = Observations::Detections(vec![DetectionScan {
        t: 0.1,
        detections: vec![Detection { range_m: 3.0, bearing_rad: 0.1, diameter_m: None }],
    }]);
    let e = robotlog::format::write(&d, &detections).unwrap_err().to_string();
    assert!(e.contains("manifest.toml") && e.contains("[laser] table"), "{e}");
    detections.manifest.laser = None;
    robotlog::format::write(&d, &detections).unwrap();
    let text = std::fs::read_to_string(d.join("manifest.toml")).unwrap();
    std::fs::write(
        d.join("manifest.toml"),
        text + "\n[laser]\nangle_min_rad = -1.5\nangle_increment_rad = 0.5\nrange_min_m = 0.1\nrange_max_m = 30.0\n",
    )
    .unwrap();
    let e = robotlog::format::read(&d).unwrap_err().to_string();
    assert!(e.contains("manifest.toml") && e.contains("[laser] table describes scans.csv"), "{e}");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn victoria_park_files_that_are_not_mat_files_are_errors() {
    let d = dir("vp-bad");
    std::fs::create_dir_all(&d).unwrap();
    assert!(matches!(robotlog::victoria_park::read(&d), Err(LogError::Missing { .. })));
    std::fs::write(d.join("VictoriaParkSinSincronizar.mat"), b"MATLAB 5.0 MAT-file, not really").unwrap();
    let e = robotlog::victoria_park::read(&d).unwrap_err().to_string();
    assert!(e.contains("VictoriaParkSinSincronizar.mat: not a MAT-file: 31 bytes, fewer than"), "{e}");
    std::fs::remove_dir_all(&d).ok();
}

/// Published files with values no car or laser gives are refused, naming the file and
/// the element, rather than replayed into a diverging filter.
#[test]
fn victoria_park_values_that_cannot_be_are_errors() {
    use matrw::{MatFile, MatVariable, NumericArray};
    let d = dir("vp-values");
    let numeric =
        |dim: Vec<usize>, v: matrw::MatlabType| MatVariable::NumericArray(NumericArray::new(dim, v, None).unwrap());
    let write_dr = |times: Vec<f64>| {
        let n = times.len();
        let mut dr = MatFile::new();
        dr.insert("time", numeric(vec![n, 1], times.into()));
        dr.insert("speed", numeric(vec![n, 1], vec![2.0f64; n].into()));
        dr.insert("steering", numeric(vec![n, 1], vec![0.0f64; n].into()));
        matrw::save_matfile_v7(d.join("aa3_dr.mat").to_str().unwrap(), dr, true).unwrap();
    };
    let write_lsr = |first_beam_cm: f64| {
        let mut ranges = vec![1000.0f64; 2 * 361];
        ranges[1] = first_beam_cm;
        let mut lsr = MatFile::new();
        lsr.insert("TLsr", numeric(vec![2, 1], vec![1010.0f64, 1220.0].into()));
        lsr.insert("LASER", numeric(vec![2, 361], ranges.into()));
        matrw::save_matfile_v7(d.join("aa3_lsr2.mat").to_str().unwrap(), lsr, true).unwrap();
    };
    let error = || robotlog::victoria_park::read(&d).unwrap_err().to_string();
    std::fs::create_dir_all(&d).unwrap();
    write_dr(vec![1000.0, 1025.0]);
    write_lsr(f64::NAN);
    let e = error();
    assert!(e.contains("aa3_lsr2.mat") && e.contains("`LASER` row 2, beam 1 is NaN"), "{e}");
    write_lsr(-5.0);
    assert!(error().contains("row 2, beam 1 is -5"), "{}", error());
    write_lsr(1000.0);
    write_dr(Vec::new());
    let e = error();
    assert!(e.contains("aa3_dr.mat") && e.contains("`time` is empty"), "{e}");
    write_dr(vec![1000.0, 1025.0]);
    let mut dr = MatFile::new();
    dr.insert("time", numeric(vec![2, 1], vec![1000.0f64, 1025.0].into()));
    dr.insert("speed", numeric(vec![2, 1], vec![2.0f64, 1e300].into()));
    dr.insert("steering", numeric(vec![2, 1], vec![0.0f64, 0.0].into()));
    matrw::save_matfile_v7(d.join("aa3_dr.mat").to_str().unwrap(), dr, true).unwrap();
    let e = error();
    assert!(e.contains("aa3_dr.mat") && e.contains("control 2: speed 1e300 m/s is beyond 343 m/s"), "{e}");
    write_dr(vec![1000.0, 1025.0]);
    let mut gps = MatFile::new();
    gps.insert("timeGps", numeric(vec![2, 1], vec![1000.0f64, 1200.0].into()));
    gps.insert("Lo_m", numeric(vec![2, 1], vec![1.0f64, 1e12].into()));
    gps.insert("La_m", numeric(vec![2, 1], vec![1.0f64, 2.0].into()));
    matrw::save_matfile_v7(d.join("aa3_gpsx.mat").to_str().unwrap(), gps, true).unwrap();
    let e = error();
    assert!(e.contains("aa3_gpsx.mat") && e.contains("fix 2 (1.000e12, 2.000e0) lies beyond 1e9 m"), "{e}");
    std::fs::remove_dir_all(&d).ok();
}

/// The detections form's bearings in degrees, and more detection cells than scan times,
/// are refused with the file and the cell, not mapped or dropped.
#[test]
fn victoria_park_detections_in_degrees_or_without_a_time_are_refused() {
    use matrw::{CellArray, MatFile, MatVariable, NumericArray};
    let d = dir("vp-detections");
    std::fs::create_dir_all(&d).unwrap();
    let numeric =
        |dim: Vec<usize>, v: Vec<f64>| MatVariable::NumericArray(NumericArray::new(dim, v.into(), None).unwrap());
    let write = |bearing: f64, cells: usize| {
        let mut mat = MatFile::new();
        mat.insert("time", numeric(vec![1, 3], vec![0.0, 0.5, 1.0]));
        mat.insert("u", numeric(vec![2, 3], vec![1.0, 0.0, 1.0, 0.0, 1.0, 0.0]));
        mat.insert("TLsr", numeric(vec![1, 2], vec![0.2, 0.7]));
        let zt: Vec<MatVariable> = (0..cells).map(|_| numeric(vec![3, 1], vec![10.0, bearing, 0.3])).collect();
        mat.insert("zt", MatVariable::CellArray(CellArray::new(vec![1, cells], zt).unwrap()));
        let file = d.join("VictoriaParkSinSincronizar.mat");
        matrw::save_matfile_v7(file.to_str().unwrap(), mat, true).unwrap();
    };
    write(1.2, 2);
    assert!(robotlog::victoria_park::read(&d).is_ok());
    write(95.0, 2);
    let e = robotlog::victoria_park::read(&d).unwrap_err().to_string();
    assert!(
        e.contains("VictoriaParkSinSincronizar.mat: `zt` cell 1 holds bearing 95 beyond a turn: radians, not degrees"),
        "{e}"
    );
    write(1.2, 3);
    let e = robotlog::victoria_park::read(&d).unwrap_err().to_string();
    assert!(e.contains("`zt` has 3 cells, more than `TLsr` has times (2)"), "{e}");
    std::fs::remove_dir_all(&d).ok();
}

/// The ACFR originals' form, made here: `aa3_dr.mat` (ms, speed, steering as int32 and
/// double) and `aa3_lsr2.mat` (ms, N x 361 ranges in cm as uint16, 8191 for no return).
#[test]
fn victoria_park_originals_are_read_as_controls_and_raw_scans() {
    use matrw::{MatFile, MatVariable, NumericArray};
    let d = dir("vp-originals");
    std::fs::create_dir_all(&d).unwrap();
    let numeric =
        |dim: Vec<usize>, v: matrw::MatlabType| MatVariable::NumericArray(NumericArray::new(dim, v, None).unwrap());
    let mut dr = MatFile::new();
    dr.insert("time", numeric(vec![3, 1], vec![1000i32, 1025, 1050].into()));
    dr.insert("speed", numeric(vec![3, 1], vec![2.0f64, 2.1, 2.2].into()));
    dr.insert("steering", numeric(vec![3, 1], vec![0.0f64, 0.01, -0.02].into()));
    matrw::save_matfile_v7(d.join("aa3_dr.mat").to_str().unwrap(), dr, true).unwrap();
    // Two scans; column-major N x 361: beam b of scan k at b * 2 + k.
    let mut ranges = vec![0u16; 2 * 361];
    for b in 0..361 {
        ranges[b * 2] = 1000 + b as u16;
        ranges[b * 2 + 1] = if b == 180 { 8191 } else { 2000 };
    }
    let mut lsr = MatFile::new();
    lsr.insert("TLsr", numeric(vec![2, 1], vec![1010u32, 1220].into()));
    lsr.insert("LASER", numeric(vec![2, 361], ranges.into()));
    matrw::save_matfile_v7(d.join("aa3_lsr2.mat").to_str().unwrap(), lsr, true).unwrap();

    let log = robotlog::victoria_park::read(&d).unwrap();
    let Motion::Controls(controls) = &log.motion else { panic!("controls") };
    assert_eq!(controls[1], (1.025, Control::Ackermann { speed: 2.1, steering: 0.01 }));
    let Observations::Scans(scans) = &log.observations else { panic!("scans") };
    assert_eq!(scans.len(), 2);
    assert_eq!((scans[0].t, scans[1].t), (1.01, 1.22));
    assert_eq!(scans[0].ranges[5], 10.05);
    assert!((scans[0].angle(0) + std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    assert!((scans[0].angle(360) - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    assert!(!scans[1].valid(180), "above 8000 cm is no return");
    assert!(scans[1].valid(179));
    // No GPS; the estimate still describes the laser, the point GPS would be compared with.
    assert!(log.reference.is_empty());
    assert_eq!(log.manifest.reference, Some(Reference { kind: ReferenceKind::Gps, point: ReferencePoint::Sensor }));
    // The same file as scipy's savemat heads it (no comma after `MAT-file`) is read alike.
    let file = d.join("aa3_dr.mat");
    let mut bytes = std::fs::read(&file).unwrap();
    let text = b"MATLAB 5.0 MAT-file Platform: posix, Created on: Sun Dec  6 12:00:00 2026";
    bytes[..116].fill(b' ');
    bytes[..text.len()].copy_from_slice(text);
    std::fs::write(&file, &bytes).unwrap();
    assert_eq!(robotlog::victoria_park::read(&d).unwrap().motion, log.motion);
    // An empty file, and a header no parser reads: plain messages, no parser internals.
    std::fs::write(d.join("aa3_lsr2.mat"), b"").unwrap();
    let e = robotlog::victoria_park::read(&d).unwrap_err().to_string();
    assert!(e.contains("aa3_lsr2.mat: not a MAT-file: 0 bytes, fewer than a MAT-file's 128-byte header"), "{e}");
    std::fs::write(d.join("aa3_lsr2.mat"), [b'x'; 300]).unwrap();
    let e = robotlog::victoria_park::read(&d).unwrap_err().to_string();
    assert!(
        e.contains("aa3_lsr2.mat: not a MAT-file of version 5 or 7: its header does not open with `MATLAB`"),
        "{e}"
    );
    let mut v73 = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Dec  7 2026 HDF5 schema 1.00 .".to_vec();
    v73.resize(600, b' ');
    std::fs::write(d.join("aa3_lsr2.mat"), v73).unwrap();
    let e = robotlog::victoria_park::read(&d).unwrap_err().to_string();
    assert!(e.contains("aa3_lsr2.mat: a MAT-file of version 7.3 (HDF5), which is not read"), "{e}");
    let mut header = b"MATLAB 5.0 MAT-file, cut short".to_vec();
    header.resize(300, b'x');
    std::fs::write(d.join("aa3_lsr2.mat"), header).unwrap();
    let e = robotlog::victoria_park::read(&d).unwrap_err().to_string();
    assert!(e.contains("aa3_lsr2.mat: not a readable MAT-file (damaged or cut short?): "), "{e}");
    assert!(!e.contains("Backtrace") && !e.contains(".cargo") && !e.contains('\u{2501}'), "{e}");
    std::fs::remove_dir_all(&d).ok();
}

/// A log given as a file, or as a directory that is not there, is refused as such (not as a
/// `manifest.toml` missing inside it), by the robot-log reader and the Victoria Park one.
#[test]
fn a_log_that_is_no_directory_is_refused_as_such() {
    let root = dir("not-a-dir");
    std::fs::create_dir_all(&root).unwrap();
    let file = root.join("log.csv");
    std::fs::write(&file, "t\n").unwrap();
    let nowhere = root.join("nowhere");
    for (path, expect) in
        [(&file, "log.csv: not a directory: a robot log is a directory"), (&nowhere, "nowhere: no such directory")]
    {
        let e = robotlog::format::open(path).err().expect("refused").to_string();
        assert!(e.contains(expect), "{e}");
        assert!(robotlog::format::read(path).unwrap_err().to_string().contains(expect));
    }
    let e = robotlog::victoria_park::read(&file).unwrap_err().to_string();
    assert!(e.contains("log.csv: not a directory: give the directory that holds the data set's files"), "{e}");
    std::fs::remove_dir_all(&root).unwrap();
}

/// Clocks, ranges or GPS in units other than the published ones, values of types the
/// published files do not hold, and files that are not files are refused, naming the file
/// and the variable: each had been replayed into nonsense (a log a thousand times as long,
/// landmarks from the no-return code) or had hung.
#[test]
fn victoria_park_files_in_other_units_or_of_other_kinds_are_refused() {
    use matrw::{MatFile, MatVariable, MatlabType, NumericArray};
    let d = dir("vp-units");
    std::fs::create_dir_all(&d).unwrap();
    let numeric = |dim: Vec<usize>, v: MatlabType| MatVariable::NumericArray(NumericArray::new(dim, v, None).unwrap());
    let save = |name: &str, mat: MatFile| matrw::save_matfile_v7(d.join(name).to_str().unwrap(), mat, true).unwrap();
    let write_dr = |times_ms: MatlabType| {
        let mut dr = MatFile::new();
        dr.insert("time", numeric(vec![3, 1], times_ms));
        dr.insert("speed", numeric(vec![3, 1], vec![2.0f64; 3].into()));
        dr.insert("steering", numeric(vec![3, 1], vec![0.0f64; 3].into()));
        save("aa3_dr.mat", dr);
    };
    let write_lsr = |times_ms: Vec<f64>, cm: f64| {
        let mut lsr = MatFile::new();
        lsr.insert("TLsr", numeric(vec![2, 1], times_ms.into()));
        lsr.insert("LASER", numeric(vec![2, 361], vec![cm; 2 * 361].into()));
        save("aa3_lsr2.mat", lsr);
    };
    let error = || robotlog::victoria_park::read(&d).unwrap_err().to_string();
    // Sound: times as int64, as numpy saves integers; no GPS, and the path is still the laser's.
    write_dr(vec![1000i64, 1025, 1050].into());
    write_lsr(vec![1010.0, 1220.0], 1500.0);
    let log = robotlog::victoria_park::read(&d).unwrap();
    let Motion::Controls(controls) = &log.motion else { panic!("controls") };
    assert_eq!(controls[2].0, 1.05);
    assert_eq!(log.manifest.reference.map(|r| r.point), Some(ReferencePoint::Sensor));
    // Times in seconds where milliseconds are published.
    write_dr(vec![1.0f64, 1.025, 1.05].into());
    let e = error();
    assert!(e.contains("aa3_dr.mat: `time` steps by 2.500e-5 s (median) once read as milliseconds"), "{e}");
    write_dr(vec![1000i64, 1025, 1050].into());
    write_lsr(vec![1010.0e3, 1220.0e3], 1500.0);
    assert!(error().contains("aa3_lsr2.mat: `TLsr` steps by 2.100e2 s"), "{}", error());
    // A scan clock that never advanced: every scan at one instant.
    write_lsr(vec![1010.0, 1010.0], 1500.0);
    assert!(error().contains("aa3_lsr2.mat: `TLsr`: all 2 times are the same (1.01 s)"), "{}", error());
    // Ranges in metres, and in millimetres.
    write_lsr(vec![1010.0, 1220.0], 15.0);
    assert!(error().contains("aa3_lsr2.mat: `LASER`: no range of any scan reaches 100"), "{}", error());
    write_lsr(vec![1010.0, 1220.0], 15000.0);
    assert!(error().contains("aa3_lsr2.mat: `LASER`: every range of every scan is above 8000 cm"), "{}", error());
    write_lsr(vec![1010.0, 1220.0], 81830.0);
    assert!(error().contains("aa3_lsr2.mat: `LASER`: a range of 81830, more than the 65535"), "{}", error());
    write_lsr(vec![1010.0, 1220.0], 1500.0);
    // GPS in seconds, and GPS with no fix.
    let write_gps = |times: Vec<f64>, lo: Vec<f64>| {
        let mut gps = MatFile::new();
        let n = times.len();
        gps.insert("timeGps", numeric(vec![n, 1], times.into()));
        gps.insert("Lo_m", numeric(vec![n, 1], lo.into()));
        gps.insert("La_m", numeric(vec![n, 1], vec![1.0f64; n].into()));
        save("aa3_gpsx.mat", gps);
    };
    write_gps(vec![1.0, 2.0, 3.0], vec![1.0, 2.0, 3.0]);
    assert!(error().contains("aa3_gpsx.mat: `timeGps` steps by 1.000e-3 s"), "{}", error());
    write_gps(vec![1000.0, 2000.0, 3000.0], vec![f64::NAN; 3]);
    assert!(error().contains("aa3_gpsx.mat: none of its 3 fixes has finite `Lo_m` and `La_m`"), "{}", error());
    write_gps(vec![1000.0, 2000.0, 3000.0], vec![1.0, 2.0, 3.0]);
    assert_eq!(robotlog::victoria_park::read(&d).unwrap().reference.len(), 3);
    // A complex variable: its imaginary part would be dropped.
    let mut dr = MatFile::new();
    let complex = NumericArray::new(vec![3, 1], vec![1000.0f64, 1025.0, 1050.0].into(), Some(vec![0.5f64; 3].into()));
    dr.insert("time", MatVariable::NumericArray(complex.unwrap()));
    dr.insert("speed", numeric(vec![3, 1], vec![2.0f64; 3].into()));
    dr.insert("steering", numeric(vec![3, 1], vec![0.0f64; 3].into()));
    save("aa3_dr.mat", dr);
    assert!(error().contains("aa3_dr.mat: variable `time` is complex"), "{}", error());
    #[cfg(unix)]
    {
        // A link to nothing in the detections form's name is named, not passed over for
        // the originals; a pipe is refused, not read for ever.
        std::os::unix::fs::symlink(d.join("nowhere.mat"), d.join("VictoriaParkSinSincronizar.mat")).unwrap();
        assert!(error().contains("VictoriaParkSinSincronizar.mat"), "{}", error());
        std::fs::remove_file(d.join("VictoriaParkSinSincronizar.mat")).unwrap();
        let status = std::process::Command::new("mkfifo").arg(d.join("aa3_dr.mat.fifo")).status();
        if status.is_ok_and(|s| s.success()) {
            std::fs::rename(d.join("aa3_dr.mat.fifo"), d.join("aa3_dr.mat")).unwrap();
            assert!(error().contains("aa3_dr.mat: not a regular file"), "{}", error());
        }
    }
    std::fs::remove_dir_all(&d).ok();
}
