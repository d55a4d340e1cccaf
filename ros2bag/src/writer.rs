//! [`BagWriter`]: a rosbag2 directory with one MCAP file.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use crate::cdr::CdrWriter;
use crate::error::{Error, Result};
use crate::metadata::{self, BagInfo, TopicInfo, TopicQos};
use crate::msg::RosMessage;

/// Name of the metadata file rosbag2 looks for in a bag directory.
pub const METADATA_FILE: &str = "metadata.yaml";

/// One registered topic.
#[derive(Debug)]
struct Topic {
    name: String,
    type_name: &'static str,
    type_hash: &'static str,
    qos: TopicQos,
    channel_id: u16,
    message_count: u64,
}

/// Writes a ROS 2 bag: a directory holding `metadata.yaml` and `<dir name>_0.mcap`.
///
/// Messages are CDR encoded and stored with their full `.msg` definitions, so `ros2 bag
/// play`/`info`, Foxglove, `rosbags` and `mcap-ros2-support` read the bag without this crate.
///
/// Call [`BagWriter::finish`] at the end to see errors. If the writer is dropped instead, it
/// still closes the MCAP file and writes `metadata.yaml` on a best-effort basis (a run that
/// stops early keeps a readable bag), but any error then goes unreported.
pub struct BagWriter {
    dir: PathBuf,
    file_name: String,
    mcap_path: PathBuf,
    /// `None` once finished.
    mcap: Option<mcap::Writer<BufWriter<File>>>,
    topics: Vec<Topic>,
    topic_index: HashMap<String, usize>,
    /// MCAP schema id per ROS type name; a schema is written once however many topics use it.
    schemas: HashMap<&'static str, u16>,
    /// (earliest, latest) log time written, in ns.
    time_bounds: Option<(u64, u64)>,
    message_count: u64,
}

impl std::fmt::Debug for BagWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BagWriter")
            .field("dir", &self.dir)
            .field("file_name", &self.file_name)
            .field("topics", &self.topics)
            .field("message_count", &self.message_count)
            .field("finished", &self.mcap.is_none())
            .finish()
    }
}

impl BagWriter {
    /// Starts a bag in directory `dir`, creating it (and its parents) if needed.
    ///
    /// Refuses a directory that already has anything in it: rosbag2 bags are written once,
    /// and silently mixing with an older run's files would make a bag that misdescribes
    /// itself. The MCAP file is named after the directory (`<dir>_0.mcap`), as rosbag2 does.
    pub fn create(dir: &Path) -> Result<Self> {
        let stem = dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .filter(|n| !n.is_empty())
            .unwrap_or_else(|| "rosbag2".to_owned());
        Self::create_named(dir, &stem)
    }

    /// Like [`BagWriter::create`], the MCAP file named `<stem>_0.mcap`: for a bag written
    /// in a staging directory and moved to a directory named `stem` once finished.
    pub fn create_named(dir: &Path, stem: &str) -> Result<Self> {
        let io = |action: &'static str, path: &Path| {
            let path = path.to_path_buf();
            move |source| Error::Io { path, action, source }
        };
        match std::fs::metadata(dir) {
            Ok(m) if !m.is_dir() => return Err(Error::NotADirectory { path: dir.into() }),
            Ok(_) => {
                let mut entries = std::fs::read_dir(dir).map_err(io("cannot list the bag directory", dir))?;
                if entries.next().is_some() {
                    return Err(Error::DirectoryNotEmpty { path: dir.into() });
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                std::fs::create_dir_all(dir).map_err(io("cannot create the bag directory", dir))?;
            }
            Err(e) => return Err(io("cannot inspect the bag directory", dir)(e)),
        }

        let file_name = format!("{stem}_0.mcap");
        let mcap_path = dir.join(&file_name);
        // create_new: never truncate a file that appeared since the emptiness check.
        let file = File::create_new(&mcap_path).map_err(io("cannot create the MCAP file", &mcap_path))?;

        let options = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("ros2bag-rs/", env!("CARGO_PKG_VERSION")))
            // Uncompressed chunks: every reader handles them with no codec installed, and the
            // choice does not change when another crate turns on mcap's zstd feature.
            .compression(None);
        let mcap =
            options.create(BufWriter::new(file)).map_err(|source| Error::Mcap { path: mcap_path.clone(), source })?;

        Ok(Self {
            dir: dir.to_path_buf(),
            file_name,
            mcap_path,
            mcap: Some(mcap),
            topics: Vec::new(),
            topic_index: HashMap::new(),
            schemas: HashMap::new(),
            time_bounds: None,
            message_count: 0,
        })
    }

    /// The bag directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The MCAP file's path.
    pub fn mcap_path(&self) -> &Path {
        &self.mcap_path
    }

    /// Registers `topic` for messages of type `M`, with the usual QoS for its name
    /// ([`TopicQos::default_for_topic`]: latched for `/tf_static`).
    ///
    /// Optional: [`BagWriter::write`] registers a topic on first use. Registering up front
    /// lists a topic in the bag even if no message arrives on it.
    pub fn add_topic<M: RosMessage>(&mut self, topic: &str) -> Result<()> {
        self.add_topic_with_qos::<M>(topic, TopicQos::default_for_topic(topic))
    }

    /// Registers `topic` for messages of type `M` with the given offered QoS.
    ///
    /// Registering the same topic again with the same type and QoS is a no-op; a different
    /// type or QoS is an error, since a rosbag2 topic has one of each.
    pub fn add_topic_with_qos<M: RosMessage>(&mut self, topic: &str, qos: TopicQos) -> Result<()> {
        self.topic::<M>(topic, Some(qos)).map(|_| ())
    }

    /// Finds or registers a topic; `qos: None` means "whatever it has, or the default".
    fn topic<M: RosMessage>(&mut self, topic: &str, qos: Option<TopicQos>) -> Result<usize> {
        if let Some(&idx) = self.topic_index.get(topic) {
            let t = &self.topics[idx];
            if t.type_name != M::TYPE_NAME {
                return Err(Error::TopicTypeMismatch {
                    topic: topic.to_owned(),
                    registered: t.type_name,
                    requested: M::TYPE_NAME,
                });
            }
            if qos.is_some_and(|q| q != t.qos) {
                return Err(Error::TopicQosMismatch { topic: topic.to_owned() });
            }
            return Ok(idx);
        }
        validate_topic_name(topic)?;
        if self.topics.len() >= usize::from(u16::MAX) {
            return Err(Error::TooManyTopics { max: usize::from(u16::MAX) });
        }
        let qos = qos.unwrap_or_else(|| TopicQos::default_for_topic(topic));
        let mcap_err = |path: &Path| {
            let path = path.to_path_buf();
            move |source| Error::Mcap { path, source }
        };
        let mcap = self.mcap.as_mut().ok_or(Error::Finished)?;

        let schema_id = match self.schemas.get(M::TYPE_NAME) {
            Some(&id) => id,
            None => {
                let text = M::schema_text();
                let id =
                    mcap.add_schema(M::TYPE_NAME, "ros2msg", text.as_bytes()).map_err(mcap_err(&self.mcap_path))?;
                self.schemas.insert(M::TYPE_NAME, id);
                id
            }
        };
        // rosbag2 keeps the QoS (and, on Jazzy, the type hash) in the channel metadata too, so
        // that the MCAP alone is enough to rebuild metadata.yaml.
        let channel_metadata = BTreeMap::from([
            ("offered_qos_profiles".to_owned(), qos.offered_profiles_yaml()),
            ("topic_type_hash".to_owned(), M::DEFINITION.type_hash.to_owned()),
        ]);
        let channel_id =
            mcap.add_channel(schema_id, topic, "cdr", &channel_metadata).map_err(mcap_err(&self.mcap_path))?;

        self.topics.push(Topic {
            name: topic.to_owned(),
            type_name: M::TYPE_NAME,
            type_hash: M::DEFINITION.type_hash,
            qos,
            channel_id,
            message_count: 0,
        });
        let idx = self.topics.len() - 1;
        self.topic_index.insert(topic.to_owned(), idx);
        Ok(idx)
    }

    /// Writes `msg` on `topic`, stamped with `log_time_ns` (the bag's receive time, ns since
    /// the epoch; players replay on this clock, not on `header.stamp`).
    ///
    /// Messages may arrive in any time order; readers sort by log time.
    pub fn write<M: RosMessage>(&mut self, topic: &str, log_time_ns: u64, msg: &M) -> Result<()> {
        let idx = self.topic::<M>(topic, None)?;
        let mut w = CdrWriter::new();
        msg.encode(&mut w).map_err(|source| Error::Encode {
            topic: topic.to_owned(),
            type_name: M::TYPE_NAME,
            source,
        })?;
        let data = w.into_bytes();

        let t = &mut self.topics[idx];
        let header = mcap::records::MessageHeader {
            channel_id: t.channel_id,
            // Per-channel message counter; readers ignore it, it only helps spot gaps.
            sequence: t.message_count as u32,
            log_time: log_time_ns,
            publish_time: log_time_ns,
        };
        let mcap = self.mcap.as_mut().ok_or(Error::Finished)?;
        mcap.write_to_known_channel(&header, &data)
            .map_err(|source| Error::Mcap { path: self.mcap_path.clone(), source })?;

        t.message_count += 1;
        self.message_count += 1;
        self.time_bounds = Some(match self.time_bounds {
            None => (log_time_ns, log_time_ns),
            Some((lo, hi)) => (lo.min(log_time_ns), hi.max(log_time_ns)),
        });
        Ok(())
    }

    /// Attaches a file to the MCAP (an attachment record, logged at time 0): data that
    /// belongs with the bag but is not a message, such as how it was made. ROS 2 players
    /// pass over attachments; MCAP tools list and extract them.
    pub fn attach(&mut self, name: &str, media_type: &str, data: &[u8]) -> Result<()> {
        let mcap = self.mcap.as_mut().ok_or(Error::Finished)?;
        let attachment = mcap::Attachment {
            log_time: 0,
            create_time: 0,
            name: name.to_owned(),
            media_type: media_type.to_owned(),
            data: std::borrow::Cow::Borrowed(data),
        };
        mcap.attach(&attachment).map_err(|source| Error::Mcap { path: self.mcap_path.clone(), source })
    }

    /// Closes the MCAP file and writes `metadata.yaml`. The bag is complete only after this.
    pub fn finish(mut self) -> Result<()> {
        self.finish_inner()
    }

    fn finish_inner(&mut self) -> Result<()> {
        let Some(mut mcap) = self.mcap.take() else {
            return Ok(());
        };
        let mcap_err = |source| Error::Mcap { path: self.mcap_path.clone(), source };
        let (start, end) = self.time_bounds.unwrap_or((0, 0));
        let info = BagInfo {
            file_name: &self.file_name,
            starting_time_ns: start,
            duration_ns: end - start,
            message_count: self.message_count,
            topics: self
                .topics
                .iter()
                .map(|t| TopicInfo {
                    name: &t.name,
                    type_name: t.type_name,
                    type_hash: t.type_hash,
                    qos: t.qos,
                    message_count: t.message_count,
                })
                .collect(),
        };

        // The same summary rosbag2 leaves inside the MCAP (record "rosbag2").
        let record = mcap::records::Metadata {
            name: "rosbag2".to_owned(),
            metadata: BTreeMap::from([("serialized_metadata".to_owned(), metadata::bag_information(&info, ""))]),
        };
        mcap.write_metadata(&record).map_err(mcap_err)?;
        mcap.finish().map_err(mcap_err)?;
        let file = mcap.into_inner().into_inner().map_err(|e| Error::Io {
            path: self.mcap_path.clone(),
            action: "cannot flush the MCAP file",
            source: e.into_error(),
        })?;
        file.sync_all().map_err(|source| Error::Io {
            path: self.mcap_path.clone(),
            action: "cannot sync the MCAP file",
            source,
        })?;

        let yaml_path = self.dir.join(METADATA_FILE);
        std::fs::write(&yaml_path, metadata::metadata_yaml(&info)).map_err(|source| Error::Io {
            path: yaml_path,
            action: "cannot write metadata.yaml",
            source,
        })
    }
}

impl Drop for BagWriter {
    fn drop(&mut self) {
        // Best effort; `finish` is the way to hear about errors.
        let _ = self.finish_inner();
    }
}

/// Checks a fully qualified ROS 2 topic name (`/a/b_c`), the only form a bag stores.
///
/// The rules are rcl's: a leading `/`, tokens of letters, digits and `_` that do not start with
/// a digit, no empty token, no trailing `/`. Relative names and `~` would depend on a node's
/// namespace, which a bag does not have.
pub fn validate_topic_name(name: &str) -> Result<()> {
    let bad = |reason| Err(Error::InvalidTopicName { name: name.to_owned(), reason });
    let Some(rest) = name.strip_prefix('/') else {
        return bad("must start with '/'");
    };
    if rest.is_empty() {
        return bad("must name a topic, not just '/'");
    }
    for token in rest.split('/') {
        let Some(first) = token.chars().next() else {
            return bad("must not contain '//' or end with '/'");
        };
        if first.is_ascii_digit() {
            return bad("a name token must not start with a digit");
        }
        if !token.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return bad("only letters, digits, '_' and '/' are allowed");
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topic_names() {
        for ok in ["/scan", "/tf_static", "/camera/image_raw", "/a1/_b"] {
            assert!(validate_topic_name(ok).is_ok(), "{ok}");
        }
        for bad in ["", "/", "scan", "/scan/", "//scan", "/1scan", "/a b", "/ä", "/a-b", "~/x"] {
            assert!(matches!(validate_topic_name(bad), Err(Error::InvalidTopicName { .. })), "{bad}");
        }
    }
}
