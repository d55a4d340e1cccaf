//! Typed errors: every one names the file, the field or line, and the problem.

use std::fmt;
use std::path::PathBuf;

/// One thing wrong with a world, located by field path and, when known, line.
#[derive(Debug, Clone, PartialEq)]
pub struct Problem {
    /// Field path such as `objects[3].shape.radius_m`.
    pub field: String,
    /// 1-based line in the file, when the field could be located.
    pub line: Option<usize>,
    pub message: String,
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            Some(line) => write!(f, "line {line}: {}: {}", self.field, self.message),
            None => write!(f, "{}: {}", self.field, self.message),
        }
    }
}

/// Errors from loading, validating, generating or exporting worlds.
#[derive(Debug, thiserror::Error)]
pub enum WorldError {
    #[error("{}: cannot read: {source}", file.display())]
    Read { file: PathBuf, source: std::io::Error },
    #[error("{}: cannot write: {source}", file.display())]
    Write { file: PathBuf, source: std::io::Error },
    /// TOML syntax error, missing field, unknown class or field: the message carries the
    /// line and column from the TOML parser.
    #[error("{}: {message}", file.display())]
    Parse { file: PathBuf, message: String },
    #[error("{}: invalid world:\n{}", file.display(), problems.iter().map(|p| format!("  - {p}")).collect::<Vec<_>>().join("\n"))]
    Invalid { file: PathBuf, problems: Vec<Problem> },
    #[error("{}: mesh {}: {message}", file.display(), mesh.display())]
    Mesh { file: PathBuf, mesh: PathBuf, message: String },
    #[error("generator parameter {field}: {message}")]
    Parameter { field: String, message: String },
    #[error(
        "generator could not place {what} after {attempts} attempts; loosen the parameters (more area, fewer objects or smaller clearances)"
    )]
    Placement { what: String, attempts: usize },
}

impl WorldError {
    /// The problems of an `Invalid` error (empty for other kinds), for tests and tools.
    pub fn problems(&self) -> &[Problem] {
        match self {
            WorldError::Invalid { problems, .. } => problems,
            _ => &[],
        }
    }
}
