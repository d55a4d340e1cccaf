//! One convention for checking settings: each settings type's `validate()` names the first
//! field that makes no sense and the problem, as `(field, problem)`; a type that holds
//! others prefixes their fields with its own, so [`InvalidSetting::path`] is the dotted
//! path from the top (`clustering.max_range_m`). Loaders add the file and the line.

/// Largest count of scans, frames or beams a setting may ask for: far beyond any use (a
/// thousand scans are 100 s of the SICK's 10 Hz), small enough that a typo is caught.
pub const MAX_COUNT: usize = 1000;

/// A setting that makes no sense.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{path}: {problem}")]
pub struct InvalidSetting {
    /// Dotted path of the field, from the settings' top (`evidence.radius_m`).
    pub path: String,
    pub problem: String,
}

impl InvalidSetting {
    /// A field of the top table.
    pub fn new(path: impl Into<String>, problem: impl Into<String>) -> Self {
        InvalidSetting { path: path.into(), problem: problem.into() }
    }

    /// A `(field, problem)` of the sub-table `table`.
    pub fn in_table(table: &str, (field, problem): (&str, String)) -> Self {
        InvalidSetting { path: format!("{table}.{field}"), problem }
    }

    /// The same problem, one table further down (`prefix.path`).
    pub fn under(self, prefix: &str) -> Self {
        InvalidSetting { path: format!("{prefix}.{}", self.path), problem: self.problem }
    }
}
