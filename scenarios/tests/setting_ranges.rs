//! Every numeric setting of a scenario refuses values outside any sensible range (NaN,
//! infinities, and negatives where only positive values mean something), with an error
//! naming the file, the line and the field: the complete default scenario
//! (`objslam config defaults`) is edited one value at a time and parsed.

use std::path::Path;

use scenarios::scenario::Scenario;

/// Settings whose valid values include negative ones (positions, angles, intervals).
const SIGNED: &[&str] = &[
    "sim.laser.mount_xyz_m",
    "sim.laser.mount_yaw_deg",
    "sim.camera.mount_xyz_m",
    "sim.camera.mount_pitch_deg",
    "sim.camera.mount_yaw_deg",
    "calibration.session.bearing_deg",
    "calibration.session.turn_deg",
    "calibration.session.tilt_deg",
    "calibration.session.segmentation.bearing_rad",
    "pipeline.sensor.mount_y",
    "pipeline.motion.encoder_offset_m",
];

/// A numeric key of the default scenario: where it is written, and its default or example.
struct Key {
    path: String,
    /// 0-based line in the defaults text.
    line: usize,
    /// Written commented out (no default): the line and, where needed, its table header are
    /// uncommented to set it.
    commented: bool,
    value: toml::Value,
}

fn numeric_keys(text: &str) -> Vec<Key> {
    let mut table = String::new();
    let mut keys = vec![];
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        let header = line.trim_start_matches("# ");
        if let Some(h) = header.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            table = h.to_string();
            continue;
        }
        let (commented, body) = match line.strip_prefix("# ") {
            Some(rest) => (true, rest),
            None => (false, line),
        };
        let Some((key, value)) = body.split_once(" = ") else { continue };
        if !key.chars().all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_') {
            continue;
        }
        let Ok(parsed) = toml::from_str::<toml::Table>(&format!("v = {value}")) else { continue };
        let value = parsed["v"].clone();
        let numeric = |v: &toml::Value| matches!(v, toml::Value::Float(_) | toml::Value::Integer(_));
        let is_numeric = numeric(&value) || value.as_array().is_some_and(|a| !a.is_empty() && a.iter().all(numeric));
        if is_numeric {
            keys.push(Key { path: format!("{table}.{key}"), line: i, commented, value });
        }
    }
    keys
}

/// The defaults with `key` set to `value` (a TOML literal), and the key's 1-based line.
fn edited(text: &str, key: &Key, value: &str) -> (String, usize) {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let name = key.path.rsplit('.').next().unwrap();
    lines[key.line] = format!("{name} = {value}");
    let mut line = key.line;
    if key.commented {
        let header = (0..key.line).rev().find(|&j| lines[j].trim_start_matches("# ").starts_with('[')).unwrap();
        // Its table's header may be commented out too.
        lines[header] = lines[header].trim_start_matches("# ").to_string();
        // The Ackermann keys are the other vehicle model's: the table holds that model alone.
        if key.path.starts_with("pipeline.motion.") {
            let end = (header + 1..lines.len()).find(|&j| lines[j].starts_with('[')).unwrap_or(lines.len());
            let own = lines[key.line].clone();
            lines.splice(header + 1..end, ["model = \"ackermann\"".to_string(), own, String::new()]);
            line = header + 2;
        }
    }
    (lines.join("\n") + "\n", line + 1)
}

fn literal(v: &toml::Value) -> String {
    match v {
        toml::Value::Float(f) if f.is_nan() => "nan".into(),
        toml::Value::Float(f) if f.is_infinite() => if *f > 0.0 { "inf" } else { "-inf" }.into(),
        toml::Value::Float(f) => format!("{f:?}"),
        toml::Value::Array(a) => format!("[{}]", a.iter().map(literal).collect::<Vec<_>>().join(", ")),
        other => other.to_string(),
    }
}

/// The bad values to try for a key: each as a TOML literal.
fn bad_values(key: &Key) -> Vec<String> {
    let signed = SIGNED.contains(&key.path.as_str());
    let scalar_bad = |v: &toml::Value| -> Vec<toml::Value> {
        match v {
            toml::Value::Float(f) => {
                let mut out = vec![toml::Value::Float(f64::NAN), toml::Value::Float(f64::INFINITY)];
                out.push(toml::Value::Float(f64::NEG_INFINITY));
                if !signed && *f >= 0.0 {
                    out.push(toml::Value::Float(-1.0));
                }
                out
            }
            // Seeds take any value; every count has an upper bound (no input may allocate or
            // loop without limit).
            toml::Value::Integer(_) if key.path.ends_with("seed") => vec![toml::Value::Integer(-1)],
            // A pass bound no run reaches only says what leaving it out says.
            toml::Value::Integer(_) if key.path.starts_with("pass.max_") => vec![toml::Value::Integer(-1)],
            // 1e9 fits a u32 field, 4e12 does not.
            toml::Value::Integer(_) => vec![
                toml::Value::Integer(-1),
                toml::Value::Integer(1_000_000_000),
                toml::Value::Integer(4_000_000_000_000),
            ],
            _ => vec![],
        }
    };
    match &key.value {
        toml::Value::Array(items) => {
            let mut out = vec![];
            for (k, item) in items.iter().enumerate() {
                for bad in scalar_bad(item) {
                    let mut a = items.clone();
                    a[k] = bad;
                    out.push(literal(&toml::Value::Array(a)));
                }
            }
            out
        }
        v => scalar_bad(v).iter().map(literal).collect(),
    }
}

#[test]
fn every_numeric_setting_refuses_values_out_of_range_naming_file_line_and_field() {
    let text = Scenario::defaults_toml(None).unwrap();
    let keys = numeric_keys(&text);
    assert!(keys.len() > 120, "found only {} numeric keys", keys.len());
    let file = Path::new("probe.toml");
    let mut accepted = vec![];
    let mut unnamed = vec![];
    let mut tried = 0;
    for key in &keys {
        // The car-like motion model's keys are shown for robot logs (`objslam replay`): a
        // scenario's simulated robot gives odometry increments, so a scenario refuses the
        // model itself, naming it, before any of its values.
        if key.commented && key.path.starts_with("pipeline.motion.") {
            let (own, _) = edited(&text, key, &literal(&key.value));
            let e = Scenario::parse(&own, file).expect_err("a scenario with the car-like model").to_string();
            assert!(e.contains("probe.toml") && e.contains("pipeline.motion.model: \"ackermann\""), "{e}");
            continue;
        }
        // Set to its own example value, a commented key must be accepted.
        if key.commented {
            let (own, _) = edited(&text, key, &literal(&key.value));
            if let Err(e) = Scenario::parse(&own, file) {
                panic!("{} = {} (its documented example) is refused: {e}", key.path, literal(&key.value));
            }
        }
        for bad in bad_values(key) {
            tried += 1;
            let (probe, line) = edited(&text, key, &bad);
            match Scenario::parse(&probe, file) {
                Ok(_) => accepted.push(format!("{} = {bad}", key.path)),
                Err(e) => {
                    let e = e.to_string();
                    let name = key.path.rsplit('.').next().unwrap();
                    let line = format!("line {line}");
                    // "line 3" must not match "line 30".
                    let line_named = e.contains(&format!("{line}:")) || e.contains(&format!("{line},"));
                    if !(e.contains("probe.toml") && line_named && e.contains(name)) {
                        unnamed.push(format!("{} = {bad}: {e}", key.path));
                    }
                }
            }
        }
    }
    assert!(tried > 600, "tried only {tried} values");
    assert!(accepted.is_empty(), "{} of {tried} bad values accepted:\n{}", accepted.len(), accepted.join("\n"));
    assert!(unnamed.is_empty(), "{} errors without file, line and field:\n{}", unnamed.len(), unnamed.join("\n"));
}
