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
pub mod config;
pub mod controller;
pub mod laser;
pub mod messages;
pub mod odometry;
pub mod people;
pub mod physics;

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
}

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
    camera_schedule: Schedule,
    camera_error: Option<String>,
    step: u64,
    dt: f64,
    pending: VecDeque<SensorEvent>,
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
        let follower = PathFollower::new(&world.robot, &config.robot);
        // Without a limit, allow three times the nominal driving time (people may block).
        let max_duration_s = config.max_duration_s.unwrap_or(3.0 * follower.total_length() / config.robot.cruise_speed_mps + 30.0);
        let mut sim = Simulation {
            world: world.clone(),
            config: config.clone(),
            seed,
            laser: Laser::new(&config.laser, derive_seed(seed, "laser")),
            odometry: OdometryModel::new(&config.odometry, derive_seed(seed, "odometry")),
            laser_schedule: Schedule::new(config.laser.rate_hz),
            odometry_schedule: Schedule::new(config.odometry.rate_hz),
            camera: if config.camera.enabled { Some(camera::CameraSensor::new(world, &config.camera, derive_seed(seed, "camera"))?) } else { None },
            camera_schedule: Schedule::new(config.camera.rate_hz),
            camera_error: None,
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

    /// Whether the robot has finished its route (or the time limit was reached).
    pub fn finished(&self) -> bool {
        self.done
    }

    /// Fraction of the route driven so far.
    pub fn route_progress(&self) -> f64 {
        self.follower.progress() / self.follower.total_length().max(1e-9)
    }

    /// Nominal duration of the run: route length over cruise speed (for progress bars).
    pub fn nominal_duration_s(&self) -> f64 {
        self.follower.total_length() / self.config.robot.cruise_speed_mps
    }

    /// The camera, when enabled.
    pub fn camera(&self) -> Option<&camera::CameraSensor> {
        self.camera.as_ref()
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
            if let Some(e) = self.pending.pop_front() {
                return Some(e);
            }
            if self.done {
                return None;
            }
            self.advance();
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
            self.pending.push_back(SensorEvent::Odometry { odometry, truth: truth.clone() });
        }
        // At one instant the image comes before the scan, so a pipeline that segments
        // scans in images has the matching image when the scan arrives.
        if let Some(cam) = &mut self.camera
            && self.camera_schedule.due(t)
        {
            match cam.capture(t, &truth.robot, &truth.people) {
                Ok(frame) => self.pending.push_back(SensorEvent::Camera { frame: Box::new(frame), truth: truth.clone() }),
                Err(e) => {
                    // A lost GPU device ends the camera, not the run; the error is kept.
                    self.camera_error = Some(e.to_string());
                    self.camera = None;
                }
            }
        }
        if self.laser_schedule.due(t) {
            let (scan, beams) = self.laser.scan(&self.scene, &truth.robot, t);
            self.last_scan = Some(scan.clone());
            self.pending.push_back(SensorEvent::Laser { scan, beams, truth });
        }
    }
}
