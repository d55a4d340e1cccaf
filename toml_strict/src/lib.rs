//! # toml_strict — settings files read the way they are written
//!
//! `toml::from_str` (toml 1.2) fills a fixed-length array field (`[f64; 3]`) from the
//! first elements of a longer TOML array and drops the rest without a word, so
//! `mount_xyz_m = [0.16, 0.0, 0.4, 9.0]` would be read as if the 9.0 were not there.
//! [`from_str`] parses as `toml::from_str` does (its errors keep their line and column),
//! then deserialises the parsed document once more through `toml::Value`, whose
//! deserialiser refuses leftover elements, and names the line and the key of what it
//! refuses. [`from_value`] does the second step alone, for settings merged from several
//! files, with the lines taken from the file that gave the key.

use serde::de::DeserializeOwned;
use serde_path_to_error::Segment;
use toml::de::{DeTable, DeValue};

/// A settings text that does not deserialise, with the line (1-based) of the problem
/// where it is known.
#[derive(Debug, Clone, PartialEq)]
pub struct TomlError {
    pub line: Option<usize>,
    /// The dotted key of the value refused (`sim.laser.mount_xyz_m`), where known.
    pub key: Option<String>,
    /// What is wrong, without the line.
    pub message: String,
    /// toml's own rendering (with the line's text) for errors it located itself.
    rendered: Option<String>,
}

impl std::fmt::Display for TomlError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(r) = &self.rendered {
            return f.write_str(r.trim_end());
        }
        if let Some(line) = self.line {
            write!(f, "line {line}: ")?;
        }
        if let Some(key) = &self.key {
            write!(f, "{key}: ")?;
        }
        f.write_str(&self.message)
    }
}

impl std::error::Error for TomlError {}

/// Deserialises settings text, refusing extra elements of fixed-length arrays.
pub fn from_str<T: DeserializeOwned>(text: &str) -> Result<T, TomlError> {
    let first: T = toml::from_str(text).map_err(|e| TomlError {
        line: e.span().map(|s| line_at(text, s.start)),
        key: None,
        message: e.message().to_string(),
        rendered: Some(e.to_string()),
    })?;
    // The text parsed above, so it parses as a document too.
    let document = DeTable::parse(text).map_err(|e| TomlError {
        line: e.span().map(|s| line_at(text, s.start)),
        key: None,
        message: e.message().to_string(),
        rendered: Some(e.to_string()),
    })?;
    from_value::<T>(value_of(&DeValue::Table(document.into_inner())), text, &[])?;
    Ok(first)
}

/// A parsed document as a `toml::Value`, for the second pass. An integer past i64 (which
/// `toml::Value` cannot hold: `toml::Table` refuses such a text) can only be meant for a
/// u64 field, whose value the first pass has read; 0 stands in for it, which every u64
/// field takes, so only the arrays' lengths are judged again.
fn value_of(v: &DeValue) -> toml::Value {
    match v {
        DeValue::String(s) => toml::Value::String(s.to_string()),
        DeValue::Integer(i) => toml::Value::Integer(i64::from_str_radix(i.as_str(), i.radix()).unwrap_or(0)),
        DeValue::Float(f) => toml::Value::Float(f.as_str().parse().unwrap_or(0.0)),
        DeValue::Boolean(b) => toml::Value::Boolean(*b),
        DeValue::Datetime(d) => toml::Value::Datetime(*d),
        DeValue::Array(a) => toml::Value::Array(a.iter().map(|v| value_of(v.get_ref())).collect()),
        DeValue::Table(t) => {
            toml::Value::Table(t.iter().map(|(k, v)| (k.get_ref().to_string(), value_of(v.get_ref()))).collect())
        }
    }
}

/// Deserialises a `toml::Value` (which refuses extra array elements); a refusal is located
/// in `text`, the file the refused key came from, where the value is the table at the
/// dotted keys `under` (empty: the whole file).
pub fn from_value<T: DeserializeOwned>(value: toml::Value, text: &str, under: &[&str]) -> Result<T, TomlError> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let segments: Vec<&Segment> = e.path().iter().collect();
        let key = key_of(&segments);
        let prefix: Vec<Segment> = under.iter().map(|k| Segment::Map { key: k.to_string() }).collect();
        let in_text: Vec<&Segment> = prefix.iter().chain(segments.iter().copied()).collect();
        TomlError {
            line: span_of(text, &in_text).map(|at| line_at(text, at)),
            key: (!key.is_empty()).then_some(key),
            message: plain_message(e.inner().message()),
            rendered: None,
        }
    })
}

/// The 1-based line of `text` where its top-level key `key` is given (a table's header).
pub fn line_of(text: &str, key: &str) -> Option<usize> {
    let segment = Segment::Map { key: key.to_string() };
    span_of(text, &[&segment]).map(|at| line_at(text, at))
}

/// The 1-based line of `text` where the key at `path` (`["pipeline", "motion", "model"]`)
/// is given, or as deep along the path as the text goes (the table's header).
pub fn line_of_path(text: &str, path: &[&str]) -> Option<usize> {
    let segments: Vec<Segment> = path.iter().map(|k| Segment::Map { key: k.to_string() }).collect();
    span_of(text, &segments.iter().collect::<Vec<_>>()).map(|at| line_at(text, at))
}

/// toml's words for an array longer than its field, said plainly.
fn plain_message(message: &str) -> String {
    match message.strip_prefix("invalid length ").and_then(|m| m.strip_suffix(", expected fewer elements in array")) {
        Some(n) => format!("{n} elements, more than it takes"),
        None => message.to_string(),
    }
}

/// The dotted key of a path (`a.b[2].c`).
fn key_of(segments: &[&Segment]) -> String {
    let mut key = String::new();
    for s in segments {
        match s {
            Segment::Map { key: k } => {
                if !key.is_empty() {
                    key.push('.');
                }
                key.push_str(k);
            }
            Segment::Seq { index } => key.push_str(&format!("[{index}]")),
            Segment::Enum { .. } | Segment::Unknown => break,
        }
    }
    key
}

/// Where in `text` the value at `segments` is given: as deep along the path as the text
/// goes (a key set only by an earlier file is located at its table, or not at all).
fn span_of(text: &str, segments: &[&Segment]) -> Option<usize> {
    let root = DeValue::Table(DeTable::parse(text).ok()?.into_inner());
    let mut at = None;
    let mut value = &root;
    for s in segments {
        let next = match (s, value) {
            (Segment::Map { key }, DeValue::Table(t)) => {
                t.iter().find(|(k, _)| k.get_ref().as_ref() == key.as_str()).map(|(k, v)| (k.span().start, v))
            }
            (Segment::Seq { index }, DeValue::Array(a)) => a.get(*index).map(|v| (v.span().start, v)),
            _ => None,
        };
        let Some((start, v)) = next else { break };
        at = Some(start);
        value = v.get_ref();
    }
    at
}

/// The 1-based line of byte `offset` of `text`.
fn line_at(text: &str, offset: usize) -> usize {
    text.as_bytes()[..offset.min(text.len())].iter().filter(|&&b| b == b'\n').count() + 1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, serde::Deserialize, PartialEq)]
    #[serde(deny_unknown_fields)]
    struct Mount {
        xyz_m: [f64; 3],
        #[serde(default)]
        seed: u64,
        #[serde(default)]
        inner: Option<Inner>,
    }

    #[derive(Debug, serde::Deserialize, PartialEq)]
    #[serde(deny_unknown_fields)]
    struct Inner {
        pairs: Vec<[u32; 2]>,
    }

    #[test]
    fn extra_array_elements_are_refused_at_their_line_and_key() {
        // toml alone accepts this, dropping the 9.0 (what the crate is for).
        let text = "# mount\n\nxyz_m = [0.16, 0.0, 0.4, 9.0]\n";
        assert_eq!(toml::from_str::<Mount>(text).unwrap().xyz_m, [0.16, 0.0, 0.4]);
        let e = from_str::<Mount>(text).unwrap_err();
        assert_eq!((e.line, e.key.as_deref()), (Some(3), Some("xyz_m")), "{e}");
        assert_eq!(e.message, "4 elements, more than it takes");
        assert!(e.to_string().starts_with("line 3: xyz_m: "), "{e}");
        // Nested, in a table and an array of arrays.
        let text = "xyz_m = [1, 2, 3]\n[inner]\npairs = [\n  [1, 2],\n  [3, 4, 5],\n]\n";
        let e = from_str::<Mount>(text).unwrap_err();
        assert_eq!((e.line, e.key.as_deref()), (Some(5), Some("inner.pairs[1]")), "{e}");
    }

    #[test]
    fn what_toml_refuses_keeps_its_line_and_what_is_right_is_read() {
        let text = "xyz_m = [1, 2, 3]\n\nnope = 1\n";
        let e = from_str::<Mount>(text).unwrap_err();
        assert_eq!(e.line, Some(3), "{e}");
        assert!(e.to_string().contains("unknown field `nope`"), "{e}");
        let text = "xyz_m = [1, 2]\n";
        assert_eq!(from_str::<Mount>(text).unwrap_err().line, Some(1));
        let m: Mount = from_str("xyz_m = [1, 2, 3.5]\n[inner]\npairs = [[1, 2]]\n").unwrap();
        assert_eq!(m, Mount { xyz_m: [1.0, 2.0, 3.5], seed: 0, inner: Some(Inner { pairs: vec![[1, 2]] }) });
        // A u64 past i64 (a seed), which toml::Value cannot hold, is read as toml reads it.
        let m: Mount = from_str("seed = 18446744073709551615\nxyz_m = [1, 2, 3]\n").unwrap();
        assert_eq!(m.seed, u64::MAX);
        let e = from_str::<Mount>("seed = 9223372036854775808\nxyz_m = [1, 2, 3, 4]\n").unwrap_err();
        assert_eq!((e.line, e.key.as_deref()), (Some(2), Some("xyz_m")), "{e}");
        // Every kind of value passes the second reading.
        #[derive(Debug, serde::Deserialize)]
        #[allow(dead_code)]
        struct Kinds {
            s: String,
            f: f64,
            nan: f64,
            b: bool,
            d: toml::value::Datetime,
            h: i64,
        }
        let k: Kinds =
            from_str("s = \"x\"\nf = -1.5e3\nnan = nan\nb = true\nd = 1979-05-27T07:32:00Z\nh = 0xff\n").unwrap();
        assert!(k.nan.is_nan() && k.h == 255);
    }

    #[test]
    fn a_merged_value_is_located_in_the_file_that_gave_the_key() {
        let mut value: toml::Value = toml::from_str("xyz_m = [1, 2, 3]").unwrap();
        let over = "\n\n\nxyz_m = [1, 2, 3, 4]\n";
        value.as_table_mut().unwrap().extend(toml::from_str::<toml::Table>(over).unwrap());
        let e = from_value::<Mount>(value.clone(), over, &[]).unwrap_err();
        assert_eq!((e.line, e.key.as_deref()), (Some(4), Some("xyz_m")), "{e}");
        // The same keys under a table of the file.
        let e = from_value::<Mount>(value, "# a\n[mount]\nxyz_m = [1, 2, 3, 4]\n", &["mount"]).unwrap_err();
        assert_eq!((e.line, e.key.as_deref()), (Some(3), Some("xyz_m")), "{e}");
    }
}
