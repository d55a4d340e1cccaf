//! What each key of a scenario file means, and the commented default scenario built from
//! it ([`Scenario::defaults_toml`], `objslam config defaults`).
//!
//! The descriptions follow the doc comments and `validate()`/`check()` functions of the
//! settings types; the tests below fail when a key a scenario accepts has no description
//! or a description names a key that is no longer printed.

use super::{PassCriteria, Scenario};

/// Every table of a scenario, by dotted path, with what it holds, in the order printed.
pub(super) const TABLES: &[(&str, &str)] = &[
    ("world", "Where the world comes from: a generator preset or a world file (required)."),
    ("world.params", "Parameters of the park generator, only with a preset; [min, max] ranges are drawn uniformly."),
    ("sim", "Simulator settings: physics rate and run length, and the robot, laser, odometry and camera below."),
    ("sim.robot", "The robot (a Pioneer 2-AT) and its path-following controller."),
    ("sim.laser", "The 2-D laser (a SICK LMS2xx)."),
    ("sim.odometry", "Wheel odometry and its errors: systematic ones drawn once per run, and per-step noise."),
    ("sim.camera", "The camera: image size, field of view, rate, mounting on the robot and image noise."),
    ("calibration", "The laser <- camera extrinsics the pipeline is given: this table, or `calibration = \"<mode>\"`."),
    ("calibration.session", "The calibration session run for mode \"estimated\": its checkerboard stations and board."),
    (
        "calibration.session.segmentation",
        "Finding the board in a scan: keys not given are derived from the camera, laser and session.",
    ),
    ("pipeline", "The SLAM pipeline: association method, gates, landmark confirmation and loop closing."),
    ("pipeline.clustering", "Splitting a scan into clusters at range jumps, and which clusters are trunk-sized."),
    ("pipeline.motion", "The filter's vehicle model and its noise."),
    ("pipeline.sensor", "The filter's range-bearing model of an observation (a cluster's centre)."),
    ("pipeline.segmentation", "Laser-camera segmentation: whether a cluster is an object, judged on one camera frame."),
    ("pipeline.evidence", "Camera methods: the segmentation's evidence pooled over the frames that judged one place."),
    ("pipeline.object_model", "Object models (patch appearance and position), compared by KL divergence."),
    ("pipeline.diameter", "The laser's trunk diameter as an association cue."),
    ("pipeline.merge", "Fusing two mapped landmarks that turn out to be one object."),
    (
        "appearance",
        "Camera methods: the patch appearance model, from a file or trained on generated images and cached.",
    ),
    ("pass", "Criteria a run must meet to pass; one left out is not checked. A run must also finish its route."),
];

/// Every key of a scenario, by dotted path, with what it means (unit, and valid range where
/// one is checked), grouped by table in the order printed.
pub(super) const KEYS: &[(&str, &str)] = &[
    (
        "name",
        "Scenario name (required): letters, digits, '_', '-' and '.', not starting with '.'; a run's output goes \
         to runs/<name>-<seed> unless told otherwise; at most 100 characters.",
    ),
    ("description", "Free text: what the scenario is for."),
    (
        "seed",
        "Run seed unless --seed gives one: it seeds the simulation's noise, the calibration, and the world when \
         world.seed is absent.",
    ),
    // [world]
    ("world.preset", "World generator preset: \"park\" (the only one). Give either preset or file."),
    ("world.file", "A world file (TOML), relative to the scenario file, instead of a preset (and without params)."),
    ("world.seed", "Seed of the generated world; absent: the run seed, so a Monte Carlo study also varies the world."),
    // [world.params]
    ("world.params.area_m2", "Ground area (m²); at least 100."),
    ("world.params.aspect", "Ground width / depth ratio; in [0.25, 4]."),
    ("world.params.trees", "Number of trees; trees, posts, palms and people together at most 2000."),
    ("world.params.tree_radius_m", "Trunk radius range (m); min at least 0.02, max at most 1."),
    ("world.params.tree_height_m", "Trunk height range (m), the canopy centred on the trunk's top; min at least 0.5."),
    ("world.params.canopy_radius_m", "Canopy radius range (m); min at least 0.1."),
    (
        "world.params.posts",
        "Number of look-alike posts, each near a different tree while trees last; posts need a tree.",
    ),
    ("world.params.post_distance_m", "Centre-to-centre distance range of a post from its tree (m); min at least 0.1."),
    ("world.params.post_radius_m", "Post radius range (m); min at least 0.02, max at most 1."),
    ("world.params.post_height_m", "Post height range (m); min at least 0.5."),
    ("world.params.palms", "Number of palms."),
    ("world.params.palm_radius_m", "Palm trunk radius range (m); min at least 0.02, max at most 1."),
    ("world.params.palm_height_m", "Palm height range (m); min at least 0.5."),
    ("world.params.wall", "Whether to place a wall of bark-like brick along the far side."),
    (
        "world.params.wall_length_m",
        "Wall length range (m); min at least 0.5 and at most the ground's width less 2 m; a longer draw is cut to \
         that.",
    ),
    ("world.params.wall_height_m", "Wall height range (m); min at least 0.5."),
    ("world.params.people", "Number of people walking back and forth across the robot's route."),
    ("world.params.person_speed_mps", "Walking speed range (m/s); min at least 0.1, max at most 12."),
    ("world.params.person_height_m", "Person height range (m); min at least 0.8, max at most 2.75."),
    (
        "world.params.person_walk_half_length_m",
        "Range of the half-length of a person's walk across the route (m); min at least 0.5.",
    ),
    (
        "world.params.person_start_time_max_s",
        "Latest start time of a person's walk (s); starts are drawn from [0, this]; 0 or more.",
    ),
    (
        "world.params.route_margin_m",
        "Inset of the robot's loop from the ground's edges (m); positive, and the loop must fit the ground.",
    ),
    ("world.params.route_corner_radius_m", "Radius of the loop's rounded corners (m); positive."),
    ("world.params.laps", "Times the robot drives the loop; 1 to 1000."),
    ("world.params.object_gap_m", "Minimum gap between static objects, posts to their tree excepted (m); positive."),
    ("world.params.post_tree_gap_m", "Minimum gap between a post and the tree it imitates (m); positive."),
    (
        "world.params.route_gap_m",
        "Minimum gap between an object and the robot's route (m); at least the robot's clearance, 0.5.",
    ),
    (
        "world.params.max_route_distance_m",
        "Maximum distance of trees and palms from the route, so that they are seen (m); positive. Posts stand \
         near their tree.",
    ),
    // [sim]
    (
        "sim.physics_rate_hz",
        "Fixed physics step rate (Hz): sensor messages are stamped with the first step at or after their time; \
         at least every sensor's rate, at most 10000.",
    ),
    (
        "sim.max_duration_s",
        "Stop after this much simulated time (s) even if the route is not finished; positive. Absent: three times \
         the route's driving time at cruise speed, plus 30 s.",
    ),
    // [sim.robot]
    ("sim.robot.length_m", "Body length, front to back (m); positive, at most 5."),
    ("sim.robot.width_m", "Body width (m); positive, at most 5."),
    ("sim.robot.body_height_m", "Height of the body's collision box (m); positive, at most 5."),
    (
        "sim.robot.max_speed_mps",
        "Speed limit of the path follower (m/s); positive, at least cruise_speed_mps, at most the Pioneer 2-AT's 1.2.",
    ),
    (
        "sim.robot.max_turn_rate_dps",
        "Turn rate limit of the path follower (deg/s); positive, at most the Pioneer 2-AT's 300. The default is \
         1.5 rad/s.",
    ),
    (
        "sim.robot.cruise_speed_mps",
        "Driving speed along the route, slower in sharp turns (m/s); positive, at most max_speed_mps.",
    ),
    ("sim.robot.lookahead_m", "Pure-pursuit look-ahead distance along the route (m); positive."),
    (
        "sim.robot.safety_stop_m",
        "Stop while the laser sees something closer than this ahead of the robot's front, within 30 deg of \
         straight ahead (m; people crossing); 0 or more, below the laser's max_range_m.",
    ),
    // [sim.laser]
    (
        "sim.laser.fov_deg",
        "Field of view, centred straight ahead (deg); positive, at most 180, a whole number of resolution_deg \
         steps, at least 2 beams.",
    ),
    ("sim.laser.resolution_deg", "Angle between beams (deg), a string: \"0.25\", \"0.5\" or \"1\"."),
    (
        "sim.laser.max_range_m",
        "Longest range (m): an LMS2xx range mode, 8, 16 or 32 (millimetre steps) or 80 (centimetre steps).",
    ),
    ("sim.laser.min_range_m", "Shorter returns are dropped (m); 0 or more, below max_range_m."),
    ("sim.laser.range_noise_sigma_m", "Standard deviation of the Gaussian range noise (m); 0 or more."),
    ("sim.laser.rate_hz", "Scans per second (Hz); positive, at most physics_rate_hz."),
    ("sim.laser.mount_xyz_m", "Laser position on the robot base (m): forward, left, up; finite, up above 0."),
    (
        "sim.laser.mount_yaw_deg",
        "Yaw of the laser on the robot (deg, positive to the left), within +-180. The pipeline's observation \
         model has no yaw term: `objslam run` refuses any other value than 0.",
    ),
    // [sim.odometry]
    ("sim.odometry.rate_hz", "Odometry messages per second (Hz); positive, at most physics_rate_hz."),
    (
        "sim.odometry.scale_sigma",
        "Standard deviation of the distance scale error e, drawn once per run (measured = true x (1+e)); 0 or \
         more.",
    ),
    (
        "sim.odometry.turn_scale_sigma",
        "Standard deviation of the turn scale error e, drawn once per run (measured = true x (1+e)); 0 or more.",
    ),
    (
        "sim.odometry.bias_sigma_rad_per_m",
        "Standard deviation of the heading drift per metre driven, drawn once per run (rad/m); 0 or more.",
    ),
    (
        "sim.odometry.a_dd",
        "Per-step distance noise: variance per squared metre of the step's distance (m²/m²); 0 or more.",
    ),
    (
        "sim.odometry.a_da",
        "Per-step distance noise: variance per squared radian of the step's turn (m²/rad²); 0 or more.",
    ),
    (
        "sim.odometry.a_ad",
        "Per-step heading noise: variance per squared metre of the step's distance (rad²/m²); 0 or more.",
    ),
    (
        "sim.odometry.a_aa",
        "Per-step heading noise: variance per squared radian of the step's turn (rad²/rad²); 0 or more.",
    ),
    // [sim.camera]
    (
        "sim.camera.enabled",
        "Whether the simulator renders camera frames: the camera methods need them; position-only runs skip them.",
    ),
    ("sim.camera.width", "Image width (pixels); 1 to 8192."),
    ("sim.camera.height", "Image height (pixels); 1 to 8192."),
    (
        "sim.camera.hfov_deg",
        "Horizontal field of view (deg), in (1, 170); fx = fy follow from it, the principal point is the image \
         centre.",
    ),
    ("sim.camera.rate_hz", "Frames per second (Hz); positive, at most physics_rate_hz."),
    ("sim.camera.mount_xyz_m", "Camera position on the robot base (m): forward, left, up; finite, up above 0."),
    ("sim.camera.mount_pitch_deg", "Downward tilt of the optical axis (deg); within +-90 (exclusive)."),
    ("sim.camera.mount_yaw_deg", "Yaw of the camera on the robot (deg, positive to the left); within +-180."),
    ("sim.camera.noise_sigma", "Gaussian pixel noise (grey levels on a 0-255 scale); 0 (off) or more."),
    (
        "sim.camera.exposure_sigma",
        "Each frame's exposure is scaled by a factor drawn from N(1, this), at least 0.1; 0 (off) to 1.",
    ),
    (
        "sim.camera.depth_image",
        "Whether frames carry a depth image; objslam run never renders one, as no method reads depth.",
    ),
    // [calibration]
    (
        "calibration.mode",
        "\"true\": the simulator's exact extrinsics; \"perturbed\": those with seeded errors of the sigmas below; \
         \"estimated\": run the calibration session first; or a calibration file's path ending in .json, \
         relative to the scenario file.",
    ),
    (
        "calibration.rotation_sigma_deg",
        "Mode \"perturbed\": standard deviation of the rotation error about each axis (deg), drawn from the run \
         seed; 0 or more, and 0 in the other modes.",
    ),
    (
        "calibration.translation_sigma_m",
        "Mode \"perturbed\": standard deviation of the translation error along each axis (m), drawn from the run \
         seed; 0 or more, and 0 in the other modes.",
    ),
    // [calibration.session]
    ("calibration.session.poses", "Number of board poses (stations); 5 to 10000."),
    ("calibration.session.board_width_m", "Board width (m); positive."),
    ("calibration.session.board_height_m", "Board height (m); positive."),
    (
        "calibration.session.squares",
        "Checker squares across and down; 3 to 100 each way, and the squares must come out square.",
    ),
    ("calibration.session.distance_m", "Range of the distance from the laser to the board centre (m); above 0.3."),
    (
        "calibration.session.bearing_deg",
        "Range of the bearing of the board centre from the laser's x axis (deg); within both sensors' fields of \
         view.",
    ),
    (
        "calibration.session.centre_height_m",
        "Range of the board centre's height above the ground (m): the laser's plane must cut every board well \
         inside its height, and no board may reach below the ground.",
    ),
    (
        "calibration.session.turn_deg",
        "Range of the board's turn about the vertical away from facing the laser (deg); strictly between -80 and 80.",
    ),
    (
        "calibration.session.tilt_deg",
        "Range of the board's tilt about its width axis (deg, positive: face up); within +-80. Tilts are needed to \
         recover the camera's height and pitch.",
    ),
    (
        "calibration.session.station_spacing_m",
        "Distance between stations (m), keeping other boards out of the camera's view; at least the board's \
         larger side plus twice the largest distance.",
    ),
    (
        "calibration.session.scans_per_pose",
        "Laser scans averaged beam by beam at each station while the robot stands still (dividing the noise by \
         their square root); 1 to 1000.",
    ),
    (
        "calibration.session.distractors",
        "Whether a post stands behind each board, in the laser's view, for segmentation to reject.",
    ),
    // [calibration.session.segmentation]
    (
        "calibration.session.segmentation.bearing_rad",
        "Bearings where the board can be (rad, laser frame), [low, high] within +-pi.",
    ),
    ("calibration.session.segmentation.range_m", "Ranges where the board can be (m), [low, high], 0 <= low."),
    (
        "calibration.session.segmentation.length_m",
        "Length range of the board's cut by the scan plane, first to last point (m), [low, high], 0 <= low.",
    ),
    (
        "calibration.session.segmentation.jump_m",
        "Consecutive points further apart than this, or than 5 beam spacings at their range, belong to different \
         objects (m); positive.",
    ),
    (
        "calibration.session.segmentation.inlier_m",
        "Largest distance of a board point from the fitted line (m); positive.",
    ),
    (
        "calibration.session.segmentation.trim",
        "Points dropped at each end of the board's cut (mixed returns at edges); at most 50.",
    ),
    (
        "calibration.session.segmentation.camera_range_tolerance_m",
        "Largest difference between the cut's mean range and the board's distance the camera sees (m); 0 or \
         more.",
    ),
    // [pipeline]
    (
        "pipeline.method",
        "Association method: \"nn\" or \"jcbb\" (position only), \"appearance\" (KL divergence only) or \
         \"combined\" (a position gate, then KL).",
    ),
    ("pipeline.gate_probability", "Probability of the chi-square gate (2 dof) for individual association; in (0, 1)."),
    (
        "pipeline.new_landmark_probability",
        "An unassociated observation starts a landmark only if its squared Mahalanobis distance to every \
         landmark exceeds the chi-square quantile at this probability; in (0, 1).",
    ),
    ("pipeline.jcbb_probability", "Joint compatibility probability for JCBB; in (0, 1)."),
    ("pipeline.initial_pose_sigma", "Initial pose standard deviations (m, m, rad); each positive, at most 1e6."),
    (
        "pipeline.image_max_age_s",
        "A scan is segmented with the latest camera image only if it is at most this old (s); 0 or more.",
    ),
    (
        "pipeline.confirm_observations",
        "A new landmark stays tentative until observed this many times (1: at once); 1 to 1000.",
    ),
    (
        "pipeline.confirm_window_s",
        "A tentative landmark not confirmed within this time is deleted, so walking people never become \
         landmarks (s); positive.",
    ),
    (
        "pipeline.joint_loop_closing",
        "Combined method: observations the KL test would start landmarks with are paired with existing ones when \
         two or more in a scan fit the map jointly (JCBB over look-alike candidates).",
    ),
    (
        "pipeline.joint_loop_free_space",
        "With joint_loop_closing: a joint closure is refused where, with the pose it corrects, a confirmed \
         landmark it leaves unpaired is in plain view where the scan's beams reach past it.",
    ),
    (
        "pipeline.defer_near_lookalike",
        "Combined method: an observation the KL test leaves without a landmark starts none while a confirmed \
         look-alike (appearance, trunk diameter) lies within its new-landmark gate.",
    ),
    (
        "pipeline.first_estimate_jacobians",
        "First-estimate Jacobians in the filter, which keep it from gaining information it does not have.",
    ),
    (
        "pipeline.observability_constrained",
        "With first_estimate_jacobians: observation Jacobians at the latest estimates, changed as little as \
         possible so the first estimates' unobservable directions stay unobservable.",
    ),
    (
        "pipeline.relinearise_loop_closures",
        "Combined method: after a scan that closes a loop jointly, relinearise the filter by solving its whole \
         history again.",
    ),
    (
        "pipeline.relinearise_every_s",
        "With relinearise_loop_closures: also relinearise once this long has passed since the last time (s); \
         positive. Absent: only at loop closures.",
    ),
    (
        "pipeline.batch_updates",
        "Position-only methods: update the filter once per scan with all its associated observations stacked, \
         instead of once per observation.",
    ),
    // [pipeline.clustering]
    (
        "pipeline.clustering.lambda_deg",
        "Incidence angle below which a surface counts as a new object (deg), in (0, 90): consecutive points \
         further apart than r sin(dphi) / sin(lambda - dphi) + 3 range_sigma_m split a cluster.",
    ),
    ("pipeline.clustering.range_sigma_m", "Range noise in that breakpoint threshold (m); 0 or more."),
    ("pipeline.clustering.min_points", "Fewest beams in a cluster; 3 (a circle fit needs three points) to 1000."),
    ("pipeline.clustering.min_diameter_m", "Smallest fitted diameter of a cluster kept (m); 0 or more."),
    ("pipeline.clustering.max_diameter_m", "Largest fitted diameter of a cluster kept (m); above min_diameter_m."),
    (
        "pipeline.clustering.max_range_m",
        "Clusters further than this are ignored, having too few beams to fit (m); positive.",
    ),
    // [pipeline.motion]
    (
        "pipeline.motion.model",
        "\"odometry\": body-frame increments from wheel encoders (the keys below); \"ackermann\": speed and \
         steering of a car-like vehicle (the keys shown commented out instead), for robot logs only: the \
         simulated robot's odometry is increments.",
    ),
    (
        "pipeline.motion.a_dd",
        "Odometry: per-step distance variance per squared metre of the step's distance (m²/m²); 0 or more.",
    ),
    (
        "pipeline.motion.a_da",
        "Odometry: per-step distance variance per squared radian of the step's turn (m²/rad²); 0 or more.",
    ),
    (
        "pipeline.motion.a_ad",
        "Odometry: per-step heading variance per squared metre of the step's distance (rad²/m²); 0 or more.",
    ),
    (
        "pipeline.motion.a_aa",
        "Odometry: per-step heading variance per squared radian of the step's turn (rad²/rad²); 0 or more.",
    ),
    (
        "pipeline.motion.d_per_m",
        "Odometry: distance variance per metre driven (m²/m), a random walk for calibration errors; 0 or more.",
    ),
    (
        "pipeline.motion.a_per_m",
        "Odometry: heading variance per metre driven (rad²/m), a random walk for calibration errors; 0 or more.",
    ),
    (
        "pipeline.motion.a_per_rad",
        "Odometry: heading variance per radian turned (rad²/rad), a random walk for calibration errors; 0 or more.",
    ),
    (
        "pipeline.motion.floor",
        "Odometry: added to both variances at every step, so that a standing robot keeps a sane covariance; \
         0 or more.",
    ),
    (
        "pipeline.motion.scale_sigma",
        "Odometry: prior standard deviation of the distance scale error; the filter estimates the three \
         calibration errors when any of their sigmas is above 0; 0 or more.",
    ),
    ("pipeline.motion.turn_scale_sigma", "Odometry: prior standard deviation of the turn scale error; 0 or more."),
    (
        "pipeline.motion.bias_sigma_rad_per_m",
        "Odometry: prior standard deviation of the heading bias (rad per metre driven); 0 or more.",
    ),
    ("pipeline.motion.wheelbase_m", "Ackermann: wheelbase (m); positive."),
    (
        "pipeline.motion.encoder_offset_m",
        "Ackermann: sideways offset from the rear axle's centre of the wheel whose speed is measured (m, positive \
         to the left); smaller than the wheelbase.",
    ),
    ("pipeline.motion.distance_var_per_m", "Ackermann: variance of the distance driven, per metre (m²/m); 0 or more."),
    ("pipeline.motion.lateral_var_per_m", "Ackermann: variance of the sideways slip, per metre (m²/m); 0 or more."),
    (
        "pipeline.motion.heading_var_per_m",
        "Ackermann: variance of the heading change per metre driven, steering and slip (rad²/m); 0 or more.",
    ),
    (
        "pipeline.motion.heading_var_per_s",
        "Ackermann: variance of the heading change per second, drift that also keeps a standing vehicle's \
         covariance sane (rad²/s); 0 or more.",
    ),
    // [pipeline.sensor]
    (
        "pipeline.sensor.mount_x",
        "Sensor position ahead of the robot's origin (m); finite. A scenario's runs take it from \
         sim.laser.mount_xyz_m: leave it out (another value is an error).",
    ),
    (
        "pipeline.sensor.mount_y",
        "Sensor position left of the robot's origin (m); finite. A scenario's runs take it from \
         sim.laser.mount_xyz_m: leave it out (another value is an error).",
    ),
    ("pipeline.sensor.range_sigma_m", "Standard deviation of an observation's range (m); positive, at most 1e6."),
    ("pipeline.sensor.range_sigma_per_m", "Added to range_sigma_m per metre of range (m/m); 0 to 1e6."),
    ("pipeline.sensor.bearing_sigma_rad", "Standard deviation of an observation's bearing (rad); positive."),
    // [pipeline.segmentation]
    (
        "pipeline.segmentation.min_hit_fraction",
        "Judged on one frame, a cluster is an object when at least this fraction of the patches its laser points \
         fall in are object patches...; in [0, 1].",
    ),
    (
        "pipeline.segmentation.min_object_patches",
        "...and at least this many object patches lie in its columns (checked with pooled evidence too); at \
         most 10000...",
    ),
    (
        "pipeline.segmentation.min_above_fraction",
        "...and at least this fraction of the patches in the band above the laser, along the trunk up from \
         where the laser hit object patches (as the camera sees it, leaning when tilted), are object patches; in \
         [0, 1].",
    ),
    (
        "pipeline.segmentation.above_band_from_m",
        "Bottom of that band (m above the laser plane, at the cluster's range); 0 or more.",
    ),
    ("pipeline.segmentation.above_band_m", "Top of that band (m above the laser plane); above above_band_from_m."),
    (
        "pipeline.segmentation.min_band_rows",
        "Fewest patch rows of the band in the image for the band to be judged; a cluster whose band is not \
         judged only updates landmarks already confirmed; 1 to 1000.",
    ),
    (
        "pipeline.segmentation.band_counts_foliage",
        "Count the band's foliage patches with its object patches in a column whose object patches end below the \
         band straight in foliage (a trunk ending in its canopy), when the appearance model has a foliage model; \
         true or false.",
    ),
    (
        "pipeline.segmentation.column_margin",
        "Extra patch columns classified on each side of the projected laser points; at most 1000.",
    ),
    (
        "pipeline.segmentation.patch_threshold",
        "A patch is an object patch when its posterior R exceeds this; in (0, 1). Absent: the appearance model's \
         own threshold (0.5 unless trained with another).",
    ),
    // [pipeline.evidence]
    (
        "pipeline.evidence.pooled",
        "Decide on the evidence pooled over frames (true) or on each frame alone (false: the segmentation's own \
         thresholds).",
    ),
    (
        "pipeline.evidence.radius_m",
        "A frame joins the nearest place whose centre (odometry frame) is within this distance, else starts a new \
         place (m); positive. Keep it under the distance between a post and the tree beside it.",
    ),
    ("pipeline.evidence.forget_after_s", "A place not judged for this long is forgotten (s); positive."),
    ("pipeline.evidence.min_frames", "Fewest judged frames before a place's means decide; 1 to 1000."),
    (
        "pipeline.evidence.undecided_by_frame",
        "Until then: false, the place is not observed; true, each frame's own judgement decides (as in the paper).",
    ),
    (
        "pipeline.evidence.min_hit_fraction",
        "Least mean fraction of a place's laser patches that are object patches; in [0, 1].",
    ),
    (
        "pipeline.evidence.min_above_fraction",
        "Least mean fraction of object patches in the band above the laser (see pipeline.segmentation); in [0, 1].",
    ),
    (
        "pipeline.evidence.retract",
        "Retract a landmark when at least retract_min_frames frames of its place judged from nearer than \
         retract_range_m have a mean hit fraction under retract_max_hit_fraction.",
    ),
    (
        "pipeline.evidence.retract_range_m",
        "Only frames judged from nearer than this count for retraction (m); positive.",
    ),
    ("pipeline.evidence.retract_min_frames", "Fewest such near frames before a landmark can be retracted; 1 to 1000."),
    (
        "pipeline.evidence.retract_max_hit_fraction",
        "A landmark is retracted when its near frames' mean hit fraction is under this; in [0, 1].",
    ),
    // [pipeline.object_model]
    (
        "pipeline.object_model.components",
        "Mixture components per object model, a fixed number; at most 32. 0 asks for a search, which as coded \
         stops at one component.",
    ),
    (
        "pipeline.object_model.position_floor_m",
        "Standard deviation added to the x-y spread of both models when they are compared, as an object has depth \
         (m); 0 or more.",
    ),
    (
        "pipeline.object_model.kl_threshold",
        "An observation joins the candidate with the smallest KL divergence below this (nats); positive.",
    ),
    (
        "pipeline.object_model.appearance_dims",
        "Leading appearance (PCA) dimensions the object models use; at least 1, at most the appearance model's \
         (appearance.pca_dims when it is trained).",
    ),
    // [pipeline.diameter]
    (
        "pipeline.diameter.enabled",
        "Combined method: a candidate landmark whose trunk diameter (the mean of its clusters' circle fits) \
         disagrees with the observation's is not that object.",
    ),
    (
        "pipeline.diameter.for_position_methods",
        "Also a cue for nn and jcbb: a landmark whose diameter disagrees is not a candidate.",
    ),
    (
        "pipeline.diameter.sigma_m",
        "Diameter spread at range 0 (m); 0 or more. Diameters agree when they differ by at most max_sigmas x \
         sigma, sigma = (sigma_m + sigma_per_m x range) x sqrt(1+1/n) for a landmark seen n times.",
    ),
    (
        "pipeline.diameter.sigma_per_m",
        "Added to sigma_m per metre of range (m/m); 0 or more, and not 0 together with sigma_m.",
    ),
    ("pipeline.diameter.max_sigmas", "Largest difference of the diameters, in sigmas; positive."),
    // [pipeline.merge]
    (
        "pipeline.merge.enabled",
        "Fuse two landmarks once the filter is sure where both are, their positions agree within the association \
         gate, they were never seen in one scan and, for the camera methods, they look alike.",
    ),
    (
        "pipeline.merge.max_sigma_m",
        "Largest standard deviation, per axis, of the difference of the two positions (m); positive.",
    ),
    ("pipeline.merge.noise_sigma_m", "Noise of the constraint that fuses them (m per axis); positive."),
    // [appearance]
    (
        "appearance.model",
        "A model file from objslam train, relative to the scenario file; the keys below then keep their \
         defaults (they are refused, since the file is read as it is). Absent: a model is trained from \
         generated images as the keys below say, and cached.",
    ),
    ("appearance.training_preset", "World generator preset of the training images: \"park\"."),
    (
        "appearance.training_world_seed",
        "World seed of the training images (with several training worlds, the seed they are drawn from).",
    ),
    (
        "appearance.training_worlds",
        "Worlds the training images are spread over, 1 to 1000 and at most training_images: 1, the preset's park; more, parks drawn from the generalisation benchmark's distribution (the preset unused).",
    ),
    ("appearance.training_images", "Number of training images rendered; 1 to 100000."),
    ("appearance.training_seed", "Seed of the training images' views and of the training's patch sampling."),
    (
        "appearance.max_patches_per_class",
        "Patches per class (object, background) given to the mixture fit: a seeded random subsample; 1 to \
         10000000.",
    ),
    (
        "appearance.distractors",
        "Fit posts, palms, walls and people with their own mixture, apart from the rest of the background: \
         fewer posts' patches called object, but fewer trees mapped (docs/results.md).",
    ),
    (
        "appearance.context",
        "Learn a column context that decides each patch again from its own log-odds and those of the patches \
         above and below it, fitted on every 5th training image (docs/results.md).",
    ),
    (
        "appearance.max_components",
        "Most mixture components of each class's appearance density (the search grows up to it); 1 to 100.",
    ),
    ("appearance.pca_dims", "PCA dimension d of the patch features; 1 to 1000."),
    // [pass]
    ("pass.max_wrong_associations", "Most observations associated with a landmark of another true object."),
    ("pass.max_false_landmarks", "Most landmarks on posts, palms, people, walls or nothing."),
    (
        "pass.min_false_landmarks",
        "Least false landmarks, for baseline scenarios that must reproduce a failure; not above \
         max_false_landmarks, at most 10000.",
    ),
    ("pass.max_duplicate_landmarks", "Most duplicate landmarks: those beyond the first on each object."),
    (
        "pass.min_tree_recall",
        "Least tree recall, the mapped share of the trees there were to map (by ground truth); in [0, 1]. A run \
         with no tree to map fails it.",
    ),
    (
        "pass.max_ate_rmse_m",
        "Largest RMS position error of the estimated trajectory against the truth, without alignment (m); \
         positive.",
    ),
    (
        "pass.max_landmark_rmse_m",
        "Largest RMS landmark error after optimal assignment to trees, posts and palms, pairs over 2 m apart left \
         out (m); positive. A run with no such pair fails it (its RMSE is undefined).",
    ),
    ("pass.max_collisions", "Most contacts between the robot and anything."),
    (
        "pass.max_calibration_rotation_error_deg",
        "Largest rotation error of the run's laser-camera extrinsics against the simulator's (deg); 0 or more.",
    ),
    (
        "pass.max_calibration_translation_error_m",
        "Largest translation error of the run's laser-camera extrinsics against the simulator's (m); 0 or more.",
    ),
];

/// Comment lines are wrapped to this many characters.
const WIDTH: usize = 100;

/// A scenario's settings as a TOML table.
fn table_of(value: impl serde::Serialize) -> Result<toml::Table, String> {
    match toml::Value::try_from(value).map_err(|e| e.to_string())? {
        toml::Value::Table(t) => Ok(t),
        other => Err(format!("expected a table, got {other}")),
    }
}

/// The values shown, commented out, for keys with no default: a scenario with every
/// optional setting given (the values are examples, not recommendations), and the keys of
/// the car-like motion model beside the default odometry model's.
fn examples() -> Result<toml::Table, String> {
    let mut s = Scenario::with_defaults("my_scenario");
    s.world.file = Some("my_world.toml".into());
    s.world.seed = Some(2006);
    s.sim.max_duration_s = Some(600.0);
    s.calibration.session.segmentation =
        Some(crate::calibrate::SegmentationSettings::all(&slam::calibration::BoardSegmentation::default()));
    s.pipeline.relinearise_every_s = Some(30.0);
    s.pipeline.segmentation.patch_threshold = Some(0.5);
    s.appearance.model = Some("model.json".into());
    // Every field named, so that a new criterion needs an example here.
    s.pass = PassCriteria {
        max_wrong_associations: Some(0),
        max_false_landmarks: Some(0),
        min_false_landmarks: Some(1),
        max_duplicate_landmarks: Some(0),
        min_tree_recall: Some(0.9),
        max_ate_rmse_m: Some(0.5),
        max_landmark_rmse_m: Some(0.2),
        max_collisions: Some(0),
        max_calibration_rotation_error_deg: Some(0.3),
        max_calibration_translation_error_m: Some(0.01),
    };
    let mut t = table_of(&s)?;
    let ackermann = table_of(slam::ekf::MotionConfig::Ackermann(Default::default()))?;
    if let Some(toml::Value::Table(motion)) =
        t.get_mut("pipeline").and_then(|p| p.as_table_mut()).and_then(|p| p.get_mut("motion"))
    {
        for (k, v) in ackermann {
            motion.entry(k).or_insert(v);
        }
    }
    Ok(t)
}

/// The value at dotted `path` in `t` (`""`: `t` itself).
fn lookup<'a>(t: &'a toml::Table, path: &str) -> Option<&'a toml::Value> {
    let mut parts = path.split('.');
    let mut value = t.get(parts.next()?)?;
    for key in parts {
        value = value.as_table()?.get(key)?;
    }
    Some(value)
}

fn table_at<'a>(t: &'a toml::Table, path: &str) -> Option<&'a toml::Table> {
    if path.is_empty() { Some(t) } else { lookup(t, path)?.as_table() }
}

/// The table part and the last key of a dotted path (`("", "seed")` at the top).
fn split(path: &str) -> (&str, &str) {
    path.rsplit_once('.').unwrap_or(("", path))
}

fn description(path: &str) -> Option<&'static str> {
    KEYS.iter().find(|(p, _)| *p == path).map(|(_, d)| *d)
}

/// `text` as comment lines of at most [`WIDTH`] characters (longer words stay whole), as
/// even in length as that many lines allow.
fn comment(out: &mut String, text: &str) {
    let lines = wrap(text, WIDTH).len();
    let mut width = WIDTH;
    while width > WIDTH / 2 && wrap(text, width - 1).len() == lines {
        width -= 1;
    }
    for line in wrap(text, width) {
        out.push_str(&line);
        out.push('\n');
    }
}

/// `text` as `# `-prefixed lines of at most `width` characters.
fn wrap(text: &str, width: usize) -> Vec<String> {
    let mut lines = vec![String::from("#")];
    for word in text.split_whitespace() {
        let line = lines.last_mut().expect("one line");
        if line.len() > 1 && line.chars().count() + 1 + word.chars().count() > width {
            lines.push(String::from("#"));
        }
        let line = lines.last_mut().expect("one line");
        line.push(' ');
        line.push_str(word);
    }
    lines
}

/// Every table path in `t` (depth first), below `prefix`.
fn table_paths(t: &toml::Table, prefix: &str, out: &mut Vec<String>) {
    for (k, v) in t {
        if let toml::Value::Table(sub) = v {
            let path = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
            out.push(path.clone());
            table_paths(sub, &path, out);
        }
    }
}

/// The value of `key` in `t`, unless it is a table.
fn leaf<'a>(t: Option<&'a toml::Table>, key: &str) -> Option<&'a toml::Value> {
    t?.get(key).filter(|v| !v.is_table())
}

/// The keys of the table at `path`, each after its description: those with a default as
/// `key = value`, those without as `# key = example`. Undescribed keys are printed too
/// (bare), so the output is always complete; the tests ask for their descriptions.
fn keys(out: &mut String, path: &str, defaults: Option<&toml::Table>, examples: Option<&toml::Table>) {
    let full = |key: &str| if path.is_empty() { key.to_string() } else { format!("{path}.{key}") };
    let mut names: Vec<String> =
        KEYS.iter().filter(|(p, _)| split(p).0 == path).map(|(p, _)| split(p).1.to_string()).collect();
    for t in [defaults, examples].into_iter().flatten() {
        for (k, v) in t {
            if !v.is_table() && !names.contains(k) {
                names.push(k.clone());
            }
        }
    }
    for name in names {
        let (value, prefix) = match (leaf(defaults, &name), leaf(examples, &name)) {
            (Some(v), _) => (v, ""),
            (None, Some(v)) => (v, "# "),
            (None, None) => continue,
        };
        if let Some(about) = description(&full(&name)) {
            comment(out, about);
        }
        out.push_str(&format!("{prefix}{name} = {value}\n"));
    }
}

/// The commented default scenario ([`Scenario::with_defaults`]) or, with `only`, that table
/// of it and the tables below it.
pub(super) fn commented(only: Option<&str>) -> Result<String, String> {
    let defaults = &table_of(Scenario::with_defaults("my_scenario"))?;
    let examples = examples()?;
    let mut out = String::new();
    match only {
        None => {
            comment(
                &mut out,
                "A scenario with every setting at its default (objslam config defaults), each with what it means. \
                 Keys shown commented out have no default: their value is an example, and their comment says what \
                 leaving them out does.",
            );
            out.push('\n');
            keys(&mut out, "", Some(defaults), Some(&examples));
        }
        Some(path) => {
            let found = [lookup(defaults, path), lookup(&examples, path)];
            if found.iter().flatten().any(|v| !v.is_table()) {
                return Err(format!("{path:?} is a value, not a table"));
            }
            if found.iter().all(Option::is_none) {
                return Err(format!("no table {path:?} in a scenario"));
            }
            out.push_str(&format!("# [{path}] of a scenario, every setting at its default.\n"));
        }
    }
    // The described tables in their order, then any other (undescribed: the tests fail).
    let mut order: Vec<String> = TABLES.iter().map(|(p, _)| p.to_string()).collect();
    let mut present = Vec::new();
    table_paths(defaults, "", &mut present);
    table_paths(&examples, "", &mut present);
    for p in present {
        if !order.contains(&p) {
            order.push(p);
        }
    }
    for path in order {
        if let Some(only) = only
            && !(path == only || path.starts_with(&format!("{only}.")))
        {
            continue;
        }
        let (d, e) = (table_at(defaults, &path), table_at(&examples, &path));
        if d.is_none() && e.is_none() {
            continue;
        }
        out.push('\n');
        if let Some((_, about)) = TABLES.iter().find(|(p, _)| *p == path) {
            comment(&mut out, about);
        }
        out.push_str(&format!("{}[{path}]\n", if d.is_some() { "" } else { "# " }));
        keys(&mut out, &path, d, e);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use super::*;

    fn is_bare_key(k: &str) -> bool {
        !k.is_empty() && k.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
    }

    /// The tables and keys `text` prints, with or without `# `, as dotted paths; a key
    /// line is `key = value` with a value TOML reads. Each key must follow a comment.
    fn printed(text: &str) -> (Vec<String>, Vec<String>) {
        let (mut tables, mut keys) = (Vec::new(), Vec::new());
        let mut table = String::new();
        let mut previous = "";
        for line in text.lines() {
            let body = line.strip_prefix("# ").unwrap_or(line);
            if let Some(inner) = body.strip_prefix('[').and_then(|b| b.strip_suffix(']'))
                && inner.split('.').all(is_bare_key)
            {
                table = inner.to_string();
                tables.push(table.clone());
            } else if let Some((k, v)) = body.split_once(" = ")
                && is_bare_key(k)
                && toml::from_str::<toml::Table>(&format!("x = {v}")).is_ok()
            {
                let path = if table.is_empty() { k.to_string() } else { format!("{table}.{k}") };
                assert!(previous.starts_with("# "), "{path} is printed without a description before it");
                keys.push(path);
            }
            previous = line;
        }
        (tables, keys)
    }

    fn difference<'a>(a: &'a BTreeSet<String>, b: &'a BTreeSet<String>) -> Vec<&'a String> {
        a.difference(b).collect()
    }

    /// What `objslam config defaults` prints and what this file describes are the same keys
    /// and tables, each once.
    #[test]
    fn every_printed_key_has_a_description_and_every_description_is_printed() {
        let text = Scenario::defaults_toml(None).unwrap();
        let (tables, keys) = printed(&text);
        let described_keys: BTreeSet<String> = KEYS.iter().map(|(p, _)| p.to_string()).collect();
        let described_tables: BTreeSet<String> = TABLES.iter().map(|(p, _)| p.to_string()).collect();
        assert_eq!(described_keys.len(), KEYS.len(), "a key is described twice");
        assert_eq!(described_tables.len(), TABLES.len(), "a table is described twice");
        let (printed_keys, printed_tables): (BTreeSet<String>, BTreeSet<String>) =
            (keys.iter().cloned().collect(), tables.iter().cloned().collect());
        assert_eq!(printed_keys.len(), keys.len(), "a key is printed twice:\n{text}");
        let undescribed = difference(&printed_keys, &described_keys);
        assert!(undescribed.is_empty(), "printed without a description in scenario/keys.rs: {undescribed:?}");
        let stale = difference(&described_keys, &printed_keys);
        assert!(stale.is_empty(), "described in scenario/keys.rs but not printed (renamed or removed?): {stale:?}");
        let undescribed = difference(&printed_tables, &described_tables);
        assert!(undescribed.is_empty(), "tables printed without a description: {undescribed:?}");
        let stale = difference(&described_tables, &printed_tables);
        assert!(stale.is_empty(), "tables described but not printed: {stale:?}");
        for (path, about) in KEYS.iter().chain(TABLES) {
            assert!(!about.trim().is_empty() && about.ends_with('.'), "{path}: {about:?}");
        }
        // Table descriptions are one line.
        for (path, about) in TABLES {
            assert!(about.chars().count() + 2 <= WIDTH, "[{path}]'s description is longer than a line");
        }
        let long: Vec<&str> = text.lines().filter(|l| l.chars().count() > WIDTH).collect();
        assert!(long.is_empty(), "lines over {WIDTH} characters: {long:?}");
    }

    /// Keys read under an earlier name (serde aliases), described under their own.
    fn is_former_spelling(key: &str) -> bool {
        // A removed key, read only to be refused with what to do.
        key == "pipeline.object_model.mosaic_patches"
            || key
                .strip_prefix("sim.odometry.")
                .is_some_and(|k| sim::OdometryConfig::FORMER_SPELLINGS.iter().any(|(old, _)| *old == k))
    }

    /// The fields a scenario table accepts, from the error for an unknown one (every table
    /// denies unknown fields, and the error lists the expected ones).
    fn accepted(mut root: toml::Table, path: &str, set: &[(&str, toml::Value)]) -> BTreeSet<String> {
        let mut t = &mut root;
        for key in path.split('.').filter(|k| !k.is_empty()) {
            t = t.entry(key).or_insert_with(|| toml::Value::Table(Default::default())).as_table_mut().unwrap();
        }
        for (k, v) in set {
            t.insert(k.to_string(), v.clone());
        }
        t.insert("no_such_key".into(), toml::Value::Integer(0));
        let e = toml::Value::Table(root).try_into::<Scenario>().unwrap_err().to_string();
        // "unknown field `no_such_key`, expected one of `a`, `b`" then "in `path`".
        let expected = e.split_once("expected ").unwrap_or_else(|| panic!("{path}: {e}")).1.lines().next().unwrap();
        let fields: BTreeSet<String> = expected.split('`').skip(1).step_by(2).map(str::to_string).collect();
        assert!(e.contains("no_such_key") && !fields.is_empty(), "{path}: {e}");
        fields
    }

    /// Every field of every table, optional ones and the car-like motion model's included,
    /// has a description: a knob added to a settings type without one fails here.
    #[test]
    fn every_field_a_scenario_accepts_is_described() {
        let defaults = table_of(Scenario::with_defaults("x")).unwrap();
        let mut missing = Vec::new();
        let mut stale = Vec::new();
        for path in std::iter::once("").chain(TABLES.iter().map(|(p, _)| *p)) {
            let mut fields = accepted(defaults.clone(), path, &[]);
            if path == "pipeline.motion" {
                // `model` picks the struct whose fields the error lists; the other's too.
                let mut ackermann = defaults.clone();
                let pipeline = ackermann.get_mut("pipeline").and_then(|p| p.as_table_mut()).unwrap();
                pipeline.insert("motion".into(), toml::Value::Table(Default::default()));
                fields.extend(accepted(ackermann, path, &[("model", "ackermann".into())]));
                fields.insert("model".into());
            }
            let children: BTreeSet<String> = KEYS
                .iter()
                .chain(TABLES)
                .filter(|(p, _)| split(p).0 == path)
                .map(|(p, _)| split(p).1.to_string())
                .collect();
            let name = |f: &String| if path.is_empty() { f.clone() } else { format!("{path}.{f}") };
            // Former spellings still read but are not printed (serde lists them as fields).
            let fields: BTreeSet<String> = fields.into_iter().filter(|f| !is_former_spelling(&name(f))).collect();
            missing.extend(fields.difference(&children).map(name));
            stale.extend(children.difference(&fields).map(name));
        }
        assert!(missing.is_empty(), "scenario keys without a description in scenario/keys.rs: {missing:?}");
        assert!(stale.is_empty(), "described keys a scenario does not accept: {stale:?}");
    }

    #[test]
    fn one_table_prints_its_keys_and_those_below_with_their_comments() {
        let evidence = Scenario::defaults_toml(Some("pipeline.evidence")).unwrap();
        assert!(evidence.contains("\n[pipeline.evidence]\n"), "{evidence}");
        assert!(evidence.contains("\n# A frame joins the nearest place"), "{evidence}");
        assert!(!evidence.contains("[pipeline.merge]") && !evidence.contains("\nmethod = "), "{evidence}");
        let pass = Scenario::defaults_toml(Some("pass")).unwrap();
        assert!(pass.contains("\n[pass]\n") && pass.contains("\n# min_tree_recall = 0.9\n"), "{pass}");
        let segmentation = Scenario::defaults_toml(Some("calibration.session.segmentation")).unwrap();
        assert!(segmentation.contains("\n# [calibration.session.segmentation]\n# "), "{segmentation}");
        let session = Scenario::defaults_toml(Some("calibration.session")).unwrap();
        assert!(
            session.contains("[calibration.session]\n") && session.contains("# [calibration.session.segmentation]")
        );
        // The whole file is every table's part.
        let all = Scenario::defaults_toml(None).unwrap();
        for (path, _) in TABLES {
            let part = Scenario::defaults_toml(Some(path)).unwrap();
            let body = part.split_once('\n').unwrap().1;
            assert!(all.contains(body), "[{path}] alone is not as in the whole:\n{body}");
        }
    }
}
