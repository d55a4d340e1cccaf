//! A log read as it is replayed: the manifest in memory, the motion and the range sensor's
//! scans one message at a time, the reference and the list of camera frames read again
//! from their files for each pass over them, so that a replay's memory does not grow with
//! the log's length ([`crate::format::open`]).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use slam::messages::{Control, LaserScan, OdometryIncrement};

use crate::{CameraFrameFile, DetectionScan, Log, LogError, Manifest, Motion, Observations, ReferenceSample};

/// One motion message.
#[derive(Debug, Clone, PartialEq)]
pub enum MotionMessage {
    Increment(OdometryIncrement),
    Control { t: f64, control: Control },
}

/// The fastest speed a vehicle's odometry may report (m/s): the speed of sound in air. No
/// ground robot's wheels read more; a larger value is corrupt data, and a large enough one
/// overflows the filter's variances.
pub const MAX_SPEED_M_S: f64 = 343.0;

/// Fastest turn rate a control may give: two turns a second, well past what ground
/// robots turn (a Pioneer 2-AT at most 300 deg/s) with their odometry's errors. Most rates
/// in degrees per second read as radians go past it.
pub const MAX_TURN_RATE_RAD_S: f64 = 2.0 * std::f64::consts::TAU;

impl MotionMessage {
    /// What makes this message impossible, if anything: a speed beyond [`MAX_SPEED_M_S`],
    /// a step beyond [`crate::format::MAX_COORDINATE_M`] or turning more than half a turn,
    /// a turn rate beyond [`MAX_TURN_RATE_RAD_S`], or steering at or past a right angle,
    /// where a car's turning geometry (tan of the angle) has no value.
    pub fn impossibility(&self) -> Option<String> {
        let too_fast = |name: &str, v: f64| {
            (v.abs() > MAX_SPEED_M_S).then(|| format!("{name} {v:e} m/s is beyond {MAX_SPEED_M_S} m/s"))
        };
        match *self {
            MotionMessage::Increment(o) => {
                let max = crate::format::MAX_COORDINATE_M;
                (o.dx.abs().max(o.dy.abs()) > max)
                    .then(|| format!("a step of ({:e}, {:e}) m is beyond {max:e} m", o.dx, o.dy))
                    .or_else(|| {
                        // Odometry reads each step's turn, never more than half a turn of it.
                        (o.dtheta.abs() > std::f64::consts::PI)
                            .then(|| format!("dtheta {} rad is more than half a turn in one step (degrees, or headings subtracted without wrapping?)", o.dtheta))
                    })
            }
            MotionMessage::Control { control: Control::Differential { v, omega }, .. } => {
                too_fast("speed", v).or_else(|| {
                    (omega.abs() > MAX_TURN_RATE_RAD_S).then(|| {
                        format!(
                            "omega {omega} rad/s is beyond two turns a second, {MAX_TURN_RATE_RAD_S:.3} rad/s (degrees?)"
                        )
                    })
                })
            }
            MotionMessage::Control { control: Control::Ackermann { speed, steering }, .. } => too_fast("speed", speed)
                .or_else(|| {
                    (steering.abs() >= std::f64::consts::FRAC_PI_2)
                        .then(|| format!("steering {steering} rad is at or past a right angle"))
                }),
        }
    }

    /// The increment, if this is one.
    pub fn into_increment(self) -> Option<OdometryIncrement> {
        match self {
            MotionMessage::Increment(o) => Some(o),
            MotionMessage::Control { .. } => None,
        }
    }

    /// The control and its time, if this is one.
    pub fn into_control(self) -> Option<(f64, Control)> {
        match self {
            MotionMessage::Control { t, control } => Some((t, control)),
            MotionMessage::Increment(_) => None,
        }
    }

    pub fn time(&self) -> f64 {
        match self {
            MotionMessage::Increment(o) => o.t,
            MotionMessage::Control { t, .. } => *t,
        }
    }
}

/// One scan of the range sensor: whole, or its detections.
#[derive(Debug, Clone, PartialEq)]
pub enum ObservationMessage {
    Scan(LaserScan),
    Detections(DetectionScan),
}

impl ObservationMessage {
    pub fn time(&self) -> f64 {
        match self {
            ObservationMessage::Scan(s) => s.t,
            ObservationMessage::Detections(d) => d.t,
        }
    }
}

/// Messages in time order. A file's fault comes as an error in the place of the message it
/// is found in (a detection scan's rows are read up to the next scan's first), and ends
/// the messages.
pub type Messages<T> = std::iter::Peekable<Rows<T>>;

/// Rows read one at a time; a fault comes in the place of the row it is found in and ends
/// them.
pub type Rows<T> = Box<dyn Iterator<Item = Result<T, LogError>>>;

/// Rows of a log that a replay passes over more than once (the reference: once to find the
/// GPS's spikes, again as the poses come; the camera's frame list: checked when the log is
/// opened, then followed). From a file they are checked whole when the log is opened and
/// read afresh for each pass, so that their number costs no memory; a log made in memory
/// keeps them there.
pub struct Reread<T> {
    len: usize,
    source: RereadSource<T>,
}

enum RereadSource<T> {
    Memory(Arc<Vec<T>>),
    File { file: PathBuf, read: fn(&Path) -> Result<Rows<T>, LogError>, stamp: FileStamp },
}

/// What tells a file changed: its length, modification time and (on Unix) inode.
#[derive(Debug, Clone, PartialEq)]
struct FileStamp {
    len: u64,
    modified: Option<std::time::SystemTime>,
    inode: Option<u64>,
}

impl FileStamp {
    fn of(file: &Path) -> Result<FileStamp, LogError> {
        let m = std::fs::metadata(file).map_err(|source| LogError::Io { file: file.to_path_buf(), source })?;
        #[cfg(unix)]
        let inode = Some(std::os::unix::fs::MetadataExt::ino(&m));
        #[cfg(not(unix))]
        let inode = None;
        Ok(FileStamp { len: m.len(), modified: m.modified().ok(), inode })
    }
}

/// The error for a file that changed between two readings of it.
fn changed(file: &Path) -> LogError {
    LogError::File {
        file: file.to_path_buf(),
        problem: "changed after the log was opened (a replay reads it again as it goes): replay a log that nothing is writing".into(),
    }
}

impl<T: Clone + 'static> Reread<T> {
    pub fn in_memory(rows: Vec<T>) -> Self {
        Reread { len: rows.len(), source: RereadSource::Memory(Arc::new(rows)) }
    }

    /// The rows of `file` as `read` reads them, all read once now to check them and count
    /// them.
    pub(crate) fn checked(file: &Path, read: fn(&Path) -> Result<Rows<T>, LogError>) -> Result<Self, LogError> {
        let stamp = FileStamp::of(file)?;
        let mut len = 0;
        for row in read(file)? {
            row.map_err(|e| if FileStamp::of(file).ok().as_ref() == Some(&stamp) { e } else { changed(file) })?;
            len += 1;
        }
        if FileStamp::of(file)? != stamp {
            return Err(changed(file));
        }
        Ok(Reread { len, source: RereadSource::File { file: file.to_path_buf(), read, stamp } })
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The file the rows are read from (`None` for rows held in memory).
    pub fn file(&self) -> Option<&Path> {
        match &self.source {
            RereadSource::Memory(_) => None,
            RereadSource::File { file, .. } => Some(file),
        }
    }

    /// The rows from the first. A file that changed since it was checked is an error: at
    /// the start, in the place of a row that no longer reads, or after the last row.
    pub fn rows(&self) -> Result<Rows<T>, LogError> {
        match &self.source {
            RereadSource::Memory(rows) => {
                let rows = Arc::clone(rows);
                Ok(Box::new((0..rows.len()).map(move |k| Ok(rows[k].clone()))))
            }
            RereadSource::File { file, read, stamp } => {
                // Gone, or another file: changed all the same.
                if FileStamp::of(file).ok().as_ref() != Some(stamp) {
                    return Err(changed(file));
                }
                let mut inner = read(file)?;
                let (file, stamp, len) = (file.clone(), stamp.clone(), self.len);
                let same = move |file: &Path| FileStamp::of(file).ok().as_ref() == Some(&stamp);
                let (mut count, mut done) = (0, false);
                Ok(Box::new(std::iter::from_fn(move || {
                    if done {
                        return None;
                    }
                    match inner.next() {
                        Some(Ok(row)) => {
                            count += 1;
                            Some(Ok(row))
                        }
                        Some(Err(e)) => {
                            done = true;
                            Some(Err(if same(&file) { e } else { changed(&file) }))
                        }
                        None => {
                            done = true;
                            (count != len || !same(&file)).then(|| Err(changed(&file)))
                        }
                    }
                })))
            }
        }
    }

    /// All rows in memory.
    pub fn collect(&self) -> Result<Vec<T>, LogError> {
        self.rows()?.collect()
    }
}

/// A log whose motion and observations are read as they are taken.
pub struct LogStream {
    pub manifest: Manifest,
    /// Ground truth or GPS.
    pub reference: Reread<ReferenceSample>,
    pub camera: Reread<CameraFrameFile>,
    pub motion: Messages<MotionMessage>,
    pub observations: Messages<ObservationMessage>,
}

/// The time of the next message, or the error that stands in its place.
pub fn next_time<T>(messages: &mut Messages<T>, time: impl Fn(&T) -> f64) -> Result<Option<f64>, LogError> {
    match messages.peek() {
        None => Ok(None),
        Some(Ok(m)) => Ok(Some(time(m))),
        Some(Err(_)) => match messages.next() {
            Some(Err(e)) => Err(e),
            _ => unreachable!("peeked an error"),
        },
    }
}

impl From<Log> for LogStream {
    fn from(log: Log) -> Self {
        let motion: Box<dyn Iterator<Item = Result<MotionMessage, LogError>>> = match log.motion {
            Motion::Increments(v) => Box::new(v.into_iter().map(|o| Ok(MotionMessage::Increment(o)))),
            Motion::Controls(v) => {
                Box::new(v.into_iter().map(|(t, control)| Ok(MotionMessage::Control { t, control })))
            }
        };
        let observations: Box<dyn Iterator<Item = Result<ObservationMessage, LogError>>> = match log.observations {
            Observations::Scans(v) => Box::new(v.into_iter().map(|s| Ok(ObservationMessage::Scan(s)))),
            Observations::Detections(v) => Box::new(v.into_iter().map(|d| Ok(ObservationMessage::Detections(d)))),
        };
        LogStream {
            manifest: log.manifest,
            reference: Reread::in_memory(log.reference),
            camera: Reread::in_memory(log.camera),
            motion: motion.peekable(),
            observations: observations.peekable(),
        }
    }
}
