//! Laser-camera extrinsic calibration in the simulator, after Zhang & Pless (IROS 2004).
//!
//! A calibration session is a *range* of checkerboards: the robot stops at `poses`
//! stations in a row, each with one board in front of it at a seeded distance, bearing,
//! height, turn and tilt (tilts and turns are stratified, so the board normals spread over
//! the whole allowed range whatever the seed), plus a distractor post behind it. Stations
//! are far enough apart that no other board is in the camera's view; the laser sees them
//! (and the posts), which the segmentation must reject. At each station the simulator
//! takes one laser scan (its noise model and quantisation) and one camera frame (its
//! noise settings), exactly as in a run.
//!
//! Per station the board is detected in the image ([`slam::checkerboard::detect`]: its
//! plane N in the camera frame), the board's points are segmented from the scan
//! ([`slam::calibration::segment_board`]: the straight stretch of board length within the
//! camera's view and at the range the camera sees the board at), and the pairs are solved
//! for Phi and Delta ([`slam::calibration::calibrate`]). Stations where the board is not
//! found in the image or the scan are reported and skipped.
//!
//! ```no_run
//! let (scenario, base) = scenarios::scenario::Scenario::load("calibration").unwrap();
//! let report = scenarios::calibrate::run_session(&scenario, &base, scenario.seed, None, None).unwrap();
//! println!("{:.3} deg, {:.4} m", report.rotation_error_deg.unwrap(), report.translation_error_m.unwrap());
//! ```

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use sim::camera::{CameraSensor, Rigid};
use sim::{Pose2D, SimConfig};
use slam::calibration::{BoardObservation, BoardSegmentation, Extrinsics};
use worlds::{Appearance, Material, ObjectClass, Pose2, Shape, StaticObject, World};

use crate::scenario::{Scenario, ScenarioError};

/// Version of `calibration.json`.
pub const CALIBRATION_FORMAT_VERSION: u32 = 1;

/// Errors of a calibration session or of a calibration file.
#[derive(Debug, thiserror::Error)]
pub enum CalibrateError {
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    #[error("{}: calibration.session.{field}: {message}", file.display())]
    Session { file: PathBuf, field: String, message: String },
    #[error("calibration range world: {0}")]
    World(String),
    /// A session whose settings pass their checks, but whose stations drawn with this seed
    /// cannot stand where they were drawn: named by the file and the settings to change.
    #[error(
        "{}: calibration.session: the stations drawn with seed {seed} cannot be laid out ({problems}): a board too near the robot's path needs a larger distance_m (or a narrower bearing_deg or turn_deg), objects of neighbouring stations touching a larger station_spacing_m",
        file.display()
    )]
    Layout { file: PathBuf, seed: u64, problems: String },
    #[error(transparent)]
    Sim(#[from] sim::SimError),
    #[error("calibration camera: {0}")]
    Camera(#[from] sim::camera::CameraError),
    /// `kept`: where the session's pose images wait, the earlier session's left in place.
    #[error("calibration failed ({used} of {requested} poses usable{skipped}){kept}: {reason}")]
    Solve { requested: usize, used: usize, skipped: String, kept: String, reason: slam::calibration::CalibrationError },
    #[error("{}: cannot read: {source}", file.display())]
    Read { file: PathBuf, source: std::io::Error },
    #[error("{}: {field}: {message}", file.display())]
    File { file: PathBuf, field: String, message: String },
    #[error("{}: cannot write: {source}", file.display())]
    Write { file: PathBuf, source: std::io::Error },
    /// The number of poses asked for in place of the scenario's.
    #[error("--poses {poses}: {problem}")]
    Poses { poses: usize, problem: String },
}

/// `[calibration.session.segmentation]`: the keys given, each replacing the value the
/// session derives (see [`SessionConfig::segmentation_for`]).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SegmentationSettings {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bearing_rad: Option<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub range_m: Option<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub length_m: Option<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub jump_m: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inlier_m: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trim: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_range_tolerance_m: Option<f64>,
}

impl SegmentationSettings {
    /// `base` with the keys given here in place of its values.
    pub fn apply(&self, base: BoardSegmentation) -> BoardSegmentation {
        BoardSegmentation {
            bearing_rad: self.bearing_rad.unwrap_or(base.bearing_rad),
            range_m: self.range_m.unwrap_or(base.range_m),
            length_m: self.length_m.unwrap_or(base.length_m),
            jump_m: self.jump_m.unwrap_or(base.jump_m),
            inlier_m: self.inlier_m.unwrap_or(base.inlier_m),
            trim: self.trim.unwrap_or(base.trim),
            camera_range_tolerance_m: self.camera_range_tolerance_m.unwrap_or(base.camera_range_tolerance_m),
        }
    }

    /// Every key given, with `s`'s values (the reference's examples).
    pub fn all(s: &BoardSegmentation) -> Self {
        SegmentationSettings {
            bearing_rad: Some(s.bearing_rad),
            range_m: Some(s.range_m),
            length_m: Some(s.length_m),
            jump_m: Some(s.jump_m),
            inlier_m: Some(s.inlier_m),
            trim: Some(s.trim),
            camera_range_tolerance_m: Some(s.camera_range_tolerance_m),
        }
    }
}

/// The calibration session of a scenario (`[calibration.session]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SessionConfig {
    /// Number of board poses (stations).
    pub poses: usize,
    /// Board size (m) and checker squares (across, down); the squares must be square.
    pub board_width_m: f64,
    pub board_height_m: f64,
    pub squares: [u32; 2],
    /// Distance from the laser to the board centre (m).
    pub distance_m: [f64; 2],
    /// Bearing of the board centre from the laser's x axis (deg).
    pub bearing_deg: [f64; 2],
    /// Height of the board centre above the ground (m); the laser's plane must cut the
    /// board.
    pub centre_height_m: [f64; 2],
    /// Turn of the board about the vertical away from facing the laser (deg).
    pub turn_deg: [f64; 2],
    /// Tilt of the board about its width axis (deg, positive: face up). Tilts are needed:
    /// with upright boards only, every normal is horizontal and the camera's height and
    /// pitch relative to the laser cannot be recovered.
    pub tilt_deg: [f64; 2],
    /// Distance between stations (m): keeps other boards out of the camera's view.
    pub station_spacing_m: f64,
    /// Laser scans taken at each station while the robot stands still (at the laser's
    /// rate), averaged beam by beam before segmentation: each scan has the laser's full
    /// noise; averaging n of them divides it by sqrt(n), as a real calibration does by
    /// standing still for a moment at each pose.
    pub scans_per_pose: usize,
    /// A post behind each board, in the laser's view, that segmentation must reject.
    pub distractors: bool,
    /// Laser segmentation settings: the bearing window, ranges, board lengths, inlier
    /// distance and range tolerance are set from the camera, the session's distances and
    /// the board's size ([`SessionConfig::segmentation_for`]); a key given here replaces its
    /// derived value, and the keys left out keep theirs.
    pub segmentation: Option<SegmentationSettings>,
}

impl Default for SessionConfig {
    fn default() -> Self {
        SessionConfig {
            poses: 20,
            board_width_m: 0.8,
            board_height_m: 0.6,
            squares: [8, 6],
            distance_m: [1.4, 2.6],
            bearing_deg: [-10.0, 10.0],
            centre_height_m: [0.45, 0.6],
            turn_deg: [-40.0, 40.0],
            tilt_deg: [-35.0, 35.0],
            station_spacing_m: 12.0,
            scans_per_pose: 10,
            distractors: true,
            segmentation: None,
        }
    }
}

/// Fewest board poses a session may ask for: the linear estimate needs 5 with laser points
/// (each constrains 2 of its 9 unknowns). Thousands add nothing but time.
pub const POSES: std::ops::RangeInclusive<usize> = 5..=10_000;

/// The longest line of stations a session may lay out, centred on the origin: as far out
/// as a world may reach ([`worlds::validate::MAX_COORDINATE_M`]: there a single-precision
/// coordinate, the physics' and the renderer's, is good to 0.06 mm, well under the
/// millimetres a calibration resolves), less 100 m for the boards beside their stations
/// and the ground around them. At 100 km a coordinate is good to 4 mm, and a session
/// spaced that far measured 0.36 degrees of error against 0.03-0.17 at the default.
pub const MAX_STATION_SPAN_M: f64 = 2.0 * (worlds::validate::MAX_COORDINATE_M - 100.0);

impl SessionConfig {
    /// Checks the settings for a session run with `sim`'s sensors; `file` names the
    /// scenario in errors.
    pub fn check(&self, file: &Path, sim: &SimConfig) -> Result<(), CalibrateError> {
        self.check_settings(file)?;
        self.check_for_sensors(file, sim)
    }

    /// Checks what does not depend on the sensors: a scenario that does not run its
    /// session (calibration mode other than `estimated`) is checked this far, so that a
    /// laser mounted where no board of the session would cut it is not refused for a
    /// session it never runs (`objslam calibrate` checks the rest).
    pub fn check_settings(&self, file: &Path) -> Result<(), CalibrateError> {
        let bad = |field: &str, message: String| {
            Err(CalibrateError::Session { file: file.to_path_buf(), field: field.into(), message })
        };
        if !POSES.contains(&self.poses) {
            return bad(
                "poses",
                format!(
                    "must be {}..{} (a calibration needs at least {} board poses), got {}",
                    POSES.start(),
                    POSES.end(),
                    POSES.start(),
                    self.poses
                ),
            );
        }
        if !(1..=1000).contains(&self.scans_per_pose) {
            return bad("scans_per_pose", format!("must be 1..1000, got {}", self.scans_per_pose));
        }
        for (field, v) in [
            ("board_width_m", self.board_width_m),
            ("board_height_m", self.board_height_m),
            ("station_spacing_m", self.station_spacing_m),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(field, format!("must be finite and positive, got {v}"));
            }
        }
        if self.squares.iter().any(|&n| n > 100) {
            return bad("squares", format!("at most 100 squares each way, got {:?}", self.squares));
        }
        if self.squares[0] < 3 || self.squares[1] < 3 {
            return bad(
                "squares",
                format!("the detector needs at least 3 x 3 squares (2 x 2 inner corners), got {:?}", self.squares),
            );
        }
        let (sx, sy) = (self.board_width_m / self.squares[0] as f64, self.board_height_m / self.squares[1] as f64);
        if (sx - sy).abs() > 1e-6 * sx {
            return bad("squares", format!("squares must be square: {sx:.4} m across but {sy:.4} m down"));
        }
        for (field, r) in [
            ("distance_m", self.distance_m),
            ("bearing_deg", self.bearing_deg),
            ("centre_height_m", self.centre_height_m),
            ("turn_deg", self.turn_deg),
            ("tilt_deg", self.tilt_deg),
        ] {
            if !(r[0].is_finite() && r[1].is_finite() && r[0] <= r[1]) {
                return bad(field, format!("must be a range [low, high] with low <= high, got {r:?}"));
            }
        }
        if self.distance_m[0] <= 0.3 {
            return bad("distance_m", format!("boards must be more than 0.3 m away, got {:?}", self.distance_m));
        }
        if self.tilt_deg[0] < -worlds::validate::MAX_BOARD_TILT_DEG
            || self.tilt_deg[1] > worlds::validate::MAX_BOARD_TILT_DEG
        {
            return bad(
                "tilt_deg",
                format!("must be within +-{} deg, got {:?}", worlds::validate::MAX_BOARD_TILT_DEG, self.tilt_deg),
            );
        }
        if self.turn_deg[0] <= -80.0 || self.turn_deg[1] >= 80.0 {
            return bad(
                "turn_deg",
                format!(
                    "must lie strictly between -80 and 80 deg (the camera must see the board's face), got {:?}",
                    self.turn_deg
                ),
            );
        }
        let max_tilt = self.tilt_deg[0].abs().max(self.tilt_deg[1].abs()).to_radians();
        let lowest = self.centre_height_m[0]
            - 0.5 * self.board_height_m * max_tilt.cos()
            - 0.5 * worlds::BOARD_THICKNESS_M * max_tilt.sin();
        if lowest < 0.0 {
            return bad(
                "centre_height_m",
                format!("the lowest, most tilted board reaches {:.3} m below the ground", -lowest),
            );
        }
        let footprint = self.board_width_m.max(self.board_height_m) + 2.0 * self.distance_m[1];
        if self.station_spacing_m < footprint {
            return bad(
                "station_spacing_m",
                format!(
                    "must be at least {footprint:.1} m so neighbouring stations' boards stay out of the camera's view, got {}",
                    self.station_spacing_m
                ),
            );
        }
        if let Some(span) = too_long_a_line(self.poses, self.station_spacing_m) {
            return bad(
                "station_spacing_m",
                format!(
                    "the {} stations stand in a line {span:.0} m long ((poses - 1) x {} m), more than {MAX_STATION_SPAN_M} m: \
                     farther out, the simulator's single-precision physics and rendering cost the calibration its accuracy; \
                     ask for fewer poses or a shorter spacing",
                    self.poses, self.station_spacing_m
                ),
            );
        }
        // The keys given, each checked as it will be used (beside the others' defaults:
        // derived values pass the same checks).
        if let Some(s) = &self.segmentation
            && let Err((field, message)) = s.apply(BoardSegmentation::default()).validate()
        {
            return bad(&format!("segmentation.{field}"), message);
        }
        Ok(())
    }

    /// Checks the session against the sensors that would run it.
    fn check_for_sensors(&self, file: &Path, sim: &SimConfig) -> Result<(), CalibrateError> {
        let bad = |field: &str, message: String| {
            Err(CalibrateError::Session { file: file.to_path_buf(), field: field.into(), message })
        };
        // The laser's plane must cut every board, away from its edges.
        // Both sensors must see every board: its centre (a bearing from the laser's axis)
        // within the camera's half field of view of the camera's axis, and the laser's of
        // its own.
        let camera_axis = sim.camera.mount_yaw_deg - sim.laser.mount_yaw_deg;
        let half_camera = sim.camera.hfov_deg / 2.0;
        let half_laser = sim.laser.fov_deg / 2.0;
        let seen = |b: f64| (b - camera_axis).abs() <= half_camera && b.abs() <= half_laser;
        if !(seen(self.bearing_deg[0]) && seen(self.bearing_deg[1])) {
            return bad(
                "bearing_deg",
                format!(
                    "boards must stand where both sensors see them: within +-{half_camera} deg of the camera's axis ({camera_axis} deg from the laser's) and +-{half_laser} deg of the laser's, got {:?}",
                    self.bearing_deg
                ),
            );
        }
        let laser_z = sim.laser.mount_xyz_m[2];
        let max_tilt = self.tilt_deg[0].abs().max(self.tilt_deg[1].abs()).to_radians();
        let reach = 0.4 * self.board_height_m * max_tilt.cos();
        if self.centre_height_m[0] - reach > laser_z || self.centre_height_m[1] + reach < laser_z {
            return bad(
                "centre_height_m",
                format!(
                    "the laser's plane ({laser_z:.2} m up) must cut the boards well inside their height: centres must be within {reach:.2} m of it, got {:?}",
                    self.centre_height_m
                ),
            );
        }
        Ok(())
    }

    fn square_m(&self) -> f64 {
        self.board_width_m / self.squares[0] as f64
    }

    fn inner_corners(&self) -> (usize, usize) {
        (self.squares[0] as usize - 1, self.squares[1] as usize - 1)
    }

    /// Segmentation settings: from the camera's field of view and mounting, the laser's
    /// noise, the session's distances and the board's size, with the keys the scenario
    /// gives in their place.
    pub fn segmentation_for(&self, sim: &SimConfig) -> BoardSegmentation {
        let derived = self.derived_segmentation(sim);
        match &self.segmentation {
            Some(given) => given.apply(derived),
            None => derived,
        }
    }

    fn derived_segmentation(&self, sim: &SimConfig) -> BoardSegmentation {
        let half_fov = (sim.camera.hfov_deg / 2.0 + 5.0).to_radians();
        let yaw = (sim.camera.mount_yaw_deg - sim.laser.mount_yaw_deg).to_radians();
        let noise = sim.laser.range_noise_sigma_m;
        let lever_arm_m =
            (0..3).map(|k| (sim.camera.mount_xyz_m[k] - sim.laser.mount_xyz_m[k]).powi(2)).sum::<f64>().sqrt();
        BoardSegmentation {
            bearing_rad: [yaw - half_fov, yaw + half_fov],
            range_m: [0.5 * self.distance_m[0], 1.5 * self.distance_m[1] + self.board_width_m],
            length_m: [
                0.5 * self.board_width_m.min(self.board_height_m),
                1.05 * self.board_width_m.hypot(self.board_height_m),
            ],
            inlier_m: (4.0 * noise + sim.laser.quantum_m()).max(0.01),
            // The laser's range to the board and the camera's differ by up to the distance
            // between the two sensors, on top of the margin for the board's own extent.
            camera_range_tolerance_m: BoardSegmentation::default().camera_range_tolerance_m + lever_arm_m,
            ..Default::default()
        }
    }
}

/// One stop of the robot in front of one board.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Station {
    pub index: usize,
    /// Robot base pose (x, y, theta).
    pub robot: [f64; 3],
    pub board: StaticObject,
    pub distractor: Option<StaticObject>,
    /// The board's tilt and its turn away from facing the laser (deg).
    pub tilt_deg: f64,
    pub turn_deg: f64,
}

/// Id of station k's board; its distractor is `DISTRACTOR_ID_BASE + k`.
const BOARD_ID_BASE: u16 = 1000;
/// Above every board's id, however many poses a session asks for.
const DISTRACTOR_ID_BASE: u16 = BOARD_ID_BASE + *POSES.end() as u16;

/// Draws the stations of a session from `seed`.
pub fn plan_stations(config: &SessionConfig, sim: &SimConfig, seed: u64) -> Vec<Station> {
    let mut rng = ChaCha8Rng::seed_from_u64(sim::derive_seed(seed, "calibration-plan"));
    let n = config.poses;
    // Stratified tilts and turns: one per 1/n of each range, paired at random.
    let strata = |rng: &mut ChaCha8Rng| {
        let mut p: Vec<usize> = (0..n).collect();
        for i in (1..n).rev() {
            let j = rng.random_range(0..=i);
            p.swap(i, j);
        }
        p
    };
    let (tilt_strata, turn_strata) = (strata(&mut rng), strata(&mut rng));
    let lerp = |r: [f64; 2], f: f64| r[0] + (r[1] - r[0]) * f;
    let uniform = |rng: &mut ChaCha8Rng, r: [f64; 2]| if r[1] > r[0] { rng.random_range(r[0]..r[1]) } else { r[0] };
    let theta = std::f64::consts::FRAC_PI_2;
    let [mx, my, _] = sim.laser.mount_xyz_m;
    (0..n)
        .map(|k| {
            let x = (k as f64 - (n as f64 - 1.0) / 2.0) * config.station_spacing_m;
            let robot = [x, 0.0, theta];
            let (s, c) = theta.sin_cos();
            let laser = [x + c * mx - s * my, s * mx + c * my];
            let tilt = lerp(config.tilt_deg, (tilt_strata[k] as f64 + rng.random_range(0.0..1.0)) / n as f64);
            let turn = lerp(config.turn_deg, (turn_strata[k] as f64 + rng.random_range(0.0..1.0)) / n as f64);
            let distance = uniform(&mut rng, config.distance_m);
            let bearing =
                uniform(&mut rng, config.bearing_deg).to_radians() + theta + sim.laser.mount_yaw_deg.to_radians();
            let centre_z = uniform(&mut rng, config.centre_height_m);
            let centre = [laser[0] + distance * bearing.cos(), laser[1] + distance * bearing.sin()];
            // Facing the laser, then turned.
            let yaw = (laser[1] - centre[1]).atan2(laser[0] - centre[0]) + turn.to_radians();
            let board = StaticObject::checkerboard(
                BOARD_ID_BASE + k as u16,
                Pose2 { x: centre[0], y: centre[1], yaw_deg: yaw.to_degrees() },
                Shape::Board {
                    width_m: config.board_width_m,
                    height_m: config.board_height_m,
                    bottom_m: centre_z - config.board_height_m / 2.0,
                    squares: config.squares,
                    tilt_deg: tilt,
                    roll_deg: 0.0,
                },
            );
            let distractor = config.distractors.then(|| {
                // Behind the board, off to one side.
                let away = bearing;
                let back = rng.random_range(0.8..1.6) + config.board_width_m / 2.0;
                let side = rng.random_range(-1.2..1.2);
                let p = [
                    centre[0] + back * away.cos() - side * away.sin(),
                    centre[1] + back * away.sin() + side * away.cos(),
                ];
                StaticObject {
                    id: DISTRACTOR_ID_BASE + k as u16,
                    class: ObjectClass::Post,
                    pose: Pose2 { x: p[0], y: p[1], yaw_deg: 0.0 },
                    shape: Shape::Post { radius_m: 0.1, height_m: 1.2 },
                    appearance: Appearance {
                        material: Material::Paint,
                        colour: [0.3, 0.25, 0.2],
                        texture_seed: k as u64,
                    },
                    mesh: None,
                    mesh_data: Default::default(),
                }
            });
            Station { index: k, robot, board, distractor, tilt_deg: tilt, turn_deg: turn }
        })
        .collect()
}

/// The world of a session: a ground like `base`'s, the stations' boards and posts, and
/// the robot at the first station.
pub fn range_world(stations: &[Station], base: &World) -> Result<World, CalibrateError> {
    let mut objects = Vec::new();
    for s in stations {
        objects.push(s.board.clone());
        objects.extend(s.distractor.clone());
    }
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in objects.iter().map(|o| [o.pose.x, o.pose.y]).chain(stations.iter().map(|s| [s.robot[0], s.robot[1]])) {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let first = &stations[0].robot;
    let last = &stations[stations.len() - 1].robot;
    let end = if stations.len() > 1 { [last[0], last[1]] } else { [first[0] + 1.0, first[1]] };
    let world = World {
        format_version: worlds::WORLD_FORMAT_VERSION,
        name: "calibration_range".into(),
        seed: 0,
        ground: worlds::Ground {
            min_m: [lo[0] - 5.0, lo[1] - 5.0],
            max_m: [hi[0] + 5.0, hi[1] + 5.0],
            appearance: base.ground.appearance.clone(),
        },
        objects,
        people: vec![],
        robot: worlds::RobotSpec {
            start: Pose2 { x: first[0], y: first[1], yaw_deg: first[2].to_degrees() },
            route: worlds::Route { waypoints: vec![[first[0], first[1]], end], looping: false },
            laps: 1,
        },
    };
    let problems = worlds::validate::validate(&world, Path::new("."));
    if !problems.is_empty() {
        // The first few: one cause (boards drawn too near) repeats at every station.
        let mut said: Vec<String> = problems.iter().take(3).map(|p| format!("{}: {}", p.field, p.message)).collect();
        if problems.len() > 3 {
            said.push(format!("and {} more", problems.len() - 3));
        }
        return Err(CalibrateError::World(said.join("; ")));
    }
    Ok(world)
}

/// What one station gave.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseReport {
    pub pose: usize,
    /// The board's plane in the camera frame (N), when detected.
    pub plane: Option<[f64; 3]>,
    /// Corner reprojection RMS of the board's pose fit (pixels).
    pub reprojection_rms_px: Option<f64>,
    /// Laser points taken for the board.
    pub laser_points: usize,
    /// Why the pose was skipped, if it was.
    pub skipped: Option<String>,
    /// RMS point-to-plane distance of its laser points under the solution (m).
    pub residual_rms_m: Option<f64>,
    /// Simulator truth, for diagnosis: angle between the detected and true board normals
    /// (deg) and the detected minus the true plane distance (m).
    pub truth_normal_error_deg: Option<f64>,
    pub truth_distance_error_m: Option<f64>,
    /// Board tilt and turn (deg) at this station.
    pub tilt_deg: f64,
    pub turn_deg: f64,
}

/// Everything `calibration.json` holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationReport {
    pub format_version: u32,
    pub tool: String,
    pub scenario: String,
    pub seed: u64,
    /// The estimate: `P_laser = phi P_camera + delta`.
    pub phi: [[f64; 3]; 3],
    pub delta: [f64; 3],
    /// The linear (closed-form) estimate the refinement started from.
    pub initial: Extrinsics,
    /// RMS and largest point-to-plane residual (m) over all points used.
    pub rms_residual_m: f64,
    pub max_residual_m: f64,
    /// One-sigma uncertainty: rotation about the laser's x, y, z axes (deg) and
    /// translation (m): the refinement's (JᵀJ)⁻¹ scaled by the residual variance (the
    /// laser's share, also given alone below) plus each board plane's covariance from its
    /// image carried through the solution to first order.
    pub rotation_sigma_deg: [f64; 3],
    pub translation_sigma_m: [f64; 3],
    pub laser_rotation_sigma_deg: [f64; 3],
    pub laser_translation_sigma_m: [f64; 3],
    pub poses_requested: usize,
    pub poses_used: usize,
    pub poses_skipped: usize,
    pub points_used: usize,
    pub iterations: usize,
    pub warnings: Vec<String>,
    pub poses: Vec<PoseReport>,
    /// The image size and K the calibration assumed.
    pub camera: sim::camera::Intrinsics,
    pub renderer: String,
    /// The simulator's true extrinsics and the estimate's error against them.
    pub truth: Option<Extrinsics>,
    pub rotation_error_deg: Option<f64>,
    pub translation_error_m: Option<f64>,
}

impl CalibrationReport {
    pub fn extrinsics(&self) -> Extrinsics {
        Extrinsics { phi: self.phi, delta: self.delta }
    }

    pub fn write(&self, path: &Path) -> Result<(), CalibrateError> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            // Named as the file asked for: "File exists" of its folder alone misleads.
            std::fs::create_dir_all(dir).map_err(|source| {
                let source = match dir.ancestors().find(|a| a.is_file()) {
                    Some(file) => std::io::Error::other(format!("{} is a file, not a directory", file.display())),
                    None => source,
                };
                CalibrateError::Write { file: path.to_path_buf(), source }
            })?;
        }
        // Whole or not at all: a full disk or a kill leaves the earlier file as it was.
        crate::partial_files::write_whole(path, (serde_json::to_string_pretty(self).expect("JSON") + "\n").as_bytes())
            .map_err(|e| CalibrateError::Write { file: path.to_path_buf(), source: e.source })
    }
}

/// Removes an earlier session's pose images (`pose_NN.png`) from `dir`: a shorter session
/// would otherwise leave some of them among its own, to be taken for its poses.
fn remove_pose_images(dir: &Path) -> Result<(), CalibrateError> {
    let io = |file: &Path| {
        let file = file.to_path_buf();
        move |source| CalibrateError::Write { file, source }
    };
    for entry in std::fs::read_dir(dir).map_err(io(dir))? {
        let path = entry.map_err(io(dir))?.path();
        if is_pose_image_name(&path) {
            std::fs::remove_file(&path).map_err(io(&path))?;
        }
    }
    Ok(())
}

/// Moves a solved session's pose images from `staging` into `dir`, after removing the
/// earlier session's there.
fn publish_pose_images(staging: &Path, dir: &Path) -> Result<(), CalibrateError> {
    let io = |file: &Path| {
        let file = file.to_path_buf();
        move |source| CalibrateError::Write { file, source }
    };
    remove_pose_images(dir)?;
    for entry in std::fs::read_dir(staging).map_err(io(staging))? {
        let from = entry.map_err(io(staging))?.path();
        let to = dir.join(from.file_name().expect("a directory entry has a name"));
        std::fs::rename(&from, &to).map_err(io(&to))?;
    }
    std::fs::remove_dir(staging).map_err(io(staging))
}

/// Whether `file` is named as a session's pose image (`pose_NN.png`): a session with
/// `--images` in its directory writes or removes it.
pub fn is_pose_image_name(file: &Path) -> bool {
    let name = file.file_name().and_then(|n| n.to_str()).unwrap_or_default();
    let digits = name.strip_prefix("pose_").and_then(|n| n.strip_suffix(".png")).unwrap_or_default();
    !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit())
}

/// The simulator's exact laser <- camera extrinsics for a configuration.
pub fn true_extrinsics(sim: &SimConfig) -> Extrinsics {
    rigid_to_extrinsics(&sim.camera.laser_from_camera(&sim.laser))
}

pub fn rigid_to_extrinsics(r: &Rigid) -> Extrinsics {
    Extrinsics { phi: r.r, delta: r.t }
}

/// The length of the line `poses` stations `spacing_m` apart make, where it is longer than
/// [`MAX_STATION_SPAN_M`].
fn too_long_a_line(poses: usize, spacing_m: f64) -> Option<f64> {
    let span = poses.saturating_sub(1) as f64 * spacing_m;
    (span > MAX_STATION_SPAN_M).then_some(span)
}

/// Checks `--poses` against the session's spacing, so that a line of stations too long is
/// refused as the option's fault rather than the scenario's `station_spacing_m`.
fn check_poses_override(poses: usize, spacing_m: f64) -> Result<(), CalibrateError> {
    let problem = if !POSES.contains(&poses) {
        format!(
            "must be {}..{} (a calibration needs at least {} board poses)",
            POSES.start(),
            POSES.end(),
            POSES.start()
        )
    } else if let Some(span) = too_long_a_line(poses, spacing_m) {
        // Only a positive spacing makes the line too long, so the division is sound.
        let most = (MAX_STATION_SPAN_M / spacing_m).floor() as usize + 1;
        format!(
            "the stations would stand in a line {span:.0} m long at the scenario's calibration.session.station_spacing_m \
             ({spacing_m} m), more than {MAX_STATION_SPAN_M} m; at most {most} poses at that spacing"
        )
    } else {
        return Ok(());
    };
    Err(CalibrateError::Poses { poses, problem })
}

/// Runs the calibration session of a scenario with `seed`; `poses` overrides the
/// session's number of poses; with `images`, each pose's camera image is written there
/// (`pose_NN.png`, detected corners marked in red).
pub fn run_session(
    scenario: &Scenario,
    base_dir: &Path,
    seed: u64,
    poses: Option<usize>,
    images: Option<&Path>,
) -> Result<CalibrationReport, CalibrateError> {
    // The scenario's file, or its name when it is built in.
    let file = PathBuf::from(scenario.describe());
    let mut config = scenario.calibration.session.clone();
    if let Some(p) = poses {
        check_poses_override(p, config.station_spacing_m)?;
        config.poses = p;
    }
    config.check(&file, &scenario.sim)?;
    let stations = plan_stations(&config, &scenario.sim, seed);
    // The range's ground looks like the scenario's world's ground.
    let world = range_world(&stations, &scenario.world(base_dir, seed)?).map_err(|e| match e {
        CalibrateError::World(problems) => CalibrateError::Layout { file: file.clone(), seed, problems },
        e => e,
    })?;
    let mut report = calibrate_stations(&world, &stations, &config, &scenario.sim, seed, images)?;
    report.scenario = scenario.name.clone();
    Ok(report)
}

/// Captures a scan and an image at every station of `world` and solves for the
/// extrinsics.
pub fn calibrate_stations(
    world: &World,
    stations: &[Station],
    config: &SessionConfig,
    sim_config: &SimConfig,
    seed: u64,
    images: Option<&Path>,
) -> Result<CalibrationReport, CalibrateError> {
    // The pose images are written beside `images` and moved in once the session is
    // solved: a failed or stopped session leaves the earlier session's images, which
    // match its calibration file, as they were.
    // The directory is held for the session: another command writing into it keeps its
    // unfinished files.
    let (staging, _held) = match images {
        Some(dir) => {
            let write =
                |e: crate::partial_files::PartialFileError| CalibrateError::Write { file: e.file, source: e.source };
            let held = crate::partial_files::lock_output(dir).map_err(write)?;
            // Another command's outputs waiting there to be moved in are not cleared away.
            crate::partial_files::check_no_other_stopped_move(dir, &[]).map_err(write)?;
            (Some(crate::partial_files::start_unfinished(dir).map_err(write)?), Some(held))
        }
        None => (None, None),
    };
    let mut cam_config = sim_config.camera.clone();
    cam_config.enabled = true;
    let mut camera = CameraSensor::new(world, &cam_config, sim::derive_seed(seed, "calibration-camera"))?;
    let scene = sim::physics::PhysicsScene::build(world, &sim_config.robot, 1.0 / sim_config.physics_rate_hz);
    let mut laser = sim::laser::Laser::new(&sim_config.laser, sim::derive_seed(seed, "calibration-laser"));
    let k = cam_config.intrinsics();
    let km = Matrix3::new(k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0);
    let segmentation = config.segmentation_for(sim_config);
    let inner = config.inner_corners();
    let square = config.square_m();
    let board_centre = Vector3::new((inner.0 as f64 - 1.0) / 2.0 * square, (inner.1 as f64 - 1.0) / 2.0 * square, 0.0);

    let mut observations: Vec<BoardObservation> = Vec::new();
    let mut obs_pose: Vec<usize> = Vec::new();
    let mut poses: Vec<PoseReport> = Vec::new();
    for st in stations {
        let t = st.index as f64;
        let robot = Pose2D { x: st.robot[0], y: st.robot[1], theta: st.robot[2] };
        let frame = camera.capture(t, &robot, &[])?;
        let scan = averaged_scan(&mut laser, &scene, &robot, t, config.scans_per_pose);
        let mut pr = PoseReport {
            pose: st.index,
            plane: None,
            reprojection_rms_px: None,
            laser_points: 0,
            skipped: None,
            residual_rms_m: None,
            truth_normal_error_deg: None,
            truth_distance_error_m: None,
            tilt_deg: st.tilt_deg,
            turn_deg: st.turn_deg,
        };
        let detection =
            slam::checkerboard::detect(&frame.image.rgb, k.width as usize, k.height as usize, inner, square, &km);
        if let Some(dir) = &staging {
            let mut rgb = frame.image.rgb.clone();
            for c in detection.as_ref().map(|d| d.corners.clone()).unwrap_or_default() {
                let (u, v) = (c[0].floor() as i64, c[1].floor() as i64);
                for d in -3i64..=3 {
                    for (x, y) in [(u + d, v), (u, v + d)] {
                        if x >= 0 && y >= 0 && x < k.width as i64 && y < k.height as i64 {
                            let i = 3 * (y as usize * k.width as usize + x as usize);
                            rgb[i..i + 3].copy_from_slice(&[255, 0, 0]);
                        }
                    }
                }
            }
            let file = dir.join(format!("pose_{:02}.png", st.index));
            crate::record::write_png(&file, k.width, k.height, image::ExtendedColorType::Rgb8, &rgb).map_err(|e| {
                CalibrateError::Write { file: file.clone(), source: std::io::Error::other(e.to_string()) }
            })?;
        }
        let det = match detection {
            Ok(d) => d,
            Err(e) => {
                pr.skipped = Some(format!("board not found in the image: {e}"));
                poses.push(pr);
                continue;
            }
        };
        pr.plane = Some([det.plane.x, det.plane.y, det.plane.z]);
        pr.reprojection_rms_px = Some(det.reprojection_rms_px);
        if let Some(truth) = true_plane(&st.board, &frame.world_from_camera) {
            pr.truth_normal_error_deg =
                Some(det.plane.normalize().dot(&truth.normalize()).clamp(-1.0, 1.0).acos().to_degrees());
            pr.truth_distance_error_m = Some(det.plane.norm() - truth.norm());
        }
        let camera_range = (det.rotation * board_centre + det.translation).norm();
        let s = crate::run::slam_scan(&scan);
        match slam::calibration::segment_board(&s, &segmentation, Some(camera_range)) {
            // The calibration leaves out a pose whose plane has no covariance: said here.
            Ok(_) if !det.plane_covariance.iter().all(|v| v.is_finite()) => {
                pr.skipped = Some("the board's plane fit gives no covariance (a singular fit)".into());
            }
            Ok(cut) => {
                pr.laser_points = cut.points.len();
                observations.push(BoardObservation {
                    plane: det.plane,
                    laser_points: cut.points,
                    plane_covariance: Some(det.plane_covariance),
                });
                obs_pose.push(poses.len());
            }
            Err(e) => pr.skipped = Some(format!("board not found in the scan: {e}")),
        }
        poses.push(pr);
    }
    let skipped: Vec<String> =
        poses.iter().filter_map(|p| p.skipped.as_ref().map(|r| format!("pose {}: {r}", p.pose))).collect();
    let result = slam::calibration::calibrate(&observations).map_err(|reason| CalibrateError::Solve {
        requested: stations.len(),
        used: observations.len(),
        skipped: if skipped.is_empty() { String::new() } else { format!("; skipped: {}", skipped.join("; ")) },
        kept: match (&staging, images) {
            (Some(s), Some(dir)) => format!(
                "; this session's pose images are in {} (the earlier session's stay in {})",
                s.display(),
                dir.display()
            ),
            _ => String::new(),
        },
        reason,
    })?;
    if let (Some(staging), Some(dir)) = (&staging, images) {
        publish_pose_images(staging, dir)?;
    }
    let est = result.extrinsics;
    let mut max_residual: f64 = 0.0;
    for (o, &pi) in observations.iter().zip(&obs_pose) {
        let r = slam::calibration::point_plane_residuals(&est, o);
        max_residual = r.iter().fold(max_residual, |m, v| m.max(v.abs()));
        poses[pi].residual_rms_m = Some((r.iter().map(|v| v * v).sum::<f64>() / r.len().max(1) as f64).sqrt());
    }
    let mut warnings = result.warnings.clone();
    for s in &skipped {
        warnings.push(format!("skipped {s}"));
    }
    let truth = true_extrinsics(sim_config);
    let (rot_err, trans_err) = est.error_to(&truth);
    Ok(CalibrationReport {
        format_version: CALIBRATION_FORMAT_VERSION,
        tool: format!("objslam calibrate {}", crate::build::describe()),
        scenario: String::new(),
        seed,
        phi: est.phi,
        delta: est.delta,
        initial: result.initial,
        rms_residual_m: result.rms_residual_m,
        max_residual_m: max_residual,
        rotation_sigma_deg: result.rotation_sigma_deg,
        translation_sigma_m: result.translation_sigma_m,
        laser_rotation_sigma_deg: result.laser_rotation_sigma_deg,
        laser_translation_sigma_m: result.laser_translation_sigma_m,
        poses_requested: stations.len(),
        poses_used: result.poses_used,
        poses_skipped: stations.len() - result.poses_used,
        points_used: result.points_used,
        iterations: result.iterations,
        warnings,
        poses,
        camera: k,
        renderer: camera.adapter().to_string(),
        truth: Some(truth),
        rotation_error_deg: Some(rot_err),
        translation_error_m: Some(trans_err),
    })
}

/// `n` scans from a standing robot, averaged beam by beam (a beam without a return in any
/// of them has none).
fn averaged_scan(
    laser: &mut sim::laser::Laser,
    scene: &sim::physics::PhysicsScene,
    robot: &Pose2D,
    t: f64,
    n: usize,
) -> sim::LaserScan {
    let period = 1.0 / laser.config.rate_hz;
    let (mut scan, _) = laser.scan(scene, robot, t);
    for k in 1..n {
        let (next, _) = laser.scan(scene, robot, t + k as f64 * period);
        for (r, q) in scan.ranges.iter_mut().zip(&next.ranges) {
            *r += q;
        }
    }
    for r in &mut scan.ranges {
        *r /= n as f64;
    }
    scan
}

/// The board's front face as the plane vector N in the camera frame (ground truth).
pub fn true_plane(board: &StaticObject, world_from_camera: &Rigid) -> Option<Vector3<f64>> {
    let f = board.shape.board_frame()?;
    let (s, c) = board.pose.yaw_rad().sin_cos();
    let to_world =
        |p: [f64; 3]| Vector3::new(board.pose.x + c * p[0] - s * p[1], board.pose.y + s * p[0] + c * p[1], p[2]);
    let n_m = f.normal();
    let n_w = Vector3::new(c * n_m[0] - s * n_m[1], s * n_m[0] + c * n_m[1], n_m[2]);
    let p_w = to_world(f.apply([worlds::BOARD_THICKNESS_M / 2.0, 0.0, 0.0]));
    let cam_from_world = world_from_camera.inverse();
    let r = Matrix3::from_fn(|a, b| cam_from_world.r[a][b]);
    let n_c = r * n_w;
    let p_c = Vector3::from(cam_from_world.apply([p_w.x, p_w.y, p_w.z]));
    Some(n_c * n_c.dot(&p_c))
}

/// Largest laser-to-camera offset a calibration file may give, per axis.
pub const MAX_MOUNT_OFFSET_M: f64 = 10.0;

/// Reads the extrinsics from a calibration file: a JSON object with `phi` (3x3 rotation,
/// row-major) and `delta` (3 numbers, m), as `objslam calibrate` writes; other keys are
/// ignored. Phi must be a rotation to within 1e-3 (it is re-orthonormalised).
pub fn load_extrinsics(path: &Path) -> Result<Extrinsics, CalibrateError> {
    extrinsics_of(path, &read_json(path)?)
}

/// Like [`load_extrinsics`], for a run with `camera`: where the file names the camera it
/// calibrated (`camera`, as `objslam calibrate` writes it), that camera must be this one.
/// Another image size or K means another camera, whose mounting the file does not
/// measure. A file without `camera` (written by hand or by another tool) is taken as is.
pub fn load_extrinsics_for(path: &Path, camera: &sim::camera::Intrinsics) -> Result<Extrinsics, CalibrateError> {
    let v = read_json(path)?;
    let extrinsics = extrinsics_of(path, &v)?;
    let written = match v.get("camera") {
        None | Some(serde_json::Value::Null) => return Ok(extrinsics),
        Some(c) if c.is_object() => c,
        Some(other) => {
            return Err(CalibrateError::File {
                file: path.to_path_buf(),
                field: "camera".into(),
                message: format!(
                    "must be a table of the image size and K (width, height, fx, fy, cx, cy), got {other}"
                ),
            });
        }
    };
    let bad = |field: &str, message: String| CalibrateError::File {
        file: path.to_path_buf(),
        field: format!("camera.{field}"),
        message,
    };
    let fields = [
        ("width", camera.width as f64),
        ("height", camera.height as f64),
        ("fx", camera.fx),
        ("fy", camera.fy),
        ("cx", camera.cx),
        ("cy", camera.cy),
    ];
    for (field, ours) in fields {
        let value = written.get(field).ok_or_else(|| bad(field, "missing".into()))?;
        let theirs = value.as_f64().ok_or_else(|| bad(field, format!("must be a number, got {value}")))?;
        // The file's own numbers come from the same formula; a relative 1e-9 allows for
        // JSON's shortest round trip only.
        if (theirs - ours).abs() > 1e-9 * ours.abs().max(1.0) {
            return Err(bad(
                field,
                format!(
                    "is {theirs}, but the scenario's camera has {ours}: the file calibrates another camera \
                     (remove its `camera` to use its extrinsics anyway)"
                ),
            ));
        }
    }
    Ok(extrinsics)
}

fn read_json(path: &Path) -> Result<serde_json::Value, CalibrateError> {
    let text =
        std::fs::read_to_string(path).map_err(|source| CalibrateError::Read { file: path.to_path_buf(), source })?;
    serde_json::from_str(&text).map_err(|e| CalibrateError::File {
        file: path.to_path_buf(),
        field: "(file)".into(),
        message: format!("not valid JSON: {e}"),
    })
}

fn extrinsics_of(path: &Path, v: &serde_json::Value) -> Result<Extrinsics, CalibrateError> {
    let bad =
        |field: &str, message: String| CalibrateError::File { file: path.to_path_buf(), field: field.into(), message };
    let obj = v.as_object().ok_or_else(|| bad("(file)", "must be a JSON object with `phi` and `delta`".into()))?;
    // A hand-written file may leave the version out; one that gives it is read only by
    // the version it names, since a later format may mean its fields otherwise.
    if let Some(version) = obj.get("format_version")
        && version.as_f64() != Some(f64::from(CALIBRATION_FORMAT_VERSION))
    {
        return Err(bad(
            "format_version",
            format!(
                "is {version}, but this objslam reads version {CALIBRATION_FORMAT_VERSION} \
                 (leave it out of a hand-written file)"
            ),
        ));
    }
    let number = |field: &str, x: &serde_json::Value| -> Result<f64, CalibrateError> {
        x.as_f64().filter(|f| f.is_finite()).ok_or_else(|| bad(field, format!("must be a finite number, got {x}")))
    };
    let phi_v = obj.get("phi").ok_or_else(|| bad("phi", "missing (the 3x3 rotation, row-major)".into()))?;
    let rows = phi_v
        .as_array()
        .filter(|r| r.len() == 3)
        .ok_or_else(|| bad("phi", format!("must be 3 rows of 3 numbers, got {phi_v}")))?;
    let mut phi = [[0.0; 3]; 3];
    for (i, row) in rows.iter().enumerate() {
        let cols = row
            .as_array()
            .filter(|c| c.len() == 3)
            .ok_or_else(|| bad(&format!("phi[{i}]"), format!("must be 3 numbers, got {row}")))?;
        for (j, x) in cols.iter().enumerate() {
            phi[i][j] = number(&format!("phi[{i}][{j}]"), x)?;
        }
    }
    let delta_v =
        obj.get("delta").ok_or_else(|| bad("delta", "missing (the translation, 3 numbers in metres)".into()))?;
    let d = delta_v
        .as_array()
        .filter(|d| d.len() == 3)
        .ok_or_else(|| bad("delta", format!("must be 3 numbers, got {delta_v}")))?;
    let mut delta = [0.0; 3];
    for (i, x) in d.iter().enumerate() {
        delta[i] = number(&format!("delta[{i}]"), x)?;
        if delta[i].abs() > MAX_MOUNT_OFFSET_M {
            return Err(bad(
                &format!("delta[{i}]"),
                format!(
                    "must be within ±{MAX_MOUNT_OFFSET_M} m (a camera that far from the laser is not on the same robot), got {}",
                    delta[i]
                ),
            ));
        }
    }
    let m = Matrix3::from_fn(|r, c| phi[r][c]);
    let off = (m.transpose() * m - Matrix3::identity()).abs().max();
    let det = m.determinant();
    if off > 1e-3 || det < 0.0 {
        return Err(bad("phi", format!("is not a rotation matrix (max |PhiᵀPhi - I| = {off:.2e}, det = {det:.4})")));
    }
    let svd = m.svd(true, true);
    let r = svd.u.expect("u") * svd.v_t.expect("v_t");
    Ok(Extrinsics::from_parts(&r, &Vector3::from(delta)))
}

/// The true extrinsics with seeded errors: a rotation by a vector with N(0, sigma)
/// components (about the laser's axes) and N(0, sigma) per translation component.
pub fn perturb(truth: &Extrinsics, rotation_sigma_deg: f64, translation_sigma_m: f64, seed: u64) -> Extrinsics {
    let mut rng = ChaCha8Rng::seed_from_u64(sim::derive_seed(seed, "calibration-perturbation"));
    let mut normal = || {
        // Box-Muller.
        let u1: f64 = rng.random_range(f64::EPSILON..1.0);
        let u2: f64 = rng.random_range(0.0..1.0);
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    };
    let w = Vector3::new(normal(), normal(), normal()) * rotation_sigma_deg.to_radians();
    let t = Vector3::new(normal(), normal(), normal()) * translation_sigma_m;
    let r = nalgebra::Rotation3::new(w);
    Extrinsics::from_parts(&(r.matrix() * truth.phi()), &(truth.delta() + t))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stations_spread_their_tilts_and_build_a_valid_world() {
        let config = SessionConfig::default();
        let sim = SimConfig::default();
        config.check(Path::new("x.toml"), &sim).unwrap();
        let st = plan_stations(&config, &sim, 4);
        assert_eq!(st.len(), 20);
        let mut tilts: Vec<f64> =
            st.iter().map(|s| if let Shape::Board { tilt_deg, .. } = s.board.shape { tilt_deg } else { 0.0 }).collect();
        tilts.sort_by(f64::total_cmp);
        // One tilt per stratum of the range.
        for (i, t) in tilts.iter().enumerate() {
            let lo = -35.0 + 70.0 * i as f64 / 20.0;
            assert!(*t >= lo && *t <= lo + 3.5, "{tilts:?}");
        }
        let world = range_world(&st, &worlds::generate::park(&Default::default(), 1).unwrap()).unwrap();
        assert_eq!(world.objects.len(), 40);
        assert_eq!(plan_stations(&config, &sim, 4), st, "same seed, same plan");
        assert_ne!(plan_stations(&config, &sim, 5), st);
    }

    /// A segmentation table that gives one key changes that key alone: the others keep
    /// the values derived from the camera, the laser and the session.
    #[test]
    fn a_segmentation_key_given_replaces_only_its_derived_value() {
        let sim = SimConfig::default();
        let derived = SessionConfig::default().segmentation_for(&sim);
        assert_ne!(derived, BoardSegmentation::default(), "the derived settings differ from the fixed ones");
        let session: SessionConfig = toml::from_str("[segmentation]\ntrim = 2\n").unwrap();
        assert_eq!(session.segmentation_for(&sim), BoardSegmentation { trim: 2, ..derived.clone() });
        let all = SessionConfig {
            segmentation: Some(SegmentationSettings::all(&BoardSegmentation::default())),
            ..SessionConfig::default()
        };
        assert_eq!(all.segmentation_for(&sim), BoardSegmentation::default());
        let e = toml::from_str::<SessionConfig>("[segmentation]\ntrimm = 2\n").unwrap_err().to_string();
        assert!(e.contains("trimm"), "{e}");
        let bad: SessionConfig = toml::from_str("[segmentation]\nrange_m = [3.0, 1.0]\n").unwrap();
        let e = bad.check_settings(Path::new("s.toml")).unwrap_err().to_string();
        assert!(e.contains("segmentation.range_m"), "{e}");
    }

    /// An earlier session's pose images go before a session writes its own; nothing else.
    #[test]
    fn an_earlier_sessions_pose_images_are_removed_and_nothing_else() {
        let dir = std::env::temp_dir().join(format!("objslam-calimages-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for name in ["pose_05.png", "pose_29.png", "pose_x.png", "pose_.png", "notes.txt", "pose_12.png.bak"] {
            std::fs::write(dir.join(name), "x").unwrap();
        }
        remove_pose_images(&dir).unwrap();
        let mut left: Vec<String> =
            std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
        left.sort();
        assert_eq!(left, ["notes.txt", "pose_.png", "pose_12.png.bak", "pose_x.png"]);
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// Boards and their distractors keep apart ids, none reserved, up to the most poses a
    /// session may ask for (more than a line of stations at any spacing a world can hold);
    /// the longest line allowed builds a valid world.
    #[test]
    fn the_largest_session_builds_a_valid_world() {
        let config = SessionConfig { poses: *POSES.end(), ..SessionConfig::default() };
        let st = plan_stations(&config, &SimConfig::default(), 1);
        let ids: std::collections::BTreeSet<u16> =
            st.iter().flat_map(|s| std::iter::once(s.board.id).chain(s.distractor.as_ref().map(|d| d.id))).collect();
        assert_eq!(ids.len(), 2 * *POSES.end());
        assert!(!ids.contains(&0) && !ids.contains(&worlds::validate::GROUND_INSTANCE_ID));
        let spacing = SessionConfig::default().station_spacing_m;
        let longest = (MAX_STATION_SPAN_M / spacing).floor() as usize + 1;
        let config = SessionConfig { poses: longest, ..SessionConfig::default() };
        let st = plan_stations(&config, &SimConfig::default(), 1);
        let world = range_world(&st, &worlds::generate::park(&Default::default(), 1).unwrap()).unwrap();
        assert_eq!(world.objects.len(), 2 * longest);
    }

    #[test]
    fn poses_asked_for_are_checked_against_the_spacing() {
        let spacing = SessionConfig::default().station_spacing_m;
        let most = (MAX_STATION_SPAN_M / spacing) as usize + 1;
        assert!(check_poses_override(most, spacing).is_ok());
        let e = check_poses_override(most + 1, spacing).unwrap_err().to_string();
        assert!(e.starts_with(&format!("--poses {}: the stations would stand", most + 1)), "{e}");
        assert!(e.contains(&format!("at most {most} poses at that spacing")), "{e}");
        let e = check_poses_override(4, spacing).unwrap_err().to_string();
        assert!(e.contains("--poses 4: must be 5..10000"), "{e}");
    }

    #[test]
    fn bad_sessions_are_named() {
        let sim = SimConfig::default();
        let f = Path::new("s.toml");
        let e = SessionConfig { squares: [8, 5], ..Default::default() }.check(f, &sim).unwrap_err().to_string();
        assert!(e.contains("s.toml") && e.contains("calibration.session.squares") && e.contains("square"), "{e}");
        let e = SessionConfig { tilt_deg: [-85.0, 10.0], ..Default::default() }.check(f, &sim).unwrap_err().to_string();
        assert!(e.contains("tilt_deg"), "{e}");
        let e =
            SessionConfig { centre_height_m: [1.5, 1.6], ..Default::default() }.check(f, &sim).unwrap_err().to_string();
        assert!(e.contains("centre_height_m") && e.contains("laser"), "{e}");
        let e =
            SessionConfig { bearing_deg: [-90.0, 90.0], ..Default::default() }.check(f, &sim).unwrap_err().to_string();
        assert!(
            e.contains("calibration.session.bearing_deg") && e.contains("within +-30 deg of the camera's axis"),
            "{e}"
        );
        // A camera turned 20 deg sees boards at 20-40 deg from the laser's axis.
        let mut turned = SimConfig::default();
        turned.camera.mount_yaw_deg = 20.0;
        SessionConfig { bearing_deg: [20.0, 40.0], ..Default::default() }.check(f, &turned).unwrap();
        let e = SessionConfig { poses: 0, ..Default::default() }.check(f, &sim).unwrap_err().to_string();
        assert!(e.contains("poses"), "{e}");
        let e = SessionConfig { station_spacing_m: 3.0, ..Default::default() }.check(f, &sim).unwrap_err().to_string();
        assert!(e.contains("station_spacing_m"), "{e}");
        // Stations strung out so far that single precision would show in the result.
        let e = SessionConfig { station_spacing_m: 1e4, ..Default::default() }.check(f, &sim).unwrap_err().to_string();
        assert!(e.contains("station_spacing_m") && e.contains("190000 m") && e.contains("fewer poses"), "{e}");
        let e = SessionConfig { poses: 1001, ..Default::default() }.check(f, &sim).unwrap_err().to_string();
        assert!(e.contains("12000 m"), "{e}");
        SessionConfig { poses: 150, ..Default::default() }.check(f, &sim).unwrap();
        let e = SessionConfig { turn_deg: [-80.0, 80.0], ..Default::default() }.check(f, &sim).unwrap_err().to_string();
        assert!(e.contains("strictly between -80 and 80 deg"), "{e}");
    }

    /// Boards that pass the session's checks but stand, as drawn, where the robot cannot
    /// pass are named by the file and the settings to change, not as an inner world.
    #[test]
    fn stations_that_cannot_be_laid_out_are_named_by_their_settings() {
        let (mut sc, base) = crate::scenario::Scenario::load("paper_park").unwrap();
        sc.calibration.session.distance_m = [0.5, 0.6];
        let e = run_session(&sc, &base, 1, None, None).unwrap_err().to_string();
        assert!(
            e.contains("paper_park.toml: calibration.session: the stations drawn with seed 1 cannot be laid out")
                && e.contains("and 8 more")
                && e.contains("a larger distance_m"),
            "{e}"
        );
    }

    #[test]
    fn calibration_files_are_read_and_bad_ones_named() {
        let scratch = tempfile::tempdir().unwrap();
        let dir = scratch.path();
        let truth = true_extrinsics(&SimConfig::default());
        let good = dir.join("good.json");
        std::fs::write(&good, serde_json::json!({"phi": truth.phi, "delta": truth.delta, "other": 1}).to_string())
            .unwrap();
        let e = load_extrinsics(&good).unwrap();
        assert!(e.error_to(&truth).0 < 1e-9 && e.error_to(&truth).1 < 1e-12);
        let cases = [
            ("nojson.json", "{".to_string(), "not valid JSON"),
            ("nophi.json", serde_json::json!({"delta": [0, 0, 0]}).to_string(), "phi: missing"),
            ("shape.json", serde_json::json!({"phi": [[1, 0], [0, 1]], "delta": [0, 0, 0]}).to_string(), "phi"),
            (
                "notrot.json",
                serde_json::json!({"phi": [[1, 0, 0], [0, 2, 0], [0, 0, 1]], "delta": [0, 0, 0]}).to_string(),
                "not a rotation",
            ),
            (
                "reflect.json",
                serde_json::json!({"phi": [[1, 0, 0], [0, 1, 0], [0, 0, -1]], "delta": [0, 0, 0]}).to_string(),
                "not a rotation",
            ),
            (
                "delta.json",
                serde_json::json!({"phi": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "delta": [0, "a", 0]}).to_string(),
                "delta[1]",
            ),
            (
                "far.json",
                serde_json::json!({"phi": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "delta": [0, 0, 1e300]}).to_string(),
                "delta[2]: must be within",
            ),
        ];
        for (name, text, want) in cases {
            let f = dir.join(name);
            std::fs::write(&f, text).unwrap();
            let msg = load_extrinsics(&f).unwrap_err().to_string();
            assert!(msg.contains(name) && msg.contains(want), "{name}: {msg}");
        }
        let msg = load_extrinsics(&dir.join("missing.json")).unwrap_err().to_string();
        assert!(msg.contains("missing.json") && msg.contains("cannot read"), "{msg}");
    }

    #[test]
    fn a_calibration_of_another_camera_is_refused() {
        let dir = std::env::temp_dir().join(format!("objslam-calcam-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let sim = SimConfig::default();
        let (truth, camera) = (true_extrinsics(&sim), sim.camera.intrinsics());
        let file = |name: &str, camera: serde_json::Value| {
            let f = dir.join(name);
            let mut v = serde_json::json!({"phi": truth.phi, "delta": truth.delta});
            if !camera.is_null() {
                v["camera"] = camera;
            }
            std::fs::write(&f, v.to_string()).unwrap();
            f
        };
        // Its own camera, as `objslam calibrate` writes it, and no camera at all: read.
        let own = file("own.json", serde_json::to_value(camera).unwrap());
        assert!(load_extrinsics_for(&own, &camera).unwrap().error_to(&truth).1 < 1e-12);
        assert!(load_extrinsics_for(&file("bare.json", serde_json::Value::Null), &camera).is_ok());
        // Another focal length or image size: refused, naming the file and the field.
        let mut wider = serde_json::to_value(camera).unwrap();
        wider["fx"] = serde_json::json!(camera.fx * 0.8);
        let msg = load_extrinsics_for(&file("wider.json", wider), &camera).unwrap_err().to_string();
        assert!(msg.contains("wider.json") && msg.contains("camera.fx") && msg.contains("another camera"), "{msg}");
        let mut taller = serde_json::to_value(camera).unwrap();
        taller["height"] = serde_json::json!(720);
        let msg = load_extrinsics_for(&file("taller.json", taller), &camera).unwrap_err().to_string();
        assert!(msg.contains("camera.height") && msg.contains("720"), "{msg}");
        let msg = load_extrinsics_for(&file("partial.json", serde_json::json!({"fx": camera.fx})), &camera)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("camera.width: missing"), "{msg}");
        let msg = load_extrinsics_for(&file("named.json", serde_json::json!("the left one")), &camera)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("named.json") && msg.contains("camera: must be a table"), "{msg}");
        let f = dir.join("null.json");
        std::fs::write(&f, serde_json::json!({"phi": truth.phi, "delta": truth.delta, "camera": null}).to_string())
            .unwrap();
        assert!(load_extrinsics_for(&f, &camera).is_ok(), "a null camera says no more than none");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn perturbation_is_seeded_and_sized() {
        let truth = true_extrinsics(&SimConfig::default());
        let a = perturb(&truth, 1.0, 0.02, 7);
        assert_eq!(a, perturb(&truth, 1.0, 0.02, 7));
        let (r, t) = a.error_to(&truth);
        assert!(r > 0.0 && r < 6.0 && t > 0.0 && t < 0.12, "{r} {t}");
        assert_eq!(perturb(&truth, 0.0, 0.0, 7).error_to(&truth).1, 0.0);
    }
}
