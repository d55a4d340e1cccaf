//! Robot logs for the `slam` crate: a documented, tool-neutral directory of plain files
//! ([`format`]), and readers for published data sets ([`victoria_park`]).
//!
//! A [`Log`] holds what a run of a real robot delivers, all on one clock: the vehicle's
//! motion (odometry increments or controls), what its range sensor saw (whole laser scans
//! or point detections), optionally a camera's frames, and optionally a reference path
//! (ground truth or GPS), with the sensors' mounting and noise in a [`Manifest`]. The format's reference is
//! docs/reference/robot-log.md.

pub mod format;
pub mod line_ends;
pub mod manifest;
pub mod stream;
pub mod victoria_park;

use std::path::PathBuf;

pub use manifest::{Manifest, ReferenceKind, ReferencePoint};
use slam::messages::{Control, Detection, LaserScan, OdometryIncrement};

/// How the vehicle's motion is given.
#[derive(Debug, Clone, PartialEq)]
pub enum Motion {
    /// Motion since the previous message in the robot frame (`odometry.csv`: `t,dx,dy,dtheta`).
    Increments(Vec<OdometryIncrement>),
    /// Controls that hold until the next one (`t,v,omega` or `t,speed,steering`).
    Controls(Vec<(f64, Control)>),
}

impl Motion {
    pub fn len(&self) -> usize {
        match self {
            Motion::Increments(v) => v.len(),
            Motion::Controls(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// One scan's point detections.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectionScan {
    pub t: f64,
    pub detections: Vec<Detection>,
}

/// What the range sensor saw.
#[derive(Debug, Clone, PartialEq)]
pub enum Observations {
    /// Whole scans (`scans.csv`), clustered by the pipeline.
    Scans(Vec<LaserScan>),
    /// Features a detector already extracted (`detections.csv`).
    Detections(Vec<DetectionScan>),
}

impl Observations {
    pub fn len(&self) -> usize {
        match self {
            Observations::Scans(v) => v.len(),
            Observations::Detections(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A reference position (and heading, where known) at time `t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReferenceSample {
    pub t: f64,
    pub x: f64,
    pub y: f64,
    pub theta: Option<f64>,
}

/// A camera frame as `camera.csv` lists it: its time and its image file. The images stay
/// on disk until a replay reaches them ([`format::read_frame`]).
#[derive(Debug, Clone, PartialEq)]
pub struct CameraFrameFile {
    pub t: f64,
    /// As read: the log's directory joined with the listed path. As written: relative
    /// paths are written as they are, taken to be relative to the log's directory.
    pub file: PathBuf,
}

/// A camera image in memory: 8-bit RGB, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

/// A whole log in memory (the camera's images apart).
#[derive(Debug, Clone, PartialEq)]
pub struct Log {
    pub manifest: Manifest,
    pub motion: Motion,
    pub observations: Observations,
    /// Ground truth or GPS (`reference.csv`), in its own frame (see [`Manifest::reference`]).
    pub reference: Vec<ReferenceSample>,
    /// The camera's frames (`camera.csv`), in time order; empty without a camera.
    pub camera: Vec<CameraFrameFile>,
}

/// Errors reading or writing a log; each names the file and, where there is one, the line.
#[derive(Debug, thiserror::Error)]
pub enum LogError {
    #[error("{}: {source}", file.display())]
    Io { file: PathBuf, source: std::io::Error },
    #[error("{}:{line}: {problem}", file.display())]
    Line { file: PathBuf, line: u64, problem: String },
    #[error("{}: {problem}", file.display())]
    File { file: PathBuf, problem: String },
    #[error("{}: no {what} (the log needs {expected})", dir.display())]
    Missing { dir: PathBuf, what: &'static str, expected: &'static str },
}
