//! The files a system under test gives `objslam score`, and how they are read: its
//! trajectory (TUM), pose covariances (CSV), map (JSON or CSV) and associations (JSON lines
//! or CSV, by observation id or by beams). Formats: docs/guide/scoring.md#inputs.

use std::path::Path;

use serde::Deserialize;

use super::log::{ScoreError, invalid, numbered_lines, read_text};
use super::scorer::{Fusion, MapLandmark, ScoredObservation};

/// Planar poses: (t, [x, y, yaw]).
pub type PlanarPoses = Vec<(f64, [f64; 3])>;

/// A TUM trajectory: (t, x, y, yaw) per pose, in file order.
pub fn read_tum(file: &Path) -> Result<PlanarPoses, ScoreError> {
    Ok(read_tum_3d(file)?.0)
}

/// What of a TUM trajectory planar scoring leaves out: the largest height and tilt.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct OffPlane {
    pub max_abs_z_m: f64,
    /// The largest angle between the pose's up axis and the world's.
    pub max_tilt_deg: f64,
}

/// The largest coordinate a pose or landmark may have (m): a million km, far past any
/// coordinate on Earth (UTM northings stay below 1e7 m), so a larger one is a unit or column
/// mistake, and errors of poses and landmarks within it square without overflow.
const MAX_POSITION_M: f64 = 1e9;

/// A TUM trajectory as [`read_tum`] reads it, with what the plane leaves out of it.
pub fn read_tum_3d(file: &Path) -> Result<(PlanarPoses, OffPlane), ScoreError> {
    let mut poses: PlanarPoses = Vec::new();
    let mut off_plane = OffPlane::default();
    let text = read_text(file)?;
    // A byte-order mark (some editors' UTF-8) is no part of the first number.
    for (i, line) in text.strip_prefix('\u{feff}').unwrap_or(&text).lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let values: Vec<f64> = line
            .split_whitespace()
            .map(|w| w.parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|e| invalid(file, Some(i + 1), format!("not a number: {e}")))?;
        let [t, x, y, z, qx, qy, qz, qw] = values[..] else {
            return Err(invalid(
                file,
                Some(i + 1),
                format!("{} values where TUM has 8 (timestamp tx ty tz qx qy qz qw)", values.len()),
            ));
        };
        if values.iter().any(|v| !v.is_finite()) {
            return Err(invalid(file, Some(i + 1), "a value is not finite"));
        }
        if let Some(v) = [x, y, z].into_iter().find(|v| v.abs() > MAX_POSITION_M) {
            return Err(invalid(
                file,
                Some(i + 1),
                format!("a position of {v:e} m: beyond any place on Earth (a unit or column mistake?)"),
            ));
        }
        // A quaternion q stands for the rotation of q / |q| (as other tools read it); one
        // already of unit length to rounding is used as written, so that a run's own file
        // scores to the last bit. A zero one is no rotation at all. The norm is taken of q
        // scaled by its largest component, which neither overflows nor underflows.
        let largest = [qx, qy, qz, qw].iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if largest == 0.0 {
            return Err(invalid(file, Some(i + 1), "the quaternion (qx qy qz qw) is zero: it gives no heading"));
        }
        let scaled = [qx, qy, qz, qw].map(|v| v / largest);
        let scaled_norm = scaled.iter().map(|v| v * v).sum::<f64>().sqrt();
        let q =
            if (largest * scaled_norm - 1.0).abs() > 1e-9 { scaled.map(|v| v / scaled_norm) } else { [qx, qy, qz, qw] };
        if let Some((last, _)) = poses.last()
            && t <= *last
        {
            return Err(invalid(file, Some(i + 1), format!("timestamp {t} does not follow {last}")));
        }
        poses.push((t, [x, y, super::scorer::yaw_of_quaternion(q)]));
        // The body's z axis against the world's: cos(tilt) = 1 - 2 (qx² + qy²).
        let tilt = (1.0 - 2.0 * (q[0] * q[0] + q[1] * q[1])).clamp(-1.0, 1.0).acos().to_degrees();
        off_plane.max_abs_z_m = off_plane.max_abs_z_m.max(z.abs());
        off_plane.max_tilt_deg = off_plane.max_tilt_deg.max(tilt);
    }
    if poses.is_empty() {
        return Err(invalid(file, None, "no pose"));
    }
    Ok((poses, off_plane))
}

/// The columns of a covariance file: the pose covariance's lower triangle (x, y, heading;
/// the heading in radians), named as its upper one, which a symmetric matrix shares.
const COVARIANCE_COLUMNS: &[&str] = &["t", "xx", "xy", "xtheta", "yy", "ytheta", "thetatheta"];

/// A row of a covariance file: its line, time and covariance.
pub(super) type CovarianceRow = (usize, f64, [[f64; 3]; 3]);

/// A pose covariance per time, in time order.
pub(super) fn read_covariances(file: &Path) -> Result<Vec<CovarianceRow>, ScoreError> {
    let (_, rows) = read_csv_numbers(file, &[COVARIANCE_COLUMNS])?;
    let mut out: Vec<CovarianceRow> = Vec::new();
    for (line, row) in rows {
        let Some(v) = row.iter().copied().collect::<Option<Vec<f64>>>() else {
            return Err(invalid(file, Some(line), "an empty cell"));
        };
        if let Some((_, last, _)) = out.last()
            && v[0] <= *last
        {
            return Err(invalid(file, Some(line), format!("timestamp {} does not follow {last}", v[0])));
        }
        let p = [[v[1], v[2], v[3]], [v[2], v[4], v[5]], [v[3], v[5], v[6]]];
        out.push((line, v[0], p));
    }
    Ok(out)
}

/// A covariance row of a pose: `t,xx,xy,xtheta,yy,ytheta,thetatheta` from the lower
/// triangle, each number with the digits that read back the same `f64`.
pub fn covariance_line(t: f64, p: &[[f64; 3]; 3]) -> String {
    format!("{t},{},{},{},{},{},{}", p[0][0], p[1][0], p[2][0], p[1][1], p[2][1], p[2][2])
}

/// The header of a covariance file.
pub fn covariance_header() -> String {
    COVARIANCE_COLUMNS.join(",")
}

/// What a system did with one scan: its observations of it, each with the landmark it
/// went to, and the fusions it made after it.
#[derive(Debug)]
pub(super) struct ScanAssociations {
    /// The file's line where the scan's entries start.
    pub line: usize,
    pub t: f64,
    pub observations: Observations,
    pub fusions: Vec<Fusion>,
}

/// A scan's observations, given by their beams or by their ids in the log's
/// `observations.jsonl` (the index in the scan's list).
#[derive(Debug)]
pub(super) enum Observations {
    Beams(Vec<ScoredObservation>),
    /// (line, observation id, landmark).
    Ids(Vec<(usize, usize, Option<u32>)>),
}

/// A line of the beams form: a scan's observations by their beams, and its fusions.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct BeamsLine {
    t: f64,
    observations: Vec<ScoredObservation>,
    #[serde(default)]
    fusions: Vec<Fusion>,
}

/// A line of the decision form (as `decisions.jsonl` writes it): one observation, by its id
/// within the scan, and the landmark it went to.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DecisionLine {
    t: f64,
    observation: usize,
    #[serde(default)]
    landmark: Option<u32>,
    /// The landmark as `decisions.jsonl` gives it: `new` or `existing` name one.
    #[serde(default)]
    choice: Option<slam::association::Choice>,
    // What decisions.jsonl writes beside them, which scoring does not read.
    #[serde(default, rename = "candidates")]
    _candidates: serde::de::IgnoredAny,
    #[serde(default, rename = "method")]
    _method: serde::de::IgnoredAny,
    #[serde(default, rename = "true_object")]
    _true_object: serde::de::IgnoredAny,
}

impl DecisionLine {
    fn landmark(&self) -> Result<Option<u32>, String> {
        use slam::association::Choice;
        let chosen = match self.choice {
            Some(Choice::New { landmark } | Choice::Existing { landmark }) => Some(landmark),
            _ => None,
        };
        match (self.landmark, self.choice) {
            (Some(a), Some(_)) if chosen.is_none() => {
                Err(format!("`landmark` {a} beside a `choice` that names no landmark (rejected or deferred)"))
            }
            (Some(a), Some(_)) if chosen != Some(a) => {
                Err(format!("`landmark` {a} and `choice`'s landmark {} disagree", chosen.expect("checked above")))
            }
            (Some(a), _) => Ok(Some(a)),
            (None, _) => Ok(chosen),
        }
    }
}

/// A fusion line of the decision form: after the scan at `t`, `removed` was fused into `kept`.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FusionLine {
    t: f64,
    fusion: Fusion,
}

/// Refuses a map and associations that cannot be one system's: every landmark of a map was
/// made from an observation associated with it (or kept when another was fused into it),
/// so a mapped landmark that no association names means the files do not belong together
/// (another run's, or ids renumbered in one of them). Associations may name landmarks the
/// map lacks: systems drop tentative landmarks that were never confirmed.
pub(super) fn check_map_is_associated(
    map_file: &Path,
    map: &[MapLandmark],
    associations_file: &Path,
    scans: &[ScanAssociations],
) -> Result<(), ScoreError> {
    let mut named = std::collections::HashSet::new();
    for scan in scans {
        match &scan.observations {
            Observations::Beams(o) => named.extend(o.iter().filter_map(|o| o.landmark)),
            Observations::Ids(o) => named.extend(o.iter().filter_map(|&(_, _, landmark)| landmark)),
        }
        named.extend(scan.fusions.iter().flat_map(|f| [f.kept, f.removed]));
    }
    // A landmark fused away is no longer in the map: the map that holds one is of an
    // earlier moment than the associations.
    let fused_away: std::collections::HashMap<u32, usize> =
        scans.iter().flat_map(|scan| scan.fusions.iter().map(|f| (f.removed, scan.line))).collect();
    if let Some((id, line)) = map.iter().find_map(|l| fused_away.get(&l.id).map(|&line| (l.id, line))) {
        return Err(invalid(
            map_file,
            None,
            format!(
                "landmark {id} of the map was fused away at {}:{line}: the two files are not one run's",
                associations_file.display()
            ),
        ));
    }
    let unnamed: Vec<u32> = map.iter().map(|l| l.id).filter(|id| !named.contains(id)).collect();
    match unnamed.first() {
        None => Ok(()),
        Some(first) => Err(invalid(
            map_file,
            None,
            format!(
                "landmark {first}{} of the map is named by no association in {}: a mapped landmark comes from observations associated with it, so the two files are not one run's",
                match unnamed.len() {
                    1 => String::new(),
                    n => format!(" (and {} more)", n - 1),
                },
                associations_file.display()
            ),
        )),
    }
}

/// One entry of an associations file, before entries are grouped by scan.
enum AssociationEntry {
    Beams(Vec<ScoredObservation>, Vec<Fusion>),
    Decision(usize, Option<u32>),
    Fusion(Fusion),
}

/// The scans of an associations file (JSON lines, or CSV when its name ends in `.csv`), in
/// time order; entries of one scan share its time (to 1 us).
pub(super) fn read_associations(file: &Path) -> Result<Vec<ScanAssociations>, ScoreError> {
    let entries = if file.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv")) {
        read_association_csv(file)?
    } else {
        read_association_lines(file)?
    };
    if entries.is_empty() {
        return Err(invalid(file, None, "no entry (to score without associations, leave --associations out)"));
    }
    let mut scans: Vec<ScanAssociations> = Vec::new();
    for (line, t, entry) in entries {
        if !t.is_finite() {
            return Err(invalid(file, Some(line), "the time is not finite"));
        }
        let fusions = match &entry {
            AssociationEntry::Beams(_, f) => &f[..],
            AssociationEntry::Fusion(f) => std::slice::from_ref(f),
            AssociationEntry::Decision(..) => &[],
        };
        if let Some(f) = fusions.iter().find(|f| f.kept == f.removed) {
            return Err(invalid(file, Some(line), format!("landmark {} fused into itself", f.kept)));
        }
        let same_scan = scans.last().is_some_and(|s| (t - s.t).abs() < 1e-6);
        if let Some(last) = scans.last()
            && !same_scan
            && t < last.t
        {
            return Err(invalid(file, Some(line), format!("scan time {t} does not follow {}", last.t)));
        }
        if !same_scan {
            let (observations, fusions) = match entry {
                AssociationEntry::Beams(o, f) => (Observations::Beams(o), f),
                AssociationEntry::Decision(id, landmark) => (Observations::Ids(vec![(line, id, landmark)]), vec![]),
                AssociationEntry::Fusion(f) => (Observations::Ids(vec![]), vec![f]),
            };
            scans.push(ScanAssociations { line, t, observations, fusions });
            continue;
        }
        let scan = scans.last_mut().expect("same scan");
        match (entry, &mut scan.observations) {
            (AssociationEntry::Beams(..), _) => {
                return Err(invalid(
                    file,
                    Some(line),
                    format!("a second entry for the scan at t = {t} s (a line by beams holds the whole scan)"),
                ));
            }
            (AssociationEntry::Decision(..), Observations::Beams(_)) => {
                return Err(invalid(file, Some(line), "observations by id and by beams for one scan"));
            }
            (AssociationEntry::Decision(..), Observations::Ids(_)) if !scan.fusions.is_empty() => {
                return Err(invalid(file, Some(line), "an observation after its scan's fusions"));
            }
            (AssociationEntry::Decision(id, landmark), Observations::Ids(all)) => all.push((line, id, landmark)),
            (AssociationEntry::Fusion(f), _) => scan.fusions.push(f),
        }
    }
    Ok(scans)
}

/// JSON lines: `{"t", "observations": [...], "fusions": [...]}` (beams), or one decision
/// `{"t", "observation", "landmark" | "choice"}` or fusion `{"t", "fusion"}` per line.
fn read_association_lines(file: &Path) -> Result<Vec<(usize, f64, AssociationEntry)>, ScoreError> {
    let mut entries = Vec::new();
    // The line each landmark was first named on.
    let mut named_at: std::collections::HashMap<u32, usize> = std::collections::HashMap::new();
    let text = read_text(file)?;
    // A byte-order mark, as some editors write, read past as in the other inputs.
    for (n, line) in numbered_lines(text.strip_prefix('\u{feff}').unwrap_or(&text)) {
        let bad = |e: serde_json::Error| invalid(file, Some(n), e.to_string());
        let v: serde_json::Value = serde_json::from_str(line).map_err(|e| {
            invalid(
                file,
                Some(n),
                format!("{e} (read as JSON lines, its name not ending in .csv: CSV associations go in a .csv file)"),
            )
        })?;
        let entry = if v.get("observations").is_some() {
            let b: BeamsLine = serde_json::from_value(v).map_err(bad)?;
            (b.t, AssociationEntry::Beams(b.observations, b.fusions))
        } else if v.get("observation").is_some() {
            // A choice that names no landmark holds nothing beside its kind: a landmark
            // there contradicts it (serde passes over keys beside a unit variant's tag).
            if let Some(choice) = v.get("choice").and_then(|c| c.as_object())
                && matches!(choice.get("kind").and_then(|k| k.as_str()), Some("rejected" | "deferred"))
                && let Some(key) = choice.keys().find(|k| *k != "kind")
            {
                return Err(invalid(
                    file,
                    Some(n),
                    format!("`choice` of kind {} names no landmark, yet holds `{key}`", choice["kind"]),
                ));
            }
            let d: DecisionLine = serde_json::from_value(v).map_err(bad)?;
            let landmark = d.landmark().map_err(|m| invalid(file, Some(n), m))?;
            // A new landmark is new once: an id named before is another system's numbering,
            // or two files joined.
            if let Some(slam::association::Choice::New { landmark: id }) = d.choice
                && let Some(first) = named_at.get(&id)
            {
                return Err(invalid(
                    file,
                    Some(n),
                    format!("landmark {id} is chosen as new, but line {first} named it before"),
                ));
            }
            if let Some(id) = landmark {
                named_at.entry(id).or_insert(n);
            }
            (d.t, AssociationEntry::Decision(d.observation, landmark))
        } else if v.get("fusion").is_some() {
            let f: FusionLine = serde_json::from_value(v).map_err(bad)?;
            (f.t, AssociationEntry::Fusion(f.fusion))
        } else {
            let keys: Vec<String> = v.as_object().map_or(vec![], |o| o.keys().map(|k| format!("`{k}`")).collect());
            return Err(invalid(
                file,
                Some(n),
                format!(
                    "keys {}: a line needs `observations` (by beams), `observation` (by id) or `fusion`",
                    keys.join(", ")
                ),
            ));
        };
        entries.push((n, entry.0, entry.1));
    }
    Ok(entries)
}

fn csv_invalid(file: &Path, e: csv::Error) -> ScoreError {
    let line = e.position().map(|p| p.line() as usize);
    let problem = robotlog::format::csv_problem(&e);
    match e.into_kind() {
        csv::ErrorKind::Io(error) => ScoreError::Io { file: file.to_path_buf(), error },
        _ => invalid(file, line, problem),
    }
}

/// A CSV row: its line and its numbers (an empty cell is `None`).
type CsvRow = (usize, Vec<Option<f64>>);

/// A CSV file's rows, and which of `headers` it has.
fn read_csv_numbers(file: &Path, headers: &[&[&str]]) -> Result<(usize, Vec<CsvRow>), ScoreError> {
    let blank = robotlog::format::blank_line_before_last_row(file)
        .map_err(|error| ScoreError::Io { file: file.to_path_buf(), error })?;
    if let Some(line) = blank {
        return Err(invalid(file, Some(line as usize), "a blank line before the last row"));
    }
    let opened = std::fs::File::open(file).map_err(|error| ScoreError::Io { file: file.to_path_buf(), error })?;
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .trim(csv::Trim::All)
        .from_reader(robotlog::line_ends::LfLineEnds::new(opened));
    let found: Vec<String> = reader.headers().map_err(|e| csv_invalid(file, e))?.iter().map(str::to_string).collect();
    let which = headers.iter().position(|h| h.iter().eq(found.iter())).ok_or_else(|| {
        let expected: Vec<String> = headers.iter().map(|h| format!("`{}`", h.join(","))).collect();
        invalid(file, Some(1), format!("header `{}`; expected {}", found.join(","), expected.join(" or ")))
    })?;
    let mut rows = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| csv_invalid(file, e))?;
        let line = record.position().map_or(0, |p| p.line() as usize);
        let values = record
            .iter()
            .zip(headers[which])
            .map(|(cell, name)| match cell {
                "" => Ok(None),
                _ => cell
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .map(Some)
                    .ok_or_else(|| invalid(file, Some(line), format!("`{name}`: `{cell}` is not a finite number"))),
            })
            .collect::<Result<Vec<_>, _>>()?;
        rows.push((line, values));
    }
    Ok((which, rows))
}

/// A whole non-negative number from a CSV cell.
fn csv_count(file: &Path, line: usize, name: &str, v: Option<f64>) -> Result<usize, ScoreError> {
    v.filter(|v| *v >= 0.0 && v.fract() == 0.0 && *v <= u32::MAX as f64)
        .map(|v| v as usize)
        .ok_or_else(|| invalid(file, Some(line), format!("`{name}` must be a whole number, 0 or more")))
}

const CSV_BY_BEAMS: &[&str] = &["t", "first_beam", "last_beam", "landmark"];
const CSV_BY_ID: &[&str] = &["t", "observation", "landmark"];

/// CSV: `t,first_beam,last_beam,landmark` or `t,observation,landmark`, a row per
/// observation (an empty `landmark`: none). Fusions need the JSON-lines form.
fn read_association_csv(file: &Path) -> Result<Vec<(usize, f64, AssociationEntry)>, ScoreError> {
    let (form, rows) = read_csv_numbers(file, &[CSV_BY_BEAMS, CSV_BY_ID])?;
    let mut entries: Vec<(usize, f64, AssociationEntry)> = Vec::new();
    for (line, row) in rows {
        let t = row[0].ok_or_else(|| invalid(file, Some(line), "`t` is empty"))?;
        let landmark = match row[row.len() - 1] {
            None => None,
            v => Some(csv_count(file, line, "landmark", v)? as u32),
        };
        if form == 0 {
            let o = ScoredObservation {
                first_beam: csv_count(file, line, "first_beam", row[1])?,
                last_beam: csv_count(file, line, "last_beam", row[2])?,
                landmark,
            };
            // Rows of one scan make its one entry.
            match entries.last_mut() {
                Some((_, last_t, AssociationEntry::Beams(all, _))) if (*last_t - t).abs() < 1e-6 => all.push(o),
                _ => entries.push((line, t, AssociationEntry::Beams(vec![o], vec![]))),
            }
        } else {
            entries.push((
                line,
                t,
                AssociationEntry::Decision(csv_count(file, line, "observation", row[1])?, landmark),
            ));
        }
    }
    Ok(entries)
}

/// A map: JSON (`[{"id", "position": [x, y]}]`, other keys ignored) or CSV (`id,x,y`).
pub(super) fn read_landmarks(file: &Path) -> Result<Vec<MapLandmark>, ScoreError> {
    let landmarks: Vec<MapLandmark> = if file.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv")) {
        let (_, rows) = read_csv_numbers(file, &[&["id", "x", "y"]])?;
        rows.into_iter()
            .map(|(line, row)| {
                let id = csv_count(file, line, "id", row[0])? as u32;
                let (Some(x), Some(y)) = (row[1], row[2]) else {
                    return Err(invalid(file, Some(line), "`x` and `y` are needed"));
                };
                Ok(MapLandmark { id, position: [x, y] })
            })
            .collect::<Result<_, _>>()?
    } else {
        // A byte-order mark (some editors' UTF-8) is read past, as in TUM and CSV files.
        let text = read_text(file)?;
        slam::settings::from_json(text.strip_prefix('\u{feff}').unwrap_or(&text)).map_err(|e| {
            invalid(
                file,
                None,
                format!("{e} (read as JSON, its name not ending in .csv: a CSV map is `id,x,y` in a .csv file)"),
            )
        })?
    };
    let mut seen = std::collections::HashSet::new();
    for l in &landmarks {
        if !l.position.iter().all(|v| v.is_finite()) {
            return Err(invalid(file, None, format!("landmark {}: position is not finite", l.id)));
        }
        // As for poses: a distance to an object must square without overflow.
        if let Some(v) = l.position.iter().find(|v| v.abs() > MAX_POSITION_M) {
            return Err(invalid(
                file,
                None,
                format!(
                    "landmark {}: a position of {v:e} m: beyond any place on Earth (a unit or column mistake?)",
                    l.id
                ),
            ));
        }
        if !seen.insert(l.id) {
            return Err(invalid(file, None, format!("landmark id {} appears twice", l.id)));
        }
    }
    Ok(landmarks)
}

/// Why beams `first..=last` are no observation of `scan`, if they are not.
pub(super) fn beams_outside(first: usize, last: usize, scan: &sim::LaserScan) -> Option<String> {
    if first > last {
        return Some(format!("beams {first}..={last}: the first beam comes after the last"));
    }
    (last >= scan.ranges.len())
        .then(|| format!("beams {first}..={last} are not within the scan's {} beams", scan.ranges.len()))
}

/// A scan's observations as the scorer takes them: given by beams, checked against the
/// scan; given by id, looked up in the log's observations of the scan.
pub(super) fn scan_observations(
    file: &Path,
    a: &ScanAssociations,
    scan: &sim::LaserScan,
    log_observations: &[(usize, usize)],
    observations_file: &Path,
) -> Result<Vec<ScoredObservation>, ScoreError> {
    match &a.observations {
        Observations::Beams(all) => {
            if let Some(problem) = all.iter().find_map(|o| beams_outside(o.first_beam, o.last_beam, scan)) {
                return Err(invalid(file, Some(a.line), problem));
            }
            // One beam is one return, so it belongs to one observation at most: a scan's
            // observations listed twice, or overlapping, would count associations twice.
            let mut spans: Vec<(usize, usize)> = all.iter().map(|o| (o.first_beam, o.last_beam)).collect();
            spans.sort_unstable();
            if let Some(w) = spans.windows(2).find(|w| w[1].0 <= w[0].1) {
                return Err(invalid(
                    file,
                    Some(a.line),
                    format!(
                        "beams {}..={} and {}..={} overlap: a beam belongs to one observation of a scan at most",
                        w[0].0, w[0].1, w[1].0, w[1].1
                    ),
                ));
            }
            Ok(all.clone())
        }
        Observations::Ids(ids) => {
            let mut sorted = ids.clone();
            sorted.sort_by_key(|(_, id, _)| *id);
            if let Some(w) = sorted.windows(2).find(|w| w[0].1 == w[1].1) {
                return Err(invalid(file, Some(w[1].0), format!("observation {} of this scan a second time", w[1].1)));
            }
            sorted
                .into_iter()
                .map(|(line, id, landmark)| match log_observations.get(id) {
                    Some(&(first_beam, last_beam)) => Ok(ScoredObservation { first_beam, last_beam, landmark }),
                    None => Err(invalid(
                        file,
                        Some(line),
                        format!(
                            "observation {id}: the scan at t = {} s has {} ({})",
                            scan.t,
                            log_observations.len(),
                            observations_file.display()
                        ),
                    )),
                })
                .collect()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decisions_and_fusions_group_by_scan_and_out_of_order_entries_are_errors() {
        let dir = std::env::temp_dir().join(format!("objslam-assoc-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("decisions.jsonl");
        let read = |text: &str| {
            std::fs::write(&file, text).unwrap();
            read_associations(&file).map_err(|e| e.to_string())
        };
        let scans = read(concat!(
            r#"{"t": 0.1, "observation": 1, "choice": {"kind": "new", "landmark": 5}, "candidates": [], "method": "nn", "true_object": 3}"#,
            "\n",
            r#"{"t": 0.1, "observation": 0, "landmark": 2}"#,
            "\n",
            r#"{"t": 0.1, "fusion": {"kept": 2, "removed": 5}}"#,
            "\n",
            r#"{"t": 0.2, "observation": 0, "choice": {"kind": "rejected"}}"#,
            "\n"
        ))
        .unwrap();
        assert_eq!(scans.len(), 2);
        let Observations::Ids(first) = &scans[0].observations else { panic!("by id") };
        assert_eq!(first, &[(1, 1, Some(5)), (2, 0, Some(2))]);
        assert_eq!(scans[0].fusions, [Fusion { kept: 2, removed: 5 }]);
        let Observations::Ids(second) = &scans[1].observations else { panic!("by id") };
        assert_eq!(second, &[(4, 0, None)]);

        let e = read(
            "{\"t\": 0.1, \"fusion\": {\"kept\": 2, \"removed\": 5}}\n{\"t\": 0.1, \"observation\": 0, \"landmark\": 2}\n",
        );
        assert!(e.as_ref().is_err_and(|e| e.contains(":2") && e.contains("after its scan's fusions")), "{e:?}");
        let e = read(
            "{\"t\": 0.2, \"observation\": 0, \"landmark\": 2}\n{\"t\": 0.1, \"observation\": 0, \"landmark\": 2}\n",
        );
        assert!(e.as_ref().is_err_and(|e| e.contains(":2") && e.contains("does not follow")), "{e:?}");
        let e = read("{\"t\": 0.1, \"observations\": []}\n{\"t\": 0.1, \"observations\": []}\n");
        assert!(e.as_ref().is_err_and(|e| e.contains(":2") && e.contains("second entry")), "{e:?}");
        let e = read("{\"t\": 0.1, \"fusion\": {\"kept\": 4, \"removed\": 4}}\n");
        assert!(e.as_ref().is_err_and(|e| e.contains(":1") && e.contains("into itself")), "{e:?}");
        let e = read("\n");
        assert!(e.as_ref().is_err_and(|e| e.contains("no entry")), "{e:?}");
        let e = read("{\"t\": 0.1, \"observation\": 0, \"landmark\": 3, \"choice\": {\"kind\": \"rejected\"}}\n");
        assert!(e.as_ref().is_err_and(|e| e.contains(":1") && e.contains("names no landmark")), "{e:?}");
        let e = read(
            "{\"t\": 0.1, \"observation\": 0, \"landmark\": 3, \"choice\": {\"kind\": \"new\", \"landmark\": 4}}\n",
        );
        assert!(e.as_ref().is_err_and(|e| e.contains("`landmark` 3 and `choice`'s landmark 4 disagree")), "{e:?}");
        let e = read("t,observation,landmark\n0.1,0,2\n");
        assert!(e.as_ref().is_err_and(|e| e.contains(":1") && e.contains("its name not ending in .csv")), "{e:?}");
        let e = read("{\"t\": 0.1, \"observation\": 0, \"landmark\": 2, \"weight\": 1}\n");
        assert!(e.as_ref().is_err_and(|e| e.contains(":1") && e.contains("weight")), "{e:?}");
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A quaternion at any scale is its rotation: neither 1e155 times a unit one (whose
    /// squared norm overflows) nor 1e-6 times one is misread or refused.
    #[test]
    fn a_quaternion_is_read_at_any_scale() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("scaled.tum");
        let (s, c) = (0.3f64.sin(), 0.3f64.cos()); // a heading of 0.6 rad
        for scale in [1.0, 1e155, 1e-6, 1e-300] {
            std::fs::write(&file, format!("0 1 2 0 0 0 {} {}\n", s * scale, c * scale)).unwrap();
            let poses = read_tum(&file).unwrap();
            assert!((poses[0].1[2] - 0.6).abs() < 1e-12, "scale {scale}: heading {}", poses[0].1[2]);
        }
        std::fs::write(&file, "0 1 2 0 0 0 0 0\n").unwrap();
        assert!(read_tum(&file).unwrap_err().to_string().contains("is zero"));
    }

    #[test]
    fn a_tum_file_with_a_bad_line_is_an_error_naming_the_line() {
        let dir = std::env::temp_dir().join(format!("objslam-tum-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("bad.tum");
        std::fs::write(&file, "# t x y z qx qy qz qw\n0 0 0 0 0 0 0 1\n1 2 3\n").unwrap();
        let e = read_tum(&file).unwrap_err().to_string();
        assert!(e.contains("bad.tum:3") && e.contains("3 values"), "{e}");
        std::fs::write(&file, "1 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n").unwrap();
        let e = read_tum(&file).unwrap_err().to_string();
        assert!(e.contains("bad.tum:2") && e.contains("does not follow"), "{e}");
        std::fs::write(&file, "0 1.5 -2 0 0 0 0.7071067811865476 0.7071067811865476\n").unwrap();
        let poses = read_tum(&file).unwrap();
        assert_eq!(poses[0].1[0..2], [1.5, -2.0]);
        assert!((poses[0].1[2] - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        // A scaled quaternion is the rotation of its unit one.
        std::fs::write(&file, "0 0 0 0 0 0 0.001 0.001\n").unwrap();
        assert!((read_tum(&file).unwrap()[0].1[2] - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        std::fs::write(&file, "0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 0\n").unwrap();
        let e = read_tum(&file).unwrap_err().to_string();
        assert!(e.contains("bad.tum:2") && e.contains("quaternion") && e.contains("zero"), "{e}");
        // A position whose errors would overflow: no ATE of infinity.
        std::fs::write(&file, "0 0 0 0 0 0 0 1\n1 1e300 0 0 0 0 0 1\n").unwrap();
        let e = read_tum(&file).unwrap_err().to_string();
        assert!(e.contains("bad.tum:2") && e.contains("beyond any place on Earth"), "{e}");
        // A map in JSON is read past a byte-order mark, as TUM and CSV files are.
        let map = dir.join("map.json");
        std::fs::write(&map, "\u{feff}[{\"id\": 1, \"position\": [1.0, 2.0]}]").unwrap();
        assert_eq!(read_landmarks(&map).unwrap()[0].position, [1.0, 2.0]);
        // And associations in JSON lines (refused at line 1 before).
        let lines = dir.join("assoc.jsonl");
        std::fs::write(
            &lines,
            "\u{feff}{\"t\": 0.1, \"observation\": 0, \"choice\": {\"kind\": \"new\", \"landmark\": 3}}\n",
        )
        .unwrap();
        assert_eq!(read_associations(&lines).unwrap().len(), 1);
        // Regression: a landmark whose distances overflow to infinity hung the scoring.
        std::fs::write(&map, r#"[{"id": 1, "position": [1.0, 2.0]}, {"id": 7, "position": [1e200, 0]}]"#).unwrap();
        let e = read_landmarks(&map).unwrap_err().to_string();
        assert!(e.contains("map.json") && e.contains("landmark 7") && e.contains("beyond any place on Earth"), "{e}");
        // A CSV cell that is not text is said so, not dumped as the reader's error value.
        let csv = dir.join("assoc.csv");
        std::fs::write(&csv, b"t,observation,landmark\n0.1,0,3\n0.2,\xff,4\n").unwrap();
        let e = read_associations(&csv).unwrap_err().to_string();
        assert!(e.contains("assoc.csv:3") && e.contains("field 2 is not UTF-8 text"), "{e}");
        // A blank line where a row was is not skipped without a word.
        std::fs::write(&csv, "t,observation,landmark\n0.1,0,3\n\n0.3,0,4\n").unwrap();
        let e = read_associations(&csv).unwrap_err().to_string();
        assert!(e.contains("assoc.csv:3") && e.contains("a blank line before the last row"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn a_map_landmark_no_association_names_is_an_error_and_unmapped_ids_are_not() {
        let scan = |t: f64, ids: Vec<Option<u32>>, fusions: Vec<Fusion>| ScanAssociations {
            line: 1,
            t,
            observations: Observations::Ids(ids.into_iter().enumerate().map(|(k, l)| (1, k, l)).collect()),
            fusions,
        };
        let scans = [
            scan(0.1, vec![Some(0), Some(1), None], vec![]),
            scan(0.2, vec![Some(7)], vec![Fusion { kept: 0, removed: 1 }]),
        ];
        let map = |ids: &[u32]| ids.iter().map(|&id| MapLandmark { id, position: [0.0; 2] }).collect::<Vec<_>>();
        let (m, a) = (Path::new("map.json"), Path::new("assoc.jsonl"));
        // 7 was never confirmed: associations may name landmarks the map lacks.
        check_map_is_associated(m, &map(&[0]), a, &scans).unwrap();
        let e = check_map_is_associated(m, &map(&[0, 100_000, 100_001]), a, &scans).unwrap_err().to_string();
        assert!(
            e.contains("map.json") && e.contains("landmark 100000 (and 1 more)") && e.contains("assoc.jsonl"),
            "{e}"
        );
        // A map that still holds a landmark the associations fused away.
        let e = check_map_is_associated(m, &map(&[0, 1]), a, &scans).unwrap_err().to_string();
        assert!(e.contains("map.json") && e.contains("landmark 1 of the map was fused away at assoc.jsonl:1"), "{e}");
    }
}
