//! `metadata.yaml`, written by hand in the layout rosbag2 itself emits.
//!
//! rosbag2 (C++) and `rosbags` (Python) both refuse a bag without this file, and read it with
//! strict key lookups, so every key their version-8 readers ask for is present. Version 8 is
//! the newest layout that keeps `offered_qos_profiles` as one YAML string with integer enums,
//! which Humble, Jazzy and `rosbags` all read.

use std::fmt::Write as _;

/// The rosbag2 metadata format version written.
pub const VERSION: u32 = 8;

/// QoS that a topic's publisher offered, as recorded for playback.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TopicQos {
    /// Nothing recorded (`offered_qos_profiles: ''`): players use their defaults, which is
    /// right for ordinary sensor streams.
    #[default]
    Unspecified,
    /// Reliable, transient-local ("latched"), as `tf2_ros::StaticTransformBroadcaster` offers
    /// on `/tf_static`: a player then republishes so that late subscribers still get it.
    TransientLocal,
}

impl TopicQos {
    /// The QoS used when a topic is registered without saying: `/tf_static` is latched in
    /// every ROS 2 system, everything else unspecified.
    pub fn default_for_topic(topic: &str) -> Self {
        if topic == "/tf_static" { Self::TransientLocal } else { Self::Unspecified }
    }

    /// The profile list as rosbag2 (metadata version ≤ 8) serialises it: a YAML document in a
    /// string. The integers are the `rmw_qos_*_policy_t` values (history 3 = unknown, as
    /// recorded from a discovered publisher; reliability 1 = reliable; durability
    /// 1 = transient local; liveliness 1 = automatic) and the durations are
    /// `RMW_DURATION_INFINITE`.
    pub fn offered_profiles_yaml(self) -> String {
        match self {
            Self::Unspecified => String::new(),
            Self::TransientLocal => {
                let inf = "\n    sec: 9223372036\n    nsec: 854775807";
                format!(
                    "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 1\n  \
                     deadline:{inf}\n  lifespan:{inf}\n  liveliness: 1\n  \
                     liveliness_lease_duration:{inf}\n  avoid_ros_namespace_conventions: false"
                )
            }
        }
    }
}

/// One topic's entry in `topics_with_message_count`.
#[derive(Debug, Clone)]
pub(crate) struct TopicInfo<'a> {
    pub name: &'a str,
    pub type_name: &'a str,
    pub type_hash: &'a str,
    pub qos: TopicQos,
    pub message_count: u64,
}

/// What the metadata summarises.
#[derive(Debug, Clone)]
pub(crate) struct BagInfo<'a> {
    pub file_name: &'a str,
    pub starting_time_ns: u64,
    pub duration_ns: u64,
    pub message_count: u64,
    pub topics: Vec<TopicInfo<'a>>,
}

/// The mapping under `rosbag2_bagfile_information`, each line prefixed by `indent`.
///
/// rosbag2 also stores this text, unindented, in the MCAP file's `rosbag2` metadata record, so
/// that `ros2 bag reindex` and MCAP-only tools can rebuild the YAML.
pub(crate) fn bag_information(info: &BagInfo<'_>, indent: &str) -> String {
    let mut s = String::new();
    let i = indent;
    let file = yaml_str(info.file_name);
    // `write!` into a String cannot fail.
    let _ = write!(
        s,
        "{i}version: {VERSION}\n\
         {i}storage_identifier: mcap\n\
         {i}duration:\n{i}  nanoseconds: {dur}\n\
         {i}starting_time:\n{i}  nanoseconds_since_epoch: {start}\n\
         {i}message_count: {count}\n",
        dur = info.duration_ns,
        start = info.starting_time_ns,
        count = info.message_count,
    );
    if info.topics.is_empty() {
        let _ = writeln!(s, "{i}topics_with_message_count: []");
    } else {
        let _ = writeln!(s, "{i}topics_with_message_count:");
        for t in &info.topics {
            let _ = write!(
                s,
                "{i}  - topic_metadata:\n\
                 {i}      name: {name}\n\
                 {i}      type: {ty}\n\
                 {i}      serialization_format: cdr\n\
                 {i}      offered_qos_profiles: {qos}\n\
                 {i}      type_description_hash: {hash}\n\
                 {i}    message_count: {count}\n",
                name = yaml_str(t.name),
                ty = yaml_str(t.type_name),
                qos = yaml_str(&t.qos.offered_profiles_yaml()),
                hash = yaml_str(t.type_hash),
                count = t.message_count,
            );
        }
    }
    let _ = write!(
        s,
        "{i}compression_format: ''\n\
         {i}compression_mode: ''\n\
         {i}relative_file_paths:\n{i}  - {file}\n\
         {i}files:\n\
         {i}  - path: {file}\n\
         {i}    starting_time:\n{i}      nanoseconds_since_epoch: {start}\n\
         {i}    duration:\n{i}      nanoseconds: {dur}\n\
         {i}    message_count: {count}\n\
         {i}custom_data: ~\n\
         {i}ros_distro: ''\n",
        dur = info.duration_ns,
        start = info.starting_time_ns,
        count = info.message_count,
    );
    s
}

/// The whole `metadata.yaml`.
pub(crate) fn metadata_yaml(info: &BagInfo<'_>) -> String {
    format!("rosbag2_bagfile_information:\n{}", bag_information(info, "  "))
}

/// A YAML scalar that reads back as exactly the string `s`.
///
/// Plain when that is unambiguous (topic and type names always are), `''` when empty, and
/// double quoted with escapes otherwise (QoS text with newlines, odd directory names).
fn yaml_str(s: &str) -> String {
    if s.is_empty() {
        return "''".to_owned();
    }
    let safe_first = s.starts_with(|c: char| c.is_ascii_alphabetic() || c == '/' || c == '_');
    let safe_rest = s.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '/' | '_' | '-' | '.'));
    let keyword = matches!(
        s.to_ascii_lowercase().as_str(),
        "true" | "false" | "yes" | "no" | "on" | "off" | "null" | "y" | "n" | ".nan" | ".inf"
    );
    if safe_first && safe_rest && !keyword {
        return s.to_owned();
    }
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\t' => out.push_str("\\t"),
            '\r' => out.push_str("\\r"),
            // Controls, and the characters YAML treats as line breaks or a BOM, would not
            // survive a round trip as themselves.
            c if c.is_control() || matches!(c, '\u{2028}' | '\u{2029}' | '\u{feff}') => {
                let _ = write!(out, "\\u{:04x}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scalars_quote_only_when_needed() {
        assert_eq!(yaml_str("/scan"), "/scan");
        assert_eq!(yaml_str("sensor_msgs/msg/LaserScan"), "sensor_msgs/msg/LaserScan");
        assert_eq!(yaml_str("run-1_0.mcap"), "run-1_0.mcap");
        assert_eq!(yaml_str(""), "''");
        assert_eq!(yaml_str("true"), "\"true\"");
        assert_eq!(yaml_str("1_0.mcap"), "\"1_0.mcap\"");
        assert_eq!(yaml_str("a: b\n\"c\""), "\"a: b\\n\\\"c\\\"\"");
    }

    #[test]
    fn layout_matches_rosbag2() {
        let info = BagInfo {
            file_name: "bag_0.mcap",
            starting_time_ns: 10,
            duration_ns: 5,
            message_count: 2,
            topics: vec![
                TopicInfo {
                    name: "/scan",
                    type_name: "sensor_msgs/msg/LaserScan",
                    type_hash: "RIHS01_64c1",
                    qos: TopicQos::Unspecified,
                    message_count: 1,
                },
                TopicInfo {
                    name: "/tf_static",
                    type_name: "tf2_msgs/msg/TFMessage",
                    type_hash: "",
                    qos: TopicQos::TransientLocal,
                    message_count: 1,
                },
            ],
        };
        let expected = "\
rosbag2_bagfile_information:
  version: 8
  storage_identifier: mcap
  duration:
    nanoseconds: 5
  starting_time:
    nanoseconds_since_epoch: 10
  message_count: 2
  topics_with_message_count:
    - topic_metadata:
        name: /scan
        type: sensor_msgs/msg/LaserScan
        serialization_format: cdr
        offered_qos_profiles: ''
        type_description_hash: RIHS01_64c1
      message_count: 1
    - topic_metadata:
        name: /tf_static
        type: tf2_msgs/msg/TFMessage
        serialization_format: cdr
        offered_qos_profiles: \"- history: 3\\n  depth: 0\\n  reliability: 1\\n  durability: 1\\n  deadline:\\n    sec: 9223372036\\n    nsec: 854775807\\n  lifespan:\\n    sec: 9223372036\\n    nsec: 854775807\\n  liveliness: 1\\n  liveliness_lease_duration:\\n    sec: 9223372036\\n    nsec: 854775807\\n  avoid_ros_namespace_conventions: false\"
        type_description_hash: ''
      message_count: 1
  compression_format: ''
  compression_mode: ''
  relative_file_paths:
    - bag_0.mcap
  files:
    - path: bag_0.mcap
      starting_time:
        nanoseconds_since_epoch: 10
      duration:
        nanoseconds: 5
      message_count: 2
  custom_data: ~
  ros_distro: ''
";
        assert_eq!(metadata_yaml(&info), expected);
    }
}
