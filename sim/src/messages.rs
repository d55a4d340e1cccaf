//! The simulator's output: time-ordered sensor messages, each with the ground truth of its
//! instant beside it (never inside it: a SLAM system sees only the sensor part).

use serde::{Deserialize, Serialize};

/// A planar pose in the world frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose2D {
    pub x: f64,
    pub y: f64,
    pub theta: f64,
}

impl Pose2D {
    /// Expresses `other` in this pose's frame: (dx, dy, dtheta).
    pub fn between(&self, other: &Pose2D) -> (f64, f64, f64) {
        let (s, c) = self.theta.sin_cos();
        let (dx, dy) = (other.x - self.x, other.y - self.y);
        (c * dx + s * dy, -s * dx + c * dy, wrap_angle(other.theta - self.theta))
    }

    /// Composes an increment expressed in this pose's frame.
    pub fn compose(&self, dx: f64, dy: f64, dtheta: f64) -> Pose2D {
        let (s, c) = self.theta.sin_cos();
        Pose2D { x: self.x + c * dx - s * dy, y: self.y + s * dx + c * dy, theta: wrap_angle(self.theta + dtheta) }
    }
}

/// Wraps an angle to (-pi, pi].
pub fn wrap_angle(a: f64) -> f64 {
    let mut a = a.rem_euclid(std::f64::consts::TAU);
    if a > std::f64::consts::PI {
        a -= std::f64::consts::TAU;
    }
    a
}

/// Incremental wheel odometry since the previous message, in the robot frame at the
/// previous message (x forward, y left).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Odometry {
    pub t: f64,
    pub dx: f64,
    pub dy: f64,
    pub dtheta: f64,
}

/// One laser scan, like ROS `sensor_msgs/LaserScan`. `ranges[i]` is measured along
/// `angle_min + i * angle_increment` in the laser frame; no return is `f64::INFINITY`
/// (written as `null` in JSON).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LaserScan {
    pub t: f64,
    pub angle_min: f64,
    pub angle_increment: f64,
    /// Time between beams; the simulator scans instantaneously, so 0.
    pub time_increment: f64,
    pub scan_time: f64,
    pub range_min: f64,
    pub range_max: f64,
    #[serde(with = "ranges_json")]
    pub ranges: Vec<f64>,
}

/// What each beam of a scan really hit (scoring only).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LaserTruth {
    /// Instance id hit by each beam (0: nothing within range).
    pub hit_ids: Vec<u16>,
    /// Noise-free range of each beam (`INFINITY` when nothing was hit).
    #[serde(with = "ranges_json")]
    pub true_ranges: Vec<f64>,
}

/// Ground truth at one instant.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroundTruth {
    pub t: f64,
    pub robot: Pose2D,
    /// (instance id, position, heading) of every person.
    pub people: Vec<PersonState>,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PersonState {
    pub id: u16,
    pub x: f64,
    pub y: f64,
    pub heading: f64,
    /// Swing angle of the left leg (rad, positive forward); the right leg is opposite.
    pub leg_swing: f64,
}

/// A contact between the robot and something, recorded when it begins.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Collision {
    pub t: f64,
    pub instance_id: u16,
    pub robot: Pose2D,
}

/// One message of the sensor stream.
#[derive(Debug, Clone, PartialEq)]
pub enum SensorEvent {
    Odometry {
        odometry: Odometry,
        truth: GroundTruth,
    },
    Laser {
        scan: LaserScan,
        beams: LaserTruth,
        truth: GroundTruth,
    },
    /// A camera frame; its instance, class and depth images are ground truth.
    Camera {
        frame: Box<crate::camera::CameraFrame>,
        truth: GroundTruth,
    },
}

impl SensorEvent {
    pub fn time(&self) -> f64 {
        match self {
            SensorEvent::Odometry { odometry, .. } => odometry.t,
            SensorEvent::Laser { scan, .. } => scan.t,
            SensorEvent::Camera { frame, .. } => frame.t,
        }
    }

    pub fn truth(&self) -> &GroundTruth {
        match self {
            SensorEvent::Odometry { truth, .. }
            | SensorEvent::Laser { truth, .. }
            | SensorEvent::Camera { truth, .. } => truth,
        }
    }
}

/// JSON has no infinity: a beam with no return (`INFINITY`) is written as `null`, and one
/// too close to measure (`NEG_INFINITY`, REP-117) as the string `"-inf"`, which Python's
/// `float` and NumPy read as minus infinity. Both read back as they were written, so a
/// log's free space stays what the laser saw (a too-close return is in the way).
mod ranges_json {
    use std::fmt;

    use serde::de::{self, SeqAccess, Visitor};
    use serde::{Deserializer, Serializer, ser::SerializeSeq};

    /// How a too-close return is written.
    pub const TOO_CLOSE: &str = "-inf";

    pub fn serialize<S: Serializer>(v: &[f64], s: S) -> Result<S::Ok, S::Error> {
        let mut seq = s.serialize_seq(Some(v.len()))?;
        for r in v {
            if r.is_finite() {
                seq.serialize_element(r)?
            } else if *r == f64::NEG_INFINITY {
                seq.serialize_element(TOO_CLOSE)?
            } else {
                seq.serialize_element(&None::<f64>)?
            }
        }
        seq.end()
    }

    /// One range: a number, `null` or `"-inf"`.
    struct Range(f64);

    impl<'de> serde::Deserialize<'de> for Range {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            struct RangeVisitor;
            impl<'de> Visitor<'de> for RangeVisitor {
                type Value = Range;
                fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                    write!(f, "a range in metres, null (no return) or \"{TOO_CLOSE}\" (a return too close to measure)")
                }
                fn visit_f64<E: de::Error>(self, v: f64) -> Result<Range, E> {
                    Ok(Range(v))
                }
                fn visit_i64<E: de::Error>(self, v: i64) -> Result<Range, E> {
                    Ok(Range(v as f64))
                }
                fn visit_u64<E: de::Error>(self, v: u64) -> Result<Range, E> {
                    Ok(Range(v as f64))
                }
                fn visit_unit<E: de::Error>(self) -> Result<Range, E> {
                    Ok(Range(f64::INFINITY))
                }
                fn visit_none<E: de::Error>(self) -> Result<Range, E> {
                    Ok(Range(f64::INFINITY))
                }
                fn visit_str<E: de::Error>(self, v: &str) -> Result<Range, E> {
                    if v == TOO_CLOSE {
                        Ok(Range(f64::NEG_INFINITY))
                    } else {
                        Err(E::invalid_value(de::Unexpected::Str(v), &self))
                    }
                }
            }
            d.deserialize_any(RangeVisitor)
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
        struct RangesVisitor;
        impl<'de> Visitor<'de> for RangesVisitor {
            type Value = Vec<f64>;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a list of ranges")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Vec<f64>, A::Error> {
                let mut out = Vec::with_capacity(seq.size_hint().unwrap_or(0));
                while let Some(Range(r)) = seq.next_element()? {
                    out.push(r);
                }
                Ok(out)
            }
        }
        d.deserialize_seq(RangesVisitor)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn between_and_compose_are_inverse() {
        let a = Pose2D { x: 1.0, y: -2.0, theta: 2.9 };
        let b = Pose2D { x: -0.5, y: 0.7, theta: -3.0 };
        let (dx, dy, dt) = a.between(&b);
        let c = a.compose(dx, dy, dt);
        assert!((c.x - b.x).abs() < 1e-12 && (c.y - b.y).abs() < 1e-12 && wrap_angle(c.theta - b.theta).abs() < 1e-12);
    }

    #[test]
    fn no_return_and_a_too_close_return_round_trip_apart() {
        let s = LaserScan {
            t: 0.0,
            angle_min: 0.0,
            angle_increment: 0.1,
            time_increment: 0.0,
            scan_time: 0.1,
            range_min: 0.05,
            range_max: 8.0,
            ranges: vec![f64::NEG_INFINITY, 2.5, f64::INFINITY, 3.0],
        };
        let text = serde_json::to_string(&s).unwrap();
        assert!(text.contains(r#""ranges":["-inf",2.5,null,3"#), "{text}");
        let back: LaserScan = serde_json::from_str(&text).unwrap();
        assert_eq!(back, s);
        // Whole numbers read as ranges too.
        let back: LaserScan = serde_json::from_str(&text.replace("2.5", "2")).unwrap();
        assert_eq!(back.ranges[1], 2.0);
    }

    #[test]
    fn a_range_that_is_neither_number_null_nor_too_close_is_refused_by_name() {
        let line = r#"{"t":0,"angle_min":0,"angle_increment":0.1,"time_increment":0,"scan_time":0.1,"range_min":0,"range_max":8,"ranges":[1.0,"inf"]}"#;
        let e = serde_json::from_str::<LaserScan>(line).unwrap_err().to_string();
        assert!(e.contains("\"inf\"") && e.contains("too close"), "{e}");
        let e = serde_json::from_str::<LaserScan>(&line.replace(r#""inf""#, "true")).unwrap_err().to_string();
        assert!(e.contains("null (no return)"), "{e}");
    }
}
