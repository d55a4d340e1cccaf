//! MCAP output with Foxglove's JSON schemas (PointCloud, FrameTransform, PosesInFrame,
//! CompressedImage, CameraCalibration), so recordings open in Foxglove without extra
//! tooling.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use serde_json::{Value, json};

/// Errors writing an MCAP file.
#[derive(Debug, thiserror::Error)]
#[error("{}: cannot write MCAP: {message}", file.display())]
pub struct McapError {
    pub file: PathBuf,
    pub message: String,
}

/// `e`'s words and those of its causes, each not already said: the MCAP writer's own words
/// ("I/O error from writing") leave out why (a full disk).
fn with_causes(e: &dyn std::error::Error) -> String {
    let mut message = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        let said = c.to_string();
        if !message.contains(&said) {
            message = format!("{message}: {said}");
        }
        cause = c.source();
    }
    message
}

/// Writes Foxglove-schema JSON messages to an MCAP file.
pub struct McapWriter {
    writer: mcap::Writer<BufWriter<File>>,
    channels: BTreeMap<String, u16>,
    sequence: u32,
    file: PathBuf,
}

/// A Foxglove `Time`.
pub fn timestamp(t: f64) -> Value {
    let sec = t.floor();
    json!({"sec": sec as u64, "nsec": ((t - sec) * 1e9).round().min(999_999_999.0) as u64})
}

/// Quaternion (x, y, z, w) of a rotation about z.
pub fn yaw_quaternion(yaw: f64) -> [f64; 4] {
    [0.0, 0.0, (yaw / 2.0).sin(), (yaw / 2.0).cos()]
}

pub fn pose_json(x: f64, y: f64, z: f64, q: [f64; 4]) -> Value {
    json!({"position": {"x": x, "y": y, "z": z}, "orientation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]}})
}

/// A laser scan's returns as a Foxglove `PointCloud` in the laser frame: x, y, z and range,
/// each a little-endian f32. Beams without a return are left out: Foxglove's `LaserScan`
/// draws every range it is given (its JSON cannot carry the +inf of "no return"), so a
/// cloud of the returns is what it draws right.
pub fn laser_points_json(scan: &sim::LaserScan) -> Value {
    const FLOAT32: u32 = 7;
    let mut data = Vec::with_capacity(16 * scan.ranges.len());
    for (i, r) in scan.ranges.iter().enumerate().filter(|(_, r)| r.is_finite()) {
        let a = scan.angle_min + i as f64 * scan.angle_increment;
        for v in [r * a.cos(), r * a.sin(), 0.0, *r] {
            data.extend_from_slice(&(v as f32).to_le_bytes());
        }
    }
    let field = |name: &str, offset: u32| json!({"name": name, "offset": offset, "type": FLOAT32});
    json!({
        "timestamp": timestamp(scan.t), "frame_id": "laser", "pose": pose_json(0.0, 0.0, 0.0, [0.0, 0.0, 0.0, 1.0]),
        "point_stride": 16, "fields": [field("x", 0), field("y", 4), field("z", 8), field("range", 12)],
        "data": crate::record::base64(&data)
    })
}

fn schema(name: &str) -> Value {
    let time = json!({"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}});
    let vec3 = json!({"type": "object", "properties": {"x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}}});
    let quat = json!({"type": "object", "properties": {"x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}, "w": {"type": "number"}}});
    let pose = json!({"type": "object", "properties": {"position": vec3, "orientation": quat}});
    match name {
        "foxglove.PointCloud" => json!({
            "title": name, "type": "object",
            "properties": {
                "timestamp": time, "frame_id": {"type": "string"}, "pose": pose,
                "point_stride": {"type": "integer"},
                "fields": {"type": "array", "items": {"type": "object", "properties": {
                    "name": {"type": "string"}, "offset": {"type": "integer"}, "type": {"type": "integer"}}}},
                "data": {"type": "string", "contentEncoding": "base64"}
            }
        }),
        "foxglove.FrameTransform" => json!({
            "title": name, "type": "object",
            "properties": {
                "timestamp": time, "parent_frame_id": {"type": "string"}, "child_frame_id": {"type": "string"},
                "translation": vec3, "rotation": quat
            }
        }),
        "foxglove.PosesInFrame" => json!({
            "title": name, "type": "object",
            "properties": {"timestamp": time, "frame_id": {"type": "string"}, "poses": {"type": "array", "items": pose}}
        }),
        "foxglove.CompressedImage" => json!({
            "title": name, "type": "object",
            "properties": {"timestamp": time, "frame_id": {"type": "string"}, "data": {"type": "string", "contentEncoding": "base64"}, "format": {"type": "string"}}
        }),
        "foxglove.CameraCalibration" => json!({
            "title": name, "type": "object",
            "properties": {
                "timestamp": time, "frame_id": {"type": "string"}, "width": {"type": "integer"}, "height": {"type": "integer"},
                "distortion_model": {"type": "string"}, "D": {"type": "array", "items": {"type": "number"}},
                "K": {"type": "array", "items": {"type": "number"}}, "R": {"type": "array", "items": {"type": "number"}},
                "P": {"type": "array", "items": {"type": "number"}}
            }
        }),
        "foxglove.SceneUpdate" => json!({"title": name, "type": "object"}),
        _ => json!({"title": name, "type": "object"}),
    }
}

impl McapWriter {
    pub fn create(path: &Path) -> Result<Self, McapError> {
        let err = |e: &dyn std::error::Error| McapError { file: path.to_path_buf(), message: with_causes(e) };
        let file = File::create(path).map_err(|e| err(&e))?;
        let writer = mcap::Writer::new(BufWriter::new(file)).map_err(|e| err(&e))?;
        Ok(McapWriter { writer, channels: BTreeMap::new(), sequence: 0, file: path.to_path_buf() })
    }

    fn err(&self, e: &dyn std::error::Error) -> McapError {
        McapError { file: self.file.clone(), message: with_causes(e) }
    }

    /// Writes one message on `topic` with Foxglove schema `schema_name`, logged at `t`.
    pub fn write(&mut self, topic: &str, schema_name: &str, t: f64, message: &Value) -> Result<(), McapError> {
        let channel = match self.channels.get(topic) {
            Some(&c) => c,
            None => {
                let data = serde_json::to_vec(&schema(schema_name)).expect("schemas serialise");
                let schema_id = self.writer.add_schema(schema_name, "jsonschema", &data).map_err(|e| self.err(&e))?;
                let c =
                    self.writer.add_channel(schema_id, topic, "json", &BTreeMap::new()).map_err(|e| self.err(&e))?;
                self.channels.insert(topic.to_string(), c);
                c
            }
        };
        self.sequence += 1;
        let time = (t * 1e9).round() as u64;
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: self.sequence,
            log_time: time,
            publish_time: time,
        };
        let data = serde_json::to_vec(message).expect("JSON values serialise");
        self.writer.write_to_known_channel(&header, &data).map_err(|e| self.err(&e))
    }

    pub fn finish(mut self) -> Result<(), McapError> {
        self.writer.finish().map_err(|e| McapError { file: self.file.clone(), message: with_causes(&e) })?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    /// The writer's own words say that a write failed; its cause says why.
    #[test]
    fn an_mcap_error_carries_its_cause() {
        let full = mcap::McapError::Io(std::io::Error::from_raw_os_error(28));
        let said = super::with_causes(&full);
        assert!(said.starts_with("I/O error from writing") && said.contains("No space left on device"), "{said}");
        // A cause already in the words is not said twice.
        let io = std::io::Error::other("disk full");
        assert_eq!(super::with_causes(&io), "disk full");
    }
}
