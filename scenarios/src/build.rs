//! Which build made an output, written beside the version into every output's metadata so
//! that a result can be traced to its code. The library cannot know its own commit: the
//! program that links it says it once at start ([`set`]); `objslam` learns it from its
//! build script. Outputs of a program that never said carry none.

use std::sync::OnceLock;

use serde::{Deserialize, Serialize};

static SOURCE: OnceLock<Source> = OnceLock::new();

/// The source a program was built from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Source {
    /// The commit checked out when it was built.
    pub commit: String,
    /// Whether the workspace's crates or manifests then differed from that commit
    /// (uncommitted changes are in the binary but in no commit).
    pub modified: bool,
}

/// What the metadata of an output records: the package version and, where known, the source.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Build {
    pub version: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<Source>,
}

/// Records the source this program was built from; later calls change nothing.
pub fn set(commit: &str, modified: bool) {
    let _ = SOURCE.set(Source { commit: commit.to_string(), modified });
}

/// This program's build.
pub fn current() -> Build {
    Build { version: env!("CARGO_PKG_VERSION").to_string(), source: SOURCE.get().cloned() }
}

/// This program's build in one line, for a tool field: `0.1.0 (abc1234, modified)`.
pub fn describe() -> String {
    current().describe()
}

impl Build {
    /// The build in one line: `0.1.0 (abc1234, modified)`, the version alone where the
    /// source is unknown.
    pub fn describe(&self) -> String {
        match &self.source {
            Some(s) => format!(
                "{} ({}{})",
                self.version,
                s.commit.get(..12).unwrap_or(&s.commit),
                if s.modified { ", modified" } else { "" }
            ),
            None => self.version.to_string(),
        }
    }
}
