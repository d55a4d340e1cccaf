//! Error types. Every failure is a value: nothing in this crate panics on bad input.

use std::path::PathBuf;

/// Why a message could not be encoded to CDR.
///
/// CDR itself can carry almost anything; these are the cases where the wire format (u32
/// lengths) or ROS 2's C string convention (NUL-terminated strings) cannot represent the value.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CdrError {
    /// ROS 2 strings are NUL-terminated on the wire; an interior NUL would silently truncate
    /// the string in every C/C++ reader, so it is refused rather than written.
    #[error("string of {len} bytes contains a NUL byte at offset {offset}")]
    StringContainsNul { len: usize, offset: usize },
    /// Lengths and element counts are u32 on the wire.
    #[error("{what} of length {len} exceeds the CDR limit of u32::MAX")]
    TooLong { what: &'static str, len: usize },
}

/// Errors from writing a bag.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The bag directory already holds files. rosbag2 never merges into an existing bag, and
    /// writing beside unknown files could produce a `metadata.yaml` that lies about them.
    #[error("{}: bag directory exists and is not empty", path.display())]
    DirectoryNotEmpty { path: PathBuf },
    /// The bag path exists but is a file (or something else), not a directory.
    #[error("{}: exists and is not a directory", path.display())]
    NotADirectory { path: PathBuf },
    /// A filesystem operation failed.
    #[error("{}: {action}", path.display())]
    Io {
        path: PathBuf,
        action: &'static str,
        #[source]
        source: std::io::Error,
    },
    /// The MCAP library refused a write (its own I/O errors arrive here too).
    #[error("{}: MCAP write failed", path.display())]
    Mcap {
        path: PathBuf,
        #[source]
        source: mcap::McapError,
    },
    /// The topic name is not a fully qualified ROS 2 name, which players would reject.
    #[error("invalid topic name {name:?}: {reason}")]
    InvalidTopicName { name: String, reason: &'static str },
    /// A topic already carries another message type; a rosbag2 topic has one type.
    #[error("topic {topic} holds {registered} messages, not {requested}")]
    TopicTypeMismatch { topic: String, registered: &'static str, requested: &'static str },
    /// A topic was registered twice with different QoS settings.
    #[error("topic {topic} is already registered with different QoS")]
    TopicQosMismatch { topic: String },
    /// MCAP channel ids are u16, so one bag holds at most 65535 topics.
    #[error("too many topics for one MCAP file (at most {max})")]
    TooManyTopics { max: usize },
    /// A message could not be encoded.
    #[error("cannot encode {type_name} for topic {topic}")]
    Encode {
        topic: String,
        type_name: &'static str,
        #[source]
        source: CdrError,
    },
    /// The bag was already closed. Only reachable from inside the writer's own `Drop`, since
    /// `finish` consumes it; a value rather than a panic all the same.
    #[error("bag already finished")]
    Finished,
    /// A time that `builtin_interfaces/Time` (i32 seconds) cannot hold, or that is not finite.
    #[error("time {seconds} s is not representable as builtin_interfaces/Time")]
    TimeOutOfRange { seconds: f64 },
}

impl Error {
    /// The file or directory the error names, where it names one.
    pub fn path(&self) -> Option<&std::path::Path> {
        match self {
            Error::DirectoryNotEmpty { path }
            | Error::NotADirectory { path }
            | Error::Io { path, .. }
            | Error::Mcap { path, .. } => Some(path),
            _ => None,
        }
    }
}

/// Result alias for this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;
