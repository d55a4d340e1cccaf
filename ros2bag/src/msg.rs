//! ROS 2 message types, their `.msg` definitions, and their CDR encoding.
//!
//! Each struct mirrors one ROS 2 (Humble/Jazzy) message field for field, in the same order,
//! because CDR is positional: the bytes are only meaningful against the exact definition.
//! The `.msg` texts below are the official definitions with comments dropped; the fields,
//! types, array bounds and default values are unchanged.

use crate::cdr::CdrWriter;
use crate::error::CdrError;
use crate::time::Time;

/// One `.msg` definition and the definitions it refers to.
///
/// This is what goes into the MCAP schema record (encoding `ros2msg`), so that readers with no
/// ROS installation (Foxglove, `rosbags`, `mcap-ros2-support`) can decode the messages.
#[derive(Debug)]
pub struct MsgDef {
    /// `package/Type`, the name used after `MSG:` in a concatenated definition.
    pub name: &'static str,
    /// The `.msg` file text.
    pub text: &'static str,
    /// The type's RIHS01 hash (REP 2011), which Jazzy and later record as
    /// `type_description_hash`; empty when unknown. It covers field names, types and order,
    /// so a reader that checks it (as `rosbags` does) catches a definition that drifted.
    pub type_hash: &'static str,
    /// Every message type a field of `text` names, each once.
    pub deps: &'static [&'static MsgDef],
}

/// The line that separates concatenated definitions in the `ros2msg` schema encoding.
const DELIMITER: &str = "================================================================================\n";

impl MsgDef {
    /// The complete definition in rosbag2's `ros2msg` encoding: this type's text, then each
    /// dependency once, depth first, each preceded by 80 `=` and a `MSG: package/Type` line.
    ///
    /// Dependencies are visited in name order, as rosbag2 does (it keeps them in a
    /// `std::set`), so the text matches what `ros2 bag record` stores for the same type.
    pub fn full_text(&'static self) -> String {
        let mut out = String::new();
        let mut seen: Vec<&'static str> = Vec::new();
        Self::append(self, &mut out, &mut seen);
        out
    }

    fn append(def: &'static MsgDef, out: &mut String, seen: &mut Vec<&'static str>) {
        out.push_str(def.text);
        let mut deps: Vec<&'static MsgDef> = def.deps.to_vec();
        deps.sort_by_key(|d| d.name);
        for dep in deps {
            if seen.contains(&dep.name) {
                continue;
            }
            seen.push(dep.name);
            out.push('\n');
            out.push_str(DELIMITER);
            out.push_str("MSG: ");
            out.push_str(dep.name);
            out.push('\n');
            Self::append(dep, out, seen);
        }
    }
}

/// A ROS 2 message this crate can write to a bag.
///
/// Implement it for further message types by writing out their `.msg` text in a [`MsgDef`]
/// and encoding the fields in definition order with [`CdrWriter`].
pub trait RosMessage {
    /// The full ROS 2 type name, e.g. `sensor_msgs/msg/LaserScan`, as stored in
    /// `metadata.yaml` and as the MCAP schema name.
    const TYPE_NAME: &'static str;
    /// The `.msg` definition and its dependencies.
    const DEFINITION: &'static MsgDef;

    /// Appends the fields, in definition order, to `w`.
    fn encode(&self, w: &mut CdrWriter) -> Result<(), CdrError>;

    /// The complete `ros2msg` schema text (see [`MsgDef::full_text`]).
    fn schema_text() -> String {
        Self::DEFINITION.full_text()
    }

    /// The message as a complete CDR payload, encapsulation header included.
    fn to_cdr(&self) -> Result<Vec<u8>, CdrError> {
        let mut w = CdrWriter::new();
        self.encode(&mut w)?;
        Ok(w.into_bytes())
    }
}

/// `.msg` definitions, as in the ROS 2 Humble/Jazzy packages (comments dropped).
///
/// The type hashes are those of ROS 2 Jazzy (unchanged in Kilted), computed over these
/// definitions with `rosbags`' REP 2011 implementation; they match the values other ROS 2
/// bridges hard-code, and `tests/check_with_rosbags.py` re-checks them.
pub mod defs {
    use super::MsgDef;

    pub static TIME: MsgDef = MsgDef {
        name: "builtin_interfaces/Time",
        type_hash: "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197",
        text: "int32 sec\nuint32 nanosec\n",
        deps: &[],
    };
    pub static HEADER: MsgDef = MsgDef {
        name: "std_msgs/Header",
        type_hash: "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01",
        text: "builtin_interfaces/Time stamp\nstring frame_id\n",
        deps: &[&TIME],
    };
    pub static VECTOR3: MsgDef = MsgDef {
        name: "geometry_msgs/Vector3",
        type_hash: "RIHS01_cc12fe83e4c02719f1ce8070bfd14aecd40f75a96696a67a2a1f37f7dbb0765d",
        text: "float64 x\nfloat64 y\nfloat64 z\n",
        deps: &[],
    };
    pub static POINT: MsgDef = MsgDef {
        name: "geometry_msgs/Point",
        type_hash: "RIHS01_6963084842a9b04494d6b2941d11444708d892da2f4b09843b9c43f42a7f6881",
        text: "float64 x\nfloat64 y\nfloat64 z\n",
        deps: &[],
    };
    pub static QUATERNION: MsgDef = MsgDef {
        name: "geometry_msgs/Quaternion",
        type_hash: "RIHS01_8a765f66778c8ff7c8ab94afcc590a2ed5325a1d9a076ffff38fbce36f458684",
        text: "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
        deps: &[],
    };
    pub static POSE: MsgDef = MsgDef {
        name: "geometry_msgs/Pose",
        type_hash: "RIHS01_d501954e9476cea2996984e812054b68026ae0bfae789d9a10b23daf35cc90fa",
        text: "Point position\nQuaternion orientation\n",
        deps: &[&POINT, &QUATERNION],
    };
    pub static POSE_WITH_COVARIANCE: MsgDef = MsgDef {
        name: "geometry_msgs/PoseWithCovariance",
        type_hash: "RIHS01_9a7c0fd234b7f45c6098745ecccd773ca1085670e64107135397aee31c02e1bb",
        text: "Pose pose\nfloat64[36] covariance\n",
        deps: &[&POSE],
    };
    pub static POSE_STAMPED: MsgDef = MsgDef {
        name: "geometry_msgs/PoseStamped",
        type_hash: "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
        text: "std_msgs/Header header\nPose pose\n",
        deps: &[&POSE, &HEADER],
    };
    pub static TWIST: MsgDef = MsgDef {
        name: "geometry_msgs/Twist",
        type_hash: "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
        text: "Vector3  linear\nVector3  angular\n",
        deps: &[&VECTOR3],
    };
    pub static TWIST_WITH_COVARIANCE: MsgDef = MsgDef {
        name: "geometry_msgs/TwistWithCovariance",
        type_hash: "RIHS01_49f574f033f095d8b6cd1beaca5ca7925e296e84af1716d16c89d38b059c8c18",
        text: "Twist twist\nfloat64[36] covariance\n",
        deps: &[&TWIST],
    };
    pub static TRANSFORM: MsgDef = MsgDef {
        name: "geometry_msgs/Transform",
        type_hash: "RIHS01_beb83fbe698636351461f6f35d1abb20010c43d55374d81bd041f1ba2581fddc",
        text: "Vector3 translation\nQuaternion rotation\n",
        deps: &[&QUATERNION, &VECTOR3],
    };
    pub static TRANSFORM_STAMPED: MsgDef = MsgDef {
        name: "geometry_msgs/TransformStamped",
        type_hash: "RIHS01_0a241f87d04668d94099cbb5ba11691d5ad32c2f29682e4eb5653424bd275206",
        text: "std_msgs/Header header\nstring child_frame_id\nTransform transform\n",
        deps: &[&TRANSFORM, &HEADER],
    };
    pub static ODOMETRY: MsgDef = MsgDef {
        name: "nav_msgs/Odometry",
        type_hash: "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
        text: "std_msgs/Header header\nstring child_frame_id\n\
               geometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n",
        deps: &[&POSE_WITH_COVARIANCE, &TWIST_WITH_COVARIANCE, &HEADER],
    };
    pub static PATH: MsgDef = MsgDef {
        name: "nav_msgs/Path",
        type_hash: "RIHS01_1957a5bb3cee5da65c4e52e52b65a93df227efce4c20f8458b36e73066ca334b",
        text: "std_msgs/Header header\ngeometry_msgs/PoseStamped[] poses\n",
        deps: &[&POSE_STAMPED, &HEADER],
    };
    pub static LASER_SCAN: MsgDef = MsgDef {
        name: "sensor_msgs/LaserScan",
        type_hash: "RIHS01_64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828",
        text: "std_msgs/Header header\n\
               float32 angle_min\nfloat32 angle_max\nfloat32 angle_increment\n\
               float32 time_increment\nfloat32 scan_time\n\
               float32 range_min\nfloat32 range_max\n\
               float32[] ranges\nfloat32[] intensities\n",
        deps: &[&HEADER],
    };
    pub static IMAGE: MsgDef = MsgDef {
        name: "sensor_msgs/Image",
        type_hash: "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47",
        text: "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n\
               uint8 is_bigendian\nuint32 step\nuint8[] data\n",
        deps: &[&HEADER],
    };
    pub static REGION_OF_INTEREST: MsgDef = MsgDef {
        name: "sensor_msgs/RegionOfInterest",
        type_hash: "RIHS01_ad16bcba5f9131dcdba6fbded19f726f5440e3c513b4fb586dd3027eeed8abb1",
        text: "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n",
        deps: &[],
    };
    pub static CAMERA_INFO: MsgDef = MsgDef {
        name: "sensor_msgs/CameraInfo",
        type_hash: "RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275",
        text: "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n\
               float64[] d\nfloat64[9]  k\nfloat64[9]  r\nfloat64[12] p\n\
               uint32 binning_x\nuint32 binning_y\nRegionOfInterest roi\n",
        deps: &[&REGION_OF_INTEREST, &HEADER],
    };
    pub static TF_MESSAGE: MsgDef = MsgDef {
        name: "tf2_msgs/TFMessage",
        type_hash: "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
        text: "geometry_msgs/TransformStamped[] transforms\n",
        deps: &[&TRANSFORM_STAMPED],
    };

    /// Every definition above, for tests and tooling.
    pub static ALL: &[&MsgDef] = &[
        &TIME,
        &HEADER,
        &VECTOR3,
        &POINT,
        &QUATERNION,
        &POSE,
        &POSE_WITH_COVARIANCE,
        &POSE_STAMPED,
        &TWIST,
        &TWIST_WITH_COVARIANCE,
        &TRANSFORM,
        &TRANSFORM_STAMPED,
        &ODOMETRY,
        &PATH,
        &LASER_SCAN,
        &IMAGE,
        &REGION_OF_INTEREST,
        &CAMERA_INFO,
        &TF_MESSAGE,
    ];
}

/// Implements [`RosMessage`] with the listed fields encoded in order.
macro_rules! ros_message {
    ($ty:ty, $name:literal, $def:expr, |$s:ident, $w:ident| $body:block) => {
        impl RosMessage for $ty {
            const TYPE_NAME: &'static str = $name;
            const DEFINITION: &'static MsgDef = &$def;
            fn encode(&self, $w: &mut CdrWriter) -> Result<(), CdrError> {
                let $s = self;
                $body
                Ok(())
            }
        }
    };
}

ros_message!(Time, "builtin_interfaces/msg/Time", defs::TIME, |s, w| {
    w.i32(s.sec);
    w.u32(s.nanosec);
});

/// `std_msgs/msg/Header`: when and in which frame a message's data was taken.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

impl Header {
    pub fn new(stamp: Time, frame_id: impl Into<String>) -> Self {
        Self { stamp, frame_id: frame_id.into() }
    }
}

ros_message!(Header, "std_msgs/msg/Header", defs::HEADER, |s, w| {
    s.stamp.encode(w)?;
    w.string(&s.frame_id)?;
});

/// `geometry_msgs/msg/Vector3`: a free vector (velocities, translations).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

ros_message!(Vector3, "geometry_msgs/msg/Vector3", defs::VECTOR3, |s, w| {
    w.f64(s.x);
    w.f64(s.y);
    w.f64(s.z);
});

/// `geometry_msgs/msg/Point`: a position.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Point {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

ros_message!(Point, "geometry_msgs/msg/Point", defs::POINT, |s, w| {
    w.f64(s.x);
    w.f64(s.y);
    w.f64(s.z);
});

/// `geometry_msgs/msg/Quaternion`, (x, y, z, w). The default is the identity rotation, as in
/// ROS 2 (`float64 w 1`), not the all-zero non-rotation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

impl Default for Quaternion {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Quaternion {
    pub const IDENTITY: Self = Self { x: 0.0, y: 0.0, z: 0.0, w: 1.0 };

    /// A rotation of `yaw` radians about +z, the only rotation a planar robot has.
    pub fn from_yaw(yaw: f64) -> Self {
        let (s, c) = (yaw / 2.0).sin_cos();
        Self { x: 0.0, y: 0.0, z: s, w: c }
    }
}

ros_message!(Quaternion, "geometry_msgs/msg/Quaternion", defs::QUATERNION, |s, w| {
    w.f64(s.x);
    w.f64(s.y);
    w.f64(s.z);
    w.f64(s.w);
});

/// `geometry_msgs/msg/Pose`: position and orientation.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Pose {
    pub position: Point,
    pub orientation: Quaternion,
}

ros_message!(Pose, "geometry_msgs/msg/Pose", defs::POSE, |s, w| {
    s.position.encode(w)?;
    s.orientation.encode(w)?;
});

/// `geometry_msgs/msg/PoseWithCovariance`: a pose and its 6×6 row-major covariance over
/// (x, y, z, rotation about x, about y, about z).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseWithCovariance {
    pub pose: Pose,
    pub covariance: [f64; 36],
}

impl Default for PoseWithCovariance {
    fn default() -> Self {
        Self { pose: Pose::default(), covariance: [0.0; 36] }
    }
}

ros_message!(PoseWithCovariance, "geometry_msgs/msg/PoseWithCovariance", defs::POSE_WITH_COVARIANCE, |s, w| {
    s.pose.encode(w)?;
    w.f64_array(&s.covariance);
});

/// `geometry_msgs/msg/PoseStamped`: a pose in a frame at a time (ground truth samples).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PoseStamped {
    pub header: Header,
    pub pose: Pose,
}

ros_message!(PoseStamped, "geometry_msgs/msg/PoseStamped", defs::POSE_STAMPED, |s, w| {
    s.header.encode(w)?;
    s.pose.encode(w)?;
});

/// `geometry_msgs/msg/Twist`: linear and angular velocity.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Twist {
    pub linear: Vector3,
    pub angular: Vector3,
}

ros_message!(Twist, "geometry_msgs/msg/Twist", defs::TWIST, |s, w| {
    s.linear.encode(w)?;
    s.angular.encode(w)?;
});

/// `geometry_msgs/msg/TwistWithCovariance`: a twist and its 6×6 row-major covariance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TwistWithCovariance {
    pub twist: Twist,
    pub covariance: [f64; 36],
}

impl Default for TwistWithCovariance {
    fn default() -> Self {
        Self { twist: Twist::default(), covariance: [0.0; 36] }
    }
}

ros_message!(TwistWithCovariance, "geometry_msgs/msg/TwistWithCovariance", defs::TWIST_WITH_COVARIANCE, |s, w| {
    s.twist.encode(w)?;
    w.f64_array(&s.covariance);
});

/// `geometry_msgs/msg/Transform`: a rigid transform, translation then rotation.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Transform {
    pub translation: Vector3,
    pub rotation: Quaternion,
}

ros_message!(Transform, "geometry_msgs/msg/Transform", defs::TRANSFORM, |s, w| {
    s.translation.encode(w)?;
    s.rotation.encode(w)?;
});

/// `geometry_msgs/msg/TransformStamped`: the transform from `header.frame_id` (parent) to
/// `child_frame_id` at `header.stamp`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TransformStamped {
    pub header: Header,
    pub child_frame_id: String,
    pub transform: Transform,
}

ros_message!(TransformStamped, "geometry_msgs/msg/TransformStamped", defs::TRANSFORM_STAMPED, |s, w| {
    s.header.encode(w)?;
    w.string(&s.child_frame_id)?;
    s.transform.encode(w)?;
});

/// `tf2_msgs/msg/TFMessage`: what `/tf` and `/tf_static` carry.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TfMessage {
    pub transforms: Vec<TransformStamped>,
}

ros_message!(TfMessage, "tf2_msgs/msg/TFMessage", defs::TF_MESSAGE, |s, w| {
    w.sequence_len(s.transforms.len())?;
    for t in &s.transforms {
        t.encode(w)?;
    }
});

/// `nav_msgs/msg/Odometry`: pose in `header.frame_id`, twist in `child_frame_id`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Odometry {
    pub header: Header,
    pub child_frame_id: String,
    pub pose: PoseWithCovariance,
    pub twist: TwistWithCovariance,
}

ros_message!(Odometry, "nav_msgs/msg/Odometry", defs::ODOMETRY, |s, w| {
    s.header.encode(w)?;
    w.string(&s.child_frame_id)?;
    s.pose.encode(w)?;
    s.twist.encode(w)?;
});

/// `nav_msgs/msg/Path`: a sequence of poses, e.g. a ground-truth trajectory.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Path {
    pub header: Header,
    pub poses: Vec<PoseStamped>,
}

ros_message!(Path, "nav_msgs/msg/Path", defs::PATH, |s, w| {
    s.header.encode(w)?;
    w.sequence_len(s.poses.len())?;
    for p in &s.poses {
        p.encode(w)?;
    }
});

/// `sensor_msgs/msg/LaserScan`: one planar scan.
///
/// Per REP 117, a beam with no return is `f32::INFINITY` (nothing within `range_max`),
/// `f32::NEG_INFINITY` (too close to measure), or NaN (invalid); these are written as they are.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LaserScan {
    pub header: Header,
    pub angle_min: f32,
    pub angle_max: f32,
    pub angle_increment: f32,
    pub time_increment: f32,
    pub scan_time: f32,
    pub range_min: f32,
    pub range_max: f32,
    pub ranges: Vec<f32>,
    pub intensities: Vec<f32>,
}

ros_message!(LaserScan, "sensor_msgs/msg/LaserScan", defs::LASER_SCAN, |s, w| {
    s.header.encode(w)?;
    w.f32(s.angle_min);
    w.f32(s.angle_max);
    w.f32(s.angle_increment);
    w.f32(s.time_increment);
    w.f32(s.scan_time);
    w.f32(s.range_min);
    w.f32(s.range_max);
    w.f32_seq(&s.ranges)?;
    w.f32_seq(&s.intensities)?;
});

/// `sensor_msgs/msg/Image`: an uncompressed image, rows of `step` bytes.
///
/// Nothing checks that `data.len() == step * height`; ROS 2 does not either, but viewers
/// reject images where it does not hold.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Image {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    /// Pixel encoding, e.g. `rgb8`, `mono8`, `32FC1` (see `sensor_msgs/image_encodings.hpp`).
    pub encoding: String,
    pub is_bigendian: u8,
    /// Row length in bytes.
    pub step: u32,
    pub data: Vec<u8>,
}

ros_message!(Image, "sensor_msgs/msg/Image", defs::IMAGE, |s, w| {
    s.header.encode(w)?;
    w.u32(s.height);
    w.u32(s.width);
    w.string(&s.encoding)?;
    w.u8(s.is_bigendian);
    w.u32(s.step);
    w.u8_seq(&s.data)?;
});

/// `sensor_msgs/msg/RegionOfInterest`: a sub-window of an image; all zero means the full image.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RegionOfInterest {
    pub x_offset: u32,
    pub y_offset: u32,
    pub height: u32,
    pub width: u32,
    pub do_rectify: bool,
}

ros_message!(RegionOfInterest, "sensor_msgs/msg/RegionOfInterest", defs::REGION_OF_INTEREST, |s, w| {
    w.u32(s.x_offset);
    w.u32(s.y_offset);
    w.u32(s.height);
    w.u32(s.width);
    w.bool(s.do_rectify);
});

/// `sensor_msgs/msg/CameraInfo`: pinhole calibration for the images on the sibling topic.
///
/// `k` is the 3×3 intrinsic matrix, `r` the rectification rotation, `p` the 3×4 projection,
/// all row major; `d` holds the distortion coefficients of `distortion_model` (`plumb_bob`:
/// k1, k2, t1, t2, k3).
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfo {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub distortion_model: String,
    pub d: Vec<f64>,
    pub k: [f64; 9],
    pub r: [f64; 9],
    pub p: [f64; 12],
    pub binning_x: u32,
    pub binning_y: u32,
    pub roi: RegionOfInterest,
}

impl Default for CameraInfo {
    fn default() -> Self {
        Self {
            header: Header::default(),
            height: 0,
            width: 0,
            distortion_model: String::new(),
            d: Vec::new(),
            k: [0.0; 9],
            r: [0.0; 9],
            p: [0.0; 12],
            binning_x: 0,
            binning_y: 0,
            roi: RegionOfInterest::default(),
        }
    }
}

impl CameraInfo {
    /// An ideal pinhole camera (no distortion, `plumb_bob` with zero coefficients) with focal
    /// lengths `fx`, `fy` and principal point `cx`, `cy` in pixels, as a simulator renders it.
    pub fn pinhole(header: Header, width: u32, height: u32, fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Self {
            header,
            height,
            width,
            distortion_model: "plumb_bob".to_owned(),
            d: vec![0.0; 5],
            k: [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
            binning_x: 0,
            binning_y: 0,
            roi: RegionOfInterest::default(),
        }
    }
}

ros_message!(CameraInfo, "sensor_msgs/msg/CameraInfo", defs::CAMERA_INFO, |s, w| {
    s.header.encode(w)?;
    w.u32(s.height);
    w.u32(s.width);
    w.string(&s.distortion_model)?;
    w.f64_seq(&s.d)?;
    w.f64_array(&s.k);
    w.f64_array(&s.r);
    w.f64_array(&s.p);
    w.u32(s.binning_x);
    w.u32(s.binning_y);
    s.roi.encode(w)?;
});

#[cfg(test)]
mod tests {
    use super::*;

    const PRIMITIVES: &[&str] = &[
        "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64",
        "uint64", "string",
    ];

    /// The message types a definition's fields name, resolved the way rosbag2 does: a bare
    /// `Type` belongs to the definition's own package.
    fn referenced_types(def: &MsgDef) -> Vec<String> {
        let package = def.name.split('/').next().unwrap();
        let mut out: Vec<String> = def
            .text
            .lines()
            .filter_map(|l| l.split_whitespace().next())
            .filter(|t| !t.starts_with('#'))
            .map(|t| t.split('[').next().unwrap())
            .filter(|t| !PRIMITIVES.contains(t))
            .map(|t| if t.contains('/') { t.to_owned() } else { format!("{package}/{t}") })
            .collect();
        out.sort();
        out.dedup();
        out
    }

    #[test]
    fn declared_dependencies_match_the_field_types() {
        for def in defs::ALL {
            let mut declared: Vec<String> = def.deps.iter().map(|d| d.name.to_owned()).collect();
            declared.sort();
            assert_eq!(declared, referenced_types(def), "{}", def.name);
        }
    }

    #[test]
    fn type_hashes_are_rihs01() {
        for def in defs::ALL {
            let hex = def.type_hash.strip_prefix("RIHS01_").unwrap_or("");
            assert!(hex.len() == 64 && hex.bytes().all(|b| b.is_ascii_hexdigit()), "{}", def.name);
        }
    }

    #[test]
    fn type_names_match_definition_names() {
        fn check<M: RosMessage>() {
            let (pkg, ty) = M::DEFINITION.name.split_once('/').unwrap();
            assert_eq!(M::TYPE_NAME, format!("{pkg}/msg/{ty}"));
        }
        check::<Time>();
        check::<Header>();
        check::<Vector3>();
        check::<Point>();
        check::<Quaternion>();
        check::<Pose>();
        check::<PoseWithCovariance>();
        check::<PoseStamped>();
        check::<Twist>();
        check::<TwistWithCovariance>();
        check::<Transform>();
        check::<TransformStamped>();
        check::<TfMessage>();
        check::<Odometry>();
        check::<Path>();
        check::<LaserScan>();
        check::<Image>();
        check::<RegionOfInterest>();
        check::<CameraInfo>();
    }

    #[test]
    fn full_text_lists_each_dependency_once_depth_first_in_name_order() {
        let text = Odometry::schema_text();
        let sections: Vec<&str> = text.lines().filter_map(|l| l.strip_prefix("MSG: ")).collect();
        assert_eq!(
            sections,
            [
                "geometry_msgs/PoseWithCovariance",
                "geometry_msgs/Pose",
                "geometry_msgs/Point",
                "geometry_msgs/Quaternion",
                "geometry_msgs/TwistWithCovariance",
                "geometry_msgs/Twist",
                "geometry_msgs/Vector3",
                "std_msgs/Header",
                "builtin_interfaces/Time",
            ]
        );
        assert!(text.starts_with("std_msgs/Header header\nstring child_frame_id\n"));
        let delimiter = format!("\n{}\nMSG: std_msgs/Header\n", "=".repeat(80));
        assert!(text.contains(&delimiter));
    }

    #[test]
    fn header_encoding() {
        let h = Header::new(Time { sec: 1, nanosec: 2 }, "a");
        assert_eq!(h.to_cdr().unwrap(), [0, 1, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 2, 0, 0, 0, b'a', 0]);
    }

    #[test]
    fn a_bad_string_anywhere_is_an_error_not_a_panic() {
        let msg = TfMessage {
            transforms: vec![TransformStamped { child_frame_id: "base\0link".into(), ..Default::default() }],
        };
        assert!(matches!(msg.to_cdr(), Err(CdrError::StringContainsNul { .. })));
    }
}
