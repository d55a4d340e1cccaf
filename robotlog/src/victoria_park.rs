//! Victoria Park (ACFR, University of Sydney; Guivant & Nebot): a utility car with a SICK
//! laser driving 26 minutes through a Sydney park, among trees. The data's licence is not
//! stated, so objslam reads the files where the user put them and never ships them.
//!
//! Two published forms are read, from one directory:
//! - the ACFR originals: `aa3_dr.mat` (`time` ms, `speed` m/s of the rear left wheel,
//!   `steering` rad, at 40 Hz) with `aa3_lsr2.mat` (`TLsr` ms, `LASER` N x 361 ranges in cm,
//!   0.5 degree steps from the right, above 8000 cm no return);
//! - the tree detections found in public EKF-SLAM benchmarks,
//!   `VictoriaParkSinSincronizar.mat`: `time` s, `u` = [speed; steering], `TLsr` s and `zt`,
//!   per scan a 3 x N matrix [range m; bearing rad, 0..pi with pi/2 straight ahead;
//!   diameter m]. Used when present.
//!
//! `aa3_gpsx.mat` (`timeGps` ms, `Lo_m`, `La_m`) is the reference where present: GPS of the
//! laser's position, with gaps and spikes.
//!
//! The car's geometry (REFERENCES: wheelbase 2.83 m, encoder 0.76 m left of the rear
//! axle's centre, laser 3.78 m ahead of the rear axle and 0.5 m to its left; info.txt's
//! 0.95 m is measured from the front axle) goes into the manifest.

use std::path::Path;

use matrw::{MatFile, MatVariable};
use slam::messages::{Control, Detection, LaserScan};

use crate::manifest::{LaserGeometry, Reference, ReferenceKind, ReferencePoint, Sensor, Vehicle};
use crate::stream::MotionMessage;
use crate::{DetectionScan, Log, LogError, Manifest, Motion, Observations, ReferenceSample};

pub const DETECTIONS_FILE: &str = "VictoriaParkSinSincronizar.mat";
pub const DEAD_RECKONING_FILE: &str = "aa3_dr.mat";
pub const LASER_FILE: &str = "aa3_lsr2.mat";
pub const GPS_FILE: &str = "aa3_gpsx.mat";
/// Every file of the data set that [`read`] may read.
pub const FILES: &[&str] = &[DETECTIONS_FILE, DEAD_RECKONING_FILE, LASER_FILE, GPS_FILE];

/// Where the median step of each clock may lie (s), once read in seconds. The data set's
/// controls come at 40 Hz (25 ms), its scans at about 4.7 Hz (0.21 s) and its GPS at
/// about 1 Hz with gaps; each window reaches at least 20 times either side of those. A
/// clock in other units (ms read as s, s as ms) is off by a thousand and lies outside, so
/// it is refused rather than replayed into a log 1,000 times as long or as short.
const CONTROL_STEP_S: (f64, f64) = (1e-3, 1.0);
const SCAN_STEP_S: (f64, f64) = (1e-2, 10.0);
const GPS_STEP_S: (f64, f64) = (1e-2, 100.0);

/// Wheelbase (m).
pub const WHEELBASE_M: f64 = 2.83;
/// The speed encoder's wheel: rear left, this far from the rear axle's centre (m).
pub const ENCODER_OFFSET_M: f64 = 0.76;
/// The laser: ahead of the rear axle, and to the left (m).
pub const LASER_X_M: f64 = 3.78;
pub const LASER_Y_M: f64 = 0.5;

/// The files of `dir` that [`read`] reads: the detections form where it is there, else the
/// originals, and the GPS.
pub fn files_read(dir: &Path) -> Vec<&'static str> {
    let mut names =
        if present(&dir.join(DETECTIONS_FILE)) { vec![DETECTIONS_FILE] } else { vec![DEAD_RECKONING_FILE, LASER_FILE] };
    names.push(GPS_FILE);
    names
}

/// Reads the data set in `dir` (either form, see the module documentation).
pub fn read(dir: &Path) -> Result<Log, LogError> {
    crate::format::check_dir(dir, "give the directory that holds the data set's files")?;
    let (motion, observations) = if present(&dir.join(DETECTIONS_FILE)) {
        read_detections_form(&dir.join(DETECTIONS_FILE))?
    } else if present(&dir.join(DEAD_RECKONING_FILE)) && present(&dir.join(LASER_FILE)) {
        (read_dead_reckoning(&dir.join(DEAD_RECKONING_FILE))?, read_laser(&dir.join(LASER_FILE))?)
    } else {
        return Err(LogError::Missing {
            dir: dir.to_path_buf(),
            what: "Victoria Park files",
            expected: "VictoriaParkSinSincronizar.mat, or aa3_dr.mat with aa3_lsr2.mat (aa3_gpsx.mat for GPS)",
        });
    };
    let gps_file = dir.join(GPS_FILE);
    let reference = if present(&gps_file) { read_gps(&gps_file)? } else { Vec::new() };
    let laser = matches!(observations, Observations::Scans(_)).then(|| LaserGeometry {
        angle_min_rad: -std::f64::consts::FRAC_PI_2,
        angle_increment_rad: 0.5f64.to_radians(),
        range_min_m: 0.5,
        range_max_m: 80.0,
    });
    let manifest = Manifest {
        format_version: 1,
        name: "victoria_park".into(),
        source: "Victoria Park, Sydney: ACFR, University of Sydney (Guivant & Nebot)".into(),
        vehicle: Vehicle {
            motion: "ackermann".into(),
            wheelbase_m: Some(WHEELBASE_M),
            encoder_offset_m: Some(ENCODER_OFFSET_M),
            start_pose: [0.0; 3],
        },
        sensor: Sensor {
            x_m: LASER_X_M,
            y_m: LASER_Y_M,
            yaw_rad: 0.0,
            range_sigma_m: None,
            range_sigma_per_m: None,
            bearing_sigma_rad: None,
        },
        laser,
        // The estimate's path is the laser's, the point the GPS is compared with, whether
        // or not the GPS file is there: a replay of the same data describes one point.
        reference: Some(Reference { kind: ReferenceKind::Gps, point: ReferencePoint::Sensor }),
        camera: None,
    };
    Ok(Log { manifest, motion, observations, reference, camera: Vec::new() })
}

/// Whether a file of the data set is there: a link that leads nowhere is, and reading it
/// says so, rather than another form being read in its place.
fn present(path: &Path) -> bool {
    path.symlink_metadata().is_ok()
}

std::thread_local! {
    /// Set while this thread runs the MAT-file parser (see [`load`]).
    static PARSING: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Loads a MAT-file. A corrupt file must be an error, not a crash: the parser is a
/// third-party crate, so a panic inside it is caught and reported as such, and the panic
/// hook stays silent for it (a user would otherwise read a crash report above the error).
fn load(file: &Path) -> Result<MatFile, LogError> {
    static QUIET_HOOK: std::sync::Once = std::sync::Once::new();
    QUIET_HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !PARSING.with(std::cell::Cell::get) {
                previous(info);
            }
        }));
    });
    // A pipe or a device would be read for ever, or not as a file.
    if let Ok(meta) = std::fs::metadata(file)
        && !meta.is_file()
        && !meta.is_dir()
    {
        return Err(LogError::File { file: file.to_path_buf(), problem: "not a regular file".into() });
    }
    let mut bytes = std::fs::read(file).map_err(|source| LogError::Io { file: file.to_path_buf(), source })?;
    if bytes.len() < MAT_HEADER_BYTES {
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: format!(
                "not a MAT-file: {} bytes, fewer than a MAT-file's {MAT_HEADER_BYTES}-byte header",
                bytes.len()
            ),
        });
    }
    if !bytes.starts_with(b"MATLAB") {
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: "not a MAT-file of version 5 or 7: its header does not open with `MATLAB` (a MAT v4 file, \
                      or not a MAT-file; MATLAB's `save -v7` and scipy's `savemat` write one that is read)"
                .into(),
        });
    }
    if bytes.starts_with(b"MATLAB 7.3") {
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: "a MAT-file of version 7.3 (HDF5), which is not read: save it with MATLAB's `save -v7`".into(),
        });
    }
    normalise_header_text(&mut bytes);
    PARSING.with(|p| p.set(true));
    let parsed = std::panic::catch_unwind(|| matrw::load_matfile_from_u8(&bytes));
    PARSING.with(|p| p.set(false));
    match parsed {
        Ok(Ok(mat)) => Ok(mat),
        Ok(Err(e)) => Err(LogError::File {
            file: file.to_path_buf(),
            problem: format!("not a readable MAT-file (damaged or cut short?): {}", parser_message(&e.to_string())),
        }),
        Err(_) => Err(LogError::File {
            file: file.to_path_buf(),
            problem: "not a readable MAT-file (the parser failed)".into(),
        }),
    }
}

/// A Level 5 MAT-file's header: 116 bytes of text, 8 of subsystem offset, 2 of version and
/// 2 of byte order.
const MAT_HEADER_BYTES: usize = 128;

/// Gives a Level 5 header's descriptive text the `MATLAB 5.0 MAT-file, ` opening the
/// parser insists on. The text is for people (MATLAB writes `MAT-file, Platform: ...`,
/// scipy's `savemat` `MAT-file Platform: ...`): a file scipy saved was refused.
fn normalise_header_text(bytes: &mut [u8]) {
    const OPENING: &[u8] = b"MATLAB 5.0 MAT-file";
    const WANTED: &[u8] = b"MATLAB 5.0 MAT-file, ";
    let text = &bytes[..116];
    if !text.starts_with(OPENING) || text.starts_with(WANTED) {
        return;
    }
    let rest: Vec<u8> = text[OPENING.len()..].iter().copied().skip_while(|&b| b == b' ' || b == b',').collect();
    let mut new = WANTED.to_vec();
    new.extend(rest);
    new.resize(116, b' ');
    bytes[..116].copy_from_slice(&new);
}

/// The parser's message for people: after its `Error: `, without terminal colour codes,
/// frame lines, backtrace or the parser's source paths, on one line.
fn parser_message(message: &str) -> String {
    let text = plain_text(message);
    let text = text.split_once("Error: ").map_or(text.as_str(), |(_, after)| after);
    let text = text.split(" at /").next().unwrap_or(text);
    text.chars().filter(|c| !('\u{2500}'..='\u{257f}').contains(c)).collect::<String>().trim().to_string()
}

/// The parser's message without its terminal colour codes, on one line.
fn plain_text(message: &str) -> String {
    let mut out = String::with_capacity(message.len());
    let mut chars = message.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            // An escape sequence `ESC [ ... letter`.
            for c in chars.by_ref() {
                if c.is_ascii_alphabetic() {
                    break;
                }
            }
        } else {
            out.push(if c == '\n' { ' ' } else { c });
        }
    }
    out.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// A real numeric variable as f64, whatever its stored type.
fn numbers(var: &MatVariable) -> Option<Vec<f64>> {
    if var.is_complex() == Some(true) {
        return None;
    }
    var.to_vec::<f64>()
        .or_else(|| var.to_vec::<f32>().map(|v| v.into_iter().map(f64::from).collect()))
        .or_else(|| var.to_vec::<i32>().map(|v| v.into_iter().map(f64::from).collect()))
        .or_else(|| var.to_vec::<u32>().map(|v| v.into_iter().map(f64::from).collect()))
        .or_else(|| var.to_vec::<u16>().map(|v| v.into_iter().map(f64::from).collect()))
        .or_else(|| var.to_vec::<i16>().map(|v| v.into_iter().map(f64::from).collect()))
        .or_else(|| var.to_vec::<u8>().map(|v| v.into_iter().map(f64::from).collect()))
        .or_else(|| var.to_vec::<i8>().map(|v| v.into_iter().map(f64::from).collect()))
        // Beyond 2^53 an integer is rounded; no time, count or range here comes near.
        .or_else(|| var.to_vec::<i64>().map(|v| v.into_iter().map(|x| x as f64).collect()))
        .or_else(|| var.to_vec::<u64>().map(|v| v.into_iter().map(|x| x as f64).collect()))
}

/// Variable `name` of `mat` as numbers, with its dimensions.
fn variable(mat: &MatFile, file: &Path, name: &str) -> Result<(Vec<f64>, Vec<usize>), LogError> {
    let var = &mat[name];
    if matches!(var, MatVariable::Null) {
        return Err(LogError::File { file: file.to_path_buf(), problem: format!("no variable `{name}`") });
    }
    let values = numbers(var).ok_or_else(|| LogError::File {
        file: file.to_path_buf(),
        problem: if var.is_complex() == Some(true) {
            format!("variable `{name}` is complex; the data set's values are real")
        } else {
            format!("variable `{name}` is not a numeric array of real numbers")
        },
    })?;
    Ok((values, var.dim()))
}

/// A vector variable (1 x N or N x 1).
fn vector(mat: &MatFile, file: &Path, name: &str) -> Result<Vec<f64>, LogError> {
    let (values, dim) = variable(mat, file, name)?;
    if dim.iter().filter(|&&d| d > 1).count() > 1 {
        return Err(LogError::File { file: file.to_path_buf(), problem: format!("`{name}` is {dim:?}, not a vector") });
    }
    Ok(values)
}

fn check_times(file: &Path, name: &str, t: &[f64]) -> Result<(), LogError> {
    if t.is_empty() {
        return Err(LogError::File { file: file.to_path_buf(), problem: format!("`{name}` is empty") });
    }
    if let Some(k) = t.iter().position(|v| !v.is_finite()) {
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: format!("`{name}` element {} is not finite ({})", k + 1, t[k]),
        });
    }
    for (k, w) in t.windows(2).enumerate() {
        if w[1] < w[0] {
            return Err(LogError::File {
                file: file.to_path_buf(),
                problem: format!("`{name}` element {} ({}) comes before element {} ({})", k + 2, w[1], k + 1, w[0]),
            });
        }
    }
    Ok(())
}

/// Refuses a clock (`name`, in seconds once read) whose median step lies outside `window`
/// (see [`CONTROL_STEP_S`]): times in other units. `unit` is what the file should hold.
fn check_step(file: &Path, name: &str, t_s: &[f64], window: (f64, f64), unit: &str) -> Result<(), LogError> {
    let mut steps: Vec<f64> = t_s.windows(2).map(|w| w[1] - w[0]).filter(|d| *d > 0.0).collect();
    if steps.is_empty() {
        // One time has no rate to judge; several, all equal, are a clock that never ran
        // (every scan would be at one instant, the vehicle still between them).
        if t_s.len() > 1 {
            return Err(LogError::File {
                file: file.to_path_buf(),
                problem: format!(
                    "`{name}`: all {} times are the same ({} s); a clock that never advanced",
                    t_s.len(),
                    t_s[0]
                ),
            });
        }
        return Ok(());
    }
    let mid = steps.len() / 2;
    let median = *steps.select_nth_unstable_by(mid, f64::total_cmp).1;
    if median < window.0 || median > window.1 {
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: format!(
                "`{name}` steps by {median:.3e} s (median) once read as {unit}, outside the {}-{} s of the data set's \
                 rate: times in another unit?",
                window.0, window.1
            ),
        });
    }
    Ok(())
}

fn controls(file: &Path, time_s: &[f64], speed: &[f64], steering: &[f64]) -> Result<Motion, LogError> {
    if speed.len() != time_s.len() || steering.len() != time_s.len() {
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: format!(
                "{} times, {} speeds and {} steering angles: they must match",
                time_s.len(),
                speed.len(),
                steering.len()
            ),
        });
    }
    check_times(file, "time", time_s)?;
    if let Some(k) = (0..time_s.len()).find(|&k| !(speed[k].is_finite() && steering[k].is_finite())) {
        return Err(LogError::File { file: file.to_path_buf(), problem: format!("control {} is not finite", k + 1) });
    }
    let controls: Vec<(f64, Control)> =
        (0..time_s.len()).map(|k| (time_s[k], Control::Ackermann { speed: speed[k], steering: steering[k] })).collect();
    for (k, &(t, control)) in controls.iter().enumerate() {
        if let Some(problem) = (MotionMessage::Control { t, control }).impossibility() {
            return Err(LogError::File { file: file.to_path_buf(), problem: format!("control {}: {problem}", k + 1) });
        }
    }
    Ok(Motion::Controls(controls))
}

fn read_detections_form(file: &Path) -> Result<(Motion, Observations), LogError> {
    let mat = load(file)?;
    let time = vector(&mat, file, "time")?;
    let (u, u_dim) = variable(&mat, file, "u")?;
    if u_dim.first() != Some(&2) || u.len() != 2 * time.len() {
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: format!("`u` is {u_dim:?}; expected 2 x {} (speed; steering)", time.len()),
        });
    }
    // Column-major 2 x N: speed, steering alternate.
    let speed: Vec<f64> = u.iter().step_by(2).copied().collect();
    let steering: Vec<f64> = u.iter().skip(1).step_by(2).copied().collect();
    let motion = controls(file, &time, &speed, &steering)?;
    check_step(file, "time", &time, CONTROL_STEP_S, "seconds")?;
    let scan_times = vector(&mat, file, "TLsr")?;
    check_times(file, "TLsr", &scan_times)?;
    check_step(file, "TLsr", &scan_times, SCAN_STEP_S, "seconds")?;
    let zt = &mat["zt"];
    let MatVariable::CellArray(_) = zt else {
        return Err(LogError::File { file: file.to_path_buf(), problem: "`zt` is missing or not a cell array".into() });
    };
    let cells: usize = zt.dim().iter().product();
    if cells > scan_times.len() {
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: format!("`zt` has {cells} cells, more than `TLsr` has times ({})", scan_times.len()),
        });
    }
    let mut scans = Vec::with_capacity(scan_times.len());
    for (k, &t) in scan_times.iter().enumerate() {
        let cell = &zt[k];
        if matches!(cell, MatVariable::Null) {
            return Err(LogError::File {
                file: file.to_path_buf(),
                problem: format!("`zt` has fewer cells than `TLsr` has times ({})", scan_times.len()),
            });
        }
        let MatVariable::NumericArray(_) = cell else {
            return Err(LogError::File {
                file: file.to_path_buf(),
                problem: format!("`zt` cell {} is not a numeric matrix", k + 1),
            });
        };
        let values = numbers(cell).ok_or_else(|| LogError::File {
            file: file.to_path_buf(),
            problem: format!("`zt` cell {} holds values that are not real numbers", k + 1),
        })?;
        let dim = cell.dim();
        // A scan that saw no tree (an empty cell) gives the filter nothing to do.
        if values.is_empty() {
            continue;
        }
        if dim.len() != 2 || dim[0] != 3 || !values.len().is_multiple_of(3) {
            return Err(LogError::File {
                file: file.to_path_buf(),
                problem: format!("`zt` cell {} is {dim:?}; expected 3 x N (range; bearing; diameter)", k + 1),
            });
        }
        let mut detections = Vec::with_capacity(values.len() / 3);
        for d in values.chunks_exact(3) {
            if !d.iter().all(|v| v.is_finite()) || d[0] <= 0.0 {
                return Err(LogError::File {
                    file: file.to_path_buf(),
                    problem: format!("`zt` cell {} holds a detection that is not finite or not ahead: {d:?}", k + 1),
                });
            }
            if d[1].abs() > std::f64::consts::TAU {
                return Err(LogError::File {
                    file: file.to_path_buf(),
                    problem: format!("`zt` cell {} holds bearing {} beyond a turn: radians, not degrees", k + 1, d[1]),
                });
            }
            // A diameter of 0 is the form's "not measured"; below, no trunk.
            if d[2] < 0.0 {
                return Err(LogError::File {
                    file: file.to_path_buf(),
                    problem: format!("`zt` cell {} holds a negative diameter: {d:?}", k + 1),
                });
            }
            // Bearings run 0..pi from the laser's right, pi/2 straight ahead.
            let diameter_m = (d[2] > 0.0).then_some(d[2]);
            detections.push(Detection { range_m: d[0], bearing_rad: d[1] - std::f64::consts::FRAC_PI_2, diameter_m });
        }
        scans.push(DetectionScan { t, detections });
    }
    Ok((motion, Observations::Detections(scans)))
}

fn read_dead_reckoning(file: &Path) -> Result<Motion, LogError> {
    let mat = load(file)?;
    let time_s: Vec<f64> = vector(&mat, file, "time")?.into_iter().map(|ms| ms / 1000.0).collect();
    let motion = controls(file, &time_s, &vector(&mat, file, "speed")?, &vector(&mat, file, "steering")?)?;
    check_step(file, "time", &time_s, CONTROL_STEP_S, "milliseconds")?;
    Ok(motion)
}

fn read_laser(file: &Path) -> Result<Observations, LogError> {
    let mat = load(file)?;
    let times: Vec<f64> = vector(&mat, file, "TLsr")?.into_iter().map(|ms| ms / 1000.0).collect();
    check_times(file, "TLsr", &times)?;
    check_step(file, "TLsr", &times, SCAN_STEP_S, "milliseconds")?;
    let (ranges, dim) = variable(&mat, file, "LASER")?;
    if dim != [times.len(), 361] {
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: format!("`LASER` is {dim:?}; expected {} x 361 (one row per time of `TLsr`)", times.len()),
        });
    }
    let n = times.len();
    if let Some(i) = ranges.iter().position(|cm| !(cm.is_finite() && *cm >= 0.0)) {
        let why = if ranges[i].is_finite() { "not negative" } else { "a finite number" };
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: format!(
                "`LASER` row {}, beam {} is {}: ranges are centimetres, {why}",
                i % n + 1,
                i / n + 1,
                ranges[i]
            ),
        });
    }
    // Ranges in another unit: in metres no beam reaches 100 (nor the no-return code
    // above 8000); in millimetres the no-return code (8183 cm) reads 81,830, more than the
    // 65,535 a uint16 reading in centimetres holds, and where no beam saw nothing, every
    // beam beyond 8 m reads as no return.
    let largest = ranges.iter().copied().fold(0.0, f64::max);
    if !ranges.is_empty() && largest < 100.0 {
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: format!(
                "`LASER`: no range of any scan reaches 100 (the largest is {largest}), so none reaches 1 m if these \
                 are centimetres: ranges in metres?"
            ),
        });
    }
    if largest > f64::from(u16::MAX) {
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: format!(
                "`LASER`: a range of {largest}, more than the 65535 the data set's 16-bit centimetres hold (no return \
                 is 8183): ranges in millimetres?"
            ),
        });
    }
    if !ranges.is_empty() && ranges.iter().all(|&cm| cm > 8000.0) {
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: "`LASER`: every range of every scan is above 8000 cm, the code for no return, so no scan saw \
                      anything: ranges in millimetres?"
                .into(),
        });
    }
    let scans = times
        .iter()
        .enumerate()
        .map(|(k, &t)| LaserScan {
            t,
            angle_min: -std::f64::consts::FRAC_PI_2,
            angle_increment: 0.5f64.to_radians(),
            range_min: 0.5,
            range_max: 80.0,
            // Column-major N x 361; cm, above 8000 no return.
            ranges: (0..361)
                .map(|b| {
                    let cm = ranges[b * n + k];
                    if cm > 8000.0 { f64::INFINITY } else { cm / 100.0 }
                })
                .collect(),
        })
        .collect();
    Ok(Observations::Scans(scans))
}

fn read_gps(file: &Path) -> Result<Vec<ReferenceSample>, LogError> {
    let mat = load(file)?;
    let t = vector(&mat, file, "timeGps")?;
    let (x, y) = (vector(&mat, file, "Lo_m")?, vector(&mat, file, "La_m")?);
    if x.len() != t.len() || y.len() != t.len() {
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: format!("{} times, {} longitudes and {} latitudes: they must match", t.len(), x.len(), y.len()),
        });
    }
    check_times(file, "timeGps", &t)?;
    let t_s: Vec<f64> = t.iter().map(|ms| ms / 1000.0).collect();
    check_step(file, "timeGps", &t_s, GPS_STEP_S, "milliseconds")?;
    let max = crate::format::MAX_COORDINATE_M;
    if let Some(k) = (0..t.len()).find(|&k| x[k].abs().max(y[k].abs()) > max) {
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: format!("fix {} ({:.3e}, {:.3e}) lies beyond {max:e} m", k + 1, x[k], y[k]),
        });
    }
    let fixes: Vec<ReferenceSample> = (0..t.len())
        .filter(|&k| x[k].is_finite() && y[k].is_finite())
        .map(|k| ReferenceSample { t: t_s[k], x: x[k], y: y[k], theta: None })
        .collect();
    // Gaps are NaN; a file of nothing but gaps is no reference, and the run would be
    // scored against nothing while naming the file as read.
    if fixes.is_empty() {
        return Err(LogError::File {
            file: file.to_path_buf(),
            problem: format!("none of its {} fixes has finite `Lo_m` and `La_m`", t.len()),
        });
    }
    Ok(fixes)
}

/// Writes `log` in the detections form and the GPS file (`VictoriaParkSinSincronizar.mat`,
/// `aa3_gpsx.mat`), as the published copies are laid out: for tests that need the
/// data set's form without the data set.
pub fn write_detections_form(dir: &Path, log: &Log) -> Result<(), LogError> {
    use matrw::{CellArray, NumericArray};
    let (Motion::Controls(controls), Observations::Detections(scans)) = (&log.motion, &log.observations) else {
        return Err(LogError::File {
            file: dir.join(DETECTIONS_FILE),
            problem: "the detections form holds speed and steering controls and detections".into(),
        });
    };
    let mut time = Vec::new();
    let mut u = Vec::new();
    for (t, c) in controls {
        let Control::Ackermann { speed, steering } = c else {
            return Err(LogError::File { file: dir.join(DETECTIONS_FILE), problem: "controls must be a car's".into() });
        };
        time.push(*t);
        u.extend([*speed, *steering]);
    }
    let numeric = |dim: Vec<usize>, v: Vec<f64>| -> Result<MatVariable, LogError> {
        NumericArray::new(dim, v.into(), None)
            .map(MatVariable::NumericArray)
            .map_err(|e| LogError::File { file: dir.join(DETECTIONS_FILE), problem: e.to_string() })
    };
    let cells = scans
        .iter()
        .map(|s| {
            let v: Vec<f64> = s
                .detections
                .iter()
                .flat_map(|d| [d.range_m, d.bearing_rad + std::f64::consts::FRAC_PI_2, d.diameter_m.unwrap_or(0.0)])
                .collect();
            numeric(vec![3, s.detections.len()], v)
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut mat = MatFile::new();
    let n = time.len();
    mat.insert("time", numeric(vec![1, n], time)?);
    mat.insert("u", numeric(vec![2, n], u)?);
    mat.insert("TLsr", numeric(vec![1, scans.len()], scans.iter().map(|s| s.t).collect())?);
    let zt = CellArray::new(vec![1, cells.len()], cells)
        .map_err(|e| LogError::File { file: dir.join(DETECTIONS_FILE), problem: e.to_string() })?;
    mat.insert("zt", MatVariable::CellArray(zt));
    save(&dir.join(DETECTIONS_FILE), mat)?;
    if !log.reference.is_empty() {
        let mut gps = MatFile::new();
        let col = |v: Vec<f64>| numeric(vec![v.len(), 1], v);
        gps.insert("timeGps", col(log.reference.iter().map(|r| (r.t * 1000.0).round()).collect())?);
        gps.insert("Lo_m", col(log.reference.iter().map(|r| r.x).collect())?);
        gps.insert("La_m", col(log.reference.iter().map(|r| r.y).collect())?);
        save(&dir.join(GPS_FILE), gps)?;
    }
    Ok(())
}

fn save(file: &Path, mat: MatFile) -> Result<(), LogError> {
    let path = file
        .to_str()
        .ok_or_else(|| LogError::File { file: file.to_path_buf(), problem: "path is not UTF-8".into() })?;
    matrw::save_matfile_v7(path, mat, true)
        .map_err(|e| LogError::File { file: file.to_path_buf(), problem: e.to_string() })
}
