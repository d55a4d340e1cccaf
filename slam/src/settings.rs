//! One convention for checking settings: each settings type's `validate()` names the first
//! field that makes no sense and the problem, as `(field, problem)`; a type that holds
//! others prefixes their fields with its own, so [`InvalidSetting::path`] is the dotted
//! path from the top (`clustering.max_range_m`). Loaders add the file and the line.

/// Largest count of scans, frames or beams a setting may ask for: far beyond any use (a
/// thousand scans are 100 s of the SICK's 10 Hz), small enough that a typo is caught.
pub const MAX_COUNT: usize = 1000;

/// Largest standard deviation a noise setting may have (metres, or metres per metre): no
/// sensor or start is a thousand kilometres uncertain, and beyond this the variance's
/// products with ranges and Jacobians overflow within a few steps, so the filter would
/// stop as diverged at its first input rather than at the setting.
pub const MAX_SIGMA: f64 = 1e6;

/// Parses JSON into `T`; an error says where, as the JSON path of the value
/// (`extractor.pca.variances[3]`) beside the line and column, and what is wrong with it.
pub fn from_json<T: serde::de::DeserializeOwned>(text: &str) -> Result<T, String> {
    let mut de = serde_json::Deserializer::from_str(text);
    let value = serde_path_to_error::deserialize(&mut de).map_err(|e| describe_json_error(&e))?;
    // Trailing characters after the value are an error too.
    de.end().map_err(|e| e.to_string())?;
    Ok(value)
}

fn describe_json_error(e: &serde_path_to_error::Error<serde_json::Error>) -> String {
    let path = e.path().to_string();
    let problem = in_json_words(&e.inner().to_string());
    // `?`: serde_path_to_error knows no place (an error before the first key).
    if path.is_empty() || path == "." || path == "?" { problem } else { format!("{path}: {problem}") }
}

/// A serde error in JSON's words: serde names a table `map` or `struct Name` (a Rust type,
/// meaningless to the file's author) and an array `sequence`.
fn in_json_words(message: &str) -> String {
    // An array where a table belongs is read as the table's fields in order, and a wrong
    // count is "invalid length N, expected struct Name with M elements".
    if message.starts_with("invalid length")
        && let Some(at) = message.find("expected struct ")
    {
        let place = message.find(" at line ").map_or("", |p| &message[p..]);
        if message[at..].contains(" with ") {
            return format!("invalid type: an array, expected an object{place}");
        }
    }
    let mut out = message.replace("invalid type: sequence", "invalid type: an array");
    out = out.replace("invalid type: map", "invalid type: an object");
    out = out.replace("expected a sequence", "expected an array");
    while let Some(at) = out.find("expected struct ") {
        let name_start = at + "expected struct ".len();
        let name_len =
            out[name_start..].find(|c: char| !(c.is_alphanumeric() || c == '_')).unwrap_or(out.len() - name_start);
        out.replace_range(at..name_start + name_len, "expected an object");
    }
    out
}

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

#[cfg(test)]
mod json_tests {
    #[derive(Debug, serde::Deserialize)]
    #[allow(dead_code)]
    struct Outer {
        inner: Inner,
    }
    #[derive(Debug, serde::Deserialize)]
    #[allow(dead_code)]
    struct Inner {
        values: Vec<f64>,
    }

    #[test]
    fn json_errors_give_the_path_of_the_bad_value() {
        let e = super::from_json::<Outer>(r#"{"inner": {"values": [1.0, "x"]}}"#).unwrap_err();
        assert!(e.starts_with("inner.values[1]: invalid type: string"), "{e}");
        assert!(super::from_json::<Outer>(r#"{"inner": {"values": []}} trailing"#).is_err());
        assert_eq!(super::from_json::<Outer>(r#"{"inner": {"values": [2.5]}}"#).unwrap().inner.values, vec![2.5]);
        // Cut short before its first key: no place to name, and no `?` for one.
        let e = super::from_json::<Outer>("{").unwrap_err();
        assert!(e.starts_with("EOF while parsing"), "{e}");
    }

    #[test]
    fn json_errors_name_json_types_not_rust_ones() {
        let e = super::from_json::<Outer>("[]").unwrap_err();
        assert!(e.starts_with("invalid type: an array, expected an object"), "{e}");
        let e = super::from_json::<Outer>(r#"{"inner": {"values": {}}}"#).unwrap_err();
        assert!(e.starts_with("inner.values: invalid type: an object, expected an array"), "{e}");
        let e = super::from_json::<Outer>(r#"{"inner": 3}"#).unwrap_err();
        assert!(e.starts_with("inner: invalid type: integer `3`, expected an object"), "{e}");
    }
}
