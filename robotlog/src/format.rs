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

use crate::{CameraFrameFile, DetectionScan, Log, LogError, Manifest, Motion, Observations, ReferenceSample, RgbImage};

pub const MANIFEST: &str = "manifest.toml";
pub const ODOMETRY: &str = "odometry.csv";
pub const SCANS: &str = "scans.csv";
pub const DETECTIONS: &str = "detections.csv";
pub const REFERENCE: &str = "reference.csv";
pub const CAMERA: &str = "camera.csv";

/// Reads the log in `dir`.
pub fn read(dir: &Path) -> Result<Log, LogError> {
    let manifest = read_manifest(&dir.join(MANIFEST))?;
    let motion = read_motion(&dir.join(ODOMETRY), &manifest)?;
    let (scans, detections) = (dir.join(SCANS), dir.join(DETECTIONS));
    let observations = match (scans.exists(), detections.exists()) {
        (true, false) => {
            let Some(laser) = &manifest.laser else {
                return Err(LogError::File {
                    file: dir.join(MANIFEST),
                    problem: "scans.csv needs a [laser] table with the beams' geometry".into(),
                });
            };
            Observations::Scans(read_scans(&scans, laser)?)
        }
        (false, true) => Observations::Detections(read_detections(&detections)?),
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
    let reference = if reference_file.exists() {
        if manifest.reference.is_none() {
            return Err(LogError::File {
                file: dir.join(MANIFEST),
                problem: "reference.csv is there but no [reference] table says what it holds".into(),
            });
        }
        read_reference(&reference_file)?
    } else {
        Vec::new()
    };
    let camera_file = dir.join(CAMERA);
    let camera = match (camera_file.exists(), &manifest.camera) {
        (true, Some(_)) => read_camera(&camera_file, dir)?,
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
        (false, None) => Vec::new(),
    };
    Ok(Log { manifest, motion, observations, reference, camera })
}

fn io(file: &Path) -> impl Fn(std::io::Error) -> LogError + '_ {
    move |source| LogError::Io { file: file.to_path_buf(), source }
}

fn read_manifest(file: &Path) -> Result<Manifest, LogError> {
    let text = fs::read_to_string(file).map_err(io(file))?;
    let manifest: Manifest = toml::from_str(&text).map_err(|e| {
        let line = e.span().map(|s| text[..s.start].matches('\n').count() as u64 + 1);
        let problem = e.message().to_string();
        match line {
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

/// A CSV file's rows as numbers, with the header checked against `expected` (one of the
/// allowed headers; returns its index) and each row's line.
struct Table {
    file: PathBuf,
    header: usize,
    rows: Vec<(u64, Vec<Option<f64>>)>,
}

impl Table {
    fn read(file: &Path, expected: &[&[&str]]) -> Result<Table, LogError> {
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(true)
            .flexible(true)
            .trim(csv::Trim::All)
            .from_path(file)
            .map_err(|e| csv_error(file, e))?;
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
                    found.join(","),
                    expected.iter().map(|h| format!("`{}`", h.join(","))).collect::<Vec<_>>().join(" or ")
                ),
            })?;
        let columns = found.len();
        let mut rows = Vec::new();
        for record in reader.records() {
            let record = record.map_err(|e| csv_error(file, e))?;
            let line = record.position().map_or(0, |p| p.line());
            if record.len() != columns {
                return Err(LogError::Line {
                    file: file.to_path_buf(),
                    line,
                    problem: format!("{} columns, the header has {columns}", record.len()),
                });
            }
            let values = record
                .iter()
                .enumerate()
                .map(|(k, v)| {
                    if v.is_empty() {
                        return Ok(None);
                    }
                    v.parse::<f64>().map(Some).map_err(|_| LogError::Line {
                        file: file.to_path_buf(),
                        line,
                        problem: format!("column `{}`: `{v}` is not a number", found[k]),
                    })
                })
                .collect::<Result<Vec<_>, _>>()?;
            rows.push((line, values));
        }
        Ok(Table { file: file.to_path_buf(), header, rows })
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

    /// Each row's time (column 0), checked to be finite and never to go back.
    fn times(&self) -> Result<Vec<f64>, LogError> {
        let mut previous = f64::NEG_INFINITY;
        let mut out = Vec::with_capacity(self.rows.len());
        for (line, row) in &self.rows {
            let t = self.finite(*line, row, 0, "t")?;
            if t < previous {
                return Err(self.problem(*line, format!("t = {t} s comes before the previous row's {previous} s")));
            }
            previous = t;
            out.push(t);
        }
        Ok(out)
    }
}

fn csv_error(file: &Path, e: csv::Error) -> LogError {
    let line = e.position().map(|p| p.line());
    match (e.into_kind(), line) {
        (csv::ErrorKind::Io(source), _) => LogError::Io { file: file.to_path_buf(), source },
        (kind, Some(line)) => LogError::Line { file: file.to_path_buf(), line, problem: format!("{kind:?}") },
        (kind, None) => LogError::File { file: file.to_path_buf(), problem: format!("{kind:?}") },
    }
}

const INCREMENTS: &[&str] = &["t", "dx", "dy", "dtheta"];
const DIFFERENTIAL: &[&str] = &["t", "v", "omega"];
const ACKERMANN: &[&str] = &["t", "speed", "steering"];

fn read_motion(file: &Path, manifest: &Manifest) -> Result<Motion, LogError> {
    let table = Table::read(file, &[INCREMENTS, DIFFERENTIAL, ACKERMANN])?;
    let times = table.times()?;
    let car = manifest.vehicle.motion == "ackermann";
    if car != (table.header == 2) {
        return Err(table.problem(
            1,
            format!(
                "the manifest's vehicle.motion = \"{}\" needs {}",
                manifest.vehicle.motion,
                if car { "`t,speed,steering`" } else { "`t,dx,dy,dtheta` or `t,v,omega`" }
            ),
        ));
    }
    let mut increments = Vec::new();
    let mut controls = Vec::new();
    for ((line, row), t) in table.rows.iter().zip(times) {
        let names = [INCREMENTS, DIFFERENTIAL, ACKERMANN][table.header];
        let v: Vec<f64> = (1..names.len()).map(|k| table.finite(*line, row, k, names[k])).collect::<Result<_, _>>()?;
        match table.header {
            0 => increments.push(OdometryIncrement { t, dx: v[0], dy: v[1], dtheta: v[2] }),
            1 => controls.push((t, Control::Differential { v: v[0], omega: v[1] })),
            _ => controls.push((t, Control::Ackermann { speed: v[0], steering: v[1] })),
        }
    }
    Ok(if table.header == 0 { Motion::Increments(increments) } else { Motion::Controls(controls) })
}

fn read_scans(file: &Path, laser: &crate::manifest::LaserGeometry) -> Result<Vec<LaserScan>, LogError> {
    let table = Table::read(file, &[&["t", "..."]])?;
    let times = table.times()?;
    let mut scans = Vec::with_capacity(times.len());
    for ((line, row), t) in table.rows.iter().zip(times) {
        // No return: empty, `inf`, or anything outside [range_min, range_max] (REP-117).
        let ranges = row[1..]
            .iter()
            .map(|r| match r {
                Some(v) if v.is_nan() => Err(table.problem(*line, "a range is NaN: write no return as `inf`")),
                Some(v) => Ok(*v),
                None => Ok(f64::INFINITY),
            })
            .collect::<Result<Vec<_>, _>>()?;
        scans.push(LaserScan {
            t,
            angle_min: laser.angle_min_rad,
            angle_increment: laser.angle_increment_rad,
            range_min: laser.range_min_m,
            range_max: laser.range_max_m,
            ranges,
        });
    }
    Ok(scans)
}

const DETECTION_COLUMNS: &[&str] = &["t", "range_m", "bearing_rad", "diameter_m"];

fn read_detections(file: &Path) -> Result<Vec<DetectionScan>, LogError> {
    let table = Table::read(file, &[DETECTION_COLUMNS])?;
    let times = table.times()?;
    let mut scans: Vec<DetectionScan> = Vec::new();
    for ((line, row), t) in table.rows.iter().zip(times) {
        let range_m = table.finite(*line, row, 1, "range_m")?;
        if range_m <= 0.0 {
            return Err(table.problem(*line, format!("`range_m` must be finite and positive, got {range_m}")));
        }
        let bearing_rad = table.finite(*line, row, 2, "bearing_rad")?;
        let diameter_m = match row[3] {
            None => None,
            Some(d) if d.is_finite() && d >= 0.0 => Some(d),
            Some(d) => return Err(table.problem(*line, format!("`diameter_m` must be empty or not negative, got {d}"))),
        };
        let detection = Detection { range_m, bearing_rad, diameter_m };
        // Rows of one scan share its time; a scan that saw nothing has no row.
        match scans.last_mut() {
            Some(s) if s.t == t => s.detections.push(detection),
            _ => scans.push(DetectionScan { t, detections: vec![detection] }),
        }
    }
    Ok(scans)
}

const CAMERA_COLUMNS: &[&str] = &["t", "file"];

/// `camera.csv`: `t,file` rows, the file relative to the log's directory (or absolute),
/// each checked to exist; the images themselves are read when needed ([`read_frame`]).
fn read_camera(file: &Path, dir: &Path) -> Result<Vec<CameraFrameFile>, LogError> {
    let line_error = |line: u64, problem: String| LogError::Line { file: file.to_path_buf(), line, problem };
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .trim(csv::Trim::All)
        .from_path(file)
        .map_err(|e| csv_error(file, e))?;
    let found: Vec<String> = reader.headers().map_err(|e| csv_error(file, e))?.iter().map(str::to_string).collect();
    if found != CAMERA_COLUMNS {
        return Err(line_error(1, format!("header `{}`; expected `{}`", found.join(","), CAMERA_COLUMNS.join(","))));
    }
    let mut frames: Vec<CameraFrameFile> = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| csv_error(file, e))?;
        let line = record.position().map_or(0, |p| p.line());
        let t = record[0]
            .parse::<f64>()
            .map_err(|_| line_error(line, format!("column `t`: `{}` is not a number", &record[0])))?;
        if !t.is_finite() {
            return Err(line_error(line, format!("`t` must be finite, got {t}")));
        }
        if let Some(previous) = frames.last().map(|f| f.t).filter(|&p| t < p) {
            return Err(line_error(line, format!("t = {t} s comes before the previous row's {previous} s")));
        }
        if record[1].is_empty() {
            return Err(line_error(line, "`file` is empty".into()));
        }
        let image = dir.join(&record[1]);
        if !image.is_file() {
            return Err(line_error(line, format!("no image file {}", image.display())));
        }
        frames.push(CameraFrameFile { t, file: image });
    }
    Ok(frames)
}

/// Reads one camera frame as 8-bit RGB (PNG or JPEG; grey and alpha are converted),
/// checked to have the manifest camera's size.
pub fn read_frame(frame: &CameraFrameFile, camera: &crate::manifest::Camera) -> Result<RgbImage, LogError> {
    let file = &frame.file;
    let image = image::open(file).map_err(|e| LogError::File { file: file.clone(), problem: e.to_string() })?;
    if (image.width(), image.height()) != (camera.width, camera.height) {
        return Err(LogError::File {
            file: file.clone(),
            problem: format!(
                "the image is {}x{}, the manifest's camera {}x{}",
                image.width(),
                image.height(),
                camera.width,
                camera.height
            ),
        });
    }
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

fn read_reference(file: &Path) -> Result<Vec<ReferenceSample>, LogError> {
    let table = Table::read(file, &[&["t", "x", "y"], &["t", "x", "y", "theta"]])?;
    let times = table.times()?;
    let mut out = Vec::with_capacity(times.len());
    for ((line, row), t) in table.rows.iter().zip(times) {
        let x = table.finite(*line, row, 1, "x")?;
        let y = table.finite(*line, row, 2, "y")?;
        let theta = if table.header == 1 { Some(table.finite(*line, row, 3, "theta")?) } else { None };
        out.push(ReferenceSample { t, x, y, theta });
    }
    Ok(out)
}

/// Writes `log` into `dir` (created if missing). Numbers are written in full precision:
/// reading the files back gives the same log, for a log that keeps the format's rules
/// (scans with equal beam counts, detection scans with at least one detection and distinct
/// times, headings on all reference samples or none, finite numbers).
pub fn write(dir: &Path, log: &Log) -> Result<(), LogError> {
    fs::create_dir_all(dir).map_err(io(dir))?;
    let manifest = toml::to_string(&log.manifest)
        .map_err(|e| LogError::File { file: dir.join(MANIFEST), problem: e.to_string() })?;
    let header = "# A robot log: docs/reference/robot-log.md describes the files.\n";
    fs::write(dir.join(MANIFEST), format!("{header}{manifest}")).map_err(io(&dir.join(MANIFEST)))?;
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
            if let Some(s) = scans.iter().find(|s| s.ranges.len() != beams) {
                return Err(LogError::File {
                    file: dir.join(SCANS),
                    problem: format!("the scan at t = {} s has {} beams, the first has {beams}", s.t, s.ranges.len()),
                });
            }
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
    if !log.camera.is_empty() {
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
    Ok(())
}

fn write_file(file: &Path, text: &str) -> Result<(), LogError> {
    let mut f = fs::File::create(file).map_err(io(file))?;
    f.write_all(text.as_bytes()).map_err(io(file))?;
    f.sync_all().map_err(io(file))
}
