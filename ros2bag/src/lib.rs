//! Writes ROS 2 bags (rosbag2, MCAP storage) from plain Rust data, with no ROS installation.
//!
//! A bag is a directory with `metadata.yaml` and one `.mcap` file whose header profile is
//! `ros2`. Each topic is an MCAP channel with message encoding `cdr`; each message type is a
//! schema with encoding `ros2msg` holding the full `.msg` text (the type's definition, then each
//! dependency after a line of 80 `=` and `MSG: pkg/Type`). That is the layout `ros2 bag record`
//! produces, so the result plays with `ros2 bag play` and opens in Foxglove, `rosbags` and
//! `mcap-ros2-support`.
//!
//! The message structs ([`LaserScan`], [`Odometry`], [`Image`], [`CameraInfo`], [`TfMessage`],
//! [`PoseStamped`], [`Path`], and their parts) mirror the ROS 2 Humble/Jazzy definitions field
//! for field; the CDR encoder ([`cdr::CdrWriter`]) is this crate's own, little endian.
//!
//! ```no_run
//! use ros2bag::{BagWriter, Header, LaserScan, Time};
//!
//! # fn main() -> Result<(), ros2bag::Error> {
//! let mut bag = BagWriter::create(std::path::Path::new("runs/park_bag"))?;
//! let t = 1_700_000_000_000_000_000u64; // log time, ns since the epoch
//! let scan = LaserScan {
//!     header: Header::new(Time::from_nanos(t)?, "laser"),
//!     angle_min: -1.5,
//!     angle_max: 1.5,
//!     angle_increment: 1.5,
//!     range_min: 0.1,
//!     range_max: 30.0,
//!     // REP 117: +inf means no return within range_max
//!     ranges: vec![2.0, f32::INFINITY, 3.5],
//!     ..Default::default()
//! };
//! bag.write("/scan", t, &scan)?;
//! bag.finish()?; // closes the MCAP file and writes metadata.yaml
//! # Ok(())
//! # }
//! ```
//!
//! `/tf_static` is registered as transient local (latched), as real systems offer it, so a
//! player republishes it for late subscribers; other topics record no QoS and players use
//! their defaults. Chunks are stored uncompressed.

pub mod cdr;
mod error;
pub mod metadata;
pub mod msg;
mod time;
mod writer;

pub use error::{CdrError, Error, Result};
pub use metadata::TopicQos;
pub use msg::{
    CameraInfo, Header, Image, LaserScan, MsgDef, Odometry, Path, Point, Pose, PoseStamped, PoseWithCovariance,
    Quaternion, RegionOfInterest, RosMessage, TfMessage, Transform, TransformStamped, Twist, TwistWithCovariance,
    Vector3,
};
pub use time::Time;
pub use writer::{BagWriter, METADATA_FILE, validate_topic_name};
