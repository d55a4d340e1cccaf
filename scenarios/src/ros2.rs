//! The simulator's stream as a ROS 2 bag (`objslam record --format ros2`), in the standard
//! messages and frames (REP-105) that ROS tools and other people's SLAM systems consume:
//!
//! - `/scan` (`sensor_msgs/msg/LaserScan`, frame `laser`; no return is +inf, REP-117);
//! - `/odom` (`nav_msgs/msg/Odometry`, `odom` -> `base_link`): the noisy wheel odometry,
//!   integrated from the start pose at the origin of `odom`, with the covariances its
//!   error model gives (`sim::odometry::increment_covariance`, propagated for the pose;
//!   z, roll and pitch unmeasured);
//! - `/tf` (`odom` -> `base_link`, from that odometry) and `/tf_static` (`base_link` ->
//!   `laser`, `base_link` -> `camera_optical` where the camera is on, latched);
//! - `/camera/image_raw` (`sensor_msgs/msg/Image`, `rgb8`) and `/camera/camera_info`;
//! - `/ground_truth/pose` (`geometry_msgs/msg/PoseStamped` in frame `world`) and, at the
//!   end, `/ground_truth/path`: on topics of their own and never on `/tf`, so the truth
//!   cannot leak into a system under test through its inputs.
//!
//! Times are simulated seconds from 0.

use crate::files;
use std::path::{Path, PathBuf};

use ros2bag::{
    BagWriter, CameraInfo, Header, Image, LaserScan, Odometry, PoseStamped, Quaternion, TfMessage, Time, Transform,
    TransformStamped, Vector3,
};
use sim::{SensorEvent, SimConfig};

use crate::partial_files as staging;

/// Errors while writing a bag.
#[derive(Debug, thiserror::Error)]
pub enum Ros2Error {
    /// The bag's directory is named once: by the error where it names a file, else here.
    #[error("ROS 2 bag{}: {source}", if source.path().is_some() { String::new() } else { format!(" {}", dir.display()) })]
    Bag { dir: std::path::PathBuf, source: ros2bag::Error },
    #[error(transparent)]
    Output(#[from] staging::PartialFileError),
    #[error("{}", crate::run::join_errors(.0))]
    Publish(Vec<staging::PartialFileError>),
}

/// A ROS 2 bag recorded into `out`'s unfinished directory, holding `out` against other
/// commands, and moved into `out` only when finished (its MCAP file first, `metadata.yaml`
/// last, which is what tells a reader the bag is whole). A bag is written once, so `out`
/// must be new or empty, apart from the unfinished files of a recording that was stopped,
/// which are cleared. One dropped unfinished (a failed run or recording) removes its files,
/// so no half bag blocks the directory.
pub struct StagedBag {
    recorder: Option<Ros2Recorder>,
    lock: Option<staging::OutputLock>,
    out: PathBuf,
    stem: String,
}

/// Refuses a bag directory no bag can be written into: a file, or a directory that holds
/// anything but a stopped recording's unfinished files. A command checks it before it sets
/// anything up, and again once it holds the directory.
pub fn check_bag_dir(out: &Path) -> Result<(), Ros2Error> {
    let bag = |source| Err(Ros2Error::Bag { dir: out.into(), source });
    match std::fs::metadata(out) {
        Err(_) => return Ok(()),
        Ok(m) if !m.is_dir() => return bag(ros2bag::Error::NotADirectory { path: out.into() }),
        Ok(_) => {}
    }
    staging::check_no_other_stopped_move(out, &[])?;
    let unfinished = staging::unfinished_dir(out);
    let listed = std::fs::read_dir(out).map_err(|source| staging::PartialFileError { file: out.into(), source })?;
    if listed.flatten().any(|e| e.path() != unfinished && e.file_name() != ".objslam.lock") {
        return bag(ros2bag::Error::DirectoryNotEmpty { path: out.into() });
    }
    Ok(())
}

impl StagedBag {
    pub fn create(out: &Path, config: &SimConfig) -> Result<Self, Ros2Error> {
        check_bag_dir(out)?;
        let lock = staging::lock_output(out)?;
        check_bag_dir(out)?;
        let stem = out
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .filter(|n| !n.is_empty())
            .unwrap_or_else(|| "rosbag2".to_owned());
        let mut staged = StagedBag { recorder: None, lock: Some(lock), out: out.to_path_buf(), stem };
        let dir = staging::start_unfinished(out)?;
        staged.recorder = Some(Ros2Recorder::create_named(&dir, &staged.stem, config)?);
        Ok(staged)
    }

    /// Attaches how the bag was made (see [`crate::record::provenance`]) and its world, as
    /// MCAP attachments `recording.json` and `world.toml` (`mcap list attachments` lists
    /// them; ROS 2 players pass over them).
    pub fn attach_provenance(
        &mut self,
        provenance: &serde_json::Value,
        world: &worlds::World,
    ) -> Result<(), Ros2Error> {
        let recorder = self.recorder.as_mut().expect("a staged bag has its recorder until finished");
        let err = |source| Ros2Error::Bag { dir: recorder.dir.clone(), source };
        let json = serde_json::to_string_pretty(provenance).expect("JSON");
        recorder.bag.attach(files::RECORDING, "application/json", json.as_bytes()).map_err(err)?;
        recorder.bag.attach(files::WORLD, "application/toml", world.to_toml().as_bytes()).map_err(err)
    }

    /// Writes one simulator event to the bag.
    pub fn write(&mut self, event: &SensorEvent) -> Result<(), Ros2Error> {
        self.recorder.as_mut().expect("a staged bag has its recorder until finished").write(event)
    }

    /// Closes the bag and moves it into its directory.
    pub fn finish(mut self) -> Result<(), Ros2Error> {
        self.recorder.take().expect("a staged bag has its recorder until finished").finish()?;
        // Closed whole: from here a failure to move a file in keeps what was not moved.
        let _lock = self.lock.take();
        // metadata.yaml is the marker: moved in after the MCAP file it describes.
        staging::publish(&staging::unfinished_dir(&self.out), &self.out, &[], ros2bag::METADATA_FILE)
            .map_err(Ros2Error::Publish)
    }
}

impl Drop for StagedBag {
    fn drop(&mut self) {
        // Not finished (or failing to move in): the recording failed, and leaves nothing.
        if let Some(lock) = self.lock.take() {
            let _ = std::fs::remove_dir_all(staging::unfinished_dir(&self.out));
            lock.release_failed();
        }
    }
}

/// The wheel odometry integrated in the `odom` frame, with its covariance.
struct OdomTrack {
    /// x, y, theta.
    pose: [f64; 3],
    covariance: [[f64; 3]; 3],
    config: sim::config::OdometryConfig,
    last_t: Option<f64>,
}

impl OdomTrack {
    fn new(config: &sim::config::OdometryConfig) -> Self {
        OdomTrack { pose: [0.0; 3], covariance: [[0.0; 3]; 3], config: config.clone(), last_t: None }
    }

    /// The `/odom` message after increment `o`: the pose integrated with its covariance
    /// propagated, and the velocity over the time since the previous increment with the
    /// increment's covariance over that time squared (unknown, before there is one).
    fn message(&mut self, o: &sim::Odometry) -> Result<Odometry, ros2bag::Error> {
        let q = sim::odometry::increment_covariance(&self.config, o.dx, o.dy, o.dtheta);
        self.covariance = sim::odometry::propagate_pose_covariance(&self.covariance, self.pose[2], (o.dx, o.dy), &q);
        self.pose = crate::record::integrate_odometry(self.pose, o);
        let dt = self.last_t.map(|p| o.t - p).filter(|d| *d > 0.0);
        self.last_t = Some(o.t);
        let [x, y, th] = self.pose;
        let mut odom = Odometry {
            header: Header::new(stamp(o.t)?, "odom"),
            child_frame_id: "base_link".into(),
            ..Default::default()
        };
        odom.pose.pose = planar_pose(x, y, th);
        odom.pose.covariance = planar_covariance(&self.covariance, 1.0);
        match dt {
            Some(dt) => {
                odom.twist.twist.linear = Vector3 { x: o.dx / dt, y: o.dy / dt, z: 0.0 };
                odom.twist.twist.angular = Vector3 { x: 0.0, y: 0.0, z: o.dtheta / dt };
                odom.twist.covariance = planar_covariance(&q, 1.0 / (dt * dt));
            }
            None => (0..6).for_each(|k| odom.twist.covariance[7 * k] = UNMEASURED_VARIANCE),
        }
        Ok(odom)
    }
}

/// Writes a simulation's events to a ROS 2 bag.
pub struct Ros2Recorder {
    bag: BagWriter,
    dir: std::path::PathBuf,
    odom: OdomTrack,
    static_written: bool,
    base_from_laser: Transform,
    /// `None` where the camera is off.
    base_from_camera: Option<Transform>,
    truth_path: Vec<PoseStamped>,
}

/// A rotation matrix (row-major) as a unit quaternion.
fn quaternion(r: &[[f64; 3]; 3]) -> Quaternion {
    let [x, y, z, w] = crate::record::rotation_quaternion(r);
    Quaternion { x, y, z, w }
}

fn stamp(t: f64) -> Result<Time, ros2bag::Error> {
    Time::from_seconds(t)
}

fn nanos(t: f64) -> u64 {
    (t.max(0.0) * 1e9).round() as u64
}

/// Variance given to z, roll and pitch, which planar odometry does not measure (the large
/// value ROS drivers of planar robots give them, so that fusing nodes ignore them).
pub const UNMEASURED_VARIANCE: f64 = 1e6;

/// A 6x6 row-major ROS covariance (x, y, z, roll, pitch, yaw) from a planar one over
/// (x, y, yaw) times `scale`, with [`UNMEASURED_VARIANCE`] for the rest.
fn planar_covariance(c: &[[f64; 3]; 3], scale: f64) -> [f64; 36] {
    let mut out = [0.0; 36];
    let at = [0, 1, 5];
    for (i, &r) in at.iter().enumerate() {
        for (j, &k) in at.iter().enumerate() {
            out[6 * r + k] = c[i][j] * scale;
        }
    }
    for k in [2, 3, 4] {
        out[6 * k + k] = UNMEASURED_VARIANCE;
    }
    out
}

fn planar_pose(x: f64, y: f64, theta: f64) -> ros2bag::Pose {
    ros2bag::Pose { position: ros2bag::Point { x, y, z: 0.0 }, orientation: Quaternion::from_yaw(theta) }
}

impl Ros2Recorder {
    /// Starts a bag in `dir` (which must be empty or absent) for a simulator with `config`,
    /// its MCAP file named `<stem>_0.mcap` (a bag staged elsewhere before it moves to a
    /// directory named `stem`; see [`StagedBag`]).
    pub fn create_named(dir: &Path, stem: &str, config: &SimConfig) -> Result<Self, Ros2Error> {
        let err = |source| Ros2Error::Bag { dir: dir.to_path_buf(), source };
        Self::with_writer(dir, BagWriter::create_named(dir, stem).map_err(err)?, config)
    }

    fn with_writer(dir: &Path, bag: BagWriter, config: &SimConfig) -> Result<Self, Ros2Error> {
        let [lx, ly, lz] = config.laser.mount_xyz_m;
        let base_from_laser = Transform {
            translation: Vector3 { x: lx, y: ly, z: lz },
            rotation: Quaternion::from_yaw(config.laser.mount_yaw_deg.to_radians()),
        };
        // A frame for a camera that records nothing would tell tools there is one.
        let base_from_camera = config.camera.enabled.then(|| {
            let c = config.camera.base_from_camera();
            Transform { translation: Vector3 { x: c.t[0], y: c.t[1], z: c.t[2] }, rotation: quaternion(&c.r) }
        });
        Ok(Ros2Recorder {
            bag,
            dir: dir.to_path_buf(),
            odom: OdomTrack::new(&config.odometry),
            static_written: false,
            base_from_laser,
            base_from_camera,
            truth_path: Vec::new(),
        })
    }

    fn err(&self) -> impl Fn(ros2bag::Error) -> Ros2Error + '_ {
        |source| Ros2Error::Bag { dir: self.dir.clone(), source }
    }

    /// Writes one simulator event.
    pub fn write(&mut self, event: &SensorEvent) -> Result<(), Ros2Error> {
        self.write_inner(event).map_err(self.err())
    }

    fn write_inner(&mut self, event: &SensorEvent) -> Result<(), ros2bag::Error> {
        let t = event.time();
        if !self.static_written {
            self.static_written = true;
            let header = Header::new(stamp(t)?, "base_link");
            let camera = self.base_from_camera.map(|c| ("camera_optical", c));
            let transforms = std::iter::once(("laser", self.base_from_laser))
                .chain(camera)
                .map(|(child, transform)| TransformStamped {
                    header: header.clone(),
                    child_frame_id: child.into(),
                    transform,
                })
                .collect();
            self.bag.write("/tf_static", nanos(t), &TfMessage { transforms })?;
        }
        match event {
            SensorEvent::Odometry { odometry: o, truth } => {
                let odom = self.odom.message(o)?;
                self.bag.write("/odom", nanos(o.t), &odom)?;
                let p = odom.pose.pose;
                let tf = TransformStamped {
                    header: odom.header,
                    child_frame_id: "base_link".into(),
                    transform: Transform {
                        translation: Vector3 { x: p.position.x, y: p.position.y, z: 0.0 },
                        rotation: p.orientation,
                    },
                };
                self.bag.write("/tf", nanos(o.t), &TfMessage { transforms: vec![tf] })?;
                let r = truth.robot;
                let truth_pose =
                    PoseStamped { header: Header::new(stamp(o.t)?, "world"), pose: planar_pose(r.x, r.y, r.theta) };
                self.bag.write("/ground_truth/pose", nanos(o.t), &truth_pose)?;
                self.truth_path.push(truth_pose);
            }
            SensorEvent::Laser { scan, .. } => {
                let n = scan.ranges.len();
                let msg = LaserScan {
                    header: Header::new(stamp(scan.t)?, "laser"),
                    angle_min: scan.angle_min as f32,
                    angle_max: (scan.angle_min + scan.angle_increment * n.saturating_sub(1) as f64) as f32,
                    angle_increment: scan.angle_increment as f32,
                    time_increment: scan.time_increment as f32,
                    scan_time: scan.scan_time as f32,
                    range_min: scan.range_min as f32,
                    range_max: scan.range_max as f32,
                    // REP-117: no return within range_max is +inf, one too close to measure -inf.
                    ranges: scan
                        .ranges
                        .iter()
                        .map(|&r| {
                            if r.is_finite() {
                                r as f32
                            } else if r < 0.0 {
                                f32::NEG_INFINITY
                            } else {
                                f32::INFINITY
                            }
                        })
                        .collect(),
                    intensities: Vec::new(),
                };
                self.bag.write("/scan", nanos(scan.t), &msg)?;
            }
            SensorEvent::Camera { frame, .. } => {
                let img = &frame.image;
                let header = Header::new(stamp(frame.t)?, "camera_optical");
                let image = Image {
                    header: header.clone(),
                    height: img.height,
                    width: img.width,
                    encoding: "rgb8".into(),
                    is_bigendian: 0,
                    step: 3 * img.width,
                    data: img.rgb.clone(),
                };
                self.bag.write("/camera/image_raw", nanos(frame.t), &image)?;
                let k = frame.intrinsics;
                // ROS puts pixel centres at whole coordinates.
                let (cx, cy) = k.principal_point_ros();
                self.bag.write(
                    "/camera/camera_info",
                    nanos(frame.t),
                    &CameraInfo::pinhole(header, k.width, k.height, k.fx, k.fy, cx, cy),
                )?;
            }
        }
        Ok(())
    }

    /// Writes the ground-truth path and closes the bag (its `metadata.yaml` is written
    /// last: a bag without one was not finished).
    pub fn finish(mut self) -> Result<(), Ros2Error> {
        let err = |source| Ros2Error::Bag { dir: self.dir.clone(), source };
        if let Some(last) = self.truth_path.last() {
            let t = last.header.stamp;
            let path = ros2bag::Path { header: Header::new(t, "world"), poses: std::mem::take(&mut self.truth_path) };
            self.bag.write("/ground_truth/path", t.as_nanos().max(0) as u64, &path).map_err(err)?;
        }
        self.bag.finish().map_err(err)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `/odom` carries the error model's covariances: the pose's growing as the robot
    /// drives, the velocity's that of one increment over its time, z, roll and pitch
    /// unmeasured, and an unknown velocity before the second increment.
    #[test]
    fn odometry_messages_carry_the_error_models_covariances() {
        let config = sim::config::OdometryConfig::default();
        let mut track = OdomTrack::new(&config);
        let step = |k: usize| sim::Odometry { t: 0.05 * k as f64, dx: 0.04, dy: 0.0, dtheta: 0.01 };
        let first = track.message(&step(0)).unwrap();
        assert_eq!(first.twist.covariance[0], UNMEASURED_VARIANCE, "no velocity before a second increment");
        let mut variances = vec![first.pose.covariance[0]];
        let mut last = first;
        for k in 1..40 {
            last = track.message(&step(k)).unwrap();
            variances.push(last.pose.covariance[0]);
        }
        assert!(variances.windows(2).all(|w| w[1] > w[0]), "the pose's x variance grows: {variances:?}");
        let c = &last.pose.covariance;
        assert!(c[7] > 0.0 && c[35] > 0.0, "y and yaw: {c:?}");
        assert_eq!([c[14], c[21], c[28]], [UNMEASURED_VARIANCE; 3]);
        assert!((0..6).all(|i| (0..6).all(|j| c[6 * i + j] == c[6 * j + i])), "symmetric");
        let q = sim::odometry::increment_covariance(&config, 0.04, 0.0, 0.01);
        let t = &last.twist.covariance;
        assert!((t[0] - q[0][0] / 0.0025).abs() < 1e-12 * t[0] && (t[35] - q[2][2] / 0.0025).abs() < 1e-12 * t[35]);
        assert_eq!(t[14], UNMEASURED_VARIANCE);
    }
}
