//! A log read as it is replayed: the manifest, the reference and the list of camera frames
//! in memory, the motion and the range sensor's scans one message at a time, so that a
//! replay's memory does not grow with the log's data ([`crate::format::open`]).

use slam::messages::{Control, LaserScan, OdometryIncrement};

use crate::{CameraFrameFile, DetectionScan, Log, LogError, Manifest, Motion, Observations, ReferenceSample};

/// One motion message.
#[derive(Debug, Clone, PartialEq)]
pub enum MotionMessage {
    Increment(OdometryIncrement),
    Control { t: f64, control: Control },
}

impl MotionMessage {
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
pub type Messages<T> = std::iter::Peekable<Box<dyn Iterator<Item = Result<T, LogError>>>>;

/// A log whose motion and observations are read as they are taken.
pub struct LogStream {
    pub manifest: Manifest,
    /// Ground truth or GPS, whole: scoring needs all of it from the start.
    pub reference: Vec<ReferenceSample>,
    pub camera: Vec<CameraFrameFile>,
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
            reference: log.reference,
            camera: log.camera,
            motion: motion.peekable(),
            observations: observations.peekable(),
        }
    }
}
