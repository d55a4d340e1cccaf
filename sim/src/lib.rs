//! # sim — what a world *does*
//!
//! Turns a [`worlds::World`] into a time-ordered stream of sensor messages with ground truth
//! beside them: a rapier3d world with people walking their routes, a Pioneer 2-AT following
//! the world's route, wheel odometry with an error model, and a SICK-style raycast laser.
//!
//! Deterministic: a fixed physics step, and every random draw from its own `ChaCha8Rng`
//! seeded from the run seed, so the same world, settings and seed give bit-identical
//! streams whatever the number of threads.
//!
//! ```
//! let world = worlds::generate::park(&Default::default(), 1).unwrap();
//! let mut sim = sim::Simulation::new(&world, &sim::SimConfig::default(), 42).unwrap();
//! let mut scans = 0;
//! while let Some(event) = sim.next_event() {
//!     if let sim::SensorEvent::Laser { scan, .. } = event {
//!         assert_eq!(scan.ranges.len(), 361);
//!         scans += 1;
//!     }
//!     if sim.time() > 1.0 { break; }
//! }
//! assert_eq!(scans, 11); // 10 Hz, first scan at t = 0
//! ```

pub mod camera;
pub mod camera_model;
mod camera_thread;
pub mod config;
pub mod controller;
pub mod laser;
pub mod messages;
pub mod odometry;
pub mod people;
pub mod physics;
mod raycast;

use std::collections::VecDeque;

pub use config::{LaserConfig, OdometryConfig, RobotConfig, SimConfig};
pub use messages::*;

use controller::PathFollower;
use laser::Laser;
use odometry::OdometryModel;
use physics::PhysicsScene;

/// Errors from setting up a simulation.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("simulator setting {field}: {message}")]
    Config { field: String, message: String },
    #[error("world: {0}")]
    World(#[from] worlds::WorldError),
    #[error("camera: {0}")]
    Camera(#[from] camera::CameraError),
    #[error("cannot start a thread: {0}")]
    Thread(String),
}

/// Longest run a simulation gives itself when no `max_duration_s` is set (s): a month.
pub const MAX_DEFAULT_DURATION_S: f64 = 30.0 * 86_400.0;

/// Derives independent seeds for each random source from the run seed, so adding a
/// sensor never changes another sensor's noise.
pub fn derive_seed(seed: u64, stream: &str) -> u64 {
    // FNV-1a of the stream name, then SplitMix64 of the combination.
    let mut h: u64 = 0xcbf29ce484222325;
    for b in stream.bytes() {
        h = (h ^ b as u64).wrapping_mul(0x100000001b3);
    }
    let mut z = seed ^ h;
    z = z.wrapping_add(0x9e3779b97f4a7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58476d1ce4e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d049bb133111eb);
    z ^ (z >> 31)
}

/// Schedules a periodic sensor: due at k / rate, fired at the first step at or after.
#[derive(Debug, Clone)]
struct Schedule {
    period: f64,
    next_k: u64,
}

impl Schedule {
    fn new(rate_hz: f64) -> Self {
        Schedule { period: 1.0 / rate_hz, next_k: 0 }
    }

    fn due(&mut self, t: f64) -> bool {
        // A small tolerance absorbs float error in t = step * dt.
        if t + 1e-9 >= self.next_k as f64 * self.period {
            while t + 1e-9 >= self.next_k as f64 * self.period {
                self.next_k += 1;
            }
            true
        } else {
            false
        }
    }
}

/// How far (simulated seconds) physics and the laser may run ahead of a camera frame that
/// is still rendering on the camera's thread.
pub const CAMERA_LOOKAHEAD_S: f64 = 1.0;

/// A message waiting in the simulator's queue: ready, or a frame the camera's thread is
/// rendering (with the ground truth of its instant).
enum Pending {
    Ready(SensorEvent),
    Frame(GroundTruth),
}

/// Chooses, from the laser scan of a frame's instant (and what its beams truly hit, for
/// consumers that score against ground truth), the pixel regions (sorted by column,
/// column-disjoint) of that frame a consumer will read.
pub type RegionSelector = Box<dyn Fn(&LaserScan, &LaserTruth) -> Vec<render::Region> + Send + Sync>;

/// A running simulation.
pub struct Simulation {
    pub world: worlds::World,
    pub config: SimConfig,
    pub seed: u64,
    scene: PhysicsScene,
    follower: PathFollower,
    laser: Laser,
    odometry: OdometryModel,
    laser_schedule: Schedule,
    odometry_schedule: Schedule,
    camera: Option<camera::CameraSensor>,
    /// The camera when it renders on a thread of its own (then `camera` is `None`).
    camera_thread: Option<camera_thread::CameraThread>,
    camera_schedule: Schedule,
    camera_error: Option<String>,
    /// See [`Simulation::render_camera_regions`].
    camera_regions: Option<RegionSelector>,
    step: u64,
    dt: f64,
    pending: VecDeque<Pending>,
    last_scan: Option<LaserScan>,
    people: Vec<PersonState>,
    touching: Vec<u16>,
    collisions: Vec<Collision>,
    done: bool,
    max_duration_s: f64,
}

impl Simulation {
    pub fn new(world: &worlds::World, config: &SimConfig, seed: u64) -> Result<Self, SimError> {
        config.check()?;
        let dt = 1.0 / config.physics_rate_hz;
        let scene = PhysicsScene::build(world, &config.robot, dt);
        let mount = controller::LaserMount {
            forward_m: config.laser.mount_xyz_m[0],
            left_m: config.laser.mount_xyz_m[1],
            yaw_rad: config.laser.mount_yaw_deg.to_radians(),
        };
        let follower = PathFollower::new(&world.robot, &config.robot, mount);
        // Without a limit, allow three times the nominal driving time (people may block);
        // one beyond a simulated month is a cruise speed nobody meant, and would look hung.
        let max_duration_s = match config.max_duration_s {
            Some(d) => d,
            None => {
                let d = 3.0 * follower.total_length() / config.robot.cruise_speed_mps + 30.0;
                if d > MAX_DEFAULT_DURATION_S {
                    return Err(SimError::Config {
                        field: "robot.cruise_speed_mps".into(),
                        message: format!(
                            "at {} m/s the route of {:.0} m would run for {d:.3e} s: give a cruise speed the robot drives at, or sim.max_duration_s for a run that long",
                            config.robot.cruise_speed_mps,
                            follower.total_length()
                        ),
                    });
                }
                d
            }
        };
        let mut sim = Simulation {
            world: world.clone(),
            config: config.clone(),
            seed,
            laser: Laser::new(&config.laser, derive_seed(seed, "laser")),
            odometry: OdometryModel::new(&config.odometry, derive_seed(seed, "odometry")),
            laser_schedule: Schedule::new(config.laser.rate_hz),
            odometry_schedule: Schedule::new(config.odometry.rate_hz),
            camera: if config.camera.enabled {
                Some(camera::CameraSensor::new(world, &config.camera, derive_seed(seed, "camera"))?)
            } else {
                None
            },
            camera_thread: None,
            camera_schedule: Schedule::new(config.camera.rate_hz),
            camera_error: None,
            camera_regions: None,
            scene,
            follower,
            step: 0,
            dt,
            pending: VecDeque::new(),
            last_scan: None,
            people: Vec::new(),
            touching: Vec::new(),
            collisions: Vec::new(),
            done: false,
            max_duration_s,
        };
        sim.people = sim.scene.pose_people(0.0, 0.0, true);
        sim.emit_sensors();
        Ok(sim)
    }

    /// Simulated time of the current step.
    pub fn time(&self) -> f64 {
        self.step as f64 * self.dt
    }

    /// Ground truth now.
    pub fn ground_truth(&self) -> GroundTruth {
        GroundTruth { t: self.time(), robot: self.scene.robot_pose(), people: self.people.clone() }
    }

    /// Every contact the robot has made so far (recorded when each begins).
    pub fn collisions(&self) -> &[Collision] {
        &self.collisions
    }

    /// The odometry's systematic errors drawn for this run: (distance scale, turn scale,
    /// heading bias in rad per metre), as ground truth for a filter that estimates them.
    pub fn odometry_errors(&self) -> [f64; 3] {
        [self.odometry.scale_error, self.odometry.turn_scale_error, self.odometry.heading_bias_rad_per_m]
    }

    /// Whether the robot has finished its route (or the time limit was reached).
    pub fn finished(&self) -> bool {
        self.done
    }

    /// Fraction of the route driven so far.
    pub fn route_progress(&self) -> f64 {
        self.follower.progress() / self.follower.total_length().max(1e-9)
    }

    /// Whether the robot reached its route's end (where the controller stops, a little
    /// short of the last waypoint): what a run's `route_completed` reports, on a route of
    /// any length (a share of the route would ask a short one to end closer than the
    /// controller stops).
    pub fn route_completed(&self) -> bool {
        self.follower.finished()
    }

    /// The simulated time after which the run stops, finished or not: `max_duration_s`,
    /// or the limit derived from the route when it is not set.
    pub fn time_limit_s(&self) -> f64 {
        self.max_duration_s
    }

    /// Nominal duration of the run: route length over cruise speed (for progress bars).
    pub fn nominal_duration_s(&self) -> f64 {
        self.follower.total_length() / self.config.robot.cruise_speed_mps
    }

    /// The camera, when enabled and rendering inline (`None` once it renders on its own
    /// thread).
    pub fn camera(&self) -> Option<&camera::CameraSensor> {
        self.camera.as_ref()
    }

    /// Where a consumer gives back camera frames it is done with, for the camera to render
    /// into again (faster, same pixels); `None` when the camera is off.
    pub fn camera_frame_pool(&self) -> Option<camera::FramePool> {
        self.camera.as_ref().map(|c| c.frame_pool()).or_else(|| self.camera_thread.as_ref().map(|c| c.frame_pool()))
    }

    /// The adapter rendering the camera's frames, when the camera is on.
    pub fn camera_adapter(&self) -> Option<render::AdapterSummary> {
        self.camera.as_ref().map(|c| c.adapter()).or_else(|| self.camera_thread.as_ref().map(|c| c.adapter().clone()))
    }

    /// Renders the camera's frames from now on on a thread of its own: physics and the laser
    /// go on while a frame renders, up to [`CAMERA_LOOKAHEAD_S`] of simulated time ahead of
    /// the oldest frame not yet delivered. The event stream is the same as inline (a test).
    /// Worth it when a core is free for the physics (a single run); nothing to gain where
    /// other runs fill the cores.
    pub fn render_camera_on_thread(&mut self) -> Result<(), SimError> {
        if let Some(camera) = self.camera.take() {
            self.camera_thread =
                Some(camera_thread::CameraThread::start(camera).map_err(|e| SimError::Thread(e.to_string()))?);
        }
        Ok(())
    }

    /// From now on renders each camera frame only in the pixel regions `select` picks from
    /// the laser scan of the same instant (frames with no scan at their instant are
    /// rendered whole). For consumers that read only where the laser points, as the
    /// paper's segmentation does: the pixels rendered are those of the whole frame (the
    /// frame's `image.regions` says which), at a fraction of the rendering cost. Regions
    /// that are not sorted by column, column-disjoint and within the image stop the camera
    /// with an error, as a lost renderer does ([`Simulation::camera_error`]).
    pub fn render_camera_regions(&mut self, select: RegionSelector) {
        self.camera_regions = Some(select);
    }

    /// A rendering failure that stopped the camera mid-run, if any.
    pub fn camera_error(&self) -> Option<&str> {
        self.camera_error.as_deref()
    }

    pub fn laser(&self) -> &Laser {
        &self.laser
    }

    /// The physics scene, for sensors added beside the simulator (the camera).
    pub fn scene(&self) -> &PhysicsScene {
        &self.scene
    }

    /// Current people states.
    pub fn people(&self) -> &[PersonState] {
        &self.people
    }

    /// The next sensor message, advancing physics as needed; `None` when the run is over.
    pub fn next_event(&mut self) -> Option<SensorEvent> {
        loop {
            match self.pending.front() {
                Some(Pending::Ready(_)) => {
                    let Some(Pending::Ready(event)) = self.pending.pop_front() else { unreachable!("just matched") };
                    return Some(event);
                }
                Some(Pending::Frame(truth)) => {
                    let ahead = self.time() - truth.t;
                    let thread = self.camera_thread.as_ref().expect("frames are pending only from the camera thread");
                    let frame = match thread.try_frame() {
                        Some(frame) => frame,
                        // Simulate on while the frame renders.
                        None if !self.done && ahead < CAMERA_LOOKAHEAD_S => {
                            self.advance();
                            continue;
                        }
                        None => thread.frame(),
                    };
                    let Some(Pending::Frame(truth)) = self.pending.pop_front() else { unreachable!("just matched") };
                    match frame {
                        Ok(frame) => return Some(SensorEvent::Camera { frame: Box::new(frame), truth }),
                        Err(e) => {
                            // As inline: a lost renderer ends the camera, not the run.
                            self.camera_error = Some(e.to_string());
                            self.camera_thread = None;
                            self.pending.retain(|p| matches!(p, Pending::Ready(_)));
                        }
                    }
                }
                None if self.done => return None,
                None => self.advance(),
            }
        }
    }

    /// One physics step: control, people, physics, contacts, then the sensors due.
    fn advance(&mut self) {
        let pose = self.scene.robot_pose();
        let (v, omega) = self.follower.command(&pose, self.last_scan.as_ref());
        self.scene.drive(v, omega);
        let t_next = (self.step + 1) as f64 * self.dt;
        self.people = self.scene.pose_people(t_next, self.dt, false);
        self.scene.step();
        self.step += 1;

        let touching = self.scene.robot_contacts();
        for id in &touching {
            if !self.touching.contains(id) {
                self.collisions.push(Collision { t: self.time(), instance_id: *id, robot: self.scene.robot_pose() });
            }
        }
        self.touching = touching;
        self.emit_sensors();
        if self.follower.finished() || self.time() >= self.max_duration_s {
            self.done = true;
        }
    }

    fn emit_sensors(&mut self) {
        let t = self.time();
        let truth = self.ground_truth();
        if self.odometry_schedule.due(t) {
            let odometry = self.odometry.measure(t, truth.robot);
            self.pending.push_back(Pending::Ready(SensorEvent::Odometry { odometry, truth: truth.clone() }));
        }
        // The scan first (the laser draws from its own random stream), so the frame of the
        // same instant can be rendered where that scan says it will be read; the image
        // still comes before the scan in the stream, so a pipeline that segments scans in
        // images has the matching image when the scan arrives.
        let scan = self.laser_schedule.due(t).then(|| self.laser.scan(&self.scene, &truth.robot, t));
        if self.camera_schedule.due(t) {
            let regions = match (&self.camera_regions, &scan) {
                (Some(select), Some((scan, beams))) => Some(select(scan, beams)),
                _ => None,
            };
            if let Some(thread) = &self.camera_thread {
                thread.request(t, truth.robot, truth.people.clone(), regions);
                self.pending.push_back(Pending::Frame(truth.clone()));
            } else if let Some(cam) = &mut self.camera {
                match cam.capture_regions(t, &truth.robot, &truth.people, regions.as_deref()) {
                    Ok(frame) => self.pending.push_back(Pending::Ready(SensorEvent::Camera {
                        frame: Box::new(frame),
                        truth: truth.clone(),
                    })),
                    Err(e) => {
                        // A lost GPU device ends the camera, not the run; the error is kept.
                        self.camera_error = Some(e.to_string());
                        self.camera = None;
                    }
                }
            }
        }
        if let Some((scan, beams)) = scan {
            self.last_scan = Some(scan.clone());
            self.pending.push_back(Pending::Ready(SensorEvent::Laser { scan, beams, truth }));
        }
    }
}
