//! The online half of a run: each sensor event goes to the pipeline, and what the pipeline
//! reports goes to the scorer and to the run's logs. The pipeline keeps no history; what
//! the metrics and the outputs need of it is kept here.

use std::collections::BTreeMap;

use sim::SensorEvent;
use slam::association::AssociationDecision;
use slam::ekf::smoother::{Relinearisation, SmootherError};
use slam::pipeline::Pipeline;

use super::outputs::{Stream, StreamedOutputs, association_line, segmentation_line, trees_shown_line};
use super::{RunError, slam_scan};
use crate::score::scorer::{Fusion, RunScorer, ScoredObservation, as_written_to_tum, true_object};
use crate::score::segmentation::ClassImage;
use crate::visibility::InstanceImage;

/// A solve of the smoother after a loop closure, at a scan's time: what it did, or why it
/// failed.
pub(super) type Solve = (f64, Result<Relinearisation, SmootherError>);

/// The ground-truth images of the latest camera frame (moved, not copied: about 1 MB).
struct TruthImages {
    t: f64,
    width: u32,
    height: u32,
    class: Vec<u8>,
    instance: Vec<u16>,
    regions: Option<Vec<render::Region>>,
}

/// What a run keeps of the pipeline's reports: the figures every run scores, and the logs
/// only runs that write outputs keep (Monte Carlo runs do not).
#[derive(Default)]
pub(super) struct RunLog {
    /// Each association decision with its observation's true object (outputs only).
    pub decisions: Vec<(AssociationDecision, u16)>,
    pub solves: Vec<Solve>,
    /// Landmarks fused into others.
    pub merged: usize,
    /// Estimated and true paths (t, x, y, theta) at each odometry message.
    pub estimate: Vec<(f64, [f64; 3])>,
    pub truth: Vec<(f64, [f64; 3])>,
    /// The estimated pose's covariance at each odometry message (outputs only).
    pub covariances: Vec<[[f64; 3]; 3]>,
    /// Fusions of landmarks at each scan's time (outputs only: decisions.jsonl).
    pub fusions: Vec<(f64, Fusion)>,
    /// The robot's contacts, one JSON line each (collisions.jsonl).
    pub collisions: String,
    pub people_tracks: BTreeMap<u16, Vec<[f64; 2]>>,
    /// Seconds spent on events (pipeline and scoring), and on the pipeline's scans alone.
    pub event_s: f64,
    pub scan_s: f64,
    pub scans: usize,
    /// Pixels the camera rendered, of the pixels its frames hold.
    pub pixels_rendered: u64,
    pub pixels_framed: u64,
}

/// Feeds the simulator's events to the pipeline, and the pipeline's reports to the scorer
/// and the log.
pub(super) struct RunLoop<'w> {
    pub pipeline: Pipeline,
    pub scorer: RunScorer<'w>,
    world: &'w worlds::World,
    /// The outputs written as the run goes (runs that write outputs).
    pub streams: Option<StreamedOutputs>,
    /// A scan and the frame of its instant fire within this many seconds (the same physics
    /// step).
    same_instant_s: f64,
    last_frame: Option<TruthImages>,
    /// Where frames go back to the camera once the pipeline and the scorer are done with
    /// them (see `sim::camera::FramePool`).
    spent_frames: Option<sim::camera::FramePool>,
    pub log: RunLog,
}

impl<'w> RunLoop<'w> {
    pub fn new(
        pipeline: Pipeline,
        scorer: RunScorer<'w>,
        world: &'w worlds::World,
        streams: Option<StreamedOutputs>,
        physics_rate_hz: f64,
        spent_frames: Option<sim::camera::FramePool>,
    ) -> Self {
        RunLoop {
            pipeline,
            scorer,
            world,
            streams,
            same_instant_s: 0.5 / physics_rate_hz,
            last_frame: None,
            spent_frames,
            log: RunLog::default(),
        }
    }

    pub fn on_event(&mut self, event: SensorEvent) -> Result<(), RunError> {
        let tick = std::time::Instant::now();
        match event {
            SensorEvent::Odometry { odometry, truth } => self.on_odometry(&odometry, &truth.robot)?,
            SensorEvent::Laser { scan, beams, truth } => self.on_scan(&scan, &beams, &truth)?,
            SensorEvent::Camera { frame, .. } => self.on_frame(frame)?,
        }
        self.log.event_s += tick.elapsed().as_secs_f64();
        Ok(())
    }

    fn on_odometry(&mut self, odometry: &sim::Odometry, robot: &sim::Pose2D) -> Result<(), RunError> {
        self.pipeline.on_odometry(&slam::messages::OdometryIncrement {
            t: odometry.t,
            dx: odometry.dx,
            dy: odometry.dy,
            dtheta: odometry.dtheta,
        })?;
        let est = self.pipeline.pose();
        if let Some(streams) = &mut self.streams {
            streams.write(Stream::Odometry, &(crate::record::odometry_line(odometry) + "\n"))?;
            self.log.covariances.push(est.covariance);
        }
        let truth = [robot.x, robot.y, robot.theta];
        self.log.estimate.push((odometry.t, est.pose));
        self.log.truth.push((odometry.t, truth));
        self.scorer.on_pose(odometry.t, as_written_to_tum(est.pose), Some(est.covariance), as_written_to_tum(truth));
        Ok(())
    }

    fn on_scan(
        &mut self,
        scan: &sim::LaserScan,
        beams: &sim::LaserTruth,
        truth: &sim::GroundTruth,
    ) -> Result<(), RunError> {
        let s = slam_scan(scan);
        let tick = std::time::Instant::now();
        let mut report = self.pipeline.on_scan(&s)?;
        self.log.scan_s += tick.elapsed().as_secs_f64();
        self.log.scans += 1;
        if self.streams.is_some() {
            for d in std::mem::take(&mut report.decisions) {
                let c = &report.clusters[d.observation];
                let object = true_object(&beams.hit_ids, c.first_beam, c.last_beam);
                self.log.decisions.push((d, object));
            }
        }
        self.log.solves.extend(report.relinearisations.drain(..).map(|r| (s.t, r)));
        for r in &report.retractions {
            self.scorer.on_retraction(r.landmark);
        }
        self.log.merged += report.merges.len();
        for rec in &report.segmentations {
            let frame = self.last_frame.as_ref().map(|f| ClassImage { t: f.t, width: f.width, class: &f.class });
            let objects = self.scorer.on_segmentation(rec, &report.clusters, beams, frame.as_ref());
            if let Some(streams) = &mut self.streams {
                for (cs, object) in rec.clusters.iter().zip(objects) {
                    let c = &report.clusters[cs.index];
                    streams
                        .write(Stream::Segmentation, &segmentation_line(s.t, rec.t_image, cs, c, object, self.world))?;
                }
            }
        }
        let observations: Vec<ScoredObservation> = report
            .clusters
            .iter()
            .zip(&report.assigned)
            .map(|(c, landmark)| ScoredObservation {
                first_beam: c.first_beam,
                last_beam: c.last_beam,
                landmark: *landmark,
            })
            .collect();
        let fusions: Vec<Fusion> = report.merges.iter().map(|m| Fusion { kept: m.kept, removed: m.removed }).collect();
        let frame =
            self.last_frame.as_ref().filter(|f| (f.t - scan.t).abs() < self.same_instant_s).map(|f| InstanceImage {
                t: f.t,
                width: f.width,
                height: f.height,
                instance: &f.instance,
                regions: f.regions.as_deref(),
            });
        let shown = frame.map(|f| self.scorer.beams_shown(scan, beams, &f));
        self.scorer.on_scan(scan, beams, shown.as_deref(), &observations, &fusions);
        if let Some(streams) = &mut self.streams {
            self.log.fusions.extend(fusions.iter().map(|f| (scan.t, *f)));
            streams.write(Stream::Associations, &association_line(scan.t, &observations, &fusions))?;
            for (stream, line) in [
                (Stream::Laser, crate::record::laser_line(scan)),
                (Stream::LaserTruth, crate::record::laser_truth_line(scan.t, beams)),
                (Stream::Observations, crate::record::observations_line(scan.t, &report.clusters)),
            ] {
                streams.write(stream, &(line + "\n"))?;
            }
            if let Some(shown) = shown.filter(|s| !s.is_empty()) {
                streams.write(Stream::TreesShown, &trees_shown_line(scan.t, &shown))?;
            }
        }
        for p in &truth.people {
            self.log.people_tracks.entry(p.id).or_default().push([p.x, p.y]);
        }
        Ok(())
    }

    fn on_frame(&mut self, frame: Box<sim::camera::CameraFrame>) -> Result<(), RunError> {
        // Moved, not copied: a frame is about 1.5 MB.
        let img = frame.image;
        let whole = img.width as u64 * img.height as u64;
        self.log.pixels_rendered += img.regions.as_ref().map_or(whole, |r| r.iter().map(render::Region::area).sum());
        self.log.pixels_framed += whole;
        let regions = img
            .regions
            .as_ref()
            .map(|r| r.iter().map(|r| slam::features::PixelRegion { columns: r.columns, rows: r.rows }).collect());
        let spent_rgb = self.pipeline.on_image_regions(frame.t, img.width, img.height, img.rgb, regions)?;
        let spent_truth = self.last_frame.replace(TruthImages {
            t: frame.t,
            width: img.width,
            height: img.height,
            class: img.class,
            instance: img.instance,
            regions: img.regions,
        });
        // The frame before this one is read by no one now: its colour went to the pipeline
        // and its masks to the scorer, each kept until the next frame.
        if let (Some(pool), Some(rgb), Some(truth)) = (&self.spent_frames, spent_rgb, spent_truth) {
            pool.give(render::Frame {
                width: truth.width,
                height: truth.height,
                rgb,
                instance: truth.instance,
                class: truth.class,
                depth_m: Vec::new(),
                regions: truth.regions,
            });
        }
        Ok(())
    }
}
