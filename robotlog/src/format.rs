//! The log directory: `manifest.toml`, `odometry.csv`, one of `scans.csv` and
//! `detections.csv`, and optionally `camera.csv` (with the images it lists) and
//! `reference.csv`. Plain CSV with a header row, SI units,
//! times in seconds on one clock; docs/reference/robot-log.md describes every column.
//!
//! Reading checks everything the pipeline would otherwise take on trust: the header, the
//! number of columns, numbers that parse and are finite where they must be, and times that
//! never go back. Each error names the file and the line.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use slam::messages::{Control, Detection, LaserScan, OdometryIncrement};

use crate::line_ends::LfLineEnds;
use crate::stream::{LogStream, MotionMessage, ObservationMessage, Reread, Rows as RowsOf};
use crate::{CameraFrameFile, DetectionScan, Log, LogError, Manifest, Motion, Observations, ReferenceSample, RgbImage};

pub const MANIFEST: &str = "manifest.toml";
pub const ODOMETRY: &str = "odometry.csv";
pub const SCANS: &str = "scans.csv";
pub const DETECTIONS: &str = "detections.csv";
pub const REFERENCE: &str = "reference.csv";
pub const CAMERA: &str = "camera.csv";

/// Reads the whole log in `dir`, checking every file (see [`open`] for a log read as it is
/// replayed).
pub fn read(dir: &Path) -> Result<Log, LogError> {
    let mut parts = open_parts(dir)?;
    let increments = parts.motion.rows.header == 0;
    // The observations first: the first increment is the motion since the log's start.
    let observations = match parts.observations {
        ObservationRows::Scans(rows) => Observations::Scans(rows.collect::<Result<Vec<_>, _>>()?),
        ObservationRows::Detections(rows) => Observations::Detections(rows.collect::<Result<Vec<_>, _>>()?),
    };
    parts.motion.first_observation_t = match &observations {
        Observations::Scans(v) => v.first().map(|s| s.t),
        Observations::Detections(v) => v.first().map(|d| d.t),
    };
    let messages = parts.motion.collect::<Result<Vec<_>, _>>()?;
    let motion = if increments {
        Motion::Increments(messages.into_iter().filter_map(MotionMessage::into_increment).collect())
    } else {
        Motion::Controls(messages.into_iter().filter_map(MotionMessage::into_control).collect())
    };
    let (reference, camera) = (parts.reference.collect()?, parts.camera.collect()?);
    Ok(Log { manifest: parts.manifest, motion, observations, reference, camera })
}

/// Opens the log in `dir` to be read as it is replayed: the manifest, the reference and
/// the camera's frame list are read and checked now (the last two read again when a replay
/// needs them: see [`Reread`]); the motion and the observations a message at a time, a
/// fault in them arriving as an error in the message's place.
pub fn open(dir: &Path) -> Result<LogStream, LogError> {
    let mut parts = open_parts(dir)?;
    let observations: Box<dyn Iterator<Item = Result<ObservationMessage, LogError>>> = match parts.observations {
        ObservationRows::Scans(rows) => Box::new(until_error(rows.map(|s| s.map(ObservationMessage::Scan)))),
        ObservationRows::Detections(rows) => Box::new(until_error(rows.map(|d| d.map(ObservationMessage::Detections)))),
    };
    let mut observations = observations.peekable();
    // A fault in the first observation is left in its place, for the reader to meet
    // first (a replay peeks the observations before the motion).
    parts.motion.first_observation_t = match observations.peek() {
        Some(Ok(m)) => Some(m.time()),
        _ => None,
    };
    let motion: Box<dyn Iterator<Item = Result<MotionMessage, LogError>>> = Box::new(until_error(parts.motion));
    Ok(LogStream {
        manifest: parts.manifest,
        reference: parts.reference,
        camera: parts.camera,
        motion: motion.peekable(),
        observations,
    })
}

/// `messages` up to and including their first error: a file's rows after a fault are not
/// read as if nothing had happened.
fn until_error<T>(messages: impl Iterator<Item = Result<T, LogError>>) -> impl Iterator<Item = Result<T, LogError>> {
    let mut failed = false;
    messages.map_while(move |m| {
        if failed {
            return None;
        }
        failed = m.is_err();
        Some(m)
    })
}

/// A log with its data files opened, their headers checked.
struct OpenLog {
    manifest: Manifest,
    motion: MotionRows,
    observations: ObservationRows,
    reference: Reread<ReferenceSample>,
    camera: Reread<CameraFrameFile>,
}

enum ObservationRows {
    Scans(ScanRows),
    Detections(DetectionRows),
}

/// Refuses a `dir` that is no directory, saying which: a log (or a data set as published)
/// is a directory of files, and a file named inside it would hide what is wrong.
pub(crate) fn check_dir(dir: &Path, what: &str) -> Result<(), LogError> {
    match std::fs::metadata(dir) {
        Ok(m) if m.is_dir() => Ok(()),
        Ok(_) => Err(LogError::File { file: dir.to_path_buf(), problem: format!("not a directory: {what}") }),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            Err(LogError::File { file: dir.to_path_buf(), problem: format!("no such directory: {what}") })
        }
        // Permission denied and the like: the directory may well be there.
        Err(source) => Err(LogError::Io { file: dir.to_path_buf(), source }),
    }
}

/// Whether the log holds `file`: a name that is there but cannot be followed (a link to
/// nothing, a directory that may not be searched) is an error that says so, not a file
/// the log lacks.
fn present(file: &Path) -> Result<bool, LogError> {
    match std::fs::symlink_metadata(file) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(false),
        Err(source) => Err(LogError::Io { file: file.to_path_buf(), source }),
        Ok(_) => match std::fs::metadata(file) {
            Ok(_) => Ok(true),
            Err(e) => Err(LogError::File {
                file: file.to_path_buf(),
                problem: format!("is there but cannot be read: {e} (a link to nothing?)"),
            }),
        },
    }
}

fn open_parts(dir: &Path) -> Result<OpenLog, LogError> {
    check_dir(dir, "a robot log is a directory holding manifest.toml (docs/reference/robot-log.md)")?;
    let manifest = read_manifest(&dir.join(MANIFEST))?;
    let motion = open_motion(&dir.join(ODOMETRY), &manifest)?;
    let (scans, detections) = (dir.join(SCANS), dir.join(DETECTIONS));
    let observations = match (present(&scans)?, present(&detections)?) {
        (true, false) => {
            let Some(laser) = &manifest.laser else {
                return Err(LogError::File {
                    file: dir.join(MANIFEST),
                    problem: "scans.csv needs a [laser] table with the beams' geometry".into(),
                });
            };
            let rows = Rows::open(&scans, &[&["t", "..."]])?;
            if rows.names.len() < 2 {
                return Err(LogError::Line { file: scans, line: 1, problem: "no beam column after `t`".into() });
            }
            // The beams sweep at most a turn: more is an increment in degrees, or too many beams.
            let sweep = laser.angle_increment_rad.abs() * (rows.names.len() - 2) as f64;
            if sweep > std::f64::consts::TAU + 1e-9 {
                return Err(LogError::File {
                    file: dir.join(MANIFEST),
                    problem: format!(
                        "laser.angle_increment_rad {} over the {} beams of scans.csv sweeps {sweep:.2} rad, more than a turn",
                        laser.angle_increment_rad,
                        rows.names.len() - 1
                    ),
                });
            }
            ObservationRows::Scans(ScanRows { rows, laser: laser.clone() })
        }
        (false, true) if manifest.laser.is_some() => {
            return Err(LogError::File {
                file: dir.join(MANIFEST),
                problem:
                    "a [laser] table describes scans.csv's beams, but this log holds detections.csv: remove the table"
                        .into(),
            });
        }
        (false, true) => ObservationRows::Detections(DetectionRows {
            rows: Rows::open(&detections, &[DETECTION_COLUMNS])?,
            pending: None,
        }),
        (true, true) => {
            return Err(LogError::File {
                file: dir.to_path_buf(),
                problem: "holds both scans.csv and detections.csv: keep one".into(),
            });
        }
        (false, false) => {
            return Err(LogError::Missing {
                dir: dir.to_path_buf(),
                what: "scans.csv or detections.csv",
                expected: "what the range sensor saw",
            });
        }
    };
    let reference_file = dir.join(REFERENCE);
    let reference = if present(&reference_file)? {
        if manifest.reference.is_none() {
            return Err(LogError::File {
                file: dir.join(MANIFEST),
                problem: "reference.csv is there but no [reference] table says what it holds".into(),
            });
        }
        Reread::checked(&reference_file, reference_rows)?
    } else if manifest.reference.is_some() {
        return Err(LogError::File {
            file: dir.join(MANIFEST),
            problem: "a [reference] table, but no reference.csv holds the samples".into(),
        });
    } else {
        Reread::in_memory(Vec::new())
    };
    let camera_file = dir.join(CAMERA);
    let camera = match (present(&camera_file)?, &manifest.camera) {
        (true, Some(_)) => Reread::checked(&camera_file, camera_rows)?,
        (true, None) => {
            return Err(LogError::File {
                file: dir.join(MANIFEST),
                problem: "camera.csv is there but no [camera] table gives the camera's intrinsics and mounting".into(),
            });
        }
        (false, Some(_)) => {
            return Err(LogError::File {
                file: dir.join(MANIFEST),
                problem: "a [camera] table, but no camera.csv lists its frames".into(),
            });
        }
        (false, None) => Reread::in_memory(Vec::new()),
    };
    Ok(OpenLog { manifest, motion, observations, reference, camera })
}

fn io(file: &Path) -> impl Fn(std::io::Error) -> LogError + '_ {
    move |source| LogError::Io { file: file.to_path_buf(), source }
}

/// Refuses what is not a regular file (a link to one is): a pipe or a device would block
/// or never end.
pub fn regular_file(file: &Path) -> Result<(), LogError> {
    if fs::metadata(file).map_err(io(file))?.is_file() {
        Ok(())
    } else {
        Err(LogError::File { file: file.to_path_buf(), problem: "not a regular file".into() })
    }
}

fn read_manifest(file: &Path) -> Result<Manifest, LogError> {
    regular_file(file)?;
    let text = fs::read_to_string(file).map_err(io(file))?;
    let manifest: Manifest = toml_strict::from_str(&text).map_err(|e| {
        let problem = match &e.key {
            Some(key) => format!("{key}: {}", e.message),
            None => e.message.clone(),
        };
        match e.line.map(|l| l as u64) {
            Some(line) => LogError::Line { file: file.to_path_buf(), line, problem },
            None => LogError::File { file: file.to_path_buf(), problem },
        }
    })?;
    manifest.validate().map_err(|(field, problem)| LogError::File {
        file: file.to_path_buf(),
        problem: format!("{field}: {problem}"),
    })?;
    Ok(manifest)
}

/// `text` cut to its first `max` characters, marked where cut (an error quotes a line that
/// may be megabytes long).
fn shortened(text: &str, max: usize) -> String {
    match text.char_indices().nth(max) {
        Some((at, _)) => format!("{}...", &text[..at]),
        None => text.to_string(),
    }
}

/// A row: its line in the file, its time (column 0) and its values, empty cells `None`.
type Row = (u64, f64, Vec<Option<f64>>);

/// A CSV file read a row at a time as numbers, its header checked against `expected` (one
/// of the allowed headers; `header` is its index), each row with its line.
struct Rows {
    file: PathBuf,
    reader: csv::Reader<LfLineEnds<fs::File>>,
    names: Vec<String>,
    header: usize,
    previous_t: f64,
    /// The first row, read when the file is opened (`None`: the file holds its header alone).
    first: Option<csv::StringRecord>,
}

impl Rows {
    /// Opens a file that must hold at least one row.
    fn open(file: &Path, expected: &[&[&str]]) -> Result<Rows, LogError> {
        let rows = Rows::open_maybe_empty(file, expected)?;
        if rows.first.is_none() {
            return Err(LogError::File { file: file.to_path_buf(), problem: "a header and no row".into() });
        }
        Ok(rows)
    }

    /// Opens a file that may hold its header alone (`camera.csv` of a log too short for a
    /// frame).
    fn open_maybe_empty(file: &Path, expected: &[&[&str]]) -> Result<Rows, LogError> {
        regular_file(file)?;
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(true)
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(LfLineEnds::new(fs::File::open(file).map_err(io(file))?));
        let found: Vec<String> = reader.headers().map_err(|e| csv_error(file, e))?.iter().map(str::to_string).collect();
        let header = expected
            .iter()
            .position(|h| h.len() == found.len() && h.iter().zip(&found).all(|(a, b)| a == b))
            .or_else(|| {
                // scans.csv: `t` then one column per beam, named freely.
                (expected.len() == 1 && expected[0] == ["t", "..."] && found.first().is_some_and(|f| f == "t"))
                    .then_some(0)
            })
            .ok_or_else(|| LogError::Line {
                file: file.to_path_buf(),
                line: 1,
                problem: format!(
                    "header `{}`; expected {}",
                    shortened(&found.join(","), 200),
                    expected.iter().map(|h| format!("`{}`", h.join(","))).collect::<Vec<_>>().join(" or ")
                ),
            })?;
        if let Some(line) = blank_line_before_last_row(file).map_err(io(file))? {
            return Err(LogError::Line {
                file: file.to_path_buf(),
                line,
                problem: "a blank line before the last row".into(),
            });
        }
        let mut first = csv::StringRecord::new();
        let first = reader.read_record(&mut first).map_err(|e| csv_error(file, e))?.then_some(first);
        Ok(Rows { file: file.to_path_buf(), reader, names: found, header, previous_t: f64::NEG_INFINITY, first })
    }

    /// The next record and its line, with as many cells as the header.
    fn next_record(&mut self) -> Option<Result<(u64, csv::StringRecord), LogError>> {
        let record = match self.first.take() {
            Some(record) => record,
            None => {
                let mut record = csv::StringRecord::new();
                match self.reader.read_record(&mut record) {
                    Ok(false) => return None,
                    Ok(true) => record,
                    Err(e) => return Some(Err(csv_error(&self.file, e))),
                }
            }
        };
        // Lines of spaces at the file's end are blank lines, not rows of one empty cell;
        // one with a row after it (`""`, which the blank-line check counts as text) is not.
        if record.len() == 1 && record[0].is_empty() {
            let mut next = csv::StringRecord::new();
            loop {
                match self.reader.read_record(&mut next) {
                    Ok(false) => return None,
                    Ok(true) if next.len() == 1 && next[0].is_empty() => continue,
                    Ok(true) => break,
                    Err(e) => return Some(Err(csv_error(&self.file, e))),
                }
            }
            let line = record.position().map_or(0, |p| p.line());
            return Some(Err(self.problem(line, format!("1 columns, the header has {}", self.names.len()))));
        }
        let line = record.position().map_or(0, |p| p.line());
        let columns = self.names.len();
        if record.len() != columns {
            return Some(Err(self.problem(line, format!("{} columns, the header has {columns}", record.len()))));
        }
        Some(Ok((line, record)))
    }

    /// The next row's line and values (empty cells `None`), with its time (column 0)
    /// checked to be finite and not to go back.
    fn next_row(&mut self) -> Option<Result<Row, LogError>> {
        Some(self.next_record()?.and_then(|(line, record)| {
            let values = (0..record.len()).map(|k| self.number(line, &record, k)).collect::<Result<Vec<_>, _>>()?;
            let t = self.time(line, values[0])?;
            Ok((line, t, values))
        }))
    }

    /// Cell `k` of a record as a number (`None` when empty).
    fn number(&self, line: u64, record: &csv::StringRecord, k: usize) -> Result<Option<f64>, LogError> {
        let v = &record[k];
        if v.is_empty() {
            return Ok(None);
        }
        v.parse::<f64>()
            .map(Some)
            .map_err(|_| self.problem(line, format!("column `{}`: `{v}` is not a number", self.names[k])))
    }

    /// A row's time, checked to be there, finite, within [`MAX_TIME_S`] and not before
    /// the previous row's.
    fn time(&mut self, line: u64, t: Option<f64>) -> Result<f64, LogError> {
        let t = self.finite(line, &[t], 0, "t")?;
        if t.abs() > MAX_TIME_S {
            return Err(
                self.problem(line, format!("t = {t:e} s lies beyond {MAX_TIME_S:e} s: seconds, not another unit"))
            );
        }
        if t < self.previous_t {
            return Err(self.problem(line, format!("t = {t} s comes before the previous row's {} s", self.previous_t)));
        }
        self.previous_t = t;
        Ok(t)
    }

    fn problem(&self, line: u64, problem: impl Into<String>) -> LogError {
        LogError::Line { file: self.file.clone(), line, problem: problem.into() }
    }

    /// Value `k` of a row, which must be present and finite.
    fn finite(&self, line: u64, row: &[Option<f64>], k: usize, name: &str) -> Result<f64, LogError> {
        match row[k] {
            Some(v) if v.is_finite() => Ok(v),
            Some(v) => Err(self.problem(line, format!("`{name}` must be finite, got {v}"))),
            None => Err(self.problem(line, format!("`{name}` is empty"))),
        }
    }
}

/// The first blank line (1-based) of CSV `file` that has a line of text after it (before
/// the header or between rows): the `csv` reader skips blank lines, so a row lost there
/// would go unseen. Blank lines at the end are left alone. Lines end as the reader ends
/// them: at `\n`, `\r\n` or a lone `\r`.
pub fn blank_line_before_last_row(file: &Path) -> std::io::Result<Option<u64>> {
    use std::io::BufRead;
    let mut reader = std::io::BufReader::new(fs::File::open(file)?);
    let (mut line, mut has_text, mut after_cr) = (1u64, false, false);
    let mut blank = None;
    loop {
        let chunk = reader.fill_buf()?;
        if chunk.is_empty() {
            return Ok(None);
        }
        for &b in chunk {
            match b {
                b'\n' if after_cr => after_cr = false,
                b'\r' | b'\n' => {
                    if !has_text {
                        blank = blank.or(Some(line));
                    }
                    (line, has_text, after_cr) = (line + 1, false, b == b'\r');
                }
                _ => {
                    after_cr = false;
                    if !b.is_ascii_whitespace() {
                        if blank.is_some() {
                            return Ok(blank);
                        }
                        has_text = true;
                    }
                }
            }
        }
        let n = chunk.len();
        reader.consume(n);
    }
}

/// What is wrong, in words, for a CSV reader's error (its UTF-8 error's own text is a
/// debug dump of the reader's state).
pub fn csv_problem(e: &csv::Error) -> String {
    match e.kind() {
        csv::ErrorKind::Utf8 { err, .. } => format!("field {} is not UTF-8 text", err.field() + 1),
        _ => e.to_string(),
    }
}

fn csv_error(file: &Path, e: csv::Error) -> LogError {
    let line = e.position().map(|p| p.line());
    let problem = csv_problem(&e);
    match (e.into_kind(), line) {
        (csv::ErrorKind::Io(source), _) => LogError::Io { file: file.to_path_buf(), source },
        (_, Some(line)) => LogError::Line { file: file.to_path_buf(), line, problem },
        (_, None) => LogError::File { file: file.to_path_buf(), problem },
    }
}

const INCREMENTS: &[&str] = &["t", "dx", "dy", "dtheta"];
const DIFFERENTIAL: &[&str] = &["t", "v", "omega"];
const ACKERMANN: &[&str] = &["t", "speed", "steering"];

/// `odometry.csv` as motion messages, its header checked against the manifest's vehicle.
struct MotionRows {
    rows: Rows,
    /// The previous row's time: an increment is the motion since then.
    previous_t: Option<f64>,
    /// The first observation's time: the first increment is the motion since the log's
    /// start, the earlier of this and its own time.
    first_observation_t: Option<f64>,
}

fn open_motion(file: &Path, manifest: &Manifest) -> Result<MotionRows, LogError> {
    let rows = Rows::open(file, &[INCREMENTS, DIFFERENTIAL, ACKERMANN])?;
    let car = manifest.vehicle.motion == "ackermann";
    if car != (rows.header == 2) {
        return Err(rows.problem(
            1,
            format!(
                "the manifest's vehicle.motion = \"{}\" needs {}",
                manifest.vehicle.motion,
                if car { "`t,speed,steering`" } else { "`t,dx,dy,dtheta` or `t,v,omega`" }
            ),
        ));
    }
    Ok(MotionRows { rows, previous_t: None, first_observation_t: None })
}

impl Iterator for MotionRows {
    type Item = Result<MotionMessage, LogError>;

    fn next(&mut self) -> Option<Self::Item> {
        let (line, t, row) = match self.rows.next_row()? {
            Ok(r) => r,
            Err(e) => return Some(Err(e)),
        };
        let names = [INCREMENTS, DIFFERENTIAL, ACKERMANN][self.rows.header];
        let v: Result<Vec<f64>, _> = (1..names.len()).map(|k| self.rows.finite(line, &row, k, names[k])).collect();
        let message = v.map(|v| match self.rows.header {
            0 => MotionMessage::Increment(OdometryIncrement { t, dx: v[0], dy: v[1], dtheta: v[2] }),
            1 => MotionMessage::Control { t, control: Control::Differential { v: v[0], omega: v[1] } },
            _ => MotionMessage::Control { t, control: Control::Ackermann { speed: v[0], steering: v[1] } },
        });
        // The first row's motion is since the log's start.
        let start = self.first_observation_t.map_or(t, |s| s.min(t));
        let since = match self.previous_t.replace(t) {
            Some(previous) => Since::PreviousRow(previous),
            None => Since::LogStart(start),
        };
        Some(message.and_then(|m| match m.impossibility().or_else(|| increment_too_fast(&m, since)) {
            Some(problem) => Err(self.rows.problem(line, problem)),
            None => Ok(m),
        }))
    }
}

/// What an increment's motion is since.
#[derive(Debug, Clone, Copy)]
enum Since {
    PreviousRow(f64),
    /// The first row's: the log's start (see [`MotionRows::first_observation_t`]).
    LogStart(f64),
}

/// Where `m` is an increment over the time since `since`, whether it moves faster than
/// any vehicle's odometry reads (as a control's speed is checked), or at all in no time.
/// (Its turn is not held to a rate: a step's few hundredths of a radian over a jittered
/// millisecond would read as a spin; [`MotionMessage::impossibility`] bounds the turn.)
fn increment_too_fast(m: &MotionMessage, since: Since) -> Option<String> {
    let MotionMessage::Increment(o) = m else { return None };
    let previous = match since {
        Since::PreviousRow(t) | Since::LogStart(t) => t,
    };
    let (dt, step) = (o.t - previous, o.dx.hypot(o.dy));
    let max = crate::stream::MAX_SPEED_M_S;
    if dt == 0.0 && (step > 0.0 || o.dtheta != 0.0) {
        let why = match since {
            Since::PreviousRow(_) => "t repeats the previous row's".to_string(),
            // A log that starts moving has a first row of no motion (nothing before it to
            // count from); one that does not would put the vehicle off its start pose.
            Since::LogStart(_) => format!(
                "the first row's motion is since the log's start, which is its own time ({}): a first row moves nothing",
                o.t
            ),
        };
        return Some(format!("a step of {step:.3} m and {} rad in no time: {why}", o.dtheta));
    }
    let since_start = match since {
        Since::LogStart(start) => format!(" (the first row's motion: since the log's start at t = {start} s)"),
        Since::PreviousRow(_) => String::new(),
    };
    (dt > 0.0 && step / dt > max)
        .then(|| format!("a step of {step:.3} m in {dt} s is {:e} m/s, beyond {max} m/s{since_start}", step / dt))
}

/// `scans.csv` as whole scans.
struct ScanRows {
    rows: Rows,
    laser: crate::manifest::LaserGeometry,
}

impl Iterator for ScanRows {
    type Item = Result<LaserScan, LogError>;

    fn next(&mut self) -> Option<Self::Item> {
        let (line, t, row) = match self.rows.next_row()? {
            Ok(r) => r,
            Err(e) => return Some(Err(e)),
        };
        // No return: empty, `inf`, or anything outside [range_min, range_max] (REP-117).
        let ranges = row[1..]
            .iter()
            .map(|r| match r {
                Some(v) if v.is_nan() => Err(self.rows.problem(line, "a range is NaN: write no return as `inf`")),
                // A finite negative range is no distance at all: a sign or unit slip, not a
                // reading to be taken as too close.
                Some(v) if v.is_finite() && *v < 0.0 => Err(self.rows.problem(
                    line,
                    format!("a range of {v} m is negative: write a return too close to measure as `-inf`"),
                )),
                Some(v) => Ok(*v),
                None => Ok(f64::INFINITY),
            })
            .collect::<Result<Vec<_>, _>>();
        let laser = &self.laser;
        Some(ranges.map(|ranges| LaserScan {
            t,
            angle_min: laser.angle_min_rad,
            angle_increment: laser.angle_increment_rad,
            range_min: laser.range_min_m,
            range_max: laser.range_max_m,
            ranges,
        }))
    }
}

const DETECTION_COLUMNS: &[&str] = &["t", "range_m", "bearing_rad", "diameter_m"];

/// `detections.csv` as scans: rows of one scan share its time, and a scan that saw nothing
/// has no row.
struct DetectionRows {
    rows: Rows,
    /// The first detection of the next scan, read while finding where this one ends.
    pending: Option<(f64, Detection)>,
}

impl DetectionRows {
    fn next_detection(&mut self) -> Option<Result<(f64, Detection), LogError>> {
        let (line, t, row) = match self.rows.next_row()? {
            Ok(r) => r,
            Err(e) => return Some(Err(e)),
        };
        Some(self.detection(line, &row).map(|d| (t, d)))
    }

    fn detection(&self, line: u64, row: &[Option<f64>]) -> Result<Detection, LogError> {
        let range_m = self.rows.finite(line, row, 1, "range_m")?;
        if range_m <= 0.0 {
            return Err(self.rows.problem(line, format!("`range_m` must be finite and positive, got {range_m}")));
        }
        if range_m > MAX_COORDINATE_M {
            return Err(self.rows.problem(line, format!("`range_m` {range_m:e} lies beyond {MAX_COORDINATE_M:e} m")));
        }
        let bearing_rad = self.rows.finite(line, row, 2, "bearing_rad")?;
        if bearing_rad.abs() > std::f64::consts::TAU {
            return Err(self
                .rows
                .problem(line, format!("`bearing_rad` {bearing_rad} is beyond a turn: radians, not degrees")));
        }
        let diameter_m = match row[3] {
            None => None,
            Some(d) if d.is_finite() && d >= 0.0 => Some(d),
            Some(d) => {
                return Err(self.rows.problem(line, format!("`diameter_m` must be empty or not negative, got {d}")));
            }
        };
        Ok(Detection { range_m, bearing_rad, diameter_m })
    }
}

impl Iterator for DetectionRows {
    type Item = Result<DetectionScan, LogError>;

    fn next(&mut self) -> Option<Self::Item> {
        let (t, first) = match self.pending.take() {
            Some(p) => p,
            None => match self.next_detection()? {
                Ok(p) => p,
                Err(e) => return Some(Err(e)),
            },
        };
        let mut detections = vec![first];
        loop {
            match self.next_detection() {
                None => break,
                // A fault on the row after a scan's last spoils the scan: it may have been
                // one of its rows.
                Some(Err(e)) => return Some(Err(e)),
                Some(Ok((next_t, d))) if next_t == t => detections.push(d),
                Some(Ok(next)) => {
                    self.pending = Some(next);
                    break;
                }
            }
        }
        Some(Ok(DetectionScan { t, detections }))
    }
}

const CAMERA_COLUMNS: &[&str] = &["t", "file"];

/// `camera.csv`: `t,file` rows, the file relative to the log's directory (or absolute),
/// each checked to exist; the images themselves are read when needed ([`read_frame`]).
fn camera_rows(file: &Path) -> Result<RowsOf<CameraFrameFile>, LogError> {
    let dir = file.parent().unwrap_or(Path::new("")).to_path_buf();
    let mut rows = Rows::open_maybe_empty(file, &[CAMERA_COLUMNS])?;
    let frames = std::iter::from_fn(move || {
        Some(rows.next_record()?.and_then(|(line, record)| {
            let t = rows.number(line, &record, 0)?;
            let t = rows.time(line, t)?;
            if record[1].is_empty() {
                return Err(rows.problem(line, "`file` is empty"));
            }
            let image = dir.join(&record[1]);
            if !image.is_file() {
                return Err(rows.problem(line, format!("no image file {}", image.display())));
            }
            Ok(CameraFrameFile { t, file: image })
        }))
    });
    Ok(Box::new(until_error(frames)))
}

/// Reads one camera frame as 8-bit RGB (PNG or JPEG; grey and alpha are converted),
/// checked to have the manifest camera's size.
pub fn read_frame(frame: &CameraFrameFile, camera: &crate::manifest::Camera) -> Result<RgbImage, LogError> {
    let file = &frame.file;
    let problem = |e: image::ImageError| LogError::File { file: file.clone(), problem: e.to_string() };
    // The size from the header first: an image of another size is refused before it is
    // decoded (a small file can hold a huge picture).
    let reader = image::ImageReader::open(file).map_err(io(file))?.with_guessed_format().map_err(io(file))?;
    let (width, height) = reader.into_dimensions().map_err(problem)?;
    if (width, height) != (camera.width, camera.height) {
        return Err(LogError::File {
            file: file.clone(),
            problem: format!("the image is {width}x{height}, the manifest's camera {}x{}", camera.width, camera.height),
        });
    }
    let image = image::open(file).map_err(problem)?;
    let rgb = image.into_rgb8();
    Ok(RgbImage { width: rgb.width(), height: rgb.height(), rgb: rgb.into_raw() })
}

/// Writes frame `index` of a log in `dir` as `camera/NNNNNN.png` (lossless, so a replay
/// sees the pixels the camera gave) and returns its `camera.csv` entry.
pub fn write_frame(dir: &Path, index: usize, t: f64, image: &RgbImage) -> Result<CameraFrameFile, LogError> {
    let relative = PathBuf::from(format!("camera/{index:06}.png"));
    let file = dir.join(&relative);
    fs::create_dir_all(dir.join("camera")).map_err(io(&dir.join("camera")))?;
    image::save_buffer(&file, &image.rgb, image.width, image.height, image::ExtendedColorType::Rgb8)
        .map_err(|e| LogError::File { file: file.clone(), problem: e.to_string() })?;
    Ok(CameraFrameFile { t, file: relative })
}

/// Largest reference coordinate taken (m): beyond any map on Earth (UTM northings are under
/// 1e7), and far enough below f64's range that squared errors cannot overflow.
pub const MAX_COORDINATE_M: f64 = 1e9;

/// Largest time a log may give, either way (s): about 300 years, past any clock's epoch
/// seconds; beyond it a time is in another unit, or garbage that would make one motion
/// step of any length.
pub const MAX_TIME_S: f64 = 1e10;

fn reference_rows(file: &Path) -> Result<RowsOf<ReferenceSample>, LogError> {
    let mut rows = Rows::open(file, &[&["t", "x", "y"], &["t", "x", "y", "theta"]])?;
    let samples = std::iter::from_fn(move || {
        Some(rows.next_row()?.and_then(|(line, t, row)| {
            let x = rows.finite(line, &row, 1, "x")?;
            let y = rows.finite(line, &row, 2, "y")?;
            if x.abs().max(y.abs()) > MAX_COORDINATE_M {
                return Err(rows.problem(line, format!("({x:.3e}, {y:.3e}) lies beyond {MAX_COORDINATE_M:e} m")));
            }
            let theta = if rows.header == 1 { Some(rows.finite(line, &row, 3, "theta")?) } else { None };
            Ok(ReferenceSample { t, x, y, theta })
        }))
    });
    Ok(Box::new(until_error(samples)))
}

/// Writes `log` into `dir` (created if missing). Numbers are written in full precision:
/// reading the files back gives the same log, for a log that keeps the format's rules
/// (scans with equal beam counts, detection scans with at least one detection and distinct
/// times, headings on all reference samples or none, finite numbers).
pub fn write(dir: &Path, log: &Log) -> Result<(), LogError> {
    // What can be refused is refused before anything is written, and the manifest, without
    // which nothing reads the directory as a log, is written last. A log has motion and
    // something seen: the reader refuses data files of a header alone.
    let motion_messages = match &log.motion {
        Motion::Increments(v) => v.len(),
        Motion::Controls(v) => v.len(),
    };
    if motion_messages == 0 {
        return Err(LogError::File { file: dir.join(ODOMETRY), problem: "no motion message to write".into() });
    }
    let (seen, file) = match &log.observations {
        Observations::Scans(s) => (s.len(), SCANS),
        Observations::Detections(s) => (s.iter().map(|s| s.detections.len()).sum(), DETECTIONS),
    };
    if seen == 0 {
        return Err(LogError::File { file: dir.join(file), problem: "no scan or detection to write".into() });
    }
    if matches!(&log.observations, Observations::Scans(s) if s[0].ranges.is_empty()) {
        return Err(LogError::File { file: dir.join(SCANS), problem: "scans of no beam".into() });
    }
    if log.manifest.reference.is_some() && log.reference.is_empty() {
        return Err(LogError::File {
            file: dir.join(REFERENCE),
            problem: "a [reference] table in the manifest, but no reference sample to write".into(),
        });
    }
    if let Observations::Scans(scans) = &log.observations {
        let beams = scans.first().map_or(0, |s| s.ranges.len());
        if let Some(s) = scans.iter().find(|s| s.ranges.len() != beams) {
            return Err(LogError::File {
                file: dir.join(SCANS),
                problem: format!("the scan at t = {} s has {} beams, the first has {beams}", s.t, s.ranges.len()),
            });
        }
    }
    if !log.camera.is_empty() && log.manifest.camera.is_none() {
        return Err(LogError::File {
            file: dir.join(MANIFEST),
            problem: "camera frames but no [camera] table to describe the camera".into(),
        });
    }
    if let Some(r) = log.reference.iter().find(|r| r.x.abs().max(r.y.abs()) > MAX_COORDINATE_M) {
        return Err(LogError::File {
            file: dir.join(REFERENCE),
            problem: format!("the sample at t = {} s lies beyond {MAX_COORDINATE_M:e} m", r.t),
        });
    }
    if matches!(log.observations, Observations::Detections(_)) && log.manifest.laser.is_some() {
        return Err(LogError::File {
            file: dir.join(MANIFEST),
            problem: "a [laser] table describes scans' beams, and this log holds detections".into(),
        });
    }
    let manifest = toml::to_string(&log.manifest)
        .map_err(|e| LogError::File { file: dir.join(MANIFEST), problem: e.to_string() })?;
    fs::create_dir_all(dir).map_err(io(dir))?;
    let mut odometry = String::new();
    match &log.motion {
        Motion::Increments(v) => {
            odometry.push_str("t,dx,dy,dtheta\n");
            for o in v {
                odometry.push_str(&format!("{},{},{},{}\n", o.t, o.dx, o.dy, o.dtheta));
            }
        }
        Motion::Controls(v) => {
            match v.first().map(|c| c.1) {
                Some(Control::Differential { .. }) => odometry.push_str("t,v,omega\n"),
                _ if log.manifest.vehicle.motion == "ackermann" => odometry.push_str("t,speed,steering\n"),
                _ => odometry.push_str("t,v,omega\n"),
            }
            for (t, c) in v {
                match c {
                    Control::Differential { v, omega } => odometry.push_str(&format!("{t},{v},{omega}\n")),
                    Control::Ackermann { speed, steering } => odometry.push_str(&format!("{t},{speed},{steering}\n")),
                }
            }
        }
    }
    write_file(&dir.join(ODOMETRY), &odometry)?;
    match &log.observations {
        Observations::Scans(scans) => {
            let beams = scans.first().map_or(0, |s| s.ranges.len());
            let mut text = String::from("t");
            for i in 0..beams {
                text.push_str(&format!(",r{i}"));
            }
            text.push('\n');
            for s in scans {
                text.push_str(&s.t.to_string());
                for r in &s.ranges {
                    text.push(',');
                    text.push_str(&r.to_string());
                }
                text.push('\n');
            }
            write_file(&dir.join(SCANS), &text)?;
        }
        Observations::Detections(scans) => {
            let mut text = format!("{}\n", DETECTION_COLUMNS.join(","));
            for s in scans {
                for d in &s.detections {
                    let diameter = d.diameter_m.map_or(String::new(), |v| v.to_string());
                    text.push_str(&format!("{},{},{},{diameter}\n", s.t, d.range_m, d.bearing_rad));
                }
            }
            write_file(&dir.join(DETECTIONS), &text)?;
        }
    }
    if !log.reference.is_empty() {
        let with_heading = log.reference.iter().all(|r| r.theta.is_some());
        let mut text = String::from(if with_heading { "t,x,y,theta\n" } else { "t,x,y\n" });
        for r in &log.reference {
            match (with_heading, r.theta) {
                (true, Some(th)) => text.push_str(&format!("{},{},{},{th}\n", r.t, r.x, r.y)),
                _ => text.push_str(&format!("{},{},{}\n", r.t, r.x, r.y)),
            }
        }
        write_file(&dir.join(REFERENCE), &text)?;
    }
    if log.manifest.camera.is_some() {
        let mut text = format!("{}\n", CAMERA_COLUMNS.join(","));
        for f in &log.camera {
            let name = f.file.strip_prefix(dir).unwrap_or(&f.file).to_string_lossy().into_owned();
            if name.contains([',', '"', '\n']) {
                return Err(LogError::File {
                    file: dir.join(CAMERA),
                    problem: format!("the image path `{name}` holds a comma, quote or line break"),
                });
            }
            text.push_str(&format!("{},{name}\n", f.t));
        }
        write_file(&dir.join(CAMERA), &text)?;
    }
    let header = "# A robot log: docs/reference/robot-log.md describes the files.\n";
    write_file(&dir.join(MANIFEST), &format!("{header}{manifest}"))
}

fn write_file(file: &Path, text: &str) -> Result<(), LogError> {
    let mut f = fs::File::create(file).map_err(io(file))?;
    f.write_all(text.as_bytes()).map_err(io(file))?;
    f.sync_all().map_err(io(file))
}
